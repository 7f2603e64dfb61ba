// Master-layer tests against the simulator: a bench (simulated ring served over a memory link, a
// Bus, an EventLoop run by the test thread) and the minimal bring-up a test needs before it can
// use a slave's mailbox: station addresses, SII mailbox words, SM0/SM1, PREOP.
//
//   auto bench = test::SimBench::make(R"(version: 1
//   simulator:
//     slaves:
//       - {name: drive, profile: servo}
//   )");
//   auto mailbox = bench->run(test::bring_to_preop(bench->loop, *bench->bus, 0x1001));
#pragma once

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/master/events.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master::test {

using namespace std::chrono_literals;

constexpr std::uint16_t kFirstStation = 0x1001;

inline std::uint16_t station_at(std::size_t position) {
  return static_cast<std::uint16_t>(kFirstStation + position);
}

// The simulated ring a YAML text describes (not serving yet); a test failure and null when the
// ring does not build.
// EK1100 + EL1809 + EL2809: the simulated ring most master tests drive.
inline constexpr const char* kTerminalRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
)";

// kTerminalRing with a CiA 402 servo drive behind it, the outputs' channel 2 wired back to the
// inputs' channel 2: the ring of the hot-path and allocation tests.
inline constexpr const char* kDriveRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: drive, profile: servo}
  wiring:
    - {from: outputs.channel_2, to: inputs.channel_2}
)";

// A slave of kTerminalRing's kind: process data in domain "main" (unless not wanted), health
// polled every 20 ms.
inline SlaveConfig quick_slave(std::string name, bool process_data = true,
                               TargetState target = TargetState::op) {
  SlaveConfig c;
  c.name = std::move(name);
  if (process_data) c.process_data = ProcessDataRequest::all("main");
  c.target = target;
  c.health_poll = std::chrono::milliseconds(20);
  return c;
}

// A configuration for sessions against the simulator: quick scans and retries, a frame timeout a
// loaded machine's simulator thread keeps (the tuned one may be too short), no DC, one domain
// "main" of `period` (3 invalid cycles make it a critical fault), and kTerminalRing's slaves at
// `target`. Tests change what they need beyond this.
inline MasterConfig quick_config(std::chrono::nanoseconds period = std::chrono::milliseconds(2),
                                 TargetState target = TargetState::op) {
  using namespace std::chrono_literals;
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 5s};
  config.awaiting_preop_timeout = 10s;
  config.retry_interval = 50ms;
  config.slave_retry_interval = 50ms;
  config.frame_timeout = 20ms;
  config.dc.reset();
  DomainConfig main;
  main.id = "main";
  main.period = period;
  main.recovery_threshold = 3;
  config.domains.push_back(main);
  config.slaves = {quick_slave("coupler", false, target), quick_slave("inputs", true, target),
                   quick_slave("outputs", true, target)};
  return config;
}

inline std::unique_ptr<sim::SimServer> make_sim_server(std::string_view ring_yaml) {
  auto ring = sim::parse_ring(ring_yaml);
  if (!ring) {
    ADD_FAILURE() << ring.error().describe();
    return nullptr;
  }
  auto server = sim::make_server(*ring);
  if (!server) {
    ADD_FAILURE() << server.error().describe();
    return nullptr;
  }
  return std::move(*server);
}

// The server's ring with a second master port (sim::RedundantPorts, in process) and a
// RedundantLink on both ports. `ports` must outlive `link`; both null after a failure (reported).
struct RedundantRig {
  std::unique_ptr<sim::RedundantPorts> ports;
  std::unique_ptr<link::RedundantLink> link;
};

inline RedundantRig open_redundant_link(sim::SimServer& server) {
  sim::RedundantPortsOptions options;
  auto ports = sim::RedundantPorts::create(server, options);
  if (!ports) {
    ADD_FAILURE() << ports.error().describe();
    return {};
  }
  link::RedundantLinkOptions link_options;
  link_options.primary_mac = options.primary_mac;
  link_options.secondary_mac = options.secondary_mac;
  auto link =
      link::RedundantLink::open((*ports)->take_link(wire::RedundantPort::primary),
                                (*ports)->take_link(wire::RedundantPort::secondary), link_options);
  if (!link) {
    ADD_FAILURE() << link.error().describe();
    return {};
  }
  return {std::move(*ports), std::move(*link)};
}

class SimBench {
 public:
  // The ring (YAML text) served over an in-process memory link.
  static std::unique_ptr<SimBench> make(std::string_view ring_yaml, bus::BusOptions options = {}) {
    auto server = make_sim_server(ring_yaml);
    if (!server) return nullptr;
    return start(std::move(server), std::move(options));
  }
  // A segment built by the test (custom ESC hardware, hand-made EEPROMs).
  static std::unique_ptr<SimBench> make(std::unique_ptr<sim::Segment> segment,
                                        bus::BusOptions options = {}) {
    return start(std::make_unique<sim::SimServer>(std::move(segment)), std::move(options));
  }

  ~SimBench() {
    if (bus) bus->stop();
    if (server) server->stop();
  }

