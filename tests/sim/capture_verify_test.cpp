// Rebuilding simulator profiles from captures and replaying captures against the simulator:
// the capture reader (pcap, pcapng), request/reply pairing, the exclusion rules on small captures
// this test writes itself, and — when the shared real-device captures are there — the fidelity
// figures the simulator reaches on each of them (exact counts, so any regression shows).
#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/capture/capture_file.hpp>
#include <ecat/sim/capture_profile.hpp>
#include <ecat/sim/capture_verify.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/shared_data.hpp"

namespace ecat::sim {
namespace {

using wire::Command;
namespace reg = wire::reg;

// ---- Building small captures ----------------------------------------------------------------

struct Dg {
  Command command = Command::nop;
  std::uint8_t index = 0;
  std::uint32_t address = 0;
  std::vector<std::uint8_t> data;
  std::uint16_t wkc = 0;
};

std::vector<std::uint8_t> encode_frame(const std::vector<Dg>& datagrams) {
  std::vector<std::uint8_t> f(2);
  for (std::size_t i = 0; i < datagrams.size(); ++i) {
    const Dg& d = datagrams[i];
    const std::size_t at = f.size();
    f.resize(at + 10 + d.data.size() + 2);
    f[at] = static_cast<std::uint8_t>(d.command);
    f[at + 1] = d.index;
    wire::store_le32(&f[at + 2], d.address);
    const auto more = static_cast<std::uint16_t>(i + 1 < datagrams.size() ? 0x8000 : 0);
    wire::store_le16(&f[at + 6], static_cast<std::uint16_t>(d.data.size() | more));
    std::copy(d.data.begin(), d.data.end(), f.begin() + static_cast<std::ptrdiff_t>(at + 10));
    wire::store_le16(&f[at + 10 + d.data.size()], d.wkc);
  }
  wire::store_le16(f.data(), static_cast<std::uint16_t>((f.size() - 2) | 0x1000));
  return f;
}

// An Ethernet capture: the master sends from 01:01:01:01:01:01, the segment's replies carry bit
// 1 of the first source byte (03:01:...), as real ESCs set it.
class CaptureWriter {
 public:
  void add(const std::vector<std::uint8_t>& frame, bool from_master) {
    std::vector<std::uint8_t> p(14, 0xFF);
    for (std::size_t i = 6; i < 12; ++i)
      p[i] = 0x01;
    if (!from_master) p[6] = 0x03;
    p[12] = 0x88;
    p[13] = 0xA4;
    p.insert(p.end(), frame.begin(), frame.end());
    packets_.push_back(std::move(p));
    times_.push_back(1'700'000'000'000'000'000 +
                     static_cast<std::int64_t>(packets_.size()) * 100'000);
  }
  std::vector<std::uint8_t> bytes() const {
    std::vector<capture::OutputPacket> out;
    for (std::size_t i = 0; i < packets_.size(); ++i)
      out.push_back({times_[i], packets_[i]});
    return capture::encode_pcap(out);
  }
  CaptureTrace trace() const {
    auto file = capture::CaptureFile::from_bytes(bytes(), "test.pcap");
    EXPECT_TRUE(file.ok());
    auto trace = load_capture_trace(*file, "test.pcap");
    EXPECT_TRUE(trace.ok()) << trace.error().describe();
    return *trace;
  }

 private:
  std::vector<std::vector<std::uint8_t>> packets_;
  std::vector<std::int64_t> times_;
};

std::vector<std::uint8_t> test_eeprom(std::uint32_t product) {
  wire::SiiImage image;
  image.pdi_control = 0x0C05;  // a PDI, both DC units
  image.identity = {0x0ACE, product, 1, product};
  image.strings = {"Test"};
  auto bytes = wire::encode_sii(image);
  EXPECT_TRUE(bytes.ok());
  return *bytes;
}

std::unique_ptr<Segment> two_slaves() {
  auto segment = std::make_unique<Segment>();
  for (std::uint32_t i = 0; i < 2; ++i) {
    EXPECT_TRUE(segment
                    ->add_slave("s" + std::to_string(i),
                                std::make_unique<Esc>(EscHardware{}, test_eeprom(i + 1), nullptr))
                    .ok());
  }
  return segment;
}

std::uint32_t fp(std::uint16_t station, std::uint16_t offset) {
  return wire::physical_address(station, offset);
}

// Records the master's requests and the replies of a reference segment, so a test can change the
// "real" replies before verifying against a fresh, identical segment.
class Session {
 public:
  Session() : reference_(two_slaves()) {
    send({{Command::apwr, 1, wire::physical_address(0, reg::kStationAddress), {0x00, 0x10}}});
    send({{Command::apwr,
           2,
           wire::physical_address(wire::position_adp(1), reg::kStationAddress),
           {0x01, 0x10}}});
  }
  // Sends a request; returns the index of its recorded reply (to change it with reply()).
  std::size_t send(std::vector<Dg> request, bool answered = true) {
    auto frame = encode_frame(request);
    requests_.push_back(frame);
    std::vector<std::uint8_t> reply = frame;
    const bool ok = reference_->process_frame(reply, now_);
    now_ += 100'000;
    replies_.push_back(ok && answered ? std::optional(reply) : std::nullopt);
    return replies_.size() - 1;
  }
  // The data of datagram `k` of recorded reply `i`.
  std::uint8_t* data(std::size_t i, std::size_t k = 0) {
    auto& f = *replies_.at(i);
    std::size_t at = 2;
    for (std::size_t j = 0; j < k; ++j)
      at += 12 + (wire::load_le16(&f[at + 6]) & 0x7FF);
    return &f[at + 10];
  }
  void set_wkc(std::size_t i, std::uint16_t wkc) {
    auto& f = *replies_.at(i);
    const std::size_t length = wire::load_le16(&f[8]) & 0x7FF;
    wire::store_le16(&f[12 + length], wkc);
  }
  CaptureTrace trace() const {
    CaptureWriter w;
    for (std::size_t i = 0; i < requests_.size(); ++i) {
      w.add(requests_[i], true);
      if (replies_[i]) w.add(*replies_[i], false);
    }
    return w.trace();
  }
  VerifyReport verify() const {
    auto segment = two_slaves();
    auto report = verify_capture(trace(), *segment);
    EXPECT_TRUE(report.ok());
    return *report;
  }

