#include <algorithm>
#include <array>

#include <fmt/format.h>

#include <ecat/sim/segment.hpp>

namespace ecat::sim {

namespace reg = wire::reg;

namespace {
// The order in which an ESC forwards a frame out of its ports after processing it.
constexpr std::array<std::uint8_t, 3> kForwardingOrder{3, 1, 2};
constexpr std::size_t kMaxDatagramsPerFrame = wire::kMaxFrameSize / wire::kDatagramOverhead + 1;
constexpr std::size_t kNotVisited = static_cast<std::size_t>(-1);
}  // namespace

Segment::Segment() {
  slots_.reserve(kMaxDatagramsPerFrame);
  valid_.reserve(kMaxDatagramsPerFrame);
  everyone_.reserve(kMaxDatagramsPerFrame);
  positional_.reserve(kMaxDatagramsPerFrame);
}

Segment::~Segment() = default;

Result<std::size_t> Segment::add_slave(std::string name, std::unique_ptr<Esc> esc,
                                       Attachment attachment, HopTiming timing) {
  if (!esc) return Error(Errc::invalid_argument, fmt::format("slave '{}' has no ESC", name));
  if (find(name)) {
    return Error(Errc::invalid_argument, fmt::format("a slave named '{}' already exists", name));
  }
  Node node;
  node.name = std::move(name);
  node.esc = std::move(esc);
  node.cable_delay_ns = attachment.cable_delay_ns;
  node.timing = timing;
  if (!nodes_.empty()) {
    const std::size_t parent = attachment.parent.value_or(nodes_.size() - 1);
    if (parent >= nodes_.size()) {
      return Error(Errc::invalid_argument,
                   fmt::format("slave '{}' attaches to slave index {}, but only {} exist",
                               node.name, parent, nodes_.size()));
    }
    const std::uint8_t port = attachment.parent_port;
    if (port < 1 || port > 3) {
      return Error(Errc::invalid_argument,
                   fmt::format("slave '{}' attaches to port {} of '{}': ports are 1, 2 or 3",
                               node.name, port, nodes_[parent].name));
    }
    if (nodes_[parent].children[port]) {
      return Error(Errc::invalid_argument,
                   fmt::format("port {} of slave '{}' already connects slave '{}'", port,
                               nodes_[parent].name, nodes_[*nodes_[parent].children[port]].name));
    }
    node.parent = parent;
    node.parent_port = port;
    nodes_[parent].children[port] = nodes_.size();
  }
  nodes_.push_back(std::move(node));
  const std::size_t index = nodes_.size() - 1;
  by_name_.emplace(nodes_[index].name, index);
  nodes_[index].esc->set_layout_observer(this, index);
  esc_layout_changed(index);
  port_control_seen_.clear();  // re-plan on the next frame
  // Only the new slave and the one it attaches to see a link change: building a ring of N
  // slaves stays O(N), not O(N^2).
  update_dl_status(index);
  if (nodes_[index].parent) update_dl_status(*nodes_[index].parent);
  return index;
}

std::optional<std::size_t> Segment::find(std::string_view name) const noexcept {
  const auto it = by_name_.find(name);
  if (it == by_name_.end()) return std::nullopt;
  return it->second;
}

void Segment::set_link(std::size_t index, std::uint8_t port, bool up) {
  if (index >= nodes_.size() || port > 3) return;
  nodes_[index].link_up[port] = up;
  // Link down shuts a port in auto close for good (until the master opens it again).
  if (!up) nodes_[index].auto_closed[port] = true;
  // A cable has two ends: the peer sees the same link state.
  if (port == 0 && nodes_[index].parent) {
    Node& peer = nodes_[*nodes_[index].parent];
    peer.link_up[nodes_[index].parent_port] = up;
    if (!up) peer.auto_closed[nodes_[index].parent_port] = true;
  } else if (port > 0 && nodes_[index].children[port]) {
    nodes_[*nodes_[index].children[port]].link_up[0] = up;
  }
  port_control_seen_.clear();
  update_dl_status();
}

bool Segment::behind(std::size_t index, std::size_t first) const noexcept {
  std::optional<std::size_t> at = index;
  while (at) {
    if (*at == first) return true;
    at = nodes_[*at].parent;
  }
  return false;
}

Result<void> Segment::add_hot_connect_group(std::string name, std::size_t first) {
  if (first >= nodes_.size()) {
    return Error(Errc::not_found, fmt::format("hot-connect group {}: no slave {}", name, first));
  }
  if (!nodes_[first].parent) {
    return Error(Errc::invalid_argument,
                 fmt::format("hot-connect group {}: {} is cabled to the master, not to a slave "
                             "it could be plugged into",
                             name, nodes_[first].name));
  }
  for (const auto& [other, at] : hot_connect_) {
    if (other == name) {
      return Error(Errc::invalid_argument,
                   fmt::format("hot-connect group {} is defined twice", name));
    }
    if (behind(first, at) || behind(at, first)) {
      return Error(Errc::invalid_argument,
                   fmt::format("hot-connect group {}: {} is already part of group {}", name,
                               nodes_[first].name, other));
    }
  }
  hot_connect_.emplace_back(std::move(name), first);
  return ok();
}

Result<void> Segment::plug(std::string_view group, bool plugged, std::int64_t now_ns) {
  for (const auto& [name, first] : hot_connect_) {
    if (name != group) continue;
    if (plugged && !nodes_[first].link_up[0]) {
      // A device that was unplugged was without power: it comes up as from the factory floor.
      for (std::size_t i = 0; i < nodes_.size(); ++i) {
        if (behind(i, first)) nodes_[i].esc->power_cycle(now_ns);
      }
    }
    set_link(first, 0, plugged);
    return ok();
  }
  std::string known;
  for (const auto& [name, first] : hot_connect_)
    known += (known.empty() ? "" : ", ") + name;
  return Error(Errc::not_found, fmt::format("no hot-connect group '{}' (known: {})", group,
                                            known.empty() ? "none" : known));
}

std::vector<Segment::HotConnectGroupInfo> Segment::hot_connect_groups() const {
  std::vector<HotConnectGroupInfo> out;
  for (const auto& [name, first] : hot_connect_) {
    HotConnectGroupInfo info;
    info.name = name;
    info.first = first;
    info.plugged = nodes_[first].link_up[0];
    for (std::size_t i = 0; i < nodes_.size(); ++i)
      info.slaves += behind(i, first) ? 1 : 0;
    out.push_back(std::move(info));
  }
  return out;
}

bool Segment::link(std::size_t index, std::uint8_t port) const {
  return index < nodes_.size() && port <= 3 && nodes_[index].link_up[port];
}

bool Segment::has_link(std::size_t index, std::uint8_t port) const noexcept {
  const Node& node = nodes_[index];
  return node.children[port].has_value() && node.link_up[port];
}

// A port's loop control: its two bits of DL control 0x0101.
std::uint8_t Segment::loop_control(std::size_t index, std::uint8_t port) const noexcept {
  return (nodes_[index].esc->read_u8(reg::kDlPortControl) >> (2 * port)) & 0x3;
}

bool Segment::port_open(std::size_t index, std::uint8_t port) const {
  const bool link = has_link(index, port);
  switch (loop_control(index, port)) {
    case 0:  // auto: open with link
    case 2:  // forced open: only useful with a link (without one the frame would be lost)
      return link;
    case 1:  // auto close: open with link unless link down closed it and 01 was not written since
      return link && !nodes_[index].auto_closed[port];
    default:  // forced closed
      return false;
  }
}

std::int64_t Segment::visit(std::size_t index, std::int64_t arrival,
                            std::vector<Visit>& visits) const {
  const Node& node = nodes_[index];
  const std::size_t slot = visits.size();
  visits.push_back(Visit{index, {}});
  PassContext pass;
  pass.port_time_ns[0] = arrival;
  pass.port_seen[0] = true;
  std::int64_t t = arrival + node.timing.processing_delay_ns;
  pass.epu_time_ns = t;
  for (std::uint8_t port : kForwardingOrder) {
    if (!port_open(index, port)) continue;
    const std::size_t child = *node.children[port];
    const std::int64_t cable = nodes_[child].cable_delay_ns;
    const std::int64_t back = visit(child, t + cable, visits) + cable;
    pass.port_time_ns[port] = back;
    pass.port_seen[port] = true;
    t = back + node.timing.forwarding_delay_ns;
  }
  visits[slot].pass = pass;
  return t + node.timing.forwarding_delay_ns;
}

void Segment::plan(std::vector<Visit>& visits, std::int64_t& round_trip) const {
  visits.clear();
  round_trip = 0;
  if (nodes_.empty() || !nodes_[0].link_up[0]) return;
  const std::int64_t cable = nodes_[0].cable_delay_ns;
  round_trip = visit(0, cable, visits) + cable;
}

std::vector<std::size_t> Segment::processing_order() const {
  std::vector<Visit> visits;
  std::int64_t round_trip = 0;
  plan(visits, round_trip);
  std::vector<std::size_t> order;
  order.reserve(visits.size());
  for (const auto& v : visits)
    order.push_back(v.index);
  return order;
}

std::int64_t Segment::round_trip_ns() const {
  std::vector<Visit> visits;
  std::int64_t round_trip = 0;
  plan(visits, round_trip);
  return round_trip;
}

void Segment::set_reported_link(std::size_t index, std::uint8_t port, std::optional<bool> up) {
  if (index >= nodes_.size() || port > 3) return;
  nodes_[index].reported_link[port] = up;
  update_dl_status(index);  // only this ESC's status changes
}

// DL status 0x0110, per port p: bit 4+p physical link, bit 8+2p loop closed, bit 9+2p
// communication established (the ESC datasheet's register description as public masters read it:
// IgH's fsm_slave_scan.c link_up / loop_closed / signal_detected, ethercrab's DlStatus). A port
// without link closes its loop; one with link opens it unless DL control 0x0101 forces it
// closed or auto close keeps it closed (link up, loop closed: a device waiting behind it).
void Segment::update_dl_status() {
  for (std::size_t i = 0; i < nodes_.size(); ++i)
    update_dl_status(i);
}

void Segment::update_dl_status(std::size_t i) {
  Node& node = nodes_[i];
  wire::DlStatus dl = wire::DlStatus::decode(node.esc->read_u16(reg::kDlStatus));
  for (std::uint8_t port = 0; port < 4; ++port) {
    const bool connected =
        port == 0 ? (node.parent.has_value() || i == 0) : node.children[port].has_value();
    bool link = connected && node.link_up[port];
    bool loop_closed = port == 0 ? !link : !port_open(i, port);
    if (node.reported_link[port]) {
      link = *node.reported_link[port];
      const std::uint8_t control = loop_control(i, port);
      loop_closed = !link || control == 3 || (control == 1 && node.auto_closed[port]);
    }
    dl.ports[port].physical_link = link;
    dl.ports[port].communication = link;
    dl.ports[port].loop_closed = loop_closed;
  }
  node.esc->pdi_write_u16(reg::kDlStatus, dl.encode());
}

void Segment::esc_layout_changed(std::size_t tag) {
  if (tag >= nodes_.size()) return;
  Node& node = nodes_[tag];
  if (!node.port_dirty) {
    node.port_dirty = true;
    port_dirty_.push_back(tag);
  }
  if (!node.index_dirty) {
    node.index_dirty = true;
    index_dirty_.push_back(tag);
  }
}

// A write of 0x0101: every port whose bits say auto close (01) is opened when it has link and
// closed (latched) when it has none, whatever the byte held before.
void Segment::esc_port_control_written(std::size_t tag) {
  if (tag >= nodes_.size()) return;
  Node& node = nodes_[tag];
  bool changed = false;
  for (std::uint8_t port = 1; port < 4; ++port) {
    if (loop_control(tag, port) != 1) continue;
    const bool closed = !has_link(tag, port);
    changed |= node.auto_closed[port] != closed;
    node.auto_closed[port] = closed;
  }
  if (!changed) return;
  port_control_seen_.clear();  // re-plan the route on the next frame
  update_dl_status(tag);
}

void Segment::reindex(std::size_t index) {
  Node& node = nodes_[index];
  node.index_dirty = false;
  const Esc& esc = *node.esc;
  std::array<std::uint16_t, 2> keys{esc.station_address(), 0};
  std::uint8_t key_count = 1;
  if ((esc.read_u8(reg::kDlAliasControl) & 0x01) != 0 && esc.station_alias() != keys[0]) {
    keys[key_count++] = esc.station_alias();
  }
  if (key_count != node.key_count || keys != node.keys) {
    for (std::uint8_t k = 0; k < node.key_count; ++k) {
      auto it = by_address_.find(node.keys[k]);
      if (it == by_address_.end()) continue;
      auto& list = it->second;
      list.erase(std::remove(list.begin(), list.end(), index), list.end());
      if (list.empty()) by_address_.erase(it);
    }
    for (std::uint8_t k = 0; k < key_count; ++k) {
      by_address_[keys[k]].push_back(index);
    }
    node.keys = keys;
    node.key_count = key_count;
  }
  std::vector<std::pair<std::uint64_t, std::uint64_t>> logical;
  for (std::size_t i = 0; i < esc.fmmu_count(); ++i) {
    const wire::FmmuConfig& f = esc.fmmu(i);
    if (!f.active || f.length == 0) continue;
    // Bytes [start, start + length) hold every bit the FMMU maps (start and stop bits inside).
    logical.emplace_back(f.logical_start, std::uint64_t{f.logical_start} + f.length);
  }
  if (logical != node.logical) {
    node.logical = std::move(logical);
    logical_dirty_ = true;
  }
}

void Segment::rebuild_logical_index() {
  logical_.clear();
  logical_max_length_ = 0;
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    for (const auto& [first, end] : nodes_[i].logical) {
      logical_.push_back(LogicalRange{first, end, i});
      logical_max_length_ = std::max(logical_max_length_, end - first);
    }
  }
  std::sort(logical_.begin(), logical_.end(),
            [](const LogicalRange& a, const LogicalRange& b) { return a.first < b.first; });
  logical_dirty_ = false;
}