  // Runs the loop on this thread until `task` finished; aborts the test binary when it does not
  // finish within `limit` (its frame would still reference the test's state).
  template <class T>
  T run(exec::Task<T> task, std::chrono::nanoseconds limit = 20s) {
    std::optional<T> result;
    exec::spawn(loop, std::move(task), [&](T&& value) {
      result.emplace(std::move(value));
      loop.stop();
    });
    const auto watchdog = loop.call_after(limit, [this] { loop.stop(); });
    loop.run();
    loop.cancel(watchdog);
    loop.reset();
    if (!result) {
      ADD_FAILURE() << "task did not finish within " << std::chrono::duration<double>(limit).count()
                    << " s";
      std::abort();
    }
    return std::move(*result);
  }

  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<bus::Bus> bus;
  exec::EventLoop loop;

 private:
  static std::unique_ptr<SimBench> start(std::unique_ptr<sim::SimServer> server,
                                         bus::BusOptions options) {
    auto bench = std::make_unique<SimBench>();
    auto link = server->serve_memory();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return nullptr;
    }
    bench->server = std::move(server);
    bench->bus = std::make_unique<bus::Bus>(std::move(*link), std::move(options));
    if (auto started = bench->bus->start(); !started) {
      ADD_FAILURE() << started.error().describe();
      return nullptr;
    }
    return bench;
  }
};

// APWR 0x0010 = kFirstStation + position for positions 0..count-1, in one transaction.
inline exec::Task<Result<void>> assign_stations(exec::EventLoop& loop, bus::Bus& bus,
                                                std::size_t count) {
  bus::Transaction tx;
  for (std::size_t position = 0; position < count; ++position) {
    const std::uint16_t station = station_at(position);
    const std::uint8_t bytes[2] = {static_cast<std::uint8_t>(station),
                                   static_cast<std::uint8_t>(station >> 8)};
    tx.apwr(static_cast<std::uint16_t>(position), wire::reg::kStationAddress, bytes, 1);
  }
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error();
  co_return ok();
}

// AL control = `state`, then AL status polled until it shows `state` (or an error).
inline exec::Task<Result<void>> request_state(exec::EventLoop& loop, bus::Bus& bus,
                                              std::uint16_t station, wire::AlState state,
                                              std::chrono::nanoseconds limit = 2s) {
  const std::uint16_t control = wire::encode_al_control(state);
  const std::uint8_t bytes[2] = {static_cast<std::uint8_t>(control),
                                 static_cast<std::uint8_t>(control >> 8)};
  bus::Transaction write;
  write.fpwr(station, wire::reg::kAlControl, bytes, 1);
  auto written = co_await exec::transact(loop, bus, std::move(write));
  if (!written) co_return written.error();
  const auto deadline = exec::Clock::now() + limit;
  for (;;) {
    bus::Transaction read;
    read.fprd(station, wire::reg::kAlStatus, 6, 1);
    auto status = co_await exec::transact(loop, bus, std::move(read));
    if (!status) co_return status.error();
    const auto data = status->data(0);
    if ((data[0] & 0x0F) == static_cast<std::uint8_t>(state)) co_return ok();
    if ((data[0] & 0x10) != 0) {
      co_return Error(
          Errc::al_error,
          fmt::format("slave {:#06x} refused AL state {:#x}: AL status {:#04x}, code "
                      "{:#06x}",
                      station, static_cast<unsigned>(state), data[0], wire::load_le16(&data[4])));
    }
    if (exec::Clock::now() >= deadline) {
      co_return Error(Errc::timeout, fmt::format("slave {:#06x} did not reach AL state {:#x}",
                                                 station, static_cast<unsigned>(state)));
    }
    co_await exec::sleep_for(loop, 1ms);
  }
}

// The SII's standard mailbox (words 0x18..0x1B, read with read_sii_words) written into SM0/SM1
// (upstream-inventory §3.5: both off, both configured, both on, in one transaction).
inline exec::Task<Result<MailboxConfig>> configure_mailbox(exec::EventLoop& loop, bus::Bus& bus,
                                                           std::uint16_t station) {
  auto words = co_await read_sii_words(loop, bus, station, wire::sii_word::kStandardMailbox, 4);
  if (!words) co_return words.error();
  MailboxConfig config;
  config.out_offset = wire::load_le16(&(*words)[0]);
  config.out_size = wire::load_le16(&(*words)[2]);
  config.in_offset = wire::load_le16(&(*words)[4]);
  config.in_size = wire::load_le16(&(*words)[6]);
  if (config.out_size == 0 || config.in_size == 0) {
    co_return Error(Errc::unsupported, fmt::format("slave {:#06x} has no mailbox", station));
  }
  auto sm = [](std::uint16_t start, std::uint16_t length, std::uint8_t control) {
    return std::vector<std::uint8_t>{static_cast<std::uint8_t>(start),
                                     static_cast<std::uint8_t>(start >> 8),
                                     static_cast<std::uint8_t>(length),
                                     static_cast<std::uint8_t>(length >> 8),
                                     control,
                                     0,
                                     0,
                                     0};
  };
  const auto sm0 = sm(config.out_offset, config.out_size, 0x26);
  const auto sm1 = sm(config.in_offset, config.in_size, 0x22);
  const std::uint8_t off = 0;
  const std::uint8_t on = 1;
  const auto sm0_base = wire::reg::sync_manager(0);
  const auto sm1_base = wire::reg::sync_manager(1);
  bus::Transaction tx;
  tx.fpwr(station, static_cast<std::uint16_t>(sm0_base + 6), wire::Bytes(&off, 1), 1);
  tx.fpwr(station, static_cast<std::uint16_t>(sm1_base + 6), wire::Bytes(&off, 1), 1);
  tx.fpwr(station, sm0_base, sm0, 1);
  tx.fpwr(station, sm1_base, sm1, 1);
  tx.fpwr(station, static_cast<std::uint16_t>(sm0_base + 6), wire::Bytes(&on, 1), 1);
  tx.fpwr(station, static_cast<std::uint16_t>(sm1_base + 6), wire::Bytes(&on, 1), 1);
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error();
  co_return config;
}

