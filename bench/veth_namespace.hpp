// Benchmarks over a real kernel path without touching the host's network: a veth pair in a private
// network namespace, and a bare echo to measure the pair's own round trip (the floor any EtherCAT
// stack on it sits on). Shared by sim_bench and master_bench.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <initializer_list>
#include <memory>
#include <string>
#include <thread>

#include <fcntl.h>
#include <sched.h>
#include <unistd.h>

#include <ecat/link/link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::bench {

// Echoes every frame it receives, as fast as the link allows.
class Echo {
 public:
  explicit Echo(link::Link& link) : link_(link), thread_([this] { run(); }) {}
  ~Echo() {
    stop_ = true;
    link_.interrupt();
    thread_.join();
  }
  Echo(const Echo&) = delete;
  Echo& operator=(const Echo&) = delete;

 private:
  void run() {
    using namespace std::chrono_literals;
    std::array<std::uint8_t, wire::kMaxFrameSize> copy{};
    while (!stop_) {
      auto r = link_.receive(100ms);
      if (!r.ok()) return;
      if (!r->has_value()) continue;
      const auto frame = (*r)->frame;
      std::copy(frame.begin(), frame.end(), copy.begin());
      (void)link_.send(wire::Bytes(copy.data(), frame.size()));
    }
  }
  link::Link& link_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// A veth pair "m" / "s" (or one "m<suffix>" / "s<suffix>" per suffix given: "m0"/"s0" and
// "m1"/"s1" for a redundant link's two cables) in an anonymous network namespace of the
// constructing thread (threads it starts afterwards inherit it); gone when the links close and
// the thread returns to its original namespace. Construct, use and destroy it on one thread.
class VethPair {
 public:
  explicit VethPair(std::initializer_list<const char*> suffixes = {""}) {
    if (geteuid() != 0) {
      problem_ = "needs root to create a veth pair in a private network namespace";
      return;
    }
    original_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    if (original_ < 0 || ::unshare(CLONE_NEWNET) != 0) {
      problem_ = "network namespaces are not available";
      return;
    }
    for (const std::string n : suffixes) {
      const std::string command = "ip link add name m" + n + " type veth peer name s" + n +
                                  " >/dev/null 2>&1 && ip link set dev m" + n +
                                  " up && ip link set dev s" + n + " up";
      if (std::system(command.c_str()) != 0) {
        problem_ = "cannot create a veth pair (is `ip` installed?)";
      }
    }
  }
  ~VethPair() {
    if (original_ >= 0) {
      (void)::setns(original_, CLONE_NEWNET);
      ::close(original_);
    }
  }
  VethPair(const VethPair&) = delete;
  VethPair& operator=(const VethPair&) = delete;

  // Empty while the pair is usable; else why not.
  const std::string& problem() const { return problem_; }

  // A raw link on "m" (the master's end) or "s" (responder: the segment's end); null with
  // problem() set when it cannot be opened.
  std::unique_ptr<link::RawLink> open(const std::string& name, bool responder) {
    link::RawLinkOptions options;
    options.interface = name;
    options.kernel_filter = true;
    options.responder = responder;
    auto opened = link::RawLink::open(options);
    if (!opened.ok()) {
      problem_ = opened.error().describe();
      return nullptr;
    }
    return std::move(*opened);
  }

 private:
  int original_ = -1;
  std::string problem_;
};

}  // namespace ecat::bench
