#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <utility>

#include <fmt/format.h>

#include <ecat/config/esi.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

namespace reg = wire::reg;

namespace {

// Frame order through an ESC: port 0 in, then the downstream ports in this order.
constexpr std::array<std::uint8_t, 3> kDownstreamOrder{3, 1, 2};

// Signed difference b - a of two 32-bit receive times (they wrap every ~4.3 s).
std::int64_t diff32(std::uint32_t a, std::uint32_t b) noexcept {
  return static_cast<std::int32_t>(b - a);
}

std::string who(std::size_t position, std::uint16_t station) {
  return fmt::format("slave {} (station 0x{:04X})", position, station);
}

std::array<bool, 4> open_ports(std::uint16_t dl_status) noexcept {
  const auto dl = wire::DlStatus::decode(dl_status);
  std::array<bool, 4> open{};
  for (std::size_t p = 0; p < 4; ++p) {
    // A port carries frames onward when communication is up and its loop is open.
    open[p] = dl.ports[p].communication && !dl.ports[p].loop_closed;
  }
  return open;
}

bool has_receive_times(const DcSlaveSnapshot& s) noexcept {
  if (!s.receive_times_valid) return false;
  if (s.epu_time != 0) return true;
  return std::any_of(s.port_time.begin(), s.port_time.end(),
                     [](std::uint32_t t) { return t != 0; });
}

}  // namespace

std::int64_t dc_master_time_now() noexcept {
  const auto unix_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                           std::chrono::system_clock::now().time_since_epoch())
                           .count();
  return unix_ns - kDcEpochOffsetNs;
}

std::vector<std::size_t> DcPlan::dc_positions() const {
  std::vector<std::size_t> out;
  for (const auto& s : slaves)
    if (s.dc) out.push_back(s.position);
  return out;
}

Result<RingTree> ring_tree(std::span<const std::uint16_t> dl_status,
                           std::span<const std::uint16_t> stations, bool ring_returns_to_master) {
  const std::size_t n = dl_status.size();
  const auto station = [&](std::size_t i) -> std::uint16_t {
    return i < stations.size() ? stations[i] : 0;
  };
  RingTree tree;
  tree.slaves.resize(n);
  if (n == 0) return tree;
  std::vector<std::array<bool, 4>> open(n);
  for (std::size_t i = 0; i < n; ++i)
    open[i] = open_ports(dl_status[i]);
  struct Open {
    std::size_t position;
    std::size_t next;  // index into kDownstreamOrder
  };
  auto next_port = [&](Open& o) -> std::optional<std::uint8_t> {
    while (o.next < kDownstreamOrder.size()) {
      const std::uint8_t port = kDownstreamOrder[o.next];
      if (open[o.position][port]) return port;
      ++o.next;
    }
    return std::nullopt;
  };
  std::vector<Open> stack;
  stack.push_back({0, 0});
  for (std::size_t k = 1; k < n; ++k) {
    std::optional<std::uint8_t> port;
    while (!stack.empty() && !(port = next_port(stack.back())))
      stack.pop_back();
    if (stack.empty()) {
      return Error(Errc::malformed,
                   fmt::format("topology: {} has no open port left on any earlier slave to hang "
                               "on (more slaves than open ports; DL status of slave 0 is 0x{:04X})",
                               who(k, station(k)), dl_status[0]));
    }
    Open& parent = stack.back();
    tree.slaves[k].parent = parent.position;
    tree.slaves[k].parent_port = *port;
    tree.slaves[parent.position].children[*port] = k;
    ++parent.next;
    stack.push_back({k, 0});
  }
  for (std::size_t k = 0; k < stack.size(); ++k) {
    Open& o = stack[k];
    if (auto port = next_port(o)) {
      // The ring's way back to the master's second port leaves the deepest slave, once.
      if (ring_returns_to_master && k + 1 == stack.size()) {
        tree.return_port = *port;
        ++o.next;
        if (!next_port(o)) continue;
        port = next_port(o);
      }
      return Error(Errc::malformed,
                   fmt::format("topology: {} has port {} open (DL status 0x{:04X}) but no "
                               "slave follows behind it",
                               who(o.position, station(o.position)), *port, dl_status[o.position]));
    }
  }
  return tree;
}

