// Error values for every fallible call in ecat. Exceptions never cross the public API: a call
// that can fail returns ecat::Result<T>, which holds either a T or an ecat::Error.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <variant>

namespace ecat {

// What kind of failure an Error is. The message says which thing failed; the code lets a caller
// branch without parsing text.
enum class Errc : std::uint8_t {
  invalid_argument,   // a caller passed a value outside what the call accepts
  malformed,          // bytes from the wire or a file do not follow the format
  truncated,          // bytes end before the format says they should
  unsupported,        // well-formed, but a feature ecat does not handle
  out_of_range,       // an index, address or length beyond a limit
  not_found,          // a named thing (slave, signal, object, interface) does not exist
  timeout,            // no answer in the time allowed
  io_error,           // the operating system refused or failed an I/O operation
  permission_denied,  // missing privilege (for example CAP_NET_RAW)
  busy,               // the resource is in use; try again later
  closed,             // the object was stopped or its peer went away
  wrong_state,        // the call is not valid in the current state
  wkc_mismatch,       // a datagram came back with an unexpected working counter
  al_error,           // a slave refused an AL state change (AL status code attached)
  sdo_abort,          // a CoE SDO transfer was aborted (abort code attached)
  mailbox_error,      // a mailbox exchange failed (protocol error, counter, unexpected reply)
  expired,            // realtime work was dropped because it became stale before it was sent
  not_ready,          // no value yet (process data before the first valid cycle)
  stale,              // a value exists but is older than its freshness window allows
  internal,           // a bug in ecat: please report it
};

std::string_view to_string(Errc code) noexcept;

// An error: a code, a message naming what failed, and optionally the error that caused it.
class Error {
 public:
  Error(Errc code, std::string message) : code_(code), message_(std::move(message)) {}

  Errc code() const noexcept { return code_; }
  const std::string& message() const noexcept { return message_; }
  const Error* cause() const noexcept { return cause_.get(); }

  // A number that goes with the code, for callers that branch on it: the AL status code of an
  // Errc::al_error, the abort code of an Errc::sdo_abort, the mailbox error detail of an
  // Errc::mailbox_error. code_value() searches the cause chain for the first error with `code`.
  Error&& with_value(std::uint32_t value) && {
    value_ = value;
    return std::move(*this);
  }
  Error& with_value(std::uint32_t value) & {
    value_ = value;
    return *this;
  }
  const std::optional<std::uint32_t>& value() const noexcept { return value_; }
  std::optional<std::uint32_t> code_value(Errc code) const noexcept {
    for (const Error* e = this; e != nullptr; e = e->cause()) {
      if (e->code() == code && e->value()) return e->value();
    }
    return std::nullopt;
  }

  // Wraps this error as the cause of a new error that says what was being attempted:
  //   sii_error.context(Errc::io_error, "reading SII of slave 3")
  Error context(Errc code, std::string message) const& {
    Error outer(code, std::move(message));
    outer.cause_ = std::make_shared<const Error>(*this);
    return outer;
  }
  // Same, keeping this error's code.
  Error context(std::string message) const& { return context(code_, std::move(message)); }

  // "message: cause message: ..." for logs and the command line.
  std::string describe() const;

 private:
  Errc code_;
  std::string message_;
  std::shared_ptr<const Error> cause_;
  std::optional<std::uint32_t> value_;
};

// A value of type T or an Error. Deliberately small: construct from either, test with ok() or
// operator bool, then take value() or error(). Accessing the wrong side is a bug and aborts.
template <class T>
class [[nodiscard]] Result {
 public:
  using value_type = T;

  template <class U = T, std::enable_if_t<std::is_constructible_v<T, U&&> &&
                                              !std::is_same_v<std::decay_t<U>, Error> &&
                                              !std::is_same_v<std::decay_t<U>, Result>,
                                          int> = 0>
  Result(U&& value) : v_(std::in_place_index<0>, std::forward<U>(value)) {}  // NOLINT
  Result(Error error) : v_(std::in_place_index<1>, std::move(error)) {}      // NOLINT

  bool ok() const noexcept { return v_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }

  T& value() & { return checked_value(); }
  const T& value() const& { return const_cast<Result*>(this)->checked_value(); }
  T&& value() && { return std::move(checked_value()); }

  const Error& error() const& { return const_cast<Result*>(this)->checked_error(); }
  Error&& error() && { return std::move(checked_error()); }

  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  T&& operator*() && { return std::move(value()); }

  template <class U>
  T value_or(U&& fallback) const& {
    return ok() ? std::get<0>(v_) : static_cast<T>(std::forward<U>(fallback));
  }

 private:
  T& checked_value();
  Error& checked_error();
  std::variant<T, Error> v_;
};

template <>
class [[nodiscard]] Result<void> {
 public:
  using value_type = void;

  Result() = default;
  Result(Error error) : error_(std::move(error)) {}  // NOLINT

  bool ok() const noexcept { return !error_.has_value(); }
  explicit operator bool() const noexcept { return ok(); }
  void value() const;
  const Error& error() const&;
  Error&& error() &&;

 private:
  std::optional<Error> error_;
};

// Convenience for `return ecat::ok();` in functions returning Result<void>.
inline Result<void> ok() {
  return {};
}

namespace detail {
[[noreturn]] void result_misuse(const char* what, const Error* error) noexcept;
}  // namespace detail

template <class T>
T& Result<T>::checked_value() {
  if (v_.index() != 0) detail::result_misuse("value() called on an error Result", &std::get<1>(v_));
  return std::get<0>(v_);
}

template <class T>
Error& Result<T>::checked_error() {
  if (v_.index() != 1) detail::result_misuse("error() called on a successful Result", nullptr);
  return std::get<1>(v_);
}

inline void Result<void>::value() const {
  if (error_) detail::result_misuse("value() called on an error Result", &*error_);
}

inline const Error& Result<void>::error() const& {
  if (!error_) detail::result_misuse("error() called on a successful Result", nullptr);
  return *error_;
}

inline Error&& Result<void>::error() && {
  if (!error_) detail::result_misuse("error() called on a successful Result", nullptr);
  return std::move(*error_);
}

}  // namespace ecat
