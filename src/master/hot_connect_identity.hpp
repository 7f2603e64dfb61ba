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
#include <utility>
#include <vector>

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

// A group already plugged on a junction port in the middle of the ring when the session starts
// shifts the fixed slaves behind it. What the startup read at every position (ring order):
struct StartSlave {
  std::uint16_t alias = 0;  // 0x0012
  FoundIdentity identity;   // SII words 8..13
};
struct StartPlacement {
  std::vector<std::uint16_t> fixed;  // the ring position of each fixed slave, in config order
  std::vector<std::pair<std::size_t, std::uint16_t>> groups;  // group index, first position
};
// Where the fixed slaves and the groups in front of any of them are. Walking the ring, a fixed
// slave that declares its alias or identity (vendor_id and product_code) and matches takes the
// position; otherwise a group not yet placed whose first slave is recognised there (alias, or
// identity) and whose every slave is what it declares (group_identity_mismatch), with room for
// the remaining fixed slaves behind it, takes its slaves' positions; otherwise the next fixed
// slave does (its identity is checked as always when it is brought up). Nullopt when no group
// sits in front of a fixed slave (the configured positions hold: groups at the end of the line
// are the hot-connect scan's), when the fixed slaves do not fit, or when a fixed slave has a
// position of its own that is not its index (positions counted without the groups). Pure.
std::optional<StartPlacement> place_at_start(std::span<const SlaveConfig> fixed,
                                             std::span<const HotConnectGroup> groups,
                                             std::span<const StartSlave> ring);

}  // namespace ecat::master
