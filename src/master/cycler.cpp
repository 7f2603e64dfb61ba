// The schedule the bus thread runs is immutable: every change builds a new one on the calling
// thread and hands it to Bus::set_cycle, which returns only once the old one no longer runs. So the
// bus thread never takes a lock of ours, and the control side frees what it replaced without any
// reclamation scheme. Per-participant timing (next due time) lives in Entry, which survives
// schedule changes and is touched by the bus thread only (the hand-over through set_cycle orders
// the control side's initialisation before it).

#include <algorithm>
#include <numeric>

#include <fmt/format.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/cycler.hpp>

namespace ecat::master {

using std::chrono::nanoseconds;

namespace {

std::int64_t to_ns(bus::Clock::time_point t) {
  return std::chrono::duration_cast<nanoseconds>(t.time_since_epoch()).count();
}

// The first multiple of `period` at or after `t` (both in ns since the steady clock's epoch).
std::int64_t align_up(std::int64_t t, std::int64_t period) {
  const std::int64_t q = t / period;
  return q * period >= t ? q * period : (q + 1) * period;
}

void store_max(std::atomic<std::int64_t>& target, std::int64_t value) {
  std::int64_t current = target.load(std::memory_order_relaxed);
  while (value > current &&
         !target.compare_exchange_weak(current, value, std::memory_order_relaxed)) {
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// CyclicParticipant

CyclicParticipant::~CyclicParticipant() {
  detach_from_cycler();
}

Result<void> CyclicParticipant::notify_period_changed() {
  Cycler* c = cycler();
  if (c == nullptr) return ok();
  return c->refresh();
}

void CyclicParticipant::detach_from_cycler() noexcept {
  Cycler* c = cycler();
  if (c != nullptr) (void)c->remove(*this);
}

// ---------------------------------------------------------------------------------------------
// Cycler

struct Cycler::Entry {
  CyclicParticipant* participant = nullptr;
  int priority = 0;
  std::uint64_t sequence = 0;  // registration order
  // Bus thread only.
  std::int64_t next_due_ns = 0;
  std::int64_t scheduled_period_ns = 0;  // 0: not aligned yet
};

struct Cycler::Schedule {
  struct Slot {
    Entry* entry = nullptr;
    std::int64_t period_ns = 0;
  };
  std::vector<Slot> slots;  // run order
  std::int64_t base_ns = 0;
  std::int64_t fastest_ns = 0;  // the shortest participant period (the link's frame budget)
};

Cycler::Cycler(bus::Bus& bus) : bus_(bus) {}

Cycler::~Cycler() {
  (void)stop();
  std::lock_guard lock(mutex_);
  for (auto& e : entries_)
    e->participant->cycler_.store(nullptr, std::memory_order_release);
  entries_.clear();
  schedule_.reset();
}

Result<std::unique_ptr<Cycler::Schedule>> Cycler::build_locked(nanoseconds* base) const {
  auto schedule = std::make_unique<Schedule>();
  std::int64_t gcd = 0;
  for (const auto& e : entries_) {
    const auto period = e->participant->cycle_period().count();
    if (period <= 0) {
      return Error(Errc::invalid_argument,
                   fmt::format("cycler: a participant has a non-positive period ({} ns)", period));
    }
    gcd = std::gcd(gcd, period);
    schedule->fastest_ns =
        schedule->fastest_ns == 0 ? period : std::min(schedule->fastest_ns, period);
    schedule->slots.push_back({e.get(), period});
  }
  if (!entries_.empty() && gcd < kMinBasePeriod.count()) {
    std::string periods;
    for (const auto& s : schedule->slots) {
      periods += fmt::format("{}{} ns", periods.empty() ? "" : ", ", s.period_ns);
    }
    return Error(Errc::out_of_range,
                 fmt::format("cycler: the periods {} have a common base tick of {} ns, below the "
                             "{} ns minimum; choose periods that are multiples of a common tick",
                             periods, gcd, kMinBasePeriod.count()));
  }
  std::stable_sort(schedule->slots.begin(), schedule->slots.end(),
                   [](const Schedule::Slot& a, const Schedule::Slot& b) {
                     if (a.entry->priority != b.entry->priority) {
                       return a.entry->priority > b.entry->priority;
                     }
                     return a.entry->sequence < b.entry->sequence;
                   });
  schedule->base_ns = gcd;
  *base = nanoseconds(gcd);
  return schedule;
}

Result<void> Cycler::install_locked(std::unique_ptr<Schedule> next) {
  if (running_.load(std::memory_order_relaxed)) {
    if (next->slots.empty()) {
      bus_.clear_cycle();
    } else {
      Schedule* raw = next.get();
      // The link's frame budget follows the fastest participant, not the base tick
      // (Bus::set_fastest_work_period); told first, so set_cycle's budget is already right.
      if (auto r = bus_.set_fastest_work_period(nanoseconds(raw->fastest_ns)); !r) {
        return std::move(r).error().context("cycler: telling the bus the fastest period");
      }
      // The lambda holds two pointers: small enough for std::function's inline storage.
      if (auto r = bus_.set_cycle(nanoseconds(raw->base_ns),
                                  [this, raw](const bus::CycleTick& tick) { run(*raw, tick); });
          !r) {
        return std::move(r).error().context("cycler: installing the cycle function");
      }
    }
  }
  // set_cycle/clear_cycle returned: the previous schedule no longer runs.
  base_period_ns_.store(next->base_ns, std::memory_order_release);
  participant_count_.store(next->slots.size(), std::memory_order_relaxed);
  schedule_ = std::move(next);
  return ok();
}

Result<void> Cycler::add(CyclicParticipant& participant, int priority) {
  if (bus_.on_bus_thread()) {
    return Error(Errc::wrong_state, "cycler: add() called on the bus thread");
  }
  std::lock_guard lock(mutex_);
  if (participant.cycler() != nullptr) {
    return Error(Errc::invalid_argument, participant.cycler() == this
                                             ? "cycler: participant already added"
                                             : "cycler: participant belongs to another cycler");
  }
  auto entry = std::make_unique<Entry>();
  entry->participant = &participant;
  entry->priority = priority;
  entry->sequence = next_sequence_++;
  entries_.push_back(std::move(entry));
  nanoseconds base{};
  auto schedule = build_locked(&base);
  if (!schedule) {
    entries_.pop_back();
    return std::move(schedule).error();
  }
  if (auto r = install_locked(std::move(*schedule)); !r) {
    entries_.pop_back();
    return r;
  }
  participant.cycler_.store(this, std::memory_order_release);
  return ok();
}

Result<void> Cycler::remove(CyclicParticipant& participant) {
  if (bus_.on_bus_thread()) {
    return Error(Errc::wrong_state, "cycler: remove() called on the bus thread");
  }
  std::lock_guard lock(mutex_);
  auto it = std::find_if(entries_.begin(), entries_.end(),
                         [&](const auto& e) { return e->participant == &participant; });
  if (it == entries_.end()) return Error(Errc::not_found, "cycler: participant not found");
  // Build without it first; the entry must outlive the schedule that still points at it.
  std::unique_ptr<Entry> removed = std::move(*it);
  entries_.erase(it);
  nanoseconds base{};
  auto schedule = build_locked(&base);
  if (!schedule) {
    // Removing cannot make the base smaller; only a participant's own bad period gets here.
    entries_.push_back(std::move(removed));
    return std::move(schedule).error();
  }
  if (auto r = install_locked(std::move(*schedule)); !r) {
    entries_.push_back(std::move(removed));
    return r;
  }
  participant.cycler_.store(nullptr, std::memory_order_release);
  return ok();
}

Result<void> Cycler::refresh() {
  if (bus_.on_bus_thread()) {
    return Error(Errc::wrong_state, "cycler: refresh() called on the bus thread");
  }
  std::lock_guard lock(mutex_);
  nanoseconds base{};
  auto schedule = build_locked(&base);
  if (!schedule) return std::move(schedule).error();
  return install_locked(std::move(*schedule));
}

Result<void> Cycler::start() {
  if (bus_.on_bus_thread()) {
    return Error(Errc::wrong_state, "cycler: start() called on the bus thread");
  }
  std::lock_guard lock(mutex_);
  if (running_.load(std::memory_order_relaxed)) return ok();
  running_.store(true, std::memory_order_release);
  nanoseconds base{};
  auto schedule = build_locked(&base);
  if (!schedule) {
    running_.store(false, std::memory_order_release);
    return std::move(schedule).error();
  }
  if (auto r = install_locked(std::move(*schedule)); !r) {
    running_.store(false, std::memory_order_release);
    return r;
  }
  return ok();
}

Result<void> Cycler::stop() {
  // The control side holds mutex_ while set_cycle() waits for the bus thread's current tick: the
  // bus thread must never wait for mutex_.
  if (bus_.on_bus_thread()) {
    return Error(Errc::wrong_state, "cycler: stop() called on the bus thread");
  }
  std::lock_guard lock(mutex_);
  if (!running_.load(std::memory_order_relaxed)) return ok();
  bus_.clear_cycle();
  running_.store(false, std::memory_order_release);
  // A later start() realigns every participant to the then current time.
  for (auto& e : entries_)
    e->scheduled_period_ns = 0;
  return ok();
}

void Cycler::run(Schedule& schedule, const bus::CycleTick& tick) noexcept {
  const auto started = bus::Clock::now();
  // The nominal grid point: a steered cycle (distributed clocks) moves the deadlines, not the
  // participants' schedule.
  const std::int64_t deadline = to_ns(tick.nominal);
  std::uint64_t ran = 0;
  for (const auto& slot : schedule.slots) {
    Entry& e = *slot.entry;
    if (e.scheduled_period_ns != slot.period_ns) {
      // New participant or new period: due from the first multiple of its period on.
      e.scheduled_period_ns = slot.period_ns;
      e.next_due_ns = align_up(deadline, slot.period_ns);
    }
    if (e.next_due_ns > deadline) continue;
    e.participant->on_tick(tick);
    ++ran;
    // Skip every deadline already behind us: one run per tick, whatever was missed.
    e.next_due_ns += slot.period_ns * ((deadline - e.next_due_ns) / slot.period_ns + 1);
  }
  const std::int64_t took = (bus::Clock::now() - started).count();
  ticks_.fetch_add(1, std::memory_order_relaxed);
  runs_.fetch_add(ran, std::memory_order_relaxed);
  skipped_.fetch_add(tick.missed, std::memory_order_relaxed);
  if (took > schedule.base_ns) overlong_.fetch_add(1, std::memory_order_relaxed);
  last_tick_ns_.store(took, std::memory_order_relaxed);
  total_tick_ns_.fetch_add(took, std::memory_order_relaxed);
  store_max(max_tick_ns_, took);
}

CyclerStats Cycler::stats() const noexcept {
  CyclerStats s;
  s.ticks = ticks_.load(std::memory_order_relaxed);
  s.participant_runs = runs_.load(std::memory_order_relaxed);
  s.deadlines_skipped = skipped_.load(std::memory_order_relaxed);
  s.overlong_ticks = overlong_.load(std::memory_order_relaxed);
  s.last_tick_duration = nanoseconds(last_tick_ns_.load(std::memory_order_relaxed));
  s.max_tick_duration = nanoseconds(max_tick_ns_.load(std::memory_order_relaxed));
  s.total_tick_duration = nanoseconds(total_tick_ns_.load(std::memory_order_relaxed));
  s.base_period = base_period();
  s.running = running();
  s.participants = participant_count_.load(std::memory_order_relaxed);
  return s;
}

}  // namespace ecat::master
