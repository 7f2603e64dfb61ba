#include <algorithm>
#include <string>
#include <utility>
#include <variant>

#include <fmt/format.h>

#include <ecat/master/coe_client.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/sdo_abort.hpp>

namespace ecat::master {

namespace {

std::string object_name(std::uint16_t index, std::uint8_t subindex) {
  return fmt::format("0x{:04X}:{:02X}", index, subindex);
}

std::string hex_bytes(wire::Bytes bytes) {
  std::string out;
  for (std::size_t i = 0; i < bytes.size() && i < 16; ++i)
    out += fmt::format("{}{:02x}", i == 0 ? "" : " ", bytes[i]);
  if (bytes.size() > 16) out += " ...";
  return out;
}

// The index and subindex a message names, when it names one.
std::optional<std::pair<std::uint16_t, std::uint8_t>> named_object(const wire::SdoMessage& m) {
  if (const auto* r = std::get_if<wire::SdoInitiateUploadResponse>(&m)) {
    return std::pair{r->index, r->subindex};
  }
  if (const auto* r = std::get_if<wire::SdoInitiateDownloadResponse>(&m)) {
    return std::pair{r->index, r->subindex};
  }
  return std::nullopt;
}

std::optional<wire::CoeService> coe_service_of(const MailboxMessage& message) {
  if (message.header.type != wire::MailboxType::coe) return std::nullopt;
  auto coe = wire::decode_coe_header(message.data);
  if (!coe) return std::nullopt;
  return coe->service;
}

// An SDO message: a response (service 3) or an abort, which travels as a request (service 2) in
// its standard form (wire/coe.hpp SdoAbort).
bool is_sdo_service(std::optional<wire::CoeService> service) {
  return service == wire::CoeService::sdo_response || service == wire::CoeService::sdo_request;
}

// Replies to an SDO request: everything but what is recognisably someone else's (a late
// initiate response or abort naming another object, SDO information traffic). Whatever else
// arrives is taken as the reply and checked, so a broken reply fails the transfer instead of
// timing it out.
Mailbox::ReplyFilter sdo_filter(std::uint16_t index, std::uint8_t subindex) {
  return [index, subindex](const MailboxMessage& message) {
    const auto service = coe_service_of(message);
    if (service == wire::CoeService::sdo_information) return false;
    if (!is_sdo_service(service)) return true;
    auto sdo = wire::decode_sdo(message.data);
    if (!sdo) return true;
    const auto named = named_object(*sdo);
    return !named || (named->first == index && named->second == subindex);
  };
}

// The failure as an error's value (coe_client.hpp).
Error tagged(Error error, SdoFailure failure) {
  return std::move(error).with_value(kSdoFailureValueBase + static_cast<std::uint32_t>(failure));
}

// Which stage of a transfer a reply answers, and the server command specifier it must carry.
enum class Stage : std::uint8_t { upload_init, upload_segment, download_init, download_segment };

constexpr std::uint8_t expected_specifier(Stage stage) {
  switch (stage) {
    case Stage::upload_init:
      return 2;
    case Stage::upload_segment:
      return 0;
    case Stage::download_init:
      return 3;
    case Stage::download_segment:
      return 1;
  }
  return 0;
}

constexpr bool is_segment(Stage stage) {
  return stage == Stage::upload_segment || stage == Stage::download_segment;
}

constexpr std::string_view specifier_name(std::uint8_t scs) {
  switch (scs) {
    case 0:
      return "upload segment response";
    case 1:
      return "download segment response";
    case 2:
      return "initiate upload response";
    case 3:
      return "initiate download response";
    case 4:
      return "abort";
    default:
      return "unknown command";
  }
}

// SDO information replies: everything but SDO traffic (a late SDO response or abort).
bool info_filter(const MailboxMessage& message) {
  return !is_sdo_service(coe_service_of(message));
}

// One transfer: the mailbox, the object, and the words for errors.
class Transfer {
 public:
  Transfer(Mailbox& mailbox, std::string what, std::uint16_t index, std::uint8_t subindex,
           const SdoOptions& options)
      : mailbox_(mailbox),
        what_(std::move(what)),
        index_(index),
        subindex_(subindex),
        options_(options) {}

