// The domain's lifecycle against the seed's diagram (../shared/seeds/domain.md): every edge of
// domain_transitions() is driven in a master session by the trigger that causes it (activation
// starts cycling, deactivate(preop) stops it, consecutive transport misses reach the miss
// threshold, recovery restarts a stopped domain) and observed in the event stream; and the
// domain's cycle health, runtime data rather than a state, is observed the same way: lost frames
// and an expired realtime exchange (the bus could not send it within its staleness budget) are
// both `timeout`, and a valid cycle makes it healthy again. The coverage check fails for an edge
// of the table no scenario took (domain.cpp gained an edge: it needs a trigger here).
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/server.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using D = DomainState;
using T = DomainTrigger;
namespace fault = sim::fault;

// One row per edge and trigger; `how` is what the test does.
struct DomainRow {
  DomainState from;
  DomainState to;
  DomainTrigger trigger;
  std::string_view how;
};
constexpr DomainRow kRows[] = {
    {D::open, D::cycling, T::start_cycling, "the master's first activation (startup to OP)"},
    {D::cycling, D::stopped, T::stop_cycling, "Master::deactivate(preop)"},
    {D::stopped, D::cycling, T::start_cycling,
     "Master::activate() after deactivate(preop); the master's recovery after the miss "
     "threshold"},
    {D::cycling, D::stopped, T::miss_threshold,
     "drop_responses until miss_threshold (5) consecutive misses"},
};

// Cycle health, observed as domain.health events: (healthy?, reason when not).
enum class Health : std::uint8_t { timeout_lost_frames, timeout_expired_exchange, healthy_again };
constexpr std::pair<Health, std::string_view> kHealthRows[] = {
    {Health::timeout_lost_frames, "drop_responses: no reply within the frame timeout -> timeout"},
    {Health::timeout_expired_exchange,
     "delay_replies 100 ms with 16 exchanges in flight: the bus's 8 realtime frame slots are "
     "taken, later exchanges expire unsent -> timeout (the bus counts them as expired)"},
    {Health::healthy_again, "the fault cleared: the next valid cycle -> healthy"},
};

using Key = std::tuple<DomainState, DomainState, DomainTrigger>;
struct Coverage {
  std::mutex mutex;
  std::set<Key> edges;
  std::set<Health> health;
};
Coverage& coverage() {
  static Coverage c;
  return c;
}

// The trigger of a domain.state event, from what the master says in its detail: the miss
// threshold names the misses ("after 5 consecutive misses (timeout)").
DomainTrigger trigger_of(const Event& e) {
  if (e.to == static_cast<std::uint8_t>(D::cycling)) return T::start_cycling;
  return e.detail().rfind("after ", 0) == 0 ? T::miss_threshold : T::stop_cycling;
}

constexpr const char* kRing = test::kTerminalRing;

MasterConfig config(std::uint32_t miss_threshold = 1000) {
  MasterConfig c = test::quick_config(2ms);
  c.domains.front().miss_threshold = miss_threshold;
  return c;
}

