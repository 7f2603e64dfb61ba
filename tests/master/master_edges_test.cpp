// The master's lifecycle against the seed's diagram (../shared/seeds/master.md "Recovery model"):
// ONE table, kRows, holds every drawn edge with the trigger the seed names for it; the scenarios
// below bring a master to the row's `from`, apply its trigger (an API call, a fault injected into
// the simulator, a timeout) and observe `from -> to` in the event stream after the trigger, with
// no undrawn change ever asked for (the refused-transition counts stay 0). The coverage check at
// the end fails for a row no scenario observed and for a drawn edge without a row (states.cpp
// gained an edge: it needs a row and a trigger here), and requires the edges seen in the stream to
// be exactly the drawn set.
//
// The fatal subsystem exits are driven by the link itself failing (tests/support/pullable_link.hpp:
// the master's end of the link with a cable that can be pulled, and that cannot be reopened).
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/master/states.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>

#include "master/master_test_support.hpp"
#include "support/pullable_link.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using M = MasterState;
using Edge = std::pair<MasterState, MasterState>;
namespace fault = sim::fault;

// ---- the table --------------------------------------------------------------------------------

enum class Row : std::uint8_t {
  start,
  discovery_done,
  startup_fails,
  stop_discovering,
  all_preop_no_activation,
  startup_activation_succeeds,
  startup_activation_refused,
  awaiting_preop_timeout,
  awaiting_preop_fatal,
  stop_awaiting_preop,
  preop_activate,
  preop_activate_refused,
  preop_runtime_fault,
  preop_stop,
  preop_fatal,
  deactivated_activate,
  deactivated_to_preop,
  deactivated_target_refused,
  deactivated_runtime_fault,
  deactivated_stop,
  deactivated_fatal,
  operational_runtime_fault,
  operational_deactivate_safeop,
  operational_deactivate_preop,
  operational_stop,
  operational_fatal,
  blocked_cleared_op,
  blocked_cleared_safeop,
  blocked_cleared_preop,
  blocked_runtime_fault,
  blocked_stop,
  blocked_fatal,
  recovering_cleared_op,
  recovering_cleared_safeop,
  recovering_cleared_preop,
  recovering_stop,
  recovering_fails,
};

struct EdgeRow {
  Row row;
  MasterState from;
  MasterState to;
  std::string_view seed;     // the trigger as the seed's diagram names it
  std::string_view trigger;  // what the test does
};

