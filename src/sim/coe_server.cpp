#include <algorithm>
#include <array>
#include <type_traits>
#include <variant>

#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/wire/sdo_info.hpp>

namespace ecat::sim {
namespace {

using wire::SdoAbortCode;

constexpr std::size_t kInitiateOverhead = wire::kMailboxHeaderSize + wire::kSdoFixedSize;      // 16
constexpr std::size_t kSegmentOverhead = wire::kMailboxHeaderSize + wire::kCoeHeaderSize + 1;  // 9
constexpr std::uint8_t kToggleBit = 0x10;

constexpr std::size_t stage_slot(MailboxStage stage) {
  return static_cast<std::size_t>(stage);
}

bool stage_matches(MailboxStage rule, MailboxStage actual) {
  if (rule == actual) return true;
  return rule == MailboxStage::request &&
         (actual == MailboxStage::upload_init || actual == MailboxStage::download_init);
}

bool is_segment_stage(MailboxStage stage) {
  return stage == MailboxStage::upload_segment || stage == MailboxStage::download_segment;
}

std::vector<std::uint8_t> encode_or_empty(const wire::SdoMessage& message) {
  auto bytes = wire::encode_sdo(message);
  return bytes ? std::move(*bytes) : std::vector<std::uint8_t>{};
}

}  // namespace

std::string_view to_string(MailboxStage stage) noexcept {
  switch (stage) {
    case MailboxStage::request:
      return "request";
    case MailboxStage::upload_init:
      return "upload_init";
    case MailboxStage::upload_segment:
      return "upload_segment";
    case MailboxStage::download_init:
      return "download_init";
    case MailboxStage::download_segment:
      return "download_segment";
  }
  return "unknown";
}

std::string_view to_string(ProtocolFaultKind kind) noexcept {
  switch (kind) {
    case ProtocolFaultKind::drop_response:
      return "drop_response";
    case ProtocolFaultKind::counter_mismatch:
      return "counter_mismatch";
    case ProtocolFaultKind::toggle_mismatch:
      return "toggle_mismatch";
    case ProtocolFaultKind::mailbox_type:
      return "mailbox_type";
    case ProtocolFaultKind::coe_service:
      return "coe_service";
    case ProtocolFaultKind::invalid_coe_payload:
      return "invalid_coe_payload";
    case ProtocolFaultKind::sdo_command:
      return "sdo_command";
    case ProtocolFaultKind::invalid_segment_padding:
      return "invalid_segment_padding";
    case ProtocolFaultKind::segment_command:
      return "segment_command";
  }
  return "unknown";
}

CoeServer::CoeServer(ObjectDictionary& dictionary, CoeServerConfig config)
    : od_(dictionary), config_(config) {}

// ---- Application hooks ----------------------------------------------------------------------

void CoeServer::on_buffer_written(Esc& esc, std::size_t sm) {
  if (sm != config_.request_sm) return;
  auto request = esc.pdi_mailbox_received(sm);
  if (!request) return;
  // Copy first: releasing the SM lets the master overwrite the buffer.
  const std::vector<std::uint8_t> buffer(request->begin(), request->end());
  esc.pdi_mailbox_release(sm);
  handle_request(esc, buffer);
}

void CoeServer::on_buffer_read(Esc& esc, std::size_t sm) {
  if (sm != config_.reply_sm) return;
  if (in_sm_) {
    ++stats_.replies_read;
    if (in_sm_->step) {
      ++stats_.stage_responses_read[stage_slot(*in_sm_->step)];
      if (step_observer_) step_observer_(*in_sm_->step, in_sm_->index, in_sm_->subindex);
    }
    in_sm_.reset();
  }
  pump(esc);
}

void CoeServer::on_mailbox_repeat(Esc& esc, std::size_t sm) {
  if (sm != config_.reply_sm) return;
  ++stats_.repeats;
  esc.pdi_mailbox_repeat(sm);
  if (!in_sm_ && last_sent_ && esc.sync_manager(sm).mailbox_full) {
    // The master lost the reply it read: the same mailbox is offered again; it already counted
    // as a step, so its second fetch does not.
    in_sm_ = last_sent_;
    in_sm_->step.reset();
  }
}

void CoeServer::on_sync_manager_changed(Esc& esc, std::size_t sm) {
  (void)esc;
  if (sm == config_.request_sm || sm == config_.reply_sm) reset();
}

void CoeServer::advance(Esc& esc) {
  if (!queue_.empty()) pump(esc);
}

void CoeServer::reset() {
  transfer_ = Transfer{};
  queue_.clear();
  in_sm_.reset();
  last_sent_.reset();
  counter_ = 0;
  last_request_counter_ = 0;
  last_request_id_ = 0;
  last_replies_.clear();
}

// ---- Device side ----------------------------------------------------------------------------

void CoeServer::queue_emergency(Esc& esc, const wire::Emergency& emergency) {
  std::array<std::uint8_t, wire::kEmergencySize> data{};
  wire::ByteWriter writer(data);
  if (!wire::encode_emergency(emergency, writer)) return;
  ++stats_.emergencies_sent;
  queue_reply(esc, wire::MailboxType::coe, data);
}

void CoeServer::queue_reply(Esc& esc, wire::MailboxType type, wire::Bytes data) {
  Response response;
  response.type = type;
  response.data.assign(data.begin(), data.end());
  send_response(esc, std::move(response), 0, 0);
}

std::string_view to_string(HandlerFaultKind kind) noexcept {
  switch (kind) {
    case HandlerFaultKind::drop_reply:
      return "drop_reply";
    case HandlerFaultKind::garble_reply:
      return "garble_reply";
  }
  return "unknown";
}

void CoeServer::set_protocol_handler(wire::MailboxType type, ProtocolHandler handler) {
  if (handler) {
    handlers_[type] = std::move(handler);
  } else {
    handlers_.erase(type);
  }
}

// ---- Fault hooks ----------------------------------------------------------------------------

void CoeServer::add_abort_rule(const SdoAbortRule& rule) {
  auto same = [&](const SdoAbortRule& r) {
    return r.index == rule.index && r.subindex == rule.subindex && r.stage == rule.stage;
  };
  std::erase_if(abort_rules_, same);
  abort_rules_.push_back(rule);
}

void CoeServer::add_protocol_fault(const ProtocolFaultRule& rule) {
  auto same = [&](const ProtocolFaultRule& r) {
    return r.index == rule.index && r.subindex == rule.subindex && r.stage == rule.stage;
  };
  std::erase_if(protocol_faults_, same);
  protocol_faults_.push_back(rule);
}

void CoeServer::clear_faults() {
  abort_rules_.clear();
  protocol_faults_.clear();
  handler_faults_.clear();
}

std::optional<std::uint32_t> CoeServer::take_abort_rule(std::uint16_t index, std::uint8_t subindex,
                                                        MailboxStage stage) {
  for (auto it = abort_rules_.begin(); it != abort_rules_.end(); ++it) {
    if (it->index != index || it->subindex != subindex || !stage_matches(it->stage, stage)) {
      continue;
    }
    const std::uint32_t code = it->code;
    if (it->once) abort_rules_.erase(it);
    ++stats_.faults_applied;
    return code;
  }
  return std::nullopt;
}

std::optional<ProtocolFault> CoeServer::take_protocol_fault(std::uint16_t index,
                                                            std::uint8_t subindex,
                                                            MailboxStage stage) {
  for (auto it = protocol_faults_.begin(); it != protocol_faults_.end(); ++it) {
    if (it->index != index || it->subindex != subindex || !stage_matches(it->stage, stage)) {
      continue;
    }
    const ProtocolFault fault = it->fault;
    if (it->once) protocol_faults_.erase(it);
    ++stats_.faults_applied;
    return fault;
  }
  return std::nullopt;
}

// ---- Requests -------------------------------------------------------------------------------

std::size_t CoeServer::reply_capacity(const Esc& esc) const {
  if (config_.reply_sm >= esc.hardware().sync_manager_count) return 0;
  return esc.sync_manager(config_.reply_sm).config.length;
}

CoeServer::Response CoeServer::mailbox_error(wire::MailboxErrorCode code) {
  Response response;
  response.type = wire::MailboxType::error;
  response.data.resize(wire::kMailboxErrorReplySize);
  wire::ByteWriter writer(response.data);
  (void)wire::encode_mailbox_error({static_cast<std::uint16_t>(code)}, writer);
  return response;
}

CoeServer::Response CoeServer::sdo_abort(std::uint16_t index, std::uint8_t subindex,
                                         std::uint32_t code, std::optional<MailboxStage> stage) {
  ++stats_.aborts_sent;
  Response response;
  response.data =
      encode_or_empty(wire::SdoAbort{index, subindex, code});  // service 2, as real slaves send
  response.stage = stage;
  response.index = index;
  response.subindex = subindex;
  response.abort = true;
  return response;
}

void CoeServer::handle_request(Esc& esc, wire::Bytes buffer) {
  ++stats_.mailboxes_received;
  auto header = wire::decode_mailbox_header(buffer);
  if (!header) {
    send_response(esc, mailbox_error(wire::MailboxErrorCode::syntax), 0, 0);
    return;
  }
  if (header->length > buffer.size() - wire::kMailboxHeaderSize) {
    send_response(esc, mailbox_error(wire::MailboxErrorCode::invalid_size), header->counter, 0);
    return;
  }
  // A request carrying the counter of the previous one is the master repeating a write whose
  // acknowledge it lost (ETG.1000.6 mailbox counter): it is not executed again. Its replies are
  // offered again once they are no longer waiting in the mailbox.
  if (header->counter != 0 && header->counter == last_request_counter_) {
    ++stats_.duplicates;
    const auto waiting = [&](const Pending& p) { return p.request_id == last_request_id_; };
    const bool still_waiting =
        (in_sm_ && waiting(*in_sm_)) || std::any_of(queue_.begin(), queue_.end(), waiting);
    if (!still_waiting) {
      for (const auto& p : last_replies_)
        enqueue(esc, p);
    }
    return;
  }
  ++request_id_;
  last_request_counter_ = header->counter;
  last_request_id_ = request_id_;
  last_replies_.clear();

  const wire::Bytes data = buffer.subspan(wire::kMailboxHeaderSize, header->length);
  std::vector<Response> responses;
  if (header->type == wire::MailboxType::coe) {
    responses = handle_coe(esc, data);
  } else if (auto it = handlers_.find(header->type); it != handlers_.end()) {
    auto replies = it->second(esc, *header, data);
    const auto fault =
        std::find_if(handler_faults_.begin(), handler_faults_.end(),
                     [&](const HandlerFaultRule& f) { return f.type == header->type; });
    if (fault != handler_faults_.end() && !replies.empty()) {
      const HandlerFaultKind kind = fault->kind;
      if (fault->once) handler_faults_.erase(fault);
      ++stats_.faults_applied;
      if (kind == HandlerFaultKind::drop_reply) replies.clear();
      for (auto& reply : replies) {
        if (reply.data.size() > 3) reply.data.resize(3);
      }
    }
    for (auto& reply : replies) {
      Response r;
      r.type = reply.type;
      r.data = std::move(reply.data);
      responses.push_back(std::move(r));
    }
  } else {
    responses.push_back(mailbox_error(wire::MailboxErrorCode::unsupported_protocol));
  }
  for (auto& r : responses)
    send_response(esc, std::move(r), header->counter, request_id_);
}

std::vector<CoeServer::Response> CoeServer::handle_coe(Esc& esc, wire::Bytes data) {
  if (data.size() < wire::kCoeHeaderSize) {
    return {mailbox_error(wire::MailboxErrorCode::size_too_short)};
  }
  auto coe = wire::decode_coe_header(data);
  if (!coe) return {mailbox_error(wire::MailboxErrorCode::invalid_header)};
  switch (coe->service) {
    case wire::CoeService::sdo_request:
      return handle_sdo(esc, data);
    case wire::CoeService::sdo_response:
      // A master's abort in the non-standard form (service 3) still ends the transfer, as real
      // slave stacks that look only at the command take it; any other response is not a request.
      if (data.size() > wire::kCoeHeaderSize && (data[wire::kCoeHeaderSize] >> 5) == 4) {
        return handle_sdo(esc, data);
      }
      break;
    case wire::CoeService::sdo_information:
      if (config_.sdo_info) {
        const std::size_t capacity = reply_capacity(esc);
        return handle_sdo_info(
            data, capacity > wire::kMailboxHeaderSize ? capacity - wire::kMailboxHeaderSize : 0);
      }
      break;
    default:
      break;
  }
  return {mailbox_error(wire::MailboxErrorCode::service_not_supported)};
}

std::vector<CoeServer::Response> CoeServer::handle_sdo(Esc& esc, wire::Bytes data) {
  if (data.size() < wire::kCoeHeaderSize + 1) {
    return {mailbox_error(wire::MailboxErrorCode::size_too_short)};
  }
  const std::uint8_t command = data[wire::kCoeHeaderSize];
  const std::uint8_t specifier = command >> 5;
  // The addressed object, for aborts of messages that carry one.
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  if (data.size() >= wire::kCoeHeaderSize + 4) {
    index = wire::load_le16(&data[wire::kCoeHeaderSize + 1]);
    subindex = data[wire::kCoeHeaderSize + 3];
  }
  if (specifier > 4) {
    ++stats_.requests_served;
    transfer_ = Transfer{};
    return {sdo_abort(index, subindex,
                      static_cast<std::uint32_t>(SdoAbortCode::command_specifier_unknown),
                      std::nullopt)};
  }
  auto message = wire::decode_sdo(data);
  if (!message) return {mailbox_error(wire::MailboxErrorCode::size_too_short)};
  ++stats_.requests_served;
  return std::visit(
      [&](auto& m) -> std::vector<Response> {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, wire::SdoInitiateUploadRequest>) {
          return {upload_init(esc, m.index, m.subindex, m.complete_access)};
        } else if constexpr (std::is_same_v<T, wire::SdoUploadSegmentRequest>) {
          return {upload_segment(esc, m.toggle)};
        } else if constexpr (std::is_same_v<T, wire::SdoInitiateDownloadRequest>) {
          Response response = download_init(esc, m);
          // The 4 bytes after index/subindex are reserved in the response. Beckhoff firmware
          // answers with the request's bytes there (the EL3004 in
          // replay-ek1914-el3004-mailbox.pcapng echoes the downloaded value), so do the same.
          constexpr std::size_t kReserved = wire::kCoeHeaderSize + 4;
          if (!response.abort && response.data.size() >= kReserved + 4 &&
              data.size() >= kReserved + 4) {
            std::copy_n(data.begin() + kReserved, 4, response.data.begin() + kReserved);
          }
          return {std::move(response)};
        } else if constexpr (std::is_same_v<T, wire::SdoDownloadSegmentRequest>) {
          return {download_segment(esc, m)};
        } else if constexpr (std::is_same_v<T, wire::SdoAbort>) {
          // The master abandons the transfer; nothing is answered.
          transfer_ = Transfer{};
          return {};
        } else {
          return {sdo_abort(index, subindex,
                            static_cast<std::uint32_t>(SdoAbortCode::command_specifier_unknown),
                            std::nullopt)};
        }
      },
      *message);
}