Result<DcPlan> plan_dc(std::span<const DcSlaveSnapshot> slaves, std::int64_t master_time_ns,
                       const DcPlanOptions& options) {
  const std::size_t n = slaves.size();
  if (n == 0) return Error(Errc::invalid_argument, "DC planning: no slaves");
  const std::int64_t p_delay = options.timing.processing_delay_ns;
  const std::int64_t f_delay = options.timing.forwarding_delay_ns;

  DcPlan plan;
  plan.slaves.resize(n);
  std::vector<bool> times(n);
  for (std::size_t i = 0; i < n; ++i) {
    auto& out = plan.slaves[i];
    out.position = i;
    out.station = slaves[i].station;
    out.open_ports = open_ports(slaves[i].dl_status);
    times[i] = has_receive_times(slaves[i]);
    out.dc = slaves[i].dc_supported && times[i] && slaves[i].epu_time != 0;
  }

  std::vector<std::uint16_t> dl(n);
  std::vector<std::uint16_t> stations(n);
  for (std::size_t i = 0; i < n; ++i) {
    dl[i] = slaves[i].dl_status;
    stations[i] = slaves[i].station;
  }
  auto tree = ring_tree(dl, stations, options.ring_returns_to_master);
  if (!tree) return Error(tree.error().code(), "DC " + tree.error().message());
  std::vector<std::array<std::optional<std::size_t>, 4>> children(n);
  for (std::size_t i = 0; i < n; ++i) {
    plan.slaves[i].parent = tree->slaves[i].parent;
    plan.slaves[i].parent_port = tree->slaves[i].parent_port;
    children[i] = tree->slaves[i].children;
  }

  // Arrival times: parents come before their children in ring order.
  auto last_port = [&](std::size_t i) -> std::optional<std::uint8_t> {
    std::optional<std::uint8_t> last;
    for (std::uint8_t port : kDownstreamOrder)
      if (children[i][port]) last = port;
    return last;
  };
  for (std::size_t i = 0; i < n; ++i) {
    const auto& s = slaves[i];
    const bool parent = std::any_of(children[i].begin(), children[i].end(),
                                    [](const auto& c) { return c.has_value(); });
    if (!parent) continue;
    if (!times[i]) {
      return Error(Errc::unsupported,
                   fmt::format("DC topology: {} has no receive times (0x0900 not answered or all "
                               "zero) but slaves hang on it; their delays cannot be measured",
                               who(i, s.station)));
    }
    std::uint32_t prev = s.port_time[0];
    std::uint8_t prev_port = 0;
    bool first = true;
    for (std::uint8_t port : kDownstreamOrder) {
      if (!children[i][port]) continue;
      const std::size_t c = *children[i][port];
      const std::int64_t loop = diff32(prev, s.port_time[port]);
      if (loop <= 0) {
        return Error(Errc::malformed,
                     fmt::format("DC receive times: {}: port {} time 0x{:08X} is not after port {} "
                                 "time 0x{:08X} (frame order 0, 3, 1, 2)",
                                 who(i, s.station), port, s.port_time[port], prev_port, prev));
      }
      // The child's own turnaround: what it measured between its port 0 and its last port,
      // plus the parts no port latches (an assumption of the timing model).
      std::int64_t turnaround = p_delay + f_delay;
      if (auto lp = last_port(c)) {
        const std::int64_t span = diff32(slaves[c].port_time[0], slaves[c].port_time[*lp]);
        turnaround = span + 2 * f_delay;
      }
      const std::int64_t out = first ? p_delay : f_delay;
      const double cable = std::max(0.0, static_cast<double>(loop - out - turnaround) / 2.0);
      plan.slaves[c].arrival_ns = plan.slaves[i].arrival_ns +
                                  static_cast<double>(diff32(s.port_time[0], prev) + out) + cable;
      prev = s.port_time[port];
      prev_port = port;
      first = false;
    }
  }

  const auto ref = std::find_if(plan.slaves.begin(), plan.slaves.end(),
                                [](const DcPlannedSlave& s) { return s.dc; });
  if (ref == plan.slaves.end()) {
    return Error(Errc::not_found,
                 fmt::format("DC: no DC-capable slave among {} (ESC feature bit 2 with a system "
                             "time unit answering 0x0918)",
                             n));
  }
  plan.reference_position = ref->position;
  plan.reference_station = ref->station;
  for (auto& s : plan.slaves) {
    if (!s.dc) continue;
    const auto delay = std::max<std::int64_t>(
        0, static_cast<std::int64_t>(std::llround(s.arrival_ns - ref->arrival_ns)));
    s.delay_ns = static_cast<std::uint32_t>(std::min<std::int64_t>(delay, 0xFFFF'FFFF));
    // System time at the latch must read master_time + delay (the frame reached it `delay`
    // after the reference). Modular arithmetic: offsets are two's complement in the ESC.
    s.offset_ns = static_cast<std::int64_t>(static_cast<std::uint64_t>(master_time_ns) +
                                            s.delay_ns - slaves[s.position].epu_time);
  }
  return plan;
}

// ---------------------------------------------------------------------------------------------
// Initialisation

namespace {

Error wkc_error(std::string_view what, std::uint16_t station, std::uint16_t wkc) {
  return Error(Errc::wkc_mismatch,
               fmt::format("DC init: {} of station 0x{:04X}: working counter {}, expected 1", what,
                           station, wkc));
}

std::array<std::uint8_t, 8> le64(std::uint64_t v) {
  std::array<std::uint8_t, 8> b{};
  wire::store_le64(b.data(), v);
  return b;
}
std::array<std::uint8_t, 4> le32(std::uint32_t v) {
  std::array<std::uint8_t, 4> b{};
  wire::store_le32(b.data(), v);
  return b;
}
std::array<std::uint8_t, 2> le16(std::uint16_t v) {
  std::array<std::uint8_t, 2> b{};
  wire::store_le16(b.data(), v);
  return b;
}

// BWR 0x0900: every slave latches the receive times of its ports (nothing else changes, anywhere).
// Returns the master's time at the latch (the middle of the exchange). `who` prefixes errors.
exec::Task<Result<std::int64_t>> latch_receive_times(exec::EventLoop& loop, bus::Bus& bus,
                                                     const std::function<std::int64_t()>& clock,
                                                     std::chrono::nanoseconds timeout,
                                                     std::string who,
                                                     std::uint16_t* answered = nullptr) {
  const std::int64_t before = clock();
  bus::Transaction tx;
  const std::uint8_t zero[4]{};
  tx.bwr(reg::kDcReceiveTimePort0, zero);
  auto reply = co_await exec::transact(loop, bus, std::move(tx), bus::TransactOptions{timeout, 0});
  if (!reply) co_return reply.error().context(who + ": receive time latch (BWR 0x0900)");
  if (reply->wkc(0) == 0) {
    co_return Error(Errc::wkc_mismatch,
                    who + ": receive time latch (BWR 0x0900) not acknowledged by any slave");
  }
  if (answered != nullptr) *answered = reply->wkc(0);
  const std::int64_t after = clock();
  co_return before + (after - before) / 2;
}

// What puts one DC slave on the common time: offset, delay, filter depths, and the speed counter
// start written again (0: the ESC's power-up value), which resets the filters.
void add_clock_writes(bus::Transaction& tx, std::uint16_t station, std::int64_t offset_ns,
                      std::uint32_t delay_ns, std::uint16_t speed_counter_start,
                      const DcInitOptions& options) {
  tx.fpwr(station, reg::kDcSystemTimeOffset, le64(static_cast<std::uint64_t>(offset_ns)), 1);
  tx.fpwr(station, reg::kDcSystemTimeDelay, le32(delay_ns), 1);
  const std::uint8_t depths[2] = {options.system_time_filter_depth,
                                  options.speed_counter_filter_depth};
  tx.fpwr(station, reg::kDcSystemTimeFilterDepth, depths, 1);
  tx.fpwr(station, reg::kDcSpeedCounterStart,
          le16(speed_counter_start != 0 ? speed_counter_start : std::uint16_t{0x1000}), 1);
}

// The ring as plan_dc sees it, latched and read in one transaction: every slave's features, DL
// status, port receive times, EPU time and speed counter start (DcSlaveSnapshot), and its current
// system-time offset and delay. A slave whose system time unit does not answer (0x0918, 0x0920,
// 0x0928) is taken as without DC. Shared by the start-up, the re-step after a heal and the
// hot-connect join; errors name `who`, the register and the station.
struct RingReading {
  std::int64_t master_time = 0;  // the master's clock at the latch
  std::vector<DcSlaveSnapshot> snapshots;
  std::vector<std::uint64_t> offsets;  // 0x0920
  std::vector<std::uint32_t> delays;   // 0x0928
};

// `by_position`: every slave the latch reached, read by ring position (APRD, `stations`
// ignored: slaves that have no station of their own yet, a hot-connect group just let in, are
// read too); each snapshot's station is the one the slave holds now.
exec::Task<Result<RingReading>> read_ring(exec::EventLoop& loop, bus::Bus& bus,
                                          std::vector<std::uint16_t> stations,
                                          const DcInitOptions& options, const std::string& who,
                                          bool by_position = false) {
  auto master_clock = options.master_clock ? options.master_clock : dc_master_time_now;
  std::uint16_t reached = 0;
  auto latched = co_await latch_receive_times(loop, bus, master_clock, options.transaction_timeout,
                                              who, &reached);
  if (!latched) co_return std::move(latched).error();
  if (by_position) stations.assign(reached, 0);
  const std::size_t kReads = by_position ? 8 : 7;
  bus::Transaction tx;
  tx.reserve(stations.size() * kReads, stations.size() * 46);
  for (std::size_t i = 0; i < stations.size(); ++i) {
    const auto read = [&](std::uint16_t offset, std::uint16_t length) {
      if (by_position) {
        tx.aprd(static_cast<std::uint16_t>(i), offset, length);
      } else {
        tx.fprd(stations[i], offset, length);
      }
    };
    read(reg::kFeatures, 2);
    read(reg::kDlStatus, 2);
    read(reg::kDcReceiveTimePort0, 16);
    read(reg::kDcReceiveTimeEpu, 8);
    read(reg::kDcSpeedCounterStart, 2);
    read(reg::kDcSystemTimeOffset, 8);
    read(reg::kDcSystemTimeDelay, 4);
    if (by_position) read(reg::kStationAddress, 2);
  }
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  auto reply = co_await exec::transact(loop, bus, std::move(tx), reliable);
  if (!reply) co_return reply.error().context(who + ": reading receive times");
  RingReading out;
  out.master_time = *latched;
  out.snapshots.resize(stations.size());
  out.offsets.resize(stations.size());
  out.delays.resize(stations.size());
  for (std::size_t i = 0; i < stations.size(); ++i) {
    const std::size_t base = i * kReads;
    auto& s = out.snapshots[i];
    if (by_position) {
      if (reply->wkc(base + 7) != 1) {
        co_return Error(Errc::wkc_mismatch,
                        fmt::format("{}: read of the station address at position {}: working "
                                    "counter {}, expected 1 (the ring changed under the reads)",
                                    who, i, reply->wkc(base + 7)));
      }
      stations[i] = wire::load_le16(reply->data(base + 7).data());
    }
    s.station = stations[i];
    if (reply->wkc(base) != 1)
      co_return wkc_error("read of 0x0008", s.station, reply->wkc(base)).context(who);
    if (reply->wkc(base + 1) != 1) {
      co_return wkc_error("read of DL status 0x0110", s.station, reply->wkc(base + 1)).context(who);
    }
    s.dc_supported =
        wire::EscFeatures::decode(wire::load_le16(reply->data(base).data())).dc_supported;
    s.dl_status = wire::load_le16(reply->data(base + 1).data());
    s.receive_times_valid = reply->wkc(base + 2) == 1;
    if (s.receive_times_valid) {
      for (std::size_t p = 0; p < 4; ++p)
        s.port_time[p] = wire::load_le32(reply->data(base + 2).data() + 4 * p);
    }
    if (reply->wkc(base + 3) == 1 && reply->wkc(base + 5) == 1 && reply->wkc(base + 6) == 1) {
      s.epu_time = wire::load_le64(reply->data(base + 3).data());
      out.offsets[i] = wire::load_le64(reply->data(base + 5).data());
      out.delays[i] = wire::load_le32(reply->data(base + 6).data());
    } else {
      s.dc_supported = false;  // no system time unit answering
    }
    if (reply->wkc(base + 4) == 1)
      s.speed_counter_start = wire::load_le16(reply->data(base + 4).data());
  }
  co_return out;
}

}  // namespace

exec::Task<Result<DcInitResult>> initialize_dc(exec::EventLoop& loop, bus::Bus& bus,
                                               std::vector<std::uint16_t> stations,
                                               DcInitOptions options) {
  using SteadyClock = std::chrono::steady_clock;
  const auto started = SteadyClock::now();
  if (stations.empty()) co_return Error(Errc::invalid_argument, "DC init: no slaves");
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  const bus::TransactOptions once{options.transaction_timeout, 0};

  // 1. Latch the receive times of every port of every slave, then read what the plan needs.
  auto reading = co_await read_ring(loop, bus, stations, options, "DC init");
  if (!reading) co_return std::move(reading).error();
  const std::vector<DcSlaveSnapshot>& snapshots = reading->snapshots;

  auto plan = plan_dc(snapshots, reading->master_time, options.plan);
  if (!plan) co_return std::move(plan).error();

  DcInitResult result;
  result.plan = std::move(*plan);
  result.reference_station = result.plan.reference_station;
  std::vector<std::uint16_t> dc_stations;
  for (const auto& s : result.plan.slaves)
    if (s.dc) dc_stations.push_back(s.station);

  // 3. Offsets, delays, filter depths, filter reset.
  {
    bus::Transaction tx;
    for (const auto& s : result.plan.slaves) {
      if (!s.dc) continue;
      add_clock_writes(tx, s.station, s.offset_ns, s.delay_ns,
                       snapshots[s.position].speed_counter_start, options);
    }
    auto reply = co_await exec::transact(loop, bus, std::move(tx), reliable);
    if (!reply) co_return reply.error().context("DC init: writing offsets, delays and filters");
  }

  // 4. Static drift compensation: the reference time to everybody, one frame at a time.
  const std::uint16_t ref = result.reference_station;
  const auto deadline = started + options.time_limit;
  std::uint32_t sent = 0;
  const std::uint32_t check_every = std::max<std::uint32_t>(1, options.check_every);
  const std::int64_t threshold = options.threshold.count();
  std::uint32_t settled = 0;
  while (true) {
    const bool check = sent + 1 >= options.min_frames && (sent + 1) % check_every == 0;
    bus::Transaction tx;
    tx.frmw(ref, reg::kDcSystemTime, 8);
    if (check) {
      for (std::uint16_t st : dc_stations)
        tx.fprd(st, reg::kDcSystemTimeDifference, 4);
    }
    auto reply = co_await exec::transact(loop, bus, std::move(tx), once);
    ++sent;
    if (!reply) {
      if (reply.error().code() != Errc::timeout) {
        co_return reply.error().context("DC init: drift compensation");
      }
    } else if (check) {
      std::int64_t worst = 0;
      for (std::size_t k = 0; k < dc_stations.size(); ++k) {
        if (reply->wkc(k + 1) != 1) {
          co_return wkc_error("read of 0x092C", dc_stations[k], reply->wkc(k + 1));
        }
        const auto d = decode_dc_difference(wire::load_le32(reply->data(k + 1).data()));
        worst = std::max(worst, std::abs(d));
      }
      result.max_difference_ns = worst;
      result.converged = worst < threshold;
      settled = result.converged ? settled + 1 : 0;
      if (settled >= std::max<std::uint32_t>(1, options.settle_checks)) break;
    }
    if (sent >= options.max_frames || SteadyClock::now() >= deadline) break;
  }
  result.drift_frames = sent;
  result.duration = SteadyClock::now() - started;
  co_return result;
}

// One slave again (see reinitialize_dc_slave in dc.hpp).

exec::Task<Result<DcReinitResult>> reinitialize_dc_slave(exec::EventLoop& loop, bus::Bus& bus,
                                                         const DcPlan& plan, std::uint16_t station,
                                                         DcInitOptions options) {
  const DcPlannedSlave* target = nullptr;
  const DcPlannedSlave* anchor = nullptr;
  for (const auto& s : plan.slaves) {
    if (!s.dc) continue;
    if (s.station == station) {
      target = &s;
    } else if (anchor == nullptr || s.station == plan.reference_station) {
      // The reference clock when it is not the slave itself, else the first other DC slave.
      if (anchor == nullptr || anchor->station != plan.reference_station) anchor = &s;
    }
  }
  if (target == nullptr) {
    co_return Error(
        Errc::not_found,
        fmt::format("DC re-init: station 0x{:04X} is not a DC slave of the plan", station));
  }
  auto master_clock = options.master_clock ? options.master_clock : dc_master_time_now;
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  const auto who = fmt::format("DC re-init of station 0x{:04X}", station);

  // 1. Latch: it changes nothing but the receive-time registers, on any slave.
  auto latched =
      co_await latch_receive_times(loop, bus, master_clock, options.transaction_timeout, who);
  if (!latched) co_return std::move(latched).error();

  // 2. The slave's latched local time and speed counter start; the anchor's latched local time
  //    and offset (its system time at the latch).
  bus::Transaction tx;
  tx.fprd(station, reg::kDcReceiveTimeEpu, 8);
  tx.fprd(station, reg::kDcSpeedCounterStart, 2);
  if (anchor != nullptr) {
    tx.fprd(anchor->station, reg::kDcReceiveTimeEpu, 8);
    tx.fprd(anchor->station, reg::kDcSystemTimeOffset, 8);
  }
  auto reply = co_await exec::transact(loop, bus, std::move(tx), reliable);
  if (!reply) co_return reply.error().context(who + ": reading the latched times");
  static constexpr const char* kReads[] = {"read of 0x0918", "read of 0x0930",
                                           "anchor's read of 0x0918", "anchor's read of 0x0920"};
  for (std::size_t i = 0; i < reply->size(); ++i) {
    if (reply->wkc(i) != 1) {
      const std::uint16_t st = i < 2 ? station : anchor->station;
      co_return wkc_error(kReads[i], st, reply->wkc(i)).context(who);
    }
  }
  const std::uint64_t epu = wire::load_le64(reply->data(0).data());
  const std::uint16_t speed_start = wire::load_le16(reply->data(1).data());

  // System time T of the frame at the reference clock: every DC slave's system time at its own
  // latch is T + its delay. From the anchor: T = its local time + its offset - its delay.
  std::int64_t reference_time = 0;
  if (anchor != nullptr) {
    const std::uint64_t anchor_epu = wire::load_le64(reply->data(2).data());
    const std::uint64_t anchor_offset = wire::load_le64(reply->data(3).data());
    reference_time = static_cast<std::int64_t>(anchor_epu + anchor_offset -
                                               static_cast<std::uint64_t>(anchor->delay_ns));
  } else {
    reference_time = *latched;  // alone: the master's time at the latch, as at startup
  }
  DcReinitResult result;
  result.station = station;
  result.anchor_station = anchor != nullptr ? anchor->station : 0;
  result.delay_ns = target->delay_ns;
  result.offset_ns = static_cast<std::int64_t>(static_cast<std::uint64_t>(reference_time) +
                                               target->delay_ns - epu);

  // 3. Offset, delay, filter depths and filter reset: to this slave alone.
  bus::Transaction writes;
  add_clock_writes(writes, station, result.offset_ns, result.delay_ns, speed_start, options);
  auto written = co_await exec::transact(loop, bus, std::move(writes), reliable);
  if (!written) co_return written.error().context(who + ": writing offset, delay and filters");
  co_return result;
}

exec::Task<Result<DcRestepResult>> restep_dc_slaves(exec::EventLoop& loop, bus::Bus& bus,
                                                    DcPlan plan,
                                                    std::vector<std::uint16_t> free_ran,
                                                    DcInitOptions options) {
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  const std::string who = "DC re-step after the ring healed";
  if (plan.slaves.empty()) co_return Error(Errc::invalid_argument, who + ": no slaves");

  // 1. Latch, then what plan_dc needs and every slave's offset, one transaction. Only the
  //    plan's DC slaves count as such.
  std::vector<std::uint16_t> stations;
  stations.reserve(plan.slaves.size());
  for (const auto& p : plan.slaves)
    stations.push_back(p.station);
  auto reading = co_await read_ring(loop, bus, stations, options, who);
  if (!reading) co_return std::move(reading).error();
  std::vector<DcSlaveSnapshot>& snapshots = reading->snapshots;
  const std::vector<std::uint64_t>& offsets = reading->offsets;
  for (std::size_t i = 0; i < plan.slaves.size(); ++i)
    snapshots[i].dc_supported = snapshots[i].dc_supported && plan.slaves[i].dc;
  auto measured = plan_dc(snapshots, reading->master_time, options.plan);
  if (!measured) co_return measured.error().context(who);
  if (measured->reference_station != plan.reference_station) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: the measured ring has reference 0x{:04X}, the session's is "
                                "0x{:04X}",
                                who, measured->reference_station, plan.reference_station));
  }

  // 2. The reference's system time at the latch (its delay is 0): what every other DC slave's
  //    reads plus its delay.
  const std::size_t ref = measured->reference_position;
  const std::uint64_t reference_time = snapshots[ref].epu_time + offsets[ref];
  DcRestepResult result;
  bus::Transaction writes;
  for (std::size_t i = 0; i < plan.slaves.size(); ++i) {
    auto& old = plan.slaves[i];
    const auto& now = measured->slaves[i];
    if (!old.dc || !now.dc || i == ref) continue;
    const bool stepped = std::find(free_ran.begin(), free_ran.end(), old.station) != free_ran.end();
    if (now.delay_ns != old.delay_ns) {
      writes.fpwr(old.station, reg::kDcSystemTimeDelay, le32(now.delay_ns), 1);
      result.delays_changed.push_back(old.station);
      old.delay_ns = now.delay_ns;
    }
    if (!stepped) continue;
    const std::uint64_t offset = reference_time + now.delay_ns - snapshots[i].epu_time;
    writes.fpwr(old.station, reg::kDcSystemTimeOffset, le64(offset), 1);
    old.offset_ns = static_cast<std::int64_t>(offset);
    result.stepped.push_back({old.station, static_cast<std::int64_t>(offset - offsets[i])});
  }
  if (!writes.empty()) {
    auto written = co_await exec::transact(loop, bus, std::move(writes), reliable);
    if (!written) co_return written.error().context(who + ": writing offsets and delays");
  }
  result.plan = std::move(plan);
  co_return result;
}