constexpr EdgeRow kRows[] = {
    {Row::start, M::idle, M::discovering, "start/1", "Master::start(link)"},
    {Row::discovery_done, M::discovering, M::awaiting_preop, "configured slaves are still pending",
     "the ring is counted and the stations assigned"},
    {Row::startup_fails, M::discovering, M::idle, "startup fails",
     "4 slaves configured on a 3-slave ring"},
    {Row::stop_discovering, M::discovering, M::idle, "stop/0",
     "Master::stop() while the slave count is still settling (scan.stable 3 s)"},
    {Row::all_preop_no_activation, M::awaiting_preop, M::preop_ready,
     "all slaves reached PREOP, no activation requested", "every slave configured target PREOP"},
    {Row::startup_activation_succeeds, M::awaiting_preop, M::operational,
     "all slaves reached PREOP and activation succeeds", "every slave reaches OP"},
    {Row::startup_activation_refused, M::awaiting_preop, M::activation_blocked,
     "activation is incomplete", "fault refuse_state(outputs, SAFEOP) before start"},
    {Row::awaiting_preop_timeout, M::awaiting_preop, M::idle, "timeout",
     "outputs configured with a product code the ring lacks; awaiting_preop_timeout 500 ms"},
    {Row::awaiting_preop_fatal, M::awaiting_preop, M::idle, "fatal startup failure",
     "the link fails and cannot be reopened while a slave is retried towards PREOP"},
    {Row::stop_awaiting_preop, M::awaiting_preop, M::idle, "stop/0",
     "Master::stop() while a slave is retried towards PREOP"},
    {Row::preop_activate, M::preop_ready, M::operational, "activate/0 succeeds",
     "Master::activate() after deactivate(preop)"},
    {Row::preop_activate_refused, M::preop_ready, M::activation_blocked, "activate/0 is incomplete",
     "Master::activate() with refuse_state(outputs, SAFEOP)"},
    {Row::preop_runtime_fault, M::preop_ready, M::recovering, "critical runtime fault",
     "disconnect outputs (it carries process data) for 100 exchanges"},
    {Row::preop_stop, M::preop_ready, M::idle, "stop/0", "Master::stop()"},
    {Row::preop_fatal, M::preop_ready, M::idle, "fatal subsystem exit",
     "the link fails and cannot be reopened (a fatal subsystem exit)"},
    {Row::deactivated_activate, M::deactivated, M::operational, "activate/0 succeeds",
     "Master::activate()"},
    {Row::deactivated_to_preop, M::deactivated, M::preop_ready, "deactivate to PREOP",
     "Master::deactivate(preop)"},
    {Row::deactivated_target_refused, M::deactivated, M::activation_blocked,
     "target transition remains incomplete",
     "Master::activate() with refuse_state(outputs, OP); Master::deactivate(preop) with "
     "refuse_state(outputs, PREOP)"},
    {Row::deactivated_runtime_fault, M::deactivated, M::recovering, "critical runtime fault",
     "disconnect outputs for 100 exchanges"},
    {Row::deactivated_stop, M::deactivated, M::idle, "stop/0", "Master::stop()"},
    {Row::deactivated_fatal, M::deactivated, M::idle, "fatal subsystem exit",
     "the link fails and cannot be reopened (a fatal subsystem exit)"},
    {Row::operational_runtime_fault, M::operational, M::recovering, "critical runtime fault",
     "disconnect outputs for 100 exchanges"},
    {Row::operational_deactivate_safeop, M::operational, M::deactivated,
     "deactivate/0 settles in SAFEOP", "Master::deactivate(safeop)"},
    {Row::operational_deactivate_preop, M::operational, M::preop_ready, "deactivate to PREOP",
     "Master::deactivate(preop)"},
    {Row::operational_stop, M::operational, M::idle, "stop/0", "Master::stop()"},
    {Row::operational_fatal, M::operational, M::idle, "fatal subsystem exit",
     "the link fails and cannot be reopened (a fatal subsystem exit)"},
    {Row::blocked_cleared_op, M::activation_blocked, M::operational,
     "activation failures clear and target is OP", "the refusal is lifted (clear_faults)"},
    {Row::blocked_cleared_safeop, M::activation_blocked, M::deactivated,
     "transition failures clear and target is SAFEOP",
     "every slave targets SAFEOP; the refusal is lifted"},
    {Row::blocked_cleared_preop, M::activation_blocked, M::preop_ready,
     "transition failures clear and target is PREOP",
     "deactivate(preop) blocked by refuse_state(outputs, PREOP); the refusal is lifted"},
    {Row::blocked_runtime_fault, M::activation_blocked, M::recovering,
     "runtime faults remain after activation retry",
     "blocked (outputs refuses SAFEOP), then inputs (process data) disconnected"},
    {Row::blocked_stop, M::activation_blocked, M::idle, "stop/0", "Master::stop()"},
    {Row::blocked_fatal, M::activation_blocked, M::idle, "fatal subsystem exit",
     "the link fails and cannot be reopened (a fatal subsystem exit)"},
    {Row::recovering_cleared_op, M::recovering, M::operational,
     "critical runtime faults are cleared and target is OP",
     "the disconnected slave answers again and is rebuilt"},
    {Row::recovering_cleared_safeop, M::recovering, M::deactivated,
     "critical runtime faults are cleared and target is SAFEOP",
     "as above, after deactivate(safeop)"},
    {Row::recovering_cleared_preop, M::recovering, M::preop_ready,
     "critical runtime faults are cleared and target is PREOP",
     "as above, after deactivate(preop)"},
    {Row::recovering_stop, M::recovering, M::idle, "stop/0",
     "Master::stop() while outputs stays disconnected"},
    {Row::recovering_fails, M::recovering, M::idle, "recovery fails",
     "the link stays down past link_recovery_window while recovering (last_failure link_lost)"},
};

const EdgeRow& row_of(Row row) {
  for (const auto& r : kRows) {
    if (r.row == row) return r;
  }
  ADD_FAILURE() << "no row " << static_cast<int>(row);
  return kRows[0];
}

std::string name_of(const EdgeRow& r) {
  return fmt::format("{} -> {} ({}: {})", to_string(r.from), to_string(r.to), r.seed, r.trigger);
}

