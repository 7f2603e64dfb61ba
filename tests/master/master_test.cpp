// The master session end to end against the simulator: discovery, every slave to PREOP and OP,
// process data through a domain (outputs wired back to inputs), SDOs through a slave, the state
// machine's public calls in the right and the wrong states.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/sii.hpp>

#include "master/master_test_support.hpp"
#include "support/shared_data.hpp"

namespace ecat::master {
namespace {

using test::edited_eeprom;

using namespace std::chrono_literals;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: rtd, profile: EL3202}
    - {name: drive, profile: servo}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_5, to: inputs.channel_5}
)";

std::string explain(Master& master) {
  auto status = master.status();
  std::string out = std::string(to_string(status.state));
  for (const auto& f : status.activation_failures)
    out += "\n  " + f.error.describe();
  for (const auto& f : status.runtime_faults)
    out += "\n  fault: " + f;
  for (const auto& s : status.slaves) {
    out += "\n  " + s.name + " " + std::string(to_string(s.state));
    if (s.fault) out += " " + *s.fault;
  }
  return out;
}

MasterConfig fast_config() {
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.awaiting_preop_timeout = 5s;
  config.retry_interval = 50ms;
  config.dc.reset();
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  config.domains.push_back(main);
  return config;
}

SlaveConfig slave(std::string name, ProcessDataRequest pd = ProcessDataRequest::all("main"),
                  TargetState target = TargetState::op) {
  SlaveConfig c;
  c.name = std::move(name);
  c.process_data = std::move(pd);
  c.target = target;
  return c;
}

class MasterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
  }
  std::unique_ptr<link::Link> link() {
    if (server_->serving()) server_->stop();
    auto l = server_->serve_memory();
    EXPECT_TRUE(l) << l.error().describe();
    return std::move(*l);
  }
  MasterConfig full_config() {
    auto config = fast_config();
    config.slaves = {slave("coupler", {}), slave("inputs"), slave("outputs"), slave("rtd"),
                     slave("drive")};
    return config;
  }
  std::unique_ptr<sim::SimServer> server_;
};

TEST_F(MasterTest, ReachesOperationalAndExchangesProcessData) {
  Master master(full_config());
  std::vector<std::pair<MasterState, MasterState>> seen;
  std::mutex seen_mutex;
  master.on_state_change([&](MasterState from, MasterState to) {
    std::lock_guard lock(seen_mutex);
    seen.emplace_back(from, to);
  });
  ASSERT_TRUE(master.start(link()));
  auto op = master.await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe() << "\n" << explain(master);
  EXPECT_EQ(master.state(), MasterState::operational);
  {
    std::lock_guard lock(seen_mutex);
    ASSERT_EQ(seen.size(), 3u);
    EXPECT_EQ(seen[0], std::make_pair(MasterState::idle, MasterState::discovering));
    EXPECT_EQ(seen[1], std::make_pair(MasterState::discovering, MasterState::awaiting_preop));
    EXPECT_EQ(seen[2], std::make_pair(MasterState::awaiting_preop, MasterState::operational));
  }
  auto slaves = master.slaves();
  ASSERT_EQ(slaves.size(), 5u);
  for (const auto& s : slaves) {
    EXPECT_EQ(s.state, SlaveState::op) << s.name;
    EXPECT_FALSE(s.fault.has_value()) << s.name << ": " << *s.fault;
  }
  EXPECT_EQ(slaves[2].station, 0x1002);

  auto out = master.slave("outputs");
  ASSERT_TRUE(out);
  auto in = master.slave("inputs");
  ASSERT_TRUE(in);
  EXPECT_EQ((*out)->info().driver, "EL2809");
  ASSERT_TRUE((*out)->write_output("channel_1", true));
  ASSERT_TRUE((*out)->write_output("channel_5", true));
  bool seen_high = false;
  for (int i = 0; i < 500 && !seen_high; ++i) {
    auto v1 = (*in)->read_input("channel_1");
    auto v5 = (*in)->read_input("channel_5");
    auto v2 = (*in)->read_input("channel_2");
    if (v1 && v5 && v2 && as_bool(*v1) == true && as_bool(*v5) == true) {
      EXPECT_EQ(as_bool(*v2), false);
      seen_high = true;
    }
    std::this_thread::sleep_for(2ms);
  }
  EXPECT_TRUE(seen_high) << "outputs never came back through the wiring";
  // The domain: EL1809 inputs (1), EL2809 outputs (2), EL3202 inputs (1), the drive both (3).
  auto domains = master.domains();
  for (int i = 0; i < 500 && domains.at(0).cycles <= 10; ++i) {
    std::this_thread::sleep_for(2ms);
    domains = master.domains();
  }
  ASSERT_EQ(domains.size(), 1u);
  EXPECT_EQ(domains[0].state, "cycling");
  EXPECT_EQ(domains[0].expected_wkc, 7);
  EXPECT_GT(domains[0].cycles, 10u);
  // Healthy = the latest cycle was valid; on a loaded machine a single exchange may time out,
  // so look a few times.
  bool healthy = domains[0].healthy;
  for (int i = 0; i < 200 && !healthy; ++i) {
    std::this_thread::sleep_for(2ms);
    healthy = master.domains().at(0).healthy;
  }
  EXPECT_TRUE(healthy);

  EXPECT_EQ(master.status().illegal_transitions, 0u);
  ASSERT_TRUE(master.stop());
  EXPECT_EQ(master.state(), MasterState::idle);
  // A stopped session leaves every slave in INIT (no outputs left driven by a dead master).
  server_->with_segment([](sim::Segment& segment, auto&) {
    for (std::size_t i = 0; i < segment.size(); ++i) {
      EXPECT_EQ(segment.esc(i).al_state(), wire::AlState::init) << "slave " << i;
    }
  });
  auto again = master.stop();
  ASSERT_TRUE(again);
  EXPECT_EQ(*again, StopOutcome::already_stopped);
}

