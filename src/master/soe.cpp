#include <algorithm>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/soe.hpp>

namespace ecat::master {

namespace {

struct ErrorText {
  std::uint16_t code;
  std::string_view text;
};

// IEC 61800-7-304 / ETG.1000.6 SoE error codes (the texts say what the standard means, in our
// words).
constexpr ErrorText kErrorTexts[] = {
    {0x1001, "IDN not present"},
    {0x1009, "invalid access to element 1"},
    {0x2001, "no name"},
    {0x2002, "name transmission too short"},
    {0x2003, "name transmission too long"},
    {0x2004, "name cannot be changed (read only)"},
    {0x2005, "name is write protected at this time"},
    {0x3002, "attribute transmission too short"},
    {0x3003, "attribute transmission too long"},
    {0x3004, "attribute cannot be changed (read only)"},
    {0x3005, "attribute is write protected at this time"},
    {0x4001, "no unit"},
    {0x4002, "unit transmission too short"},
    {0x4003, "unit transmission too long"},
    {0x4004, "unit cannot be changed (read only)"},
    {0x4005, "unit is write protected at this time"},
    {0x5001, "no minimum input value"},
    {0x5002, "minimum input value transmission too short"},
    {0x5003, "minimum input value transmission too long"},
    {0x5004, "minimum input value cannot be changed (read only)"},
    {0x5005, "minimum input value is write protected at this time"},
    {0x6001, "no maximum input value"},
    {0x6002, "maximum input value transmission too short"},
    {0x6003, "maximum input value transmission too long"},
    {0x6004, "maximum input value cannot be changed (read only)"},
    {0x6005, "maximum input value is write protected at this time"},
    {0x7002, "operation data transmission too short"},
    {0x7003, "operation data transmission too long"},
    {0x7004, "operation data cannot be changed (read only)"},
    {0x7005, "operation data is write protected at this time"},
    {0x7006, "operation data is smaller than the minimum input value"},
    {0x7007, "operation data is greater than the maximum input value"},
    {0x7008, "invalid operation data (configured IDN not supported)"},
    {0x7009, "operation data is write protected by a password"},
    {0x700A, "operation data is write protected (configured cyclically)"},
    {0x700B, "invalid indirect addressing"},
    {0x700C, "operation data is write protected due to other settings"},
    {0x7010, "procedure command already active"},
    {0x7011, "procedure command not interruptible"},
    {0x7012, "procedure command not executable at this time"},
    {0x7013, "procedure command not executable (invalid or wrong parameters)"},
    {0x7014, "no data state"},
    {0x8001, "no default value"},
    {0x8002, "default value transmission too long"},
    {0x8004, "default value cannot be changed (read only)"},
    {0x800A, "invalid drive number"},
    {0x800B, "general error"},
    {0x800C, "no element addressed"},
};

std::string describe_transfer(std::string_view kind, const Mailbox& mailbox, std::uint8_t drive,
                              std::uint16_t idn) {
  return fmt::format("SoE {} of {} (drive {}) of slave 0x{:04x}", kind, wire::format_idn(idn),
                     drive, mailbox.station());
}

std::optional<wire::SoeHeader> soe_header_of(const MailboxMessage& message) {
  if (message.header.type != wire::MailboxType::soe) return std::nullopt;
  auto header = wire::decode_soe_header(message.data);
  if (!header) return std::nullopt;
  return *header;
}

bool is_unsolicited_opcode(wire::SoeOpcode opcode) {
  return opcode == wire::SoeOpcode::notification || opcode == wire::SoeOpcode::slave_info;
}

// Replies to a read or write: every SoE message but notifications and slave info, which the
// mailbox queues. An SoE message too short for its header is claimed too, so that it fails the
// transfer (with what was wrong) instead of timing it out.
bool soe_reply(const MailboxMessage& message) {
  if (message.header.type != wire::MailboxType::soe) return false;
  const auto header = soe_header_of(message);
  return !header || !is_unsolicited_opcode(header->opcode);
}

Error soe_failure(const std::string& what, std::uint16_t code) {
  return Error(Errc::mailbox_error,
               fmt::format("{}: the drive answered with SoE error 0x{:04x} ({})", what, code,
                           soe_error_text(code)))
      .with_value(kSoeErrorValueBase + code);
}

Error violation(const std::string& what, std::string detail) {
  return Error(Errc::mailbox_error, fmt::format("{}: {}", what, detail));
}

// Checks one response of a transfer: the error flag first (a drive answering with an error may
// not echo the rest faithfully), then opcode, drive number and elements.
Result<wire::SoeMessage> check_response(const MailboxMessage& message, wire::SoeOpcode expected,
                                        std::uint8_t drive, std::uint8_t elements,
                                        const std::string& what) {
  auto soe = wire::decode_soe(message.data);
  if (!soe) return soe.error().context(Errc::malformed, fmt::format("{}: the response", what));
  const wire::SoeHeader& h = soe->header;
  if (h.error) {
    if (h.opcode != expected) {
      return violation(what, fmt::format("an error response with opcode {} ({}), expected {}",
                                         static_cast<unsigned>(h.opcode), to_string(h.opcode),
                                         to_string(expected)));
    }
    return soe_failure(what, soe->error_code.value_or(0));
  }
  if (h.opcode != expected) {
    return violation(what, fmt::format("the drive answered with opcode {} ({}), expected {}",
                                       static_cast<unsigned>(h.opcode), to_string(h.opcode),
                                       to_string(expected)));
  }
  if (h.drive_number != drive) {
    return violation(what, fmt::format("the response is for drive {}, expected drive {}",
                                       h.drive_number, drive));
  }
  if (h.elements != elements) {
    return violation(what, fmt::format("the response carries elements 0x{:02x}, asked for 0x{:02x}",
                                       h.elements, elements));
  }
  return soe;
}

Result<void> check_arguments(const std::string& what, std::uint8_t drive, std::uint8_t elements) {
  if (drive > 7) {
    return Error(Errc::invalid_argument, fmt::format("{}: drive number {} exceeds 7", what, drive));
  }
  if (elements == 0) {
    return Error(Errc::invalid_argument, fmt::format("{}: no element asked for", what));
  }
  return ok();
}

std::uint16_t load_u16(wire::Bytes b, std::size_t at) {
  return static_cast<std::uint16_t>(b[at] | (b[at + 1] << 8));
}

}  // namespace

std::string_view soe_error_text(std::uint16_t code) noexcept {
  for (const auto& e : kErrorTexts) {
    if (e.code == code) return e.text;
  }
  return "unknown SoE error";
}

std::optional<std::uint16_t> soe_error_code(const Error& error) noexcept {
  for (const Error* e = &error; e != nullptr; e = e->cause()) {
    if (e->code() != Errc::mailbox_error || !e->value()) continue;
    const std::uint32_t v = *e->value();
    if (v >= kSoeErrorValueBase && v <= kSoeErrorValueBase + 0xFFFF) {
      return static_cast<std::uint16_t>(v - kSoeErrorValueBase);
    }
  }
  return std::nullopt;
}

// ---- Transfers -------------------------------------------------------------------------------

exec::Task<Result<std::vector<std::uint8_t>>> soe_read(Mailbox& mailbox, std::uint8_t drive_number,
                                                       std::uint16_t idn, std::uint8_t elements,
                                                       SoeOptions options) {
  const std::string what = describe_transfer("read", mailbox, drive_number, idn);
  if (auto checked = check_arguments(what, drive_number, elements); !checked) {
    co_return checked.error();
  }
  auto request = wire::encode_soe(
      {{wire::SoeOpcode::read_request, false, false, drive_number, elements, idn}, {}, {}});
  if (!request) co_return request.error().context(what);

  auto guard = co_await mailbox.lock();
  auto reply = co_await mailbox.exchange(guard, wire::MailboxType::soe, std::move(*request),
                                         options.timeout, soe_reply, what);
  std::vector<std::uint8_t> data;
  std::optional<std::uint16_t> left;  // fragments still to come, as the last fragment said
  for (std::size_t fragment = 1;; ++fragment) {
    if (!reply) co_return reply.error();
    auto soe = check_response(*reply, wire::SoeOpcode::read_response, drive_number, elements, what);
    if (!soe) co_return soe.error();
    const wire::SoeHeader& h = soe->header;
    if (h.incomplete) {
      // A fragment: the IDN field counts the fragments after it, down by one each time.
      if (h.idn == 0) {
        co_return violation(
            what, fmt::format("fragment {} is incomplete with 0 fragments left", fragment));
      }
      if (left && h.idn != *left - 1) {
        co_return violation(
            what, fmt::format("fragment {} says {} fragments left, expected {} (a fragment was "
                              "lost)",
                              fragment, h.idn, *left - 1));
      }
      left = h.idn;
    } else {
      if (left && *left != 1) {
        co_return violation(
            what, fmt::format("the last fragment came as fragment {} while {} more were announced "
                              "(a fragment was lost)",
                              fragment, *left));
      }
      if (h.idn != idn) {
        co_return violation(what, fmt::format("the response is for {}, expected {}",
                                              wire::format_idn(h.idn), wire::format_idn(idn)));
      }
    }
    if (soe->data.size() > options.max_size - std::min(options.max_size, data.size())) {
      co_return Error(Errc::out_of_range,
                      fmt::format("{}: the response exceeds the limit of {} bytes "
                                  "(SoeOptions::max_size)",
                                  what, options.max_size));
    }
    data.insert(data.end(), soe->data.begin(), soe->data.end());
    if (!h.incomplete) co_return data;
    reply = co_await mailbox.receive(guard, options.timeout, soe_reply, what);
  }
}

exec::Task<Result<void>> soe_write(Mailbox& mailbox, std::uint8_t drive_number, std::uint16_t idn,
                                   std::uint8_t elements, std::vector<std::uint8_t> data,
                                   SoeOptions options) {
  const std::string what = describe_transfer("write", mailbox, drive_number, idn);
  if (auto checked = check_arguments(what, drive_number, elements); !checked) {
    co_return checked.error();
  }
  if (data.size() > options.max_size) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: {} bytes exceed the limit of {} bytes (SoeOptions::max_size)",
                                what, data.size(), options.max_size));
  }
  const std::size_t room = mailbox.max_request_data();
  if (room <= wire::kSoeHeaderSize) {
    co_return Error(
        Errc::invalid_argument,
        fmt::format("{}: the mailbox ({} bytes of data) has no room for SoE data", what, room));
  }
  const std::size_t per_fragment = room - wire::kSoeHeaderSize;
  const std::size_t fragments =
      std::max<std::size_t>(1, (data.size() + per_fragment - 1) / per_fragment);
  if (fragments - 1 > 0xFFFF) {
    co_return Error(
        Errc::invalid_argument,
        fmt::format("{}: {} fragments exceed the 16-bit fragments-left count", what, fragments));
  }

  auto guard = co_await mailbox.lock();
  for (std::size_t i = 0; i < fragments; ++i) {
    const bool last = i + 1 == fragments;
    const std::size_t begin = i * per_fragment;
    const std::size_t end = std::min(data.size(), begin + per_fragment);
    wire::SoeMessage message;
    message.header = {wire::SoeOpcode::write_request,
                      !last,
                      false,
                      drive_number,
                      elements,
                      last ? idn : static_cast<std::uint16_t>(fragments - 1 - i)};
    message.data.assign(data.begin() + static_cast<std::ptrdiff_t>(begin),
                        data.begin() + static_cast<std::ptrdiff_t>(end));
    auto bytes = wire::encode_soe(message);
    if (!bytes) co_return bytes.error().context(what);
    // Only the last fragment is answered (a drive that refuses earlier answers one of the
    // others: that answer is taken as the reply below).
    auto sent = co_await mailbox.send(guard, wire::MailboxType::soe, std::move(*bytes),
                                      options.timeout, what);
    if (!sent) co_return sent.error();
  }
  auto reply = co_await mailbox.receive(guard, options.timeout, soe_reply, what);
  if (!reply) co_return reply.error();
  auto soe = check_response(*reply, wire::SoeOpcode::write_response, drive_number, elements, what);
  if (!soe) co_return soe.error();
  if (soe->header.incomplete) {
    co_return violation(what, "the write response has the incomplete flag set");
  }
  if (soe->header.idn != idn) {
    co_return violation(
        what, fmt::format("the response is for {}, expected {}", wire::format_idn(soe->header.idn),
                          wire::format_idn(idn)));
  }
  co_return ok();
}

