// The slave side of SoE (Servo drive profile over EtherCAT, mailbox type 5) for a simulated
// drive: IDN parameters with their seven elements, served through the device's CoeServer
// (CoeServer::set_protocol_handler(wire::MailboxType::soe, ...)), which keeps the mailbox
// mechanics (counters, repeats, queued replies).
//
// What it serves (ETG.1000.6 §5.9, IEC 61800-7-304):
//  - Read requests of any combination of name, attribute, unit, minimum, maximum, value and
//    default (in that order in the response); the data state element is not kept (0x7014).
//    A response larger than the reply mailbox goes out in fragments: incomplete flag set and the
//    fragments still to come in the IDN field, the last one with the IDN.
//  - Write requests of the value, in fragments as the master sends them (only the last one is
//    answered), bounded by SoeServerConfig::max_write_size. Refusals with their SoE error codes:
//    IDN not present 0x1001, another element than the value 0x2004/0x3004/0x4004/0x5004/0x6004/
//    0x8004, read only (write protected in every state) 0x7004, write protected in the present
//    AL state (attribute bits 28/29/30 for PREOP/SAFEOP/OP) 0x7005, too short / long 0x7002 /
//    0x7003, below the minimum / above the maximum 0x7006 / 0x7007, and what the device's write
//    hook refuses (procedure commands).
//  - Drive numbers 0..drives-1 (up to 8), each with its own copy of the IDNs; others 0x800A.
//  - Notifications (opcode 5) a device sends with notify().
// Fault hooks answer chosen IDNs with an error code, drop a fragment of a read response, or drop
// the response altogether.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/sim/coe_server.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/soe.hpp>
#include <ecat/wire/voe.hpp>

namespace ecat::sim {

class Esc;

// The attribute element's bits (IEC 61800-7-204; the master decodes them with
// master::decode_soe_attribute).
namespace soe_attribute {
constexpr std::uint32_t kLength1 = 0u << 16;  // items of 1, 2, 4, 8 bytes
constexpr std::uint32_t kLength2 = 1u << 16;
constexpr std::uint32_t kLength4 = 2u << 16;
constexpr std::uint32_t kLength8 = 3u << 16;
constexpr std::uint32_t kList = 1u << 18;     // variable length: a list of such items
constexpr std::uint32_t kCommand = 1u << 19;  // a procedure command
constexpr std::uint32_t kBinary = 0u << 20;   // display formats
constexpr std::uint32_t kUnsigned = 1u << 20;
constexpr std::uint32_t kSigned = 2u << 20;
constexpr std::uint32_t kHex = 3u << 20;
constexpr std::uint32_t kText = 4u << 20;
constexpr std::uint32_t kIdn = 5u << 20;
constexpr std::uint32_t kFloat = 6u << 20;
constexpr std::uint32_t kWriteProtectedPreop = 1u << 28;
constexpr std::uint32_t kWriteProtectedSafeop = 1u << 29;
constexpr std::uint32_t kWriteProtectedOp = 1u << 30;
constexpr std::uint32_t kReadOnly =
    kWriteProtectedPreop | kWriteProtectedSafeop | kWriteProtectedOp;
constexpr std::uint32_t decimals(unsigned n) {
  return (n & 0x0Fu) << 24;
}
}  // namespace soe_attribute

// One IDN with its elements. Fixed-size values hold exactly the attribute's item size; lists
// (attribute kList) hold the list's data without its 4-byte header, up to max_length bytes.
struct SoeIdn {
  std::uint16_t idn = 0;
  std::string name;
  std::uint32_t attribute = soe_attribute::kLength2;
  std::optional<std::string> unit;
  std::optional<std::vector<std::uint8_t>> minimum;
  std::optional<std::vector<std::uint8_t>> maximum;
  std::vector<std::uint8_t> value;
  std::optional<std::vector<std::uint8_t>> default_value;
  std::uint16_t max_length = 0;  // lists: the maximum length in bytes

  bool list() const noexcept { return (attribute & soe_attribute::kList) != 0; }
  std::size_t item_size() const noexcept { return std::size_t{1} << ((attribute >> 16) & 0x03); }
};

struct SoeServerConfig {
  std::uint8_t drives = 1;  // drive numbers 0..drives-1 (1..8)
  std::vector<SoeIdn> idns;
  std::size_t max_write_size = 64 * 1024;  // a longer fragmented write is refused (0x7003)
};

enum class SoeFaultKind : std::uint8_t {
  error_response,  // answer with SoE error code `value`
  drop_fragment,   // read: leave out fragment number `value` (1-based) of the response
  drop_response,   // no response at all: the master times out
};
// "error_response", "drop_fragment", "drop_response".
std::string_view to_string(SoeFaultKind kind) noexcept;

struct SoeFaultRule {
  std::uint8_t drive = 0;
  std::uint16_t idn = 0;
  bool write = false;  // a rule for writes of the IDN, else for reads
  SoeFaultKind kind = SoeFaultKind::error_response;
  std::uint16_t value = 0;
  bool once = false;  // removed after it fired; otherwise sticky until clear_faults()
};

struct SoeServerStats {
  std::uint64_t reads = 0;               // read requests answered (errors included)
  std::uint64_t writes = 0;              // write requests answered (errors included)
  std::uint64_t fragments_sent = 0;      // read responses beyond the first of a transfer
  std::uint64_t fragments_received = 0;  // incomplete write requests taken
  std::uint64_t errors_sent = 0;
  std::uint64_t notifications_sent = 0;
  std::uint64_t faults_applied = 0;
};

class SoeServer {
 public:
  // Told before the master's write of a value is stored (all checks passed): 0 accepts it, an
  // SoE error code refuses it. Procedure commands and model parameters hook in here.
  using WriteHook = std::function<std::uint16_t(Esc& esc, std::uint8_t drive, std::uint16_t idn,
                                                const std::vector<std::uint8_t>& value)>;

