// Fixtures of the mailbox and retained-configuration scenarios (docs/scenarios/): the segmented
// ring with a startup download that really takes several segments, the hardware ring with the
// EL3202 `rtd`, SDO helpers and what the simulator's CoE server saw.
//
//   auto ring = scenarios::start_segmented(/*held_in_preop=*/true);
//   auto& mbx = ring->slave("mailbox");
//   ASSERT_TRUE(ring->server->inject(sim::fault::mailbox_abort("mailbox", 0x2000, 1, code)));
//   EXPECT_EQ(master::sdo_failure(mbx.upload_sdo(0x2000, 1).error()), SdoFailure::aborted);
//
// Built on scenario_support.hpp (the rings, ScenarioRing, eventually()). The mailbox device has a
// 64-byte mailbox: a download carries 48 bytes in its initiate request and 55 per segment, so the
// 192-byte startup blob to 0x2003:01 is an initiate and three segments.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/coe_client.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/server.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {

using master::SdoFailure;
using Bytes = std::vector<std::uint8_t>;

// The mailbox device's objects as it starts (src/sim/devices/mailbox_device.cpp).
inline Bytes pattern(std::size_t n, unsigned step) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * step) & 0xFF);
  return out;
}
inline Bytes default_0x2002() {
  return pattern(80, 1);
}
inline Bytes default_0x2003() {
  return pattern(192, 1);
}

// What the segmented ring's startup downloads to 0x2003:01: 192 bytes unlike the default.
inline Bytes startup_blob() {
  Bytes blob(192);
  for (std::size_t i = 0; i < blob.size(); ++i)
    blob[i] = static_cast<std::uint8_t>(0xFF - i);
  return blob;
}

// The mailbox slave's startup SDOs: the multi-segment blob.
inline std::vector<master::SdoWrite> mailbox_startup_sdos() {
  return {{0x2003, 0x01, startup_blob(), false}};
}

// The segmented ring (coupler, inputs, outputs, mailbox). `held_in_preop`: every slave's target
// is PREOP, the session ends preop_ready (the reference's PREOP-first start).
inline RingSpec segmented_spec(bool held_in_preop) {
  RingSpec spec;
  spec.kind = RingKind::segmented;
  if (held_in_preop) {
    for (const char* name : {"coupler", "inputs", "outputs", "mailbox"})
      spec.targets[name] = TargetState::preop;
  }
  spec.adjust = [](master::MasterConfig& config) {
    for (auto& s : config.slaves) {
      if (s.name == "mailbox") s.startup_sdos = mailbox_startup_sdos();
    }
  };
  return spec;
}

// The hardware ring: the segmented ring's digital I/O plus an EL3202 `rtd` whose startup SDOs
// set the RTD element of both channels (0x8000:19, then 0x8010:19: PT100 = 0). `split`: the RTD's
// signals go to their own domain `rtd`, the digital I/O stays in `main`.
inline RingSpec hardware_spec(bool split) {
  RingSpec spec;
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: rtd, profile: EL3202}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_16, to: inputs.channel_16}
)";
  const auto health = spec.health_poll;
  spec.adjust = [split, health](master::MasterConfig& config) {
    if (split) {
      master::DomainConfig rtd = config.domains.front();
      rtd.id = "rtd";
      config.domains.push_back(rtd);
    }
    master::SlaveConfig rtd;
    rtd.name = "rtd";
    rtd.process_data = master::ProcessDataRequest::all(split ? "rtd" : "main");
    rtd.health_poll = health;
    rtd.startup_sdos = {{0x8000, 0x19, {0x00, 0x00}, false}, {0x8010, 0x19, {0x00, 0x00}, false}};
    config.slaves.push_back(std::move(rtd));
  };
  return spec;
}

// Starts the segmented ring and waits until it runs (preop_ready or operational).
inline std::unique_ptr<ScenarioRing> start_segmented(bool held_in_preop) {
  auto ring = ScenarioRing::create(segmented_spec(held_in_preop));
  if (!ring) return nullptr;
  const MasterState want = held_in_preop ? MasterState::preop_ready : MasterState::operational;
  if (!eventually([&] { return ring->state() == want; }, 10s)) {
    std::string failures;
    for (const auto& f : ring->master->status().activation_failures)
      failures += "; " + f.slave + ": " + f.error.describe();
    ADD_FAILURE() << "the segmented ring did not reach " << master::to_string(want) << ": "
                  << ring->describe() << failures;
    return nullptr;
  }
  return ring;
}

// Short per-exchange timeouts for transfers expected to time out.
inline master::SdoOptions quick_sdo() {
  master::SdoOptions options;
  options.timeout = 100ms;
  return options;
}

// The failure an SDO result carries (none when it succeeded).
template <class T>
SdoFailure failure_of(const Result<T>& result) {
  return result ? SdoFailure::none : master::sdo_failure(result.error());
}

// The simulator's CoE server statistics of a slave (zeros for one without a mailbox).
inline sim::CoeServerStats coe_stats(sim::SimServer& server, const std::string& slave) {
  return server.with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto index = segment.find(slave);
    if (!index) return sim::CoeServerStats{};
    auto* coe = sim::coe_server_of(segment.esc(*index));
    return coe ? coe->stats() : sim::CoeServerStats{};
  });
}

inline std::size_t stage_slot(sim::MailboxStage stage) {
  return static_cast<std::size_t>(stage);
}

// A mailbox protocol fault that fires once.
inline sim::Fault protocol_fault_once(const std::string& slave, std::uint16_t index,
                                      std::uint8_t subindex, sim::MailboxStage stage,
                                      sim::ProtocolFaultKind kind, std::uint8_t value = 0) {
  auto fault = sim::fault::mailbox_protocol_fault(slave, index, subindex, stage, {kind, value});
  fault.effect.once = true;
  return fault;
}

// The retained PREOP configuration failure of a slave, if any.
inline std::optional<std::string> configuration_error(ScenarioRing& ring, const std::string& name) {
  return ring.slave(name).info().configuration_error;
}

}  // namespace ecat::scenarios
