// Fixtures of the fault scenario suite (docs/scenarios/): the reference's rings served by the
// simulator, a master configured the way the scenarios need it, and polling helpers.
//
//   auto ring = scenarios::ScenarioRing::start(scenarios::RingSpec{});
//   ASSERT_TRUE(ring) ...
//   ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::drop_responses(), 10)));
//   EXPECT_TRUE(ring->saw(master::MasterState::recovering));
//
// The default ring is the reference's: EK1100 `coupler` -> EL1809 `inputs` -> EL2809 `outputs`,
// outputs channel 1 and 16 wired to inputs channel 1 and 16, domain `main`. The segmented ring
// adds a mailbox-only slave `mailbox` (target OP, no process data) whose startup SDOs download
// a segmented blob to 0x2003:01. Periods are short (domain 2 ms, health poll 20 ms, retries
// 50 ms) so that a scenario takes well under a few seconds.
//
// Transports: an in-process memory pair (default), UDP over loopback, or raw Ethernet on a veth
// pair in a private network namespace of the test thread (RawNamespace: needs root; the
// namespace and its interfaces vanish when the test leaves it and the sockets are closed).
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <sched.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/bus/bus.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::scenarios {

using namespace std::chrono_literals;
using master::MasterState;
using master::SlaveState;
using master::TargetState;

// Polls `condition` every 2 ms until it holds or `limit` passed; the last evaluation decides.
inline bool eventually(const std::function<bool()>& condition,
                       std::chrono::milliseconds limit = 10s) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(2ms);
  }
  return condition();
}

// Polls for `duration` and fails as soon as `condition` does not hold.
inline bool stays(const std::function<bool()>& condition, std::chrono::milliseconds duration) {
  const auto end = std::chrono::steady_clock::now() + duration;
  while (std::chrono::steady_clock::now() < end) {
    if (!condition()) return false;
    std::this_thread::sleep_for(2ms);
  }
  return condition();
}

// ---- rings ------------------------------------------------------------------------------------

enum class RingKind : std::uint8_t {
  basic,      // coupler, inputs, outputs
  segmented,  // + mailbox (mailbox-only, startup segmented download)
  servo,      // coupler + drive (servo profile, cia402 driver)
};

// redundant: the simulator's ring with its second master port (sim::RedundantPorts, in process)
// and the master on a link::RedundantLink over both ports. redundant_raw: the same over two veth
// pairs in a private network namespace (RawNamespace with two pairs: the master on `master` and
// `master2`, the simulator serving `segment` and `segment2`).
enum class Transport : std::uint8_t { memory, udp, raw, redundant, redundant_raw };

// The blob the segmented ring downloads to 0x2003:01 at startup (several segments).
inline std::vector<std::uint8_t> segmented_blob() {
  std::vector<std::uint8_t> blob(40);
  for (std::size_t i = 0; i < blob.size(); ++i)
    blob[i] = static_cast<std::uint8_t>(0xA0 + i);
  return blob;
}

struct RingSpec {
  RingKind kind = RingKind::basic;
  Transport transport = Transport::memory;
  std::chrono::nanoseconds domain_period = 5ms;
  // Consecutive invalid cycles that make the domain a critical fault. The reference reports the
  // first invalid cycle; the tests that assert the master stays operational keep 3 so that one
  // frame late on a loaded machine does not count.
  std::uint32_t recovery_threshold = 3;
  std::chrono::nanoseconds health_poll = 20ms;
  std::chrono::nanoseconds retry_interval = 50ms;
  // Per-slave overrides.
  std::map<std::string, TargetState> targets;
  std::map<std::string, std::optional<std::chrono::nanoseconds>> health_polls;
  // Called on the configuration before the master is created.
  std::function<void(master::MasterConfig&)> adjust;
  // The simulator's ring file, when the kind's default is not wanted.
  std::string ring_yaml;
  // Called once the ring is served (in the raw namespace, for raw), before the master starts.
  std::function<void()> before_start;
  // Wraps the master's end of the link before the master starts (e.g. to log its frames).
  std::function<std::unique_ptr<link::Link>(std::unique_ptr<link::Link>)> wrap_link;
  // Transport::redundant(_raw): the cabling the ring is served with (broken before the master
  // starts).
  std::optional<sim::RedundantTopology> redundant_cabling;
};