// ---- Notifications
// -------------------------------------------------------------------------------

std::vector<SoeNotification> soe_notifications(Mailbox& mailbox, std::size_t* malformed) {
  std::vector<SoeNotification> out;
  const auto which = [](const MailboxMessage& message) {
    if (message.header.type != wire::MailboxType::soe) return false;
    const auto header = soe_header_of(message);
    return !header || is_unsolicited_opcode(header->opcode);
  };
  while (auto message = mailbox.take_unsolicited(which)) {
    auto soe = wire::decode_soe(message->data);
    if (!soe) {
      if (malformed != nullptr) ++*malformed;
      continue;
    }
    const wire::SoeHeader& h = soe->header;
    out.push_back(
        {h.opcode, h.drive_number, h.elements, h.idn, h.incomplete, std::move(soe->data)});
  }
  return out;
}

// ---- Elements
// ------------------------------------------------------------------------------------

std::string_view to_string(SoeDisplayFormat format) noexcept {
  switch (format) {
    case SoeDisplayFormat::binary:
      return "binary";
    case SoeDisplayFormat::unsigned_decimal:
      return "unsigned decimal";
    case SoeDisplayFormat::signed_decimal:
      return "signed decimal";
    case SoeDisplayFormat::hexadecimal:
      return "hexadecimal";
    case SoeDisplayFormat::text:
      return "text";
    case SoeDisplayFormat::idn:
      return "IDN";
    case SoeDisplayFormat::floating_point:
      return "floating point";
    case SoeDisplayFormat::sercos_time:
      return "SERCOS time";
  }
  return "unknown";
}

