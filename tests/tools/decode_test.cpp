// `ecat decode`: runs the built tool (env ECAT_TOOL) on handcrafted captures and on the shared
// real-device captures.
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include "support/shared_data.hpp"
#include "support/tool_runner.hpp"

namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<std::uint8_t>;

class DecodeTool : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(ecat::test::tool_path()))
        << "ecat tool not found at " << ecat::test::tool_path() << " (set ECAT_TOOL)";
    tool_ = std::make_unique<ecat::test::ToolRunner>("decode-test");
    dir_ = tool_->dir();
  }
  ecat::test::ToolRun run_tool(const std::string& arguments) const {
    return tool_->run("decode " + arguments);
  }

  fs::path write(const std::string& name, const Bytes& bytes) const {
    const auto path = dir_ / name;
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char*>(bytes.data()),
               static_cast<std::streamsize>(bytes.size()));
    return path;
  }

  std::unique_ptr<ecat::test::ToolRunner> tool_;
  fs::path dir_;
};

// ---------------------------------------------------------------------------------------------
// Building captures byte by byte, independently of the code under test.

void le16(Bytes& out, std::uint16_t v) {
  out.push_back(static_cast<std::uint8_t>(v));
  out.push_back(static_cast<std::uint8_t>(v >> 8));
}
void le32(Bytes& out, std::uint32_t v) {
  le16(out, static_cast<std::uint16_t>(v));
  le16(out, static_cast<std::uint16_t>(v >> 16));
}
void be16(Bytes& out, std::uint16_t v) {
  out.push_back(static_cast<std::uint8_t>(v >> 8));
  out.push_back(static_cast<std::uint8_t>(v));
}
void append(Bytes& out, const Bytes& more) {
  out.insert(out.end(), more.begin(), more.end());
}

struct Datagram {
  std::uint8_t command;
  std::uint8_t index;
  std::uint16_t adp;
  std::uint16_t ado;
  Bytes data;
  std::uint16_t wkc = 0;
};

Bytes ethercat_frame(const std::vector<Datagram>& datagrams) {
  Bytes body;
  for (std::size_t i = 0; i < datagrams.size(); ++i) {
    const auto& d = datagrams[i];
    body.push_back(d.command);
    body.push_back(d.index);
    le16(body, d.adp);
    le16(body, d.ado);
    le16(body, static_cast<std::uint16_t>(d.data.size() | (i + 1 < datagrams.size() ? 0x8000 : 0)));
    le16(body, 0);
    append(body, d.data);
    le16(body, d.wkc);
  }
  Bytes frame;
  le16(frame, static_cast<std::uint16_t>(0x1000 | body.size()));
  append(frame, body);
  return frame;
}

const Bytes kSourceMac{0x02, 0x00, 0x00, 0x00, 0x00, 0x01};

// Frames a master sends: the source MAC's locally-administered bit is how the tool tells them
// from the frames ESCs send back (which have it set).
const Bytes kMasterMac{0x00, 0x1B, 0x21, 0x00, 0x00, 0x01};
const Bytes kReturnedMac{0x02, 0x1B, 0x21, 0x00, 0x00, 0x01};

Bytes ethernet(std::uint16_t ether_type, const Bytes& payload, bool vlan = false,
               const Bytes& source = kSourceMac) {
  Bytes out(6, 0xFF);
  append(out, source);
  if (vlan) {
    be16(out, 0x8100);
    be16(out, 0x0005);
  }
  be16(out, ether_type);
  append(out, payload);
  if (out.size() < 60) out.resize(60, 0);
  return out;
}

Bytes ipv4_udp(std::uint16_t source_port, std::uint16_t destination_port, const Bytes& payload) {
  Bytes out{0x45, 0x00};
  be16(out, static_cast<std::uint16_t>(20 + 8 + payload.size()));
  append(out, {0x00, 0x01, 0x40, 0x00, 0x40, 17, 0x00, 0x00, 192, 168, 0, 1, 192, 168, 0, 2});
  be16(out, source_port);
  be16(out, destination_port);
  be16(out, static_cast<std::uint16_t>(8 + payload.size()));
  be16(out, 0);
  append(out, payload);
  return out;
}

