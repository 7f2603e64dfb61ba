// The slave side of File access over EtherCAT (ETG.1000.6 §5.8) for a simulated device: a small
// file store and a firmware slot, served through the CoE server's mailbox (a StandardApplication
// whose SII declares FoE installs it with CoeServer::set_protocol_handler).
//
// What it answers, as slave stacks do (SOES foe.c, Beckhoff terminals):
//   RRQ  unknown file -> ERROR 0x8001 not found; wrong password -> ERROR 0x800A no rights (SOES
//        compares the request's password with the file's and answers FOE_ERR_NORIGHTS);
//        else DATA(1), and DATA(n+1) for every ACK(n) until a packet shorter than the reply
//        mailbox allows (an empty one when the file is an exact multiple) has been acknowledged.
//   WRQ  read-only file -> ERROR 0x8002 access denied; wrong password -> 0x800A; the firmware
//        file outside BOOTSTRAP -> ERROR 0x8009 not in bootstrap; else ACK(0), then ACK(n) for
//        every DATA(n) until a short packet ends the file. A configurable number of BUSY answers
//        precede each ACK (a device that flashes slowly): the master sends the packet again.
//   A packet number out of sequence -> ERROR 0x8005; a file beyond the store's bound -> 0x8003
//   disk full; an opcode that makes no sense now -> ERROR 0x8004 illegal; an ERROR from the
//   master ends the transfer without a reply.
//
// The firmware slot: a complete write of FoeServerConfig::firmware_file in BOOTSTRAP is checked
// (see FirmwareImage: header, length and CRC-32); a bad image is refused with ERROR 0x800C
// checksum error in place of the last ACK and the old image is kept. A good one is started when
// the device leaves BOOTSTRAP for INIT: firmware() reports it and the dictionary's 0x100A
// (manufacturer software version) becomes its version, also after later power cycles.
//
// Fault hooks (tests): an ERROR after N packets of the next transfer, a reply that is never sent
// (the master's repeat request then gets the previous reply again, which it drops as a
// duplicate: the transfer times out), and a wrong packet number in a reply.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/foe.hpp>

namespace ecat::sim {

class Esc;

// The simulator's firmware image format (a real device has its vendor's):
//   offset 0  magic "ECFW"
//          4  payload length, u32 little-endian
//          8  CRC-32 (IEEE 802.3, as zlib) of the payload, u32 little-endian
//         12  version, 32 bytes of text, NUL-padded
//         44  payload
struct FirmwareImage {
  std::string version;
  std::vector<std::uint8_t> payload;

  friend bool operator==(const FirmwareImage&, const FirmwareImage&) = default;
};
constexpr std::size_t kFirmwareHeaderSize = 44;
constexpr std::size_t kFirmwareVersionSize = 32;

// CRC-32 (reflected polynomial 0xEDB88320, initial and final XOR 0xFFFFFFFF).
std::uint32_t crc32(wire::Bytes bytes) noexcept;
// An image of `version` (at most 32 characters, no NUL) and `payload`.
Result<std::vector<std::uint8_t>> make_firmware_image(std::string_view version,
                                                      wire::Bytes payload);
// Errc::malformed naming what is wrong (magic, length, checksum, version).
Result<FirmwareImage> parse_firmware_image(wire::Bytes image);

struct FoeFile {
  std::vector<std::uint8_t> data;
  std::uint32_t password = 0;  // 0: none
  bool read_only = false;
};

struct FoeServerConfig {
  // All files together (writes in progress included); beyond it a write fails with disk full.
  std::size_t max_total_size = 8 * 1024 * 1024;
  // The firmware slot: writable in BOOTSTRAP only, never readable (ERROR access denied).
  std::string firmware_file = "firmware.efw";
  std::uint32_t firmware_password = 0;
  std::size_t max_firmware_size = 4 * 1024 * 1024;
  // BUSY answers before each DATA packet of a write is acknowledged.
  std::uint32_t busy_per_packet = 0;
};

enum class FoeFaultKind : std::uint8_t {
  error,         // answer with ERROR `code` (text "injected fault") and drop the transfer
  drop_reply,    // take the packet but send no reply
  wrong_packet,  // the reply's packet number one too high
  busy,          // writes: answer the DATA packet with BUSY `count` times before taking it
};
// "error", "drop_reply", "wrong_packet", "busy".
std::string_view to_string(FoeFaultKind kind) noexcept;

// Fires at the reply to the packet that follows `after_packets` DATA (write) or ACK (read)
// packets of a transfer (0: the reply to the request itself); once.
struct FoeFault {
  FoeFaultKind kind = FoeFaultKind::error;
  std::uint32_t after_packets = 0;
  std::uint32_t code = static_cast<std::uint32_t>(wire::FoeErrorCode::not_defined);
  std::uint32_t count = 1;  // busy: BUSY answers (1..)
};

struct FoeServerStats {
  std::uint64_t requests = 0;      // RRQ and WRQ taken
  std::uint64_t data_sent = 0;     // DATA packets sent (reads)
  std::uint64_t data_taken = 0;    // DATA packets acknowledged (writes)
  std::uint64_t busy_sent = 0;     // BUSY answers
  std::uint64_t errors_sent = 0;   // ERROR answers
  std::uint64_t errors_taken = 0;  // ERROR packets from the master
  std::uint64_t files_read = 0;    // reads completed (last ACK taken)
  std::uint64_t files_written = 0;
  std::uint64_t faults_applied = 0;
  std::uint64_t firmware_updates = 0;  // new images started
};

class FoeServer {
 public:
  // `dictionary` (0x100A) must outlive the server.
  explicit FoeServer(ObjectDictionary& dictionary, FoeServerConfig config = {});