SoeAttribute decode_soe_attribute(std::uint32_t raw) noexcept {
  SoeAttribute a;
  a.conversion_factor = static_cast<std::uint16_t>(raw & 0xFFFF);
  a.length_code = static_cast<std::uint8_t>((raw >> 16) & 0x03);
  a.list = ((raw >> 18) & 1) != 0;
  a.procedure_command = ((raw >> 19) & 1) != 0;
  a.format = static_cast<SoeDisplayFormat>((raw >> 20) & 0x07);
  a.decimals = static_cast<std::uint8_t>((raw >> 24) & 0x0F);
  a.write_protected_preop = ((raw >> 28) & 1) != 0;
  a.write_protected_safeop = ((raw >> 29) & 1) != 0;
  a.write_protected_op = ((raw >> 30) & 1) != 0;
  return a;
}

std::uint32_t encode_soe_attribute(const SoeAttribute& a) noexcept {
  std::uint32_t raw = a.conversion_factor;
  raw |= std::uint32_t{a.length_code & 0x03u} << 16;
  raw |= std::uint32_t{a.list ? 1u : 0u} << 18;
  raw |= std::uint32_t{a.procedure_command ? 1u : 0u} << 19;
  raw |= (static_cast<std::uint32_t>(a.format) & 0x07u) << 20;
  raw |= std::uint32_t{a.decimals & 0x0Fu} << 24;
  raw |= std::uint32_t{a.write_protected_preop ? 1u : 0u} << 28;
  raw |= std::uint32_t{a.write_protected_safeop ? 1u : 0u} << 29;
  raw |= std::uint32_t{a.write_protected_op ? 1u : 0u} << 30;
  return raw;
}

