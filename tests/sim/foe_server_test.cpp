// The simulator's FoE server behind the "mailbox" profile, driven with raw FoE packets through
// SM0/SM1 of a real Esc: reads and writes with their exact replies, passwords, read-only files,
// the store's bound, BUSY answers, packet numbers, the firmware slot (BOOTSTRAP only, image
// checked, started at BOOT -> INIT and visible in 0x100A) and the fault hooks.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/foe_server.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/foe.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;
using wire::AlState;
using wire::FoeMessage;

constexpr std::size_t kPacket = 52;  // 64-byte standard mailbox - 12

Bytes pattern(std::size_t n, unsigned step = 5) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * step + 1) & 0xFF);
  return out;
}

class FoeServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    test::add_device(segment_, "mbx", test::profile("mailbox"));
    m_.assign_stations();
    m_.bring_to_preop(0);
    sii_ = m_.sii(0);
    use_mailbox(sii_.standard_mailbox);
  }

  FoeServer& server() {
    auto* s = foe_server_of(segment_.esc(0));
    EXPECT_NE(s, nullptr);
    return *s;
  }

  void use_mailbox(const wire::SiiMailbox& mbx) { mbx_ = mbx; }

  // One FoE packet into SM0; the reply from SM1 (nullopt when none came).
  std::optional<FoeMessage> send(const FoeMessage& message) {
    auto data = wire::encode_foe(message);
    EXPECT_TRUE(data.ok());
    wire::MailboxHeader header;
    header.type = wire::MailboxType::foe;
    counter_ = wire::next_mailbox_counter(counter_);
    header.counter = counter_;
    auto bytes = wire::encode_mailbox(header, *data);
    EXPECT_TRUE(bytes.ok());
    Bytes padded = *bytes;
    padded.resize(mbx_.recv_size, 0);
    EXPECT_EQ(
        m_.exchange(wire::Command::fpwr, test::fp(m_.station(0), mbx_.recv_offset), padded).wkc, 1);
    auto r = m_.exchange(wire::Command::fprd, test::fp(m_.station(0), mbx_.send_offset),
                         Bytes(mbx_.send_size, 0));
    if (r.wkc != 1) return std::nullopt;
    auto decoded = wire::decode_mailbox(r.data);
    EXPECT_TRUE(decoded.ok());
    if (!decoded) return std::nullopt;
    EXPECT_EQ(decoded->header.type, wire::MailboxType::foe);
    auto foe = wire::decode_foe(decoded->data);
    EXPECT_TRUE(foe.ok());
    if (!foe) return std::nullopt;
    return *foe;
  }

  static std::uint32_t error_code(const std::optional<FoeMessage>& m) {
    if (!m || !std::holds_alternative<wire::FoeError>(*m)) return 0;
    return std::get<wire::FoeError>(*m).code;
  }

  // A whole write with `packet`-sized DATA packets; the reply to the last packet.
  std::optional<FoeMessage> write(const std::string& name, const Bytes& file,
                                  std::uint32_t password = 0, std::size_t packet = kPacket) {
    auto r = send(wire::FoeWriteRequest{password, name});
    if (!r || !std::holds_alternative<wire::FoeAck>(*r)) return r;
    std::size_t offset = 0;
    for (std::uint32_t n = 1;; ++n) {
      const std::size_t len = std::min(packet, file.size() - offset);
      r = send(wire::FoeData{n, Bytes(file.begin() + static_cast<std::ptrdiff_t>(offset),
                                      file.begin() + static_cast<std::ptrdiff_t>(offset + len))});
      offset += len;
      if (!r || !std::holds_alternative<wire::FoeAck>(*r) || len < packet) return r;
    }
  }

  // A whole read; nullopt on anything but DATA with the right numbers.
  std::optional<Bytes> read(const std::string& name, std::uint32_t password = 0) {
    Bytes file;
    auto r = send(wire::FoeReadRequest{password, name});
    for (std::uint32_t n = 1;; ++n) {
      if (!r || !std::holds_alternative<wire::FoeData>(*r)) return std::nullopt;
      const auto& d = std::get<wire::FoeData>(*r);
      EXPECT_EQ(d.packet_number, n);
      file.insert(file.end(), d.data.begin(), d.data.end());
      const bool last = d.data.size() < kPacket;
      r = send(wire::FoeAck{n});
      if (last) {
        EXPECT_FALSE(r.has_value());  // the last ACK is not answered
        return file;
      }
    }
  }

  // INIT, the bootstrap mailbox SyncManagers, BOOT.
  void enter_bootstrap() {
    ASSERT_EQ(m_.request(0, AlState::init).state, AlState::init);
    const auto& boot = sii_.bootstrap_mailbox;
    ASSERT_TRUE(boot.present());
    m_.write_sm(0, 0, boot.recv_offset, boot.recv_size, wire::kMailboxOutControl.encode());
    m_.write_sm(0, 1, boot.send_offset, boot.send_size, wire::kMailboxInControl.encode());
    ASSERT_EQ(m_.request(0, AlState::bootstrap).state, AlState::bootstrap);
    use_mailbox(boot);
    counter_ = 0;
  }

  Segment segment_;
  test::SimMaster m_{segment_};
  wire::SiiImage sii_;
  wire::SiiMailbox mbx_;
  std::uint8_t counter_ = 0;
};

