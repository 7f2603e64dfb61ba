// CANopen over EtherCAT (ETG.1000.6 §5.6): the CoE header and the SDO services.
//
// All CoE decoders here take the mailbox data (what follows the 6-byte mailbox header, trimmed to
// the header's length field): the 2-byte CoE header, then the service.
//
//   CoE header (u16): number[8:0] | reserved[11:9] | service[15:12]
//   SDO (service 2 request, 3 response): command(1) index(2) subindex(1) then 4 bytes (expedited
//   data, complete size, abort code or reserved) and, for normal transfers, more data; segments
//   carry command(1) then at least 7 data bytes.
//
// Command byte, by client command specifier (requests) / server command specifier (responses):
//   initiate download req   ccs=1: size indicated[0] expedited[1] unused bytes n[3:2] CA[4]
//   initiate download resp  scs=3
//   download segment req    ccs=0: last[0] unused bytes n[3:1] toggle[4]
//   download segment resp   scs=1: toggle[4]
//   initiate upload req     ccs=2: CA[4]
//   initiate upload resp    scs=2: size indicated[0] expedited[1] unused bytes n[3:2] CA[4]
//   upload segment req      ccs=3: toggle[4]
//   upload segment resp     scs=0: last[0] unused bytes n[3:1] toggle[4]
//   abort transfer          cs=4 (either direction)
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <variant>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kCoeHeaderSize = 2;

enum class CoeService : std::uint8_t {
  emergency = 1,
  sdo_request = 2,
  sdo_response = 3,
  tx_pdo = 4,
  rx_pdo = 5,
  tx_pdo_remote_request = 6,
  rx_pdo_remote_request = 7,
  sdo_information = 8,
};

// "emergency", "SDO request", ..., "SDO information"; "reserved" for other values.
std::string_view to_string(CoeService service) noexcept;

struct CoeHeader {
  std::uint16_t number = 0;  // 9 bits; a PDO number for the PDO services, otherwise 0
  CoeService service = CoeService::sdo_request;

  friend bool operator==(const CoeHeader&, const CoeHeader&) = default;
};

Result<void> encode_coe_header(const CoeHeader& header, ByteWriter& out);
// Decodes the first 2 bytes of the mailbox data.
Result<CoeHeader> decode_coe_header(Bytes coe);

// ---------------------------------------------------------------------------------------------
// SDO services

// Bytes of an SDO message after the CoE header, before any variable-length data: the command byte,
// index, subindex and the 4-byte field.
constexpr std::size_t kSdoHeaderSize = 8;
// Mailbox data length of every fixed-size SDO message (CoE header + SDO header).
constexpr std::size_t kSdoFixedSize = kCoeHeaderSize + kSdoHeaderSize;
// Segments always carry at least 7 data bytes; shorter data is padded and counted as unused.
constexpr std::size_t kSdoMinSegmentData = 7;
constexpr std::size_t kSdoMaxExpeditedData = 4;

// Initiate download request (ccs 1).
//  expedited: data holds the value (1..4 bytes with size_indicated, exactly 4 without) and
//             complete_size is 0.
//  normal:    complete_size is the size of the whole value; data is the part carried in this
//             mailbox (the rest follows in download segments).
struct SdoInitiateDownloadRequest {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool complete_access = false;
  bool expedited = false;
  bool size_indicated = true;
  std::uint32_t complete_size = 0;
  std::vector<std::uint8_t> data{};

  friend bool operator==(const SdoInitiateDownloadRequest&,
                         const SdoInitiateDownloadRequest&) = default;
};

// Initiate download response (scs 3). Its last 4 bytes are reserved (some slaves echo the data);
// they are ignored when decoding and written as zero.
struct SdoInitiateDownloadResponse {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;

  friend bool operator==(const SdoInitiateDownloadResponse&,
                         const SdoInitiateDownloadResponse&) = default;
};

// Download segment request (ccs 0). Data shorter than 7 bytes is padded to 7 on the wire.
struct SdoDownloadSegmentRequest {
  bool toggle = false;
  bool last = false;
  std::vector<std::uint8_t> data{};

  friend bool operator==(const SdoDownloadSegmentRequest&,
                         const SdoDownloadSegmentRequest&) = default;
};

// Download segment response (scs 1).
struct SdoDownloadSegmentResponse {
  bool toggle = false;

  friend bool operator==(const SdoDownloadSegmentResponse&,
                         const SdoDownloadSegmentResponse&) = default;
};

// Initiate upload request (ccs 2).
struct SdoInitiateUploadRequest {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool complete_access = false;

  friend bool operator==(const SdoInitiateUploadRequest&,
                         const SdoInitiateUploadRequest&) = default;
};

