// Hostile input through the command line (issue 11), class by class: every bad input ends in a
// clear error that names what was wrong and a documented exit code, never an abort, a hang,
// unbounded memory or silent success; a failure after the ring is up takes every slave back to
// INIT. Runs under ASan/UBSan with the rest of the tests.
//
// Classes and where they are tested:
//  - outside files that are not regular files, unreadable or too large (ring, EEPROM, ESI,
//    capture), and endless inputs: here;
//  - non-finite and out-of-range numbers on the command line and in ring files: here;
//  - deeply nested YAML: here;
//  - failures at each phase of a session against a simulated ring that outlives the tool: here;
//  - `ecat sim verify` comparing nothing or meeting malformed frames: sim_verify_tool_test.cpp;
//  - listeners on loopback and control-socket discovery of the user's own sockets: here (and the
//    UDP link's own rules in tests/link/udp_link_test.cpp).
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <ecat/link/udp_link.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string quoted(const fs::path& path) {
  return "'" + path.string() + "'";
}

// The tool ended on its own with `code`, printed `needle` on stderr and nothing that says it
// crashed (an abort through the shell is status 134; a sanitizer report names itself).
void expect_clean_error(const ToolRun& r, int code, const std::string& needle,
                        const std::string& what) {
  EXPECT_EQ(r.status, code) << what << "\nstdout: " << r.out << "\nstderr: " << r.err;
  EXPECT_NE(r.err.find(needle), std::string::npos)
      << what << ": stderr lacks \"" << needle << "\":\n"
      << r.err << "\nstdout: " << r.out;
  for (const char* crash : {"terminate called", "Sanitizer", "runtime error", "Aborted"}) {
    EXPECT_EQ(r.err.find(crash), std::string::npos) << what << ": " << r.err;
  }
}

class HostileInput : public ::testing::Test {
 protected:
  HostileInput() : tool_("hostile") {}

  fs::path write(const std::string& name, const std::string& text) const {
    const auto path = tool_.dir() / name;
    std::ofstream(path, std::ios::binary) << text;
    return path;
  }
  // A sparse file of `bytes` bytes (costs no disk).
  fs::path sparse(const std::string& name, std::uintmax_t bytes) const {
    const auto path = tool_.dir() / name;
    std::ofstream(path, std::ios::binary).put('x');
    fs::resize_file(path, bytes);
    return path;
  }
  fs::path fifo(const std::string& name) const {
    const auto path = tool_.dir() / name;
    EXPECT_EQ(::mkfifo(path.c_str(), 0600), 0);
    return path;
  }
  fs::path directory(const std::string& name) const {
    const auto path = tool_.dir() / name;
    fs::create_directories(path);
    return path;
  }

  ToolRunner tool_;
};

// ---- Outside files ---------------------------------------------------------------------------

TEST_F(HostileInput, FilesThatAreNotRegularFilesAreRefusedByName) {
  const auto dir = directory("a-directory");
  const auto pipe = fifo("a-fifo");
  struct Bad {
    fs::path path;
    std::string says;
  };
  const std::vector<Bad> bad{
      {dir, "is a directory"},
      {"/dev/zero", "is a device"},
      {pipe, "is a FIFO (named pipe)"},
      {tool_.dir() / "absent", "no such"},
      // A regular file whose read fails (EIO), as a failing disk would.
      {"/proc/self/mem", "Input/output error"},
  };
  // Every command that reads a file, with the kind of file it reads.
  const std::vector<std::pair<std::string, std::string>> commands{
      {"run {}", "a ring file"},
      {"slaves --backend sim:{}", "a ring file"},
      {"sim --ring {} --udp 0", "a ring file"},
      {"sii {}", "an SII EEPROM image"},
      {"decode {}", "a capture"},
      {"sim verify {}", "a capture"},
      {"sim profile {} --out " + quoted(tool_.dir() / "profile"), "a capture"},
  };
  for (const auto& [pattern, kind] : commands) {
    for (const auto& b : bad) {
      const std::string args = fmt::format(fmt::runtime(pattern), quoted(b.path));
      const auto r = tool_.run(args);
      expect_clean_error(r, 2, b.path.string(), args);
      EXPECT_NE(r.err.find(b.says), std::string::npos) << args << ": " << r.err;
      if (b.says.rfind("is a", 0) == 0) {
        EXPECT_NE(r.err.find(kind + " must be a regular file"), std::string::npos)
            << args << ": " << r.err;
      }
    }
  }
}

