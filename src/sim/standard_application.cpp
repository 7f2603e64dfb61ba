#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::sim {

namespace reg = wire::reg;
namespace al = wire::al_status;
using wire::AlState;

namespace {

// Order of the states for "a step down": BOOT sits beside PREOP (it only leads back to INIT).
int rank(AlState state) noexcept {
  switch (state) {
    case AlState::init:
      return 1;
    case AlState::preop:
    case AlState::bootstrap:
      return 2;
    case AlState::safeop:
      return 3;
    case AlState::op:
      return 4;
  }
  return 0;
}

bool is_output(PdoDirection direction) noexcept {
  return direction == PdoDirection::rx;
}

// Process-data watchdog time from the ESC registers (0x0400 divider, 0x0420 ticks), as the ESC
// itself computes it; 0 when disabled.
std::int64_t watchdog_time_ns(const Esc& esc) noexcept {
  return esc.process_data_watchdog().time().count();
}

}  // namespace

std::vector<ProcessDataSyncManager> process_data_sync_managers(const wire::SiiImage& sii) {
  std::vector<ProcessDataSyncManager> out;
  for (std::size_t i = 0; i < sii.sync_managers.size() && i < reg::kMaxSyncManagers; ++i) {
    const auto& sm = sii.sync_managers[i];
    if (!sm.enabled() || sm.virtual_sm()) continue;
    if (sm.type == wire::sii_sm_type::kOutputs) {
      out.push_back({static_cast<std::uint8_t>(i), PdoDirection::rx, sm.start});
    } else if (sm.type == wire::sii_sm_type::kInputs) {
      out.push_back({static_cast<std::uint8_t>(i), PdoDirection::tx, sm.start});
    }
  }
  return out;
}

StandardApplication::StandardApplication(StandardConfig config)
    : config_(std::move(config)), pd_sms_(process_data_sync_managers(config_.sii)) {
  od_ = config_.dictionary;
  if (config_.sii.standard_mailbox.present()) {
    coe_ = std::make_unique<CoeServer>(od_, config_.coe);
    if ((config_.sii.mailbox_protocols & wire::mailbox_protocol::kFoe) != 0) {
      foe_ = std::make_unique<FoeServer>(od_, config_.foe);
      coe_->set_protocol_handler(wire::MailboxType::foe,
                                 [this](Esc& esc, const wire::MailboxHeader&, wire::Bytes data) {
                                   return foe_->handle(esc, data);
                                 });
    }
  }
  if (coe_ && (config_.sii.mailbox_protocols & wire::mailbox_protocol::kSoe) != 0) {
    soe_ = std::make_unique<SoeServer>(*coe_, config_.soe);
    coe_->set_protocol_handler(
        wire::MailboxType::soe,
        [this](Esc& esc, const wire::MailboxHeader& header, wire::Bytes data) {
          return soe_->handle(esc, header, data);
        });
  }
  if (coe_ && (config_.sii.mailbox_protocols & wire::mailbox_protocol::kEoe) != 0) {
    eoe_ = std::make_unique<EoeServer>(*coe_, config_.eoe);
    coe_->set_protocol_handler(
        wire::MailboxType::eoe,
        [this](Esc& esc, const wire::MailboxHeader& header, wire::Bytes data) {
          return eoe_->handle(esc, header, data);
        });
  }
}

AlState StandardApplication::al_state() const noexcept {
  return state_;
}

void StandardApplication::restore_dictionary() {
  od_ = config_.dictionary;
  od_.set_change_listener(
      [this](std::uint16_t index, std::uint8_t subindex) { object_written(index, subindex); });
}

void StandardApplication::start(Esc& esc) {
  esc_ = &esc;
  restore_dictionary();
  if (foe_) foe_->on_power_up();
  if (coe_) {
    coe_->reset();
    coe_->clear_faults();
  }
  if (soe_) {
    soe_->power_up();
    soe_->clear_faults();
  }
  if (eoe_) {
    eoe_->power_up();
    eoe_->clear_faults();
  }
  layouts_.clear();
  resolved_.clear();
  valid_outputs_.clear();
  forced_.clear();
  outputs_received_ = 0;
  op_entered_ns_ = 0;
  state_ = AlState::init;
  watchdog_handled_ = false;
  reset_model();
  if (auto* dc = esc.dc()) {
    dc->set_sync_handler([this, &esc](const SyncPulse& pulse) { on_sync(esc, pulse); });
  }
  esc.pdi_set_al_status(AlState::init, false, 0);
}

