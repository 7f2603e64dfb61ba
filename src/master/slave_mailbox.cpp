// Slave::mailbox_exchange: one message passed through the slave's mailbox for the mailbox gateway
// (mailbox_gateway.hpp), on the control thread, as the protocol clients' calls are.
#include <chrono>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/mailbox.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/sii.hpp>

#include "blocking.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

namespace {

using namespace std::chrono_literals;

// The SII's mailbox protocol bit (ETG.2010 word 0x1C) of a mailbox type; 0 for the error type and
// the reserved ones, which no slave declares.
std::uint16_t protocol_bit(wire::MailboxType type) noexcept {
  switch (type) {
    case wire::MailboxType::aoe:
      return wire::mailbox_protocol::kAoe;
    case wire::MailboxType::eoe:
      return wire::mailbox_protocol::kEoe;
    case wire::MailboxType::coe:
      return wire::mailbox_protocol::kCoe;
    case wire::MailboxType::foe:
      return wire::mailbox_protocol::kFoe;
    case wire::MailboxType::soe:
      return wire::mailbox_protocol::kSoe;
    case wire::MailboxType::voe:
      return wire::mailbox_protocol::kVoe;
    case wire::MailboxType::error:
      break;
  }
  return 0;
}

}  // namespace

Result<MailboxMessage> Slave::mailbox_exchange(wire::MailboxType type,
                                               std::vector<std::uint8_t> data,
                                               std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, wire::MailboxType t, std::vector<std::uint8_t> bytes,
                 std::chrono::nanoseconds wait,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<MailboxMessage>> {
    (void)keep;
    if (auto checked = impl.check_mailbox(); !checked) co_return checked.error();
    const std::uint16_t bit = protocol_bit(t);
    const bool declared = impl.sii && (impl.sii->decoded.image.mailbox_protocols & bit) != 0;
    if (bit == 0 || !declared) {
      co_return Error(Errc::unsupported,
                      fmt::format("{}: its SII does not declare mailbox type {} ({})", impl.who(),
                                  static_cast<unsigned>(t), wire::to_string(t)));
    }
    const std::string what = fmt::format("{} message passed to {}", wire::to_string(t), impl.who());
    auto reply = co_await impl.mailbox->request(
        t, std::move(bytes), wait, [t](const MailboxMessage& m) { return m.header.type == t; },
        what);
    impl.note_mailbox_counters();
    co_return reply;
  };
  // The mailbox's own waits (a full SM0, the reply, the repeat request) are bounded by `timeout`
  // each; the blocking wait allows for them all.
  return blocking(impl_->session,
                  task(*impl_, type, std::move(data), timeout, impl_->session.shared_from_this()),
                  timeout * 3 + 1s, fmt::format("mailbox exchange with slave {}", name_));
}

}  // namespace ecat::master
