#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::sim {

using wire::RedundantPort;

namespace {

// One down cable in a description: 0 and N are the master's cables.
std::string cable_text(std::size_t cable, std::size_t slave_count) {
  if (cable == 0) return "master break primary";
  if (cable == slave_count) return "master break secondary";
  return fmt::format("break after {}", cable);
}

}  // namespace

RedundantTopology RedundantTopology::cables_down(std::vector<std::size_t> cables,
                                                 std::size_t slave_count) {
  std::sort(cables.begin(), cables.end());
  cables.erase(std::unique(cables.begin(), cables.end()), cables.end());
  if (cables.empty()) return whole_ring();
  if (cables.size() == 1) {
    if (cables[0] == 0) return cut_at(RedundantPort::primary);
    if (cables[0] == slave_count) return cut_at(RedundantPort::secondary);
    return broken_after(cables[0]);
  }
  RedundantTopology t;
  t.kind = Kind::several;
  t.cables = std::move(cables);
  t.slaves = slave_count;
  return t;
}

std::string describe(const RedundantTopology& topology) {
  switch (topology.kind) {
    case RedundantTopology::Kind::break_after:
      return fmt::format("break after {}", topology.break_after);
    case RedundantTopology::Kind::master_break:
      return fmt::format("master break {}", wire::to_string(topology.master_break));
    case RedundantTopology::Kind::several: {
      std::string out;
      for (const std::size_t cable : topology.cables)
        out += (out.empty() ? "" : ", ") + cable_text(cable, topology.slaves);
      return out;
    }
    case RedundantTopology::Kind::whole:
      break;
  }
  return "whole";
}

Result<std::vector<bool>> cables_down(const RedundantTopology& topology, std::size_t slave_count) {
  std::vector<bool> down(slave_count + 1, false);
  switch (topology.kind) {
    case RedundantTopology::Kind::whole:
      break;
    case RedundantTopology::Kind::break_after:
      if (topology.break_after < 1 || topology.break_after >= slave_count) {
        return Error(
            Errc::invalid_argument,
            fmt::format("a ring of {} slaves cannot break after slave {} (1..{})", slave_count,
                        topology.break_after, slave_count > 0 ? slave_count - 1 : 0));
      }
      down[topology.break_after] = true;
      break;
    case RedundantTopology::Kind::master_break:
      down[topology.master_break == RedundantPort::primary ? 0 : slave_count] = true;
      break;
    case RedundantTopology::Kind::several:
      for (const std::size_t cable : topology.cables) {
        if (cable > slave_count) {
          return Error(Errc::invalid_argument,
                       fmt::format("a ring of {} slaves has no cable {} (0..{})", slave_count,
                                   cable, slave_count));
        }
        down[cable] = true;
      }
      break;
  }
  return down;
}

std::string describe(const RedundantCabling& cabling) {
  std::string out = describe(cabling.topology);
  for (const RedundantPort port : {RedundantPort::primary, RedundantPort::secondary}) {
    const RedundantPortDelay& d = cabling.delays[static_cast<std::size_t>(port)];
    if (d.delay.count() <= 0) continue;
    out += fmt::format("; {} +{} us{}", wire::to_string(port),
                       static_cast<double>(d.delay.count()) / 1e3,
                       d.from ? fmt::format(" (from {})", wire::to_string(*d.from)) : "");
  }
  return out;
}

RedundantRoute route_redundant(const std::vector<bool>& down, RedundantPort ingress) {
  const std::size_t n = down.empty() ? 0 : down.size() - 1;
  if (ingress == RedundantPort::primary) {
    if (n == 0 || down[0]) return RedundantRoute{0, 0, std::nullopt};
    // Out of each slave's port 1 until a cable without link: that port closes its loop.
    for (std::size_t cable = 1; cable <= n; ++cable) {
      if (down[cable]) return RedundantRoute{0, cable, RedundantPort::primary};
    }
    return RedundantRoute{0, n, RedundantPort::secondary};
  }
  if (n == 0 || down[n]) return RedundantRoute{0, 0, std::nullopt};
  // In at the last slave's port 1, unprocessed towards slave 0 (the processing unit sits on the
  // way out of port 0) until a port 0 without link turns it round into the processing unit.
  for (std::size_t cable = n; cable-- > 0;) {
    if (down[cable]) return RedundantRoute{cable, n, RedundantPort::secondary};
  }
  return RedundantRoute{n, n, RedundantPort::primary};
}

