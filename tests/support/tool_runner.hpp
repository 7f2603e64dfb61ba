// Runs the built `ecat` tool from a test: `ToolRunner runner("demo"); auto r = runner.run("...")`.
// The tool is found through ECAT_TOOL (set by CTest) or the build tree; output goes through
// files in a per-test temporary directory that is removed afterwards.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::test {

struct ToolRun {
  int status = -1;  // exit code; -1 when the tool did not exit normally
  std::string out;
  std::string err;
};

inline std::string tool_path() {
  if (const char* env = std::getenv("ECAT_TOOL")) return env;
  return std::string(ECAT_BINARY_DIR) + "/tools/ecat/ecat";
}

inline std::string read_text_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

class ToolRunner {
 public:
  explicit ToolRunner(std::string label) {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = std::filesystem::temp_directory_path() /
           fmt::format("ecat-{}-{}-{}", label, ::getpid(), info ? info->name() : "test");
    std::filesystem::create_directories(dir_);
  }
  ~ToolRunner() {
    std::error_code ignored;
    std::filesystem::remove_all(dir_, ignored);
  }
  ToolRunner(const ToolRunner&) = delete;
  ToolRunner& operator=(const ToolRunner&) = delete;

  // `arguments` is pasted into a shell command line after the tool's path: quote what needs it.
  ToolRun run(const std::string& arguments) const { return run_script("\"$ECAT\" " + arguments); }

  // Runs a shell script in which "$ECAT" is the tool; everything it prints is captured.
  ToolRun run_script(const std::string& script) const {
    const auto out = dir_ / "stdout";
    const auto err = dir_ / "stderr";
    const auto command = fmt::format("ECAT='{}'; {{ {} ; }} >'{}' 2>'{}'", tool_path(), script,
                                     out.string(), err.string());
    const int raw = std::system(command.c_str());
    ToolRun result;
    result.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    result.out = read_text_file(out);
    result.err = read_text_file(err);
    return result;
  }

  const std::filesystem::path& dir() const noexcept { return dir_; }

 private:
  std::filesystem::path dir_;
};

}  // namespace ecat::test