// What the scenarios saw: rows confirmed by their driver, and every master.state edge of the
// stream.
struct Coverage {
  std::mutex mutex;
  std::set<Row> rows;
  std::set<Edge> edges;
};
Coverage& coverage() {
  static Coverage c;
  return c;
}

// ---- a session --------------------------------------------------------------------------------

constexpr const char* kRing = test::kTerminalRing;

// AL status 0x001D: invalid output configuration (what the refusing slave answers).
constexpr std::uint16_t kRefusal = 0x001D;

SlaveConfig slave(std::string name, bool process_data, TargetState target = TargetState::op) {
  return test::quick_slave(std::move(name), process_data, target);
}

MasterConfig base_config(TargetState target = TargetState::op) {
  return test::quick_config(2ms, target);
}

class Session {
 public:
  // Serves the ring, applies `before_start` faults, starts the master (does not wait).
  // With a `cable`, the master's end of the link can be pulled (ecat::test::PullableLink).
  Session(MasterConfig config, const std::vector<sim::Fault>& before_start = {},
          std::shared_ptr<ecat::test::PullableLink::Cable> cable = nullptr) {
    server = test::make_sim_server(kRing);
    if (!server) return;
    for (const auto& f : before_start) {
      auto injected = server->inject(f);
      EXPECT_TRUE(injected) << injected.error().describe();
    }
    auto link = server->serve_memory();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return;
    }
    if (cable) *link = std::make_unique<ecat::test::PullableLink>(std::move(*link), cable);
    master = std::make_unique<Master>(std::move(config));
    subscription_ = master->subscribe_events([this](const Event& e, std::uint64_t missed) {
      std::lock_guard lock(mutex_);
      missed_ += missed;
      events_.push_back(e);
      cv_.notify_all();
    });
    auto started = master->start(std::move(*link));
    EXPECT_TRUE(started) << started.error().describe();
  }
  ~Session() { finish(); }
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  bool ok() const { return master != nullptr && server != nullptr; }

  // Events seen so far: what a trigger applied now must come after.
  std::size_t mark() {
    std::lock_guard lock(mutex_);
    return events_.size();
  }

  // Waits for `row`'s edge in the stream after `since`; records the row as observed.
  bool observe(Row which, std::size_t since, std::chrono::nanoseconds limit = 15s) {
    const EdgeRow& r = row_of(which);
    const bool seen = wait_after(since, limit, [&](const Event& e) {
      return e.kind == EventKind::master_state && e.from == static_cast<std::uint8_t>(r.from) &&
             e.to == static_cast<std::uint8_t>(r.to);
    });
    EXPECT_TRUE(seen) << "not observed: " << name_of(r) << "\nmaster " << to_string(state()) << "\n"
                      << dump();
    if (seen) {
      std::lock_guard lock(coverage().mutex);
      coverage().rows.insert(which);
    }
    return seen;
  }

  // Waits until the master is in `state` (a precondition, not a row).
  bool reach(MasterState wanted, std::chrono::nanoseconds limit = 15s) {
    const bool reached = wait_after(0, limit,
                                    [&](const Event& e) {
                                      return e.kind == EventKind::master_state &&
                                             e.to == static_cast<std::uint8_t>(wanted);
                                    }) &&
                         state() == wanted;
    EXPECT_TRUE(reached) << "never " << to_string(wanted) << " (now " << to_string(state()) << ")\n"
                         << dump();
    return reached;
  }
  // Waits until a slave is in `wanted` (the slave's own table is slave_lifecycle_test's).
  bool slave_in(std::string_view name, SlaveState wanted, std::chrono::nanoseconds limit = 15s) {
    const auto deadline = std::chrono::steady_clock::now() + limit;
    for (;;) {
      auto s = master->slave(name);
      if (s && (*s)->state() == wanted) return true;
      if (std::chrono::steady_clock::now() >= deadline) break;
      std::unique_lock lock(mutex_);
      cv_.wait_for(lock, 5ms);
    }
    ADD_FAILURE() << name << " never " << to_string(wanted) << "\n" << dump();
    return false;
  }

  MasterState state() const { return master->state(); }

  void inject(const sim::Fault& f) {
    auto injected = server->inject(f);
    EXPECT_TRUE(injected) << sim::describe(f) << ": " << injected.error().describe();
  }

  std::string dump() {
    std::lock_guard lock(mutex_);
    std::string out;
    for (const auto& e : events_) {
      if (e.kind == EventKind::master_state || e.kind == EventKind::slave_state ||
          e.kind == EventKind::activation_failed || e.kind == EventKind::fault_raised ||
          e.kind == EventKind::fault_cleared || e.kind == EventKind::domain_state) {
        out += "  " + describe(e) + "\n";
      }
    }
    return out;
  }

  // Stops the master (if it runs), checks nothing undrawn was asked for, and hands the stream's
  // master.state edges to the coverage.
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
    EXPECT_EQ(missed_, 0u);
    std::lock_guard cover(coverage().mutex);
    for (const auto& e : events_) {
      if (e.kind != EventKind::master_state) continue;
      const Edge edge{static_cast<MasterState>(e.from), static_cast<MasterState>(e.to)};
      EXPECT_TRUE(master_transition_allowed(edge.first, edge.second))
          << "undrawn " << to_string(edge.first) << " -> " << to_string(edge.second);
      coverage().edges.insert(edge);
    }
  }

  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;

 private:
  template <class Predicate>
  bool wait_after(std::size_t since, std::chrono::nanoseconds limit, Predicate predicate) {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, limit, [&] {
      return std::any_of(events_.begin() + static_cast<std::ptrdiff_t>(since), events_.end(),
                         predicate);
    });
  }

  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Event> events_;
  std::uint64_t missed_ = 0;
  EventSubscriptionId subscription_ = 0;
  bool finished_ = false;
};

