#include <chrono>
#include <deque>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {
namespace {

using namespace std::chrono_literals;
using ByteVector = std::vector<std::uint8_t>;

constexpr wire::MacAddress kPrimaryMac{0x02, 0x10, 0x00, 0x00, 0x00, 0x01};
constexpr wire::MacAddress kSecondaryMac{0x02, 0x10, 0x00, 0x00, 0x00, 0x02};

// A ring of `slaves` toy slaves between two master ports. Slave i answers LRW/LRD by writing
// 0x80 + i into byte 2 + i and counting 1, BRD by counting 1. Frames are processed in send(), as
// a real ring would: the primary's enters slave 0, the secondary's enters the last slave and,
// travelling backwards, is processed only after it turned round at a break.
struct ToyRing {
  enum class Shape { whole, break_after, primary_cut, secondary_cut };
  std::size_t slaves = 4;
  Shape shape = Shape::whole;
  std::size_t break_after = 0;
  std::array<std::deque<std::pair<ByteVector, wire::MacAddress>>, 2> queues;  // arriving per port
  std::array<bool, 2> send_fails{};
  std::array<bool, 2> held{};  // a port's arrivals held back (a late side)

  void process(ByteVector& frame, std::size_t first, std::size_t last) {
    if (first >= last) return;
    auto decoded = wire::decode_frame(frame);
    ASSERT_TRUE(decoded);
    for (const auto d : *decoded.frame) {
      auto* data = const_cast<std::uint8_t*>(d.data.data());
      std::uint16_t wkc = d.wkc;
      for (std::size_t i = first; i < last; ++i) {
        if (d.header.command == wire::Command::lrw || d.header.command == wire::Command::lrd) {
          if (2 + i < d.data.size()) data[2 + i] = static_cast<std::uint8_t>(0x80 + i);
          ++wkc;
        } else if (d.header.command == wire::Command::brd) {
          ++wkc;
        }
      }
      wire::store_le16(data + d.data.size(), wkc);
    }
  }

  std::array<std::vector<ByteVector>, 2> sent_by;  // what each port sent, in order

  void on_send(std::size_t port, wire::Bytes sent) {
    ByteVector frame(sent.begin(), sent.end());
    sent_by[port].push_back(frame);
    wire::MacAddress source = port == 0 ? kPrimaryMac : kSecondaryMac;
    source[0] |= 0x02;
    switch (shape) {
      case Shape::whole:
        if (port == 0) process(frame, 0, slaves);
        queues[1 - port].emplace_back(frame, source);  // cross
        break;
      case Shape::break_after:
        if (port == 0) {
          process(frame, 0, break_after);
        } else {
          process(frame, break_after, slaves);
        }
        queues[port].emplace_back(frame, source);  // bounce
        break;
      case Shape::primary_cut:
      case Shape::secondary_cut: {
        const std::size_t cut = shape == Shape::primary_cut ? 0 : 1;
        if (port == cut) return;  // lost on the cut cable
        process(frame, 0, slaves);
        queues[port].emplace_back(frame, source);
        break;
      }
    }
  }
};

class ToyPort final : public Link {
 public:
  ToyPort(ToyRing& ring, std::size_t port) : ring_(ring), port_(port) {}
  Result<void> send(wire::Bytes frame) override {
    if (ring_.send_fails[port_]) {
      ++stats_.send_errors;
      return Error(Errc::io_error, "cable pulled");
    }
    ++stats_.frames_sent;
    ring_.on_send(port_, frame);
    return {};
  }
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds) override {
    auto& q = ring_.queues[port_];
    if (q.empty() || ring_.held[port_]) return std::optional<ReceivedFrame>{};
    held_ = std::move(q.front().first);
    const auto source = q.front().second;
    q.pop_front();
    ++stats_.frames_received;
    return std::optional<ReceivedFrame>(ReceivedFrame{held_, 0, source});
  }
  void interrupt() override {}
  void close() override {}
  std::string name() const override { return port_ == 0 ? "toy0" : "toy1"; }
  LinkStats stats() const override { return stats_; }

