// Faults on a redundant segment (sim::RedundantPorts, in process): the exchange and reply faults
// on the replies of the two master ports (all of them, or those arriving at a named port), the
// link faults turning the ring round where a port loses its link, hot-connect plugs composed with
// the ring's cabling, and the routes over several cables down. The frames are BRDs of register
// 0x0000 sent on both ports as a redundant master does: the working counter is the number of
// slaves that processed a copy.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <ecat/link/link.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::sim {
namespace {

using namespace std::chrono_literals;
using wire::RedundantPort;

constexpr const char* kBasic = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
)";

// The basic ring with a hot-connect group `tool` (one slave) at its end.
constexpr const char* kWithTool = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: tool, profile: EL2809, hot_connect: {group: tool, plugged: true}}
)";

struct Arrival {
  std::uint8_t index = 0;
  std::uint16_t wkc = 0;
  bool from_primary = false;  // the request's source: the primary's frame or the secondary's
  bool operator==(const Arrival&) const = default;
};

std::ostream& operator<<(std::ostream& out, const Arrival& a) {
  return out << "{index 0x" << std::hex << int(a.index) << std::dec << ", wkc " << a.wkc << ", "
             << (a.from_primary ? "primary's" : "secondary's") << "}";
}

std::unique_ptr<SimServer> server_for(const char* yaml) {
  auto ring = parse_ring(yaml);
  EXPECT_TRUE(ring) << ring.error().describe();
  if (!ring) return nullptr;
  auto server = make_server(*ring);
  EXPECT_TRUE(server) << server.error().describe();
  return server ? std::move(*server) : nullptr;
}

struct RedundantRing {
  std::unique_ptr<SimServer> server;
  std::unique_ptr<RedundantPorts> ports;
  std::unique_ptr<link::Link> primary;
  std::unique_ptr<link::Link> secondary;

  explicit RedundantRing(const char* yaml = kBasic) : RedundantRing(server_for(yaml)) {}
  explicit RedundantRing(std::unique_ptr<SimServer> s) : server(std::move(s)) {
    if (!server) return;
    auto created = RedundantPorts::create(*server);
    EXPECT_TRUE(created) << created.error().describe();
    if (!created) return;
    ports = std::move(*created);
    primary = ports->take_link(RedundantPort::primary);
    secondary = ports->take_link(RedundantPort::secondary);
  }

  // A BRD with datagram index `index`, sent on both ports (the primary first).
  void send(std::uint8_t index) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    wire::DatagramHeader header;
    header.command = wire::Command::brd;
    header.index = index;
    header.address = 0;
    header.length = 1;
    const std::array<std::uint8_t, 1> data{};
    ASSERT_TRUE(builder.add(header, data).has_value());
    const auto frame = builder.finish();
    ASSERT_TRUE(primary->send(frame));
    ASSERT_TRUE(secondary->send(frame));
  }

  // What arrives at `port`, in order, waiting at most `wait` for the first.
  std::vector<Arrival> take(RedundantPort port, std::chrono::nanoseconds wait = 0ns) {
    link::Link& l = port == RedundantPort::primary ? *primary : *secondary;
    std::vector<Arrival> out;
    for (;;) {
      auto received = l.receive(out.empty() ? wait : 0ns);
      EXPECT_TRUE(received);
      if (!received || !*received) return out;
      const auto decoded = wire::decode_frame((*received)->frame);
      EXPECT_TRUE(decoded) << decoded.error.describe();
      if (!decoded) return out;
      const wire::DatagramView d = *decoded.frame->begin();
      out.push_back(Arrival{d.header.index, d.wkc, (*received)->source[5] == 0x01});
    }
  }

  std::string ring_text() { return server->fault_info().ring; }
};

Arrival processed(std::uint8_t index, std::uint16_t wkc, bool from_primary) {
  return Arrival{index, wkc, from_primary};
}
// The secondary's copy, through a whole ring unprocessed.
Arrival passthrough(std::uint8_t index) {
  return Arrival{index, 0, false};
}