TEST_F(MasterTest, SubscribersSeeSignalChanges) {
  Master master(full_config());
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  auto in = master.slave("inputs");
  auto out = master.slave("outputs");
  ASSERT_TRUE(in && out);
  std::atomic<int> rising{0};
  auto sub = (*in)->subscribe("channel_1", [&](const SignalEvent& e) {
    if (as_bool(e.value) == true) ++rising;
  });
  ASSERT_TRUE(sub) << sub.error().describe();
  ASSERT_FALSE((*in)->subscribe("no_such_signal", [](const SignalEvent&) {}));
  ASSERT_TRUE((*out)->write_output("channel_1", true));
  for (int i = 0; i < 500 && rising == 0; ++i)
    std::this_thread::sleep_for(2ms);
  EXPECT_EQ(rising.load(), 1);
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, SdosThroughTheSlave) {
  Master master(full_config());
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  // Device type (0x1000) of a CiA 402 drive: profile 402 in the low word.
  auto type = (*drive)->upload_sdo(0x1000, 0);
  ASSERT_TRUE(type) << type.error().describe();
  ASSERT_EQ(type->size(), 4u);
  EXPECT_EQ((*type)[0] | ((*type)[1] << 8), 402);
  auto missing = (*drive)->upload_sdo(0x5FFF, 0);
  ASSERT_FALSE(missing);
  EXPECT_EQ(missing.error().code(), Errc::sdo_abort);
  auto coupler = master.slave("coupler");
  ASSERT_TRUE(coupler);
  auto none = (*coupler)->upload_sdo(0x1000, 0);
  ASSERT_FALSE(none);
  EXPECT_EQ(none.error().code(), Errc::unsupported);
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, DynamicSessionHoldsEverySlaveInPreop) {
  auto config = fast_config();
  config.domains.clear();
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  auto running = master.await_running(10s);
  ASSERT_TRUE(running) << running.error().describe();
  EXPECT_EQ(master.state(), MasterState::preop_ready);
  auto slaves = master.slaves();
  ASSERT_EQ(slaves.size(), 5u);
  EXPECT_EQ(slaves[0].name, "coupler");  // the EK1100's SII says so (dynamic_names.hpp)
  EXPECT_EQ(slaves[1].name, "slave_1");
  for (const auto& s : slaves)
    EXPECT_EQ(s.state, SlaveState::preop);
  auto d = master.deactivate(TargetState::safeop);
  ASSERT_FALSE(d);
  EXPECT_EQ(d.error().code(), Errc::wrong_state);
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, PreopFirstThenActivateAndDeactivate) {
  auto config = full_config();
  for (auto& s : config.slaves)
    s.target = TargetState::preop;
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_running(10s));
  EXPECT_EQ(master.state(), MasterState::preop_ready);
  // Reconfigure in PREOP: the EL2809 with a startup SDO-free configuration, routed differently.
  auto reconf = slave("outputs");
  ASSERT_TRUE(master.configure_slave("outputs", reconf));
  auto unknown = master.configure_slave("nobody", slave("nobody"));
  ASSERT_FALSE(unknown);
  EXPECT_EQ(unknown.error().code(), Errc::not_found);
  for (auto& s : config.slaves)
    s.target = TargetState::op;
  for (const char* name : {"coupler", "inputs", "outputs", "rtd", "drive"}) {
    auto sl = master.slave(name);
    ASSERT_TRUE(sl);
    auto c = (*sl)->info();
    (void)c;
  }
  // Only the reconfigured slave targets OP now: activate() brings it to OP, the others stay in
  // PREOP (min(op, their preop target)).
  auto activated = master.activate();
  ASSERT_TRUE(activated) << activated.error().describe() << "\n" << explain(master);
  EXPECT_EQ(master.state(), MasterState::operational);
  for (const auto& s : master.slaves()) {
    EXPECT_EQ(s.state, s.name == "outputs" ? SlaveState::op : SlaveState::preop) << s.name;
  }
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, ActivateDeactivateCycle) {
  Master master(full_config());
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  auto again = master.activate();
  ASSERT_FALSE(again);
  EXPECT_EQ(again.error().code(), Errc::wrong_state);
  ASSERT_TRUE(master.deactivate(TargetState::safeop));
  EXPECT_EQ(master.state(), MasterState::deactivated);
  for (const auto& s : master.slaves())
    EXPECT_EQ(s.state, SlaveState::safeop) << s.name;
  ASSERT_TRUE(master.activate());
  EXPECT_EQ(master.state(), MasterState::operational);
  ASSERT_TRUE(master.deactivate(TargetState::preop));
  EXPECT_EQ(master.state(), MasterState::preop_ready);
  for (const auto& s : master.slaves())
    EXPECT_EQ(s.state, SlaveState::preop) << s.name;
  ASSERT_FALSE(master.deactivate(TargetState::op));
  EXPECT_EQ(master.status().illegal_transitions, 0u);
  ASSERT_TRUE(master.stop());
}