// ---------------------------------------------------------------------------------------------
// The AL state machine (ETG.1000.6, "AL state machine"): every write of AL control passes here.
//
//   INIT ⇄ PREOP ⇄ SAFEOP ⇄ OP      INIT ⇄ BOOT      any state → INIT     OP → PREOP
//
//   ->PREOP   (from INIT)   mailbox SyncManagers match the SII standard mailbox     else 0x0016
//   ->BOOT    (from INIT)   the device has a bootstrap mailbox                      else 0x0013
//                           mailbox SyncManagers match it                           else 0x0015
//   ->SAFEOP  (from PREOP)  the PDO layout is valid                          else 0x0024 / 0x0025
//                           process-data SyncManagers match it               else 0x001E / 0x001D
//                           the DC synchronisation the device needs          else 0x0030 / 0x0035
//   ->OP      (from SAFEOP) valid outputs (only with require_valid_outputs)  else 0x001B / 0x0019
//   then the device model's own check (check_transition).
// A refusal keeps the state and sets the error indicator with the code. An unknown state code is
// 0x0012, a transition the diagram does not have 0x0011.

StandardApplication::AlOutcome StandardApplication::al_transition(Esc& esc, std::uint16_t control) {
  const AlState current = esc.al_state();
  bool error = esc.al_error();
  std::uint16_t code = esc.al_status_code();
  if (error && (control & wire::kAlControlErrorAcknowledge) != 0) {
    error = false;
    code = al::kNoError;
  }
  const auto requested = wire::al_state_from_code(static_cast<std::uint8_t>(control & 0x0F));
  if (!requested) return {current, true, al::kUnknownRequestedState};
  const AlState to = *requested;

  if (error) {
    // Unacknowledged: a step down is taken and the error stays; anything else waits for the ack.
    if (rank(to) < rank(current) && al_transition_allowed(current, to)) return {to, true, code};
    return {current, true, code};
  }
  if (to == current) return {current, false, al::kNoError};
  if (to == AlState::bootstrap && !config_.sii.bootstrap_mailbox.present()) {
    return {current, true, al::kBootstrapNotSupported};
  }
  if (!al_transition_allowed(current, to)) {
    return {current, true, al::kInvalidRequestedStateChange};
  }

  std::uint16_t refusal = al::kNoError;
  switch (to) {
    case AlState::init:
      break;
    case AlState::preop:
      if (current == AlState::init) {
        refusal =
            check_mailbox(esc, config_.sii.standard_mailbox, al::kInvalidMailboxConfigurationPreop);
      }
      break;
    case AlState::bootstrap:
      refusal = check_mailbox(esc, config_.sii.bootstrap_mailbox,
                              al::kInvalidMailboxConfigurationBootstrap);
      break;
    case AlState::safeop:
      if (current == AlState::preop) {
        refusal = check_process_data(esc);
        if (refusal == al::kNoError) refusal = check_dc(esc);
      }
      break;
    case AlState::op:
      refusal = check_valid_outputs(esc);
      break;
  }
  if (refusal == al::kNoError) refusal = check_transition(current, to);
  if (refusal != al::kNoError) return {current, true, refusal};
  return {to, false, al::kNoError};
}

void StandardApplication::on_al_control(Esc& esc, std::uint16_t control) {
  esc_ = &esc;
  if (device_emulation(esc)) {
    // The ESC itself mirrored AL control into AL status (ESC configuration bit 0, as simple
    // terminals without a microcontroller are set up): nothing is checked or refused, the
    // firmware only follows.
    if (auto requested = wire::al_state_from_code(static_cast<std::uint8_t>(control & 0x0F))) {
      enter(esc, *requested);
    }
    return;
  }
  catch_up(esc);
  const AlOutcome outcome = al_transition(esc, control);
  enter(esc, outcome.state);
  esc.pdi_set_al_status(outcome.state, outcome.error, outcome.code);
  if ((control & wire::kAlControlIdRequest) != 0 && !outcome.error) {
    // Explicit device identification: the ID (the SII station alias) in the AL status code.
    esc.pdi_write_u16(reg::kAlStatus, static_cast<std::uint16_t>(esc.read_u16(reg::kAlStatus) |
                                                                 wire::kAlStatusIdLoaded));
    esc.pdi_write_u16(reg::kAlStatusCode, config_.sii.station_alias);
  }
}

