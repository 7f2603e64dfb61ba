// Fault injection for a simulated segment: everything a master's recovery paths must survive,
// scheduled by exchange count, by segment time or by milestone (upstream-inventory §4.5, plus the
// wire faults the reference lacks).
//
// A Fault is a tree: a leaf FaultEffect (what goes wrong) inside scheduling forms (when). The same
// vocabulary is spoken by C++ (the builders in ecat::sim::fault), the ring file's `faults:`
// section and the control channel (JSON) — docs/RING-FILE.md lists every kind and key.
//
//   using namespace ecat::sim;
//   injector.inject(fault::next(fault::disconnect("outputs"), 30), now);
//   injector.inject(fault::after_milestone(fault::retreat_to_safeop("drive"),
//                                          fault::healthy_exchanges(100)), now);
//
// The FaultInjector installs itself as the Segment's hooks. One "exchange" is one frame the
// segment processes; on a segment with a second master port (RedundantPorts), every frame that
// enters a master port, processed or passing the ring unprocessed (so a master's exchange is two:
// one per port). Not thread-safe: the SimServer serializes access with its lock.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/eoe_server.hpp>
#include <ecat/sim/foe_server.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/soe_server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/redundancy.hpp>

namespace ecat::sim {

enum class FaultKind : std::uint8_t {
  // ---- Exchange faults: how the segment answers a frame. Sticky, or for the next N exchanges.
  drop_responses,      // no reply at all: the master times out
  wkc_offset,          // delta added to every datagram's WKC (clamped to 0..65535)
  command_wkc_offset,  // delta added to the WKC of datagrams with one command
  logical_wkc_offset,  // delta added to one slave's share of LRD/LWR/LRW WKCs (PDO faults only)
  disconnect,          // the slave is cut off: no processing, no WKC, not counted by APxx
  // ---- Reply faults: the reply altered on its way back (the transport edge). Sticky or next N.
  truncate_reply,    // the last `bytes` bytes cut off (the reply no longer decodes)
  unsupported_type,  // the EtherCAT header type set to `frame_type` (not 1: not datagrams)
  wrong_index,       // the first datagram's index + 1 (the master sees a foreign reply)
  replay_previous,   // the previous reply is sent instead of this one
  corrupt_byte,      // the byte at `offset` XOR `mask` (EtherCAT frame offset; clamped)
  duplicate_reply,   // the reply is sent twice
  reorder_replies,   // the reply is held back and sent after the next one
  delay_replies,     // the reply leaves `ns` later
  // ---- Slave faults: applied once, when the fault activates.
  retreat_to_safeop,       // OP -> SAFEOP without error (a no-op below OP)
  power_cycle,             // registers reset, station 0, INIT, SMs/FMMUs off, mailbox rules gone
  latch_al_error,          // keep the state, set the AL error bit and status `code`
  refuse_state,            // standing: requests for AL `state` refused with status `code`
  mailbox_abort,           // SDO abort `code` for (index, subindex) at `stage`
  mailbox_protocol_fault,  // corrupt the mailbox response for (index, subindex) at `stage`
  dc_jump,                 // the slave's DC local clock steps by `ns`
  foe_fault,               // the slave's FoE server misbehaves once (`foe`, `packet`, `value`)
  soe_fault,               // an SoE rule for (`drive`, `idn`): error code, lost fragment/response
  eoe_fault,               // the slave's EoE server loses or corrupts a fragment (`eoe`, `value`)
  voe_fault,               // the slave's VoE replies are dropped or garbled (`voe`)
  // ---- Segment faults: cabling, applied once.
  link_down,         // the link on `port` of the slave goes down (port 0: towards the master)
  link_up,           // ... and comes back
  master_link_down,  // the master's own cable to the first slave
  master_link_up,
  // ---- Redundant ring faults: the cabling of a segment with a second master port
  //      (RedundantPorts), applied once; refused on a segment without one.
  ring_break,  // the cable after the `after`-th slave breaks (1..slaves-1)
  ring_cut,    // the cable at the master's port `master_port` is cut
  ring_heal,   // every cable of the ring whole again
  port_delay,  // replies leaving by `master_port` held back `ns` (only those entered by `from`)
  // ---- Hot connect: a group of the segment (Segment::add_hot_connect_group), applied once.
  hot_plug,    // the group `group` is plugged in (powered up afresh, its cable up)
  hot_unplug,  // ... and pulled out (its cable down)
};
constexpr std::size_t kFaultKindCount = 34;

// What a foe_fault does. `error`, `drop_reply`, `wrong_packet` and `busy` are the FoE server's
// own faults (FoeFaultKind); `wrong_password` is an ERROR 0x800A (FoE "no rights") to the
// request, as a server demanding a password the master did not send.
enum class FoeFaultMode : std::uint8_t { error, busy, drop_reply, wrong_packet, wrong_password };
// "error", "busy", "drop_reply", "wrong_packet", "wrong_password".
std::string_view to_string(FoeFaultMode mode) noexcept;

enum class FaultClass : std::uint8_t { exchange, reply, slave, segment };

// "drop_responses", "wkc_offset", ... (the names in ring files and control requests).
std::string_view to_string(FaultKind kind) noexcept;
std::optional<FaultKind> fault_kind_from_string(std::string_view name) noexcept;
FaultClass fault_class(FaultKind kind) noexcept;
// Exchange and reply faults act per exchange (sticky or `next N`); the others act once.
bool is_per_exchange(FaultKind kind) noexcept;

// What a fault does. Only the fields its kind names are meaningful.
struct FaultEffect {
  FaultKind kind = FaultKind::drop_responses;
  std::string slave;  // the slave's name in the segment
  std::string group;  // hot_plug, hot_unplug: the hot-connect group's name
  // wkc_offset, command_wkc_offset, logical_wkc_offset.
  std::int64_t delta = 0;
  wire::Command command = wire::Command::nop;  // command_wkc_offset
  // latch_al_error, refuse_state (AL status code) and mailbox_abort (SDO abort code).
  std::uint32_t code = 0;
  wire::AlState state = wire::AlState::op;  // refuse_state: the AL state the slave refuses
  // mailbox_abort, mailbox_protocol_fault.
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  MailboxStage stage = MailboxStage::request;
  ProtocolFault protocol{};
  // Mailbox rules: removed after firing once. Default: sticky, but once-only as a script step.
  std::optional<bool> once;
  std::int64_t ns = 0;          // dc_jump (step), delay_replies (delay, > 0)
  std::uint32_t bytes = 1;      // truncate_reply
  std::uint32_t offset = 12;    // corrupt_byte: first datagram's first data byte by default
  std::uint8_t mask = 0xFF;     // corrupt_byte
  std::uint8_t frame_type = 0;  // unsupported_type
  std::uint8_t port = 0;        // link_down, link_up (0..3)
  // ring_break: the slaves before the break, counted from the primary port (1..slaves-1).
  std::uint32_t after = 0;
  // ring_cut, port_delay: the master's port; port_delay: `ns` (0: none), and only the replies to
  // frames that entered by `from` when set.
  wire::RedundantPort master_port = wire::RedundantPort::primary;
  std::optional<wire::RedundantPort> from;
  // drop_responses, wkc_offset, command_wkc_offset and the reply faults on a segment with a second
  // master port: only the frames whose reply arrives at this master port (the route is known
  // before the ring processes a frame); none: every frame. Refused without a second port.
  std::optional<wire::RedundantPort> on_port;
  // foe_fault, soe_fault, eoe_fault, voe_fault: what goes wrong (the `mode` key).
  FoeFaultMode foe = FoeFaultMode::error;
  SoeFaultKind soe = SoeFaultKind::error_response;
  EoeFaultKind eoe = EoeFaultKind::drop_reply_fragment;
  HandlerFaultKind voe = HandlerFaultKind::drop_reply;
  // foe_fault: the DATA (write) or ACK (read) packets of a transfer before the one it hits.
  std::uint32_t packet = 0;
  // foe_fault: the error code (error; 0x8000 by default) or the BUSY answers (busy; 1).
  // soe_fault: the SoE error code (error_response) or the fragment (drop_fragment, 1-based).
  // eoe_fault: the fragment number (0..63).
  std::uint32_t value = 0;
  std::uint16_t idn = 0;   // soe_fault
  std::uint8_t drive = 0;  // soe_fault (0..7)
  bool write = false;      // soe_fault: a rule for writes of the IDN, else reads
};

struct Milestone {
  enum class Kind : std::uint8_t {
    // Exchanges untouched by faults (no drop, global WKC offset, disconnect, queued or reply
    // fault) in which every datagram came back with WKC > 0.
    healthy_exchanges,
    // In a healthy exchange: an FPRD of the slave's AL status (0x0130) with WKC > 0, OP, no error.
    healthy_polls,
    // The master fetched an SDO response of `step` from the slave's mailbox (aborts excluded).
    mailbox_step,
  };
  Kind kind = Kind::healthy_exchanges;
  std::string slave;
  MailboxStage step = MailboxStage::upload_init;  // mailbox_step: upload_init ... (not request)
  std::uint64_t count = 1;
};

// "healthy_exchanges", "healthy_polls", "mailbox_step".
std::string_view to_string(Milestone::Kind kind) noexcept;

struct Fault {
  enum class Form : std::uint8_t {
    effect,           // `effect` now: per-exchange kinds sticky (or for `exchanges`), others once
    after_delay,      // steps[0] after `delay` of segment time
    after_milestone,  // steps[0] after `milestone` is reached (counted from now)
    script,           // steps in order; exchange steps take one exchange each (or `exchanges`)
    wait,             // script step: pause for `delay`
    wait_for,         // script step: pause until `milestone`
  };
  Form form = Form::effect;
  FaultEffect effect;
  // effect, per-exchange kinds: 0 = sticky (a script step: 1), N = the next N exchanges.
  std::uint64_t exchanges = 0;
  std::chrono::nanoseconds delay{0};
  Milestone milestone;
  std::vector<Fault> steps;
};

// Builders. Per-exchange kinds are sticky until clear(); wrap them in next() to limit them.
namespace fault {
Fault drop_responses();
Fault wkc_offset(std::int64_t delta);
Fault command_wkc_offset(wire::Command command, std::int64_t delta);
Fault logical_wkc_offset(std::string slave, std::int64_t delta);
Fault disconnect(std::string slave);
Fault truncate_reply(std::uint32_t bytes = 1);
Fault unsupported_type(std::uint8_t frame_type = 0);
Fault wrong_index();
Fault replay_previous();
Fault corrupt_byte(std::uint32_t offset, std::uint8_t mask = 0xFF);
Fault duplicate_reply();
Fault reorder_replies();
Fault delay_replies(std::chrono::nanoseconds delay);
Fault retreat_to_safeop(std::string slave);
Fault power_cycle(std::string slave);
Fault latch_al_error(std::string slave, std::uint16_t code);
// The slave's firmware refuses `state`: a request for it (from any other state) leaves the slave
// where it was with the AL error bit and `code` (e.g. 0x001D invalid output configuration), as a
// real device whose application refuses a transition. Standing until clear() or a power cycle.
Fault refuse_state(std::string slave, wire::AlState state, std::uint16_t code);
Fault mailbox_abort(std::string slave, std::uint16_t index, std::uint8_t subindex,
                    std::uint32_t code, MailboxStage stage = MailboxStage::request);
Fault mailbox_protocol_fault(std::string slave, std::uint16_t index, std::uint8_t subindex,
                             MailboxStage stage, ProtocolFault protocol);
Fault dc_jump(std::string slave, std::chrono::nanoseconds step);
// FoE: `mode` at the reply to the packet after `packet` DATA/ACK packets (0: the request).
// `value`: the error code (error) or the BUSY answers (busy). Fires once.
Fault foe_fault(std::string slave, FoeFaultMode mode, std::uint32_t packet = 0,
                std::uint32_t value = 0);
// SoE: `kind` for reads (or writes) of `idn` on `drive`; `value` the error code or fragment.
Fault soe_fault(std::string slave, SoeFaultKind kind, std::uint16_t idn, std::uint32_t value,
                std::uint8_t drive = 0, bool write = false);
// EoE: `kind` with fragment number `value`.
Fault eoe_fault(std::string slave, EoeFaultKind kind, std::uint32_t value = 0);
// VoE: the replies to the next VoE request dropped or garbled.
Fault voe_fault(std::string slave, HandlerFaultKind kind);
Fault link_down(std::string slave, std::uint8_t port);
Fault link_up(std::string slave, std::uint8_t port);
Fault master_link_down();
Fault master_link_up();
// A segment with a second master port (RedundantPorts): the ring breaks after the `after`-th
// slave, or is cut at a master port, or is whole again; a port's replies are held back.
Fault ring_break(std::uint32_t after);
Fault ring_cut(wire::RedundantPort port);
Fault ring_heal();
Fault port_delay(wire::RedundantPort port, std::chrono::nanoseconds delay,
                 std::optional<wire::RedundantPort> from = std::nullopt);
// `fault` (drop_responses, wkc_offset, command_wkc_offset or a reply fault) only on the replies
// arriving at the master's `port` of a redundant segment.
Fault at_port(Fault fault, wire::RedundantPort port);
// A hot-connect group plugged in or pulled out (Segment::plug); refused for an unknown group.
// clear() does not plug a pulled group back in.
Fault hot_plug(std::string group);
Fault hot_unplug(std::string group);

// Scheduling. next() is only valid around per-exchange kinds.
Fault next(Fault fault, std::uint64_t exchanges = 1);
Fault after(Fault fault, std::chrono::nanoseconds delay);
Fault after_milestone(Fault fault, Milestone milestone);
Fault script(std::vector<Fault> steps);
Fault wait(std::chrono::nanoseconds delay);
Fault wait_for(Milestone milestone);

Milestone healthy_exchanges(std::uint64_t count);
Milestone healthy_polls(std::string slave, std::uint64_t count);
Milestone mailbox_step(std::string slave, MailboxStage step, std::uint64_t count);
}  // namespace fault

// "next 30 exchanges disconnect outputs", "mailbox abort 0x06010002 on mbx 0x2000:01 at
// request", "after 250 ms: drop responses", "script: drop responses; wait for 3 healthy
// exchanges; power cycle io".
std::string describe(const FaultEffect& effect);
std::string describe(const Fault& fault);
std::string describe(const Milestone& milestone);

// Structural checks that need no segment (next() around a one-shot kind, a wait outside a
// script, a protocol fault at a stage it cannot apply to, values out of range).
Result<void> validate(const Fault& fault);

// The JSON form used by the control channel (and, as YAML, by ring files), e.g.
//   {"kind":"disconnect","slave":"outputs","next":30}
//   {"after_ms":250,"fault":{"kind":"drop_responses"}}
//   {"script":[{"kind":"drop_responses"},{"wait_for":{"milestone":"healthy_exchanges",
//    "count":3}}]}
std::string to_json(const Fault& fault);
// Errors name the key path: "fault.script[1].wait_for.count: ...".
Result<Fault> parse_fault_json(std::string_view json);
// The command-line form: KIND ARGS... ("disconnect outputs", "mailbox_abort mbx 0x2000:1
// 0x06010002 upload_segment", "mailbox_protocol_fault mbx 0x2000:1 upload_init sdo_command=0x60").
Result<Fault> parse_fault_words(std::span<const std::string> words);

struct FaultKindInfo {
  FaultKind kind;
  std::string_view name;       // "drop_responses" (what to_string(kind) returns)
  std::string_view arguments;  // command-line arguments after the kind, "" for none
  std::string_view summary;
};
const std::array<FaultKindInfo, kFaultKindCount>& fault_kinds() noexcept;

// ---- Observation --------------------------------------------------------------------------

struct QueuedFaultInfo {
  std::string description;      // "disconnect outputs"
  std::uint64_t remaining = 0;  // exchanges it still applies to
};

struct ScheduledFaultInfo {
  std::string description;                // the whole scheduled fault or script
  std::optional<std::int64_t> due_in_ns;  // waiting for time
  std::string waiting_on;                 // waiting for a milestone: describe(milestone)
  std::uint64_t remaining = 0;            // ... this many more events
  std::size_t step = 0;                   // scripts: the next step (0-based)
};

struct FaultInfo {
  std::vector<std::string> active;  // sticky faults and standing rules, described
  std::vector<QueuedFaultInfo> queued;
  std::vector<ScheduledFaultInfo> scheduled;
  // The exchange state those add up to for the next exchange.
  bool drop_responses = false;
  std::int64_t wkc_offset = 0;
  std::map<std::string, std::int64_t> command_wkc_offsets;  // "LRW" -> delta
  std::map<std::string, std::int64_t> logical_wkc_offsets;  // slave -> delta
  std::vector<std::string> disconnected;
  std::vector<std::string> links_down;  // "outputs:1", "master"
  // A segment with a second master port: its cabling ("break after 2; secondary +200 us"), else
  // empty.
  std::string ring;
};

struct FaultStats {
  std::uint64_t exchanges = 0;
  std::uint64_t healthy_exchanges = 0;
  std::uint64_t responses_dropped = 0;
  std::uint64_t replies_altered = 0;
  std::uint64_t faults_activated = 0;  // effects applied or armed
};

// What the transport should do with a reply (after FaultInjector::shape_reply).
struct ReplyPlan {
  std::size_t copies = 1;  // 2 for a duplicate
  bool hold = false;       // send after the next reply (reorder)
  std::chrono::nanoseconds delay{0};
};

class FaultInjector final : public SegmentHooks {
 public:
  // Installs itself as `segment`'s hooks and observes every CoE server's mailbox steps. The
  // segment must outlive the injector, and its slaves must not change while it exists.
  explicit FaultInjector(Segment& segment);
  ~FaultInjector() override;
  FaultInjector(const FaultInjector&) = delete;
  FaultInjector& operator=(const FaultInjector&) = delete;

