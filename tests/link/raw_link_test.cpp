// RawLink on a veth pair inside a private network namespace. The namespace is anonymous
// (unshare(CLONE_NEWNET) on the test thread), so the kernel deletes it and its interfaces as soon
// as the test thread has returned to the original namespace and the sockets are closed: nothing
// is left behind even when an assertion fails or the process dies, and parallel runs cannot
// collide on interface names.
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <linux/if_packet.h>
#include <net/ethernet.h>
#include <net/if.h>
#include <poll.h>
#include <sched.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/link/raw_link.hpp>

namespace ecat::link {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

constexpr wire::MacAddress kMacA{0x10, 0x00, 0x00, 0x00, 0x00, 0x0A};
constexpr wire::MacAddress kMacB{0x10, 0x00, 0x00, 0x00, 0x00, 0x0B};

bool has_capability(int cap) {
  __user_cap_header_struct header{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, 2> data{};
  if (::syscall(SYS_capget, &header, data.data()) != 0) return false;
  return (data[static_cast<std::size_t>(cap / 32)].effective & (1u << (cap % 32))) != 0;
}

bool run(const std::string& command) {
  const int status = std::system((command + " >/dev/null 2>&1").c_str());
  return status != -1 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

std::string mac_text(const wire::MacAddress& mac) {
  char text[18];
  std::snprintf(text, sizeof text, "%02x:%02x:%02x:%02x:%02x:%02x", mac[0], mac[1], mac[2], mac[3],
                mac[4], mac[5]);
  return text;
}

std::int64_t now_ns() {
  return std::chrono::nanoseconds(Clock::now().time_since_epoch()).count();
}

std::vector<std::uint8_t> to_vector(wire::Bytes b) {
  return {b.begin(), b.end()};
}

std::vector<std::uint8_t> pattern(std::size_t size, std::uint8_t seed) {
  std::vector<std::uint8_t> v(size);
  for (std::size_t i = 0; i < size; ++i)
    v[i] = static_cast<std::uint8_t>(seed + 3 * i);
  return v;
}

// A plain AF_PACKET socket on an interface: sees whole Ethernet frames and injects arbitrary ones.
class Tap {
 public:
  explicit Tap(const std::string& interface) {
    fd_ = ::socket(AF_PACKET, SOCK_RAW | SOCK_CLOEXEC, htons(ETH_P_ALL));
    if (fd_ < 0) return;
    const int on = 1;
    ::setsockopt(fd_, SOL_PACKET, PACKET_IGNORE_OUTGOING, &on, sizeof on);
    sockaddr_ll address{};
    address.sll_family = AF_PACKET;
    address.sll_protocol = htons(ETH_P_ALL);
    address.sll_ifindex = static_cast<int>(::if_nametoindex(interface.c_str()));
    ifindex_ = address.sll_ifindex;
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~Tap() {
    if (fd_ >= 0) ::close(fd_);
  }
  Tap(const Tap&) = delete;
  Tap& operator=(const Tap&) = delete;
  bool ok() const { return fd_ >= 0; }

  bool inject(const std::vector<std::uint8_t>& frame) {
    sockaddr_ll to{};
    to.sll_family = AF_PACKET;
    to.sll_ifindex = ifindex_;
    to.sll_halen = ETH_ALEN;
    std::memset(to.sll_addr, 0xFF, ETH_ALEN);
    return ::sendto(fd_, frame.data(), frame.size(), 0, reinterpret_cast<sockaddr*>(&to),
                    sizeof to) == static_cast<ssize_t>(frame.size());
  }

  // The next frame with EtherType 0x88A4 (foreign frames are skipped), or empty after `timeout`.
  std::vector<std::uint8_t> capture_ethercat(std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    std::array<std::uint8_t, 2048> buffer{};
    while (Clock::now() < end) {
      pollfd p{fd_, POLLIN, 0};
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now());
      if (::poll(&p, 1, static_cast<int>(left.count()) + 1) <= 0) continue;
      const ssize_t n = ::recv(fd_, buffer.data(), buffer.size(), MSG_DONTWAIT);
      if (n >= 14 && wire::load_be16(&buffer[12]) == wire::kEtherTypeEtherCat) {
        return {buffer.begin(), buffer.begin() + n};
      }
    }
    return {};
  }

 private:
  int fd_ = -1;
  int ifindex_ = 0;
};

std::vector<std::uint8_t> ethernet(const wire::MacAddress& src, std::uint16_t ether_type,
                                   const std::vector<std::uint8_t>& payload,
                                   std::optional<std::uint16_t> vlan = std::nullopt) {
  std::vector<std::uint8_t> f;
  f.reserve(64 + payload.size());
  for (const auto byte : wire::kBroadcastMac)
    f.push_back(byte);
  for (const auto byte : src)
    f.push_back(byte);
  if (vlan) {
    f.push_back(0x81);
    f.push_back(0x00);
    f.push_back(static_cast<std::uint8_t>(*vlan >> 8));
    f.push_back(static_cast<std::uint8_t>(*vlan));
  }
  f.push_back(static_cast<std::uint8_t>(ether_type >> 8));
  f.push_back(static_cast<std::uint8_t>(ether_type));
  for (const auto byte : payload)
    f.push_back(byte);
  if (f.size() < 60) f.resize(60, 0);
  return f;
}

class RawLinkTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!has_capability(CAP_NET_ADMIN) || !has_capability(CAP_NET_RAW) ||
        !has_capability(CAP_SYS_ADMIN)) {
      GTEST_SKIP() << "needs root (CAP_NET_ADMIN, CAP_NET_RAW and CAP_SYS_ADMIN) to create a "
                      "network namespace with a veth pair";
    }
    if (!run("command -v ip")) GTEST_SKIP() << "the `ip` command (iproute2) is not installed";
    original_ns_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    ASSERT_GE(original_ns_, 0) << "cannot open /proc/thread-self/ns/net: " << std::strerror(errno);
    if (::unshare(CLONE_NEWNET) != 0) {
      const int err = errno;
      ::close(original_ns_);
      original_ns_ = -1;
      GTEST_SKIP() << "network namespaces are not available: unshare(CLONE_NEWNET): "
                   << std::strerror(err);
    }
    in_private_ns_ = true;
    // IPv6 would make the veths chatter (router solicitations, MLD) and spoil the exact counts.
    for (const char* knob : {"/proc/sys/net/ipv6/conf/default/disable_ipv6",
                             "/proc/sys/net/ipv6/conf/all/disable_ipv6"}) {
      std::ofstream(knob) << "1\n";
    }
    if (!run("ip link add name a type veth peer name b")) {
      GTEST_SKIP() << "cannot create a veth pair (is the veth driver available?)";
    }
    ASSERT_TRUE(run("ip link set dev a address " + mac_text(kMacA)));
    ASSERT_TRUE(run("ip link set dev b address " + mac_text(kMacB)));
    ASSERT_TRUE(run("ip link set dev a up"));
    ASSERT_TRUE(run("ip link set dev b up"));
  }

