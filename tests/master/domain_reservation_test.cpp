// Domain reservations (hot connect, domain.hpp): room kept while open, registrations made in it
// while cycling, the working counter share accepted while joining and expected while present, a
// vanished share leaving the others' cycle valid, inputs stale while absent.
#include <atomic>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/sim/faults.hpp>

#include "master/domain_test_support.hpp"

namespace ecat::master::test {
namespace {

using Reservation = Domain::ReservationState;

class LostObserver : public DomainObserver {
 public:
  void on_reservation_lost(Domain&, std::uint32_t reservation) override {
    last.store(reservation);
    lost.fetch_add(1);
  }
  std::atomic<int> lost{0};
  std::atomic<std::uint32_t> last{0xFFFF};
};

// The domain the cycling tests use: "main", the rig's period, at logical 0x00010000.
std::unique_ptr<Domain> make_main_domain(Rig& rig, DomainObserver* observer = nullptr) {
  DomainConfig c;
  c.id = "main";
  c.period = kPeriod;
  c.logical_base = 0x00010000;
  auto created = Domain::create(*rig.bus, c, observer);
  EXPECT_TRUE(created.ok()) << created.error().describe();
  return created.ok() ? std::move(*created) : nullptr;
}

// Starts `d` cycling on `cycler` and takes every slave to OP; true once cycles come back valid.
bool cycle_in_op(Rig& rig, Cycler& cycler, Domain& d) {
  if (!cycler.add(d).ok() || !cycler.start().ok() || !d.start_cycling().ok()) return false;
  rig.all_to(wire::AlState::safeop);
  rig.all_to(wire::AlState::op);
  return eventually([&] { return d.stats().valid_count > 5; });
}

TEST(DomainReservation, JoinsWhileCyclingAndAVanishedShareLeavesTheOthersValid) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  LostObserver observer;
  auto domain = make_main_domain(*rig, &observer);
  ASSERT_TRUE(domain);
  auto& d = *domain;
  auto r = d.reserve("group", 16, {kInputs2});
  ASSERT_TRUE(r.ok()) << r.error().describe();
  const std::uint32_t group = *r;
  EXPECT_FALSE(d.reserve("again", 8, {kInputs2}).ok());  // a station belongs to one reservation
  rig->attach(d, kOutputs);
  rig->attach(d, kInputs);
  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycle_in_op(*rig, cycler, d));
  const auto mismatches = d.stats().wkc_mismatch_count;
  const auto layout = d.layout();

  // Registration outside a reservation is closed once cycling; inside it is open.
  auto refused = d.register_pdo({0x1777, 0}, 2, PdoDirection::input);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::wrong_state);
  ASSERT_TRUE(d.set_reservation_state(group, Reservation::joining).ok());
  rig->attach(d, kInputs2);  // registered in the room, mapped: its share appears in some cycle
  EXPECT_EQ(d.reservation_used(group), 2u);
  EXPECT_EQ(d.layout().size(), layout.size());  // nothing moved
  EXPECT_EQ(d.layout().front().logical, layout.front().logical);
  std::array<std::uint8_t, 2> buffer{};
  auto early = d.read_fresh(PdoKey{kInputs2, 0}, buffer);
  ASSERT_FALSE(early.ok());
  EXPECT_EQ(early.error().code(), Errc::stale);
  EXPECT_NE(early.error().message().find("group"), std::string::npos) << early.error().describe();
  ASSERT_TRUE(d.set_reservation_state(group, Reservation::present).ok());
  EXPECT_TRUE(eventually([&] { return d.read_fresh(PdoKey{kInputs2, 0}, buffer).ok(); }));
  const auto valid = d.stats().valid_count;
  EXPECT_TRUE(eventually([&] { return d.stats().valid_count > valid + 5; }));
  EXPECT_EQ(d.stats().wkc_mismatch_count, mismatches);

  // The reservation's slave vanishes: the cycle is still valid for the others, the reservation
  // absent, the observer told.
  ASSERT_TRUE(rig->server->inject(sim::fault::disconnect("inputs2")).ok());
  ASSERT_TRUE(eventually([&] { return observer.lost.load() == 1; }));
  EXPECT_EQ(observer.last.load(), group);
  EXPECT_EQ(d.reservation_state(group), Reservation::absent);
  EXPECT_EQ(d.reservations_lost(), 1u);
  // The bus thread's change is a drawn one, and the master's confirmation after it too.
  EXPECT_EQ(d.stats().refused_reservation_transitions, 0u);
  ASSERT_TRUE(d.set_reservation_state(group, Reservation::absent).ok());
  EXPECT_EQ(d.stats().refused_reservation_transitions, 0u);
  const auto after_loss = d.stats().valid_count;
  EXPECT_TRUE(eventually([&] { return d.stats().valid_count > after_loss + 5; }));
  EXPECT_EQ(d.stats().wkc_mismatch_count, mismatches);
  auto stale = d.read_fresh(PdoKey{kInputs2, 0}, buffer);
  ASSERT_FALSE(stale.ok());
  EXPECT_EQ(stale.error().code(), Errc::stale);
  EXPECT_TRUE(d.read_fresh(PdoKey{kInputs, 0}, buffer).ok());  // the others are fresh

  // More than the room: refused, naming the reservation.
  auto too_big = d.register_pdo({kInputs2, 5}, 15, PdoDirection::input);
  ASSERT_FALSE(too_big.ok());
  EXPECT_EQ(too_big.error().code(), Errc::out_of_range);
  EXPECT_NE(too_big.error().message().find("16 bytes reserved for group"), std::string::npos)
      << too_big.error().describe();
  (void)cycler.stop();
}

