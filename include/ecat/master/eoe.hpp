// Ethernet over EtherCAT (EoE, mailbox type 2, ETG.1000.6 §5.7), the master's side: Ethernet
// frames tunnelled to and from a slave through its mailbox, and the Set IP Parameter service.
//
// Fragmentation (the facts as ETG.1000.6 §5.7 lays them out; SOEM's ethercateoe.c and IgH's
// fsm_eoe agree): a frame goes out as fragments numbered 0, 1, 2 ... of one frame number (0..15,
// one step per frame). Every fragment but the last carries a multiple of 32 bytes, because the
// offset field counts 32-byte blocks: fragment 0 carries the size of the whole frame in blocks
// ((bytes + 31) / 32), every later fragment its offset in the frame (bytes / 32). The last
// fragment has "last fragment" set. A fragment fills the mailbox as far as that rule allows.
//
// Reassembly of what the slave sends (bounded, hostile bytes): a frame starts with fragment 0 and
// grows only with the next fragment number of the same frame number at exactly the offset
// reached so far; anything else (a lost fragment, one out of order, a new fragment 0 while a
// frame is open, a frame beyond its announced size or beyond kEoeMaxFrameSize, a frame shorter
// than an Ethernet header) drops the frame in progress and is counted. A fragment that belongs to
// no open frame is dropped and counted too.
//
// Nothing here runs in the cyclic path: the tasks are mailbox traffic on the control thread.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <ecat/exec/task.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/eoe.hpp>

namespace ecat::master {

// An Ethernet frame without its FCS: 14 bytes of header at least, at most 1500 bytes of payload
// plus a 4-byte VLAN tag.
constexpr std::size_t kEoeMinFrameSize = 14;
constexpr std::size_t kEoeMaxFrameSize = 1518;

struct EoeOptions {
  std::uint8_t port = 0;  // the EoE port (0..15) frames are sent to
  // For each fragment written into the mailbox (a full SM0 is retried until then).
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // Pause between two reads of an empty SM1 while eoe_receive waits: 1 ms keeps the acyclic
  // traffic of an idle tunnel small.
  std::chrono::nanoseconds poll_interval = std::chrono::milliseconds(1);
};

struct EoeStats {
  std::uint64_t frames_sent = 0;
  std::uint64_t fragments_sent = 0;
  std::uint64_t frames_received = 0;     // complete frames reassembled
  std::uint64_t fragments_received = 0;  // EoE fragments taken from the mailbox
  std::uint64_t frames_dropped = 0;      // frames in progress abandoned (see above)
  std::uint64_t fragments_dropped = 0;   // fragments of no open frame, undecodable EoE messages
  std::uint64_t other_dropped = 0;       // EoE frame types nobody waited for (late responses ...)
};

// The mailbox data (EoE header + part of the frame) of each fragment of `frame`, for a mailbox
// that carries `max_data` bytes of data. Errc::invalid_argument for a frame outside
// kEoeMinFrameSize..kEoeMaxFrameSize or a frame number / port beyond 15, Errc::unsupported when
// the mailbox cannot carry the EoE header and one 32-byte block.
Result<std::vector<std::vector<std::uint8_t>>> eoe_fragments(std::span<const std::uint8_t> frame,
                                                             std::size_t max_data,
                                                             std::uint8_t frame_number,
                                                             std::uint8_t port = 0);

// The EoE state of one slave: the frame counter, the frame being reassembled, the counters.
// Used on the control thread only.
class EoeClient {
 public:
  explicit EoeClient(EoeOptions options = {}) : options_(options) {}

  // Sends one Ethernet frame in fragments (the mailbox is held for the whole frame). `timeout`:
  // for each fragment, options().timeout when not given.
  exec::Task<Result<void>> send(Mailbox& mailbox, std::vector<std::uint8_t> frame,
                                std::optional<std::chrono::nanoseconds> timeout = std::nullopt);
  // The frames completed from the EoE fragments queued in the mailbox, else from those the slave
  // sends within `timeout` (SM1 polled every poll_interval). Empty when none came in time: an
  // idle tunnel is not an error. Errors are the mailbox's (a failed read, a mailbox error).
  exec::Task<Result<std::vector<std::vector<std::uint8_t>>>> receive(
      Mailbox& mailbox, std::chrono::nanoseconds timeout);
  // Set IP Parameter request and its response: Errc::mailbox_error (value: the EoE result code,
  // message: wire::eoe_result_text) when the slave refuses, Errc::timeout without a response.
  exec::Task<Result<void>> set_ip(Mailbox& mailbox, wire::EoeIpParameters parameters,
                                  std::chrono::nanoseconds timeout);

  // Takes one fragment as it came from the slave: the frame it completes, if any.
  std::optional<std::vector<std::uint8_t>> accept(const wire::EoeFragment& fragment);
  // Takes one EoE mailbox message (any frame type): the frame it completes, if any.
  std::optional<std::vector<std::uint8_t>> accept(wire::Bytes mailbox_data);
  // Forgets the frame in progress (after the mailbox was reset); counters are kept.
  void reset() noexcept;

  const EoeStats& stats() const noexcept { return stats_; }
  const EoeOptions& options() const noexcept { return options_; }

 private:
  void drop_frame() noexcept;
  // Takes every queued EoE message of the mailbox into `frames`.
  void drain(Mailbox& mailbox, std::vector<std::vector<std::uint8_t>>& frames);

  EoeOptions options_;
  EoeStats stats_;
  std::uint8_t tx_frame_number_ = 0;
  // The frame being reassembled.
  bool open_ = false;
  std::uint8_t rx_frame_number_ = 0;
  std::uint8_t next_fragment_ = 0;
  std::size_t announced_ = 0;  // fragment 0's size in blocks, as bytes
  std::vector<std::uint8_t> rx_;
};

// The EoE result code an EoE refusal carried (searching the error's causes), or nullopt.
std::optional<std::uint16_t> eoe_result_code(const Error& error) noexcept;

}  // namespace ecat::master