Result<RedundantRoute> route_redundant(const RedundantTopology& topology, std::size_t slave_count,
                                       RedundantPort ingress) {
  auto down = cables_down(topology, slave_count);
  if (!down) return std::move(down).error();
  return route_redundant(*down, ingress);
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

  // A reply to a frame that entered by `ingress`, held back by reorder_replies until the next one
  // leaves by the same port.
  std::array<Slot, 2> held;
  std::array<bool, 2> holding{};
  std::vector<std::uint8_t> reply = [] {
    std::vector<std::uint8_t> v;
    v.reserve(wire::kMaxFrameSize);
    return v;
  }();

  // Queues a reply for `port` in the order of the times it is due (a late one is overtaken, as on
  // a wire). False on a full queue.
  bool enqueue(std::size_t port, const std::uint8_t* data, std::size_t size,
               const wire::MacAddress& source, std::chrono::steady_clock::time_point due) {
    PortQueue& q = queues[port];
    const std::size_t capacity = q.slots.size();
    if (q.count == capacity) {
      ++stats.overflowed;
      return false;
    }
    Slot& slot = q.slots[(q.head + q.count) % capacity];
    std::memcpy(slot.bytes.data(), data, size);
    slot.size = size;
    slot.source = source;
    slot.due = due;
    for (std::size_t i = q.count++; i > 0; --i) {
      Slot& before = q.slots[(q.head + i - 1) % capacity];
      Slot& at = q.slots[(q.head + i) % capacity];
      if (before.due <= at.due) break;
      std::swap(before, at);
    }
    return true;
  }

  // The frame the master sent on `ingress` (from `source`: the requester's address), through the
  // ring and the reply faults. Returns the port its reply leaves by, if any.
  std::optional<RedundantPort> carry(RedundantPort ingress, wire::Bytes frame,
                                     const wire::MacAddress& source) {
    std::unique_lock lock(mutex);
    ++stats.frames;
    if (server == nullptr || frame.size() > work.size()) {
      ++stats.lost;
      return std::nullopt;
    }
    std::memcpy(work.data(), frame.data(), frame.size());
    const std::span<std::uint8_t> bytes(work.data(), frame.size());
    // The cabling is the injector's (faults change it): the route and the delay are read under
    // the server's lock, with the frame's trip through the slaves and the reply faults.
    const std::int64_t now = server->now_ns();
    std::optional<RedundantPort> egress;
    RedundantPortDelay delay;
    ReplyPlan plan;
    const bool replied = server->with_segment([&](Segment& segment, FaultInjector& injector) {
      const auto& cabling = injector.redundant_cabling();
      const auto route = injector.redundant_route(ingress);
      if (!cabling || !route || !route->egress) return false;  // lost on a cut cable
      egress = route->egress;
      delay = cabling->delays[side(*egress)];
      injector.set_exchange_port(*egress);
      bool ok = false;
      if (route->first >= route->last) {
        ok = injector.pass_frame(bytes, now);  // passes every slave unprocessed
      } else {
        RangeHooks hooks(injector, route->first, route->last);
        segment.set_hooks(&hooks);
        ok = segment.process_frame(bytes, now);
        segment.set_hooks(&injector);
      }
      if (ok) {
        // The EtherCAT frame only, without the padding the request may have carried.
        std::size_t size = bytes.size();
        if (size >= wire::kFrameHeaderSize) {
          size = std::min(size, wire::kFrameHeaderSize + (wire::load_le16(bytes.data()) & 0x07FF));
        }
        reply.assign(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(size));
        plan = injector.shape_reply(reply);
      }
      injector.set_exchange_port(std::nullopt);
      return ok;
    });
    if (!replied) {
      ++stats.lost;
      return std::nullopt;
    }
    const std::size_t out = side(*egress);
    if (*egress == ingress) {
      ++stats.bounces;
    } else {
      ++stats.crosses;
    }
    wire::MacAddress from = source;
    from[0] |= 0x02;  // set by the ESCs the frame passed
    auto due = std::chrono::steady_clock::now() +
               std::chrono::duration_cast<std::chrono::steady_clock::duration>(plan.delay);
    if (!delay.from || *delay.from == ingress) {
      due += std::chrono::duration_cast<std::chrono::steady_clock::duration>(delay.delay);
    }
    if (plan.delay.count() > 0 || plan.hold) ++stats.delayed;
    if (plan.hold) {
      // Sent after the next reply that leaves by this port; one held before leaves now.
      if (holding[out]) {
        (void)enqueue(out, held[out].bytes.data(), held[out].size, held[out].source, due);
      }
      std::memcpy(held[out].bytes.data(), reply.data(), reply.size());
      held[out].size = reply.size();
      held[out].source = from;
      holding[out] = true;
    } else {
      for (std::size_t i = 0; i < plan.copies; ++i)
        (void)enqueue(out, reply.data(), reply.size(), from, due);
      stats.duplicated += plan.copies - 1;
      if (holding[out]) {
        (void)enqueue(out, held[out].bytes.data(), held[out].size, held[out].source, due);
        holding[out] = false;
      }
    }
    lock.unlock();
    arrived.notify_all();
    return egress;
  }

  // The earliest reply waiting for `port`, if any (steady clock).
  std::optional<std::chrono::steady_clock::time_point> next_due(RedundantPort port) const {
    std::lock_guard lock(mutex);
    const PortQueue& q = queues[side(port)];
    if (q.count == 0) return std::nullopt;
    return q.slots[q.head].due;
  }

  // Takes the reply at the head of `port`'s queue when it is due: copies it into `out` and gives
  // its size and source address.
  std::optional<std::pair<std::size_t, wire::MacAddress>> take_due(RedundantPort port,
                                                                   std::span<std::uint8_t> out) {
    std::lock_guard lock(mutex);
    PortQueue& q = queues[side(port)];
    if (q.count == 0 || q.slots[q.head].due > std::chrono::steady_clock::now()) {
      return std::nullopt;
    }
    const Slot& slot = q.slots[q.head];
    const std::size_t size = std::min(slot.size, out.size());
    std::memcpy(out.data(), slot.bytes.data(), size);
    const wire::MacAddress source = slot.source;
    q.head = (q.head + 1) % q.slots.size();
    --q.count;
    return std::make_pair(size, source);
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
    const auto& o = shared_->options;
    shared_->carry(port_, frame, port_ == RedundantPort::primary ? o.primary_mac : o.secondary_mac);
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

// ---- Serving two raw interfaces ----------------------------------------------------------------

struct RedundantPorts::Serving {
  std::shared_ptr<Shared> shared;
  std::array<std::unique_ptr<link::RawLink>, 2> links;
  // One sender per link at a time (a reply may leave by either port from either thread), and the
  // frame being sent.
  std::array<std::mutex, 2> send_mutex;
  std::array<std::vector<std::uint8_t>, 2> tx{std::vector<std::uint8_t>(wire::kMaxFrameSize),
                                              std::vector<std::uint8_t>(wire::kMaxFrameSize)};
  std::array<std::thread, 2> threads;
  std::atomic<bool> stopping{false};

  // Sends the replies due on `port`, in order. Returns whether some wait on (held back).
  bool flush(RedundantPort port) {
    const std::size_t i = side(port);
    std::lock_guard send_lock(send_mutex[i]);
    while (auto taken = shared->take_due(port, tx[i])) {
      const auto sent = links[i]->send_as(wire::Bytes(tx[i].data(), taken->first), taken->second,
                                          wire::kBroadcastMac);
      if (!sent) {
        std::lock_guard lock(shared->mutex);
        ++shared->stats.send_errors;
      }
    }
    return shared->next_due(port).has_value();
  }

  void run(RedundantPort port) {
    const std::size_t i = side(port);
    link::RawLink& link = *links[i];
    const RedundantPort other =
        port == RedundantPort::primary ? RedundantPort::secondary : RedundantPort::primary;
    while (!stopping.load(std::memory_order_relaxed)) {
      // The primary's thread keeps the segment's time moving (watchdogs, scheduled faults).
      std::chrono::nanoseconds timeout = std::chrono::milliseconds(100);
      if (port == RedundantPort::primary) {
        SimServer* server = nullptr;
        {
          std::lock_guard lock(shared->mutex);
          server = shared->server;
        }
        if (server != nullptr) timeout = server->tick();
      }
      if (const auto due = shared->next_due(port)) {
        const auto until = *due - std::chrono::steady_clock::now();
        timeout = std::max(
            std::chrono::nanoseconds(0),
            std::min(timeout, std::chrono::duration_cast<std::chrono::nanoseconds>(until)));
      }
      auto received = link.receive(timeout);
      if (stopping.load(std::memory_order_relaxed)) break;
      if (!received) {
        if (received.error().code() == Errc::closed) break;
        // An interface gone down: not a busy spin.
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
        continue;
      }
      if (received->has_value()) {
        const link::ReceivedFrame& frame = **received;
        if (const auto egress = shared->carry(port, frame.frame, frame.source)) {
          // Sent from here when due (no thread hop on the way out); a held-back reply on the
          // other port is that port's thread's to send: it learns its new deadline.
          if (flush(*egress) && *egress == other) links[side(other)]->interrupt();
        }
      }
      (void)flush(port);
    }
  }
};

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
  const RedundantCabling base{options.topology, options.delays};
  if (auto attached = server.with_segment(
          [&](Segment&, FaultInjector& injector) { return injector.attach_redundant_ring(base); });
      !attached) {
    return attached.error();
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
  stop();
  SimServer* server = nullptr;
  {
    std::lock_guard lock(shared_->mutex);
    server = std::exchange(shared_->server, nullptr);
  }
  if (server != nullptr) {
    server->with_segment(
        [](Segment&, FaultInjector& injector) { injector.detach_redundant_ring(); });
  }
}

std::unique_ptr<link::Link> RedundantPorts::take_link(RedundantPort port) {
  return std::make_unique<PortLink>(shared_, port);
}

Result<void> RedundantPorts::serve(std::unique_ptr<link::RawLink> primary,
                                   std::unique_ptr<link::RawLink> secondary) {
  if (!primary || !secondary) return Error(Errc::invalid_argument, "serve: a port has no link");
  if (serving_) {
    return Error(Errc::wrong_state,
                 fmt::format("the redundant segment already serves {}", served()));
  }
  auto serving = std::make_unique<Serving>();
  serving->shared = shared_;
  serving->links = {std::move(primary), std::move(secondary)};
  Serving& s = *serving;
  for (const RedundantPort port : {RedundantPort::primary, RedundantPort::secondary}) {
    s.threads[side(port)] = std::thread([&s, port] { s.run(port); });
  }
  serving_ = std::move(serving);
  return ok();
}

void RedundantPorts::stop() {
  if (!serving_) return;
  serving_->stopping = true;
  for (auto& link : serving_->links)
    link->interrupt();
  for (auto& thread : serving_->threads) {
    if (thread.joinable()) thread.join();
  }
  for (auto& link : serving_->links)
    link->close();
  serving_.reset();
}

bool RedundantPorts::serving() const {
  return serving_ != nullptr;
}

std::string RedundantPorts::served() const {
  if (!serving_) return {};
  return serving_->links[0]->name() + "," + serving_->links[1]->name();
}

Result<void> RedundantPorts::set_topology(const RedundantTopology& topology) {
  std::lock_guard lock(shared_->mutex);
  if (shared_->server == nullptr) return Error(Errc::closed, "the redundant segment is gone");
  return shared_->server->with_segment(
      [&](Segment&, FaultInjector& injector) { return injector.set_redundant_topology(topology); });
}

void RedundantPorts::set_delay(RedundantPort egress, std::chrono::nanoseconds delay,
                               std::optional<RedundantPort> from_ingress) {
  std::lock_guard lock(shared_->mutex);
  if (shared_->server == nullptr) return;
  shared_->server->with_segment([&](Segment&, FaultInjector& injector) {
    (void)injector.set_port_delay(egress, RedundantPortDelay{delay, from_ingress});
  });
}

RedundantTopology RedundantPorts::topology() const {
  std::lock_guard lock(shared_->mutex);
  if (shared_->server == nullptr) return {};
  return shared_->server->with_segment([](Segment&, FaultInjector& injector) {
    const auto& cabling = injector.redundant_cabling();
    return cabling ? cabling->topology : RedundantTopology{};
  });
}

RedundantPortsStats RedundantPorts::stats() const {
  std::lock_guard lock(shared_->mutex);
  return shared_->stats;
}

}  // namespace ecat::sim
