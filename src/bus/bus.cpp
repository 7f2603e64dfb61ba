// The bus thread's loop, in order, every turn:
//   take new submissions -> give up on overdue frames and transactions -> run the cycle function
//   when its deadline has come -> send realtime work -> send reliable frames (re-checking for
//   realtime work before each) -> wait in Link::receive() until the next deadline or a frame
//   arrives, and match it.
// Everything below `// bus thread` is touched by the bus thread only; the cross-thread pieces are
// the two submission queues, the cycle slot and the published counters.

#include <algorithm>
#include <array>
#include <atomic>
#include <cassert>
#include <condition_variable>
#include <exception>
#include <limits>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <pthread.h>

#include <ecat/bus/bus.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::bus {

using std::chrono::nanoseconds;
using namespace std::chrono_literals;

namespace {

constexpr std::size_t kIndexCount = 256;
// The frame header's 11-bit length caps the datagram chain whatever the link carries.
constexpr std::size_t kLargestFrame = wire::kFrameHeaderSize + wire::kMaxDatagramLength;
constexpr std::size_t kMaxDatagramsPerFrame =
    (kLargestFrame - wire::kFrameHeaderSize) / wire::kDatagramOverhead + 1;
constexpr int kMaxConsecutiveLinkErrors = 3;
constexpr nanoseconds kIdleWait = 100ms;
constexpr nanoseconds kDeadLinkPoll = 1ms;
// Frames taken from the link in one pass before timeouts are checked: more than can be in flight
// (256 indices), so a backlog of replies is never cut short, yet a flood cannot hold the thread.
constexpr std::size_t kMaxArrivedPerPass = 512;
// transact() waits this much past the transaction's own timeout before calling the bus broken.
constexpr nanoseconds kTransactGrace = 1s;

std::string format_duration(nanoseconds d) {
  const auto ns = d.count();
  if (ns % 1'000'000 == 0) return fmt::format("{} ms", ns / 1'000'000);
  if (ns % 1'000 == 0) return fmt::format("{} us", ns / 1'000);
  return fmt::format("{} ns", ns);
}

// now + d, clamped instead of overflowing for huge timeouts.
Clock::time_point saturating_add(Clock::time_point t, nanoseconds d) {
  if (d > Clock::time_point::max() - t) return Clock::time_point::max();
  return t + d;
}

std::int64_t to_ns(Clock::time_point t) {
  return std::chrono::duration_cast<nanoseconds>(t.time_since_epoch()).count();
}

bool address_matches(wire::Command command, std::uint32_t sent, std::uint32_t received) {
  switch (wire::addressing_of(command)) {
    case wire::Addressing::position:
    case wire::Addressing::broadcast:
      // Every slave a position or broadcast datagram passes increments ADP: only ADO survives.
      return (sent >> 16) == (received >> 16);
    default:
      return sent == received;
  }
}

// Frames needed to send `tx` alone, packed in order into frames of `max_frame` bytes.
std::size_t frames_for(const Transaction& tx, std::size_t max_frame) {
  std::size_t frames = 0;
  std::size_t used = max_frame;  // forces a first frame
  for (const auto& d : tx.datagrams()) {
    const std::size_t need = wire::FrameBuilder::footprint(d.length);
    if (used + need > max_frame) {
      ++frames;
      used = wire::kFrameHeaderSize;
    }
    used += need;
  }
  return frames;
}

std::string summary(const Transaction& tx) {
  if (tx.empty()) return "empty transaction";
  const std::string first = describe(tx.datagrams()[0]);
  if (tx.size() == 1) return first;
  return fmt::format("transaction of {} datagrams (first {})", tx.size(), first);
}

// Intrusive doubly linked list; the bus thread's queues never allocate.
template <class T, T* T::*Prev, T* T::*Next>
class List {
 public:
  bool empty() const noexcept { return head_ == nullptr; }
  std::size_t size() const noexcept { return size_; }
  T* front() const noexcept { return head_; }
  static T* next(T* x) noexcept { return x->*Next; }
  void push_back(T* x) noexcept {
    x->*Prev = tail_;
    x->*Next = nullptr;
    if (tail_)
      tail_->*Next = x;
    else
      head_ = x;
    tail_ = x;
    ++size_;
  }
  void push_front(T* x) noexcept {
    x->*Prev = nullptr;
    x->*Next = head_;
    if (head_)
      head_->*Prev = x;
    else
      tail_ = x;
    head_ = x;
    ++size_;
  }
  void erase(T* x) noexcept {
    if (x->*Prev)
      (x->*Prev)->*Next = x->*Next;
    else
      head_ = x->*Next;
    if (x->*Next)
      (x->*Next)->*Prev = x->*Prev;
    else
      tail_ = x->*Prev;
    x->*Prev = x->*Next = nullptr;
    --size_;
  }
  // Moves all of `other` to the back of this list.
  void splice_back(List& other) noexcept {
    if (other.empty()) return;
    if (tail_) {
      tail_->*Next = other.head_;
      other.head_->*Prev = tail_;
    } else {
      head_ = other.head_;
    }
    tail_ = other.tail_;
    size_ += other.size_;
    other.head_ = other.tail_ = nullptr;
    other.size_ = 0;
  }

 private:
  T* head_ = nullptr;
  T* tail_ = nullptr;
  std::size_t size_ = 0;
};

// Singly linked FIFO of realtime transactions through their next_active_ field.
struct RtQueue {
  RealtimeTransaction* head = nullptr;
  RealtimeTransaction* tail = nullptr;
  std::size_t size = 0;
};

struct Counter {
  std::atomic<std::uint64_t> value{0};
  void add(std::uint64_t n = 1) noexcept { value.fetch_add(n, std::memory_order_relaxed); }
  std::uint64_t get() const noexcept { return value.load(std::memory_order_relaxed); }
};

}  // namespace

// Field order follows the roles below, not the smallest padding: there is one Impl per bus.
struct Bus::Impl {  // NOLINT(clang-analyzer-optin.performance.Padding)
  // A reliable transaction from acceptance to completion. Allocated by the submitting thread,
  // owned by the bus thread from then on.
  struct Pending {
    Transaction tx;
    TransactOptions options;
    Completion completion;
    std::vector<std::uint8_t> reply_data;
    std::vector<TransactionResult::Entry> entries;
    std::vector<std::uint8_t> sent_index;
    Clock::time_point submitted_at;
    Clock::time_point deadline;
    std::size_t next_to_send = 0;
    std::size_t outstanding = 0;  // datagrams in frames in flight
    unsigned retries_left = 0;
    bool lost = false;      // a frame of the current attempt got no reply
    bool finished = false;  // completion already called
    bool in_fifo = false;
    std::size_t lost_slot = 0;
    std::uint8_t lost_index = 0;
    Pending* queue_prev = nullptr;
    Pending* queue_next = nullptr;
    Pending* live_prev = nullptr;
    Pending* live_next = nullptr;
  };
  using Queue = List<Pending, &Pending::queue_prev, &Pending::queue_next>;
  using LiveList = List<Pending, &Pending::live_prev, &Pending::live_next>;

  enum class SlotState : std::uint8_t { free, in_flight, retired };
  enum class History : std::uint8_t { none, replied, lost };
  struct IndexSlot {
    SlotState state = SlotState::free;
    Pending* pending = nullptr;
    RealtimeTransaction* realtime = nullptr;
    std::uint32_t datagram = 0;  // slot in the owner's transaction
    std::uint16_t frame = 0;     // frames[] position
    wire::Command command = wire::Command::nop;
    std::uint32_t address = 0;
    std::uint16_t length = 0;
    Clock::time_point retired_until{};
    // What the frame this index last headed looked like, to tell late and duplicate replies
    // from stray frames.
    History history = History::none;
    wire::Command history_command = wire::Command::nop;
    std::uint16_t history_length = 0;
    std::uint16_t history_count = 0;
  };
  struct FrameSlot {
    bool used = false;
    bool realtime = false;
    Clock::time_point deadline{};
    std::uint16_t count = 0;
    std::array<std::uint8_t, kMaxDatagramsPerFrame> indices{};
  };
  // One owner's contiguous run of datagrams inside a frame.
  struct Run {
    Pending* pending = nullptr;
    RealtimeTransaction* realtime = nullptr;
  };

  enum class Phase : std::uint8_t { created, running, stopped };

  Impl(std::unique_ptr<link::Link> l, BusOptions o) : link(std::move(l)), options(std::move(o)) {
    link_name = link->name();
    max_frame = std::min(link->max_frame_size(), kLargestFrame);
    frame_timeout_ns.store(options.frame_timeout.count());
    reliable_timeout_ns.store(options.frame_timeout.count());
    send_buffer.assign(max_frame, 0);
    tell_link_budget();
  }

  // The link is told how long a reply may take (Link::set_frame_budget): the frame timeout, and
  // while a cycle runs no more than three periods of the fastest work it carries (the fastest
  // domain: set_fastest_work_period; the cycle's own period when not told). A redundant link
  // waits for a late side of the ring half the budget at most, counted once from the oldest frame
  // that side owes, so a cable cut delays the frames then in flight together by at most a period
  // and a half of the fastest domain, once: its exchanges in flight (three or more, as the
  // master's domains keep by default) absorb it and no cycle of it is lost. The cap is not the
  // base tick (with domains at 2 ms and 3 ms the cycle ticks at 1 ms): that would shorten the
  // wait below what any domain needs and hand every domain's frames on short of a side that is
  // merely late. A slower domain's frames get the same wait, never less than the fastest's, and
  // the bus's frame timeout still bounds them all. From the setters, never on the cycle path.
  void tell_link_budget() {
    std::lock_guard lock(budget_mutex);
    nanoseconds budget = frame_timeout();
    nanoseconds period(cycle_period_ns.load(std::memory_order_relaxed));
    const nanoseconds fastest(fastest_work_period_ns.load(std::memory_order_relaxed));
    if (period > nanoseconds(0) && fastest > nanoseconds(0)) period = fastest;
    if (period > nanoseconds(0)) budget = std::min(budget, 3 * period);
    link->set_frame_budget(budget);
  }

