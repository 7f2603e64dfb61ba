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

namespace {

bool matches_head(const HotConnectGroup& g, const StartSlave& at) {
  if (g.alias) return at.alias == *g.alias;
  const auto& first = g.slaves.front();
  const auto vendor = g.vendor_id ? g.vendor_id : first.vendor_id;
  const auto product = g.product_code ? g.product_code : first.product_code;
  return vendor && product && at.identity.vendor_id == *vendor &&
         at.identity.product_code == *product;
}

// The fixed slave declares who it is and that is who sits here.
bool matches_fixed(const SlaveConfig& c, const StartSlave& at) {
  if (c.alias) return at.alias == *c.alias;
  return c.vendor_id && c.product_code && at.identity.vendor_id == *c.vendor_id &&
         at.identity.product_code == *c.product_code;
}

}  // namespace

std::optional<StartPlacement> place_at_start(std::span<const SlaveConfig> fixed,
                                             std::span<const HotConnectGroup> groups,
                                             std::span<const StartSlave> ring) {
  for (std::size_t i = 0; i < fixed.size(); ++i) {
    if (fixed[i].position && *fixed[i].position != i) return std::nullopt;
  }
  const std::size_t n = ring.size();
  StartPlacement out;
  std::vector<bool> used(groups.size(), false);
  std::vector<FoundIdentity> ids;
  ids.reserve(n);
  for (const auto& r : ring)
    ids.push_back(r.identity);
  std::size_t pos = 0;
  std::size_t i = 0;
  while (pos < n && i < fixed.size()) {
    if (!matches_fixed(fixed[i], ring[pos])) {
      bool placed = false;
      for (std::size_t g = 0; g < groups.size() && !placed; ++g) {
        const std::size_t k = groups[g].slaves.size();
        if (used[g] || k == 0 || pos + k > n || n - pos - k < fixed.size() - i) continue;
        if (!matches_head(groups[g], ring[pos])) continue;
        const auto whole = std::span<const FoundIdentity>(ids).subspan(pos, k);
        if (group_identity_mismatch(groups[g], static_cast<std::uint16_t>(pos), whole)) continue;
        used[g] = true;
        out.groups.emplace_back(g, static_cast<std::uint16_t>(pos));
        pos += k;
        placed = true;
      }
      if (placed) continue;
    }
    out.fixed.push_back(static_cast<std::uint16_t>(pos++));
    ++i;
  }
  if (i < fixed.size() || out.groups.empty()) return std::nullopt;
  return out;
}

}  // namespace ecat::master
