#include <type_traits>

#include <fmt/format.h>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/sdo_info.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {
namespace {

constexpr std::uint8_t kIncomplete = 0x80;
// A reassembled response larger than this is treated as hostile rather than allocated.
constexpr std::size_t kMaxReassembledSize = std::size_t{1} << 24;

std::size_t value_size(std::uint16_t bit_length) {
  return (std::size_t{bit_length} + 7) / 8;
}

Result<SdoInfoMessage> decode_entry_description(Bytes data) {
  detail::FieldReader r(data, "SDO info entry description response");
  EntryDescriptionResponse m;
  m.index = r.u16("index");
  m.subindex = r.u8("subindex");
  m.value_info = r.u8("value info");
  m.data_type = r.u16("data type");
  m.bit_length = r.u16("bit length");
  m.object_access = r.u16("object access");
  if (m.value_info & kValueInfoUnitType) m.unit_type = r.u32("unit type");
  const std::size_t size = value_size(m.bit_length);
  auto read_value = [&](std::uint8_t flag, std::string_view field, std::vector<std::uint8_t>& out) {
    if (!(m.value_info & flag)) return;
    Bytes v = r.bytes(field, size);
    out.assign(v.begin(), v.end());
  };
  read_value(kValueInfoDefaultValue, "default value", m.default_value);
  read_value(kValueInfoMinimumValue, "minimum value", m.minimum_value);
  read_value(kValueInfoMaximumValue, "maximum value", m.maximum_value);
  m.description = detail::text_field(r.rest());
  if (!r.ok()) return r.error();
  return SdoInfoMessage{std::move(m)};
}

Result<void> check_entry_value(const EntryDescriptionResponse& m, std::uint8_t flag,
                               std::string_view field, const std::vector<std::uint8_t>& value) {
  const std::size_t expected = (m.value_info & flag) ? value_size(m.bit_length) : 0;
  if (value.size() != expected) {
    return detail::invalid_argument(
        "SDO info entry description response",
        fmt::format("{} is {} bytes, value info 0x{:02x} and bit length {} need {}", field,
                    value.size(), m.value_info, m.bit_length, expected));
  }
  return ok();
}

Result<std::vector<std::uint8_t>> encode_entry_description(const EntryDescriptionResponse& m) {
  constexpr std::string_view what = "SDO info entry description response";
  if (!(m.value_info & kValueInfoUnitType) && m.unit_type != 0) {
    return detail::invalid_argument(what, "unit_type is set but value info lacks the unit flag");
  }
  for (auto check :
       {check_entry_value(m, kValueInfoDefaultValue, "default value", m.default_value),
        check_entry_value(m, kValueInfoMinimumValue, "minimum value", m.minimum_value),
        check_entry_value(m, kValueInfoMaximumValue, "maximum value", m.maximum_value)}) {
    if (!check) return std::move(check).error();
  }
  if (detail::holds_nul(m.description)) {
    return detail::invalid_argument(what, "description holds a NUL character");
  }
  std::vector<std::uint8_t> out;
  detail::append_u16(out, m.index);
  out.push_back(m.subindex);
  out.push_back(m.value_info);
  detail::append_u16(out, m.data_type);
  detail::append_u16(out, m.bit_length);
  detail::append_u16(out, m.object_access);
  if (m.value_info & kValueInfoUnitType) detail::append_u32(out, m.unit_type);
  detail::append(out, m.default_value);
  detail::append(out, m.minimum_value);
  detail::append(out, m.maximum_value);
  detail::append(out, detail::as_bytes(m.description));
  return out;
}

void append_info_header(std::vector<std::uint8_t>& out, SdoInfoOpcode opcode, bool incomplete,
                        std::uint16_t fragments_left) {
  detail::append_u16(
      out, static_cast<std::uint16_t>(static_cast<unsigned>(CoeService::sdo_information) << 12));
  out.push_back(static_cast<std::uint8_t>(static_cast<std::uint8_t>(opcode) |
                                          (incomplete ? kIncomplete : 0)));
  out.push_back(0);
  detail::append_u16(out, fragments_left);
}

}  // namespace

