// File access over EtherCAT, the master's side (ETG.1000.6 §5.8): reading and writing a slave's
// files over its Mailbox, from tasks on the control thread. Firmware updates write the image in
// BOOTSTRAP (Slave::update_firmware does the state changes around it).
//
//   auto file = co_await master::foe_read(mailbox, "config.bin", {.password = 0x1234});
//   auto done = co_await master::foe_write(mailbox, "firmware.efw", image);
//
// The exchange, as the slave stacks (SOES, Beckhoff) and masters (SOEM, IgH) run it:
//   write: WRQ(password, name) -> ACK(0); DATA(1) -> ACK(1); DATA(2) -> ACK(2) ...
//   read:  RRQ(password, name) -> DATA(1); ACK(1) -> DATA(2); ... ACK(n) ends it
// Every DATA packet but the last carries the most data the mailbox allows (its size minus the
// 6-byte mailbox and the 6-byte FoE header); a shorter packet ends the file, so a file whose size
// is an exact multiple of that ends with an empty DATA packet. The packet size is therefore not a
// choice: a smaller one would end the file early on the slave's side.
//
// BUSY from the slave (it is flashing, or not ready) means "ask again": the last packet is sent
// again after FoeOptions::busy_interval, for at most FoeOptions::busy_timeout in a row.
//
// Failures: an FoE ERROR from the slave ends the transfer with the slave's code and text, e.g.
//   "FoE write of 'firmware.efw' to slave 0x1001: error 0x800A no access rights: bad password"
// with an Errc by the code (not_found, permission_denied, wrong_state, out_of_range, else
// mailbox_error); foe_error_code(error) is the code. Anything else that breaks the protocol (a
// wrong packet number, an unexpected opcode, bytes that do not decode, another mailbox type, a
// file larger than FoeOptions::max_read_size) fails with a message naming it, and the master
// sends the slave an FoE ERROR (packet number wrong, illegal, disk full) so that it drops the
// transfer too. No reply within FoeOptions::timeout is Errc::timeout (the Mailbox first tries the
// SM1 repeat request, which recovers a reply lost on the wire); the slave is sent an ERROR then
// as well. A transfer is never retried from the middle: slaves check packet numbers and take a
// repeated DATA packet as an error, so after a failure the caller starts the transfer again.
//
// A transfer holds the mailbox for its whole length (other users of the mailbox queue behind it).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string_view>
#include <vector>

#include <ecat/exec/task.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

struct FoeOptions {
  // Sent with the read or write request; 0 when the file has none.
  std::uint32_t password = 0;
  // For each packet's reply.
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // How long a slave may keep answering BUSY (counted from the first BUSY of a run) before the
  // transfer fails with Errc::timeout, and the pause before the packet is sent again.
  std::chrono::nanoseconds busy_timeout = std::chrono::seconds(10);
  std::chrono::nanoseconds busy_interval = std::chrono::milliseconds(1);
  // Reads fail (Errc::out_of_range, the slave is sent ERROR disk full) once the file grows
  // beyond this: the bound of the memory a read takes.
  std::size_t max_read_size = 16 * 1024 * 1024;
  // Called on the control thread after every acknowledged packet: bytes done, and the file's
  // size when it is known (writes; reads learn it only at the end).
  std::function<void(std::size_t done, std::optional<std::size_t> total)> progress{};
};

// The file's contents.
exec::Task<Result<std::vector<std::uint8_t>>> foe_read(Mailbox& mailbox, std::string_view file_name,
                                                       FoeOptions options = {});

// Writes `data` as the file (an empty file is one empty DATA packet).
exec::Task<Result<void>> foe_write(Mailbox& mailbox, std::string_view file_name,
                                   std::vector<std::uint8_t> data, FoeOptions options = {});

// The FoE error code an FoE ERROR from the slave carried (searching the error's causes), or
// nullopt for any other failure.
std::optional<std::uint32_t> foe_error_code(const Error& error) noexcept;

// The most file data one DATA packet to (write) or from (read) this mailbox carries.
std::size_t foe_write_packet_size(const Mailbox& mailbox) noexcept;
std::size_t foe_read_packet_size(const Mailbox& mailbox) noexcept;

}  // namespace ecat::master
