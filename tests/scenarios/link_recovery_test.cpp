// The link itself failing under a running session (issue #13, "a fatal subsystem exit"): the bus
// reopens it with a bounded backoff and the session heals without a restart; a link that stays
// down (or cannot be reopened) ends the session in idle with a last_failure saying why. Driven
// with an in-process link that fails on command, and with a real interface taken down and up
// inside a network namespace.
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "scenarios/scenario_support.hpp"
#include "support/pullable_link.hpp"

namespace ecat::scenarios {
namespace {

// Every event's stable name (and detail), in order.
class EventLog {
 public:
  explicit EventLog(master::Master& m) : master_(m) {
    id_ = master_.subscribe_events([this](const master::Event& e, std::uint64_t) {
      std::lock_guard lock(mutex_);
      std::string line(master::to_string(e.kind));
      if (e.kind == master::EventKind::master_state)
        line += fmt::format(" {}->{}", e.from_name(), e.to_name());
      lines_.push_back(line);
      if (!e.detail().empty()) details_.push_back(line + ": " + std::string(e.detail()));
    });
  }
  ~EventLog() { master_.unsubscribe_events(id_); }
  EventLog(const EventLog&) = delete;
  EventLog& operator=(const EventLog&) = delete;

  bool saw(const std::string& line) const {
    std::lock_guard lock(mutex_);
    return std::find(lines_.begin(), lines_.end(), line) != lines_.end();
  }
  std::string dump() const {
    std::lock_guard lock(mutex_);
    std::string out;
    for (const auto& l : details_)
      out += l + "\n";
    return out;
  }

 private:
  master::Master& master_;
  master::EventSubscriptionId id_ = 0;
  mutable std::mutex mutex_;
  std::vector<std::string> lines_;
  std::vector<std::string> details_;
};

RingSpec pullable_spec(std::shared_ptr<test::PullableLink::Cable> cable) {
  RingSpec spec;
  spec.wrap_link = [cable](std::unique_ptr<link::Link> inner) -> std::unique_ptr<link::Link> {
    return std::make_unique<test::PullableLink>(std::move(inner), cable);
  };
  return spec;
}

void expect_back_in_op(ScenarioRing& ring) {
  ASSERT_TRUE(ring.master->await_operational(10s)) << ring.describe();
  EXPECT_TRUE(eventually([&] {
    return ring.all_slaves_in(SlaveState::op) && ring.master->status().runtime_faults.empty();
  })) << ring.describe();
  EXPECT_TRUE(ring.loopback(true)) << ring.describe();
  EXPECT_TRUE(ring.loopback(false)) << ring.describe();
}

TEST(LinkRecovery, ACablePulledAndPluggedBackHealsTheSessionWithoutARestart) {
  auto cable = std::make_shared<test::PullableLink::Cable>();
  auto ring = ScenarioRing::operational(pullable_spec(cable));
  ASSERT_TRUE(ring);
  EventLog events(*ring->master);
  ring->forget_states();
  cable->pulled = true;
  ASSERT_TRUE(eventually([&] { return events.saw("link.down"); })) << events.dump();
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }))
      << ring->describe();
  // Reopened with a backoff while the cable is out (each attempt fails).
  ASSERT_TRUE(eventually([&] { return cable->reopens.load() >= 3; }));
  EXPECT_FALSE(events.saw("link.reopened"));
  const auto down = ring->master->status();
  EXPECT_FALSE(down.runtime_faults.empty());

  cable->pulled = false;
  ASSERT_TRUE(eventually([&] { return events.saw("link.reopened"); })) << events.dump();
  expect_back_in_op(*ring);
  // The same session: never idle, never discovering again.
  EXPECT_FALSE(ring->saw(MasterState::idle));
  EXPECT_FALSE(ring->saw(MasterState::discovering));
  ASSERT_TRUE(ring->master->flush_events());  // the stream may trail the state
  EXPECT_TRUE(events.saw("master.state operational->recovering")) << events.dump();
  EXPECT_TRUE(events.saw("master.state recovering->operational")) << events.dump();
  EXPECT_FALSE(ring->master->last_failure().has_value());
}

