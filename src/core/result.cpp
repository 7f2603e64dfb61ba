#include <cstdio>
#include <cstdlib>

#include <ecat/result.hpp>

namespace ecat {

std::string_view to_string(Errc code) noexcept {
  switch (code) {
    case Errc::invalid_argument:
      return "invalid argument";
    case Errc::malformed:
      return "malformed";
    case Errc::truncated:
      return "truncated";
    case Errc::unsupported:
      return "unsupported";
    case Errc::out_of_range:
      return "out of range";
    case Errc::not_found:
      return "not found";
    case Errc::timeout:
      return "timeout";
    case Errc::io_error:
      return "I/O error";
    case Errc::permission_denied:
      return "permission denied";
    case Errc::busy:
      return "busy";
    case Errc::closed:
      return "closed";
    case Errc::wrong_state:
      return "wrong state";
    case Errc::wkc_mismatch:
      return "working counter mismatch";
    case Errc::al_error:
      return "AL error";
    case Errc::sdo_abort:
      return "SDO abort";
    case Errc::mailbox_error:
      return "mailbox error";
    case Errc::expired:
      return "expired";
    case Errc::not_ready:
      return "not ready";
    case Errc::stale:
      return "stale";
    case Errc::internal:
      return "internal error";
  }
  return "unknown error";
}

std::string Error::describe() const {
  std::string text = message_;
  for (const Error* c = cause(); c != nullptr; c = c->cause()) {
    text += ": ";
    text += c->message();
  }
  return text;
}

namespace detail {
void result_misuse(const char* what, const Error* error) noexcept {
  if (error != nullptr) {
    std::fprintf(stderr, "ecat: %s: %s\n", what, error->describe().c_str());
  } else {
    std::fprintf(stderr, "ecat: %s\n", what);
  }
  std::abort();
}
}  // namespace detail

}  // namespace ecat
