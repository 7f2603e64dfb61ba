// The master's mailbox against simulated slaves: one frame per exchange when the slave answers at
// once, the request counter cycle, mailbox error replies, emergencies and unsolicited messages,
// repeats dropped as duplicates, a reply lost on the wire recovered with the repeat request, a
// slave that never takes or answers requests, and serialization of concurrent users.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>

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

struct Fixture {
  std::unique_ptr<SimBench> bench;
  MailboxConfig config;
};

Fixture bring_up() {
  Fixture f;
  f.bench = SimBench::make(kRing);
  if (!f.bench) return f;
  auto configs = f.bench->run(test::bring_all_to_preop(f.bench->loop, *f.bench->bus, 1));
  EXPECT_TRUE(configs.ok()) << configs.error().describe();
  if (configs) f.config = configs->front();
  return f;
}

Bytes upload_request(std::uint16_t index, std::uint8_t subindex) {
  auto data = wire::encode_sdo(wire::SdoInitiateUploadRequest{index, subindex, false});
  EXPECT_TRUE(data.ok());
  return data.ok() ? *data : Bytes{};
}

// The value of an expedited upload reply.
Bytes expedited_value(const MailboxMessage& message) {
  auto sdo = wire::decode_sdo(message.data);
  EXPECT_TRUE(sdo.ok());
  if (!sdo) return {};
  const auto* init = std::get_if<wire::SdoInitiateUploadResponse>(&*sdo);
  EXPECT_NE(init, nullptr);
  return init != nullptr ? init->data : Bytes{};
}

sim::CoeServerStats coe_stats(SimBench& bench, std::size_t position) {
  return bench.server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    return sim::coe_server_of(segment.esc(position))->stats();
  });
}

TEST(Mailbox, TheSimulatorConfigAndOneFramePerExchange) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  EXPECT_EQ(f.config, (MailboxConfig{0x1000, 64, 0x1040, 64, 1}));
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  EXPECT_EQ(mailbox.max_request_data(), 58u);
  const auto before = f.bench->bus->stats().frames_sent;
  auto reply = f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 1s));
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  // The simulated slave answers while the frame passes: the read in the request's frame gets it.
  EXPECT_EQ(f.bench->bus->stats().frames_sent - before, 1u);
  EXPECT_EQ(reply->header.type, wire::MailboxType::coe);
  EXPECT_EQ(reply->header.counter, 1);  // the slave's own count, starting at 1
  EXPECT_EQ(expedited_value(*reply), (Bytes{0x34, 0x12}));
  EXPECT_EQ(mailbox.stats().requests, 1u);
  EXPECT_EQ(mailbox.stats().replies, 1u);
}

TEST(Mailbox, WithoutTheReadInTheRequestFrameAnExchangeTakesTwoFrames) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  MailboxOptions separate;
  separate.read_with_request = false;
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config, separate);
  const auto start = f.bench->bus->stats().frames_sent;
  auto reply = f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 2), 1s));
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  EXPECT_EQ(f.bench->bus->stats().frames_sent - start, 2u);  // write, then read
  EXPECT_EQ(expedited_value(*reply), (Bytes{0x00}));
}

TEST(Mailbox, RequestCountersRunOneToSevenAndWrapToOne) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  std::vector<int> counters;
  for (int i = 0; i < 9; ++i) {
    auto reply =
        f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 1s));
    ASSERT_TRUE(reply.ok()) << reply.error().describe();
    // The request as it sits in the slave's SM0 area: byte 5 holds the counter.
    auto sm0 = f.bench->server->read_memory("mbx", f.config.out_offset, 6);
    ASSERT_TRUE(sm0.ok());
    counters.push_back((*sm0)[5] >> 4);
  }
  EXPECT_EQ(counters, (std::vector<int>{1, 2, 3, 4, 5, 6, 7, 1, 2}));
  EXPECT_EQ(coe_stats(*f.bench, 0).duplicates, 0u);
}

TEST(Mailbox, AMailboxErrorReplyFailsTheExchangeWithItsCode) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  // The simulated slave does not speak AoE: an AoE request is refused with "unsupported protocol".
  auto reply = f.bench->run(
      mailbox.request(wire::MailboxType::aoe, Bytes{1, 2, 3, 4}, 1s, {}, "AoE request"));
  ASSERT_FALSE(reply.ok());
  EXPECT_EQ(reply.error().code(), Errc::mailbox_error);
  EXPECT_EQ(reply.error().message(),
            "AoE request: slave 0x1001 answered with mailbox error 0x0002: " +
                wire::mailbox_error_text(0x0002));
  EXPECT_EQ(reply.error().code_value(Errc::mailbox_error), 0x0002u);
}

