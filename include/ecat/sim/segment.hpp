// A simulated EtherCAT segment: emulated ESCs wired into a topology. A frame enters the first
// slave's port 0, is processed by each ESC's processing unit in the order a real segment visits
// them (depth first, ports in ESC forwarding order 0 -> 3 -> 1 -> 2), and returns to the master.
// Every hop costs time, so DC receive-time latches see realistic, topology-dependent times.
//
// What a frame costs: an ESC a datagram addresses advances just before its first datagram and
// processes the datagrams that address it; of the others, those with time-driven work due
// (Esc::advance_due: a running SII operation, a watchdog running out, DC SYNC, a device model)
// advance and note the frame passing (its time, for DC), and the rest are not touched (a frame
// addressing every slave, an LRW over the ring or a broadcast, checks none). Indexes kept
// as registers change (EscLayoutObserver) find them: configured addresses and aliases for FP*,
// the FMMUs' logical ranges for LRD/LWR/LRW, the position for AP* (whose ADP the slaves passed
// increment is computed); broadcasts reach every ESC. An ESC whose addressing or FMMUs change while
// it processes a frame sees the rest of that frame datagram by datagram, as before.
//
// Not thread-safe: one thread processes frames (the server holds a lock around it).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::sim {

// Where a slave is attached: to which port of which earlier slave.
struct Attachment {
  // Index of the slave this one hangs off; nullopt = the previous slave (a line).
  std::optional<std::size_t> parent;
  // The parent's port (1, 2 or 3) this slave's port 0 is cabled to.
  std::uint8_t parent_port = 1;
  // Propagation delay of the cable into this slave's port 0.
  std::int64_t cable_delay_ns = 5;
};

// Timing of the processing and forwarding inside one ESC.
struct HopTiming {
  std::int64_t processing_delay_ns = 100;  // port 0 in -> processing unit -> next port out
  std::int64_t forwarding_delay_ns = 50;   // a port's return path through the ESC
};

// Observes and alters processing, for fault injection (include/ecat/sim/faults.hpp).
class SegmentHooks {
 public:
  virtual ~SegmentHooks() = default;
  // Before a frame: return false to lose it (no reply at all).
  virtual bool before_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
    (void)frame;
    (void)now_ns;
    return true;
  }
  // Whether slave `index` is cut off for this frame (the frame passes it unprocessed, and it is
  // not counted for auto-increment addressing).
  virtual bool slave_unreachable(std::size_t index) {
    (void)index;
    return false;
  }
  // After slave `index` processed a datagram. Only for the slaves a datagram addresses (or may
  // address: broadcasts, positions, stations, FMMU ranges), not for every slave it passes.
  virtual void after_datagram(std::size_t index, std::size_t datagram_number,
                              DatagramInFlight& datagram, const DatagramEffect& effect) {
    (void)index;
    (void)datagram_number;
    (void)datagram;
    (void)effect;
  }
  // After the whole frame; may still change it (e.g. a WKC offset per command).
  virtual void after_frame(std::span<std::uint8_t> frame, std::int64_t now_ns) {
    (void)frame;
    (void)now_ns;
  }
};

struct SegmentStats {
  std::uint64_t frames = 0;
  std::uint64_t frames_lost = 0;       // hooks or topology swallowed them
  std::uint64_t frames_malformed = 0;  // not an EtherCAT frame: ignored, not answered
  std::uint64_t datagrams = 0;
};

class Segment : private EscLayoutObserver {
 public:
  Segment();
  ~Segment() override;
  Segment(const Segment&) = delete;
  Segment& operator=(const Segment&) = delete;

  // Adds a slave; returns its index (its position in a line). Fails for a parent that does not
  // exist, a port outside 1..3 or one already taken, or a duplicate name.
  Result<std::size_t> add_slave(std::string name, std::unique_ptr<Esc> esc,
                                Attachment attachment = {}, HopTiming timing = {});

  std::size_t size() const noexcept { return nodes_.size(); }
  Esc& esc(std::size_t index) { return *nodes_.at(index).esc; }
  const Esc& esc(std::size_t index) const { return *nodes_.at(index).esc; }
  const std::string& name(std::size_t index) const { return nodes_.at(index).name; }
  std::optional<std::size_t> find(std::string_view name) const noexcept;
  // Where slave `index` is cabled: the slave whose port its port 0 hangs on and that port
  // (none for the first slave: the master).
  std::optional<std::size_t> parent(std::size_t index) const { return nodes_.at(index).parent; }
  std::uint8_t parent_port(std::size_t index) const { return nodes_.at(index).parent_port; }

