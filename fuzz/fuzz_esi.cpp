// ESI XML device descriptions come from vendors' files: parsing and the SII generated from them
// must never crash, hang or read out of bounds, whatever the file holds.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include <ecat/config/esi.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view xml(reinterpret_cast<const char*>(data), size);
  auto file = ecat::config::parse_esi(xml);
  if (!file) return 0;
  for (const auto& device : file->devices) {
    (void)ecat::config::esi_to_sii(*file, device);
  }
  return 0;
}