// A classic little-endian pcap file, microsecond timestamps.
Bytes pcap_file(std::uint32_t link_type, const std::vector<Bytes>& packets) {
  Bytes out;
  le32(out, 0xA1B2C3D4);
  le16(out, 2);
  le16(out, 4);
  le32(out, 0);
  le32(out, 0);
  le32(out, 65535);
  le32(out, link_type);
  std::uint32_t usec = 250;
  for (const auto& packet : packets) {
    le32(out, 1700000000);
    le32(out, usec);
    usec += 1000;
    le32(out, static_cast<std::uint32_t>(packet.size()));
    le32(out, static_cast<std::uint32_t>(packet.size()));
    append(out, packet);
  }
  return out;
}

Bytes good_frame() {
  return ethercat_frame({{7, 0x2A, 0x0000, 0x0130, {0x02, 0x00}, 3}});
}

// Datagram 0 carries command byte 0x1F, which no EtherCAT command has.
Bytes corrupt_frame() {
  return ethercat_frame({{0x1F, 0x01, 0x1001, 0x0130, {0x00, 0x00}, 0}});
}

std::vector<Bytes> mixed_packets() {
  return {ethernet(0x88A4, good_frame()), ethernet(0x88A4, corrupt_frame()),
          ethernet(0x0800, ipv4_udp(5353, 5353, Bytes(20, 0xAB)))};
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    out.push_back(line);
  return out;
}

// ---------------------------------------------------------------------------------------------

TEST_F(DecodeTool, CountsFramesAndNamesTheBadOne) {
  const auto file = write("mixed.pcap", pcap_file(1, mixed_packets()));
  const auto result = run_tool(file.string());
  EXPECT_EQ(result.status, 1) << result.out << result.err;
  const auto output = lines(result.out);
  ASSERT_FALSE(output.empty());
  EXPECT_EQ(output.back(), "frames=3 ethercat=2 errors=1");
  EXPECT_NE(result.out.find("frame 2: error: datagram 0 at byte 2: unknown command 0x1F "
                            "(commands are 0x00..0x0E)"),
            std::string::npos)
      << result.out;
  // The good frame and its datagram.
  ASSERT_GE(output.size(), 3u);
  EXPECT_NE(output[0].find("     1  1700000000.000250000  ethernet"), std::string::npos)
      << output[0];
  EXPECT_NE(output[0].find("02:00:00:00:00:01"), std::string::npos) << output[0];
  EXPECT_NE(output[0].find("1 datagram"), std::string::npos) << output[0];
  EXPECT_EQ(output[1], "        BRD  idx=0x2a adp=0x0000 ado=0x0130 len=2    wkc=3     irq=0x0000");
  EXPECT_EQ(output.size(), 4u);  // frame, datagram, error, summary: nothing for the IPv4 packet
}