TEST_F(HostileInput, FilesLargerThanTheirKindAllowsAreRefusedWithTheLimit) {
  const auto ring = sparse("big.yaml", (4u << 20) + 1);
  expect_clean_error(tool_.run("run " + quoted(ring)), 2,
                     "is too large for a ring file (at most 4 MiB", "ring");
  const auto eeprom = sparse("big.bin", (8u << 20) + 1);
  expect_clean_error(tool_.run("sii " + quoted(eeprom)), 2,
                     "is too large for an SII EEPROM image (at most 8 MiB", "eeprom");
  const auto capture = sparse("big.pcap", (std::uintmax_t{1} << 30) + 1);
  expect_clean_error(tool_.run("decode " + quoted(capture)), 2,
                     "is too large for a capture (at most 1024 MiB", "capture");
  expect_clean_error(tool_.run("sim verify " + quoted(capture)), 2,
                     "is too large for a capture (at most 1024 MiB", "capture (verify)");
}

// Files a ring names (an EEPROM image, an ESI file) get the same rules as the ring itself.
TEST_F(HostileInput, FilesNamedInsideARingAreRefusedByName) {
  const auto dir = directory("images");
  const auto esi = sparse("huge.xml", (std::uintmax_t{64} << 20) + 1);
  const std::vector<std::pair<std::string, std::string>> slaves{
      {fmt::format("{{name: x, profile: eeprom, file: {}}}", dir.string()),
       dir.string() + ": is a directory; an SII EEPROM image must be a regular file"},
      {"{name: x, profile: eeprom, file: /dev/zero}",
       "/dev/zero: is a device; an SII EEPROM image must be a regular file"},
      {"{name: x, profile: esi, file: /dev/urandom}",
       "/dev/urandom: is a device; an ESI file must be a regular file"},
      {fmt::format("{{name: x, profile: esi, file: {}}}", esi.string()),
       "is too large for an ESI file (at most 64 MiB"},
  };
  for (const auto& [slave, says] : slaves) {
    const auto ring =
        write("ring.yaml", "version: 1\nsimulator:\n  slaves:\n    - " + slave + "\n");
    expect_clean_error(tool_.run("run " + quoted(ring) + " --timeout 2"), 2, says, slave);
    expect_clean_error(tool_.run("sim --ring " + quoted(ring) + " --udp 0"), 2, says, slave);
  }
}

// An endless stream behind a FIFO is refused before anything is read, whoever feeds it.
TEST_F(HostileInput, EndlessInputsAreRefusedAtOnce) {
  const auto pipe = fifo("stream");
  const auto start = std::chrono::steady_clock::now();
  // The writer blocks until a reader opens the FIFO, or dies of SIGPIPE once that reader closes
  // it: either way it is stopped afterwards, never left running.
  const auto r = tool_.run_script(
      fmt::format("yes 'a: [' > {0} 2>/dev/null & w=$!; \"$ECAT\" run {0}; s=$?; kill $w "
                  "2>/dev/null; wait $w 2>/dev/null; exit $s",
                  quoted(pipe)));
  expect_clean_error(r, 2, "is a FIFO (named pipe); a ring file must be a regular file", "fifo");
  EXPECT_LT(std::chrono::steady_clock::now() - start, 30s);
  expect_clean_error(tool_.run("sii /dev/urandom"), 2, "is a device", "urandom");
}

