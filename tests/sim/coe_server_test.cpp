// The simulator's CoE server, driven the way a master drives a slave: mailbox requests written
// into SM0 and replies read from SM1 through a real Esc in a Segment, encoded and decoded with
// the wire codecs. Covers every SDO transfer kind, complete access, aborts, SDO information,
// emergencies, mailbox counters and repeat, mailbox errors, fault rules and PDO mapping changes.
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/application.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/sim/pdo_mapping.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sdo_abort.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim {
namespace {

using wire::AlState;
using wire::Command;
using wire::MailboxType;
using wire::SdoAbortCode;
using Bytes = std::vector<std::uint8_t>;
namespace reg = wire::reg;

constexpr std::uint16_t kStation = 0x1001;
constexpr std::uint16_t kOutStart = 0x1000;
constexpr std::uint16_t kInStart = 0x1400;

constexpr std::uint32_t code(SdoAbortCode c) {
  return static_cast<std::uint32_t>(c);
}

Bytes stored(const ObjectDictionary& od, std::uint16_t index, std::uint8_t subindex) {
  auto v = od.value(index, subindex);
  return v ? Bytes(v->begin(), v->end()) : Bytes{};
}

Bytes pattern(std::size_t n, std::uint8_t seed = 0) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>(seed + i);
  return out;
}

// The firmware of the test device: the AL state machine plus the CoE server over a dictionary.
class CoeDevice : public BasicApplication {
 public:
  explicit CoeDevice(CoeServerConfig config) : server(od, config) {}
  void on_buffer_written(Esc& esc, std::size_t sm) override { server.on_buffer_written(esc, sm); }
  void on_buffer_read(Esc& esc, std::size_t sm) override { server.on_buffer_read(esc, sm); }
  void on_mailbox_repeat(Esc& esc, std::size_t sm) override { server.on_mailbox_repeat(esc, sm); }
  void on_sync_manager_changed(Esc& esc, std::size_t sm) override {
    server.on_sync_manager_changed(esc, sm);
  }

  ObjectDictionary od;
  CoeServer server;
};

// A dictionary with objects of every shape the tests need.
void fill_dictionary(ObjectDictionary& od) {
  od.add(make_device_type(0x00001389));
  od.add(make_device_name("CoE test device"));
  od.add(make_identity({0x00000ACE, 0x00001602, 0x00000001, 0x00000002}));
  od.add(make_sync_manager_types({1, 2, 3, 4}));
  od.add(make_var(0x7000, "Output word",
                  make_entry(0, "", DataType::unsigned16, kAccessReadWrite | kAccessRxPdo)));
  od.add(make_var(0x7001, "Output bit",
                  make_entry(0, "", DataType::boolean, kAccessReadWrite | kAccessRxPdo)));
  od.add(make_record(0x6000, "Inputs",
                     {make_entry(1, "Status", DataType::unsigned8, kAccessRead | kAccessTxPdo),
                      make_entry(2, "Value", DataType::integer32, kAccessRead | kAccessTxPdo)}));
  add_pdo_mapping(od, 0x1600, "RxPDO 1", {{0x7000, 0, 16}}, {4, true, 0});
  add_pdo_mapping(od, 0x1601, "RxPDO 2", {{0x7001, 0, 1}, {0, 0, 7}});
  add_pdo_mapping(od, 0x1A00, "TxPDO 1", {{0x6000, 1, 8}, {0x6000, 2, 32}});
  add_pdo_assignment(od, 2, PdoDirection::rx, {0x1601});
  add_pdo_assignment(od, 3, PdoDirection::tx, {0x1A00});
  od.add(make_record(
      0x2000, "Settings",
      {make_entry_of(1, "Vendor word", DataType::unsigned16, kAccessReadWrite,
                     std::uint16_t{0x1234}),
       make_entry_of(2, "Enable", DataType::unsigned8, kAccessReadWrite, std::uint8_t{0}),
       make_entry_of(3, "Counter", DataType::unsigned32, kAccessReadWrite,
                     std::uint32_t{0x0A0B0C0D}),
       make_entry_of(4, "Read only", DataType::unsigned16, kAccessRead, std::uint16_t{0xBEEF}),
       make_entry_of(5, "Write only", DataType::unsigned16, kAccessWrite, std::uint16_t{0}),
       make_entry_of(6, "PREOP only", DataType::integer16, kAccessReadWritePreop, std::int16_t{0}),
       make_entry(7, "Flag", DataType::boolean, kAccessReadWrite)}));
  od.add(
      make_var(0x2001, "Blob",
               make_octet_entry(0, "", Bytes{'h', 'e', 'l', 'l', 'o', '-', 's', 'i', 'm', 0, 0, 0},
                                kAccessReadWrite)));
  od.add(
      make_var(0x2002, "Segmented blob", make_octet_entry(0, "", pattern(80), kAccessReadWrite)));
  od.add(make_var(0x2003, "Multi-segment blob",
                  make_octet_entry(0, "", pattern(192), kAccessReadWrite)));
  auto limited = make_entry_of(0, "", DataType::integer16, kAccessReadWrite, std::int16_t{20});
  limited.minimum = to_le_bytes(std::int16_t{-50});
  limited.maximum = to_le_bytes(std::int16_t{150});
  limited.default_value = to_le_bytes(std::int16_t{20});
  limited.unit = 0x002D0000;  // degree Celsius
  od.add(make_var(0x8000, "Limit", limited));
}

std::vector<std::uint8_t> test_eeprom() {
  wire::SiiImage image;
  image.identity = {0x00000ACE, 0x1602, 1, 2};
  image.standard_mailbox = {kOutStart, 128, kInStart, 128};
  image.mailbox_protocols = 0x0004;
  image.strings = {"CoE"};
  auto bytes = wire::encode_sii(image);
  EXPECT_TRUE(bytes.ok());
  return bytes.ok() ? *bytes : Bytes{};
}

struct Reply {
  wire::MailboxHeader header;
  Bytes data;
};

// The master side: frames through the segment, one datagram each.
class Master {
 public:
  explicit Master(std::uint16_t out_size = 128, std::uint16_t in_size = 128,
                  CoeServerConfig config = {})
      : out_size_(out_size), in_size_(in_size) {
    auto app = std::make_unique<CoeDevice>(config);
    device_ = app.get();
    fill_dictionary(device_->od);
    EXPECT_TRUE(
        segment_
            .add_slave("coe", std::make_unique<Esc>(EscHardware{}, test_eeprom(), std::move(app)))
            .ok());
    EXPECT_EQ(exchange(Command::apwr, wire::physical_address(0, reg::kStationAddress),
                       {static_cast<std::uint8_t>(kStation), kStation >> 8})
                  .second,
              1);
    configure_sm(0, kOutStart, out_size, wire::kMailboxOutControl);
    configure_sm(1, kInStart, in_size, wire::kMailboxInControl);
    set_state(AlState::preop);
  }

  CoeDevice& device() { return *device_; }
  CoeServer& server() { return device_->server; }
  ObjectDictionary& od() { return device_->od; }
  Esc& esc() { return segment_.esc(0); }

  void set_state(AlState state) {
    exchange(Command::fpwr, fp(reg::kAlControl), {static_cast<std::uint8_t>(state), 0});
    ASSERT_EQ(esc().al_state(), state);
  }

  // Writes one mailbox (padded to the SM size); true when the ESC took it.
  bool write(const Bytes& mailbox) {
    Bytes padded = mailbox;
    padded.resize(out_size_, 0);
    return exchange(Command::fpwr, fp(kOutStart), padded).second == 1;
  }
  // Reads SM1 whole; nullopt while it is empty.
  std::optional<Bytes> read_raw() {
    auto [data, wkc] = exchange(Command::fprd, fp(kInStart), Bytes(in_size_, 0));
    if (wkc != 1) return std::nullopt;
    return data;
  }
  std::optional<Reply> read() {
    auto raw = read_raw();
    if (!raw) return std::nullopt;
    auto mailbox = wire::decode_mailbox(*raw);
    EXPECT_TRUE(mailbox.ok()) << mailbox.error().describe();
    if (!mailbox) return std::nullopt;
    return Reply{mailbox->header, Bytes(mailbox->data.begin(), mailbox->data.end())};
  }

  Bytes encode(MailboxType type, const Bytes& data, std::uint8_t counter) {
    wire::MailboxHeader header;
    header.type = type;
    header.counter = counter;
    auto bytes = wire::encode_mailbox(header, data);
    EXPECT_TRUE(bytes.ok());
    return *bytes;
  }
  // Sends mailbox data with the next counter and returns the reply (if any).
  std::optional<Reply> request(MailboxType type, const Bytes& data) {
    counter_ = wire::next_mailbox_counter(counter_);
    EXPECT_TRUE(write(encode(type, data, counter_)));
    return read();
  }
  std::optional<Reply> sdo(const wire::SdoMessage& message) {
    auto data = wire::encode_sdo(message);
    EXPECT_TRUE(data.ok()) << data.error().describe();
    return request(MailboxType::coe, *data);
  }
  static wire::SdoMessage decode(const std::optional<Reply>& reply) {
    EXPECT_TRUE(reply.has_value());
    if (!reply) return wire::SdoAbort{0, 0, 0xFFFFFFFF};
    EXPECT_EQ(reply->header.type, MailboxType::coe);
    auto message = wire::decode_sdo(reply->data);
    EXPECT_TRUE(message.ok()) << message.error().describe();
    return message.ok() ? *message : wire::SdoMessage{wire::SdoAbort{0, 0, 0xFFFFFFFF}};
  }
  static std::uint32_t abort_code(const wire::SdoMessage& message) {
    const auto* abort = std::get_if<wire::SdoAbort>(&message);
    return abort != nullptr ? abort->code : 0;
  }

  struct Upload {
    std::optional<Bytes> value;
    std::uint32_t abort = 0;
    int segments = 0;
    bool expedited = false;
    std::uint8_t command = 0;  // of the initiate response
  };
  Upload upload(std::uint16_t index, std::uint8_t subindex, bool complete_access = false) {
    Upload result;
    auto reply = sdo(wire::SdoInitiateUploadRequest{index, subindex, complete_access});
    if (reply && reply->data.size() > 2) result.command = reply->data[2];
    auto message = decode(reply);
    if (auto* a = std::get_if<wire::SdoAbort>(&message)) {
      result.abort = a->code;
      return result;
    }
    const auto* init = std::get_if<wire::SdoInitiateUploadResponse>(&message);
    EXPECT_NE(init, nullptr);
    if (init == nullptr) return result;
    EXPECT_EQ(init->index, index);
    EXPECT_EQ(init->subindex, subindex);
    EXPECT_EQ(init->complete_access, complete_access);
    result.expedited = init->expedited;
    Bytes value = init->data;
    bool toggle = false;
    while (!init->expedited && value.size() < init->complete_size) {
      auto segment = decode(sdo(wire::SdoUploadSegmentRequest{toggle}));
      if (auto* a = std::get_if<wire::SdoAbort>(&segment)) {
        result.abort = a->code;
        return result;
      }
      const auto* seg = std::get_if<wire::SdoUploadSegmentResponse>(&segment);
      EXPECT_NE(seg, nullptr);
      if (seg == nullptr) return result;
      EXPECT_EQ(seg->toggle, toggle);
      value.insert(value.end(), seg->data.begin(), seg->data.end());
      ++result.segments;
      toggle = !toggle;
      if (seg->last) break;
    }
    if (!init->expedited) {
      EXPECT_EQ(value.size(), init->complete_size);
    }
    result.value = value;
    return result;
  }

  struct Download {
    std::uint32_t abort = 0;
    int segments = 0;
  };
  Download download(std::uint16_t index, std::uint8_t subindex, const Bytes& value,
                    bool complete_access = false, bool force_normal = false) {
    Download result;
    wire::SdoInitiateDownloadRequest init;
    init.index = index;
    init.subindex = subindex;
    init.complete_access = complete_access;
    const bool expedited = !force_normal && !value.empty() && value.size() <= 4;
    std::size_t sent = 0;
    if (expedited) {
      init.expedited = true;
      init.data = value;
      sent = value.size();
    } else {
      init.complete_size = static_cast<std::uint32_t>(value.size());
      sent = std::min<std::size_t>(value.size(), out_size_ - 16u);
      init.data.assign(value.begin(), value.begin() + static_cast<std::ptrdiff_t>(sent));
    }
    auto message = decode(sdo(init));
    if (auto* a = std::get_if<wire::SdoAbort>(&message)) {
      result.abort = a->code;
      return result;
    }
    const auto* ack = std::get_if<wire::SdoInitiateDownloadResponse>(&message);
    EXPECT_NE(ack, nullptr);
    if (ack != nullptr) {
      EXPECT_EQ(ack->index, index);
      EXPECT_EQ(ack->subindex, subindex);
    }
    bool toggle = false;
    const std::size_t segment_size = out_size_ - 9u;
    while (sent < value.size()) {
      const std::size_t n = std::min(segment_size, value.size() - sent);
      wire::SdoDownloadSegmentRequest seg;
      seg.toggle = toggle;
      seg.last = sent + n == value.size();
      seg.data.assign(value.begin() + static_cast<std::ptrdiff_t>(sent),
                      value.begin() + static_cast<std::ptrdiff_t>(sent + n));
      auto reply = decode(sdo(seg));
      if (auto* a = std::get_if<wire::SdoAbort>(&reply)) {
        result.abort = a->code;
        return result;
      }
      const auto* seg_ack = std::get_if<wire::SdoDownloadSegmentResponse>(&reply);
      EXPECT_NE(seg_ack, nullptr);
      if (seg_ack != nullptr) {
        EXPECT_EQ(seg_ack->toggle, toggle);
      }
      sent += n;
      toggle = !toggle;
      ++result.segments;
    }
    return result;
  }

  std::uint8_t last_counter() const { return counter_; }
  void set_counter(std::uint8_t counter) { counter_ = counter; }
  std::uint16_t out_size() const { return out_size_; }
  std::uint16_t in_size() const { return in_size_; }

  std::pair<Bytes, std::uint16_t> exchange(Command command, std::uint32_t address, Bytes data) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    wire::DatagramHeader header;
    header.command = command;
    header.index = 1;
    header.address = address;
    header.length = static_cast<std::uint16_t>(data.size());
    EXPECT_TRUE(builder.add(header, data).has_value());
    const auto frame = builder.finish();
    Bytes bytes(frame.begin(), frame.end());
    now_ns_ += 100'000;
    EXPECT_TRUE(segment_.process_frame(bytes, now_ns_));
    auto decoded = wire::decode_frame(bytes);
    EXPECT_TRUE(decoded);
    std::pair<Bytes, std::uint16_t> out;
    for (const auto& d : *decoded.frame) {
      out.first.assign(d.data.begin(), d.data.end());
      out.second = d.wkc;
    }
    return out;
  }
  static std::uint32_t fp(std::uint16_t offset) { return wire::physical_address(kStation, offset); }

  void configure_sm(std::size_t sm, std::uint16_t start, std::uint16_t length,
                    wire::SmControl control, bool enable = true) {
    wire::SyncManagerConfig c;
    c.physical_start = start;
    c.length = length;
    c.control = control;
    c.activate.enable = enable;
    const auto bytes = c.encode();
    exchange(Command::fpwr, fp(reg::sync_manager(sm)), Bytes(bytes.begin(), bytes.end()));
  }

 private:
  Segment segment_;
  CoeDevice* device_ = nullptr;
  std::uint16_t out_size_;
  std::uint16_t in_size_;
  std::uint8_t counter_ = 0;
  std::int64_t now_ns_ = 1'000'000;
};

