// A CiA 402 (IEC 61800-7-201) drive: the power state machine driven by the controlword, the
// statusword it reports, and a motor with simple first-order dynamics in the modes profile
// position (PP, 1), cyclic synchronous position (CSP, 8), velocity (CSV, 9) and torque (CST, 10).
// It works on the objects of an ObjectDictionary (0x6040 controlword, 0x6041 statusword, ...), so
// the built-in "servo" profile and drives built from an ESI share it.
//
// Statusword patterns (bit 9 "remote" is always set; bit 4 "voltage enabled" in the states with
// power applied):
//   not ready to switch on 0x0200   switch on disabled 0x0240   ready to switch on 0x0231
//   switched on 0x0233   operation enabled 0x0237   quick stop active 0x0217
//   fault reaction active 0x020F   fault 0x0208
// plus bit 10 target reached, bit 12 set-point acknowledge (PP) / drive follows the command value
// (CSP/CSV/CST), bit 13 following error.
//
// Simplifications: a new PP set-point is always taken at once (bit 5 "change set immediately"
// is implied); leaving OP with the power stage on disables the voltage (switch on disabled),
// as abort connection option code 0x6007 = 2 would.
#pragma once

#include <cstdint>
#include <functional>

#include <ecat/sim/object_dictionary.hpp>

namespace ecat::sim::devices {

enum class Ds402State : std::uint8_t {
  not_ready_to_switch_on,
  switch_on_disabled,
  ready_to_switch_on,
  switched_on,
  operation_enabled,
  quick_stop_active,
  fault_reaction_active,
  fault,
};

// The statusword bits 0..6 and 9 that show `state` (see the table above).
std::uint16_t ds402_statusword(Ds402State state) noexcept;

// Modes of operation (0x6060).
namespace ds402_mode {
constexpr std::int8_t kProfilePosition = 1;
constexpr std::int8_t kCyclicPosition = 8;
constexpr std::int8_t kCyclicVelocity = 9;
constexpr std::int8_t kCyclicTorque = 10;
}  // namespace ds402_mode

// The objects a CiA 402 drive needs, with defaults (units: position in counts, velocity in
// counts/s, acceleration in counts/s², torque in per mille of rated torque).
void add_cia402_objects(ObjectDictionary& od);

class Cia402Drive {
 public:
  // Called when the drive raises (error_code != 0) or clears (0) an error.
  using Emergency = std::function<void(std::uint16_t error_code, std::uint8_t error_register)>;

  Cia402Drive(ObjectDictionary& od, Emergency emergency);

  // Power-up: not ready to switch on, motor at rest at position 0.
  void reset(std::int64_t now_ns);
  // The controlword, the mode or a set-point may have changed: run the state machine now.
  void command(std::int64_t now_ns);
  // Time passes: motion, following error, fault reaction, quick stop.
  void advance(std::int64_t now_ns);
  // The master stopped driving the outputs (left OP): power stage off.
  void communication_lost(std::int64_t now_ns);
  // A fault from outside the model (a test, a fault injection).
  void raise_fault(std::uint16_t error_code, std::int64_t now_ns);

  Ds402State state() const noexcept { return state_; }
  double position() const noexcept { return position_; }
  double velocity() const noexcept { return velocity_; }
  double torque() const noexcept { return torque_; }

 private:
  void step(double dt);
  void publish();
  void enter(Ds402State state);
  std::int8_t mode() const noexcept { return mode_; }
  template <class T>
  T get(std::uint16_t index, std::uint8_t subindex, T fallback) const {
    return od_.get<T>(index, subindex).value_or(fallback);
  }

  ObjectDictionary& od_;
  Emergency emergency_;
  Ds402State state_ = Ds402State::not_ready_to_switch_on;
  std::int8_t mode_ = 0;
  std::uint16_t last_controlword_ = 0;
  std::int64_t now_ns_ = 0;
  double position_ = 0;  // actual
  double velocity_ = 0;
  double torque_ = 0;
  double demand_ = 0;           // position demand (CSP: the target; PP: the profile generator)
  double demand_velocity_ = 0;  // PP profile generator velocity
  double pp_target_ = 0;
  bool setpoint_ack_ = false;
  bool following_error_ = false;
  std::int64_t following_error_since_ = -1;
  bool moving_ = false;
};

}  // namespace ecat::sim::devices
