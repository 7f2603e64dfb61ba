// Domain: one logical process image, exchanged with the slaves by LRW every cycle.
//
// Life cycle (the reference design's states; the table is Domain::transition in domain.cpp):
//
//     open --start_cycling--> cycling --stop_cycling / miss threshold--> stopped
//                               ^                                          |
//                               +----------------start_cycling-------------+
//
//  * open: slaves register their process-data SyncManager images (register_pdo). Each
//    registration appends one whole SM image to the image and returns its logical address (the
//    FMMU's logical start). Outputs may already be staged.
//  * cycling: start_cycling() froze the layout into LRW datagrams. The Domain is a
//    CyclicParticipant: the Cycler of its bus calls on_tick() on the bus thread every period
//    (add the Domain to the Cycler; a Domain not in a Cycler never cycles).
//  * stopped: no more exchanges; the image keeps its last values. start_cycling() resumes (and
//    resets the consecutive miss count). Registration is closed for good once cycling started.
//  Cycle health (healthy / invalid{reason}) is runtime data in stats(), not a state.
//
// Keys and layout
//  * A registration is named by PdoKey {slave, sync_manager, kind}: the slave's configured station
//    address, the SyncManager index and what of it is mapped (its image, or its status byte:
//    register_sm_status). One key, one registration.
//  * The image is the registrations in registration order, each at the next free byte. The
//    domain's logical window starts at DomainConfig::logical_base.
//  * Images larger than one datagram are split into several LRW datagrams (each at most
//    DomainConfig::max_datagram_size, by default as large as a frame of the bus allows), cut at
//    registration boundaries when a registration fits, sent in one realtime exchange (the bus
//    puts them in as many frames as needed). An image may be up to max_image_size bytes.
//
// Expected working counter, per datagram: each slave with a registration overlapping the datagram
// adds 1 when one of its overlapping registrations is an input (its read FMMU is served) and 2 when
// one is an output (its write FMMU is served): an LRW counts 3 for a slave with both. A
// registration made with contributes_wkc = false is left out (an SM whose FMMU another domain
// counts, padding). With one datagram this is the reference's 2 x output slaves + input slaves.
// set_expected_wkc() overrides it. A cycle is valid when every datagram's WKC equals its
// expectation and their sum is above 0.
//
// Hot path (write, write_bits, read, read_fresh, sample) — any thread, any time, never waits for
// the bus thread and never allocates on success:
//  * Outputs: writers copy into a staging image under a tiny spinlock (writers only wait for each
//    other, for a memcpy). The bus thread takes the staging image with try_lock each cycle; if a
//    writer holds the lock at that instant, the cycle goes out with the previous cycle's outputs
//    (counted as output_stage_skips) rather than waiting: a cycle never blocks on a user thread.
//    A seqlock would need the bus thread to retry (unbounded while writers keep writing) and a
//    triple buffer needs a single writer; the spinlock fallback keeps the bus thread wait-free
//    with any number of writers.
//  * Inputs: the bus thread publishes each valid reply into the input image under a seqlock
//    (single writer, any number of readers that retry on a concurrent publish). Readers get one
//    cycle's bytes for a key, never a mix of two cycles.
//  * read() of an input fails with Errc::not_ready until the first valid cycle; read() of an
//    output with Errc::not_ready until it was written. read_fresh() also fails with Errc::stale
//    when the last valid cycle is older than stale_after. Unknown keys: Errc::not_found.
//
// Events: after each valid cycle the bus thread records which input registrations changed (and
// which bytes) into a bounded lock-free SPSC queue; the owner drains it with drain_changes() on
// its control thread. A full queue drops records and counts them; the next drain reports the
// drop. DomainObserver tells the owner, on the bus thread, about changes, degradation, recovery
// and the stop at the miss threshold.
//
// Threading: control-plane calls (register_pdo, start_cycling, update_period, set_expected_wkc)
// may come from any thread but the bus thread (refused there with Errc::wrong_state), serialized
// by a mutex the bus thread never takes; stop_cycling() works from any thread, the bus thread
// included. layout(), registrations(), info() are for the control side. Destroying the Domain waits
// for its exchanges still in flight (the bus completes every exchange) and removes it from its
// Cycler first.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <compare>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include <ecat/master/config.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/pdo.hpp>  // PdoDirection: input (read FMMU), output (write FMMU)
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::bus {
class Bus;
struct CycleTick;
}  // namespace ecat::bus