  // ---- configuration (fixed after construction)
  std::unique_ptr<link::Link> link;
  BusOptions options;
  std::string link_name;
  std::size_t max_frame = 0;
  std::size_t reliable_index_limit = kIndexCount;
  std::atomic<std::int64_t> frame_timeout_ns{0};
  std::atomic<std::int64_t> cycle_period_ns{0};         // 0 while no cycle is set
  std::atomic<std::int64_t> fastest_work_period_ns{0};  // set_fastest_work_period; 0: not told
  std::mutex budget_mutex;                              // tell_link_budget()
  std::atomic<std::int64_t> reliable_timeout_ns{0};     // >= frame_timeout_ns (adaptive)

  // ---- lifecycle
  std::mutex lifecycle_mutex;
  std::atomic<Phase> phase{Phase::created};
  std::thread thread;
  std::atomic<std::thread::id> thread_id{};
  std::atomic<bool> stop_requested{false};
  std::atomic<bool> sleeping{false};

  // ---- reliable submissions (any thread -> bus thread)
  // Transactions the bus thread finished with, linked through queue_next; freed by submitters.
  std::atomic<Pending*> graveyard{nullptr};
  std::atomic<std::size_t> graveyard_size{0};
  // Beyond this many the bus thread frees them itself: a chain of submissions made only from
  // completions on the bus thread has no other thread to free them, and the memory must stay
  // bounded (a rare free() there beats growing without end).
  static constexpr std::size_t kGraveyardBound = 1024;
  std::mutex incoming_mutex;
  Queue incoming;          // guarded by incoming_mutex
  bool accepting = false;  // guarded by incoming_mutex
  std::atomic<std::size_t> incoming_count{0};

  // ---- realtime submissions (any thread -> bus thread); never shares a lock with the above
  std::mutex rt_mutex;
  RtQueue rt_incoming;        // guarded by rt_mutex
  bool rt_accepting = false;  // guarded by rt_mutex
  std::atomic<std::size_t> rt_incoming_count{0};

  // ---- cycle
  struct Cycle {
    bool active = false;
    nanoseconds period{};
    CycleFunction function;
    Clock::time_point nominal{};  // next grid point, unsteered
    Clock::time_point next{};     // nominal + steering offset: when the bus thread runs it
    std::uint64_t count = 0;
  };
  std::mutex cycle_mutex;  // held by the bus thread while the cycle function runs
  Cycle cycle;             // guarded by cycle_mutex
  std::atomic<std::int64_t> cycle_next_ns{std::numeric_limits<std::int64_t>::max()};
  std::atomic<bool> cycle_changed{false};
  bool in_cycle_call = false;           // bus thread
  std::optional<Cycle> deferred_cycle;  // bus thread: set/clear from inside the cycle function

  // ---- cycle steering (see Bus::set_cycle_rate)
  std::atomic<std::int64_t> steer_rate_ppb{0};
  std::atomic<std::int64_t> steer_pending_ns{0};  // requested phase steps, not applied yet
  std::atomic<std::int64_t> steer_offset_ns{0};   // published offset (rounded)
  std::atomic<std::uint64_t> steer_steps{0};
  std::atomic<bool> steer_reset{false};
  double steer_offset_exact = 0.0;  // bus thread (and install_cycle under cycle_mutex)

  // ---- cycle trace (Bus::set_cycle_trace)
  std::atomic<CycleTrace*> trace_slot{nullptr};    // what the controller asks for
  std::atomic<CycleTrace*> trace_in_use{nullptr};  // what the bus thread uses (published first)
  CycleTrace* trace = nullptr;                     // bus thread: this loop turn's
  CycleTraceRecord trace_tick{};                   // bus thread: the tick being recorded
  bool trace_open = false;                         // bus thread: trace_tick holds a tick
  struct {
    std::int64_t entered = 0, until = 0, returned = 0;
    bool frame = false;
  } last_wait;  // bus thread, while tracing

  // ---- link failure
  std::atomic<bool> link_failed{false};
  mutable std::mutex failure_mutex;
  std::optional<Error> link_failure;       // guarded by failure_mutex
  std::optional<Error> last_reopen_error;  // guarded by failure_mutex
  std::atomic<std::uint64_t> link_failures{0}, link_reopens{0}, reopen_attempts{0};
  std::atomic<bool> link_reopenable{true};
  Clock::time_point next_reopen_at{};  // bus thread
  nanoseconds reopen_backoff{0};       // bus thread: the wait before the next attempt

  // ---- bus thread
  Queue fifo;  // reliable transactions with datagrams still to send, oldest first
  LiveList live;
  RtQueue rt_active;  // realtime transactions waiting to be sent
  std::array<IndexSlot, kIndexCount> indices{};
  std::uint8_t cursor = 0;
  std::size_t indices_in_flight = 0;
  std::size_t reliable_indices_in_flight = 0;
  std::size_t indices_retired = 0;
  std::vector<FrameSlot> frames;
  std::size_t reliable_frames_used = 0;
  std::size_t realtime_frames_used = 0;
  std::vector<std::uint8_t> send_buffer;
  Clock::time_point next_tx_deadline = Clock::time_point::max();
  int consecutive_send_errors = 0;
  int consecutive_receive_errors = 0;
  std::array<Run, kMaxDatagramsPerFrame> runs{};

  // ---- published for stats()/info()
  struct {
    Counter frames_sent, realtime_frames_sent, datagrams_sent, frames_received, frames_lost,
        transactions_completed, transactions_failed, transaction_timeouts, retries, wkc_mismatches,
        unmatched_replies, mismatched_replies, late_replies, duplicate_replies, decode_errors,
        realtime_completed, realtime_expired, realtime_timeouts, send_errors, receive_errors,
        callback_exceptions, cycles, cycle_deadlines_missed;
  } stats;
  std::atomic<std::size_t> pub_fifo{0}, pub_live{0}, pub_rt_active{0}, pub_frames{0},
      pub_rt_frames{0}, pub_datagrams{0};

  nanoseconds frame_timeout() const noexcept {
    return nanoseconds(frame_timeout_ns.load(std::memory_order_relaxed));
  }
  nanoseconds reliable_timeout() const noexcept {
    return nanoseconds(reliable_timeout_ns.load(std::memory_order_relaxed));
  }
  // A late reply: reliable frames get twice the time, up to the ceiling (BusOptions).
  void on_late_reply() noexcept {
    stats.late_replies.add();
    const std::int64_t limit = options.adaptive_frame_timeout_limit.count();
    const std::int64_t now = reliable_timeout_ns.load(std::memory_order_relaxed);
    if (limit <= now) return;
    const std::int64_t raised = now > limit / 2 ? limit : 2 * now;
    reliable_timeout_ns.store(raised, std::memory_order_relaxed);
  }

  bool on_bus_thread() const noexcept {
    return thread_id.load(std::memory_order_acquire) == std::this_thread::get_id();
  }

  // Wakes the bus thread if it is (about to be) blocked in receive(). Pairs with the
  // sleeping/queue-count check in wait_and_receive().
  void wake() {
    if (sleeping.exchange(false, std::memory_order_seq_cst)) link->interrupt();
  }

  Error not_running_error() const {
    if (phase.load() == Phase::created) {
      return Error(Errc::wrong_state, fmt::format("bus on link {} is not started", link_name));
    }
    return Error(Errc::closed, fmt::format("bus on link {} is stopped", link_name));
  }

  std::optional<Error> failure() const {
    std::lock_guard lock(failure_mutex);
    return link_failure;
  }

  Error link_failed_error(const std::string& what) const {
    auto cause = failure();
    if (!cause) return Error(Errc::io_error, fmt::format("{}: link {} failed", what, link_name));
    return cause->context(cause->code(), fmt::format("{}: link {} failed", what, link_name));
  }

  std::optional<Error> validate(const Transaction& tx, const char* kind) const {
    if (tx.error()) return *tx.error();
    if (tx.empty()) {
      return Error(Errc::invalid_argument,
                   fmt::format("empty {}: add at least one datagram", kind));
    }
    const auto datagrams = tx.datagrams();
    for (std::size_t slot = 0; slot < datagrams.size(); ++slot) {
      const std::size_t need = wire::FrameBuilder::footprint(datagrams[slot].length);
      if (wire::kFrameHeaderSize + need > max_frame) {
        return Error(Errc::invalid_argument,
                     fmt::format("datagram {} ({}) needs {} bytes, but frames on link {} hold "
                                 "at most {} bytes of datagrams",
                                 slot, describe(datagrams[slot]), need, link_name,
                                 max_frame - wire::kFrameHeaderSize));
      }
    }
    return std::nullopt;
  }

  // =============================================================================================
  // bus thread

  void publish() noexcept {
    pub_fifo.store(fifo.size(), std::memory_order_relaxed);
    pub_live.store(live.size(), std::memory_order_relaxed);
    pub_rt_active.store(rt_active.size, std::memory_order_relaxed);
    pub_frames.store(reliable_frames_used + realtime_frames_used, std::memory_order_relaxed);
    pub_rt_frames.store(realtime_frames_used, std::memory_order_relaxed);
    pub_datagrams.store(indices_in_flight, std::memory_order_relaxed);
  }

