#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/registers.hpp>

#include "config/spec_tree.hpp"
#include "sim/fault_spec.hpp"

namespace ecat::sim {

namespace {

// One row per kind, in enum order: the name ring files, control requests and the command line
// use, the command-line arguments, and what it does.
constexpr std::array<FaultKindInfo, kFaultKindCount> kKinds{{
    {FaultKind::drop_responses, "drop_responses", "[PORT]",
     "no reply to the frame (the master times out)"},
    {FaultKind::wkc_offset, "wkc_offset", "DELTA [PORT]", "add DELTA to every datagram's WKC"},
    {FaultKind::command_wkc_offset, "command_wkc_offset", "COMMAND DELTA [PORT]",
     "add DELTA to the WKC of one command"},
    {FaultKind::logical_wkc_offset, "logical_wkc_offset", "SLAVE DELTA",
     "add DELTA to the slave's share of logical WKCs"},
    {FaultKind::disconnect, "disconnect", "SLAVE", "cut the slave off (no processing, no WKC)"},
    {FaultKind::truncate_reply, "truncate_reply", "[BYTES [PORT]]",
     "cut the last BYTES (1) bytes off the reply"},
    {FaultKind::unsupported_type, "unsupported_type", "[TYPE [PORT]]",
     "set the EtherCAT header type to TYPE (0)"},
    {FaultKind::wrong_index, "wrong_index", "[PORT]",
     "add 1 to the first datagram's index in the reply"},
    {FaultKind::replay_previous, "replay_previous", "[PORT]", "send the previous reply instead"},
    {FaultKind::corrupt_byte, "corrupt_byte", "[OFFSET [MASK [PORT]]]",
     "XOR the reply byte at OFFSET (12) with MASK (0xFF)"},
    {FaultKind::duplicate_reply, "duplicate_reply", "[PORT]", "send the reply twice"},
    {FaultKind::reorder_replies, "reorder_replies", "[PORT]", "send the reply after the next one"},
    {FaultKind::delay_replies, "delay_replies", "MS [PORT]",
     "send the reply MS milliseconds later"},
    {FaultKind::retreat_to_safeop, "retreat_to_safeop", "SLAVE", "OP -> SAFEOP without an error"},
    {FaultKind::power_cycle, "power_cycle", "SLAVE", "power cycle the slave"},
    {FaultKind::latch_al_error, "latch_al_error", "SLAVE CODE",
     "set the AL error bit with status CODE"},
    {FaultKind::refuse_state, "refuse_state", "SLAVE STATE CODE",
     "refuse requests for AL STATE with status CODE (the slave stays where it is)"},
    {FaultKind::mailbox_abort, "mailbox_abort", "SLAVE INDEX:SUB CODE [STAGE]",
     "abort SDO transfers of INDEX:SUB with CODE at STAGE (request)"},
    {FaultKind::mailbox_protocol_fault, "mailbox_protocol_fault",
     "SLAVE INDEX:SUB STAGE KIND[=VALUE]", "corrupt mailbox responses for INDEX:SUB at STAGE"},
    {FaultKind::dc_jump, "dc_jump", "SLAVE NS", "step the slave's DC clock by NS nanoseconds"},
    {FaultKind::foe_fault, "foe_fault", "SLAVE MODE [PACKET [VALUE]]",
     "FoE: MODE (error, busy, drop_reply, wrong_packet, wrong_password) at the reply after "
     "PACKET (0) packets; VALUE: error code or BUSY answers"},
    {FaultKind::soe_fault, "soe_fault", "SLAVE MODE IDN [VALUE [DRIVE [WRITE]]]",
     "SoE: MODE (error_response, drop_fragment, drop_response) for IDN; VALUE: error code or "
     "fragment"},
    {FaultKind::eoe_fault, "eoe_fault", "SLAVE MODE [VALUE]",
     "EoE: MODE (drop_reply_fragment, drop_request_fragment, drop_reply, "
     "corrupt_fragment_offset) with fragment number VALUE"},
    {FaultKind::voe_fault, "voe_fault", "SLAVE MODE",
     "VoE: MODE (drop_reply, garble_reply) for the next VoE reply"},
    {FaultKind::link_down, "link_down", "SLAVE PORT", "take the link on the slave's PORT down"},
    {FaultKind::link_up, "link_up", "SLAVE PORT", "bring the link on the slave's PORT up"},
    {FaultKind::master_link_down, "master_link_down", "", "take the master's link down"},
    {FaultKind::master_link_up, "master_link_up", "", "bring the master's link up"},
    {FaultKind::ring_break, "ring_break", "AFTER",
     "redundant ring: the cable after the AFTER-th slave breaks (1..slaves-1)"},
    {FaultKind::ring_cut, "ring_cut", "PORT",
     "redundant ring: the cable at the master's PORT (primary, secondary) is cut"},
    {FaultKind::ring_heal, "ring_heal", "", "redundant ring: every cable whole again"},
    {FaultKind::port_delay, "port_delay", "PORT MS [FROM]",
     "redundant ring: replies leaving by master PORT come MS later (0: no delay); only those to "
     "frames that entered by port FROM"},
    {FaultKind::hot_plug, "hot_plug", "GROUP",
     "hot connect: plug the group GROUP in (its slaves powered up afresh)"},
    {FaultKind::hot_unplug, "hot_unplug", "GROUP", "hot connect: pull the group GROUP out"},
}};

constexpr std::array<ProtocolFaultKind, 9> kProtocolKinds{
    ProtocolFaultKind::drop_response,   ProtocolFaultKind::counter_mismatch,
    ProtocolFaultKind::toggle_mismatch, ProtocolFaultKind::mailbox_type,
    ProtocolFaultKind::coe_service,     ProtocolFaultKind::invalid_coe_payload,
    ProtocolFaultKind::sdo_command,     ProtocolFaultKind::invalid_segment_padding,
    ProtocolFaultKind::segment_command,
};

constexpr std::array<MailboxStage, kMailboxStageCount> kStages{
    MailboxStage::request, MailboxStage::upload_init, MailboxStage::upload_segment,
    MailboxStage::download_init, MailboxStage::download_segment};

bool protocol_has_value(ProtocolFaultKind kind) {
  return kind == ProtocolFaultKind::mailbox_type || kind == ProtocolFaultKind::coe_service ||
         kind == ProtocolFaultKind::sdo_command || kind == ProtocolFaultKind::segment_command;
}

std::optional<ProtocolFaultKind> protocol_kind_from_string(std::string_view name) {
  for (auto k : kProtocolKinds) {
    if (to_string(k) == name) return k;
  }
  return std::nullopt;
}

constexpr std::array<FoeFaultMode, 5> kFoeModes{
    FoeFaultMode::error, FoeFaultMode::busy, FoeFaultMode::drop_reply, FoeFaultMode::wrong_packet,
    FoeFaultMode::wrong_password};
constexpr std::array<SoeFaultKind, 3> kSoeModes{
    SoeFaultKind::error_response, SoeFaultKind::drop_fragment, SoeFaultKind::drop_response};
constexpr std::array<EoeFaultKind, 4> kEoeModes{
    EoeFaultKind::drop_reply_fragment, EoeFaultKind::drop_request_fragment,
    EoeFaultKind::drop_reply, EoeFaultKind::corrupt_fragment_offset};
constexpr std::array<HandlerFaultKind, 2> kVoeModes{HandlerFaultKind::drop_reply,
                                                    HandlerFaultKind::garble_reply};

// The mailbox protocol kinds: their `mode` by name, a rule that fires once unless `once: false`.
bool is_protocol_kind(FaultKind kind) {
  return kind == FaultKind::foe_fault || kind == FaultKind::soe_fault ||
         kind == FaultKind::eoe_fault || kind == FaultKind::voe_fault;
}

std::optional<MailboxStage> stage_from_string(std::string_view name) {
  for (auto s : kStages) {
    if (to_string(s) == name) return s;
  }
  return std::nullopt;
}

// AL states as ring files and control requests spell them (refuse_state).
constexpr std::array<std::pair<wire::AlState, std::string_view>, 5> kAlStateNames{{
    {wire::AlState::init, "init"},
    {wire::AlState::preop, "preop"},
    {wire::AlState::bootstrap, "bootstrap"},
    {wire::AlState::safeop, "safeop"},
    {wire::AlState::op, "op"},
}};

std::string_view al_state_name(wire::AlState state) {
  for (const auto& [s, name] : kAlStateNames) {
    if (s == state) return name;
  }
  return "?";
}

// Case-insensitive; "boot" (the ESC's own abbreviation) names bootstrap too.
std::optional<wire::AlState> al_state_from_name(std::string_view name) {
  std::string lower(name);
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  if (lower == "boot") return wire::AlState::bootstrap;
  for (const auto& [s, text] : kAlStateNames) {
    if (text == lower) return s;
  }
  return std::nullopt;
}

std::optional<wire::Command> command_from_string(std::string_view name) {
  for (std::uint8_t c = 0; c < wire::kCommandCount; ++c) {
    const auto command = static_cast<wire::Command>(c);
    const auto text = wire::to_string(command);
    if (text.size() == name.size() &&
        std::equal(text.begin(), text.end(), name.begin(), [](char a, char b) {
          return std::tolower(static_cast<unsigned char>(a)) ==
                 std::tolower(static_cast<unsigned char>(b));
        })) {
      return command;
    }
  }
  return std::nullopt;
}

std::string list_names(auto&& range) {
  std::string out;
  for (const auto& item : range) {
    if (!out.empty()) out += ", ";
    out += std::string(to_string(item));
  }
  return out;
}

std::string unknown_kind(std::string_view name) {
  std::string known;
  for (const auto& k : kKinds)
    known += (known.empty() ? "" : ", ") + std::string(k.name);
  return fmt::format("unknown fault kind '{}' (known: {})", name, known);
}

// A command-line argument of a kind ("SLAVE", "INDEX:SUB", "[STAGE]"): kKinds lists them in
// order; a token opening with '[' starts the optional tail ("[OFFSET [MASK]]").
struct Argument {
  std::string_view name;
  bool optional = false;
};

std::vector<Argument> arguments_of(FaultKind kind) {
  std::vector<Argument> out;
  std::string_view args = kKinds[static_cast<std::size_t>(kind)].arguments;
  bool optional = false;
  while (!args.empty()) {
    const auto space = args.find(' ');
    std::string_view token = args.substr(0, space);
    args = space == std::string_view::npos ? std::string_view() : args.substr(space + 1);
    if (token.empty()) continue;
    if (token.front() == '[') {
      optional = true;
      token.remove_prefix(1);
    }
    while (!token.empty() && token.back() == ']' && token.find('[') == std::string_view::npos) {
      token.remove_suffix(1);
    }
    out.push_back({token, optional});
  }
  return out;
}

// The mapping keys an argument fills: its name in lower case, two for the combined ones.
std::vector<std::string> argument_keys(std::string_view argument) {
  if (argument == "INDEX:SUB") return {"index", "subindex"};
  if (argument == "KIND[=VALUE]") return {"protocol", "value"};
  std::string key(argument);
  std::transform(key.begin(), key.end(), key.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  return {key};
}

// The largest `value` a protocol fault takes: a nibble for the mailbox type and CoE service.
std::uint8_t protocol_value_max(ProtocolFaultKind kind) {
  return kind == ProtocolFaultKind::mailbox_type || kind == ProtocolFaultKind::coe_service ? 15
                                                                                           : 255;
}

bool protocol_stage_valid(ProtocolFaultKind kind, MailboxStage stage) {
  switch (kind) {
    case ProtocolFaultKind::toggle_mismatch:
    case ProtocolFaultKind::segment_command:
      return stage == MailboxStage::upload_segment || stage == MailboxStage::download_segment;
    case ProtocolFaultKind::invalid_segment_padding:
      return stage == MailboxStage::upload_segment;
    case ProtocolFaultKind::sdo_command:
      return stage == MailboxStage::request || stage == MailboxStage::upload_init ||
             stage == MailboxStage::download_init;
    default:
      return true;
  }
}

std::string protocol_text(const ProtocolFault& p) {
  if (protocol_has_value(p.kind)) return fmt::format("{}=0x{:02X}", to_string(p.kind), p.value);
  return std::string(to_string(p.kind));
}

std::string duration_text(std::chrono::nanoseconds d) {
  const auto ns = d.count();
  if (ns % 1'000'000 == 0) return fmt::format("{} ms", ns / 1'000'000);
  if (ns % 1'000 == 0) return fmt::format("{} us", ns / 1'000);
  if (std::llabs(ns) >= 1'000'000) return fmt::format("{:g} ms", static_cast<double>(ns) / 1e6);
  return fmt::format("{} ns", ns);
}

std::string plural(std::uint64_t n, std::string_view one, std::string_view many) {
  return fmt::format("{} {}", n, n == 1 ? one : many);
}

Fault make(FaultKind kind, std::string slave = {}) {
  Fault f;
  f.effect.kind = kind;
  f.effect.slave = std::move(slave);
  return f;
}

bool needs_slave(FaultKind kind) {
  switch (kind) {
    case FaultKind::logical_wkc_offset:
    case FaultKind::disconnect:
    case FaultKind::retreat_to_safeop:
    case FaultKind::power_cycle:
    case FaultKind::latch_al_error:
    case FaultKind::refuse_state:
    case FaultKind::mailbox_abort:
    case FaultKind::mailbox_protocol_fault:
    case FaultKind::dc_jump:
    case FaultKind::foe_fault:
    case FaultKind::soe_fault:
    case FaultKind::eoe_fault:
    case FaultKind::voe_fault:
    case FaultKind::link_down:
    case FaultKind::link_up:
      return true;
    default:
      return false;
  }
}

}  // namespace

// ---- Names --------------------------------------------------------------------------------

std::string_view to_string(FaultKind kind) noexcept {
  const auto i = static_cast<std::size_t>(kind);
  return i < kKinds.size() ? kKinds[i].name : std::string_view("?");
}

std::optional<FaultKind> fault_kind_from_string(std::string_view name) noexcept {
  for (const auto& k : kKinds) {
    if (k.name == name) return k.kind;
  }
  return std::nullopt;
}

std::string_view to_string(FoeFaultMode mode) noexcept {
  switch (mode) {
    case FoeFaultMode::error:
      return "error";
    case FoeFaultMode::busy:
      return "busy";
    case FoeFaultMode::drop_reply:
      return "drop_reply";
    case FoeFaultMode::wrong_packet:
      return "wrong_packet";
    case FoeFaultMode::wrong_password:
      return "wrong_password";
  }
  return "?";
}

FaultClass fault_class(FaultKind kind) noexcept {
  switch (kind) {
    case FaultKind::drop_responses:
    case FaultKind::wkc_offset:
    case FaultKind::command_wkc_offset:
    case FaultKind::logical_wkc_offset:
    case FaultKind::disconnect:
      return FaultClass::exchange;
    case FaultKind::truncate_reply:
    case FaultKind::unsupported_type:
    case FaultKind::wrong_index:
    case FaultKind::replay_previous:
    case FaultKind::corrupt_byte:
    case FaultKind::duplicate_reply:
    case FaultKind::reorder_replies:
    case FaultKind::delay_replies:
      return FaultClass::reply;
    case FaultKind::retreat_to_safeop:
    case FaultKind::power_cycle:
    case FaultKind::latch_al_error:
    case FaultKind::refuse_state:
    case FaultKind::mailbox_abort:
    case FaultKind::mailbox_protocol_fault:
    case FaultKind::dc_jump:
    case FaultKind::foe_fault:
    case FaultKind::soe_fault:
    case FaultKind::eoe_fault:
    case FaultKind::voe_fault:
      return FaultClass::slave;
    case FaultKind::link_down:
    case FaultKind::link_up:
    case FaultKind::master_link_down:
    case FaultKind::master_link_up:
    case FaultKind::ring_break:
    case FaultKind::ring_cut:
    case FaultKind::ring_heal:
    case FaultKind::port_delay:
    case FaultKind::hot_plug:
    case FaultKind::hot_unplug:
      return FaultClass::segment;
  }
  return FaultClass::segment;
}

bool is_per_exchange(FaultKind kind) noexcept {
  const auto c = fault_class(kind);
  return c == FaultClass::exchange || c == FaultClass::reply;
}

namespace {

// The per-exchange kinds that may name the master port whose replies they act on (`port`): those
// that act on a whole frame, not on one slave.
bool takes_port(FaultKind kind) noexcept {
  return kind == FaultKind::drop_responses || kind == FaultKind::wkc_offset ||
         kind == FaultKind::command_wkc_offset || fault_class(kind) == FaultClass::reply;
}

}  // namespace

std::string_view to_string(Milestone::Kind kind) noexcept {
  switch (kind) {
    case Milestone::Kind::healthy_exchanges:
      return "healthy_exchanges";
    case Milestone::Kind::healthy_polls:
      return "healthy_polls";
    case Milestone::Kind::mailbox_step:
      return "mailbox_step";
  }
  return "?";
}

const std::array<FaultKindInfo, kFaultKindCount>& fault_kinds() noexcept {
  return kKinds;
}

// ---- Builders -----------------------------------------------------------------------------

namespace fault {
Fault drop_responses() {
  return make(FaultKind::drop_responses);
}
Fault wkc_offset(std::int64_t delta) {
  auto f = make(FaultKind::wkc_offset);
  f.effect.delta = delta;
  return f;
}
Fault command_wkc_offset(wire::Command command, std::int64_t delta) {
  auto f = make(FaultKind::command_wkc_offset);
  f.effect.command = command;
  f.effect.delta = delta;
  return f;
}
Fault logical_wkc_offset(std::string slave, std::int64_t delta) {
  auto f = make(FaultKind::logical_wkc_offset, std::move(slave));
  f.effect.delta = delta;
  return f;
}
Fault disconnect(std::string slave) {
  return make(FaultKind::disconnect, std::move(slave));
}
Fault truncate_reply(std::uint32_t bytes) {
  auto f = make(FaultKind::truncate_reply);
  f.effect.bytes = bytes;
  return f;
}
Fault unsupported_type(std::uint8_t frame_type) {
  auto f = make(FaultKind::unsupported_type);
  f.effect.frame_type = frame_type;
  return f;
}
Fault wrong_index() {
  return make(FaultKind::wrong_index);
}
Fault replay_previous() {
  return make(FaultKind::replay_previous);
}
Fault corrupt_byte(std::uint32_t offset, std::uint8_t mask) {
  auto f = make(FaultKind::corrupt_byte);
  f.effect.offset = offset;
  f.effect.mask = mask;
  return f;
}
Fault duplicate_reply() {
  return make(FaultKind::duplicate_reply);
}
Fault reorder_replies() {
  return make(FaultKind::reorder_replies);
}
Fault delay_replies(std::chrono::nanoseconds delay) {
  auto f = make(FaultKind::delay_replies);
  f.effect.ns = delay.count();
  return f;
}
Fault at_port(Fault fault, wire::RedundantPort port) {
  if (fault.form == Fault::Form::effect) fault.effect.on_port = port;
  return fault;
}
Fault retreat_to_safeop(std::string slave) {
  return make(FaultKind::retreat_to_safeop, std::move(slave));
}
Fault power_cycle(std::string slave) {
  return make(FaultKind::power_cycle, std::move(slave));
}
Fault latch_al_error(std::string slave, std::uint16_t code) {
  auto f = make(FaultKind::latch_al_error, std::move(slave));
  f.effect.code = code;
  return f;
}
Fault refuse_state(std::string slave, wire::AlState state, std::uint16_t code) {
  auto f = make(FaultKind::refuse_state, std::move(slave));
  f.effect.state = state;
  f.effect.code = code;
  return f;
}
Fault mailbox_abort(std::string slave, std::uint16_t index, std::uint8_t subindex,
                    std::uint32_t code, MailboxStage stage) {
  auto f = make(FaultKind::mailbox_abort, std::move(slave));
  f.effect.index = index;
  f.effect.subindex = subindex;
  f.effect.code = code;
  f.effect.stage = stage;
  return f;
}
Fault mailbox_protocol_fault(std::string slave, std::uint16_t index, std::uint8_t subindex,
                             MailboxStage stage, ProtocolFault protocol) {
  auto f = make(FaultKind::mailbox_protocol_fault, std::move(slave));
  f.effect.index = index;
  f.effect.subindex = subindex;
  f.effect.stage = stage;
  f.effect.protocol = protocol;
  return f;
}
Fault dc_jump(std::string slave, std::chrono::nanoseconds step) {
  auto f = make(FaultKind::dc_jump, std::move(slave));
  f.effect.ns = step.count();
  return f;
}
Fault foe_fault(std::string slave, FoeFaultMode mode, std::uint32_t packet, std::uint32_t value) {
  auto f = make(FaultKind::foe_fault, std::move(slave));
  f.effect.foe = mode;
  f.effect.packet = packet;
  f.effect.value = value;
  if (value == 0 && mode == FoeFaultMode::error) {
    f.effect.value = static_cast<std::uint32_t>(wire::FoeErrorCode::not_defined);
  }
  if (value == 0 && mode == FoeFaultMode::busy) f.effect.value = 1;
  return f;
}
Fault soe_fault(std::string slave, SoeFaultKind kind, std::uint16_t idn, std::uint32_t value,
                std::uint8_t drive, bool write) {
  auto f = make(FaultKind::soe_fault, std::move(slave));
  f.effect.soe = kind;
  f.effect.idn = idn;
  f.effect.value = value;
  f.effect.drive = drive;
  f.effect.write = write;
  return f;
}
Fault eoe_fault(std::string slave, EoeFaultKind kind, std::uint32_t value) {
  auto f = make(FaultKind::eoe_fault, std::move(slave));
  f.effect.eoe = kind;
  f.effect.value = value;
  return f;
}
Fault voe_fault(std::string slave, HandlerFaultKind kind) {
  auto f = make(FaultKind::voe_fault, std::move(slave));
  f.effect.voe = kind;
  return f;
}
Fault link_down(std::string slave, std::uint8_t port) {
  auto f = make(FaultKind::link_down, std::move(slave));
  f.effect.port = port;
  return f;
}
Fault link_up(std::string slave, std::uint8_t port) {
  auto f = make(FaultKind::link_up, std::move(slave));
  f.effect.port = port;
  return f;
}
Fault master_link_down() {
  return make(FaultKind::master_link_down);
}
Fault master_link_up() {
  return make(FaultKind::master_link_up);
}
Fault ring_break(std::uint32_t after) {
  auto f = make(FaultKind::ring_break);
  f.effect.after = after;
  return f;
}
Fault ring_cut(wire::RedundantPort port) {
  auto f = make(FaultKind::ring_cut);
  f.effect.master_port = port;
  return f;
}
Fault ring_heal() {
  return make(FaultKind::ring_heal);
}
Fault hot_plug(std::string group) {
  auto f = make(FaultKind::hot_plug);
  f.effect.group = std::move(group);
  return f;
}
Fault hot_unplug(std::string group) {
  auto f = make(FaultKind::hot_unplug);
  f.effect.group = std::move(group);
  return f;
}
Fault port_delay(wire::RedundantPort port, std::chrono::nanoseconds delay,
                 std::optional<wire::RedundantPort> from) {
  auto f = make(FaultKind::port_delay);
  f.effect.master_port = port;
  f.effect.ns = delay.count();
  f.effect.from = from;
  return f;
}

Fault next(Fault fault, std::uint64_t exchanges) {
  fault.exchanges = exchanges;
  return fault;
}
Fault after(Fault fault, std::chrono::nanoseconds delay) {
  Fault f;
  f.form = Fault::Form::after_delay;
  f.delay = delay;
  f.steps.push_back(std::move(fault));
  return f;
}
Fault after_milestone(Fault fault, Milestone milestone) {
  Fault f;
  f.form = Fault::Form::after_milestone;
  f.milestone = std::move(milestone);
  f.steps.push_back(std::move(fault));
  return f;
}
Fault script(std::vector<Fault> steps) {
  Fault f;
  f.form = Fault::Form::script;
  f.steps = std::move(steps);
  return f;
}
Fault wait(std::chrono::nanoseconds delay) {
  Fault f;
  f.form = Fault::Form::wait;
  f.delay = delay;
  return f;
}
Fault wait_for(Milestone milestone) {
  Fault f;
  f.form = Fault::Form::wait_for;
  f.milestone = std::move(milestone);
  return f;
}
Milestone healthy_exchanges(std::uint64_t count) {
  return Milestone{Milestone::Kind::healthy_exchanges, {}, MailboxStage::upload_init, count};
}
Milestone healthy_polls(std::string slave, std::uint64_t count) {
  return Milestone{Milestone::Kind::healthy_polls, std::move(slave), MailboxStage::upload_init,
                   count};
}
Milestone mailbox_step(std::string slave, MailboxStage step, std::uint64_t count) {
  return Milestone{Milestone::Kind::mailbox_step, std::move(slave), step, count};
}
}  // namespace fault

// ---- describe -----------------------------------------------------------------------------

std::string describe(const FaultEffect& e) {
  if (e.on_port) {
    FaultEffect any = e;
    any.on_port.reset();
    return fmt::format("{} at the {} port", describe(any), wire::to_string(*e.on_port));
  }
  switch (e.kind) {
    case FaultKind::drop_responses:
      return "drop responses";
    case FaultKind::wkc_offset:
      return fmt::format("WKC offset {:+}", e.delta);
    case FaultKind::command_wkc_offset:
      return fmt::format("{} WKC offset {:+}", wire::to_string(e.command), e.delta);
    case FaultKind::logical_wkc_offset:
      return fmt::format("logical WKC offset {:+} for {}", e.delta, e.slave);
    case FaultKind::disconnect:
      return fmt::format("disconnect {}", e.slave);
    case FaultKind::truncate_reply:
      return fmt::format("truncate replies by {}", plural(e.bytes, "byte", "bytes"));
    case FaultKind::unsupported_type:
      return fmt::format("frame type {} in replies", e.frame_type);
    case FaultKind::wrong_index:
      return "wrong index in replies";
    case FaultKind::replay_previous:
      return "replay the previous reply";
    case FaultKind::corrupt_byte:
      return fmt::format("corrupt reply byte {} (xor 0x{:02X})", e.offset, e.mask);
    case FaultKind::duplicate_reply:
      return "duplicate replies";
    case FaultKind::reorder_replies:
      return "reorder replies";
    case FaultKind::delay_replies:
      return fmt::format("delay replies by {}", duration_text(std::chrono::nanoseconds(e.ns)));
    case FaultKind::retreat_to_safeop:
      return fmt::format("retreat {} to SAFEOP", e.slave);
    case FaultKind::power_cycle:
      return fmt::format("power cycle {}", e.slave);
    case FaultKind::latch_al_error:
      return fmt::format("latch AL error 0x{:04X} on {}", e.code, e.slave);
    case FaultKind::refuse_state:
      return fmt::format("refuse {} on {} with AL status 0x{:04X}", wire::to_string(e.state),
                         e.slave, e.code);
    case FaultKind::mailbox_abort:
      return fmt::format("mailbox abort 0x{:08X} on {} 0x{:04X}:{:02X} at {}{}", e.code, e.slave,
                         e.index, e.subindex, to_string(e.stage),
                         e.once.value_or(false) ? " (once)" : "");
    case FaultKind::mailbox_protocol_fault:
      return fmt::format("mailbox protocol fault {} on {} 0x{:04X}:{:02X} at {}{}",
                         protocol_text(e.protocol), e.slave, e.index, e.subindex,
                         to_string(e.stage), e.once.value_or(false) ? " (once)" : "");
    case FaultKind::dc_jump:
      return fmt::format("DC clock jump {:+} ns on {}", e.ns, e.slave);
    case FaultKind::foe_fault: {
      std::string what(to_string(e.foe));
      if (e.foe == FoeFaultMode::error) what += fmt::format(" 0x{:04X}", e.value);
      if (e.foe == FoeFaultMode::busy) what += fmt::format(" x{}", e.value);
      return fmt::format("FoE {} on {} after {}", what, e.slave,
                         plural(e.packet, "packet", "packets"));
    }
    case FaultKind::soe_fault: {
      std::string what(to_string(e.soe));
      if (e.soe == SoeFaultKind::error_response) what = fmt::format("error 0x{:04X}", e.value);
      if (e.soe == SoeFaultKind::drop_fragment) what += fmt::format(" {}", e.value);
      return fmt::format("SoE {} on {} drive {} IDN {}{}{}", what, e.slave, e.drive, e.idn,
                         e.write ? " (write)" : "", e.once.value_or(true) ? " (once)" : "");
    }
    case FaultKind::eoe_fault: {
      std::string what(to_string(e.eoe));
      if (e.eoe != EoeFaultKind::drop_reply) what += fmt::format(" {}", e.value);
      return fmt::format("EoE {} on {}{}", what, e.slave, e.once.value_or(true) ? " (once)" : "");
    }
    case FaultKind::voe_fault:
      return fmt::format("VoE {} on {}{}", to_string(e.voe), e.slave,
                         e.once.value_or(true) ? " (once)" : "");
    case FaultKind::link_down:
      return fmt::format("link down on {} port {}", e.slave, e.port);
    case FaultKind::link_up:
      return fmt::format("link up on {} port {}", e.slave, e.port);
    case FaultKind::master_link_down:
      return "master link down";
    case FaultKind::master_link_up:
      return "master link up";
    case FaultKind::ring_break:
      return fmt::format("ring break after slave {}", e.after);
    case FaultKind::ring_cut:
      return fmt::format("ring cut at the master's {} port", wire::to_string(e.master_port));
    case FaultKind::ring_heal:
      return "ring whole";
    case FaultKind::port_delay:
      return fmt::format("{} port replies +{}{}", wire::to_string(e.master_port),
                         duration_text(std::chrono::nanoseconds(e.ns)),
                         e.from ? fmt::format(" (from {})", wire::to_string(*e.from)) : "");
    case FaultKind::hot_plug:
      return fmt::format("hot plug {}", e.group);
    case FaultKind::hot_unplug:
      return fmt::format("hot unplug {}", e.group);
  }
  return "?";
}

std::string describe(const Milestone& m) {
  switch (m.kind) {
    case Milestone::Kind::healthy_exchanges:
      return plural(m.count, "healthy exchange", "healthy exchanges");
    case Milestone::Kind::healthy_polls:
      return fmt::format("{} of {}", plural(m.count, "healthy poll", "healthy polls"), m.slave);
    case Milestone::Kind::mailbox_step:
      return fmt::format("{} mailbox {} {} of {}", m.count, to_string(m.step),
                         m.count == 1 ? "step" : "steps", m.slave);
  }
  return "?";
}

std::string describe(const Fault& f) {
  switch (f.form) {
    case Fault::Form::effect:
      if (f.exchanges == 0) return describe(f.effect);
      if (f.exchanges == 1) return "next exchange " + describe(f.effect);
      return fmt::format("next {} exchanges {}", f.exchanges, describe(f.effect));
    case Fault::Form::after_delay:
      return fmt::format("after {}: {}", duration_text(f.delay),
                         f.steps.empty() ? "nothing" : describe(f.steps[0]));
    case Fault::Form::after_milestone:
      return fmt::format("after {}: {}", describe(f.milestone),
                         f.steps.empty() ? "nothing" : describe(f.steps[0]));
    case Fault::Form::script: {
      std::string out = "script:";
      for (std::size_t i = 0; i < f.steps.size(); ++i) {
        out += (i == 0 ? " " : "; ") + describe(f.steps[i]);
      }
      return out;
    }
    case Fault::Form::wait:
      return "wait " + duration_text(f.delay);
    case Fault::Form::wait_for:
      return "wait for " + describe(f.milestone);
  }
  return "?";
}

// ---- validate -----------------------------------------------------------------------------

namespace {

Result<void> validate_effect(const FaultEffect& e) {
  const auto bad = [&](std::string what) {
    return Error(Errc::invalid_argument, fmt::format("{}: {}", to_string(e.kind), what));
  };
  if (needs_slave(e.kind) && e.slave.empty()) return bad("needs a slave");
  if (e.on_port && !takes_port(e.kind)) {
    return bad(
        "names no master port (only drop_responses, wkc_offset, command_wkc_offset and the "
        "reply faults do)");
  }
  switch (e.kind) {
    case FaultKind::command_wkc_offset:
      if (e.command == wire::Command::nop) return bad("needs a command (APRD ... FRMW)");
      break;
    case FaultKind::truncate_reply:
      if (e.bytes == 0) return bad("bytes must be at least 1");
      break;
    case FaultKind::unsupported_type:
      if (e.frame_type == wire::kFrameTypeDatagrams || e.frame_type > 15) {
        return bad(fmt::format("type {} is not an unsupported type (0, 2..15)", e.frame_type));
      }
      break;
    case FaultKind::corrupt_byte:
      if (e.mask == 0) return bad("a mask of 0 corrupts nothing");
      break;
    case FaultKind::delay_replies:
      if (e.ns <= 0) return bad("the delay must be positive");
      break;
    case FaultKind::latch_al_error:
      if (e.code > 0xFFFF) return bad(fmt::format("AL status code 0x{:X} exceeds 16 bits", e.code));
      break;
    case FaultKind::refuse_state:
      if (e.code > 0xFFFF) return bad(fmt::format("AL status code 0x{:X} exceeds 16 bits", e.code));
      if (e.code == 0) return bad("a refusal needs an AL status code (not 0)");
      if (!wire::al_state_from_code(static_cast<std::uint8_t>(e.state))) {
        return bad(fmt::format("AL state 0x{:X} does not exist", static_cast<unsigned>(e.state)));
      }
      break;
    case FaultKind::mailbox_protocol_fault:
      if (!protocol_stage_valid(e.protocol.kind, e.stage)) {
        return bad(fmt::format("{} cannot apply at stage {}", to_string(e.protocol.kind),
                               to_string(e.stage)));
      }
      if (e.protocol.value > protocol_value_max(e.protocol.kind)) {
        return bad(fmt::format("{} value {} exceeds {}", to_string(e.protocol.kind),
                               e.protocol.value, protocol_value_max(e.protocol.kind)));
      }
      break;
    case FaultKind::link_down:
    case FaultKind::link_up:
      if (e.port > 3) return bad(fmt::format("port {} does not exist (0..3)", e.port));
      break;
    case FaultKind::ring_break:
      if (e.after == 0) return bad("a ring breaks after slave 1 at the earliest");
      break;
    case FaultKind::port_delay:
      if (e.ns < 0) return bad("the delay must not be negative");
      break;
    case FaultKind::hot_plug:
    case FaultKind::hot_unplug:
      if (e.group.empty()) return bad("needs a hot-connect group");
      break;
    case FaultKind::foe_fault:
      if (e.foe == FoeFaultMode::busy && (e.value == 0 || e.value > 0xFFFF)) {
        return bad(fmt::format("busy takes 1..65535 BUSY answers, not {}", e.value));
      }
      break;
    case FaultKind::soe_fault:
      if (e.drive > 7) return bad(fmt::format("drive {} does not exist (0..7)", e.drive));
      if (e.value > 0xFFFF) return bad(fmt::format("value 0x{:X} exceeds 16 bits", e.value));
      if (e.soe == SoeFaultKind::drop_fragment && e.value == 0) {
        return bad("drop_fragment needs a fragment number (1..)");
      }
      break;
    case FaultKind::eoe_fault:
      if (e.value > 63) return bad(fmt::format("fragment number {} exceeds 63", e.value));
      if (e.eoe == EoeFaultKind::corrupt_fragment_offset && e.value == 0) {
        return bad(
            "corrupt_fragment_offset needs a fragment number 1..63 (fragment 0 holds "
            "the frame size)");
      }
      break;
    default:
      break;
  }
  return ok();
}

Result<void> validate_milestone(const Milestone& m) {
  if (m.count == 0) return Error(Errc::invalid_argument, "a milestone count must be at least 1");
  if (m.kind != Milestone::Kind::healthy_exchanges && m.slave.empty()) {
    return Error(Errc::invalid_argument,
                 fmt::format("milestone {} needs a slave", to_string(m.kind)));
  }
  if (m.kind == Milestone::Kind::mailbox_step && m.step == MailboxStage::request) {
    return Error(Errc::invalid_argument,
                 "mailbox_step needs a step: upload_init, upload_segment, download_init or "
                 "download_segment");
  }
  return ok();
}

Result<void> validate_at(const Fault& f, bool in_script, int depth) {
  if (depth > 64) return Error(Errc::invalid_argument, "faults nested deeper than 64 levels");
  switch (f.form) {
    case Fault::Form::effect:
      if (f.exchanges != 0 && !is_per_exchange(f.effect.kind)) {
        return Error(Errc::invalid_argument,
                     fmt::format("{}: 'next' applies only to exchange and reply faults (it acts "
                                 "once)",
                                 to_string(f.effect.kind)));
      }
      return validate_effect(f.effect);
    case Fault::Form::after_delay:
    case Fault::Form::after_milestone:
      if (f.steps.size() != 1) {
        return Error(Errc::invalid_argument, "an 'after' form schedules exactly one fault");
      }
      if (f.form == Fault::Form::after_delay && f.delay.count() < 0) {
        return Error(Errc::invalid_argument, "a delay cannot be negative");
      }
      if (f.form == Fault::Form::after_milestone) {
        if (auto r = validate_milestone(f.milestone); !r) return r;
      }
      return validate_at(f.steps[0], in_script, depth + 1);
    case Fault::Form::script:
      if (f.steps.empty()) return Error(Errc::invalid_argument, "a script needs steps");
      for (const auto& step : f.steps) {
        if (auto r = validate_at(step, true, depth + 1); !r) return r;
      }
      return ok();
    case Fault::Form::wait:
    case Fault::Form::wait_for:
      if (!in_script) {
        return Error(Errc::invalid_argument, "wait and wait_for are only valid inside a script");
      }
      if (f.form == Fault::Form::wait && f.delay.count() < 0) {
        return Error(Errc::invalid_argument, "a wait cannot be negative");
      }
      if (f.form == Fault::Form::wait_for) return validate_milestone(f.milestone);
      return ok();
  }
  return ok();
}

}  // namespace

Result<void> validate(const Fault& fault) {
  return validate_at(fault, false, 0);
}

// ---- JSON / spec tree -----------------------------------------------------------------------

namespace detail {

namespace {

using Json = nlohmann::ordered_json;  // key order is part of the form (tests compare text)

std::string hex(std::uint64_t value, int width) {
  return fmt::format("0x{:0{}X}", value, width);
}

// Milliseconds as a whole number when they are one (250), else the exact fraction (1.5).
Json ms_value(std::chrono::nanoseconds d) {
  if (d.count() % 1'000'000 == 0) return d.count() / 1'000'000;
  return static_cast<double>(d.count()) / 1e6;
}

Json milestone_json(const Milestone& m) {
  Json j;
  j["milestone"] = to_string(m.kind);
  if (m.kind != Milestone::Kind::healthy_exchanges) j["slave"] = m.slave;
  if (m.kind == Milestone::Kind::mailbox_step) j["step"] = to_string(m.step);
  j["count"] = m.count;
  return j;
}

Json effect_json(const Fault& f) {
  const FaultEffect& e = f.effect;
  Json j;
  j["kind"] = to_string(e.kind);
  if (needs_slave(e.kind)) j["slave"] = e.slave;
  switch (e.kind) {
    case FaultKind::wkc_offset:
    case FaultKind::logical_wkc_offset:
      j["delta"] = e.delta;
      break;
    case FaultKind::command_wkc_offset:
      j["command"] = wire::to_string(e.command);
      j["delta"] = e.delta;
      break;
    case FaultKind::truncate_reply:
      j["bytes"] = e.bytes;
      break;
    case FaultKind::unsupported_type:
      j["type"] = e.frame_type;
      break;
    case FaultKind::corrupt_byte:
      j["offset"] = e.offset;
      j["mask"] = hex(e.mask, 2);
      break;
    case FaultKind::delay_replies:
      j["ms"] = ms_value(std::chrono::nanoseconds(e.ns));
      break;
    case FaultKind::latch_al_error:
      j["code"] = hex(e.code, 4);
      break;
    case FaultKind::refuse_state:
      j["state"] = al_state_name(e.state);
      j["code"] = hex(e.code, 4);
      break;
    case FaultKind::mailbox_abort:
    case FaultKind::mailbox_protocol_fault:
      j["index"] = hex(e.index, 4);
      j["subindex"] = e.subindex;
      j["stage"] = to_string(e.stage);
      if (e.kind == FaultKind::mailbox_abort) {
        j["code"] = hex(e.code, 8);
      } else {
        j["protocol"] = to_string(e.protocol.kind);
        if (protocol_has_value(e.protocol.kind)) j["value"] = e.protocol.value;
      }
      if (e.once) j["once"] = *e.once;
      break;
    case FaultKind::dc_jump:
      j["ns"] = e.ns;
      break;
    case FaultKind::foe_fault:
      j["mode"] = to_string(e.foe);
      j["packet"] = e.packet;
      if (e.foe == FoeFaultMode::error) j["value"] = hex(e.value, 4);
      if (e.foe == FoeFaultMode::busy) j["value"] = e.value;
      break;
    case FaultKind::soe_fault:
      j["mode"] = to_string(e.soe);
      j["idn"] = e.idn;
      if (e.soe != SoeFaultKind::drop_response) {
        j["value"] = e.soe == SoeFaultKind::error_response ? Json(hex(e.value, 4)) : Json(e.value);
      }
      j["drive"] = e.drive;
      j["write"] = e.write;
      if (e.once) j["once"] = *e.once;
      break;
    case FaultKind::eoe_fault:
      j["mode"] = to_string(e.eoe);
      if (e.eoe != EoeFaultKind::drop_reply) j["value"] = e.value;
      if (e.once) j["once"] = *e.once;
      break;
    case FaultKind::voe_fault:
      j["mode"] = to_string(e.voe);
      if (e.once) j["once"] = *e.once;
      break;
    case FaultKind::link_down:
    case FaultKind::link_up:
      j["port"] = e.port;
      break;
    case FaultKind::ring_break:
      j["after"] = e.after;
      break;
    case FaultKind::ring_cut:
      j["port"] = wire::to_string(e.master_port);
      break;
    case FaultKind::port_delay:
      j["port"] = wire::to_string(e.master_port);
      j["ms"] = ms_value(std::chrono::nanoseconds(e.ns));
      if (e.from) j["from"] = wire::to_string(*e.from);
      break;
    case FaultKind::hot_plug:
    case FaultKind::hot_unplug:
      j["group"] = e.group;
      break;
    default:
      break;
  }
  if (e.on_port && takes_port(e.kind)) j["port"] = wire::to_string(*e.on_port);
  if (f.exchanges != 0) j["next"] = f.exchanges;
  return j;
}

Json fault_json(const Fault& f) {
  switch (f.form) {
    case Fault::Form::effect:
      return effect_json(f);
    case Fault::Form::after_delay:
    case Fault::Form::after_milestone: {
      Json j;
      if (f.form == Fault::Form::after_delay) {
        j["after_ms"] = ms_value(f.delay);
      } else {
        j["after_milestone"] = milestone_json(f.milestone);
      }
      j["fault"] = f.steps.empty() ? Json::object() : fault_json(f.steps[0]);
      return j;
    }
    case Fault::Form::script: {
      Json steps = Json::array();
      for (const auto& step : f.steps)
        steps.push_back(fault_json(step));
      Json j;
      j["script"] = std::move(steps);
      return j;
    }
    case Fault::Form::wait: {
      Json j;
      j["wait_ms"] = ms_value(f.delay);
      return j;
    }
    case Fault::Form::wait_for: {
      Json j;
      j["wait_for"] = milestone_json(f.milestone);
      return j;
    }
  }
  return Json::object();
}

}  // namespace

void append_fault_json(std::string& out, const Fault& f) {
  // Slave names come from ring files: invalid UTF-8 becomes U+FFFD rather than an exception.
  out += fault_json(f).dump(-1, ' ', false, Json::error_handler_t::replace);
}

namespace {

Result<std::chrono::nanoseconds> to_ms(const SpecContext& c, const SpecNode& n,
                                       const std::string& path, bool positive) {
  auto ms = to_double(c, n, path);
  if (!ms) return std::move(ms).error();
  // A day is far beyond any useful fault delay; the bound keeps the conversion exact.
  if (*ms < 0 || *ms > 86'400'000.0 || (positive && *ms <= 0)) {
    return spec_error(
        c, n, path,
        fmt::format("{} ms is out of range ({} to 86400000)", n.text, positive ? "above 0" : "0"),
        Errc::out_of_range);
  }
  return std::chrono::nanoseconds(static_cast<std::int64_t>(std::llround(*ms * 1e6)));
}

// A master port of a redundant ring: "primary" or "secondary" at `key`.
Result<std::optional<wire::RedundantPort>> master_port_key(const SpecContext& c,
                                                           const SpecNode& node,
                                                           const std::string& path,
                                                           std::string_view key) {
  auto found = require(c, node, path, key);
  if (!found) return std::move(found).error();
  const std::string p = join_path(path, key);
  auto text = to_text(c, **found, p);
  if (!text) return std::move(text).error();
  if (*text == "primary") return std::optional(wire::RedundantPort::primary);
  if (*text == "secondary") return std::optional(wire::RedundantPort::secondary);
  return spec_error(c, **found, p,
                    fmt::format("unknown master port '{}' (known: primary, secondary)", *text));
}

Result<std::string> slave_name(const SpecContext& c, const SpecNode& node,
                               const std::string& path) {
  auto slave = require(c, node, path, "slave");
  if (!slave) return std::move(slave).error();
  auto text = to_text(c, **slave, join_path(path, "slave"));
  if (!text) return text;
  if (text->empty()) return spec_error(c, **slave, join_path(path, "slave"), "empty slave name");
  return text;
}

// Reads `key` of `node` with `read(value node, its path)`; when the key is absent, `fallback`,
// or an error without one.
template <class T, class Read>
Result<T> read_key(const SpecContext& c, const SpecNode& node, const std::string& path,
                   std::string_view key, std::optional<T> fallback, Read&& read) {
  const SpecNode* value = node.find(key);
  if (value == nullptr) {
    if (fallback) return *fallback;
    return spec_error(c, node, path, fmt::format("missing key '{}'", key));
  }
  return read(*value, join_path(path, key));
}

template <class T>
Result<T> int_key(const SpecContext& c, const SpecNode& node, const std::string& path,
                  std::string_view key, std::int64_t min, std::int64_t max,
                  std::optional<T> fallback = std::nullopt) {
  return read_key<T>(c, node, path, key, fallback,
                     [&](const SpecNode& value, const std::string& p) -> Result<T> {
                       auto v = to_int(c, value, p, min, max);
                       if (!v) return std::move(v).error();
                       return static_cast<T>(*v);
                     });
}

Result<MailboxStage> stage_key(const SpecContext& c, const SpecNode& node, const std::string& path,
                               std::string_view key, std::optional<MailboxStage> fallback) {
  return read_key<MailboxStage>(
      c, node, path, key, fallback,
      [&](const SpecNode& value, const std::string& p) -> Result<MailboxStage> {
        auto text = to_text(c, value, p);
        if (!text) return std::move(text).error();
        const auto stage = stage_from_string(*text);
        if (!stage) {
          return spec_error(
              c, value, p,
              fmt::format("unknown stage '{}' (known: {})", *text, list_names(kStages)));
        }
        return *stage;
      });
}

// The `mode` of a mailbox protocol fault, one of `modes` by name.
template <class T, std::size_t N>
Result<T> mode_key(const SpecContext& c, const SpecNode& node, const std::string& path,
                   const std::array<T, N>& modes) {
  return read_key<T>(c, node, path, "mode", std::nullopt,
                     [&](const SpecNode& value, const std::string& p) -> Result<T> {
                       auto text = to_text(c, value, p);
                       if (!text) return std::move(text).error();
                       for (auto m : modes) {
                         if (to_string(m) == *text) return m;
                       }
                       return spec_error(
                           c, value, p,
                           fmt::format("unknown mode '{}' (known: {})", *text, list_names(modes)));
                     });
}

// The when of a scheduling form: `after_ms` / `wait_ms` set the delay, `after_milestone` /
// `wait_for` the milestone.
Result<void> parse_trigger(const SpecContext& c, const SpecNode& node, const std::string& path,
                           std::string_view form, Fault& f) {
  const SpecNode& value = *node.find(form);
  const std::string p = join_path(path, form);
  if (form == "after_ms" || form == "wait_ms") {
    auto d = to_ms(c, value, p, false);
    if (!d) return std::move(d).error();
    f.delay = *d;
  } else {
    auto m = parse_milestone_node(c, value, p);
    if (!m) return std::move(m).error();
    f.milestone = std::move(*m);
  }
  return ok();
}

// The keys of an effect mapping: its kind, `next` for per-exchange kinds, one per command-line
// argument (two for INDEX:SUB and KIND[=VALUE]) and `once` for the mailbox rules.
std::vector<std::string> effect_keys(FaultKind kind) {
  std::vector<std::string> keys{"kind"};
  if (is_per_exchange(kind)) keys.emplace_back("next");
  for (const auto& argument : arguments_of(kind)) {
    const auto names = argument_keys(argument.name);
    keys.insert(keys.end(), names.begin(), names.end());
  }
  if (kind == FaultKind::mailbox_abort || kind == FaultKind::mailbox_protocol_fault ||
      kind == FaultKind::soe_fault || kind == FaultKind::eoe_fault ||
      kind == FaultKind::voe_fault) {
    keys.emplace_back("once");
  }
  return keys;
}

Result<void> check_keys_list(const SpecContext& c, const SpecNode& node, const std::string& path,
                             const std::vector<std::string>& known) {
  for (const auto& [key, value] : node.entries) {
    if (std::find(known.begin(), known.end(), key) != known.end()) continue;
    std::string list;
    for (const auto& k : known)
      list += (list.empty() ? "" : ", ") + k;
    return spec_error(c, value, join_path(path, key), fmt::format("unknown key (known: {})", list));
  }
  return ok();
}

Result<Fault> parse_effect(const SpecContext& c, const SpecNode& node, const std::string& path,
                           bool in_script) {
  const SpecNode* kind_node = node.find("kind");
  const std::string kind_path = join_path(path, "kind");
  auto kind_text = to_text(c, *kind_node, kind_path);
  if (!kind_text) return std::move(kind_text).error();
  const auto kind = fault_kind_from_string(*kind_text);
  if (!kind) {
    return spec_error(c, *kind_node, kind_path, unknown_kind(*kind_text));
  }
  if (auto r = check_keys_list(c, node, path, effect_keys(*kind)); !r) return std::move(r).error();
  Fault f = make(*kind);
  FaultEffect& e = f.effect;
#define ECAT_TRY(var, expr) \
  auto var = (expr);        \
  if (!var) return std::move(var).error();
  if (needs_slave(*kind)) {
    ECAT_TRY(slave, slave_name(c, node, path));
    e.slave = std::move(*slave);
  }
  constexpr std::int64_t kMaxDelta = 0xFFFF;
  switch (*kind) {
    case FaultKind::wkc_offset:
    case FaultKind::logical_wkc_offset: {
      ECAT_TRY(delta, int_key<std::int64_t>(c, node, path, "delta", -kMaxDelta, kMaxDelta));
      e.delta = *delta;
      break;
    }
    case FaultKind::command_wkc_offset: {
      ECAT_TRY(command_node, require(c, node, path, "command"));
      const std::string p = join_path(path, "command");
      ECAT_TRY(text, to_text(c, **command_node, p));
      const auto command = command_from_string(*text);
      if (!command || *command == wire::Command::nop) {
        return spec_error(c, **command_node, p,
                          fmt::format("unknown command '{}' (known: APRD, APWR, APRW, FPRD, "
                                      "FPWR, FPRW, BRD, BWR, BRW, LRD, LWR, LRW, ARMW, FRMW)",
                                      *text));
      }
      e.command = *command;
      ECAT_TRY(delta, int_key<std::int64_t>(c, node, path, "delta", -kMaxDelta, kMaxDelta));
      e.delta = *delta;
      break;
    }
    case FaultKind::truncate_reply: {
      ECAT_TRY(bytes, int_key<std::uint32_t>(c, node, path, "bytes", 1, wire::kMaxFrameSize,
                                             std::uint32_t{1}));
      e.bytes = *bytes;
      break;
    }
    case FaultKind::unsupported_type: {
      ECAT_TRY(type, int_key<std::uint8_t>(c, node, path, "type", 0, 15, std::uint8_t{0}));
      if (*type == wire::kFrameTypeDatagrams) {
        return spec_error(c, *node.find("type"), join_path(path, "type"),
                          "type 1 is the supported type (datagrams); use 0 or 2..15");
      }
      e.frame_type = *type;
      break;
    }
    case FaultKind::corrupt_byte: {
      ECAT_TRY(offset, int_key<std::uint32_t>(c, node, path, "offset", 0, wire::kMaxFrameSize,
                                              std::uint32_t{12}));
      ECAT_TRY(mask, int_key<std::uint8_t>(c, node, path, "mask", 1, 255, std::uint8_t{0xFF}));
      e.offset = *offset;
      e.mask = *mask;
      break;
    }
    case FaultKind::delay_replies: {
      ECAT_TRY(ms_node, require(c, node, path, "ms"));
      ECAT_TRY(delay, to_ms(c, **ms_node, join_path(path, "ms"), true));
      e.ns = delay->count();
      break;
    }
    case FaultKind::latch_al_error: {
      ECAT_TRY(code, int_key<std::uint32_t>(c, node, path, "code", 0, 0xFFFF));
      e.code = *code;
      break;
    }
    case FaultKind::refuse_state: {
      ECAT_TRY(state_node, require(c, node, path, "state"));
      const std::string p = join_path(path, "state");
      ECAT_TRY(text, to_text(c, **state_node, p));
      const auto state = al_state_from_name(*text);
      if (!state) {
        return spec_error(c, **state_node, p,
                          fmt::format("unknown AL state '{}' (known: init, preop, bootstrap, "
                                      "safeop, op)",
                                      *text));
      }
      e.state = *state;
      ECAT_TRY(code, int_key<std::uint32_t>(c, node, path, "code", 1, 0xFFFF));
      e.code = *code;
      break;
    }
    case FaultKind::mailbox_abort:
    case FaultKind::mailbox_protocol_fault: {
      ECAT_TRY(index, int_key<std::uint16_t>(c, node, path, "index", 0, 0xFFFF));
      ECAT_TRY(sub, int_key<std::uint8_t>(c, node, path, "subindex", 0, 0xFF));
      e.index = *index;
      e.subindex = *sub;
      const bool abort = *kind == FaultKind::mailbox_abort;
      ECAT_TRY(stage, stage_key(c, node, path, "stage",
                                abort ? std::optional(MailboxStage::request) : std::nullopt));
      e.stage = *stage;
      if (abort) {
        ECAT_TRY(code, int_key<std::uint32_t>(c, node, path, "code", 0, 0xFFFFFFFF));
        e.code = *code;
      } else {
        ECAT_TRY(protocol_node, require(c, node, path, "protocol"));
        const std::string p = join_path(path, "protocol");
        ECAT_TRY(text, to_text(c, **protocol_node, p));
        const auto protocol = protocol_kind_from_string(*text);
        if (!protocol) {
          return spec_error(c, **protocol_node, p,
                            fmt::format("unknown protocol fault '{}' (known: {})", *text,
                                        list_names(kProtocolKinds)));
        }
        e.protocol.kind = *protocol;
        if (protocol_has_value(*protocol)) {
          ECAT_TRY(value,
                   int_key<std::uint8_t>(c, node, path, "value", 0, protocol_value_max(*protocol)));
          e.protocol.value = *value;
        } else if (const SpecNode* v = node.find("value")) {
          return spec_error(c, *v, join_path(path, "value"),
                            fmt::format("{} takes no value", to_string(*protocol)));
        }
        if (!protocol_stage_valid(e.protocol.kind, e.stage)) {
          return spec_error(c, *node.find("stage"), join_path(path, "stage"),
                            fmt::format("{} cannot apply at stage {}", to_string(e.protocol.kind),
                                        to_string(e.stage)));
        }
      }
      if (const SpecNode* once = node.find("once")) {
        ECAT_TRY(value, to_bool(c, *once, join_path(path, "once")));
        e.once = *value;
      }
      break;
    }
    case FaultKind::dc_jump: {
      constexpr std::int64_t kMaxJump = 1'000'000'000'000;  // 1000 s
      ECAT_TRY(ns, int_key<std::int64_t>(c, node, path, "ns", -kMaxJump, kMaxJump));
      e.ns = *ns;
      break;
    }
    case FaultKind::link_down:
    case FaultKind::link_up: {
      ECAT_TRY(port, int_key<std::uint8_t>(c, node, path, "port", 0, 3));
      e.port = *port;
      break;
    }
    case FaultKind::ring_break: {
      ECAT_TRY(after, int_key<std::uint32_t>(c, node, path, "after", 1, 4095));
      e.after = *after;
      break;
    }
    case FaultKind::ring_cut: {
      ECAT_TRY(port, master_port_key(c, node, path, "port"));
      e.master_port = **port;
      break;
    }
    case FaultKind::port_delay: {
      ECAT_TRY(port, master_port_key(c, node, path, "port"));
      e.master_port = **port;
      ECAT_TRY(ms_node, require(c, node, path, "ms"));
      ECAT_TRY(delay, to_ms(c, **ms_node, join_path(path, "ms"), false));
      e.ns = delay->count();
      if (node.find("from") != nullptr) {
        ECAT_TRY(from, master_port_key(c, node, path, "from"));
        e.from = *from;
      }
      break;
    }
    case FaultKind::hot_plug:
    case FaultKind::hot_unplug: {
      ECAT_TRY(group_node, require(c, node, path, "group"));
      ECAT_TRY(group, to_text(c, **group_node, join_path(path, "group")));
      if (group->empty()) {
        return spec_error(c, **group_node, join_path(path, "group"), "empty group name");
      }
      e.group = std::move(*group);
      break;
    }
    case FaultKind::foe_fault: {
      ECAT_TRY(mode, mode_key(c, node, path, kFoeModes));
      e.foe = *mode;
      ECAT_TRY(packet,
               int_key<std::uint32_t>(c, node, path, "packet", 0, 0xFFFF'FFFF, std::uint32_t{0}));
      e.packet = *packet;
      if (e.foe == FoeFaultMode::error) {
        ECAT_TRY(code, int_key<std::uint32_t>(
                           c, node, path, "value", 0, 0xFFFF'FFFF,
                           static_cast<std::uint32_t>(wire::FoeErrorCode::not_defined)));
        e.value = *code;
      } else if (e.foe == FoeFaultMode::busy) {
        ECAT_TRY(count,
                 int_key<std::uint32_t>(c, node, path, "value", 1, 0xFFFF, std::uint32_t{1}));
        e.value = *count;
      } else if (const SpecNode* v = node.find("value")) {
        return spec_error(c, *v, join_path(path, "value"),
                          fmt::format("{} takes no value", to_string(e.foe)));
      }
      break;
    }
    case FaultKind::soe_fault: {
      ECAT_TRY(mode, mode_key(c, node, path, kSoeModes));
      e.soe = *mode;
      ECAT_TRY(idn, int_key<std::uint16_t>(c, node, path, "idn", 0, 0xFFFF));
      e.idn = *idn;
      if (e.soe == SoeFaultKind::drop_response) {
        if (const SpecNode* v = node.find("value")) {
          return spec_error(c, *v, join_path(path, "value"), "drop_response takes no value");
        }
      } else {
        const bool fragment = e.soe == SoeFaultKind::drop_fragment;
        ECAT_TRY(value, int_key<std::uint32_t>(c, node, path, "value", fragment ? 1 : 0, 0xFFFF));
        e.value = *value;
      }
      ECAT_TRY(drive, int_key<std::uint8_t>(c, node, path, "drive", 0, 7, std::uint8_t{0}));
      e.drive = *drive;
      if (const SpecNode* w = node.find("write")) {
        ECAT_TRY(write, to_bool(c, *w, join_path(path, "write")));
        e.write = *write;
      }
      break;
    }
    case FaultKind::eoe_fault: {
      ECAT_TRY(mode, mode_key(c, node, path, kEoeModes));
      e.eoe = *mode;
      if (e.eoe == EoeFaultKind::drop_reply) {
        if (const SpecNode* v = node.find("value")) {
          return spec_error(c, *v, join_path(path, "value"), "drop_reply takes no value");
        }
      } else {
        const bool offset = e.eoe == EoeFaultKind::corrupt_fragment_offset;
        ECAT_TRY(value, int_key<std::uint32_t>(c, node, path, "value", offset ? 1 : 0, 63,
                                               offset ? std::optional<std::uint32_t>()
                                                      : std::optional<std::uint32_t>(0)));
        e.value = *value;
      }
      break;
    }
    case FaultKind::voe_fault: {
      ECAT_TRY(mode, mode_key(c, node, path, kVoeModes));
      e.voe = *mode;
      break;
    }
    default:
      break;
  }
  if (takes_port(*kind) && node.find("port") != nullptr) {
    ECAT_TRY(port, master_port_key(c, node, path, "port"));
    e.on_port = *port;
  }
  if (is_protocol_kind(*kind)) {
    if (const SpecNode* once = node.find("once")) {
      ECAT_TRY(value, to_bool(c, *once, join_path(path, "once")));
      e.once = *value;
    }
  }
  if (const SpecNode* next = node.find("next")) {
    ECAT_TRY(n, to_int(c, *next, join_path(path, "next"), 1, 1'000'000'000));
    f.exchanges = static_cast<std::uint64_t>(*n);
  }
#undef ECAT_TRY
  (void)in_script;
  return f;
}

Result<Fault> parse_at(const SpecContext& c, const SpecNode& node, const std::string& path,
                       bool in_script, int depth) {
  if (depth > 32) return spec_error(c, node, path, "faults nested deeper than 32 levels");
  if (node.is_scalar()) {
    // A bare kind: "drop_responses" in a script.
    SpecNode mapping;
    mapping.type = SpecNode::Type::mapping;
    mapping.line = node.line;
    mapping.entries.emplace_back("kind", node);
    return parse_at(c, mapping, path, in_script, depth);
  }
  if (!node.is_mapping()) {
    return spec_error(c, node, path,
                      fmt::format("expected a fault (a mapping), found {}", type_name(node)));
  }
  constexpr std::array<std::string_view, 6> kForms{"kind",   "after_ms", "after_milestone",
                                                   "script", "wait_ms",  "wait_for"};
  std::string_view form;
  for (auto key : kForms) {
    if (node.find(key) == nullptr) continue;
    if (!form.empty()) {
      return spec_error(c, node, path,
                        fmt::format("'{}' and '{}' cannot be combined: one fault form per "
                                    "mapping",
                                    form, key));
    }
    form = key;
  }
  if (form.empty()) {
    return spec_error(c, node, path,
                      "a fault needs one of: kind, after_ms, after_milestone, script (wait_ms, "
                      "wait_for inside scripts)");
  }
  if (form == "kind") return parse_effect(c, node, path, in_script);
  if (form == "wait_ms" || form == "wait_for") {
    if (!in_script) {
      return spec_error(c, node, join_path(path, form), "only valid as a script step");
    }
    if (auto r = check_keys(c, node, path, {form}); !r) return std::move(r).error();
    Fault f;
    f.form = form == "wait_ms" ? Fault::Form::wait : Fault::Form::wait_for;
    if (auto r = parse_trigger(c, node, path, form, f); !r) return std::move(r).error();
    return f;
  }
  if (form == "script") {
    if (auto r = check_keys(c, node, path, {"script"}); !r) return std::move(r).error();
    const SpecNode& list = *node.find("script");
    const std::string p = join_path(path, "script");
    if (!list.is_sequence() || list.items.empty()) {
      return spec_error(c, list, p, "expected a non-empty list of steps");
    }
    Fault f;
    f.form = Fault::Form::script;
    for (std::size_t i = 0; i < list.items.size(); ++i) {
      auto step = parse_at(c, list.items[i], index_path(p, i), true, depth + 1);
      if (!step) return step;
      f.steps.push_back(std::move(*step));
    }
    return f;
  }
  // after_ms / after_milestone
  if (auto r = check_keys(c, node, path, {form, "fault"}); !r) return std::move(r).error();
  Fault f;
  f.form = form == "after_ms" ? Fault::Form::after_delay : Fault::Form::after_milestone;
  if (auto r = parse_trigger(c, node, path, form, f); !r) return std::move(r).error();
  auto child_node = require(c, node, path, "fault");
  if (!child_node) return std::move(child_node).error();
  auto child = parse_at(c, **child_node, join_path(path, "fault"), in_script, depth + 1);
  if (!child) return child;
  f.steps.push_back(std::move(*child));
  return f;
}

}  // namespace

Result<Milestone> parse_milestone_node(const SpecContext& c, const SpecNode& node,
                                       const std::string& path) {
  if (auto r = check_keys(c, node, path, {"milestone", "slave", "step", "count"}); !r) {
    return std::move(r).error();
  }
  auto kind_node = require(c, node, path, "milestone");
  if (!kind_node) return std::move(kind_node).error();
  const std::string kp = join_path(path, "milestone");
  auto text = to_text(c, **kind_node, kp);
  if (!text) return std::move(text).error();
  Milestone m;
  if (*text == "healthy_exchanges") {
    m.kind = Milestone::Kind::healthy_exchanges;
  } else if (*text == "healthy_polls") {
    m.kind = Milestone::Kind::healthy_polls;
  } else if (*text == "mailbox_step") {
    m.kind = Milestone::Kind::mailbox_step;
  } else {
    return spec_error(c, **kind_node, kp,
                      fmt::format("unknown milestone '{}' (known: healthy_exchanges, "
                                  "healthy_polls, mailbox_step)",
                                  *text));
  }
  if (m.kind == Milestone::Kind::healthy_exchanges) {
    if (const SpecNode* s = node.find("slave")) {
      return spec_error(c, *s, join_path(path, "slave"), "healthy_exchanges takes no slave");
    }
  } else {
    auto slave = slave_name(c, node, path);
    if (!slave) return std::move(slave).error();
    m.slave = std::move(*slave);
  }
  if (m.kind == Milestone::Kind::mailbox_step) {
    auto step = stage_key(c, node, path, "step", std::nullopt);
    if (!step) return std::move(step).error();
    if (*step == MailboxStage::request) {
      return spec_error(c, *node.find("step"), join_path(path, "step"),
                        "a step is upload_init, upload_segment, download_init or "
                        "download_segment");
    }
    m.step = *step;
  } else if (const SpecNode* s = node.find("step")) {
    return spec_error(c, *s, join_path(path, "step"),
                      fmt::format("{} takes no step", to_string(m.kind)));
  }
  auto count = int_key<std::uint64_t>(c, node, path, "count", 1, 1'000'000'000);
  if (!count) return std::move(count).error();
  m.count = *count;
  return m;
}

Result<Fault> parse_fault_node(const SpecContext& context, const SpecNode& node,
                               const std::string& path) {
  auto f = parse_at(context, node, path, false, 0);
  if (!f) return f;
  if (auto r = validate(*f); !r) {
    return spec_error(context, node, path, r.error().message());
  }
  return f;
}

}  // namespace detail

std::string to_json(const Fault& fault) {
  std::string out;
  detail::append_fault_json(out, fault);
  return out;
}

Result<Fault> parse_fault_json(std::string_view json) {
  auto tree = detail::parse_json(json);
  if (!tree) return std::move(tree).error();
  return detail::parse_fault_node(detail::SpecContext{}, *tree, "fault");
}

// ---- Command-line words ---------------------------------------------------------------------

Result<Fault> parse_fault_words(std::span<const std::string> words) {
  using detail::SpecNode;
  if (words.empty()) {
    return Error(Errc::invalid_argument, "no fault kind given (see `ecat sim fault kinds`)");
  }
  const auto kind = fault_kind_from_string(words[0]);
  if (!kind) {
    return Error(Errc::invalid_argument, unknown_kind(words[0]));
  }
  const auto& info = fault_kinds()[static_cast<std::size_t>(*kind)];
  const auto usage = [&] {
    return fmt::format("usage: {}{}{}", words[0], info.arguments.empty() ? "" : " ",
                       info.arguments);
  };
  const auto arguments = arguments_of(*kind);
  std::size_t required = 0;
  for (const auto& argument : arguments)
    required += argument.optional ? 0 : 1;
  const std::size_t given = words.size() - 1;
  if (given < required || given > arguments.size()) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: expected {} argument{}, got {} ({})", words[0],
                             required == arguments.size()
                                 ? fmt::format("{}", required)
                                 : fmt::format("{} to {}", required, arguments.size()),
                             arguments.size() == 1 ? "" : "s", given, usage()));
  }
  SpecNode node;
  node.type = SpecNode::Type::mapping;
  auto scalar = [](std::string text) {
    SpecNode n;
    n.type = SpecNode::Type::scalar;
    n.text = std::move(text);
    return n;
  };
  node.entries.emplace_back("kind", scalar(words[0]));
  for (std::size_t i = 0; i < given; ++i) {
    const std::string_view name = arguments[i].name;
    const std::string& word = words[i + 1];
    const auto keys = argument_keys(name);
    if (keys.size() == 1) {
      node.entries.emplace_back(keys[0], scalar(word));
      continue;
    }
    // INDEX:SUB and KIND[=VALUE]: two keys in one word (the second optional after '=').
    const char separator = name == "INDEX:SUB" ? ':' : '=';
    const auto split = word.find(separator);
    if (split == std::string::npos && separator == ':') {
      return Error(
          Errc::invalid_argument,
          fmt::format("{}: '{}' is not INDEX:SUB (e.g. 0x2000:1) ({})", words[0], word, usage()));
    }
    node.entries.emplace_back(keys[0], scalar(word.substr(0, split)));
    if (split != std::string::npos) {
      node.entries.emplace_back(keys[1], scalar(word.substr(split + 1)));
    }
  }
  auto fault = detail::parse_fault_node(detail::SpecContext{}, node, words[0]);
  if (!fault) {
    return Error(fault.error().code(), fmt::format("{} ({})", fault.error().message(), usage()));
  }
  return fault;
}

// ---- The injector ---------------------------------------------------------------------------

namespace {

struct ResolvedMilestone {
  Milestone::Kind kind = Milestone::Kind::healthy_exchanges;
  std::size_t slave = 0;
  MailboxStage step = MailboxStage::upload_init;
};

// The FoE server's rule for a foe_fault.
FoeFault foe_rule(const FaultEffect& e) {
  FoeFault f;
  f.after_packets = e.packet;
  switch (e.foe) {
    case FoeFaultMode::error:
      f.kind = FoeFaultKind::error;
      f.code = e.value;
      break;
    case FoeFaultMode::busy:
      f.kind = FoeFaultKind::busy;
      f.count = e.value;
      break;
    case FoeFaultMode::drop_reply:
      f.kind = FoeFaultKind::drop_reply;
      break;
    case FoeFaultMode::wrong_packet:
      f.kind = FoeFaultKind::wrong_packet;
      break;
    case FoeFaultMode::wrong_password:
      f.kind = FoeFaultKind::error;
      f.code = static_cast<std::uint32_t>(wire::FoeErrorCode::no_rights);
      break;
  }
  return f;
}

// The part the abort and protocol fault rules share: which object, at which stage, how often.
template <class Rule>
Rule mailbox_rule(const FaultEffect& e, bool once) {
  Rule rule;
  rule.index = e.index;
  rule.subindex = e.subindex;
  rule.stage = e.stage;
  rule.once = once;
  return rule;
}

// A standing mailbox rule as the effect that installed it (for info()).
template <class Rule>
FaultEffect rule_effect(FaultKind kind, std::string slave, const Rule& rule) {
  FaultEffect e;
  e.kind = kind;
  e.slave = std::move(slave);
  e.index = rule.index;
  e.subindex = rule.subindex;
  e.stage = rule.stage;
  e.once = rule.once;
  return e;
}

std::size_t stage_slot(MailboxStage stage) {
  return static_cast<std::size_t>(stage);
}

}  // namespace

struct FaultInjector::Impl {
  struct Countdown {
    FaultEffect effect;
    std::size_t slave = 0;
    std::uint64_t remaining = 0;
    std::uint64_t id = 0;
  };
  struct Sticky {
    FaultEffect effect;
    std::size_t slave = 0;
  };
  struct Step {
    Fault fault;
    bool in_script = false;
  };
  enum class Wait : std::uint8_t { none, timer, milestone, countdown };
  struct Task {
    std::uint64_t id = 0;
    std::string description;
    std::deque<Step> steps;
    std::size_t steps_started = 0;
    Wait wait = Wait::none;
    std::int64_t due_ns = 0;
    ResolvedMilestone milestone;
    std::string milestone_text;
    std::uint64_t remaining = 0;
    std::uint64_t countdown = 0;
  };
  // Everything that shapes one exchange, summed over sticky and queued faults.
  struct ExchangeState {
    bool drop = false;
    std::int64_t wkc_offset = 0;
    std::array<std::int64_t, wire::kCommandCount> command_offsets{};
    bool any_command_offset = false;
    std::vector<std::int64_t> logical;
    std::vector<std::uint8_t> disconnected;
    bool any_logical = false;
    bool any_disconnected = false;
    bool queued = false;  // a `next N` fault applies
    bool reply_faults = false;
    std::uint32_t truncate = 0;
    std::optional<std::uint8_t> frame_type;
    bool wrong_index = false;
    bool replay = false;
    bool duplicate = false;
    bool reorder = false;
    std::vector<std::pair<std::uint32_t, std::uint8_t>> corrupt;
    std::int64_t delay_ns = 0;

