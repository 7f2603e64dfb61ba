// Round-trip latency of each link: the benchmark thread sends a frame and waits for the echo that
// a second thread sends back. Reports ns per round trip; never asserts a timing.
#include <array>
#include <chrono>
#include <string>

#include <benchmark/benchmark.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>

#include "veth_namespace.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::bench::Echo;
using ecat::link::Link;

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

// A veth pair in an anonymous network namespace (bench/veth_namespace.hpp).
void BM_RawVethRoundTrip(benchmark::State& state) {
  ecat::bench::VethPair pair;
  if (!pair.problem().empty()) {
    state.SkipWithError(pair.problem().c_str());
    return;
  }
  auto master = pair.open("m", false);
  auto segment = pair.open("s", false);
  if (master && segment) {
    round_trips(state, *master, *segment);
  } else {
    state.SkipWithError(pair.problem().c_str());
  }
}
BENCHMARK(BM_RawVethRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