  void run() {
    thread_id.store(std::this_thread::get_id(), std::memory_order_release);
    if (options.on_thread_start) {
      try {
        options.on_thread_start();
      } catch (...) {
        stats.callback_exceptions.add();
      }
    }
    while (!stop_requested.load(std::memory_order_acquire)) {
      refresh_trace();
      Clock::time_point now = Clock::now();
      take_incoming();
      take_realtime();
      take_arrived_replies(now);
      check_frame_timeouts(now);
      check_transaction_deadlines(now);
      run_cycle(now);
      if (link_failed.load(std::memory_order_acquire)) {
        // The first reopen attempt comes before the work in flight is failed, so that whoever
        // watches the link (BusOptions::on_link_change) hears whether it can come back before
        // any failed request's news.
        if (!try_reopen(Clock::now())) {
          handle_link_failure();
          publish();
          // Nothing can be sent; new work fails promptly until the link is back (or the bus
          // stops).
          wait_while_dead();
          continue;
        }
      }
      send_all();
      publish();
      wait_and_receive();
      publish();
      if (trace_open) ++trace_tick.turns;
    }
    // The controller may be waiting for the bus thread to let go of its trace.
    trace = nullptr;
    trace_open = false;
    trace_in_use.store(nullptr, std::memory_order_seq_cst);
    shutdown();
    publish();
    // Thread ids are recycled: a later thread must not pass for this one.
    thread_id.store(std::thread::id(), std::memory_order_release);
  }

  // ---- cycle trace

  static std::int64_t now_ns() noexcept { return to_ns(Clock::now()); }

  // Takes the trace the controller asked for. The one in use is published before it is used, so
  // Bus::set_cycle_trace can wait until the previous one is let go.
  void refresh_trace() noexcept {
    CycleTrace* asked = trace_slot.load(std::memory_order_acquire);
    while (asked != trace) {
      trace_in_use.store(asked, std::memory_order_seq_cst);
      trace = asked;
      trace_open = false;
      last_wait = {};
      asked = trace_slot.load(std::memory_order_seq_cst);
    }
  }

  // Files the tick being recorded (if any) and starts recording `tick` (unless the trace is full).
  void trace_begin_tick(const CycleTick& tick, nanoseconds period) noexcept {
    const std::size_t n = trace->size_.load(std::memory_order_relaxed);
    if (trace_open && n < trace->records_.size()) {
      trace->records_[n] = trace_tick;
      trace->size_.store(n + 1, std::memory_order_release);
    }
    trace_open = trace->size_.load(std::memory_order_relaxed) < trace->records_.size();
    if (!trace_open) return;
    trace_tick = CycleTraceRecord{};
    trace_tick.cycle = tick.cycle;
    trace_tick.missed = tick.missed;
    trace_tick.due_ns =
        to_ns(tick.deadline) - static_cast<std::int64_t>(tick.missed) * period.count();
    trace_tick.wait_entered_ns = last_wait.entered;
    trace_tick.wait_until_ns = last_wait.until;
    trace_tick.wait_returned_ns = last_wait.returned;
    trace_tick.wait_got_frame = last_wait.frame;
    trace_tick.woke_ns = to_ns(tick.woke_at);
  }

  // Realtime work sent at or after the traced tick began is the tick's.
  bool traced_tick_owns(const RealtimeTransaction* rt) const noexcept {
    return trace_open && rt->sent_timestamp_ns_ >= trace_tick.woke_ns;
  }

  void take_incoming() {
    if (incoming_count.load(std::memory_order_acquire) == 0) return;
    Queue taken;
    {
      std::lock_guard lock(incoming_mutex);
      taken.splice_back(incoming);
      incoming_count.store(0, std::memory_order_release);
    }
    while (Pending* p = taken.front()) {
      taken.erase(p);
      live.push_back(p);
      fifo.push_back(p);
      p->in_fifo = true;
      next_tx_deadline = std::min(next_tx_deadline, p->deadline);
    }
  }

  void take_realtime() {
    if (rt_incoming_count.load(std::memory_order_acquire) == 0) return;
    RtQueue taken;
    {
      std::lock_guard lock(rt_mutex);
      taken = rt_incoming;
      rt_incoming = RtQueue{};
      rt_incoming_count.store(0, std::memory_order_release);
    }
    if (taken.head == nullptr) return;
    if (rt_active.tail) {
      rt_active.tail->next_active_ = taken.head;
    } else {
      rt_active.head = taken.head;
    }
    rt_active.tail = taken.tail;
    rt_active.size += taken.size;
  }

  // ---- index and frame tables

  std::size_t free_indices(Clock::time_point now) {
    std::size_t available = kIndexCount - indices_in_flight - indices_retired;
    if (indices_retired > 0) {
      for (auto& s : indices) {
        if (s.state == SlotState::retired && s.retired_until <= now) {
          s.state = SlotState::free;
          --indices_retired;
          ++available;
        }
      }
    }
    return available;
  }

  std::optional<std::uint8_t> allocate_index(Clock::time_point now) {
    // Round robin: a freed index is reused as late as possible, which keeps a straggling
    // duplicate from landing on a new datagram.
    for (std::size_t n = 0; n < kIndexCount; ++n) {
      const std::uint8_t i = cursor++;
      IndexSlot& s = indices[i];
      if (s.state == SlotState::retired && s.retired_until <= now) {
        s.state = SlotState::free;
        --indices_retired;
      }
      if (s.state == SlotState::free) return i;
    }
    return std::nullopt;
  }

  std::optional<std::size_t> allocate_frame(bool realtime) {
    const std::size_t reliable = options.max_reliable_frames_in_flight;
    const std::size_t begin = realtime ? reliable : 0;
    const std::size_t end = realtime ? frames.size() : reliable;
    for (std::size_t f = begin; f < end; ++f) {
      if (!frames[f].used) return f;
    }
    return std::nullopt;
  }

  std::size_t free_realtime_frames() const {
    return options.max_realtime_frames_in_flight - realtime_frames_used;
  }

  Clock::time_point earliest_retirement_end() const {
    auto t = Clock::time_point::max();
    for (const auto& s : indices) {
      if (s.state == SlotState::retired) t = std::min(t, s.retired_until);
    }
    return t;
  }

  // Records `index` as carrying datagram `slot` of its owner in frame `f`.
  void claim_index(std::uint8_t index, std::size_t f, const DatagramRequest& d, std::size_t slot,
                   Pending* p, RealtimeTransaction* rt) {
    IndexSlot& s = indices[index];
    s.state = SlotState::in_flight;
    s.pending = p;
    s.realtime = rt;
    s.datagram = static_cast<std::uint32_t>(slot);
    s.frame = static_cast<std::uint16_t>(f);
    s.command = d.command;
    s.address = d.address;
    s.length = d.length;
    ++indices_in_flight;
    if (p) ++reliable_indices_in_flight;
    FrameSlot& frame = frames[f];
    frame.indices[frame.count++] = index;
  }

  void release_index(std::uint8_t index) {
    IndexSlot& s = indices[index];
    if (s.pending) --reliable_indices_in_flight;
    --indices_in_flight;
    s.pending = nullptr;
    s.realtime = nullptr;
  }

  // Gathers the owners of frame `f`'s datagrams as runs, in frame order.
  std::size_t collect_runs(const FrameSlot& frame) {
    std::size_t n = 0;
    for (std::size_t k = 0; k < frame.count; ++k) {
      const IndexSlot& s = indices[frame.indices[k]];
      if (n > 0 && runs[n - 1].pending == s.pending && runs[n - 1].realtime == s.realtime) continue;
      runs[n++] = Run{s.pending, s.realtime};
    }
    return n;
  }

  void release_frame(std::size_t f) {
    FrameSlot& frame = frames[f];
    frame.used = false;
    frame.count = 0;
    if (frame.realtime) {
      --realtime_frames_used;
    } else {
      --reliable_frames_used;
    }
  }

  // ---- sending

  // Sends the frame being built in frames[f]; on failure gives its datagrams back to their owners
  // as failed. Returns whether the frame went out.
  bool send_frame(std::size_t f, wire::FrameBuilder& builder) {
    FrameSlot& frame = frames[f];
    const wire::Bytes bytes = builder.finish();
    auto sent = link->send(bytes);
    const Clock::time_point now = Clock::now();
    if (sent) {
      consecutive_send_errors = 0;
      frame.deadline = saturating_add(now, frame.realtime ? frame_timeout() : reliable_timeout());
      stats.frames_sent.add();
      if (frame.realtime) stats.realtime_frames_sent.add();
      stats.datagrams_sent.add(frame.count);
      return true;
    }
    stats.send_errors.add();
    const Error error = std::move(sent).error();
    const std::size_t n = collect_runs(frame);
    for (std::size_t k = 0; k < frame.count; ++k) {
      IndexSlot& s = indices[frame.indices[k]];
      s.state = SlotState::free;
      s.history = History::none;
      if (s.pending) --s.pending->outstanding;
      if (s.realtime) --s.realtime->outstanding_;
      release_index(frame.indices[k]);
    }
    release_frame(f);
    for (std::size_t r = 0; r < n; ++r) {
      if (Pending* p = runs[r].pending) {
        fail_pending(
            p, error.context(error.code(), fmt::format("{}: sending a frame on link {} failed",
                                                       summary(p->tx), link_name)));
        maybe_destroy(p);
      } else if (RealtimeTransaction* rt = runs[r].realtime) {
        if (!rt->link_error_) rt->link_error_ = error;
        rt->lost_ = true;
        rt->next_to_send_ = rt->size();
        if (rt->outstanding_ == 0) finish_realtime(rt, now);
      }
    }
    if (error.code() == Errc::closed || ++consecutive_send_errors >= kMaxConsecutiveLinkErrors) {
      declare_link_failure(
          error.context(error.code(), fmt::format("sending on link {} failed", link_name)));
    }
    return false;
  }

