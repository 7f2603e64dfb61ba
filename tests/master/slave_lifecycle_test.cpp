// The slave's lifecycle against the seed's diagram (../shared/seeds/slave.md): every drawn edge is
// driven by the trigger the seed names (an API request, a fault from the simulator, a retry) and
// observed in the event stream, and no undrawn edge ever happens (refused and counted: the count
// stays 0). The edges are collected over several sessions, then checked against the table.
#include <chrono>
#include <filesystem>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/master/states.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/sii.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using test::EventRecorder;
using Edge = std::pair<SlaveState, SlaveState>;
namespace fault = sim::fault;

// Edges seen by the scenarios below.
std::set<Edge>& observed() {
  static std::set<Edge> edges;
  return edges;
}
std::mutex observed_mutex;

template <class Predicate>
bool test_eventually(Predicate predicate, std::chrono::nanoseconds timeout = 5s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (predicate()) return true;
    std::this_thread::sleep_for(2ms);
  }
  return predicate();
}

// Takes every slave.state edge the recorder saw; fails on an undrawn one.
void collect(EventRecorder& events, Master& master) {
  ASSERT_TRUE(master.flush_events());
  std::lock_guard lock(observed_mutex);
  for (const auto& e : events.events()) {
    if (e.kind != EventKind::slave_state) continue;
    const Edge edge{static_cast<SlaveState>(e.from), static_cast<SlaveState>(e.to)};
    EXPECT_TRUE(slave_transition_allowed(edge.first, edge.second))
        << "undrawn edge " << to_string(edge.first) << " -> " << to_string(edge.second);
    observed().insert(edge);
  }
}

void expect_nothing_refused(Master& master) {
  const auto status = master.status();
  EXPECT_EQ(status.illegal_transitions, 0u);
  EXPECT_EQ(status.illegal_slave_transitions, 0u);
  EXPECT_EQ(status.illegal_domain_transitions, 0u);
}

MasterConfig base_config() {
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.awaiting_preop_timeout = 5s;
  config.retry_interval = 50ms;
  config.slave_retry_interval = 50ms;
  config.dc.reset();
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  config.domains.push_back(main);
  return config;
}

SlaveConfig slave(std::string name, bool process_data = true,
                  TargetState target = TargetState::op) {
  SlaveConfig c;
  c.name = std::move(name);
  if (process_data) c.process_data = ProcessDataRequest::all("main");
  c.target = target;
  c.health_poll = 20ms;
  return c;
}

constexpr const char* kRing = test::kTerminalRing;

struct Session {
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;
  std::unique_ptr<EventRecorder> events;

  static Session start(const std::string& ring, MasterConfig config, bool wait = true) {
    Session s;
    s.server = test::make_sim_server(ring);
    EXPECT_TRUE(s.server);
    if (!s.server) return s;
    auto link = s.server->serve_memory();
    EXPECT_TRUE(link);
    s.master = std::make_unique<Master>(std::move(config));
    s.events = std::make_unique<EventRecorder>(*s.master);
    EXPECT_TRUE(s.master->start(std::move(*link)));
    if (wait) {
      EXPECT_TRUE(s.master->await_running(10s));
    }
    return s;
  }
  bool saw(std::string_view name, SlaveState from, SlaveState to) {
    return events->saw(EventKind::slave_state, name, to_string(from), to_string(to));
  }
  Slave& get(std::string_view name) { return **master->slave(name); }
  void finish() {
    expect_nothing_refused(*master);
    collect(*events, *master);
    ASSERT_TRUE(master->stop());  // stopped, or already stopped (a session that failed)
    events.reset();
  }
};

// Requests walk the AL states; the seed's request edges go straight to the target.
void requests_take_the_drawn_edges() {
  auto config = base_config();
  config.slaves = {slave("coupler", false), slave("inputs"), slave("outputs")};
  auto s = Session::start(kRing, config);
  ASSERT_TRUE(s.master);
  ASSERT_TRUE(s.master->await_operational(10s));
  EXPECT_TRUE(s.saw("outputs", SlaveState::init, SlaveState::preop)) << s.events->dump();
  EXPECT_TRUE(s.saw("outputs", SlaveState::preop, SlaveState::op)) << s.events->dump();
  Slave& outputs = s.get("outputs");
  const std::pair<wire::AlState, Edge> steps[] = {
      {wire::AlState::safeop, {SlaveState::op, SlaveState::safeop}},
      {wire::AlState::op, {SlaveState::safeop, SlaveState::op}},
      {wire::AlState::preop, {SlaveState::op, SlaveState::preop}},
      {wire::AlState::safeop, {SlaveState::preop, SlaveState::safeop}},
      {wire::AlState::preop, {SlaveState::safeop, SlaveState::preop}},
      {wire::AlState::init, {SlaveState::preop, SlaveState::init}},
      {wire::AlState::op, {SlaveState::init, SlaveState::op}},
      {wire::AlState::init, {SlaveState::op, SlaveState::init}},
      {wire::AlState::safeop, {SlaveState::init, SlaveState::safeop}},
      {wire::AlState::init, {SlaveState::safeop, SlaveState::init}},
      {wire::AlState::op, {SlaveState::init, SlaveState::op}},
  };
  for (const auto& [target, edge] : steps) {
    auto done = outputs.request(target);
    ASSERT_TRUE(done) << wire::to_string(target) << ": " << done.error().describe();
    EXPECT_TRUE(s.saw("outputs", edge.first, edge.second))
        << to_string(edge.first) << " -> " << to_string(edge.second) << "\n"
        << s.events->dump();
  }
  s.finish();
}

