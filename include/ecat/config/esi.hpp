// EtherCAT Slave Information (ESI) device descriptions (ETG.2000 XML): the parts a master and the
// simulator use — identity, names, SyncManagers, FMMUs, PDOs, mailbox protocols, DC operation
// modes, EEPROM settings and the CoE object dictionary with its data types flattened into
// entries — and the SII image a device built to such a description carries.
//
// Numbers in ESI files are decimal or "#x"-prefixed hexadecimal; DefaultData is little-endian
// hex bytes. Errors name the element (and device) that could not be read.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::config {

// One subindex of a dictionary object, with its data type resolved.
struct EsiEntry {
  std::uint8_t subindex = 0;
  std::string name;
  std::string type;  // ESI type name: "UINT", "BOOL", "STRING(10)", "DINT" ...
  std::uint32_t bit_size = 0;
  std::uint32_t bit_offset = 0;
  std::string access = "ro";       // "ro", "rw", "wo"
  std::string write_restrictions;  // "", "PreOP", "PreOP_SafeOP", "PreOP_OP", "SafeOP_OP" ...
  std::string read_restrictions;
  std::string pdo_mapping;  // "", "R", "T", "RT" (upper case)
  bool backup = false;
  bool setting = false;
  std::vector<std::uint8_t> default_data;  // little-endian; empty: none given
  std::optional<std::int64_t> minimum;
  std::optional<std::int64_t> maximum;
};

enum class EsiObjectCode : std::uint8_t { var, array, record };

struct EsiObject {
  std::uint16_t index = 0;
  std::string name;
  std::string type;
  std::uint32_t bit_size = 0;
  EsiObjectCode code = EsiObjectCode::var;
  // VAR: subindex 0 only. ARRAY / RECORD: subindex 0 first, then the entries in order.
  std::vector<EsiEntry> entries;
};

struct EsiPdoEntry {
  std::uint16_t index = 0;  // 0: a gap
  std::uint8_t subindex = 0;
  std::uint8_t bit_length = 0;
  std::string name;
  std::string data_type;
};

struct EsiPdo {
  std::uint16_t index = 0;
  std::string name;
  std::optional<std::uint8_t> sync_manager;  // the Sm attribute: assigned by default
  bool fixed = false;
  bool mandatory = false;
  std::vector<std::uint16_t> excludes;
  std::vector<EsiPdoEntry> entries;
};

struct EsiSyncManager {
  std::string type;  // "MBoxOut", "MBoxIn", "Outputs", "Inputs"
  std::uint16_t start = 0;
  std::uint16_t default_size = 0;
  std::uint16_t min_size = 0;
  std::uint16_t max_size = 0;
  std::uint8_t control_byte = 0;
  bool enable = false;
  bool virtual_sm = false;
  bool op_only = false;
};

struct EsiDcOpMode {
  std::string name;
  std::string description;
  std::uint16_t assign_activate = 0;
  std::uint32_t cycle_time_sync0 = 0;
  std::int16_t cycle_time_sync0_factor = 0;
  std::int32_t shift_time_sync0 = 0;
  std::uint32_t cycle_time_sync1 = 0;
  std::int16_t cycle_time_sync1_factor = 0;
  std::int32_t shift_time_sync1 = 0;
};

struct EsiMailbox {
  bool aoe = false;
  bool eoe = false;
  bool coe = false;
  bool foe = false;
  bool soe = false;
  bool voe = false;
  bool data_link_layer = false;
  // CoE attributes.
  bool sdo_info = false;
  bool complete_access = false;
  bool pdo_assign = false;
  bool pdo_config = false;
  bool pdo_upload = false;
  bool segmented_sdo = false;
};

struct EsiDevice {
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::string type;  // the Type element's text (order code)
  std::string name;  // the first Name
  std::string group_type;
  std::string physics;                  // one letter per port: 'Y' MII, 'K' E-bus, ' ' none
  std::uint32_t profile_no = 0;         // 402 for drives, 5001 modular devices ...
  std::uint8_t sync_manager_count = 0;  // Info/EtherCATController; 0 when not given
  std::uint8_t fmmu_count = 0;
  std::uint32_t dpram_size = 0;
  std::vector<std::string> fmmus;  // "Outputs", "Inputs", "MBoxState"
  std::vector<EsiSyncManager> sync_managers;
  std::vector<EsiPdo> rxpdos;
  std::vector<EsiPdo> txpdos;
  std::optional<EsiMailbox> mailbox;
  std::vector<EsiDcOpMode> dc_op_modes;
  std::uint32_t eeprom_byte_size = 0;
  std::vector<std::uint8_t> eeprom_config_data;           // header words 0..6 as bytes
  std::optional<std::array<std::uint16_t, 4>> bootstrap;  // recv offset/size, send offset/size
  std::vector<EsiObject> objects;

  const EsiObject* object(std::uint16_t index) const noexcept;
};

struct EsiFile {
  std::uint32_t vendor_id = 0;
  std::string vendor_name;
  std::vector<EsiDevice> devices;
};

// Parses an ESI document.
Result<EsiFile> parse_esi(std::string_view xml);
// Reads and parses an ESI file.
Result<EsiFile> load_esi(const std::string& path);

// The device with `product_code` (the first revision listed), or — without a product code — the
// only device of the file. Errors list the product codes the file has.
Result<const EsiDevice*> find_esi_device(const EsiFile& file,
                                         std::optional<std::uint32_t> product_code);

// The CoE data type index of an ESI type name ("UINT" -> 0x0006, "BOOL" -> 0x0001,
// "STRING(10)" -> 0x0009), or 0 when the name is not a basic type.
std::uint16_t esi_basic_type(std::string_view type) noexcept;

// The SII image of a device built to this description: header (ConfigData, identity, mailboxes,
// bootstrap mailbox, protocols, EEPROM size), STRINGS, GENERAL, FMMU, SYNCM (process-data
// lengths = DefaultSize), TXPDO/RXPDO (PDOs without Sm unassigned: 0xFF) and DC.
Result<wire::SiiImage> esi_to_sii(const EsiFile& file, const EsiDevice& device);

}  // namespace ecat::config