 private:
  std::unique_ptr<Segment> reference_;
  std::vector<std::vector<std::uint8_t>> requests_;
  std::vector<std::optional<std::vector<std::uint8_t>>> replies_;
  std::int64_t now_ = 1'000'000;
};

// ---- Capture files ----------------------------------------------------------------------------

// Reading and writing capture files (libpcap): tests/capture/capture_file_test.cpp.

TEST(CaptureFile, ExtractsEtherCatFromUdpAndKnowsItsDirection) {
  // IPv4/UDP from port 5000 to 0x88A4: a request.
  std::vector<std::uint8_t> p(14, 0);
  p[12] = 0x08;
  std::vector<std::uint8_t> ip{0x45, 0, 0, 0, 0, 0, 0, 0, 64, 17, 0, 0, 10, 0, 0, 1, 10, 0, 0, 2};
  const auto frame = encode_frame({{Command::brd, 0, 0, {0}, 0}});
  std::vector<std::uint8_t> udp{0x13, 0x88, 0x88, 0xA4, 0, 0, 0, 0};
  wire::store_be16(&udp[4], static_cast<std::uint16_t>(8 + frame.size()));
  udp.insert(udp.end(), frame.begin(), frame.end());
  wire::store_be16(&ip[2], static_cast<std::uint16_t>(20 + udp.size()));
  p.insert(p.end(), ip.begin(), ip.end());
  p.insert(p.end(), udp.begin(), udp.end());
  auto e = capture::extract_ethercat(capture::kLinkTypeEthernet, p);
  ASSERT_TRUE(e);
  EXPECT_EQ(e->encapsulation, capture::Encapsulation::udp);
  EXPECT_EQ(e->frame.size(), frame.size());
  EXPECT_EQ(frame_direction(*e), FrameDirection::master);
  e->udp_source_port = 0x88A4;
  e->udp_destination_port = 5000;
  EXPECT_EQ(frame_direction(*e), FrameDirection::slave);
  capture::EtherCatPacket raw;
  raw.source = wire::MacAddress{0x12, 0x10, 0x10, 0x10, 0x10, 0x10};
  EXPECT_EQ(frame_direction(raw), FrameDirection::slave);
  raw.source = wire::MacAddress{0x10, 0x10, 0x10, 0x10, 0x10, 0x10};
  EXPECT_EQ(frame_direction(raw), FrameDirection::master);
  raw.source.reset();
  EXPECT_EQ(frame_direction(raw), FrameDirection::unknown);
  raw.outgoing = true;
  EXPECT_EQ(frame_direction(raw), FrameDirection::master);
}

// ---- Pairing ------------------------------------------------------------------------------------

TEST(Pairing, RepliesFindTheirRequestsRetriesAndLostFramesAreKept) {
  auto req = [](std::uint8_t index, std::uint16_t ado) {
    return encode_frame({{Command::fprd, index, fp(0x1000, ado), {0, 0}, 0}});
  };
  auto rep = [](std::uint8_t index, std::uint16_t ado) {
    return encode_frame({{Command::fprd, index, fp(0x1000, ado), {1, 2}, 1}});
  };
  CaptureWriter w;
  w.add(req(1, 0x0130), true);   // A
  w.add(req(2, 0x0134), true);   // B
  w.add(rep(2, 0x0134), false);  // B's reply first
  w.add(rep(1, 0x0130), false);  // then A's
  w.add(rep(9, 0x0010), false);  // nobody asked
  w.add(req(3, 0x0110), true);   // C: lost ...
  w.add(req(3, 0x0110), true);   // ... and retried
  w.add(rep(3, 0x0110), false);
  w.add(req(4, 0x0110), true);  // D: the capture ends
  const CaptureTrace t = w.trace();
  EXPECT_EQ(t.frames.size(), 9u);
  EXPECT_EQ(t.replies, 4u);
  EXPECT_EQ(t.orphan_replies, 1u);
  ASSERT_EQ(t.exchanges.size(), 5u);
  EXPECT_EQ(t.exchanges[0].reply, std::optional<std::size_t>(3));
  EXPECT_EQ(t.exchanges[1].reply, std::optional<std::size_t>(2));
  EXPECT_FALSE(t.exchanges[2].reply);
  EXPECT_FALSE(t.exchanges[2].after_last_reply);
  EXPECT_EQ(t.exchanges[3].reply, std::optional<std::size_t>(7));
  EXPECT_FALSE(t.exchanges[4].reply);
  EXPECT_TRUE(t.exchanges[4].after_last_reply);
  EXPECT_EQ(t.frames[2].number, 3u);
}

TEST(Pairing, UnknownDirectionsArePairedByContent) {
  std::vector<CaptureFrame> frames;
  // BRD 1, its reply (WKC 2), BRD 2, an identical copy of BRD 2 (a retry, not a reply).
  for (auto [index, wkc] : {std::pair{1, 0}, {1, 2}, {2, 0}, {2, 0}}) {
    CaptureFrame f;
    f.number = frames.size() + 1;
    f.frame = encode_frame({{Command::brd,
                             static_cast<std::uint8_t>(index),
                             0,
                             {0},
                             static_cast<std::uint16_t>(wkc)}});
    frames.push_back(f);
  }
  const CaptureTrace t =
      pair_capture_frames(frames, std::vector<FrameDirection>(4, FrameDirection::unknown), "x");
  ASSERT_EQ(t.exchanges.size(), 3u);
  EXPECT_EQ(t.exchanges[0].reply, std::optional<std::size_t>(1));
  EXPECT_TRUE(t.frames[0].from_master);
  EXPECT_FALSE(t.frames[1].from_master);
  EXPECT_TRUE(t.frames[3].from_master);
  EXPECT_FALSE(t.exchanges[1].reply);
  EXPECT_FALSE(t.exchanges[2].reply);
  EXPECT_TRUE(t.exchanges[2].after_last_reply);
}

// ---- Comparison rules ---------------------------------------------------------------------------

TEST(Verify, IdenticalRepliesMatchEverywhere) {
  Session s;
  s.send({{Command::brd, 3, 0, {0}}});
  s.send({{Command::fprd, 4, fp(0x1001, reg::kStationAddress), {0, 0}}});
  s.send({{Command::fpwr, 5, fp(0x1000, reg::kAlControl), {0x02, 0}}});
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.summary_line(), "datagrams=5 wkc_match=5/5 data_match=2/2 malformed=0");
  EXPECT_TRUE(r.passed());
  EXPECT_TRUE(r.mismatches.empty());
  EXPECT_EQ(r.exclusions.at("write_data"), 3u);
  EXPECT_EQ(r.per_command.at(Command::apwr).wkc_matched, 2u);
  EXPECT_EQ(r.per_command.at(Command::fprd).data_matched, 1u);
}

TEST(Verify, DataDifferencesOutsideTheRulesAreMismatches) {
  Session s;
  const auto i = s.send({{Command::fprd, 3, fp(0x1001, reg::kStationAddress), {0, 0}}});
  s.data(i)[1] = 0x20;  // the real slave said 0x2001
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.summary_line(), "datagrams=3 wkc_match=3/3 data_match=0/1 malformed=0");
  EXPECT_FALSE(r.passed());
  ASSERT_EQ(r.mismatches.size(), 1u);
  const auto& m = r.mismatches[0];
  EXPECT_EQ(m.frame, 5u);
  EXPECT_EQ(m.reply_frame, 6u);
  EXPECT_EQ(m.command, Command::fprd);
  EXPECT_TRUE(m.data_differs);
  EXPECT_FALSE(m.wkc_differs);
  EXPECT_EQ(m.detail, "data at 0x0011 (byte 1): expected 0x20, got 0x10");
  EXPECT_EQ(m.expected_data, (std::vector<std::uint8_t>{0x01, 0x20}));
  EXPECT_EQ(m.actual_data, (std::vector<std::uint8_t>{0x01, 0x10}));
}

TEST(Verify, WorkingCountersAndMissingRepliesAreAlwaysCompared) {
  Session s;
  const auto i = s.send({{Command::brd, 3, 0, {0}}});
  s.set_wkc(i, 1);
  s.send({{Command::fprd, 4, fp(0x1000, reg::kAlStatus), {0, 0}}}, false);  // lost
  s.send({{Command::fprd, 5, fp(0x1000, reg::kAlStatus), {0, 0}}});
  s.send({{Command::fprd, 6, fp(0x1000, reg::kAlStatus), {0, 0}}}, false);  // capture ends
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.summary_line(), "datagrams=6 wkc_match=3/5 data_match=2/2 malformed=0");
  EXPECT_EQ(r.unanswered_at_end, 1u);
  ASSERT_EQ(r.mismatches.size(), 2u);
  EXPECT_EQ(r.mismatches[0].detail, "WKC expected 1, got 2");
  EXPECT_EQ(r.mismatches[1].detail, "the real segment did not answer, the simulator did (WKC 1)");
  EXPECT_FALSE(r.mismatches[1].expected_wkc);
  EXPECT_EQ(r.mismatches[1].actual_wkc, std::optional<std::uint16_t>(1));
  EXPECT_FALSE(r.passed());
}

