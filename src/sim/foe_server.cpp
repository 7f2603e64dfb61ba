#include <algorithm>
#include <array>
#include <utility>

#include <fmt/format.h>

#include <ecat/sim/esc.hpp>
#include <ecat/sim/foe_server.hpp>
#include <ecat/sim/standard_application.hpp>

namespace ecat::sim {

namespace {

using wire::FoeErrorCode;

constexpr std::array<char, 4> kFirmwareMagic{'E', 'C', 'F', 'W'};
constexpr std::size_t kRequestSm = 0;  // the CoE server's defaults (CoeServerConfig)
constexpr std::size_t kReplySm = 1;

std::uint32_t load_u32(wire::Bytes b, std::size_t at) {
  return static_cast<std::uint32_t>(b[at]) | (static_cast<std::uint32_t>(b[at + 1]) << 8) |
         (static_cast<std::uint32_t>(b[at + 2]) << 16) |
         (static_cast<std::uint32_t>(b[at + 3]) << 24);
}

void store_u32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i)
    out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}

// The most file data one DATA packet through SyncManager `sm` carries (its length minus the
// mailbox and FoE headers); 0 when the SyncManager is missing or too small.
std::size_t packet_size(const Esc& esc, std::size_t sm) {
  if (sm >= esc.hardware().sync_manager_count) return 0;
  const std::size_t length = esc.sync_manager(sm).config.length;
  constexpr std::size_t kOverhead = wire::kMailboxHeaderSize + wire::kFoeHeaderSize;
  return length > kOverhead ? length - kOverhead : 0;
}

}  // namespace

// ---- Firmware images ----------------------------------------------------------------------------

std::uint32_t crc32(wire::Bytes bytes) noexcept {
  std::uint32_t crc = 0xFFFFFFFFu;
  for (const std::uint8_t b : bytes) {
    crc ^= b;
    for (int bit = 0; bit < 8; ++bit)
      crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return crc ^ 0xFFFFFFFFu;
}

Result<std::vector<std::uint8_t>> make_firmware_image(std::string_view version,
                                                      wire::Bytes payload) {
  if (version.size() > kFirmwareVersionSize || version.find('\0') != std::string_view::npos) {
    return Error(Errc::invalid_argument,
                 fmt::format("firmware image: version '{}' must be at most {} characters without "
                             "NUL",
                             version, kFirmwareVersionSize));
  }
  if (payload.size() > 0xFFFFFFFFu) {
    return Error(Errc::out_of_range, "firmware image: payload longer than 4 GiB");
  }
  std::vector<std::uint8_t> out(kFirmwareMagic.begin(), kFirmwareMagic.end());
  store_u32(out, static_cast<std::uint32_t>(payload.size()));
  store_u32(out, crc32(payload));
  out.insert(out.end(), version.begin(), version.end());
  out.resize(kFirmwareHeaderSize, 0);
  out.insert(out.end(), payload.begin(), payload.end());
  return out;
}

Result<FirmwareImage> parse_firmware_image(wire::Bytes image) {
  if (image.size() < kFirmwareHeaderSize) {
    return Error(Errc::malformed, fmt::format("firmware image: {} bytes, shorter than its {}-byte "
                                              "header",
                                              image.size(), kFirmwareHeaderSize));
  }
  if (!std::equal(kFirmwareMagic.begin(), kFirmwareMagic.end(), image.begin())) {
    return Error(Errc::malformed, "firmware image: no \"ECFW\" magic at offset 0");
  }
  const std::uint32_t length = load_u32(image, 4);
  const std::uint32_t crc = load_u32(image, 8);
  const wire::Bytes payload = image.subspan(kFirmwareHeaderSize);
  if (payload.size() != length) {
    return Error(Errc::malformed,
                 fmt::format("firmware image: the header announces {} bytes of payload, {} "
                             "follow",
                             length, payload.size()));
  }
  if (const std::uint32_t actual = crc32(payload); actual != crc) {
    return Error(Errc::malformed,
                 fmt::format("firmware image: payload CRC-32 0x{:08X}, the header says 0x{:08X}",
                             actual, crc));
  }
  FirmwareImage out;
  const auto version = image.subspan(12, kFirmwareVersionSize);
  for (const std::uint8_t c : version) {
    if (c == 0) break;
    out.version += static_cast<char>(c);
  }
  out.payload.assign(payload.begin(), payload.end());
  return out;
}

std::string_view to_string(FoeFaultKind kind) noexcept {
  switch (kind) {
    case FoeFaultKind::error:
      return "error";
    case FoeFaultKind::drop_reply:
      return "drop_reply";
    case FoeFaultKind::wrong_packet:
      return "wrong_packet";
    case FoeFaultKind::busy:
      return "busy";
  }
  return "unknown";
}

// ---- The server ---------------------------------------------------------------------------------

FoeServer::FoeServer(ObjectDictionary& dictionary, FoeServerConfig config)
    : od_(dictionary), config_(std::move(config)) {
  firmware_.version = od_.get_string(0x100A, 0).value_or("");
}

std::vector<MailboxReply> FoeServer::reply(const wire::FoeMessage& message) {
  auto data = wire::encode_foe(message);
  if (!data) return {};
  switch (wire::opcode_of(message)) {
    case wire::FoeOpcode::data:
      ++stats_.data_sent;
      break;
    case wire::FoeOpcode::busy:
      ++stats_.busy_sent;
      break;
    case wire::FoeOpcode::error:
      ++stats_.errors_sent;
      break;
    default:
      break;
  }
  return {MailboxReply{wire::MailboxType::foe, std::move(*data)}};
}

std::vector<MailboxReply> FoeServer::error(FoeErrorCode code, std::string text) {
  transfer_ = Transfer{};
  return reply(wire::FoeError{static_cast<std::uint32_t>(code), std::move(text)});
}

std::optional<FoeFault> FoeServer::take_fault(std::uint32_t packet) {
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->after_packets != packet) continue;
    FoeFault fault = *it;
    faults_.erase(it);
    ++stats_.faults_applied;
    return fault;
  }
  return std::nullopt;
}

