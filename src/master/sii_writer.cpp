#include <algorithm>
#include <array>
#include <map>
#include <string>
#include <utility>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/sii_writer.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {

namespace {

namespace sc = wire::sii_control;
namespace reg = wire::reg;

// Errors a NOP command clears; the checksum and device-information bits report the last load of
// the configuration area and stay until the next one.
constexpr std::uint16_t kClearableErrors = sc::kAcknowledgeError | sc::kWriteEnableError;
constexpr std::uint16_t kCommandWriteEnabled = sc::kCommandWrite | sc::kWriteEnable;  // 0x0201
// EEPROMs up to 16 kbit take one address byte (0x0502 bit 7 clear); the SII's size word 0x3E
// holds kbit - 1.
constexpr std::size_t kOneAddressByteMaxBytes = 2048;
constexpr std::size_t kTwoAddressBytesMaxBytes = 512 * 1024;  // 4 Mbit, the largest the ESCs take
constexpr std::uint32_t kConfigurationWords = wire::sii_word::kChecksum + 1;  // words 0..7

std::array<std::uint8_t, 2> le16(std::uint16_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8)};
}
std::array<std::uint8_t, 4> le32(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

std::string ms_text(std::chrono::nanoseconds d) {
  return fmt::format("{} ms", std::chrono::duration<double, std::milli>(d).count());
}

std::string target_text(SiiTarget t) {
  return t.addressing == SiiTarget::Addressing::station
             ? fmt::format("slave {:#06x}", t.value)
             : fmt::format("the slave at position {}", t.value);
}

// One slave's EEPROM interface for the duration of a write.
class SiiPort {
 public:
  SiiPort(exec::EventLoop& loop, bus::Bus& bus, SiiTarget target, const SiiWriteOptions& options)
      : loop_(loop), bus_(bus), target_(target), options_(options) {}

  std::uint16_t status() const noexcept { return status_; }
  std::size_t chunk_bytes() const noexcept { return (status_ & sc::kReadSize8) != 0 ? 8 : 4; }
  std::string who() const { return target_text(target_); }

  // Takes the EEPROM for EtherCAT (when asked) and reads the status.
  exec::Task<Result<void>> prepare() {
    bus::Transaction tx;
    if (options_.take_ecat_access) {
      const std::uint8_t force = wire::sii_access::kForceEcatAccess;
      const std::uint8_t ecat = 0;
      write(tx, reg::kSiiAccess, wire::Bytes(&force, 1));
      write(tx, reg::kSiiAccess, wire::Bytes(&ecat, 1));
    }
    const auto status_slot = read(tx, reg::kSiiControl, 2);
    auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
    if (!reply) {
      co_return reply.error().context(
          fmt::format("preparing the SII write of {} (0x0500/0x0502)", who()));
    }
    status_ = wire::load_le16(reply->data(status_slot).data());
    co_return ok();
  }

  // Writes one word (steps 1..4 of the header).
  exec::Task<Result<void>> write_word(std::uint32_t word, std::uint16_t value) {
    const unsigned attempts = options_.acknowledge_retries + 1;
    for (unsigned attempt = 1;; ++attempt) {
      if (auto ready = co_await ready_for_command(word, "write"); !ready) co_return ready.error();
      bus::Transaction tx;
      const auto data = le16(value);
      const auto address = le32(word);
      const auto command = le16(kCommandWriteEnabled);
      write(tx, reg::kSiiData, data);
      write(tx, reg::kSiiAddress, address);
      write(tx, reg::kSiiControl, command);
      const auto status_slot = read(tx, reg::kSiiControl, 2);
      auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
      if (!reply) co_return reply.error().context(where("write", word));
      status_ = wire::load_le16(reply->data(status_slot).data());
      if (auto idle = co_await wait_idle(word, "write", "after the write command"); !idle) {
        co_return idle.error();
      }
      if ((status_ & sc::kWriteEnableError) != 0) {
        co_return Error(Errc::io_error,
                        fmt::format("{}: the ESC refused the write command for lack of write "
                                    "enable (0x0502 = {:#06x}, bit 14)",
                                    where("write", word), status_));
      }
      if ((status_ & sc::kAcknowledgeError) != 0) {
        if (attempt < attempts) {
          co_await exec::sleep_for(loop_, options_.acknowledge_retry_delay);
          continue;
        }
        co_return Error(Errc::io_error,
                        fmt::format("{}: the EEPROM did not acknowledge the write ({} attempts, "
                                    "0x0502 = {:#06x}, bit 13)",
                                    where("write", word), attempts, status_));
      }
      co_return ok();
    }
  }

  // chunk_bytes() bytes from `word` on.
  exec::Task<Result<std::vector<std::uint8_t>>> read_chunk(std::uint32_t word) {
    const unsigned attempts = options_.acknowledge_retries + 1;
    for (unsigned attempt = 1;; ++attempt) {
      if (auto ready = co_await ready_for_command(word, "read"); !ready) co_return ready.error();
      bus::Transaction tx;
      const auto address = le32(word);
      const auto command = le16(sc::kCommandRead);
      write(tx, reg::kSiiAddress, address);
      write(tx, reg::kSiiControl, command);
      const auto status_slot = read(tx, reg::kSiiControl, 2);
      auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
      if (!reply) co_return reply.error().context(where("read", word));
      status_ = wire::load_le16(reply->data(status_slot).data());
      if (auto idle = co_await wait_idle(word, "read", "after the read command"); !idle) {
        co_return idle.error();
      }
      if ((status_ & sc::kAcknowledgeError) != 0) {
        if (attempt < attempts) {
          co_await exec::sleep_for(loop_, options_.acknowledge_retry_delay);
          continue;
        }
        co_return Error(Errc::io_error,
                        fmt::format("{}: the EEPROM did not acknowledge the read ({} attempts, "
                                    "0x0502 = {:#06x})",
                                    where("read", word), attempts, status_));
      }
      bus::Transaction fetch;
      const auto data_slot = read(fetch, reg::kSiiData, static_cast<std::uint16_t>(chunk_bytes()));
      auto data = co_await exec::transact(loop_, bus_, std::move(fetch), options_.transact);
      if (!data) co_return data.error().context(where("read", word));
      const auto bytes = data->data(data_slot);
      co_return std::vector<std::uint8_t>(bytes.begin(), bytes.end());
    }
  }

  // `count` words from `word` on.
  exec::Task<Result<std::vector<std::uint16_t>>> read_words(std::uint32_t word, std::size_t count) {
    std::vector<std::uint16_t> out;
    out.reserve(count + 4);
    while (out.size() < count) {
      auto chunk = co_await read_chunk(static_cast<std::uint32_t>(word + out.size()));
      if (!chunk) co_return chunk.error();
      for (std::size_t i = 0; i + 1 < chunk->size(); i += 2)
        out.push_back(wire::load_le16(&(*chunk)[i]));
    }
    out.resize(count);
    co_return out;
  }

  // Writes 0x0012 (the alias register); whether the ESC took it (working counter).
  exec::Task<Result<bool>> write_alias_register(std::uint16_t alias) {
    bus::Transaction tx;
    const auto bytes = le16(alias);
    const auto slot = target_.addressing == SiiTarget::Addressing::station
                          ? tx.fpwr(target_.value, reg::kStationAlias, bytes)
                          : tx.apwr(target_.value, reg::kStationAlias, bytes);
    auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
    if (!reply) co_return reply.error().context(fmt::format("writing 0x0012 of {}", who()));
    co_return reply->wkc(slot) == 1;
  }

 private:
  std::string where(const char* what, std::uint32_t word) const {
    return fmt::format("SII {} of {} word {:#06x}", what, who(), word);
  }

  std::size_t write(bus::Transaction& tx, std::uint16_t offset, wire::Bytes data) {
    return target_.addressing == SiiTarget::Addressing::station
               ? tx.fpwr(target_.value, offset, data, 1)
               : tx.apwr(target_.value, offset, data, 1);
  }
  std::size_t read(bus::Transaction& tx, std::uint16_t offset, std::uint16_t length) {
    return target_.addressing == SiiTarget::Addressing::station
               ? tx.fprd(target_.value, offset, length, 1)
               : tx.aprd(target_.value, offset, length, 1);
  }

  // Idle, with the clearable error bits cleared (the ESC ignores commands while the acknowledge
  // error is pending).
  exec::Task<Result<void>> ready_for_command(std::uint32_t word, const char* what) {
    if (auto idle = co_await wait_idle(word, what, "before the command could be issued"); !idle) {
      co_return idle.error();
    }
    if ((status_ & kClearableErrors) == 0) co_return ok();
    bus::Transaction tx;
    const auto nop = le16(sc::kCommandNop);
    write(tx, reg::kSiiControl, nop);
    const auto status_slot = read(tx, reg::kSiiControl, 2);
    auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
    if (!reply) co_return reply.error().context(where(what, word) + ": clearing EEPROM errors");
    status_ = wire::load_le16(reply->data(status_slot).data());
    if ((status_ & kClearableErrors) != 0) {
      co_return Error(Errc::io_error,
                      fmt::format("{}: the NOP command did not clear the EEPROM error bits "
                                  "(0x0502 = {:#06x})",
                                  where(what, word), status_));
    }
    co_return ok();
  }

  exec::Task<Result<void>> wait_idle(std::uint32_t word, const char* what, const char* when) {
    const auto deadline = exec::Clock::now() + options_.busy_timeout;
    while ((status_ & sc::kBusy) != 0) {
      if (exec::Clock::now() >= deadline) {
        co_return Error(
            Errc::timeout,
            fmt::format("{}: EEPROM interface busy for more than {} {} (0x0502 = "
                        "{:#06x})",
                        where(what, word), ms_text(options_.busy_timeout), when, status_));
      }
      if (options_.poll_interval > std::chrono::nanoseconds::zero()) {
        co_await exec::sleep_for(loop_, options_.poll_interval);
      }
      bus::Transaction tx;
      const auto status_slot = read(tx, reg::kSiiControl, 2);
      auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
      if (!reply) co_return reply.error().context(where(what, word));
      status_ = wire::load_le16(reply->data(status_slot).data());
    }
    co_return ok();
  }

  exec::EventLoop& loop_;
  bus::Bus& bus_;
  SiiTarget target_;
  const SiiWriteOptions& options_;
  std::uint16_t status_ = 0;
};

// The EEPROM's size in bytes: SII word 0x3E (kbit - 1) when it is plausible for the address
// algorithm 0x0502 bit 7 reports, else the largest that algorithm addresses.
std::size_t eeprom_bytes(std::uint16_t size_word, std::uint16_t status) {
  const std::size_t algorithm_max =
      (status & sc::kTwoAddressBytes) != 0 ? kTwoAddressBytesMaxBytes : kOneAddressByteMaxBytes;
  if (size_word == 0xFFFF) return algorithm_max;
  const std::size_t declared = (static_cast<std::size_t>(size_word) + 1) * 128;
  return std::min(declared, algorithm_max);
}

exec::Task<Result<SiiWriteReport>> write_words(exec::EventLoop& loop, bus::Bus& bus,
                                               SiiTarget target, std::uint32_t first,
                                               std::vector<std::uint16_t> words,
                                               SiiWriteOptions options,
                                               std::optional<std::uint16_t> alias_register) {
  const std::string who = target_text(target);
  if (words.empty()) {
    co_return Error(Errc::invalid_argument, fmt::format("SII write of {}: no words", who));
  }
  SiiPort port(loop, bus, target, options);
  if (auto prepared = co_await port.prepare(); !prepared) co_return prepared.error();
  SiiWriteReport report;
  report.status_before = port.status();
  if ((port.status() & sc::kEmulation) != 0) {
    co_return Error(Errc::unsupported,
                    fmt::format("SII write of {}: the PDI emulates the EEPROM (0x0502 = {:#06x}, "
                                "bit 5); it cannot be written through the ESC",
                                who, port.status()));
  }
  auto size_word = co_await port.read_words(wire::sii_word::kEepromSize, 1);
  if (!size_word) co_return size_word.error().context("reading the EEPROM size (SII word 0x3E)");
  report.eeprom_bytes = eeprom_bytes(size_word->front(), port.status());
  const std::size_t end_word = static_cast<std::size_t>(first) + words.size();
  if (end_word * 2 > report.eeprom_bytes) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("SII write of {}: words {:#06x}..{:#06x} ({} bytes) do not fit the "
                                "EEPROM of {} bytes (SII word 0x3E = {:#06x}, 0x0502 = {:#06x})",
                                who, first, end_word - 1, words.size() * 2, report.eeprom_bytes,
                                size_word->front(), port.status()));
  }

  // What the EEPROM holds now, for the words to write and, when the configuration area is
  // touched, for words 0..7 (the checksum covers words the caller may not write).
  std::map<std::uint32_t, std::uint16_t> wanted;
  for (std::size_t i = 0; i < words.size(); ++i)
    wanted[first + static_cast<std::uint32_t>(i)] = words[i];
  const bool touches_configuration = first < kConfigurationWords;
  if (touches_configuration && options.fix_checksum) {
    std::array<std::uint8_t, wire::kSiiChecksummedBytes> area{};
    std::optional<std::vector<std::uint16_t>> current;
    for (std::uint32_t w = 0; w < wire::sii_word::kChecksum; ++w) {
      std::uint16_t value = 0;
      if (auto it = wanted.find(w); it != wanted.end()) {
        value = it->second;
      } else {
        if (!current) {
          auto read = co_await port.read_words(0, wire::sii_word::kChecksum);
          if (!read) co_return read.error().context("reading the ESC configuration area");
          current = std::move(*read);
        }
        value = (*current)[w];
      }
      wire::store_le16(&area[w * 2], value);
    }
    // The high byte of word 7 is reserved (0).
    wanted[wire::sii_word::kChecksum] = wire::sii_crc8(wire::Bytes(area.data(), area.size()));
  }
  const std::uint32_t lowest = wanted.begin()->first;
  const std::uint32_t highest = wanted.rbegin()->first;
  std::vector<std::uint16_t> before;
  if (!options.force_all) {
    auto read = co_await port.read_words(lowest, highest - lowest + 1);
    if (!read) co_return read.error().context("reading the words to compare");
    before = std::move(*read);
  }

  SiiWriteProgress progress;
  progress.total = wanted.size();
  std::vector<std::uint32_t> written;
  for (const auto& [word, value] : wanted) {
    const bool same = !options.force_all && before[word - lowest] == value;
    if (same) {
      ++report.words_unchanged;
    } else {
      if (auto done = co_await port.write_word(word, value); !done) co_return done.error();
      ++report.words_written;
      written.push_back(word);
      if (word == wire::sii_word::kChecksum && touches_configuration && options.fix_checksum) {
        report.checksum_written = true;
      }
    }
    ++progress.done;
    progress.word = word;
    if (options.progress) options.progress(progress);
  }

  if (options.verify) {
    for (std::uint32_t word : written) {
      auto back = co_await port.read_words(word, 1);
      if (!back) co_return back.error().context("verifying the written words");
      if (back->front() != wanted[word]) {
        co_return Error(Errc::io_error,
                        fmt::format("SII write of {}: word {:#06x} reads back {:#06x} after "
                                    "writing {:#06x}",
                                    who, word, back->front(), wanted[word]));
      }
    }
  }
  if (alias_register) {
    auto took = co_await port.write_alias_register(*alias_register);
    if (!took) co_return took.error();
    report.alias_register = *took;
  }
  co_return report;
}

}  // namespace

