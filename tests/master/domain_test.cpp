// Domain against the simulated ring of domain_test_support.hpp: states and errors, layout and
// expected working counters, the loopback (outputs written appear as inputs), freshness, lost
// frames up to the miss threshold, WKC mismatches with degraded/recovered notifications, live
// period changes and images larger than one frame.

#include <array>
#include <map>

#include <gtest/gtest.h>

#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>

#include "master/domain_test_support.hpp"

namespace ecat::master::test {
namespace {

using Bytes = std::vector<std::uint8_t>;

DomainConfig config(std::string id = "main") {
  DomainConfig c;
  c.id = std::move(id);
  c.period = kPeriod;
  c.logical_base = 0x00010000;
  return c;
}

std::unique_ptr<Domain> make_domain(bus::Bus& bus, DomainConfig c,
                                    DomainObserver* observer = nullptr) {
  auto d = Domain::create(bus, std::move(c), observer);
  EXPECT_TRUE(d.ok()) << d.error().describe();
  return d.ok() ? std::move(*d) : nullptr;
}

// A cycling domain over the loopback: outputs SM0/SM1 of the EL2809, then SM0 of the EL1809.
struct Loopback {
  std::unique_ptr<Rig> rig;
  std::unique_ptr<Domain> domain;
  std::unique_ptr<Cycler> cycler;

  explicit Loopback(DomainConfig c = config(), DomainObserver* observer = nullptr,
                    std::function<void(Domain&)> before_slaves = {}) {
    rig = make_rig();
    if (!rig) return;
    domain = make_domain(*rig->bus, std::move(c), observer);
    if (!domain) return;
    if (before_slaves) before_slaves(*domain);
    rig->attach(*domain, kOutputs);
    rig->attach(*domain, kInputs);
    cycler = std::make_unique<Cycler>(*rig->bus);
    EXPECT_TRUE(cycler->add(*domain).ok());
    EXPECT_TRUE(cycler->start().ok());
    EXPECT_TRUE(domain->start_cycling().ok());
    rig->all_to(wire::AlState::safeop);
    rig->all_to(wire::AlState::op);
  }
  ~Loopback() {
    if (cycler) (void)cycler->stop();
    cycler.reset();
    domain.reset();
  }
  bool ok() const { return rig && domain && cycler; }

  // Waits until the inputs read `expected`.
  bool inputs_become(const Bytes& expected) {
    return eventually([&] {
      auto v = domain->read(PdoKey{kInputs, 0});
      return v.ok() && *v == expected;
    });
  }
};

// ---------------------------------------------------------------------------------------------

TEST(DomainConfigTest, InvalidConfigurationsNameTheField) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto c = config();
  c.period = 40us;
  auto d = Domain::create(*rig->bus, c);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().code(), Errc::invalid_argument);
  EXPECT_EQ(d.error().message(), "domain \"main\": period 40 us is below the 50 us minimum");

  c = config();
  c.id = "";
  d = Domain::create(*rig->bus, c);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().message(), "domain: id must not be empty");

  c = config();
  c.miss_threshold = 0;
  d = Domain::create(*rig->bus, c);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().message(), "domain \"main\": miss_threshold must be at least 1");

  c = config();
  c.max_datagram_size = 1487;
  d = Domain::create(*rig->bus, c);
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().message().find("max_datagram_size 1487 exceeds the 1486 data bytes"),
            std::string::npos)
      << d.error().message();

  c = config();
  c.logical_base = 0xFFFFFF00;
  d = Domain::create(*rig->bus, c);
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().message().find("logical window 0xffffff00"), std::string::npos);

  // Sub-millisecond and non-integer-millisecond periods are fine.
  c = config();
  c.period = 750us;
  EXPECT_TRUE(Domain::create(*rig->bus, c).ok());
}

TEST(DomainStateTest, TransitionsAndErrorsAsTheReference) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto domain = make_domain(*rig->bus, config());
  ASSERT_TRUE(domain);
  EXPECT_EQ(domain->state(), DomainState::open);
  EXPECT_EQ(to_string(domain->state()), "open");

  auto started = domain->start_cycling();
  ASSERT_FALSE(started.ok());
  EXPECT_EQ(started.error().code(), Errc::wrong_state);
  EXPECT_EQ(started.error().message(), "domain \"main\": cannot start cycling: nothing_registered");

  auto a = domain->register_pdo({kOutputs, 0}, 1, PdoDirection::output);
  auto b = domain->register_pdo({kOutputs, 1}, 1, PdoDirection::output);
  auto c = domain->register_pdo({kInputs, 0}, 2, PdoDirection::input);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(*a, 0x00010000u);
  EXPECT_EQ(*b, 0x00010001u);
  EXPECT_EQ(*c, 0x00010002u);

  auto dup = domain->register_pdo({kOutputs, 1}, 1, PdoDirection::output);
  ASSERT_FALSE(dup.ok());
  EXPECT_EQ(dup.error().code(), Errc::invalid_argument);
  EXPECT_EQ(dup.error().message(),
            "domain \"main\": station 0x1003 SM1 is already registered (at logical 0x00010001, 1 "
            "bytes)");

  // A self-sizing domain (the default) takes images beyond one datagram, up to its ceiling.
  auto big = domain->register_pdo({kInputs2, 0}, 2033, PdoDirection::input);
  ASSERT_TRUE(big.ok()) << big.error().message();
  auto huge = domain->register_pdo({kInputs2, 1}, 60000, PdoDirection::input);
  ASSERT_TRUE(huge.ok()) << huge.error().message();

  auto zero = domain->register_pdo({kInputs2, 0}, 0, PdoDirection::input);
  ASSERT_FALSE(zero.ok());
  EXPECT_EQ(zero.error().code(), Errc::invalid_argument);

  ASSERT_TRUE(domain->start_cycling().ok());
  EXPECT_EQ(domain->state(), DomainState::cycling);
  auto again = domain->start_cycling();
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().message(), "domain \"main\": cannot start cycling: already_cycling");

  auto late = domain->register_pdo({kInputs2, 0}, 2, PdoDirection::input);
  ASSERT_FALSE(late.ok());
  EXPECT_EQ(late.error().code(), Errc::wrong_state);
  EXPECT_EQ(late.error().message(),
            "domain \"main\": cannot register station 0x1004 SM0 (input): not_open (the domain is "
            "cycling; registration is only possible before it first cycles)");

  ASSERT_TRUE(domain->stop_cycling().ok());
  EXPECT_EQ(domain->state(), DomainState::stopped);
  auto stop_again = domain->stop_cycling();
  ASSERT_FALSE(stop_again.ok());
  EXPECT_EQ(stop_again.error().message(),
            "domain \"main\": cannot stop cycling: the domain is stopped");
  EXPECT_FALSE(domain->register_pdo({kInputs2, 0}, 2, PdoDirection::input).ok());
  ASSERT_TRUE(domain->start_cycling().ok());
  EXPECT_EQ(domain->state(), DomainState::cycling);
}

