#include <algorithm>
#include <array>
#include <cstring>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/master/domain.hpp>
#include <ecat/master/events.hpp>
#include <ecat/master/states.hpp>

namespace ecat::master {

namespace {

constexpr std::array<std::string_view, kEventKindCount> kNames{
    "master.state",        "slave.state",
    "domain.state",        "domain.health",
    "fault.raised",        "fault.cleared",
    "recovery.step",       "activation.failed",
    "dc.locked",           "dc.lost",
    "link.down",           "link.up",
    "sdo.failed",          "mailbox.failed",
    "bus.frames_lost",     "bus.timeouts",
    "link.reopened",       "link.redundancy",
    "hotconnect.appeared", "hotconnect.ready",
    "hotconnect.lost",     "hotconnect.refused",
};

template <std::size_t N>
void copy_text(std::array<char, N>& out, std::string_view text) noexcept {
  const std::size_t n = std::min(text.size(), N - 1);
  if (n > 0) std::memcpy(out.data(), text.data(), n);  // an empty view may hold a null pointer
  out[n] = '\0';
}

template <std::size_t N>
std::string_view text_of(const std::array<char, N>& buffer) noexcept {
  return {buffer.data(), ::strnlen(buffer.data(), N)};
}

std::string_view state_name(EventKind kind, std::uint8_t value) noexcept {
  switch (kind) {
    case EventKind::master_state:
      return value <= static_cast<std::uint8_t>(MasterState::recovering)
                 ? to_string(static_cast<MasterState>(value))
                 : "?";
    case EventKind::slave_state:
      return value <= static_cast<std::uint8_t>(SlaveState::down)
                 ? to_string(static_cast<SlaveState>(value))
                 : "?";
    case EventKind::domain_state:
      return value <= static_cast<std::uint8_t>(DomainState::stopped)
                 ? to_string(static_cast<DomainState>(value))
                 : "?";
    case EventKind::domain_health:
      return value != 0 ? "healthy" : "invalid";
    default:
      return "";
  }
}

bool is_state_kind(EventKind kind) noexcept {
  return kind == EventKind::master_state || kind == EventKind::slave_state ||
         kind == EventKind::domain_state;
}

// The JSON key the event's name goes under.
std::string_view subject_key(EventKind kind) noexcept {
  switch (kind) {
    case EventKind::domain_state:
    case EventKind::domain_health:
      return "domain";
    case EventKind::master_state:
    case EventKind::dc_locked:
    case EventKind::dc_lost:
    case EventKind::link_down:
    case EventKind::link_up:
    case EventKind::link_reopened:
    case EventKind::frames_lost:
    case EventKind::timeouts:
      return "";
    case EventKind::hotconnect_appeared:
    case EventKind::hotconnect_ready:
    case EventKind::hotconnect_lost:
    case EventKind::hotconnect_refused:
      return "group";
    default:
      return "slave";
  }
}

// The name of the event's number in JSON, "" when it has none worth a key.
std::string_view value_key(EventKind kind) noexcept {
  switch (kind) {
    case EventKind::activation_failed:
      return "al_status_code";
    case EventKind::sdo_failed:
      return "abort_code";
    case EventKind::dc_locked:
    case EventKind::dc_lost:
      return "max_difference_ns";
    case EventKind::frames_lost:
    case EventKind::timeouts:
      return "total";
    case EventKind::link_reopened:
      return "attempts";
    case EventKind::hotconnect_ready:
      return "join_ns";
    default:
      return "";
  }
}

}  // namespace

std::string_view to_string(EventKind kind) noexcept {
  const auto i = static_cast<std::size_t>(kind);
  return i < kNames.size() ? kNames[i] : "unknown";
}

std::optional<EventKind> event_kind_from_string(std::string_view name) noexcept {
  for (std::size_t i = 0; i < kNames.size(); ++i) {
    if (kNames[i] == name) return static_cast<EventKind>(i);
  }
  return std::nullopt;
}

std::string_view Event::name() const noexcept {
  return text_of(name_buffer);
}
std::string_view Event::detail() const noexcept {
  return text_of(detail_buffer);
}
void Event::set_name(std::string_view text) noexcept {
  copy_text(name_buffer, text);
}
void Event::set_detail(std::string_view text) noexcept {
  copy_text(detail_buffer, text);
}
std::string_view Event::from_name() const noexcept {
  return state_name(kind, from);
}
std::string_view Event::to_name() const noexcept {
  return state_name(kind, to);
}

std::string describe(const Event& e) {
  std::string out(to_string(e.kind));
  if (!e.name().empty()) out += fmt::format(" {}:", e.name());
  if (is_state_kind(e.kind)) {
    out += fmt::format(" {} -> {}", e.from_name(), e.to_name());
  } else if (e.kind == EventKind::domain_health) {
    out += fmt::format(" {}", e.to_name());
  }
  const bool code = e.kind == EventKind::activation_failed || e.kind == EventKind::sdo_failed;
  if (const auto key = value_key(e.kind); !key.empty() && (!code || e.value != 0)) {
    out += code ? fmt::format(" {}=0x{:X}", key, e.value) : fmt::format(" {}={}", key, e.value);
  }
  if (!e.detail().empty()) out += fmt::format(" ({})", e.detail());
  return out;
}

std::string event_json(const Event& e) {
  nlohmann::json j;
  j["seq"] = e.sequence;
  j["time_ns"] = e.time_ns;
  j["event"] = to_string(e.kind);
  if (const auto key = subject_key(e.kind); !key.empty() && !e.name().empty()) {
    j[std::string(key)] = e.name();
  }
  if (e.subject >= 0) j["index"] = e.subject;
  if (is_state_kind(e.kind)) {
    j["from"] = e.from_name();
    j["to"] = e.to_name();
  } else if (e.kind == EventKind::domain_health) {
    j["healthy"] = e.to != 0;
  }
  const bool code = e.kind == EventKind::activation_failed || e.kind == EventKind::sdo_failed;
  if (const auto key = value_key(e.kind); !key.empty() && (!code || e.value != 0)) {
    j[std::string(key)] = e.value;  // a code of 0 is none: no key
  }
  if (!e.detail().empty()) j["detail"] = e.detail();
  // Text cut to fit a fixed-size event may end inside a UTF-8 sequence: replace, never throw.
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace ecat::master
