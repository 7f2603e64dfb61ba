// ecat sii FILE [--json]: decodes an SII EEPROM image file and prints it.
// Exit codes: 0 decoded (possibly partially, see the warnings), 1 not decodable, 2 unreadable.
#include <cstdio>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <nlohmann/json.hpp>

#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "command.hpp"
#include "core/read_file.hpp"
#include "session_view.hpp"

namespace {

using ecat::wire::SiiDecoded;
using ecat::wire::SiiImage;
using ecat::wire::SiiPdo;
using nlohmann::json;

struct Options {
  std::string file;
  bool json = false;
};

std::string text(std::string_view latin1) {
  return ecat::wire::sii_string_to_utf8(latin1);
}

std::string_view data_type_name(std::uint8_t type) {
  switch (type) {
    case 0x00:
      return "padding";
    case 0x01:
      return "BOOLEAN";
    case 0x02:
      return "INTEGER8";
    case 0x03:
      return "INTEGER16";
    case 0x04:
      return "INTEGER32";
    case 0x05:
      return "UNSIGNED8";
    case 0x06:
      return "UNSIGNED16";
    case 0x07:
      return "UNSIGNED32";
    case 0x08:
      return "REAL32";
    case 0x09:
      return "VISIBLE_STRING";
    case 0x0A:
      return "OCTET_STRING";
    case 0x0B:
      return "UNICODE_STRING";
    case 0x0C:
      return "TIME_OF_DAY";
    case 0x0D:
      return "TIME_DIFFERENCE";
    case 0x0F:
      return "DOMAIN";
    case 0x10:
      return "INTEGER24";
    case 0x11:
      return "REAL64";
    case 0x12:
      return "INTEGER40";
    case 0x13:
      return "INTEGER48";
    case 0x14:
      return "INTEGER56";
    case 0x15:
      return "INTEGER64";
    case 0x16:
      return "UNSIGNED24";
    case 0x18:
      return "UNSIGNED40";
    case 0x19:
      return "UNSIGNED48";
    case 0x1A:
      return "UNSIGNED56";
    case 0x1B:
      return "UNSIGNED64";
    case 0x30:
      return "BIT1";
    case 0x31:
      return "BIT2";
    case 0x32:
      return "BIT3";
    case 0x33:
      return "BIT4";
    case 0x34:
      return "BIT5";
    case 0x35:
      return "BIT6";
    case 0x36:
      return "BIT7";
    case 0x37:
      return "BIT8";
    default:
      return "unknown";
  }
}

std::vector<std::string> coe_detail_names(std::uint8_t coe) {
  namespace d = ecat::wire::sii_coe_detail;
  std::vector<std::string> names;
  const std::pair<std::uint8_t, const char*> bits[] = {
      {d::kSdo, "SDO"},
      {d::kSdoInfo, "SDO info"},
      {d::kPdoAssign, "PDO assign"},
      {d::kPdoConfiguration, "PDO configuration"},
      {d::kPdoUploadAtStartup, "PDO upload at startup"},
      {d::kSdoCompleteAccess, "SDO complete access"}};
  for (const auto& [bit, name] : bits) {
    if ((coe & bit) != 0) names.emplace_back(name);
  }
  return names;
}

std::vector<std::string> general_flag_names(std::uint8_t flags) {
  namespace f = ecat::wire::sii_general_flag;
  std::vector<std::string> names;
  const std::pair<std::uint8_t, const char*> bits[] = {
      {f::kEnableSafeOp, "enable SafeOp"},
      {f::kEnableNotLrw, "enable not LRW"},
      {f::kMailboxDataLinkLayer, "mailbox data link layer"},
      {f::kIdentAlStatus, "identification via AL status"},
      {f::kIdentPhysicalMemory, "identification via physical memory"}};
  for (const auto& [bit, name] : bits) {
    if ((flags & bit) != 0) names.emplace_back(name);
  }
  return names;
}

std::string control_description(std::uint8_t control) {
  auto decoded = ecat::wire::SmControl::decode(control);
  if (!decoded) return "reserved mode or direction";
  std::string s = decoded->mode == ecat::wire::SmMode::mailbox ? "mailbox" : "buffered";
  s += decoded->direction == ecat::wire::SmDirection::write ? ", ECAT writes" : ", ECAT reads";
  if (decoded->ecat_event) s += ", ECAT event";
  if (decoded->pdi_event) s += ", PDI event";
  if (decoded->watchdog) s += ", watchdog";
  return s;
}

// ---------------------------------------------------------------------------------------------
// JSON

json mailbox_json(const ecat::wire::SiiMailbox& m) {
  return {{"recv_offset", m.recv_offset},
          {"recv_size", m.recv_size},
          {"send_offset", m.send_offset},
          {"send_size", m.send_size}};
}

json pdos_json(const SiiImage& img, const std::vector<SiiPdo>& pdos) {
  json list = json::array();
  for (const auto& pdo : pdos) {
    json entries = json::array();
    for (const auto& e : pdo.entries) {
      entries.push_back({{"index", e.index},
                         {"subindex", e.subindex},
                         {"bit_length", e.bit_length},
                         {"name", text(img.string(e.name_index))},
                         {"name_index", e.name_index},
                         {"data_type", e.data_type},
                         {"data_type_name", data_type_name(e.data_type)},
                         {"flags", e.flags}});
    }
    list.push_back({{"index", pdo.index},
                    {"sm", pdo.sync_manager},
                    {"dc_sync", pdo.dc_sync},
                    {"name", text(img.string(pdo.name_index))},
                    {"name_index", pdo.name_index},
                    {"flags", pdo.flags},
                    {"bit_length", pdo.bit_length()},
                    {"entries", std::move(entries)}});
  }
  return list;
}

json to_json(const Options& options, std::size_t file_size, const SiiDecoded& decoded) {
  const SiiImage& img = decoded.image;
  json j;
  j["file"] = options.file;
  j["size_bytes"] = file_size;
  j["device_name"] = text(img.device_name());
  j["identity"] = {{"vendor_id", img.identity.vendor_id},
                   {"product_code", img.identity.product_code},
                   {"revision", img.identity.revision},
                   {"serial", img.identity.serial}};
  j["header"] = {{"pdi_control", img.pdi_control},
                 {"pdi_configuration", img.pdi_configuration},
                 {"sync_impulse_length", img.sync_impulse_length},
                 {"pdi_configuration2", img.pdi_configuration2},
                 {"station_alias", img.station_alias},
                 {"execution_delay", img.execution_delay},
                 {"port0_delay", img.port0_delay},
                 {"port1_delay", img.port1_delay}};
  j["checksum_ok"] = decoded.checksum_ok;
  j["checksum_word"] = decoded.checksum_word;
  j["checksum_computed"] = decoded.checksum_computed;
  j["eeprom_size_word"] = img.eeprom_size;
  j["eeprom_size_bytes"] = img.eeprom_size_bytes();
  j["version"] = img.version;
  j["standard_mailbox"] = mailbox_json(img.standard_mailbox);
  j["bootstrap_mailbox"] = mailbox_json(img.bootstrap_mailbox);
  j["mailbox_protocols"] = json::array();
  for (auto name : ecat::wire::mailbox_protocol_names(img.mailbox_protocols)) {
    j["mailbox_protocols"].push_back(name);
  }
  j["mailbox_protocols_raw"] = img.mailbox_protocols;

  j["categories"] = json::array();
  for (const auto& c : decoded.categories) {
    j["categories"].push_back({{"type", c.type},
                               {"name", ecat::wire::sii_category_name(c.type)},
                               {"word_address", c.word_address},
                               {"size_words", c.size_words},
                               {"truncated", c.truncated}});
  }

  j["strings"] = json::array();
  for (const auto& s : img.strings)
    j["strings"].push_back(text(s));

  if (img.general) {
    const auto& g = *img.general;
    json ports = json::array();
    for (std::size_t p = 0; p < 4; ++p)
      ports.push_back(ecat::wire::sii_port_name(g.port(p)));
    j["general"] = {{"group", text(img.string(g.group_index))},
                    {"image", text(img.string(g.image_index))},
                    {"order", text(img.string(g.order_index))},
                    {"name", text(img.string(g.name_index))},
                    {"group_index", g.group_index},
                    {"image_index", g.image_index},
                    {"order_index", g.order_index},
                    {"name_index", g.name_index},
                    {"coe_details", g.coe_details},
                    {"coe_details_names", coe_detail_names(g.coe_details)},
                    {"foe_details", g.foe_details},
                    {"eoe_details", g.eoe_details},
                    {"soe_channels", g.soe_channels},
                    {"ds402_channels", g.ds402_channels},
                    {"sysman_class", g.sysman_class},
                    {"flags", g.flags},
                    {"flags_names", general_flag_names(g.flags)},
                    {"current_on_ebus_ma", g.current_on_ebus_ma},
                    {"physical_port", g.physical_port},
                    {"ports", std::move(ports)},
                    {"physical_memory_address", g.physical_memory_address}};
  } else {
    j["general"] = nullptr;
  }

  j["fmmus"] = json::array();
  j["fmmus_raw"] = json::array();
  for (auto usage : img.fmmus) {
    j["fmmus"].push_back(ecat::wire::sii_fmmu_usage_name(usage));
    j["fmmus_raw"].push_back(usage);
  }

  j["sync_managers"] = json::array();
  for (std::size_t i = 0; i < img.sync_managers.size(); ++i) {
    const auto& sm = img.sync_managers[i];
    j["sync_managers"].push_back({{"index", i},
                                  {"start", sm.start},
                                  {"length", sm.length},
                                  {"control", sm.control},
                                  {"control_description", control_description(sm.control)},
                                  {"status", sm.status},
                                  {"enable", sm.enable},
                                  {"enabled", sm.enabled()},
                                  {"fixed_content", sm.fixed_content()},
                                  {"virtual", sm.virtual_sm()},
                                  {"op_only", sm.op_only()},
                                  {"type", sm.type},
                                  {"type_name", ecat::wire::sii_sync_manager_type_name(sm.type)}});
  }

  j["txpdos"] = pdos_json(img, img.txpdos);
  j["rxpdos"] = pdos_json(img, img.rxpdos);

  j["dc"] = json::array();
  for (const auto& d : img.dc) {
    j["dc"].push_back({{"name", text(img.string(d.name_index))},
                       {"description", text(img.string(d.description_index))},
                       {"assign_activate", d.assign_activate},
                       {"cycle_time_0", d.cycle_time_0},
                       {"shift_time_0", d.shift_time_0},
                       {"shift_time_1", d.shift_time_1},
                       {"sync0_cycle_factor", d.sync0_cycle_factor},
                       {"sync1_cycle_factor", d.sync1_cycle_factor}});
  }

  const auto raw = [](const std::optional<std::vector<std::uint8_t>>& data) -> json {
    if (!data) return nullptr;
    return json(*data);
  };
  j["data_types"] = raw(img.data_types);
  j["fmmu_ex"] = raw(img.fmmu_ex);
  j["sync_unit"] = raw(img.sync_unit);
  j["other_categories"] = json::array();
  for (const auto& c : img.other_categories) {
    j["other_categories"].push_back({{"type", c.type}, {"data", c.data}});
  }
  j["warnings"] = decoded.warnings;
  return j;
}

// ---------------------------------------------------------------------------------------------
// Text

void print_mailbox(const char* label, const ecat::wire::SiiMailbox& m) {
  if (m.recv_size == 0 && m.send_size == 0 && m.recv_offset == 0 && m.send_offset == 0) {
    fmt::print("{}: none\n", label);
    return;
  }
  fmt::print("{}: receive 0x{:04x} ({} bytes), send 0x{:04x} ({} bytes)\n", label, m.recv_offset,
             m.recv_size, m.send_offset, m.send_size);
}

void print_pdos(const SiiImage& img, const char* label, const std::vector<SiiPdo>& pdos) {
  if (pdos.empty()) return;
  fmt::print("{}:\n", label);
  for (const auto& pdo : pdos) {
    fmt::print("  0x{:04x} \"{}\" SM{} {} bits, flags 0x{:04x}{}\n", pdo.index,
               text(img.string(pdo.name_index)), pdo.sync_manager, pdo.bit_length(), pdo.flags,
               pdo.dc_sync != 0 ? fmt::format(", DC sync {}", pdo.dc_sync) : std::string());
    for (const auto& e : pdo.entries) {
      if (e.padding()) {
        fmt::print("    (padding) {} bits\n", e.bit_length);
        continue;
      }
      fmt::print("    0x{:04x}:{:02x} {:>2} bits {:<14} \"{}\"\n", e.index, e.subindex,
                 e.bit_length, data_type_name(e.data_type), text(img.string(e.name_index)));
    }
  }
}

void print_text(const Options& options, std::size_t file_size, const SiiDecoded& decoded) {
  const SiiImage& img = decoded.image;
  fmt::print("file: {} ({} bytes)\n", options.file, file_size);
  fmt::print("device: {}\n", text(img.device_name()));
  fmt::print("identity: vendor 0x{:08x}, product 0x{:08x}, revision 0x{:08x}, serial 0x{:08x}\n",
             img.identity.vendor_id, img.identity.product_code, img.identity.revision,
             img.identity.serial);
  fmt::print(
      "header: PDI control 0x{:04x}, PDI configuration 0x{:04x}/0x{:04x}, sync impulse {} x 10 "
      "ns, station alias {}, checksum 0x{:02x} ({})\n",
      img.pdi_control, img.pdi_configuration, img.pdi_configuration2, img.sync_impulse_length,
      img.station_alias, decoded.checksum_word & 0xFF,
      decoded.checksum_ok ? "ok"
                          : fmt::format("BAD, computed 0x{:02x}", decoded.checksum_computed));
  fmt::print("EEPROM: {} bytes declared, SII version {}\n", img.eeprom_size_bytes(), img.version);
  print_mailbox("standard mailbox", img.standard_mailbox);
  print_mailbox("bootstrap mailbox", img.bootstrap_mailbox);
  const auto protocols = ecat::wire::mailbox_protocol_names(img.mailbox_protocols);
  fmt::print("mailbox protocols: {}\n",
             protocols.empty() ? "none" : fmt::format("{}", fmt::join(protocols, " ")));

  fmt::print("categories:\n");
  for (const auto& c : decoded.categories) {
    if (c.type == ecat::wire::sii_category::kEnd) {
      fmt::print("  word 0x{:04x}  END\n", c.word_address);
      continue;
    }
    fmt::print("  word 0x{:04x}  {:<14} type {:>5}  {} words{}\n", c.word_address,
               ecat::wire::sii_category_name(c.type), c.type, c.size_words,
               c.truncated ? " (truncated)" : "");
  }

  if (!img.strings.empty()) {
    fmt::print("strings:\n");
    for (std::size_t i = 0; i < img.strings.size(); ++i) {
      fmt::print("  {:>3} \"{}\"\n", i + 1, text(img.strings[i]));
    }
  }

  if (img.general) {
    const auto& g = *img.general;
    fmt::print("general:\n");
    fmt::print("  group \"{}\", order \"{}\", name \"{}\"\n", text(img.string(g.group_index)),
               text(img.string(g.order_index)), text(img.string(g.name_index)));
    const auto coe = coe_detail_names(g.coe_details);
    fmt::print("  CoE 0x{:02x}{}, FoE 0x{:02x}, EoE 0x{:02x}, SoE channels {}, DS402 channels {}\n",
               g.coe_details, coe.empty() ? "" : fmt::format(" ({})", fmt::join(coe, ", ")),
               g.foe_details, g.eoe_details, g.soe_channels, g.ds402_channels);
    const auto flags = general_flag_names(g.flags);
    fmt::print("  flags 0x{:02x}{}, SysmanClass {}, E-bus current {} mA\n", g.flags,
               flags.empty() ? "" : fmt::format(" ({})", fmt::join(flags, ", ")), g.sysman_class,
               g.current_on_ebus_ma);
    fmt::print("  ports {} {} {} {}, physical memory address 0x{:04x}\n",
               ecat::wire::sii_port_name(g.port(0)), ecat::wire::sii_port_name(g.port(1)),
               ecat::wire::sii_port_name(g.port(2)), ecat::wire::sii_port_name(g.port(3)),
               g.physical_memory_address);
  }

  if (!img.fmmus.empty()) {
    fmt::print("FMMUs:");
    for (std::size_t i = 0; i < img.fmmus.size(); ++i) {
      fmt::print(" {}={}", i, ecat::wire::sii_fmmu_usage_name(img.fmmus[i]));
    }
    fmt::print("\n");
  }

  if (!img.sync_managers.empty()) {
    fmt::print("sync managers:\n");
    for (std::size_t i = 0; i < img.sync_managers.size(); ++i) {
      const auto& sm = img.sync_managers[i];
      std::string enable = sm.enabled() ? "enabled" : "disabled";
      if (sm.fixed_content()) enable += ", fixed content";
      if (sm.virtual_sm()) enable += ", virtual";
      if (sm.op_only()) enable += ", OP only";
      fmt::print(
          "  SM{} start 0x{:04x} length {} control 0x{:02x} ({}) enable 0x{:02x} ({}) type {}\n", i,
          sm.start, sm.length, sm.control, control_description(sm.control), sm.enable, enable,
          ecat::wire::sii_sync_manager_type_name(sm.type));
    }
  }

  print_pdos(img, "TxPDOs (inputs)", img.txpdos);
  print_pdos(img, "RxPDOs (outputs)", img.rxpdos);

  if (!img.dc.empty()) {
    fmt::print("DC:\n");
    for (const auto& d : img.dc) {
      fmt::print(
          "  \"{}\" AssignActivate 0x{:04x}, cycle time 0 {}, shift 0 {}, shift 1 {}, sync0 "
          "factor {}, sync1 factor {}\n",
          text(img.string(d.name_index)), d.assign_activate, d.cycle_time_0, d.shift_time_0,
          d.shift_time_1, d.sync0_cycle_factor, d.sync1_cycle_factor);
    }
  }
  const std::pair<const char*, const std::optional<std::vector<std::uint8_t>>*> raws[] = {
      {"DATATYPES", &img.data_types}, {"FMMU_EX", &img.fmmu_ex}, {"SYNCUNIT", &img.sync_unit}};
  for (const auto& [name, data] : raws) {
    if (*data) fmt::print("{}: {} bytes kept raw\n", name, (*data)->size());
  }
  for (const auto& c : img.other_categories) {
    fmt::print("category type {} ({}): {} bytes kept raw\n", c.type,
               ecat::wire::sii_category_name(c.type), c.data.size());
  }

  if (!decoded.warnings.empty()) {
    fmt::print("warnings:\n");
    for (const auto& w : decoded.warnings)
      fmt::print("  {}\n", w);
  }
}

// ---------------------------------------------------------------------------------------------

int print_image(const Options& options, const std::vector<std::uint8_t>& bytes) {
  auto decoded = ecat::wire::decode_sii(bytes);
  if (!decoded) {
    fmt::print(stderr, "ecat sii: {}: {}\n", options.file, decoded.error().describe());
    return 1;
  }
  if (options.json) {
    // The file name is the user's bytes: one that is not UTF-8 prints with U+FFFD rather than
    // making dump() throw.
    fmt::print("{}\n", to_json(options, bytes.size(), *decoded)
                           .dump(2, ' ', false, json::error_handler_t::replace));
  } else {
    print_text(options, bytes.size(), *decoded);
  }
  return 0;
}

int run(const Options& options) {
  auto read = ecat::read_binary_file(options.file, ecat::FileKind::eeprom);
  if (!read) {
    fmt::print(stderr, "ecat sii: {}\n", read.error().describe());
    return 2;
  }
  return print_image(options, *read);
}

ecat::tool::Command setup(CLI::App& parent) {
  auto* app = parent.add_subcommand("sii", "Decode an SII EEPROM image file");
  auto options = std::make_shared<Options>();
  app->add_option("FILE", options->file, "EEPROM image (raw little-endian words)")->required();
  app->add_flag("--json", options->json, "Print JSON instead of text");
  return {app, [options] { return run(*options); }};
}

const bool registered = ecat::tool::register_command(&setup);

}  // namespace

namespace ecat::tool {

int print_sii(const std::vector<std::uint8_t>& image, const std::string& label, bool json) {
  return print_image(Options{label, json}, image);
}

}  // namespace ecat::tool