// ---- Numbers ---------------------------------------------------------------------------------

TEST_F(HostileInput, NumericOptionsRefuseNonFiniteAndOutOfRangeValuesWithTheRange) {
  const auto ring = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
  struct Case {
    std::string args;
    std::string says;
  };
  const std::vector<Case> cases{
      {"run '" + ring + "' --duration nan",
       "--duration: 'nan' is not a finite number (expected "
       "0 to 31536000 seconds)"},
      {"run '" + ring + "' --duration inf", "'inf' is not a finite number"},
      {"run '" + ring + "' --duration -inf", "'-inf' is not a finite number"},
      {"run '" + ring + "' --duration 1e300", "'1e300' is out of range (expected 0 to 31536000"},
      {"run '" + ring + "' --duration -1", "'-1' is out of range"},
      {"run '" + ring + "' --duration 2s", "'2s' is not a finite number"},
      {"run '" + ring + "' --timeout 0",
       "--timeout: '0' is out of range (expected above 0 to "
       "86400 seconds)"},
      {"run '" + ring + "' --timeout nan", "--timeout: 'nan' is not a finite number"},
      {"slaves --backend 'sim:" + ring + "' --timeout 1e309", "'1e309' is not a finite number"},
      {"demo --duration NaN", "--duration: 'NaN' is not a finite number"},
      {"demo --timeout infinity", "--timeout: 'infinity' is not a finite number"},
      {"sim fault inject drop_responses --after-ms inf --control /nonexistent",
       "--after-ms: 'inf' is not a finite number (expected 0 to 86400000 ms)"},
      {"sim fault inject drop_responses --next 0 --control /nonexistent",
       "--next: '0' is out of range (expected 1 to 1000000000 exchanges)"},
      {"run '" + ring + "' --duration " + std::string(400, '9'), "is not a finite number"},
      {"sim set outputs.channel_1 nan --control /nonexistent",
       "'nan' is not a finite number (or true/false)"},
      {"sim set outputs.channel_1 inf --control /nonexistent", "'inf' is not a finite number"},
      {"sim --ring '" + ring + "' --udp 127.0.0.1:0 --spin",
       "--spin and --busy-poll apply to raw serving: give --interface IFACE"},
      {"sim --ring '" + ring + "' --udp 127.0.0.1:0 --busy-poll 50",
       "--spin and --busy-poll apply to raw serving"},
  };
  for (const auto& c : cases) {
    const auto r = tool_.run(c.args);
    expect_clean_error(r, 2, c.says, c.args);
    EXPECT_LT(r.err.size(), 400u) << "a refused number should not be echoed at length: " << r.err;
  }
}

TEST_F(HostileInput, NonFiniteNumbersInRingFilesAreRefusedWithTheirPlace) {
  const std::vector<std::pair<std::string, std::string>> files{
      {"version: 1\nsimulator:\n  slaves:\n    - {name: a, profile: EK1100, clock: {drift_ppm: "
       ".nan}}\n",
       "ring.yaml:4: simulator.slaves[0].clock.drift_ppm: '.nan' is not a number"},
      {"version: 1\nsimulator:\n  slaves:\n    - {name: a, profile: EK1100, clock: {drift_ppm: "
       "1e300}}\n",
       "1e300 ppm is out of range (-1000 to 1000)"},
      {"version: 1\ndomains:\n  - {id: main, period_us: 1e300}\n", "domains[0].period_us"},
      {"version: 1\ndomains:\n  - {id: main, period_us: .inf}\n", "domains[0].period_us"},
  };
  for (const auto& [text, says] : files) {
    const auto ring = write("ring.yaml", text);
    const bool simulator = text.find("simulator:") != std::string::npos;
    const std::string args = simulator ? "sim --ring " + quoted(ring) + " --udp 0"
                                       : "run " + quoted(ring) + " --backend udp:127.0.0.1:9";
    expect_clean_error(tool_.run(args), 2, says, text);
  }
}

