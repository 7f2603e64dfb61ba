// The built-in device drivers, and the CiA 402 (IEC 61800-7-201) state machine helpers the drive
// driver is made of. drivers::builtin_registry() (builtin.hpp) registers all of them.
//
//   EL1809  Beckhoff 16-channel digital input (0x00000002:0x07113052): channel_1..channel_16
//   EL2809  Beckhoff 16-channel digital output (0x00000002:0x0AF93052): channel_1..channel_16
//   EL3202  Beckhoff 2-channel RTD input (0x00000002:0x0C823052): channel_N.temperature (°C),
//           channel_N.underrange / overrange / error / limit_1 / limit_2 / txpdo_state /
//           txpdo_toggle. Options: element (pt100 ni100 pt1000 pt500 pt200 ni1000
//           ni1000_tk1500 ni120), connection (2_wire 3_wire 4_wire not_connected),
//           presentation (signed: 0.1 °C, high_resolution: 0.01 °C); "channel_N.<option>"
//           sets one channel. Each given option becomes a 0x80n0 download in PREOP.
//   EL4102  Beckhoff 2-channel analog output 0..10 V (0x00000002:0x10063052): channel_N.output
//           (V). Options: watchdog (default_value ramp last_value), default_output (V).
//   cia402  CiA 402 drive (the simulator's servo 0x00000ACE:0x00002402; chosen by name for any
//           other drive). Signals named after the objects (controlword, statusword,
//           modes_of_operation, target_position, position_actual ...), other mapped entries
//           named as the generic driver names them.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

#include <ecat/drivers/builtin.hpp>
#include <ecat/master/driver.hpp>

namespace ecat::drivers {

std::shared_ptr<const master::Driver> el1809_driver();
std::shared_ptr<const master::Driver> el2809_driver();
std::shared_ptr<const master::Driver> el3202_driver();
std::shared_ptr<const master::Driver> el4102_driver();
std::shared_ptr<const master::Driver> cia402_driver();
std::vector<std::shared_ptr<const master::Driver>> builtin_drivers();

// ---- CiA 402 ---------------------------------------------------------------------------------

enum class Cia402State : std::uint8_t {
  not_ready_to_switch_on,
  switch_on_disabled,
  ready_to_switch_on,
  switched_on,
  operation_enabled,
  quick_stop_active,
  fault_reaction_active,
  fault,
  unknown,  // a statusword that matches no pattern of the state table
};
// "not_ready_to_switch_on", ..., "fault", "unknown".
std::string_view to_string(Cia402State state) noexcept;

// The state a statusword shows (CiA 402 Table 30, bits 0-3, 5 and 6):
//   xxxx xxxx x0xx 0000  not ready to switch on     xxxx xxxx x1xx 0000  switch on disabled
//   xxxx xxxx x01x 0001  ready to switch on         xxxx xxxx x01x 0011  switched on
//   xxxx xxxx x01x 0111  operation enabled          xxxx xxxx x00x 0111  quick stop active
//   xxxx xxxx x0xx 1111  fault reaction active      xxxx xxxx x0xx 1000  fault
Cia402State cia402_state(std::uint16_t statusword) noexcept;

// Device control commands (CiA 402 Table 28).
enum class Cia402Command : std::uint8_t {
  shutdown,           // xxxx x110  -> ready to switch on
  switch_on,          // xxxx 0111  -> switched on
  enable_operation,   // xxxx 1111  -> operation enabled (also from switched on)
  disable_operation,  // xxxx 0111  -> switched on
  disable_voltage,    // xxxx xx0x  -> switch on disabled
  quick_stop,         // xxxx x01x  -> quick stop active
  fault_reset,        // 0->1 edge of bit 7 -> switch on disabled (from fault)
};
std::string_view to_string(Cia402Command command) noexcept;
std::optional<Cia402Command> cia402_command_from_string(std::string_view name) noexcept;

// The controlword for `command`, keeping the bits of `current` that are not part of the device
// control command (4..6 operation-mode specific, 8 halt, 9..15). Bit 7 (fault reset) is set
// only by fault_reset and cleared by every other command, so a later fault_reset is an edge.
std::uint16_t cia402_controlword(Cia402Command command, std::uint16_t current) noexcept;

// Modes of operation (0x6060 / 0x6061).
namespace cia402_mode {
constexpr std::int8_t kProfilePosition = 1;       // "pp"
constexpr std::int8_t kProfileVelocity = 3;       // "pv"
constexpr std::int8_t kProfileTorque = 4;         // "pt"
constexpr std::int8_t kHoming = 6;                // "hm"
constexpr std::int8_t kInterpolatedPosition = 7;  // "ip"
constexpr std::int8_t kCyclicPosition = 8;        // "csp"
constexpr std::int8_t kCyclicVelocity = 9;        // "csv"
constexpr std::int8_t kCyclicTorque = 10;         // "cst"
}  // namespace cia402_mode
// "pp", "pv", "pt", "hm", "ip", "csp", "csv", "cst"; "mode_<n>" for others ("none" for 0).
std::string cia402_mode_name(std::int8_t mode);
// The inverse of cia402_mode_name (also accepts the number as text).
std::optional<std::int8_t> cia402_mode_from_string(std::string_view name) noexcept;

}  // namespace ecat::drivers
