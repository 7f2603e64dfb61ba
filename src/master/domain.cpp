// Domain: registrations and planning on the control side, staging and the seqlocked input image
// for the hot path, the cycle and its classification on the bus thread. See domain.hpp for the
// model; the comments here say why the mechanics are as they are.

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <limits>
#include <thread>
#include <type_traits>

#include <fmt/format.h>
#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <ecat/bus/bus.hpp>
#include <ecat/bus/realtime.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/wire/frame.hpp>

#include "tsc_clock.hpp"

namespace ecat::master {

static_assert(std::is_same_v<Clock, bus::Clock>, "domain times are the bus's clock");

using std::chrono::nanoseconds;
using namespace std::chrono_literals;

namespace {

std::int64_t to_ns(Clock::time_point t) {
  return std::chrono::duration_cast<nanoseconds>(t.time_since_epoch()).count();
}

// 0 is "never": the steady clock starts at boot, so a real time stamp is never 0.
std::optional<Clock::time_point> from_ns(std::int64_t ns) {
  if (ns == 0) return std::nullopt;
  return Clock::time_point(nanoseconds(ns));
}

void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

std::string format_duration(nanoseconds d) {
  const auto ns = d.count();
  if (ns % 1'000'000 == 0) return fmt::format("{} ms", ns / 1'000'000);
  if (ns % 1'000 == 0) return fmt::format("{} us", ns / 1'000);
  return fmt::format("{} ns", ns);
}

// The input image is an array of 64-bit atomics so that the seqlock's racing reads are
// well-defined; bytes are packed into words in host order (only this file ever sees the words).
void store_bytes(std::atomic<std::uint64_t>* words, std::size_t offset, const std::uint8_t* src,
                 std::size_t n) noexcept {
  while (n > 0) {
    const std::size_t w = offset / 8;
    const std::size_t in_word = offset % 8;
    const std::size_t take = std::min<std::size_t>(8 - in_word, n);
    std::uint64_t value = words[w].load(std::memory_order_relaxed);  // single writer
    std::memcpy(reinterpret_cast<std::uint8_t*>(&value) + in_word, src, take);
    words[w].store(value, std::memory_order_relaxed);
    offset += take;
    src += take;
    n -= take;
  }
}

void load_bytes(const std::atomic<std::uint64_t>* words, std::size_t offset, std::uint8_t* dst,
                std::size_t n) noexcept {
  while (n > 0) {
    const std::size_t w = offset / 8;
    const std::size_t in_word = offset % 8;
    const std::size_t take = std::min<std::size_t>(8 - in_word, n);
    const std::uint64_t value = words[w].load(std::memory_order_relaxed);
    std::memcpy(dst, reinterpret_cast<const std::uint8_t*>(&value) + in_word, take);
    offset += take;
    dst += take;
    n -= take;
  }
}

// The seqlocked copy of `n` published input bytes at `offset` (retried while the bus thread
// publishes); returns the last valid cycle's time (0: none yet) and, when asked, `changed_src`
// and `until_src` (the publish's TSC freshness stamp) read in the same section.
std::int64_t copy_published(const std::atomic<std::uint64_t>& seq,
                            const std::atomic<std::int64_t>& refreshed_ns,
                            const std::atomic<std::atomic<std::uint64_t>*>& words,
                            std::size_t offset, std::uint8_t* out, std::size_t n,
                            const std::atomic<std::int64_t>* changed_src = nullptr,
                            std::int64_t* changed = nullptr,
                            const std::atomic<std::uint64_t>* until_src = nullptr,
                            std::uint64_t* until = nullptr) noexcept {
  for (int spins = 0;; ++spins) {
    const std::uint64_t s1 = seq.load(std::memory_order_acquire);
    if ((s1 & 1u) == 0) {
      const std::int64_t refreshed = refreshed_ns.load(std::memory_order_relaxed);
      if (changed != nullptr) *changed = changed_src->load(std::memory_order_relaxed);
      if (until != nullptr) *until = until_src->load(std::memory_order_relaxed);
      load_bytes(words.load(std::memory_order_acquire), offset, out, n);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (seq.load(std::memory_order_relaxed) == s1) return refreshed;
    }
    if (spins < 64) {
      cpu_relax();
    } else {
      std::this_thread::yield();
    }
  }
}

// The last invalid cycle and the health fit one atomic word each, so a reader never sees the
// reason of one cycle with the counters of another.
constexpr std::uint64_t kPresentBit = std::uint64_t{1} << 63;
constexpr std::uint32_t kWkcFieldMax = (1u << 20) - 1;

std::uint64_t pack(const CycleInvalid& c) noexcept {
  const std::uint64_t expected = std::min(c.expected_wkc, kWkcFieldMax);
  const std::uint64_t actual = std::min(c.actual_wkc, kWkcFieldMax);
  return kPresentBit | (static_cast<std::uint64_t>(c.reason) << 56) |
         (static_cast<std::uint64_t>(c.datagram) << 40) | (actual << 20) | expected;
}

std::optional<CycleInvalid> unpack(std::uint64_t v) noexcept {
  if ((v & kPresentBit) == 0) return std::nullopt;
  CycleInvalid c;
  c.reason = static_cast<InvalidReason>((v >> 56) & 0x7F);
  c.datagram = static_cast<std::uint16_t>(v >> 40);
  c.actual_wkc = static_cast<std::uint32_t>((v >> 20) & kWkcFieldMax);
  c.expected_wkc = static_cast<std::uint32_t>(v & kWkcFieldMax);
  return c;
}

using DomainEvent = DomainTrigger;

// The state diagram of the seed (domain.hpp), and nothing else.
constexpr std::array kDomainTransitions{
    DomainTransition{DomainState::open, DomainState::cycling, DomainTrigger::start_cycling,
                     "start_cycling and layout preparation succeed"},
    DomainTransition{DomainState::cycling, DomainState::stopped, DomainTrigger::stop_cycling,
                     "stop_cycling"},
    DomainTransition{DomainState::cycling, DomainState::stopped, DomainTrigger::miss_threshold,
                     "miss threshold is reached"},
    DomainTransition{DomainState::stopped, DomainState::cycling, DomainTrigger::start_cycling,
                     "start_cycling"},
};

constexpr std::optional<DomainState> transition(DomainState from, DomainEvent event) noexcept {
  for (const auto& t : kDomainTransitions) {
    if (t.from == from && t.trigger == event) return t.to;
  }
  return std::nullopt;
}

using RS = Domain::ReservationState;

// The hot-connect reservation's diagram (domain.hpp), and nothing else.
constexpr std::array kReservationTransitions{
    Domain::ReservationTransition{RS::absent, RS::joining,
                                  "the group's stations are assigned: its FMMUs may answer"},
    Domain::ReservationTransition{RS::joining, RS::present, "the group reached its target"},
    Domain::ReservationTransition{RS::joining, RS::absent,
                                  "the group failed to come up or left while joining"},
    Domain::ReservationTransition{
        RS::present, RS::absent,
        "the group left: a cycle came back short exactly its share (bus thread), the slave "
        "count no longer reaches it, or a slave of it stopped answering"},
    Domain::ReservationTransition{
        RS::absent, RS::absent,
        "the master confirms a loss that a cycle (bus thread) already recorded"},
};

constexpr bool reservation_allowed(RS from, RS to) noexcept {
  for (const auto& t : kReservationTransitions) {
    if (t.from == from && t.to == to) return true;
  }
  return false;
}

}  // namespace

std::span<const Domain::ReservationTransition> Domain::reservation_transitions() noexcept {
  return kReservationTransitions;
}

bool Domain::reservation_transition_allowed(ReservationState from, ReservationState to) noexcept {
  return reservation_allowed(from, to);
}

std::string_view to_string(Domain::ReservationState state) noexcept {
  switch (state) {
    case RS::absent:
      return "absent";
    case RS::joining:
      return "joining";
    case RS::present:
      return "present";
  }
  return "unknown";
}

std::string_view to_string(DomainTrigger trigger) noexcept {
  switch (trigger) {
    case DomainTrigger::start_cycling:
      return "start_cycling";
    case DomainTrigger::stop_cycling:
      return "stop_cycling";
    case DomainTrigger::miss_threshold:
      return "miss_threshold";
  }
  return "unknown";
}

std::span<const DomainTransition> domain_transitions() noexcept {
  return kDomainTransitions;
}

std::string_view to_string(DomainState state) noexcept {
  switch (state) {
    case DomainState::open:
      return "open";
    case DomainState::cycling:
      return "cycling";
    case DomainState::stopped:
      return "stopped";
  }
  return "unknown";
}

std::string to_string(const PdoKey& key) {
  return fmt::format("station 0x{:04x} SM{}{}", key.slave, key.sync_manager,
                     key.kind == RegistrationKind::sm_status ? " status" : "");
}

std::string_view to_string(RegistrationKind kind) noexcept {
  switch (kind) {
    case RegistrationKind::process_data:
      return "process_data";
    case RegistrationKind::reserved:
      return "reserved";
    case RegistrationKind::sm_status:
      return "sm_status";
  }
  return "unknown";
}

std::string_view to_string(InvalidReason reason) noexcept {
  switch (reason) {
    case InvalidReason::wkc_mismatch:
      return "wkc_mismatch";
    case InvalidReason::timeout:
      return "timeout";
    case InvalidReason::link_error:
      return "link_error";
    case InvalidReason::closed:
      return "closed";
  }
  return "unknown";
}

std::string_view to_string(Freshness freshness) noexcept {
  switch (freshness) {
    case Freshness::not_ready:
      return "not_ready";
    case Freshness::fresh:
      return "fresh";
    case Freshness::stale:
      return "stale";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// Internal types

constexpr std::uint8_t kNoReservation = 0xFF;

struct Domain::Entry {
  PdoKey key;
  std::uint32_t index = 0;
  std::uint32_t offset = 0;
  std::uint16_t size = 0;
  PdoDirection direction = PdoDirection::input;
  bool contributes_wkc = true;
  std::uint8_t reservation = kNoReservation;  // the hot-connect reservation it lies in
  // Outputs: written under the staging lock; atomics so stats-like readers need no lock.
  mutable std::atomic<std::int64_t> output_written_ns{0};
  mutable std::atomic<std::int64_t> output_changed_ns{0};
  // Inputs: written by the bus thread inside the seqlock's write section.
  mutable std::atomic<std::int64_t> input_changed_ns{0};
};

struct Domain::Reservation {
  std::string name;
  std::vector<std::uint16_t> stations;
  std::uint32_t index = 0;
  std::uint32_t offset = 0;  // in the image
  std::uint32_t size = 0;
  std::uint32_t used = 0;  // control thread
  std::atomic<ReservationState> state{ReservationState::absent};
  // Per datagram of the plan: the reservation's registrations' share of the working counter.
  std::unique_ptr<std::atomic<std::uint16_t>[]> shares;
  std::size_t datagrams = 0;
  // Its input registrations (process data, SyncManager status), published by count: at most one
  // per byte reserved.
  std::unique_ptr<std::atomic<std::uint32_t>[]> inputs;
  std::atomic<std::uint32_t> input_count{0};
  std::unique_ptr<std::atomic<std::uint32_t>[]> statuses;
  std::atomic<std::uint32_t> status_count{0};
};

struct Domain::Exchange {
  Domain* domain = nullptr;
  std::unique_ptr<bus::RealtimeTransaction> rt;
  std::uint64_t cycle = 0;
  Clock::time_point submitted_at{};
};

struct Domain::Plan {
  std::vector<DomainDatagram> datagrams;
  std::uint32_t image_size = 0;
  std::uint32_t expected_total = 0;
  std::uint32_t entry_count = 0;
  std::vector<std::uint32_t> input_entries;   // process data: change records
  std::vector<std::uint32_t> status_entries;  // SyncManager status bytes: published, no records
  std::vector<std::unique_ptr<Exchange>> exchanges;

  // Bus thread only from here on.
  std::vector<std::uint8_t> tx_image;     // outputs of the next exchange
  std::vector<std::uint8_t> rx_image;     // the reply being classified
  std::vector<std::uint8_t> last_inputs;  // as last published (change detection)
  struct Changed {
    std::uint32_t entry = 0;
    std::uint16_t first = 0;
    std::uint16_t last = 0;
  };
  std::vector<Changed> changed;  // capacity: one per input registration
  std::size_t next_exchange = 0;
  std::uint64_t next_cycle = 0;
  std::uint64_t last_classified = 0;  // newest cycle whose result counted for health
  std::uint64_t seen_staging_version = std::numeric_limits<std::uint64_t>::max();
  std::uint32_t seen_generation = 0;
  bool published = false;
  bool degraded = false;
  std::uint64_t miss_streak = 0;
  std::uint64_t invalid_streak = 0;
  // The TSC's rate against the clock (tsc_clock.hpp) and the TSC read just before the clock read
  // of the reply being classified: what publish_inputs stamps the inputs' freshness with.
  detail::TscCalibration tsc;
  std::uint64_t reply_tsc = 0;
};

struct Domain::Counters {
  std::atomic<std::uint64_t> cycles{0}, valid{0}, miss_streak{0}, total_miss{0}, invalid_streak{0},
      wkc_mismatch{0}, timeout{0}, expired{0}, overrun{0}, link_error{0}, late{0}, stage_skips{0};
  std::atomic<std::uint32_t> last_wkc{0};
  std::atomic<std::int64_t> last_valid_ns{0}, last_invalid_ns{0};
  std::atomic<std::uint64_t> last_invalid{0};  // packed CycleInvalid, 0: none
  std::atomic<std::uint64_t> health{0};        // packed CycleInvalid of the latest cycle, 0: ok
  std::atomic<std::int64_t> last_latency{0}, min_latency{std::numeric_limits<std::int64_t>::max()},
      max_latency{0}, latency_sum{0};
  std::atomic<std::uint64_t> latency_count{0};
  // When the tick in progress started (bus thread), 0 before the first: what an output write
  // stamps while the domain cycles, instead of reading the clock on the application's hot path.
  std::atomic<std::int64_t> tick_ns{0};
};

// ---------------------------------------------------------------------------------------------
// Creation

Result<std::unique_ptr<Domain>> Domain::create(bus::Bus& bus, DomainConfig config,
                                               DomainObserver* observer) {
  const auto fail = [&](std::string what) {
    return Error(Errc::invalid_argument,
                 fmt::format("domain \"{}\": {}", config.id, std::move(what)));
  };
  if (config.id.empty()) return Error(Errc::invalid_argument, "domain: id must not be empty");
  if (config.period < kMinPeriod) {
    return fail(fmt::format("period {} is below the {} minimum", format_duration(config.period),
                            format_duration(kMinPeriod)));
  }
  if (config.miss_threshold == 0) return fail("miss_threshold must be at least 1");
  if (config.recovery_threshold == 0) return fail("recovery_threshold must be at least 1");
  if (config.stale_after < 0ns) return fail("stale_after must not be negative");
  if (config.realtime_budget < 0ns) return fail("realtime_budget must not be negative");
  const std::size_t image_limit =
      config.max_image_size != 0 ? config.max_image_size : kAutoImageLimit;
  if (static_cast<std::uint64_t>(config.logical_base) + image_limit > (std::uint64_t{1} << 32)) {
    return fail(
        fmt::format("logical window 0x{:08x} + {} bytes ({}) passes the end of the 4 GiB "
                    "logical address space",
                    config.logical_base, image_limit,
                    config.max_image_size != 0 ? "max_image_size"
                                               : "the largest image a domain sizes itself to"));
  }
  const std::size_t frame_room =
      bus.max_frame_size() > wire::kFrameHeaderSize + wire::kDatagramOverhead
          ? std::min<std::size_t>(
                bus.max_frame_size() - wire::kFrameHeaderSize - wire::kDatagramOverhead,
                wire::kMaxDatagramLength)
          : 0;
  if (frame_room == 0) return fail("the bus's frames have no room for a datagram");
  if (config.max_datagram_size > frame_room) {
    return fail(
        fmt::format("max_datagram_size {} exceeds the {} data bytes one frame of bus {} "
                    "carries",
                    config.max_datagram_size, frame_room, bus.link_name()));
  }
  if (config.max_datagram_size == 0) config.max_datagram_size = frame_room;
  if (config.max_registrations > kMaxRegistrations) {
    return fail(fmt::format("max_registrations must be 0 (as many as registered) or 1..{}, got {}",
                            kMaxRegistrations, config.max_registrations));
  }
  if (config.exchanges_in_flight == 0 || config.exchanges_in_flight > 64) {
    return fail(
        fmt::format("exchanges_in_flight must be 1..64, got {}", config.exchanges_in_flight));
  }
  if (config.change_queue_capacity == 0 || config.change_queue_capacity > (1u << 24)) {
    return fail(fmt::format("change_queue_capacity must be 1..16777216, got {}",
                            config.change_queue_capacity));
  }
  return std::unique_ptr<Domain>(new Domain(bus, std::move(config), observer));
}

Domain::Domain(bus::Bus& bus, DomainConfig config, DomainObserver* observer)
    : bus_(bus),
      config_(std::move(config)),
      observer_(observer),
      period_ns_(config_.period.count()),
      registration_limit_(config_.max_registrations != 0 ? config_.max_registrations
                                                         : kMaxRegistrations),
      image_limit_(config_.max_image_size != 0 ? config_.max_image_size : kAutoImageLimit),
      entry_blocks_(std::make_unique<std::atomic<Entry*>[]>(
          (registration_limit_ + kEntryBlock - 1) / kEntryBlock)),
      counters_(std::make_unique<Counters>()) {
  for (std::size_t i = 0; i < (registration_limit_ + kEntryBlock - 1) / kEntryBlock; ++i)
    entry_blocks_[i].store(nullptr, std::memory_order_relaxed);
  // A configured image size is reserved at once (as before); an automatic one starts small.
  reserve_image_locked(config_.max_image_size != 0 ? config_.max_image_size : 64);
  std::size_t capacity = 1;
  while (capacity < config_.change_queue_capacity)
    capacity <<= 1;
  changes_ = std::make_unique<InputChange[]>(capacity);
  change_mask_ = capacity - 1;
}

Domain::Entry& Domain::entry(std::uint32_t i) const noexcept {
  return entry_blocks_[i / kEntryBlock].load(std::memory_order_relaxed)[i % kEntryBlock];
}

std::string_view Domain::registration_limit_name() const noexcept {
  return config_.max_registrations != 0 ? "max_registrations" : "the most a domain holds";
}

std::string_view Domain::image_limit_name() const noexcept {
  return config_.max_image_size != 0 ? "max_image_size"
                                     : "the largest image a domain sizes itself to";
}

void Domain::reserve_entry_locked(std::uint32_t count) {
  const std::uint32_t block = count / kEntryBlock;
  if (entry_blocks_[block].load(std::memory_order_relaxed) != nullptr) return;
  entry_storage_.push_back(std::make_unique<Entry[]>(kEntryBlock));
  // Relaxed: the count published after the entry is written (release) carries it to readers.
  entry_blocks_[block].store(entry_storage_.back().get(), std::memory_order_relaxed);
}

void Domain::reserve_image_locked(std::size_t bytes) {
  if (bytes <= image_capacity_) return;
  std::size_t capacity = std::max<std::size_t>(image_capacity_ * 2, bytes);
  capacity = std::min(capacity, image_limit_);
  const std::size_t words = (capacity + 7) / 8;
  auto inputs = std::make_unique<std::atomic<std::uint64_t>[]>(words);
  for (std::size_t i = 0; i < words; ++i)
    inputs[i].store(0, std::memory_order_relaxed);
  // Nothing was published into the inputs yet (the domain is open): the new words are all zero.
  input_words_.store(inputs.get(), std::memory_order_release);
  input_storage_.push_back(std::move(inputs));
  // Staged outputs move along, under the staging lock every writer and reader of it takes.
  auto staging = std::make_unique<std::uint8_t[]>(capacity);
  lock_staging();
  if (staging_) std::memcpy(staging.get(), staging_.get(), image_capacity_);
  staging_ = std::move(staging);
  unlock_staging();
  image_capacity_ = capacity;
}

Domain::~Domain() {
  // First make sure the bus thread no longer calls on_tick, then wait for the exchanges it still
  // has: their completions call into this object.
  detach_from_cycler();
  state_.store(DomainState::stopped, std::memory_order_release);
  if (plan_) {
    for (auto& x : plan_->exchanges)
      x->rt->wait();
  }
}

Error Domain::error(Errc code, std::string_view what) const {
  return Error(code, fmt::format("domain \"{}\": {}", config_.id, what));
}

// The control side may hold control_mutex_ while the Cycler waits for the bus thread's tick; a
// bus-thread caller waiting for control_mutex_ would close the circle.
Error Domain::refuse_on_bus_thread(std::string_view call) const {
  return error(Errc::wrong_state,
               fmt::format("{}() called on the bus thread (from an observer or a completion); "
                           "post it to the control thread",
                           call));
}

nanoseconds Domain::stale_after() const noexcept {
  if (config_.stale_after > 0ns) return config_.stale_after;
  return 3 * cycle_period();
}

nanoseconds Domain::realtime_budget() const noexcept {
  if (config_.realtime_budget > 0ns) return config_.realtime_budget;
  return std::max<nanoseconds>(cycle_period() * 9 / 10, 200us);
}

// ---------------------------------------------------------------------------------------------
// Control plane

Result<void> Domain::check_room(std::size_t count, std::size_t bytes) const {
  std::lock_guard lock(control_mutex_);
  const std::size_t used = entry_count_.load(std::memory_order_relaxed);
  if (used + count > registration_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {} more: {} of {} registrations ({}) used", count,
                             used, registration_limit_, registration_limit_name()));
  }
  // Once the domain cycled, registrations go only into reservations, which check their room.
  if (state() == DomainState::open && image_size_ + bytes > image_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {} more bytes: image_too_large: {} + {} bytes "
                             "exceeds the {} byte maximum ({})",
                             bytes, image_size_, bytes, image_limit_, image_limit_name()));
  }
  return ok();
}