CoeServer::Response CoeServer::upload_init(Esc& esc, std::uint16_t index, std::uint8_t subindex,
                                           bool complete_access) {
  constexpr auto stage = MailboxStage::upload_init;
  transfer_ = Transfer{};
  if (auto code = take_abort_rule(index, subindex, stage)) {
    return sdo_abort(index, subindex, *code, stage);
  }
  if (complete_access && !config_.complete_access) {
    return sdo_abort(index, subindex,
                     static_cast<std::uint32_t>(SdoAbortCode::complete_access_not_supported),
                     stage);
  }
  AccessContext context;
  context.state = esc.al_state();
  context.complete_access = complete_access;
  std::vector<std::uint8_t> value;
  const SdoStatus status = complete_access ? od_.sdo_read_complete(index, subindex, context, value)
                                           : od_.sdo_read(index, subindex, context, value);
  if (!status.ok()) return sdo_abort(index, subindex, status.code(), stage);

  wire::SdoInitiateUploadResponse reply;
  reply.index = index;
  reply.subindex = subindex;
  reply.complete_access = complete_access;
  if (!complete_access && !value.empty() && value.size() <= wire::kSdoMaxExpeditedData) {
    reply.expedited = true;
    reply.data = std::move(value);
  } else {
    const std::size_t capacity = reply_capacity(esc);
    const std::size_t first = capacity > kInitiateOverhead ? capacity - kInitiateOverhead : 0;
    reply.complete_size = static_cast<std::uint32_t>(value.size());
    if (value.size() <= first) {
      reply.data = std::move(value);
    } else {
      if (capacity < kSegmentOverhead + wire::kSdoMinSegmentData) {
        return sdo_abort(index, subindex,
                         static_cast<std::uint32_t>(SdoAbortCode::object_exceeds_mailbox), stage);
      }
      reply.data.assign(value.begin(), value.begin() + static_cast<std::ptrdiff_t>(first));
      transfer_.kind = TransferKind::upload;
      transfer_.index = index;
      transfer_.subindex = subindex;
      transfer_.complete_access = complete_access;
      transfer_.complete_size = reply.complete_size;
      transfer_.offset = first;
      transfer_.data = std::move(value);
    }
  }
  Response response;
  response.data = encode_or_empty(reply);
  response.stage = stage;
  response.index = index;
  response.subindex = subindex;
  return response;
}

