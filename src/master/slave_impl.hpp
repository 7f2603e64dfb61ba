// Slave::Impl: the control-loop side of a slave. Private to src/master.
#pragma once

#include <atomic>
#include <cstring>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <ecat/config/esi.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/master/coe_client.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/master/slave.hpp>

#include "preop_plan.hpp"
#include "session.hpp"
#include "slave_fsm.hpp"

namespace ecat::master {

class EoeClient;  // <ecat/master/eoe.hpp>

// Writes SM0/SM1 as the mailbox SyncManagers of `mbx` (both disabled first, then configured
// and enabled, in one transaction): the standard mailbox at bring-up, the bootstrap mailbox on
// the way into BOOTSTRAP. Returns the configuration of the Mailbox that uses them.
exec::Task<Result<MailboxConfig>> write_mailbox_sync_managers(exec::EventLoop& loop, bus::Bus& bus,
                                                              std::uint16_t station,
                                                              const wire::SiiMailbox& mbx);

namespace detail {

// The hot path's way to its data (read_input / write_output), made when the attachments and
// signals are: each attachment's domain and registration handle (no lookup by domain name or
// PDO key per call), and the signals by name.
struct SlaveRoute {
  std::uint8_t sync_manager = 0;
  std::uint16_t size = 0;
  Domain* domain = nullptr;
  PdoHandle handle{};
  bool operator==(const SlaveRoute&) const = default;
};
// What read_input / write_output need, as one immutable view read without the slave's `mutex`:
// index_routes makes a new one under the slave's `mutex` and publishes it through Slave::Impl::hot
// (release; readers acquire). A view once published is never changed nor freed while the slave
// lives (a reader may still hold it): Impl::views keeps every one made, and index_routes reuses an
// equal one, so they number the distinct layouts the slave has had (one, unless reconfigured), not
// its reconfigurations.
struct SlaveHotPath {
  std::vector<Signal> signals;  // a copy of Impl::signals
  // A name as the lookup compares it: its length and its first and last eight bytes (they
  // overlap from 8 to 16 bytes; zero-padded below 8), which are the whole name up to 16 bytes;
  // a longer one compares its middle too. Two loads and no library call for a short name.
  struct NameKey {
    std::uint64_t head = 0;
    std::uint64_t tail = 0;
    std::size_t length = 0;
    bool operator==(const NameKey&) const = default;
  };
  static NameKey name_key(std::string_view name) noexcept {
    if (name.size() < 8) return short_name_key(name);
    NameKey key;
    key.length = name.size();
    std::memcpy(&key.head, name.data(), 8);
    std::memcpy(&key.tail, name.data() + name.size() - 8, 8);
    return key;
  }
  static NameKey short_name_key(std::string_view name) noexcept;  // below 8 bytes
  // The table slot to probe first: the key's words mixed by one multiplication, its top bits
  // (`shift`: 64 less the table's size in bits).
  static std::size_t hash(const NameKey& key, unsigned shift) noexcept {
    const std::uint64_t h =
        (key.head ^ (key.tail >> 7) ^ (key.tail << 29) ^ key.length) * 0x9E3779B97F4A7C15ull;
    return shift >= 64 ? 0 : static_cast<std::size_t>(h >> shift);
  }
  // A domain field a scalar signal is read from or staged into (Domain::field: no lookup nor
  // range check per call).
  struct Target {
    Domain* domain = nullptr;
    Domain::Field field;
    bool operator==(const Target&) const = default;
  };
  // How the hot path reaches each signal (same order as `signals`).
  enum class Path : std::uint8_t {
    slow,         // under the slave's `mutex` (a bytes signal, a field outside its image, unrouted)
    input_field,  // read_fresh of `input` (the first domain of its SyncManager)
    output_field,  // write_bits into `targets[first, first + count)`, kept in `*image`
  };
  struct Slot {
    NameKey key;
    Path path = Path::slow;
    Target input;
    std::uint32_t first = 0;
    std::uint32_t count = 0;
    // The retained image of the signal's SyncManager (a node of Impl::output_images: never
    // erased, so the pointer stays; its bytes are read and written under the output lock).
    std::vector<std::uint8_t>* image = nullptr;
    std::size_t image_size = 0;
    bool operator==(const Slot&) const = default;
  };
  std::vector<Slot> slots;
  std::vector<Target> targets;
  // The signals by name: open addressing over a power-of-two table of signal index + 1 (0:
  // empty), at most half full, probed linearly from hash(name_key(name)); empty when two
  // signals share a name (find then walks `signals`, keeping the first). Our own rather than
  // std::unordered_map because it is on read_input/write_output's path (issue #17's 50 ns
  // target): no node per entry to chase, and two words compared per probe.
  std::vector<std::uint32_t> signal_index;
  unsigned index_shift = 64;  // 64 less log2 of signal_index's size
  std::vector<SlaveRoute> routes;
  bool all_routed = false;  // a route for every attachment (else writes look domains up)
  // Sets every slot's key and fills signal_index from `signals` (index_routes).
  void index_names();
  // The index of the signal of that name, or -1.
  std::ptrdiff_t find_index(std::string_view name) const noexcept;
  const Signal* find(std::string_view name) const noexcept {
    const std::ptrdiff_t i = find_index(name);
    return i >= 0 ? &signals[static_cast<std::size_t>(i)] : nullptr;
  }
  const SlaveRoute* route_for(std::uint8_t sm) const noexcept;
  bool operator==(const SlaveHotPath&) const = default;
};

}  // namespace detail

struct Slave::Impl {
  Impl(Slave& owner, Session& s, SlaveConfig c);

