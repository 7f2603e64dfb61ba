#include <cstdint>
#include <map>
#include <set>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <ecat/wire/al.hpp>
#include <ecat/wire/registers.hpp>

namespace {

using namespace ecat::wire;
using ::testing::HasSubstr;

TEST(AlState, NamesAndCodes) {
  EXPECT_EQ(to_string(AlState::init), "INIT");
  EXPECT_EQ(to_string(AlState::preop), "PREOP");
  EXPECT_EQ(to_string(AlState::bootstrap), "BOOT");
  EXPECT_EQ(to_string(AlState::safeop), "SAFEOP");
  EXPECT_EQ(to_string(AlState::op), "OP");
  EXPECT_EQ(static_cast<int>(AlState::init), 1);
  EXPECT_EQ(static_cast<int>(AlState::preop), 2);
  EXPECT_EQ(static_cast<int>(AlState::bootstrap), 3);
  EXPECT_EQ(static_cast<int>(AlState::safeop), 4);
  EXPECT_EQ(static_cast<int>(AlState::op), 8);
  for (int code = 0; code < 16; ++code) {
    const auto state = al_state_from_code(static_cast<std::uint8_t>(code));
    const bool valid = code == 1 || code == 2 || code == 3 || code == 4 || code == 8;
    ASSERT_EQ(state.has_value(), valid) << code;
    if (valid) {
      EXPECT_EQ(static_cast<int>(*state), code);
    }
  }
}

TEST(AlControl, Encode) {
  EXPECT_EQ(encode_al_control(AlState::init), 0x0001);
  EXPECT_EQ(encode_al_control(AlState::init, true), 0x0011);
  EXPECT_EQ(encode_al_control(AlState::op), 0x0008);
  EXPECT_EQ(encode_al_control(AlState::safeop, true), 0x0014);
  EXPECT_EQ((AlControl{AlState::preop, false, true}).encode(), 0x0022);
  EXPECT_EQ((AlControl{AlState::bootstrap, true, true}).encode(), 0x0033);
}

TEST(AlControl, DecodeAndRoundTrip) {
  for (AlState s :
       {AlState::init, AlState::preop, AlState::bootstrap, AlState::safeop, AlState::op}) {
    for (bool ack : {false, true}) {
      for (bool id : {false, true}) {
        const AlControl c{s, ack, id};
        auto back = AlControl::decode(c.encode());
        ASSERT_TRUE(back.ok());
        EXPECT_EQ(*back, c);
      }
    }
  }
  auto one_byte = AlControl::decode(Bytes{std::initializer_list<std::uint8_t>{0x12}.begin(), 1});
  ASSERT_TRUE(one_byte.ok());
  EXPECT_EQ(one_byte->state, AlState::preop);
  EXPECT_TRUE(one_byte->acknowledge_error);

  auto bad = AlControl::decode(std::uint16_t{0x0015});
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code(), ecat::Errc::malformed);
  EXPECT_THAT(bad.error().message(), HasSubstr("AL control 0x0015"));
  EXPECT_THAT(bad.error().message(), HasSubstr("state code 5"));

  EXPECT_FALSE(AlControl::decode(Bytes{}).ok());
  const std::uint8_t three[3] = {1, 0, 0};
  EXPECT_FALSE(AlControl::decode(three).ok());
}

TEST(AlStatus, Decode) {
  auto s = AlStatus::decode(std::uint16_t{0x0014});
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, AlState::safeop);
  EXPECT_TRUE(s->error);
  EXPECT_FALSE(s->id_loaded);

  s = AlStatus::decode(std::uint16_t{0x0028});
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, AlState::op);
  EXPECT_FALSE(s->error);
  EXPECT_TRUE(s->id_loaded);

  s = AlStatus::decode(std::uint16_t{0x0003});
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, AlState::bootstrap);

  // Reserved high bits do not disturb the state.
  s = AlStatus::decode(std::uint16_t{0xFF02 & 0xFFCF});
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, AlState::preop);
  EXPECT_FALSE(s->error);
}

TEST(AlStatus, RejectsInvalidStateCodes) {
  for (std::uint16_t raw : {0x0000, 0x0005, 0x0006, 0x0007, 0x0009, 0x000F, 0x0010, 0x001C}) {
    auto s = AlStatus::decode(raw);
    ASSERT_FALSE(s.ok()) << raw;
    EXPECT_EQ(s.error().code(), ecat::Errc::malformed);
    EXPECT_THAT(s.error().message(), HasSubstr("AL status"));
    EXPECT_THAT(s.error().message(), HasSubstr("state code " + std::to_string(raw & 0x0F)));
  }
}

