// Slave's FoE calls and the bootstrap mailbox (Slave::Impl's part of them: slave_impl.hpp).
//
// BOOTSTRAP is entered and left only through go_to (the one AL path table and the slave's
// transition table): go_to calls enter_boot_mailbox() before the step INIT -> BOOT, because a
// slave checks its mailbox SyncManagers against the SII's *bootstrap* mailbox on that step
// (refusing with 0x0015 otherwise), and leave_boot_mailbox() after BOOT -> INIT, so that the next
// INIT -> PREOP finds the standard mailbox again (0x0016 otherwise).
//
// update_firmware holds the slave for its whole length (firmware_update, and `busy` for the
// health loop): go_to refuses every other caller with Errc::busy, so neither the session's retry
// loop (which walks slaves back to their target when a domain or a slave is faulted) nor
// Slave::request can pull the slave out of BOOTSTRAP under the transfer. The update itself walks
// through walk_to, go_to's body. At the end the slave is rebuilt as after a reconnect (bring_up:
// SII, mailbox, PREOP, configuration) and the master is told (SlaveNotice::reconnected), which
// brings it back to its target.
#include <algorithm>
#include <array>
#include <chrono>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/foe.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "blocking.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

namespace reg = wire::reg;
using namespace std::chrono_literals;

namespace {

// How long a caller waits for a transfer of `bytes` at most: every packet may take its timeout
// twice (the Mailbox's repeat request) plus one run of BUSY. Only a bound for the blocking call;
// the transfer's own timeouts end it first.
std::chrono::nanoseconds transfer_bound(std::size_t bytes, std::size_t packet,
                                        const FoeOptions& options) {
  const std::size_t packets = bytes / std::max<std::size_t>(packet, 1) + 3;
  const auto per_packet = options.timeout * 2 + options.busy_interval;
  return per_packet * static_cast<std::int64_t>(packets) + options.busy_timeout + 5s;
}

// The smallest FoE packet of the slave's mailboxes (1 when it has none): for transfer_bound.
std::size_t packet_hint(const Mailbox* standard, const Mailbox* boot) {
  std::size_t packet = 0;
  for (const Mailbox* m : {standard, boot}) {
    if (m == nullptr) continue;
    const std::size_t p = std::min(foe_write_packet_size(*m), foe_read_packet_size(*m));
    if (p != 0) packet = packet == 0 ? p : std::min(packet, p);
  }
  return std::max<std::size_t>(packet, 1);
}

}  // namespace

// ---- Impl: loop thread ------------------------------------------------------------------------

exec::Task<Result<void>> Slave::Impl::enter_boot_mailbox() {
  if (!sii) co_return ok();  // nothing known: the slave decides (and refuses without a mailbox)
  const auto& mbx = sii->decoded.image.bootstrap_mailbox;
  // Without a bootstrap mailbox the slave refuses BOOT itself (0x0013), which says it best.
  if (!mbx.present()) co_return ok();
  auto mc = co_await write_mailbox_sync_managers(session.loop, *session.bus, self.station(), mbx);
  if (!mc) {
    co_return mc.error().context(
        fmt::format("{}: writing the bootstrap mailbox SyncManagers", who()));
  }
  std::lock_guard lock(mutex);
  // Kept for the slave's life like the standard one (a transfer may still hold it).
  if (boot_mailbox && boot_mailbox->config() == *mc) {
    boot_mailbox->reset();
  } else {
    boot_mailbox = std::make_unique<Mailbox>(session.loop, *session.bus, self.station(), *mc);
  }
  co_return ok();
}

exec::Task<Result<void>> Slave::Impl::leave_boot_mailbox() {
  if (!sii) co_return ok();
  const auto& mbx = sii->decoded.image.standard_mailbox;
  if (!mbx.present()) co_return ok();
  auto mc = co_await write_mailbox_sync_managers(session.loop, *session.bus, self.station(), mbx);
  if (!mc) {
    co_return mc.error().context(
        fmt::format("{}: writing the standard mailbox SyncManagers after BOOTSTRAP", who()));
  }
  // The slave counts its messages from the start again.
  if (mailbox) mailbox->reset();
  co_return ok();
}

