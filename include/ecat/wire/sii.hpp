// The SII (slave information interface) EEPROM image: decoding a whole image into typed fields
// and encoding typed fields back into an image. Layout per ETG.1000.6 and ETG.2010:
//
//   words 0x00..0x3F  fixed header: ESC configuration area (0x00..0x07, CRC-8 in word 7),
//                     identity (0x08..0x0F), delays, bootstrap and standard mailbox, mailbox
//                     protocols (0x1C), EEPROM size (0x3E), version (0x3F)
//   words 0x40..      categories: type (1 word), size in words (1 word), data; type 0xFFFF ends
//
// Decoding is tolerant: real images are sometimes truncated or carry a bad checksum, so anything
// that can still be read is returned, with one warning per problem naming the category and its
// word address. Only images with nothing to read (too short for the header, blank) are errors.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

// Word addresses of the fixed header.
namespace sii_word {
constexpr std::uint16_t kPdiControl = 0x0000;
constexpr std::uint16_t kPdiConfiguration = 0x0001;
constexpr std::uint16_t kSyncImpulseLength = 0x0002;
constexpr std::uint16_t kPdiConfiguration2 = 0x0003;
constexpr std::uint16_t kStationAlias = 0x0004;
constexpr std::uint16_t kChecksum = 0x0007;
constexpr std::uint16_t kVendorId = 0x0008;
constexpr std::uint16_t kProductCode = 0x000A;
constexpr std::uint16_t kRevision = 0x000C;
constexpr std::uint16_t kSerialNumber = 0x000E;
constexpr std::uint16_t kExecutionDelay = 0x0010;
constexpr std::uint16_t kPort0Delay = 0x0011;
constexpr std::uint16_t kPort1Delay = 0x0012;
constexpr std::uint16_t kBootstrapMailbox = 0x0014;  // 4 words: recv offset/size, send offset/size
constexpr std::uint16_t kStandardMailbox = 0x0018;   // 4 words, same layout
constexpr std::uint16_t kMailboxProtocols = 0x001C;
constexpr std::uint16_t kEepromSize = 0x003E;
constexpr std::uint16_t kVersion = 0x003F;
constexpr std::uint16_t kFirstCategory = 0x0040;
}  // namespace sii_word

constexpr std::size_t kSiiHeaderWords = 0x40;
constexpr std::size_t kSiiHeaderBytes = 2 * kSiiHeaderWords;
constexpr std::size_t kSiiChecksummedBytes = 14;  // words 0..6

// True for header words that carry no named field of SiiImage (5, 6, 0x13, 0x1D..0x3D).
constexpr bool sii_header_word_reserved(std::size_t word) noexcept {
  return word == 5 || word == 6 || word == 0x13 || (word >= 0x1D && word <= 0x3D);
}

// CRC-8 of the ESC configuration area: polynomial x^8 + x^2 + x + 1 (0x07), initial value 0xFF,
// no reflection, no final XOR. The SII stores it in the low byte of word 7.
std::uint8_t sii_crc8(Bytes bytes) noexcept;

// Category types.
namespace sii_category {
constexpr std::uint16_t kNop = 0;
constexpr std::uint16_t kStrings = 10;
constexpr std::uint16_t kDataTypes = 20;
constexpr std::uint16_t kGeneral = 30;
constexpr std::uint16_t kFmmu = 40;
constexpr std::uint16_t kSyncManager = 41;
constexpr std::uint16_t kFmmuEx = 42;
constexpr std::uint16_t kSyncUnit = 43;
constexpr std::uint16_t kTxPdo = 50;
constexpr std::uint16_t kRxPdo = 51;
constexpr std::uint16_t kDc = 60;
constexpr std::uint16_t kEnd = 0xFFFF;
}  // namespace sii_category

// "STRINGS", "DATATYPES", "GENERAL", "FMMU", "SYNCM", "FMMU_EX", "SYNCUNIT", "TXPDO", "RXPDO",
// "DC", "END", "NOP"; "vendor/unknown" for any other type.
std::string_view sii_category_name(std::uint16_t type) noexcept;