  void send_all() {
    for (;;) {
      if (link_failed.load(std::memory_order_relaxed)) return;
      take_realtime();
      send_realtime();
      if (!send_reliable_frame()) return;
    }
  }

  void send_realtime() {
    RealtimeTransaction* prev = nullptr;
    RealtimeTransaction* rt = rt_active.head;
    while (rt != nullptr) {
      RealtimeTransaction* next = rt->next_active_;
      const Clock::time_point now = Clock::now();
      const bool expired = now > rt->stale_at_;
      const bool sendable = !expired && rt->frames_needed_ <= free_realtime_frames() &&
                            rt->size() <= free_indices(now);
      if (!expired && !sendable) {
        prev = rt;
        rt = next;
        continue;
      }
      // Unlink first: once completed, its owner may resubmit or destroy it.
      if (prev) {
        prev->next_active_ = next;
      } else {
        rt_active.head = next;
      }
      if (rt_active.tail == rt) rt_active.tail = prev;
      --rt_active.size;
      rt->next_active_ = nullptr;
      if (expired) {
        stats.realtime_expired.add();
        complete_realtime(rt, RealtimeStatus::expired);
      } else {
        send_realtime_frames(rt, now);
      }
      rt = next;
      if (link_failed.load(std::memory_order_relaxed)) return;
    }
  }

  // Sends every datagram of `rt` in frames of its own. Enough frame slots and indices were
  // checked by the caller.
  void send_realtime_frames(RealtimeTransaction* rt, Clock::time_point now) {
    rt->stage_.store(RealtimeTransaction::Stage::in_flight, std::memory_order_release);
    rt->frame_timeout_ = frame_timeout();
    rt->sent_timestamp_ns_ = to_ns(now);
    const auto datagrams = rt->layout_.datagrams();
    wire::FrameBuilder builder(wire::MutableBytes{send_buffer.data(), max_frame});
    std::optional<std::size_t> f;
    while (rt->next_to_send_ < datagrams.size()) {
      const std::size_t slot = rt->next_to_send_;
      const DatagramRequest& d = datagrams[slot];
      if (f && !builder.fits(d.length)) {
        const std::size_t sent_frame = *f;
        f.reset();
        if (!send_frame(sent_frame, builder)) return;  // rt already handed its failure
      }
      if (!f) {
        f = allocate_frame(true);
        assert(f);
        frames[*f].used = true;
        frames[*f].realtime = true;
        ++realtime_frames_used;
        builder.reset();
      }
      const auto index = allocate_index(now);
      assert(index);
      builder.add(wire::DatagramHeader{d.command, *index, d.address, d.length, false, false, 0},
                  rt->layout_.data(slot));
      claim_index(*index, *f, d, slot, nullptr, rt);
      rt->sent_index_[slot] = *index;
      ++rt->next_to_send_;
      ++rt->outstanding_;
    }
    if (f) (void)send_frame(*f, builder);
    if (trace_open) trace_tick.sent_ns = now_ns();
  }

  // Builds and sends one frame of reliable datagrams, oldest transactions first. Returns false
  // when nothing could be sent.
  bool send_reliable_frame() {
    if (fifo.empty() || reliable_frames_used >= options.max_reliable_frames_in_flight) {
      return false;
    }
    const Clock::time_point now = Clock::now();
    const auto f = allocate_frame(false);
    if (!f) return false;
    FrameSlot& frame = frames[*f];
    frame.used = true;
    frame.realtime = false;
    frame.count = 0;
    ++reliable_frames_used;
    wire::FrameBuilder builder(wire::MutableBytes{send_buffer.data(), max_frame});

    bool full = false;
    Pending* p = fifo.front();
    while (p != nullptr && !full) {
      Pending* next = Queue::next(p);
      // A transaction that fits a frame of its own is not split across two just to fill this one.
      if (p->next_to_send == 0 && !builder.empty()) {
        const std::size_t need = p->tx.wire_size();
        if (need > max_frame - builder.size() && need <= max_frame - wire::kFrameHeaderSize) break;
      }
      const auto datagrams = p->tx.datagrams();
      while (p->next_to_send < datagrams.size()) {
        const std::size_t slot = p->next_to_send;
        const DatagramRequest& d = datagrams[slot];
        if (!builder.fits(d.length) || builder.datagram_count() >= kMaxDatagramsPerFrame ||
            reliable_indices_in_flight >= reliable_index_limit) {
          full = true;
          break;
        }
        const auto index = allocate_index(now);
        if (!index) {
          full = true;
          break;
        }
        builder.add(wire::DatagramHeader{d.command, *index, d.address, d.length, false, false, 0},
                    p->tx.data(slot));
        claim_index(*index, *f, d, slot, p, nullptr);
        p->sent_index[slot] = *index;
        ++p->next_to_send;
        ++p->outstanding;
      }
      if (p->next_to_send == datagrams.size()) {
        fifo.erase(p);
        p->in_fifo = false;
      }
      p = next;
    }
    if (builder.empty()) {
      release_frame(*f);
      return false;
    }
    send_frame(*f, builder);
    return true;
  }

  // ---- receiving

  void wait_and_receive() {
    const Clock::time_point now = Clock::now();
    Clock::time_point until = now + kIdleWait;
    for (const auto& frame : frames) {
      if (frame.used) until = std::min(until, frame.deadline);
    }
    if (!live.empty()) until = std::min(until, next_tx_deadline);
    bool waiting_for_indices = !fifo.empty() && reliable_frames_used == 0;
    for (auto* rt = rt_active.head; rt != nullptr; rt = rt->next_active_) {
      until = std::min(until, saturating_add(rt->stale_at_, 1ns));
      waiting_for_indices = true;
    }
    if (waiting_for_indices && indices_retired > 0) {
      until = std::min(until, earliest_retirement_end());
    }
    const std::int64_t cycle_at = cycle_next_ns.load(std::memory_order_acquire);
    if (cycle_at != std::numeric_limits<std::int64_t>::max()) {
      until = std::min(until, Clock::time_point(nanoseconds(cycle_at)));
    }
    nanoseconds timeout = std::max(nanoseconds(0), until - now);

    sleeping.store(true, std::memory_order_seq_cst);
    if (incoming_count.load(std::memory_order_seq_cst) > 0 ||
        rt_incoming_count.load(std::memory_order_seq_cst) > 0 ||
        stop_requested.load(std::memory_order_seq_cst) ||
        cycle_changed.load(std::memory_order_seq_cst)) {
      timeout = nanoseconds(0);
    }
    if (trace) {
      last_wait.entered = now_ns();
      last_wait.until = std::min(to_ns(until), to_ns(now) + timeout.count());
    }
    auto received = link->receive(timeout);
    if (trace) {
      last_wait.returned = now_ns();
      last_wait.frame = received && received.value();
    }
    sleeping.store(false, std::memory_order_seq_cst);
    cycle_changed.store(false, std::memory_order_relaxed);
    if (!received) {
      stats.receive_errors.add();
      const Error& error = received.error();
      if (error.code() == Errc::closed ||
          ++consecutive_receive_errors >= kMaxConsecutiveLinkErrors) {
        declare_link_failure(
            error.context(error.code(), fmt::format("receiving on link {} failed", link_name)));
      }
      return;
    }
    consecutive_receive_errors = 0;
    if (received.value()) on_frame(*received.value());
  }

  void on_frame(const link::ReceivedFrame& received) {
    stats.frames_received.add();
    const auto decoded = wire::decode_frame(received.frame);
    if (!decoded) {
      stats.decode_errors.add();
      return;
    }
    const wire::FrameView& view = *decoded.frame;
    const wire::DatagramView first = *view.begin();
    const IndexSlot& head = indices[first.header.index];
    if (head.state != SlotState::in_flight) {
      classify_stray(view, first);
      return;
    }
    const std::size_t f = head.frame;
    FrameSlot& frame = frames[f];
    if (view.datagram_count() != frame.count) {
      stats.mismatched_replies.add();
      return;
    }
    std::size_t k = 0;
    for (const wire::DatagramView d : view) {
      const std::uint8_t index = frame.indices[k++];
      const IndexSlot& s = indices[index];
      if (d.header.index != index || d.header.command != s.command || d.header.length != s.length ||
          !address_matches(s.command, s.address, d.header.address)) {
        stats.mismatched_replies.add();
        return;
      }
    }

    // The reply is this frame's: hand every datagram to its owner.
    const Clock::time_point now = Clock::now();
    const std::size_t n = collect_runs(frame);
    bool late = false;
    k = 0;
    for (const wire::DatagramView d : view) {
      const std::uint8_t index = frame.indices[k];
      IndexSlot& s = indices[index];
      if (Pending* p = s.pending) {
        if (p->finished) {
          late = true;
        } else {
          auto& e = p->entries[s.datagram];
          std::copy(d.data.begin(), d.data.end(), p->reply_data.begin() + e.offset);
          e.wkc = d.wkc;
          e.irq = d.header.irq;
          e.circulating = d.header.circulating;
        }
        --p->outstanding;
      } else if (RealtimeTransaction* rt = s.realtime) {
        const auto& request = rt->layout_.datagrams()[s.datagram];
        std::copy(d.data.begin(), d.data.end(), rt->input_.begin() + request.data_offset);
        auto& reply = rt->replies_[s.datagram];
        reply.wkc = d.wkc;
        reply.irq = d.header.irq;
        reply.circulating = d.header.circulating;
        rt->reply_timestamp_ns_ = received.timestamp_ns;
        --rt->outstanding_;
        if (trace_tick.reply_ns == 0 && traced_tick_owns(rt)) trace_tick.reply_ns = to_ns(now);
      }
      s.state = SlotState::free;
      if (k == 0) {
        s.history = History::replied;
        s.history_command = first.header.command;
        s.history_length = first.header.length;
        s.history_count = frame.count;
      } else {
        s.history = History::none;
      }
      release_index(index);
      ++k;
    }
    if (late) on_late_reply();
    release_frame(f);
    for (std::size_t r = 0; r < n; ++r)
      resolve(runs[r], now);
  }