TEST(LinkRecovery, ALinkThatStaysDownEndsTheSessionInIdleWithLastFailure) {
  auto cable = std::make_shared<test::PullableLink::Cable>();
  auto spec = pullable_spec(cable);
  spec.adjust = [](master::MasterConfig& c) { c.link_recovery_window = 500ms; };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  EventLog events(*ring->master);
  cable->pulled = true;
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::idle; }, 10s))
      << ring->describe();
  const auto failure = ring->master->last_failure();
  ASSERT_TRUE(failure.has_value());
  EXPECT_EQ(failure->kind, "link_lost");
  const std::string why = failure->error.describe();
  EXPECT_NE(why.find("did not come back within 500 ms"), std::string::npos) << why;
  EXPECT_NE(why.find("no carrier"), std::string::npos) << why;  // the link's own error
  // The event stream is delivered by its own thread: it may trail the state.
  EXPECT_TRUE(eventually([&] { return events.saw("master.state recovering->idle"); }))
      << events.dump();
  // A caller waiting for the session learns why it ended.
  auto waited = ring->master->await_operational(100ms);
  ASSERT_FALSE(waited);
  EXPECT_NE(waited.error().describe().find("did not come back"), std::string::npos)
      << waited.error().describe();
  // Stopping it now is the seed's :already_stopped, not an error.
  auto stopped = ring->master->stop();
  ASSERT_TRUE(stopped);
  EXPECT_EQ(*stopped, master::StopOutcome::already_stopped);
}

TEST(LinkRecovery, ALinkThatCannotBeReopenedEndsTheSessionAtOnce) {
  auto cable = std::make_shared<test::PullableLink::Cable>();
  cable->reopenable = false;
  auto spec = pullable_spec(cable);
  spec.adjust = [](master::MasterConfig& c) { c.link_recovery_window = 60s; };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  cable->pulled = true;
  // Long before the 60 s window: the link said it cannot come back.
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::idle; }, 10s))
      << ring->describe();
  const auto failure = ring->master->last_failure();
  ASSERT_TRUE(failure.has_value());
  EXPECT_EQ(failure->kind, "link_lost");
  EXPECT_NE(failure->error.describe().find("cannot be reopened"), std::string::npos)
      << failure->error.describe();
  EXPECT_EQ(cable->reopens.load(), 1);
}

TEST(LinkRecovery, AFailureDuringStartupAlsoEndsInIdle) {
  auto cable = std::make_shared<test::PullableLink::Cable>();
  cable->pulled = true;  // no carrier from the start
  auto spec = pullable_spec(cable);
  spec.adjust = [](master::MasterConfig& c) { c.link_recovery_window = 300ms; };
  auto ring = ScenarioRing::create(spec);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::idle; }, 10s))
      << ring->describe();
  const auto failure = ring->master->last_failure();
  ASSERT_TRUE(failure.has_value());
  EXPECT_NE(failure->error.describe().find("no carrier"), std::string::npos)
      << failure->error.describe();
}

// ---- a real interface, down and up, inside a network namespace ----------------------------------

bool ip(const std::string& args) {
  return std::system(("ip " + args + " >/dev/null 2>&1").c_str()) == 0;
}

TEST(LinkRecovery, AnInterfaceTakenDownAndUpAgainHealsTheSession) {
  RingSpec spec;
  spec.transport = Transport::raw;
  std::string skip;
  auto ring = ScenarioRing::operational(spec, &skip);
  if (!ring && !skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  EventLog events(*ring->master);
  ring->forget_states();
  ASSERT_TRUE(ip("link set dev master down"));
  ASSERT_TRUE(eventually([&] { return events.saw("link.down"); })) << events.dump();
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }))
      << ring->describe();
  std::this_thread::sleep_for(200ms);  // a few reopen attempts fail: the interface is down
  EXPECT_FALSE(events.saw("link.reopened"));
  ASSERT_TRUE(ip("link set dev master up"));
  ASSERT_TRUE(eventually([&] { return events.saw("link.reopened"); }, 10s)) << events.dump();
  expect_back_in_op(*ring);
  EXPECT_FALSE(ring->saw(MasterState::idle));
  EXPECT_TRUE(ring->master->status().runtime_faults.empty()) << ring->describe();
}

TEST(LinkRecovery, AnInterfaceThatStaysDownEndsTheSession) {
  RingSpec spec;
  spec.transport = Transport::raw;
  spec.adjust = [](master::MasterConfig& c) { c.link_recovery_window = 500ms; };
  std::string skip;
  auto ring = ScenarioRing::operational(spec, &skip);
  if (!ring && !skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ip("link set dev master down"));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::idle; }, 10s))
      << ring->describe();
  const auto failure = ring->master->last_failure();
  ASSERT_TRUE(failure.has_value());
  EXPECT_EQ(failure->kind, "link_lost");
  EXPECT_NE(failure->error.describe().find("is down"), std::string::npos)
      << failure->error.describe();
}

}  // namespace
}  // namespace ecat::scenarios
