// The flight recorder's rings and the recording link (recording_link.hpp has the contract).
//
// One Lane per direction, each with a single producer:
//   words    the frame bytes, packed into 64-bit atomics (relaxed loads and stores: a reader
//            copying while the producer overwrites is a detected race, not undefined behaviour);
//            a frame occupies consecutive words, never wrapping (the producer skips to the start
//            when the rest of the ring is too short). Positions count words ever written.
//   entries  one per frame, in record order (seq n sits at n % entry_count): where its bytes are,
//            its length and times. `seq` holds n once the entry is complete, kWriting meanwhile.
//   reserved the word position up to which the producer has begun writing (published before the
//            bytes, behind a release fence): a reader that copied words [pos, pos+w) and then,
//            after an acquire fence, still sees reserved <= pos + capacity knows none was
//            overwritten under it. The same goes for an entry and its `seq`.
//   committed frames complete (release): readers look at seq < committed only.
// The bytes and the entries are sized from the byte budget; whichever runs out first decides how
// far back a lane reaches.
#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <thread>
#include <utility>

#include <time.h>

#include <ecat/link/recording_link.hpp>

namespace ecat::link {

namespace {

constexpr std::uint64_t kWriting = ~std::uint64_t{0};
constexpr std::size_t kMinBudget = std::size_t{64} << 10;
constexpr std::size_t kMaxBudget = std::size_t{1} << 30;
constexpr std::size_t kMaxFrameLimit = std::size_t{64} << 10;

std::int64_t clock_ns(clockid_t clock) noexcept {
  timespec ts{};
  ::clock_gettime(clock, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

struct Entry {
  std::atomic<std::uint64_t> seq{kWriting};
  std::atomic<std::uint64_t> word_pos{0};
  std::atomic<std::int64_t> realtime_ns{0};
  std::atomic<std::int64_t> steady_ns{0};
  std::atomic<std::uint32_t> length{0};
  std::atomic<std::uint32_t> original_length{0};
};

struct Lane {
  FrameDirection direction = FrameDirection::outbound;
  std::unique_ptr<std::atomic<std::uint64_t>[]> words;
  std::size_t word_count = 0;
  std::unique_ptr<Entry[]> entries;
  std::size_t entry_count = 0;
  std::uint64_t head = 0;  // producer only: the next free word position
  std::atomic<std::uint64_t> reserved{0};
  std::atomic<std::uint64_t> committed{0};

  void allocate(std::size_t bytes, std::size_t max_frame_words) {
    // Three quarters for bytes, a quarter for entries; the bytes hold at least two largest frames.
    word_count = std::max(bytes * 3 / 4 / 8, 2 * max_frame_words);
    entry_count = std::max<std::size_t>(bytes / 4 / sizeof(Entry), 16);
    words = std::make_unique<std::atomic<std::uint64_t>[]>(word_count);
    entries = std::make_unique<Entry[]>(entry_count);
  }

  void record(wire::Bytes frame, std::size_t length, std::int64_t realtime_ns,
              std::int64_t steady_ns) noexcept {
    const std::uint64_t n = committed.load(std::memory_order_relaxed);
    const std::size_t needed = (length + 7) / 8;
    std::uint64_t pos = head;
    const std::size_t offset = static_cast<std::size_t>(pos % word_count);
    if (offset + needed > word_count) pos += word_count - offset;
    const std::uint64_t end = pos + needed;
    Entry& entry = entries[n % entry_count];
    reserved.store(end, std::memory_order_relaxed);
    entry.seq.store(kWriting, std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_release);
    const std::size_t base = static_cast<std::size_t>(pos % word_count);
    for (std::size_t i = 0; i < needed; ++i) {
      std::uint64_t word = 0;
      std::memcpy(&word, frame.data() + i * 8, std::min<std::size_t>(8, length - i * 8));
      words[base + i].store(word, std::memory_order_relaxed);
    }
    entry.word_pos.store(pos, std::memory_order_relaxed);
    entry.realtime_ns.store(realtime_ns, std::memory_order_relaxed);
    entry.steady_ns.store(steady_ns, std::memory_order_relaxed);
    entry.length.store(static_cast<std::uint32_t>(length), std::memory_order_relaxed);
    entry.original_length.store(static_cast<std::uint32_t>(frame.size()),
                                std::memory_order_relaxed);
    entry.seq.store(n, std::memory_order_release);
    head = end;
    committed.store(n + 1, std::memory_order_release);
  }

  // Copies frame `n` (n < committed) into `out` (resized: the reader's own memory). False when
  // the producer has overwritten it, before or while it was copied.
  bool read(std::uint64_t n, RecordedFrame& out) const {
    const Entry& entry = entries[n % entry_count];
    if (entry.seq.load(std::memory_order_acquire) != n) return false;
    const std::uint64_t pos = entry.word_pos.load(std::memory_order_relaxed);
    out.direction = direction;
    out.realtime_ns = entry.realtime_ns.load(std::memory_order_relaxed);
    out.steady_ns = entry.steady_ns.load(std::memory_order_relaxed);
    out.original_length = entry.original_length.load(std::memory_order_relaxed);
    const std::size_t length =
        std::min<std::size_t>(entry.length.load(std::memory_order_relaxed), word_count * 8);
    // Before copying: gone already?
    if (reserved.load(std::memory_order_acquire) > pos + word_count) return false;
    const std::size_t needed = (length + 7) / 8;
    const std::size_t base = static_cast<std::size_t>(pos % word_count);
    if (base + needed > word_count) return false;  // a torn entry: positions never wrap
    out.data.resize(length);
    for (std::size_t i = 0; i < needed; ++i) {
      const std::uint64_t word = words[base + i].load(std::memory_order_relaxed);
      std::memcpy(out.data.data() + i * 8, &word, std::min<std::size_t>(8, length - i * 8));
    }
    std::atomic_thread_fence(std::memory_order_acquire);
    if (entry.seq.load(std::memory_order_relaxed) != n) return false;
    return reserved.load(std::memory_order_relaxed) <= pos + word_count;
  }

  // The oldest frame that may still be readable.
  std::uint64_t oldest(std::uint64_t end) const noexcept {
    return end > entry_count ? end - entry_count : 0;
  }
};

bool earlier(const RecordedFrame& a, const RecordedFrame& b) noexcept {
  return a.steady_ns < b.steady_ns;
}

}  // namespace

std::string_view to_string(FrameDirection direction) noexcept {
  return direction == FrameDirection::inbound ? "inbound" : "outbound";
}

struct FrameRecorder::Impl {
  FrameRecorderOptions options;
  Lane lanes[2];  // [0] inbound, [1] outbound
  std::atomic<std::uint64_t> truncated{0};
  std::atomic<std::uint64_t> stream_dropped{0};
  std::atomic<std::uint64_t> streamed{0};

  // Streaming (the streaming thread and start/stop only).
  std::mutex stream_mutex;
  std::condition_variable stream_wake;
  bool stream_stop = false;
  std::thread stream_thread;
  Sink sink;
  std::chrono::milliseconds period{20};
  std::uint64_t stream_next[2] = {0, 0};
  std::optional<Error> stream_error;

  Lane& lane(FrameDirection d) noexcept { return lanes[d == FrameDirection::inbound ? 0 : 1]; }

  // Hands every frame committed since the last call to the sink (streaming thread).
  void drain(std::vector<RecordedFrame>& batch) {
    batch.clear();
    for (int l = 0; l < 2; ++l) {
      const Lane& lane = lanes[l];
      const std::uint64_t end = lane.committed.load(std::memory_order_acquire);
      std::uint64_t& next = stream_next[l];
      if (next < lane.oldest(end)) {
        stream_dropped.fetch_add(lane.oldest(end) - next, std::memory_order_relaxed);
        next = lane.oldest(end);
      }
      for (; next < end; ++next) {
        batch.emplace_back();
        if (!lane.read(next, batch.back())) {
          batch.pop_back();
          stream_dropped.fetch_add(1, std::memory_order_relaxed);
        }
      }
    }
    std::stable_sort(batch.begin(), batch.end(), earlier);
    for (const auto& frame : batch) {
      if (stream_error) {
        stream_dropped.fetch_add(1, std::memory_order_relaxed);
        continue;
      }
      if (auto written = sink(frame.view()); !written) {
        stream_error = std::move(written).error();
        continue;
      }
      streamed.fetch_add(1, std::memory_order_relaxed);
    }
  }

  void stream_loop() {
    std::vector<RecordedFrame> batch;
    std::unique_lock lock(stream_mutex);
    for (;;) {
      // Polled, not signalled: the producer (the bus thread) never wakes anybody.
      stream_wake.wait_for(lock, period, [&] { return stream_stop; });
      const bool last = stream_stop;
      lock.unlock();
      drain(batch);
      lock.lock();
      if (last) return;
    }
  }
};

FrameRecorder::FrameRecorder(FrameRecorderOptions options) : impl_(std::make_unique<Impl>()) {
  options.byte_budget = std::clamp(options.byte_budget, kMinBudget, kMaxBudget);
  options.max_frame_bytes = std::clamp<std::size_t>(options.max_frame_bytes, 1, kMaxFrameLimit);
  if (options.window < std::chrono::nanoseconds(0)) options.window = std::chrono::nanoseconds(0);
  impl_->options = options;
  const std::size_t max_frame_words = (options.max_frame_bytes + 7) / 8;
  impl_->lanes[0].direction = FrameDirection::inbound;
  impl_->lanes[1].direction = FrameDirection::outbound;
  for (auto& lane : impl_->lanes)
    lane.allocate(options.byte_budget / 2, max_frame_words);
}

FrameRecorder::~FrameRecorder() {
  if (impl_->stream_thread.joinable()) {
    {
      std::lock_guard lock(impl_->stream_mutex);
      impl_->stream_stop = true;
    }
    impl_->stream_wake.notify_all();
    impl_->stream_thread.join();
  }
}

void FrameRecorder::record(FrameDirection direction, wire::Bytes frame,
                           std::int64_t steady_ns) noexcept {
  const std::int64_t steady_now = clock_ns(CLOCK_MONOTONIC);
  const std::int64_t realtime_now = clock_ns(CLOCK_REALTIME);
  if (steady_ns == 0) steady_ns = steady_now;
  // The wall-clock time of the moment the link saw the frame (a kernel receive stamp is earlier
  // than now).
  const std::int64_t realtime_ns = realtime_now - (steady_now - steady_ns);
  std::size_t length = frame.size();
  if (length > impl_->options.max_frame_bytes) {
    length = impl_->options.max_frame_bytes;
    impl_->truncated.fetch_add(1, std::memory_order_relaxed);
  }
  impl_->lane(direction).record(frame, length, realtime_ns, steady_ns);
}

std::vector<RecordedFrame> FrameRecorder::snapshot(std::optional<std::chrono::nanoseconds> last,
                                                   std::size_t max_bytes, bool* cut) const {
  const std::int64_t window =
      last ? std::max<std::int64_t>(last->count(), 0) : impl_->options.window.count();
  const std::int64_t now = clock_ns(CLOCK_MONOTONIC);
  const std::int64_t cutoff = now - window;
  std::vector<RecordedFrame> out;
  for (const Lane& lane : impl_->lanes) {
    const std::uint64_t end = lane.committed.load(std::memory_order_acquire);
    RecordedFrame frame;
    for (std::uint64_t n = lane.oldest(end); n < end; ++n) {
      if (lane.read(n, frame) && frame.steady_ns >= cutoff) out.push_back(frame);
    }
  }
  std::stable_sort(out.begin(), out.end(), earlier);
  // The newest frames within max_bytes.
  std::size_t bytes = 0;
  std::size_t keep_from = out.size();
  while (keep_from > 0 && bytes + out[keep_from - 1].data.size() <= max_bytes) {
    bytes += out[--keep_from].data.size();
  }
  if (cut != nullptr) *cut = keep_from > 0;
  out.erase(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(keep_from));
  return out;
}

Result<void> FrameRecorder::start_streaming(Sink sink, std::chrono::milliseconds period) {
  if (impl_->stream_thread.joinable()) {
    return Error(Errc::busy, "the frame recorder is already streaming");
  }
  if (!sink) return Error(Errc::invalid_argument, "streaming frames needs a sink");
  impl_->sink = std::move(sink);
  impl_->period = std::max(period, std::chrono::milliseconds(1));
  impl_->stream_stop = false;
  impl_->stream_error.reset();
  // From now on: what is in the rings already is the flight recorder's, not the stream's.
  for (int l = 0; l < 2; ++l)
    impl_->stream_next[l] = impl_->lanes[l].committed.load(std::memory_order_acquire);
  impl_->stream_thread = std::thread([impl = impl_.get()] { impl->stream_loop(); });
  return ok();
}

Result<void> FrameRecorder::stop_streaming() {
  if (!impl_->stream_thread.joinable()) return ok();
  {
    std::lock_guard lock(impl_->stream_mutex);
    impl_->stream_stop = true;
  }
  impl_->stream_wake.notify_all();
  impl_->stream_thread.join();
  impl_->sink = nullptr;
  if (impl_->stream_error) return *std::exchange(impl_->stream_error, std::nullopt);
  return ok();
}

FrameRecorderStats FrameRecorder::stats() const noexcept {
  FrameRecorderStats out;
  for (const Lane& lane : impl_->lanes)
    out.recorded += lane.committed.load(std::memory_order_relaxed);
  out.truncated = impl_->truncated.load(std::memory_order_relaxed);
  out.stream_dropped = impl_->stream_dropped.load(std::memory_order_relaxed);
  out.streamed = impl_->streamed.load(std::memory_order_relaxed);
  return out;
}

const FrameRecorderOptions& FrameRecorder::options() const noexcept {
  return impl_->options;
}

// ---- RecordingLink ------------------------------------------------------------------------------

RecordingLink::RecordingLink(std::unique_ptr<Link> inner, std::shared_ptr<FrameRecorder> recorder)
    : inner_(std::move(inner)), recorder_(std::move(recorder)) {}

Result<void> RecordingLink::send(wire::Bytes ethercat_frame) {
  // The time the frame was handed to the link, recorded once it went out (frames the link
  // refused never crossed it, and the bus does not count them as sent either).
  const std::int64_t now = clock_ns(CLOCK_MONOTONIC);
  auto sent = inner_->send(ethercat_frame);
  if (sent) recorder_->record(FrameDirection::outbound, ethercat_frame, now);
  return sent;
}

Result<std::optional<ReceivedFrame>> RecordingLink::receive(std::chrono::nanoseconds timeout) {
  auto received = inner_->receive(timeout);
  if (received && received->has_value()) {
    const ReceivedFrame& frame = **received;
    recorder_->record(FrameDirection::inbound, frame.frame, frame.timestamp_ns);
  }
  return received;
}

void RecordingLink::interrupt() {
  inner_->interrupt();
}
void RecordingLink::close() {
  inner_->close();
}
Result<void> RecordingLink::reopen() {
  return inner_->reopen();
}
std::string RecordingLink::name() const {
  return inner_->name();
}
LinkStats RecordingLink::stats() const {
  return inner_->stats();
}
std::size_t RecordingLink::max_frame_size() const {
  return inner_->max_frame_size();
}
int RecordingLink::wait_fd() {
  return inner_->wait_fd();
}
std::optional<RedundancyStatus> RecordingLink::redundancy() const {
  return inner_->redundancy();
}
void RecordingLink::set_frame_budget(std::chrono::nanoseconds budget) {
  inner_->set_frame_budget(budget);
}

Result<void> RecordingLink::set_port_nop(Port port, NopSlot slot,
                                         std::optional<DatagramSelector> selector) {
  return inner_->set_port_nop(port, slot, selector);
}

}  // namespace ecat::link