Result<Mailbox*> Slave::Impl::foe_mailbox() const {
  const auto s = state();
  if (s == SlaveState::down) return Error(Errc::wrong_state, fmt::format("{} is down", who()));
  if (!sii) return Error(Errc::not_ready, fmt::format("{}: SII not read yet", who()));
  const auto protocols = sii->decoded.image.mailbox_protocols;
  if ((protocols & wire::mailbox_protocol::kFoe) == 0) {
    return Error(Errc::unsupported,
                 fmt::format("{} does not support FoE (its SII declares mailbox protocols "
                             "0x{:04x})",
                             who(), protocols));
  }
  if (s == SlaveState::bootstrap) {
    if (!boot_mailbox) {
      return Error(Errc::wrong_state,
                   fmt::format("{}: in BOOTSTRAP, but its bootstrap mailbox was not configured by "
                               "this master (request INIT, then BOOTSTRAP)",
                               who()));
    }
    return boot_mailbox.get();
  }
  if (s == SlaveState::init) {
    return Error(
        Errc::wrong_state,
        fmt::format("{}: FoE needs PREOP or higher, or BOOTSTRAP; the slave is in INIT", who()));
  }
  if (!mailbox) return Error(Errc::unsupported, fmt::format("{} has no mailbox", who()));
  return mailbox.get();
}

exec::Task<Result<void>> Slave::Impl::firmware_update_task(std::string name,
                                                           std::vector<std::uint8_t> image,
                                                           FoeOptions options,
                                                           std::shared_ptr<Session> keep) {
  if (awaiting_rebuild()) co_return Error(Errc::wrong_state, fmt::format("{} is down", who()));
  if (!sii) co_return Error(Errc::not_ready, fmt::format("{}: SII not read yet", who()));
  const auto& sii_image = sii->decoded.image;
  if ((sii_image.mailbox_protocols & wire::mailbox_protocol::kFoe) == 0) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: firmware update needs FoE, which its SII does not declare "
                                "(mailbox protocols 0x{:04x})",
                                who(), sii_image.mailbox_protocols));
  }
  if (!sii_image.bootstrap_mailbox.present()) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: firmware update needs BOOTSTRAP, and its SII declares no "
                                "bootstrap mailbox",
                                who()));
  }
  if (firmware_update) {
    co_return Error(Errc::busy, fmt::format("{}: a firmware update is already running", who()));
  }
  // The hold (see the top of this file), released before the master is told.
  struct Hold {
    Impl& impl;
    explicit Hold(Impl& i) : impl(i) {
      impl.firmware_update = true;
      ++impl.busy;
    }
    ~Hold() {
      impl.firmware_update = false;
      --impl.busy;
    }
    Hold(const Hold&) = delete;
    Hold& operator=(const Hold&) = delete;
  };
  std::optional<Error> failure;
  bool rebuilt = false;
  {
    Hold hold(*this);
    auto init = co_await walk_to(wire::AlState::init, keep);
    if (!init) co_return init.error().context(fmt::format("{}: firmware update", who()));
    auto boot = co_await walk_to(wire::AlState::bootstrap, keep);
    if (!boot) {
      failure = boot.error().context(fmt::format("{}: firmware update: entering BOOTSTRAP", who()));
    } else if (!boot_mailbox) {
      failure = Error(
          Errc::internal,
          fmt::format("{}: firmware update: in BOOTSTRAP without a bootstrap mailbox", who()));
    } else {
      auto written = co_await master::foe_write(*boot_mailbox, name, std::move(image), options);
      note_mailbox_counters();
      if (!written) failure = std::move(written).error();
    }
    // Back to INIT in every case: the device starts its (new, or on failure its old) image.
    auto back = co_await walk_to(wire::AlState::init, keep);
    if (!back && !failure) {
      failure = back.error().context(
          fmt::format("{}: firmware update: returning to INIT after the transfer", who()));
    }
    if (back) {
      // A restarted device: rebuilt as after a reconnect (SII, mailbox, PREOP, configuration).
      auto up = co_await bring_up(keep);
      if (up) up = co_await reinit_dc();
      if (!up) {
        // Left to the health loop's rebuild, as a failed reconnect is.
        rebuild_pending = true;
        raise_fault(fmt::format("rebuild after firmware update failed: {}", up.error().describe()));
        if (!failure) {
          failure = up.error().context(
              fmt::format("{}: firmware update: bringing the slave up again", who()));
        }
      } else {
        rebuilt = true;
      }
    }
  }
  if (rebuilt && session.notify) {
    session.notify({SlaveNotice::Kind::reconnected, self.name(),
                    failure ? "firmware update failed: back in PREOP with its old image"
                            : "firmware updated: restarted and rebuilt to PREOP"});
  }
  if (failure) co_return std::move(*failure);
  co_return ok();
}

