// What a bench measures with: the build type, the compiler and its flags, and whether assert()
// is compiled in (ECAT_ASSERTIONS keeps it on in every build type, Release included).
#pragma once

#include <string>

#include <fmt/format.h>

namespace ecat::bench {

inline std::string build_info() {
#ifdef NDEBUG
  const char* asserts = "off";
#else
  const char* asserts = "on (ECAT_ASSERTIONS=ON; -DECAT_ASSERTIONS=OFF measures without)";
#endif
  return fmt::format("build: {}, g++/clang {} with \"{}\", assert() {}", ECAT_BENCH_BUILD_TYPE,
                     __VERSION__, ECAT_BENCH_CXX_FLAGS, asserts);
}

}  // namespace ecat::bench
