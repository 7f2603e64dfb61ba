// ENI (ETG.2100) reader: include/ecat/config/eni.hpp. Element names as published ENIs spell them
// (see the header); where a configurator is known to vary (a CoE InitCmd's Disabled flag as an
// attribute or a child element) both are accepted.
#include <algorithm>
#include <charconv>
#include <cstring>
#include <limits>
#include <set>

#include <fmt/format.h>
#include <pugixml.hpp>

#include <ecat/config/eni.hpp>

#include "core/read_file.hpp"

namespace ecat::config {

namespace {

std::string_view trim(std::string_view text) {
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(" \t\r\n");
  return text.substr(first, last - first + 1);
}

// Longest text kept for names and comments (longer ones are cut, not refused: they are labels).
constexpr std::size_t kMaxLabel = 1024;

std::string label(std::string_view text) {
  const auto t = trim(text);
  return std::string(t.substr(0, std::min(t.size(), kMaxLabel)));
}

class Reader {
 public:
  Reader(std::string_view xml, std::string_view source) : xml_(xml), source_(source) {
    for (std::size_t i = 0; i < xml.size(); ++i) {
      if (xml[i] == '\n') newlines_.push_back(i);
    }
  }

  Result<EniFile> read() {
    pugi::xml_document doc;
    // parse_default without parse_escapes? No: entities in names and CDATA comments are common.
    const pugi::xml_parse_result parsed = doc.load_buffer(xml_.data(), xml_.size());
    if (!parsed) {
      return Error(
          Errc::malformed,
          fmt::format("{}:{}: not well-formed XML: {}", source_,
                      line_at(static_cast<std::size_t>(std::max<std::ptrdiff_t>(parsed.offset, 0))),
                      parsed.description()));
    }
    const pugi::xml_node root = doc.document_element();
    if (std::strcmp(root.name(), "EtherCATConfig") != 0) {
      return Error(Errc::malformed,
                   fmt::format("{}:{}: the root element is <{}>, not <EtherCATConfig> (an ENI)",
                               source_, line(root), root.name()));
    }
    EniFile file;
    file.version = label(root.attribute("Version").value());
    const pugi::xml_node config = root.child("Config");
    if (!config) return fail(root, "has no <Config>");
    for (const auto& child : root.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (name != "Config") note_unknown(file.unrecognised, child);
    }
    for (const auto& child : config.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (name == "Master") {
        if (auto r = master(child, file.master); !r) return r.error();
      } else if (name == "Slave") {
        if (file.slaves.size() >= kMaxEniSlaves) {
          return fail(child, fmt::format("more than {} slaves", kMaxEniSlaves));
        }
        auto s = slave(child);
        if (!s) return s.error();
        file.slaves.push_back(std::move(*s));
      } else if (name == "Cyclic") {
        if (file.cyclic.size() >= kMaxEniInitCmds) return fail(child, "too many <Cyclic>");
        auto c = cyclic(child);
        if (!c) return c.error();
        file.cyclic.push_back(std::move(*c));
      } else if (name == "ProcessImage") {
        file.has_process_image = true;
      } else {
        note_unknown(file.unrecognised, child);
      }
    }
    return file;
  }

 private:
  int line_at(std::size_t offset) const {
    return static_cast<int>(std::upper_bound(newlines_.begin(), newlines_.end(), offset) -
                            newlines_.begin()) +
           1;
  }
  int line(const pugi::xml_node& node) const {
    const auto offset = node.offset_debug();
    return offset < 0 ? 0 : line_at(static_cast<std::size_t>(offset));
  }

  Error fail(const pugi::xml_node& node, std::string_view what) const {
    return Error(Errc::malformed,
                 fmt::format("{}:{}: <{}>: {}", source_, line(node), node.name(), what));
  }

  void note_unknown(std::vector<std::string>& out, const pugi::xml_node& node) const {
    if (out.size() < 256) out.push_back(fmt::format("<{}> (line {})", node.name(), line(node)));
  }

