// The master's startup steps and AL transitions against the simulator, and the state tables.
#include <chrono>
#include <memory>
#include <set>
#include <string>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/startup.hpp>
#include <ecat/master/states.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using wire::AlState;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: rtd, profile: EL3202}
)";

class StartupTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
    auto link = server_->serve_memory();
    ASSERT_TRUE(link) << link.error().describe();
    bus_ = std::make_unique<bus::Bus>(std::move(*link));
    ASSERT_TRUE(bus_->start());
    loop_.start_thread("test-control");
  }
  void TearDown() override {
    loop_.stop();
    loop_.join();
    if (bus_) bus_->stop();
  }
  template <class T>
  T run(exec::Task<T> task) {
    auto result = exec::run_blocking(loop_, std::move(task), 10s);
    EXPECT_TRUE(result.has_value()) << "task did not finish";
    return std::move(*result);
  }

  std::unique_ptr<sim::SimServer> server_;
  std::unique_ptr<bus::Bus> bus_;
  exec::EventLoop loop_;
};

TEST_F(StartupTest, CountsAssignsResetsAndReachesInit) {
  auto count = run(await_stable_count(loop_, *bus_, {.poll = 2ms, .stable = 10ms, .timeout = 2s}));
  ASSERT_TRUE(count) << count.error().describe();
  EXPECT_EQ(*count, 4);
  auto assigned = run(assign_stations(loop_, *bus_, 4, 0x1000));
  ASSERT_TRUE(assigned) << assigned.error().describe();
  auto dl = run(read_dl_status(loop_, *bus_, 4, 0x1000));
  ASSERT_TRUE(dl) << dl.error().describe();
  ASSERT_EQ(dl->size(), 4u);
  // The first slave's port 0 faces the master and its port 1 the next slave.
  EXPECT_TRUE((*dl)[0].ports[0].physical_link);
  EXPECT_TRUE((*dl)[0].ports[1].communication);
  // The last slave's port 1 is open: the ESC closes the loop there.
  EXPECT_FALSE((*dl)[3].ports[1].communication);
  auto reset = run(reset_slaves(loop_, *bus_, 4));
  ASSERT_TRUE(reset) << reset.error().describe();
  // A reset block that expects more slaves than answer names the write.
  auto short_reset = run(reset_slaves(loop_, *bus_, 5));
  ASSERT_FALSE(short_reset);
  EXPECT_NE(short_reset.error().message().find("reached 4 of 5"), std::string::npos)
      << short_reset.error().message();
  auto init = run(init_all(loop_, *bus_, 4, 0x1000));
  ASSERT_TRUE(init) << init.error().describe();
  for (std::uint16_t s = 0x1000; s < 0x1004; ++s) {
    auto status = run(read_al_status(loop_, *bus_, s));
    ASSERT_TRUE(status);
    EXPECT_EQ(status->status.state, AlState::init);
  }
}

