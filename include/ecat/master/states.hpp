// The master's and the slave's lifecycle states and their transition tables, exactly as the
// reference design's diagrams draw them (../shared/seeds/master.md "Recovery model",
// ../shared/seeds/slave.md "State transitions"). The state machines consult these tables for
// every change, so a transition that is not drawn cannot happen (it is a bug and is reported).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string_view>

#include <ecat/wire/al.hpp>

namespace ecat::master {

enum class MasterState : std::uint8_t {
  idle,                // no active session
  discovering,         // scanning, counting slaves, assigning stations, preparing startup
  awaiting_preop,      // waiting for configured slaves to reach PREOP
  preop_ready,         // all slaves in PREOP; ready for activation or dynamic configuration
  deactivated,         // live below OP on purpose (SAFEOP)
  operational,         // cyclic runtime active
  activation_blocked,  // the desired runtime target was not fully reached
  recovering,          // critical runtime faults are being healed
};
std::string_view to_string(MasterState state) noexcept;
std::optional<MasterState> master_state_from_string(std::string_view name) noexcept;

struct MasterTransition {
  MasterState from;
  MasterState to;
  std::string_view trigger;  // the diagram's label
};
std::span<const MasterTransition> master_transitions() noexcept;
bool master_transition_allowed(MasterState from, MasterState to) noexcept;

// The slave's states: the AL states plus `down` (lost from the bus).
enum class SlaveState : std::uint8_t { init, preop, bootstrap, safeop, op, down };
std::string_view to_string(SlaveState state) noexcept;
SlaveState slave_state_of(wire::AlState state) noexcept;
std::optional<wire::AlState> al_state_of(SlaveState state) noexcept;

struct SlaveTransition {
  SlaveState from;
  SlaveState to;
  std::string_view trigger;
};
std::span<const SlaveTransition> slave_transitions() noexcept;
bool slave_transition_allowed(SlaveState from, SlaveState to) noexcept;

// The session's runtime target, and a slave's configured target.
enum class TargetState : std::uint8_t { preop, safeop, op };
std::string_view to_string(TargetState target) noexcept;
wire::AlState al_state_of(TargetState target) noexcept;

}  // namespace ecat::master
