#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <mutex>
#include <vector>

#include <fmt/format.h>
#include <poll.h>

#include <ecat/link/raw_link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/wire/redundancy.hpp>

#include "link/posix.hpp"

namespace ecat::link {

using std::chrono::nanoseconds;
using Clock = std::chrono::steady_clock;
using wire::ArrivalKind;
using wire::RedundantPort;

namespace {

// Frames in flight (and recently answered, so that their late copies are recognised): more than
// the bus ever has in flight at once.
constexpr std::size_t kSlots = 64;
// With a leg that has no descriptor to wait on (Link::wait_fd: a spinning or busy-polling leg, a
// link of the caller's own): how long one blocking wait on a leg lasts before the other leg is
// looked at.
constexpr nanoseconds kSlice = std::chrono::microseconds(100);
// Datagrams of one frame a port's copy may carry as NOP (Link::set_port_nop): every datagram a
// frame can hold.
constexpr std::size_t kMaxMasked = wire::kMaxFrameSize / wire::kDatagramOverhead + 1;

// A port's NOP selector packed into one word, so that send() reads it without a lock:
// bit 48 set = active, bit 49 = any ADP, bits 40..47 command, 16..31 ADP, 0..15 ADO.
constexpr std::uint64_t kSelectorActive = std::uint64_t{1} << 48;
constexpr std::uint64_t kSelectorAnyAdp = std::uint64_t{1} << 49;
constexpr std::uint64_t kSelectorWhileOtherReads = std::uint64_t{1} << 50;
std::uint64_t pack(const DatagramSelector& d) {
  return kSelectorActive | (d.any_adp ? kSelectorAnyAdp : 0) |
         (d.while_other_side_reads ? kSelectorWhileOtherReads : 0) |
         (std::uint64_t{d.command} << 40) | (std::uint64_t{d.adp} << 16) | d.ado;
}
bool matches(std::uint64_t packed, const wire::DatagramHeader& h) {
  return (packed & kSelectorActive) != 0 &&
         static_cast<std::uint8_t>(packed >> 40) == static_cast<std::uint8_t>(h.command) &&
         ((packed & kSelectorAnyAdp) != 0 || static_cast<std::uint16_t>(packed >> 16) == h.adp()) &&
         static_cast<std::uint16_t>(packed) == h.ado();
}

// A datagram one port's copy carried as NOP: where its command byte is and what it was.
struct Masked {
  std::uint16_t offset = 0;
  std::uint8_t command = 0;
};

enum class SlotState : std::uint8_t { free, waiting, done };

struct Exchange {
  SlotState state = SlotState::free;
  std::uint64_t sequence = 0;
  std::uint8_t first_index = 0;
  std::size_t count = 0;
  std::array<std::uint8_t, wire::kMaxFrameSize> sent{};
  std::size_t sent_size = 0;
  std::array<bool, 2> leg_sent{};
  // Datagrams one port's copy carried as NOP: an arrival's are put back to the request's
  // command, so that it is compared and merged with the frame the bus sent.
  std::array<Masked, kMaxMasked> masked{};
  std::size_t masked_count = 0;
  std::array<bool, 2> arrived{};  // anything came back on this port (a copy, a bounce)
  std::array<bool, 2> has_bounce{};
  std::array<std::array<std::uint8_t, wire::kMaxFrameSize>, 2> bounce{};
  std::array<std::size_t, 2> bounce_size{};
  std::int64_t last_arrival_ns = 0;
  Clock::time_point sent_at{};
  Clock::time_point window_end{};
};

struct Leg {
  std::unique_ptr<Link> link;
  std::string name;
  std::atomic<bool> healthy{true};
  std::atomic<std::uint64_t> frames_sent{0}, frames_received{0}, send_errors{0}, receive_errors{0},
      reopens{0};
  Clock::time_point next_reopen{};
  bool reopenable = true;
};

std::size_t side(RedundantPort port) {
  return port == RedundantPort::primary ? 0 : 1;
}
std::size_t other(std::size_t s) {
  return 1 - s;
}

}  // namespace

std::string_view to_string(RedundancyTopology topology) noexcept {
  switch (topology) {
    case RedundancyTopology::redundant:
      return "redundant";
    case RedundancyTopology::degraded_primary_leg:
      return "degraded_primary_leg";
    case RedundancyTopology::degraded_secondary_leg:
      return "degraded_secondary_leg";
    case RedundancyTopology::offline:
      break;
  }
  return "offline";
}

std::string_view to_string(RingState state) noexcept {
  switch (state) {
    case RingState::whole:
      return "whole";
    case RingState::broken:
      return "broken";
    case RingState::unknown:
      break;
  }
  return "unknown";
}

std::string_view to_string(RingBreak::Where where) noexcept {
  switch (where) {
    case RingBreak::Where::primary_cable:
      return "primary_cable";
    case RingBreak::Where::secondary_cable:
      return "secondary_cable";
    case RingBreak::Where::between_slaves:
      break;
  }
  return "between_slaves";
}

std::string describe(const RingBreak& b) {
  switch (b.where) {
    case RingBreak::Where::primary_cable:
      return fmt::format("at the primary port's cable (slave {}, station 0x{:04X}, port 0)",
                         b.before_position, b.before_station);
    case RingBreak::Where::secondary_cable:
      return fmt::format("at the secondary port's cable (slave {}, station 0x{:04X}, port {})",
                         b.before_position, b.before_station, b.before_port);
    case RingBreak::Where::between_slaves:
      break;
  }
  if (b.before_port != 1 || b.after_port != 0) {
    return fmt::format(
        "between slave {} (station 0x{:04X}, port {}) and slave {} (station 0x{:04X}, port {})",
        b.before_position, b.before_station, b.before_port, b.after_position, b.after_station,
        b.after_port);
  }
  return fmt::format("between slave {} (station 0x{:04X}) and slave {} (station 0x{:04X})",
                     b.before_position, b.before_station, b.after_position, b.after_station);
}

struct RedundantLink::Impl {
  RedundantLinkOptions options;
  std::array<Leg, 2> legs;
  std::string name;
  std::size_t max_frame = wire::kMaxFrameSize;

