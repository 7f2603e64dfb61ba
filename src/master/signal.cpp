#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include <ecat/master/signal.hpp>

namespace ecat::master {

std::string_view to_string(SignalType type) noexcept {
  switch (type) {
    case SignalType::boolean:
      return "bool";
    case SignalType::int8:
      return "int8";
    case SignalType::int16:
      return "int16";
    case SignalType::int32:
      return "int32";
    case SignalType::int64:
      return "int64";
    case SignalType::uint8:
      return "uint8";
    case SignalType::uint16:
      return "uint16";
    case SignalType::uint32:
      return "uint32";
    case SignalType::uint64:
      return "uint64";
    case SignalType::real32:
      return "real32";
    case SignalType::real64:
      return "real64";
    case SignalType::bytes:
      return "bytes";
  }
  return "unknown";
}

std::uint16_t max_bit_length(SignalType type) noexcept {
  switch (type) {
    case SignalType::boolean:
    case SignalType::int64:
    case SignalType::uint64:
    case SignalType::real64:
      return 64;
    case SignalType::int8:
    case SignalType::uint8:
      return 8;
    case SignalType::int16:
    case SignalType::uint16:
      return 16;
    case SignalType::int32:
    case SignalType::uint32:
    case SignalType::real32:
      return 32;
    case SignalType::bytes:
      return 0;
  }
  return 0;
}

bool is_signed(SignalType type) noexcept {
  return type == SignalType::int8 || type == SignalType::int16 || type == SignalType::int32 ||
         type == SignalType::int64;
}

bool is_unsigned(SignalType type) noexcept {
  return type == SignalType::uint8 || type == SignalType::uint16 || type == SignalType::uint32 ||
         type == SignalType::uint64;
}

namespace {

SignalType unsigned_for_bits(std::uint16_t bits) noexcept {
  if (bits == 1) return SignalType::boolean;
  if (bits <= 8) return SignalType::uint8;
  if (bits <= 16) return SignalType::uint16;
  if (bits <= 32) return SignalType::uint32;
  if (bits <= 64) return SignalType::uint64;
  return SignalType::bytes;
}

SignalType signed_for_bits(std::uint16_t bits) noexcept {
  if (bits <= 8) return SignalType::int8;
  if (bits <= 16) return SignalType::int16;
  if (bits <= 32) return SignalType::int32;
  if (bits <= 64) return SignalType::int64;
  return SignalType::bytes;
}

std::optional<SignalType> coe_kind(std::uint16_t data_type) noexcept {
  using namespace coe_type;
  switch (data_type) {
    case kBoolean:
      return SignalType::boolean;
    case kInteger8:
      return SignalType::int8;
    case kInteger16:
      return SignalType::int16;
    case kInteger24:
    case kInteger32:
      return SignalType::int32;
    case kInteger40:
    case kInteger48:
    case kInteger56:
    case kInteger64:
      return SignalType::int64;
    case kUnsigned8:
    case kByte:
    case kBitArr8:
      return SignalType::uint8;
    case kUnsigned16:
    case kWord:
    case kBitArr16:
      return SignalType::uint16;
    case kUnsigned24:
    case kUnsigned32:
    case kDword:
    case kBitArr32:
      return SignalType::uint32;
    case kUnsigned40:
    case kUnsigned48:
    case kUnsigned56:
    case kUnsigned64:
      return SignalType::uint64;
    case kReal32:
      return SignalType::real32;
    case kReal64:
      return SignalType::real64;
    case kVisibleString:
    case kOctetString:
    case kUnicodeString:
      return SignalType::bytes;
    default:
      break;
  }
  if (data_type >= kBit1 && data_type <= kBit8) return SignalType::uint8;
  return std::nullopt;
}

}  // namespace

SignalType signal_type_for(std::uint16_t data_type, std::uint16_t bit_length) noexcept {
  const auto kind = coe_kind(data_type);
  if (!kind) return unsigned_for_bits(bit_length);
  if (*kind == SignalType::bytes) return SignalType::bytes;
  if (*kind == SignalType::boolean) return SignalType::boolean;
  if (*kind == SignalType::real32 || *kind == SignalType::real64) {
    return bit_length == max_bit_length(*kind) ? *kind : unsigned_for_bits(bit_length);
  }
  if (bit_length <= max_bit_length(*kind)) return *kind;
  // Wider than the declared type (a mislabelled entry): keep the sign, grow the width.
  return is_signed(*kind) ? signed_for_bits(bit_length) : unsigned_for_bits(bit_length);
}

Result<Signal> signal_for_entry(const PdoLayout& layout, std::uint16_t index, std::uint8_t subindex,
                                std::string name) {
  const auto where = layout.find_entry(index, subindex);
  if (!where) {
    return Error(
        Errc::not_found,
        fmt::format("signal '{}': object 0x{:04x}:{:02x} is not mapped in any assigned PDO", name,
                    index, subindex));
  }
  Signal s;
  s.name = std::move(name);
  s.direction = where->sync_manager->direction;
  s.sync_manager = where->sync_manager->sync_manager;
  s.bit_offset = where->entry->bit_offset;
  s.bit_length = where->entry->bit_length;
  s.type = signal_type_for(where->entry->data_type, where->entry->bit_length);
  s.pdo_index = where->pdo->index;
  s.index = index;
  s.subindex = subindex;
  return s;
}

Result<void> validate_signal(const Signal& signal, std::optional<std::size_t> image_bytes) {
  if (signal.bit_length == 0) {
    return Error(Errc::invalid_argument, fmt::format("signal '{}' has bit length 0", signal.name));
  }
  const std::uint16_t max = max_bit_length(signal.type);
  if ((signal.type == SignalType::real32 || signal.type == SignalType::real64) &&
      signal.bit_length != max) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal '{}': a {} field must be {} bits, not {}", signal.name,
                             to_string(signal.type), max, signal.bit_length));
  }
  if (max != 0 && signal.bit_length > max) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal '{}': {} bits do not fit a {} (at most {})", signal.name,
                             signal.bit_length, to_string(signal.type), max));
  }
  if (signal.scale) {
    if (!std::isfinite(signal.scale->factor) || signal.scale->factor == 0.0 ||
        !std::isfinite(signal.scale->offset)) {
      return Error(Errc::invalid_argument,
                   fmt::format("signal '{}': scale factor {} / offset {} unusable", signal.name,
                               signal.scale->factor, signal.scale->offset));
    }
    if (signal.type == SignalType::bytes) {
      return Error(Errc::invalid_argument,
                   fmt::format("signal '{}': a bytes field cannot be scaled", signal.name));
    }
  }
  if (image_bytes) {
    const std::uint64_t end = std::uint64_t{signal.bit_offset} + signal.bit_length;
    if (end > std::uint64_t{*image_bytes} * 8) {
      return Error(
          Errc::out_of_range,
          fmt::format("signal '{}': bits {}..{} lie outside the {}-byte image of "
                      "SyncManager {}",
                      signal.name, signal.bit_offset, end - 1, *image_bytes, signal.sync_manager));
    }
  }
  return ok();
}

