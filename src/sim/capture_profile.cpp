#include <algorithm>
#include <array>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <set>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/capture/capture_file.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/capture_profile.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "config/spec_tree.hpp"
#include "sim/devices/applications.hpp"
#include "sim/devices/profiles.hpp"

namespace ecat::sim {

namespace reg = wire::reg;
using wire::Command;

// ---------------------------------------------------------------------------------------------
// Trace: frames and their pairing

namespace {

constexpr std::size_t kMaxOpenRequests = 256;

// What identifies a reply's request: per datagram the command, index, length and the address
// bytes no slave changes (auto-increment and broadcast commands count ADP up on the way).
struct Signature {
  std::vector<std::uint64_t> keys;
  bool operator==(const Signature&) const = default;
};

std::optional<Signature> signature_of(wire::Bytes frame) {
  const auto decoded = wire::decode_frame(frame);
  if (!decoded) return std::nullopt;
  Signature s;
  for (const wire::DatagramView d : *decoded.frame) {
    const auto addressing = wire::addressing_of(d.header.command);
    std::uint32_t address = d.header.address;
    if (addressing == wire::Addressing::position || addressing == wire::Addressing::broadcast) {
      address &= 0xFFFF0000u;
    }
    s.keys.push_back((static_cast<std::uint64_t>(d.header.command) << 56) |
                     (static_cast<std::uint64_t>(d.header.index) << 48) |
                     (static_cast<std::uint64_t>(d.header.length) << 32) | address);
  }
  return s;
}

}  // namespace

FrameDirection frame_direction(const capture::EtherCatPacket& packet) noexcept {
  if (packet.encapsulation == capture::Encapsulation::udp &&
      packet.udp_source_port != packet.udp_destination_port) {
    return packet.udp_destination_port == wire::kEtherCatUdpPort ? FrameDirection::master
                                                                 : FrameDirection::slave;
  }
  if (packet.source) {
    return ((*packet.source)[0] & 0x02) != 0 ? FrameDirection::slave : FrameDirection::master;
  }
  if (packet.outgoing) return *packet.outgoing ? FrameDirection::master : FrameDirection::slave;
  return FrameDirection::unknown;
}

CaptureTrace pair_capture_frames(std::vector<CaptureFrame> frames,
                                 std::vector<FrameDirection> directions, std::string source) {
  CaptureTrace trace;
  trace.source = std::move(source);
  struct Open {
    std::size_t exchange = 0;
    Signature signature;
  };
  std::vector<Open> open;
  directions.resize(frames.size(), FrameDirection::unknown);
  for (std::size_t i = 0; i < frames.size(); ++i) {
    auto signature = signature_of(frames[i].frame);
    if (!signature) {
      ++trace.malformed_frames;
      continue;
    }
    auto match = open.end();
    if (directions[i] != FrameDirection::master) {
      match = std::find_if(open.begin(), open.end(),
                           [&](const Open& o) { return o.signature == *signature; });
    }
    // By content, a byte-identical copy of an open request is its retry (a segment that nobody
    // answered returns frames unchanged, but then nothing comes back to a capture either).
    const bool identical =
        match != open.end() &&
        trace.frames[trace.exchanges[match->exchange].request].frame == frames[i].frame;
    const bool reply =
        directions[i] == FrameDirection::slave ||
        (directions[i] == FrameDirection::unknown && match != open.end() && !identical);
    frames[i].from_master = !reply;
    const std::size_t index = trace.frames.size();
    trace.frames.push_back(std::move(frames[i]));
    if (reply) {
      ++trace.replies;
      if (match == open.end()) {
        ++trace.orphan_replies;
      } else {
        trace.exchanges[match->exchange].reply = index;
        open.erase(match);
      }
      continue;
    }
    // A request repeated before its reply came: the earlier one is lost (a master's retry).
    open.erase(std::remove_if(open.begin(), open.end(),
                              [&](const Open& o) { return o.signature == *signature; }),
               open.end());
    if (open.size() >= kMaxOpenRequests) open.erase(open.begin());
    trace.exchanges.push_back(CaptureExchange{index, std::nullopt, false});
    open.push_back(Open{trace.exchanges.size() - 1, std::move(*signature)});
  }
  // Requests after the last reply of the capture: nothing tells whether they were answered.
  std::optional<std::size_t> last_reply;
  for (std::size_t i = 0; i < trace.frames.size(); ++i) {
    if (!trace.frames[i].from_master) last_reply = i;
  }
  for (auto& e : trace.exchanges) {
    if (!e.reply && last_reply && e.request > *last_reply) e.after_last_reply = true;
  }
  return trace;
}

Result<CaptureTrace> load_capture_trace(capture::CaptureFile& file, std::string source) {
  std::vector<CaptureFrame> frames;
  std::vector<FrameDirection> directions;
  std::size_t other = 0;
  while (true) {
    auto packet = file.next();
    if (!packet) return packet.error();
    if (!*packet) break;
    const capture::Packet& p = **packet;
    if (!capture::link_type_supported(p.link_type)) {
      return Error(Errc::unsupported,
                   fmt::format("capture '{}': packet {} has link type {}, which is not supported "
                               "(Ethernet, Linux cooked SLL and SLL2 are)",
                               source, p.number, p.link_type));
    }
    const auto ethercat = capture::extract_ethercat(p.link_type, p.data);
    if (!ethercat) {
      ++other;
      continue;
    }
    CaptureFrame frame;
    frame.number = p.number;
    frame.timestamp_ns = p.timestamp_ns;
    frame.frame.assign(ethercat->frame.begin(), ethercat->frame.end());
    frames.push_back(std::move(frame));
    directions.push_back(frame_direction(*ethercat));
  }
  CaptureTrace trace =
      pair_capture_frames(std::move(frames), std::move(directions), std::move(source));
  trace.other_packets = other;
  return trace;
}

Result<CaptureTrace> load_capture_trace(const std::string& path) {
  auto file = capture::CaptureFile::open(path);
  if (!file) return file.error();
  return load_capture_trace(*file, std::filesystem::path(path).filename().string());
}

std::string_view to_string(Evidence evidence) noexcept {
  switch (evidence) {
    case Evidence::observed:
      return "observed";
    case Evidence::inferred:
      return "inferred";
    case Evidence::assumed:
      return "assumed";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// Profile building

namespace {

constexpr std::uint32_t kRegisterAreaSize = 0x1000;
constexpr std::size_t kDefaultEepromBytes = 2048;
constexpr std::size_t kMaxEepromBytes = 64 * 1024;
constexpr std::uint16_t kDcSystemTimeFirst = 0x0910;
constexpr std::uint16_t kDcLast = 0x09FF;

// Nanoseconds from `from` to `to`: 0 when `to` is earlier, at most about 31 years (damaged
// captures may hold any timestamps; the arithmetic must not overflow).
std::int64_t elapsed_ns(std::int64_t from, std::int64_t to) noexcept {
  constexpr std::uint64_t kLimit = std::uint64_t{1} << 60;
  if (to <= from) return 0;
  const std::uint64_t d = static_cast<std::uint64_t>(to) - static_cast<std::uint64_t>(from);
  return static_cast<std::int64_t>(std::min(d, kLimit));
}

bool sm_is_mailbox(std::uint8_t control) {
  return (control & 0x03) == 0x02;
}
bool sm_ecat_writes(std::uint8_t control) {
  return (control & 0x0C) == 0x04;
}

// ESC classes the profile falls back on when the capture does not show a value.
struct EscClass {
  std::uint8_t type;
  std::uint8_t fmmus;
  std::uint8_t sms;
  std::uint8_t ram_kib;
  std::uint8_t ports;  // port descriptor byte
  std::uint16_t features;
  const char* label;
};
// A coupler-class ESC (ET1100, as the EK1100 reports: MII/EBUS/MII ports) and a terminal-class
// ESC (ET1200, as the EL1004 reports: two EBUS ports, port 3 configured by the SII).
constexpr EscClass kCouplerClass{0x11, 8, 8, 8, 0x3B, 0x00FC, "ET1100-class (coupler)"};
constexpr EscClass kTerminalClass{0x12, 3, 4, 1, 0x4A, 0x01FC, "ET1200-class (terminal)"};

struct SdoTransfer {
  bool upload = true;
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  bool complete_access = false;
  std::uint32_t size = 0;
  std::vector<std::uint8_t> data;
  bool segmented = false;
  bool active = false;
};

struct SlaveState {
  // Register shadow as far as the capture shows it (writes and reads of this slave).
  std::array<std::uint8_t, kRegisterAreaSize> shadow{};
  std::array<bool, kRegisterAreaSize> written{};
  std::map<std::uint16_t, std::uint8_t> initial;
  // SII
  std::optional<std::uint32_t> sii_read_address;
  std::map<std::uint32_t, std::uint16_t> sii_words;
  std::optional<bool> sii_8_bytes;
  std::optional<bool> sii_two_address_bytes;  // 0x0502 bit 7 as read
  std::optional<bool> sii_emulation;          // 0x0502 bit 5 as read
  std::optional<bool> enhanced_link;          // DL status 0x0110 bit 2 as read
  // How long the EEPROM stays busy: polls after a read command that still showed busy (lower
  // bound) and the first that did not (upper bound), in capture nanoseconds.
  std::optional<std::int64_t> sii_command_ns;
  std::int64_t sii_busy_lo = 0;
  std::optional<std::int64_t> sii_busy_hi;
  bool sii_busy_seen = false;
  // FMMU / SM counts: per-slave bounds [lo, hi].
  int fmmu_lo = 0, fmmu_hi = 16, sm_lo = 0, sm_hi = 16;
  std::optional<bool> system_time;  // from a per-slave access of 0x0910..0x09FF
  // AL
  std::optional<std::uint16_t> last_al_control;
  bool al_control_pending = false;  // written, not read back yet
  int emulation_for = 0;
  int emulation_against = 0;
  std::optional<std::uint16_t> first_al_status;  // before any AL control write
  // AL control writes the device refused: AL status read back with the error indicator and
  // another state. By requested state: the AL status code (0x0134), once read.
  std::map<std::uint8_t, std::optional<std::uint16_t>> refused;
  bool al_outcome_pending = false;  // AL control written; neither reached nor refused yet
  std::optional<std::uint8_t> refusal_awaiting_code;  // refused, 0x0134 not read since
  std::set<std::uint8_t> reached;                     // states the device showed without error
  bool al_control_seen = false;
  // CoE
  SdoTransfer sdo;
  std::map<std::pair<std::uint16_t, std::uint8_t>, CapturedObject> objects;
  bool addressed = false;  // answered at least one datagram
};

class ProfileBuilder {
 public:
  explicit ProfileBuilder(const CaptureTrace& trace) : trace_(trace) {}

  Result<CaptureProfile> build();

 private:
  struct Pair {
    wire::DatagramView request;
    wire::DatagramView reply;
    std::int64_t time_ns = 0;
  };

  void count_slaves();
  void assign_stations();
  std::vector<std::size_t> targets(const Pair& p);
  void observe(const Pair& p);
  void observe_write(std::size_t slave, std::uint16_t ado, wire::Bytes data, std::int64_t time_ns);
  void observe_read(std::size_t slave, std::uint16_t ado, wire::Bytes data, std::int64_t time_ns);
  void observe_mailbox(std::size_t slave, std::uint16_t ado, wire::Bytes data, bool from_master);
  void observe_sdo(std::size_t slave, wire::Bytes mailbox, bool from_master);
  void observe_counts(const Pair& p);
  CaptureSlaveProfile finish_slave(std::size_t position);
  void reconcile_hardware(std::vector<CaptureSlaveProfile>& slaves);

  template <class F>
  void for_each_pair(F&& f) {
    for (const auto& e : trace_.exchanges) {
      if (!e.reply) continue;
      const auto& rq = trace_.frames[e.request];
      const auto& rp = trace_.frames[*e.reply];
      const auto a = wire::decode_frame(rq.frame);
      const auto b = wire::decode_frame(rp.frame);
      if (!a || !b || a.frame->datagram_count() != b.frame->datagram_count()) continue;
      auto ib = b.frame->begin();
      for (const wire::DatagramView d : *a.frame) {
        f(Pair{d, *ib, rq.timestamp_ns});
        ++ib;
      }
    }
  }

  const CaptureTrace& trace_;
  std::size_t count_ = 0;
  std::vector<SlaveState> slaves_;
  std::map<std::uint16_t, std::size_t> station_to_position_;
  std::vector<std::optional<std::uint16_t>> station_of_;
  std::vector<bool> preset_;
  std::vector<ProfileNote> notes_;
  // Broadcast evidence: register offset -> the largest WKC a broadcast access of it returned.
  std::map<std::uint16_t, std::uint16_t> fmmu_broadcast_, sm_broadcast_;
  std::optional<std::uint16_t> dc_broadcast_;  // slaves whose system time took a broadcast write
  std::array<std::optional<std::uint8_t>, 10> info_or_{};  // BRD of 0x0000..0x0009 (OR)
};

void ProfileBuilder::count_slaves() {
  std::set<std::uint16_t> stations;
  for_each_pair([&](const Pair& p) {
    const auto addressing = wire::addressing_of(p.request.header.command);
    if (addressing == wire::Addressing::position || addressing == wire::Addressing::broadcast) {
      const auto passed = static_cast<std::uint16_t>(p.reply.header.adp() - p.request.header.adp());
      count_ = std::max<std::size_t>(count_, passed);
    }
    if (addressing == wire::Addressing::station && p.reply.wkc > 0 &&
        p.request.header.command != Command::frmw) {
      stations.insert(p.request.header.adp());
    }
  });
  if (count_ == 0 && !stations.empty()) {
    count_ = stations.size();
    notes_.push_back({"slave_count", Evidence::inferred,
                      fmt::format("no broadcast or auto-increment datagram came back: {} station "
                                  "addresses answered",
                                  count_)});
  } else {
    notes_.push_back({"slave_count", Evidence::observed,
                      "address increments of broadcast / auto-increment datagrams"});
  }
}

void ProfileBuilder::assign_stations() {
  // Pass over the capture in order: APWR 0x0010 assigns, FPWR 0x0010 moves, APRD 0x0010 shows.
  station_of_.assign(count_, std::nullopt);
  preset_.assign(count_, false);
  std::vector<bool> assigned(count_, false);
  std::vector<std::uint16_t> unknown;  // stations used before anything assigned them
  std::map<std::uint16_t, std::size_t> current;
  for_each_pair([&](const Pair& p) {
    const auto& h = p.request.header;
    const bool covers_station =
        h.ado() <= reg::kStationAddress && h.ado() + h.length >= reg::kStationAddress + 2;
    const std::size_t off = reg::kStationAddress - h.ado();
    if ((h.command == Command::apwr || h.command == Command::aprw) && covers_station &&
        p.reply.wkc > 0) {
      const std::size_t pos = static_cast<std::uint16_t>(0x10000 - h.adp());
      if (pos < count_) {
        const std::uint16_t station = wire::load_le16(p.request.data.data() + off);
        std::erase_if(current, [&](const auto& kv) { return kv.second == pos; });
        current[station] = pos;
        assigned[pos] = true;
      }
    } else if (h.command == Command::aprd && covers_station && p.reply.wkc > 0) {
      const std::size_t pos = static_cast<std::uint16_t>(0x10000 - h.adp());
      const std::uint16_t station = wire::load_le16(p.reply.data.data() + off);
      if (pos < count_ && station != 0 && !current.contains(station)) current[station] = pos;
    } else if (wire::addressing_of(h.command) == wire::Addressing::station && p.reply.wkc > 0 &&
               h.command != Command::frmw) {
      if (!current.contains(h.adp()) &&
          std::find(unknown.begin(), unknown.end(), h.adp()) == unknown.end()) {
        unknown.push_back(h.adp());
      }
      if (h.command == Command::fpwr && covers_station && current.contains(h.adp())) {
        const std::size_t pos = current[h.adp()];
        current.erase(h.adp());
        current[wire::load_le16(p.request.data.data() + off)] = pos;
      }
    }
  });
  // Stations in use before the capture assigned any: the master configured the segment before
  // recording started. Without positional evidence, ascending stations go to the positions
  // nothing assigned, in order (masters number stations along the line).
  std::sort(unknown.begin(), unknown.end());
  std::size_t next = 0;
  for (std::uint16_t station : unknown) {
    while (next < count_ && assigned[next])
      ++next;
    if (next >= count_) break;
    station_of_[next] = station;
    preset_[next] = true;
    assigned[next] = true;
    ++next;
  }
}

std::vector<std::size_t> ProfileBuilder::targets(const Pair& p) {
  const auto& h = p.request.header;
  switch (wire::addressing_of(h.command)) {
    case wire::Addressing::position: {
      const std::size_t pos = static_cast<std::uint16_t>(0x10000 - h.adp());
      if (h.command == Command::armw) return {};
      if (pos < count_) return {pos};
      return {};
    }
    case wire::Addressing::station: {
      if (h.command == Command::frmw) return {};
      auto it = station_to_position_.find(h.adp());
      if (it != station_to_position_.end()) return {it->second};
      return {};
    }
    case wire::Addressing::broadcast: {
      std::vector<std::size_t> all(count_);
      for (std::size_t i = 0; i < count_; ++i)
        all[i] = i;
      return all;
    }
    default:
      return {};
  }
}

void ProfileBuilder::observe_write(std::size_t slave, std::uint16_t ado, wire::Bytes data,
                                   std::int64_t time_ns) {
  SlaveState& s = slaves_[slave];
  for (std::size_t i = 0; i < data.size(); ++i) {
    const std::uint32_t a = ado + static_cast<std::uint32_t>(i);
    if (a >= kRegisterAreaSize) break;
    s.written[a] = true;
    s.shadow[a] = data[i];
  }
  const std::uint32_t first = ado;
  const std::uint32_t last = ado + static_cast<std::uint32_t>(data.size()) - 1;
  auto covers = [&](std::uint32_t a) { return a >= first && a <= last; };
  // SII command: a read takes the address now in 0x0504..0x0507.
  if (covers(reg::kSiiControl + 1)) {
    const std::uint8_t command = s.shadow[reg::kSiiControl + 1] & 0x07;
    if (command == 0x01) {
      s.sii_read_address = wire::load_le32(&s.shadow[reg::kSiiAddress]);
      s.sii_command_ns = time_ns;
    } else {
      s.sii_read_address.reset();
    }
  }
  if (covers(reg::kAlControl)) {
    s.last_al_control = wire::load_le16(&s.shadow[reg::kAlControl]);
    s.al_control_pending = true;
    s.al_outcome_pending = true;
    s.al_control_seen = true;
  }
}

void ProfileBuilder::observe_read(std::size_t slave, std::uint16_t ado, wire::Bytes data,
                                  std::int64_t time_ns) {
  SlaveState& s = slaves_[slave];
  for (std::size_t i = 0; i < data.size(); ++i) {
    const std::uint32_t a = ado + static_cast<std::uint32_t>(i);
    if (a >= kRegisterAreaSize) break;
    if (!s.written[a] && !s.initial.contains(static_cast<std::uint16_t>(a))) {
      s.initial[static_cast<std::uint16_t>(a)] = data[i];
    }
    s.shadow[a] = data[i];
  }
  const std::uint32_t first = ado;
  const std::uint32_t last = ado + static_cast<std::uint32_t>(data.size()) - 1;
  auto covers = [&](std::uint32_t a) { return a >= first && a <= last; };
  if (covers(reg::kDlStatus)) {
    s.enhanced_link = (s.shadow[reg::kDlStatus] & 0x04) != 0;
  }
  if (covers(reg::kSiiControl)) {
    s.sii_emulation = (s.shadow[reg::kSiiControl] & wire::sii_control::kEmulation) != 0;
    s.sii_8_bytes = (s.shadow[reg::kSiiControl] & wire::sii_control::kReadSize8) != 0;
    s.sii_two_address_bytes =
        (s.shadow[reg::kSiiControl] & wire::sii_control::kTwoAddressBytes) != 0;
  }
  if (covers(reg::kSiiControl + 1) && s.sii_command_ns) {
    const std::int64_t since = elapsed_ns(*s.sii_command_ns, time_ns);
    if ((s.shadow[reg::kSiiControl + 1] & 0x80) != 0) {
      s.sii_busy_lo = std::max(s.sii_busy_lo, since);
      s.sii_busy_seen = true;
    } else {
      s.sii_busy_hi = std::min(s.sii_busy_hi.value_or(since), since);
      s.sii_command_ns.reset();
    }
  }
  if (covers(reg::kSiiData) && s.sii_read_address) {
    // The words the last read command fetched, as far as this read covers them.
    for (std::uint32_t a = std::max<std::uint32_t>(first, reg::kSiiData);
         a + 1 <= std::min<std::uint32_t>(last, reg::kSiiData + 7); a += 2) {
      if ((a - reg::kSiiData) % 2 != 0) continue;
      const std::uint32_t word = *s.sii_read_address + (a - reg::kSiiData) / 2;
      s.sii_words[word] = wire::load_le16(&s.shadow[a]);
    }
  }
  if (covers(reg::kAlStatus) && covers(reg::kAlStatus + 1)) {
    const std::uint16_t status = wire::load_le16(&s.shadow[reg::kAlStatus]);
    if (!s.al_control_seen && !s.first_al_status) s.first_al_status = status;
    if (s.al_control_pending && s.last_al_control) {
      // Device emulation copies AL control at once, acknowledge bit included.
      if ((status & 0x1F) == (*s.last_al_control & 0x1F)) {
        if ((*s.last_al_control & 0x10) != 0 || (status & 0x0F) != 0x01) ++s.emulation_for;
      } else {
        ++s.emulation_against;
      }
      s.al_control_pending = false;
    }
    if (s.al_outcome_pending && s.last_al_control) {
      // Refused: the error indicator with a state other than the one requested. A slave still
      // on its way shows the old state without the error (al_transition): keep waiting.
      const auto requested = static_cast<std::uint8_t>(*s.last_al_control & 0x0F);
      if ((status & 0x0F) == requested) {
        s.al_outcome_pending = false;
      } else if ((status & 0x10) != 0) {
        s.refused.try_emplace(requested);
        s.refusal_awaiting_code = requested;
        s.al_outcome_pending = false;
      }
    }
    if ((status & 0x10) == 0) s.reached.insert(static_cast<std::uint8_t>(status & 0x0F));
  }
  if (covers(reg::kAlStatusCode) && covers(reg::kAlStatusCode + 1) && s.refusal_awaiting_code) {
    const std::uint16_t code = wire::load_le16(&s.shadow[reg::kAlStatusCode]);
    if (code != 0) s.refused[*s.refusal_awaiting_code] = code;
    s.refusal_awaiting_code.reset();
  }
}

void ProfileBuilder::observe_mailbox(std::size_t slave, std::uint16_t ado, wire::Bytes data,
                                     bool from_master) {
  SlaveState& s = slaves_[slave];
  for (std::size_t i = 0; i < reg::kMaxSyncManagers; ++i) {
    const std::uint16_t base = reg::sync_manager(i);
    const std::uint16_t start = wire::load_le16(&s.shadow[base]);
    const std::uint16_t length = wire::load_le16(&s.shadow[base + 2]);
    const std::uint8_t control = s.shadow[base + 4];
    const bool enabled = (s.shadow[base + 6] & 0x01) != 0;
    if (!enabled || length == 0 || start != ado || !sm_is_mailbox(control)) continue;
    if (sm_ecat_writes(control) != from_master) continue;
    observe_sdo(slave, data, from_master);
    return;
  }
}

void ProfileBuilder::observe_sdo(std::size_t slave, wire::Bytes mailbox, bool from_master) {
  SlaveState& s = slaves_[slave];
  auto box = wire::decode_mailbox(mailbox);
  if (!box || box->header.type != wire::MailboxType::coe) return;
  auto message = wire::decode_sdo(box->data);
  if (!message) return;
  SdoTransfer& t = s.sdo;
  auto object = [&](std::uint16_t index, std::uint8_t subindex) -> CapturedObject& {
    auto& o = s.objects[{index, subindex}];
    o.index = index;
    o.subindex = subindex;
    return o;
  };
  auto finish_upload = [&] {
    auto& o = object(t.index, t.subindex);
    o.complete_access = t.complete_access;
    if (!o.uploaded && !o.downloaded) {
      o.value = t.data;
      if (t.size != 0 && o.value.size() > t.size) o.value.resize(t.size);
    }
    o.uploaded = true;
    o.abort_code.reset();
    t.active = false;
  };
  auto finish_download = [&] {
    auto& o = object(t.index, t.subindex);
    o.complete_access = t.complete_access;
    if (!o.uploaded && !o.downloaded) o.value = t.data;
    o.downloaded = true;
    o.abort_code.reset();
    t.active = false;
  };
  std::visit(
      [&](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, wire::SdoInitiateUploadRequest>) {
          if (!from_master) return;
          t = SdoTransfer{true, m.index, m.subindex, m.complete_access, 0, {}, false, true};
        } else if constexpr (std::is_same_v<T, wire::SdoInitiateUploadResponse>) {
          if (from_master || !t.active || !t.upload) return;
          t.data = m.data;
          t.size = m.expedited ? static_cast<std::uint32_t>(m.data.size()) : m.complete_size;
          if (m.expedited || t.data.size() >= t.size) {
            finish_upload();
          } else {
            t.segmented = true;
          }
        } else if constexpr (std::is_same_v<T, wire::SdoUploadSegmentResponse>) {
          if (from_master || !t.active || !t.upload) return;
          t.data.insert(t.data.end(), m.data.begin(), m.data.end());
          if (m.last) finish_upload();
        } else if constexpr (std::is_same_v<T, wire::SdoInitiateDownloadRequest>) {
          if (!from_master) return;
          t = SdoTransfer{false,
                          m.index,
                          m.subindex,
                          m.complete_access,
                          m.expedited ? static_cast<std::uint32_t>(m.data.size()) : m.complete_size,
                          m.data,
                          false,
                          true};
        } else if constexpr (std::is_same_v<T, wire::SdoDownloadSegmentRequest>) {
          if (!from_master || !t.active || t.upload) return;
          t.data.insert(t.data.end(), m.data.begin(), m.data.end());
          t.segmented = !m.last;
        } else if constexpr (std::is_same_v<T, wire::SdoInitiateDownloadResponse>) {
          if (from_master || !t.active || t.upload) return;
          if (t.data.size() >= t.size) finish_download();
        } else if constexpr (std::is_same_v<T, wire::SdoDownloadSegmentResponse>) {
          if (from_master || !t.active || t.upload) return;
          if (!t.segmented) finish_download();
        } else if constexpr (std::is_same_v<T, wire::SdoAbort>) {
          if (from_master || !t.active) return;
          auto& o = object(t.index, t.subindex);
          o.complete_access = t.complete_access;
          o.abort_code = m.code;
          t.active = false;
        }
      },
      *message);
}

void ProfileBuilder::observe_counts(const Pair& p) {
  const auto& h = p.request.header;
  const auto addressing = wire::addressing_of(h.command);
  const std::uint32_t first = h.ado();
  const std::uint32_t last = first + h.length - 1;
  if (h.length == 0 || first >= kRegisterAreaSize) return;
  auto block_index = [&](std::uint32_t base, std::uint32_t size,
                         std::uint32_t count) -> std::optional<std::uint32_t> {
    if (first < base || last >= base + size * count) return std::nullopt;
    if ((first - base) / size != (last - base) / size) return std::nullopt;
    return (first - base) / size;
  };
  const auto fmmu = block_index(reg::kFmmuBase, reg::kFmmuSize, reg::kMaxFmmus);
  const auto sm = block_index(reg::kSyncManagerBase, reg::kSyncManagerSize, reg::kMaxSyncManagers);
  const bool system_time = first >= kDcSystemTimeFirst && last <= kDcLast;
  if (addressing == wire::Addressing::broadcast) {
    // The most slaves that ever answered for a block (a broadcast before all slaves powered up
    // may count fewer).
    if (fmmu) {
      auto& w = fmmu_broadcast_[static_cast<std::uint16_t>(*fmmu)];
      w = std::max(w, p.reply.wkc);
    }
    if (sm) {
      auto& w = sm_broadcast_[static_cast<std::uint16_t>(*sm)];
      w = std::max(w, p.reply.wkc);
    }
    // A broadcast write to a writable system-time register counts the slaves that have one.
    bool writable = false;
    for (std::uint32_t a = first; a <= last; ++a) {
      writable = writable || ecat_may_write_register(static_cast<std::uint16_t>(a));
    }
    if (system_time && writable && wire::command_writes(h.command) && h.command == Command::bwr) {
      dc_broadcast_ = std::max<std::uint16_t>(dc_broadcast_.value_or(0), p.reply.wkc);
    }
    if (h.command == Command::brd && last < 10) {
      for (std::uint32_t a = first; a <= last; ++a)
        info_or_[a] = p.reply.data[a - first];
    }
    return;
  }
  const auto t = targets(p);
  if (t.size() != 1) return;
  SlaveState& s = slaves_[t[0]];
  const bool answered = p.reply.wkc > 0;
  if (fmmu) {
    if (answered) {
      s.fmmu_lo = std::max<int>(s.fmmu_lo, static_cast<int>(*fmmu) + 1);
    } else {
      s.fmmu_hi = std::min<int>(s.fmmu_hi, static_cast<int>(*fmmu));
    }
  }
  if (sm) {
    if (answered) {
      s.sm_lo = std::max<int>(s.sm_lo, static_cast<int>(*sm) + 1);
    } else {
      s.sm_hi = std::min<int>(s.sm_hi, static_cast<int>(*sm));
    }
  }
  const bool writes_only = h.command == Command::fpwr || h.command == Command::apwr;
  bool writable = false;
  for (std::uint32_t a = first; a <= last; ++a) {
    writable = writable || ecat_may_write_register(static_cast<std::uint16_t>(a));
  }
  if (system_time && (!writes_only || writable)) s.system_time = answered;
}

void ProfileBuilder::observe(const Pair& p) {
  const auto& h = p.request.header;
  const auto addressing = wire::addressing_of(h.command);
  if (addressing == wire::Addressing::logical || addressing == wire::Addressing::none) return;
  observe_counts(p);
  const auto t = targets(p);
  if (t.empty() || p.reply.wkc == 0) return;
  const bool broadcast = addressing == wire::Addressing::broadcast;
  // Station changes by FPWR take effect for later datagrams.
  const bool writes = h.command == Command::fpwr || h.command == Command::apwr ||
                      h.command == Command::bwr || h.command == Command::fprw ||
                      h.command == Command::aprw || h.command == Command::brw;
  const bool reads = h.command == Command::fprd || h.command == Command::aprd ||
                     h.command == Command::fprw || h.command == Command::aprw ||
                     (h.command == Command::brd && count_ == 1);
  for (std::size_t slave : t) {
    slaves_[slave].addressed = true;
    if (reads) {
      if (h.ado() < kRegisterAreaSize) observe_read(slave, h.ado(), p.reply.data, p.time_ns);
      if (h.ado() >= kRegisterAreaSize && !broadcast) {
        observe_mailbox(slave, h.ado(), p.reply.data, false);
      }
    }
    if (writes) {
      if (h.ado() < kRegisterAreaSize) observe_write(slave, h.ado(), p.request.data, p.time_ns);
      if (h.ado() >= kRegisterAreaSize && !broadcast) {
        observe_mailbox(slave, h.ado(), p.request.data, true);
      }
    }
  }
  if (h.command == Command::fpwr && h.ado() <= reg::kStationAddress &&
      h.ado() + h.length >= reg::kStationAddress + 2 && t.size() == 1) {
    const std::uint16_t station =
        wire::load_le16(p.request.data.data() + (reg::kStationAddress - h.ado()));
    station_to_position_.erase(h.adp());
    station_to_position_[station] = t[0];
  }
  if ((h.command == Command::apwr || h.command == Command::aprw) && t.size() == 1 &&
      h.ado() <= reg::kStationAddress && h.ado() + h.length >= reg::kStationAddress + 2) {
    const std::uint16_t station =
        wire::load_le16(p.request.data.data() + (reg::kStationAddress - h.ado()));
    std::erase_if(station_to_position_, [&](const auto& kv) { return kv.second == t[0]; });
    station_to_position_[station] = t[0];
    station_of_[t[0]] = station;
  }
  if (h.command == Command::aprd && t.size() == 1 && h.ado() <= reg::kStationAddress &&
      h.ado() + h.length >= reg::kStationAddress + 2) {
    const std::uint16_t station =
        wire::load_le16(p.reply.data.data() + (reg::kStationAddress - h.ado()));
    if (station != 0 && !station_to_position_.contains(station)) {
      station_to_position_[station] = t[0];
    }
  }
}

}  // namespace

namespace {

std::string sanitize_name(std::string_view text) {
  std::string out;
  for (char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (std::isalnum(u) != 0 || c == '-' || c == '_') {
      out += c;
    } else if (c == ' ' || c == '.') {
      if (!out.empty() && out.back() != '_') out += '_';
    }
    if (out.size() >= 24) break;
  }
  while (!out.empty() && out.back() == '_')
    out.pop_back();
  return out;
}

}  // namespace

CaptureSlaveProfile ProfileBuilder::finish_slave(std::size_t position) {
  SlaveState& s = slaves_[position];
  CaptureSlaveProfile out;
  out.position = position;
  out.station = station_of_[position];
  out.station_preset = preset_[position];
  out.initial_registers = s.initial;
  out.objects = s.objects;
  auto note = [&](std::string field, Evidence e, std::string reason) {
    out.notes.push_back({std::move(field), e, std::move(reason)});
  };
  if (out.station) {
    note("station", out.station_preset ? Evidence::inferred : Evidence::observed,
         out.station_preset ? "in use before the capture assigned stations; ascending stations "
                              "along the line"
                            : "APWR 0x0010");
  }
  if (s.first_al_status && (*s.first_al_status & 0x0F) != 0x01) {
    out.initial_al_status = s.first_al_status;
    note("initial_al_status", Evidence::observed, "AL status read before any AL control write");
  }

  // ---- SII words
  std::size_t bytes = kDefaultEepromBytes;
  for (const auto& [word, value] : s.sii_words) {
    if (static_cast<std::size_t>(word) * 2 + 2 <= kMaxEepromBytes) {
      bytes =
          std::max<std::size_t>(bytes, (static_cast<std::size_t>(word) * 2 + 2 + 127) / 128 * 128);
    }
  }
  if (auto it = s.sii_words.find(wire::sii_word::kEepromSize); it != s.sii_words.end()) {
    const std::size_t declared = (static_cast<std::size_t>(it->second) + 1) * 128;
    if (declared <= kMaxEepromBytes) bytes = std::max(bytes, declared);
  }
  std::vector<std::uint16_t> words(bytes / 2, 0xFFFF);
  out.sii_word_read.assign(words.size(), false);
  for (const auto& [word, value] : s.sii_words) {
    if (word < words.size()) {
      words[word] = value;
      out.sii_word_read[word] = true;
    }
  }
  // What the SII says about the device (from the words read).
  std::vector<std::uint8_t> raw(words.size() * 2);
  for (std::size_t i = 0; i < words.size(); ++i)
    wire::store_le16(&raw[i * 2], words[i]);
  std::optional<wire::SiiImage> sii;
  if (auto decoded = wire::decode_sii(raw)) sii = decoded->image;
  out.has_mailbox = sii && sii->standard_mailbox.present() &&
                    out.sii_word_read[wire::sii_word::kStandardMailbox + 1];

  // ---- Behaviour: device emulation, DC system time
  if (s.emulation_for > 0 && s.emulation_against == 0) {
    out.device_emulation = true;
    note("device_emulation", Evidence::observed,
         fmt::format("AL status followed AL control at once {} times", s.emulation_for));
  } else if (s.emulation_against > 0) {
    out.device_emulation = false;
    note("device_emulation", Evidence::observed,
         fmt::format("AL status differed from the AL control just written {} times (firmware)",
                     s.emulation_against));
  } else {
    out.device_emulation = !out.has_mailbox;
    note("device_emulation", Evidence::assumed,
         out.device_emulation ? "no AL control write was read back; no mailbox, so no firmware"
                              : "no AL control write was read back; a mailbox needs firmware");
  }
  if (s.system_time) {
    out.dc_system_time = *s.system_time;
    note("dc_system_time", Evidence::observed,
         *s.system_time ? "the slave answered an access of 0x0910..0x09FF"
                        : "the slave did not answer an access of 0x0910..0x09FF (WKC 0)");
  }

  // ---- ESC configuration area (words 0..7)
  auto reg_initial = [&](std::uint16_t a) -> std::optional<std::uint8_t> {
    auto it = s.initial.find(a);
    if (it == s.initial.end()) return std::nullopt;
    return it->second;
  };
  if (!out.sii_word_read[wire::sii_word::kPdiControl]) {
    std::uint8_t pdi = out.has_mailbox ? 0x05 : 0x04;
    Evidence pdi_evidence = Evidence::assumed;
    if (auto v = reg_initial(reg::kPdiControl)) {
      pdi = *v;
      pdi_evidence = Evidence::observed;
    } else if (auto dl = reg_initial(reg::kDlStatus)) {
      // DL status bit 1 (PDI watchdog) stays 0 without a PDI.
      if ((*dl & 0x02) == 0) pdi = 0x00;
      pdi_evidence = Evidence::inferred;
    }
    std::uint8_t config = 0;
    Evidence config_evidence = Evidence::inferred;
    if (auto v = reg_initial(reg::kEscConfiguration)) {
      config = *v;
      config_evidence = Evidence::observed;
      out.device_emulation = (config & 0x01) != 0;
      if (!s.system_time) out.dc_system_time = (config & 0x0C) != 0;
    } else {
      config = static_cast<std::uint8_t>((out.device_emulation ? 0x01 : 0x00) |
                                         (out.dc_system_time ? 0x0C : 0x00));
    }
    words[wire::sii_word::kPdiControl] = static_cast<std::uint16_t>(pdi | (config << 8));
    note("sii.word[0]", std::max(pdi_evidence, config_evidence),
         fmt::format("PDI control {:#04x} ({}), ESC configuration {:#04x} ({}: device "
                     "emulation, DC units)",
                     pdi, to_string(pdi_evidence), config, to_string(config_evidence)));
  } else {
    const std::uint8_t config = static_cast<std::uint8_t>(words[0] >> 8);
    out.device_emulation = (config & 0x01) != 0;
    if (!s.system_time) out.dc_system_time = (config & 0x0C) != 0;
  }
  for (std::uint16_t w : {wire::sii_word::kPdiConfiguration, wire::sii_word::kSyncImpulseLength,
                          wire::sii_word::kPdiConfiguration2, std::uint16_t{5}, std::uint16_t{6}}) {
    if (!out.sii_word_read[w]) words[w] = 0;
  }
  if (!out.sii_word_read[wire::sii_word::kStationAlias]) {
    const auto lo = reg_initial(reg::kStationAlias);
    const auto hi = reg_initial(reg::kStationAlias + 1);
    words[wire::sii_word::kStationAlias] =
        static_cast<std::uint16_t>(lo.value_or(0) | (hi.value_or(0) << 8));
  }
  if (!out.sii_word_read[wire::sii_word::kEepromSize]) {
    words[wire::sii_word::kEepromSize] = static_cast<std::uint16_t>(bytes / 128 - 1);
  }
  if (!out.sii_word_read[wire::sii_word::kVersion]) words[wire::sii_word::kVersion] = 1;
  out.sii.resize(words.size() * 2);
  for (std::size_t i = 0; i < words.size(); ++i)
    wire::store_le16(&out.sii[i * 2], words[i]);
  bool area_read = true;
  for (std::size_t w = 0; w <= wire::sii_word::kChecksum; ++w) {
    area_read = area_read && out.sii_word_read[w];
  }
  if (!area_read) {
    // A real ESC loads only a checksummed configuration area.
    out.sii[wire::sii_word::kChecksum * 2] =
        wire::sii_crc8(wire::Bytes(out.sii).first(wire::kSiiChecksummedBytes));
    out.sii[wire::sii_word::kChecksum * 2 + 1] = 0;
  }
  std::size_t read_count = 0;
  for (bool r : out.sii_word_read)
    read_count += r ? 1 : 0;
  note("sii", read_count > 0 ? Evidence::observed : Evidence::assumed,
       fmt::format("{} of {} words read in the capture; the others are 0xFFFF except the ESC "
                   "configuration area and the size/version words",
                   read_count, words.size()));

  // ---- Name
  std::string device;
  if (auto decoded = wire::decode_sii(out.sii)) device = std::string(decoded->image.device_name());
  device = sanitize_name(device);
  out.name = device.empty() ? fmt::format("slave{}", position)
                            : fmt::format("slave{}_{}", position, device);

  // ---- Hardware (what the capture shows directly; reconcile_hardware fills the rest)
  if (s.sii_8_bytes) out.hardware.sii_reads_8_bytes = *s.sii_8_bytes;
  // 0x0502 bit 7 (EEPROM address algorithm) is a hardware fact (the ESC's EEPROM size pin or
  // PDI setting), not something the simulator should derive from how many words the capture
  // happened to read: every ESC of the shared captures reads 0x..40, one address byte.
  if (s.sii_two_address_bytes) {
    out.hardware.sii_two_address_bytes = *s.sii_two_address_bytes;
    note("esc.sii_two_address_bytes", Evidence::observed,
         fmt::format("SII control 0x0502 bit 7 read as {}", *s.sii_two_address_bytes ? 1 : 0));
  }
  if (s.sii_emulation) {
    out.hardware.sii_emulation = *s.sii_emulation;
    note("esc.sii_emulation", Evidence::observed,
         fmt::format("SII control 0x0502 bit 5 read as {}", *s.sii_emulation ? 1 : 0));
  }
  if (s.enhanced_link) {
    out.hardware.enhanced_link_detection = *s.enhanced_link;
    note("esc.enhanced_link_detection", Evidence::observed,
         fmt::format("DL status 0x0110 bit 2 read as {}", *s.enhanced_link ? 1 : 0));
  }
  for (const auto& [state, code] : s.refused) {
    // A state the device reached later in the capture was not refused for good (the master
    // changed what the device objected to): only standing refusals are the device's.
    if (s.reached.contains(state) || !code) continue;
    const auto al = wire::al_state_from_code(state);
    if (!al) continue;
    out.hardware.al_refusals.emplace_back(*al, *code);
    note("esc.al_refusals", Evidence::observed,
         fmt::format("AL control {:#04x} answered by the error indicator and status code {:#06x}, "
                     "the state never reached",
                     state, *code));
  }
  if (s.sii_busy_seen) {
    // Between the longest time a poll still saw busy and the shortest it saw the EEPROM done.
    const std::int64_t hi = s.sii_busy_hi.value_or(s.sii_busy_lo + s.sii_busy_lo / 4);
    out.hardware.sii_busy_ns = hi >= s.sii_busy_lo ? (s.sii_busy_lo + hi) / 2 : hi;
    note("esc.sii_busy_ns", Evidence::observed,
         fmt::format("SII polls saw busy up to {} us after a read command and idle from {} us",
                     s.sii_busy_lo / 1000, hi / 1000));
  }
  return out;
}

void ProfileBuilder::reconcile_hardware(std::vector<CaptureSlaveProfile>& out) {
  const std::size_t n = out.size();
  // Class guess per slave: an SII that declares an MII port, or 8 FMMUs/SMs seen, means an
  // ET1100-class ESC; everything else is taken for an ET1200-class terminal ESC.
  std::vector<const EscClass*> cls(n, &kTerminalClass);
  for (std::size_t i = 0; i < n; ++i) {
    const SlaveState& s = slaves_[i];
    bool mii = false;
    if (auto decoded = wire::decode_sii(out[i].sii); decoded && decoded->image.general) {
      for (std::size_t p = 0; p < 4; ++p) {
        mii = mii || decoded->image.general->port(p) == wire::sii_port::kMii;
      }
    }
    if (auto it = s.initial.find(0x0000); it != s.initial.end()) {
      mii = mii || it->second == 0x11;
    }
    if (mii || s.fmmu_lo > 3 || s.sm_lo > 4) cls[i] = &kCouplerClass;
  }
  // A broadcast read of the ESC type ORs all slaves' types: when it shows the coupler type's bits
  // that no guess explains, the first slaves of unknown type (couplers head a segment) are
  // couplers.
  if (info_or_[0]) {
    auto types = [&] {
      std::uint8_t all = 0;
      for (std::size_t i = 0; i < n; ++i) {
        auto it = slaves_[i].initial.find(0x0000);
        all |= it != slaves_[i].initial.end() ? it->second : cls[i]->type;
      }
      return all;
    };
    for (std::size_t i = 0; i < n && types() != *info_or_[0]; ++i) {
      if (slaves_[i].initial.contains(0x0000) || cls[i] == &kCouplerClass) continue;
      if ((*info_or_[0] & kCouplerClass.type) == kCouplerClass.type) cls[i] = &kCouplerClass;
    }
  }
  // FMMU and SM counts: per-slave bounds, then the broadcast counts (how many slaves have more
  // than i) decide among the rest, preferring coupler-class ESCs for the larger counts.
  auto solve = [&](bool fmmu) {
    std::vector<int> count(n);
    for (std::size_t i = 0; i < n; ++i) {
      const SlaveState& s = slaves_[i];
      const int lo = fmmu ? s.fmmu_lo : s.sm_lo;
      const int hi = fmmu ? s.fmmu_hi : s.sm_hi;
      const int guess = fmmu ? cls[i]->fmmus : cls[i]->sms;
      count[i] = std::clamp(guess, lo, std::max(lo, hi));
      if (auto it = s.initial.find(fmmu ? 0x0004 : 0x0005); it != s.initial.end()) {
        count[i] = it->second;
      }
    }
    const auto& broadcast = fmmu ? fmmu_broadcast_ : sm_broadcast_;
    for (const auto& [index, wkc] : broadcast) {
      for (int round = 0; round < 2; ++round) {
        std::size_t more = 0;
        for (int c : count)
          more += c > index ? 1 : 0;
        if (more == wkc) break;
        // Order: slaves without per-slave evidence, terminals first when lowering, couplers
        // first when raising.
        std::vector<std::size_t> order(n);
        for (std::size_t i = 0; i < n; ++i)
          order[i] = i;
        const bool lower = more > wkc;
        std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
          const bool ca = cls[a] == &kCouplerClass;
          const bool cb = cls[b] == &kCouplerClass;
          return lower ? (!ca && cb) : (ca && !cb);
        });
        for (std::size_t i : order) {
          const SlaveState& s = slaves_[i];
          const int lo = fmmu ? s.fmmu_lo : s.sm_lo;
          const int hi = fmmu ? s.fmmu_hi : s.sm_hi;
          if (lower && more > wkc && count[i] > index && lo <= index) {
            count[i] = index;
            --more;
          } else if (!lower && more < wkc && count[i] <= index && hi > index) {
            count[i] = std::max<int>(index + 1, fmmu ? cls[i]->fmmus : cls[i]->sms);
            count[i] = std::min(count[i], hi);
            ++more;
          }
        }
      }
    }
    return count;
  };
  const auto fmmus = solve(true);
  const auto sms = solve(false);
  for (std::size_t i = 0; i < n; ++i) {
    const SlaveState& s = slaves_[i];
    auto& hw = out[i].hardware;
    auto initial = [&](std::uint16_t a) -> std::optional<std::uint8_t> {
      auto it = s.initial.find(a);
      if (it == s.initial.end()) return std::nullopt;
      return it->second;
    };
    auto pick = [&](std::uint16_t a, std::uint8_t fallback, const char* field) {
      if (auto v = initial(a)) {
        out[i].notes.push_back({field, Evidence::observed, fmt::format("register {:#06x}", a)});
        return *v;
      }
      out[i].notes.push_back({field, Evidence::assumed, cls[i]->label});
      return fallback;
    };
    hw.type = pick(0x0000, cls[i]->type, "esc.type");
    hw.revision = pick(0x0001, 0x00, "esc.revision");
    hw.build = static_cast<std::uint16_t>(pick(0x0002, 0x00, "esc.build") |
                                          (pick(0x0003, 0x00, "esc.build_high") << 8));
    hw.fmmu_count = static_cast<std::uint8_t>(std::clamp(fmmus[i], 0, 16));
    hw.sync_manager_count = static_cast<std::uint8_t>(std::clamp(sms[i], 0, 16));
    out[i].notes.push_back({"esc.fmmu_count",
                            initial(0x0004) ? Evidence::observed : Evidence::inferred,
                            "per-slave FMMU accesses and broadcast working counters"});
    out[i].notes.push_back({"esc.sync_manager_count",
                            initial(0x0005) ? Evidence::observed : Evidence::inferred,
                            "per-slave SyncManager accesses and broadcast working counters"});
    hw.ram_size_kib = pick(0x0006, cls[i]->ram_kib, "esc.ram_size_kib");
    const std::uint8_t ports = pick(0x0007, cls[i]->ports, "esc.ports");
    for (std::size_t p = 0; p < 4; ++p) {
      hw.ports.ports[p] = static_cast<wire::PortType>((ports >> (2 * p)) & 0x03);
    }
    const std::uint16_t features = static_cast<std::uint16_t>(
        pick(0x0008, static_cast<std::uint8_t>(cls[i]->features), "esc.features") |
        (pick(0x0009, static_cast<std::uint8_t>(cls[i]->features >> 8), "esc.features_high") << 8));
    hw.features = wire::EscFeatures::decode(features);
    hw.dc_supported = hw.features.dc_supported;
  }
  // ESC information that only a broadcast read showed (ORed over all slaves): make the unknown
  // slaves' values produce the same OR.
  for (std::size_t a = 0; a < info_or_.size(); ++a) {
    if (!info_or_[a] || a == 4 || a == 5) continue;
    auto byte_of = [&](CaptureSlaveProfile& p) -> std::uint8_t {
      const auto info = [&] {
        wire::EscInformation e;
        e.type = p.hardware.type;
        e.revision = p.hardware.revision;
        e.build = p.hardware.build;
        e.fmmu_count = p.hardware.fmmu_count;
        e.sync_manager_count = p.hardware.sync_manager_count;
        e.ram_size_kib = p.hardware.ram_size_kib;
        e.ports = p.hardware.ports;
        e.features = p.hardware.features;
        e.features.dc_supported = p.hardware.dc_supported;
        e.features.dc_64bit = p.hardware.dc_supported;
        return e.encode();
      }();
      return info[a];
    };
    std::uint8_t known = 0;
    std::uint8_t all = 0;
    std::vector<std::size_t> unknown;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint8_t v = byte_of(out[i]);
      all |= v;
      if (slaves_[i].initial.contains(static_cast<std::uint16_t>(a))) {
        known |= v;
      } else {
        unknown.push_back(i);
      }
    }
    if (all == *info_or_[a] || unknown.empty()) continue;
    const auto target = *info_or_[a];
    for (std::size_t k = 0; k < unknown.size(); ++k) {
      auto& hw = out[unknown[k]].hardware;
      std::uint8_t v = static_cast<std::uint8_t>(byte_of(out[unknown[k]]) & target);
      if (k == 0) v = static_cast<std::uint8_t>(v | (target & ~known));
      switch (a) {
        case 0:
          hw.type = v;
          break;
        case 1:
          hw.revision = v;
          break;
        case 2:
          hw.build = static_cast<std::uint16_t>((hw.build & 0xFF00) | v);
          break;
        case 3:
          hw.build = static_cast<std::uint16_t>((hw.build & 0x00FF) | (v << 8));
          break;
        default:
          break;
      }
      out[unknown[k]].notes.push_back(
          {fmt::format("esc.info[{}]", a), Evidence::inferred,
           fmt::format("a broadcast read returned {:#04x} ORed over all slaves", target)});
    }
  }
  // What the capture does not show: the ESC datasheet's value for the slave's ESC type
  // (esc_type_defaults()): the SII read size and the DL control reset value.
  for (std::size_t i = 0; i < n; ++i) {
    const SlaveState& s = slaves_[i];
    auto& hw = out[i].hardware;
    const EscTypeDefaults defaults = esc_type_defaults(hw.type);
    if (!s.sii_8_bytes) {
      hw.sii_reads_8_bytes = defaults.sii_reads_8_bytes;
      out[i].notes.push_back(
          {"esc.sii_8_byte_reads", Evidence::assumed,
           fmt::format("0x0502 never read: the {} datasheet value", defaults.name)});
    }
    std::uint32_t dl_control = defaults.dl_control;
    int dl_bytes_seen = 0;
    for (std::uint16_t b = 0; b < 4; ++b) {
      auto it = s.initial.find(static_cast<std::uint16_t>(reg::kDlControl + b));
      if (it == s.initial.end()) continue;
      dl_control = (dl_control & ~(0xFFu << (8 * b))) | (std::uint32_t{it->second} << (8 * b));
      ++dl_bytes_seen;
    }
    hw.dl_control = dl_control;
    out[i].notes.push_back(
        {"esc.dl_control", dl_bytes_seen == 4 ? Evidence::observed : Evidence::assumed,
         dl_bytes_seen == 4
             ? std::string("register 0x0100..0x0103 before the master wrote it")
             : fmt::format("{} of 4 bytes read before the master wrote them; the rest the {} "
                           "datasheet reset value",
                           dl_bytes_seen, defaults.name)});
  }
  // DC system time from broadcast writes when per-slave evidence is missing.
  for (std::size_t i = 0; i < n; ++i) {
    if (!out[i].hardware.dc_supported) out[i].dc_system_time = false;
  }
  if (dc_broadcast_) {
    std::size_t have = 0;
    for (std::size_t i = 0; i < n; ++i)
      have += out[i].dc_system_time ? 1 : 0;
    for (std::size_t i = 0; i < n && have < *dc_broadcast_; ++i) {
      if (!out[i].dc_system_time && out[i].hardware.dc_supported && !slaves_[i].system_time &&
          !out[i].sii_word_read[0]) {
        out[i].dc_system_time = true;
        ++have;
      }
    }
    for (std::size_t i = n; i-- > 0 && have > *dc_broadcast_;) {
      if (out[i].dc_system_time && !slaves_[i].system_time && !out[i].sii_word_read[0]) {
        out[i].dc_system_time = false;
        --have;
      }
    }
  }
  // The ESC configuration word follows the final decision (unless the SII itself was read).
  for (std::size_t i = 0; i < n; ++i) {
    auto& p = out[i];
    if (p.sii_word_read[0] || slaves_[i].initial.contains(reg::kEscConfiguration)) continue;
    std::uint8_t config = p.sii[1];
    config = static_cast<std::uint8_t>((config & ~0x0D) | (p.device_emulation ? 0x01 : 0) |
                                       (p.dc_system_time ? 0x0C : 0));
    p.sii[1] = config;
    bool area_read = true;
    for (std::size_t w = 0; w <= wire::sii_word::kChecksum; ++w) {
      area_read = area_read && p.sii_word_read[w];
    }
    if (!area_read) {
      p.sii[wire::sii_word::kChecksum * 2] =
          wire::sii_crc8(wire::Bytes(p.sii).first(wire::kSiiChecksummedBytes));
    }
  }
}