// ---- scenarios ----------------------------------------------------------------------------------

// Startup to OP, then the API walks: deactivate / activate between every running state, stop.
void api_walk_through_the_running_states() {
  Session s(base_config());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.observe(Row::start, 0));
  ASSERT_TRUE(s.observe(Row::discovery_done, 0));
  ASSERT_TRUE(s.observe(Row::startup_activation_succeeds, 0));
  auto m = s.mark();
  ASSERT_TRUE(s.master->deactivate(TargetState::safeop));
  ASSERT_TRUE(s.observe(Row::operational_deactivate_safeop, m));
  m = s.mark();
  ASSERT_TRUE(s.master->activate());
  ASSERT_TRUE(s.observe(Row::deactivated_activate, m));
  m = s.mark();
  ASSERT_TRUE(s.master->deactivate(TargetState::preop));
  ASSERT_TRUE(s.observe(Row::operational_deactivate_preop, m));
  m = s.mark();
  ASSERT_TRUE(s.master->activate());
  ASSERT_TRUE(s.observe(Row::preop_activate, m));
  ASSERT_TRUE(s.master->deactivate(TargetState::safeop));
  ASSERT_TRUE(s.reach(M::deactivated));
  m = s.mark();
  ASSERT_TRUE(s.master->deactivate(TargetState::preop));
  ASSERT_TRUE(s.observe(Row::deactivated_to_preop, m));
  m = s.mark();
  ASSERT_TRUE(s.master->stop());
  ASSERT_TRUE(s.observe(Row::preop_stop, m));
}

// stop() from operational and from deactivated.
void stop_from_operational_and_deactivated() {
  {
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    const auto m = s.mark();
    ASSERT_TRUE(s.master->stop());
    ASSERT_TRUE(s.observe(Row::operational_stop, m));
  }
  {
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    ASSERT_TRUE(s.master->deactivate(TargetState::safeop));
    ASSERT_TRUE(s.reach(M::deactivated));
    const auto m = s.mark();
    ASSERT_TRUE(s.master->stop());
    ASSERT_TRUE(s.observe(Row::deactivated_stop, m));
  }
}

// Every slave held in PREOP: startup ends preop_ready without an activation.
void startup_without_activation() {
  Session s(base_config(TargetState::preop));
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.observe(Row::all_preop_no_activation, 0));
}