// ---- SDO transfers --------------------------------------------------------------------------

TEST(SdoUpload, ExpeditedCarriesExactBytesAndSizeBits) {
  Master m;
  auto u8 = m.upload(0x2000, 2);
  EXPECT_TRUE(u8.expedited);
  EXPECT_EQ(u8.command, 0x4F);
  EXPECT_EQ(u8.value, Bytes{0x00});
  auto u16 = m.upload(0x2000, 1);
  EXPECT_EQ(u16.command, 0x4B);
  EXPECT_EQ(u16.value, (Bytes{0x34, 0x12}));
  auto u32 = m.upload(0x2000, 3);
  EXPECT_EQ(u32.command, 0x43);
  EXPECT_EQ(u32.value, (Bytes{0x0D, 0x0C, 0x0B, 0x0A}));
  auto sub0 = m.upload(0x1018, 0);
  EXPECT_EQ(sub0.value, Bytes{4});
}

TEST(SdoUpload, NormalFitsOneMailbox) {
  Master m;
  auto blob = m.upload(0x2001, 0);
  EXPECT_FALSE(blob.expedited);
  EXPECT_EQ(blob.command, 0x41);
  EXPECT_EQ(blob.segments, 0);
  EXPECT_EQ(blob.value, (Bytes{'h', 'e', 'l', 'l', 'o', '-', 's', 'i', 'm', 0, 0, 0}));
  auto name = m.upload(0x1008, 0);
  const std::string text = "CoE test device";
  EXPECT_EQ(name.value, Bytes(text.begin(), text.end()));
}