bool StandardApplication::device_emulation(const Esc& esc) const noexcept {
  return (esc.read_u8(reg::kEscConfiguration) & 0x01) != 0;
}

void StandardApplication::catch_up(Esc& esc) {
  // Someone else (fault injection, a test) set the AL status through the PDI.
  if (esc.al_state() != state_) enter(esc, esc.al_state());
}

// The side effects of entering and leaving states, kept apart from the decisions above.
void StandardApplication::enter(Esc& esc, AlState to) {
  const AlState from = state_;
  if (from == to) return;
  if (from == AlState::op) apply_safe_outputs();
  if (rank(to) < rank(AlState::safeop)) {
    layouts_.clear();
    resolved_.clear();
  }
  if (rank(to) >= rank(AlState::safeop) && rank(from) < rank(AlState::safeop)) {
    // The PDO layout is fixed from SAFEOP on: take it as the dictionary says now.
    layouts_.clear();
    resolved_.clear();
    for (const auto& pd : pd_sms_) {
      if (auto l = process_data_layout(od_, pd.index)) layouts_[pd.index] = std::move(*l);
    }
    valid_outputs_.clear();
    outputs_received_ = 0;
  }
  if (to == AlState::init && coe_) coe_->reset();
  if (to == AlState::op) {
    op_entered_ns_ = esc.now_ns();
    watchdog_handled_ = false;
  }
  state_ = to;
  if (foe_) foe_->on_state_changed(from, to);
  on_state_changed(from, to);
}

void StandardApplication::raise_al_error(Esc& esc, std::uint16_t code, AlState state) {
  esc_ = &esc;
  catch_up(esc);
  const AlState current = esc.al_state();
  const AlState to = rank(state) < rank(current) ? state : current;
  enter(esc, to);
  esc.pdi_set_al_status(to, true, code);
}

std::uint16_t StandardApplication::check_mailbox(const Esc& esc, const wire::SiiMailbox& mailbox,
                                                 std::uint16_t code) const {
  if (!mailbox.present()) return al::kNoError;
  struct Expected {
    std::size_t sm;
    std::uint16_t start;
    std::uint16_t length;
    wire::SmDirection direction;
  };
  const Expected expected[] = {
      {0, mailbox.recv_offset, mailbox.recv_size, wire::SmDirection::write},
      {1, mailbox.send_offset, mailbox.send_size, wire::SmDirection::read},
  };
  for (const auto& e : expected) {
    if (e.sm >= esc.hardware().sync_manager_count) return code;
    const auto& sm = esc.sync_manager(e.sm);
    if (!sm.enabled || sm.config.physical_start != e.start || sm.config.length != e.length ||
        sm.config.control.mode != wire::SmMode::mailbox ||
        sm.config.control.direction != e.direction) {
      return code;
    }
  }
  return al::kNoError;
}

std::uint16_t StandardApplication::check_process_data(const Esc& esc) const {
  for (const auto& pd : pd_sms_) {
    const bool output = is_output(pd.direction);
    auto l = process_data_layout(od_, pd.index);
    if (!l) return output ? al::kInvalidOutputMapping : al::kInvalidInputMapping;
    if (l->byte_length == 0) continue;  // nothing assigned: the SyncManager stays unused
    const std::uint16_t refusal =
        output ? al::kInvalidOutputConfiguration : al::kInvalidInputConfiguration;
    if (pd.index >= esc.hardware().sync_manager_count) return refusal;
    const auto& sm = esc.sync_manager(pd.index);
    const auto direction = output ? wire::SmDirection::write : wire::SmDirection::read;
    if (!sm.enabled || sm.config.physical_start != pd.start || sm.config.length != l->byte_length ||
        sm.config.control.mode != wire::SmMode::buffered ||
        sm.config.control.direction != direction) {
      return refusal;
    }
    if (config_.check_fmmus) {
      bool mapped = false;
      for (std::size_t i = 0; i < esc.hardware().fmmu_count && !mapped; ++i) {
        const auto& f = esc.fmmu(i);
        const bool type_ok = f.type == wire::FmmuType::read_write ||
                             f.type == (output ? wire::FmmuType::write : wire::FmmuType::read);
        mapped = f.active && type_ok && f.physical_start >= pd.start &&
                 f.physical_start < pd.start + l->byte_length;
      }
      if (!mapped) return refusal;
    }
  }
  return al::kNoError;
}