// A startup that fails after the ring is up (one slave never reaches PREOP: its identity is not
// the configured one) ends in idle with every slave back in INIT, those that got to PREOP too.
TEST_F(MasterTest, AFailedStartupLeavesEverySlaveInInit) {
  auto config = full_config();
  config.awaiting_preop_timeout = 1s;
  config.slave_retry_interval = 50ms;
  config.slaves[4].product_code = 0x0BADC0DE;
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  const auto in_preop = [&] {
    for (const auto& s : server_->status().slaves) {
      if (s.al_state == wire::AlState::preop) return true;
    }
    return false;
  };
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  bool saw_preop = false;
  while (master.state() != MasterState::idle && std::chrono::steady_clock::now() < deadline) {
    saw_preop = saw_preop || in_preop();
    std::this_thread::sleep_for(2ms);
  }
  ASSERT_EQ(master.state(), MasterState::idle);
  EXPECT_TRUE(saw_preop) << "the other slaves never reached PREOP: nothing to take back";
  ASSERT_TRUE(master.last_failure().has_value());
  EXPECT_EQ(master.last_failure()->kind, "awaiting_preop_failed");
  EXPECT_NE(master.last_failure()->error.describe().find("drive"), std::string::npos)
      << master.last_failure()->error.describe();
  for (const auto& s : server_->status().slaves) {
    EXPECT_EQ(s.al_state, wire::AlState::init) << s.name;
  }
}

TEST_F(MasterTest, BadConfigurationsAreRefusedByName) {
  auto config = full_config();
  config.slaves[1].process_data = ProcessDataRequest::all("nowhere");
  Master master(config);
  auto started = master.start(link());
  ASSERT_FALSE(started);
  EXPECT_EQ(started.error().code(), Errc::invalid_argument);
  EXPECT_NE(started.error().message().find("nowhere"), std::string::npos);

  auto dup = full_config();
  dup.slaves[2].name = "inputs";
  EXPECT_FALSE(validate(dup));
  auto period = full_config();
  period.domains[0].period = 1us;
  EXPECT_FALSE(validate(period));

  // More slaves configured than the ring has: startup fails, the master returns to idle and
  // keeps the failure.
  auto too_many = full_config();
  too_many.slaves.push_back(slave("ghost", {}));
  Master m2(too_many);
  ASSERT_TRUE(m2.start(link()));
  auto running = m2.await_running(10s);
  ASSERT_FALSE(running);
  EXPECT_NE(running.error().describe().find("6 slaves configured, the ring has 5"),
            std::string::npos)
      << running.error().describe();
  EXPECT_EQ(m2.state(), MasterState::idle);
  ASSERT_TRUE(m2.last_failure().has_value());
  EXPECT_EQ(m2.last_failure()->kind, "startup_failed");
}

