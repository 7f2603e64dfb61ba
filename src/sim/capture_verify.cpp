#include <algorithm>
#include <array>
#include <set>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/sim/capture_verify.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>

#include "config/spec_tree.hpp"

namespace ecat::sim {

namespace reg = wire::reg;
using wire::Command;

namespace {

constexpr std::array<VerifyRule, 11> kRules{{
    {"write_data",
     "data of datagrams that only write (APWR, FPWR, BWR, LWR) or that no slave "
     "answered (recorded WKC 0)",
     "the ESCs return such data unchanged, so comparing it proves nothing; the WKC still is"},
    {"dc_time",
     "registers 0x0900..0x09FF (DC receive times, system time, offset, delay, drift "
     "filter, SYNC/latch times)",
     "they hold nanosecond clocks of the real devices, or values the master computed from them"},
    {"error_counters",
     "registers 0x0300..0x0313 (RX, forwarded RX, processing-unit, PDI error "
     "and lost-link counters)",
     "they count physical-layer events of the real wiring"},
    {"watchdog", "registers 0x0440..0x0443 (process-data watchdog status and counters)",
     "they depend on how long the master's cycles took"},
    {"reserved", "reserved bits of SII control 0x0502 (bits 1..4)",
     "the specifications leave them undefined and the real ESCs differ: the EL2828 and EL3004 read "
     "1 in bit 4, the EK1100 0, and the EL1004 of soem-sdinfo-ek1100-el1004 changes from 0 to 1 "
     "in the middle of the capture"},
    {"sii_busy",
     "SII control 0x0503 bits 8..10 (command) and 15 (busy) when one side shows busy "
     "and the other does not",
     "the simulated EEPROM is busy for one fixed time per slave (estimated from the capture), the "
     "real one varies with the I2C transfer"},
    {"mailbox_stale", "bytes of a mailbox read after the mailbox message (6-byte header + length)",
     "real ESC RAM keeps what an earlier message left there; the simulator clears the rest"},
    {"inputs",
     "process-data inputs: logical-read bytes mapped by a read FMMU, physical reads of an "
     "input SyncManager",
     "they are the real sensors' values at that moment"},
    {"al_transition",
     "AL status 0x0130..0x0131 while the recorded slave still shows a state it "
     "had before the last AL control write",
     "real firmware takes milliseconds to change state, the simulated firmware answers at once"},
    {"mailbox_latency",
     "status byte of a read-direction mailbox SyncManager while the recorded "
     "slave has not yet put its reply there (mailbox-full bit clear)",
     "real firmware takes time to answer a request, the simulated firmware answers at once"},
    {"mailbox_pdi",
     "status bits 1 (read event), 6 and 7 (buffer open) of read-direction mailbox "
     "SyncManagers",
     "they show the firmware's own PDI accesses to the buffer (it opens the next reply early), "
     "which depend on firmware timing"},
}};

// Nanoseconds from `from` to `to`: 0 when `to` is earlier, at most about 31 years (damaged
// captures may hold any timestamps; the arithmetic must not overflow).
std::int64_t elapsed_ns(std::int64_t from, std::int64_t to) noexcept {
  constexpr std::uint64_t kLimit = std::uint64_t{1} << 60;
  if (to <= from) return 0;
  const std::uint64_t d = static_cast<std::uint64_t>(to) - static_cast<std::uint64_t>(from);
  return static_cast<std::int64_t>(std::min(d, kLimit));
}

std::string hex(wire::Bytes bytes, std::size_t max = 64) {
  std::string out;
  for (std::size_t i = 0; i < bytes.size() && i < max; ++i) {
    out += fmt::format("{}{:02x}", i ? " " : "", bytes[i]);
  }
  if (bytes.size() > max) out += " ..";
  return out;
}

bool command_reads_data(Command c) {
  switch (c) {
    case Command::aprd:
    case Command::aprw:
    case Command::fprd:
    case Command::fprw:
    case Command::brd:
    case Command::brw:
    case Command::lrd:
    case Command::lrw:
    case Command::armw:
    case Command::frmw:
      return true;
    default:
      return false;
  }
}

std::string address_text(const wire::DatagramHeader& h) {
  switch (wire::addressing_of(h.command)) {
    case wire::Addressing::logical:
      return fmt::format("log=0x{:08x}", h.address);
    case wire::Addressing::none:
      return fmt::format("addr=0x{:08x}", h.address);
    default:
      return fmt::format("adp=0x{:04x} ado=0x{:04x}", h.adp(), h.ado());
  }
}

// Per-ESC state the comparison rules follow between frames.
struct EscTrack {
  std::vector<std::uint16_t> earlier_al_status;  // states the real slave may still show
};

class Verifier {
 public:
  Verifier(const CaptureTrace& trace, Segment& segment, const VerifyOptions& options)
      : trace_(trace), segment_(segment), options_(options), track_(segment.size()) {}

