#include <array>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {
namespace {

using wire::AlState;
namespace reg = wire::reg;

constexpr std::array kToPreop{AlState::preop};
constexpr std::array kToBoot{AlState::bootstrap};
constexpr std::array kToInit{AlState::init};
constexpr std::array kToSafeop{AlState::safeop};
constexpr std::array kToOp{AlState::op};
constexpr std::array kInitToSafeop{AlState::preop, AlState::safeop};
constexpr std::array kInitToOp{AlState::preop, AlState::safeop, AlState::op};
constexpr std::array kPreopToOp{AlState::safeop, AlState::op};
constexpr std::array kOpToPreop{AlState::safeop, AlState::preop};
constexpr std::array kOpToInit{AlState::safeop, AlState::preop, AlState::init};
constexpr std::array kBootToPreop{AlState::init, AlState::preop};
constexpr std::array kBootToSafeop{AlState::init, AlState::preop, AlState::safeop};
constexpr std::array kBootToOp{AlState::init, AlState::preop, AlState::safeop, AlState::op};
constexpr std::array kViaInitToBoot{AlState::init, AlState::bootstrap};
constexpr std::array kOpToBoot{AlState::safeop, AlState::preop, AlState::init, AlState::bootstrap};

// The reference design's path table (upstream-inventory §2.6) plus the ways into and out of BOOT
// that a slave accepts: BOOT is entered from INIT and left to INIT only, so every other way to or
// from it walks through INIT (the reference has only INIT <-> BOOT and BOOT -> PREOP).
constexpr std::array kPaths{
    AlPathRow{AlState::init, AlState::preop, kToPreop},
    AlPathRow{AlState::init, AlState::bootstrap, kToBoot},
    AlPathRow{AlState::init, AlState::safeop, kInitToSafeop},
    AlPathRow{AlState::init, AlState::op, kInitToOp},
    AlPathRow{AlState::bootstrap, AlState::init, kToInit},
    AlPathRow{AlState::bootstrap, AlState::preop, kBootToPreop},
    AlPathRow{AlState::bootstrap, AlState::safeop, kBootToSafeop},
    AlPathRow{AlState::bootstrap, AlState::op, kBootToOp},
    AlPathRow{AlState::preop, AlState::bootstrap, kViaInitToBoot},
    AlPathRow{AlState::safeop, AlState::bootstrap, kViaInitToBoot},
    AlPathRow{AlState::op, AlState::bootstrap, kOpToBoot},
    AlPathRow{AlState::preop, AlState::safeop, kToSafeop},
    AlPathRow{AlState::preop, AlState::op, kPreopToOp},
    AlPathRow{AlState::preop, AlState::init, kToInit},
    AlPathRow{AlState::safeop, AlState::op, kToOp},
    AlPathRow{AlState::safeop, AlState::preop, kToPreop},
    AlPathRow{AlState::safeop, AlState::init, kToInit},
    AlPathRow{AlState::op, AlState::safeop, kToSafeop},
    AlPathRow{AlState::op, AlState::preop, kOpToPreop},
    AlPathRow{AlState::op, AlState::init, kOpToInit},
};

Error al_refused(std::uint16_t station, AlState wanted, const wire::AlStatusBlock& status) {
  return Error(Errc::al_error,
               fmt::format("slave 0x{:04x} refused {} (now {}): AL status code 0x{:04x} {}",
                           station, wire::to_string(wanted), wire::to_string(status.status.state),
                           status.code, wire::al_status_code_text(status.code)))
      .with_value(status.code);
}

}  // namespace

std::span<const AlPathRow> al_path_table() noexcept {
  return kPaths;
}

std::optional<std::vector<AlState>> al_path(AlState from, AlState to) {
  if (from == to) return std::vector<AlState>{};
  for (const auto& row : kPaths) {
    if (row.from == from && row.to == to)
      return std::vector<AlState>(row.steps.begin(), row.steps.end());
  }
  return std::nullopt;
}

std::optional<std::uint16_t> al_status_code(const Error& error) noexcept {
  auto value = error.code_value(Errc::al_error);
  if (!value) return std::nullopt;
  return static_cast<std::uint16_t>(*value);
}

