#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/link/udp_link.hpp>

namespace ecat::link {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

std::vector<std::uint8_t> frame_with(std::uint8_t tag, std::size_t size = 20) {
  std::vector<std::uint8_t> f(size);
  for (std::size_t i = 0; i < size; ++i)
    f[i] = static_cast<std::uint8_t>(tag + i);
  return f;
}

std::vector<std::uint8_t> to_vector(wire::Bytes b) {
  return {b.begin(), b.end()};
}

std::unique_ptr<UdpLink> serve_loopback() {
  auto server = UdpLink::serve("127.0.0.1", 0);
  EXPECT_TRUE(server.ok()) << (server.ok() ? "" : server.error().describe());
  if (!server.ok()) return nullptr;
  EXPECT_NE((*server)->local_port(), 0);
  return std::move(*server);
}

std::unique_ptr<UdpLink> connect_to(const UdpLink& server, const std::string& host = "127.0.0.1") {
  auto client = UdpLink::connect(host, server.local_port());
  EXPECT_TRUE(client.ok()) << (client.ok() ? "" : client.error().describe());
  if (!client.ok()) return nullptr;
  return std::move(*client);
}

std::vector<std::uint8_t> receive_frame(Link& link, std::chrono::nanoseconds timeout = 2s) {
  auto r = link.receive(timeout);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().describe());
  if (!r.ok() || !r->has_value()) return {};
  return to_vector((*r)->frame);
}

TEST(UdpLinkTest, RoundTripOnLoopback) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto client = connect_to(*server);
  ASSERT_TRUE(client);
  const std::string port = std::to_string(server->local_port());
  EXPECT_EQ(server->name(), "udp-server:127.0.0.1:" + port);
  EXPECT_EQ(client->name(), "udp:127.0.0.1:" + port);
  EXPECT_EQ(client->peer(), "127.0.0.1:" + port);
  EXPECT_EQ(server->peer(), "");

  const auto request = frame_with(1, 44);
  const auto before = std::chrono::nanoseconds(Clock::now().time_since_epoch()).count();
  ASSERT_TRUE(client->send(request).ok());
  auto got = server->receive(2s);
  const auto after = std::chrono::nanoseconds(Clock::now().time_since_epoch()).count();
  ASSERT_TRUE(got.ok() && got->has_value());
  EXPECT_EQ(to_vector((*got)->frame), request);
  EXPECT_EQ((*got)->source, wire::MacAddress{});
  EXPECT_GE((*got)->timestamp_ns, before);
  EXPECT_LE((*got)->timestamp_ns, after);
  EXPECT_EQ(server->peer(), "127.0.0.1:" + std::to_string(client->local_port()));

  const auto reply = frame_with(2, wire::kMaxFrameSize);
  ASSERT_TRUE(server->send(reply).ok());
  EXPECT_EQ(receive_frame(*client), reply);

  EXPECT_EQ(client->stats().frames_sent, 1u);
  EXPECT_EQ(client->stats().bytes_sent, 44u);
  EXPECT_EQ(client->stats().frames_received, 1u);
  EXPECT_EQ(client->stats().bytes_received, wire::kMaxFrameSize);
  EXPECT_EQ(server->stats().frames_received, 1u);
  EXPECT_EQ(server->stats().frames_sent, 1u);
}

TEST(UdpLinkTest, IPv6Loopback) {
  auto server = UdpLink::serve("::1", 0);
  if (!server.ok()) GTEST_SKIP() << "no IPv6 loopback here: " << server.error().describe();
  auto client = UdpLink::connect("::1", (*server)->local_port());
  ASSERT_TRUE(client.ok()) << client.error().describe();
  EXPECT_EQ((*client)->name(), "udp:[::1]:" + std::to_string((*server)->local_port()));
  ASSERT_TRUE((*client)->send(frame_with(9)).ok());
  EXPECT_EQ(receive_frame(**server), frame_with(9));
  ASSERT_TRUE((*server)->send(frame_with(10)).ok());
  EXPECT_EQ(receive_frame(**client), frame_with(10));
}