TEST(SdoDownload, ExpeditedAndNormalStoreExactValues) {
  Master m;
  EXPECT_EQ(m.download(0x2000, 2, {0x7F}).abort, 0u);
  EXPECT_EQ(m.od().get<std::uint8_t>(0x2000, 2), 0x7F);
  EXPECT_EQ(m.download(0x2000, 1, {0xCD, 0xAB}).abort, 0u);
  EXPECT_EQ(m.od().get<std::uint16_t>(0x2000, 1), 0xABCD);
  EXPECT_EQ(m.download(0x2000, 3, {1, 2, 3, 4}).abort, 0u);
  EXPECT_EQ(m.od().get<std::uint32_t>(0x2000, 3), 0x04030201u);
  // Normal (non-expedited) transfer of a short value.
  EXPECT_EQ(m.download(0x2000, 1, {0x11, 0x22}, false, true).abort, 0u);
  EXPECT_EQ(m.od().get<std::uint16_t>(0x2000, 1), 0x2211);
  const Bytes blob = pattern(12, 0x40);
  auto normal = m.download(0x2001, 0, blob);
  EXPECT_EQ(normal.abort, 0u);
  EXPECT_EQ(normal.segments, 0);
  EXPECT_EQ(stored(m.od(), 0x2001, 0), blob);
  // Expedited without size indication: 4 bytes for a 2-byte entry.
  wire::SdoInitiateDownloadRequest unsized;
  unsized.index = 0x2000;
  unsized.subindex = 1;
  unsized.expedited = true;
  unsized.size_indicated = false;
  unsized.data = {0x55, 0x66, 0, 0};
  EXPECT_TRUE(
      std::holds_alternative<wire::SdoInitiateDownloadResponse>(Master::decode(m.sdo(unsized))));
  EXPECT_EQ(m.od().get<std::uint16_t>(0x2000, 1), 0x6655);
}

struct SegmentCase {
  std::uint16_t out_size;
  std::uint16_t in_size;
};

class SegmentedTransfers : public ::testing::TestWithParam<SegmentCase> {};

int expected_segments(std::size_t size, std::size_t mailbox) {
  const std::size_t first = mailbox - 16;
  if (size <= first) return 0;
  const std::size_t per = mailbox - 9;
  return static_cast<int>((size - first + per - 1) / per);
}

TEST_P(SegmentedTransfers, UploadAndDownload80And192Bytes) {
  const auto [out_size, in_size] = GetParam();
  Master m(out_size, in_size);
  for (std::uint16_t index : {std::uint16_t{0x2002}, std::uint16_t{0x2003}}) {
    const std::size_t size = index == 0x2002 ? 80 : 192;
    auto up = m.upload(index, 0);
    EXPECT_EQ(up.abort, 0u);
    EXPECT_EQ(up.value, pattern(size)) << "0x" << std::hex << index;
    EXPECT_EQ(up.segments, expected_segments(size, in_size)) << "in " << in_size;
    EXPECT_FALSE(m.server().transfer_in_progress());

    const Bytes fresh = pattern(size, 0x80);
    auto down = m.download(index, 0, fresh);
    EXPECT_EQ(down.abort, 0u);
    EXPECT_EQ(down.segments, expected_segments(size, out_size)) << "out " << out_size;
    EXPECT_EQ(stored(m.od(), index, 0), fresh);
    EXPECT_EQ(m.upload(index, 0).value, fresh);
  }
}

INSTANTIATE_TEST_SUITE_P(MailboxSizes, SegmentedTransfers,
                         ::testing::Values(SegmentCase{32, 32}, SegmentCase{48, 64},
                                           SegmentCase{128, 128}, SegmentCase{64, 256},
                                           SegmentCase{256, 40}));

TEST(SegmentedTransfers, ToggleErrorsAbortAndDiscardTheTransfer) {
  Master m(32, 32);
  auto init = Master::decode(m.sdo(wire::SdoInitiateUploadRequest{0x2002, 0, false}));
  ASSERT_TRUE(std::holds_alternative<wire::SdoInitiateUploadResponse>(init));
  auto bad = Master::decode(m.sdo(wire::SdoUploadSegmentRequest{true}));
  EXPECT_EQ(Master::abort_code(bad), code(SdoAbortCode::toggle_bit_not_changed));
  EXPECT_EQ(std::get<wire::SdoAbort>(bad).index, 0x2002);
  EXPECT_FALSE(m.server().transfer_in_progress());
  auto after = Master::decode(m.sdo(wire::SdoUploadSegmentRequest{false}));
  EXPECT_EQ(Master::abort_code(after), code(SdoAbortCode::command_specifier_unknown));

  wire::SdoInitiateDownloadRequest down;
  down.index = 0x2002;
  down.complete_size = 80;
  down.data = pattern(16);
  ASSERT_TRUE(
      std::holds_alternative<wire::SdoInitiateDownloadResponse>(Master::decode(m.sdo(down))));
  auto ok = Master::decode(m.sdo(wire::SdoDownloadSegmentRequest{false, false, pattern(23)}));
  ASSERT_TRUE(std::holds_alternative<wire::SdoDownloadSegmentResponse>(ok));
  auto repeat = Master::decode(m.sdo(wire::SdoDownloadSegmentRequest{false, false, pattern(23)}));
  EXPECT_EQ(Master::abort_code(repeat), code(SdoAbortCode::toggle_bit_not_changed));
  EXPECT_EQ(stored(m.od(), 0x2002, 0), pattern(80)) << "nothing stored";
  auto orphan = Master::decode(m.sdo(wire::SdoDownloadSegmentRequest{true, true, {1}}));
  EXPECT_EQ(Master::abort_code(orphan), code(SdoAbortCode::command_specifier_unknown));
}

