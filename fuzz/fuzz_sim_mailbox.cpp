// The simulator's stateful mailbox servers (CoE with its segmented transfers, FoE with its file
// store and firmware slot, SoE with its fragmented writes, EoE with its frame reassembly, ARP and
// ping) fed a sequence of messages the way a master sends them: written into each device's SM0
// by datagrams, every reply read out of SM1, so that state carries from one message to the next.
//
// Input: messages, each a 2-byte little-endian length and that many bytes (fuzz/seeds/sim_mailbox
// is written by tests/sim/mailbox_fuzz_seeds_test.cpp in this framing). A message's first byte
// says what to do with the rest:
//   t % 4 == 0, 1, 2: the rest is written into SM0 of the mailbox device (CoE, FoE, VoE), the SoE
//                     drive or the EoE device (mailbox header included; cut or zero-padded to
//                     the SyncManager's size), then SM1 is read until it is empty (not in INIT,
//                     which has no mailbox);
//   t % 4 == 3:       the mailbox device is sent to INIT, PREOP, BOOTSTRAP (by (t >> 2) % 4; the
//                     mailbox SyncManagers follow, as a master writes them) or, for 3, the SM1
//                     repeat request is toggled.
// Every reply must be a mailbox whose header and body decode: a device that answers with bytes
// no master can read is a bug.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <ecat/sim/device.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>
#include <ecat/wire/soe.hpp>

namespace {

using namespace ecat;

void require(bool condition) {
  if (!condition) std::abort();
}

struct Reply {
  std::uint16_t wkc = 0;
  std::vector<std::uint8_t> data;
};

struct Device {
  std::uint16_t station = 0;
  wire::SiiMailbox standard;
  wire::SiiMailbox bootstrap;
  wire::AlState state = wire::AlState::init;
  bool repeat = false;
};

class Ring {
 public:
  bool add(const char* profile, std::map<std::string, std::string> options = {}) {
    sim::DeviceConfig config;
    config.profile = profile;
    config.options = std::move(options);
    auto esc = sim::make_device(config);
    if (!esc) return false;
    auto sii = wire::decode_sii((*esc)->eeprom());
    if (!sii) return false;
    Device device;
    device.station = static_cast<std::uint16_t>(0x1001 + devices_.size());
    device.standard = sii->image.standard_mailbox;
    device.bootstrap = sii->image.bootstrap_mailbox;
    const auto position = segment_.size();
    if (!segment_.add_slave(profile, std::move(*esc))) return false;
    const std::uint8_t station[2] = {static_cast<std::uint8_t>(device.station),
                                     static_cast<std::uint8_t>(device.station >> 8)};
    if (datagram(wire::Command::apwr, static_cast<std::uint16_t>(-static_cast<int>(position)),
                 wire::reg::kStationAddress, station, 2)
            .wkc != 1) {
      return false;
    }
    devices_.push_back(device);
    return true;
  }

  Device& device(std::size_t i) { return devices_[i]; }

  // One datagram in a frame of its own through the segment.
  Reply datagram(wire::Command command, std::uint16_t adp, std::uint16_t ado, wire::Bytes data,
                 std::uint16_t length) {
    std::uint8_t buffer[wire::kMaxFrameSize];
    wire::FrameBuilder builder(buffer);
    wire::DatagramHeader header;
    header.command = command;
    header.address = static_cast<std::uint32_t>(adp) | (static_cast<std::uint32_t>(ado) << 16);
    header.length = length;
    require(builder.add(header, data.size() == length ? data : wire::Bytes{}).has_value());
    const auto frame = builder.finish();
    std::vector<std::uint8_t> bytes(frame.begin(), frame.end());
    now_ += 20'000;
    (void)segment_.process_frame(bytes, now_);
    auto view = wire::decode_frame(bytes);
    require(view.frame.has_value() && view.frame->begin() != view.frame->end());
    const auto d = *view.frame->begin();
    return {d.wkc, std::vector<std::uint8_t>(d.data.begin(), d.data.end())};
  }

  void write_u16(const Device& d, std::uint16_t address, std::uint16_t value) {
    const std::uint8_t bytes[2] = {static_cast<std::uint8_t>(value),
                                   static_cast<std::uint8_t>(value >> 8)};
    (void)datagram(wire::Command::fpwr, d.station, address, bytes, 2);
  }

  // SM0/SM1 at `mailbox` (disabled first, as masters do).
  void write_mailbox_sms(const Device& d, const wire::SiiMailbox& mailbox) {
    const std::uint8_t off[wire::SyncManagerConfig::kSize * 2] = {};
    (void)datagram(wire::Command::fpwr, d.station, wire::reg::sync_manager(0), off, sizeof off);
    for (std::size_t sm = 0; sm < 2; ++sm) {
      wire::SyncManagerConfig config;
      config.physical_start = sm == 0 ? mailbox.recv_offset : mailbox.send_offset;
      config.length = sm == 0 ? mailbox.recv_size : mailbox.send_size;
      config.control = sm == 0 ? wire::kMailboxOutControl : wire::kMailboxInControl;
      config.activate.enable = true;
      const auto bytes = config.encode();
      (void)datagram(wire::Command::fpwr, d.station, wire::reg::sync_manager(sm), bytes,
                     static_cast<std::uint16_t>(bytes.size()));
    }
  }

