// Slave's EoE calls: the EoE client (eoe.hpp) runs on the control thread for an application
// thread (the TAP pump, a tool), as the SoE and VoE calls in slave_soe.cpp do. The client's state
// (frame counter, the frame being reassembled, counters) lives with the slave and is made at the
// first EoE call.
#include <chrono>
#include <memory>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/eoe.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/sii.hpp>

#include "blocking.hpp"
#include "slave_impl.hpp"

namespace ecat::master {

using detail::blocking;

namespace {

using namespace std::chrono_literals;

// The mailbox is usable and the SII declares EoE; the slave's client (made on first use).
// (A template: Slave::Impl is private to Slave, and this helper is not a member.)
template <class Impl>
Result<EoeClient*> eoe_client(Impl& impl) {
  if (auto checked = impl.check_mailbox(); !checked) return checked.error();
  const bool declared =
      impl.sii && (impl.sii->decoded.image.mailbox_protocols & wire::mailbox_protocol::kEoe) != 0;
  if (!declared) {
    return Error(
        Errc::unsupported,
        fmt::format("{}: its SII does not declare EoE among its mailbox protocols", impl.who()));
  }
  if (!impl.eoe) impl.eoe = std::make_shared<EoeClient>();
  return impl.eoe.get();
}

}  // namespace

Result<void> Slave::eoe_send(std::span<const std::uint8_t> frame,
                             std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::vector<std::uint8_t> bytes, std::chrono::nanoseconds t,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<void>> {
    (void)keep;
    auto client = eoe_client(impl);
    if (!client) co_return client.error();
    auto sent = co_await (*client)->send(*impl.mailbox, std::move(bytes), t);
    impl.note_mailbox_counters();
    co_return sent;
  };
  // `timeout` bounds each fragment's write (SM0 full); the wait here allows for a frame of a few
  // fragments that each take long before it gives up on the control thread.
  return blocking(impl_->session,
                  task(*impl_, std::vector<std::uint8_t>(frame.begin(), frame.end()), timeout,
                       impl_->session.shared_from_this()),
                  timeout * 4 + 1s, fmt::format("EoE send to slave {}", name_));
}

Result<std::vector<std::vector<std::uint8_t>>> Slave::eoe_receive(
    std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::chrono::nanoseconds t, std::shared_ptr<Session> keep)
      -> exec::Task<Result<std::vector<std::vector<std::uint8_t>>>> {
    (void)keep;
    auto client = eoe_client(impl);
    if (!client) co_return client.error();
    auto frames = co_await (*client)->receive(*impl.mailbox, t);
    impl.note_mailbox_counters();
    co_return frames;
  };
  return blocking(impl_->session, task(*impl_, timeout, impl_->session.shared_from_this()),
                  timeout * 2 + 1s, fmt::format("EoE receive from slave {}", name_));
}

Result<void> Slave::eoe_set_ip(const wire::EoeIpParameters& parameters,
                               std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, wire::EoeIpParameters p, std::chrono::nanoseconds t,
                 std::shared_ptr<Session> keep) -> exec::Task<Result<void>> {
    (void)keep;
    auto client = eoe_client(impl);
    if (!client) co_return client.error();
    auto done = co_await (*client)->set_ip(*impl.mailbox, std::move(p), t);
    impl.note_mailbox_counters();
    co_return done;
  };
  return blocking(impl_->session,
                  task(*impl_, parameters, timeout, impl_->session.shared_from_this()),
                  timeout * 2 + 1s, fmt::format("EoE set IP parameter of slave {}", name_));
}

Result<EoeStats> Slave::eoe_stats(std::chrono::nanoseconds timeout) {
  auto task = [](Impl& impl, std::shared_ptr<Session> keep) -> exec::Task<Result<EoeStats>> {
    (void)keep;
    co_return impl.eoe ? impl.eoe->stats() : EoeStats{};
  };
  return blocking(impl_->session, task(*impl_, impl_->session.shared_from_this()), timeout,
                  fmt::format("EoE counters of slave {}", name_));
}

}  // namespace ecat::master
