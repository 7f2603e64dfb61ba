// The master's event stream: what happens to a session, as it happens, typed and serialisable.
//
// Every event has a stable name ("master.state", "slave.state", "domain.health", ...) and one JSON
// form (event_json), so the command line (`ecat run --events --json`), bindings and dashboards all
// read the same thing. Events are fixed-size values: producing one allocates nothing, which is
// what lets the cycle thread publish (domain health, DC lock) without ever waiting. They leave
// their producer through a bounded lock-free queue and reach subscribers on the master's own
// dispatcher thread; a subscriber that falls behind is told how many events it missed, and the
// producers never wait for it.
//
//   master.subscribe_events([](const ecat::master::Event& e, std::uint64_t missed) { ... });
//   auto queue = master.open_event_queue();      // pull style
//   while (auto next = queue->next(1s)) { ... next->missed_before ... }
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace ecat::master {

enum class EventKind : std::uint8_t {
  master_state,       // from/to: MasterState
  slave_state,        // subject: slave position, name; from/to: SlaveState
  domain_state,       // subject: domain index, name: its id; from/to: DomainState
  domain_health,      // to: 1 healthy, 0 invalid; value: InvalidReason when invalid; detail
  fault_raised,       // name: the slave (empty: the session); detail: the fault
  fault_cleared,      // name, detail: the fault that cleared
  recovery_step,      // name: the slave or domain acted on; detail: what was done
  activation_failed,  // name: the slave; value: AL status code (0: none); detail: the error
  dc_locked,          // value: max |difference| in ns at the change
  dc_lost,            // value: max |difference| in ns at the change
  link_down,          // detail: why (the link failed: it is reopened with a backoff)
  link_up,            // detail: the link
  sdo_failed,         // name: the slave; value: abort code (0: not an abort); detail
  mailbox_failed,     // name: the slave; detail
  frames_lost,        // value: total frames lost, at each threshold crossed (1, 10, 100, ...)
  timeouts,           // value: total transaction timeouts, at each threshold crossed
  link_reopened,      // the failed link is back; value: reopen attempts so far; detail: the link
  link_redundancy,  // a redundant link's topology or ring changed; detail: "redundant, ring broken"
  // Hot connect (MasterConfig::hot_connect); name: the group, subject: its ring position.
  hotconnect_appeared,  // the group was recognised in the ring; detail: how (alias / identity)
  hotconnect_ready,     // every slave of the group at its target; value: ns since it was noticed
  hotconnect_lost,      // the group left the ring; detail: how it was noticed
  hotconnect_refused,   // a device that is no group's, or a group that failed to come up; detail
};
inline constexpr std::size_t kEventKindCount = 22;

// "master.state", "slave.state", "domain.health", "dc.locked", ...: the event's stable name.
std::string_view to_string(EventKind kind) noexcept;
std::optional<EventKind> event_kind_from_string(std::string_view name) noexcept;

struct Event {
  static constexpr std::size_t kNameSize = 32;
  static constexpr std::size_t kDetailSize = 256;

  std::uint64_t sequence = 0;  // 1, 2, 3 ... per master, in the order events were dispatched
  std::int64_t time_ns = 0;    // steady clock, when the event was raised
  EventKind kind = EventKind::master_state;
  std::uint8_t from = 0;      // the enum value of the state left (state kinds)
  std::uint8_t to = 0;        // the enum value of the state entered (state kinds; health: 1/0)
  std::int32_t subject = -1;  // slave position or domain index; -1 when none
  std::uint64_t value = 0;    // kind-specific number (see EventKind)
  std::array<char, kNameSize> name_buffer{};
  std::array<char, kDetailSize> detail_buffer{};

  // The slave or domain this event is about ("" when none); text is NUL-terminated, cut to fit.
  std::string_view name() const noexcept;
  std::string_view detail() const noexcept;
  void set_name(std::string_view text) noexcept;
  void set_detail(std::string_view text) noexcept;

  // For the state kinds: the names of `from` and `to` ("operational", "op", "cycling").
  std::string_view from_name() const noexcept;
  std::string_view to_name() const noexcept;
};

// One line of text: "master.state awaiting_preop -> operational", "slave.state drive: safeop ->
// op", "domain.health main: invalid (timeout) ...".
std::string describe(const Event& event);
// The event as one JSON object: {"seq":..,"time_ns":..,"event":"slave.state","slave":"drive",
// "from":"safeop","to":"op",...}. Keys depend on the kind; "event", "seq" and "time_ns" always.
std::string event_json(const Event& event);

// A pull-style subscription: events queue here (up to its capacity) until taken. When it is full,
// newer events are dropped and counted; the next event taken says how many were missed.
class EventQueue {
 public:
  struct Item {
    Event event;
    std::uint64_t missed_before = 0;  // events this queue lost just before this one
  };
  virtual ~EventQueue() = default;
  // The next event, waiting up to `timeout`; nullopt when none came (or the queue was closed).
  virtual std::optional<Item> next(std::chrono::nanoseconds timeout) = 0;
  // Events lost so far because the queue was full (or the master's own queue overflowed).
  virtual std::uint64_t missed() const noexcept = 0;
  // Stops delivery; a waiting next() returns.
  virtual void close() = 0;
};

// A callback subscription runs on the dispatcher thread. `missed` is the number of events this
// subscriber lost just before this one (the master's queue overflowed): 0 normally. A callback
// that takes long delays the other subscribers, never the session.
using EventCallback = std::function<void(const Event& event, std::uint64_t missed)>;
using EventSubscriptionId = std::uint64_t;

// Counts of the stream itself.
struct EventStats {
  std::uint64_t published = 0;  // accepted by the queue
  std::uint64_t dropped = 0;    // refused because the queue was full (producers never wait)
  std::uint64_t delivered = 0;  // dispatched to subscribers (each event once)
};

}  // namespace ecat::master