TEST(DomainLayoutTest, ExpectedWkcPerSlaveAndDatagram) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto c = config();
  auto domain = make_domain(*rig->bus, c);
  ASSERT_TRUE(domain);
  // Slave 0x2001: input and output (3), slave 0x2002: input only (1), slave 0x2003: two outputs
  // (2), slave 0x2004: not counted.
  ASSERT_TRUE(domain->register_pdo({0x2001, 2}, 4, PdoDirection::output).ok());
  ASSERT_TRUE(domain->register_pdo({0x2001, 3}, 4, PdoDirection::input).ok());
  ASSERT_TRUE(domain->register_pdo({0x2002, 3}, 2, PdoDirection::input).ok());
  ASSERT_TRUE(domain->register_pdo({0x2003, 2}, 1, PdoDirection::output).ok());
  ASSERT_TRUE(domain->register_pdo({0x2003, 3}, 1, PdoDirection::output).ok());
  ASSERT_TRUE(domain->register_pdo({0x2004, 3}, 8, PdoDirection::input, false).ok());
  auto layout = domain->layout();
  ASSERT_EQ(layout.size(), 1u);
  EXPECT_EQ(layout[0].offset, 0u);
  EXPECT_EQ(layout[0].logical, 0x00010000u);
  EXPECT_EQ(layout[0].length, 20u);
  EXPECT_EQ(layout[0].expected_wkc, 6u);

  // Override, then restore.
  ASSERT_TRUE(domain->set_expected_wkc({9}).ok());
  EXPECT_EQ(domain->layout()[0].expected_wkc, 9u);
  auto wrong = domain->set_expected_wkc({1, 2});
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().message(),
            "domain \"main\": expected WKC override has 2 values, the image makes 1 datagrams");
  ASSERT_TRUE(domain->set_expected_wkc({}).ok());
  EXPECT_EQ(domain->info().expected_wkc, 6u);

  // Datagrams of at most 6 bytes, cut at registration boundaries where one fits.
  c.id = "small";
  c.max_datagram_size = 6;
  auto small = make_domain(*rig->bus, c);
  ASSERT_TRUE(small);
  ASSERT_TRUE(small->register_pdo({0x2001, 2}, 4, PdoDirection::output).ok());  // 0..4
  ASSERT_TRUE(small->register_pdo({0x2001, 3}, 4, PdoDirection::input).ok());   // 4..8
  ASSERT_TRUE(small->register_pdo({0x2002, 3}, 2, PdoDirection::input).ok());   // 8..10
  ASSERT_TRUE(small->register_pdo({0x2005, 3}, 9, PdoDirection::input).ok());   // 10..19
  layout = small->layout();
  ASSERT_EQ(layout.size(), 4u);
  const std::array<std::pair<std::uint32_t, std::uint16_t>, 4> expected_spans{
      {{0, 4}, {4, 6}, {10, 6}, {16, 3}}};
  const std::array<std::uint16_t, 4> expected_wkc{2, 2, 1, 1};
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(layout[i].offset, expected_spans[i].first) << i;
    EXPECT_EQ(layout[i].length, expected_spans[i].second) << i;
    EXPECT_EQ(layout[i].logical, 0x00010000u + expected_spans[i].first) << i;
    EXPECT_EQ(layout[i].expected_wkc, expected_wkc[i]) << i;
  }
}

// A SyncManager status registration (the mailbox status in the cyclic frame) is one input byte of
// its own kind: it counts as a read FMMU does, once per slave and datagram, so it adds 1 for a
// slave with only outputs there and nothing for one that reads already; it has its own key beside
// the SyncManager's image, and any other shape is refused.
TEST(DomainLayoutTest, SyncManagerStatusRegistration) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto c = config();
  c.max_datagram_size = 6;
  auto domain = make_domain(*rig->bus, c);
  ASSERT_TRUE(domain);
  ASSERT_TRUE(domain->register_pdo({0x2001, 2}, 2, PdoDirection::output).ok());  // 0..2
  ASSERT_TRUE(domain->register_pdo({0x2001, 3}, 2, PdoDirection::input).ok());   // 2..4
  auto status1 = domain->register_sm_status(0x2001, 1);                          // 4
  ASSERT_TRUE(status1) << status1.error().describe();
  EXPECT_EQ(*status1, 0x00010004u);
  ASSERT_TRUE(domain->register_pdo({0x2002, 2}, 1, PdoDirection::output).ok());  // 5
  ASSERT_TRUE(domain->register_sm_status(0x2002, 1).ok());                       // 6: next datagram
  ASSERT_TRUE(domain->register_pdo({0x2003, 2}, 1, PdoDirection::output).ok());  // 7
  auto layout = domain->layout();
  ASSERT_EQ(layout.size(), 2u);
  EXPECT_EQ(layout[0].length, 6u);
  EXPECT_EQ(layout[0].expected_wkc, 3u + 2u);  // 0x2001 reads and writes, 0x2002 writes
  EXPECT_EQ(layout[1].length, 2u);
  EXPECT_EQ(layout[1].expected_wkc, 1u + 2u);  // 0x2002's status alone, 0x2003 writes

  const PdoKey key{0x2001, 1, RegistrationKind::sm_status};
  auto reg = domain->registration(key);
  ASSERT_TRUE(reg) << reg.error().describe();
  EXPECT_EQ(reg->size, 1u);
  EXPECT_EQ(reg->direction, PdoDirection::input);
  EXPECT_EQ(to_string(key), "station 0x2001 SM1 status");
  EXPECT_FALSE(domain->registration(PdoKey{0x2001, 1}));  // not the SyncManager's image
  EXPECT_EQ(domain->register_sm_status(0x2001, 1).error().code(), Errc::invalid_argument);
  auto wrong =
      domain->register_pdo(PdoKey{0x2004, 1, RegistrationKind::sm_status}, 2, PdoDirection::input);
  ASSERT_FALSE(wrong);
  EXPECT_NE(wrong.error().message().find("one input byte"), std::string::npos);
  EXPECT_FALSE(domain->register_pdo(PdoKey{0x2004, 1, RegistrationKind::sm_status}, 1,
                                    PdoDirection::output));
}

