#include "slave_access.hpp"

#include <mutex>
#include <utility>

#include <fmt/format.h>

#include "slave_impl.hpp"

namespace ecat::master::detail {

exec::Task<Result<void>> SlaveAccess::bring_up(Slave& slave, std::shared_ptr<Session> keep) {
  return slave.impl().bring_up(std::move(keep));
}

void SlaveAccess::set_startup_error(Slave& slave, std::optional<std::string> why) {
  auto& impl = slave.impl();
  std::lock_guard lock(impl.mutex);
  impl.startup_error = std::move(why);
}

void SlaveAccess::note_retry_in_init(Slave& slave) noexcept {
  slave.impl().note_retry_in_init();
}

void SlaveAccess::start_health(Slave& slave, std::shared_ptr<Session> keep) {
  slave.impl().start_health(std::move(keep));
}

TargetState SlaveAccess::target(const Slave& slave) noexcept {
  return slave.impl().config.target;
}

void SlaveAccess::set_absent(Slave& slave, bool absent) noexcept {
  slave.impl().absent.store(absent, std::memory_order_release);
}

bool SlaveAccess::absent(const Slave& slave) noexcept {
  return slave.impl().absent.load(std::memory_order_acquire);
}

void SlaveAccess::move_to(Slave& slave, std::uint16_t position) noexcept {
  slave.position_.store(position, std::memory_order_relaxed);
}

void SlaveAccess::place(Slave& slave, std::uint16_t position) {
  slave.position_.store(position, std::memory_order_relaxed);
  auto& impl = slave.impl();
  impl.rebuild_pending = false;
  impl.failed_polls = 0;
  std::lock_guard lock(impl.mutex);
  impl.known_identity.reset();
}

void SlaveAccess::lose(Slave& slave, std::string why) {
  auto& impl = slave.impl();
  impl.absent.store(true, std::memory_order_release);
  const auto now = impl.state();
  if (now == SlaveState::preop || now == SlaveState::safeop || now == SlaveState::op) {
    impl.raise_fault(std::move(why));
    impl.set_state(SlaveState::down);
  }
}

bool SlaveAccess::awaiting_rebuild(const Slave& slave) noexcept {
  return slave.impl().awaiting_rebuild();
}

exec::Task<Result<void>> SlaveAccess::go_to(Slave& slave, wire::AlState target,
                                            std::shared_ptr<Session> keep) {
  return slave.impl().go_to(target, std::move(keep));
}

exec::Task<Result<void>> SlaveAccess::retry_configuration(Slave& slave,
                                                          std::shared_ptr<Session> keep) {
  return slave.impl().retry_configuration(std::move(keep));
}

void SlaveAccess::clear_fault(Slave& slave) {
  slave.impl().clear_fault();
}

bool SlaveAccess::retained_failure_without_process_data(const Slave& slave) {
  const auto& impl = slave.impl();
  std::lock_guard lock(impl.mutex);
  return impl.configuration_error.has_value() && impl.attachments.empty() &&
         impl.config.process_data.kind == ProcessDataRequest::Kind::none;
}

bool SlaveAccess::carries_process_data(const Slave& slave) {
  const auto& impl = slave.impl();
  std::lock_guard lock(impl.mutex);
  return !impl.attachments.empty();
}

void SlaveAccess::on_input_change(Slave& slave, const InputChange& change) {
  slave.impl().on_input_change(change);
}

std::uint64_t SlaveAccess::refused_transitions(const Slave& slave) noexcept {
  return slave.impl().fsm.refused();
}

MasterCounters::SlaveCounters SlaveAccess::counters(const Slave& slave) {
  const auto& c = slave.impl().counters;
  return {slave.name(), c.wkc_errors.load(std::memory_order_relaxed),
          c.mailbox_retries.load(std::memory_order_relaxed),
          c.sdo_failures.load(std::memory_order_relaxed)};
}

Result<void> SlaveAccess::stage_output(Slave& slave, const Signal& signal, std::uint64_t raw,
                                       Result<void> (*stage)(const void*), const void* context) {
  Slave::Impl& impl = slave.impl();
  const Slave::Impl::OutputLock images(impl);
  if (auto staged = stage(context); !staged) [[unlikely]] {
    return staged;
  }
  // output_images' nodes are never erased (the hot path keeps pointers to them); a SyncManager
  // without one was never configured, and only the domains hold the value.
  auto it = impl.output_images.find(signal.sync_manager);
  if (it == impl.output_images.end()) [[unlikely]] {
    return ok();
  }
  // The signal's bits as the handle staged them (a `bytes` signal of at most 64 bits too).
  if (!store_bits(it->second, signal.bit_offset, signal.bit_length, raw)) [[unlikely]] {
    return Error(Errc::out_of_range,
                 fmt::format("signal \"{}\" of slave {} lies outside its SyncManager's {} bytes",
                             signal.name, slave.name(), it->second.size()));
  }
  return ok();
}

}  // namespace ecat::master::detail