  // Processes one EtherCAT frame (header + datagrams) in place at segment time `now_ns`.
  // Returns false when no reply goes back (lost frame, malformed frame, master link down).
  bool process_frame(std::span<std::uint8_t> ethercat_frame, std::int64_t now_ns);

  // Lets every ESC's time-driven behaviour advance (all of them: the idle advance).
  void advance(std::int64_t now_ns);

  // Physical link of slave `index`'s `port` (0 = towards the master). Down on port 0 cuts the
  // slave and everything behind it off; the parent's port then closes its loop. Loop control
  // (DL control 0x0101, two bits per port) decides whether a port with link is open: 00 auto
  // (open with link), 01 auto close (closed at link down and kept closed when the link comes
  // back, until the master writes 01 to the port's bits again while it has link: DL status then
  // shows link up, loop closed), 10 open, 11 closed. A frame arriving from outside at a port
  // closed by auto close (which also opens it on a real ESC) does not exist here: frames enter
  // at the first slave's port 0 only.
  void set_link(std::size_t index, std::uint8_t port, bool up);
  bool link(std::size_t index, std::uint8_t port) const;
  // The master's own link to the first slave.
  void set_master_link(bool up) noexcept { master_link_ = up; }
  // The link slave `index`'s `port` reports in its DL status (0x0110) when it differs from what
  // the segment's own cables say, without changing where the segment's frames go: a master port
  // cabled to a free port (a redundant ring's far end), or a cable broken while another part of
  // the simulator (RedundantPorts) routes the frames round the break. nullopt: the cables' word.
  void set_reported_link(std::size_t index, std::uint8_t port, std::optional<bool> up);

  // Hot connect: a group is slave `first` and everything cabled behind it; it hangs on the cable
  // into `first`'s port 0 (the end of a line, or a junction port of its parent). Unplugging takes
  // that cable down (the parent's port loses its link and closes its loop, as DL status shows);
  // plugging powers every slave of the group up afresh (station 0, INIT, as a device that was
  // switched off) and brings the cable up. Fails for an unknown slave, a slave with no parent, a
  // name used twice or a slave already in a group.
  Result<void> add_hot_connect_group(std::string name, std::size_t first);
  Result<void> plug(std::string_view group, bool plugged, std::int64_t now_ns);
  struct HotConnectGroupInfo {
    std::string name;
    std::size_t first = 0;
    std::size_t slaves = 0;  // in the group
    bool plugged = true;
  };
  std::vector<HotConnectGroupInfo> hot_connect_groups() const;

  // The slaves the frame visits, in processing order (reachable ones only).
  std::vector<std::size_t> processing_order() const;
  // The time a frame needs for the whole round trip through the segment.
  std::int64_t round_trip_ns() const;

  void set_hooks(SegmentHooks* hooks) noexcept { hooks_ = hooks; }
  // Called after every frame, e.g. to move wired outputs to inputs.
  void add_after_frame(std::function<void(Segment&, std::int64_t now_ns)> callback);

  const SegmentStats& stats() const noexcept { return stats_; }

  // Every reachable slave processes every datagram, as the frame physically passes them, instead
  // of the slaves the indexes find: slower, the same result (tests hold the indexes to it).
  void set_reference_dispatch(bool on) noexcept { reference_dispatch_ = on; }

 private:
  struct Node {
    // What every frame touches first (one cache line), the rest after.
    std::unique_ptr<Esc> esc;
    std::uint64_t advanced_in = 0;  // the frame (frame_serial_) this ESC was last advanced in
    bool port_dirty = false;        // port control not compared since the layout changed
    bool index_dirty = false;       // addresses and FMMUs not re-read since the layout changed
    std::string name;
    std::optional<std::size_t> parent;
    std::uint8_t parent_port = 1;
    std::array<std::optional<std::size_t>, 4> children{};  // by port; [0] unused
    std::array<bool, 4> link_up{true, true, true, true};
    std::array<std::optional<bool>, 4> reported_link{};  // set_reported_link
    // Loop control "auto close" (0x0101 bits 01): the port was closed at link down (or 01 was
    // written while it had no link) and stays closed, link or not, until 01 is written again
    // while it has a link. Only read in that mode.
    std::array<bool, 4> auto_closed{};
    std::int64_t cable_delay_ns = 5;
    HopTiming timing;
    // Dispatch indexes (see esc_layout_changed): what they hold for this node.
    std::array<std::uint16_t, 2> keys{};  // station address, alias (when enabled and different)
    std::uint8_t key_count = 0;
    std::vector<std::pair<std::uint64_t, std::uint64_t>> logical;  // FMMU bytes [first, end)
  };
  struct LogicalRange {
    std::uint64_t first = 0;
    std::uint64_t end = 0;
    std::size_t node = 0;
  };
  struct Visit {
    std::size_t index = 0;
    PassContext pass;  // times relative to the frame start
  };

