#include <algorithm>
#include <array>

#include <fmt/format.h>

#include <ecat/wire/sdo_abort.hpp>

namespace ecat::wire {
namespace {

// Ascending by code, so lookups can binary-search.
constexpr std::array<SdoAbortCodeInfo, 36> kAbortCodes{{
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
     "data cannot be transferred or stored to the application because of local "
     "control"},
    {0x08000022,
     "data cannot be transferred or stored to the application because of the present "
     "device state"},
    {0x08000023, "object dictionary dynamic generation fails or no object dictionary is present"},
    {0x08000024, "no data available"},
}};

}  // namespace

std::span<const SdoAbortCodeInfo> sdo_abort_codes() noexcept {
  return kAbortCodes;
}

std::optional<std::string_view> find_sdo_abort_text(std::uint32_t code) noexcept {
  auto it = std::lower_bound(kAbortCodes.begin(), kAbortCodes.end(), code,
                             [](const SdoAbortCodeInfo& e, std::uint32_t c) { return e.code < c; });
  if (it == kAbortCodes.end() || it->code != code) return std::nullopt;
  return it->text;
}

std::string sdo_abort_text(std::uint32_t code) {
  if (auto text = find_sdo_abort_text(code)) return std::string(*text);
  return fmt::format("unknown SDO abort code 0x{:08x}", code);
}

}  // namespace ecat::wire