// BOOTSTRAP: entered from PREOP and SAFEOP straight (the diagram's edges), from INIT on request,
// and left through INIT only.
void bootstrap_is_entered_and_left_through_the_drawn_edges() {
  const auto file = test::edited_eeprom("mailbox", "lifecycle-boot", [](wire::SiiImage& image) {
    image.bootstrap_mailbox = image.standard_mailbox;
  });
  ASSERT_FALSE(file.empty());
  const std::string ring = fmt::format(
      "version: 1\nsimulator:\n  slaves:\n    - {{name: coupler, profile: EK1100}}\n"
      "    - {{name: loader, profile: eeprom, file: \"{}\"}}\n",
      file.string());
  auto config = base_config();
  config.domains.clear();
  config.slaves = {slave("coupler", false, TargetState::preop),
                   slave("loader", false, TargetState::preop)};
  auto s = Session::start(ring, config);
  std::filesystem::remove(file);
  ASSERT_TRUE(s.master);
  Slave& loader = s.get("loader");
  const std::pair<wire::AlState, std::vector<Edge>> steps[] = {
      {wire::AlState::bootstrap, {{SlaveState::preop, SlaveState::bootstrap}}},
      {wire::AlState::preop,
       {{SlaveState::bootstrap, SlaveState::init}, {SlaveState::init, SlaveState::preop}}},
      {wire::AlState::safeop, {{SlaveState::preop, SlaveState::safeop}}},
      {wire::AlState::bootstrap, {{SlaveState::safeop, SlaveState::bootstrap}}},
      {wire::AlState::init, {{SlaveState::bootstrap, SlaveState::init}}},
      {wire::AlState::bootstrap, {{SlaveState::init, SlaveState::bootstrap}}},
      {wire::AlState::preop, {}},
  };
  for (const auto& [target, edges] : steps) {
    auto done = loader.request(target, 5s);
    ASSERT_TRUE(done) << wire::to_string(target) << ": " << done.error().describe();
    for (const auto& edge : edges) {
      EXPECT_TRUE(s.saw("loader", edge.first, edge.second))
          << to_string(edge.first) << " -> " << to_string(edge.second) << "\n"
          << s.events->dump();
    }
  }
  s.finish();
}

// Lost from the bus in PREOP, SAFEOP and OP (health poll without the slave's WKC): DOWN; found
// again and rebuilt: DOWN -> PREOP, then back to its target.
void lost_slaves_go_down_and_come_back_through_preop() {
  struct Case {
    TargetState session;
    SlaveState from;
  };
  for (const auto& c :
       {Case{TargetState::op, SlaveState::op}, Case{TargetState::safeop, SlaveState::safeop},
        Case{TargetState::preop, SlaveState::preop}}) {
    auto config = base_config();
    config.slaves = {slave("coupler", false), slave("inputs"), slave("outputs", true, c.session)};
    auto s = Session::start(kRing, config);
    ASSERT_TRUE(s.master);
    ASSERT_TRUE(s.master->await_running(10s));
    ASSERT_TRUE(test_eventually([&] { return s.get("outputs").state() == c.from; }))
        << to_string(c.from) << s.events->dump();
    ASSERT_TRUE(s.server->inject(fault::next(fault::disconnect("outputs"), 100)));
    EXPECT_TRUE(s.saw("outputs", c.from, SlaveState::down)) << s.events->dump();
    EXPECT_TRUE(s.saw("outputs", SlaveState::down, SlaveState::preop)) << s.events->dump();
    ASSERT_TRUE(test_eventually([&] { return s.get("outputs").state() == c.from; }, 10s))
        << s.events->dump();
    s.finish();
  }
}