    void reset(std::size_t slaves) {
      drop = false;
      wkc_offset = 0;
      command_offsets.fill(0);
      any_command_offset = false;
      // Per slave: cleared only when the last exchange set one (an exchange without such a
      // fault costs nothing per slave).
      if (any_logical || logical.size() != slaves) logical.assign(slaves, 0);
      if (any_disconnected || disconnected.size() != slaves) disconnected.assign(slaves, 0);
      any_logical = false;
      any_disconnected = false;
      queued = false;
      reply_faults = false;
      truncate = 0;
      frame_type.reset();
      wrong_index = replay = duplicate = reorder = false;
      corrupt.clear();
      delay_ns = 0;
    }
    void add(const FaultEffect& e, std::size_t slave) {
      if (fault_class(e.kind) == FaultClass::reply) reply_faults = true;
      switch (e.kind) {
        case FaultKind::drop_responses:
          drop = true;
          break;
        case FaultKind::wkc_offset:
          wkc_offset += e.delta;
          break;
        case FaultKind::command_wkc_offset:
          command_offsets[static_cast<std::size_t>(e.command)] += e.delta;
          any_command_offset = true;
          break;
        case FaultKind::logical_wkc_offset:
          logical[slave] += e.delta;
          any_logical = true;
          break;
        case FaultKind::disconnect:
          disconnected[slave] = 1;
          any_disconnected = true;
          break;
        case FaultKind::truncate_reply:
          truncate = std::max(truncate, e.bytes);
          break;
        case FaultKind::unsupported_type:
          frame_type = e.frame_type;
          break;
        case FaultKind::wrong_index:
          wrong_index = true;
          break;
        case FaultKind::replay_previous:
          replay = true;
          break;
        case FaultKind::corrupt_byte:
          corrupt.emplace_back(e.offset, e.mask);
          break;
        case FaultKind::duplicate_reply:
          duplicate = true;
          break;
        case FaultKind::reorder_replies:
          reorder = true;
          break;
        case FaultKind::delay_replies:
          delay_ns = std::max(delay_ns, e.ns);
          break;
        default:
          break;
      }
    }
  };