  void TearDown() override {
    links_.clear();
    if (in_private_ns_) {
      // The anonymous namespace disappears with its last user: this thread leaving it and the
      // sockets closed above.
      EXPECT_EQ(::setns(original_ns_, CLONE_NEWNET), 0) << std::strerror(errno);
      in_private_ns_ = false;
    }
    if (original_ns_ >= 0) ::close(original_ns_);
    original_ns_ = -1;
  }

  RawLink& open_ok(RawLinkOptions options) {
    auto r = RawLink::open(options);
    EXPECT_TRUE(r.ok()) << options.interface << ": " << (r.ok() ? "" : r.error().describe());
    // gtest reports the exception as a failure of this test and still runs TearDown().
    if (!r.ok()) throw std::runtime_error("cannot open " + options.interface);
    links_.push_back(std::move(*r));
    return *links_.back();
  }
  RawLink& open_ok(const std::string& interface) {
    RawLinkOptions options;
    options.interface = interface;
    return open_ok(options);
  }

  std::vector<std::uint8_t> receive_frame(Link& link, std::chrono::nanoseconds timeout = 2s) {
    auto r = link.receive(timeout);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().describe());
    if (!r.ok() || !r->has_value()) return {};
    last_source_ = (*r)->source;
    last_timestamp_ = (*r)->timestamp_ns;
    return to_vector((*r)->frame);
  }

  int original_ns_ = -1;
  bool in_private_ns_ = false;
  std::vector<std::unique_ptr<RawLink>> links_;
  wire::MacAddress last_source_{};
  std::int64_t last_timestamp_ = 0;
};