std::vector<MailboxReply> FoeServer::apply_fault(const FoeFault& fault, wire::FoeMessage message) {
  switch (fault.kind) {
    case FoeFaultKind::error:
      transfer_ = Transfer{};
      ++stats_.errors_sent;
      {
        auto data = wire::encode_foe(wire::FoeError{fault.code, "injected fault"});
        if (!data) return {};
        return {MailboxReply{wire::MailboxType::foe, std::move(*data)}};
      }
    case FoeFaultKind::drop_reply:
      return {};
    case FoeFaultKind::wrong_packet:
      if (auto* d = std::get_if<wire::FoeData>(&message)) ++d->packet_number;
      if (auto* a = std::get_if<wire::FoeAck>(&message)) ++a->packet_number;
      return reply(message);
    case FoeFaultKind::busy:
      break;  // taken in data(), before the packet is
  }
  return reply(message);
}

std::vector<MailboxReply> FoeServer::handle(Esc& esc, wire::Bytes data) {
  auto message = wire::decode_foe(data);
  if (!message) return error(FoeErrorCode::illegal, "malformed FoE request");
  return std::visit(
      [&](const auto& m) -> std::vector<MailboxReply> {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, wire::FoeReadRequest>) {
          return read_request(esc, m);
        } else if constexpr (std::is_same_v<T, wire::FoeWriteRequest>) {
          return write_request(esc, m);
        } else if constexpr (std::is_same_v<T, wire::FoeAck>) {
          return ack(esc, m);
        } else if constexpr (std::is_same_v<T, wire::FoeData>) {
          return this->data(esc, m);
        } else if constexpr (std::is_same_v<T, wire::FoeError>) {
          // The master abandons the transfer; nothing is answered.
          ++stats_.errors_taken;
          transfer_ = Transfer{};
          return {};
        } else {
          return error(FoeErrorCode::illegal, "BUSY is not a request");
        }
      },
      *message);
}

std::vector<MailboxReply> FoeServer::read_request(Esc& esc, const wire::FoeReadRequest& request) {
  transfer_ = Transfer{};
  ++stats_.requests;
  if (request.file_name == config_.firmware_file) {
    return error(FoeErrorCode::access_denied, "the firmware cannot be read");
  }
  auto it = files_.find(request.file_name);
  if (it == files_.end()) return error(FoeErrorCode::not_found, request.file_name);
  if (it->second.password != request.password) {
    return error(FoeErrorCode::no_rights, "wrong password");
  }
  transfer_.mode = Mode::reading;
  transfer_.name = request.file_name;
  return next_data(esc);
}