TEST(Verify, TimeAndWiringDependentRegistersAreLeftOut) {
  Session s;
  const auto dc =
      s.send({{Command::fprd, 3, fp(0x1000, reg::kDcSystemTime), std::vector<std::uint8_t>(8)}});
  s.data(dc)[0] ^= 0x55;
  const auto errors = s.send(
      {{Command::fprd, 4, fp(0x1000, reg::kRxErrorCounter), std::vector<std::uint8_t>(0x16)}});
  s.data(errors)[3] = 7;     // a real RX error counter
  s.data(errors)[0x15] = 9;  // 0x0315: outside the counters, compared
  const auto wd = s.send({{Command::fprd, 5, fp(0x1000, reg::kWatchdogStatus), {0, 0}}});
  s.data(wd)[0] = 0;
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.summary_line(), "datagrams=5 wkc_match=5/5 data_match=0/1 malformed=0");
  EXPECT_EQ(r.exclusions.at("dc_time"), 1u);
  EXPECT_EQ(r.exclusions.at("error_counters"), 1u);
  EXPECT_EQ(r.exclusions.at("watchdog"), 1u);
  // What the rules hid: bits that differed.
  EXPECT_EQ(r.differences_left_out.at("dc_time"), 1u);
  EXPECT_EQ(r.differences_left_out.at("error_counters"), 1u);
  ASSERT_EQ(r.mismatches.size(), 1u);
  EXPECT_EQ(r.mismatches[0].detail, "data at 0x0315 (byte 21): expected 0x09, got 0x00");
}

