// The PDI side of an emulated slave: the firmware that reacts to what the master does through the
// ESC. The ESC calls these hooks synchronously while it processes a datagram (or from advance()),
// so an application answers "instantly" unless it chooses to defer work to advance().
#pragma once

#include <cstddef>
#include <cstdint>

#include <ecat/wire/al.hpp>

namespace ecat::sim {

class Esc;

class Application {
 public:
  virtual ~Application() = default;

  // Once, after the ESC is built, and again after every power cycle.
  virtual void start(Esc& esc) { (void)esc; }

  // The master wrote AL control (0x0120). The application decides and reports the new AL status
  // with Esc::pdi_set_al_status.
  virtual void on_al_control(Esc& esc, std::uint16_t control) = 0;

  // The master completed writing a SyncManager buffer: a mailbox request (mailbox mode) or new
  // outputs (3-buffer mode).
  virtual void on_buffer_written(Esc& esc, std::size_t sm) {
    (void)esc;
    (void)sm;
  }

  // The master completed reading a SyncManager buffer: the mailbox reply was fetched, or inputs
  // were read.
  virtual void on_buffer_read(Esc& esc, std::size_t sm) {
    (void)esc;
    (void)sm;
  }

  // The master is about to read a 3-buffer input SyncManager: a chance to publish fresh inputs.
  virtual void before_buffer_read(Esc& esc, std::size_t sm) {
    (void)esc;
    (void)sm;
  }

  // The master toggled the repeat request of a mailbox SyncManager.
  virtual void on_mailbox_repeat(Esc& esc, std::size_t sm) {
    (void)esc;
    (void)sm;
  }

  // The master enabled or disabled a SyncManager, or changed its configuration.
  virtual void on_sync_manager_changed(Esc& esc, std::size_t sm) {
    (void)esc;
    (void)sm;
  }

  // Time passes (called before a frame that addresses the ESC, before every frame while
  // wants_advance() says so, and when the segment is idle).
  virtual void advance(Esc& esc, std::int64_t now_ns) {
    (void)esc;
    (void)now_ns;
  }
  // Whether advance(esc, now_ns) must run before the next frame even when no datagram of it
  // addresses this ESC: anything time-driven that shows without the master asking (a model that
  // moves, a watchdog about to act). An application that returns false is advanced only before
  // the frames that address it (and at idle advances). The default keeps every frame.
  virtual bool wants_advance(const Esc& esc, std::int64_t now_ns) const {
    (void)esc;
    (void)now_ns;
    return true;
  }
};

// The smallest firmware: the AL state machine with its standard transitions and no further
// checks. Devices build on StandardApplication (include/ecat/sim/standard_application.hpp); this
// one is for ESC-level tests and for couplers without process data.
class BasicApplication : public Application {
 public:
  void start(Esc& esc) override;
  void on_al_control(Esc& esc, std::uint16_t control) override;
  // Nothing in it is time-driven.
  bool wants_advance(const Esc& esc, std::int64_t now_ns) const override {
    (void)esc;
    (void)now_ns;
    return false;
  }
};

// The AL transition rules every device shares (ETG.1000.6): whether `from` → `to` is a valid
// request. Same-state requests are valid (they acknowledge errors).
bool al_transition_allowed(wire::AlState from, wire::AlState to) noexcept;

}  // namespace ecat::sim