std::uint16_t StandardApplication::check_dc(const Esc& esc) const {
  const std::uint8_t activation = esc.read_u8(reg::kDcActivation);
  const std::uint8_t sync0 = wire::dc_activation::kCyclicOperation | wire::dc_activation::kSync0;
  const bool sync0_active = (activation & sync0) == sync0;
  const auto sync_type = od_.get<std::uint16_t>(0x1C32, 1);
  const bool needed = config_.dc.required || (sync_type && (*sync_type == 2 || *sync_type == 3));
  if (needed && !sync0_active) return al::kInvalidDcSyncConfiguration;
  if (sync_type && *sync_type == 3 && (activation & wire::dc_activation::kSync1) == 0) {
    return al::kInvalidDcSyncConfiguration;
  }
  if (!sync0_active) return al::kNoError;
  if (!config_.dc.supported) return al::kInvalidDcSyncConfiguration;
  const std::uint32_t cycle = esc.read_u32(reg::kDcSync0CycleTime);
  if (cycle == 0 || (config_.dc.min_cycle_ns != 0 && cycle < config_.dc.min_cycle_ns) ||
      (config_.dc.max_cycle_ns != 0 && cycle > config_.dc.max_cycle_ns)) {
    return al::kDcInvalidSyncCycleTime;
  }
  return al::kNoError;
}

bool StandardApplication::watchdog_expired(const Esc& esc) const {
  bool watched = false;
  for (const auto& pd : pd_sms_) {
    if (!is_output(pd.direction) || pd.index >= esc.hardware().sync_manager_count) continue;
    auto it = layouts_.find(pd.index);
    if (it == layouts_.end() || it->second.byte_length == 0) continue;
    const auto& sm = esc.sync_manager(pd.index);
    watched = watched || (sm.enabled && sm.config.control.watchdog);
  }
  return watched && watchdog_time_ns(esc) > 0 && (esc.read_u16(reg::kWatchdogStatus) & 0x0001) == 0;
}

std::uint16_t StandardApplication::check_valid_outputs(const Esc& esc) const {
  if (!config_.require_valid_outputs) return al::kNoError;
  if (watchdog_expired(esc)) return al::kSyncManagerWatchdog;
  for (const auto& [sm, layout] : layouts_) {
    const auto* pd = find_pd(sm);
    if (pd == nullptr || !is_output(pd->direction) || layout.byte_length == 0) continue;
    auto it = valid_outputs_.find(sm);
    if (it == valid_outputs_.end() || !it->second) return al::kNoValidOutputs;
  }
  return al::kNoError;
}

// ---------------------------------------------------------------------------------------------
// Mailbox and process data

const ProcessDataSyncManager* StandardApplication::find_pd(std::size_t sm) const noexcept {
  for (const auto& pd : pd_sms_) {
    if (pd.index == sm) return &pd;
  }
  return nullptr;
}

void StandardApplication::on_buffer_written(Esc& esc, std::size_t sm) {
  esc_ = &esc;
  if (coe_ && sm == coe_->config().request_sm) {
    coe_->on_buffer_written(esc, sm);
    return;
  }
  const auto* pd = find_pd(sm);
  if (pd != nullptr && is_output(pd->direction)) take_outputs(esc, sm);
}

