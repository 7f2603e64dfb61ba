#include <algorithm>
#include <array>
#include <atomic>
#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>

#include <ecat/exec/quiesce.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/ipc/line_server.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/mailbox_gateway.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/ring_break.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/master/startup.hpp>

#include "cycle_thread.hpp"
#include "dynamic_names.hpp"
#include "hot_connect_identity.hpp"
#include "session.hpp"
#include "slave_access.hpp"

namespace ecat::master {

using namespace std::chrono_literals;
using detail::SlaveAccess;

namespace {

constexpr auto kCallTimeout = 5s;
// The quiet window of the reference's quiesce before preop_ready and before activation.
constexpr auto kQuietWindow = 2ms;
// The ceiling a session with the auto-tuned frame timeout lets reliable frames grow to after late
// replies (BusOptions::adaptive_frame_timeout_limit).
constexpr auto kAdaptiveFrameTimeoutLimit = std::chrono::milliseconds(250);

std::chrono::milliseconds ms(std::chrono::nanoseconds d) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(d);
}

}  // namespace

std::string_view to_string(HotConnectState state) noexcept {
  switch (state) {
    case HotConnectState::absent:
      return "absent";
    case HotConnectState::joining:
      return "joining";
    case HotConnectState::present:
      return "present";
    case HotConnectState::failed:
      return "failed";
  }
  return "unknown";
}

namespace {

wire::AlState min_target(TargetState session_target, TargetState slave_target) {
  return al_state_of(std::min(session_target, slave_target));
}

// Thread names tell the masters of a process apart (ps, top, perf): the first master alive has
// "ecat-control" and "ecat-cycle", one made while it lives "ecat-control-2" and "ecat-cycle-2",
// and so on (the lowest number free).
std::mutex instance_mutex;
std::vector<bool> instances_used;

int acquire_instance() {
  std::lock_guard lock(instance_mutex);
  std::size_t i = 0;
  while (i < instances_used.size() && instances_used[i])
    ++i;
  if (i == instances_used.size()) instances_used.push_back(false);
  instances_used[i] = true;
  return static_cast<int>(i) + 1;
}

void release_instance(int n) {
  std::lock_guard lock(instance_mutex);
  instances_used[static_cast<std::size_t>(n - 1)] = false;
}

std::string thread_name(std::string_view base, int instance) {
  return instance == 1 ? std::string(base) : fmt::format("{}-{}", base, instance);
}

}  // namespace

struct Master::Impl : DomainObserver {
  explicit Impl(MasterConfig c) : config(std::move(c)), instance(acquire_instance()) {
    for (auto& n : notices)
      n.impl = this;
    loop.start_thread(thread_name("ecat-control", instance));
  }
  ~Impl() override {
    shutdown();
    loop.stop();
    loop.join();
    release_instance(instance);
  }

  MasterConfig config;
  const int instance;  // 1, 2, ...: numbers the threads' names (acquire_instance)
  EventHub events;     // before the loop: it outlives every task that publishes

  // A domain's rare notices (degraded, recovered, stopped) go from the bus thread to the loop
  // through a fixed pool of work items posted with EventLoop::post(Work&): nothing on the bus
  // thread allocates (a std::function post would). A notice is taken from the pool with one
  // compare-exchange (any thread may take one), filled, posted; the loop copies it out and frees
  // it before acting, in posting order. Should every item be in use at once (32 notices queued
  // and the loop not yet at the first), the notice is dropped, `notices_lost` is set and the loop
  // then re-reads every cycling domain's health instead. Declared before the loop: a notice
  // still queued when the loop goes is discarded while the pool still exists.
  struct DomainNotice final : exec::EventLoop::Work {
    enum class Kind : std::uint8_t { degraded, recovered, stopped };
    DomainNotice() noexcept : Work(&DomainNotice::run) {}
    static void run(Work& self, bool execute) {
      auto& n = static_cast<DomainNotice&>(self);
      const Domain* domain = n.domain;
      const Kind kind = n.kind;
      const CycleInvalid invalid = n.invalid;
      const std::uint64_t misses = n.misses;
      n.busy.store(false, std::memory_order_release);
      if (execute) n.impl->on_domain_notice(domain, kind, invalid, misses);
    }
    Impl* impl = nullptr;
    std::atomic<bool> busy{false};
    const Domain* domain = nullptr;
    Kind kind = Kind::degraded;
    CycleInvalid invalid{};
    std::uint64_t misses = 0;
  };
  std::array<DomainNotice, 32> notices;
  std::atomic<bool> notices_lost{false};

  // The control endpoint (control_endpoint.hpp): from the first start() whose configuration
  // names one until the master goes (or a start() names another). Its handler calls the
  // Master's public API, so ~Master closes it before anything else goes.
  struct Endpoint {
    std::unique_ptr<ipc::LineServer> server;
    ControlEndpointConfig config;
    EventSubscriptionId events = 0;
  };
  Endpoint endpoint;
  std::mutex endpoint_mutex;  // start() and ~Master (application threads)

  Result<void> open_endpoint(Master& master) {
    std::lock_guard lock(endpoint_mutex);
    const ControlEndpointConfig& want = config.control;
    if (endpoint.server && want.name == endpoint.config.name && want.mode == endpoint.config.mode &&
        want.allow_writes == endpoint.config.allow_writes &&
        want.flight_recorder == endpoint.config.flight_recorder) {
      return ok();
    }
    close_endpoint_locked();
    if (want.name.empty()) return ok();
    const ControlAccess access{want.allow_writes, want.flight_recorder};
    auto started = ipc::LineServer::start(
        control_socket_path(want.name),
        [&master, access](std::string_view line, const ipc::Peer&) {
          bool follow = false;
          std::string reply = handle_control_request(master, line, access, &follow);
          return ipc::Reply{std::move(reply), follow};
        },
        // The server's own refusals (fixed texts without quotes): too many clients, or a line
        // beyond the limit.
        [](std::string_view message) {
          const bool busy = message.starts_with("too many");
          return fmt::format(R"({{"ok":false,"error":"{}","code":"{}"}})", message,
                             busy ? "busy" : "out_of_range");
        },
        // Requests may carry a firmware image in hex (foe.write, sii.write): lines up to 32 MiB
        // (16 MiB of file); replies up to 40 MiB (capture.frames: 16 MiB of frames); at most 16
        // clients: bounded, if large, in the worst case.
        {.mode = want.mode,
         .max_line = 32u << 20,
         .max_pending_output = 40u << 20,
         .what = "master"});
    if (!started) {
      return started.error().context(
          started.error().code(),
          fmt::format("opening the control endpoint '{}' (master: control:)", want.name));
    }
    endpoint.server = std::move(*started);
    endpoint.config = want;
    ipc::LineServer* server = endpoint.server.get();
    endpoint.events = events.subscribe([server](const Event& e, std::uint64_t missed) {
      if (missed != 0) {
        server->publish(fmt::format(R"({{"event":"events.missed","count":{}}})", missed));
      }
      server->publish(event_json(e));
    });
    return ok();
  }

  void close_endpoint_locked() {
    if (!endpoint.server) return;
    (void)events.unsubscribe(endpoint.events);
    endpoint.server->stop();
    endpoint.server.reset();
    endpoint.config = {};
  }

  void close_endpoint() {
    std::lock_guard lock(endpoint_mutex);
    close_endpoint_locked();
  }

  // The mailbox gateway (mailbox_gateway.hpp): like the endpoint, from the first start() whose
  // configuration enables it until the master goes (or a start() configures another). Its
  // workers call the Master's public API, so ~Master stops it before anything else goes.
  std::unique_ptr<MailboxGateway> gateway;
  mutable std::mutex gateway_mutex;

  Result<void> open_gateway(Master& master) {
    std::lock_guard lock(gateway_mutex);
    const MailboxGatewayConfig& want = config.mailbox_gateway;
    if (gateway) {
      const MailboxGatewayConfig& have = gateway->config();
      if (want.enabled && want.address == have.address && want.port == have.port &&
          want.request_timeout == have.request_timeout && want.max_queued == have.max_queued &&
          want.workers == have.workers) {
        return ok();
      }
      gateway->stop();
      gateway.reset();
    }
    if (!want.enabled) return ok();
    auto started = MailboxGateway::start(master, want);
    if (!started) {
      return started.error().context(started.error().code(),
                                     "opening the mailbox gateway (master: mailbox_gateway:)");
    }
    gateway = std::move(*started);
    return ok();
  }

  void close_gateway() {
    std::lock_guard lock(gateway_mutex);
    if (gateway) gateway->stop();
    gateway.reset();
  }
  exec::EventLoop loop;
  std::shared_ptr<Session> session;  // loop thread writes; guarded by `mutex` for readers

  mutable std::mutex mutex;
  std::condition_variable changed;
  MasterState state = MasterState::idle;
  TargetState desired = TargetState::op;
  std::optional<Error> startup_error;     // why the last startup ended in idle
  std::optional<Error> ended_error;       // why the last session ended by itself (link lost)
  std::optional<Error> activation_error;  // why activation is blocked
  std::map<std::string, ActivationFailure> activation_failures;
  std::map<std::string, std::string> runtime_faults;
  std::optional<Failure> last;
  std::uint64_t refused_transitions = 0;
  std::string last_refused_transition;  // "from -> to" of the last one
  std::function<void(MasterState, MasterState)> on_change;
  std::atomic<bool> inputs_pending{false};
  std::atomic<bool> retry_armed{false};

  // ---- state -------------------------------------------------------------------------------

  // Changes the state along the seed diagram. A change the diagram does not draw is a bug: it
  // is refused and counted (tests check the count stays 0).
  bool transition(MasterState to) {
    MasterState from;
    std::function<void(MasterState, MasterState)> cb;
    {
      std::lock_guard lock(mutex);
      from = state;
      if (from == to) return true;
      if (!master_transition_allowed(from, to)) {
        ++refused_transitions;
        last_refused_transition = fmt::format("{} -> {}", to_string(from), to_string(to));
        return false;
      }
      state = to;
      cb = on_change;
    }
    Event e = make_event(EventKind::master_state);
    e.from = static_cast<std::uint8_t>(from);
    e.to = static_cast<std::uint8_t>(to);
    events.publish(e);
    if (cb) cb(from, to);
    changed.notify_all();
    return true;
  }

  MasterState current() const {
    std::lock_guard lock(mutex);
    return state;
  }

  void fail(std::string kind, const Error& error) {
    std::lock_guard lock(mutex);
    last = Failure{std::move(kind), error, std::chrono::system_clock::now()};
  }

  // ---- startup -----------------------------------------------------------------------------

  // The configured slaves with their ring positions: an entry with an alias is the slave whose
  // configured station alias (0x0012, from its SII) it is, wherever it sits; an entry without a
  // position is the slave after the previous entry's. `aliases` is by position (empty when no
  // entry uses an alias).
  Result<std::vector<SlaveConfig>> effective_slaves(
      std::uint16_t count, const std::vector<std::uint16_t>& aliases) const {
    std::vector<SlaveConfig> out;
    if (config.slaves.empty()) {
      for (std::uint16_t pos = 0; pos < count; ++pos) {
        SlaveConfig c;
        c.name = fmt::format("slave_{}", pos);  // positional; run_startup names couplers
        c.target = TargetState::preop;
        c.position = pos;
        out.push_back(std::move(c));
      }
      return out;
    }
    int next = 0;
    for (const auto& configured : config.slaves) {
      SlaveConfig c = configured;
      if (c.alias) {
        std::optional<std::uint16_t> found;
        for (std::size_t pos = 0; pos < aliases.size(); ++pos) {
          if (aliases[pos] != *c.alias) continue;
          if (found) {
            return Error(Errc::invalid_argument,
                         fmt::format("slave {}: station alias 0x{:04x} is held by the slaves at "
                                     "positions {} and {}",
                                     c.name, *c.alias, *found, pos));
          }
          found = static_cast<std::uint16_t>(pos);
        }
        if (!found) {
          return Error(Errc::not_found,
                       fmt::format("slave {}: no slave in the ring has station alias 0x{:04x}",
                                   c.name, *c.alias));
        }
        if (c.position && *c.position != *found) {
          return Error(Errc::invalid_argument,
                       fmt::format("slave {}: configured at position {}, but station alias "
                                   "0x{:04x} is at position {}",
                                   c.name, *c.position, *c.alias, *found));
        }
        c.position = *found;
      }
      if (!c.position) c.position = static_cast<std::uint16_t>(next);
      next = *c.position + 1;
      if (*c.position >= count) {
        return Error(Errc::invalid_argument,
                     fmt::format("slave {} is configured at position {}, the ring has {} slaves",
                                 c.name, *c.position, count));
      }
      out.push_back(std::move(c));
    }
    return out;
  }

  // Configured station aliases (0x0012) by position.
  exec::Task<Result<std::vector<std::uint16_t>>> read_aliases(Session& s, std::uint16_t count) {
    bus::Transaction tx;
    for (std::uint16_t pos = 0; pos < count; ++pos) {
      tx.fprd(static_cast<std::uint16_t>(s.config.base_station + pos), wire::reg::kStationAlias, 2,
              1);
    }
    auto reply = co_await exec::transact(loop, *s.bus, std::move(tx));
    if (!reply) co_return reply.error().context("reading the station aliases (0x0012)");
    std::vector<std::uint16_t> out;
    for (std::uint16_t pos = 0; pos < count; ++pos)
      out.push_back(wire::load_le16(reply->data(pos).data()));
    co_return out;
  }

  // Startup with more slaves in the ring than fixed ones and hot-connect groups configured: the
  // alias and SII identity at every position (stations base + position, just assigned), and
  // place_at_start says whether a group sits in front of fixed slaves. If so, the stations are
  // assigned again: the fixed slaves base + their index, everyone else after them in ring order.
  // Returns the ring position of the slave at base + k (empty: nothing in front, k itself).
  exec::Task<Result<std::vector<std::uint16_t>>> place_groups_at_start(Session& s,
                                                                       std::uint16_t count) {
    const auto base = s.config.base_station;
    auto aliases = co_await read_aliases(s, count);
    if (!aliases) co_return aliases.error();
    std::vector<exec::Task<Result<std::vector<std::uint8_t>>>> reads;
    for (std::uint16_t pos = 0; pos < count; ++pos)
      reads.push_back(read_sii_words(loop, *s.bus, static_cast<std::uint16_t>(base + pos), 8, 6));
    auto words = co_await exec::when_all(loop, std::move(reads));
    std::vector<StartSlave> ring(count);
    for (std::uint16_t pos = 0; pos < count; ++pos) {
      if (!words[pos]) {
        co_return words[pos].error().context(
            fmt::format("reading the identity at position {} (hot-connect groups at start)", pos));
      }
      auto id = decode_found_identity(*words[pos]);
      if (!id) co_return std::vector<std::uint16_t>{};
      ring[pos] = {(*aliases)[pos], *id};
    }
    auto placed = place_at_start(s.config.slaves, s.config.hot_connect, ring);
    if (!placed) co_return std::vector<std::uint16_t>{};
    std::vector<std::uint16_t> order = placed->fixed;  // station index -> position
    std::vector<bool> taken(count, false);
    for (const auto p : order)
      taken[p] = true;
    for (std::uint16_t pos = 0; pos < count; ++pos) {
      if (!taken[pos]) order.push_back(pos);
    }
    bus::Transaction assign;
    for (std::uint16_t k = 0; k < count; ++k)
      assign.apwr(order[k], wire::reg::kStationAddress, le16(static_cast<std::uint16_t>(base + k)));
    // On a ring already broken at start, each through the frame that reaches its position.
    auto assigned = co_await transact_by_position(loop, *s.bus, s.position_access,
                                                  std::move(assign), bus::TransactOptions{});
    if (!assigned)
      co_return assigned.error().context("assigning stations around a hot-connect group");
    for (std::uint16_t k = 0; k < count; ++k) {
      if ((*assigned)[k].wkc != 1) {
        co_return Error(Errc::wkc_mismatch,
                        fmt::format("assigning station 0x{:04x} to position {}: working counter {}",
                                    base + k, order[k], (*assigned)[k].wkc));
      }
    }
    s.groups_in_front = true;
    std::string where;
    for (const auto& [g, at] : placed->groups) {
      where += fmt::format("{}{} at position {}", where.empty() ? "" : ", ",
                           s.config.hot_connect[g].name, at);
    }
    events.publish(make_event(EventKind::recovery_step, "hotconnect",
                              fmt::format("plugged at start in front of fixed slaves: {}; the "
                                          "fixed slaves are placed around it",
                                          where)));
    co_return order;
  }

  exec::Task<Result<void>> bring_up_with_retry(std::shared_ptr<Session> s, Slave& slave,
                                               exec::Clock::time_point deadline) {
    std::optional<Error> last_error;
    while (!s->stopping) {
      auto up = co_await SlaveAccess::bring_up(slave, s);
      // Readable while the session waits: a caller that gives up early can say why.
      SlaveAccess::set_startup_error(
          slave, up ? std::nullopt : std::optional<std::string>(up.error().describe()));
      if (up) {
        SlaveAccess::start_health(slave, s);
        co_return ok();
      }
      last_error = up.error();
      if (exec::Clock::now() + s->config.slave_retry_interval >= deadline) break;
      co_await exec::sleep_for(s->loop, s->config.slave_retry_interval);
      SlaveAccess::note_retry_in_init(slave);
    }
    if (s->stopping) co_return Error(Errc::closed, "session stopped");
    co_return last_error->context(fmt::format("slave {} did not reach PREOP within {} ms",
                                              slave.name(),
                                              ms(s->config.awaiting_preop_timeout).count()));
  }

