#include <algorithm>
#include <utility>

#include <ecat/sim/esc.hpp>
#include <ecat/sim/soe_server.hpp>
#include <ecat/sim/standard_application.hpp>

namespace ecat::sim {

namespace {

// SoE error codes the server answers with (IEC 61800-7-304; texts in master/soe.hpp).
constexpr std::uint16_t kNoIdn = 0x1001;
constexpr std::uint16_t kNoName = 0x2001;
constexpr std::uint16_t kNoUnit = 0x4001;
constexpr std::uint16_t kNoMinimum = 0x5001;
constexpr std::uint16_t kNoMaximum = 0x6001;
constexpr std::uint16_t kTooShort = 0x7002;
constexpr std::uint16_t kTooLong = 0x7003;
constexpr std::uint16_t kReadOnly = 0x7004;
constexpr std::uint16_t kWriteProtected = 0x7005;
constexpr std::uint16_t kBelowMinimum = 0x7006;
constexpr std::uint16_t kAboveMaximum = 0x7007;
constexpr std::uint16_t kNoDataState = 0x7014;
constexpr std::uint16_t kNoDefault = 0x8001;
constexpr std::uint16_t kInvalidDrive = 0x800A;
constexpr std::uint16_t kGeneralError = 0x800B;
constexpr std::uint16_t kNoElement = 0x800C;

constexpr std::size_t kMaxDrives = 8;

void append_list(std::vector<std::uint8_t>& out, wire::Bytes data, std::uint16_t max_length) {
  const auto actual = static_cast<std::uint16_t>(data.size());
  out.push_back(static_cast<std::uint8_t>(actual));
  out.push_back(static_cast<std::uint8_t>(actual >> 8));
  out.push_back(static_cast<std::uint8_t>(max_length));
  out.push_back(static_cast<std::uint8_t>(max_length >> 8));
  out.insert(out.end(), data.begin(), data.end());
}

void append_text(std::vector<std::uint8_t>& out, const std::string& text) {
  const auto n = std::min<std::size_t>(text.size(), 0xFFFF);
  const wire::Bytes bytes(reinterpret_cast<const std::uint8_t*>(text.data()), n);
  append_list(out, bytes, static_cast<std::uint16_t>(n));
}

// A fixed-size element as a number, sign-extended for signed display formats.
std::int64_t as_number(const std::vector<std::uint8_t>& bytes, bool is_signed) {
  std::uint64_t raw = 0;
  const std::size_t n = std::min<std::size_t>(bytes.size(), 8);
  for (std::size_t i = 0; i < n; ++i)
    raw |= std::uint64_t{bytes[i]} << (8 * i);
  if (is_signed && n > 0 && n < 8 && (bytes[n - 1] & 0x80) != 0)
    raw |= ~std::uint64_t{0} << (8 * n);
  return static_cast<std::int64_t>(raw);
}

bool is_signed(const SoeIdn& idn) {
  return ((idn.attribute >> 20) & 0x07) == 2;
}

// -1, 0, 1: a compared with b in the IDN's number format.
int compare(const SoeIdn& idn, const std::vector<std::uint8_t>& a,
            const std::vector<std::uint8_t>& b) {
  if (is_signed(idn)) {
    const auto x = as_number(a, true);
    const auto y = as_number(b, true);
    return x < y ? -1 : (x > y ? 1 : 0);
  }
  const auto x = static_cast<std::uint64_t>(as_number(a, false));
  const auto y = static_cast<std::uint64_t>(as_number(b, false));
  return x < y ? -1 : (x > y ? 1 : 0);
}

// The "read only" code of each element but the value (written in element order).
std::uint16_t read_only_code(std::uint8_t elements) {
  constexpr std::pair<std::uint8_t, std::uint16_t> kCodes[] = {
      {wire::kSoeElementDataState, kNoDataState}, {wire::kSoeElementName, 0x2004},
      {wire::kSoeElementAttribute, 0x3004},       {wire::kSoeElementUnit, 0x4004},
      {wire::kSoeElementMinimum, 0x5004},         {wire::kSoeElementMaximum, 0x6004},
      {wire::kSoeElementDefault, 0x8004},
  };
  for (const auto& [flag, code] : kCodes) {
    if ((elements & flag) != 0) return code;
  }
  return 0;
}

std::uint32_t protection_bit(wire::AlState state) {
  switch (state) {
    case wire::AlState::safeop:
      return soe_attribute::kWriteProtectedSafeop;
    case wire::AlState::op:
      return soe_attribute::kWriteProtectedOp;
    default:
      return soe_attribute::kWriteProtectedPreop;
  }
}

}  // namespace

std::string_view to_string(SoeFaultKind kind) noexcept {
  switch (kind) {
    case SoeFaultKind::error_response:
      return "error_response";
    case SoeFaultKind::drop_fragment:
      return "drop_fragment";
    case SoeFaultKind::drop_response:
      return "drop_response";
  }
  return "unknown";
}

SoeServer::SoeServer(CoeServer& mailbox, SoeServerConfig config)
    : mailbox_(mailbox), config_(std::move(config)) {
  config_.drives =
      static_cast<std::uint8_t>(std::clamp<std::size_t>(config_.drives, 1, kMaxDrives));
  power_up();
}

void SoeServer::power_up() {
  drives_.assign(config_.drives, {});
  for (auto& drive : drives_) {
    for (const auto& idn : config_.idns)
      drive[idn.idn] = idn;
  }
  write_ = WriteTransfer{};
  deferred_.clear();
}

const SoeIdn* SoeServer::find(std::uint8_t drive, std::uint16_t idn) const noexcept {
  if (drive >= drives_.size()) return nullptr;
  auto it = drives_[drive].find(idn);
  return it == drives_[drive].end() ? nullptr : &it->second;
}

SoeIdn* SoeServer::find_mutable(std::uint8_t drive, std::uint16_t idn) noexcept {
  return const_cast<SoeIdn*>(find(drive, idn));
}

bool SoeServer::set_value(std::uint8_t drive, std::uint16_t idn, std::vector<std::uint8_t> value) {
  SoeIdn* entry = find_mutable(drive, idn);
  if (entry == nullptr) return false;
  if (entry->list() ? value.size() > entry->max_length : value.size() != entry->item_size()) {
    return false;
  }
  entry->value = std::move(value);
  return true;
}

std::optional<std::int64_t> SoeServer::number(std::uint8_t drive,
                                              std::uint16_t idn) const noexcept {
  const SoeIdn* entry = find(drive, idn);
  if (entry == nullptr || entry->list()) return std::nullopt;
  return as_number(entry->value, is_signed(*entry));
}

bool SoeServer::set_number(std::uint8_t drive, std::uint16_t idn, std::int64_t value) {
  const SoeIdn* entry = find(drive, idn);
  if (entry == nullptr || entry->list()) return false;
  std::vector<std::uint8_t> bytes(entry->item_size());
  for (std::size_t i = 0; i < bytes.size(); ++i)
    bytes[i] = static_cast<std::uint8_t>(static_cast<std::uint64_t>(value) >> (8 * i));
  return set_value(drive, idn, std::move(bytes));
}

void SoeServer::notify(Esc& esc, std::uint8_t drive, std::uint16_t idn, std::uint8_t elements,
                       std::vector<std::uint8_t> data) {
  wire::SoeMessage message;
  message.header = {wire::SoeOpcode::notification,           false,    false,
                    static_cast<std::uint8_t>(drive & 0x07), elements, idn};
  message.data = std::move(data);
  auto bytes = wire::encode_soe(message);
  if (!bytes) return;
  ++stats_.notifications_sent;
  if (handling_) {
    deferred_.push_back({wire::MailboxType::soe, std::move(*bytes)});
  } else {
    mailbox_.queue_reply(esc, wire::MailboxType::soe, *bytes);
  }
}

void SoeServer::add_fault(const SoeFaultRule& rule) {
  std::erase_if(faults_, [&](const SoeFaultRule& r) {
    return r.drive == rule.drive && r.idn == rule.idn && r.write == rule.write;
  });
  faults_.push_back(rule);
}

std::optional<SoeFaultRule> SoeServer::take_fault(std::uint8_t drive, std::uint16_t idn,
                                                  bool write) {
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->drive != drive || it->idn != idn || it->write != write) continue;
    const SoeFaultRule rule = *it;
    if (rule.once) faults_.erase(it);
    ++stats_.faults_applied;
    return rule;
  }
  return std::nullopt;
}

