// CANopen over EtherCAT, the master's side: SDO upload and download (expedited, normal and
// segmented; single entries and complete access) and the SDO information service, over a slave's
// Mailbox, from tasks on the control thread.
//
//   auto value = co_await master::upload<std::uint16_t>(mailbox, 0x6041, 0);
//   auto done = co_await master::download_sdo(mailbox, 0x1C12, 0, {1, 0, 0x01, 0x16},
//                                             {.complete_access = true});
//
// A transfer holds the mailbox for its whole length, so transfers from several tasks to one slave
// queue behind each other, and transfers to different slaves run side by side (sharing frames).
//
// Every reply is checked as hostile input: command, index and subindex, toggle bit, sizes. A
// reply that breaks the protocol fails the transfer (Errc::mailbox_error, or Errc::malformed for
// bytes that do not decode) with a message naming what was wrong, and the master then aborts the
// transfer on the slave's side. An SDO abort from the slave fails it with Errc::sdo_abort:
//   "SDO upload 0x6041:00 of slave 0x1001 aborted: 0x06020000 object does not exist in the object
//    dictionary"
// and the abort code is sdo_abort_code(error).
#pragma once

#include <chrono>
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string_view>
#include <type_traits>
#include <vector>

#include <ecat/exec/task.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/sdo_info.hpp>

namespace ecat::master {

// The value of index:subindex (with complete access: of the object from subindex on).
exec::Task<Result<std::vector<std::uint8_t>>> upload_sdo(Mailbox& mailbox, std::uint16_t index,
                                                         std::uint8_t subindex,
                                                         SdoOptions options = {});

// Writes `data`: expedited for 1..4 bytes (without complete access), otherwise normal, with
// segments when the value does not fit one mailbox.
exec::Task<Result<void>> download_sdo(Mailbox& mailbox, std::uint16_t index, std::uint8_t subindex,
                                      std::vector<std::uint8_t> data, SdoOptions options = {});

// The SDO abort code of an Errc::sdo_abort error (searching its causes), or nullopt.
std::optional<std::uint32_t> sdo_abort_code(const Error& error) noexcept;

// Why a transfer failed, for callers that branch on it (the message says it in words, with the
// expected and received values). Protocol violations are Errc::mailbox_error (Errc::malformed
// for replies that do not decode) whose value() is kSdoFailureValueBase + the failure; the value
// is outside the 16-bit range of mailbox error details, so the two never mix.
enum class SdoFailure : std::uint8_t {
  none,                        // not a failed transfer (or a cause none of these names)
  aborted,                     // the slave aborted: sdo_abort_code() has the code
  response_timeout,            // no reply within SdoOptions::timeout (Errc::timeout)
  mailbox_error,               // the slave answered with a mailbox error reply (value: detail)
  counter_mismatch,            // the reply's mailbox counter broke the slave's sequence
  unexpected_mailbox_type,     // the reply is not a CoE mailbox
  unexpected_coe_service,      // the reply is CoE but not an SDO response
  invalid_response,            // no complete CoE header, or an SDO response that does not decode
  unexpected_sdo_command,      // an initiate stage answered with another kind of SDO
  unexpected_object,           // the initiate response names another index:subindex
  toggle_mismatch,             // a segment response carries the wrong toggle bit
  invalid_segment_padding,     // a segment's unused-bytes count leaves it no data
  unexpected_segment_command,  // a segment stage answered with another command
  size_mismatch,               // the uploaded bytes disagree with the announced size
  too_large,                   // the announced size exceeds SdoOptions::max_upload_size
};
inline constexpr std::uint32_t kSdoFailureValueBase = 0x0001'0000;
// "aborted", "response_timeout", "counter_mismatch", ...
std::string_view to_string(SdoFailure failure) noexcept;
// The failure an error (or the first of its causes that names one) stands for.
SdoFailure sdo_failure(const Error& error) noexcept;

// ---- Typed helpers for integral values (little-endian, exactly sizeof(T) bytes) -------------

namespace detail {
Error typed_size_mismatch(std::uint16_t station, std::uint16_t index, std::uint8_t subindex,
                          std::size_t got, std::size_t expected);
}  // namespace detail

template <class T>
concept SdoIntegral = std::integral<T> && !std::same_as<T, bool>;

template <SdoIntegral T>
exec::Task<Result<T>> upload(Mailbox& mailbox, std::uint16_t index, std::uint8_t subindex,
                             SdoOptions options = {}) {
  auto bytes = co_await upload_sdo(mailbox, index, subindex, options);
  if (!bytes) co_return bytes.error();
  if (bytes->size() != sizeof(T)) {
    co_return detail::typed_size_mismatch(mailbox.station(), index, subindex, bytes->size(),
                                          sizeof(T));
  }
  using Raw = std::make_unsigned_t<T>;
  Raw raw = 0;
  for (std::size_t i = 0; i < sizeof(T); ++i)
    raw = static_cast<Raw>(raw | static_cast<Raw>(Raw{(*bytes)[i]} << (8 * i)));
  co_return static_cast<T>(raw);
}

template <SdoIntegral T>
exec::Task<Result<void>> download(Mailbox& mailbox, std::uint16_t index, std::uint8_t subindex,
                                  T value, SdoOptions options = {}) {
  std::vector<std::uint8_t> bytes(sizeof(T));
  const auto raw = static_cast<std::make_unsigned_t<T>>(value);
  for (std::size_t i = 0; i < sizeof(T); ++i)
    bytes[i] = static_cast<std::uint8_t>(raw >> (8 * i));
  co_return co_await download_sdo(mailbox, index, subindex, std::move(bytes), options);
}

// ---- SDO information service -------------------------------------------------------------------

// The object indices of a list (for OdListType::number_of_objects: the lengths of lists 1..5).
exec::Task<Result<std::vector<std::uint16_t>>> od_list(Mailbox& mailbox, wire::OdListType type,
                                                       SdoOptions options = {});
exec::Task<Result<wire::ObjectDescriptionResponse>> object_description(Mailbox& mailbox,
                                                                       std::uint16_t index,
                                                                       SdoOptions options = {});
// `value_info`: wire::kValueInfo* flags (unit, default, minimum, maximum value).
exec::Task<Result<wire::EntryDescriptionResponse>> entry_description(Mailbox& mailbox,
                                                                     std::uint16_t index,
                                                                     std::uint8_t subindex,
                                                                     std::uint8_t value_info,
                                                                     SdoOptions options = {});

}  // namespace ecat::master