  std::mutex mutex;  // the exchanges and what follows; never held while waiting
  std::vector<Exchange> slots = std::vector<Exchange>(kSlots);
  std::uint64_t next_sequence = 1;
  // Completed exchanges in a row in which a leg's side of the ring returned nothing (a
  // conditional NOP selector does not apply while the other side is silent: port_copy_of).
  std::array<unsigned, 2> silent{};
  // Per side: since when it owes a frame, i.e. the send time of the oldest exchange a lone bounce
  // waited in for that side's half since the side last returned anything (`kNever`: it owes
  // nothing). A side that has owed one for the whole patience() is taken as cut off: a lone
  // bounce then completes at once, so a dead side costs the frames in flight one patience, once.
  static constexpr Clock::time_point kNever = Clock::time_point::max();
  std::array<Clock::time_point, 2> owed_since{kNever, kNever};
  std::array<std::uint8_t, wire::kMaxFrameSize> out{};
  // Per-port frame contents (set_port_nop): each port's selector, and the copy a port sends
  // when it differs (send() only: one thread sends at a time).
  std::array<std::array<std::atomic<std::uint64_t>, kNopSlots>, 2> nop_selector{};
  // For a selector that applies only while the other port's side reads: whether the other
  // port's copy of the last matching datagram came back with its data changed (under `mutex`).
  std::array<std::array<bool, kNopSlots>, 2> other_side_reads{};
  std::array<std::uint8_t, wire::kMaxFrameSize> port_copy{};
  // An arrival with its masked datagrams put back (under `mutex`).
  std::array<std::uint8_t, wire::kMaxFrameSize> restored{};
  std::size_t next_leg_to_wait = 1;  // the secondary, where a whole ring's replies arrive

  // The sender's wait for a reply (set_frame_budget), 0 when not told.
  std::atomic<std::int64_t> frame_budget_ns{0};
  std::atomic<bool> closed{false};
  // interrupt() and close(): wakes a receive() waiting on both legs' descriptors.
  detail::Interrupter interrupter;
  std::atomic<RingState> ring{RingState::unknown};
  std::atomic<std::uint64_t> frames_sent{0}, frames_received{0}, bytes_sent{0}, bytes_received{0},
      send_errors{0}, receive_errors{0}, ignored{0};
  std::atomic<std::uint64_t> forward_crosses{0}, reverse_crosses{0}, passthrough{0}, merged{0},
      lone{0}, merge_timeouts{0}, late_halves{0}, unknown_sources{0}, stale{0}, breaks{0}, heals{0};

  // How long a side may owe its half of a frame before it is taken as cut off: half the frame
  // budget (set_frame_budget), and at least merge_window.
  nanoseconds patience() const {
    return std::max(options.merge_window,
                    nanoseconds(frame_budget_ns.load(std::memory_order_relaxed)) / 2);
  }

  void set_ring(RingState state) {
    const RingState was = ring.exchange(state, std::memory_order_relaxed);
    if (was == RingState::whole && state == RingState::broken) breaks.fetch_add(1);
    if (was == RingState::broken && state == RingState::whole) heals.fetch_add(1);
  }

