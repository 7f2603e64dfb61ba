// How fast the simulator answers. In process: frames per second through SimServer's function link
// for 1 to 1024 slaves, each frame a cyclic LRW over every slave's process data plus an AL status
// read, and a health-poll frame of 8 FPRDs (AL status and code) to slaves spread over the ring:
// the cyclic frame addresses every slave, the poll only 8, so its rate shows what a frame costs
// apart from the slaves it addresses. Over a veth pair: a round trip through a SimServer serving a
// raw link, against a bare echo on the same pair (the cost of the simulator itself). Figures only;
// nothing asserts.
#include <algorithm>
#include <array>
#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

#include "benchmark_main.hpp"
#include "veth_namespace.hpp"

namespace {

using namespace std::chrono_literals;
namespace reg = ecat::wire::reg;
using ecat::bench::Echo;
using ecat::bench::VethPair;
using ecat::wire::Command;

constexpr std::uint16_t kBytesPerSlave = 2;

std::vector<std::uint8_t> frame_of(std::initializer_list<ecat::wire::DatagramHeader> headers,
                                   const std::vector<std::vector<std::uint8_t>>& data = {}) {
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  std::size_t i = 0;
  for (const auto& h : headers) {
    (void)builder.add(h, i < data.size() ? ecat::wire::Bytes(data[i]) : ecat::wire::Bytes{});
    ++i;
  }
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

// N generic slaves, stations 0x1001.., each with an FMMU mapping 2 logical bytes onto its RAM.
std::unique_ptr<ecat::sim::SimServer> configured_server(std::size_t slaves) {
  auto segment = std::make_unique<ecat::sim::Segment>();
  for (std::size_t i = 0; i < slaves; ++i) {
    auto esc = ecat::sim::make_device(ecat::sim::DeviceConfig{});
    std::string name = "s";  // not "s" + ...: GCC 12 -O3 reports a false -Wrestrict there
    name += std::to_string(i);
    if (!esc.ok() || !segment->add_slave(name, std::move(*esc)).ok()) {
      return nullptr;
    }
  }
  auto server = std::make_unique<ecat::sim::SimServer>(std::move(segment));
  for (std::size_t i = 0; i < slaves; ++i) {
    const auto station = static_cast<std::uint16_t>(0x1001 + i);
    ecat::wire::DatagramHeader h;
    h.command = Command::apwr;
    h.address = ecat::wire::physical_address(
        ecat::wire::position_adp(static_cast<std::uint16_t>(i)), reg::kStationAddress);
    h.length = 2;
    (void)server->exchange(frame_of(
        {h}, {{static_cast<std::uint8_t>(station), static_cast<std::uint8_t>(station >> 8)}}));
    ecat::wire::FmmuConfig fmmu;
    fmmu.logical_start = static_cast<std::uint32_t>(i * kBytesPerSlave);
    fmmu.length = kBytesPerSlave;
    fmmu.physical_start = 0x1000;
    fmmu.type = ecat::wire::FmmuType::read_write;
    fmmu.active = true;
    const auto bytes = fmmu.encode();
    h.command = Command::fpwr;
    h.address = ecat::wire::physical_address(station, reg::kFmmuBase);
    h.length = static_cast<std::uint16_t>(bytes.size());
    (void)server->exchange(frame_of({h}, {{bytes.begin(), bytes.end()}}));
  }
  return server;
}

// Slaves whose process data one LRW carries (1,024 bytes; a frame holds at most 1,486).
constexpr std::size_t kSlavesPerLrw = 512;

// One LRW over slaves [first, first + count), and an AL status read of the first slave when
// `with_status` (the veth benchmarks send cyclic_frame(n), n <= 256).
std::vector<std::uint8_t> cyclic_frame(std::size_t first, std::size_t count, bool with_status) {
  ecat::wire::DatagramHeader lrw;
  lrw.command = Command::lrw;
  lrw.address = static_cast<std::uint32_t>(first * kBytesPerSlave);
  lrw.length = static_cast<std::uint16_t>(count * kBytesPerSlave);
  if (!with_status) return frame_of({lrw});
  ecat::wire::DatagramHeader status;
  status.command = Command::fprd;
  status.index = 1;
  status.address = ecat::wire::physical_address(0x1001, reg::kAlStatus);
  status.length = 2;
  return frame_of({lrw, status});
}

std::vector<std::uint8_t> cyclic_frame(std::size_t slaves) {
  return cyclic_frame(0, slaves, true);
}

// One cycle's frames: an LRW per 512 slaves, the first frame with the AL status read.
std::vector<std::vector<std::uint8_t>> cyclic_frames(std::size_t slaves) {
  std::vector<std::vector<std::uint8_t>> frames;
  for (std::size_t first = 0; first < slaves; first += kSlavesPerLrw) {
    frames.push_back(cyclic_frame(first, std::min(kSlavesPerLrw, slaves - first), frames.empty()));
  }
  return frames;
}

void BM_InProcessCyclicFrame(benchmark::State& state) {
  const auto slaves = static_cast<std::size_t>(state.range(0));
  auto server = configured_server(slaves);
  if (!server) {
    state.SkipWithError("cannot build the segment");
    return;
  }
  auto link = server->function_link();
  const auto frames = cyclic_frames(slaves);
  std::uint64_t wrong = 0;
  for (auto _ : state) {
    for (std::size_t f = 0; f < frames.size(); ++f) {
      (void)link->send(frames[f]);
      auto r = link->receive(0ns);
      if (!r.ok() || !r->has_value()) {
        state.SkipWithError("no reply");
        return;
      }
      const std::size_t count = std::min(kSlavesPerLrw, slaves - f * kSlavesPerLrw);
      const auto reply = (*r)->frame;
      const std::size_t wkc_at =
          ecat::wire::kFrameHeaderSize + ecat::wire::kDatagramHeaderSize + count * kBytesPerSlave;
      if (ecat::wire::load_le16(reply.data() + wkc_at) != 3 * count) ++wrong;
    }
  }
  state.counters["slaves"] = static_cast<double>(slaves);
  state.counters["wrong_wkc"] = static_cast<double>(wrong);
  state.counters["frames/s"] = benchmark::Counter(
      static_cast<double>(state.iterations() * frames.size()), benchmark::Counter::kIsRate);
  state.counters["cycles/s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_InProcessCyclicFrame)->Arg(1)->Arg(16)->Arg(64)->Arg(256)->Arg(512)->Arg(1024);

constexpr std::size_t kPolledSlaves = 8;

// FPRD AL status + AL status code (0x0130..0x0135) of 8 slaves spread over the ring.
std::vector<std::uint8_t> health_poll_frame(std::size_t slaves) {
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  for (std::size_t k = 0; k < kPolledSlaves; ++k) {
    const std::size_t slave = k * slaves / kPolledSlaves;
    ecat::wire::DatagramHeader h;
    h.command = Command::fprd;
    h.index = static_cast<std::uint8_t>(k);
    h.address =
        ecat::wire::physical_address(static_cast<std::uint16_t>(0x1001 + slave), reg::kAlStatus);
    h.length = 6;
    (void)builder.add(h, ecat::wire::Bytes{});
  }
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

void BM_InProcessHealthPollFrame(benchmark::State& state) {
  const auto slaves = static_cast<std::size_t>(state.range(0));
  auto server = configured_server(slaves);
  if (!server) {
    state.SkipWithError("cannot build the segment");
    return;
  }
  auto link = server->function_link();
  const auto frame = health_poll_frame(slaves);
  std::uint64_t wrong = 0;
  for (auto _ : state) {
    (void)link->send(frame);
    auto r = link->receive(0ns);
    if (!r.ok() || !r->has_value()) {
      state.SkipWithError("no reply");
      break;
    }
    const auto decoded = ecat::wire::decode_frame((*r)->frame);
    if (!decoded) {
      ++wrong;
      continue;
    }
    for (const ecat::wire::DatagramView d : *decoded.frame) {
      if (d.wkc != 1) ++wrong;
    }
  }
  state.counters["slaves"] = static_cast<double>(slaves);
  state.counters["wrong_wkc"] = static_cast<double>(wrong);
  state.counters["frames/s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_InProcessHealthPollFrame)->Arg(8)->Arg(64)->Arg(256)->Arg(512)->Arg(1024);

// The master's reset block at start-up (src/master/startup.cpp, reset_slaves): 13 BWRs, each
// reaching every slave (DL port control, event mask, error counters, FMMUs 0-2, SyncManagers 0-3,
// DC registers, alias control, AL control, EEPROM access). A broadcast costs every slave: the
// frame's time bounds how short the master's frame timeout may be against this simulator.
std::vector<std::uint8_t> reset_block_frame() {
  struct Step {
    std::uint16_t offset;
    std::size_t length;
    std::uint8_t first;
    std::uint8_t second = 0;
  };
  static constexpr std::array<Step, 13> kSteps{
      {{reg::kDlPortControl, 1, 0},
       {reg::kEcatEventMask, 2, 4},
       {reg::kRxErrorCounter, 8, 0},
       {reg::kFmmuBase, 3 * reg::kFmmuSize, 0},
       {reg::kSyncManagerBase, 4 * reg::kSyncManagerSize, 0},
       {reg::kDcActivation, 1, 0},
       {reg::kDcSystemTime, 4, 0},
       {reg::kDcSpeedCounterStart, 2, 0, 0x10},
       {reg::kDcSystemTimeFilterDepth, 2, 0, 0x0C},
       {reg::kDlAliasControl, 1, 0},
       {reg::kAlControl, 2, 0x11},
       {reg::kSiiAccess, 1, 2},
       {reg::kSiiAccess, 1, 0}}};
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  std::uint8_t index = 0;
  for (const Step& step : kSteps) {
    ecat::wire::DatagramHeader h;
    h.command = Command::bwr;
    h.index = index++;
    h.address = ecat::wire::physical_address(0, step.offset);
    h.length = static_cast<std::uint16_t>(step.length);
    std::vector<std::uint8_t> data(step.length, 0);
    data[0] = step.first;
    if (step.length > 1) data[1] = step.second;
    (void)builder.add(h, ecat::wire::Bytes(data));
  }
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

void BM_InProcessResetBlockFrame(benchmark::State& state) {
  const auto slaves = static_cast<std::size_t>(state.range(0));
  auto server = configured_server(slaves);
  if (!server) {
    state.SkipWithError("cannot build the segment");
    return;
  }
  auto link = server->function_link();
  const auto frame = reset_block_frame();
  std::uint64_t wrong = 0;
  for (auto _ : state) {
    (void)link->send(frame);
    auto r = link->receive(0ns);
    if (!r.ok() || !r->has_value()) {
      state.SkipWithError("no reply");
      break;
    }
    const auto decoded = ecat::wire::decode_frame((*r)->frame);
    if (!decoded) {
      ++wrong;
      continue;
    }
    for (const ecat::wire::DatagramView d : *decoded.frame) {
      if (d.wkc != slaves) ++wrong;
    }
  }
  state.counters["slaves"] = static_cast<double>(slaves);
  state.counters["wrong_wkc"] = static_cast<double>(wrong);
  state.counters["frames/s"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_InProcessResetBlockFrame)->Arg(64)->Arg(256)->Arg(512)->Arg(1024);

// ---- veth ---------------------------------------------------------------------------------------

void veth_round_trips(benchmark::State& state, ecat::link::Link& master,
                      const std::vector<std::uint8_t>& frame) {
  std::int64_t lost = 0;
  for (auto _ : state) {
    if (!master.send(frame).ok()) {
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

// Both ends of a veth pair in a private namespace, raw links open on each; false (the benchmark
// skipped with the reason) when there are none.
struct VethEnds {
  VethPair pair;
  std::unique_ptr<ecat::link::RawLink> master, segment;

  bool open(benchmark::State& state) {
    if (pair.problem().empty()) {
      master = pair.open("m", false);
      segment = pair.open("s", true);
    }
    if (!master || !segment) {
      state.SkipWithError(pair.problem().c_str());
      return false;
    }
    return true;
  }
};

void BM_VethBareEcho(benchmark::State& state) {
  VethEnds ends;
  if (!ends.open(state)) return;
  const auto frame = cyclic_frame(static_cast<std::size_t>(state.range(0)));
  Echo echo(*ends.segment);
  veth_round_trips(state, *ends.master, frame);
}
BENCHMARK(BM_VethBareEcho)->Arg(1)->Arg(16)->Arg(64)->Arg(256)->UseRealTime();

void BM_VethSimServer(benchmark::State& state) {
  const auto slaves = static_cast<std::size_t>(state.range(0));
  auto server = configured_server(slaves);
  if (!server) {
    state.SkipWithError("cannot build the segment");
    return;
  }
  VethEnds ends;
  if (!ends.open(state)) return;
  if (auto r = server->serve(std::move(ends.segment)); !r) {
    state.SkipWithError(r.error().describe().c_str());
    return;
  }
  veth_round_trips(state, *ends.master, cyclic_frame(slaves));
  server->stop();
}
BENCHMARK(BM_VethSimServer)->Arg(1)->Arg(16)->Arg(64)->Arg(256)->UseRealTime();

}  // namespace

int main(int argc, char** argv) {
  return ecat::bench::benchmark_main(argc, argv);
}
