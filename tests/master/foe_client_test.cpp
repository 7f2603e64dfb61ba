// The FoE client against scripted slave replies: the simulated "mailbox" device's CoE server
// hands every FoE request to a script (its protocol handler for mailbox type 4), which records
// the request's bytes and answers with the bytes a test chose. So the exact packets the master
// sends are checked, and the slave's side can do what real slaves do (BUSY, ERROR) and what they
// should not (wrong packet numbers, other protocols, garbage, silence).
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/foe.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/foe.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using test::SimBench;
using Bytes = std::vector<std::uint8_t>;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: mbx, profile: mailbox}
)";

// The mailbox device's 64-byte mailboxes: 64 - 6 (mailbox header) - 6 (FoE header).
constexpr std::size_t kPacket = 52;

Bytes foe(const wire::FoeMessage& m) {
  auto r = wire::encode_foe(m);
  EXPECT_TRUE(r.ok());
  return r.ok() ? *r : Bytes{};
}

Bytes pattern(std::size_t n, unsigned offset = 0) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * 3 + offset) & 0xFF);
  return out;
}

Bytes slice(const Bytes& b, std::size_t from, std::size_t n) {
  return Bytes(b.begin() + static_cast<std::ptrdiff_t>(from),
               b.begin() + static_cast<std::ptrdiff_t>(from + n));
}

// The slave's side: one entry of replies per request, in order (an empty entry: no reply).
// Requests beyond the script get no reply either.
struct Script {
  std::mutex mutex;
  std::deque<std::vector<sim::MailboxReply>> replies;
  std::vector<Bytes> requests;  // mailbox data of each FoE request
  std::vector<Bytes> raw_sm0;   // the request as it sits in SM0 (header + data)

  void add(std::vector<Bytes> foe_replies) {
    std::vector<sim::MailboxReply> r;
    for (auto& data : foe_replies)
      r.push_back({wire::MailboxType::foe, std::move(data)});
    replies.push_back(std::move(r));
  }
  void add_raw(std::vector<sim::MailboxReply> r) { replies.push_back(std::move(r)); }
};

class FoeClientTest : public ::testing::Test {
 protected:
  void SetUp() override {
    bench_ = SimBench::make(kRing);
    ASSERT_TRUE(bench_);
    auto configs = bench_->run(test::bring_all_to_preop(bench_->loop, *bench_->bus, 1));
    ASSERT_TRUE(configs.ok()) << configs.error().describe();
    config_ = configs->front();
    MailboxOptions options;
    options.repeat_timeout = 50ms;
    mailbox_ = std::make_unique<Mailbox>(bench_->loop, *bench_->bus, test::station_at(0), config_,
                                         options);
    script_ = std::make_shared<Script>();
    bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      auto* coe = sim::coe_server_of(segment.esc(0));
      ASSERT_NE(coe, nullptr);
      const std::uint16_t sm0 = config_.out_offset;
      coe->set_protocol_handler(
          wire::MailboxType::foe,
          [script = script_, sm0](sim::Esc& esc, const wire::MailboxHeader& header,
                                  wire::Bytes data) -> std::vector<sim::MailboxReply> {
            std::lock_guard lock(script->mutex);
            script->requests.emplace_back(data.begin(), data.end());
            Bytes raw;
            for (std::size_t i = 0; i < wire::kMailboxHeaderSize + header.length; ++i)
              raw.push_back(esc.read_u8(static_cast<std::uint16_t>(sm0 + i)));
            script->raw_sm0.push_back(std::move(raw));
            if (script->replies.empty()) return {};
            auto r = std::move(script->replies.front());
            script->replies.pop_front();
            return r;
          });
    });
  }

  std::vector<Bytes> requests() {
    std::lock_guard lock(script_->mutex);
    return script_->requests;
  }

  template <class T>
  T run(exec::Task<T> task) {
    return bench_->run(std::move(task));
  }

  std::unique_ptr<SimBench> bench_;
  MailboxConfig config_;
  std::unique_ptr<Mailbox> mailbox_;
  std::shared_ptr<Script> script_;
};

// ---- write ------------------------------------------------------------------------------------

TEST_F(FoeClientTest, PacketSizeFollowsTheMailbox) {
  EXPECT_EQ(foe_write_packet_size(*mailbox_), kPacket);
  EXPECT_EQ(foe_read_packet_size(*mailbox_), kPacket);
}