TEST(SegmentedTransfers, MasterAbortEndsTheTransferWithoutReply) {
  Master m(32, 32);
  ASSERT_TRUE(std::holds_alternative<wire::SdoInitiateUploadResponse>(
      Master::decode(m.sdo(wire::SdoInitiateUploadRequest{0x2003, 0, false}))));
  EXPECT_TRUE(m.server().transfer_in_progress());
  EXPECT_FALSE(m.sdo(wire::SdoAbort{0x2003, 0, 0x05040000, wire::SdoDirection::request}));
  EXPECT_FALSE(m.server().transfer_in_progress());
}

TEST(SdoCommands, UnknownCommandSpecifierAborts) {
  Master m;
  Bytes raw{0x00, 0x20, 0xA0, 0x00, 0x20, 0x01, 0, 0, 0, 0};  // ccs 5
  auto reply = m.request(MailboxType::coe, raw);
  auto message = Master::decode(reply);
  EXPECT_EQ(Master::abort_code(message), code(SdoAbortCode::command_specifier_unknown));
  EXPECT_EQ(std::get<wire::SdoAbort>(message).index, 0x2000);
  EXPECT_EQ(std::get<wire::SdoAbort>(message).subindex, 1);
}

// ---- complete access ---------------------------------------------------------------------------

TEST(CompleteAccess, UploadPadsSubindexZeroLikeRealSlaves) {
  Master m;
  auto assign = m.upload(0x1C12, 0, true);
  EXPECT_EQ(assign.abort, 0u);
  EXPECT_FALSE(assign.expedited);
  EXPECT_EQ(assign.value, (Bytes{0x01, 0x00, 0x01, 0x16}));
  auto mapping = m.upload(0x1A00, 0, true);
  EXPECT_EQ(mapping.value, (Bytes{0x02, 0x00, 0x08, 0x01, 0x00, 0x60, 0x20, 0x02, 0x00, 0x60}));
  auto from_one = m.upload(0x1A00, 1, true);
  EXPECT_EQ(from_one.value, (Bytes{0x08, 0x01, 0x00, 0x60, 0x20, 0x02, 0x00, 0x60}));
  EXPECT_EQ(m.upload(0x2001, 0, true).abort, code(SdoAbortCode::complete_access_not_supported));
}

TEST(CompleteAccess, LargeRecordUploadIsSegmented) {
  Master m(32, 32);
  auto identity = m.upload(0x1018, 0, true);
  EXPECT_EQ(identity.segments, 1);
  EXPECT_EQ(identity.value,
            (Bytes{0x04, 0x00, 0xCE, 0x0A, 0, 0, 0x02, 0x16, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0}));
}

TEST(CompleteAccess, DownloadRewritesAssignmentAndMapping) {
  Master m;
  EXPECT_EQ(m.download(0x1C12, 0, {0x02, 0x00, 0x00, 0x16, 0x01, 0x16}, true).abort, 0u);
  EXPECT_EQ(m.od().get<std::uint8_t>(0x1C12, 0), 2);
  EXPECT_EQ(m.od().get<std::uint16_t>(0x1C12, 1), 0x1600);
  EXPECT_EQ(m.od().get<std::uint16_t>(0x1C12, 2), 0x1601);
  EXPECT_EQ(m.download(0x1600, 0, {0x01, 0x00, 0x01, 0x00, 0x01, 0x70}, true).abort, 0u);
  auto layout = process_data_layout(m.od(), 2);
  ASSERT_TRUE(layout.ok());
  EXPECT_EQ(layout->byte_length, 2u) << "1 bit, then 1 bit + 7 gap bits";
  EXPECT_EQ(m.download(0x1C12, 0, {0x01, 0x00, 0x00}, true).abort,
            code(SdoAbortCode::length_too_low));
  m.set_state(AlState::safeop);
  EXPECT_EQ(m.download(0x1C12, 0, {0x01, 0x00, 0x01, 0x16}, true).abort,
            code(SdoAbortCode::cannot_store_device_state));
}

TEST(CompleteAccess, RefusedWhenTheServerDoesNotOfferIt) {
  CoeServerConfig config;
  config.complete_access = false;
  Master m(128, 128, config);
  EXPECT_EQ(m.upload(0x1C12, 0, true).abort, code(SdoAbortCode::complete_access_not_supported));
  EXPECT_EQ(m.download(0x1C12, 0, {0, 0}, true).abort,
            code(SdoAbortCode::complete_access_not_supported));
}

// ---- aborts ------------------------------------------------------------------------------------

