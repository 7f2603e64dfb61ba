// Before a plugged hot-connect group is brought up, every slave of it is checked against the
// group's declaration (MasterConfig::hot_connect): as many slaves in the ring as it declares, each
// with the vendor, product code and revision its entry gives (SII words 8..13). A group is
// recognised by its first slave alone (alias or identity); a group whose later slaves differ, or
// that is short of slaves, is refused before anything but station addresses is written to it.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>

#include <ecat/master/config.hpp>

namespace ecat::master {

// What a slave says it is: SII words 8..13.
struct FoundIdentity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
};

// Decodes SII words 8..13 (12 bytes, little-endian); nullopt when fewer bytes are given.
std::optional<FoundIdentity> decode_found_identity(std::span<const std::uint8_t> words) noexcept;

// Empty when the ring holds every slave `group` declares, each what it declares; otherwise why
// not, naming the first slave that differs (its name and ring position) and each field that
// differs (declared, found). `found` holds what the slaves from `first_position` on say, in ring
// order, as many as the ring has (fewer than declared: the group is short). Pure.
std::optional<std::string> group_identity_mismatch(const HotConnectGroup& group,
                                                   std::uint16_t first_position,
                                                   std::span<const FoundIdentity> found);

}  // namespace ecat::master
