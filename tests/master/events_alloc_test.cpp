// Publishing an event allocates nothing, so the cycle thread can publish (domain health, DC
// lock) without ever reaching the allocator: proven with the counting allocator, subscribers
// attached (callback and pull queue), the detail formatted in place.
#include <chrono>

#include <gtest/gtest.h>

#include "master/event_hub.hpp"
#include "support/counting_allocator.hpp"

namespace ecat::master {
namespace {

namespace allocs = ecat::test::allocations;
using namespace std::chrono_literals;

TEST(EventAllocations, PublishingAllocatesNothing) {
  EventHub hub(256);
  std::uint64_t seen = 0;
  hub.subscribe([&](const Event&, std::uint64_t) { ++seen; });
  auto queue = hub.open_queue(512);
  // Warm-up: the dispatcher's own first allocations are not the publisher's.
  ASSERT_TRUE(hub.publish(make_event(EventKind::recovery_step)));
  ASSERT_TRUE(hub.flush(5s));

  allocs::counted = 0;
  allocs::count_this_thread = true;
  for (int i = 0; i < 200; ++i) {
    Event e = make_event(EventKind::domain_health, "main");
    e.to = static_cast<std::uint8_t>(i % 2);
    format_detail(e, "timeout (expected wkc {}, got {})", 7, i);
    (void)hub.publish(e);
  }
  allocs::count_this_thread = false;
  EXPECT_EQ(allocs::counted.load(), 0u) << "publishing an event allocated";
  ASSERT_TRUE(hub.flush(5s));
  EXPECT_EQ(hub.stats().published, 201u);
}

}  // namespace
}  // namespace ecat::master
