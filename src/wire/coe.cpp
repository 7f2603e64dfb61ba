#include <type_traits>

#include <fmt/format.h>

#include <ecat/wire/coe.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {
namespace {

// Command specifiers (bits 7..5 of the SDO command byte).
constexpr std::uint8_t kCcsDownloadSegment = 0;
constexpr std::uint8_t kCcsInitiateDownload = 1;
constexpr std::uint8_t kCcsInitiateUpload = 2;
constexpr std::uint8_t kCcsUploadSegment = 3;
constexpr std::uint8_t kScsUploadSegment = 0;
constexpr std::uint8_t kScsDownloadSegment = 1;
constexpr std::uint8_t kScsInitiateUpload = 2;
constexpr std::uint8_t kScsInitiateDownload = 3;
constexpr std::uint8_t kCsAbort = 4;

constexpr std::uint8_t kSizeIndicated = 0x01;
constexpr std::uint8_t kExpedited = 0x02;
constexpr std::uint8_t kCompleteAccess = 0x10;
constexpr std::uint8_t kToggle = 0x10;
constexpr std::uint8_t kLastSegment = 0x01;

constexpr std::uint8_t command(std::uint8_t specifier, std::uint8_t flags) {
  return static_cast<std::uint8_t>((specifier << 5) | flags);
}

// Reads CoE header and command byte; every SDO decoder starts so.
std::uint8_t read_command(detail::FieldReader& r) {
  (void)r.bytes("CoE header", kCoeHeaderSize);
  return r.u8("command");
}

// Initiate download request and initiate upload response share one layout.
template <class Message>
Result<SdoMessage> decode_initiate_transfer(Bytes coe, std::string_view what) {
  detail::FieldReader r(coe, what);
  const std::uint8_t cmd = read_command(r);
  Message m;
  m.index = r.u16("index");
  m.subindex = r.u8("subindex");
  m.complete_access = (cmd & kCompleteAccess) != 0;
  m.expedited = (cmd & kExpedited) != 0;
  m.size_indicated = (cmd & kSizeIndicated) != 0;
  if (m.expedited) {
    Bytes value = r.bytes("expedited data", kSdoMaxExpeditedData);
    if (!r.ok()) return r.error();
    // Without the size indicator the value's size is unspecified: all 4 bytes are kept.
    const std::size_t unused = m.size_indicated ? (cmd >> 2) & 0x03 : 0;
    value = value.first(kSdoMaxExpeditedData - unused);
    m.data.assign(value.begin(), value.end());
  } else {
    m.complete_size = r.u32("complete size");
    Bytes value = r.rest();
    if (!r.ok()) return r.error();
    m.data.assign(value.begin(), value.end());
  }
  return SdoMessage{std::move(m)};
}

template <class Message>
Result<SdoMessage> decode_segment(Bytes coe, std::string_view what) {
  detail::FieldReader r(coe, what);
  const std::uint8_t cmd = read_command(r);
  // Segments carry at least 7 data bytes, the unused ones counted in bits 3..1.
  (void)r.bytes("segment data", kSdoMinSegmentData);
  if (!r.ok()) return r.error();
  Bytes segment = coe.subspan(kCoeHeaderSize + 1);
  const std::size_t unused = (cmd >> 1) & 0x07;
  Message m;
  m.toggle = (cmd & kToggle) != 0;
  m.last = (cmd & kLastSegment) != 0;
  segment = segment.first(segment.size() - unused);
  m.data.assign(segment.begin(), segment.end());
  return SdoMessage{std::move(m)};
}

// Messages made of the command byte and 7 more fixed bytes: they must all be there.
Result<void> require_fixed_size(detail::FieldReader& r) {
  (void)r.bytes("reserved bytes", kSdoFixedSize - r.position());
  if (!r.ok()) return r.error();
  return ok();
}

Result<SdoMessage> decode_addressed(Bytes coe, std::uint8_t specifier, SdoDirection direction) {
  const bool abort = specifier == kCsAbort;
  const std::string_view what = abort ? "SDO abort transfer"
                                : direction == SdoDirection::request
                                    ? "SDO initiate upload request"
                                    : "SDO initiate download response";
  detail::FieldReader r(coe, what);
  const std::uint8_t cmd = read_command(r);
  const std::uint16_t index = r.u16("index");
  const std::uint8_t subindex = r.u8("subindex");
  if (abort) {
    const std::uint32_t code = r.u32("abort code");
    if (!r.ok()) return r.error();
    return SdoMessage{SdoAbort{index, subindex, code, direction}};
  }
  if (auto fixed = require_fixed_size(r); !fixed) return std::move(fixed).error();
  if (direction == SdoDirection::request) {
    return SdoMessage{SdoInitiateUploadRequest{index, subindex, (cmd & kCompleteAccess) != 0}};
  }
  return SdoMessage{SdoInitiateDownloadResponse{index, subindex}};
}

Result<SdoMessage> decode_toggle_only(Bytes coe, std::uint8_t cmd, SdoDirection direction) {
  detail::FieldReader r(coe, direction == SdoDirection::request ? "SDO upload segment request"
                                                                : "SDO download segment response");
  (void)read_command(r);
  if (auto fixed = require_fixed_size(r); !fixed) return std::move(fixed).error();
  const bool toggle = (cmd & kToggle) != 0;
  if (direction == SdoDirection::request) return SdoMessage{SdoUploadSegmentRequest{toggle}};
  return SdoMessage{SdoDownloadSegmentResponse{toggle}};
}

// --- encoding ---

class SdoEncoder {
 public:
  explicit SdoEncoder(CoeService service) {
    detail::append_u16(out_, static_cast<std::uint16_t>(static_cast<unsigned>(service) << 12));
  }
  void u8(std::uint8_t v) { out_.push_back(v); }
  void u16(std::uint16_t v) { detail::append_u16(out_, v); }
  void u32(std::uint32_t v) { detail::append_u32(out_, v); }
  void bytes(Bytes b) { detail::append(out_, b); }
  void zeros(std::size_t n) { out_.insert(out_.end(), n, 0); }
  Result<std::vector<std::uint8_t>> finish(std::string_view what) && {
    if (out_.size() > detail::kMaxMailboxData) {
      return detail::invalid_argument(
          what, fmt::format("{} bytes exceed the mailbox length limit of 65535", out_.size()));
    }
    return std::move(out_);
  }