  exec::Task<void> startup(std::shared_ptr<Session> s) {
    auto result = co_await run_startup(s);
    if (s->stopping || session != s) co_return;
    if (!result) {
      {
        std::lock_guard lock(mutex);
        startup_error = result.error();
      }
      const bool awaiting = current() == MasterState::awaiting_preop;
      fail(awaiting ? "awaiting_preop_failed" : "startup_failed", result.error());
      // The ring was up: slaves that got anywhere go back to INIT before the session ends.
      co_await leave_slaves_in_init(s);
      if (session != s) co_return;  // stop() ended the session meanwhile
      teardown();
      transition(MasterState::idle);
    }
  }

  exec::Task<Result<void>> run_startup(std::shared_ptr<Session> s) {
    auto& bus = *s->bus;
    auto count = co_await await_stable_count(loop, bus, s->config.scan, &s->position_access);
    if (!count) co_return count.error().context("discovering the ring");
    if (s->stopping) co_return Error(Errc::closed, "stopped");
    if (s->config.slaves.size() > *count) {
      std::string missing;
      for (std::size_t i = *count; i < s->config.slaves.size(); ++i) {
        missing += fmt::format("{}'{}'", missing.empty() ? "" : ", ", s->config.slaves[i].name);
      }
      co_return Error(Errc::invalid_argument,
                      fmt::format("{} slaves configured, the ring has {} (nothing found for {})",
                                  s->config.slaves.size(), *count, missing));
    }
    s->slave_count = *count;
    if (!s->config.frame_timeout) (void)bus.set_frame_timeout(auto_frame_timeout(*count));
    s->start_sides.reset();
    s->port_descriptors.clear();
    RingSides sides{};
    if (auto r = co_await assign_stations(loop, bus, *count, s->config.base_station, &sides); !r) {
      co_return r.error();
    }
    if (bus.info().redundancy) s->start_sides = sides;
    // A group on a junction port in the middle, plugged already: the fixed slaves behind it get
    // their stations as if it were not there (by config order), the group the ones after them
    // (it is claimed by the hot-connect scan once the session runs). `ring_position`: the ring
    // position of the slave at base_station + k (empty: k itself).
    std::vector<std::uint16_t> ring_position;
    if (!s->config.hot_connect.empty() && *count > s->config.slaves.size()) {
      auto placed = co_await place_groups_at_start(*s, *count);
      if (!placed) co_return placed.error();
      ring_position = std::move(*placed);
      if (s->stopping) co_return Error(Errc::closed, "stopped");
    }
    s->start_ring_stations.clear();
    for (std::uint16_t k = 0; k < *count; ++k) {
      const std::uint16_t pos = ring_position.empty() ? k : ring_position[k];
      s->start_ring_stations.resize(*count);
      s->start_ring_stations[pos] = static_cast<std::uint16_t>(s->config.base_station + k);
    }
    std::vector<std::uint16_t> aliases;
    for (const auto& c : s->config.slaves) {
      if (!c.alias || !aliases.empty()) continue;
      auto read = co_await read_aliases(*s, *count);
      if (!read) co_return read.error();
      aliases = std::move(*read);
    }
    auto effective = effective_slaves(*count, aliases);
    if (!effective) co_return effective.error();
    auto configs = std::move(*effective);
    s->fixed_end = *count;
    if (!s->config.hot_connect.empty()) {
      // Hot-connect groups sit behind the last fixed slave: whatever is found there is theirs to
      // claim once the session runs (hot_connect_scan), never part of the startup.
      s->fixed_end = 0;
      for (const auto& c : configs)
        s->fixed_end = std::max<std::uint16_t>(s->fixed_end, *c.position + 1);
    }
    auto dl = co_await read_dl_status(loop, bus, *count, s->config.base_station);
    if (!dl) co_return dl.error();
    s->dl_status = *dl;
    for (std::size_t k = 0; k < ring_position.size() && k < dl->size(); ++k)
      s->dl_status[ring_position[k]] = (*dl)[k];  // read by station: kept by position
    if (s->start_sides) {
      // Only for a broken ring's shape (seed_ring_shape): unread, there is none.
      auto ports = co_await read_port_descriptors(loop, bus, *count, s->config.base_station);
      if (ports) s->port_descriptors = *ports;
      for (std::size_t k = 0; ports && k < ring_position.size() && k < ports->size(); ++k)
        s->port_descriptors[ring_position[k]] = (*ports)[k];
    }
    if (auto r = co_await reset_slaves(loop, bus, *count); !r) co_return r.error();
    if (auto r = co_await init_all(loop, bus, *count, s->config.base_station, s->config.init); !r) {
      co_return r.error();
    }
    if (s->stopping) co_return Error(Errc::closed, "stopped");
    if (s->config.dc) co_await init_dc(s);
    if (s->stopping) co_return Error(Errc::closed, "stopped");
    if (auto r = co_await set_junction_auto_close(s); !r) co_return r.error();
    // A dynamic session names a coupler `coupler` (its SII decides: dynamic_names.hpp), the
    // others slave_<position>. Read now, with every slave in INIT and the EEPROM with ECAT (the
    // reset block), for all slaves at once: the name is needed before the Slave is made.
    if (s->config.slaves.empty()) {
      std::vector<exec::Task<std::optional<bool>>> probes;
      for (const auto& c : configs) {
        probes.push_back(probe_coupler(
            loop, bus, static_cast<std::uint16_t>(s->config.base_station + *c.position)));
      }
      const auto couplers = co_await exec::when_all(loop, std::move(probes));
      const auto names = dynamic_slave_names(couplers);
      for (std::size_t i = 0; i < configs.size(); ++i)
        configs[i].name = names[i];
      if (s->stopping) co_return Error(Errc::closed, "stopped");
    }

    // Domains (open: slaves register their SyncManagers while reaching PREOP).
    std::uint32_t base = 0;
    for (auto dc : s->config.domains) {
      if (dc.logical_base == 0) dc.logical_base = base;
      // Each domain gets a logical window as large as its image may grow (a self-sizing one:
      // kAutoImageLimit), so that no two domains' FMMUs ever map the same logical addresses.
      const std::size_t limit = dc.max_image_size != 0 ? dc.max_image_size : kAutoImageLimit;
      const std::uint32_t span = static_cast<std::uint32_t>(
          std::max<std::size_t>(0x800, (limit + 0x7FF) & ~std::size_t{0x7FF}));
      base = dc.logical_base + span;
      auto domain = Domain::create(bus, dc, this);
      if (!domain) co_return domain.error();
      std::lock_guard lock(mutex);  // Master::domain() reads the list from other threads
      s->domains.push_back(std::move(*domain));
    }

    // Slaves.
    for (auto& c : configs) {
      const auto index = *c.position;
      const auto station = static_cast<std::uint16_t>(s->config.base_station + index);
      const auto pos = ring_position.empty() ? index : ring_position[index];
      auto slave = std::make_unique<Slave>(*s, std::move(c), pos, station);
      std::lock_guard lock(mutex);  // Master::slave() reads the list from other threads
      s->slaves.push_back(std::move(slave));
    }
    if (auto r = make_hot_connect_groups(*s); !r) co_return r.error();
    bool any_active = false;
    for (const auto& slave : s->slaves) {
      if (SlaveAccess::absent(*slave)) continue;
      if (SlaveAccess::target(*slave) != TargetState::preop) any_active = true;
    }
    // Held in PREOP from the start: no health polls until activation (the reference hands its
    // slaves no poll period then; scenarios 47 and 51).
    s->health_held = !any_active;
    transition(MasterState::awaiting_preop);
    const auto deadline = exec::Clock::now() + s->config.awaiting_preop_timeout;
    std::vector<exec::Task<Result<void>>> ups;
    for (auto& slave : s->slaves) {
      if (SlaveAccess::absent(*slave)) continue;  // a hot-connect group's: joins later
      ups.push_back(bring_up_with_retry(s, *slave, deadline));
    }
    auto results = co_await exec::when_all(loop, std::move(ups));
    if (s->stopping) co_return Error(Errc::closed, "stopped");
    for (auto& r : results) {
      if (!r) co_return r.error();
    }
    // Quiesce (the reference's Bus.quiesce(2 ms)): no startup reply may still be on its way when
    // the first public exchange or the first OP transition datagram goes out.
    if (auto quiet = co_await exec::quiesce(loop, bus, kQuietWindow); !quiet) {
      co_return quiet.error().context("activation: the bus is not ready");
    }

    if (!any_active) {
      {
        std::lock_guard lock(mutex);
        desired = TargetState::preop;
      }
      transition(MasterState::preop_ready);
      start_hot_connect(s);
      co_return ok();
    }
    {
      std::lock_guard lock(mutex);
      desired = TargetState::op;
    }
    co_await run_activation(s);
    start_hot_connect(s);
    co_return ok();
  }

  // ---- hot connect ---------------------------------------------------------------------------
  // Groups of slaves behind the fixed ones that come and go (MasterConfig::hot_connect; docs:
  // ARCHITECTURE.md "Hot connect"). Their Slave objects exist from the start, absent; every domain
  // they map into reserves room for them. A task on the loop polls the slave count (one BRD per
  // hot_connect_poll); slaves found behind the last present group are identified (alias, or the
  // SII identity of the first one, read at a scratch station), given their stations and brought to
  // the session's target while the domains accept their share of the working counter or not; the
  // group is lost when the count shrinks past it, when a domain finds its share gone, or when one
  // of its slaves stops answering its health poll.

  Result<void> make_hot_connect_groups(Session& s) {
    const auto& groups = s.config.hot_connect;
    // After every fixed station: base + position up to the last fixed position, which with gaps
    // in the configured positions lies past base + the number of configured slaves (the slaves
    // in the gaps have stations there too).
    auto station = static_cast<std::uint16_t>(
        s.config.base_station + std::max<std::size_t>(s.config.slaves.size(), s.fixed_end));
    for (std::size_t gi = 0; gi < groups.size(); ++gi) {
      const auto& group = groups[gi];
      HotConnectRuntime rt;
      rt.index = gi;
      rt.name = group.name;
      std::vector<std::uint16_t> stations;
      std::vector<std::string> used;
      auto use = [&](const std::string& id) {
        if (std::find(used.begin(), used.end(), id) == used.end()) used.push_back(id);
      };
      for (const auto& c : group.slaves) {
        auto slave = std::make_unique<Slave>(s, c, s.fixed_end, station);
        SlaveAccess::set_absent(*slave, true);
        stations.push_back(station++);
        if (c.process_data.kind == ProcessDataRequest::Kind::all) use(c.process_data.domain);
        for (const auto& route : c.process_data.routes)
          use(route.domain);
        rt.slaves.push_back(slave.get());
        std::lock_guard lock(mutex);
        s.slaves.push_back(std::move(slave));
      }
      const std::size_t bytes = group.reserve_bytes != 0
                                    ? group.reserve_bytes
                                    : std::min<std::size_t>(64 * group.slaves.size(), 0xFFFF);
      for (const auto& id : used) {
        Domain* d = s.find_domain(id);
        if (!d) continue;
        auto r = d->reserve(group.name, bytes, stations);
        if (!r) {
          return r.error().context(fmt::format(
              "hot_connect group {}: reserving {} bytes in domain {}", group.name, bytes, id));
        }
        rt.reservations.emplace_back(d, *r);
      }
      std::lock_guard lock(mutex);
      s.hot_connect.push_back(std::move(rt));
    }
    s.hot_connect_scratch = station;
    return ok();
  }

  static HotConnectRuntime* group_of(Session& s, const Slave& slave) {
    for (auto& g : s.hot_connect) {
      if (std::find(g.slaves.begin(), g.slaves.end(), &slave) != g.slaves.end()) return &g;
    }
    return nullptr;
  }

  // The session's walks (activation, the slave retry loop) take a group's slaves only while the
  // group is present: joining ones are walked by their join.
  static bool hot_connect_walkable(Session& s, const Slave& slave) {
    if (SlaveAccess::absent(slave)) return false;
    const HotConnectRuntime* g = group_of(s, slave);
    return g == nullptr || g->state == HotConnectState::present;
  }

  void start_hot_connect(const std::shared_ptr<Session>& s) {
    if (s->hot_connect.empty() || s->stopping || session != s) return;
    exec::spawn(loop, hot_connect_watch(s));
  }

  exec::Task<void> hot_connect_watch(std::shared_ptr<Session> s) {
    while (!s->stopping && session == s) {
      co_await hot_connect_scan(s);
      if (s->stopping || session != s) break;
      co_await exec::sleep_for(loop, s->config.hot_connect_poll);
    }
  }

  void set_group(HotConnectRuntime& g, HotConnectState to, std::string detail) {
    std::lock_guard lock(mutex);
    g.state = to;
    g.detail = std::move(detail);
  }

  static std::array<std::uint8_t, 2> le16(std::uint16_t v) {
    std::array<std::uint8_t, 2> out{};
    wire::store_le16(out.data(), v);
    return out;
  }

  // The station address at every position of the ring (APRD 0x0010), in ring order; nullopt when
  // a position does not answer (the ring changed under the read) or the frame was lost.
  exec::Task<std::optional<std::vector<std::uint16_t>>> read_station_map(Session& s,
                                                                         std::uint16_t n) {
    if (n == 0 || n > 0x8000) co_return std::nullopt;  // auto-increment addresses 0..-0x8000
    bus::Transaction tx;
    for (std::uint32_t pos = 0; pos < n; ++pos)
      tx.aprd(static_cast<std::uint16_t>(pos), wire::reg::kStationAddress, 2);
    // Behind a break of a redundant ring, through the secondary's frame (transact_by_position).
    auto reply =
        co_await transact_by_position(loop, *s.bus, s.position_access, std::move(tx), {50ms, 1});
    if (!reply) co_return std::nullopt;
    std::vector<std::uint16_t> map;
    map.reserve(n);
    for (std::uint32_t pos = 0; pos < n; ++pos) {
      if ((*reply)[pos].wkc != 1) co_return std::nullopt;
      map.push_back(wire::load_le16((*reply)[pos].data.data()));
    }
    co_return map;
  }

  // Where the ring's slaves are now. A group may hang on a junction port in the middle of the
  // ring: position addressing counts in ring order, so plugging it shifts the positions of the
  // fixed slaves behind it. Their stations do not change, so the stations read by position say
  // which slave is where: the fixed slaves' and the present groups' positions follow them, a
  // present group whose stations are no longer all in the ring, in its order, is lost, and the
  // first position holding a station nobody has (a device that came up at 0, or one left with a
  // refused group's or the scratch station) is where something new begins. Returns that
  // position and how many new slaves follow it in a row (none: nothing new); nullopt when the
  // read failed or a fixed slave is missing (the session's own recovery: a power-cycled fixed
  // slave, back at station 0, must not be taken for a new device).
  struct NewRun {
    std::uint16_t at = 0;
    std::uint16_t length = 0;
    std::string after;  // the slave in front of it in ring order (for the reports)
  };
  exec::Task<std::optional<NewRun>> locate_slaves(std::shared_ptr<Session> s, std::uint16_t n) {
    auto map = co_await read_station_map(*s, n);
    if (!map || s->stopping || session != s) co_return std::nullopt;
    std::unordered_map<std::uint16_t, std::uint16_t> where;  // station -> position
    for (std::uint16_t pos = 0; pos < map->size(); ++pos)
      where.emplace((*map)[pos], pos);
    for (auto& g : s->hot_connect) {
      if (!g.position || g.state == HotConnectState::absent) continue;
      const auto first = where.find(g.slaves.front()->station());
      bool whole = first != where.end() && first->second + g.slaves.size() <= map->size();
      for (std::size_t k = 0; whole && k < g.slaves.size(); ++k)
        whole = (*map)[first->second + k] == g.slaves[k]->station();
      if (!whole) {
        group_lost(s, g, fmt::format("its stations are no longer in the ring ({} slaves)", n));
        continue;
      }
      if (first->second != *g.position) {
        std::lock_guard lock(mutex);
        g.position = first->second;
      }
      for (std::size_t k = 0; k < g.slaves.size(); ++k)
        SlaveAccess::move_to(*g.slaves[k], static_cast<std::uint16_t>(first->second + k));
    }
    std::unordered_map<std::uint16_t, Slave*> fixed;  // station -> fixed slave
    for (auto& slave : s->slaves) {
      if (group_of(*s, *slave) == nullptr) fixed.emplace(slave->station(), slave.get());
    }
    bool fixed_missing = false;
    for (std::uint16_t pos = 0; pos < s->fixed_end; ++pos) {
      const auto station = static_cast<std::uint16_t>(s->config.base_station + pos);
      const auto it = where.find(station);
      if (it == where.end()) {
        fixed_missing = true;
        continue;
      }
      if (auto f = fixed.find(station); f != fixed.end() && f->second->position() != it->second)
        SlaveAccess::move_to(*f->second, it->second);
    }
    if (fixed_missing) co_return std::nullopt;
    auto known = [&](std::uint16_t station) {
      if (station >= s->config.base_station && station - s->config.base_station < s->fixed_end)
        return true;
      for (const auto& g : s->hot_connect) {
        if (!g.position || g.state == HotConnectState::absent) continue;
        for (const Slave* slave : g.slaves) {
          if (slave->station() == station) return true;
        }
      }
      return false;
    };
    for (std::uint16_t pos = 0; pos < map->size(); ++pos) {
      if (known((*map)[pos])) continue;
      NewRun run;
      run.at = pos;
      while (pos < map->size() && !known((*map)[pos])) {
        ++run.length;
        ++pos;
      }
      if (run.at > 0) {
        const auto before = (*map)[run.at - 1];
        for (const auto& slave : s->slaves) {
          if (slave->station() == before) run.after = slave->name();
        }
      }
      co_return run;
    }
    co_return NewRun{};
  }

