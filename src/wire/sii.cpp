#include <algorithm>
#include <numeric>

#include <fmt/format.h>

#include <ecat/wire/sii.hpp>

namespace ecat::wire {

std::uint8_t sii_crc8(Bytes bytes) noexcept {
  std::uint8_t crc = 0xFF;
  for (std::uint8_t byte : bytes) {
    crc = static_cast<std::uint8_t>(crc ^ byte);
    for (int i = 0; i < 8; ++i) {
      crc = static_cast<std::uint8_t>((crc & 0x80) != 0 ? (crc << 1) ^ 0x07 : crc << 1);
    }
  }
  return crc;
}

std::string_view sii_category_name(std::uint16_t type) noexcept {
  switch (type) {
    case sii_category::kNop:
      return "NOP";
    case sii_category::kStrings:
      return "STRINGS";
    case sii_category::kDataTypes:
      return "DATATYPES";
    case sii_category::kGeneral:
      return "GENERAL";
    case sii_category::kFmmu:
      return "FMMU";
    case sii_category::kSyncManager:
      return "SYNCM";
    case sii_category::kFmmuEx:
      return "FMMU_EX";
    case sii_category::kSyncUnit:
      return "SYNCUNIT";
    case sii_category::kTxPdo:
      return "TXPDO";
    case sii_category::kRxPdo:
      return "RXPDO";
    case sii_category::kDc:
      return "DC";
    case sii_category::kEnd:
      return "END";
    default:
      return "vendor/unknown";
  }
}

std::vector<std::string_view> mailbox_protocol_names(std::uint16_t mask) {
  static constexpr std::pair<std::uint16_t, std::string_view> kNames[] = {
      {mailbox_protocol::kAoe, "AoE"}, {mailbox_protocol::kEoe, "EoE"},
      {mailbox_protocol::kCoe, "CoE"}, {mailbox_protocol::kFoe, "FoE"},
      {mailbox_protocol::kSoe, "SoE"}, {mailbox_protocol::kVoe, "VoE"}};
  std::vector<std::string_view> names;
  for (const auto& [bit, name] : kNames) {
    if ((mask & bit) != 0) names.push_back(name);
  }
  return names;
}

std::string_view sii_port_name(std::uint8_t code) noexcept {
  switch (code) {
    case sii_port::kUnused:
      return "unused";
    case sii_port::kMii:
      return "MII";
    case sii_port::kReserved:
      return "reserved";
    case sii_port::kEbus:
      return "EBUS";
    case sii_port::kFastHotConnect:
      return "fast hot connect";
    default:
      return "unknown";
  }
}

std::string_view sii_fmmu_usage_name(std::uint8_t usage) noexcept {
  switch (usage) {
    case sii_fmmu_usage::kUnused:
    case sii_fmmu_usage::kNone:
      return "unused";
    case sii_fmmu_usage::kOutputs:
      return "outputs";
    case sii_fmmu_usage::kInputs:
      return "inputs";
    case sii_fmmu_usage::kMailboxState:
      return "mailbox_state";
    default:
      return "unknown";
  }
}

std::string_view sii_sync_manager_type_name(std::uint8_t type) noexcept {
  switch (type) {
    case sii_sm_type::kUnused:
      return "unused";
    case sii_sm_type::kMailboxOut:
      return "mailbox_out";
    case sii_sm_type::kMailboxIn:
      return "mailbox_in";
    case sii_sm_type::kOutputs:
      return "outputs";
    case sii_sm_type::kInputs:
      return "inputs";
    default:
      return "unknown";
  }
}

std::uint32_t SiiPdo::bit_length() const noexcept {
  std::uint32_t bits = 0;
  for (const auto& e : entries)
    bits += e.bit_length;
  return bits;
}

std::string_view SiiImage::string(std::uint8_t index) const noexcept {
  if (index == 0 || index > strings.size()) return {};
  return strings[index - 1];
}

std::string_view SiiImage::device_name() const noexcept {
  if (general && !string(general->name_index).empty()) return string(general->name_index);
  return string(1);
}

std::string sii_string_to_utf8(std::string_view latin1) {
  std::string out;
  out.reserve(latin1.size());
  for (char ch : latin1) {
    const auto c = static_cast<unsigned char>(ch);
    if (c < 0x80) {
      out.push_back(static_cast<char>(c));
    } else {
      out.push_back(static_cast<char>(0xC0 | (c >> 6)));
      out.push_back(static_cast<char>(0x80 | (c & 0x3F)));
    }
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Decoding

namespace {

class Decoder {
 public:
  explicit Decoder(Bytes image) : image_(image) {}

  Result<SiiDecoded> run();

 private:
  std::uint16_t word(std::size_t address) const noexcept { return load_le16(&image_[2 * address]); }
  std::uint32_t dword(std::size_t address) const noexcept {
    return load_le32(&image_[2 * address]);
  }
  SiiMailbox mailbox(std::size_t address) const noexcept {
    return SiiMailbox{word(address), word(address + 1), word(address + 2), word(address + 3)};
  }

  template <class... Args>
  void warn(fmt::format_string<Args...> format, Args&&... args) {
    out_.warnings.push_back(fmt::format(format, std::forward<Args>(args)...));
  }
  // "TXPDO at word 0x00ed": how every category warning starts.
  static std::string where(std::uint16_t type, std::size_t word_address) {
    return fmt::format("category {} (type {}) at word 0x{:04x}", sii_category_name(type), type,
                       word_address);
  }

  void decode_header();
  void walk_categories();
  void decode_category(std::uint16_t type, std::size_t word_address, Bytes data);
  void decode_strings(const std::string& at, Bytes data);
  void decode_general(const std::string& at, Bytes data);
  void decode_sync_managers(const std::string& at, Bytes data);
  void decode_pdos(const std::string& at, Bytes data, std::vector<SiiPdo>& pdos);
  void decode_dc(const std::string& at, Bytes data);
  void check_string_references();

  Bytes image_;
  std::size_t words_ = 0;
  SiiDecoded out_;
};

Result<SiiDecoded> Decoder::run() {
  if (image_.size() < kSiiHeaderBytes) {
    return Error(Errc::truncated,
                 fmt::format("SII image is {} bytes; the fixed header alone (words 0x00..0x3f) "
                             "needs {}",
                             image_.size(), kSiiHeaderBytes));
  }
  const bool all_ff = std::all_of(image_.begin(), image_.end(), [](auto b) { return b == 0xFF; });
  const bool all_00 = std::all_of(image_.begin(), image_.end(), [](auto b) { return b == 0x00; });
  if (all_ff || all_00) {
    return Error(Errc::malformed,
                 fmt::format("SII image is blank (all {} bytes are 0x{}): the EEPROM holds no "
                             "content",
                             image_.size(), all_ff ? "ff" : "00"));
  }
  if (image_.size() % 2 != 0) {
    warn("SII image has an odd length ({} bytes); the last byte is not part of any word",
         image_.size());
  }
  words_ = image_.size() / 2;
  decode_header();
  walk_categories();
  check_string_references();
  return std::move(out_);
}

void Decoder::decode_header() {
  SiiImage& img = out_.image;
  img.pdi_control = word(sii_word::kPdiControl);
  img.pdi_configuration = word(sii_word::kPdiConfiguration);
  img.sync_impulse_length = word(sii_word::kSyncImpulseLength);
  img.pdi_configuration2 = word(sii_word::kPdiConfiguration2);
  img.station_alias = word(sii_word::kStationAlias);
  img.identity.vendor_id = dword(sii_word::kVendorId);
  img.identity.product_code = dword(sii_word::kProductCode);
  img.identity.revision = dword(sii_word::kRevision);
  img.identity.serial = dword(sii_word::kSerialNumber);
  img.execution_delay = word(sii_word::kExecutionDelay);
  img.port0_delay = word(sii_word::kPort0Delay);
  img.port1_delay = word(sii_word::kPort1Delay);
  img.bootstrap_mailbox = mailbox(sii_word::kBootstrapMailbox);
  img.standard_mailbox = mailbox(sii_word::kStandardMailbox);
  img.mailbox_protocols = word(sii_word::kMailboxProtocols);
  img.eeprom_size = word(sii_word::kEepromSize);
  img.version = word(sii_word::kVersion);
  for (std::size_t w = 0; w < kSiiHeaderWords; ++w) {
    if (sii_header_word_reserved(w)) img.reserved_words[w] = word(w);
  }

  out_.checksum_word = word(sii_word::kChecksum);
  out_.checksum_computed = sii_crc8(image_.first(kSiiChecksummedBytes));
  out_.checksum_ok = (out_.checksum_word & 0xFF) == out_.checksum_computed;
  if (!out_.checksum_ok) {
    warn(
        "header checksum mismatch: word 0x0007 holds 0x{:02x} in its low byte, the CRC-8 of "
        "bytes 0..13 is 0x{:02x}",
        out_.checksum_word & 0xFF, out_.checksum_computed);
  }
}

void Decoder::walk_categories() {
  std::size_t address = sii_word::kFirstCategory;
  std::size_t nops = 0;
  // Every step advances by at least the two header words, so the walk ends within the image.
  while (true) {
    if (address >= words_) {
      warn("category list runs to the end of the image (word 0x{:04x}) without an END marker",
           address);
      break;
    }
    const std::uint16_t type = word(address);
    if (type == sii_category::kEnd) {
      out_.categories.push_back(SiiCategoryInfo{type, address, 0, false});
      break;
    }
    if (address + 1 >= words_) {
      warn("{}: the image ends before the category's size word", where(type, address));
      out_.categories.push_back(SiiCategoryInfo{type, address, 0, true});
      break;
    }
    const std::size_t size = word(address + 1);
    const std::size_t data_start = address + 2;
    const std::size_t available = words_ - data_start;
    const bool truncated = size > available;
    const std::size_t taken = truncated ? available : size;
    if (type == sii_category::kNop) {
      ++nops;
    } else {
      out_.categories.push_back(SiiCategoryInfo{type, address, size, truncated});
      if (truncated) {
        warn("{}: declares {} words but the image ends after {}; decoded partially",
             where(type, address), size, available);
      }
      decode_category(type, address, image_.subspan(2 * data_start, 2 * taken));
    }
    if (truncated) break;
    address = data_start + size;
  }
  if (nops > 0) warn("{} NOP categories skipped", nops);
  // The encoder writes categories by ascending type; ordering here too keeps a decode of a
  // re-encoded image equal to the first decode.
  std::stable_sort(out_.image.other_categories.begin(), out_.image.other_categories.end(),
                   [](const auto& a, const auto& b) { return a.type < b.type; });
}

void Decoder::decode_category(std::uint16_t type, std::size_t word_address, Bytes data) {
  SiiImage& img = out_.image;
  const std::string at = where(type, word_address);
  const auto append_raw = [&](std::optional<std::vector<std::uint8_t>>& field) {
    if (!field) {
      field.emplace();
    } else {
      warn("{}: another category of this type came before; contents appended", at);
    }
    field->insert(field->end(), data.begin(), data.end());
  };
  switch (type) {
    case sii_category::kStrings:
      decode_strings(at, data);
      break;
    case sii_category::kDataTypes:
      append_raw(img.data_types);
      break;
    case sii_category::kGeneral:
      decode_general(at, data);
      break;
    case sii_category::kFmmu:
      img.fmmus.insert(img.fmmus.end(), data.begin(), data.end());
      break;
    case sii_category::kSyncManager:
      decode_sync_managers(at, data);
      break;
    case sii_category::kFmmuEx:
      append_raw(img.fmmu_ex);
      break;
    case sii_category::kSyncUnit:
      append_raw(img.sync_unit);
      break;
    case sii_category::kTxPdo:
      decode_pdos(at, data, img.txpdos);
      break;
    case sii_category::kRxPdo:
      decode_pdos(at, data, img.rxpdos);
      break;
    case sii_category::kDc:
      decode_dc(at, data);
      break;
    default:
      img.other_categories.push_back(SiiRawCategory{type, {data.begin(), data.end()}});
      break;
  }
}

void Decoder::decode_strings(const std::string& at, Bytes data) {
  if (!out_.image.strings.empty()) {
    warn("{}: a STRINGS category came before; these strings continue its numbering", at);
  }
  if (data.empty()) {
    warn("{}: empty, not even a string count", at);
    return;
  }
  ByteReader r(data);
  const std::size_t count = r.u8();
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t length = r.u8();
    Bytes text = r.bytes(length);
    if (!r.ok()) {
      warn(
          "{}: declares {} strings but string {} (byte offset {}) runs past the category; "
          "{} strings decoded",
          at, count, i + 1, data.size() - r.remaining(), i);
      return;
    }
    out_.image.strings.emplace_back(reinterpret_cast<const char*>(text.data()), text.size());
  }
}

void Decoder::decode_general(const std::string& at, Bytes data) {
  if (out_.image.general) {
    warn("{}: a GENERAL category came before; this one is ignored", at);
    return;
  }
  if (data.size() != SiiGeneral::kSize) {
    warn("{}: {} bytes, expected {}; {}", at, data.size(), SiiGeneral::kSize,
         data.size() < SiiGeneral::kSize ? "missing fields read as 0" : "extra bytes ignored");
  }
  std::array<std::uint8_t, SiiGeneral::kSize> b{};
  std::copy_n(data.begin(), std::min(data.size(), b.size()), b.begin());
  SiiGeneral g;
  g.group_index = b[0];
  g.image_index = b[1];
  g.order_index = b[2];
  g.name_index = b[3];
  g.reserved_4 = b[4];
  g.coe_details = b[5];
  g.foe_details = b[6];
  g.eoe_details = b[7];
  g.soe_channels = b[8];
  g.ds402_channels = b[9];
  g.sysman_class = b[10];
  g.flags = b[11];
  g.current_on_ebus_ma = static_cast<std::int16_t>(load_le16(&b[12]));
  g.group_index_2 = b[14];
  g.reserved_15 = b[15];
  g.physical_port = load_le16(&b[16]);
  g.physical_memory_address = load_le16(&b[18]);
  std::copy_n(b.begin() + 20, g.reserved_tail.size(), g.reserved_tail.begin());
  out_.image.general = g;
}

void Decoder::decode_sync_managers(const std::string& at, Bytes data) {
  ByteReader r(data);
  while (r.remaining() >= SiiSyncManager::kSize) {
    SiiSyncManager sm;
    sm.start = r.u16();
    sm.length = r.u16();
    sm.control = r.u8();
    sm.status = r.u8();
    sm.enable = r.u8();
    sm.type = r.u8();
    out_.image.sync_managers.push_back(sm);
  }
  if (r.remaining() != 0) {
    warn("{}: {} trailing bytes do not make a whole 8-byte SyncManager entry; ignored", at,
         r.remaining());
  }
}

void Decoder::decode_pdos(const std::string& at, Bytes data, std::vector<SiiPdo>& pdos) {
  ByteReader r(data);
  while (r.remaining() > 0) {
    const std::size_t offset = data.size() - r.remaining();
    if (r.remaining() < SiiPdo::kHeaderSize) {
      warn("{}: {} trailing bytes at byte offset {} do not make a whole PDO header; ignored", at,
           r.remaining(), offset);
      return;
    }
    SiiPdo pdo;
    pdo.index = r.u16();
    const std::size_t count = r.u8();
    pdo.sync_manager = r.u8();
    pdo.dc_sync = r.u8();
    pdo.name_index = r.u8();
    pdo.flags = r.u16();
    for (std::size_t i = 0; i < count; ++i) {
      if (r.remaining() < SiiPdoEntry::kSize) {
        warn(
            "{}: PDO 0x{:04x} (byte offset {}) declares {} entries but the category ends "
            "after {}; decoded partially",
            at, pdo.index, offset, count, i);
        pdos.push_back(std::move(pdo));
        return;
      }
      SiiPdoEntry e;
      e.index = r.u16();
      e.subindex = r.u8();
      e.name_index = r.u8();
      e.data_type = r.u8();
      e.bit_length = r.u8();
      e.flags = r.u16();
      pdo.entries.push_back(e);
    }
    pdos.push_back(std::move(pdo));
  }
}

void Decoder::decode_dc(const std::string& at, Bytes data) {
  ByteReader r(data);
  while (r.remaining() >= SiiDcSync::kSize) {
    SiiDcSync d;
    d.cycle_time_0 = r.u32();
    d.shift_time_0 = r.u32();
    d.shift_time_1 = r.u32();
    d.sync1_cycle_factor = r.i16();
    d.assign_activate = r.u16();
    d.sync0_cycle_factor = r.i16();
    d.name_index = r.u8();
    d.description_index = r.u8();
    d.reserved = r.u32();
    out_.image.dc.push_back(d);
  }
  if (r.remaining() != 0) {
    warn("{}: {} trailing bytes do not make a whole 24-byte DC entry; ignored", at, r.remaining());
  }
}

void Decoder::check_string_references() {
  const SiiImage& img = out_.image;
  const std::size_t count = img.strings.size();
  const auto check = [&](std::uint8_t index, const std::string& what) {
    if (index != 0 && index > count) {
      warn("{} refers to string {}, but the image has {} strings", what, index, count);
    }
  };
  if (img.general) {
    check(img.general->group_index, "GENERAL group");
    check(img.general->image_index, "GENERAL image");
    check(img.general->order_index, "GENERAL order");
    check(img.general->name_index, "GENERAL name");
  }
  const auto check_pdos = [&](const std::vector<SiiPdo>& pdos, const char* kind) {
    for (const auto& pdo : pdos) {
      check(pdo.name_index, fmt::format("{} 0x{:04x} name", kind, pdo.index));
      for (const auto& e : pdo.entries) {
        check(e.name_index, fmt::format("{} 0x{:04x} entry 0x{:04x}:{:02x} name", kind, pdo.index,
                                        e.index, e.subindex));
      }
    }
  };
  check_pdos(img.txpdos, "TxPDO");
  check_pdos(img.rxpdos, "RxPDO");
  for (std::size_t i = 0; i < img.dc.size(); ++i) {
    check(img.dc[i].name_index, fmt::format("DC entry {} name", i));
    check(img.dc[i].description_index, fmt::format("DC entry {} description", i));
  }
}

// ---------------------------------------------------------------------------------------------
// Encoding

struct PendingCategory {
  std::uint16_t type;
  std::vector<std::uint8_t> data;
};

class CategoryBuilder {
 public:
  void u8(std::uint8_t v) { data_.push_back(v); }
  void u16(std::uint16_t v) {
    data_.push_back(static_cast<std::uint8_t>(v));
    data_.push_back(static_cast<std::uint8_t>(v >> 8));
  }
  void u32(std::uint32_t v) {
    u16(static_cast<std::uint16_t>(v));
    u16(static_cast<std::uint16_t>(v >> 16));
  }
  void bytes(const std::vector<std::uint8_t>& v) { data_.insert(data_.end(), v.begin(), v.end()); }
  std::vector<std::uint8_t> take() { return std::move(data_); }

 private:
  std::vector<std::uint8_t> data_;
};

Error unrepresentable(std::string message) {
  return Error(Errc::out_of_range, std::move(message));
}

Result<std::vector<std::uint8_t>> encode_strings(const std::vector<std::string>& strings) {
  if (strings.size() > 255) {
    return unrepresentable(
        fmt::format("SII STRINGS holds at most 255 strings, the image has {}", strings.size()));
  }
  CategoryBuilder b;
  b.u8(static_cast<std::uint8_t>(strings.size()));
  for (std::size_t i = 0; i < strings.size(); ++i) {
    if (strings[i].size() > 255) {
      return unrepresentable(
          fmt::format("SII string {} is {} bytes, at most 255 fit", i + 1, strings[i].size()));
    }
    b.u8(static_cast<std::uint8_t>(strings[i].size()));
    for (char c : strings[i])
      b.u8(static_cast<std::uint8_t>(c));
  }
  return b.take();
}

std::vector<std::uint8_t> encode_general(const SiiGeneral& g) {
  CategoryBuilder b;
  for (std::uint8_t v :
       {g.group_index, g.image_index, g.order_index, g.name_index, g.reserved_4, g.coe_details,
        g.foe_details, g.eoe_details, g.soe_channels, g.ds402_channels, g.sysman_class, g.flags}) {
    b.u8(v);
  }
  b.u16(static_cast<std::uint16_t>(g.current_on_ebus_ma));
  b.u8(g.group_index_2);
  b.u8(g.reserved_15);
  b.u16(g.physical_port);
  b.u16(g.physical_memory_address);
  for (std::uint8_t v : g.reserved_tail)
    b.u8(v);
  return b.take();
}

Result<std::vector<std::uint8_t>> encode_pdos(const std::vector<SiiPdo>& pdos, const char* kind) {
  CategoryBuilder b;
  for (const auto& pdo : pdos) {
    if (pdo.entries.size() > 255) {
      return unrepresentable(fmt::format("{} 0x{:04x} has {} entries, at most 255 fit", kind,
                                         pdo.index, pdo.entries.size()));
    }
    b.u16(pdo.index);
    b.u8(static_cast<std::uint8_t>(pdo.entries.size()));
    b.u8(pdo.sync_manager);
    b.u8(pdo.dc_sync);
    b.u8(pdo.name_index);
    b.u16(pdo.flags);
    for (const auto& e : pdo.entries) {
      b.u16(e.index);
      b.u8(e.subindex);
      b.u8(e.name_index);
      b.u8(e.data_type);
      b.u8(e.bit_length);
      b.u16(e.flags);
    }
  }
  return b.take();
}

bool has_own_field(std::uint16_t type) noexcept {
  switch (type) {
    case sii_category::kStrings:
    case sii_category::kDataTypes:
    case sii_category::kGeneral:
    case sii_category::kFmmu:
    case sii_category::kSyncManager:
    case sii_category::kFmmuEx:
    case sii_category::kSyncUnit:
    case sii_category::kTxPdo:
    case sii_category::kRxPdo:
    case sii_category::kDc:
      return true;
    default:
      return false;
  }
}

}  // namespace

Result<SiiDecoded> decode_sii(Bytes image) {
  return Decoder(image).run();
}

Result<std::vector<std::uint8_t>> encode_sii(const SiiImage& image, SiiEncodeOptions options) {
  std::vector<PendingCategory> categories;

  if (!image.strings.empty()) {
    auto data = encode_strings(image.strings);
    if (!data) return std::move(data).error();
    categories.push_back({sii_category::kStrings, std::move(*data)});
  }
  if (image.data_types) categories.push_back({sii_category::kDataTypes, *image.data_types});
  if (image.general) categories.push_back({sii_category::kGeneral, encode_general(*image.general)});
  if (!image.fmmus.empty()) {
    auto data = image.fmmus;
    if (data.size() % 2 != 0) data.push_back(sii_fmmu_usage::kNone);
    categories.push_back({sii_category::kFmmu, std::move(data)});
  }
  if (!image.sync_managers.empty()) {
    CategoryBuilder b;
    for (const auto& sm : image.sync_managers) {
      b.u16(sm.start);
      b.u16(sm.length);
      b.u8(sm.control);
      b.u8(sm.status);
      b.u8(sm.enable);
      b.u8(sm.type);
    }
    categories.push_back({sii_category::kSyncManager, b.take()});
  }
  if (image.fmmu_ex) categories.push_back({sii_category::kFmmuEx, *image.fmmu_ex});
  if (image.sync_unit) categories.push_back({sii_category::kSyncUnit, *image.sync_unit});
  if (!image.txpdos.empty()) {
    auto data = encode_pdos(image.txpdos, "TxPDO");
    if (!data) return std::move(data).error();
    categories.push_back({sii_category::kTxPdo, std::move(*data)});
  }
  if (!image.rxpdos.empty()) {
    auto data = encode_pdos(image.rxpdos, "RxPDO");
    if (!data) return std::move(data).error();
    categories.push_back({sii_category::kRxPdo, std::move(*data)});
  }
  if (!image.dc.empty()) {
    CategoryBuilder b;
    for (const auto& d : image.dc) {
      b.u32(d.cycle_time_0);
      b.u32(d.shift_time_0);
      b.u32(d.shift_time_1);
      b.u16(static_cast<std::uint16_t>(d.sync1_cycle_factor));
      b.u16(d.assign_activate);
      b.u16(static_cast<std::uint16_t>(d.sync0_cycle_factor));
      b.u8(d.name_index);
      b.u8(d.description_index);
      b.u32(d.reserved);
    }
    categories.push_back({sii_category::kDc, b.take()});
  }
  for (std::size_t i = 0; i < image.other_categories.size(); ++i) {
    const auto& raw = image.other_categories[i];
    if (raw.type == sii_category::kNop || raw.type == sii_category::kEnd ||
        has_own_field(raw.type)) {
      return Error(Errc::invalid_argument,
                   fmt::format("other_categories[{}] has type {} ({}), which cannot be written "
                               "as a raw category",
                               i, raw.type, sii_category_name(raw.type)));
    }
    categories.push_back({raw.type, raw.data});
  }
  // Ascending type reproduces the order real images use (vendor types below 10 first).
  std::stable_sort(categories.begin(), categories.end(),
                   [](const auto& a, const auto& b) { return a.type < b.type; });

  std::size_t total_bytes = kSiiHeaderBytes + 2;  // header and END marker
  for (auto& c : categories) {
    if (c.data.size() % 2 != 0) c.data.push_back(0xFF);
    if (c.data.size() / 2 > 0xFFFF) {
      return unrepresentable(fmt::format("SII category {} needs {} words, at most 65535 fit",
                                         sii_category_name(c.type), c.data.size() / 2));
    }
    total_bytes += 4 + c.data.size();
  }
  if (options.pad_to_eeprom_size) total_bytes = std::max(total_bytes, image.eeprom_size_bytes());

  std::vector<std::uint8_t> out(total_bytes, 0xFF);
  const auto put = [&](std::size_t word_address, std::uint16_t value) {
    store_le16(&out[2 * word_address], value);
  };
  for (std::size_t w = 0; w < kSiiHeaderWords; ++w) {
    put(w, sii_header_word_reserved(w) ? image.reserved_words[w] : 0);
  }
  put(sii_word::kPdiControl, image.pdi_control);
  put(sii_word::kPdiConfiguration, image.pdi_configuration);
  put(sii_word::kSyncImpulseLength, image.sync_impulse_length);
  put(sii_word::kPdiConfiguration2, image.pdi_configuration2);
  put(sii_word::kStationAlias, image.station_alias);
  store_le32(&out[2 * sii_word::kVendorId], image.identity.vendor_id);
  store_le32(&out[2 * sii_word::kProductCode], image.identity.product_code);
  store_le32(&out[2 * sii_word::kRevision], image.identity.revision);
  store_le32(&out[2 * sii_word::kSerialNumber], image.identity.serial);
  put(sii_word::kExecutionDelay, image.execution_delay);
  put(sii_word::kPort0Delay, image.port0_delay);
  put(sii_word::kPort1Delay, image.port1_delay);
  for (const auto& [base, mbx] : {std::pair{sii_word::kBootstrapMailbox, image.bootstrap_mailbox},
                                  std::pair{sii_word::kStandardMailbox, image.standard_mailbox}}) {
    put(base, mbx.recv_offset);
    put(base + 1u, mbx.recv_size);
    put(base + 2u, mbx.send_offset);
    put(base + 3u, mbx.send_size);
  }
  put(sii_word::kMailboxProtocols, image.mailbox_protocols);
  put(sii_word::kEepromSize, image.eeprom_size);
  put(sii_word::kVersion, image.version);
  put(sii_word::kChecksum, sii_crc8(Bytes{out.data(), kSiiChecksummedBytes}));

  std::size_t offset = kSiiHeaderBytes;
  for (const auto& c : categories) {
    store_le16(&out[offset], c.type);
    store_le16(&out[offset + 2], static_cast<std::uint16_t>(c.data.size() / 2));
    std::copy(c.data.begin(), c.data.end(), out.begin() + static_cast<std::ptrdiff_t>(offset + 4));
    offset += 4 + c.data.size();
  }
  store_le16(&out[offset], sii_category::kEnd);
  return out;
}

}  // namespace ecat::wire