 private:
  ToyRing& ring_;
  std::size_t port_;
  ByteVector held_;
  LinkStats stats_;
};

ByteVector lrw_frame(std::uint8_t index, std::size_t length = 8) {
  ByteVector buffer(wire::kMaxFrameSize);
  wire::FrameBuilder builder(buffer);
  ByteVector data(length, 0);
  data[0] = 0x5A;
  EXPECT_TRUE(builder.add(
      {wire::Command::lrw, index, 0x00010000, static_cast<std::uint16_t>(length), false, false, 0},
      data));
  EXPECT_TRUE(builder.add(
      {wire::Command::brd, static_cast<std::uint8_t>(index + 1), 0, 2, false, false, 0}));
  const auto f = builder.finish();
  return ByteVector(f.begin(), f.end());
}

struct Reply {
  ByteVector data;
  std::uint16_t lrw_wkc = 0;
  std::uint16_t brd_wkc = 0;
};

std::optional<Reply> exchange(RedundantLink& link, std::uint8_t index) {
  const auto frame = lrw_frame(index);
  EXPECT_TRUE(link.send(frame));
  auto received = link.receive(5ms);
  EXPECT_TRUE(received) << received.error().describe();
  if (!received || !*received) return std::nullopt;
  auto decoded = wire::decode_frame((*received)->frame);
  EXPECT_TRUE(decoded);
  Reply r;
  auto it = decoded.frame->begin();
  const auto lrw = *it++;
  const auto brd = *it;
  r.data.assign(lrw.data.begin(), lrw.data.end());
  r.lrw_wkc = lrw.wkc;
  r.brd_wkc = brd.wkc;
  return r;
}

const ByteVector kWhole{0x5A, 0x00, 0x80, 0x81, 0x82, 0x83, 0x00, 0x00};

struct Fixture {
  ToyRing ring;
  std::unique_ptr<RedundantLink> link;
  explicit Fixture(std::chrono::nanoseconds window = 500us) {
    RedundantLinkOptions options;
    options.primary_mac = kPrimaryMac;
    options.secondary_mac = kSecondaryMac;
    options.merge_window = window;
    auto opened = RedundantLink::open(std::make_unique<ToyPort>(ring, 0),
                                      std::make_unique<ToyPort>(ring, 1), options);
    EXPECT_TRUE(opened) << opened.error().describe();
    link = std::move(*opened);
  }
};

TEST(RedundantLink, WholeRingForwardCrossAndPassthroughDropped) {
  Fixture f;
  const auto r = exchange(*f.link, 0x10);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->data, kWhole);
  EXPECT_EQ(r->lrw_wkc, 4);
  EXPECT_EQ(r->brd_wkc, 4);
  // The secondary's untouched copy came round too, and nothing else is handed on.
  auto more = f.link->receive(0ns);
  ASSERT_TRUE(more);
  EXPECT_FALSE(*more);
  const auto status = f.link->status();
  EXPECT_EQ(status.topology, RedundancyTopology::redundant);
  EXPECT_EQ(status.ring, RingState::whole);
  EXPECT_EQ(status.forward_crosses, 1u);
  EXPECT_EQ(status.passthrough_copies, 1u);
  EXPECT_EQ(status.primary.frames_sent, 1u);
  EXPECT_EQ(status.secondary.frames_sent, 1u);
  EXPECT_EQ(f.link->name(), "redundant:toy0,toy1");
  EXPECT_EQ(f.link->stats().frames_received, 1u);
}

