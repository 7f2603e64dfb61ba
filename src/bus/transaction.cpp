#include <algorithm>

#include <fmt/format.h>

#include <ecat/bus/transaction.hpp>

namespace ecat::bus {

namespace {

std::string byte_count(std::size_t n) {
  return fmt::format("{} byte{}", n, n == 1 ? "" : "s");
}

}  // namespace

std::string describe(const DatagramRequest& datagram) {
  const std::string_view name = wire::to_string(datagram.command);
  const std::string command =
      name.empty() ? fmt::format("command 0x{:02x}", static_cast<unsigned>(datagram.command))
                   : std::string(name);
  switch (wire::addressing_of(datagram.command)) {
    case wire::Addressing::position: {
      // ADP carries -position; negate back for the reader.
      const auto position = static_cast<std::uint16_t>(0x10000u - datagram.adp());
      return fmt::format("{} position {} offset 0x{:04x} ({})", command, position, datagram.ado(),
                         byte_count(datagram.length));
    }
    case wire::Addressing::station:
      return fmt::format("{} station 0x{:04x} offset 0x{:04x} ({})", command, datagram.adp(),
                         datagram.ado(), byte_count(datagram.length));
    case wire::Addressing::broadcast:
      return fmt::format("{} offset 0x{:04x} ({})", command, datagram.ado(),
                         byte_count(datagram.length));
    case wire::Addressing::logical:
      return fmt::format("{} logical 0x{:08x} ({})", command, datagram.address,
                         byte_count(datagram.length));
    case wire::Addressing::none:
      break;
  }
  return fmt::format("{} ({})", command, byte_count(datagram.length));
}

// ---------------------------------------------------------------------------------------------

void Transaction::fail(std::string message) {
  if (!error_) error_.emplace(Errc::invalid_argument, std::move(message));
}

std::size_t Transaction::push(wire::Command command, std::uint32_t address, std::size_t length,
                              wire::Bytes data, std::optional<std::uint16_t> expected_wkc) {
  DatagramRequest request;
  request.command = command;
  request.address = address;
  request.expected_wkc = expected_wkc;
  const std::size_t slot = datagrams_.size();
  if (static_cast<std::size_t>(command) >= wire::kCommandCount) {
    fail(fmt::format("datagram {}: command code 0x{:02x} is not an EtherCAT command", slot,
                     static_cast<unsigned>(command)));
    length = 0;
    data = {};
  }
  if (!data.empty() && data.size() != length) {
    request.length = 0;
    fail(fmt::format("datagram {} ({}): {} data bytes given for a length of {}", slot,
                     describe(request), data.size(), length));
    length = std::min(length, data.size());
  }
  if (length > wire::kMaxDatagramLength) {
    request.length = static_cast<std::uint16_t>(std::min<std::size_t>(length, 0xFFFF));
    fail(fmt::format("datagram {} ({}): length {} exceeds the {}-byte datagram limit", slot,
                     describe(request), length, wire::kMaxDatagramLength));
    // Keep the layout consistent (slot numbers stay valid) with a zero-length stand-in.
    length = 0;
    data = {};
  }
  request.length = static_cast<std::uint16_t>(length);
  request.data_offset = static_cast<std::uint32_t>(payload_.size());
  if (data.empty()) {
    payload_.resize(payload_.size() + length, 0);
  } else {
    payload_.insert(payload_.end(), data.begin(),
                    data.begin() + static_cast<std::ptrdiff_t>(length));
  }
  datagrams_.push_back(request);
  return slot;
}

std::size_t Transaction::aprd(std::uint16_t position, std::uint16_t offset, std::uint16_t length,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::aprd, wire::physical_address(wire::position_adp(position), offset),
              length, {}, expected_wkc);
}
std::size_t Transaction::apwr(std::uint16_t position, std::uint16_t offset, wire::Bytes data,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::apwr, wire::physical_address(wire::position_adp(position), offset),
              data.size(), data, expected_wkc);
}
std::size_t Transaction::aprw(std::uint16_t position, std::uint16_t offset, wire::Bytes data,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::aprw, wire::physical_address(wire::position_adp(position), offset),
              data.size(), data, expected_wkc);
}
std::size_t Transaction::armw(std::uint16_t position, std::uint16_t offset, std::uint16_t length,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::armw, wire::physical_address(wire::position_adp(position), offset),
              length, {}, expected_wkc);
}

