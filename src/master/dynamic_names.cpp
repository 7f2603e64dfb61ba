#include "dynamic_names.hpp"

#include <fmt/format.h>

#include <ecat/master/sii_reader.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::master {

namespace {

// Categories that belong to a slave with process data or a mailbox of its own.
bool rules_out_coupler(std::uint16_t type) noexcept {
  namespace c = wire::sii_category;
  return type == c::kFmmu || type == c::kSyncManager || type == c::kFmmuEx ||
         type == c::kSyncUnit || type == c::kTxPdo || type == c::kRxPdo || type == c::kDc;
}

// The walk stops here even without an END marker: a real coupler's SII is a few hundred bytes.
constexpr std::size_t kMaxCategories = 64;
constexpr std::uint32_t kMaxWordAddress = 0x8000;  // 64 KiB, the largest SII

}  // namespace

bool sii_shape_is_coupler(const SiiShape& shape) noexcept {
  if (shape.standard_mailbox.recv_size != 0 || shape.standard_mailbox.send_size != 0 ||
      shape.mailbox_protocols != 0) {
    return false;
  }
  bool general = false;
  bool ended = false;
  for (const auto type : shape.category_types) {
    if (rules_out_coupler(type)) return false;
    if (type == wire::sii_category::kGeneral) general = true;
    if (type == wire::sii_category::kEnd) ended = true;
  }
  // A blank or unreadable category area (no GENERAL, no END) says nothing about the slave.
  return general && ended;
}

SiiShape sii_shape_of(const wire::SiiDecoded& decoded) {
  SiiShape shape;
  shape.standard_mailbox = decoded.image.standard_mailbox;
  shape.mailbox_protocols = decoded.image.mailbox_protocols;
  for (const auto& category : decoded.categories)
    shape.category_types.push_back(category.type);
  return shape;
}

exec::Task<std::optional<bool>> probe_coupler(exec::EventLoop& loop, bus::Bus& bus,
                                              std::uint16_t station) {
  SiiShape shape;
  auto header = co_await read_sii_words(loop, bus, station, wire::sii_word::kStandardMailbox, 5);
  if (!header) co_return std::nullopt;
  const auto* h = header->data();
  shape.standard_mailbox = {wire::load_le16(h), wire::load_le16(h + 2), wire::load_le16(h + 4),
                            wire::load_le16(h + 6)};
  shape.mailbox_protocols = wire::load_le16(h + 8);
  // A slave with a mailbox is no coupler: no need to walk its categories.
  if (shape.standard_mailbox.recv_size != 0 || shape.standard_mailbox.send_size != 0 ||
      shape.mailbox_protocols != 0) {
    co_return false;
  }
  std::uint32_t word = wire::sii_word::kFirstCategory;
  for (std::size_t i = 0; i < kMaxCategories && word < kMaxWordAddress; ++i) {
    auto category = co_await read_sii_words(loop, bus, station, word, 2);
    if (!category) co_return std::nullopt;
    const auto type = wire::load_le16(category->data());
    const auto size = wire::load_le16(category->data() + 2);
    shape.category_types.push_back(type);
    if (type == wire::sii_category::kEnd || rules_out_coupler(type)) break;
    word += 2u + size;
  }
  co_return sii_shape_is_coupler(shape);
}

std::vector<std::string> dynamic_slave_names(std::span<const std::optional<bool>> coupler) {
  std::vector<std::string> names;
  names.reserve(coupler.size());
  unsigned couplers = 0;
  for (std::size_t pos = 0; pos < coupler.size(); ++pos) {
    if (coupler[pos].value_or(false)) {
      ++couplers;
      names.push_back(couplers == 1 ? std::string("coupler") : fmt::format("coupler_{}", couplers));
    } else {
      names.push_back(fmt::format("slave_{}", pos));
    }
  }
  return names;
}

}  // namespace ecat::master