std::string_view to_string(SdoInfoOpcode opcode) noexcept {
  switch (opcode) {
    case SdoInfoOpcode::get_od_list_request:
      return "get OD list request";
    case SdoInfoOpcode::get_od_list_response:
      return "get OD list response";
    case SdoInfoOpcode::get_object_description_request:
      return "get object description request";
    case SdoInfoOpcode::get_object_description_response:
      return "get object description response";
    case SdoInfoOpcode::get_entry_description_request:
      return "get entry description request";
    case SdoInfoOpcode::get_entry_description_response:
      return "get entry description response";
    case SdoInfoOpcode::error_request:
      return "SDO info error";
  }
  return "reserved";
}

std::string_view to_string(OdListType type) noexcept {
  switch (type) {
    case OdListType::number_of_objects:
      return "number of objects";
    case OdListType::all:
      return "all";
    case OdListType::rx_pdo_mappable:
      return "RxPDO mappable";
    case OdListType::tx_pdo_mappable:
      return "TxPDO mappable";
    case OdListType::backup:
      return "backup";
    case OdListType::settings:
      return "settings";
  }
  return "reserved";
}

std::string_view to_string(ObjectCode code) noexcept {
  switch (code) {
    case ObjectCode::null:
      return "NULL";
    case ObjectCode::domain:
      return "DOMAIN";
    case ObjectCode::deftype:
      return "DEFTYPE";
    case ObjectCode::defstruct:
      return "DEFSTRUCT";
    case ObjectCode::var:
      return "VAR";
    case ObjectCode::array:
      return "ARRAY";
    case ObjectCode::record:
      return "RECORD";
  }
  return "reserved";
}

Result<SdoInfoFragment> decode_sdo_info_fragment(Bytes coe) {
  constexpr std::string_view what = "SDO information";
  detail::FieldReader r(coe, what);
  const std::uint16_t coe_header = r.u16("CoE header");
  const std::uint8_t opcode = r.u8("opcode");
  (void)r.u8("reserved");
  SdoInfoFragment f;
  f.header.fragments_left = r.u16("fragments left");
  f.data = r.rest();
  if (!r.ok()) return r.error();
  const auto service = coe_header >> 12;
  if (service != static_cast<unsigned>(CoeService::sdo_information)) {
    return detail::malformed(
        what, fmt::format("CoE service {} at offset 0 is not SDO information (8)", service));
  }
  f.header.opcode = static_cast<SdoInfoOpcode>(opcode & 0x7F);
  f.header.incomplete = (opcode & kIncomplete) != 0;
  return f;
}

SdoInfoOpcode opcode_of(const SdoInfoMessage& message) noexcept {
  static constexpr SdoInfoOpcode kOpcodes[] = {
      SdoInfoOpcode::get_od_list_request,
      SdoInfoOpcode::get_od_list_response,
      SdoInfoOpcode::get_object_description_request,
      SdoInfoOpcode::get_object_description_response,
      SdoInfoOpcode::get_entry_description_request,
      SdoInfoOpcode::get_entry_description_response,
      SdoInfoOpcode::error_request,
  };
  static_assert(std::size(kOpcodes) == std::variant_size_v<SdoInfoMessage>);
  return kOpcodes[message.index()];
}