exec::Task<Result<wire::AlStatusBlock>> read_al_status(exec::EventLoop& loop, bus::Bus& bus,
                                                       std::uint16_t station,
                                                       bus::TransactOptions options) {
  bus::Transaction tx;
  tx.fprd(station, reg::kAlStatus, 6, 1);
  auto reply = co_await exec::transact(loop, bus, std::move(tx), options);
  if (!reply) {
    co_return reply.error().context(fmt::format("reading AL status of slave 0x{:04x}", station));
  }
  auto block = wire::decode_al_status_block(reply->data(0));
  if (!block) {
    co_return block.error().context(fmt::format("AL status of slave 0x{:04x}", station));
  }
  co_return *block;
}

namespace {

exec::Task<Result<void>> write_al_control(exec::EventLoop& loop, bus::Bus& bus,
                                          std::uint16_t station, std::uint16_t control,
                                          const AlOptions& options) {
  bus::Transaction tx;
  std::array<std::uint8_t, 2> data{};
  wire::store_le16(data.data(), control);
  tx.fpwr(station, reg::kAlControl, data, 1);
  auto reply = co_await exec::transact(
      loop, bus, std::move(tx), bus::TransactOptions{options.read_timeout, options.read_retries});
  if (!reply) {
    co_return reply.error().context(
        fmt::format("writing AL control 0x{:04x} to slave 0x{:04x}", control, station));
  }
  co_return ok();
}

}  // namespace

exec::Task<Result<wire::AlStatusBlock>> al_acknowledge(exec::EventLoop& loop, bus::Bus& bus,
                                                       std::uint16_t station, AlOptions options) {
  auto status = co_await read_al_status(
      loop, bus, station, bus::TransactOptions{options.read_timeout, options.read_retries});
  if (!status) co_return status.error();
  if (!status->status.error) co_return *status;
  auto written = co_await write_al_control(
      loop, bus, station, wire::encode_al_control(status->status.state, true), options);
  if (!written) co_return written.error();
  co_return co_await read_al_status(
      loop, bus, station, bus::TransactOptions{options.read_timeout, options.read_retries});
}

exec::Task<Result<void>> al_step(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station,
                                 AlState state, AlOptions options) {
  auto written =
      co_await write_al_control(loop, bus, station, wire::encode_al_control(state), options);
  if (!written) co_return written.error();
  const auto deadline = exec::Clock::now() + options.step_timeout;
  wire::AlStatusBlock last{};
  while (true) {
    auto status = co_await read_al_status(
        loop, bus, station, bus::TransactOptions{options.read_timeout, options.read_retries});
    if (!status) co_return status.error();
    last = *status;
    if (last.status.error) {
      // Acknowledge so the slave accepts the next request, but report what it refused with.
      auto acked = co_await write_al_control(
          loop, bus, station, wire::encode_al_control(last.status.state, true), options);
      Error refused = al_refused(station, state, last);
      if (!acked) co_return refused.context(acked.error().message());
      co_return refused;
    }
    if (last.status.state == state) co_return ok();
    if (exec::Clock::now() >= deadline) break;
    co_await exec::sleep_for(loop, options.poll_interval);
  }
  co_return Error(
      Errc::timeout,
      fmt::format(
          "slave 0x{:04x} did not reach {} within {} ms (still {})", station,
          wire::to_string(state),
          std::chrono::duration_cast<std::chrono::milliseconds>(options.step_timeout).count(),
          wire::to_string(last.status.state)));
}

exec::Task<Result<AlState>> al_request(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station,
                                       AlState target, AlOptions options) {
  auto status = co_await read_al_status(
      loop, bus, station, bus::TransactOptions{options.read_timeout, options.read_retries});
  if (!status) co_return status.error();
  if (status->status.error) {
    auto acked = co_await al_acknowledge(loop, bus, station, options);
    if (!acked) co_return acked.error();
    status = *acked;
  }
  const AlState from = status->status.state;
  auto path = al_path(from, target);
  if (!path) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("slave 0x{:04x}: no AL path from {} to {}", station,
                                wire::to_string(from), wire::to_string(target)));
  }
  for (AlState step : *path) {
    auto stepped = co_await al_step(loop, bus, station, step, options);
    if (!stepped) {
      co_return stepped.error().context(fmt::format("requesting {} of slave 0x{:04x} (from {})",
                                                    wire::to_string(target), station,
                                                    wire::to_string(from)));
    }
  }
  co_return target;
}

}  // namespace ecat::master