TEST(DomainHotPathTest, ErrorsBeforeCycling) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto domain = make_domain(*rig->bus, config());
  ASSERT_TRUE(domain);
  ASSERT_TRUE(domain->register_pdo({kOutputs, 0}, 1, PdoDirection::output).ok());
  ASSERT_TRUE(domain->register_pdo({kInputs, 0}, 2, PdoDirection::input).ok());

  std::array<std::uint8_t, 4> buffer{};
  auto in = domain->read(PdoKey{kInputs, 0}, buffer);
  ASSERT_FALSE(in.ok());
  EXPECT_EQ(in.error().code(), Errc::not_ready);
  EXPECT_EQ(in.error().message(),
            "domain \"main\": station 0x1002 SM0 (input) has no valid cycle yet");
  auto out = domain->read(PdoKey{kOutputs, 0}, buffer);
  ASSERT_FALSE(out.ok());
  EXPECT_EQ(out.error().code(), Errc::not_ready);
  auto missing = domain->read(PdoKey{0x7777, 2}, buffer);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  EXPECT_EQ(missing.error().message(), "domain \"main\": station 0x7777 SM2 is not registered");

  const Bytes two{1, 2};
  auto wrong_size = domain->write(PdoKey{kOutputs, 0}, two);
  ASSERT_FALSE(wrong_size.ok());
  EXPECT_EQ(wrong_size.error().message(),
            "domain \"main\": cannot write station 0x1003 SM0: 2 bytes given, the SM image has 1");
  auto to_input = domain->write(PdoKey{kInputs, 0}, two);
  ASSERT_FALSE(to_input.ok());
  EXPECT_EQ(to_input.error().message(),
            "domain \"main\": cannot write station 0x1002 SM0: it is an input");
  auto bits = domain->write_bits(PdoKey{kOutputs, 0}, 6, 3, 7);
  ASSERT_FALSE(bits.ok());
  EXPECT_EQ(bits.error().code(), Errc::invalid_argument);

  // Outputs can be staged while open; read gives them back.
  const Bytes one{0x5A};
  ASSERT_TRUE(domain->write(PdoKey{kOutputs, 0}, one).ok());
  ASSERT_TRUE(domain->write_bits(PdoKey{kOutputs, 0}, 0, 2, 0x3).ok());  // 0x5A -> 0x5B
  auto value = domain->read(PdoKey{kOutputs, 0});
  ASSERT_TRUE(value.ok());
  EXPECT_EQ(*value, Bytes{0x5B});
  auto s = domain->sample(PdoKey{kOutputs, 0});
  ASSERT_TRUE(s.ok());
  EXPECT_TRUE(s->info.updated_at.has_value());
  EXPECT_FALSE(s->info.freshness.has_value());
  auto small = domain->read(PdoKey{kInputs, 0}, std::span<std::uint8_t>(buffer.data(), 1));
  ASSERT_FALSE(small.ok());
  EXPECT_EQ(small.error().code(), Errc::invalid_argument);
  EXPECT_EQ(domain->freshness().state, Freshness::not_ready);
}