namespace ecat::master {

class Domain;

// Told about cycle events, on the bus thread, right when they happen. Keep it cheap: no blocking,
// no allocation in on_inputs_changed (it may come every cycle) — typically set a flag or post to
// the owner's own event loop and do the work there. stop_cycling() may be called from here; the
// other control-plane methods are refused on the bus thread.
class DomainObserver {
 public:
  virtual ~DomainObserver() = default;
  // Input records were queued for drain_changes() (count: this cycle's records).
  virtual void on_inputs_changed(Domain& domain, std::size_t count) {
    (void)domain;
    (void)count;
  }
  // The invalid streak reached recovery_threshold.
  virtual void on_cycle_degraded(Domain& domain, const CycleInvalid& last) {
    (void)domain;
    (void)last;
  }
  // The first valid cycle after a degradation.
  virtual void on_cycle_recovered(Domain& domain) { (void)domain; }
  // A present reservation's slaves stopped answering: this cycle's working counter was the
  // expected one less exactly their share, so the cycle counted as valid for the others and the
  // reservation is now absent (Domain::reserve). Rare: posting to the owner's loop is fine.
  virtual void on_reservation_lost(Domain& domain, std::uint32_t reservation) {
    (void)domain;
    (void)reservation;
  }
  // The miss streak reached miss_threshold: the domain is now stopped.
  virtual void on_stopped(Domain& domain, const CycleInvalid& last, std::uint64_t misses) {
    (void)domain;
    (void)last;
    (void)misses;
  }
};

class Domain final : public CyclicParticipant {
 public:
  static constexpr std::chrono::nanoseconds kMinPeriod = std::chrono::microseconds(50);

  // Checks the configuration (errors name the field) and reserves all storage.
  static Result<std::unique_ptr<Domain>> create(bus::Bus& bus, DomainConfig config,
                                                DomainObserver* observer = nullptr);
  ~Domain() override;

  const std::string& id() const noexcept { return config_.id; }
  DomainState state() const noexcept { return state_.load(std::memory_order_acquire); }
  // Replaces the observer (nullptr: none). Takes effect from the next event.
  void set_observer(DomainObserver* observer) noexcept {
    observer_.store(observer, std::memory_order_release);
  }