  Slave& self;
  Session& session;
  SlaveConfig config;
  // Its lifecycle: what the hardware last showed, changed only through set_state (slave_fsm.hpp).
  SlaveFsm fsm;
  SlaveState state() const noexcept { return fsm.state(); }
  // Lost and not yet rebuilt: DOWN, or back in INIT after a failed rebuild that is retried.
  // Loop thread.
  bool rebuild_pending = false;
  bool awaiting_rebuild() const noexcept {
    return state() == SlaveState::down || (rebuild_pending && state() == SlaveState::init);
  }
  // Lost while in INIT or BOOTSTRAP (a fault, no state change); loop thread.
  bool lost_in_place = false;
  // A hot-connect group's slave whose group is not in the ring (SlaveAccess::set_absent).
  std::atomic<bool> absent{false};

  // Guards everything below (application threads read snapshots; the loop writes).
  mutable std::mutex mutex;
  std::optional<std::uint16_t> al_code;
  wire::EscInformation esc{};
  std::optional<SiiReadResult> sii;
  std::optional<config::EsiDevice> esi_device;  // from config.esi_file, once read
  std::optional<wire::SiiIdentity> known_identity;
  std::unique_ptr<Mailbox> mailbox;
  std::shared_ptr<const Driver> driver;
  std::unique_ptr<DriverState> driver_state;
  DeviceState device_state;
  PdoLayout layout;
  std::vector<Signal> signals;
  std::vector<SmAttachment> attachments;
  // The hot path's way to its data and the view of it (detail::SlaveRoute, SlaveHotPath).
  using Route = detail::SlaveRoute;
  using HotPath = detail::SlaveHotPath;
  std::atomic<const HotPath*> hot{nullptr};
  std::vector<std::unique_ptr<const HotPath>> views;  // under `mutex`
  // SM1's status mapped into a domain (mailbox status in the cyclic frame), when it is.
  std::optional<detail::MailboxStatusMapping> mailbox_status;
  // The retained output image of each output SyncManager: what write_output staged; written to
  // every domain the SyncManager is in, and again after a reconnect. Guarded by `output_lock`
  // (taken inside `mutex` where both are): write_output's scalar path stages into the domains
  // and updates this image under it alone, so two writers leave the image and the domains alike.
  std::map<std::uint8_t, std::vector<std::uint8_t>> output_images;
  // On a cache line of its own: the neighbouring fields are written by other threads.
  alignas(64) mutable std::atomic<bool> output_lock{false};
  struct OutputLock {
    explicit OutputLock(const Impl& impl) noexcept;
    ~OutputLock();
    OutputLock(const OutputLock&) = delete;
    OutputLock& operator=(const OutputLock&) = delete;
    const Impl& impl;
  };
  std::vector<std::uint8_t> write_scratch;  // Slave::write_output's encoding buffer
  std::optional<std::string> configuration_error;
  std::optional<Error> configuration_failure;  // the same, as the error it was
  std::optional<std::string> fault;
  // Why the last attempt to bring the slave to PREOP failed, while the session still retries
  // (awaiting_preop); cleared when the slave gets there.
  std::optional<std::string> startup_error;