  // ---- The cabling of a redundant segment ----
  // Which of the ring's cables are down: the cabling's own, and both ends of every unplugged
  // hot-connect group (its slaves are without power: no frame passes them).
  std::vector<bool> effective_down() const {
    const std::size_t n = segment.size();
    auto down = cables_down(cabling->topology, n);
    std::vector<bool> out = down ? std::move(*down) : std::vector<bool>(n + 1, false);
    const std::vector<bool> ring = ring_slaves();
    for (const auto& g : segment.hot_connect_groups()) {
      // A group on a branch (a junction port off the ring) is out of the segment's own cabling
      // when unplugged; the ring stays whole.
      if (g.plugged || g.first >= n || !ring[g.first]) continue;
      out[g.first] = true;
      out[std::min(g.first + g.slaves, n)] = true;
    }
    return out;
  }

  // The slaves the ring passes through: the last slave in frame order (whose port 1 is cabled to
  // the secondary port) and every slave on the way to it from the first. The others hang on
  // branches off the ring (junction ports whose subtree ends there): the cable into such a slave
  // is not one of the ring's, and neither master port reaches it when it is down.
  std::vector<bool> ring_slaves() const {
    const std::size_t n = segment.size();
    std::vector<bool> ring(n, false);
    std::optional<std::size_t> k;
    if (n > 0) k = n - 1;
    while (k && !ring[*k]) {
      ring[*k] = true;
      k = segment.parent(*k);
    }
    return ring;
  }

