// The one way ecat reads a file that came from outside (a ring file, an EEPROM image, an ESI
// description, a capture): regular files only, a size cap per kind, and a named error for
// everything else. Nothing here throws, blocks on a FIFO, or reads past the cap, so a path that
// names a directory, a device, a pipe fed by an endless stream or a huge file costs little and
// says what it is.
//
// Private to the library, the tool and the tests (not part of the installed headers).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>

namespace ecat {

enum class FileKind : std::uint8_t {
  ring,     // YAML ring file (master and simulator sections)
  eeprom,   // SII EEPROM image
  esi,      // ESI XML device description
  capture,  // pcap / pcapng capture
};

// "ring file", "EEPROM image", ...
std::string_view to_string(FileKind kind) noexcept;
// The largest file of this kind that is read, in bytes.
std::size_t max_file_bytes(FileKind kind) noexcept;

// Checks that `path` names a readable regular file no larger than the kind's cap, without reading
// it (for readers that open the file themselves, such as libpcap). Errors: not_found (absent),
// permission_denied (unreadable), invalid_argument (a directory, device, FIFO, socket or empty
// path), out_of_range (too large), io_error (anything else the system refused).
Result<void> check_regular_file(const std::string& path, FileKind kind);

// Reads the whole file, with the errors of check_regular_file. A file that grows past the cap
// while it is read is refused too.
Result<std::string> read_file(const std::string& path, FileKind kind);
Result<std::vector<std::uint8_t>> read_binary_file(const std::string& path, FileKind kind);

// "4 MiB", "1536 bytes": a size in words for messages.
std::string describe_size(std::uint64_t bytes);

}  // namespace ecat
