#include <cerrno>
#include <cstring>
#include <variant>

#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/link/mailbox_gateway_client.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/mailbox_gateway.hpp>
#include <ecat/wire/sdo_abort.hpp>

#include "link/posix.hpp"

namespace ecat::link {

namespace {

using Clock = std::chrono::steady_clock;

std::string station_text(std::uint16_t station) {
  return fmt::format("{:#06x}", station);
}

}  // namespace

Result<std::unique_ptr<MailboxGatewayClient>> MailboxGatewayClient::connect(
    std::string_view address) {
  std::string host(address);
  std::string port = std::to_string(wire::kMailboxGatewayPort);
  if (const auto colon = address.rfind(':'); colon != address.npos) {
    host = std::string(address.substr(0, colon));
    port = std::string(address.substr(colon + 1));
    if (port.empty() || port.size() > 5 ||
        port.find_first_not_of("0123456789") != std::string::npos || std::stoul(port) > 0xFFFF ||
        std::stoul(port) == 0) {
      return Error(Errc::invalid_argument,
                   fmt::format("mailbox gateway '{}': the port is not 1..65535", address));
    }
  }
  if (host.empty()) {
    return Error(Errc::invalid_argument,
                 fmt::format("mailbox gateway '{}': no host (HOST:PORT or HOST)", address));
  }
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_DGRAM;
  addrinfo* found = nullptr;
  if (const int rc = ::getaddrinfo(host.c_str(), port.c_str(), &hints, &found); rc != 0) {
    return Error(Errc::not_found, fmt::format("mailbox gateway '{}': cannot resolve '{}': {}",
                                              address, host, ::gai_strerror(rc)));
  }
  detail::UniqueFd fd(::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0));
  if (!fd.valid()) {
    ::freeaddrinfo(found);
    return detail::os_error(Errc::io_error, "mailbox gateway client: socket()", errno);
  }
  const int connected = ::connect(fd.get(), found->ai_addr, found->ai_addrlen);
  const int err = errno;
  ::freeaddrinfo(found);
  if (connected != 0) {
    return detail::os_error(Errc::io_error, fmt::format("mailbox gateway '{}': connect", address),
                            err);
  }
  return std::unique_ptr<MailboxGatewayClient>(
      new MailboxGatewayClient(fd.release(), fmt::format("{}:{}", host, port)));
}

MailboxGatewayClient::~MailboxGatewayClient() {
  if (fd_ >= 0) ::close(fd_);
}

Result<void> MailboxGatewayClient::send_datagram(wire::Bytes datagram) {
  const ssize_t n = ::send(fd_, datagram.data(), datagram.size(), 0);
  if (n != static_cast<ssize_t>(datagram.size())) {
    return detail::os_error(Errc::io_error, fmt::format("mailbox gateway {}: send", peer_), errno);
  }
  return ok();
}

Result<std::vector<std::uint8_t>> MailboxGatewayClient::receive_datagram(
    std::chrono::nanoseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  std::vector<std::uint8_t> buffer(4096);
  for (;;) {
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) {
      return Error(Errc::timeout,
                   fmt::format("mailbox gateway {}: no reply within {} ms", peer_,
                               std::chrono::ceil<std::chrono::milliseconds>(timeout).count()));
    }
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(left.count()));
    if (ready < 0 && errno != EINTR) {
      return detail::os_error(Errc::io_error, fmt::format("mailbox gateway {}: poll", peer_),
                              errno);
    }
    if (ready <= 0) continue;
    const ssize_t n = ::recv(fd_, buffer.data(), buffer.size(), MSG_DONTWAIT);
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      // ECONNREFUSED: nothing listens there (an ICMP port unreachable came back).
      return detail::os_error(errno == ECONNREFUSED ? Errc::closed : Errc::io_error,
                              fmt::format("mailbox gateway {}: receive", peer_), errno);
    }
    buffer.resize(static_cast<std::size_t>(n));
    return buffer;
  }
}

Result<GatewayReply> MailboxGatewayClient::exchange(std::uint16_t station, wire::MailboxType type,
                                                    wire::Bytes data,
                                                    std::chrono::nanoseconds timeout) {
  counter_ = wire::next_mailbox_counter(counter_);
  wire::MailboxHeader header;
  header.address = station;
  header.type = type;
  header.counter = counter_;
  auto datagram = wire::encode_gateway_message(header, data);
  if (!datagram) return std::move(datagram).error();
  if (auto sent = send_datagram(*datagram); !sent) return sent.error();
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    const auto left = deadline - Clock::now();
    if (left <= std::chrono::nanoseconds::zero()) {
      return Error(Errc::timeout,
                   fmt::format("mailbox gateway {}: no reply from station {} within {} ms", peer_,
                               station_text(station),
                               std::chrono::ceil<std::chrono::milliseconds>(timeout).count()));
    }
    auto raw = receive_datagram(left);
    if (!raw) {
      if (raw.error().code() == Errc::timeout) continue;
      return raw.error();
    }
    auto message = wire::decode_gateway_message(*raw);
    if (!message) {
      return message.error().context(
          Errc::malformed, fmt::format("mailbox gateway {}: the reply for station {}", peer_,
                                       station_text(station)));
    }
    if (message->header.address != station) {
      ++skipped_;
      continue;
    }
    return GatewayReply{message->header, {message->data.begin(), message->data.end()}};
  }
}

