// The line server under the simulator's control channel and the master's control endpoint:
// replies in order, followers receive what is published, the socket's mode and the peer's
// credentials, and the bounds (line length, clients) that keep bad clients from hurting it.
#include <chrono>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <ecat/ipc/line_server.hpp>

namespace ecat::ipc {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

std::string socket_path() {
  return (fs::temp_directory_path() /
          fmt::format("ecat-ipc-{}-{}.sock", ::getpid(),
                      ::testing::UnitTest::GetInstance()->current_test_info()->name()))
      .string();
}

std::string error_json(std::string_view message) {
  return fmt::format(R"({{"ok":false,"error":"{}"}})", message);
}

TEST(LineServer, RepliesFollowersAndPeers) {
  const auto path = socket_path();
  std::uint32_t seen_uid = 12345;
  auto server =
      LineServer::start(path,
                        [&](std::string_view line, const Peer& peer) {
                          seen_uid = peer.uid;
                          return Reply{fmt::format("echo {}", line), line == "follow"};
                        },
                        error_json, {.mode = 0640, .max_clients = 2, .what = "test endpoint"});
  ASSERT_TRUE(server.ok()) << server.error().describe();
  struct stat st {};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0640u);

  auto reply = call(path, "hello");
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  EXPECT_EQ(*reply, "echo hello");
  EXPECT_EQ(seen_uid, ::geteuid());

  // A follower gets every published line after its request's reply, in order.
  auto follower = LineClient::connect(path);
  ASSERT_TRUE(follower.ok());
  auto first = follower->request("follow");
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(*first, "echo follow");
  for (int i = 0; i < 100 && (*server)->followers() == 0; ++i)
    std::this_thread::sleep_for(1ms);
  EXPECT_EQ((*server)->followers(), 1u);
  (*server)->publish("one");
  (*server)->publish("two");
  auto a = follower->read_line(2s);
  auto b = follower->read_line(2s);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(a->has_value() && b->has_value());
  EXPECT_EQ(**a, "one");
  EXPECT_EQ(**b, "two");

  // Two clients at most: the third is told so and closed.
  auto second = LineClient::connect(path);
  ASSERT_TRUE(second.ok());
  ASSERT_TRUE(second->request("x").ok());
  auto third = LineClient::connect(path);
  ASSERT_TRUE(third.ok());
  auto refused = third->read_line(2s);
  ASSERT_TRUE(refused.ok());
  ASSERT_TRUE(refused->has_value());
  EXPECT_NE((*refused)->find("too many clients (at most 2)"), std::string::npos) << **refused;

  // The socket is exclusive, and removed on stop.
  auto again = LineServer::start(path, [](std::string_view, const Peer&) { return Reply{}; },
                                 error_json, {.what = "test endpoint"});
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().code(), Errc::busy);
  EXPECT_NE(again.error().message().find("another test endpoint already listens"),
            std::string::npos);
  server->reset();
  EXPECT_FALSE(fs::exists(path));
  auto gone = call(path, "hello", 1s, "test endpoint");
  ASSERT_FALSE(gone.ok());
  EXPECT_EQ(gone.error().code(), Errc::not_found);
}

TEST(LineServer, AnOverlongLineIsRefusedAndTheServerCarriesOn) {
  const auto path = socket_path();
  auto server = LineServer::start(
      path, [](std::string_view line, const Peer&) { return Reply{std::string(line)}; }, error_json,
      {.max_line = 1024});
  ASSERT_TRUE(server.ok());
  auto client = LineClient::connect(path);
  ASSERT_TRUE(client.ok());
  auto refused = client->request(std::string(5000, 'x'));
  ASSERT_TRUE(refused.ok()) << refused.error().describe();
  EXPECT_NE(refused->find("line longer than 1024 bytes; closing"), std::string::npos);
  auto closed = client->read_line(2s);
  ASSERT_FALSE(closed.ok());
  EXPECT_EQ(closed.error().code(), Errc::closed);
  auto fine = call(path, "still here");
  ASSERT_TRUE(fine.ok());
  EXPECT_EQ(*fine, "still here");
}

TEST(LineServer, RefusesBadArguments) {
  auto no_path = LineServer::start(
      "", [](std::string_view, const Peer&) { return Reply{}; }, error_json);
  ASSERT_FALSE(no_path.ok());
  EXPECT_EQ(no_path.error().code(), Errc::invalid_argument);
  auto bad_mode =
      LineServer::start(socket_path(), [](std::string_view, const Peer&) { return Reply{}; },
                        error_json, {.mode = 01777});
  ASSERT_FALSE(bad_mode.ok());
  EXPECT_EQ(bad_mode.error().code(), Errc::invalid_argument);
}

}  // namespace
}  // namespace ecat::ipc