// A joining group's slaves switch their shares on one at a time (each slave's SyncManagers and
// FMMUs are configured in its own walk; on many real slaves an output's write counts only from OP):
// every part of the share on the way is a valid cycle, not a mismatch. Once present, the whole
// share is expected. The group here is an output slave (a write: 2) and an input slave (a read: 1).
TEST(DomainReservation, EveryPartOfAJoiningShareIsValid) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  auto domain = make_main_domain(*rig);
  ASSERT_TRUE(domain);
  auto& d = *domain;
  auto r = d.reserve("group", 16, {kOutputs, kInputs2});
  ASSERT_TRUE(r.ok()) << r.error().describe();
  const std::uint32_t group = *r;
  rig->attach(d, kInputs);
  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycle_in_op(*rig, cycler, d));
  const auto mismatches = d.stats().wkc_mismatch_count;
  const auto settle = [&] {
    const auto valid = d.stats().valid_count;
    return eventually([&] { return d.stats().valid_count > valid + 5; });
  };

  // A slave's FMMUs on or off (byte 12 of an FMMU is its activate register): its share counts or
  // not, while its registrations stay.
  const auto fmmus = [&](std::uint16_t station, bool on) {
    for (std::uint8_t n = 0; n < rig->next_fmmu[position_of(station)]; ++n) {
      rig->write(station, static_cast<std::uint16_t>(wire::reg::fmmu(n) + 12),
                 {static_cast<std::uint8_t>(on ? 1 : 0)});
    }
  };

  ASSERT_TRUE(d.set_reservation_state(group, Reservation::joining).ok());
  rig->attach(d, kOutputs);
  rig->attach(d, kInputs2);
  fmmus(kOutputs, false);
  fmmus(kInputs2, false);
  EXPECT_TRUE(settle());  // the whole share registered, none of it counted
  fmmus(kInputs2, true);
  EXPECT_TRUE(settle());  // the input slave's read: 1 of the share's 3
  fmmus(kInputs2, false);
  fmmus(kOutputs, true);
  EXPECT_TRUE(settle());  // the output slave's write: 2 of 3
  fmmus(kInputs2, true);
  EXPECT_TRUE(settle());  // the whole share
  EXPECT_EQ(d.stats().wkc_mismatch_count, mismatches);
  ASSERT_TRUE(d.set_reservation_state(group, Reservation::present).ok());
  EXPECT_TRUE(settle());
  EXPECT_EQ(d.stats().wkc_mismatch_count, mismatches);

  // Present, the whole share is expected: the output slave's write gone leaves the cycle short of
  // part of the share, neither the whole share nor none of it: a mismatch, and the reservation
  // stays present.
  fmmus(kOutputs, false);
  EXPECT_TRUE(eventually([&] { return d.stats().wkc_mismatch_count > mismatches; }));
  EXPECT_EQ(d.reservation_state(group), Reservation::present);
  (void)cycler.stop();
}