Result<std::uint32_t> Domain::register_pdo(PdoKey key, std::size_t bytes, PdoDirection direction,
                                           bool contributes_wkc) {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("register_pdo");
  std::lock_guard lock(control_mutex_);
  if (Reservation* r = reservation_of_locked(key.slave)) {
    return register_reserved_locked(*r, key, bytes, direction, contributes_wkc);
  }
  const DomainState s = state();
  if (s != DomainState::open) {
    return error(Errc::wrong_state,
                 fmt::format("cannot register {} ({}): not_open (the domain is {}; registration "
                             "is only possible before it first cycles)",
                             to_string(key), to_string(direction), to_string(s)));
  }
  if (auto checked = check_new_registration_locked(key, bytes, direction); !checked) {
    return std::move(checked).error();
  }
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  if (count >= registration_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {}: all {} registrations ({}) used", to_string(key),
                             registration_limit_, registration_limit_name()));
  }
  if (image_size_ + bytes > image_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {}: image_too_large: {} + {} bytes exceeds the {} "
                             "byte maximum ({})",
                             to_string(key), image_size_, bytes, image_limit_, image_limit_name()));
  }
  reserve_entry_locked(count);
  reserve_image_locked(image_size_ + bytes);
  Entry& e = entry(count);
  e.key = key;
  e.index = count;
  e.offset = image_size_;
  e.size = static_cast<std::uint16_t>(bytes);
  e.direction = direction;
  e.contributes_wkc = contributes_wkc;
  image_size_ += static_cast<std::uint32_t>(bytes);
  // Publishing the count makes the entry visible to hot-path readers, fully written.
  entry_count_.store(count + 1, std::memory_order_release);
  return config_.logical_base + e.offset;
}