class Session {
 public:
  explicit Session(MasterConfig c) {
    server = test::make_sim_server(kRing);
    if (!server) return;
    auto link = server->serve_memory();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return;
    }
    master = std::make_unique<Master>(std::move(c));
    subscription_ = master->subscribe_events([this](const Event& e, std::uint64_t) {
      std::lock_guard lock(mutex_);
      events_.push_back(e);
      cv_.notify_all();
    });
    auto started = master->start(std::move(*link));
    EXPECT_TRUE(started) << started.error().describe();
  }
  ~Session() { finish(); }
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  bool ok() const { return master != nullptr; }
  std::size_t mark() {
    std::lock_guard lock(mutex_);
    return events_.size();
  }
  template <class Predicate>
  bool wait_after(std::size_t since, Predicate predicate, std::chrono::nanoseconds limit = 15s) {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, limit, [&] {
      return std::any_of(events_.begin() + static_cast<std::ptrdiff_t>(since), events_.end(),
                         predicate);
    });
  }
  // A domain.state `from -> to` caused by `trigger`, after `since`.
  bool observe(std::size_t since, DomainState from, DomainState to, DomainTrigger trigger) {
    const bool seen = wait_after(since, [&](const Event& e) {
      return e.kind == EventKind::domain_state && e.from == static_cast<std::uint8_t>(from) &&
             e.to == static_cast<std::uint8_t>(to) && trigger_of(e) == trigger;
    });
    EXPECT_TRUE(seen) << "not observed: " << to_string(from) << " -> " << to_string(to) << " by "
                      << to_string(trigger) << "\n"
                      << dump();
    return seen;
  }
  // A domain.health event after `since`: invalid with `reason`, or healthy (nullopt).
  bool observe_health(std::size_t since, std::optional<InvalidReason> reason, Health row) {
    const bool seen = wait_after(since, [&](const Event& e) {
      if (e.kind != EventKind::domain_health) return false;
      if (!reason) return e.to == 1;
      return e.to == 0 && e.value == static_cast<std::uint64_t>(*reason);
    });
    EXPECT_TRUE(seen) << "no domain.health "
                      << (reason ? std::string(to_string(*reason)) : "healthy") << "\n"
                      << dump();
    if (seen) {
      std::lock_guard lock(coverage().mutex);
      coverage().health.insert(row);
    }
    return seen;
  }
  bool reach(MasterState wanted) {
    const auto deadline = std::chrono::steady_clock::now() + 15s;
    while (master->state() != wanted && std::chrono::steady_clock::now() < deadline) {
      std::unique_lock lock(mutex_);
      cv_.wait_for(lock, 5ms);
    }
    EXPECT_EQ(master->state(), wanted) << dump();
    return master->state() == wanted;
  }
  DomainStats stats() { return (*master->domain("main"))->stats(); }
  std::string dump() {
    std::lock_guard lock(mutex_);
    std::string out;
    for (const auto& e : events_) {
      if (e.kind == EventKind::master_state || e.kind == EventKind::domain_state ||
          e.kind == EventKind::domain_health) {
        out += "  " + describe(e) + "\n";
      }
    }
    return out;
  }
  void finish() {
    if (!master || finished_) return;
    finished_ = true;
    const auto status = master->status();
    EXPECT_EQ(status.illegal_transitions, 0u) << dump();
    EXPECT_EQ(status.illegal_slave_transitions, 0u) << dump();
    EXPECT_EQ(status.illegal_domain_transitions, 0u) << dump();
    EXPECT_TRUE(master->stop());
    EXPECT_TRUE(master->flush_events());
    master->unsubscribe_events(subscription_);
    std::lock_guard lock(mutex_);
    std::lock_guard cover(coverage().mutex);
    for (const auto& e : events_) {
      if (e.kind != EventKind::domain_state) continue;
      coverage().edges.insert(
          {static_cast<DomainState>(e.from), static_cast<DomainState>(e.to), trigger_of(e)});
    }
  }

  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Event> events_;
  EventSubscriptionId subscription_ = 0;
  bool finished_ = false;
};

// Activation opens the exchange, deactivate(preop) stops it, activate() starts it again.
void api_starts_and_stops_cycling() {
  Session s(config());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.observe(0, D::open, D::cycling, T::start_cycling));
  ASSERT_TRUE(s.reach(MasterState::operational));
  auto m = s.mark();
  ASSERT_TRUE(s.master->deactivate(TargetState::preop));
  ASSERT_TRUE(s.observe(m, D::cycling, D::stopped, T::stop_cycling));
  EXPECT_EQ(s.stats().state, D::stopped);
  m = s.mark();
  ASSERT_TRUE(s.master->activate());
  ASSERT_TRUE(s.observe(m, D::stopped, D::cycling, T::start_cycling));
  EXPECT_EQ(s.stats().state, D::cycling);
}

