// The master's side for simulator device tests: real datagrams through a Segment, one frame per
// datagram, at a segment time the test controls. It does what a simple master does: assigns
// station addresses, reads the SII, configures the mailbox and process-data SyncManagers and one
// FMMU per process-data SyncManager (lengths computed from the SII's PDOs, as real masters do),
// requests AL states, exchanges the process image with LRW and runs SDO transfers.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim::test {

using Bytes = std::vector<std::uint8_t>;
namespace reg = wire::reg;

struct Reply {
  Bytes data;
  std::uint16_t wkc = 0;
};

struct AlResult {
  wire::AlState state = wire::AlState::init;
  bool error = false;
  std::uint16_t code = 0;
};

// Where a process-data SyncManager landed in the process image.
struct ImageSlot {
  std::uint32_t offset = 0;
  std::uint16_t length = 0;
  bool output = false;
};

struct SdoResult {
  std::optional<Bytes> value;  // uploads: the data; downloads: empty vector on success
  std::uint32_t abort = 0;
};

inline std::uint32_t fp(std::uint16_t station, std::uint16_t offset) {
  return wire::physical_address(station, offset);
}

inline Bytes le16(std::uint16_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8)};
}
inline Bytes le32(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

class SimMaster {
 public:
  explicit SimMaster(Segment& segment) : segment_(segment) {}

  Segment& segment() { return segment_; }
  std::int64_t now() const { return now_; }
  // Lets `ns` of segment time pass (the devices' advance() runs).
  void wait(std::int64_t ns) {
    now_ += ns;
    segment_.advance(now_);
  }

  Reply exchange(wire::Command command, std::uint32_t address, Bytes data) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    wire::DatagramHeader header;
    header.command = command;
    header.index = index_++;
    header.address = address;
    header.length = static_cast<std::uint16_t>(data.size());
    EXPECT_TRUE(builder.add(header, data).has_value());
    const auto frame = builder.finish();
    Bytes bytes(frame.begin(), frame.end());
    now_ += 10'000;  // 10 µs per frame
    Reply reply;
    if (!segment_.process_frame(bytes, now_)) return reply;
    auto decoded = wire::decode_frame(bytes);
    EXPECT_TRUE(decoded) << decoded.error.describe();
    if (!decoded) return reply;
    for (const auto& d : *decoded.frame) {
      reply.data.assign(d.data.begin(), d.data.end());
      reply.wkc = d.wkc;
    }
    return reply;
  }

  std::uint16_t station(std::size_t position) const {
    return static_cast<std::uint16_t>(0x1001 + position);
  }
  Esc& esc(std::size_t position) { return segment_.esc(position); }

  void assign_stations() {
    for (std::size_t pos = 0; pos < segment_.size(); ++pos) {
      auto r = exchange(wire::Command::apwr,
                        wire::physical_address(wire::position_adp(static_cast<std::uint16_t>(pos)),
                                               reg::kStationAddress),
                        le16(station(pos)));
      EXPECT_EQ(r.wkc, 1) << "station assignment of position " << pos;
    }
  }

  // The SII through the ESC's EEPROM interface, word by word as a master reads it.
  Bytes read_sii(std::size_t position, std::size_t bytes) {
    Bytes out;
    const std::uint16_t s = station(position);
    for (std::uint32_t word = 0; out.size() < bytes; word += 4) {
      exchange(wire::Command::fpwr, fp(s, reg::kSiiAddress), le32(word));
      exchange(wire::Command::fpwr, fp(s, reg::kSiiControl), le16(wire::sii_control::kCommandRead));
      auto data = exchange(wire::Command::fprd, fp(s, reg::kSiiData), Bytes(8, 0));
      out.insert(out.end(), data.data.begin(), data.data.end());
    }
    out.resize(bytes);
    return out;
  }

  wire::SiiImage sii(std::size_t position) {
    auto decoded = wire::decode_sii(esc(position).eeprom());
    EXPECT_TRUE(decoded.ok());
    return decoded.ok() ? decoded->image : wire::SiiImage{};
  }

  AlResult al_status(std::size_t position) {
    auto r = exchange(wire::Command::fprd, fp(station(position), reg::kAlStatus), Bytes(6, 0));
    AlResult result;
    if (r.wkc != 1 || r.data.size() < 6) return result;
    result.state = wire::al_state_from_code(r.data[0] & 0x0F).value_or(wire::AlState::init);
    result.error = (r.data[0] & 0x10) != 0;
    result.code = wire::load_le16(&r.data[4]);
    return result;
  }

  AlResult request(std::size_t position, wire::AlState state, bool acknowledge = false) {
    exchange(wire::Command::fpwr, fp(station(position), reg::kAlControl),
             le16(wire::encode_al_control(state, acknowledge)));
    return al_status(position);
  }

  void write_sm(std::size_t position, std::size_t sm, std::uint16_t start, std::uint16_t length,
                std::uint8_t control, bool enable = true) {
    const std::uint16_t s = station(position);
    const auto base = reg::sync_manager(sm);
    exchange(wire::Command::fpwr, fp(s, static_cast<std::uint16_t>(base + 6)), {0});
    exchange(
        wire::Command::fpwr, fp(s, base),
        {static_cast<std::uint8_t>(start), static_cast<std::uint8_t>(start >> 8),
         static_cast<std::uint8_t>(length), static_cast<std::uint8_t>(length >> 8), control, 0});
    if (enable) exchange(wire::Command::fpwr, fp(s, static_cast<std::uint16_t>(base + 6)), {1});
  }

  void write_fmmu(std::size_t position, std::size_t index, std::uint32_t logical,
                  std::uint16_t length, std::uint16_t physical, bool output) {
    wire::FmmuConfig f;
    f.logical_start = logical;
    f.length = length;
    f.logical_start_bit = 0;
    f.logical_stop_bit = 7;
    f.physical_start = physical;
    f.type = output ? wire::FmmuType::write : wire::FmmuType::read;
    f.active = true;
    const auto bytes = f.encode();
    exchange(wire::Command::fpwr, fp(station(position), reg::fmmu(index)),
             Bytes(bytes.begin(), bytes.end()));
  }

  // SM0/SM1 as the SII's standard mailbox says.
  void configure_mailbox(std::size_t position) {
    const auto image = sii(position);
    const auto& mb = image.standard_mailbox;
    if (!mb.present()) return;
    write_sm(position, 0, mb.recv_offset, mb.recv_size, wire::kMailboxOutControl.encode());
    write_sm(position, 1, mb.send_offset, mb.send_size, wire::kMailboxInControl.encode());
    mailbox_[position] = {mb.recv_offset, mb.recv_size, mb.send_offset, mb.send_size};
    counter_[position] = 0;
  }

  // The SII's process-data SyncManagers with lengths from its assigned PDOs (or `lengths`), one
  // FMMU each, appended to the process image.
  void configure_process_data(std::size_t position,
                              const std::map<std::size_t, std::uint16_t>& lengths = {}) {
    const auto image = sii(position);
    std::size_t fmmu = 0;
    for (std::size_t sm = 0; sm < image.sync_managers.size(); ++sm) {
      const auto& s = image.sync_managers[sm];
      const bool output = s.type == wire::sii_sm_type::kOutputs;
      if ((!output && s.type != wire::sii_sm_type::kInputs) || !s.enabled() || s.virtual_sm()) {
        continue;
      }
      std::uint32_t bits = 0;
      for (const auto* list : {&image.rxpdos, &image.txpdos}) {
        for (const auto& p : *list) {
          if (p.sync_manager == sm) bits += p.bit_length();
        }
      }
      auto it = lengths.find(sm);
      const auto length =
          it != lengths.end() ? it->second : static_cast<std::uint16_t>((bits + 7) / 8);
      if (length == 0) continue;
      write_sm(position, sm, s.start, length, s.control);
      write_fmmu(position, fmmu++, image_size_, length, s.start, output);
      slots_[{position, sm}] = {image_size_, length, output};
      image_size_ += length;
    }
  }

  // Station, mailbox, PREOP, process data: a slave ready for SAFEOP.
  void bring_to_preop(std::size_t position) {
    configure_mailbox(position);
    const auto r = request(position, wire::AlState::preop);
    EXPECT_EQ(r.state, wire::AlState::preop) << "AL status code " << r.code;
  }

  const ImageSlot& slot(std::size_t position, std::size_t sm) { return slots_.at({position, sm}); }
  std::uint32_t image_size() const { return image_size_; }
  Bytes& image() {
    image_.resize(image_size_, 0);
    return image_;
  }

  // One LRW over the whole image: outputs go out from image(), inputs come back into it.
  std::uint16_t lrw() {
    Bytes& img = image();
    auto r = exchange(wire::Command::lrw, 0, img);
    // Outputs stay what the application wrote; inputs take what came back.
    for (const auto& [key, s] : slots_) {
      if (s.output) continue;
      for (std::uint32_t i = 0; i < s.length; ++i)
        img[s.offset + i] = r.data[s.offset + i];
    }
    return r.wkc;
  }

  // ---- mailbox --------------------------------------------------------------------------------
  bool write_mailbox(std::size_t position, wire::MailboxType type, const Bytes& data) {
    auto& mb = mailbox_.at(position);
    wire::MailboxHeader header;
    header.type = type;
    counter_[position] = wire::next_mailbox_counter(counter_[position]);
    header.counter = counter_[position];
    auto bytes = wire::encode_mailbox(header, data);
    EXPECT_TRUE(bytes.ok());
    Bytes padded = *bytes;
    padded.resize(mb[1], 0);
    return exchange(wire::Command::fpwr, fp(station(position), mb[0]), padded).wkc == 1;
  }
  // Reads SM1 when it is full.
  std::optional<std::pair<wire::MailboxHeader, Bytes>> read_mailbox(std::size_t position) {
    auto& mb = mailbox_.at(position);
    auto r = exchange(wire::Command::fprd, fp(station(position), mb[2]), Bytes(mb[3], 0));
    if (r.wkc != 1) return std::nullopt;
    auto decoded = wire::decode_mailbox(r.data);
    EXPECT_TRUE(decoded.ok());
    if (!decoded) return std::nullopt;
    return std::make_pair(decoded->header, Bytes(decoded->data.begin(), decoded->data.end()));
  }
  // Reads mailboxes until an SDO reply; emergencies met on the way are collected.
  std::optional<wire::SdoMessage> sdo(std::size_t position, const wire::SdoMessage& request) {
    auto data = wire::encode_sdo(request);
    EXPECT_TRUE(data.ok());
    if (!write_mailbox(position, wire::MailboxType::coe, *data)) return std::nullopt;
    for (int i = 0; i < 8; ++i) {
      auto reply = read_mailbox(position);
      if (!reply) return std::nullopt;
      if (auto emergency = wire::decode_emergency(reply->second)) {
        emergencies.push_back(*emergency);
        continue;
      }
      auto message = wire::decode_sdo(reply->second);
      if (message) return *message;
    }
    return std::nullopt;
  }
  // Emergencies waiting in SM1 (reads until the mailbox is empty).
  std::vector<wire::Emergency> drain_emergencies(std::size_t position) {
    while (auto reply = read_mailbox(position)) {
      if (auto e = wire::decode_emergency(reply->second)) emergencies.push_back(*e);
    }
    auto out = emergencies;
    emergencies.clear();
    return out;
  }

  SdoResult upload(std::size_t position, std::uint16_t index, std::uint8_t subindex) {
    SdoResult result;
    auto reply = sdo(position, wire::SdoInitiateUploadRequest{index, subindex, false});
    if (!reply) return result;
    if (auto* a = std::get_if<wire::SdoAbort>(&*reply)) {
      result.abort = a->code;
      return result;
    }
    auto* init = std::get_if<wire::SdoInitiateUploadResponse>(&*reply);
    if (init == nullptr) return result;
    Bytes value = init->data;
    bool toggle = false;
    while (!init->expedited && value.size() < init->complete_size) {
      auto seg = sdo(position, wire::SdoUploadSegmentRequest{toggle});
      if (!seg) return result;
      if (auto* a = std::get_if<wire::SdoAbort>(&*seg)) {
        result.abort = a->code;
        return result;
      }
      auto* s = std::get_if<wire::SdoUploadSegmentResponse>(&*seg);
      if (s == nullptr) return result;
      value.insert(value.end(), s->data.begin(), s->data.end());
      toggle = !toggle;
      if (s->last) break;
    }
    result.value = value;
    return result;
  }

  SdoResult download(std::size_t position, std::uint16_t index, std::uint8_t subindex,
                     const Bytes& value) {
    SdoResult result;
    const auto& mb = mailbox_.at(position);
    wire::SdoInitiateDownloadRequest init;
    init.index = index;
    init.subindex = subindex;
    std::size_t sent = 0;
    if (!value.empty() && value.size() <= 4) {
      init.expedited = true;
      init.data = value;
      sent = value.size();
    } else {
      init.complete_size = static_cast<std::uint32_t>(value.size());
      sent = std::min<std::size_t>(value.size(), mb[1] - 16u);
      init.data.assign(value.begin(), value.begin() + static_cast<std::ptrdiff_t>(sent));
    }
    auto reply = sdo(position, init);
    if (!reply) return result;
    if (auto* a = std::get_if<wire::SdoAbort>(&*reply)) {
      result.abort = a->code;
      return result;
    }
    bool toggle = false;
    while (sent < value.size()) {
      const std::size_t n = std::min<std::size_t>(mb[1] - 9u, value.size() - sent);
      wire::SdoDownloadSegmentRequest seg;
      seg.toggle = toggle;
      seg.last = sent + n == value.size();
      seg.data.assign(value.begin() + static_cast<std::ptrdiff_t>(sent),
                      value.begin() + static_cast<std::ptrdiff_t>(sent + n));
      auto r = sdo(position, seg);
      if (!r) return result;
      if (auto* a = std::get_if<wire::SdoAbort>(&*r)) {
        result.abort = a->code;
        return result;
      }
      sent += n;
      toggle = !toggle;
    }
    result.value = Bytes{};
    return result;
  }

  std::vector<wire::Emergency> emergencies;

 private:
  Segment& segment_;
  std::int64_t now_ = 1'000'000;
  std::uint8_t index_ = 0;
  std::uint32_t image_size_ = 0;
  Bytes image_;
  std::map<std::pair<std::size_t, std::size_t>, ImageSlot> slots_;
  std::map<std::size_t, std::array<std::uint16_t, 4>> mailbox_;
  std::map<std::size_t, std::uint8_t> counter_;
};

// A segment of devices made by make_device, in a line.
inline void add_device(Segment& segment, const std::string& name, const DeviceConfig& config) {
  auto esc = make_device(config);
  ASSERT_TRUE(esc.ok()) << esc.error().describe();
  ASSERT_TRUE(segment.add_slave(name, std::move(*esc)).ok());
}

inline DeviceConfig profile(std::string name, std::map<std::string, std::string> options = {}) {
  DeviceConfig c;
  c.profile = std::move(name);
  c.options = std::move(options);
  return c;
}

}  // namespace ecat::sim::test