TEST(SdoAborts, EveryRuleAnswersItsCode) {
  Master m;
  EXPECT_EQ(m.upload(0x5555, 0).abort, code(SdoAbortCode::object_does_not_exist));
  EXPECT_EQ(m.download(0x5555, 0, {1}).abort, code(SdoAbortCode::object_does_not_exist));
  EXPECT_EQ(m.upload(0x2000, 9).abort, code(SdoAbortCode::subindex_does_not_exist));
  EXPECT_EQ(m.download(0x2000, 1, {1, 2, 3}).abort, code(SdoAbortCode::length_too_high));
  EXPECT_EQ(m.download(0x2000, 1, {1}).abort, code(SdoAbortCode::length_too_low));
  EXPECT_EQ(m.download(0x2000, 3, pattern(8)).abort, code(SdoAbortCode::length_too_high))
      << "a normal transfer announcing too much is refused at once";
  EXPECT_EQ(m.download(0x2000, 4, {1, 2}).abort, code(SdoAbortCode::write_of_read_only));
  EXPECT_EQ(m.upload(0x2000, 5).abort, code(SdoAbortCode::read_of_write_only));
  EXPECT_EQ(m.download(0x2000, 7, {2}).abort, code(SdoAbortCode::value_range_exceeded));
  EXPECT_EQ(m.download(0x8000, 0, {151, 0}).abort, code(SdoAbortCode::value_too_high));
  EXPECT_EQ(m.download(0x8000, 0, {0xCD, 0xFF}).abort, code(SdoAbortCode::value_too_low));
  EXPECT_EQ(m.download(0x8000, 0, {150, 0}).abort, 0u);
  EXPECT_EQ(m.download(0x2000, 6, {1, 0}).abort, 0u);
  m.set_state(AlState::safeop);
  EXPECT_EQ(m.download(0x2000, 6, {2, 0}).abort, code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(m.od().get<std::int16_t>(0x2000, 6), 1);
  EXPECT_EQ(m.server().stats().aborts_sent, 12u);
}

TEST(SdoAborts, SegmentedDownloadShorterThanAnnouncedIsALengthMismatch) {
  Master m(32, 32);
  wire::SdoInitiateDownloadRequest init;
  init.index = 0x2002;
  init.complete_size = 80;
  init.data = pattern(16);
  ASSERT_TRUE(
      std::holds_alternative<wire::SdoInitiateDownloadResponse>(Master::decode(m.sdo(init))));
  auto last = Master::decode(m.sdo(wire::SdoDownloadSegmentRequest{false, true, pattern(23)}));
  EXPECT_EQ(Master::abort_code(last), code(SdoAbortCode::length_mismatch));
  EXPECT_EQ(stored(m.od(), 0x2002, 0), pattern(80));
}

// ---- SDO information ---------------------------------------------------------------------------

struct InfoResult {
  std::optional<wire::SdoInfoMessage> message;
  int fragments = 0;
  std::vector<wire::SdoInfoHeader> headers;
};

InfoResult info(Master& m, const wire::SdoInfoMessage& request) {
  InfoResult result;
  auto data = wire::encode_sdo_info(request);
  EXPECT_TRUE(data.ok());
  auto reply = m.request(MailboxType::coe, *data);
  wire::SdoInfoReassembler reassembler;
  while (reply) {
    ++result.fragments;
    auto fragment = wire::decode_sdo_info_fragment(reply->data);
    EXPECT_TRUE(fragment.ok());
    if (!fragment) break;
    result.headers.push_back(fragment->header);
    auto status = reassembler.add(reply->data);
    EXPECT_TRUE(status.ok()) << status.error().describe();
    if (!status) break;
    if (*status == wire::SdoInfoReassembler::Status::complete) {
      auto message = reassembler.message();
      EXPECT_TRUE(message.ok());
      if (message) result.message = *message;
      break;
    }
    reply = m.read();
  }
  return result;
}

TEST(SdoInformation, OdListsAreFragmentedToTheMailbox) {
  Master small(128, 32);
  const std::vector<std::uint16_t> all{0x1000, 0x1008, 0x1018, 0x1600, 0x1601, 0x1A00,
                                       0x1C00, 0x1C12, 0x1C13, 0x2000, 0x2001, 0x2002,
                                       0x2003, 0x6000, 0x7000, 0x7001, 0x8000};
  auto listed = info(small, wire::OdListRequest{wire::OdListType::all});
  ASSERT_TRUE(listed.message.has_value());
  EXPECT_EQ(std::get<wire::OdListResponse>(*listed.message).indices, all);
  // 32-byte mailbox: 26 bytes of data, 20 per fragment after the headers; 2 + 34 bytes -> 2.
  EXPECT_EQ(listed.fragments, 2);
  ASSERT_EQ(listed.headers.size(), 2u);
  EXPECT_TRUE(listed.headers[0].incomplete);
  EXPECT_EQ(listed.headers[0].fragments_left, 1);
  EXPECT_FALSE(listed.headers[1].incomplete);
  EXPECT_EQ(listed.headers[1].fragments_left, 0);

  Master big;
  auto one = info(big, wire::OdListRequest{wire::OdListType::all});
  EXPECT_EQ(one.fragments, 1);
  EXPECT_EQ(std::get<wire::OdListResponse>(*one.message).indices, all);
  EXPECT_EQ(std::get<wire::OdListResponse>(
                *info(big, wire::OdListRequest{wire::OdListType::rx_pdo_mappable}).message)
                .indices,
            (std::vector<std::uint16_t>{0x7000, 0x7001}));
  EXPECT_EQ(std::get<wire::OdListResponse>(
                *info(big, wire::OdListRequest{wire::OdListType::tx_pdo_mappable}).message)
                .indices,
            (std::vector<std::uint16_t>{0x6000}));
  EXPECT_TRUE(std::get<wire::OdListResponse>(
                  *info(big, wire::OdListRequest{wire::OdListType::backup}).message)
                  .indices.empty());
  EXPECT_EQ(std::get<wire::OdListResponse>(
                *info(big, wire::OdListRequest{wire::OdListType::number_of_objects}).message)
                .indices,
            (std::vector<std::uint16_t>{17, 2, 1, 0, 0}));
}

TEST(SdoInformation, DescriptionsOfObjectsAndEntries) {
  Master m;
  auto object = info(m, wire::ObjectDescriptionRequest{0x1018});
  ASSERT_TRUE(object.message.has_value());
  EXPECT_EQ(
      std::get<wire::ObjectDescriptionResponse>(*object.message),
      (wire::ObjectDescriptionResponse{0x1018, 0x0023, 4, wire::ObjectCode::record, "Identity"}));
  auto var = info(m, wire::ObjectDescriptionRequest{0x8000});
  EXPECT_EQ(std::get<wire::ObjectDescriptionResponse>(*var.message),
            (wire::ObjectDescriptionResponse{0x8000, 0x0003, 0, wire::ObjectCode::var, "Limit"}));

  auto entry = info(m, wire::EntryDescriptionRequest{0x8000, 0, 0x7F});
  ASSERT_TRUE(entry.message.has_value());
  wire::EntryDescriptionResponse expected;
  expected.index = 0x8000;
  expected.subindex = 0;
  expected.value_info = 0x7F;
  expected.data_type = 0x0003;
  expected.bit_length = 16;
  expected.object_access = kAccessReadWrite;
  expected.unit_type = 0x002D0000;
  expected.default_value = {20, 0};
  expected.minimum_value = {0xCE, 0xFF};
  expected.maximum_value = {150, 0};
  expected.description = "Limit";
  EXPECT_EQ(std::get<wire::EntryDescriptionResponse>(*entry.message), expected);

  // Flags for values the entry lacks (or a string cannot have) are cleared in the answer.
  auto text = info(m, wire::EntryDescriptionRequest{0x1008, 0, 0x10});
  const auto& name = std::get<wire::EntryDescriptionResponse>(*text.message);
  EXPECT_EQ(name.value_info, 0x00);
  EXPECT_EQ(name.data_type, 0x0009);
  EXPECT_EQ(name.bit_length, 8 * 15);
  EXPECT_EQ(name.description, "Device name");
  auto mapped = info(m, wire::EntryDescriptionRequest{0x6000, 2, 0x07});
  const auto& value = std::get<wire::EntryDescriptionResponse>(*mapped.message);
  EXPECT_EQ(value.object_access, kAccessRead | kAccessTxPdo);
  EXPECT_EQ(value.description, "Value");

  EXPECT_EQ(std::get<wire::SdoInfoError>(*info(m, wire::ObjectDescriptionRequest{0x4444}).message)
                .abort_code,
            code(SdoAbortCode::object_does_not_exist));
  EXPECT_EQ(
      std::get<wire::SdoInfoError>(*info(m, wire::EntryDescriptionRequest{0x1018, 7, 0}).message)
          .abort_code,
      code(SdoAbortCode::subindex_does_not_exist));
}

TEST(SdoInformation, RefusedWithAMailboxErrorWhenNotOffered) {
  CoeServerConfig config;
  config.sdo_info = false;
  Master m(128, 128, config);
  auto data = wire::encode_sdo_info(wire::OdListRequest{wire::OdListType::all});
  auto reply = m.request(MailboxType::coe, *data);
  ASSERT_TRUE(reply);
  EXPECT_EQ(reply->header.type, MailboxType::error);
  EXPECT_EQ(wire::decode_mailbox_error(reply->data)->detail,
            static_cast<std::uint16_t>(wire::MailboxErrorCode::service_not_supported));
}

// ---- emergencies, counters, repeat ------------------------------------------------------------

TEST(Emergencies, WaitBehindAFullMailbox) {
  Master m;
  // A request whose reply stays unread, then an emergency from the device.
  m.set_counter(0);
  ASSERT_TRUE(m.write(m.encode(
      MailboxType::coe, *wire::encode_sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false}), 1)));
  m.server().queue_emergency(m.esc(), {0x8611, 0x80, {1, 2, 3, 4, 5}});
  EXPECT_EQ(m.server().queued_replies(), 1u);
  auto sdo_reply = m.read();
  ASSERT_TRUE(sdo_reply);
  EXPECT_EQ(sdo_reply->header.counter, 1);
  EXPECT_TRUE(std::holds_alternative<wire::SdoInitiateUploadResponse>(Master::decode(sdo_reply)));
  auto emergency = m.read();
  ASSERT_TRUE(emergency);
  EXPECT_EQ(emergency->header.counter, 2);
  EXPECT_EQ(emergency->header.address, kStation);
  auto decoded = wire::decode_emergency(emergency->data);
  ASSERT_TRUE(decoded.ok());
  EXPECT_EQ(*decoded, (wire::Emergency{0x8611, 0x80, {1, 2, 3, 4, 5}}));
  EXPECT_FALSE(m.read()) << "nothing more";
  // With the mailbox free, an emergency goes out at once.
  m.server().queue_emergency(m.esc(), {0xFF00, 0x01, {}});
  EXPECT_EQ(m.server().queued_replies(), 0u);
  EXPECT_EQ(wire::decode_emergency(m.read()->data)->error_code, 0xFF00);
  EXPECT_EQ(m.server().stats().emergencies_sent, 2u);
}

