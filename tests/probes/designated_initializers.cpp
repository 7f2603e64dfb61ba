// Every public configuration struct, initialised the way users write them: designated
// initialisers naming one member and omitting the others. Compiled with -Wall -Wextra -Werror
// (tests/CMakeLists.txt, api.designated_initializers): GCC's -Wmissing-field-initializers warns
// for every omitted member that has no default member initialiser, so each member of these
// structs carries one (`std::string name{};`).
#include <chrono>

#include <ecat/bus/bus.hpp>
#include <ecat/ecat.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/master/coe_client.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/master/sii_reader.hpp>
#include <ecat/sim/capture_verify.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/pdo_mapping.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/sim/standard_application.hpp>

using namespace std::chrono_literals;
namespace m = ecat::master;

void designated_initializers() {
  // Master and its parts.
  [[maybe_unused]] m::MasterConfig master{.backend = "sim:ring.yaml"};
  [[maybe_unused]] m::MasterConfig master2{.scan = {.poll = 2ms}, .retry_interval = 1s};
  [[maybe_unused]] m::SlaveConfig slave{.name = "inputs"};
  [[maybe_unused]] m::SlaveConfig slave2{.target = m::TargetState::preop};
  [[maybe_unused]] m::DomainConfig domain{.id = "main", .period = 1ms};
  [[maybe_unused]] m::DomainConfig domain2{.period = 2ms};
  [[maybe_unused]] m::DcConfig dc{.await_lock = true};
  [[maybe_unused]] m::SyncConfig sync{.mode = m::SyncMode::sync0};
  [[maybe_unused]] m::LatchConfig latch{.unit = 1};
  [[maybe_unused]] m::CycleThreadOptions cycle_thread{.cpu = 1};
  [[maybe_unused]] m::ProcessDataRequest process_data{.kind = m::ProcessDataRequest::Kind::all};
  [[maybe_unused]] m::ProcessDataRequest::Route route{.signal = "channel_1"};
  [[maybe_unused]] m::ScanOptions scan{.poll = 2ms};
  [[maybe_unused]] m::AlOptions al{.step_timeout = 1s};
  [[maybe_unused]] m::InitOptions init{.attempts = 3};
  [[maybe_unused]] m::SdoOptions sdo{.complete_access = true};
  [[maybe_unused]] m::SdoWrite sdo_write{.index = 0x6060};
  [[maybe_unused]] m::DriverConfig driver{.options = {{"mode", "csp"}}};
  [[maybe_unused]] m::SyncSettings sync_settings{.output = std::nullopt};
  [[maybe_unused]] m::OutputWrite output_write{.signal = "channel_1"};
  [[maybe_unused]] m::LinearScale scale{.factor = 0.1};
  [[maybe_unused]] m::CoePdoConfiguration pdo_configuration{.assignments = {}};
  [[maybe_unused]] m::CoePdoAssignment assignment{.sync_manager = 2};
  [[maybe_unused]] m::CoePdoMapping mapping{.pdo_index = 0x1600};
  [[maybe_unused]] m::CoeEntryInfo entry_info{.index = 0x6040};
  [[maybe_unused]] m::CoeMappingOptions mapping_options{.write_fixed_mappings = true};
  [[maybe_unused]] m::MailboxConfig mailbox{.out_size = 128};
  [[maybe_unused]] m::MailboxOptions mailbox_options{.read_with_request = false};
  [[maybe_unused]] m::SiiReadOptions sii{.busy_timeout = 10ms};
  [[maybe_unused]] m::DcPlanOptions dc_plan{.timing = {}};
  [[maybe_unused]] m::DcInitOptions dc_init{.system_time_filter_depth = 2};
  [[maybe_unused]] m::DcRuntimeOptions dc_runtime{.read_every = 5};
  [[maybe_unused]] m::DcSyncRequest dc_sync{.station = 0x1001};
  // The application layer.
  [[maybe_unused]] ecat::OpenMasterOptions open{.backend = "udp:127.0.0.1"};
  // Bus and links.
  [[maybe_unused]] ecat::bus::BusOptions bus{.frame_timeout = 5ms};
  [[maybe_unused]] ecat::bus::TransactOptions transact{.retries = 0};
  [[maybe_unused]] ecat::bus::DatagramRequest datagram{.address = 0x0130};
  [[maybe_unused]] ecat::link::RawLinkOptions raw{.interface = "eth0"};
  [[maybe_unused]] ecat::link::UdpLinkOptions udp{.host = "127.0.0.1"};
  [[maybe_unused]] ecat::link::FunctionLinkOptions function_link{.reply_queue_depth = 4};
  [[maybe_unused]] ecat::wire::SiiEncodeOptions sii_encode{.pad_to_eeprom_size = false};
  // The simulator.
  [[maybe_unused]] ecat::sim::SimServerOptions server{.advance_period = 1ms};
  [[maybe_unused]] ecat::sim::DeviceConfig device{.profile = "EL1809"};
  [[maybe_unused]] ecat::sim::EscPreset esc{.fmmu_count = 8};
  [[maybe_unused]] ecat::sim::StartState start{.station = 0x1000};
  [[maybe_unused]] ecat::sim::ObjectPreset object{.index = 0x1008};
  [[maybe_unused]] ecat::sim::StandardConfig standard{.sii = {}};
  [[maybe_unused]] ecat::sim::CoeServerConfig coe{.request_sm = 0};
  [[maybe_unused]] ecat::sim::PdoMappingOptions pdo_mapping{.capacity = 4};
  [[maybe_unused]] ecat::sim::PdoAssignmentOptions pdo_assignment{.capacity = 2};
  [[maybe_unused]] ecat::sim::SiiDictionaryOptions sii_dictionary{.writable = true};
  [[maybe_unused]] ecat::sim::VerifyOptions verify{.start_ns = 0};
}
