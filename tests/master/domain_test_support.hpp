// A simulated ring for Domain and Cycler tests, brought up the way a master would (upstream §3.5)
// because the Slave layer that normally does it is not part of these tests: station addresses,
// process-data SyncManagers sized from the SII's PDOs, one FMMU per SyncManager at the logical
// address the Domain assigned, AL state requests through 0x0120.
//
// Ring: coupler (EK1100) 0x1001, inputs (EL1809) 0x1002, outputs (EL2809) 0x1003, inputs2
// (EL1809) 0x1004. outputs.channel_N drives inputs.channel_N (as examples/default.yaml).
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#if defined(__SANITIZE_ADDRESS__)
#define ECAT_DOMAIN_TEST_SLOW 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define ECAT_DOMAIN_TEST_SLOW 1
#endif
#endif

namespace ecat::master::test {

using namespace std::chrono_literals;

// Sanitized Debug builds run the simulator some 100 times slower (about 0.5 ms per frame with
// terminals in OP): their cycles, timeouts and waits are stretched by kSlow.
#ifdef ECAT_DOMAIN_TEST_SLOW
constexpr int kSlow = 5;
#else
constexpr int kSlow = 1;
#endif
// The period the cycling tests use.
constexpr std::chrono::nanoseconds kPeriod = std::chrono::milliseconds(1) * kSlow;

constexpr std::uint16_t kCoupler = 0x1001;
constexpr std::uint16_t kInputs = 0x1002;
constexpr std::uint16_t kOutputs = 0x1003;
constexpr std::uint16_t kInputs2 = 0x1004;
constexpr std::size_t kSlaveCount = 4;

inline std::size_t position_of(std::uint16_t station) {
  return static_cast<std::size_t>(station - kCoupler);
}

inline const char* kRingYaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: inputs2, profile: EL1809}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_2, to: inputs.channel_2}
    - {from: outputs.channel_3, to: inputs.channel_3}
    - {from: outputs.channel_4, to: inputs.channel_4}
    - {from: outputs.channel_5, to: inputs.channel_5}
    - {from: outputs.channel_6, to: inputs.channel_6}
    - {from: outputs.channel_7, to: inputs.channel_7}
    - {from: outputs.channel_8, to: inputs.channel_8}
    - {from: outputs.channel_9, to: inputs.channel_9}
    - {from: outputs.channel_10, to: inputs.channel_10}
    - {from: outputs.channel_11, to: inputs.channel_11}
    - {from: outputs.channel_12, to: inputs.channel_12}
    - {from: outputs.channel_13, to: inputs.channel_13}
    - {from: outputs.channel_14, to: inputs.channel_14}
    - {from: outputs.channel_15, to: inputs.channel_15}
    - {from: outputs.channel_16, to: inputs.channel_16}
)";

// One process-data SyncManager as the SII describes it, its length from the assigned PDOs.
struct ProcessDataSm {
  std::uint8_t index = 0;
  std::uint16_t start = 0;
  std::uint16_t length = 0;
  std::uint8_t control = 0;
  PdoDirection direction = PdoDirection::input;
};

struct Rig {
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<bus::Bus> bus;
  std::vector<std::uint8_t> next_fmmu = std::vector<std::uint8_t>(kSlaveCount, 0);

