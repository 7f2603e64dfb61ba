#include <algorithm>
#include <iterator>
#include <type_traits>

#include <fmt/format.h>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/sdo_abort.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/soe.hpp>
#include <ecat/wire/voe.hpp>

namespace ecat::wire {
namespace {

// A summary is one line: long data and texts are cut.
constexpr std::size_t kMaxHexBytes = 16;
constexpr std::size_t kMaxTextChars = 64;
constexpr std::size_t kMaxListedIndices = 8;

using Out = std::back_insert_iterator<std::string>;

void append_hex(std::string& s, Bytes bytes) {
  const std::size_t shown = std::min(bytes.size(), kMaxHexBytes);
  for (std::size_t i = 0; i < shown; ++i) {
    fmt::format_to(Out(s), "{}{:02x}", i == 0 ? "" : " ", bytes[i]);
  }
  if (shown < bytes.size()) fmt::format_to(Out(s), " ... ({} bytes)", bytes.size());
}

// " = 01 02 03", or nothing for no data.
void append_data(std::string& s, Bytes bytes) {
  if (bytes.empty()) return;
  s += " = ";
  append_hex(s, bytes);
}

// 'text' with non-printable characters escaped.
void append_quoted(std::string& s, std::string_view text) {
  s += '\'';
  const std::size_t shown = std::min(text.size(), kMaxTextChars);
  for (std::size_t i = 0; i < shown; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7F && c != '\'' && c != '\\') {
      s += static_cast<char>(c);
    } else {
      fmt::format_to(Out(s), "\\x{:02x}", c);
    }
  }
  if (shown < text.size()) s += "...";
  s += '\'';
}

void append_address(std::string& s, std::uint16_t index, std::uint8_t subindex) {
  fmt::format_to(Out(s), " 0x{:04X}:{:02X}", index, subindex);
}

void append_malformed(std::string& s, const Error& error) {
  fmt::format_to(Out(s), " (malformed: {})", error.message());
}

template <class Initiate>
void append_initiate(std::string& s, const Initiate& m) {
  s += m.expedited ? " expedited" : " normal";
  append_address(s, m.index, m.subindex);
  if (m.complete_access) s += " complete-access";
  if (!m.expedited) fmt::format_to(Out(s), " size={}", m.complete_size);
  append_data(s, m.data);
}

void summarize_sdo(std::string& s, const SdoMessage& message) {
  std::visit(
      [&s](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, SdoInitiateDownloadRequest>) {
          s += " SDO download req";
          append_initiate(s, m);
        } else if constexpr (std::is_same_v<T, SdoInitiateDownloadResponse>) {
          s += " SDO download resp";
          append_address(s, m.index, m.subindex);
        } else if constexpr (std::is_same_v<T, SdoDownloadSegmentRequest>) {
          fmt::format_to(Out(s), " SDO download segment req toggle={}{}", m.toggle ? 1 : 0,
                         m.last ? " last" : "");
          append_data(s, m.data);
        } else if constexpr (std::is_same_v<T, SdoDownloadSegmentResponse>) {
          fmt::format_to(Out(s), " SDO download segment resp toggle={}", m.toggle ? 1 : 0);
        } else if constexpr (std::is_same_v<T, SdoInitiateUploadRequest>) {
          s += " SDO upload req";
          append_address(s, m.index, m.subindex);
          if (m.complete_access) s += " complete-access";
        } else if constexpr (std::is_same_v<T, SdoInitiateUploadResponse>) {
          s += " SDO upload resp";
          append_initiate(s, m);
        } else if constexpr (std::is_same_v<T, SdoUploadSegmentRequest>) {
          fmt::format_to(Out(s), " SDO upload segment req toggle={}", m.toggle ? 1 : 0);
        } else if constexpr (std::is_same_v<T, SdoUploadSegmentResponse>) {
          fmt::format_to(Out(s), " SDO upload segment resp toggle={}{}", m.toggle ? 1 : 0,
                         m.last ? " last" : "");
          append_data(s, m.data);
        } else {
          static_assert(std::is_same_v<T, SdoAbort>);
          s += " SDO abort";
          append_address(s, m.index, m.subindex);
          fmt::format_to(Out(s), " 0x{:08x} ({})", m.code, sdo_abort_text(m.code));
        }
      },
      message);
}