TEST(DomainCycleTest, OutputsAppearAsInputsWithExactWkc) {
  RecordingObserver observer;
  Loopback lb(config(), &observer);
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  EXPECT_EQ(d.info().expected_wkc, 3u);
  ASSERT_EQ(d.info().datagrams.size(), 1u);

  ASSERT_TRUE(d.write(PdoKey{kOutputs, 0}, Bytes{0xA5}).ok());
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 1}, Bytes{0x3C}).ok());
  ASSERT_TRUE(lb.inputs_become({0xA5, 0x3C}));
  const auto stats = d.stats();
  EXPECT_EQ(stats.state, DomainState::cycling);
  EXPECT_EQ(stats.last_wkc, 3u);
  EXPECT_TRUE(stats.health.healthy);
  EXPECT_GT(stats.valid_count, 0u);
  EXPECT_EQ(stats.wkc_mismatch_count, 0u);
  EXPECT_TRUE(stats.last_valid_at.has_value());
  EXPECT_GT(stats.max_latency.count(), 0);
  EXPECT_LE(stats.min_latency, stats.mean_latency);
  EXPECT_LE(stats.mean_latency, stats.max_latency);

  // Channel 16 (bit 7 of SM1) on, channel 1 (bit 0 of SM0) off.
  ASSERT_TRUE(d.write_bits(PdoKey{kOutputs, 1}, 7, 1, 1).ok());
  ASSERT_TRUE(d.write_bits(PdoKey{kOutputs, 0}, 0, 1, 0).ok());
  ASSERT_TRUE(lb.inputs_become({0xA4, 0xBC}));
  // A field across the two input bytes (bits 4..11: 0xCA), read alone; outputs have no freshness.
  const auto in_handle = d.find(PdoKey{kInputs, 0});
  const auto out_handle = d.find(PdoKey{kOutputs, 0});
  ASSERT_TRUE(in_handle.ok() && out_handle.ok());
  auto across = d.read_fresh_bits(*in_handle, 4, 8);
  for (int retry = 0; retry < 1000 && !across && across.error().code() == Errc::stale; ++retry) {
    std::this_thread::sleep_for(kPeriod);  // a starved bus thread on a loaded machine
    across = d.read_fresh_bits(*in_handle, 4, 8);
  }
  ASSERT_TRUE(across.ok()) << across.error().describe();
  EXPECT_EQ(*across, 0xCAu);
  EXPECT_EQ(d.read_fresh_bits(*out_handle, 0, 1).error().code(), Errc::invalid_argument);

  // Sample: value, timestamps, freshness.
  auto s = d.sample(PdoKey{kInputs, 0});
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->value, (Bytes{0xA4, 0xBC}));
  ASSERT_TRUE(s->info.freshness.has_value());
  EXPECT_EQ(s->info.freshness->state, Freshness::fresh);
  EXPECT_EQ(s->info.freshness->stale_after, 3 * kPeriod);
  ASSERT_TRUE(s->info.updated_at && s->info.changed_at);
  EXPECT_LE(*s->info.changed_at, *s->info.updated_at);

  // Change records: the inputs' first publication and each change, with the changed bytes.
  std::vector<InputChange> changes;
  auto drained = d.drain_changes([&](const InputChange& c) { changes.push_back(c); });
  EXPECT_EQ(drained.dropped, 0u);
  EXPECT_EQ(drained.delivered, changes.size());
  ASSERT_GE(changes.size(), 3u);
  for (const auto& c : changes)
    EXPECT_EQ(c.key, (PdoKey{kInputs, 0}));
  EXPECT_EQ(changes.front().first_byte, 0u);  // first publication: the whole image
  EXPECT_EQ(changes.front().last_byte, 1u);
  for (std::size_t i = 1; i < changes.size(); ++i)
    EXPECT_GT(changes[i].cycle, changes[i - 1].cycle);
  EXPECT_EQ(observer.inputs_changed.load(), changes.size());
  // Nothing changes any more: nothing more to drain.
  std::this_thread::sleep_for(20 * kPeriod);
  const auto more = d.drain_changes([](const InputChange&) {});
  EXPECT_EQ(more.delivered, 0u);
  EXPECT_EQ(observer.degraded_count(), 0u);
  EXPECT_EQ(observer.stopped_count(), 0u);
}

// Domain::Field: resolved once, then read and staged without a lookup. Five bytes of padding
// first (no slave serves them, not counted in the WKC) put the two input bytes at image bytes 7
// and 8, across the image's first two 64-bit words: every field of them reads as the bytes say,
// as read_fresh_bits does. Fields of the wrong direction or domain, or unbound, are refused.
TEST(DomainCycleTest, FieldsReadAndStageTheirOwnBitsAcrossWords) {
  Loopback lb(config(), nullptr, [](Domain& d) {
    ASSERT_TRUE(d.register_pdo(PdoKey{0x7777, 0}, 5, PdoDirection::output, false).ok());
  });
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  const auto in_handle = d.find(PdoKey{kInputs, 0});
  const auto out0 = d.find(PdoKey{kOutputs, 0});
  const auto out1 = d.find(PdoKey{kOutputs, 1});
  ASSERT_TRUE(in_handle.ok() && out0.ok() && out1.ok());
  ASSERT_EQ(d.registration(PdoKey{kInputs, 0})->offset, 7u) << "the premise: across two words";

  // Staged through fields: SM0 whole, then the high nibble of SM1 over what write() put there.
  auto whole = d.field(*out0, 0, 8);
  auto nibble = d.field(*out1, 4, 4);
  ASSERT_TRUE(whole.ok() && nibble.ok());
  EXPECT_EQ(whole->direction(), PdoDirection::output);
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 1}, Bytes{0x3C}).ok());
  ASSERT_TRUE(d.write_bits(*whole, 0xA5).ok());
  ASSERT_TRUE(d.write_bits(*nibble, 0x9).ok());
  ASSERT_TRUE(lb.inputs_become({0xA5, 0x9C}));
  const std::uint64_t image = 0x9CA5;  // the two input bytes, LSB first
  for (std::size_t offset = 0; offset < 16; ++offset) {
    for (std::size_t length = 1; offset + length <= 16; ++length) {
      auto f = d.field(*in_handle, offset, length);
      ASSERT_TRUE(f.ok()) << offset << "+" << length;
      const std::uint64_t expected = (image >> offset) & ((std::uint64_t{1} << length) - 1);
      auto got = d.read_fresh(*f);
      auto bits = d.read_fresh_bits(*in_handle, offset, length);
      for (int retry = 0; retry < 1000 && !(got && bits); ++retry) {
        ASSERT_EQ((got ? bits : got).error().code(), Errc::stale);  // a starved bus thread
        std::this_thread::sleep_for(kPeriod);
        got = d.read_fresh(*f);
        bits = d.read_fresh_bits(*in_handle, offset, length);
      }
      ASSERT_TRUE(got.ok() && bits.ok());
      EXPECT_EQ(*got, expected) << offset << "+" << length;
      EXPECT_EQ(*bits, expected) << offset << "+" << length;
    }
  }

  // field() checks what read_fresh_bits / write_bits check, in their words.
  EXPECT_EQ(d.field(PdoHandle{99}, 0, 1).error().code(), Errc::not_found);
  auto outside = d.field(*in_handle, 9, 8);
  ASSERT_FALSE(outside.ok());
  EXPECT_EQ(outside.error().message(),
            "domain \"main\": cannot read bits 9..17 of station 0x1002 SM0: the SM image has 16 "
            "bits and at most 64 bits are read at once");
  EXPECT_EQ(d.field(*in_handle, 0, 0).error().code(), Errc::invalid_argument);
  EXPECT_EQ(d.field(*out0, 0, 9).error().message(),
            "domain \"main\": cannot write bits 0..9 of station 0x1003 SM0: the SM image has 8 "
            "bits and at most 64 bits are written at once");
  // An output field has no freshness, an input field is not staged.
  auto in_field = d.field(*in_handle, 0, 4);
  ASSERT_TRUE(in_field.ok());
  auto no_freshness = d.read_fresh(*whole);
  ASSERT_FALSE(no_freshness.ok());
  EXPECT_EQ(no_freshness.error().code(), Errc::invalid_argument);
  EXPECT_EQ(no_freshness.error().message(),
            "domain \"main\": read_fresh_bits(station 0x1003 SM0): outputs have no freshness");
  auto to_input = d.write_bits(*in_field, 1);
  ASSERT_FALSE(to_input.ok());
  EXPECT_EQ(to_input.error().message(),
            "domain \"main\": cannot write bits of station 0x1002 SM0: it is an input");
  // Unbound, or another domain's: refused, nothing read or staged.
  const Domain::Field unbound;
  EXPECT_FALSE(unbound.bound());
  EXPECT_EQ(d.read_fresh(unbound).error().code(), Errc::invalid_argument);
  EXPECT_EQ(d.write_bits(unbound, 1).error().code(), Errc::invalid_argument);
  auto other = make_domain(*lb.rig->bus, config("other"));
  ASSERT_TRUE(other);
  ASSERT_TRUE(other->register_pdo(PdoKey{kOutputs, 0}, 1, PdoDirection::output).ok());
  auto foreign = other->field(PdoHandle{0}, 0, 8);
  ASSERT_TRUE(foreign.ok());
  auto refused = d.write_bits(*foreign, 0);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().message(), "domain \"main\": a field made by another domain");
  EXPECT_EQ(other->write_bits(*whole, 0).error().code(), Errc::invalid_argument);
  EXPECT_TRUE(lb.inputs_become({0xA5, 0x9C})) << "nothing staged by the refused writes";
}