  // Junction ports (Session::JunctionPort) at startup, all slaves in INIT and the DC delays
  // measured: from the startup's DL status, the tree of the ring; every port of a fixed slave
  // that leads to no fixed slave (free, or a group plugged at start) and has fixed DC slaves
  // after it in frame order (depth first, ports 3, 1, 2) gets loop control "auto close" (01):
  // a port with link stays open (a group in at start is measured with the rest), one without
  // stays closed when a group is plugged there until the hot-connect watch opens it. Only with
  // hot-connect groups, distributed clocks and a line (a redundant ring's break heals by the
  // ports' own link detection). Ports at the end of a line have nobody behind them: untouched.
  exec::Task<Result<void>> set_junction_auto_close(std::shared_ptr<Session> s) {
    s->junction_ports.clear();
    if (s->config.hot_connect.empty() || !s->dc_init || s->bus->info().redundancy) co_return ok();
    const auto& stations = s->start_ring_stations;
    const std::size_t n = stations.size();
    if (n == 0 || s->dl_status.size() != n) co_return ok();
    std::vector<std::uint16_t> raw;
    raw.reserve(n);
    for (const auto& dl : s->dl_status)
      raw.push_back(dl.encode());
    auto tree = ring_tree(raw, stations, false);
    if (!tree) {
      events.publish(make_event(
          EventKind::recovery_step, "hotconnect",
          "junction ports left in auto mode (a group plugged there disturbs the clocks behind "
          "it): " +
              tree.error().describe()));
      co_return ok();
    }
    const auto base = s->config.base_station;
    const auto fixed = [&](std::size_t pos) {
      return stations[pos] >= base && stations[pos] - base < s->fixed_end;
    };
    std::vector<std::uint16_t> dc_fixed;
    for (const auto& p : s->dc_init->plan.slaves) {
      if (p.dc && p.position < n && fixed(p.position)) dc_fixed.push_back(p.station);
    }
    // End (exclusive) of each slave's subtree in ring order.
    std::vector<std::size_t> end(n);
    for (std::size_t i = 0; i < n; ++i)
      end[i] = i + 1;
    for (std::size_t i = n; i-- > 1;) {
      if (const auto parent = tree->slaves[i].parent) end[*parent] = std::max(end[*parent], end[i]);
    }
    bus::Transaction tx;
    for (std::size_t i = 0; i < n; ++i) {
      if (!fixed(i)) continue;
      std::uint8_t control = 0;
      std::size_t at = i + 1;  // where a slave on the next port would be
      for (const std::uint8_t port : {std::uint8_t{3}, std::uint8_t{1}, std::uint8_t{2}}) {
        const auto child = tree->slaves[i].children[port];
        if (!child || !fixed(*child)) {
          Session::JunctionPort jp;
          jp.owner = stations[i];
          jp.port = port;
          jp.open = child.has_value();
          for (std::size_t pos = at; pos < n; ++pos) {
            if (std::find(dc_fixed.begin(), dc_fixed.end(), stations[pos]) != dc_fixed.end())
              jp.behind.push_back(stations[pos]);
          }
          if (!jp.behind.empty()) {
            control = static_cast<std::uint8_t>(control | (1u << (2 * port)));
            s->junction_ports.push_back(std::move(jp));
          }
        }
        if (child) at = end[*child];
      }
      if (control == 0) continue;
      const std::uint8_t byte[1] = {control};
      tx.fpwr(stations[i], wire::reg::kDlPortControl, byte, 1);
    }
    if (tx.empty()) co_return ok();
    auto written = co_await exec::transact(loop, *s->bus, std::move(tx));
    if (!written) {
      co_return written.error().context(
          "setting the junction ports hot-connect groups plug into to auto close (0x0101)");
    }
    co_return ok();
  }

  // The loop control byte the master keeps in `owner`'s 0x0101: auto close on its junction ports.
  static std::uint8_t junction_control(const Session& s, std::uint16_t owner) {
    std::uint8_t control = 0;
    for (const auto& jp : s.junction_ports) {
      if (jp.owner == owner) control = static_cast<std::uint8_t>(control | (1u << (2 * jp.port)));
    }
    return control;
  }

  // Every hot-connect poll: the DL status of the slaves that own junction ports. A port with
  // link and its loop closed has a group waiting behind it: the fixed DC slaves behind it are
  // taken out of the lock, the port opened (0x0101 written again: auto close with link opens),
  // and the delays measured by position and written at once (update_dc_delays), before those
  // slaves' clocks follow the later frame far; then they rejoin the lock. A port the master
  // opened that lost its link was shut by the ESC itself (auto close) as the group left: the
  // same measurement for the shorter way. The group itself is found, joined or lost by the
  // scan that follows.
  exec::Task<void> watch_junctions(std::shared_ptr<Session> s) {
    std::vector<std::uint16_t> owners;
    for (const auto& jp : s->junction_ports) {
      if (std::find(owners.begin(), owners.end(), jp.owner) == owners.end())
        owners.push_back(jp.owner);
    }
    bus::Transaction read;
    for (const auto owner : owners)
      read.fprd(owner, wire::reg::kDlStatus, 2);
    auto reply = co_await exec::transact(loop, *s->bus, std::move(read), {50ms, 0});
    if (!reply || s->stopping || session != s) co_return;
    std::vector<std::uint16_t> open_owners;
    std::vector<std::uint16_t> held;
    std::string what;
    for (std::size_t k = 0; k < owners.size(); ++k) {
      if (reply->wkc(k) != 1) continue;  // a fixed slave missing: the session's recovery
      const auto dl = wire::DlStatus::decode(wire::load_le16(reply->data(k).data()));
      for (auto& jp : s->junction_ports) {
        if (jp.owner != owners[k]) continue;
        const auto& port = dl.ports[jp.port];
        bool moved = false;
        if (port.physical_link && port.loop_closed) {
          if (std::find(open_owners.begin(), open_owners.end(), jp.owner) == open_owners.end())
            open_owners.push_back(jp.owner);
          moved = true;
          jp.open = true;
          what += fmt::format("{}port {} of station 0x{:04x} opened", what.empty() ? "" : ", ",
                              jp.port, jp.owner);
        } else if (!port.physical_link && jp.open) {
          moved = true;
          jp.open = false;
          what += fmt::format("{}port {} of station 0x{:04x} closed at link down",
                              what.empty() ? "" : ", ", jp.port, jp.owner);
        } else if (port.physical_link && !port.loop_closed) {
          jp.open = true;
        }
        if (!moved) continue;
        for (const auto st : jp.behind) {
          if (std::find(held.begin(), held.end(), st) == held.end()) held.push_back(st);
        }
      }
    }
    if (what.empty()) co_return;
    if (s->dc) s->dc->hold_stations(held);
    if (!open_owners.empty()) {
      bus::Transaction open;
      for (const auto owner : open_owners) {
        const std::uint8_t byte[1] = {junction_control(*s, owner)};
        open.fpwr(owner, wire::reg::kDlPortControl, byte, 1);
      }
      auto opened = co_await exec::transact(loop, *s->bus, std::move(open), {50ms, 1});
      if (s->stopping || session != s) co_return;
      if (!opened) {
        events.publish(
            make_event(EventKind::recovery_step, "hotconnect",
                       opened.error().context("opening a junction port (0x0101)").describe()));
      }
    }
    if (s->dc_init) {
      std::vector<std::uint16_t> dc_stations;
      for (const auto& p : s->dc_init->plan.slaves)
        if (p.dc) dc_stations.push_back(p.station);
      DcInitOptions options;
      options.threshold = s->config.dc->lock_threshold;
      auto updated = co_await update_dc_delays(loop, *s->bus, s->dc_init->reference_station,
                                               std::move(dc_stations), options);
      if (s->stopping || session != s) co_return;
      if (updated) {
        std::lock_guard lock(mutex);
        for (const auto& c : updated->changed) {
          for (auto& p : s->dc_init->plan.slaves)
            if (p.station == c.station) p.delay_ns = c.delay_ns;
        }
      } else {
        // The join (or the leave) measures the ring again: the delays are written there.
        events.publish(make_event(EventKind::recovery_step, "dc",
                                  fmt::format("{}: {}", what, updated.error().describe())));
      }
    }
    if (s->dc) s->dc->release_stations(held);
  }

  // watch_junctions, one at a time: asked for while one runs, it runs once more after it.
  exec::Task<void> junction_watch(std::shared_ptr<Session> s) {
    if (s->junction_ports.empty()) co_return;
    if (s->junction_watching) {
      s->junction_watch_again = true;
      co_return;
    }
    s->junction_watching = true;
    do {
      s->junction_watch_again = false;
      co_await watch_junctions(s);
    } while (s->junction_watch_again && !s->stopping && session == s);
    s->junction_watching = false;
  }

  exec::Task<void> hot_connect_scan(std::shared_ptr<Session> s) {
    auto& bus = *s->bus;
    if (!s->junction_ports.empty()) {
      co_await junction_watch(s);
      if (s->stopping || session != s) co_return;
    }
    auto count = co_await count_slaves(loop, bus, {50ms, 0});
    if (!count || s->stopping || session != s) co_return;  // a lost frame says nothing
    const std::uint16_t n = *count;
    if (n != s->hot_connect_seen_count) {
      // The ring changed: a refused group or device may have been swapped for the right one, so
      // the retry waits start afresh (the next look is now, not retry_interval after the refusal).
      s->hot_connect_seen_count = n;
      for (auto& g : s->hot_connect)
        g.retry_after = {};
      s->hot_connect_refused_at = {};
    }
    if (n < s->fixed_end) {
      // Fixed slaves missing (the session's own recovery); present groups behind the end are gone.
      for (auto& g : s->hot_connect) {
        if (g.position && *g.position + g.slaves.size() > n) {
          group_lost(s, g, fmt::format("the ring has {} slaves", n));
        }
      }
      co_return;
    }
    std::size_t expected = s->fixed_end;
    for (const auto& g : s->hot_connect) {
      if (g.position && g.state != HotConnectState::absent) expected += g.slaves.size();
    }
    if (n == expected && n == s->hot_connect_located_count) {
      for (auto& g : s->hot_connect)
        g.short_since.reset();  // nothing new in the ring: no group is short
      co_return;
    }
    // A refused device is looked at again when the ring changes, and after retry_interval (a
    // device swapped for another between two polls leaves the count as it was).
    if (n == s->hot_connect_refused_count && !s->hot_connect_refused.empty() &&
        exec::Clock::now() - s->hot_connect_refused_at < s->config.retry_interval) {
      co_return;
    }
    auto located = co_await locate_slaves(s, n);
    if (!located || s->stopping || session != s) co_return;  // looked at again at the next poll
    s->hot_connect_located_count = n;
    if (located->length == 0) {
      for (auto& g : s->hot_connect)
        g.short_since.reset();  // nothing new in the ring: no group is short
      co_return;
    }
    const std::uint16_t new_slaves = located->length;
    const std::string behind =
        located->after.empty() ? std::string() : fmt::format(" (behind {})", located->after);
    // The first new slave: at the scratch station, its alias and identity.
    const std::uint16_t at = located->at;
    const std::uint16_t scratch = s->hot_connect_scratch;
    const bus::TransactOptions quick{50ms, 1};
    bus::Transaction assign;
    assign.apwr(at, wire::reg::kStationAddress, le16(scratch));
    // Behind a break of a redundant ring, through the frame that reaches `at`.
    auto assigned =
        co_await transact_by_position(loop, bus, s->position_access, std::move(assign), quick);
    if (!assigned || (*assigned)[0].wkc != 1 || s->stopping || session != s) co_return;
    bus::Transaction alias_tx;
    alias_tx.fprd(scratch, wire::reg::kStationAlias, 2);
    auto alias_reply = co_await exec::transact(loop, bus, std::move(alias_tx), quick);
    if (!alias_reply || alias_reply->wkc(0) != 1) co_return;
    const std::uint16_t alias = wire::load_le16(alias_reply->data(0).data());
    auto words = co_await read_sii_words(loop, bus, scratch, 0x0008, 4);
    if (s->stopping || session != s) co_return;
    if (!words || words->size() < 8) co_return;  // tried again at the next poll
    const std::uint32_t vendor = wire::load_le32(words->data());
    const std::uint32_t product = wire::load_le32(words->data() + 4);
    // Its explicit device ID, when a group waiting is known by one.
    std::optional<std::uint16_t> device_id;
    bool asked_id = false;
    for (const auto& g : s->hot_connect) {
      const bool waiting =
          g.state != HotConnectState::present && g.state != HotConnectState::joining;
      if (waiting && s->config.hot_connect[g.index].device_id) asked_id = true;
    }
    if (asked_id) {
      auto id = co_await read_device_id(*s, scratch);
      if (s->stopping || session != s) co_return;
      if (!id) co_return;  // tried again at the next poll
      device_id = *id;
    }

    HotConnectRuntime* match = nullptr;
    std::string how;
    for (auto& g : s->hot_connect) {
      if (g.state == HotConnectState::present || g.state == HotConnectState::joining) continue;
      const auto& cfg = s->config.hot_connect[g.index];
      const auto& first = cfg.slaves.front();
      const auto v = cfg.vendor_id ? cfg.vendor_id : first.vendor_id;
      const auto p = cfg.product_code ? cfg.product_code : first.product_code;
      if (cfg.device_id) {
        // The device ID, and the alias and identity where the group gives them.
        if (device_id != cfg.device_id) continue;
        if (cfg.alias && alias != *cfg.alias) continue;
        if (v && p && (vendor != *v || product != *p)) continue;
        how = fmt::format("device ID {} at position {}{}", *device_id, at, behind);
      } else if (cfg.alias) {
        if (alias != *cfg.alias) continue;
        how = fmt::format("alias 0x{:04x} at position {}{}", alias, at, behind);
      } else {
        if (vendor != v.value_or(~0u) || product != p.value_or(~0u)) continue;
        how = fmt::format("vendor 0x{:08x} product 0x{:08x} at position {}{}", vendor, product, at,
                          behind);
      }
      match = &g;
      break;
    }
    if (!match) {
      const std::string id_text = !asked_id   ? std::string()
                                  : device_id ? fmt::format(", device ID {}", *device_id)
                                              : std::string(", no device ID");
      auto why = fmt::format(
          "position {}{}: alias 0x{:04x}, vendor 0x{:08x} product 0x{:08x}{}: "
          "matches no absent hot-connect group; not configured",
          at, behind, alias, vendor, product, id_text);
      const bool again = why == s->hot_connect_refused;  // reported once while it lasts
      {
        std::lock_guard lock(mutex);
        s->hot_connect_refused = std::move(why);
        s->hot_connect_refused_count = n;
        s->hot_connect_refused_at = exec::Clock::now();
      }
      if (!again) {
        Event e = make_event(EventKind::hotconnect_refused, {}, s->hot_connect_refused);
        e.subject = at;
        events.publish(e);
      }
      co_return;
    }
    {
      std::lock_guard lock(mutex);
      s->hot_connect_refused.clear();
      s->hot_connect_refused_count = 0;
    }
    for (auto& g : s->hot_connect) {
      if (&g != match) g.short_since.reset();
    }
    if (exec::Clock::now() < match->retry_after) co_return;
    if (new_slaves < match->slaves.size()) {
      // Short of slaves: the rest may still be powering up. Refused (reported once) when it
      // lasts retry_interval; joined as soon as they are all there.
      auto why = fmt::format("{}: {} of its {} slaves in the ring so far ({} missing)", how,
                             new_slaves, match->slaves.size(), match->slaves[new_slaves]->name());
      const auto now = exec::Clock::now();
      if (!match->short_since) match->short_since = now;
      if (now - *match->short_since >= s->config.retry_interval) {
        refuse_group(*s, *match, std::move(why));
      } else if (match->state != HotConnectState::failed) {
        set_group(*match, HotConnectState::absent, std::move(why));
      }
      co_return;
    }
    match->short_since.reset();
    co_await join_group(s, *match, at, std::move(how));
  }