// Initiate upload response (scs 2); fields as for SdoInitiateDownloadRequest. A normal response
// whose data is shorter than complete_size is followed by upload segments.
struct SdoInitiateUploadResponse {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool complete_access = false;
  bool expedited = false;
  bool size_indicated = true;
  std::uint32_t complete_size = 0;
  std::vector<std::uint8_t> data{};

  friend bool operator==(const SdoInitiateUploadResponse&,
                         const SdoInitiateUploadResponse&) = default;
};

// Upload segment request (ccs 3).
struct SdoUploadSegmentRequest {
  bool toggle = false;

  friend bool operator==(const SdoUploadSegmentRequest&, const SdoUploadSegmentRequest&) = default;
};

// Upload segment response (scs 0). Data shorter than 7 bytes is padded to 7 on the wire.
struct SdoUploadSegmentResponse {
  bool toggle = false;
  bool last = false;
  std::vector<std::uint8_t> data{};

  friend bool operator==(const SdoUploadSegmentResponse&,
                         const SdoUploadSegmentResponse&) = default;
};

// The CoE service an SDO message travels in: request (service 2: client to server, master to
// slave, and every abort in its standard form) or response (service 3: server to client).
enum class SdoDirection : std::uint8_t { request, response };

// Abort transfer (cs 4): sent by the slave to refuse or end a transfer, or by the master to
// abandon one. On the wire an abort travels as an SDO *request* (CoE service 2) whichever side
// sends it: SOES, KickCAT and Beckhoff terminals answer a refused transfer with service 2 and
// command 0x80, and the IgH master recognises an abort only in that form (SOEM takes a service-3
// abort of a download for a success). Some stacks send it as service 3; decoders accept both and
// keep the form in `service` (so a decoded abort re-encodes to the same bytes), encoders send
// service 2 unless told otherwise.
struct SdoAbort {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint32_t code = 0;  // see sdo_abort.hpp
  // The CoE service the abort travels in: request (2, the standard form from either side) or
  // response (3, the non-standard form some stacks send).
  SdoDirection service = SdoDirection::request;

  friend bool operator==(const SdoAbort&, const SdoAbort&) = default;
};

using SdoMessage =
    std::variant<SdoInitiateDownloadRequest, SdoInitiateDownloadResponse, SdoDownloadSegmentRequest,
                 SdoDownloadSegmentResponse, SdoInitiateUploadRequest, SdoInitiateUploadResponse,
                 SdoUploadSegmentRequest, SdoUploadSegmentResponse, SdoAbort>;

// The CoE service the message travels in (an abort: its `service`).
SdoDirection direction_of(const SdoMessage& message) noexcept;
// "initiate download request", "upload segment response", "abort transfer", ...
std::string_view to_string(const SdoMessage& message) noexcept;

// Decodes mailbox data holding an SDO request or response: the CoE service (2 or 3) picks the
// command specifier table, the specifier picks the message.
Result<SdoMessage> decode_sdo(Bytes coe);
// Encodes CoE header + SDO message; the result is the mailbox data (wrap it with encode_mailbox).
// Fails (invalid_argument) on values the wire cannot carry (expedited data of 0 or more than 4
// bytes, more than 65535 bytes of data, ...).
Result<std::vector<std::uint8_t>> encode_sdo(const SdoMessage& message);

// ---------------------------------------------------------------------------------------------
// Complete access values
//
// A complete-access transfer starting at subindex 0 carries subindex 0 padded to 16 bits, then the
// entries: real slaves answer a complete-access upload of 0x1C12 holding one PDO 0x1601 with
// `01 00 01 16`. (A transfer starting at subindex 1 carries the entries only.)

struct CompleteAccessValue {
  std::uint8_t subindex0 = 0;  // number of entries
  Bytes entries{};             // everything after the padded subindex 0
};

// Splits a complete-access value that starts at subindex 0 (at least 2 bytes).
Result<CompleteAccessValue> split_complete_access(Bytes value);
// Builds such a value: subindex0, a zero pad byte, then the entries.
std::vector<std::uint8_t> join_complete_access(std::uint8_t subindex0, Bytes entries);
// The first subindex0 entries of 16 bits (PDO assignment objects 0x1C1x) or 32 bits (PDO mapping
// objects 0x16xx / 0x1Axx). Fails when the value is too short for subindex0 entries; bytes after
// them (entries beyond subindex 0's count) are ignored.
Result<std::vector<std::uint16_t>> complete_access_u16_entries(Bytes value);
Result<std::vector<std::uint32_t>> complete_access_u32_entries(Bytes value);

}  // namespace ecat::wire