TEST(Verify, SiiBusyDifferencesAndReservedBitsAreLeftOut) {
  Session s;
  const auto i = s.send({{Command::fprd, 3, fp(0x1000, reg::kSiiControl), {0, 0}}});
  s.data(i)[0] |= 0x10;  // reserved bit 4, as the EL2828's ESC shows
  s.data(i)[1] = 0x81;   // still busy with a read
  const auto j = s.send({{Command::fprd, 4, fp(0x1000, reg::kSiiControl), {0, 0}}});
  s.data(j)[0] |= 0x01;  // write enable: compared
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.exclusions.at("reserved"), 2u);
  EXPECT_EQ(r.exclusions.at("sii_busy"), 1u);
  EXPECT_EQ(r.differences_left_out.at("reserved"), 1u);  // only the first differs there
  EXPECT_EQ(r.differences_left_out.at("sii_busy"), 1u);
  EXPECT_EQ(r.summary_line(), "datagrams=4 wkc_match=4/4 data_match=1/2 malformed=0");
}

TEST(Verify, InputsReadThroughFmmusAreLeftOutOutputsAreCompared) {
  Session s;
  // Slave 0: FMMU 0 maps logical 0x100 (1 byte) onto its inputs at 0x1100 for reading; FMMU 1
  // maps logical 0x101 onto 0x1200 for writing.
  wire::FmmuConfig in;
  in.logical_start = 0x100;
  in.length = 1;
  in.logical_stop_bit = 7;
  in.physical_start = 0x1100;
  in.type = wire::FmmuType::read;
  in.active = true;
  wire::FmmuConfig out = in;
  out.logical_start = 0x101;
  out.physical_start = 0x1200;
  out.type = wire::FmmuType::write;
  const auto in_bytes = in.encode();
  const auto out_bytes = out.encode();
  s.send({{Command::fpwr, 3, fp(0x1000, reg::fmmu(0)), {in_bytes.begin(), in_bytes.end()}}});
  s.send({{Command::fpwr, 4, fp(0x1000, reg::fmmu(1)), {out_bytes.begin(), out_bytes.end()}}});
  const auto i = s.send({{Command::lrw, 5, 0x100, {0x00, 0x5A, 0x77}}});
  s.data(i)[0] = 0xEE;  // a real sensor value
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.exclusions.at("inputs"), 1u);
  EXPECT_EQ(r.summary_line(), "datagrams=5 wkc_match=5/5 data_match=1/1 malformed=0");
  const auto j = s.send({{Command::lrw, 6, 0x100, {0x00, 0x5A, 0x77}}});
  s.data(j)[2] = 0x78;  // unmapped byte: must come back unchanged
  EXPECT_EQ(s.verify().summary_line(), "datagrams=6 wkc_match=6/6 data_match=1/2 malformed=0");
}