exec::Task<Result<DcRingChangeResult>> adapt_dc_to_ring(exec::EventLoop& loop, bus::Bus& bus,
                                                        std::uint16_t reference_station,
                                                        std::vector<std::uint16_t> stations,
                                                        std::vector<std::uint16_t> joining,
                                                        DcInitOptions options) {
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  const std::string who = "DC after the ring changed";
  if (stations.empty()) co_return Error(Errc::invalid_argument, who + ": no slaves");

  // 1. Latch, then what plan_dc needs, every slave's offset and delay, one transaction.
  auto reading = co_await read_ring(loop, bus, stations, options, who);
  if (!reading) co_return std::move(reading).error();
  const std::vector<DcSlaveSnapshot>& snapshots = reading->snapshots;
  const std::vector<std::uint64_t>& offsets = reading->offsets;
  const std::vector<std::uint32_t>& delays = reading->delays;
  auto measured = plan_dc(snapshots, reading->master_time, options.plan);
  if (!measured) co_return measured.error().context(who);
  if (measured->reference_station != reference_station) {
    const bool joiner =
        std::find(joining.begin(), joining.end(), measured->reference_station) != joining.end();
    co_return Error(
        Errc::unsupported,
        joiner ? fmt::format("{}: DC slave 0x{:04X} of the joining slaves is ahead of the "
                             "reference clock 0x{:04X} in frame order (the reference time cannot "
                             "reach it)",
                             who, measured->reference_station, reference_station)
               : fmt::format("{}: the measured ring has reference 0x{:04X}, the session's is "
                             "0x{:04X}",
                             who, measured->reference_station, reference_station));
  }

  // 2. The reference's system time at the latch (its delay is 0). A joining DC slave gets the
  //    offset that puts it there plus its delay, its delay, filter depths and a filter reset;
  //    every other DC slave keeps its time and only gets its new delay where the propagation to
  //    it changed (slaves upstream of it came or went): its clock is right, only the comparison
  //    its loop makes against the reference time moved.
  const std::size_t ref = measured->reference_position;
  const std::uint64_t reference_time = snapshots[ref].epu_time + offsets[ref];
  DcRingChangeResult result;
  bus::Transaction writes;
  for (std::size_t i = 0; i < stations.size(); ++i) {
    auto& now = measured->slaves[i];
    if (!now.dc) continue;
    const bool joins = std::find(joining.begin(), joining.end(), now.station) != joining.end();
    if (joins) {
      const std::uint64_t offset = reference_time + now.delay_ns - snapshots[i].epu_time;
      now.offset_ns = static_cast<std::int64_t>(offset);
      add_clock_writes(writes, now.station, now.offset_ns, now.delay_ns,
                       snapshots[i].speed_counter_start, options);
      result.joined.push_back(now.station);
      continue;
    }
    now.offset_ns = static_cast<std::int64_t>(offsets[i]);
    if (i == ref || now.delay_ns == delays[i]) continue;
    writes.fpwr(now.station, reg::kDcSystemTimeDelay, le32(now.delay_ns), 1);
    result.delays_changed.push_back(now.station);
  }
  if (!writes.empty()) {
    auto written = co_await exec::transact(loop, bus, std::move(writes), reliable);
    if (!written) co_return written.error().context(who + ": writing offsets and delays");
  }
  result.plan = std::move(*measured);
  co_return result;
}

