// The SII writer (master/sii_writer.hpp) against the simulated ESC: words, verify, checksum,
// alias, write-enable and acknowledge errors, busy polling, refused images; and the register
// sequence on the wire, recorded at the master's end of the in-process link.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/link/link.hpp>
#include <ecat/master/sii_writer.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
namespace reg = wire::reg;
namespace sc = wire::sii_control;
using wire::Command;

constexpr std::uint16_t kStation = 0x1001;

struct RecordedDatagram {
  Command command = Command::nop;
  std::uint16_t adp = 0;
  std::uint16_t ado = 0;
  std::vector<std::uint8_t> data;
  std::size_t frame = 0;  // which frame it went in
};

// The master's end of the link, recording every datagram it sends.
class RecordingLink final : public link::Link {
 public:
  explicit RecordingLink(std::unique_ptr<link::Link> inner) : inner_(std::move(inner)) {}
  Result<void> send(wire::Bytes frame) override {
    if (auto decoded = wire::decode_frame(frame)) {
      std::lock_guard lock(mutex_);
      for (const wire::DatagramView d : *decoded.frame) {
        sent_.push_back({d.header.command, d.header.adp(), d.header.ado(),
                         std::vector<std::uint8_t>(d.data.begin(), d.data.end()), frames_});
      }
      ++frames_;
    }
    return inner_->send(frame);
  }
  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    return inner_->receive(timeout);
  }
  void interrupt() override { inner_->interrupt(); }
  void close() override { inner_->close(); }
  Result<void> reopen() override { return inner_->reopen(); }
  std::string name() const override { return "recording:" + inner_->name(); }
  link::LinkStats stats() const override { return inner_->stats(); }
  std::size_t max_frame_size() const override { return inner_->max_frame_size(); }

  std::vector<RecordedDatagram> take() {
    std::lock_guard lock(mutex_);
    return std::exchange(sent_, {});
  }

 private:
  std::unique_ptr<link::Link> inner_;
  std::mutex mutex_;
  std::vector<RecordedDatagram> sent_;
  std::size_t frames_ = 0;
};

// Clears bit 0 (write enable) of every write of 0x0502 on its way to the ESC: a master that
// forgot it, as the ESC sees it.
class StripWriteEnable final : public sim::SegmentHooks {
 public:
  bool before_frame(std::span<std::uint8_t> frame, std::int64_t) override {
    auto decoded = wire::decode_frame(frame);
    if (!decoded) return true;
    std::size_t offset = wire::kFrameHeaderSize;
    for (const wire::DatagramView d : *decoded.frame) {
      if ((d.header.command == Command::fpwr || d.header.command == Command::apwr) &&
          d.header.ado() == reg::kSiiControl) {
        frame[offset + wire::kDatagramHeaderSize] &= static_cast<std::uint8_t>(~sc::kWriteEnable);
      }
      offset += wire::kDatagramHeaderSize + d.header.length + 2;
    }
    return true;
  }
};

