// Foreign EtherCAT traffic on the wire while the master starts the ring over raw Ethernet (the
// reference's raw_socket_noise_resilience test, docs/scenarios/rogue-frames.md).
//
// A second and a third AF_PACKET socket sit on the two ends of the veth pair:
//  * towards the segment: another tool's frames, as a diagnostic program or a second master on a
//    shared wire would send them: reads of registers that have no read side effects (ESC type and
//    features, station address, DL and AL status) by broadcast, position and station addressing,
//    logical reads of an address no FMMU maps, NOPs, and frames that are not valid EtherCAT
//    (truncated, a frame type other than datagrams, a length field longer than the frame). Every
//    index is random, so the segment's replies to them reach the master with indices it may have
//    in flight. Nothing writes: a frame that writes registers is not noise but a second master,
//    which no master can be expected to survive.
//  * towards the master: frames that look like replies of another segment (random commands,
//    indices, addresses, working counters, 1-3 datagrams), and malformed ones.
// The master must tell all of it apart from its own replies: the ring still reaches OP with every
// slave at its station and process data going round.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstring>
#include <functional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <linux/if_packet.h>
#include <net/ethernet.h>
#include <net/if.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

constexpr wire::MacAddress kRogueMac{0x02, 0x00, 0x00, 0x00, 0x00, 0x66};