TEST(Mailbox, EmergenciesAreQueuedAndReportedNeverTakenAsReplies) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  std::vector<std::pair<std::uint16_t, wire::Emergency>> seen;
  MailboxOptions options;
  options.on_emergency = [&](std::uint16_t station, const wire::Emergency& e) {
    seen.emplace_back(station, e);
  };
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config, options);
  const wire::Emergency first{0x8611, 0x81, {1, 2, 3, 4, 5}};
  const wire::Emergency second{0x2310, 0x03, {0, 0, 0, 0, 9}};
  f.bench->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto& esc = segment.esc(0);
    sim::coe_server_of(esc)->queue_emergency(esc, first);
    sim::coe_server_of(esc)->queue_emergency(esc, second);
    return 0;
  });
  // The exchange reads both emergencies before its reply and still gets the reply.
  auto reply = f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 1s));
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  EXPECT_EQ(expedited_value(*reply), (Bytes{0x34, 0x12}));
  EXPECT_EQ(mailbox.emergencies(), (std::vector<wire::Emergency>{first, second}));
  EXPECT_TRUE(mailbox.emergencies().empty());  // taken
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].first, 0x1001);
  EXPECT_EQ(seen[1].second, second);
  EXPECT_EQ(mailbox.stats().emergencies, 2u);

  // Without an exchange, poll() fetches them.
  f.bench->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto& esc = segment.esc(0);
    sim::coe_server_of(esc)->queue_emergency(esc, second);
    return 0;
  });
  auto polled = f.bench->run(mailbox.poll());
  ASSERT_TRUE(polled.ok()) << polled.error().describe();
  EXPECT_EQ(*polled, 1u);
  EXPECT_EQ(mailbox.emergencies(), (std::vector<wire::Emergency>{second}));
  EXPECT_TRUE(mailbox.unsolicited().empty());
}

TEST(Mailbox, MessagesTheFilterDoesNotClaimAreQueuedAsUnsolicited) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  // A filter that claims nothing: the reply is queued and the exchange times out.
  auto reply = f.bench->run(mailbox.request(
      wire::MailboxType::coe, upload_request(0x2000, 1), 20ms,
      [](const MailboxMessage&) { return false; }, "picky request"));
  ASSERT_FALSE(reply.ok());
  EXPECT_EQ(reply.error().code(), Errc::timeout);
  auto queued = mailbox.unsolicited();
  ASSERT_EQ(queued.size(), 1u);
  EXPECT_EQ(expedited_value(queued[0]), (Bytes{0x34, 0x12}));
  EXPECT_EQ(mailbox.stats().unsolicited, 1u);
  EXPECT_EQ(mailbox.stats().timeouts, 1u);
}

TEST(Mailbox, ARepeatedMessageIsDroppedAsDuplicate) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  auto reply = f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 1s));
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  // Toggle SM1's repeat request by hand (activate register 0x080E bit 1; 0x0806 would be SM0's):
  // the slave puts the same reply into SM1 again.
  auto toggle = [&]() -> exec::Task<Result<void>> {
    bus::Transaction read;
    read.fprd(0x1001, 0x080E, 1, 1);
    auto current = co_await exec::transact(f.bench->loop, *f.bench->bus, std::move(read));
    if (!current) co_return current.error();
    const std::uint8_t toggled = static_cast<std::uint8_t>(current->data(0)[0] ^ 0x02);
    bus::Transaction write;
    write.fpwr(0x1001, 0x080E, wire::Bytes(&toggled, 1), 1);
    auto written = co_await exec::transact(f.bench->loop, *f.bench->bus, std::move(write));
    if (!written) co_return written.error();
    co_return ok();
  };
  ASSERT_TRUE(f.bench->run(toggle()).ok());
  auto polled = f.bench->run(mailbox.poll());
  ASSERT_TRUE(polled.ok());
  EXPECT_EQ(*polled, 1u);
  EXPECT_EQ(mailbox.stats().duplicates, 1u);
  EXPECT_TRUE(mailbox.unsolicited().empty());
}

TEST(Mailbox, AReplyLostOnTheWayBackIsRecoveredWithTheRepeatRequest) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  MailboxOptions options;
  options.read_with_request = false;  // write and read in frames of their own
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config, options);
  // The write's frame passes; the reply to the read's frame is cut short on its way back: the
  // slave handed the mailbox over, the master never saw it, and the retried read finds SM1 empty.
  ASSERT_TRUE(
      f.bench->server
          ->inject(sim::fault::script({sim::fault::wait_for(sim::fault::healthy_exchanges(1)),
                                       sim::fault::truncate_reply(4)}))
          .ok());
  auto reply =
      f.bench->run(mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 30ms));
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  EXPECT_EQ(expedited_value(*reply), (Bytes{0x34, 0x12}));
  EXPECT_EQ(mailbox.stats().repeat_requests, 1u);
  EXPECT_EQ(coe_stats(*f.bench, 0).repeats, 1u);
  EXPECT_GE(f.bench->bus->stats().retries, 1u);
}

