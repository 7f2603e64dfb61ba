// The ring file parser (YAML through yaml-cpp, then the strict simulator schema and the fault
// vocabulary) must never crash, hang or leak an exception on any input; whatever parses must
// describe its faults and serialize them to JSON that parses back to the same JSON.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include <ecat/sim/faults.hpp>
#include <ecat/sim/ring.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > 64 * 1024) return 0;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto ring = ecat::sim::parse_ring(text, "fuzz.yaml", "/nonexistent");
  if (!ring.ok()) {
    if (ring.error().message().empty()) std::abort();
    return 0;
  }
  if (ring->slaves.empty()) std::abort();
  for (const auto& f : ring->faults) {
    (void)ecat::sim::describe(f.fault);
    const std::string json = ecat::sim::to_json(f.fault);
    auto again = ecat::sim::parse_fault_json(json);
    if (!again.ok() || ecat::sim::to_json(*again) != json) std::abort();
  }
  return 0;
}