Result<std::uint32_t> Domain::register_sm_status(std::uint16_t slave, std::uint8_t sync_manager) {
  return register_pdo(PdoKey{slave, sync_manager, RegistrationKind::sm_status}, 1,
                      PdoDirection::input);
}

// ---- Reservations (hot connect) --------------------------------------------------------------

Domain::Reservation* Domain::reservation_of_locked(std::uint16_t station) const noexcept {
  const std::uint32_t n = reservation_count_.load(std::memory_order_relaxed);
  for (std::uint32_t k = 0; k < n; ++k) {
    const auto& st = reservations_[k]->stations;
    if (std::find(st.begin(), st.end(), station) != st.end()) return reservations_[k].get();
  }
  return nullptr;
}

Result<std::uint32_t> Domain::reserve(std::string_view name, std::size_t bytes,
                                      std::vector<std::uint16_t> stations) {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("reserve");
  std::lock_guard lock(control_mutex_);
  const DomainState s = state();
  if (s != DomainState::open) {
    return error(Errc::wrong_state,
                 fmt::format("cannot reserve room for {}: the domain is {} (reservations are made "
                             "before it first cycles)",
                             name, to_string(s)));
  }
  if (bytes == 0 || bytes > 0xFFFF) {
    return error(
        Errc::invalid_argument,
        fmt::format("cannot reserve room for {}: size {} bytes is outside 1..65535", name, bytes));
  }
  const std::uint32_t index = reservation_count_.load(std::memory_order_relaxed);
  if (index >= kMaxReservations) {
    return error(Errc::out_of_range, fmt::format("cannot reserve room for {}: all {} reservations "
                                                 "used",
                                                 name, kMaxReservations));
  }
  for (const auto station : stations) {
    if (station == 0) {
      return error(Errc::invalid_argument,
                   fmt::format("cannot reserve room for {}: station 0 is no slave's", name));
    }
    if (const Reservation* other = reservation_of_locked(station)) {
      return error(Errc::invalid_argument,
                   fmt::format("cannot reserve room for {}: station 0x{:04x} already belongs to "
                               "{}",
                               name, station, other->name));
    }
    const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
    for (std::uint32_t i = 0; i < count; ++i) {
      if (entry(i).key.slave == station) {
        return error(Errc::invalid_argument,
                     fmt::format("cannot reserve room for {}: station 0x{:04x} has registrations "
                                 "outside it already",
                                 name, station));
      }
    }
  }
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  if (count >= registration_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot reserve room for {}: all {} registrations ({}) used", name,
                             registration_limit_, registration_limit_name()));
  }
  if (image_size_ + bytes > image_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot reserve {} bytes for {}: image_too_large: {} + {} bytes "
                             "exceeds the {} byte maximum ({})",
                             bytes, name, image_size_, bytes, image_limit_, image_limit_name()));
  }
  auto r = std::make_unique<Reservation>();
  r->name = std::string(name);
  r->stations = std::move(stations);
  r->index = index;
  r->offset = image_size_;
  r->size = static_cast<std::uint32_t>(bytes);
  r->inputs = std::make_unique<std::atomic<std::uint32_t>[]>(bytes);
  r->statuses = std::make_unique<std::atomic<std::uint32_t>[]>(bytes);
  reserve_entry_locked(count);
  reserve_image_locked(image_size_ + bytes);
  Entry& e = entry(count);
  e.key = PdoKey{0, static_cast<std::uint8_t>(index), RegistrationKind::reserved};
  e.index = count;
  e.offset = image_size_;
  e.size = static_cast<std::uint16_t>(bytes);
  e.direction = PdoDirection::output;
  e.contributes_wkc = false;
  e.reservation = static_cast<std::uint8_t>(index);
  image_size_ += static_cast<std::uint32_t>(bytes);
  reservations_[index] = std::move(r);
  reservation_count_.store(index + 1, std::memory_order_release);
  entry_count_.store(count + 1, std::memory_order_release);
  return index;
}

// The checks every new registration passes, into the image or into a hot-connect reservation.
Result<void> Domain::check_new_registration_locked(PdoKey key, std::size_t bytes,
                                                   PdoDirection direction) const {
  if (bytes == 0 || bytes > 0xFFFF) {
    return error(Errc::invalid_argument,
                 fmt::format("cannot register {}: size {} bytes is outside 1..65535",
                             to_string(key), bytes));
  }
  if (key.kind == RegistrationKind::sm_status && (bytes != 1 || direction != PdoDirection::input)) {
    return error(Errc::invalid_argument,
                 fmt::format("cannot register {}: a SyncManager status is one input byte, not {} "
                             "{} bytes",
                             to_string(key), to_string(direction), bytes));
  }
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  for (std::uint32_t i = 0; i < count; ++i) {
    if (entry(i).key == key) {
      return error(
          Errc::invalid_argument,
          fmt::format("{} is already registered (at logical 0x{:08x}, {} bytes)", to_string(key),
                      config_.logical_base + entry(i).offset, entry(i).size));
    }
  }
  return {};
}

Result<std::uint32_t> Domain::register_reserved_locked(Reservation& r, PdoKey key,
                                                       std::size_t bytes, PdoDirection direction,
                                                       bool contributes_wkc) {
  if (r.state.load(std::memory_order_acquire) == ReservationState::present) {
    return error(Errc::wrong_state,
                 fmt::format("cannot register {}: reservation {} is present (registrations are "
                             "made while it is absent or joining)",
                             to_string(key), r.name));
  }
  if (auto checked = check_new_registration_locked(key, bytes, direction); !checked) {
    return std::move(checked).error();
  }
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  if (r.used + bytes > r.size) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {}: {} + {} bytes exceed the {} bytes reserved for "
                             "{} (hot_connect reserve_bytes)",
                             to_string(key), r.used, bytes, r.size, r.name));
  }
  if (count >= registration_limit_) {
    return error(Errc::out_of_range,
                 fmt::format("cannot register {}: all {} registrations ({}) used", to_string(key),
                             registration_limit_, registration_limit_name()));
  }
  reserve_entry_locked(count);
  Entry& e = entry(count);
  e.key = key;
  e.index = count;
  e.offset = r.offset + r.used;
  e.size = static_cast<std::uint16_t>(bytes);
  e.direction = direction;
  e.contributes_wkc = contributes_wkc;
  e.reservation = static_cast<std::uint8_t>(r.index);
  r.used += static_cast<std::uint32_t>(bytes);
  entry_count_.store(count + 1, std::memory_order_release);
  if (direction == PdoDirection::input) {
    auto& list = key.kind == RegistrationKind::sm_status ? r.statuses : r.inputs;
    auto& n = key.kind == RegistrationKind::sm_status ? r.status_count : r.input_count;
    const std::uint32_t at = n.load(std::memory_order_relaxed);
    list[at].store(count, std::memory_order_relaxed);
    n.store(at + 1, std::memory_order_release);
  }
  compute_shares_locked(r);
  return config_.logical_base + e.offset;
}

void Domain::compute_shares_locked(Reservation& r) {
  if (!plan_ || !r.shares) return;
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  for (std::size_t slot = 0; slot < r.datagrams; ++slot) {
    const auto& d = plan_->datagrams[slot];
    const std::uint32_t end = d.offset + d.length;
    // Per slave of the reservation: 1 when it has an input and 2 when it has an output here.
    std::uint32_t wkc = 0;
    for (const auto station : r.stations) {
      bool reads = false;
      bool writes = false;
      for (std::uint32_t i = 0; i < count; ++i) {
        const Entry& e = entry(i);
        if (e.reservation != r.index || e.key.slave != station || !e.contributes_wkc) continue;
        if (e.offset >= end || e.offset + e.size <= d.offset) continue;
        (e.direction == PdoDirection::input ? reads : writes) = true;
      }
      wkc += (reads ? 1u : 0u) + (writes ? 2u : 0u);
    }
    r.shares[slot].store(static_cast<std::uint16_t>(std::min<std::uint32_t>(wkc, 0xFFFF)),
                         std::memory_order_relaxed);
  }
}

