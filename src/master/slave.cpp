#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cstring>
#include <map>
#include <set>
#include <thread>

#include <fmt/format.h>

#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/coe_client.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/master/startup.hpp>
#include <ecat/wire/bytes.hpp>

#include "blocking.hpp"
#include "master/event_hub.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

namespace reg = wire::reg;
using namespace std::chrono_literals;

namespace {

std::string hex_identity(const wire::SiiIdentity& id) {
  return fmt::format("vendor 0x{:08x} product 0x{:08x} revision 0x{:08x}", id.vendor_id,
                     id.product_code, id.revision);
}

}  // namespace

// ---- Impl: control loop side ------------------------------------------------------------------

Slave::Impl::Impl(Slave& owner, Session& s, SlaveConfig c)
    : self(owner), session(s), config(std::move(c)) {}

std::string Slave::Impl::who() const {
  return fmt::format("slave {} (station 0x{:04x})", self.name(), self.station());
}

exec::Task<Result<void>> Slave::Impl::bring_up(std::shared_ptr<Session> keep) {
  (void)keep;
  auto& loop = session.loop;
  auto& bus = *session.bus;
  const auto station = self.station();
  {
    std::lock_guard lock(mutex);
    configuration_error.reset();
    configuration_failure.reset();
  }
  auto init = co_await al_request(loop, bus, station, wire::AlState::init, session.config.al);
  if (!init) co_return init.error().context(fmt::format("{}: reaching INIT", who()));
  // A lost slave stays DOWN while it is rebuilt: the seed's edges are DOWN -> PREOP (the
  // rebuild succeeds) and DOWN -> INIT (it is retried from INIT), nothing in between.
  if (state() != SlaveState::down) set_state(SlaveState::init);

  bus::Transaction esc_tx;
  esc_tx.fprd(station, reg::kType, static_cast<std::uint16_t>(reg::kEscInformationSize), 1);
  auto esc_reply = co_await exec::transact(loop, bus, std::move(esc_tx));
  if (!esc_reply)
    co_return esc_reply.error().context(fmt::format("{}: reading ESC information", who()));
  auto esc_info = wire::EscInformation::decode(esc_reply->data(0));
  if (!esc_info) co_return esc_info.error().context(fmt::format("{}: ESC information", who()));

  auto sii_read = co_await read_sii(loop, bus, station);
  if (!sii_read) co_return sii_read.error().context(fmt::format("{}: reading the SII", who()));
  const auto& image = sii_read->decoded.image;
  if (session.stopping) co_return Error(Errc::closed, "session stopped");

  if ((config.vendor_id && *config.vendor_id != image.identity.vendor_id) ||
      (config.product_code && *config.product_code != image.identity.product_code) ||
      (config.revision && *config.revision != image.identity.revision)) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: identity mismatch: configured vendor 0x{:08x} product "
                                "0x{:08x} revision 0x{:08x}, found {}",
                                who(), config.vendor_id.value_or(image.identity.vendor_id),
                                config.product_code.value_or(image.identity.product_code),
                                config.revision.value_or(image.identity.revision),
                                hex_identity(image.identity)));
  }
  if (known_identity && (known_identity->vendor_id != image.identity.vendor_id ||
                         known_identity->product_code != image.identity.product_code ||
                         known_identity->serial != image.identity.serial)) {
    co_return Error(
        Errc::invalid_argument,
        fmt::format("{}: a different device answers at this position: was {}, now {}", who(),
                    hex_identity(*known_identity), hex_identity(image.identity)));
  }
  {
    std::lock_guard lock(mutex);
    esc = *esc_info;
    sii = std::move(*sii_read);
    known_identity = sii->decoded.image.identity;
  }

  // Mailbox SyncManagers (SM0 master -> slave, SM1 slave -> master) from the SII.
  const auto& mbx = sii->decoded.image.standard_mailbox;
  if (mbx.present()) {
    auto written = co_await write_mailbox_sync_managers(loop, bus, station, mbx);
    if (!written) {
      co_return written.error().context(fmt::format("{}: writing the mailbox SyncManagers", who()));
    }
    const MailboxConfig mc = *written;
    std::lock_guard lock(mutex);
    // One Mailbox per slave for its whole life: after the SyncManagers were written again (a
    // rebuild) it is reset, so counters start over as the slave's do.
    if (mailbox && mailbox->config() == mc) {
      mailbox->reset();
    } else {
      mailbox = std::make_unique<Mailbox>(loop, bus, station, mc);
    }
    // Polled until the PREOP configuration has mapped SM1's status again (an FMMU written now).
    mailbox->set_status_source(std::nullopt);
  } else {
    std::lock_guard lock(mutex);
    mailbox.reset();
  }

  auto preop = co_await al_step(loop, bus, station, wire::AlState::preop, session.config.al);
  if (!preop) {
    record_al_error(preop.error());
    co_return preop.error().context(fmt::format("{}: reaching PREOP", who()));
  }
  set_state(SlaveState::preop);

  auto configured = co_await configure_preop(keep);
  if (!configured) {
    // Retained: the slave stays in PREOP (reachable for SDOs and reconfiguration) and SAFEOP/OP
    // requests are refused with this error until retry() or configure() succeeds.
    std::lock_guard lock(mutex);
    configuration_error = configured.error().describe();
    configuration_failure = configured.error();
  }
  co_return ok();
}

exec::Task<Result<void>> Slave::Impl::run_sdos(const std::vector<SdoWrite>& writes) {
  for (const auto& w : writes) {
    if (!mailbox) {
      co_return Error(
          Errc::unsupported,
          fmt::format("{}: SDO {} needs a mailbox, the slave has none", who(), to_string(w)));
    }
    SdoOptions options;
    options.complete_access = w.complete_access;
    auto done = co_await master::download_sdo(*mailbox, w.index, w.subindex, w.data, options);
    if (!done)
      co_return done.error().context(fmt::format("{}: startup SDO {}", who(), to_string(w)));
  }
  co_return ok();
}

exec::Task<Result<CoePdoConfiguration>> Slave::Impl::read_coe_pdos(const PdoLayout& known) {
  if (!mailbox) {
    co_return Error(
        Errc::unsupported,
        fmt::format("{}: PDO layout from CoE needs a mailbox, the slave has none", who()));
  }
  CoePdoConfiguration coe;
  for (auto assignment : detail::coe_assignments_to_read(sii->decoded.image)) {
    const auto object = pdo_assignment_object(assignment.sync_manager);
    auto count = co_await master::upload<std::uint8_t>(*mailbox, object, 0);
    if (!count) {
      if (sdo_abort_code(count.error())) continue;  // no such object: SM not used for PDOs
      co_return count.error();
    }
    for (std::uint8_t sub = 1; sub <= *count; ++sub) {
      auto pdo = co_await master::upload<std::uint16_t>(*mailbox, object, sub);
      if (!pdo) co_return pdo.error();
      assignment.pdo_indices.push_back(*pdo);
      CoePdoMapping mapping;
      mapping.pdo_index = *pdo;
      auto entries = co_await master::upload<std::uint8_t>(*mailbox, *pdo, 0);
      if (!entries) {
        if (known.find_pdo(*pdo) != nullptr) continue;  // fixed PDO, the SII knows it
        co_return entries.error();
      }
      for (std::uint8_t e = 1; e <= *entries; ++e) {
        auto entry = co_await master::upload<std::uint32_t>(*mailbox, *pdo, e);
        if (!entry) co_return entry.error();
        mapping.entries.push_back(*entry);
      }
      coe.mappings.push_back(std::move(mapping));
    }
    coe.assignments.push_back(std::move(assignment));
  }
  co_return coe;
}