  // Explicit device identification (ETG.1000.6 AL control bit 5): AL control = INIT + ID request
  // to the slave at `station`; while the request is set, a device with an ID sets AL status bit 5
  // (ID loaded) and shows the ID in the AL status code register 0x0134. Polled for up to 100 ms
  // (the firmware answers), then the request is taken back. Nullopt inside: the device has no
  // ID (bit 5 never set, or ID 0); an error when the slave does not answer.
  exec::Task<Result<std::optional<std::uint16_t>>> read_device_id(Session& s,
                                                                  std::uint16_t station) {
    const bus::TransactOptions quick{50ms, 1};
    auto request = [&](bool on) {
      bus::Transaction tx;
      tx.fpwr(station, wire::reg::kAlControl,
              le16(static_cast<std::uint16_t>(wire::encode_al_control(wire::AlState::init, false) |
                                              (on ? wire::kAlControlIdRequest : 0))));
      return tx;
    };
    auto asked = co_await exec::transact(loop, *s.bus, request(true), quick);
    if (!asked) co_return asked.error().context("requesting the explicit device ID");
    if (asked->wkc(0) != 1) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("requesting the explicit device ID of station 0x{:04x}: "
                                  "working counter {}",
                                  station, asked->wkc(0)));
    }
    std::optional<std::uint16_t> id;
    const auto deadline = exec::Clock::now() + 100ms;
    while (true) {
      bus::Transaction read;
      read.fprd(station, wire::reg::kAlStatus, 6);
      auto reply = co_await exec::transact(loop, *s.bus, std::move(read), quick);
      if (!reply) co_return reply.error().context("reading the explicit device ID");
      if (reply->wkc(0) == 1) {
        const auto data = reply->data(0);
        if ((data[0] & 0x20) != 0) {
          const auto value = wire::load_le16(data.data() + 4);
          if (value != 0) id = value;
          break;
        }
      }
      if (exec::Clock::now() >= deadline || s.stopping) break;
      co_await exec::sleep_for(loop, 2ms);
    }
    (void)co_await exec::transact(loop, *s.bus, request(false), quick);
    co_return id;
  }

  // A group seen but not taken (short of slaves, or its slaves not what it declares): nothing is
  // written to it but station addresses; `failed` with the reason, reported once while the same,
  // looked at again after retry_interval.
  void refuse_group(Session& s, HotConnectRuntime& g, std::string why) {
    bool again = false;
    {
      std::lock_guard lock(mutex);
      again = g.state == HotConnectState::failed && g.detail == why;
      g.state = HotConnectState::failed;
      g.detail = why;
      g.position.reset();
      g.retry_after = exec::Clock::now() + s.config.retry_interval;
    }
    if (!again) events.publish(make_event(EventKind::hotconnect_refused, g.name, std::move(why)));
  }

  // What each slave of a group placed at `at` says it is (SII words 8..13), read at its station.
  exec::Task<Result<std::vector<FoundIdentity>>> read_group_identities(Session& s,
                                                                       HotConnectRuntime& g) {
    std::vector<exec::Task<Result<std::vector<std::uint8_t>>>> reads;
    for (Slave* slave : g.slaves)
      reads.push_back(read_sii_words(loop, *s.bus, slave->station(), 0x0008, 6));
    auto words = co_await exec::when_all(loop, std::move(reads));
    std::vector<FoundIdentity> found;
    for (std::size_t k = 0; k < words.size(); ++k) {
      if (!words[k]) {
        co_return words[k].error().context(
            fmt::format("reading the identity of {}", g.slaves[k]->name()));
      }
      auto id = decode_found_identity(*words[k]);
      if (!id) {
        co_return Error(Errc::invalid_argument,
                        fmt::format("reading the identity of {}: {} bytes of SII words 8..13",
                                    g.slaves[k]->name(), words[k]->size()));
      }
      found.push_back(*id);
    }
    co_return found;
  }

  exec::Task<void> join_group(std::shared_ptr<Session> s, HotConnectRuntime& g, std::uint16_t at,
                              std::string how) {
    auto& bus = *s->bus;
    const auto noticed = exec::Clock::now();
    bus::Transaction assign;
    for (std::size_t k = 0; k < g.slaves.size(); ++k) {
      assign.apwr(static_cast<std::uint16_t>(at + k), wire::reg::kStationAddress,
                  le16(g.slaves[k]->station()));
    }
    // Behind a break of a redundant ring, each through the frame that reaches its position.
    auto assigned = co_await transact_by_position(loop, bus, s->position_access, std::move(assign),
                                                  bus::TransactOptions{});
    if (s->stopping || session != s) co_return;
    if (!assigned) {
      refuse_group(*s, g, assigned.error().context("assigning the group's stations").describe());
      co_return;
    }
    for (std::size_t k = 0; k < g.slaves.size(); ++k) {
      if ((*assigned)[k].wkc != 1) {
        refuse_group(*s, g,
                     fmt::format("assigning station 0x{:04x} to position {}: working counter {}",
                                 g.slaves[k]->station(), at + k, (*assigned)[k].wkc));
        co_return;
      }
    }
    // Every slave of the group is what the group declares, or none is brought up.
    auto found = co_await read_group_identities(*s, g);
    if (s->stopping || session != s) co_return;
    if (!found) {
      refuse_group(*s, g, found.error().describe());
      co_return;
    }
    if (auto why = group_identity_mismatch(s->config.hot_connect[g.index], at, *found)) {
      refuse_group(*s, g, std::move(*why));
      co_return;
    }
    {
      std::lock_guard lock(mutex);
      g.state = HotConnectState::joining;
      g.position = at;
      g.detail = how;
      ++g.appearances;
    }
    {
      Event e = make_event(EventKind::hotconnect_appeared, g.name, how);
      e.subject = at;
      events.publish(e);
    }
    for (std::size_t k = 0; k < g.slaves.size(); ++k)
      SlaveAccess::place(*g.slaves[k], static_cast<std::uint16_t>(at + k));
    // From here the group's FMMUs may answer at any cycle: the domains take either count.
    for (const auto& [d, r] : g.reservations)
      (void)d->set_reservation_state(r, Domain::ReservationState::joining);
    std::vector<exec::Task<Result<void>>> ups;
    for (Slave* slave : g.slaves)
      ups.push_back(SlaveAccess::bring_up(*slave, s));
    auto brought = co_await exec::when_all(loop, std::move(ups));
    if (s->stopping || session != s) co_return;
    for (auto& r : brought) {
      if (!r) {
        co_await fail_group(s, g, r.error());
        co_return;
      }
    }
    if (g.state != HotConnectState::joining) co_return;  // lost meanwhile
    if (auto clocks = co_await join_group_dc(s, g); !clocks) {
      if (s->stopping || session != s) co_return;
      co_await fail_group(s, g, clocks.error());
      co_return;
    }
    if (s->stopping || session != s || g.state != HotConnectState::joining) co_return;
    TargetState want;
    {
      std::lock_guard lock(mutex);
      want = desired;
    }
    if (current() == MasterState::preop_ready || current() == MasterState::awaiting_preop)
      want = TargetState::preop;
    for (Slave* slave : g.slaves) {
      SlaveAccess::set_absent(*slave, false);
      SlaveAccess::start_health(*slave, s);
    }
    std::vector<exec::Task<Result<void>>> walks;
    for (Slave* slave : g.slaves)
      walks.push_back(SlaveAccess::go_to(*slave, min_target(want, SlaveAccess::target(*slave)), s));
    auto walked = co_await exec::when_all(loop, std::move(walks));
    if (s->stopping || session != s) co_return;
    for (std::size_t k = 0; k < walked.size(); ++k) {
      if (!walked[k]) {
        co_await fail_group(s, g, walked[k].error());
        co_return;
      }
    }
    if (g.state != HotConnectState::joining) co_return;
    for (const auto& [d, r] : g.reservations)
      (void)d->set_reservation_state(r, Domain::ReservationState::present);
    const auto took = exec::Clock::now() - noticed;
    {
      std::lock_guard lock(mutex);
      g.state = HotConnectState::present;
      g.last_join = took;
    }
    for (Slave* slave : g.slaves)
      SlaveAccess::clear_fault(*slave);
    Event e = make_event(EventKind::hotconnect_ready, g.name, how);
    e.subject = at;
    e.value = static_cast<std::uint64_t>(took.count());
    events.publish(e);
  }

  // Distributed clocks for a joining group (docs/ARCHITECTURE.md "Hot connect"), its slaves in
  // PREOP and placed: the propagation delays of the ring as it is now, the group's DC slaves
  // stepped onto the reference's time (the fixed slaves keep theirs; one behind a junction port
  // the group hangs on gets its new delay), the plan replaced (configure_sync finds the group's
  // slaves in it), and the runtime reads them into the lock once they are within the threshold,
  // which the join waits for (bounded: DcConfig::lock_timeout) before any slave of the group goes
  // on to SAFEOP with SYNC0. A failure fails the group when one of its slaves asks for SYNC (it
  // would fail there anyway), else it is reported and the group joins without DC.
  exec::Task<Result<void>> join_group_dc(std::shared_ptr<Session> s, HotConnectRuntime& g) {
    if (!s->config.dc || !s->dc_init) co_return ok();
    std::vector<std::uint16_t> joining;
    bool needs_sync = false;
    const auto& declared = s->config.hot_connect[g.index].slaves;
    for (std::size_t k = 0; k < g.slaves.size(); ++k) {
      joining.push_back(g.slaves[k]->station());
      const auto& sync = declared[k].sync;
      needs_sync |= sync && (sync->mode != SyncMode::free_run || !sync->latches.empty());
    }
    auto adapted = co_await adapt_dc(s, joining);
    if (s->stopping || session != s) co_return Error(Errc::closed, "session stopped");
    if (!adapted) {
      auto error = adapted.error().context(fmt::format("distributed clocks of group {}", g.name));
      if (needs_sync) co_return error;
      events.publish(make_event(EventKind::recovery_step, "dc",
                                error.describe() + " (the group joins without them)"));
      co_return ok();
    }
    if (!s->dc || adapted->joined.empty()) co_return ok();
    s->dc->join_stations(adapted->joined);
    const auto deadline = exec::Clock::now() + s->config.dc->lock_timeout;
    while (!s->dc->all_in_lock(adapted->joined) && exec::Clock::now() < deadline) {
      co_await exec::sleep_for(loop, 1ms);
      if (s->stopping || session != s) co_return Error(Errc::closed, "session stopped");
      if (g.state != HotConnectState::joining) co_return ok();  // lost meanwhile
    }
    co_return ok();
  }

  // The ring changed (a group joined: `joining`, or left): adapt_dc_to_ring over the stations at
  // every position now, the session's plan replaced with what was measured.
  exec::Task<Result<DcRingChangeResult>> adapt_dc(std::shared_ptr<Session> s,
                                                  std::vector<std::uint16_t> joining) {
    auto count = co_await count_slaves(loop, *s->bus, {50ms, 1});
    if (!count) co_return count.error().context("counting the slaves");
    if (s->stopping || session != s) co_return Error(Errc::closed, "session stopped");
    auto map = co_await read_station_map(*s, *count);
    if (!map) {
      co_return Error(Errc::timeout,
                      fmt::format("reading the station at each of {} positions", *count));
    }
    if (s->stopping || session != s) co_return Error(Errc::closed, "session stopped");
    DcInitOptions options;
    options.threshold = s->config.dc->lock_threshold;
    options.plan.ring_returns_to_master = s->bus->info().redundancy.has_value();
    auto adapted = co_await adapt_dc_to_ring(loop, *s->bus, s->dc_init->reference_station,
                                             std::move(*map), std::move(joining), options);
    if (!adapted || s->stopping || session != s) co_return adapted;
    std::lock_guard lock(mutex);
    s->dc_init->plan = adapted->plan;
    co_return adapted;
  }

  // A group left: its DC slaves out of the runtime (absent: no loss of the others' lock), and the
  // delays measured again for the slaves that stay (one behind the junction port it hung on
  // gets its shorter delay). A group leaving while the ring is being measured for another is
  // not dropped: the measurement runs once more after the one under way (coalesced: one more
  // for any number of leaves meanwhile), so it sees the ring without either.
  exec::Task<void> group_left_dc(std::shared_ptr<Session> s, std::vector<std::uint16_t> stations) {
    if (s->dc) s->dc->leave_stations(stations);
    if (!s->dc_init) co_return;
    if (s->dc_adapting) {
      s->dc_adapt_again = true;
      co_return;
    }
    s->dc_adapting = true;
    do {
      s->dc_adapt_again = false;
      auto adapted = co_await adapt_dc(s, {});
      if (s->stopping || session != s) co_return;
      if (!adapted) {
        events.publish(make_event(
            EventKind::recovery_step, "dc",
            "distributed clocks after a hot-connect group left: " + adapted.error().describe()));
      }
    } while (s->dc_adapt_again);
    s->dc_adapting = false;
  }

  // A group that was recognised but could not be brought up: its slaves back to INIT with their
  // FMMUs off (so they touch no domain), the group failed, tried again after retry_interval.
  exec::Task<void> fail_group(std::shared_ptr<Session> s, HotConnectRuntime& g, Error error) {
    for (const auto& [d, r] : g.reservations)
      (void)d->set_reservation_state(r, Domain::ReservationState::absent);
    auto& bus = *s->bus;
    bus::Transaction off;
    const std::vector<std::uint8_t> fmmus(8 * wire::reg::kFmmuSize, 0);
    for (Slave* slave : g.slaves) {
      SlaveAccess::lose(*slave, fmt::format("hot-connect group {} failed", g.name));
      off.fpwr(slave->station(), wire::reg::kFmmuBase, fmmus);
      off.fpwr(slave->station(), wire::reg::kAlControl,
               le16(wire::encode_al_control(wire::AlState::init, true)));
    }
    (void)co_await exec::transact(loop, bus, std::move(off), {50ms, 0});
    const auto why = error.describe();
    {
      std::lock_guard lock(mutex);
      g.state = HotConnectState::failed;
      g.detail = why;
      g.position.reset();
      g.retry_after = exec::Clock::now() + s->config.retry_interval;
    }
    events.publish(make_event(EventKind::hotconnect_refused, g.name, why));
  }

  void group_lost(const std::shared_ptr<Session>& s, HotConnectRuntime& g, std::string how) {
    if (g.state == HotConnectState::absent) return;
    for (const auto& [d, r] : g.reservations)
      (void)d->set_reservation_state(r, Domain::ReservationState::absent);
    for (Slave* slave : g.slaves) {
      SlaveAccess::lose(*slave, fmt::format("hot-connect group {} left the ring", g.name));
      clear_runtime_fault("slave:" + slave->name());
    }
    const auto at = g.position;
    {
      std::lock_guard lock(mutex);
      g.state = HotConnectState::absent;
      g.position.reset();
      g.detail = how;
      ++g.losses;
    }
    Event e = make_event(EventKind::hotconnect_lost, g.name, how);
    if (at) e.subject = *at;
    events.publish(e);
    if (s->config.dc && s->dc_init) {
      std::vector<std::uint16_t> stations;
      for (const Slave* slave : g.slaves)
        stations.push_back(slave->station());
      exec::spawn(loop, group_left_dc(s, std::move(stations)));
    }
  }

  // ---- distributed clocks --------------------------------------------------------------------

  // Delays, offsets and static drift compensation for every DC slave (all slaves in INIT). A ring
  // without a DC-capable slave, or a failed initialisation, runs without DC: dc_status() says why.
  exec::Task<void> init_dc(std::shared_ptr<Session> s) {
    std::vector<std::uint16_t> stations;
    if (s->groups_in_front) {
      // A group in the middle: the topology needs every slave of the ring, in ring order.
      stations = s->start_ring_stations;
    } else {
      for (std::uint16_t pos = 0; pos < s->fixed_end; ++pos)
        stations.push_back(static_cast<std::uint16_t>(s->config.base_station + pos));
    }
    DcInitOptions options;
    options.threshold = s->config.dc->lock_threshold;
    // Two master ports: the last slave's open port leads back to the second one.
    options.plan.ring_returns_to_master = s->bus->info().redundancy.has_value();
    auto result = co_await initialize_dc(loop, *s->bus, std::move(stations), options);
    if (result && s->groups_in_front) {
      // The group's slaves are the hot-connect join's (their stations change there): out of the
      // plan's DC slaves, and never the reference.
      for (auto& p : result->plan.slaves) {
        if (p.station - s->config.base_station >= s->fixed_end) p.dc = false;
      }
      if (result->reference_station - s->config.base_station >= s->fixed_end) {
        result = Error(Errc::unsupported,
                       fmt::format("the first DC slave (the reference clock) would be station "
                                   "0x{:04x}, a hot-connect group's",
                                   result->reference_station));
      }
    }
    std::lock_guard lock(mutex);
    if (result) {
      s->dc_init = std::move(*result);
    } else {
      s->dc_error = result.error();
    }
  }

  // The runtime participant: the reference time to every DC slave each DC cycle, differences
  // sampled, lock tracked. Created once per session, at the first activation.
  void start_dc(Session& s) {
    if (s.dc && s.dc->cycler() == nullptr && s.cycler) {
      // Taken out of the cycle by a rolled-back activation (activate_once): running again, its
      // lock counted afresh.
      s.dc->reset_lock();
      if (auto added = s.cycler->add(*s.dc, Cycler::kPriorityDc); !added) {
        std::lock_guard lock(mutex);
        s.dc_error = added.error().context("restarting the distributed-clock runtime");
      }
      return;
    }
    if (!s.dc_init || s.dc || !s.config.dc) return;
    DcRuntimeOptions options;
    options.period = s.config.dc->cycle;
    options.threshold = s.config.dc->lock_threshold;
    options.follow_reference = s.config.dc->follow_reference;
    options.phase_target = -s.config.dc->frame_lead.value_or(s.config.dc->cycle / 4);
    for (const auto& g : s.hot_connect) {
      for (const Slave* slave : g.slaves)
        options.optional_stations.push_back(slave->station());
    }
    for (const auto& jp : s.junction_ports) {
      auto& watched = options.watch_stations;
      if (std::find(watched.begin(), watched.end(), jp.owner) == watched.end())
        watched.push_back(jp.owner);
    }
    auto dc = std::make_unique<DcMaintainer>(*s.bus, *s.dc_init, options);
    // A junction port's link changed (a group plugged or pulled): looked at now, not at the next
    // hot-connect poll.
    dc->set_watch_callback([this, weak = s.weak_from_this()] {
      loop.post([this, weak] {
        if (auto sp = weak.lock(); sp && !sp->stopping && session == sp)
          exec::spawn(loop, junction_watch(sp));
      });
    });
    // Lock changes are rare: the bus thread only posts them to the loop.
    dc->set_lock_callback([this, weak = s.weak_from_this()](bool locked) {
      loop.post([this, weak, locked] {
        if (auto sp = weak.lock()) on_dc_lock(sp, locked);
      });
    });
    dc->set_health_callback([this, weak = s.weak_from_this()](bool healthy) {
      loop.post([this, weak, healthy] {
        if (auto sp = weak.lock()) on_dc_runtime(sp, healthy);
      });
    });
    if (s.bus->info().redundancy) {
      // Cable redundancy: the secondary's copy of the reference-time FRMW is a NOP whenever the
      // primary's side reads it (the reference is there) and answers; the link decides it frame
      // by frame, so a break takes effect from the next frame (see apply_dc_reach).
      const link::DatagramSelector frmw{static_cast<std::uint8_t>(wire::Command::frmw),
                                        s.dc_init->reference_station, wire::reg::kDcSystemTime,
                                        false, true};
      if (auto armed = s.bus->set_port_nop(link::Port::secondary, link::NopSlot::dc_time, frmw);
          !armed) {
        std::lock_guard lock(mutex);
        s.dc_error = armed.error().context("starting the distributed-clock runtime");
        return;
      }
    }
    if (auto added = s.cycler->add(*dc, Cycler::kPriorityDc); !added) {
      std::lock_guard lock(mutex);
      s.dc_error = added.error().context("starting the distributed-clock runtime");
      return;
    }
    std::lock_guard lock(mutex);
    s.dc = std::move(dc);
  }

  void on_dc_lock(const std::shared_ptr<Session>& s, bool locked) {
    if (s->stopping || session != s || !s->dc) return;
    static const std::string kKey = "dc:lock";
    if (locked) {
      bool raised;
      {
        std::lock_guard lock(mutex);
        raised = runtime_faults.count(kKey) != 0;
      }
      if (raised) clear_runtime_fault(kKey);
      return;
    }
    const auto status = s->dc->status();
    const auto why = fmt::format(
        "distributed clocks lost lock: max system-time difference {} ns (threshold {} ns)",
        status.max_difference_ns, s->config.dc->lock_threshold.count());
    switch (s->config.dc->lock_policy) {
      case LockPolicy::advisory:
        return;
      case LockPolicy::recovering:
        raise_runtime_fault(kKey, why);
        return;
      case LockPolicy::fatal:
        end_session(s, "dc_lock_lost", Error(Errc::stale, why), true);
        return;
    }
  }

  // The reference design's DC runtime failure: consecutive reference-time exchanges unanswered
  // are a critical runtime fault (recovering, whatever the lock policy: without the FRMW the
  // slaves' clocks drift apart); the retry loop restarts the runtime's lock tracking, and the
  // first answered exchange clears the fault.
  static constexpr const char* kDcRuntimeKey = "dc:runtime";
  void on_dc_runtime(const std::shared_ptr<Session>& s, bool healthy) {
    if (s->stopping || session != s || !s->dc) return;
    if (healthy) {
      events.publish(
          make_event(EventKind::recovery_step, "dc", "distributed-clock runtime answered again"));
      clear_runtime_fault(kDcRuntimeKey);
      return;
    }
    const auto status = s->dc->status();
    raise_runtime_fault(
        kDcRuntimeKey,
        fmt::format("distributed clocks: {} consecutive reference-time exchanges (FRMW 0x0910 "
                    "to station {:#06x}) failed",
                    status.consecutive_failures, status.reference_station));
  }

  // DcConfig::await_lock: activation drives the slaves up only once the clocks are locked.
  exec::Task<Result<void>> await_lock(std::shared_ptr<Session> s) {
    if (!s->config.dc || !s->dc) co_return ok();
    // Warm-up: the maintainer sends this many drift-compensation FRMWs (counted as sent, each one
    // cycle) before any slave goes on to SAFEOP, so their clocks have converged when SYNC starts.
    const std::uint64_t warmup = s->config.dc->warmup_cycles;
    const auto warmup_limit =
        exec::Clock::now() + s->config.dc->cycle * (2 * warmup) + s->config.dc->lock_timeout;
    while (s->dc->status().frmw_sent < warmup) {
      if (s->stopping) co_return Error(Errc::closed, "session stopped");
      if (exec::Clock::now() >= warmup_limit) {
        co_return Error(Errc::timeout,
                        fmt::format("distributed clocks: {} of {} warm-up cycles in time",
                                    s->dc->status().frmw_sent, warmup));
      }
      co_await exec::sleep_for(loop, 1ms);
    }
    if (!s->config.dc->await_lock) co_return ok();
    const auto deadline = exec::Clock::now() + s->config.dc->lock_timeout;
    while (!s->dc->locked()) {
      if (s->stopping) co_return Error(Errc::closed, "session stopped");
      if (exec::Clock::now() >= deadline) {
        co_return Error(
            Errc::timeout,
            fmt::format("distributed clocks did not lock within {} ms (max difference "
                        "{} ns)",
                        ms(s->config.dc->lock_timeout).count(), s->dc->status().max_difference_ns));
      }
      co_await exec::sleep_for(loop, 1ms);
    }
    co_return ok();
  }

  // ---- activation ----------------------------------------------------------------------------

  // Brings every activatable slave to min(desired, its target), starting the domains first.
  // Ends operational / deactivated / preop_ready, or activation_blocked with the failures kept.
  // One activation at a time: one asked for while another runs (a retry timer and a cleared
  // fault can both start one) makes the running one go round again instead of racing it (two
  // overlapping runs once ended in operational and then asked for operational ->
  // activation_blocked, which the diagram does not draw). Loop thread; the flags are the
  // session's (a stopped session takes them along).
  exec::Task<void> run_activation(std::shared_ptr<Session> s) {
    if (s->activation_running) {
      // The running one goes round again; a caller that awaits this (activate, deactivate) sees
      // the state that run ends in.
      s->activation_again = true;
      while (s->activation_running && !s->stopping)
        co_await exec::sleep_for(loop, 1ms);
      co_return;
    }
    s->activation_running = true;
    do {
      s->activation_again = false;
      co_await activate_once(s);
    } while (s->activation_again && !s->stopping && session == s);
    s->activation_running = false;
  }

  exec::Task<void> activate_once(std::shared_ptr<Session> s) {
    TargetState want;
    {
      // The failures of the last attempt stay readable until this one has its own (they are
      // replaced below): a status read meanwhile must not find a blocked session without them.
      std::lock_guard lock(mutex);
      want = desired;
    }
    if (want != TargetState::preop) {
      // What this activation starts, so that an activation error can roll it back.
      std::vector<Domain*> idle_domains;
      for (auto& d : s->domains) {
        if (d->state() != DomainState::cycling) idle_domains.push_back(d.get());
      }
      const bool dc_was_running = s->dc && s->dc->cycler() != nullptr;
      start_cycling(*s);
      // Activation restores health polling, also of slaves held in PREOP and of slaves whose
      // poll was configured while the session was held (scenarios 49-51).
      s->health_held = false;
      for (auto& slave : s->slaves)
        SlaveAccess::start_health(*slave, s);
      if (auto locked = co_await await_lock(s); !locked) {
        if (s->stopping || session != s) co_return;
        // An activation error (the clocks did not lock or warm up in time) rolls back the
        // runtime this activation started, as the reference does: the domains it started stop,
        // a DC runtime it started stops. No slave has left PREOP yet. Unlike the reference
        // (which ends a startup activation or answers activate() with the error and stays), the
        // session is activation_blocked and tries again every retry_interval (ARCHITECTURE.md).
        for (std::size_t i = 0; i < s->domains.size(); ++i) {
          Domain& d = *s->domains[i];
          const bool started_here =
              std::find(idle_domains.begin(), idle_domains.end(), &d) != idle_domains.end();
          if (started_here && d.state() == DomainState::cycling && d.stop_cycling()) {
            publish_domain_state(i, d, DomainState::cycling, DomainState::stopped,
                                 "activation rolled back");
          }
        }
        if (!dc_was_running && s->dc && s->cycler) (void)s->cycler->remove(*s->dc);
        {
          std::lock_guard lock(mutex);
          activation_error = locked.error();
        }
        if (current() != MasterState::recovering) transition(MasterState::activation_blocked);
        arm_retry(s);
        co_return;
      }
    }
    std::vector<exec::Task<Result<void>>> steps;
    std::vector<Slave*> order;
    // While recovering, and while the session already stands operational at an OP target (a
    // second pass of run_activation after recovery ended in operational), a retained PREOP
    // failure of a slave without process data is a slave-local fault its own retry loop heals:
    // it neither holds the session in recovering nor blocks a running one (operational ->
    // activation_blocked is not drawn: that second pass once asked for it and was refused).
    const MasterState at_start = current();
    const bool slave_local_skipped =
        at_start == MasterState::recovering ||
        (at_start == MasterState::operational && want == TargetState::op);
    for (auto& slave : s->slaves) {
      const auto target = min_target(want, SlaveAccess::target(*slave));
      if (SlaveAccess::awaiting_rebuild(*slave)) continue;
      if (!hot_connect_walkable(*s, *slave)) continue;  // a group not (yet) present
      if (slave_local_skipped && retained_slave_local(*slave)) continue;
      order.push_back(slave.get());
      steps.push_back(SlaveAccess::go_to(*slave, target, s));
    }
    auto results = co_await exec::when_all(loop, std::move(steps));
    if (s->stopping || session != s) co_return;
    std::map<std::string, ActivationFailure> failures;
    for (std::size_t i = 0; i < results.size(); ++i) {
      const auto target = min_target(want, SlaveAccess::target(*order[i]));
      if (results[i]) {
        // `operational` means every slave driven here is at its target: a walk that reported
        // success but left the slave elsewhere (it dropped back meanwhile, or a step was skipped)
        // keeps the session blocked and says where the slave is.
        const auto now = order[i]->state();
        if (al_state_of(now) == target) continue;
        results[i] = Error(Errc::wrong_state,
                           fmt::format("slave {} is {} after its walk to {}", order[i]->name(),
                                       to_string(now), wire::to_string(target)));
      }
      failures.emplace(order[i]->name(),
                       ActivationFailure{order[i]->name(), target, results[i].error(),
                                         al_status_code(results[i].error())});
    }
    if (want == TargetState::preop) stop_cycling(*s);
    const bool blocked = !failures.empty();
    {
      std::lock_guard lock(mutex);
      // Each failure once while it lasts (activation is retried every retry_interval).
      for (const auto& [name, f] : failures) {
        auto before = activation_failures.find(name);
        if (before != activation_failures.end() &&
            before->second.error.describe() == f.error.describe()) {
          continue;
        }
        Event e = make_event(EventKind::activation_failed, name, f.error.describe());
        e.value = f.al_status_code.value_or(0);
        events.publish(e);
      }
      activation_failures = std::move(failures);
      activation_error.reset();
      if (blocked) {
        const auto& first = activation_failures.begin()->second;
        activation_error =
            first.error.context(fmt::format("activation to {} blocked for {} slave(s)",
                                            to_string(want), activation_failures.size()));
      }
    }
    if (blocked) {
      if (current() == MasterState::operational && want != TargetState::op) {
        // A deactivation that did not complete: the session settles at the level asked for and
        // is blocked there (the diagram draws operational -> deactivated / preop_ready and their
        // exits to activation_blocked; operational -> activation_blocked it does not).
        transition(state_for(want));
      }
      // From recovering the diagram has no edge to activation_blocked: recovery goes on.
      if (current() != MasterState::recovering) transition(MasterState::activation_blocked);
      arm_retry(s);
      co_return;
    }
    bool faults;
    {
      std::lock_guard lock(mutex);
      faults = !runtime_faults.empty() && want != TargetState::preop;
    }
    if (faults && current() == MasterState::recovering) {
      arm_retry(s);
      co_return;
    }
    // The session state follows what the slaves were driven to: min(session target, slave
    // target), the highest of those (a session whose slaves are all held in PREOP stays
    // preop_ready even when OP is desired).
    TargetState reached = TargetState::preop;
    for (auto& slave : s->slaves) {
      if (SlaveAccess::absent(*slave)) continue;
      reached = std::max(reached, std::min(want, SlaveAccess::target(*slave)));
    }
    transition(state_for(reached));
  }

  void publish_domain_state(std::size_t index, const Domain& d, DomainState from, DomainState to,
                            std::string_view detail) {
    Event e = make_event(EventKind::domain_state, d.id(), detail);
    e.subject = static_cast<std::int32_t>(index);
    e.from = static_cast<std::uint8_t>(from);
    e.to = static_cast<std::uint8_t>(to);
    events.publish(e);
  }

  // While a session runs: what only counters and status show becomes events (DC lock gained and
  // lost, the bus's frame losses and time-outs at 1, 10, 100 ..., the link failing).
  exec::Task<void> watch(std::shared_ptr<Session> s) {
    bool locked = false;
    std::uint64_t lost_mark = 1;
    std::uint64_t timeout_mark = 1;
    while (!s->stopping && session == s) {
      co_await exec::sleep_for(loop, kWatchPeriod);
      if (s->stopping || session != s) break;
      if (s->dc) {
        const auto dc = s->dc->status();
        if (dc.locked != locked) {
          locked = dc.locked;
          Event e = make_event(locked ? EventKind::dc_locked : EventKind::dc_lost);
          e.value = static_cast<std::uint64_t>(dc.max_difference_ns < 0 ? -dc.max_difference_ns
                                                                        : dc.max_difference_ns);
          events.publish(e);
        }
      }
      const auto stats = s->bus->stats();
      cross_marks(EventKind::frames_lost, stats.frames_lost, lost_mark);
      cross_marks(EventKind::timeouts, stats.transaction_timeouts, timeout_mark);
      if (!watch_link(s)) co_return;
    }
  }
  static constexpr std::chrono::milliseconds kWatchPeriod{50};

  struct LinkWatch {
    std::uint64_t failures = 0;  // bus counts seen so far
    std::uint64_t reopens = 0;
    std::optional<exec::Clock::time_point> down_since;
    // A redundant link's topology and ring as last reported (link.redundancy events).
    std::optional<std::pair<link::RedundancyTopology, link::RingState>> redundancy;
    // While the ring is broken, the slaves' DL status is read again every kLocatePeriod (the
    // break may move without the ring's state changing): one locate_break at a time.
    bool locating = false;
    std::optional<exec::Clock::time_point> located_at;
    std::optional<link::RingBreak> reported;  // the break the last event named
    // The ring's shape (which slave hangs on which port of which: ring_tree), read while the
    // ring was whole, for the slaves at `shape_stations` in ring order; a break is located on it
    // (on a ring through junctions the line rule would take a branch's end for a break). A ring
    // broken since start has the shape its two sides show (broken_ring_tree), when they fit one
    // tree only (`shape_whole` false): replaced by the whole ring's once it is whole.
    std::optional<RingTree> shape;
    std::vector<std::uint16_t> shape_stations;
    bool shape_whole = false;
    bool learning_shape = false;
    bool shape_seeded = false;  // seed_ring_shape built its tree, or found it would not hold
    std::optional<exec::Clock::time_point> shape_tried_at;
    // DC across a break (apply_dc_reach): the DC slaves the reference's time cannot reach (the
    // secondary's copy of the FRMW is a NOP meanwhile), and a re-step after the heal running.
    std::vector<std::uint16_t> dc_unreached;
    bool dc_restepping = false;
  };
  static constexpr std::chrono::milliseconds kLocatePeriod{200};
  std::optional<link::RingBreak> ring_break;  // guarded by `mutex`; for status()
  LinkWatch link_watch;                       // loop thread; the current session's

  // The link as the bus reports it. A failed link is reopened by the bus with a bounded backoff:
  // meanwhile the session is recovering (runtime fault "link"), and it heals by itself once the
  // link is back. A link not back within link_recovery_window, one that cannot be reopened at
  // all, or a bus that stopped under the session is a fatal subsystem exit: the session ends in
  // idle with last_failure saying why. False when the session ended here.
  // Runs every watch period and at once when the bus reports a change (BusOptions::
  // on_link_change). A fatal exit is checked first: a link that cannot come back ends the session
  // straight from where it is, before the loss shows as a runtime fault.
  bool watch_link(const std::shared_ptr<Session>& s) {
    if (s->stopping || session != s) return false;
    LinkWatch& w = link_watch;
    const auto info = s->bus->info();
    const auto now = exec::Clock::now();
    if (!info.running) {
      end_session(s, "bus_stopped",
                  Error(Errc::closed, fmt::format("the bus on link {} stopped while the session "
                                                  "ran",
                                                  info.link_name)));
      return false;
    }
    if (info.link_failure && !info.link_reopenable) {
      const Error& cause = *info.link_failure;
      if (info.link_failures != w.failures) {
        events.publish(make_event(EventKind::link_down, {}, cause.describe()));
      }
      end_session(
          s, "link_lost",
          cause.context(
              cause.code(),
              fmt::format("link {} failed and cannot be reopened{}", info.link_name,
                          info.last_reopen_error ? " (" + info.last_reopen_error->describe() + ")"
                                                 : std::string())));
      return false;
    }
    if (info.link_failures != w.failures) {
      w.failures = info.link_failures;
      if (!w.down_since) w.down_since = now;
      const std::string why = info.link_failure ? info.link_failure->describe()
                                                : fmt::format("link {} failed", info.link_name);
      events.publish(make_event(EventKind::link_down, {}, why));
      raise_runtime_fault(kLinkFaultKey, why);
    }
    if (info.redundancy) {
      const auto seen = std::make_pair(info.redundancy->topology, info.redundancy->ring);
      if (seen != w.redundancy && seen.second != link::RingState::unknown) {
        w.redundancy = seen;
        if (seen.second == link::RingState::broken) {
          // The event waits for the slaves' word on where the ring is open.
          w.reported.reset();
          if (!w.locating) {
            w.locating = true;
            exec::spawn(loop, locate_break(s, true));
          }
        } else {
          {
            std::lock_guard lock(mutex);
            ring_break.reset();
          }
          w.reported.reset();
          apply_dc_reach(s, std::nullopt);
          events.publish(make_event(EventKind::link_redundancy, {},
                                    fmt::format("{}, ring {}", link::to_string(seen.first),
                                                link::to_string(seen.second))));
        }
      } else if (w.redundancy && w.redundancy->second == link::RingState::broken && !w.locating &&
                 (!w.located_at || now - *w.located_at >= kLocatePeriod)) {
        w.locating = true;
        exec::spawn(loop, locate_break(s, false));
      }
      if (!w.shape && !w.shape_seeded) seed_ring_shape(*s);
      if (w.redundancy && w.redundancy->second == link::RingState::whole && !w.learning_shape &&
          (!w.shape_tried_at || now - *w.shape_tried_at >= kLocatePeriod)) {
        auto stations = ring_stations(*s);
        if (stations != w.shape_stations || !w.shape || !w.shape_whole) {
          w.learning_shape = true;
          w.shape_tried_at = now;
          exec::spawn(loop, learn_ring_shape(s, std::move(stations)));
        }
      }
    }
    if (info.link_reopens != w.reopens) {
      w.reopens = info.link_reopens;
      Event e = make_event(EventKind::link_reopened, {}, info.link_name);
      e.value = info.reopen_attempts;
      events.publish(e);
    }
    if (w.down_since && !info.link_failure) {
      w.down_since.reset();
      clear_runtime_fault(kLinkFaultKey);
    }
    if (!w.down_since || !info.link_failure) return true;
    if (now - *w.down_since >= s->config.link_recovery_window) {
      const Error& cause = *info.link_failure;
      end_session(
          s, "link_lost",
          cause.context(cause.code(),
                        fmt::format("link {} did not come back within {} ms ({} reopen attempts; "
                                    "last: {})",
                                    info.link_name, ms(s->config.link_recovery_window).count(),
                                    info.reopen_attempts,
                                    info.last_reopen_error ? info.last_reopen_error->describe()
                                                           : std::string("none"))));
      return false;
    }
    return true;
  }
  static constexpr const char* kLinkFaultKey = "link";

  // The stations of the slaves in the ring, in ring order: the session's slaves that are there
  // (a hot-connect group's only while present; a group on a junction port shifts the positions
  // of the fixed slaves behind it), or base + position without hot connect.
  static std::vector<std::uint16_t> ring_stations(const Session& s) {
    std::vector<std::uint16_t> out;
    if (s.hot_connect.empty()) {
      for (std::uint16_t pos = 0; pos < s.slave_count; ++pos)
        out.push_back(static_cast<std::uint16_t>(s.config.base_station + pos));
      return out;
    }
    std::vector<std::pair<std::uint16_t, std::uint16_t>> at;  // position, station
    for (const auto& slave : s.slaves) {
      if (!SlaveAccess::absent(*slave)) at.emplace_back(slave->position(), slave->station());
    }
    std::sort(at.begin(), at.end());
    for (const auto& [pos, station] : at)
      out.push_back(station);
    return out;
  }

  // Every listed slave's DL status (0x0110), one frame through both ports; none where a read
  // was not answered.
  exec::Task<Result<std::vector<RingPortReading>>> read_ring_ports(
      std::shared_ptr<Session> s, const std::vector<std::uint16_t>& stations) {
    std::vector<RingPortReading> readings(stations.size());
    if (stations.empty()) co_return readings;
    bus::Transaction tx;
    for (std::size_t i = 0; i < stations.size(); ++i) {
      readings[i].station = stations[i];
      tx.fprd(stations[i], wire::reg::kDlStatus, 2);
    }
    auto reply = co_await exec::transact(loop, *s->bus, std::move(tx));
    if (!reply) co_return reply.error();
    for (std::size_t i = 0; i < stations.size(); ++i) {
      if (reply->wkc(i) == 1) {
        readings[i].dl_status = wire::DlStatus::decode(wire::load_le16(reply->data(i).data()));
      }
    }
    co_return readings;
  }

  // The shape from the DL status the startup read (Session::dl_status, by ring position), when
  // the ring has not changed since: a whole ring's tree, or, on a ring broken at the start, the
  // tree its two sides make (broken_ring_tree, from the sides counted and the port descriptors
  // read at the start) when they fit only one; otherwise none (the line rule), until it is whole.
  void seed_ring_shape(const Session& s) {
    LinkWatch& w = link_watch;
    auto stations = ring_stations(s);
    if (stations != s.start_ring_stations || s.dl_status.size() != stations.size()) return;
    w.shape_seeded = true;  // the start-up's reading is what it is: one try
    std::vector<std::uint16_t> dl;
    for (const auto& d : s.dl_status)
      dl.push_back(d.encode());
    auto tree = ring_tree(dl, stations, true);
    if (tree && tree->return_port) {
      w.shape = std::move(*tree);
      w.shape_whole = true;
      w.shape_stations = std::move(stations);
      return;
    }
    if (!s.start_sides || s.port_descriptors.size() != stations.size()) return;
    auto broken = broken_ring_tree(dl, s.port_descriptors, stations, s.start_sides->primary);
    if (!broken) return;
    w.shape = std::move(*broken);
    w.shape_whole = false;
    w.shape_stations = std::move(stations);
  }

  // The whole ring's shape, from its slaves' DL status (ring_tree, the last slave's free port
  // the cable back to the secondary port). Kept only when every slave answered, the tree holds
  // and the ring was still whole.
  exec::Task<void> learn_ring_shape(std::shared_ptr<Session> s,
                                    std::vector<std::uint16_t> stations) {
    auto readings = co_await read_ring_ports(s, stations);
    if (session != s || s->stopping) co_return;
    LinkWatch& w = link_watch;
    w.learning_shape = false;
    if (!readings || !w.redundancy || w.redundancy->second != link::RingState::whole) co_return;
    std::vector<std::uint16_t> dl;
    for (const auto& r : *readings) {
      if (!r.dl_status) co_return;
      dl.push_back(r.dl_status->encode());
    }
    auto tree = ring_tree(dl, stations, true);
    if (!tree) co_return;
    w.shape = std::move(*tree);
    w.shape_whole = true;
    w.shape_stations = std::move(stations);
  }

  // Where the broken redundant ring is open: every slave's DL status (0x0110), one frame through
  // both ports (locate_ring_break). Publishes link.redundancy naming the break when `announce`
  // (the ring was just seen broken) or when the break moved; the ring healed meanwhile: nothing.
  // On the ring's shape when one was read for these slaves (learn_ring_shape), else as a line.
  exec::Task<void> locate_break(std::shared_ptr<Session> s, bool announce) {
    const std::vector<std::uint16_t> stations = ring_stations(*s);
    std::vector<RingPortReading> readings;
    std::optional<Error> failed;
    if (auto r = co_await read_ring_ports(s, stations)) {
      readings = std::move(*r);
    } else {
      failed = r.error();
    }
    LinkWatch& w = link_watch;
    if (session != s || s->stopping) co_return;
    w.locating = false;
    w.located_at = exec::Clock::now();
    if (!w.redundancy || w.redundancy->second != link::RingState::broken) co_return;
    std::optional<link::RingBreak> found;
    if (!failed) {
      found = w.shape && w.shape_stations == stations ? locate_ring_break(readings, *w.shape)
                                                      : locate_ring_break(readings);
    }
    {
      std::lock_guard lock(mutex);
      ring_break = found;
    }
    if (found) apply_dc_reach(s, found);
    if (!announce && found == w.reported) co_return;
    w.reported = found;
    std::string where;
    if (found) {
      where = " " + link::describe(*found);
    } else if (failed) {
      where = " (not located: " + failed->describe() + ")";
    } else {
      where = " (not located: every slave that answered reports its links up)";
    }
    events.publish(
        make_event(EventKind::link_redundancy, {},
                   fmt::format("{}, ring broken{}", link::to_string(w.redundancy->first), where)));
  }

  // Distributed clocks across a break of a redundant ring. With the ring broken between slaves
  // and the reference on the primary's side, the slaves behind the break see only the
  // secondary's copy of the reference-time FRMW, which carries the master's host-clock
  // prediction (no reference reads it on that side): tens of microseconds of host jitter that no
  // measurement can remove. So that copy goes out as a NOP (Link::set_port_nop) and those slaves
  // free-run on their last drift correction, outside the lock (DcSlaveStatus::free_running), the
  // others locked. The link applies the NOP from the next frame after the break (armed in
  // start_dc: only while the primary's side reads the FRMW); here the master learns which slaves
  // it cut off, once the break is located. A reference behind the break is reached by the
  // secondary's frame first, as on a whole ring: nothing to do. When the ring is whole again (or
  // cut at a master port, where one port's frame passes every slave in ring order), the mask ends,
  // the delays are measured again and the slaves that free-ran are stepped back onto the
  // reference's time (restep_dc_slaves); they rejoin the lock once within the threshold. `found`:
  // where the ring is open now (none: whole).
  void apply_dc_reach(const std::shared_ptr<Session>& s,
                      const std::optional<link::RingBreak>& found) {
    if (!s->dc || !s->dc_init || session != s || s->stopping) return;
    LinkWatch& w = link_watch;
    const DcPlan& plan = s->dc_init->plan;
    std::vector<std::uint16_t> unreached;
    if (found && found->where == link::RingBreak::Where::between_slaves &&
        plan.reference_position <= found->before_position) {
      for (const auto& p : plan.slaves)
        if (p.dc && p.position >= found->after_position) unreached.push_back(p.station);
    }
    if (unreached == w.dc_unreached) return;
    if (!unreached.empty()) {
      s->dc->set_free_running(unreached);
      std::string list;
      for (const std::uint16_t st : unreached)
        list += fmt::format("{}0x{:04X}", list.empty() ? "" : ", ", st);
      events.publish(make_event(
          EventKind::recovery_step, "dc",
          fmt::format("ring broken {}: DC slaves {} free-run on their last drift correction, "
                      "outside the lock (the reference 0x{:04X} cannot reach them)",
                      link::describe(*found), list, plan.reference_station)));
      w.dc_unreached = std::move(unreached);
      return;
    }
    std::vector<std::uint16_t> free_ran = std::move(w.dc_unreached);
    w.dc_unreached.clear();
    if (!w.dc_restepping) {
      w.dc_restepping = true;
      exec::spawn(loop, restep_dc(s, std::move(free_ran)));
    }
  }

  exec::Task<void> restep_dc(std::shared_ptr<Session> s, std::vector<std::uint16_t> free_ran) {
    DcInitOptions options;
    options.threshold = s->config.dc->lock_threshold;
    options.plan.ring_returns_to_master = true;
    auto result = co_await restep_dc_slaves(loop, *s->bus, s->dc_init->plan, free_ran, options);
    if (session != s || s->stopping) co_return;
    link_watch.dc_restepping = false;
    if (!result) {
      // Left outside the lock: their time is not known to be right.
      events.publish(
          make_event(EventKind::recovery_step, "dc",
                     "distributed clocks after the ring healed: " + result.error().describe()));
      co_return;
    }
    {
      std::lock_guard lock(mutex);
      s->dc_init->plan = std::move(result->plan);
    }
    // Broken again meanwhile: they stay outside the lock (apply_dc_reach named them again).
    if (link_watch.dc_unreached.empty()) s->dc->rejoin_free_running();
    std::string steps;
    for (const auto& step : result->stepped)
      steps +=
          fmt::format("{}0x{:04X} by {} ns", steps.empty() ? "" : ", ", step.station, step.step_ns);
    events.publish(
        make_event(EventKind::recovery_step, "dc",
                   fmt::format("ring whole again: delays measured again ({} changed), {}",
                               result->delays_changed.size(),
                               steps.empty() ? std::string("no slave had free-run")
                                             : "offsets stepped: " + steps)));
  }

  // A fatal subsystem exit: the session ends and the master goes idle with last_failure saying
  // why. With the link still up the slaves are walked to INIT first (a failure after the ring
  // is up leaves no slave in OP); without one they cannot be, and their SyncManager watchdogs
  // take them out of OP.
  void end_session(const std::shared_ptr<Session>& s, std::string kind, const Error& error,
                   bool link_usable = false) {
    if (session != s || s->stopping) return;
    {
      std::lock_guard lock(mutex);
      ended_error = error;
    }
    fail(std::move(kind), error);
    if (link_usable) {
      exec::spawn(loop, walk_down_and_end(s));
      return;
    }
    teardown();
    transition(MasterState::idle);
  }
  exec::Task<void> walk_down_and_end(std::shared_ptr<Session> s) {
    co_await leave_slaves_in_init(s);
    if (session != s) co_return;  // stop() ended the session meanwhile
    teardown();
    transition(MasterState::idle);
  }

  // One event each time `count` passes the next power of ten.
  void cross_marks(EventKind kind, std::uint64_t count, std::uint64_t& mark) {
    if (count < mark) return;
    while (mark <= count && mark < (std::uint64_t{1} << 62))
      mark *= 10;
    Event e = make_event(kind);
    e.value = count;
    events.publish(e);
  }

  static MasterState state_for(TargetState target) {
    switch (target) {
      case TargetState::op:
        return MasterState::operational;
      case TargetState::safeop:
        return MasterState::deactivated;
      case TargetState::preop:
        return MasterState::preop_ready;
    }
    return MasterState::preop_ready;
  }

  void start_cycling(Session& s) {
    if (!s.cycler) s.cycler = std::make_unique<Cycler>(*s.bus);
    start_dc(s);
    for (std::size_t i = 0; i < s.domains.size(); ++i) {
      Domain& d = *s.domains[i];
      const DomainState before = d.state();
      if (before == DomainState::cycling || d.registrations().empty()) continue;
      if (d.cycler() == nullptr) (void)s.cycler->add(d);
      if (!d.start_cycling()) continue;
      publish_domain_state(i, d, before, DomainState::cycling,
                           before == DomainState::stopped ? "restarted" : "");
      if (before == DomainState::stopped) {
        events.publish(make_event(EventKind::recovery_step, d.id(), "stopped domain restarted"));
      }
    }
    if (!s.cycler->running()) (void)s.cycler->start();
    arm_pump(s.shared_from_this());
  }

  void stop_cycling(Session& s) {
    for (std::size_t i = 0; i < s.domains.size(); ++i) {
      Domain& d = *s.domains[i];
      if (d.state() == DomainState::cycling && d.stop_cycling()) {
        publish_domain_state(i, d, DomainState::cycling, DomainState::stopped, "stopped");
      }
    }
  }

  // In activation_blocked / recovering: try again every retry_interval.
  void arm_retry(std::shared_ptr<Session> s) {
    if (retry_armed.exchange(true)) return;
    loop.call_after(s->config.retry_interval, [this, s] {
      retry_armed = false;
      if (s->stopping || session != s) return;
      const auto now = current();
      if (now != MasterState::activation_blocked && now != MasterState::recovering) return;
      exec::spawn(loop, retry(s));
    });
  }

  exec::Task<void> retry(std::shared_ptr<Session> s) {
    // Slaves with a retained configuration failure get it retried first.
    for (auto& slave : s->slaves) {
      if (slave->state() == SlaveState::preop) {
        (void)co_await SlaveAccess::retry_configuration(*slave, s);
      }
    }
    if (s->stopping || session != s) co_return;
    const auto now = current();
    if (now == MasterState::recovering) {
      bool faults;
      {
        std::lock_guard lock(mutex);
        faults = !runtime_faults.empty();
      }
      if (faults) {
        // Domains that stopped at the miss threshold are restarted; a fault clears when its
        // domain cycles validly again (on_cycle_recovered). A failed DC runtime is restarted:
        // its lock is counted afresh (the fault clears at its first answered exchange).
        bool dc_failed;
        {
          std::lock_guard lock(mutex);
          dc_failed = runtime_faults.count(kDcRuntimeKey) != 0;
        }
        if (dc_failed && s->dc) {
          s->dc->reset_lock();
          events.publish(make_event(EventKind::recovery_step, "dc",
                                    "distributed-clock runtime restarted (lock counted afresh)"));
        }
        start_cycling(*s);
        arm_retry(s);
        co_return;
      }
    }
    co_await run_activation(s);
  }

  // ---- domain events (bus thread: keep cheap, hand over to the loop) -------------------------

  void on_inputs_changed(Domain&, std::size_t) override {
    inputs_pending.store(true, std::memory_order_release);
  }
  // Rare events: the bus thread only posts (no formatting, no string copies); the text is made on
  // the loop, for a domain of the current session only.
  void on_cycle_degraded(Domain& domain, const CycleInvalid& invalid) override {
    Event e = make_event(EventKind::domain_health, domain.id());
    e.to = 0;
    e.value = static_cast<std::uint64_t>(invalid.reason);
    format_detail(e, "{} (expected wkc {}, got {})", to_string(invalid.reason),
                  invalid.expected_wkc, invalid.actual_wkc);
    events.publish(e);
    post_notice(domain, DomainNotice::Kind::degraded, invalid, 0);
  }
  void on_cycle_recovered(Domain& domain) override {
    Event e = make_event(EventKind::domain_health, domain.id());
    e.to = 1;
    events.publish(e);
    post_notice(domain, DomainNotice::Kind::recovered, {}, 0);
  }
  void on_stopped(Domain& domain, const CycleInvalid& invalid, std::uint64_t misses) override {
    Event e = make_event(EventKind::domain_state, domain.id());
    e.from = static_cast<std::uint8_t>(DomainState::cycling);
    e.to = static_cast<std::uint8_t>(DomainState::stopped);
    format_detail(e, "after {} consecutive misses ({})", misses, to_string(invalid.reason));
    events.publish(e);
    post_notice(domain, DomainNotice::Kind::stopped, invalid, misses);
  }
  // Bus thread (any thread): hands a notice to the loop without allocating.
  void post_notice(const Domain& domain, DomainNotice::Kind kind, const CycleInvalid& invalid,
                   std::uint64_t misses) noexcept {
    for (auto& n : notices) {
      bool free = false;
      if (!n.busy.compare_exchange_strong(free, true, std::memory_order_acquire)) continue;
      n.domain = &domain;
      n.kind = kind;
      n.invalid = invalid;
      n.misses = misses;
      loop.post(n);
      return;
    }
    notices_lost.store(true, std::memory_order_release);
  }
  // Loop thread: what a notice means for the session's runtime faults.
  void on_domain_notice(const Domain* d, DomainNotice::Kind kind, const CycleInvalid& invalid,
                        std::uint64_t misses) {
    if (owns(d)) {
      switch (kind) {
        case DomainNotice::Kind::degraded:
          raise_runtime_fault(
              "domain:" + d->id(),
              fmt::format("domain {}: {} (expected wkc {}, got {})", d->id(),
                          to_string(invalid.reason), invalid.expected_wkc, invalid.actual_wkc));
          break;
        case DomainNotice::Kind::recovered:
          clear_runtime_fault("domain:" + d->id());
          break;
        case DomainNotice::Kind::stopped:
          raise_runtime_fault("domain:" + d->id(),
                              fmt::format("domain {} stopped after {} consecutive misses ({})",
                                          d->id(), misses, to_string(invalid.reason)));
          break;
      }
    }
    if (!notices_lost.exchange(false, std::memory_order_acq_rel) || !session) return;
    // Some notice was dropped (the pool was exhausted): judge every cycling domain as it is now.
    for (const auto& domain : session->domains) {
      const DomainStats st = domain->stats();
      if (st.state != DomainState::cycling) continue;
      if (st.health.healthy) {
        clear_runtime_fault("domain:" + domain->id());
      } else if (st.health.invalid) {
        raise_runtime_fault(
            "domain:" + domain->id(),
            fmt::format("domain {}: {} (expected wkc {}, got {})", domain->id(),
                        to_string(st.health.invalid->reason), st.health.invalid->expected_wkc,
                        st.health.invalid->actual_wkc));
      }
    }
  }
  void on_reservation_lost(Domain& domain, std::uint32_t reservation) override {
    loop.post([this, d = &domain, reservation] {
      if (!owns(d)) return;
      auto s = session;
      for (auto& g : s->hot_connect) {
        for (const auto& [gd, r] : g.reservations) {
          if (gd == d && r == reservation) {
            group_lost(s, g,
                       fmt::format("its share of domain {}'s working counter vanished", d->id()));
            return;
          }
        }
      }
    });
  }
  // Whether `d` belongs to the running session (a late event may outlive its session).
  bool owns(const Domain* d) const {
    if (!session || session->stopping) return false;
    for (const auto& mine : session->domains) {
      if (mine.get() == d) return true;
    }
    return false;
  }

  void raise_runtime_fault(const std::string& key, const std::string& why) {
    auto s = session;
    if (!s || s->stopping) return;
    bool changed_fault = false;
    {
      std::lock_guard lock(mutex);
      auto& kept = runtime_faults[key];
      changed_fault = kept != why;
      kept = why;
    }
    if (changed_fault) events.publish(make_event(EventKind::fault_raised, key, why));
    const auto now = current();
    if (now == MasterState::operational || now == MasterState::deactivated ||
        now == MasterState::preop_ready || now == MasterState::activation_blocked) {
      transition(MasterState::recovering);
      arm_retry(s);
    }
  }

  void clear_runtime_fault(const std::string& key) {
    auto s = session;
    if (!s || s->stopping) return;
    bool empty;
    std::string cleared;
    {
      std::lock_guard lock(mutex);
      if (auto it = runtime_faults.find(key); it != runtime_faults.end()) {
        cleared = std::move(it->second);
        runtime_faults.erase(it);
      }
      empty = runtime_faults.empty();
    }
    if (!cleared.empty()) events.publish(make_event(EventKind::fault_cleared, key, cleared));
    if (empty && current() == MasterState::recovering) {
      events.publish(
          make_event(EventKind::recovery_step, key, "runtime faults cleared: activating again"));
      exec::spawn(loop, run_activation(s));
    }
  }

  // ---- slave notices (loop) -------------------------------------------------------------------

  // A retained PREOP failure of a slave configured without process data. A slave configured
  // with process data whose registration failed has no attachments either, yet it is not
  // slave-local: the session without its data is not operational (it stays blocked).
  static bool retained_slave_local(Slave& slave) {
    return SlaveAccess::retained_failure_without_process_data(slave);
  }

  static bool carries_process_data(Slave& slave) {
    return SlaveAccess::carries_process_data(slave);
  }

  void on_notice(const SlaveNotice& notice) {
    auto s = session;
    if (!s || s->stopping) return;
    Slave* slave = s->find_slave(notice.slave);
    if (!slave) return;
    if (HotConnectRuntime* g = group_of(*s, *slave); g && notice.kind == SlaveNotice::Kind::down) {
      // A group's slave lost: the group left the ring (or part of it did); it joins again when
      // it is found again. Not a fault of the session.
      group_lost(s, *g, fmt::format("slave {} stopped answering", notice.slave));
      return;
    }
    const std::string key = "slave:" + notice.slave;
    switch (notice.kind) {
      case SlaveNotice::Kind::down:
        // A lost slave that carries process data breaks its domains: critical. Others are
        // tracked as slave-local faults while the session stays where it is.
        if (carries_process_data(*slave)) {
          raise_runtime_fault(key,
                              fmt::format("slave {} is down: {}", notice.slave, notice.detail));
        }
        break;
      case SlaveNotice::Kind::retreated:
        events.publish(
            make_event(EventKind::recovery_step, notice.slave, "retreated: back to its target"));
        arm_slave_retry(s);
        break;
      case SlaveNotice::Kind::reconnected:
        events.publish(make_event(EventKind::recovery_step, notice.slave,
                                  "reconnected and rebuilt to PREOP: back to its target"));
        exec::spawn(loop, restore_slave(s, slave, key));
        break;
    }
  }

  // Brings a slave that came back (or retreated) to its runtime target: min(session target, its
  // configured target). Clears its runtime fault when it gets there.
  // `retry_configuration`: from the retry loop only, so that a failure retained by a rebuild stays
  // visible for a retry interval (as the reference's 1 s retry) instead of being re-run at once.
  exec::Task<void> restore_slave(std::shared_ptr<Session> s, Slave* slave, std::string key,
                                 bool retry_configuration = false) {
    TargetState want;
    {
      std::lock_guard lock(mutex);
      want = desired;
    }
    const auto state_now = current();
    if (state_now == MasterState::preop_ready) want = TargetState::preop;
    auto target = min_target(want, SlaveAccess::target(*slave));
    // A PREOP configuration failure retained by a rebuild is retried first (go_to refuses
    // SAFEOP/OP while it stands); without this the slave would stay in PREOP for good.
    if (retry_configuration && slave->state() == SlaveState::preop &&
        target != wire::AlState::preop) {
      auto retried = co_await SlaveAccess::retry_configuration(*slave, s);
      if (s->stopping || session != s) co_return;
      if (!retried) {
        arm_slave_retry(s);
        co_return;
      }
    }
    auto done = co_await SlaveAccess::go_to(*slave, target, s);
    if (s->stopping || session != s) co_return;
    if (!done) {
      arm_slave_retry(s);
      co_return;
    }
    SlaveAccess::clear_fault(*slave);
    clear_runtime_fault(key);
  }

  std::atomic<bool> slave_retry_armed{false};
  void arm_slave_retry(std::shared_ptr<Session> s) {
    if (slave_retry_armed.exchange(true)) return;
    loop.call_after(s->config.retry_interval, [this, s] {
      slave_retry_armed = false;
      if (s->stopping || session != s) return;
      const auto now = current();
      if (now != MasterState::operational && now != MasterState::deactivated &&
          now != MasterState::recovering) {
        return;
      }
      TargetState want;
      {
        std::lock_guard lock(mutex);
        want = desired;
      }
      for (auto& slave : s->slaves) {
        const auto target = min_target(want, SlaveAccess::target(*slave));
        const auto st = slave->state();
        if (SlaveAccess::awaiting_rebuild(*slave)) continue;
        if (!hot_connect_walkable(*s, *slave)) continue;
        if (al_state_of(st) != target) {
          exec::spawn(loop, restore_slave(s, slave.get(), "slave:" + slave->name(), true));
        }
      }
    });
  }

  // Delivers input changes to subscribers on the loop.
  void arm_pump(std::shared_ptr<Session> s) {
    auto period = 1ms;
    loop.call_after(period, [this, s] {
      if (s->stopping || session != s) return;
      if (inputs_pending.exchange(false, std::memory_order_acq_rel)) {
        for (auto& d : s->domains) {
          d->drain_changes([&](const InputChange& change) {
            for (auto& slave : s->slaves) {
              if (slave->station() == change.key.slave) {
                SlaveAccess::on_input_change(*slave, change);
              }
            }
          });
        }
      }
      arm_pump(s);
    });
  }

  // ---- teardown ------------------------------------------------------------------------------

  // A stopped session leaves its slaves in INIT, outputs no longer driven by process data (their
  // SyncManager watchdogs would otherwise trip in SAFEOP/OP). Best effort and bounded: slaves
  // that are gone or do not answer are left as they are.
  exec::Task<void> leave_slaves_in_init(std::shared_ptr<Session> s) {
    s->stopping = true;  // health polls and retries end instead of reacting to the walk down
    if (s->cycler) (void)s->cycler->stop();
    if (!s->bus || s->slave_count == 0) co_return;
    (void)co_await init_all(loop, *s->bus, s->slave_count, s->config.base_station,
                            {.attempts = 10, .interval = 5ms});
  }

  // Stops the session's cycle and bus; the objects go when the last task holding them ends.
  void teardown() {
    auto s = session;
    if (!s) return;
    {
      std::lock_guard lock(mutex);
      ending = s;
    }
    s->stopping = true;
    if (s->cycler) (void)s->cycler->stop();
    if (s->bus) s->bus->stop();
    // The bus thread has ended: what it held for the session (cpu_dma_latency, the memory lock)
    // goes now, not when the last task lets the session go.
    s->cycle_thread_holds.release();
    std::lock_guard lock(mutex);
    // What the session counted to its very end (the walk back to INIT included): counters()
    // gives it until the next start, so a tool can compare a capture with the bus's own counts.
    final_counters = collect_counters(*s);
    session.reset();
  }

  // The counts of a session (under `mutex`).
  static MasterCounters collect_counters(const Session& s) {
    MasterCounters out;
    if (s.bus) {
      const auto b = s.bus->stats();
      out.frames_sent = b.frames_sent;
      out.frames_received = b.frames_received;
      out.frames_lost = b.frames_lost;
      out.transaction_timeouts = b.transaction_timeouts;
      out.retries = b.retries;
      out.realtime_expired = b.realtime_expired;
      out.cycle_deadlines_missed = b.cycle_deadlines_missed;
    }
    for (const auto& d : s.domains) {
      const auto st = d->stats();
      out.domains.push_back(
          {d->id(), st.cycle_count, st.valid_count, st.wkc_mismatch_count, st.total_miss_count});
    }
    for (const auto& slave : s.slaves)
      out.slaves.push_back(SlaveAccess::counters(*slave));
    if (s.dc) out.dc_max_difference_ns = s.dc->status().max_difference_ns;
    return out;
  }
  std::optional<MasterCounters> final_counters;  // the last session's, once it ended (mutex)

  void shutdown() {
    if (current() != MasterState::idle || session) {
      auto done = exec::run_blocking(loop, stop_task(), 10s);
      (void)done;
    }
    await_session_end();
  }

  // Waits (on the caller's thread, the loop running) until the tasks of the last session have run
  // out: a task sleeping in a health poll wakes, sees `stopping` and ends, releasing the session.
  // Without this, a loop stopped under a sleeping task would never free what it holds.
  std::weak_ptr<Session> ending;
  void await_session_end() {
    std::weak_ptr<Session> previous;
    {
      std::lock_guard lock(mutex);
      previous = ending;
    }
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (!previous.expired() && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
    }
  }

  exec::Task<Result<StopOutcome>> stop_task() {
    if (!session) co_return StopOutcome::already_stopped;
    co_await leave_slaves_in_init(session);
    teardown();
    transition(MasterState::idle);
    co_return StopOutcome::stopped;
  }
};