  Result<VerifyReport> run();

 private:
  std::vector<std::size_t> targets(const wire::DatagramHeader& h) const;
  void rules(const wire::DatagramHeader& h, wire::Bytes expected, wire::Bytes actual,
             std::vector<std::uint8_t>& mask, std::set<std::string>& applied,
             std::set<std::string>& hid);
  void compare(std::size_t exchange, std::size_t k, const wire::DatagramView& request,
               const std::optional<wire::DatagramView>& recorded,
               const std::optional<wire::DatagramView>& simulated);

  const CaptureTrace& trace_;
  Segment& segment_;
  VerifyOptions options_;
  std::vector<EscTrack> track_;
  std::vector<std::size_t> order_;  // processing order: position -> slave index
  VerifyReport report_;
};

std::vector<std::size_t> Verifier::targets(const wire::DatagramHeader& h) const {
  switch (wire::addressing_of(h.command)) {
    case wire::Addressing::station: {
      for (std::size_t i = 0; i < segment_.size(); ++i) {
        if (segment_.esc(i).station_address() == h.adp()) return {i};
      }
      return {};
    }
    case wire::Addressing::position: {
      const std::size_t pos = static_cast<std::uint16_t>(0x10000 - h.adp());
      if (pos < order_.size()) return {order_[pos]};
      return {};
    }
    case wire::Addressing::broadcast:
      return order_;
    default:
      return {};
  }
}

void Verifier::rules(const wire::DatagramHeader& h, wire::Bytes expected, wire::Bytes actual,
                     std::vector<std::uint8_t>& mask, std::set<std::string>& applied,
                     std::set<std::string>& hid) {
  const std::size_t n = mask.size();
  auto clear = [&](std::size_t i, std::uint8_t bits, const char* rule) {
    if ((mask[i] & bits) == 0) return;
    if (((expected[i] ^ actual[i]) & mask[i] & bits) != 0) hid.insert(rule);
    mask[i] = static_cast<std::uint8_t>(mask[i] & ~bits);
    applied.insert(rule);
  };
  const auto addressing = wire::addressing_of(h.command);
  if (addressing == wire::Addressing::logical) {
    // Bytes some slave fills from its inputs.
    for (std::size_t s = 0; s < segment_.size(); ++s) {
      const Esc& esc = segment_.esc(s);
      const std::size_t count = std::min<std::size_t>(esc.hardware().fmmu_count, reg::kMaxFmmus);
      for (std::size_t f = 0; f < count; ++f) {
        const auto& fmmu = esc.fmmu(f);
        if (!fmmu.active || fmmu.length == 0 || fmmu.type == wire::FmmuType::write) continue;
        const std::uint64_t first = fmmu.logical_start;
        const std::uint64_t end = first + fmmu.length;
        for (std::size_t i = 0; i < n; ++i) {
          const std::uint64_t a = static_cast<std::uint64_t>(h.address) + i;
          if (a >= first && a < end) clear(i, 0xFF, "inputs");
        }
      }
    }
    return;
  }
  const auto t = targets(h);
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t a = h.ado() + static_cast<std::uint32_t>(i);
    if (a >= 0x0900 && a < 0x0A00) clear(i, 0xFF, "dc_time");
    if (a >= reg::kRxErrorCounter && a < 0x0314) clear(i, 0xFF, "error_counters");
    if (a >= 0x0440 && a < 0x0444) clear(i, 0xFF, "watchdog");
    if (a == reg::kSiiControl) clear(i, 0x1E, "reserved");
    if (a == reg::kSiiControl + 1 && ((expected[i] ^ actual[i]) & 0x87) != 0 &&
        ((expected[i] & 0x80) != 0 || (actual[i] & 0x80) != 0)) {
      clear(i, 0x87, "sii_busy");
    }
  }
  // Mailbox and process-data SyncManagers of the addressed slave.
  if (t.size() == 1) {
    const Esc& esc = segment_.esc(t.front());
    const std::size_t count =
        std::min<std::size_t>(esc.hardware().sync_manager_count, reg::kMaxSyncManagers);
    for (std::size_t m = 0; m < count; ++m) {
      const auto& sm = esc.sync_manager(m);
      const std::uint32_t base = reg::sync_manager(m);
      const bool mailbox = sm.config.control.mode == wire::SmMode::mailbox;
      const bool ecat_reads = sm.config.control.direction == wire::SmDirection::read;
      // The SM's status byte.
      const std::uint32_t status = base + reg::kSyncManagerStatusOffset;
      if (mailbox && ecat_reads && status >= h.ado() && status < h.ado() + n) {
        const std::size_t i = status - h.ado();
        clear(i, 0xC2, "mailbox_pdi");
        if ((expected[i] & 0x08) == 0 && (actual[i] & 0x08) != 0) clear(i, 0x09, "mailbox_latency");
      }
      if (!sm.enabled || sm.config.length == 0) continue;
      const std::uint32_t start = sm.config.physical_start;
      const std::uint32_t end = start + sm.config.length;
      if (mailbox && ecat_reads && h.ado() == start && n >= wire::kMailboxHeaderSize) {
        const std::size_t message = wire::kMailboxHeaderSize + wire::load_le16(expected.data());
        for (std::size_t i = message; i < n && h.ado() + i < end; ++i) {
          clear(i, 0xFF, "mailbox_stale");
        }
      } else if (!mailbox && ecat_reads) {
        for (std::size_t i = 0; i < n; ++i) {
          const std::uint32_t a = h.ado() + static_cast<std::uint32_t>(i);
          if (a >= start && a < end) clear(i, 0xFF, "inputs");
        }
      }
    }
  }
  // AL status that still shows an earlier state on the real slave.
  const std::uint32_t al = reg::kAlStatus;
  if (h.ado() <= al && h.ado() + n >= al + 2 && !t.empty()) {
    const std::size_t i = al - h.ado();
    const std::uint16_t recorded = wire::load_le16(expected.data() + i);
    const std::uint16_t simulated = wire::load_le16(actual.data() + i);
    if (recorded != simulated) {
      // Values the addressed slaves could show together (BRD ORs them).
      std::set<std::uint16_t> candidates{0};
      for (std::size_t s : t) {
        std::set<std::uint16_t> next;
        std::vector<std::uint16_t> own = track_[s].earlier_al_status;
        own.push_back(segment_.esc(s).read_u16(reg::kAlStatus));
        for (std::uint16_t c : candidates) {
          for (std::uint16_t v : own)
            next.insert(static_cast<std::uint16_t>(c | v));
        }
        candidates = std::move(next);
        if (candidates.size() > 256) break;
      }
      if (candidates.contains(recorded)) {
        clear(i, 0xFF, "al_transition");
        clear(i + 1, 0xFF, "al_transition");
      }
    } else if (t.size() == 1) {
      track_[t.front()].earlier_al_status.clear();  // the real slave caught up
    }
  }
}

void Verifier::compare(std::size_t exchange, std::size_t k, const wire::DatagramView& request,
                       const std::optional<wire::DatagramView>& recorded,
                       const std::optional<wire::DatagramView>& simulated) {
  const auto& e = trace_.exchanges[exchange];
  const auto& h = request.header;
  auto& tally = report_.per_command[h.command];
  ++report_.datagrams;
  ++tally.datagrams;
  if (!recorded && e.after_last_reply) return;

  DatagramMismatch m;
  m.frame = trace_.frames[e.request].number;
  m.reply_frame = e.reply ? trace_.frames[*e.reply].number : 0;
  m.datagram = k;
  m.command = h.command;
  m.address = h.address;
  if (recorded) m.expected_wkc = recorded->wkc;
  if (simulated) m.actual_wkc = simulated->wkc;

  ++report_.wkc_compared;
  ++tally.wkc_compared;
  bool wkc_ok = recorded.has_value() == simulated.has_value();
  if (recorded && simulated) {
    wkc_ok =
        recorded->wkc == simulated->wkc && recorded->header.address == simulated->header.address;
  }
  if (wkc_ok) {
    ++report_.wkc_matched;
    ++tally.wkc_matched;
  } else {
    m.wkc_differs = true;
    if (!recorded) {
      m.detail = fmt::format("the real segment did not answer, the simulator did (WKC {})",
                             simulated->wkc);
    } else if (!simulated) {
      m.detail =
          fmt::format("the real segment answered (WKC {}), the simulator did not", recorded->wkc);
    } else if (recorded->wkc != simulated->wkc) {
      m.detail = fmt::format("WKC expected {}, got {}", recorded->wkc, simulated->wkc);
    } else {
      m.detail = fmt::format("returned address expected 0x{:08x}, got 0x{:08x}",
                             recorded->header.address, simulated->header.address);
    }
  }

  std::set<std::string> applied;
  std::set<std::string> hid;
  if (recorded && simulated && recorded->data.size() == simulated->data.size()) {
    if (!command_reads_data(h.command) || recorded->wkc == 0) {
      applied.insert("write_data");
    } else {
      std::vector<std::uint8_t> mask(recorded->data.size(), 0xFF);
      rules(h, recorded->data, simulated->data, mask, applied, hid);
      const bool compared = std::any_of(mask.begin(), mask.end(), [](auto b) { return b != 0; });
      if (compared) {
        ++report_.data_compared;
        ++tally.data_compared;
        std::optional<std::size_t> first;
        for (std::size_t i = 0; i < mask.size() && !first; ++i) {
          if (((recorded->data[i] ^ simulated->data[i]) & mask[i]) != 0) first = i;
        }
        if (!first) {
          ++report_.data_matched;
          ++tally.data_matched;
        } else {
          m.data_differs = true;
          m.expected_data.assign(recorded->data.begin(), recorded->data.end());
          m.actual_data.assign(simulated->data.begin(), simulated->data.end());
          const std::size_t i = *first;
          const std::string where = wire::addressing_of(h.command) == wire::Addressing::logical
                                        ? fmt::format("logical 0x{:08x}", h.address + i)
                                        : fmt::format("0x{:04x}", h.ado() + i);
          const std::string text =
              fmt::format("data at {} (byte {}): expected 0x{:02x}, got 0x{:02x}", where, i,
                          recorded->data[i], simulated->data[i]);
          m.detail = m.detail.empty() ? text : m.detail + "; " + text;
        }
      }
    }
  }
  for (const auto& rule : applied)
    ++report_.exclusions[rule];
  for (const auto& rule : hid)
    ++report_.differences_left_out[rule];
  if (m.wkc_differs || m.data_differs) report_.mismatches.push_back(std::move(m));
}

Result<VerifyReport> Verifier::run() {
  report_.source = trace_.source;
  report_.malformed_frames = trace_.malformed_frames;
  order_ = segment_.processing_order();
  if (trace_.exchanges.empty()) return report_;
  const std::int64_t t0 = trace_.frames[trace_.exchanges.front().request].timestamp_ns;
  std::int64_t now = options_.start_ns;
  std::vector<std::uint8_t> buffer;
  std::vector<std::uint16_t> before(segment_.size());
  for (std::size_t x = 0; x < trace_.exchanges.size(); ++x) {
    const auto& e = trace_.exchanges[x];
    const CaptureFrame& rq = trace_.frames[e.request];
    now = std::max(now, options_.start_ns + elapsed_ns(t0, rq.timestamp_ns));
    for (std::size_t s = 0; s < segment_.size(); ++s) {
      before[s] = segment_.esc(s).read_u16(reg::kAlStatus);
    }
    buffer = rq.frame;
    const bool replied = segment_.process_frame(buffer, now);
    ++report_.requests;
    if (e.reply) ++report_.recorded_replies;
    if (!e.reply && e.after_last_reply) ++report_.unanswered_at_end;

    const auto request = wire::decode_frame(rq.frame);
    if (!request) {
      return Error(Errc::malformed, fmt::format("frame {} of {} does not decode: {}", rq.number,
                                                trace_.source, request.error.describe()));
    }
    std::optional<wire::FrameDecodeResult> recorded;
    if (e.reply) recorded = wire::decode_frame(trace_.frames[*e.reply].frame);
    std::optional<wire::FrameDecodeResult> simulated;
    if (replied) simulated = wire::decode_frame(buffer);
    auto rec_it = recorded && *recorded ? recorded->frame->begin() : wire::FrameView::Iterator{};
    auto sim_it = simulated && *simulated ? simulated->frame->begin() : wire::FrameView::Iterator{};
    std::size_t k = 0;
    for (const wire::DatagramView d : *request.frame) {
      std::optional<wire::DatagramView> r;
      std::optional<wire::DatagramView> s;
      if (recorded && *recorded && k < recorded->frame->datagram_count()) r = *rec_it++;
      if (simulated && *simulated && k < simulated->frame->datagram_count()) s = *sim_it++;
      compare(x, k, d, r, s);
      ++k;
    }
    // State changes the real slaves may show later than the simulated ones.
    for (std::size_t s = 0; s < segment_.size(); ++s) {
      const std::uint16_t after = segment_.esc(s).read_u16(reg::kAlStatus);
      if (after != before[s]) {
        auto& earlier = track_[s].earlier_al_status;
        if (std::find(earlier.begin(), earlier.end(), before[s]) == earlier.end()) {
          earlier.push_back(before[s]);
        }
      }
    }
  }
  return report_;
}

}  // namespace

