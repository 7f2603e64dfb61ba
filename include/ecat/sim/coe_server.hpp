// The slave side of the mailbox for a simulated device: a CoE server over an ObjectDictionary.
//
// A device's Application forwards four hooks to it:
//   on_buffer_written(esc, sm)       -> CoeServer::on_buffer_written   (requests in SM0)
//   on_buffer_read(esc, sm)          -> CoeServer::on_buffer_read      (SM1 fetched: next reply)
//   on_mailbox_repeat(esc, sm)       -> CoeServer::on_mailbox_repeat   (resend the last reply)
//   on_sync_manager_changed(esc, sm) -> CoeServer::on_sync_manager_changed (mailbox reset)
//
// It serves SDO upload/download (expedited, normal, segmented, complete access), the SDO
// information service (fragmented when a response exceeds the mailbox) and emergencies, answers
// other mailbox types with a mailbox error (unless a handler is installed for them), detects
// repeated requests by their mailbox counter, and queues replies while SM1 is still full.
//
// Fault hooks let the fault injector abort chosen transfers or corrupt chosen responses
// (upstream-inventory §4.5 B), and counters report progress for milestone scheduling.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <string_view>
#include <vector>

#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::sim {

class Esc;

// The step of an SDO transfer a response belongs to. `request` is the initiate step of either
// direction (it matches upload_init and download_init in rules).
enum class MailboxStage : std::uint8_t {
  request,
  upload_init,
  upload_segment,
  download_init,
  download_segment,
};
constexpr std::size_t kMailboxStageCount = 5;
// "request", "upload_init", "upload_segment", "download_init", "download_segment".
std::string_view to_string(MailboxStage stage) noexcept;

// Aborts a transfer of (index, subindex) at a stage with `code`; the transfer is discarded.
// Stages: request (an initiate upload or download), upload_init, download_init (one direction
// only), upload_segment, download_segment (the next segment request of that transfer).
struct SdoAbortRule {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  MailboxStage stage = MailboxStage::request;
  std::uint32_t code = 0;
  bool once = false;  // removed after it fired; otherwise sticky until clear_faults()
};

enum class ProtocolFaultKind : std::uint8_t {
  drop_response,            // no response at all (SM1 never fills): the master times out
  counter_mismatch,         // the response's mailbox counter is one ahead of the right one
  toggle_mismatch,          // segment responses: the toggle bit flipped
  mailbox_type,             // the mailbox type nibble replaced by `value` (0..15)
  coe_service,              // the CoE service nibble replaced by `value` (0..15)
  invalid_coe_payload,      // the mailbox data replaced by one byte (no complete CoE header)
  sdo_command,              // the first SDO byte (command) replaced by `value`
  invalid_segment_padding,  // upload segment: command 000t 111 1 (7 unused bytes, no data)
  segment_command,          // segment responses: the SDO part replaced by the one byte `value`
};
// "drop_response", "counter_mismatch", ...
std::string_view to_string(ProtocolFaultKind kind) noexcept;

struct ProtocolFault {
  ProtocolFaultKind kind = ProtocolFaultKind::drop_response;
  std::uint8_t value = 0;  // for mailbox_type, coe_service, sdo_command, segment_command

  friend bool operator==(const ProtocolFault&, const ProtocolFault&) = default;
};

// Corrupts the response to (index, subindex) at a stage (request matches both initiate stages).
struct ProtocolFaultRule {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  MailboxStage stage = MailboxStage::request;
  ProtocolFault fault{};
  bool once = false;  // removed after it fired; otherwise sticky until clear_faults()
};

// How the server numbers its replies' mailbox counters.
enum class ReplyCounterMode : std::uint8_t {
  sequence,      // its own counter 1..7, wrapping to 1, one step per mailbox sent (real slaves)
  echo_request,  // the counter of the request being answered (the reference simulator)
};

struct CoeServerConfig {
  std::size_t request_sm = 0;  // master -> slave mailbox
  std::size_t reply_sm = 1;    // slave -> master mailbox
  ReplyCounterMode counter_mode = ReplyCounterMode::sequence;
  bool sdo_info = true;         // serve the SDO information service
  bool complete_access = true;  // serve complete access (else abort 0x06010004)
  std::size_t max_queued_replies = 1024;
  // How long the firmware takes to answer: a reply (or any mailbox it sends) enters the reply SM
  // this long after it was produced, at the ESC's next advance() (before each frame, and when the
  // segment idles). 0: in the same datagram that delivered the request, as before. Real devices
  // take from a few hundred microseconds to milliseconds.
  std::chrono::nanoseconds reply_delay{0};
};