  const std::string& what() const noexcept { return what_; }

  // Sends `request` and returns the SDO reply; a slave's abort becomes Errc::sdo_abort. A reply
  // that breaks the protocol fails with its SdoFailure and the transfer is aborted on the slave.
  exec::Task<Result<wire::SdoMessage>> exchange(const Mailbox::Guard& guard,
                                                const wire::SdoMessage& request, Stage stage) {
    auto data = wire::encode_sdo(request);
    if (!data) co_return data.error().context(Errc::invalid_argument, what_);
    auto reply = co_await mailbox_.exchange(guard, wire::MailboxType::coe, std::move(*data),
                                            options_.timeout, sdo_filter(index_, subindex_), what_);
    if (!reply) {
      // The slave may still be inside the transfer: tell it to give up (best effort).
      if (reply.error().code() == Errc::timeout) {
        co_await abort(guard, wire::SdoAbortCode::protocol_timeout);
      }
      co_return reply.error();
    }
    last_command_ = reply->data.size() > wire::kCoeHeaderSize ? reply->data[wire::kCoeHeaderSize]
                                                              : std::uint8_t{0};
    auto parsed = parse(*reply, stage);
    if (!parsed && parsed.error().code() != Errc::sdo_abort) {
      co_await abort(guard, wire::SdoAbortCode::general_error);
    }
    co_return parsed;
  }

  // A protocol violation by the slave: the transfer is aborted on its side too.
  exec::Task<Error> violation(const Mailbox::Guard& guard, Errc code, SdoFailure failure,
                              std::string problem, wire::SdoAbortCode abort_code) {
    co_await abort(guard, abort_code);
    co_return tagged(Error(code, fmt::format("{}: {}", what_, problem)), failure);
  }

  // The command byte of the last SDO reply (0 when it had none).
  std::uint8_t last_command() const noexcept { return last_command_; }

 private:
  Result<wire::SdoMessage> parse(const MailboxMessage& reply, Stage stage) {
    const auto station = mailbox_.station();
    if (reply.expected_counter) {
      return tagged(
          Error(Errc::mailbox_error,
                fmt::format("{}: the reply of slave {:#06x} carries mailbox counter {}, "
                            "expected {} (the slave's sequence skipped a message)",
                            what_, station, reply.header.counter, *reply.expected_counter)),
          SdoFailure::counter_mismatch);
    }
    if (reply.header.type != wire::MailboxType::coe) {
      return tagged(
          Error(Errc::mailbox_error,
                fmt::format("{}: slave {:#06x} answered with a {} mailbox (type {}) instead of "
                            "CoE",
                            what_, station, wire::to_string(reply.header.type),
                            static_cast<unsigned>(reply.header.type))),
          SdoFailure::unexpected_mailbox_type);
    }
    auto coe = wire::decode_coe_header(reply.data);
    if (!coe) {
      return tagged(coe.error().context(Errc::malformed,
                                        fmt::format("{}: the reply of slave {:#06x} has no "
                                                    "complete CoE header ({} bytes of mailbox "
                                                    "data)",
                                                    what_, station, reply.data.size())),
                    SdoFailure::invalid_response);
    }
    // Service 2 is an SDO request: from a slave, only an abort comes in that form (its standard
    // one); anything else in it is not an answer.
    const bool abort_request = coe->service == wire::CoeService::sdo_request &&
                               reply.data.size() > wire::kCoeHeaderSize &&
                               (reply.data[wire::kCoeHeaderSize] >> 5) == 4;
    if (coe->service != wire::CoeService::sdo_response && !abort_request) {
      return tagged(
          Error(Errc::mailbox_error,
                fmt::format("{}: slave {:#06x} answered with CoE service {} ({}), expected 3 "
                            "(SDO response) or an abort",
                            what_, station, static_cast<unsigned>(coe->service),
                            wire::to_string(coe->service))),
          SdoFailure::unexpected_coe_service);
    }
    auto message = wire::decode_sdo(reply.data);
    if (!message) {
      // A reply of the wrong kind for this stage that does not decode either (a bare command
      // byte) is named by its command; one of the right kind is broken.
      const std::uint8_t scs = static_cast<std::uint8_t>(last_command_ >> 5);
      if (reply.data.size() > wire::kCoeHeaderSize && scs != 4 &&
          scs != expected_specifier(stage)) {
        return tagged(
            Error(Errc::mailbox_error,
                  fmt::format("{}: slave {:#06x} answered with SDO command {:#04x} ({}) instead "
                              "of the expected {} ({} bytes: {})",
                              what_, station, last_command_, specifier_name(scs),
                              specifier_name(expected_specifier(stage)), reply.data.size(),
                              hex_bytes(reply.data))),
            is_segment(stage) ? SdoFailure::unexpected_segment_command
                              : SdoFailure::unexpected_sdo_command);
      }
      return tagged(message.error().context(Errc::malformed,
                                            fmt::format("{}: slave {:#06x} sent an SDO response "
                                                        "that does not decode ({})",
                                                        what_, station, hex_bytes(reply.data))),
                    SdoFailure::invalid_response);
    }
    if (const auto* a = std::get_if<wire::SdoAbort>(&*message)) {
      return Error(Errc::sdo_abort, fmt::format("{} aborted: 0x{:08X} {}", what_, a->code,
                                                wire::sdo_abort_text(a->code)))
          .with_value(a->code);
    }
    return std::move(*message);
  }