TEST(Verify, AlStatusStillShowingTheEarlierStateIsFirmwareTime) {
  Session s;
  s.send({{Command::fpwr, 3, fp(0x1000, reg::kAlControl), {0x02, 0}}});
  const auto i = s.send({{Command::fprd, 4, fp(0x1000, reg::kAlStatus), {0, 0}}});
  s.data(i)[0] = 0x01;  // the real slave is still in INIT
  const auto j = s.send({{Command::fprd, 5, fp(0x1000, reg::kAlStatus), {0, 0}}});
  s.data(j)[0] = 0x04;  // SAFEOP was never the state: a mismatch
  const VerifyReport r = s.verify();
  EXPECT_EQ(r.exclusions.at("al_transition"), 1u);
  EXPECT_EQ(r.summary_line(), "datagrams=5 wkc_match=5/5 data_match=0/1 malformed=0");
}

TEST(Verify, RulesAreDocumented) {
  std::set<std::string_view> ids;
  for (const auto& rule : verify_rules()) {
    EXPECT_FALSE(rule.what.empty());
    EXPECT_FALSE(rule.why.empty());
    EXPECT_TRUE(ids.insert(rule.id).second) << rule.id;
  }
  EXPECT_EQ(ids.size(), 11u);
}

// ---- Profiles from small captures ------------------------------------------------------------

TEST(Profile, RebuildsStationsSiiWordsAndDeviceEmulation) {
  Session s;
  // SII word 8..11 through the EEPROM interface, as masters read the identity.
  s.send({{Command::fpwr, 3, fp(0x1001, reg::kSiiControl), {0x00, 0x01, 0x08, 0, 0, 0}}});
  s.send({{Command::fprd, 4, fp(0x1001, reg::kSiiData), std::vector<std::uint8_t>(8)}});
  s.send({{Command::bwr, 5, reg::kAlControl * 0x10000u, {0x11, 0}}});
  s.send({{Command::brd, 6, reg::kAlStatus * 0x10000u, {0, 0}}});
  s.send({{Command::fprd, 7, fp(0x1000, reg::kAlStatus), {0, 0}}});
  auto profile = build_capture_profile(s.trace());
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 2u);
  const auto& a = profile->slaves[0];
  const auto& b = profile->slaves[1];
  EXPECT_EQ(a.station, std::optional<std::uint16_t>(0x1000));
  EXPECT_EQ(b.station, std::optional<std::uint16_t>(0x1001));
  EXPECT_FALSE(a.station_preset);
  EXPECT_TRUE(b.sii_word_read[8]);
  EXPECT_TRUE(b.sii_word_read[11]);
  EXPECT_FALSE(b.sii_word_read[12]);
  EXPECT_EQ(wire::load_le32(&b.sii[16]), 0x0ACEu) << "vendor ID";
  EXPECT_EQ(wire::load_le32(&b.sii[20]), 2u) << "product code";
  EXPECT_EQ(wire::load_le16(&b.sii[24]), 0xFFFF) << "unread words stay 0xFFFF";
  // The reference slaves have firmware (BasicApplication): AL status 0x0001 after 0x0011.
  EXPECT_FALSE(a.device_emulation);
  EXPECT_EQ(a.sii[1] & 0x01, 0) << "ESC configuration without device emulation";
  EXPECT_TRUE(b.device_emulation) << "no evidence and no mailbox: no firmware assumed";
  EXPECT_EQ(b.sii[1] & 0x01, 0x01);
  EXPECT_EQ(b.sii[14], wire::sii_crc8(wire::Bytes(b.sii).first(14))) << "checksummed";
  EXPECT_EQ(a.hardware.sync_manager_count, 4u) << "nothing seen: a terminal-class ESC";
}

TEST(Profile, StationsInUseBeforeTheCaptureArePresetInAscendingOrder) {
  CaptureWriter w;
  for (std::uint16_t station : {0x03EA, 0x03E9}) {
    w.add(encode_frame({{Command::fprd, 1, fp(station, reg::kAlStatus), {0, 0}, 0}}), true);
    w.add(encode_frame({{Command::fprd, 1, fp(station, reg::kAlStatus), {0x02, 0}, 1}}), false);
  }
  auto profile = build_capture_profile(w.trace());
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 2u);
  EXPECT_EQ(profile->slaves[0].station, std::optional<std::uint16_t>(0x03E9));
  EXPECT_TRUE(profile->slaves[0].station_preset);
  EXPECT_EQ(profile->slaves[1].station, std::optional<std::uint16_t>(0x03EA));
  EXPECT_EQ(profile->slaves[0].initial_al_status, std::optional<std::uint16_t>(0x0002));
  auto segment = build_capture_segment(*profile);
  ASSERT_TRUE(segment.ok());
  EXPECT_EQ((*segment)->esc(0).station_address(), 0x03E9);
  EXPECT_EQ((*segment)->esc(1).al_state(), wire::AlState::preop);
  auto report = verify_capture(w.trace(), **segment);
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->summary_line(), "datagrams=2 wkc_match=2/2 data_match=2/2 malformed=0");
}

