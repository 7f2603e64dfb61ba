#include <ecat/sim/application.hpp>
#include <ecat/sim/esc.hpp>

namespace ecat::sim {

using wire::AlState;

bool al_transition_allowed(AlState from, AlState to) noexcept {
  if (from == to || to == AlState::init) return true;
  switch (from) {
    case AlState::init:
      return to == AlState::preop || to == AlState::bootstrap;
    case AlState::preop:
      return to == AlState::safeop;
    case AlState::bootstrap:
      return false;  // only back to INIT
    case AlState::safeop:
      return to == AlState::op || to == AlState::preop;
    case AlState::op:
      return to == AlState::safeop || to == AlState::preop;
  }
  return false;
}

void BasicApplication::start(Esc& esc) {
  esc.pdi_set_al_status(AlState::init, false, 0);
}

void BasicApplication::on_al_control(Esc& esc, std::uint16_t control) {
  const auto requested = wire::al_state_from_code(static_cast<std::uint8_t>(control & 0x0F));
  const bool acknowledge = (control & wire::kAlControlErrorAcknowledge) != 0;
  const AlState current = esc.al_state();
  bool error = esc.al_error();
  std::uint16_t code = esc.al_status_code();
  if (error && acknowledge) {
    error = false;
    code = 0;
  }
  if (!requested) {
    esc.pdi_set_al_status(current, true, wire::al_status::kUnknownRequestedState);
    return;
  }
  if (error && *requested != AlState::init && *requested != current) {
    // While an error is pending, only a step down (to INIT) is taken without acknowledge.
    return;
  }
  if (*requested == AlState::bootstrap) {
    esc.pdi_set_al_status(current, true, wire::al_status::kBootstrapNotSupported);
    return;
  }
  if (!al_transition_allowed(current, *requested)) {
    esc.pdi_set_al_status(current, true, wire::al_status::kInvalidRequestedStateChange);
    return;
  }
  esc.pdi_set_al_status(*requested, error, code);
}

}  // namespace ecat::sim
