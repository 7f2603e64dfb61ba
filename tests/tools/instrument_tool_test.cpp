// The instrument commands end to end: `ecat serve` with a control endpoint, the commands
// attached to it (text and JSON, errors too) while the domain keeps cycling, SIGTERM ending the
// service cleanly, and the same commands standalone on their own session.
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

using nlohmann::json;

std::string default_ring() {
  return std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
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
  r = tool.run("alias --ring '" + default_ring() + "' --name inputs 0x0042 --json");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(json::parse(r.out)["alias"], 0x42);
  r = tool.run("domains --ring '" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.err;
  // Laid out, not cycling: the slaves are held in PREOP, nothing moves.
  const auto domains = json::parse(r.out)["domains"];
  EXPECT_EQ(domains[0]["id"], "main");
  EXPECT_EQ(domains[0]["image_size"], 40);
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
  EXPECT_EQ(json::parse(file("crc.json"))["slaves"].size(), 5u);
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