TEST(MailboxCounter, RepliesCountOneToSevenThenWrap) {
  Master m;
  std::vector<std::uint8_t> counters;
  for (int i = 0; i < 9; ++i)
    counters.push_back(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter);
  EXPECT_EQ(counters, (std::vector<std::uint8_t>{1, 2, 3, 4, 5, 6, 7, 1, 2}));
}

TEST(MailboxCounter, EchoModeAnswersWithTheRequestCounter) {
  CoeServerConfig config;
  config.counter_mode = ReplyCounterMode::echo_request;
  Master m(128, 128, config);
  m.set_counter(4);
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 5);
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 6);
}

// The initiate download response echoes the request's 4 data bytes in its reserved field, as
// Beckhoff firmware does (the EL2828 in replay-ek1100-el2828-el2889.pcapng answers
// 60 08 f0 00 01 00 00 00 to a download of 1). Byte 14.. of SM1: 6 mailbox + 2 CoE + 4 + 4.
TEST(SdoDownload, ResponseEchoesTheRequestDataBytes) {
  Master m;
  wire::SdoInitiateDownloadRequest req;
  req.index = 0x2000;
  req.subindex = 3;
  req.expedited = true;
  req.data = {0x2A, 0, 0, 0};
  ASSERT_TRUE(m.write(m.encode(MailboxType::coe, *wire::encode_sdo(req), 1)));
  auto raw = m.read_raw();
  ASSERT_TRUE(raw);
  EXPECT_EQ((*raw)[8] >> 5, 3) << "initiate download response";
  EXPECT_EQ(Bytes(raw->begin() + 12, raw->begin() + 16), (Bytes{0x2A, 0, 0, 0}));
  // An aborted download has no such field: its bytes carry the abort code.
  req.index = 0x7777;
  ASSERT_TRUE(m.write(m.encode(MailboxType::coe, *wire::encode_sdo(req), 2)));
  raw = m.read_raw();
  ASSERT_TRUE(raw);
  EXPECT_EQ((*raw)[8] >> 5, 4) << "abort";
  EXPECT_EQ(wire::load_le32(&(*raw)[12]), 0x06020000u);
}

TEST(MailboxCounter, RepeatedRequestIsAnsweredAgainNotExecutedAgain) {
  Master m;
  int writes = 0;
  m.od().find(0x2000, 3)->on_written = [&](ObjectEntry&, const AccessContext&) { ++writes; };
  wire::SdoInitiateDownloadRequest req;
  req.index = 0x2000;
  req.subindex = 3;
  req.expedited = true;
  req.data = {1, 0, 0, 0};
  const Bytes mailbox = m.encode(MailboxType::coe, *wire::encode_sdo(req), 3);
  ASSERT_TRUE(m.write(mailbox));
  auto first = m.read_raw();
  ASSERT_TRUE(first);
  EXPECT_EQ(writes, 1);
  // The master lost the write's acknowledge and writes the same request again.
  ASSERT_TRUE(m.write(mailbox));
  EXPECT_EQ(writes, 1) << "not executed again";
  auto again = m.read_raw();
  ASSERT_TRUE(again);
  EXPECT_EQ(*again, *first) << "the same reply, same counter";
  // While that reply is still unread, a third copy adds nothing.
  ASSERT_TRUE(m.write(mailbox));
  EXPECT_TRUE(m.read_raw());
  EXPECT_FALSE(m.read_raw());
  EXPECT_EQ(m.server().stats().duplicates, 2u);
  // A new counter is a new request; counter 0 is never a repeat.
  req.data = {2, 0, 0, 0};
  ASSERT_TRUE(m.write(m.encode(MailboxType::coe, *wire::encode_sdo(req), 0)));
  ASSERT_TRUE(m.read_raw());
  ASSERT_TRUE(m.write(m.encode(MailboxType::coe, *wire::encode_sdo(req), 0)));
  ASSERT_TRUE(m.read_raw());
  EXPECT_EQ(writes, 3);
}

TEST(MailboxRepeat, ResendsTheLastReply) {
  Master m;
  auto reply = m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false});
  ASSERT_TRUE(reply);
  EXPECT_FALSE(m.read_raw()) << "read once";
  // Repeat request: toggle bit 1 of SM1's activate register.
  m.exchange(Command::fpwr, Master::fp(reg::sync_manager(1) + 6), {0x03});
  EXPECT_TRUE(m.esc().sync_manager(1).config.pdi_control.repeat_ack);
  auto again = m.read();
  ASSERT_TRUE(again);
  EXPECT_EQ(again->header, reply->header);
  EXPECT_EQ(again->data, reply->data);
  EXPECT_EQ(m.server().stats().repeats, 1u);
  EXPECT_EQ(m.server().stats().stage_responses_read[1], 1u) << "the repeat is not a new step";
  // The next request works as before.
  EXPECT_EQ(m.upload(0x2000, 2).value, Bytes{0});
}

// ---- mailbox errors ----------------------------------------------------------------------------

std::uint16_t mailbox_error_detail(const std::optional<Reply>& reply) {
  EXPECT_TRUE(reply);
  if (!reply) return 0;
  EXPECT_EQ(reply->header.type, MailboxType::error);
  auto error = wire::decode_mailbox_error(reply->data);
  EXPECT_TRUE(error.ok());
  return error.ok() ? error->detail : 0;
}

TEST(MailboxErrors, UnsupportedProtocolsAndMalformedHeaders) {
  Master m;
  EXPECT_EQ(mailbox_error_detail(m.request(MailboxType::foe, {0x01, 0x00, 0, 0, 0, 0})),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::unsupported_protocol));
  EXPECT_EQ(mailbox_error_detail(m.request(MailboxType::eoe, {0x00, 0x00, 0, 0})),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::unsupported_protocol));
  EXPECT_EQ(mailbox_error_detail(m.request(MailboxType::coe, {0x00})),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::size_too_short));
  EXPECT_EQ(mailbox_error_detail(m.request(MailboxType::coe, {0x00, 0x40, 0, 0, 0, 0, 0, 0})),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::service_not_supported))
      << "TxPDO service";
  EXPECT_EQ(mailbox_error_detail(m.request(MailboxType::coe, {0x00, 0x20, 0x40})),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::size_too_short))
      << "truncated SDO";
  // A length field beyond the mailbox.
  Bytes bad(128, 0);
  bad[0] = 200;
  bad[5] = 0x13;
  ASSERT_TRUE(m.write(bad));
  EXPECT_EQ(mailbox_error_detail(m.read()),
            static_cast<std::uint16_t>(wire::MailboxErrorCode::invalid_size));
  EXPECT_EQ(m.server().stats().mailbox_errors_sent, 6u);
}

TEST(MailboxErrors, AProtocolHandlerServesOtherTypes) {
  Master m;
  m.server().set_protocol_handler(
      MailboxType::foe, [](Esc&, const wire::MailboxHeader& header, wire::Bytes data) {
        EXPECT_EQ(header.type, MailboxType::foe);
        return std::vector<MailboxReply>{{MailboxType::foe, Bytes(data.rbegin(), data.rend())}};
      });
  auto reply = m.request(MailboxType::foe, {1, 2, 3});
  ASSERT_TRUE(reply);
  EXPECT_EQ(reply->header.type, MailboxType::foe);
  EXPECT_EQ(reply->data, (Bytes{3, 2, 1}));
}

// ---- fault rules -------------------------------------------------------------------------------

