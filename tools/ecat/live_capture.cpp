// Live capture: the recorder's streaming thread writes pcapng (live_capture.hpp).
#include "live_capture.hpp"

#include <cstdio>
#include <utility>

#include <fmt/format.h>

#include <ecat/capture/pcapng_writer.hpp>

namespace ecat::tool {

namespace {

// The --pcap recorder: it only buffers between two passes of the streaming thread (every 10 ms),
// so a few MiB hold far more than that even at line rate; the window does not matter here.
constexpr std::size_t kStreamBudget = std::size_t{8} << 20;
constexpr auto kStreamPeriod = std::chrono::milliseconds(10);

capture::PcapngInterface interface_for(const std::string& link_name) {
  capture::PcapngInterface interface;
  interface.link_type = capture::kLinkTypeEthernet;
  interface.name = link_name;
  return interface;
}

Result<void> write_frame(capture::PcapngWriter& writer, const link::RecordedFrameView& frame) {
  const bool outbound = frame.direction == link::FrameDirection::outbound;
  const auto ethernet = capture::ethernet_for_capture(frame.data, outbound);
  capture::PcapngPacket packet;
  packet.timestamp_ns = frame.realtime_ns;
  packet.data = ethernet;
  packet.direction =
      outbound ? capture::PacketDirection::outbound : capture::PacketDirection::inbound;
  // A frame the recorder kept cut short: say how long it was on the wire.
  if (frame.original_length > frame.data.size()) {
    packet.original_length =
        static_cast<std::uint32_t>(ethernet.size() - frame.data.size() + frame.original_length);
  }
  return writer.write(packet);
}

}  // namespace

struct LiveCapture::File {
  capture::PcapngWriter writer;
};

std::unique_ptr<LiveCapture> LiveCapture::open(const std::string& path,
                                               const std::string& link_name) {
  auto writer = capture::PcapngWriter::create(path, interface_for(link_name));
  if (!writer) {
    fmt::print(stderr, "ecat: --pcap: {}\n", writer.error().describe());
    return nullptr;
  }
  auto capture = std::unique_ptr<LiveCapture>(new LiveCapture());
  capture->path_ = path;
  capture->file_ = std::make_shared<File>(File{std::move(*writer)});
  link::FrameRecorderOptions options;
  options.byte_budget = kStreamBudget;
  capture->recorder_ = std::make_shared<link::FrameRecorder>(options);
  auto started = capture->recorder_->start_streaming(
      [file = capture->file_](const link::RecordedFrameView& frame) {
        return write_frame(file->writer, frame);
      },
      kStreamPeriod);
  if (!started) {
    fmt::print(stderr, "ecat: --pcap {}: {}\n", path, started.error().describe());
    return nullptr;
  }
  return capture;
}

LiveCapture::~LiveCapture() {
  if (!finished_) (void)finish();
}

std::unique_ptr<link::Link> LiveCapture::wrap(std::unique_ptr<link::Link> link) {
  return std::make_unique<link::RecordingLink>(std::move(link), recorder_);
}

bool LiveCapture::finish(const master::MasterCounters* bus) {
  if (finished_) return true;
  finished_ = true;
  auto streamed = recorder_->stop_streaming();
  auto closed = file_->writer.close();
  const auto stats = recorder_->stats();
  fmt::print(stderr, "ecat: capture {}: {} frames written{}{}\n", path_, file_->writer.packets(),
             stats.stream_dropped > 0
                 ? fmt::format(", {} dropped (the file could not keep up)", stats.stream_dropped)
                 : std::string(),
             bus != nullptr ? fmt::format("; the bus sent {} and received {}", bus->frames_sent,
                                          bus->frames_received)
                            : std::string());
  if (!streamed) {
    fmt::print(stderr, "ecat: capture {}: {}\n", path_, streamed.error().describe());
    return false;
  }
  if (!closed) {
    fmt::print(stderr, "ecat: capture {}: {}\n", path_, closed.error().describe());
    return false;
  }
  return stats.stream_dropped == 0;
}

Result<void> write_recorded_frames(const std::string& path,
                                   std::span<const link::RecordedFrame> frames,
                                   const std::string& link_name) {
  auto writer = capture::PcapngWriter::create(path, interface_for(link_name));
  if (!writer) return std::move(writer).error();
  for (const auto& frame : frames) {
    if (auto written = write_frame(*writer, frame.view()); !written) return written;
  }
  return writer->close();
}

}  // namespace ecat::tool