  // Errc::invalid_argument for a cable down (1 .. n-1, numbered by the slave it leads into)
  // that leads into a branch off the ring rather than along it.
  Result<void> check_ring_cables(const std::vector<bool>& down) const {
    const std::vector<bool> ring = ring_slaves();
    for (std::size_t k = 1; k < ring.size() && k < down.size(); ++k) {
      if (!down[k] || ring[k]) continue;
      const std::size_t parent = segment.parent(k).value_or(k - 1);
      return Error(Errc::invalid_argument,
                   fmt::format("cable {} leads into '{}' on port {} of '{}', a branch off the "
                               "ring, not a ring cable (take that link down instead: link_down "
                               "on '{}' port 0)",
                               k, segment.name(k), segment.parent_port(k), segment.name(parent),
                               segment.name(k)));
    }
    return ok();
  }

  // Sets one cable of the ring (0: the primary's, n: the secondary's) up or down.
  void set_cable(std::size_t cable, bool up) {
    const std::size_t n = segment.size();
    auto down = cables_down(cabling->topology, n);
    if (!down || cable > n) return;
    (*down)[cable] = !up;
    std::vector<std::size_t> list;
    for (std::size_t k = 0; k <= n; ++k) {
      if ((*down)[k]) list.push_back(k);
    }
    cabling->topology = RedundantTopology::cables_down(std::move(list), n);
  }

