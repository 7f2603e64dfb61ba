// The master's way into its slaves' control-loop side. Private to src/master.
//
// The public Slave header names this class as a friend and nothing more, so Slave::Impl stays out
// of every public header, and the master asks for what it needs by name (bring a slave up, step
// it, retry its configuration, ...) instead of reaching into the slave's fields and locks. A new
// need of the master's is a new operation here, with the locking rule it follows.
//
// Every operation runs on the control loop unless it says otherwise.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <ecat/exec/task.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/master/states.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/al.hpp>

#include "session.hpp"

namespace ecat::master::detail {

class SlaveAccess {
 public:
  // ---- startup -------------------------------------------------------------------------------
  // INIT -> ESC information -> SII -> mailbox -> PREOP -> PREOP configuration. A failed PREOP
  // configuration is retained on the slave, not returned.
  static exec::Task<Result<void>> bring_up(Slave& slave, std::shared_ptr<Session> keep);
  // Why the last bring-up failed (nullopt: it succeeded), readable by applications while the
  // session waits for the slave (SlaveInfo::startup_error).
  static void set_startup_error(Slave& slave, std::optional<std::string> why);
  // A bring-up retried from INIT (the seed's init -> init edge).
  static void note_retry_in_init(Slave& slave) noexcept;
  // Starts the slave's health polling when its configuration asks for one (once: later calls do
  // nothing).
  static void start_health(Slave& slave, std::shared_ptr<Session> keep);

  // ---- lifecycle -------------------------------------------------------------------------------
  // The slave's configured target. Read without the slave's lock: the control loop is the only
  // writer of its configuration.
  static TargetState target(const Slave& slave) noexcept;
  // Lost and not yet rebuilt: the master leaves such a slave to its own rebuild.
  static bool awaiting_rebuild(const Slave& slave) noexcept;
  // Walks the AL state machine to `target` (Slave::request's work).
  static exec::Task<Result<void>> go_to(Slave& slave, wire::AlState target,
                                        std::shared_ptr<Session> keep);
  // Re-runs a retained PREOP configuration failure; ok when there is none (Slave::retry's work).
  static exec::Task<Result<void>> retry_configuration(Slave& slave, std::shared_ptr<Session> keep);
  // Clears the slave's tracked fault (published when there was one).
  static void clear_fault(Slave& slave);

  // ---- hot connect -----------------------------------------------------------------------------
  // A hot-connect group's slave that is not in the ring: its health loop leaves it alone and the
  // master's walks skip it. Loop thread writes, any thread reads.
  static void set_absent(Slave& slave, bool absent) noexcept;
  static bool absent(const Slave& slave) noexcept;
  // The group appeared at `position`: the slave is there now, any unit of its identity (the serial
  // number seen before is forgotten).
  static void place(Slave& slave, std::uint16_t position);
  // The slave is still there, at another position (a group plugged or pulled in front of it on a
  // junction port): only its position changes.
  static void move_to(Slave& slave, std::uint16_t position) noexcept;
  // The group went: DOWN when it was in PREOP or above, with `why` as its fault.
  static void lose(Slave& slave, std::string why);

  // ---- what the master's policy asks (any thread; they take the slave's lock) ----------------
  // A PREOP configuration failure is retained and the slave was configured without process data:
  // the failure cannot hold a domain back.
  static bool retained_failure_without_process_data(const Slave& slave);
  // Some of the slave's SyncManagers are registered in a domain.
  static bool carries_process_data(const Slave& slave);

  // ---- runtime ---------------------------------------------------------------------------------
  // An input change of this slave, from a domain (its subscribers are called).
  static void on_input_change(Slave& slave, const InputChange& change);
  // Any thread.
  static std::uint64_t refused_transitions(const Slave& slave) noexcept;
  static MasterCounters::SlaveCounters counters(const Slave& slave);

  // ---- signal handles (any thread) -------------------------------------------------------------
  // SignalHandle::write: `stage(context)` (the handle's writes of the signal's bits into every
  // domain of its SyncManager) runs under the slave's output lock, then `raw` is kept in the
  // retained image of the signal's SyncManager, as write_output does: the domains and the image
  // stay alike, and a reconnect restages what the handle wrote. No allocation, no `mutex`.
  static Result<void> stage_output(Slave& slave, const Signal& signal, std::uint64_t raw,
                                   Result<void> (*stage)(const void*), const void* context);
};

}  // namespace ecat::master::detail