  // The exchange an arrival on side `at` belongs to. A port returns its frames in the order they
  // were sent, so among the exchanges sent with this first index and datagram count it is the
  // oldest whose copy on that side has not come back yet: a late half finds its own exchange
  // (answered or expired already), never a later one that reuses the index and is waiting. An
  // answered exchange stops owing a half once its send is older than claim_horizon() (that half
  // is lost: a cut cable). When none owes one: the newest (a duplicate).
  Exchange* find(std::size_t at, std::uint8_t index, std::size_t count, Clock::time_point now) {
    Exchange* owed = nullptr;
    Exchange* newest = nullptr;
    const Clock::time_point horizon = now - claim_horizon();
    for (auto& e : slots) {
      if (e.state == SlotState::free || e.first_index != index || e.count != count) continue;
      if (newest == nullptr || e.sequence > newest->sequence) newest = &e;
      const bool owes = e.leg_sent[at] && !e.arrived[at] &&
                        (e.state == SlotState::waiting || e.sent_at >= horizon);
      if (owes && (owed == nullptr || e.sequence < owed->sequence)) owed = &e;
    }
    return owed != nullptr ? owed : newest;
  }

  // How long an answered exchange still owns the halves that come back late: the frame budget
  // (the sender has given it up by then), and at least twice the patience.
  nanoseconds claim_horizon() const {
    return std::max(nanoseconds(frame_budget_ns.load(std::memory_order_relaxed)), 2 * patience());
  }

  Exchange& allocate() {
    Exchange* pick = nullptr;
    for (auto& e : slots) {
      if (e.state == SlotState::free) return e;
      // The oldest answered one, else the oldest of all (long given up by the bus).
      if (pick == nullptr || (e.state == SlotState::done && pick->state != SlotState::done) ||
          (e.state == pick->state && e.sequence < pick->sequence)) {
        pick = &e;
      }
    }
    return *pick;
  }

  // Hands `frame` to the bus as this receive()'s result.
  ReceivedFrame deliver(wire::Bytes frame, std::int64_t timestamp_ns,
                        const wire::MacAddress& source) {
    const std::size_t n = std::min(frame.size(), out.size());
    std::memcpy(out.data(), frame.data(), n);
    frames_received.fetch_add(1, std::memory_order_relaxed);
    bytes_received.fetch_add(n, std::memory_order_relaxed);
    return ReceivedFrame{wire::Bytes(out.data(), n), timestamp_ns, source};
  }

  std::optional<ReceivedFrame> complete_lone(Exchange& e, std::size_t s, bool after_window) {
    e.state = SlotState::done;
    lone.fetch_add(1, std::memory_order_relaxed);
    if (after_window) merge_timeouts.fetch_add(1, std::memory_order_relaxed);
    // Nothing at all came back by the other port: that side may be cut off (an empty copy that
    // came back is no silence).
    if (!e.arrived[other(s)]) ++silent[other(s)];
    return deliver(wire::Bytes(e.bounce[s].data(), e.bounce_size[s]), e.last_arrival_ns,
                   s == 0 ? options.primary_mac : options.secondary_mac);
  }

  // `arrival` with the datagrams its port's copy carried as NOP given back the request's command
  // (a NOP comes back as sent: working counter 0, data untouched), in `restored`. Under `mutex`.
  ReceivedFrame restore(const Exchange& e, const ReceivedFrame& arrival) {
    if (e.masked_count == 0) return arrival;
    const std::size_t n = std::min(arrival.frame.size(), restored.size());
    std::memcpy(restored.data(), arrival.frame.data(), n);
    for (std::size_t k = 0; k < e.masked_count; ++k) {
      const Masked& m = e.masked[k];
      if (m.offset < n && restored[m.offset] == static_cast<std::uint8_t>(wire::Command::nop)) {
        restored[m.offset] = m.command;
      }
    }
    ReceivedFrame put_back = arrival;
    put_back.frame = wire::Bytes(restored.data(), n);
    return put_back;
  }