TEST_F(RawLinkTest, FramesCrossThePairBothWays) {
  RawLink& master = open_ok("a");
  RawLink& segment = open_ok("b");
  EXPECT_EQ(master.name(), "a");
  EXPECT_EQ(master.interface_mac(), kMacA);
  EXPECT_EQ(master.source_mac(), kMacA);
  EXPECT_EQ(master.max_frame_size(), 1500u);
  EXPECT_GT(master.interface_index(), 0);

  const auto request = pattern(20, 1);
  ASSERT_TRUE(master.send(request).ok());
  auto got = receive_frame(segment);
  // Padded to the 60-byte Ethernet minimum: 46 bytes after the 14-byte header.
  ASSERT_EQ(got.size(), 46u);
  EXPECT_EQ(std::vector<std::uint8_t>(got.begin(), got.begin() + 20), request);
  EXPECT_EQ(std::vector<std::uint8_t>(got.begin() + 20, got.end()), std::vector<std::uint8_t>(26));
  EXPECT_EQ(last_source_, kMacA);

  const auto reply = pattern(1500, 7);
  ASSERT_TRUE(segment.send(reply).ok());
  EXPECT_EQ(receive_frame(master), reply);
  EXPECT_EQ(last_source_, kMacB);

  EXPECT_EQ(master.stats().frames_sent, 1u);
  EXPECT_EQ(master.stats().bytes_sent, 20u);
  EXPECT_EQ(master.stats().frames_received, 1u);
  EXPECT_EQ(master.stats().bytes_received, 1500u);
  EXPECT_EQ(segment.stats().bytes_received, 46u);
  EXPECT_EQ(master.stats().frames_ignored, 0u);
}

TEST_F(RawLinkTest, OwnOutgoingFramesAreNotReceived) {
  RawLink& master = open_ok("a");
  RawLink& segment = open_ok("b");
  EXPECT_TRUE(master.ignores_outgoing_in_kernel());
  ASSERT_TRUE(master.send(pattern(30, 2)).ok());
  ASSERT_TRUE(master.send(pattern(30, 3)).ok());
  auto r = master.receive(50ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_EQ(master.stats().frames_received, 0u);
  EXPECT_EQ(receive_frame(segment).size(), 46u);
  EXPECT_EQ(receive_frame(segment).size(), 46u);
}

TEST_F(RawLinkTest, ForeignFramesAreIgnoredAndCounted) {
  RawLink& master = open_ok("a");
  Tap tap("b");
  ASSERT_TRUE(tap.ok());
  ASSERT_TRUE(tap.inject(ethernet(kMacB, 0x0800, pattern(40, 9))));  // IPv4
  ASSERT_TRUE(tap.inject(ethernet(kMacB, 0x0806, pattern(28, 9))));  // ARP
  ASSERT_TRUE(tap.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(50, 4))));
  EXPECT_EQ(receive_frame(master), pattern(50, 4));
  EXPECT_EQ(master.stats().frames_ignored, 2u);
  EXPECT_EQ(master.stats().frames_received, 1u);
}