Result<CaptureProfile> ProfileBuilder::build() {
  count_slaves();
  if (count_ > kMaxProfileSlaves) {
    return Error(Errc::out_of_range,
                 fmt::format("capture '{}' shows {} slaves; profiles hold at most {}",
                             trace_.source, count_, kMaxProfileSlaves));
  }
  assign_stations();
  slaves_.assign(count_, SlaveState{});
  station_to_position_.clear();
  for (std::size_t i = 0; i < count_; ++i) {
    if (preset_[i] && station_of_[i]) station_to_position_[*station_of_[i]] = i;
  }
  for_each_pair([&](const Pair& p) { observe(p); });

  CaptureProfile profile;
  profile.source = trace_.source;
  profile.notes = notes_;
  for (std::size_t i = 0; i < count_; ++i)
    profile.slaves.push_back(finish_slave(i));
  reconcile_hardware(profile.slaves);
  std::set<std::string> names;
  for (auto& s : profile.slaves) {
    std::string name = s.name;
    for (int k = 2; !names.insert(name).second; ++k)
      name = fmt::format("{}_{}", s.name, k);
    s.name = name;
  }
  return profile;
}

Result<CaptureProfile> build_capture_profile(const CaptureTrace& trace) {
  ProfileBuilder builder(trace);
  return builder.build();
}