Result<void> Domain::set_reservation_state(std::uint32_t reservation, ReservationState state) {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("set_reservation_state");
  std::lock_guard lock(control_mutex_);
  if (reservation >= reservation_count_.load(std::memory_order_relaxed)) {
    return error(Errc::not_found, fmt::format("no reservation {}", reservation));
  }
  Reservation& r = *reservations_[reservation];
  ReservationState from = r.state.load(std::memory_order_acquire);
  for (;;) {
    if (!reservation_allowed(from, state)) {
      refused_reservation_transitions_.fetch_add(1, std::memory_order_relaxed);
      return error(Errc::wrong_state,
                   fmt::format("reservation {} ({}): {} -> {} is not a transition of its diagram",
                               reservation, r.name, to_string(from), to_string(state)));
    }
    // Fails only when the bus thread found the reservation gone meanwhile: decide again.
    if (r.state.compare_exchange_weak(from, state, std::memory_order_acq_rel,
                                      std::memory_order_acquire)) {
      return ok();
    }
  }
}

Domain::ReservationState Domain::reservation_state(std::uint32_t reservation) const noexcept {
  if (reservation >= reservation_count_.load(std::memory_order_acquire)) {
    return ReservationState::absent;
  }
  return reservations_[reservation]->state.load(std::memory_order_acquire);
}

std::size_t Domain::reservation_used(std::uint32_t reservation) const {
  std::lock_guard lock(control_mutex_);
  if (reservation >= reservation_count_.load(std::memory_order_relaxed)) return 0;
  return reservations_[reservation]->used;
}

std::uint64_t Domain::reservations_lost() const noexcept {
  return reservations_lost_.load(std::memory_order_relaxed);
}

bool Domain::reservation_absent(const Entry& e) const noexcept {
  return e.reservation != kNoReservation && e.key.kind != RegistrationKind::reserved &&
         reservations_[e.reservation]->state.load(std::memory_order_acquire) !=
             ReservationState::present;
}

std::vector<DomainDatagram> Domain::plan_locked() const {
  std::vector<DomainDatagram> out;
  const std::uint32_t count = entry_count_.load(std::memory_order_relaxed);
  const std::size_t max_dg = config_.max_datagram_size;
  std::uint32_t offset = 0;
  std::uint32_t first = 0;  // first registration ending after `offset`
  while (offset < image_size_) {
    while (first < count && entry(first).offset + entry(first).size <= offset)
      ++first;
    // Whole registrations while they fit; a registration larger than a datagram is cut.
    std::uint32_t end = offset;
    for (std::uint32_t i = first; i < count; ++i) {
      const std::uint32_t reg_end = entry(i).offset + entry(i).size;
      if (reg_end - offset <= max_dg) {
        end = reg_end;
        continue;
      }
      if (end == offset) end = offset + static_cast<std::uint32_t>(max_dg);
      break;
    }
    DomainDatagram d;
    d.offset = offset;
    d.logical = config_.logical_base + offset;
    d.length = static_cast<std::uint16_t>(end - offset);
    // Expected WKC: per slave, 1 when it has an input and 2 when it has an output overlapping.
    struct SlaveShare {
      std::uint16_t slave;
      bool reads;
      bool writes;
    };
    std::vector<SlaveShare> shares;
    for (std::uint32_t i = first; i < count && entry(i).offset < end; ++i) {
      const Entry& e = entry(i);
      if (!e.contributes_wkc || e.reservation != kNoReservation) continue;
      auto it = std::find_if(shares.begin(), shares.end(),
                             [&](const SlaveShare& s) { return s.slave == e.key.slave; });
      if (it == shares.end()) {
        shares.push_back({e.key.slave, false, false});
        it = shares.end() - 1;
      }
      (e.direction == PdoDirection::input ? it->reads : it->writes) = true;
    }
    std::uint32_t wkc = 0;
    for (const auto& s : shares)
      wkc += (s.reads ? 1u : 0u) + (s.writes ? 2u : 0u);
    d.expected_wkc = static_cast<std::uint16_t>(std::min<std::uint32_t>(wkc, 0xFFFF));
    out.push_back(d);
    offset = end;
  }
  if (!wkc_override_.empty() && wkc_override_.size() == out.size()) {
    for (std::size_t i = 0; i < out.size(); ++i)
      out[i].expected_wkc = wkc_override_[i];
  }
  return out;
}

Result<void> Domain::build_exchanges_locked() {
  auto plan = std::make_unique<Plan>();
  plan->datagrams = plan_locked();
  if (!wkc_override_.empty() && wkc_override_.size() != plan->datagrams.size()) {
    return error(Errc::invalid_argument,
                 fmt::format("the expected WKC override has {} values, but the image makes {} "
                             "datagrams",
                             wkc_override_.size(), plan->datagrams.size()));
  }
  plan->image_size = image_size_;
  plan->entry_count = entry_count_.load(std::memory_order_relaxed);
  for (const auto& d : plan->datagrams)
    plan->expected_total += d.expected_wkc;
  std::size_t reserved_inputs = 0;
  for (std::uint32_t k = 0; k < reservation_count_.load(std::memory_order_relaxed); ++k)
    reserved_inputs += reservations_[k]->size;
  for (std::uint32_t i = 0; i < plan->entry_count; ++i) {
    if (entry(i).direction != PdoDirection::input) continue;
    if (entry(i).reservation != kNoReservation) continue;  // published by their reservation
    if (entry(i).key.kind == RegistrationKind::sm_status) {
      plan->status_entries.push_back(i);
    } else {
      plan->input_entries.push_back(i);
    }
  }
  plan->tx_image.assign(image_size_, 0);
  plan->rx_image.assign(image_size_, 0);
  plan->last_inputs.assign(image_size_, 0);
  plan->changed.resize(plan->input_entries.size() + reserved_inputs);
  plan->seen_generation = restart_generation_.load(std::memory_order_relaxed);
  for (std::size_t k = 0; k < config_.exchanges_in_flight; ++k) {
    bus::Transaction tx;
    tx.reserve(plan->datagrams.size(), image_size_);
    for (const auto& d : plan->datagrams) {
      tx.lrw(d.logical, wire::Bytes(plan->tx_image.data() + d.offset, d.length), d.expected_wkc);
    }
    if (tx.error()) return tx.error()->context(fmt::format("domain \"{}\": LRW layout", id()));
    auto x = std::make_unique<Exchange>();
    x->domain = this;
    x->rt = std::make_unique<bus::RealtimeTransaction>(std::move(tx));
    Exchange* raw = x.get();
    x->rt->set_completion(
        [raw](bus::RealtimeTransaction&) { raw->domain->on_exchange_done(*raw); });
    plan->exchanges.push_back(std::move(x));
  }
  plan_ = std::move(plan);
  for (std::uint32_t k = 0; k < reservation_count_.load(std::memory_order_relaxed); ++k) {
    Reservation& r = *reservations_[k];
    r.datagrams = plan_->datagrams.size();
    r.shares = std::make_unique<std::atomic<std::uint16_t>[]>(r.datagrams);
    compute_shares_locked(r);
  }
  return ok();
}

Result<void> Domain::start_cycling() {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("start_cycling");
  std::lock_guard lock(control_mutex_);
  const DomainState s = state();
  if (s == DomainState::cycling) {
    refused_transitions_.fetch_add(1, std::memory_order_relaxed);
    return error(Errc::wrong_state, "cannot start cycling: already_cycling");
  }
  if (s == DomainState::open) {
    if (entry_count_.load(std::memory_order_relaxed) == 0) {
      return error(Errc::wrong_state, "cannot start cycling: nothing_registered");
    }
    if (auto r = build_exchanges_locked(); !r) return r;
  } else {
    // stopped -> cycling: the bus thread resets its streaks when it sees the new generation.
    restart_generation_.fetch_add(1, std::memory_order_acq_rel);
  }
  counters_->tick_ns.store(0, std::memory_order_relaxed);  // writes read the clock until a tick
  DomainState expected = s;
  const auto next = transition(s, DomainEvent::start_cycling);
  if (!next || !state_.compare_exchange_strong(expected, *next, std::memory_order_acq_rel)) {
    refused_transitions_.fetch_add(1, std::memory_order_relaxed);
    return error(Errc::wrong_state,
                 fmt::format("cannot start cycling from state {}", to_string(expected)));
  }
  return ok();
}

Result<void> Domain::stop_cycling() {
  // Lock-free (one compare-exchange), so an observer may stop the domain from the bus thread.
  DomainState s = state();
  const auto next = transition(s, DomainEvent::stop_cycling);
  if (!next || !state_.compare_exchange_strong(s, *next, std::memory_order_acq_rel)) {
    refused_transitions_.fetch_add(1, std::memory_order_relaxed);
    return error(Errc::wrong_state,
                 fmt::format("cannot stop cycling: the domain is {}", to_string(s)));
  }
  return ok();
}

Result<void> Domain::update_period(nanoseconds period) {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("update_period");
  if (period < kMinPeriod) {
    return error(Errc::invalid_argument,
                 fmt::format("period {} is below the {} minimum", format_duration(period),
                             format_duration(kMinPeriod)));
  }
  std::lock_guard lock(control_mutex_);
  const std::int64_t previous = period_ns_.exchange(period.count(), std::memory_order_acq_rel);
  // The last publish's freshness stamp was sized for the old period's stale_after(): dropped, so
  // reads take the clock until the next publish stamps with the new one.
  fresh_until_tsc_.store(0, std::memory_order_release);
  if (auto r = notify_period_changed(); !r) {
    period_ns_.store(previous, std::memory_order_release);
    return std::move(r).error().context(
        fmt::format("domain \"{}\": changing the period to {}", id(), format_duration(period)));
  }
  return ok();
}

Result<void> Domain::set_expected_wkc(std::vector<std::uint16_t> per_datagram) {
  if (bus_.on_bus_thread()) return refuse_on_bus_thread("set_expected_wkc");
  std::lock_guard lock(control_mutex_);
  if (state() != DomainState::open) {
    return error(Errc::wrong_state, "the expected WKC can only be overridden while open");
  }
  wkc_override_.clear();
  const auto computed = plan_locked();
  if (!per_datagram.empty() && per_datagram.size() != computed.size()) {
    return error(Errc::invalid_argument,
                 fmt::format("expected WKC override has {} values, the image makes {} datagrams",
                             per_datagram.size(), computed.size()));
  }
  wkc_override_ = std::move(per_datagram);
  return ok();
}

std::vector<DomainDatagram> Domain::layout() const {
  std::lock_guard lock(control_mutex_);
  if (plan_) return plan_->datagrams;
  return plan_locked();
}

std::vector<PdoRegistration> Domain::registrations() const {
  std::vector<PdoRegistration> out;
  const std::uint32_t count = entry_count_.load(std::memory_order_acquire);
  out.reserve(count);
  for (std::uint32_t i = 0; i < count; ++i) {
    const Entry& e = entry(i);
    out.push_back({e.key, PdoHandle{i}, e.offset, config_.logical_base + e.offset, e.size,
                   e.direction, e.contributes_wkc});
  }
  return out;
}

Result<PdoHandle> Domain::find(PdoKey key) const {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  return PdoHandle{(*e)->index};
}