TEST(DomainCycleTest, FreshnessNotReadyFreshStale) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto domain = make_domain(*rig->bus, config());
  ASSERT_TRUE(domain);
  rig->attach(*domain, kInputs);
  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycler.add(*domain).ok());
  ASSERT_TRUE(cycler.start().ok());

  std::array<std::uint8_t, 2> buffer{};
  auto s = domain->sample(PdoKey{kInputs, 0}, buffer);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code(), Errc::not_ready);
  // read / read_fresh (their own paths, without a SampleInfo) give the same answers.
  const auto handle = domain->find(PdoKey{kInputs, 0});
  ASSERT_TRUE(handle.ok());
  EXPECT_EQ(domain->read(*handle, buffer).error().code(), Errc::not_ready);
  EXPECT_EQ(domain->read(PdoKey{kInputs, 0}, buffer).error().code(), Errc::not_ready);
  EXPECT_EQ(domain->read_fresh(*handle, buffer).error().code(), Errc::not_ready);
  std::array<std::uint8_t, 1> small{};
  EXPECT_EQ(domain->read(*handle, small).error().code(), Errc::invalid_argument);
  EXPECT_EQ(domain->read_fresh(*handle, small).error().code(), Errc::invalid_argument);
  EXPECT_EQ(domain->read(PdoHandle{99}, buffer).error().code(), Errc::not_found);
  // read_fresh_bits: the same answers, and its own argument checks.
  EXPECT_EQ(domain->read_fresh_bits(*handle, 0, 16).error().code(), Errc::not_ready);
  EXPECT_EQ(domain->read_fresh_bits(PdoHandle{99}, 0, 1).error().code(), Errc::not_found);
  auto outside = domain->read_fresh_bits(*handle, 9, 8);  // bits 9..16 of a 16-bit image
  ASSERT_FALSE(outside.ok());
  EXPECT_EQ(outside.error().code(), Errc::invalid_argument);
  EXPECT_EQ(outside.error().message(),
            "domain \"main\": cannot read bits 9..17 of station 0x1002 SM0: the SM image has 16 "
            "bits and at most 64 bits are read at once");
  EXPECT_EQ(domain->read_fresh_bits(*handle, 0, 0).error().code(), Errc::invalid_argument);

  ASSERT_TRUE(domain->start_cycling().ok());
  rig->all_to(wire::AlState::safeop);
  ASSERT_TRUE(eventually([&] { return domain->freshness().state == Freshness::fresh; }));
  s = domain->sample(PdoKey{kInputs, 0}, buffer);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->freshness->state, Freshness::fresh);
  EXPECT_EQ(domain->stats().last_wkc, 1u);
  ASSERT_TRUE(domain->read_fresh(PdoKey{kInputs, 0}, buffer).ok());
  auto got = domain->read_fresh(*handle, buffer);
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(*got, 2u);
  // The bits of the image just read, at every offset and length (the inputs do not change here:
  // nothing drives them).
  const std::uint64_t image = std::uint64_t{buffer[0]} | (std::uint64_t{buffer[1]} << 8);
  for (std::size_t off = 0; off < 16; ++off) {
    for (std::size_t len = 1; off + len <= 16; ++len) {
      auto bits = domain->read_fresh_bits(*handle, off, len);
      // A loaded machine may starve the bus thread past stale_after: that read is retried.
      for (int retry = 0; retry < 1000 && !bits && bits.error().code() == Errc::stale; ++retry) {
        std::this_thread::sleep_for(kPeriod);
        bits = domain->read_fresh_bits(*handle, off, len);
      }
      ASSERT_TRUE(bits.ok()) << off << "+" << len;
      EXPECT_EQ(*bits, (image >> off) & ((std::uint64_t{1} << len) - 1)) << off << "+" << len;
    }
  }
  EXPECT_EQ(domain->read(*handle, buffer).value(), 2u);

  ASSERT_TRUE(domain->stop_cycling().ok());
  std::this_thread::sleep_for(10 * kPeriod);  // > 3 periods
  s = domain->sample(PdoKey{kInputs, 0}, buffer);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->freshness->state, Freshness::stale);
  EXPECT_GT(*s->freshness->age, 3 * kPeriod);
  auto fresh = domain->read_fresh(PdoKey{kInputs, 0}, buffer);
  ASSERT_FALSE(fresh.ok());
  EXPECT_EQ(fresh.error().code(), Errc::stale);
  EXPECT_NE(fresh.error().message().find("station 0x1002 SM0 (input) is stale"), std::string::npos);
  auto stale_bits = domain->read_fresh_bits(*handle, 3, 5);
  ASSERT_FALSE(stale_bits.ok());
  EXPECT_EQ(stale_bits.error().code(), Errc::stale);
  EXPECT_NE(stale_bits.error().message().find("station 0x1002 SM0 (input) is stale"),
            std::string::npos);
  EXPECT_TRUE(domain->read(PdoKey{kInputs, 0}, buffer).ok());  // the image stays readable
  (void)cycler.stop();
}

