// Bad input from API callers, class by class (issue 6 "Bad input"; ring files: config_test.cpp):
// each is an error value with a code and a message naming what was wrong, never a crash.
#include <chrono>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: drive, profile: servo}
)";

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
    config_.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
    config_.dc.reset();
    DomainConfig main;
    main.id = "main";
    config_.domains.push_back(main);
    for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
      SlaveConfig s;
      s.name = name;
      if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
      config_.slaves.push_back(s);
    }
  }
  void start() {
    auto link = server_->serve_memory();
    ASSERT_TRUE(link);
    master_ = std::make_unique<Master>(config_);
    ASSERT_TRUE(master_->start(std::move(*link)));
    ASSERT_TRUE(master_->await_operational(10s));
  }
  void TearDown() override {
    if (master_) (void)master_->stop();
  }
  static void expect(const Error& e, Errc code, const std::string& names) {
    EXPECT_EQ(e.code(), code) << e.describe();
    EXPECT_NE(e.describe().find(names), std::string::npos) << e.describe();
  }
  std::unique_ptr<sim::SimServer> server_;
  MasterConfig config_;
  std::unique_ptr<Master> master_;
};

TEST_F(BadInput, CallsInTheWrongState) {
  Master idle(config_);
  EXPECT_EQ(idle.stop().value(), StopOutcome::already_stopped);  // not an error (the seed's)
  expect(idle.activate().error(), Errc::wrong_state, "while idle");
  expect(idle.slave("inputs").error(), Errc::wrong_state, "not started");
  ASSERT_NO_FATAL_FAILURE(start());
  auto second = test::make_sim_server(kRing);
  ASSERT_TRUE(second);
  auto link = second->serve_memory();
  ASSERT_TRUE(link);
  expect(master_->start(std::move(*link)).error(), Errc::wrong_state, "already started");
  expect(master_->start(nullptr).error(), Errc::invalid_argument, "no link given");
  auto outputs = master_->slave("outputs");
  ASSERT_TRUE(outputs);
  // Reconfiguration is a PREOP business.
  auto configure = (*outputs)->configure(config_.slaves[2]);
  ASSERT_FALSE(configure);
  expect(configure.error(), Errc::wrong_state, "outputs");
}

TEST_F(BadInput, UnknownSlaveSignalDomainAndCommandNames) {
  ASSERT_NO_FATAL_FAILURE(start());
  expect(master_->slave("nobody").error(), Errc::not_found, "nobody");
  expect(master_->domain("nowhere").error(), Errc::not_found, "nowhere");
  expect(master_->update_domain_cycle_time("nowhere", 2ms).error(), Errc::not_found, "nowhere");
  auto inputs = master_->slave("inputs");
  ASSERT_TRUE(inputs);
  expect((*inputs)->read_input("channel_99").error(), Errc::not_found, "channel_99");
  expect((*inputs)->write_output("channel_1", Value(true)).error(), Errc::invalid_argument,
         "is an input");
  expect((*inputs)->command("explode").error(), Errc::not_found, "explode");
  expect((*inputs)->subscribe("channel_99", [](const SignalEvent&) {}).error(), Errc::not_found,
         "channel_99");
}

TEST_F(BadInput, OutOfRangeValues) {
  ASSERT_NO_FATAL_FAILURE(start());
  auto drive = master_->slave("drive");
  ASSERT_TRUE(drive);
  // target_velocity is a 32-bit signed PDO entry.
  auto big = (*drive)->write_output("target_velocity", Value(std::int64_t{1} << 40));
  ASSERT_FALSE(big);
  expect(big.error(), Errc::out_of_range, "target_velocity");
  auto text = (*drive)->write_output("target_velocity", Value(std::string("fast")));
  ASSERT_FALSE(text);
  EXPECT_NE(text.error().describe().find("target_velocity"), std::string::npos);
  auto outputs = master_->slave("outputs");
  ASSERT_TRUE(outputs);
  auto mask = (*outputs)->command("set_channels", {{"mask", Value(std::uint64_t{0x1FFFF})}});
  ASSERT_FALSE(mask);
  EXPECT_NE(mask.error().describe().find("mask must be 0..0xffff"), std::string::npos);
  expect(master_->update_domain_cycle_time("main", 1us).error(), Errc::invalid_argument, "main");
}

TEST_F(BadInput, SdoRequestsToSlavesWithoutAMailbox) {
  ASSERT_NO_FATAL_FAILURE(start());
  auto coupler = master_->slave("coupler");
  ASSERT_TRUE(coupler);
  expect((*coupler)->upload_sdo(0x1000, 0).error(), Errc::unsupported, "coupler");
  expect((*coupler)->download_sdo(0x1000, 0, {1}).error(), Errc::unsupported, "coupler");
  expect((*coupler)->object_list().error(), Errc::unsupported, "coupler");
  auto drive = master_->slave("drive");
  ASSERT_TRUE(drive);
  expect((*drive)->download_sdo(0x6040, 0, {}).error(), Errc::invalid_argument, "no data");
}

}  // namespace
}  // namespace ecat::master