// Mailbox protocol bits of word 0x1C.
namespace mailbox_protocol {
constexpr std::uint16_t kAoe = 0x0001;
constexpr std::uint16_t kEoe = 0x0002;
constexpr std::uint16_t kCoe = 0x0004;
constexpr std::uint16_t kFoe = 0x0008;
constexpr std::uint16_t kSoe = 0x0010;
constexpr std::uint16_t kVoe = 0x0020;
}  // namespace mailbox_protocol

// "AoE", "EoE", "CoE", "FoE", "SoE", "VoE" for the bits set, in bit order; other bits are
// skipped.
std::vector<std::string_view> mailbox_protocol_names(std::uint16_t mask);

struct SiiIdentity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::uint32_t serial = 0;

  bool operator==(const SiiIdentity&) const = default;
};

// A mailbox's SyncManager areas: "receive" is master -> slave (SM0 for the standard mailbox),
// "send" is slave -> master (SM1).
struct SiiMailbox {
  std::uint16_t recv_offset = 0;
  std::uint16_t recv_size = 0;
  std::uint16_t send_offset = 0;
  std::uint16_t send_size = 0;

  bool present() const noexcept { return recv_size != 0 && send_size != 0; }
  bool operator==(const SiiMailbox&) const = default;
};

// GENERAL category (30), 32 bytes.
namespace sii_coe_detail {
constexpr std::uint8_t kSdo = 0x01;
constexpr std::uint8_t kSdoInfo = 0x02;
constexpr std::uint8_t kPdoAssign = 0x04;
constexpr std::uint8_t kPdoConfiguration = 0x08;
constexpr std::uint8_t kPdoUploadAtStartup = 0x10;
constexpr std::uint8_t kSdoCompleteAccess = 0x20;
}  // namespace sii_coe_detail

namespace sii_general_flag {
constexpr std::uint8_t kEnableSafeOp = 0x01;
constexpr std::uint8_t kEnableNotLrw = 0x02;
constexpr std::uint8_t kMailboxDataLinkLayer = 0x04;
constexpr std::uint8_t kIdentAlStatus = 0x08;
constexpr std::uint8_t kIdentPhysicalMemory = 0x10;
}  // namespace sii_general_flag

// Port types in the GENERAL physical port word (4 bits per port).
namespace sii_port {
constexpr std::uint8_t kUnused = 0;
constexpr std::uint8_t kMii = 1;
constexpr std::uint8_t kReserved = 2;
constexpr std::uint8_t kEbus = 3;
constexpr std::uint8_t kFastHotConnect = 4;
}  // namespace sii_port
// "unused", "MII", "reserved", "EBUS", "fast hot connect"; "unknown" otherwise.
std::string_view sii_port_name(std::uint8_t code) noexcept;

struct SiiGeneral {
  static constexpr std::size_t kSize = 32;

  std::uint8_t group_index = 0;  // string indices: 1-based, 0 = none
  std::uint8_t image_index = 0;
  std::uint8_t order_index = 0;
  std::uint8_t name_index = 0;
  std::uint8_t reserved_4 = 0;  // byte 4, kept as found
  std::uint8_t coe_details = 0;
  std::uint8_t foe_details = 0;
  std::uint8_t eoe_details = 0;
  std::uint8_t soe_channels = 0;
  std::uint8_t ds402_channels = 0;
  std::uint8_t sysman_class = 0;
  std::uint8_t flags = 0;
  std::int16_t current_on_ebus_ma = 0;  // negative: the device feeds the E-bus
  std::uint8_t group_index_2 = 0;       // byte 14: second group index (compatibility)
  std::uint8_t reserved_15 = 0;
  std::uint16_t physical_port = 0;               // byte 16: 4 bits per port, see sii_port
  std::uint16_t physical_memory_address = 0;     // byte 18
  std::array<std::uint8_t, 12> reserved_tail{};  // bytes 20..31, kept as found

  std::uint8_t port(std::size_t index) const noexcept {
    return static_cast<std::uint8_t>((physical_port >> (4 * (index % 4))) & 0x0Fu);
  }
  bool operator==(const SiiGeneral&) const = default;
};

// FMMU category (40): one usage byte per FMMU.
namespace sii_fmmu_usage {
constexpr std::uint8_t kUnused = 0x00;
constexpr std::uint8_t kOutputs = 0x01;
constexpr std::uint8_t kInputs = 0x02;
constexpr std::uint8_t kMailboxState = 0x03;  // SyncManager status (mailbox full flag)
constexpr std::uint8_t kNone = 0xFF;          // also unused (fills the category to whole words)
}  // namespace sii_fmmu_usage
// "unused", "outputs", "inputs", "mailbox_state"; "unknown" otherwise.
std::string_view sii_fmmu_usage_name(std::uint8_t usage) noexcept;