// ---- values -----------------------------------------------------------------------------------

std::string to_string(const Value& value) {
  return std::visit(
      [](const auto& v) -> std::string {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, bool>) {
          return v ? "true" : "false";
        } else if constexpr (std::is_same_v<T, std::string>) {
          return fmt::format("\"{}\"", v);
        } else if constexpr (std::is_same_v<T, std::vector<std::uint8_t>>) {
          std::string out;
          for (std::size_t i = 0; i < v.size(); ++i) {
            if (i != 0) out += ' ';
            out += fmt::format("{:02x}", v[i]);
          }
          return out;
        } else {
          return fmt::format("{}", v);
        }
      },
      value);
}

namespace {

constexpr double kTwo63 = 9223372036854775808.0;
constexpr double kTwo64 = 18446744073709551616.0;

}  // namespace

std::optional<double> as_double(const Value& value) noexcept {
  if (const auto* b = std::get_if<bool>(&value)) return *b ? 1.0 : 0.0;
  if (const auto* i = std::get_if<std::int64_t>(&value)) return static_cast<double>(*i);
  if (const auto* u = std::get_if<std::uint64_t>(&value)) return static_cast<double>(*u);
  if (const auto* d = std::get_if<double>(&value)) return *d;
  return std::nullopt;
}

std::optional<std::int64_t> as_int64(const Value& value) noexcept {
  if (const auto* b = std::get_if<bool>(&value)) return *b ? 1 : 0;
  if (const auto* i = std::get_if<std::int64_t>(&value)) return *i;
  if (const auto* u = std::get_if<std::uint64_t>(&value)) {
    if (*u > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
      return std::nullopt;
    }
    return static_cast<std::int64_t>(*u);
  }
  if (const auto* d = std::get_if<double>(&value)) {
    if (!std::isfinite(*d) || std::trunc(*d) != *d || *d < -kTwo63 || *d >= kTwo63) {
      return std::nullopt;
    }
    return static_cast<std::int64_t>(*d);
  }
  return std::nullopt;
}

