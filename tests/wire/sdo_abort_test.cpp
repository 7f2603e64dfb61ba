#include <cstdint>
#include <set>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include <ecat/wire/sdo_abort.hpp>

namespace ecat::wire {
namespace {

// The whole table, written out independently of the implementation (ETG.1000.6 SDO abort codes
// plus the CiA 301 ones a CANopen-based slave stack may send).
const std::pair<std::uint32_t, const char*> kExpected[] = {
    {0x05030000, "toggle bit not changed"},
    {0x05040000, "SDO protocol timeout"},
    {0x05040001, "client/server command specifier not valid or unknown"},
    {0x05040002, "invalid block size (block mode only)"},
    {0x05040003, "invalid sequence number (block mode only)"},
    {0x05040004, "CRC error (block mode only)"},
    {0x05040005, "out of memory"},
    {0x06010000, "unsupported access to an object"},
    {0x06010001, "attempt to read a write-only object"},
    {0x06010002, "attempt to write a read-only object"},
    {0x06010003, "subindex cannot be written, SI0 must be 0 for write access"},
    {0x06010004, "SDO complete access not supported for objects of variable length"},
    {0x06010005, "object length exceeds mailbox size"},
    {0x06010006, "object mapped to RxPDO, SDO download blocked"},
    {0x06020000, "object does not exist in the object dictionary"},
    {0x06040041, "object cannot be mapped to the PDO"},
    {0x06040042, "number and length of the objects to be mapped would exceed the PDO length"},
    {0x06040043, "general parameter incompatibility"},
    {0x06040047, "general internal incompatibility in the device"},
    {0x06060000, "access failed due to a hardware error"},
    {0x06070010, "data type does not match, length of service parameter does not match"},
    {0x06070012, "data type does not match, length of service parameter too high"},
    {0x06070013, "data type does not match, length of service parameter too low"},
    {0x06090011, "subindex does not exist"},
    {0x06090030, "value range of parameter exceeded (only for write access)"},
    {0x06090031, "value of parameter written too high"},
    {0x06090032, "value of parameter written too low"},
    {0x06090033, "configured module list does not match detected module list"},
    {0x06090036, "maximum value is less than minimum value"},
    {0x060A0023, "resource not available: SDO connection"},
    {0x08000000, "general error"},
    {0x08000020, "data cannot be transferred or stored to the application"},
    {0x08000021,
     "data cannot be transferred or stored to the application because of local control"},
    {0x08000022,
     "data cannot be transferred or stored to the application because of the present device "
     "state"},
    {0x08000023, "object dictionary dynamic generation fails or no object dictionary is present"},
    {0x08000024, "no data available"},
};

TEST(SdoAbort, EveryCodeHasItsText) {
  for (const auto& [code, text] : kExpected) {
    EXPECT_EQ(sdo_abort_text(code), text) << std::hex << code;
    auto found = find_sdo_abort_text(code);
    ASSERT_TRUE(found.has_value());
    EXPECT_EQ(*found, text);
  }
}

TEST(SdoAbort, TableHoldsExactlyTheseCodesInOrder) {
  const auto table = sdo_abort_codes();
  ASSERT_EQ(table.size(), std::size(kExpected));
  for (std::size_t i = 0; i < table.size(); ++i) {
    EXPECT_EQ(table[i].code, kExpected[i].first);
    EXPECT_EQ(table[i].text, kExpected[i].second);
    if (i > 0) {
      EXPECT_LT(table[i - 1].code, table[i].code);
    }
  }
}

TEST(SdoAbort, UnknownCodes) {
  EXPECT_EQ(sdo_abort_text(0x00000000), "unknown SDO abort code 0x00000000");
  EXPECT_EQ(sdo_abort_text(0x0badc0de), "unknown SDO abort code 0x0badc0de");
  EXPECT_EQ(sdo_abort_text(0xFFFFFFFF), "unknown SDO abort code 0xffffffff");
  // Neighbours of known codes are not matched.
  EXPECT_EQ(sdo_abort_text(0x06020001), "unknown SDO abort code 0x06020001");
  EXPECT_EQ(sdo_abort_text(0x05030001), "unknown SDO abort code 0x05030001");
  EXPECT_FALSE(find_sdo_abort_text(0x08000025).has_value());
  EXPECT_FALSE(find_sdo_abort_text(0x08000025 + 0x10000000).has_value());
}

TEST(SdoAbort, NamedCodesMatchTheTable) {
  const std::pair<SdoAbortCode, std::uint32_t> named[] = {
      {SdoAbortCode::toggle_bit_not_changed, 0x05030000},
      {SdoAbortCode::protocol_timeout, 0x05040000},
      {SdoAbortCode::command_specifier_unknown, 0x05040001},
      {SdoAbortCode::invalid_block_size, 0x05040002},
      {SdoAbortCode::invalid_sequence_number, 0x05040003},
      {SdoAbortCode::block_crc_error, 0x05040004},
      {SdoAbortCode::out_of_memory, 0x05040005},
      {SdoAbortCode::unsupported_access, 0x06010000},
      {SdoAbortCode::read_of_write_only, 0x06010001},
      {SdoAbortCode::write_of_read_only, 0x06010002},
      {SdoAbortCode::subindex_cannot_be_written, 0x06010003},
      {SdoAbortCode::complete_access_not_supported, 0x06010004},
      {SdoAbortCode::object_exceeds_mailbox, 0x06010005},
      {SdoAbortCode::object_mapped_to_rx_pdo, 0x06010006},
      {SdoAbortCode::object_does_not_exist, 0x06020000},
      {SdoAbortCode::object_not_mappable, 0x06040041},
      {SdoAbortCode::pdo_length_exceeded, 0x06040042},
      {SdoAbortCode::parameter_incompatibility, 0x06040043},
      {SdoAbortCode::internal_incompatibility, 0x06040047},
      {SdoAbortCode::hardware_error, 0x06060000},
      {SdoAbortCode::length_mismatch, 0x06070010},
      {SdoAbortCode::length_too_high, 0x06070012},
      {SdoAbortCode::length_too_low, 0x06070013},
      {SdoAbortCode::subindex_does_not_exist, 0x06090011},
      {SdoAbortCode::value_range_exceeded, 0x06090030},
      {SdoAbortCode::value_too_high, 0x06090031},
      {SdoAbortCode::value_too_low, 0x06090032},
      {SdoAbortCode::module_list_mismatch, 0x06090033},
      {SdoAbortCode::maximum_less_than_minimum, 0x06090036},
      {SdoAbortCode::resource_not_available, 0x060A0023},
      {SdoAbortCode::general_error, 0x08000000},
      {SdoAbortCode::cannot_store, 0x08000020},
      {SdoAbortCode::cannot_store_local_control, 0x08000021},
      {SdoAbortCode::cannot_store_device_state, 0x08000022},
      {SdoAbortCode::no_object_dictionary, 0x08000023},
      {SdoAbortCode::no_data_available, 0x08000024},
  };
  std::set<std::uint32_t> seen;
  for (const auto& [name, code] : named) {
    EXPECT_EQ(static_cast<std::uint32_t>(name), code);
    EXPECT_TRUE(find_sdo_abort_text(code).has_value()) << std::hex << code;
    EXPECT_EQ(sdo_abort_text(name), sdo_abort_text(code));
    seen.insert(code);
  }
  // Every table entry has a name.
  EXPECT_EQ(seen.size(), sdo_abort_codes().size());
}

}  // namespace
}  // namespace ecat::wire