void StandardApplication::take_outputs(Esc& esc, std::size_t sm) {
  const AlState state = state_;
  if (state != AlState::safeop && state != AlState::op) return;
  auto it = layouts_.find(static_cast<std::uint8_t>(sm));
  if (it == layouts_.end()) return;
  valid_outputs_[static_cast<std::uint8_t>(sm)] = true;
  ++outputs_received_;
  // SAFEOP: the outputs stay in their safe state; only OP applies them.
  if (state != AlState::op) return;
  auto changed =
      unpack_outputs(it->second, resolved(it->first, it->second), esc.pdi_read_buffer(sm));
  outputs_changed(changed);
}

void StandardApplication::on_buffer_read(Esc& esc, std::size_t sm) {
  esc_ = &esc;
  if (coe_ && sm == coe_->config().reply_sm) coe_->on_buffer_read(esc, sm);
}

void StandardApplication::before_buffer_read(Esc& esc, std::size_t sm) {
  esc_ = &esc;
  // A DC-synchronous device latched its inputs at the last SYNC0 pulse.
  if (const auto* dc = esc.dc(); dc != nullptr && dc->sync_state() == SyncUnitState::running) {
    return;
  }
  publish_inputs(esc, sm);
}

void StandardApplication::on_sync(Esc& esc, const SyncPulse& pulse) {
  if (pulse.signal != SyncSignal::sync0) return;
  for (const auto& pd : pd_sms_) {
    if (!is_output(pd.direction)) publish_inputs(esc, pd.index);
  }
}

void StandardApplication::publish_inputs(Esc& esc, std::size_t sm) {
  const AlState state = state_;
  if (state != AlState::safeop && state != AlState::op) return;
  const auto* pd = find_pd(sm);
  if (pd == nullptr || is_output(pd->direction)) return;
  auto it = layouts_.find(static_cast<std::uint8_t>(sm));
  if (it == layouts_.end() || it->second.byte_length == 0) return;
  update_inputs(esc.now_ns());
  if (!forced_.empty()) {
    for (const auto& b : bindings_) {
      if (!b.entry || b.info.direction != SignalDirection::input) continue;
      if (auto f = forced(b.info.name)) {
        set_entry_number(od_, b.index, b.subindex, (*f - b.offset) / b.scale);
      }
    }
  }
  image_.assign(it->second.byte_length, 0);
  pack_inputs(od_, it->second, resolved(it->first, it->second), image_, true);
  esc.pdi_write_buffer(sm, image_);
}

std::span<ObjectEntry* const> StandardApplication::resolved(std::uint8_t sm,
                                                            const SyncManagerLayout& layout) {
  ResolvedEntries& r = resolved_[sm];
  if (r.generation != od_.generation() || r.entries.size() != layout.entries.size()) {
    r.entries = resolve_entries(od_, layout);
    r.generation = od_.generation();
  }
  return r.entries;
}

void StandardApplication::on_mailbox_repeat(Esc& esc, std::size_t sm) {
  esc_ = &esc;
  if (coe_) coe_->on_mailbox_repeat(esc, sm);
}

void StandardApplication::on_sync_manager_changed(Esc& esc, std::size_t sm) {
  esc_ = &esc;
  if (coe_ && (sm == coe_->config().request_sm || sm == coe_->config().reply_sm)) {
    coe_->on_sync_manager_changed(esc, sm);
  }
  // A process-data SyncManager changed under a running device: real firmware notices the SM
  // change event and leaves SAFEOP/OP with the configuration error.
  if (device_emulation(esc)) return;
  catch_up(esc);
  if ((state_ == AlState::safeop || state_ == AlState::op) && find_pd(sm) != nullptr &&
      !esc.al_error()) {
    if (const std::uint16_t refusal = check_process_data(esc); refusal != al::kNoError) {
      raise_al_error(esc, refusal, AlState::preop);
    }
  }
}

void StandardApplication::advance(Esc& esc, std::int64_t now_ns) {
  esc_ = &esc;
  const bool emulation = device_emulation(esc);
  if (!emulation) catch_up(esc);
  if (state_ == AlState::op && watchdog_expired(esc) &&
      now_ns - op_entered_ns_ >= watchdog_time_ns(esc)) {
    if (!emulation) {
      raise_al_error(esc, al::kSyncManagerWatchdog, AlState::safeop);
    } else if (!watchdog_handled_) {
      // Without firmware the ESC cannot change the AL state; its outputs go to their safe
      // state until the master writes again.
      apply_safe_outputs();
      watchdog_handled_ = true;
    }
  }
  if (emulation && watchdog_handled_ && !watchdog_expired(esc)) watchdog_handled_ = false;
  if (coe_) coe_->advance(esc);
  update(now_ns);
}

