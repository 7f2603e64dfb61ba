// Access to ../shared/data (real EEPROM images and captures). That data is not ours to ship, so a
// test that needs it skips with a clear message when it is absent.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::test {

inline std::filesystem::path shared_data_dir() {
  if (const char* env = std::getenv("ECAT_SHARED_DATA")) return env;
  return ECAT_SHARED_DATA_DIR;
}

// The path of a file under the shared data folder, or nullopt when it is not there.
inline std::optional<std::filesystem::path> shared_data(const std::string& relative) {
  auto path = shared_data_dir() / relative;
  if (!std::filesystem::exists(path)) return std::nullopt;
  return path;
}

inline std::vector<std::uint8_t> read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace ecat::test

// Declares `var` as the path of a shared data file, or skips the test when it is absent.
#define ECAT_SHARED_DATA_OR_SKIP(var, relative)                                            \
  const auto var##_maybe = ::ecat::test::shared_data(relative);                            \
  if (!var##_maybe) {                                                                      \
    GTEST_SKIP() << "real-device data " << relative << " not found under "                 \
                 << ::ecat::test::shared_data_dir() << " (it is not part of the project)"; \
  }                                                                                        \
  const std::filesystem::path var = *var##_maybe
