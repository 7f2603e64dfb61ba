// Signals: named, typed views on bits of one SyncManager image, and the codecs that read and
// write them.
//
// Bit fields are LSB-first little-endian, as EtherCAT maps them: bit k of a field with bit
// offset o is bit (o + k) % 8 of image byte (o + k) / 8. A field that starts on a byte boundary
// and has a whole number of bytes is copied as bytes.
//
// decode() and encode() are the cycle-path codecs: for scalar types they neither allocate nor
// throw; only an error (a bad signal or value, which validate_signal() rules out up front) builds
// a message.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <ecat/master/pdo.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

enum class SignalType : std::uint8_t {
  boolean,
  int8,
  int16,
  int32,
  int64,
  uint8,
  uint16,
  uint32,
  uint64,
  real32,
  real64,
  bytes,
};
// "bool", "int8", ..., "uint64", "real32", "real64", "bytes".
std::string_view to_string(SignalType type) noexcept;
// The widest field the type can hold (8 for int8, 32 for real32 ...); 0 for bytes (any length).
std::uint16_t max_bit_length(SignalType type) noexcept;
bool is_signed(SignalType type) noexcept;
bool is_unsigned(SignalType type) noexcept;  // uint8..uint64 (not boolean)

// The signal type for a mapped entry of CoE data type `data_type` and `bit_length` bits: the
// CoE type's own kind (INTEGER24 -> int32, BITn -> uint8, strings -> bytes); by the bit length
// for unknown codes or when the field is wider than the type (1 bit -> boolean, up to 64 bits ->
// the smallest unsigned type that holds it, wider -> bytes).
SignalType signal_type_for(std::uint16_t data_type, std::uint16_t bit_length) noexcept;

// engineering value = raw * factor + offset; `minimum` / `maximum` bound what encode_scaled
// accepts (engineering units), on top of what the raw field can hold.
struct LinearScale {
  double factor = 1.0;
  double offset = 0.0;
  std::optional<double> minimum{};
  std::optional<double> maximum{};

  bool operator==(const LinearScale&) const = default;
};

struct Signal {
  std::string name;
  PdoDirection direction = PdoDirection::input;
  std::uint8_t sync_manager = 0;
  std::uint32_t bit_offset = 0;  // in the SyncManager image
  std::uint16_t bit_length = 0;
  SignalType type = SignalType::uint8;
  std::uint16_t pdo_index = 0;
  std::uint16_t index = 0;  // the mapped object (0 when the signal spans several entries)
  std::uint8_t subindex = 0;
  std::string unit;                  // of the engineering value; may be empty
  std::optional<LinearScale> scale;  // raw -> engineering; none: the raw value is the value

  bool operator==(const Signal&) const = default;
};

// The signal for one mapped entry of `layout` (its SM, offset, PDO and type), named `name`.
// Fails when the layout does not map index:subindex.
Result<Signal> signal_for_entry(const PdoLayout& layout, std::uint16_t index, std::uint8_t subindex,
                                std::string name);

// Checks that the signal's type can hold its bit length (real32 exactly 32, real64 exactly 64,
// integers at most their width, at least 1 bit) and, when `image_bytes` is given, that it lies
// inside an image of that many bytes. Errors name the signal.
Result<void> validate_signal(const Signal& signal,
                             std::optional<std::size_t> image_bytes = std::nullopt);

// A signal's value, a projected state value or a command argument.
//   boolean -> bool, int8..int64 -> std::int64_t, uint8..uint64 -> std::uint64_t,
//   real32/real64 (and scaled values) -> double, bytes -> std::vector<std::uint8_t>;
//   std::string only for projected state and command arguments (a state name, a mode).
// A variant of plain alternatives: holding a scalar never allocates, and values compare.
using Value =
    std::variant<bool, std::int64_t, std::uint64_t, double, std::string, std::vector<std::uint8_t>>;