TEST_F(DecodeTool, JsonHasEveryKey) {
  const auto file = write("mixed.pcap", pcap_file(1, mixed_packets()));
  const auto result = run_tool(file.string() + " --json");
  EXPECT_EQ(result.status, 1) << result.err;
  const auto document = nlohmann::json::parse(result.out, nullptr, false);
  ASSERT_FALSE(document.is_discarded()) << result.out;

  ASSERT_TRUE(document["frames"].is_array());
  ASSERT_EQ(document["frames"].size(), 1u);
  const auto& frame = document["frames"][0];
  EXPECT_EQ(frame["number"], 1);
  EXPECT_TRUE(frame["number"].is_number_integer());
  EXPECT_EQ(frame["timestamp_ns"], 1700000000000250000LL);
  EXPECT_TRUE(frame["timestamp_ns"].is_number_integer());
  EXPECT_EQ(frame["encapsulation"], "ethernet");
  EXPECT_EQ(frame["source"], "02:00:00:00:00:01");
  ASSERT_EQ(frame["datagrams"].size(), 1u);
  const auto& datagram = frame["datagrams"][0];
  EXPECT_EQ(datagram["command"], "BRD");
  EXPECT_EQ(datagram["index"], 0x2A);
  EXPECT_EQ(datagram["adp"], 0);
  EXPECT_EQ(datagram["ado"], 0x130);
  EXPECT_TRUE(datagram["ado"].is_number_integer());
  EXPECT_EQ(datagram["length"], 2);
  EXPECT_EQ(datagram["wkc"], 3);
  EXPECT_EQ(datagram["circulating"], false);
  EXPECT_EQ(datagram["irq"], 0);
  EXPECT_FALSE(datagram.contains("mailbox"));
  EXPECT_FALSE(datagram.contains("logical"));

  ASSERT_EQ(document["errors"].size(), 1u);
  EXPECT_EQ(document["errors"][0]["frame"], 2);
  EXPECT_EQ(document["errors"][0]["reason"],
            "datagram 0 at byte 2: unknown command 0x1F (commands are 0x00..0x0E)");

  EXPECT_EQ(document["summary"]["frames"], 3);
  EXPECT_EQ(document["summary"]["ethercat"], 2);
  EXPECT_EQ(document["summary"]["errors"], 1);
}

TEST_F(DecodeTool, LogicalAddressInJson) {
  const auto frame = ethercat_frame({{12, 5, 0x0000, 0x0001, Bytes(4, 0), 2}});
  const auto file = write("lrw.pcap", pcap_file(1, {ethernet(0x88A4, frame)}));
  const auto result = run_tool(file.string() + " --json");
  EXPECT_EQ(result.status, 0) << result.err;
  const auto document = nlohmann::json::parse(result.out);
  const auto& datagram = document["frames"][0]["datagrams"][0];
  EXPECT_EQ(datagram["command"], "LRW");
  EXPECT_EQ(datagram["logical"], 0x00010000);
  EXPECT_FALSE(datagram.contains("adp"));
}

TEST_F(DecodeTool, UdpAndVlanEncapsulations) {
  const auto frame = good_frame();
  const std::vector<Bytes> packets{
      ethernet(0x0800, ipv4_udp(0x88A4, 0x88A4, frame)),
      ethernet(0x0800, ipv4_udp(0x88A4, 40000, frame)),  // the reply direction of a client
      ethernet(0x88A4, frame, /*vlan=*/true),
      ethernet(0x0800, ipv4_udp(40000, 40001, frame)),  // another port: not EtherCAT
  };
  const auto file = write("encapsulations.pcap", pcap_file(1, packets));
  const auto result = run_tool(file.string() + " --json");
  EXPECT_EQ(result.status, 0) << result.out << result.err;
  const auto document = nlohmann::json::parse(result.out);
  ASSERT_EQ(document["frames"].size(), 3u);
  EXPECT_EQ(document["frames"][0]["encapsulation"], "udp");
  EXPECT_EQ(document["frames"][1]["encapsulation"], "udp");
  EXPECT_EQ(document["frames"][2]["encapsulation"], "ethernet/vlan");
  EXPECT_EQ(document["frames"][2]["number"], 3);
  EXPECT_EQ(document["frames"][0]["datagrams"][0]["wkc"], 3);
  EXPECT_EQ(document["summary"]["frames"], 4);
  EXPECT_EQ(document["summary"]["ethercat"], 3);
  EXPECT_EQ(document["summary"]["errors"], 0);
}