std::optional<std::uint64_t> as_uint64(const Value& value) noexcept {
  if (const auto* b = std::get_if<bool>(&value)) return *b ? 1u : 0u;
  if (const auto* i = std::get_if<std::int64_t>(&value)) {
    if (*i < 0) return std::nullopt;
    return static_cast<std::uint64_t>(*i);
  }
  if (const auto* u = std::get_if<std::uint64_t>(&value)) return *u;
  if (const auto* d = std::get_if<double>(&value)) {
    if (!std::isfinite(*d) || std::trunc(*d) != *d || *d < 0 || *d >= kTwo64) return std::nullopt;
    return static_cast<std::uint64_t>(*d);
  }
  return std::nullopt;
}

std::optional<bool> as_bool(const Value& value) noexcept {
  if (const auto* b = std::get_if<bool>(&value)) return *b;
  const auto u = as_uint64(value);
  if (u && *u <= 1) return *u == 1;
  return std::nullopt;
}

// ---- bit codec --------------------------------------------------------------------------------

namespace {

// Reads `len` (1..64) bits starting at bit `off`; the caller has checked the bounds.
std::uint64_t read_bits(const std::uint8_t* image, std::uint32_t off, std::uint16_t len) noexcept {
  const std::uint8_t* p = image + off / 8;
  const unsigned shift = off % 8;
  std::uint64_t v = 0;
  if (shift == 0 && len % 8 == 0) {
    for (unsigned i = 0; i < len / 8u; ++i)
      v |= std::uint64_t{p[i]} << (8 * i);
    return v;
  }
  const unsigned bytes = (shift + len + 7) / 8;  // at most 9
  v = std::uint64_t{p[0]} >> shift;
  for (unsigned i = 1; i < bytes; ++i) {
    const unsigned pos = 8 * i - shift;  // < 64: with shift 0 there are at most 8 bytes
    v |= std::uint64_t{p[i]} << pos;
  }
  if (len < 64) v &= (std::uint64_t{1} << len) - 1;
  return v;
}

// Writes the low `len` (1..64) bits of `v` at bit `off`, keeping the neighbouring bits.
void write_bits(std::uint8_t* image, std::uint32_t off, std::uint16_t len,
                std::uint64_t v) noexcept {
  std::uint8_t* p = image + off / 8;
  unsigned bit = off % 8;
  if (bit == 0 && len % 8 == 0) {
    for (unsigned i = 0; i < len / 8u; ++i)
      p[i] = static_cast<std::uint8_t>(v >> (8 * i));
    return;
  }
  unsigned remaining = len;
  unsigned consumed = 0;
  for (std::size_t i = 0; remaining != 0; ++i) {
    const unsigned take = std::min(8u - bit, remaining);
    const auto mask = static_cast<std::uint8_t>(((1u << take) - 1u) << bit);
    const auto bits = static_cast<std::uint8_t>((v >> consumed) << bit) & mask;
    p[i] = static_cast<std::uint8_t>((p[i] & ~mask) | bits);
    consumed += take;
    remaining -= take;
    bit = 0;
  }
}

Error bad_image(const Signal& s, std::size_t image_bytes) {
  const std::uint64_t end = std::uint64_t{s.bit_offset} + s.bit_length;
  return Error(
      Errc::out_of_range,
      fmt::format("signal '{}': bits {}..{} lie outside the {}-byte image of SyncManager "
                  "{}",
                  s.name, s.bit_offset, end == 0 ? 0 : end - 1, image_bytes, s.sync_manager));
}

// Cheap checks every codec call repeats (validate_signal builds messages; this does not unless
// something is wrong).
bool usable(const Signal& s, std::size_t image_bytes) noexcept {
  if (s.bit_length == 0) return false;
  const std::uint16_t max = max_bit_length(s.type);
  if (max != 0 && s.bit_length > max) return false;
  if ((s.type == SignalType::real32 || s.type == SignalType::real64) && s.bit_length != max) {
    return false;
  }
  return std::uint64_t{s.bit_offset} + s.bit_length <= std::uint64_t{image_bytes} * 8;
}

Error unusable(const Signal& s, std::size_t image_bytes) {
  auto valid = validate_signal(s, image_bytes);
  if (!valid) return std::move(valid).error();
  return bad_image(s, image_bytes);
}

std::int64_t sign_extend(std::uint64_t raw, std::uint16_t bits) noexcept {
  if (bits < 64 && ((raw >> (bits - 1)) & 1u) != 0) raw |= ~((std::uint64_t{1} << bits) - 1);
  return static_cast<std::int64_t>(raw);
}

std::string range_text(const Signal& s) {
  if (s.type == SignalType::boolean) return "false/true (or 0/1)";
  if (is_signed(s.type)) {
    if (s.bit_length >= 64) return "-9223372036854775808..9223372036854775807";
    const std::int64_t max = (std::int64_t{1} << (s.bit_length - 1)) - 1;
    return fmt::format("{}..{}", -max - 1, max);
  }
  if (s.bit_length >= 64) return "0..18446744073709551615";
  return fmt::format("0..{}", (std::uint64_t{1} << s.bit_length) - 1);
}

Error out_of_range(const Signal& s, const Value& value) {
  return Error(
      Errc::out_of_range,
      fmt::format("signal '{}' ({}, {} bit{}): value {} out of range {}", s.name, to_string(s.type),
                  s.bit_length, s.bit_length == 1 ? "" : "s", to_string(value), range_text(s)));
}

Error wrong_kind(const Signal& s, const Value& value, std::string_view expected) {
  return Error(Errc::invalid_argument, fmt::format("signal '{}' ({}): value {} is not {}", s.name,
                                                   to_string(s.type), to_string(value), expected));
}

// The raw bits for an integer or boolean field, range-checked.
Result<std::uint64_t> integer_bits(const Signal& s, const Value& value) {
  if (std::holds_alternative<std::string>(value) ||
      std::holds_alternative<std::vector<std::uint8_t>>(value)) {
    return wrong_kind(s, value, "a number");
  }
  if (const auto* d = std::get_if<double>(&value);
      d != nullptr && (!std::isfinite(*d) || std::trunc(*d) != *d)) {
    if (s.type == SignalType::boolean) return wrong_kind(s, value, "a boolean");
    return wrong_kind(s, value, "an integer");
  }
  const std::uint16_t n = s.bit_length;
  const std::uint64_t mask = n >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << n) - 1;
  if (s.type == SignalType::boolean) {
    const auto b = as_bool(value);
    if (!b) return out_of_range(s, value);
    return std::uint64_t{*b ? 1u : 0u};
  }
  if (is_signed(s.type)) {
    const auto v = as_int64(value);
    if (!v) return out_of_range(s, value);
    if (n < 64) {
      const std::int64_t max = (std::int64_t{1} << (n - 1)) - 1;
      if (*v > max || *v < -max - 1) return out_of_range(s, value);
    }
    return static_cast<std::uint64_t>(*v) & mask;
  }
  const auto v = as_uint64(value);
  if (!v || (*v & ~mask) != 0) return out_of_range(s, value);
  return *v;
}

