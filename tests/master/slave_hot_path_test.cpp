// Slave::read_input / write_output on a running master: a scalar signal is read and staged as its
// own bits (the Domain::Field it keeps: read_fresh / write_bits) and must say what the whole SM
// image says, fail closed when stale with the error naming the signal, and stage a multi-byte value
// whole.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

template <class F>
bool eventually(F&& f, std::chrono::milliseconds limit = 5s) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (f()) return true;
    std::this_thread::sleep_for(1ms);
  }
  return f();
}

struct Running {
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;

  explicit Running(std::chrono::nanoseconds stale_after = 2s) {
    server = test::make_sim_server(test::kDriveRing);
    if (!server) return;
    MasterConfig config = test::quick_config(2ms);
    config.frame_timeout = 1s;  // no spurious loss on a loaded machine
    config.domains[0].recovery_threshold = 1'000'000;
    config.domains[0].miss_threshold = 1'000'000;
    config.domains[0].stale_after = stale_after;
    config.slaves.push_back(test::quick_slave("drive"));
    for (auto& s : config.slaves)
      s.health_poll.reset();
    master = std::make_unique<Master>(config);
    auto link = server->serve_memory();
    if (!link || !master->start(std::move(*link)) || !master->await_operational(20s)) {
      master.reset();
    }
  }
  ~Running() {
    if (master) (void)master->stop();
  }
  Slave& slave(std::string_view name) { return **master->slave(name); }
  Domain& domain() { return **master->domain("main"); }
  // The SM image a signal lies in, as the domain holds it now.
  std::vector<std::uint8_t> image_of(Slave& s, const Signal& sig) {
    const SlaveInfo info = s.info();
    for (const auto& a : info.attachments) {
      if (a.sync_manager != sig.sync_manager) continue;
      auto bytes = domain().read(PdoKey{info.station, a.sync_manager});
      if (bytes) return *bytes;
    }
    return {};
  }
};

const Signal* find(const std::vector<Signal>& signals, std::string_view name) {
  const auto it =
      std::find_if(signals.begin(), signals.end(), [&](const Signal& s) { return s.name == name; });
  return it == signals.end() ? nullptr : &*it;
}

TEST(SlaveHotPath, FieldReadsSayWhatTheImageSaysAndStaleInputsFail) {
  Running r;
  ASSERT_TRUE(r.master);
  Slave& in = r.slave("inputs");
  Slave& out = r.slave("outputs");
  ASSERT_TRUE(out.write_output("channel_2", Value(true)));
  ASSERT_TRUE(eventually([&] {
    auto v = in.read_input("channel_2");
    return v && *v == Value(true);
  }));
  // Every input signal of the EL1809 and the drive reads as the whole image decodes (the image
  // is read before and after: equal, nothing changed in between).
  for (Slave* s : {&in, &r.slave("drive")}) {
    const auto signals = s->signals();
    std::size_t compared = 0;
    for (const auto& sig : signals) {
      if (sig.direction != PdoDirection::input) continue;
      bool same = false;
      for (int attempt = 0; attempt < 100 && !same; ++attempt) {
        const auto before = r.image_of(*s, sig);
        auto value = s->read_input(sig.name);
        const auto after = r.image_of(*s, sig);
        ASSERT_TRUE(value.ok()) << sig.name << ": " << value.error().describe();
        if (before != after || before.empty()) continue;
        auto expected = decode_scaled(sig, before);
        ASSERT_TRUE(expected.ok());
        EXPECT_EQ(*value, *expected) << s->name() << " " << sig.name;
        same = true;
      }
      EXPECT_TRUE(same) << sig.name << " kept changing";
      ++compared;
    }
    EXPECT_GT(compared, 0u) << s->name();
  }
  // Errors as before: unknown signals and inputs written are named.
  auto unknown = in.read_input("channel_99");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().code(), Errc::not_found);
  EXPECT_EQ(unknown.error().message(), "slave inputs has no signal \"channel_99\"");
  auto to_input = in.write_output("channel_1", Value(true));
  ASSERT_FALSE(to_input.ok());
  EXPECT_EQ(to_input.error().code(), Errc::invalid_argument);
  auto too_big = r.slave("drive").write_output("target_position", Value(std::int64_t{1} << 40));
  ASSERT_FALSE(too_big.ok());
  EXPECT_EQ(too_big.error().code(), Errc::out_of_range);
  EXPECT_NE(too_big.error().message().find("output \"target_position\" of slave drive"),
            std::string::npos);

  // The domain stops: after stale_after the read fails closed, naming the signal and the slave.
  ASSERT_TRUE(r.domain().stop_cycling());
  std::this_thread::sleep_for(2500ms);
  auto stale = in.read_input("channel_2");
  ASSERT_FALSE(stale.ok());
  EXPECT_EQ(stale.error().code(), Errc::stale);
  EXPECT_EQ(stale.error().message(), "input \"channel_2\" of slave inputs");
  ASSERT_NE(stale.error().cause(), nullptr);
  EXPECT_NE(stale.error().cause()->message().find("(input) is stale"), std::string::npos);
}