Result<PdoRegistration> Domain::registration(PdoKey key) const {
  auto found = lookup(key);
  if (!found) return std::move(found).error();
  const Entry& e = **found;
  return PdoRegistration{
      e.key,  PdoHandle{e.index}, e.offset,         config_.logical_base + e.offset,
      e.size, e.direction,        e.contributes_wkc};
}

DomainStats Domain::stats() const noexcept {
  const Counters& c = *counters_;
  DomainStats s;
  s.state = state();
  s.refused_transitions = refused_transitions_.load(std::memory_order_relaxed);
  s.refused_reservation_transitions =
      refused_reservation_transitions_.load(std::memory_order_relaxed);
  const auto health = unpack(c.health.load(std::memory_order_relaxed));
  s.health.healthy = !health.has_value();
  s.health.invalid = health;
  s.cycle_count = c.cycles.load(std::memory_order_relaxed);
  s.valid_count = c.valid.load(std::memory_order_relaxed);
  s.miss_count = c.miss_streak.load(std::memory_order_relaxed);
  s.total_miss_count = c.total_miss.load(std::memory_order_relaxed);
  s.invalid_streak = c.invalid_streak.load(std::memory_order_relaxed);
  s.wkc_mismatch_count = c.wkc_mismatch.load(std::memory_order_relaxed);
  s.timeout_count = c.timeout.load(std::memory_order_relaxed);
  s.expired_count = c.expired.load(std::memory_order_relaxed);
  s.overrun_count = c.overrun.load(std::memory_order_relaxed);
  s.link_error_count = c.link_error.load(std::memory_order_relaxed);
  s.late_results = c.late.load(std::memory_order_relaxed);
  s.output_stage_skips = c.stage_skips.load(std::memory_order_relaxed);
  s.changes_dropped = changes_dropped_.load(std::memory_order_relaxed);
  s.last_wkc = c.last_wkc.load(std::memory_order_relaxed);
  s.last_valid_at = from_ns(c.last_valid_ns.load(std::memory_order_relaxed));
  s.last_invalid_at = from_ns(c.last_invalid_ns.load(std::memory_order_relaxed));
  s.last_invalid = unpack(c.last_invalid.load(std::memory_order_relaxed));
  const auto count = c.latency_count.load(std::memory_order_relaxed);
  if (count > 0) {
    s.last_latency = nanoseconds(c.last_latency.load(std::memory_order_relaxed));
    s.min_latency = nanoseconds(c.min_latency.load(std::memory_order_relaxed));
    s.max_latency = nanoseconds(c.max_latency.load(std::memory_order_relaxed));
    s.mean_latency = nanoseconds(c.latency_sum.load(std::memory_order_relaxed) /
                                 static_cast<std::int64_t>(count));
  }
  return s;
}

DomainInfo Domain::info() const {
  DomainInfo info;
  info.id = config_.id;
  info.period = cycle_period();
  info.stale_after = stale_after();
  info.realtime_budget = realtime_budget();
  info.logical_base = config_.logical_base;
  {
    std::lock_guard lock(control_mutex_);
    info.image_size = image_size_;
    info.datagrams = plan_ ? plan_->datagrams : plan_locked();
  }
  for (const auto& d : info.datagrams)
    info.expected_wkc += d.expected_wkc;
  info.registrations = registrations();
  info.stats = stats();
  info.state = info.stats.state;
  return info;
}

// ---------------------------------------------------------------------------------------------
// Hot path

Result<const Domain::Entry*> Domain::lookup(PdoKey key) const {
  const std::uint32_t count = entry_count_.load(std::memory_order_acquire);
  for (std::uint32_t i = 0; i < count; ++i) {
    if (entry(i).key == key) return &entry(i);
  }
  return error(Errc::not_found, fmt::format("{} is not registered", to_string(key)));
}

Result<const Domain::Entry*> Domain::lookup(PdoHandle handle) const {
  const std::uint32_t count = entry_count_.load(std::memory_order_acquire);
  if (handle.index >= count) [[unlikely]] {
    return error(Errc::not_found, fmt::format("no registration with handle {} ({} registered)",
                                              handle.index, count));
  }
  return &entry(handle.index);
}

void Domain::lock_staging() const noexcept {
  for (int spins = 0;; ++spins) {
    bool expected = false;
    if (staging_lock_.compare_exchange_weak(expected, true, std::memory_order_acquire,
                                            std::memory_order_relaxed)) {
      return;
    }
    // Holders only copy a few bytes; a holder that lost its CPU needs the CPU back.
    if (spins < 64) {
      cpu_relax();
    } else {
      std::this_thread::yield();
    }
  }
}

void Domain::unlock_staging() const noexcept {
  staging_lock_.store(false, std::memory_order_release);
}

Result<void> Domain::write_entry(const Entry& e, wire::Bytes data) {
  if (e.direction != PdoDirection::output) [[unlikely]] {
    return error(Errc::invalid_argument,
                 fmt::format("cannot write {}: it is an input", to_string(e.key)));
  }
  if (data.size() != e.size) [[unlikely]] {
    return error(Errc::invalid_argument,
                 fmt::format("cannot write {}: {} bytes given, the SM image has {}",
                             to_string(e.key), data.size(), e.size));
  }
  // While the domain cycles, an output is stamped with the start of the tick in progress (it
  // leaves with the next one): no clock read on the hot path. Otherwise, the clock.
  const std::int64_t tick =
      state() == DomainState::cycling ? counters_->tick_ns.load(std::memory_order_relaxed) : 0;
  const std::int64_t now = tick != 0 ? tick : to_ns(Clock::now());
  lock_staging();
  std::uint8_t* target = staging_.get() + e.offset;
  bool changed = e.output_written_ns.load(std::memory_order_relaxed) == 0;
  if (data.size() <= 16) {
    // A few bytes (most SM images): compared and copied in one pass, no library calls.
    for (std::size_t i = 0; i < data.size(); ++i) {
      changed = changed || target[i] != data[i];
      target[i] = data[i];
    }
  } else {
    changed = changed || std::memcmp(target, data.data(), data.size()) != 0;
    std::memcpy(target, data.data(), data.size());
  }
  ++staging_version_;
  e.output_written_ns.store(now, std::memory_order_relaxed);
  if (changed) e.output_changed_ns.store(now, std::memory_order_relaxed);
  unlock_staging();
  return ok();
}

Result<void> Domain::write(PdoKey key, wire::Bytes data) {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  return write_entry(**e, data);
}

Result<void> Domain::write(PdoHandle handle, wire::Bytes data) {
  auto e = lookup(handle);
  if (!e) return std::move(e).error();
  return write_entry(**e, data);
}

Result<void> Domain::write_bits_entry(const Entry& e, std::size_t bit_offset,
                                      std::size_t bit_length, std::uint64_t value) {
  if (e.direction != PdoDirection::output) {
    return error(Errc::invalid_argument,
                 fmt::format("cannot write bits of {}: it is an input", to_string(e.key)));
  }
  auto f = field(PdoHandle{e.index}, bit_offset, bit_length);
  if (!f) return std::move(f).error();
  return write_bits(*f, value);
}

Result<void> Domain::write_bits(PdoKey key, std::size_t bit_offset, std::size_t bit_length,
                                std::uint64_t value) {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  return write_bits_entry(**e, bit_offset, bit_length, value);
}

Result<void> Domain::write_bits(PdoHandle handle, std::size_t bit_offset, std::size_t bit_length,
                                std::uint64_t value) {
  auto e = lookup(handle);
  if (!e) return std::move(e).error();
  return write_bits_entry(**e, bit_offset, bit_length, value);
}

Result<Domain::Field> Domain::field(PdoHandle handle, std::size_t bit_offset,
                                    std::size_t bit_length) const {
  auto found = lookup(handle);
  if (!found) return std::move(found).error();
  const Entry& e = **found;
  if (bit_length == 0 || bit_length > 64 || bit_offset + bit_length > std::size_t{e.size} * 8) {
    return error(Errc::invalid_argument,
                 fmt::format("cannot {} bits {}..{} of {}: the SM image has {} bits and at most 64 "
                             "bits are {} at once",
                             e.direction == PdoDirection::input ? "read" : "write", bit_offset,
                             bit_offset + bit_length, to_string(e.key), std::size_t{e.size} * 8,
                             e.direction == PdoDirection::input ? "read" : "written"));
  }
  // Entries never move nor change once registered (but for their atomics): the position is
  // computed once.
  const std::size_t bit = std::size_t{e.offset} * 8 + bit_offset;
  Field f;
  f.domain_ = this;
  f.entry_ = &e;
  f.word_ = static_cast<std::uint32_t>(bit / 64);
  f.word_shift_ = static_cast<std::uint8_t>(bit % 64);
  f.byte_ = static_cast<std::uint32_t>(bit / 8);
  f.byte_shift_ = static_cast<std::uint8_t>(bit % 8);
  f.bit_length_ = static_cast<std::uint16_t>(bit_length);
  f.reserved_ = e.reservation != kNoReservation && e.key.kind != RegistrationKind::reserved;
  f.direction_ = e.direction;
  return f;
}

Error Domain::field_refused(const Field& f, PdoDirection direction) const {
  if (f.domain_ != this) {
    return error(Errc::invalid_argument, f.bound() ? "a field made by another domain"
                                                   : "an unbound field (Domain::field makes them)");
  }
  if (direction == PdoDirection::input) {
    return error(
        Errc::invalid_argument,
        fmt::format("read_fresh_bits({}): outputs have no freshness", to_string(f.entry_->key)));
  }
  return error(Errc::invalid_argument,
               fmt::format("cannot write bits of {}: it is an input", to_string(f.entry_->key)));
}

Result<void> Domain::write_bits(const Field& f, std::uint64_t value) {
  if (f.domain_ != this || f.direction_ != PdoDirection::output) [[unlikely]] {
    return field_refused(f, PdoDirection::output);
  }
  const Entry& e = *f.entry_;
  // While the domain cycles, an output is stamped with the start of the tick in progress (it
  // leaves with the next one): no clock read on the hot path. Otherwise, the clock.
  const std::int64_t tick =
      state() == DomainState::cycling ? counters_->tick_ns.load(std::memory_order_relaxed) : 0;
  const std::int64_t now = tick != 0 ? tick : to_ns(Clock::now());
  lock_staging();
  std::uint8_t* p = staging_.get() + f.byte_;
  bool changed = e.output_written_ns.load(std::memory_order_relaxed) == 0;
  // A byte at a time: the field's bits of each byte it covers, the others kept.
  unsigned bit = f.byte_shift_;
  const std::size_t bit_length = f.bit_length_;
  std::size_t consumed = 0;
  for (std::size_t i = 0; consumed < bit_length; ++i) {
    const unsigned take =
        static_cast<unsigned>(std::min<std::size_t>(8 - bit, bit_length - consumed));
    const auto mask = static_cast<std::uint8_t>(((1u << take) - 1u) << bit);
    const auto bits =
        static_cast<std::uint8_t>(static_cast<std::uint8_t>((value >> consumed) << bit) & mask);
    const auto next = static_cast<std::uint8_t>((p[i] & ~mask) | bits);
    changed = changed || next != p[i];
    p[i] = next;
    consumed += take;
    bit = 0;
  }
  ++staging_version_;
  e.output_written_ns.store(now, std::memory_order_relaxed);
  if (changed) e.output_changed_ns.store(now, std::memory_order_relaxed);
  unlock_staging();
  return ok();
}