bool StandardApplication::wants_advance(const Esc& esc, std::int64_t now_ns) const {
  (void)now_ns;
  if (esc.al_state() != state_ || watchdog_handled_) return true;
  return state_ == AlState::op && (esc.read_u16(reg::kWatchdogStatus) & 0x0001) == 0 &&
         watchdog_expired(esc);
}

void StandardApplication::apply_safe_outputs() {
  for (const auto& [sm, layout] : layouts_) {
    const auto* pd = find_pd(sm);
    if (pd == nullptr || !is_output(pd->direction)) continue;
    for (const auto& m : layout.entries) {
      if (m.gap) continue;
      ObjectEntry* e = od_.find(m.index, m.subindex);
      if (e == nullptr) continue;
      std::vector<std::uint8_t> safe = e->default_value;
      safe.resize(e->value.size(), 0);
      e->value = std::move(safe);
    }
  }
}

void StandardApplication::emergency(Esc& esc, std::uint16_t error_code, std::uint8_t error_register,
                                    std::array<std::uint8_t, 5> data) {
  od_.set<std::uint8_t>(0x1001, 0, error_register);
  if (!coe_) return;
  wire::Emergency e;
  e.error_code = error_code;
  e.error_register = error_register;
  e.data = data;
  coe_->queue_emergency(esc, e);
}

// ---------------------------------------------------------------------------------------------
// Signals

void StandardApplication::add_entry_signal(SignalInfo info, std::uint16_t index,
                                           std::uint8_t subindex, double scale, double offset) {
  Binding b;
  b.info = std::move(info);
  b.entry = true;
  b.index = index;
  b.subindex = subindex;
  b.scale = scale == 0.0 ? 1.0 : scale;
  b.offset = offset;
  bindings_.push_back(std::move(b));
}

void StandardApplication::add_model_signal(SignalInfo info, std::function<double()> read) {
  Binding b;
  b.info = std::move(info);
  b.read = std::move(read);
  bindings_.push_back(std::move(b));
}

const StandardApplication::Binding* StandardApplication::find_binding(
    std::string_view name) const noexcept {
  for (const auto& b : bindings_) {
    if (b.info.name == name) return &b;
  }
  return nullptr;
}

std::optional<double> StandardApplication::forced(std::string_view name) const {
  auto it = forced_.find(name);
  if (it == forced_.end()) return std::nullopt;
  return it->second;
}

std::vector<SignalInfo> StandardApplication::signals() const {
  std::vector<SignalInfo> out;
  out.reserve(bindings_.size());
  for (const auto& b : bindings_)
    out.push_back(b.info);
  return out;
}

std::optional<double> StandardApplication::signal(std::string_view name) const {
  const Binding* b = find_binding(name);
  if (b == nullptr) return std::nullopt;
  if (b->info.direction == SignalDirection::input) {
    if (auto f = forced(name)) return f;
  }
  if (!b->entry) return b->read ? std::optional<double>(b->read()) : std::nullopt;
  auto raw = entry_number(od_, b->index, b->subindex);
  if (!raw) return std::nullopt;
  return *raw * b->scale + b->offset;
}

bool StandardApplication::set_input(std::string_view name, double value) {
  const Binding* b = find_binding(name);
  if (b == nullptr || b->info.direction != SignalDirection::input) return false;
  forced_.insert_or_assign(std::string(name), value);
  if (b->entry) set_entry_number(od_, b->index, b->subindex, (value - b->offset) / b->scale);
  return true;
}

void StandardApplication::clear_input(std::string_view name) {
  auto it = forced_.find(name);
  if (it != forced_.end()) forced_.erase(it);
}

// ---------------------------------------------------------------------------------------------
// Entry values as numbers

