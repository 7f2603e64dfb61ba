// The master's event stream: the hub's delivery rules (order, sequence, pull queues, overflow told
// as missed events, unsubscribe), the stable names and JSON form, and a session's events end to
// end against the simulator (states of master, slaves and domains, domain health, faults raised
// and cleared, recovery steps, SDO failures, DC lock, the link).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <ecat/master/events.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/server.hpp>

#include "master/event_hub.hpp"
#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;

// ---- the hub ----------------------------------------------------------------------------------

TEST(EventHub, DeliversInOrderWithSequenceNumbersToCallbacksAndQueues) {
  EventHub hub(64);
  std::mutex mutex;
  std::vector<Event> got;
  hub.subscribe([&](const Event& e, std::uint64_t missed) {
    EXPECT_EQ(missed, 0u);
    std::lock_guard lock(mutex);
    got.push_back(e);
  });
  auto queue = hub.open_queue(16);
  for (int i = 0; i < 10; ++i) {
    Event e = make_event(EventKind::recovery_step, "s", std::to_string(i));
    ASSERT_TRUE(hub.publish(e));
  }
  ASSERT_TRUE(hub.flush(5s));
  std::lock_guard lock(mutex);
  ASSERT_EQ(got.size(), 10u);
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].sequence, i + 1);
    EXPECT_EQ(got[i].detail(), std::to_string(i));
    EXPECT_GT(got[i].time_ns, 0);
    auto item = queue->next(1s);
    ASSERT_TRUE(item);
    EXPECT_EQ(item->event.sequence, i + 1);
    EXPECT_EQ(item->missed_before, 0u);
  }
  EXPECT_FALSE(queue->next(10ms));
  const auto stats = hub.stats();
  EXPECT_EQ(stats.published, 10u);
  EXPECT_EQ(stats.dropped, 0u);
  EXPECT_EQ(stats.delivered, 10u);
}

// A subscriber that stalls the dispatcher: producers never wait, the overflow is dropped and
// counted, and the subscriber is told how many it missed with the next event it gets.
TEST(EventHub, ASlowSubscriberIsToldWhatItMissedAndProducersNeverWait) {
  EventHub hub(8);
  std::mutex mutex;
  std::condition_variable cv;
  bool release = false;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> got;  // sequence, missed
  hub.subscribe([&](const Event& e, std::uint64_t missed) {
    std::unique_lock lock(mutex);
    got.emplace_back(e.sequence, missed);
    cv.wait(lock, [&] { return release; });
  });
  ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  // The dispatcher now sits in the callback; the queue (8) fills, the rest is dropped.
  ASSERT_TRUE([&] {
    for (int i = 0; i < 1000; ++i) {
      std::lock_guard lock(mutex);
      if (!got.empty()) return true;
      std::this_thread::sleep_for(1ms);
    }
    return false;
  }());
  const auto start = std::chrono::steady_clock::now();
  std::size_t accepted = 0;
  for (int i = 0; i < 100; ++i)
    accepted += hub.publish(make_event(EventKind::recovery_step)) ? 1 : 0;
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s) << "a producer waited";
  EXPECT_EQ(accepted, 8u);
  EXPECT_EQ(hub.stats().dropped, 92u);
  {
    std::lock_guard lock(mutex);
    release = true;
  }
  cv.notify_all();
  ASSERT_TRUE(hub.flush(5s));
  std::lock_guard lock(mutex);
  ASSERT_EQ(got.size(), 9u);
  std::uint64_t missed = 0;
  for (const auto& [sequence, m] : got)
    missed += m;
  EXPECT_EQ(missed, 92u);
  // A later event reports nothing missed.
}