MailboxReply SoeServer::error_reply(wire::SoeOpcode opcode, const wire::SoeHeader& request,
                                    std::uint16_t code) {
  ++stats_.errors_sent;
  wire::SoeMessage message;
  message.header = {opcode, false, true, request.drive_number, request.elements, request.idn};
  message.error_code = code;
  auto bytes = wire::encode_soe(message);
  return {wire::MailboxType::soe, bytes ? std::move(*bytes) : std::vector<std::uint8_t>{}};
}

std::vector<MailboxReply> SoeServer::handle(Esc& esc, const wire::MailboxHeader& header,
                                            wire::Bytes data) {
  (void)header;
  auto soe = wire::decode_soe(data);
  if (!soe) {
    // Not even an SoE header: the mailbox-level answer (ETG.1000.4 mailbox error).
    std::vector<std::uint8_t> reply(wire::kMailboxErrorReplySize);
    wire::ByteWriter writer(reply);
    (void)wire::encode_mailbox_error(
        {static_cast<std::uint16_t>(wire::MailboxErrorCode::size_too_short)}, writer);
    return {{wire::MailboxType::error, std::move(reply)}};
  }
  handling_ = true;
  deferred_.clear();
  std::vector<MailboxReply> replies;
  const wire::SoeHeader& h = soe->header;
  switch (h.opcode) {
    case wire::SoeOpcode::read_request:
      ++stats_.reads;
      replies = read(esc, h);
      break;
    case wire::SoeOpcode::write_request:
      replies = write(esc, h, soe->data);
      break;
    default: {
      // Responses, notifications and slave info are the drive's to send, not the master's.
      std::vector<std::uint8_t> reply(wire::kMailboxErrorReplySize);
      wire::ByteWriter writer(reply);
      (void)wire::encode_mailbox_error(
          {static_cast<std::uint16_t>(wire::MailboxErrorCode::service_not_supported)}, writer);
      replies.push_back({wire::MailboxType::error, std::move(reply)});
      break;
    }
  }
  handling_ = false;
  for (auto& d : deferred_)
    replies.push_back(std::move(d));
  deferred_.clear();
  return replies;
}

