#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <ctime>
#include <deque>
#include <thread>

#include <fmt/format.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::sim {

namespace {

std::int64_t monotonic_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// Replies ready to leave, in a reusable buffer: no allocation per frame in steady state.
struct Batch {
  std::vector<std::vector<std::uint8_t>> frames;
  std::size_t count = 0;

  void clear() noexcept { count = 0; }
  void push(wire::Bytes bytes) {
    if (count == frames.size()) frames.emplace_back();
    frames[count++].assign(bytes.begin(), bytes.end());
  }
};

}  // namespace

struct SimServer::Impl {
  struct Delayed {
    std::vector<std::uint8_t> bytes;
    std::int64_t due_ns = 0;
  };

  SimServerOptions options;
  // Guarded by SimServer::mutex_.
  SimServerStats stats;
  std::vector<std::uint8_t> buffer;
  std::deque<Delayed> delayed;  // ordered by due time
  std::optional<std::vector<std::uint8_t>> held;
  std::int64_t last_time = 0;
  std::int64_t last_advance = 0;
  std::string link_name;

  // The serving thread.
  std::unique_ptr<link::Link> link;
  std::thread thread;
  std::atomic<bool> stopping{false};
  std::mutex wait_mutex;
  std::condition_variable wait_cv;

  std::int64_t clock() {
    const std::int64_t t = options.clock ? options.clock() : monotonic_ns();
    // Segment time never runs backwards, whatever the clock does.
    last_time = std::max(last_time, t);
    return last_time;
  }

  // The segment time of a frame the link stamped at `stamped` (CLOCK_MONOTONIC): a frame is on
  // the wire when it was sent, not when this thread got round to it. A busy host can hold the
  // thread for hundreds of microseconds, where a real segment processes the frame microseconds
  // after the master sent it; distributed clocks (the reference's time in a frame) depend on it.
  // A stamp from the future or older than kMaxFrameAge is not trusted: then the time is now.
  std::int64_t frame_clock(std::int64_t stamped) {
    if (options.clock || stamped <= 0) return clock();
    constexpr std::int64_t kMaxFrameAge = 50'000'000;
    const std::int64_t now = monotonic_ns();
    const std::int64_t t = stamped <= now && now - stamped <= kMaxFrameAge ? stamped : now;
    last_time = std::max(last_time, t);
    return last_time;
  }

  void release_due(std::int64_t now, Batch& out) {
    while (!delayed.empty() && delayed.front().due_ns <= now) {
      out.push(delayed.front().bytes);
      delayed.pop_front();
    }
  }

  void schedule(wire::Bytes bytes, std::int64_t due) {
    auto it = std::upper_bound(delayed.begin(), delayed.end(), due,
                               [](std::int64_t d, const Delayed& x) { return d < x.due_ns; });
    delayed.insert(it, Delayed{{bytes.begin(), bytes.end()}, due});
    ++stats.delayed;
  }
};

SimServer::SimServer(std::unique_ptr<Segment> segment, SimServerOptions options)
    : segment_(segment ? std::move(segment) : std::make_unique<Segment>()),
      injector_(std::make_unique<FaultInjector>(*segment_)),
      impl_(std::make_unique<Impl>()) {
  impl_->options = std::move(options);
  if (impl_->options.advance_period <= std::chrono::nanoseconds(0)) {
    impl_->options.advance_period = std::chrono::milliseconds(1);
  }
  impl_->buffer.reserve(wire::kMaxFrameSize + 64);
  const std::int64_t now = impl_->clock();
  segment_->advance(now);
  impl_->last_advance = now;
}

SimServer::~SimServer() {
  stop();
  injector_.reset();
}

// ---- Frame handling -------------------------------------------------------------------------