// (port 0 link, port 1 link) of each slave, from DL status 0x0110.
std::vector<std::array<bool, 2>> links_of(SimServer& server) {
  return server.with_segment([](Segment& segment, FaultInjector&) {
    std::vector<std::array<bool, 2>> out;
    for (std::size_t i = 0; i < segment.size(); ++i) {
      const auto dl = wire::DlStatus::decode(segment.esc(i).read_u16(wire::reg::kDlStatus));
      EXPECT_EQ(dl.ports[0].loop_closed, !dl.ports[0].physical_link) << i;
      EXPECT_EQ(dl.ports[1].loop_closed, !dl.ports[1].physical_link) << i;
      out.push_back({dl.ports[0].physical_link, dl.ports[1].physical_link});
    }
    return out;
  });
}

using Links = std::vector<std::array<bool, 2>>;
constexpr std::array<bool, 2> kThrough{true, true};

// ---- Reply and exchange faults on the two ports' replies ----------------------------------------

TEST(RedundantFaults, DuplicateActsOnTheNamedPortOrOnBoth) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(
      ring.server->inject(fault::at_port(fault::duplicate_reply(), RedundantPort::secondary)));
  ring.send(0x10);
  // The primary's frame crossed the whole ring: its reply at the secondary, twice.
  EXPECT_EQ(ring.take(RedundantPort::secondary),
            (std::vector<Arrival>{processed(0x10, 3, true), processed(0x10, 3, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x10)}));
  EXPECT_EQ(ring.ports->stats().duplicated, 1u);
  // The control channel's status shows the two ports' counters when it is given the ports.
  const auto status = nlohmann::json::parse(
      handle_control_request(*ring.server, R"({"op":"status"})", ring.ports.get()));
  ASSERT_TRUE(status.contains("redundant")) << status.dump();
  EXPECT_EQ(status["redundant"]["duplicated"], 1);
  EXPECT_EQ(status["redundant"]["frames"], 2);
  EXPECT_EQ(status["redundant"]["crosses"], 2);  // both copies left by the other end
  EXPECT_EQ(status["redundant"]["bounces"], 0);
  EXPECT_EQ(status["redundant"]["topology"], describe(ring.ports->topology()));
  EXPECT_FALSE(nlohmann::json::parse(handle_control_request(*ring.server, R"({"op":"status"})"))
                   .contains("redundant"));
  ring.server->clear_faults();

  // Without a port: every frame, the secondary's unprocessed copy too (two exchanges).
  ASSERT_TRUE(ring.server->inject(fault::next(fault::duplicate_reply(), 2)));
  ring.send(0x11);
  EXPECT_EQ(ring.take(RedundantPort::secondary),
            (std::vector<Arrival>{processed(0x11, 3, true), processed(0x11, 3, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary),
            (std::vector<Arrival>{passthrough(0x11), passthrough(0x11)}));
  ring.send(0x12);  // spent
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x12, 3, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x12)}));

  // On a broken ring each side's bounce is its port's.
  ASSERT_TRUE(ring.server->inject(fault::ring_break(2)));
  ASSERT_TRUE(ring.server->inject(
      fault::next(fault::at_port(fault::duplicate_reply(), RedundantPort::primary), 1)));
  ring.send(0x13);
  EXPECT_EQ(ring.take(RedundantPort::primary),
            (std::vector<Arrival>{processed(0x13, 2, true), processed(0x13, 2, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x13, 1, false)}));
}

