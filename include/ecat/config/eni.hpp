// EtherCAT Network Information (ENI, ETG.2100 XML): the file TwinCAT, EC-Engineer and other
// configurators export to describe one configured ring: the master, the slaves in ring order with
// their identities, process data (SyncManagers, PDO assignment and mapping), mailbox start-up
// commands (CoE, SoE), distributed-clock settings, the ESC register writes the configurator
// computed, and the master's cyclic frames.
//
// This reader only parses: neutral structs, no master types (the config layer sits below the
// master). ecat::master::import_eni (master/config.hpp) maps the result onto a MasterConfig.
//
// The element names follow the ETG.2100 structure as published ENIs use it (for example the
// `EtherCATConfig/Config/{Master,Slave,Cyclic,ProcessImage}` tree of the ENI test files in
// leducp/KickCAT unit/kickcat_eni_test_*.xml, and the ENI field list of Hilscher's EtherCAT
// master API header). Numbers are decimal or hexadecimal ("#x1A00", "0x1A00"), negative decimal
// values of 32-bit fields are taken as their two's complement (xs:int in the schema), Data is
// hex bytes ("0100001a"). The file is hostile input: every error names source:line and the
// element; lists are bounded (kMaxEni*) so a crafted file cannot make the reader allocate
// without limit beyond the file's own size.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>

