// A master's control endpoint (master/control_endpoint.hpp): opened by Master::start from
// MasterConfig::control, answering status, slaves, domains, SDO and register requests through the
// master's own mailboxes and bus, refusing writes unless allowed, following the event stream, and
// giving every bad request a reply that says what was wrong. The domain keeps cycling without a
// miss while requests come in.
#include <chrono>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include <ecat/ipc/line_server.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;

class ControlEndpointTest : public ::testing::Test {
 protected:
  void start(bool allow_writes) {
    path_ = (std::filesystem::temp_directory_path() /
             fmt::format("ecat-master-{}-{}.sock", ::getpid(),
                         ::testing::UnitTest::GetInstance()->current_test_info()->name()))
                .string();
    server_ = test::make_sim_server(test::kTerminalRing);
    ASSERT_TRUE(server_);
    auto config = test::quick_config();
    config.control = {.name = path_, .mode = 0600, .allow_writes = allow_writes};
    master_ = std::make_unique<Master>(config);
    auto link = server_->serve_memory();
    ASSERT_TRUE(link.ok());
    ASSERT_TRUE(master_->start(std::move(*link)).ok());
    ASSERT_TRUE(master_->await_operational(10s).ok());
  }
  void TearDown() override {
    if (master_) (void)master_->stop();
    master_.reset();
  }

  json ask(const std::string& request) {
    auto reply = ipc::call(path_, request, 10s, "master");
    EXPECT_TRUE(reply.ok()) << reply.error().describe();
    if (!reply) return json{};
    return json::parse(*reply);
  }

  std::string path_;
  std::unique_ptr<sim::SimServer> server_;
  std::unique_ptr<Master> master_;
};

TEST_F(ControlEndpointTest, AnswersWhatAMasterIsAndRefusesWritesWhenReadOnly) {
  start(false);
  EXPECT_EQ(control_socket_path(path_), path_);
  auto found = find_control_endpoint(path_);
  ASSERT_TRUE(found.ok());
  EXPECT_EQ(*found, path_);

  auto status = ask(R"({"op":"status","id":7})");
  EXPECT_EQ(status["ok"], true);
  EXPECT_EQ(status["id"], 7);
  EXPECT_EQ(status["state"], "operational");
  EXPECT_EQ(status["slaves"].size(), 3u);
  EXPECT_EQ(status["domains"][0]["id"], "main");

  auto slaves = ask(R"({"op":"slaves","verbose":true})");
  ASSERT_EQ(slaves["slaves"].size(), 3u);
  EXPECT_EQ(slaves["slaves"][1]["name"], "inputs");
  EXPECT_EQ(slaves["slaves"][1]["identity"]["product_code"], 0x07113052u);
  EXPECT_FALSE(slaves["slaves"][1]["signals"].empty());

  // Registers through the master's bus: AL status of "outputs" is OP (8).
  auto al = ask(R"({"op":"reg.read","slave":"outputs","address":"0x0130","length":2})");
  EXPECT_EQ(al["ok"], true) << al.dump();
  EXPECT_EQ(al["data"], "0800");

  auto image = ask(R"({"op":"domain.data","domain":"main"})");
  EXPECT_EQ(image["ok"], true) << image.dump();
  EXPECT_EQ(image["size"], 4);

  auto sii = ask(R"({"op":"sii.read","slave":"coupler"})");
  EXPECT_EQ(sii["ok"], true);
  EXPECT_GT(sii["size"].get<int>(), 64);

  // Writes are refused: the endpoint was not opened for them.
  for (const char* write :
       {R"({"op":"output.write","slave":"outputs","signal":"channel_1","value":true})",
        R"({"op":"state.request","state":"safeop"})",
        R"({"op":"reg.write","slave":"outputs","address":"0x0120","data":"0100"})"}) {
    auto refused = ask(write);
    EXPECT_EQ(refused["ok"], false);
    EXPECT_EQ(refused["code"], "permission_denied") << refused.dump();
  }
  EXPECT_EQ(master_->state(), MasterState::operational);

  // Bad requests: each gets a reply naming what was wrong.
  const std::pair<const char*, const char*> bad[] = {
      {"not json", "malformed"},
      {R"({"no":"op"})", "invalid_argument"},
      {R"({"op":"nonsense"})", "invalid_argument"},
      {R"({"op":"slave","slave":"nobody"})", "not_found"},
      {R"({"op":"reg.read","slave":"outputs","address":70000,"length":2})", "invalid_argument"},
      {R"({"op":"reg.read","slave":"outputs","address":"0xFFFF","length":2})", "invalid_argument"},
      {R"({"op":"sdo.upload","slave":"inputs","index":"zz","subindex":0})", "invalid_argument"},
      {R"({"op":"domain.data","domain":"other"})", "not_found"},
      {R"({"op":"status","id":{"nested":1}})", "invalid_argument"},
  };
  for (const auto& [request, code] : bad) {
    auto reply = ask(request);
    EXPECT_EQ(reply["ok"], false) << request;
    EXPECT_EQ(reply["code"], code) << request << " -> " << reply.dump();
    EXPECT_FALSE(reply["error"].get<std::string>().empty());
  }
}