TEST(Mailbox, ASlaveThatNeverTakesOrAnswersTimesOut) {
  // An ESC whose firmware never reads SM0 and does not serve repeat requests.
  sim::DeviceConfig device;
  device.profile = "mailbox";
  auto template_esc = sim::make_device(device);
  ASSERT_TRUE(template_esc.ok());
  const auto eeprom = (*template_esc)->eeprom();
  auto segment = std::make_unique<sim::Segment>();
  ASSERT_TRUE(segment
                  ->add_slave("mute", std::make_unique<sim::Esc>(
                                          sim::EscHardware{},
                                          std::vector<std::uint8_t>(eeprom.begin(), eeprom.end()),
                                          std::make_unique<sim::BasicApplication>()))
                  .ok());
  auto bench = SimBench::make(std::move(segment));
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 1)).ok());
  auto config = bench->run(test::configure_mailbox(bench->loop, *bench->bus, 0x1001));
  ASSERT_TRUE(config.ok()) << config.error().describe();
  MailboxOptions options;
  options.repeat_timeout = 10ms;
  Mailbox mailbox(bench->loop, *bench->bus, 0x1001, *config, options);
  auto first = bench->run(
      mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 20ms, {}, "first"));
  ASSERT_FALSE(first.ok());
  EXPECT_EQ(first.error().code(), Errc::timeout);
  EXPECT_EQ(first.error().message(),
            "first: no reply from slave 0x1001 within 20 ms, and the slave did not acknowledge a "
            "mailbox repeat request");
  // SM0 still holds the first request: the second is never taken.
  auto second = bench->run(
      mailbox.request(wire::MailboxType::coe, upload_request(0x2000, 1), 20ms, {}, "second"));
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code(), Errc::timeout);
  EXPECT_EQ(second.error().message(),
            "second: slave 0x1001 did not take the request within 20 ms: its mailbox SM0 at "
            "0x1000 stayed full (WKC 0)");
  EXPECT_GE(mailbox.stats().write_retries, 1u);
  EXPECT_EQ(mailbox.stats().requests, 1u);
}

TEST(Mailbox, ConcurrentUsersAreSerialized) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  auto all = [&]() -> exec::Task<std::vector<Result<MailboxMessage>>> {
    std::vector<exec::Task<Result<MailboxMessage>>> tasks;
    for (int i = 0; i < 6; ++i) {
      tasks.push_back(mailbox.request(wire::MailboxType::coe,
                                      upload_request(0x2000, static_cast<std::uint8_t>(1 + i % 2)),
                                      1s));
    }
    co_return co_await exec::when_all(f.bench->loop, std::move(tasks));
  };
  auto replies = f.bench->run(all());
  ASSERT_EQ(replies.size(), 6u);
  for (std::size_t i = 0; i < replies.size(); ++i) {
    ASSERT_TRUE(replies[i].ok()) << replies[i].error().describe();
    EXPECT_EQ(expedited_value(*replies[i]), (i % 2 == 0 ? Bytes{0x34, 0x12} : Bytes{0x00}));
  }
  EXPECT_EQ(mailbox.stats().requests, 6u);
}

TEST(Mailbox, RefusesMisuse) {
  auto f = bring_up();
  ASSERT_TRUE(f.bench);
  Mailbox mailbox(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  Mailbox other(f.bench->loop, *f.bench->bus, 0x1001, f.config);
  auto wrong_lock = [&]() -> exec::Task<Result<MailboxMessage>> {
    auto guard = co_await other.lock();
    co_return co_await mailbox.exchange(guard, wire::MailboxType::coe, upload_request(0x2000, 1),
                                        1s, {}, "borrowed lock");
  };
  auto misuse = f.bench->run(wrong_lock());
  ASSERT_FALSE(misuse.ok());
  EXPECT_EQ(misuse.error().code(), Errc::wrong_state);
  EXPECT_EQ(misuse.error().message(),
            "borrowed lock: the mailbox of slave 0x1001 is used without holding its lock");
  auto too_big =
      f.bench->run(mailbox.request(wire::MailboxType::coe, Bytes(59, 0), 1s, {}, "big request"));
  ASSERT_FALSE(too_big.ok());
  EXPECT_EQ(too_big.error().code(), Errc::invalid_argument);
  EXPECT_EQ(too_big.error().message(),
            "big request: 59 bytes of mailbox data do not fit the mailbox of slave 0x1001 (SM0 of "
            "64 bytes holds at most 58)");
  EXPECT_EQ(mailbox.stats().requests, 0u);
}

}  // namespace
}  // namespace ecat::master
