// Shared helpers of the mailbox protocol codecs: field-by-field reading with precise errors, text
// fields, and encoder argument errors. Private to src/wire.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <fmt/format.h>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire::detail {

// Reads named fields in sequence. The first field that does not fit fails the reader, later reads
// return zero, and error() names that field, its offset, and the bytes it needed and had. So a
// decoder reads all its fields, then checks ok() once.
class FieldReader {
 public:
  FieldReader(Bytes bytes, std::string_view what) noexcept : bytes_(bytes), what_(what) {}

  std::uint8_t u8(std::string_view field) noexcept {
    return take(field, 1) ? bytes_[pos_ - 1] : std::uint8_t{0};
  }
  std::uint16_t u16(std::string_view field) noexcept {
    return take(field, 2) ? load_le16(&bytes_[pos_ - 2]) : std::uint16_t{0};
  }
  std::uint32_t u32(std::string_view field) noexcept {
    return take(field, 4) ? load_le32(&bytes_[pos_ - 4]) : std::uint32_t{0};
  }
  Bytes bytes(std::string_view field, std::size_t n) noexcept {
    return take(field, n) ? bytes_.subspan(pos_ - n, n) : Bytes{};
  }
  // Everything not read yet (empty once failed).
  Bytes rest() noexcept {
    if (failed_) return {};
    Bytes r = bytes_.subspan(pos_);
    pos_ = bytes_.size();
    return r;
  }

  bool ok() const noexcept { return !failed_; }
  std::size_t position() const noexcept { return pos_; }
  std::size_t remaining() const noexcept { return bytes_.size() - pos_; }
  std::string_view what() const noexcept { return what_; }

  Error error() const {
    return Error(Errc::truncated,
                 fmt::format("{}: {} at offset {} needs {} byte{}, {} remain{}", what_, field_,
                             failed_at_, need_, need_ == 1 ? "" : "s", bytes_.size() - failed_at_,
                             bytes_.size() - failed_at_ == 1 ? "s" : ""));
  }

 private:
  bool take(std::string_view field, std::size_t n) noexcept {
    if (failed_) return false;
    if (n > bytes_.size() - pos_) {
      failed_ = true;
      field_ = field;
      failed_at_ = pos_;
      need_ = n;
      return false;
    }
    pos_ += n;
    return true;
  }

  Bytes bytes_;
  std::string_view what_;
  std::size_t pos_ = 0;
  bool failed_ = false;
  std::string_view field_;
  std::size_t failed_at_ = 0;
  std::size_t need_ = 0;
};

inline Error malformed(std::string_view what, std::string_view detail) {
  return Error(Errc::malformed, fmt::format("{}: {}", what, detail));
}
inline Error invalid_argument(std::string_view what, std::string_view detail) {
  return Error(Errc::invalid_argument, fmt::format("{}: {}", what, detail));
}
inline Error no_room(std::string_view what, std::size_t need, std::size_t have) {
  return Error(Errc::out_of_range,
               fmt::format("{}: needs {} bytes of buffer, {} left", what, need, have));
}

// A text field: the bytes up to the first NUL (senders may or may not terminate them).
inline std::string text_field(Bytes bytes) {
  auto end = std::find(bytes.begin(), bytes.end(), std::uint8_t{0});
  return std::string(bytes.begin(), end);
}
inline bool holds_nul(std::string_view text) noexcept {
  return text.find('\0') != std::string_view::npos;
}
inline Bytes as_bytes(std::string_view text) noexcept {
  return Bytes{reinterpret_cast<const std::uint8_t*>(text.data()), text.size()};
}

inline void append(std::vector<std::uint8_t>& out, Bytes bytes) {
  out.insert(out.end(), bytes.begin(), bytes.end());
}
inline void append_u16(std::vector<std::uint8_t>& out, std::uint16_t v) {
  out.push_back(static_cast<std::uint8_t>(v));
  out.push_back(static_cast<std::uint8_t>(v >> 8));
}
inline void append_u32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i)
    out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}

// Mailbox data is limited by the 16-bit length field.
constexpr std::size_t kMaxMailboxData = 0xFFFF;

}  // namespace ecat::wire::detail