Result<SdoInfoMessage> decode_sdo_info(SdoInfoOpcode opcode, Bytes data) {
  switch (opcode) {
    case SdoInfoOpcode::get_od_list_request: {
      detail::FieldReader r(data, "SDO info get OD list request");
      OdListRequest m{static_cast<OdListType>(r.u16("list type"))};
      if (!r.ok()) return r.error();
      return SdoInfoMessage{m};
    }
    case SdoInfoOpcode::get_od_list_response: {
      detail::FieldReader r(data, "SDO info get OD list response");
      OdListResponse m;
      m.list_type = static_cast<OdListType>(r.u16("list type"));
      Bytes list = r.rest();
      if (!r.ok()) return r.error();
      if (list.size() % 2 != 0) {
        return detail::malformed(
            "SDO info get OD list response",
            fmt::format("index list from offset 2 has odd length {}", list.size()));
      }
      m.indices.reserve(list.size() / 2);
      for (std::size_t i = 0; i < list.size(); i += 2)
        m.indices.push_back(load_le16(&list[i]));
      return SdoInfoMessage{std::move(m)};
    }
    case SdoInfoOpcode::get_object_description_request: {
      detail::FieldReader r(data, "SDO info get object description request");
      ObjectDescriptionRequest m{r.u16("index")};
      if (!r.ok()) return r.error();
      return SdoInfoMessage{m};
    }
    case SdoInfoOpcode::get_object_description_response: {
      detail::FieldReader r(data, "SDO info object description response");
      ObjectDescriptionResponse m;
      m.index = r.u16("index");
      m.data_type = r.u16("data type");
      m.max_subindex = r.u8("max subindex");
      m.object_code = static_cast<ObjectCode>(r.u8("object code"));
      m.name = detail::text_field(r.rest());
      if (!r.ok()) return r.error();
      return SdoInfoMessage{std::move(m)};
    }
    case SdoInfoOpcode::get_entry_description_request: {
      detail::FieldReader r(data, "SDO info get entry description request");
      EntryDescriptionRequest m;
      m.index = r.u16("index");
      m.subindex = r.u8("subindex");
      m.value_info = r.u8("value info");
      if (!r.ok()) return r.error();
      return SdoInfoMessage{m};
    }
    case SdoInfoOpcode::get_entry_description_response:
      return decode_entry_description(data);
    case SdoInfoOpcode::error_request: {
      detail::FieldReader r(data, "SDO info error");
      SdoInfoError m{r.u32("abort code")};
      if (!r.ok()) return r.error();
      return SdoInfoMessage{m};
    }
  }
  return detail::malformed("SDO information",
                           fmt::format("opcode {} is not an SDO information opcode (1..7)",
                                       static_cast<unsigned>(opcode)));
}

Result<SdoInfoMessage> decode_sdo_info(Bytes coe) {
  auto fragment = decode_sdo_info_fragment(coe);
  if (!fragment) return std::move(fragment).error();
  if (fragment->header.incomplete || fragment->header.fragments_left != 0) {
    return Error(Errc::unsupported,
                 fmt::format("SDO information: {} is a fragment ({} more to come); reassemble it "
                             "first",
                             to_string(fragment->header.opcode), fragment->header.fragments_left));
  }
  return decode_sdo_info(fragment->header.opcode, fragment->data);
}

Result<std::vector<std::uint8_t>> encode_sdo_info_data(const SdoInfoMessage& message) {
  return std::visit(
      [](const auto& m) -> Result<std::vector<std::uint8_t>> {
        using T = std::decay_t<decltype(m)>;
        std::vector<std::uint8_t> out;
        if constexpr (std::is_same_v<T, OdListRequest>) {
          detail::append_u16(out, static_cast<std::uint16_t>(m.list_type));
        } else if constexpr (std::is_same_v<T, OdListResponse>) {
          detail::append_u16(out, static_cast<std::uint16_t>(m.list_type));
          for (auto index : m.indices)
            detail::append_u16(out, index);
        } else if constexpr (std::is_same_v<T, ObjectDescriptionRequest>) {
          detail::append_u16(out, m.index);
        } else if constexpr (std::is_same_v<T, ObjectDescriptionResponse>) {
          if (detail::holds_nul(m.name)) {
            return detail::invalid_argument("SDO info object description response",
                                            "name holds a NUL character");
          }
          detail::append_u16(out, m.index);
          detail::append_u16(out, m.data_type);
          out.push_back(m.max_subindex);
          out.push_back(static_cast<std::uint8_t>(m.object_code));
          detail::append(out, detail::as_bytes(m.name));
        } else if constexpr (std::is_same_v<T, EntryDescriptionRequest>) {
          detail::append_u16(out, m.index);
          out.push_back(m.subindex);
          out.push_back(m.value_info);
        } else if constexpr (std::is_same_v<T, EntryDescriptionResponse>) {
          return encode_entry_description(m);
        } else {
          static_assert(std::is_same_v<T, SdoInfoError>);
          detail::append_u32(out, m.abort_code);
        }
        return out;
      },
      message);
}

