#include <algorithm>
#include <string>
#include <utility>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

namespace {

namespace sc = wire::sii_control;
namespace reg = wire::reg;

// Errors the master can clear with a NOP command; the checksum and device-information bits report
// how the EEPROM was loaded and stay until the next load.
constexpr std::uint16_t kClearableErrors = sc::kAcknowledgeError | sc::kWriteEnableError;

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

// One slave's EEPROM interface for the duration of a read.
class SiiAccess {
 public:
  SiiAccess(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station, SiiReadOptions options)
      : loop_(loop), bus_(bus), station_(station), options_(options) {}

  std::size_t chunk_bytes() const noexcept { return chunk_bytes_; }

  // Takes the EEPROM for EtherCAT and learns the data register size.
  exec::Task<Result<void>> prepare() {
    bus::Transaction tx;
    if (options_.take_ecat_access) {
      const std::uint8_t ecat = 0;
      tx.fpwr(station_, reg::kSiiAccess, wire::Bytes(&ecat, 1), 1);
    }
    const auto status_slot = tx.fprd(station_, reg::kSiiControl, 2, 1);
    auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
    if (!reply) {
      co_return reply.error().context(
          fmt::format("preparing the SII read of slave {:#06x} (0x0500/0x0502)", station_));
    }
    status_ = wire::load_le16(reply->data(status_slot).data());
    chunk_bytes_ = (status_ & sc::kReadSize8) != 0 ? 8 : 4;
    co_return ok();
  }

  // The chunk_bytes() bytes at `word`.
  exec::Task<Result<std::vector<std::uint8_t>>> read_chunk(std::uint32_t word) {
    const unsigned attempts = options_.acknowledge_retries + 1;
    for (unsigned attempt = 1;; ++attempt) {
      if ((status_ & sc::kBusy) != 0) {
        auto idle = co_await wait_idle(word, "before the read command could be issued");
        if (!idle) co_return idle.error();
      }
      if ((status_ & kClearableErrors) != 0) {
        auto cleared = co_await clear_errors(word);
        if (!cleared) co_return cleared.error();
      }
      // The checksum and device-information bits report how the EEPROM was loaded: they show
      // before any command (and some ESCs drop them from the status once a command ran).
      if (auto loaded = check_load_errors(word); !loaded) co_return loaded.error();
      bus::Transaction tx;
      const auto address = le32(word);
      const auto command = le16(sc::kCommandRead);
      tx.fpwr(station_, reg::kSiiAddress, address, 1);
      tx.fpwr(station_, reg::kSiiControl, command, 1);
      const auto status_slot = tx.fprd(station_, reg::kSiiControl, 2, 1);
      const auto data_slot =
          tx.fprd(station_, reg::kSiiData, static_cast<std::uint16_t>(chunk_bytes_), 1);
      auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
      if (!reply) co_return reply.error().context(where(word));
      status_ = wire::load_le16(reply->data(status_slot).data());
      const auto data = reply->data(data_slot);
      std::vector<std::uint8_t> bytes(data.begin(), data.end());
      if ((status_ & sc::kBusy) != 0) {
        // The status and data reads ride in the same frame, behind each other: once a poll sees
        // the interface idle, the data read after it is the finished chunk.
        auto done = co_await wait_idle(word, "after the read command", &bytes);
        if (!done) co_return done.error();
      }
      if ((status_ & sc::kAcknowledgeError) != 0) {
        if (attempt < attempts) continue;
        co_return Error(Errc::io_error,
                        fmt::format("{}: the EEPROM did not acknowledge the read ({} attempts, "
                                    "0x0502 = {:#06x})",
                                    where(word), attempts, status_));
      }
      if (auto loaded = check_load_errors(word); !loaded) co_return loaded.error();
      if ((status_ & sc::kWriteEnableError) != 0) {
        co_return Error(Errc::io_error, fmt::format("{}: EEPROM write enable error (0x0502 = "
                                                    "{:#06x})",
                                                    where(word), status_));
      }
      co_return bytes;
    }
  }

 private:
  Result<void> check_load_errors(std::uint32_t word) const {
    if ((status_ & sc::kDeviceInfoError) != 0) {
      return Error(Errc::io_error,
                   fmt::format("{}: EEPROM device information error, the ESC could not load its "
                               "configuration (0x0502 = {:#06x})",
                               where(word), status_));
    }
    if ((status_ & sc::kChecksumError) != 0 && !options_.ignore_checksum_error) {
      return Error(Errc::io_error,
                   fmt::format("{}: EEPROM checksum error in the ESC configuration area (0x0502 "
                               "= {:#06x})",
                               where(word), status_));
    }
    return ok();
  }

  std::string where(std::uint32_t word) const {
    return fmt::format("SII read of slave {:#06x} word {:#06x}", station_, word);
  }

  // Polls status (and data, when `data` is given) until the interface is idle.
  exec::Task<Result<void>> wait_idle(std::uint32_t word, const char* when,
                                     std::vector<std::uint8_t>* data = nullptr) {
    const auto deadline = exec::Clock::now() + options_.busy_timeout;
    while ((status_ & sc::kBusy) != 0) {
      if (exec::Clock::now() >= deadline) {
        co_return Error(Errc::timeout,
                        fmt::format("{}: EEPROM interface busy for more than {} {} (0x0502 = "
                                    "{:#06x})",
                                    where(word), ms_text(options_.busy_timeout), when, status_));
      }
      if (options_.poll_interval > std::chrono::nanoseconds::zero()) {
        co_await exec::sleep_for(loop_, options_.poll_interval);
      }
      bus::Transaction tx;
      const auto status_slot = tx.fprd(station_, reg::kSiiControl, 2, 1);
      std::size_t data_slot = 0;
      if (data != nullptr) {
        data_slot = tx.fprd(station_, reg::kSiiData, static_cast<std::uint16_t>(chunk_bytes_), 1);
      }
      auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
      if (!reply) co_return reply.error().context(where(word));
      status_ = wire::load_le16(reply->data(status_slot).data());
      if (data != nullptr) {
        const auto bytes = reply->data(data_slot);
        data->assign(bytes.begin(), bytes.end());
      }
    }
    co_return ok();
  }