 private:
  std::vector<std::uint8_t> out_;
};

template <class Message>
Result<std::vector<std::uint8_t>> encode_initiate_transfer(const Message& m, std::uint8_t specifier,
                                                           CoeService service,
                                                           std::string_view what) {
  std::uint8_t flags = m.complete_access ? kCompleteAccess : 0;
  if (m.size_indicated) flags |= kSizeIndicated;
  SdoEncoder e(service);
  if (m.expedited) {
    if (m.complete_size != 0) {
      return detail::invalid_argument(
          what,
          fmt::format("complete_size must be 0 for an expedited transfer, is {}", m.complete_size));
    }
    if (m.size_indicated && (m.data.empty() || m.data.size() > kSdoMaxExpeditedData)) {
      return detail::invalid_argument(
          what, fmt::format("expedited data must be 1 to 4 bytes, is {}", m.data.size()));
    }
    if (!m.size_indicated && m.data.size() != kSdoMaxExpeditedData) {
      return detail::invalid_argument(
          what, fmt::format("expedited data without size indicator must be 4 bytes, is {}",
                            m.data.size()));
    }
    flags |= kExpedited;
    if (m.size_indicated) {
      flags |= static_cast<std::uint8_t>((kSdoMaxExpeditedData - m.data.size()) << 2);
    }
    e.u8(command(specifier, flags));
    e.u16(m.index);
    e.u8(m.subindex);
    e.bytes(m.data);
    e.zeros(kSdoMaxExpeditedData - m.data.size());
  } else {
    e.u8(command(specifier, flags));
    e.u16(m.index);
    e.u8(m.subindex);
    e.u32(m.complete_size);
    e.bytes(m.data);
  }
  return std::move(e).finish(what);
}

template <class Message>
Result<std::vector<std::uint8_t>> encode_segment(const Message& m, std::uint8_t specifier,
                                                 CoeService service, std::string_view what) {
  const std::size_t unused =
      m.data.size() < kSdoMinSegmentData ? kSdoMinSegmentData - m.data.size() : 0;
  std::uint8_t flags = static_cast<std::uint8_t>(unused << 1);
  if (m.toggle) flags |= kToggle;
  if (m.last) flags |= kLastSegment;
  SdoEncoder e(service);
  e.u8(command(specifier, flags));
  e.bytes(m.data);
  e.zeros(unused);
  return std::move(e).finish(what);
}

Result<std::vector<std::uint8_t>> encode_fixed(CoeService service, std::uint8_t cmd,
                                               std::uint16_t index, std::uint8_t subindex,
                                               std::uint32_t last) {
  SdoEncoder e(service);
  e.u8(cmd);
  e.u16(index);
  e.u8(subindex);
  e.u32(last);
  return std::move(e).finish("SDO");
}

Result<std::vector<std::uint8_t>> encode_toggle_only(CoeService service, std::uint8_t specifier,
                                                     bool toggle) {
  SdoEncoder e(service);
  e.u8(command(specifier, toggle ? kToggle : 0));
  e.zeros(kSdoHeaderSize - 1);
  return std::move(e).finish("SDO");
}

template <class Entry>
Result<std::vector<Entry>> complete_access_entries(Bytes value) {
  auto split = split_complete_access(value);
  if (!split) return std::move(split).error();
  const std::size_t need = std::size_t{split->subindex0} * sizeof(Entry);
  if (split->entries.size() < need) {
    return Error(Errc::truncated,
                 fmt::format("complete-access value: subindex 0 counts {} entries of {} bytes "
                             "({} bytes from offset 2), only {} bytes follow",
                             split->subindex0, sizeof(Entry), need, split->entries.size()));
  }
  std::vector<Entry> entries;
  entries.reserve(split->subindex0);
  for (std::size_t i = 0; i < split->subindex0; ++i) {
    const std::uint8_t* p = split->entries.data() + i * sizeof(Entry);
    if constexpr (sizeof(Entry) == 2) {
      entries.push_back(load_le16(p));
    } else {
      entries.push_back(load_le32(p));
    }
  }
  return entries;
}

}  // namespace