// Which slaves each datagram of the frame (slots_) addresses. The sets may be larger than the
// slaves that act (Esc::process decides); they never miss one.
void Segment::find_addressed() {
  valid_.clear();
  everyone_.clear();
  hits_.clear();
  positional_.clear();
  // Where each datagram's hits begin in hits_: every run is in route order as a rule (an LRW
  // over a domain laid out along the ring, one station), so the runs are merged, not sorted.
  std::array<std::size_t, kMaxDatagramsPerFrame + 1> run_begin;
  std::size_t runs = 0;
  for (std::size_t k = 0; k < slots_.size(); ++k) {
    const Slot& slot = slots_[k];
    if (!slot.command) continue;
    valid_.push_back(k);
    if (runs < kMaxDatagramsPerFrame && (runs == 0 || run_begin[runs - 1] != hits_.size())) {
      run_begin[runs++] = hits_.size();
    }
    const auto adp = static_cast<std::uint16_t>(slot.address);
    switch (*slot.command) {
      case wire::Command::nop:
        break;
      case wire::Command::aprd:
      case wire::Command::apwr:
      case wire::Command::aprw:
        // The ESC at reachable position p sees ADP + p; the one that sees 0 is addressed.
        positional_.emplace_back(static_cast<std::uint16_t>(0x10000u - adp), k);
        break;
      case wire::Command::fprd:
      case wire::Command::fpwr:
      case wire::Command::fprw: {
        const auto it = by_address_.find(adp);
        if (it == by_address_.end()) break;
        for (const std::size_t node : it->second) {
          if (visit_of_[node] != kNotVisited) hits_.emplace_back(visit_of_[node], k);
        }
        break;
      }
      case wire::Command::lrd:
      case wire::Command::lwr:
      case wire::Command::lrw: {
        if (slot.length == 0) break;
        if (logical_dirty_) rebuild_logical_index();
        const std::uint64_t first = slot.address;
        const std::uint64_t end = first + slot.length;
        // A range that overlaps [first, end) starts after first - max length.
        const std::uint64_t from =
            first >= logical_max_length_ ? first - logical_max_length_ + 1 : 0;
        auto it = std::lower_bound(
            logical_.begin(), logical_.end(), from,
            [](const LogicalRange& r, std::uint64_t value) { return r.first < value; });
        for (; it != logical_.end() && it->first < end; ++it) {
          if (it->end > first && visit_of_[it->node] != kNotVisited) {
            hits_.emplace_back(visit_of_[it->node], k);
          }
        }
        break;
      }
      default:  // BRD, BWR, BRW, ARMW, FRMW: every slave processes them
        everyone_.push_back(k);
        break;
    }
  }
  if (!std::is_sorted(hits_.begin(), hits_.end())) {
    bool runs_sorted = true;
    for (std::size_t r = 0; r < runs && runs_sorted; ++r) {
      const std::size_t end = r + 1 < runs ? run_begin[r + 1] : hits_.size();
      runs_sorted = std::is_sorted(hits_.begin() + static_cast<std::ptrdiff_t>(run_begin[r]),
                                   hits_.begin() + static_cast<std::ptrdiff_t>(end));
    }
    std::size_t longest_later_run = 0;
    for (std::size_t r = 1; r < runs; ++r) {
      const std::size_t end = r + 1 < runs ? run_begin[r + 1] : hits_.size();
      longest_later_run = std::max(longest_later_run, end - run_begin[r]);
    }
    if (runs_sorted && runs <= 8 && longest_later_run <= 8) {
      // Short later runs (a station's FPRD after an LRW) are inserted into the sorted prefix in
      // place: std::inplace_merge would take a temporary buffer from the heap on every frame.
      for (std::size_t j = run_begin[1]; j < hits_.size(); ++j) {
        const auto value = hits_[j];
        const auto prefix_end = hits_.begin() + static_cast<std::ptrdiff_t>(j);
        const auto at = std::upper_bound(hits_.begin(), prefix_end, value);
        std::move_backward(at, prefix_end, prefix_end + 1);
        *at = value;
      }
    } else {
      std::sort(hits_.begin(), hits_.end());
    }
  }
  hits_.erase(std::unique(hits_.begin(), hits_.end()), hits_.end());
  if (!std::is_sorted(positional_.begin(), positional_.end())) {
    std::sort(positional_.begin(), positional_.end());
  }
}