TEST(UdpLinkTest, ServerRepliesToTheMostRecentPeer) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto first = connect_to(*server);
  auto second = connect_to(*server);
  ASSERT_TRUE(first && second);
  ASSERT_NE(first->local_port(), second->local_port());

  ASSERT_TRUE(first->send(frame_with(1)).ok());
  EXPECT_EQ(receive_frame(*server), frame_with(1));
  ASSERT_TRUE(server->send(frame_with(11)).ok());
  ASSERT_TRUE(second->send(frame_with(2)).ok());
  EXPECT_EQ(receive_frame(*server), frame_with(2));
  ASSERT_TRUE(server->send(frame_with(12)).ok());

  EXPECT_EQ(receive_frame(*first), frame_with(11));
  EXPECT_EQ(receive_frame(*second), frame_with(12));
  auto extra_first = first->receive(20ms);
  auto extra_second = second->receive(0ns);
  ASSERT_TRUE(extra_first.ok() && extra_second.ok());
  EXPECT_FALSE(extra_first->has_value());
  EXPECT_FALSE(extra_second->has_value());
}

TEST(UdpLinkTest, ServerWithoutPeerCannotSend) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto r = server->send(frame_with(1));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::wrong_state);
  EXPECT_EQ(r.error().message(), server->name() +
                                     ": no client has sent a frame yet, so there is nobody to "
                                     "reply to");
}

TEST(UdpLinkTest, ClientIgnoresDatagramsFromOtherSenders) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto client = connect_to(*server);
  ASSERT_TRUE(client);
  // A stranger writes to the client's port: a connected UDP socket never sees it.
  const int stranger = ::socket(AF_INET, SOCK_DGRAM, 0);
  ASSERT_GE(stranger, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(client->local_port());
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const auto junk = frame_with(0x40);
  ASSERT_EQ(
      ::sendto(stranger, junk.data(), junk.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof to),
      static_cast<ssize_t>(junk.size()));
  ::close(stranger);
  auto r = client->receive(30ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(UdpLinkTest, RuntAndOversizedDatagramsAreIgnored) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  const int raw = ::socket(AF_INET, SOCK_DGRAM, 0);
  ASSERT_GE(raw, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(server->local_port());
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const std::vector<std::uint8_t> runt{0x01};
  const std::vector<std::uint8_t> huge(3000, 0xAB);
  const auto good = frame_with(3);
  for (const auto* d : {&runt, &huge, &good}) {
    ASSERT_EQ(::sendto(raw, d->data(), d->size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof to),
              static_cast<ssize_t>(d->size()));
  }
  ::close(raw);
  EXPECT_EQ(receive_frame(*server), good);
  EXPECT_EQ(server->stats().frames_ignored, 2u);
  EXPECT_EQ(server->stats().frames_received, 1u);
}

TEST(UdpLinkTest, ReceiveTimesOut) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto start = Clock::now();
  auto r = server->receive(30ms);
  auto elapsed = Clock::now() - start;
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_GE(elapsed, 30ms);
  EXPECT_LT(elapsed, 2s);
  start = Clock::now();
  r = server->receive(0ns);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 50ms);
}

TEST(UdpLinkTest, NobodyListeningIsATimeoutNotAnError) {
  // Find a port nobody listens on by binding and closing it.
  std::uint16_t port = 0;
  {
    auto probe = serve_loopback();
    ASSERT_TRUE(probe);
    port = probe->local_port();
  }
  auto client = UdpLink::connect("127.0.0.1", port);
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE((*client)->send(frame_with(1)).ok());
  auto r = (*client)->receive(50ms);
  ASSERT_TRUE(r.ok()) << r.error().describe();
  EXPECT_FALSE(r->has_value());
  // The ICMP refusal is counted; the next send still goes out.
  ASSERT_TRUE((*client)->send(frame_with(2)).ok());
  EXPECT_EQ((*client)->stats().frames_sent, 2u);
}