TEST(EventHub, AFullPullQueueCountsWhatItMissed) {
  EventHub hub(64);
  auto queue = hub.open_queue(3);
  for (int i = 0; i < 5; ++i)
    ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  ASSERT_TRUE(hub.flush(5s));
  EXPECT_EQ(queue->missed(), 2u);
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(queue->next(1s));
  ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  auto item = queue->next(1s);
  ASSERT_TRUE(item);
  EXPECT_EQ(item->missed_before, 2u);
  EXPECT_EQ(item->event.sequence, 6u);
  queue->close();
  EXPECT_FALSE(queue->next(1s));
}

TEST(EventHub, UnsubscribedCallbacksAreNotCalledAgain) {
  EventHub hub(64);
  std::atomic<int> calls{0};
  const auto id = hub.subscribe([&](const Event&, std::uint64_t) { ++calls; });
  ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  ASSERT_TRUE(hub.flush(5s));
  EXPECT_EQ(calls.load(), 1);
  EXPECT_TRUE(hub.unsubscribe(id));
  EXPECT_FALSE(hub.unsubscribe(id));
  ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  ASSERT_TRUE(hub.flush(5s));
  EXPECT_EQ(calls.load(), 1);
}

TEST(EventHub, ACallbackThatThrowsDoesNotStopTheStream) {
  EventHub hub(64);
  std::atomic<int> others{0};
  hub.subscribe([](const Event&, std::uint64_t) { throw std::runtime_error("subscriber bug"); });
  hub.subscribe([&](const Event&, std::uint64_t) { ++others; });
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  ASSERT_TRUE(hub.flush(5s));
  EXPECT_EQ(others.load(), 3);
}

// ---- names and the JSON form ------------------------------------------------------------------

TEST(Events, EveryKindHasAStableNameThatParsesBack) {
  std::set<std::string> names;
  for (std::size_t i = 0; i < kEventKindCount; ++i) {
    const auto kind = static_cast<EventKind>(i);
    const std::string name(to_string(kind));
    EXPECT_NE(name, "unknown");
    EXPECT_NE(name.find('.'), std::string::npos) << name;
    EXPECT_TRUE(names.insert(name).second) << "duplicate " << name;
    EXPECT_EQ(event_kind_from_string(name), kind);
  }
  EXPECT_FALSE(event_kind_from_string("master.nonsense"));
  EXPECT_EQ(to_string(EventKind::master_state), "master.state");
  EXPECT_EQ(to_string(EventKind::domain_health), "domain.health");
  EXPECT_EQ(to_string(EventKind::timeouts), "bus.timeouts");
}

TEST(Events, JsonFormNamesTheEventItsSubjectAndStates) {
  Event e = make_event(EventKind::slave_state, "drive");
  e.sequence = 7;
  e.time_ns = 123;
  e.subject = 4;
  e.from = static_cast<std::uint8_t>(SlaveState::safeop);
  e.to = static_cast<std::uint8_t>(SlaveState::op);
  auto j = json::parse(event_json(e));
  EXPECT_EQ(j.at("seq"), 7);
  EXPECT_EQ(j.at("time_ns"), 123);
  EXPECT_EQ(j.at("event"), "slave.state");
  EXPECT_EQ(j.at("slave"), "drive");
  EXPECT_EQ(j.at("index"), 4);
  EXPECT_EQ(j.at("from"), "safeop");
  EXPECT_EQ(j.at("to"), "op");
  EXPECT_EQ(describe(e), "slave.state drive: safeop -> op");

  Event sdo = make_event(EventKind::sdo_failed, "drive", "0x6060:00 refused");
  sdo.value = 0x06090011;
  j = json::parse(event_json(sdo));
  EXPECT_EQ(j.at("abort_code"), 0x06090011);
  EXPECT_EQ(j.at("detail"), "0x6060:00 refused");
  EXPECT_EQ(describe(sdo), "sdo.failed drive: abort_code=0x6090011 (0x6060:00 refused)");

  Event health = make_event(EventKind::domain_health, "main", "timeout");
  health.to = 0;
  j = json::parse(event_json(health));
  EXPECT_EQ(j.at("domain"), "main");
  EXPECT_EQ(j.at("healthy"), false);
}