std::span<const VerifyRule> verify_rules() noexcept {
  return kRules;
}

std::string VerifyReport::summary_line() const {
  return fmt::format("datagrams={} wkc_match={}/{} data_match={}/{} malformed={}", datagrams,
                     wkc_matched, wkc_compared, data_matched, data_compared, malformed_frames);
}

Result<VerifyReport> verify_capture(const CaptureTrace& trace, Segment& segment,
                                    const VerifyOptions& options) {
  Verifier verifier(trace, segment, options);
  return verifier.run();
}

namespace {

std::string mismatch_line(const DatagramMismatch& m) {
  wire::DatagramHeader h;
  h.command = m.command;
  h.address = m.address;
  return fmt::format("frame {} datagram {} {} {}: {}", m.frame, m.datagram,
                     wire::to_string(m.command), address_text(h), m.detail);
}

}  // namespace

std::string format_verify_report(const VerifyReport& r) {
  std::string out = fmt::format("capture: {}\n", r.source);
  out += fmt::format(
      "requests: {} ({} with a recorded reply, {} unanswered at the end of the "
      "capture, not compared)\n\n",
      r.requests, r.recorded_replies, r.unanswered_at_end);
  out +=
      fmt::format("{:<8}{:>10}{:>18}{:>18}\n", "command", "datagrams", "wkc match", "data match");
  for (const auto& [command, t] : r.per_command) {
    out += fmt::format("{:<8}{:>10}{:>18}{:>18}\n", wire::to_string(command), t.datagrams,
                       fmt::format("{}/{}", t.wkc_matched, t.wkc_compared),
                       fmt::format("{}/{}", t.data_matched, t.data_compared));
  }
  if (!r.exclusions.empty()) {
    out += "\nleft out of the data comparison (datagrams; of which differed):\n";
    for (const auto& rule : verify_rules()) {
      auto it = r.exclusions.find(std::string(rule.id));
      if (it == r.exclusions.end()) continue;
      auto differed = r.differences_left_out.find(std::string(rule.id));
      out += fmt::format(
          "  {:<16}{:>7}{:>7}  {}\n", rule.id, it->second,
          differed == r.differences_left_out.end() ? std::size_t{0} : differed->second, rule.what);
    }
  }
  out += fmt::format("\nmismatches: {}\n", r.mismatches.size());
  for (const auto& m : r.mismatches) {
    out += "  " + mismatch_line(m) + "\n";
    if (m.data_differs) {
      out += fmt::format("    expected {}\n    actual   {}\n", hex(m.expected_data),
                         hex(m.actual_data));
    }
  }
  if (r.malformed_frames > 0) {
    out += fmt::format("\nmalformed EtherCAT frames (do not decode; counted as errors): {}\n",
                       r.malformed_frames);
  }
  if (r.wkc_compared == 0) {
    out += "\nnothing was compared: the capture holds no request with a recorded reply\n";
  }
  out += r.summary_line() + "\n";
  return out;
}