void Segment::add_after_frame(std::function<void(Segment&, std::int64_t)> callback) {
  after_frame_.push_back(std::move(callback));
}

void Segment::advance(std::int64_t now_ns) {
  for (auto& node : nodes_)
    node.esc->advance(now_ns);
}

void Segment::advance_due(std::int64_t now_ns) {
  // A slave this frame addresses by station or logical address is advanced in dispatch() right
  // before it processes (advance_for_frame), so it needs no check here; a frame with a
  // broadcast addresses every reachable slave. Only the others are asked whether time-driven
  // work is due: a cyclic LRW over the whole ring costs no per-slave check at all. (An
  // addressed slave the fault hooks cut off is asked in dispatch(), where they are consulted.)
  const auto check = [&](std::size_t i) {
    if (nodes_[i].esc->advance_due(now_ns)) advance_for_frame(i, now_ns);
  };
  if (visits_.size() != nodes_.size()) {
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      if (i >= visit_of_.size() || visit_of_[i] == kNotVisited) check(i);  // off the route
    }
  }
  if (!everyone_.empty()) return;
  hit_.assign(visits_.size(), 0);
  for (const auto& [position, k] : hits_) {
    (void)k;
    hit_[position] = 1;
  }
  for (std::size_t position = 0; position < visits_.size(); ++position) {
    if (hit_[position] == 0) check(visits_[position].index);
  }
}