  // `mailbox` carries the replies (it must outlive this server).
  SoeServer(CoeServer& mailbox, SoeServerConfig config);

  // The CoeServer protocol handler for wire::MailboxType::soe.
  std::vector<MailboxReply> handle(Esc& esc, const wire::MailboxHeader& header, wire::Bytes data);
  // Power-up: every IDN back to its configured elements, a write in progress dropped (faults
  // and stats are kept).
  void power_up();

  // ---- Device side --------------------------------------------------------------------------
  const SoeIdn* find(std::uint8_t drive, std::uint16_t idn) const noexcept;
  // Sets a value as the device does (no protection, no limits); false when the IDN is missing or
  // the size is wrong for it.
  bool set_value(std::uint8_t drive, std::uint16_t idn, std::vector<std::uint8_t> value);
  // A fixed-size value as a little-endian integer (sign-extended for signed display formats).
  std::optional<std::int64_t> number(std::uint8_t drive, std::uint16_t idn) const noexcept;
  bool set_number(std::uint8_t drive, std::uint16_t idn, std::int64_t value);
  // Sends a notification (opcode 5) for the IDN; while a request is being handled it follows
  // that request's response.
  void notify(Esc& esc, std::uint8_t drive, std::uint16_t idn, std::uint8_t elements,
              std::vector<std::uint8_t> data);
  void set_write_hook(WriteHook hook) { write_hook_ = std::move(hook); }

  // ---- Fault hooks ----------------------------------------------------------------------------
  // Replaces a rule for the same (drive, idn, write).
  void add_fault(const SoeFaultRule& rule);
  void clear_faults() { faults_.clear(); }
  const std::vector<SoeFaultRule>& faults() const noexcept { return faults_; }

  const SoeServerStats& stats() const noexcept { return stats_; }
  const SoeServerConfig& config() const noexcept { return config_; }

 private:
  struct WriteTransfer {
    bool active = false;
    std::uint8_t drive = 0;
    std::uint8_t elements = 0;
    std::uint16_t left = 0;   // fragments still to come, as the last fragment said
    std::uint16_t error = 0;  // a refusal decided on the way (too long, lost fragment)
    std::vector<std::uint8_t> data;
  };

  std::vector<MailboxReply> read(Esc& esc, const wire::SoeHeader& header);
  std::vector<MailboxReply> write(Esc& esc, const wire::SoeHeader& header, wire::Bytes data);
  std::uint16_t apply_write(Esc& esc, std::uint8_t drive, std::uint16_t idn, std::uint8_t elements,
                            std::vector<std::uint8_t> data);
  MailboxReply error_reply(wire::SoeOpcode opcode, const wire::SoeHeader& request,
                           std::uint16_t code);
  std::optional<SoeFaultRule> take_fault(std::uint8_t drive, std::uint16_t idn, bool write);
  SoeIdn* find_mutable(std::uint8_t drive, std::uint16_t idn) noexcept;

  CoeServer& mailbox_;
  SoeServerConfig config_;
  std::vector<std::map<std::uint16_t, SoeIdn>> drives_;
  WriteTransfer write_;
  WriteHook write_hook_;
  std::vector<SoeFaultRule> faults_;
  SoeServerStats stats_;
  bool handling_ = false;
  std::vector<MailboxReply> deferred_;  // notifications sent while handling a request
};

// The SoE server of a device built on StandardApplication whose SII declares SoE, or nullptr.
SoeServer* soe_server_of(Esc& esc) noexcept;

// ---- VoE ---------------------------------------------------------------------------------------
// Vendor specific messages (mailbox type 15) have no server of their own: a device installs a
// handler with CoeServer::set_protocol_handler(wire::MailboxType::voe, voe_handler(...)). The
// handler sees decoded messages and returns the messages to send back; a request too short for
// the VoE header is answered with mailbox error 0x06 (size too short).
using VoeHandler =
    std::function<std::vector<wire::VoeMessage>(Esc& esc, const wire::VoeMessage& request)>;
CoeServer::ProtocolHandler voe_handler(VoeHandler handler);
// The "mailbox" profile's handler: every message echoed with vendor type + 1.
std::vector<wire::VoeMessage> voe_echo(Esc& esc, const wire::VoeMessage& request);

}  // namespace ecat::sim