std::vector<std::uint8_t> test_eeprom(std::uint16_t alias = 0) {
  wire::SiiImage image;
  image.pdi_control = 0x0C05;
  image.station_alias = alias;
  image.identity = {0x0000'0ACE, 0x99, 1, 5};
  image.strings = {"Writable"};
  auto bytes = wire::encode_sii(image);
  EXPECT_TRUE(bytes.ok());
  bytes->resize(2048, 0xFF);
  wire::store_le16(&(*bytes)[wire::sii_word::kEepromSize * 2], 0x000F);  // 16 kbit
  return *bytes;
}

class SiiWriter : public ::testing::Test {
 protected:
  void SetUp() override { start(); }
  void TearDown() override {
    if (bus) bus->stop();
    if (server) server->stop();
  }
  void start(std::int64_t write_busy_ns = 200'000, bool reads_8_bytes = true) {
    auto segment = std::make_unique<sim::Segment>();
    sim::EscHardware hw;
    hw.sii_busy_ns = 20'000;
    hw.sii_write_busy_ns = write_busy_ns;
    hw.sii_reads_8_bytes = reads_8_bytes;
    ASSERT_TRUE(segment->add_slave("s", std::make_unique<sim::Esc>(hw, test_eeprom(), nullptr)));
    server = std::make_unique<sim::SimServer>(std::move(segment));
    auto link = server->serve_memory();
    ASSERT_TRUE(link) << link.error().describe();
    auto recording = std::make_unique<RecordingLink>(std::move(*link));
    recorder = recording.get();
    bus = std::make_unique<bus::Bus>(std::move(recording), bus::BusOptions{});
    ASSERT_TRUE(bus->start());
    ASSERT_TRUE(run(test::assign_stations(loop, *bus, 1)));
    recorder->take();
  }
  template <class T>
  T run(exec::Task<T> task) {
    std::optional<T> result;
    exec::spawn(loop, std::move(task), [&](T&& value) {
      result.emplace(std::move(value));
      loop.stop();
    });
    const auto watchdog = loop.call_after(20s, [this] { loop.stop(); });
    loop.run();
    loop.cancel(watchdog);
    loop.reset();
    if (!result) {
      ADD_FAILURE() << "task did not finish";
      std::abort();
    }
    return std::move(*result);
  }
  template <class F>
  decltype(auto) with_esc(F&& f) {
    return server->with_segment([&](sim::Segment& s, auto&) { return f(s.esc(0)); });
  }
  std::uint16_t eeprom_word(std::size_t word) {
    return with_esc([&](sim::Esc& e) { return wire::load_le16(&e.eeprom()[word * 2]); });
  }
  Result<SiiWriteReport> write(std::uint32_t first, std::vector<std::uint16_t> words,
                               SiiWriteOptions options = {}) {
    return run(write_sii_words(loop, *bus, SiiTarget::station(kStation), first, std::move(words),
                               std::move(options)));
  }

  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<bus::Bus> bus;
  RecordingLink* recorder = nullptr;
  exec::EventLoop loop;
};

TEST_F(SiiWriter, WritesOnlyTheWordsThatDifferAndVerifiesThem) {
  const std::uint16_t same = eeprom_word(0x40);
  std::vector<SiiWriteProgress> progress;
  SiiWriteOptions options;
  options.progress = [&](const SiiWriteProgress& p) { progress.push_back(p); };
  auto report = write(0x40, {same, 0x1234, 0x5678}, options);
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_EQ(report->words_written, 2u);
  EXPECT_EQ(report->words_unchanged, 1u);
  EXPECT_FALSE(report->checksum_written);
  EXPECT_EQ(report->eeprom_bytes, 2048u);
  EXPECT_EQ(eeprom_word(0x41), 0x1234);
  EXPECT_EQ(eeprom_word(0x42), 0x5678);
  ASSERT_EQ(progress.size(), 3u);
  EXPECT_EQ(progress.back().done, 3u);
  EXPECT_EQ(progress.back().total, 3u);
  EXPECT_EQ(progress.back().word, 0x42u);
  // Only two write commands went out.
  const auto sent = recorder->take();
  const auto writes = std::count_if(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.command == Command::fpwr && d.ado == reg::kSiiControl &&
           d.data == std::vector<std::uint8_t>{0x01, 0x02};
  });
  EXPECT_EQ(writes, 2);
  // force_all writes the unchanged word too.
  SiiWriteOptions force;
  force.force_all = true;
  auto forced = write(0x40, {same}, force);
  ASSERT_TRUE(forced) << forced.error().describe();
  EXPECT_EQ(forced->words_written, 1u);
}

TEST_F(SiiWriter, RegisterSequencePerWordIsTheDatasheetOne) {
  auto report = write(0x50, {0xA55A});
  ASSERT_TRUE(report) << report.error().describe();
  const auto sent = recorder->take();
  ASSERT_GE(sent.size(), 3u);
  // Ownership for ECAT first: force (bit 1), then ECAT (0), then the status.
  EXPECT_EQ(sent[0].command, Command::fpwr);
  EXPECT_EQ(sent[0].ado, reg::kSiiAccess);
  EXPECT_EQ(sent[0].data, std::vector<std::uint8_t>{0x02});
  EXPECT_EQ(sent[1].ado, reg::kSiiAccess);
  EXPECT_EQ(sent[1].data, std::vector<std::uint8_t>{0x00});
  EXPECT_EQ(sent[2].command, Command::fprd);
  EXPECT_EQ(sent[2].ado, reg::kSiiControl);
  // The write: data, address, control 0x0201, status, in that order in one frame.
  auto it = std::find_if(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.command == Command::fpwr && d.ado == reg::kSiiData;
  });
  ASSERT_NE(it, sent.end());
  ASSERT_GE(sent.end() - it, 4);
  EXPECT_EQ(it[0].adp, kStation);
  EXPECT_EQ(it[0].data, (std::vector<std::uint8_t>{0x5A, 0xA5}));
  EXPECT_EQ(it[1].command, Command::fpwr);
  EXPECT_EQ(it[1].ado, reg::kSiiAddress);
  EXPECT_EQ(it[1].data, (std::vector<std::uint8_t>{0x50, 0x00, 0x00, 0x00}));
  EXPECT_EQ(it[2].command, Command::fpwr);
  EXPECT_EQ(it[2].ado, reg::kSiiControl);
  EXPECT_EQ(it[2].data, (std::vector<std::uint8_t>{0x01, 0x02})) << "write enable + write, once";
  EXPECT_EQ(it[3].command, Command::fprd);
  EXPECT_EQ(it[3].ado, reg::kSiiControl);
  EXPECT_EQ(it[0].frame, it[3].frame);
  // Afterwards: status polls, then the read-back (address, read command 0x0100).
  auto verify = std::find_if(it + 4, sent.end(), [](const RecordedDatagram& d) {
    return d.command == Command::fpwr && d.ado == reg::kSiiControl &&
           d.data == std::vector<std::uint8_t>{0x00, 0x01};
  });
  ASSERT_NE(verify, sent.end()) << "the written word is read back";
  EXPECT_EQ(eeprom_word(0x50), 0xA55A);
}

