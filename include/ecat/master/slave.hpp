// One slave of a running session: its AL state machine (seeds/slave.md), identity, process data
// as named signals, SDO access and events.
//
// Slave objects belong to the Master; get one with Master::slave(name). Every call is
// thread-safe. read_input / write_output touch only the domains' images (never the control
// loop); the others are handed to the control loop and answered within their timeout.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/master/config.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/master/pdo.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/master/states.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sdo_info.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::wire {
struct VoeMessage;  // <ecat/wire/voe.hpp>: declared only, so the application's face stays small
struct EoeIpParameters;                 // <ecat/wire/eoe.hpp>
enum class MailboxType : std::uint8_t;  // <ecat/wire/mailbox.hpp>
}  // namespace ecat::wire

namespace ecat::master {

struct Session;
struct SoeNotification;  // <ecat/master/soe.hpp>
// Options of the calls below that take them, declared only so that the application's face stays
// small: callers that pass options include the header.
struct FoeOptions;       // <ecat/master/foe.hpp>
struct SiiWriteOptions;  // <ecat/master/sii_writer.hpp>
struct EoeStats;         // <ecat/master/eoe.hpp>
struct MailboxMessage;   // <ecat/master/mailbox.hpp>
namespace detail {
class SlaveAccess;
}

// Where one SyncManager's image lives in one domain (one FMMU).
struct SmAttachment {
  std::uint8_t sync_manager = 0;
  PdoDirection direction = PdoDirection::input;
  std::string domain;
  std::uint32_t logical_address = 0;
  std::uint16_t physical_address = 0;
  std::uint16_t size = 0;
  std::uint8_t fmmu = 0;
};

struct SlaveInfo {
  std::string name;
  std::uint16_t position = 0;
  std::uint16_t station = 0;
  SlaveState state = SlaveState::init;
  TargetState target = TargetState::op;
  std::optional<std::uint16_t> al_status_code;  // the last refusal / error the slave reported
  std::optional<wire::SiiIdentity> identity;
  std::string device_name;  // from the SII
  wire::EscInformation esc{};
  std::optional<wire::DlStatus> dl_status;  // ports as read at discovery
  bool has_mailbox = false;
  bool coe = false;
  // The domain SM1's status is mapped into (MasterConfig::mailbox_status), and the FMMU mapping
  // it; empty: the mailbox is polled.
  std::string mailbox_status_domain;
  std::uint8_t mailbox_status_fmmu = 0;
  std::string driver;
  PdoLayout layout;
  std::vector<Signal> signals;
  std::vector<SmAttachment> attachments;
  std::optional<std::string> configuration_error;  // retained PREOP configuration failure
  std::optional<std::string> fault;                // tracked slave-local fault
  // Why the last attempt to bring the slave to PREOP failed while the session still retries
  // (awaiting_preop); empty once it is there.
  std::optional<std::string> startup_error;
  DeviceState device_state;
  // The SYNC/latch configuration written on the way to SAFEOP (DC sessions with `sync` set).
  std::optional<DcSyncResult> dc_sync;
};

struct SignalEvent {
  std::string slave;
  std::string signal;
  Value value;
  std::uint64_t cycle = 0;
  Clock::time_point at;
};

using SubscriptionId = std::uint64_t;

class Slave {
 public:
  Slave(Session& session, SlaveConfig config, std::uint16_t position, std::uint16_t station);
  ~Slave();
  Slave(const Slave&) = delete;
  Slave& operator=(const Slave&) = delete;

  const std::string& name() const noexcept { return name_; }
  // Where the slave sits in the ring; a hot-connect group's slave takes the position where its
  // group was found each time it appears.
  std::uint16_t position() const noexcept { return position_.load(std::memory_order_relaxed); }
  std::uint16_t station() const noexcept { return station_; }
  SlaveState state() const noexcept;
  TargetState target() const;
  // The AL status code the slave last reported with its error flag, if any.
  std::optional<std::uint16_t> error() const;
  // Vendor, product, revision, serial (from the SII); Errc::not_ready before it was read.
  Result<wire::SiiIdentity> identity() const;
  // The SII EEPROM image as read when the slave was brought up (words 0 up to the end marker);
  // Errc::not_ready before it was read.
  Result<std::vector<std::uint8_t>> sii_image() const;
  SlaveInfo info() const;

  // Walks the AL state machine to `target` (intermediate states included). Errc::al_error with
  // the AL status code when the slave refuses; Errc::wrong_state when it is down or SAFEOP/OP is
  // asked while a PREOP configuration failure is retained.
  Result<void> request(wire::AlState target,
                       std::chrono::nanoseconds timeout = std::chrono::seconds(10));
  // Replaces the slave's configuration (in PREOP only) and re-runs the PREOP setup.
  Result<void> configure(SlaveConfig config,
                         std::chrono::nanoseconds timeout = std::chrono::seconds(10));
  // Re-runs a failed PREOP configuration; ok when there is none.
  Result<void> retry(std::chrono::nanoseconds timeout = std::chrono::seconds(10));