TEST(FirmwareImage, Crc32AndHeaderRoundTrip) {
  const std::string check = "123456789";
  EXPECT_EQ(crc32(Bytes(check.begin(), check.end())), 0xCBF43926u);  // the CRC-32 check value
  auto image = make_firmware_image("2.1.0", Bytes{1, 2, 3});
  ASSERT_TRUE(image.ok());
  ASSERT_EQ(image->size(), kFirmwareHeaderSize + 3);
  EXPECT_EQ(Bytes(image->begin(), image->begin() + 12),
            (Bytes{'E', 'C', 'F', 'W', 3, 0, 0, 0, 0x1D, 0x80, 0xBC, 0x55}));  // crc32({1,2,3})
  auto parsed = parse_firmware_image(*image);
  ASSERT_TRUE(parsed.ok()) << parsed.error().describe();
  EXPECT_EQ(*parsed, (FirmwareImage{"2.1.0", Bytes{1, 2, 3}}));
  Bytes corrupt = *image;
  corrupt.back() ^= 0xFF;
  auto bad = parse_firmware_image(corrupt);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(),
            "firmware image: payload CRC-32 0x78BE6F90, the header says 0x55BC801D");
  Bytes short_image(image->begin(), image->end() - 1);
  EXPECT_FALSE(parse_firmware_image(short_image).ok());
  EXPECT_FALSE(parse_firmware_image(Bytes(10, 0)).ok());
  EXPECT_FALSE(make_firmware_image(std::string(33, 'v'), Bytes{}).ok());
}

TEST_F(FoeServerTest, TheProfilesDeclareFoeAndABootstrapMailbox) {
  EXPECT_NE(sii_.mailbox_protocols & wire::mailbox_protocol::kFoe, 0);
  EXPECT_EQ(sii_.bootstrap_mailbox, (wire::SiiMailbox{0x1200, 256, 0x1300, 256}));
  Segment servo;
  test::add_device(servo, "drive", test::profile("servo"));
  EXPECT_NE(foe_server_of(servo.esc(0)), nullptr);
  Segment el3202;
  test::add_device(el3202, "temp", test::profile("EL3202"));
  EXPECT_EQ(foe_server_of(el3202.esc(0)), nullptr);  // CoE only
}

