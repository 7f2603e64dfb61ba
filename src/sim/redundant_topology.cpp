#include <algorithm>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <vector>

#include <fmt/format.h>

#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::sim {

using wire::RedundantPort;

std::string describe(const RedundantTopology& topology) {
  switch (topology.kind) {
    case RedundantTopology::Kind::break_after:
      return fmt::format("break after {}", topology.break_after);
    case RedundantTopology::Kind::master_break:
      return fmt::format("master break {}", wire::to_string(topology.master_break));
    case RedundantTopology::Kind::whole:
      break;
  }
  return "whole";
}

Result<RedundantRoute> route_redundant(const RedundantTopology& topology, std::size_t slave_count,
                                       RedundantPort ingress) {
  const bool primary = ingress == RedundantPort::primary;
  switch (topology.kind) {
    case RedundantTopology::Kind::whole:
      // The processing unit sits on the way out of port 0: only the primary's frame meets it.
      if (primary) return RedundantRoute{0, slave_count, RedundantPort::secondary};
      return RedundantRoute{slave_count, slave_count, RedundantPort::primary};
    case RedundantTopology::Kind::break_after:
      if (topology.break_after < 1 || topology.break_after >= slave_count) {
        return Error(
            Errc::invalid_argument,
            fmt::format("a ring of {} slaves cannot break after slave {} (1..{})", slave_count,
                        topology.break_after, slave_count > 0 ? slave_count - 1 : 0));
      }
      if (primary) return RedundantRoute{0, topology.break_after, RedundantPort::primary};
      return RedundantRoute{topology.break_after, slave_count, RedundantPort::secondary};
    case RedundantTopology::Kind::master_break:
      if (ingress == topology.master_break) return RedundantRoute{0, 0, std::nullopt};
      // In from the far end, unprocessed to slave 0, whose open port 0 turns it round.
      return RedundantRoute{0, slave_count, ingress};
  }
  return Error(Errc::invalid_argument, "unknown redundant topology");
}

namespace {

// The fault injector's hooks with the slaves outside [first, last) cut off for one frame.
class RangeHooks final : public SegmentHooks {
 public:
  RangeHooks(SegmentHooks& inner, std::size_t first, std::size_t last)
      : inner_(inner), first_(first), last_(last) {}
  bool before_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) override {
    return inner_.before_frame(frame, now_ns);
  }
  bool slave_unreachable(std::size_t index) override {
    return index < first_ || index >= last_ || inner_.slave_unreachable(index);
  }
  void after_datagram(std::size_t index, std::size_t datagram_number, DatagramInFlight& datagram,
                      const DatagramEffect& effect) override {
    inner_.after_datagram(index, datagram_number, datagram, effect);
  }
  void after_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) override {
    inner_.after_frame(frame, now_ns);
  }

 private:
  SegmentHooks& inner_;
  std::size_t first_;
  std::size_t last_;
};

struct Slot {
  std::vector<std::uint8_t> bytes = std::vector<std::uint8_t>(wire::kMaxFrameSize);
  std::size_t size = 0;
  wire::MacAddress source{};
  std::chrono::steady_clock::time_point due{};
};

struct Delay {
  std::chrono::nanoseconds delay{0};
  std::optional<RedundantPort> from_ingress;
};

struct PortQueue {
  std::vector<Slot> slots;
  std::size_t head = 0;
  std::size_t count = 0;
  bool interrupted = false;
};

std::size_t side(RedundantPort port) {
  return port == RedundantPort::primary ? 0 : 1;
}

}  // namespace

struct RedundantPorts::Shared {
  SimServer* server = nullptr;  // null once the RedundantPorts is gone
  RedundantPortsOptions options;
  mutable std::mutex mutex;
  std::condition_variable arrived;
  std::array<PortQueue, 2> queues;
  std::vector<std::uint8_t> work = std::vector<std::uint8_t>(wire::kMaxFrameSize);
  RedundantPortsStats stats;
  std::size_t slave_count = 0;
  std::array<Delay, 2> delays{};  // per egress port

  // The frame the master sent on `ingress`, through the ring.
  void carry(RedundantPort ingress, wire::Bytes frame) {
    std::unique_lock lock(mutex);
    ++stats.frames;
    if (server == nullptr || frame.size() > work.size()) {
      ++stats.lost;
      return;
    }
    const auto route = route_redundant(options.topology, slave_count, ingress);
    if (!route || !route->egress) {
      ++stats.lost;
      return;
    }
    std::memcpy(work.data(), frame.data(), frame.size());
    const std::span<std::uint8_t> bytes(work.data(), frame.size());
    if (route->first < route->last) {
      const std::int64_t now = server->now_ns();
      const bool replied = server->with_segment([&](Segment& segment, FaultInjector& injector) {
        RangeHooks hooks(injector, route->first, route->last);
        segment.set_hooks(&hooks);
        const bool ok = segment.process_frame(bytes, now);
        segment.set_hooks(&injector);
        return ok;
      });
      if (!replied) {
        ++stats.lost;
        return;
      }
    }
    PortQueue& q = queues[side(*route->egress)];
    if (q.count == q.slots.size()) {
      ++stats.overflowed;
      return;
    }
    Slot& slot = q.slots[(q.head + q.count) % q.slots.size()];
    std::memcpy(slot.bytes.data(), bytes.data(), bytes.size());
    slot.size = bytes.size();
    slot.source = ingress == RedundantPort::primary ? options.primary_mac : options.secondary_mac;
    slot.source[0] |= 0x02;  // set by the ESCs the frame passed
    const Delay& delay = delays[side(*route->egress)];
    slot.due = std::chrono::steady_clock::now();
    if (!delay.from_ingress || *delay.from_ingress == ingress) slot.due += delay.delay;
    ++q.count;
    if (*route->egress == ingress) {
      ++stats.bounces;
    } else {
      ++stats.crosses;
    }
    lock.unlock();
    arrived.notify_all();
  }
};