// --udp-port: EtherCAT over UDP on a port other than 0x88A4 (ecat sim --udp and ecat's UDP
// links take any port).
TEST_F(DecodeTool, UdpOnAnotherPort) {
  const auto frame = good_frame();
  const std::vector<Bytes> packets{
      ethernet(0x0800, ipv4_udp(40000, 5000, frame)),
      ethernet(0x0800, ipv4_udp(5000, 40000, frame)),
      ethernet(0x0800, ipv4_udp(0x88A4, 0x88A4, frame)),  // now another port: not EtherCAT
  };
  const auto file = write("port5000.pcap", pcap_file(1, packets));
  auto result = run_tool(file.string() + " --udp-port 5000");
  EXPECT_EQ(result.status, 0) << result.out << result.err;
  EXPECT_EQ(lines(result.out).back(), "frames=3 ethercat=2 errors=0");
  result = run_tool(file.string());
  EXPECT_EQ(lines(result.out).back(), "frames=3 ethercat=1 errors=0");
  result = run_tool(file.string() + " --udp-port 0");
  EXPECT_EQ(result.status, 2) << result.err;
}

TEST_F(DecodeTool, LinuxCookedCapture) {
  // SLL: packet type, ARPHRD_ETHER, address length 6, address (8), protocol.
  Bytes sll;
  be16(sll, 0);
  be16(sll, 1);
  be16(sll, 6);
  append(sll, kSourceMac);
  append(sll, {0, 0});
  be16(sll, 0x88A4);
  append(sll, good_frame());
  const auto file = write("cooked.pcap", pcap_file(113, {sll}));
  const auto result = run_tool(file.string());
  EXPECT_EQ(result.status, 0) << result.out << result.err;
  EXPECT_EQ(lines(result.out).back(), "frames=1 ethercat=1 errors=0");
  EXPECT_NE(result.out.find("02:00:00:00:00:01"), std::string::npos) << result.out;
}

TEST_F(DecodeTool, MailboxSummariesFollowTheSyncManagerConfiguration) {
  // SM0 (mailbox out, 0x1000) and SM1 (mailbox in, 0x1080) of station 0x1001.
  const Bytes sm0{0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00};
  const Bytes sm1{0x80, 0x10, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00};
  // CoE SDO upload request 0x1018:01, counter 1, padded to the 128-byte mailbox.
  Bytes request{0x0A, 0x00, 0x00, 0x00, 0x00, 0x13, 0x00, 0x20, 0x40, 0x18, 0x10, 0x01};
  request.resize(128, 0);
  const std::vector<Bytes> packets{
      ethernet(0x88A4, ethercat_frame({{5, 1, 0x1001, 0x0800, sm0}, {5, 2, 0x1001, 0x0808, sm1}})),
      ethernet(0x88A4, ethercat_frame({{5, 3, 0x1001, 0x1000, request, 1}})),
      // Same bytes where station 0x1001 has no mailbox: process data, not a mailbox.
      ethernet(0x88A4, ethercat_frame({{5, 4, 0x1001, 0x1100, request, 1}})),
      // A station whose configuration the capture never saw: recognised by the data's shape.
      ethernet(0x88A4, ethercat_frame({{5, 5, 0x1002, 0x1800, request, 1}})),
      // A read of the mailbox-in area that returned nothing.
      ethernet(0x88A4, ethercat_frame({{4, 6, 0x1001, 0x1080, Bytes(128, 0), 0}})),
  };
  const auto file = write("mailbox.pcap", pcap_file(1, packets));
  const auto result = run_tool(file.string() + " --json");
  EXPECT_EQ(result.status, 0) << result.err;
  const auto document = nlohmann::json::parse(result.out);
  ASSERT_EQ(document["frames"].size(), 5u);
  auto mailbox_of = [&](std::size_t frame) {
    const auto& datagram = document["frames"][frame]["datagrams"][0];
    return datagram.contains("mailbox") ? datagram["mailbox"].get<std::string>() : "";
  };
  EXPECT_EQ(mailbox_of(0), "");
  EXPECT_EQ(mailbox_of(1).rfind("mbx CoE", 0), 0u) << mailbox_of(1);
  EXPECT_NE(mailbox_of(1).find("0x1018:01"), std::string::npos) << mailbox_of(1);
  EXPECT_EQ(mailbox_of(2), "");
  EXPECT_EQ(mailbox_of(3).rfind("mbx CoE", 0), 0u) << mailbox_of(3);
  EXPECT_EQ(mailbox_of(4), "");

  const auto text = run_tool(file.string());
  EXPECT_NE(text.out.find("len=128  wkc=1     irq=0x0000  mbx CoE"), std::string::npos) << text.out;
}