std::string_view to_string(CoeService service) noexcept {
  switch (service) {
    case CoeService::emergency:
      return "emergency";
    case CoeService::sdo_request:
      return "SDO request";
    case CoeService::sdo_response:
      return "SDO response";
    case CoeService::tx_pdo:
      return "TxPDO";
    case CoeService::rx_pdo:
      return "RxPDO";
    case CoeService::tx_pdo_remote_request:
      return "TxPDO remote request";
    case CoeService::rx_pdo_remote_request:
      return "RxPDO remote request";
    case CoeService::sdo_information:
      return "SDO information";
  }
  return "reserved";
}

Result<void> encode_coe_header(const CoeHeader& header, ByteWriter& out) {
  if (header.number > 0x1FF) {
    return detail::invalid_argument("CoE header",
                                    fmt::format("number {} exceeds 511", header.number));
  }
  const auto service = static_cast<unsigned>(header.service);
  if (service > 0x0F) {
    return detail::invalid_argument("CoE header", fmt::format("service {} exceeds 15", service));
  }
  if (out.remaining() < kCoeHeaderSize) {
    return detail::no_room("CoE header", kCoeHeaderSize, out.remaining());
  }
  out.u16(static_cast<std::uint16_t>(header.number | (service << 12)));
  return ok();
}

Result<CoeHeader> decode_coe_header(Bytes coe) {
  detail::FieldReader r(coe, "CoE header");
  const std::uint16_t word = r.u16("number/service");
  if (!r.ok()) return r.error();
  return CoeHeader{static_cast<std::uint16_t>(word & 0x1FF), static_cast<CoeService>(word >> 12)};
}

SdoDirection direction_of(const SdoMessage& message) noexcept {
  return std::visit(
      [](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, SdoAbort>) {
          return m.service;
        } else if constexpr (std::is_same_v<T, SdoInitiateDownloadRequest> ||
                             std::is_same_v<T, SdoDownloadSegmentRequest> ||
                             std::is_same_v<T, SdoInitiateUploadRequest> ||
                             std::is_same_v<T, SdoUploadSegmentRequest>) {
          return SdoDirection::request;
        } else {
          return SdoDirection::response;
        }
      },
      message);
}

std::string_view to_string(const SdoMessage& message) noexcept {
  static constexpr std::string_view kNames[] = {
      "initiate download request", "initiate download response", "download segment request",
      "download segment response", "initiate upload request",    "initiate upload response",
      "upload segment request",    "upload segment response",    "abort transfer",
  };
  static_assert(std::size(kNames) == std::variant_size_v<SdoMessage>);
  return kNames[message.index()];
}