TEST(RedundantLink, BreakAnywhereGivesTheWholeRingsReply) {
  for (std::size_t at = 1; at < 4; ++at) {
    Fixture f;
    ASSERT_TRUE(exchange(*f.link, 0x20));
    f.ring.shape = ToyRing::Shape::break_after;
    f.ring.break_after = at;
    const auto r = exchange(*f.link, 0x22);
    ASSERT_TRUE(r) << at;
    EXPECT_EQ(r->data, kWhole) << at;
    EXPECT_EQ(r->lrw_wkc, 4) << at;
    EXPECT_EQ(r->brd_wkc, 4) << at;
    const auto status = f.link->status();
    EXPECT_EQ(status.ring, RingState::broken);
    EXPECT_EQ(status.merged, 1u);
    EXPECT_EQ(status.ring_breaks, 1u);
    // Healing: a forward cross again.
    f.ring.shape = ToyRing::Shape::whole;
    const auto healed = exchange(*f.link, 0x24);
    ASSERT_TRUE(healed);
    EXPECT_EQ(healed->lrw_wkc, 4);
    EXPECT_EQ(f.link->status().ring, RingState::whole);
    EXPECT_EQ(f.link->status().ring_heals, 1u);
  }
}

// Per-port frame contents: the datagrams a port's selector matches go out on that port as NOPs
// (the other port's copy unchanged), and the reply is still the frame that was sent, with only the
// other side's part of those datagrams.
TEST(RedundantLink, APortsNopCopyLeavesThoseDatagramsToTheOtherSide) {
  Fixture f;
  const std::uint8_t brd = static_cast<std::uint8_t>(wire::Command::brd);
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::dc_time, DatagramSelector{brd, 0, 0}));
  const auto command_of = [](const ByteVector& frame, std::size_t datagram) {
    auto decoded = wire::decode_frame(frame);
    auto it = decoded.frame->begin();
    for (std::size_t k = 0; k < datagram; ++k)
      ++it;
    return (*it).header.command;
  };
  // Whole: the secondary's copy (a passthrough) carries the BRD as a NOP; the reply is the
  // primary's forward cross.
  auto r = exchange(*f.link, 0x50);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->brd_wkc, 4);
  EXPECT_EQ(command_of(f.ring.sent_by[0].back(), 1), wire::Command::brd);
  EXPECT_EQ(command_of(f.ring.sent_by[1].back(), 1), wire::Command::nop);
  EXPECT_EQ(command_of(f.ring.sent_by[1].back(), 0), wire::Command::lrw);
  EXPECT_EQ(f.link->status().passthrough_copies, 1u);
  // Broken after slave 1: the BRD counts the primary's side only, the LRW both; the reply has
  // the request's commands.
  f.ring.shape = ToyRing::Shape::break_after;
  f.ring.break_after = 1;
  r = exchange(*f.link, 0x52);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->brd_wkc, 1);
  EXPECT_EQ(r->lrw_wkc, 4);
  EXPECT_EQ(r->data, kWhole);
  EXPECT_EQ(f.link->status().merged, 1u);
  EXPECT_EQ(f.link->status().stale, 0u);
  // Every LRW (any address) a NOP on the primary's copy: only the secondary's side maps.
  ASSERT_TRUE(f.link->set_port_nop(
      Port::primary, NopSlot::dc_time,
      DatagramSelector{static_cast<std::uint8_t>(wire::Command::lrw), 0, 1, true}));
  r = exchange(*f.link, 0x54);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->lrw_wkc, 3);
  EXPECT_EQ(r->brd_wkc, 1);
  EXPECT_EQ(r->data, (ByteVector{0x5A, 0x00, 0x00, 0x81, 0x82, 0x83, 0x00, 0x00}));
  // Ended: both sides again.
  ASSERT_TRUE(f.link->set_port_nop(Port::primary, NopSlot::dc_time, std::nullopt));
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::dc_time, std::nullopt));
  r = exchange(*f.link, 0x56);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->lrw_wkc, 4);
  EXPECT_EQ(r->brd_wkc, 4);
  EXPECT_EQ(command_of(f.ring.sent_by[1].back(), 1), wire::Command::brd);
  // A link with one port has no per-port contents.
  auto [one, other_end] = make_memory_link_pair();
  auto refused = one->set_port_nop(Port::secondary, NopSlot::dc_time, DatagramSelector{brd, 0, 0});
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::unsupported);
}