TEST(AlStatus, DecodeBytes) {
  const std::uint8_t one[1] = {0x04};
  const std::uint8_t two[2] = {0x18, 0x00};
  const std::uint8_t six[6] = {0x12, 0x00, 0x00, 0x00, 0x1D, 0x00};
  auto a = AlStatus::decode(one);
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->state, AlState::safeop);
  auto b = AlStatus::decode(two);
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->state, AlState::op);
  EXPECT_TRUE(b->error);
  auto c = AlStatus::decode(six);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->state, AlState::preop);
  EXPECT_TRUE(c->error);
  const std::uint8_t three[3] = {1, 0, 0};
  auto bad = AlStatus::decode(three);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message(), HasSubstr("got 3"));
  EXPECT_FALSE(AlStatus::decode(Bytes{}).ok());
}

TEST(AlStatus, RoundTrip) {
  for (AlState st :
       {AlState::init, AlState::preop, AlState::bootstrap, AlState::safeop, AlState::op}) {
    for (bool err : {false, true}) {
      for (bool id : {false, true}) {
        const AlStatus s{st, err, id};
        auto back = AlStatus::decode(s.encode());
        ASSERT_TRUE(back.ok());
        EXPECT_EQ(*back, s);
      }
    }
  }
  EXPECT_EQ((AlStatus{AlState::safeop, true, false}).encode(), 0x0014);
}

TEST(AlStatus, Block) {
  const std::uint8_t six[6] = {0x14, 0x00, 0x00, 0x00, 0x1B, 0x00};
  auto b = decode_al_status_block(six);
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->status.state, AlState::safeop);
  EXPECT_TRUE(b->status.error);
  EXPECT_EQ(b->code, al_status::kSyncManagerWatchdog);
  EXPECT_EQ(al_status_code_text(b->code), "Sync manager watchdog");
  EXPECT_FALSE(decode_al_status_block(Bytes{six, 4}).ok());
  const std::uint8_t bad_state[6] = {0x00, 0x00, 0x00, 0x00, 0x00, 0x00};
  EXPECT_FALSE(decode_al_status_block(bad_state).ok());
}

// The expected texts, written out independently of the implementation's table.
const std::map<std::uint16_t, std::string>& expected_codes() {
  static const std::map<std::uint16_t, std::string> codes = {
      {0x0000, "No error"},
      {0x0001, "Unspecified error"},
      {0x0002, "No memory"},
      {0x0003, "Invalid device setup"},
      {0x0004, "Invalid revision"},
      {0x0006, "SII/EEPROM information does not match firmware"},
      {0x0007, "Firmware update not successful, old firmware still running"},
      {0x000E, "License error"},
      {0x0011, "Invalid requested state change"},
      {0x0012, "Unknown requested state"},
      {0x0013, "Bootstrap not supported"},
      {0x0014, "No valid firmware"},
      {0x0015, "Invalid mailbox configuration (bootstrap)"},
      {0x0016, "Invalid mailbox configuration (PREOP)"},
      {0x0017, "Invalid sync manager configuration"},
      {0x0018, "No valid inputs available"},
      {0x0019, "No valid outputs"},
      {0x001A, "Synchronization error"},
      {0x001B, "Sync manager watchdog"},
      {0x001C, "Invalid sync manager types"},
      {0x001D, "Invalid output configuration"},
      {0x001E, "Invalid input configuration"},
      {0x001F, "Invalid watchdog configuration"},
      {0x0020, "Slave needs cold start"},
      {0x0021, "Slave needs INIT"},
      {0x0022, "Slave needs PREOP"},
      {0x0023, "Slave needs SAFEOP"},
      {0x0024, "Invalid input mapping"},
      {0x0025, "Invalid output mapping"},
      {0x0026, "Inconsistent settings"},
      {0x0027, "FreeRun not supported"},
      {0x0028, "SyncMode not supported"},
      {0x0029, "FreeRun needs 3-buffer mode"},
      {0x002A, "Background watchdog"},
      {0x002B, "No valid inputs and outputs"},
      {0x002C, "Fatal sync error"},
      {0x002D, "No sync error"},
      {0x002E, "Cycle time too small"},
      {0x0030, "Invalid DC SYNC configuration"},
      {0x0031, "Invalid DC latch configuration"},
      {0x0032, "PLL error"},
      {0x0033, "DC sync IO error"},
      {0x0034, "DC sync timeout error"},
      {0x0035, "DC invalid sync cycle time"},
      {0x0036, "DC Sync0 cycle time"},
      {0x0037, "DC Sync1 cycle time"},
      {0x0041, "MBX_AOE"},
      {0x0042, "MBX_EOE"},
      {0x0043, "MBX_COE"},
      {0x0044, "MBX_FOE"},
      {0x0045, "MBX_SOE"},
      {0x004F, "MBX_VOE"},
      {0x0050, "EEPROM no access"},
      {0x0051, "EEPROM error"},
      {0x0052, "External hardware not ready"},
      {0x0060, "Slave restarted locally"},
      {0x0061, "Device identification value updated"},
      {0x0070, "Detected module ident list does not match"},
      {0x0080, "Supply voltage too low"},
      {0x0081, "Supply voltage too high"},
      {0x0082, "Temperature too low"},
      {0x0083, "Temperature too high"},
      {0x00F0, "Application controller available"},
  };
  return codes;
}