// A scalar field's value from its raw bits (the low bit_length bits of `raw`; the caller has
// checked the signal).
Value scalar_value(const Signal& s, std::uint64_t raw) noexcept {
  switch (s.type) {
    case SignalType::boolean:
      return Value(raw != 0);
    case SignalType::int8:
    case SignalType::int16:
    case SignalType::int32:
    case SignalType::int64:
      return Value(sign_extend(raw, s.bit_length));
    case SignalType::real32:
      return Value(static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(raw))));
    case SignalType::real64:
      return Value(std::bit_cast<double>(raw));
    default:
      return Value(raw);
  }
}

// The raw bits of a scalar (not bytes) field for `value`, range-checked.
Result<std::uint64_t> scalar_bits(const Signal& s, const Value& value) {
  switch (s.type) {
    case SignalType::real32: {
      const auto d = as_double(value);
      if (!d) return wrong_kind(s, value, "a number");
      if (std::isfinite(*d) && std::fabs(*d) > std::numeric_limits<float>::max()) {
        return Error(Errc::out_of_range,
                     fmt::format("signal '{}' (real32): value {} out of range ±{}", s.name, *d,
                                 std::numeric_limits<float>::max()));
      }
      return std::uint64_t{std::bit_cast<std::uint32_t>(static_cast<float>(*d))};
    }
    case SignalType::real64: {
      const auto d = as_double(value);
      if (!d) return wrong_kind(s, value, "a number");
      return std::bit_cast<std::uint64_t>(*d);
    }
    default:
      return integer_bits(s, value);
  }
}