  void classify_stray(const wire::FrameView& view, const wire::DatagramView& first) {
    const IndexSlot& s = indices[first.header.index];
    const bool same_frame =
        s.history != History::none && s.history_command == first.header.command &&
        s.history_length == first.header.length && s.history_count == view.datagram_count();
    if (same_frame && s.history == History::replied) {
      stats.duplicate_replies.add();
    } else if (same_frame && s.history == History::lost) {
      on_late_reply();
    } else {
      stats.unmatched_replies.add();
    }
  }

  // ---- timeouts

  // A reply that arrived while this thread was off the processor (descheduled between two
  // receives on a loaded machine) is late, not lost: before any frame is declared lost, every
  // frame already waiting on the link is taken. Errors are left to wait_and_receive, which meets
  // them again.
  void take_arrived_replies(Clock::time_point now) {
    bool overdue = false;
    for (const FrameSlot& frame : frames)
      overdue = overdue || (frame.used && frame.deadline <= now);
    if (!overdue) return;
    for (std::size_t n = 0; n < kMaxArrivedPerPass; ++n) {
      auto received = link->receive(nanoseconds(0));
      if (!received || !received.value()) return;
      on_frame(*received.value());
    }
  }

  void check_frame_timeouts(Clock::time_point now) {
    for (std::size_t f = 0; f < frames.size(); ++f) {
      FrameSlot& frame = frames[f];
      if (!frame.used || frame.deadline > now) continue;
      stats.frames_lost.add();
      const nanoseconds timeout = frame.realtime ? frame_timeout() : reliable_timeout();
      const nanoseconds quarantine = options.late_reply_quarantine > nanoseconds(0)
                                         ? options.late_reply_quarantine
                                     : timeout > nanoseconds::max() / 4 ? nanoseconds::max()
                                                                        : 4 * timeout;
      const std::size_t n = collect_runs(frame);
      for (std::size_t k = 0; k < frame.count; ++k) {
        const std::uint8_t index = frame.indices[k];
        IndexSlot& s = indices[index];
        if (Pending* p = s.pending) {
          if (!p->lost) {
            p->lost = true;
            p->lost_slot = s.datagram;
            p->lost_index = index;
          }
          if (p->in_fifo) {
            fifo.erase(p);
            p->in_fifo = false;
          }
          --p->outstanding;
        } else if (RealtimeTransaction* rt = s.realtime) {
          if (!rt->lost_) {
            rt->lost_ = true;
            rt->failed_slot_ = s.datagram;
            rt->failed_index_ = index;
          }
          --rt->outstanding_;
        }
        s.state = SlotState::retired;
        s.retired_until = saturating_add(now, quarantine);
        if (k == 0) {
          s.history = History::lost;
          s.history_command = s.command;
          s.history_length = s.length;
          s.history_count = frame.count;
        } else {
          s.history = History::none;
        }
        release_index(index);
        ++indices_retired;
      }
      release_frame(f);
      for (std::size_t r = 0; r < n; ++r)
        resolve(runs[r], now);
    }
  }

  void check_transaction_deadlines(Clock::time_point now) {
    if (now < next_tx_deadline) return;
    next_tx_deadline = Clock::time_point::max();
    Pending* p = live.front();
    while (p != nullptr) {
      Pending* next = LiveList::next(p);
      if (!p->finished) {
        if (p->deadline <= now) {
          stats.transaction_timeouts.add();
          fail_pending(p, Error(Errc::timeout, timeout_message(*p)));
          maybe_destroy(p);
        } else {
          next_tx_deadline = std::min(next_tx_deadline, p->deadline);
        }
      }
      p = next;
    }
  }

  std::string timeout_message(const Pending& p) const {
    std::string state;
    const unsigned used = p.options.retries - p.retries_left;
    if (p.lost || used > 0) {
      state = fmt::format("lost a frame (datagram {}: {}, index 0x{:02x}) and retried {} time{}",
                          p.lost_slot, describe(p.tx.datagrams()[p.lost_slot]), p.lost_index, used,
                          used == 1 ? "" : "s");
    } else if (p.next_to_send == 0 && p.outstanding == 0) {
      state = "still queued behind other work";
    } else {
      state = fmt::format("{} of {} datagrams sent, {} awaiting replies", p.next_to_send,
                          p.tx.size(), p.outstanding);
    }
    return fmt::format("{} timed out after {} on link {}: {}", summary(p.tx),
                       format_duration(p.options.timeout), link_name, state);
  }

  // ---- completion

  void resolve(const Run& run, Clock::time_point now) {
    if (run.pending) resolve_pending(run.pending, now);
    if (run.realtime && run.realtime->outstanding_ == 0 &&
        run.realtime->next_to_send_ >= run.realtime->size()) {
      finish_realtime(run.realtime, now);
    }
  }

  void resolve_pending(Pending* p, Clock::time_point now) {
    if (p->outstanding > 0) return;
    if (p->finished) {
      maybe_destroy(p);
      return;
    }
    if (p->lost) {
      if (p->retries_left > 0 && now < p->deadline) {
        --p->retries_left;
        stats.retries.add();
        p->lost = false;
        p->next_to_send = 0;
        fifo.push_front(p);
        p->in_fifo = true;
        return;
      }
      const auto& d = p->tx.datagrams()[p->lost_slot];
      std::string message = fmt::format(
          "no reply to the frame with {} (datagram {}, index 0x{:02x}) within {} on "
          "link {}",
          describe(d), p->lost_slot, p->lost_index, format_duration(frame_timeout()), link_name);
      if (p->options.retries > 0) {
        message += fmt::format("; gave up after {} retr{}", p->options.retries,
                               p->options.retries == 1 ? "y" : "ies");
      }
      if (p->tx.size() > 1) message = fmt::format("{}: {}", summary(p->tx), message);
      stats.transaction_timeouts.add();
      fail_pending(p, Error(Errc::timeout, std::move(message)));
      maybe_destroy(p);
      return;
    }
    if (p->next_to_send < p->tx.size()) return;  // more to send, still queued

    const auto datagrams = p->tx.datagrams();
    std::optional<Error> mismatch;
    for (std::size_t slot = 0; slot < datagrams.size(); ++slot) {
      const auto& expected = datagrams[slot].expected_wkc;
      const std::uint16_t actual = p->entries[slot].wkc;
      if (expected && *expected != actual) {
        stats.wkc_mismatches.add();
        if (!mismatch) {
          mismatch.emplace(
              Errc::wkc_mismatch,
              fmt::format("{} (datagram {}, index 0x{:02x}): working counter {}, "
                          "expected {}",
                          describe(datagrams[slot]), slot, p->sent_index[slot], actual, *expected));
        }
      }
    }
    if (mismatch) {
      fail_pending(p, std::move(*mismatch));
    } else {
      TransactionResult result;
      result.entries_ = std::move(p->entries);
      result.data_ = std::move(p->reply_data);
      p->finished = true;
      stats.transactions_completed.add();
      call(p->completion, Result<TransactionResult>(std::move(result)));
    }
    maybe_destroy(p);
  }

  void call(Completion& completion, Result<TransactionResult> result) {
    try {
      if (completion) completion(std::move(result));
    } catch (...) {
      stats.callback_exceptions.add();
    }
  }

  // Completes `p` with `error` now; its frames still in flight keep it alive until they resolve.
  void fail_pending(Pending* p, Error error) {
    if (p->finished) return;
    p->finished = true;
    if (p->in_fifo) {
      fifo.erase(p);
      p->in_fifo = false;
    }
    stats.transactions_failed.add();
    call(p->completion, Result<TransactionResult>(std::move(error)));
  }

  void maybe_destroy(Pending* p) {
    if (!p->finished || p->outstanding > 0) return;
    if (p->in_fifo) {
      fifo.erase(p);
      p->in_fifo = false;
    }
    live.erase(p);
    // The completion's captures go here, as they always did; the memory (the transaction's
    // buffers, the Pending itself) is freed by the next submitting thread: a free() here would
    // take the lock of the malloc arena the submitter allocated it from, which a thread of normal
    // priority may hold while preempted (priority inversion: milliseconds at SCHED_FIFO,
    // docs/BENCHMARKS.md "Cycle-start lateness").
    p->completion = nullptr;
    Pending* head = graveyard.load(std::memory_order_relaxed);
    do {
      p->queue_next = head;
    } while (!graveyard.compare_exchange_weak(head, p, std::memory_order_release,
                                              std::memory_order_relaxed));
    if (graveyard_size.fetch_add(1, std::memory_order_relaxed) + 1 > kGraveyardBound) {
      free_finished();
    }
  }

  // Frees what the bus thread finished with (any thread but the bus thread, or once it ended;
  // the bus thread only beyond kGraveyardBound).
  void free_finished() noexcept {
    Pending* p = graveyard.exchange(nullptr, std::memory_order_acquire);
    while (p != nullptr) {
      Pending* next = p->queue_next;
      delete p;
      graveyard_size.fetch_sub(1, std::memory_order_relaxed);
      p = next;
    }
  }