// The staleness rule holds exactly on the fast path (a TSC stamp proves freshness without a
// clock read; past it, one clock read decides): once the domain stops, every read that says
// fresh began within stale_after of the last valid cycle, every read that says stale ended
// beyond it, through Slave::read_input and a SignalHandle alike. No timing tolerance: each read
// is bracketed by clock reads, and the domain's last valid cycle is the publish's own time.
TEST(SlaveHotPath, AStoppedDomainsInputsTurnStaleExactlyAfterStaleAfter) {
  constexpr auto kStaleAfter = 100ms;
  Running r(kStaleAfter);
  ASSERT_TRUE(r.master);
  Slave& in = r.slave("inputs");
  auto handle = r.master->signal_handle("inputs", "channel_2");
  ASSERT_TRUE(handle.ok()) << handle.error().describe();
  // Some cycles first: the TSC stamps start after a measured window of 5 ms (tsc_clock.hpp).
  std::this_thread::sleep_for(50ms);
  ASSERT_TRUE(eventually([&] { return in.read_input("channel_2").ok() && handle->read().ok(); }));
  ASSERT_TRUE(r.domain().stop_cycling());
  std::this_thread::sleep_for(20ms);  // an exchange still in flight completes
  std::size_t fresh = 0, stale = 0;
  const auto end = std::chrono::steady_clock::now() + 3 * kStaleAfter;
  while (std::chrono::steady_clock::now() < end) {
    const auto before_stats = r.domain().stats().last_valid_at;
    const auto t0 = std::chrono::steady_clock::now();
    auto by_name = in.read_input("channel_2");
    auto by_handle = handle->read();
    const auto t1 = std::chrono::steady_clock::now();
    const auto last_valid = r.domain().stats().last_valid_at;
    ASSERT_TRUE(last_valid.has_value());
    if (before_stats != last_valid) continue;  // published meanwhile: not this sample
    for (const auto* got : {&by_name, &by_handle}) {
      if (got->ok()) {
        EXPECT_LE(t0 - *last_valid, kStaleAfter) << "fresh, yet older than stale_after";
        ++fresh;
      } else {
        ASSERT_EQ(got->error().code(), Errc::stale) << got->error().describe();
        EXPECT_GT(t1 - *last_valid, kStaleAfter) << "stale, yet not older than stale_after";
        ++stale;
      }
    }
    std::this_thread::sleep_for(100us);
  }
  EXPECT_GT(fresh, 0u);
  EXPECT_GT(stale, 0u);
  // Still stale long after (nothing turns fresh without a valid cycle).
  EXPECT_EQ(in.read_input("channel_2").error().code(), Errc::stale);
  EXPECT_EQ(handle->read().error().code(), Errc::stale);
}

