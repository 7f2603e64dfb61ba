// A redundant simulated segment: the ring of a SimServer with a second master port at its far
// end (the last slave's port 1), so that a master with a redundant link (link/redundant_link.hpp)
// can be tested against a cable break anywhere.
//
// Routing follows the ESC's forwarding rules: a frame is processed only on its way from port 0
// through the processing unit, and a port without link closes its loop (the frame turns round
// there). So on a whole ring the primary's frame is processed by every slave and leaves into the
// secondary port, and the secondary's frame passes every slave unprocessed and leaves into the
// primary port. A break between slave n-1 and slave n turns both round: the primary's frame comes
// back to the primary processed by slaves 0..n-1, the secondary's comes back to the secondary
// processed by n..N-1, which count positions (auto-increment addressing) from n, as real slaves
// behind a break do. A cut at a master port loses that port's frames, and the other port's frame
// goes through every slave and back. With several cables down, the slaves between two breaks are
// out of reach of both ports.
//
// The ring's cables are numbered: 0 is the primary's (to slave 0's port 0), n in 1..N-1 the one
// from slave n-1's port 1 to slave n's port 0, N the secondary's (from the last slave's port 1).
//
// The two ports are in-process links (take_link; like SimServer::function_link: the master's
// send() processes the frame in its thread, under the server's lock; no thread, deterministic),
// or two raw interfaces served by a thread each (serve: `ecat sim --interface A
// --redundant-interface B`). Replies carry the requester's source address with bit 1 of the first
// byte set, as an ESC sets it.
//
// A port's replies can be held back (set_delay: all of them, or only those of frames that entered
// by a given port), as a slow master NIC or a late passthrough copy would arrive.
//
// The cabling (which cables are down, and the delays) is segment state with one owner: the
// server's FaultInjector. The ring faults (ring_break, ring_cut, ring_heal, port_delay), the link
// faults on the ring's ports (link_down/link_up on a slave's port 0 or 1: that cable;
// master_link_down/up: the primary's cable), hot-connect plugs (an unplugged group is out of the
// ring: the cables at both its ends are down), scripts, the control channel and
// set_topology/set_delay all change it under the server's lock, and fault.clear returns it to the
// one the ports were created with. Every frame entering a master port is one exchange for the
// exchange and reply faults (faults.hpp), which act on the replies of both ports or, naming a
// port, on those arriving there.
//
// The ESCs' DL status (0x0110) follows the cabling (the injector sets Segment::set_reported_link
// at every change): the last slave's port 1 has a link while the secondary's cable is in; a cable
// down between slave n-1 and n takes the link of slave n-1's port 1 and slave n's port 0; a cut
// master cable that of slave 0's port 0 or the last slave's port 1. Ports without link report
// their loop closed.
//
// Not yet modelled: the DC receive-time latches of the break's paths (the secondary's frame
// latches the times a whole ring's frame would, at the moment the secondary sends it).
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/redundancy.hpp>

namespace ecat::sim {

class SimServer;

struct RedundantTopology {
  // several: two or more cables down (`cables`).
  enum class Kind : std::uint8_t { whole, break_after, master_break, several };
  Kind kind = Kind::whole;
  // break_after: slaves 0..n-1 stay on the primary's side (1 <= n < slave count).
  std::size_t break_after = 0;
  // master_break: the port whose cable is cut.
  wire::RedundantPort master_break = wire::RedundantPort::primary;
  // several: the cables down by number (0 .. slave count, see above), ascending, and the slave
  // count they were numbered for (cable `slaves` is the secondary's).
  std::vector<std::size_t> cables;
  std::size_t slaves = 0;