Result<SoeAttribute> decode_soe_attribute(wire::Bytes data) {
  if (data.size() != 4) {
    return Error(Errc::malformed, fmt::format("SoE attribute: {} bytes, expected 4", data.size()));
  }
  return decode_soe_attribute(
      static_cast<std::uint32_t>(data[0] | (data[1] << 8) | (data[2] << 16)) |
      (static_cast<std::uint32_t>(data[3]) << 24));
}

Result<SoeList> decode_soe_list(wire::Bytes data, std::size_t* consumed) {
  if (data.size() < kSoeListHeaderSize) {
    return Error(Errc::truncated, fmt::format("SoE list: {} bytes, the header needs {}",
                                              data.size(), kSoeListHeaderSize));
  }
  const std::uint16_t actual = load_u16(data, 0);
  SoeList list;
  list.max_length = load_u16(data, 2);
  if (actual > data.size() - kSoeListHeaderSize) {
    return Error(Errc::truncated,
                 fmt::format("SoE list: actual length {} exceeds the {} bytes after the header",
                             actual, data.size() - kSoeListHeaderSize));
  }
  const auto body = data.subspan(kSoeListHeaderSize, actual);
  list.data.assign(body.begin(), body.end());
  if (consumed != nullptr) *consumed = kSoeListHeaderSize + actual;
  return list;
}