  bool port_open(std::size_t index, std::uint8_t port) const;
  void plan(std::vector<Visit>& visits, std::int64_t& round_trip) const;
  std::int64_t visit(std::size_t index, std::int64_t arrival, std::vector<Visit>& visits) const;
  void update_dl_status();
  void update_dl_status(std::size_t index);  // one slave's
  void esc_layout_changed(std::size_t tag) override;
  void esc_port_control_written(std::size_t tag) override;
  bool has_link(std::size_t index, std::uint8_t port) const noexcept;
  std::uint8_t loop_control(std::size_t index, std::uint8_t port) const noexcept;
  void reindex(std::size_t index);
  void rebuild_logical_index();
  void find_addressed();
  void dispatch(std::span<std::uint8_t> frame, std::int64_t now_ns);
  // Advances the ESCs with work due (Esc::advance_due) for this frame.
  void advance_due(std::int64_t now_ns);
  // Advances node `index` for this frame unless it already was.
  void advance_for_frame(std::size_t index, std::int64_t now_ns) {
    Node& node = nodes_[index];
    if (node.advanced_in == frame_serial_) return;
    node.advanced_in = frame_serial_;
    node.esc->advance(now_ns);
  }
  void dispatch_to_every_slave(std::span<std::uint8_t> frame, std::int64_t now_ns);

  std::vector<Node> nodes_;
  // Name -> index (find() and add_slave's duplicate check without a walk over every slave).
  struct NameHash {
    using is_transparent = void;
    std::size_t operator()(std::string_view name) const noexcept {
      return std::hash<std::string_view>{}(name);
    }
  };
  std::unordered_map<std::string, std::size_t, NameHash, std::equal_to<>> by_name_;
  std::vector<std::pair<std::string, std::size_t>> hot_connect_;  // group name, first slave
  bool behind(std::size_t index, std::size_t first) const noexcept;
  std::vector<Visit> visits_;  // reused per frame; no allocation in steady state
  std::int64_t round_trip_ = 0;
  bool master_link_ = true;
  bool reference_dispatch_ = false;
  SegmentHooks* hooks_ = nullptr;
  std::vector<std::function<void(Segment&, std::int64_t)>> after_frame_;
  SegmentStats stats_;
  std::uint64_t frame_serial_ = 0;  // frames processed (Node::advanced_in)
  struct Slot {
    std::size_t offset = 0;
    std::size_t length = 0;
    std::uint32_t address = 0;  // as the frame arrived
    std::optional<wire::Command> command;
  };
  std::vector<Slot> slots_;
  std::vector<std::uint8_t> port_control_seen_;

  // Dispatch indexes, kept by esc_layout_changed.
  std::vector<std::size_t> port_dirty_;   // nodes whose port control may have changed
  std::vector<std::size_t> index_dirty_;  // nodes whose addresses or FMMUs may have changed
  std::unordered_map<std::uint16_t, std::vector<std::size_t>> by_address_;  // -> nodes
  std::vector<LogicalRange> logical_;                                       // by first
  std::uint64_t logical_max_length_ = 0;
  bool logical_dirty_ = true;
  std::vector<std::size_t> visit_of_;  // node -> position in visits_ (kNotVisited: off route)
  // Per frame: datagrams with a valid command, those every slave processes, (visit, datagram)
  // pairs from the indexes, (reachable position, datagram) for AP*.
  std::vector<std::size_t> valid_;
  std::vector<std::size_t> everyone_;
  std::vector<std::pair<std::size_t, std::size_t>> hits_;
  std::vector<std::uint8_t> hit_;  // by route position: some datagram of this frame hits it
  std::vector<std::pair<std::size_t, std::size_t>> positional_;
};

}  // namespace ecat::sim
