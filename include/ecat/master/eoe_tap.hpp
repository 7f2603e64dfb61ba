// A Linux TAP interface per EoE slave: ordinary tools (ping, ssh, a web browser) reach the device
// behind the ring. The interface ("eoe0s<position>" unless named) carries Ethernet frames
// (IFF_TAP | IFF_NO_PI); two threads of its own move them:
//   - TAP -> slave: waits on the interface (poll), reads each frame and hands it to
//     Slave::eoe_send;
//   - slave -> TAP: calls Slave::eoe_receive in a loop and writes each frame to the interface.
// Both go through the Slave's blocking calls, i.e. acyclic mailbox traffic on the control thread
// (never the cyclic path). Frames from the interface are hostile too: shorter than an Ethernet
// header or longer than 1518 bytes they are dropped and counted. A failing slave call (the slave
// went down, left PREOP) is counted and retried after a pause, and the interface stays.
//
// Creating the interface needs CAP_NET_ADMIN: without it open() fails with
// Errc::permission_denied naming the capability. The interface goes with the EoeTap (its
// descriptor closed). It is created in the network namespace of the calling thread.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include <ecat/result.hpp>

namespace ecat::master {

class Slave;

struct EoeTapOptions {
  // The interface's name (at most 15 characters); empty: "eoe0s<slave position>".
  std::string name{};
  // Set the interface up, and give it this IPv4 address / prefix length when present
  // (192.168.1.1 is 0xC0A80101).
  bool up = true;
  std::optional<std::uint32_t> address{};
  std::uint8_t prefix_length = 24;
  // How long one eoe_receive waits before the thread looks at its stop flag again.
  std::chrono::milliseconds receive_timeout{20};
  // Pause after a failed slave call.
  std::chrono::milliseconds error_pause{100};
};

struct EoeTapStats {
  std::uint64_t to_slave = 0;        // frames from the interface sent to the slave
  std::uint64_t from_slave = 0;      // frames from the slave written to the interface
  std::uint64_t dropped = 0;         // frames of the interface too short / too long
  std::uint64_t send_errors = 0;     // failed eoe_send calls (the frame is lost)
  std::uint64_t receive_errors = 0;  // failed eoe_receive calls
  std::uint64_t write_errors = 0;    // frames the interface did not take
};

class EoeTap {
 public:
  // Creates the interface for `slave` (which must outlive the EoeTap) and starts its threads.
  static Result<std::unique_ptr<EoeTap>> open(Slave& slave, EoeTapOptions options = {});
  ~EoeTap();
  EoeTap(const EoeTap&) = delete;
  EoeTap& operator=(const EoeTap&) = delete;

  const std::string& name() const noexcept { return name_; }
  EoeTapStats stats() const noexcept;
  // Stops the threads (the interface stays until the EoeTap goes). Idempotent.
  void stop();

 private:
  EoeTap(Slave& slave, int fd, int wake, std::string name, EoeTapOptions options);
  void to_slave_loop();
  void from_slave_loop();

  Slave& slave_;
  int fd_ = -1;
  int wake_ = -1;  // an eventfd that wakes the TAP reader on stop()
  std::string name_;
  EoeTapOptions options_;
  std::atomic<bool> running_{true};
  std::atomic<std::uint64_t> to_slave_{0}, from_slave_{0}, dropped_{0}, send_errors_{0},
      receive_errors_{0}, write_errors_{0};
  std::thread reader_;
  std::thread writer_;
};

}  // namespace ecat::master