// ---- public ---------------------------------------------------------------------------------

Master::Master(MasterConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}

Master::~Master() {
  // The endpoint's requests call this Master: none may run once its parts start to go.
  impl_->close_endpoint();
  impl_->close_gateway();
}

Result<void> Master::start(std::unique_ptr<link::Link> link, MasterConfig config) {
  if (state() != MasterState::idle) {
    return Error(Errc::wrong_state,
                 fmt::format("the master is already started ({})", to_string(state())));
  }
  impl_->config = std::move(config);
  return start(std::move(link));
}

Result<void> Master::start(std::unique_ptr<link::Link> link) {
  if (!link) return Error(Errc::invalid_argument, "start: no link given");
  if (auto valid = validate(impl_->config); !valid) return valid.error();
  if (state() == MasterState::idle) {
    if (auto opened = impl_->open_endpoint(*this); !opened) return opened.error();
    if (auto opened = impl_->open_gateway(*this); !opened) return opened.error();
  }
  auto started = exec::run_blocking(
      impl_->loop,
      [](Impl& impl, std::unique_ptr<link::Link> l) -> exec::Task<Result<void>> {
        if (impl.current() != MasterState::idle || impl.session) {
          co_return Error(Errc::wrong_state, fmt::format("the master is already started ({})",
                                                         to_string(impl.current())));
        }
        auto s = std::make_shared<Session>(impl.loop, impl.config);
        s->notify = [&impl](const SlaveNotice& notice) { impl.on_notice(notice); };
        s->events = &impl.events;
        bus::BusOptions options;
        if (impl.config.frame_timeout) {
          options.frame_timeout = *impl.config.frame_timeout;
        } else {
          // The auto-tuned timeout (auto_frame_timeout) is a guess from the slave count: late
          // replies let reliable frames wait longer instead of being re-sent (a simulator on a
          // loaded machine, a ring slower than its count says). A timeout the user set is kept.
          options.adaptive_frame_timeout_limit = kAdaptiveFrameTimeoutLimit;
        }
        options.thread_name = thread_name("ecat-cycle", impl.instance);
        if (asks_anything(impl.config.cycle_thread)) {
          // The session outlives its bus, so the report and the holds have a home when the
          // thread starts (the holds go with the session, after the bus thread ended).
          options.on_thread_start = [session = s.get()] {
            auto report =
                apply_cycle_thread(session->config.cycle_thread, session->cycle_thread_holds);
            std::lock_guard lock(session->report_mutex);
            session->cycle_thread_report = std::move(report);
          };
        }
        // Link news reaches the loop at once (the watch also polls, for the recovery window).
        options.on_link_change = [&impl, weak = std::weak_ptr<Session>(s)] {
          impl.loop.post([&impl, weak] {
            if (auto sp = weak.lock()) (void)impl.watch_link(sp);
          });
        };
        impl.link_watch = {};
        {
          std::lock_guard lock(impl.mutex);
          impl.ring_break.reset();
        }
        s->bus = std::make_unique<bus::Bus>(std::move(l), options);
        if (auto r = s->bus->start(); !r) co_return r.error().context("starting the bus");
        {
          std::lock_guard lock(impl.mutex);
          impl.startup_error.reset();
          impl.ended_error.reset();
          impl.activation_error.reset();
          impl.activation_failures.clear();
          impl.runtime_faults.clear();
        }
        {
          std::lock_guard lock(impl.mutex);
          impl.session = s;
        }
        impl.events.publish(make_event(EventKind::link_up, {}, s->bus->info().link_name));
        impl.transition(MasterState::discovering);
        exec::spawn(impl.loop, impl.startup(s));
        exec::spawn(impl.loop, impl.watch(s));
        co_return ok();
      }(*impl_, std::move(link)),
      kCallTimeout);
  if (!started) return Error(Errc::timeout, "start: the control thread did not answer");
  return std::move(*started);
}