TEST_F(SiiWriter, BusyIsPolledUntilTheWriteCycleEnds) {
  TearDown();
  start(3'000'000);  // 3 ms per word
  auto report = write(0x60, {0x0001});
  ASSERT_TRUE(report) << report.error().describe();
  const auto sent = recorder->take();
  const auto polls = std::count_if(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.command == Command::fprd && d.ado == reg::kSiiControl;
  });
  EXPECT_GE(polls, 3) << "status read with the command, then polled while busy";
  EXPECT_EQ(eeprom_word(0x60), 0x0001);
}

TEST_F(SiiWriter, StuckBusyTimesOut) {
  TearDown();
  start(60'000'000'000);  // a minute
  SiiWriteOptions options;
  options.busy_timeout = 20ms;
  auto report = write(0x60, {0x0002}, options);
  ASSERT_FALSE(report);
  EXPECT_EQ(report.error().code(), Errc::timeout);
  EXPECT_NE(report.error().describe().find("busy for more than 20 ms"), std::string::npos)
      << report.error().describe();
}

TEST_F(SiiWriter, ChecksumIsFixedWhenTheConfigurationAreaChanges) {
  auto report = write(wire::sii_word::kPdiConfiguration, {0x0102});
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_TRUE(report->checksum_written);
  EXPECT_EQ(report->words_written, 2u);
  const auto image = with_esc([](sim::Esc& e) {
    return std::vector<std::uint8_t>(e.eeprom().begin(), e.eeprom().begin() + 16);
  });
  EXPECT_EQ(image[14], wire::sii_crc8(wire::Bytes(image).first(14)));
  EXPECT_EQ(image[15], 0);
  // The ESC loads the area at the next power-up: no checksum error, the new value in 0x0150.
  with_esc([](sim::Esc& e) { e.power_cycle(e.now_ns()); });
  EXPECT_EQ(with_esc([](sim::Esc& e) { return e.read_u16(reg::kSiiControl); }) & sc::kChecksumError,
            0);
  EXPECT_EQ(with_esc([](sim::Esc& e) { return e.read_u16(reg::kPdiConfiguration); }), 0x0102);
  // Without fix_checksum the word 7 stays as it is (and the ESC reports the mismatch).
  ASSERT_TRUE(run(test::assign_stations(loop, *bus, 1)));
  SiiWriteOptions raw;
  raw.fix_checksum = false;
  ASSERT_TRUE(write(wire::sii_word::kPdiConfiguration, {0x0304}, raw));
  with_esc([](sim::Esc& e) { e.power_cycle(e.now_ns()); });
  EXPECT_NE(with_esc([](sim::Esc& e) { return e.read_u16(reg::kSiiControl); }) & sc::kChecksumError,
            0);
}

TEST_F(SiiWriter, AliasGoesToWord4WithItsChecksumAndTheRegisterIsReadOnly) {
  SiiWriteOptions options;
  options.write_alias_register = true;
  auto report = run(write_sii_alias(loop, *bus, SiiTarget::station(kStation), 0x0777, options));
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_EQ(eeprom_word(wire::sii_word::kStationAlias), 0x0777);
  EXPECT_TRUE(report->checksum_written);
  ASSERT_TRUE(report->alias_register.has_value());
  EXPECT_FALSE(*report->alias_register) << "0x0012 is read-only from EtherCAT";
  EXPECT_EQ(with_esc([](sim::Esc& e) { return e.station_alias(); }), 0);
  with_esc([](sim::Esc& e) { e.power_cycle(e.now_ns()); });
  EXPECT_EQ(with_esc([](sim::Esc& e) { return e.station_alias(); }), 0x0777);
}

TEST_F(SiiWriter, PositionAddressingWorksWithoutAStation) {
  with_esc([](sim::Esc& e) { e.power_cycle(e.now_ns()); });  // station 0 again
  auto report = run(write_sii_alias(loop, *bus, SiiTarget::position(0), 0x0042, SiiWriteOptions{}));
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_EQ(eeprom_word(wire::sii_word::kStationAlias), 0x0042);
  const auto sent = recorder->take();
  EXPECT_TRUE(std::all_of(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.command == Command::apwr || d.command == Command::aprd;
  }));
}