FreshnessInfo Domain::freshness() const noexcept {
  FreshnessInfo f;
  f.stale_after = stale_after();
  const std::int64_t refreshed = refreshed_ns_.load(std::memory_order_acquire);
  if (refreshed == 0) return f;
  const auto now = Clock::now();
  f.refreshed_at = from_ns(refreshed);
  f.age = std::max(nanoseconds(0), now - *f.refreshed_at);
  f.state = *f.age <= f.stale_after ? Freshness::fresh : Freshness::stale;
  return f;
}

Result<SampleInfo> Domain::sample_entry(const Entry& e, wire::MutableBytes out,
                                        bool fail_stale) const {
  if (out.size() < e.size) {
    return error(Errc::invalid_argument,
                 fmt::format("cannot read {}: buffer of {} bytes, the SM image has {}",
                             to_string(e.key), out.size(), e.size));
  }
  SampleInfo info;
  info.size = e.size;
  if (e.direction == PdoDirection::output) {
    lock_staging();
    const std::int64_t written = e.output_written_ns.load(std::memory_order_relaxed);
    const std::int64_t changed = e.output_changed_ns.load(std::memory_order_relaxed);
    if (written != 0) std::memcpy(out.data(), staging_.get() + e.offset, e.size);
    unlock_staging();
    if (written == 0) {
      return error(Errc::not_ready,
                   fmt::format("{} (output) has not been written yet", to_string(e.key)));
    }
    info.updated_at = from_ns(written);
    info.changed_at = from_ns(changed);
    return info;
  }
  std::int64_t changed = 0;
  const std::int64_t refreshed = copy_published(input_seq_, refreshed_ns_, input_words_, e.offset,
                                                out.data(), e.size, &e.input_changed_ns, &changed);
  if (refreshed == 0) {
    return error(Errc::not_ready,
                 fmt::format("{} (input) has no valid cycle yet", to_string(e.key)));
  }
  FreshnessInfo f;
  f.stale_after = stale_after();
  f.refreshed_at = from_ns(refreshed);
  f.age = std::max(nanoseconds(0), Clock::now() - *f.refreshed_at);
  f.state = *f.age <= f.stale_after ? Freshness::fresh : Freshness::stale;
  if (reservation_absent(e)) {
    // A hot-connect group's input while the group is absent or still joining: what it holds is
    // from its last presence, if any.
    f.state = Freshness::stale;
    if (fail_stale) {
      return error(Errc::stale,
                   fmt::format("{} (input) is stale: it belongs to {}, which is not present",
                               to_string(e.key), reservations_[e.reservation]->name));
    }
  }
  if (fail_stale && f.state == Freshness::stale) {
    return error(
        Errc::stale,
        fmt::format("{} (input) is stale: last valid cycle {} us ago, stale after {} us",
                    to_string(e.key),
                    std::chrono::duration_cast<std::chrono::microseconds>(*f.age).count(),
                    std::chrono::duration_cast<std::chrono::microseconds>(f.stale_after).count()));
  }
  info.updated_at = f.refreshed_at;
  info.changed_at = from_ns(changed);
  info.freshness = f;
  return info;
}

Result<std::size_t> Domain::read(PdoHandle handle, wire::MutableBytes out) const {
  auto found = lookup(handle);
  if (!found) return std::move(found).error();
  const Entry& e = **found;
  if (e.direction == PdoDirection::output || out.size() < e.size) {
    auto s = sample_entry(e, out, false);
    if (!s) return std::move(s).error();
    return s->size;
  }
  // An input: sample_entry's copy and readiness check without its timestamps (no clock read).
  if (copy_published(input_seq_, refreshed_ns_, input_words_, e.offset, out.data(), e.size) == 0) {
    return error(Errc::not_ready,
                 fmt::format("{} (input) has no valid cycle yet", to_string(e.key)));
  }
  return std::size_t{e.size};
}

Result<std::size_t> Domain::read(PdoKey key, wire::MutableBytes out) const {
  auto h = find(key);
  if (!h) return std::move(h).error();
  return read(*h, out);
}

Result<std::vector<std::uint8_t>> Domain::read(PdoKey key) const {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  std::vector<std::uint8_t> value((*e)->size);
  auto s = sample_entry(**e, value, false);
  if (!s) return std::move(s).error();
  return value;
}

// read_fresh's verdict on a copy made at `refreshed` (the last valid cycle's time, 0: none) and
// stamped `fresh_until` (a TSC count, 0: none): a valid cycle, the entry's reservation present,
// not older than stale_after. Below the stamp the copy is certainly younger than that
// (tsc_clock.hpp); otherwise one clock read decides.
Result<void> Domain::check_fresh(const Entry& e, std::int64_t refreshed,
                                 std::uint64_t fresh_until) const {
  if (refreshed == 0) [[unlikely]] {
    return error(Errc::not_ready,
                 fmt::format("{} (input) has no valid cycle yet", to_string(e.key)));
  }
  if (reservation_absent(e)) [[unlikely]] {
    // A hot-connect group's input while the group is absent or still joining (as sample_entry).
    return error(Errc::stale,
                 fmt::format("{} (input) is stale: it belongs to {}, which is not present",
                             to_string(e.key), reservations_[e.reservation]->name));
  }
  if (fresh_until != 0 && detail::read_tsc() < fresh_until) [[likely]] {
    return ok();
  }
  return fresh_by_clock(e, refreshed);
}

Result<void> Domain::fresh_by_clock(const Entry& e, std::int64_t refreshed) const {
  const std::int64_t age = std::max<std::int64_t>(0, to_ns(Clock::now()) - refreshed);
  const nanoseconds limit = stale_after();
  if (age > limit.count()) [[unlikely]] {
    return error(Errc::stale,
                 fmt::format("{} (input) is stale: last valid cycle {} us ago, stale after {} us",
                             to_string(e.key), age / 1000,
                             std::chrono::duration_cast<std::chrono::microseconds>(limit).count()));
  }
  return ok();
}

Result<std::size_t> Domain::read_fresh(PdoHandle handle, wire::MutableBytes out) const {
  auto found = lookup(handle);
  if (!found) return std::move(found).error();
  const Entry& e = **found;
  if (e.direction != PdoDirection::input) {
    return error(Errc::invalid_argument,
                 fmt::format("read_fresh({}): outputs have no freshness", to_string(e.key)));
  }
  if (out.size() < e.size) {
    auto s = sample_entry(e, out, true);  // its error names the buffer's and the image's sizes
    if (!s) return std::move(s).error();
    return s->size;
  }
  // sample_entry's checks (a valid cycle, not stale) in nanoseconds, without building its
  // SampleInfo: the TSC stamp or one clock read against stale_after().
  std::uint64_t until = 0;
  const std::int64_t refreshed =
      copy_published(input_seq_, refreshed_ns_, input_words_, e.offset, out.data(), e.size, nullptr,
                     nullptr, &fresh_until_tsc_, &until);
  if (auto fresh = check_fresh(e, refreshed, until); !fresh) return std::move(fresh).error();
  return std::size_t{e.size};
}

Result<std::uint64_t> Domain::read_fresh_bits(PdoHandle handle, std::size_t bit_offset,
                                              std::size_t bit_length) const {
  auto found = lookup(handle);
  if (!found) return std::move(found).error();
  if ((*found)->direction != PdoDirection::input) {
    return error(
        Errc::invalid_argument,
        fmt::format("read_fresh_bits({}): outputs have no freshness", to_string((*found)->key)));
  }
  auto f = field(handle, bit_offset, bit_length);
  if (!f) return std::move(f).error();
  return read_fresh(*f);
}