// The write request as real stacks lay it out (SOEM's ec_FOEt: the 6-byte mailbox header with
// length 6 + name, address 0, channel/priority 0, type 4 | counter << 4; then opcode 2, a reserved
// byte, the password little-endian and the file name without a terminating NUL; SOES decodes it
// the same way).
TEST_F(FoeClientTest, WriteRequestWithPasswordIsEncodedAsRealStacksDo) {
  script_->add({foe(wire::FoeAck{0})});
  script_->add({foe(wire::FoeAck{1})});
  ASSERT_TRUE(
      run(foe_write(*mailbox_, "firmware.efw", Bytes{0xAA, 0xBB}, {.password = 0x12345678})).ok());
  std::lock_guard lock(script_->mutex);
  ASSERT_EQ(script_->raw_sm0.size(), 2u);
  EXPECT_EQ(script_->raw_sm0[0],
            (Bytes{0x12, 0x00, 0x00, 0x00, 0x00, 0x14,  // length 18, counter 1, type FoE
                   0x02, 0x00, 0x78, 0x56, 0x34, 0x12,  // WRQ, password 0x12345678
                   'f',  'i',  'r',  'm',  'w',  'a',  'r', 'e', '.', 'e', 'f', 'w'}));
  EXPECT_EQ(script_->raw_sm0[1], (Bytes{0x08, 0x00, 0x00, 0x00, 0x00, 0x24,  // counter 2
                                        0x03, 0x00, 0x01, 0x00, 0x00, 0x00, 0xAA, 0xBB}));
}

TEST_F(FoeClientTest, WriteSendsFullPacketsThenAShortOneAndReportsProgress) {
  const Bytes file = pattern(2 * kPacket + 10);
  for (std::uint32_t i = 0; i <= 3; ++i)
    script_->add({foe(wire::FoeAck{i})});
  std::vector<std::pair<std::size_t, std::optional<std::size_t>>> progress;
  FoeOptions options;
  options.progress = [&](std::size_t done, std::optional<std::size_t> total) {
    progress.emplace_back(done, total);
  };
  auto done = run(foe_write(*mailbox_, "app.bin", file, options));
  ASSERT_TRUE(done.ok()) << done.error().describe();
  EXPECT_EQ(requests(), (std::vector<Bytes>{
                            foe(wire::FoeWriteRequest{0, "app.bin"}),
                            foe(wire::FoeData{1, slice(file, 0, kPacket)}),
                            foe(wire::FoeData{2, slice(file, kPacket, kPacket)}),
                            foe(wire::FoeData{3, slice(file, 2 * kPacket, 10)}),
                        }));
  using P = std::pair<std::size_t, std::optional<std::size_t>>;
  EXPECT_EQ(progress, (std::vector<P>{P{52, 114}, P{104, 114}, P{114, 114}}));
}

TEST_F(FoeClientTest, AFileOfWholePacketsEndsWithAnEmptyPacket) {
  const Bytes file = pattern(2 * kPacket);
  for (std::uint32_t i = 0; i <= 3; ++i)
    script_->add({foe(wire::FoeAck{i})});
  ASSERT_TRUE(run(foe_write(*mailbox_, "two.bin", file)).ok());
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 4u);
  EXPECT_EQ(sent[3], foe(wire::FoeData{3, {}}));
}

TEST_F(FoeClientTest, AnEmptyFileIsOneEmptyPacket) {
  script_->add({foe(wire::FoeAck{0})});
  script_->add({foe(wire::FoeAck{1})});
  ASSERT_TRUE(run(foe_write(*mailbox_, "empty", {})).ok());
  EXPECT_EQ(requests(), (std::vector<Bytes>{foe(wire::FoeWriteRequest{0, "empty"}),
                                            foe(wire::FoeData{1, {}})}));
}

TEST_F(FoeClientTest, BusySendsTheSamePacketAgain) {
  script_->add({foe(wire::FoeAck{0})});
  script_->add({foe(wire::FoeBusy{1, 3})});
  script_->add({foe(wire::FoeBusy{2, 3})});
  script_->add({foe(wire::FoeAck{1})});
  auto done = run(foe_write(*mailbox_, "slow", Bytes{1, 2, 3}));
  ASSERT_TRUE(done.ok()) << done.error().describe();
  const Bytes data1 = foe(wire::FoeData{1, {1, 2, 3}});
  EXPECT_EQ(requests(),
            (std::vector<Bytes>{foe(wire::FoeWriteRequest{0, "slow"}), data1, data1, data1}));
}

TEST_F(FoeClientTest, BusyForLongerThanAllowedFailsAndTellsTheSlave) {
  script_->add({foe(wire::FoeAck{0})});
  for (int i = 0; i < 1000; ++i)
    script_->add({foe(wire::FoeBusy{0, 100})});
  FoeOptions options;
  options.busy_timeout = 30ms;
  options.busy_interval = 2ms;
  auto done = run(foe_write(*mailbox_, "slow", Bytes{1}, options));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().code(), Errc::timeout);
  EXPECT_NE(done.error().message().find("FoE write of 'slow' to slave 0x1001: the slave answered "
                                        "the DATA packet 1 with BUSY for"),
            std::string::npos)
      << done.error().message();
  const auto sent = requests();
  ASSERT_GE(sent.size(), 4u);
  ASSERT_LE(sent.size(), 40u);  // bounded: about busy_timeout / busy_interval resends
  auto last = wire::decode_foe(sent.back());
  ASSERT_TRUE(last.ok());
  ASSERT_TRUE(std::holds_alternative<wire::FoeError>(*last));
  EXPECT_EQ(std::get<wire::FoeError>(*last).code, 0x8000u);
}

