// Reading a slave's SII EEPROM through its ESC's EEPROM interface (0x0500..0x050F), from a task on
// the control thread. Many slaves can be read at once (exec::when_all): their datagrams share
// frames, so reading 16 slaves costs about as many round trips as reading one.
//
// Per chunk (4 or 8 bytes, as the ESC's data register holds; 0x0502 bit 6): wait until the
// interface is not busy, clear stale error bits (NOP command), then one transaction writes the word
// address (0x0504) and the read command (0x0502 = 0x0100) and reads status and data back in the
// same frame. An ESC that is still busy is polled (status + data, back to back or every
// poll_interval) until it is done or busy_timeout has passed. A missing-acknowledge error is
// retried; checksum and device-information errors are reported by name.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {

struct SiiReadOptions {
  // How long one EEPROM command may keep the interface busy (and how long a busy interface is
  // waited for before a command is issued).
  std::chrono::nanoseconds busy_timeout = std::chrono::milliseconds(100);
  // Pause between two polls of a busy interface; zero polls back to back (each poll is a round
  // trip, so the loop thread never sleeps either way).
  std::chrono::nanoseconds poll_interval{0};
  // Retries of a read the EEPROM did not acknowledge (0x0502 bit 13).
  unsigned acknowledge_retries = 10;
  // read_sii: the most bytes the category walk may read before it gives up (an EEPROM without
  // an end marker, or with a corrupt category size).
  std::size_t max_image_bytes = 64 * 1024;
  // Take the EEPROM for EtherCAT (0x0500 = 0) before reading, in case the PDI holds it.
  bool take_ecat_access = true;
  // The ESC's checksum error (0x0502 bit 11) reports a bad CRC of the ESC configuration area; the
  // EEPROM can still be read. By default it fails the read (the image is not trustworthy).
  bool ignore_checksum_error = false;
  // For every transaction.
  bus::TransactOptions transact{};
};

struct SiiReadResult {
  // Words 0 up to and including the end-of-categories marker (0xFFFF).
  std::vector<std::uint8_t> bytes;
  wire::SiiDecoded decoded;
};

// Reads `word_count` words from `word_address`: 2 * word_count bytes. Errors name the station, the
// word address and the register value that was wrong.
exec::Task<Result<std::vector<std::uint8_t>>> read_sii_words(exec::EventLoop& loop, bus::Bus& bus,
                                                             std::uint16_t station,
                                                             std::uint32_t word_address,
                                                             std::size_t word_count,
                                                             SiiReadOptions options = {});

// Reads the fixed header, then walks the categories until the end marker, reading no more than
// needed; returns the bytes and their decoding. Fails with Errc::out_of_range naming
// max_image_bytes when no end marker comes before that limit.
exec::Task<Result<SiiReadResult>> read_sii(exec::EventLoop& loop, bus::Bus& bus,
                                           std::uint16_t station, SiiReadOptions options = {});

}  // namespace ecat::master
