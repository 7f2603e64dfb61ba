#include <atomic>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <new>
#include <random>

#include <gtest/gtest.h>

#include <ecat/master/signal.hpp>

#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::master {
namespace {

Signal field(SignalType type, std::uint32_t offset, std::uint16_t bits, std::string name = "sig") {
  Signal s;
  s.name = std::move(name);
  s.type = type;
  s.bit_offset = offset;
  s.bit_length = bits;
  return s;
}

// Reference bit access, one bit at a time (independent of the codec's byte paths).
std::uint64_t reference_read(const std::vector<std::uint8_t>& image, std::uint32_t off,
                             std::uint16_t bits) {
  std::uint64_t v = 0;
  for (std::uint16_t k = 0; k < bits; ++k) {
    const std::uint32_t b = off + k;
    if ((image[b / 8] >> (b % 8)) & 1u) v |= std::uint64_t{1} << k;
  }
  return v;
}

// The image with the field's bits cleared, to compare what lies around a field.
std::vector<std::uint8_t> outside(std::vector<std::uint8_t> image, std::uint32_t off,
                                  std::uint16_t bits) {
  for (std::uint16_t k = 0; k < bits; ++k) {
    const std::uint32_t b = off + k;
    image[b / 8] = static_cast<std::uint8_t>(image[b / 8] & ~(1u << (b % 8)));
  }
  return image;
}

std::vector<std::uint8_t> noise(std::size_t size, std::mt19937_64& rng) {
  std::vector<std::uint8_t> image(size);
  for (auto& b : image)
    b = static_cast<std::uint8_t>(rng());
  return image;
}

TEST(SignalCodec, UnsignedRoundTripEveryLengthAndOffset) {
  std::mt19937_64 rng(1);
  for (std::uint16_t bits = 1; bits <= 64; ++bits) {
    const SignalType type = bits <= 8    ? SignalType::uint8
                            : bits <= 16 ? SignalType::uint16
                            : bits <= 32 ? SignalType::uint32
                                         : SignalType::uint64;
    const std::uint64_t max = bits == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1;
    for (std::uint32_t off = 0; off < 8; ++off) {
      const Signal s = field(type, off + 8, bits);
      for (std::uint64_t value : {std::uint64_t{0}, max, rng() & max, rng() & max}) {
        auto image = noise(12, rng);
        const auto before = outside(image, s.bit_offset, bits);
        ASSERT_TRUE(encode(s, Value(value), image).ok()) << bits << "@" << off;
        EXPECT_EQ(reference_read(image, s.bit_offset, bits), value) << bits << "@" << off;
        EXPECT_EQ(outside(image, s.bit_offset, bits), before) << bits << "@" << off;
        auto back = decode(s, image);
        ASSERT_TRUE(back.ok());
        EXPECT_EQ(*back, Value(value)) << bits << "@" << off;
      }
      if (bits < 64) {
        auto image = noise(12, rng);
        const auto copy = image;
        auto too_big = encode(s, Value(max + 1), image);
        ASSERT_FALSE(too_big.ok());
        EXPECT_EQ(too_big.error().code(), Errc::out_of_range);
        EXPECT_EQ(image, copy);
      }
    }
  }
}

TEST(SignalCodec, SignedRoundTripEveryLengthAndOffset) {
  std::mt19937_64 rng(2);
  for (std::uint16_t bits = 1; bits <= 64; ++bits) {
    const SignalType type = bits <= 8    ? SignalType::int8
                            : bits <= 16 ? SignalType::int16
                            : bits <= 32 ? SignalType::int32
                                         : SignalType::int64;
    const std::int64_t max =
        bits == 64 ? std::numeric_limits<std::int64_t>::max() : (std::int64_t{1} << (bits - 1)) - 1;
    const std::int64_t min = -max - 1;
    for (std::uint32_t off = 0; off < 8; ++off) {
      const Signal s = field(type, off, bits);
      const auto r = static_cast<std::int64_t>(rng());
      const std::int64_t random = bits == 64 ? r : (r % (max + 1));
      for (std::int64_t value :
           {std::int64_t{0}, max, min, std::int64_t{-1} * (bits > 1), random}) {
        auto image = noise(10, rng);
        const auto before = outside(image, off, bits);
        ASSERT_TRUE(encode(s, Value(value), image).ok()) << bits << "@" << off << " " << value;
        EXPECT_EQ(outside(image, off, bits), before);
        auto back = decode(s, image);
        ASSERT_TRUE(back.ok());
        EXPECT_EQ(*back, Value(value)) << bits << "@" << off;
      }
      if (bits < 64) {
        auto image = noise(10, rng);
        EXPECT_FALSE(encode(s, Value(max + 1), image).ok());
        EXPECT_FALSE(encode(s, Value(min - 1), image).ok());
      }
    }
  }
}

TEST(SignalCodec, BooleanRealAndBytesAtOddOffsets) {
  std::mt19937_64 rng(3);
  for (std::uint32_t off = 0; off < 8; ++off) {
    auto image = noise(20, rng);
    const Signal b = field(SignalType::boolean, off, 1);
    for (bool v : {true, false}) {
      ASSERT_TRUE(encode(b, Value(v), image).ok());
      EXPECT_EQ(*decode(b, image), Value(v));
      EXPECT_EQ(reference_read(image, off, 1), v ? 1u : 0u);
    }
    const Signal f = field(SignalType::real32, off + 3, 32);
    ASSERT_TRUE(encode(f, Value(-21.5), image).ok());
    EXPECT_EQ(*decode(f, image), Value(-21.5));
    EXPECT_EQ(reference_read(image, off + 3, 32), std::bit_cast<std::uint32_t>(-21.5f));
    const Signal d = field(SignalType::real64, off + 40, 64);
    ASSERT_TRUE(encode(d, Value(3.141592653589793), image).ok());
    EXPECT_EQ(*decode(d, image), Value(3.141592653589793));
    EXPECT_EQ(*decode(f, image), Value(-21.5));  // the neighbour is untouched
    for (std::uint16_t bits = 1; bits <= 40; ++bits) {
      const Signal x = field(SignalType::bytes, off + 104, bits);
      std::vector<std::uint8_t> bytes((bits + 7) / 8);
      for (auto& byte : bytes)
        byte = static_cast<std::uint8_t>(rng());
      if (bits % 8 != 0)
        bytes.back() = static_cast<std::uint8_t>(bytes.back() & ((1u << (bits % 8)) - 1));
      const auto before = outside(image, off + 104, bits);
      ASSERT_TRUE(encode(x, Value(bytes), image).ok()) << bits;
      EXPECT_EQ(outside(image, off + 104, bits), before);
      EXPECT_EQ(*decode(x, image), Value(bytes)) << bits << "@" << off;
    }
  }
}

TEST(SignalCodec, KnownLayoutLsbFirstLittleEndian) {
  std::vector<std::uint8_t> image{0x00, 0x00, 0x00, 0x00};
  ASSERT_TRUE(encode(field(SignalType::uint16, 4, 12), Value(std::uint64_t{0xABC}), image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0xC0, 0xAB, 0x00, 0x00}));
  ASSERT_TRUE(encode(field(SignalType::int16, 16, 16), Value(std::int64_t{-2}), image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0xC0, 0xAB, 0xFE, 0xFF}));
  EXPECT_EQ(*decode(field(SignalType::int8, 4, 4), image), Value(std::int64_t{-4}));
  EXPECT_EQ(*decode(field(SignalType::boolean, 7, 1), image), Value(true));
  EXPECT_EQ(*decode(field(SignalType::boolean, 0, 1), image), Value(false));
}