// Each user has a slot of its own: two selectors on one port both apply, and ending one leaves
// the other in place (the DC runtime's FRMW and a position-addressed access side by side).
TEST(RedundantLink, APortsSelectorSlotsApplyTogetherAndEndApart) {
  Fixture f;
  f.ring.shape = ToyRing::Shape::break_after;
  f.ring.break_after = 1;
  const std::uint8_t brd = static_cast<std::uint8_t>(wire::Command::brd);
  const std::uint8_t lrw = static_cast<std::uint8_t>(wire::Command::lrw);
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::dc_time, DatagramSelector{brd, 0, 0}));
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::addressing,
                                   DatagramSelector{lrw, 0, 1, true}));
  // Both datagrams are NOPs in the secondary's copy: only the primary's side (slave 0) counts.
  auto r = exchange(*f.link, 0x60);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->brd_wkc, 1);
  EXPECT_EQ(r->lrw_wkc, 1);
  EXPECT_EQ(r->data, (ByteVector{0x5A, 0x00, 0x80, 0x00, 0x00, 0x00, 0x00, 0x00}));
  // The addressing slot ended: the LRW reaches both sides again, the BRD still one.
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::addressing, std::nullopt));
  r = exchange(*f.link, 0x62);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->brd_wkc, 1);
  EXPECT_EQ(r->lrw_wkc, 4);
  EXPECT_EQ(r->data, kWhole);
  ASSERT_TRUE(f.link->set_port_nop(Port::secondary, NopSlot::dc_time, std::nullopt));
  r = exchange(*f.link, 0x64);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->brd_wkc, 4);
  // A slot the link does not have is refused.
  auto refused = f.link->set_port_nop(Port::primary, static_cast<NopSlot>(kNopSlots), std::nullopt);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::invalid_argument);
}

// On a loaded host one side's bounce may come back well after the merge window: with a frame
// budget the lone bounce waits until half of it after the send, and the late side is merged.
TEST(RedundantLink, ALateSideIsMergedWithinHalfTheFrameBudget) {
  Fixture f;  // merge window 500 us
  f.link->set_frame_budget(200ms);
  f.ring.shape = ToyRing::Shape::break_after;
  f.ring.break_after = 1;
  f.ring.held[1] = true;
  ASSERT_TRUE(f.link->send(lrw_frame(0x70)));
  // Well past the merge window: the primary's bounce still waits for the secondary's.
  auto early = f.link->receive(20ms);
  ASSERT_TRUE(early);
  EXPECT_FALSE(*early);
  f.ring.held[1] = false;
  auto late = f.link->receive(5ms);
  ASSERT_TRUE(late);
  ASSERT_TRUE(*late);
  auto decoded = wire::decode_frame((*late)->frame);
  ASSERT_TRUE(decoded);
  EXPECT_EQ((*decoded.frame->begin()).wkc, 4);
  EXPECT_EQ(f.link->status().merged, 1u);
  EXPECT_EQ(f.link->status().merge_timeouts, 0u);
  // A side that never answers: the lone bounce is handed over by half the budget.
  f.ring.held[1] = true;
  const auto sent = std::chrono::steady_clock::now();
  ASSERT_TRUE(f.link->send(lrw_frame(0x72)));
  auto lone = f.link->receive(1s);
  ASSERT_TRUE(lone);
  ASSERT_TRUE(*lone);
  EXPECT_LT(std::chrono::steady_clock::now() - sent, 200ms);
  EXPECT_EQ(f.link->status().merge_timeouts, 1u);
}

