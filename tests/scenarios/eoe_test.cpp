// EoE through a whole master session on the in-process simulator: a coupler and an "eoe_device"
// (CoE + EoE, no process data). Set IP Parameter gives the device its address; an ARP request and
// an ICMP echo request sent with Slave::eoe_send come back answered through Slave::eoe_receive;
// a lost reply fragment (the device's fault hook) drops that frame, counted, and the next echo
// works. Then the Linux path: inside a private network namespace of the test thread (made and
// left by the test; skipped without root) a TAP interface for the slave (master::EoeTap) gets
// 192.168.7.1/24 and `ping` reaches the device at 192.168.7.2 -- or, where no ping binary is
// installed, the same ICMP echo from a raw socket of the test -- also after a lost fragment.
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sched.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/master/eoe.hpp>
#include <ecat/master/eoe_tap.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/eoe_server.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/eoe.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

constexpr std::uint32_t kDeviceIp = 0xC0A80702;  // 192.168.7.2
constexpr std::uint32_t kHostIp = 0xC0A80701;    // 192.168.7.1
const Bytes kHostMac = {0x02, 0x11, 0x22, 0x33, 0x44, 0x55};
const Bytes kDeviceMac = {0x02, 0x00, 0x0A, 0xCE, 0x00, 0x01};

RingSpec eoe_spec(const std::string& options) {
  RingSpec spec;
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: eoe, profile: eoe_device)" +
                   options + R"(}
)";
  spec.adjust = [](master::MasterConfig& config) {
    const auto health = config.slaves.front().health_poll;
    config.slaves.clear();
    for (const char* name : {"coupler", "eoe"}) {
      master::SlaveConfig s;
      s.name = name;
      s.health_poll = health;
      config.slaves.push_back(std::move(s));
    }
  };
  return spec;
}

void put16(Bytes& b, std::size_t at, std::uint16_t v) {
  b[at] = static_cast<std::uint8_t>(v >> 8);
  b[at + 1] = static_cast<std::uint8_t>(v);
}
void put32(Bytes& b, std::size_t at, std::uint32_t v) {
  put16(b, at, static_cast<std::uint16_t>(v >> 16));
  put16(b, at + 2, static_cast<std::uint16_t>(v));
}

// An ICMP echo request from the host to the device, `payload` data bytes.
Bytes echo_request(std::uint16_t sequence, std::size_t payload) {
  Bytes f(14 + 20 + 8 + payload, 0);
  std::copy(kDeviceMac.begin(), kDeviceMac.end(), f.begin());
  std::copy(kHostMac.begin(), kHostMac.end(), f.begin() + 6);
  put16(f, 12, 0x0800);
  f[14] = 0x45;
  put16(f, 16, static_cast<std::uint16_t>(20 + 8 + payload));
  f[22] = 64;
  f[23] = 1;
  put32(f, 26, kHostIp);
  put32(f, 30, kDeviceIp);
  put16(f, 24, sim::internet_checksum(std::span<const std::uint8_t>(f).subspan(14, 20)));
  f[34] = 8;
  put16(f, 38, 0x4242);
  put16(f, 40, sequence);
  for (std::size_t i = 0; i < payload; ++i)
    f[42 + i] = static_cast<std::uint8_t>(i);
  put16(f, 36, sim::internet_checksum(std::span<const std::uint8_t>(f).subspan(34)));
  return f;
}

Bytes arp_request() {
  Bytes f = {0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF};
  f.insert(f.end(), kHostMac.begin(), kHostMac.end());
  Bytes rest = {0x08, 0x06, 0x00, 0x01, 0x08, 0x00, 0x06, 0x04, 0x00, 0x01};
  f.insert(f.end(), rest.begin(), rest.end());
  f.insert(f.end(), kHostMac.begin(), kHostMac.end());
  f.insert(f.end(), {0xC0, 0xA8, 0x07, 0x01, 0, 0, 0, 0, 0, 0, 0xC0, 0xA8, 0x07, 0x02});
  return f;
}

// The frames the slave sends within `limit`.
std::vector<Bytes> collect(master::Slave& slave, std::chrono::milliseconds limit) {
  std::vector<Bytes> out;
  const auto end = std::chrono::steady_clock::now() + limit;
  while (out.empty() && std::chrono::steady_clock::now() < end) {
    auto frames = slave.eoe_receive(50ms);
    if (!frames) {
      ADD_FAILURE() << frames.error().describe();
      return out;
    }
    out.insert(out.end(), frames->begin(), frames->end());
  }
  return out;
}

