// The PREOP configuration plan without I/O: facts (SII images of the simulator's devices, ESC and
// domain facts made up here) and a slave's configuration in, SDOs, layout, registrations and
// register writes out. Digital input and output terminals, a CiA 402 drive with its PDO
// assignment from the configuration and from CoE, a slave without process data, and the
// configurations that cannot work, each refused before anything would be written.
#include "master/preop_plan.hpp"

#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/drivers/builtin.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master::detail {
namespace {

wire::SiiImage profile_sii(const std::string& profile) {
  sim::DeviceConfig config;
  config.profile = profile;
  auto esc = sim::make_device(config);
  EXPECT_TRUE(esc.ok()) << (esc.ok() ? "" : esc.error().describe());
  if (!esc.ok()) return {};
  auto decoded = wire::decode_sii((*esc)->eeprom());
  EXPECT_TRUE(decoded.ok());
  return decoded.ok() ? decoded->image : wire::SiiImage{};
}

PreopFacts facts_for(const std::string& profile, std::vector<std::string> domains = {"main"}) {
  PreopFacts facts;
  facts.who = "slave dut (station 0x1001)";
  facts.sii = profile_sii(profile);
  facts.fmmu_count = 8;
  facts.has_mailbox = facts.sii.standard_mailbox.present();
  for (auto& id : domains)
    facts.domains.push_back({std::move(id), {}, {}});
  return facts;
}

std::shared_ptr<const Driver> driver_for(const PreopFacts& facts, const SlaveConfig& config) {
  static const DriverRegistry registry = drivers::builtin_registry();
  auto chosen = choose_driver(registry, config, facts.sii.identity, facts.who);
  EXPECT_TRUE(chosen.ok()) << (chosen.ok() ? "" : chosen.error().describe());
  return chosen.ok() ? *chosen : nullptr;
}

struct Planned {
  LayoutPlan layout;
  ProcessDataPlan process_data;
};

// Both planning steps, for configurations that do not read the layout from CoE.
Result<Planned> plan(const PreopFacts& facts, const SlaveConfig& config) {
  auto driver = driver_for(facts, config);
  if (!driver) return Error(Errc::not_found, "no driver");
  auto layout = plan_layout(facts, config, *driver);
  if (!layout) return layout.error();
  auto process_data = plan_process_data(facts, config, *driver, *layout);
  if (!process_data) return process_data.error();
  return Planned{std::move(*layout), std::move(*process_data)};
}

// What the domains would hand out: consecutive logical addresses from `base`.
void register_all(ProcessDataPlan& plan, std::uint32_t base = 0x10000) {
  for (const auto i : plan.new_registrations) {
    plan.attachments[i].logical_address = base;
    base += plan.attachments[i].size;
  }
}

wire::SyncManagerConfig decode_sm(const RegisterWrite& write) {
  auto sm = wire::SyncManagerConfig::decode(write.data);
  EXPECT_TRUE(sm.ok());
  return sm.ok() ? *sm : wire::SyncManagerConfig{};
}

wire::FmmuConfig decode_fmmu(const RegisterWrite& write) {
  auto fmmu = wire::FmmuConfig::decode(write.data);
  EXPECT_TRUE(fmmu.ok());
  return fmmu.ok() ? *fmmu : wire::FmmuConfig{};
}

std::vector<std::pair<std::uint16_t, std::uint8_t>> addresses(const std::vector<SdoWrite>& sdos) {
  std::vector<std::pair<std::uint16_t, std::uint8_t>> out;
  for (const auto& s : sdos)
    out.emplace_back(s.index, s.subindex);
  return out;
}

SdoWrite u16_sdo(std::uint16_t index, std::uint8_t subindex, std::uint16_t value) {
  return {index,
          subindex,
          {static_cast<std::uint8_t>(value), static_cast<std::uint8_t>(value >> 8)},
          false};
}

// ---- digital terminals --------------------------------------------------------------------------

TEST(PreopPlan, DigitalInputTerminalMapsItsInputSyncManagerWithOneReadFmmu) {
  const auto facts = facts_for("EL1809");
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  EXPECT_TRUE(planned->layout.sdos.empty());  // no mailbox, nothing to download
  EXPECT_FALSE(planned->layout.read_from_coe);
  auto& pd = planned->process_data;
  EXPECT_TRUE(pd.sdos.empty());
  ASSERT_EQ(pd.signals.size(), 16u);
  EXPECT_EQ(pd.signals.front().name, "channel_1");
  EXPECT_EQ(pd.signals.back().name, "channel_16");

  ASSERT_EQ(pd.attachments.size(), 1u);
  const auto& a = pd.attachments[0];
  EXPECT_EQ(a.sync_manager, 0);
  EXPECT_EQ(a.direction, PdoDirection::input);
  EXPECT_EQ(a.domain, "main");
  EXPECT_EQ(a.physical_address, 0x1000);
  EXPECT_EQ(a.size, 2);
  EXPECT_EQ(a.fmmu, 0);
  EXPECT_EQ(pd.new_registrations, std::vector<std::size_t>{0});
  ASSERT_EQ(pd.room.size(), 1u);
  EXPECT_EQ(pd.room[0].domain, "main");
  EXPECT_EQ(pd.room[0].count, 1u);
  EXPECT_EQ(pd.room[0].bytes, 2u);

  register_all(pd);
  const auto writes = process_data_writes(pd);
  ASSERT_EQ(writes.size(), 3u);
  // SM0 deactivated, then configured (and activated), then the FMMU.
  EXPECT_EQ(writes[0], (RegisterWrite{0x0806, {0}}));
  EXPECT_EQ(writes[1].address, 0x0800);
  const auto sm = decode_sm(writes[1]);
  EXPECT_EQ(sm.physical_start, 0x1000);
  EXPECT_EQ(sm.length, 2);
  EXPECT_EQ(sm.control.mode, wire::SmMode::buffered);
  EXPECT_EQ(sm.control.direction, wire::SmDirection::read);
  EXPECT_TRUE(sm.activate.enable);
  EXPECT_EQ(writes[2].address, 0x0600);
  const auto fmmu = decode_fmmu(writes[2]);
  EXPECT_EQ(fmmu.logical_start, 0x10000u);
  EXPECT_EQ(fmmu.length, 2);
  EXPECT_EQ(fmmu.physical_start, 0x1000);
  EXPECT_EQ(fmmu.type, wire::FmmuType::read);
  EXPECT_TRUE(fmmu.active);
}

TEST(PreopPlan, DigitalOutputTerminalGetsOneWriteFmmuPerSyncManager) {
  const auto facts = facts_for("EL2809");
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  auto& pd = planned->process_data;
  ASSERT_EQ(pd.attachments.size(), 2u);
  for (std::uint8_t i = 0; i < 2; ++i) {
    EXPECT_EQ(pd.attachments[i].sync_manager, i);
    EXPECT_EQ(pd.attachments[i].direction, PdoDirection::output);
    EXPECT_EQ(pd.attachments[i].physical_address, 0x0F00 + i);
    EXPECT_EQ(pd.attachments[i].size, 1);
    EXPECT_EQ(pd.attachments[i].fmmu, i);
  }
  ASSERT_EQ(pd.room.size(), 1u);
  EXPECT_EQ(pd.room[0].count, 2u);
  EXPECT_EQ(pd.room[0].bytes, 2u);

  register_all(pd, 0x200);
  const auto writes = process_data_writes(pd);
  std::vector<std::uint16_t> order;
  for (const auto& w : writes)
    order.push_back(w.address);
  EXPECT_EQ(order, (std::vector<std::uint16_t>{0x0806, 0x0800, 0x0600, 0x080E, 0x0808, 0x0610}));
  // The SII's control byte (buffered, ECAT writes, watchdog) is kept.
  const auto sm1 = decode_sm(writes[4]);
  EXPECT_EQ(sm1.physical_start, 0x0F01);
  EXPECT_EQ(sm1.control.direction, wire::SmDirection::write);
  EXPECT_TRUE(sm1.control.watchdog);
  const auto fmmu1 = decode_fmmu(writes[5]);
  EXPECT_EQ(fmmu1.logical_start, 0x201u);
  EXPECT_EQ(fmmu1.type, wire::FmmuType::write);
}

TEST(PreopPlan, SyncManagerRoutedNowhereIsStillConfiguredWithoutFmmu) {
  // Only channel 1 (SM0) goes to a domain; SM1 still has assigned PDOs, which the slave checks
  // on its way to SAFEOP.
  const auto facts = facts_for("EL2809", {"fast"});
  SlaveConfig config;
  config.name = "dut";
  config.process_data.kind = ProcessDataRequest::Kind::signals;
  config.process_data.routes = {{"channel_1", "fast"}};

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  auto& pd = planned->process_data;
  ASSERT_EQ(pd.attachments.size(), 1u);
  EXPECT_EQ(pd.attachments[0].domain, "fast");
  ASSERT_EQ(pd.sync_managers.size(), 2u);
  EXPECT_EQ(pd.sync_managers[0].sync_manager, 0);
  EXPECT_TRUE(pd.sync_managers[0].config.control.watchdog);
  EXPECT_EQ(pd.sync_managers[1].sync_manager, 1);
  EXPECT_TRUE(pd.sync_managers[1].config.activate.enable);
  // Nothing writes it: its watchdog trigger is off, or the slave would leave OP one watchdog
  // time after reaching it.
  EXPECT_FALSE(pd.sync_managers[1].config.control.watchdog);
  register_all(pd);
  const auto writes = process_data_writes(pd);
  std::vector<std::uint16_t> order;
  for (const auto& w : writes)
    order.push_back(w.address);
  EXPECT_EQ(order, (std::vector<std::uint16_t>{0x0806, 0x0800, 0x0600, 0x080E, 0x0808}));
}

// The process-data watchdog against the period of the domain writing the outputs: left as the
// ESC has it (100 ms) while three periods fit, raised to three periods beyond; a configured one is
// written as it is, 0 turns it off, and one not longer than the period is refused.
TEST(PreopPlan, WatchdogCoversThreePeriodsOfTheDomainWritingTheOutputs) {
  auto facts = facts_for("EL2809", {"slow"});
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("slow");
  const auto planned_with = [&](std::chrono::nanoseconds period,
                                std::optional<std::chrono::nanoseconds> watchdog) {
    facts.domains[0].period = period;
    config.watchdog = watchdog;
    return plan(facts, config);
  };
  auto fast = planned_with(std::chrono::milliseconds(10), std::nullopt);
  ASSERT_TRUE(fast.ok()) << fast.error().describe();
  EXPECT_FALSE(fast->process_data.watchdog);
  auto slow = planned_with(std::chrono::milliseconds(50), std::nullopt);
  ASSERT_TRUE(slow.ok()) << slow.error().describe();
  ASSERT_TRUE(slow->process_data.watchdog);
  EXPECT_EQ(slow->process_data.watchdog->time(), std::chrono::milliseconds(150));
  register_all(slow->process_data);
  const auto writes = process_data_writes(slow->process_data);
  ASSERT_GE(writes.size(), 2u);
  EXPECT_EQ(writes[0], (RegisterWrite{0x0400, {0xC2, 0x09}}));  // 2498: 100 us ticks
  EXPECT_EQ(writes[1], (RegisterWrite{0x0420, {0xDC, 0x05}}));  // 1500 ticks

  auto off = planned_with(std::chrono::milliseconds(50), std::chrono::nanoseconds(0));
  ASSERT_TRUE(off.ok()) << off.error().describe();
  ASSERT_TRUE(off->process_data.watchdog);
  EXPECT_TRUE(off->process_data.watchdog->off());
  auto set = planned_with(std::chrono::milliseconds(1), std::chrono::microseconds(2500));
  ASSERT_TRUE(set.ok()) << set.error().describe();
  ASSERT_TRUE(set->process_data.watchdog);
  EXPECT_EQ(set->process_data.watchdog->ticks, 25);

  auto too_short = planned_with(std::chrono::milliseconds(10), std::chrono::milliseconds(10));
  ASSERT_FALSE(too_short.ok());
  EXPECT_EQ(too_short.error().code(), Errc::invalid_argument);
  EXPECT_NE(too_short.error().message().find("domain \"slow\""), std::string::npos)
      << too_short.error().describe();

  // Inputs only: nothing is written to watch.
  auto inputs = facts_for("EL1809", {"slow"});
  inputs.domains[0].period = std::chrono::milliseconds(500);
  config.watchdog.reset();
  auto in = plan(inputs, config);
  ASSERT_TRUE(in.ok()) << in.error().describe();
  EXPECT_FALSE(in->process_data.watchdog);
}

TEST(PreopPlan, KeptRegistrationIsReusedNotRegisteredAgain) {
  // A rebuilt slave: its SyncManager is still in the domain, at the address it had.
  auto facts = facts_for("EL1809");
  facts.domains[0].registered.push_back(
      {0, 2, PdoDirection::input, 0x4242, RegistrationKind::process_data});
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  const auto& pd = planned->process_data;
  EXPECT_TRUE(pd.new_registrations.empty());
  EXPECT_TRUE(pd.room.empty());
  ASSERT_EQ(pd.attachments.size(), 1u);
  EXPECT_EQ(pd.attachments[0].logical_address, 0x4242u);
  EXPECT_EQ(decode_fmmu(process_data_writes(pd).back()).logical_start, 0x4242u);
}

// ---- a CoE drive -------------------------------------------------------------------------------

CoePdoConfiguration short_drive_mapping() {
  CoePdoConfiguration coe;
  coe.assignments = {{2, {0x1601}, PdoDirection::output}, {3, {0x1A01}, PdoDirection::input}};
  coe.mappings = {
      {0x1601, {coe_mapping_entry(0x6040, 0, 16), coe_mapping_entry(0x607A, 0, 32)}, ""},
      {0x1A01, {coe_mapping_entry(0x6041, 0, 16), coe_mapping_entry(0x6064, 0, 32)}, ""}};
  return coe;
}

TEST(PreopPlan, CoeDriveWithConfiguredAssignmentWritesItAfterTheStartupSdos) {
  const auto facts = facts_for("servo");
  ASSERT_TRUE(facts.has_mailbox);
  SlaveConfig config;
  config.name = "dut";
  config.driver = "cia402";
  config.process_data = ProcessDataRequest::all("main");
  config.startup_sdos = {{0x6060, 0, {8}, false}};
  config.pdo_source = SlaveConfig::PdoSource::configured;
  config.pdo_mapping = short_drive_mapping();

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  const auto& lp = planned->layout;
  EXPECT_FALSE(lp.read_from_coe);
  // The startup SDO, then ETG.1020's order: unassign, remap, assign.
  using A = std::pair<std::uint16_t, std::uint8_t>;
  EXPECT_EQ(addresses(lp.sdos), (std::vector<A>{{0x6060, 0},
                                                {0x1C12, 0},
                                                {0x1C13, 0},
                                                {0x1601, 0},
                                                {0x1601, 1},
                                                {0x1601, 2},
                                                {0x1601, 0},
                                                {0x1A01, 0},
                                                {0x1A01, 1},
                                                {0x1A01, 2},
                                                {0x1A01, 0},
                                                {0x1C12, 1},
                                                {0x1C12, 0},
                                                {0x1C13, 1},
                                                {0x1C13, 0}}));
  EXPECT_EQ(lp.sdos[11], u16_sdo(0x1C12, 1, 0x1601));

  const auto& pd = planned->process_data;
  ASSERT_EQ(pd.layout.sync_managers.size(), 2u);
  EXPECT_EQ(pd.layout.sync_managers[0].byte_length(), 6);
  EXPECT_EQ(pd.layout.sync_managers[1].byte_length(), 6);
  ASSERT_EQ(pd.attachments.size(), 2u);
  EXPECT_EQ(pd.attachments[0].physical_address, 0x1100);
  EXPECT_EQ(pd.attachments[0].size, 6);  // the mapping's length, not the SII's default 13
  EXPECT_EQ(pd.attachments[1].physical_address, 0x1200);
  auto has = [&](std::string_view name) {
    return std::any_of(pd.signals.begin(), pd.signals.end(),
                       [&](const Signal& s) { return s.name == name; });
  };
  EXPECT_TRUE(has("controlword"));
  EXPECT_TRUE(has("statusword"));
}

TEST(PreopPlan, CoeDriveWithLayoutFromCoeReadsAfterTheStartupSdos) {
  const auto facts = facts_for("servo");
  SlaveConfig config;
  config.name = "dut";
  config.driver = "cia402";
  config.process_data = ProcessDataRequest::all("main");
  config.startup_sdos = {u16_sdo(0x1C12, 0, 0)};
  config.pdo_source = SlaveConfig::PdoSource::coe;
  auto driver = driver_for(facts, config);
  ASSERT_NE(driver, nullptr);

  auto lp = plan_layout(facts, config, *driver);
  ASSERT_TRUE(lp.ok()) << lp.error().describe();
  EXPECT_TRUE(lp->read_from_coe);
  EXPECT_EQ(lp->sdos.size(), 1u);
  const auto to_read = coe_assignments_to_read(facts.sii);
  ASSERT_EQ(to_read.size(), 2u);
  EXPECT_EQ(to_read[0].sync_manager, 2);
  EXPECT_EQ(to_read[0].direction, PdoDirection::output);
  EXPECT_EQ(to_read[1].sync_manager, 3);
  EXPECT_EQ(to_read[1].direction, PdoDirection::input);

  // Planning on without what was read is a caller's bug, said as such.
  EXPECT_FALSE(plan_process_data(facts, config, *driver, *lp).ok());
  const auto read = short_drive_mapping();
  auto pd = plan_process_data(facts, config, *driver, *lp, &read);
  ASSERT_TRUE(pd.ok()) << pd.error().describe();
  EXPECT_EQ(pd->layout.sync_managers.size(), 2u);
  EXPECT_EQ(pd->attachments.size(), 2u);
  EXPECT_EQ(pd->attachments[1].size, 6);
}

// ---- no process data ---------------------------------------------------------------------------

TEST(PreopPlan, CouplerWithoutProcessDataPlansNothing) {
  const auto facts = facts_for("EK1100");
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");

  auto planned = plan(facts, config);
  ASSERT_TRUE(planned.ok()) << planned.error().describe();
  EXPECT_TRUE(planned->layout.sdos.empty());
  const auto& pd = planned->process_data;
  EXPECT_TRUE(pd.layout.empty());
  EXPECT_TRUE(pd.signals.empty());
  EXPECT_TRUE(pd.attachments.empty());
  EXPECT_TRUE(pd.room.empty());
  EXPECT_TRUE(pd.sync_managers.empty());
  EXPECT_TRUE(process_data_writes(pd).empty());
}

// ---- what cannot work ---------------------------------------------------------------------------

void expect_error(const Result<Planned>& planned, Errc code, const std::string& text) {
  ASSERT_FALSE(planned.ok());
  EXPECT_EQ(planned.error().code(), code) << planned.error().describe();
  EXPECT_NE(planned.error().describe().find(text), std::string::npos) << planned.error().describe();
  EXPECT_NE(planned.error().describe().find("slave dut (station 0x1001)"), std::string::npos)
      << planned.error().describe();
}

// Mailbox status in the cyclic frame: a mailbox slave with process data and an FMMU to spare
// gets one more read FMMU, 1 byte at SM1's status register, registered in the fastest of its
// domains after its SyncManagers; none when the option is off, when the FMMUs are all taken, or
// without process data; a rebuilt slave keeps the registration it has.
TEST(PreopPlan, MailboxStatusMappedWithASpareFmmu) {
  auto facts = facts_for("mailbox", {"slow", "fast"});
  facts.domains[0].period = std::chrono::milliseconds(4);
  facts.domains[1].period = std::chrono::milliseconds(1);
  facts.mailbox_status = true;
  facts.fmmu_count = 3;
  SlaveConfig config;
  config.process_data.kind = ProcessDataRequest::Kind::signals;
  config.process_data.routes = {{"outputs.led0", "slow"}, {"inputs.button1", "fast"}};
  auto planned = plan(facts, config);
  ASSERT_TRUE(planned) << planned.error().describe();
  auto& p = planned->process_data;
  ASSERT_EQ(p.attachments.size(), 2u);
  ASSERT_TRUE(p.mailbox_status);
  EXPECT_EQ(p.mailbox_status->domain, "fast");
  EXPECT_EQ(p.mailbox_status->fmmu, 2);
  EXPECT_EQ(p.mailbox_status->sync_manager, 1);
  EXPECT_EQ(p.mailbox_status->physical_address, 0x080D);
  EXPECT_TRUE(p.mailbox_status->new_registration);
  std::size_t fast_count = 0;
  for (const auto& r : p.room) {
    if (r.domain == "fast") fast_count = r.count;
  }
  EXPECT_EQ(fast_count, 2u);  // the inputs and the status byte
  register_all(p);
  p.mailbox_status->logical_address = 0x20000;
  const auto writes = process_data_writes(p);
  ASSERT_FALSE(writes.empty());
  const auto& last = writes.back();
  EXPECT_EQ(last.address, wire::reg::kFmmuBase + 2 * wire::reg::kFmmuSize);
  auto fmmu = wire::FmmuConfig::decode(last.data);
  ASSERT_TRUE(fmmu);
  EXPECT_EQ(fmmu->logical_start, 0x20000u);
  EXPECT_EQ(fmmu->length, 1);
  EXPECT_EQ(fmmu->physical_start, 0x080D);
  EXPECT_EQ(fmmu->type, wire::FmmuType::read);
  EXPECT_TRUE(fmmu->active);

  facts.fmmu_count = 2;  // both taken by the process data
  auto full = plan(facts, config);
  ASSERT_TRUE(full);
  EXPECT_FALSE(full->process_data.mailbox_status);
  facts.fmmu_count = 3;
  facts.mailbox_status = false;
  auto off = plan(facts, config);
  ASSERT_TRUE(off);
  EXPECT_FALSE(off->process_data.mailbox_status);
  // Off now, but registered before (a rebuild): kept, as the domain's image cannot change.
  facts.domains[0].registered.push_back(
      {1, 1, PdoDirection::input, 0x30000, RegistrationKind::sm_status});
  auto kept = plan(facts, config);
  ASSERT_TRUE(kept);
  ASSERT_TRUE(kept->process_data.mailbox_status);
  EXPECT_EQ(kept->process_data.mailbox_status->domain, "slow");
  EXPECT_EQ(kept->process_data.mailbox_status->logical_address, 0x30000u);
  EXPECT_FALSE(kept->process_data.mailbox_status->new_registration);

  auto none = facts_for("mailbox");
  none.mailbox_status = true;
  auto no_pd = plan(none, SlaveConfig{});
  ASSERT_TRUE(no_pd);
  EXPECT_FALSE(no_pd->process_data.mailbox_status);
}

TEST(PreopPlanErrors, MoreSyncManagersThanTheEscHasFmmus) {
  auto facts = facts_for("EL2809");
  facts.fmmu_count = 1;
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");
  expect_error(plan(facts, config), Errc::out_of_range, "needs 2 FMMUs, the ESC has 1");
}

TEST(PreopPlanErrors, KeptRegistrationOfAnotherSize) {
  auto facts = facts_for("EL1809");
  facts.domains[0].registered.push_back(
      {0, 1, PdoDirection::input, 0x100, RegistrationKind::process_data});
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("main");
  expect_error(plan(facts, config), Errc::wrong_state,
               "SyncManager 0 is registered in domain \"main\" with 1 bytes, now 2: the domain "
               "must be rebuilt");
}

TEST(PreopPlanErrors, MappingWithAnEntryOfNoBits) {
  const auto facts = facts_for("servo");
  SlaveConfig config;
  config.name = "dut";
  config.driver = "cia402";
  config.pdo_source = SlaveConfig::PdoSource::configured;
  config.pdo_mapping = short_drive_mapping();
  config.pdo_mapping->mappings[0].entries.push_back(coe_mapping_entry(0x60FF, 0, 0));
  expect_error(plan(facts, config), Errc::malformed,
               "configured PDO mapping: PDO mapping 0x1601:03 = 0x60ff0000 maps 0x60ff:00 with bit "
               "length 0");
}

TEST(PreopPlanErrors, PdosAssignedToASyncManagerTheSiiDoesNotDescribe) {
  const auto facts = facts_for("servo");  // SM0..SM3
  SlaveConfig config;
  config.name = "dut";
  config.driver = "cia402";
  config.process_data = ProcessDataRequest::all("main");
  config.pdo_source = SlaveConfig::PdoSource::configured;
  config.pdo_mapping = short_drive_mapping();
  config.pdo_mapping->assignments[1].sync_manager = 5;
  expect_error(plan(facts, config), Errc::invalid_argument,
               "PDOs assigned to SyncManager 5, which the SII does not describe");
}

TEST(PreopPlanErrors, ConfiguredSourceWithoutMapping) {
  const auto facts = facts_for("servo");
  SlaveConfig config;
  config.name = "dut";
  config.driver = "cia402";
  config.pdo_source = SlaveConfig::PdoSource::configured;
  expect_error(plan(facts, config), Errc::invalid_argument,
               "pdo_source is 'configured' but no mapping is given");
}

TEST(PreopPlanErrors, SdosForASlaveWithoutMailbox) {
  const auto facts = facts_for("EL1809");
  SlaveConfig config;
  config.name = "dut";
  config.startup_sdos = {{0x8000, 1, {1}, false}};
  expect_error(plan(facts, config), Errc::unsupported,
               "SDO 0x8000:01 = 01 needs a mailbox, the slave has none");

  config.startup_sdos.clear();
  config.pdo_source = SlaveConfig::PdoSource::coe;
  expect_error(plan(facts, config), Errc::unsupported, "PDO layout from CoE needs a mailbox");
}

TEST(PreopPlanErrors, RoutesToUnknownSignalsAndDomains) {
  const auto facts = facts_for("EL1809");
  SlaveConfig config;
  config.name = "dut";
  config.process_data = ProcessDataRequest::all("elsewhere");
  expect_error(plan(facts, config), Errc::not_found,
               "process data routed to unknown domain \"elsewhere\"");

  config.process_data.kind = ProcessDataRequest::Kind::signals;
  config.process_data.routes = {{"channel_17", "main"}};
  expect_error(plan(facts, config), Errc::not_found,
               "process_data names signal \"channel_17\", which the EL1809 driver does not have");
}

TEST(PreopPlanErrors, UnknownDriverName) {
  const auto facts = facts_for("EL1809");
  SlaveConfig config;
  config.name = "dut";
  config.driver = "no-such-driver";
  auto chosen = choose_driver(drivers::builtin_registry(), config, facts.sii.identity, facts.who);
  ASSERT_FALSE(chosen.ok());
  EXPECT_EQ(chosen.error().code(), Errc::not_found);
  EXPECT_EQ(chosen.error().message(),
            "slave dut (station 0x1001): unknown driver \"no-such-driver\"");
}

}  // namespace
}  // namespace ecat::master::detail