// Mailbox configured and PREOP requested and reached.
inline exec::Task<Result<MailboxConfig>> bring_to_preop(exec::EventLoop& loop, bus::Bus& bus,
                                                        std::uint16_t station) {
  auto config = co_await configure_mailbox(loop, bus, station);
  if (!config) co_return config.error();
  auto preop = co_await request_state(loop, bus, station, wire::AlState::preop);
  if (!preop) co_return preop.error();
  co_return *config;
}

// Stations assigned to all `count` slaves, then every one of them brought to PREOP at once.
inline exec::Task<Result<std::vector<MailboxConfig>>> bring_all_to_preop(exec::EventLoop& loop,
                                                                         bus::Bus& bus,
                                                                         std::size_t count) {
  auto assigned = co_await assign_stations(loop, bus, count);
  if (!assigned) co_return assigned.error();
  std::vector<exec::Task<Result<MailboxConfig>>> tasks;
  for (std::size_t i = 0; i < count; ++i)
    tasks.push_back(bring_to_preop(loop, bus, station_at(i)));
  auto results = co_await exec::when_all(loop, std::move(tasks));
  std::vector<MailboxConfig> configs;
  for (auto& r : results) {
    if (!r) co_return r.error();
    configs.push_back(*r);
  }
  co_return configs;
}

// A built-in profile's SII image changed by `edit`, written to a temporary file for the `eeprom`
// profile (removed by the caller); empty (and a test failure) when something does not work.
inline std::filesystem::path edited_eeprom(const std::string& profile, const std::string& tag,
                                           const std::function<void(wire::SiiImage&)>& edit) {
  sim::DeviceConfig device;
  device.profile = profile;
  auto template_esc = sim::make_device(device);
  if (!template_esc) {
    ADD_FAILURE() << template_esc.error().describe();
    return {};
  }
  const auto eeprom = (*template_esc)->eeprom();
  auto decoded = wire::decode_sii(wire::Bytes(eeprom.data(), eeprom.size()));
  if (!decoded) {
    ADD_FAILURE() << decoded.error().describe();
    return {};
  }
  auto image = decoded->image;
  edit(image);
  auto encoded = wire::encode_sii(image);
  if (!encoded) {
    ADD_FAILURE() << encoded.error().describe();
    return {};
  }
  const auto file =
      std::filesystem::temp_directory_path() / fmt::format("ecat-{}-{}.bin", tag, ::getpid());
  std::ofstream(file, std::ios::binary)
      .write(reinterpret_cast<const char*>(encoded->data()),
             static_cast<std::streamsize>(encoded->size()));
  return file;
}

// Collects a master's events; waits for one that matches.
class EventRecorder {
 public:
  explicit EventRecorder(Master& master) : master_(master) {
    id_ = master.subscribe_events([this](const Event& e, std::uint64_t missed) {
      std::lock_guard lock(mutex_);
      missed_ += missed;
      events_.push_back(e);
      cv_.notify_all();
    });
  }
  ~EventRecorder() { master_.unsubscribe_events(id_); }
  EventRecorder(const EventRecorder&) = delete;
  EventRecorder& operator=(const EventRecorder&) = delete;

  template <class Predicate>
  bool wait_for(Predicate predicate, std::chrono::nanoseconds timeout = 10s) {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, timeout,
                        [&] { return std::any_of(events_.begin(), events_.end(), predicate); });
  }
  bool saw(EventKind kind, std::string_view name = {}, std::string_view from = {},
           std::string_view to = {}) {
    return wait_for([&](const Event& e) {
      return e.kind == kind && (name.empty() || e.name() == name) &&
             (from.empty() || e.from_name() == from) && (to.empty() || e.to_name() == to);
    });
  }
  std::vector<Event> events() {
    std::lock_guard lock(mutex_);
    return events_;
  }
  std::uint64_t missed() {
    std::lock_guard lock(mutex_);
    return missed_;
  }
  std::string dump() {
    std::string out;
    for (const auto& e : events())
      out += describe(e) + "\n";
    return out;
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Event> events_;
  std::uint64_t missed_ = 0;
  Master& master_;
  EventSubscriptionId id_ = 0;
};

}  // namespace ecat::master::test