TEST(RedundantFaults, ReorderHoldsAReplyUntilTheNextOneAtItsPort) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(ring.server->inject(fault::ring_break(2)));
  // `next 1` counts the frames it acts on: only those whose reply arrives at the secondary.
  ASSERT_TRUE(ring.server->inject(
      fault::next(fault::at_port(fault::reorder_replies(), RedundantPort::secondary), 1)));
  ring.send(0x20);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x20, 2, true)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
  ring.send(0x21);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x21, 2, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary),
            (std::vector<Arrival>{processed(0x21, 1, false), processed(0x20, 1, false)}));
  EXPECT_EQ(ring.ports->stats().delayed, 1u);
}

TEST(RedundantFaults, DelayedReplyIsOvertakenByTheNextOne) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(ring.server->inject(
      fault::next(fault::at_port(fault::delay_replies(50ms), RedundantPort::secondary), 1)));
  ring.send(0x30);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x30)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
  ring.send(0x31);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x31)}));
  // The later reply leaves first; the delayed one follows when it is due.
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x31, 3, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary, 5s),
            (std::vector<Arrival>{processed(0x30, 3, true)}));
}

TEST(RedundantFaults, DropAndWkcOffsetOnOnePort) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(ring.server->inject(fault::ring_break(1)));
  ASSERT_TRUE(ring.server->inject(fault::at_port(fault::drop_responses(), RedundantPort::primary)));
  ring.send(0x40);
  EXPECT_TRUE(ring.take(RedundantPort::primary).empty());
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x40, 2, false)}));
  ring.server->clear_faults();  // the ring whole again, as the ports were created
  EXPECT_EQ(ring.ring_text(), "whole");
  ASSERT_TRUE(ring.server->inject(fault::ring_break(1)));
  ASSERT_TRUE(ring.server->inject(fault::at_port(fault::wkc_offset(+5), RedundantPort::secondary)));
  ring.send(0x41);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x41, 1, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x41, 7, false)}));
  // A drop without a port loses both frames.
  ring.server->clear_faults();
  ASSERT_TRUE(ring.server->inject(fault::drop_responses()));
  ring.send(0x42);
  EXPECT_TRUE(ring.take(RedundantPort::primary).empty());
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
}

TEST(RedundantFaults, ReplayAndWrongIndexKeepToTheirPort) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(ring.server->inject(fault::ring_break(1)));
  ring.send(0x50);
  EXPECT_EQ(ring.take(RedundantPort::primary).size(), 1u);
  EXPECT_EQ(ring.take(RedundantPort::secondary).size(), 1u);
  // The previous reply of the port it arrives at, not the other port's.
  ASSERT_TRUE(ring.server->inject(
      fault::next(fault::at_port(fault::replay_previous(), RedundantPort::secondary), 1)));
  ring.send(0x51);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x51, 1, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x50, 2, false)}));
  ASSERT_TRUE(ring.server->inject(
      fault::next(fault::at_port(fault::wrong_index(), RedundantPort::primary), 1)));
  ring.send(0x52);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x53, 1, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x52, 2, false)}));
}

