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

#include "benchmark_main.hpp"
#include "veth_namespace.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::link::Link;
using ecat::link::RawLink;
using ecat::link::RedundantLink;

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
  ecat::bench::VethPair pairs{"0", "1"};
  std::unique_ptr<RedundantLink> link;
  std::unique_ptr<RawLink> s0, s1;
  ecat::link::RedundantLinkOptions options;
  std::string problem;

  explicit Rig(bool sliced) {
    if (!pairs.problem().empty()) {
      problem = pairs.problem();
      return;
    }
    auto m0 = pairs.open("m0", false);
    auto m1 = pairs.open("m1", false);
    s0 = pairs.open("s0", false);
    s1 = pairs.open("s1", false);
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
  return ecat::bench::benchmark_main(argc, argv);
}