  std::optional<ReceivedFrame> on_arrival(RedundantPort port, const ReceivedFrame& arrival) {
    const std::size_t at = side(port);
    legs[at].frames_received.fetch_add(1, std::memory_order_relaxed);
    const auto decoded = wire::decode_frame(arrival.frame);
    if (!decoded) {
      // Not ours to judge: the bus counts what does not decode.
      return deliver(arrival.frame, arrival.timestamp_ns, arrival.source);
    }
    const wire::DatagramView first = *decoded.frame->begin();
    std::lock_guard lock(mutex);
    Exchange* e = find(at, first.header.index, decoded.frame->datagram_count(), Clock::now());
    const wire::Bytes sent = e ? wire::Bytes(e->sent.data(), e->sent_size) : wire::Bytes{};
    const ReceivedFrame frame = e != nullptr ? restore(*e, arrival) : arrival;
    if (e == nullptr || !wire::same_shape(sent, frame.frame)) {
      stale.fetch_add(1, std::memory_order_relaxed);
      ignored.fetch_add(1, std::memory_order_relaxed);
      return std::nullopt;
    }
    const bool arrived_before = e->arrived[at];
    e->arrived[at] = true;
    owed_since[at] = kNever;  // this side answers (late, perhaps): it owes nothing any more
    if (wire::is_passthrough_copy(sent, frame.frame)) {
      silent[at] = 0;
      passthrough.fetch_add(1, std::memory_order_relaxed);
      ignored.fetch_add(1, std::memory_order_relaxed);
      // The other side's lone bounce need not wait for this side any more.
      if (e->state == SlotState::waiting && e->has_bounce[other(at)] && !e->has_bounce[at]) {
        return complete_lone(*e, other(at), false);
      }
      return std::nullopt;
    }
    const ArrivalKind kind =
        wire::classify_arrival(port, frame.source, options.primary_mac, options.secondary_mac);
    note_reader(kind, sent, frame.frame);
    if (kind == ArrivalKind::primary_bounce || kind == ArrivalKind::secondary_bounce) {
      const std::size_t s = kind == ArrivalKind::primary_bounce ? 0 : 1;
      silent[s] = 0;
      if (wire::any_processed(frame.frame)) set_ring(RingState::broken);
      if (e->state != SlotState::waiting) {
        // The late half of an exchange answered or expired without it (a second copy of a half
        // that came is stale): counted and dropped, never merged into another exchange.
        (arrived_before ? stale : late_halves).fetch_add(1, std::memory_order_relaxed);
        return std::nullopt;
      }
      const std::size_t n = std::min(frame.frame.size(), e->bounce[s].size());
      std::memcpy(e->bounce[s].data(), frame.frame.data(), n);
      e->bounce_size[s] = n;
      e->has_bounce[s] = true;
      e->last_arrival_ns = std::max(e->last_arrival_ns, frame.timestamp_ns);
      if (e->has_bounce[other(s)]) {
        auto result = wire::merge_bounces(sent, wire::Bytes(e->bounce[0].data(), e->bounce_size[0]),
                                          wire::Bytes(e->bounce[1].data(), e->bounce_size[1]),
                                          wire::MutableBytes(out));
        e->state = SlotState::done;
        if (!result) return std::nullopt;  // shapes were checked: cannot happen
        merged.fetch_add(1, std::memory_order_relaxed);
        frames_received.fetch_add(1, std::memory_order_relaxed);
        bytes_received.fetch_add(result->size(), std::memory_order_relaxed);
        return ReceivedFrame{*result, e->last_arrival_ns, options.primary_mac};
      }
      // The other side sent nothing, or already came back empty.
      const std::size_t o = other(s);
      if (!e->leg_sent[o] || e->arrived[o]) return complete_lone(*e, s, false);
      // The window: the other side's half is awaited until it has owed a frame for the whole
      // patience (from the oldest frame it still owes, not from this one: frames sent after a
      // cable was cut do not each wait it again), and at least merge_window from now. A side that
      // owed one longer is cut off: no wait.
      const Clock::time_point now = Clock::now();
      owed_since[o] = std::min(owed_since[o], e->sent_at);
      const Clock::time_point patience_end = owed_since[o] + patience();
      if (now >= patience_end) return complete_lone(*e, s, false);
      e->window_end = std::max(now + options.merge_window, patience_end);
      return std::nullopt;
    }
    if (e->state != SlotState::waiting) return std::nullopt;  // answered already
    e->state = SlotState::done;
    switch (kind) {
      case ArrivalKind::forward_cross:
        forward_crosses.fetch_add(1, std::memory_order_relaxed);
        silent = {};
        set_ring(RingState::whole);
        break;
      case ArrivalKind::reverse_cross:
        reverse_crosses.fetch_add(1, std::memory_order_relaxed);
        set_ring(RingState::whole);
        break;
      default:
        unknown_sources.fetch_add(1, std::memory_order_relaxed);
        break;
    }
    return deliver(frame.frame, frame.timestamp_ns, frame.source);
  }

  // A lone bounce whose window has run out, if any; also the earliest window still open.
  std::optional<ReceivedFrame> expire_windows(Clock::time_point now, Clock::time_point& next) {
    std::lock_guard lock(mutex);
    for (auto& e : slots) {
      if (e.state != SlotState::waiting || e.has_bounce[0] == e.has_bounce[1]) continue;
      if (e.window_end <= now) return complete_lone(e, e.has_bounce[0] ? 0 : 1, true);
      next = std::min(next, e.window_end);
    }
    return std::nullopt;
  }

