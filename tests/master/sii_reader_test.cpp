// The master's SII reader against simulated ESCs: whole images byte for byte (built-in profiles and
// real EEPROM images), word ranges, 4- and 8-byte data registers, a slow and a stuck EEPROM
// interface, checksum errors, missing acknowledges, the image size bound, and concurrent reads
// of 16 slaves sharing frames.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/sii_reader.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/sii.hpp>

#include "master/master_test_support.hpp"
#include "support/shared_data.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using test::SimBench;
using Bytes = std::vector<std::uint8_t>;

// The image up to and including the end marker, found by walking the categories.
Bytes through_end_marker(const Bytes& image) {
  std::size_t word = wire::sii_word::kFirstCategory;
  while (2 * word + 2 <= image.size()) {
    const auto type = wire::load_le16(&image[2 * word]);
    if (type == wire::sii_category::kEnd) return Bytes(image.begin(), image.begin() + 2 * word + 2);
    if (2 * word + 4 > image.size()) break;
    word += 2 + wire::load_le16(&image[2 * word + 2]);
  }
  ADD_FAILURE() << "test image has no end marker";
  return {};
}

Bytes eeprom_of(SimBench& bench, std::size_t position) {
  return bench.server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto e = segment.esc(position).eeprom();
    return Bytes(e.begin(), e.end());
  });
}

Bytes profile_eeprom(const std::string& profile) {
  sim::DeviceConfig config;
  config.profile = profile;
  auto esc = sim::make_device(config);
  EXPECT_TRUE(esc.ok());
  if (!esc) return {};
  auto e = (*esc)->eeprom();
  return Bytes(e.begin(), e.end());
}

// One ESC with chosen hardware and EEPROM (BasicApplication firmware).
std::unique_ptr<SimBench> bench_with(const Bytes& eeprom, sim::EscHardware hardware) {
  auto segment = std::make_unique<sim::Segment>();
  auto added = segment->add_slave(
      "slave",
      std::make_unique<sim::Esc>(hardware, eeprom, std::make_unique<sim::BasicApplication>()));
  EXPECT_TRUE(added.ok());
  return SimBench::make(std::move(segment));
}

std::string ring_of(const std::vector<std::string>& profiles) {
  std::string ring = "version: 1\nsimulator:\n  slaves:\n";
  for (std::size_t i = 0; i < profiles.size(); ++i)
    ring += fmt::format("    - {{name: s{}, profile: {}}}\n", i, profiles[i]);
  return ring;
}

TEST(SiiReader, ReadsBuiltInProfilesUpToTheEndMarker) {
  auto bench = SimBench::make(ring_of({"EK1100", "EL2809", "servo"}));
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 3)).ok());
  for (std::size_t position = 0; position < 3; ++position) {
    auto result = bench->run(read_sii(bench->loop, *bench->bus, test::station_at(position)));
    ASSERT_TRUE(result.ok()) << result.error().describe();
    const Bytes expected = through_end_marker(eeprom_of(*bench, position));
    EXPECT_EQ(result->bytes, expected) << "position " << position;
    auto decoded = wire::decode_sii(expected);
    ASSERT_TRUE(decoded.ok());
    EXPECT_EQ(result->decoded.image, decoded->image);
    EXPECT_TRUE(result->decoded.checksum_ok);
  }
  auto ek1100 = bench->run(read_sii(bench->loop, *bench->bus, test::station_at(0)));
  ASSERT_TRUE(ek1100.ok());
  EXPECT_EQ(ek1100->decoded.image.identity.vendor_id, 0x00000002u);
  EXPECT_EQ(ek1100->decoded.image.identity.product_code, 0x044C2C52u);
  auto servo = bench->run(read_sii(bench->loop, *bench->bus, test::station_at(2)));
  ASSERT_TRUE(servo.ok());
  EXPECT_EQ(servo->decoded.image.standard_mailbox, (wire::SiiMailbox{0x1000, 128, 0x1080, 128}));
}

void expect_real_image(const std::string& name) {
  SCOPED_TRACE(name);
  ECAT_SHARED_DATA_OR_SKIP(path, "eeprom/" + name);
  const Bytes file = ecat::test::read_file(path);
  auto bench = SimBench::make(
      fmt::format("version: 1\nsimulator:\n  slaves:\n    - {{name: d, profile: eeprom, file: "
                  "\"{}\"}}\n",
                  path.string()));
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  auto result = bench->run(read_sii(bench->loop, *bench->bus, test::station_at(0)));
  ASSERT_TRUE(result.ok()) << result.error().describe();
  const Bytes expected = through_end_marker(file);
  ASSERT_FALSE(expected.empty());
  EXPECT_EQ(result->bytes, expected);
  EXPECT_LT(result->bytes.size(), file.size());  // it stopped at the marker, not the EEPROM end
}