Result<SdoMessage> decode_sdo(Bytes coe) {
  auto header = decode_coe_header(coe);
  if (!header) return std::move(header).error();
  SdoDirection direction;
  if (header->service == CoeService::sdo_request) {
    direction = SdoDirection::request;
  } else if (header->service == CoeService::sdo_response) {
    direction = SdoDirection::response;
  } else {
    return detail::malformed(
        "SDO", fmt::format("CoE service {} ({}) at offset 0 is neither SDO request (2) nor SDO "
                           "response (3)",
                           static_cast<unsigned>(header->service), to_string(header->service)));
  }
  if (coe.size() <= kCoeHeaderSize) {
    detail::FieldReader r(coe, "SDO");
    (void)read_command(r);
    return r.error();
  }
  const std::uint8_t cmd = coe[kCoeHeaderSize];
  const std::uint8_t specifier = cmd >> 5;
  if (direction == SdoDirection::request) {
    switch (specifier) {
      case kCcsDownloadSegment:
        return decode_segment<SdoDownloadSegmentRequest>(coe, "SDO download segment request");
      case kCcsInitiateDownload:
        return decode_initiate_transfer<SdoInitiateDownloadRequest>(
            coe, "SDO initiate download request");
      case kCcsInitiateUpload:
        return decode_addressed(coe, specifier, direction);
      case kCcsUploadSegment:
        return decode_toggle_only(coe, cmd, direction);
      case kCsAbort:
        return decode_addressed(coe, specifier, direction);
      default:
        break;
    }
    return detail::malformed(
        "SDO request", fmt::format("client command specifier {} (command 0x{:02x} at offset 2) "
                                   "is not valid for EtherCAT",
                                   specifier, cmd));
  }
  switch (specifier) {
    case kScsUploadSegment:
      return decode_segment<SdoUploadSegmentResponse>(coe, "SDO upload segment response");
    case kScsDownloadSegment:
      return decode_toggle_only(coe, cmd, direction);
    case kScsInitiateUpload:
      return decode_initiate_transfer<SdoInitiateUploadResponse>(coe,
                                                                 "SDO initiate upload response");
    case kScsInitiateDownload:
      return decode_addressed(coe, specifier, direction);
    case kCsAbort:
      return decode_addressed(coe, specifier, direction);
    default:
      break;
  }
  return detail::malformed(
      "SDO response", fmt::format("server command specifier {} (command 0x{:02x} at offset 2) is "
                                  "not valid for EtherCAT",
                                  specifier, cmd));
}

Result<std::vector<std::uint8_t>> encode_sdo(const SdoMessage& message) {
  constexpr auto kRequest = CoeService::sdo_request;
  constexpr auto kResponse = CoeService::sdo_response;
  return std::visit(
      [&](const auto& m) -> Result<std::vector<std::uint8_t>> {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, SdoInitiateDownloadRequest>) {
          return encode_initiate_transfer(m, kCcsInitiateDownload, kRequest,
                                          "SDO initiate download request");
        } else if constexpr (std::is_same_v<T, SdoInitiateDownloadResponse>) {
          return encode_fixed(kResponse, command(kScsInitiateDownload, 0), m.index, m.subindex, 0);
        } else if constexpr (std::is_same_v<T, SdoDownloadSegmentRequest>) {
          return encode_segment(m, kCcsDownloadSegment, kRequest, "SDO download segment request");
        } else if constexpr (std::is_same_v<T, SdoDownloadSegmentResponse>) {
          return encode_toggle_only(kResponse, kScsDownloadSegment, m.toggle);
        } else if constexpr (std::is_same_v<T, SdoInitiateUploadRequest>) {
          return encode_fixed(kRequest,
                              command(kCcsInitiateUpload, m.complete_access ? kCompleteAccess : 0),
                              m.index, m.subindex, 0);
        } else if constexpr (std::is_same_v<T, SdoInitiateUploadResponse>) {
          return encode_initiate_transfer(m, kScsInitiateUpload, kResponse,
                                          "SDO initiate upload response");
        } else if constexpr (std::is_same_v<T, SdoUploadSegmentRequest>) {
          return encode_toggle_only(kRequest, kCcsUploadSegment, m.toggle);
        } else if constexpr (std::is_same_v<T, SdoUploadSegmentResponse>) {
          return encode_segment(m, kScsUploadSegment, kResponse, "SDO upload segment response");
        } else {
          static_assert(std::is_same_v<T, SdoAbort>);
          return encode_fixed(m.service == SdoDirection::request ? kRequest : kResponse,
                              command(kCsAbort, 0), m.index, m.subindex, m.code);
        }
      },
      message);
}

Result<CompleteAccessValue> split_complete_access(Bytes value) {
  detail::FieldReader r(value, "complete-access value");
  CompleteAccessValue v;
  v.subindex0 = r.u8("subindex 0");
  (void)r.u8("subindex 0 padding");
  if (!r.ok()) return r.error();
  v.entries = r.rest();
  return v;
}

std::vector<std::uint8_t> join_complete_access(std::uint8_t subindex0, Bytes entries) {
  std::vector<std::uint8_t> out{subindex0, 0};
  detail::append(out, entries);
  return out;
}

Result<std::vector<std::uint16_t>> complete_access_u16_entries(Bytes value) {
  return complete_access_entries<std::uint16_t>(value);
}

Result<std::vector<std::uint32_t>> complete_access_u32_entries(Bytes value) {
  return complete_access_entries<std::uint32_t>(value);
}

}  // namespace ecat::wire