  exec::Task<Result<void>> clear_errors(std::uint32_t word) {
    bus::Transaction tx;
    const auto nop = le16(sc::kCommandNop);
    tx.fpwr(station_, reg::kSiiControl, nop, 1);
    const auto status_slot = tx.fprd(station_, reg::kSiiControl, 2, 1);
    auto reply = co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
    if (!reply) co_return reply.error().context(where(word) + ": clearing EEPROM error bits");
    status_ = wire::load_le16(reply->data(status_slot).data());
    co_return ok();
  }

  exec::EventLoop& loop_;
  bus::Bus& bus_;
  std::uint16_t station_;
  SiiReadOptions options_;
  std::uint16_t status_ = 0;
  std::size_t chunk_bytes_ = 4;
};

// Reads chunks until `image` holds at least `bytes` bytes.
template <class TooLarge>
exec::Task<Result<void>> read_until(SiiAccess& access, std::vector<std::uint8_t>& image,
                                    std::size_t limit, const TooLarge& too_large,
                                    std::size_t bytes) {
  if (bytes > limit) co_return too_large(bytes);
  while (image.size() < bytes) {
    auto chunk = co_await access.read_chunk(static_cast<std::uint32_t>(image.size() / 2));
    if (!chunk) co_return chunk.error();
    image.insert(image.end(), chunk->begin(), chunk->end());
  }
  co_return ok();
}

}  // namespace

exec::Task<Result<std::vector<std::uint8_t>>> read_sii_words(exec::EventLoop& loop, bus::Bus& bus,
                                                             std::uint16_t station,
                                                             std::uint32_t word_address,
                                                             std::size_t word_count,
                                                             SiiReadOptions options) {
  if (word_count > 0 && word_count - 1 > 0xFFFFFFFFu - word_address) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("SII read of slave {:#06x}: {} words from word {:#x} run past the "
                                "32-bit word address space",
                                station, word_count, word_address));
  }
  std::vector<std::uint8_t> out;
  if (word_count == 0) co_return out;
  SiiAccess access(loop, bus, station, options);
  auto prepared = co_await access.prepare();
  if (!prepared) co_return prepared.error();
  const std::size_t wanted = word_count * 2;
  out.reserve(wanted + access.chunk_bytes());
  std::uint32_t word = word_address;
  while (out.size() < wanted) {
    auto chunk = co_await access.read_chunk(word);
    if (!chunk) co_return chunk.error();
    out.insert(out.end(), chunk->begin(), chunk->end());
    word += static_cast<std::uint32_t>(access.chunk_bytes() / 2);
  }
  out.resize(wanted);
  co_return out;
}

exec::Task<Result<SiiReadResult>> read_sii(exec::EventLoop& loop, bus::Bus& bus,
                                           std::uint16_t station, SiiReadOptions options) {
  SiiAccess access(loop, bus, station, options);
  auto prepared = co_await access.prepare();
  if (!prepared) co_return prepared.error();

  const std::size_t limit = options.max_image_bytes;
  std::vector<std::uint8_t> image;  // whole chunks from word 0, so chunk reads stay aligned
  std::string reading = "the fixed header";
  auto too_large = [&](std::size_t needed) {
    return Error(Errc::out_of_range,
                 fmt::format("SII of slave {:#06x}: no end marker within "
                             "SiiReadOptions::max_image_bytes ({} bytes): {} needs {} bytes",
                             station, limit, reading, needed));
  };
  if (auto got = co_await read_until(access, image, limit, too_large, wire::kSiiHeaderBytes); !got)
    co_return got.error();
  std::size_t word = wire::sii_word::kFirstCategory;
  for (;;) {
    reading = fmt::format("the category header at word {:#06x}", word);
    if (auto got = co_await read_until(access, image, limit, too_large, 2 * word + 2); !got)
      co_return got.error();
    const std::uint16_t type = wire::load_le16(&image[2 * word]);
    if (type == wire::sii_category::kEnd) {
      image.resize(2 * word + 2);
      break;
    }
    if (auto got = co_await read_until(access, image, limit, too_large, 2 * word + 4); !got)
      co_return got.error();
    const std::uint16_t size_words = wire::load_le16(&image[2 * word + 2]);
    reading = fmt::format("category {:#06x} ({}) at word {:#06x} with {} words", type,
                          wire::sii_category_name(type), word, size_words);
    word += 2 + static_cast<std::size_t>(size_words);
    if (2 * word + 2 > limit) co_return too_large(2 * word + 2);
  }

  auto decoded = wire::decode_sii(image);
  if (!decoded) {
    co_return decoded.error().context(
        fmt::format("decoding the SII of slave {:#06x} ({} bytes)", station, image.size()));
  }
  SiiReadResult result;
  result.bytes = std::move(image);
  result.decoded = std::move(*decoded);
  co_return result;
}

}  // namespace ecat::master
