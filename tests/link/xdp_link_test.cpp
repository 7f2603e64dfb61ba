// XdpLink on a veth pair inside a private network namespace, exchanging frames with a RawLink (or a
// plain AF_PACKET socket) on the other end. The namespace is anonymous (unshare(CLONE_NEWNET) on
// the test thread): the kernel deletes it, its interfaces and the XDP program attached to them
// as soon as the test thread has returned to the original namespace and the sockets are closed.
// Skips with the reason when the build has no AF_XDP link or the privileges are missing.
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
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

#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/xdp_link.hpp>

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

std::vector<std::uint8_t> to_vector(wire::Bytes b) {
  return {b.begin(), b.end()};
}

std::vector<std::uint8_t> pattern(std::size_t size, std::uint8_t seed) {
  std::vector<std::uint8_t> v(size);
  for (std::size_t i = 0; i < size; ++i)
    v[i] = static_cast<std::uint8_t>(seed + 3 * i);
  return v;
}

std::vector<std::uint8_t> ethernet(const wire::MacAddress& src, std::uint16_t ether_type,
                                   const std::vector<std::uint8_t>& payload,
                                   std::optional<std::uint16_t> vlan = std::nullopt) {
  std::vector<std::uint8_t> f(wire::kBroadcastMac.begin(), wire::kBroadcastMac.end());
  f.insert(f.end(), src.begin(), src.end());
  if (vlan) {
    f.insert(f.end(),
             {0x81, 0x00, static_cast<std::uint8_t>(*vlan >> 8), static_cast<std::uint8_t>(*vlan)});
  }
  f.push_back(static_cast<std::uint8_t>(ether_type >> 8));
  f.push_back(static_cast<std::uint8_t>(ether_type));
  f.insert(f.end(), payload.begin(), payload.end());
  if (f.size() < 60) f.resize(60, 0);
  return f;
}

// A plain AF_PACKET socket on an interface: injects arbitrary frames and sees what the kernel's
// stack receives there (what the XDP program passed on).
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

  // The next frame with this EtherType (others are skipped), or empty after `timeout`.
  std::vector<std::uint8_t> capture(std::uint16_t ether_type, std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    std::array<std::uint8_t, 2048> buffer{};
    while (Clock::now() < end) {
      pollfd p{fd_, POLLIN, 0};
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now());
      if (::poll(&p, 1, static_cast<int>(left.count()) + 1) <= 0) continue;
      const ssize_t n = ::recv(fd_, buffer.data(), buffer.size(), MSG_DONTWAIT);
      if (n >= 14 && wire::load_be16(&buffer[12]) == ether_type) {
        return {buffer.begin(), buffer.begin() + n};
      }
    }
    return {};
  }

 private:
  int fd_ = -1;
  int ifindex_ = 0;
};

class XdpLinkTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!xdp_link_available()) {
      GTEST_SKIP() << "this build has no AF_XDP link (libxdp-dev and libbpf-dev were not found)";
    }
    if (!has_capability(CAP_NET_ADMIN) || !has_capability(CAP_NET_RAW) ||
        !has_capability(CAP_SYS_ADMIN)) {
      GTEST_SKIP() << "needs root (CAP_NET_ADMIN, CAP_NET_RAW and CAP_SYS_ADMIN) to create a "
                      "network namespace with a veth pair and attach an XDP program";
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
    // Whether AF_XDP and XDP work here at all: skip (not fail) when the kernel refuses them.
    XdpLinkOptions probe;
    probe.interface = "a";
    auto opened = XdpLink::open(probe);
    if (!opened.ok() && (opened.error().code() == Errc::unsupported ||
                         opened.error().code() == Errc::permission_denied)) {
      GTEST_SKIP() << "AF_XDP is not usable here: " << opened.error().describe();
    }
    ASSERT_TRUE(opened.ok()) << opened.error().describe();
  }

  void TearDown() override {
    xdp_links_.clear();
    raw_links_.clear();
    if (in_private_ns_) {
      EXPECT_EQ(::setns(original_ns_, CLONE_NEWNET), 0) << std::strerror(errno);
      in_private_ns_ = false;
    }
    if (original_ns_ >= 0) ::close(original_ns_);
    original_ns_ = -1;
  }

  XdpLink& open_xdp(XdpLinkOptions options) {
    auto r = XdpLink::open(options);
    EXPECT_TRUE(r.ok()) << options.interface << ": " << (r.ok() ? "" : r.error().describe());
    if (!r.ok()) throw std::runtime_error("cannot open " + options.interface);
    xdp_links_.push_back(std::move(*r));
    return *xdp_links_.back();
  }
  XdpLink& open_xdp(const std::string& interface) {
    XdpLinkOptions options;
    options.interface = interface;
    return open_xdp(options);
  }
  RawLink& open_raw(const std::string& interface, bool responder = false) {
    RawLinkOptions options;
    options.interface = interface;
    options.responder = responder;
    auto r = RawLink::open(options);
    EXPECT_TRUE(r.ok()) << interface << ": " << (r.ok() ? "" : r.error().describe());
    if (!r.ok()) throw std::runtime_error("cannot open " + interface);
    raw_links_.push_back(std::move(*r));
    return *raw_links_.back();
  }

  std::vector<std::uint8_t> receive_frame(Link& link, std::chrono::nanoseconds timeout = 2s) {
    auto r = link.receive(timeout);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().describe());
    if (!r.ok() || !r->has_value()) return {};
    last_source_ = (*r)->source;
    last_timestamp_ = (*r)->timestamp_ns;
    return to_vector((*r)->frame);
  }

  void expect_exchange(Link& master, Link& segment, std::uint8_t seed) {
    const auto request = pattern(20, seed);
    ASSERT_TRUE(master.send(request).ok());
    auto got = receive_frame(segment);
    ASSERT_EQ(got.size(), 46u);  // padded to the 60-byte Ethernet minimum
    EXPECT_EQ(std::vector<std::uint8_t>(got.begin(), got.begin() + 20), request);
    const auto reply = pattern(1500, static_cast<std::uint8_t>(seed + 1));
    ASSERT_TRUE(segment.send(reply).ok());
    EXPECT_EQ(receive_frame(master), reply);
  }

  int original_ns_ = -1;
  bool in_private_ns_ = false;
  std::vector<std::unique_ptr<XdpLink>> xdp_links_;
  std::vector<std::unique_ptr<RawLink>> raw_links_;
  wire::MacAddress last_source_{};
  std::int64_t last_timestamp_ = 0;
};

TEST_F(XdpLinkTest, FramesCrossThePairBothWaysWithARawLink) {
  XdpLink& master = open_xdp("a");
  RawLink& segment = open_raw("b");
  EXPECT_EQ(master.name(), "xdp:a");
  EXPECT_EQ(master.max_frame_size(), 1500u);
  const XdpLinkInfo info = master.info();
  EXPECT_EQ(info.interface_mac, kMacA);
  EXPECT_GT(info.interface_index, 0);
  EXPECT_EQ(info.queue_id, 0u);
  EXPECT_TRUE(info.native) << "veth runs XDP in its driver";
  EXPECT_FALSE(info.zero_copy) << "veth has no zero-copy AF_XDP";
  EXPECT_FALSE(info.busy_poll);

  const auto request = pattern(20, 1);
  ASSERT_TRUE(master.send(request).ok());
  auto got = receive_frame(segment);
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
  EXPECT_EQ(master.stats().frames_ignored, 0u);
}

