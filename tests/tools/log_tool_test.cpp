// The tool's -v / -q: the library's log (include/ecat/log.hpp) on stderr through spdlog, warnings
// and errors by default, more with each -v, errors only with -q; stdout is never touched.
#include <string>

#include <gtest/gtest.h>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

std::string default_ring() {
  return std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
}

bool has(const std::string& text, const std::string& needle) {
  return text.find(needle) != std::string::npos;
}

TEST(LogTool, VerboseShowsTheLibrarysLogOnStderr) {
  ToolRunner tool("log-v");
  const auto quiet_run = tool.run("run '" + default_ring() + "' --duration 0.2");
  ASSERT_EQ(quiet_run.status, 0) << quiet_run.out << quiet_run.err;
  EXPECT_FALSE(has(quiet_run.err, "[info]")) << quiet_run.err;

  const auto r = tool.run("-v run '" + default_ring() + "' --duration 0.2");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  // The master's events, as the event hub dispatched them: subsystem, then the event's text.
  EXPECT_TRUE(has(r.err, "[info] master: master.state idle -> discovering")) << r.err;
  EXPECT_TRUE(has(r.err, "[info] slave: slave.state drive: preop -> op")) << r.err;
  EXPECT_TRUE(has(r.err, "[info] domain: domain.state main: open -> cycling")) << r.err;
  EXPECT_TRUE(has(r.err, "[info] link: link.up")) << r.err;
  EXPECT_FALSE(has(r.err, "[debug]")) << r.err;
  // The log goes to stderr only: stdout is the same as without -v.
  EXPECT_FALSE(has(r.out, "[info]")) << r.out;
  EXPECT_TRUE(has(r.out, "master: awaiting_preop -> operational")) << r.out;

  // After the subcommand too, and repeated.
  const auto vv = tool.run("run -vv '" + default_ring() + "' --duration 0.2");
  ASSERT_EQ(vv.status, 0) << vv.out << vv.err;
  EXPECT_TRUE(has(vv.err, "[info] master: master.state")) << vv.err;
}

TEST(LogTool, WarningsByDefaultErrorsOnlyWithQuiet) {
  ToolRunner tool("log-q");
  // A link that cannot be opened: the library warns, the tool reports the error itself.
  const std::string bad_link =
      "run '" + default_ring() + "' --backend raw:ecat-no-such-if0 --duration 0";
  const auto r = tool.run(bad_link);
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_TRUE(has(r.err, "[warning] link: ")) << r.err;
  EXPECT_TRUE(has(r.err, "ecat-no-such-if0")) << r.err;

  const auto q = tool.run("-q " + bad_link);
  EXPECT_EQ(q.status, 2) << q.out << q.err;
  EXPECT_FALSE(has(q.err, "[warning]")) << q.err;
  EXPECT_TRUE(has(q.err, "ecat-no-such-if0")) << q.err;  // the tool's own message stays

  const auto ok = tool.run("-q run '" + default_ring() + "' --duration 0.2");
  ASSERT_EQ(ok.status, 0) << ok.out << ok.err;
  EXPECT_FALSE(has(ok.err, "] [")) << ok.err;  // no log line at all

  const auto both = tool.run("-v -q run '" + default_ring() + "' --duration 0");
  EXPECT_EQ(both.status, 2) << both.err;
}

}  // namespace
}  // namespace ecat::test