// The patience (half the frame budget) runs from the oldest frame a side owes, not from each
// frame: a side stalled across several frames (a descheduled thread) is waited for and merged for
// each; one that stops answering delays the frames in flight together, once, and later frames
// are handed on at once until it answers again.
TEST(RedundantLink, ASideOwingFramesIsWaitedForFromTheOldestOnce) {
  Fixture f;                        // merge window 500 us
  f.link->set_frame_budget(200ms);  // patience 100 ms
  f.ring.shape = ToyRing::Shape::break_after;
  f.ring.break_after = 1;
  const auto lrw_wkc = [](const std::optional<ReceivedFrame>& r) {
    auto decoded = wire::decode_frame(r->frame);
    EXPECT_TRUE(decoded);
    return decoded ? (*decoded.frame->begin()).wkc : std::uint16_t{0};
  };
  // Stalled past the merge window for two frames, then answering: both merged.
  f.ring.held[1] = true;
  ASSERT_TRUE(f.link->send(lrw_frame(0x80)));
  auto none = f.link->receive(5ms);
  ASSERT_TRUE(none);
  EXPECT_FALSE(*none);
  ASSERT_TRUE(f.link->send(lrw_frame(0x82)));
  none = f.link->receive(5ms);
  ASSERT_TRUE(none);
  EXPECT_FALSE(*none);
  f.ring.held[1] = false;
  for (int i = 0; i < 2; ++i) {
    auto r = f.link->receive(50ms);
    ASSERT_TRUE(r);
    ASSERT_TRUE(*r);
    EXPECT_EQ(lrw_wkc(*r), 4);
  }
  EXPECT_EQ(f.link->status().merged, 2u);
  EXPECT_EQ(f.link->status().merge_timeouts, 0u);

  // Gone for good: a frame sent well after the first still owed is handed on with it, by the
  // first's patience, not 60 ms after it.
  f.ring.held[1] = true;
  ASSERT_TRUE(f.link->send(lrw_frame(0x84)));
  none = f.link->receive(60ms);
  ASSERT_TRUE(none);
  EXPECT_FALSE(*none);
  ASSERT_TRUE(f.link->send(lrw_frame(0x86)));
  auto first = f.link->receive(1s);
  ASSERT_TRUE(first);
  ASSERT_TRUE(*first);
  EXPECT_EQ(lrw_wkc(*first), 1);  // the primary's side alone
  const auto first_at = std::chrono::steady_clock::now();
  auto second = f.link->receive(1s);
  ASSERT_TRUE(second);
  ASSERT_TRUE(*second);
  EXPECT_LT(std::chrono::steady_clock::now() - first_at, 40ms);
  EXPECT_EQ(f.link->status().merge_timeouts, 2u);
  // Later frames: at once, no window.
  ASSERT_TRUE(f.link->send(lrw_frame(0x88)));
  auto third = f.link->receive(0ns);
  ASSERT_TRUE(third);
  ASSERT_TRUE(*third);
  EXPECT_EQ(f.link->status().merge_timeouts, 2u);
  EXPECT_EQ(f.link->status().lone_bounces, 3u);
  // Answering again (the held halves arrive late and are no second reply): waited for again.
  f.ring.held[1] = false;
  auto late = f.link->receive(5ms);
  ASSERT_TRUE(late);
  EXPECT_FALSE(*late);
  const auto r = exchange(*f.link, 0x8A);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->lrw_wkc, 4);
  EXPECT_EQ(f.link->status().merged, 3u);
}

// A ring broken after slave 0: `frame` as each side returns it, built by hand (the primary's
// side is slave 0, the secondary's slaves 1..3), with the sources the ESCs give them.
std::pair<ByteVector, ByteVector> bounces_of(const ByteVector& frame) {
  ToyRing ring;
  ByteVector primary = frame;
  ByteVector secondary = frame;
  ring.process(primary, 0, 1);
  ring.process(secondary, 1, 4);
  return {primary, secondary};
}

wire::MacAddress forwarded(wire::MacAddress mac) {
  mac[0] |= 0x02;
  return mac;
}

