// The instrument commands end to end: `ecat serve` with a control endpoint, the commands
// attached to it (text and JSON, errors too) while the domain keeps cycling, SIGTERM ending the
// service cleanly, and the same commands standalone on their own session.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <ecat/sim/foe_server.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

using nlohmann::json;

std::string default_ring() {
  return std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
}

// Firmware updates: the default ring whose drive's firmware slot wants password 0x5eed, and the
// images `foe_write --firmware` sends (the simulator's format: ECFW, length, CRC-32, version).
constexpr const char* kFirmwarePassword = "0x5eed";

std::string firmware_ring(const std::filesystem::path& dir) {
  std::string ring = read_text_file(default_ring());
  const std::string servo = "      profile: servo\n";
  const auto at = ring.find(servo);
  if (at == std::string::npos) return {};
  ring.insert(at + servo.size(), "      options: {firmware_password: 0x5eed}\n");
  const auto path = (dir / "firmware.yaml").string();
  std::ofstream(path) << ring;
  return path;
}

// A valid image of `version`; `corrupt`: one payload byte changed after the CRC was taken.
void write_firmware(const std::filesystem::path& path, const std::string& version,
                    bool corrupt = false) {
  std::vector<std::uint8_t> payload(20000);
  for (std::size_t i = 0; i < payload.size(); ++i)
    payload[i] = static_cast<std::uint8_t>((i * 13 + (i >> 8)) & 0xFF);
  auto image = sim::make_firmware_image(version, payload);
  ASSERT_TRUE(image) << image.error().describe();
  if (corrupt) (*image)[sim::kFirmwareHeaderSize + 1000] ^= 0x01;
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(image->data()),
             static_cast<std::streamsize>(image->size()));
}

TEST(InstrumentTool, AttachedToARunningServiceTextJsonAndErrors) {
  ToolRunner tool("serve");
  const std::string socket = (tool.dir() / "line.sock").string();
  // One script: the service in the background, the commands against it, then SIGTERM and the
  // service's exit code.
  const std::string script = fmt::format(
      R"("$ECAT" serve '{ring}' --control '{sock}' --timeout 20 2>serve.err &
pid=$!
for i in $(seq 1 400); do "$ECAT" master --attach '{sock}' --json 2>/dev/null | grep -q '"state": "operational"' && break; sleep 0.05; done
cd '{dir}'
"$ECAT" slaves --attach '{sock}' > slaves.txt
"$ECAT" slaves --attach '{sock}' --json -v > slaves.json
"$ECAT" master --attach '{sock}' --json > master.json
"$ECAT" domains --attach '{sock}' -v > domains.txt
"$ECAT" upload --attach '{sock}' --name drive 0x6041 0 --type uint16 > upload.txt
"$ECAT" reg_read --attach '{sock}' -p 2 0x0130 --type uint16 > reg.txt
"$ECAT" download --attach '{sock}' --name drive 0x6060 0 8 --type int8 --json > refused.json; echo $? > refused.code
"$ECAT" upload --attach '{sock}' --name nobody 0x6041 0 --json > unknown.json; echo $? > unknown.code
"$ECAT" upload --attach '{sock}' --name drive 0x6041 0 --type uint128 > badtype.txt 2>&1; echo $? > badtype.code
printf 'not an image' > fw.efw
"$ECAT" foe_write --attach '{sock}' --name drive --firmware firmware.efw fw.efw --json > firmware.json; echo $? > firmware.code
"$ECAT" master --attach '{sock}' --json > after.json
kill -TERM $pid; wait $pid; echo $? > serve.code)",
      fmt::arg("ring", default_ring()), fmt::arg("sock", socket),
      fmt::arg("dir", tool.dir().string()));
  const auto r = tool.run_script("cd '" + tool.dir().string() + "' && " + script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  EXPECT_EQ(file("serve.code"), "0\n") << file("serve.err");
  EXPECT_NE(file("serve.err").find("stopped; every slave back in INIT"), std::string::npos)
      << file("serve.err");

  EXPECT_NE(file("slaves.txt").find("EL2809"), std::string::npos) << file("slaves.txt");
  const auto slaves = json::parse(file("slaves.json"));
  ASSERT_EQ(slaves["slaves"].size(), 5u);
  EXPECT_EQ(slaves["slaves"][4]["name"], "drive");
  EXPECT_TRUE(slaves["slaves"][4].contains("esc"));
  const auto master = json::parse(file("master.json"));
  EXPECT_EQ(master["state"], "operational");
  EXPECT_NE(file("domains.txt").find("domain main: cycling"), std::string::npos);
  EXPECT_NE(file("domains.txt").find("  0000  "), std::string::npos);
  EXPECT_FALSE(file("upload.txt").empty());
  EXPECT_EQ(file("reg.txt"), "8\n");  // AL status of the EL2809: OP

  // The service was started without --writes: the download is refused, as JSON.
  EXPECT_EQ(file("refused.code"), "1\n");
  const auto refused = json::parse(file("refused.json"));
  EXPECT_EQ(refused["ok"], false);
  EXPECT_EQ(refused["code"], "permission_denied");
  EXPECT_EQ(file("unknown.code"), "1\n");
  EXPECT_EQ(json::parse(file("unknown.json"))["code"], "not_found");
  EXPECT_NE(file("badtype.txt").find("is not a type"), std::string::npos) << file("badtype.txt");
  // A firmware update is a write: refused too, and the drive was left alone (still in OP).
  EXPECT_EQ(file("firmware.code"), "1\n");
  EXPECT_EQ(json::parse(file("firmware.json"))["code"], "permission_denied")
      << file("firmware.json");

  // Zero cycles missed because of the commands: none at all in this test's window would be too
  // strict on a loaded machine, but the commands must not have cost the domain its health.
  const auto after = json::parse(file("after.json"));
  EXPECT_EQ(after["state"], "operational");
  EXPECT_EQ(after["domains"][0]["healthy"], true);
  (void)r;
}

