// Servo drive profile over EtherCAT (SoE, mailbox type 5), the master's side: reading and writing
// the IDN parameters of SERCOS drives over a slave's Mailbox, from tasks on the control thread.
//
//   auto cycle = co_await master::soe_read(mailbox, 0, 0x0001);           // S-0-0001, its value
//   auto done = co_await master::soe_write(mailbox, 0, 0x0024, wire::kSoeElementValue, bytes);
//
// What ETG.1000.6 §5.9 (and the SERCOS drive profile, IEC 61800-7-304) says, as this client
// follows it:
//  - A read request carries the IDN and the elements wanted; the drive answers with one read
//    response holding the elements in bit order, or, when they exceed its mailbox, with several:
//    every one but the last has the incomplete flag set and the number of fragments still to come
//    in the IDN field; the last carries the IDN again. The master sends no request in between.
//  - A write larger than the master's mailbox goes out the same way (incomplete fragments, the
//    IDN field counting down the fragments left, the last one with the IDN); only the last one is
//    answered.
//  - A failure is a response with the error flag and a 2-byte SoE error code after the header.
//  - Notifications (opcode 5) and slave info (opcode 6) come unsolicited; the Mailbox queues them
//    and soe_notifications() takes them out.
//
// Every response is checked as hostile input: opcode, drive number, elements, IDN, the
// fragments-left count (a count that does not go down by one means a fragment was lost), the
// reassembled size against SoeOptions::max_size. A violation fails the transfer with
// Errc::mailbox_error (Errc::malformed for bytes that do not decode); an SoE error response fails
// it with Errc::mailbox_error whose value is kSoeErrorValueBase + the code:
//   "SoE write of S-0-0001 (drive 0) of slave 0x1001: the drive answered with SoE error 0x7005
//    (operation data is write protected at this time)"
// and soe_error_code(error) gives the code back.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/exec/task.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/soe.hpp>

namespace ecat::master {

struct SoeOptions {
  // How long to wait for each response (each fragment of a fragmented read).
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // The most bytes a read reassembles (the drive's fragments beyond it fail the read) and a
  // write sends.
  std::size_t max_size = 64 * 1024;
};

// ---- Error codes ---------------------------------------------------------------------------

// The common SoE error codes (IEC 61800-7-304, as ETG.1000.6 lists them): the high nibble names
// the element (1 IDN, 2 name, 3 attribute, 4 unit, 5 minimum, 6 maximum, 7 operation data,
// 8 default / general), the low byte what went wrong.
namespace soe_error {
constexpr std::uint16_t kNoIdn = 0x1001;
constexpr std::uint16_t kInvalidAccessToElement1 = 0x1009;
constexpr std::uint16_t kNoName = 0x2001;
constexpr std::uint16_t kNameReadOnly = 0x2004;
constexpr std::uint16_t kAttributeReadOnly = 0x3004;
constexpr std::uint16_t kNoUnit = 0x4001;
constexpr std::uint16_t kUnitReadOnly = 0x4004;
constexpr std::uint16_t kNoMinimum = 0x5001;
constexpr std::uint16_t kMinimumReadOnly = 0x5004;
constexpr std::uint16_t kNoMaximum = 0x6001;
constexpr std::uint16_t kMaximumReadOnly = 0x6004;
constexpr std::uint16_t kDataTooShort = 0x7002;
constexpr std::uint16_t kDataTooLong = 0x7003;
constexpr std::uint16_t kDataReadOnly = 0x7004;
constexpr std::uint16_t kDataWriteProtected = 0x7005;
constexpr std::uint16_t kDataBelowMinimum = 0x7006;
constexpr std::uint16_t kDataAboveMaximum = 0x7007;
constexpr std::uint16_t kInvalidData = 0x7008;
constexpr std::uint16_t kCommandAlreadyActive = 0x7010;
constexpr std::uint16_t kCommandNotExecutableNow = 0x7012;
constexpr std::uint16_t kCommandNotExecutable = 0x7013;
constexpr std::uint16_t kNoDataState = 0x7014;
constexpr std::uint16_t kNoDefault = 0x8001;
constexpr std::uint16_t kDefaultReadOnly = 0x8004;
constexpr std::uint16_t kInvalidDriveNumber = 0x800A;
constexpr std::uint16_t kGeneralError = 0x800B;
constexpr std::uint16_t kNoElementAddressed = 0x800C;
}  // namespace soe_error

// "IDN not present", "operation data is write protected at this time", ...; "unknown SoE error"
// for codes outside the table.
std::string_view soe_error_text(std::uint16_t code) noexcept;

// The value of an Errc::mailbox_error that is an SoE error response: this base + the code. It
// lies beside the 16-bit mailbox error details and the CoE client's kSdoFailureValueBase range.
inline constexpr std::uint32_t kSoeErrorValueBase = 0x0002'0000;
// The SoE error code of a failed transfer (searching the error's causes), or nullopt.
std::optional<std::uint16_t> soe_error_code(const Error& error) noexcept;

// ---- Transfers -------------------------------------------------------------------------------

// The bytes of the elements asked for (wire::kSoeElement* flags), as the drive sends them: in
// element order, fragments reassembled. split_soe_elements() takes several apart.
exec::Task<Result<std::vector<std::uint8_t>>> soe_read(
    Mailbox& mailbox, std::uint8_t drive_number, std::uint16_t idn,
    std::uint8_t elements = wire::kSoeElementValue, SoeOptions options = {});

// Writes `data` to the elements (normally only the value, kSoeElementValue), in fragments when it
// exceeds the mailbox.
exec::Task<Result<void>> soe_write(Mailbox& mailbox, std::uint8_t drive_number, std::uint16_t idn,
                                   std::uint8_t elements, std::vector<std::uint8_t> data,
                                   SoeOptions options = {});

// ---- Notifications -----------------------------------------------------------------------------

// A message the drive sent on its own: a notification (opcode 5: the data state of an IDN
// changed, a procedure command finished) or slave info (opcode 6).
struct SoeNotification {
  wire::SoeOpcode opcode = wire::SoeOpcode::notification;
  std::uint8_t drive_number = 0;
  std::uint8_t elements = 0;
  std::uint16_t idn = 0;  // fragments left when `incomplete`
  bool incomplete = false;
  std::vector<std::uint8_t> data;

