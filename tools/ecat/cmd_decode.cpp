// ecat decode FILE [--json]: decodes every EtherCAT frame of a pcap/pcapng capture.
// Exit codes: 0 every EtherCAT frame decoded, 1 some did not (each is named), 2 the file could not
// be read.
#include <array>
#include <bitset>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/capture/capture_file.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/registers.hpp>

#include "command.hpp"

namespace ecat::tool {
namespace {

using capture::EtherCatPacket;
using capture::extract_ethercat;
using nlohmann::ordered_json;
using wire::Addressing;
using wire::Bytes;
using wire::DatagramView;

struct Options {
  std::string file;
  bool json = false;
  std::uint16_t udp_port = wire::kEtherCatUdpPort;  // EtherCAT over UDP on this port
};

constexpr std::uint16_t kSmBase = wire::reg::kSyncManagerBase;
constexpr std::size_t kSmSize = wire::reg::kSyncManagerSize;
constexpr std::size_t kSmBytes = kSmSize * wire::reg::kMaxSyncManagers;
constexpr std::size_t kSmControlOffset = 4;
constexpr std::uint8_t kSmModeMask = 0x03;
constexpr std::uint8_t kSmModeMailbox = 0x02;
constexpr std::uint8_t kSmDirectionWrite = 0x01;  // control bits 2-3: ECAT writes (mailbox out)
constexpr std::uint16_t kProcessRamStart = 0x1000;
constexpr std::size_t kMailboxHeaderSize = 6;

// Knows which physical addresses are mailbox SyncManagers, from the SyncManager configuration
// writes seen so far in the capture. Each station keeps a shadow of its SyncManager registers, so
// partial writes (a control byte alone, an activate byte alone) combine as they do in the ESC.
class MailboxTracker {
 public:
  // The mailbox summary for a datagram that accesses a mailbox, or "" for any other datagram.
  std::string summarize(const DatagramView& datagram) const {
    const wire::Command command = datagram.header.command;
    if (wire::addressing_of(command) != Addressing::station || command == wire::Command::frmw)
      return {};
    const std::uint16_t station = datagram.header.adp();
    const std::uint16_t address = datagram.header.ado();
    const Shadow& shadow = shadow_of(station);
    bool any_mailbox = false;
    for (std::size_t sm = 0; sm < wire::reg::kMaxSyncManagers; ++sm) {
      const auto config = shadow.sync_manager(sm);
      if (!config || (config->control & kSmModeMask) != kSmModeMailbox) continue;
      any_mailbox = true;
      if (config->start != address) continue;
      const bool out = ((config->control >> 2) & 0x03) == kSmDirectionWrite;
      if (out ? !wire::command_writes(command) : !wire::command_reads(command)) continue;
      return wire::summarize_mailbox(datagram.data);
    }
    // Captures that start after the configuration: fall back to the shape of the data.
    if (!any_mailbox && address >= kProcessRamStart && looks_like_mailbox(datagram.data)) {
      return wire::summarize_mailbox(datagram.data);
    }
    return {};
  }

  // `from_master`: the frame is on its way out (auto-increment addresses not yet incremented).
  void learn(const DatagramView& datagram, bool from_master) {
    const wire::Command command = datagram.header.command;
    if (!wire::command_writes(command)) return;
    const std::uint16_t address = datagram.header.ado();
    switch (wire::addressing_of(command)) {
      case Addressing::station:
        if (command != wire::Command::frmw)
          write(stations_[datagram.header.adp()], address, datagram.data);
        break;
      case Addressing::position: {
        if (!from_master || command == wire::Command::armw) break;
        const auto position = static_cast<std::uint16_t>(0x10000u - datagram.header.adp());
        if (address == wire::reg::kStationAddress && datagram.data.size() >= 2) {
          station_at_position_[position] = wire::load_le16(datagram.data.data());
        }
        auto found = station_at_position_.find(position);
        if (found != station_at_position_.end()) {
          write(shadow_for_update(found->second), address, datagram.data);
        }
        break;
      }
      case Addressing::broadcast:
        write(broadcast_, address, datagram.data);
        for (auto& [station, shadow] : stations_)
          write(shadow, address, datagram.data);
        break;
      default:
        break;
    }
  }

 private:
  struct SmConfig {
    std::uint16_t start = 0;
    std::uint16_t length = 0;
    std::uint8_t control = 0;
  };

