#include <array>

#include <ecat/master/states.hpp>

namespace ecat::master {
namespace {

using M = MasterState;
using S = SlaveState;

constexpr std::array kMasterTransitions{
    MasterTransition{M::idle, M::discovering, "start"},
    MasterTransition{M::discovering, M::awaiting_preop, "configured slaves are still pending"},
    MasterTransition{M::discovering, M::idle, "startup fails or stop"},
    MasterTransition{M::awaiting_preop, M::preop_ready,
                     "all slaves reached PREOP, no activation requested"},
    MasterTransition{M::awaiting_preop, M::operational,
                     "all slaves reached PREOP and activation succeeds"},
    MasterTransition{M::awaiting_preop, M::activation_blocked, "activation is incomplete"},
    MasterTransition{M::awaiting_preop, M::idle, "timeout, fatal startup failure, or stop"},
    MasterTransition{M::preop_ready, M::operational, "activate succeeds"},
    MasterTransition{M::preop_ready, M::activation_blocked, "activate is incomplete"},
    MasterTransition{M::preop_ready, M::recovering, "critical runtime fault"},
    MasterTransition{M::preop_ready, M::idle, "stop or fatal subsystem exit"},
    MasterTransition{M::deactivated, M::operational, "activate succeeds"},
    MasterTransition{M::deactivated, M::preop_ready, "deactivate to PREOP"},
    MasterTransition{M::deactivated, M::activation_blocked, "target transition remains incomplete"},
    MasterTransition{M::deactivated, M::recovering, "critical runtime fault"},
    MasterTransition{M::deactivated, M::idle, "stop or fatal subsystem exit"},
    MasterTransition{M::operational, M::recovering, "critical runtime fault"},
    MasterTransition{M::operational, M::deactivated, "deactivate settles in SAFEOP"},
    MasterTransition{M::operational, M::preop_ready, "deactivate to PREOP"},
    MasterTransition{M::operational, M::idle, "stop or fatal subsystem exit"},
    MasterTransition{M::activation_blocked, M::operational,
                     "activation failures clear and target is OP"},
    MasterTransition{M::activation_blocked, M::deactivated,
                     "transition failures clear and target is SAFEOP"},
    MasterTransition{M::activation_blocked, M::preop_ready,
                     "transition failures clear and target is PREOP"},
    MasterTransition{M::activation_blocked, M::recovering,
                     "runtime faults remain after activation retry"},
    MasterTransition{M::activation_blocked, M::idle, "stop or fatal subsystem exit"},
    MasterTransition{M::recovering, M::operational,
                     "critical runtime faults are cleared and target is OP"},
    MasterTransition{M::recovering, M::deactivated,
                     "critical runtime faults are cleared and target is SAFEOP"},
    MasterTransition{M::recovering, M::preop_ready,
                     "critical runtime faults are cleared and target is PREOP"},
    MasterTransition{M::recovering, M::idle, "stop or recovery fails"},
};

constexpr std::array kSlaveTransitions{
    SlaveTransition{S::init, S::preop, "auto-advance succeeds"},
    SlaveTransition{S::init, S::init, "auto-advance retries"},
    SlaveTransition{S::init, S::bootstrap, "bootstrap is requested"},
    SlaveTransition{S::init, S::safeop, "SAFEOP request path succeeds"},
    SlaveTransition{S::init, S::op, "OP request path succeeds"},
    SlaveTransition{S::bootstrap, S::init, "INIT is requested"},
    SlaveTransition{S::preop, S::safeop, "SAFEOP is requested"},
    SlaveTransition{S::preop, S::op, "OP is requested"},
    SlaveTransition{S::preop, S::init, "INIT is requested or AL health regresses to INIT"},
    SlaveTransition{S::preop, S::bootstrap, "AL health regresses to BOOTSTRAP"},
    SlaveTransition{S::preop, S::down, "health poll sees bus loss or zero WKC"},
    SlaveTransition{S::safeop, S::op, "OP is requested"},
    SlaveTransition{S::safeop, S::preop, "PREOP is requested or AL health regresses to PREOP"},
    SlaveTransition{S::safeop, S::init, "INIT is requested or AL health regresses to INIT"},
    SlaveTransition{S::safeop, S::bootstrap, "AL health regresses to BOOTSTRAP"},
    SlaveTransition{S::safeop, S::down, "health poll sees bus loss or zero WKC"},
    SlaveTransition{S::op, S::safeop, "SAFEOP is requested or AL health retreats"},
    SlaveTransition{S::op, S::preop, "PREOP is requested"},
    SlaveTransition{S::op, S::init, "INIT is requested"},
    SlaveTransition{S::op, S::down, "health poll sees bus loss or zero WKC"},
    SlaveTransition{S::down, S::preop, "link/position probe succeeds and PREOP rebuild succeeds"},
    SlaveTransition{S::down, S::init, "reconnect rebuild retries from INIT"},
};

constexpr std::array<std::string_view, 8> kMasterNames{
    "idle",        "discovering", "awaiting_preop",     "preop_ready",
    "deactivated", "operational", "activation_blocked", "recovering"};

}  // namespace

std::string_view to_string(MasterState state) noexcept {
  const auto i = static_cast<std::size_t>(state);
  return i < kMasterNames.size() ? kMasterNames[i] : "unknown";
}

std::optional<MasterState> master_state_from_string(std::string_view name) noexcept {
  for (std::size_t i = 0; i < kMasterNames.size(); ++i) {
    if (kMasterNames[i] == name) return static_cast<MasterState>(i);
  }
  return std::nullopt;
}

std::span<const MasterTransition> master_transitions() noexcept {
  return kMasterTransitions;
}

bool master_transition_allowed(MasterState from, MasterState to) noexcept {
  for (const auto& t : kMasterTransitions) {
    if (t.from == from && t.to == to) return true;
  }
  return false;
}

std::string_view to_string(SlaveState state) noexcept {
  switch (state) {
    case S::init:
      return "init";
    case S::preop:
      return "preop";
    case S::bootstrap:
      return "bootstrap";
    case S::safeop:
      return "safeop";
    case S::op:
      return "op";
    case S::down:
      return "down";
  }
  return "unknown";
}

SlaveState slave_state_of(wire::AlState state) noexcept {
  switch (state) {
    case wire::AlState::init:
      return S::init;
    case wire::AlState::preop:
      return S::preop;
    case wire::AlState::bootstrap:
      return S::bootstrap;
    case wire::AlState::safeop:
      return S::safeop;
    case wire::AlState::op:
      return S::op;
  }
  return S::init;
}

std::optional<wire::AlState> al_state_of(SlaveState state) noexcept {
  switch (state) {
    case S::init:
      return wire::AlState::init;
    case S::preop:
      return wire::AlState::preop;
    case S::bootstrap:
      return wire::AlState::bootstrap;
    case S::safeop:
      return wire::AlState::safeop;
    case S::op:
      return wire::AlState::op;
    case S::down:
      return std::nullopt;
  }
  return std::nullopt;
}

std::span<const SlaveTransition> slave_transitions() noexcept {
  return kSlaveTransitions;
}

bool slave_transition_allowed(SlaveState from, SlaveState to) noexcept {
  for (const auto& t : kSlaveTransitions) {
    if (t.from == from && t.to == to) return true;
  }
  return false;
}

std::string_view to_string(TargetState target) noexcept {
  switch (target) {
    case TargetState::preop:
      return "preop";
    case TargetState::safeop:
      return "safeop";
    case TargetState::op:
      return "op";
  }
  return "unknown";
}

wire::AlState al_state_of(TargetState target) noexcept {
  switch (target) {
    case TargetState::preop:
      return wire::AlState::preop;
    case TargetState::safeop:
      return wire::AlState::safeop;
    case TargetState::op:
      return wire::AlState::op;
  }
  return wire::AlState::preop;
}

}  // namespace ecat::master