std::vector<MailboxReply> SoeServer::read(Esc& esc, const wire::SoeHeader& h) {
  constexpr auto kResponse = wire::SoeOpcode::read_response;
  if (h.drive_number >= drives_.size()) return {error_reply(kResponse, h, kInvalidDrive)};
  if (h.elements == 0) return {error_reply(kResponse, h, kNoElement)};
  const SoeIdn* entry = find(h.drive_number, h.idn);
  if (entry == nullptr) return {error_reply(kResponse, h, kNoIdn)};
  std::optional<SoeFaultRule> fault = take_fault(h.drive_number, h.idn, false);
  if (fault && fault->kind == SoeFaultKind::drop_response) return {};
  if (fault && fault->kind == SoeFaultKind::error_response) {
    return {error_reply(kResponse, h, fault->value)};
  }
  if ((h.elements & wire::kSoeElementDataState) != 0) {
    return {error_reply(kResponse, h, kNoDataState)};
  }

  // The elements in bit order.
  std::vector<std::uint8_t> data;
  const auto add_data = [&](const std::vector<std::uint8_t>& bytes) {
    if (entry->list()) {
      append_list(data, bytes, entry->max_length);
    } else {
      data.insert(data.end(), bytes.begin(), bytes.end());
    }
  };
  if ((h.elements & wire::kSoeElementName) != 0) {
    if (entry->name.empty()) return {error_reply(kResponse, h, kNoName)};
    append_text(data, entry->name);
  }
  if ((h.elements & wire::kSoeElementAttribute) != 0) {
    for (int i = 0; i < 4; ++i)
      data.push_back(static_cast<std::uint8_t>(entry->attribute >> (8 * i)));
  }
  if ((h.elements & wire::kSoeElementUnit) != 0) {
    if (!entry->unit) return {error_reply(kResponse, h, kNoUnit)};
    append_text(data, *entry->unit);
  }
  if ((h.elements & wire::kSoeElementMinimum) != 0) {
    if (!entry->minimum) return {error_reply(kResponse, h, kNoMinimum)};
    add_data(*entry->minimum);
  }
  if ((h.elements & wire::kSoeElementMaximum) != 0) {
    if (!entry->maximum) return {error_reply(kResponse, h, kNoMaximum)};
    add_data(*entry->maximum);
  }
  if ((h.elements & wire::kSoeElementValue) != 0) add_data(entry->value);
  if ((h.elements & wire::kSoeElementDefault) != 0) {
    if (!entry->default_value) return {error_reply(kResponse, h, kNoDefault)};
    add_data(*entry->default_value);
  }

  // Fragments: as much as the reply mailbox holds after the mailbox and SoE headers.
  const std::size_t sm = mailbox_.config().reply_sm;
  const std::size_t capacity =
      sm < esc.hardware().sync_manager_count ? esc.sync_manager(sm).config.length : 0;
  const std::size_t overhead = wire::kMailboxHeaderSize + wire::kSoeHeaderSize;
  const std::size_t per = capacity > overhead ? capacity - overhead : 1;
  const std::size_t count = std::max<std::size_t>(1, (data.size() + per - 1) / per);
  if (count - 1 > 0xFFFF) return {error_reply(kResponse, h, kGeneralError)};
  std::vector<MailboxReply> replies;
  for (std::size_t i = 0; i < count; ++i) {
    const bool last = i + 1 == count;
    const std::size_t begin = i * per;
    const std::size_t end = std::min(data.size(), begin + per);
    if (i > 0) ++stats_.fragments_sent;
    if (fault && fault->kind == SoeFaultKind::drop_fragment && fault->value == i + 1) continue;
    wire::SoeMessage message;
    message.header = {kResponse,  !last,
                      false,      h.drive_number,
                      h.elements, last ? h.idn : static_cast<std::uint16_t>(count - 1 - i)};
    message.data.assign(data.begin() + static_cast<std::ptrdiff_t>(begin),
                        data.begin() + static_cast<std::ptrdiff_t>(end));
    auto bytes = wire::encode_soe(message);
    if (!bytes) return {error_reply(kResponse, h, kGeneralError)};
    replies.push_back({wire::MailboxType::soe, std::move(*bytes)});
  }
  return replies;
}