TEST_F(HostileInput, DeeplyNestedYamlIsNamed) {
  // Deeper than yaml-cpp's own guard (2000) and than ours (48).
  const auto deep = write("deep.yaml", "version: 1\nmaster:\n  backend: " + std::string(3000, '[') +
                                           std::string(3000, ']') + "\n");
  expect_clean_error(tool_.run("run " + quoted(deep)), 2,
                     "deep.yaml:3: nested deeper than 48 levels", "3000 levels");
  const auto mapping = write(
      "mapping.yaml", "a: " + [] {
        std::string s;
        for (int i = 0; i < 100; ++i)
          s += "{b: ";
        return s + "1" + std::string(100, '}');
      }() + "\n");
  expect_clean_error(tool_.run("sim --ring " + quoted(mapping) + " --udp 0"), 2,
                     "nested deeper than 48 levels", "100 levels");
}

// ---- A session that fails after the ring is up ------------------------------------------------

// A simulated ring served over UDP on loopback from this process, so that it outlives the tool
// and its AL states can be read after the tool has exited.
class SimulatedRing {
 public:
  explicit SimulatedRing(const std::string& ring_yaml, const std::string& base_dir = "") {
    auto ring = sim::parse_ring(ring_yaml, "ring.yaml", base_dir);
    if (!ring) {
      ADD_FAILURE() << ring.error().describe();
      return;
    }
    auto server = sim::make_server(*ring);
    if (!server) {
      ADD_FAILURE() << server.error().describe();
      return;
    }
    server_ = std::move(*server);
    auto link = link::UdpLink::serve("127.0.0.1", 0);
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return;
    }
    port_ = (*link)->local_port();
    if (auto served = server_->serve(std::move(*link)); !served) {
      ADD_FAILURE() << served.error().describe();
    }
  }
  ~SimulatedRing() {
    if (server_) server_->stop();
  }
  bool ok() const { return server_ && port_ != 0; }
  std::string backend() const { return fmt::format("udp:127.0.0.1:{}", port_); }
  sim::SimServer& server() { return *server_; }

  // "coupler=INIT inputs=INIT ..." for messages; every_slave_in_init() for the check.
  std::string states() const {
    std::string out;
    for (const auto& s : server_->status().slaves) {
      out += fmt::format("{}{}={}", out.empty() ? "" : " ", s.name, wire::to_string(s.al_state));
    }
    return out;
  }
  bool every_slave_in_init() const {
    for (const auto& s : server_->status().slaves) {
      if (s.al_state != wire::AlState::init) return false;
    }
    return true;
  }
  bool any_slave_above_init() const { return !every_slave_in_init(); }

 private:
  std::unique_ptr<sim::SimServer> server_;
  std::uint16_t port_ = 0;
};

constexpr const char* kSimulatedSlaves = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: drive, profile: servo}
)";

// The EL1809's SII image with one byte of the checksummed configuration area changed (the
// checksum word left as it was), written to `path`.
void write_corrupt_eeprom(const fs::path& path) {
  sim::DeviceConfig device;
  device.profile = "EL1809";
  auto esc = sim::make_device(device);
  ASSERT_TRUE(esc) << esc.error().describe();
  auto eeprom = (*esc)->eeprom();
  std::vector<std::uint8_t> bytes(eeprom.begin(), eeprom.end());
  ASSERT_GE(bytes.size(), 16u);
  bytes[4] ^= 0x5A;
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
}