  // At every cabling change: the routes of the two master ports' frames, and the DL status the
  // slaves report for the ring's cables (Segment::set_reported_link): each end of a cable down
  // loses its link and closes its loop; the last slave's port 1 has a link while the secondary's
  // cable is in. Without a second master port the segment's cables speak for themselves again.
  void refresh_cabling() {
    const std::size_t n = segment.size();
    for (std::size_t i = 0; i < n; ++i) {
      for (std::uint8_t port = 0; port < 4; ++port)
        segment.set_reported_link(i, port, std::nullopt);
    }
    routes = {};
    if (!cabling || n == 0) return;
    const std::vector<bool> down = effective_down();
    routes[0] = route_redundant(down, wire::RedundantPort::primary);
    routes[1] = route_redundant(down, wire::RedundantPort::secondary);
    // Cable k (0 < k < n) leads into slave k's port 0 from its parent's port; only the ring's
    // (branches speak for themselves through the segment's cables). Cable n leaves the last
    // slave's port 1 for the secondary port.
    const std::vector<bool> ring = ring_slaves();
    segment.set_reported_link(0, 0, !down[0]);
    segment.set_reported_link(n - 1, 1, !down[n]);
    for (std::size_t cable = 1; cable < n; ++cable) {
      if (!ring[cable]) continue;
      segment.set_reported_link(segment.parent(cable).value_or(cable - 1),
                                segment.parent_port(cable), !down[cable]);
      segment.set_reported_link(cable, 0, !down[cable]);
    }
  }