// A writer alternates a 32-bit output between two values whose every byte differs while a reader
// takes the staged image as a cycle would (under the staging lock): each image holds one of the
// values whole, never bytes of both. The slave's retained copy (read_input of an output) too.
TEST(SlaveHotPath, MultiByteOutputsAreStagedWhole) {
  Running r;
  ASSERT_TRUE(r.master);
  Slave& drive = r.slave("drive");
  const auto signals = drive.signals();
  const Signal* target = find(signals, "target_position");
  ASSERT_NE(target, nullptr);
  ASSERT_GE(target->bit_length, 32);
  const Value a(std::int64_t{0x11223344});
  const Value b(std::int64_t{-0x55667788});
  ASSERT_TRUE(drive.write_output("target_position", a));
  std::atomic<bool> stop{false};
  std::atomic<int> write_errors{0};
  std::thread writer([&] {
    for (std::uint64_t i = 0; !stop.load(); ++i) {
      if (!drive.write_output("target_position", (i & 1) != 0 ? a : b)) write_errors.fetch_add(1);
      if (i % 256 == 0) std::this_thread::yield();
    }
  });
  std::size_t seen_a = 0, seen_b = 0, torn = 0;
  const auto end = std::chrono::steady_clock::now() + 300ms;
  while (std::chrono::steady_clock::now() < end) {
    const auto image = r.image_of(drive, *target);
    auto staged = decode_scaled(*target, image);
    auto retained = drive.read_input("target_position");
    ASSERT_TRUE(staged.ok() && retained.ok());
    for (const Value& v : {*staged, *retained}) {
      if (v == a) {
        ++seen_a;
      } else if (v == b) {
        ++seen_b;
      } else {
        ++torn;
      }
    }
  }
  stop.store(true);
  writer.join();
  EXPECT_EQ(write_errors.load(), 0);
  EXPECT_EQ(torn, 0u);
  EXPECT_GT(seen_a + seen_b, 0u);
  // The last value written is what the domain and the slave hold.
  ASSERT_TRUE(drive.write_output("target_position", b));
  EXPECT_EQ(*decode_scaled(*target, r.image_of(drive, *target)), b);
  EXPECT_EQ(*drive.read_input("target_position"), b);
}

// read_input / write_output read the slave's published view without its mutex (Slave::Impl::
// HotPath) while the control thread replaces it: each PREOP configuration publishes a new view
// and restages the retained outputs. Readers and writers on two threads keep going through
// several reconfigurations of both slaves: every call either succeeds or fails with a named,
// expected error (an input not fresh while the slave is out of OP), a value read is one the
// writer wrote, and afterwards the last value written is what the domain, the retained image
// and the reading slave hold.
TEST(SlaveHotPath, ReadsAndWritesRaceReconfigurationSafely) {
  Running r;
  ASSERT_TRUE(r.master);
  Slave& in = r.slave("inputs");
  Slave& out = r.slave("outputs");
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> reads{0}, writes{0};
  std::atomic<int> bad_reads{0}, bad_writes{0};
  std::string first_bad_read, first_bad_write;  // written once by their thread, read after join
  std::thread reader([&] {
    while (!stop.load()) {
      auto v = in.read_input("channel_2");
      if (v) {
        reads.fetch_add(1);
        if (*v != Value(true) && *v != Value(false)) bad_reads.fetch_add(1);
      } else if (v.error().code() != Errc::stale && v.error().code() != Errc::not_ready) {
        if (bad_reads.fetch_add(1) == 0) first_bad_read = v.error().describe();
      }
    }
  });
  std::thread writer([&] {
    for (std::uint64_t i = 0; !stop.load(); ++i) {
      if (auto w = out.write_output("channel_2", Value((i & 1) != 0)); w) {
        writes.fetch_add(1);
      } else if (bad_writes.fetch_add(1) == 0) {
        first_bad_write = w.error().describe();
      }
      if (i % 64 == 0) std::this_thread::yield();
    }
  });
  // A failed assertion below returns early: the threads are stopped and joined then too.
  struct StopAndJoin {
    std::atomic<bool>& stop;
    std::thread& a;
    std::thread& b;
    ~StopAndJoin() {
      stop.store(true);
      for (std::thread* t : {&a, &b}) {
        if (t->joinable()) t->join();
      }
    }
  } guard{stop, reader, writer};
  // Both threads calling before the first reconfiguration (on a loaded machine a new thread may
  // wait a while for a core).
  EXPECT_TRUE(eventually([&] { return reads.load() > 0 && writes.load() > 0; }));
  for (int round = 0; round < 3; ++round) {
    for (Slave* s : {&in, &out}) {
      ASSERT_TRUE(s->request(wire::AlState::preop)) << s->name();
      auto reconfigured = s->configure(test::quick_slave(std::string(s->name())));
      ASSERT_TRUE(reconfigured) << reconfigured.error().describe();
    }
    for (Slave* s : {&in, &out})
      ASSERT_TRUE(s->request(wire::AlState::op)) << s->name();
  }
  // And after the last one, with the new views.
  const auto reads_before = reads.load();
  const auto writes_before = writes.load();
  EXPECT_TRUE(
      eventually([&] { return reads.load() > reads_before && writes.load() > writes_before; }));
  stop.store(true);
  reader.join();
  writer.join();
  EXPECT_EQ(bad_reads.load(), 0) << first_bad_read;
  EXPECT_EQ(bad_writes.load(), 0) << first_bad_write;
  EXPECT_GT(reads.load(), 0u);
  EXPECT_GT(writes.load(), 0u);
  // Back in OP with the same layout: the last write is staged, retained and read back.
  for (bool value : {true, false}) {
    ASSERT_TRUE(out.write_output("channel_2", Value(value)));
    EXPECT_EQ(*out.read_input("channel_2"), Value(value));
    EXPECT_TRUE(eventually([&] {
      auto v = in.read_input("channel_2");
      return v && *v == Value(value);
    })) << value;
  }
}

