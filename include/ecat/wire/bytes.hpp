// Little-endian loads and stores, and bounds-checked readers and writers over byte spans.
// EtherCAT is little-endian throughout; every field access in the wire layer goes through here.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>

namespace ecat::wire {

using Bytes = std::span<const std::uint8_t>;
using MutableBytes = std::span<std::uint8_t>;

constexpr std::uint16_t load_le16(const std::uint8_t* p) noexcept {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
constexpr std::uint32_t load_le32(const std::uint8_t* p) noexcept {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
constexpr std::uint64_t load_le64(const std::uint8_t* p) noexcept {
  return static_cast<std::uint64_t>(load_le32(p)) |
         (static_cast<std::uint64_t>(load_le32(p + 4)) << 32);
}
constexpr std::uint16_t load_be16(const std::uint8_t* p) noexcept {
  return static_cast<std::uint16_t>((p[0] << 8) | p[1]);
}

constexpr void store_le16(std::uint8_t* p, std::uint16_t v) noexcept {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
constexpr void store_le32(std::uint8_t* p, std::uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
constexpr void store_le64(std::uint8_t* p, std::uint64_t v) noexcept {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
constexpr void store_be16(std::uint8_t* p, std::uint16_t v) noexcept {
  p[0] = static_cast<std::uint8_t>(v >> 8);
  p[1] = static_cast<std::uint8_t>(v);
}

// Reads fields in sequence. Reading past the end never touches memory out of bounds: it returns
// zero, and the reader stays failed (ok() == false) so a whole parse can be checked once at the
// end.
class ByteReader {
 public:
  explicit ByteReader(Bytes bytes) noexcept : bytes_(bytes) {}

  std::uint8_t u8() noexcept { return take(1) ? bytes_[pos_ - 1] : 0; }
  std::uint16_t u16() noexcept { return take(2) ? load_le16(&bytes_[pos_ - 2]) : 0; }
  std::uint32_t u32() noexcept { return take(4) ? load_le32(&bytes_[pos_ - 4]) : 0; }
  std::uint64_t u64() noexcept { return take(8) ? load_le64(&bytes_[pos_ - 8]) : 0; }
  std::int16_t i16() noexcept { return static_cast<std::int16_t>(u16()); }
  std::int32_t i32() noexcept { return static_cast<std::int32_t>(u32()); }
  std::int64_t i64() noexcept { return static_cast<std::int64_t>(u64()); }
  // A sub-span of n bytes; empty (and the reader failed) when fewer remain.
  Bytes bytes(std::size_t n) noexcept { return take(n) ? bytes_.subspan(pos_ - n, n) : Bytes{}; }
  void skip(std::size_t n) noexcept { (void)take(n); }

  bool ok() const noexcept { return ok_; }
  std::size_t position() const noexcept { return pos_; }
  std::size_t remaining() const noexcept { return bytes_.size() - pos_; }
  Bytes rest() const noexcept { return bytes_.subspan(pos_); }

 private:
  bool take(std::size_t n) noexcept {
    if (!ok_ || n > bytes_.size() - pos_) {
      ok_ = false;
      return false;
    }
    pos_ += n;
    return true;
  }
  Bytes bytes_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

// Writes fields in sequence into a caller-owned buffer; never allocates. Writing past the end
// writes nothing and leaves the writer failed (ok() == false).
class ByteWriter {
 public:
  explicit ByteWriter(MutableBytes buffer) noexcept : buffer_(buffer) {}

  void u8(std::uint8_t v) noexcept {
    if (auto* p = take(1)) *p = v;
  }
  void u16(std::uint16_t v) noexcept {
    if (auto* p = take(2)) store_le16(p, v);
  }
  void u32(std::uint32_t v) noexcept {
    if (auto* p = take(4)) store_le32(p, v);
  }
  void u64(std::uint64_t v) noexcept {
    if (auto* p = take(8)) store_le64(p, v);
  }
  void bytes(Bytes data) noexcept {
    if (data.empty()) return;
    if (auto* p = take(data.size())) std::memcpy(p, data.data(), data.size());
  }
  void zeros(std::size_t n) noexcept {
    if (auto* p = take(n)) std::memset(p, 0, n);
  }
  // Reserves n bytes and returns them for the caller to fill (empty span on overflow).
  MutableBytes reserve(std::size_t n) noexcept {
    auto* p = take(n);
    return p ? MutableBytes{p, n} : MutableBytes{};
  }

  bool ok() const noexcept { return ok_; }
  std::size_t size() const noexcept { return pos_; }
  std::size_t remaining() const noexcept { return buffer_.size() - pos_; }
  Bytes written() const noexcept { return Bytes{buffer_.data(), pos_}; }

 private:
  std::uint8_t* take(std::size_t n) noexcept {
    if (!ok_ || n > buffer_.size() - pos_) {
      ok_ = false;
      return nullptr;
    }
    pos_ += n;
    return buffer_.data() + pos_ - n;
  }
  MutableBytes buffer_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

}  // namespace ecat::wire