  // The ring's cable at a slave's port on a redundant segment: port 0 of a slave on the ring
  // (the cable into it), the port of a slave on the ring that the next one along it hangs on,
  // the last slave's port 1 (the secondary's cable). Ports into branches are not the ring's.
  std::optional<std::size_t> ring_cable(std::size_t slave, std::uint8_t port) const {
    const std::size_t n = segment.size();
    if (!cabling || port > 3 || slave >= n) return std::nullopt;
    const std::vector<bool> ring = ring_slaves();
    if (!ring[slave]) return std::nullopt;
    if (port == 0) return slave;
    if (slave + 1 == n) return port == 1 ? std::optional<std::size_t>(n) : std::nullopt;
    for (std::size_t k = slave + 1; k < n; ++k) {
      if (ring[k] && segment.parent(k) == slave && segment.parent_port(k) == port) return k;
    }
    return std::nullopt;
  }

  // The cable into an unplugged group's first slave: the group, not a fault, holds it down.
  bool unplugged_cable(std::size_t slave, std::uint8_t port) const {
    if (port != 0) return false;
    for (const auto& g : segment.hot_connect_groups()) {
      if (g.first == slave && !g.plugged) return true;
    }
    return false;
  }

  Result<void> plug(std::string_view group, bool plugged, std::int64_t now_ns) {
    if (auto r = segment.plug(group, plugged, now_ns); !r) return r;
    if (plugged && !cabling) {
      // A link_down on the group's cable still holds it down: the group is in, its cable is not.
      for (const auto& g : segment.hot_connect_groups()) {
        if (g.name != group) continue;
        for (const auto& [slave, port] : links_down) {
          if (slave == g.first && port == 0) segment.set_link(slave, 0, false);
        }
      }
    }
    refresh_cabling();
    return ok();
  }

  explicit Impl(Segment& s) : segment(s) {
    const std::size_t n = segment.size();
    current.reset(n);
    poll_counts.assign(n, 0);
    step_counts.assign(n, {});
    latched.assign(n, std::nullopt);
    for (std::size_t i = 0; i < n; ++i) {
      if (CoeServer* coe = coe_server_of(segment.esc(i))) {
        coe->set_step_observer([this, i](MailboxStage stage, std::uint16_t, std::uint8_t) {
          ++step_counts[i][stage_slot(stage)];
          steps_counted = true;
        });
      }
    }
  }
  ~Impl() {
    for (std::size_t i = 0; i < segment.size(); ++i) {
      if (CoeServer* coe = coe_server_of(segment.esc(i))) coe->set_step_observer({});
    }
  }

  // ---- Resolution ----
  Result<std::size_t> find_slave(const std::string& name) const {
    if (auto index = segment.find(name)) return *index;
    std::string known;
    const std::size_t shown = std::min<std::size_t>(segment.size(), 16);
    for (std::size_t i = 0; i < shown; ++i)
      known += (i ? ", " : "") + segment.name(i);
    if (segment.size() > shown) known += ", ...";
    return Error(Errc::not_found, fmt::format("unknown slave '{}' (known: {})", name, known));
  }

  Result<void> check_effect(const FaultEffect& e) {
    if (e.on_port && !cabling) {
      return Error(Errc::unsupported,
                   fmt::format("{} at the {} port: the segment has no second master port",
                               to_string(e.kind), wire::to_string(*e.on_port)));
    }
    if (e.kind == FaultKind::ring_break || e.kind == FaultKind::ring_cut ||
        e.kind == FaultKind::ring_heal || e.kind == FaultKind::port_delay) {
      if (!cabling) {
        return Error(Errc::unsupported,
                     fmt::format("{}: the segment has no second master port (serve it redundantly: "
                                 "ecat sim --redundant-interface, sim::RedundantPorts)",
                                 to_string(e.kind)));
      }
      if (e.kind == FaultKind::ring_break) {
        auto down = cables_down(RedundantTopology::broken_after(e.after), segment.size());
        if (!down) return Error(down.error().code(), "ring_break: " + down.error().message());
        if (auto r = check_ring_cables(*down); !r) {
          return Error(r.error().code(), "ring_break: " + r.error().message());
        }
      }
      return ok();
    }
    if (e.kind == FaultKind::hot_plug || e.kind == FaultKind::hot_unplug) {
      const auto groups = segment.hot_connect_groups();
      std::string known;
      for (const auto& g : groups) {
        if (g.name == e.group) return ok();
        known += (known.empty() ? "" : ", ") + g.name;
      }
      return Error(Errc::not_found,
                   fmt::format("{}: unknown hot-connect group '{}' (known: {})", to_string(e.kind),
                               e.group, known.empty() ? "none" : known));
    }
    if (!needs_slave(e.kind)) return ok();
    auto index = find_slave(e.slave);
    if (!index) return std::move(index).error();
    Esc& esc = segment.esc(*index);
    if ((e.kind == FaultKind::mailbox_abort || e.kind == FaultKind::mailbox_protocol_fault) &&
        coe_server_of(esc) == nullptr) {
      return Error(Errc::unsupported,
                   fmt::format("{}: slave '{}' has no CoE mailbox", to_string(e.kind), e.slave));
    }
    const auto missing = [&](std::string_view what) {
      return Error(Errc::unsupported,
                   fmt::format("{}: slave '{}' has no {}", to_string(e.kind), e.slave, what));
    };
    if (e.kind == FaultKind::foe_fault && foe_server_of(esc) == nullptr) return missing("FoE");
    if (e.kind == FaultKind::soe_fault && soe_server_of(esc) == nullptr) return missing("SoE");
    if (e.kind == FaultKind::eoe_fault && eoe_server_of(esc) == nullptr) return missing("EoE");
    if (e.kind == FaultKind::voe_fault) {
      const CoeServer* coe = coe_server_of(esc);
      if (coe == nullptr || !coe->has_protocol_handler(wire::MailboxType::voe)) {
        return missing("VoE");
      }
    }
    if (e.kind == FaultKind::dc_jump && esc.dc() == nullptr) {
      return Error(Errc::unsupported, fmt::format("dc_jump: slave '{}' has no DC unit", e.slave));
    }
    return ok();
  }

  Result<void> check_milestone(const Milestone& m) {
    if (m.kind == Milestone::Kind::healthy_exchanges) return ok();
    auto index = find_slave(m.slave);
    if (!index) return std::move(index).error();
    if (m.kind == Milestone::Kind::mailbox_step && coe_server_of(segment.esc(*index)) == nullptr) {
      return Error(Errc::unsupported,
                   fmt::format("mailbox_step: slave '{}' has no CoE mailbox", m.slave));
    }
    return ok();
  }