// An AF_PACKET socket that only sends, bound to one interface.
class Injector {
 public:
  explicit Injector(const std::string& interface) {
    fd_ = ::socket(AF_PACKET, SOCK_RAW | SOCK_CLOEXEC, htons(ETH_P_ALL));
    if (fd_ < 0) return;
    ifindex_ = static_cast<int>(::if_nametoindex(interface.c_str()));
    if (ifindex_ == 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~Injector() {
    if (fd_ >= 0) ::close(fd_);
  }
  Injector(const Injector&) = delete;
  Injector& operator=(const Injector&) = delete;
  bool ok() const { return fd_ >= 0; }

  // `payload` after an Ethernet header with EtherType 0x88A4 (padded to the minimum size).
  bool send(const std::vector<std::uint8_t>& payload) {
    std::vector<std::uint8_t> frame(std::max<std::size_t>(60, 14 + payload.size()), 0);
    std::memcpy(frame.data(), wire::kBroadcastMac.data(), 6);
    std::memcpy(frame.data() + 6, kRogueMac.data(), 6);
    frame[12] = 0x88;
    frame[13] = 0xA4;
    if (!payload.empty()) std::memcpy(frame.data() + 14, payload.data(), payload.size());
    sockaddr_ll to{};
    to.sll_family = AF_PACKET;
    to.sll_ifindex = ifindex_;
    to.sll_halen = ETH_ALEN;
    std::memset(to.sll_addr, 0xFF, ETH_ALEN);
    const auto n =
        ::sendto(fd_, frame.data(), frame.size(), 0, reinterpret_cast<sockaddr*>(&to), sizeof to);
    if (n == static_cast<ssize_t>(frame.size())) ++sent_;
    return n == static_cast<ssize_t>(frame.size());
  }
  std::uint64_t sent() const { return sent_; }

 private:
  int fd_ = -1;
  int ifindex_ = 0;
  std::uint64_t sent_ = 0;
};

using Rng = std::mt19937;

std::uint8_t byte(Rng& rng) {
  return static_cast<std::uint8_t>(rng() & 0xFF);
}

std::vector<std::uint8_t> encode(const std::vector<wire::DatagramHeader>& datagrams,
                                 const std::vector<std::uint16_t>& wkcs = {}) {
  std::vector<std::uint8_t> buffer(1500);
  wire::FrameBuilder builder(buffer);
  for (std::size_t i = 0; i < datagrams.size(); ++i) {
    (void)builder.add(datagrams[i], {}, i < wkcs.size() ? wkcs[i] : 0);
  }
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

// A read of a register without read side effects: what a monitoring tool polls.
wire::DatagramHeader harmless_read(Rng& rng) {
  struct Register {
    std::uint16_t address;
    std::uint16_t length;
  };
  constexpr std::array<Register, 5> kRegisters{{
      {0x0000, 10},  // type, revision, build, FMMUs, SMs, RAM, ports, features
      {wire::reg::kStationAddress, 2},
      {0x0110, 2},  // DL status
      {wire::reg::kAlStatus, 2},
      {wire::reg::kAlStatus, 6},  // AL status + status code
  }};
  const auto& r = kRegisters[rng() % kRegisters.size()];
  wire::DatagramHeader h;
  h.index = byte(rng);
  h.length = r.length;
  switch (rng() % 5) {
    case 0:
    case 1:
      h.command = wire::Command::brd;
      h.address = static_cast<std::uint32_t>(r.address) << 16;
      break;
    case 2: {
      h.command = wire::Command::aprd;
      const auto position = static_cast<std::uint16_t>(rng() % 4);
      h.address = wire::position_adp(position) | (static_cast<std::uint32_t>(r.address) << 16);
      if (position == 0) h.address = static_cast<std::uint32_t>(r.address) << 16;
      break;
    }
    case 3: {
      h.command = wire::Command::fprd;
      // The master's stations and some that nobody has.
      const auto station = static_cast<std::uint16_t>(rng() % 2 ? 0x1000 + rng() % 3 : rng());
      h.address = station | (static_cast<std::uint32_t>(r.address) << 16);
      break;
    }
    default:
      // A logical read far above every domain's window: no FMMU maps it.
      h.command = wire::Command::lrd;
      h.address = 0x40000000u + (rng() & 0xFFFF);
      h.length = static_cast<std::uint16_t>(1 + rng() % 8);
      break;
  }
  return h;
}

// Towards the segment: mostly harmless reads and NOPs, sometimes a malformed frame.
std::vector<std::uint8_t> foreign_request(Rng& rng) {
  switch (rng() % 8) {
    case 0: {  // a NOP with a random address and length
      wire::DatagramHeader h;
      h.command = wire::Command::nop;
      h.index = byte(rng);
      h.address = static_cast<std::uint32_t>(rng());
      h.length = static_cast<std::uint16_t>(rng() % 32);
      return encode({h});
    }
    case 1: {  // truncated: the datagram header is cut short
      auto f = encode({harmless_read(rng)});
      f.resize(2 + 1 + rng() % 8);
      return f;
    }
    case 2: {  // a frame type other than datagrams
      auto f = encode({harmless_read(rng)});
      f[1] = static_cast<std::uint8_t>((f[1] & 0x0F) |
                                       (static_cast<std::uint8_t>(2 + rng() % 13) << 4));
      return f;
    }
    case 3: {  // the length field claims more than the frame holds
      auto f = encode({harmless_read(rng)});
      f[0] = 0xFF;
      f[1] = static_cast<std::uint8_t>((f[1] & 0xF0) | 0x07);
      return f;
    }
    default: {  // one to three harmless reads
      std::vector<wire::DatagramHeader> ds;
      const auto n = 1 + rng() % 3;
      for (unsigned i = 0; i < n; ++i)
        ds.push_back(harmless_read(rng));
      return encode(ds);
    }
  }
}

// Towards the master: what another segment's replies look like, any command, random contents.
std::vector<std::uint8_t> foreign_reply(Rng& rng) {
  constexpr std::array<wire::Command, 12> kCommands{
      wire::Command::aprd, wire::Command::apwr, wire::Command::fprd, wire::Command::fpwr,
      wire::Command::brd,  wire::Command::bwr,  wire::Command::lrd,  wire::Command::lwr,
      wire::Command::lrw,  wire::Command::armw, wire::Command::fprw, wire::Command::nop};
  if (rng() % 6 == 0) {
    auto f = foreign_request(rng);
    if (f.size() > 3) f.resize(f.size() - 1 - rng() % 3);  // cut mid-datagram
    return f;
  }
  std::vector<wire::DatagramHeader> ds;
  std::vector<std::uint16_t> wkcs;
  const auto n = 1 + rng() % 3;
  for (unsigned i = 0; i < n; ++i) {
    wire::DatagramHeader h;
    h.command = kCommands[rng() % kCommands.size()];
    h.index = byte(rng);
    h.address = static_cast<std::uint32_t>(rng());
    h.length = static_cast<std::uint16_t>(rng() % 48);
    ds.push_back(h);
    wkcs.push_back(static_cast<std::uint16_t>(rng() % 4));
  }
  return encode(ds, wkcs);
}

TEST(RogueFrames, RingReachesOperationalDespiteForeignFramesDuringStartup) {
  const auto seed = static_cast<unsigned>(
      std::chrono::steady_clock::now().time_since_epoch().count() & 0x7FFFFFFF);
  SCOPED_TRACE(fmt::format("seed {}", seed));
  std::unique_ptr<Injector> to_segment;
  std::unique_ptr<Injector> to_master;
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> injected{0};
  std::thread noise;
  auto stop_noise = [&] {
    stop = true;
    if (noise.joinable()) noise.join();
  };
  // Whatever way the test leaves, the noise stops before the sockets close.
  struct Joiner {
    std::function<void()> f;
    ~Joiner() { f(); }
  } joiner{stop_noise};

  RingSpec spec;
  spec.transport = Transport::raw;
  // The sockets are opened in the test's network namespace before the master starts, so that
  // the noise covers discovery, station assignment, SII reads and the AL walk.
  spec.before_start = [&] {
    to_segment = std::make_unique<Injector>("master");
    to_master = std::make_unique<Injector>("segment");
    if (!to_segment->ok() || !to_master->ok()) return;
    noise = std::thread([&, seed] {
      Rng rng(seed);
      // A few malformed frames first, whatever the random draw does later: on a loaded machine
      // the noise may get few turns before the ring is up, and the segment must have seen some.
      // And one every few turns: frames sent before the kernel has activated the new veth
      // pair's queues (its link watch runs late on a loaded machine) can be dropped unseen.
      auto malformed = [&] {
        auto f = encode({harmless_read(rng)});
        f[0] = 0xFF;  // the length field claims more than the frame holds
        f[1] = static_cast<std::uint8_t>((f[1] & 0xF0) | 0x07);
        (void)to_segment->send(f);
        ++injected;
      };
      for (int i = 0; i < 3; ++i)
        malformed();
      for (std::uint64_t turn = 1; !stop; ++turn) {
        (void)to_segment->send(foreign_request(rng));
        (void)to_master->send(foreign_reply(rng));
        injected += 2;
        if (turn % 8 == 0) malformed();
        std::this_thread::sleep_for(std::chrono::microseconds(300 + rng() % 700));
      }
    });
  };
  std::string skip;
  auto ring = ScenarioRing::create(spec, &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  ASSERT_TRUE(to_segment && to_segment->ok() && to_master && to_master->ok())
      << "cannot open the injecting sockets: " << std::strerror(errno);

  auto op = ring->master->await_operational(10s);
  stop_noise();
  ASSERT_TRUE(op) << op.error().describe() << "; " << ring->describe();
  EXPECT_GT(injected.load(), 20u) << "too little noise to mean anything";

  // Every slave in OP at the station the master gave it; process data goes round.
  EXPECT_TRUE(ring->all_slaves_in(SlaveState::op)) << ring->describe();
  EXPECT_FALSE(ring->any_slave_fault()) << ring->describe();
  const auto sim = ring->server->status();
  ASSERT_EQ(sim.slaves.size(), 3u);
  for (std::size_t i = 0; i < sim.slaves.size(); ++i) {
    EXPECT_EQ(sim.slaves[i].station, 0x1000 + i) << sim.slaves[i].name;
    EXPECT_EQ(sim.slaves[i].al_state, wire::AlState::op) << sim.slaves[i].name;
    EXPECT_FALSE(sim.slaves[i].al_error) << sim.slaves[i].name;
  }
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);

  // The noise did reach both ends: the segment answered (or ignored) the foreign requests, and
  // the master threw away replies that were not its own.
  EXPECT_GT(sim.counters.malformed, 0u);
  const auto bus = ring->master->bus()->stats();
  EXPECT_GT(bus.unmatched_replies + bus.mismatched_replies + bus.decode_errors, 0u);
}

}  // namespace
}  // namespace ecat::scenarios
