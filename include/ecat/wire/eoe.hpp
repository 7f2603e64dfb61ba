// Ethernet over EtherCAT (mailbox type 2, ETG.1000.6 §5.7): Ethernet frames tunnelled through the
// mailbox in fragments, and the IP parameter services.
//
//   mailbox data: EoE header(4) then by frame type
//     word 0: type[3:0] port[7:4] last fragment[8] time appended[9] time request[10]
//     reserved[15:11] word 1: fragment number[5:0] offset/size[11:6] frame number[15:12] -- or a
//     result code in the
//             responses of the IP parameter and address filter services
//   fragment offsets and frame sizes count 32-byte blocks: fragment 0 carries the size of the
//   whole frame ((bytes + 31) / 32), every later fragment its offset in the frame (bytes / 32).
//   With "time appended" on the last fragment, its last 4 bytes are a timestamp.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kEoeHeaderSize = 4;
constexpr std::size_t kEoeBlockSize = 32;
constexpr std::size_t kEoeDnsNameSize = 32;

enum class EoeFrameType : std::uint8_t {
  fragment = 0,
  timestamp_response = 1,
  set_ip_request = 2,
  set_ip_response = 3,
  set_address_filter_request = 4,
  set_address_filter_response = 5,
  get_ip_request = 6,
  get_ip_response = 7,
  get_address_filter_request = 8,
  get_address_filter_response = 9,
};

// "fragment", "set IP parameter request", ...; "reserved" for other values.
std::string_view to_string(EoeFrameType type) noexcept;

enum class EoeResult : std::uint16_t {
  success = 0x0000,
  unspecified_error = 0x0001,
  unsupported_frame_type = 0x0002,
  no_ip_support = 0x0201,
  dhcp_not_supported = 0x0202,
  no_filter_support = 0x0401,
};

// "success", "unspecified error", ...; "unknown EoE result" for other values.
std::string_view eoe_result_text(std::uint16_t result) noexcept;

struct EoeHeader {
  EoeFrameType type = EoeFrameType::fragment;
  std::uint8_t port = 0;  // 0..15
  bool last_fragment = false;
  bool time_appended = false;
  bool time_request = false;
  std::uint8_t fragment_number = 0;  // 0..63
  std::uint8_t offset_blocks = 0;    // 0..63: frame size (fragment 0) or offset, in 32-byte blocks
  std::uint8_t frame_number = 0;     // 0..15

  friend bool operator==(const EoeHeader&, const EoeHeader&) = default;
};

// Word 1 read as the result code of a response (the fragment fields taken together).
constexpr std::uint16_t eoe_result_of(const EoeHeader& header) noexcept {
  return static_cast<std::uint16_t>((header.fragment_number & 0x3F) |
                                    ((header.offset_blocks & 0x3F) << 6) |
                                    ((header.frame_number & 0x0F) << 12));
}

Result<void> encode_eoe_header(const EoeHeader& header, ByteWriter& out);
Result<EoeHeader> decode_eoe_header(Bytes data);

// A fragment of a tunnelled Ethernet frame.
struct EoeFragment {
  EoeHeader header{};
  std::vector<std::uint8_t> data{};
  std::optional<std::uint32_t> timestamp{};  // present exactly when header.time_appended

  friend bool operator==(const EoeFragment&, const EoeFragment&) = default;
};

// IPv4 addresses as numbers (192.168.1.2 is 0xC0A80102), sent little-endian as real slaves and
// masters do. Only the parameters present are on the wire, after a u32 of "included" flags.
struct EoeIpParameters {
  std::optional<std::array<std::uint8_t, 6>> mac{};
  std::optional<std::uint32_t> ip{};
  std::optional<std::uint32_t> subnet_mask{};
  std::optional<std::uint32_t> default_gateway{};
  std::optional<std::uint32_t> dns_server{};
  std::optional<std::string> dns_name{};  // at most 32 bytes, zero-padded to 32 on the wire

  friend bool operator==(const EoeIpParameters&, const EoeIpParameters&) = default;
};

struct EoeSetIpRequest {
  std::uint8_t port = 0;
  EoeIpParameters parameters{};

  friend bool operator==(const EoeSetIpRequest&, const EoeSetIpRequest&) = default;
};

struct EoeSetIpResponse {
  std::uint8_t port = 0;
  std::uint16_t result = 0;  // an EoeResult value

  friend bool operator==(const EoeSetIpResponse&, const EoeSetIpResponse&) = default;
};

// Any other frame type, kept as header and raw data.
struct EoeOther {
  EoeHeader header{};
  std::vector<std::uint8_t> data{};

  friend bool operator==(const EoeOther&, const EoeOther&) = default;
};

using EoeMessage = std::variant<EoeFragment, EoeSetIpRequest, EoeSetIpResponse, EoeOther>;

// Decodes the data of a type-2 mailbox.
Result<EoeMessage> decode_eoe(Bytes data);
Result<std::vector<std::uint8_t>> encode_eoe(const EoeMessage& message);

// "192.168.1.2"
std::string format_ipv4(std::uint32_t address);

}  // namespace ecat::wire
