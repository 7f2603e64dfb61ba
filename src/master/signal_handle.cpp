#include <algorithm>
#include <cstring>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/master.hpp>
#include <ecat/master/signal_handle.hpp>
#include <ecat/wire/bytes.hpp>

#include "master/slave_access.hpp"

namespace ecat::master {

Result<SignalHandle> SignalHandle::resolve(Master& master, std::string_view slave_name,
                                           std::string_view signal_name) {
  const auto what = [&] {
    return fmt::format("signal \"{}\" of slave {}", signal_name, slave_name);
  };
  auto slave = master.slave(slave_name);
  if (!slave) return slave.error().context(fmt::format("resolving {}", what()));
  const SlaveInfo info = (*slave)->info();
  if (info.signals.empty()) {
    return Error(Errc::not_ready,
                 fmt::format("resolving {}: the slave has no signals yet (they come with its "
                             "PREOP configuration; state {})",
                             what(), to_string(info.state)));
  }
  const auto sig = std::find_if(info.signals.begin(), info.signals.end(),
                                [&](const Signal& s) { return s.name == signal_name; });
  if (sig == info.signals.end()) {
    std::string names;
    for (const auto& s : info.signals)
      names += (names.empty() ? "" : ", ") + s.name;
    return Error(Errc::not_found, fmt::format("slave {} has no signal \"{}\" (it has: {})",
                                              slave_name, signal_name, names));
  }
  if (sig->bit_length == 0 || sig->bit_length > 64) {
    return Error(Errc::unsupported,
                 fmt::format("{} has {} bits: handles carry signals of 1..64 bits (read wider "
                             "ones with Slave::read_input)",
                             what(), sig->bit_length));
  }
  SignalHandle handle;
  handle.owner_ = *slave;
  handle.slave_ = std::string(slave_name);
  handle.signal_ = *sig;
  handle.field_ = *sig;
  handle.field_.bit_offset = 0;
  std::size_t image_size = 0;
  for (const auto& a : info.attachments) {
    if (a.sync_manager != sig->sync_manager) continue;
    auto domain = master.domain(a.domain);
    if (!domain) return domain.error().context(fmt::format("resolving {}", what()));
    auto pdo = (*domain)->find(PdoKey{info.station, a.sync_manager});
    if (!pdo) return pdo.error().context(fmt::format("resolving {}", what()));
    auto field = (*domain)->field(*pdo, sig->bit_offset, sig->bit_length);
    if (!field) return field.error().context(fmt::format("resolving {}", what()));
    handle.targets_.push_back(Target{*domain, *pdo, *field});
    image_size = std::max<std::size_t>(image_size, a.size);
    if (sig->direction == PdoDirection::input) break;  // read from one domain
  }
  if (handle.targets_.empty()) {
    return Error(Errc::not_found,
                 fmt::format("{} is not routed to a domain (its slave's process_data)", what()));
  }
  handle.scalar_ = sig->type != SignalType::bytes;
  handle.image_.assign(image_size, 0);
  return handle;
}

Result<Value> SignalHandle::read() const {
  if (!bound()) {
    return Error(Errc::not_ready, "read() of an unbound signal handle (SignalHandle::resolve)");
  }
  const Target& t = targets_.front();
  if (signal_.direction == PdoDirection::input && scalar_) {
    // Only the field's own bits, from one cycle, with read_fresh's checks.
    auto raw = t.domain->read_fresh(t.field);
    if (!raw) [[unlikely]] {
      return raw.error().context(fmt::format("input \"{}\" of slave {}", signal_.name, slave_));
    }
    return decode_field(signal_, *raw);
  }
  wire::MutableBytes image(image_.data(), image_.size());
  auto got = signal_.direction == PdoDirection::input ? t.domain->read_fresh(t.pdo, image)
                                                      : t.domain->read(t.pdo, image);
  if (!got) {
    return got.error().context(
        fmt::format("{} \"{}\" of slave {}", to_string(signal_.direction), signal_.name, slave_));
  }
  return decode_scaled(signal_, image.first(*got));
}

Result<void> SignalHandle::write(const Value& value) {
  if (!bound()) {
    return Error(Errc::not_ready, "write() of an unbound signal handle (SignalHandle::resolve)");
  }
  if (signal_.direction != PdoDirection::output) {
    return Error(Errc::invalid_argument,
                 fmt::format("signal \"{}\" of slave {} is an input", signal_.name, slave_));
  }
  std::uint64_t bits = 0;
  if (scalar_) {
    auto raw = encode_field(signal_, value);
    if (!raw) [[unlikely]] {
      return raw.error().context(fmt::format("output \"{}\" of slave {}", signal_.name, slave_));
    }
    bits = *raw;
  } else {
    // A `bytes` signal of at most 64 bits: encoded into a word at bit 0.
    auto raw = from_engineering(signal_, value);
    if (!raw) return raw.error();
    std::uint8_t word[8] = {};
    if (auto encoded = encode(field_, *raw, std::span<std::uint8_t>(word, sizeof word)); !encoded) {
      return encoded.error().context(
          fmt::format("output \"{}\" of slave {}", signal_.name, slave_));
    }
    bits = wire::load_le64(word);
  }
  // Staged in every domain and kept in the slave's retained image under its output lock, as
  // Slave::write_output does (detail::SlaveAccess::stage_output).
  struct Staging {
    const SignalHandle* handle;
    std::uint64_t bits;
  };
  const Staging staging{this, bits};
  return detail::SlaveAccess::stage_output(
      *owner_, signal_, bits,
      [](const void* context) -> Result<void> {
        const auto& [self, staged_bits] = *static_cast<const Staging*>(context);
        for (const Target& t : self->targets_) {
          if (auto w = t.domain->write_bits(t.field, staged_bits); !w) [[unlikely]] {
            return w.error().context(fmt::format("staging \"{}\" of slave {} in domain \"{}\"",
                                                 self->signal_.name, self->slave_, t.domain->id()));
          }
        }
        return ok();
      },
      &staging);
}

Result<SignalHandle> Master::signal_handle(std::string_view slave, std::string_view signal) {
  return SignalHandle::resolve(*this, slave, signal);
}

}  // namespace ecat::master