TEST(RedundantFaults, PortNamedOnlyOnARedundantSegmentAndInEveryForm) {
  auto alone = server_for(kBasic);
  ASSERT_TRUE(alone);
  auto refused = alone->inject(fault::at_port(fault::duplicate_reply(), RedundantPort::primary));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::unsupported);
  EXPECT_NE(refused.error().message().find("no second master port"), std::string::npos)
      << refused.error().message();
  // Only the kinds that act on a whole frame name a port.
  auto slave_kind = fault::at_port(fault::disconnect("inputs"), RedundantPort::primary);
  ASSERT_FALSE(validate(slave_kind));
  EXPECT_NE(validate(slave_kind).error().message().find("names no master port"), std::string::npos);

  const auto f =
      fault::next(fault::at_port(fault::delay_replies(200us), RedundantPort::secondary), 2);
  EXPECT_EQ(describe(f), "next 2 exchanges delay replies by 200 us at the secondary port");
  EXPECT_EQ(to_json(f), R"({"kind":"delay_replies","ms":0.2,"port":"secondary","next":2})");
  auto again = parse_fault_json(to_json(f));
  ASSERT_TRUE(again) << again.error().describe();
  EXPECT_EQ(again->effect.on_port, RedundantPort::secondary);
  EXPECT_EQ(describe(*again), describe(f));
  const std::vector<std::string> words{"delay_replies", "0.2", "secondary"};
  auto parsed = parse_fault_words(words);
  ASSERT_TRUE(parsed) << parsed.error().describe();
  EXPECT_EQ(parsed->effect.on_port, RedundantPort::secondary);
  EXPECT_EQ(parsed->effect.ns, 200'000);
  const std::vector<std::string> drop{"drop_responses", "primary"};
  parsed = parse_fault_words(drop);
  ASSERT_TRUE(parsed) << parsed.error().describe();
  EXPECT_EQ(parsed->effect.on_port, RedundantPort::primary);
  const std::vector<std::string> bad{"duplicate_reply", "tertiary"};
  parsed = parse_fault_words(bad);
  ASSERT_FALSE(parsed);
  EXPECT_NE(parsed.error().message().find("unknown master port 'tertiary'"), std::string::npos);
  auto json_bad = parse_fault_json(R"({"kind":"disconnect","slave":"a","port":"primary"})");
  ASSERT_FALSE(json_bad);
  EXPECT_NE(json_bad.error().message().find("unknown key"), std::string::npos);
}

// ---- Link faults turn the ring round
// -------------------------------------------------------------

TEST(RedundantFaults, LinkDownTurnsTheRingRoundAtThePort) {
  RedundantRing ring;
  ASSERT_TRUE(ring.ports);
  ASSERT_TRUE(ring.server->inject(fault::link_down("inputs", 0)));
  EXPECT_EQ(ring.ring_text(), "break after 1");
  EXPECT_EQ(describe(ring.ports->topology()), "break after 1");
  EXPECT_EQ(links_of(*ring.server), (Links{{true, false}, {false, true}, kThrough}));
  ring.send(0x60);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x60, 1, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x60, 2, false)}));
  // The segment's own cables are untouched: the ring's cabling is the one model.
  EXPECT_TRUE(ring.server->with_segment([](Segment& s, FaultInjector&) { return s.link(1, 0); }));
  EXPECT_TRUE(ring.server->fault_info().links_down.empty());

  ASSERT_TRUE(ring.server->inject(fault::link_up("inputs", 0)));
  EXPECT_EQ(ring.ring_text(), "whole");
  ring.send(0x61);
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x61, 3, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x61)}));

  // The same cable from its other end; then the last slave's port 1, the secondary's cable.
  ASSERT_TRUE(ring.server->inject(fault::link_down("coupler", 1)));
  EXPECT_EQ(ring.ring_text(), "break after 1");
  ASSERT_TRUE(ring.server->inject(fault::link_up("inputs", 0)));
  ASSERT_TRUE(ring.server->inject(fault::link_down("outputs", 1)));
  EXPECT_EQ(ring.ring_text(), "master break secondary");
  EXPECT_EQ(links_of(*ring.server), (Links{kThrough, kThrough, {true, false}}));
  ring.send(0x62);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x62, 3, true)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());

  // master_link_down: the primary's cable. With the secondary's cut too nothing comes back.
  ASSERT_TRUE(ring.server->inject(fault::master_link_down()));
  EXPECT_EQ(ring.ring_text(), "master break primary, master break secondary");
  ring.send(0x63);
  EXPECT_TRUE(ring.take(RedundantPort::primary).empty());
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
  ASSERT_TRUE(ring.server->inject(fault::link_up("outputs", 1)));
  EXPECT_EQ(ring.ring_text(), "master break primary");
  EXPECT_EQ(links_of(*ring.server), (Links{{false, true}, kThrough, kThrough}));
  ring.send(0x64);
  EXPECT_TRUE(ring.take(RedundantPort::primary).empty());
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x64, 3, false)}));
  ASSERT_TRUE(ring.server->inject(fault::master_link_up()));
  EXPECT_EQ(ring.ring_text(), "whole");

  // Two cables down: the slave between them is out of reach of both ports.
  ASSERT_TRUE(ring.server->inject(fault::link_down("inputs", 0)));
  ASSERT_TRUE(ring.server->inject(fault::link_down("outputs", 0)));
  EXPECT_EQ(ring.ring_text(), "break after 1, break after 2");
  EXPECT_EQ(links_of(*ring.server), (Links{{true, false}, {false, false}, {false, true}}));
  ring.send(0x65);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x65, 1, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x65, 1, false)}));
  // ring_heal and fault.clear heal them, as every cable of the ring.
  ASSERT_TRUE(ring.server->inject(fault::ring_heal()));
  EXPECT_EQ(ring.ring_text(), "whole");
  ASSERT_TRUE(ring.server->inject(fault::link_down("outputs", 0)));
  ring.server->clear_faults();
  EXPECT_EQ(ring.ring_text(), "whole");
  EXPECT_EQ(links_of(*ring.server), (Links{kThrough, kThrough, kThrough}));
}