// SYNCM category (41): 8 bytes per SyncManager.
namespace sii_sm_type {
constexpr std::uint8_t kUnused = 0;
constexpr std::uint8_t kMailboxOut = 1;  // master -> slave
constexpr std::uint8_t kMailboxIn = 2;   // slave -> master
constexpr std::uint8_t kOutputs = 3;
constexpr std::uint8_t kInputs = 4;
}  // namespace sii_sm_type
// "unused", "mailbox_out", "mailbox_in", "outputs", "inputs"; "unknown" otherwise.
std::string_view sii_sync_manager_type_name(std::uint8_t type) noexcept;

struct SiiSyncManager {
  static constexpr std::size_t kSize = 8;

  std::uint16_t start = 0;
  std::uint16_t length = 0;
  std::uint8_t control = 0;  // as the SyncManager control register (see SmControl)
  std::uint8_t status = 0;
  std::uint8_t enable = 0;  // bit 0 enable, 1 fixed content, 2 virtual, 3 OP only
  std::uint8_t type = 0;    // see sii_sm_type

  bool enabled() const noexcept { return (enable & 0x01) != 0; }
  bool fixed_content() const noexcept { return (enable & 0x02) != 0; }
  bool virtual_sm() const noexcept { return (enable & 0x04) != 0; }
  bool op_only() const noexcept { return (enable & 0x08) != 0; }
  bool operator==(const SiiSyncManager&) const = default;
};

// TXPDO (50) / RXPDO (51) categories: 8-byte PDO header, then 8 bytes per entry.
namespace sii_pdo_flag {
constexpr std::uint16_t kMandatory = 0x0001;
constexpr std::uint16_t kDefault = 0x0002;
constexpr std::uint16_t kFixedContent = 0x0010;
constexpr std::uint16_t kVirtualContent = 0x0020;
constexpr std::uint16_t kDownloadAnyway = 0x0040;
constexpr std::uint16_t kFromModule = 0x0080;
}  // namespace sii_pdo_flag

struct SiiPdoEntry {
  static constexpr std::size_t kSize = 8;

  std::uint16_t index = 0;  // 0 with subindex 0: a padding (gap) entry
  std::uint8_t subindex = 0;
  std::uint8_t name_index = 0;
  std::uint8_t data_type = 0;  // CoE basic data type index (0x01 BOOLEAN, 0x07 UNSIGNED32, ...)
  std::uint8_t bit_length = 0;
  std::uint16_t flags = 0;

  bool padding() const noexcept { return index == 0; }
  bool operator==(const SiiPdoEntry&) const = default;
};

struct SiiPdo {
  static constexpr std::size_t kHeaderSize = 8;

  std::uint16_t index = 0;
  std::uint8_t sync_manager = 0;  // 0xFF: not assigned
  std::uint8_t dc_sync = 0;
  std::uint8_t name_index = 0;
  std::uint16_t flags = 0;
  std::vector<SiiPdoEntry> entries;  // the count byte of the header is entries.size()

  std::uint32_t bit_length() const noexcept;
  bool operator==(const SiiPdo&) const = default;
};

// DC category (60): 24 bytes per operation mode.
struct SiiDcSync {
  static constexpr std::size_t kSize = 24;

  std::uint32_t cycle_time_0 = 0;
  std::uint32_t shift_time_0 = 0;
  std::uint32_t shift_time_1 = 0;
  std::int16_t sync1_cycle_factor = 0;
  std::uint16_t assign_activate = 0;
  std::int16_t sync0_cycle_factor = 0;
  std::uint8_t name_index = 0;
  std::uint8_t description_index = 0;
  std::uint32_t reserved = 0;  // bytes 20..23, kept as found

  bool operator==(const SiiDcSync&) const = default;
};

// A category kept as bytes (vendor or unknown types).
struct SiiRawCategory {
  std::uint16_t type = 0;
  std::vector<std::uint8_t> data;

  bool operator==(const SiiRawCategory&) const = default;
};