inline std::string ring_yaml(RingKind kind) {
  if (kind == RingKind::servo) {
    return R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: drive, profile: servo}
)";
  }
  std::string yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
)";
  if (kind == RingKind::segmented) yaml += "    - {name: mailbox, profile: mailbox}\n";
  yaml += R"(  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_16, to: inputs.channel_16}
)";
  return yaml;
}

inline master::MasterConfig ring_config(const RingSpec& spec) {
  master::MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 5s};
  config.retry_interval = spec.retry_interval;
  config.slave_retry_interval = spec.retry_interval;
  config.dc.reset();
  // The reference's harness uses 20 ms: a loaded machine may not run the simulator's thread
  // within the 5 ms the master tunes itself to for three slaves.
  config.frame_timeout = 20ms;
  master::DomainConfig main;
  main.id = "main";
  main.period = spec.domain_period;
  main.recovery_threshold = spec.recovery_threshold;
  config.domains.push_back(main);
  auto add = [&](const char* name, bool process_data) {
    master::SlaveConfig s;
    s.name = name;
    if (process_data) s.process_data = master::ProcessDataRequest::all("main");
    s.health_poll = spec.health_poll;
    if (auto t = spec.targets.find(name); t != spec.targets.end()) s.target = t->second;
    if (auto h = spec.health_polls.find(name); h != spec.health_polls.end()) {
      s.health_poll = h->second;
    }
    config.slaves.push_back(std::move(s));
  };
  add("coupler", false);
  if (spec.kind == RingKind::servo) {
    add("drive", true);
    config.slaves.back().driver = "cia402";
  } else {
    add("inputs", true);
    add("outputs", true);
  }
  if (spec.kind == RingKind::segmented) {
    add("mailbox", false);
    config.slaves.back().startup_sdos.push_back({0x2003, 0x01, segmented_blob(), false});
  }
  if (spec.adjust) spec.adjust(config);
  return config;
}

// ---- raw transport: a veth pair in a private network namespace ------------------------------