// The field's bits from the seqlocked input words (one or two: a field of at most 64 bits spans
// at most two), with the publish's time and TSC stamp from the same section; then read_fresh's
// checks, the stamp first.
Result<std::uint64_t> Domain::read_fresh(const Field& f) const {
  if (f.domain_ != this || f.direction_ != PdoDirection::input) [[unlikely]] {
    return field_refused(f, PdoDirection::input);
  }
  const bool two = f.word_shift_ + f.bit_length_ > 64;
  std::uint64_t low = 0;
  std::uint64_t high = 0;
  std::int64_t refreshed = 0;
  std::uint64_t until = 0;
  for (int spins = 0;; ++spins) {
    const std::uint64_t s1 = input_seq_.load(std::memory_order_acquire);
    if ((s1 & 1u) == 0) [[likely]] {
      refreshed = refreshed_ns_.load(std::memory_order_relaxed);
      until = fresh_until_tsc_.load(std::memory_order_relaxed);
      const std::atomic<std::uint64_t>* words = input_words_.load(std::memory_order_acquire);
      low = words[f.word_].load(std::memory_order_relaxed);
      if (two) high = words[f.word_ + 1].load(std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (input_seq_.load(std::memory_order_relaxed) == s1) [[likely]] {
        break;
      }
    }
    if (spins < 64) {
      cpu_relax();
    } else {
      std::this_thread::yield();
    }
  }
  if (refreshed == 0 || f.reserved_) [[unlikely]] {
    if (auto checked = check_fresh(*f.entry_, refreshed, until); !checked) {
      return std::move(checked).error();
    }
  } else if (until == 0 || detail::read_tsc() >= until) [[unlikely]] {
    if (auto checked = fresh_by_clock(*f.entry_, refreshed); !checked) {
      return std::move(checked).error();
    }
  }
  // The words hold the image's bytes in memory order (store_bytes): image bit n is bit n % 8 of
  // byte n / 8, that is bit n % 64 of word n / 64 read as little-endian.
  if constexpr (std::endian::native == std::endian::big) {
    low = __builtin_bswap64(low);
    high = __builtin_bswap64(high);
  }
  std::uint64_t v = low >> f.word_shift_;
  if (two) v |= high << (64 - f.word_shift_);
  if (f.bit_length_ < 64) v &= (std::uint64_t{1} << f.bit_length_) - 1;
  return v;
}

Result<std::size_t> Domain::read_fresh(PdoKey key, wire::MutableBytes out) const {
  auto h = find(key);
  if (!h) return std::move(h).error();
  return read_fresh(*h, out);
}

Result<SampleInfo> Domain::sample(PdoHandle handle, wire::MutableBytes out) const {
  auto e = lookup(handle);
  if (!e) return std::move(e).error();
  return sample_entry(**e, out, false);
}

Result<SampleInfo> Domain::sample(PdoKey key, wire::MutableBytes out) const {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  return sample_entry(**e, out, false);
}

Result<Sample> Domain::sample(PdoKey key) const {
  auto e = lookup(key);
  if (!e) return std::move(e).error();
  Sample sample;
  sample.value.resize((*e)->size);
  auto s = sample_entry(**e, sample.value, false);
  if (!s) return std::move(s).error();
  sample.info = *s;
  return sample;
}

// ---------------------------------------------------------------------------------------------
// Change records (SPSC ring)

bool Domain::push_change(const InputChange& change) noexcept {
  const std::uint64_t head = change_head_.load(std::memory_order_relaxed);
  const std::uint64_t tail = change_tail_.load(std::memory_order_acquire);
  if (head - tail > change_mask_) {
    changes_dropped_.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  changes_[head & change_mask_] = change;
  change_head_.store(head + 1, std::memory_order_release);
  return true;
}

bool Domain::pop_change(InputChange& out) noexcept {
  const std::uint64_t tail = change_tail_.load(std::memory_order_relaxed);
  const std::uint64_t head = change_head_.load(std::memory_order_acquire);
  if (tail == head) return false;
  out = changes_[tail & change_mask_];
  change_tail_.store(tail + 1, std::memory_order_release);
  return true;
}

std::uint64_t Domain::take_dropped_changes() noexcept {
  const std::uint64_t total = changes_dropped_.load(std::memory_order_relaxed);
  const std::uint64_t fresh = total - changes_dropped_reported_;
  changes_dropped_reported_ = total;
  return fresh;
}

// ---------------------------------------------------------------------------------------------
// The cycle (bus thread)

void Domain::on_tick(const bus::CycleTick& tick) {
  (void)tick;
  if (state() != DomainState::cycling) return;
  Plan& p = *plan_;  // set before the state first became cycling (acquire above)
  Counters& c = *counters_;
  const auto now = Clock::now();
  c.tick_ns.store(to_ns(now), std::memory_order_relaxed);

  const std::uint32_t generation = restart_generation_.load(std::memory_order_acquire);
  if (generation != p.seen_generation) {
    // Restarted after a stop: the consecutive misses start over (as the reference does). The
    // invalid streak and a pending degradation stay, so the first valid cycle reports recovery.
    p.seen_generation = generation;
    p.miss_streak = 0;
    c.miss_streak.store(0, std::memory_order_relaxed);
  }

  const std::uint64_t cycle = ++p.next_cycle;
  c.cycles.fetch_add(1, std::memory_order_relaxed);

  Exchange* x = nullptr;
  const std::size_t n = p.exchanges.size();
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t i = (p.next_exchange + k) % n;
    if (!p.exchanges[i]->rt->pending()) {
      x = p.exchanges[i].get();
      p.next_exchange = (i + 1) % n;
      break;
    }
  }
  if (x == nullptr) {
    // Every exchange is still waiting for its reply or its timeout: this cycle cannot go out.
    c.overrun.fetch_add(1, std::memory_order_relaxed);
    classify_invalid(cycle, CycleInvalid{InvalidReason::timeout, p.expected_total, 0, 0}, now);
    return;
  }

  bool expected = false;
  if (staging_lock_.compare_exchange_strong(expected, true, std::memory_order_acquire,
                                            std::memory_order_relaxed)) {
    if (staging_version_ != p.seen_staging_version) {
      p.seen_staging_version = staging_version_;
      // Input ranges of the staging image are never written: they stay zero.
      std::memcpy(p.tx_image.data(), staging_.get(), p.image_size);
    }
    unlock_staging();
  } else {
    c.stage_skips.fetch_add(1, std::memory_order_relaxed);
  }
  for (std::size_t slot = 0; slot < p.datagrams.size(); ++slot) {
    const auto& d = p.datagrams[slot];
    std::memcpy(x->rt->output(slot).data(), p.tx_image.data() + d.offset, d.length);
  }

  x->cycle = cycle;
  x->submitted_at = now;
  if (auto r = bus_.submit_realtime(*x->rt, realtime_budget()); !r) {
    c.link_error.fetch_add(1, std::memory_order_relaxed);
    const InvalidReason reason =
        r.error().code() == Errc::closed ? InvalidReason::closed : InvalidReason::link_error;
    classify_invalid(cycle, CycleInvalid{reason, p.expected_total, 0, 0}, now);
  }
}

void Domain::record_latency(std::int64_t ns) noexcept {
  Counters& c = *counters_;
  c.last_latency.store(ns, std::memory_order_relaxed);
  if (ns < c.min_latency.load(std::memory_order_relaxed)) {
    c.min_latency.store(ns, std::memory_order_relaxed);
  }
  if (ns > c.max_latency.load(std::memory_order_relaxed)) {
    c.max_latency.store(ns, std::memory_order_relaxed);
  }
  c.latency_sum.fetch_add(ns, std::memory_order_relaxed);
  c.latency_count.fetch_add(1, std::memory_order_relaxed);
}

void Domain::on_exchange_done(Exchange& x) noexcept {
  Plan& p = *plan_;
  Counters& c = *counters_;
  const std::uint64_t tsc_before = detail::read_tsc();
  const auto now = Clock::now();
  const std::uint64_t tsc_after = detail::read_tsc();
  p.tsc.sample(tsc_before, to_ns(now), tsc_after);
  p.reply_tsc = tsc_before;
  const bus::RealtimeStatus status = x.rt->status();
  const bool replied =
      status == bus::RealtimeStatus::ok || status == bus::RealtimeStatus::wkc_mismatch;
  if (replied) {
    record_latency((now - x.submitted_at).count());
    std::uint32_t actual = 0;
    std::optional<std::uint16_t> first_bad;
    const std::uint32_t reservations = reservation_count_.load(std::memory_order_acquire);
    // Reservations (hot connect): present ones' shares are expected, joining ones' may be there
    // or not (their FMMUs are being switched on). Read once per cycle.
    std::uint32_t present = 0;
    std::uint32_t joining = 0;
    for (std::uint32_t k = 0; k < reservations; ++k) {
      const auto st = reservations_[k]->state.load(std::memory_order_acquire);
      if (st == ReservationState::present) present |= 1u << k;
      if (st == ReservationState::joining) joining |= 1u << k;
    }
    auto share = [&](std::uint32_t mask, std::size_t slot) {
      std::uint32_t sum = 0;
      for (std::uint32_t k = 0; k < reservations; ++k) {
        if ((mask & (1u << k)) != 0 && reservations_[k]->shares &&
            slot < reservations_[k]->datagrams)
          sum += reservations_[k]->shares[slot].load(std::memory_order_relaxed);
      }
      return sum;
    };
    for (std::size_t slot = 0; slot < p.datagrams.size(); ++slot) {
      const std::uint16_t wkc = x.rt->wkc(slot);
      actual += wkc;
      if (first_bad) continue;
      std::uint32_t lo = p.datagrams[slot].expected_wkc;
      if (present != 0) lo += share(present, slot);
      const std::uint32_t hi = joining != 0 ? lo + share(joining, slot) : lo;
      // A joining group's slaves switch their shares on one by one (an input slave counts from
      // SAFEOP, an output slave's write only from OP): any part of the joining share is valid.
      if (wkc < lo || wkc > hi) first_bad = static_cast<std::uint16_t>(slot);
    }
    c.last_wkc.store(actual, std::memory_order_relaxed);
    if (first_bad && present != 0 && actual > 0) {
      // A present reservation gone (a hot-connect group unplugged)? Its share, or every present
      // one's (a group cut off the ones behind it), missing from every datagram and nothing
      // else: the others' cycle is whole.
      auto gone_explains = [&](std::uint32_t gone) {
        for (std::size_t slot = 0; slot < p.datagrams.size(); ++slot) {
          const std::uint32_t missing = share(gone, slot);
          const std::uint32_t lo = p.datagrams[slot].expected_wkc + share(present, slot) - missing;
          const std::uint32_t hi = joining != 0 ? lo + share(joining, slot) : lo;
          const std::uint16_t wkc = x.rt->wkc(slot);
          if (wkc < lo || wkc > hi) return false;
        }
        return true;
      };
      std::uint32_t gone = 0;
      for (std::uint32_t k = 0; k < reservations && gone == 0; ++k) {
        if ((present & (1u << k)) != 0 && gone_explains(1u << k)) gone = 1u << k;
      }
      if (gone == 0 && gone_explains(present)) gone = present;
      bool counted = false;
      for (std::uint32_t k = 0; k < reservations; ++k) {
        if ((gone & (1u << k)) == 0) continue;
        // The diagram's present -> absent, one compare-exchange: a reservation the control
        // thread changed meanwhile is its to report.
        static_assert(reservation_allowed(RS::present, RS::absent));
        ReservationState expected = ReservationState::present;
        if (!reservations_[k]->state.compare_exchange_strong(expected, ReservationState::absent,
                                                             std::memory_order_acq_rel)) {
          continue;
        }
        counted = true;
        reservations_lost_.fetch_add(1, std::memory_order_relaxed);
        if (DomainObserver* o = observer_.load(std::memory_order_acquire)) {
          o->on_reservation_lost(*this, k);
        }
      }
      if (counted || gone != 0) first_bad.reset();
    }
    if (!first_bad && actual > 0) {
      classify_valid(x, now);
      return;
    }
    c.wkc_mismatch.fetch_add(1, std::memory_order_relaxed);
    classify_invalid(
        x.cycle,
        CycleInvalid{InvalidReason::wkc_mismatch, p.expected_total, actual, first_bad.value_or(0)},
        now);
    return;
  }
  InvalidReason reason = InvalidReason::timeout;
  switch (status) {
    case bus::RealtimeStatus::expired:
      c.expired.fetch_add(1, std::memory_order_relaxed);
      break;
    case bus::RealtimeStatus::timeout:
      c.timeout.fetch_add(1, std::memory_order_relaxed);
      break;
    case bus::RealtimeStatus::link_error:
      c.link_error.fetch_add(1, std::memory_order_relaxed);
      reason = InvalidReason::link_error;
      break;
    case bus::RealtimeStatus::closed:
      c.link_error.fetch_add(1, std::memory_order_relaxed);
      reason = InvalidReason::closed;
      break;
    default:
      return;
  }
  classify_invalid(x.cycle, CycleInvalid{reason, p.expected_total, 0, 0}, now);
}

void Domain::classify_valid(Exchange& x, Clock::time_point now) noexcept {
  Plan& p = *plan_;
  Counters& c = *counters_;
  if (x.cycle <= p.last_classified) {
    // A newer cycle already counted (this one waited behind a lost frame): its inputs are older
    // than what readers have.
    c.late.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  p.last_classified = x.cycle;
  for (std::size_t slot = 0; slot < p.datagrams.size(); ++slot) {
    const auto& d = p.datagrams[slot];
    const auto in = x.rt->input(slot);
    std::memcpy(p.rx_image.data() + d.offset, in.data(),
                std::min<std::size_t>(in.size(), d.length));
  }
  publish_inputs(x.cycle, now);
  c.valid.fetch_add(1, std::memory_order_relaxed);
  c.last_valid_ns.store(to_ns(now), std::memory_order_relaxed);
  c.health.store(0, std::memory_order_relaxed);
  p.miss_streak = 0;
  p.invalid_streak = 0;
  c.miss_streak.store(0, std::memory_order_relaxed);
  c.invalid_streak.store(0, std::memory_order_relaxed);
  if (p.degraded) {
    p.degraded = false;
    if (DomainObserver* o = observer_.load(std::memory_order_acquire)) o->on_cycle_recovered(*this);
  }
  if (config_.on_cycle) config_.on_cycle(*this, CycleOutcome{x.cycle, true, std::nullopt});
  announce_valid_cycle(x.cycle);
}

void Domain::classify_invalid(std::uint64_t cycle, CycleInvalid invalid,
                              Clock::time_point now) noexcept {
  Plan& p = *plan_;
  Counters& c = *counters_;
  const bool miss = invalid.reason != InvalidReason::wkc_mismatch;
  if (miss) c.total_miss.fetch_add(1, std::memory_order_relaxed);
  c.last_invalid_ns.store(to_ns(now), std::memory_order_relaxed);
  c.last_invalid.store(pack(invalid), std::memory_order_relaxed);
  if (cycle <= p.last_classified) {
    // Older than the newest result: counted, but it says nothing about the current health.
    c.late.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  p.last_classified = cycle;
  c.health.store(pack(invalid), std::memory_order_relaxed);
  ++p.invalid_streak;
  p.miss_streak = miss ? p.miss_streak + 1 : 0;
  c.invalid_streak.store(p.invalid_streak, std::memory_order_relaxed);
  c.miss_streak.store(p.miss_streak, std::memory_order_relaxed);
  DomainObserver* observer = observer_.load(std::memory_order_acquire);
  if (!p.degraded && p.invalid_streak >= config_.recovery_threshold) {
    p.degraded = true;
    if (observer) observer->on_cycle_degraded(*this, invalid);
  }
  if (miss && p.miss_streak >= config_.miss_threshold) {
    DomainState expected = DomainState::cycling;
    const auto next = transition(expected, DomainEvent::miss_threshold);
    if (next && state_.compare_exchange_strong(expected, *next, std::memory_order_acq_rel)) {
      if (observer) observer->on_stopped(*this, invalid, p.miss_streak);
    }
  }
  if (config_.on_cycle) config_.on_cycle(*this, CycleOutcome{cycle, false, invalid});
}

void Domain::publish_inputs(std::uint64_t cycle, Clock::time_point now) noexcept {
  Plan& p = *plan_;
  std::size_t changed = 0;
  // The present reservations' inputs (hot connect) after the fixed ones'.
  const std::uint32_t reservations = reservation_count_.load(std::memory_order_acquire);
  std::uint32_t present = 0;
  for (std::uint32_t k = 0; k < reservations; ++k) {
    if (reservations_[k]->state.load(std::memory_order_acquire) == ReservationState::present) {
      present |= 1u << k;
    }
  }
  auto detect = [&](std::uint32_t index) {
    const Entry& e = entry(index);
    const std::uint8_t* fresh = p.rx_image.data() + e.offset;
    const std::uint8_t* old = p.last_inputs.data() + e.offset;
    std::size_t first = 0;
    if (p.published) {
      while (first < e.size && fresh[first] == old[first])
        ++first;
      if (first == e.size) return;
    }
    std::size_t last = e.size - 1;
    if (p.published) {
      while (last > first && fresh[last] == old[last])
        --last;
    }
    if (changed >= p.changed.size()) return;
    p.changed[changed++] = {index, static_cast<std::uint16_t>(first),
                            static_cast<std::uint16_t>(last)};
  };
  for (std::uint32_t k = 0; k < reservations; ++k) {
    if ((present & (1u << k)) == 0) continue;
    const Reservation& r = *reservations_[k];
    const std::uint32_t n = r.input_count.load(std::memory_order_acquire);
    for (std::uint32_t i = 0; i < n; ++i)
      detect(r.inputs[i].load(std::memory_order_relaxed));
  }
  for (const std::uint32_t index : p.input_entries)
    detect(index);

  const std::int64_t now_ns = to_ns(now);
  const std::uint64_t seq = input_seq_.load(std::memory_order_relaxed);
  input_seq_.store(seq + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  for (std::size_t i = 0; i < changed; ++i) {
    Entry& e = entry(p.changed[i].entry);
    store_bytes(input_words_.load(std::memory_order_relaxed), e.offset,
                p.rx_image.data() + e.offset, e.size);
    e.input_changed_ns.store(now_ns, std::memory_order_relaxed);
  }
  // SyncManager status bytes (a mailbox's "full" bit) are read by the master itself: published
  // with the cycle, but not change records (they are nobody's signal).
  auto status = [&](std::uint32_t index) {
    Entry& e = entry(index);
    const std::uint8_t* fresh = p.rx_image.data() + e.offset;
    std::uint8_t* old = p.last_inputs.data() + e.offset;
    if (p.published && std::memcmp(fresh, old, e.size) == 0) return;
    store_bytes(input_words_.load(std::memory_order_relaxed), e.offset, fresh, e.size);
    e.input_changed_ns.store(now_ns, std::memory_order_relaxed);
    std::memcpy(old, fresh, e.size);
  };
  for (const std::uint32_t index : p.status_entries)
    status(index);
  for (std::uint32_t k = 0; k < reservations; ++k) {
    if ((present & (1u << k)) == 0) continue;
    const Reservation& r = *reservations_[k];
    const std::uint32_t n = r.status_count.load(std::memory_order_acquire);
    for (std::uint32_t i = 0; i < n; ++i)
      status(r.statuses[i].load(std::memory_order_relaxed));
  }
  refreshed_ns_.store(now_ns, std::memory_order_relaxed);
  // Until this TSC count, less than stale_after has certainly passed since `now` (reply_tsc was
  // read before it): a reader below it needs no clock read. 0: no stamp, readers read the clock.
  const std::uint64_t ticks = p.tsc.ticks_within(stale_after());
  fresh_until_tsc_.store(ticks != 0 ? p.reply_tsc + ticks : 0, std::memory_order_relaxed);
  input_seq_.store(seq + 2, std::memory_order_release);
  p.published = true;

  for (std::size_t i = 0; i < changed; ++i) {
    const Entry& e = entry(p.changed[i].entry);
    std::memcpy(p.last_inputs.data() + e.offset, p.rx_image.data() + e.offset, e.size);
    InputChange record;
    record.handle = PdoHandle{e.index};
    record.key = e.key;
    record.cycle = cycle;
    record.at = now;
    record.first_byte = p.changed[i].first;
    record.last_byte = p.changed[i].last;
    push_change(record);
  }
  if (changed > 0) {
    if (DomainObserver* o = observer_.load(std::memory_order_acquire)) {
      o->on_inputs_changed(*this, changed);
    }
  }
}

// ---- await_next_cycle ----------------------------------------------------------------------
// A futex on the count of valid cycles: the bus thread bumps it and wakes only when a waiter
// announced itself (both sides sequentially consistent, so either the bus thread sees the waiter
// or the waiter's FUTEX_WAIT sees the new count and returns at once). Waiters sleep in slices so
// that a domain stopped under them is noticed.

namespace {

static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t) &&
              std::atomic<std::uint32_t>::is_always_lock_free);

std::uint32_t* futex_word(std::atomic<std::uint32_t>& word) noexcept {
  return reinterpret_cast<std::uint32_t*>(&word);
}

void futex_wait(std::atomic<std::uint32_t>& word, std::uint32_t expected,
                nanoseconds timeout) noexcept {
  const auto ns = std::max<std::int64_t>(0, timeout.count());
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAIT_PRIVATE, expected, &ts, nullptr, 0);
}

void futex_wake_all(std::atomic<std::uint32_t>& word) noexcept {
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAKE_PRIVATE, std::numeric_limits<int>::max(),
                nullptr, nullptr, 0);
}

}  // namespace

