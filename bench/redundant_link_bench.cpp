// The redundant link's wait on its two ports (link::RedundantLink over two raw veth pairs in a
// private network namespace; needs root): one ppoll on both ports' descriptors (Link::wait_fd)
// against the wait it replaced and still uses for legs without a descriptor, 100 us slices on one
// port then the other. The round trip of a whole ring's reply, which comes back on the secondary
// port while the primary gets only the secondary's passthrough copy, and the CPU the bus thread
// burns while nothing comes back.
//
//   redundant_link_bench --benchmark_filter=Redundant
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <benchmark/benchmark.h>
#include <fcntl.h>
#include <sched.h>
#include <time.h>
#include <unistd.h>

#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/wire/frame.hpp>

#include "build_info.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::link::Link;
using ecat::link::RawLink;
using ecat::link::RedundantLink;

// Two veth pairs, "m0"/"s0" (the primary's cable) and "m1"/"s1" (the secondary's), in an
// anonymous network namespace of the constructing thread; construct, use and destroy on one thread.
class TwoVethPairs {
 public:
  TwoVethPairs() {
    if (geteuid() != 0) {
      problem_ = "needs root to create veth pairs in a private network namespace";
      return;
    }
    original_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    if (original_ < 0 || ::unshare(CLONE_NEWNET) != 0) {
      problem_ = "network namespaces are not available";
      return;
    }
    for (const char* n : {"0", "1"}) {
      const std::string c = std::string("ip link add name m") + n + " type veth peer name s" + n +
                            " >/dev/null 2>&1 && ip link set dev m" + n +
                            " up && ip link set dev s" + n + " up";
      if (std::system(c.c_str()) != 0) problem_ = "cannot create a veth pair (is `ip` installed?)";
    }
  }
  ~TwoVethPairs() {
    if (original_ >= 0) {
      (void)::setns(original_, CLONE_NEWNET);
      ::close(original_);
    }
  }
  TwoVethPairs(const TwoVethPairs&) = delete;
  TwoVethPairs& operator=(const TwoVethPairs&) = delete;
  const std::string& problem() const { return problem_; }

  std::unique_ptr<RawLink> open(const std::string& name) {
    ecat::link::RawLinkOptions options;
    options.interface = name;
    options.kernel_filter = true;
    auto opened = RawLink::open(options);
    if (!opened) {
      problem_ = opened.error().describe();
      return nullptr;
    }
    return std::move(*opened);
  }

 private:
  int original_ = -1;
  std::string problem_;
};

// A leg that hides its descriptor: the redundant link then waits as it did before it had one,
// 100 us on one port, then the other.
class NoDescriptor final : public ecat::link::ForwardingLink {
 public:
  using ForwardingLink::ForwardingLink;
  int wait_fd() override { return -1; }
};

ecat::wire::MacAddress forwarded(ecat::wire::MacAddress mac) {
  mac[0] |= 0x02;
  return mac;
}

// A whole ring between s0 and s1: the primary's frame is processed (working counter + 1) and
// leaves by s1, the secondary's passes through unchanged and leaves by s0.
class WholeRing {
 public:
  WholeRing(RawLink& s0, RawLink& s1, ecat::wire::MacAddress primary,
            ecat::wire::MacAddress secondary)
      : forward_([this, &s0, &s1, primary] { carry(s0, s1, forwarded(primary), true); }),
        back_([this, &s0, &s1, secondary] { carry(s1, s0, forwarded(secondary), false); }) {}
  ~WholeRing() {
    stop_ = true;
    forward_.join();
    back_.join();
  }
  WholeRing(const WholeRing&) = delete;
  WholeRing& operator=(const WholeRing&) = delete;

 private:
  void carry(RawLink& in, RawLink& out, ecat::wire::MacAddress source, bool process) {
    std::array<std::uint8_t, ecat::wire::kMaxFrameSize> copy{};
    while (!stop_) {
      auto r = in.receive(20ms);
      if (!r) return;
      if (!*r) continue;
      const auto frame = (*r)->frame;
      std::copy(frame.begin(), frame.end(), copy.begin());
      const std::size_t size = frame.size();
      if (process) {
        // Every datagram's working counter + 1, as one slave would (frames arrive padded).
        const auto decoded = ecat::wire::decode_frame(frame);
        if (decoded) {
          for (const auto d : *decoded.frame) {
            const auto at = static_cast<std::size_t>(d.data.data() + d.data.size() - frame.data());
            copy[at] = static_cast<std::uint8_t>(copy[at] + 1);
          }
        }
      }
      (void)out.send_as(ecat::wire::Bytes(copy.data(), size), source, ecat::wire::kBroadcastMac);
    }
  }
  std::atomic<bool> stop_{false};
  std::thread forward_;
  std::thread back_;
};