  void finish_realtime(RealtimeTransaction* rt, Clock::time_point now) {
    (void)now;
    RealtimeStatus status = RealtimeStatus::ok;
    if (rt->link_error_) {
      status = RealtimeStatus::link_error;
    } else if (rt->lost_) {
      status = RealtimeStatus::timeout;
      stats.realtime_timeouts.add();
    } else {
      const auto datagrams = rt->layout_.datagrams();
      for (std::size_t slot = 0; slot < datagrams.size(); ++slot) {
        const auto& expected = datagrams[slot].expected_wkc;
        if (expected && *expected != rt->replies_[slot].wkc) {
          stats.wkc_mismatches.add();
          if (status == RealtimeStatus::ok) {
            status = RealtimeStatus::wkc_mismatch;
            rt->failed_slot_ = slot;
            rt->failed_index_ = rt->sent_index_[slot];
            rt->failed_wkc_ = rt->replies_[slot].wkc;
          }
        }
      }
    }
    complete_realtime(rt, status);
  }

  // The last touch of `rt`: once its mutex is released its owner may destroy it.
  void complete_realtime(RealtimeTransaction* rt, RealtimeStatus status) {
    const bool traced = traced_tick_owns(rt);
    stats.realtime_completed.add();
    rt->status_.store(status, std::memory_order_release);
    if (rt->completion_) {
      try {
        rt->completion_(*rt);
      } catch (...) {
        stats.callback_exceptions.add();
      }
    }
    if (traced) trace_tick.completed_ns = now_ns();
    std::lock_guard lock(rt->wait_mutex_);
    rt->completions_.fetch_add(1, std::memory_order_release);
    rt->stage_.store(RealtimeTransaction::Stage::done, std::memory_order_release);
    rt->wait_cv_.notify_all();
  }

  // ---- failure and shutdown

  void declare_link_failure(Error error) {
    {
      std::lock_guard lock(failure_mutex);
      if (link_failure) return;
      link_failure = std::move(error);
    }
    link_failures.fetch_add(1, std::memory_order_relaxed);
    // The first attempt at once (a link that says it cannot be reopened is known at once), then
    // the backoff. The failure is announced with the first attempt's outcome.
    reopen_backoff = nanoseconds(0);
    next_reopen_at = Clock::now();
    failure_announced = false;
    link_failed.store(true, std::memory_order_release);
  }
  bool failure_announced = true;  // bus thread

  void notify_link_change() {
    if (!options.on_link_change) return;
    try {
      options.on_link_change();
    } catch (...) {
      stats.callback_exceptions.add();
    }
  }

  // While the link is failed: one attempt to reopen it when its time has come. True when the
  // link is back (work flows again from the next turn of the loop).
  bool try_reopen(Clock::time_point now) {
    if (!link_reopenable.load(std::memory_order_relaxed) || now < next_reopen_at) return false;
    reopen_attempts.fetch_add(1, std::memory_order_relaxed);
    auto reopened = link->reopen();
    const bool announce = !std::exchange(failure_announced, true);
    if (!reopened) {
      const Errc code = reopened.error().code();
      {
        std::lock_guard lock(failure_mutex);
        last_reopen_error = reopened.error();
      }
      if (code == Errc::unsupported || code == Errc::closed) {
        link_reopenable.store(false, std::memory_order_relaxed);
        notify_link_change();
        return false;
      }
      reopen_backoff = reopen_backoff == nanoseconds(0)
                           ? options.reopen_backoff_min
                           : std::min(reopen_backoff * 2, options.reopen_backoff_max);
      next_reopen_at = now + reopen_backoff;
      if (announce) notify_link_change();
      return false;
    }
    {
      std::lock_guard lock(failure_mutex);
      link_failure.reset();
      last_reopen_error.reset();
    }
    consecutive_send_errors = 0;
    consecutive_receive_errors = 0;
    link_reopens.fetch_add(1, std::memory_order_relaxed);
    link_failed.store(false, std::memory_order_release);
    notify_link_change();
    return true;
  }

  // Forgets every frame in flight: no reply will be matched any more. Owners lose their
  // outstanding datagrams; the caller completes them.
  void abandon_frames() {
    for (std::size_t f = 0; f < frames.size(); ++f) {
      FrameSlot& frame = frames[f];
      if (!frame.used) continue;
      for (std::size_t k = 0; k < frame.count; ++k) {
        IndexSlot& s = indices[frame.indices[k]];
        if (s.pending) --s.pending->outstanding;
        if (s.realtime) {
          RealtimeTransaction* rt = s.realtime;
          if (--rt->outstanding_ == 0) {
            rt->next_active_ = nullptr;
            abandoned_rt.push_back(rt);
          }
        }
        s.state = SlotState::free;
        s.history = History::none;
        release_index(frame.indices[k]);
      }
      release_frame(f);
    }
  }
  std::vector<RealtimeTransaction*> abandoned_rt;

  // Completes everything accepted so far: reliable work with an error made by `make_error`,
  // realtime work with `status` (and `cause` as its link error, when given).
  template <class MakeError>
  void complete_everything(MakeError make_error, RealtimeStatus status, const Error* cause) {
    abandon_frames();
    Pending* p = live.front();
    while (p != nullptr) {
      Pending* next = LiveList::next(p);
      fail_pending(p, make_error(*p));
      maybe_destroy(p);
      p = next;
    }
    RealtimeTransaction* queued = rt_active.head;
    rt_active = RtQueue{};
    for (RealtimeTransaction* rt = queued; rt != nullptr; rt = rt->next_active_) {
      abandoned_rt.push_back(rt);
    }
    for (RealtimeTransaction* rt : abandoned_rt) {
      rt->next_active_ = nullptr;
      if (cause && !rt->link_error_) rt->link_error_ = *cause;
      complete_realtime(rt, status);
    }
    abandoned_rt.clear();
  }

  void handle_link_failure() {
    if (live.empty() && rt_active.size == 0 && indices_in_flight == 0) return;
    const auto cause = failure();
    complete_everything([&](const Pending& p) { return link_failed_error(summary(p.tx)); },
                        RealtimeStatus::link_error, cause ? &*cause : nullptr);
  }

  void wait_while_dead() {
    if (incoming_count.load() == 0 && rt_incoming_count.load() == 0 && !stop_requested.load()) {
      std::this_thread::sleep_for(kDeadLinkPoll);  // short: new work is failed promptly
    }
  }

  void shutdown() {
    {
      std::lock_guard lock(incoming_mutex);
      accepting = false;
    }
    {
      std::lock_guard lock(rt_mutex);
      rt_accepting = false;
    }
    take_incoming();
    take_realtime();
    complete_everything(
        [&](const Pending& p) {
          return Error(Errc::closed, fmt::format("{}: bus on link {} stopped before it completed",
                                                 summary(p.tx), link_name));
        },
        RealtimeStatus::closed, nullptr);
  }

  // ---- cycle

  void run_cycle(Clock::time_point now) {
    if (cycle_next_ns.load(std::memory_order_acquire) > to_ns(now)) return;
    std::unique_lock lock(cycle_mutex);
    if (!cycle.active || cycle.next > now) return;
    const auto behind = (now - cycle.next) / cycle.period;  // whole periods missed
    CycleTick tick;
    tick.cycle = cycle.count;
    tick.deadline = cycle.next + behind * cycle.period;
    tick.nominal = cycle.nominal + behind * cycle.period;
    tick.woke_at = now;
    tick.missed = static_cast<std::uint64_t>(behind);
    if (trace) trace_begin_tick(tick, cycle.period);
    in_cycle_call = true;
    try {
      cycle.function(tick);
    } catch (...) {
      stats.callback_exceptions.add();
    }
    in_cycle_call = false;
    if (trace_open) trace_tick.participants_ns = now_ns();
    stats.cycles.add();
    stats.cycle_deadlines_missed.add(tick.missed);
    ++cycle.count;
    cycle.nominal = tick.nominal + cycle.period;
    cycle.next = cycle.nominal + steer(cycle.period);
    if (deferred_cycle) {
      cycle = std::move(*deferred_cycle);
      deferred_cycle.reset();
      cycle.next = cycle.nominal + current_offset();
    }
    cycle_next_ns.store(cycle.active ? to_ns(cycle.next) : std::numeric_limits<std::int64_t>::max(),
                        std::memory_order_release);
  }

  // Advances the steering by one tick of `period`; returns the offset for the next deadline.
  // Bus thread, under cycle_mutex.
  nanoseconds steer(nanoseconds period) {
    take_steering_reset();
    const std::int64_t ppb = steer_rate_ppb.load(std::memory_order_relaxed);
    if (ppb != 0) {
      steer_offset_exact += static_cast<double>(period.count()) * static_cast<double>(ppb) * 1e-9;
    }
    if (steer_pending_ns.load(std::memory_order_relaxed) != 0) {
      const std::int64_t requested = steer_pending_ns.exchange(0, std::memory_order_acq_rel);
      const std::int64_t limit = std::max<std::int64_t>(1, period.count() / 4);
      const std::int64_t applied = std::clamp(requested, -limit, limit);
      if (applied != requested) {
        steer_pending_ns.fetch_add(requested - applied, std::memory_order_acq_rel);
      }
      steer_offset_exact += static_cast<double>(applied);
      steer_steps.fetch_add(1, std::memory_order_relaxed);
    }
    const auto offset = static_cast<std::int64_t>(std::llround(steer_offset_exact));
    steer_offset_ns.store(offset, std::memory_order_relaxed);
    return nanoseconds(offset);
  }

  // The offset the next deadline gets without advancing the steering. Under cycle_mutex.
  nanoseconds current_offset() {
    take_steering_reset();
    return nanoseconds(static_cast<std::int64_t>(std::llround(steer_offset_exact)));
  }

  void take_steering_reset() {
    if (steer_reset.exchange(false, std::memory_order_acq_rel)) {
      steer_offset_exact = 0.0;
      steer_offset_ns.store(0, std::memory_order_relaxed);
    }
  }