// ---- Slave: public, any thread ------------------------------------------------------------------

Result<std::vector<std::uint8_t>> Slave::foe_read(std::string_view name) {
  return foe_read(name, FoeOptions{});
}

Result<std::vector<std::uint8_t>> Slave::foe_read(std::string_view name,
                                                  const FoeOptions& options) {
  std::size_t packet = 1;
  {
    std::lock_guard lock(impl_->mutex);
    packet = packet_hint(impl_->mailbox.get(), impl_->boot_mailbox.get());
  }
  const auto bound = transfer_bound(options.max_read_size, packet, options);
  auto task = [](Impl& impl, std::string n, FoeOptions o,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<std::vector<std::uint8_t>>> {
    (void)keep;
    auto mailbox = impl.foe_mailbox();
    if (!mailbox) co_return mailbox.error();
    auto file = co_await master::foe_read(**mailbox, n, std::move(o));
    impl.note_mailbox_counters();
    co_return file;
  };
  return blocking(impl_->session,
                  task(*impl_, std::string(name), options, impl_->session.shared_from_this()),
                  bound, fmt::format("FoE read of '{}' from slave {}", name, name_));
}

Result<void> Slave::foe_write(std::string_view name, std::vector<std::uint8_t> data) {
  return foe_write(name, std::move(data), FoeOptions{});
}

Result<void> Slave::foe_write(std::string_view name, std::vector<std::uint8_t> data,
                              const FoeOptions& options) {
  std::size_t packet = 1;
  {
    std::lock_guard lock(impl_->mutex);
    packet = packet_hint(impl_->mailbox.get(), impl_->boot_mailbox.get());
  }
  const auto bound = transfer_bound(data.size(), packet, options);
  auto task = [](Impl& impl, std::string n, std::vector<std::uint8_t> d, FoeOptions o,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<void>> {
    (void)keep;
    auto mailbox = impl.foe_mailbox();
    if (!mailbox) co_return mailbox.error();
    auto done = co_await master::foe_write(**mailbox, n, std::move(d), std::move(o));
    impl.note_mailbox_counters();
    co_return done;
  };
  return blocking(
      impl_->session,
      task(*impl_, std::string(name), std::move(data), options, impl_->session.shared_from_this()),
      bound, fmt::format("FoE write of '{}' to slave {}", name, name_));
}

Result<void> Slave::update_firmware(std::string_view name, std::vector<std::uint8_t> image) {
  return update_firmware(name, std::move(image), FoeOptions{});
}

Result<void> Slave::update_firmware(std::string_view name, std::vector<std::uint8_t> image,
                                    const FoeOptions& options) {
  std::size_t packet = 1;
  {
    std::lock_guard lock(impl_->mutex);
    packet = packet_hint(impl_->mailbox.get(), impl_->boot_mailbox.get());
  }
  // The transfer, and the state changes and the rebuild around it.
  const auto bound = transfer_bound(image.size(), packet, options) + 60s;
  return blocking(impl_->session,
                  impl_->firmware_update_task(std::string(name), std::move(image), options,
                                              impl_->session.shared_from_this()),
                  bound, fmt::format("firmware update of slave {}", name_));
}

}  // namespace ecat::master