// Firmware that accepts INIT and PREOP but refuses SAFEOP and OP with "invalid input
// configuration" (0x001E), as a device does whose process data the master set up wrongly.
class RefusesSafeop : public sim::Application {
 public:
  void on_al_control(sim::Esc& esc, std::uint16_t control) override {
    const auto requested = static_cast<wire::AlState>(control & 0x0F);
    if (requested == wire::AlState::safeop || requested == wire::AlState::op) {
      esc.pdi_set_al_status(esc.al_state(), true, 0x001E);
    } else {
      esc.pdi_set_al_status(requested, false, 0);
    }
  }
};

TEST(MasterActivation, BlockedNamesTheSlaveAndCode) {
  sim::DeviceConfig coupler_device;
  coupler_device.profile = "EK1100";
  auto coupler = sim::make_device(coupler_device);
  ASSERT_TRUE(coupler);
  sim::DeviceConfig io_device;
  io_device.profile = "EL1809";
  auto io = sim::make_device(io_device);
  ASSERT_TRUE(io);
  const auto eeprom = (*io)->eeprom();
  auto segment = std::make_unique<sim::Segment>();
  ASSERT_TRUE(segment->add_slave("coupler", std::move(*coupler)));
  ASSERT_TRUE(segment->add_slave(
      "stubborn", std::make_unique<sim::Esc>(
                      sim::EscHardware{}, std::vector<std::uint8_t>(eeprom.begin(), eeprom.end()),
                      std::make_unique<RefusesSafeop>())));
  sim::SimServer server(std::move(segment));
  auto link = server.serve_memory();
  ASSERT_TRUE(link);
  auto config = fast_config();
  config.domains.clear();
  config.slaves = {slave("coupler", {}), slave("stubborn", {})};
  Master master(config);
  ASSERT_TRUE(master.start(std::move(*link)));
  auto running = master.await_running(10s);
  ASSERT_FALSE(running);
  EXPECT_EQ(master.state(), MasterState::activation_blocked);
  auto status = master.status();
  ASSERT_EQ(status.activation_failures.size(), 1u);
  EXPECT_EQ(status.activation_failures[0].slave, "stubborn");
  EXPECT_EQ(status.activation_failures[0].wanted, wire::AlState::op);
  ASSERT_TRUE(status.activation_failures[0].al_status_code.has_value());
  EXPECT_EQ(*status.activation_failures[0].al_status_code, 0x001E);
  EXPECT_NE(running.error().describe().find("0x001e"), std::string::npos)
      << running.error().describe();
  EXPECT_EQ(status.illegal_transitions, 0u);
  ASSERT_TRUE(master.stop());
}

