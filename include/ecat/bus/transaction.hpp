// Transactions: ordered groups of datagrams that the bus sends together and answers together.
//
// A Transaction is built on the caller's side with one method per EtherCAT command. Each method
// returns the datagram's slot (0, 1, 2, ... in call order); the result of the exchange is looked
// up by that slot. The bus may spread the datagrams of one transaction over several frames, but
// it always sends them in slot order, and it never reorders them against each other on a retry
// (a retry re-sends the whole transaction, in order).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <ecat/bus/transact_options.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::bus {

class Bus;

// One datagram as the caller asked for it.
struct DatagramRequest {
  wire::Command command = wire::Command::nop;
  // ADP | ADO << 16 for position, station and broadcast addressing (see wire::physical_address);
  // the 32-bit logical address for LRD/LWR/LRW.
  std::uint32_t address = 0;
  std::uint16_t length = 0;  // data bytes
  // Where this datagram's data starts in the transaction's payload.
  std::uint32_t data_offset = 0;
  // When set, the bus fails the transaction with Errc::wkc_mismatch if the reply's working
  // counter differs.
  std::optional<std::uint16_t> expected_wkc{};

  std::uint16_t adp() const noexcept { return static_cast<std::uint16_t>(address); }
  std::uint16_t ado() const noexcept { return static_cast<std::uint16_t>(address >> 16); }
};

// "FPRD station 0x1001 offset 0x0130 (2 bytes)", "APWR position 3 offset 0x0010 (2 bytes)",
// "BRD offset 0x0000 (1 byte)", "LRW logical 0x00010000 (12 bytes)", "NOP (0 bytes)".
std::string describe(const DatagramRequest& datagram);

class Transaction {
 public:
  Transaction() = default;

  // Auto-increment addressing: `position` is the slave's place in the ring (0 = first); the
  // datagram carries ADP = -position (wire::position_adp).
  std::size_t aprd(std::uint16_t position, std::uint16_t offset, std::uint16_t length,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t apwr(std::uint16_t position, std::uint16_t offset, wire::Bytes data,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t aprw(std::uint16_t position, std::uint16_t offset, wire::Bytes data,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  // Read at `position`, write the value read into every other slave.
  std::size_t armw(std::uint16_t position, std::uint16_t offset, std::uint16_t length,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);

  // Configured (station) addressing.
  std::size_t fprd(std::uint16_t station, std::uint16_t offset, std::uint16_t length,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t fpwr(std::uint16_t station, std::uint16_t offset, wire::Bytes data,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t fprw(std::uint16_t station, std::uint16_t offset, wire::Bytes data,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);
  // Read at `station`, write the value read into every other slave (DC reference time).
  std::size_t frmw(std::uint16_t station, std::uint16_t offset, std::uint16_t length,
                   std::optional<std::uint16_t> expected_wkc = std::nullopt);

  // Broadcast: every slave.
  std::size_t brd(std::uint16_t offset, std::uint16_t length,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t bwr(std::uint16_t offset, wire::Bytes data,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t brw(std::uint16_t offset, wire::Bytes data,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);

  // Logical addressing through the slaves' FMMUs.
  std::size_t lrd(std::uint32_t logical, std::uint16_t length,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t lwr(std::uint32_t logical, wire::Bytes data,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);
  std::size_t lrw(std::uint32_t logical, wire::Bytes data,
                  std::optional<std::uint16_t> expected_wkc = std::nullopt);

  // A datagram no slave acts on (padding, link tests).
  std::size_t nop(std::uint16_t length = 0);

  // Any command with a raw address; `data` empty means `length` zero bytes, otherwise `length`
  // must equal data.size().
  std::size_t add(wire::Command command, std::uint32_t address, std::uint16_t length,
                  wire::Bytes data = {}, std::optional<std::uint16_t> expected_wkc = std::nullopt);

  // Sets (or replaces) the expected working counter of a datagram already added.
  void expect_wkc(std::size_t slot, std::uint16_t wkc);

  std::size_t size() const noexcept { return datagrams_.size(); }
  bool empty() const noexcept { return datagrams_.empty(); }
  std::span<const DatagramRequest> datagrams() const noexcept { return datagrams_; }
  // The data a datagram carries to the segment (zeros for reads).
  wire::Bytes data(std::size_t slot) const noexcept;
  wire::MutableBytes mutable_data(std::size_t slot) noexcept;
  std::size_t payload_size() const noexcept { return payload_.size(); }
  // Bytes the datagrams occupy in frames (headers and working counters included).
  std::size_t wire_size() const noexcept;

  // The first mistake made while building (a length over 2047 bytes, an unknown slot passed to
  // expect_wkc, ...). The bus refuses a transaction that has one, with this error.
  const std::optional<Error>& error() const noexcept { return error_; }

  void reserve(std::size_t datagrams, std::size_t payload_bytes);
  void clear() noexcept;

 private:
  std::size_t push(wire::Command command, std::uint32_t address, std::size_t length,
                   wire::Bytes data, std::optional<std::uint16_t> expected_wkc);
  void fail(std::string message);

  std::vector<DatagramRequest> datagrams_;
  std::vector<std::uint8_t> payload_;
  std::optional<Error> error_;
};

// The reply to one datagram.
struct DatagramResult {
  wire::Bytes data;  // points into the TransactionResult that produced it
  std::uint16_t wkc = 0;
  bool circulating = false;
  std::uint16_t irq = 0;
};

// The replies to a whole transaction, by slot.
class TransactionResult {
 public:
  TransactionResult() = default;

  std::size_t size() const noexcept { return entries_.size(); }
  // An empty DatagramResult (no data, wkc 0) for a slot the transaction did not have.
  DatagramResult operator[](std::size_t slot) const noexcept;
  wire::Bytes data(std::size_t slot) const noexcept { return (*this)[slot].data; }
  std::uint16_t wkc(std::size_t slot) const noexcept { return (*this)[slot].wkc; }
  bool circulating(std::size_t slot) const noexcept { return (*this)[slot].circulating; }
  std::uint16_t irq(std::size_t slot) const noexcept { return (*this)[slot].irq; }

 private:
  friend class Bus;
  struct Entry {
    std::uint32_t offset = 0;
    std::uint16_t length = 0;
    std::uint16_t wkc = 0;
    std::uint16_t irq = 0;
    bool circulating = false;
  };
  std::vector<Entry> entries_;
  std::vector<std::uint8_t> data_;
};

}  // namespace ecat::bus