// Why a signal is not a scalar field of 1..64 bits whose type holds its length (what
// decode_field / encode_field / store_field carry).
Error not_a_field(const Signal& s) {
  auto valid = validate_signal(s);
  if (!valid) return std::move(valid).error();
  return Error(Errc::unsupported,
               fmt::format("signal '{}' ({}, {} bits): not a scalar field of 1..64 bits", s.name,
                           to_string(s.type), s.bit_length));
}

bool field_usable(const Signal& s) noexcept {
  if (s.type == SignalType::bytes || s.bit_length == 0) return false;
  const std::uint16_t max = max_bit_length(s.type);
  if (s.bit_length > max) return false;
  return (s.type != SignalType::real32 && s.type != SignalType::real64) || s.bit_length == max;
}

}  // namespace

Result<Value> decode(const Signal& s, std::span<const std::uint8_t> image) {
  if (!usable(s, image.size())) return unusable(s, image.size());
  const std::uint8_t* data = image.data();
  if (s.type == SignalType::bytes) {
    std::vector<std::uint8_t> out((s.bit_length + 7u) / 8u);
    for (std::size_t i = 0; i < out.size(); ++i) {
      const auto take = static_cast<std::uint16_t>(std::min<std::size_t>(8, s.bit_length - 8 * i));
      out[i] = static_cast<std::uint8_t>(
          read_bits(data, s.bit_offset + static_cast<std::uint32_t>(8 * i), take));
    }
    return Value(std::move(out));
  }
  return scalar_value(s, read_bits(data, s.bit_offset, s.bit_length));
}

Result<void> encode(const Signal& s, const Value& value, std::span<std::uint8_t> image) {
  if (!usable(s, image.size())) return unusable(s, image.size());
  std::uint8_t* data = image.data();
  if (s.type == SignalType::bytes) {
    const auto* bytes = std::get_if<std::vector<std::uint8_t>>(&value);
    if (bytes == nullptr) return wrong_kind(s, value, "bytes");
    const std::size_t need = (s.bit_length + 7u) / 8u;
    if (bytes->size() != need) {
      return Error(Errc::invalid_argument,
                   fmt::format("signal '{}' (bytes, {} bits): {} bytes given, {} needed", s.name,
                               s.bit_length, bytes->size(), need));
    }
    for (std::size_t i = 0; i < need; ++i) {
      const auto take = static_cast<std::uint16_t>(std::min<std::size_t>(8, s.bit_length - 8 * i));
      if (take < 8 && ((*bytes)[i] >> take) != 0) {
        return Error(Errc::out_of_range,
                     fmt::format("signal '{}' (bytes, {} bits): last byte 0x{:02x} has bits "
                                 "beyond the field",
                                 s.name, s.bit_length, (*bytes)[i]));
      }
    }
    for (std::size_t i = 0; i < need; ++i) {
      const auto take = static_cast<std::uint16_t>(std::min<std::size_t>(8, s.bit_length - 8 * i));
      write_bits(data, s.bit_offset + static_cast<std::uint32_t>(8 * i), take, (*bytes)[i]);
    }
    return ok();
  }
  auto bits = scalar_bits(s, value);
  if (!bits) return std::move(bits).error();
  write_bits(data, s.bit_offset, s.bit_length, *bits);
  return ok();
}