  friend bool operator==(const SoeNotification&, const SoeNotification&) = default;
};

// Takes the SoE notifications and slave info the mailbox queued as unsolicited, oldest first;
// every other queued message stays where it is. Malformed SoE messages are dropped (counted in
// `malformed` when given).
std::vector<SoeNotification> soe_notifications(Mailbox& mailbox, std::size_t* malformed = nullptr);

// ---- Elements ------------------------------------------------------------------------------

// Display format of the attribute (bits 20..22).
enum class SoeDisplayFormat : std::uint8_t {
  binary = 0,
  unsigned_decimal = 1,
  signed_decimal = 2,
  hexadecimal = 3,
  text = 4,
  idn = 5,
  floating_point = 6,
  sercos_time = 7,
};
// "binary", "unsigned decimal", ...
std::string_view to_string(SoeDisplayFormat format) noexcept;

// The attribute element (4 bytes, little-endian), IEC 61800-7-204 as SOEM's ec_SoEattributet
// lays it out:
//   bits 0..15 conversion factor, 16..17 data length (1, 2, 4, 8 bytes), 18 variable length
//   (a list of such items), 19 procedure command, 20..22 display format, 24..27 decimal places,
//   28 / 29 / 30 write protected in PREOP (CP2) / SAFEOP (CP3) / OP (CP4).
struct SoeAttribute {
  std::uint16_t conversion_factor = 1;
  std::uint8_t length_code = 1;  // 0..3: items of 1 << length_code bytes
  bool list = false;
  bool procedure_command = false;
  SoeDisplayFormat format = SoeDisplayFormat::binary;
  std::uint8_t decimals = 0;  // 0..15
  bool write_protected_preop = false;
  bool write_protected_safeop = false;
  bool write_protected_op = false;

  // Bytes of one item: the value when not a list, one list entry otherwise.
  std::size_t item_size() const noexcept { return std::size_t{1} << (length_code & 0x03); }

  friend bool operator==(const SoeAttribute&, const SoeAttribute&) = default;
};
SoeAttribute decode_soe_attribute(std::uint32_t raw) noexcept;
// Fields beyond their bits are cut to them.
std::uint32_t encode_soe_attribute(const SoeAttribute& attribute) noexcept;
// From element bytes: exactly 4.
Result<SoeAttribute> decode_soe_attribute(wire::Bytes data);

// A variable-length element (names, units, strings, lists such as S-0-0017): actual length in
// bytes (2), maximum length in bytes (2), then the actual length's bytes.
constexpr std::size_t kSoeListHeaderSize = 4;
struct SoeList {
  std::uint16_t max_length = 0;
  std::vector<std::uint8_t> data;  // its size is the actual length

  friend bool operator==(const SoeList&, const SoeList&) = default;
};
// Reads one list from the start of `data` (bytes after it are left; `consumed` says how many
// were used). Fails when the actual length exceeds the bytes there.
Result<SoeList> decode_soe_list(wire::Bytes data, std::size_t* consumed = nullptr);
// Fails when the data exceeds the maximum length or 65535 bytes.
Result<std::vector<std::uint8_t>> encode_soe_list(const SoeList& list);
// A text list (a name, a unit, a string parameter): up to the first NUL.
Result<std::string> decode_soe_string(wire::Bytes data);
// An IDN list (S-0-0017, S-0-0016 ...): 2-byte IDNs; an odd actual length is malformed.
Result<std::vector<std::uint16_t>> decode_soe_idn_list(wire::Bytes data);
std::vector<std::uint8_t> encode_soe_idn_list(const std::vector<std::uint16_t>& idns,
                                              std::uint16_t max_count);

// The elements of one read response, taken apart.
struct SoeElements {
  std::optional<std::uint16_t> data_state;
  std::optional<std::string> name;
  std::optional<SoeAttribute> attribute;
  std::optional<std::string> unit;
  // As sent: fixed-size values, or lists with their 4-byte header.
  std::optional<std::vector<std::uint8_t>> minimum;
  std::optional<std::vector<std::uint8_t>> maximum;
  std::optional<std::vector<std::uint8_t>> value;
  std::optional<std::vector<std::uint8_t>> default_value;
};
// Splits `data` (a read of `elements`) in element order. The size of the minimum, maximum, value
// and default comes from the attribute (read in the same response, or `attribute`); without one
// only the last element may be of these (it takes the rest). Bytes left over are malformed.
Result<SoeElements> split_soe_elements(std::uint8_t elements, wire::Bytes data,
                                       std::optional<SoeAttribute> attribute = std::nullopt);
// soe_read + split_soe_elements; asks for the attribute too when it is needed to split.
exec::Task<Result<SoeElements>> soe_read_elements(Mailbox& mailbox, std::uint8_t drive_number,
                                                  std::uint16_t idn, std::uint8_t elements,
                                                  SoeOptions options = {});

}  // namespace ecat::master
