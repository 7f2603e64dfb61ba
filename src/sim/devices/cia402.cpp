#include "sim/devices/cia402.hpp"

#include <algorithm>
#include <cmath>

namespace ecat::sim::devices {

namespace {

constexpr double kPositionTau = 2e-3;                    // position loop: actual follows the demand
constexpr double kVelocityTau = 5e-3;                    // velocity loop
constexpr double kTorqueTau = 1e-3;                      // current loop
constexpr double kVelocityFilterTau = 1e-3;              // the measured velocity in position modes
constexpr double kCountsPerSecond2PerPermille = 1000.0;  // acceleration per unit of torque
constexpr double kDamping = 1.0;                         // 1/s: viscous friction in torque mode
constexpr double kMaxStep = 100e-6;                      // integration step
constexpr long kMaxSteps = 200000;  // 20 s of fine steps per call; longer gaps in one step
constexpr std::uint16_t kFollowingError = 0x8611;
constexpr std::uint8_t kGenericError = 0x01;

constexpr std::uint16_t kStatusRemote = 0x0200;
constexpr std::uint16_t kStatusTargetReached = 0x0400;
constexpr std::uint16_t kStatusModeBit12 = 0x1000;
constexpr std::uint16_t kStatusModeBit13 = 0x2000;

// Controlword commands (CiA 402 Table 5: bits 7, 3, 2, 1, 0).
bool is_shutdown(std::uint16_t cw) {
  return (cw & 0x0087) == 0x0006;
}
bool is_switch_on(std::uint16_t cw) {
  return (cw & 0x008F) == 0x0007;
}  // = disable operation
bool is_enable_operation(std::uint16_t cw) {
  return (cw & 0x008F) == 0x000F;
}
bool is_disable_voltage(std::uint16_t cw) {
  return (cw & 0x0082) == 0x0000;
}
bool is_quick_stop(std::uint16_t cw) {
  return (cw & 0x0086) == 0x0002;
}

bool supported_mode(std::int8_t mode) {
  return mode == ds402_mode::kProfilePosition || mode == ds402_mode::kCyclicPosition ||
         mode == ds402_mode::kCyclicVelocity || mode == ds402_mode::kCyclicTorque;
}

double approach(double value, double target, double dt, double tau) {
  return value + (target - value) * (1.0 - std::exp(-dt / tau));
}

// Moves `v` toward `target` by at most `rate * dt`.
double ramp(double v, double target, double rate, double dt) {
  const double step = rate * dt;
  if (v < target) return std::min(target, v + step);
  return std::max(target, v - step);
}

}  // namespace

std::uint16_t ds402_statusword(Ds402State state) noexcept {
  switch (state) {
    case Ds402State::not_ready_to_switch_on:
      return kStatusRemote | 0x0000;
    case Ds402State::switch_on_disabled:
      return kStatusRemote | 0x0040;
    case Ds402State::ready_to_switch_on:
      return kStatusRemote | 0x0031;
    case Ds402State::switched_on:
      return kStatusRemote | 0x0033;
    case Ds402State::operation_enabled:
      return kStatusRemote | 0x0037;
    case Ds402State::quick_stop_active:
      return kStatusRemote | 0x0017;
    case Ds402State::fault_reaction_active:
      return kStatusRemote | 0x000F;
    case Ds402State::fault:
      return kStatusRemote | 0x0008;
  }
  return kStatusRemote;
}

void add_cia402_objects(ObjectDictionary& od) {
  const std::uint16_t rw = kAccessReadWrite;
  const std::uint16_t rx = kAccessReadWrite | kAccessRxPdo;
  const std::uint16_t tx = kAccessRead | kAccessTxPdo;
  auto var = [&od](std::uint16_t index, const char* name, ObjectEntry entry) {
    entry.default_value = entry.value;
    od.add(make_var(index, name, std::move(entry)));
  };
  var(0x603F, "Error code", make_entry_of(0, "", DataType::unsigned16, tx, std::uint16_t{0}));
  var(0x6040, "Controlword", make_entry_of(0, "", DataType::unsigned16, rx, std::uint16_t{0}));
  var(0x6041, "Statusword",
      make_entry_of(0, "", DataType::unsigned16, tx,
                    ds402_statusword(Ds402State::not_ready_to_switch_on)));
  var(0x605A, "Quick stop option code",
      make_entry_of(0, "", DataType::integer16, rw, std::int16_t{2}));
  var(0x6060, "Modes of operation", make_entry_of(0, "", DataType::integer8, rx, std::int8_t{0}));
  var(0x6061, "Modes of operation display",
      make_entry_of(0, "", DataType::integer8, tx, std::int8_t{0}));
  var(0x6062, "Position demand value",
      make_entry_of(0, "", DataType::integer32, tx, std::int32_t{0}));
  var(0x6064, "Position actual value",
      make_entry_of(0, "", DataType::integer32, tx, std::int32_t{0}));
  var(0x6065, "Following error window",
      make_entry_of(0, "", DataType::unsigned32, rx, std::uint32_t{10000}));
  var(0x6066, "Following error time out",
      make_entry_of(0, "", DataType::unsigned16, rw, std::uint16_t{10}));
  var(0x6067, "Position window", make_entry_of(0, "", DataType::unsigned32, rw, std::uint32_t{10}));
  var(0x6068, "Position window time",
      make_entry_of(0, "", DataType::unsigned16, rw, std::uint16_t{0}));
  var(0x606C, "Velocity actual value",
      make_entry_of(0, "", DataType::integer32, tx, std::int32_t{0}));
  var(0x6071, "Target torque", make_entry_of(0, "", DataType::integer16, rx, std::int16_t{0}));
  var(0x6072, "Max torque", make_entry_of(0, "", DataType::unsigned16, rw, std::uint16_t{1000}));
  var(0x6077, "Torque actual value",
      make_entry_of(0, "", DataType::integer16, tx, std::int16_t{0}));
  var(0x607A, "Target position", make_entry_of(0, "", DataType::integer32, rx, std::int32_t{0}));
  var(0x6081, "Profile velocity",
      make_entry_of(0, "", DataType::unsigned32, rx, std::uint32_t{10000}));
  var(0x6083, "Profile acceleration",
      make_entry_of(0, "", DataType::unsigned32, rx, std::uint32_t{100000}));
  var(0x6084, "Profile deceleration",
      make_entry_of(0, "", DataType::unsigned32, rx, std::uint32_t{100000}));
  var(0x6085, "Quick stop deceleration",
      make_entry_of(0, "", DataType::unsigned32, rw, std::uint32_t{1000000}));
  var(0x60F4, "Following error actual value",
      make_entry_of(0, "", DataType::integer32, tx, std::int32_t{0}));
  var(0x60FF, "Target velocity", make_entry_of(0, "", DataType::integer32, rx, std::int32_t{0}));
  // Supported drive modes: PP (bit 0), CSP (bit 7), CSV (bit 8), CST (bit 9).
  var(0x6502, "Supported drive modes",
      make_entry_of(0, "", DataType::unsigned32, kAccessRead, std::uint32_t{0x00000381}));
}

Cia402Drive::Cia402Drive(ObjectDictionary& od, Emergency emergency)
    : od_(od), emergency_(std::move(emergency)) {}

void Cia402Drive::reset(std::int64_t now_ns) {
  state_ = Ds402State::not_ready_to_switch_on;
  mode_ = 0;
  last_controlword_ = 0;
  now_ns_ = now_ns;
  position_ = velocity_ = torque_ = 0;
  demand_ = demand_velocity_ = pp_target_ = 0;
  setpoint_ack_ = following_error_ = moving_ = false;
  following_error_since_ = -1;
  publish();
}

void Cia402Drive::enter(Ds402State state) {
  if (state == Ds402State::operation_enabled && state_ != Ds402State::operation_enabled &&
      state_ != Ds402State::quick_stop_active) {
    // The position loop starts where the motor is, so enabling never jumps.
    demand_ = pp_target_ = position_;
    demand_velocity_ = 0;
    moving_ = false;
  }
  if (state == Ds402State::switch_on_disabled || state == Ds402State::ready_to_switch_on ||
      state == Ds402State::switched_on || state == Ds402State::fault) {
    velocity_ = torque_ = demand_velocity_ = 0;  // power stage off: the brake holds the motor
    demand_ = position_;
  }
  following_error_since_ = -1;
  following_error_ = false;
  state_ = state;
}

void Cia402Drive::command(std::int64_t now_ns) {
  advance(now_ns);
  const auto cw = get<std::uint16_t>(0x6040, 0, 0);
  const std::uint16_t previous = last_controlword_;
  last_controlword_ = cw;
  const auto requested = get<std::int8_t>(0x6060, 0, 0);
  if (requested != mode_ && supported_mode(requested)) {
    mode_ = requested;
    demand_ = pp_target_ = position_;
    demand_velocity_ = 0;
    moving_ = false;
  }
  if (state_ == Ds402State::not_ready_to_switch_on) enter(Ds402State::switch_on_disabled);

  switch (state_) {
    case Ds402State::not_ready_to_switch_on:
      break;
    case Ds402State::switch_on_disabled:
      if (is_shutdown(cw)) enter(Ds402State::ready_to_switch_on);  // 2
      break;
    case Ds402State::ready_to_switch_on:
      if (is_switch_on(cw)) {
        enter(Ds402State::switched_on);  // 3
      } else if (is_enable_operation(cw)) {
        enter(Ds402State::operation_enabled);  // 3 + 4
      } else if (is_disable_voltage(cw) || is_quick_stop(cw)) {
        enter(Ds402State::switch_on_disabled);  // 7
      }
      break;
    case Ds402State::switched_on:
      if (is_enable_operation(cw)) {
        enter(Ds402State::operation_enabled);  // 4
      } else if (is_shutdown(cw)) {
        enter(Ds402State::ready_to_switch_on);  // 6
      } else if (is_disable_voltage(cw) || is_quick_stop(cw)) {
        enter(Ds402State::switch_on_disabled);  // 10
      }
      break;
    case Ds402State::operation_enabled:
      if (is_switch_on(cw)) {
        enter(Ds402State::switched_on);  // 5 (disable operation)
      } else if (is_shutdown(cw)) {
        enter(Ds402State::ready_to_switch_on);  // 8
      } else if (is_disable_voltage(cw)) {
        enter(Ds402State::switch_on_disabled);  // 9
      } else if (is_quick_stop(cw)) {
        enter(Ds402State::quick_stop_active);  // 11
      }
      break;
    case Ds402State::quick_stop_active: {
      const auto option = get<std::int16_t>(0x605A, 0, 2);
      if (is_disable_voltage(cw)) {
        enter(Ds402State::switch_on_disabled);  // 12
      } else if (is_enable_operation(cw) && option >= 5 && option <= 8) {
        enter(Ds402State::operation_enabled);  // 16
      }
      break;
    }
    case Ds402State::fault_reaction_active:
      break;  // 14 happens by itself when the motor has stopped
    case Ds402State::fault:
      if ((cw & 0x0080) != 0 && (previous & 0x0080) == 0) {  // 15: fault reset (rising edge)
        od_.set<std::uint16_t>(0x603F, 0, 0);
        enter(Ds402State::switch_on_disabled);
        if (emergency_) emergency_(0x0000, 0x00);
      }
      break;
  }

  // Profile position set-point handshake: bit 4 rising takes the target (bit 6: relative),
  // statusword bit 12 acknowledges until bit 4 falls again.
  if (state_ == Ds402State::operation_enabled && mode_ == ds402_mode::kProfilePosition) {
    if ((cw & 0x0010) != 0 && (previous & 0x0010) == 0) {
      const double target = get<std::int32_t>(0x607A, 0, 0);
      pp_target_ = (cw & 0x0040) != 0 ? pp_target_ + target : target;
      setpoint_ack_ = true;
      moving_ = true;
    }
  }
  if ((cw & 0x0010) == 0) setpoint_ack_ = false;
  publish();
}

void Cia402Drive::communication_lost(std::int64_t now_ns) {
  advance(now_ns);
  if (state_ == Ds402State::ready_to_switch_on || state_ == Ds402State::switched_on ||
      state_ == Ds402State::operation_enabled || state_ == Ds402State::quick_stop_active) {
    enter(Ds402State::switch_on_disabled);
  }
  publish();
}

void Cia402Drive::raise_fault(std::uint16_t error_code, std::int64_t now_ns) {
  advance(now_ns);
  if (state_ == Ds402State::fault || state_ == Ds402State::fault_reaction_active) return;
  od_.set<std::uint16_t>(0x603F, 0, error_code);
  const bool following = following_error_;
  enter(Ds402State::fault_reaction_active);  // 13
  following_error_ = following;
  if (emergency_) emergency_(error_code, kGenericError);
  publish();
}

void Cia402Drive::advance(std::int64_t now_ns) {
  if (now_ns <= now_ns_) return;
  // 1: the drive's self-test is over as soon as time passes after power-up.
  if (state_ == Ds402State::not_ready_to_switch_on) enter(Ds402State::switch_on_disabled);
  double remaining = static_cast<double>(now_ns - now_ns_) * 1e-9;
  now_ns_ = now_ns;
  long steps = 0;
  while (remaining > 1e-12) {
    const double dt = ++steps < kMaxSteps ? std::min(kMaxStep, remaining) : remaining;
    step(dt);
    remaining -= dt;
  }
  publish();
}

void Cia402Drive::step(double dt) {
  const double previous_position = position_;
  const double previous_velocity = velocity_;
  bool position_mode = false;
  switch (state_) {
    case Ds402State::operation_enabled:
      switch (mode_) {
        case ds402_mode::kCyclicPosition:
          demand_ = get<std::int32_t>(0x607A, 0, 0);
          position_ = approach(position_, demand_, dt, kPositionTau);
          position_mode = true;
          break;
        case ds402_mode::kProfilePosition: {
          const bool halt = (last_controlword_ & 0x0100) != 0;
          const double v_max = get<std::uint32_t>(0x6081, 0, 10000);
          const double acc = std::max(1.0, static_cast<double>(get<std::uint32_t>(0x6083, 0, 1)));
          const double dec = std::max(1.0, static_cast<double>(get<std::uint32_t>(0x6084, 0, 1)));
          const double to_go = pp_target_ - demand_;
          double wanted = 0;
          if (!halt && moving_) {
            // Trapezoid: as fast as allowed while the remaining distance still lets it stop.
            const double stop_speed = std::sqrt(2.0 * dec * std::abs(to_go));
            wanted = std::copysign(std::min(v_max, stop_speed), to_go);
          }
          const double rate = std::abs(wanted) > std::abs(demand_velocity_) ? acc : dec;
          demand_velocity_ = ramp(demand_velocity_, wanted, rate, dt);
          demand_ += demand_velocity_ * dt;
          if (moving_ &&
              (std::abs(pp_target_ - demand_) < 0.5 || (pp_target_ - demand_) * to_go < 0)) {
            demand_ = pp_target_;  // arrived (or would overshoot in this step)
            demand_velocity_ = 0;
            moving_ = false;
          }
          position_ = approach(position_, demand_, dt, kPositionTau);
          position_mode = true;
          break;
        }
        case ds402_mode::kCyclicVelocity:
          velocity_ = approach(velocity_, get<std::int32_t>(0x60FF, 0, 0), dt, kVelocityTau);
          position_ += velocity_ * dt;
          demand_ = position_;
          break;
        case ds402_mode::kCyclicTorque: {
          const double limit = get<std::uint16_t>(0x6072, 0, 1000);
          const double target = std::clamp<double>(get<std::int16_t>(0x6071, 0, 0), -limit, limit);
          torque_ = approach(torque_, target, dt, kTorqueTau);
          velocity_ += (torque_ * kCountsPerSecond2PerPermille - kDamping * velocity_) * dt;
          position_ += velocity_ * dt;
          demand_ = position_;
          break;
        }
        default:
          velocity_ = 0;
          demand_ = position_;
          break;
      }
      break;
    case Ds402State::quick_stop_active:
    case Ds402State::fault_reaction_active: {
      const double dec = std::max(1.0, static_cast<double>(get<std::uint32_t>(0x6085, 0, 1)));
      velocity_ = ramp(velocity_, 0.0, dec, dt);
      position_ += velocity_ * dt;
      demand_ = position_;
      if (std::abs(velocity_) < 1e-9) {
        if (state_ == Ds402State::fault_reaction_active) {
          const bool following = following_error_;
          enter(Ds402State::fault);  // 14
          following_error_ = following;
        } else {
          const auto option = get<std::int16_t>(0x605A, 0, 2);
          if (option >= 0 && option <= 4) enter(Ds402State::switch_on_disabled);  // 12
        }
      }
      break;
    }
    default:
      velocity_ = torque_ = 0;
      demand_ = position_;
      break;
  }
  if (position_mode && dt > 0) {
    // Measured like a drive measures it: the derivative of the position, filtered.
    velocity_ = approach(velocity_, (position_ - previous_position) / dt, dt, kVelocityFilterTau);
  }
  if (mode_ != ds402_mode::kCyclicTorque || state_ != Ds402State::operation_enabled) {
    const double accel = dt > 0 ? (velocity_ - previous_velocity) / dt : 0.0;
    const double limit = get<std::uint16_t>(0x6072, 0, 1000);
    const double wanted = state_ == Ds402State::operation_enabled ||
                                  state_ == Ds402State::quick_stop_active ||
                                  state_ == Ds402State::fault_reaction_active
                              ? std::clamp(accel / kCountsPerSecond2PerPermille, -limit, limit)
                              : 0.0;
    torque_ = approach(torque_, wanted, dt, kTorqueTau);
  }

  // Following error: the actual position lags the demand by more than the window for longer
  // than the time-out (position modes only).
  if (state_ == Ds402State::operation_enabled && position_mode) {
    const auto window = get<std::uint32_t>(0x6065, 0, 0xFFFFFFFF);
    const double error = std::abs(demand_ - position_);
    if (window != 0xFFFFFFFF && error > window) {
      following_error_ = true;
      const std::int64_t timeout_ns =
          static_cast<std::int64_t>(get<std::uint16_t>(0x6066, 0, 0)) * 1'000'000;
      if (following_error_since_ < 0) following_error_since_ = now_ns_;
      if (now_ns_ - following_error_since_ >= timeout_ns) {
        od_.set<std::uint16_t>(0x603F, 0, kFollowingError);
        enter(Ds402State::fault_reaction_active);
        following_error_ = true;
        if (emergency_) emergency_(kFollowingError, kGenericError);
      }
    } else {
      following_error_ = false;
      following_error_since_ = -1;
    }
  }
}

void Cia402Drive::publish() {
  std::uint16_t sw = ds402_statusword(state_);
  if (state_ == Ds402State::operation_enabled) {
    const double window = get<std::uint32_t>(0x6067, 0, 10);
    switch (mode_) {
      case ds402_mode::kProfilePosition:
        if (!moving_ && std::abs(pp_target_ - position_) <= window) sw |= kStatusTargetReached;
        if (setpoint_ack_) sw |= kStatusModeBit12;
        break;
      case ds402_mode::kCyclicPosition:
        if (std::abs(get<std::int32_t>(0x607A, 0, 0) - position_) <= window) {
          sw |= kStatusTargetReached;
        }
        sw |= kStatusModeBit12;
        break;
      case ds402_mode::kCyclicVelocity:
      case ds402_mode::kCyclicTorque:
        sw |= kStatusModeBit12;
        break;
      default:
        break;
    }
  }
  if (following_error_) sw |= kStatusModeBit13;
  od_.set<std::uint16_t>(0x6041, 0, sw);
  od_.set<std::int8_t>(0x6061, 0, mode_);
  od_.set<std::int32_t>(0x6064, 0, static_cast<std::int32_t>(std::lround(position_)));
  od_.set<std::int32_t>(0x6062, 0, static_cast<std::int32_t>(std::lround(demand_)));
  od_.set<std::int32_t>(0x606C, 0, static_cast<std::int32_t>(std::lround(velocity_)));
  od_.set<std::int16_t>(0x6077, 0, static_cast<std::int16_t>(std::lround(torque_)));
  od_.set<std::int32_t>(0x60F4, 0, static_cast<std::int32_t>(std::lround(demand_ - position_)));
}

}  // namespace ecat::sim::devices