// The scan's early end: a whole ring (every port with a link leads to a counted slave) is known
// stable at the second poll, long before a 10 s window; without the link check, or when a link
// leads to a device the count does not hold, the window is waited out (here: the timeout first).
TEST_F(StartupTest, LinkPictureEndsTheScanEarlyOnlyWhenTheLinksAddUp) {
  auto picture = run(read_link_picture(loop_, *bus_, 4));
  ASSERT_TRUE(picture) << picture.error().describe();
  ASSERT_TRUE(picture->has_value());
  EXPECT_TRUE((*picture)->complete);
  ASSERT_EQ((*picture)->ports.size(), 4u);
  // Slaves 0-2 carry the next one on port 1 (link, communication, open); the last has none.
  EXPECT_EQ((*picture)->ports[0], (1u << 1) | (1u << 5) | (1u << 10) | (1u << 11));
  EXPECT_EQ((*picture)->ports[3], (1u << 9) | (1u << 10) | (1u << 11));
  // A count that claims a slave less: one link too many.
  auto short_picture = run(read_link_picture(loop_, *bus_, 3));
  ASSERT_TRUE(short_picture);
  ASSERT_TRUE(short_picture->has_value());
  EXPECT_FALSE((*short_picture)->complete);
  // More than answer: no picture.
  auto long_picture = run(read_link_picture(loop_, *bus_, 5));
  ASSERT_TRUE(long_picture);
  EXPECT_FALSE(long_picture->has_value());

  auto early = run(await_stable_count(
      loop_, *bus_, {.poll = 2ms, .stable = 10s, .link_check = true, .timeout = 2s}));
  ASSERT_TRUE(early) << early.error().describe();
  EXPECT_EQ(*early, 4);
  auto windowed = run(await_stable_count(
      loop_, *bus_, {.poll = 2ms, .stable = 10s, .link_check = false, .timeout = 200ms}));
  ASSERT_FALSE(windowed);
  EXPECT_EQ(windowed.error().code(), Errc::timeout);
  // The last slave cut off behind a live link (a device still coming up): the coupler count says
  // 3, the links say 4.
  ASSERT_TRUE(server_->inject(sim::fault::disconnect("rtd")));
  auto cut = run(await_stable_count(
      loop_, *bus_, {.poll = 2ms, .stable = 10s, .link_check = true, .timeout = 200ms}));
  ASSERT_FALSE(cut);
  EXPECT_EQ(cut.error().code(), Errc::timeout);
  EXPECT_NE(cut.error().message().find("last count 3"), std::string::npos) << cut.error().message();
}

// On a redundant ring the last slave's port 1 is cabled back to the master's second port: that
// link leads to no slave, and the scan still ends early (it used to wait out the window).
// Behind a break position addressing counts from the first slave the secondary's frame
// processes; a whole ring (or the secondary's cable cut) is all on the primary's side, the
// primary's cable cut all on the secondary's.
TEST(RedundantStartup, RingPositionsRouteToThePortWhoseFrameReachesThem) {
  using link::Port;
  const RingSides broken_after_two{2, 5};
  EXPECT_EQ(route_position(broken_after_two, 0), (PositionRoute{Port::primary, 0}));
  EXPECT_EQ(route_position(broken_after_two, 1), (PositionRoute{Port::primary, 1}));
  EXPECT_EQ(route_position(broken_after_two, 2), (PositionRoute{Port::secondary, 0}));
  EXPECT_EQ(route_position(broken_after_two, 4), (PositionRoute{Port::secondary, 2}));
  EXPECT_EQ(route_position(RingSides{5, 5}, 4), (PositionRoute{Port::primary, 4}));
  EXPECT_EQ(route_position(RingSides{0, 5}, 0), (PositionRoute{Port::secondary, 0}));
  EXPECT_EQ(route_position(RingSides{0, 5}, 4), (PositionRoute{Port::secondary, 4}));
}

// kRing on a redundant link cabled as `cabling`: the link picture read at start-up (complete
// expected) and a scan with a 10 s window, which must end early at 4 slaves.
std::optional<LinkPicture> picture_and_early_scan(const sim::RedundantTopology& cabling) {
  SCOPED_TRACE(sim::describe(cabling));
  auto server = test::make_sim_server(kRing);
  EXPECT_TRUE(server);
  if (!server) return std::nullopt;
  auto [ports, link] = test::open_redundant_link(*server);
  EXPECT_TRUE(ports && link);
  if (!ports || !link) return std::nullopt;
  EXPECT_TRUE(ports->set_topology(cabling));
  bus::Bus bus(std::move(link));
  EXPECT_TRUE(bus.start());
  exec::EventLoop loop;
  loop.start_thread("test-control");
  std::optional<LinkPicture> out;
  auto picture = exec::run_blocking(loop, read_link_picture(loop, bus, 4), 10s);
  EXPECT_TRUE(picture.has_value());
  if (picture && *picture && picture->value()) {
    out = *picture->value();
    EXPECT_TRUE(out->complete);
  } else {
    ADD_FAILURE() << "no link picture"
                  << (picture && !*picture ? ": " + picture->error().describe() : "");
  }
  auto early = exec::run_blocking(
      loop,
      await_stable_count(loop, bus,
                         {.poll = 2ms, .stable = 10s, .link_check = true, .timeout = 2s}),
      10s);
  EXPECT_TRUE(early.has_value());
  if (early) {
    EXPECT_TRUE(*early) << early->error().describe();
    if (*early) {
      EXPECT_EQ(**early, 4);
    }
  }
  loop.stop();
  loop.join();
  bus.stop();
  return out;
}