// The late half of an exchange answered without it finds that exchange by its index, in the
// order its port returns frames, even when a later exchange with the same index (an index
// reused) is waiting: it is counted and dropped, never merged into the later one, which is then
// merged from its own halves.
TEST(RedundantLink, ALateHalfFindsItsOwnExchangeNotTheNextWithTheSameIndex) {
  Fixture f;                        // merge window 500 us
  f.link->set_frame_budget(600ms);  // patience 300 ms; an answered exchange owns halves 600 ms
  const ByteVector a = lrw_frame(0x10);
  ByteVector e = a;  // the next exchange with the same indices, other outputs
  e[wire::kDatagramHeaderSize + 2 + 1] = 0x11;  // the LRW's second data byte
  const auto [a_primary, a_secondary] = bounces_of(a);
  const auto [e_primary, e_secondary] = bounces_of(e);
  const auto lrw = [](const std::optional<ReceivedFrame>& r) {
    auto decoded = wire::decode_frame(r->frame);
    EXPECT_TRUE(decoded);
    const auto d = *decoded.frame->begin();
    return std::make_pair(ByteVector(d.data.begin(), d.data.end()), d.wkc);
  };

  // A: only the secondary's side answers in time; after the patience, its lone bounce.
  ASSERT_TRUE(f.link->send(a));
  f.ring.queues = {};
  f.ring.queues[1].emplace_back(a_secondary, forwarded(kSecondaryMac));
  auto lone = f.link->receive(5s);
  ASSERT_TRUE(lone);
  ASSERT_TRUE(*lone);
  EXPECT_EQ(lrw(*lone).second, 3);
  EXPECT_EQ(f.link->status().merge_timeouts, 1u);

  // E, same index, sent; then A's primary half comes back, late.
  ASSERT_TRUE(f.link->send(e));
  f.ring.queues = {};
  f.ring.queues[0].emplace_back(a_primary, forwarded(kPrimaryMac));
  auto late = f.link->receive(0ns);
  ASSERT_TRUE(late);
  EXPECT_FALSE(*late);
  EXPECT_EQ(f.link->status().late_halves, 1u);
  // E's secondary half: E still waits for its own primary half (A's was not taken for it).
  f.ring.queues[1].emplace_back(e_secondary, forwarded(kSecondaryMac));
  auto waiting = f.link->receive(0ns);
  ASSERT_TRUE(waiting);
  EXPECT_FALSE(*waiting) << "merged with the late half of the previous exchange";
  f.ring.queues[0].emplace_back(e_primary, forwarded(kPrimaryMac));
  auto merged = f.link->receive(5ms);
  ASSERT_TRUE(merged);
  ASSERT_TRUE(*merged);
  const ByteVector e_whole{0x5A, 0x11, 0x80, 0x81, 0x82, 0x83, 0x00, 0x00};
  EXPECT_EQ(lrw(*merged).first, e_whole);
  EXPECT_EQ(lrw(*merged).second, 4);
  const auto status = f.link->status();
  EXPECT_EQ(status.merged, 1u);
  EXPECT_EQ(status.late_halves, 1u);
  EXPECT_EQ(status.merge_timeouts, 1u);
  // A second copy of a half already in is stale, not late.
  f.ring.queues[0].emplace_back(e_primary, forwarded(kPrimaryMac));
  auto duplicate = f.link->receive(0ns);
  ASSERT_TRUE(duplicate);
  EXPECT_FALSE(*duplicate);
  EXPECT_EQ(f.link->status().late_halves, 1u);
  EXPECT_EQ(f.link->status().stale, 1u);
}

TEST(RedundantLink, CableCutAtTheMasterWaitsOnceThenNotAgain) {
  for (auto shape : {ToyRing::Shape::primary_cut, ToyRing::Shape::secondary_cut}) {
    Fixture f(2ms);
    f.ring.shape = shape;
    // The first lone bounce waits out the window (the other side might still answer)...
    const auto start = std::chrono::steady_clock::now();
    const auto first = exchange(*f.link, 0x30);
    ASSERT_TRUE(first);
    EXPECT_EQ(first->data, kWhole);
    EXPECT_EQ(first->lrw_wkc, 4);
    EXPECT_GE(std::chrono::steady_clock::now() - start, 2ms);
    EXPECT_EQ(f.link->status().merge_timeouts, 1u);
    // ...later ones do not: that side has been silent.
    for (std::uint8_t i = 0; i < 5; ++i) {
      const auto r = exchange(*f.link, static_cast<std::uint8_t>(0x40 + 2 * i));
      ASSERT_TRUE(r);
      EXPECT_EQ(r->lrw_wkc, 4);
    }
    EXPECT_EQ(f.link->status().merge_timeouts, 1u);
    EXPECT_EQ(f.link->status().lone_bounces, 6u);
  }
}

