#include "master/hot_connect_identity.hpp"

#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <ecat/wire/bytes.hpp>

namespace ecat::master {

std::optional<FoundIdentity> decode_found_identity(std::span<const std::uint8_t> words) noexcept {
  if (words.size() < 12) return std::nullopt;
  return FoundIdentity{wire::load_le32(words.data()), wire::load_le32(words.data() + 4),
                       wire::load_le32(words.data() + 8)};
}

std::optional<std::string> group_identity_mismatch(const HotConnectGroup& group,
                                                   std::uint16_t first_position,
                                                   std::span<const FoundIdentity> found) {
  const std::size_t declared = group.slaves.size();
  for (std::size_t k = 0; k < declared; ++k) {
    const SlaveConfig& want = group.slaves[k];
    const auto position = static_cast<unsigned>(first_position + k);
    if (k >= found.size()) {
      return fmt::format(
          "group {}: {} of its {} slaves in the ring from position {}: {} "
          "(position {}) is missing",
          group.name, found.size(), declared, first_position, want.name, position);
    }
    const FoundIdentity& got = found[k];
    // The first slave also answers for the group's own identity, when the group gives one.
    auto vendor = want.vendor_id;
    auto product = want.product_code;
    if (k == 0) {
      if (group.vendor_id) vendor = group.vendor_id;
      if (group.product_code) product = group.product_code;
    }
    std::vector<std::string> differs;
    auto check = [&](const char* what, const std::optional<std::uint32_t>& declared_value,
                     std::uint32_t actual) {
      if (declared_value && *declared_value != actual) {
        differs.push_back(
            fmt::format("{} 0x{:08x} declared, 0x{:08x} found", what, *declared_value, actual));
      }
    };
    check("vendor", vendor, got.vendor_id);
    check("product code", product, got.product_code);
    check("revision", want.revision, got.revision);
    if (!differs.empty()) {
      return fmt::format("group {}: slave {} at position {}: {}", group.name, want.name, position,
                         fmt::join(differs, ", "));
    }
  }
  return std::nullopt;
}

}  // namespace ecat::master
