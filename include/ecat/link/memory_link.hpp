// In-process links for tests and the embedded simulator: no sockets, no privileges.
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <utility>

#include <ecat/link/link.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::link {

// Two connected ends ("memory:a", "memory:b"): a frame sent on one is received on the other.
// Each direction is a bounded queue of `queue_depth` preallocated frame slots; send() copies the
// frame into a slot and never allocates or blocks. When the queue is full the frame is dropped and
// counted in the sender's LinkStats::frames_dropped, as a congested wire would lose it. After one
// end is closed (or destroyed) the other end receives what is still queued, then Errc::closed;
// its send() fails with Errc::closed.
std::pair<std::unique_ptr<Link>, std::unique_ptr<Link>> make_memory_link_pair(
    std::size_t queue_depth = 64);

// Where a FrameHandler puts its replies.
class ReplySink {
 public:
  // Queues a copy of `frame` for receive(). Returns false, and counts the frame in frames_dropped,
  // when the reply queue is full or the frame is larger than wire::kMaxFrameSize.
  virtual bool reply(wire::Bytes frame) = 0;

 protected:
  ~ReplySink() = default;
};

// Called synchronously inside send() with the sent frame; may reply any number of times
// (including none: a lost frame).
using FrameHandler = std::function<void(wire::Bytes request, ReplySink& replies)>;

struct FunctionLinkOptions {
  std::string name = "function";
  // Replies that may wait for receive() at once.
  std::size_t reply_queue_depth = 16;
};

// A Link whose send() hands the frame to `handler` in the caller's thread (e.g. a simulated
// segment) and whose receive() returns the replies in order: deterministic, no threads, no
// allocation per frame. Since nothing can arrive while no send() runs, receive() on an empty
// queue returns std::nullopt at once instead of sleeping through the timeout.
std::unique_ptr<Link> make_function_link(FrameHandler handler, FunctionLinkOptions options = {});

}  // namespace ecat::link
