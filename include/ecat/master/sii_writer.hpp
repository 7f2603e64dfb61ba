// Writing a slave's SII EEPROM through its ESC's EEPROM interface (0x0500..0x050F), from a task on
// the control thread: what IgH's `ethercat sii_write` / `ethercat alias` and SOEM's eepromtool do.
//
// Per word (ESC datasheets, section II, "SII EEPROM interface"; the same order as SOEM's
// ecx_writeeepromFP and IgH's fsm_sii.c):
//   1. wait until the interface is not busy (0x0502 bit 15); clear a pending acknowledge or
//      write-enable error with the NOP command (0x0502 = 0x0000): the ESC ignores commands while
//      the acknowledge error is pending;
//   2. one transaction: the word into the data register (0x0508, 2 bytes), the word address
//      (0x0504, 4 bytes), then the control register with write enable (bit 0) and the write
//      command (bits 8..10 = 2) in ONE write, 0x0201 (the write enable is self-clearing at the
//      next frame, so it must come with the command), and the status read back;
//   3. poll 0x0502 until busy clears (the EEPROM's write cycle, up to 5 ms for 24Cxx EEPROMs)
//      or busy_timeout passed;
//   4. bit 14 (write enable error) fails the write; bit 13 (acknowledge error: the EEPROM did not
//      answer, as it does while an earlier write cycle still runs) is cleared and the word
//      written again, up to acknowledge_retries times.
// Afterwards every written word is read back and compared.
//
// Only words that differ from the EEPROM's are written (unless force_all). When any word of the
// ESC configuration area (words 0..7) is written, word 7 gets the CRC-8 of words 0..6 in its low
// byte (wire::sii_crc8), so the ESC loads the area at the next power-up.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

// Which slave: by configured station address (FPRD/FPWR) or by ring position (APRD/APWR), for
// tools that run without a session and before stations are assigned.
struct SiiTarget {
  enum class Addressing : std::uint8_t { station, position };
  Addressing addressing = Addressing::station;
  std::uint16_t value = 0;

  static SiiTarget station(std::uint16_t station) noexcept {
    return {Addressing::station, station};
  }
  static SiiTarget position(std::uint16_t position) noexcept {
    return {Addressing::position, position};
  }
};

struct SiiWriteProgress {
  std::size_t done = 0;    // words handled (written or found unchanged) so far
  std::size_t total = 0;   // words to handle
  std::uint32_t word = 0;  // the word just handled
};

struct SiiWriteOptions {
  // Write every word, also those the EEPROM already holds.
  bool force_all = false;
  // Recompute word 7 (checksum of the ESC configuration area) when any of words 0..7 is written.
  // Off: word 7 is written as given (a test that wants a broken checksum).
  bool fix_checksum = true;
  // Read every written word back and compare.
  bool verify = true;
  // Take the EEPROM for EtherCAT first (0x0500 = 0x02, forcing the PDI off, then 0x00, as SOEM's
  // ecx_eeprom2master does), in case the PDI holds it.
  bool take_ecat_access = true;
  // write_sii_alias only: also write the alias register 0x0012 so that the alias takes effect
  // without a power cycle. Real ESCs (ET1100, ET1200, IP cores) have 0x0012 read-only from
  // EtherCAT (PDI r/w) and load it from word 4 only at power-up, not on a reload command: the
  // write then has working counter 0, and SiiWriteReport::alias_register says so. IgH does not
  // write the register either: after `ethercat alias` it only changes its own record of the
  // slave's alias ("TODO: read alias from register 0x0012" in fsm_master.c).
  bool write_alias_register = false;
  // How long one command may keep the interface busy (a write's EEPROM write cycle included),
  // and how long a busy interface is waited for before a command.
  std::chrono::nanoseconds busy_timeout = std::chrono::milliseconds(100);
  // Pause between two polls of a busy interface (zero: back to back).
  std::chrono::nanoseconds poll_interval = std::chrono::microseconds(500);
  // Retries of a command the EEPROM did not acknowledge (0x0502 bit 13), with a pause between.
  unsigned acknowledge_retries = 5;
  std::chrono::nanoseconds acknowledge_retry_delay = std::chrono::milliseconds(1);
  // Called after every word (control thread); long writes (a whole image: 1024 words at up to
  // 5 ms each) report their progress here.
  std::function<void(const SiiWriteProgress&)> progress;
  // For every transaction.
  bus::TransactOptions transact{};
};

struct SiiWriteReport {
  std::size_t words_written = 0;
  std::size_t words_unchanged = 0;  // skipped: the EEPROM held the value already
  bool checksum_written = false;    // word 7 was recomputed and written
  std::size_t eeprom_bytes = 0;     // the EEPROM size the write was checked against
  // 0x0502 before the write: bits 11 (checksum error) and 12 (device information not loaded)
  // report the last load of the configuration area.
  std::uint16_t status_before = 0;
  // write_sii_alias with write_alias_register: whether the ESC took the write of 0x0012.
  std::optional<bool> alias_register;
};

// Writes `words` from `word_address` on. Errc::invalid_argument for an empty write or one past
// the EEPROM (its size from SII word 0x3E, or 0x0502 bit 7 when that word is unusable); errors
// name the slave, the word and the register value that was wrong.
exec::Task<Result<SiiWriteReport>> write_sii_words(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target, std::uint32_t word_address,
                                                   std::vector<std::uint16_t> words,
                                                   SiiWriteOptions options = {});

// Writes a whole image from word 0 (little-endian bytes, as `ecat sii` reads and EEPROM files
// hold them). Errc::invalid_argument for an empty or odd-length image, or one larger than the
// EEPROM.
exec::Task<Result<SiiWriteReport>> write_sii_image(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target,
                                                   std::span<const std::uint8_t> image,
                                                   SiiWriteOptions options = {});

// The configured station alias: SII word 4, then the checksum word 7 (and 0x0012 when asked).
exec::Task<Result<SiiWriteReport>> write_sii_alias(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target, std::uint16_t alias,
                                                   SiiWriteOptions options = {});

}  // namespace ecat::master