TEST_F(SiiWriter, MissingWriteEnableIsReportedAsBit14) {
  StripWriteEnable strip;
  server->with_segment([&](sim::Segment& s, auto&) { s.set_hooks(&strip); });
  auto report = write(0x40, {0x4444});
  // The server's own hooks (its fault injector) back.
  server->with_segment([&](sim::Segment& s, sim::FaultInjector& f) { s.set_hooks(&f); });
  ASSERT_FALSE(report);
  EXPECT_EQ(report.error().code(), Errc::io_error);
  EXPECT_NE(report.error().describe().find("bit 14"), std::string::npos)
      << report.error().describe();
  EXPECT_NE(eeprom_word(0x40), 0x4444);
  // The next write clears the error with a NOP first and succeeds.
  auto again = write(0x40, {0x4444});
  ASSERT_TRUE(again) << again.error().describe();
  EXPECT_EQ(eeprom_word(0x40), 0x4444);
}

TEST_F(SiiWriter, AcknowledgeErrorsAreRetriedABoundedNumberOfTimes) {
  with_esc([](sim::Esc& e) { e.inject_sii_acknowledge_errors(2, true); });
  SiiWriteOptions options;
  options.force_all = true;  // no compare read: the NACKs hit the write itself
  auto report = write(0x44, {0x1357}, options);
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_EQ(eeprom_word(0x44), 0x1357);
  const auto sent = recorder->take();
  const auto writes = std::count_if(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.ado == reg::kSiiControl && d.data == std::vector<std::uint8_t>{0x01, 0x02};
  });
  EXPECT_EQ(writes, 3) << "two NACKed attempts, then the one that took";

  with_esc([](sim::Esc& e) { e.inject_sii_acknowledge_errors(50, true); });
  options.acknowledge_retries = 2;
  auto failed = write(0x45, {0x2468}, options);
  with_esc([](sim::Esc& e) { e.inject_sii_acknowledge_errors(0); });
  ASSERT_FALSE(failed);
  EXPECT_NE(failed.error().describe().find("did not acknowledge the write (3 attempts"),
            std::string::npos)
      << failed.error().describe();
}

TEST_F(SiiWriter, BadImagesAreRefusedBeforeAnythingIsWritten) {
  const std::vector<std::uint8_t> odd(7, 0);
  auto r1 = run(write_sii_image(loop, *bus, SiiTarget::station(kStation), odd));
  ASSERT_FALSE(r1);
  EXPECT_EQ(r1.error().code(), Errc::invalid_argument);
  EXPECT_NE(r1.error().describe().find("7 bytes"), std::string::npos);
  auto r2 = run(write_sii_image(loop, *bus, SiiTarget::station(kStation), {}));
  ASSERT_FALSE(r2);
  EXPECT_EQ(r2.error().code(), Errc::invalid_argument);
  const std::vector<std::uint8_t> too_big(4096, 0);
  auto r3 = run(write_sii_image(loop, *bus, SiiTarget::station(kStation), too_big));
  ASSERT_FALSE(r3);
  EXPECT_EQ(r3.error().code(), Errc::invalid_argument);
  EXPECT_NE(r3.error().describe().find("do not fit the EEPROM of 2048 bytes"), std::string::npos)
      << r3.error().describe();
  const auto sent = recorder->take();
  EXPECT_TRUE(std::none_of(sent.begin(), sent.end(), [](const RecordedDatagram& d) {
    return d.ado == reg::kSiiControl && d.data.size() == 2 && (d.data[1] & 0x07) == 0x02;
  })) << "no write command went out";
}

TEST_F(SiiWriter, WholeImageRoundTripsWith4ByteReads) {
  TearDown();
  start(50'000, false);
  auto image = test_eeprom(0x0101);
  image[0x100] = 0xAB;  // somewhere in the categories
  auto report = run(write_sii_image(loop, *bus, SiiTarget::station(kStation), image));
  ASSERT_TRUE(report) << report.error().describe();
  EXPECT_EQ(report->words_written, 3u) << "alias, checksum and the changed word";
  const auto now = with_esc(
      [](sim::Esc& e) { return std::vector<std::uint8_t>(e.eeprom().begin(), e.eeprom().end()); });
  EXPECT_EQ(now, image);
}

}  // namespace
}  // namespace ecat::master