// The application's synchronisation goes to 0x1C32/0x1C33:01 on the way to SAFEOP (ETG.1020):
// SyncManager-synchronous without distributed clocks.
TEST_F(MasterTest, SmSynchronousModeIsWrittenToTheSyncManagerParameters) {
  auto config = full_config();
  SyncConfig sync;
  sync.mode = SyncMode::sm_synchronous;
  config.slaves[4].sync = sync;  // the drive
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  auto op = master.await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe();
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  auto out = (*drive)->upload_sdo(0x1C32, 1);
  ASSERT_TRUE(out) << out.error().describe();
  EXPECT_EQ(*out, (std::vector<std::uint8_t>{0x01, 0x00}));
  auto in = (*drive)->upload_sdo(0x1C33, 1);
  ASSERT_TRUE(in) << in.error().describe();
  EXPECT_EQ(*in, (std::vector<std::uint8_t>{0x22, 0x00}));
  EXPECT_FALSE((*drive)->info().dc_sync.has_value());  // no DC unit touched
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, PdoLayoutReadFromCoe) {
  auto config = full_config();
  config.slaves[4].pdo_source = SlaveConfig::PdoSource::coe;
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  auto op = master.await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe() << "\n" << explain(master);
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  auto info = (*drive)->info();
  EXPECT_EQ(info.driver, "cia402");
  ASSERT_FALSE(info.layout.sync_managers.empty());
  std::vector<std::string> names;
  for (const auto& s : info.signals)
    names.push_back(s.name);
  EXPECT_NE(std::find(names.begin(), names.end(), "statusword"), names.end());
  EXPECT_NE(std::find(names.begin(), names.end(), "controlword"), names.end());
  // The drive's statusword arrives through the CoE-described layout.
  bool fresh = false;
  for (int i = 0; i < 500 && !fresh; ++i) {
    fresh = static_cast<bool>((*drive)->read_input("statusword"));
    std::this_thread::sleep_for(2ms);
  }
  EXPECT_TRUE(fresh);
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, StartupSdoFailureIsRetainedAndBlocksSafeop) {
  auto config = full_config();
  // An object the drive does not have: the PREOP configuration fails, the slave stays in PREOP
  // with the failure retained, and activation is blocked naming it.
  config.slaves[4].startup_sdos.push_back(SdoWrite{0x5FFF, 0, {1}, false});
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  auto running = master.await_running(10s);
  ASSERT_FALSE(running);
  EXPECT_EQ(master.state(), MasterState::activation_blocked);
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  auto info = (*drive)->info();
  ASSERT_TRUE(info.configuration_error.has_value());
  EXPECT_NE(info.configuration_error->find("0x5fff"), std::string::npos)
      << *info.configuration_error;
  EXPECT_EQ((*drive)->state(), SlaveState::preop);
  auto refused = (*drive)->request(wire::AlState::op);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::wrong_state);
  // Retrying does not help while the object is missing.
  EXPECT_FALSE((*drive)->retry());
  ASSERT_TRUE(master.stop());
}

TEST_F(MasterTest, TwoMastersInOneProcess) {
  auto server2 = test::make_sim_server(kRing);
  ASSERT_TRUE(server2);
  auto link2 = server2->serve_memory();
  ASSERT_TRUE(link2);
  Master a(full_config());
  Master b(full_config());
  ASSERT_TRUE(a.start(link()));
  ASSERT_TRUE(b.start(std::move(*link2)));
  ASSERT_TRUE(a.await_operational(10s));
  ASSERT_TRUE(b.await_operational(10s));
  EXPECT_NE(a.bus(), b.bus());
  ASSERT_TRUE(a.stop());
  EXPECT_EQ(b.state(), MasterState::operational);
  ASSERT_TRUE(b.stop());
}

TEST_F(MasterTest, PerCycleCallbackRunsOnTheCycleThreadWithThisCyclesInputs) {
  auto config = full_config();
  struct Seen {
    std::atomic<std::uint64_t> valid{0};
    std::atomic<std::uint64_t> invalid{0};
    std::atomic<std::uint64_t> last_cycle{0};
    std::atomic<bool> out_of_order{false};
  };
  auto seen = std::make_shared<Seen>();
  config.domains[0].on_cycle = [seen](Domain&, const CycleOutcome& outcome) {
    if (outcome.cycle <= seen->last_cycle.load()) seen->out_of_order = true;
    seen->last_cycle = outcome.cycle;
    (outcome.valid ? seen->valid : seen->invalid).fetch_add(1);
  };
  config.cycle_thread.cpu = 0;
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  for (int i = 0; i < 2000 && seen->valid.load() < 50; ++i)
    std::this_thread::sleep_for(1ms);
  EXPECT_GE(seen->valid.load(), 50u);
  EXPECT_FALSE(seen->out_of_order.load());
  // Never more reports than cycles the domain ran.
  const auto reported = seen->valid.load() + seen->invalid.load();
  EXPECT_GE(master.domains().at(0).cycles, reported);
  ASSERT_TRUE(master.stop());
  EXPECT_EQ(master.status().cycle_thread, "");  // stopped: no session to report on
}

TEST_F(MasterTest, CycleThreadOptionsAreReported) {
  auto config = full_config();
  config.cycle_thread.cpu = 0;
  config.cycle_thread.fifo_priority = 10;
  Master master(config);
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  const auto report = master.status().cycle_thread;
  // Root in a container may or may not be allowed SCHED_FIFO; either way the report says which.
  EXPECT_TRUE(report.starts_with("SCHED_FIFO 10: applied; ") ||
              report.starts_with("SCHED_FIFO 10: refused ("))
      << report;
  EXPECT_TRUE(report.ends_with("CPU 0: pinned")) << report;
  ASSERT_TRUE(master.stop());

  config.cycle_thread = {.fifo_priority = std::nullopt, .cpu = 100000};
  Master refused(config);
  ASSERT_TRUE(refused.start(link()));
  ASSERT_TRUE(refused.await_operational(10s));
  EXPECT_EQ(refused.status().cycle_thread, "CPU 100000: refused (Invalid argument)");
  ASSERT_TRUE(refused.stop());
}