std::vector<MailboxReply> SoeServer::write(Esc& esc, const wire::SoeHeader& h, wire::Bytes data) {
  constexpr auto kResponse = wire::SoeOpcode::write_response;
  if (h.incomplete) {
    // A fragment: kept until the last one; its IDN field counts the fragments still to come.
    ++stats_.fragments_received;
    if (!write_.active || write_.drive != h.drive_number || write_.elements != h.elements) {
      write_ = WriteTransfer{};
      write_.active = true;
      write_.drive = h.drive_number;
      write_.elements = h.elements;
    } else if (write_.error == 0 && h.idn != write_.left - 1) {
      write_.error = kGeneralError;  // a fragment went missing
    }
    write_.left = h.idn;
    if (write_.error == 0 && data.size() > config_.max_write_size - write_.data.size()) {
      write_.error = kTooLong;
      write_.data.clear();
    }
    if (write_.error == 0) write_.data.insert(write_.data.end(), data.begin(), data.end());
    return {};
  }
  ++stats_.writes;
  std::vector<std::uint8_t> value;
  std::uint16_t refused = 0;
  if (write_.active) {
    if (write_.drive != h.drive_number || write_.elements != h.elements || write_.left != 1) {
      refused = write_.error != 0 ? write_.error : kGeneralError;
    } else {
      refused = write_.error;
    }
    value = std::move(write_.data);
    write_ = WriteTransfer{};
  }
  if (refused == 0 && data.size() > config_.max_write_size - value.size()) refused = kTooLong;
  if (refused != 0) return {error_reply(kResponse, h, refused)};
  value.insert(value.end(), data.begin(), data.end());

  if (h.drive_number >= drives_.size()) return {error_reply(kResponse, h, kInvalidDrive)};
  if (find(h.drive_number, h.idn) == nullptr) return {error_reply(kResponse, h, kNoIdn)};
  if (auto fault = take_fault(h.drive_number, h.idn, true)) {
    if (fault->kind == SoeFaultKind::drop_response) return {};
    if (fault->kind == SoeFaultKind::error_response) {
      return {error_reply(kResponse, h, fault->value)};
    }
  }
  const std::uint16_t code = apply_write(esc, h.drive_number, h.idn, h.elements, std::move(value));
  if (code != 0) return {error_reply(kResponse, h, code)};
  wire::SoeMessage message;
  message.header = {kResponse, false, false, h.drive_number, h.elements, h.idn};
  auto bytes = wire::encode_soe(message);
  if (!bytes) return {};
  return {{wire::MailboxType::soe, std::move(*bytes)}};
}