TEST(SignalCodec, ErrorsNameSignalValueAndRange) {
  std::vector<std::uint8_t> image(2, 0x5A);
  const auto copy = image;
  auto e =
      encode(field(SignalType::uint8, 0, 8, "channel_3.level"), Value(std::int64_t{256}), image);
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.error().message(),
            "signal 'channel_3.level' (uint8, 8 bits): value 256 out of range 0..255");
  auto n = encode(field(SignalType::int16, 0, 12, "t"), Value(std::int64_t{-2049}), image);
  ASSERT_FALSE(n.ok());
  EXPECT_EQ(n.error().message(),
            "signal 't' (int16, 12 bits): value -2049 out of range -2048..2047");
  auto frac = encode(field(SignalType::int16, 0, 16, "t"), Value(1.5), image);
  ASSERT_FALSE(frac.ok());
  EXPECT_EQ(frac.error().message(), "signal 't' (int16): value 1.5 is not an integer");
  EXPECT_FALSE(encode(field(SignalType::uint8, 0, 8), Value(std::int64_t{-1}), image).ok());
  EXPECT_FALSE(encode(field(SignalType::uint8, 0, 8), Value(std::string("x")), image).ok());
  EXPECT_FALSE(encode(field(SignalType::boolean, 0, 1), Value(std::int64_t{2}), image).ok());
  EXPECT_FALSE(
      encode(field(SignalType::bytes, 0, 12), Value(std::vector<std::uint8_t>{1}), image).ok());
  EXPECT_FALSE(
      encode(field(SignalType::bytes, 0, 12), Value(std::vector<std::uint8_t>{1, 0x10}), image)
          .ok());
  EXPECT_FALSE(encode(field(SignalType::real32, 0, 16), Value(1.0), image).ok());
  EXPECT_EQ(image, copy);
  // Exact values from other alternatives are accepted.
  EXPECT_TRUE(encode(field(SignalType::uint8, 0, 8), Value(200.0), image).ok());
  EXPECT_TRUE(encode(field(SignalType::boolean, 0, 1), Value(std::uint64_t{1}), image).ok());
  EXPECT_TRUE(encode(field(SignalType::int8, 8, 8), Value(std::uint64_t{127}), image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0xC9, 0x7F}));
}