// Register facts the capture shows are carried into the profile and its ring: SII control bit 5,
// DL status bit 2, an AL control write the device refused (error indicator, status code, state
// kept); where it shows nothing, the datasheet value for the ESC type.
TEST(Profile, CarriesRegisterFactsAndRefusedStates) {
  Session s;
  const auto sii = s.send({{Command::fprd, 3, fp(0x1001, reg::kSiiControl), {0, 0}}});
  s.data(sii)[0] |= 0x20;  // EEPROM emulated by the PDI
  const auto dl = s.send({{Command::fprd, 4, fp(0x1001, reg::kDlStatus), {0, 0}}});
  s.data(dl)[0] |= 0x04;  // enhanced link detection
  // Slave 1 refuses OP for good; slave 0 refuses PREOP once, then takes it.
  s.send({{Command::fpwr, 5, fp(0x1001, reg::kAlControl), {0x08, 0}}});
  const auto op =
      s.send({{Command::fprd, 6, fp(0x1001, reg::kAlStatus), std::vector<std::uint8_t>(6)}});
  s.data(op)[0] = 0x11;
  s.data(op)[4] = 0x1D;
  s.send({{Command::fpwr, 7, fp(0x1000, reg::kAlControl), {0x02, 0}}});
  const auto pre =
      s.send({{Command::fprd, 8, fp(0x1000, reg::kAlStatus), std::vector<std::uint8_t>(6)}});
  s.data(pre)[0] = 0x11;
  s.data(pre)[4] = 0x16;
  s.send({{Command::fpwr, 9, fp(0x1000, reg::kAlControl), {0x02, 0}}});
  s.send({{Command::fprd, 10, fp(0x1000, reg::kAlStatus), {0, 0}}});
  auto profile = build_capture_profile(s.trace());
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 2u);
  const EscHardware& a = profile->slaves[0].hardware;
  const EscHardware& b = profile->slaves[1].hardware;
  EXPECT_TRUE(a.al_refusals.empty()) << "PREOP was reached later: not the device's refusal";
  ASSERT_EQ(b.al_refusals.size(), 1u);
  EXPECT_EQ(b.al_refusals[0].first, wire::AlState::op);
  EXPECT_EQ(b.al_refusals[0].second, 0x001D);
  EXPECT_TRUE(b.sii_emulation);
  EXPECT_EQ(b.enhanced_link_detection, std::optional<bool>(true));
  EXPECT_FALSE(a.sii_emulation);
  EXPECT_EQ(a.enhanced_link_detection, std::nullopt);
  // Nothing shows DL control or slave 0's read size: the datasheet's for the (assumed) type.
  EXPECT_EQ(a.dl_control, esc_type_defaults(a.type).dl_control);
  EXPECT_EQ(a.sii_reads_8_bytes, esc_type_defaults(a.type).sii_reads_8_bytes);
  // The rebuilt segment answers the refused request like the device did.
  auto segment = build_capture_segment(*profile);
  ASSERT_TRUE(segment.ok());
  auto report = verify_capture(s.trace(), **segment);
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->wkc_matched, report->wkc_compared);
  // Everything but slave 0's passing refusal, which the profile rightly does not keep: the
  // rebuilt slave takes PREOP at once.
  EXPECT_EQ(report->data_matched + 1, report->data_compared) << report->summary_line();
  ASSERT_EQ(report->mismatches.size(), 1u);
  EXPECT_EQ(report->mismatches[0].address, fp(0x1000, reg::kAlStatus));
  // And so does the ring written from it.
  const auto dir = std::filesystem::path(ECAT_BINARY_DIR) / "capture_profile_facts_test";
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(write_capture_profile(*profile, dir.string()).ok());
  const auto ring = test::read_file(dir / "ring.yaml");
  const std::string text(ring.begin(), ring.end());
  EXPECT_NE(text.find("al_refusals: [{state: op, code: 0x001d}]"), std::string::npos) << text;
  EXPECT_NE(text.find("sii_emulation: true, enhanced_link_detection: true"), std::string::npos)
      << text;
  auto ring_file = load_ring((dir / "ring.yaml").string());
  ASSERT_TRUE(ring_file.ok()) << ring_file.error().describe();
  auto ring_segment = build_segment(*ring_file);
  ASSERT_TRUE(ring_segment.ok()) << ring_segment.error().describe();
  auto again = verify_capture(s.trace(), **ring_segment);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->summary_line(), report->summary_line());
}

