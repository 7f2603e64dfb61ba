#include <algorithm>
#include <ctime>
#include <memory>
#include <vector>

#include <linux/futex.h>
#include <pthread.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <ecat/exec/event_loop.hpp>

namespace ecat::exec {

namespace {

// A posted std::function: its own node, freed after it ran (or was discarded).
struct FunctionWork final : EventLoop::Work {
  explicit FunctionWork(std::function<void()> f) : Work(&invoke), function(std::move(f)) {}
  static void invoke(Work& self, bool run) {
    std::unique_ptr<FunctionWork> owned(static_cast<FunctionWork*>(&self));
    if (run && owned->function) owned->function();
  }
  std::function<void()> function;
};

std::uint32_t* futex_word(std::atomic<std::uint32_t>& word) noexcept {
  static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t));
  return reinterpret_cast<std::uint32_t*>(&word);  // NOLINT: the futex ABI wants the word itself
}

// Sleeps while `word` holds `expected`, at most until `until` (steady clock = CLOCK_MONOTONIC).
void futex_wait_until(std::atomic<std::uint32_t>& word, std::uint32_t expected,
                      Clock::time_point until) noexcept {
  if (until == Clock::time_point::max()) {
    (void)syscall(SYS_futex, futex_word(word), FUTEX_WAIT_PRIVATE, expected, nullptr, nullptr, 0);
    return;
  }
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(until.time_since_epoch());
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns.count() / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns.count() % 1'000'000'000);
  // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC time.
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAIT_BITSET_PRIVATE, expected, &ts, nullptr,
                FUTEX_BITSET_MATCH_ANY);
}

void futex_wake_one(std::atomic<std::uint32_t>& word) noexcept {
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAKE_PRIVATE, 1, nullptr, nullptr, 0);
}

}  // namespace

EventLoop::~EventLoop() {
  stop();
  join();
  discard_all();
}

void EventLoop::push(Work& work) noexcept {
  Work* head = posted_.load(std::memory_order_relaxed);
  do {
    work.next_ = head;
  } while (!posted_.compare_exchange_weak(head, &work, std::memory_order_release,
                                          std::memory_order_relaxed));
  posted_count_.fetch_add(1, std::memory_order_relaxed);
  wake();
}

// Pairs with run_one_batch: the loop announces it sleeps, then checks the sequence it read before
// looking for work; a poster bumps the sequence, then checks whether the loop sleeps. Both sides
// sequentially consistent: either the loop sees the new sequence, or the poster sees it asleep
// (and FUTEX_WAIT, comparing the sequence in the kernel, cannot miss the wake).
void EventLoop::wake() noexcept {
  wake_seq_.fetch_add(1, std::memory_order_seq_cst);
  if (sleeping_.load(std::memory_order_seq_cst)) futex_wake_one(wake_seq_);
}

void EventLoop::post(std::function<void()> work) {
  push(*new FunctionWork(std::move(work)));
}

void EventLoop::post(Work& work) noexcept {
  push(work);
}

EventLoop::TimerId EventLoop::call_at(Clock::time_point when, std::function<void()> work) {
  TimerId id = 0;
  {
    std::lock_guard lock(mutex_);
    id = next_timer_++;
    timers_.emplace(when, std::make_pair(id, std::move(work)));
  }
  wake();
  return id;
}

bool EventLoop::cancel(TimerId id) {
  std::lock_guard lock(mutex_);
  for (auto it = timers_.begin(); it != timers_.end(); ++it) {
    if (it->second.first == id) {
      timers_.erase(it);
      return true;
    }
  }
  return false;
}

std::size_t EventLoop::pending() const {
  std::lock_guard lock(mutex_);
  return posted_count_.load(std::memory_order_relaxed) + timers_.size();
}

bool EventLoop::drain_posted() {
  Work* taken = posted_.exchange(nullptr, std::memory_order_acquire);
  if (taken == nullptr) return false;
  // Newest first: reverse into posting order, then append.
  Work* ordered = nullptr;
  Work* last = taken;
  while (taken != nullptr) {
    Work* next = taken->next_;
    taken->next_ = ordered;
    ordered = taken;
    taken = next;
  }
  if (local_tail_ != nullptr) {
    local_tail_->next_ = ordered;
  } else {
    local_head_ = ordered;
  }
  local_tail_ = last;
  return true;
}

