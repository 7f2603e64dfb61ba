// SDO information service (CoE service 8, ETG.1000.6 §5.6.3): reading the object dictionary's
// lists and descriptions.
//
//   mailbox data: CoE header(2) opcode[6:0]|incomplete[7](1) reserved(1) fragments left(2) data
//
// A response too long for one mailbox is split into fragments: every fragment but the last has
// the incomplete flag set, and fragments_left counts down to 0. The service data is the
// concatenation of all fragments' data (an OD list's list type appears only once, at the start),
// so a response is decoded after reassembly (SdoInfoReassembler).
#pragma once

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

constexpr std::size_t kSdoInfoHeaderSize = 4;

enum class SdoInfoOpcode : std::uint8_t {
  get_od_list_request = 0x01,
  get_od_list_response = 0x02,
  get_object_description_request = 0x03,
  get_object_description_response = 0x04,
  get_entry_description_request = 0x05,
  get_entry_description_response = 0x06,
  error_request = 0x07,  // the slave's answer when it cannot serve a request
};

// "get OD list request", ..., "SDO info error"; "reserved" for other values.
std::string_view to_string(SdoInfoOpcode opcode) noexcept;

enum class OdListType : std::uint16_t {
  number_of_objects = 0,  // the response holds the length of lists 1..5
  all = 1,
  rx_pdo_mappable = 2,
  tx_pdo_mappable = 3,
  backup = 4,    // objects stored for device replacement
  settings = 5,  // startup parameters
};

// "number of objects", "all", "RxPDO mappable", "TxPDO mappable", "backup", "settings";
// "reserved" for other values.
std::string_view to_string(OdListType type) noexcept;

// Object codes (CiA 301 Table 42) in object description responses.
enum class ObjectCode : std::uint8_t {
  null = 0x00,
  domain = 0x02,
  deftype = 0x05,
  defstruct = 0x06,
  var = 0x07,
  array = 0x08,
  record = 0x09,
};

// "VAR", "ARRAY", "RECORD", ...; "reserved" for other values.
std::string_view to_string(ObjectCode code) noexcept;

// Value info flags of entry description requests/responses: which optional fields the response
// carries after the object access word. Bits 0..2 (access rights, object category, PDO mapping)
// are always answered in the fixed fields; bits 3..6 add fields.
constexpr std::uint8_t kValueInfoAccessRights = 0x01;
constexpr std::uint8_t kValueInfoObjectCategory = 0x02;
constexpr std::uint8_t kValueInfoPdoMapping = 0x04;
constexpr std::uint8_t kValueInfoUnitType = 0x08;
constexpr std::uint8_t kValueInfoDefaultValue = 0x10;
constexpr std::uint8_t kValueInfoMinimumValue = 0x20;
constexpr std::uint8_t kValueInfoMaximumValue = 0x40;

// Object access bits of entry description responses.
constexpr std::uint16_t kAccessReadPreop = 0x0001;
constexpr std::uint16_t kAccessReadSafeop = 0x0002;
constexpr std::uint16_t kAccessReadOp = 0x0004;
constexpr std::uint16_t kAccessWritePreop = 0x0008;
constexpr std::uint16_t kAccessWriteSafeop = 0x0010;
constexpr std::uint16_t kAccessWriteOp = 0x0020;
constexpr std::uint16_t kAccessRxPdoMappable = 0x0040;
constexpr std::uint16_t kAccessTxPdoMappable = 0x0080;
constexpr std::uint16_t kAccessBackup = 0x0100;
constexpr std::uint16_t kAccessSettings = 0x0200;

struct SdoInfoHeader {
  SdoInfoOpcode opcode = SdoInfoOpcode::get_od_list_request;
  bool incomplete = false;  // more fragments follow
  std::uint16_t fragments_left = 0;

  friend bool operator==(const SdoInfoHeader&, const SdoInfoHeader&) = default;
};

// One mailbox of SDO information: its header and a view of its data.
struct SdoInfoFragment {
  SdoInfoHeader header{};
  Bytes data{};
};

// Decodes mailbox data whose CoE service is "SDO information" into header and data view.
Result<SdoInfoFragment> decode_sdo_info_fragment(Bytes coe);

// --- the services (the service data of a whole, reassembled message) ---

struct OdListRequest {
  OdListType list_type = OdListType::all;

  friend bool operator==(const OdListRequest&, const OdListRequest&) = default;
};

struct OdListResponse {
  OdListType list_type = OdListType::all;
  // The object indices of the list; for number_of_objects, the lengths of lists 1..5 in order.
  std::vector<std::uint16_t> indices{};