TEST(AbortRules, RequestStageAbortsBothDirectionsBeforeExecuting) {
  Master m;
  m.server().add_abort_rule({0x2000, 1, MailboxStage::request, 0x08000000, false});
  EXPECT_EQ(m.upload(0x2000, 1).abort, 0x08000000u);
  EXPECT_EQ(m.download(0x2000, 1, {9, 9}).abort, 0x08000000u);
  EXPECT_EQ(m.od().get<std::uint16_t>(0x2000, 1), 0x1234);
  EXPECT_EQ(m.upload(0x2000, 2).abort, 0u) << "other objects are untouched";
  m.server().add_abort_rule({0x2000, 1, MailboxStage::request, 0x06060000, true});
  EXPECT_EQ(m.server().abort_rules().size(), 1u) << "same key replaced";
  EXPECT_EQ(m.upload(0x2000, 1).abort, 0x06060000u);
  EXPECT_EQ(m.upload(0x2000, 1).abort, 0u) << "once-only";
  m.server().add_abort_rule({0x2000, 1, MailboxStage::download_init, 0x06060000, false});
  EXPECT_EQ(m.upload(0x2000, 1).abort, 0u) << "download_init leaves uploads alone";
  EXPECT_EQ(m.download(0x2000, 1, {9, 9}).abort, 0x06060000u);
  m.server().clear_faults();
  EXPECT_EQ(m.download(0x2000, 1, {9, 9}).abort, 0u);
  EXPECT_EQ(m.server().stats().faults_applied, 4u);
}

TEST(AbortRules, SegmentStagesAbortMidTransferAndDiscardIt) {
  Master m(32, 32);
  m.server().add_abort_rule({0x2003, 0, MailboxStage::upload_segment, 0x06060000, true});
  auto up = m.upload(0x2003, 0);
  EXPECT_EQ(up.abort, 0x06060000u);
  EXPECT_EQ(up.segments, 0);
  EXPECT_FALSE(m.server().transfer_in_progress());
  EXPECT_EQ(m.upload(0x2003, 0).value, pattern(192));

  m.server().add_abort_rule({0x2003, 0, MailboxStage::download_segment, 0x08000020, true});
  auto down = m.download(0x2003, 0, pattern(192, 0x33));
  EXPECT_EQ(down.abort, 0x08000020u);
  EXPECT_FALSE(m.server().transfer_in_progress());
  EXPECT_EQ(stored(m.od(), 0x2003, 0), pattern(192)) << "nothing stored";
}

// Runs an upload of 0x2003 with a 32-byte mailbox up to the first segment and returns the raw
// replies of the initiate and the first segment.
std::pair<std::optional<Reply>, std::optional<Reply>> upload_first_segment(Master& m) {
  auto init = m.sdo(wire::SdoInitiateUploadRequest{0x2003, 0, false});
  auto segment = m.sdo(wire::SdoUploadSegmentRequest{false});
  return {init, segment};
}

TEST(ProtocolFaults, DropResponseLeavesTheMailboxEmpty) {
  Master m;
  m.server().add_protocol_fault(
      {0x2000, 1, MailboxStage::upload_init, {ProtocolFaultKind::drop_response, 0}, true});
  EXPECT_FALSE(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false}));
  EXPECT_EQ(m.upload(0x2000, 1).value, (Bytes{0x34, 0x12})) << "once-only";
  EXPECT_TRUE(m.server().protocol_faults().empty());
}

TEST(ProtocolFaults, CounterMismatchIsOneAhead) {
  Master m;
  m.server().add_protocol_fault(
      {0x2000, 1, MailboxStage::request, {ProtocolFaultKind::counter_mismatch, 0}, false});
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 2);
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 2, false})->header.counter, 2);
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 4)
      << "sticky, and matches download_init and upload_init";
  CoeServerConfig config;
  config.counter_mode = ReplyCounterMode::echo_request;
  Master echo(128, 128, config);
  echo.server().add_protocol_fault(
      {0x2000, 1, MailboxStage::upload_init, {ProtocolFaultKind::counter_mismatch, 0}, true});
  EXPECT_EQ(echo.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 2)
      << "request counter 1, reply next(1)";
}

TEST(ProtocolFaults, HeaderAndPayloadCorruptions) {
  Master m;
  const auto upload_reply = [&](ProtocolFault fault) {
    m.server().add_protocol_fault({0x2000, 1, MailboxStage::upload_init, fault, true});
    return m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false});
  };
  auto type = upload_reply({ProtocolFaultKind::mailbox_type, 4});
  ASSERT_TRUE(type);
  EXPECT_EQ(type->header.type, MailboxType::foe);
  auto service = upload_reply({ProtocolFaultKind::coe_service, 2});
  ASSERT_TRUE(service);
  EXPECT_EQ(wire::decode_coe_header(service->data)->service, wire::CoeService::sdo_request);
  auto payload = upload_reply({ProtocolFaultKind::invalid_coe_payload, 0});
  ASSERT_TRUE(payload);
  EXPECT_EQ(payload->data, Bytes{0x00});
  auto command = upload_reply({ProtocolFaultKind::sdo_command, 0x60});
  ASSERT_TRUE(command);
  EXPECT_EQ(command->data[2], 0x60);
  EXPECT_EQ(command->data.size(), 10u);
}

TEST(ProtocolFaults, SegmentCorruptions) {
  Master m(32, 32);
  m.server().add_protocol_fault(
      {0x2003, 0, MailboxStage::upload_segment, {ProtocolFaultKind::toggle_mismatch, 0}, true});
  auto [init, toggled] = upload_first_segment(m);
  auto toggled_message = Master::decode(toggled);
  ASSERT_TRUE(std::holds_alternative<wire::SdoUploadSegmentResponse>(toggled_message));
  EXPECT_TRUE(std::get<wire::SdoUploadSegmentResponse>(toggled_message).toggle);

  m.server().add_protocol_fault({0x2003,
                                 0,
                                 MailboxStage::upload_segment,
                                 {ProtocolFaultKind::invalid_segment_padding, 0},
                                 true});
  auto [init2, padded] = upload_first_segment(m);
  ASSERT_TRUE(padded);
  EXPECT_EQ(padded->data.size(), 10u);
  EXPECT_EQ(padded->data[2], 0x0F) << "000t 111 1 with toggle 0";
  auto padded_message = Master::decode(padded);
  EXPECT_TRUE(std::get<wire::SdoUploadSegmentResponse>(padded_message).data.empty());

  m.server().add_protocol_fault(
      {0x2003, 0, MailboxStage::upload_segment, {ProtocolFaultKind::segment_command, 0x60}, true});
  auto [init3, single] = upload_first_segment(m);
  ASSERT_TRUE(single);
  EXPECT_EQ(single->data, (Bytes{0x00, 0x30, 0x60}));

  m.server().add_protocol_fault({0x2003,
                                 0,
                                 MailboxStage::download_segment,
                                 {ProtocolFaultKind::segment_command, 0x20},
                                 true});
  wire::SdoInitiateDownloadRequest down;
  down.index = 0x2003;
  down.complete_size = 192;
  down.data = pattern(16);
  ASSERT_TRUE(m.sdo(down));
  auto seg = m.sdo(wire::SdoDownloadSegmentRequest{false, false, pattern(23)});
  ASSERT_TRUE(seg);
  EXPECT_EQ(seg->data, (Bytes{0x00, 0x30, 0x20}));

  m.server().add_protocol_fault(
      {0x2003, 0, MailboxStage::download_segment, {ProtocolFaultKind::toggle_mismatch, 0}, true});
  auto seg2 = Master::decode(m.sdo(wire::SdoDownloadSegmentRequest{true, false, pattern(23)}));
  ASSERT_TRUE(std::holds_alternative<wire::SdoDownloadSegmentResponse>(seg2));
  EXPECT_FALSE(std::get<wire::SdoDownloadSegmentResponse>(seg2).toggle);
  EXPECT_TRUE(m.server().protocol_faults().empty());
}