TEST(SiiReader, ReadsRealImagesByteForByteUpToTheEndMarker) {
  expect_real_image("ek1100.bin");
  expect_real_image("el2004.bin");
  expect_real_image("el2262.bin");
  expect_real_image("el2828.bin");
}

TEST(SiiReader, ReadsWordRangesWithEitherDataRegisterSize) {
  const Bytes eeprom = profile_eeprom("EL2809");
  ASSERT_GE(eeprom.size(), 256u);
  for (const bool eight : {true, false}) {
    SCOPED_TRACE(eight ? "8-byte data register" : "4-byte data register");
    sim::EscHardware hardware;
    hardware.sii_reads_8_bytes = eight;
    auto bench = bench_with(eeprom, hardware);
    ASSERT_TRUE(bench);
    ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
    // Odd start and length: the reader trims the chunks.
    auto words = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, 0x09, 3));
    ASSERT_TRUE(words.ok()) << words.error().describe();
    EXPECT_EQ(*words, Bytes(eeprom.begin() + 18, eeprom.begin() + 24));
    auto none = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, 0x10, 0));
    ASSERT_TRUE(none.ok());
    EXPECT_TRUE(none->empty());
    const auto before = bench->bus->stats().frames_sent;
    auto image = bench->run(read_sii(bench->loop, *bench->bus, 0x1001));
    ASSERT_TRUE(image.ok()) << image.error().describe();
    EXPECT_EQ(image->bytes, through_end_marker(eeprom));
    // One round trip per chunk (plus the preparation): 8-byte reads need about half as many.
    const auto frames = bench->bus->stats().frames_sent - before;
    const auto chunks = (image->bytes.size() + (eight ? 7 : 3)) / (eight ? 8 : 4);
    EXPECT_EQ(frames, chunks + 1);
  }
}

TEST(SiiReader, PollsASlowEepromInterfaceUntilItIsDone) {
  const Bytes eeprom = profile_eeprom("EL2809");
  sim::EscHardware hardware;
  hardware.sii_busy_ns = 300'000;  // 0.3 ms per command
  auto bench = bench_with(eeprom, hardware);
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  auto image = bench->run(read_sii(bench->loop, *bench->bus, 0x1001));
  ASSERT_TRUE(image.ok()) << image.error().describe();
  EXPECT_EQ(image->bytes, through_end_marker(eeprom));
  // Also with a pause between polls instead of back-to-back round trips.
  SiiReadOptions options;
  options.poll_interval = 100us;
  auto again = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, 0, 64, options));
  ASSERT_TRUE(again.ok()) << again.error().describe();
  EXPECT_EQ(*again, Bytes(eeprom.begin(), eeprom.begin() + 128));
}

TEST(SiiReader, AStuckBusyBitTimesOutNamingStationAndWord) {
  const Bytes eeprom = profile_eeprom("EL2809");
  sim::EscHardware hardware;
  hardware.sii_busy_ns = 60'000'000'000;  // a minute: stuck
  auto bench = bench_with(eeprom, hardware);
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  SiiReadOptions options;
  options.busy_timeout = 30ms;
  const auto start = exec::Clock::now();
  auto result = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, 0x40, 4, options));
  const auto took = exec::Clock::now() - start;
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.error().code(), Errc::timeout);
  EXPECT_EQ(result.error().message(),
            "SII read of slave 0x1001 word 0x0040: EEPROM interface busy for more than 30 ms "
            "after the read command (0x0502 = 0x8140)");
  EXPECT_GE(took, 30ms);
  EXPECT_LT(took, 2s);
  // The next read finds the interface still busy before it can even start.
  auto next = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, 0x00, 1, options));
  ASSERT_FALSE(next.ok());
  EXPECT_EQ(next.error().code(), Errc::timeout);
  EXPECT_EQ(next.error().message(),
            "SII read of slave 0x1001 word 0x0000: EEPROM interface busy for more than 30 ms "
            "before the read command could be issued (0x0502 = 0x8140)");
}

TEST(SiiReader, ReportsAChecksumErrorByNameUnlessToldToIgnoreIt) {
  Bytes eeprom = profile_eeprom("EL2809");
  eeprom[14] ^= 0x5A;  // the CRC of the ESC configuration area no longer matches
  auto bench = bench_with(eeprom, sim::EscHardware{});
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  auto result = bench->run(read_sii(bench->loop, *bench->bus, 0x1001));
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.error().code(), Errc::io_error);
  EXPECT_EQ(result.error().message(),
            "SII read of slave 0x1001 word 0x0000: EEPROM checksum error in the ESC configuration "
            "area (0x0502 = 0x0840)");
  SiiReadOptions options;
  options.ignore_checksum_error = true;
  auto ignored = bench->run(read_sii(bench->loop, *bench->bus, 0x1001, options));
  ASSERT_TRUE(ignored.ok()) << ignored.error().describe();
  EXPECT_EQ(ignored->bytes, through_end_marker(eeprom));
  EXPECT_FALSE(ignored->decoded.checksum_ok);
}