Result<StopOutcome> Master::stop() {
  auto done = exec::run_blocking(impl_->loop, impl_->stop_task(), 10s);
  if (!done) return Error(Errc::timeout, "stop: the control thread did not answer");
  impl_->await_session_end();
  return std::move(*done);
}

MasterState Master::state() const noexcept {
  std::lock_guard lock(impl_->mutex);
  return impl_->state;
}

namespace {

template <class Pred>
Result<void> wait_for_state(Master::Impl& impl, std::chrono::nanoseconds timeout, Pred done,
                            bool running_counts, std::string_view what) {
  std::unique_lock lock(impl.mutex);
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    const auto s = impl.state;
    if (done(s)) return ok();
    if (s == MasterState::idle) {
      if (impl.startup_error)
        return impl.startup_error->context(fmt::format("{}: startup failed", what));
      if (impl.ended_error)
        return impl.ended_error->context(fmt::format("{}: the session ended", what));
      return Error(Errc::wrong_state, fmt::format("{}: the master is not started", what));
    }
    if (running_counts && s == MasterState::activation_blocked && impl.activation_error) {
      return *impl.activation_error;
    }
    if (running_counts && s == MasterState::recovering) {
      std::string faults;
      for (const auto& [k, v] : impl.runtime_faults)
        faults += (faults.empty() ? "" : "; ") + v;
      return Error(Errc::wrong_state,
                   fmt::format("{}: the session is recovering: {}", what, faults));
    }
    if (impl.changed.wait_until(lock, deadline) == std::cv_status::timeout && !done(impl.state)) {
      return Error(Errc::timeout, fmt::format("{}: still {} after {} ms", what,
                                              to_string(impl.state), ms(timeout).count()));
    }
  }
}

}  // namespace