TEST(Profile, WritesSiiImagesRingAndJson) {
  Session s;
  auto profile = build_capture_profile(s.trace());
  ASSERT_TRUE(profile.ok());
  const auto dir = std::filesystem::path(ECAT_BINARY_DIR) / "capture_profile_test";
  std::filesystem::remove_all(dir);
  auto written = write_capture_profile(*profile, dir.string());
  ASSERT_TRUE(written.ok()) << written.error().describe();
  ASSERT_EQ(written->size(), 4u);
  EXPECT_EQ(std::filesystem::file_size(dir / "slave0.bin"), 2048u);
  const auto ring = test::read_file(dir / "ring.yaml");
  const std::string text(ring.begin(), ring.end());
  EXPECT_NE(text.find("    - name: slave1\n      profile: eeprom\n      file: slave1.bin\n"),
            std::string::npos)
      << text;
  // The ESC facts and the start state the capture showed travel with the image.
  EXPECT_NE(text.find("      esc: {type: 0x"), std::string::npos) << text;
  auto ring_file = load_ring((dir / "ring.yaml").string());
  ASSERT_TRUE(ring_file.ok()) << ring_file.error().describe();
  ASSERT_EQ(ring_file->slaves.size(), 2u);
  const EscPreset& esc = ring_file->slaves[1].device.esc;
  ASSERT_TRUE(esc.type && esc.fmmu_count && esc.sync_manager_count && esc.features && esc.ports &&
              esc.sii_read_bytes && esc.sii_busy_ns);
  const EscHardware& hw = profile->slaves[1].hardware;
  EXPECT_EQ(*esc.type, hw.type);
  EXPECT_EQ(*esc.fmmu_count, hw.fmmu_count);
  EXPECT_EQ(*esc.sync_manager_count, hw.sync_manager_count);
  EXPECT_EQ(*esc.ports, hw.ports.encode());
  EXPECT_EQ(*esc.sii_read_bytes, hw.sii_reads_8_bytes ? 8 : 4);
  EXPECT_EQ(*esc.sii_busy_ns, hw.sii_busy_ns);
  const auto json = test::read_file(dir / "profile.json");
  EXPECT_NE(std::string(json.begin(), json.end()).find("\"slave_count\": 2"), std::string::npos);
}

// ---- The shared real-device captures
// -------------------------------------------------------------

struct Expected {
  const char* file;
  std::size_t slaves;
  std::size_t datagrams;
  std::size_t wkc_compared;
  std::size_t data_compared;
  std::size_t data_matched;
};

// What the simulator reaches on each capture, rebuilt from the capture itself. Every WKC matches.
constexpr Expected kCaptures[] = {
    {"twincat-run-ek1100-el1004.pcapng", 2, 291, 290, 248, 248},
    {"soem-sdinfo-ek1100-el1004.pcapng", 2, 290, 290, 186, 186},
    {"soem-sdinfo-no-slaves.pcapng", 0, 19, 19, 0, 0},
    {"rs-example-sii-el2004.pcapng", 3, 127, 127, 78, 78},
    {"replay-ek1100-el2828-el2889.pcapng", 3, 2062, 2062, 1620, 1620},
    {"replay-ek1914-el3004-mailbox.pcapng", 2, 497, 497, 260, 260},
    {"replay-ek1914-segmented-upload.pcapng", 2, 482, 482, 248, 248},
    {"replay-dc.pcapng", 3, 2838, 2838, 2114, 2114},
};

class SharedCapture : public ::testing::TestWithParam<Expected> {};

TEST_P(SharedCapture, ProfileBuildsAndTheSimulatorAnswersLikeTheRealSegment) {
  const Expected& e = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(path, std::string("captures/") + e.file);
  auto trace = load_capture_trace(path.string());
  ASSERT_TRUE(trace.ok()) << trace.error().describe();
  auto profile = build_capture_profile(*trace);
  ASSERT_TRUE(profile.ok()) << profile.error().describe();
  EXPECT_EQ(profile->slaves.size(), e.slaves);
  auto segment = build_capture_segment(*profile);
  ASSERT_TRUE(segment.ok()) << segment.error().describe();
  auto report = verify_capture(*trace, **segment);
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->datagrams, e.datagrams);
  EXPECT_EQ(report->wkc_compared, e.wkc_compared);
  EXPECT_EQ(report->wkc_matched, e.wkc_compared);
  EXPECT_EQ(report->data_compared, e.data_compared);
  EXPECT_EQ(report->data_matched, e.data_matched);
  EXPECT_TRUE(report->passed());
  for (const auto& m : report->mismatches)
    ADD_FAILURE() << m.frame << ": " << m.detail;

  // The ring file `ecat sim profile` writes answers exactly as the profile itself.
  if (profile->slaves.empty()) return;
  const auto dir = std::filesystem::path(ECAT_BINARY_DIR) /
                   // The whole name: two captures share their first characters, and CTest runs
                   // them in parallel.
                   (std::string("capture_ring_") + std::filesystem::path(e.file).stem().string());
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(write_capture_profile(*profile, dir.string()).ok());
  auto ring = load_ring((dir / "ring.yaml").string());
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  auto ring_segment = build_segment(*ring);
  ASSERT_TRUE(ring_segment.ok()) << ring_segment.error().describe();
  auto through_ring = verify_capture(*trace, **ring_segment);
  ASSERT_TRUE(through_ring.ok());
  EXPECT_EQ(through_ring->wkc_matched, e.wkc_compared);
  EXPECT_EQ(through_ring->data_compared, e.data_compared);
  EXPECT_EQ(through_ring->data_matched, e.data_matched);
  for (const auto& m : through_ring->mismatches)
    ADD_FAILURE() << "through ring.yaml: " << m.frame << ": " << m.detail;
  std::filesystem::remove_all(dir);
}

