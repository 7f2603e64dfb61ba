// Recording what crosses a link: `RecordingLink` wraps any Link and hands every frame it sends or
// receives (with its times and direction) to a `FrameRecorder`, a bounded in-memory ring that
// keeps the recent past (the flight recorder) and can stream everything to a caller's sink on a
// thread of its own (`ecat --pcap FILE` writes a pcapng file from there).
//
// The link layer knows nothing of file formats: the capture layer writes pcapng
// (capture/pcapng_writer.hpp) and the tool plugs the two together through the sink.
//
// Cycle path: RecordingLink::send/receive run on the bus thread. Recording copies the frame into
// memory preallocated at construction and takes no lock, allocates nothing and logs nothing. Each
// direction has a ring of its own with exactly one producer (the Link contract: one thread sends
// at a time, one receives at a time), so the two never contend. Readers (snapshot, the streaming
// thread, a control endpoint) never hold the producer up: they validate what they copied against
// the producer's counters afterwards (a sequence lock) and count what was overwritten under them
// as dropped.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::link {

enum class FrameDirection : std::uint8_t { inbound, outbound };
std::string_view to_string(FrameDirection direction) noexcept;

// A frame as the recorder hands it out. `data` points into the reader's buffer: valid during the
// sink call (streaming) or as long as the snapshot that holds it.
struct RecordedFrameView {
  FrameDirection direction = FrameDirection::outbound;
  std::int64_t realtime_ns = 0;  // CLOCK_REALTIME: what files carry
  std::int64_t steady_ns = 0;    // CLOCK_MONOTONIC: the bus's clock (ReceivedFrame::timestamp_ns)
  std::uint32_t original_length = 0;  // the frame's length; data may hold less (max_frame_bytes)
  wire::Bytes data;
};

struct RecordedFrame {
  FrameDirection direction = FrameDirection::outbound;
  std::int64_t realtime_ns = 0;
  std::int64_t steady_ns = 0;
  std::uint32_t original_length = 0;
  std::vector<std::uint8_t> data;
  RecordedFrameView view() const noexcept {
    return {direction, realtime_ns, steady_ns, original_length, wire::Bytes(data)};
  }
};

struct FrameRecorderOptions {
  // How far back snapshot() looks by default (the flight recorder's "last N seconds").
  std::chrono::nanoseconds window = std::chrono::seconds(10);
  // Memory for both directions together, all allocated at construction: frames older than what
  // fits are gone even when younger than `window`. At least 64 KiB, at most 1 GiB.
  std::size_t byte_budget = std::size_t{32} << 20;
  // Longer frames are kept cut to this many bytes (original_length tells); at most 64 KiB.
  std::size_t max_frame_bytes = 1514;
};

struct FrameRecorderStats {
  std::uint64_t recorded = 0;   // frames handed to record()
  std::uint64_t truncated = 0;  // of those, kept shorter than they were (max_frame_bytes)
  // Frames the streaming thread did not get to before the ring overwrote them (the sink fell
  // behind): the file lacks them, the bus never waited for it.
  std::uint64_t stream_dropped = 0;
  std::uint64_t streamed = 0;  // frames handed to the sink
};

class FrameRecorder {
 public:
  // Allocates the rings (byte_budget, clamped to its bounds).
  explicit FrameRecorder(FrameRecorderOptions options = {});
  ~FrameRecorder();  // stops streaming (without waiting for the rest to drain: call stop_streaming)
  FrameRecorder(const FrameRecorder&) = delete;
  FrameRecorder& operator=(const FrameRecorder&) = delete;

  // Records one frame: copies it into the direction's ring. `steady_ns` is when it crossed the
  // link on CLOCK_MONOTONIC (0: now); the CLOCK_REALTIME time is derived from it. At most one
  // thread per direction at a time. Never allocates, blocks or logs.
  void record(FrameDirection direction, wire::Bytes frame, std::int64_t steady_ns = 0) noexcept;

  // The frames of the last `last` (default: options().window) still in memory, both directions
  // merged in time order, at most `max_bytes` of frame data (the newest kept). Any thread; does
  // not hold up record(). `*cut` (when given) tells whether max_bytes left older frames out.
  std::vector<RecordedFrame> snapshot(std::optional<std::chrono::nanoseconds> last = std::nullopt,
                                      std::size_t max_bytes = SIZE_MAX, bool* cut = nullptr) const;

  // Streaming: a thread of the recorder's own hands every frame recorded from now on to `sink`
  // (in batches, every `period`), in time order within a batch. A sink error ends streaming
  // (stop_streaming returns it). Errc::busy when already streaming.
  using Sink = std::function<Result<void>(const RecordedFrameView&)>;
  Result<void> start_streaming(Sink sink,
                               std::chrono::milliseconds period = std::chrono::milliseconds(20));
  // Hands what is left to the sink, ends the thread; the sink's error if it failed. A no-op when
  // not streaming.
  Result<void> stop_streaming();

  FrameRecorderStats stats() const noexcept;
  const FrameRecorderOptions& options() const noexcept;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A Link that records every frame it sends (after a successful send) and receives into
// `recorder`, and otherwise does what `inner` does (name, stats, reopen, interrupt, close).
class RecordingLink final : public Link {
 public:
  RecordingLink(std::unique_ptr<Link> inner, std::shared_ptr<FrameRecorder> recorder);

  Result<void> send(wire::Bytes ethercat_frame) override;
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override;
  void interrupt() override;
  void close() override;
  Result<void> reopen() override;
  std::string name() const override;
  LinkStats stats() const override;
  std::size_t max_frame_size() const override;
  int wait_fd() override;
  std::optional<RedundancyStatus> redundancy() const override;
  void set_frame_budget(std::chrono::nanoseconds budget) override;
  Result<void> set_port_nop(Port port, NopSlot slot,
                            std::optional<DatagramSelector> selector) override;

  FrameRecorder& recorder() const noexcept { return *recorder_; }

 private:
  std::unique_ptr<Link> inner_;
  std::shared_ptr<FrameRecorder> recorder_;
};

}  // namespace ecat::link