Result<void> Master::await_running(std::chrono::nanoseconds timeout) {
  return wait_for_state(
      *impl_, timeout,
      [](MasterState s) {
        return s == MasterState::preop_ready || s == MasterState::deactivated ||
               s == MasterState::operational;
      },
      true, "await_running");
}

Result<void> Master::await_operational(std::chrono::nanoseconds timeout) {
  return wait_for_state(
      *impl_, timeout, [](MasterState s) { return s == MasterState::operational; }, false,
      "await_operational");
}

Result<void> Master::activate() {
  auto done = exec::run_blocking(
      impl_->loop,
      [](Impl& impl) -> exec::Task<Result<void>> {
        const auto now = impl.current();
        switch (now) {
          case MasterState::operational:
            co_return Error(Errc::wrong_state, "activate: already operational");
          case MasterState::activation_blocked:
            co_return Error(Errc::wrong_state, "activate: an activation is in progress (blocked)");
          case MasterState::recovering:
            co_return Error(Errc::wrong_state, "activate: recovery in progress");
          case MasterState::preop_ready:
          case MasterState::deactivated:
            break;
          default:
            co_return Error(Errc::wrong_state,
                            fmt::format("activate: not possible while {}", to_string(now)));
        }
        auto s = impl.session;
        // As the reference: the bus quiesces before activation; a bus that does not is an
        // activation error and the session stays where it is.
        if (auto quiet = co_await exec::quiesce(impl.loop, *s->bus, kQuietWindow); !quiet) {
          co_return quiet.error().context("activate: the bus is not ready");
        }
        {
          std::lock_guard lock(impl.mutex);
          impl.desired = TargetState::op;
        }
        co_await impl.run_activation(s);
        std::lock_guard lock(impl.mutex);
        if (impl.state == MasterState::activation_blocked && impl.activation_error) {
          co_return *impl.activation_error;
        }
        co_return ok();
      }(*impl_),
      60s);
  if (!done) return Error(Errc::timeout, "activate: no answer within 60 s");
  return std::move(*done);
}

