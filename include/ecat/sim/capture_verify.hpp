// Proving the simulator against real hardware: replay the master's requests of a capture, in
// order and at their capture times, against a simulated segment and compare every reply with the
// one the real segment sent.
//
// Working counters (and the addresses auto-increment and broadcast datagrams come back with) are
// always compared, as is whether a reply came back at all. Data is compared where it does not
// depend on time or on the physical world; verify_rules() lists each exclusion with its reason,
// and the report counts how often each one applied, so nothing is hidden.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/capture_profile.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::sim {

// One rule that takes bytes (or bits) out of the data comparison.
struct VerifyRule {
  std::string_view id;    // "dc_time", "inputs", ...
  std::string_view what;  // which bytes
  std::string_view why;   // why they cannot be expected to match
};
std::span<const VerifyRule> verify_rules() noexcept;

struct DatagramMismatch {
  std::uint64_t frame = 0;        // packet number of the master's request in the capture
  std::uint64_t reply_frame = 0;  // packet number of the recorded reply (0: none)
  std::size_t datagram = 0;       // 0-based position in the frame
  wire::Command command = wire::Command::nop;
  std::uint32_t address = 0;                  // as the master sent it
  std::optional<std::uint16_t> expected_wkc;  // nullopt: no reply
  std::optional<std::uint16_t> actual_wkc;
  bool wkc_differs = false;  // WKC, returned address or presence of the reply
  bool data_differs = false;
  std::vector<std::uint8_t> expected_data;  // filled when data_differs
  std::vector<std::uint8_t> actual_data;
  std::string detail;  // what differs first, in words
};

struct CommandTally {
  std::size_t datagrams = 0;
  std::size_t wkc_compared = 0;
  std::size_t wkc_matched = 0;
  std::size_t data_compared = 0;
  std::size_t data_matched = 0;
};

struct VerifyReport {
  std::string source;
  std::size_t requests = 0;           // master frames replayed
  std::size_t recorded_replies = 0;   // of which the capture has the reply
  std::size_t unanswered_at_end = 0;  // no reply recorded, capture over (not compared)
  std::size_t datagrams = 0;
  std::size_t wkc_compared = 0;
  std::size_t wkc_matched = 0;
  std::size_t data_compared = 0;  // datagrams with at least one compared bit
  std::size_t data_matched = 0;
  std::size_t malformed_frames = 0;  // EtherCAT frames of the capture that do not decode
  std::map<wire::Command, CommandTally> per_command;
  std::map<std::string, std::size_t> exclusions;  // rule id -> datagrams it applied to
  // rule id -> datagrams in which it left out bits that differed (without the rule they would
  // be mismatches): what each rule actually hides.
  std::map<std::string, std::size_t> differences_left_out;
  std::vector<DatagramMismatch> mismatches;

  double data_ratio() const noexcept {
    return data_compared == 0
               ? 1.0
               : static_cast<double>(data_matched) / static_cast<double>(data_compared);
  }
  // Something was compared, every compared WKC matches, at least 99 % of the compared data does,
  // and no frame of the capture was malformed (a capture that cannot be read whole proves
  // nothing about what it left out).
  bool passed() const noexcept {
    return wkc_compared > 0 && malformed_frames == 0 && wkc_matched == wkc_compared &&
           data_ratio() >= 0.99;
  }
  // "datagrams=N wkc_match=A/B data_match=C/D malformed=M"
  std::string summary_line() const;
};

struct VerifyOptions {
  // Time of the first frame in segment nanoseconds (the segment's clock starts at 0).
  std::int64_t start_ns = 1'000'000;
};

// Replays `trace` against `segment` (which it changes: it is the simulated bus the master talks
// to) and compares. Fails only when a recorded frame cannot be replayed (never for traces built
// by load_capture_trace).
Result<VerifyReport> verify_capture(const CaptureTrace& trace, Segment& segment,
                                    const VerifyOptions& options = {});

// The report as text: per-command table, exclusions, every mismatch, then the summary line.
std::string format_verify_report(const VerifyReport& report);
// The report as JSON (one object; the summary line under "summary").
std::string verify_report_json(const VerifyReport& report);

}  // namespace ecat::sim