std::size_t Transaction::fprd(std::uint16_t station, std::uint16_t offset, std::uint16_t length,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::fprd, wire::physical_address(station, offset), length, {},
              expected_wkc);
}
std::size_t Transaction::fpwr(std::uint16_t station, std::uint16_t offset, wire::Bytes data,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::fpwr, wire::physical_address(station, offset), data.size(), data,
              expected_wkc);
}
std::size_t Transaction::fprw(std::uint16_t station, std::uint16_t offset, wire::Bytes data,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::fprw, wire::physical_address(station, offset), data.size(), data,
              expected_wkc);
}
std::size_t Transaction::frmw(std::uint16_t station, std::uint16_t offset, std::uint16_t length,
                              std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::frmw, wire::physical_address(station, offset), length, {},
              expected_wkc);
}

std::size_t Transaction::brd(std::uint16_t offset, std::uint16_t length,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::brd, wire::physical_address(0, offset), length, {}, expected_wkc);
}
std::size_t Transaction::bwr(std::uint16_t offset, wire::Bytes data,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::bwr, wire::physical_address(0, offset), data.size(), data,
              expected_wkc);
}
std::size_t Transaction::brw(std::uint16_t offset, wire::Bytes data,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::brw, wire::physical_address(0, offset), data.size(), data,
              expected_wkc);
}

std::size_t Transaction::lrd(std::uint32_t logical, std::uint16_t length,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::lrd, logical, length, {}, expected_wkc);
}
std::size_t Transaction::lwr(std::uint32_t logical, wire::Bytes data,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::lwr, logical, data.size(), data, expected_wkc);
}
std::size_t Transaction::lrw(std::uint32_t logical, wire::Bytes data,
                             std::optional<std::uint16_t> expected_wkc) {
  return push(wire::Command::lrw, logical, data.size(), data, expected_wkc);
}

std::size_t Transaction::nop(std::uint16_t length) {
  return push(wire::Command::nop, 0, length, {}, std::nullopt);
}

std::size_t Transaction::add(wire::Command command, std::uint32_t address, std::uint16_t length,
                             wire::Bytes data, std::optional<std::uint16_t> expected_wkc) {
  return push(command, address, length, data, expected_wkc);
}

void Transaction::expect_wkc(std::size_t slot, std::uint16_t wkc) {
  if (slot >= datagrams_.size()) {
    fail(fmt::format("expect_wkc: slot {} does not exist (the transaction has {} datagrams)", slot,
                     datagrams_.size()));
    return;
  }
  datagrams_[slot].expected_wkc = wkc;
}

wire::Bytes Transaction::data(std::size_t slot) const noexcept {
  if (slot >= datagrams_.size()) return {};
  const auto& d = datagrams_[slot];
  return wire::Bytes{payload_.data() + d.data_offset, d.length};
}

wire::MutableBytes Transaction::mutable_data(std::size_t slot) noexcept {
  if (slot >= datagrams_.size()) return {};
  const auto& d = datagrams_[slot];
  return wire::MutableBytes{payload_.data() + d.data_offset, d.length};
}

std::size_t Transaction::wire_size() const noexcept {
  return payload_.size() + datagrams_.size() * wire::kDatagramOverhead;
}

void Transaction::reserve(std::size_t datagrams, std::size_t payload_bytes) {
  datagrams_.reserve(datagrams);
  payload_.reserve(payload_bytes);
}

void Transaction::clear() noexcept {
  datagrams_.clear();
  payload_.clear();
  error_.reset();
}

// ---------------------------------------------------------------------------------------------

DatagramResult TransactionResult::operator[](std::size_t slot) const noexcept {
  if (slot >= entries_.size()) return {};
  const Entry& e = entries_[slot];
  DatagramResult result;
  result.data = wire::Bytes{data_.data() + e.offset, e.length};
  result.wkc = e.wkc;
  result.circulating = e.circulating;
  result.irq = e.irq;
  return result;
}

}  // namespace ecat::bus