TEST(DomainReservation, ReservingIsForAnOpenDomainAndNamesWhatIsWrong) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  DomainConfig c;
  c.id = "main";
  c.period = kPeriod;
  c.max_image_size = 32;
  auto created = Domain::create(*rig->bus, c);
  ASSERT_TRUE(created.ok());
  auto& d = **created;
  auto zero = d.reserve("g", 0, {kInputs2});
  ASSERT_FALSE(zero.ok());
  EXPECT_NE(zero.error().message().find("outside 1..65535"), std::string::npos);
  auto big = d.reserve("g", 64, {kInputs2});
  ASSERT_FALSE(big.ok());
  EXPECT_NE(big.error().message().find("image_too_large"), std::string::npos)
      << big.error().describe();
  auto station0 = d.reserve("g", 8, {0});
  ASSERT_FALSE(station0.ok());
  rig->attach(d, kInputs);
  auto taken = d.reserve("g", 8, {kInputs});
  ASSERT_FALSE(taken.ok());
  EXPECT_NE(taken.error().message().find("registrations outside it"), std::string::npos);
  ASSERT_TRUE(d.reserve("g", 8, {kInputs2}).ok());
  bool listed = false;
  for (const auto& reg : d.registrations())
    listed |= reg.key.kind == RegistrationKind::reserved && reg.size == 8;
  EXPECT_TRUE(listed);
  EXPECT_FALSE(d.set_reservation_state(7, Reservation::present).ok());
}

TEST(DomainReservation, OnlyTheDrawnChangesHappenAndUndrawnOnesAreCounted) {
  // The diagram: into present only from joining, out of it only to absent.
  const auto table = Domain::reservation_transitions();
  ASSERT_FALSE(table.empty());
  for (const auto& t : table) {
    EXPECT_TRUE(Domain::reservation_transition_allowed(t.from, t.to));
    EXPECT_FALSE(t.label.empty());
    if (t.to == Reservation::present) {
      EXPECT_EQ(t.from, Reservation::joining);
    }
    if (t.from == Reservation::present) {
      EXPECT_EQ(t.to, Reservation::absent);
    }
  }
  EXPECT_TRUE(Domain::reservation_transition_allowed(Reservation::present, Reservation::absent));
  EXPECT_FALSE(Domain::reservation_transition_allowed(Reservation::absent, Reservation::present));
  EXPECT_FALSE(Domain::reservation_transition_allowed(Reservation::present, Reservation::joining));
  EXPECT_FALSE(Domain::reservation_transition_allowed(Reservation::joining, Reservation::joining));
  EXPECT_FALSE(Domain::reservation_transition_allowed(Reservation::present, Reservation::present));

  auto rig = make_rig();
  ASSERT_TRUE(rig);
  DomainConfig c;
  c.id = "main";
  c.period = kPeriod;
  auto created = Domain::create(*rig->bus, c);
  ASSERT_TRUE(created.ok());
  auto& d = **created;
  auto r = d.reserve("tool", 8, {kInputs2});
  ASSERT_TRUE(r.ok()) << r.error().describe();
  const std::uint32_t g = *r;
  EXPECT_EQ(d.reservation_state(g), Reservation::absent);

  // Straight to present: refused, named, counted, and nothing changes.
  auto skip = d.set_reservation_state(g, Reservation::present);
  ASSERT_FALSE(skip.ok());
  EXPECT_EQ(skip.error().code(), Errc::wrong_state);
  EXPECT_NE(skip.error().message().find("tool"), std::string::npos) << skip.error().describe();
  EXPECT_NE(skip.error().message().find("absent -> present"), std::string::npos)
      << skip.error().describe();
  EXPECT_EQ(d.reservation_state(g), Reservation::absent);
  EXPECT_EQ(d.stats().refused_reservation_transitions, 1u);

  ASSERT_TRUE(d.set_reservation_state(g, Reservation::joining).ok());
  EXPECT_FALSE(d.set_reservation_state(g, Reservation::joining).ok());
  ASSERT_TRUE(d.set_reservation_state(g, Reservation::present).ok());
  EXPECT_FALSE(d.set_reservation_state(g, Reservation::joining).ok());
  EXPECT_FALSE(d.set_reservation_state(g, Reservation::present).ok());
  EXPECT_EQ(d.reservation_state(g), Reservation::present);
  EXPECT_EQ(d.stats().refused_reservation_transitions, 4u);
  ASSERT_TRUE(d.set_reservation_state(g, Reservation::absent).ok());
  ASSERT_TRUE(d.set_reservation_state(g, Reservation::absent).ok());
  ASSERT_TRUE(d.set_reservation_state(g, Reservation::joining).ok());
  ASSERT_TRUE(d.set_reservation_state(g, Reservation::absent).ok());  // a failed join
  EXPECT_EQ(d.stats().refused_reservation_transitions, 4u);
  EXPECT_EQ(to_string(Reservation::joining), "joining");
}

}  // namespace
}  // namespace ecat::master::test