struct CoeServerStats {
  std::uint64_t mailboxes_received = 0;  // requests taken from the request SM
  std::uint64_t requests_served = 0;     // SDO and SDO information requests answered
  std::uint64_t duplicates = 0;          // repeated requests (same counter) not re-executed
  std::uint64_t aborts_sent = 0;         // SDO aborts (and SDO information errors) produced
  std::uint64_t mailbox_errors_sent = 0;
  std::uint64_t emergencies_sent = 0;
  std::uint64_t replies_sent = 0;     // mailboxes copied into the reply SM
  std::uint64_t replies_read = 0;     // ... and fetched by the master
  std::uint64_t repeats = 0;          // mailbox repeat requests served
  std::uint64_t faults_applied = 0;   // abort rules and protocol faults that fired
  std::uint64_t replies_dropped = 0;  // lost to a full queue or a disabled SM
  // Non-abort SDO responses per stage (request unused): produced, and fetched by the master.
  std::array<std::uint64_t, kMailboxStageCount> stage_responses{};
  std::array<std::uint64_t, kMailboxStageCount> stage_responses_read{};
};

// A reply mailbox another protocol handler produces: type and mailbox data.
// Faults on the replies of a protocol handler (VoE and the other non-CoE types a device serves
// through set_protocol_handler).
enum class HandlerFaultKind : std::uint8_t {
  drop_reply,    // the handler's replies to the next request are not sent
  garble_reply,  // they are cut to 3 bytes: shorter than any protocol header (VoE needs 6)
};
// "drop_reply", "garble_reply".
std::string_view to_string(HandlerFaultKind kind) noexcept;

struct HandlerFaultRule {
  wire::MailboxType type = wire::MailboxType::voe;
  HandlerFaultKind kind = HandlerFaultKind::drop_reply;
  bool once = true;  // removed after it fired; otherwise until clear_faults()
};

struct MailboxReply {
  wire::MailboxType type = wire::MailboxType::coe;
  std::vector<std::uint8_t> data;
};

class CoeServer {
 public:
  // Serves another mailbox type (FoE, EoE, VoE ...): gets the request header and data, returns
  // the replies (possibly none). Types without a handler are refused with mailbox error 0x02.
  using ProtocolHandler = std::function<std::vector<MailboxReply>(
      Esc& esc, const wire::MailboxHeader& header, wire::Bytes data)>;
  // Told when the master fetched an SDO response of a stage (not aborts): milestones.
  using StepObserver =
      std::function<void(MailboxStage stage, std::uint16_t index, std::uint8_t subindex)>;

  explicit CoeServer(ObjectDictionary& dictionary, CoeServerConfig config = {});

  // ---- Application hooks ----------------------------------------------------------------
  void on_buffer_written(Esc& esc, std::size_t sm);
  void on_buffer_read(Esc& esc, std::size_t sm);
  void on_mailbox_repeat(Esc& esc, std::size_t sm);
  // A mailbox SM disabled or reconfigured: transfers, queued replies and counters start over.
  void on_sync_manager_changed(Esc& esc, std::size_t sm);
  // Moves a delayed reply whose time has come into the reply SM (StandardApplication::advance).
  void advance(Esc& esc);
  // The same reset, for power cycles and the INIT state (faults and stats are kept).
  void reset();

  // ---- Device side ------------------------------------------------------------------------
  // Queues an emergency; it is sent when the reply SM is free (now, if it is).
  void queue_emergency(Esc& esc, const wire::Emergency& emergency);
  // Queues any mailbox (type + data) behind the pending replies.
  void queue_reply(Esc& esc, wire::MailboxType type, wire::Bytes data);
  void set_protocol_handler(wire::MailboxType type, ProtocolHandler handler);
  bool has_protocol_handler(wire::MailboxType type) const { return handlers_.contains(type); }
  void set_step_observer(StepObserver observer) { step_observer_ = std::move(observer); }

  // ---- Fault hooks --------------------------------------------------------------------------
  // Both replace an existing rule for the same (index, subindex, stage).
  void add_abort_rule(const SdoAbortRule& rule);
  void add_protocol_fault(const ProtocolFaultRule& rule);
  void add_handler_fault(const HandlerFaultRule& rule) { handler_faults_.push_back(rule); }
  const std::vector<HandlerFaultRule>& handler_faults() const noexcept { return handler_faults_; }
  void clear_faults();
  const std::vector<SdoAbortRule>& abort_rules() const noexcept { return abort_rules_; }
  const std::vector<ProtocolFaultRule>& protocol_faults() const noexcept {
    return protocol_faults_;
  }

