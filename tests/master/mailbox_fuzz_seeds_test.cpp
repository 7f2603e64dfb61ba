// The committed seeds of fuzz/fuzz_master_mailbox.cpp (fuzz/seeds/master_mailbox/): what a slave
// puts into SM1 during a master's FoE read and write, SoE read and write and EoE session, made by
// our own encoders: several packets, BUSY, the slave's errors, fragmented SoE responses and EoE
// frames, notifications, emergencies and repeats in between. Regenerate with
// ECAT_WRITE_MAILBOX_SEEDS=1.
//
// Framing (the fuzz target's): byte 0 the operation (0 FoE read, 1 FoE write, 2 SoE read, 3 SoE
// write, 4 EoE receive, 5 EoE Set IP + receive), byte 1 the shape (mailbox 32 << (b % 6) bytes,
// transfer (b >> 3) * 97 bytes), then SM1 messages, each a 2-byte little-endian length and its
// bytes (mailbox header included).
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/eoe.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/foe.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/soe.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::master {
namespace {

using Vec = std::vector<std::uint8_t>;

template <class T>
T value_of(Result<T> r) {
  EXPECT_TRUE(r.ok()) << r.error().describe();
  return r ? std::move(*r) : T{};
}

class Script {
 public:
  Script(std::uint8_t operation, std::uint8_t shape) : bytes_{operation, shape} {}

  // The slave's next message; `repeat`: the previous counter again (a repeated message).
  Script& send(wire::MailboxType type, const Vec& data, bool repeat = false) {
    if (!repeat) counter_ = wire::next_mailbox_counter(counter_);
    wire::MailboxHeader header;
    header.length = static_cast<std::uint16_t>(data.size());
    header.type = type;
    header.counter = counter_;
    return raw(value_of(wire::encode_mailbox(header, data)));
  }
  Script& foe(const wire::FoeMessage& m) {
    return send(wire::MailboxType::foe, value_of(wire::encode_foe(m)));
  }
  Script& soe(const wire::SoeMessage& m) {
    return send(wire::MailboxType::soe, value_of(wire::encode_soe(m)));
  }
  Script& eoe(const Vec& data) { return send(wire::MailboxType::eoe, data); }
  Script& emergency() {
    std::uint8_t buf[wire::kEmergencySize];
    wire::ByteWriter w(buf);
    EXPECT_TRUE(wire::encode_emergency({0x8611, 0x80, {0, 0, 0, 0, 0}}, w).ok());
    return send(wire::MailboxType::coe, Vec(buf, buf + sizeof buf));
  }
  Script& raw(const Vec& message) {
    bytes_.push_back(static_cast<std::uint8_t>(message.size()));
    bytes_.push_back(static_cast<std::uint8_t>(message.size() >> 8));
    bytes_.insert(bytes_.end(), message.begin(), message.end());
    return *this;
  }
  Vec bytes() const { return bytes_; }

 private:
  Vec bytes_;
  std::uint8_t counter_ = 0;
};

Vec pattern(std::size_t n) {
  Vec out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>(i * 3 + 1);
  return out;
}

wire::SoeMessage soe(wire::SoeOpcode opcode, std::uint16_t idn, Vec data, bool incomplete = false) {
  wire::SoeMessage m;
  m.header = {.opcode = opcode, .incomplete = incomplete, .elements = 0x40, .idn = idn};
  m.data = std::move(data);
  return m;
}

std::vector<std::pair<std::string, Vec>> generated_seeds() {
  std::vector<std::pair<std::string, Vec>> seeds;
  // Shape 1: a 64-byte mailbox, FoE packets of 52 bytes.
  seeds.emplace_back("foe_read_busy", Script(0, 1)
                                          .foe(wire::FoeData{1, pattern(52)})
                                          .foe(wire::FoeBusy{1, 4})
                                          .foe(wire::FoeData{2, pattern(52)})
                                          .emergency()
                                          .foe(wire::FoeData{3, pattern(9)})
                                          .bytes());
  seeds.emplace_back("foe_read_error", Script(0, 1)
                                           .foe(wire::FoeData{1, pattern(52)})
                                           .foe(wire::FoeError{0x800A, "wrong password"})
                                           .bytes());
  // Shape 9: 64-byte mailbox, 97 bytes to write: packets of 52 and 45.
  seeds.emplace_back("foe_write_busy", Script(1, 9)
                                           .foe(wire::FoeAck{0})
                                           .foe(wire::FoeBusy{1, 2})
                                           .foe(wire::FoeAck{1})
                                           .foe(wire::FoeAck{2})
                                           .bytes());
  seeds.emplace_back(
      "foe_write_refused",
      Script(1, 9).foe(wire::FoeAck{0}).foe(wire::FoeError{0x800C, "checksum error"}).bytes());
  // SoE read of a 200-byte value in three fragments on a 64-byte mailbox (the IDN field of an
  // incomplete response counts the fragments still to come), a notification in between.
  const Vec value = pattern(130);
  Script soe_read(2, 1);
  soe_read.soe(soe(wire::SoeOpcode::read_response, 2, Vec(value.begin(), value.begin() + 50), true))
      .soe(soe(wire::SoeOpcode::notification, 0x0021, {1, 0}))
      .soe(soe(wire::SoeOpcode::read_response, 1, Vec(value.begin() + 50, value.begin() + 100),
               true))
      .soe(soe(wire::SoeOpcode::read_response, 0x0011, Vec(value.begin() + 100, value.end())));
  seeds.emplace_back("soe_read_fragments", soe_read.bytes());
  wire::SoeMessage error = soe(wire::SoeOpcode::read_response, 0x0011, {});
  error.header.error = true;
  error.error_code = 0x1001;
  seeds.emplace_back("soe_read_error", Script(2, 1).soe(error).bytes());
  // SoE write of 97 bytes on a 64-byte mailbox: fragments, only the last answered.
  seeds.emplace_back("soe_write",
                     Script(3, 9).soe(soe(wire::SoeOpcode::write_response, 0x8001, {})).bytes());
  // EoE: a 100-byte frame in fragments on a 64-byte mailbox, a repeated fragment, a Set IP
  // response, a lost fragment.
  std::vector<Vec> parts = value_of(eoe_fragments(pattern(100), 58, 3));
  Script eoe(5, 1);
  eoe.eoe(value_of(wire::encode_eoe(wire::EoeSetIpResponse{0, 0})));
  for (const auto& p : parts)
    eoe.eoe(p);
  eoe.send(wire::MailboxType::eoe, parts.back(), true);
  std::vector<Vec> next = value_of(eoe_fragments(pattern(100), 58, 4));
  eoe.eoe(next[0]).eoe(next[2]);
  seeds.emplace_back("eoe_fragments", eoe.bytes());
  return seeds;
}

TEST(MasterMailboxFuzzSeeds, CommittedSeedsMatchTheEncoders) {
  const std::filesystem::path dir =
      std::filesystem::path(ECAT_SOURCE_DIR) / "fuzz/seeds/master_mailbox";
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
}  // namespace ecat::master