TEST(RedundantLink, OneLegFailingToSendDegradesWithoutLosingFrames) {
  Fixture f;
  f.ring.shape = ToyRing::Shape::secondary_cut;
  f.ring.send_fails[1] = true;
  const auto r = exchange(*f.link, 0x50);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->lrw_wkc, 4);
  auto status = f.link->status();
  EXPECT_EQ(status.topology, RedundancyTopology::degraded_secondary_leg);
  EXPECT_FALSE(status.secondary.healthy);
  EXPECT_EQ(status.secondary.send_errors, 1u);
  EXPECT_EQ(status.merge_timeouts, 0u);  // the other leg sent nothing: no waiting
  // The leg comes back at its next successful send.
  f.ring.send_fails[1] = false;
  f.ring.shape = ToyRing::Shape::whole;
  ASSERT_TRUE(exchange(*f.link, 0x52));
  EXPECT_EQ(f.link->status().topology, RedundancyTopology::redundant);
  // Both failing: the send fails, the topology is offline.
  f.ring.send_fails = {true, true};
  auto sent = f.link->send(lrw_frame(0x54));
  ASSERT_FALSE(sent);
  EXPECT_NE(sent.error().describe().find("both ports"), std::string::npos);
  EXPECT_EQ(f.link->status().topology, RedundancyTopology::offline);
  auto received = f.link->receive(0ns);
  EXPECT_FALSE(received);
}

TEST(RedundantLink, StaleAndForeignFramesAreNotHandedOn) {
  Fixture f;
  // A reply to nothing that was sent.
  f.ring.queues[1].emplace_back(lrw_frame(0x77), kPrimaryMac);
  auto r = f.link->receive(0ns);
  ASSERT_TRUE(r);
  EXPECT_FALSE(*r);
  EXPECT_EQ(f.link->status().stale, 1u);
  // A processed frame from an unknown source is handed on as is.
  const auto frame = lrw_frame(0x60);
  ASSERT_TRUE(f.link->send(frame));
  f.ring.queues = {};
  ByteVector processed = frame;
  f.ring.process(processed, 0, 4);
  f.ring.queues[0].emplace_back(processed, wire::MacAddress{0x00, 0x11, 0x22, 0x33, 0x44, 0x55});
  r = f.link->receive(1ms);
  ASSERT_TRUE(r);
  ASSERT_TRUE(*r);
  EXPECT_EQ(f.link->status().unknown_sources, 1u);
}

// A memory link whose arrivals carry the source address a ring's ESCs would give them.
class StampedLink final : public ForwardingLink {
 public:
  StampedLink(std::unique_ptr<Link> inner, wire::MacAddress source)
      : ForwardingLink(std::move(inner)), source_(source) {}
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    auto received = ForwardingLink::receive(timeout);
    if (received && *received) (*received)->source = source_;
    return received;
  }

 private:
  wire::MacAddress source_;
};