Result<std::vector<std::uint8_t>> encode_soe_list(const SoeList& list) {
  if (list.data.size() > list.max_length) {
    return Error(Errc::invalid_argument,
                 fmt::format("SoE list: {} bytes exceed its maximum length {}", list.data.size(),
                             list.max_length));
  }
  std::vector<std::uint8_t> out;
  out.reserve(kSoeListHeaderSize + list.data.size());
  const auto actual = static_cast<std::uint16_t>(list.data.size());
  out.push_back(static_cast<std::uint8_t>(actual));
  out.push_back(static_cast<std::uint8_t>(actual >> 8));
  out.push_back(static_cast<std::uint8_t>(list.max_length));
  out.push_back(static_cast<std::uint8_t>(list.max_length >> 8));
  out.insert(out.end(), list.data.begin(), list.data.end());
  return out;
}

Result<std::string> decode_soe_string(wire::Bytes data) {
  auto list = decode_soe_list(data);
  if (!list) return std::move(list).error();
  const auto end = std::find(list->data.begin(), list->data.end(), std::uint8_t{0});
  return std::string(list->data.begin(), end);
}

Result<std::vector<std::uint16_t>> decode_soe_idn_list(wire::Bytes data) {
  auto list = decode_soe_list(data);
  if (!list) return std::move(list).error();
  if (list->data.size() % 2 != 0) {
    return Error(Errc::malformed,
                 fmt::format("SoE IDN list: actual length {} is odd", list->data.size()));
  }
  std::vector<std::uint16_t> idns;
  idns.reserve(list->data.size() / 2);
  for (std::size_t i = 0; i < list->data.size(); i += 2)
    idns.push_back(load_u16(list->data, i));
  return idns;
}

std::vector<std::uint8_t> encode_soe_idn_list(const std::vector<std::uint16_t>& idns,
                                              std::uint16_t max_count) {
  const std::size_t count = std::min<std::size_t>({idns.size(), max_count, 0x7FFF});
  SoeList list;
  list.max_length = static_cast<std::uint16_t>(std::min<std::size_t>(max_count, 0x7FFF) * 2);
  for (std::size_t i = 0; i < count; ++i) {
    list.data.push_back(static_cast<std::uint8_t>(idns[i]));
    list.data.push_back(static_cast<std::uint8_t>(idns[i] >> 8));
  }
  auto bytes = encode_soe_list(list);
  return bytes ? std::move(*bytes) : std::vector<std::uint8_t>{};
}