  // Read by Master::counters() from any thread.
  struct Counters {
    std::atomic<std::uint64_t> wkc_errors{0};       // health polls without this slave's WKC
    std::atomic<std::uint64_t> sdo_failures{0};     // SDO transfers that failed
    std::atomic<std::uint64_t> mailbox_retries{0};  // refreshed after each SDO transfer
  } counters;

  // Every change of the state goes through here (the fsm refuses and counts an undrawn one);
  // a change made is published as a slave.state event.
  void set_state(SlaveState to) noexcept;
  // A bring-up retried from INIT: the seed's init -> init edge, published as such.
  void note_retry_in_init() noexcept;
  // A tracked fault raised (published) or cleared (published when there was one). Take `mutex`
  // for neither: they take it.
  void raise_fault(std::string why);
  void clear_fault();
  // An SDO transfer's failure, counted and published (sdo.failed or mailbox.failed).
  void note_sdo_failure(const Error& error);
  // Copies the mailbox's retry counts into `counters` (loop thread, after an exchange).
  void note_mailbox_counters() noexcept;

  struct Subscription {
    SubscriptionId id;
    std::string signal;
    std::function<void(const SignalEvent&)> callback;
    std::optional<Value> last;
  };
  std::vector<Subscription> subscriptions;
  SubscriptionId next_subscription = 0;

  std::string who() const;
  void record_al_error(const Error& error);
  Result<void> check_mailbox() const;
  // The signal of that name in the published view (nullptr before the first configuration).
  const Signal* find_signal(std::string_view name) const noexcept;
  const SmAttachment* attachment_for(std::uint8_t sm) const noexcept;
  // A signal the hot path reads and stages as its own bits (a Domain::Field: read_fresh /
  // write_bits, decode_field / encode_field): a scalar of 1..64 bits inside an SM image of
  // `image_bytes`. Others (bytes, a field outside its image) take the whole-image path, whose
  // codecs name what is wrong.
  static bool is_field(const Signal& s, std::size_t image_bytes) noexcept {
    return s.type != SignalType::bytes && s.bit_length != 0 && s.bit_length <= 64 &&
           std::uint64_t{s.bit_offset} + s.bit_length <= std::uint64_t{image_bytes} * 8;
  }
  // Makes the view of `attachments` and `signals` and publishes it through `hot` (under `mutex`).
  void index_routes();
  // Engineering values of every signal: inputs from `inputs` (per SM image), outputs as staged;
  // 0 where an image is missing (mutex held).
  std::vector<Value> signal_values(
      const std::map<std::uint8_t, std::vector<std::uint8_t>>& inputs) const;
  // The driver's projected device state from these input images and the staged outputs
  // (mutex held).
  void project(const std::map<std::uint8_t, std::vector<std::uint8_t>>& inputs);
  // Called on the loop with an input change of this slave (subscriptions).
  void on_input_change(const InputChange& change);

