// Signal text parsing and the bit codecs must never crash or read outside the image, whatever
// the signal definition, the image size or the text. What parses and encodes must decode back
// to the same value (exactly for integers, booleans and bytes).
//
// Input: byte 0 type, byte 1 bit offset, byte 2 bit length, byte 3 image size, byte 4 flags
// (bit 0: scaled), then the text.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include <ecat/master/signal.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace ecat::master;
  if (size < 5) return 0;
  Signal s;
  s.name = "fuzz";
  s.type = static_cast<SignalType>(data[0] % 12);
  s.bit_offset = data[1];
  s.bit_length = data[2];
  if ((data[4] & 1) != 0) s.scale = LinearScale{0.1, -3.0, -1000.0, 1000.0};
  std::vector<std::uint8_t> image(data[3] % 48, 0xA5);
  const std::string_view text(reinterpret_cast<const char*>(data + 5), size - 5);

  (void)decode(s, image);
  auto value = parse_value(s, text);
  if (!value.ok()) return 0;
  (void)to_string(*value);
  if (!encode_scaled(s, *value, image).ok()) return 0;
  auto back = decode(s, image);
  if (!back.ok()) std::abort();
  if (!s.scale && s.type != SignalType::real32 && s.type != SignalType::real64) {
    const bool same = s.type == SignalType::boolean ? as_bool(*back) == as_bool(*value)
                      : s.type == SignalType::bytes ? *back == *value
                      : is_signed(s.type)           ? as_int64(*back) == as_int64(*value)
                                                    : as_uint64(*back) == as_uint64(*value);
    if (!same) std::abort();
  }
  return 0;
}