TEST(AlStatusCode, EveryDefinedCodeHasItsText) {
  for (const auto& [code, text] : expected_codes()) {
    SCOPED_TRACE(code);
    EXPECT_EQ(al_status_code_text(code), text);
    const auto name = al_status_code_name(code);
    ASSERT_TRUE(name.has_value());
    EXPECT_EQ(*name, text);
  }
}

TEST(AlStatusCode, TableMatchesTheExpectedListExactly) {
  const auto table = al_status_codes();
  ASSERT_EQ(table.size(), expected_codes().size());
  std::set<std::uint16_t> seen;
  for (const auto& info : table) {
    EXPECT_TRUE(seen.insert(info.code).second) << "duplicate " << info.code;
    const auto it = expected_codes().find(info.code);
    ASSERT_NE(it, expected_codes().end()) << "unexpected code " << info.code;
    EXPECT_EQ(info.text, it->second);
  }
}

TEST(AlStatusCode, EveryOtherCodeIsUnknownOrVendorSpecific) {
  for (std::uint32_t code = 0; code <= 0xFFFF; ++code) {
    const auto c = static_cast<std::uint16_t>(code);
    if (expected_codes().count(c) != 0) continue;
    EXPECT_FALSE(al_status_code_name(c).has_value()) << code;
  }
  EXPECT_EQ(al_status_code_text(0x0005), "unknown AL status code 0x0005");
  EXPECT_EQ(al_status_code_text(0x002F), "unknown AL status code 0x002f");
  EXPECT_EQ(al_status_code_text(0x00FF), "unknown AL status code 0x00ff");
  EXPECT_EQ(al_status_code_text(0x7FFF), "unknown AL status code 0x7fff");
  EXPECT_EQ(al_status_code_text(0x8000), "vendor-specific AL status code 0x8000");
  EXPECT_EQ(al_status_code_text(0xFFFF), "vendor-specific AL status code 0xffff");
}

TEST(AlStatusCode, NamedConstants) {
  EXPECT_EQ(al_status::kNoError, 0x0000);
  EXPECT_EQ(al_status::kInvalidRequestedStateChange, 0x0011);
  EXPECT_EQ(al_status::kUnknownRequestedState, 0x0012);
  EXPECT_EQ(al_status::kInvalidMailboxConfigurationPreop, 0x0016);
  EXPECT_EQ(al_status::kSyncManagerWatchdog, 0x001B);
  EXPECT_EQ(al_status::kFatalSyncError, 0x002C);
  EXPECT_EQ(al_status::kInvalidDcSyncConfiguration, 0x0030);
  EXPECT_EQ(al_status::kDcSync1CycleTime, 0x0037);
  EXPECT_EQ(al_status::kMailboxVoe, 0x004F);
  EXPECT_EQ(al_status::kApplicationControllerAvailable, 0x00F0);
  EXPECT_EQ(kAlControlErrorAcknowledge, 0x0010);
  EXPECT_EQ(kAlStatusError, 0x0010);
  EXPECT_EQ(kAlStatusIdLoaded, 0x0020);
  EXPECT_EQ(reg::kAlControl, 0x0120);
  EXPECT_EQ(reg::kAlStatus, 0x0130);
  EXPECT_EQ(reg::kAlStatusCode, 0x0134);
}

}  // namespace