std::vector<MailboxReply> FoeServer::next_data(Esc& esc) {
  auto it = files_.find(transfer_.name);
  if (it == files_.end()) return error(FoeErrorCode::not_found, "file removed during the read");
  const std::size_t max = packet_size(esc, kReplySm);
  if (max == 0) return error(FoeErrorCode::illegal, "reply mailbox too small");
  const auto& file = it->second.data;
  const std::size_t n = std::min(max, file.size() - std::min(transfer_.offset, file.size()));
  wire::FoeData packet{transfer_.packet + 1, {}};
  packet.data.assign(file.begin() + static_cast<std::ptrdiff_t>(transfer_.offset),
                     file.begin() + static_cast<std::ptrdiff_t>(transfer_.offset + n));
  if (auto fault = take_fault(transfer_.packet)) return apply_fault(*fault, std::move(packet));
  transfer_.packet = packet.packet_number;
  transfer_.offset += n;
  transfer_.last_sent = n < max;
  return reply(packet);
}

std::vector<MailboxReply> FoeServer::ack(Esc& esc, const wire::FoeAck& ack) {
  if (transfer_.mode != Mode::reading) {
    return error(FoeErrorCode::illegal, "ACK without a read in progress");
  }
  if (ack.packet_number != transfer_.packet) {
    return error(FoeErrorCode::packet_number_wrong,
                 fmt::format("ACK {}, expected {}", ack.packet_number, transfer_.packet));
  }
  if (transfer_.last_sent) {
    ++stats_.files_read;
    transfer_ = Transfer{};
    return {};
  }
  return next_data(esc);
}

std::vector<MailboxReply> FoeServer::write_request(Esc& esc, const wire::FoeWriteRequest& request) {
  transfer_ = Transfer{};
  ++stats_.requests;
  const bool firmware = request.file_name == config_.firmware_file;
  if (firmware) {
    if (request.password != config_.firmware_password) {
      return error(FoeErrorCode::no_rights, "wrong password");
    }
    if (esc.al_state() != wire::AlState::bootstrap) {
      return error(FoeErrorCode::not_in_bootstrap, "firmware is written in BOOTSTRAP only");
    }
  } else if (auto it = files_.find(request.file_name); it != files_.end()) {
    if (it->second.password != request.password) {
      return error(FoeErrorCode::no_rights, "wrong password");
    }
    if (it->second.read_only) return error(FoeErrorCode::access_denied, "read-only file");
  }
  transfer_.mode = Mode::writing;
  transfer_.name = request.file_name;
  transfer_.firmware = firmware;
  transfer_.password = request.password;
  transfer_.busy_left = config_.busy_per_packet;
  transfer_.busy_total = config_.busy_per_packet;
  wire::FoeMessage ack0 = wire::FoeAck{0};
  if (auto fault = take_fault(0)) return apply_fault(*fault, std::move(ack0));
  return reply(ack0);
}