TEST_F(MasterTest, SdoInformationAndEmergenciesThroughTheSlave) {
  Master master(full_config());
  ASSERT_TRUE(master.start(link()));
  ASSERT_TRUE(master.await_operational(10s));
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  auto objects = (*drive)->object_list();
  ASSERT_TRUE(objects) << objects.error().describe();
  EXPECT_NE(std::find(objects->begin(), objects->end(), 0x6040), objects->end());
  EXPECT_NE(std::find(objects->begin(), objects->end(), 0x1000), objects->end());
  auto controlword = (*drive)->describe_object(0x6040);
  ASSERT_TRUE(controlword) << controlword.error().describe();
  EXPECT_EQ(controlword->index, 0x6040);
  EXPECT_EQ(controlword->name, "Controlword");
  auto entry = (*drive)->describe_entry(0x6040, 0);
  ASSERT_TRUE(entry) << entry.error().describe();
  EXPECT_EQ(entry->bit_length, 16);
  auto coupler = master.slave("coupler");
  ASSERT_TRUE(coupler);
  auto none = (*coupler)->object_list();
  ASSERT_FALSE(none);
  EXPECT_EQ(none.error().code(), Errc::unsupported) << none.error().describe();
  auto no_emergencies = (*coupler)->emergencies();
  ASSERT_TRUE(no_emergencies);
  EXPECT_TRUE(no_emergencies->empty());

  // A following error in cyclic synchronous position mode: the drive faults and sends an
  // emergency (0x8611) that the slave hands over.
  ASSERT_TRUE((*drive)->download_sdo(0x6065, 0, {10, 0, 0, 0}));  // following error window
  ASSERT_TRUE((*drive)->download_sdo(0x6066, 0, {0, 0}));         // ... and time-out
  ASSERT_TRUE((*drive)->command("set_mode", {{"mode", Value(std::string("csp"))}}));
  for (const char* step : {"shutdown", "switch_on", "enable_operation"}) {
    ASSERT_TRUE((*drive)->command(step)) << step;
    std::this_thread::sleep_for(20ms);
  }
  ASSERT_TRUE((*drive)->write_output("target_position", Value(std::int64_t{1'000'000})));
  std::vector<wire::Emergency> got;
  for (int i = 0; i < 200 && got.empty(); ++i) {
    auto e = (*drive)->emergencies();
    ASSERT_TRUE(e) << e.error().describe();
    got.insert(got.end(), e->begin(), e->end());
    if (got.empty()) std::this_thread::sleep_for(10ms);
  }
  ASSERT_FALSE(got.empty()) << "no emergency from the faulted drive";
  EXPECT_EQ(got.back().error_code, 0x8611);
  ASSERT_TRUE(master.stop());
}

// A mailbox device given a bootstrap mailbox in its SII: request(BOOTSTRAP) walks PREOP -> INIT ->
// BOOT, and back up again; the same device without one refuses with AL status 0x0013.
TEST(MasterBootstrap, RequestWalksThroughInitToBootstrapAndBack) {
  const auto file = edited_eeprom("mailbox", "bootstrap", [](wire::SiiImage& image) {
    image.bootstrap_mailbox = image.standard_mailbox;
  });
  ASSERT_FALSE(file.empty());
  // The "mailbox" profile has a bootstrap mailbox of its own (FoE): the plain one is edited out.
  const auto plain_file = edited_eeprom(
      "mailbox", "no-bootstrap", [](wire::SiiImage& image) { image.bootstrap_mailbox = {}; });
  ASSERT_FALSE(plain_file.empty());
  auto server = test::make_sim_server(fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
    - {{name: loader, profile: eeprom, file: "{}"}}
    - {{name: plain, profile: eeprom, file: "{}"}}
)",
                                                  file.string(), plain_file.string()));
  std::filesystem::remove(file);
  std::filesystem::remove(plain_file);
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  auto config = fast_config();
  config.domains.clear();
  Master master(config);
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_running(10s));
  auto loader = master.slave("slave_1");
  ASSERT_TRUE(loader);
  auto boot = (*loader)->request(wire::AlState::bootstrap);
  ASSERT_TRUE(boot) << boot.error().describe();
  EXPECT_EQ((*loader)->state(), SlaveState::bootstrap);
  server->with_segment([](sim::Segment& segment, auto&) {
    EXPECT_EQ(segment.esc(1).al_state(), wire::AlState::bootstrap);
  });
  // SDOs need the standard mailbox: refused by name in BOOTSTRAP.
  auto sdo = (*loader)->upload_sdo(0x1000, 0);
  ASSERT_FALSE(sdo);
  EXPECT_EQ(sdo.error().code(), Errc::wrong_state);
  auto back = (*loader)->request(wire::AlState::preop);
  ASSERT_TRUE(back) << back.error().describe();
  EXPECT_EQ((*loader)->state(), SlaveState::preop);
  EXPECT_TRUE((*loader)->upload_sdo(0x1000, 0));

  auto plain = master.slave("slave_2");  // the same device without a bootstrap mailbox
  ASSERT_TRUE(plain);
  auto refused = (*plain)->request(wire::AlState::bootstrap);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::al_error) << refused.error().describe();
  EXPECT_EQ(al_status_code(refused.error()), 0x0013) << refused.error().describe();
  EXPECT_EQ(master.status().illegal_transitions, 0u);
  ASSERT_TRUE(master.stop());
}