std::optional<double> entry_number(const ObjectDictionary& od, std::uint16_t index,
                                   std::uint8_t subindex) {
  const ObjectEntry* e = od.find(index, subindex);
  if (e == nullptr || is_variable_length(e->data_type) || e->value.empty() || e->value.size() > 8) {
    return std::nullopt;
  }
  if (e->data_type == DataType::real32) {
    auto v = from_le_bytes<float>(e->value);
    return v ? std::optional<double>(*v) : std::nullopt;
  }
  if (e->data_type == DataType::real64) return from_le_bytes<double>(e->value);
  if (is_signed_integer(e->data_type)) {
    // Sign-extend from the entry's own bit length (an INTEGER16 mapped as 12 bits stays signed).
    std::uint64_t raw = from_le_bytes<std::uint64_t>(e->value).value_or(0);
    const unsigned bits = std::min<unsigned>(e->bit_length, 64);
    if (bits < 64) {
      raw &= (std::uint64_t{1} << bits) - 1;
      if (bits > 0 && ((raw >> (bits - 1)) & 1u) != 0) raw |= ~std::uint64_t{0} << bits;
    }
    return static_cast<double>(static_cast<std::int64_t>(raw));
  }
  std::uint64_t raw = from_le_bytes<std::uint64_t>(e->value).value_or(0);
  if (e->bit_length < 64) raw &= (std::uint64_t{1} << e->bit_length) - 1;
  return static_cast<double>(raw);
}

bool set_entry_number(ObjectDictionary& od, std::uint16_t index, std::uint8_t subindex,
                      double value) {
  const ObjectEntry* e = od.find(index, subindex);
  if (e == nullptr || is_variable_length(e->data_type) || e->byte_length() == 0 ||
      e->byte_length() > 8 || std::isnan(value)) {
    return false;
  }
  const std::size_t n = e->byte_length();
  if (e->data_type == DataType::real32) {
    return od.set_value(index, subindex, to_le_bytes(static_cast<float>(value)));
  }
  if (e->data_type == DataType::real64) return od.set_value(index, subindex, to_le_bytes(value));
  const unsigned bits = std::min<unsigned>(e->bit_length, 64);
  const double rounded = std::round(value);
  if (is_signed_integer(e->data_type)) {
    const double hi = std::ldexp(1.0, static_cast<int>(bits) - 1) - 1;
    const double lo = -std::ldexp(1.0, static_cast<int>(bits) - 1);
    const auto v = static_cast<std::int64_t>(std::clamp(rounded, lo, hi));
    auto bytes = to_le_bytes(v, n);
    return od.set_value(index, subindex, bytes);
  }
  const double hi =
      bits >= 64 ? 18446744073709549568.0 : std::ldexp(1.0, static_cast<int>(bits)) - 1;
  const auto v = static_cast<std::uint64_t>(std::clamp(rounded, 0.0, hi));
  return od.set_value(index, subindex, to_le_bytes(v, n));
}

// ---------------------------------------------------------------------------------------------
// Dictionaries from SII images

namespace {

// The CoE type of an SII PDO entry: its declared data type when that type has the entry's bit
// length, else a type chosen by the length.
DataType sii_entry_type(const wire::SiiPdoEntry& entry) {
  if (entry.data_type != 0) {
    const auto declared = static_cast<DataType>(entry.data_type);
    const auto natural = natural_bit_length(declared);
    if (natural != 0 && natural == entry.bit_length) return declared;
    if (natural != 0 && entry.bit_length < natural && entry.bit_length > 8) return declared;
  }
  const std::uint8_t bits = entry.bit_length;
  if (bits == 1) return DataType::boolean;
  if (bits < 8) return static_cast<DataType>(static_cast<std::uint16_t>(DataType::bit1) + bits - 1);
  if (bits == 8) return DataType::unsigned8;
  if (bits <= 16) return DataType::unsigned16;
  if (bits <= 24) return DataType::unsigned24;
  if (bits <= 32) return DataType::unsigned32;
  return DataType::unsigned64;
}

}  // namespace