TEST(UdpLinkTest, InterruptWakesBlockedReceive) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  std::atomic<bool> returned{false};
  bool ok = false;
  bool had_value = true;
  Clock::time_point woke;
  std::thread receiver([&, link = server.get()] {
    auto r = link->receive(10s);
    woke = Clock::now();
    ok = r.ok();
    had_value = ok && r->has_value();
    returned = true;
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(returned.load());
  const auto interrupted = Clock::now();
  server->interrupt();
  receiver.join();
  EXPECT_TRUE(ok);
  EXPECT_FALSE(had_value);
  EXPECT_LT(woke - interrupted, 200ms);

  // An interrupt with nobody waiting wakes the next receive once.
  server->interrupt();
  auto r = server->receive(5s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  const auto start = Clock::now();
  r = server->receive(30ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_GE(Clock::now() - start, 30ms);
}

TEST(UdpLinkTest, CloseWakesReceiverAndFailsLaterCalls) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  Errc code = Errc::internal;
  std::thread receiver([&, link = server.get()] {
    auto r = link->receive(10s);
    code = r.ok() ? Errc::internal : r.error().code();
  });
  std::this_thread::sleep_for(20ms);
  server->close();
  receiver.join();
  EXPECT_EQ(code, Errc::closed);
  auto s = server->send(frame_with(1));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code(), Errc::closed);
  auto r = server->receive(0ns);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::closed);
  EXPECT_EQ(r.error().message(), server->name() + ": link is closed");
}

TEST(UdpLinkTest, RejectsOversizedFrame) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto client = connect_to(*server);
  ASSERT_TRUE(client);
  std::vector<std::uint8_t> big(wire::kMaxFrameSize + 1);
  auto r = client->send(big);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_EQ(r.error().message(),
            client->name() + ": frame of 1501 bytes exceeds the 1500-byte maximum");
}

TEST(UdpLinkTest, BadHostIsNotFound) {
  auto r = UdpLink::connect("no-such-host.invalid", 34980);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
  EXPECT_EQ(r.error().message().rfind("cannot resolve host 'no-such-host.invalid': ", 0), 0u)
      << r.error().message();
}

TEST(UdpLinkTest, PortInUseIsBusy) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  UdpLinkOptions options;
  options.mode = UdpLinkOptions::Mode::server;
  options.host = "127.0.0.1";
  options.port = server->local_port();
  auto second = UdpLink::open(options);
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code(), Errc::busy);
  EXPECT_EQ(second.error().message(),
            "UDP address 127.0.0.1:" + std::to_string(server->local_port()) + " is already in use");
}

TEST(UdpLinkTest, ClientBindAddressIsUsed) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  UdpLinkOptions options;
  options.host = "127.0.0.1";
  options.port = server->local_port();
  options.bind_address = "127.0.0.1";
  auto client = UdpLink::open(options);
  ASSERT_TRUE(client.ok()) << client.error().describe();
  ASSERT_TRUE((*client)->send(frame_with(4)).ok());
  EXPECT_EQ(receive_frame(*server), frame_with(4));
  EXPECT_EQ(server->peer(), "127.0.0.1:" + std::to_string((*client)->local_port()));

  options.bind_address = "192.0.2.77";  // TEST-NET-1: not configured here
  auto unbindable = UdpLink::open(options);
  ASSERT_FALSE(unbindable.ok());
  EXPECT_EQ(unbindable.error().code(), Errc::not_found) << unbindable.error().describe();
}