std::vector<std::uint8_t> brd_frame() {
  std::vector<std::uint8_t> buffer(ecat::wire::kMaxFrameSize);
  ecat::wire::FrameBuilder builder(buffer);
  (void)builder.add({ecat::wire::Command::brd, 0x10, 0, 2, false, false, 0});
  const auto f = builder.finish();
  return {f.begin(), f.end()};
}

struct Rig {
  TwoVethPairs pairs;
  std::unique_ptr<RedundantLink> link;
  std::unique_ptr<RawLink> s0, s1;
  ecat::link::RedundantLinkOptions options;
  std::string problem;

  explicit Rig(bool sliced) {
    if (!pairs.problem().empty()) {
      problem = pairs.problem();
      return;
    }
    auto m0 = pairs.open("m0");
    auto m1 = pairs.open("m1");
    s0 = pairs.open("s0");
    s1 = pairs.open("s1");
    if (!m0 || !m1 || !s0 || !s1) {
      problem = pairs.problem();
      return;
    }
    options.primary_mac = m0->source_mac();
    options.secondary_mac = m1->source_mac();
    std::unique_ptr<Link> primary = std::move(m0);
    std::unique_ptr<Link> secondary = std::move(m1);
    if (sliced) {
      primary = std::make_unique<NoDescriptor>(std::move(primary));
      secondary = std::make_unique<NoDescriptor>(std::move(secondary));
    }
    auto opened = RedundantLink::open(std::move(primary), std::move(secondary), options);
    if (!opened) {
      problem = opened.error().describe();
      return;
    }
    link = std::move(*opened);
  }
};

const char* label(bool sliced) {
  return sliced ? "100 us slices, one port then the other" : "one ppoll on both ports";
}

std::int64_t thread_cpu_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

// A whole ring's reply, back on the secondary port (the primary gets the secondary's passthrough
// copy). Arg 0: both ports at once; 1: the slices.
void BM_RedundantVethRoundTrip(benchmark::State& state) {
  const bool sliced = state.range(0) == 1;
  Rig rig(sliced);
  if (!rig.problem.empty()) {
    state.SkipWithError(rig.problem.c_str());
    return;
  }
  WholeRing ring(*rig.s0, *rig.s1, rig.options.primary_mac, rig.options.secondary_mac);
  const auto frame = brd_frame();
  std::uint64_t lost = 0;
  std::vector<std::int64_t> samples;
  samples.reserve(1 << 20);
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    if (!rig.link->send(frame)) {
      state.SkipWithError("send failed");
      break;
    }
    auto r = rig.link->receive(100ms);
    if (!r || !*r) ++lost;
    // The passthrough copy, if it is still on its way, is dropped by the next receive.
    if (samples.size() < samples.capacity()) {
      samples.push_back(std::chrono::duration_cast<std::chrono::nanoseconds>(
                            std::chrono::steady_clock::now() - start)
                            .count());
    }
  }
  state.SetLabel(label(sliced));
  state.counters["lost"] = static_cast<double>(lost);
  if (!samples.empty()) {
    std::sort(samples.begin(), samples.end());
    const auto at = [&](double q) {
      return static_cast<double>(
                 samples[static_cast<std::size_t>(q * static_cast<double>(samples.size() - 1))]) /
             1000.0;
    };
    state.counters["p50_us"] = at(0.5);
    state.counters["p99_us"] = at(0.99);
    state.counters["max_us"] = at(1.0);
  }
  state.counters["forward_crosses"] = static_cast<double>(rig.link->status().forward_crosses);
}
BENCHMARK(BM_RedundantVethRoundTrip)->Arg(0)->Arg(1)->UseRealTime();

// Nothing comes back: the CPU time the waiting thread uses per second of receive().
void BM_RedundantIdleWait(benchmark::State& state) {
  const bool sliced = state.range(0) == 1;
  Rig rig(sliced);
  if (!rig.problem.empty()) {
    state.SkipWithError(rig.problem.c_str());
    return;
  }
  std::int64_t cpu = 0;
  std::int64_t wall = 0;
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    const std::int64_t cpu_start = thread_cpu_ns();
    auto r = rig.link->receive(50ms);
    benchmark::DoNotOptimize(r);
    cpu += thread_cpu_ns() - cpu_start;
    wall += std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() -
                                                                 start)
                .count();
  }
  state.SetLabel(label(sliced));
  state.counters["cpu_percent"] =
      wall > 0 ? 100.0 * static_cast<double>(cpu) / static_cast<double>(wall) : 0.0;
}
BENCHMARK(BM_RedundantIdleWait)->Arg(0)->Arg(1)->Iterations(20)->UseRealTime();

}  // namespace

int main(int argc, char** argv) {
  benchmark::AddCustomContext("ecat build", ecat::bench::build_info());
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
