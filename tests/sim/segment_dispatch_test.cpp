// The segment's dispatch indexes (stations and aliases, FMMU ranges, positions) against the
// reference in which every reachable slave processes every datagram: random frames, the same
// replies, the same registers and RAM, the same time in every ESC once both are advanced to the
// same moment (the indexed segment advances only the ESCs a frame addresses or that have
// time-driven work due).
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::sim {
namespace {

namespace reg = wire::reg;
using wire::Command;

constexpr std::size_t kSlaves = 12;

// A line with two branches: slaves 4 and 9 hang off ports 2 and 3 of earlier slaves.
std::unique_ptr<Segment> make_segment(bool reference) {
  auto segment = std::make_unique<Segment>();
  for (std::size_t i = 0; i < kSlaves; ++i) {
    DeviceConfig config;
    config.profile = i % 3 == 0 ? "EL1809" : (i % 3 == 1 ? "EL2809" : "generic");
    auto esc = make_device(config);
    EXPECT_TRUE(esc.ok());
    Attachment at;
    if (i == 4) at = Attachment{1, 2, 5};
    if (i == 9) at = Attachment{6, 3, 5};
    EXPECT_TRUE(segment->add_slave("s" + std::to_string(i), std::move(*esc), at).ok());
  }
  segment->set_reference_dispatch(reference);
  return segment;
}

struct FrameMaker {
  std::mt19937 rng;
  explicit FrameMaker(unsigned seed) : rng(seed) {}

  unsigned pick(unsigned n) { return std::uniform_int_distribution<unsigned>(0, n - 1)(rng); }

  std::uint16_t station() {
    static constexpr std::array<std::uint16_t, 6> kStations{0, 0x1001, 0x1002, 0x1005, 0x2000, 7};
    return kStations[pick(kStations.size())];
  }

  // A register or RAM range that matters to dispatch or is plainly observable.
  std::pair<std::uint16_t, std::uint16_t> physical(std::vector<std::uint8_t>& data) {
    data.clear();
    switch (pick(9)) {
      case 0: {  // station address
        const std::uint16_t s = station();
        data = {static_cast<std::uint8_t>(s), static_cast<std::uint8_t>(s >> 8)};
        return {reg::kStationAddress, 2};
      }
      case 1: {  // alias
        const std::uint16_t s = station();
        data = {static_cast<std::uint8_t>(s), static_cast<std::uint8_t>(s >> 8)};
        return {reg::kStationAlias, 2};
      }
      case 2:  // alias enable
        data = {static_cast<std::uint8_t>(pick(2))};
        return {reg::kDlAliasControl, 1};
      case 3: {  // an FMMU onto RAM, logical ranges overlapping often
        wire::FmmuConfig f;
        f.logical_start = pick(24);
        f.length = static_cast<std::uint16_t>(1 + pick(4));
        f.logical_start_bit = static_cast<std::uint8_t>(pick(2) * 3);
        f.logical_stop_bit = static_cast<std::uint8_t>(pick(8));
        f.physical_start = static_cast<std::uint16_t>(0x1000 + pick(8));
        f.type = pick(3) == 0 ? wire::FmmuType::read
                              : (pick(2) == 0 ? wire::FmmuType::write : wire::FmmuType::read_write);
        f.active = pick(5) != 0;
        const auto bytes = f.encode();
        data.assign(bytes.begin(), bytes.end());
        return {reg::fmmu(pick(3)), static_cast<std::uint16_t>(bytes.size())};
      }
      case 4:  // process RAM
        for (int i = 0; i < 4; ++i)
          data.push_back(static_cast<std::uint8_t>(rng()));
        return {static_cast<std::uint16_t>(0x1000 + pick(6)), 4};
      case 5:  // AL control / status
        data = {static_cast<std::uint8_t>(1 + pick(2)), 0};
        return {reg::kAlControl, 2};
      case 6:
        data = {0, 0, 0, 0, 0, 0};
        return {reg::kAlStatus, 6};
      case 7:  // DC receive time latch and system time
        data = {1, 2, 3, 4, 5, 6, 7, 8};
        return {pick(2) == 0 ? reg::kDcReceiveTimePort0 : reg::kDcSystemTime, 8};
      default:  // port loop control, rarely closing a port
        data = {static_cast<std::uint8_t>(pick(6) == 0 ? 0x30 : 0x00)};
        return {reg::kDlPortControl, 1};
    }
  }

  std::vector<std::uint8_t> frame() {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    const unsigned count = 1 + pick(6);
    std::vector<std::uint8_t> data;
    std::size_t invalid_at = 99;
    for (unsigned k = 0; k < count; ++k) {
      wire::DatagramHeader h;
      h.index = static_cast<std::uint8_t>(k);
      const auto [ado, length] = physical(data);
      switch (pick(8)) {
        case 0: {
          static constexpr std::array<Command, 3> kAp{Command::aprd, Command::apwr, Command::aprw};
          h.command = kAp[pick(3)];
          h.address = wire::physical_address(
              wire::position_adp(static_cast<std::uint16_t>(pick(kSlaves + 3))), ado);
          break;
        }
        case 1:
        case 2: {
          static constexpr std::array<Command, 3> kFp{Command::fprd, Command::fpwr, Command::fprw};
          h.command = kFp[pick(3)];
          h.address = wire::physical_address(station(), ado);
          break;
        }
        case 3: {
          static constexpr std::array<Command, 5> kAll{Command::brd, Command::bwr, Command::brw,
                                                       Command::armw, Command::frmw};
          h.command = kAll[pick(5)];
          const std::uint16_t adp = h.command == Command::frmw ? station() : 0;
          h.address = wire::physical_address(adp, ado);
          break;
        }
        case 4:
        case 5: {
          static constexpr std::array<Command, 3> kL{Command::lrd, Command::lwr, Command::lrw};
          h.command = kL[pick(3)];
          h.address = pick(28);
          data.resize(pick(10));
          for (auto& b : data)
            b = static_cast<std::uint8_t>(rng());
          (void)builder.add(wire::DatagramHeader{h.command, h.index, h.address,
                                                 static_cast<std::uint16_t>(data.size())},
                            wire::Bytes(data));
          continue;
        }
        case 6:
          h.command = Command::nop;
          break;
        default:
          h.command = Command::fprd;
          h.address = wire::physical_address(station(), ado);
          invalid_at = k;
          break;
      }
      h.length = length;
      (void)builder.add(h, wire::Bytes(data));
    }
    const auto built = builder.finish();
    std::vector<std::uint8_t> frame(built.begin(), built.end());
    if (invalid_at != 99) {
      // Turn one datagram's command into one no ESC knows.
      auto decoded = wire::decode_frame(frame);
      std::size_t k = 0;
      if (decoded) {
        for (const wire::DatagramView view : *decoded.frame) {
          if (k++ == invalid_at) {
            const auto offset = static_cast<std::size_t>(view.data.data() - frame.data()) -
                                wire::kDatagramHeaderSize;
            frame[offset] = 0x3E;
          }
        }
      }
    }
    return frame;
  }
};

// Advances both to `now` first: the reference has advanced every ESC to each frame's passing
// time, the indexed segment only those the frames addressed or that had work due.
void expect_same_escs(Segment& a, Segment& b, int frame, std::int64_t now) {
  a.advance(now);
  b.advance(now);
  for (std::size_t i = 0; i < a.size(); ++i) {
    const auto ma = a.esc(i).memory();
    const auto mb = b.esc(i).memory();
    ASSERT_EQ(std::vector<std::uint8_t>(ma.begin(), ma.end()),
              std::vector<std::uint8_t>(mb.begin(), mb.end()))
        << "slave " << i << " after frame " << frame;
    ASSERT_EQ(a.esc(i).now_ns(), b.esc(i).now_ns()) << "slave " << i << " after frame " << frame;
  }
}

TEST(SegmentDispatch, IndexedDispatchMatchesEverySlaveProcessingEveryDatagram) {
  for (unsigned seed = 1; seed <= 12; ++seed) {
    auto indexed = make_segment(false);
    auto reference = make_segment(true);
    FrameMaker maker(seed);
    std::int64_t now = 1'000'000;
    bool stations_seen = false;  // the frames did give stations on the way
    bool fmmus_seen = false;     // ... and FMMUs
    for (int n = 0; n < 1500; ++n) {
      const auto frame = maker.frame();
      auto a = frame;
      auto b = frame;
      now += 1000 + static_cast<std::int64_t>(maker.pick(400'000));
      const bool replied_a = indexed->process_frame(a, now);
      const bool replied_b = reference->process_frame(b, now);
      ASSERT_EQ(replied_a, replied_b) << "seed " << seed << " frame " << n;
      ASSERT_EQ(a, b) << "seed " << seed << " frame " << n;
      if (n % 50 == 0 || n == 1499) {
        now += 1'000'000;  // past every passing time of the frames so far
        expect_same_escs(*indexed, *reference, n, now);
        if (HasFatalFailure()) return;
        for (std::size_t i = 0; i < indexed->size(); ++i) {
          stations_seen |= indexed->esc(i).station_address() != 0;
          fmmus_seen |= indexed->esc(i).fmmu(0).active;
        }
      }
    }
    EXPECT_TRUE(stations_seen) << "seed " << seed;
    EXPECT_TRUE(fmmus_seen) << "seed " << seed;
  }
}

// A slave whose station address or FMMU changes in the middle of a frame answers the datagrams
// after the change by its new address or mapping, as before the indexes.
TEST(SegmentDispatch, AddressAndFmmuChangesInsideAFrameApplyToTheRestOfIt) {
  auto segment = make_segment(false);
  std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
  wire::FrameBuilder builder(buffer);
  // Slave 2 gets station 0x3003 and an FMMU mapping logical 0x100 onto 0x1000, then is read by
  // both in the same frame.
  wire::FmmuConfig f;
  f.logical_start = 0x100;
  f.length = 2;
  f.physical_start = 0x1000;
  f.type = wire::FmmuType::read_write;
  f.active = true;
  const auto fmmu = f.encode();
  (void)builder.add({Command::apwr, 0, wire::physical_address(wire::position_adp(2), 0x0010), 2},
                    wire::Bytes(std::vector<std::uint8_t>{0x03, 0x30}));
  (void)builder.add({Command::fpwr, 1, wire::physical_address(0x3003, reg::fmmu(0)),
                     static_cast<std::uint16_t>(fmmu.size())},
                    wire::Bytes(fmmu));
  (void)builder.add({Command::fprd, 2, wire::physical_address(0x3003, reg::kStationAddress), 2});
  (void)builder.add({Command::lrw, 3, 0x100, 2});
  const auto built = builder.finish();
  std::vector<std::uint8_t> frame(built.begin(), built.end());
  ASSERT_TRUE(segment->process_frame(frame, 1'000'000));
  const auto decoded = wire::decode_frame(frame);
  ASSERT_TRUE(decoded);
  std::vector<std::uint16_t> wkcs;
  for (const wire::DatagramView view : *decoded.frame)
    wkcs.push_back(view.wkc);
  EXPECT_EQ(wkcs, (std::vector<std::uint16_t>{1, 1, 1, 3}));
  // The next frame finds the slave through the rebuilt indexes.
  std::array<std::uint8_t, wire::kMaxFrameSize> buffer2{};
  wire::FrameBuilder builder2(buffer2);
  (void)builder2.add({Command::fprd, 0, wire::physical_address(0x3003, reg::kStationAddress), 2});
  (void)builder2.add({Command::lrd, 1, 0x100, 2});
  const auto built2 = builder2.finish();
  std::vector<std::uint8_t> frame2(built2.begin(), built2.end());
  ASSERT_TRUE(segment->process_frame(frame2, 2'000'000));
  const auto decoded2 = wire::decode_frame(frame2);
  ASSERT_TRUE(decoded2);
  wkcs.clear();
  for (const wire::DatagramView view : *decoded2.frame)
    wkcs.push_back(view.wkc);
  EXPECT_EQ(wkcs, (std::vector<std::uint16_t>{1, 1}));
}

// Position addressing: the ADP that comes back counts every reachable slave, with or without a
// slave at the position.
TEST(SegmentDispatch, PositionAddressedDatagramsComeBackIncrementedBySlaveCount) {
  auto segment = make_segment(false);
  for (const std::uint16_t position : {std::uint16_t{0}, std::uint16_t{5}, std::uint16_t{40}}) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    (void)builder.add(
        {Command::aprd, 0, wire::physical_address(wire::position_adp(position), 0x0000), 1});
    const auto built = builder.finish();
    std::vector<std::uint8_t> frame(built.begin(), built.end());
    ASSERT_TRUE(segment->process_frame(frame, 1'000'000));
    const auto decoded = wire::decode_frame(frame);
    ASSERT_TRUE(decoded);
    const wire::DatagramView view = *(*decoded.frame).begin();
    EXPECT_EQ(view.header.adp(),
              static_cast<std::uint16_t>(wire::position_adp(position) + kSlaves));
    EXPECT_EQ(view.wkc, position < kSlaves ? 1 : 0);
  }
}

// A frame advances the ESCs it addresses and those with time-driven work due, not the others: an
// EEPROM write running on a slave completes without a datagram for it, an idle slave no datagram
// addresses keeps its time until one does (then it is advanced first).
TEST(SegmentDispatch, AFrameAdvancesOnlyAddressedSlavesAndThoseWithWorkDue) {
  auto segment = make_segment(false);
  const auto frame_of = [](wire::DatagramHeader header, std::vector<std::uint8_t> data) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    (void)builder.add(header, wire::Bytes(data));
    const auto built = builder.finish();
    return std::vector<std::uint8_t>(built.begin(), built.end());
  };
  // The first slave starts an EEPROM write of word 0x40 (0x0502: write enable + write command,
  // 0x0504: address 0x40, 0x0508: the data), busy for the EEPROM's write cycle.
  auto start_write = frame_of(
      {Command::apwr, 0, wire::physical_address(wire::position_adp(0), reg::kSiiControl), 10},
      {0x01, 0x02, 0x40, 0x00, 0x00, 0x00, 0x34, 0x12, 0x00, 0x00});
  const auto order = segment->processing_order();
  ASSERT_EQ(order.size(), kSlaves);
  Esc& writing = segment->esc(order[0]);
  Esc& polled = segment->esc(order[3]);
  Esc& idle = segment->esc(order[5]);
  ASSERT_TRUE(segment->process_frame(start_write, 1'000'000));
  ASSERT_NE(writing.read_u16(reg::kSiiControl) & 0x8000, 0) << "the write is running";
  const std::int64_t idle_since = idle.now_ns();
  // 50 ms later a frame for the fourth slave only: the first one's write completes, the sixth is
  // not touched.
  auto poll = frame_of(
      {Command::aprd, 0, wire::physical_address(wire::position_adp(3), reg::kAlStatus), 2}, {});
  ASSERT_TRUE(segment->process_frame(poll, 51'000'000));
  EXPECT_EQ(writing.read_u16(reg::kSiiControl) & 0x8000, 0) << "the write completed";
  EXPECT_GE(polled.now_ns(), 51'000'000);
  EXPECT_EQ(idle.now_ns(), idle_since);
  // Addressed, the sixth catches up before it processes the datagram.
  auto read5 = frame_of(
      {Command::aprd, 0, wire::physical_address(wire::position_adp(5), reg::kAlStatus), 2}, {});
  ASSERT_TRUE(segment->process_frame(read5, 52'000'000));
  EXPECT_GE(idle.now_ns(), 52'000'000);
}

// A slave being written by station is advanced by the frame that addresses it (no separate check
// for it), and its time-driven work (the EEPROM write) completes before it processes the
// datagram, as when every due slave was advanced first.
TEST(SegmentDispatch, AnAddressedSlaveWithWorkDueFinishesItBeforeProcessing) {
  auto segment = make_segment(false);
  const auto frame_of = [](wire::DatagramHeader header, std::vector<std::uint8_t> data) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    (void)builder.add(header, wire::Bytes(data));
    const auto built = builder.finish();
    return std::vector<std::uint8_t>(built.begin(), built.end());
  };
  const auto order = segment->processing_order();
  Esc& writing = segment->esc(order[0]);
  // Station 0x1001 for the first slave, then an EEPROM write on it.
  auto assign = frame_of(
      {Command::apwr, 0, wire::physical_address(wire::position_adp(0), reg::kStationAddress), 2},
      {0x01, 0x10});
  ASSERT_TRUE(segment->process_frame(assign, 1'000'000));
  auto start_write =
      frame_of({Command::fpwr, 0, wire::physical_address(0x1001, reg::kSiiControl), 10},
               {0x01, 0x02, 0x40, 0x00, 0x00, 0x00, 0x34, 0x12, 0x00, 0x00});
  ASSERT_TRUE(segment->process_frame(start_write, 2'000'000));
  ASSERT_NE(writing.read_u16(reg::kSiiControl) & 0x8000, 0) << "the write is running";
  // 50 ms later its SII status, read by station: the write has completed when it is read.
  auto read = frame_of({Command::fprd, 0, wire::physical_address(0x1001, reg::kSiiControl), 2}, {});
  ASSERT_TRUE(segment->process_frame(read, 52'000'000));
  const auto view = wire::decode_frame(read);
  ASSERT_TRUE(view);
  const wire::DatagramView d = *view.frame->begin();
  EXPECT_EQ(d.wkc, 1);
  EXPECT_EQ(wire::load_le16(d.data.data()) & 0x8000, 0) << "read while still busy";
}

// add_slave updates the DL status of the new slave and its parent only; the result is what a
// recomputation over every slave gives (set_link recomputes all).
TEST(SegmentDispatch, DlStatusBuiltSlaveBySlaveMatchesAFullRecomputation) {
  auto segment = make_segment(false);
  std::vector<std::uint16_t> built;
  for (std::size_t i = 0; i < segment->size(); ++i)
    built.push_back(segment->esc(i).read_u16(reg::kDlStatus));
  segment->set_link(0, 0, true);  // no change; recomputes every slave's DL status
  for (std::size_t i = 0; i < segment->size(); ++i) {
    EXPECT_EQ(segment->esc(i).read_u16(reg::kDlStatus), built[i]) << "slave " << i;
  }
  // The branch parents show their extra ports linked.
  EXPECT_NE(built[1] & (1u << (4 + 2)), 0u) << "port 2 of s1 carries s4";
  EXPECT_NE(built[6] & (1u << (4 + 3)), 0u) << "port 3 of s6 carries s9";
  EXPECT_EQ(segment->find("s9"), std::optional<std::size_t>(9));
  EXPECT_FALSE(segment->find("s12").has_value());
  DeviceConfig config;
  auto esc = make_device(config);
  ASSERT_TRUE(esc.ok());
  EXPECT_FALSE(segment->add_slave("s3", std::move(*esc)).ok()) << "a second s3";
}

}  // namespace
}  // namespace ecat::sim