TEST_F(HostileInput, AFailureAtEachPhaseLeavesEverySlaveInInit) {
  // The master's side of each case: what fails, and where.
  struct Phase {
    std::string name;
    std::string master;  // the master's sections of the ring file
    std::string says;    // on stderr
  };
  const auto not_a_file = directory("esi-directory");
  const std::vector<Phase> phases{
      // Discovery: the ring holds four slaves, the configuration wants five.
      {"discovery",
       "slaves:\n  - {name: coupler}\n  - {name: inputs}\n  - {name: outputs}\n"
       "  - {name: drive}\n  - {name: extra}\n",
       "nothing found for 'extra'"},
      // PREOP configuration: a startup SDO to an object the drive does not have.
      {"preop",
       "slaves:\n  - {name: coupler}\n  - {name: inputs}\n  - {name: outputs}\n"
       "  - name: drive\n    startup_sdos:\n      - {index: 0x5FFF, subindex: 1, type: u8, "
       "value: 1}\n",
       "slave drive (station 0x1003): startup SDO 0x5fff:01"},
      // Activation: the drive's ESI path names a directory, read on the way to SAFEOP.
      {"activation",
       fmt::format("domains:\n  - {{id: main, period_us: 1000}}\nslaves:\n  - {{name: coupler}}\n"
                   "  - {{name: inputs, process_data: main}}\n"
                   "  - {{name: outputs, process_data: main}}\n"
                   "  - {{name: drive, process_data: main, sync: {{mode: sync0}}, esi: {}}}\n"
                   "dc: {{cycle_us: 1000}}\n",
                   not_a_file.string()),
       "is a directory; an ESI file must be a regular file"},
  };
  for (const auto& phase : phases) {
    SimulatedRing ring(kSimulatedSlaves);
    ASSERT_TRUE(ring.ok());
    const auto file = write("master.yaml", "version: 1\n" + phase.master);
    const auto r = tool_.run("run " + quoted(file) + " --backend " + ring.backend() +
                             " --timeout 4 --duration 0 --no-chase");
    expect_clean_error(r, 1, phase.says, phase.name);
    EXPECT_TRUE(ring.every_slave_in_init()) << phase.name << ": " << ring.states();
  }
}

// A session that is running when a slave fails for good: the run ends with exit 1 and every
// slave it can still reach back in INIT.
TEST_F(HostileInput, AFailureWhileRunningLeavesEverySlaveInInit) {
  SimulatedRing ring(kSimulatedSlaves);
  ASSERT_TRUE(ring.ok());
  const auto file = write("master.yaml",
                          "version: 1\ndomains:\n  - {id: main, period_us: 1000}\nslaves:\n"
                          "  - {name: coupler}\n  - {name: inputs, process_data: main}\n"
                          "  - {name: outputs, process_data: main}\n");
  std::thread faulter([&] {
    // Once the ring is in OP, the outputs terminal refuses to stay there. It waits for the
    // terminal to stay in OP for 500 ms: the master (another process) has then seen it there and
    // reported the session operational; a retreat at once could come before the master read the
    // terminal's OP, and the session would end as never started (activation blocked) instead.
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    bool op = false;
    auto op_since = std::chrono::steady_clock::time_point::max();
    while (!op && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(10ms);
      for (const auto& s : ring.server().status().slaves) {
        if (s.name != "outputs") continue;
        const auto now = std::chrono::steady_clock::now();
        if (s.al_state != wire::AlState::op) {
          op_since = std::chrono::steady_clock::time_point::max();
        } else if (op_since == std::chrono::steady_clock::time_point::max()) {
          op_since = now;
        }
        op = op_since != std::chrono::steady_clock::time_point::max() && now - op_since >= 500ms;
      }
    }
    EXPECT_TRUE(op) << "the outputs terminal never reached OP: " << ring.states();
    EXPECT_TRUE(ring.server().inject(sim::fault::retreat_to_safeop("outputs")).ok());
    for (int i = 0; i < 40; ++i) {
      std::this_thread::sleep_for(50ms);
      (void)ring.server().inject(sim::fault::retreat_to_safeop("outputs"));
    }
  });
  const auto r = tool_.run("run " + quoted(file) + " --backend " + ring.backend() +
                           " --timeout 10 --duration 2.5 --no-chase");
  faulter.join();
  EXPECT_NE(r.out.find("operational"), std::string::npos) << r.out << r.err;
  EXPECT_NE(r.out.find("stopped: every slave back in INIT"), std::string::npos) << r.out;
  EXPECT_TRUE(ring.every_slave_in_init()) << ring.states();
}

