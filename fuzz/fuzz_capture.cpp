// Capture files from anywhere: the pcap/pcapng reader (CaptureFile::from_bytes: libpcap reading
// the bytes through fmemopen, the same path as CaptureFile::open on a file), EtherCAT extraction,
// request/reply pairing, profile rebuilding and the replay against the rebuilt segment must turn
// any bytes into values or error values, never a crash, hang or undefined behaviour. libpcap is
// the system's (not coverage-instrumented): the guidance comes from our code after it.
#include <cstddef>
#include <cstdint>
#include <vector>

#include <ecat/capture/capture_file.hpp>
#include <ecat/sim/capture_profile.hpp>
#include <ecat/sim/capture_verify.hpp>

namespace {
// Bounds that keep one input fast: a replay costs (frames x slaves).
constexpr std::size_t kMaxFrames = 256;
constexpr std::size_t kMaxSlaves = 8;
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  auto file =
      ecat::capture::CaptureFile::from_bytes(std::vector<std::uint8_t>(data, data + size), "fuzz");
  if (!file) return 0;
  std::vector<ecat::sim::CaptureFrame> frames;
  std::vector<ecat::sim::FrameDirection> directions;
  while (frames.size() < kMaxFrames) {
    auto packet = file->next();
    if (!packet || !*packet) break;
    const auto& p = **packet;
    const auto ethercat = ecat::capture::extract_ethercat(p.link_type, p.data);
    if (!ethercat) continue;
    ecat::sim::CaptureFrame frame;
    frame.number = p.number;
    frame.timestamp_ns = p.timestamp_ns;
    frame.frame.assign(ethercat->frame.begin(), ethercat->frame.end());
    frames.push_back(std::move(frame));
    directions.push_back(ecat::sim::frame_direction(*ethercat));
  }
  const auto trace =
      ecat::sim::pair_capture_frames(std::move(frames), std::move(directions), "fuzz");
  auto profile = ecat::sim::build_capture_profile(trace);
  if (!profile || profile->slaves.size() > kMaxSlaves) return 0;
  (void)ecat::sim::capture_profile_json(*profile);
  auto segment = ecat::sim::build_capture_segment(*profile);
  if (!segment) return 0;
  auto report = ecat::sim::verify_capture(trace, **segment);
  if (report) {
    (void)ecat::sim::format_verify_report(*report);
    (void)ecat::sim::verify_report_json(*report);
  }
  return 0;
}