TEST_F(ControlEndpointTest, WritesWhenAllowedAndTheEventStreamFollows) {
  start(true);
  auto follower = ipc::LineClient::connect(path_, "master");
  ASSERT_TRUE(follower.ok());
  auto following = follower->request(R"({"op":"events.follow"})");
  ASSERT_TRUE(following.ok());
  EXPECT_EQ(json::parse(*following)["following"], true);

  auto write = ask(R"({"op":"output.write","slave":"outputs","signal":"channel_1","value":true})");
  EXPECT_EQ(write["ok"], true) << write.dump();
  auto down = ask(R"({"op":"state.request","state":"safeop"})");
  EXPECT_EQ(down["ok"], true) << down.dump();
  EXPECT_EQ(master_->state(), MasterState::deactivated);
  // The change came as events, one JSON object per line.
  bool saw_master_state = false;
  for (int i = 0; i < 50 && !saw_master_state; ++i) {
    auto line = follower->read_line(200ms);
    ASSERT_TRUE(line.ok());
    if (!*line) continue;
    auto e = json::parse(**line);
    if (e["event"] == "master.state" && e["to"] == "deactivated") saw_master_state = true;
  }
  EXPECT_TRUE(saw_master_state);
  auto up = ask(R"({"op":"state.request","state":"op"})");
  EXPECT_EQ(up["ok"], true) << up.dump();
  auto bad_state = ask(R"({"op":"state.request","slave":"outputs","state":"flying"})");
  EXPECT_EQ(bad_state["code"], "invalid_argument");
}

TEST_F(ControlEndpointTest, RequestsDoNotDisturbTheCycle) {
  start(false);
  auto domain = master_->domain("main");
  ASSERT_TRUE(domain.ok());
  // Misses caused by the requests: those during a burst of them, against those of an equally
  // long quiet window right after (a loaded machine misses a cycle now and then by itself).
  const auto misses = [&] { return (*domain)->stats().total_miss_count; };
  const auto before = misses();
  const auto started = std::chrono::steady_clock::now();
  for (int i = 0; i < 40; ++i) {
    ASSERT_EQ(ask(R"({"op":"reg.read","slave":"inputs","address":"0x0000","length":10})")["ok"],
              true);
    ASSERT_EQ(ask(R"({"op":"slaves","verbose":true})")["ok"], true);
    ASSERT_EQ(ask(R"({"op":"domain.data","domain":"main"})")["ok"], true);
    ASSERT_EQ(ask(R"({"op":"sdo.upload","slave":"inputs","index":"0x1000","subindex":0})")["ok"],
              false);  // an EL1809 has no mailbox: refused at once, no frame
  }
  const auto burst = std::chrono::steady_clock::now() - started;
  const auto during = misses() - before;
  const auto quiet_start = misses();
  std::this_thread::sleep_for(burst);
  const auto quiet = misses() - quiet_start;
  // One miss of slack: a miss lands in either window by chance on a loaded machine (requests
  // that cost cycles cost one per request: 160 here).
  EXPECT_LE(during, quiet + 1) << "the requests cost the domain cycles (" << during << " missed in "
                               << std::chrono::duration<double>(burst).count() << " s, " << quiet
                               << " in as long a quiet window)";
  EXPECT_EQ(master_->state(), MasterState::operational);
}

TEST(ControlEndpointConfig, ASecondMasterOnTheSameEndpointIsRefusedAtStart) {
  const auto path =
      (std::filesystem::temp_directory_path() / fmt::format("ecat-master-{}-dup.sock", ::getpid()))
          .string();
  auto server = test::make_sim_server(test::kTerminalRing);
  ASSERT_TRUE(server);
  auto config = test::quick_config();
  config.control.name = path;
  Master first(config);
  auto link = server->serve_memory();
  ASSERT_TRUE(link.ok());
  ASSERT_TRUE(first.start(std::move(*link)).ok());
  Master second(config);
  auto other = test::make_sim_server(test::kTerminalRing);
  auto link2 = other->serve_memory();
  ASSERT_TRUE(link2.ok());
  auto refused = second.start(std::move(*link2));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::busy);
  EXPECT_NE(refused.error().describe().find("another master already listens"), std::string::npos)
      << refused.error().describe();
  (void)first.stop();
}

}  // namespace
}  // namespace ecat::master