void Segment::dispatch_to_every_slave(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  for (const Visit& v : visits_) {
    if (hooks_ != nullptr && hooks_->slave_unreachable(v.index)) continue;
    Esc& esc = *nodes_[v.index].esc;
    PassContext pass = v.pass;
    pass.epu_time_ns += now_ns;
    for (std::size_t p = 0; p < 4; ++p) {
      if (pass.port_seen[p]) pass.port_time_ns[p] += now_ns;
    }
    for (std::size_t k = 0; k < slots_.size(); ++k) {
      if (!slots_[k].command) continue;
      std::uint8_t* base = frame.data() + slots_[k].offset;
      DatagramInFlight d;
      d.command = *slots_[k].command;
      d.address = wire::load_le32(base + 2);
      d.data = std::span<std::uint8_t>(base + wire::kDatagramHeaderSize, slots_[k].length);
      std::uint8_t* wkc = base + wire::kDatagramHeaderSize + slots_[k].length;
      d.wkc = wire::load_le16(wkc);
      const DatagramEffect effect = esc.process(d, pass);
      if (hooks_ != nullptr) hooks_->after_datagram(v.index, k, d, effect);
      wire::store_le32(base + 2, d.address);
      wire::store_le16(wkc, d.wkc);
    }
  }
}

void Segment::dispatch(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  // Slave-major, as the frame travels: each reachable slave processes the datagrams that address
  // it, in frame order; a slave no datagram addresses only sees the frame pass.
  std::size_t reachable = 0;
  std::size_t hit = 0;
  std::size_t positional = 0;
  for (std::size_t position = 0; position < visits_.size(); ++position) {
    const Visit& v = visits_[position];
    const std::size_t hits_begin = hit;
    while (hit < hits_.size() && hits_[hit].first == position)
      ++hit;
    const std::size_t hits_end = hit;
    if (hooks_ != nullptr && hooks_->slave_unreachable(v.index)) {
      // Cut off: not addressed after all, so work due is done here (see advance_due).
      if (nodes_[v.index].esc->advance_due(now_ns)) advance_for_frame(v.index, now_ns);
      continue;
    }
    const std::size_t ordinal = reachable++;
    while (positional < positional_.size() && positional_[positional].first < ordinal)
      ++positional;
    std::size_t positional_end = positional;
    while (positional_end < positional_.size() && positional_[positional_end].first == ordinal)
      ++positional_end;
    if (valid_.empty()) continue;

    Node& node = nodes_[v.index];
    Esc& esc = *node.esc;
    PassContext pass = v.pass;
    pass.epu_time_ns += now_ns;
    for (std::size_t p = 0; p < 4; ++p) {
      if (pass.port_seen[p]) pass.port_time_ns[p] += now_ns;
    }
    if (everyone_.empty() && hits_begin == hits_end && positional == positional_end) {
      // Not addressed: only an ESC with time-driven work due notes the frame passing (pass_by
      // finishes SII operations and steps DC; an idle ESC has neither to do).
      if (node.advanced_in == frame_serial_) esc.pass_by(pass);
      continue;
    }
    advance_for_frame(v.index, now_ns);
    // Walk the frame's datagrams; those not addressing this slave only pass it (pass_by is
    // idempotent and process() starts with it, so one after the last processed one suffices).
    // Should the slave's addresses or FMMUs change on the way, it processes every datagram left.
    bool all = false;
    bool passed_after = false;
    std::size_t e = 0;
    std::size_t h = hits_begin;
    std::size_t a = positional;
    for (const std::size_t k : valid_) {
      bool addressed = all;
      if (e < everyone_.size() && everyone_[e] == k) {
        addressed = true;
        ++e;
      }
      if (h < hits_end && hits_[h].second == k) {
        addressed = true;
        ++h;
      }
      if (a < positional_end && positional_[a].second == k) {
        addressed = true;
        ++a;
      }
      if (!addressed) {
        passed_after = true;
        continue;
      }
      passed_after = false;
      const Slot& slot = slots_[k];
      std::uint8_t* base = frame.data() + slot.offset;
      DatagramInFlight d;
      d.command = *slot.command;
      d.address = wire::load_le32(base + 2);
      if (d.command == wire::Command::aprd || d.command == wire::Command::apwr ||
          d.command == wire::Command::aprw) {
        // The slaves before this one each incremented the ADP.
        d.set_adp(static_cast<std::uint16_t>(slot.address + ordinal));
      }
      d.data = std::span<std::uint8_t>(base + wire::kDatagramHeaderSize, slot.length);
      std::uint8_t* wkc = base + wire::kDatagramHeaderSize + slot.length;
      d.wkc = wire::load_le16(wkc);
      const DatagramEffect effect = esc.process(d, pass);
      if (hooks_ != nullptr) hooks_->after_datagram(v.index, k, d, effect);
      wire::store_le32(base + 2, d.address);
      wire::store_le16(wkc, d.wkc);
      if (node.index_dirty) all = true;
    }
    if (passed_after) esc.pass_by(pass);
    positional = positional_end;
  }
  // Every reachable slave incremented the ADP of the position-addressed datagrams.
  for (const auto& [ordinal, k] : positional_) {
    (void)ordinal;
    std::uint8_t* base = frame.data() + slots_[k].offset;
    const std::uint32_t address = wire::load_le32(base + 2);
    wire::store_le32(base + 2, (address & 0xFFFF0000u) |
                                   static_cast<std::uint16_t>(slots_[k].address + reachable));
  }
}