CoeServer::Response CoeServer::upload_segment(Esc& esc, bool toggle) {
  constexpr auto stage = MailboxStage::upload_segment;
  if (transfer_.kind != TransferKind::upload) {
    transfer_ = Transfer{};
    return sdo_abort(0, 0, static_cast<std::uint32_t>(SdoAbortCode::command_specifier_unknown),
                     std::nullopt);
  }
  const std::uint16_t index = transfer_.index;
  const std::uint8_t subindex = transfer_.subindex;
  if (auto code = take_abort_rule(index, subindex, stage)) {
    transfer_ = Transfer{};
    return sdo_abort(index, subindex, *code, stage);
  }
  if (toggle != transfer_.toggle) {
    transfer_ = Transfer{};
    return sdo_abort(index, subindex,
                     static_cast<std::uint32_t>(SdoAbortCode::toggle_bit_not_changed), stage);
  }
  const std::size_t capacity = reply_capacity(esc);
  const std::size_t segment = capacity > kSegmentOverhead ? capacity - kSegmentOverhead : 0;
  const std::size_t remaining = transfer_.data.size() - transfer_.offset;
  const std::size_t n = std::min(segment, remaining);
  wire::SdoUploadSegmentResponse reply;
  reply.toggle = toggle;
  reply.last = n == remaining;
  const auto begin = transfer_.data.begin() + static_cast<std::ptrdiff_t>(transfer_.offset);
  reply.data.assign(begin, begin + static_cast<std::ptrdiff_t>(n));
  transfer_.offset += n;
  transfer_.toggle = !toggle;
  if (reply.last) transfer_ = Transfer{};
  Response response;
  response.data = encode_or_empty(reply);
  response.stage = stage;
  response.index = index;
  response.subindex = subindex;
  return response;
}