bool store_bits(std::span<std::uint8_t> image, std::uint32_t bit_offset, std::uint16_t bit_length,
                std::uint64_t raw) noexcept {
  if (bit_length == 0 || bit_length > 64 ||
      std::size_t{bit_offset} + bit_length > 8 * image.size()) {
    return false;
  }
  write_bits(image.data(), bit_offset, bit_length, raw);
  return true;
}

Result<void> store_field(const Signal& s, std::uint64_t raw, std::span<std::uint8_t> image) {
  if (!field_usable(s)) return not_a_field(s);
  if (!usable(s, image.size())) return unusable(s, image.size());
  write_bits(image.data(), s.bit_offset, s.bit_length, raw);
  return ok();
}

// ---- scaling ----------------------------------------------------------------------------------

Value to_engineering(const Signal& s, const Value& raw) {
  if (!s.scale) return raw;
  if (std::holds_alternative<bool>(raw)) return raw;
  const auto d = as_double(raw);
  if (!d) return raw;
  return Value(*d * s.scale->factor + s.scale->offset);
}

Result<Value> from_engineering(const Signal& s, const Value& value) {
  if (!s.scale) return value;
  const auto d = as_double(value);
  if (!d || std::holds_alternative<bool>(value)) return wrong_kind(s, value, "a number");
  const auto& sc = *s.scale;
  if ((sc.minimum && *d < *sc.minimum) || (sc.maximum && *d > *sc.maximum) || !std::isfinite(*d)) {
    return Error(Errc::out_of_range,
                 fmt::format("signal '{}': value {}{}{} out of range {}..{}{}{}", s.name, *d,
                             s.unit.empty() ? "" : " ", s.unit,
                             sc.minimum ? fmt::format("{}", *sc.minimum) : "",
                             sc.maximum ? fmt::format("{}", *sc.maximum) : "",
                             s.unit.empty() ? "" : " ", s.unit));
  }
  const double raw = (*d - sc.offset) / sc.factor;
  if (s.type == SignalType::real32 || s.type == SignalType::real64) return Value(raw);
  return Value(std::round(raw));
}

Result<Value> decode_scaled(const Signal& s, std::span<const std::uint8_t> image) {
  auto raw = decode(s, image);
  if (!raw || !s.scale) return raw;
  return to_engineering(s, *raw);
}

Result<void> encode_scaled(const Signal& s, const Value& value, std::span<std::uint8_t> image) {
  if (!s.scale) return encode(s, value, image);
  auto raw = from_engineering(s, value);
  if (!raw) return std::move(raw).error();
  auto done = encode(s, *raw, image);
  if (!done) {
    return done.error().context(fmt::format("signal '{}': writing {}{}{}", s.name, to_string(value),
                                            s.unit.empty() ? "" : " ", s.unit));
  }
  return ok();
}

Result<Value> decode_field(const Signal& s, std::uint64_t raw) {
  if (!field_usable(s)) return not_a_field(s);
  if (s.bit_length < 64) raw &= (std::uint64_t{1} << s.bit_length) - 1;
  Value value = scalar_value(s, raw);
  if (!s.scale || s.type == SignalType::boolean) return value;
  return Value(*as_double(value) * s.scale->factor + s.scale->offset);
}