  // ---- Control plane ---------------------------------------------------------------------
  // Appends a whole SM image of `bytes` bytes (1..65535) and returns its logical address.
  // Errc::wrong_state when not open (not_open), Errc::invalid_argument for a zero or oversized
  // size or a key already registered, Errc::out_of_range when the image would exceed
  // max_image_size (image_too_large) or max_registrations is reached (their defaults: the
  // kAutoImageLimit and kMaxRegistrations ceilings).
  Result<std::uint32_t> register_pdo(PdoKey key, std::size_t bytes, PdoDirection direction,
                                     bool contributes_wkc = true);
  // Appends SyncManager `sync_manager`'s status byte (0x0805 + 8 n, read through an FMMU of the
  // slave's own): a registration of kind sm_status, one input byte that counts in the working
  // counter as any read FMMU does (once per slave and datagram). Its value is published with each
  // valid cycle (read / read_fresh / sample by its key or handle) but makes no change records.
  Result<std::uint32_t> register_sm_status(std::uint16_t slave, std::uint8_t sync_manager);
  // Whether `count` more registrations of `bytes` bytes in all fit (max_registrations,
  // max_image_size), refused in the words register_pdo would use: a slave checks all its
  // SyncManagers first, so it registers all of them or none (a half-registered slave would leave
  // the domain expecting a working counter that cannot come).
  Result<void> check_room(std::size_t count, std::size_t bytes) const;
  // open/stopped -> cycling. Errc::wrong_state when already cycling (already_cycling) or with
  // nothing registered (nothing_registered).
  Result<void> start_cycling();
  // cycling -> stopped. Errc::wrong_state when not cycling.
  Result<void> stop_cycling();
  // New period (>= kMinPeriod), live: the Cycler reschedules between two ticks; stale_after and
  // the realtime budget follow unless configured.
  Result<void> update_period(std::chrono::nanoseconds period);
  // ---- Reservations (hot connect) ------------------------------------------------------------
  // Room in the image kept for slaves that may come and go (a hot-connect group): `bytes` at the
  // image's end, reserved while open, so that nothing moves when they appear. A registration of
  // one of `stations` (register_pdo, register_sm_status) is placed inside the reservation instead
  // of appended, and is allowed in any domain state (while cycling too). The reservation's
  // registrations count in the expected working counter only while it is `present`; while
  // `joining` a datagram's WKC is accepted with or without their share (their FMMUs are being
  // switched on); while `absent` their inputs read as stale (read_fresh/sample fail with
  // Errc::stale naming the reservation) and their staged outputs are kept. A present
  // reservation whose share vanishes from a cycle (the group was unplugged) becomes absent on the
  // bus thread, the cycle stays valid for the others, and the observer hears of it.
  static constexpr std::size_t kMaxReservations = 16;
  enum class ReservationState : std::uint8_t { absent, joining, present };
  // The reservation's state diagram: the only changes a reservation makes, each edge with what
  // causes it. The control thread's changes (set_reservation_state) and the bus thread's
  // present -> absent (one compare-exchange) both go through it; an undrawn change asked for is
  // refused and counted (DomainStats::refused_reservation_transitions).
  struct ReservationTransition {
    ReservationState from;
    ReservationState to;
    std::string_view label;
  };
  static std::span<const ReservationTransition> reservation_transitions() noexcept;
  static bool reservation_transition_allowed(ReservationState from, ReservationState to) noexcept;
  Result<std::uint32_t> reserve(std::string_view name, std::size_t bytes,
                                std::vector<std::uint16_t> stations);
  // From the control side only: a drawn change from the reservation's state now (read and
  // compare-exchanged, so a loss the bus thread records meanwhile is taken into account);
  // Errc::wrong_state, counted, for an undrawn one.
  Result<void> set_reservation_state(std::uint32_t reservation, ReservationState state);
  ReservationState reservation_state(std::uint32_t reservation) const noexcept;
  // Bytes used by the reservation's registrations.
  std::size_t reservation_used(std::uint32_t reservation) const;
  // Times a present reservation was found gone by the bus thread.
  std::uint64_t reservations_lost() const noexcept;

  // Replaces the computed per-datagram expected WKC (size must match layout().size()); an empty
  // vector restores the computed values. Only while open.
  Result<void> set_expected_wkc(std::vector<std::uint16_t> per_datagram);

  // The datagrams the current registrations make (the plan start_cycling() freezes).
  std::vector<DomainDatagram> layout() const;
  std::vector<PdoRegistration> registrations() const;
  Result<PdoHandle> find(PdoKey key) const;
  Result<PdoRegistration> registration(PdoKey key) const;

  DomainStats stats() const noexcept;
  DomainInfo info() const;