  exec::Task<void> abort(const Mailbox::Guard& guard, wire::SdoAbortCode code) {
    wire::SdoAbort request{index_, subindex_, static_cast<std::uint32_t>(code)};
    auto data = wire::encode_sdo(request);
    if (!data) co_return;
    (void)co_await mailbox_.send(guard, wire::MailboxType::coe, std::move(*data), options_.timeout,
                                 what_ + ": aborting the transfer");
  }

  Mailbox& mailbox_;
  std::string what_;
  std::uint16_t index_;
  std::uint8_t subindex_;
  SdoOptions options_;
  std::uint8_t last_command_ = 0;
};

std::string transfer_name(const char* direction, const Mailbox& mailbox, std::uint16_t index,
                          std::uint8_t subindex, bool complete_access) {
  return fmt::format("SDO {} {} of slave {:#06x}{}", direction, object_name(index, subindex),
                     mailbox.station(), complete_access ? " (complete access)" : "");
}

Result<void> check_complete_access(const std::string& what, std::uint8_t subindex,
                                   const SdoOptions& options) {
  if (options.complete_access && subindex > 1) {
    return Error(
        Errc::invalid_argument,
        fmt::format("{}: complete access starts at subindex 0 or 1, not {}", what, subindex));
  }
  return ok();
}

}  // namespace

namespace detail {
Error typed_size_mismatch(std::uint16_t station, std::uint16_t index, std::uint8_t subindex,
                          std::size_t got, std::size_t expected) {
  return Error(Errc::malformed,
               fmt::format("SDO upload {} of slave {:#06x}: the slave sent {} bytes, expected {}",
                           object_name(index, subindex), station, got, expected));
}
}  // namespace detail

std::optional<std::uint32_t> sdo_abort_code(const Error& error) noexcept {
  return error.code_value(Errc::sdo_abort);
}

std::string_view to_string(SdoFailure failure) noexcept {
  switch (failure) {
    case SdoFailure::none:
      return "none";
    case SdoFailure::aborted:
      return "aborted";
    case SdoFailure::response_timeout:
      return "response_timeout";
    case SdoFailure::mailbox_error:
      return "mailbox_error";
    case SdoFailure::counter_mismatch:
      return "counter_mismatch";
    case SdoFailure::unexpected_mailbox_type:
      return "unexpected_mailbox_type";
    case SdoFailure::unexpected_coe_service:
      return "unexpected_coe_service";
    case SdoFailure::invalid_response:
      return "invalid_response";
    case SdoFailure::unexpected_sdo_command:
      return "unexpected_sdo_command";
    case SdoFailure::unexpected_object:
      return "unexpected_object";
    case SdoFailure::toggle_mismatch:
      return "toggle_mismatch";
    case SdoFailure::invalid_segment_padding:
      return "invalid_segment_padding";
    case SdoFailure::unexpected_segment_command:
      return "unexpected_segment_command";
    case SdoFailure::size_mismatch:
      return "size_mismatch";
    case SdoFailure::too_large:
      return "too_large";
  }
  return "unknown";
}

SdoFailure sdo_failure(const Error& error) noexcept {
  constexpr auto kLast = static_cast<std::uint32_t>(SdoFailure::too_large);
  for (const Error* e = &error; e != nullptr; e = e->cause()) {
    const auto& value = e->value();
    if (value && *value >= kSdoFailureValueBase && *value <= kSdoFailureValueBase + kLast &&
        (e->code() == Errc::mailbox_error || e->code() == Errc::malformed ||
         e->code() == Errc::out_of_range)) {
      return static_cast<SdoFailure>(*value - kSdoFailureValueBase);
    }
    switch (e->code()) {
      case Errc::sdo_abort:
        if (value) return SdoFailure::aborted;
        break;
      case Errc::timeout:
        return SdoFailure::response_timeout;
      case Errc::mailbox_error:
        if (value && *value <= 0xFFFF) return SdoFailure::mailbox_error;
        break;
      default:
        break;
    }
  }
  return SdoFailure::none;
}

exec::Task<Result<std::vector<std::uint8_t>>> upload_sdo(Mailbox& mailbox, std::uint16_t index,
                                                         std::uint8_t subindex,
                                                         SdoOptions options) {
  Transfer transfer(mailbox,
                    transfer_name("upload", mailbox, index, subindex, options.complete_access),
                    index, subindex, options);
  const std::string& what = transfer.what();
  if (auto valid = check_complete_access(what, subindex, options); !valid) {
    co_return valid.error();
  }
  auto guard = co_await mailbox.lock();
  auto reply = co_await transfer.exchange(
      guard, wire::SdoInitiateUploadRequest{index, subindex, options.complete_access},
      Stage::upload_init);
  if (!reply) co_return reply.error();
  const auto* init = std::get_if<wire::SdoInitiateUploadResponse>(&*reply);
  if (init == nullptr) {
    co_return co_await transfer.violation(
        guard, Errc::mailbox_error, SdoFailure::unexpected_sdo_command,
        fmt::format("the slave answered with an SDO {} instead of an initiate upload response",
                    wire::to_string(*reply)),
        wire::SdoAbortCode::command_specifier_unknown);
  }
  if (init->index != index || init->subindex != subindex) {
    co_return co_await transfer.violation(
        guard, Errc::mailbox_error, SdoFailure::unexpected_object,
        fmt::format("the initiate upload response names {} instead",
                    object_name(init->index, init->subindex)),
        wire::SdoAbortCode::general_error);
  }
  std::vector<std::uint8_t> value = init->data;
  if (init->expedited) co_return value;

  const bool sized = init->size_indicated;
  const std::size_t size = init->complete_size;
  if (sized && size > options.max_upload_size) {
    co_return co_await transfer.violation(
        guard, Errc::out_of_range, SdoFailure::too_large,
        fmt::format("the slave announces {} bytes, more than SdoOptions::max_upload_size ({})",
                    size, options.max_upload_size),
        wire::SdoAbortCode::out_of_memory);
  }
  if (sized && value.size() >= size) {
    value.resize(size);  // slaves may pad a normal response; the size says what counts
    co_return value;
  }
  if (!sized) co_return value;  // a normal response without a size carries the whole value

  bool toggle = false;
  for (std::size_t segment = 1;; ++segment) {
    auto seg_reply = co_await transfer.exchange(guard, wire::SdoUploadSegmentRequest{toggle},
                                                Stage::upload_segment);
    if (!seg_reply) co_return seg_reply.error();
    const auto* seg = std::get_if<wire::SdoUploadSegmentResponse>(&*seg_reply);
    if (seg == nullptr) {
      co_return co_await transfer.violation(
          guard, Errc::mailbox_error, SdoFailure::unexpected_segment_command,
          fmt::format("the slave answered segment {} with an SDO {} instead of an upload segment "
                      "response",
                      segment, wire::to_string(*seg_reply)),
          wire::SdoAbortCode::command_specifier_unknown);
    }
    if (seg->toggle != toggle) {
      co_return co_await transfer.violation(
          guard, Errc::mailbox_error, SdoFailure::toggle_mismatch,
          fmt::format("upload segment {} carries toggle bit {}, expected {}", segment,
                      seg->toggle ? 1 : 0, toggle ? 1 : 0),
          wire::SdoAbortCode::toggle_bit_not_changed);
    }
    // Seven unused bytes of seven: a segment without data (a slave's padding gone wrong).
    if (seg->data.empty() && ((transfer.last_command() >> 1) & 0x07) == 0x07) {
      co_return co_await transfer.violation(
          guard, Errc::malformed, SdoFailure::invalid_segment_padding,
          fmt::format("upload segment {} declares 7 unused bytes: it carries no data", segment),
          wire::SdoAbortCode::general_error);
    }
    value.insert(value.end(), seg->data.begin(), seg->data.end());
    const std::size_t limit = sized ? size : options.max_upload_size;
    if (value.size() > limit) {
      co_return co_await transfer.violation(
          guard, Errc::malformed, SdoFailure::size_mismatch,
          sized ? fmt::format("the slave sent {} bytes by segment {}, more than the {} it "
                              "announced",
                              value.size(), segment, size)
                : fmt::format("the slave sent {} bytes by segment {}, more than "
                              "SdoOptions::max_upload_size ({})",
                              value.size(), segment, options.max_upload_size),
          wire::SdoAbortCode::general_error);
    }
    if (seg->last) break;
    toggle = !toggle;
  }
  if (sized && value.size() != size) {
    co_return tagged(Error(Errc::malformed, fmt::format("{}: the slave announced {} bytes and "
                                                        "sent {}",
                                                        what, size, value.size())),
                     SdoFailure::size_mismatch);
  }
  co_return value;
}

exec::Task<Result<void>> download_sdo(Mailbox& mailbox, std::uint16_t index, std::uint8_t subindex,
                                      std::vector<std::uint8_t> data, SdoOptions options) {
  Transfer transfer(mailbox,
                    transfer_name("download", mailbox, index, subindex, options.complete_access),
                    index, subindex, options);
  const std::string& what = transfer.what();
  if (auto valid = check_complete_access(what, subindex, options); !valid) {
    co_return valid.error();
  }
  const std::size_t capacity = mailbox.max_request_data();
  if (capacity < wire::kSdoFixedSize) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: the mailbox (SM0 of {} bytes) is too small for SDO transfers "
                                "(at least 16 bytes)",
                                what, mailbox.config().out_size));
  }
  if (data.size() > 0xFFFFFFFFu) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: {} bytes exceed the 32-bit SDO size", what, data.size()));
  }
  wire::SdoInitiateDownloadRequest init;
  init.index = index;
  init.subindex = subindex;
  init.complete_access = options.complete_access;
  std::size_t sent = 0;
  if (!options.complete_access && !data.empty() && data.size() <= wire::kSdoMaxExpeditedData) {
    init.expedited = true;
    init.data = data;
    sent = data.size();
  } else {
    init.complete_size = static_cast<std::uint32_t>(data.size());
    sent = std::min(data.size(), capacity - wire::kSdoFixedSize);
    init.data.assign(data.begin(), data.begin() + static_cast<std::ptrdiff_t>(sent));
  }

  auto guard = co_await mailbox.lock();
  auto reply = co_await transfer.exchange(guard, init, Stage::download_init);
  if (!reply) co_return reply.error();
  const auto* response = std::get_if<wire::SdoInitiateDownloadResponse>(&*reply);
  if (response == nullptr) {
    co_return co_await transfer.violation(
        guard, Errc::mailbox_error, SdoFailure::unexpected_sdo_command,
        fmt::format("the slave answered with an SDO {} instead of an initiate download response",
                    wire::to_string(*reply)),
        wire::SdoAbortCode::command_specifier_unknown);
  }
  if (response->index != index || response->subindex != subindex) {
    co_return co_await transfer.violation(
        guard, Errc::mailbox_error, SdoFailure::unexpected_object,
        fmt::format("the initiate download response names {} instead",
                    object_name(response->index, response->subindex)),
        wire::SdoAbortCode::general_error);
  }

  // A segment: CoE header, command byte, then the data.
  const std::size_t segment_capacity = capacity - wire::kCoeHeaderSize - 1;
  bool toggle = false;
  for (std::size_t segment = 1; sent < data.size(); ++segment) {
    const std::size_t n = std::min(segment_capacity, data.size() - sent);
    wire::SdoDownloadSegmentRequest request;
    request.toggle = toggle;
    request.last = sent + n == data.size();
    request.data.assign(data.begin() + static_cast<std::ptrdiff_t>(sent),
                        data.begin() + static_cast<std::ptrdiff_t>(sent + n));
    auto seg_reply = co_await transfer.exchange(guard, request, Stage::download_segment);
    if (!seg_reply) co_return seg_reply.error();
    const auto* seg = std::get_if<wire::SdoDownloadSegmentResponse>(&*seg_reply);
    if (seg == nullptr) {
      co_return co_await transfer.violation(
          guard, Errc::mailbox_error, SdoFailure::unexpected_segment_command,
          fmt::format("the slave answered segment {} with an SDO {} instead of a download "
                      "segment response",
                      segment, wire::to_string(*seg_reply)),
          wire::SdoAbortCode::command_specifier_unknown);
    }
    if (seg->toggle != toggle) {
      co_return co_await transfer.violation(
          guard, Errc::mailbox_error, SdoFailure::toggle_mismatch,
          fmt::format("download segment response {} carries toggle bit {}, expected {}", segment,
                      seg->toggle ? 1 : 0, toggle ? 1 : 0),
          wire::SdoAbortCode::toggle_bit_not_changed);
    }
    sent += n;
    toggle = !toggle;
  }
  co_return ok();
}

