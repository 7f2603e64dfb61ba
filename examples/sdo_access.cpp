// CoE SDO access: read a drive's identity and name, change a parameter and read it back, and see
// how a refused transfer is reported. Against the simulated CiA 402 drive of
// examples/default.yaml (slave "drive").
//
// SDO transfers go through the slave's mailbox on the master's control thread; they work from
// PREOP up, so they can run while process data is exchanged.
//
//   example_sdo_access [examples/default.yaml]
//
// Exit code 0 when every transfer did what it shows.
#include <chrono>
#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <ecat/ecat.hpp>

using namespace std::chrono_literals;

// CoE data is little-endian; ecat::wire has the loads and stores.
static std::vector<std::uint8_t> u32_bytes(std::uint32_t value) {
  std::vector<std::uint8_t> bytes(4);
  ecat::wire::store_le32(bytes.data(), value);
  return bytes;
}

static bool read_u32(ecat::master::Slave& slave, std::uint16_t index, std::uint8_t subindex,
                     const char* what, std::uint32_t& out) {
  auto data = slave.upload_sdo(index, subindex);
  if (!data || data->size() != 4) {
    std::fprintf(stderr, "0x%04X:%02X: %s\n", index, subindex,
                 data ? "not 4 bytes" : data.error().describe().c_str());
    return false;
  }
  out = ecat::wire::load_le32(data->data());
  std::printf("0x%04X:%02X %-18s 0x%08" PRIX32 "\n", index, subindex, what, out);
  return true;
}

int main(int argc, char** argv) {
  const std::string ring = argc > 1 ? argv[1] : "examples/default.yaml";
  auto opened = ecat::open_master(ring);  // configured and started from the file
  if (!opened) {
    std::fprintf(stderr, "%s\n", opened.error().describe().c_str());
    return 1;
  }
  ecat::master::Master& master = **opened;
  // Running: every slave reached the state its configuration asks for (PREOP at least).
  auto running = master.await_running(20s);
  auto drive = master.slave("drive");
  if (!running || !drive) {
    std::fprintf(stderr, "%s\n", !running ? running.error().describe().c_str() : "no drive");
    return 1;
  }
  ecat::master::Slave& servo = **drive;
  bool ok = true;

  // Uploads: the identity object 0x1018 (vendor, product, revision, serial) ...
  std::uint32_t value = 0;
  ok = read_u32(servo, 0x1018, 0x01, "vendor id", value) && ok;
  ok = read_u32(servo, 0x1018, 0x02, "product code", value) && ok;
  ok = read_u32(servo, 0x1018, 0x03, "revision", value) && ok;
  // ... and a string: 0x1008 the device name (longer ones arrive in segments, transparently).
  if (auto name = servo.upload_sdo(0x1008, 0x00); name) {
    std::printf("0x1008:00 %-18s \"%s\"\n", "device name",
                std::string(name->begin(), name->end()).c_str());
  } else {
    std::fprintf(stderr, "0x1008:00: %s\n", name.error().describe().c_str());
    ok = false;
  }

  // A download: the profile velocity 0x6081:00 (UNSIGNED32), then read back.
  constexpr std::uint32_t kVelocity = 25'000;
  if (auto written = servo.download_sdo(0x6081, 0x00, u32_bytes(kVelocity)); !written) {
    std::fprintf(stderr, "0x6081:00: %s\n", written.error().describe().c_str());
    ok = false;
  }
  ok = read_u32(servo, 0x6081, 0x00, "profile velocity", value) && value == kVelocity && ok;

  // A refused transfer is an Error with Errc::sdo_abort; the abort code is attached to it.
  // 0x6502 (supported drive modes) is read-only: writing it aborts with 0x06010002.
  auto refused = servo.download_sdo(0x6502, 0x00, u32_bytes(0));
  if (refused) {
    std::fprintf(stderr, "0x6502:00 was written, but it is read-only\n");
    ok = false;
  } else {
    const auto abort = refused.error().code_value(ecat::Errc::sdo_abort);
    std::printf("0x6502:00 refused (abort code 0x%08" PRIX32 "): %s\n", abort.value_or(0),
                refused.error().describe().c_str());
    ok = abort == 0x06010002u && ok;
  }

  (void)master.stop();  // every slave back to INIT
  return ok ? 0 : 1;
}
