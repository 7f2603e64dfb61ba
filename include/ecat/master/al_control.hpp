// AL state changes of one slave, as coroutines on the control loop.
//
// A request walks the intermediate states a slave needs (OP -> INIT goes OP -> SAFEOP -> PREOP ->
// INIT), writes AL control (0x0120) for each step and polls AL status (0x0130) until the slave
// shows the state. A slave that refuses sets the error indicator: the AL status code (0x0134) is
// read, the error is acknowledged (AL control = current state | 0x10) and the request fails with
// Errc::al_error, the code attached (al_status_code()) and its ETG text in the message.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/master/config.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/al.hpp>

namespace ecat::master {

// The states a request from `from` to `to` passes through, `to` last; empty when `from == to`;
// nullopt when there is no path (BOOT is reached from INIT only and left to INIT only).
std::optional<std::vector<wire::AlState>> al_path(wire::AlState from, wire::AlState to);

// One row of the path table (for documentation and tests).
struct AlPathRow {
  wire::AlState from;
  wire::AlState to;
  std::span<const wire::AlState> steps;
};
std::span<const AlPathRow> al_path_table() noexcept;

// The AL status code an Errc::al_error carries, if the error (or one of its causes) has one.
std::optional<std::uint16_t> al_status_code(const Error& error) noexcept;

// Reads AL status and AL status code (0x0130..0x0135) of one slave.
exec::Task<Result<wire::AlStatusBlock>> read_al_status(exec::EventLoop& loop, bus::Bus& bus,
                                                       std::uint16_t station,
                                                       bus::TransactOptions options = {});

// One step: writes AL control = `state` (optionally acknowledging an error) and waits until AL
// status shows it. Errors: Errc::al_error (refused; code attached, acknowledged), Errc::timeout
// (still in another state at the step timeout; names both), Errc::wkc_mismatch (the slave did
// not take the AL control write: gone), bus errors.
exec::Task<Result<void>> al_step(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station,
                                 wire::AlState state, AlOptions options = {});

// Walks from the slave's current state (read first) to `target` along al_path().
// Errc::invalid_argument when there is no path. Acknowledges a pending error first.
exec::Task<Result<wire::AlState>> al_request(exec::EventLoop& loop, bus::Bus& bus,
                                             std::uint16_t station, wire::AlState target,
                                             AlOptions options = {});

// Acknowledges a pending AL error (AL control = current state | 0x10) and returns the status
// read afterwards.
exec::Task<Result<wire::AlStatusBlock>> al_acknowledge(exec::EventLoop& loop, bus::Bus& bus,
                                                       std::uint16_t station,
                                                       AlOptions options = {});

}  // namespace ecat::master