  // A number: decimal, "#x" or "0x" hexadecimal, optionally negative. In [min, max]; with
  // `wrap_bits` a negative value down to -2^(bits-1) is taken as its two's complement (xs:int
  // fields such as ProductCode and AutoIncAddr, which configurators write signed).
  Result<std::int64_t> number_text(const pugi::xml_node& where, std::string_view raw,
                                   std::int64_t min, std::int64_t max, int wrap_bits = 0) const {
    const auto text = trim(raw);
    std::string_view t = text;
    bool negative = false;
    int base = 10;
    if (!t.empty() && t[0] == '-') {
      negative = true;
      t.remove_prefix(1);
    }
    if (t.size() > 2 && (t[0] == '#' || t[0] == '0') && (t[1] == 'x' || t[1] == 'X')) {
      t.remove_prefix(2);
      base = 16;
    }
    std::uint64_t magnitude = 0;
    const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), magnitude, base);
    if (t.empty() || ec != std::errc{} || end != t.data() + t.size()) {
      return fail(where, fmt::format("\"{}\" is not a number", label(text)));
    }
    if (magnitude > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
      return fail(where, fmt::format("{} is out of range", label(text)));
    }
    std::int64_t v = static_cast<std::int64_t>(magnitude);
    if (negative) v = -v;
    if (negative && wrap_bits > 0 && v >= -(std::int64_t{1} << (wrap_bits - 1))) {
      v += std::int64_t{1} << wrap_bits;
    }
    if (v < min || v > max) {
      return fail(where, fmt::format("{} is out of range [{}, {}]", label(text), min, max));
    }
    return v;
  }

  // The text of the child element `name` of `node` as a number; `fallback` when it is absent.
  template <class T>
  Result<T> child_number(const pugi::xml_node& node, const char* name, std::optional<T> fallback,
                         int wrap_bits = 0) const {
    const pugi::xml_node c = node.child(name);
    if (!c) {
      if (fallback) return *fallback;
      return fail(node, fmt::format("<{}> is missing", name));
    }
    auto v = number_text(c, c.child_value(), std::numeric_limits<T>::min(),
                         static_cast<std::int64_t>(std::numeric_limits<T>::max()), wrap_bits);
    if (!v) return v.error();
    return static_cast<T>(*v);
  }
  template <class T>
  Result<std::optional<T>> optional_number(const pugi::xml_node& node, const char* name,
                                           int wrap_bits = 0) const {
    if (!node.child(name)) return std::optional<T>{};
    auto v = child_number<T>(node, name, std::nullopt, wrap_bits);
    if (!v) return v.error();
    return std::optional<T>(*v);
  }

  Result<bool> boolean(const pugi::xml_node& where, std::string_view raw) const {
    const auto t = trim(raw);
    if (t == "1" || t == "true") return true;
    if (t == "0" || t == "false" || t.empty()) return false;
    return fail(where, fmt::format("\"{}\" is not a boolean (true, false, 1, 0)", label(t)));
  }
  Result<bool> attr_bool(const pugi::xml_node& node, const char* name) const {
    const auto a = node.attribute(name);
    if (!a) return false;
    auto b = boolean(node, a.value());
    if (!b) return b.error().context(fmt::format("attribute {}", name));
    return b;
  }
  Result<bool> child_bool(const pugi::xml_node& node, const char* name) const {
    const auto c = node.child(name);
    if (!c) return false;
    return boolean(c, c.child_value());
  }

  // Hex bytes ("0100001a"), whitespace allowed between bytes.
  Result<std::vector<std::uint8_t>> hex(const pugi::xml_node& where) const {
    const std::string_view text = trim(where.child_value());
    std::vector<std::uint8_t> out;
    std::size_t i = 0;
    while (i < text.size()) {
      if (text[i] == ' ' || text[i] == '\t' || text[i] == '\r' || text[i] == '\n') {
        ++i;
        continue;
      }
      if (i + 1 >= text.size()) return fail(where, "hex data has an odd number of digits");
      std::uint8_t byte = 0;
      const auto [end, ec] = std::from_chars(text.data() + i, text.data() + i + 2, byte, 16);
      if (ec != std::errc{} || end != text.data() + i + 2) {
        return fail(where, fmt::format("\"{}\" is not hex data", label(text.substr(i, 2))));
      }
      if (out.size() >= kMaxEniDataBytes) {
        return fail(where, fmt::format("more than {} bytes of data", kMaxEniDataBytes));
      }
      out.push_back(byte);
      i += 2;
    }
    return out;
  }