class EoeScenario : public ::testing::Test {
 protected:
  void start(const std::string& options) {
    ring_ = ScenarioRing::operational(eoe_spec(options));
    ASSERT_TRUE(ring_);
  }
  master::Slave& eoe() { return ring_->slave("eoe"); }
  template <class F>
  auto device(F f) {
    return ring_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      return f(*sim::eoe_server_of(segment.esc(*segment.find("eoe"))));
    });
  }
  std::unique_ptr<ScenarioRing> ring_;
};

TEST_F(EoeScenario, SetIpThenArpAndEchoThroughTheSlaveApi) {
  start("");
  // No address yet: an echo is not answered.
  ASSERT_TRUE(eoe().eoe_send(echo_request(1, 8)).ok());
  EXPECT_TRUE(collect(eoe(), 200ms).empty());

  wire::EoeIpParameters p;
  p.ip = kDeviceIp;
  p.subnet_mask = 0xFFFFFF00;
  p.default_gateway = kHostIp;
  p.dns_name = "eoe-device";
  auto set = eoe().eoe_set_ip(p);
  ASSERT_TRUE(set.ok()) << set.error().describe();
  EXPECT_EQ(device([](sim::EoeServer& s) { return s.ip(); }), kDeviceIp);
  EXPECT_EQ(device([](sim::EoeServer& s) { return s.ip_parameters(); }), p);

  ASSERT_TRUE(eoe().eoe_send(arp_request()).ok());
  auto arp = collect(eoe(), 2s);
  ASSERT_EQ(arp.size(), 1u);
  ASSERT_GE(arp[0].size(), 42u);
  EXPECT_EQ(Bytes(arp[0].begin() + 22, arp[0].begin() + 28), kDeviceMac);  // sender MAC

  // 200 data bytes: a 242-byte frame, three fragments each way.
  const Bytes request = echo_request(7, 200);
  ASSERT_TRUE(eoe().eoe_send(request).ok());
  auto replies = collect(eoe(), 2s);
  ASSERT_EQ(replies.size(), 1u);
  const Bytes& r = replies[0];
  ASSERT_EQ(r.size(), request.size());
  EXPECT_EQ(Bytes(r.begin(), r.begin() + 6), kHostMac);
  EXPECT_EQ(r[34], 0);  // echo reply
  EXPECT_EQ(Bytes(r.begin() + 38, r.end()), Bytes(request.begin() + 38, request.end()));
  EXPECT_EQ(sim::internet_checksum(std::span<const std::uint8_t>(r).subspan(14, 20)), 0);
  EXPECT_EQ(sim::internet_checksum(std::span<const std::uint8_t>(r).subspan(34)), 0);
  auto stats = eoe().eoe_stats();
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->frames_sent, 3u);
  EXPECT_GE(stats->fragments_sent, 5u);  // 1 + 1 + 3
  EXPECT_EQ(stats->frames_received, 2u);
  EXPECT_EQ(stats->frames_dropped, 0u);
  EXPECT_EQ(device([](sim::EoeServer& s) { return s.stats().icmp_replies; }), 1u);

  // The coupler has no mailbox: EoE is refused.
  auto coupler = ring_->slave("coupler").eoe_send(request);
  ASSERT_FALSE(coupler.ok());
  EXPECT_EQ(coupler.error().code(), Errc::unsupported);
}

TEST_F(EoeScenario, ALostReplyFragmentDropsThatFrameAndTheNextEchoWorks) {
  start(", options: {ip: 192.168.7.2}");
  device([](sim::EoeServer& s) {
    s.add_fault({sim::EoeFaultKind::drop_reply_fragment, 1, true});
    return 0;
  });
  ASSERT_TRUE(eoe().eoe_send(echo_request(1, 200)).ok());
  EXPECT_TRUE(collect(eoe(), 300ms).empty());
  ASSERT_TRUE(eoe().eoe_send(echo_request(2, 200)).ok());
  auto replies = collect(eoe(), 2s);
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0][41], 2);  // sequence 2
  auto stats = eoe().eoe_stats();
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->frames_dropped, 1u);
  EXPECT_EQ(stats->frames_received, 1u);
  // A lost request fragment: the device drops that frame and counts it.
  device([](sim::EoeServer& s) {
    s.add_fault({sim::EoeFaultKind::drop_request_fragment, 1, true});
    return 0;
  });
  ASSERT_TRUE(eoe().eoe_send(echo_request(3, 200)).ok());
  EXPECT_TRUE(collect(eoe(), 300ms).empty());
  EXPECT_EQ(device([](sim::EoeServer& s) { return s.stats().frames_dropped; }), 1u);
  ASSERT_TRUE(eoe().eoe_send(echo_request(4, 200)).ok());
  ASSERT_EQ(collect(eoe(), 2s).size(), 1u);
}