// A ring made of the real Beckhoff EEPROM images (shared data): the master reads their SII, builds
// their process data from it and runs them in OP.
TEST(MasterRealEeproms, RingFromBeckhoffImagesReachesOperational) {
  ECAT_SHARED_DATA_OR_SKIP(ek1100, "eeprom/ek1100.bin");
  ECAT_SHARED_DATA_OR_SKIP(el2004, "eeprom/el2004.bin");
  ECAT_SHARED_DATA_OR_SKIP(el2828, "eeprom/el2828.bin");
  auto server =
      test::make_sim_server(fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: eeprom, file: "{}"}}
    - {{name: out4, profile: eeprom, file: "{}"}}
    - {{name: out8, profile: eeprom, file: "{}"}}
)",
                                        ek1100.string(), el2004.string(), el2828.string()));
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  auto config = fast_config();
  config.slaves = {slave("coupler", {}), slave("out4"), slave("out8")};
  Master master(config);
  ASSERT_TRUE(master.start(std::move(*link)));
  auto op = master.await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe() << "\n" << explain(master);
  auto out4 = master.slave("out4");
  ASSERT_TRUE(out4);
  const auto info = (*out4)->info();
  ASSERT_TRUE(info.identity);
  EXPECT_EQ(info.identity->vendor_id, 2u);
  EXPECT_EQ(info.identity->product_code, 0x07d43052u);  // EL2004
  EXPECT_EQ(info.device_name.substr(0, 6), "EL2004");
  ASSERT_GE(info.signals.size(), 4u);
  ASSERT_TRUE((*out4)->write_output(info.signals[0].name, Value(true)));
  // Two output terminals, written by the LRW: 2 each.
  EXPECT_EQ(master.domains().at(0).expected_wkc, 4);
  bool healthy = false;
  for (int i = 0; i < 500 && !healthy; ++i) {
    const auto d = master.domains().at(0);
    healthy = d.healthy && d.cycles > 10;
    if (!healthy) std::this_thread::sleep_for(2ms);
  }
  EXPECT_TRUE(healthy);
  ASSERT_TRUE(master.stop());
}