// ---------------------------------------------------------------------------------------------
// Devices

namespace {}  // namespace

namespace {

// The captured objects as the dictionary presets a ring file can also carry.
std::vector<ObjectPreset> object_presets(const CaptureSlaveProfile& slave) {
  std::vector<ObjectPreset> out;
  for (const auto& [key, o] : slave.objects) {
    out.push_back(ObjectPreset{o.index, o.subindex, o.value, o.downloaded, o.abort_code});
  }
  return out;
}

}  // namespace

Result<std::unique_ptr<Esc>> make_capture_device(const CaptureSlaveProfile& slave) {
  std::unique_ptr<Application> application;
  if (slave.device_emulation && slave.objects.empty()) {
    application = std::make_unique<devices::NoFirmware>();
  } else {
    StandardConfig config;
    if (auto decoded = wire::decode_sii(slave.sii)) config.sii = decoded->image;
    if (config.sii.standard_mailbox.present()) {
      add_sii_process_data(config.dictionary, config.sii);
    }
    devices::apply_object_presets(config.dictionary, object_presets(slave));
    application = std::make_unique<StandardApplication>(std::move(config));
  }
  EscHardware hardware = slave.hardware;
  auto esc = std::make_unique<Esc>(hardware, slave.sii, std::move(application));
  if (slave.station_preset && slave.station) {
    esc->pdi_write_u16(reg::kStationAddress, *slave.station);
  }
  if (slave.initial_al_status) {
    const std::uint16_t status = *slave.initial_al_status;
    esc->pdi_write_u16(reg::kAlStatus, status);
    esc->pdi_write_u16(reg::kAlControl, static_cast<std::uint16_t>(status & 0x0F));
  }
  return esc;
}