TEST(InstrumentTool, StandaloneCommandsRunTheirOwnSession) {
  ToolRunner tool("standalone");
  auto r = tool.run("upload --ring '" + default_ring() + "' --name drive 0x1018 1 --type uint32");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(r.out, "2766\n");  // 0x0ace: the simulated drive's vendor id
  r = tool.run("slaves --ring '" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(json::parse(r.out)["slaves"].size(), 5u);
  r = tool.run("pdos --ring '" + default_ring() + "' --name drive");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("0x6040:00 16 bits \"Controlword\""), std::string::npos) << r.out;
  // As read from the device: the drive's 0x1C12/0x1C13 and mapping objects, by SDO.
  r = tool.run("pdos --ring '" + default_ring() + "' --name drive --read --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto as_read = json::parse(r.out)["as_read"];
  ASSERT_TRUE(as_read.contains("sync_managers")) << as_read.dump();
  EXPECT_EQ(as_read["sync_managers"][0]["pdos"][0]["index"], "0x1600");
  EXPECT_EQ(as_read["sync_managers"][0]["pdos"][0]["entries"][0]["index"], "0x6040");
  r = tool.run("alias --ring '" + default_ring() + "' --name inputs 0x0042 --json");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(json::parse(r.out)["alias"], 0x42);
  // A C header of the image: compiles, and its struct is as large as the image.
  const auto header = (tool.dir() / "image.h").string();
  r = tool.run("cstruct --ring '" + default_ring() + "' -o '" + header + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(read_text_file(header).find("#define ECAT_MAIN_DRIVE_STATUSWORD_BYTE"),
            std::string::npos);
  const auto compiled = tool.run_script(
      "command -v cc >/dev/null || { echo skipped; exit 0; }; cd '" + tool.dir().string() +
      "' && printf '#include \"image.h\"\\nint main(void) { return 0; }\\n' > t.c && "
      "cc -std=c11 -Wall -Werror -fsyntax-only t.c");
  EXPECT_EQ(compiled.status, 0) << compiled.out << compiled.err;
  // -a ALIAS: the slaves of the simulated ring have alias 0; the first one is the coupler.
  r = tool.run("reg_read --ring '" + default_ring() + "' -a 0x0000 0x0000 1");
  ASSERT_EQ(r.status, 0) << r.err;
  // The device description, the dictionary with values, the SII decoded.
  r = tool.run("xml --ring '" + default_ring() + "' --name inputs");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("<Type ProductCode=\"#x07113052\" RevisionNo=\"#x00120000\">EL1809</Type>"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("<TxPdo Sm=\"0\" Fixed=\"1\">"), std::string::npos) << r.out;
  r = tool.run("sdos --ring '" + default_ring() + "' --name drive --values --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto objects = json::parse(r.out)["objects"];
  ASSERT_FALSE(objects.empty());
  EXPECT_TRUE(objects[0].contains("values")) << objects[0].dump();
  r = tool.run("sii_read --ring '" + default_ring() + "' --name inputs --decode");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("EL1809"), std::string::npos) << r.out;
  // rescan: the wire against the session (here the same five slaves, held in PREOP).
  r = tool.run("rescan --ring '" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto rescan = json::parse(r.out);
  EXPECT_EQ(rescan["on_wire"], 5);
  EXPECT_EQ(rescan["unknown"], 0);
  EXPECT_EQ(rescan["slaves"][4]["name"], "drive");
  EXPECT_EQ(rescan["slaves"][4]["station"], 0x1004);
  EXPECT_EQ(rescan["slaves"][4]["al_state"], "PREOP");
  r = tool.run("domains --ring '" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.err;
  // Laid out, not cycling: the slaves are held in PREOP, nothing moves.
  const auto domains = json::parse(r.out)["domains"];
  EXPECT_EQ(domains[0]["id"], "main");
  // 40 bytes of process data and the SM1 status byte of each mailbox slave with process data
  // (rtd, drive), mapped so that waiting for a mailbox reply costs no frame.
  EXPECT_EQ(domains[0]["image_size"], 42);
  EXPECT_EQ(domains[0]["state"], "open");
}

TEST(InstrumentTool, WritesThroughAServiceThatAllowsThem) {
  ToolRunner tool("writes");
  const std::string socket = (tool.dir() / "w.sock").string();
  const std::string script = fmt::format(
      R"("$ECAT" serve '{ring}' --control '{sock}' --writes --timeout 20 2>serve.err &
pid=$!
for i in $(seq 1 400); do "$ECAT" master --attach '{sock}' --json 2>/dev/null | grep -q '"state": "operational"' && break; sleep 0.05; done
cd '{dir}'
printf 'firmware notes' > notes.txt
"$ECAT" foe_write --attach '{sock}' --name drive notes.txt notes.txt > foe_write.txt
"$ECAT" foe_read --attach '{sock}' --name drive notes.txt -o back.txt > foe_read.txt
"$ECAT" download --attach '{sock}' --name drive 0x6065 0 5000 --type uint32 > download.txt; echo $? > download.code
"$ECAT" upload --attach '{sock}' --name drive 0x6065 0 --type uint32 > upload.txt
"$ECAT" alias --attach '{sock}' --name inputs 0x1234 --json > alias.json; echo $? > alias.code
"$ECAT" download --attach '{sock}' --name drive 0x1018 1 7 --type uint32 --json > readonly.json; echo $? > readonly.code
"$ECAT" diag --attach '{sock}' > diag.txt
"$ECAT" crc --attach '{sock}' --json > crc.json
kill -TERM $pid; wait $pid; echo $? > serve.code)",
      fmt::arg("ring", default_ring()), fmt::arg("sock", socket),
      fmt::arg("dir", tool.dir().string()));
  (void)tool.run_script("cd '" + tool.dir().string() + "' && " + script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  EXPECT_EQ(file("serve.code"), "0\n") << file("serve.err");
  EXPECT_EQ(file("back.txt"), "firmware notes") << file("foe_write.txt") << file("foe_read.txt");
  EXPECT_EQ(file("download.code"), "0\n") << file("download.txt");
  EXPECT_EQ(file("upload.txt"), "5000\n");
  // EEPROM writes need the slave in INIT or PREOP: refused while the service runs it in OP.
  EXPECT_EQ(file("alias.code"), "1\n");
  EXPECT_EQ(json::parse(file("alias.json"))["code"], "wrong_state") << file("alias.json");
  EXPECT_NE(file("diag.txt").find("master: operational"), std::string::npos) << file("diag.txt");
  // A read-only object: the drive's own abort, with its code.
  EXPECT_EQ(file("readonly.code"), "1\n");
  const auto readonly = json::parse(file("readonly.json"));
  EXPECT_EQ(readonly["code"], "sdo_abort") << readonly.dump();
  EXPECT_NE(readonly["error"].get<std::string>().find("0x06010002"), std::string::npos)
      << readonly.dump();
  EXPECT_EQ(json::parse(file("crc.json"))["slaves"].size(), 5u);
}

// `ecat config`: the user's first configuration in one command. Written from the ring as found,
// it brings the same ring to OP.
TEST(InstrumentTool, ConfigWritesARingFileThatBringsTheRingToOp) {
  ToolRunner tool("config");
  const auto file = (tool.dir() / "found.yaml").string();
  auto r = tool.run("config --backend 'sim:" + default_ring() + "' -o '" + file + "'");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(r.out, "5 slaves written to " + file + "\n");
  const auto yaml = read_text_file(file);
  EXPECT_NE(yaml.find("{name: el1809, position: 1, vendor_id: 0x00000002, product_code: "
                      "0x07113052, process_data: main}"),
            std::string::npos)
      << yaml;
  r = tool.run("run '" + file + "' --duration 0.2");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("-> operational"), std::string::npos) << r.out;

  r = tool.run("graph --ring '" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto graph = json::parse(r.out);
  ASSERT_EQ(graph["edges"].size(), 5u);
  EXPECT_EQ(graph["edges"][0]["from"], "master");
  EXPECT_EQ(graph["edges"][4]["from"], "rtd");
  EXPECT_EQ(graph["edges"][4]["to"], "drive");
}

// Standalone over EtherCAT-over-UDP: the simulated ring served by `ecat sim` on loopback.
TEST(InstrumentTool, StandaloneOverUdp) {
  ToolRunner tool("udp");
  const std::string script = fmt::format(
      R"(cd '{dir}'
"$ECAT" sim --ring '{ring}' --udp 127.0.0.1:0 --control '{dir}/sim.sock' > sim.out 2>&1 &
pid=$!
for i in $(seq 1 200); do grep -q 'udp-server:' sim.out 2>/dev/null && break; sleep 0.05; done
port=$(sed -n 's/.*udp-server:127.0.0.1:\([0-9]*\).*/\1/p' sim.out | head -1)
"$ECAT" slaves --backend udp:127.0.0.1:$port --json > slaves.json; echo $? > slaves.code
"$ECAT" reg_read --backend udp:127.0.0.1:$port -p 1 0x0000 1 > type.txt
kill -TERM $pid; wait $pid)",
      fmt::arg("ring", default_ring()), fmt::arg("dir", tool.dir().string()));
  (void)tool.run_script(script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  ASSERT_EQ(file("slaves.code"), "0\n") << file("sim.out");
  const auto slaves = json::parse(file("slaves.json"))["slaves"];
  ASSERT_EQ(slaves.size(), 5u);
  EXPECT_EQ(slaves[0]["name"], "coupler");  // a dynamic session names the EK1100 so
  EXPECT_EQ(slaves[1]["name"], "slave_1");
  EXPECT_FALSE(file("type.txt").empty());
}

// `ecat eoe`: Set IP Parameter on a simulated EoE device, its tunnel counters, a bad address.
TEST(InstrumentTool, EoeSetsIpParametersAndShowsCounters) {
  ToolRunner tool("eoe");
  const auto ring = (tool.dir() / "eoe.yaml").string();
  {
    std::ofstream out(ring);
    out << "version: 1\nsimulator:\n  slaves:\n    - {name: dev, profile: eoe_device}\n"
           "slaves:\n  - {name: dev}\n";
  }
  auto r = tool.run("eoe --ring '" + ring +
                    "' --name dev --ip 192.168.7.2 --subnet-mask "
                    "255.255.255.0");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(r.out, "dev: IP parameters set\n");
  r = tool.run("eoe --ring '" + ring + "' --name dev --json");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(json::parse(r.out)["frames_dropped"], 0);
  r = tool.run("eoe --ring '" + ring + "' --name dev --ip 300.1.1.1 --json");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(json::parse(r.out)["code"], "invalid_argument");
}

// The commands the other tests do not reach: data, states, events, reg_write, version attached
// to a service allowing writes; soe_read/soe_write on a SERCOS drive and sii_write standalone.
TEST(InstrumentTool, TheRemainingCommandsTextAndJson) {
  ToolRunner tool("remaining");
  const std::string socket = (tool.dir() / "r.sock").string();
  const std::string script = fmt::format(
      R"("$ECAT" serve '{ring}' --control '{sock}' --writes --timeout 20 2>serve.err &
pid=$!
for i in $(seq 1 400); do "$ECAT" master --attach '{sock}' --json 2>/dev/null | grep -q '"state": "operational"' && break; sleep 0.05; done
cd '{dir}'
"$ECAT" data --attach '{sock}' > image.bin
"$ECAT" data --attach '{sock}' --json > image.json
"$ECAT" events --attach '{sock}' --json --duration 3 > events.jsonl &
epid=$!
sleep 0.5
"$ECAT" states --attach '{sock}' safeop > states.txt
"$ECAT" states --attach '{sock}' op --json > states.json
"$ECAT" reg_write --attach '{sock}' -p 1 0x0f80 0102 --json > reg_write.json
"$ECAT" reg_read --attach '{sock}' -p 1 0x0f80 2 > reg_read.txt
"$ECAT" version --attach '{sock}' --json > version.json
wait $epid
kill -TERM $pid; wait $pid; echo $? > serve.code)",
      fmt::arg("ring", default_ring()), fmt::arg("sock", socket),
      fmt::arg("dir", tool.dir().string()));
  (void)tool.run_script("cd '" + tool.dir().string() + "' && " + script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  EXPECT_EQ(file("serve.code"), "0\n") << file("serve.err");
  // The default ring's image, raw: process data and two SM1 status bytes (rtd, drive).
  EXPECT_EQ(file("image.bin").size(), 42u);
  EXPECT_EQ(json::parse(file("image.json"))["size"], 42);
  EXPECT_EQ(file("states.txt"), "now deactivated\n");
  EXPECT_EQ(json::parse(file("states.json"))["state"], "operational");
  EXPECT_EQ(json::parse(file("reg_write.json"))["wkc"], 1);
  EXPECT_EQ(file("reg_read.txt"), "01 02\n");  // ESC RAM beyond the registers: written, read
  EXPECT_FALSE(json::parse(file("version.json"))["master"].get<std::string>().empty());
  // The event stream saw the session leave OP and come back, one JSON object per line.
  const auto events = file("events.jsonl");
  EXPECT_NE(events.find(R"("to":"deactivated")"), std::string::npos) << events;
  EXPECT_NE(events.find(R"("to":"operational")"), std::string::npos) << events;

  // SoE on a SERCOS drive (no CoE), standalone: read, write where PREOP allows it, a refusal.
  const auto soe_ring = (tool.dir() / "soe.yaml").string();
  {
    std::ofstream out(soe_ring);
    out << "version: 1\nsimulator:\n  slaves:\n    - {name: axis, profile: soe_drive}\n"
           "slaves:\n  - {name: axis}\n";
  }
  auto r = tool.run("soe_read --ring '" + soe_ring + "' --name axis S-0-0001 --type uint16");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_FALSE(r.out.empty());
  r = tool.run("soe_write --ring '" + soe_ring + "' --name axis S-0-0001 1000 --type uint16");
  EXPECT_EQ(r.status, 0) << r.err;
  r = tool.run("soe_read --ring '" + soe_ring + "' --name axis S-0-0017 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(json::parse(r.out)["size"], 126);  // the IDN list: two read fragments
  r = tool.run("soe_write --ring '" + soe_ring + "' --name axis S-0-0051 0 --type int32 --json");
  EXPECT_EQ(r.status, 1);  // position feedback is read only
  EXPECT_EQ(json::parse(r.out)["ok"], false);
  r = tool.run("soe_read --ring '" + soe_ring + "' --name axis X-1 --json");
  EXPECT_EQ(r.status, 2);

  // sii_write: the image as read, written back (verified word by word).
  const auto image = (tool.dir() / "inputs.bin").string();
  r = tool.run("sii_read --ring '" + default_ring() + "' --name inputs -o '" + image + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  r = tool.run("sii_write --ring '" + default_ring() + "' --name inputs '" + image + "'");
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("written to the EEPROM and verified"), std::string::npos) << r.out;
}

// `foe_write --firmware` attached to a service allowing writes: the drive is taken through INIT
// and BOOTSTRAP, the image written, and the drive restarted with it and brought back to OP by the
// session. The device's refusals come back as its errors and leave it running its old image.
TEST(InstrumentTool, FirmwareUpdateAttached) {
  ToolRunner tool("firmware");
  const std::string ring = firmware_ring(tool.dir());
  ASSERT_FALSE(ring.empty());
  write_firmware(tool.dir() / "fw2.efw", "2.0.0");
  write_firmware(tool.dir() / "bad.efw", "6.6.6", true);
  write_firmware(tool.dir() / "fw3.efw", "3.0.0");
  const std::string socket = (tool.dir() / "f.sock").string();
  const std::string script = fmt::format(
      R"("$ECAT" serve '{ring}' --control '{sock}' --writes --timeout 20 2>serve.err &
pid=$!
for i in $(seq 1 400); do "$ECAT" master --attach '{sock}' --json 2>/dev/null | grep -q '"state": "operational"' && break; sleep 0.05; done
cd '{dir}'
"$ECAT" upload --attach '{sock}' --name drive 0x100A 0 --type string > version.before
"$ECAT" foe_write --attach '{sock}' --name drive --firmware firmware.efw fw2.efw --password {pw} > update.txt 2>&1; echo $? > update.code
"$ECAT" upload --attach '{sock}' --name drive 0x100A 0 --type string > version.after
"$ECAT" slaves --attach '{sock}' --json > slaves.json
"$ECAT" master --attach '{sock}' --json > master.json
"$ECAT" foe_write --attach '{sock}' --name drive --firmware firmware.efw bad.efw --password {pw} --json > corrupt.json; echo $? > corrupt.code
"$ECAT" foe_write --attach '{sock}' --name drive --firmware firmware.efw fw3.efw --password 0x1 --json > password.json; echo $? > password.code
"$ECAT" foe_write --attach '{sock}' --name rtd --firmware firmware.efw fw3.efw --json > nofoe.json; echo $? > nofoe.code
"$ECAT" upload --attach '{sock}' --name drive 0x100A 0 --type string > version.end
"$ECAT" slaves --attach '{sock}' --json > slaves.end.json
"$ECAT" master --attach '{sock}' --json > master.end.json
kill -TERM $pid; wait $pid; echo $? > serve.code)",
      fmt::arg("ring", ring), fmt::arg("sock", socket), fmt::arg("dir", tool.dir().string()),
      fmt::arg("pw", kFirmwarePassword));
  (void)tool.run_script("cd '" + tool.dir().string() + "' && " + script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  EXPECT_EQ(file("serve.code"), "0\n") << file("serve.err");
  ASSERT_EQ(file("update.code"), "0\n") << file("update.txt") << file("serve.err");
  EXPECT_EQ(file("update.txt"),
            "firmware 'firmware.efw' (20044 bytes) written to drive in BOOTSTRAP; restarted, back "
            "in op\n");
  EXPECT_NE(file("version.before"), "2.0.0\n");
  EXPECT_EQ(file("version.after"), "2.0.0\n");  // object 0x100A: the image the device runs
  const auto state_of = [](const json& slaves, const std::string& name) {
    for (const auto& s : slaves["slaves"])
      if (s["name"] == name) return s["state"].get<std::string>();
    return std::string("absent");
  };
  EXPECT_EQ(state_of(json::parse(file("slaves.json")), "drive"), "op");
  EXPECT_EQ(json::parse(file("master.json"))["state"], "operational");

  // A corrupt image: the device's own refusal (checksum error), exit 1.
  EXPECT_EQ(file("corrupt.code"), "1\n");
  const auto corrupt = json::parse(file("corrupt.json"));
  EXPECT_NE(corrupt["error"].get<std::string>().find("error 0x800C checksum error"),
            std::string::npos)
      << corrupt.dump();
  // A wrong password: the device's "no rights".
  EXPECT_EQ(file("password.code"), "1\n");
  const auto password = json::parse(file("password.json"));
  EXPECT_EQ(password["code"], "permission_denied") << password.dump();
  EXPECT_NE(password["error"].get<std::string>().find("0x800A"), std::string::npos)
      << password.dump();
  // A slave without FoE.
  EXPECT_EQ(file("nofoe.code"), "1\n");
  const auto nofoe = json::parse(file("nofoe.json"));
  EXPECT_EQ(nofoe["code"], "unsupported") << nofoe.dump();
  EXPECT_NE(nofoe["error"].get<std::string>().find("needs FoE"), std::string::npos) << nofoe.dump();
  // After the refusals: still the image of the good update, the drive and the session back.
  EXPECT_EQ(file("version.end"), "2.0.0\n");
  EXPECT_EQ(state_of(json::parse(file("slaves.end.json")), "drive"), "op");
  EXPECT_EQ(json::parse(file("master.end.json"))["state"], "operational");
}

// `foe_write --firmware` standalone, against `ecat sim` over UDP (so that the device outlives
// each command's session): updated, running the new image (read by a later command), back in
// PREOP where the standalone session holds its slaves; then the same refusals.
TEST(InstrumentTool, FirmwareUpdateStandalone) {
  ToolRunner tool("firmware_standalone");
  const std::string ring = firmware_ring(tool.dir());
  ASSERT_FALSE(ring.empty());
  write_firmware(tool.dir() / "fw2.efw", "2.0.0");
  write_firmware(tool.dir() / "bad.efw", "6.6.6", true);
  const std::string script = fmt::format(
      R"(cd '{dir}'
"$ECAT" sim --ring '{ring}' --udp 127.0.0.1:0 > sim.out 2>&1 &
pid=$!
for i in $(seq 1 200); do grep -q 'udp-server:' sim.out 2>/dev/null && break; sleep 0.05; done
port=$(sed -n 's/.*udp-server:127.0.0.1:\([0-9]*\).*/\1/p' sim.out | head -1)
b="--backend udp:127.0.0.1:$port -p 4"
"$ECAT" foe_write $b --firmware firmware.efw fw2.efw --password {pw} --json > update.json; echo $? > update.code
"$ECAT" upload $b 0x100A 0 --type string > version.after
"$ECAT" foe_write $b --firmware firmware.efw bad.efw --password {pw} > corrupt.txt 2>&1; echo $? > corrupt.code
"$ECAT" foe_write $b --firmware firmware.efw fw2.efw --password 0x1 --json > password.json; echo $? > password.code
"$ECAT" foe_write --backend udp:127.0.0.1:$port -p 3 --firmware firmware.efw fw2.efw --json > nofoe.json; echo $? > nofoe.code
"$ECAT" upload $b 0x100A 0 --type string > version.end
kill -TERM $pid; wait $pid)",
      fmt::arg("ring", ring), fmt::arg("dir", tool.dir().string()),
      fmt::arg("pw", kFirmwarePassword));
  (void)tool.run_script(script);
  const auto file = [&](const char* name) { return read_text_file(tool.dir() / name); };
  ASSERT_EQ(file("update.code"), "0\n") << file("update.json") << file("sim.out");
  const auto update = json::parse(file("update.json"));
  EXPECT_EQ(update["size"], 20044);
  EXPECT_EQ(update["state"], "preop");  // where a standalone session holds its slaves
  EXPECT_EQ(file("version.after"), "2.0.0\n");
  EXPECT_EQ(file("corrupt.code"), "1\n");
  EXPECT_NE(file("corrupt.txt").find("error 0x800C checksum error"), std::string::npos)
      << file("corrupt.txt");
  EXPECT_EQ(file("password.code"), "1\n");
  EXPECT_EQ(json::parse(file("password.json"))["code"], "permission_denied")
      << file("password.json");
  EXPECT_EQ(file("nofoe.code"), "1\n");
  EXPECT_EQ(json::parse(file("nofoe.json"))["code"], "unsupported") << file("nofoe.json");
  EXPECT_EQ(file("version.end"), "2.0.0\n");
}

TEST(InstrumentTool, ClearErrorsWithoutAMaster) {
  ToolRunner tool("errors");
  auto r = tool.run("slaves --attach '" + (tool.dir() / "absent.sock").string() + "' --json");
  EXPECT_EQ(r.status, 1);
  const auto error = json::parse(r.out);
  EXPECT_EQ(error["code"], "not_found");
  EXPECT_NE(error["error"].get<std::string>().find("no master listens"), std::string::npos);
  r = tool.run("upload 0x6041 0 --name drive");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("give --attach"), std::string::npos) << r.err;
  r = tool.run("events");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("events follows a running master"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace ecat::test