// Several writers of the same output: the domain's staged image and the slave's retained one end
// with the same value (write_output stages and retains under one per-slave lock).
TEST(SlaveHotPath, ConcurrentWritersLeaveTheDomainAndTheRetainedImageAlike) {
  Running r;
  ASSERT_TRUE(r.master);
  Slave& drive = r.slave("drive");
  const auto signals = drive.signals();
  const Signal* target = find(signals, "target_position");
  ASSERT_NE(target, nullptr);
  for (int round = 0; round < 20; ++round) {
    std::vector<std::thread> writers;
    for (std::int64_t w = 0; w < 3; ++w) {
      writers.emplace_back([&drive, w] {
        for (std::int64_t i = 0; i < 2000; ++i)
          (void)drive.write_output("target_position", Value(w * 100'000 + i));
      });
    }
    for (auto& t : writers)
      t.join();
    const auto staged = decode_scaled(*target, r.image_of(drive, *target));
    const auto retained = drive.read_input("target_position");
    ASSERT_TRUE(staged.ok() && retained.ok());
    ASSERT_EQ(*staged, *retained) << "round " << round;
  }
}

// A handle's write is kept in the slave's retained image too: Slave::read_input of the output
// says what the handle staged, and a reconfiguration (as after a reconnect), which restages the
// retained image, keeps it; write_output and the handle may then write the same SyncManager.
TEST(SlaveHotPath, HandleWritesSurviveAReconfiguration) {
  Running r;
  ASSERT_TRUE(r.master);
  Slave& out = r.slave("outputs");
  Slave& in = r.slave("inputs");
  // channel_2 (wired to the inputs' channel_2) through a handle, channel_3 of the same
  // SyncManager through the Slave.
  auto handle = r.master->signal_handle("outputs", "channel_2");
  ASSERT_TRUE(handle) << handle.error().describe();
  ASSERT_TRUE(out.write_output("channel_3", Value(true)));
  ASSERT_TRUE(handle->write(Value(true)));
  EXPECT_EQ(*out.read_input("channel_2"), Value(true));
  ASSERT_TRUE(out.request(wire::AlState::preop));
  auto reconfigured = out.configure(test::quick_slave("outputs"));
  ASSERT_TRUE(reconfigured) << reconfigured.error().describe();
  ASSERT_TRUE(out.request(wire::AlState::op));
  // Both stayed staged, and the handle's reaches the input wired to it.
  const auto signals = out.signals();
  for (const char* name : {"channel_2", "channel_3"}) {
    const Signal* sig = find(signals, name);
    ASSERT_NE(sig, nullptr);
    EXPECT_EQ(*decode_scaled(*sig, r.image_of(out, *sig)), Value(true)) << name;
  }
  EXPECT_TRUE(eventually([&] {
    auto v = in.read_input("channel_2");
    return v && *v == Value(true);
  }));
  ASSERT_TRUE(handle->write(Value(false)));
  EXPECT_EQ(*out.read_input("channel_2"), Value(false));
  EXPECT_EQ(*out.read_input("channel_3"), Value(true));
}

}  // namespace
}  // namespace ecat::master