detail::PreopFacts Slave::Impl::preop_facts() const {
  detail::PreopFacts facts;
  facts.who = who();
  facts.sii = sii->decoded.image;
  facts.fmmu_count = esc.fmmu_count;
  facts.has_mailbox = mailbox != nullptr;
  facts.mailbox_status = config.mailbox_status.value_or(session.config.mailbox_status);
  if (mailbox) facts.mailbox_in_sync_manager = mailbox->config().in_sync_manager;
  const auto station = self.station();
  for (const auto& domain : session.domains) {
    detail::DomainFacts d;
    d.id = domain->id();
    d.period = domain->cycle_period();
    for (const auto& r : domain->registrations()) {
      if (r.key.slave != station) continue;
      d.registered.push_back({r.key.sync_manager, r.size, r.direction, r.logical, r.key.kind});
    }
    facts.domains.push_back(std::move(d));
  }
  return facts;
}

// The plan (preop_plan.hpp) decides; this carries it out: SDOs, the PDO mapping read where the
// layout comes from CoE, the domains' registrations, the SyncManager and FMMU writes, and then
// what the slave publishes.
exec::Task<Result<void>> Slave::Impl::configure_preop(std::shared_ptr<Session> keep) {
  (void)keep;
  auto& loop = session.loop;
  auto& bus = *session.bus;
  const auto station = self.station();

  auto chosen = detail::choose_driver(session.drivers, config, sii->decoded.image.identity, who());
  if (!chosen) co_return chosen.error();
  auto made_state = (*chosen)->init(config.driver_config);
  if (!made_state) {
    co_return made_state.error().context(fmt::format("{}: driver {}", who(), (*chosen)->name()));
  }

  const auto facts = preop_facts();
  auto setup = detail::plan_layout(facts, config, **chosen);
  if (!setup) co_return setup.error();
  if (auto ran = co_await run_sdos(setup->sdos); !ran) co_return ran.error();
  std::optional<CoePdoConfiguration> coe;
  if (setup->read_from_coe) {
    auto read = co_await read_coe_pdos(setup->sii_layout);
    if (!read) co_return read.error().context(fmt::format("{}: reading the PDO mapping", who()));
    coe = std::move(*read);
  }

  auto plan = detail::plan_process_data(facts, config, **chosen, *setup, coe ? &*coe : nullptr);
  if (!plan) co_return plan.error();
  if (auto ran = co_await run_sdos(plan->sdos); !ran) co_return ran.error();

  // All of the slave's SyncManagers are registered or none: room first, domain by domain.
  for (const auto& need : plan->room) {
    if (auto room = session.find_domain(need.domain)->check_room(need.count, need.bytes); !room) {
      co_return room.error().context(
          fmt::format("{}: registering its {} SyncManager(s) in domain \"{}\"", who(), need.count,
                      need.domain));
    }
  }
  for (const auto i : plan->new_registrations) {
    auto& a = plan->attachments[i];
    auto logical = session.find_domain(a.domain)->register_pdo(PdoKey{station, a.sync_manager},
                                                               a.size, a.direction);
    if (!logical) {
      co_return logical.error().context(fmt::format(
          "{}: registering SyncManager {} in domain \"{}\"", who(), a.sync_manager, a.domain));
    }
    a.logical_address = *logical;
  }
  if (auto& m = plan->mailbox_status; m && m->new_registration) {
    auto logical = session.find_domain(m->domain)->register_sm_status(station, m->sync_manager);
    if (!logical) {
      co_return logical.error().context(
          fmt::format("{}: registering the status of SyncManager {} (mailbox) in domain \"{}\"",
                      who(), m->sync_manager, m->domain));
    }
    m->logical_address = *logical;
  }

  bus::Transaction tx;
  for (const auto& w : detail::process_data_writes(*plan))
    tx.fpwr(station, w.address, w.data, 1);
  if (!tx.empty()) {
    auto written = co_await exec::transact(loop, bus, std::move(tx));
    if (!written) {
      co_return written.error().context(
          fmt::format("{}: writing process-data SyncManagers and FMMUs", who()));
    }
  }

  // Publish. Output images start as zeros, or keep what was staged before (a reconnect).
  std::lock_guard lock(mutex);
  driver = std::move(*chosen);
  driver_state = std::move(*made_state);
  layout = std::move(plan->layout);
  signals = std::move(plan->signals);
  attachments = std::move(plan->attachments);
  {
    // The images and the view change together under the output lock: a write_output on the
    // view before waits, then sees that the view changed and takes the `mutex` path.
    const OutputLock images(*this);
    for (const auto& a : attachments) {
      if (a.direction != PdoDirection::output) continue;
      auto& img = output_images[a.sync_manager];
      if (img.size() != a.size) img.assign(a.size, 0);
      auto* domain = session.find_domain(a.domain);
      (void)domain->write(PdoKey{station, a.sync_manager}, img);
    }
    index_routes();
  }
  mailbox_status = plan->mailbox_status;
  if (mailbox) {
    std::optional<MailboxStatusSource> source;
    if (mailbox_status) {
      const auto* domain = session.find_domain(mailbox_status->domain);
      auto handle =
          domain->find(PdoKey{station, mailbox_status->sync_manager, RegistrationKind::sm_status});
      if (handle) source = MailboxStatusSource{domain, *handle};
    }
    mailbox->set_status_source(source);
  }
  configuration_error.reset();
  configuration_failure.reset();
  co_return ok();
}

void Slave::Impl::record_al_error(const Error& error) {
  if (auto code = al_status_code(error)) {
    std::lock_guard lock(mutex);
    al_code = *code;
  }
}

exec::Task<Result<MailboxConfig>> write_mailbox_sync_managers(exec::EventLoop& loop, bus::Bus& bus,
                                                              std::uint16_t station,
                                                              const wire::SiiMailbox& mbx) {
  wire::SyncManagerConfig out;
  out.physical_start = mbx.recv_offset;
  out.length = mbx.recv_size;
  out.control = wire::kMailboxOutControl;
  out.activate.enable = true;
  wire::SyncManagerConfig in;
  in.physical_start = mbx.send_offset;
  in.length = mbx.send_size;
  in.control = wire::kMailboxInControl;
  in.activate.enable = true;
  bus::Transaction tx;
  const std::array<std::uint8_t, 1> off{0};
  tx.fpwr(station, reg::kSyncManagerBase + reg::kSyncManagerActivateOffset, off, 1);
  tx.fpwr(station, reg::kSyncManagerBase + 8 + reg::kSyncManagerActivateOffset, off, 1);
  tx.fpwr(station, reg::kSyncManagerBase, out.encode(), 1);
  tx.fpwr(station, reg::kSyncManagerBase + 8, in.encode(), 1);
  auto written = co_await exec::transact(loop, bus, std::move(tx));
  if (!written) co_return written.error();
  MailboxConfig mc;
  mc.out_offset = mbx.recv_offset;
  mc.out_size = mbx.recv_size;
  mc.in_offset = mbx.send_offset;
  mc.in_size = mbx.send_size;
  co_return mc;
}

exec::Task<Result<void>> Slave::Impl::go_to(wire::AlState target, std::shared_ptr<Session> keep) {
  if (firmware_update) {
    co_return Error(Errc::busy, fmt::format("{}: a firmware update is in progress; {} is refused "
                                            "until it ends",
                                            who(), wire::to_string(target)));
  }
  co_return co_await walk_to(target, std::move(keep));
}