inline bool has_capability(int cap) {
  __user_cap_header_struct header{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, 2> data{};
  if (::syscall(SYS_capget, &header, data.data()) != 0) return false;
  return (data[static_cast<std::size_t>(cap / 32)].effective & (1u << (cap % 32))) != 0;
}

inline bool run_command(const std::string& command) {
  const int status = std::system((command + " >/dev/null 2>&1").c_str());
  return status != -1 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

// The test thread moves into an anonymous network namespace with a veth pair `master` <->
// `segment`; the destructor moves it back (the namespace goes with its last socket).
class RawNamespace {
 public:
  // Empty `why_not()` when it is usable; otherwise the reason to skip. `pairs` 2: a second veth
  // pair `master2` <-> `segment2` (a redundant ring's far end).
  explicit RawNamespace(int pairs = 1) {
    if (!has_capability(CAP_NET_ADMIN) || !has_capability(CAP_NET_RAW) ||
        !has_capability(CAP_SYS_ADMIN)) {
      why_not_ =
          "needs CAP_NET_ADMIN, CAP_NET_RAW and CAP_SYS_ADMIN (root) for a private network "
          "namespace with a veth pair";
      return;
    }
    if (!run_command("command -v ip")) {
      why_not_ = "the `ip` command (iproute2) is not installed";
      return;
    }
    original_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    if (original_ < 0 || ::unshare(CLONE_NEWNET) != 0) {
      why_not_ = fmt::format("network namespaces are not available: {}", std::strerror(errno));
      if (original_ >= 0) ::close(original_);
      original_ = -1;
      return;
    }
    inside_ = true;
    // No IPv6 chatter on the veths.
    for (const char* knob : {"/proc/sys/net/ipv6/conf/default/disable_ipv6",
                             "/proc/sys/net/ipv6/conf/all/disable_ipv6"}) {
      std::ofstream(knob) << "1\n";
    }
    if (!run_command("ip link add name master type veth peer name segment") ||
        !run_command("ip link set dev master up") || !run_command("ip link set dev segment up")) {
      why_not_ = "cannot create a veth pair (is the veth driver available?)";
    }
    if (why_not_.empty() && pairs > 1 &&
        (!run_command("ip link add name master2 type veth peer name segment2") ||
         !run_command("ip link set dev master2 up") ||
         !run_command("ip link set dev segment2 up"))) {
      why_not_ = "cannot create a second veth pair (is the veth driver available?)";
    }
  }
  ~RawNamespace() {
    if (inside_) (void)::setns(original_, CLONE_NEWNET);
    if (original_ >= 0) ::close(original_);
  }
  RawNamespace(const RawNamespace&) = delete;
  RawNamespace& operator=(const RawNamespace&) = delete;

  const std::string& why_not() const { return why_not_; }

 private:
  int original_ = -1;
  bool inside_ = false;
  std::string why_not_;
};

// Samples the master's public state every millisecond on its own thread and remembers what it saw
// ("master:recovering", "state:outputs:down", "fault:outputs", "invalid:main:timeout",
// "wkc:main:3/2", "redundancy:redundant, ring broken"), so that a test can assert on states that
// only last a few cycles.
class Monitor {
 public:
  // Invalid cycles from before the monitor started are not reported.
  explicit Monitor(master::Master& m) : master_(m) {
    for (const auto& d : master_.domains()) {
      if (auto domain = master_.domain(d.id))
        last_invalid_at_[d.id] = (*domain)->stats().last_invalid_at;
    }
    // States from the event stream too: every change, however brief, not only the sampled ones.
    subscription_ = master_.subscribe_events([this](const master::Event& e, std::uint64_t) {
      std::string what;
      if (e.kind == master::EventKind::slave_state) {
        what = fmt::format("state:{}:{}", e.name(), e.to_name());
      } else if (e.kind == master::EventKind::master_state) {
        what = fmt::format("master:{}", e.to_name());
      } else if (e.kind == master::EventKind::link_redundancy) {
        what = fmt::format("redundancy:{}", e.detail());
      } else {
        return;
      }
      std::lock_guard lock(mutex_);
      seen_.emplace(what, samples_);
    });
    thread_ = std::thread([this] { run(); });
  }
  ~Monitor() { stop(); }
  Monitor(const Monitor&) = delete;
  Monitor& operator=(const Monitor&) = delete;

  void stop() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
    if (subscription_ != 0) master_.unsubscribe_events(std::exchange(subscription_, 0));
  }
  bool saw(const std::string& what) const {
    std::lock_guard lock(mutex_);
    return seen_.count(what) != 0;
  }
  // The sample in which `what` was first seen (samples are numbered from 0).
  std::optional<std::uint64_t> first(const std::string& what) const {
    std::lock_guard lock(mutex_);
    auto it = seen_.find(what);
    if (it == seen_.end()) return std::nullopt;
    return it->second;
  }
  // The first sample of any entry starting with `prefix`.
  std::optional<std::uint64_t> first_matching(const std::string& prefix) const {
    std::lock_guard lock(mutex_);
    std::optional<std::uint64_t> out;
    for (const auto& [s, n] : seen_) {
      if (s.rfind(prefix, 0) == 0 && (!out || n < *out)) out = n;
    }
    return out;
  }
  // Every entry starting with `prefix`.
  std::vector<std::string> matching(const std::string& prefix) const {
    std::lock_guard lock(mutex_);
    std::vector<std::string> out;
    for (const auto& [s, n] : seen_) {
      if (s.rfind(prefix, 0) == 0) out.push_back(s);
    }
    return out;
  }
  std::string seen() const {
    std::lock_guard lock(mutex_);
    std::string out;
    for (const auto& [s, n] : seen_)
      out += s + " ";
    return out;
  }

 private:
  void run() {
    while (running_) {
      sample();
      std::this_thread::sleep_for(1ms);
    }
  }
  void sample() {
    std::set<std::string> now;
    now.insert("master:" + std::string(master::to_string(master_.state())));
    for (const auto& s : master_.slaves()) {
      now.insert(fmt::format("state:{}:{}", s.name, master::to_string(s.state)));
      if (s.fault) {
        now.insert("fault:" + s.name);
        now.insert(fmt::format("fault:{}:{}", s.name, *s.fault));
      }
    }
    for (const auto& d : master_.domains()) {
      auto domain = master_.domain(d.id);
      if (!domain) continue;
      const auto stats = (*domain)->stats();
      auto record = [&](const master::CycleInvalid& inv) {
        now.insert(fmt::format("invalid:{}:{}", d.id, master::to_string(inv.reason)));
        if (inv.reason == master::InvalidReason::wkc_mismatch) {
          now.insert(fmt::format("wkc:{}:{}/{}", d.id, inv.expected_wkc, inv.actual_wkc));
        }
      };
      if (stats.health.invalid) record(*stats.health.invalid);
      // An invalid cycle since the previous sample, even when the next one was valid again.
      auto& previous = last_invalid_at_[d.id];
      if (stats.last_invalid_at != previous && stats.last_invalid) record(*stats.last_invalid);
      previous = stats.last_invalid_at;
    }
    std::lock_guard lock(mutex_);
    for (const auto& s : now)
      seen_.emplace(s, samples_);
    ++samples_;
  }

  master::Master& master_;
  std::atomic<bool> running_{true};
  mutable std::mutex mutex_;
  std::map<std::string, std::uint64_t> seen_;  // entry -> first sample
  std::map<std::string, std::optional<master::Clock::time_point>> last_invalid_at_;  // thread
  std::uint64_t samples_ = 0;
  master::EventSubscriptionId subscription_ = 0;
  std::thread thread_;
};

// ---- the ring under test ----------------------------------------------------------------------

class ScenarioRing {
 public:
  // Builds the simulated ring, serves it on the spec's transport and starts the master (does not
  // wait). A test failure and null when something cannot be set up; `skip` is set instead when
  // the transport is not available here (raw without privileges).
  static std::unique_ptr<ScenarioRing> create(const RingSpec& spec, std::string* skip = nullptr) {
    auto ring = std::make_unique<ScenarioRing>();
    ring->spec_ = spec;
    if (spec.transport == Transport::raw || spec.transport == Transport::redundant_raw) {
      ring->ns_ =
          std::make_unique<RawNamespace>(spec.transport == Transport::redundant_raw ? 2 : 1);
      if (!ring->ns_->why_not().empty()) {
        if (skip) *skip = ring->ns_->why_not();
        return nullptr;
      }
    }
    auto parsed = sim::parse_ring(spec.ring_yaml.empty() ? ring_yaml(spec.kind) : spec.ring_yaml);
    if (!parsed) {
      ADD_FAILURE() << parsed.error().describe();
      return nullptr;
    }
    auto server = sim::make_server(*parsed);
    if (!server) {
      ADD_FAILURE() << server.error().describe();
      return nullptr;
    }
    ring->server = std::move(*server);
    auto link = ring->serve();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return nullptr;
    }
    if (spec.before_start) spec.before_start();
    if (spec.wrap_link) *link = spec.wrap_link(std::move(*link));
    ring->master = std::make_unique<master::Master>(ring_config(spec));
    ring->master->on_state_change([r = ring.get()](MasterState, MasterState to) {
      std::lock_guard lock(r->states_mutex_);
      r->states_.push_back(to);
    });
    if (auto started = ring->master->start(std::move(*link)); !started) {
      ADD_FAILURE() << started.error().describe();
      return nullptr;
    }
    return ring;
  }

  // create() and then waits until operational.
  static std::unique_ptr<ScenarioRing> operational(const RingSpec& spec,
                                                   std::string* skip = nullptr) {
    auto ring = create(spec, skip);
    if (!ring) return nullptr;
    auto op = ring->master->await_operational(10s);
    if (!op) {
      ADD_FAILURE() << "the ring did not become operational: " << op.error().describe();
      return nullptr;
    }
    return ring;
  }

  ~ScenarioRing() {
    if (master) {
      // Every scenario, whatever it drove: no change the seed's diagrams do not draw, for the
      // master, its slaves or its domains (each is refused and counted, never made).
      const auto status = master->status();
      EXPECT_EQ(status.illegal_transitions, 0u) << "last: " << status.last_illegal_transition;
      EXPECT_EQ(status.illegal_slave_transitions, 0u);
      EXPECT_EQ(status.illegal_domain_transitions, 0u);
    }
    if (master) (void)master->stop();
    master.reset();
    if (redundant_ports) redundant_ports->stop();
    redundant_ports.reset();
    if (server) server->stop();
    server.reset();
    ns_.reset();  // last: the sockets are closed
  }

  // ---- observation -------------------------------------------------------------------------

  MasterState state() const { return master->state(); }

  // Whether the master went through `state` since the start (or the last forget_states()).
  bool saw(MasterState state) const {
    std::lock_guard lock(states_mutex_);
    return std::find(states_.begin(), states_.end(), state) != states_.end();
  }
  void forget_states() {
    std::lock_guard lock(states_mutex_);
    states_.clear();
  }
  std::vector<MasterState> states() const {
    std::lock_guard lock(states_mutex_);
    return states_;
  }

  master::Slave& slave(const std::string& name) {
    auto s = master->slave(name);
    if (!s) throw std::runtime_error(s.error().describe());
    return **s;
  }
  SlaveState slave_state(const std::string& name) { return slave(name).state(); }
  std::optional<std::string> slave_fault(const std::string& name) {
    return slave(name).info().fault;
  }
  master::DomainStats domain_stats(const std::string& id = "main") {
    auto d = master->domain(id);
    if (!d) throw std::runtime_error(d.error().describe());
    return (*d)->stats();
  }
  bool all_slaves_in(SlaveState state) {
    for (const auto& s : master->slaves()) {
      if (s.state != state) return false;
    }
    return true;
  }
  bool any_slave_fault() {
    for (const auto& s : master->slaves()) {
      if (s.fault) return true;
    }
    return false;
  }
  std::string describe_slaves() {
    std::string out;
    for (const auto& s : master->slaves()) {
      out += fmt::format("{}={}{} ", s.name, master::to_string(s.state),
                         s.fault ? " (" + *s.fault + ")" : "");
    }
    return out;
  }
  std::string describe() {
    const auto status = master->status();
    std::string out = fmt::format("master {}; ", master::to_string(status.state));
    out += describe_slaves();
    for (const auto& f : status.runtime_faults)
      out += "; runtime fault: " + f;
    return out;
  }

  // The AL state the simulated device is really in (slave_state() is what the master believes).
  std::optional<wire::AlState> device_state(const std::string& name) const {
    for (const auto& s : server->status().slaves) {
      if (s.name == name) return s.al_state;
    }
    return std::nullopt;
  }

  // One frame sent straight to the simulated segment, past the master (its faults apply): an FPRD
  // of the AL status of `name` at its station. The working counter: 1 when the slave answers, 0
  // when it is cut off; nullopt when no decodable reply came back.
  std::optional<std::uint16_t> probe_wkc(const std::string& name) {
    std::array<std::uint8_t, 64> buffer{};
    wire::FrameBuilder frame(buffer);
    wire::DatagramHeader header;
    header.command = wire::Command::fprd;
    header.index = 0xEE;
    header.address = wire::physical_address(slave(name).station(), wire::reg::kAlStatus);
    header.length = 2;
    if (!frame.add(header)) return std::nullopt;
    const auto replies = server->exchange(frame.finish());
    if (replies.empty()) return std::nullopt;
    const auto decoded = wire::decode_frame(replies.front());
    if (!decoded || decoded.frame->datagram_count() != 1) return std::nullopt;
    return (*decoded.frame->begin()).wkc;
  }

  // The simulator's scheduled, queued and scripted faults have all run out.
  bool fault_queue_drained() const {
    const auto info = server->fault_info();
    return info.queued.empty() && info.scheduled.empty();
  }

  // Output channel 1 and 16 of `outputs` are wired to the same inputs: writes `value` to both
  // and waits until `inputs` reads it back (process data goes round the ring).
  bool loopback(bool value, std::chrono::milliseconds limit = 5s) {
    auto& out = slave("outputs");
    auto& in = slave("inputs");
    if (!out.write_output("channel_1", value) || !out.write_output("channel_16", !value)) {
      return false;
    }
    return eventually(
        [&] {
          auto a = in.read_input("channel_1");
          auto b = in.read_input("channel_16");
          return a && b && master::as_bool(*a) == value && master::as_bool(*b) == !value;
        },
        limit);
  }

  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<master::Master> master;
  // Transport::redundant and redundant_raw: the simulator's two ports and the master's link
  // (owned by the master's bus; valid while the master runs).
  std::unique_ptr<sim::RedundantPorts> redundant_ports;
  link::RedundantLink* redundant_link = nullptr;

 private:
  Result<std::unique_ptr<link::Link>> serve() {
    switch (spec_.transport) {
      case Transport::memory:
        return server->serve_memory();
      case Transport::redundant: {
        sim::RedundantPortsOptions options;
        if (spec_.redundant_cabling) options.topology = *spec_.redundant_cabling;
        auto ports = sim::RedundantPorts::create(*server, options);
        if (!ports) return ports.error();
        redundant_ports = std::move(*ports);
        link::RedundantLinkOptions link_options;
        link_options.primary_mac = options.primary_mac;
        link_options.secondary_mac = options.secondary_mac;
        auto link = link::RedundantLink::open(
            redundant_ports->take_link(wire::RedundantPort::primary),
            redundant_ports->take_link(wire::RedundantPort::secondary), link_options);
        if (!link) return link.error();
        redundant_link = link->get();
        return std::unique_ptr<link::Link>(std::move(*link));
      }
      case Transport::redundant_raw: {
        sim::RedundantPortsOptions cabling;
        if (spec_.redundant_cabling) cabling.topology = *spec_.redundant_cabling;
        auto ports = sim::RedundantPorts::create(*server, cabling);
        if (!ports) return ports.error();
        redundant_ports = std::move(*ports);
        std::array<std::unique_ptr<link::RawLink>, 2> served;
        for (std::size_t i = 0; i < 2; ++i) {
          link::RawLinkOptions options;
          options.interface = i == 0 ? "segment" : "segment2";
          auto opened = link::RawLink::open(options);
          if (!opened) return opened.error();
          served[i] = std::move(*opened);
        }
        if (auto r = redundant_ports->serve(std::move(served[0]), std::move(served[1])); !r) {
          return r.error();
        }
        auto link = link::RedundantLink::open_raw("master", "master2");
        if (!link) return link.error();
        redundant_link = link->get();
        return std::unique_ptr<link::Link>(std::move(*link));
      }
      case Transport::udp: {
        auto listening = link::UdpLink::serve("127.0.0.1", 0);
        if (!listening) return listening.error();
        const auto port = (*listening)->local_port();
        if (auto served = server->serve(std::move(*listening)); !served) return served.error();
        auto client = link::UdpLink::connect("127.0.0.1", port);
        if (!client) return client.error();
        return std::unique_ptr<link::Link>(std::move(*client));
      }
      case Transport::raw: {
        link::RawLinkOptions segment;
        segment.interface = "segment";
        segment.responder = true;
        auto served_link = link::RawLink::open(segment);
        if (!served_link) return served_link.error();
        if (auto served = server->serve(std::move(*served_link)); !served) return served.error();
        link::RawLinkOptions master_side;
        master_side.interface = "master";
        auto client = link::RawLink::open(master_side);
        if (!client) return client.error();
        return std::unique_ptr<link::Link>(std::move(*client));
      }
    }
    return Error(Errc::invalid_argument, "unknown transport");
  }

  RingSpec spec_;
  std::unique_ptr<RawNamespace> ns_;
  mutable std::mutex states_mutex_;
  std::vector<MasterState> states_;
};

}  // namespace ecat::scenarios