std::string_view short_name(SdoInfoOpcode opcode) {
  switch (opcode) {
    case SdoInfoOpcode::get_od_list_request:
      return "get OD list req";
    case SdoInfoOpcode::get_od_list_response:
      return "get OD list resp";
    case SdoInfoOpcode::get_object_description_request:
      return "get object description req";
    case SdoInfoOpcode::get_object_description_response:
      return "get object description resp";
    case SdoInfoOpcode::get_entry_description_request:
      return "get entry description req";
    case SdoInfoOpcode::get_entry_description_response:
      return "get entry description resp";
    case SdoInfoOpcode::error_request:
      return "error";
  }
  return "reserved opcode";
}

void summarize_sdo_info(std::string& s, Bytes data) {
  auto fragment = decode_sdo_info_fragment(data);
  if (!fragment) return append_malformed(s, fragment.error());
  const SdoInfoHeader& h = fragment->header;
  fmt::format_to(Out(s), " SDO info {}", short_name(h.opcode));
  if (h.incomplete || h.fragments_left != 0) {
    fmt::format_to(Out(s), " fragment ({} left) {} bytes", h.fragments_left, fragment->data.size());
    return;
  }
  auto message = decode_sdo_info(h.opcode, fragment->data);
  if (!message) return append_malformed(s, message.error());
  std::visit(
      [&s](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, OdListRequest>) {
          fmt::format_to(Out(s), " type={}", to_string(m.list_type));
        } else if constexpr (std::is_same_v<T, OdListResponse>) {
          fmt::format_to(Out(s), " type={} {} {}:", to_string(m.list_type), m.indices.size(),
                         m.list_type == OdListType::number_of_objects ? "counts" : "objects");
          const bool counts = m.list_type == OdListType::number_of_objects;
          const std::size_t shown = std::min(m.indices.size(), kMaxListedIndices);
          for (std::size_t i = 0; i < shown; ++i) {
            if (counts) {
              fmt::format_to(Out(s), " {}", m.indices[i]);
            } else {
              fmt::format_to(Out(s), " 0x{:04X}", m.indices[i]);
            }
          }
          if (shown < m.indices.size()) s += " ...";
        } else if constexpr (std::is_same_v<T, ObjectDescriptionRequest>) {
          fmt::format_to(Out(s), " 0x{:04X}", m.index);
        } else if constexpr (std::is_same_v<T, ObjectDescriptionResponse>) {
          fmt::format_to(Out(s), " 0x{:04X} ", m.index);
          append_quoted(s, m.name);
          fmt::format_to(Out(s), " {} type=0x{:04x} max subindex={}", to_string(m.object_code),
                         m.data_type, m.max_subindex);
        } else if constexpr (std::is_same_v<T, EntryDescriptionRequest>) {
          append_address(s, m.index, m.subindex);
          fmt::format_to(Out(s), " value info=0x{:02x}", m.value_info);
        } else if constexpr (std::is_same_v<T, EntryDescriptionResponse>) {
          append_address(s, m.index, m.subindex);
          s += ' ';
          append_quoted(s, m.description);
          fmt::format_to(Out(s), " type=0x{:04x} bits={} access=0x{:04x}", m.data_type,
                         m.bit_length, m.object_access);
        } else {
          static_assert(std::is_same_v<T, SdoInfoError>);
          fmt::format_to(Out(s), " 0x{:08x} ({})", m.abort_code, sdo_abort_text(m.abort_code));
        }
      },
      *message);
}