  // ---- Hot path ----------------------------------------------------------------------------
  // Stages a whole output SM image (data.size() must equal its size).
  Result<void> write(PdoKey key, wire::Bytes data);
  Result<void> write(PdoHandle handle, wire::Bytes data);
  // Stages `bit_length` (1..64) bits of `value` at `bit_offset` within the output image, LSB
  // first (EtherCAT bit order), leaving the other bits as they are.
  Result<void> write_bits(PdoKey key, std::size_t bit_offset, std::size_t bit_length,
                          std::uint64_t value);
  Result<void> write_bits(PdoHandle handle, std::size_t bit_offset, std::size_t bit_length,
                          std::uint64_t value);
  // Copies the current value into `out` (at least the registration's size); returns the size.
  Result<std::size_t> read(PdoKey key, wire::MutableBytes out) const;
  Result<std::size_t> read(PdoHandle handle, wire::MutableBytes out) const;
  Result<std::vector<std::uint8_t>> read(PdoKey key) const;
  // Like read() for inputs, but fails closed: Errc::stale when the last valid cycle is older than
  // stale_after.
  Result<std::size_t> read_fresh(PdoHandle handle, wire::MutableBytes out) const;
  Result<std::size_t> read_fresh(PdoKey key, wire::MutableBytes out) const;
  // read_fresh of `bit_length` (1..64) bits at `bit_offset` within an input image only (LSB
  // first, the mirror of write_bits): the bytes they cover, from one cycle, with read_fresh's
  // checks and errors (Errc::invalid_argument for an output or bits outside the image).
  Result<std::uint64_t> read_fresh_bits(PdoHandle handle, std::size_t bit_offset,
                                        std::size_t bit_length) const;
  // A field of 1..64 bits of one registration, checked once (field()) and then read or staged
  // without a lookup or a range check per call: what Slave::read_input / write_output and
  // SignalHandle keep. Only the Domain that made it accepts it; a default-constructed one is
  // unbound (refused with Errc::invalid_argument).
 private:
  struct Entry;

 public:
  class Field {
   public:
    Field() = default;
    bool bound() const noexcept { return entry_ != nullptr; }
    PdoDirection direction() const noexcept { return direction_; }
    bool operator==(const Field&) const = default;

   private:
    friend class Domain;
    const Domain* domain_ = nullptr;
    const Entry* entry_ = nullptr;
    std::uint32_t word_ = 0;        // inputs: the first 64-bit word of the image it covers
    std::uint32_t byte_ = 0;        // outputs: its first byte in the image
    std::uint16_t bit_length_ = 0;  // 1..64
    std::uint8_t word_shift_ = 0;   // its first bit in word_ (0..63)
    std::uint8_t byte_shift_ = 0;   // its first bit in byte_ (0..7)
    bool reserved_ = false;         // in a hot-connect reservation: absent reads as stale
    PdoDirection direction_ = PdoDirection::input;
  };
  // `bit_length` (1..64) bits at `bit_offset` of the registration's image, as read_fresh_bits /
  // write_bits take them: Errc::not_found for an unknown handle, Errc::invalid_argument for bits
  // outside the image.
  Result<Field> field(PdoHandle handle, std::size_t bit_offset, std::size_t bit_length) const;
  // read_fresh_bits / write_bits of a field made by field(): the same checks and errors, with no
  // lookup. The freshness check is read_fresh's (a TSC stamp, else one clock read).
  Result<std::uint64_t> read_fresh(const Field& field) const;
  Result<void> write_bits(const Field& field, std::uint64_t value);
  // Value plus timestamps and freshness.
  Result<SampleInfo> sample(PdoHandle handle, wire::MutableBytes out) const;
  Result<SampleInfo> sample(PdoKey key, wire::MutableBytes out) const;
  Result<Sample> sample(PdoKey key) const;
  // Freshness of the inputs as a whole.
  FreshnessInfo freshness() const noexcept;

  // ---- Waiting for the cycle (application threads) ------------------------------------------
  // Blocks until the next valid cycle after the call has completed: its inputs published (read()
  // sees them) and the per-cycle callback run. Invalid cycles are waited through. Returns that
  // cycle's outcome. Errc::timeout when none came in `timeout` (the message says how many invalid
  // ones did, and why the last was invalid); Errc::wrong_state when the domain is not cycling or
  // stops while waited on, and on the bus thread (the per-cycle callback, an observer): there it
  // would wait for the cycle it is part of. The bus thread wakes waiters with one system call
  // per valid cycle, and only while someone waits.
  Result<CycleOutcome> await_next_cycle(std::chrono::nanoseconds timeout);