Result<std::unique_ptr<Segment>> build_capture_segment(const CaptureProfile& profile) {
  auto segment = std::make_unique<Segment>();
  for (const auto& slave : profile.slaves) {
    auto esc = make_capture_device(slave);
    if (!esc) return esc.error().context(fmt::format("slave {} ({})", slave.position, slave.name));
    auto added = segment->add_slave(slave.name, std::move(*esc));
    if (!added) return added.error();
  }
  return segment;
}

// ---------------------------------------------------------------------------------------------
// Output

namespace {

std::string hex(wire::Bytes bytes) {
  std::string out;
  for (auto b : bytes)
    out += fmt::format("{:02x}", b);
  return out;
}

// profile.json keeps the order a reader expects (source first, each slave's name before its
// details), so the keys stay in the order written.
using Json = nlohmann::ordered_json;

Json notes_json(const std::vector<ProfileNote>& notes) {
  Json out = Json::array();
  for (const auto& note : notes) {
    out.push_back(Json{
        {"field", note.field}, {"evidence", to_string(note.evidence)}, {"reason", note.reason}});
  }
  return out;
}

// Register values and identities as the hex text engineers read them in ESI files and manuals.
template <class T>
Json hex_or_null(const std::optional<T>& value, int width) {
  if (!value) return nullptr;
  return fmt::format("{:#0{}x}", *value, width);
}

Json refusals_json(const std::vector<std::pair<wire::AlState, std::uint16_t>>& refusals) {
  Json out = Json::array();
  for (const auto& [state, code] : refusals) {
    out.push_back(Json{{"state", static_cast<int>(state)}, {"code", fmt::format("{:#06x}", code)}});
  }
  return out;
}

Json slave_json(const CaptureSlaveProfile& s) {
  const auto& hw = s.hardware;
  std::size_t read = 0;
  for (bool r : s.sii_word_read)
    read += r ? 1 : 0;
  Json identity = nullptr;
  if (auto decoded = wire::decode_sii(s.sii)) {
    const auto& id = decoded->image.identity;
    identity = Json{{"vendor_id", fmt::format("{:#010x}", id.vendor_id)},
                    {"product_code", fmt::format("{:#010x}", id.product_code)},
                    {"revision", fmt::format("{:#010x}", id.revision)},
                    {"serial", fmt::format("{:#010x}", id.serial)},
                    {"name", wire::sii_string_to_utf8(decoded->image.device_name())}};
  }
  Json objects = Json::array();
  for (const auto& [key, o] : s.objects) {
    objects.push_back(Json{{"index", fmt::format("{:#06x}", o.index)},
                           {"subindex", o.subindex},
                           {"value", hex(o.value)},
                           {"uploaded", o.uploaded},
                           {"downloaded", o.downloaded},
                           {"abort", hex_or_null(o.abort_code, 10)}});
  }
  Json registers = Json::object();
  for (const auto& [address, value] : s.initial_registers) {
    registers[fmt::format("{:#06x}", address)] = fmt::format("{:#04x}", value);
  }
  return Json{{"position", s.position},
              {"name", s.name},
              {"station", hex_or_null(s.station, 6)},
              {"station_preset", s.station_preset},
              {"initial_al_status", hex_or_null(s.initial_al_status, 6)},
              {"identity", std::move(identity)},
              {"esc",
               {{"type", fmt::format("{:#04x}", hw.type)},
                {"revision", fmt::format("{:#04x}", hw.revision)},
                {"build", fmt::format("{:#06x}", hw.build)},
                {"fmmus", hw.fmmu_count},
                {"sync_managers", hw.sync_manager_count},
                {"ram_kib", hw.ram_size_kib},
                {"features", fmt::format("{:#06x}", hw.features.encode())},
                {"dc", hw.dc_supported},
                {"dc_system_time", s.dc_system_time},
                {"sii_8_byte_reads", hw.sii_reads_8_bytes},
                {"sii_two_address_bytes",
                 hw.sii_two_address_bytes ? Json(*hw.sii_two_address_bytes) : Json(nullptr)},
                {"sii_emulation", hw.sii_emulation},
                {"dl_control", fmt::format("{:#010x}", hw.dl_control)},
                {"enhanced_link_detection",
                 hw.enhanced_link_detection ? Json(*hw.enhanced_link_detection) : Json(nullptr)},
                {"al_refusals", refusals_json(hw.al_refusals)}}},
              {"device_emulation", s.device_emulation},
              {"mailbox", s.has_mailbox},
              {"sii", {{"bytes", s.sii.size()}, {"words_read", read}}},
              {"objects", std::move(objects)},
              {"initial_registers", std::move(registers)},
              {"notes", notes_json(s.notes)}};
}

}  // namespace