// Startup failures: a configuration the ring cannot satisfy, a slave that never reaches PREOP,
// and stop() in the middle of discovery and of awaiting_preop.
void startup_ends_in_idle() {
  {
    auto config = base_config();
    config.slaves.push_back(slave("missing", false));
    Session s(config);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.observe(Row::startup_fails, 0));
    EXPECT_TRUE(s.master->last_failure().has_value());
  }
  {
    auto config = base_config();
    config.awaiting_preop_timeout = 500ms;
    config.slaves[2].product_code = 0x0BADC0DE;  // never the device found: every attempt fails
    Session s(config);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.observe(Row::awaiting_preop_timeout, 0));
    const auto failure = s.master->last_failure();
    ASSERT_TRUE(failure.has_value());
    EXPECT_EQ(failure->kind, "awaiting_preop_failed");
  }
  {
    auto config = base_config();
    config.scan = {.poll = 2ms, .stable = 3s, .timeout = 10s};
    Session s(config);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::discovering));
    const auto m = s.mark();
    ASSERT_TRUE(s.master->stop());
    ASSERT_TRUE(s.observe(Row::stop_discovering, m));
  }
  {
    auto config = base_config();
    config.awaiting_preop_timeout = 60s;
    config.slaves[2].product_code = 0x0BADC0DE;
    Session s(config);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::awaiting_preop));
    const auto m = s.mark();
    ASSERT_TRUE(s.master->stop());
    ASSERT_TRUE(s.observe(Row::stop_awaiting_preop, m));
  }
}

// A slave that refuses SAFEOP from the start: activation is incomplete; lifting the refusal lets
// the retry finish at the target (OP, or SAFEOP when every slave targets SAFEOP); stop() while
// blocked.
void refused_activation_at_startup() {
  const auto refuse_safeop = fault::refuse_state("outputs", wire::AlState::safeop, kRefusal);
  {
    Session s(base_config(), {refuse_safeop});
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.observe(Row::startup_activation_refused, 0));
    const auto failures = s.master->status().activation_failures;
    ASSERT_FALSE(failures.empty()) << s.dump();
    EXPECT_EQ(failures.front().slave, "outputs");
    EXPECT_EQ(failures.front().al_status_code.value_or(0), kRefusal);
    const auto m = s.mark();
    s.server->clear_faults();
    ASSERT_TRUE(s.observe(Row::blocked_cleared_op, m));
  }
  {
    Session s(base_config(TargetState::safeop), {refuse_safeop});
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::activation_blocked));
    const auto m = s.mark();
    s.server->clear_faults();
    ASSERT_TRUE(s.observe(Row::blocked_cleared_safeop, m));
  }
  {
    Session s(base_config(), {refuse_safeop});
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::activation_blocked));
    const auto m = s.mark();
    ASSERT_TRUE(s.master->stop());
    ASSERT_TRUE(s.observe(Row::blocked_stop, m));
  }
}

// activate() from preop_ready with a slave refusing SAFEOP; while blocked, a slave with process
// data is lost (critical); once it is back and the refusal lifted, the session is operational.
void refused_activation_from_preop_then_runtime_fault() {
  Session s(base_config());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.reach(M::operational));
  ASSERT_TRUE(s.master->deactivate(TargetState::preop));
  ASSERT_TRUE(s.reach(M::preop_ready));
  s.inject(fault::refuse_state("outputs", wire::AlState::safeop, kRefusal));
  auto m = s.mark();
  EXPECT_FALSE(s.master->activate());  // blocked: the refusal is the answer
  ASSERT_TRUE(s.observe(Row::preop_activate_refused, m));
  m = s.mark();
  s.inject(fault::next(fault::disconnect("inputs"), 100));
  ASSERT_TRUE(s.observe(Row::blocked_runtime_fault, m));
  ASSERT_TRUE(s.slave_in("inputs", SlaveState::op));  // found again, rebuilt, sent back to OP
  m = s.mark();
  s.server->clear_faults();
  ASSERT_TRUE(s.observe(Row::recovering_cleared_op, m));
}