// No replies: every cycle a timeout; the health says so at recovery_threshold and the domain
// stops at miss_threshold; with the replies back, the master's recovery restarts it and the next
// valid cycle is healthy.
void lost_frames_reach_the_miss_threshold() {
  Session s(config(5));
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.reach(MasterState::operational));
  auto m = s.mark();
  ASSERT_TRUE(s.server->inject(fault::drop_responses()));
  ASSERT_TRUE(s.observe_health(m, InvalidReason::timeout, Health::timeout_lost_frames));
  ASSERT_TRUE(s.observe(m, D::cycling, D::stopped, T::miss_threshold));
  EXPECT_GE(s.stats().total_miss_count, 5u);  // time-outs, or overruns behind them
  m = s.mark();
  s.server->clear_faults();
  ASSERT_TRUE(s.observe(m, D::stopped, D::cycling, T::start_cycling));
  ASSERT_TRUE(s.observe_health(m, std::nullopt, Health::healthy_again));
  ASSERT_TRUE(s.reach(MasterState::operational));
}

// An exchange the bus cannot send within its staleness budget expires unsent; the domain reports
// the cycle as `timeout` all the same (the seed: timeout-class misses stay `timeout` in domain
// health; the finer expiry shows in the bus's and the domain's counters).
void an_expired_exchange_is_timeout_health() {
  auto c = config();
  c.frame_timeout = 1s;                   // the delayed replies come back, never time out
  c.domains[0].exchanges_in_flight = 16;  // more exchanges than the bus's 8 realtime slots
  Session s(c);
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.reach(MasterState::operational));
  const auto before = s.stats();
  const auto m = s.mark();
  ASSERT_TRUE(s.server->inject(fault::delay_replies(100ms)));
  ASSERT_TRUE(s.observe_health(m, InvalidReason::timeout, Health::timeout_expired_exchange));
  s.server->clear_faults();
  const auto after = s.stats();
  EXPECT_GT(after.expired_count, before.expired_count);
  EXPECT_EQ(after.timeout_count, before.timeout_count) << "a frame timed out: not only expiry";
  ASSERT_TRUE(after.last_invalid.has_value());
  EXPECT_EQ(after.last_invalid->reason, InvalidReason::timeout);
  EXPECT_GT(s.master->counters().realtime_expired, 0u);
}

TEST(DomainEdges, EveryDrawnEdgeIsTakenByItsTriggerAndHealthIsReported) {
  const std::pair<const char*, void (*)()> scenarios[] = {
      {"api_starts_and_stops_cycling", &api_starts_and_stops_cycling},
      {"lost_frames_reach_the_miss_threshold", &lost_frames_reach_the_miss_threshold},
      {"an_expired_exchange_is_timeout_health", &an_expired_exchange_is_timeout_health},
  };
  for (const auto& [name, run] : scenarios) {
    SCOPED_TRACE(name);
    run();
  }
  std::lock_guard lock(coverage().mutex);
  std::set<Key> drawn;
  for (const auto& t : domain_transitions())
    drawn.insert({t.from, t.to, t.trigger});
  std::set<Key> in_table;
  for (const auto& r : kRows)
    in_table.insert({r.from, r.to, r.trigger});
  EXPECT_EQ(in_table, drawn)
      << "kRows must hold every edge of domain_transitions(), and only those";
  for (const auto& t : domain_transitions()) {
    EXPECT_TRUE(coverage().edges.count({t.from, t.to, t.trigger}) != 0)
        << "never observed: " << to_string(t.from) << " -> " << to_string(t.to) << " by "
        << to_string(t.trigger) << " (" << t.label << ")";
  }
  EXPECT_EQ(coverage().edges, drawn);
  for (const auto& [row, how] : kHealthRows) {
    EXPECT_TRUE(coverage().health.count(row) != 0) << "health never observed: " << how;
  }
}

}  // namespace
}  // namespace ecat::master