TEST_F(FoeClientTest, AnErrorFromTheSlaveEndsTheWriteWithItsCodeAndText) {
  script_->add({foe(wire::FoeAck{0})});
  script_->add({foe(wire::FoeError{0x8002, "flash locked"})});
  auto done = run(foe_write(*mailbox_, "firmware.efw", pattern(100)));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().code(), Errc::permission_denied);
  EXPECT_EQ(done.error().describe(),
            "FoE write of 'firmware.efw' to slave 0x1001: error 0x8002 access denied: flash "
            "locked");
  EXPECT_EQ(foe_error_code(done.error()), 0x8002u);
  EXPECT_EQ(requests().size(), 2u);  // nothing sent after the slave's error
}

TEST_F(FoeClientTest, ErrorCodesMapToErrc) {
  const std::vector<std::pair<std::uint32_t, Errc>> cases{
      {0x8001, Errc::not_found},     {0x800A, Errc::permission_denied},
      {0x8003, Errc::out_of_range},  {0x8009, Errc::wrong_state},
      {0x800C, Errc::mailbox_error}, {0x1234, Errc::mailbox_error}};
  for (const auto& [code, errc] : cases) {
    script_->add({foe(wire::FoeError{code, ""})});
    auto done = run(foe_write(*mailbox_, "f", Bytes{1}));
    ASSERT_FALSE(done.ok());
    EXPECT_EQ(done.error().code(), errc) << code;
    EXPECT_EQ(foe_error_code(done.error()), code);
  }
  script_->add({foe(wire::FoeError{0x8001, ""})});
  auto missing = run(foe_read(*mailbox_, "nothing"));
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().describe(),
            "FoE read of 'nothing' from slave 0x1001: error 0x8001 file not found");
}

TEST_F(FoeClientTest, AWrongAckNumberFailsAndTellsTheSlave) {
  script_->add({foe(wire::FoeAck{0})});
  script_->add({foe(wire::FoeAck{5})});
  auto done = run(foe_write(*mailbox_, "f", Bytes{1, 2}));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().code(), Errc::mailbox_error);
  EXPECT_EQ(done.error().message(),
            "FoE write of 'f' to slave 0x1001: the slave answered the DATA packet 1 with ACK 5, "
            "expected ACK 1");
  EXPECT_EQ(foe_error_code(done.error()), std::nullopt);
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 3u);
  auto told = wire::decode_foe(sent[2]);
  ASSERT_TRUE(told.ok());
  EXPECT_EQ(std::get<wire::FoeError>(*told).code, 0x8005u);
}

TEST_F(FoeClientTest, DataInPlaceOfAnAckIsAClearError) {
  script_->add({foe(wire::FoeData{1, {1}})});
  auto done = run(foe_write(*mailbox_, "f", Bytes{1, 2}));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().message(),
            "FoE write of 'f' to slave 0x1001: the slave answered the write request with data "
            "instead of ACK 0");
  auto told = wire::decode_foe(requests().back());
  ASSERT_TRUE(told.ok());
  EXPECT_EQ(std::get<wire::FoeError>(*told).code, 0x8004u);
}

// ---- read -------------------------------------------------------------------------------------

TEST_F(FoeClientTest, ReadAcknowledgesEveryPacketUntilAShortOne) {
  const Bytes file = pattern(kPacket + 10, 7);
  script_->add({foe(wire::FoeData{1, slice(file, 0, kPacket)})});
  script_->add({foe(wire::FoeData{2, slice(file, kPacket, 10)})});
  std::vector<std::pair<std::size_t, std::optional<std::size_t>>> progress;
  FoeOptions options;
  options.password = 0xCAFE;
  options.progress = [&](std::size_t done, std::optional<std::size_t> total) {
    progress.emplace_back(done, total);
  };
  auto read = run(foe_read(*mailbox_, "log.txt", options));
  ASSERT_TRUE(read.ok()) << read.error().describe();
  EXPECT_EQ(*read, file);
  EXPECT_EQ(requests(), (std::vector<Bytes>{Bytes{0x01, 0x00, 0xFE, 0xCA, 0x00, 0x00, 'l', 'o', 'g',
                                                  '.', 't', 'x', 't'},
                                            foe(wire::FoeAck{1}), foe(wire::FoeAck{2})}));
  using P = std::pair<std::size_t, std::optional<std::size_t>>;
  EXPECT_EQ(progress, (std::vector<P>{P{52, std::nullopt}, P{62, 62}}));
}