namespace {

// One frame through the segment and the reply faults, under the server's lock. Replies that
// leave now go into `out`.
void handle_frame(SimServer::Impl& s, Segment& segment, FaultInjector& injector, wire::Bytes frame,
                  std::int64_t now, Batch& out) {
  ++s.stats.frames;
  s.release_due(now, out);
  s.buffer.assign(frame.begin(), frame.end());
  const std::uint64_t malformed_before = segment.stats().frames_malformed;
  const bool replied = segment.process_frame(s.buffer, now);
  s.last_advance = now;
  if (!replied) {
    if (segment.stats().frames_malformed != malformed_before) {
      ++s.stats.malformed;
    } else {
      ++s.stats.lost;
    }
    return;
  }
  // Reply with the EtherCAT frame only, without the padding the request may have carried.
  if (s.buffer.size() >= wire::kFrameHeaderSize) {
    const std::size_t length = wire::kFrameHeaderSize + (wire::load_le16(s.buffer.data()) & 0x07FF);
    if (length < s.buffer.size()) s.buffer.resize(length);
  }
  const ReplyPlan plan = injector.shape_reply(s.buffer);
  s.stats.duplicated += plan.copies > 0 ? plan.copies - 1 : 0;
  if (plan.delay.count() > 0) {
    for (std::size_t i = 0; i < plan.copies; ++i)
      s.schedule(s.buffer, now + plan.delay.count());
    return;
  }
  if (plan.hold) {
    if (s.held) out.push(*s.held);
    s.held.emplace(s.buffer.begin(), s.buffer.end());
    ++s.stats.delayed;
    return;
  }
  for (std::size_t i = 0; i < plan.copies; ++i)
    out.push(s.buffer);
  if (s.held) {
    out.push(*s.held);
    s.held.reset();
  }
}

}  // namespace

std::vector<std::vector<std::uint8_t>> SimServer::exchange(wire::Bytes frame) {
  Batch out;
  {
    std::lock_guard lock(mutex_);
    handle_frame(*impl_, *segment_, *injector_, frame, impl_->clock(), out);
    impl_->stats.replies += out.count;
  }
  out.frames.resize(out.count);
  return std::move(out.frames);
}

std::unique_ptr<link::Link> SimServer::function_link(std::string name) {
  auto batch = std::make_shared<Batch>();
  link::FunctionLinkOptions options;
  options.name = std::move(name);
  options.reply_queue_depth = 64;
  return link::make_function_link(
      [this, batch](wire::Bytes request, link::ReplySink& sink) {
        batch->clear();
        {
          std::lock_guard lock(mutex_);
          handle_frame(*impl_, *segment_, *injector_, request, impl_->clock(), *batch);
        }
        std::size_t sent = 0;
        for (std::size_t i = 0; i < batch->count; ++i) {
          if (sink.reply(batch->frames[i])) ++sent;
        }
        std::lock_guard lock(mutex_);
        impl_->stats.replies += sent;
        impl_->stats.send_errors += batch->count - sent;
      },
      std::move(options));
}

// ---- Serving thread -------------------------------------------------------------------------

Result<void> SimServer::serve(std::unique_ptr<link::Link> link) {
  if (!link) return Error(Errc::invalid_argument, "serve: no link");
  if (impl_->thread.joinable()) {
    return Error(Errc::wrong_state,
                 fmt::format("the simulator already serves {}", impl_->link_name));
  }
  impl_->stopping = false;
  impl_->link = std::move(link);
  {
    std::lock_guard lock(mutex_);
    impl_->link_name = impl_->link->name();
  }
  impl_->thread = std::thread([this] {
    Impl& s = *impl_;
    link::Link& served = *s.link;
    Batch out;
    const std::int64_t period = s.options.advance_period.count();
    while (!s.stopping.load(std::memory_order_relaxed)) {
      std::int64_t timeout_ns = 0;
      {
        std::lock_guard lock(mutex_);
        // Only a look at the clock: segment time moves when something is processed (a frame
        // queued meanwhile is then processed at its own, earlier, send time).
        const std::int64_t now = s.options.clock ? s.options.clock() : monotonic_ns();
        std::int64_t deadline = s.last_advance + period;
        if (auto due = injector_->next_due_ns()) deadline = std::min(deadline, *due);
        if (!s.delayed.empty()) deadline = std::min(deadline, s.delayed.front().due_ns);
        timeout_ns = std::max<std::int64_t>(0, deadline - now);
      }
      auto received = served.receive(std::chrono::nanoseconds(timeout_ns));
      if (s.stopping.load(std::memory_order_relaxed)) break;
      out.clear();
      if (!received) {
        if (received.error().code() == Errc::closed) break;
        {
          std::lock_guard lock(mutex_);
          ++s.stats.receive_errors;
        }
        // A failing link (an interface gone down) must not turn this loop into a busy spin.
        std::unique_lock wait_lock(s.wait_mutex);
        s.wait_cv.wait_for(wait_lock, s.options.advance_period * 10,
                           [&] { return s.stopping.load(); });
        continue;
      }
      {
        std::lock_guard lock(mutex_);
        const std::int64_t now =
            received->has_value() ? s.frame_clock((*received)->timestamp_ns) : s.clock();
        if (received->has_value()) {
          handle_frame(s, *segment_, *injector_, (*received)->frame, now, out);
        } else {
          s.release_due(now, out);
          if (now - s.last_advance >= period) {
            segment_->advance(now);
            s.last_advance = now;
            ++s.stats.idle_advances;
          }
          injector_->advance(now);
        }
      }
      std::size_t sent = 0;
      std::size_t failed = 0;
      for (std::size_t i = 0; i < out.count; ++i) {
        if (served.send(out.frames[i])) {
          ++sent;
        } else {
          ++failed;
        }
      }
      if (out.count != 0) {
        std::lock_guard lock(mutex_);
        s.stats.replies += sent;
        s.stats.send_errors += failed;
      }
    }
  });
  return ok();
}

