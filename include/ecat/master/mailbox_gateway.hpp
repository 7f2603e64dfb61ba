// The mailbox gateway (ETG.8200): a UDP port on which a configuration tool outside the segment
// sends mailbox messages (CoE, FoE, SoE, VoE, ... as wire/mailbox_gateway.hpp frames them) to the
// slaves of a running master and gets the slaves' replies back, framed the same way.
//
// A request's mailbox header names the slave by its station address. The gateway passes the
// message's type and data to that slave's mailbox (Slave::mailbox_exchange: behind the master's
// own counter, serialized with the master's own mailbox traffic) and sends the slave's reply back
// to the requester with the request's address in the header; the rest of the reply's header
// (type, counter, channel, priority) is the slave's. The request's counter, channel and priority
// are the tool's and are not passed on: the slave sees the master's counter, so it takes every
// message as new, whatever the tool numbered it.
//
// ETG.8200 specifies no error handling (a request to a slave that does not exist may go
// unanswered). ecat answers what it can tell at once with a mailbox error message (type 0,
// ETG.1000.6 §5.6 codes, addressed as the request was) and counts it:
//   station 0 (the master; ecat has no master object dictionary) -> 0x0002 unsupported protocol
//   a station no slave of the session has                         -> 0x0001 syntax (the header)
//   a slave without a mailbox, or without the protocol in its SII -> 0x0002 unsupported protocol
//   data larger than the slave's mailbox                          -> 0x0008 invalid size
//   the queue full                                                -> 0x0007 no more memory
// The slave's own mailbox error reply is passed on as it came. A request the slave does not answer
// within MailboxGatewayConfig::request_timeout, or that cannot run (the slave down or below PREOP)
// gets no reply, as a slave that does not answer would give none; datagrams that are not a
// gateway message are dropped. All of these are counted (MailboxGatewayStats).
//
// Threads: one receives (it never waits for a slave), MailboxGatewayConfig::workers carry
// requests to the slaves, one request in flight per slave, the others queued (bounded) in order
// of arrival. None of them is the bus thread: the gateway's mailbox traffic is acyclic work on the
// control thread, as every Slave call's.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include <ecat/master/config.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

class Master;

struct MailboxGatewayStats {
  std::uint64_t datagrams = 0;        // datagrams received
  std::uint64_t malformed = 0;        // ... that were no gateway message (dropped)
  std::uint64_t forwarded = 0;        // requests passed to a slave's mailbox
  std::uint64_t replies = 0;          // slave replies sent back (its mailbox errors included)
  std::uint64_t error_replies = 0;    // mailbox errors the gateway answered with, all causes:
  std::uint64_t unknown_station = 0;  //   a station no slave has, or the master's (0)
  std::uint64_t unsupported = 0;      //   no mailbox, or a protocol the slave does not declare
  std::uint64_t too_large = 0;        //   data larger than the slave's mailbox
  std::uint64_t queue_full = 0;       //   the queue was full
  std::uint64_t timeouts = 0;         // requests the slave did not answer in time (no reply)
  std::uint64_t failed = 0;           // requests that could not run (no reply)
  std::uint64_t send_errors = 0;      // replies the socket refused
};

struct MailboxGatewayStatus {
  std::string address;     // where it listens, "127.0.0.1"
  std::uint16_t port = 0;  // the port bound (the one chosen when the configuration said 0)
  std::size_t queued = 0;
  std::size_t in_flight = 0;
  MailboxGatewayStats stats{};
};

// Where a gateway listens, as a ring file and `ecat serve --mailbox-gateway` write it: "ADDR:PORT",
// "ADDR" (port 34980) or "PORT" (loopback); ADDR an IPv4 address or "*". Sets address and port.
Result<void> parse_mailbox_gateway_address(std::string_view text, MailboxGatewayConfig& config);

class MailboxGateway {
 public:
  // Binds the socket and starts the threads. Errc::busy for a port in use, Errc::invalid_argument
  // for an address that is not an IPv4 address (or "*"), Errc::io_error otherwise. `master` must
  // outlive the gateway; the gateway calls its public API (slaves(), slave(), Slave calls).
  static Result<std::unique_ptr<MailboxGateway>> start(Master& master, MailboxGatewayConfig config);
  ~MailboxGateway();
  MailboxGateway(const MailboxGateway&) = delete;
  MailboxGateway& operator=(const MailboxGateway&) = delete;

  // Stops receiving, drops the queue and waits for the requests in flight (each bounded by the
  // request timeout). Idempotent.
  void stop();

  const MailboxGatewayConfig& config() const noexcept;
  MailboxGatewayStatus status() const;

  struct Impl;

 private:
  explicit MailboxGateway(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::master