void summarize_coe(std::string& s, Bytes data) {
  auto header = decode_coe_header(data);
  if (!header) return append_malformed(s, header.error());
  switch (header->service) {
    case CoeService::sdo_request:
    case CoeService::sdo_response: {
      auto sdo = decode_sdo(data);
      if (!sdo) return append_malformed(s, sdo.error());
      return summarize_sdo(s, *sdo);
    }
    case CoeService::emergency: {
      auto e = decode_emergency(data);
      if (!e) return append_malformed(s, e.error());
      fmt::format_to(Out(s), " emergency 0x{:04X} ({}) reg=0x{:02x}", e->error_code,
                     emergency_error_text(e->error_code), e->error_register);
      if (std::any_of(e->data.begin(), e->data.end(), [](std::uint8_t b) { return b != 0; })) {
        s += " data=";
        append_hex(s, e->data);
      }
      return;
    }
    case CoeService::sdo_information:
      return summarize_sdo_info(s, data);
    case CoeService::tx_pdo:
    case CoeService::rx_pdo:
    case CoeService::tx_pdo_remote_request:
    case CoeService::rx_pdo_remote_request:
      fmt::format_to(Out(s), " {} number={}", to_string(header->service), header->number);
      return append_data(s, data.subspan(kCoeHeaderSize));
  }
  fmt::format_to(Out(s), " service {} {} bytes", static_cast<unsigned>(header->service),
                 data.size());
}

void summarize_foe(std::string& s, Bytes data) {
  auto message = decode_foe(data);
  if (!message) return append_malformed(s, message.error());
  std::visit(
      [&s](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, FoeReadRequest> || std::is_same_v<T, FoeWriteRequest>) {
          s += std::is_same_v<T, FoeReadRequest> ? " read req " : " write req ";
          append_quoted(s, m.file_name);
          if (m.password != 0) fmt::format_to(Out(s), " password=0x{:08x}", m.password);
        } else if constexpr (std::is_same_v<T, FoeData>) {
          fmt::format_to(Out(s), " data packet={} {} bytes", m.packet_number, m.data.size());
        } else if constexpr (std::is_same_v<T, FoeAck>) {
          fmt::format_to(Out(s), " ack packet={}", m.packet_number);
        } else if constexpr (std::is_same_v<T, FoeError>) {
          fmt::format_to(Out(s), " error 0x{:08x} ({})", m.code, foe_error_text(m.code));
          if (!m.text.empty()) {
            s += ' ';
            append_quoted(s, m.text);
          }
        } else {
          static_assert(std::is_same_v<T, FoeBusy>);
          fmt::format_to(Out(s), " busy done={} entire={}", m.done, m.entire);
        }
      },
      *message);
}

void append_ip_parameters(std::string& s, const EoeIpParameters& p) {
  if (p.mac) {
    const auto& m = *p.mac;
    fmt::format_to(Out(s), " mac={:02x}:{:02x}:{:02x}:{:02x}:{:02x}:{:02x}", m[0], m[1], m[2], m[3],
                   m[4], m[5]);
  }
  if (p.ip) fmt::format_to(Out(s), " ip={}", format_ipv4(*p.ip));
  if (p.subnet_mask) fmt::format_to(Out(s), " mask={}", format_ipv4(*p.subnet_mask));
  if (p.default_gateway) fmt::format_to(Out(s), " gateway={}", format_ipv4(*p.default_gateway));
  if (p.dns_server) fmt::format_to(Out(s), " dns={}", format_ipv4(*p.dns_server));
  if (p.dns_name) {
    s += " name=";
    append_quoted(s, *p.dns_name);
  }
}