std::vector<MailboxReply> FoeServer::data(Esc& esc, const wire::FoeData& data) {
  if (transfer_.mode != Mode::writing) {
    return error(FoeErrorCode::illegal, "DATA without a write in progress");
  }
  const std::uint32_t expected = transfer_.packet + 1;
  if (data.packet_number != expected) {
    return error(FoeErrorCode::packet_number_wrong,
                 fmt::format("DATA {}, expected {}", data.packet_number, expected));
  }
  // An injected BUSY (FoeFaultKind::busy) for this packet: `count` answers before it is taken.
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->kind != FoeFaultKind::busy || it->after_packets != expected - 1) continue;
    transfer_.busy_left = std::max(transfer_.busy_left, it->count);
    transfer_.busy_total = std::max(transfer_.busy_total, it->count);
    faults_.erase(it);
    ++stats_.faults_applied;
    break;
  }
  if (transfer_.busy_left > 0) {
    // Still flashing the previous packet: the master sends this one again.
    --transfer_.busy_left;
    return reply(wire::FoeBusy{
        static_cast<std::uint16_t>(
            std::min<std::uint32_t>(transfer_.busy_total - transfer_.busy_left, 0xFFFF)),
        static_cast<std::uint16_t>(std::min<std::uint32_t>(transfer_.busy_total, 0xFFFF))});
  }
  const std::size_t max = packet_size(esc, kRequestSm);
  if (data.data.size() > max) {
    return error(FoeErrorCode::illegal, "DATA packet larger than the mailbox allows");
  }
  const std::size_t limit =
      transfer_.firmware
          ? config_.max_firmware_size
          : config_.max_total_size - std::min(stored_bytes(), config_.max_total_size);
  // Rewriting a file frees its old content at the end; count it as free already.
  std::size_t room = limit;
  if (!transfer_.firmware) {
    if (auto it = files_.find(transfer_.name); it != files_.end()) room += it->second.data.size();
  }
  if (transfer_.buffer.size() + data.data.size() > room) {
    return error(FoeErrorCode::disk_full, "file store full");
  }
  transfer_.buffer.insert(transfer_.buffer.end(), data.data.begin(), data.data.end());
  transfer_.packet = expected;
  transfer_.busy_left = config_.busy_per_packet;
  transfer_.busy_total = config_.busy_per_packet;
  ++stats_.data_taken;
  const bool last = data.data.size() < max;
  if (auto fault = take_fault(expected - 1)) {
    if (last && fault->kind == FoeFaultKind::drop_reply) (void)finish_write();
    return apply_fault(*fault, wire::FoeAck{expected});
  }
  if (last) return finish_write();
  return reply(wire::FoeAck{expected});
}

std::vector<MailboxReply> FoeServer::finish_write() {
  const std::uint32_t packet = transfer_.packet;
  Transfer done = std::move(transfer_);
  transfer_ = Transfer{};
  if (done.firmware) {
    auto image = parse_firmware_image(done.buffer);
    if (!image) {
      // The old image stays.
      return error(FoeErrorCode::checksum_error, image.error().message());
    }
    pending_ = std::move(*image);
  } else {
    FoeFile& file = files_[done.name];
    file.data = std::move(done.buffer);
    file.password = done.password;
  }
  ++stats_.files_written;
  return reply(wire::FoeAck{packet});
}

void FoeServer::on_state_changed(wire::AlState from, wire::AlState to) {
  if (to == wire::AlState::init) transfer_ = Transfer{};
  if (from == wire::AlState::bootstrap && to == wire::AlState::init && pending_) {
    start_firmware(std::move(*pending_));
    pending_.reset();
  }
}

void FoeServer::start_firmware(FirmwareImage image) {
  firmware_ = std::move(image);
  firmware_updated_ = true;
  ++stats_.firmware_updates;
  set_software_version();
}

void FoeServer::set_software_version() {
  od_.add(make_software_version(firmware_.version));
}

void FoeServer::on_power_up() {
  transfer_ = Transfer{};
  pending_.reset();
  if (firmware_updated_) set_software_version();
}

Result<void> FoeServer::put_file(std::string name, FoeFile file) {
  if (name == config_.firmware_file) {
    return Error(Errc::invalid_argument,
                 fmt::format("FoE store: '{}' is the firmware slot, not a file", name));
  }
  std::size_t others = stored_bytes();
  if (auto it = files_.find(name); it != files_.end()) others -= it->second.data.size();
  if (others + file.data.size() > config_.max_total_size) {
    return Error(Errc::out_of_range,
                 fmt::format("FoE store: '{}' ({} bytes) exceeds the store's {} bytes ({} in use)",
                             name, file.data.size(), config_.max_total_size, others));
  }
  files_.insert_or_assign(std::move(name), std::move(file));
  return ok();
}

const FoeFile* FoeServer::file(std::string_view name) const {
  auto it = files_.find(name);
  return it == files_.end() ? nullptr : &it->second;
}

bool FoeServer::remove_file(std::string_view name) {
  auto it = files_.find(name);
  if (it == files_.end()) return false;
  files_.erase(it);
  return true;
}

std::size_t FoeServer::stored_bytes() const noexcept {
  std::size_t total = 0;
  for (const auto& [name, file] : files_)
    total += file.data.size();
  return total;
}

FoeServer* foe_server_of(Esc& esc) noexcept {
  auto* app = dynamic_cast<StandardApplication*>(&esc.application());
  return app != nullptr ? app->foe_server() : nullptr;
}

}  // namespace ecat::sim
