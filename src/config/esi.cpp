#include <algorithm>
#include <cctype>
#include <charconv>
#include <iterator>
#include <map>

#include <fmt/format.h>
#include <pugixml.hpp>

#include <ecat/config/esi.hpp>

#include "core/read_file.hpp"

namespace ecat::config {

namespace {

std::string trim(std::string_view text) {
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(" \t\r\n");
  return std::string(text.substr(first, last - first + 1));
}

// "#x1A00" (hexadecimal), "0x1A00", "-3" or "6400" (decimal).
std::optional<std::int64_t> parse_number(std::string_view raw) {
  const std::string text = trim(raw);
  std::string_view t = text;
  bool negative = false;
  int base = 10;
  if (!t.empty() && t[0] == '-') {
    negative = true;
    t.remove_prefix(1);
  }
  if (t.size() > 2 && t[0] == '#' && (t[1] == 'x' || t[1] == 'X')) {
    t.remove_prefix(2);
    base = 16;
  } else if (t.size() > 2 && t[0] == '0' && (t[1] == 'x' || t[1] == 'X')) {
    t.remove_prefix(2);
    base = 16;
  }
  if (t.empty()) return std::nullopt;
  std::uint64_t value = 0;
  auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), value, base);
  if (ec != std::errc{} || end != t.data() + t.size()) return std::nullopt;
  const auto v = static_cast<std::int64_t>(value);
  return negative ? -v : v;
}

std::vector<std::uint8_t> parse_hex(std::string_view raw) {
  const std::string text = trim(raw);
  std::vector<std::uint8_t> out;
  for (std::size_t i = 0; i + 1 < text.size(); i += 2) {
    std::uint8_t byte = 0;
    auto [end, ec] = std::from_chars(text.data() + i, text.data() + i + 2, byte, 16);
    if (ec != std::errc{} || end != text.data() + i + 2) return {};
    out.push_back(byte);
  }
  return out;
}

bool truthy(const pugi::xml_attribute& a) {
  const std::string v = a.value();
  return v == "1" || v == "true";
}

struct Context {
  std::string where;  // for error messages: "device 'EVS-NET-01'"
};

Error malformed(const Context& ctx, std::string_view what) {
  return Error(Errc::malformed, fmt::format("ESI {}: {}", ctx.where, what));
}

template <class T>
Result<T> number(const Context& ctx, const pugi::xml_node& node, std::string_view what,
                 std::optional<T> fallback = std::nullopt) {
  const std::string text = node.text().as_string();
  if (trim(text).empty()) {
    if (fallback) return *fallback;
    return malformed(ctx, fmt::format("{} is missing", what));
  }
  auto v = parse_number(text);
  if (!v) return malformed(ctx, fmt::format("{} '{}' is not a number", what, text));
  return static_cast<T>(*v);
}

template <class T>
Result<T> attr_number(const Context& ctx, const pugi::xml_node& node, const char* name,
                      std::optional<T> fallback = std::nullopt) {
  const pugi::xml_attribute a = node.attribute(name);
  if (!a) {
    if (fallback) return *fallback;
    return malformed(ctx, fmt::format("attribute {} of <{}> is missing", name, node.name()));
  }
  auto v = parse_number(a.value());
  if (!v) {
    return malformed(ctx, fmt::format("attribute {}=\"{}\" of <{}> is not a number", name,
                                      a.value(), node.name()));
  }
  return static_cast<T>(*v);
}

// ---- data types ------------------------------------------------------------------------------

struct TypeFlags {
  bool present = false;
  std::string access;
  std::string write_restrictions;
  std::string read_restrictions;
  std::string pdo_mapping;
  bool backup = false;
  bool setting = false;
};