CoeServer::Response CoeServer::download_init(Esc& esc,
                                             const wire::SdoInitiateDownloadRequest& request) {
  constexpr auto stage = MailboxStage::download_init;
  const std::uint16_t index = request.index;
  const std::uint8_t subindex = request.subindex;
  transfer_ = Transfer{};
  if (auto code = take_abort_rule(index, subindex, stage)) {
    return sdo_abort(index, subindex, *code, stage);
  }
  if (request.complete_access && !config_.complete_access) {
    return sdo_abort(index, subindex,
                     static_cast<std::uint32_t>(SdoAbortCode::complete_access_not_supported),
                     stage);
  }
  AccessContext context;
  context.state = esc.al_state();
  context.complete_access = request.complete_access;
  const auto write = [&](wire::Bytes value, bool unsized) {
    return request.complete_access ? od_.sdo_write_complete(index, subindex, value, context)
                                   : od_.sdo_write(index, subindex, value, context, unsized);
  };
  SdoStatus status;
  if (request.expedited) {
    status = write(request.data, !request.size_indicated);
  } else {
    const std::size_t size = request.complete_size;
    if (!request.complete_access) status = od_.sdo_check_write(index, subindex, size, context);
    if (status.ok()) {
      if (request.data.size() >= size) {
        status = write(wire::Bytes(request.data).first(size), false);
      } else {
        transfer_.kind = TransferKind::download;
        transfer_.index = index;
        transfer_.subindex = subindex;
        transfer_.complete_access = request.complete_access;
        transfer_.complete_size = request.complete_size;
        transfer_.data = request.data;
      }
    }
  }
  if (!status.ok()) return sdo_abort(index, subindex, status.code(), stage);
  Response response;
  response.data = encode_or_empty(wire::SdoInitiateDownloadResponse{index, subindex});
  response.stage = stage;
  response.index = index;
  response.subindex = subindex;
  return response;
}