Result<void> Master::deactivate(TargetState target) {
  auto done = exec::run_blocking(
      impl_->loop,
      [](Impl& impl, TargetState t) -> exec::Task<Result<void>> {
        if (t == TargetState::op) {
          co_return Error(Errc::invalid_argument, "deactivate: the target must be safeop or preop");
        }
        const auto now = impl.current();
        if (now == MasterState::idle || now == MasterState::discovering ||
            now == MasterState::awaiting_preop) {
          co_return Error(Errc::wrong_state,
                          fmt::format("deactivate: not possible while {}", to_string(now)));
        }
        if (now == MasterState::preop_ready && t == TargetState::safeop) {
          co_return Error(Errc::wrong_state,
                          "deactivate to safeop: the session is not operational");
        }
        auto s = impl.session;
        {
          std::lock_guard lock(impl.mutex);
          impl.desired = t;
          impl.runtime_faults.clear();
        }
        co_await impl.run_activation(s);
        std::lock_guard lock(impl.mutex);
        if (impl.state == MasterState::activation_blocked && impl.activation_error) {
          co_return *impl.activation_error;
        }
        co_return ok();
      }(*impl_, target),
      60s);
  if (!done) return Error(Errc::timeout, "deactivate: no answer within 60 s");
  return std::move(*done);
}

Result<void> Master::configure_slave(std::string_view name, SlaveConfig config) {
  const auto now = state();
  if (now != MasterState::preop_ready) {
    return Error(Errc::wrong_state,
                 fmt::format("configure_slave: only in preop_ready (now {})", to_string(now)));
  }
  auto slave = this->slave(name);
  if (!slave) return slave.error();
  if (config.name.empty()) config.name = std::string(name);
  return (*slave)->configure(std::move(config));
}

Result<void> Master::update_domain_cycle_time(std::string_view id,
                                              std::chrono::nanoseconds period) {
  auto d = domain(id);
  if (!d) return d.error();
  return (*d)->update_period(period);
}

bus::Bus* Master::bus() noexcept {
  std::lock_guard lock(impl_->mutex);
  auto s = impl_->session;
  return s ? s->bus.get() : nullptr;
}

Result<std::vector<WirePosition>> Master::scan_wire() {
  std::shared_ptr<Session> running;
  {
    std::lock_guard lock(impl_->mutex);
    running = impl_->session;
  }
  if (!running) return Error(Errc::not_ready, "scan_wire: no session runs");
  auto done = exec::run_blocking(
      impl_->loop,
      [](Impl& impl, std::shared_ptr<Session> s) -> exec::Task<Result<std::vector<WirePosition>>> {
        // A broadcast read of the ESC type register: every slave increments the working counter
        // (on a redundant ring, both sides' counts merged).
        bus::Transaction count;
        count.brd(wire::reg::kType, 1);
        auto counted = co_await exec::transact(impl.loop, *s->bus, std::move(count));
        if (!counted) co_return counted.error().context("scan_wire: counting the slaves");
        const std::size_t on_wire = counted->wkc(0);
        std::vector<WirePosition> out(on_wire);
        if (on_wire == 0) co_return out;
        // One register per position-addressed transaction (transact_by_position's rule).
        for (const std::uint16_t reg : {wire::reg::kStationAddress, wire::reg::kAlStatus}) {
          bus::Transaction tx;
          for (std::size_t pos = 0; pos < on_wire; ++pos)
            tx.aprd(static_cast<std::uint16_t>(pos), reg, 2);
          auto read = co_await transact_by_position(impl.loop, *s->bus, s->position_access,
                                                    std::move(tx), bus::TransactOptions{});
          if (!read) co_return read.error().context("scan_wire");
          for (std::size_t pos = 0; pos < on_wire; ++pos) {
            out[pos].position = static_cast<std::uint16_t>(pos);
            const auto& r = (*read)[pos];
            if (r.wkc != 1 || r.data.size() != 2) continue;
            const auto value = wire::load_le16(r.data.data());
            (reg == wire::reg::kStationAddress ? out[pos].station : out[pos].al_status) = value;
          }
        }
        co_return out;
      }(*impl_, std::move(running)),
      10s);
  if (!done) return Error(Errc::timeout, "scan_wire: no answer within 10 s");
  return std::move(*done);
}

std::vector<SlaveSummary> Master::slaves() const {
  // Slave::info() is thread-safe; the list only grows during startup, under this mutex.
  std::lock_guard lock(impl_->mutex);
  std::vector<SlaveSummary> out;
  if (!impl_->session) return out;
  for (const auto& slave : impl_->session->slaves) {
    auto info = slave->info();
    SlaveSummary summary;
    summary.name = info.name;
    summary.position = info.position;
    summary.station = info.station;
    summary.state = info.state;
    summary.target = info.target;
    if (info.configuration_error) summary.fault = *info.configuration_error;
    if (info.fault) summary.fault = *info.fault;
    summary.startup_error = info.startup_error;
    out.push_back(std::move(summary));
  }
  return out;
}

std::vector<DomainSummary> Master::domains() const {
  // Domain::info() is thread-safe; the list only grows during startup, under this mutex.
  std::lock_guard lock(impl_->mutex);
  std::vector<DomainSummary> out;
  if (!impl_->session) return out;
  for (const auto& d : impl_->session->domains) {
    auto info = d->info();
    DomainSummary summary;
    summary.id = info.id;
    summary.period = info.period;
    summary.state = std::string(to_string(info.state));
    summary.logical_base = info.logical_base;
    summary.image_size = info.image_size;
    summary.expected_wkc = static_cast<std::uint16_t>(info.expected_wkc);
    summary.cycles = info.stats.cycle_count;
    summary.total_misses = info.stats.total_miss_count;
    summary.healthy = info.stats.health.healthy;
    out.push_back(std::move(summary));
  }
  return out;
}

Result<DcStatus> Master::dc_status() const {
  std::lock_guard lock(impl_->mutex);
  const auto& s = impl_->session;
  if (!s) return Error(Errc::unsupported, "distributed clocks: no session (the master is idle)");
  if (!s->config.dc) {
    return Error(Errc::unsupported, "distributed clocks are disabled in the configuration");
  }
  if (s->dc) return s->dc->status();
  if (s->dc_error) {
    return s->dc_error->context(Errc::unsupported, "distributed clocks do not run");
  }
  if (!s->dc_init) return Error(Errc::not_ready, "distributed clocks are not initialised yet");
  return Error(Errc::not_ready,
               "distributed clocks are initialised; their runtime starts with the activation");
}

Result<ReferenceClock> Master::reference_clock() const {
  std::lock_guard lock(impl_->mutex);
  const auto& s = impl_->session;
  if (!s || !s->config.dc || !s->dc_init) {
    if (s && s->dc_error) {
      return s->dc_error->context(Errc::unsupported, "no reference clock");
    }
    return Error(Errc::not_ready, "no reference clock (distributed clocks not initialised)");
  }
  ReferenceClock out;
  out.station = s->dc_init->reference_station;
  out.position = static_cast<std::uint16_t>(s->dc_init->plan.reference_position);
  for (const auto& slave : s->slaves) {
    if (slave->station() == out.station) out.slave = slave->name();
  }
  return out;
}

Result<void> Master::await_dc_locked(std::chrono::nanoseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    // The lock flag is an atomic: polling it costs the cycle thread nothing; the full status
    // (copied under the maintainer's lock) is only taken to explain a refusal or a timeout.
    bool running = false;
    {
      std::lock_guard lock(impl_->mutex);
      const auto& s = impl_->session;
      running = s && s->dc;
      if (running && s->dc->locked()) return ok();
    }
    if (running && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
      continue;
    }
    auto status = dc_status();
    if (status && status->locked) return ok();
    if (!status && status.error().code() != Errc::not_ready) return status.error();
    if (std::chrono::steady_clock::now() >= deadline) {
      if (!status) return status.error().context(Errc::timeout, "waiting for the DC lock");
      return Error(Errc::timeout,
                   fmt::format("distributed clocks not locked within {} ms: max system-time "
                               "difference {} ns",
                               ms(timeout).count(), status->max_difference_ns));
    }
    std::this_thread::sleep_for(1ms);
  }
}

std::optional<Failure> Master::last_failure() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->last;
}

MasterStatus Master::status() const {
  MasterStatus out;
  {
    std::lock_guard lock(impl_->mutex);
    out.state = impl_->state;
    out.desired_target = impl_->desired;
    out.last_failure = impl_->last;
    out.illegal_transitions = impl_->refused_transitions;
    out.last_illegal_transition = impl_->last_refused_transition;
    if (impl_->session) {
      std::lock_guard report_lock(impl_->session->report_mutex);
      out.cycle_thread = impl_->session->cycle_thread_report;
    }
    for (const auto& [name, f] : impl_->activation_failures)
      out.activation_failures.push_back(f);
    for (const auto& [key, why] : impl_->runtime_faults)
      out.runtime_faults.push_back(why);
    if (impl_->session) {
      out.link = impl_->session->bus ? impl_->session->bus->link_name() : "";
      if (impl_->session->bus) out.redundancy = impl_->session->bus->info().redundancy;
      if (out.redundancy && out.redundancy->ring == link::RingState::broken)
        out.redundancy->break_location = impl_->ring_break;
      out.slave_count = impl_->session->slave_count;
      for (const auto& g : impl_->session->hot_connect) {
        HotConnectStatus h;
        h.group = g.name;
        h.state = g.state;
        h.position = g.position;
        for (const Slave* slave : g.slaves)
          h.slaves.push_back(slave->name());
        h.detail = g.detail;
        h.appearances = g.appearances;
        h.losses = g.losses;
        h.last_join = g.last_join;
        out.hot_connect.push_back(std::move(h));
      }
      out.hot_connect_refused = impl_->session->hot_connect_refused;
      for (const auto& slave : impl_->session->slaves)
        out.illegal_slave_transitions += SlaveAccess::refused_transitions(*slave);
      for (const auto& d : impl_->session->domains) {
        const auto stats = d->stats();
        out.illegal_domain_transitions += stats.refused_transitions;
        out.illegal_reservation_transitions += stats.refused_reservation_transitions;
      }
    }
  }
  out.slaves = slaves();
  out.domains = domains();
  return out;
}

std::optional<MailboxGatewayStatus> Master::mailbox_gateway() const {
  std::lock_guard lock(impl_->gateway_mutex);
  if (!impl_->gateway) return std::nullopt;
  return impl_->gateway->status();
}

Result<Slave*> Master::slave(std::string_view name) {
  std::lock_guard lock(impl_->mutex);
  auto s = impl_->session;
  if (!s) return Error(Errc::wrong_state, "the master is not started");
  if (impl_->state == MasterState::discovering) {
    return Error(Errc::not_ready,
                 fmt::format("slave {}: the ring is still being discovered", name));
  }
  if (auto* found = s->find_slave(name)) return found;
  return Error(Errc::not_found, fmt::format("no slave named \"{}\"", name));
}

Result<Domain*> Master::domain(std::string_view id) {
  std::lock_guard lock(impl_->mutex);
  auto s = impl_->session;
  if (!s) return Error(Errc::wrong_state, "the master is not started");
  if (auto* found = s->find_domain(id)) return found;
  return Error(Errc::not_found, fmt::format("no domain named \"{}\"", id));
}

EventSubscriptionId Master::subscribe_events(EventCallback callback) {
  return impl_->events.subscribe(std::move(callback));
}

bool Master::unsubscribe_events(EventSubscriptionId id) {
  return impl_->events.unsubscribe(id);
}

std::shared_ptr<EventQueue> Master::open_event_queue(std::size_t capacity) {
  return impl_->events.open_queue(capacity);
}

EventStats Master::event_stats() const noexcept {
  return impl_->events.stats();
}

bool Master::flush_events(std::chrono::nanoseconds timeout) {
  return impl_->events.flush(timeout);
}

MasterCounters Master::counters() const {
  const auto events = impl_->events.stats();  // before the lock, as the event hub has its own
  std::lock_guard lock(impl_->mutex);
  MasterCounters out;
  if (impl_->session) {
    out = Impl::collect_counters(*impl_->session);
  } else if (impl_->final_counters) {
    out = *impl_->final_counters;
  }
  out.events = events;
  return out;
}

void Master::on_state_change(std::function<void(MasterState, MasterState)> callback) {
  std::lock_guard lock(impl_->mutex);
  impl_->on_change = std::move(callback);
}

}  // namespace ecat::master
