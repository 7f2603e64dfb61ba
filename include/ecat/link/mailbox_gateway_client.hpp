// A client of an EtherCAT mailbox gateway (ETG.8200, wire/mailbox_gateway.hpp): sends one mailbox
// message for a slave (by station address) to a master's gateway over UDP and waits for the reply,
// as a configuration tool does. `ecat upload/download --gateway` use it; so do the gateway's tests.
//
// Requests are numbered 1..7 in the mailbox header's counter (the gateway passes its own counter to
// the slave; this one only has to be well-formed). A reply is the next gateway message from the
// gateway whose address is the station asked; others (a late reply to an earlier request that
// timed out) are skipped and counted.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::link {

struct GatewayReply {
  wire::MailboxHeader header{};
  std::vector<std::uint8_t> data;
};

class MailboxGatewayClient {
 public:
  // `address`: "HOST:PORT" or "HOST" (port 34980); HOST an IPv4 address or a name resolved once.
  // Errc::not_found for a name that does not resolve, Errc::invalid_argument for a bad address.
  static Result<std::unique_ptr<MailboxGatewayClient>> connect(std::string_view address);
  ~MailboxGatewayClient();
  MailboxGatewayClient(const MailboxGatewayClient&) = delete;
  MailboxGatewayClient& operator=(const MailboxGatewayClient&) = delete;

  // One message to `station` and its reply (a mailbox error reply included: see
  // GatewayReply::header.type). Errc::timeout when none comes.
  Result<GatewayReply> exchange(std::uint16_t station, wire::MailboxType type, wire::Bytes data,
                                std::chrono::nanoseconds timeout = std::chrono::seconds(2));

  // SDO transfers over exchange(), as a configuration tool makes them: an upload (expedited,
  // normal or segmented) and a download (expedited up to 4 bytes, else normal in one message).
  // The slave's abort is Errc::sdo_abort with the code as value(); a mailbox error reply is
  // Errc::mailbox_error with the detail as value().
  Result<std::vector<std::uint8_t>> upload_sdo(
      std::uint16_t station, std::uint16_t index, std::uint8_t subindex,
      std::chrono::nanoseconds timeout = std::chrono::seconds(2));
  Result<void> download_sdo(std::uint16_t station, std::uint16_t index, std::uint8_t subindex,
                            wire::Bytes data,
                            std::chrono::nanoseconds timeout = std::chrono::seconds(2));

  // Raw datagrams, for tests and tools that frame their own.
  Result<void> send_datagram(wire::Bytes datagram);
  Result<std::vector<std::uint8_t>> receive_datagram(std::chrono::nanoseconds timeout);

  // Replies skipped because they named another station.
  std::uint64_t skipped() const noexcept { return skipped_; }
  // "127.0.0.1:34980"
  const std::string& peer() const noexcept { return peer_; }

 private:
  MailboxGatewayClient(int fd, std::string peer) noexcept : fd_(fd), peer_(std::move(peer)) {}
  int fd_ = -1;
  std::string peer_;
  std::uint8_t counter_ = 0;
  std::uint64_t skipped_ = 0;
};

}  // namespace ecat::link