namespace {

// The reply as an SDO message, or the error it is (a mailbox error, an abort, another protocol).
Result<wire::SdoMessage> sdo_reply(const GatewayReply& reply, std::uint16_t station,
                                   const std::string& what) {
  if (reply.header.type == wire::MailboxType::error) {
    auto error = wire::decode_mailbox_error(reply.data);
    if (!error) return error.error().context(Errc::mailbox_error, what);
    return Error(Errc::mailbox_error,
                 fmt::format("{}: station {} answered with mailbox error {:#06x}: {}", what,
                             station_text(station), error->detail,
                             wire::mailbox_error_text(error->detail)))
        .with_value(error->detail);
  }
  if (reply.header.type != wire::MailboxType::coe) {
    return Error(Errc::mailbox_error,
                 fmt::format("{}: station {} answered with a {} message", what,
                             station_text(station), wire::to_string(reply.header.type)));
  }
  auto sdo = wire::decode_sdo(reply.data);
  if (!sdo) return sdo.error().context(Errc::malformed, what);
  if (const auto* abort = std::get_if<wire::SdoAbort>(&*sdo)) {
    return Error(Errc::sdo_abort, fmt::format("{}: aborted with {:#010x} ({})", what, abort->code,
                                              wire::sdo_abort_text(abort->code)))
        .with_value(abort->code);
  }
  return sdo;
}

Error unexpected(const std::string& what, const wire::SdoMessage& message) {
  return Error(Errc::mailbox_error,
               fmt::format("{}: unexpected {}", what, wire::to_string(message)));
}

}  // namespace

Result<std::vector<std::uint8_t>> MailboxGatewayClient::upload_sdo(
    std::uint16_t station, std::uint16_t index, std::uint8_t subindex,
    std::chrono::nanoseconds timeout) {
  const std::string what = fmt::format("SDO upload {:#06x}:{:02x} from station {} through {}",
                                       index, subindex, station_text(station), peer_);
  auto request = wire::encode_sdo(wire::SdoInitiateUploadRequest{index, subindex, false});
  if (!request) return std::move(request).error();
  auto reply = exchange(station, wire::MailboxType::coe, *request, timeout);
  if (!reply) return reply.error().context(reply.error().code(), what);
  auto sdo = sdo_reply(*reply, station, what);
  if (!sdo) return sdo.error();
  const auto* initiate = std::get_if<wire::SdoInitiateUploadResponse>(&*sdo);
  if (initiate == nullptr) return unexpected(what, *sdo);
  std::vector<std::uint8_t> value = initiate->data;
  if (initiate->expedited || value.size() >= initiate->complete_size) return value;
  // Segmented: upload segment requests with alternating toggles until the last one. Bounded by
  // the size announced (and a segment carries at least one byte when it is not the last).
  bool toggle = false;
  while (value.size() < initiate->complete_size) {
    auto segment_request = wire::encode_sdo(wire::SdoUploadSegmentRequest{toggle});
    if (!segment_request) return std::move(segment_request).error();
    auto segment_reply = exchange(station, wire::MailboxType::coe, *segment_request, timeout);
    if (!segment_reply) return segment_reply.error().context(segment_reply.error().code(), what);
    auto message = sdo_reply(*segment_reply, station, what);
    if (!message) return message.error();
    const auto* segment = std::get_if<wire::SdoUploadSegmentResponse>(&*message);
    if (segment == nullptr) return unexpected(what, *message);
    if (segment->toggle != toggle) {
      return Error(Errc::mailbox_error, fmt::format("{}: the segment's toggle bit is wrong", what));
    }
    value.insert(value.end(), segment->data.begin(), segment->data.end());
    if (segment->last) break;
    if (segment->data.empty()) {
      return Error(Errc::mailbox_error,
                   fmt::format("{}: an empty segment that is not the last", what));
    }
    toggle = !toggle;
  }
  if (value.size() > initiate->complete_size) value.resize(initiate->complete_size);
  return value;
}

Result<void> MailboxGatewayClient::download_sdo(std::uint16_t station, std::uint16_t index,
                                                std::uint8_t subindex, wire::Bytes data,
                                                std::chrono::nanoseconds timeout) {
  const std::string what = fmt::format("SDO download {:#06x}:{:02x} to station {} through {}",
                                       index, subindex, station_text(station), peer_);
  if (data.empty()) {
    return Error(Errc::invalid_argument, fmt::format("{}: no data", what));
  }
  wire::SdoInitiateDownloadRequest initiate;
  initiate.index = index;
  initiate.subindex = subindex;
  initiate.expedited = data.size() <= wire::kSdoMaxExpeditedData;
  initiate.size_indicated = true;
  initiate.complete_size = initiate.expedited ? 0 : static_cast<std::uint32_t>(data.size());
  initiate.data.assign(data.begin(), data.end());
  auto request = wire::encode_sdo(initiate);
  if (!request) return std::move(request).error();
  auto reply = exchange(station, wire::MailboxType::coe, *request, timeout);
  if (!reply) return reply.error().context(reply.error().code(), what);
  auto sdo = sdo_reply(*reply, station, what);
  if (!sdo) return sdo.error();
  if (!std::holds_alternative<wire::SdoInitiateDownloadResponse>(*sdo)) {
    return unexpected(what, *sdo);
  }
  return ok();
}

}  // namespace ecat::link