void Domain::announce_valid_cycle(std::uint64_t cycle) noexcept {
  last_valid_cycle_.store(cycle, std::memory_order_relaxed);
  valid_cycle_seq_.fetch_add(1, std::memory_order_seq_cst);
  if (cycle_waiters_.load(std::memory_order_seq_cst) != 0) futex_wake_all(valid_cycle_seq_);
}

Result<CycleOutcome> Domain::await_next_cycle(nanoseconds timeout) {
  if (bus_.on_bus_thread()) {
    return error(Errc::wrong_state,
                 "await_next_cycle() called on the bus thread (from the per-cycle callback or an "
                 "observer): it would wait for the cycle it is part of; the callback already "
                 "runs once per cycle");
  }
  const auto not_cycling = [this](std::string_view when) {
    return error(Errc::wrong_state, fmt::format("await_next_cycle(): the domain is {} ({})",
                                                to_string(state()), when));
  };
  if (state() != DomainState::cycling) return not_cycling("when called");
  const std::uint32_t seen = valid_cycle_seq_.load(std::memory_order_seq_cst);
  const std::uint64_t invalid_before = stats().cycle_count - stats().valid_count;
  const auto deadline = Clock::now() + timeout;
  constexpr nanoseconds kSlice = 50ms;  // how soon a stop under a waiter is noticed
  for (;;) {
    if (valid_cycle_seq_.load(std::memory_order_seq_cst) != seen) {
      return CycleOutcome{last_valid_cycle_.load(std::memory_order_relaxed), true, std::nullopt};
    }
    if (state() != DomainState::cycling) return not_cycling("stopped while waited on");
    const auto left = deadline - Clock::now();
    if (left <= nanoseconds(0)) break;
    cycle_waiters_.fetch_add(1, std::memory_order_seq_cst);
    futex_wait(valid_cycle_seq_, seen, std::min<nanoseconds>(left, kSlice));
    cycle_waiters_.fetch_sub(1, std::memory_order_seq_cst);
  }
  const DomainStats s = stats();
  const std::uint64_t invalid = s.cycle_count - s.valid_count - invalid_before;
  return error(
      Errc::timeout,
      fmt::format("no valid cycle within {} us ({} cycles meanwhile not valid{})",
                  std::chrono::duration_cast<std::chrono::microseconds>(timeout).count(), invalid,
                  s.last_invalid
                      ? fmt::format(", last invalid: {}", to_string(s.last_invalid->reason))
                      : std::string()));
}

}  // namespace ecat::master