exec::Task<Result<DcDelayUpdate>> update_dc_delays(exec::EventLoop& loop, bus::Bus& bus,
                                                   std::uint16_t reference_station,
                                                   std::vector<std::uint16_t> dc_stations,
                                                   DcInitOptions options) {
  const bus::TransactOptions reliable{options.transaction_timeout, 2};
  const std::string who = "DC delays after a junction port changed";
  auto reading = co_await read_ring(loop, bus, {}, options, who, true);
  if (!reading) co_return std::move(reading).error();
  const std::vector<DcSlaveSnapshot>& snapshots = reading->snapshots;
  auto measured = plan_dc(snapshots, reading->master_time, options.plan);
  if (!measured) co_return measured.error().context(who);
  if (measured->reference_station != reference_station) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: the measured ring has reference 0x{:04X}, the session's is "
                                "0x{:04X}",
                                who, measured->reference_station, reference_station));
  }
  DcDelayUpdate result;
  result.slaves = snapshots.size();
  bus::Transaction writes;
  for (std::size_t i = 0; i < snapshots.size(); ++i) {
    const auto& now = measured->slaves[i];
    if (!now.dc || i == measured->reference_position) continue;
    if (std::find(dc_stations.begin(), dc_stations.end(), now.station) == dc_stations.end())
      continue;
    // A station held twice (a slave come up at another's) is nobody's to write.
    const auto holders =
        std::count_if(snapshots.begin(), snapshots.end(),
                      [&](const DcSlaveSnapshot& x) { return x.station == now.station; });
    if (holders != 1 || now.delay_ns == reading->delays[i]) continue;
    writes.fpwr(now.station, reg::kDcSystemTimeDelay, le32(now.delay_ns), 1);
    result.changed.push_back({now.station, now.delay_ns});
  }
  if (!writes.empty()) {
    auto written = co_await exec::transact(loop, bus, std::move(writes), reliable);
    if (!written) co_return written.error().context(who + ": writing the delays");
  }
  co_return result;
}