// From deactivated, the target cannot be reached: activate() with OP refused, deactivate(preop)
// with PREOP refused. Lifting the refusal ends at the target (operational, preop_ready).
void deactivated_target_refused() {
  {
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    ASSERT_TRUE(s.master->deactivate(TargetState::safeop));
    ASSERT_TRUE(s.reach(M::deactivated));
    s.inject(fault::refuse_state("outputs", wire::AlState::op, kRefusal));
    auto m = s.mark();
    EXPECT_FALSE(s.master->activate());
    ASSERT_TRUE(s.observe(Row::deactivated_target_refused, m));
    m = s.mark();
    s.server->clear_faults();
    ASSERT_TRUE(s.observe(Row::blocked_cleared_op, m));
  }
  {
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    ASSERT_TRUE(s.master->deactivate(TargetState::safeop));
    ASSERT_TRUE(s.reach(M::deactivated));
    s.inject(fault::refuse_state("outputs", wire::AlState::preop, kRefusal));
    auto m = s.mark();
    EXPECT_FALSE(s.master->deactivate(TargetState::preop));
    ASSERT_TRUE(s.observe(Row::deactivated_target_refused, m));
    m = s.mark();
    s.server->clear_faults();
    ASSERT_TRUE(s.observe(Row::blocked_cleared_preop, m));
  }
  {
    // Straight from operational, a deactivation a slave refuses: the session settles at the
    // level asked for, then is blocked there (operational -> activation_blocked is not drawn).
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    s.inject(fault::refuse_state("outputs", wire::AlState::safeop, kRefusal));
    auto m = s.mark();
    EXPECT_FALSE(s.master->deactivate(TargetState::safeop));
    ASSERT_TRUE(s.observe(Row::operational_deactivate_safeop, m));
    ASSERT_TRUE(s.observe(Row::deactivated_target_refused, m));
    const auto failures = s.master->status().activation_failures;
    ASSERT_EQ(failures.size(), 1u) << s.dump();
    EXPECT_EQ(failures.front().slave, "outputs");
    m = s.mark();
    s.server->clear_faults();
    ASSERT_TRUE(s.observe(Row::blocked_cleared_safeop, m));
  }
}

// A slave with process data is lost in operational, deactivated and preop_ready: recovering;
// found again and rebuilt: back to the state the target asks for.
void critical_runtime_faults_and_their_recovery() {
  struct Case {
    TargetState target;
    MasterState running;
    Row lost;
    Row back;
  };
  for (const auto& c : {Case{TargetState::op, M::operational, Row::operational_runtime_fault,
                             Row::recovering_cleared_op},
                        Case{TargetState::safeop, M::deactivated, Row::deactivated_runtime_fault,
                             Row::recovering_cleared_safeop},
                        Case{TargetState::preop, M::preop_ready, Row::preop_runtime_fault,
                             Row::recovering_cleared_preop}}) {
    SCOPED_TRACE(to_string(c.running));
    Session s(base_config());
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    if (c.target != TargetState::op) {
      ASSERT_TRUE(s.master->deactivate(c.target));
      ASSERT_TRUE(s.reach(c.running));
    }
    auto m = s.mark();
    s.inject(fault::next(fault::disconnect("outputs"), 100));
    ASSERT_TRUE(s.observe(c.lost, m));
    m = s.mark();
    ASSERT_TRUE(s.observe(c.back, m));
  }
}

// stop() while recovering (the lost slave never comes back).
void stop_while_recovering() {
  Session s(base_config());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s.reach(M::operational));
  s.inject(fault::disconnect("outputs"));
  ASSERT_TRUE(s.reach(M::recovering));
  const auto m = s.mark();
  ASSERT_TRUE(s.master->stop());
  ASSERT_TRUE(s.observe(Row::recovering_stop, m));
}