TEST(SignalCodec, FieldsOutsideTheImageFailWithoutTouchingIt) {
  std::vector<std::uint8_t> image(4, 0);
  auto d = decode(field(SignalType::uint16, 20, 16, "late"), image);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().message(),
            "signal 'late': bits 20..35 lie outside the 4-byte image of SyncManager 0");
  EXPECT_FALSE(encode(field(SignalType::uint16, 20, 16), Value(std::uint64_t{1}), image).ok());
  EXPECT_FALSE(decode(field(SignalType::uint8, 0, 9), image).ok());
  EXPECT_FALSE(decode(field(SignalType::uint8, 0, 0), image).ok());
  EXPECT_FALSE(decode(field(SignalType::uint8, 0xFFFFFFF0u, 8), image).ok());
  EXPECT_EQ(image, std::vector<std::uint8_t>(4, 0));
  EXPECT_TRUE(validate_signal(field(SignalType::uint16, 16, 16), 4).ok());
  EXPECT_FALSE(validate_signal(field(SignalType::uint16, 17, 16), 4).ok());
}

TEST(SignalCodec, ScalarCodecsDoNotAllocate) {
  std::vector<std::uint8_t> image(16, 0);
  const Signal u = field(SignalType::uint32, 3, 27);
  const Signal i = field(SignalType::int16, 40, 16);
  const Signal r = field(SignalType::real64, 64, 64);
  Signal t = field(SignalType::int16, 40, 16);
  t.scale = LinearScale{0.1, 0.0, std::nullopt, std::nullopt};
  const auto before = allocs::total.load();
  double sum = 0;
  for (int k = 0; k < 1000; ++k) {
    if (!encode(u, Value(std::uint64_t(k)), image).ok()) std::abort();
    if (!encode(i, Value(std::int64_t{-k}), image).ok()) std::abort();
    if (!encode(r, Value(k * 0.5), image).ok()) std::abort();
    if (!encode_scaled(t, Value(k * 0.1), image).ok()) std::abort();
    sum += *as_double(*decode(u, image)) + *as_double(*decode(i, image)) +
           *as_double(*decode(r, image)) + *as_double(*decode_scaled(t, image));
  }
  EXPECT_EQ(allocs::total.load() - before, 0u);
  EXPECT_GT(sum, 0);
}