TEST(RedundantFaults, PortsTakeOverTheLinksAlreadyDown) {
  auto server = server_for(kBasic);
  ASSERT_TRUE(server);
  ASSERT_TRUE(server->inject(fault::link_down("outputs", 0)));
  ASSERT_TRUE(server->inject(fault::master_link_down()));
  EXPECT_EQ(server->fault_info().links_down, (std::vector<std::string>{"outputs:0", "master"}));
  RedundantRing ring(std::move(server));
  ASSERT_TRUE(ring.ports);
  EXPECT_EQ(ring.ring_text(), "master break primary, break after 2");
  EXPECT_TRUE(ring.server->fault_info().links_down.empty());
  ring.send(0x70);
  EXPECT_TRUE(ring.take(RedundantPort::primary).empty());
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x70, 1, false)}));
  ASSERT_TRUE(ring.server->inject(fault::master_link_up()));
  ring.send(0x71);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x71, 2, true)}));
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x71, 1, false)}));
}

// ---- Hot-connect plugs through the cabling
// --------------------------------------------------------

TEST(RedundantFaults, UnpluggedGroupIsOutOfTheRingAndComposesWithABreak) {
  RedundantRing ring(kWithTool);
  ASSERT_TRUE(ring.ports);
  ring.send(0x80);
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x80, 4, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x80)}));

  // A break, then the group pulled behind it: the primary's side turns round at the coupler, and
  // the secondary's cable has no partner any more (the tool is without power).
  ASSERT_TRUE(ring.server->inject(fault::ring_break(1)));
  ASSERT_TRUE(ring.server->plug("tool", false));
  EXPECT_EQ(links_of(*ring.server)[2], (std::array<bool, 2>{true, false}));
  ring.send(0x81);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x81, 1, true)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
  // Healed, the primary's frame turns round at the outputs terminal.
  ASSERT_TRUE(ring.server->inject(fault::ring_heal()));
  ring.send(0x82);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x82, 3, true)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
  // fault.clear leaves the group out.
  ring.server->clear_faults();
  ring.send(0x83);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x83, 3, true)}));
  EXPECT_FALSE(ring.server->status().hot_connect.at(0).plugged);

  // Plugged back in (by the fault kind, the same path): the ring is whole, the tool powered up
  // afresh (station 0, INIT).
  ASSERT_TRUE(ring.server->inject(fault::hot_plug("tool")));
  EXPECT_TRUE(ring.server->status().hot_connect.at(0).plugged);
  EXPECT_EQ(links_of(*ring.server), (Links{kThrough, kThrough, kThrough, kThrough}));
  ring.send(0x84);
  EXPECT_EQ(ring.take(RedundantPort::secondary), (std::vector<Arrival>{processed(0x84, 4, true)}));
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{passthrough(0x84)}));
  const auto tool = ring.server->status().slaves.at(3);
  EXPECT_EQ(tool.station, 0u);
  EXPECT_EQ(tool.al_state, wire::AlState::init);
  // Pulled by the fault kind with the ring broken before it: the secondary's side is lost, the
  // slaves between the break and the group are out of reach.
  ASSERT_TRUE(ring.server->inject(fault::ring_break(2)));
  ASSERT_TRUE(ring.server->inject(fault::hot_unplug("tool")));
  ring.send(0x85);
  EXPECT_EQ(ring.take(RedundantPort::primary), (std::vector<Arrival>{processed(0x85, 2, true)}));
  EXPECT_TRUE(ring.take(RedundantPort::secondary).empty());
}