  Result<std::vector<std::string>> transitions(const pugi::xml_node& cmd) const {
    static const std::set<std::string_view> kKnown{"IP", "PS", "SO", "OS", "SP", "PI",
                                                   "SI", "OI", "IB", "BI", "II", "OP"};
    std::vector<std::string> out;
    for (const auto& t : cmd.children("Transition")) {
      const auto text = trim(t.child_value());
      if (!kKnown.count(text)) {
        return fail(t, fmt::format("unknown transition \"{}\" (IP, PS, SO, SP, OP, PI, SI, OI, "
                                   "IB, BI, II, OS)",
                                   label(text)));
      }
      if (out.size() < 16) out.emplace_back(text);
    }
    return out;
  }

  // ---- Master --------------------------------------------------------------------------------

  Result<void> master(const pugi::xml_node& node, EniMaster& m) {
    m.name = label(node.child("Info").child_value("Name"));
    m.has_mailbox_states = static_cast<bool>(node.child("MailboxStates"));
    m.has_eoe = static_cast<bool>(node.child("EoE"));
    return esc_init_cmds(node.child("InitCmds"), m.init_cmds);
  }

  // ---- Slave ---------------------------------------------------------------------------------

  Result<EniSlave> slave(const pugi::xml_node& node) {
    EniSlave s;
    s.line = line(node);
    const pugi::xml_node info = node.child("Info");
    if (!info) return fail(node, "has no <Info> (the slave's identity)");
    if (auto r = slave_info(info, s.info); !r) return r.error();
    // Known children ecat reads, and those it knows and leaves to the report (the master layer).
    static const std::set<std::string_view> kKnown{
        "Info",       "ProcessData", "Mailbox", "InitCmds",  "DC",        "PreviousPort",
        "HotConnect", "BootMailbox", "Boot",    "SlotIndex", "Interface", "Group"};
    for (const auto& child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (!kKnown.count(name)) {
        note_unknown(s.unrecognised, child);
      } else if (name == "ProcessData") {
        auto pd = process_data(child);
        if (!pd) return pd.error();
        s.process_data = std::move(*pd);
      } else if (name == "Mailbox") {
        auto mb = mailbox(child);
        if (!mb) return mb.error();
        s.mailbox = std::move(*mb);
      } else if (name == "InitCmds") {
        if (auto r = esc_init_cmds(child, s.init_cmds); !r) return r.error();
      } else if (name == "DC") {
        auto dc = distributed_clocks(child);
        if (!dc) return dc.error();
        s.dc = *dc;
      } else if (name == "HotConnect") {
        if (s.hot_connect) return fail(child, "a second <HotConnect> in one <Slave>");
        auto hc = hot_connect(child);
        if (!hc) return hc.error();
        s.hot_connect = std::move(*hc);
      }
    }
    return s;
  }

  Result<void> slave_info(const pugi::xml_node& info, EniSlaveInfo& out) {
    out.name = label(info.child_value("Name"));
    auto phys = optional_number<std::uint16_t>(info, "PhysAddr", 16);
    if (!phys) return phys.error();
    out.phys_addr = *phys;
    auto aia = optional_number<std::uint16_t>(info, "AutoIncAddr", 16);
    if (!aia) return aia.error();
    out.auto_inc_addr = *aia;
    if (const auto id = info.child("Identification")) {
      auto ado = optional_number<std::uint16_t>(id, "Ado", 16);
      if (!ado) return ado.error();
      auto value = optional_number<std::uint16_t>(id, "Value", 16);
      if (!value) return value.error();
      out.identification_ado = *ado;
      out.identification_value = *value;
    }
    auto vendor = child_number<std::uint32_t>(info, "VendorId", std::nullopt, 32);
    if (!vendor) return vendor.error();
    out.vendor_id = *vendor;
    auto product = child_number<std::uint32_t>(info, "ProductCode", std::nullopt, 32);
    if (!product) return product.error();
    out.product_code = *product;
    auto revision = optional_number<std::uint32_t>(info, "RevisionNo", 32);
    if (!revision) return revision.error();
    out.revision_no = *revision;
    auto serial = optional_number<std::uint32_t>(info, "SerialNo", 32);
    if (!serial) return serial.error();
    out.serial_no = *serial;
    return ok();
  }