TEST_F(FoeServerTest, WriteThenReadAFileOfWholePackets) {
  const Bytes file = pattern(2 * kPacket);
  auto last = write("data.bin", file);
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(*last, FoeMessage{wire::FoeAck{3}});  // DATA 3 was the empty one
  ASSERT_NE(server().file("data.bin"), nullptr);
  EXPECT_EQ(server().file("data.bin")->data, file);
  EXPECT_EQ(read("data.bin"), file);
  EXPECT_EQ(server().stats().files_written, 1u);
  EXPECT_EQ(server().stats().files_read, 1u);
  EXPECT_EQ(server().stats().data_sent, 3u);
  EXPECT_FALSE(server().transfer_in_progress());
}

TEST_F(FoeServerTest, ReadsOfMissingFilesAndWrongPasswords) {
  EXPECT_EQ(error_code(send(wire::FoeReadRequest{0, "nothing"})), 0x8001u);
  ASSERT_TRUE(server().put_file("secret", {pattern(10), 0x1234, false}).ok());
  EXPECT_EQ(error_code(send(wire::FoeReadRequest{0, "secret"})), 0x800Au);  // SOES: no rights
  EXPECT_EQ(error_code(send(wire::FoeWriteRequest{7, "secret"})), 0x800Au);
  EXPECT_EQ(read("secret", 0x1234), pattern(10));
  ASSERT_TRUE(server().put_file("ro", {pattern(3), 0, true}).ok());
  EXPECT_EQ(error_code(send(wire::FoeWriteRequest{0, "ro"})), 0x8002u);
  EXPECT_EQ(read("ro"), pattern(3));
  EXPECT_EQ(error_code(send(wire::FoeReadRequest{0, "firmware.efw"})), 0x8002u);
}

TEST_F(FoeServerTest, PacketNumbersAndOpcodesAreChecked) {
  ASSERT_EQ(send(wire::FoeWriteRequest{0, "f"}), FoeMessage{wire::FoeAck{0}});
  EXPECT_EQ(error_code(send(wire::FoeData{2, {1}})), 0x8005u);
  EXPECT_FALSE(server().transfer_in_progress());
  EXPECT_EQ(error_code(send(wire::FoeData{1, {1}})), 0x8004u);  // no write in progress
  EXPECT_EQ(error_code(send(wire::FoeAck{1})), 0x8004u);
  ASSERT_TRUE(server().put_file("r", {pattern(200), 0, false}).ok());
  ASSERT_TRUE(send(wire::FoeReadRequest{0, "r"}).has_value());
  EXPECT_EQ(error_code(send(wire::FoeAck{2})), 0x8005u);
  // An ERROR from the master ends a transfer silently.
  ASSERT_TRUE(send(wire::FoeReadRequest{0, "r"}).has_value());
  EXPECT_FALSE(send(wire::FoeError{0x8000, "stop"}).has_value());
  EXPECT_FALSE(server().transfer_in_progress());
  EXPECT_EQ(server().stats().errors_taken, 1u);
}

TEST_F(FoeServerTest, BusyAnswersPrecedeEachAck) {
  server().set_busy_per_packet(2);
  ASSERT_EQ(send(wire::FoeWriteRequest{0, "slow"}), FoeMessage{wire::FoeAck{0}});
  const FoeMessage data1 = wire::FoeData{1, pattern(kPacket)};
  EXPECT_EQ(send(data1), FoeMessage{(wire::FoeBusy{1, 2})});
  EXPECT_EQ(send(data1), FoeMessage{(wire::FoeBusy{2, 2})});
  EXPECT_EQ(send(data1), FoeMessage{wire::FoeAck{1}});
  EXPECT_EQ(send(wire::FoeData{2, {7}}), FoeMessage{(wire::FoeBusy{1, 2})});
  EXPECT_EQ(server().stats().busy_sent, 3u);
}

TEST_F(FoeServerTest, TheStoreIsBounded) {
  const std::size_t bound = server().config().max_total_size;
  ASSERT_TRUE(server().put_file("big", {Bytes(bound - 60, 0), 0, false}).ok());
  EXPECT_FALSE(server().put_file("more", {Bytes(61, 0), 0, false}).ok());
  auto r = write("more", pattern(2 * kPacket));
  EXPECT_EQ(error_code(r), 0x8003u);  // the second packet does not fit
  EXPECT_EQ(server().file("more"), nullptr);
  // Rewriting a file counts its old content as free.
  EXPECT_EQ(write("big", Bytes(10, 1)), FoeMessage{wire::FoeAck{1}});
  EXPECT_EQ(server().stored_bytes(), 10u);
}