TEST(DomainCycleTest, LostFramesReachTheMissThresholdAndStop) {
  RecordingObserver observer;
  auto c = config();
  c.miss_threshold = 6;
  Loopback lb(c, &observer);
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  ASSERT_TRUE(eventually([&] { return d.stats().valid_count > 5; }));

  ASSERT_TRUE(lb.rig->server->inject(sim::fault::drop_responses()).ok());
  ASSERT_TRUE(eventually([&] { return observer.stopped_count() == 1; }));
  EXPECT_EQ(d.state(), DomainState::stopped);
  {
    std::lock_guard lock(observer.mutex);
    EXPECT_EQ(observer.stopped.front().reason, InvalidReason::timeout);
    EXPECT_EQ(observer.stopped_misses, 6u);
    ASSERT_EQ(observer.degraded.size(), 1u);  // at 3 invalid cycles, before the stop
    EXPECT_EQ(observer.degraded.front().reason, InvalidReason::timeout);
  }
  auto stats = d.stats();
  EXPECT_EQ(stats.miss_count, 6u);
  EXPECT_GE(stats.total_miss_count, 6u);
  EXPECT_FALSE(stats.health.healthy);
  ASSERT_TRUE(stats.health.invalid.has_value());
  EXPECT_EQ(stats.health.invalid->reason, InvalidReason::timeout);
  EXPECT_GE(stats.timeout_count + stats.overrun_count + stats.expired_count, 6u);

  // Recovery: the faults go, cycling restarts, the next valid cycle reports recovered.
  lb.rig->server->clear_faults();
  std::this_thread::sleep_for(60ms *
                              kSlow);  // let the lost exchanges time out (20 ms frame timeout)
  ASSERT_TRUE(d.start_cycling().ok());
  ASSERT_TRUE(eventually([&] { return observer.recovered.load() == 1; }));
  stats = d.stats();
  EXPECT_EQ(stats.miss_count, 0u);
  EXPECT_TRUE(stats.health.healthy);
  EXPECT_EQ(d.state(), DomainState::cycling);
}

TEST(DomainCycleTest, WkcMismatchIsInvalidThenDegradedThenRecovered) {
  RecordingObserver observer;
  Loopback lb(config(), &observer);
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  ASSERT_TRUE(eventually([&] { return d.stats().valid_count > 5; }));
  const auto before = d.stats();

  // The EL2809 drops off the ring for 20 exchanges (only our LRWs run now): its 2 go missing.
  ASSERT_TRUE(lb.rig->server->inject(sim::fault::next(sim::fault::disconnect("outputs"), 20)).ok());
  ASSERT_TRUE(eventually([&] { return observer.recovered.load() == 1; }));
  const auto stats = d.stats();
  const auto mismatches = stats.wkc_mismatch_count - before.wkc_mismatch_count;
  const auto timeouts = stats.timeout_count - before.timeout_count;
  if (timeouts == 0) {
    EXPECT_EQ(mismatches, 20u);
  } else {
    // A starved machine: some replies came too late and counted as timeouts instead.
    EXPECT_LE(mismatches, 20u);
    EXPECT_GE(mismatches + timeouts, 20u);
  }
  EXPECT_EQ(stats.total_miss_count, stats.timeout_count + stats.expired_count +
                                        stats.overrun_count + stats.link_error_count);
  ASSERT_TRUE(stats.last_invalid.has_value());
  EXPECT_EQ(*stats.last_invalid, (CycleInvalid{InvalidReason::wkc_mismatch, 3, 1, 0}));
  EXPECT_GT(stats.valid_count, before.valid_count);
  EXPECT_TRUE(stats.health.healthy);
  EXPECT_EQ(stats.invalid_streak, 0u);
  std::lock_guard lock(observer.mutex);
  ASSERT_EQ(observer.degraded.size(), 1u);
  EXPECT_EQ(observer.degraded.front(), (CycleInvalid{InvalidReason::wkc_mismatch, 3, 1, 0}));
  EXPECT_EQ(observer.stopped.size(), 0u);
  EXPECT_EQ(d.state(), DomainState::cycling);
}

// An observer may stop the domain from the bus thread; the other control calls are refused there.
class StoppingObserver : public DomainObserver {
 public:
  void on_cycle_degraded(Domain& domain, const CycleInvalid&) override {
    auto refused = domain.update_period(2ms);
    if (!refused.ok() && refused.error().code() == Errc::wrong_state) {
      refused_message = refused.error().message();
    }
    stopped_ok = domain.stop_cycling().ok();
    called.store(true);
  }
  std::atomic<bool> called{false};
  bool stopped_ok = false;
  std::string refused_message;
};

