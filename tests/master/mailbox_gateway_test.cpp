// The mailbox gateway (master/mailbox_gateway.hpp) of a master cycling in OP on the simulated ring:
// SDO uploads, downloads and aborts through it from our own client and from bytes built as the
// ETG.8200 framing lays them out; unknown stations, the master's address, protocols a slave does
// not have, malformed and oversized datagrams; two clients at once. The domain keeps cycling.
#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <ecat/link/mailbox_gateway_client.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/mailbox_gateway.hpp>
#include <ecat/master/master.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/mailbox_gateway.hpp>
#include <ecat/wire/sdo_abort.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using Vec = std::vector<std::uint8_t>;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: drive, profile: servo}
)";

// Stations as the master assigns them (base 0x1000 + position); SetUp checks them.
constexpr std::uint16_t kCoupler = 0x1000;
constexpr std::uint16_t kDrive = 0x1002;

class MailboxGatewayTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
    auto config = test::quick_config();
    config.slaves = {test::quick_slave("coupler", false), test::quick_slave("inputs"),
                     test::quick_slave("drive")};
    config.mailbox_gateway.enabled = true;
    config.mailbox_gateway.port = 0;  // a free port: tests run side by side
    config.mailbox_gateway.request_timeout = 500ms;
    master_ = std::make_unique<Master>(config);
    auto link = server_->serve_memory();
    ASSERT_TRUE(link.ok());
    ASSERT_TRUE(master_->start(std::move(*link)).ok());
    ASSERT_TRUE(master_->await_operational(10s).ok());
    ASSERT_EQ((*master_->slave("coupler"))->station(), kCoupler);
    ASSERT_EQ((*master_->slave("drive"))->station(), kDrive);
    auto status = master_->mailbox_gateway();
    ASSERT_TRUE(status);
    EXPECT_EQ(status->address, "127.0.0.1");
    ASSERT_NE(status->port, 0);
    address_ = "127.0.0.1:" + std::to_string(status->port);
  }
  void TearDown() override {
    if (master_) (void)master_->stop();
    master_.reset();
  }

  std::unique_ptr<link::MailboxGatewayClient> client() {
    auto c = link::MailboxGatewayClient::connect(address_);
    EXPECT_TRUE(c) << c.error().describe();
    return c ? std::move(*c) : nullptr;
  }
  MailboxGatewayStats stats() { return master_->mailbox_gateway()->stats; }
  std::uint64_t cycles() {
    for (const auto& d : master_->domains()) {
      if (d.id == "main") return d.cycles;
    }
    return 0;
  }

  std::unique_ptr<sim::SimServer> server_;
  std::unique_ptr<Master> master_;
  std::string address_;
};

TEST_F(MailboxGatewayTest, UploadsDownloadsAndAbortsWhileTheMasterCycles) {
  auto c = client();
  ASSERT_TRUE(c);
  const auto cycles_before = cycles();

  // The identity object's vendor id, as the slave holds it (the master reads it too).
  auto vendor = c->upload_sdo(kDrive, 0x1018, 1);
  ASSERT_TRUE(vendor) << vendor.error().describe();
  ASSERT_EQ(vendor->size(), 4u);
  auto direct = (*master_->slave("drive"))->upload_sdo(0x1018, 1);
  ASSERT_TRUE(direct);
  EXPECT_EQ(*vendor, *direct);

  // A download, read back both through the gateway and by the master itself.
  const Vec velocity = {0xD2, 0x04, 0x00, 0x00};  // 1234
  ASSERT_TRUE(c->download_sdo(kDrive, 0x6081, 0, velocity));
  auto back = c->upload_sdo(kDrive, 0x6081, 0);
  ASSERT_TRUE(back) << back.error().describe();
  EXPECT_EQ(*back, velocity);
  auto own = (*master_->slave("drive"))->upload_sdo(0x6081, 0);
  ASSERT_TRUE(own);
  EXPECT_EQ(*own, velocity);

  // The statusword is read-only: the slave's abort comes back as it sent it.
  auto refused = c->download_sdo(kDrive, 0x6041, 0, Vec{0x00, 0x00});
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::sdo_abort) << refused.error().describe();
  EXPECT_EQ(refused.error().value(),
            static_cast<std::uint32_t>(wire::SdoAbortCode::write_of_read_only));

  // A string longer than 4 bytes: a normal (not expedited) upload.
  auto name = c->upload_sdo(kDrive, 0x1008, 0);
  ASSERT_TRUE(name) << name.error().describe();
  EXPECT_GT(name->size(), 4u);

  const auto s = stats();
  EXPECT_EQ(s.forwarded, 5u);
  EXPECT_EQ(s.replies, 5u);
  EXPECT_EQ(s.error_replies, 0u);
  EXPECT_EQ(master_->state(), MasterState::operational);
  // The domain went on cycling (its counters are published with a delay: wait for them, bounded).
  for (int i = 0; i < 300 && cycles() <= cycles_before; ++i)
    std::this_thread::sleep_for(10ms);
  EXPECT_GT(cycles(), cycles_before);
}