// ---------------------------------------------------------------------------------------------
// Runtime

namespace {

// The FRMW, the 0x092C reads (with_reads), then the watched stations' DL status.
bus::Transaction maintainer_layout(std::uint16_t reference, std::span<const std::uint16_t> stations,
                                   bool with_reads, std::span<const std::uint16_t> watched) {
  bus::Transaction tx;
  tx.frmw(reference, reg::kDcSystemTime, 8);
  if (with_reads) {
    for (std::uint16_t st : stations)
      tx.fprd(st, reg::kDcSystemTimeDifference, 4);
  }
  for (std::uint16_t st : watched)
    tx.fprd(st, reg::kDlStatus, 2);
  return tx;
}

std::vector<std::uint16_t> dc_stations_of(const DcInitResult& init) {
  std::vector<std::uint16_t> out;
  for (const auto& s : init.plan.slaves)
    if (s.dc) out.push_back(s.station);
  return out;
}

// The DC slaves followed by the optional stations not among them.
std::vector<std::uint16_t> with_optional(std::vector<std::uint16_t> stations,
                                         const DcRuntimeOptions& options) {
  for (const std::uint16_t st : options.optional_stations) {
    if (std::find(stations.begin(), stations.end(), st) == stations.end()) stations.push_back(st);
  }
  return stations;
}

}  // namespace

DcMaintainer::DcMaintainer(bus::Bus& bus, const DcInitResult& init, DcRuntimeOptions options)
    : DcMaintainer(bus, init.reference_station, dc_stations_of(init), std::move(options)) {}

DcMaintainer::DcMaintainer(bus::Bus& bus, std::uint16_t reference_station,
                           std::vector<std::uint16_t> dc_stations, DcRuntimeOptions options)
    : bus_(bus),
      options_(std::move(options)),
      reference_station_(reference_station),
      stations_(with_optional(dc_stations, options_)),
      frmw_only_(maintainer_layout(reference_station, stations_, false, options_.watch_stations)),
      frmw_and_reads_(
          maintainer_layout(reference_station, stations_, true, options_.watch_stations)) {
  watch_last_.assign(options_.watch_stations.size(), 0);
  watch_seen_.assign(options_.watch_stations.size(), false);
  if (options_.read_every == 0) options_.read_every = 1;
  if (options_.history == 0) options_.history = 1;
  if (options_.sync0_cycle.count() <= 0) options_.sync0_cycle = options_.period;
  if (options_.stale_after.count() <= 0) options_.stale_after = options_.period;
  status_.reference_station = reference_station;
  status_.slaves.resize(stations_.size());
  for (std::size_t i = 0; i < stations_.size(); ++i)
    status_.slaves[i].station = stations_[i];
  membership_.assign(stations_.size(), kInLock);
  optional_.assign(stations_.size(), false);
  const auto& optional = options_.optional_stations;
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (std::find(optional.begin(), optional.end(), stations_[i]) == optional.end()) continue;
    optional_[i] = true;
    // Not a DC slave of the plan: out of the ring until it joins.
    if (std::find(dc_stations.begin(), dc_stations.end(), stations_[i]) == dc_stations.end())
      membership_[i] = kAbsent;
  }
  rejoin_samples_.assign(stations_.size(), 0);
  rejoin_good_.assign(stations_.size(), 0);
  status_.history.assign(options_.history, 0);
  status_.phase_history.assign(options_.history, 0);
  status_.follows_reference = options_.follow_reference;
  status_.phase_target_ns = options_.phase_target.count();
  frmw_only_.set_completion([this](bus::RealtimeTransaction& rt) { on_complete(rt, false); });
  frmw_and_reads_.set_completion([this](bus::RealtimeTransaction& rt) { on_complete(rt, true); });
}

DcMaintainer::~DcMaintainer() {
  detach_from_cycler();
  // The bus completes every pending exchange (reply, timeout, expiry or stop).
  frmw_only_.wait();
  frmw_and_reads_.wait();
  // The cycle no longer follows a reference that nobody watches.
  if (options_.follow_reference) bus_.reset_cycle_steering();
}

void DcMaintainer::reset_lock() {
  reset_requested_.store(true, std::memory_order_release);
}

void DcMaintainer::note_reinitialised(std::uint16_t station) {
  std::lock_guard lock(mutex_);
  for (auto& s : status_.slaves) {
    if (s.station == station) ++s.reinitialised;
  }
}

void DcMaintainer::set_free_running(std::span<const std::uint16_t> stations) {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (membership_[i] == kAbsent) continue;
    const bool behind = std::find(stations.begin(), stations.end(), stations_[i]) != stations.end();
    if (behind && membership_[i] != kFreeRunning) {
      membership_[i] = kFreeRunning;
      ++status_.slaves[i].free_runs;
    } else if (!behind && membership_[i] == kFreeRunning) {
      // The break moved: back in reach without its offset stepped (the ring did not heal).
      membership_[i] = kRejoining;
      rejoin_samples_[i] = 0;
      rejoin_good_[i] = 0;
    }
  }
  update_membership_locked();
}

void DcMaintainer::rejoin_free_running() {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (membership_[i] != kFreeRunning) continue;
    membership_[i] = kRejoining;
    rejoin_samples_[i] = 0;
    rejoin_good_[i] = 0;
  }
  update_membership_locked();
}

void DcMaintainer::update_membership_locked() {
  std::size_t outside = 0;
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    const bool out = outside_lock(membership_[i]);
    status_.slaves[i].free_running = out;
    if (out) ++outside;
  }
  status_.free_running = outside;
}

void DcMaintainer::join_stations(std::span<const std::uint16_t> stations) {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (!optional_[i]) continue;
    if (std::find(stations.begin(), stations.end(), stations_[i]) == stations.end()) continue;
    membership_[i] = kRejoining;
    rejoin_samples_[i] = 0;
    rejoin_good_[i] = 0;
    status_.slaves[i].difference_ns = 0;
    status_.slaves[i].max_abs_difference_ns = 0;
  }
  update_membership_locked();
}

void DcMaintainer::leave_stations(std::span<const std::uint16_t> stations) {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (!optional_[i]) continue;
    if (std::find(stations.begin(), stations.end(), stations_[i]) != stations.end())
      membership_[i] = kAbsent;
  }
  update_membership_locked();
}

void DcMaintainer::hold_stations(std::span<const std::uint16_t> stations) {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (membership_[i] == kAbsent) continue;
    if (std::find(stations.begin(), stations.end(), stations_[i]) == stations.end()) continue;
    membership_[i] = kHeld;
  }
  update_membership_locked();
}

void DcMaintainer::release_stations(std::span<const std::uint16_t> stations) {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (membership_[i] != kHeld) continue;
    if (std::find(stations.begin(), stations.end(), stations_[i]) == stations.end()) continue;
    membership_[i] = kRejoining;
    rejoin_samples_[i] = 0;
    rejoin_good_[i] = 0;
  }
  update_membership_locked();
}

bool DcMaintainer::all_in_lock(std::span<const std::uint16_t> stations) const {
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < stations_.size(); ++i) {
    if (std::find(stations.begin(), stations.end(), stations_[i]) == stations.end()) continue;
    if (outside_lock(membership_[i])) return false;
  }
  return true;
}