std::chrono::nanoseconds SimServer::tick() {
  std::lock_guard lock(mutex_);
  Impl& s = *impl_;
  const std::int64_t period = s.options.advance_period.count();
  const std::int64_t now = s.clock();
  if (now - s.last_advance >= period) {
    segment_->advance(now);
    s.last_advance = now;
    ++s.stats.idle_advances;
  }
  injector_->advance(now);
  std::int64_t deadline = s.last_advance + period;
  if (auto due = injector_->next_due_ns()) deadline = std::min(deadline, *due);
  return std::chrono::nanoseconds(std::max<std::int64_t>(0, deadline - now));
}

Result<std::unique_ptr<link::Link>> SimServer::serve_memory(std::size_t queue_depth) {
  auto [master, segment_end] = link::make_memory_link_pair(queue_depth);
  if (auto r = serve(std::move(segment_end)); !r) return std::move(r).error();
  return std::move(master);
}

void SimServer::stop() {
  if (!impl_->thread.joinable()) return;
  impl_->stopping = true;
  impl_->link->interrupt();
  { std::lock_guard lock(impl_->wait_mutex); }
  impl_->wait_cv.notify_all();
  impl_->thread.join();
  impl_->link->close();
  impl_->link.reset();
  std::lock_guard lock(mutex_);
  impl_->link_name.clear();
}

bool SimServer::serving() const {
  return impl_->thread.joinable();
}

// ---- Control --------------------------------------------------------------------------------

namespace {

Result<std::size_t> find_slave(const Segment& segment, std::string_view name) {
  if (auto index = segment.find(name)) return *index;
  std::string known;
  const std::size_t shown = std::min<std::size_t>(segment.size(), 16);
  for (std::size_t i = 0; i < shown; ++i)
    known += (i ? ", " : "") + segment.name(i);
  if (segment.size() > shown) known += ", ...";
  return Error(Errc::not_found, fmt::format("unknown slave '{}' (known: {})", name, known));
}

Result<DeviceApplication*> find_device(Segment& segment, std::string_view name) {
  auto index = find_slave(segment, name);
  if (!index) return std::move(index).error();
  DeviceApplication* app = device_application(segment.esc(*index));
  if (app == nullptr) {
    return Error(Errc::unsupported, fmt::format("slave '{}' has no signals", name));
  }
  return app;
}

Error unknown_signal(DeviceApplication& app, std::string_view slave, std::string_view signal) {
  std::string known;
  for (const auto& s : app.signals())
    known += (known.empty() ? "" : ", ") + s.name;
  return Error(Errc::not_found, fmt::format("slave '{}' has no signal '{}' (known: {})", slave,
                                            signal, known.empty() ? "none" : known));
}

}  // namespace

Result<void> SimServer::inject(const Fault& fault) {
  std::lock_guard lock(mutex_);
  return injector_->inject(fault, impl_->clock());
}

void SimServer::clear_faults() {
  std::lock_guard lock(mutex_);
  injector_->clear();
  impl_->delayed.clear();
  impl_->held.reset();
}

FaultInfo SimServer::fault_info() const {
  std::lock_guard lock(mutex_);
  return injector_->info(impl_->clock());
}

Result<std::vector<SignalInfo>> SimServer::signals(std::string_view slave) const {
  std::lock_guard lock(mutex_);
  auto app = find_device(*segment_, slave);
  if (!app) return std::move(app).error();
  return (*app)->signals();
}

Result<double> SimServer::signal(std::string_view slave, std::string_view signal) const {
  std::lock_guard lock(mutex_);
  auto app = find_device(*segment_, slave);
  if (!app) return std::move(app).error();
  if (auto value = (*app)->signal(signal)) return *value;
  return unknown_signal(**app, slave, signal);
}

