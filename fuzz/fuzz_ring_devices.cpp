// Building the emulated devices of a ring (parse_ring, then build_segment: every profile, EEPROM
// images for `eeprom`, ESI XML for `esi`, wiring) must never crash, hang or leak an exception,
// whatever the ring and the files it names hold. Errors name the file. A segment that builds has
// one ESC per ring slave under the ring's names, every signal a built-in profile lists has a
// value, and it answers broadcast reads and a broadcast AL control write with one working-counter
// increment per slave.
//
// Input: the ring's YAML text, then up to four files, each introduced by the 4-byte separator
// "\0\0FZ":  YAML [SEP a.bin [SEP b.bin [SEP c.xml [SEP d.xml]]]]. The files are written to a
// temporary folder (created once per process) that is the ring's base_dir, so the YAML names
// them `file: a.bin`. A file whose part is absent does not exist. Rings naming any other file are
// not built (no reads from the host), nor rings of more than 128 slaves or more than 8 slaves
// built from files (large rings only cost time).
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <unistd.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/frame.hpp>

namespace {

constexpr std::string_view kSeparator("\0\0FZ", 4);
constexpr std::array<const char*, 4> kFileNames{"a.bin", "b.bin", "c.xml", "d.xml"};
constexpr std::string_view kSource = "fuzz.yaml";
constexpr std::size_t kMaxSlaves = 128;
constexpr std::size_t kMaxFileSlaves = 8;

[[noreturn]] void fail(const char* what, int line) {
  std::fprintf(stderr, "fuzz_ring_devices.cpp:%d: %s does not hold\n", line, what);
  std::abort();
}
#define REQUIRE(condition) ((condition) ? void() : fail(#condition, __LINE__))

struct Folder {
  std::string dir;
  std::array<std::string, kFileNames.size()> paths;
};

void remove_folder();

// Never destroyed: remove_folder runs at exit, after static destructors may have run.
const Folder& folder() {
  static const Folder* const f = [] {
    auto* out = new Folder;
    char pattern[] = "/tmp/ecat-fuzz-ring-devices-XXXXXX";
    if (::mkdtemp(pattern) == nullptr) {
      std::perror("mkdtemp");
      std::abort();
    }
    out->dir = pattern;
    for (std::size_t i = 0; i < kFileNames.size(); ++i)
      out->paths[i] = out->dir + "/" + kFileNames[i];
    return out;
  }();
  return *f;
}

void remove_folder() {
  const Folder& f = folder();
  for (const auto& path : f.paths)
    ::unlink(path.c_str());
  ::rmdir(f.dir.c_str());
}

void write_file(const std::string& path, std::string_view content) {
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) std::abort();
  if (!content.empty() && std::fwrite(content.data(), 1, content.size(), file) != content.size())
    std::abort();
  if (std::fclose(file) != 0) std::abort();
}

// Splits the input at the separators: parts[0] is the YAML text, parts[1..] the files.
std::vector<std::string_view> split(std::string_view input) {
  std::vector<std::string_view> parts;
  while (parts.size() < kFileNames.size()) {
    const void* found = ::memmem(input.data(), input.size(), kSeparator.data(), kSeparator.size());
    if (found == nullptr) break;
    const auto at = static_cast<std::size_t>(static_cast<const char*>(found) - input.data());
    parts.push_back(input.substr(0, at));
    input.remove_prefix(at + kSeparator.size());
  }
  parts.push_back(input);
  return parts;
}

void check_error(const ecat::Error& error) {
  REQUIRE(error.message().starts_with(kSource));
  REQUIRE(!error.describe().empty());
}

// One frame of broadcast datagrams through the segment; each must come back with `wkc`.
void exchange(ecat::sim::Segment& segment, ecat::wire::Command command, std::uint16_t offset,
              std::vector<std::uint8_t> data, std::int64_t now_ns, std::uint16_t wkc) {
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  ecat::wire::DatagramHeader header;
  header.command = command;
  header.index = 1;
  header.address = static_cast<std::uint32_t>(offset) << 16;
  header.length = static_cast<std::uint16_t>(data.size());
  REQUIRE(builder.add(header, data).has_value());
  const auto frame = builder.finish();
  std::vector<std::uint8_t> bytes(frame.begin(), frame.end());
  REQUIRE(segment.process_frame(bytes, now_ns));
  const auto decoded = ecat::wire::decode_frame(bytes);
  REQUIRE(decoded.frame.has_value());
  for (const auto& d : *decoded.frame)
    REQUIRE(d.wkc == wkc);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > 1024 * 1024) return 0;
  static const bool cleanup = std::atexit(remove_folder) == 0;
  (void)cleanup;
  const Folder& files = folder();
  const auto parts = split(std::string_view(reinterpret_cast<const char*>(data), size));
  if (parts[0].size() > 64 * 1024) return 0;
  for (std::size_t i = 0; i < kFileNames.size(); ++i) {
    if (i + 1 < parts.size()) {
      write_file(files.paths[i], parts[i + 1]);
    } else {
      ::unlink(files.paths[i].c_str());
    }
  }

  auto ring = ecat::sim::parse_ring(parts[0], std::string(kSource), files.dir);
  if (!ring) {
    check_error(ring.error());
    return 0;
  }
  REQUIRE(!ring->slaves.empty());
  if (ring->slaves.size() > kMaxSlaves) return 0;
  std::size_t from_files = 0;
  for (const auto& s : ring->slaves) {
    if (s.device.file.empty()) continue;
    bool ours = false;
    for (const auto& path : files.paths)
      ours = ours || s.device.file == path;
    if (!ours) return 0;
    ++from_files;
  }
  if (from_files > kMaxFileSlaves) return 0;

  auto segment = ecat::sim::build_segment(*ring);
  if (!segment) {
    check_error(segment.error());
    return 0;
  }
  ecat::sim::Segment& s = **segment;
  REQUIRE(s.size() == ring->slaves.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    REQUIRE(s.name(i) == ring->slaves[i].name);
    REQUIRE(s.find(ring->slaves[i].name) == i);
    if (auto* app = ecat::sim::device_application(s.esc(i))) {
      // Every signal a device lists has a value, whatever its EEPROM image or ESI maps.
      for (const auto& signal : app->signals()) {
        REQUIRE(!signal.name.empty());
        REQUIRE(app->signal(signal.name).has_value());
      }
    }
  }

  // Broadcast reads of the ESC information and AL status, a request for PREOP, AL status again.
  namespace reg = ecat::wire::reg;
  const auto count = static_cast<std::uint16_t>(s.size());
  using ecat::wire::Command;
  exchange(s, Command::brd, reg::kType, std::vector<std::uint8_t>(10), 1'000'000, count);
  exchange(s, Command::brd, reg::kAlStatus, std::vector<std::uint8_t>(6), 2'000'000, count);
  exchange(s, Command::bwr, reg::kAlControl, {0x02, 0x00}, 3'000'000, count);
  s.advance(10'000'000);
  exchange(s, Command::brd, reg::kAlStatus, std::vector<std::uint8_t>(6), 10'000'000, count);
  return 0;
}