TEST(RedundantFaults, LinkUpDoesNotPlugAPulledGroupOnASinglePort) {
  auto server = server_for(kWithTool);
  ASSERT_TRUE(server);
  ASSERT_TRUE(server->plug("tool", false));
  ASSERT_TRUE(server->inject(fault::link_up("tool", 0)));
  EXPECT_FALSE(server->status().hot_connect.at(0).plugged);
  EXPECT_FALSE(server->with_segment([](Segment& s, FaultInjector&) { return s.link(3, 0); }));
  // A link_down on the group's cable still holds it down once the group is plugged in.
  ASSERT_TRUE(server->inject(fault::link_down("tool", 0)));
  ASSERT_TRUE(server->plug("tool", true));
  EXPECT_FALSE(server->with_segment([](Segment& s, FaultInjector&) { return s.link(3, 0); }));
  server->clear_faults();
  EXPECT_TRUE(server->with_segment([](Segment& s, FaultInjector&) { return s.link(3, 0); }));
  EXPECT_TRUE(server->status().hot_connect.at(0).plugged);
}

// ---- Routes over the cables (pure) ------------------------------------------------------------

TEST(RedundantFaults, RoutesOverSeveralCablesDown) {
  // Five slaves, cables 0..5.
  std::vector<bool> down(6, false);
  down[2] = down[4] = true;
  auto r = route_redundant(down, RedundantPort::primary);
  EXPECT_EQ(r.first, 0u);
  EXPECT_EQ(r.last, 2u);
  EXPECT_EQ(r.egress, RedundantPort::primary);
  r = route_redundant(down, RedundantPort::secondary);
  EXPECT_EQ(r.first, 4u);
  EXPECT_EQ(r.last, 5u);
  EXPECT_EQ(r.egress, RedundantPort::secondary);
  down[0] = true;  // the primary's cable too
  EXPECT_FALSE(route_redundant(down, RedundantPort::primary).egress);
  down[5] = true;
  EXPECT_FALSE(route_redundant(down, RedundantPort::secondary).egress);

  const auto t = RedundantTopology::cables_down({5, 2, 2, 0}, 5);
  EXPECT_EQ(t.kind, RedundantTopology::Kind::several);
  EXPECT_EQ(describe(t), "master break primary, break after 2, master break secondary");
  auto cables = cables_down(t, 5);
  ASSERT_TRUE(cables);
  EXPECT_EQ(*cables, (std::vector<bool>{true, false, true, false, false, true}));
  EXPECT_EQ(RedundantTopology::cables_down({5}, 5).kind, RedundantTopology::Kind::master_break);
  EXPECT_EQ(describe(RedundantTopology::cables_down({3}, 5)), "break after 3");
  EXPECT_EQ(describe(RedundantTopology::cables_down({}, 5)), "whole");
  auto beyond = cables_down(t, 3);
  ASSERT_FALSE(beyond);
  EXPECT_NE(beyond.error().message().find("has no cable 5 (0..3)"), std::string::npos)
      << beyond.error().message();
}

}  // namespace
}  // namespace ecat::sim