TEST(SiiReader, ReadsPastTheEepromFailAfterTheAcknowledgeRetries) {
  const Bytes eeprom = profile_eeprom("EL2809");
  auto bench = bench_with(eeprom, sim::EscHardware{});
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  const auto word = static_cast<std::uint32_t>(eeprom.size() / 2);
  const auto before = bench->bus->stats().frames_sent;
  auto result = bench->run(read_sii_words(bench->loop, *bench->bus, 0x1001, word, 2));
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.error().code(), Errc::io_error);
  EXPECT_EQ(result.error().message(),
            fmt::format("SII read of slave 0x1001 word {:#06x}: the EEPROM did not acknowledge "
                        "the read (11 attempts, 0x0502 = 0x2040)",
                        word));
  // Preparation, then per attempt a read (and, from the second on, a NOP clearing the error).
  EXPECT_EQ(bench->bus->stats().frames_sent - before, 1u + 11u + 10u);
}

TEST(SiiReader, StopsAtTheImageSizeBound) {
  // A category that claims far more words than the EEPROM has: no end marker in reach.
  Bytes eeprom = profile_eeprom("EL2809");
  const std::size_t first = 2 * wire::sii_word::kFirstCategory;
  wire::store_le16(&eeprom[first], 0x0800);      // a vendor category
  wire::store_le16(&eeprom[first + 2], 0x7FFF);  // 32767 words
  auto bench = bench_with(eeprom, sim::EscHardware{});
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  SiiReadOptions options;
  options.max_image_bytes = 4096;
  const auto before = bench->bus->stats().frames_sent;
  auto result = bench->run(read_sii(bench->loop, *bench->bus, 0x1001, options));
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.error().code(), Errc::out_of_range);
  EXPECT_EQ(result.error().message(),
            "SII of slave 0x1001: no end marker within SiiReadOptions::max_image_bytes (4096 "
            "bytes): category 0x0800 (vendor/unknown) at word 0x0040 with 32767 words needs 65668 "
            "bytes");
  // Nothing beyond the header and the category header was read.
  EXPECT_EQ(bench->bus->stats().frames_sent - before, 1u + 17u);
}

TEST(SiiReader, ConcurrentReadsOfSixteenSlavesShareFrames) {
  std::vector<std::string> profiles{"EK1100"};
  for (int i = 0; i < 15; ++i)
    profiles.push_back(i % 2 == 0 ? "EL2809" : "EL3202");
  // One frame in flight: what the tasks submit meanwhile waits and leaves packed in the next frame.
  bus::BusOptions options;
  options.max_reliable_frames_in_flight = 1;
  auto bench = SimBench::make(ring_of(profiles), options);
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 16)).ok());
  // A wire-like round trip: without it the in-process simulator answers faster than the loop
  // thread resumes the next task (notably under sanitizers), and every frame leaves alone.
  ASSERT_TRUE(bench->server->inject(sim::fault::delay_replies(500us)).ok());
  auto& loop = bench->loop;
  auto& bus = *bench->bus;

  auto sequential = [&]() -> exec::Task<std::vector<Result<SiiReadResult>>> {
    std::vector<Result<SiiReadResult>> out;
    for (std::size_t i = 0; i < 16; ++i)
      out.push_back(co_await read_sii(loop, bus, test::station_at(i)));
    co_return out;
  };
  auto concurrent = [&]() -> exec::Task<std::vector<Result<SiiReadResult>>> {
    std::vector<exec::Task<Result<SiiReadResult>>> tasks;
    for (std::size_t i = 0; i < 16; ++i)
      tasks.push_back(read_sii(loop, bus, test::station_at(i)));
    co_return co_await exec::when_all(loop, std::move(tasks));
  };

  auto start = bus.stats().frames_sent;
  auto one_by_one = bench->run(sequential());
  const auto sequential_frames = bus.stats().frames_sent - start;
  start = bus.stats().frames_sent;
  auto together = bench->run(concurrent());
  const auto concurrent_frames = bus.stats().frames_sent - start;

  ASSERT_EQ(one_by_one.size(), 16u);
  ASSERT_EQ(together.size(), 16u);
  for (std::size_t i = 0; i < 16; ++i) {
    ASSERT_TRUE(one_by_one[i].ok()) << one_by_one[i].error().describe();
    ASSERT_TRUE(together[i].ok()) << together[i].error().describe();
    EXPECT_EQ(together[i]->bytes, one_by_one[i]->bytes);
    EXPECT_EQ(together[i]->bytes, through_end_marker(eeprom_of(*bench, i)));
  }
  // Sequential: one frame per chunk of every slave. Concurrent: the chunks of all slaves ride
  // together, so about as many frames as the longest image has chunks.
  EXPECT_LT(concurrent_frames * 3, sequential_frames)
      << "sequential " << sequential_frames << " frames, concurrent " << concurrent_frames;
}

}  // namespace
}  // namespace ecat::master