  friend bool operator==(const OdListResponse&, const OdListResponse&) = default;
};

struct ObjectDescriptionRequest {
  std::uint16_t index = 0;

  friend bool operator==(const ObjectDescriptionRequest&,
                         const ObjectDescriptionRequest&) = default;
};

struct ObjectDescriptionResponse {
  std::uint16_t index = 0;
  std::uint16_t data_type = 0;
  std::uint8_t max_subindex = 0;
  ObjectCode object_code = ObjectCode::var;
  std::string name{};  // up to the first NUL, if any

  friend bool operator==(const ObjectDescriptionResponse&,
                         const ObjectDescriptionResponse&) = default;
};

struct EntryDescriptionRequest {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint8_t value_info = 0;  // kValueInfo* flags asked for

  friend bool operator==(const EntryDescriptionRequest&, const EntryDescriptionRequest&) = default;
};

// The unit type (a 32-bit CiA 303-2 unit code) is present when value_info has kValueInfoUnitType;
// default, minimum and maximum value (each (bit_length + 7) / 8 bytes) when it has the matching
// flag. The description is the rest.
struct EntryDescriptionResponse {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint8_t value_info = 0;
  std::uint16_t data_type = 0;
  std::uint16_t bit_length = 0;
  std::uint16_t object_access = 0;  // kAccess* bits
  std::uint32_t unit_type = 0;
  std::vector<std::uint8_t> default_value{};
  std::vector<std::uint8_t> minimum_value{};
  std::vector<std::uint8_t> maximum_value{};
  std::string description{};  // up to the first NUL, if any

  friend bool operator==(const EntryDescriptionResponse&,
                         const EntryDescriptionResponse&) = default;
};

// The slave's refusal of an SDO information request, with an SDO abort code.
struct SdoInfoError {
  std::uint32_t abort_code = 0;

  friend bool operator==(const SdoInfoError&, const SdoInfoError&) = default;
};

using SdoInfoMessage =
    std::variant<OdListRequest, OdListResponse, ObjectDescriptionRequest, ObjectDescriptionResponse,
                 EntryDescriptionRequest, EntryDescriptionResponse, SdoInfoError>;

SdoInfoOpcode opcode_of(const SdoInfoMessage& message) noexcept;

// Decodes the service data of a whole message with the given opcode.
Result<SdoInfoMessage> decode_sdo_info(SdoInfoOpcode opcode, Bytes service_data);
// Decodes mailbox data holding a complete (unfragmented) SDO information message. A fragment of a
// longer message fails (unsupported): feed it to an SdoInfoReassembler instead.
Result<SdoInfoMessage> decode_sdo_info(Bytes coe);

// The service data of a message (no CoE or SDO information header).
Result<std::vector<std::uint8_t>> encode_sdo_info_data(const SdoInfoMessage& message);
// The message as mailbox data (CoE header + SDO information header + service data), unfragmented.
Result<std::vector<std::uint8_t>> encode_sdo_info(const SdoInfoMessage& message);
// The message as one or more mailbox data blocks of at most max_mailbox_data bytes each (the
// receiving mailbox's size minus the 6-byte mailbox header), as a slave sends a long response.
// Fragment data is cut at even sizes so no 16-bit index straddles two fragments.
Result<std::vector<std::vector<std::uint8_t>>> encode_sdo_info_fragments(
    const SdoInfoMessage& message, std::size_t max_mailbox_data);

// Collects the fragments of one SDO information response, in order.
class SdoInfoReassembler {
 public:
  enum class Status : std::uint8_t { need_more, complete };

  // Adds the next fragment (mailbox data, CoE header included). Fails when the fragment does not
  // continue the message: another opcode, or a fragments_left that is not one less than the
  // previous one. After an error or after completion the reassembler starts over with the next
  // fragment.
  Result<Status> add(Bytes coe);

  // The opcode and concatenated service data once add() has returned complete.
  SdoInfoOpcode opcode() const noexcept { return opcode_; }
  const std::vector<std::uint8_t>& data() const noexcept { return data_; }
  // Decodes the reassembled message.
  Result<SdoInfoMessage> message() const;

  void reset() noexcept;

 private:
  bool started_ = false;
  bool complete_ = false;
  SdoInfoOpcode opcode_ = SdoInfoOpcode::get_od_list_response;
  std::uint16_t fragments_left_ = 0;
  std::vector<std::uint8_t> data_{};
};

}  // namespace ecat::wire
