// A Link moves whole EtherCAT frames (2-byte EtherCAT header + datagrams) between the master and a
// segment. It knows the encapsulation (Ethernet II, UDP, in-process memory) and nothing about the
// protocol: no retries, no index matching, no timeouts beyond the one receive() is given.
//
// Threading: send() and receive() may be called from different threads, but at most one thread
// receives at a time and at most one thread sends at a time. interrupt() may be called from any
// thread to wake a blocked receive().
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::link {

struct ReceivedFrame {
  // The EtherCAT frame (header + datagrams, possibly followed by Ethernet padding). Points into
  // the link's own buffer: valid until the next receive() on the same link.
  wire::Bytes frame;
  // When the frame arrived, in CLOCK_MONOTONIC nanoseconds: the kernel's receive timestamp where
  // the link has one, otherwise taken right after the receive call returned.
  std::int64_t timestamp_ns = 0;
  // Ethernet source address (all zero for links without one).
  std::array<std::uint8_t, 6> source{};  // wire::MacAddress
};

struct LinkStats {
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t bytes_sent = 0;
  std::uint64_t bytes_received = 0;
  // Frames the link read but did not hand on: foreign EtherType, its own outgoing frames, runt
  // or oversized frames.
  std::uint64_t frames_ignored = 0;
  std::uint64_t send_errors = 0;
  std::uint64_t receive_errors = 0;
  // Frames send() accepted but the medium could not deliver (a full in-process queue), the way a
  // congested wire loses them. Not included in frames_sent.
  std::uint64_t frames_dropped = 0;
};

// Cable redundancy (RedundantLink, redundant_link.hpp): what a link over two ports knows of them
// and of the ring between them. Plain data, here so that the bus and the master can report it
// for any link.
enum class RedundancyTopology : std::uint8_t {
  redundant,               // both ports healthy
  degraded_primary_leg,    // the primary port fails: the ring is served through the secondary
  degraded_secondary_leg,  // the secondary port fails
  offline,                 // neither port works
};
std::string_view to_string(RedundancyTopology topology) noexcept;

// What the frames that came back say about the ring.
enum class RingState : std::uint8_t {
  unknown,  // nothing has come back yet
  whole,    // the primary's frames cross to the secondary: the ring is closed
  broken,   // frames come back to the port that sent them (bounces)
};
std::string_view to_string(RingState state) noexcept;

struct RedundantPortStatus {
  std::string name;  // the leg link's name ("eth0")
  bool healthy = true;
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t send_errors = 0;
  std::uint64_t receive_errors = 0;
  std::uint64_t reopens = 0;
};

// Where a redundant ring is open, as the slaves' DL status (0x0110) shows it: which link was
// lost. Plain data; the master fills it (master/ring_break.hpp), a link alone cannot know it.
struct RingBreak {
  enum class Where : std::uint8_t {
    between_slaves,   // the cable from `before`'s port 1 to `after`'s port 0
    primary_cable,    // the primary port's cable: slave 0's port 0 has no link
    secondary_cable,  // the secondary port's cable: the last slave's port 1 has no link
  };
  Where where = Where::between_slaves;
  // between_slaves: the last slave on the primary's side and the first on the secondary's
  // (positions in ring order from the primary, station addresses); a cut master cable: the slave
  // whose port lost the link, in both.
  std::size_t before_position = 0;
  std::uint16_t before_station = 0;
  std::size_t after_position = 0;
  std::uint16_t after_station = 0;
  // The ports that lost the link: `before`'s port the cable leaves (1 on a line, a junction's
  // port 1..3 on a ring through junctions; 0 for the primary's cable, the port back to the
  // secondary for its cable) and `after`'s port it enters (always 0: towards the master).
  std::uint8_t before_port = 1;
  std::uint8_t after_port = 0;

  bool operator==(const RingBreak&) const = default;
};
std::string_view to_string(RingBreak::Where where) noexcept;
// "between slave 1 (station 0x1001) and slave 2 (station 0x1002)", "at the primary port's cable
// (slave 0, station 0x1001, port 0)"; a cable leaving a port other than 1: "between slave 1
// (station 0x1002, port 2) and slave 4 (station 0x1005, port 0)".
std::string describe(const RingBreak& ring_break);

struct RedundancyStatus {
  RedundancyTopology topology = RedundancyTopology::redundant;
  RingState ring = RingState::unknown;
  RedundantPortStatus primary;
  RedundantPortStatus secondary;
  std::uint64_t forward_crosses = 0;     // replies through a whole ring
  std::uint64_t reverse_crosses = 0;     // processed frames the secondary sent round to the primary
  std::uint64_t passthrough_copies = 0;  // unprocessed copies dropped
  std::uint64_t merged = 0;              // replies merged from two bounces
  std::uint64_t lone_bounces = 0;        // replies from one bounce (the other side silent)
  std::uint64_t merge_timeouts = 0;      // lone bounces handed on when their wait ran out
  // Halves that came back after their exchange was answered without them (lone) or expired:
  // dropped, never merged into another exchange.
  std::uint64_t late_halves = 0;
  std::uint64_t unknown_sources = 0;  // frames from neither port's address, handed on as is
  std::uint64_t stale = 0;            // arrivals for no frame in flight, dropped
  std::uint64_t ring_breaks = 0;      // whole -> broken changes seen
  std::uint64_t ring_heals = 0;       // broken -> whole changes seen
  // Where the ring is open, once the master has read the slaves' DL status after the ring was
  // seen broken (none from a link, none while whole or not yet located).
  std::optional<RingBreak> break_location;
};

// A redundant link's two ports (wire::RedundantPort in the pure part; this header keeps the
// frame codecs out of the application's headers).
enum class Port : std::uint8_t { primary, secondary };

// One datagram of a frame, picked out by its command and address, for a redundant link's
// per-port frame contents (Link::set_port_nop).
struct DatagramSelector {
  std::uint8_t command = 0;  // a wire::Command
  std::uint16_t adp = 0;     // position or station
  std::uint16_t ado = 0;     // register
  bool any_adp = false;      // every position or station: `adp` is not compared
  // Only while the other port's copy of the last matching datagram came back with its data
  // changed (a reader on that side: for the DC FRMW, the reference clock) and that side is not
  // silent; otherwise this port's copy carries the datagram as it is.
  bool while_other_side_reads = false;
  bool operator==(const DatagramSelector&) const = default;
};

// A redundant link keeps one selector per port for each user of per-port frame contents
// (Link::set_port_nop), so that one user's selector never ends another's.
enum class NopSlot : std::uint8_t {
  dc_time,     // the DC reference-time FRMW (the master's DC runtime)
  addressing,  // position addressing through one port (startup, a slave found by its position)
};
inline constexpr std::size_t kNopSlots = 2;

class Link {
 public:
  virtual ~Link() = default;
  Link() = default;
  Link(const Link&) = delete;
  Link& operator=(const Link&) = delete;

  // Sends one EtherCAT frame. Does not allocate. Fails with Errc::invalid_argument for a frame
  // larger than the link carries, Errc::closed after close(), Errc::io_error otherwise.
  virtual Result<void> send(wire::Bytes ethercat_frame) = 0;

  // Waits up to `timeout` for one frame (a zero timeout polls). Returns std::nullopt on timeout or
  // when interrupt() was called and no frame is waiting: a frame that has arrived is returned
  // first (the interrupt then ends the next receive), so an interrupt never hides a reply.
  // Does not allocate.
  virtual Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) = 0;

  // Wakes a receive() that is blocked now (or the next one, if none is).
  virtual void interrupt() = 0;

  // Releases the underlying resource; later send/receive calls fail with Errc::closed.
  virtual void close() = 0;

  // Brings a failed link back: a cable plugged in again, an interface that went down and came
  // up. Opens the underlying resource anew with the options the link was opened with. Called
  // only by the thread that sends and receives, never while a send() or receive() runs (the bus
  // calls it from its own thread while the link is failed). Fails with Errc::closed after
  // close(), Errc::unsupported for links that cannot be reopened (the default: in-process links
  // have nothing to reopen), or the error of the attempt (for example the interface still down).
  virtual Result<void> reopen() {
    return Error(Errc::unsupported, "link " + name() + " cannot be reopened");
  }

  // "eth0", "udp:127.0.0.1:34980", "memory:a", ... for messages and status.
  virtual std::string name() const = 0;

  virtual LinkStats stats() const = 0;

  // The state of the two ports and the ring for a redundant link; none for every other link
  // (wrappers forward their inner link's). Any thread.
  virtual std::optional<RedundancyStatus> redundancy() const { return std::nullopt; }

  // Cable redundancy, per-port frame contents: while set, the copy of every frame that leaves
  // through `port` carries each datagram matching `selector` as a NOP (command 0: no slave
  // processes it, its working counter stays 0); the other port's copy is the frame as sent. The
  // reply handed back is still the frame the bus sent (the NOP copy's datagram adds nothing to
  // it). The master uses it to keep the secondary's copy of the DC reference-time FRMW from the
  // slaves behind a ring break (they would take the master's prediction for the reference's
  // time), or to send datagrams through one port only (a NOP on the other: where position
  // addressing counts from each side's first slave, behind a break). Each `slot` holds one
  // selector per port; a datagram any of a port's selectors matches is a NOP in its copy.
  // std::nullopt ends the slot's. Any thread, allocation-free; applies from the next send().
  // Errc::unsupported for a link with one port (the default).
  virtual Result<void> set_port_nop(Port port, NopSlot slot,
                                    std::optional<DatagramSelector> selector);

  // How long the sender waits for the reply to a frame (the bus tells its frame timeout, bounded
  // by three periods of the cycle's fastest work while a cycle runs). A redundant link waits for a
  // late side of the ring up to half of it from the oldest frame that side owes (RedundantLink, the
  // merge rule). Any thread; ignored by default.
  virtual void set_frame_budget(std::chrono::nanoseconds budget);

  // A descriptor that poll() reports readable (POLLIN) while a frame may be waiting for
  // receive(), so that a caller can wait on several links at once (RedundantLink waits on both
  // its ports in one ppoll). It may be readable for nothing (a frame the link then ignores); a
  // receive() that finds nothing leaves it quiet until something arrives. -1 when the link has
  // none (the default; also a link that never sleeps in receive(): spinning, busy polling): its
  // caller then waits in receive() itself. Only the receiving thread, between receives; may
  // change after reopen(), invalid after close(). In-process links open it at the first call and
  // only then signal it.
  virtual int wait_fd();

  // Largest EtherCAT frame send() accepts.
  virtual std::size_t max_frame_size() const;  // wire::kMaxFrameSize unless the link says less
};

}  // namespace ecat::link