  struct Shadow {
    std::array<std::uint8_t, kSmBytes> bytes{};
    std::bitset<kSmBytes> written;

    std::optional<SmConfig> sync_manager(std::size_t sm) const {
      const std::size_t base = sm * kSmSize;
      for (std::size_t i = 0; i <= kSmControlOffset; ++i) {
        if (!written[base + i]) return std::nullopt;
      }
      return SmConfig{wire::load_le16(&bytes[base]), wire::load_le16(&bytes[base + 2]),
                      bytes[base + kSmControlOffset]};
    }
  };

  static void write(Shadow& shadow, std::uint16_t address, Bytes data) {
    for (std::size_t i = 0; i < data.size(); ++i) {
      const std::size_t target = address + i;
      if (target < kSmBase || target >= kSmBase + kSmBytes) continue;
      shadow.bytes[target - kSmBase] = data[i];
      shadow.written.set(target - kSmBase);
    }
  }

  // A mailbox header whose length fits the data, channel 0 and a known mailbox type.
  static bool looks_like_mailbox(Bytes data) {
    if (data.size() < kMailboxHeaderSize) return false;
    const std::size_t length = wire::load_le16(data.data());
    if (length < 2 || length > data.size() - kMailboxHeaderSize) return false;
    if ((data[4] & 0x3F) != 0) return false;
    const unsigned type = data[5] & 0x0F;
    return (type >= 1 && type <= 5) || type == 0x0F;
  }

  const Shadow& shadow_of(std::uint16_t station) const {
    auto found = stations_.find(station);
    return found != stations_.end() ? found->second : broadcast_;
  }

  Shadow& shadow_for_update(std::uint16_t station) {
    auto [it, inserted] = stations_.try_emplace(station, broadcast_);
    return it->second;
  }