TEST(DomainCycleTest, ObserverMayStopButNotReconfigure) {
  StoppingObserver observer;
  Loopback lb(config(), &observer);
  ASSERT_TRUE(lb.ok());
  ASSERT_TRUE(eventually([&] { return lb.domain->stats().valid_count > 5; }));
  ASSERT_TRUE(lb.rig->server->inject(sim::fault::disconnect("inputs")).ok());
  ASSERT_TRUE(eventually([&] { return observer.called.load(); }));
  EXPECT_TRUE(observer.stopped_ok);
  EXPECT_EQ(observer.refused_message,
            "domain \"main\": update_period() called on the bus thread (from an observer or a "
            "completion); post it to the control thread");
  EXPECT_EQ(lb.domain->state(), DomainState::stopped);
  EXPECT_EQ(lb.domain->cycle_period(), kPeriod);
  lb.rig->server->clear_faults();
}

TEST(DomainCycleTest, UpdatePeriodIsLive) {
  Loopback lb;
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  ASSERT_TRUE(eventually([&] { return d.stats().valid_count > 5; }));

  auto bad = d.update_period(20us);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(), "domain \"main\": period 20 us is below the 50 us minimum");
  EXPECT_EQ(d.cycle_period(), kPeriod);

  const auto slow = 4 * kPeriod;  // 4 ms
  ASSERT_TRUE(d.update_period(slow).ok());
  EXPECT_EQ(d.cycle_period(), slow);
  EXPECT_EQ(d.stale_after(), 3 * slow);
  EXPECT_EQ(d.realtime_budget(), slow * 9 / 10);
  EXPECT_EQ(lb.cycler->base_period(), slow);
  // Over 200 ms: the domain's cycles plus the deadlines a late bus thread skipped make the
  // nominal count; the domain never runs faster than its period.
  const auto count = [&] {
    return std::pair{d.stats().cycle_count, lb.cycler->stats().deadlines_skipped};
  };
  auto before = count();
  std::this_thread::sleep_for(200ms * kSlow);
  auto now = count();
  auto cycles = now.first - before.first;
  EXPECT_GE(cycles + (now.second - before.second), 45u);  // 50 nominal
  EXPECT_LE(cycles, 52u);

  const auto fast = kPeriod / 4;  // 250 us: not a whole millisecond
  ASSERT_TRUE(d.update_period(fast).ok());
  EXPECT_EQ(d.stale_after(), 3 * fast);
  EXPECT_EQ(d.realtime_budget(), std::max<std::chrono::nanoseconds>(fast * 9 / 10, 200us));
  EXPECT_EQ(lb.cycler->base_period(), fast);
  before = count();
  std::this_thread::sleep_for(200ms * kSlow);
  now = count();
  cycles = now.first - before.first;
  EXPECT_GE(cycles + (now.second - before.second), 720u);  // 800 nominal
  EXPECT_LE(cycles, 805u);
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 0}, Bytes{0x11}).ok());
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 1}, Bytes{0x22}).ok());
  EXPECT_TRUE(lb.inputs_become({0x11, 0x22}));
}

// The limits a user sets are kept, and the errors name them; without them a domain grows with
// its registrations up to the built-in ceilings, which the errors name instead.
TEST(DomainStateTest, ConfiguredAndBuiltInLimits) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto c = config();
  c.max_image_size = 2035;
  c.max_registrations = 3;
  auto limited = make_domain(*rig->bus, c);
  ASSERT_TRUE(limited);
  auto big = limited->register_pdo({kInputs2, 0}, 2036, PdoDirection::input);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().code(), Errc::out_of_range);
  EXPECT_EQ(big.error().message(),
            "domain \"main\": cannot register station 0x1004 SM0: image_too_large: 0 + 2036 bytes "
            "exceeds the 2035 byte maximum (max_image_size)");
  for (std::uint8_t sm = 0; sm < 3; ++sm)
    ASSERT_TRUE(limited->register_pdo({kInputs2, sm}, 1, PdoDirection::input).ok());
  auto fourth = limited->register_pdo({kInputs2, 3}, 1, PdoDirection::input);
  ASSERT_FALSE(fourth.ok());
  EXPECT_EQ(fourth.error().message(),
            "domain \"main\": cannot register station 0x1004 SM3: all 3 registrations "
            "(max_registrations) used");

  auto grows = make_domain(*rig->bus, config());
  ASSERT_TRUE(grows);
  // 1000 registrations (four blocks of entries) and an image of 1000 x 3 bytes: far beyond the
  // reference's fixed 256 registrations and 2035 bytes.
  for (std::uint16_t i = 0; i < 1000; ++i) {
    auto r = grows->register_pdo(
        {static_cast<std::uint16_t>(0x2000 + i / 16), static_cast<std::uint8_t>(i % 16)}, 3,
        i % 2 == 0 ? PdoDirection::input : PdoDirection::output);
    ASSERT_TRUE(r.ok()) << r.error().message();
    EXPECT_EQ(*r, 0x00010000u + 3u * i);
  }
  EXPECT_EQ(grows->info().image_size, 3000u);
  // Outputs staged while the image grew are kept.
  const std::vector<std::uint8_t> staged{1, 2, 3};
  ASSERT_TRUE(grows->write(PdoKey{0x2000, 1}, staged).ok());
  ASSERT_TRUE(grows->register_pdo({0x3000, 0}, 5000, PdoDirection::input).ok());
  std::vector<std::uint8_t> back(3);
  ASSERT_TRUE(grows->read(PdoKey{0x2000, 1}, back).ok());
  EXPECT_EQ(back, (std::vector<std::uint8_t>{1, 2, 3}));
  auto ceiling = grows->register_pdo({0x3000, 1}, 65535, PdoDirection::input);
  ASSERT_TRUE(ceiling.ok());
  for (std::uint8_t sm = 2; sm < 16; ++sm) {
    auto r = grows->register_pdo({0x3000, sm}, 65535, PdoDirection::input);
    if (!r) {
      EXPECT_NE(r.error().message().find("the largest image a domain sizes itself to"),
                std::string::npos)
          << r.error().message();
      break;
    }
    ASSERT_LE(grows->info().image_size, kAutoImageLimit);
  }
}