  Result<void> check(const Fault& f) {
    switch (f.form) {
      case Fault::Form::effect:
        return check_effect(f.effect);
      case Fault::Form::after_milestone:
      case Fault::Form::wait_for:
        if (auto r = check_milestone(f.milestone); !r) return r;
        break;
      default:
        break;
    }
    for (const auto& step : f.steps) {
      if (auto r = check(step); !r) return r;
    }
    return ok();
  }

  std::size_t slave_index(const std::string& name) const { return segment.find(name).value_or(0); }

  ResolvedMilestone resolve(const Milestone& m) const {
    ResolvedMilestone r;
    r.kind = m.kind;
    r.step = m.step;
    if (m.kind != Milestone::Kind::healthy_exchanges) r.slave = slave_index(m.slave);
    return r;
  }

  // ---- Activation ----
  void apply_once(const FaultEffect& e, bool in_script) {
    ++stats->faults_activated;
    const std::size_t slave = needs_slave(e.kind) ? slave_index(e.slave) : 0;
    switch (e.kind) {
      case FaultKind::retreat_to_safeop: {
        Esc& esc = segment.esc(slave);
        if (esc.al_state() != wire::AlState::op) break;
        // Through the firmware, so that the outputs go to their safe state as on a real drop;
        // then without the error indicator, as the reference simulator does it.
        if (auto* app = dynamic_cast<StandardApplication*>(&esc.application())) {
          app->raise_al_error(esc, 0, wire::AlState::safeop);
        }
        esc.pdi_set_al_status(wire::AlState::safeop, false, 0);
        break;
      }
      case FaultKind::power_cycle: {
        Esc& esc = segment.esc(slave);
        if (CoeServer* coe = coe_server_of(esc)) coe->clear_faults();
        esc.power_cycle(now);
        latched[slave].reset();
        break;
      }
      case FaultKind::latch_al_error: {
        Esc& esc = segment.esc(slave);
        const auto code = static_cast<std::uint16_t>(e.code);
        if (auto* app = dynamic_cast<StandardApplication*>(&esc.application())) {
          app->raise_al_error(esc, code, esc.al_state());
        } else {
          esc.pdi_set_al_status(esc.al_state(), true, code);
        }
        latched[slave] = code;
        break;
      }
      case FaultKind::refuse_state: {
        segment.esc(slave).set_al_refusal(e.state, static_cast<std::uint16_t>(e.code));
        const auto key = std::make_pair(slave, e.state);
        if (std::find(refusals.begin(), refusals.end(), key) == refusals.end()) {
          refusals.push_back(key);
        }
        break;
      }
      case FaultKind::mailbox_abort: {
        auto rule = mailbox_rule<SdoAbortRule>(e, e.once.value_or(false));
        rule.code = e.code;
        if (CoeServer* coe = coe_server_of(segment.esc(slave))) coe->add_abort_rule(rule);
        break;
      }
      case FaultKind::mailbox_protocol_fault: {
        auto rule = mailbox_rule<ProtocolFaultRule>(e, e.once.value_or(in_script));
        rule.fault = e.protocol;
        if (CoeServer* coe = coe_server_of(segment.esc(slave))) coe->add_protocol_fault(rule);
        break;
      }
      case FaultKind::dc_jump:
        if (DcUnit* dc = segment.esc(slave).dc()) dc->jump(e.ns);
        break;
      case FaultKind::foe_fault:
        if (FoeServer* foe = foe_server_of(segment.esc(slave))) foe->add_fault(foe_rule(e));
        break;
      case FaultKind::soe_fault:
        if (SoeServer* soe = soe_server_of(segment.esc(slave))) {
          soe->add_fault(SoeFaultRule{e.drive, e.idn, e.write, e.soe,
                                      static_cast<std::uint16_t>(e.value), e.once.value_or(true)});
        }
        break;
      case FaultKind::eoe_fault:
        if (EoeServer* eoe = eoe_server_of(segment.esc(slave))) {
          eoe->add_fault(
              EoeFaultRule{e.eoe, static_cast<std::uint8_t>(e.value), e.once.value_or(true)});
        }
        break;
      case FaultKind::voe_fault:
        if (CoeServer* coe = coe_server_of(segment.esc(slave))) {
          coe->add_handler_fault(
              HandlerFaultRule{wire::MailboxType::voe, e.voe, e.once.value_or(true)});
        }
        break;
      case FaultKind::link_down:
      case FaultKind::link_up: {
        const bool up = e.kind == FaultKind::link_up;
        if (const auto cable = ring_cable(slave, e.port)) {
          // A redundant ring: the port closes its loop and the ring turns round there.
          set_cable(*cable, up);
          refresh_cabling();
          break;
        }
        if (!up || !unplugged_cable(slave, e.port)) segment.set_link(slave, e.port, up);
        const auto key = std::make_pair(slave, e.port);
        auto it = std::find(links_down.begin(), links_down.end(), key);
        if (!up && it == links_down.end()) links_down.push_back(key);
        if (up && it != links_down.end()) links_down.erase(it);
        break;
      }
      case FaultKind::master_link_down:
      case FaultKind::master_link_up: {
        const bool up = e.kind == FaultKind::master_link_up;
        if (cabling) {
          // The primary's cable of a redundant ring.
          set_cable(0, up);
          refresh_cabling();
          break;
        }
        segment.set_master_link(up);
        master_down = !up;
        break;
      }
      case FaultKind::hot_plug:
      case FaultKind::hot_unplug:
        // Checked at injection; groups never change while the injector exists.
        (void)plug(e.group, e.kind == FaultKind::hot_plug, now);
        break;
      // Checked at injection; a detached ring (the ports gone meanwhile) ignores them.
      case FaultKind::ring_break:
        if (cabling) cabling->topology = RedundantTopology::broken_after(e.after);
        refresh_cabling();
        break;
      case FaultKind::ring_cut:
        if (cabling) cabling->topology = RedundantTopology::cut_at(e.master_port);
        refresh_cabling();
        break;
      case FaultKind::ring_heal:
        if (cabling) cabling->topology = RedundantTopology::whole_ring();
        refresh_cabling();
        break;
      case FaultKind::port_delay:
        if (cabling) {
          cabling->delays[static_cast<std::size_t>(e.master_port)] =
              RedundantPortDelay{std::chrono::nanoseconds(e.ns), e.from};
        }
        break;
      default:
        break;
    }
  }

  // Returns the id of the countdown it queued (0: none).
  std::uint64_t activate_effect(const Fault& f, bool in_script) {
    const FaultEffect& e = f.effect;
    if (!is_per_exchange(e.kind)) {
      apply_once(e, in_script);
      return 0;
    }
    ++stats->faults_activated;
    const std::size_t slave = needs_slave(e.kind) ? slave_index(e.slave) : 0;
    if (f.exchanges == 0 && !in_script) {
      sticky.push_back(Sticky{e, slave});
      return 0;
    }
    Countdown c;
    c.effect = e;
    c.slave = slave;
    c.remaining = f.exchanges == 0 ? 1 : f.exchanges;
    c.id = ++next_id;
    countdowns.push_back(std::move(c));
    return countdowns.back().id;
  }

  void start_wait_milestone(Task& task, const Milestone& m) {
    task.wait = Wait::milestone;
    task.milestone = resolve(m);
    task.milestone_text = describe(m);
    task.remaining = m.count;
  }

  // Runs a task's steps until it waits or ends. Returns false when it has ended.
  bool run(Task& task) {
    while (task.wait == Wait::none && !task.steps.empty()) {
      Step step = std::move(task.steps.front());
      task.steps.pop_front();
      const Fault& f = step.fault;
      // Count what a reader sees as a step: faults and waits, not the forms that expand.
      if (f.form == Fault::Form::effect || f.form == Fault::Form::wait ||
          f.form == Fault::Form::wait_for) {
        ++task.steps_started;
      }
      switch (f.form) {
        case Fault::Form::effect: {
          const std::uint64_t id = activate_effect(f, step.in_script);
          if (id != 0 && step.in_script) {
            task.wait = Wait::countdown;
            task.countdown = id;
          }
          break;
        }
        case Fault::Form::after_delay:
          task.steps.push_front(Step{f.steps.at(0), step.in_script});
          if (f.delay.count() > 0) {
            task.wait = Wait::timer;
            task.due_ns = now + f.delay.count();
          }
          break;
        case Fault::Form::after_milestone:
          task.steps.push_front(Step{f.steps.at(0), step.in_script});
          start_wait_milestone(task, f.milestone);
          break;
        case Fault::Form::script:
          for (auto it = f.steps.rbegin(); it != f.steps.rend(); ++it) {
            task.steps.push_front(Step{*it, true});
          }
          break;
        case Fault::Form::wait:
          if (f.delay.count() > 0) {
            task.wait = Wait::timer;
            task.due_ns = now + f.delay.count();
          }
          break;
        case Fault::Form::wait_for:
          start_wait_milestone(task, f.milestone);
          break;
      }
    }
    return task.wait != Wait::none || !task.steps.empty();
  }

  void run_ready() {
    // Tasks may be appended while running (never by run() itself), so index, don't iterate.
    for (std::size_t i = 0; i < tasks.size();) {
      if (tasks[i].wait == Wait::none && !run(tasks[i])) {
        tasks.erase(tasks.begin() + static_cast<std::ptrdiff_t>(i));
      } else {
        ++i;
      }
    }
  }

  void advance(std::int64_t now_ns) {
    now = std::max(now, now_ns);
    bool woke = false;
    for (auto& task : tasks) {
      if (task.wait == Wait::timer && task.due_ns <= now) {
        task.wait = Wait::none;
        woke = true;
      }
    }
    if (woke) run_ready();
  }

  // ---- Exchanges ----
  // Whether a fault acts on this exchange: one naming a master port only on the frames whose
  // reply arrives there.
  bool applies(const FaultEffect& e) const {
    return !e.on_port || (exchange_port && *e.on_port == *exchange_port);
  }

  void begin_exchange() {
    current.reset(segment.size());
    for (const auto& s : sticky) {
      if (applies(s.effect)) current.add(s.effect, s.slave);
    }
    for (auto& c : countdowns) {
      if (!applies(c.effect)) continue;
      current.add(c.effect, c.slave);
      current.queued = true;
      --c.remaining;
    }
    std::erase_if(countdowns, [](const Countdown& c) { return c.remaining == 0; });
    ++stats->exchanges;
  }

  void end_exchange(bool healthy) {
    if (healthy) ++stats->healthy_exchanges;
    bool woke = false;
    for (auto& task : tasks) {
      if (task.wait == Wait::countdown) {
        const bool pending =
            std::any_of(countdowns.begin(), countdowns.end(),
                        [&](const Countdown& c) { return c.id == task.countdown; });
        if (!pending) {
          task.wait = Wait::none;
          woke = true;
        }
        continue;
      }
      if (task.wait != Wait::milestone) continue;
      std::uint64_t events = 0;
      switch (task.milestone.kind) {
        case Milestone::Kind::healthy_exchanges:
          events = healthy ? 1 : 0;
          break;
        case Milestone::Kind::healthy_polls:
          events = poll_counts[task.milestone.slave];
          break;
        case Milestone::Kind::mailbox_step:
          events = step_counts[task.milestone.slave][stage_slot(task.milestone.step)];
          break;
      }
      task.remaining -= std::min(task.remaining, events);
      if (task.remaining == 0) {
        task.wait = Wait::none;
        woke = true;
      }
    }
    if (polls_counted) std::fill(poll_counts.begin(), poll_counts.end(), 0);
    if (steps_counted) {
      for (auto& counts : step_counts)
        counts.fill(0);
    }
    polls_counted = steps_counted = false;
    if (woke) run_ready();
  }

  // Counts healthy AL status polls in a processed frame.
  void count_polls(std::span<const std::uint8_t> frame) {
    // Only a task waiting for healthy polls reads the counts.
    const bool wanted = std::any_of(tasks.begin(), tasks.end(), [](const Task& t) {
      return t.wait == Wait::milestone && t.milestone.kind == Milestone::Kind::healthy_polls;
    });
    if (!wanted) return;
    const auto decoded = wire::decode_frame(frame);
    if (!decoded) return;
    for (const wire::DatagramView d : *decoded.frame) {
      if (d.header.command != wire::Command::fprd || d.wkc == 0) continue;
      const std::uint32_t first = d.header.ado();
      const std::uint32_t end = first + d.header.length;
      if (first > wire::reg::kAlStatus || end < wire::reg::kAlStatus + 2u) continue;
      const std::uint8_t status = d.data[wire::reg::kAlStatus - first];
      if ((status & 0x0F) != static_cast<std::uint8_t>(wire::AlState::op) ||
          (status & wire::kAlStatusError) != 0) {
        continue;
      }
      for (std::size_t i = 0; i < segment.size(); ++i) {
        if (segment.esc(i).station_address() == d.header.adp()) {
          ++poll_counts[i];
          polls_counted = true;
          break;
        }
      }
    }
  }