// The field codecs (the hot path's) agree with the image codecs for every scalar type, length
// and offset: encode_field + store_field writes what encode_scaled writes, decode_field of the
// field's bits reads what decode_scaled reads, and they round-trip.
TEST(SignalFieldCodec, AgreesWithTheImageCodecsAndRoundTrips) {
  std::mt19937_64 rng(17);
  const SignalType types[] = {SignalType::boolean, SignalType::int8,   SignalType::int16,
                              SignalType::int32,   SignalType::int64,  SignalType::uint8,
                              SignalType::uint16,  SignalType::uint32, SignalType::uint64,
                              SignalType::real32,  SignalType::real64};
  for (const SignalType type : types) {
    const std::uint16_t max = max_bit_length(type);
    const bool real = type == SignalType::real32 || type == SignalType::real64;
    for (std::uint16_t bits = real ? max : 1; bits <= max; ++bits) {
      for (std::uint32_t off : {0u, 3u, 8u, 13u}) {
        for (bool scaled : {false, true}) {
          // Scaled: not booleans (a scale does not apply to them), and only as wide as a double
          // holds exactly.
          if (scaled && (type == SignalType::boolean || (!real && bits > 48))) continue;
          Signal s = field(type, off, bits);
          if (scaled) s.scale = LinearScale{0.5, -2.0, std::nullopt, std::nullopt};
          auto image = noise(12, rng);
          auto expected = image;
          const std::uint64_t mask =
              bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1;
          // A raw pattern the field holds, read back through both codecs.
          const std::uint64_t raw_pattern =
              real ? (type == SignalType::real32
                          ? std::uint64_t{std::bit_cast<std::uint32_t>(
                                static_cast<float>(rng() % 1000) / 4)}
                          : std::bit_cast<std::uint64_t>(static_cast<double>(rng() % 1000) / 4))
                   : rng() & mask;
          // A boolean reads any non-zero field as true and writes true as 1: round-trips 0/1.
          const std::uint64_t raw_in = type == SignalType::boolean ? raw_pattern & 1u : raw_pattern;
          ASSERT_TRUE(store_field(s, raw_in, expected).ok());
          EXPECT_EQ(reference_read(expected, off, bits), raw_in);
          EXPECT_EQ(outside(expected, off, bits), outside(image, off, bits));
          auto via_image = decode_scaled(s, expected);
          auto via_field = decode_field(s, raw_in | (bits < 64 ? ~mask : 0));  // high bits ignored
          ASSERT_TRUE(via_image.ok() && via_field.ok()) << to_string(type) << bits;
          EXPECT_EQ(*via_image, *via_field) << to_string(type) << " " << bits << "@" << off;
          // Round trip: the value read encodes to the same bits, as encode_scaled writes them.
          auto back = encode_field(s, *via_field);
          ASSERT_TRUE(back.ok()) << to_string(type) << bits << " " << back.error().describe();
          EXPECT_EQ(*back, raw_in) << to_string(type) << " " << bits << "@" << off;
          auto written = image;
          ASSERT_TRUE(encode_scaled(s, *via_field, written).ok());
          EXPECT_EQ(written, expected);
        }
      }
    }
  }
}

TEST(SignalFieldCodec, ErrorsAsTheImageCodecs) {
  std::vector<std::uint8_t> image(4, 0);
  const Signal u8 = field(SignalType::uint8, 0, 8, "channel_3.level");
  auto big = encode_field(u8, Value(std::int64_t{256}));
  ASSERT_FALSE(big.ok());
  auto big_image = encode(u8, Value(std::int64_t{256}), image);
  EXPECT_EQ(big.error().message(), big_image.error().message());
  EXPECT_EQ(big.error().code(), Errc::out_of_range);
  EXPECT_FALSE(encode_field(u8, Value(std::string("x"))).ok());
  Signal v = field(SignalType::int16, 0, 16, "channel_1.output");
  v.unit = "V";
  v.scale = LinearScale{10.0 / 32767.0, 0.0, 0.0, 10.0};
  auto high = encode_field(v, Value(10.5));
  ASSERT_FALSE(high.ok());
  EXPECT_EQ(high.error().message(), "signal 'channel_1.output': value 10.5 V out of range 0..10 V");
  // Not scalar fields: bytes, too long for the type, outside the image.
  auto bytes = decode_field(field(SignalType::bytes, 0, 16, "blob"), 0);
  ASSERT_FALSE(bytes.ok());
  EXPECT_EQ(bytes.error().code(), Errc::unsupported);
  EXPECT_NE(bytes.error().message().find("blob"), std::string::npos);
  EXPECT_FALSE(encode_field(field(SignalType::uint8, 0, 9), Value(std::uint64_t{1})).ok());
  EXPECT_FALSE(decode_field(field(SignalType::real32, 0, 16), 0).ok());
  EXPECT_FALSE(store_field(field(SignalType::uint16, 24, 16), 1, image).ok());
  EXPECT_EQ(image, std::vector<std::uint8_t>(4, 0));
}