TEST(UdpLinkTest, SpinModeReceives) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  UdpLinkOptions options;
  options.host = "127.0.0.1";
  options.port = server->local_port();
  options.spin = true;
  auto client = UdpLink::open(options);
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE((*client)->send(frame_with(5)).ok());
  EXPECT_EQ(receive_frame(*server), frame_with(5));
  std::thread replier([&] {
    std::this_thread::sleep_for(10ms);
    EXPECT_TRUE(server->send(frame_with(6)).ok());
  });
  EXPECT_EQ(receive_frame(**client, 2s), frame_with(6));
  replier.join();
  auto r = (*client)->receive(5ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  (*client)->interrupt();
  const auto start = Clock::now();
  r = (*client)->receive(5s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 1s);
}

}  // namespace
}  // namespace ecat::link

namespace ecat::link {
namespace {

// A server without an address listens on loopback only; "*" is every address, asked for.
TEST(UdpLinkTest, ServerWithoutAddressListensOnLoopbackOnly) {
  auto server = UdpLink::serve("", 0);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  EXPECT_EQ((*server)->name(), "udp-server:127.0.0.1:" + std::to_string((*server)->local_port()));
  auto every = UdpLink::serve("*", 0);
  ASSERT_TRUE(every.ok()) << every.error().describe();
  EXPECT_EQ((*every)->name().find("udp-server:127.0.0.1:"), std::string::npos) << (*every)->name();
}

// One master per segment: while 127.0.0.1 is heard from, 127.0.0.2 (another host on the loopback
// network) is ignored and counted; after the hold time it takes over.
TEST(UdpLinkTest, ServerAnswersOneHostAtATime) {
  UdpLinkOptions options;
  options.mode = UdpLinkOptions::Mode::server;
  options.host = "127.0.0.1";
  options.port = 0;
  options.peer_hold = std::chrono::milliseconds(300);
  auto server = UdpLink::open(options);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  auto first = connect_to(**server);
  ASSERT_TRUE(first);
  UdpLinkOptions other;
  other.host = "127.0.0.1";
  other.port = (*server)->local_port();
  other.bind_address = "127.0.0.2";
  auto second = UdpLink::open(other);
  if (!second.ok()) GTEST_SKIP() << "cannot bind 127.0.0.2: " << second.error().describe();

  ASSERT_TRUE(first->send(frame_with(1, 20)).ok());
  EXPECT_EQ(receive_frame(**server), frame_with(1, 20));
  ASSERT_TRUE((*second)->send(frame_with(2, 20)).ok());
  auto ignored = (*server)->receive(100ms);
  ASSERT_TRUE(ignored.ok());
  EXPECT_FALSE(ignored->has_value()) << "a frame of another host was taken while the first held";
  EXPECT_EQ((*server)->foreign_frames(), 1u);
  EXPECT_EQ((*server)->stats().frames_ignored, 1u);
  ASSERT_TRUE((*server)->send(frame_with(3, 20)).ok());
  EXPECT_EQ(receive_frame(*first), frame_with(3, 20));

  std::this_thread::sleep_for(400ms);
  ASSERT_TRUE((*second)->send(frame_with(4, 20)).ok());
  EXPECT_EQ(receive_frame(**server), frame_with(4, 20));
  EXPECT_EQ((*server)->peer().rfind("127.0.0.2:", 0), 0u) << (*server)->peer();
}

}  // namespace
}  // namespace ecat::link

namespace ecat::link {
namespace {

// A datagram that has arrived is returned before a pending interrupt, which then ends the next
// receive: a reply is never hidden behind a wake-up.
TEST(UdpLinkTest, AFrameThatArrivedComesBeforeAPendingInterrupt) {
  auto server = serve_loopback();
  ASSERT_TRUE(server);
  auto client = connect_to(*server);
  ASSERT_TRUE(client);
  ASSERT_TRUE(client->send(frame_with(7)).ok());
  // Loopback delivers inside sendto: the datagram is queued on the server's socket now.
  server->interrupt();
  EXPECT_EQ(receive_frame(*server, 0s), frame_with(7));
  const auto start = Clock::now();
  auto r = server->receive(5s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 1s);
}

}  // namespace
}  // namespace ecat::link