  // What port `k` sends of `frame`: the frame itself, or a copy in `port_copy` whose datagrams
  // that match the port's selector are NOPs (recorded in `e`, under the lock, for restore()).
  // A processed copy of port j's frame came back (`kind`): whether the datagram the other port's
  // conditional selector matches had its data changed on j's side (a reader there). Under `mutex`.
  void note_reader(ArrivalKind kind, wire::Bytes sent, wire::Bytes arrived) {
    std::size_t from = 0;
    if (kind == ArrivalKind::forward_cross || kind == ArrivalKind::primary_bounce) {
      from = 0;
    } else if (kind == ArrivalKind::reverse_cross || kind == ArrivalKind::secondary_bounce) {
      from = 1;
    } else {
      return;
    }
    const std::size_t k = other(from);
    for (std::size_t slot = 0; slot < kNopSlots; ++slot) {
      const std::uint64_t selector = nop_selector[k][slot].load(std::memory_order_acquire);
      if ((selector & kSelectorWhileOtherReads) == 0) continue;
      const auto request = wire::decode_frame(sent);
      const auto reply = wire::decode_frame(arrived);
      if (!request || !reply) return;
      auto r = reply.frame->begin();
      for (const wire::DatagramView d : *request.frame) {
        if (r == reply.frame->end()) break;
        const wire::DatagramView got = *r;
        ++r;
        if (!matches(selector, d.header)) continue;
        other_side_reads[k][slot] = got.wkc > 0 && !std::equal(d.data.begin(), d.data.end(),
                                                               got.data.begin(), got.data.end());
        break;
      }
    }
  }

  wire::Bytes port_copy_of(std::size_t k, wire::Bytes frame, Exchange& e) {
    // The port's selectors that apply to this frame (inactive ones are 0).
    std::array<std::uint64_t, kNopSlots> selectors{};
    bool any = false;
    for (std::size_t slot = 0; slot < kNopSlots; ++slot) {
      const std::uint64_t selector = nop_selector[k][slot].load(std::memory_order_acquire);
      if ((selector & kSelectorActive) == 0) continue;
      if ((selector & kSelectorWhileOtherReads) != 0) {
        // Only while the other side reads it, and has not gone silent (a cut cable).
        std::lock_guard lock(mutex);
        if (!other_side_reads[k][slot] || silent[other(k)] > 0) continue;
      }
      selectors[slot] = selector;
      any = true;
    }
    if (!any) return frame;
    const auto matches_any = [&](const wire::DatagramHeader& h) {
      return std::any_of(selectors.begin(), selectors.end(),
                         [&](std::uint64_t selector) { return matches(selector, h); });
    };
    const auto decoded = wire::decode_frame(frame);
    if (!decoded) return frame;
    bool copied = false;
    std::array<Masked, kMaxMasked> found{};
    std::size_t count = 0;
    for (const wire::DatagramView d : *decoded.frame) {
      if (count == kMaxMasked) break;
      if (!matches_any(d.header)) continue;
      if (!copied) {
        std::memcpy(port_copy.data(), frame.data(), frame.size());
        copied = true;
      }
      const auto offset =
          static_cast<std::size_t>(d.data.data() - frame.data()) - wire::kDatagramHeaderSize;
      port_copy[offset] = static_cast<std::uint8_t>(wire::Command::nop);
      found[count++] = Masked{static_cast<std::uint16_t>(offset), frame[offset]};
    }
    if (!copied) return frame;
    std::lock_guard lock(mutex);
    for (std::size_t i = 0; i < count && e.masked_count < kMaxMasked; ++i) {
      bool known = false;
      for (std::size_t j = 0; j < e.masked_count; ++j)
        known = known || e.masked[j].offset == found[i].offset;
      if (!known) e.masked[e.masked_count++] = found[i];
    }
    return wire::Bytes(port_copy.data(), frame.size());
  }

  void leg_failed(std::size_t s) { legs[s].healthy.store(false, std::memory_order_relaxed); }

  // One receive on leg `s`; an arrival that completes an exchange is returned.
  Result<std::optional<ReceivedFrame>> take(std::size_t s, nanoseconds wait,
                                            bool* got_frame = nullptr) {
    Leg& leg = legs[s];
    if (!leg.healthy.load(std::memory_order_relaxed)) return std::optional<ReceivedFrame>{};
    auto received = leg.link->receive(wait);
    if (!received) {
      leg.receive_errors.fetch_add(1, std::memory_order_relaxed);
      leg_failed(s);
      return std::move(received).error();
    }
    if (!*received) return std::optional<ReceivedFrame>{};
    if (got_frame != nullptr) *got_frame = true;
    return on_arrival(s == 0 ? RedundantPort::primary : RedundantPort::secondary, **received);
  }

