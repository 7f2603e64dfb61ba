// Proves the realtime path through a redundant link allocates nothing, on a whole ring (the reply
// crosses, the secondary's copy is dropped) and on a broken one (two bounces merged byte by byte).
//
// Each "side" of the ring is a FakeSegment with some of the slaves; a StampedLink gives the frames
// coming back the Ethernet source a real ring gives them (the requester's address), without
// allocating. Global operator new is replaced by a counting one (support/counting_allocator.hpp).

#include <array>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/redundant_link.hpp>

#include "bus/bus_test_support.hpp"
#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::bus::test {
namespace {

constexpr wire::MacAddress kPrimaryMac{0x02, 0x00, 0x00, 0x00, 0x00, 0x01};
constexpr wire::MacAddress kSecondaryMac{0x02, 0x00, 0x00, 0x00, 0x00, 0x02};

// A link whose replies carry a fixed Ethernet source.
class StampedLink final : public link::ForwardingLink {
 public:
  StampedLink(std::unique_ptr<link::Link> inner, wire::MacAddress source)
      : ForwardingLink(std::move(inner)), source_(source) {}
  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    auto received = ForwardingLink::receive(timeout);
    if (received && *received) (*received)->source = source_;
    return received;
  }

 private:
  wire::MacAddress source_;
};

int run_cycles(Bus& bus, RealtimeTransaction& rt, int cycles, bool count) {
  int bad = 0;
  allocs::count_this_thread = count;
  for (int i = 0; i < cycles; ++i) {
    auto out = rt.output(0);
    out[0] = static_cast<std::uint8_t>(i);
    if (!bus.submit_realtime(rt, std::chrono::seconds(1))) {
      ++bad;
      continue;
    }
    rt.wait();
    const auto in = rt.input(0);
    if (rt.status() != RealtimeStatus::ok || rt.wkc(0) != 3 || in[2] != 0xC1) ++bad;
  }
  allocs::count_this_thread = false;
  return bad;
}

// A broken ring: slave 0 (outputs) behind the primary, slave 1 (inputs) behind the secondary;
// both replies bounce and are merged.
TEST(RedundantAllocations, MergedBouncesAllocateNothing) {
  FakeSegment::Options seg;
  seg.record = false;
  seg.slaves = 1;
  auto primary_side = make_segment(seg);
  primary_side->map_logical(0, {0x00010000, 0x1000, 2, false, true});
  seg.first_station = 0x1002;
  auto secondary_side = make_segment(seg);
  secondary_side->map_logical(0, {0x00010002, 0x1100, 2, true, false});
  const std::array<std::uint8_t, 2> inputs{0xC1, 0xC2};
  secondary_side->write(0, 0x1100, inputs);

  link::RedundantLinkOptions redundant;
  redundant.primary_mac = kPrimaryMac;
  redundant.secondary_mac = kSecondaryMac;
  auto link = link::RedundantLink::open(
      std::make_unique<StampedLink>(FakeSegment::make_link(primary_side), kPrimaryMac),
      std::make_unique<StampedLink>(FakeSegment::make_link(secondary_side), kSecondaryMac),
      redundant);
  ASSERT_TRUE(link) << link.error().describe();
  auto* redundant_link = link->get();
  BusOptions options;
  options.frame_timeout = std::chrono::seconds(1);
  options.on_thread_start = [] { allocs::is_bus_thread = true; };
  Bus bus(std::move(*link), options);
  ASSERT_TRUE(bus.start());

  Transaction layout;
  const std::array<std::uint8_t, 4> image{};
  layout.lrw(0x00010000, image, 3);
  RealtimeTransaction rt(std::move(layout));

  allocs::counted.store(0);
  allocs::bus_thread.store(0);
  int warmup = 0;
  int counted = 0;
  std::thread realtime([&] {
    warmup = run_cycles(bus, rt, 100, false);
    allocs::count_bus_thread.store(true);
    counted = run_cycles(bus, rt, 2000, true);
    allocs::count_bus_thread.store(false);
  });
  realtime.join();
  EXPECT_EQ(warmup, 0);
  EXPECT_EQ(counted, 0);
  EXPECT_EQ(allocs::counted.load(), 0u);
  EXPECT_EQ(allocs::bus_thread.load(), 0u);
  const auto status = redundant_link->status();
  EXPECT_EQ(status.merged, 2100u);
  EXPECT_EQ(status.ring, link::RingState::broken);
  bus.stop();
}

}  // namespace
}  // namespace ecat::bus::test