void EventLoop::discard_all() noexcept {
  (void)drain_posted();
  while (Work* w = local_head_) {
    local_head_ = w->next_;
    if (local_head_ == nullptr) local_tail_ = nullptr;
    posted_count_.fetch_sub(1, std::memory_order_relaxed);
    w->function_(*w, false);
  }
}

// Runs the posted work and the timers that are due; if there was none, waits (up to
// `wait_until`) for more. Returns false once stopped.
bool EventLoop::run_one_batch(Clock::time_point wait_until) {
  std::vector<std::function<void()>> due_timers;
  for (;;) {
    const std::uint32_t seen = wake_seq_.load(std::memory_order_seq_cst);
    if (stop_.load(std::memory_order_acquire)) return false;
    (void)drain_posted();
    Clock::time_point next_timer = Clock::time_point::max();
    {
      std::lock_guard lock(mutex_);
      const auto now = Clock::now();
      while (!timers_.empty() && timers_.begin()->first <= now) {
        due_timers.push_back(std::move(timers_.begin()->second.second));
        timers_.erase(timers_.begin());
      }
      if (!timers_.empty()) next_timer = timers_.begin()->first;
    }
    if (local_head_ != nullptr || !due_timers.empty()) break;
    const auto until = std::min(wait_until, next_timer);
    if (Clock::now() >= until) {
      if (Clock::now() >= wait_until) return true;
      continue;  // a timer is due
    }
    sleeping_.store(true, std::memory_order_seq_cst);
    if (wake_seq_.load(std::memory_order_seq_cst) == seen) futex_wait_until(wake_seq_, seen, until);
    sleeping_.store(false, std::memory_order_relaxed);
  }
  // Posted work first, then the timers that were due, each followed by a look at stop_.
  while (Work* w = local_head_) {
    local_head_ = w->next_;
    if (local_head_ == nullptr) local_tail_ = nullptr;
    posted_count_.fetch_sub(1, std::memory_order_relaxed);
    w->function_(*w, true);
    if (stop_.load(std::memory_order_acquire)) {
      // Keep what was not run for a later run() (timers due but not run are put back).
      std::lock_guard lock(mutex_);
      for (auto& f : due_timers)
        timers_.emplace(Clock::time_point::min(), std::make_pair(next_timer_++, std::move(f)));
      return false;
    }
  }
  for (std::size_t i = 0; i < due_timers.size(); ++i) {
    due_timers[i]();
    if (stop_.load(std::memory_order_acquire)) {
      std::lock_guard lock(mutex_);
      for (std::size_t k = i + 1; k < due_timers.size(); ++k) {
        timers_.emplace(Clock::time_point::min(),
                        std::make_pair(next_timer_++, std::move(due_timers[k])));
      }
      return false;
    }
  }
  return true;
}

void EventLoop::run() {
  loop_thread_ = std::this_thread::get_id();
  while (run_one_batch(Clock::time_point::max())) {
  }
  loop_thread_ = std::thread::id{};
}

void EventLoop::run_until(Clock::time_point deadline) {
  loop_thread_ = std::this_thread::get_id();
  stop_.store(false, std::memory_order_release);
  while (Clock::now() < deadline) {
    if (!run_one_batch(deadline)) break;
  }
  loop_thread_ = std::thread::id{};
}

void EventLoop::reset() {
  stop_.store(false, std::memory_order_release);
}

void EventLoop::stop() {
  stop_.store(true, std::memory_order_release);
  wake();
}

void EventLoop::start_thread(std::string name) {
  join();
  stop_.store(false, std::memory_order_release);
  thread_ = std::thread([this] { run(); });
  // Named from here, so the name is there when start_thread returns.
  pthread_setname_np(thread_.native_handle(), name.substr(0, 15).c_str());
}

void EventLoop::join() {
  if (thread_.joinable() && thread_.get_id() != std::this_thread::get_id()) thread_.join();
}

}  // namespace ecat::exec