TEST_F(FoeClientTest, ReadEndsWithAnEmptyPacketAfterWholePackets) {
  const Bytes file = pattern(kPacket);
  script_->add({foe(wire::FoeData{1, file})});
  script_->add({foe(wire::FoeData{2, {}})});
  auto read = run(foe_read(*mailbox_, "x"));
  ASSERT_TRUE(read.ok()) << read.error().describe();
  EXPECT_EQ(*read, file);
  EXPECT_EQ(requests().size(), 3u);  // RRQ, ACK 1, ACK 2
}

TEST_F(FoeClientTest, AWrongPacketNumberFailsTheReadAndTellsTheSlave) {
  script_->add({foe(wire::FoeData{1, pattern(kPacket)})});
  script_->add({foe(wire::FoeData{3, pattern(4)})});
  auto read = run(foe_read(*mailbox_, "x"));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.error().message(),
            "FoE read of 'x' from slave 0x1001: the slave answered the ACK of packet 1 with DATA "
            "packet 3, expected packet 2");
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 3u);
  auto told = wire::decode_foe(sent[2]);
  ASSERT_TRUE(told.ok());
  EXPECT_EQ(std::get<wire::FoeError>(*told).code, 0x8005u);
}

TEST_F(FoeClientTest, AFileLargerThanAllowedFailsBeforeItIsKept) {
  for (std::uint32_t i = 1; i <= 10; ++i)
    script_->add({foe(wire::FoeData{i, pattern(kPacket)})});
  FoeOptions options;
  options.max_read_size = 100;
  auto read = run(foe_read(*mailbox_, "big", options));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.error().code(), Errc::out_of_range);
  EXPECT_EQ(read.error().message(),
            "FoE read of 'big' from slave 0x1001: the file grows beyond FoeOptions::max_read_size "
            "(100 bytes) with packet 2");
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 3u);  // RRQ, ACK 1, ERROR
  EXPECT_EQ(std::get<wire::FoeError>(*wire::decode_foe(sent[2])).code, 0x8003u);
}

TEST_F(FoeClientTest, BusyDuringAReadResendsTheAck) {
  script_->add({foe(wire::FoeData{1, pattern(kPacket)})});
  script_->add({foe(wire::FoeBusy{0, 0})});
  script_->add({foe(wire::FoeData{2, {9}})});
  auto read = run(foe_read(*mailbox_, "x"));
  ASSERT_TRUE(read.ok()) << read.error().describe();
  EXPECT_EQ(read->size(), kPacket + 1);
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 4u);
  EXPECT_EQ(sent[1], foe(wire::FoeAck{1}));
  EXPECT_EQ(sent[2], foe(wire::FoeAck{1}));
}

// ---- what a slave should never do ---------------------------------------------------------------

TEST_F(FoeClientTest, NoReplyIsATimeoutNeverAHang) {
  script_->add_raw({});  // the write request is never answered
  FoeOptions options;
  options.timeout = 50ms;
  auto done = run(foe_write(*mailbox_, "f", Bytes{1}, options));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().code(), Errc::timeout);
  EXPECT_EQ(mailbox_->stats().repeat_requests, 1u);  // the lost-reply recovery was tried first
  // The slave is told to drop the transfer.
  const auto sent = requests();
  ASSERT_EQ(sent.size(), 2u);
  EXPECT_EQ(std::get<wire::FoeError>(*wire::decode_foe(sent[1])).code, 0x8000u);
}

TEST_F(FoeClientTest, AnotherProtocolOrGarbageIsAClearError) {
  script_->add_raw({{wire::MailboxType::voe, Bytes{1, 2, 3, 4, 5, 6}}});
  auto done = run(foe_write(*mailbox_, "f", Bytes{1}));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().message(),
            "FoE write of 'f' to slave 0x1001: the slave answered the write request with a VoE "
            "mailbox (type 15) instead of FoE");
  script_->add({Bytes{0x09, 0x00, 1, 2, 3, 4}});
  auto read = run(foe_read(*mailbox_, "f"));
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.error().code(), Errc::malformed);
  EXPECT_NE(read.error().describe().find("FoE read of 'f' from slave 0x1001: the slave's reply to "
                                         "the read request does not decode"),
            std::string::npos)
      << read.error().describe();
}

TEST_F(FoeClientTest, ANameWithANulIsRefusedBeforeAnythingIsSent) {
  auto done = run(foe_write(*mailbox_, std::string("a\0b", 3), Bytes{1}));
  ASSERT_FALSE(done.ok());
  EXPECT_EQ(done.error().code(), Errc::invalid_argument);
  EXPECT_TRUE(requests().empty());
}

}  // namespace
}  // namespace ecat::master
