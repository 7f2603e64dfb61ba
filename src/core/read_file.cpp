#include "core/read_file.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

namespace ecat {

namespace {

// The caps are generous for real files and small enough that a wrong path costs little: the
// largest vendor ESI files (a whole product family in one XML) are tens of MiB; the SII's size
// word can state at most 8 MiB of EEPROM; ring files are hand-written or generated text.
constexpr std::size_t kMiB = std::size_t{1} << 20;

// Closes a descriptor on every path out of a reader.
class Descriptor {
 public:
  explicit Descriptor(int fd) noexcept : fd_(fd) {}
  ~Descriptor() {
    if (fd_ >= 0) ::close(fd_);
  }
  Descriptor(const Descriptor&) = delete;
  Descriptor& operator=(const Descriptor&) = delete;
  int get() const noexcept { return fd_; }

 private:
  int fd_;
};

// "a ring file", "an ESI file".
std::string with_article(FileKind kind) {
  const std::string_view noun = to_string(kind);
  const bool vowel = noun.front() == 'E' || noun.front() == 'S';  // "an ESI", "an SII" (ess-)
  return fmt::format("{} {}", vowel ? "an" : "a", noun);
}

Error open_error(const std::string& path, FileKind kind, int error) {
  switch (error) {
    case ENOENT:
    case ENOTDIR:
      return Error(Errc::not_found, fmt::format("{}: no such {}", path, to_string(kind)));
    case EACCES:
    case EPERM:
      return Error(
          Errc::permission_denied,
          fmt::format("{}: the {} cannot be read (permission denied)", path, to_string(kind)));
    default:
      return Error(Errc::io_error, fmt::format("{}: cannot open the {}: {}", path, to_string(kind),
                                               std::strerror(error)));
  }
}

// Everything but a regular file of at most the cap is refused, by what it is.
Result<void> check_stat(const std::string& path, FileKind kind, const struct stat& st) {
  const char* what = nullptr;
  if (S_ISDIR(st.st_mode)) {
    what = "a directory";
  } else if (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode)) {
    what = "a device";
  } else if (S_ISFIFO(st.st_mode)) {
    what = "a FIFO (named pipe)";
  } else if (S_ISSOCK(st.st_mode)) {
    what = "a socket";
  } else if (!S_ISREG(st.st_mode)) {
    what = "not a regular file";  // unreachable on Linux, kept for exotic file types
  }
  if (what != nullptr) {
    return Error(Errc::invalid_argument, fmt::format("{}: is {}; {} must be a regular file", path,
                                                     what, with_article(kind)));
  }
  const auto size = static_cast<std::uint64_t>(st.st_size);
  if (size > max_file_bytes(kind)) {
    return Error(Errc::out_of_range, fmt::format("{}: {} is too large for {} (at most {} are read)",
                                                 path, describe_size(size), with_article(kind),
                                                 describe_size(max_file_bytes(kind))));
  }
  return ok();
}

Result<void> check_path(const std::string& path, FileKind kind) {
  if (path.empty()) {
    return Error(Errc::invalid_argument, fmt::format("no {} named (empty path)", to_string(kind)));
  }
  if (path.find('\0') != std::string::npos) {
    return Error(Errc::invalid_argument,
                 fmt::format("the {} path contains a NUL character", to_string(kind)));
  }
  return ok();
}

template <class Buffer>
Result<Buffer> read_into(const std::string& path, FileKind kind) {
  if (auto valid = check_path(path, kind); !valid) return valid.error();
  // O_NONBLOCK: opening a FIFO without a writer must not wait; a regular file ignores the flag.
  Descriptor fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK));
  if (fd.get() < 0) return open_error(path, kind, errno);
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) return open_error(path, kind, errno);
  if (auto regular = check_stat(path, kind, st); !regular) return regular.error();

  const std::size_t cap = max_file_bytes(kind);
  Buffer out;
  out.resize(static_cast<std::size_t>(st.st_size));
  std::size_t filled = 0;
  for (;;) {
    if (filled == out.size()) {
      // The file may have grown since fstat: read on, one chunk at a time, up to the cap + 1.
      if (out.size() > cap) {
        return Error(Errc::out_of_range,
                     fmt::format("{}: grew past {} while it was read (too large for {})", path,
                                 describe_size(cap), with_article(kind)));
      }
      out.resize(std::min(cap + 1, out.size() + 65536));
    }
    const ssize_t n = ::read(fd.get(), out.data() + filled, out.size() - filled);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Error(Errc::io_error, fmt::format("{}: reading the {} failed: {}", path,
                                               to_string(kind), std::strerror(errno)));
    }
    if (n == 0) break;
    filled += static_cast<std::size_t>(n);
  }
  out.resize(filled);
  return out;
}

}  // namespace

std::string_view to_string(FileKind kind) noexcept {
  switch (kind) {
    case FileKind::ring:
      return "ring file";
    case FileKind::eeprom:
      return "SII EEPROM image";
    case FileKind::esi:
      return "ESI file";
    case FileKind::capture:
      return "capture";
  }
  return "file";
}

std::size_t max_file_bytes(FileKind kind) noexcept {
  switch (kind) {
    case FileKind::ring:
      return 4 * kMiB;
    case FileKind::eeprom:
      return 8 * kMiB;
    case FileKind::esi:
      return 64 * kMiB;
    case FileKind::capture:
      return 1024 * kMiB;
  }
  return 0;
}

std::string describe_size(std::uint64_t bytes) {
  if (bytes >= kMiB && bytes % kMiB == 0) return fmt::format("{} MiB", bytes / kMiB);
  if (bytes >= 1024 && bytes % 1024 == 0) return fmt::format("{} KiB", bytes / 1024);
  return fmt::format("{} bytes", bytes);
}

Result<void> check_regular_file(const std::string& path, FileKind kind) {
  if (auto valid = check_path(path, kind); !valid) return valid.error();
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return open_error(path, kind, errno);
  if (auto regular = check_stat(path, kind, st); !regular) return regular.error();
  if (::access(path.c_str(), R_OK) != 0) return open_error(path, kind, errno);
  return ok();
}

Result<std::string> read_file(const std::string& path, FileKind kind) {
  return read_into<std::string>(path, kind);
}

Result<std::vector<std::uint8_t>> read_binary_file(const std::string& path, FileKind kind) {
  return read_into<std::vector<std::uint8_t>>(path, kind);
}

}  // namespace ecat
