// Round-trip latency of each link: the benchmark thread sends a frame and waits for the echo that
// a second thread sends back. Reports ns per round trip; never asserts a timing.
#include <array>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <string>
#include <thread>

#include <benchmark/benchmark.h>
#include <fcntl.h>
#include <sched.h>
#include <unistd.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>

namespace {

using namespace std::chrono_literals;
using ecat::link::Link;

// Echoes every frame received on `link` until stopped.
class Echo {
 public:
  explicit Echo(Link& link) : link_(link), thread_([this] { run(); }) {}
  ~Echo() {
    stop_ = true;
    link_.interrupt();
    thread_.join();
  }
  Echo(const Echo&) = delete;
  Echo& operator=(const Echo&) = delete;

 private:
  void run() {
    std::array<std::uint8_t, ecat::wire::kMaxFrameSize> copy{};
    while (!stop_) {
      auto r = link_.receive(100ms);
      if (!r.ok()) return;
      if (!r->has_value()) continue;
      const auto frame = (*r)->frame;
      std::copy(frame.begin(), frame.end(), copy.begin());
      (void)link_.send(ecat::wire::Bytes(copy.data(), frame.size()));
    }
  }
  Link& link_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

void round_trips(benchmark::State& state, Link& master, Link& segment) {
  const auto size = static_cast<std::size_t>(state.range(0));
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> frame{};
  Echo echo(segment);
  std::int64_t lost = 0;
  for (auto _ : state) {
    if (!master.send(ecat::wire::Bytes(frame.data(), size)).ok()) {
      state.SkipWithError("send failed");
      break;
    }
    auto r = master.receive(1s);
    if (!r.ok()) {
      state.SkipWithError(r.error().describe().c_str());
      break;
    }
    if (!r->has_value()) ++lost;
  }
  state.counters["lost"] = static_cast<double>(lost);
  state.SetItemsProcessed(state.iterations());
}

void BM_MemoryPairRoundTrip(benchmark::State& state) {
  auto [master, segment] = ecat::link::make_memory_link_pair();
  round_trips(state, *master, *segment);
}
BENCHMARK(BM_MemoryPairRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

void BM_FunctionLinkRoundTrip(benchmark::State& state) {
  auto link = ecat::link::make_function_link(
      [](ecat::wire::Bytes request, ecat::link::ReplySink& replies) { replies.reply(request); });
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> frame{};
  const auto size = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) {
    (void)link->send(ecat::wire::Bytes(frame.data(), size));
    auto r = link->receive(0ns);
    benchmark::DoNotOptimize(r);
  }
}
BENCHMARK(BM_FunctionLinkRoundTrip)->Arg(60)->Arg(1500);

void BM_UdpLoopbackRoundTrip(benchmark::State& state) {
  auto server = ecat::link::UdpLink::serve("127.0.0.1", 0);
  if (!server.ok()) {
    state.SkipWithError(server.error().describe().c_str());
    return;
  }
  auto client = ecat::link::UdpLink::connect("127.0.0.1", (*server)->local_port());
  if (!client.ok()) {
    state.SkipWithError(client.error().describe().c_str());
    return;
  }
  round_trips(state, **client, **server);
}
BENCHMARK(BM_UdpLoopbackRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

// A veth pair in an anonymous network namespace that vanishes when the links close and this
// thread returns to its original namespace.
void BM_RawVethRoundTrip(benchmark::State& state) {
  if (geteuid() != 0) {
    state.SkipWithError("needs root to create a veth pair in a private network namespace");
    return;
  }
  const int original = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
  if (original < 0 || ::unshare(CLONE_NEWNET) != 0) {
    if (original >= 0) ::close(original);
    state.SkipWithError("network namespaces are not available");
    return;
  }
  std::unique_ptr<ecat::link::RawLink> master;
  std::unique_ptr<ecat::link::RawLink> segment;
  std::string problem = "cannot create a veth pair (is `ip` installed?)";
  const bool created =
      std::system(
          "ip link add name a type veth peer name b >/dev/null 2>&1 && ip link set dev a up && "
          "ip link set dev b up") == 0;
  if (created) {
    ecat::link::RawLinkOptions options;
    options.interface = "a";
    options.kernel_filter = true;
    auto a = ecat::link::RawLink::open(options);
    options.interface = "b";
    auto b = ecat::link::RawLink::open(options);
    if (a.ok() && b.ok()) {
      master = std::move(*a);
      segment = std::move(*b);
    } else {
      problem = (a.ok() ? b.error() : a.error()).describe();
    }
  }
  if (master && segment) {
    round_trips(state, *master, *segment);
  } else {
    state.SkipWithError(problem.c_str());
  }
  master.reset();
  segment.reset();
  (void)::setns(original, CLONE_NEWNET);
  ::close(original);
}
BENCHMARK(BM_RawVethRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