// Bytes as a configuration tool sends them, built from the ETG.8200 layout by hand (not by our
// encoder): EtherCAT header 0x5010 (16 bytes, type 5), mailbox header (length 10, station 0x1002,
// channel/priority 0, type 3 CoE | counter 1), CoE header (service 2: SDO request), SDO initiate
// upload request (command 0x40) of 0x1018:01.
TEST_F(MailboxGatewayTest, AnswersBytesAsAToolSendsThem) {
  auto c = client();
  ASSERT_TRUE(c);
  const Vec request = {0x10, 0x50, 0x0A, 0x00, 0x02, 0x10, 0x00, 0x13, 0x00,
                       0x20, 0x40, 0x18, 0x10, 0x01, 0x00, 0x00, 0x00, 0x00};
  ASSERT_TRUE(c->send_datagram(request));
  auto reply = c->receive_datagram(2s);
  ASSERT_TRUE(reply) << reply.error().describe();
  ASSERT_GE(reply->size(), 18u);
  // EtherCAT header: type 5, length = what follows.
  const unsigned word = (*reply)[0] | ((*reply)[1] << 8);
  EXPECT_EQ(word >> 12, 5u);
  EXPECT_EQ(word & 0x7FF, reply->size() - 2);
  // Mailbox header: the request's address, CoE, a counter of the slave's (1..7).
  EXPECT_EQ((*reply)[4], 0x02);
  EXPECT_EQ((*reply)[5], 0x10);
  EXPECT_EQ((*reply)[7] & 0x0F, 0x03);
  EXPECT_NE((*reply)[7] & 0x70, 0);
  // CoE service 3 (SDO response), expedited upload response of 4 bytes (0x43) of 0x1018:01.
  EXPECT_EQ((*reply)[9] >> 4, 3);
  EXPECT_EQ((*reply)[10], 0x43);
  EXPECT_EQ((*reply)[11], 0x18);
  EXPECT_EQ((*reply)[12], 0x10);
  EXPECT_EQ((*reply)[13], 0x01);
  auto direct = (*master_->slave("drive"))->upload_sdo(0x1018, 1);
  ASSERT_TRUE(direct);
  EXPECT_EQ(Vec(reply->begin() + 14, reply->begin() + 18), *direct);
}

// Reads the mailbox error of a reply: (type, detail), or (0xFF, 0) when it is not one.
std::pair<unsigned, unsigned> mailbox_error(const link::GatewayReply& reply) {
  if (reply.header.type != wire::MailboxType::error || reply.data.size() != 4) return {0xFF, 0};
  return {reply.data[0] | (reply.data[1] << 8), reply.data[2] | (reply.data[3] << 8)};
}

