// ecat::open_master (a master started from a ring file), Domain::await_next_cycle and
// master::SignalHandle's control-side errors, against examples/default.yaml's simulated ring.
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>

#include <ecat/ecat.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat {
namespace {

using namespace std::chrono_literals;

const std::string kDefaultRing = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";

std::string write_temp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("ecat_open_master_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path.string();
}

TEST(OpenMaster, StartsTheFilesOwnSimulatedRingAndReachesOp) {
  auto master = open_master(kDefaultRing);
  ASSERT_TRUE(master) << master.error().describe();
  ASSERT_TRUE((*master)->await_operational(20s));
  EXPECT_GT((*master)->slaves().size(), 0u);
  EXPECT_TRUE((*master)->stop());
}

TEST(OpenMaster, MissingFileIsNamed) {
  auto master = open_master("/nonexistent/ring.yaml");
  ASSERT_FALSE(master);
  EXPECT_NE(master.error().describe().find("/nonexistent/ring.yaml"), std::string::npos)
      << master.error().describe();
}

TEST(OpenMaster, FileWithoutBackendOrSimulatorIsRefusedNamingIt) {
  const auto path = write_temp("nobackend.yaml", "version: 1\ndomains:\n  - {id: main}\n");
  auto master = open_master(path);
  ASSERT_FALSE(master);
  const auto text = master.error().describe();
  EXPECT_NE(text.find(path), std::string::npos) << text;
  EXPECT_NE(text.find("backend"), std::string::npos) << text;
  std::filesystem::remove(path);
}

TEST(OpenMaster, BadBackendIsNamed) {
  auto master = open_master(kDefaultRing, {.backend = "carrier-pigeon:1"});
  ASSERT_FALSE(master);
  const auto text = master.error().describe();
  EXPECT_NE(text.find("carrier-pigeon:1"), std::string::npos) << text;
  EXPECT_NE(text.find(kDefaultRing), std::string::npos) << text;
}

TEST(OpenMaster, ConfigureHookRunsBeforeStart) {
  bool called = false;
  auto master = open_master(kDefaultRing, {.configure = [&](master::MasterConfig& config) {
                              called = true;
                              for (auto& d : config.domains)
                                d.period = 2ms;
                            }});
  ASSERT_TRUE(master) << master.error().describe();
  EXPECT_TRUE(called);
  ASSERT_TRUE((*master)->await_operational(20s));
  for (const auto& d : (*master)->domains())
    EXPECT_EQ(d.period, 2ms) << d.id;
}

TEST(AwaitNextCycle, ReturnsAFreshValidCycleAndRefusesOnTheBusThread) {
  std::atomic<bool> refused_in_callback{false};
  std::atomic<bool> tried{false};
  auto master =
      open_master(kDefaultRing, {.configure = [&](master::MasterConfig& config) {
                    for (auto& d : config.domains) {
                      d.on_cycle = [&](master::Domain& domain, const master::CycleOutcome&) {
                        if (tried.exchange(true)) return;
                        auto r = domain.await_next_cycle(1ms);
                        refused_in_callback = !r && r.error().code() == Errc::wrong_state;
                      };
                    }
                  }});
  ASSERT_TRUE(master) << master.error().describe();
  ASSERT_TRUE((*master)->await_operational(20s));
  auto domain = (*master)->domain("main");
  ASSERT_TRUE(domain);
  const auto before = (*domain)->stats().valid_count;
  auto first = (*domain)->await_next_cycle(2s);
  ASSERT_TRUE(first) << first.error().describe();
  EXPECT_TRUE(first->valid);
  auto second = (*domain)->await_next_cycle(2s);
  ASSERT_TRUE(second) << second.error().describe();
  EXPECT_GT(second->cycle, first->cycle);
  EXPECT_GT((*domain)->stats().valid_count, before);
  EXPECT_TRUE(tried.load());
  EXPECT_TRUE(refused_in_callback.load());

  ASSERT_TRUE((*master)->stop());
}

TEST(SignalHandle, ResolutionErrorsNameTheSlaveAndSignal) {
  auto master = open_master(kDefaultRing);
  ASSERT_TRUE(master) << master.error().describe();
  ASSERT_TRUE((*master)->await_operational(20s));

  auto no_slave = (*master)->signal_handle("nobody", "channel_1");
  ASSERT_FALSE(no_slave);
  EXPECT_NE(no_slave.error().describe().find("nobody"), std::string::npos);

  auto no_signal = (*master)->signal_handle("inputs", "channel_99");
  ASSERT_FALSE(no_signal);
  EXPECT_EQ(no_signal.error().code(), Errc::not_found);
  EXPECT_NE(no_signal.error().describe().find("channel_99"), std::string::npos);
  EXPECT_NE(no_signal.error().describe().find("channel_1"), std::string::npos);  // what it has

  auto input = (*master)->signal_handle("inputs", "channel_1");
  ASSERT_TRUE(input) << input.error().describe();
  auto write_input = input->write(master::Value(true));
  ASSERT_FALSE(write_input);
  EXPECT_EQ(write_input.error().code(), Errc::invalid_argument);

  auto output = (*master)->signal_handle("outputs", "channel_1");
  ASSERT_TRUE(output) << output.error().describe();
  auto wrong_value = output->write(master::Value(std::uint64_t{7}));
  ASSERT_FALSE(wrong_value);
  EXPECT_NE(wrong_value.error().describe().find("channel_1"), std::string::npos)
      << wrong_value.error().describe();

  master::SignalHandle unbound;
  EXPECT_FALSE(unbound.bound());
  EXPECT_FALSE(unbound.read());

  // An output written through the handle comes back on the wired input.
  auto domain = (*master)->domain("main");
  ASSERT_TRUE(domain);
  for (const bool level : {true, false}) {
    ASSERT_TRUE(output->write(master::Value(level)));
    bool seen = false;
    for (int i = 0; i < 2000 && !seen; ++i) {
      ASSERT_TRUE((*domain)->await_next_cycle(1s));
      auto v = input->read();
      seen = v && master::as_bool(*v) == level;
    }
    EXPECT_TRUE(seen) << "level " << level;
    auto staged = output->read();
    ASSERT_TRUE(staged) << staged.error().describe();
    EXPECT_EQ(master::as_bool(*staged), level);
  }
  ASSERT_TRUE((*master)->stop());
}

}  // namespace
}  // namespace ecat