  Segment& segment;
  FaultStats* stats = nullptr;
  std::int64_t now = 0;
  std::uint64_t next_id = 0;
  std::vector<Sticky> sticky;
  std::vector<Countdown> countdowns;
  std::vector<Task> tasks;
  ExchangeState current;
  std::vector<std::uint64_t> poll_counts;
  std::vector<std::array<std::uint64_t, kMailboxStageCount>> step_counts;
  bool polls_counted = false;  // some count is not 0 (cleared at the end of the exchange)
  bool steps_counted = false;
  std::vector<std::optional<std::uint16_t>> latched;
  std::vector<std::pair<std::size_t, wire::AlState>> refusals;  // refuse_state rules set
  std::vector<std::pair<std::size_t, std::uint8_t>> links_down;
  bool master_down = false;
  // A second master port's cabling (RedundantPorts), and the one clear() returns to.
  std::optional<RedundantCabling> cabling;
  RedundantCabling cabling_base;
  std::array<std::optional<RedundantRoute>, 2> routes;  // by ingress (refresh_cabling)
  // The master port the current exchange's reply leaves by (RedundantPorts), if any.
  std::optional<wire::RedundantPort> exchange_port;
  // The previous reply, for replay_previous: of a single port, of the primary, of the secondary.
  std::array<std::vector<std::uint8_t>, 3> previous_reply;
  std::size_t reply_slot() const {
    return exchange_port ? 1 + static_cast<std::size_t>(*exchange_port) : 0;
  }
  std::vector<std::uint8_t> scratch;
};

FaultInjector::FaultInjector(Segment& segment) : impl_(std::make_unique<Impl>(segment)) {
  impl_->stats = &stats_;
  segment.set_hooks(this);
}

FaultInjector::~FaultInjector() {
  impl_->segment.set_hooks(nullptr);
}

Result<void> FaultInjector::attach_redundant_ring(const RedundantCabling& base) {
  Impl& s = *impl_;
  if (s.cabling) {
    return Error(Errc::wrong_state, "the segment has a second master port already");
  }
  if (auto r = route_redundant(base.topology, s.segment.size(), wire::RedundantPort::primary); !r) {
    return std::move(r).error();
  }
  if (auto r = s.check_ring_cables(*cables_down(base.topology, s.segment.size())); !r) return r;
  s.cabling = base;
  s.cabling_base = base;
  // The links the faults took down on the ring's cables become the ring's: one model from now on.
  for (auto it = s.links_down.begin(); it != s.links_down.end();) {
    const auto cable = s.ring_cable(it->first, it->second);
    if (!cable) {
      ++it;
      continue;
    }
    if (!s.unplugged_cable(it->first, it->second)) s.segment.set_link(it->first, it->second, true);
    s.set_cable(*cable, false);
    it = s.links_down.erase(it);
  }
  if (s.master_down) {
    s.segment.set_master_link(true);
    s.master_down = false;
    s.set_cable(0, false);
  }
  s.refresh_cabling();
  return ok();
}

void FaultInjector::detach_redundant_ring() {
  impl_->cabling.reset();
  impl_->refresh_cabling();
}

std::optional<RedundantRoute> FaultInjector::redundant_route(
    wire::RedundantPort ingress) const noexcept {
  return impl_->routes[static_cast<std::size_t>(ingress)];
}

void FaultInjector::set_exchange_port(std::optional<wire::RedundantPort> egress) noexcept {
  impl_->exchange_port = egress;
}

bool FaultInjector::pass_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  if (!before_frame(frame, now_ns)) return false;
  after_frame(frame, now_ns);
  return true;
}

Result<void> FaultInjector::plug(std::string_view group, bool plugged, std::int64_t now_ns) {
  impl_->advance(now_ns);
  return impl_->plug(group, plugged, now_ns);
}

const std::optional<RedundantCabling>& FaultInjector::redundant_cabling() const noexcept {
  return impl_->cabling;
}

Result<void> FaultInjector::set_redundant_topology(const RedundantTopology& topology) {
  Impl& s = *impl_;
  if (!s.cabling) return Error(Errc::unsupported, "the segment has no second master port");
  const std::size_t n = s.segment.size();
  auto down = cables_down(topology, n);
  if (!down) return std::move(down).error();
  if (auto r = s.check_ring_cables(*down); !r) return r;
  std::vector<std::size_t> list;
  for (std::size_t k = 0; k <= n; ++k) {
    if ((*down)[k]) list.push_back(k);
  }
  s.cabling->topology = RedundantTopology::cables_down(std::move(list), n);
  s.refresh_cabling();
  return ok();
}

Result<void> FaultInjector::set_port_delay(wire::RedundantPort egress,
                                           const RedundantPortDelay& delay) {
  Impl& s = *impl_;
  if (!s.cabling) return Error(Errc::unsupported, "the segment has no second master port");
  s.cabling->delays[static_cast<std::size_t>(egress)] =
      RedundantPortDelay{std::max(std::chrono::nanoseconds(0), delay.delay), delay.from};
  return ok();
}

Result<void> FaultInjector::inject(const Fault& fault, std::int64_t now_ns) {
  if (auto r = validate(fault); !r) return r;
  if (auto r = impl_->check(fault); !r) return r;
  impl_->advance(now_ns);
  if (fault.form == Fault::Form::effect) {
    impl_->activate_effect(fault, false);
    return ok();
  }
  Impl::Task task;
  task.id = ++impl_->next_id;
  task.description = describe(fault);
  task.steps.push_back(Impl::Step{fault, false});
  if (impl_->run(task)) impl_->tasks.push_back(std::move(task));
  return ok();
}

void FaultInjector::clear() {
  Impl& s = *impl_;
  s.sticky.clear();
  s.countdowns.clear();
  s.tasks.clear();
  s.current.reset(s.segment.size());
  for (std::size_t i = 0; i < s.segment.size(); ++i) {
    Esc& esc = s.segment.esc(i);
    if (CoeServer* coe = coe_server_of(esc)) coe->clear_faults();
    if (FoeServer* foe = foe_server_of(esc)) foe->clear_faults();
    if (SoeServer* soe = soe_server_of(esc)) soe->clear_faults();
    if (EoeServer* eoe = eoe_server_of(esc)) eoe->clear_faults();
    if (s.latched[i] && esc.al_error() && esc.al_status_code() == *s.latched[i]) {
      esc.pdi_set_al_status(esc.al_state(), false, 0);
    }
    s.latched[i].reset();
  }
  for (const auto& [slave, state] : s.refusals)
    s.segment.esc(slave).set_al_refusal(state, std::nullopt);
  s.refusals.clear();
  if (s.cabling) {
    s.cabling = s.cabling_base;
    s.refresh_cabling();
  }
  for (const auto& [slave, port] : s.links_down)
    s.segment.set_link(slave, port, true);
  s.links_down.clear();
  if (s.master_down) s.segment.set_master_link(true);
  s.master_down = false;
}

void FaultInjector::advance(std::int64_t now_ns) {
  impl_->advance(now_ns);
}

std::optional<std::int64_t> FaultInjector::next_due_ns() const {
  std::optional<std::int64_t> due;
  for (const auto& task : impl_->tasks) {
    if (task.wait == Impl::Wait::timer && (!due || task.due_ns < *due)) due = task.due_ns;
  }
  return due;
}

FaultInfo FaultInjector::info(std::int64_t now_ns) const {
  const Impl& s = *impl_;
  FaultInfo info;
  Impl::ExchangeState next;
  next.reset(s.segment.size());
  for (const auto& st : s.sticky) {
    info.active.push_back(describe(st.effect));
    next.add(st.effect, st.slave);
  }
  for (const auto& c : s.countdowns) {
    info.queued.push_back(QueuedFaultInfo{describe(c.effect), c.remaining});
    next.add(c.effect, c.slave);
  }
  for (std::size_t i = 0; i < s.segment.size(); ++i) {
    Esc& esc = s.segment.esc(i);
    if (const CoeServer* coe = coe_server_of(esc)) {
      for (const auto& rule : coe->abort_rules()) {
        FaultEffect e = rule_effect(FaultKind::mailbox_abort, s.segment.name(i), rule);
        e.code = rule.code;
        info.active.push_back(describe(e));
      }
      for (const auto& rule : coe->protocol_faults()) {
        FaultEffect e = rule_effect(FaultKind::mailbox_protocol_fault, s.segment.name(i), rule);
        e.protocol = rule.fault;
        info.active.push_back(describe(e));
      }
      for (const auto& rule : coe->handler_faults()) {
        if (rule.type != wire::MailboxType::voe) continue;
        info.active.push_back(describe(fault::voe_fault(s.segment.name(i), rule.kind).effect) +
                              (rule.once ? "" : " (sticky)"));
      }
    }
    if (const FoeServer* foe = foe_server_of(esc)) {
      for (const auto& rule : foe->faults()) {
        info.active.push_back(fmt::format("FoE {} on {} after {}", to_string(rule.kind),
                                          s.segment.name(i),
                                          plural(rule.after_packets, "packet", "packets")));
      }
    }
    if (const SoeServer* soe = soe_server_of(esc)) {
      for (const auto& rule : soe->faults()) {
        auto f = fault::soe_fault(s.segment.name(i), rule.kind, rule.idn, rule.value, rule.drive,
                                  rule.write);
        f.effect.once = rule.once;
        info.active.push_back(describe(f.effect));
      }
    }
    if (const EoeServer* eoe = eoe_server_of(esc)) {
      for (const auto& rule : eoe->faults()) {
        auto f = fault::eoe_fault(s.segment.name(i), rule.kind, rule.value);
        f.effect.once = rule.once;
        info.active.push_back(describe(f.effect));
      }
    }
    if (s.latched[i] && esc.al_error() && esc.al_status_code() == *s.latched[i]) {
      info.active.push_back(
          fmt::format("latch AL error 0x{:04X} on {}", *s.latched[i], s.segment.name(i)));
    }
  }
  for (const auto& [slave, state] : s.refusals) {
    // A power cycle lifted it meanwhile when the ESC no longer has it.
    if (const auto code = s.segment.esc(slave).al_refusal(state)) {
      FaultEffect e;
      e.kind = FaultKind::refuse_state;
      e.slave = s.segment.name(slave);
      e.state = state;
      e.code = *code;
      info.active.push_back(describe(e));
    }
  }
  for (const auto& [slave, port] : s.links_down) {
    info.active.push_back(fmt::format("link down on {} port {}", s.segment.name(slave), port));
    info.links_down.push_back(fmt::format("{}:{}", s.segment.name(slave), port));
  }
  if (s.master_down) {
    info.active.emplace_back("master link down");
    info.links_down.emplace_back("master");
  }
  if (s.cabling) info.ring = describe(*s.cabling);
  for (const auto& task : s.tasks) {
    ScheduledFaultInfo sched;
    sched.description = task.description;
    sched.step = task.steps_started;
    if (task.wait == Impl::Wait::timer)
      sched.due_in_ns = std::max<std::int64_t>(0, task.due_ns - now_ns);
    if (task.wait == Impl::Wait::milestone) {
      sched.waiting_on = task.milestone_text;
      sched.remaining = task.remaining;
    }
    if (task.wait == Impl::Wait::countdown) {
      for (const auto& c : s.countdowns) {
        if (c.id == task.countdown) sched.remaining = c.remaining;
      }
      sched.waiting_on = "queued exchange faults";
    }
    info.scheduled.push_back(std::move(sched));
  }
  info.drop_responses = next.drop;
  info.wkc_offset = next.wkc_offset;
  for (std::size_t c = 0; c < wire::kCommandCount; ++c) {
    if (next.command_offsets[c] != 0) {
      info.command_wkc_offsets[std::string(wire::to_string(static_cast<wire::Command>(c)))] =
          next.command_offsets[c];
    }
  }
  for (std::size_t i = 0; i < s.segment.size(); ++i) {
    if (next.logical[i] != 0) info.logical_wkc_offsets[s.segment.name(i)] = next.logical[i];
    if (next.disconnected[i] != 0) info.disconnected.push_back(s.segment.name(i));
  }
  return info;
}

ReplyPlan FaultInjector::shape_reply(std::vector<std::uint8_t>& reply) {
  Impl& s = *impl_;
  const Impl::ExchangeState& x = s.current;
  ReplyPlan plan;
  std::vector<std::uint8_t>& previous = s.previous_reply[s.reply_slot()];
  if (!x.reply_faults) {
    previous.assign(reply.begin(), reply.end());
    return plan;
  }
  ++stats_.replies_altered;
  s.scratch.assign(reply.begin(), reply.end());
  if (x.replay && !previous.empty()) reply.assign(previous.begin(), previous.end());
  // The first datagram's index sits after the 2-byte frame header and its command byte.
  if (x.wrong_index && reply.size() > 3) reply[3] = static_cast<std::uint8_t>(reply[3] + 1);
  if (x.frame_type && reply.size() >= 2) {
    reply[1] = static_cast<std::uint8_t>((reply[1] & 0x0F) | (*x.frame_type << 4));
  }
  for (const auto& [offset, mask] : x.corrupt) {
    if (reply.empty()) break;
    const std::size_t at = std::min<std::size_t>(offset, reply.size() - 1);
    reply[at] ^= mask;
  }
  if (x.truncate != 0) reply.resize(reply.size() - std::min<std::size_t>(x.truncate, reply.size()));
  plan.copies = x.duplicate ? 2 : 1;
  plan.hold = x.reorder;
  plan.delay = std::chrono::nanoseconds(x.delay_ns);
  previous.swap(s.scratch);
  return plan;
}

bool FaultInjector::before_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  (void)frame;
  impl_->advance(now_ns);
  impl_->begin_exchange();
  if (impl_->current.drop) {
    ++stats_.responses_dropped;
    impl_->end_exchange(false);
    return false;
  }
  return true;
}

bool FaultInjector::slave_unreachable(std::size_t index) {
  const auto& d = impl_->current.disconnected;
  return impl_->current.any_disconnected && index < d.size() && d[index] != 0;
}

void FaultInjector::after_datagram(std::size_t index, std::size_t datagram_number,
                                   DatagramInFlight& datagram, const DatagramEffect& effect) {
  (void)datagram_number;
  const auto& logical = impl_->current.logical;
  if (index >= logical.size() || logical[index] == 0 || effect.wkc_added == 0) return;
  if (wire::addressing_of(datagram.command) != wire::Addressing::logical) return;
  const std::int64_t share = std::max<std::int64_t>(0, effect.wkc_added + logical[index]);
  const std::int64_t wkc =
      std::clamp<std::int64_t>(datagram.wkc - effect.wkc_added + share, 0, 0xFFFF);
  datagram.wkc = static_cast<std::uint16_t>(wkc);
}

void FaultInjector::after_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  (void)now_ns;
  Impl& s = *impl_;
  const Impl::ExchangeState& x = s.current;
  bool all_answered = true;
  const auto decoded = wire::decode_frame(frame);
  if (decoded) {
    for (const wire::DatagramView d : *decoded.frame) {
      const auto wkc_offset =
          static_cast<std::size_t>(d.data.data() - frame.data()) + d.header.length;
      std::int64_t wkc = d.wkc;
      const std::int64_t delta =
          x.wkc_offset + x.command_offsets[static_cast<std::size_t>(d.header.command)];
      if (delta != 0) {
        wkc = std::clamp<std::int64_t>(wkc + delta, 0, 0xFFFF);
        wire::store_le16(frame.data() + wkc_offset, static_cast<std::uint16_t>(wkc));
      }
      if (wkc == 0) all_answered = false;
    }
  }
  const bool healthy = decoded && all_answered && x.wkc_offset == 0 && !x.any_disconnected &&
                       !x.queued && !x.reply_faults;
  if (healthy) s.count_polls(frame);
  s.end_exchange(healthy);
}

CoeServer* coe_server_of(Esc& esc) noexcept {
  auto* app = dynamic_cast<StandardApplication*>(&esc.application());
  return app != nullptr ? app->coe_server() : nullptr;
}

}  // namespace ecat::sim