void summarize_eoe(std::string& s, Bytes data) {
  auto message = decode_eoe(data);
  if (!message) return append_malformed(s, message.error());
  std::visit(
      [&s](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, EoeFragment>) {
          const EoeHeader& h = m.header;
          fmt::format_to(Out(s), " fragment frame={} part={} {}={}", h.frame_number,
                         h.fragment_number, h.fragment_number == 0 ? "size" : "offset",
                         std::size_t{h.offset_blocks} * kEoeBlockSize);
          if (h.port != 0) fmt::format_to(Out(s), " port={}", h.port);
          if (h.last_fragment) s += " last";
          if (h.time_request) s += " time-request";
          fmt::format_to(Out(s), " {} bytes", m.data.size());
          if (m.timestamp) fmt::format_to(Out(s), " time=0x{:08x}", *m.timestamp);
        } else if constexpr (std::is_same_v<T, EoeSetIpRequest>) {
          s += " set IP req";
          if (m.port != 0) fmt::format_to(Out(s), " port={}", m.port);
          append_ip_parameters(s, m.parameters);
        } else if constexpr (std::is_same_v<T, EoeSetIpResponse>) {
          fmt::format_to(Out(s), " set IP resp result=0x{:04x} ({})", m.result,
                         eoe_result_text(m.result));
        } else {
          static_assert(std::is_same_v<T, EoeOther>);
          fmt::format_to(Out(s), " {} {} bytes", to_string(m.header.type), m.data.size());
        }
      },
      *message);
}

void summarize_soe(std::string& s, Bytes data) {
  auto message = decode_soe(data);
  if (!message) return append_malformed(s, message.error());
  const SoeHeader& h = message->header;
  fmt::format_to(Out(s), " {} drive={}", to_string(h.opcode), h.drive_number);
  if (h.incomplete) {
    fmt::format_to(Out(s), " fragments left={}", h.idn);
  } else {
    fmt::format_to(Out(s), " {}", format_idn(h.idn));
  }
  fmt::format_to(Out(s), " elements=0x{:02x}", h.elements);
  if (message->error_code) fmt::format_to(Out(s), " error 0x{:04x}", *message->error_code);
  append_data(s, message->data);
}

void summarize_voe(std::string& s, Bytes data) {
  auto message = decode_voe(data);
  if (!message) return append_malformed(s, message.error());
  fmt::format_to(Out(s), " vendor=0x{:08x} type=0x{:04x}", message->header.vendor_id,
                 message->header.vendor_type);
  append_data(s, message->data);
}

}  // namespace

std::string summarize_mailbox(Bytes mailbox_buffer) {
  if (mailbox_buffer.size() < kMailboxHeaderSize) return "";
  auto header = decode_mailbox_header(mailbox_buffer);
  if (!header || header->length == 0) return "";

  std::string s = "mbx ";
  const std::string_view type_name = to_string(header->type);
  if (type_name == "reserved") {
    fmt::format_to(Out(s), "type={}", static_cast<unsigned>(header->type));
  } else {
    s += type_name;
  }
  // An error reply's counter means nothing; its text follows instead.
  if (header->type != MailboxType::error) fmt::format_to(Out(s), " cnt={}", header->counter);

  auto mailbox = decode_mailbox(mailbox_buffer);
  if (!mailbox) {
    append_malformed(s, mailbox.error());
    return s;
  }
  const Bytes data = mailbox->data;
  switch (header->type) {
    case MailboxType::error: {
      auto reply = decode_mailbox_error(data);
      if (!reply) {
        append_malformed(s, reply.error());
      } else {
        s += ": " + mailbox_error_text(reply->detail);
      }
      break;
    }
    case MailboxType::coe:
      summarize_coe(s, data);
      break;
    case MailboxType::foe:
      summarize_foe(s, data);
      break;
    case MailboxType::eoe:
      summarize_eoe(s, data);
      break;
    case MailboxType::soe:
      summarize_soe(s, data);
      break;
    case MailboxType::voe:
      summarize_voe(s, data);
      break;
    default:
      fmt::format_to(Out(s), " {} bytes", data.size());
      break;
  }
  return s;
}

}  // namespace ecat::wire