TEST_F(RawLinkTest, KernelFilterDropsForeignFramesBeforeUserSpace) {
  RawLinkOptions options;
  options.interface = "a";
  options.kernel_filter = true;
  RawLink& master = open_ok(options);
  Tap tap("b");
  ASSERT_TRUE(tap.ok());
  ASSERT_TRUE(tap.inject(ethernet(kMacB, 0x0800, pattern(40, 9))));
  ASSERT_TRUE(tap.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(50, 4))));
  ASSERT_TRUE(tap.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(50, 5), 0x0005)));
  EXPECT_EQ(receive_frame(master), pattern(50, 4));
  EXPECT_EQ(receive_frame(master), pattern(50, 5));
  EXPECT_EQ(master.stats().frames_ignored, 0u);
}

TEST_F(RawLinkTest, VlanTaggedFramesAreAccepted) {
  RawLink& master = open_ok("a");
  Tap tap("b");
  ASSERT_TRUE(tap.ok());
  ASSERT_TRUE(tap.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(64, 6), 0x2007)));
  EXPECT_EQ(receive_frame(master), pattern(64, 6));
  EXPECT_EQ(last_source_, kMacB);
  // A tagged foreign frame is still foreign.
  ASSERT_TRUE(tap.inject(ethernet(kMacB, 0x0800, pattern(64, 6), 0x0007)));
  auto r = master.receive(50ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_EQ(master.stats().frames_ignored, 1u);
}

TEST_F(RawLinkTest, SentFramesArePaddedTo60Bytes) {
  RawLink& master = open_ok("a");
  Tap tap("b");
  ASSERT_TRUE(tap.ok());
  const auto frame = pattern(10, 0x20);
  ASSERT_TRUE(master.send(frame).ok());
  const auto wire_frame = tap.capture_ethercat(2000ms);
  ASSERT_EQ(wire_frame.size(), 60u);
  EXPECT_EQ(std::vector<std::uint8_t>(wire_frame.begin(), wire_frame.begin() + 6),
            std::vector<std::uint8_t>(6, 0xFF));
  EXPECT_EQ(std::vector<std::uint8_t>(wire_frame.begin() + 6, wire_frame.begin() + 12),
            std::vector<std::uint8_t>(kMacA.begin(), kMacA.end()));
  EXPECT_EQ(wire_frame[12], 0x88);
  EXPECT_EQ(wire_frame[13], 0xA4);
  EXPECT_EQ(std::vector<std::uint8_t>(wire_frame.begin() + 14, wire_frame.begin() + 24), frame);
  EXPECT_EQ(std::vector<std::uint8_t>(wire_frame.begin() + 24, wire_frame.end()),
            std::vector<std::uint8_t>(36));

  // A frame that already fills the minimum is not padded.
  ASSERT_TRUE(master.send(pattern(100, 1)).ok());
  EXPECT_EQ(tap.capture_ethercat(2000ms).size(), 114u);
}

TEST_F(RawLinkTest, SourceMacOverride) {
  RawLinkOptions options;
  options.interface = "a";
  options.source_mac = wire::MacAddress{0x02, 0xEC, 0xA7, 0x00, 0x00, 0x01};
  RawLink& master = open_ok(options);
  EXPECT_EQ(master.interface_mac(), kMacA);
  EXPECT_EQ(master.source_mac(), *options.source_mac);
  Tap tap("b");
  ASSERT_TRUE(tap.ok());
  ASSERT_TRUE(master.send(pattern(10, 0)).ok());
  const auto wire_frame = tap.capture_ethercat(2000ms);
  ASSERT_EQ(wire_frame.size(), 60u);
  EXPECT_EQ(std::vector<std::uint8_t>(wire_frame.begin() + 6, wire_frame.begin() + 12),
            std::vector<std::uint8_t>(options.source_mac->begin(), options.source_mac->end()));
}