TEST_F(XdpLinkTest, ManyFramesReuseThePreallocatedUmem) {
  // More round trips than the UMEM has frames in either direction: frames go back to the rings.
  XdpLinkOptions options;
  options.interface = "a";
  options.rx_frames = 8;
  options.tx_frames = 8;
  XdpLink& master = open_xdp(options);
  RawLink& segment = open_raw("b");
  for (int i = 0; i < 100; ++i) {
    const auto frame = pattern(64, static_cast<std::uint8_t>(i));
    ASSERT_TRUE(master.send(frame).ok()) << i;
    ASSERT_EQ(receive_frame(segment), frame) << i;
    ASSERT_TRUE(segment.send(frame).ok()) << i;
    ASSERT_EQ(receive_frame(master), frame) << i;
  }
  EXPECT_EQ(master.stats().frames_sent, 100u);
  EXPECT_EQ(master.stats().frames_received, 100u);
  EXPECT_EQ(master.stats().frames_dropped, 0u);
}

TEST_F(XdpLinkTest, OnlyEtherCatIsRedirectedTheRestReachesTheKernel) {
  XdpLink& master = open_xdp("a");
  Tap kernel_side("a");  // what the kernel's stack on `a` receives
  Tap peer("b");
  ASSERT_TRUE(kernel_side.ok() && peer.ok());
  ASSERT_TRUE(peer.inject(ethernet(kMacB, 0x0800, pattern(40, 9))));  // IPv4
  ASSERT_TRUE(peer.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(50, 4))));
  ASSERT_TRUE(peer.inject(ethernet(kMacB, wire::kEtherTypeEtherCat, pattern(50, 5), 0x0005)));
  EXPECT_EQ(receive_frame(master), pattern(50, 4));
  EXPECT_EQ(receive_frame(master), pattern(50, 5)) << "802.1Q-tagged EtherCAT";
  // The IPv4 frame went to the kernel, the EtherCAT ones did not.
  EXPECT_FALSE(kernel_side.capture(0x0800, 2000ms).empty());
  EXPECT_TRUE(kernel_side.capture(wire::kEtherTypeEtherCat, 100ms).empty());
  EXPECT_EQ(master.stats().frames_ignored, 0u);
  EXPECT_EQ(master.stats().frames_received, 2u);
}

TEST_F(XdpLinkTest, AnAfXdpLinkOnEachEnd) {
  XdpLink& master = open_xdp("a");
  XdpLinkOptions options;
  options.interface = "b";
  options.responder = true;
  XdpLink& segment = open_xdp(options);
  ASSERT_TRUE(master.send(pattern(40, 1)).ok());
  ASSERT_EQ(receive_frame(segment).size(), 46u);
  EXPECT_EQ(last_source_, kMacA);
  ASSERT_TRUE(segment.send(pattern(40, 2)).ok());
  const auto reply = receive_frame(master);
  ASSERT_EQ(reply.size(), 46u);
  EXPECT_EQ(std::vector<std::uint8_t>(reply.begin(), reply.begin() + 40), pattern(40, 2));
  // As a real ESC: from the request's source with bit 1 of the first byte set.
  const wire::MacAddress expected{0x12, 0x00, 0x00, 0x00, 0x00, 0x0A};
  EXPECT_EQ(last_source_, expected);
}

TEST_F(XdpLinkTest, GenericModeCopyModeBusyPollAndSpin) {
  XdpLinkOptions options;
  options.interface = "a";
  options.attach = XdpAttachMode::generic;
  options.copy = XdpCopyMode::copy;
  options.busy_poll_us = 20;
  options.spin = true;
  XdpLink& master = open_xdp(options);
  EXPECT_FALSE(master.info().native);
  EXPECT_FALSE(master.info().zero_copy);
  EXPECT_TRUE(master.info().busy_poll);
  RawLink& segment = open_raw("b");
  expect_exchange(master, segment, 3);
  // Spinning still honours the deadline.
  const auto start = Clock::now();
  auto r = master.receive(5ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_GE(Clock::now() - start, 5ms);
}

TEST_F(XdpLinkTest, ASecondLinkOnTheInterfaceIsBusyAndClosingDetaches) {
  XdpLink& first = open_xdp("a");
  XdpLinkOptions options;
  options.interface = "a";
  auto second = XdpLink::open(options);
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code(), Errc::busy) << second.error().describe();
  // The queue's socket is found first (a second queue would find the program instead).
  EXPECT_EQ(second.error().message(), "xdp:a: queue 0 of 'a' already has an AF_XDP socket");
  first.close();
  // The program went with the first link: the interface takes a new one, and frames flow.
  XdpLink& third = open_xdp("a");
  RawLink& segment = open_raw("b");
  expect_exchange(third, segment, 5);
}