// Fatal subsystem exits: the link fails and cannot be reopened. From every state where the
// session runs, the master goes straight to idle with last_failure link_lost (before the loss
// could show as a runtime fault); the same link staying down past the recovery window while
// recovering is the recovery failing.
void fatal_subsystem_exits() {
  auto expect_link_lost = [](Session& s, std::string_view what) {
    const auto failure = s.master->last_failure();
    ASSERT_TRUE(failure.has_value()) << s.dump();
    EXPECT_EQ(failure->kind, "link_lost");
    EXPECT_NE(failure->error.describe().find(what), std::string::npos) << failure->error.describe();
  };
  struct Case {
    Row row;
    MasterState from;
    std::vector<sim::Fault> before_start;
    std::optional<TargetState> deactivate_to;
  };
  const auto refuse_safeop = fault::refuse_state("outputs", wire::AlState::safeop, kRefusal);
  for (const auto& c :
       {Case{Row::operational_fatal, M::operational, {}, std::nullopt},
        Case{Row::deactivated_fatal, M::deactivated, {}, TargetState::safeop},
        Case{Row::preop_fatal, M::preop_ready, {}, TargetState::preop},
        Case{Row::blocked_fatal, M::activation_blocked, {refuse_safeop}, std::nullopt}}) {
    SCOPED_TRACE(to_string(c.from));
    auto cable = std::make_shared<ecat::test::PullableLink::Cable>();
    cable->reopenable = false;
    Session s(base_config(), c.before_start, cable);
    ASSERT_TRUE(s.ok());
    if (c.deactivate_to) {
      ASSERT_TRUE(s.reach(M::operational));
      ASSERT_TRUE(s.master->deactivate(*c.deactivate_to));
    }
    ASSERT_TRUE(s.reach(c.from));
    const auto m = s.mark();
    cable->pulled = true;
    ASSERT_TRUE(s.observe(c.row, m));
    expect_link_lost(s, "cannot be reopened");
  }
  {
    auto config = base_config();
    config.awaiting_preop_timeout = 60s;
    config.slaves[2].product_code = 0x0BADC0DE;  // retried towards PREOP until the end
    auto cable = std::make_shared<ecat::test::PullableLink::Cable>();
    cable->reopenable = false;
    Session s(config, {}, cable);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::awaiting_preop));
    const auto m = s.mark();
    cable->pulled = true;
    ASSERT_TRUE(s.observe(Row::awaiting_preop_fatal, m));
    expect_link_lost(s, "cannot be reopened");
  }
  {
    auto config = base_config();
    config.link_recovery_window = 400ms;
    auto cable = std::make_shared<ecat::test::PullableLink::Cable>();
    Session s(config, {}, cable);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE(s.reach(M::operational));
    cable->pulled = true;  // reopened with a backoff, in vain
    ASSERT_TRUE(s.reach(M::recovering));
    const auto m = s.mark();
    ASSERT_TRUE(s.observe(Row::recovering_fails, m));
    expect_link_lost(s, "did not come back within 400 ms");
  }
}

// One test, so that the coverage check sees every scenario wherever the tests run (CTest runs
// each test in a process of its own).
TEST(MasterEdges, EveryDrawnEdgeIsTakenByItsTriggerAndNoOtherEver) {
  const std::pair<const char*, void (*)()> scenarios[] = {
      {"api_walk_through_the_running_states", &api_walk_through_the_running_states},
      {"stop_from_operational_and_deactivated", &stop_from_operational_and_deactivated},
      {"startup_without_activation", &startup_without_activation},
      {"startup_ends_in_idle", &startup_ends_in_idle},
      {"refused_activation_at_startup", &refused_activation_at_startup},
      {"refused_activation_from_preop_then_runtime_fault",
       &refused_activation_from_preop_then_runtime_fault},
      {"deactivated_target_refused", &deactivated_target_refused},
      {"critical_runtime_faults_and_their_recovery", &critical_runtime_faults_and_their_recovery},
      {"stop_while_recovering", &stop_while_recovering},
      {"fatal_subsystem_exits", &fatal_subsystem_exits},
  };
  for (const auto& [name, run] : scenarios) {
    SCOPED_TRACE(name);
    run();
  }

  std::lock_guard lock(coverage().mutex);
  // The table: every row a drawn edge, every drawn edge a row.
  std::set<Edge> drawn;
  for (const auto& t : master_transitions())
    drawn.insert({t.from, t.to});
  std::set<Edge> in_table;
  for (const auto& r : kRows) {
    EXPECT_TRUE(drawn.count({r.from, r.to}) != 0) << "row of an undrawn edge: " << name_of(r);
    in_table.insert({r.from, r.to});
  }
  for (const auto& t : master_transitions()) {
    EXPECT_TRUE(in_table.count({t.from, t.to}) != 0)
        << "drawn edge without a row (and a trigger) in kRows: " << to_string(t.from) << " -> "
        << to_string(t.to) << " (" << t.trigger << ")";
  }
  // Every row observed by its trigger.
  for (const auto& r : kRows) {
    EXPECT_TRUE(coverage().rows.count(r.row) != 0) << "never observed: " << name_of(r);
  }
  // The stream saw exactly the drawn edges.
  EXPECT_EQ(coverage().edges, drawn);
  for (const auto& e : drawn) {
    EXPECT_TRUE(coverage().edges.count(e) != 0)
        << "edge never seen in the stream: " << to_string(e.first) << " -> " << to_string(e.second);
  }
}

}  // namespace
}  // namespace ecat::master