TEST_F(MailboxGatewayTest, AnswersWhatItCannotForwardWithAMailboxError) {
  auto c = client();
  ASSERT_TRUE(c);
  auto sdo = wire::encode_sdo(wire::SdoInitiateUploadRequest{0x1018, 1, false});
  ASSERT_TRUE(sdo);

  // A station no slave has: error 0x0001 (the mailbox header's address is wrong).
  auto unknown = c->exchange(0x2222, wire::MailboxType::coe, *sdo, 2s);
  ASSERT_TRUE(unknown) << unknown.error().describe();
  EXPECT_EQ(unknown->header.address, 0x2222);
  EXPECT_EQ(mailbox_error(*unknown), std::make_pair(1u, 0x0001u));

  // The master itself (station 0): ecat has no master object dictionary.
  auto master = c->exchange(0, wire::MailboxType::coe, *sdo, 2s);
  ASSERT_TRUE(master);
  EXPECT_EQ(mailbox_error(*master), std::make_pair(1u, 0x0002u));

  // The coupler has no mailbox; the drive declares CoE and FoE, not SoE.
  auto coupler = c->exchange(kCoupler, wire::MailboxType::coe, *sdo, 2s);
  ASSERT_TRUE(coupler);
  EXPECT_EQ(mailbox_error(*coupler), std::make_pair(1u, 0x0002u));
  auto soe = c->exchange(kDrive, wire::MailboxType::soe, Vec{0x01, 0x40, 0x20, 0x00}, 2s);
  ASSERT_TRUE(soe);
  EXPECT_EQ(mailbox_error(*soe), std::make_pair(1u, 0x0002u));

  // More data than the drive's mailbox holds (but within what a gateway message carries).
  Vec oversized(1500, 0);
  oversized[1] = 0x20;
  auto big = c->exchange(kDrive, wire::MailboxType::coe, oversized, 2s);
  ASSERT_TRUE(big);
  EXPECT_EQ(mailbox_error(*big), std::make_pair(1u, 0x0008u));

  const auto s = stats();
  EXPECT_EQ(s.error_replies, 5u);
  EXPECT_EQ(s.unknown_station, 2u);
  EXPECT_EQ(s.unsupported, 2u);
  EXPECT_EQ(s.too_large, 1u);

  // The gateway still serves.
  auto fine = c->upload_sdo(kDrive, 0x1018, 1);
  EXPECT_TRUE(fine) << fine.error().describe();
}

TEST_F(MailboxGatewayTest, DropsDatagramsThatAreNoGatewayMessage) {
  auto c = client();
  ASSERT_TRUE(c);
  const Vec bad[] = {
      {},                                                      // empty
      {0x0E},                                                  // half a header
      {0x0E, 0x10, 0x0A, 0x00, 0x03, 0x10, 0x00, 0x13},        // type 1: datagrams, not a mailbox
      {0x20, 0x50, 0x0A, 0x00, 0x03, 0x10, 0x00, 0x13},        // EtherCAT length past the end
      {0x08, 0x50, 0x0A, 0x00, 0x03, 0x10, 0x00, 0x13, 0, 0},  // mailbox longer than its frame
      Vec(5000, 0x55),                                         // longer than any gateway message
  };
  for (const auto& datagram : bad)
    ASSERT_TRUE(c->send_datagram(datagram));
  auto nothing = c->receive_datagram(300ms);
  ASSERT_FALSE(nothing);
  EXPECT_EQ(nothing.error().code(), Errc::timeout);
  // The good request after them is answered.
  auto fine = c->upload_sdo(kDrive, 0x1018, 1);
  ASSERT_TRUE(fine) << fine.error().describe();
  const auto s = stats();
  EXPECT_EQ(s.malformed, 6u);
  EXPECT_EQ(s.datagrams, 7u);
  EXPECT_EQ(s.replies, 1u);
}

TEST_F(MailboxGatewayTest, ServesTwoClientsAtOnce) {
  auto a = client();
  auto b = client();
  ASSERT_TRUE(a && b);
  auto slave = master_->slave("drive");
  ASSERT_TRUE(slave);
  auto expected = (*slave)->upload_sdo(0x1018, 1);
  ASSERT_TRUE(expected);
  constexpr int kEach = 20;
  int failures_a = 0;
  int failures_b = 0;
  const auto run = [&](link::MailboxGatewayClient& c, int& failures, std::uint8_t sub) {
    for (int i = 0; i < kEach; ++i) {
      auto value = c.upload_sdo(kDrive, 0x1018, sub, 3s);
      if (!value) ++failures;
    }
  };
  std::thread ta([&] { run(*a, failures_a, 1); });
  std::thread tb([&] { run(*b, failures_b, 2); });
  ta.join();
  tb.join();
  EXPECT_EQ(failures_a, 0);
  EXPECT_EQ(failures_b, 0);
  // Each reply went to the client that asked: a's are the vendor id.
  auto again = a->upload_sdo(kDrive, 0x1018, 1);
  ASSERT_TRUE(again);
  EXPECT_EQ(*again, *expected);
  EXPECT_EQ(stats().replies, 2u * kEach + 1);
  EXPECT_EQ(a->skipped() + b->skipped(), 0u);
}