namespace {

// `value` wrapped into (-cycle/2, cycle/2].
std::int64_t wrap_phase(std::int64_t value, std::int64_t cycle) {
  std::int64_t phase = ((value % cycle) + cycle) % cycle;
  if (phase > cycle / 2) phase -= cycle;
  return phase;
}

// Steering gains per FRMW sample. The rate comes from the measured drift of the reference
// (feed-forward); a proportional phase step (time constant ~20 samples) holds the phase and a
// slow integral (~2500 samples) trims what the drift estimate gets wrong. Both stay small: a
// sample carries tens of microseconds of host jitter, which must not become cycle jitter.
constexpr double kSteerKp = 0.05;
constexpr double kSteerKi = 2e-5;
constexpr double kSteerMaxIntegralPpm = 200.0;
constexpr std::uint32_t kSettleSamples = 20;
constexpr std::uint32_t kFarSamplesForReacquire = 10;  // medians, consecutive

}  // namespace

void DcMaintainer::steer(std::int64_t frame_error_ns, std::int64_t lateness_ns) {
  const std::int64_t cycle = options_.sync0_cycle.count();
  // The frame's phase without the send jitter: how late this frame left against its deadline,
  // compared with how late frames usually leave, is noise the controller cannot correct
  // (following it would add it to the cycle). The usual lateness stays in: the typical frame is
  // what must be on target. "Usual" is a running median (a step of 1 us towards each sample):
  // a mean would be dragged by the rare very late frame and put the typical one off target.
  const auto lateness = static_cast<double>(lateness_ns);
  if (!lateness_seen_) {
    lateness_usual_ns_ = lateness;
    lateness_seen_ = true;
  } else if (lateness > lateness_usual_ns_) {
    lateness_usual_ns_ += std::min(1000.0, lateness - lateness_usual_ns_);
  } else {
    lateness_usual_ns_ -= std::min(1000.0, lateness_usual_ns_ - lateness);
  }
  const std::int64_t raw =
      wrap_phase(frame_error_ns - std::llround(lateness - lateness_usual_ns_), cycle);
  // The rate follows the reference's measured drift (plus the integral) whatever else happens.
  bus_.set_cycle_rate(feedforward_ppm_ + integral_ppm_);
  if (hold_ > 0) {
    --hold_;
    return;
  }
  // A coarse step still being spread over the ticks (a late bus thread applies it later than
  // planned): the samples do not show its effect yet.
  if (bus_.cycle_steering().pending.count() != 0) return;
  // The median of the last samples: a frame delayed on its way (a busy host, a late simulator)
  // is an outlier, not a phase change.
  recent_errors_[recent_count_ % recent_errors_.size()] = raw;
  ++recent_count_;
  if (recent_count_ < recent_errors_.size()) return;
  auto sorted = recent_errors_;
  const auto middle = static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), sorted.begin() + middle, sorted.end());
  const std::int64_t e = sorted[sorted.size() / 2];
  const std::int64_t fine = cycle / 20;
  const std::int64_t far = cycle / 8;
  far_samples_ = std::abs(e) > far ? far_samples_ + 1 : 0;
  if (!acquired_ || far_samples_ >= kFarSamplesForReacquire) {
    far_samples_ = 0;
    acquired_ = true;
    settled_samples_ = 0;
    status_.phase_settled = false;
    if (std::abs(e) > fine) {
      // Acquire (or re-acquire) in one step; the bus spreads it over ticks of at most a
      // quarter period, and the next samples still show the old phase: skip them, and start
      // the median afresh.
      bus_.shift_cycle(std::chrono::nanoseconds(-e));
      hold_ = 2 + static_cast<std::uint32_t>(std::abs(e) / std::max<std::int64_t>(1, cycle / 4));
      recent_count_ = 0;
      ++status_.phase_steps;
      return;
    }
  }
  // Fine: a proportional step and the slow integral, on a clamped error.
  const double clamped = static_cast<double>(std::clamp(e, -fine, fine));
  integral_ppm_ = std::clamp(integral_ppm_ - kSteerKi * clamped / static_cast<double>(cycle) * 1e6,
                             -kSteerMaxIntegralPpm, kSteerMaxIntegralPpm);
  bus_.shift_cycle(std::chrono::nanoseconds(std::llround(-kSteerKp * clamped)));
  if (std::abs(e) <= fine && !status_.phase_settled && ++settled_samples_ >= kSettleSamples) {
    status_.phase_settled = true;
    status_.max_abs_phase_error_ns = 0;  // from now on: how well it holds
  }
}

void DcMaintainer::on_tick(const bus::CycleTick& tick) {
  if (pending_ != nullptr && pending_->pending()) {
    std::lock_guard lock(mutex_);
    ++status_.overruns;
    return;
  }
  const bool reads = ticks_ % options_.read_every == 0;
  ++ticks_;
  bus::RealtimeTransaction& rt = reads ? frmw_and_reads_ : frmw_only_;
  pending_ = &rt;
  submitted_deadline_ns_ =
      std::chrono::duration_cast<std::chrono::nanoseconds>(tick.deadline.time_since_epoch())
          .count();
  if (last_ref_host_ns_ != 0) {
    // Without the reference (a power cycle, a lost slave) nobody reads the FRMW and every other
    // DC slave writes what it carries into its clock loop: a prediction, not zeros.
    const auto now_ns =
        std::chrono::duration_cast<std::chrono::nanoseconds>(tick.woke_at.time_since_epoch())
            .count();
    const auto elapsed = static_cast<double>(now_ns - last_ref_host_ns_);
    const auto predicted = static_cast<std::uint64_t>(
        static_cast<double>(last_ref_time_) + elapsed * (1.0 + drift_for_prediction_ppm_ * 1e-6));
    wire::store_le64(rt.output(0).data(), predicted);
  }
  if (!bus_.submit_realtime(rt, options_.stale_after)) {
    pending_ = nullptr;
    std::lock_guard lock(mutex_);
    ++status_.frmw_failed;
  }
}