Result<std::uint64_t> encode_field(const Signal& s, const Value& value) {
  if (!field_usable(s)) return not_a_field(s);
  if (!s.scale) return scalar_bits(s, value);
  auto raw = from_engineering(s, value);
  if (!raw) return std::move(raw).error();
  auto bits = scalar_bits(s, *raw);
  if (!bits) {
    return bits.error().context(fmt::format("signal '{}': writing {}{}{}", s.name, to_string(value),
                                            s.unit.empty() ? "" : " ", s.unit));
  }
  return bits;
}

// ---- text -------------------------------------------------------------------------------------

namespace {

std::string_view trim(std::string_view text) {
  while (!text.empty() && std::isspace(static_cast<unsigned char>(text.front())) != 0)
    text.remove_prefix(1);
  while (!text.empty() && std::isspace(static_cast<unsigned char>(text.back())) != 0)
    text.remove_suffix(1);
  return text;
}

std::string lower(std::string_view text) {
  std::string out(text);
  for (auto& c : out)
    c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::optional<Value> parse_integer(std::string_view text) {
  bool negative = false;
  std::string_view digits = text;
  if (!digits.empty() && (digits.front() == '-' || digits.front() == '+')) {
    negative = digits.front() == '-';
    digits.remove_prefix(1);
  }
  int base = 10;
  if (digits.size() > 2 && digits[0] == '0' && (digits[1] == 'x' || digits[1] == 'X')) {
    base = 16;
    digits.remove_prefix(2);
  }
  if (digits.empty()) return std::nullopt;
  std::uint64_t magnitude = 0;
  const auto [end, ec] =
      std::from_chars(digits.data(), digits.data() + digits.size(), magnitude, base);
  if (ec != std::errc() || end != digits.data() + digits.size()) return std::nullopt;
  if (!negative) return Value(magnitude);
  constexpr auto kMinMagnitude = std::uint64_t{1} << 63;
  if (magnitude > kMinMagnitude) return std::nullopt;
  if (magnitude == kMinMagnitude) return Value(std::numeric_limits<std::int64_t>::min());
  return Value(-static_cast<std::int64_t>(magnitude));
}

std::optional<double> parse_real(std::string_view text) {
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
  return v;
}

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

}  // namespace

Result<Value> parse_value(const Signal& s, std::string_view raw_text) {
  const std::string_view text = trim(raw_text);
  auto bad = [&](std::string_view expected) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal '{}' ({}): cannot read \"{}\" as {}", s.name,
                             to_string(s.type), raw_text.substr(0, 64), expected));
  };
  if (s.type == SignalType::boolean) {
    const std::string t = lower(text);
    if (t == "true" || t == "1" || t == "on" || t == "yes") return Value(true);
    if (t == "false" || t == "0" || t == "off" || t == "no") return Value(false);
    return bad("a boolean (true/false, 1/0, on/off)");
  }
  if (s.type == SignalType::bytes) {
    std::vector<std::uint8_t> out;
    int high = -1;
    for (char c : text) {
      if (c == ' ' || c == ':' || c == '-') {
        if (high >= 0) return bad("hex bytes (\"0a0b\" or \"0a 0b\")");
        continue;
      }
      const int d = hex_digit(c);
      if (d < 0) return bad("hex bytes (\"0a0b\" or \"0a 0b\")");
      if (high < 0) {
        high = d;
      } else {
        out.push_back(static_cast<std::uint8_t>(high * 16 + d));
        high = -1;
      }
    }
    if (high >= 0 || out.empty()) return bad("hex bytes (\"0a0b\" or \"0a 0b\")");
    return Value(std::move(out));
  }
  if (s.scale || s.type == SignalType::real32 || s.type == SignalType::real64) {
    if (auto v = parse_real(text)) return Value(*v);
    if (auto i = parse_integer(text)) return Value(*as_double(*i));
    return bad("a number");
  }
  if (auto i = parse_integer(text)) return *i;
  return bad(is_signed(s.type) ? "an integer" : "an unsigned integer");
}

std::string snake_case(std::string_view text) {
  std::string out;
  bool gap = false;
  for (char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x80 && std::isalnum(u) != 0) {
      if (gap && !out.empty()) out += '_';
      gap = false;
      out += static_cast<char>(std::tolower(u));
    } else {
      gap = true;
    }
  }
  return out;
}

}  // namespace ecat::master