TEST_F(DecodeTool, MailboxSyncManagersConfiguredByPosition) {
  const Bytes sm0{0x00, 0x18, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00};
  const Bytes sm1{0x80, 0x18, 0x80, 0x00, 0x22, 0x00, 0x01, 0x00};
  Bytes request{0x0A, 0x00, 0x00, 0x00, 0x00, 0x23, 0x00, 0x20, 0x40, 0x00, 0x10, 0x00};
  request.resize(128, 0);
  auto from_master = [](const std::vector<Datagram>& datagrams) {
    return ethernet(0x88A4, ethercat_frame(datagrams), false, kMasterMac);
  };
  auto returned = [](const std::vector<Datagram>& datagrams) {
    return ethernet(0x88A4, ethercat_frame(datagrams), false, kReturnedMac);
  };
  const std::vector<Bytes> packets{
      // Position 1 (ADP 0xFFFF) becomes station 0x1002; the copy that comes back after passing
      // two slaves (ADP 0x0001) must not be mistaken for position 0xFFFF.
      from_master({{2, 1, 0xFFFF, 0x0010, {0x02, 0x10}}}),
      returned({{2, 1, 0x0001, 0x0010, {0x02, 0x10}, 1}}),
      // Its mailbox SyncManagers, split over two partial writes for SM1.
      from_master({{2, 2, 0xFFFF, 0x0800, sm0},
                   {2, 3, 0xFFFF, 0x0808, Bytes(sm1.begin(), sm1.begin() + 4)}}),
      from_master({{2, 4, 0xFFFF, 0x080C, Bytes(sm1.begin() + 4, sm1.end())}}),
      returned({{2, 5, 0x0001, 0x0800, Bytes(16, 0)}}),  // ignored: ADP already incremented
      from_master({{5, 6, 0x1002, 0x1800, request}}),    // mailbox out of station 0x1002
      from_master({{5, 7, 0x1002, 0x1000, request}}),    // not a mailbox of that station
      from_master({{4, 8, 0x1002, 0x1880, request}}),    // mailbox in, read
  };
  const auto file = write("position.pcap", pcap_file(1, packets));
  const auto result = run_tool(file.string() + " --json");
  EXPECT_EQ(result.status, 0) << result.err;
  const auto document = nlohmann::json::parse(result.out);
  ASSERT_EQ(document["frames"].size(), packets.size());
  auto has_mailbox = [&](std::size_t frame) {
    return document["frames"][frame]["datagrams"][0].contains("mailbox");
  };
  EXPECT_TRUE(has_mailbox(5));
  EXPECT_FALSE(has_mailbox(6));
  EXPECT_TRUE(has_mailbox(7));
  EXPECT_EQ(document["frames"][0]["source"], "00:1b:21:00:00:01");
}

TEST_F(DecodeTool, MissingFileExitsWithTwo) {
  const auto missing = (dir_ / "does-not-exist.pcapng").string();
  const auto result = run_tool(missing);
  EXPECT_EQ(result.status, 2);
  EXPECT_NE(result.err.find(missing), std::string::npos) << result.err;
  EXPECT_NE(result.err.find(": no such capture"), std::string::npos) << result.err;
  EXPECT_EQ(result.out, "");
}

