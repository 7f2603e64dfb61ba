// The EtherCAT mailbox gateway datagram (ETG.8200): how a configuration tool outside the segment
// hands one mailbox message to the master, which forwards it to a slave's mailbox and returns the
// slave's reply the same way.
//
// Layout (little-endian), one message per UDP datagram, UDP port 0x88A4 (34980) by default:
//   EtherCAT header(2)  length[10:0] | reserved[11] | type[15:12]; type 5 = mailbox
//                       communication; length = the bytes of the mailbox message that follows
//   mailbox header(6)   as in wire/mailbox.hpp; its address field names the slave by its
//                       configured station address (0: the master itself)
//   mailbox data(length field of the mailbox header)
//
// Sources (read for facts): the ETG.8200 summary of ethercat.org (UDP mandatory, TCP optional);
// KickCAT's Gateway.cc / protocol.h (EthercatType MAILBOX = 0x5, "EtherCAT gateway"; the 11-bit
// length covers the mailbox header and data; UDP port 0x88A4 "defined in ETG 8200"); the
// etherlab-dev "ethercat_mbg" thread (2019-2021), whose captures show requests such as
// `10 50 | 0a 00 e9 03 00 23 | ...` (EtherCAT header 0x5010: length 16 = 6 + 10, type 5; mailbox
// to station 0x03e9, CoE, counter 2) and replies framed the same way.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::wire {

constexpr std::uint16_t kMailboxGatewayPort = 0x88A4;  // 34980, the ETG.8200 UDP port
constexpr std::uint8_t kEtherCatTypeMailbox = 5;       // EtherCAT header type of a gateway message
constexpr std::size_t kMailboxGatewayHeaderSize = 2;   // the EtherCAT header before the mailbox
// The EtherCAT header's length field has 11 bits: a gateway message carries at most 2047 bytes of
// mailbox (header included).
constexpr std::size_t kMaxGatewayMailboxSize = 0x7FF;

// A decoded gateway datagram. `mailbox` views the whole message (6 + header.length bytes, as it
// would sit in a SyncManager), `data` only what follows the mailbox header.
struct GatewayMessage {
  MailboxHeader header{};
  Bytes mailbox{};
  Bytes data{};
};

// Decodes one datagram: an EtherCAT header of type 5 whose length is at least 6 and fits the
// bytes present, then a mailbox whose header's length fits that length. Bytes after it (within the
// EtherCAT length or after it) are padding and ignored. Errors (Errc::truncated, Errc::malformed,
// Errc::unsupported for another EtherCAT type) name the field and both numbers.
Result<GatewayMessage> decode_gateway_message(Bytes datagram);

// Writes the EtherCAT header and the mailbox (header with length = data.size(), then the data) to
// the start of `out`; returns 2 + 6 + data.size(). Errc::invalid_argument when the mailbox header
// does not encode or the message exceeds 2047 bytes; Errc::out_of_range when `out` is too small.
Result<std::size_t> encode_gateway_message(MailboxHeader header, Bytes data, MutableBytes out);
// Same, into a new vector of exactly that size.
Result<std::vector<std::uint8_t>> encode_gateway_message(MailboxHeader header, Bytes data);

}  // namespace ecat::wire
