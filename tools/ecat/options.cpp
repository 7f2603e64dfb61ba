#include <charconv>
#include <cmath>
#include <optional>
#include <string>
#include <string_view>

#include <fmt/format.h>

#include "command.hpp"

namespace ecat::tool {

namespace {

// Parses the whole text as a finite number: decimal, exponent or 0x hex integer.
std::optional<double> parse_finite(std::string_view text) {
  if (text.empty() || text.size() > 64) return std::nullopt;
  double value = 0;
  if (text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X')) {
    unsigned long long integer = 0;
    const auto [end, ec] = std::from_chars(text.data() + 2, text.data() + text.size(), integer, 16);
    if (ec != std::errc() || end != text.data() + text.size()) return std::nullopt;
    value = static_cast<double>(integer);
  } else {
    if (text.front() == '+') text.remove_prefix(1);
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (ec != std::errc() || end != text.data() + text.size()) return std::nullopt;
  }
  if (!std::isfinite(value)) return std::nullopt;
  return value;
}

// 31536000 rather than 3.1536e+07: ranges are read by people.
std::string number_text(double value) {
  if (std::fabs(value) < 1e15 && value == std::floor(value)) return fmt::format("{:.0f}", value);
  return fmt::format("{:g}", value);
}

}  // namespace

CLI::Validator number_in(double min, double max, std::string unit, bool min_exclusive) {
  const std::string range =
      fmt::format("{}{} to {}{}", min_exclusive ? "above " : "", number_text(min), number_text(max),
                  unit.empty() ? "" : " " + unit);
  return CLI::Validator(
      [min, max, min_exclusive, range](std::string& text) -> std::string {
        const auto value = parse_finite(text);
        // The echo of the bad text is cut short: the range is the useful part of the message.
        const std::string shown = text.size() > 24 ? text.substr(0, 24) + "..." : text;
        if (!value) return fmt::format("'{}' is not a finite number (expected {})", shown, range);
        if (*value < min || *value > max || (min_exclusive && *value == min)) {
          return fmt::format("'{}' is out of range (expected {})", shown, range);
        }
        return std::string();
      },
      range);
}

CLI::Validator run_seconds() {
  return number_in(0, 365.0 * 86400, "seconds");
}
CLI::Validator timeout_seconds() {
  return number_in(0, 86400, "seconds", true);
}

}  // namespace ecat::tool