std::uint16_t SoeServer::apply_write(Esc& esc, std::uint8_t drive, std::uint16_t idn,
                                     std::uint8_t elements, std::vector<std::uint8_t> data) {
  if (elements == 0) return kNoElement;
  if (elements != wire::kSoeElementValue) return read_only_code(elements);
  SoeIdn* entry = find_mutable(drive, idn);
  if (entry == nullptr) return kNoIdn;
  if ((entry->attribute & soe_attribute::kReadOnly) == soe_attribute::kReadOnly) return kReadOnly;
  if ((entry->attribute & protection_bit(esc.al_state())) != 0) return kWriteProtected;
  if (entry->list()) {
    if (data.size() < 4) return kTooShort;
    const std::size_t actual = static_cast<std::size_t>(data[0] | (data[1] << 8));
    if (actual > data.size() - 4) return kTooShort;
    if (actual < data.size() - 4 || actual > entry->max_length) return kTooLong;
    data.erase(data.begin(), data.begin() + 4);
  } else {
    if (data.size() < entry->item_size()) return kTooShort;
    if (data.size() > entry->item_size()) return kTooLong;
    if (entry->minimum && compare(*entry, data, *entry->minimum) < 0) return kBelowMinimum;
    if (entry->maximum && compare(*entry, data, *entry->maximum) > 0) return kAboveMaximum;
  }
  if (write_hook_) {
    if (const std::uint16_t code = write_hook_(esc, drive, idn, data); code != 0) return code;
  }
  entry->value = std::move(data);
  return 0;
}

CoeServer::ProtocolHandler voe_handler(VoeHandler handler) {
  return [handler = std::move(handler)](Esc& esc, const wire::MailboxHeader& header,
                                        wire::Bytes data) {
    (void)header;
    std::vector<MailboxReply> replies;
    auto request = wire::decode_voe(data);
    if (!request) {
      std::vector<std::uint8_t> reply(wire::kMailboxErrorReplySize);
      wire::ByteWriter writer(reply);
      (void)wire::encode_mailbox_error(
          {static_cast<std::uint16_t>(wire::MailboxErrorCode::size_too_short)}, writer);
      replies.push_back({wire::MailboxType::error, std::move(reply)});
      return replies;
    }
    for (const auto& message : handler(esc, *request)) {
      if (auto bytes = wire::encode_voe(message)) {
        replies.push_back({wire::MailboxType::voe, std::move(*bytes)});
      }
    }
    return replies;
  };
}

std::vector<wire::VoeMessage> voe_echo(Esc& esc, const wire::VoeMessage& request) {
  (void)esc;
  wire::VoeMessage reply = request;
  reply.header.vendor_type = static_cast<std::uint16_t>(request.header.vendor_type + 1);
  return {std::move(reply)};
}

SoeServer* soe_server_of(Esc& esc) noexcept {
  auto* app = dynamic_cast<StandardApplication*>(&esc.application());
  return app != nullptr ? app->soe_server() : nullptr;
}

}  // namespace ecat::sim