TEST(RedundantStartup, TheCableBackToTheSecondPortIsNoMissingSlave) {
  const auto picture = picture_and_early_scan(sim::RedundantTopology::whole_ring());
  ASSERT_TRUE(picture);
  EXPECT_NE(picture->ports[3] & (1u << 1), 0u);  // the cable back: link on port 1
}

// A ring already broken when the scan runs: each position is read through the port whose frame
// reaches it (both ports' copies would otherwise answer a position, or the wrong slave), and the
// break's missing link is allowed for, so the scan still ends early instead of waiting out the
// window. A cut master cable leaves a plain line on one side.
TEST(RedundantStartup, ABrokenRingGivesAWholeLinkPictureAndTheScanEndsEarly) {
  using sim::RedundantTopology;
  for (const auto& cabling :
       {RedundantTopology::broken_after(1), RedundantTopology::broken_after(2),
        RedundantTopology::broken_after(3), RedundantTopology::cut_at(wire::RedundantPort::primary),
        RedundantTopology::cut_at(wire::RedundantPort::secondary)}) {
    EXPECT_TRUE(picture_and_early_scan(cabling)) << sim::describe(cabling);
  }
}

TEST_F(StartupTest, WrongCountsAndStationRangesAreNamed) {
  EXPECT_FALSE(check_addressing(3, 0));
  auto overflow = check_addressing(3, 0xFFFE);
  ASSERT_FALSE(overflow);
  EXPECT_NE(overflow.error().message().find("0xfffe"), std::string::npos);
  EXPECT_TRUE(check_addressing(2, 0xFFFE));
  // Assigning more slaves than exist: the APWR to position 4 is not taken.
  auto assigned = run(assign_stations(loop_, *bus_, 5, 0x1000));
  ASSERT_FALSE(assigned);
  EXPECT_EQ(assigned.error().code(), Errc::wkc_mismatch);
  EXPECT_NE(assigned.error().message().find("position 4"), std::string::npos);
}

TEST_F(StartupTest, AlRequestWalksThePathAndReportsRefusals) {
  ASSERT_TRUE(run(assign_stations(loop_, *bus_, 4, 0x1000)));
  ASSERT_TRUE(run(init_all(loop_, *bus_, 4, 0x1000)));
  // The coupler has no process data: it reaches OP through PREOP and SAFEOP.
  auto op = run(al_request(loop_, *bus_, 0x1000, AlState::op));
  ASSERT_TRUE(op) << op.error().describe();
  EXPECT_EQ(*op, AlState::op);
  auto back = run(al_request(loop_, *bus_, 0x1000, AlState::init));
  ASSERT_TRUE(back) << back.error().describe();
  // The EL3202 (firmware, mailbox) without its mailbox SyncManagers configured refuses PREOP
  // with "invalid mailbox configuration" (0x0016). (The EL1809 would not: like the real
  // terminal it is a device-emulation ESC that takes any state.)
  auto refused = run(al_request(loop_, *bus_, 0x1003, AlState::safeop));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::al_error);
  auto code = al_status_code(refused.error());
  ASSERT_TRUE(code.has_value()) << refused.error().describe();
  EXPECT_EQ(*code, wire::al_status::kInvalidMailboxConfigurationPreop)
      << refused.error().describe();
  EXPECT_NE(refused.error().describe().find("0x1003"), std::string::npos);
  // The error was acknowledged: the slave sits in INIT without the error flag.
  auto status = run(read_al_status(loop_, *bus_, 0x1003));
  ASSERT_TRUE(status);
  EXPECT_EQ(status->status.state, AlState::init);
  EXPECT_FALSE(status->status.error);
  // A station nobody has: the write is not taken.
  auto gone = run(al_request(loop_, *bus_, 0x2000, AlState::preop));
  ASSERT_FALSE(gone);
}