std::string capture_profile_json(const CaptureProfile& profile) {
  Json slaves = Json::array();
  for (const auto& s : profile.slaves)
    slaves.push_back(slave_json(s));
  const Json out{{"source", profile.source},
                 {"slave_count", profile.slaves.size()},
                 {"notes", notes_json(profile.notes)},
                 {"slaves", std::move(slaves)}};
  return config::detail::dump_json(out, 2) + "\n";
}

namespace {

// One slave of ring.yaml: the `eeprom` profile with everything the capture showed beyond the SII
// image (docs/RING-FILE.md), so that the ring answers as build_capture_segment does.
std::string_view al_state_key(wire::AlState state) {
  switch (state) {
    case wire::AlState::init:
      return "init";
    case wire::AlState::preop:
      return "preop";
    case wire::AlState::bootstrap:
      return "bootstrap";
    case wire::AlState::safeop:
      return "safeop";
    case wire::AlState::op:
      return "op";
  }
  return "init";
}

std::string ring_slave_yaml(const CaptureSlaveProfile& s, const std::string& file) {
  const EscHardware& hw = s.hardware;
  std::string out =
      fmt::format("    - name: {}\n      profile: eeprom\n      file: {}\n", s.name, file);
  if (s.device_emulation && s.objects.empty()) out += "      options: {firmware: none}\n";
  wire::EscFeatures features = hw.features;
  features.dc_supported = hw.dc_supported;
  features.dc_64bit = hw.dc_supported;
  out += fmt::format(
      "      esc: {{type: {:#04x}, revision: {:#04x}, build: {:#06x}, fmmus: {}, "
      "sync_managers: {}, ram_kib: {}, ports: {:#04x}, features: {:#06x}, sii_busy_ns: {}, "
      "sii_read_bytes: {}, dl_control: {:#010x}",
      hw.type, hw.revision, hw.build, hw.fmmu_count, hw.sync_manager_count, hw.ram_size_kib,
      hw.ports.encode(), features.encode(), hw.sii_busy_ns, hw.sii_reads_8_bytes ? 8 : 4,
      hw.dl_control);
  if (hw.sii_two_address_bytes) {
    out += fmt::format(", sii_address_bytes: {}", *hw.sii_two_address_bytes ? 2 : 1);
  }
  if (hw.sii_emulation) out += ", sii_emulation: true";
  if (hw.enhanced_link_detection) {
    out += fmt::format(", enhanced_link_detection: {}", *hw.enhanced_link_detection);
  }
  if (!hw.al_refusals.empty()) {
    out += ",\n            al_refusals: [";
    for (std::size_t r = 0; r < hw.al_refusals.size(); ++r) {
      out += fmt::format("{}{{state: {}, code: {:#06x}}}", r == 0 ? "" : ", ",
                         al_state_key(hw.al_refusals[r].first), hw.al_refusals[r].second);
    }
    out += "]";
  }
  out += "}\n";
  std::string start;
  if (s.station_preset && s.station) start += fmt::format("station: {:#06x}", *s.station);
  if (s.initial_al_status) {
    start += fmt::format("{}al_status: {:#06x}", start.empty() ? "" : ", ", *s.initial_al_status);
  }
  if (!start.empty()) out += fmt::format("      start: {{{}}}\n", start);
  if (!s.objects.empty()) out += "      objects:\n";
  for (const auto& [key, o] : s.objects) {
    out += fmt::format("        - {{index: {:#06x}, subindex: {}", o.index, o.subindex);
    if (!o.value.empty()) out += fmt::format(", value: \"{}\"", hex(o.value));
    if (o.downloaded) out += ", writable: true";
    if (o.abort_code) out += fmt::format(", abort: {:#010x}", *o.abort_code);
    out += "}\n";
  }
  return out;
}

}  // namespace

