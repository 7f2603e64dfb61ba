// SDO abort codes (ETG.1000.6 Table "SDO Abort Codes", CiA 301 §7.2.4.3.17) and their texts.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace ecat::wire {

// The codes a master meets or a simulated slave sends. Any other u32 can still arrive on the wire;
// functions here take the raw value.
enum class SdoAbortCode : std::uint32_t {
  toggle_bit_not_changed = 0x05030000,
  protocol_timeout = 0x05040000,
  command_specifier_unknown = 0x05040001,
  invalid_block_size = 0x05040002,       // CiA 301 block transfer (unused by EtherCAT)
  invalid_sequence_number = 0x05040003,  // CiA 301 block transfer (unused by EtherCAT)
  block_crc_error = 0x05040004,          // CiA 301 block transfer (unused by EtherCAT)
  out_of_memory = 0x05040005,
  unsupported_access = 0x06010000,
  read_of_write_only = 0x06010001,
  write_of_read_only = 0x06010002,
  subindex_cannot_be_written = 0x06010003,
  complete_access_not_supported = 0x06010004,
  object_exceeds_mailbox = 0x06010005,
  object_mapped_to_rx_pdo = 0x06010006,
  object_does_not_exist = 0x06020000,
  object_not_mappable = 0x06040041,
  pdo_length_exceeded = 0x06040042,
  parameter_incompatibility = 0x06040043,
  internal_incompatibility = 0x06040047,
  hardware_error = 0x06060000,
  length_mismatch = 0x06070010,
  length_too_high = 0x06070012,
  length_too_low = 0x06070013,
  subindex_does_not_exist = 0x06090011,
  value_range_exceeded = 0x06090030,
  value_too_high = 0x06090031,
  value_too_low = 0x06090032,
  module_list_mismatch = 0x06090033,
  maximum_less_than_minimum = 0x06090036,
  resource_not_available = 0x060A0023,  // CiA 301
  general_error = 0x08000000,
  cannot_store = 0x08000020,
  cannot_store_local_control = 0x08000021,
  cannot_store_device_state = 0x08000022,
  no_object_dictionary = 0x08000023,
  no_data_available = 0x08000024,  // CiA 301
};

struct SdoAbortCodeInfo {
  std::uint32_t code;
  std::string_view text;
};

// Every code this table knows, in ascending order.
std::span<const SdoAbortCodeInfo> sdo_abort_codes() noexcept;

// The text of a known code ("object does not exist in the object dictionary"), or nullopt.
std::optional<std::string_view> find_sdo_abort_text(std::uint32_t code) noexcept;

// The text of a code; "unknown SDO abort code 0x0badc0de" for codes the table does not know.
std::string sdo_abort_text(std::uint32_t code);
inline std::string sdo_abort_text(SdoAbortCode code) {
  return sdo_abort_text(static_cast<std::uint32_t>(code));
}

}  // namespace ecat::wire
