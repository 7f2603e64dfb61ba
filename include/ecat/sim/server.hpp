// Serving a simulated segment to a master: a SimServer owns a Segment and its FaultInjector and
// answers frames that arrive on a Link — an in-process memory pair, a UDP server socket or a raw
// interface in responder mode — on its own thread. Or, with function_link(), in the caller's
// thread: the master's send() processes the frame synchronously, deterministic and without a
// thread (the fastest way to run a master against the simulator in tests).
//
// Segment time is CLOCK_MONOTONIC in nanoseconds (or the clock in the options). While no frames
// arrive the serving thread still advances the segment at least every `advance_period`, so
// watchdogs, SYNC pulses and drive dynamics keep running; it never sleep-polls: it blocks in
// receive() until the next frame or the next deadline.
//
// Every control operation is thread-safe and may be used while serving.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/al.hpp>

namespace ecat::sim {

struct SimServerOptions {
  // Segment time in nanoseconds; CLOCK_MONOTONIC when empty. Must not go backwards.
  std::function<std::int64_t()> clock{};
  // The longest the segment goes without advance() while the link is idle.
  std::chrono::nanoseconds advance_period = std::chrono::milliseconds(1);
  // Profile name of each slave, for status (make_server fills it from the ring).
  std::vector<std::string> profiles{};
};

struct SimServerStats {
  std::uint64_t frames = 0;      // frames received
  std::uint64_t replies = 0;     // replies sent (a duplicated reply counts twice)
  std::uint64_t lost = 0;        // frames without a reply: faults, topology, link down
  std::uint64_t malformed = 0;   // not EtherCAT frames: ignored
  std::uint64_t delayed = 0;     // replies held back by delay or reorder faults
  std::uint64_t duplicated = 0;  // extra copies sent by duplicate_reply
  std::uint64_t send_errors = 0;
  std::uint64_t receive_errors = 0;
  std::uint64_t idle_advances = 0;  // advance() calls without a frame
};

struct SlaveStatus {
  std::size_t index = 0;  // ring position
  std::string name;
  std::string profile;
  std::uint32_t vendor_id = 0;  // from the SII
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::uint16_t station = 0;
  std::uint16_t alias = 0;
  wire::AlState al_state = wire::AlState::init;
  bool al_error = false;
  std::uint16_t al_status_code = 0;
  bool dc = false;
  std::array<bool, 4> links{};  // link up per port (connected or not)
};

struct SimStatus {
  std::int64_t time_ns = 0;
  std::string link;  // what the serving thread serves, "" when it does not
  std::vector<SlaveStatus> slaves;
  SimServerStats counters;
  SegmentStats segment;
  FaultStats fault_stats;
  FaultInfo faults;
  std::vector<Segment::HotConnectGroupInfo> hot_connect;
};

class SimServer {
 public:
  explicit SimServer(std::unique_ptr<Segment> segment, SimServerOptions options = {});
  ~SimServer();  // stops serving
  SimServer(const SimServer&) = delete;
  SimServer& operator=(const SimServer&) = delete;

  // ---- Serving --------------------------------------------------------------------------
  // Answers frames arriving on `link` on a new thread until stop(). Errc::wrong_state when
  // already serving.
  Result<void> serve(std::unique_ptr<link::Link> link);
  // Serves one end of a new memory pair; returns the master's end.
  Result<std::unique_ptr<link::Link>> serve_memory(std::size_t queue_depth = 64);
  void stop();
  bool serving() const;

  // A link for the master whose send() processes the frame right away in the caller's thread;
  // receive() returns the replies. The server must outlive it. Delayed replies come out at the
  // first send() after they are due (as a late reply would).
  std::unique_ptr<link::Link> function_link(std::string name = "sim");

  // For a transport of its own (RedundantPorts serving two raw interfaces): advances the segment
  // when `advance_period` passed since it last did, lets time-scheduled faults fire, and returns
  // how long until that is due again (what a serving thread may wait for a frame).
  std::chrono::nanoseconds tick();

  // Processes one frame synchronously and returns the replies that leave now (normally one;
  // none for a lost frame; more for duplicates or released delayed replies).
  std::vector<std::vector<std::uint8_t>> exchange(wire::Bytes frame);

  // ---- Control (thread-safe) -----------------------------------------------------------
  Result<void> inject(const Fault& fault);
  void clear_faults();
  FaultInfo fault_info() const;

  Result<std::vector<SignalInfo>> signals(std::string_view slave) const;
  Result<double> signal(std::string_view slave, std::string_view signal) const;
  // Forces an input the device senses (sticky until clear_input).
  Result<void> set_input(std::string_view slave, std::string_view signal, double value);
  Result<void> clear_input(std::string_view slave, std::string_view signal);
  // Register or RAM bytes of a slave's ESC (address + length within the ESC's memory).
  Result<std::vector<std::uint8_t>> read_memory(std::string_view slave, std::uint32_t address,
                                                std::size_t length) const;
  Result<void> power_cycle(std::string_view slave);
  Result<void> set_link(std::string_view slave, std::uint8_t port, bool up);
  void set_master_link(bool up);
  // Plugs or unplugs a hot-connect group (through the injector's cabling: FaultInjector::plug).
  Result<void> plug(std::string_view group, bool plugged);

  SimStatus status() const;
  SimServerStats stats() const;
  std::size_t slave_count() const;
  std::int64_t now_ns() const;

  // Runs `f(Segment&, FaultInjector&)` under the server's lock (for what the API above lacks).
  template <class F>
  decltype(auto) with_segment(F&& f) {
    std::lock_guard lock(mutex_);
    return f(*segment_, *injector_);
  }

  struct Impl;

 private:
  mutable std::mutex mutex_;
  std::unique_ptr<Segment> segment_;
  std::unique_ptr<FaultInjector> injector_;
  std::unique_ptr<Impl> impl_;
};

// A server for a ring: builds the segment (build_segment), then injects the ring's start faults.
Result<std::unique_ptr<SimServer>> make_server(const Ring& ring, SimServerOptions options = {});

}  // namespace ecat::sim
