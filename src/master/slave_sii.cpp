// Slave::write_sii / write_alias: writing a session slave's SII EEPROM (master/sii_writer.hpp).
//
// Which states: INIT and PREOP only. There the EtherCAT side normally owns the EEPROM and no
// process data depends on the device's configuration. In SAFEOP and OP the firmware may hold
// the EEPROM through its PDI (0x0500 bit 0 offered, 0x0501 bit 0 taken) and the writer would force
// it away from a running device (0x0500 bit 1), and a write cycle of up to 5 ms per word stalls
// nothing but still changes what the device loads at its next start under running I/O. A slave
// that is down, or busy walking AL states, is refused as well.
//
// After a write: the session's copy of the SII (what info(), the PDO layout and the identity
// check of a rebuild use) would be stale, so it is read again from the EEPROM, and the identity
// the session expects of this slave after a power cycle becomes the one now in the EEPROM (a
// repaired serial number must not make the next rebuild report "a different device"). The PREOP
// configuration already applied (PDO layout, driver) stays until the slave is configured again
// (Slave::configure, a rebuild, a new session). The alias register 0x0012 keeps its value until
// the ESC's next power-up; the session addresses its slaves by station, so nothing changes for it.
#include <chrono>
#include <utility>

#include <fmt/format.h>

#include <ecat/exec/task.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/master/sii_writer.hpp>
#include <ecat/master/slave.hpp>

#include "blocking.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

using namespace std::chrono_literals;

namespace {

// A generous bound for the blocking call: every word may take the busy timeout and its retries,
// twice over (the compare read and the write), plus the verify read.
std::chrono::nanoseconds write_timeout(std::size_t words, const SiiWriteOptions& options) {
  const auto per_word = options.busy_timeout * 3 * (options.acknowledge_retries + 1) +
                        options.acknowledge_retry_delay * options.acknowledge_retries;
  return per_word * static_cast<std::int64_t>(words + 16) + 5s;
}

enum class WriteKind : std::uint8_t { words, alias };

// A template only because Slave::Impl is private to Slave (the member functions below deduce it).
template <class SlaveImpl>
exec::Task<Result<void>> write_task(SlaveImpl& impl, WriteKind kind, std::uint32_t first,
                                    std::vector<std::uint16_t> words, SiiWriteOptions options,
                                    std::shared_ptr<Session> keep) {
  (void)keep;
  const auto station = impl.self.station();
  const auto state = impl.state();
  if (impl.awaiting_rebuild()) {
    co_return Error(Errc::wrong_state,
                    fmt::format("{} is down; its EEPROM cannot be written", impl.who()));
  }
  if (state != SlaveState::init && state != SlaveState::preop) {
    co_return Error(Errc::wrong_state,
                    fmt::format("{}: the EEPROM is written in INIT or PREOP only (the slave is in "
                                "{}; in SAFEOP and OP the device's PDI may own it)",
                                impl.who(), to_string(state)));
  }
  if (impl.busy > 0) {
    co_return Error(Errc::busy,
                    fmt::format("{}: an AL state change is in progress; the EEPROM write is "
                                "refused until it ends",
                                impl.who()));
  }
  // Keeps the health loop from polling (and a rebuild from reading the SII) meanwhile.
  struct Busy {
    int& count;
    explicit Busy(int& c) : count(c) { ++count; }
    ~Busy() { --count; }
    Busy(const Busy&) = delete;
    Busy& operator=(const Busy&) = delete;
  } busy_guard(impl.busy);

  auto& loop = impl.session.loop;
  auto& bus = *impl.session.bus;
  const std::uint16_t alias = words.empty() ? 0 : words.front();
  const bool want_register = options.write_alias_register;
  auto report =
      kind == WriteKind::alias
          ? co_await write_sii_alias(loop, bus, SiiTarget::station(station), alias, options)
          : co_await write_sii_words(loop, bus, SiiTarget::station(station), first,
                                     std::move(words), options);
  if (!report) co_return report.error().context(impl.who());

  auto reread = co_await read_sii(loop, bus, station);
  if (!reread) {
    co_return reread.error().context(fmt::format(
        "{}: the EEPROM was written, but reading it back for the session failed", impl.who()));
  }
  {
    std::lock_guard lock(impl.mutex);
    impl.sii = std::move(*reread);
    impl.known_identity = impl.sii->decoded.image.identity;
  }
  if (kind == WriteKind::alias && want_register && report->alias_register &&
      !*report->alias_register) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: SII word 4 holds alias {:#06x} now, but the ESC did not take "
                                "the write of its alias register 0x0012 (read-only from EtherCAT); "
                                "the alias takes effect at the next power-up",
                                impl.who(), alias));
  }
  co_return ok();
}

}  // namespace

Result<void> Slave::write_sii(std::span<const std::uint8_t> image) {
  return write_sii(image, SiiWriteOptions{});
}

Result<void> Slave::write_sii(std::span<const std::uint8_t> image, const SiiWriteOptions& options) {
  if (image.empty() || image.size() % 2 != 0) {
    return Error(Errc::invalid_argument,
                 fmt::format("SII image for slave {}: {} bytes; an image is a whole number of "
                             "16-bit words",
                             name_, image.size()));
  }
  std::vector<std::uint16_t> words(image.size() / 2);
  for (std::size_t i = 0; i < words.size(); ++i)
    words[i] = static_cast<std::uint16_t>(image[2 * i] | (image[2 * i + 1] << 8));
  return write_sii(0, std::move(words), options);
}

Result<void> Slave::write_sii(std::uint32_t word_address, std::vector<std::uint16_t> words) {
  return write_sii(word_address, std::move(words), SiiWriteOptions{});
}

Result<void> Slave::write_sii(std::uint32_t word_address, std::vector<std::uint16_t> words,
                              const SiiWriteOptions& options) {
  const auto timeout = write_timeout(words.size(), options);
  auto keep = impl_->session.shared_from_this();
  return blocking(
      impl_->session,
      write_task(*impl_, WriteKind::words, word_address, std::move(words), options, keep), timeout,
      fmt::format("SII write of slave {}", name_));
}

Result<void> Slave::write_alias(std::uint16_t alias) {
  return write_alias(alias, SiiWriteOptions{});
}

Result<void> Slave::write_alias(std::uint16_t alias, const SiiWriteOptions& options) {
  const auto timeout = write_timeout(2, options);
  auto keep = impl_->session.shared_from_this();
  std::vector<std::uint16_t> words(1, alias);
  return blocking(impl_->session,
                  write_task(*impl_, WriteKind::alias, 0, std::move(words), options, keep), timeout,
                  fmt::format("alias write of slave {}", name_));
}

}  // namespace ecat::master