  // Delivers queued input change records to `f(const InputChange&)`, oldest first. One drainer
  // at a time (serialized internally).
  template <class F>
  DrainResult drain_changes(F&& f) {
    std::lock_guard lock(drain_mutex_);
    DrainResult result;
    result.dropped = take_dropped_changes();
    InputChange change;
    while (pop_change(change)) {
      f(static_cast<const InputChange&>(change));
      ++result.delivered;
    }
    return result;
  }

  // ---- CyclicParticipant ---------------------------------------------------------------------
  // Bus thread: stages outputs and submits this cycle's exchange.
  void on_tick(const bus::CycleTick& tick) override;
  std::chrono::nanoseconds cycle_period() const noexcept override {
    return std::chrono::nanoseconds(period_ns_.load(std::memory_order_acquire));
  }
  std::chrono::nanoseconds stale_after() const noexcept;
  std::chrono::nanoseconds realtime_budget() const noexcept;

 private:
  struct Exchange;
  struct Plan;
  struct Reservation;

  Domain(bus::Bus& bus, DomainConfig config, DomainObserver* observer);

  Error error(Errc code, std::string_view what) const;
  Error refuse_on_bus_thread(std::string_view call) const;
  Result<const Entry*> lookup(PdoKey key) const;
  Result<const Entry*> lookup(PdoHandle handle) const;
  Result<void> write_entry(const Entry& e, wire::Bytes data);
  Result<void> write_bits_entry(const Entry& e, std::size_t bit_offset, std::size_t bit_length,
                                std::uint64_t value);
  Result<SampleInfo> sample_entry(const Entry& e, wire::MutableBytes out, bool fail_stale) const;
  Result<void> check_fresh(const Entry& e, std::int64_t refreshed, std::uint64_t fresh_until) const;
  // The field's refusal when it is not this domain's or not of `direction` (cold).
  Error field_refused(const Field& field, PdoDirection direction) const;
  // read_fresh(Field)'s verdict when the TSC stamp did not prove the copy fresh (cold).
  Result<void> fresh_by_clock(const Entry& e, std::int64_t refreshed) const;
  Result<void> build_exchanges_locked();
  std::vector<DomainDatagram> plan_locked() const;

  void lock_staging() const noexcept;
  void unlock_staging() const noexcept;

  // Bus thread.
  void on_exchange_done(Exchange& x) noexcept;
  void classify_valid(Exchange& x, Clock::time_point now) noexcept;
  void classify_invalid(std::uint64_t cycle, CycleInvalid invalid, Clock::time_point now) noexcept;
  void publish_inputs(std::uint64_t cycle, Clock::time_point now) noexcept;
  void record_latency(std::int64_t ns) noexcept;
  bool push_change(const InputChange& change) noexcept;
  bool pop_change(InputChange& out) noexcept;
  std::uint64_t take_dropped_changes() noexcept;

  bus::Bus& bus_;
  const DomainConfig config_;
  std::atomic<DomainObserver*> observer_;
  std::atomic<DomainState> state_{DomainState::open};
  std::atomic<std::uint64_t> refused_transitions_{0};  // undrawn changes asked for
  std::atomic<std::int64_t> period_ns_;

  mutable std::mutex control_mutex_;  // control plane only
  mutable std::mutex drain_mutex_;

  // Registrations: blocks of kEntryBlock entries that never move once allocated, published by
  // count (entries [0, count) are immutable but for their atomics). A block's pointer is stored
  // before the count that makes its first entry visible, so a reader that saw the count sees it.
  static constexpr std::uint32_t kEntryBlock = 256;
  Entry& entry(std::uint32_t i) const noexcept;
  // Makes room for entry `count` (a new block when needed); control thread, under control_mutex_.
  void reserve_entry_locked(std::uint32_t count);
  // Makes the image hold `bytes` (staging and input words grow, never beyond image_limit_);
  // control thread, under control_mutex_, while open.
  void reserve_image_locked(std::size_t bytes);
  // What the limits are called in errors: the configured field, or the built-in ceiling.
  std::string_view registration_limit_name() const noexcept;
  std::string_view image_limit_name() const noexcept;
  std::size_t registration_limit_;  // max_registrations, or kMaxRegistrations
  std::size_t image_limit_;         // max_image_size, or kAutoImageLimit
  std::unique_ptr<std::atomic<Entry*>[]> entry_blocks_;
  std::vector<std::unique_ptr<Entry[]>> entry_storage_;  // owns the blocks (control thread)
  std::atomic<std::uint32_t> entry_count_{0};
  std::uint32_t image_size_ = 0;    // control thread (under control_mutex_)
  std::size_t image_capacity_ = 0;  // bytes staging_ and input_words_ hold (control thread)
  std::vector<std::uint16_t> wkc_override_;