TEST(SignalFieldCodec, DoesNotAllocate) {
  Signal t = field(SignalType::int16, 40, 16);
  t.scale = LinearScale{0.1, 0.0, std::nullopt, std::nullopt};
  const Signal u = field(SignalType::uint32, 3, 27);
  std::vector<std::uint8_t> image(16, 0);
  const auto before = allocs::total.load();
  double sum = 0;
  for (int k = 0; k < 1000; ++k) {
    auto a = encode_field(t, Value(k * 0.1));
    auto b = encode_field(u, Value(std::uint64_t(k)));
    if (!a || !b || !store_field(u, *b, image)) std::abort();
    sum += *as_double(*decode_field(t, *a)) + *as_double(*decode_field(u, *b));
  }
  EXPECT_EQ(allocs::total.load() - before, 0u);
  EXPECT_GT(sum, 0);
}

TEST(SignalScale, EngineeringValuesAndLimits) {
  Signal v = field(SignalType::int16, 0, 16, "channel_1.output");
  v.unit = "V";
  v.scale = LinearScale{10.0 / 32767.0, 0.0, 0.0, 10.0};
  std::vector<std::uint8_t> image(2, 0);
  ASSERT_TRUE(encode_scaled(v, Value(10.0), image).ok());
  EXPECT_EQ(*decode(v, image), Value(std::int64_t{32767}));
  EXPECT_EQ(*decode_scaled(v, image), Value(10.0));
  ASSERT_TRUE(encode_scaled(v, Value(std::int64_t{5}), image).ok());
  EXPECT_EQ(*decode(v, image), Value(std::int64_t{16384}));  // 16383.5 rounds away from zero
  auto high = encode_scaled(v, Value(10.5), image);
  ASSERT_FALSE(high.ok());
  EXPECT_EQ(high.error().message(), "signal 'channel_1.output': value 10.5 V out of range 0..10 V");
  EXPECT_FALSE(encode_scaled(v, Value(std::string("5")), image).ok());
  EXPECT_EQ(*decode(v, image), Value(std::int64_t{16384}));

  Signal t = field(SignalType::int16, 0, 16, "t");
  t.scale = LinearScale{0.1, 0.0, std::nullopt, std::nullopt};
  EXPECT_EQ(to_engineering(t, Value(std::int64_t{215})), Value(21.5));
  EXPECT_EQ(*from_engineering(t, Value(-12.34)), Value(-123.0));
  EXPECT_FALSE(encode_scaled(t, Value(4000.0), image).ok());  // raw 40000 exceeds int16
  Signal bad = t;
  bad.scale->factor = 0;
  EXPECT_FALSE(validate_signal(bad).ok());
}

TEST(SignalValue, ConversionsAndText) {
  EXPECT_EQ(to_string(Value(true)), "true");
  EXPECT_EQ(to_string(Value(std::int64_t{-12})), "-12");
  EXPECT_EQ(to_string(Value(std::uint64_t{4096})), "4096");
  EXPECT_EQ(to_string(Value(21.5)), "21.5");
  EXPECT_EQ(to_string(Value(std::string("csp"))), "\"csp\"");
  EXPECT_EQ(to_string(Value(std::vector<std::uint8_t>{0x0a, 0xff})), "0a ff");
  EXPECT_EQ(as_int64(Value(std::uint64_t{1} << 63)), std::nullopt);
  EXPECT_EQ(as_int64(Value(-3.0)), -3);
  EXPECT_EQ(as_int64(Value(9.3e18)), std::nullopt);
  EXPECT_EQ(as_uint64(Value(std::int64_t{-1})), std::nullopt);
  EXPECT_EQ(as_uint64(Value(1.8446744073709552e19)), std::nullopt);
  EXPECT_EQ(as_bool(Value(std::int64_t{1})), true);
  EXPECT_EQ(as_bool(Value(std::int64_t{2})), std::nullopt);
  EXPECT_EQ(as_double(Value(std::string("1"))), std::nullopt);
}