exec::Task<Result<void>> Slave::Impl::walk_to(wire::AlState target, std::shared_ptr<Session> keep) {
  (void)keep;
  auto& loop = session.loop;
  auto& bus = *session.bus;
  const auto station = self.station();
  if (awaiting_rebuild()) {
    co_return Error(Errc::wrong_state, fmt::format("{} is down", who()));
  }
  struct Busy {
    int& count;
    explicit Busy(int& c) : count(c) { ++count; }
    ~Busy() { --count; }
    Busy(const Busy&) = delete;
    Busy& operator=(const Busy&) = delete;
  } busy_guard(busy);
  if (target == wire::AlState::safeop || target == wire::AlState::op) {
    std::lock_guard lock(mutex);
    if (configuration_error) {
      // The failure stays the cause, so callers can still branch on it (sdo_failure, codes).
      if (configuration_failure) {
        co_return configuration_failure->context(
            Errc::wrong_state, fmt::format("{}: PREOP configuration failed, {} refused until it "
                                           "is retried",
                                           who(), wire::to_string(target)));
      }
      co_return Error(Errc::wrong_state,
                      fmt::format("{}: PREOP configuration failed, {} refused until it is "
                                  "retried: {}",
                                  who(), wire::to_string(target), *configuration_error));
    }
  }
  auto status = co_await read_al_status(
      loop, bus, station,
      bus::TransactOptions{session.config.al.read_timeout, session.config.al.read_retries});
  if (!status) co_return status.error().context(fmt::format("{}: reading AL status", who()));
  if (status->status.error) {
    auto acked = co_await al_acknowledge(loop, bus, station, session.config.al);
    if (!acked) co_return acked.error();
    status = *acked;
  }
  const auto from = status->status.state;
  set_state(slave_state_of(from));
  auto path = al_path(from, target);
  if (!path) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: no AL path from {} to {}", who(), wire::to_string(from),
                                wire::to_string(target)));
  }
  // The seed's request edges go straight to the target (init -> op: "OP request path
  // succeeds"): the steps on the way are the runtime's, and only where the diagram has no direct
  // edge (out of BOOTSTRAP, into BOOTSTRAP from OP) is the state changed step by step.
  const SlaveState final_state = slave_state_of(target);
  wire::AlState at = from;
  for (auto step : *path) {
    if (step == wire::AlState::safeop) {
      if (auto synced = co_await apply_sync(); !synced) co_return synced.error();
    }
    // BOOTSTRAP has its own mailbox (slave_foe.cpp): its SyncManagers before the step in, the
    // standard mailbox's after the step out.
    if (step == wire::AlState::bootstrap) {
      if (auto boot = co_await enter_boot_mailbox(); !boot) co_return boot.error();
    }
    auto stepped = co_await al_step(loop, bus, station, step, session.config.al);
    if (!stepped && step == wire::AlState::bootstrap) (void)co_await leave_boot_mailbox();
    if (stepped && at == wire::AlState::bootstrap) {
      if (auto left = co_await leave_boot_mailbox(); !left) {
        set_state(slave_state_of(step));
        co_return left.error();
      }
    }
    at = step;
    if (!stepped) {
      record_al_error(stepped.error());
      // What the slave is in now (it may have fallen back).
      if (auto now =
              co_await read_al_status(loop, bus, station,
                                      bus::TransactOptions{session.config.al.read_timeout,
                                                           session.config.al.read_retries})) {
        set_state(slave_state_of(now->status.state));
      }
      co_return stepped.error().context(
          fmt::format("{}: requesting {}", who(), wire::to_string(target)));
    }
    if (step == path->back() || !slave_transition_allowed(state(), final_state)) {
      set_state(slave_state_of(step));
    }
  }
  co_return ok();
}

// ---- what the event stream and the counters see ---------------------------------------------

void Slave::Impl::set_state(SlaveState to) noexcept {
  const SlaveState from = fsm.state();
  const auto change = fsm.change(to);
  if (session.events == nullptr || change == SlaveFsm::Change::unchanged) return;
  if (change == SlaveFsm::Change::refused) {
    Event e = make_event(EventKind::fault_raised, self.name());
    format_detail(e, "refused an undrawn state change {} -> {} (a bug: please report it)",
                  to_string(from), to_string(to));
    session.events->publish(e);
    return;
  }
  Event e = make_event(EventKind::slave_state, self.name());
  e.subject = self.position();
  e.from = static_cast<std::uint8_t>(from);
  e.to = static_cast<std::uint8_t>(to);
  session.events->publish(e);
}

void Slave::Impl::note_retry_in_init() noexcept {
  if (!fsm.retries_in_init() || session.events == nullptr) return;
  Event e = make_event(EventKind::slave_state, self.name(), "auto-advance retries");
  e.subject = self.position();
  e.from = static_cast<std::uint8_t>(SlaveState::init);
  e.to = static_cast<std::uint8_t>(SlaveState::init);
  session.events->publish(e);
}

void Slave::Impl::raise_fault(std::string why) {
  {
    std::lock_guard lock(mutex);
    if (fault == why) return;
    fault = why;
  }
  if (session.events)
    session.events->publish(make_event(EventKind::fault_raised, self.name(), why));
}

void Slave::Impl::clear_fault() {
  std::optional<std::string> was;
  {
    std::lock_guard lock(mutex);
    was.swap(fault);
  }
  if (was && session.events) {
    session.events->publish(make_event(EventKind::fault_cleared, self.name(), *was));
  }
}

void Slave::Impl::note_sdo_failure(const Error& error) {
  counters.sdo_failures.fetch_add(1, std::memory_order_relaxed);
  if (session.events == nullptr) return;
  const auto abort = error.code_value(Errc::sdo_abort);
  Event e = make_event(abort ? EventKind::sdo_failed
                       : (error.code() == Errc::mailbox_error || error.code() == Errc::timeout)
                           ? EventKind::mailbox_failed
                           : EventKind::sdo_failed,
                       self.name(), error.describe());
  e.value = abort.value_or(0);
  session.events->publish(e);
}

void Slave::Impl::note_mailbox_counters() noexcept {
  if (!mailbox) return;
  const auto& m = mailbox->stats();
  counters.mailbox_retries.store(m.write_retries + m.repeat_requests, std::memory_order_relaxed);
}

exec::Task<Result<std::vector<std::uint8_t>>> Slave::Impl::sdo_upload(
    std::uint16_t index, std::uint8_t subindex, SdoOptions options, std::shared_ptr<Session> keep) {
  (void)keep;
  auto checked = check_mailbox();
  if (!checked) co_return checked.error();
  auto value = co_await master::upload_sdo(*mailbox, index, subindex, options);
  note_mailbox_counters();
  if (!value) note_sdo_failure(value.error());
  co_return value;
}

exec::Task<Result<void>> Slave::Impl::sdo_download(std::uint16_t index, std::uint8_t subindex,
                                                   std::vector<std::uint8_t> data,
                                                   SdoOptions options,
                                                   std::shared_ptr<Session> keep) {
  (void)keep;
  auto checked = check_mailbox();
  if (!checked) co_return checked.error();
  if (data.empty()) {
    co_return Error(
        Errc::invalid_argument,
        fmt::format("{}: SDO download of 0x{:04x}:{:02x} with no data", who(), index, subindex));
  }
  auto done = co_await master::download_sdo(*mailbox, index, subindex, std::move(data), options);
  note_mailbox_counters();
  if (!done) note_sdo_failure(done.error());
  co_return done;
}