  // Reservations: made while open (control thread), never moved; their states and per-datagram
  // shares are atomics the bus thread reads.
  std::array<std::unique_ptr<Reservation>, kMaxReservations> reservations_;  // null until made
  std::atomic<std::uint32_t> reservation_count_{0};
  std::atomic<std::uint64_t> reservations_lost_{0};
  std::atomic<std::uint64_t> refused_reservation_transitions_{0};
  Reservation* reservation_of_locked(std::uint16_t station) const noexcept;
  Result<void> check_new_registration_locked(PdoKey key, std::size_t bytes,
                                             PdoDirection direction) const;
  Result<std::uint32_t> register_reserved_locked(Reservation& r, PdoKey key, std::size_t bytes,
                                                 PdoDirection direction, bool contributes_wkc);
  void compute_shares_locked(Reservation& r);
  bool reservation_absent(const Entry& e) const noexcept;

  // Outputs: staging image under a writer spinlock (replaced, grown, only under it too).
  mutable std::atomic<bool> staging_lock_{false};
  std::unique_ptr<std::uint8_t[]> staging_;
  std::uint64_t staging_version_ = 0;  // under staging_lock_

  // Inputs: seqlocked words, single writer (bus thread).
  std::atomic<std::uint64_t> input_seq_{0};
  // Read through input_words_ (lock-free readers); a grown array replaces it while the domain is
  // open, and the arrays it replaced stay alive until the domain goes (a reader may still hold
  // one: all zeros, as nothing was published yet).
  std::atomic<std::atomic<std::uint64_t>*> input_words_{nullptr};
  std::vector<std::unique_ptr<std::atomic<std::uint64_t>[]>> input_storage_;
  std::atomic<std::int64_t> refreshed_ns_{0};  // 0: never
  // Published with refreshed_ns_: the TSC count below which that cycle is certainly younger than
  // stale_after() (src/master/tsc_clock.hpp); 0: none, a freshness check reads the clock.
  std::atomic<std::uint64_t> fresh_until_tsc_{0};

  // Frozen at the first start_cycling.
  std::unique_ptr<Plan> plan_;
  std::atomic<std::uint32_t> restart_generation_{0};

  // Change records: SPSC ring (producer bus thread, consumer drain_changes).
  std::unique_ptr<InputChange[]> changes_;
  std::size_t change_mask_ = 0;
  std::atomic<std::uint64_t> change_head_{0};  // next to write (producer)
  std::atomic<std::uint64_t> change_tail_{0};  // next to read (consumer)
  std::atomic<std::uint64_t> changes_dropped_{0};
  std::uint64_t changes_dropped_reported_ = 0;  // under drain_mutex_

  // Statistics (written by the bus thread, read anywhere).
  struct Counters;
  std::unique_ptr<Counters> counters_;

  // await_next_cycle: valid cycles completed (a futex word) and the threads waiting on it.
  void announce_valid_cycle(std::uint64_t cycle) noexcept;
  std::atomic<std::uint32_t> valid_cycle_seq_{0};
  std::atomic<std::uint32_t> cycle_waiters_{0};
  std::atomic<std::uint64_t> last_valid_cycle_{0};
};

std::string_view to_string(Domain::ReservationState state) noexcept;

}  // namespace ecat::master