Result<std::vector<std::string>> write_capture_profile(const CaptureProfile& profile,
                                                       const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return Error(Errc::io_error,
                 fmt::format("cannot create directory '{}': {}", dir, ec.message()));
  }
  std::vector<std::string> written;
  auto write = [&](const std::string& name, std::string_view bytes) -> Result<void> {
    const std::string path = (fs::path(dir) / name).string();
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    if (!out) return Error(Errc::io_error, fmt::format("cannot create '{}'", path));
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    if (!out) return Error(Errc::io_error, fmt::format("cannot write '{}'", path));
    written.push_back(path);
    return {};
  };
  std::string ring = fmt::format(
      "# Rebuilt by `ecat sim profile` from the capture {}.\n"
      "# Each slave is its SII image as far as the capture shows it, with the ESC hardware, start\n"
      "# state and CoE objects the capture showed (profile.json lists what was observed,\n"
      "# inferred or assumed, and why).\n"
      "version: 1\n"
      "simulator:\n",
      profile.source);
  ring += "  slaves:\n";
  for (const auto& s : profile.slaves) {
    const std::string file = s.name + ".bin";
    if (auto ok = write(
            file, std::string_view(reinterpret_cast<const char*>(s.sii.data()), s.sii.size()));
        !ok) {
      return ok.error();
    }
    ring += ring_slave_yaml(s, file);
  }
  // A ring needs at least one slave; an empty segment has only the JSON summary.
  if (!profile.slaves.empty()) {
    if (auto ok = write("ring.yaml", ring); !ok) return ok.error();
  }
  if (auto ok = write("profile.json", capture_profile_json(profile)); !ok) return ok.error();
  return written;
}

}  // namespace ecat::sim