// ---- the TAP, inside a private network namespace ----------------------------------------------

// The test thread in an anonymous network namespace until the object goes (the namespace goes
// with its last interface and socket).
class TapNamespace {
 public:
  TapNamespace() {
    if (!has_capability(CAP_NET_ADMIN) || !has_capability(CAP_SYS_ADMIN)) {
      why_not_ =
          "needs CAP_NET_ADMIN and CAP_SYS_ADMIN (root) for a private network namespace "
          "with a TAP interface";
      return;
    }
    if (::access("/dev/net/tun", R_OK | W_OK) != 0) {
      why_not_ = "/dev/net/tun is not available (no tun driver)";
      return;
    }
    original_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    if (original_ < 0 || ::unshare(CLONE_NEWNET) != 0) {
      why_not_ = fmt::format("network namespaces are not available: {}", std::strerror(errno));
      return;
    }
    inside_ = true;
    // No IPv6 chatter (router solicitations) on the TAP.
    for (const char* knob : {"/proc/sys/net/ipv6/conf/default/disable_ipv6",
                             "/proc/sys/net/ipv6/conf/all/disable_ipv6"}) {
      std::ofstream(knob) << "1\n";
    }
  }
  ~TapNamespace() {
    if (inside_) (void)::setns(original_, CLONE_NEWNET);
    if (original_ >= 0) ::close(original_);
  }
  TapNamespace(const TapNamespace&) = delete;
  TapNamespace& operator=(const TapNamespace&) = delete;
  const std::string& why_not() const { return why_not_; }

 private:
  int original_ = -1;
  bool inside_ = false;
  std::string why_not_;
};

// One echo request to `address` from a raw ICMP socket (what ping does), `payload` data bytes:
// whether the reply came within `limit`.
bool raw_ping(std::uint32_t address, std::uint16_t sequence, std::size_t payload,
              std::chrono::milliseconds limit) {
  const int s = ::socket(AF_INET, SOCK_RAW | SOCK_CLOEXEC, IPPROTO_ICMP);
  if (s < 0) return false;
  Bytes icmp(8 + payload, 0);
  icmp[0] = 8;
  put16(icmp, 4, 0x5151);
  put16(icmp, 6, sequence);
  for (std::size_t i = 0; i < payload; ++i)
    icmp[8 + i] = static_cast<std::uint8_t>(i);
  put16(icmp, 2, sim::internet_checksum(icmp));
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_addr.s_addr = htonl(address);
  bool answered = false;
  if (::sendto(s, icmp.data(), icmp.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof(to)) ==
      static_cast<ssize_t>(icmp.size())) {
    const auto end = std::chrono::steady_clock::now() + limit;
    std::array<std::uint8_t, 2048> buffer{};
    while (!answered && std::chrono::steady_clock::now() < end) {
      pollfd fd{s, POLLIN, 0};
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now());
      if (::poll(&fd, 1, static_cast<int>(std::max<long>(left.count(), 1))) <= 0) continue;
      const ssize_t got = ::recv(s, buffer.data(), buffer.size(), 0);
      if (got < 20) continue;
      const std::size_t ihl = (buffer[0] & 0x0F) * 4u;
      if (static_cast<std::size_t>(got) < ihl + 8) continue;
      const std::uint8_t* r = buffer.data() + ihl;  // the reply's ICMP part
      answered = r[0] == 0 && r[4] == 0x51 && r[5] == 0x51 && r[6] == (sequence >> 8) &&
                 r[7] == (sequence & 0xFF);
    }
  }
  ::close(s);
  return answered;
}