  Result<std::optional<EniImageRange>> image_range(const pugi::xml_node& node) const {
    if (!node) return std::optional<EniImageRange>{};
    EniImageRange r;
    auto start = child_number<std::uint32_t>(node, "BitStart", 0u);
    if (!start) return start.error();
    auto length = child_number<std::uint32_t>(node, "BitLength", 0u);
    if (!length) return length.error();
    r.bit_start = *start;
    r.bit_length = *length;
    return std::optional<EniImageRange>(r);
  }

  Result<EniProcessData> process_data(const pugi::xml_node& node) {
    EniProcessData pd;
    auto send = image_range(node.child("Send"));
    if (!send) return send.error();
    pd.send = *send;
    auto recv = image_range(node.child("Recv"));
    if (!recv) return recv.error();
    pd.recv = *recv;
    for (const auto& child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (name.size() >= 3 && name.size() <= 4 && name.starts_with("Sm") &&
          std::all_of(name.begin() + 2, name.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        // <Sm0>..<Sm15>: the element's name carries the SyncManager number.
        const int index = std::stoi(std::string(name.substr(2)));
        if (index > 15) return fail(child, "an ESC has SyncManagers 0..15");
        auto sm = sync_manager(child, static_cast<std::uint8_t>(index));
        if (!sm) return sm.error();
        pd.sync_managers.push_back(std::move(*sm));
      } else if (name == "RxPdo" || name == "TxPdo") {
        auto& list = name == "RxPdo" ? pd.rx_pdos : pd.tx_pdos;
        if (list.size() >= kMaxEniPdos) {
          return fail(child, fmt::format("more than {} PDOs", kMaxEniPdos));
        }
        auto pdo = read_pdo(child);
        if (!pdo) return pdo.error();
        list.push_back(std::move(*pdo));
      }
    }
    return pd;
  }

  Result<EniSyncManager> sync_manager(const pugi::xml_node& node, std::uint8_t index) {
    EniSyncManager sm;
    sm.index = index;
    sm.line = line(node);
    sm.type = label(node.child_value("Type"));
    auto size = child_number<std::uint16_t>(node, "DefaultSize", std::uint16_t{0});
    if (!size) return size.error();
    sm.default_size = *size;
    auto start = child_number<std::uint16_t>(node, "StartAddress", std::uint16_t{0});
    if (!start) return start.error();
    sm.start_address = *start;
    auto control = child_number<std::uint8_t>(node, "ControlByte", std::uint8_t{0});
    if (!control) return control.error();
    sm.control_byte = *control;
    auto enable = child_bool(node, "Enable");
    if (!enable) return enable.error();
    sm.enable = *enable;
    for (const auto& p : node.children("Pdo")) {
      if (sm.pdos.size() >= kMaxEniPdos) {
        return fail(p, fmt::format("more than {} PDOs on one SyncManager", kMaxEniPdos));
      }
      auto v = number_text(p, p.child_value(), 0, 0xFFFF);
      if (!v) return v.error();
      sm.pdos.push_back(static_cast<std::uint16_t>(*v));
    }
    return sm;
  }

  Result<EniPdo> read_pdo(const pugi::xml_node& node) {
    EniPdo pdo;
    pdo.line = line(node);
    auto index = child_number<std::uint16_t>(node, "Index", std::nullopt);
    if (!index) return index.error();
    pdo.index = *index;
    pdo.name = label(node.child_value("Name"));
    auto fixed = attr_bool(node, "Fixed");
    if (!fixed) return fixed.error();
    pdo.fixed = *fixed;
    auto mandatory = attr_bool(node, "Mandatory");
    if (!mandatory) return mandatory.error();
    pdo.mandatory = *mandatory;
    if (const auto sm = node.attribute("Sm")) {
      auto v = number_text(node, sm.value(), 0, 15);
      if (!v) return v.error().context("attribute Sm");
      pdo.sync_manager = static_cast<std::uint8_t>(*v);
    }
    for (const auto& e : node.children("Entry")) {
      if (pdo.entries.size() >= kMaxEniPdoEntries) {
        return fail(e, fmt::format("more than {} entries in one PDO", kMaxEniPdoEntries));
      }
      EniPdoEntry entry;
      entry.line = line(e);
      // A gap (padding) entry may leave out its Index (0).
      auto ix = child_number<std::uint16_t>(e, "Index", std::uint16_t{0});
      if (!ix) return ix.error();
      entry.index = *ix;
      auto sub = child_number<std::uint8_t>(e, "SubIndex", std::uint8_t{0});
      if (!sub) return sub.error();
      entry.subindex = *sub;
      auto bits = child_number<std::uint8_t>(e, "BitLen", std::nullopt);
      if (!bits) return bits.error();
      if (*bits == 0) return fail(e.child("BitLen"), "a PDO entry needs at least one bit");
      entry.bit_length = *bits;
      entry.name = label(e.child_value("Name"));
      entry.data_type = label(e.child_value("DataType"));
      pdo.entries.push_back(std::move(entry));
    }
    return pdo;
  }

  // ---- Mailbox -------------------------------------------------------------------------------

  Result<EniMailbox> mailbox(const pugi::xml_node& node) {
    EniMailbox mb;
    mb.line = line(node);
    const auto send = node.child("Send");
    const auto recv = node.child("Recv");
    auto ss = child_number<std::uint16_t>(send, "Start", std::uint16_t{0});
    auto sl = child_number<std::uint16_t>(send, "Length", std::uint16_t{0});
    auto rs = child_number<std::uint16_t>(recv, "Start", std::uint16_t{0});
    auto rl = child_number<std::uint16_t>(recv, "Length", std::uint16_t{0});
    for (auto* r : {&ss, &sl, &rs, &rl}) {
      if (!*r) return r->error();
    }
    mb.send_start = *ss;
    mb.send_length = *sl;
    mb.recv_start = *rs;
    mb.recv_length = *rl;
    for (const auto& p : node.children("Protocol")) {
      if (mb.protocols.size() < 16) mb.protocols.push_back(label(p.child_value()));
    }
    mb.has_eoe = static_cast<bool>(node.child("EoE"));
    for (const auto& cmd : node.child("CoE").child("InitCmds").children("InitCmd")) {
      if (mb.coe_init_cmds.size() >= kMaxEniInitCmds) {
        return fail(cmd, fmt::format("more than {} CoE InitCmds", kMaxEniInitCmds));
      }
      auto c = coe_init_cmd(cmd);
      if (!c) return c.error();
      mb.coe_init_cmds.push_back(std::move(*c));
    }
    for (const auto& cmd : node.child("SoE").child("InitCmds").children("InitCmd")) {
      if (mb.soe_init_cmds.size() >= kMaxEniInitCmds) {
        return fail(cmd, fmt::format("more than {} SoE InitCmds", kMaxEniInitCmds));
      }
      auto c = soe_init_cmd(cmd);
      if (!c) return c.error();
      mb.soe_init_cmds.push_back(std::move(*c));
    }
    return mb;
  }

  Result<EniCoeInitCmd> coe_init_cmd(const pugi::xml_node& node) {
    EniCoeInitCmd c;
    c.line = line(node);
    auto t = transitions(node);
    if (!t) return t.error();
    c.transitions = std::move(*t);
    c.comment = label(node.child_value("Comment"));
    auto ccs = child_number<std::uint8_t>(node, "Ccs", std::uint8_t{1});
    if (!ccs) return ccs.error();
    if (*ccs != 1 && *ccs != 2) {
      return fail(node.child("Ccs"),
                  fmt::format("Ccs {} is neither 1 (download) nor 2 (upload)", *ccs));
    }
    c.ccs = *ccs;
    auto index = child_number<std::uint16_t>(node, "Index", std::nullopt);
    if (!index) return index.error();
    c.index = *index;
    auto sub = child_number<std::uint8_t>(node, "SubIndex", std::uint8_t{0});
    if (!sub) return sub.error();
    c.subindex = *sub;
    if (const auto data = node.child("Data")) {
      auto bytes = hex(data);
      if (!bytes) return bytes.error();
      c.data = std::move(*bytes);
    }
    auto timeout = child_number<std::uint32_t>(node, "Timeout", 0u);
    if (!timeout) return timeout.error();
    c.timeout_ms = *timeout;
    auto ca = attr_bool(node, "CompleteAccess");
    if (!ca) return ca.error();
    c.complete_access = *ca;
    auto fixed = attr_bool(node, "Fixed");
    if (!fixed) return fixed.error();
    c.fixed = *fixed;
    auto disabled_attr = attr_bool(node, "Disabled");
    if (!disabled_attr) return disabled_attr.error();
    auto disabled_child = child_bool(node, "Disabled");
    if (!disabled_child) return disabled_child.error();
    c.disabled = *disabled_attr || *disabled_child;
    if (c.ccs == 1 && c.data.empty() && !c.disabled) {
      return fail(
          node, fmt::format("the download to 0x{:04X}:{:02X} has no <Data>", c.index, c.subindex));
    }
    return c;
  }

  Result<EniSoeInitCmd> soe_init_cmd(const pugi::xml_node& node) {
    EniSoeInitCmd c;
    c.line = line(node);
    auto t = transitions(node);
    if (!t) return t.error();
    c.transitions = std::move(*t);
    c.comment = label(node.child_value("Comment"));
    auto op = child_number<std::uint8_t>(node, "OpCode", std::uint8_t{0});
    if (!op) return op.error();
    c.op_code = *op;
    auto drive = child_number<std::uint8_t>(node, "DriveNo", std::uint8_t{0});
    if (!drive) return drive.error();
    c.drive_no = *drive;
    auto idn = child_number<std::uint16_t>(node, "IDN", std::nullopt);
    if (!idn) return idn.error();
    c.idn = *idn;
    if (const auto data = node.child("Data")) {
      auto bytes = hex(data);
      if (!bytes) return bytes.error();
      c.data = std::move(*bytes);
    }
    return c;
  }

  // ---- ESC init commands (Slave/InitCmds, Master/InitCmds) -----------------------------------

  Result<void> esc_init_cmds(const pugi::xml_node& list, std::vector<EniEscInitCmd>& out) {
    for (const auto& node : list.children("InitCmd")) {
      if (out.size() >= kMaxEniInitCmds) {
        return fail(node, fmt::format("more than {} InitCmds", kMaxEniInitCmds));
      }
      EniEscInitCmd c;
      c.line = line(node);
      auto t = transitions(node);
      if (!t) return t.error();
      c.transitions = std::move(*t);
      c.comment = label(node.child_value("Comment"));
      auto cmd = child_number<std::uint8_t>(node, "Cmd", std::nullopt);
      if (!cmd) return cmd.error();
      c.cmd = *cmd;
      auto adp = child_number<std::uint16_t>(node, "Adp", std::uint16_t{0}, 16);
      if (!adp) return adp.error();
      c.adp = *adp;
      auto ado = child_number<std::uint16_t>(node, "Ado", std::uint16_t{0});
      if (!ado) return ado.error();
      c.ado = *ado;
      auto addr = optional_number<std::uint32_t>(node, "Addr", 32);
      if (!addr) return addr.error();
      c.addr = *addr;
      if (const auto data = node.child("Data")) {
        auto bytes = hex(data);
        if (!bytes) return bytes.error();
        c.data = std::move(*bytes);
      }
      auto length = child_number<std::uint32_t>(node, "DataLength",
                                                static_cast<std::uint32_t>(c.data.size()));
      if (!length) return length.error();
      if (*length > kMaxEniDataBytes) {
        return fail(node.child("DataLength"),
                    fmt::format("{} bytes is more than a datagram carries", *length));
      }
      c.data_length = *length;
      out.push_back(std::move(c));
    }
    return ok();
  }

  // ---- hot connect (Slave/HotConnect) ---------------------------------------------------------

  Result<EniHotConnect> hot_connect(const pugi::xml_node& node) {
    EniHotConnect hc;
    hc.line = line(node);
    // GroupName is text, or (as other names in the schema) a <Name> inside it.
    const pugi::xml_node name = node.child("GroupName");
    std::string_view raw = name.child_value();
    if (trim(raw).empty() && name.child("Name")) raw = name.child("Name").child_value();
    hc.group_name = label(trim(raw));
    auto count = optional_number<std::uint32_t>(node, "GroupMemberCnt");
    if (!count) return count.error();
    hc.member_count = *count;
    for (const auto& cmd : node.children("IdentifyCmd")) {
      if (hc.identify.size() >= 16) return fail(cmd, "more than 16 <IdentifyCmd>");
      EniIdentifyCmd c;
      c.line = line(cmd);
      auto op = child_number<std::uint8_t>(cmd, "Cmd", std::nullopt);
      if (!op) return op.error();
      c.cmd = *op;
      auto adp = child_number<std::uint16_t>(cmd, "Adp", std::uint16_t{0}, 16);
      if (!adp) return adp.error();
      c.adp = *adp;
      auto ado = child_number<std::uint16_t>(cmd, "Ado", std::nullopt);
      if (!ado) return ado.error();
      c.ado = *ado;
      std::vector<std::uint8_t> data;
      if (const auto d = cmd.child("Data")) {
        auto bytes = hex(d);
        if (!bytes) return bytes.error();
        data = std::move(*bytes);
      }
      auto length =
          child_number<std::uint32_t>(cmd, "DataLength", static_cast<std::uint32_t>(data.size()));
      if (!length) return length.error();
      if (*length > kMaxEniDataBytes) {
        return fail(cmd.child("DataLength"),
                    fmt::format("{} bytes is more than a datagram carries", *length));
      }
      c.data_length = *length;
      if (const auto v = cmd.child("Validate")) {
        if (const auto d = v.child("Data")) {
          auto bytes = hex(d);
          if (!bytes) return bytes.error();
          c.expected = std::move(*bytes);
        }
        if (const auto m = v.child("DataMask")) {
          auto bytes = hex(m);
          if (!bytes) return bytes.error();
          c.mask = std::move(*bytes);
        }
        if (c.expected.empty()) return fail(v, "<Data> (the value expected) is missing");
        if (!c.mask.empty() && c.mask.size() != c.expected.size()) {
          return fail(v, fmt::format("<DataMask> has {} bytes, <Data> {}", c.mask.size(),
                                     c.expected.size()));
        }
      }
      hc.identify.push_back(std::move(c));
    }
    return hc;
  }

  Result<EniDc> distributed_clocks(const pugi::xml_node& node) {
    EniDc dc;
    dc.line = line(node);
    auto prc = child_bool(node, "PotentialReferenceClock");
    if (!prc) return prc.error();
    dc.potential_reference_clock = *prc;
    auto rc = child_bool(node, "ReferenceClock");
    if (!rc) return rc.error();
    dc.reference_clock = *rc;
    // Nanoseconds; ETG.2100 types CycleTime0 as unsigned, ShiftTime and CycleTime1 as signed.
    constexpr std::int64_t kMaxNs = 4'000'000'000;
    if (const auto c = node.child("CycleTime0")) {
      auto v = number_text(c, c.child_value(), 0, kMaxNs);
      if (!v) return v.error();
      dc.cycle_time0 = *v;
    }
    if (const auto c = node.child("CycleTime1")) {
      auto v = number_text(c, c.child_value(), -kMaxNs, kMaxNs);
      if (!v) return v.error();
      dc.cycle_time1 = *v;
    }
    if (const auto c = node.child("ShiftTime")) {
      auto v = number_text(c, c.child_value(), -kMaxNs, kMaxNs);
      if (!v) return v.error();
      dc.shift_time = *v;
    }
    return dc;
  }

  // ---- Cyclic --------------------------------------------------------------------------------

  Result<EniCyclic> cyclic(const pugi::xml_node& node) {
    EniCyclic c;
    c.line = line(node);
    auto cycle = child_number<std::uint32_t>(node, "CycleTime", 0u);
    if (!cycle) return cycle.error();
    c.cycle_time_us = *cycle;
    std::size_t total = 0;
    for (const auto& frame : node.children("Frame")) {
      std::vector<EniCyclicCmd> cmds;
      for (const auto& cmd : frame.children("Cmd")) {
        if (++total > kMaxEniInitCmds) {
          return fail(cmd, fmt::format("more than {} cyclic commands", kMaxEniInitCmds));
        }
        EniCyclicCmd x;
        x.line = line(cmd);
        x.comment = label(cmd.child_value("Comment"));
        auto code = child_number<std::uint8_t>(cmd, "Cmd", std::nullopt);
        if (!code) return code.error();
        x.cmd = *code;
        auto addr = optional_number<std::uint32_t>(cmd, "Addr", 32);
        if (!addr) return addr.error();
        x.addr = *addr;
        auto adp = child_number<std::uint16_t>(cmd, "Adp", std::uint16_t{0}, 16);
        if (!adp) return adp.error();
        x.adp = *adp;
        auto ado = child_number<std::uint16_t>(cmd, "Ado", std::uint16_t{0});
        if (!ado) return ado.error();
        x.ado = *ado;
        auto length = child_number<std::uint32_t>(cmd, "DataLength", 0u);
        if (!length) return length.error();
        x.data_length = *length;
        auto cnt = optional_number<std::uint16_t>(cmd, "Cnt");
        if (!cnt) return cnt.error();
        x.cnt = *cnt;
        cmds.push_back(std::move(x));
      }
      c.frames.push_back(std::move(cmds));
    }
    return c;
  }

  std::string_view xml_;
  std::string_view source_;
  std::vector<std::size_t> newlines_;
};

}  // namespace