  wire::SiiImage sii(std::uint16_t station) {
    return server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      auto decoded = wire::decode_sii(segment.esc(position_of(station)).eeprom());
      EXPECT_TRUE(decoded.ok());
      return decoded.ok() ? decoded->image : wire::SiiImage{};
    });
  }

  std::vector<ProcessDataSm> process_data_sms(std::uint16_t station) {
    const auto image = sii(station);
    std::vector<ProcessDataSm> out;
    for (std::size_t sm = 0; sm < image.sync_managers.size(); ++sm) {
      const auto& s = image.sync_managers[sm];
      const bool output = s.type == wire::sii_sm_type::kOutputs;
      if ((!output && s.type != wire::sii_sm_type::kInputs) || !s.enabled() || s.virtual_sm()) {
        continue;
      }
      std::uint32_t bits = 0;
      for (const auto& p : output ? image.rxpdos : image.txpdos) {
        if (p.sync_manager == sm) bits += p.bit_length();
      }
      if (bits == 0) continue;
      out.push_back({static_cast<std::uint8_t>(sm), s.start,
                     static_cast<std::uint16_t>((bits + 7) / 8), s.control,
                     output ? PdoDirection::output : PdoDirection::input});
    }
    return out;
  }

  void write(std::uint16_t station, std::uint16_t offset, std::vector<std::uint8_t> data) {
    bus::Transaction tx;
    tx.fpwr(station, offset, data, 1);
    auto r = bus->transact(std::move(tx));
    ASSERT_TRUE(r.ok()) << r.error().describe();
  }

  std::uint16_t read16(std::uint16_t station, std::uint16_t offset) {
    bus::Transaction tx;
    tx.fprd(station, offset, 2, 1);
    auto r = bus->transact(std::move(tx));
    EXPECT_TRUE(r.ok()) << r.error().describe();
    return r.ok() ? wire::load_le16(r->data(0).data()) : 0;
  }

  // SM (deactivate, configure, activate) and one FMMU for it.
  void map(std::uint16_t station, const ProcessDataSm& sm, std::uint32_t logical) {
    const auto base = wire::reg::sync_manager(sm.index);
    const auto activate = static_cast<std::uint16_t>(base + wire::reg::kSyncManagerActivateOffset);
    write(station, activate, {0});
    write(station, base,
          {static_cast<std::uint8_t>(sm.start), static_cast<std::uint8_t>(sm.start >> 8),
           static_cast<std::uint8_t>(sm.length), static_cast<std::uint8_t>(sm.length >> 8),
           sm.control, 0});
    write(station, activate, {1});
    wire::FmmuConfig f;
    f.logical_start = logical;
    f.length = sm.length;
    f.physical_start = sm.start;
    f.type = sm.direction == PdoDirection::output ? wire::FmmuType::write : wire::FmmuType::read;
    f.active = true;
    const auto bytes = f.encode();
    auto& n = next_fmmu[position_of(station)];
    write(station, wire::reg::fmmu(n++), std::vector<std::uint8_t>(bytes.begin(), bytes.end()));
  }

  // Registers every process-data SM of `station` in `domain` and maps it there.
  void attach(Domain& domain, std::uint16_t station) {
    for (const auto& sm : process_data_sms(station)) {
      auto logical = domain.register_pdo({station, sm.index}, sm.length, sm.direction);
      ASSERT_TRUE(logical.ok()) << logical.error().describe();
      map(station, sm, *logical);
    }
  }

  void request(std::uint16_t station, wire::AlState state) {
    write(station, wire::reg::kAlControl,
          {static_cast<std::uint8_t>(wire::encode_al_control(state)), 0});
    const auto deadline = std::chrono::steady_clock::now() + 2s;
    std::uint16_t status = 0;
    while (std::chrono::steady_clock::now() < deadline) {
      status = read16(station, wire::reg::kAlStatus);
      if (wire::al_state_from_code(status & 0x0F) == state && (status & 0x10) == 0) return;
      std::this_thread::sleep_for(1ms);
    }
    ADD_FAILURE() << fmt::format("station 0x{:04x} did not reach {} (AL status 0x{:04x})", station,
                                 wire::to_string(state), status);
  }

  void all_to(wire::AlState state) {
    for (std::uint16_t s = kCoupler; s < kCoupler + kSlaveCount; ++s)
      request(s, state);
  }
};

inline std::unique_ptr<Rig> make_rig(bus::BusOptions options = {}) {
  auto rig = std::make_unique<Rig>();
  auto ring = sim::parse_ring(kRingYaml);
  EXPECT_TRUE(ring.ok()) << ring.error().describe();
  if (!ring) return nullptr;
  auto server = sim::make_server(*ring);
  EXPECT_TRUE(server.ok()) << server.error().describe();
  if (!server) return nullptr;
  rig->server = std::move(*server);
  auto link = rig->server->serve_memory();
  EXPECT_TRUE(link.ok()) << link.error().describe();
  if (!link) return nullptr;
  if (options.frame_timeout == std::chrono::milliseconds(25)) options.frame_timeout = 20ms * kSlow;
  rig->bus = std::make_unique<bus::Bus>(std::move(*link), std::move(options));
  auto started = rig->bus->start();
  EXPECT_TRUE(started.ok()) << started.error().describe();
  for (std::size_t pos = 0; pos < kSlaveCount; ++pos) {
    bus::Transaction tx;
    const std::array<std::uint8_t, 2> station{static_cast<std::uint8_t>(kCoupler + pos),
                                              static_cast<std::uint8_t>((kCoupler + pos) >> 8)};
    tx.apwr(static_cast<std::uint16_t>(pos), wire::reg::kStationAddress, station, 1);
    auto r = rig->bus->transact(std::move(tx));
    EXPECT_TRUE(r.ok()) << r.error().describe();
  }
  rig->all_to(wire::AlState::init);
  rig->all_to(wire::AlState::preop);
  return rig;
}

// Polls `condition` until it holds or `timeout` passes.
template <class F>
bool eventually(F&& condition, std::chrono::milliseconds timeout = 3000ms) {
  const auto deadline = std::chrono::steady_clock::now() + timeout * kSlow;
  while (std::chrono::steady_clock::now() < deadline) {
    if (condition()) return true;
    std::this_thread::sleep_for(1ms);
  }
  return condition();
}

// Records every observer call (thread-safe: called on the bus thread, read by the test).
class RecordingObserver : public DomainObserver {
 public:
  void on_inputs_changed(Domain&, std::size_t count) override {
    inputs_changed.fetch_add(count, std::memory_order_relaxed);
  }
  void on_cycle_degraded(Domain&, const CycleInvalid& last) override {
    std::lock_guard lock(mutex);
    degraded.push_back(last);
  }
  void on_cycle_recovered(Domain&) override { recovered.fetch_add(1); }
  void on_stopped(Domain&, const CycleInvalid& last, std::uint64_t misses) override {
    std::lock_guard lock(mutex);
    stopped.push_back(last);
    stopped_misses = misses;
  }

  std::size_t degraded_count() {
    std::lock_guard lock(mutex);
    return degraded.size();
  }
  std::size_t stopped_count() {
    std::lock_guard lock(mutex);
    return stopped.size();
  }

  std::mutex mutex;
  std::vector<CycleInvalid> degraded;
  std::vector<CycleInvalid> stopped;
  std::uint64_t stopped_misses = 0;
  std::atomic<std::size_t> inputs_changed{0};
  std::atomic<int> recovered{0};
};

}  // namespace ecat::master::test