// A slave configured by its station alias is found wherever it sits; a missing or duplicated
// alias is named.
TEST(MasterAliases, SlaveFoundByStationAliasWhereverItSits) {
  const auto file =
      edited_eeprom("EL2809", "alias", [](wire::SiiImage& image) { image.station_alias = 0x0042; });
  ASSERT_FALSE(file.empty());
  // The aliased EL2809 sits at position 2 in one ring and at position 1 in the other.
  for (const bool first_ring : {true, false}) {
    auto server = test::make_sim_server(
        fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
{}    - {{name: aliased, profile: eeprom, file: "{}"}}
)",
                    first_ring ? "    - {name: other, profile: EL1809}\n" : "", file.string()));
    ASSERT_TRUE(server);
    auto link = server->serve_memory();
    ASSERT_TRUE(link);
    auto config = fast_config();
    SlaveConfig out = slave("out");
    out.alias = 0x0042;
    config.slaves = {slave("coupler", {}), out};
    Master master(config);
    ASSERT_TRUE(master.start(std::move(*link)));
    auto op = master.await_operational(10s);
    ASSERT_TRUE(op) << op.error().describe();
    auto found = master.slave("out");
    ASSERT_TRUE(found);
    EXPECT_EQ((*found)->position(), first_ring ? 2 : 1);
    EXPECT_EQ((*found)->info().identity->product_code, 0x0af93052u);
    ASSERT_TRUE(master.stop());
  }
  // No slave holds alias 0x0043: startup names it.
  auto server = test::make_sim_server(fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
    - {{name: aliased, profile: eeprom, file: "{}"}}
)",
                                                  file.string()));
  std::filesystem::remove(file);
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  auto config = fast_config();
  SlaveConfig missing = slave("missing");
  missing.alias = 0x0043;
  config.slaves = {slave("coupler", {}), missing};
  Master master(config);
  ASSERT_TRUE(master.start(std::move(*link)));
  auto running = master.await_running(10s);
  ASSERT_FALSE(running);
  EXPECT_NE(running.error().describe().find("no slave in the ring has station alias 0x0043"),
            std::string::npos)
      << running.error().describe();
}

}  // namespace
}  // namespace ecat::master

namespace ecat::master {
namespace {

// A ring that cannot all get to OP (its terminals overflow the domain's registrations) stays
// activation_blocked, naming the slaves left behind, through its retries: `operational` means
// every activatable slave is at its target, never "most of them".
TEST(MasterActivation, ARingThatOverflowsItsDomainStaysBlockedAndNamesTheSlaves) {
  std::string ring = "version: 1\nsimulator:\n  slaves:\n    - {name: coupler, profile: EK1100}\n";
  auto config = fast_config();
  config.slaves.push_back(slave("coupler", {}));
  for (int i = 0; i < 200; ++i) {
    const auto name = fmt::format("t{}", i);
    ring +=
        fmt::format("    - {{name: {}, profile: {}}}\n", name, i % 2 == 0 ? "EL1809" : "EL2809");
    config.slaves.push_back(slave(name));
  }
  // Domains size themselves to their registrations; a limit set by hand can still leave slaves
  // out (each terminal here registers one or two SyncManagers).
  config.domains[0].max_registrations = 128;
  auto server = test::make_sim_server(ring);
  ASSERT_TRUE(server);
  // The simulator answers inside the bus's send: 200 slaves under a sanitizer must not lose
  // frames to a starved simulator thread (this test is about registrations, not timing).
  std::unique_ptr<link::Link> link = server->function_link();
  config.retry_interval = 20ms;
  Master master(config);
  std::atomic<bool> operational{false};
  master.on_state_change([&](MasterState, MasterState to) {
    if (to == MasterState::operational) operational = true;
  });
  ASSERT_TRUE(master.start(std::move(link)));
  const auto deadline = std::chrono::steady_clock::now() + 3s;
  while (std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(10ms);
  EXPECT_FALSE(operational.load()) << explain(master);
  // Blocked; or recovering, when a transient domain fault came on top (a loaded machine), which
  // the seed's diagram does not leave for activation_blocked while the failures remain.
  EXPECT_TRUE(master.state() == MasterState::activation_blocked ||
              master.state() == MasterState::recovering)
      << explain(master);
  const auto status = master.status();
  ASSERT_FALSE(status.activation_failures.empty());
  std::size_t below_op = 0;
  for (const auto& s : status.slaves)
    below_op += s.state != SlaveState::op ? 1 : 0;
  EXPECT_EQ(status.activation_failures.size(), below_op) << "every slave left behind is named";
  // First "all registrations used", on the retries "the domain is cycling" (it cannot take them
  // any more): either way the failure says why.
  const auto why = status.activation_failures.front().error.describe();
  EXPECT_TRUE(why.find("registrations") != std::string::npos ||
              why.find("not_open") != std::string::npos)
      << why;
  // A slave left behind has none of its SyncManagers in the domain (all or none: a half-registered
  // slave would leave the domain expecting a working counter that cannot come).
  auto domain = master.domain("main");
  ASSERT_TRUE(domain);
  const auto registrations = (*domain)->registrations();
  for (const auto& f : status.activation_failures) {
    const auto station = (*master.slave(f.slave))->station();
    for (const auto& r : registrations)
      EXPECT_NE(r.key.slave, station) << f.slave;
  }
  ASSERT_TRUE(master.stop());
}

}  // namespace
}  // namespace ecat::master