  // ---- Observation ----------------------------------------------------------------------------
  const CoeServerStats& stats() const noexcept { return stats_; }
  bool transfer_in_progress() const noexcept { return transfer_.kind != TransferKind::none; }
  std::size_t queued_replies() const noexcept { return queue_.size(); }
  ObjectDictionary& dictionary() noexcept { return od_; }
  const CoeServerConfig& config() const noexcept { return config_; }

 private:
  enum class TransferKind : std::uint8_t { none, upload, download };
  struct Transfer {
    TransferKind kind = TransferKind::none;
    std::uint16_t index = 0;
    std::uint8_t subindex = 0;
    bool complete_access = false;
    bool toggle = false;  // the toggle the next segment request must carry
    std::uint32_t complete_size = 0;
    std::size_t offset = 0;  // upload: next byte to send
    std::vector<std::uint8_t> data;
  };
  // A mailbox waiting for (or sitting in) the reply SM.
  struct Pending {
    std::vector<std::uint8_t> bytes;   // header + data, exactly 6 + length
    std::optional<MailboxStage> step;  // an SDO response that counts as a milestone step
    std::uint16_t index = 0;
    std::uint8_t subindex = 0;
    std::uint64_t request_id = 0;  // which request produced it (0: none)
    std::int64_t ready_ns = 0;     // ESC time from which it may enter the reply SM
  };
  struct Response {
    std::vector<std::uint8_t> data;  // mailbox data (CoE header + service)
    wire::MailboxType type = wire::MailboxType::coe;
    std::optional<MailboxStage> stage;
    std::uint16_t index = 0;
    std::uint8_t subindex = 0;
    bool abort = false;
  };

  void handle_request(Esc& esc, wire::Bytes buffer);
  std::vector<Response> handle_coe(Esc& esc, wire::Bytes data);
  std::vector<Response> handle_sdo(Esc& esc, wire::Bytes data);
  Response upload_init(Esc& esc, std::uint16_t index, std::uint8_t subindex, bool complete_access);
  Response upload_segment(Esc& esc, bool toggle);
  Response download_init(Esc& esc, const wire::SdoInitiateDownloadRequest& request);
  Response download_segment(Esc& esc, const wire::SdoDownloadSegmentRequest& request);
  std::vector<Response> handle_sdo_info(wire::Bytes data, std::size_t max_data);
  Response sdo_abort(std::uint16_t index, std::uint8_t subindex, std::uint32_t code,
                     std::optional<MailboxStage> stage);
  static Response mailbox_error(wire::MailboxErrorCode code);
  std::optional<std::uint32_t> take_abort_rule(std::uint16_t index, std::uint8_t subindex,
                                               MailboxStage stage);
  std::optional<ProtocolFault> take_protocol_fault(std::uint16_t index, std::uint8_t subindex,
                                                   MailboxStage stage);
  std::uint8_t next_counter(std::uint8_t request_counter);
  void send_response(Esc& esc, Response response, std::uint8_t request_counter,
                     std::uint64_t request_id);
  void enqueue(Esc& esc, Pending pending);
  void pump(Esc& esc);
  std::size_t reply_capacity(const Esc& esc) const;

  ObjectDictionary& od_;
  CoeServerConfig config_;
  Transfer transfer_;
  std::deque<Pending> queue_;
  std::optional<Pending> in_sm_;      // the reply the reply SM holds now
  std::optional<Pending> last_sent_;  // the last reply copied into the reply SM (repeats)
  std::map<wire::MailboxType, ProtocolHandler> handlers_;
  std::vector<HandlerFaultRule> handler_faults_;
  std::vector<SdoAbortRule> abort_rules_;
  std::vector<ProtocolFaultRule> protocol_faults_;
  StepObserver step_observer_;
  CoeServerStats stats_;
  std::uint8_t counter_ = 0;               // last reply counter (sequence mode)
  std::uint8_t last_request_counter_ = 0;  // for duplicate detection; 0 = none
  std::uint64_t request_id_ = 0;
  std::uint64_t last_request_id_ = 0;
  std::vector<Pending> last_replies_;  // the replies to the last request (duplicates)
};

}  // namespace ecat::sim