  std::map<std::uint16_t, Shadow> stations_;
  Shadow broadcast_;
  std::map<std::uint16_t, std::uint16_t> station_at_position_;
};

std::string timestamp_text(std::int64_t ns) {
  const bool negative = ns < 0;
  const auto magnitude =
      negative ? -static_cast<std::uint64_t>(ns) : static_cast<std::uint64_t>(ns);
  return fmt::format("{}{}.{:09}", negative ? "-" : "", magnitude / 1'000'000'000,
                     magnitude % 1'000'000'000);
}

std::string encapsulation_text(const EtherCatPacket& packet) {
  return fmt::format("{}{}", to_string(packet.encapsulation), packet.vlan ? "/vlan" : "");
}

std::string source_text(const EtherCatPacket& packet) {
  return packet.source ? wire::to_string(*packet.source) : std::string("-");
}

// ESCs set bit 1 of the first source-MAC byte on frames they send back; frames without it are on
// their way out from the master.
bool sent_by_master(const EtherCatPacket& packet) {
  return packet.source.has_value() && ((*packet.source)[0] & 0x02) == 0;
}

std::string address_text(const wire::DatagramHeader& header) {
  if (wire::addressing_of(header.command) == Addressing::logical) {
    return fmt::format("logical=0x{:08x}", header.address);
  }
  return fmt::format("adp=0x{:04x} ado=0x{:04x}", header.adp(), header.ado());
}

class Decoder {
 public:
  explicit Decoder(const Options& options) : options_(options) {}

  int run() {
    // The library's reader (libpcap underneath): the same one `ecat sim verify` uses.
    auto reader = capture::CaptureFile::open(options_.file);
    if (!reader) {
      std::fprintf(stderr, "ecat decode: %s\n", reader.error().describe().c_str());
      return 2;
    }
    if (!capture::link_type_supported(reader->link_type())) {
      std::fprintf(stderr,
                   "ecat decode: capture '%s': link type %d is not supported (Ethernet, Linux "
                   "cooked SLL and SLL2 are)\n",
                   options_.file.c_str(), reader->link_type());
      return 2;
    }
    std::optional<Error> read_error;
    for (;;) {
      auto packet = reader->next();
      if (!packet) {
        read_error = packet.error();
        break;
      }
      if (!packet->has_value()) break;
      handle(reader->link_type(), **packet);
    }
    finish();
    if (read_error) {
      std::fprintf(stderr, "ecat decode: %s\n", read_error->describe().c_str());
      return 2;
    }
    return errors_ > 0 ? 1 : 0;
  }

 private:
  void handle(int link_type, const capture::Packet& packet) {
    ++frames_;
    auto ethercat = extract_ethercat(link_type, packet.data, options_.udp_port);
    if (!ethercat) return;
    ++ethercat_;
    auto decoded = wire::decode_frame(ethercat->frame);
    if (!decoded) {
      ++errors_;
      const auto reason = decoded.error.describe();
      if (options_.json) {
        json_errors_.push_back(ordered_json{{"frame", packet.number}, {"reason", reason}});
      } else {
        fmt::print("frame {}: error: {}\n", packet.number, reason);
      }
      return;
    }
    const bool from_master = sent_by_master(*ethercat);
    if (options_.json) {
      ordered_json frame{{"number", packet.number},
                         {"timestamp_ns", packet.timestamp_ns},
                         {"encapsulation", encapsulation_text(*ethercat)},
                         {"source", ethercat->source ? ordered_json(source_text(*ethercat))
                                                     : ordered_json(nullptr)}};
      ordered_json datagrams = ordered_json::array();
      for (auto datagram : *decoded.frame) {
        datagrams.push_back(datagram_json(datagram));
        mailboxes_.learn(datagram, from_master);
      }
      frame["datagrams"] = std::move(datagrams);
      json_frames_.push_back(std::move(frame));
      return;
    }
    fmt::print("{:>6}  {}  {:<13} {}  {} datagram{}\n", packet.number,
               timestamp_text(packet.timestamp_ns), encapsulation_text(*ethercat),
               source_text(*ethercat), decoded.frame->datagram_count(),
               decoded.frame->datagram_count() == 1 ? "" : "s");
    for (auto datagram : *decoded.frame) {
      const auto& header = datagram.header;
      const auto mailbox = mailboxes_.summarize(datagram);
      fmt::print("        {:<4} idx=0x{:02x} {:<21} len={:<4} wkc={:<5} irq=0x{:04x}{}{}{}\n",
                 wire::to_string(header.command), header.index, address_text(header), header.length,
                 datagram.wkc, header.irq, header.circulating ? " circulating" : "",
                 mailbox.empty() ? "" : "  ", mailbox);
      mailboxes_.learn(datagram, from_master);
    }
  }

  ordered_json datagram_json(const DatagramView& datagram) const {
    const auto& header = datagram.header;
    ordered_json out{{"command", wire::to_string(header.command)}, {"index", header.index}};
    if (wire::addressing_of(header.command) == Addressing::logical) {
      out["logical"] = header.address;
    } else {
      out["adp"] = header.adp();
      out["ado"] = header.ado();
    }
    out["length"] = header.length;
    out["wkc"] = datagram.wkc;
    out["circulating"] = header.circulating;
    out["irq"] = header.irq;
    if (auto mailbox = mailboxes_.summarize(datagram); !mailbox.empty()) out["mailbox"] = mailbox;
    return out;
  }

  void finish() {
    if (options_.json) {
      ordered_json document{
          {"frames", std::move(json_frames_)},
          {"errors", std::move(json_errors_)},
          {"summary", {{"frames", frames_}, {"ethercat", ethercat_}, {"errors", errors_}}}};
      fmt::print("{}\n", document.dump(1));
      return;
    }
    fmt::print("frames={} ethercat={} errors={}\n", frames_, ethercat_, errors_);
  }

  const Options& options_;
  MailboxTracker mailboxes_;
  std::uint64_t frames_ = 0;
  std::uint64_t ethercat_ = 0;
  std::uint64_t errors_ = 0;
  ordered_json json_frames_ = ordered_json::array();
  ordered_json json_errors_ = ordered_json::array();
};

Command setup(CLI::App& parent) {
  auto* app = parent.add_subcommand(
      "decode",
      "Decode every EtherCAT frame of a pcap/pcapng capture (exit 1 if any is malformed)");
  auto options = std::make_shared<Options>();
  app->add_option("FILE", options->file, "Capture file (pcap or pcapng)")->required();
  app->add_flag("--json", options->json, "Print JSON instead of text");
  app->add_option("--udp-port", options->udp_port,
                  "EtherCAT over UDP on this port (default 34980, 0x88A4)")
      ->check(CLI::Range(1, 65535));
  return {app, [options] { return Decoder(*options).run(); }};
}

const bool registered = register_command(&setup);

}  // namespace
}  // namespace ecat::tool