exec::Task<Result<void>> Slave::Impl::apply_sync() {
  if (!config.sync) co_return ok();
  // The application's synchronisation (ETG.1020 0x1C32/0x1C33 subindex 1), when it has the
  // objects: 0 free run, 1 SyncManager event (inputs: 0x22, on the output SM's event), 2 SYNC0,
  // 3 SYNC1.
  if (mailbox && (sii && (sii->decoded.image.mailbox_protocols & wire::mailbox_protocol::kCoe))) {
    std::uint16_t out_type = 0;
    std::uint16_t in_type = 0;
    switch (config.sync->mode) {
      case SyncMode::free_run:
        break;
      case SyncMode::sm_synchronous:
        out_type = 1;
        in_type = 0x22;
        break;
      case SyncMode::sync0:
        out_type = in_type = 2;
        break;
      case SyncMode::sync1:
        out_type = in_type = 3;
        break;
    }
    for (const auto& [index, type] :
         {std::pair{std::uint16_t{0x1C32}, out_type}, std::pair{std::uint16_t{0x1C33}, in_type}}) {
      std::vector<std::uint8_t> value{static_cast<std::uint8_t>(type & 0xFF),
                                      static_cast<std::uint8_t>(type >> 8)};
      auto written = co_await master::download_sdo(*mailbox, index, 0x01, std::move(value), {});
      if (written) continue;
      const auto code = sdo_abort_code(written.error());
      // A device without the object (or without that subindex) has a fixed synchronisation.
      if (code && (*code == 0x06020000 || *code == 0x06090011)) continue;
      co_return written.error().context(fmt::format("{}: setting sync mode {} in 0x{:04x}:01",
                                                    who(), to_string(config.sync->mode), index));
    }
  }
  if (config.sync->mode == SyncMode::sm_synchronous && config.sync->latches.empty()) co_return ok();
  if (!session.config.dc) {
    if (config.sync->mode == SyncMode::free_run || config.sync->mode == SyncMode::sm_synchronous) {
      co_return ok();
    }
    co_return Error(Errc::unsupported,
                    fmt::format("{}: sync {} configured, but distributed clocks are disabled",
                                who(), to_string(config.sync->mode)));
  }
  std::optional<DcPlannedSlave> planned;
  {
    // dc_init is written under the master's lock once, at startup, before any slave steps.
    if (!session.dc_init) {
      if (config.sync->mode == SyncMode::free_run && config.sync->latches.empty()) co_return ok();
      co_return Error(Errc::unsupported,
                      fmt::format("{}: sync {} configured, but distributed clocks do not run{}",
                                  who(), to_string(config.sync->mode),
                                  session.dc_error ? ": " + session.dc_error->message() : ""));
    }
    for (const auto& p : session.dc_init->plan.slaves) {
      if (p.station == self.station()) planned = p;
    }
  }
  if (!planned || !planned->dc) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: sync {} configured, but the slave has no distributed clock",
                                who(), to_string(config.sync->mode)));
  }
  if (!config.esi_file.empty() && !esi_device) {
    auto file = config::load_esi(config.esi_file);
    if (!file) co_return file.error().context(fmt::format("{}: ESI file", who()));
    const std::optional<std::uint32_t> product =
        sii ? std::optional(sii->decoded.image.identity.product_code) : std::nullopt;
    auto device = config::find_esi_device(*file, product);
    if (!device) {
      co_return device.error().context(
          fmt::format("{}: ESI file {} has no description of this device", who(), config.esi_file));
    }
    esi_device = **device;
  }
  DcSyncRequest request;
  request.station = self.station();
  request.cycle = session.config.dc->cycle;
  request.sync = *config.sync;
  request.sii = sii ? &sii->decoded.image : nullptr;
  request.esi = esi_device ? &*esi_device : nullptr;
  auto result = co_await configure_sync(session.loop, *session.bus, request);
  if (!result) co_return result.error().context(fmt::format("{}: configuring SYNC", who()));
  {
    std::lock_guard lock(mutex);
    dc_sync = *result;
  }
  if (!config.sync->latches.empty() && !latch_running) {
    latch_running = true;
    exec::spawn(session.loop, latch_loop(session.shared_from_this()));
  }
  co_return ok();
}

exec::Task<Result<void>> Slave::Impl::reinit_dc() {
  // dc_init is written once at startup, on this loop, before any slave steps.
  if (!session.dc_init) co_return ok();
  const auto& plan = session.dc_init->plan;
  const bool planned = std::any_of(plan.slaves.begin(), plan.slaves.end(), [&](const auto& p) {
    return p.dc && p.station == self.station();
  });
  if (!planned) co_return ok();
  auto result =
      co_await reinitialize_dc_slave(session.loop, *session.bus, plan, self.station(), {});
  if (!result) {
    co_return result.error().context(
        fmt::format("{}: re-initialising its distributed clock", who()));
  }
  if (session.dc) session.dc->note_reinitialised(self.station());
  co_return ok();
}

const LatchConfig* Slave::Impl::find_latch(std::string_view name) const {
  if (!config.sync) return nullptr;
  for (const auto& l : config.sync->latches) {
    if (l.name == name) return &l;
  }
  return nullptr;
}

exec::Task<void> Slave::Impl::latch_loop(std::shared_ptr<Session> keep) {
  (void)keep;
  // The reference polls every millisecond in OP; SAFEOP too here (the units run from SAFEOP on).
  constexpr auto kPeriod = std::chrono::milliseconds(1);
  while (!session.stopping) {
    co_await exec::sleep_for(session.loop, kPeriod);
    if (session.stopping) break;
    const auto now = state();
    if (now != SlaveState::safeop && now != SlaveState::op) continue;
    auto events = co_await poll_latches(session.loop, *session.bus, self.station());
    if (!events || events->empty()) continue;  // a lost slave is the health poll's business
    std::vector<std::pair<std::function<void(const SignalEvent&)>, SignalEvent>> calls;
    {
      std::lock_guard lock(mutex);
      if (!config.sync) continue;
      for (const auto& e : *events) {
        for (const auto& l : config.sync->latches) {
          if (l.unit != e.unit || l.edge != e.edge) continue;
          for (const auto& sub : subscriptions) {
            if (sub.signal != l.name) continue;
            calls.emplace_back(
                sub.callback, SignalEvent{self.name(), l.name, Value(std::uint64_t{e.timestamp_ns}),
                                          0, Clock::now()});
          }
        }
      }
    }
    for (auto& [callback, event] : calls)
      callback(event);
  }
  latch_running = false;
}

Result<void> Slave::Impl::check_mailbox() const {
  const auto s = state();
  if (s == SlaveState::down) return Error(Errc::wrong_state, fmt::format("{} is down", who()));
  if (s == SlaveState::init || s == SlaveState::bootstrap) {
    return Error(Errc::wrong_state,
                 fmt::format("{}: mailbox not ready in {}", who(), to_string(s)));
  }
  if (!mailbox) {
    return Error(Errc::unsupported, fmt::format("{} has no mailbox (no CoE)", who()));
  }
  return ok();
}

detail::SlaveHotPath::NameKey detail::SlaveHotPath::short_name_key(std::string_view name) noexcept {
  NameKey key;
  const std::size_t n = name.size();
  const char* p = name.data();
  key.length = n;
  if (n >= 4) {
    // Two overlapping four-byte loads, the second moved up to its place: bytes 0..n-1, zeros above.
    std::uint32_t first = 0;
    std::uint32_t last = 0;
    std::memcpy(&first, p, 4);
    std::memcpy(&last, p + n - 4, 4);
    std::uint8_t bytes[8] = {};
    std::memcpy(bytes, &first, 4);
    std::memcpy(bytes + n - 4, &last, 4);
    std::memcpy(&key.head, bytes, 8);
  } else if (n > 0) {
    std::uint8_t bytes[8] = {};
    bytes[0] = static_cast<std::uint8_t>(p[0]);
    bytes[n / 2] = static_cast<std::uint8_t>(p[n / 2]);
    bytes[n - 1] = static_cast<std::uint8_t>(p[n - 1]);
    std::memcpy(&key.head, bytes, 8);
  }
  return key;
}