  static RedundantTopology whole_ring() { return {}; }
  static RedundantTopology broken_after(std::size_t n) { return {Kind::break_after, n, {}, {}, 0}; }
  static RedundantTopology cut_at(wire::RedundantPort port) {
    return {Kind::master_break, 0, port, {}, 0};
  }
  // The topology with exactly `cables` down (any order, repeats ignored), in its simplest kind.
  static RedundantTopology cables_down(std::vector<std::size_t> cables, std::size_t slave_count);
};
// "whole", "break after 2", "master break primary", "master break primary, break after 2"
std::string describe(const RedundantTopology& topology);

// Which of the ring's slave_count + 1 cables are down. Errc::invalid_argument for a break_after
// outside 1..slave_count-1 or a cable beyond slave_count (naming it).
Result<std::vector<bool>> cables_down(const RedundantTopology& topology, std::size_t slave_count);

// Where a frame entering a master port goes: the slaves [first, last) process it, and it leaves
// into `egress` (none: lost on a cut cable).
struct RedundantRoute {
  std::size_t first = 0;
  std::size_t last = 0;
  std::optional<wire::RedundantPort> egress;
};
// Pure. Errc::invalid_argument for a break_after outside 1..slave_count-1 (naming it).
Result<RedundantRoute> route_redundant(const RedundantTopology& topology, std::size_t slave_count,
                                       wire::RedundantPort ingress);
// The same over the cables (down.size() == slave count + 1).
RedundantRoute route_redundant(const std::vector<bool>& down, wire::RedundantPort ingress);

// Replies leaving by a port held back `delay` (0: none); only those to frames that entered by
// `from` when set.
struct RedundantPortDelay {
  std::chrono::nanoseconds delay{0};
  std::optional<wire::RedundantPort> from;
};

struct RedundantCabling {
  RedundantTopology topology{};
  std::array<RedundantPortDelay, 2> delays{};  // by egress port: primary, secondary
};
// "whole", "break after 2; secondary +200 us (from secondary)"
std::string describe(const RedundantCabling& cabling);

struct RedundantPortsOptions {
  // The master's two port addresses on in-process links (raw: each request's source) for replies.
  wire::MacAddress primary_mac{0x02, 0xEC, 0x00, 0x00, 0x00, 0x01};
  wire::MacAddress secondary_mac{0x02, 0xEC, 0x00, 0x00, 0x00, 0x02};
  RedundantTopology topology{};
  std::array<RedundantPortDelay, 2> delays{};  // by egress port
  // Replies that may wait on one port at once.
  std::size_t queue_depth = 16;
};

struct RedundantPortsStats {
  std::uint64_t frames = 0;       // frames sent by the master on either port
  std::uint64_t crosses = 0;      // replies that left by the other port
  std::uint64_t bounces = 0;      // replies that came back to the port they entered
  std::uint64_t lost = 0;         // frames lost on a cut cable or by a fault
  std::uint64_t overflowed = 0;   // replies dropped on a full queue
  std::uint64_t delayed = 0;      // replies held back by delay_replies or reorder_replies
  std::uint64_t duplicated = 0;   // extra copies sent by duplicate_reply
  std::uint64_t send_errors = 0;  // replies a raw port could not send
};

class RedundantPorts {
 public:
  // Over `server` (which must outlive the ports and the links), serving nothing else. The slaves
  // are the ring in position order; Errc::invalid_argument for a ring that is not a line, or a
  // topology it cannot have; Errc::wrong_state when the server has a second master port already.
  // The options' topology and delays are the cabling fault.clear returns to.
  static Result<std::unique_ptr<RedundantPorts>> create(SimServer& server,
                                                        RedundantPortsOptions options = {});
  ~RedundantPorts();
  RedundantPorts(const RedundantPorts&) = delete;
  RedundantPorts& operator=(const RedundantPorts&) = delete;

  // The master's end of one cable ("sim-primary", "sim-secondary"); take each once. The links
  // stay valid after the RedundantPorts is gone (then they lose every frame).
  std::unique_ptr<link::Link> take_link(wire::RedundantPort port);

  // Serves the two master ports on raw interfaces until stop(): a thread per port receives what
  // the master sends there and carries it through the ring; replies leave by the port the route
  // says (sent from whichever thread has one ready; a held-back reply by its port's thread), and
  // the primary's thread keeps the segment's time moving (SimServer::tick). Open the links
  // without `responder`: the replies' addresses are set here. Errc::wrong_state when already
  // serving.
  Result<void> serve(std::unique_ptr<link::RawLink> primary,
                     std::unique_ptr<link::RawLink> secondary);
  void stop();
  bool serving() const;
  // "eth1,eth2", while serving.
  std::string served() const;

  // Thread-safe; takes effect from the next frame.
  Result<void> set_topology(const RedundantTopology& topology);
  RedundantTopology topology() const;
  // Replies leaving by `egress` are held back `delay` (0: none); with `from_ingress`, only replies
  // to frames that entered by that port. Thread-safe.
  void set_delay(wire::RedundantPort egress, std::chrono::nanoseconds delay,
                 std::optional<wire::RedundantPort> from_ingress = std::nullopt);
  RedundantPortsStats stats() const;

  struct Shared;
  struct Serving;

 private:
  RedundantPorts() = default;
  std::shared_ptr<Shared> shared_;
  std::unique_ptr<Serving> serving_;
};

}  // namespace ecat::sim