namespace ecat::config {

// Bounds on what one ENI may hold (far above any real ring).
inline constexpr std::size_t kMaxEniSlaves = 4096;
inline constexpr std::size_t kMaxEniPdos = 512;         // per slave and direction
inline constexpr std::size_t kMaxEniPdoEntries = 255;   // per PDO (CoE subindex limit)
inline constexpr std::size_t kMaxEniInitCmds = 4096;    // per list
inline constexpr std::size_t kMaxEniDataBytes = 65536;  // one command's Data

struct EniPdoEntry {
  std::uint16_t index = 0;  // 0: a gap of bit_length bits
  std::uint8_t subindex = 0;
  std::uint8_t bit_length = 0;
  std::string name{};
  std::string data_type{};  // as written: "BOOL", "UINT", "DINT", "BIT2" ...; empty when absent
  int line = 0;
};

struct EniPdo {
  std::uint16_t index = 0;
  std::string name{};
  bool fixed = false;
  bool mandatory = false;
  std::optional<std::uint8_t> sync_manager{};  // the Sm attribute: the SM it is assigned to
  std::vector<EniPdoEntry> entries{};
  int line = 0;
};

// <Sm0>..<Sm15> of <ProcessData>: a process-data SyncManager and the PDOs assigned to it.
struct EniSyncManager {
  std::uint8_t index = 0;
  std::string type{};  // "Outputs", "Inputs" (as written)
  std::uint16_t default_size = 0;
  std::uint16_t start_address = 0;
  std::uint8_t control_byte = 0;
  bool enable = false;
  std::vector<std::uint16_t> pdos{};  // <Pdo> children, in order
  int line = 0;
};

// <Send>/<Recv> of <ProcessData>: where the slave's outputs / inputs sit in the configurator's
// process image (bits).
struct EniImageRange {
  std::uint32_t bit_start = 0;
  std::uint32_t bit_length = 0;
};

struct EniProcessData {
  std::optional<EniImageRange> send{};  // outputs (master -> slave)
  std::optional<EniImageRange> recv{};  // inputs
  std::vector<EniSyncManager> sync_managers{};
  std::vector<EniPdo> rx_pdos{};  // outputs
  std::vector<EniPdo> tx_pdos{};  // inputs
};

// Mailbox/CoE/InitCmds/InitCmd: an SDO download (Ccs 1) or upload (Ccs 2) the configurator wants
// at the given transitions. Transitions are kept as written ("IP", "PS", "SO", "SP", "OP", "PI",
// "SI", "OI", "IB", "BI", "II"); the master layer decides what it runs.
struct EniCoeInitCmd {
  std::vector<std::string> transitions{};
  std::string comment{};
  std::uint8_t ccs = 1;  // 1: download, 2: upload
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::vector<std::uint8_t> data{};
  bool complete_access = false;
  bool fixed = false;
  bool disabled = false;  // Disabled="true": listed, not to be sent
  std::uint32_t timeout_ms = 0;
  int line = 0;
};

// Mailbox/SoE/InitCmds/InitCmd: a SERCOS parameter write (IDN, drive number, data).
struct EniSoeInitCmd {
  std::vector<std::string> transitions{};
  std::string comment{};
  std::uint8_t op_code = 0;
  std::uint8_t drive_no = 0;
  std::uint16_t idn = 0;
  std::vector<std::uint8_t> data{};
  int line = 0;
};

struct EniMailbox {
  std::uint16_t send_start = 0;  // master -> slave mailbox (SM0)
  std::uint16_t send_length = 0;
  std::uint16_t recv_start = 0;
  std::uint16_t recv_length = 0;
  std::vector<std::string> protocols{};  // <Protocol> children: "CoE", "SoE", "EoE", "FoE", ...
  std::vector<EniCoeInitCmd> coe_init_cmds{};
  std::vector<EniSoeInitCmd> soe_init_cmds{};
  bool has_eoe = false;  // an <EoE> element (IP settings, ...)
  int line = 0;
};

// Slave/InitCmds/InitCmd and Master/InitCmds/InitCmd: one EtherCAT command (ESC register access)
// the configurator computed: Cmd is the datagram command (1 APRD, 2 APWR, 4 FPRD, 5 FPWR, 7 BRD,
// 8 BWR, 10 LRD, 11 LWR, 12 LRW ...), Adp/Ado the address (Addr for logical ones).
struct EniEscInitCmd {
  std::vector<std::string> transitions{};
  std::string comment{};
  std::uint8_t cmd = 0;
  std::uint16_t adp = 0;
  std::uint16_t ado = 0;
  std::optional<std::uint32_t> addr{};
  std::vector<std::uint8_t> data{};
  std::uint32_t data_length = 0;  // <DataLength> (zero-filled data) or the size of <Data>
  int line = 0;
};

// Slave/DC. Times in nanoseconds.
struct EniDc {
  bool potential_reference_clock = false;
  bool reference_clock = false;
  std::int64_t cycle_time0 = 0;
  std::optional<std::int64_t> cycle_time1{};
  std::int64_t shift_time = 0;
  int line = 0;
};

struct EniSlaveInfo {
  std::string name{};
  std::optional<std::uint16_t> phys_addr{};      // configured station address
  std::optional<std::uint16_t> auto_inc_addr{};  // 0, 0xFFFF, 0xFFFE ... (position -n)
  // Info/Identification: a register (Ado) whose value (Value) identifies the slave; Ado 0x0012
  // is the configured station alias.
  std::optional<std::uint16_t> identification_ado{};
  std::optional<std::uint16_t> identification_value{};
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::optional<std::uint32_t> revision_no{};
  std::optional<std::uint32_t> serial_no{};
};

// Slave/HotConnect/IdentifyCmd: a command that reads what tells a hot-connect group apart, and
// the value expected (Validate/Data, under Validate/DataMask): Ado 0x0012 is the configured
// station alias, 0x0134 an explicit device ID (AL status code after an ID request).
struct EniIdentifyCmd {
  std::uint8_t cmd = 0;
  std::uint16_t adp = 0;
  std::uint16_t ado = 0;
  std::uint32_t data_length = 0;
  std::vector<std::uint8_t> expected{};  // Validate/Data; empty when there is no <Validate>
  std::vector<std::uint8_t> mask{};      // Validate/DataMask; empty: every bit counts
  int line = 0;
};

// Slave/HotConnect: this slave heads a hot-connect group, GroupMemberCnt slaves (itself and the
// ones after it in the file, in ring order) that may be absent at start and come and go (ETG.2100;
// the same structure as the HotConnect type of public ENI readers: GroupName, GroupMemberCnt,
// IdentifyCmd*).
struct EniHotConnect {
  std::string group_name{};
  std::optional<std::uint32_t> member_count{};  // absent: the file did not say
  std::vector<EniIdentifyCmd> identify{};
  int line = 0;
};

struct EniSlave {
  EniSlaveInfo info{};
  std::optional<EniProcessData> process_data{};
  std::optional<EniMailbox> mailbox{};
  std::vector<EniEscInitCmd> init_cmds{};
  std::optional<EniDc> dc{};
  std::optional<EniHotConnect> hot_connect{};
  // Child elements of <Slave> this reader does not know (PreviousPort, Boot ... are known and
  // skipped): "Name (line N)".
  std::vector<std::string> unrecognised{};
  int line = 0;
};

// Config/Cyclic/Frame/Cmd: one datagram of the master's precomputed cyclic frames.
struct EniCyclicCmd {
  std::uint8_t cmd = 0;
  std::optional<std::uint32_t> addr{};  // logical address (LRD/LWR/LRW)
  std::uint16_t adp = 0;
  std::uint16_t ado = 0;
  std::uint32_t data_length = 0;
  std::optional<std::uint16_t> cnt{};  // expected working counter
  std::string comment{};
  int line = 0;
};

struct EniCyclic {
  std::uint32_t cycle_time_us = 0;  // Cyclic/CycleTime: microseconds
  std::vector<std::vector<EniCyclicCmd>> frames{};
  int line = 0;
};

struct EniMaster {
  std::string name{};
  std::vector<EniEscInitCmd> init_cmds{};
  bool has_mailbox_states = false;
  bool has_eoe = false;
};

struct EniFile {
  std::string version{};  // the root's Version attribute
  EniMaster master{};
  std::vector<EniSlave> slaves{};  // ring order
  std::vector<EniCyclic> cyclic{};
  bool has_process_image = false;
  // Child elements of <Config> / <EtherCATConfig> this reader does not know: "Name (line N)".
  std::vector<std::string> unrecognised{};
};

// Whether `text` is an XML document whose root element is <EtherCATConfig> (looks past a BOM,
// the XML declaration, comments and processing instructions; does not parse the rest).
bool looks_like_eni(std::string_view text) noexcept;

// Parses an ENI. `source` names it in errors ("source:line: <Element>: ...").
Result<EniFile> parse_eni(std::string_view xml, std::string_view source = "ENI");
// Reads (at most the ring-file size cap, core/read_file.hpp) and parses the file at `path`.
Result<EniFile> load_eni(const std::string& path);

}  // namespace ecat::config