  void install_cycle(Cycle next) {
    if (on_bus_thread() && in_cycle_call) {
      deferred_cycle = std::move(next);
      return;
    }
    Cycle old;
    {
      std::lock_guard lock(cycle_mutex);
      old = std::move(cycle);
      cycle = std::move(next);
      if (cycle.active) {
        // A steered cycle keeps its offset: the first deadline is the first steered grid point
        // still ahead (never a pause of the accumulated offset's length).
        const nanoseconds offset = current_offset();
        if (cycle.next == Clock::time_point{}) {
          const auto period = cycle.period;
          const auto now = Clock::now().time_since_epoch() - offset;
          cycle.nominal = Clock::time_point((now / period + 1) * period);
          cycle.next = cycle.nominal + offset;
        } else {
          cycle.nominal = cycle.next - offset;
        }
      }
      cycle_next_ns.store(
          cycle.active ? to_ns(cycle.next) : std::numeric_limits<std::int64_t>::max(),
          std::memory_order_release);
    }
    cycle_changed.store(true, std::memory_order_seq_cst);
    wake();
  }
};

// =============================================================================================

Bus::Bus(std::unique_ptr<link::Link> link, BusOptions options) {
  if (!link) {
    link_name_ = "(no link)";
    return;
  }
  impl_ = std::make_unique<Impl>(std::move(link), std::move(options));
  link_name_ = impl_->link_name;
  max_frame_size_ = impl_->max_frame;
}

Bus::~Bus() {
  if (!impl_) return;
  stop();
  impl_->link->close();
  impl_->free_finished();
}

Result<void> Bus::start() {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  auto& s = *impl_;
  std::lock_guard lock(s.lifecycle_mutex);
  if (s.phase.load() != Impl::Phase::created) {
    return Error(Errc::wrong_state, fmt::format("bus on link {} was already started", s.link_name));
  }
  const auto& o = s.options;
  if (o.frame_timeout <= nanoseconds(0)) {
    return Error(Errc::invalid_argument,
                 fmt::format("frame timeout must be positive, got {} ns", o.frame_timeout.count()));
  }
  if (o.max_reliable_frames_in_flight == 0 || o.max_realtime_frames_in_flight == 0 ||
      o.max_reliable_frames_in_flight + o.max_realtime_frames_in_flight > 1024) {
    return Error(Errc::invalid_argument,
                 fmt::format("frames in flight must be 1..1024 in total with at least one of each "
                             "class, got {} reliable and {} realtime",
                             o.max_reliable_frames_in_flight, o.max_realtime_frames_in_flight));
  }
  if (o.realtime_reserved_indices >= kIndexCount) {
    return Error(Errc::invalid_argument,
                 fmt::format("realtime_reserved_indices must be below {}, got {}", kIndexCount,
                             o.realtime_reserved_indices));
  }
  if (o.reopen_backoff_min <= nanoseconds(0) || o.reopen_backoff_max < o.reopen_backoff_min) {
    return Error(Errc::invalid_argument,
                 fmt::format("reopen backoff must be positive with min <= max, got {} ns .. {} ns",
                             o.reopen_backoff_min.count(), o.reopen_backoff_max.count()));
  }
  if (o.adaptive_frame_timeout_limit < nanoseconds(0)) {
    return Error(Errc::invalid_argument, "adaptive_frame_timeout_limit must not be negative");
  }
  if (o.late_reply_quarantine < nanoseconds(0)) {
    return Error(Errc::invalid_argument, "late_reply_quarantine must not be negative");
  }
  if (s.max_frame < wire::kFrameHeaderSize + wire::kDatagramOverhead) {
    return Error(Errc::invalid_argument,
                 fmt::format("link {} carries frames of at most {} bytes: too small for a datagram",
                             s.link_name, s.max_frame));
  }
  s.reliable_index_limit = kIndexCount - o.realtime_reserved_indices;
  s.frames.assign(o.max_reliable_frames_in_flight + o.max_realtime_frames_in_flight,
                  Impl::FrameSlot{});
  s.abandoned_rt.reserve(kIndexCount + s.frames.size());
  {
    std::lock_guard q(s.incoming_mutex);
    s.accepting = true;
  }
  {
    std::lock_guard q(s.rt_mutex);
    s.rt_accepting = true;
  }
  s.phase.store(Impl::Phase::running);
  try {
    s.thread = std::thread([&s] { s.run(); });
    // Named from here, before start() returns (on_thread_start may rename it).
    if (!o.thread_name.empty()) {
      pthread_setname_np(s.thread.native_handle(), o.thread_name.substr(0, 15).c_str());
    }
  } catch (const std::exception& e) {
    s.phase.store(Impl::Phase::stopped);
    return Error(Errc::io_error,
                 fmt::format("cannot start the bus thread for link {}: {}", s.link_name, e.what()));
  }
  return ok();
}

void Bus::stop() {
  if (!impl_) return;
  auto& s = *impl_;
  {
    std::lock_guard q(s.incoming_mutex);
    s.accepting = false;
  }
  {
    std::lock_guard q(s.rt_mutex);
    s.rt_accepting = false;
  }
  s.stop_requested.store(true, std::memory_order_seq_cst);
  if (s.on_bus_thread()) return;  // the loop ends after the current callback; ~Bus joins
  std::lock_guard lock(s.lifecycle_mutex);
  if (s.thread.joinable()) {
    s.link->interrupt();
    s.thread.join();
  }
  s.phase.store(Impl::Phase::stopped);
  s.free_finished();
}

bool Bus::running() const noexcept {
  return impl_ && impl_->phase.load() == Impl::Phase::running &&
         !impl_->stop_requested.load(std::memory_order_acquire);
}

bool Bus::on_bus_thread() const noexcept {
  return impl_ && impl_->on_bus_thread();
}

Result<void> Bus::submit(Transaction transaction, Completion completion, TransactOptions options) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  auto& s = *impl_;
  if (auto error = s.validate(transaction, "transaction")) return std::move(*error);
  if (options.timeout <= nanoseconds(0)) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: timeout must be positive, got {} ns", summary(transaction),
                             options.timeout.count()));
  }
  if (s.link_failed.load(std::memory_order_acquire)) {
    // A stopped bus says so (Errc::closed): its link failing is no longer the news.
    if (s.phase.load() != Impl::Phase::running) return s.not_running_error();
    return s.link_failed_error(summary(transaction));
  }
  if (!s.on_bus_thread()) s.free_finished();  // (a completion submitting leaves it to others)
  auto p = std::make_unique<Impl::Pending>();
  const auto datagrams = transaction.datagrams();
  p->entries.resize(datagrams.size());
  for (std::size_t i = 0; i < datagrams.size(); ++i) {
    p->entries[i].offset = datagrams[i].data_offset;
    p->entries[i].length = datagrams[i].length;
  }
  p->reply_data.assign(transaction.payload_size(), 0);
  p->sent_index.assign(datagrams.size(), 0);
  p->tx = std::move(transaction);
  p->options = options;
  p->retries_left = options.retries;
  p->completion = std::move(completion);
  p->submitted_at = Clock::now();
  p->deadline = saturating_add(p->submitted_at, options.timeout);
  {
    std::lock_guard lock(s.incoming_mutex);
    if (!s.accepting) return s.not_running_error();
    s.incoming.push_back(p.release());
    s.incoming_count.fetch_add(1, std::memory_order_seq_cst);
  }
  s.wake();
  return ok();
}

Result<TransactionResult> Bus::transact(Transaction transaction, TransactOptions options) {
  if (on_bus_thread()) {
    return Error(Errc::wrong_state,
                 fmt::format("transact() on the bus thread of link {} would wait for itself; use "
                             "submit() from callbacks and cycle functions",
                             link_name_));
  }
  struct Waiter {
    std::mutex mutex;
    std::condition_variable cv;
    std::optional<Result<TransactionResult>> result;
  };
  auto waiter = std::make_shared<Waiter>();
  const auto what = summary(transaction);
  auto submitted = submit(
      std::move(transaction),
      [waiter](Result<TransactionResult> result) {
        std::lock_guard lock(waiter->mutex);
        waiter->result.emplace(std::move(result));
        waiter->cv.notify_all();
      },
      options);
  if (!submitted) return std::move(submitted).error();
  std::unique_lock lock(waiter->mutex);
  const auto deadline =
      saturating_add(saturating_add(Clock::now(), options.timeout), kTransactGrace);
  if (!waiter->cv.wait_until(lock, deadline, [&] { return waiter->result.has_value(); })) {
    return Error(Errc::internal,
                 fmt::format("{}: the bus on link {} did not complete it {} past its timeout", what,
                             link_name_, format_duration(kTransactGrace)));
  }
  return std::move(*waiter->result);
}