TEST(Events, TextIsCutToFitAndNeverBreaksTheJson) {
  const std::string long_name(100, 'n');
  std::string detail(300, 'x');
  detail[Event::kDetailSize - 2] = '\xC3';  // a UTF-8 lead byte where the text is cut
  Event e = make_event(EventKind::fault_raised, long_name, detail);
  EXPECT_EQ(e.name().size(), Event::kNameSize - 1);
  EXPECT_EQ(e.detail().size(), Event::kDetailSize - 1);
  const auto parsed = json::parse(event_json(e), nullptr, false);
  EXPECT_FALSE(parsed.is_discarded());
  format_detail(e, "{} and {}", 1, std::string(400, 'y'));
  EXPECT_EQ(e.detail().size(), Event::kDetailSize - 1);
  EXPECT_EQ(e.detail().substr(0, 8), "1 and yy");
}

// ---- a session's events -----------------------------------------------------------------------

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: drive, profile: servo}
)";

MasterConfig session_config() {
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.retry_interval = 50ms;
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  config.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
    SlaveConfig s;
    s.name = name;
    if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
    config.slaves.push_back(s);
  }
  return config;
}

using test::EventRecorder;

TEST(MasterEvents, ASessionTellsItsStatesHealthFaultsAndRecovery) {
  auto server = test::make_sim_server(kRing);
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  Master master(session_config());
  EventRecorder events(master);
  auto queue = master.open_event_queue();
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_operational(10s));

  // Startup: the link, every master state on the way, each slave to OP, the domain cycling.
  EXPECT_TRUE(events.saw(EventKind::link_up)) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "idle", "discovering")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "discovering", "awaiting_preop"));
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "awaiting_preop", "operational"));
  for (const char* slave : {"coupler", "inputs", "outputs", "drive"}) {
    EXPECT_TRUE(events.saw(EventKind::slave_state, slave, "", "op")) << slave << events.dump();
  }
  EXPECT_TRUE(events.saw(EventKind::domain_state, "main", "open", "cycling")) << events.dump();

  // A working-counter fault on the domain: invalid cycles, a runtime fault, then recovery.
  ASSERT_TRUE(server->inject(sim::fault::next(sim::fault::logical_wkc_offset("outputs", -1), 50)));
  EXPECT_TRUE(events.wait_for([](const Event& e) {
    return e.kind == EventKind::domain_health && e.name() == "main" && e.to == 0;
  })) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::fault_raised, "domain:main")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "operational", "recovering"));
  EXPECT_TRUE(events.wait_for([](const Event& e) {
    return e.kind == EventKind::domain_health && e.name() == "main" && e.to == 1;
  })) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::fault_cleared, "domain:main")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::recovery_step, "domain:main")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "recovering", "operational"));

  // A slave that retreats from OP: its state, its fault, the recovery step, back to OP.
  ASSERT_TRUE(server->inject(sim::fault::retreat_to_safeop("outputs")));
  EXPECT_TRUE(events.saw(EventKind::slave_state, "outputs", "op", "safeop")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::fault_raised, "outputs")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::recovery_step, "outputs")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::slave_state, "outputs", "safeop", "op")) << events.dump();
  EXPECT_TRUE(events.saw(EventKind::fault_cleared, "outputs")) << events.dump();

  // An SDO the drive refuses: sdo.failed with the abort code, counted per slave.
  auto drive = master.slave("drive");
  ASSERT_TRUE(drive);
  EXPECT_FALSE((*drive)->upload_sdo(0x5FFF, 1));
  EXPECT_TRUE(events.wait_for([](const Event& e) {
    return e.kind == EventKind::sdo_failed && e.name() == "drive" && e.value == 0x06020000;
  })) << events.dump();
  const auto counters = master.counters();
  const auto it = std::find_if(counters.slaves.begin(), counters.slaves.end(),
                               [](const auto& c) { return c.name == "drive"; });
  ASSERT_NE(it, counters.slaves.end());
  EXPECT_EQ(it->sdo_failures, 1u);
  EXPECT_GT(counters.frames_sent, 0u);
  ASSERT_EQ(counters.domains.size(), 1u);
  EXPECT_GT(counters.domains[0].wkc_mismatches, 0u);

  ASSERT_TRUE(master.stop());
  ASSERT_TRUE(master.flush_events());
  EXPECT_TRUE(events.saw(EventKind::master_state, "", "operational", "idle")) << events.dump();
  EXPECT_EQ(events.missed(), 0u);

  // The pull queue saw the same stream, in the same order.
  const auto all = events.events();
  for (const auto& e : all) {
    auto item = queue->next(1s);
    ASSERT_TRUE(item);
    EXPECT_EQ(item->event.sequence, e.sequence);
    EXPECT_EQ(item->event.kind, e.kind);
  }
  for (std::size_t i = 1; i < all.size(); ++i)
    EXPECT_EQ(all[i].sequence, all[i - 1].sequence + 1);
}

