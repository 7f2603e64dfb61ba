// SII image decoding must never crash, hang or read out of bounds; whatever decodes must survive
// encode -> decode unchanged.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include <ecat/wire/sii.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace ecat::wire;
  auto first = decode_sii(Bytes{data, size});
  if (!first.ok()) return 0;
  const SiiImage& image = first->image;
  (void)image.device_name();
  for (std::size_t i = 0; i <= image.strings.size() + 1 && i < 256; ++i) {
    (void)image.string(static_cast<std::uint8_t>(i));
  }
  auto encoded = encode_sii(image, {.pad_to_eeprom_size = false});
  if (!encoded.ok()) return 0;  // merged categories can outgrow what one category holds
  auto second = decode_sii(*encoded);
  if (!second.ok()) std::abort();
  if (!(second->image == image)) std::abort();
  if (!second->checksum_ok) std::abort();
  return 0;
}
