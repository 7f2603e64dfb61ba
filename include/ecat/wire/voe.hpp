// Vendor specific protocol over EtherCAT (mailbox type 15, ETG.1000.6 §5.10): a 6-byte header
// naming the vendor and the vendor's own message type, then whatever the vendor defines.
//
//   mailbox data: vendor id(4) vendor type(2) then the vendor's data
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kVoeHeaderSize = 6;

struct VoeHeader {
  std::uint32_t vendor_id = 0;    // the vendor's EtherCAT vendor ID (as in the SII identity)
  std::uint16_t vendor_type = 0;  // the vendor's message type

  friend bool operator==(const VoeHeader&, const VoeHeader&) = default;
};

Result<void> encode_voe_header(const VoeHeader& header, ByteWriter& out);
Result<VoeHeader> decode_voe_header(Bytes data);

struct VoeMessage {
  VoeHeader header{};
  std::vector<std::uint8_t> data{};  // everything after the header

  friend bool operator==(const VoeMessage&, const VoeMessage&) = default;
};

// Decodes the data of a type-15 mailbox.
Result<VoeMessage> decode_voe(Bytes data);
// Fails (Errc::invalid_argument) when header + data exceed the 65535-byte mailbox length limit.
Result<std::vector<std::uint8_t>> encode_voe(const VoeMessage& message);

}  // namespace ecat::wire