std::string verify_report_json(const VerifyReport& r) {
  // Ordered: the counts a reader looks for come first, in the order the text report shows them.
  using Json = nlohmann::ordered_json;
  Json per_command = Json::object();
  for (const auto& [command, t] : r.per_command) {
    per_command[std::string(wire::to_string(command))] = Json{{"datagrams", t.datagrams},
                                                              {"wkc_compared", t.wkc_compared},
                                                              {"wkc_matched", t.wkc_matched},
                                                              {"data_compared", t.data_compared},
                                                              {"data_matched", t.data_matched}};
  }
  Json exclusions = Json::object();
  for (const auto& [rule, count] : r.exclusions)
    exclusions[rule] = count;
  Json differences_left_out = Json::object();
  for (const auto& [rule, count] : r.differences_left_out)
    differences_left_out[rule] = count;
  Json mismatches = Json::array();
  for (const auto& m : r.mismatches) {
    wire::DatagramHeader h;
    h.command = m.command;
    h.address = m.address;
    mismatches.push_back(Json{{"frame", m.frame},
                              {"reply_frame", m.reply_frame},
                              {"datagram", m.datagram},
                              {"command", wire::to_string(m.command)},
                              {"address", address_text(h)},
                              {"expected_wkc", m.expected_wkc ? Json(*m.expected_wkc) : Json()},
                              {"actual_wkc", m.actual_wkc ? Json(*m.actual_wkc) : Json()},
                              {"wkc_differs", m.wkc_differs},
                              {"data_differs", m.data_differs},
                              {"expected_data", hex(m.expected_data, 4096)},
                              {"actual_data", hex(m.actual_data, 4096)},
                              {"detail", m.detail}});
  }
  const Json out{{"source", r.source},
                 {"requests", r.requests},
                 {"recorded_replies", r.recorded_replies},
                 {"unanswered_at_end", r.unanswered_at_end},
                 {"datagrams", r.datagrams},
                 {"wkc_compared", r.wkc_compared},
                 {"wkc_matched", r.wkc_matched},
                 {"data_compared", r.data_compared},
                 {"data_matched", r.data_matched},
                 {"malformed_frames", r.malformed_frames},
                 {"passed", r.passed()},
                 {"per_command", std::move(per_command)},
                 {"exclusions", std::move(exclusions)},
                 {"differences_left_out", std::move(differences_left_out)},
                 {"mismatches", std::move(mismatches)},
                 {"summary", r.summary_line()}};
  return config::detail::dump_json(out, 2) + "\n";
}

}  // namespace ecat::sim
