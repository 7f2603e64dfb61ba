// The committed seeds of fuzz/fuzz_sim_mailbox.cpp (fuzz/seeds/sim_mailbox/): sequences of
// messages for the simulator's mailbox servers, made by our own encoders, that walk the paths
// worth fuzzing from: FoE writes and reads over several packets, a firmware image written in
// BOOTSTRAP and started at INIT, FoE refusals (password, state, numbering, opcodes), SoE reads of
// a fragmented IDN list and fragmented writes, EoE Set IP, ARP and a fragmented ping, CoE
// segmented transfers and repeats. Regenerate with ECAT_WRITE_MAILBOX_SEEDS=1.
//
// Framing (the fuzz target's): each message is a 2-byte little-endian length and its bytes; a
// message's first byte chooses the device (0 mailbox, 1 SoE drive, 2 EoE device) or, for 3 + 4 k,
// the mailbox device's state (k = 0 INIT, 1 PREOP, 2 BOOTSTRAP, 3 the SM1 repeat request).
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/foe_server.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/soe.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::sim {
namespace {

using Vec = std::vector<std::uint8_t>;

constexpr std::uint8_t kMailboxDevice = 0;
constexpr std::uint8_t kSoeDrive = 1;
constexpr std::uint8_t kEoeDevice = 2;
constexpr std::uint8_t kInit = 3;
constexpr std::uint8_t kPreop = 3 + 4;
constexpr std::uint8_t kBootstrap = 3 + 8;
constexpr std::uint8_t kRepeat = 3 + 12;

template <class T>
T value_of(Result<T> r) {
  EXPECT_TRUE(r.ok()) << r.error().describe();
  return r ? std::move(*r) : T{};
}

class Sequence {
 public:
  // One mailbox (header + data) to `target`; counters run 1..7 per target as a master's do.
  Sequence& send(std::uint8_t target, wire::MailboxType type, Vec data) {
    auto& counter = counters_[target];
    counter = wire::next_mailbox_counter(counter);
    wire::MailboxHeader header;
    header.length = static_cast<std::uint16_t>(data.size());
    header.type = type;
    header.counter = counter;
    Vec message{target};
    const auto mailbox = value_of(wire::encode_mailbox(header, data));
    message.insert(message.end(), mailbox.begin(), mailbox.end());
    return raw(std::move(message));
  }
  Sequence& control(std::uint8_t t) { return raw({t}); }
  Sequence& foe(std::uint8_t target, const wire::FoeMessage& m) {
    return send(target, wire::MailboxType::foe, value_of(wire::encode_foe(m)));
  }
  Sequence& soe(const wire::SoeMessage& m) {
    return send(kSoeDrive, wire::MailboxType::soe, value_of(wire::encode_soe(m)));
  }
  Sequence& eoe(const wire::EoeMessage& m) {
    return send(kEoeDevice, wire::MailboxType::eoe, value_of(wire::encode_eoe(m)));
  }
  Sequence& coe(const wire::SdoMessage& m) {
    Vec data = value_of(wire::encode_sdo(m));
    return send(kMailboxDevice, wire::MailboxType::coe, std::move(data));
  }
  Sequence& raw(Vec message) {
    bytes_.push_back(static_cast<std::uint8_t>(message.size()));
    bytes_.push_back(static_cast<std::uint8_t>(message.size() >> 8));
    bytes_.insert(bytes_.end(), message.begin(), message.end());
    return *this;
  }
  // `file` written in DATA packets of `packet` bytes (a shorter one ends it).
  Sequence& foe_data(std::uint8_t target, const Vec& file, std::size_t packet) {
    std::uint32_t number = 1;
    for (std::size_t at = 0;; at += packet, ++number) {
      const std::size_t n = std::min(packet, file.size() - at);
      foe(target, wire::FoeData{number, Vec(file.begin() + static_cast<std::ptrdiff_t>(at),
                                            file.begin() + static_cast<std::ptrdiff_t>(at + n))});
      if (n < packet) return *this;
    }
  }
  Vec bytes() const { return bytes_; }

 private:
  Vec bytes_;
  std::uint8_t counters_[3]{};
};

Vec pattern(std::size_t n) {
  Vec out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>(i * 5 + 1);
  return out;
}

// EoE fragments of `frame` for a mailbox carrying `max_data` bytes of data.
std::vector<wire::EoeMessage> eoe_fragments(const Vec& frame, std::size_t max_data,
                                            std::uint8_t frame_number) {
  std::vector<wire::EoeMessage> out;
  const std::size_t room = max_data - wire::kEoeHeaderSize;
  const std::size_t block_room = room / wire::kEoeBlockSize * wire::kEoeBlockSize;
  std::uint8_t number = 0;
  for (std::size_t offset = 0; offset < frame.size(); ++number) {
    const std::size_t left = frame.size() - offset;
    const bool last = left <= room;
    const std::size_t size = last ? left : block_room;
    wire::EoeFragment f;
    f.header.last_fragment = last;
    f.header.fragment_number = number;
    f.header.offset_blocks = static_cast<std::uint8_t>(
        number == 0 ? (frame.size() + wire::kEoeBlockSize - 1) / wire::kEoeBlockSize
                    : offset / wire::kEoeBlockSize);
    f.header.frame_number = frame_number;
    f.data.assign(frame.begin() + static_cast<std::ptrdiff_t>(offset),
                  frame.begin() + static_cast<std::ptrdiff_t>(offset + size));
    out.emplace_back(std::move(f));
    offset += size;
  }
  return out;
}

std::uint16_t checksum(const Vec& d, std::size_t from, std::size_t n) {
  std::uint32_t sum = 0;
  for (std::size_t i = 0; i + 1 < n; i += 2)
    sum += static_cast<std::uint32_t>((d[from + i] << 8) | d[from + i + 1]);
  if (n % 2 != 0) sum += static_cast<std::uint32_t>(d[from + n - 1] << 8);
  while (sum >> 16)
    sum = (sum & 0xFFFF) + (sum >> 16);
  return static_cast<std::uint16_t>(~sum);
}

void put16(Vec& d, std::size_t at, std::uint16_t v) {
  d[at] = static_cast<std::uint8_t>(v >> 8);
  d[at + 1] = static_cast<std::uint8_t>(v);
}

// An Ethernet frame from 02:00:00:00:00:99 / 192.168.1.1 to the EoE device (192.168.1.2).
Vec arp_request() {
  Vec f(42, 0);
  std::fill(f.begin(), f.begin() + 6, 0xFF);
  f[6] = 0x02, f[11] = 0x99;
  put16(f, 12, 0x0806);
  put16(f, 14, 1), put16(f, 16, 0x0800), f[18] = 6, f[19] = 4, put16(f, 20, 1);
  f[22] = 0x02, f[27] = 0x99;
  f[28] = 192, f[29] = 168, f[30] = 1, f[31] = 1;
  f[38] = 192, f[39] = 168, f[40] = 1, f[41] = 2;
  return f;
}

Vec ping(const std::array<std::uint8_t, 6>& mac, std::size_t payload) {
  Vec f(14 + 20 + 8 + payload, 0);
  std::copy(mac.begin(), mac.end(), f.begin());
  f[6] = 0x02, f[11] = 0x99;
  put16(f, 12, 0x0800);
  f[14] = 0x45;
  put16(f, 16, static_cast<std::uint16_t>(20 + 8 + payload));
  f[22] = 64, f[23] = 1;  // TTL, ICMP
  f[26] = 192, f[27] = 168, f[28] = 1, f[29] = 1;
  f[30] = 192, f[31] = 168, f[32] = 1, f[33] = 2;
  put16(f, 24, checksum(f, 14, 20));
  f[34] = 8;  // echo request
  put16(f, 38, 0x1234), put16(f, 40, 1);
  for (std::size_t i = 0; i < payload; ++i)
    f[42 + i] = static_cast<std::uint8_t>(i);
  put16(f, 36, checksum(f, 34, 8 + payload));
  return f;
}

std::vector<std::pair<std::string, Vec>> generated_seeds() {
  std::vector<std::pair<std::string, Vec>> seeds;
  // The mailbox device: 64-byte mailbox (52 bytes of FoE data a packet), 256-byte bootstrap
  // mailbox (244).
  const Vec file = pattern(120);
  seeds.emplace_back("foe_write_read", Sequence()
                                           .foe(kMailboxDevice, wire::FoeWriteRequest{7, "a.txt"})
                                           .foe_data(kMailboxDevice, file, 52)
                                           .foe(kMailboxDevice, wire::FoeReadRequest{7, "a.txt"})
                                           .foe(kMailboxDevice, wire::FoeAck{1})
                                           .foe(kMailboxDevice, wire::FoeAck{2})
                                           .foe(kMailboxDevice, wire::FoeAck{3})
                                           .bytes());
  const Vec image = value_of(make_firmware_image("2.0.0", pattern(400)));
  seeds.emplace_back("foe_firmware_update",
                     Sequence()
                         .control(kBootstrap)
                         .foe(kMailboxDevice, wire::FoeWriteRequest{0, "firmware.efw"})
                         .foe_data(kMailboxDevice, image, 244)
                         .control(kInit)
                         .control(kPreop)
                         .coe(wire::SdoInitiateUploadRequest{0x100A, 0, false})
                         .bytes());
  // A message to the mailbox device in INIT after BOOTSTRAP: its SyncManagers still cover the
  // bootstrap mailbox, so the standard mailbox's area is plain RAM (a fuzz run once read it back
  // as a reply); then PREOP, whose mailbox must answer as if nothing had happened.
  seeds.emplace_back("init_after_bootstrap",
                     Sequence()
                         .control(kBootstrap)
                         .control(kInit)
                         .coe(wire::SdoInitiateUploadRequest{0x1008, 0, false})
                         .control(kPreop)
                         .coe(wire::SdoInitiateUploadRequest{0x1008, 0, false})
                         .bytes());
  Vec corrupt = image;
  corrupt[kFirmwareHeaderSize + 7] ^= 1;
  seeds.emplace_back("foe_firmware_corrupt",
                     Sequence()
                         .control(kBootstrap)
                         .foe(kMailboxDevice, wire::FoeWriteRequest{0, "firmware.efw"})
                         .foe_data(kMailboxDevice, corrupt, 244)
                         .control(kPreop)
                         .bytes());
  seeds.emplace_back(
      "foe_refusals",
      Sequence()
          .foe(kMailboxDevice, wire::FoeWriteRequest{0, "firmware.efw"})  // not in BOOTSTRAP
          .foe(kMailboxDevice, wire::FoeReadRequest{0, "missing"})        // not found
          .foe(kMailboxDevice, wire::FoeAck{1})                           // no read running
          .foe(kMailboxDevice, wire::FoeWriteRequest{5, "p.bin"})
          .foe(kMailboxDevice, wire::FoeData{2, {1, 2}})  // wrong packet number
          .foe(kMailboxDevice, wire::FoeWriteRequest{5, "p.bin"})
          .foe(kMailboxDevice, wire::FoeData{1, {1, 2}})
          .foe(kMailboxDevice, wire::FoeReadRequest{6, "p.bin"})   // wrong password
          .foe(kMailboxDevice, wire::FoeWriteRequest{6, "p.bin"})  // ... for a write too
          .foe(kMailboxDevice, wire::FoeBusy{1, 2})                // not a request
          .foe(kMailboxDevice, wire::FoeWriteRequest{0, "q.bin"})
          .foe(kMailboxDevice, wire::FoeError{0x8000, "master gives up"})
          .foe(kMailboxDevice, wire::FoeData{1, {}})  // no write running any more
          .bytes());
  // CoE: a segmented upload and download on the 64-byte mailbox, a repeated request, the SM1
  // repeat request.
  seeds.emplace_back(
      "coe_segmented",
      Sequence()
          .coe(wire::SdoInitiateUploadRequest{0x2003, 1, false})
          .coe(wire::SdoUploadSegmentRequest{false})
          .coe(wire::SdoUploadSegmentRequest{true})
          .control(kRepeat)
          .coe(wire::SdoInitiateDownloadRequest{
              .index = 0x2002, .subindex = 1, .complete_size = 80, .data = pattern(40)})
          .coe(wire::SdoDownloadSegmentRequest{.toggle = false, .last = true, .data = pattern(40)})
          .bytes());
  // SoE (128-byte mailbox): the IDN list in fragments, an unknown IDN, a fragmented write of a
  // configuration list, a read-only IDN.
  const auto soe_read = [](std::uint16_t idn, std::uint8_t elements) {
    wire::SoeMessage m;
    m.header = {.opcode = wire::SoeOpcode::read_request, .elements = elements, .idn = idn};
    return m;
  };
  Vec list{120, 0, 120, 0};
  for (std::uint16_t i = 0; i < 60; ++i) {
    list.push_back(static_cast<std::uint8_t>(i + 1));
    list.push_back(0);
  }
  wire::SoeMessage first;
  first.header = {
      .opcode = wire::SoeOpcode::write_request, .incomplete = true, .elements = 0x40, .idn = 1};
  first.data.assign(list.begin(), list.begin() + 100);
  wire::SoeMessage last;
  last.header = {.opcode = wire::SoeOpcode::write_request, .elements = 0x40, .idn = 24};
  last.data.assign(list.begin() + 100, list.end());
  wire::SoeMessage read_only;
  read_only.header = {.opcode = wire::SoeOpcode::write_request, .elements = 0x40, .idn = 51};
  read_only.data = {0, 0, 0, 0};
  seeds.emplace_back("soe_read_write", Sequence()
                                           .soe(soe_read(17, 0x40))
                                           .soe(soe_read(17, 0x7C))
                                           .soe(soe_read(0x0999, 0x40))
                                           .soe(first)
                                           .soe(last)
                                           .soe(soe_read(24, 0x40))
                                           .soe(read_only)
                                           .bytes());
  // EoE (128-byte mailbox): Set IP, ARP, a ping in fragments, then fragments out of order.
  wire::EoeSetIpRequest set_ip;
  set_ip.parameters.ip = 0xC0A80102;
  set_ip.parameters.mac = std::array<std::uint8_t, 6>{2, 0, 0x0A, 0xCE, 0, 1};
  Sequence eoe;
  eoe.eoe(set_ip);
  for (auto& f : eoe_fragments(arp_request(), 122, 0))
    eoe.eoe(f);
  const std::array<std::uint8_t, 6> mac{2, 0, 0x0A, 0xCE, 0, 1};
  for (auto& f : eoe_fragments(ping(mac, 200), 122, 1))
    eoe.eoe(f);
  auto parts = eoe_fragments(ping(mac, 100), 122, 2);
  std::swap(parts[0], parts[1]);
  for (auto& f : parts)
    eoe.eoe(f);
  seeds.emplace_back("eoe_ip_arp_ping", eoe.bytes());
  return seeds;
}

TEST(SimMailboxFuzzSeeds, CommittedSeedsMatchTheEncoders) {
  const std::filesystem::path dir =
      std::filesystem::path(ECAT_SOURCE_DIR) / "fuzz/seeds/sim_mailbox";
  const bool write = std::getenv("ECAT_WRITE_MAILBOX_SEEDS") != nullptr;
  if (write) std::filesystem::create_directories(dir);
  for (const auto& [name, bytes] : generated_seeds()) {
    const auto path = dir / (name + ".bin");
    if (write) {
      std::ofstream(path, std::ios::binary)
          .write(reinterpret_cast<const char*>(bytes.data()),
                 static_cast<std::streamsize>(bytes.size()));
    }
    std::ifstream in(path, std::ios::binary);
    ASSERT_TRUE(in.good()) << path << " missing; regenerate with ECAT_WRITE_MAILBOX_SEEDS=1";
    const Vec committed{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    EXPECT_EQ(committed, bytes) << path;
  }
}

}  // namespace
}  // namespace ecat::sim