Result<std::vector<std::uint8_t>> encode_sdo_info(const SdoInfoMessage& message) {
  auto fragments = encode_sdo_info_fragments(message, detail::kMaxMailboxData);
  if (!fragments) return std::move(fragments).error();
  if (fragments->size() != 1) {
    return detail::invalid_argument(
        "SDO information", "message exceeds one mailbox (65535 bytes); send it in fragments");
  }
  return std::move(fragments->front());
}

Result<std::vector<std::vector<std::uint8_t>>> encode_sdo_info_fragments(
    const SdoInfoMessage& message, std::size_t max_mailbox_data) {
  constexpr std::size_t kOverhead = kCoeHeaderSize + kSdoInfoHeaderSize;
  auto data = encode_sdo_info_data(message);
  if (!data) return std::move(data).error();
  max_mailbox_data = std::min(max_mailbox_data, detail::kMaxMailboxData);
  if (max_mailbox_data < kOverhead + 2) {
    return detail::invalid_argument(
        "SDO information",
        fmt::format("{} bytes of mailbox data cannot hold a fragment (need at least {})",
                    max_mailbox_data, kOverhead + 2));
  }
  const std::size_t capacity = (max_mailbox_data - kOverhead) & ~std::size_t{1};
  const std::size_t count = data->empty() ? 1 : (data->size() + capacity - 1) / capacity;
  if (count - 1 > 0xFFFF) {
    return detail::invalid_argument(
        "SDO information",
        fmt::format("{} fragments exceed the 16-bit fragments-left field", count));
  }
  const SdoInfoOpcode opcode = opcode_of(message);
  std::vector<std::vector<std::uint8_t>> fragments;
  fragments.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t begin = i * capacity;
    const std::size_t end = std::min(begin + capacity, data->size());
    std::vector<std::uint8_t> out;
    out.reserve(kOverhead + end - begin);
    append_info_header(out, opcode, i + 1 < count, static_cast<std::uint16_t>(count - 1 - i));
    out.insert(out.end(), data->begin() + static_cast<std::ptrdiff_t>(begin),
               data->begin() + static_cast<std::ptrdiff_t>(end));
    fragments.push_back(std::move(out));
  }
  return fragments;
}

Result<SdoInfoReassembler::Status> SdoInfoReassembler::add(Bytes coe) {
  constexpr std::string_view what = "SDO information reassembly";
  auto fragment = decode_sdo_info_fragment(coe);
  if (!fragment) {
    reset();
    return std::move(fragment).error();
  }
  const SdoInfoHeader& h = fragment->header;
  if (!started_ || complete_) {
    reset();
    started_ = true;
    opcode_ = h.opcode;
  } else if (h.opcode != opcode_) {
    const auto expected = opcode_;
    reset();
    return detail::malformed(what,
                             fmt::format("fragment has opcode {} ({}), expected {} ({})",
                                         static_cast<unsigned>(h.opcode), to_string(h.opcode),
                                         static_cast<unsigned>(expected), to_string(expected)));
  } else if (h.fragments_left + 1 != fragments_left_) {
    const auto expected = fragments_left_ - 1;
    reset();
    return detail::malformed(what, fmt::format("fragment says {} fragments left, expected {}",
                                               h.fragments_left, expected));
  }
  if (data_.size() + fragment->data.size() > kMaxReassembledSize) {
    reset();
    return Error(Errc::out_of_range,
                 fmt::format("{}: message exceeds {} bytes", what, kMaxReassembledSize));
  }
  detail::append(data_, fragment->data);
  fragments_left_ = h.fragments_left;
  if (!h.incomplete) {
    complete_ = true;
    return Status::complete;
  }
  if (h.fragments_left == 0) {
    reset();
    return detail::malformed(what, "fragment is marked incomplete but 0 fragments are left");
  }
  return Status::need_more;
}

Result<SdoInfoMessage> SdoInfoReassembler::message() const {
  if (!complete_) {
    return Error(Errc::wrong_state, "SDO information reassembly: the message is not complete");
  }
  return decode_sdo_info(opcode_, data_);
}

void SdoInfoReassembler::reset() noexcept {
  started_ = false;
  complete_ = false;
  fragments_left_ = 0;
  data_.clear();
}

}  // namespace ecat::wire