void add_sii_process_data(ObjectDictionary& od, const wire::SiiImage& sii,
                          SiiDictionaryOptions options) {
  const bool writable = options.writable;
  struct Mapped {
    ObjectEntry entry;
    std::string object_name;
  };
  std::map<std::uint16_t, std::map<std::uint8_t, Mapped>> objects;
  std::map<std::uint8_t, std::pair<PdoDirection, std::vector<std::uint16_t>>> assignments;

  auto add_pdos = [&](const std::vector<wire::SiiPdo>& pdos, PdoDirection direction) {
    for (const auto& pdo : pdos) {
      std::vector<PdoEntryRef> refs;
      for (const auto& e : pdo.entries) {
        refs.push_back({e.index, e.subindex, e.bit_length});
        if (!options.entry_objects || e.padding() || e.index <= 0x0007) continue;
        if (od.find(e.index) != nullptr) continue;  // the device's own object wins
        auto& slot = objects[e.index];
        if (slot.count(e.subindex) != 0) continue;  // mapped twice: the first wins
        const DataType type = sii_entry_type(e);
        std::string name(sii.string(e.name_index));
        if (name.empty()) name = fmt::format("SubIndex {:03}", e.subindex);
        const std::uint16_t access = direction == PdoDirection::rx
                                         ? (kAccessReadWrite | kAccessRxPdo)
                                         : (kAccessRead | kAccessTxPdo);
        ObjectEntry entry = make_entry(e.subindex, std::move(name), type, access);
        entry.bit_length = e.bit_length;
        entry.value.assign(entry.byte_length(), 0);
        entry.default_value = entry.value;
        std::string object_name(sii.string(pdo.name_index));
        slot.emplace(e.subindex, Mapped{std::move(entry), std::move(object_name)});
      }
      std::string name(sii.string(pdo.name_index));
      if (name.empty()) name = fmt::format("PDO 0x{:04X}", pdo.index);
      PdoMappingOptions mapping;
      mapping.capacity = static_cast<std::uint8_t>(std::clamp<std::size_t>(refs.size(), 1, 255));
      mapping.writable = writable && (pdo.flags & wire::sii_pdo_flag::kFixedContent) == 0;
      add_pdo_mapping(od, pdo.index, std::move(name), refs, mapping);
      if (options.assignments && pdo.sync_manager < sii.sync_managers.size() &&
          pdo.sync_manager < reg::kMaxSyncManagers) {
        auto& a = assignments[pdo.sync_manager];
        a.first = direction;
        a.second.push_back(pdo.index);
      }
    }
  };
  add_pdos(sii.rxpdos, PdoDirection::rx);
  add_pdos(sii.txpdos, PdoDirection::tx);

  for (auto& [index, entries] : objects) {
    if (entries.size() == 1 && entries.begin()->first == 0) {
      auto& m = entries.begin()->second;
      od.add(make_var(index, m.object_name.empty() ? m.entry.name : m.object_name,
                      std::move(m.entry)));
      continue;
    }
    std::vector<ObjectEntry> list;
    std::string name;
    for (auto& [sub, m] : entries) {
      if (sub == 0) continue;
      if (name.empty()) name = m.object_name;
      list.push_back(std::move(m.entry));
    }
    if (name.empty()) name = fmt::format("Object 0x{:04X}", index);
    od.add(make_record(index, std::move(name), std::move(list)));
  }
  for (auto& [sm, a] : assignments) {
    PdoAssignmentOptions assignment;
    assignment.capacity =
        static_cast<std::uint8_t>(std::clamp<std::size_t>(a.second.size(), 1, 255));
    assignment.writable = writable;
    add_pdo_assignment(od, sm, a.first, a.second, assignment);
  }
}

void add_sii_identity(ObjectDictionary& od, const wire::SiiImage& sii, std::uint32_t device_type,
                      std::string_view hardware_version, std::string_view software_version) {
  od.add(make_device_type(device_type));
  od.add(make_error_register());
  od.add(make_device_name(sii.device_name()));
  if (!hardware_version.empty()) od.add(make_hardware_version(hardware_version));
  if (!software_version.empty()) od.add(make_software_version(software_version));
  od.add(make_identity({sii.identity.vendor_id, sii.identity.product_code, sii.identity.revision,
                        sii.identity.serial}));
  std::vector<std::uint8_t> types;
  for (const auto& sm : sii.sync_managers)
    types.push_back(sm.type);
  if (!types.empty()) od.add(make_sync_manager_types(types));
}

}  // namespace ecat::sim
