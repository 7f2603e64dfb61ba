// The master's sections of a ring file (master:, domains:, slaves:, dc:; docs/MASTER-CONFIG.md)
// must never crash, hang or leak an exception on any input. Every error names where: it starts
// with the file name (and a line within the text when it gives one) and, when it wraps a cause,
// the cause says what. Whatever parses passes validate() again and holds only values inside the
// ranges the parser promises.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <set>
#include <string>
#include <string_view>

#include <ecat/master/config.hpp>

namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::nanoseconds;
using std::chrono::seconds;

constexpr std::string_view kSource = "fuzz.yaml";

[[noreturn]] void fail(const char* what, int line) {
  std::fprintf(stderr, "fuzz_master_config.cpp:%d: %s does not hold\n", line, what);
  std::abort();
}
#define REQUIRE(condition) ((condition) ? void() : fail(#condition, __LINE__))

bool within(nanoseconds value, nanoseconds min, nanoseconds max) {
  return value >= min && value <= max;
}

// "fuzz.yaml:LINE: ..." or "fuzz.yaml: ..." or "fuzz.yaml" (validate's errors, with a cause).
void check_error(const ecat::Error& error, std::string_view text) {
  const std::string& message = error.message();
  REQUIRE(message.starts_with(kSource));
  std::string_view rest = std::string_view(message).substr(kSource.size());
  if (rest.empty()) {
    REQUIRE(error.cause() != nullptr && !error.cause()->message().empty());
    return;
  }
  REQUIRE(rest.starts_with(":"));
  rest.remove_prefix(1);
  if (!rest.empty() && rest.front() >= '1' && rest.front() <= '9') {
    std::size_t line = 0;
    while (!rest.empty() && rest.front() >= '0' && rest.front() <= '9') {
      line = line * 10 + static_cast<std::size_t>(rest.front() - '0');
      REQUIRE(line < (std::size_t{1} << 40));
      rest.remove_prefix(1);
    }
    std::size_t lines = 1;
    for (char c : text)
      lines += c == '\n' || c == '\r' ? 1 : 0;
    REQUIRE(line <= lines);
    REQUIRE(rest.starts_with(":"));
  }
  REQUIRE(!error.describe().empty());
}

void check_config(const ecat::master::MasterConfig& config) {
  using namespace ecat::master;
  REQUIRE(validate(config).ok());
  REQUIRE(config.base_station >= 1);
  if (config.cycle_thread.fifo_priority) {
    REQUIRE(*config.cycle_thread.fifo_priority >= 1 && *config.cycle_thread.fifo_priority <= 99);
  }
  if (config.cycle_thread.cpu) {
    REQUIRE(*config.cycle_thread.cpu >= 0 && *config.cycle_thread.cpu <= 1023);
  }
  if (config.cycle_thread.cpu_dma_latency_us) {
    REQUIRE(*config.cycle_thread.cpu_dma_latency_us >= 0 &&
            *config.cycle_thread.cpu_dma_latency_us <= 1'000'000);
  }
  if (!config.backend.empty()) {
    REQUIRE(config.backend.size() > 4 &&
            (config.backend.starts_with("raw:") || config.backend.starts_with("udp:") ||
             config.backend.starts_with("sim:")));
  }
  if (config.frame_timeout) REQUIRE(within(*config.frame_timeout, microseconds(50), seconds(10)));
  for (auto d : {config.scan.poll, config.scan.stable, config.scan.timeout,
                 config.awaiting_preop_timeout, config.retry_interval}) {
    REQUIRE(within(d, milliseconds(1), seconds(3600)));
  }

  std::set<std::string> domains;
  for (const auto& d : config.domains) {
    REQUIRE(!d.id.empty() && domains.insert(d.id).second);
    REQUIRE(within(d.period, microseconds(50), seconds(10)));
    REQUIRE(d.miss_threshold >= 1 && d.miss_threshold <= (1u << 30));
    REQUIRE(d.recovery_threshold >= 1 && d.recovery_threshold <= (1u << 30));
    // 0: the domain sizes itself (the default); a value from the file is 1..1 MiB.
    REQUIRE(d.max_image_size <= (1u << 20));
    REQUIRE(d.logical_base == 0);  // assigned by the master, never by the file
  }

  std::set<std::string> names;
  for (const auto& s : config.slaves) {
    REQUIRE(!s.name.empty() && names.insert(s.name).second);
    if (s.alias) REQUIRE(*s.alias >= 1);
    if (s.health_poll) REQUIRE(within(*s.health_poll, milliseconds(1), seconds(3600)));
    REQUIRE(s.pdo_source != SlaveConfig::PdoSource::configured && !s.pdo_mapping);
    REQUIRE(s.target == TargetState::op || s.target == TargetState::safeop ||
            s.target == TargetState::preop);
    switch (s.process_data.kind) {
      case ProcessDataRequest::Kind::none:
        REQUIRE(s.process_data.routes.empty());
        break;
      case ProcessDataRequest::Kind::all:
        REQUIRE(domains.count(s.process_data.domain) == 1);
        break;
      case ProcessDataRequest::Kind::signals:
        for (const auto& route : s.process_data.routes)
          REQUIRE(domains.count(route.domain) == 1);
        break;
    }
    for (const auto& sdo : s.startup_sdos)
      REQUIRE(!sdo.data.empty());  // a typed value is 1..8 bytes, `bytes` at least one
    if (s.sync) {
      REQUIRE(within(s.sync->sync0_pulse, nanoseconds(0), seconds(4)));
      REQUIRE(within(s.sync->sync0_shift, -seconds(1), seconds(4)));
      REQUIRE(within(s.sync->sync1_offset, nanoseconds(0), seconds(4)));
      if (s.sync->mode == SyncMode::sync0 || s.sync->mode == SyncMode::sync1) {
        REQUIRE(config.dc.has_value());
      }
      for (const auto& latch : s.sync->latches)
        REQUIRE(!latch.name.empty() && latch.unit <= 1);
    }
  }

  if (config.dc) {
    const DcConfig& dc = *config.dc;
    REQUIRE(within(dc.cycle, microseconds(50), seconds(1)));
    REQUIRE(within(dc.lock_threshold, nanoseconds(1), seconds(1)));
    REQUIRE(within(dc.lock_timeout, milliseconds(1), seconds(3600)));
    REQUIRE(dc.warmup_cycles <= 1'000'000);
    if (dc.frame_lead) {
      REQUIRE(within(*dc.frame_lead, nanoseconds(0), milliseconds(500)));
      REQUIRE(*dc.frame_lead * 2 < dc.cycle);
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > 64 * 1024) return 0;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto config = ecat::master::parse_master_config(text, std::string(kSource));
  if (!config) {
    check_error(config.error(), text);
    return 0;
  }
  check_config(*config);
  return 0;
}