TEST_F(FoeServerTest, FirmwareIsWrittenInBootstrapOnlyAndStartsAtBootToInit) {
  auto image = make_firmware_image("2.0.0", pattern(700, 3));
  ASSERT_TRUE(image.ok());
  EXPECT_EQ(error_code(write("firmware.efw", *image)), 0x8009u);  // PREOP: not in bootstrap
  const std::string before = server().firmware().version;

  enter_bootstrap();
  // The bootstrap mailbox is larger: 256 - 12 bytes per packet.
  auto done = write("firmware.efw", *image, 0, 244);
  ASSERT_TRUE(done.has_value());
  EXPECT_TRUE(std::holds_alternative<wire::FoeAck>(*done));
  ASSERT_TRUE(server().pending_firmware().has_value());
  EXPECT_EQ(server().firmware().version, before);  // not yet: it runs after BOOT -> INIT
  ASSERT_EQ(m_.request(0, AlState::init).state, AlState::init);
  EXPECT_EQ(server().firmware(), (FirmwareImage{"2.0.0", pattern(700, 3)}));
  EXPECT_EQ(server().stats().firmware_updates, 1u);
  auto* app = dynamic_cast<StandardApplication*>(&segment_.esc(0).application());
  ASSERT_NE(app, nullptr);
  EXPECT_EQ(app->dictionary().get_string(0x100A, 0), "2.0.0");
}

TEST_F(FoeServerTest, ACorruptImageIsRefusedWithChecksumErrorAndTheOldOneKept) {
  auto image = make_firmware_image("9.9.9", pattern(300));
  ASSERT_TRUE(image.ok());
  (*image)[kFirmwareHeaderSize + 5] ^= 0x01;
  enter_bootstrap();
  EXPECT_EQ(error_code(write("firmware.efw", *image, 0, 244)), 0x800Cu);
  EXPECT_FALSE(server().pending_firmware().has_value());
  ASSERT_EQ(m_.request(0, AlState::init).state, AlState::init);
  EXPECT_EQ(server().stats().firmware_updates, 0u);
  EXPECT_NE(server().firmware().version, "9.9.9");
}

TEST_F(FoeServerTest, FaultHooks) {
  // An error after one packet of a write.
  server().add_fault({FoeFaultKind::error, 1, 0x800B});
  auto r = write("f", pattern(3 * kPacket));
  EXPECT_EQ(error_code(r), 0x800Bu);
  EXPECT_EQ(server().file("f"), nullptr);
  EXPECT_TRUE(server().faults().empty());  // fired once
  // A dropped reply: nothing comes back; the master's ERROR resets the transfer.
  server().add_fault({FoeFaultKind::drop_reply, 0, 0});
  EXPECT_FALSE(send(wire::FoeWriteRequest{0, "g"}).has_value());
  EXPECT_TRUE(server().transfer_in_progress());
  EXPECT_FALSE(send(wire::FoeError{0x8000, ""}).has_value());
  EXPECT_FALSE(server().transfer_in_progress());
  // A wrong packet number in a read's DATA.
  ASSERT_TRUE(server().put_file("r", {pattern(100), 0, false}).ok());
  server().add_fault({FoeFaultKind::wrong_packet, 1, 0});
  ASSERT_EQ(std::get<wire::FoeData>(*send(wire::FoeReadRequest{0, "r"})).packet_number, 1u);
  EXPECT_EQ(std::get<wire::FoeData>(*send(wire::FoeAck{1})).packet_number, 3u);
  EXPECT_EQ(server().stats().faults_applied, 3u);
}

}  // namespace
}  // namespace ecat::sim