// A lost slave that answers again but cannot be rebuilt (its SII now names another device):
// DOWN -> INIT, and the rebuild is retried from there until it succeeds (INIT -> PREOP).
void a_failed_rebuild_retries_from_init() {
  auto config = base_config();
  config.slaves = {slave("coupler", false), slave("inputs"), slave("outputs")};
  auto s = Session::start(kRing, config);
  ASSERT_TRUE(s.master);
  ASSERT_TRUE(s.master->await_operational(10s));
  const auto product_word = 2 * wire::sii_word::kProductCode;
  std::uint8_t saved = 0;
  s.server->with_segment([&](sim::Segment& segment, auto&) {
    auto& eeprom = segment.esc(*segment.find("outputs")).pdi_eeprom();
    saved = eeprom[product_word];
    eeprom[product_word] ^= 0xFF;
  });
  ASSERT_TRUE(s.server->inject(fault::next(fault::disconnect("outputs"), 60)));
  EXPECT_TRUE(s.saw("outputs", SlaveState::op, SlaveState::down)) << s.events->dump();
  EXPECT_TRUE(s.saw("outputs", SlaveState::down, SlaveState::init)) << s.events->dump();
  EXPECT_TRUE(s.events->saw(EventKind::fault_raised, "outputs")) << s.events->dump();
  s.server->with_segment([&](sim::Segment& segment, auto&) {
    segment.esc(*segment.find("outputs")).pdi_eeprom()[product_word] = saved;
  });
  EXPECT_TRUE(s.saw("outputs", SlaveState::init, SlaveState::preop)) << s.events->dump();
  ASSERT_TRUE(test_eventually([&] { return s.get("outputs").state() == SlaveState::op; }, 10s))
      << s.events->dump();
  s.finish();
}

// A slave whose bring-up fails in INIT is retried there: the seed's init -> init.
void a_bring_up_retried_in_init_is_the_init_to_init_edge() {
  auto config = base_config();
  config.awaiting_preop_timeout = 500ms;
  config.slaves = {slave("coupler", false), slave("inputs"), slave("outputs")};
  config.slaves[2].product_code = 0x0BADC0DE;  // never the device found: every attempt fails
  auto s = Session::start(kRing, config, false);
  ASSERT_TRUE(s.master);
  EXPECT_TRUE(s.saw("outputs", SlaveState::init, SlaveState::init)) << s.events->dump();
  EXPECT_TRUE(test_eventually([&] { return s.master->state() == MasterState::idle; }, 10s));
  s.finish();
}

// Lost while in INIT: the diagram has no edge to DOWN from there; the slave keeps its state and
// the loss is a fault until it answers again.
void a_slave_lost_in_init_keeps_its_state_and_reports_a_fault() {
  auto config = base_config();
  config.slaves = {slave("coupler", false), slave("inputs"), slave("outputs")};
  auto s = Session::start(kRing, config);
  ASSERT_TRUE(s.master);
  ASSERT_TRUE(s.master->await_operational(10s));
  ASSERT_TRUE(s.get("outputs").request(wire::AlState::init));
  ASSERT_TRUE(s.server->inject(fault::next(fault::disconnect("outputs"), 100)));
  EXPECT_TRUE(s.events->wait_for([](const Event& e) {
    return e.kind == EventKind::fault_raised && e.name() == "outputs" &&
           e.detail().find("lost while in init") != std::string_view::npos;
  })) << s.events->dump();
  EXPECT_EQ(s.get("outputs").state(), SlaveState::init);
  EXPECT_TRUE(s.events->saw(EventKind::fault_cleared, "outputs")) << s.events->dump();
  for (const auto& e : s.events->events()) {
    EXPECT_FALSE(e.kind == EventKind::slave_state && e.name() == "outputs" &&
                 e.to == static_cast<std::uint8_t>(SlaveState::down))
        << s.events->dump();
  }
  s.finish();
}

// One test, so that the coverage check sees every scenario wherever the tests run (CTest runs
// each test of a file in a process of its own).
TEST(SlaveLifecycle, EveryDrawnEdgeIsTakenByItsTriggerAndNoOtherEver) {
  const std::pair<const char*, void (*)()> scenarios[] = {
      {"requests_take_the_drawn_edges", &requests_take_the_drawn_edges},
      {"bootstrap_is_entered_and_left_through_the_drawn_edges",
       &bootstrap_is_entered_and_left_through_the_drawn_edges},
      {"lost_slaves_go_down_and_come_back_through_preop",
       &lost_slaves_go_down_and_come_back_through_preop},
      {"a_failed_rebuild_retries_from_init", &a_failed_rebuild_retries_from_init},
      {"a_bring_up_retried_in_init_is_the_init_to_init_edge",
       &a_bring_up_retried_in_init_is_the_init_to_init_edge},
      {"a_slave_lost_in_init_keeps_its_state_and_reports_a_fault",
       &a_slave_lost_in_init_keeps_its_state_and_reports_a_fault},
  };
  for (const auto& [name, run] : scenarios) {
    SCOPED_TRACE(name);
    run();
  }
  std::lock_guard lock(observed_mutex);
  for (const auto& t : slave_transitions()) {
    EXPECT_TRUE(observed().count({t.from, t.to}) != 0)
        << "never observed: " << to_string(t.from) << " -> " << to_string(t.to) << " (" << t.trigger
        << ")";
  }
}

}  // namespace
}  // namespace ecat::master