// "true", "-12", "4096", "21.5", "\"text\"" for strings (quoted), "0a 0b" for bytes.
std::string to_string(const Value& value);
// Numeric views: bool as 0/1; a double only when it is integral and in range (as_int64/as_uint64);
// nullopt for strings, bytes and values out of range.
std::optional<double> as_double(const Value& value) noexcept;
std::optional<std::int64_t> as_int64(const Value& value) noexcept;
std::optional<std::uint64_t> as_uint64(const Value& value) noexcept;
// true/false; integers 0/1 too.
std::optional<bool> as_bool(const Value& value) noexcept;

// Reads the signal's raw value from its SyncManager image (typed per SignalType, no scaling).
// Fails (without touching anything) when the field does not lie inside the image or the signal
// is invalid.
Result<Value> decode(const Signal& signal, std::span<const std::uint8_t> sm_image);
// Writes a raw value into the image, leaving every other bit as it was. Accepts any numeric
// alternative that fits the field exactly (an integral double for an integer field, 0/1 for a
// boolean, any number for a real); bytes need exactly ceil(bit_length / 8) bytes. Fails naming
// the signal, the value and the range of the field; the image is then unchanged.
Result<void> encode(const Signal& signal, const Value& value, std::span<std::uint8_t> sm_image);

// The engineering value: raw * factor + offset as a double when the signal has a scale, else
// the raw value unchanged.
Value to_engineering(const Signal& signal, const Value& raw);
// The raw value for an engineering value: (value - offset) / factor rounded to the nearest
// integer for integer fields; checks the scale's minimum/maximum first (errors name the signal,
// the value, the range and the unit). Without a scale the value is returned unchanged.
Result<Value> from_engineering(const Signal& signal, const Value& value);
// decode + to_engineering, and from_engineering + encode: what an application reads and writes.
Result<Value> decode_scaled(const Signal& signal, std::span<const std::uint8_t> sm_image);
Result<void> encode_scaled(const Signal& signal, const Value& value,
                           std::span<std::uint8_t> sm_image);

// The same codecs for a field already taken out of its image (the hot path reads and stages only
// a signal's own bits: Domain::read_fresh_bits / write_bits). Scalar signals of 1..64 bits only
// (not bytes): others fail with validate_signal's error or Errc::unsupported.
//   decode_field: the engineering value of the field whose raw bits are the low bit_length bits
//                 of `raw` (higher bits are ignored), as decode_scaled would read it.
//   encode_field: the raw bits (in the low bit_length bits) for an engineering value, checked
//                 and failing as encode_scaled would.
//   store_field:  writes raw bits (as encode_field made them) into the signal's place in an
//                 image, leaving every other bit as it was; fails like encode for a field that
//                 does not lie inside the image.
// decode_field(s, encode_field(s, v)) gives v back for every v the field holds exactly.
Result<Value> decode_field(const Signal& signal, std::uint64_t raw);
Result<std::uint64_t> encode_field(const Signal& signal, const Value& value);
Result<void> store_field(const Signal& signal, std::uint64_t raw, std::span<std::uint8_t> sm_image);
// The low `bit_length` (1..64) bits of `raw` at bit `bit_offset` of `image` (EtherCAT bit order:
// LSB first), every other bit kept, whatever the signal's type (store_field's bit writer; a
// `bytes` field of at most 64 bits too). False, with nothing written, when they do not fit.
bool store_bits(std::span<std::uint8_t> image, std::uint32_t bit_offset, std::uint16_t bit_length,
                std::uint64_t raw) noexcept;

// Parses text (a command line, a configuration file) into a value for the signal: "true" /
// "false" / "1" / "0" for booleans, decimal or 0x-hexadecimal integers, decimal reals, hex byte
// strings ("0a0b" or "0a 0b") for bytes. A scaled signal takes a real in engineering units.
// Errors name the signal and the text.
Result<Value> parse_value(const Signal& signal, std::string_view text);

// Lower-case ASCII letters and digits; every other run of characters becomes one '_', none at
// either end ("Status__Underrange" -> "status_underrange", "AO Outputs Ch.1" -> "ao_outputs_ch_1").
std::string snake_case(std::string_view text);

}  // namespace ecat::master