TEST_F(DecodeTool, NotACaptureExitsWithTwo) {
  const auto file = write("notes.txt", Bytes{'h', 'e', 'l', 'l', 'o', '\n'});
  const auto result = run_tool(file.string());
  EXPECT_EQ(result.status, 2);
  EXPECT_NE(result.err.find(file.string()), std::string::npos) << result.err;
}

TEST_F(DecodeTool, TruncatedCaptureExitsWithTwo) {
  auto bytes = pcap_file(1, mixed_packets());
  bytes.resize(bytes.size() - 10);  // the last record ends early
  const auto file = write("cut.pcap", bytes);
  const auto result = run_tool(file.string());
  EXPECT_EQ(result.status, 2);
  EXPECT_NE(result.err.find("packet 3"), std::string::npos) << result.err;
}

TEST_F(DecodeTool, SharedCapturesDecodeWithoutErrors) {
  ECAT_SHARED_DATA_OR_SKIP(captures, "captures");
  struct Expected {
    std::size_t frames;
    std::size_t ethercat;
    std::size_t mailboxes;  // datagrams with a mailbox summary
  };
  const std::map<std::string, Expected> expected{
      {"replay-dc.pcapng", {3604, 3604, 0}},
      {"replay-ek1100-el2828-el2889.pcapng", {3578, 3578, 0}},
      {"replay-ek1914-el3004-mailbox.pcapng", {994, 994, 9}},
      {"replay-ek1914-segmented-upload.pcapng", {964, 964, 3}},
      {"rs-example-sii-el2004.pcapng", {572, 254, 0}},
      {"soem-sdinfo-ek1100-el1004.pcapng", {594, 580, 0}},
      {"soem-sdinfo-no-slaves.pcapng", {23, 19, 0}},
      {"twincat-run-ek1100-el1004.pcapng", {554, 553, 0}},
  };
  std::size_t checked = 0;
  for (const auto& entry : fs::directory_iterator(captures)) {
    const auto name = entry.path().filename().string();
    const auto result = run_tool("'" + entry.path().string() + "'");
    EXPECT_EQ(result.status, 0) << name << "\n" << result.err;
    const auto output = lines(result.out);
    ASSERT_FALSE(output.empty()) << name;
    std::size_t mailboxes = 0;
    for (const auto& line : output)
      mailboxes += line.find("  mbx ") != std::string::npos;
    auto known = expected.find(name);
    if (known == expected.end()) {
      EXPECT_NE(output.back().find(" errors=0"), std::string::npos)
          << name << ": " << output.back();
      continue;
    }
    ++checked;
    EXPECT_EQ(output.back(), fmt::format("frames={} ethercat={} errors=0", known->second.frames,
                                         known->second.ethercat))
        << name;
    EXPECT_EQ(mailboxes, known->second.mailboxes) << name;
  }
  EXPECT_EQ(checked, expected.size());
}

TEST_F(DecodeTool, SharedCaptureAsJson) {
  ECAT_SHARED_DATA_OR_SKIP(capture, "captures/replay-ek1914-el3004-mailbox.pcapng");
  const auto result = run_tool("--json '" + capture.string() + "'");
  ASSERT_EQ(result.status, 0) << result.err;
  const auto document = nlohmann::json::parse(result.out, nullptr, false);
  ASSERT_FALSE(document.is_discarded());
  EXPECT_EQ(document["summary"]["frames"], 994);
  EXPECT_EQ(document["summary"]["errors"], 0);
  EXPECT_EQ(document["frames"].size(), 994u);
  EXPECT_TRUE(document["errors"].empty());
  std::size_t mailboxes = 0;
  for (const auto& frame : document["frames"]) {
    for (const auto& datagram : frame["datagrams"])
      mailboxes += datagram.contains("mailbox");
  }
  EXPECT_EQ(mailboxes, 9u);
}

}  // namespace