// The bus's losses are told as they pass 1, 10, 100 ... (not once per frame); DC lock is told.
TEST(MasterEvents, FrameLossAndDcLockAreTold) {
  auto server = test::make_sim_server(kRing);
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  auto config = session_config();
  config.dc = DcConfig{};
  config.dc->cycle = 1ms;
  Master master(config);
  EventRecorder events(master);
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_operational(10s));
  EXPECT_TRUE(events.saw(EventKind::dc_locked)) << events.dump();
  ASSERT_TRUE(server->inject(sim::fault::next(sim::fault::drop_responses(), 12)));
  EXPECT_TRUE(events.wait_for([](const Event& e) {
    return e.kind == EventKind::frames_lost && e.value >= 10;
  })) << events.dump();
  // Marks crossed within one look at the counters make one event (12 losses: one, at 12).
  std::size_t loss_events = 0;
  for (const auto& e : events.events())
    loss_events += e.kind == EventKind::frames_lost ? 1 : 0;
  EXPECT_LE(loss_events, 2u) << events.dump();
  ASSERT_TRUE(master.stop());
}

}  // namespace
}  // namespace ecat::master

namespace ecat::master {
namespace {

// dc.warmup_cycles: the maintainer runs that many DC cycles before any slave goes on to SAFEOP
// (a lower bound on time, which a loaded machine can only lengthen).
TEST(MasterEvents, DcWarmupCyclesRunBeforeSafeop) {
  auto server = test::make_sim_server(kRing);
  ASSERT_TRUE(server);
  std::unique_ptr<link::Link> link = server->function_link();
  auto config = session_config();
  config.dc = DcConfig{};
  config.dc->cycle = 1ms;
  config.dc->warmup_cycles = 300;
  Master master(config);
  test::EventRecorder events(master);
  ASSERT_TRUE(master.start(std::move(link)));
  ASSERT_TRUE(master.await_operational(10s));
  ASSERT_TRUE(master.flush_events());
  std::optional<std::int64_t> cycling;
  std::optional<std::int64_t> first_safeop;
  for (const auto& e : events.events()) {
    if (e.kind == EventKind::domain_state && e.to_name() == "cycling" && !cycling) {
      cycling = e.time_ns;
    }
    if (e.kind == EventKind::slave_state && e.from_name() == "preop" && !first_safeop) {
      first_safeop = e.time_ns;
    }
  }
  ASSERT_TRUE(cycling && first_safeop) << events.dump();
  EXPECT_GE(*first_safeop - *cycling, std::chrono::nanoseconds(290ms).count()) << events.dump();
  EXPECT_GE(master.dc_status()->frmw_sent, 300u);
  ASSERT_TRUE(master.stop());
}

}  // namespace
}  // namespace ecat::master