std::ptrdiff_t detail::SlaveHotPath::find_index(std::string_view name) const noexcept {
  if (!signal_index.empty()) {
    const NameKey key = name_key(name);
    const std::size_t mask = signal_index.size() - 1;
    for (std::size_t i = hash(key, index_shift);; i = (i + 1) & mask) {
      const std::uint32_t slot = signal_index[i];
      if (slot == 0) return -1;  // the table is at most half full: an empty slot ends it
      const std::size_t k = slot - 1;
      // Up to 16 bytes the key is the name; a longer name compares its middle too.
      if (slots[k].key == key &&
          (key.length <= 16 ||
           std::memcmp(signals[k].name.data() + 8, name.data() + 8, key.length - 16) == 0)) {
        return static_cast<std::ptrdiff_t>(k);
      }
    }
  }
  for (std::size_t k = 0; k < signals.size(); ++k) {
    if (signals[k].name == name) return static_cast<std::ptrdiff_t>(k);
  }
  return -1;
}

void detail::SlaveHotPath::index_names() {
  slots.resize(signals.size());
  for (std::size_t k = 0; k < signals.size(); ++k)
    slots[k].key = name_key(signals[k].name);
  signal_index.clear();
  index_shift = 64;
  if (signals.empty()) return;
  signal_index.assign(std::bit_ceil(signals.size() * 2), 0);
  const std::size_t mask = signal_index.size() - 1;
  index_shift = 64 - static_cast<unsigned>(std::countr_zero(signal_index.size()));
  for (std::size_t k = 0; k < signals.size(); ++k) {
    for (std::size_t i = hash(slots[k].key, index_shift);; i = (i + 1) & mask) {
      if (signal_index[i] == 0) {
        signal_index[i] = static_cast<std::uint32_t>(k + 1);
        break;
      }
      if (signals[signal_index[i] - 1].name == signals[k].name) {
        // Duplicate names (none expected): the walk in find_index keeps the first one.
        signal_index.clear();
        return;
      }
    }
  }
}

const detail::SlaveRoute* detail::SlaveHotPath::route_for(std::uint8_t sm) const noexcept {
  for (const auto& r : routes) {
    if (r.sync_manager == sm) return &r;
  }
  return nullptr;
}

const Signal* Slave::Impl::find_signal(std::string_view name) const noexcept {
  const HotPath* view = hot.load(std::memory_order_acquire);
  return view != nullptr ? view->find(name) : nullptr;
}

void Slave::Impl::index_routes() {
  auto view = std::make_unique<HotPath>();
  view->signals = signals;
  for (const auto& a : attachments) {
    Domain* domain = session.find_domain(a.domain);
    if (!domain) continue;
    auto handle = domain->find(PdoKey{self.station(), a.sync_manager});
    if (!handle) continue;
    view->routes.push_back(Route{a.sync_manager, a.size, domain, *handle});
  }
  view->all_routed = view->routes.size() == attachments.size();
  view->slots.resize(signals.size());
  for (std::size_t k = 0; k < signals.size(); ++k) {
    const Signal& sig = signals[k];
    HotPath::Slot& slot = view->slots[k];
    const Route* route = view->route_for(sig.sync_manager);
    if (route == nullptr || !is_field(sig, route->size)) continue;
    if (sig.direction == PdoDirection::input) {
      auto f = route->domain->field(route->handle, sig.bit_offset, sig.bit_length);
      if (!f) continue;
      slot.input = HotPath::Target{route->domain, *f};
      slot.path = HotPath::Path::input_field;
      continue;
    }
    // An output: staged in every domain of its SyncManager, so only when all are routed.
    auto image = output_images.find(sig.sync_manager);
    if (!view->all_routed || image == output_images.end()) continue;
    const auto first = static_cast<std::uint32_t>(view->targets.size());
    bool made = true;
    for (const auto& r : view->routes) {
      if (r.sync_manager != sig.sync_manager) continue;
      auto f = r.domain->field(r.handle, sig.bit_offset, sig.bit_length);
      if (!f) {
        made = false;
        break;
      }
      view->targets.push_back(HotPath::Target{r.domain, *f});
    }
    if (!made) {
      view->targets.resize(first);
      continue;
    }
    slot.first = first;
    slot.count = static_cast<std::uint32_t>(view->targets.size()) - first;
    slot.image = &image->second;
    slot.image_size = route->size;
    slot.path = HotPath::Path::output_field;
  }
  view->index_names();
  // Readers may still hold the view published before: it stays (see `views`).
  for (const auto& made : views) {
    if (*made == *view) {
      hot.store(made.get(), std::memory_order_release);
      return;
    }
  }
  views.push_back(std::move(view));
  hot.store(views.back().get(), std::memory_order_release);
}

Slave::Impl::OutputLock::OutputLock(const Impl& owner) noexcept : impl(owner) {
  for (int spins = 0;; ++spins) {
    bool expected = false;
    if (impl.output_lock.compare_exchange_weak(expected, true, std::memory_order_acquire,
                                               std::memory_order_relaxed)) {
      return;
    }
    // Holders stage a few bytes; a holder that lost its CPU needs the CPU back.
    if (spins >= 64) std::this_thread::yield();
  }
}

Slave::Impl::OutputLock::~OutputLock() {
  impl.output_lock.store(false, std::memory_order_release);
}

const SmAttachment* Slave::Impl::attachment_for(std::uint8_t sm) const noexcept {
  for (const auto& a : attachments) {
    if (a.sync_manager == sm) return &a;
  }
  return nullptr;
}

std::vector<Value> Slave::Impl::signal_values(
    const std::map<std::uint8_t, std::vector<std::uint8_t>>& inputs) const {
  std::vector<Value> values;
  values.reserve(signals.size());
  const OutputLock guard(*this);
  for (const auto& sig : signals) {
    const auto& images = sig.direction == PdoDirection::output ? output_images : inputs;
    auto it = images.find(sig.sync_manager);
    Value v = std::int64_t{0};
    if (it != images.end()) {
      if (auto d = decode_scaled(sig, it->second)) v = std::move(*d);
    }
    values.push_back(std::move(v));
  }
  return values;
}

void Slave::Impl::project(const std::map<std::uint8_t, std::vector<std::uint8_t>>& inputs) {
  if (!driver) return;
  const auto values = signal_values(inputs);
  SignalValues current(signals, values);
  auto next = driver->project_state(current, &device_state, driver_state.get());
  if (next) device_state = std::move(*next);
}

void Slave::Impl::on_input_change(const InputChange& change) {
  std::vector<std::pair<std::function<void(const SignalEvent&)>, SignalEvent>> calls;
  {
    std::lock_guard lock(mutex);
    if (driver) {
      // The driver's projected device state follows the inputs.
      std::map<std::uint8_t, std::vector<std::uint8_t>> inputs;
      for (const auto& a : attachments) {
        if (a.direction != PdoDirection::input || inputs.count(a.sync_manager)) continue;
        auto* domain = session.find_domain(a.domain);
        std::vector<std::uint8_t> image(a.size);
        if (domain && domain->read(PdoKey{self.station(), a.sync_manager}, image)) {
          inputs.emplace(a.sync_manager, std::move(image));
        }
      }
      project(inputs);
    }
    if (subscriptions.empty()) return;
    const auto* a = attachment_for(change.key.sync_manager);
    if (!a) return;
    auto* domain = session.find_domain(a->domain);
    if (!domain) return;
    std::vector<std::uint8_t> image(a->size);
    if (!domain->read(change.key, image)) return;
    for (auto& sub : subscriptions) {
      const Signal* sig = find_signal(sub.signal);
      if (!sig || sig->sync_manager != change.key.sync_manager) continue;
      auto value = decode_scaled(*sig, image);
      if (!value) continue;
      if (sub.last && *sub.last == *value) continue;
      sub.last = *value;
      calls.emplace_back(sub.callback,
                         SignalEvent{self.name(), sub.signal, *value, change.cycle, change.at});
    }
  }
  for (auto& [cb, ev] : calls)
    cb(ev);
}

void Slave::Impl::start_health(std::shared_ptr<Session> keep) {
  if (health_running || !config.health_poll) return;
  health_running = true;
  exec::spawn(session.loop, health_loop(std::move(keep)));
}

