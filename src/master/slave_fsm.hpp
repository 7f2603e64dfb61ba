// The slave's lifecycle (../shared/seeds/slave.md "State transitions"): the one place its state
// changes, and nothing but that. Each change is checked against the seed's table
// (slave_transitions() in states.cpp); an undrawn one is refused and counted, never made. What
// decides when to change (AL requests, health polls, reconnects) lives in slave.cpp.
//
// Lost while in INIT or BOOTSTRAP: the seed draws no edge to DOWN from either, and neither has
// anything to rebuild (no process data, no mailbox configuration of the session's), so such a
// slave keeps its state and its loss is tracked as a fault until it answers again.
#pragma once

#include <atomic>
#include <cstdint>

#include <ecat/master/states.hpp>

namespace ecat::master {

class SlaveFsm {
 public:
  enum class Change : std::uint8_t { made, unchanged, refused };

  SlaveState state() const noexcept { return state_.load(std::memory_order_acquire); }

  // One control thread changes the state; any thread reads it.
  Change change(SlaveState to) noexcept {
    const SlaveState from = state();
    if (from == to) return Change::unchanged;
    if (!slave_transition_allowed(from, to)) {
      refused_.fetch_add(1, std::memory_order_relaxed);
      return Change::refused;
    }
    state_.store(to, std::memory_order_release);
    return Change::made;
  }

  // The seed's init -> init ("auto-advance retries"): true when the slave is in INIT, where a
  // retried bring-up is that edge.
  bool retries_in_init() const noexcept { return state() == SlaveState::init; }

  // Undrawn changes asked for and refused: always 0 unless the master has a bug.
  std::uint64_t refused() const noexcept { return refused_.load(std::memory_order_relaxed); }

 private:
  std::atomic<SlaveState> state_{SlaveState::init};
  std::atomic<std::uint64_t> refused_{0};
};

}  // namespace ecat::master