bool Segment::process_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
  ++stats_.frames;
  const auto decoded = wire::decode_frame(frame);
  if (!decoded) {
    ++stats_.frames_malformed;
    return false;
  }
  // With no slave the master's port has no link partner: the frame is lost, nothing comes back
  // (soem-sdinfo-no-slaves.pcapng records only the master's frames).
  if (nodes_.empty() || !master_link_ ||
      (hooks_ != nullptr && !hooks_->before_frame(frame, now_ns))) {
    ++stats_.frames_lost;
    return false;
  }
  slots_.clear();
  for (const wire::DatagramView view : *decoded.frame) {
    const auto data_offset = static_cast<std::size_t>(view.data.data() - frame.data());
    const std::uint8_t* base = frame.data() + data_offset - wire::kDatagramHeaderSize;
    slots_.push_back(Slot{data_offset - wire::kDatagramHeaderSize, view.header.length,
                          wire::load_le32(base + 2), wire::command_from_byte(base[0])});
  }
  stats_.datagrams += slots_.size();

  // Re-plan the route when a port's loop control changed since the last frame. Only ESCs whose
  // DL control was written (or that were power cycled) can have changed it.
  bool replan = port_control_seen_.size() != nodes_.size();
  for (const std::size_t i : port_dirty_) {
    if (!replan && nodes_[i].esc->read_u8(reg::kDlPortControl) != port_control_seen_[i]) {
      replan = true;
    }
    nodes_[i].port_dirty = false;
  }
  port_dirty_.clear();
  if (replan) {
    plan(visits_, round_trip_);
    port_control_seen_.resize(nodes_.size());
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      port_control_seen_[i] = nodes_[i].esc->read_u8(reg::kDlPortControl);
    }
    visit_of_.assign(nodes_.size(), kNotVisited);
    for (std::size_t v = 0; v < visits_.size(); ++v)
      visit_of_[visits_[v].index] = v;
    update_dl_status();
  }
  if (!nodes_.empty() && !nodes_[0].link_up[0]) {
    ++stats_.frames_lost;
    return false;
  }

  ++frame_serial_;
  const auto reindex_dirty = [this] {
    for (const std::size_t i : index_dirty_) {
      if (nodes_[i].index_dirty) reindex(i);
    }
    index_dirty_.clear();
  };
  if (reference_dispatch_) {
    for (std::size_t i = 0; i < nodes_.size(); ++i)
      advance_for_frame(i, now_ns);
    reindex_dirty();
    dispatch_to_every_slave(frame, now_ns);
  } else {
    reindex_dirty();
    find_addressed();
    advance_due(now_ns);
    if (!index_dirty_.empty()) {
      // Time-driven work changed a slave's addresses or FMMUs: address the frame again.
      reindex_dirty();
      find_addressed();
    }
    dispatch(frame, now_ns);
  }
  if (hooks_ != nullptr) hooks_->after_frame(frame, now_ns);
  for (auto& callback : after_frame_)
    callback(*this, now_ns);
  return true;
}

}  // namespace ecat::sim