exec::Task<void> Slave::Impl::health_loop(std::shared_ptr<Session> keep) {
  auto& loop = session.loop;
  auto& bus = *session.bus;
  const auto station = self.station();
  while (!session.stopping) {
    std::chrono::nanoseconds period;
    {
      std::lock_guard lock(mutex);
      if (!config.health_poll) break;
      period = *config.health_poll;
    }
    co_await exec::sleep_for(loop, period);
    if (session.stopping) break;
    // A session held in PREOP since startup does not poll until it is activated (the
    // reference's rule, scenarios 47-51).
    if (session.health_held || absent.load(std::memory_order_acquire)) {
      failed_polls = 0;
      continue;
    }
    const auto now = state();
    if (awaiting_rebuild()) {
      if (co_await probe_and_rebuild(keep)) {
        session.notify({SlaveNotice::Kind::reconnected, self.name(), "back in PREOP"});
      }
      continue;
    }
    if (busy > 0) continue;  // a request is walking the AL states right now
    const bus::TransactOptions quick{std::max<std::chrono::nanoseconds>(period, 20ms), 1};
    auto status = co_await read_al_status(loop, bus, station, quick);
    if (session.stopping) break;
    if (busy > 0) continue;
    if (!status) {
      // A poll that got no reply at all says nothing about this slave: the frame was lost on
      // the way (the domains report that as a transport miss). A reply without this slave's
      // working counter is counted, and one such poll may be a passing fault: the slave is down
      // when the next poll fails as well.
      if (status.error().code() == Errc::timeout) continue;
      counters.wkc_errors.fetch_add(1, std::memory_order_relaxed);
      if (++failed_polls < kFailedPollsForDown) continue;
      failed_polls = 0;
      if (now == SlaveState::init || now == SlaveState::bootstrap) {
        // No edge to DOWN from here, and nothing to rebuild (slave_fsm.hpp): a fault while the
        // slave does not answer.
        lost_in_place = true;
        raise_fault(fmt::format("lost while in {}: {}", to_string(now), status.error().message()));
        continue;
      }
      // The fault first: whoever sees the slave DOWN finds why.
      raise_fault(fmt::format("down: {}", status.error().message()));
      set_state(SlaveState::down);
      session.notify({SlaveNotice::Kind::down, self.name(), status.error().describe()});
      continue;
    }
    failed_polls = 0;
    if (lost_in_place) {
      lost_in_place = false;
      clear_fault();
    }
    const auto seen = slave_state_of(status->status.state);
    if (status->status.error) {
      std::lock_guard lock(mutex);
      al_code = status->code;
    }
    if (now == SlaveState::op && (seen != SlaveState::op || status->status.error)) {
      // Retreat to SAFEOP, acknowledging the error; the master decides when to go back to OP.
      auto retreat = co_await go_to(wire::AlState::safeop, keep);
      const auto why =
          fmt::format("left OP (AL status {}{}, code 0x{:04x} {})",
                      wire::to_string(status->status.state), status->status.error ? " + error" : "",
                      status->code, wire::al_status_code_text(status->code));
      raise_fault(why);
      if (!retreat) {
        set_state(SlaveState::down);
        session.notify(
            {SlaveNotice::Kind::down, self.name(), retreat.error().context(why).describe()});
      } else {
        session.notify({SlaveNotice::Kind::retreated, self.name(), why});
      }
      continue;
    }
    // Held in PREOP or SAFEOP: only a fall to a lower state counts.
    auto rank = [](SlaveState st) {
      switch (st) {
        case SlaveState::op:
          return 4;
        case SlaveState::safeop:
          return 3;
        case SlaveState::preop:
          return 2;
        default:
          return 1;
      }
    };
    if (rank(seen) < rank(now)) {
      set_state(seen);
      const auto why = fmt::format("fell from {} to {}", to_string(now), to_string(seen));
      raise_fault(why);
      session.notify({SlaveNotice::Kind::retreated, self.name(), why});
    }
  }
  health_running = false;
}

exec::Task<bool> Slave::Impl::probe_and_rebuild(std::shared_ptr<Session> keep) {
  auto& loop = session.loop;
  auto& bus = *session.bus;
  const auto station = self.station();
  const bus::TransactOptions quick{50ms, 0};
  bus::Transaction probe;
  probe.fprd(station, reg::kAlStatus, 2);
  auto by_station = co_await exec::transact(loop, bus, std::move(probe), quick);
  if (!by_station || by_station->wkc(0) == 0) {
    // Not at its station: a power-cycled slave has station 0. Look at its position (behind a
    // break of a redundant ring, through the secondary's frame: transact_by_position).
    bus::Transaction at_position;
    at_position.aprd(self.position(), reg::kStationAddress, 2);
    auto found = co_await transact_by_position(loop, bus, session.position_access,
                                               std::move(at_position), quick);
    if (!found || (*found)[0].wkc != 1) co_return false;
    const auto there = wire::load_le16((*found)[0].data.data());
    if (there != 0 && there != station) co_return false;  // another slave: keep waiting
    if (there == 0) {
      bus::Transaction assign;
      std::array<std::uint8_t, 2> value{};
      wire::store_le16(value.data(), station);
      assign.apwr(self.position(), reg::kStationAddress, value, 1);
      if (!co_await transact_by_position(loop, bus, session.position_access, std::move(assign),
                                         quick)) {
        co_return false;
      }
    }
  }
  // Rebuild to PREOP (the SII identity must be the one seen before).
  auto up = co_await bring_up(keep);
  if (up) up = co_await reinit_dc();
  if (!up) {
    // It answered, the rebuild failed: DOWN -> INIT, and the rebuild is retried from there.
    rebuild_pending = true;
    set_state(SlaveState::init);
    raise_fault(fmt::format("down; rebuild failed: {}", up.error().describe()));
    co_return false;
  }
  rebuild_pending = false;
  clear_fault();
  co_return true;
}

// ---- Slave: public, any thread ----------------------------------------------------------------

Slave::Slave(Session& session, SlaveConfig config, std::uint16_t position, std::uint16_t station)
    : name_(config.name),
      position_(position),
      station_(station),
      impl_(std::make_unique<Impl>(*this, session, std::move(config))) {}

Slave::~Slave() = default;

SlaveState Slave::state() const noexcept {
  return impl_->state();
}

TargetState Slave::target() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->config.target;
}

std::optional<std::uint16_t> Slave::error() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->al_code;
}

Result<wire::SiiIdentity> Slave::identity() const {
  std::lock_guard lock(impl_->mutex);
  if (!impl_->known_identity) {
    return Error(Errc::not_ready, fmt::format("{}: SII not read yet", impl_->who()));
  }
  return *impl_->known_identity;
}

Result<std::vector<std::uint8_t>> Slave::sii_image() const {
  std::lock_guard lock(impl_->mutex);
  if (!impl_->sii) return Error(Errc::not_ready, fmt::format("{}: SII not read yet", impl_->who()));
  return impl_->sii->bytes;
}

SlaveInfo Slave::info() const {
  std::lock_guard lock(impl_->mutex);
  SlaveInfo out;
  out.name = name_;
  out.position = position_;
  out.station = station_;
  out.state = impl_->state();
  out.target = impl_->config.target;
  out.al_status_code = impl_->al_code;
  out.identity = impl_->known_identity;
  if (impl_->sii) out.device_name = std::string(impl_->sii->decoded.image.device_name());
  out.esc = impl_->esc;
  // Written once at discovery, before any Slave exists.
  if (position_ < impl_->session.dl_status.size())
    out.dl_status = impl_->session.dl_status[position_];
  out.has_mailbox = impl_->mailbox != nullptr;
  out.coe = impl_->sii &&
            (impl_->sii->decoded.image.mailbox_protocols & wire::mailbox_protocol::kCoe) != 0;
  out.driver = impl_->driver ? std::string(impl_->driver->name()) : std::string();
  out.layout = impl_->layout;
  out.signals = impl_->signals;
  out.attachments = impl_->attachments;
  if (impl_->mailbox_status) {
    out.mailbox_status_domain = impl_->mailbox_status->domain;
    out.mailbox_status_fmmu = impl_->mailbox_status->fmmu;
  }
  out.configuration_error = impl_->configuration_error;
  out.fault = impl_->fault;
  out.startup_error = impl_->startup_error;
  out.device_state = impl_->device_state;
  out.dc_sync = impl_->dc_sync;
  return out;
}