  // Waits until `until` for anything on either healthy leg, or interrupt()/close(): one ppoll on
  // both legs' descriptors (Link::wait_fd) and the interrupter, so an arrival on either port ends
  // it at once and an idle link sleeps. Without a descriptor on some healthy leg: a slice on one
  // leg (arrivals there are handled), the legs in turn.
  Result<std::optional<ReceivedFrame>> wait(Clock::time_point now, Clock::time_point until) {
    std::array<pollfd, 3> fds{};
    std::size_t n = 0;
    bool all_waitable = true;
    for (std::size_t k = 0; k < 2; ++k) {
      if (!legs[k].healthy.load(std::memory_order_relaxed)) continue;
      const int fd = legs[k].link->wait_fd();
      if (fd < 0) {
        all_waitable = false;
        break;
      }
      fds[n].fd = fd;
      fds[n].events = POLLIN;
      ++n;
    }
    if (!all_waitable) return wait_on_one_leg(now, until);
    fds[n].fd = interrupter.fd();
    fds[n].events = POLLIN;
    ++n;
    const std::int64_t left =
        std::max<std::int64_t>(0, std::chrono::duration_cast<nanoseconds>(until - now).count());
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(left / 1'000'000'000);
    ts.tv_nsec = static_cast<long>(left % 1'000'000'000);
    const int r = ::ppoll(fds.data(), n, &ts, nullptr);
    // ppoll fails only for want of memory: wait as a link without descriptors would.
    if (r < 0 && errno != EINTR) return wait_on_one_leg(Clock::now(), until);
    // A wake-up whose interrupt was already taken: drained, or it would end every later wait.
    if (r > 0 && (fds[n - 1].revents & POLLIN) != 0 && !interrupter.pending()) {
      interrupter.drain();
    }
    return std::optional<ReceivedFrame>{};
  }

  Result<std::optional<ReceivedFrame>> wait_on_one_leg(Clock::time_point now,
                                                       Clock::time_point until) {
    std::size_t k = next_leg_to_wait;
    if (!legs[k].healthy.load(std::memory_order_relaxed)) k = other(k);
    next_leg_to_wait = other(next_leg_to_wait);
    const nanoseconds slice = std::min<nanoseconds>(kSlice, until - now);
    return take(k, std::max(nanoseconds(0), slice));
  }

  bool any_healthy() const {
    return legs[0].healthy.load(std::memory_order_relaxed) ||
           legs[1].healthy.load(std::memory_order_relaxed);
  }

  void maybe_reopen(std::size_t s, Clock::time_point now) {
    Leg& leg = legs[s];
    if (leg.healthy.load(std::memory_order_relaxed) || !leg.reopenable || now < leg.next_reopen) {
      return;
    }
    leg.next_reopen = now + options.reopen_interval;
    auto reopened = leg.link->reopen();
    if (reopened) {
      leg.reopens.fetch_add(1, std::memory_order_relaxed);
    } else if (reopened.error().code() == Errc::unsupported) {
      leg.reopenable = false;
    }
  }
};

Result<std::unique_ptr<RedundantLink>> RedundantLink::open(std::unique_ptr<Link> primary,
                                                           std::unique_ptr<Link> secondary,
                                                           RedundantLinkOptions options) {
  if (!primary || !secondary) {
    return Error(Errc::invalid_argument, "a redundant link needs two links, primary and secondary");
  }
  for (const Link* leg : {primary.get(), secondary.get()}) {
    if (dynamic_cast<const UdpLink*>(leg) != nullptr) {
      return Error(Errc::unsupported,
                   fmt::format("cable redundancy needs two raw Ethernet ports at the two ends of "
                               "the ring (raw:eth0,eth1); {} is EtherCAT over UDP, which cannot "
                               "close a ring",
                               leg->name()));
    }
  }
  if (wire::same_station_mac(options.primary_mac, options.secondary_mac)) {
    return Error(
        Errc::invalid_argument,
        fmt::format("redundant link over {} and {}: both send from {}, so replies "
                    "cannot be told apart; give the ports different addresses",
                    primary->name(), secondary->name(), wire::to_string(options.primary_mac)));
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->name = fmt::format("redundant:{},{}", primary->name(), secondary->name());
  if (auto r = impl->interrupter.open(impl->name); !r) return std::move(r).error();
  impl->max_frame = std::min(primary->max_frame_size(), secondary->max_frame_size());
  impl->legs[0].name = primary->name();
  impl->legs[1].name = secondary->name();
  impl->legs[0].link = std::move(primary);
  impl->legs[1].link = std::move(secondary);
  return std::unique_ptr<RedundantLink>(new RedundantLink(std::move(impl)));
}

Result<std::unique_ptr<RedundantLink>> RedundantLink::open_raw(std::string primary_interface,
                                                               std::string secondary_interface,
                                                               RedundantLinkOptions options) {
  if (primary_interface == secondary_interface) {
    return Error(Errc::invalid_argument,
                 fmt::format("redundant link: primary and secondary are both {}; a ring needs "
                             "two interfaces",
                             primary_interface));
  }
  RawLinkOptions a;
  a.interface = std::move(primary_interface);
  auto primary = RawLink::open(std::move(a));
  if (!primary) return primary.error().context("opening the redundant link's primary port");
  RawLinkOptions b;
  b.interface = std::move(secondary_interface);
  auto secondary = RawLink::open(std::move(b));
  if (!secondary) return secondary.error().context("opening the redundant link's secondary port");
  options.primary_mac = (*primary)->source_mac();
  options.secondary_mac = (*secondary)->source_mac();
  return open(std::move(*primary), std::move(*secondary), options);
}

RedundantLink::RedundantLink(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RedundantLink::~RedundantLink() = default;

Result<void> RedundantLink::send(wire::Bytes ethercat_frame) {
  Impl& s = *impl_;
  if (s.closed.load(std::memory_order_acquire)) {
    return Error(Errc::closed, fmt::format("link {} is closed", s.name));
  }
  if (ethercat_frame.size() > s.max_frame) {
    return Error(Errc::invalid_argument,
                 fmt::format("a {}-byte frame does not fit link {} (at most {} bytes)",
                             ethercat_frame.size(), s.name, s.max_frame));
  }
  const Clock::time_point now = Clock::now();
  Exchange* e = nullptr;
  if (const auto decoded = wire::decode_frame(ethercat_frame)) {
    std::lock_guard lock(s.mutex);
    e = &s.allocate();
    e->state = SlotState::waiting;
    e->sequence = s.next_sequence++;
    e->first_index = (*decoded.frame->begin()).header.index;
    e->count = decoded.frame->datagram_count();
    std::memcpy(e->sent.data(), ethercat_frame.data(), ethercat_frame.size());
    e->sent_size = ethercat_frame.size();
    e->leg_sent = {true, true};
    e->arrived = {};
    e->has_bounce = {};
    e->last_arrival_ns = 0;
    e->sent_at = now;
    e->masked_count = 0;
  }
  std::optional<Error> first_error;
  std::array<bool, 2> sent{};
  for (std::size_t k = 0; k < 2; ++k) {
    Leg& leg = s.legs[k];
    s.maybe_reopen(k, now);
    const wire::Bytes copy = e != nullptr ? s.port_copy_of(k, ethercat_frame, *e) : ethercat_frame;
    auto result = leg.link->send(copy);
    sent[k] = static_cast<bool>(result);
    if (result) {
      leg.frames_sent.fetch_add(1, std::memory_order_relaxed);
      leg.healthy.store(true, std::memory_order_relaxed);
    } else {
      leg.send_errors.fetch_add(1, std::memory_order_relaxed);
      s.leg_failed(k);
      if (!first_error) first_error = std::move(result).error();
    }
  }
  if (e != nullptr) {
    std::lock_guard lock(s.mutex);
    e->leg_sent = sent;
    if (!sent[0] && !sent[1]) e->state = SlotState::free;
  }
  if (!sent[0] && !sent[1]) {
    s.send_errors.fetch_add(1, std::memory_order_relaxed);
    return first_error->context(first_error->code(),
                                fmt::format("sending on both ports of {} failed", s.name));
  }
  s.frames_sent.fetch_add(1, std::memory_order_relaxed);
  s.bytes_sent.fetch_add(ethercat_frame.size(), std::memory_order_relaxed);
  return {};
}

Result<std::optional<ReceivedFrame>> RedundantLink::receive(nanoseconds timeout) {
  Impl& s = *impl_;
  if (s.closed.load(std::memory_order_acquire)) {
    return Error(Errc::closed, fmt::format("link {} is closed", s.name));
  }
  const Clock::time_point deadline =
      timeout > nanoseconds(0) ? Clock::now() + timeout : Clock::now();
  std::optional<Error> error;
  for (;;) {
    // Everything already waiting on either leg first, the primary first: on a whole ring its
    // queue holds the secondary's passthrough copies, which must not pile up behind the replies.
    for (std::size_t k : {std::size_t{0}, std::size_t{1}}) {
      for (std::size_t n = 0; n < kSlots; ++n) {
        bool got_frame = false;
        auto taken = s.take(k, nanoseconds(0), &got_frame);
        if (!taken) {
          error = std::move(taken).error();
          break;
        }
        if (*taken) return std::move(*taken);
        if (!got_frame) break;  // a frame that completed nothing: look again
      }
    }
    const Clock::time_point now = Clock::now();
    Clock::time_point next = deadline;
    if (auto lone = s.expire_windows(now, next)) return std::move(*lone);
    if (!s.any_healthy()) {
      s.receive_errors.fetch_add(1, std::memory_order_relaxed);
      if (error) {
        return error->context(error->code(),
                              fmt::format("receiving on both ports of {} failed", s.name));
      }
      return Error(Errc::io_error, fmt::format("both ports of {} fail", s.name));
    }
    if (s.interrupter.consume() || now >= deadline) return std::optional<ReceivedFrame>{};
    if (s.closed.load(std::memory_order_acquire)) {
      return Error(Errc::closed, fmt::format("link {} is closed", s.name));
    }
    auto waited = s.wait(now, next);
    if (!waited) {
      error = std::move(waited).error();
      continue;
    }
    if (*waited) return std::move(*waited);
  }
}

void RedundantLink::interrupt() {
  impl_->interrupter.signal();
  // A leg a receive() waits in (one without a descriptor: Impl::wait).
  for (auto& leg : impl_->legs)
    leg.link->interrupt();
}

void RedundantLink::close() {
  impl_->closed.store(true, std::memory_order_release);
  impl_->interrupter.signal();
  for (auto& leg : impl_->legs)
    leg.link->close();
}

Result<void> RedundantLink::reopen() {
  Impl& s = *impl_;
  if (s.closed.load(std::memory_order_acquire)) {
    return Error(Errc::closed, fmt::format("link {} is closed", s.name));
  }
  std::optional<Error> error;
  for (auto& leg : s.legs) {
    if (leg.healthy.load(std::memory_order_relaxed)) continue;
    auto reopened = leg.link->reopen();
    if (reopened) {
      leg.reopens.fetch_add(1, std::memory_order_relaxed);
      leg.healthy.store(true, std::memory_order_relaxed);
    } else if (!error) {
      error = std::move(reopened).error();
    }
  }
  if (s.any_healthy()) return {};
  return error ? error->context(error->code(), fmt::format("reopening {}", s.name))
               : Error(Errc::io_error, fmt::format("reopening {}: no port works", s.name));
}

void RedundantLink::set_frame_budget(nanoseconds budget) {
  impl_->frame_budget_ns.store(std::max<std::int64_t>(0, budget.count()),
                               std::memory_order_relaxed);
}

Result<void> RedundantLink::set_port_nop(Port port, NopSlot slot,
                                         std::optional<DatagramSelector> selector) {
  const std::size_t k = port == Port::primary ? 0 : 1;
  const auto s = static_cast<std::size_t>(slot);
  if (s >= kNopSlots) {
    return Error(Errc::invalid_argument,
                 fmt::format("per-port frame contents: no selector slot {}", s));
  }
  {
    std::lock_guard lock(impl_->mutex);
    impl_->other_side_reads[k][s] = false;
  }
  impl_->nop_selector[k][s].store(selector ? pack(*selector) : 0, std::memory_order_release);
  return {};
}

std::string RedundantLink::name() const {
  return impl_->name;
}

LinkStats RedundantLink::stats() const {
  const Impl& s = *impl_;
  LinkStats out;
  out.frames_sent = s.frames_sent.load(std::memory_order_relaxed);
  out.frames_received = s.frames_received.load(std::memory_order_relaxed);
  out.bytes_sent = s.bytes_sent.load(std::memory_order_relaxed);
  out.bytes_received = s.bytes_received.load(std::memory_order_relaxed);
  out.frames_ignored = s.ignored.load(std::memory_order_relaxed);
  out.send_errors = s.send_errors.load(std::memory_order_relaxed);
  out.receive_errors = s.receive_errors.load(std::memory_order_relaxed);
  for (const auto& leg : s.legs) {
    const LinkStats l = leg.link->stats();
    out.frames_ignored += l.frames_ignored;
    out.frames_dropped += l.frames_dropped;
  }
  return out;
}

std::size_t RedundantLink::max_frame_size() const {
  return impl_->max_frame;
}

RedundancyStatus RedundantLink::status() const {
  const Impl& s = *impl_;
  RedundancyStatus out;
  const auto port = [](const Leg& leg) {
    RedundantPortStatus p;
    p.name = leg.name;
    p.healthy = leg.healthy.load(std::memory_order_relaxed);
    p.frames_sent = leg.frames_sent.load(std::memory_order_relaxed);
    p.frames_received = leg.frames_received.load(std::memory_order_relaxed);
    p.send_errors = leg.send_errors.load(std::memory_order_relaxed);
    p.receive_errors = leg.receive_errors.load(std::memory_order_relaxed);
    p.reopens = leg.reopens.load(std::memory_order_relaxed);
    return p;
  };
  out.primary = port(s.legs[0]);
  out.secondary = port(s.legs[1]);
  out.topology = out.primary.healthy
                     ? (out.secondary.healthy ? RedundancyTopology::redundant
                                              : RedundancyTopology::degraded_secondary_leg)
                     : (out.secondary.healthy ? RedundancyTopology::degraded_primary_leg
                                              : RedundancyTopology::offline);
  out.ring = s.ring.load(std::memory_order_relaxed);
  out.forward_crosses = s.forward_crosses.load(std::memory_order_relaxed);
  out.reverse_crosses = s.reverse_crosses.load(std::memory_order_relaxed);
  out.passthrough_copies = s.passthrough.load(std::memory_order_relaxed);
  out.merged = s.merged.load(std::memory_order_relaxed);
  out.lone_bounces = s.lone.load(std::memory_order_relaxed);
  out.merge_timeouts = s.merge_timeouts.load(std::memory_order_relaxed);
  out.late_halves = s.late_halves.load(std::memory_order_relaxed);
  out.unknown_sources = s.unknown_sources.load(std::memory_order_relaxed);
  out.stale = s.stale.load(std::memory_order_relaxed);
  out.ring_breaks = s.breaks.load(std::memory_order_relaxed);
  out.ring_heals = s.heals.load(std::memory_order_relaxed);
  return out;
}

}  // namespace ecat::link