// ---- SDO information ------------------------------------------------------------------------

namespace {

exec::Task<Result<wire::SdoInfoMessage>> info_exchange(Mailbox& mailbox,
                                                       const wire::SdoInfoMessage& request,
                                                       const std::string& what,
                                                       const SdoOptions& options) {
  auto data = wire::encode_sdo_info(request);
  if (!data) co_return data.error().context(Errc::invalid_argument, what);
  auto guard = co_await mailbox.lock();
  auto reply = co_await mailbox.exchange(guard, wire::MailboxType::coe, std::move(*data),
                                         options.timeout, info_filter, what);
  wire::SdoInfoReassembler reassembler;
  for (std::size_t fragment = 1;; ++fragment) {
    if (!reply) co_return reply.error();
    if (reply->header.type != wire::MailboxType::coe) {
      co_return Error(Errc::mailbox_error,
                      fmt::format("{}: slave {:#06x} answered with a {} mailbox (type {}) instead "
                                  "of CoE",
                                  what, mailbox.station(), wire::to_string(reply->header.type),
                                  static_cast<unsigned>(reply->header.type)));
    }
    auto coe = wire::decode_coe_header(reply->data);
    if (!coe) {
      co_return coe.error().context(
          Errc::malformed, fmt::format("{}: the reply of slave {:#06x} has no complete CoE "
                                       "header",
                                       what, mailbox.station()));
    }
    if (coe->service != wire::CoeService::sdo_information) {
      co_return Error(Errc::mailbox_error,
                      fmt::format("{}: slave {:#06x} answered with CoE service {} ({}), expected "
                                  "8 (SDO information)",
                                  what, mailbox.station(), static_cast<unsigned>(coe->service),
                                  wire::to_string(coe->service)));
    }
    auto status = reassembler.add(reply->data);
    if (!status) {
      co_return status.error().context(
          Errc::malformed,
          fmt::format("{}: fragment {} from slave {:#06x}", what, fragment, mailbox.station()));
    }
    if (*status == wire::SdoInfoReassembler::Status::complete) break;
    reply = co_await mailbox.receive(guard, options.timeout, info_filter, what);
  }
  auto message = reassembler.message();
  if (!message) {
    co_return message.error().context(
        Errc::malformed,
        fmt::format("{}: the response of slave {:#06x} does not decode", what, mailbox.station()));
  }
  if (const auto* refused = std::get_if<wire::SdoInfoError>(&*message)) {
    co_return Error(Errc::sdo_abort,
                    fmt::format("{} aborted: 0x{:08X} {}", what, refused->abort_code,
                                wire::sdo_abort_text(refused->abort_code)))
        .with_value(refused->abort_code);
  }
  co_return std::move(*message);
}

Error wrong_info_response(const std::string& what, const Mailbox& mailbox,
                          const wire::SdoInfoMessage& message, std::string_view expected) {
  return Error(Errc::mailbox_error,
               fmt::format("{}: slave {:#06x} answered with a {} instead of a {}", what,
                           mailbox.station(), wire::to_string(wire::opcode_of(message)), expected));
}

}  // namespace

