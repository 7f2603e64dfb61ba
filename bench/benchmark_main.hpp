// BENCHMARK_MAIN for the Google Benchmark programs, plus what the figures were measured with
// (build_info.hpp) in the context. Include from the program's one file and call from main().
#pragma once

#include <benchmark/benchmark.h>

#include "build_info.hpp"

namespace ecat::bench {

inline int benchmark_main(int argc, char** argv) {
  benchmark::AddCustomContext("ecat build", build_info());
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

}  // namespace ecat::bench