TEST_F(RawLinkTest, ResponderRepliesFromTheRequestersAddressWithBit1Set) {
  RawLink& master = open_ok("a");
  RawLinkOptions options;
  options.interface = "b";
  options.responder = true;
  RawLink& segment = open_ok(options);

  ASSERT_TRUE(master.send(pattern(40, 1)).ok());
  ASSERT_EQ(receive_frame(segment).size(), 46u);
  EXPECT_EQ(last_source_, kMacA);
  Tap tap("a");
  ASSERT_TRUE(tap.ok());
  ASSERT_TRUE(segment.send(pattern(40, 2)).ok());
  const auto reply = receive_frame(master);
  ASSERT_EQ(reply.size(), 46u);
  EXPECT_EQ(std::vector<std::uint8_t>(reply.begin(), reply.begin() + 40), pattern(40, 2));
  const wire::MacAddress expected{0x12, 0x00, 0x00, 0x00, 0x00, 0x0A};
  EXPECT_EQ(last_source_, expected);
  const auto seen = tap.capture_ethercat(2000ms);
  ASSERT_EQ(seen.size(), 60u);
  EXPECT_EQ(std::vector<std::uint8_t>(seen.begin(), seen.begin() + 6),
            std::vector<std::uint8_t>(6, 0xFF));  // the request's destination
  EXPECT_EQ(std::vector<std::uint8_t>(seen.begin() + 6, seen.begin() + 12),
            std::vector<std::uint8_t>(expected.begin(), expected.end()));
}

TEST_F(RawLinkTest, ReceiveTimestampsAreMonotonicClock) {
  RawLink& master = open_ok("a");
  RawLink& segment = open_ok("b");
  EXPECT_TRUE(segment.has_kernel_timestamps());
  // The kernel switches receive stamping on through deferred work after the first socket asks for
  // it; until then a frame is stamped when it is read. Let that settle: frames until one is
  // stamped at its arrival (a loaded machine runs the deferred work late), for 5 s at most.
  const auto settle_until = std::chrono::steady_clock::now() + 5s;
  bool settled = false;
  while (!settled && std::chrono::steady_clock::now() < settle_until) {
    ASSERT_TRUE(master.send(pattern(20, 0xFF)).ok());
    std::this_thread::sleep_for(2ms);
    ASSERT_EQ(receive_frame(segment).size(), 46u);
    settled = last_timestamp_ < now_ns() - 1'000'000;
  }
  ASSERT_TRUE(settled) << "every frame for 5 s was stamped when read, not when it arrived";
  std::int64_t previous = 0;
  for (int i = 0; i < 5; ++i) {
    const std::int64_t before = now_ns();
    ASSERT_TRUE(master.send(pattern(20, static_cast<std::uint8_t>(i))).ok());
    std::this_thread::sleep_for(2ms);  // the stamp must be the arrival, not the read
    ASSERT_EQ(receive_frame(segment).size(), 46u);
    const std::int64_t after = now_ns();
    EXPECT_GE(last_timestamp_, before);
    EXPECT_LE(last_timestamp_, after);
    EXPECT_LT(last_timestamp_, after - 1'000'000) << "looks like a read-time stamp";
    EXPECT_GT(last_timestamp_, previous);
    previous = last_timestamp_;
  }
}