void DcMaintainer::on_complete(bus::RealtimeTransaction& rt, bool with_reads) {
  const bool replied =
      rt.status() == bus::RealtimeStatus::ok || rt.status() == bus::RealtimeStatus::wkc_mismatch;
  const bool frmw_ok = replied && rt.wkc(0) > 0;
  std::optional<bool> lock_change;
  std::optional<bool> health_change;
  {
    std::lock_guard lock(mutex_);
    ++status_.frmw_sent;
    if (!frmw_ok) {
      ++status_.frmw_failed;
      ++status_.consecutive_failures;
      if (!status_.failed && options_.failure_threshold > 0 &&
          status_.consecutive_failures >= options_.failure_threshold) {
        status_.failed = true;
        ++status_.runtime_failures;
        health_change = false;
      }
    } else {
      status_.consecutive_failures = 0;
      if (status_.failed) {
        status_.failed = false;
        health_change = true;
      }
      const std::uint64_t ref_time = wire::load_le64(rt.input(0).data());
      status_.reference_time = ref_time;
      const auto cycle = static_cast<std::uint64_t>(options_.sync0_cycle.count());
      const auto icycle = static_cast<std::int64_t>(cycle);
      const auto since = static_cast<std::int64_t>(ref_time - options_.sync0_start);
      status_.phase_ns = wrap_phase(since, icycle);
      const std::int64_t error = wrap_phase(status_.phase_ns - status_.phase_target_ns, icycle);
      status_.phase_error_ns = error;
      status_.max_abs_phase_error_ns = std::max(status_.max_abs_phase_error_ns, std::abs(error));
      // When the frame left: a reply means the bus sent it, so its send stamp is set. The stamp
      // covers the wake-up and everything the tick ran before the frame.
      const std::int64_t host = rt.sent_timestamp_ns();
      if (options_.follow_reference) steer(error, host - submitted_deadline_ns_);
      last_ref_time_ = ref_time;
      last_ref_host_ns_ = host;
      // The frame passes the reference a latency after it left that is never negative: the
      // window's least-latency sample (smallest reference - send) is the cleanest view of it.
      const std::int64_t offset = static_cast<std::int64_t>(ref_time) - host;
      if (!window_open_ || offset < window_best_offset_) {
        if (!window_open_) window_start_ns_ = host;
        window_open_ = true;
        window_best_offset_ = offset;
        window_best_host_ = host;
      }
      if (host - window_start_ns_ >= 200'000'000) {
        window_bests_[window_count_ % kRateWindows] = {window_best_host_, window_best_offset_};
        ++window_count_;
        const std::size_t n = std::min(window_count_, kRateWindows);
        if (n >= 3) {
          // Least-squares slope of offset over host time, relative to the first point kept.
          const auto& origin = window_bests_[(window_count_ - n) % kRateWindows];
          double sx = 0, sy = 0, sxx = 0, sxy = 0;
          for (std::size_t k = 0; k < n; ++k) {
            const auto& [h, o] = window_bests_[(window_count_ - n + k) % kRateWindows];
            const auto x = static_cast<double>(h - origin.first);
            const auto y = static_cast<double>(o - origin.second);
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
          }
          const double m = static_cast<double>(n);
          const double den = m * sxx - sx * sx;
          if (den > 0) status_.reference_drift_ppm = (m * sxy - sx * sy) / den * 1e6;
          feedforward_ppm_ = -status_.reference_drift_ppm;
          drift_for_prediction_ppm_ = status_.reference_drift_ppm;
        }
        window_open_ = false;
      }
    }
    if (reset_requested_.exchange(false, std::memory_order_acq_rel)) {
      below_ = 0;
      if (locked_.load(std::memory_order_relaxed)) {
        locked_.store(false, std::memory_order_release);
        ++status_.unlock_count;
        status_.last_lock_change = std::chrono::steady_clock::now();
        lock_change = false;
      }
    }
    if (with_reads && replied) {
      std::int64_t worst = 0;
      bool all_answered = true;
      bool membership_changed = false;
      for (std::size_t i = 0; i < stations_.size(); ++i) {
        if (membership_[i] == kAbsent) continue;  // a hot-connect slave out of the ring
        const bool answered = rt.wkc(i + 1) == 1;
        // An optional (hot-connect) slave that stops answering left the ring before the master
        // noticed: not counted, and not a loss of the others' lock.
        if (!answered && optional_[i]) continue;
        const auto d = answered ? decode_dc_difference(wire::load_le32(rt.input(i + 1).data())) : 0;
        if (membership_[i] == kRejoining) {
          // Back once within the threshold for lock_samples samples in a row (or at the limit).
          const bool in = answered && std::abs(d) < options_.threshold.count();
          rejoin_good_[i] = in ? rejoin_good_[i] + 1 : 0;
          rejoin_samples_[i] = std::min(rejoin_samples_[i] + 1, kRejoinSamples);
          if (rejoin_good_[i] >= options_.lock_samples || rejoin_samples_[i] >= kRejoinSamples) {
            membership_[i] = kInLock;
            membership_changed = true;
          }
        }
        if (membership_[i] != kInLock) {
          // Outside the lock: its difference is shown, not counted.
          if (answered) status_.slaves[i].difference_ns = d;
          continue;
        }
        if (!answered) {
          all_answered = false;
          continue;
        }
        auto& s = status_.slaves[i];
        s.difference_ns = d;
        s.max_abs_difference_ns = std::max(s.max_abs_difference_ns, std::abs(d));
        worst = std::max(worst, std::abs(d));
      }
      if (membership_changed) update_membership_locked();
      ++status_.samples;
      status_.max_difference_ns = worst;
      status_.history[history_head_] = worst;
      status_.phase_history[history_head_] = status_.phase_error_ns;
      history_head_ = (history_head_ + 1) % status_.history.size();
      history_size_ = std::min(history_size_ + 1, status_.history.size());
      const bool good = all_answered && worst < options_.threshold.count();
      const bool was_locked = locked_.load(std::memory_order_relaxed);
      if (good) {
        ++below_;
        if (!was_locked && below_ >= options_.lock_samples) {
          locked_.store(true, std::memory_order_release);
          ++status_.lock_count;
          status_.last_lock_change = std::chrono::steady_clock::now();
          lock_change = true;
        }
      } else {
        below_ = 0;
        if (was_locked) {
          locked_.store(false, std::memory_order_release);
          ++status_.unlock_count;
          status_.last_lock_change = std::chrono::steady_clock::now();
          lock_change = false;
        }
      }
    }
    status_.locked = locked_.load(std::memory_order_relaxed);
    if (options_.follow_reference) {
      const auto steering = bus_.cycle_steering();
      status_.cycle_rate_ppm = steering.rate_ppm;
      status_.cycle_offset_ns = steering.offset.count();
    }
  }
  if (lock_change) {
    if (!*lock_change) lock_lost_.store(true, std::memory_order_release);
    if (lock_callback_) lock_callback_(*lock_change);
  }
  if (health_change && health_callback_) health_callback_(*health_change);
  if (replied && !watch_last_.empty()) {
    // Bits 4..15: the ports' link, loop and communication.
    constexpr std::uint16_t kPortBits = 0xFFF0;
    const std::size_t first = 1 + (with_reads ? stations_.size() : 0);
    bool changed = false;
    for (std::size_t w = 0; w < watch_last_.size(); ++w) {
      if (rt.wkc(first + w) != 1) continue;
      const auto bits =
          static_cast<std::uint16_t>(wire::load_le16(rt.input(first + w).data()) & kPortBits);
      changed |= watch_seen_[w] && bits != watch_last_[w];
      watch_last_[w] = bits;
      watch_seen_[w] = true;
    }
    if (changed && watch_callback_) watch_callback_();
  }
}

DcStatus DcMaintainer::status() const {
  // The bus thread takes mutex_ on every completion: allocate before taking it, so the section
  // it may wait for only copies (vector assignment reuses the reserved capacity; the sizes are
  // fixed at construction).
  DcStatus out;
  out.slaves.reserve(stations_.size());
  out.history.reserve(options_.history);
  out.phase_history.reserve(options_.history);
  std::vector<std::int64_t> ordered;
  ordered.reserve(options_.history);
  std::vector<std::int64_t> ordered_phase;
  ordered_phase.reserve(options_.history);
  std::vector<std::uint32_t> membership;
  membership.reserve(stations_.size());
  std::size_t head = 0;
  std::size_t size = 0;
  {
    std::lock_guard lock(mutex_);
    out = status_;
    membership = membership_;
    head = history_head_;
    size = history_size_;
  }
  // Hot-connect slaves out of the ring are not part of the status.
  std::size_t kept = 0;
  for (std::size_t i = 0; i < out.slaves.size(); ++i) {
    if (membership[i] != kAbsent) out.slaves[kept++] = out.slaves[i];
  }
  out.slaves.resize(kept);
  // Unroll the ring buffer: oldest first, only the samples taken.
  const std::size_t cap = out.history.size();
  const std::size_t first = (head + cap - size) % cap;
  for (std::size_t k = 0; k < size; ++k) {
    ordered.push_back(out.history[(first + k) % cap]);
    ordered_phase.push_back(out.phase_history[(first + k) % cap]);
  }
  out.history = std::move(ordered);
  out.phase_history = std::move(ordered_phase);
  return out;
}

// ---------------------------------------------------------------------------------------------
// SYNC and latches

namespace {

constexpr std::uint16_t kSync0Bit = 0x0200;
constexpr std::uint16_t kSync1Bit = 0x0400;

}  // namespace

std::string_view to_string(AssignActivateSource source) noexcept {
  switch (source) {
    case AssignActivateSource::config:
      return "configuration";
    case AssignActivateSource::esi:
      return "ESI";
    case AssignActivateSource::sii:
      return "SII";
    case AssignActivateSource::mode_default:
      return "mode default";
    case AssignActivateSource::none:
      break;
  }
  return "none";
}