  // INIT -> ESC info -> SII -> mailbox -> PREOP -> PREOP configuration (whose failure is
  // retained, not returned).
  exec::Task<Result<void>> bring_up(std::shared_ptr<Session> keep);
  // Health: while the slave is in PREOP or above, reads AL status every health_poll; a slave
  // that stops answering goes `down` and is probed (by station, then by position) until it is
  // back, then rebuilt to PREOP (identity checked) and reported to the master. An OP slave
  // found below OP or with its error flag set is retreated to SAFEOP and reported.
  void start_health(std::shared_ptr<Session> keep);
  exec::Task<void> health_loop(std::shared_ptr<Session> keep);
  exec::Task<bool> probe_and_rebuild(std::shared_ptr<Session> keep);
  bool health_running = false;
  // Consecutive polls whose reply lacked this slave (loop thread only).
  static constexpr int kFailedPollsForDown = 2;
  int failed_polls = 0;
  int busy = 0;  // go_to() calls in progress (loop thread only)
  // The PREOP configuration: the facts it depends on, planned (preop_plan.hpp), then carried out.
  exec::Task<Result<void>> configure_preop(std::shared_ptr<Session> keep);
  detail::PreopFacts preop_facts() const;
  // SYNC0/SYNC1 and latch units from config.sync, on the way to SAFEOP (DC sessions only).
  exec::Task<Result<void>> apply_sync();
  // After a rebuild: a DC slave's offset, delay and filters again (a power cycle reset them),
  // from a DC slave that kept its time; nothing is written to any other slave.
  exec::Task<Result<void>> reinit_dc();
  std::optional<DcSyncResult> dc_sync;  // guarded by `mutex`
  // Latch edges (config.sync->latches) are polled while the slave is in SAFEOP or OP and handed
  // to the subscribers of the latch's name.
  exec::Task<void> latch_loop(std::shared_ptr<Session> keep);
  bool latch_running = false;  // loop thread only
  const LatchConfig* find_latch(std::string_view name) const;
  exec::Task<Result<void>> run_sdos(const std::vector<SdoWrite>& writes);
  // The assignment and mapping objects of the SyncManagers coe_assignments_to_read() names; a
  // PDO whose mapping object is missing is left to `known` (a fixed PDO the SII describes).
  exec::Task<Result<CoePdoConfiguration>> read_coe_pdos(const PdoLayout& known);
  exec::Task<Result<void>> go_to(wire::AlState target, std::shared_ptr<Session> keep);
  // go_to's walk itself, for the firmware update that holds the slave (go_to refuses then).
  exec::Task<Result<void>> walk_to(wire::AlState target, std::shared_ptr<Session> keep);

  // ---- EoE (slave_eoe.cpp): frame counter, reassembly and counters, made at the first use ----
  std::shared_ptr<EoeClient> eoe;  // loop thread only

  // ---- FoE and BOOTSTRAP (slave_foe.cpp) ----
  // The mailbox of the SII's bootstrap mailbox while the slave is in BOOTSTRAP: go_to writes its
  // SyncManagers before the step INIT -> BOOT and the standard mailbox's again after BOOT -> INIT.
  std::unique_ptr<Mailbox> boot_mailbox;
  // A firmware update holds the slave (loop thread): go_to refuses everyone else's requests, so
  // the session's retries do not pull it out of BOOTSTRAP, and the health loop waits (busy).
  bool firmware_update = false;
  exec::Task<Result<void>> enter_boot_mailbox();
  exec::Task<Result<void>> leave_boot_mailbox();
  // The mailbox FoE uses now (standard in PREOP and above, bootstrap in BOOT), or why none.
  Result<Mailbox*> foe_mailbox() const;
  exec::Task<Result<void>> firmware_update_task(std::string name, std::vector<std::uint8_t> image,
                                                FoeOptions options, std::shared_ptr<Session> keep);
  exec::Task<Result<void>> reconfigure(SlaveConfig next, std::shared_ptr<Session> keep);
  exec::Task<Result<void>> retry_configuration(std::shared_ptr<Session> keep);
  exec::Task<Result<std::vector<std::uint8_t>>> sdo_upload(std::uint16_t index,
                                                           std::uint8_t subindex,
                                                           SdoOptions options,
                                                           std::shared_ptr<Session> keep);
  exec::Task<Result<void>> sdo_download(std::uint16_t index, std::uint8_t subindex,
                                        std::vector<std::uint8_t> data, SdoOptions options,
                                        std::shared_ptr<Session> keep);
};

}  // namespace ecat::master