exec::Task<Result<SiiWriteReport>> write_sii_words(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target, std::uint32_t word_address,
                                                   std::vector<std::uint16_t> words,
                                                   SiiWriteOptions options) {
  if (!words.empty() && words.size() - 1 > 0xFFFFFFFFu - word_address) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("SII write of {}: {} words from word {:#x} run past the 32-bit "
                                "word address space",
                                target_text(target), words.size(), word_address));
  }
  co_return co_await write_words(loop, bus, target, word_address, std::move(words),
                                 std::move(options), std::nullopt);
}

exec::Task<Result<SiiWriteReport>> write_sii_image(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target,
                                                   std::span<const std::uint8_t> image,
                                                   SiiWriteOptions options) {
  if (image.empty() || image.size() % 2 != 0) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("SII image for {}: {} bytes; an image is a whole number of "
                                "16-bit words",
                                target_text(target), image.size()));
  }
  if (image.size() > kTwoAddressBytesMaxBytes) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("SII image for {}: {} bytes, more than any ESC's EEPROM ({} "
                                "bytes)",
                                target_text(target), image.size(), kTwoAddressBytesMaxBytes));
  }
  std::vector<std::uint16_t> words(image.size() / 2);
  for (std::size_t i = 0; i < words.size(); ++i)
    words[i] = wire::load_le16(&image[i * 2]);
  co_return co_await write_words(loop, bus, target, 0, std::move(words), std::move(options),
                                 std::nullopt);
}

exec::Task<Result<SiiWriteReport>> write_sii_alias(exec::EventLoop& loop, bus::Bus& bus,
                                                   SiiTarget target, std::uint16_t alias,
                                                   SiiWriteOptions options) {
  std::optional<std::uint16_t> alias_register;
  if (options.write_alias_register) alias_register = alias;
  options.fix_checksum = true;  // an alias without its checksum is not loaded at power-up
  std::vector<std::uint16_t> words(1, alias);
  co_return co_await write_words(loop, bus, target, wire::sii_word::kStationAlias, std::move(words),
                                 std::move(options), alias_register);
}

}  // namespace ecat::master