TEST_F(XdpLinkTest, ReopenAttachesAnew) {
  XdpLink& master = open_xdp("a");
  RawLink& segment = open_raw("b");
  expect_exchange(master, segment, 1);
  ASSERT_TRUE(master.reopen().ok());
  expect_exchange(master, segment, 2);
}

TEST_F(XdpLinkTest, InterruptAndClose) {
  XdpLink& master = open_xdp("a");
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
  EXPECT_EQ(s.error().message(), "xdp:a: link is closed");
}

TEST_F(XdpLinkTest, FramesLargerThanTheMtuAreRejected) {
  ASSERT_TRUE(run("ip link set dev a mtu 1000"));
  XdpLink& master = open_xdp("a");
  EXPECT_EQ(master.max_frame_size(), 1000u);
  auto r = master.send(pattern(1001, 0));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_EQ(r.error().message(), "xdp:a: frame of 1001 bytes exceeds the 1000-byte maximum");
  EXPECT_TRUE(master.send(pattern(1000, 0)).ok());
}

TEST_F(XdpLinkTest, ClearErrors) {
  XdpLinkOptions options;
  options.interface = "ecs0";
  auto missing = XdpLink::open(options);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  EXPECT_EQ(missing.error().message(), "network interface 'ecs0' does not exist (see `ip link`)");

  ASSERT_TRUE(run("ip link add name c type veth peer name d"));
  options.interface = "c";
  auto down = XdpLink::open(options);
  ASSERT_FALSE(down.ok());
  EXPECT_EQ(down.error().code(), Errc::io_error);
  EXPECT_EQ(down.error().message(),
            "network interface 'c' is down (bring it up with `ip link set c up`)");

  options.interface = "a";
  options.queue_id = 7;  // a veth has one queue
  auto queue = XdpLink::open(options);
  ASSERT_FALSE(queue.ok());
  EXPECT_EQ(queue.error().code(), Errc::not_found) << queue.error().describe();
  EXPECT_NE(queue.error().message().find("queue 7 of 'a'"), std::string::npos);

  options.queue_id = 0;
  options.rx_frames = 100;
  auto frames = XdpLink::open(options);
  ASSERT_FALSE(frames.ok());
  EXPECT_EQ(frames.error().code(), Errc::invalid_argument);

  ASSERT_TRUE(run("ip link set dev lo up"));
  options.interface = "lo";
  options.rx_frames = 256;
  auto loopback = XdpLink::open(options);
  ASSERT_FALSE(loopback.ok());
  EXPECT_EQ(loopback.error().code(), Errc::unsupported);
}

TEST_F(XdpLinkTest, OpenLinkSpec) {
  auto link = open_link("xdp:a,busy_poll=10,spin");
  ASSERT_TRUE(link.ok()) << link.error().describe();
  EXPECT_EQ((*link)->name(), "xdp:a");
  auto* xdp = dynamic_cast<XdpLink*>(link->get());
  ASSERT_NE(xdp, nullptr);
  EXPECT_TRUE(xdp->info().busy_poll);
  RawLink& segment = open_raw("b");
  expect_exchange(**link, segment, 9);
}

}  // namespace
}  // namespace ecat::link
