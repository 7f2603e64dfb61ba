// Slave's SoE and VoE calls: the mailbox protocol clients (soe.hpp, voe.hpp) run on the control
// thread for an application thread, as the SDO calls in slave.cpp do.
#include <chrono>
#include <utility>

#include <fmt/format.h>

#include <ecat/exec/event_loop.hpp>
#include <ecat/master/soe.hpp>
#include <ecat/master/voe.hpp>
#include <ecat/wire/soe.hpp>
#include <ecat/wire/voe.hpp>

#include "blocking.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

namespace {

using namespace std::chrono_literals;

// The mailbox is usable (PREOP or above, a mailbox at all) and the SII declares the protocol.
// Only the declaration is asked for: an SoE-only drive (no CoE) is fine. (A template: Slave::Impl
// is private to Slave, and this helper is not a member.)
template <class Impl>
Result<void> check_protocol(const Impl& impl, std::uint16_t bit, std::string_view name) {
  if (auto checked = impl.check_mailbox(); !checked) return checked.error();
  const bool declared = impl.sii && (impl.sii->decoded.image.mailbox_protocols & bit) != 0;
  if (!declared) {
    return Error(Errc::unsupported,
                 fmt::format("{}: its SII does not declare {} among its mailbox protocols",
                             impl.who(), name));
  }
  return ok();
}

}  // namespace

Result<std::vector<std::uint8_t>> Slave::soe_read(std::uint8_t drive, std::uint16_t idn,
                                                  std::uint8_t elements,
                                                  std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::uint8_t d, std::uint16_t i, std::uint8_t e, SoeOptions o,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<std::vector<std::uint8_t>>> {
    (void)keep;
    if (auto checked = check_protocol(impl, wire::mailbox_protocol::kSoe, "SoE"); !checked) {
      co_return checked.error();
    }
    auto value = co_await master::soe_read(*impl.mailbox, d, i, e, o);
    impl.note_mailbox_counters();
    co_return value;
  };
  SoeOptions options;
  options.timeout = timeout;
  // A fragmented read waits up to `timeout` per fragment: the blocking wait allows for a long
  // list (up to 64 fragments) before it gives up on the control thread.
  return blocking(
      impl_->session,
      task(*impl_, drive, idn, elements, options, impl_->session.shared_from_this()),
      timeout * 64 + 1s,
      fmt::format("SoE read of {} (drive {}) of slave {}", wire::format_idn(idn), drive, name_));
}

Result<void> Slave::soe_write(std::uint8_t drive, std::uint16_t idn, std::uint8_t elements,
                              std::vector<std::uint8_t> data, std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::uint8_t d, std::uint16_t i, std::uint8_t e,
                 std::vector<std::uint8_t> bytes, SoeOptions o,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<void>> {
    (void)keep;
    if (auto checked = check_protocol(impl, wire::mailbox_protocol::kSoe, "SoE"); !checked) {
      co_return checked.error();
    }
    auto done = co_await master::soe_write(*impl.mailbox, d, i, e, std::move(bytes), o);
    impl.note_mailbox_counters();
    co_return done;
  };
  SoeOptions options;
  options.timeout = timeout;
  return blocking(
      impl_->session,
      task(*impl_, drive, idn, elements, std::move(data), options,
           impl_->session.shared_from_this()),
      timeout * 64 + 1s,
      fmt::format("SoE write of {} (drive {}) of slave {}", wire::format_idn(idn), drive, name_));
}

Result<std::vector<SoeNotification>> Slave::soe_notifications(std::chrono::nanoseconds timeout) {
  auto task =
      [](Impl& impl,
         std::shared_ptr<Session> keep) -> exec::Task<Result<std::vector<SoeNotification>>> {
    (void)keep;
    if (auto checked = check_protocol(impl, wire::mailbox_protocol::kSoe, "SoE"); !checked) {
      co_return checked.error();
    }
    // A notification still waiting in SM1 is read first.
    if (auto polled = co_await impl.mailbox->poll(); !polled) co_return polled.error();
    co_return master::soe_notifications(*impl.mailbox);
  };
  return blocking(impl_->session, task(*impl_, impl_->session.shared_from_this()), timeout,
                  fmt::format("SoE notifications of slave {}", name_));
}

Result<void> Slave::voe_send(std::uint32_t vendor_id, std::uint16_t vendor_type,
                             std::vector<std::uint8_t> data, std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::uint32_t vendor, std::uint16_t type,
                 std::vector<std::uint8_t> bytes, std::chrono::nanoseconds t,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<void>> {
    (void)keep;
    if (auto checked = check_protocol(impl, wire::mailbox_protocol::kVoe, "VoE"); !checked) {
      co_return checked.error();
    }
    co_return co_await master::voe_send(*impl.mailbox, vendor, type, std::move(bytes), t);
  };
  return blocking(impl_->session,
                  task(*impl_, vendor_id, vendor_type, std::move(data), timeout,
                       impl_->session.shared_from_this()),
                  timeout * 2 + 1s, fmt::format("VoE send to slave {}", name_));
}

Result<wire::VoeMessage> Slave::voe_receive(std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::chrono::nanoseconds t,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<wire::VoeMessage>> {
    (void)keep;
    if (auto checked = check_protocol(impl, wire::mailbox_protocol::kVoe, "VoE"); !checked) {
      co_return checked.error();
    }
    co_return co_await master::voe_receive(*impl.mailbox, t);
  };
  return blocking(impl_->session, task(*impl_, timeout, impl_->session.shared_from_this()),
                  timeout * 2 + 1s, fmt::format("VoE receive from slave {}", name_));
}

}  // namespace ecat::master
