// The state one master session shares between the Master, its slaves and its domains. Private to
// src/master. Owned through shared_ptr: every coroutine of the session holds a reference, so
// nothing it touches is destroyed while it is suspended; stop() sets `stopping`, stops the bus
// (which completes everything in flight) and lets the tasks run out.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/async_mutex.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/master/startup.hpp>
#include <ecat/wire/registers.hpp>

#include "master/cycle_thread.hpp"
#include "master/event_hub.hpp"

namespace ecat::master {

// What a slave tells its master (on the control loop).
struct SlaveNotice {
  enum class Kind : std::uint8_t { retreated, down, reconnected };
  Kind kind = Kind::down;
  std::string slave;
  std::string detail;
};

// A hot-connect group of the session (MasterConfig::hot_connect[index]). The loop writes; the
// fields a status reads are written under the master's mutex.
struct HotConnectRuntime {
  std::size_t index = 0;
  std::string name;
  std::vector<Slave*> slaves;
  std::vector<std::pair<Domain*, std::uint32_t>> reservations;  // domain, reservation
  HotConnectState state = HotConnectState::absent;
  std::optional<std::uint16_t> position;
  std::string detail;
  std::uint64_t appearances = 0;
  std::uint64_t losses = 0;
  std::optional<std::chrono::nanoseconds> last_join;
  exec::Clock::time_point retry_after{};  // a failed join is tried again from then on
  // Since when the group's first slave is in the ring without all the others (hot_connect_scan).
  std::optional<exec::Clock::time_point> short_since;
};

struct Session : std::enable_shared_from_this<Session> {
  Session(exec::EventLoop& control_loop, MasterConfig master_config)
      : loop(control_loop), config(std::move(master_config)) {}

  exec::EventLoop& loop;
  MasterConfig config;
  std::unique_ptr<bus::Bus> bus;
  std::unique_ptr<Cycler> cycler;
  // Distributed clocks (when configured and a DC-capable slave was found). dc_init and dc_error
  // are written on the loop at startup; `dc` is created at the first activation, published under
  // the master's mutex, and removed from the cycler before it goes (it is declared after it).
  std::optional<DcInitResult> dc_init;
  std::optional<Error> dc_error;
  std::unique_ptr<DcMaintainer> dc;
  std::vector<std::unique_ptr<Domain>> domains;
  std::vector<std::unique_ptr<Slave>> slaves;
  // The configuration's (MasterConfig::drivers), fixed for the session.
  DriverRegistry drivers = config.drivers;
  std::uint16_t slave_count = 0;
  std::vector<wire::DlStatus> dl_status;
  // On a redundant link, what else the start-up read of the ring (by ring position, as
  // dl_status): the slaves the primary's frame processed, and the port descriptors (0x0007;
  // none where unanswered). The link watch builds a ring broken since start's shape from them.
  std::optional<RingSides> start_sides;
  std::vector<std::optional<wire::PortDescriptor>> port_descriptors;
  // Hot connect: the fixed slaves end before this position; the groups follow it.
  std::uint16_t fixed_end = 0;
  std::vector<HotConnectRuntime> hot_connect;
  // Startup: the station at each ring position, and whether a hot-connect group sat in front of
  // fixed slaves (place_at_start): then the fixed slaves' positions are not their indices.
  std::vector<std::uint16_t> start_ring_stations;
  bool groups_in_front = false;
  // Hot connect on junction ports (docs/ARCHITECTURE.md "Hot connect", DC): a port of a fixed
  // slave where a group plugged in would delay the fixed DC slaves behind it (`behind`, later in
  // frame order) is set to auto close at startup; the hot-connect watch opens it (`open`) when a
  // link comes up behind it and the delays are measured again at once. Loop thread.
  struct JunctionPort {
    std::uint16_t owner = 0;  // the fixed slave's station
    std::uint8_t port = 0;    // 1, 2 or 3
    std::vector<std::uint16_t> behind;
    bool open = false;  // a group behind it, let in (or in at start)
  };
  std::vector<JunctionPort> junction_ports;
  bool junction_watching = false;     // watch_junctions under way
  bool junction_watch_again = false;  // ... and asked for again meanwhile
  bool dc_adapting = false;           // a group left: the DC delays are being measured again (loop)
  bool dc_adapt_again = false;        // another left meanwhile: measure once more after this one
  std::uint16_t hot_connect_scratch = 0;             // the station a candidate is read at
  std::string hot_connect_refused;                   // the last device that matched no group
  std::uint16_t hot_connect_refused_count = 0;       // ... at this slave count
  exec::Clock::time_point hot_connect_refused_at{};  // looked at again after retry_interval
  std::uint16_t hot_connect_seen_count = 0;          // the slave count at the last poll
  std::uint16_t hot_connect_located_count = 0;  // ... when the stations were last read by position
  std::atomic<bool> stopping{false};
  // Position-addressed accesses after startup (transact_by_position), one at a time: on a
  // redundant ring they share the link's addressing selector. Loop thread.
  exec::AsyncMutex position_access{loop};
  // What the cycle thread's CycleThreadOptions came to (written once by the bus thread), and
  // what it holds for the session (cpu_dma_latency, the memory lock; written by the bus thread at
  // its start, released when the session goes).
  std::mutex report_mutex;
  std::string cycle_thread_report;
  CycleThreadHolds cycle_thread_holds;
  // Health polls pause while the session is held in PREOP since startup (until activation).
  std::atomic<bool> health_held{false};
  // Set by the master: slaves report here (called on the loop).
  std::function<void(const SlaveNotice&)> notify;
  // The master's event stream (outlives every session of the master).
  EventHub* events = nullptr;
  // One activation at a time (Master::Impl::run_activation); loop thread.
  bool activation_running = false;
  bool activation_again = false;

  Domain* find_domain(std::string_view id) const noexcept {
    for (const auto& d : domains) {
      if (d->id() == id) return d.get();
    }
    return nullptr;
  }
  Slave* find_slave(std::string_view name) const noexcept {
    for (const auto& s : slaves) {
      if (s->name() == name) return s.get();
    }
    return nullptr;
  }
};

}  // namespace ecat::master