TEST_F(RawLinkTest, SpinModeReceives) {
  RawLink& master = open_ok("a");
  RawLinkOptions options;
  options.interface = "b";
  options.spin = true;
  RawLink& segment = open_ok(options);
  std::thread sender([&] {
    std::this_thread::sleep_for(10ms);
    EXPECT_TRUE(master.send(pattern(50, 3)).ok());
  });
  EXPECT_EQ(receive_frame(segment), pattern(50, 3));
  sender.join();
  auto r = segment.receive(5ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST_F(RawLinkTest, InterruptAndClose) {
  RawLink& master = open_ok("a");
  std::atomic<bool> returned{false};
  bool ok = false;
  bool had_value = true;
  std::thread receiver([&] {
    auto r = master.receive(10s);
    ok = r.ok();
    had_value = ok && r->has_value();
    returned = true;
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(returned.load());
  const auto start = Clock::now();
  master.interrupt();
  receiver.join();
  EXPECT_LT(Clock::now() - start, 200ms);
  EXPECT_TRUE(ok);
  EXPECT_FALSE(had_value);

  Errc code = Errc::internal;
  std::thread blocked([&] {
    auto r = master.receive(10s);
    code = r.ok() ? Errc::internal : r.error().code();
  });
  std::this_thread::sleep_for(20ms);
  master.close();
  blocked.join();
  EXPECT_EQ(code, Errc::closed);
  auto s = master.send(pattern(10, 0));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code(), Errc::closed);
  EXPECT_EQ(s.error().message(), "a: link is closed");
}

TEST_F(RawLinkTest, FramesLargerThanTheMtuAreRejected) {
  ASSERT_TRUE(run("ip link set dev a mtu 1000"));
  RawLink& master = open_ok("a");
  EXPECT_EQ(master.max_frame_size(), 1000u);
  auto r = master.send(pattern(1001, 0));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_EQ(r.error().message(), "a: frame of 1001 bytes exceeds the 1000-byte maximum");
  EXPECT_TRUE(master.send(pattern(1000, 0)).ok());
}

TEST_F(RawLinkTest, MissingInterfaceIsNotFound) {
  RawLinkOptions options;
  options.interface = "ecs0";
  auto r = RawLink::open(options);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
  EXPECT_EQ(r.error().message(), "network interface 'ecs0' does not exist (see `ip link`)");
}

TEST_F(RawLinkTest, InterfaceDownIsAClearError) {
  ASSERT_TRUE(run("ip link add name c type veth peer name d"));
  RawLinkOptions options;
  options.interface = "c";
  auto r = RawLink::open(options);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::io_error);
  EXPECT_EQ(r.error().message(),
            "network interface 'c' is down (bring it up with `ip link set c up`)");
}

TEST_F(RawLinkTest, NonEthernetInterfaceIsUnsupported) {
  ASSERT_TRUE(run("ip link set dev lo up"));
  RawLinkOptions options;
  options.interface = "lo";
  auto r = RawLink::open(options);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::unsupported);
  EXPECT_EQ(r.error().message(),
            "network interface 'lo' is not an Ethernet interface (ARP hardware type 772)");
}

// Runs RawLink::open on "lo" without CAP_NET_RAW and reports code and message.
TEST(RawLinkPermissionTest, WithoutCapNetRawTheErrorNamesTheFix) {
  const std::string expected =
      "cannot open a raw socket on 'lo': raw sockets need CAP_NET_RAW: run as root or grant it "
      "with `setcap cap_net_raw,cap_net_admin+ep <binary>`";
  auto check = [&](const Result<std::unique_ptr<RawLink>>& r) {
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code(), Errc::permission_denied);
    EXPECT_EQ(r.error().message(), expected);
  };
  RawLinkOptions options;
  options.interface = "lo";
  if (!has_capability(CAP_NET_RAW)) {
    check(RawLink::open(options));
    return;
  }
  if (!has_capability(CAP_SETUID) || !has_capability(CAP_SETGID)) {
    GTEST_SKIP() << "has CAP_NET_RAW but cannot drop to another user to lose it";
  }
  std::array<int, 2> pipe_fds{};
  ASSERT_EQ(::pipe(pipe_fds.data()), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(pipe_fds[0]);
    // Changing every uid away from 0 clears the permitted and effective capability sets.
    if (::setgroups(0, nullptr) != 0 || ::setgid(65534) != 0 || ::setuid(65534) != 0) _exit(3);
    auto r = RawLink::open(options);
    std::string report =
        r.ok() ? std::string("opened")
               : std::string(to_string(r.error().code())) + "\n" + r.error().message();
    const auto written = ::write(pipe_fds[1], report.data(), report.size());
    _exit(written == static_cast<ssize_t>(report.size()) ? 0 : 4);
  }
  ::close(pipe_fds[1]);
  std::string report;
  std::array<char, 512> buffer{};
  ssize_t n = 0;
  while ((n = ::read(pipe_fds[0], buffer.data(), buffer.size())) > 0) {
    report.append(buffer.data(), static_cast<std::size_t>(n));
  }
  ::close(pipe_fds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0) << "the child could not drop privileges or report";
  EXPECT_EQ(report, std::string(to_string(Errc::permission_denied)) + "\n" + expected);
}

}  // namespace
}  // namespace ecat::link