TEST_F(EoeScenario, APingThroughTheTapReachesTheDevice) {
  start(", options: {ip: 192.168.7.2}");
  TapNamespace ns;
  if (!ns.why_not().empty()) GTEST_SKIP() << ns.why_not();
  master::EoeTapOptions options;
  options.address = kHostIp;
  options.prefix_length = 24;
  auto tap = master::EoeTap::open(eoe(), options);
  ASSERT_TRUE(tap.ok()) << tap.error().describe();
  EXPECT_EQ((*tap)->name(), fmt::format("eoe0s{}", eoe().position()));
  const bool have_ping = run_command("command -v ping");
  // 200 data bytes: the request and the reply go in three fragments each.
  auto ping = [&](std::uint16_t sequence) {
    if (have_ping) return run_command("ping -n -c 1 -W 2 -s 200 192.168.7.2");
    return raw_ping(kDeviceIp, sequence, 200, 2s);
  };
  if (!have_ping) std::cout << "[ info ] no ping binary: an ICMP echo from a raw socket instead\n";
  EXPECT_TRUE(ping(1)) << "no answer through " << (*tap)->name();
  EXPECT_GE(device([](sim::EoeServer& s) { return s.stats().arp_replies; }), 1u);
  EXPECT_GE(device([](sim::EoeServer& s) { return s.stats().icmp_replies; }), 1u);
  // A lost fragment of the next reply: that ping fails, the one after it works.
  device([](sim::EoeServer& s) {
    s.add_fault({sim::EoeFaultKind::drop_reply_fragment, 1, true});
    return 0;
  });
  EXPECT_FALSE(ping(2));
  EXPECT_TRUE(ping(3));
  const auto stats = (*tap)->stats();
  EXPECT_GE(stats.to_slave, 3u);
  EXPECT_GE(stats.from_slave, 2u);
  EXPECT_EQ(stats.send_errors, 0u);
  auto eoe_stats = eoe().eoe_stats();
  ASSERT_TRUE(eoe_stats.ok());
  EXPECT_GE(eoe_stats->frames_dropped, 1u);
  (*tap)->stop();
}

// CAP_NET_ADMIN out of the test thread's effective set while it lives (root keeps it permitted
// and takes it back).
class WithoutNetAdmin {
 public:
  WithoutNetAdmin() {
    if (::syscall(SYS_capget, &header_, saved_.data()) != 0) return;
    auto lowered = saved_;
    lowered[CAP_NET_ADMIN / 32].effective &= ~(1u << (CAP_NET_ADMIN % 32));
    changed_ = ::syscall(SYS_capset, &header_, lowered.data()) == 0;
  }
  ~WithoutNetAdmin() {
    if (changed_) (void)::syscall(SYS_capset, &header_, saved_.data());
  }
  WithoutNetAdmin(const WithoutNetAdmin&) = delete;
  WithoutNetAdmin& operator=(const WithoutNetAdmin&) = delete;

 private:
  __user_cap_header_struct header_{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, 2> saved_{};
  bool changed_ = false;
};

TEST(EoeTap, WithoutTheCapabilityTheErrorNamesIt) {
  auto ring = ScenarioRing::operational(eoe_spec(""));
  ASSERT_TRUE(ring);
  WithoutNetAdmin lowered;
  ASSERT_FALSE(has_capability(CAP_NET_ADMIN));
  auto tap = master::EoeTap::open(ring->slave("eoe"));
  ASSERT_FALSE(tap.ok());
  EXPECT_EQ(tap.error().code(), Errc::permission_denied);
  EXPECT_NE(tap.error().message().find("CAP_NET_ADMIN"), std::string::npos);
}

// The EoE faults through the fault language: a lost reply fragment from the ring file, a wrong
// fragment offset through the control channel. The master's reassembly drops each frame and
// counts it; the next echo works.
TEST_F(EoeScenario, RingAndControlChannelFaultsLoseOneFrameEach) {
  RingSpec spec = eoe_spec(", options: {ip: 192.168.7.2}");
  spec.ring_yaml +=
      "  faults:\n    - {kind: eoe_fault, slave: eoe, mode: drop_reply_fragment, "
      "value: 1}\n";
  ring_ = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring_);
  ASSERT_TRUE(eoe().eoe_send(echo_request(1, 200)).ok());
  EXPECT_TRUE(collect(eoe(), 300ms).empty());
  const std::string reply = sim::handle_control_request(
      *ring_->server, R"({"op":"fault.inject","fault":{"kind":"eoe_fault","slave":"eoe",)"
                      R"("mode":"corrupt_fragment_offset","value":1}})");
  ASSERT_EQ(reply.rfind(R"({"ok":true)", 0), 0u) << reply;
  ASSERT_TRUE(eoe().eoe_send(echo_request(2, 200)).ok());
  EXPECT_TRUE(collect(eoe(), 300ms).empty());
  auto stats = eoe().eoe_stats();
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->frames_dropped, 2u);
  ASSERT_TRUE(eoe().eoe_send(echo_request(3, 200)).ok());
  auto replies = collect(eoe(), 2s);
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0][41], 3);
}

}  // namespace
}  // namespace ecat::scenarios