std::pair<std::uint16_t, AssignActivateSource> resolve_assign_activate(
    const SyncConfig& sync, const wire::SiiImage* sii, const config::EsiDevice* esi) noexcept {
  if (sync.mode == SyncMode::free_run || sync.mode == SyncMode::sm_synchronous) {
    return {0, AssignActivateSource::none};
  }
  if (sync.assign_activate) return {*sync.assign_activate, AssignActivateSource::config};
  // An entry for the mode: SYNC0 on, SYNC1 on exactly when the mode is sync1.
  const bool want_sync1 = sync.mode == SyncMode::sync1;
  auto fits = [want_sync1](std::uint16_t aa) {
    return (aa & kSync0Bit) != 0 && ((aa & kSync1Bit) != 0) == want_sync1;
  };
  if (esi != nullptr) {
    for (const auto& op : esi->dc_op_modes)
      if (fits(op.assign_activate)) return {op.assign_activate, AssignActivateSource::esi};
  }
  if (sii != nullptr) {
    for (const auto& op : sii->dc)
      if (fits(op.assign_activate)) return {op.assign_activate, AssignActivateSource::sii};
  }
  return {sync.mode == SyncMode::sync1 ? std::uint16_t{0x0700} : std::uint16_t{0x0300},
          AssignActivateSource::mode_default};
}

std::uint8_t latch_control(const std::vector<LatchConfig>& latches, std::uint8_t unit) noexcept {
  std::uint8_t control = 0;
  for (const auto& l : latches) {
    if (l.unit != unit) continue;
    control |= l.edge == LatchEdge::rising ? 0x01 : 0x02;
  }
  return control;
}

exec::Task<Result<DcSyncResult>> configure_sync(exec::EventLoop& loop, bus::Bus& bus,
                                                DcSyncRequest request) {
  const std::uint16_t st = request.station;
  const bus::TransactOptions options{request.timeout, 2};
  DcSyncResult result;
  const auto [aa, source] = resolve_assign_activate(request.sync, request.sii, request.esi);
  result.assign_activate = aa;
  result.source = source;
  result.latch_control[0] = latch_control(request.sync.latches, 0);
  result.latch_control[1] = latch_control(request.sync.latches, 1);
  const bool cyclic = request.sync.mode == SyncMode::sync0 || request.sync.mode == SyncMode::sync1;

  if (cyclic) {
    if (request.cycle.count() <= 0 || request.cycle.count() > 0xFFFF'FFFF) {
      co_return Error(Errc::invalid_argument,
                      fmt::format("DC sync of station 0x{:04X}: cycle {} ns outside 1..2^32-1", st,
                                  request.cycle.count()));
    }
    if (request.sync.sync1_offset.count() < 0 || request.sync.sync1_offset.count() > 0xFFFF'FFFF) {
      co_return Error(Errc::invalid_argument,
                      fmt::format("DC sync of station 0x{:04X}: SYNC1 offset {} ns outside "
                                  "0..2^32-1",
                                  st, request.sync.sync1_offset.count()));
    }
    bus::Transaction tx;
    tx.fprd(st, reg::kDcSystemTime, 8);
    auto now = co_await exec::transact(loop, bus, std::move(tx), options);
    if (!now)
      co_return now.error().context(fmt::format("DC sync of station 0x{:04X}: reading 0x0910", st));
    if (now->wkc(0) != 1) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("DC sync of station 0x{:04X}: read of 0x0910 got working "
                                  "counter {} (no DC system time)",
                                  st, now->wkc(0)));
    }
    const std::uint64_t time = wire::load_le64(now->data(0).data());
    const auto cycle = static_cast<std::uint64_t>(request.cycle.count());
    const auto lead =
        static_cast<std::uint64_t>(std::max<std::int64_t>(0, request.start_lead.count()));
    // The next grid point at least `lead` ahead: every slave configured with the same cycle
    // lands on the same grid (multiples of the cycle in system time), whenever it is configured.
    const std::uint64_t start = ((time + lead) / cycle + 1) * cycle;
    result.start_time = start + static_cast<std::uint64_t>(request.sync.sync0_shift.count());
    result.sync0_cycle_ns = static_cast<std::uint32_t>(cycle);
    result.sync1_cycle_ns = static_cast<std::uint32_t>(request.sync.sync1_offset.count());
  }

  bus::Transaction tx;
  const std::uint8_t off = 0;
  tx.fpwr(st, reg::kDcActivation, wire::Bytes(&off, 1), 1);
  if (cyclic) {
    tx.fpwr(st, reg::kDcSync0CycleTime, le32(result.sync0_cycle_ns), 1);
    tx.fpwr(st, reg::kDcSync1CycleTime, le32(result.sync1_cycle_ns), 1);
    if (request.sync.sync0_pulse.count() > 0) {
      // 10 ns units; many ESCs take it from the SII only and ignore the write (no WKC check).
      const auto units = static_cast<std::uint16_t>(
          std::min<std::int64_t>(0xFFFF, request.sync.sync0_pulse.count() / 10));
      tx.fpwr(st, reg::kDcPulseLength, le16(units));
    }
    tx.fpwr(st, reg::kDcStartTime, le64(result.start_time), 1);
  }
  tx.fpwr(st, reg::kDcLatch0Control, wire::Bytes(&result.latch_control[0], 1), 1);
  tx.fpwr(st, reg::kDcLatch1Control, wire::Bytes(&result.latch_control[1], 1), 1);
  if (cyclic) {
    const std::uint8_t low = static_cast<std::uint8_t>(aa & 0xFF);
    const std::uint8_t high = static_cast<std::uint8_t>(aa >> 8);
    tx.fpwr(st, reg::kDcCyclicUnitControl, wire::Bytes(&low, 1), 1);
    tx.fpwr(st, reg::kDcActivation, wire::Bytes(&high, 1), 1);
  }
  auto written = co_await exec::transact(loop, bus, std::move(tx), options);
  if (!written) {
    co_return written.error().context(
        fmt::format("DC sync of station 0x{:04X}: writing the "
                    "SYNC configuration",
                    st));
  }
  co_return result;
}

exec::Task<Result<std::vector<LatchEvent>>> poll_latches(exec::EventLoop& loop, bus::Bus& bus,
                                                         std::uint16_t station,
                                                         std::chrono::nanoseconds timeout) {
  const bus::TransactOptions options{timeout, 2};
  bus::Transaction status_tx;
  status_tx.fprd(station, reg::kDcLatch0Status, 2, 1);
  auto status = co_await exec::transact(loop, bus, std::move(status_tx), options);
  if (!status) {
    co_return status.error().context(
        fmt::format("latch poll of station 0x{:04X}: reading 0x09AE", station));
  }
  const std::uint8_t bits[2] = {status->data(0)[0], status->data(0)[1]};
  static constexpr std::uint16_t kTimestamp[2][2] = {
      {reg::kDcLatch0PositiveEdge, reg::kDcLatch0NegativeEdge},
      {reg::kDcLatch1PositiveEdge, reg::kDcLatch1NegativeEdge}};
  std::vector<LatchEvent> events;
  bus::Transaction tx;
  for (std::uint8_t unit = 0; unit < 2; ++unit) {
    for (std::uint8_t edge = 0; edge < 2; ++edge) {
      if ((bits[unit] & (1u << edge)) == 0) continue;
      tx.fprd(station, kTimestamp[unit][edge], 8, 1);
      events.push_back({station, unit, edge == 0 ? LatchEdge::rising : LatchEdge::falling, 0});
    }
  }
  if (events.empty()) co_return events;
  auto times = co_await exec::transact(loop, bus, std::move(tx), options);
  if (!times) {
    co_return times.error().context(
        fmt::format("latch poll of station 0x{:04X}: reading timestamps", station));
  }
  for (std::size_t i = 0; i < events.size(); ++i)
    events[i].timestamp_ns = wire::load_le64(times->data(i).data());
  co_return events;
}

}  // namespace ecat::master