Result<SoeElements> split_soe_elements(std::uint8_t elements, wire::Bytes data,
                                       std::optional<SoeAttribute> attribute) {
  SoeElements out;
  std::size_t pos = 0;
  const auto fail = [&](Errc code, std::string_view element, std::string detail) {
    return Error(code, fmt::format("SoE elements 0x{:02x}: {} at offset {}: {}", elements, element,
                                   pos, detail));
  };
  const auto take_list = [&](std::string_view element) -> Result<std::vector<std::uint8_t>> {
    std::size_t used = 0;
    auto list = decode_soe_list(data.subspan(pos), &used);
    if (!list) return fail(list.error().code(), element, list.error().message());
    std::vector<std::uint8_t> raw(data.begin() + static_cast<std::ptrdiff_t>(pos),
                                  data.begin() + static_cast<std::ptrdiff_t>(pos + used));
    pos += used;
    return raw;
  };
  const auto take_fixed = [&](std::string_view element,
                              std::size_t n) -> Result<std::vector<std::uint8_t>> {
    if (n > data.size() - pos) {
      return fail(Errc::truncated, element,
                  fmt::format("needs {} bytes, {} remain", n, data.size() - pos));
    }
    std::vector<std::uint8_t> raw(data.begin() + static_cast<std::ptrdiff_t>(pos),
                                  data.begin() + static_cast<std::ptrdiff_t>(pos + n));
    pos += n;
    return raw;
  };
  // A data element (minimum, maximum, value, default): sized by the attribute, else the rest.
  const auto take_data = [&](std::string_view element,
                             std::uint8_t flag) -> Result<std::vector<std::uint8_t>> {
    if (attribute) {
      if (attribute->list) return take_list(element);
      return take_fixed(element, attribute->item_size());
    }
    const bool last = (elements & ~((flag << 1) - 1)) == 0;
    if (!last) {
      return fail(Errc::invalid_argument, element,
                  "its size needs the attribute (not read, not given) when other elements follow");
    }
    return take_fixed(element, data.size() - pos);
  };
  const auto text = [](const std::vector<std::uint8_t>& raw) {
    auto s = decode_soe_string(raw);
    return s ? std::move(*s) : std::string{};
  };

  if ((elements & wire::kSoeElementDataState) != 0) {
    auto raw = take_fixed("data state", 2);
    if (!raw) return raw.error();
    out.data_state = load_u16(*raw, 0);
  }
  if ((elements & wire::kSoeElementName) != 0) {
    auto raw = take_list("name");
    if (!raw) return raw.error();
    out.name = text(*raw);
  }
  if ((elements & wire::kSoeElementAttribute) != 0) {
    auto raw = take_fixed("attribute", 4);
    if (!raw) return raw.error();
    out.attribute = *decode_soe_attribute(*raw);
    attribute = out.attribute;
  }
  if ((elements & wire::kSoeElementUnit) != 0) {
    auto raw = take_list("unit");
    if (!raw) return raw.error();
    out.unit = text(*raw);
  }
  struct DataElement {
    std::uint8_t flag;
    std::string_view name;
    std::optional<std::vector<std::uint8_t>> SoeElements::*slot;
  };
  constexpr DataElement kData[] = {
      {wire::kSoeElementMinimum, "minimum", &SoeElements::minimum},
      {wire::kSoeElementMaximum, "maximum", &SoeElements::maximum},
      {wire::kSoeElementValue, "value", &SoeElements::value},
      {wire::kSoeElementDefault, "default", &SoeElements::default_value},
  };
  for (const auto& d : kData) {
    if ((elements & d.flag) == 0) continue;
    auto raw = take_data(d.name, d.flag);
    if (!raw) return raw.error();
    out.*d.slot = std::move(*raw);
  }
  if (pos != data.size()) {
    return Error(Errc::malformed, fmt::format("SoE elements 0x{:02x}: {} bytes left over after {}",
                                              elements, data.size() - pos, pos));
  }
  return out;
}

exec::Task<Result<SoeElements>> soe_read_elements(Mailbox& mailbox, std::uint8_t drive_number,
                                                  std::uint16_t idn, std::uint8_t elements,
                                                  SoeOptions options) {
  constexpr std::uint8_t kDataElements = wire::kSoeElementMinimum | wire::kSoeElementMaximum |
                                         wire::kSoeElementValue | wire::kSoeElementDefault;
  const std::uint8_t data_elements = elements & kDataElements;
  std::uint8_t asked = elements;
  // More than one data element (or one followed by nothing it could be told from): their sizes
  // come from the attribute.
  if ((data_elements & (data_elements - 1)) != 0) asked |= wire::kSoeElementAttribute;
  auto data = co_await soe_read(mailbox, drive_number, idn, asked, options);
  if (!data) co_return data.error();
  auto split = split_soe_elements(asked, *data);
  if (!split) {
    co_return split.error().context(
        fmt::format("{}: the response", describe_transfer("read", mailbox, drive_number, idn)));
  }
  if ((elements & wire::kSoeElementAttribute) == 0) split->attribute.reset();
  co_return std::move(*split);
}

}  // namespace ecat::master