// A corrupt EEPROM under a short time-out: the error names the slave and what is wrong with it,
// not only the state the session was left in.
TEST_F(HostileInput, ACorruptEepromIsNamedWhenTheSessionTimesOut) {
  const auto image = tool_.dir() / "corrupt.bin";
  write_corrupt_eeprom(image);
  SimulatedRing ring(
      fmt::format("version: 1\nsimulator:\n  slaves:\n    - {{name: coupler, "
                  "profile: EK1100}}\n    - {{name: broken, profile: eeprom, file: "
                  "{}}}\n",
                  image.string()));
  ASSERT_TRUE(ring.ok());
  const auto file =
      write("master.yaml", "version: 1\nslaves:\n  - {name: coupler}\n  - {name: broken}\n");
  const auto r = tool_.run("run " + quoted(file) + " --backend " + ring.backend() + " --timeout 4");
  expect_clean_error(r, 1, "broken", "corrupt eeprom");
  EXPECT_NE(r.err.find("checksum"), std::string::npos) << r.err;
  EXPECT_TRUE(ring.every_slave_in_init()) << ring.states();
}

// ---- Listeners and discovery ------------------------------------------------------------------

TEST_F(HostileInput, TheSimulatorListensOnLoopbackUnlessToldAndSaysSoWhenTold) {
  const auto ring = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
  const auto control = tool_.dir() / "c.sock";
  auto r = tool_.run_script(fmt::format(
      "\"$ECAT\" sim --ring '{}' --udp :0 --control {} & pid=$!; sleep 1; kill -TERM $pid; "
      "wait $pid",
      ring, quoted(control)));
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("on udp-server:127.0.0.1:"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("not loopback"), std::string::npos) << r.err;

  r = tool_.run_script(fmt::format(
      "\"$ECAT\" sim --ring '{}' --udp 0.0.0.0:0 --control {} & pid=$!; sleep 1; kill -TERM $pid; "
      "wait $pid",
      ring, quoted(control)));
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.err.find("is not loopback: any host that reaches this machine can drive the "
                       "simulated ring"),
            std::string::npos)
      << r.err;

  expect_clean_error(tool_.run("sim --ring '" + ring + "' --udp 127.0.0.1:http"), 2,
                     "--udp '127.0.0.1:http': expected [ADDR:]PORT", "port");
}

// A live socket named like a simulator's but owned by another user is never talked to.
TEST_F(HostileInput, DiscoveryIgnoresOtherUsersSockets) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to create a socket owned by another user";
  const auto runtime = directory("runtime");
  const auto path = runtime / "ecat-sim-999999.sock";
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::snprintf(address.sun_path, sizeof address.sun_path, "%s", path.c_str());
  ASSERT_EQ(::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address), 0);
  ASSERT_EQ(::listen(fd, 1), 0);
  ASSERT_EQ(::fcntl(fd, F_SETFL, O_NONBLOCK), 0);
  ASSERT_EQ(::chown(path.c_str(), 65534, 65534), 0);  // nobody
  const auto r = tool_.run_script("XDG_RUNTIME_DIR=" + quoted(runtime) + " \"$ECAT\" sim status");
  // The tool may find a simulator of this user's elsewhere (/tmp); it must not have connected here.
  const int connection = ::accept4(fd, nullptr, nullptr, SOCK_NONBLOCK);
  EXPECT_LT(connection, 0) << "the tool connected to another user's socket: " << r.out << r.err;
  if (connection >= 0) ::close(connection);
  ::close(fd);
  EXPECT_EQ(r.out.find("ecat-sim-999999"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("ecat-sim-999999"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace ecat::test