bool looks_like_eni(std::string_view text) noexcept {
  if (text.starts_with("\xEF\xBB\xBF")) text.remove_prefix(3);
  for (;;) {
    const auto start = text.find_first_not_of(" \t\r\n");
    if (start == std::string_view::npos) return false;
    text.remove_prefix(start);
    if (text.starts_with("<?")) {
      const auto end = text.find("?>");
      if (end == std::string_view::npos) return false;
      text.remove_prefix(end + 2);
    } else if (text.starts_with("<!--")) {
      const auto end = text.find("-->");
      if (end == std::string_view::npos) return false;
      text.remove_prefix(end + 3);
    } else if (text.starts_with("<!")) {  // DOCTYPE
      const auto end = text.find('>');
      if (end == std::string_view::npos) return false;
      text.remove_prefix(end + 1);
    } else {
      constexpr std::string_view kRoot = "<EtherCATConfig";
      if (!text.starts_with(kRoot)) return false;
      if (text.size() == kRoot.size()) return false;
      const char next = text[kRoot.size()];
      return next == '>' || next == '/' || next == ' ' || next == '\t' || next == '\r' ||
             next == '\n';
    }
  }
}

Result<EniFile> parse_eni(std::string_view xml, std::string_view source) {
  return Reader(xml, source).read();
}

Result<EniFile> load_eni(const std::string& path) {
  auto text = read_file(path, FileKind::ring);
  if (!text) return std::move(text).error();
  return parse_eni(*text, path);
}

}  // namespace ecat::config