CoeServer::Response CoeServer::download_segment(Esc& esc,
                                                const wire::SdoDownloadSegmentRequest& request) {
  constexpr auto stage = MailboxStage::download_segment;
  if (transfer_.kind != TransferKind::download) {
    transfer_ = Transfer{};
    return sdo_abort(0, 0, static_cast<std::uint32_t>(SdoAbortCode::command_specifier_unknown),
                     std::nullopt);
  }
  const std::uint16_t index = transfer_.index;
  const std::uint8_t subindex = transfer_.subindex;
  if (auto code = take_abort_rule(index, subindex, stage)) {
    transfer_ = Transfer{};
    return sdo_abort(index, subindex, *code, stage);
  }
  if (request.toggle != transfer_.toggle) {
    transfer_ = Transfer{};
    return sdo_abort(index, subindex,
                     static_cast<std::uint32_t>(SdoAbortCode::toggle_bit_not_changed), stage);
  }
  transfer_.data.insert(transfer_.data.end(), request.data.begin(), request.data.end());
  transfer_.toggle = !request.toggle;
  const bool too_long = transfer_.data.size() > transfer_.complete_size;
  if (too_long || (request.last && transfer_.data.size() != transfer_.complete_size)) {
    transfer_ = Transfer{};
    return sdo_abort(index, subindex, static_cast<std::uint32_t>(SdoAbortCode::length_mismatch),
                     stage);
  }
  if (request.last) {
    AccessContext context;
    context.state = esc.al_state();
    context.complete_access = transfer_.complete_access;
    const std::vector<std::uint8_t> value = std::move(transfer_.data);
    const bool complete_access = transfer_.complete_access;
    transfer_ = Transfer{};
    const SdoStatus status = complete_access
                                 ? od_.sdo_write_complete(index, subindex, value, context)
                                 : od_.sdo_write(index, subindex, value, context);
    if (!status.ok()) return sdo_abort(index, subindex, status.code(), stage);
  }
  Response response;
  response.data = encode_or_empty(wire::SdoDownloadSegmentResponse{request.toggle});
  response.stage = stage;
  response.index = index;
  response.subindex = subindex;
  return response;
}