Result<void> Slave::request(wire::AlState target, std::chrono::nanoseconds timeout) {
  auto keep = impl_->session.shared_from_this();
  return blocking(impl_->session, impl_->go_to(target, keep), timeout,
                  fmt::format("request {} of slave {}", wire::to_string(target), name_));
}

exec::Task<Result<void>> Slave::Impl::reconfigure(SlaveConfig next, std::shared_ptr<Session> keep) {
  if (state() != SlaveState::preop) {
    co_return Error(Errc::wrong_state, fmt::format("{}: configure needs PREOP, the slave is in {}",
                                                   who(), to_string(state())));
  }
  if (next.name != self.name()) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: configure got the configuration of \"{}\"", who(), next.name));
  }
  {
    std::lock_guard lock(mutex);
    config = std::move(next);
  }
  auto done = co_await configure_preop(keep);
  std::lock_guard lock(mutex);
  if (!done) {
    configuration_error = done.error().describe();
    configuration_failure = done.error();
    co_return done.error();
  }
  co_return ok();
}

exec::Task<Result<void>> Slave::Impl::retry_configuration(std::shared_ptr<Session> keep) {
  {
    std::lock_guard lock(mutex);
    if (!configuration_error) co_return ok();
  }
  if (state() != SlaveState::preop) {
    co_return Error(Errc::wrong_state, fmt::format("{}: retry needs PREOP, the slave is in {}",
                                                   who(), to_string(state())));
  }
  auto done = co_await configure_preop(keep);
  std::lock_guard lock(mutex);
  if (!done) {
    configuration_error = done.error().describe();
    configuration_failure = done.error();
    co_return done.error();
  }
  co_return ok();
}

Result<void> Slave::configure(SlaveConfig config, std::chrono::nanoseconds timeout) {
  auto keep = impl_->session.shared_from_this();
  return blocking(impl_->session, impl_->reconfigure(std::move(config), keep), timeout,
                  fmt::format("configure slave {}", name_));
}

Result<void> Slave::retry(std::chrono::nanoseconds timeout) {
  auto keep = impl_->session.shared_from_this();
  return blocking(impl_->session, impl_->retry_configuration(keep), timeout,
                  fmt::format("retry slave {}", name_));
}

Result<std::vector<std::uint8_t>> Slave::upload_sdo(std::uint16_t index, std::uint8_t subindex,
                                                    SdoOptions options) {
  auto keep = impl_->session.shared_from_this();
  const auto timeout = options.timeout * 2 + 1s;
  return blocking(impl_->session, impl_->sdo_upload(index, subindex, options, keep), timeout,
                  fmt::format("SDO upload 0x{:04x}:{:02x} of slave {}", index, subindex, name_));
}

Result<void> Slave::download_sdo(std::uint16_t index, std::uint8_t subindex,
                                 std::vector<std::uint8_t> data, SdoOptions options) {
  auto keep = impl_->session.shared_from_this();
  const auto timeout = options.timeout * 2 + 1s;
  return blocking(impl_->session,
                  impl_->sdo_download(index, subindex, std::move(data), options, keep), timeout,
                  fmt::format("SDO download 0x{:04x}:{:02x} of slave {}", index, subindex, name_));
}

Result<std::vector<std::uint16_t>> Slave::object_list(wire::OdListType type, SdoOptions options) {
  auto task = [](Impl& impl, wire::OdListType t, SdoOptions o,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<std::vector<std::uint16_t>>> {
    (void)keep;
    if (auto checked = impl.check_mailbox(); !checked) co_return checked.error();
    co_return co_await master::od_list(*impl.mailbox, t, o);
  };
  return blocking(impl_->session, task(*impl_, type, options, impl_->session.shared_from_this()),
                  options.timeout * 2 + 1s,
                  fmt::format("SDO information object list of slave {}", name_));
}

Result<wire::ObjectDescriptionResponse> Slave::describe_object(std::uint16_t index,
                                                               SdoOptions options) {
  auto task =
      [](Impl& impl, std::uint16_t i, SdoOptions o,
         std::shared_ptr<Session> keep) -> exec::Task<Result<wire::ObjectDescriptionResponse>> {
    (void)keep;
    if (auto checked = impl.check_mailbox(); !checked) co_return checked.error();
    co_return co_await master::object_description(*impl.mailbox, i, o);
  };
  return blocking(impl_->session, task(*impl_, index, options, impl_->session.shared_from_this()),
                  options.timeout * 2 + 1s,
                  fmt::format("SDO information of object 0x{:04x} of slave {}", index, name_));
}

Result<wire::EntryDescriptionResponse> Slave::describe_entry(std::uint16_t index,
                                                             std::uint8_t subindex,
                                                             std::uint8_t value_info,
                                                             SdoOptions options) {
  auto task =
      [](Impl& impl, std::uint16_t i, std::uint8_t sub, std::uint8_t info, SdoOptions o,
         std::shared_ptr<Session> keep) -> exec::Task<Result<wire::EntryDescriptionResponse>> {
    (void)keep;
    if (auto checked = impl.check_mailbox(); !checked) co_return checked.error();
    co_return co_await master::entry_description(*impl.mailbox, i, sub, info, o);
  };
  return blocking(
      impl_->session,
      task(*impl_, index, subindex, value_info, options, impl_->session.shared_from_this()),
      options.timeout * 2 + 1s,
      fmt::format("SDO information of entry 0x{:04x}:{:02x} of slave {}", index, subindex, name_));
}

Result<std::vector<wire::Emergency>> Slave::emergencies(std::chrono::nanoseconds timeout) {
  auto task =
      [](Impl& impl,
         std::shared_ptr<Session> keep) -> exec::Task<Result<std::vector<wire::Emergency>>> {
    (void)keep;
    if (!impl.mailbox) co_return std::vector<wire::Emergency>{};
    if (impl.check_mailbox()) (void)co_await impl.mailbox->poll();
    co_return impl.mailbox->emergencies();
  };
  return blocking(impl_->session, task(*impl_, impl_->session.shared_from_this()), timeout,
                  fmt::format("emergencies of slave {}", name_));
}

std::vector<Signal> Slave::signals() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->signals;
}