  void al_request(Device& d, wire::AlState state) {
    write_u16(d, wire::reg::kAlControl, static_cast<std::uint16_t>(state) | 0x10);  // ack errors
    write_u16(d, wire::reg::kAlControl, static_cast<std::uint16_t>(state));
    const auto status = datagram(wire::Command::fprd, d.station, wire::reg::kAlStatus, {}, 2);
    if (status.wkc == 1) d.state = static_cast<wire::AlState>(status.data[0] & 0x0F);
  }

  // As a master walks it: through INIT, with the mailbox SyncManagers of the state it goes to.
  void go_to(Device& d, wire::AlState state) {
    al_request(d, wire::AlState::init);
    if (state == wire::AlState::init) return;
    const bool boot = state == wire::AlState::bootstrap;
    if (boot && !d.bootstrap.present()) return;
    write_mailbox_sms(d, boot ? d.bootstrap : d.standard);
    al_request(d, state);
  }

  void toggle_repeat(Device& d) {
    d.repeat = !d.repeat;
    wire::SmActivate activate;
    activate.enable = true;
    activate.repeat_request = d.repeat;
    const std::uint8_t byte = activate.encode();
    (void)datagram(wire::Command::fpwr, d.station,
                   static_cast<std::uint16_t>(wire::reg::sync_manager(1) + 6), {&byte, 1}, 1);
    drain(d);
  }

  const wire::SiiMailbox& mailbox_of(const Device& d) const {
    return d.state == wire::AlState::bootstrap ? d.bootstrap : d.standard;
  }

  void send(Device& d, wire::Bytes message) {
    const auto& mailbox = mailbox_of(d);
    std::vector<std::uint8_t> area(mailbox.recv_size, 0);
    std::copy_n(message.begin(), std::min(message.size(), area.size()), area.begin());
    (void)datagram(wire::Command::fpwr, d.station, mailbox.recv_offset, area,
                   static_cast<std::uint16_t>(area.size()));
    drain(d);
  }

  // SM1 read until it is empty (bounded: a device that never stops talking is a bug too).
  // INIT has no mailbox: the SyncManagers may still cover the bootstrap layout, so the standard
  // area is plain process RAM and reading it returns what is there (WKC 1), as a real ESC does.
  // A master reads nothing there; neither do we.
  void drain(const Device& d) {
    if (d.state == wire::AlState::init) return;
    const auto& mailbox = mailbox_of(d);
    for (int i = 0; i < 256; ++i) {
      auto reply =
          datagram(wire::Command::fprd, d.station, mailbox.send_offset, {}, mailbox.send_size);
      if (reply.wkc == 0) return;
      check_reply(reply.data);
    }
    std::abort();
  }

  static void check_reply(wire::Bytes area) {
    auto message = wire::decode_mailbox(area);  // padding after the message is ignored
    require(message.ok());
    const auto body = message->data;
    switch (message->header.type) {
      case wire::MailboxType::error:
        require(wire::decode_mailbox_error(body).ok());
        break;
      case wire::MailboxType::foe:
        require(wire::decode_foe(body).ok());
        break;
      case wire::MailboxType::eoe:
        require(wire::decode_eoe(body).ok());
        break;
      case wire::MailboxType::soe:
        require(wire::decode_soe(body).ok());
        break;
      default:
        break;
    }
  }

 private:
  sim::Segment segment_;
  std::vector<Device> devices_;
  std::int64_t now_ = 1'000'000'000;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  Ring ring;
  require(ring.add("mailbox"));
  require(ring.add("soe_drive"));
  require(ring.add("eoe_device", {{"ip", "192.168.1.2"}}));
  for (std::size_t i = 0; i < 3; ++i)
    ring.go_to(ring.device(i), wire::AlState::preop);

  std::size_t at = 0;
  while (at + 2 <= size) {
    std::size_t length = static_cast<std::size_t>(data[at] | (data[at + 1] << 8));
    at += 2;
    length = std::min(length, size - at);
    const wire::Bytes message(data + at, length);
    at += length;
    if (message.empty()) continue;
    const std::uint8_t t = message[0];
    const auto rest = message.subspan(1);
    if (t % 4 != 3) {
      ring.send(ring.device(t % 4), rest);
      continue;
    }
    auto& mbx = ring.device(0);
    switch ((t >> 2) % 4) {
      case 0:
        ring.go_to(mbx, wire::AlState::init);
        break;
      case 1:
        ring.go_to(mbx, wire::AlState::preop);
        break;
      case 2:
        ring.go_to(mbx, wire::AlState::bootstrap);
        break;
      default:
        ring.toggle_repeat(mbx);
        break;
    }
  }
  return 0;
}