// The content of an SII image. decode_sii fills it; encode_sii turns it back into bytes.
struct SiiImage {
  // Fixed header.
  std::uint16_t pdi_control = 0;
  std::uint16_t pdi_configuration = 0;
  std::uint16_t sync_impulse_length = 0;  // in 10 ns units
  std::uint16_t pdi_configuration2 = 0;
  std::uint16_t station_alias = 0;
  SiiIdentity identity;
  std::uint16_t execution_delay = 0;
  std::uint16_t port0_delay = 0;
  std::uint16_t port1_delay = 0;
  SiiMailbox bootstrap_mailbox;
  SiiMailbox standard_mailbox;
  std::uint16_t mailbox_protocols = 0;  // see mailbox_protocol
  std::uint16_t eeprom_size = 15;       // word 0x3E: EEPROM size in KiBit minus 1 (15: 2 KiB)
  std::uint16_t version = 1;
  // Header words without a named field (sii_header_word_reserved), kept as found; the encoder
  // writes only those positions back and ignores the others.
  std::array<std::uint16_t, kSiiHeaderWords> reserved_words{};

  // Categories. Several categories of one type are merged in image order (GENERAL: the first
  // one wins). The encoder writes them in ascending category type.
  std::vector<std::string> strings;  // STRINGS; string index i is strings[i - 1]; Latin-1 bytes
  std::optional<std::vector<std::uint8_t>> data_types;  // DATATYPES, raw
  std::optional<SiiGeneral> general;
  std::vector<std::uint8_t> fmmus;  // FMMU usage bytes (an odd count is padded with 0xFF)
  std::vector<SiiSyncManager> sync_managers;
  std::optional<std::vector<std::uint8_t>> fmmu_ex;    // FMMU_EX, raw
  std::optional<std::vector<std::uint8_t>> sync_unit;  // SYNCUNIT, raw
  std::vector<SiiPdo> txpdos;
  std::vector<SiiPdo> rxpdos;
  std::vector<SiiDcSync> dc;
  std::vector<SiiRawCategory> other_categories;  // vendor/unknown, ascending type

  std::size_t eeprom_size_bytes() const noexcept {
    return (static_cast<std::size_t>(eeprom_size) + 1) * 128;
  }
  // The string with 1-based `index`; empty for 0 and for indices past the STRINGS category.
  std::string_view string(std::uint8_t index) const noexcept;
  // The device name (GENERAL name string), else the first string, else empty.
  std::string_view device_name() const noexcept;

  bool operator==(const SiiImage&) const = default;
};

// Where a category sat in a decoded image.
struct SiiCategoryInfo {
  std::uint16_t type = 0;
  std::size_t word_address = 0;  // of the category header
  std::size_t size_words = 0;    // as declared (0 for END)
  bool truncated = false;        // the image ends before the declared size

  bool operator==(const SiiCategoryInfo&) const = default;
};

struct SiiDecoded {
  SiiImage image;
  std::vector<SiiCategoryInfo> categories;  // image order, END included when present
  std::uint16_t checksum_word = 0;          // word 7 as found
  std::uint8_t checksum_computed = 0;       // CRC-8 of bytes 0..13
  bool checksum_ok = false;
  std::vector<std::string> warnings;  // every irregularity, each naming where it is
};

// Decodes a whole image (any length; a trailing odd byte is ignored with a warning).
// Errors only when there is nothing to decode: fewer than 128 bytes (the fixed header), or a
// blank image (every byte 0xFF or every byte 0x00).
Result<SiiDecoded> decode_sii(Bytes image);

struct SiiEncodeOptions {
  // Fill with 0xFF after the END marker up to eeprom_size_bytes(), as a real EEPROM reads.
  bool pad_to_eeprom_size = true;
};

// Encodes header (with its CRC), categories (ascending type, each padded to whole words) and the
// END marker. Fails when a field cannot be represented: more than 255 strings, a string or a PDO
// with more than 255 bytes or entries, a category over 65535 words, or an other_categories
// entry whose type is NOP, END or one with its own field.
Result<std::vector<std::uint8_t>> encode_sii(const SiiImage& image, SiiEncodeOptions options = {});

// SII strings are Latin-1 bytes (real images use bytes such as 0xB5 for "µ"); this converts them
// for display and JSON.
std::string sii_string_to_utf8(std::string_view latin1);

}  // namespace ecat::wire