TEST(DomainCycleTest, ImageLargerThanOneFrame) {
  auto c = config();
  c.max_image_size = 4096;
  // 3000 bytes nobody maps (no FMMU: WKC 0), then the loopback behind it in the third frame.
  Loopback lb(c, nullptr, [](Domain& d) {
    ASSERT_TRUE(d.register_pdo({0xFFFF, 0}, 3000, PdoDirection::output, false).ok());
  });
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  const auto info = d.info();
  EXPECT_EQ(info.image_size, 3004u);
  ASSERT_EQ(info.datagrams.size(), 3u);
  EXPECT_EQ(info.datagrams[0].length, 1486u);
  EXPECT_EQ(info.datagrams[1].length, 1486u);
  EXPECT_EQ(info.datagrams[2].offset, 2972u);
  EXPECT_EQ(info.datagrams[2].length, 32u);
  EXPECT_EQ(info.datagrams[0].expected_wkc, 0u);
  EXPECT_EQ(info.datagrams[1].expected_wkc, 0u);
  EXPECT_EQ(info.datagrams[2].expected_wkc, 3u);

  ASSERT_TRUE(d.write(PdoKey{kOutputs, 0}, Bytes{0x0F}).ok());
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 1}, Bytes{0xF0}).ok());
  ASSERT_TRUE(lb.inputs_become({0x0F, 0xF0}));
  EXPECT_EQ(d.stats().last_wkc, 3u);
  EXPECT_EQ(d.stats().wkc_mismatch_count, 0u);

  // Three frames per exchange that went out. Counted over a window closed by stopping and letting
  // every exchange complete: cycles that found no free exchange or expired before they could be
  // sent (a slow machine) send nothing, every other one exactly three frames.
  const auto before = d.stats();
  const auto frames_before = lb.rig->bus->stats().realtime_frames_sent;
  std::this_thread::sleep_for(50ms * kSlow);
  ASSERT_TRUE(d.stop_cycling().ok());
  std::this_thread::sleep_for(100ms * kSlow);  // > the 20 ms frame timeout
  const auto after = d.stats();
  const auto frames = lb.rig->bus->stats().realtime_frames_sent - frames_before;
  const auto sent = (after.cycle_count - before.cycle_count) -
                    (after.overrun_count - before.overrun_count) -
                    (after.expired_count - before.expired_count) -
                    (after.link_error_count - before.link_error_count);
  EXPECT_GT(sent, 5u);
  EXPECT_EQ(frames, 3 * sent);
}

TEST(DomainCycleTest, OneByteDatagramsCountWkcPerDatagram) {
  auto c = config();
  c.max_datagram_size = 1;
  Loopback lb(c);
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  const auto layout = d.layout();
  ASSERT_EQ(layout.size(), 4u);  // out SM0, out SM1, in byte 0, in byte 1
  EXPECT_EQ(layout[0].expected_wkc, 2u);
  EXPECT_EQ(layout[1].expected_wkc, 2u);
  EXPECT_EQ(layout[2].expected_wkc, 1u);
  EXPECT_EQ(layout[3].expected_wkc, 1u);
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 0}, Bytes{0x81}).ok());
  ASSERT_TRUE(d.write(PdoKey{kOutputs, 1}, Bytes{0x18}).ok());
  ASSERT_TRUE(lb.inputs_become({0x81, 0x18}));
  EXPECT_EQ(d.stats().last_wkc, 6u);
}

TEST(DomainCycleTest, ConcurrentWritersAndReaders) {
  Loopback lb;
  ASSERT_TRUE(lb.ok());
  auto& d = *lb.domain;
  const auto out0 = d.find({kOutputs, 0});
  const auto out1 = d.find({kOutputs, 1});
  const auto in = d.find({kInputs, 0});
  ASSERT_TRUE(out0.ok() && out1.ok() && in.ok());
  std::atomic<bool> stop{false};
  std::atomic<int> errors{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] {
      std::uint8_t v = 0;
      while (!stop.load()) {
        // Bursts, then a pause: contention without starving the simulator's thread.
        for (int i = 0; i < 200; ++i) {
          const std::array<std::uint8_t, 1> b{v++};
          if (!d.write(t == 0 ? *out0 : *out1, b).ok()) errors.fetch_add(1);
        }
        std::this_thread::sleep_for(50us);
      }
    });
  }
  threads.emplace_back([&] {
    std::array<std::uint8_t, 2> b{};
    while (!stop.load()) {
      for (int i = 0; i < 200; ++i) {
        auto r = d.read(*in, b);
        if (!r.ok() && r.error().code() != Errc::not_ready) errors.fetch_add(1);
      }
      std::this_thread::sleep_for(50us);
    }
  });
  const auto valid_before = d.stats().valid_count;
  std::this_thread::sleep_for(100ms * kSlow);
  stop.store(true);
  for (auto& t : threads)
    t.join();
  EXPECT_EQ(errors.load(), 0);
  const auto s = d.stats();
  EXPECT_GT(s.valid_count, valid_before);
  std::printf(
      "cycles %llu, valid %llu (during the writers: %llu), sent with previous outputs "
      "(writer held the lock) %llu, misses %llu\n",
      static_cast<unsigned long long>(s.cycle_count),
      static_cast<unsigned long long>(s.valid_count),
      static_cast<unsigned long long>(s.valid_count - valid_before),
      static_cast<unsigned long long>(s.output_stage_skips),
      static_cast<unsigned long long>(s.total_miss_count));
  // The writers stop; the last values come through.
  ASSERT_TRUE(d.write(*out0, Bytes{0x42}).ok());
  ASSERT_TRUE(d.write(*out1, Bytes{0x24}).ok());
  EXPECT_TRUE(lb.inputs_become({0x42, 0x24}));
}

}  // namespace
}  // namespace ecat::master::test