Result<void> Bus::submit_realtime(RealtimeTransaction& rt, nanoseconds stale_after) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  auto& s = *impl_;
  if (stale_after <= nanoseconds(0)) {
    return Error(Errc::invalid_argument,
                 fmt::format("realtime {}: stale_after must be positive, got {} ns",
                             summary(rt.layout_), stale_after.count()));
  }
  if (rt.validated_for_ != this) {
    if (auto error = s.validate(rt.layout_, "realtime transaction")) return std::move(*error);
    const std::size_t frames = frames_for(rt.layout_, s.max_frame);
    if (frames > s.options.max_realtime_frames_in_flight || rt.size() > kIndexCount) {
      return Error(Errc::invalid_argument,
                   fmt::format("realtime {} needs {} frames and {} indices, more than the bus "
                               "allows in flight ({} frames, {} indices)",
                               summary(rt.layout_), frames, rt.size(),
                               s.options.max_realtime_frames_in_flight, kIndexCount));
    }
    rt.frames_needed_ = frames;
    rt.validated_for_ = this;
  }
  if (s.link_failed.load(std::memory_order_acquire)) {
    return s.link_failed_error(fmt::format("realtime {}", summary(rt.layout_)));
  }
  RealtimeTransaction::Stage previous;
  {
    std::lock_guard lock(rt.wait_mutex_);
    previous = rt.stage_.load(std::memory_order_acquire);
    if (previous == RealtimeTransaction::Stage::queued ||
        previous == RealtimeTransaction::Stage::in_flight) {
      return Error(Errc::busy, fmt::format("realtime {} is still pending from its last submission",
                                           summary(rt.layout_)));
    }
    rt.stage_.store(RealtimeTransaction::Stage::queued, std::memory_order_release);
  }
  rt.stale_after_ = stale_after;
  rt.stale_at_ = saturating_add(Clock::now(), stale_after);
  rt.next_to_send_ = 0;
  rt.outstanding_ = 0;
  rt.lost_ = false;
  if (rt.link_error_) rt.link_error_.reset();
  rt.next_active_ = nullptr;
  {
    std::lock_guard lock(s.rt_mutex);
    if (s.rt_accepting) {
      if (s.rt_incoming.tail) {
        s.rt_incoming.tail->next_active_ = &rt;
      } else {
        s.rt_incoming.head = &rt;
      }
      s.rt_incoming.tail = &rt;
      ++s.rt_incoming.size;
      s.rt_incoming_count.fetch_add(1, std::memory_order_seq_cst);
    } else {
      std::lock_guard rt_lock(rt.wait_mutex_);
      rt.stage_.store(previous, std::memory_order_release);
      return s.not_running_error();
    }
  }
  s.wake();
  return ok();
}

Result<void> Bus::set_frame_timeout(nanoseconds timeout) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  if (timeout <= nanoseconds(0)) {
    return Error(Errc::invalid_argument,
                 fmt::format("frame timeout must be positive, got {} ns", timeout.count()));
  }
  impl_->frame_timeout_ns.store(timeout.count(), std::memory_order_relaxed);
  impl_->reliable_timeout_ns.store(timeout.count(), std::memory_order_relaxed);
  impl_->tell_link_budget();
  return ok();
}

nanoseconds Bus::frame_timeout() const noexcept {
  return impl_ ? impl_->frame_timeout() : nanoseconds(0);
}

Result<void> Bus::set_cycle(nanoseconds period, CycleFunction function,
                            std::optional<Clock::time_point> first_deadline) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  if (period <= nanoseconds(0)) {
    return Error(Errc::invalid_argument,
                 fmt::format("cycle period must be positive, got {} ns", period.count()));
  }
  if (!function) return Error(Errc::invalid_argument, "cycle function is empty");
  Impl::Cycle next;
  next.active = true;
  next.period = period;
  next.function = std::move(function);
  // No first deadline: install_cycle() takes the next multiple of the period (steered).
  if (first_deadline) next.next = *first_deadline;
  impl_->install_cycle(std::move(next));
  impl_->cycle_period_ns.store(period.count(), std::memory_order_relaxed);
  impl_->tell_link_budget();
  return ok();
}

void Bus::clear_cycle() {
  if (!impl_) return;
  impl_->install_cycle(Impl::Cycle{});
  impl_->cycle_period_ns.store(0, std::memory_order_relaxed);
  impl_->fastest_work_period_ns.store(0, std::memory_order_relaxed);
  impl_->tell_link_budget();
}

Result<void> Bus::set_fastest_work_period(nanoseconds period) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  if (period < nanoseconds(0)) {
    return Error(
        Errc::invalid_argument,
        fmt::format("fastest work period must not be negative, got {} ns", period.count()));
  }
  impl_->fastest_work_period_ns.store(period.count(), std::memory_order_relaxed);
  impl_->tell_link_budget();
  return ok();
}

void Bus::set_cycle_rate(double rate_ppm) noexcept {
  if (!impl_ || !std::isfinite(rate_ppm)) return;
  // A clock that runs off by more than 1000 ppm is broken, not something to follow.
  const double ppm = std::clamp(rate_ppm, -1000.0, 1000.0);
  impl_->steer_rate_ppb.store(static_cast<std::int64_t>(std::llround(ppm * 1000.0)),
                              std::memory_order_relaxed);
}

void Bus::shift_cycle(nanoseconds step) noexcept {
  if (!impl_ || step.count() == 0) return;
  impl_->steer_pending_ns.fetch_add(step.count(), std::memory_order_acq_rel);
}

void Bus::reset_cycle_steering() noexcept {
  if (!impl_) return;
  impl_->steer_rate_ppb.store(0, std::memory_order_relaxed);
  impl_->steer_pending_ns.store(0, std::memory_order_relaxed);
  impl_->steer_offset_ns.store(0, std::memory_order_relaxed);
  impl_->steer_reset.store(true, std::memory_order_release);
}

CycleSteering Bus::cycle_steering() const noexcept {
  CycleSteering out;
  if (!impl_) return out;
  out.rate_ppm =
      static_cast<double>(impl_->steer_rate_ppb.load(std::memory_order_relaxed)) / 1000.0;
  out.offset = nanoseconds(impl_->steer_offset_ns.load(std::memory_order_relaxed));
  out.pending = nanoseconds(impl_->steer_pending_ns.load(std::memory_order_relaxed));
  out.steps = impl_->steer_steps.load(std::memory_order_relaxed);
  return out;
}

Result<void> Bus::set_cycle_trace(CycleTrace* trace) {
  if (!impl_) return Error(Errc::invalid_argument, "bus created without a link");
  auto& s = *impl_;
  if (s.on_bus_thread()) {
    return Error(Errc::wrong_state,
                 "set_cycle_trace() called on the bus thread (it would wait for itself)");
  }
  CycleTrace* const previous = s.trace_slot.exchange(trace, std::memory_order_seq_cst);
  if (previous == nullptr || previous == trace) return ok();
  // The bus thread lets go of it at its next loop turn (or when it ends); wake it from its wait.
  const auto give_up = Clock::now() + 5s;
  while (s.trace_in_use.load(std::memory_order_seq_cst) == previous) {
    if (Clock::now() > give_up) {
      return Error(Errc::timeout,
                   fmt::format("bus on link {}: the bus thread did not finish its loop turn "
                               "within 5 s (a completion or cycle function blocking?)",
                               s.link_name));
    }
    s.wake();
    std::this_thread::sleep_for(50us);
  }
  return ok();
}

BusStats Bus::stats() const noexcept {
  BusStats out;
  if (!impl_) return out;
  const auto& c = impl_->stats;
  out.frames_sent = c.frames_sent.get();
  out.realtime_frames_sent = c.realtime_frames_sent.get();
  out.datagrams_sent = c.datagrams_sent.get();
  out.frames_received = c.frames_received.get();
  out.frames_lost = c.frames_lost.get();
  out.transactions_completed = c.transactions_completed.get();
  out.transactions_failed = c.transactions_failed.get();
  out.transaction_timeouts = c.transaction_timeouts.get();
  out.retries = c.retries.get();
  out.wkc_mismatches = c.wkc_mismatches.get();
  out.unmatched_replies = c.unmatched_replies.get();
  out.mismatched_replies = c.mismatched_replies.get();
  out.late_replies = c.late_replies.get();
  out.duplicate_replies = c.duplicate_replies.get();
  out.decode_errors = c.decode_errors.get();
  out.realtime_completed = c.realtime_completed.get();
  out.realtime_expired = c.realtime_expired.get();
  out.realtime_timeouts = c.realtime_timeouts.get();
  out.send_errors = c.send_errors.get();
  out.receive_errors = c.receive_errors.get();
  out.callback_exceptions = c.callback_exceptions.get();
  out.cycles = c.cycles.get();
  out.cycle_deadlines_missed = c.cycle_deadlines_missed.get();
  out.finished_awaiting_free = impl_->graveyard_size.load(std::memory_order_relaxed);
  return out;
}

Result<void> Bus::set_port_nop(link::Port port, link::NopSlot slot,
                               std::optional<link::DatagramSelector> selector) {
  if (!impl_) return Error(Errc::closed, "bus on link " + link_name_ + " is gone");
  return impl_->link->set_port_nop(port, slot, selector);
}

BusInfo Bus::info() const {
  BusInfo out;
  out.link_name = link_name_;
  if (!impl_) return out;
  const auto& s = *impl_;
  out.running = running();
  out.link_failure = s.failure();
  {
    std::lock_guard lock(s.failure_mutex);
    out.last_reopen_error = s.last_reopen_error;
  }
  out.link_failures = s.link_failures.load(std::memory_order_relaxed);
  out.link_reopens = s.link_reopens.load(std::memory_order_relaxed);
  out.reopen_attempts = s.reopen_attempts.load(std::memory_order_relaxed);
  out.link_reopenable = s.link_reopenable.load(std::memory_order_relaxed);
  out.frame_timeout = s.frame_timeout();
  out.reliable_frame_timeout = s.reliable_timeout();
  out.max_frame_size = s.max_frame;
  out.realtime_queued = s.rt_incoming_count.load() + s.pub_rt_active.load();
  out.reliable_queued = s.incoming_count.load() + s.pub_fifo.load();
  out.reliable_pending = s.incoming_count.load() + s.pub_live.load();
  out.frames_in_flight = s.pub_frames.load();
  out.realtime_frames_in_flight = s.pub_rt_frames.load();
  out.datagrams_in_flight = s.pub_datagrams.load();
  out.link_stats = s.link->stats();
  out.redundancy = s.link->redundancy();
  return out;
}

}  // namespace ecat::bus