std::vector<CoeServer::Response> CoeServer::handle_sdo_info(wire::Bytes data,
                                                            std::size_t max_data) {
  const auto answer = [&](const wire::SdoInfoMessage& message) {
    std::vector<Response> out;
    auto fragments = wire::encode_sdo_info_fragments(message, max_data);
    if (!fragments) return out;
    for (auto& f : *fragments) {
      Response r;
      r.data = std::move(f);
      out.push_back(std::move(r));
    }
    return out;
  };
  const auto refuse = [&](SdoAbortCode code) {
    ++stats_.aborts_sent;
    return answer(wire::SdoInfoError{static_cast<std::uint32_t>(code)});
  };
  auto fragment = wire::decode_sdo_info_fragment(data);
  if (!fragment) return {mailbox_error(wire::MailboxErrorCode::size_too_short)};
  ++stats_.requests_served;
  auto message = wire::decode_sdo_info(fragment->header.opcode, fragment->data);
  if (!message) {
    const auto op = fragment->header.opcode;
    const bool known_request = op == wire::SdoInfoOpcode::get_od_list_request ||
                               op == wire::SdoInfoOpcode::get_object_description_request ||
                               op == wire::SdoInfoOpcode::get_entry_description_request;
    return known_request ? refuse(SdoAbortCode::length_too_low)
                         : refuse(SdoAbortCode::command_specifier_unknown);
  }
  if (const auto* list = std::get_if<wire::OdListRequest>(&*message)) {
    const auto type = static_cast<std::uint16_t>(list->list_type);
    if (type > static_cast<std::uint16_t>(wire::OdListType::settings)) {
      return refuse(SdoAbortCode::value_range_exceeded);
    }
    return answer(wire::OdListResponse{list->list_type, od_.od_list(list->list_type)});
  }
  if (const auto* od = std::get_if<wire::ObjectDescriptionRequest>(&*message)) {
    const OdObject* object = od_.find(od->index);
    if (object == nullptr) return refuse(SdoAbortCode::object_does_not_exist);
    wire::ObjectDescriptionResponse reply;
    reply.index = object->index;
    reply.data_type = object->data_type;
    reply.max_subindex = object->max_subindex();
    reply.object_code = object->code;
    reply.name = object->name;
    return answer(reply);
  }
  if (const auto* ed = std::get_if<wire::EntryDescriptionRequest>(&*message)) {
    const OdObject* object = od_.find(ed->index);
    if (object == nullptr) return refuse(SdoAbortCode::object_does_not_exist);
    const ObjectEntry* entry = object->entry(ed->subindex);
    if (entry == nullptr) return refuse(SdoAbortCode::subindex_does_not_exist);
    wire::EntryDescriptionResponse reply;
    reply.index = ed->index;
    reply.subindex = ed->subindex;
    reply.data_type = static_cast<std::uint16_t>(entry->data_type);
    reply.bit_length = entry->bit_length;
    reply.object_access = entry->access;
    // Answer the optional fields asked for that the entry has; strings carry no value range.
    std::uint8_t info = ed->value_info & 0x07;
    if ((ed->value_info & wire::kValueInfoUnitType) != 0) {
      info |= wire::kValueInfoUnitType;
      reply.unit_type = entry->unit;
    }
    const bool numeric = !is_variable_length(entry->data_type);
    const auto add_value = [&](std::uint8_t flag, const std::vector<std::uint8_t>& source,
                               std::vector<std::uint8_t>& target) {
      if ((ed->value_info & flag) == 0 || !numeric || source.empty()) return;
      info |= flag;
      target = source;
      target.resize(entry->byte_length(), 0);
    };
    add_value(wire::kValueInfoDefaultValue, entry->default_value, reply.default_value);
    add_value(wire::kValueInfoMinimumValue, entry->minimum, reply.minimum_value);
    add_value(wire::kValueInfoMaximumValue, entry->maximum, reply.maximum_value);
    reply.value_info = info;
    reply.description = entry->name;
    if (auto nul = reply.description.find('\0'); nul != std::string::npos) {
      reply.description.resize(nul);
    }
    return answer(reply);
  }
  return refuse(SdoAbortCode::command_specifier_unknown);
}