std::string capture_test_name(const ::testing::TestParamInfo<Expected>& param) {
  std::string name = param.param.file;
  name = name.substr(0, name.find('.'));
  for (char& c : name) {
    if (c == '-') c = '_';
  }
  return name;
}

INSTANTIATE_TEST_SUITE_P(Captures, SharedCapture, ::testing::ValuesIn(kCaptures),
                         capture_test_name);

// The SII words a capture shows are the device's real EEPROM contents.
void expect_words_match(const CaptureSlaveProfile& slave, const std::vector<std::uint8_t>& real) {
  std::size_t compared = 0;
  for (std::size_t w = 0; w < slave.sii_word_read.size() && 2 * w + 1 < real.size(); ++w) {
    if (!slave.sii_word_read[w]) continue;
    ++compared;
    EXPECT_EQ(wire::load_le16(&slave.sii[2 * w]), wire::load_le16(&real[2 * w])) << "word " << w;
  }
  EXPECT_GT(compared, 30u);
}

TEST(SharedCaptureSii, RebuiltWordsEqualTheRealEepromImages) {
  ECAT_SHARED_DATA_OR_SKIP(capture, "captures/replay-ek1100-el2828-el2889.pcapng");
  ECAT_SHARED_DATA_OR_SKIP(ek1100, "eeprom/ek1100.bin");
  ECAT_SHARED_DATA_OR_SKIP(el2828, "eeprom/el2828.bin");
  auto trace = load_capture_trace(capture.string());
  ASSERT_TRUE(trace.ok());
  auto profile = build_capture_profile(*trace);
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 3u);
  EXPECT_EQ(profile->slaves[0].name, "slave0_EK1100");
  EXPECT_EQ(profile->slaves[1].name, "slave1_EL2828");
  EXPECT_EQ(profile->slaves[2].name, "slave2_EL2889");
  expect_words_match(profile->slaves[0], test::read_file(ek1100));
  expect_words_match(profile->slaves[1], test::read_file(el2828));
  // The ESC configuration rebuilt from behaviour equals the real word 0 (0x0D00: device
  // emulation and both DC units, no PDI; 0x0104 for the EL2828: emulation, no DC units).
  EXPECT_EQ(wire::load_le16(profile->slaves[0].sii.data()),
            wire::load_le16(test::read_file(ek1100).data()));
  EXPECT_EQ(profile->slaves[1].sii[1], test::read_file(el2828)[1]);
  EXPECT_EQ(profile->slaves[0].hardware.fmmu_count, 8u);
  EXPECT_EQ(profile->slaves[1].hardware.fmmu_count, 3u);
  EXPECT_EQ(profile->slaves[2].hardware.sync_manager_count, 4u);
  EXPECT_FALSE(profile->slaves[1].dc_system_time);
  EXPECT_TRUE(profile->slaves[2].dc_system_time);
}

TEST(SharedCaptureSii, El2004WordsFromAnotherMaster) {
  ECAT_SHARED_DATA_OR_SKIP(capture, "captures/rs-example-sii-el2004.pcapng");
  ECAT_SHARED_DATA_OR_SKIP(el2004, "eeprom/el2004.bin");
  auto trace = load_capture_trace(capture.string());
  ASSERT_TRUE(trace.ok());
  EXPECT_GT(trace->other_packets, 0u) << "the capture also holds unrelated host traffic";
  auto profile = build_capture_profile(*trace);
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 3u);
  expect_words_match(profile->slaves[1], test::read_file(el2004));
}

TEST(SharedCaptureSii, CoeObjectsComeFromTheMailboxTraffic) {
  ECAT_SHARED_DATA_OR_SKIP(capture, "captures/replay-ek1914-el3004-mailbox.pcapng");
  auto trace = load_capture_trace(capture.string());
  ASSERT_TRUE(trace.ok());
  auto profile = build_capture_profile(*trace);
  ASSERT_TRUE(profile.ok());
  ASSERT_EQ(profile->slaves.size(), 2u);
  const auto& el3004 = profile->slaves[1];
  EXPECT_TRUE(el3004.has_mailbox);
  EXPECT_FALSE(el3004.device_emulation);
  ASSERT_EQ(el3004.objects.size(), 2u);
  const auto& version = el3004.objects.at({0x100A, 0});
  EXPECT_EQ(std::string(version.value.begin(), version.value.end()), "08");
  const auto& f008 = el3004.objects.at({0xF008, 0});
  EXPECT_TRUE(f008.downloaded);
  EXPECT_TRUE(f008.uploaded);
  EXPECT_EQ(f008.value, (std::vector<std::uint8_t>{1, 0, 0, 0}));
}

}  // namespace
}  // namespace ecat::sim