  // Activates or schedules a fault at segment time `now_ns`. Fails (and changes nothing) for an
  // unknown slave, a slave without a mailbox / DC unit / such a port, or a structural error.
  Result<void> inject(const Fault& fault, std::int64_t now_ns);
  // Removes every exchange and reply fault, queued and scheduled fault and script, every mailbox
  // rule and AL state refusal, latched AL errors this injector set, and brings links it took down
  // back up. Does not
  // undo power cycles, retreats or clock jumps (they happened).
  void clear();

  // Lets time-scheduled faults fire. process_frame() does this too (before_frame).
  void advance(std::int64_t now_ns);
  // The earliest segment time a scheduled fault waits for, if any.
  std::optional<std::int64_t> next_due_ns() const;

  FaultInfo info(std::int64_t now_ns) const;
  const FaultStats& stats() const noexcept { return stats_; }

  // The transport edge: applies this exchange's reply faults to `reply` (the EtherCAT frame the
  // segment produced; it may shrink or be replaced) and says how to send it. Call once per reply
  // of a processed frame. Also remembers the reply for replay_previous.
  ReplyPlan shape_reply(std::vector<std::uint8_t>& reply);

  // ---- The cabling of a redundant segment (RedundantPorts) ----
  // Kept here so that faults, scripts, the control channel and the API change it under the one
  // lock that serializes the segment. attach: the ring faults apply from now on, and clear()
  // returns the cabling to `base`; detach: they are refused again.
  Result<void> attach_redundant_ring(const RedundantCabling& base);
  void detach_redundant_ring();
  // Empty when no second master port is attached.
  const std::optional<RedundantCabling>& redundant_cabling() const noexcept;
  // Errc::invalid_argument for a break outside 1..slaves-1, Errc::unsupported when detached.
  Result<void> set_redundant_topology(const RedundantTopology& topology);
  Result<void> set_port_delay(wire::RedundantPort egress, const RedundantPortDelay& delay);
  // Where a frame entering `ingress` goes under the cabling (the cables down and the unplugged
  // hot-connect groups); empty when detached. Computed at every change, not per frame.
  std::optional<RedundantRoute> redundant_route(wire::RedundantPort ingress) const noexcept;
  // The master port the next exchange's reply leaves by: faults naming a port act only on
  // theirs. Set by RedundantPorts around each frame (nullopt after it).
  void set_exchange_port(std::optional<wire::RedundantPort> egress) noexcept;
  // An exchange for a frame that passes every slave unprocessed (a whole ring's secondary copy):
  // the exchange faults apply (false: lost), then shape_reply may be called as for a processed
  // frame.
  bool pass_frame(std::span<std::uint8_t> frame, std::int64_t now_ns);

  // Plugs or pulls a hot-connect group (Segment::plug) and keeps the cabling with it: DL status,
  // a redundant ring's route (an unplugged group is out of the ring) and the links a link_down
  // holds down compose. Errc::not_found for an unknown group.
  Result<void> plug(std::string_view group, bool plugged, std::int64_t now_ns);

  // ---- SegmentHooks ----
  bool before_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) override;
  bool slave_unreachable(std::size_t index) override;
  void after_datagram(std::size_t index, std::size_t datagram_number, DatagramInFlight& datagram,
                      const DatagramEffect& effect) override;
  void after_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) override;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
  FaultStats stats_;
};

// The CoE server of a device built on StandardApplication, or nullptr (no mailbox).
CoeServer* coe_server_of(Esc& esc) noexcept;

}  // namespace ecat::sim