Result<void> SimServer::set_input(std::string_view slave, std::string_view signal, double value) {
  std::lock_guard lock(mutex_);
  auto app = find_device(*segment_, slave);
  if (!app) return std::move(app).error();
  if ((*app)->set_input(signal, value)) return ok();
  for (const auto& info : (*app)->signals()) {
    if (info.name == signal && info.direction == SignalDirection::output) {
      return Error(Errc::invalid_argument,
                   fmt::format("signal '{}.{}' is an output: the master drives it", slave, signal));
    }
  }
  if ((*app)->signal(signal)) {
    return Error(Errc::invalid_argument,
                 fmt::format("slave '{}' refused value {} for signal '{}'", slave, value, signal));
  }
  return unknown_signal(**app, slave, signal);
}

Result<void> SimServer::clear_input(std::string_view slave, std::string_view signal) {
  std::lock_guard lock(mutex_);
  auto app = find_device(*segment_, slave);
  if (!app) return std::move(app).error();
  if (!(*app)->signal(signal)) return unknown_signal(**app, slave, signal);
  (*app)->clear_input(signal);
  return ok();
}

Result<std::vector<std::uint8_t>> SimServer::read_memory(std::string_view slave,
                                                         std::uint32_t address,
                                                         std::size_t length) const {
  std::lock_guard lock(mutex_);
  auto index = find_slave(*segment_, slave);
  if (!index) return std::move(index).error();
  const auto memory = segment_->esc(*index).memory();
  if (address > memory.size() || length > memory.size() - address) {
    return Error(Errc::out_of_range,
                 fmt::format("slave '{}': 0x{:04X}+{} is outside its {} bytes of ESC memory", slave,
                             address, length, memory.size()));
  }
  return std::vector<std::uint8_t>(memory.begin() + address, memory.begin() + address + length);
}

Result<void> SimServer::power_cycle(std::string_view slave) {
  return inject(fault::power_cycle(std::string(slave)));
}

Result<void> SimServer::set_link(std::string_view slave, std::uint8_t port, bool up) {
  return inject(up ? fault::link_up(std::string(slave), port)
                   : fault::link_down(std::string(slave), port));
}

Result<void> SimServer::plug(std::string_view group, bool plugged) {
  std::lock_guard lock(mutex_);
  return injector_->plug(group, plugged, impl_->clock());
}

void SimServer::set_master_link(bool up) {
  (void)inject(up ? fault::master_link_up() : fault::master_link_down());
}

SimStatus SimServer::status() const {
  std::lock_guard lock(mutex_);
  SimStatus st;
  st.time_ns = impl_->clock();
  st.link = impl_->link_name;
  st.counters = impl_->stats;
  st.segment = segment_->stats();
  st.fault_stats = injector_->stats();
  st.faults = injector_->info(st.time_ns);
  st.hot_connect = segment_->hot_connect_groups();
  for (std::size_t i = 0; i < segment_->size(); ++i) {
    Esc& esc = segment_->esc(i);
    SlaveStatus s;
    s.index = i;
    s.name = segment_->name(i);
    if (i < impl_->options.profiles.size()) s.profile = impl_->options.profiles[i];
    const auto eeprom = esc.eeprom();
    if (eeprom.size() >= 0x20) {
      s.vendor_id = wire::load_le32(eeprom.data() + 0x10);
      s.product_code = wire::load_le32(eeprom.data() + 0x14);
      s.revision = wire::load_le32(eeprom.data() + 0x18);
    }
    s.station = esc.station_address();
    s.alias = esc.station_alias();
    s.al_state = esc.al_state();
    s.al_error = esc.al_error();
    s.al_status_code = esc.al_status_code();
    s.dc = esc.dc() != nullptr;
    for (std::uint8_t p = 0; p < 4; ++p)
      s.links[p] = segment_->link(i, p);
    st.slaves.push_back(std::move(s));
  }
  return st;
}

SimServerStats SimServer::stats() const {
  std::lock_guard lock(mutex_);
  return impl_->stats;
}

std::size_t SimServer::slave_count() const {
  std::lock_guard lock(mutex_);
  return segment_->size();
}

std::int64_t SimServer::now_ns() const {
  std::lock_guard lock(mutex_);
  return impl_->clock();
}

Result<std::unique_ptr<SimServer>> make_server(const Ring& ring, SimServerOptions options) {
  auto segment = build_segment(ring);
  if (!segment) return std::move(segment).error();
  options.profiles.clear();
  for (const auto& slave : ring.slaves)
    options.profiles.push_back(slave.device.profile);
  auto server = std::make_unique<SimServer>(std::move(*segment), std::move(options));
  for (const auto& start : ring.faults) {
    if (auto r = server->inject(start.fault); !r) {
      return Error(r.error().code(),
                   fmt::format("{}:{}: simulator.faults: '{}': {}", ring.source, start.line,
                               describe(start.fault), r.error().describe()));
    }
  }
  return server;
}

}  // namespace ecat::sim