TypeFlags read_flags(const pugi::xml_node& flags) {
  TypeFlags f;
  if (!flags) return f;
  f.present = true;
  const pugi::xml_node access = flags.child("Access");
  f.access = trim(access.text().as_string());
  f.write_restrictions = access.attribute("WriteRestrictions").value();
  f.read_restrictions = access.attribute("ReadRestrictions").value();
  f.pdo_mapping = trim(flags.child("PdoMapping").text().as_string());
  std::transform(f.pdo_mapping.begin(), f.pdo_mapping.end(), f.pdo_mapping.begin(),
                 [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
  f.backup = trim(flags.child("Backup").text().as_string()) == "1";
  f.setting = trim(flags.child("Setting").text().as_string()) == "1";
  return f;
}

void apply_flags(EsiEntry& entry, const TypeFlags& f) {
  if (!f.present) return;
  if (!f.access.empty()) entry.access = f.access;
  entry.write_restrictions = f.write_restrictions;
  entry.read_restrictions = f.read_restrictions;
  entry.pdo_mapping = f.pdo_mapping;
  entry.backup = f.backup;
  entry.setting = f.setting;
}

struct SubItemDef {
  std::optional<std::uint8_t> subindex;
  std::string name;
  std::string type;
  std::uint32_t bit_size = 0;
  std::uint32_t bit_offset = 0;
  TypeFlags flags;
};

struct DataTypeDef {
  std::string name;
  std::string base_type;
  std::uint32_t bit_size = 0;
  std::optional<std::int64_t> lbound;
  std::uint32_t elements = 0;
  std::vector<SubItemDef> subitems;
};

using TypeMap = std::map<std::string, DataTypeDef, std::less<>>;

Result<TypeMap> read_data_types(const Context& ctx, const pugi::xml_node& types) {
  TypeMap map;
  for (const auto& t : types.children("DataType")) {
    DataTypeDef def;
    def.name = trim(t.child_value("Name"));
    def.base_type = trim(t.child_value("BaseType"));
    auto bits = number<std::uint32_t>(ctx, t.child("BitSize"),
                                      fmt::format("BitSize of data type {}", def.name), 0u);
    if (!bits) return bits.error();
    def.bit_size = *bits;
    if (const auto array = t.child("ArrayInfo")) {
      auto lb = number<std::int64_t>(ctx, array.child("LBound"),
                                     fmt::format("LBound of data type {}", def.name), 0);
      auto n = number<std::uint32_t>(ctx, array.child("Elements"),
                                     fmt::format("Elements of data type {}", def.name), 0u);
      if (!lb) return lb.error();
      if (!n) return n.error();
      def.lbound = *lb;
      def.elements = *n;
    }
    for (const auto& s : t.children("SubItem")) {
      SubItemDef sub;
      if (s.child("SubIdx")) {
        auto idx = number<std::uint32_t>(ctx, s.child("SubIdx"),
                                         fmt::format("SubIdx in data type {}", def.name));
        if (!idx) return idx.error();
        sub.subindex = static_cast<std::uint8_t>(*idx);
      }
      sub.name = trim(s.child_value("Name"));
      sub.type = trim(s.child_value("Type"));
      auto sb = number<std::uint32_t>(ctx, s.child("BitSize"),
                                      fmt::format("BitSize of {}.{}", def.name, sub.name), 0u);
      auto so = number<std::uint32_t>(ctx, s.child("BitOffs"),
                                      fmt::format("BitOffs of {}.{}", def.name, sub.name), 0u);
      if (!sb) return sb.error();
      if (!so) return so.error();
      sub.bit_size = *sb;
      sub.bit_offset = *so;
      sub.flags = read_flags(s.child("Flags"));
      def.subitems.push_back(std::move(sub));
    }
    map[def.name] = std::move(def);
  }
  return map;
}

// Flattens an object's type into entries; `flags` are the object's own Flags.
std::vector<EsiEntry> flatten(const TypeMap& types, const EsiObject& object, const TypeFlags& flags,
                              EsiObjectCode& code) {
  std::vector<EsiEntry> out;
  auto it = types.find(object.type);
  if (it == types.end() || (it->second.subitems.empty() && !it->second.lbound)) {
    EsiEntry e;
    e.subindex = 0;
    e.name = object.name;
    e.type = object.type;
    e.bit_size = object.bit_size;
    apply_flags(e, flags);
    out.push_back(std::move(e));
    code = EsiObjectCode::var;
    return out;
  }
  const DataTypeDef& def = it->second;
  code = EsiObjectCode::record;
  if (def.subitems.empty()) {
    // The object's type is an array type itself: subindex 0 holds the element count.
    EsiEntry count;
    count.name = "SubIndex 000";
    count.type = "USINT";
    count.bit_size = 8;
    count.default_data = {static_cast<std::uint8_t>(def.elements)};
    apply_flags(count, flags);
    count.access = "ro";
    out.push_back(std::move(count));
    const std::uint32_t element_bits = def.elements ? def.bit_size / def.elements : 0;
    for (std::uint32_t k = 0; k < def.elements && k < 255; ++k) {
      EsiEntry e;
      e.subindex = static_cast<std::uint8_t>(k + 1);
      e.name = fmt::format("SubIndex {:03}", k + 1);
      e.type = def.base_type;
      e.bit_size = element_bits;
      e.bit_offset = 16 + k * element_bits;
      apply_flags(e, flags);
      out.push_back(std::move(e));
    }
    code = EsiObjectCode::array;
    return out;
  }
  bool expanded_array = false;
  for (const auto& sub : def.subitems) {
    auto st = types.find(sub.type);
    const bool array_type =
        !sub.subindex && st != types.end() && st->second.lbound && st->second.subitems.empty();
    if (array_type) {
      const DataTypeDef& at = st->second;
      const std::uint32_t element_bits = at.elements ? at.bit_size / at.elements : 0;
      for (std::uint32_t k = 0; k < at.elements; ++k) {
        const std::int64_t subindex = *at.lbound + k;
        if (subindex < 0 || subindex > 255) continue;
        EsiEntry e;
        e.subindex = static_cast<std::uint8_t>(subindex);
        e.name = fmt::format("{} {}", sub.name, k + 1);
        e.type = at.base_type;
        e.bit_size = element_bits;
        e.bit_offset = sub.bit_offset + k * element_bits;
        apply_flags(e, flags);
        apply_flags(e, sub.flags);
        out.push_back(std::move(e));
      }
      expanded_array = true;
      continue;
    }
    EsiEntry e;
    e.subindex = sub.subindex.value_or(static_cast<std::uint8_t>(out.size()));
    e.name = sub.name;
    e.type = sub.type;
    e.bit_size = sub.bit_size;
    e.bit_offset = sub.bit_offset;
    apply_flags(e, flags);
    apply_flags(e, sub.flags);
    out.push_back(std::move(e));
  }
  if (expanded_array && def.subitems.size() == 2) code = EsiObjectCode::array;
  std::stable_sort(out.begin(), out.end(),
                   [](const EsiEntry& a, const EsiEntry& b) { return a.subindex < b.subindex; });
  return out;
}

void read_info(const pugi::xml_node& info, EsiEntry& e) {
  if (!info) return;
  if (const auto d = info.child("DefaultData")) {
    e.default_data = parse_hex(d.text().as_string());
  } else if (const auto s = info.child("DefaultString")) {
    const std::string text = s.text().as_string();
    e.default_data.assign(text.begin(), text.end());
  } else if (const auto v = info.child("DefaultValue")) {
    if (auto n = parse_number(v.text().as_string())) {
      const std::size_t bytes = std::max<std::size_t>(1, (e.bit_size + 7) / 8);
      for (std::size_t i = 0; i < bytes && i < 8; ++i) {
        e.default_data.push_back(
            static_cast<std::uint8_t>(static_cast<std::uint64_t>(*n) >> (8 * i)));
      }
    }
  }
  if (auto n = parse_number(info.child_value("MinValue")); n) e.minimum = *n;
  if (auto n = parse_number(info.child_value("MaxValue")); n) e.maximum = *n;
}

Result<std::vector<EsiObject>> read_objects(const Context& ctx, const pugi::xml_node& dictionary) {
  auto types = read_data_types(ctx, dictionary.child("DataTypes"));
  if (!types) return types.error();
  std::vector<EsiObject> out;
  for (const auto& o : dictionary.child("Objects").children("Object")) {
    EsiObject object;
    auto index = number<std::uint32_t>(ctx, o.child("Index"), "Index of an Object");
    if (!index) return index.error();
    if (*index > 0xFFFF)
      return malformed(ctx, fmt::format("object index {} is beyond 0xFFFF", *index));
    object.index = static_cast<std::uint16_t>(*index);
    object.name = trim(o.child_value("Name"));
    object.type = trim(o.child_value("Type"));
    auto bits = number<std::uint32_t>(ctx, o.child("BitSize"),
                                      fmt::format("BitSize of object 0x{:04X}", object.index), 0u);
    if (!bits) return bits.error();
    object.bit_size = *bits;
    object.entries = flatten(*types, object, read_flags(o.child("Flags")), object.code);
    const pugi::xml_node info = o.child("Info");
    if (object.code == EsiObjectCode::var) {
      read_info(info, object.entries.front());
    } else {
      // Info/SubItem lists the entries in order, each with its name and default.
      std::size_t k = 0;
      for (const auto& s : info.children("SubItem")) {
        if (k >= object.entries.size()) break;
        EsiEntry& e = object.entries[k++];
        const std::string name = trim(s.child_value("Name"));
        if (!name.empty()) e.name = name;
        read_info(s.child("Info"), e);
      }
    }
    out.push_back(std::move(object));
  }
  return out;
}

// ---- PDOs, SyncManagers, device ------------------------------------------------------------

Result<EsiPdo> read_pdo(const Context& ctx, const pugi::xml_node& p) {
  EsiPdo pdo;
  auto index = number<std::uint32_t>(ctx, p.child("Index"), "Index of a PDO");
  if (!index) return index.error();
  pdo.index = static_cast<std::uint16_t>(*index);
  pdo.name = trim(p.child_value("Name"));
  if (p.attribute("Sm")) {
    auto sm = attr_number<std::uint32_t>(ctx, p, "Sm");
    if (!sm) return sm.error();
    pdo.sync_manager = static_cast<std::uint8_t>(*sm);
  }
  pdo.fixed = truthy(p.attribute("Fixed"));
  pdo.mandatory = truthy(p.attribute("Mandatory"));
  for (const auto& x : p.children("Exclude")) {
    if (auto v = parse_number(x.text().as_string()))
      pdo.excludes.push_back(static_cast<std::uint16_t>(*v));
  }
  for (const auto& e : p.children("Entry")) {
    EsiPdoEntry entry;
    auto ei = number<std::uint32_t>(ctx, e.child("Index"),
                                    fmt::format("Index of an entry of PDO 0x{:04X}", pdo.index));
    auto es =
        number<std::uint32_t>(ctx, e.child("SubIndex"),
                              fmt::format("SubIndex of an entry of PDO 0x{:04X}", pdo.index), 0u);
    auto eb = number<std::uint32_t>(ctx, e.child("BitLen"),
                                    fmt::format("BitLen of an entry of PDO 0x{:04X}", pdo.index));
    if (!ei) return ei.error();
    if (!es) return es.error();
    if (!eb) return eb.error();
    if (*eb > 255) {
      return malformed(
          ctx, fmt::format("PDO 0x{:04X} maps an entry of {} bits (at most 255)", pdo.index, *eb));
    }
    entry.index = static_cast<std::uint16_t>(*ei);
    entry.subindex = static_cast<std::uint8_t>(*es);
    entry.bit_length = static_cast<std::uint8_t>(*eb);
    entry.name = trim(e.child_value("Name"));
    entry.data_type = trim(e.child_value("DataType"));
    pdo.entries.push_back(std::move(entry));
  }
  return pdo;
}

Result<EsiDevice> read_device(const pugi::xml_node& d) {
  EsiDevice dev;
  const pugi::xml_node type = d.child("Type");
  Context ctx{fmt::format("device '{}'", trim(type.text().as_string()))};
  auto product = attr_number<std::uint32_t>(ctx, type, "ProductCode");
  if (!product) return product.error();
  auto revision = attr_number<std::uint32_t>(ctx, type, "RevisionNo", 0u);
  if (!revision) return revision.error();
  dev.product_code = *product;
  dev.revision = *revision;
  dev.type = trim(type.text().as_string());
  dev.name = trim(d.child_value("Name"));
  dev.group_type = trim(d.child_value("GroupType"));
  dev.physics = d.attribute("Physics").value();
  const pugi::xml_node controller = d.child("Info").child("EtherCATController");
  if (controller) {
    auto sm = number<std::uint32_t>(ctx, controller.child("SmCount"), "SmCount", 0u);
    auto fm = number<std::uint32_t>(ctx, controller.child("FmmuCount"), "FmmuCount", 0u);
    auto ram = number<std::uint32_t>(ctx, controller.child("DpramSize"), "DpramSize", 0u);
    if (!sm) return sm.error();
    if (!fm) return fm.error();
    if (!ram) return ram.error();
    dev.sync_manager_count = static_cast<std::uint8_t>(std::min<std::uint32_t>(*sm, 16));
    dev.fmmu_count = static_cast<std::uint8_t>(std::min<std::uint32_t>(*fm, 16));
    dev.dpram_size = *ram;
  }
  for (const auto& f : d.children("Fmmu"))
    dev.fmmus.push_back(trim(f.text().as_string()));
  for (const auto& s : d.children("Sm")) {
    EsiSyncManager sm;
    sm.type = trim(s.text().as_string());
    auto start = attr_number<std::uint32_t>(ctx, s, "StartAddress", 0u);
    auto def = attr_number<std::uint32_t>(ctx, s, "DefaultSize", 0u);
    auto min = attr_number<std::uint32_t>(ctx, s, "MinSize", 0u);
    auto max = attr_number<std::uint32_t>(ctx, s, "MaxSize", 0u);
    auto control = attr_number<std::uint32_t>(ctx, s, "ControlByte", 0u);
    for (auto* r : {&start, &def, &min, &max, &control}) {
      if (!*r) return r->error();
    }
    sm.start = static_cast<std::uint16_t>(*start);
    sm.default_size = static_cast<std::uint16_t>(*def);
    sm.min_size = static_cast<std::uint16_t>(*min);
    sm.max_size = static_cast<std::uint16_t>(*max);
    sm.control_byte = static_cast<std::uint8_t>(*control);
    sm.enable = truthy(s.attribute("Enable"));
    sm.virtual_sm = truthy(s.attribute("Virtual"));
    sm.op_only = truthy(s.attribute("OpOnly"));
    dev.sync_managers.push_back(std::move(sm));
  }
  for (const auto& p : d.children("RxPdo")) {
    auto pdo = read_pdo(ctx, p);
    if (!pdo) return pdo.error();
    dev.rxpdos.push_back(std::move(*pdo));
  }
  for (const auto& p : d.children("TxPdo")) {
    auto pdo = read_pdo(ctx, p);
    if (!pdo) return pdo.error();
    dev.txpdos.push_back(std::move(*pdo));
  }
  if (const auto m = d.child("Mailbox")) {
    EsiMailbox mb;
    mb.data_link_layer = truthy(m.attribute("DataLinkLayer"));
    mb.aoe = static_cast<bool>(m.child("AoE"));
    mb.eoe = static_cast<bool>(m.child("EoE"));
    mb.foe = static_cast<bool>(m.child("FoE"));
    mb.soe = static_cast<bool>(m.child("SoE"));
    mb.voe = static_cast<bool>(m.child("VoE"));
    if (const auto coe = m.child("CoE")) {
      mb.coe = true;
      mb.sdo_info = truthy(coe.attribute("SdoInfo"));
      mb.complete_access = truthy(coe.attribute("CompleteAccess"));
      mb.pdo_assign = truthy(coe.attribute("PdoAssign"));
      mb.pdo_config = truthy(coe.attribute("PdoConfig"));
      mb.pdo_upload = truthy(coe.attribute("PdoUpload"));
      mb.segmented_sdo = truthy(coe.attribute("SegmentedSdo"));
    }
    dev.mailbox = mb;
  }
  for (const auto& op : d.child("Dc").children("OpMode")) {
    EsiDcOpMode mode;
    mode.name = trim(op.child_value("Name"));
    mode.description = trim(op.child_value("Desc"));
    auto aa = number<std::uint32_t>(ctx, op.child("AssignActivate"), "AssignActivate", 0u);
    auto c0 = number<std::uint32_t>(ctx, op.child("CycleTimeSync0"), "CycleTimeSync0", 0u);
    auto f0 = attr_number<std::int32_t>(ctx, op.child("CycleTimeSync0"), "Factor", 0);
    auto s0 = number<std::int32_t>(ctx, op.child("ShiftTimeSync0"), "ShiftTimeSync0", 0);
    auto c1 = number<std::uint32_t>(ctx, op.child("CycleTimeSync1"), "CycleTimeSync1", 0u);
    auto f1 = attr_number<std::int32_t>(ctx, op.child("CycleTimeSync1"), "Factor", 0);
    auto s1 = number<std::int32_t>(ctx, op.child("ShiftTimeSync1"), "ShiftTimeSync1", 0);
    if (!aa) return aa.error();
    if (!c0) return c0.error();
    if (!f0) return f0.error();
    if (!s0) return s0.error();
    if (!c1) return c1.error();
    if (!f1) return f1.error();
    if (!s1) return s1.error();
    mode.assign_activate = static_cast<std::uint16_t>(*aa);
    mode.cycle_time_sync0 = *c0;
    mode.cycle_time_sync0_factor = static_cast<std::int16_t>(*f0);
    mode.shift_time_sync0 = *s0;
    mode.cycle_time_sync1 = *c1;
    mode.cycle_time_sync1_factor = static_cast<std::int16_t>(*f1);
    mode.shift_time_sync1 = *s1;
    dev.dc_op_modes.push_back(std::move(mode));
  }
  if (const auto e = d.child("Eeprom")) {
    auto size = number<std::uint32_t>(ctx, e.child("ByteSize"), "Eeprom ByteSize", 0u);
    if (!size) return size.error();
    dev.eeprom_byte_size = *size;
    dev.eeprom_config_data = parse_hex(e.child_value("ConfigData"));
    const auto boot = parse_hex(e.child_value("BootStrap"));
    if (boot.size() == 8) {
      std::array<std::uint16_t, 4> words{};
      for (std::size_t i = 0; i < 4; ++i) {
        words[i] = static_cast<std::uint16_t>(boot[2 * i] | (boot[2 * i + 1] << 8));
      }
      dev.bootstrap = words;
    }
  }
  const pugi::xml_node profile = d.child("Profile");
  auto profile_no = number<std::uint32_t>(ctx, profile.child("ProfileNo"), "ProfileNo", 0u);
  if (!profile_no) return profile_no.error();
  dev.profile_no = *profile_no;
  if (const auto dictionary = profile.child("Dictionary")) {
    auto objects = read_objects(ctx, dictionary);
    if (!objects) return objects.error();
    dev.objects = std::move(*objects);
  }
  return dev;
}

}  // namespace

const EsiObject* EsiDevice::object(std::uint16_t index) const noexcept {
  for (const auto& o : objects) {
    if (o.index == index) return &o;
  }
  return nullptr;
}

Result<EsiFile> parse_esi(std::string_view xml) {
  pugi::xml_document doc;
  const pugi::xml_parse_result parsed = doc.load_buffer(xml.data(), xml.size());
  if (!parsed) {
    return Error(Errc::malformed,
                 fmt::format("ESI: XML error at byte {}: {}", parsed.offset, parsed.description()));
  }
  const pugi::xml_node root = doc.child("EtherCATInfo");
  if (!root) return Error(Errc::malformed, "ESI: the document has no <EtherCATInfo> element");
  EsiFile file;
  const pugi::xml_node vendor = root.child("Vendor");
  auto id = parse_number(vendor.child_value("Id"));
  if (!id) {
    return Error(Errc::malformed, fmt::format("ESI: Vendor/Id '{}' is missing or not a number",
                                              vendor.child_value("Id")));
  }
  file.vendor_id = static_cast<std::uint32_t>(*id);
  file.vendor_name = trim(vendor.child_value("Name"));
  for (const auto& d : root.child("Descriptions").child("Devices").children("Device")) {
    auto device = read_device(d);
    if (!device) return device.error();
    file.devices.push_back(std::move(*device));
  }
  if (file.devices.empty()) {
    return Error(Errc::malformed, "ESI: Descriptions/Devices holds no <Device>");
  }
  return file;
}

Result<EsiFile> load_esi(const std::string& path) {
  auto xml = read_file(path, FileKind::esi);
  if (!xml) return std::move(xml).error();
  auto file = parse_esi(*xml);
  if (!file) {
    return Error(file.error().code(), fmt::format("{}: {}", path, file.error().describe()));
  }
  return file;
}

Result<const EsiDevice*> find_esi_device(const EsiFile& file,
                                         std::optional<std::uint32_t> product_code) {
  if (!product_code) {
    if (file.devices.size() == 1) return &file.devices.front();
  } else {
    for (const auto& d : file.devices) {
      if (d.product_code == *product_code) return &d;
    }
  }
  std::string list;
  for (const auto& d : file.devices) {
    list += fmt::format("{}0x{:08X} ({})", list.empty() ? "" : ", ", d.product_code, d.type);
  }
  if (!product_code) {
    return Error(Errc::invalid_argument,
                 fmt::format("the ESI file describes {} devices; choose one with product= ({})",
                             file.devices.size(), list));
  }
  return Error(Errc::not_found, fmt::format("the ESI file has no device with product code "
                                            "0x{:08X} (it has {})",
                                            *product_code, list));
}

std::uint16_t esi_basic_type(std::string_view type) noexcept {
  struct Name {
    std::string_view name;
    std::uint16_t index;
  };
  static constexpr Name kNames[] = {
      {"BOOL", 0x0001},         {"BOOLEAN", 0x0001},        {"BIT", 0x0001},
      {"SINT", 0x0002},         {"INTEGER8", 0x0002},       {"INT", 0x0003},
      {"INTEGER16", 0x0003},    {"DINT", 0x0004},           {"INTEGER32", 0x0004},
      {"USINT", 0x0005},        {"UNSIGNED8", 0x0005},      {"UINT", 0x0006},
      {"UNSIGNED16", 0x0006},   {"UDINT", 0x0007},          {"UNSIGNED32", 0x0007},
      {"REAL", 0x0008},         {"REAL32", 0x0008},         {"VISIBLE_STRING", 0x0009},
      {"OCTET_STRING", 0x000A}, {"UNICODE_STRING", 0x000B}, {"INT24", 0x0010},
      {"INTEGER24", 0x0010},    {"LREAL", 0x0011},          {"REAL64", 0x0011},
      {"LINT", 0x0015},         {"INTEGER64", 0x0015},      {"UINT24", 0x0016},
      {"UNSIGNED24", 0x0016},   {"ULINT", 0x001B},          {"UNSIGNED64", 0x001B},
      {"BYTE", 0x001E},         {"WORD", 0x001F},           {"DWORD", 0x0020},
      {"BITARR8", 0x002D},      {"BITARR16", 0x002E},       {"BITARR32", 0x002F},
      {"BIT1", 0x0030},         {"BIT2", 0x0031},           {"BIT3", 0x0032},
      {"BIT4", 0x0033},         {"BIT5", 0x0034},           {"BIT6", 0x0035},
      {"BIT7", 0x0036},         {"BIT8", 0x0037},
  };
  for (const auto& n : kNames) {
    if (n.name == type) return n.index;
  }
  if (type.rfind("STRING(", 0) == 0) return 0x0009;
  return 0;
}

Result<wire::SiiImage> esi_to_sii(const EsiFile& file, const EsiDevice& device) {
  wire::SiiImage sii;
  const auto word = [&](std::size_t i) -> std::uint16_t {
    const auto& c = device.eeprom_config_data;
    return 2 * i + 1 < c.size() ? static_cast<std::uint16_t>(c[2 * i] | (c[2 * i + 1] << 8)) : 0;
  };
  sii.pdi_control = word(0);
  sii.pdi_configuration = word(1);
  sii.sync_impulse_length = word(2);
  sii.pdi_configuration2 = word(3);
  sii.station_alias = word(4);
  sii.identity = {file.vendor_id, device.product_code, device.revision, 0};
  if (device.eeprom_byte_size >= 128) {
    sii.eeprom_size = static_cast<std::uint16_t>(
        std::min<std::uint32_t>(device.eeprom_byte_size * 8 / 1024, 0x10000) - 1);
  }
  for (const auto& sm : device.sync_managers) {
    if (sm.type == "MBoxOut") {
      sii.standard_mailbox.recv_offset = sm.start;
      sii.standard_mailbox.recv_size = sm.default_size ? sm.default_size : sm.max_size;
    } else if (sm.type == "MBoxIn") {
      sii.standard_mailbox.send_offset = sm.start;
      sii.standard_mailbox.send_size = sm.default_size ? sm.default_size : sm.max_size;
    }
  }
  if (device.bootstrap) {
    const auto& b = *device.bootstrap;
    sii.bootstrap_mailbox = {b[0], b[1], b[2], b[3]};
  }
  if (device.mailbox) {
    const auto& m = *device.mailbox;
    namespace mp = wire::mailbox_protocol;
    sii.mailbox_protocols = static_cast<std::uint16_t>(
        (m.aoe ? mp::kAoe : 0) | (m.eoe ? mp::kEoe : 0) | (m.coe ? mp::kCoe : 0) |
        (m.foe ? mp::kFoe : 0) | (m.soe ? mp::kSoe : 0) | (m.voe ? mp::kVoe : 0));
  }

  auto add_string = [&sii](std::string_view text) -> std::uint8_t {
    if (text.empty()) return 0;
    for (std::size_t i = 0; i < sii.strings.size(); ++i) {
      if (sii.strings[i] == text) return static_cast<std::uint8_t>(i + 1);
    }
    if (sii.strings.size() >= 255) return 0;
    // SII strings are at most 255 bytes.
    sii.strings.emplace_back(text.substr(0, 255));
    return static_cast<std::uint8_t>(sii.strings.size());
  };
  wire::SiiGeneral general;
  general.order_index = add_string(device.type);
  general.group_index = add_string(device.group_type);
  general.name_index = add_string(device.name);
  if (device.mailbox) {
    const auto& m = *device.mailbox;
    namespace cd = wire::sii_coe_detail;
    if (m.coe) {
      general.coe_details = static_cast<std::uint8_t>(
          cd::kSdo | (m.sdo_info ? cd::kSdoInfo : 0) | (m.pdo_assign ? cd::kPdoAssign : 0) |
          (m.pdo_config ? cd::kPdoConfiguration : 0) |
          (m.pdo_upload ? cd::kPdoUploadAtStartup : 0) |
          (m.complete_access ? cd::kSdoCompleteAccess : 0));
    }
    general.foe_details = m.foe ? 1 : 0;
    general.eoe_details = m.eoe ? 1 : 0;
    if (m.data_link_layer) general.flags |= wire::sii_general_flag::kMailboxDataLinkLayer;
  }
  general.ds402_channels = device.profile_no == 402 ? 1 : 0;
  for (std::size_t i = 0; i < device.physics.size() && i < 4; ++i) {
    std::uint8_t port = wire::sii_port::kUnused;
    switch (device.physics[i]) {
      case 'Y':
      case 'H':
        port = wire::sii_port::kMii;
        break;
      case 'K':
        port = wire::sii_port::kEbus;
        break;
      default:
        break;
    }
    general.physical_port = static_cast<std::uint16_t>(general.physical_port | (port << (4 * i)));
  }
  sii.general = general;

  for (const auto& f : device.fmmus) {
    sii.fmmus.push_back(f == "Outputs"     ? wire::sii_fmmu_usage::kOutputs
                        : f == "Inputs"    ? wire::sii_fmmu_usage::kInputs
                        : f == "MBoxState" ? wire::sii_fmmu_usage::kMailboxState
                                           : wire::sii_fmmu_usage::kUnused);
  }
  for (const auto& sm : device.sync_managers) {
    wire::SiiSyncManager s;
    s.start = sm.start;
    s.length = sm.default_size;
    s.control = sm.control_byte;
    s.enable = static_cast<std::uint8_t>((sm.enable ? 0x01 : 0) | (sm.virtual_sm ? 0x04 : 0) |
                                         (sm.op_only ? 0x08 : 0));
    s.type = sm.type == "MBoxOut"   ? wire::sii_sm_type::kMailboxOut
             : sm.type == "MBoxIn"  ? wire::sii_sm_type::kMailboxIn
             : sm.type == "Outputs" ? wire::sii_sm_type::kOutputs
             : sm.type == "Inputs"  ? wire::sii_sm_type::kInputs
                                    : wire::sii_sm_type::kUnused;
    sii.sync_managers.push_back(s);
  }
  auto add_pdos = [&](const std::vector<EsiPdo>& pdos, std::vector<wire::SiiPdo>& out) {
    for (const auto& p : pdos) {
      wire::SiiPdo pdo;
      pdo.index = p.index;
      pdo.sync_manager = p.sync_manager.value_or(0xFF);
      pdo.name_index = add_string(p.name);
      pdo.flags = static_cast<std::uint16_t>((p.mandatory ? wire::sii_pdo_flag::kMandatory : 0) |
                                             (p.sync_manager ? wire::sii_pdo_flag::kDefault : 0) |
                                             (p.fixed ? wire::sii_pdo_flag::kFixedContent : 0));
      for (const auto& e : p.entries) {
        wire::SiiPdoEntry entry;
        entry.index = e.index;
        entry.subindex = e.subindex;
        entry.name_index = add_string(e.name);
        entry.data_type = static_cast<std::uint8_t>(esi_basic_type(e.data_type));
        entry.bit_length = e.bit_length;
        pdo.entries.push_back(entry);
      }
      out.push_back(std::move(pdo));
    }
  };
  add_pdos(device.txpdos, sii.txpdos);
  add_pdos(device.rxpdos, sii.rxpdos);
  for (const auto& op : device.dc_op_modes) {
    wire::SiiDcSync dc;
    dc.cycle_time_0 = op.cycle_time_sync0;
    dc.shift_time_0 = static_cast<std::uint32_t>(op.shift_time_sync0);
    dc.shift_time_1 = static_cast<std::uint32_t>(op.shift_time_sync1);
    dc.sync1_cycle_factor = op.cycle_time_sync1_factor;
    dc.assign_activate = op.assign_activate;
    dc.sync0_cycle_factor = op.cycle_time_sync0_factor;
    dc.name_index = add_string(op.name);
    dc.description_index = add_string(op.description);
    sii.dc.push_back(dc);
  }
  return sii;
}

}  // namespace ecat::config