  // CoE SDO transfers (Errc::unsupported for a slave without CoE, Errc::wrong_state below PREOP).
  Result<std::vector<std::uint8_t>> upload_sdo(std::uint16_t index, std::uint8_t subindex,
                                               SdoOptions options = {});
  Result<void> download_sdo(std::uint16_t index, std::uint8_t subindex,
                            std::vector<std::uint8_t> data, SdoOptions options = {});

  // CoE SDO information service (same states as the SDO transfers; Errc::unsupported through
  // an SDO information error reply when the device has no SDO information).
  Result<std::vector<std::uint16_t>> object_list(wire::OdListType type = wire::OdListType::all,
                                                 SdoOptions options = {});
  Result<wire::ObjectDescriptionResponse> describe_object(std::uint16_t index,
                                                          SdoOptions options = {});
  // `value_info`: wire::kValueInfo* flags (unit, default, minimum, maximum value).
  Result<wire::EntryDescriptionResponse> describe_entry(std::uint16_t index, std::uint8_t subindex,
                                                        std::uint8_t value_info = 0,
                                                        SdoOptions options = {});

  // FoE
  // File access over EtherCAT (master/foe.hpp): Errc::unsupported when the slave's SII does not
  // declare FoE, Errc::wrong_state unless the slave is in PREOP or higher, or in BOOTSTRAP (then
  // over the bootstrap mailbox). FoeOptions::progress is called on the control thread.
  Result<std::vector<std::uint8_t>> foe_read(std::string_view name);
  Result<std::vector<std::uint8_t>> foe_read(std::string_view name, const FoeOptions& options);
  Result<void> foe_write(std::string_view name, std::vector<std::uint8_t> data);
  Result<void> foe_write(std::string_view name, std::vector<std::uint8_t> data,
                         const FoeOptions& options);
  // A firmware update as devices expect it: INIT, then BOOTSTRAP with the mailbox SyncManagers
  // of the SII's bootstrap mailbox, the image written as file `name`, then INIT again (the device
  // starts the new image) and PREOP, and the session brings the slave back to its target as
  // after a rebuild. The session's retries and health checks leave the slave alone meanwhile.
  // Errc::unsupported without FoE or a bootstrap mailbox; a failed write still ends in INIT.
  Result<void> update_firmware(std::string_view name, std::vector<std::uint8_t> image);
  Result<void> update_firmware(std::string_view name, std::vector<std::uint8_t> image,
                               const FoeOptions& options);

  // SII EEPROM (src/master/slave_sii.cpp; sii_writer.hpp for the options). Allowed in INIT and
  // PREOP only (Errc::wrong_state otherwise); on success the session's copy of the SII and the
  // slave's identity are read again from the EEPROM. The ESC loads the configuration area (the
  // alias among it) at its next power-up.
  // `image`: little-endian bytes from word 0; `words`: from `word_address` on.
  Result<void> write_sii(std::span<const std::uint8_t> image);
  Result<void> write_sii(std::span<const std::uint8_t> image, const SiiWriteOptions& options);
  Result<void> write_sii(std::uint32_t word_address, std::vector<std::uint16_t> words);
  Result<void> write_sii(std::uint32_t word_address, std::vector<std::uint16_t> words,
                         const SiiWriteOptions& options);
  // SII word 4 (and its checksum); with options.write_alias_register also 0x0012, which fails
  // with Errc::unsupported naming the register when the ESC does not take it (real ESCs do not).
  Result<void> write_alias(std::uint16_t alias);
  Result<void> write_alias(std::uint16_t alias, const SiiWriteOptions& options);