exec::Task<Result<std::vector<std::uint16_t>>> od_list(Mailbox& mailbox, wire::OdListType type,
                                                       SdoOptions options) {
  const std::string what = fmt::format("SDO information: OD list '{}' of slave {:#06x}",
                                       wire::to_string(type), mailbox.station());
  auto message = co_await info_exchange(mailbox, wire::OdListRequest{type}, what, options);
  if (!message) co_return message.error();
  const auto* list = std::get_if<wire::OdListResponse>(&*message);
  if (list == nullptr) {
    co_return wrong_info_response(what, mailbox, *message, "get OD list response");
  }
  if (list->list_type != type) {
    co_return Error(Errc::mailbox_error, fmt::format("{}: the response is list type {} ({})", what,
                                                     static_cast<unsigned>(list->list_type),
                                                     wire::to_string(list->list_type)));
  }
  co_return list->indices;
}

exec::Task<Result<wire::ObjectDescriptionResponse>> object_description(Mailbox& mailbox,
                                                                       std::uint16_t index,
                                                                       SdoOptions options) {
  const std::string what = fmt::format(
      "SDO information: object description 0x{:04X} of slave "
      "{:#06x}",
      index, mailbox.station());
  auto message =
      co_await info_exchange(mailbox, wire::ObjectDescriptionRequest{index}, what, options);
  if (!message) co_return message.error();
  auto* description = std::get_if<wire::ObjectDescriptionResponse>(&*message);
  if (description == nullptr) {
    co_return wrong_info_response(what, mailbox, *message, "get object description response");
  }
  if (description->index != index) {
    co_return Error(Errc::mailbox_error,
                    fmt::format("{}: the response describes 0x{:04X}", what, description->index));
  }
  co_return std::move(*description);
}

exec::Task<Result<wire::EntryDescriptionResponse>> entry_description(Mailbox& mailbox,
                                                                     std::uint16_t index,
                                                                     std::uint8_t subindex,
                                                                     std::uint8_t value_info,
                                                                     SdoOptions options) {
  const std::string what = fmt::format("SDO information: entry description {} of slave {:#06x}",
                                       object_name(index, subindex), mailbox.station());
  auto message = co_await info_exchange(
      mailbox, wire::EntryDescriptionRequest{index, subindex, value_info}, what, options);
  if (!message) co_return message.error();
  auto* entry = std::get_if<wire::EntryDescriptionResponse>(&*message);
  if (entry == nullptr) {
    co_return wrong_info_response(what, mailbox, *message, "get entry description response");
  }
  if (entry->index != index || entry->subindex != subindex) {
    co_return Error(Errc::mailbox_error, fmt::format("{}: the response describes {}", what,
                                                     object_name(entry->index, entry->subindex)));
  }
  co_return std::move(*entry);
}

}  // namespace ecat::master
