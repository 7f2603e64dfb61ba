// A signal resolved once, then read and written without lookups, locks or allocation: what a
// per-cycle callback (DomainConfig::on_cycle) uses to reach process data.
//
//   auto in = ecat::master::SignalHandle::resolve(master, "inputs", "channel_1");   // control side
//   ...
//   // in the cycle callback:
//   if (auto v = in->read()) { ... }
//
// Resolution (control side, on a running session whose slaves have their PREOP configuration)
// looks the slave and the signal up once and keeps where the signal lives: the domain(s) its
// SyncManager is registered in and its registration there. read() and write() then go straight to
// the domains' process images (the signal's Domain::Field: read_fresh / write_bits): they never
// take a mutex, never wait for the control thread and allocate nothing on success (scalar signals;
// errors build a message). Values are in engineering units, as Slave::read_input / write_output use
// them.
//
// Threads: a handle is used by one thread at a time (it owns a scratch copy of its SyncManager
// image); copy it for another thread. It refers to the session's domains, so it is valid until
// Master::stop(), like the Slave* Master::slave() returns; a default-constructed handle is
// unbound and its calls fail with Errc::not_ready.
//
// Writes change only the signal's own bits of the staged output image (Domain::write_bits): two
// handles of one SyncManager do not disturb each other. Like Slave::write_output, a write also
// keeps the bits in the slave's retained copy of the SyncManager image (under the slave's output
// lock), which the slave restages whole after a reconnect and for a `bytes` signal's
// write_output: handles and the Slave may write outputs of one SyncManager alike.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/master/domain.hpp>
#include <ecat/master/pdo.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

class Master;
class Slave;

class SignalHandle {
 public:
  SignalHandle() = default;

  // Errc::not_found naming the slave or the signal (with the signals the slave has), or a signal
  // not routed to any domain; Errc::not_ready before the slave's PREOP configuration or when no
  // session runs; Errc::unsupported for a signal wider than 64 bits (Slave::read_input reads
  // those).
  static Result<SignalHandle> resolve(Master& master, std::string_view slave,
                                      std::string_view signal);

  bool bound() const noexcept { return !targets_.empty(); }
  const std::string& slave() const noexcept { return slave_; }
  const Signal& signal() const noexcept { return signal_; }
  PdoDirection direction() const noexcept { return signal_.direction; }

  // An input's latest value, failing closed: Errc::not_ready before the first valid cycle,
  // Errc::stale when the last valid cycle is older than the domain's freshness window. An
  // output's staged value (Errc::not_ready until written).
  Result<Value> read() const;
  // Stages an output for the next cycle of every domain its SyncManager is in. Errc::invalid_
  // argument for an input or a value the signal cannot hold (the message names both).
  Result<void> write(const Value& value);

 private:
  struct Target {
    Domain* domain = nullptr;
    PdoHandle pdo{};
    Domain::Field field{};  // the signal's bits in the registration (Domain::field)
  };
  Slave* owner_ = nullptr;  // valid until Master::stop(), like the handle
  std::string slave_{};
  Signal signal_{};
  // The signal moved to bit 0: encode() fills a 64-bit word with it for Domain::write_bits.
  Signal field_{};
  bool scalar_ =
      false;  // not `bytes`: read and staged as its own bits (decode_field / encode_field)
  std::vector<Target> targets_{};  // inputs: one; outputs: every domain of the SyncManager
  mutable std::vector<std::uint8_t> image_{};  // scratch: one SyncManager image
};

}  // namespace ecat::master