  // SoE
  // IDN parameters of SERCOS drives (master/soe.hpp): Errc::unsupported when the slave's SII does
  // not declare SoE, Errc::wrong_state below PREOP. `elements`: wire::kSoeElement* flags (0x40:
  // the value); a read gives the elements' bytes in element order (master::split_soe_elements
  // takes several apart), fragments reassembled. A drive's refusal is Errc::mailbox_error with
  // its SoE error code in words (master::soe_error_code). `timeout`: for each response.
  Result<std::vector<std::uint8_t>> soe_read(
      std::uint8_t drive, std::uint16_t idn, std::uint8_t elements = 0x40,
      std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  Result<void> soe_write(std::uint8_t drive, std::uint16_t idn, std::uint8_t elements,
                         std::vector<std::uint8_t> data,
                         std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  // Notifications and slave info the drive sent since the last call, oldest first (the mailbox is
  // read first). SoeNotification is in <ecat/master/soe.hpp>.
  Result<std::vector<SoeNotification>> soe_notifications(
      std::chrono::nanoseconds timeout = std::chrono::seconds(2));

  // VoE
  // Vendor specific messages (master/voe.hpp): Errc::unsupported when the SII does not declare
  // VoE, Errc::wrong_state below PREOP. voe_receive gives the oldest VoE message the mailbox
  // queued, else waits for one (wire::VoeMessage is in <ecat/wire/voe.hpp>).
  Result<void> voe_send(std::uint32_t vendor_id, std::uint16_t vendor_type,
                        std::vector<std::uint8_t> data,
                        std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  Result<wire::VoeMessage> voe_receive(std::chrono::nanoseconds timeout = std::chrono::seconds(1));

  // EoE
  // Ethernet over EtherCAT (master/eoe.hpp): Errc::unsupported when the SII does not declare
  // EoE, Errc::wrong_state below PREOP. eoe_send tunnels one Ethernet frame (14..1518 bytes, no
  // FCS) in fragments; eoe_receive gives the frames the slave sent, reassembled, oldest first,
  // waiting up to `timeout` for the first (empty when none came: not an error); eoe_set_ip is the
  // Set IP Parameter service (a refusal is Errc::mailbox_error, master::eoe_result_code).
  Result<void> eoe_send(std::span<const std::uint8_t> frame,
                        std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  Result<std::vector<std::vector<std::uint8_t>>> eoe_receive(
      std::chrono::nanoseconds timeout = std::chrono::milliseconds(100));
  Result<void> eoe_set_ip(const wire::EoeIpParameters& parameters,
                          std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  // The slave's EoE counters (frames, fragments, drops); zeros before the first EoE call.
  Result<EoeStats> eoe_stats(std::chrono::nanoseconds timeout = std::chrono::seconds(1));

  // One mailbox message passed through as another tool wrote it (the mailbox gateway,
  // master/mailbox_gateway.hpp): `type` and `data` go into the slave's mailbox behind the master's
  // own mailbox header (its counter, so the slave takes it as new; serialized with the master's
  // own mailbox traffic), and the slave's next message of the same type is the reply (CoE
  // emergencies stay queued as always). The slave's mailbox error reply is Errc::mailbox_error
  // with the detail code as value(). Errc::unsupported when the slave has no mailbox or its SII
  // does not declare the protocol, Errc::wrong_state below PREOP, Errc::invalid_argument when
  // the data do not fit its mailbox. Writes nothing on its own: what the message asks for (an SDO
  // download) is the caller's request.
  Result<MailboxMessage> mailbox_exchange(
      wire::MailboxType type, std::vector<std::uint8_t> data,
      std::chrono::nanoseconds timeout = std::chrono::seconds(1));

  // CoE emergencies the slave sent since the last call, oldest first (the mailbox is read first,
  // so an emergency waiting in it is included). Empty for a slave without a mailbox.
  Result<std::vector<wire::Emergency>> emergencies(
      std::chrono::nanoseconds timeout = std::chrono::seconds(2));

  // The signals the driver made of the PDO layout (empty before PREOP configuration).
  std::vector<Signal> signals() const;
  // The latest value of an input (or the staged value of an output) signal. Errc::not_ready
  // before the first valid cycle, Errc::stale (with the age) when the last valid cycle is older
  // than the domain's freshness window, Errc::not_found for an unknown signal or one not routed
  // to a domain.
  Result<Value> read_input(std::string_view signal) const;
  // Stages an output for the next cycle of every domain the signal's SyncManager is in. The
  // value is kept while the slave is down and applied when it is back.
  Result<void> write_output(std::string_view signal, const Value& value);
  // Runs a driver command (set_output, enable_operation, ...).
  Result<void> command(std::string_view name, const CommandArgs& args = {});
  // Calls `callback` on the control thread whenever the signal's value changes, or, for the name
  // of a latch in the slave's sync configuration, on every latched edge (value: the edge's
  // system time in ns, std::uint64_t).
  Result<SubscriptionId> subscribe(std::string_view signal,
                                   std::function<void(const SignalEvent&)> callback);
  void unsubscribe(SubscriptionId id);

 private:
  // The control-loop side. Only its name is here: the master drives it through the named
  // operations of detail::SlaveAccess (src/master/slave_access.hpp), so neither applications nor
  // the master's own code depend on its fields.
  friend class detail::SlaveAccess;
  struct Impl;
  Impl& impl() noexcept { return *impl_; }
  const Impl& impl() const noexcept { return *impl_; }

  std::string name_;
  std::atomic<std::uint16_t> position_;
  std::uint16_t station_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::master