// ---- Replies ----------------------------------------------------------------------------------

std::uint8_t CoeServer::next_counter(std::uint8_t request_counter) {
  if (config_.counter_mode == ReplyCounterMode::echo_request) return request_counter & 0x07;
  counter_ = wire::next_mailbox_counter(counter_);
  return counter_;
}

void CoeServer::send_response(Esc& esc, Response response, std::uint8_t request_counter,
                              std::uint64_t request_id) {
  std::optional<ProtocolFault> fault;
  if (response.stage)
    fault = take_protocol_fault(response.index, response.subindex, *response.stage);
  if (fault && fault->kind == ProtocolFaultKind::drop_response) return;

  wire::MailboxHeader header;
  // Real slaves answer a master's request with mailbox address 0 (EK1914 and EL3004 in
  // replay-ek1914-el3004-mailbox.pcapng); messages of their own (emergencies) name the station.
  header.address = request_id == 0 ? esc.station_address() : std::uint16_t{0};
  header.type = response.type;
  header.counter = next_counter(request_counter);
  std::vector<std::uint8_t>& data = response.data;
  if (fault) {
    const std::size_t command_at = wire::kCoeHeaderSize;
    switch (fault->kind) {
      case ProtocolFaultKind::drop_response:
        break;
      case ProtocolFaultKind::counter_mismatch:
        header.counter = wire::next_mailbox_counter(header.counter);
        break;
      case ProtocolFaultKind::toggle_mismatch:
        if (is_segment_stage(*response.stage) && data.size() > command_at) {
          data[command_at] ^= kToggleBit;
        }
        break;
      case ProtocolFaultKind::mailbox_type:
        header.type = static_cast<wire::MailboxType>(fault->value & 0x0F);
        break;
      case ProtocolFaultKind::coe_service:
        if (data.size() >= wire::kCoeHeaderSize) {
          data[1] = static_cast<std::uint8_t>((data[1] & 0x0F) | ((fault->value & 0x0F) << 4));
        }
        break;
      case ProtocolFaultKind::invalid_coe_payload:
        data.assign(1, 0x00);
        break;
      case ProtocolFaultKind::sdo_command:
        if (data.size() > command_at) data[command_at] = fault->value;
        break;
      case ProtocolFaultKind::invalid_segment_padding: {
        const bool toggle = data.size() > command_at && (data[command_at] & kToggleBit) != 0;
        data.resize(command_at);
        // Last segment, 7 unused bytes, no data.
        data.push_back(static_cast<std::uint8_t>((toggle ? kToggleBit : 0) | (7u << 1) | 1u));
        data.insert(data.end(), wire::kSdoMinSegmentData, 0);
        break;
      }
      case ProtocolFaultKind::segment_command:
        data.resize(std::min(data.size(), command_at));
        data.push_back(fault->value);
        break;
    }
  }
  auto bytes = wire::encode_mailbox(header, data);
  if (!bytes) {
    ++stats_.replies_dropped;
    return;
  }
  if (response.type == wire::MailboxType::error) ++stats_.mailbox_errors_sent;
  Pending pending;
  pending.bytes = std::move(*bytes);
  pending.index = response.index;
  pending.subindex = response.subindex;
  pending.request_id = request_id;
  if (response.stage && !response.abort && *response.stage != MailboxStage::request) {
    pending.step = response.stage;
    ++stats_.stage_responses[stage_slot(*response.stage)];
  }
  if (request_id != 0) last_replies_.push_back(pending);
  enqueue(esc, std::move(pending));
}

void CoeServer::enqueue(Esc& esc, Pending pending) {
  if (queue_.size() >= config_.max_queued_replies) {
    ++stats_.replies_dropped;
    return;
  }
  pending.ready_ns = esc.now_ns() + config_.reply_delay.count();
  queue_.push_back(std::move(pending));
  pump(esc);
}

void CoeServer::pump(Esc& esc) {
  if (config_.reply_sm >= esc.hardware().sync_manager_count) return;
  while (!queue_.empty()) {
    const auto& sm = esc.sync_manager(config_.reply_sm);
    if (sm.mailbox_full) return;
    if (queue_.front().ready_ns > esc.now_ns()) return;  // the firmware is still at it
    Pending next = std::move(queue_.front());
    queue_.pop_front();
    if (!esc.pdi_mailbox_send(config_.reply_sm, next.bytes)) {
      ++stats_.replies_dropped;  // reply SM disabled or smaller than the reply
      continue;
    }
    ++stats_.replies_sent;
    last_sent_ = next;
    in_sm_ = std::move(next);
    return;
  }
}

}  // namespace ecat::sim