namespace {

class PortLink final : public link::Link {
 public:
  PortLink(std::shared_ptr<RedundantPorts::Shared> shared, RedundantPort port)
      : shared_(std::move(shared)), port_(port) {}

  Result<void> send(wire::Bytes frame) override {
    if (closed_) return Error(Errc::closed, fmt::format("link {} is closed", name()));
    if (frame.size() > wire::kMaxFrameSize) {
      return Error(Errc::invalid_argument,
                   fmt::format("a {}-byte frame does not fit link {}", frame.size(), name()));
    }
    ++stats_.frames_sent;
    stats_.bytes_sent += frame.size();
    shared_->carry(port_, frame);
    return {};
  }

  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    if (closed_) return Error(Errc::closed, fmt::format("link {} is closed", name()));
    std::unique_lock lock(shared_->mutex);
    PortQueue& q = shared_->queues[side(port_)];
    // Replies leave in order: a held-back one holds up those behind it, as on a wire.
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    const auto ready = [&] {
      return q.count > 0 && q.slots[q.head].due <= std::chrono::steady_clock::now();
    };
    while (!ready() && !q.interrupted && std::chrono::steady_clock::now() < deadline) {
      auto until = deadline;
      if (q.count > 0) until = std::min(until, q.slots[q.head].due);
      shared_->arrived.wait_until(lock, until);
    }
    if (!ready()) {
      q.interrupted = false;
      return std::optional<link::ReceivedFrame>{};
    }
    const Slot& slot = q.slots[q.head];
    std::memcpy(held_.data(), slot.bytes.data(), slot.size);
    const wire::MacAddress source = slot.source;
    const std::size_t size = slot.size;
    q.head = (q.head + 1) % q.slots.size();
    --q.count;
    lock.unlock();
    ++stats_.frames_received;
    stats_.bytes_received += size;
    const auto now = std::chrono::steady_clock::now().time_since_epoch();
    return std::optional<link::ReceivedFrame>(link::ReceivedFrame{
        wire::Bytes(held_.data(), size),
        std::chrono::duration_cast<std::chrono::nanoseconds>(now).count(), source});
  }

  void interrupt() override {
    {
      std::lock_guard lock(shared_->mutex);
      shared_->queues[side(port_)].interrupted = true;
    }
    shared_->arrived.notify_all();
  }
  void close() override { closed_ = true; }
  std::string name() const override {
    return port_ == RedundantPort::primary ? "sim-primary" : "sim-secondary";
  }
  link::LinkStats stats() const override { return stats_; }

 private:
  std::shared_ptr<RedundantPorts::Shared> shared_;
  RedundantPort port_;
  std::vector<std::uint8_t> held_ = std::vector<std::uint8_t>(wire::kMaxFrameSize);
  link::LinkStats stats_;
  bool closed_ = false;
};

}  // namespace

Result<std::unique_ptr<RedundantPorts>> RedundantPorts::create(SimServer& server,
                                                               RedundantPortsOptions options) {
  if (wire::same_station_mac(options.primary_mac, options.secondary_mac)) {
    return Error(Errc::invalid_argument,
                 "a redundant segment's two master ports need different addresses");
  }
  const std::size_t count = server.slave_count();
  const auto order = server.with_segment(
      [](Segment& segment, FaultInjector&) { return segment.processing_order(); });
  for (std::size_t i = 0; i < order.size(); ++i) {
    if (order[i] != i) {
      return Error(Errc::invalid_argument,
                   fmt::format("a redundant segment needs its slaves in a line in ring order; "
                               "slave {} is visited at position {}",
                               order[i], i));
    }
  }
  if (auto checked = route_redundant(options.topology, count, RedundantPort::primary); !checked) {
    return checked.error();
  }
  std::unique_ptr<RedundantPorts> ports(new RedundantPorts());
  ports->shared_ = std::make_shared<Shared>();
  Shared& s = *ports->shared_;
  s.server = &server;
  s.options = options;
  s.slave_count = count;
  for (auto& q : s.queues)
    q.slots.resize(std::max<std::size_t>(1, options.queue_depth));
  return ports;
}

RedundantPorts::~RedundantPorts() {
  std::lock_guard lock(shared_->mutex);
  shared_->server = nullptr;
}

std::unique_ptr<link::Link> RedundantPorts::take_link(RedundantPort port) {
  return std::make_unique<PortLink>(shared_, port);
}

Result<void> RedundantPorts::set_topology(const RedundantTopology& topology) {
  std::lock_guard lock(shared_->mutex);
  if (auto checked = route_redundant(topology, shared_->slave_count, RedundantPort::primary);
      !checked) {
    return checked.error();
  }
  shared_->options.topology = topology;
  return {};
}

void RedundantPorts::set_delay(RedundantPort egress, std::chrono::nanoseconds delay,
                               std::optional<RedundantPort> from_ingress) {
  std::lock_guard lock(shared_->mutex);
  shared_->delays[side(egress)] = Delay{std::max(std::chrono::nanoseconds(0), delay), from_ingress};
}

RedundantTopology RedundantPorts::topology() const {
  std::lock_guard lock(shared_->mutex);
  return shared_->options.topology;
}

RedundantPortsStats RedundantPorts::stats() const {
  std::lock_guard lock(shared_->mutex);
  return shared_->stats;
}

}  // namespace ecat::sim