TEST_F(MailboxGatewayTest, CountersAreInTheControlEndpointsReply) {
  auto c = client();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->upload_sdo(kDrive, 0x1018, 1));
  auto reply = nlohmann::json::parse(
      handle_control_request(*master_, R"({"op":"gateway.stats"})", ControlAccess{}));
  EXPECT_EQ(reply["ok"], true) << reply.dump();
  EXPECT_EQ(reply["address"], "127.0.0.1");
  EXPECT_EQ(reply["replies"], 1);
  EXPECT_EQ(reply["forwarded"], 1);
}

TEST(MailboxGatewayConfig, RefusesAPortInUseAndBadAddresses) {
  MailboxGatewayConfig config;
  EXPECT_TRUE(parse_mailbox_gateway_address("127.0.0.1:4000", config));
  EXPECT_EQ(config.address, "127.0.0.1");
  EXPECT_EQ(config.port, 4000);
  EXPECT_TRUE(parse_mailbox_gateway_address("5000", config));
  EXPECT_EQ(config.address, "");
  EXPECT_EQ(config.port, 5000);
  EXPECT_TRUE(parse_mailbox_gateway_address("*", config));
  EXPECT_EQ(config.port, wire::kMailboxGatewayPort);
  EXPECT_FALSE(parse_mailbox_gateway_address("host.example:1", config));
  EXPECT_FALSE(parse_mailbox_gateway_address("127.0.0.1:99999", config));
  EXPECT_FALSE(parse_mailbox_gateway_address("127.0.0.1:x", config));

  Master master{MasterConfig{}};
  MailboxGatewayConfig first;
  first.enabled = true;
  first.port = 0;
  auto a = MailboxGateway::start(master, first);
  ASSERT_TRUE(a) << a.error().describe();
  MailboxGatewayConfig second = first;
  second.port = (*a)->status().port;
  auto b = MailboxGateway::start(master, second);
  ASSERT_FALSE(b);
  EXPECT_EQ(b.error().code(), Errc::busy);
  EXPECT_NE(b.error().message().find("in use"), std::string::npos);
}

TEST(MailboxGatewayConfig, ReadsTheRingFilesForms) {
  auto off = parse_master_config("master: {}\n");
  ASSERT_TRUE(off) << off.error().describe();
  EXPECT_FALSE(off->mailbox_gateway.enabled);

  auto on = parse_master_config("master:\n  mailbox_gateway: true\n");
  ASSERT_TRUE(on) << on.error().describe();
  EXPECT_TRUE(on->mailbox_gateway.enabled);
  EXPECT_EQ(on->mailbox_gateway.address, "");
  EXPECT_EQ(on->mailbox_gateway.port, 0x88A4);

  auto text = parse_master_config("master:\n  mailbox_gateway: \"127.0.0.1:34981\"\n");
  ASSERT_TRUE(text) << text.error().describe();
  EXPECT_TRUE(text->mailbox_gateway.enabled);
  EXPECT_EQ(text->mailbox_gateway.port, 34981);

  auto full = parse_master_config(
      "master:\n  mailbox_gateway: {address: \"*:4000\", timeout_ms: 250, queue: 8, workers: "
      "2}\n");
  ASSERT_TRUE(full) << full.error().describe();
  EXPECT_EQ(full->mailbox_gateway.address, "*");
  EXPECT_EQ(full->mailbox_gateway.port, 4000);
  EXPECT_EQ(full->mailbox_gateway.request_timeout, 250ms);
  EXPECT_EQ(full->mailbox_gateway.max_queued, 8u);
  EXPECT_EQ(full->mailbox_gateway.workers, 2u);

  for (const char* bad :
       {"master:\n  mailbox_gateway: nowhere:1\n", "master:\n  mailbox_gateway: {workers: 0}\n",
        "master:\n  mailbox_gateway: {port: 1}\n", "master:\n  mailbox_gateway: [1]\n"}) {
    auto refused = parse_master_config(bad);
    ASSERT_FALSE(refused) << bad;
    EXPECT_NE(refused.error().message().find("mailbox_gateway"), std::string::npos)
        << refused.error().message();
  }
}

}  // namespace
}  // namespace ecat::master
