#include <algorithm>

#include <fmt/format.h>

#include <ecat/sim/segment.hpp>

namespace ecat::sim {

namespace reg = wire::reg;

namespace {
// The order in which an ESC forwards a frame out of its ports after processing it.
constexpr std::array<std::uint8_t, 3> kForwardingOrder{3, 1, 2};
constexpr std::size_t kMaxDatagramsPerFrame = wire::kMaxFrameSize / wire::kDatagramOverhead + 1;
}  // namespace

Segment::Segment() {
  slots_.reserve(kMaxDatagramsPerFrame);
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
  port_control_seen_.clear();  // re-plan on the next frame
  update_dl_status();
  return nodes_.size() - 1;
}

std::optional<std::size_t> Segment::find(std::string_view name) const noexcept {
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    if (nodes_[i].name == name) return i;
  }
  return std::nullopt;
}

void Segment::set_link(std::size_t index, std::uint8_t port, bool up) {
  if (index >= nodes_.size() || port > 3) return;
  nodes_[index].link_up[port] = up;
  // A cable has two ends: the peer sees the same link state.
  if (port == 0 && nodes_[index].parent) {
    nodes_[*nodes_[index].parent].link_up[nodes_[index].parent_port] = up;
  } else if (port > 0 && nodes_[index].children[port]) {
    nodes_[*nodes_[index].children[port]].link_up[0] = up;
  }
  port_control_seen_.clear();
  update_dl_status();
}

bool Segment::link(std::size_t index, std::uint8_t port) const {
  return index < nodes_.size() && port <= 3 && nodes_[index].link_up[port];
}

bool Segment::port_open(std::size_t index, std::uint8_t port) const {
  const Node& node = nodes_[index];
  const bool has_link = node.children[port].has_value() && node.link_up[port];
  const std::uint8_t control = (node.esc->read_u8(reg::kDlPortControl) >> (2 * port)) & 0x3;
  switch (control) {
    case 0:  // auto: open with link
    case 1:  // auto close
      return has_link;
    case 2:  // forced open: only useful with a link (without one the frame would be lost)
      return has_link;
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

void Segment::update_dl_status() {
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    Node& node = nodes_[i];
    wire::DlStatus dl = wire::DlStatus::decode(node.esc->read_u16(reg::kDlStatus));
    for (std::uint8_t port = 0; port < 4; ++port) {
      const bool connected =
          port == 0 ? (node.parent.has_value() || i == 0) : node.children[port].has_value();
      const bool link = connected && node.link_up[port];
      dl.ports[port].physical_link = link;
      dl.ports[port].communication = link;
      dl.ports[port].loop_closed = port == 0 ? !link : !port_open(i, port);
    }
    node.esc->pdi_write_u16(reg::kDlStatus, dl.encode());
  }
}

void Segment::add_after_frame(std::function<void(Segment&, std::int64_t)> callback) {
  after_frame_.push_back(std::move(callback));
}

void Segment::advance(std::int64_t now_ns) {
  for (auto& node : nodes_)
    node.esc->advance(now_ns);
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
    slots_.push_back(Slot{data_offset - wire::kDatagramHeaderSize, view.header.length});
  }
  stats_.datagrams += slots_.size();

  // Re-plan the route when a port's loop control changed since the last frame.
  bool replan = port_control_seen_.size() != nodes_.size();
  if (!replan) {
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      if (nodes_[i].esc->read_u8(reg::kDlPortControl) != port_control_seen_[i]) {
        replan = true;
        break;
      }
    }
  }
  if (replan) {
    plan(visits_, round_trip_);
    port_control_seen_.resize(nodes_.size());
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      port_control_seen_[i] = nodes_[i].esc->read_u8(reg::kDlPortControl);
    }
    update_dl_status();
  }
  if (!nodes_.empty() && !nodes_[0].link_up[0]) {
    ++stats_.frames_lost;
    return false;
  }

  advance(now_ns);
  for (const Visit& v : visits_) {
    if (hooks_ != nullptr && hooks_->slave_unreachable(v.index)) continue;
    Esc& esc = *nodes_[v.index].esc;
    PassContext pass = v.pass;
    pass.epu_time_ns += now_ns;
    for (std::size_t p = 0; p < 4; ++p) {
      if (pass.port_seen[p]) pass.port_time_ns[p] += now_ns;
    }
    for (std::size_t k = 0; k < slots_.size(); ++k) {
      std::uint8_t* base = frame.data() + slots_[k].offset;
      const auto command = wire::command_from_byte(base[0]);
      if (!command) continue;
      DatagramInFlight d;
      d.command = *command;
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
  if (hooks_ != nullptr) hooks_->after_frame(frame, now_ns);
  for (auto& callback : after_frame_)
    callback(*this, now_ns);
  return true;
}

}  // namespace ecat::sim