// ---- counters and milestones -------------------------------------------------------------------

TEST(Stats, StagesAreCountedWhenProducedAndWhenFetched) {
  Master m(32, 32);
  std::vector<std::pair<MailboxStage, std::uint16_t>> steps;
  m.server().set_step_observer([&](MailboxStage stage, std::uint16_t index, std::uint8_t) {
    steps.emplace_back(stage, index);
  });
  ASSERT_EQ(m.upload(0x2002, 0).segments, 3);  // 16 + 23 + 23 + 18
  ASSERT_EQ(m.download(0x2002, 0, pattern(80)).segments, 3);
  EXPECT_EQ(m.upload(0x5555, 0).abort, code(SdoAbortCode::object_does_not_exist));
  const auto& s = m.server().stats();
  EXPECT_EQ(s.stage_responses[static_cast<std::size_t>(MailboxStage::upload_init)], 1u);
  EXPECT_EQ(s.stage_responses[static_cast<std::size_t>(MailboxStage::upload_segment)], 3u);
  EXPECT_EQ(s.stage_responses[static_cast<std::size_t>(MailboxStage::download_init)], 1u);
  EXPECT_EQ(s.stage_responses[static_cast<std::size_t>(MailboxStage::download_segment)], 3u);
  EXPECT_EQ(s.stage_responses_read, s.stage_responses);
  EXPECT_EQ(s.requests_served, 9u);
  EXPECT_EQ(s.aborts_sent, 1u);
  EXPECT_EQ(s.replies_sent, 9u);
  EXPECT_EQ(s.replies_read, 9u);
  EXPECT_EQ(steps.size(), 8u) << "aborts are not steps";
  EXPECT_EQ(steps[1],
            (std::pair<MailboxStage, std::uint16_t>{MailboxStage::upload_segment, 0x2002}));
}

TEST(Stats, DisablingTheMailboxResetsTransfersAndQueue) {
  Master m(32, 32);
  ASSERT_TRUE(m.sdo(wire::SdoInitiateUploadRequest{0x2003, 0, false}));
  ASSERT_TRUE(m.server().transfer_in_progress());
  m.server().queue_emergency(m.esc(), {0x1000, 0, {}});
  m.server().queue_emergency(m.esc(), {0x1001, 0, {}});
  EXPECT_EQ(m.server().queued_replies(), 1u) << "the first went out, the second waits";
  m.configure_sm(1, kInStart, 32, wire::kMailboxInControl, false);
  EXPECT_FALSE(m.server().transfer_in_progress());
  EXPECT_EQ(m.server().queued_replies(), 0u);
  m.configure_sm(1, kInStart, 32, wire::kMailboxInControl, true);
  EXPECT_FALSE(m.read()) << "nothing left from before";
  EXPECT_EQ(m.sdo(wire::SdoInitiateUploadRequest{0x2000, 1, false})->header.counter, 1)
      << "counters start over";
}

// ---- PDO mapping over SDO
// -------------------------------------------------------------------------

TEST(PdoMappingOverSdo, ChangedInPreopRefusedInSafeop) {
  Master m;
  const auto u32 = [](std::uint32_t v) { return to_le_bytes(v); };
  EXPECT_EQ(m.download(0x1600, 1, u32(0x70010001)).abort,
            code(SdoAbortCode::cannot_store_device_state))
      << "subindex 0 must be 0 first";
  EXPECT_EQ(m.download(0x1600, 0, {0}).abort, 0u);
  EXPECT_EQ(m.download(0x1600, 1, u32(0x60000108)).abort, code(SdoAbortCode::object_not_mappable));
  EXPECT_EQ(m.download(0x1600, 1, u32(0x70000008)).abort, code(SdoAbortCode::object_not_mappable));
  EXPECT_EQ(m.download(0x1600, 1, u32(0x70000010)).abort, 0u);
  EXPECT_EQ(m.download(0x1600, 2, u32(0x00000010)).abort, 0u);
  EXPECT_EQ(m.download(0x1600, 0, {2}).abort, 0u);
  EXPECT_EQ(m.download(0x1C12, 0, {0}).abort, 0u);
  EXPECT_EQ(m.download(0x1C12, 1, {0x00, 0x16}).abort, 0u);
  EXPECT_EQ(m.download(0x1C12, 2, {0x01, 0x16}).abort, 0u);
  EXPECT_EQ(m.download(0x1C12, 0, {2}).abort, 0u);
  auto layout = process_data_layout(m.od(), 2);
  ASSERT_TRUE(layout.ok());
  EXPECT_EQ(layout->byte_length, 5u);
  ASSERT_EQ(layout->entries.size(), 4u);
  EXPECT_EQ(layout->entries[2], (MappedEntry{0x1601, 0x7001, 0, 32, 1, false}));
  m.set_state(AlState::safeop);
  EXPECT_EQ(m.download(0x1C12, 0, {0}).abort, code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(m.download(0x1600, 0, {0}).abort, code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(m.upload(0x1C12, 0, true).value, (Bytes{0x02, 0x00, 0x00, 0x16, 0x01, 0x16}))
      << "still readable";
}

}  // namespace
}  // namespace ecat::sim

namespace ecat::sim {
namespace {

// Whatever a master writes into the mailbox, the server answers or stays silent, never breaks,
// and afterwards still serves ordinary requests.
TEST(Robustness, RandomMailboxesNeverBreakTheServer) {
  Master m(32, 48);
  std::mt19937 rng(20240611);
  const auto byte = [&] { return static_cast<std::uint8_t>(rng() & 0xFF); };
  int replies = 0;
  for (int i = 0; i < 3000; ++i) {
    Bytes data(rng() % 27);
    for (auto& b : data)
      b = byte();
    // Mostly well-formed CoE headers with SDO / SDO information services and valid-looking
    // commands, so the deeper paths are reached too.
    if (data.size() >= 2 && rng() % 4 != 0) {
      data[0] = 0;
      data[1] = static_cast<std::uint8_t>((rng() % 2 == 0 ? 2 : 8) << 4);
    }
    if (data.size() >= 6 && rng() % 2 == 0) {
      const std::array<std::uint16_t, 6> indices{0x2000, 0x2002, 0x2003, 0x1C12, 0x1600, 0x1018};
      const std::uint16_t index = indices[rng() % indices.size()];
      data[3] = static_cast<std::uint8_t>(index);
      data[4] = static_cast<std::uint8_t>(index >> 8);
      data[5] = static_cast<std::uint8_t>(rng() % 5);
    }
    wire::MailboxHeader header;
    header.type = rng() % 8 == 0 ? static_cast<MailboxType>(rng() % 16) : MailboxType::coe;
    header.counter = static_cast<std::uint8_t>(rng() % 8);
    Bytes mailbox = *wire::encode_mailbox(header, data);
    if (rng() % 16 == 0) mailbox[0] = byte();  // a length that may not fit
    ASSERT_TRUE(m.write(mailbox));
    for (int k = 0; k < 8 && m.read_raw(); ++k)
      ++replies;
  }
  EXPECT_GT(replies, 1000);
  EXPECT_FALSE(m.sdo(wire::SdoAbort{0, 0, 0x08000000, wire::SdoDirection::request}));
  m.set_state(AlState::preop);
  m.od().set<std::uint16_t>(0x2000, 1, 0x4321);
  EXPECT_EQ(m.upload(0x2000, 1).value, (Bytes{0x21, 0x43}));
}

}  // namespace
}  // namespace ecat::sim