// Both ports waited on at once (Link::wait_fd): a reply that comes back only on the secondary
// port, while the primary stays quiet, ends a long receive() as it arrives, and interrupt() ends
// one that waits on both. The bounds are generous: nothing here is timed.
TEST(RedundantLink, AReplyOnTheSecondaryAloneEndsTheWaitOnBothPorts) {
  // Not structured bindings: the ring's thread captures the far ends.
  auto primary_pair = make_memory_link_pair();
  auto secondary_pair = make_memory_link_pair();
  std::unique_ptr<Link> primary = std::move(primary_pair.first);
  std::unique_ptr<Link> primary_ring = std::move(primary_pair.second);
  std::unique_ptr<Link> secondary = std::move(secondary_pair.first);
  std::unique_ptr<Link> secondary_ring = std::move(secondary_pair.second);
  EXPECT_GE(primary->wait_fd(), 0);
  EXPECT_GE(secondary->wait_fd(), 0);
  RedundantLinkOptions options;
  options.primary_mac = kPrimaryMac;
  options.secondary_mac = kSecondaryMac;
  auto opened = RedundantLink::open(
      std::make_unique<StampedLink>(std::move(primary), forwarded(kSecondaryMac)),
      std::make_unique<StampedLink>(std::move(secondary), forwarded(kPrimaryMac)), options);
  ASSERT_TRUE(opened) << opened.error().describe();
  RedundantLink& link = **opened;

  // The ring: the primary's frame crosses it and leaves by the secondary port, a while after
  // the master began to wait; the secondary's copy is lost.
  std::thread ring([&] {
    auto request = primary_ring->receive(10s);
    ASSERT_TRUE(request && *request);
    ByteVector frame((*request)->frame.begin(), (*request)->frame.end());
    std::this_thread::sleep_for(20ms);
    ToyRing toy;
    toy.process(frame, 0, 4);
    ASSERT_TRUE(secondary_ring->send(frame));
  });
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE(link.send(lrw_frame(0x90)));
  auto reply = link.receive(30s);
  const auto waited = std::chrono::steady_clock::now() - start;
  ring.join();
  ASSERT_TRUE(reply) << reply.error().describe();
  ASSERT_TRUE(*reply);
  auto decoded = wire::decode_frame((**reply).frame);
  ASSERT_TRUE(decoded);
  EXPECT_EQ((*decoded.frame->begin()).wkc, 4);
  EXPECT_LT(waited, 10s);
  EXPECT_EQ(link.status().forward_crosses, 1u);
  EXPECT_EQ(link.status().ring, RingState::whole);

  // Nothing comes: interrupt() ends the wait on both ports.
  std::thread waker([&] {
    std::this_thread::sleep_for(20ms);
    link.interrupt();
  });
  const auto idle_start = std::chrono::steady_clock::now();
  auto idle = link.receive(30s);
  waker.join();
  ASSERT_TRUE(idle);
  EXPECT_FALSE(*idle);
  EXPECT_LT(std::chrono::steady_clock::now() - idle_start, 10s);
  // A close from another thread ends it too.
  std::thread closer([&] {
    std::this_thread::sleep_for(20ms);
    link.close();
  });
  auto closed = link.receive(30s);
  closer.join();
  EXPECT_FALSE(closed && *closed);
}

TEST(RedundantLink, RefusesUdpAndIndistinguishablePorts) {
  auto [a, b] = make_memory_link_pair();
  auto [c, d] = make_memory_link_pair();
  RedundantLinkOptions same;
  same.primary_mac = kPrimaryMac;
  same.secondary_mac = kPrimaryMac;
  same.secondary_mac[0] ^= 0x02;
  auto r = RedundantLink::open(std::move(a), std::move(c), same);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  RedundantLinkOptions ok;
  ok.primary_mac = kPrimaryMac;
  ok.secondary_mac = kSecondaryMac;
  EXPECT_FALSE(RedundantLink::open(nullptr, std::move(d), ok));
  auto udp = UdpLink::connect("127.0.0.1", 34980);
  if (!udp) GTEST_SKIP() << udp.error().describe();
  auto refused = RedundantLink::open(std::move(*udp), std::move(b), ok);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::unsupported);
  EXPECT_NE(refused.error().message().find("UDP"), std::string::npos);
}

TEST(RedundantLink, ClosedLinkRefuses) {
  Fixture f;
  f.link->close();
  EXPECT_EQ(f.link->send(lrw_frame(1)).error().code(), Errc::closed);
  EXPECT_EQ(f.link->receive(0ns).error().code(), Errc::closed);
  EXPECT_EQ(f.link->reopen().error().code(), Errc::closed);
}

}  // namespace
}  // namespace ecat::link