Result<Value> Slave::read_input(std::string_view name) const {
  // The published view, without `mutex` (Impl::HotPath): nullptr before the first configuration.
  const Impl::HotPath* view = impl_->hot.load(std::memory_order_acquire);
  for (;;) {
    const std::ptrdiff_t k = view != nullptr ? view->find_index(name) : -1;
    if (k < 0) {
      return Error(Errc::not_found, fmt::format("slave {} has no signal \"{}\"", name_, name));
    }
    // A routed input of a scalar field: only its own bits, from one cycle, with the domain's
    // freshness checks (Domain::read_fresh of the field the view keeps).
    const Impl::HotPath::Slot& slot = view->slots[static_cast<std::size_t>(k)];
    if (slot.path != Impl::HotPath::Path::input_field) break;
    auto raw = slot.input.domain->read_fresh(slot.input.field);
    // The bits were read under this view only if it is still the published one (the read's
    // seqlock ends with an acquire fence); else reconfigured meanwhile: read again.
    const Impl::HotPath* now = impl_->hot.load(std::memory_order_acquire);
    if (now != view) [[unlikely]] {
      view = now;
      continue;
    }
    if (!raw) [[unlikely]] {
      return raw.error().context(fmt::format("input \"{}\" of slave {}", name, name_));
    }
    return decode_field(view->signals[static_cast<std::size_t>(k)], *raw);
  }
  // The rest (an output's staged value, a wide or unrouted input) under `mutex`, as configured.
  std::lock_guard lock(impl_->mutex);
  const Signal* sig = impl_->find_signal(name);  // again: the configuration may have changed it
  if (!sig) {
    return Error(Errc::not_found, fmt::format("slave {} has no signal \"{}\"", name_, name));
  }
  const SmAttachment* a = impl_->attachment_for(sig->sync_manager);
  if (!a) {
    return Error(Errc::not_found,
                 fmt::format("signal \"{}\" of slave {} is not routed to a domain", name, name_));
  }
  if (sig->direction == PdoDirection::output) {
    const Impl::OutputLock images(*impl_);
    auto it = impl_->output_images.find(sig->sync_manager);
    if (it == impl_->output_images.end()) {
      return Error(Errc::not_ready,
                   fmt::format("output \"{}\" of slave {} not staged", name, name_));
    }
    return decode_scaled(*sig, it->second);
  }
  const Impl::Route* route =
      impl_->hot.load(std::memory_order_relaxed)->route_for(sig->sync_manager);
  std::array<std::uint8_t, 512> small;  // not zeroed: read_fresh fills what is used
  std::vector<std::uint8_t> large;
  wire::MutableBytes buffer(small.data(), small.size());
  if (a->size > small.size()) {
    large.resize(a->size);
    buffer = wire::MutableBytes(large.data(), large.size());
  }
  auto got = route ? route->domain->read_fresh(route->handle, buffer)
                   : impl_->session.find_domain(a->domain)->read_fresh(
                         PdoKey{station_, sig->sync_manager}, buffer);
  if (!got) {
    return got.error().context(fmt::format("input \"{}\" of slave {}", name, name_));
  }
  return decode_scaled(*sig, buffer.first(*got));
}

Result<void> Slave::write_output(std::string_view name, const Value& value) {
  const Impl::HotPath* view = impl_->hot.load(std::memory_order_acquire);
  const std::ptrdiff_t k = view != nullptr ? view->find_index(name) : -1;
  if (k < 0) {
    return Error(Errc::not_found, fmt::format("slave {} has no signal \"{}\"", name_, name));
  }
  const Signal& sig = view->signals[static_cast<std::size_t>(k)];
  if (sig.direction != PdoDirection::output) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal \"{}\" of slave {} is an input", name, name_));
  }
  const Impl::HotPath::Slot& slot = view->slots[static_cast<std::size_t>(k)];
  if (slot.path == Impl::HotPath::Path::output_field) {
    // A scalar field, without `mutex`: encoded once into its raw bits and staged as those bits
    // only (under each domain's staging lock, so a multi-byte value leaves whole in one cycle);
    // the retained image takes them when every domain did. Under the output lock throughout, so
    // concurrent writers leave the domains and the retained image with the same value.
    auto raw = encode_field(sig, value);
    if (!raw) [[unlikely]] {
      return raw.error().context(fmt::format("output \"{}\" of slave {}", name, name_));
    }
    const Impl::OutputLock images(*impl_);
    // The configuration changes the images and the view together under this lock: a view that
    // is no longer the published one was reconfigured meanwhile (the `mutex` path below).
    if (impl_->hot.load(std::memory_order_relaxed) == view && slot.image->size() == slot.image_size)
        [[likely]] {
      for (std::uint32_t t = slot.first; t < slot.first + slot.count; ++t) {
        const Impl::HotPath::Target& target = view->targets[t];
        if (auto w = target.domain->write_bits(target.field, *raw); !w) [[unlikely]] {
          return w.error().context(fmt::format("staging \"{}\" of slave {} in domain \"{}\"", name,
                                               name_, target.domain->id()));
        }
      }
      return store_field(sig, *raw, *slot.image);
    }
  }
  // The rest (a wide value, a field outside its image, an unrouted attachment) under `mutex`.
  std::lock_guard lock(impl_->mutex);
  view = impl_->hot.load(std::memory_order_relaxed);
  // Again: the configuration may have changed it meanwhile.
  const Signal* current = view != nullptr ? view->find(name) : nullptr;
  if (!current) {
    return Error(Errc::not_found, fmt::format("slave {} has no signal \"{}\"", name_, name));
  }
  if (current->direction != PdoDirection::output) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal \"{}\" of slave {} is an input", name, name_));
  }
  const Impl::OutputLock images(*impl_);
  auto it = impl_->output_images.find(current->sync_manager);
  if (it == impl_->output_images.end()) {
    return Error(Errc::not_found,
                 fmt::format("signal \"{}\" of slave {} is not routed to a domain", name, name_));
  }
  // Encoded into a scratch image kept between calls (its capacity stays), so a write does not
  // allocate; it replaces the retained image only when every domain took it.
  auto& staged = impl_->write_scratch;
  staged.assign(it->second.begin(), it->second.end());
  if (auto encoded = encode_scaled(*current, value, staged); !encoded) {
    return encoded.error().context(fmt::format("output \"{}\" of slave {}", name, name_));
  }
  if (view->all_routed) {
    for (const auto& r : view->routes) {
      if (r.sync_manager != current->sync_manager) continue;
      if (auto w = r.domain->write(r.handle, staged); !w) {
        return w.error().context(fmt::format("staging \"{}\" of slave {} in domain \"{}\"", name,
                                             name_, r.domain->id()));
      }
    }
  } else {
    for (const auto& a : impl_->attachments) {
      if (a.sync_manager != current->sync_manager) continue;
      Domain* domain = impl_->session.find_domain(a.domain);
      if (auto w = domain->write(PdoKey{station_, a.sync_manager}, staged); !w) {
        return w.error().context(
            fmt::format("staging \"{}\" of slave {} in domain \"{}\"", name, name_, a.domain));
      }
    }
  }
  it->second.swap(staged);
  return ok();
}

Result<void> Slave::command(std::string_view name, const CommandArgs& args) {
  std::vector<OutputWrite> writes;
  {
    std::lock_guard lock(impl_->mutex);
    if (!impl_->driver) {
      return Error(Errc::not_ready, fmt::format("slave {} is not configured yet", name_));
    }
    // The driver sees the staged outputs (what a command changes); inputs are not needed.
    const auto values = impl_->signal_values({});
    SignalValues current(impl_->signals, values);
    auto made =
        impl_->driver->command(name, args, current, impl_->device_state, impl_->driver_state.get());
    if (!made) return made.error().context(fmt::format("command {} of slave {}", name, name_));
    writes = std::move(*made);
  }
  for (const auto& w : writes) {
    if (auto r = write_output(w.signal, w.value); !r) return r;
  }
  return ok();
}

Result<SubscriptionId> Slave::subscribe(std::string_view signal,
                                        std::function<void(const SignalEvent&)> callback) {
  std::lock_guard lock(impl_->mutex);
  if (!impl_->find_signal(signal) && !impl_->find_latch(signal)) {
    return Error(
        Errc::not_found,
        fmt::format("slave {} has no signal or latch \"{}\" to subscribe to", name_, signal));
  }
  const SubscriptionId id = ++impl_->next_subscription;
  impl_->subscriptions.push_back({id, std::string(signal), std::move(callback), std::nullopt});
  return id;
}

void Slave::unsubscribe(SubscriptionId id) {
  std::lock_guard lock(impl_->mutex);
  std::erase_if(impl_->subscriptions, [id](const auto& s) { return s.id == id; });
}

}  // namespace ecat::master