TEST(SignalValue, ParseText) {
  const Signal b = field(SignalType::boolean, 0, 1, "b");
  EXPECT_EQ(*parse_value(b, " On "), Value(true));
  EXPECT_EQ(*parse_value(b, "0"), Value(false));
  EXPECT_FALSE(parse_value(b, "maybe").ok());
  const Signal i = field(SignalType::int32, 0, 32, "i");
  EXPECT_EQ(*parse_value(i, "-42"), Value(std::int64_t{-42}));
  EXPECT_EQ(*parse_value(i, "0x10"), Value(std::uint64_t{16}));
  EXPECT_EQ(*parse_value(i, "-9223372036854775808"),
            Value(std::numeric_limits<std::int64_t>::min()));
  EXPECT_FALSE(parse_value(i, "-9223372036854775809").ok());
  EXPECT_FALSE(parse_value(i, "12abc").ok());
  EXPECT_FALSE(parse_value(i, "").ok());
  auto bad = parse_value(i, "1.5");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(), "signal 'i' (int32): cannot read \"1.5\" as an integer");
  const Signal r = field(SignalType::real32, 0, 32, "r");
  EXPECT_EQ(*parse_value(r, "2.5e1"), Value(25.0));
  EXPECT_EQ(*parse_value(r, "7"), Value(7.0));
  Signal scaled = field(SignalType::int16, 0, 16, "s");
  scaled.scale = LinearScale{};
  EXPECT_EQ(*parse_value(scaled, "1.25"), Value(1.25));
  const Signal x = field(SignalType::bytes, 0, 24, "x");
  EXPECT_EQ(*parse_value(x, "0a 0B:ff"), Value(std::vector<std::uint8_t>{0x0a, 0x0b, 0xff}));
  EXPECT_FALSE(parse_value(x, "0a0").ok());
  EXPECT_FALSE(parse_value(x, "zz").ok());
}

TEST(SignalNames, SnakeCaseAndTypes) {
  EXPECT_EQ(snake_case("Channel 1"), "channel_1");
  EXPECT_EQ(snake_case("Status__Underrange"), "status_underrange");
  EXPECT_EQ(snake_case("AO RxPDO-Map Outputs Ch.1"), "ao_rxpdo_map_outputs_ch_1");
  EXPECT_EQ(snake_case("  Temp (\xb5V) "), "temp_v");
  EXPECT_EQ(snake_case("--"), "");
  EXPECT_EQ(signal_type_for(coe_type::kBoolean, 1), SignalType::boolean);
  EXPECT_EQ(signal_type_for(coe_type::kInteger24, 24), SignalType::int32);
  EXPECT_EQ(signal_type_for(0x0031, 2), SignalType::uint8);  // BIT2
  EXPECT_EQ(signal_type_for(coe_type::kUnsigned8, 16), SignalType::uint16);
  EXPECT_EQ(signal_type_for(coe_type::kInteger8, 16), SignalType::int16);
  EXPECT_EQ(signal_type_for(coe_type::kReal32, 32), SignalType::real32);
  EXPECT_EQ(signal_type_for(coe_type::kReal32, 16), SignalType::uint16);
  EXPECT_EQ(signal_type_for(coe_type::kNone, 1), SignalType::boolean);
  EXPECT_EQ(signal_type_for(coe_type::kNone, 12), SignalType::uint16);
  EXPECT_EQ(signal_type_for(coe_type::kNone, 72), SignalType::bytes);
  EXPECT_EQ(signal_type_for(coe_type::kVisibleString, 64), SignalType::bytes);
}

TEST(SignalForEntry, TakesOffsetAndTypeFromTheLayout) {
  Pdo pdo{
      0x1A00,
      PdoDirection::input,
      3,
      "In",
      {{0x6000, 1, 1, coe_type::kBoolean, "A", 0}, {0x6000, 2, 16, coe_type::kInteger16, "B", 0}}};
  auto layout = make_pdo_layout({pdo});
  ASSERT_TRUE(layout.ok());
  auto s = signal_for_entry(*layout, 0x6000, 2, "b");
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->bit_offset, 1u);
  EXPECT_EQ(s->bit_length, 16);
  EXPECT_EQ(s->type, SignalType::int16);
  EXPECT_EQ(s->sync_manager, 3);
  EXPECT_EQ(s->pdo_index, 0x1A00);
  auto missing = signal_for_entry(*layout, 0x6000, 3, "c");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().message(),
            "signal 'c': object 0x6000:03 is not mapped in any assigned PDO");
}

}  // namespace
}  // namespace ecat::master