  // The CoeServer's protocol handler for mailbox type 4.
  std::vector<MailboxReply> handle(Esc& esc, wire::Bytes data);
  // The device changed AL state: a transfer ends at INIT; BOOT -> INIT starts a new image.
  void on_state_changed(wire::AlState from, wire::AlState to);
  // A power cycle: the dictionary is back at its initial content (files and firmware stay, as in
  // flash): 0x100A is set to the running image's version again.
  void on_power_up();

  // ---- The file store ---------------------------------------------------------------------------
  // Fails (out_of_range) when the store's bound would be exceeded, or for the firmware file.
  Result<void> put_file(std::string name, FoeFile file);
  const FoeFile* file(std::string_view name) const;
  bool remove_file(std::string_view name);
  std::size_t stored_bytes() const noexcept;

  // ---- Firmware ---------------------------------------------------------------------------------
  // The running image (version from the dictionary's 0x100A until an update).
  const FirmwareImage& firmware() const noexcept { return firmware_; }
  // An image written in BOOTSTRAP that starts at BOOT -> INIT.
  const std::optional<FirmwareImage>& pending_firmware() const noexcept { return pending_; }

  // ---- Faults and observation
  // --------------------------------------------------------------------
  void add_fault(const FoeFault& fault) { faults_.push_back(fault); }
  void clear_faults() noexcept { faults_.clear(); }
  const std::vector<FoeFault>& faults() const noexcept { return faults_; }
  void set_busy_per_packet(std::uint32_t n) noexcept { config_.busy_per_packet = n; }
  bool transfer_in_progress() const noexcept { return transfer_.mode != Mode::idle; }
  const FoeServerStats& stats() const noexcept { return stats_; }
  const FoeServerConfig& config() const noexcept { return config_; }

 private:
  enum class Mode : std::uint8_t { idle, reading, writing };
  struct Transfer {
    Mode mode = Mode::idle;
    std::string name;
    bool firmware = false;
    std::uint32_t password = 0;
    std::uint32_t packet = 0;  // reads: last DATA sent; writes: last DATA acknowledged
    std::size_t offset = 0;    // reads: next byte to send
    bool last_sent = false;    // reads: the short packet is out, its ACK ends the read
    std::uint32_t busy_left = 0;
    std::uint32_t busy_total = 0;      // BUSY answers this packet gets in all
    std::vector<std::uint8_t> buffer;  // writes
  };

  std::vector<MailboxReply> read_request(Esc& esc, const wire::FoeReadRequest& request);
  std::vector<MailboxReply> write_request(Esc& esc, const wire::FoeWriteRequest& request);
  std::vector<MailboxReply> ack(Esc& esc, const wire::FoeAck& ack);
  std::vector<MailboxReply> data(Esc& esc, const wire::FoeData& data);
  std::vector<MailboxReply> next_data(Esc& esc);
  std::vector<MailboxReply> finish_write();
  std::vector<MailboxReply> error(wire::FoeErrorCode code, std::string text);
  std::vector<MailboxReply> reply(const wire::FoeMessage& message);
  // A fault due at the reply to packet `packet` of the transfer, taken from the list.
  std::optional<FoeFault> take_fault(std::uint32_t packet);
  std::vector<MailboxReply> apply_fault(const FoeFault& fault, wire::FoeMessage message);
  void start_firmware(FirmwareImage image);
  void set_software_version();

  ObjectDictionary& od_;
  FoeServerConfig config_;
  std::map<std::string, FoeFile, std::less<>> files_;
  FirmwareImage firmware_;
  bool firmware_updated_ = false;
  std::optional<FirmwareImage> pending_;
  Transfer transfer_;
  std::vector<FoeFault> faults_;
  FoeServerStats stats_;
};

// The FoE server of a device built on StandardApplication, or nullptr (no FoE).
FoeServer* foe_server_of(Esc& esc) noexcept;

}  // namespace ecat::sim
