// Cable redundancy: one Link over two ports (primary, secondary) cabled to both ends of a ring,
// so that one broken cable anywhere does not stop the machine.
//
// Every frame goes out on both ports. What comes back is classified by the port it arrived on and
// its Ethernet source address (wire/redundancy.hpp): a forward cross (the primary's frame through
// a whole ring) is the reply; the unprocessed copy that only passed through the ring is dropped;
// two bounces (each side of a broken ring processed part of the slaves) are merged byte by byte
// with their working counters summed, so the bus sees one reply with the whole ring's working
// counter wherever the ring is broken.
//
// How long a lone bounce waits for its complement (the merge rule): the other side is awaited
// while it "owes" frames for less than the patience, max(merge_window, half the frame budget
// given by set_frame_budget); the time runs from the send of the oldest frame that side still
// owes (a lone bounce waited for its half and nothing at all has come back on that port since),
// not from each frame, and a lone bounce waits at least merge_window from its arrival. A side that
// has owed a frame for the whole patience is taken as cut off: lone bounces complete at once
// until anything arrives on its port again. It is never waited for when its port sent nothing or
// its copy already came back empty. So a side answering late on a loaded host (a descheduled
// thread, a slow NIC) is merged for every frame as long as it is less than a patience late, and a
// cable cut at the master delays only the frames then in flight, together, by one patience, once.
// The bus gives the link its frame timeout, bounded by three periods of the fastest domain while
// a cycle runs (Bus::set_fastest_work_period), so on a master the patience is at most a period
// and a half of it.
//
// An arrival belongs to the oldest exchange with its first datagram index and datagram count
// whose copy on that port has not come back (a port returns frames in the order they were sent):
// the late half of an exchange answered without it is counted (late_halves) and dropped, never
// merged into a later exchange that reuses the index.
//
// Waiting: one ppoll on both legs' descriptors (Link::wait_fd) and an interrupt eventfd, so a
// reply on either port ends the wait at once and an idle link sleeps; with a leg that has no
// descriptor, 100 us on one leg, then the other.
//
// Port health is observed (send and receive errors, what arrives), never taken from the carrier:
// a leg that fails is still tried on every frame, and reopened at most once a second when its
// link supports it. `status()` (any thread) gives the topology: redundant, degraded on one leg,
// or offline, and whether the ring is whole or broken.
//
// Threading: the bus thread sends and receives (send() and receive() may come from different
// threads: the table of frames in flight is behind a mutex that neither holds while waiting).
// Neither allocates.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {

struct RedundantLinkOptions {
  // Ethernet source addresses the two legs send with, by which arrivals are classified; they must
  // differ in more than the locally administered bit. open_raw takes them from the interfaces.
  wire::MacAddress primary_mac{};
  wire::MacAddress secondary_mac{};
  // Least a lone bounce waits for its complement (from its arrival) while the other side may
  // still answer, and the least patience (see the merge rule above): with a frame budget
  // (set_frame_budget) the patience is half of it if that is longer. Keep it below the bus's
  // frame timeout.
  std::chrono::nanoseconds merge_window = std::chrono::microseconds(500);
  // A failed leg is reopened at most this often (from send(), on the bus thread).
  std::chrono::nanoseconds reopen_interval = std::chrono::seconds(1);
};

class RedundantLink final : public Link {
 public:
  // Over two links already open. Errc::unsupported for an EtherCAT-over-UDP leg (a UDP
  // endpoint is not a ring's end: it cannot cross), Errc::invalid_argument for a missing leg or
  // two addresses that cannot be told apart.
  static Result<std::unique_ptr<RedundantLink>> open(std::unique_ptr<Link> primary,
                                                     std::unique_ptr<Link> secondary,
                                                     RedundantLinkOptions options);
  // Over two raw interfaces (CAP_NET_RAW), each sending with its own hardware address.
  static Result<std::unique_ptr<RedundantLink>> open_raw(std::string primary_interface,
                                                         std::string secondary_interface,
                                                         RedundantLinkOptions options = {});

  ~RedundantLink() override;

  // Sends on both legs; fails only when both fail (with the primary's error).
  Result<void> send(wire::Bytes ethercat_frame) override;
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override;
  void interrupt() override;
  void close() override;
  // Reopens the legs that fail; succeeds when at least one works again.
  Result<void> reopen() override;
  // "redundant:eth0,eth1"
  std::string name() const override;
  // frames_sent: frames the bus sent; frames_received: replies handed to the bus.
  LinkStats stats() const override;
  std::size_t max_frame_size() const override;
  // The datagrams matching `selector` go out as NOP on `port`'s copy only (Link::set_port_nop);
  // an arrival's are given back the request's command before it is classified and merged.
  // The patience a late side gets is half of it (at least merge_window; the merge rule above).
  // Any thread.
  void set_frame_budget(std::chrono::nanoseconds budget) override;
  Result<void> set_port_nop(Port port, NopSlot slot,
                            std::optional<DatagramSelector> selector) override;

  RedundancyStatus status() const;
  std::optional<RedundancyStatus> redundancy() const override { return status(); }

  struct Impl;

 private:
  explicit RedundantLink(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::link
