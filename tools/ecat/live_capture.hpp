// Live capture for the `ecat` commands: `--pcap FILE` streams every frame a session's link sends
// and receives into a pcapng file (a link::RecordingLink feeding a link::FrameRecorder, whose
// streaming thread writes through capture::PcapngWriter), and the flight recorder's frames are
// written the same way (`ecat capture`, `ecat serve --flight-recorder-dir`).
//
// The tool is where link (the recorder) and capture (the file format) meet: neither layer sees
// the other.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include <ecat/link/link.hpp>
#include <ecat/link/recording_link.hpp>
#include <ecat/master/master.hpp>
#include <ecat/result.hpp>

namespace ecat::tool {

class LiveCapture {
 public:
  // Creates `path` (a pcapng file) and starts streaming into it. Prints why not (naming the file)
  // and returns nullptr.
  static std::unique_ptr<LiveCapture> open(const std::string& path, const std::string& link_name);
  ~LiveCapture();  // finish() if not done yet

  // The link the session should use instead of `link`: records into this capture's recorder.
  std::unique_ptr<link::Link> wrap(std::unique_ptr<link::Link> link);

  // Writes what is still in flight, closes the file and prints a line on stderr (the frames
  // written, those dropped, and with `bus` the frames the bus counted, to compare). Call it once
  // the session has stopped. False (after printing why) when the file could not be written in
  // full.
  bool finish(const master::MasterCounters* bus = nullptr);

  const std::shared_ptr<link::FrameRecorder>& recorder() const noexcept { return recorder_; }

 private:
  struct File;
  LiveCapture() = default;
  std::string path_;
  std::shared_ptr<link::FrameRecorder> recorder_;
  std::shared_ptr<File> file_;
  bool finished_ = false;
};

// One recorded frame as a pcapng packet (the EtherCAT frame in an Ethernet II frame, the
// direction in epb_flags), for files of recorded frames.
Result<void> write_recorded_frames(const std::string& path,
                                   std::span<const link::RecordedFrame> frames,
                                   const std::string& link_name);

}  // namespace ecat::tool