TEST(AlPath, MatchesTheReferenceTable) {
  EXPECT_EQ(al_path(AlState::init, AlState::op),
            (std::vector<AlState>{AlState::preop, AlState::safeop, AlState::op}));
  EXPECT_EQ(al_path(AlState::op, AlState::init),
            (std::vector<AlState>{AlState::safeop, AlState::preop, AlState::init}));
  EXPECT_EQ(al_path(AlState::op, AlState::preop),
            (std::vector<AlState>{AlState::safeop, AlState::preop}));
  EXPECT_EQ(al_path(AlState::safeop, AlState::safeop), std::vector<AlState>{});
  // BOOT is entered from INIT and left to INIT only: other ways walk through INIT.
  EXPECT_EQ(al_path(AlState::preop, AlState::bootstrap),
            (std::vector<AlState>{AlState::init, AlState::bootstrap}));
  EXPECT_EQ(
      al_path(AlState::op, AlState::bootstrap),
      (std::vector<AlState>{AlState::safeop, AlState::preop, AlState::init, AlState::bootstrap}));
  EXPECT_EQ(al_path(AlState::bootstrap, AlState::op),
            (std::vector<AlState>{AlState::init, AlState::preop, AlState::safeop, AlState::op}));
  // Every pair of the five states has a path, and no path jumps BOOT <-> anything but INIT.
  EXPECT_EQ(al_path_table().size(), 20u);
  for (const auto& row : al_path_table()) {
    AlState at = row.from;
    for (AlState step : row.steps) {
      if (at == AlState::bootstrap || step == AlState::bootstrap) {
        EXPECT_TRUE(at == AlState::init || step == AlState::init)
            << wire::to_string(at) << " -> " << wire::to_string(step);
      }
      at = step;
    }
    EXPECT_EQ(at, row.to);
  }
}

TEST(StateTables, MasterTableIsTheSeedDiagram) {
  EXPECT_EQ(master_transitions().size(), 29u);
  EXPECT_TRUE(master_transition_allowed(MasterState::idle, MasterState::discovering));
  EXPECT_TRUE(master_transition_allowed(MasterState::recovering, MasterState::deactivated));
  EXPECT_FALSE(master_transition_allowed(MasterState::idle, MasterState::operational));
  EXPECT_FALSE(master_transition_allowed(MasterState::discovering, MasterState::operational));
  EXPECT_FALSE(
      master_transition_allowed(MasterState::operational, MasterState::activation_blocked));
  // Every state but idle can be left to idle (stop), and idle is reachable from all of them.
  for (auto t : master_transitions())
    EXPECT_NE(t.trigger, "");
  for (int s = 1; s < 8; ++s) {
    EXPECT_TRUE(master_transition_allowed(static_cast<MasterState>(s), MasterState::idle))
        << to_string(static_cast<MasterState>(s));
    EXPECT_EQ(master_state_from_string(to_string(static_cast<MasterState>(s))),
              static_cast<MasterState>(s));
  }
}

TEST(StateTables, SlaveTableIsTheSeedDiagram) {
  EXPECT_EQ(slave_transitions().size(), 22u);
  EXPECT_TRUE(slave_transition_allowed(SlaveState::op, SlaveState::down));
  EXPECT_TRUE(slave_transition_allowed(SlaveState::down, SlaveState::preop));
  EXPECT_FALSE(slave_transition_allowed(SlaveState::down, SlaveState::op));
  EXPECT_FALSE(slave_transition_allowed(SlaveState::init, SlaveState::down));
  EXPECT_FALSE(slave_transition_allowed(SlaveState::bootstrap, SlaveState::preop));
}

}  // namespace
}  // namespace ecat::master
