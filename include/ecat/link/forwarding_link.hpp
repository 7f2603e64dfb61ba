#pragma once
// A link that hands every call to an inner link: the base of wrappers that change one or two
// things (a reply's source, what is recorded, who keeps the inner link's owner alive) and would
// otherwise forward the rest by hand, and forget the calls added later (set_port_nop,
// set_frame_budget, redundancy).
#include <memory>
#include <utility>

#include <ecat/link/link.hpp>

namespace ecat::link {

class ForwardingLink : public Link {
 public:
  explicit ForwardingLink(std::unique_ptr<Link> inner) : inner_(std::move(inner)) {}

  Result<void> send(wire::Bytes frame) override { return inner_->send(frame); }
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    return inner_->receive(timeout);
  }
  void interrupt() override { inner_->interrupt(); }
  void close() override { inner_->close(); }
  Result<void> reopen() override { return inner_->reopen(); }
  std::string name() const override { return inner_->name(); }
  LinkStats stats() const override { return inner_->stats(); }
  std::optional<RedundancyStatus> redundancy() const override { return inner_->redundancy(); }
  Result<void> set_port_nop(Port port, NopSlot slot,
                            std::optional<DatagramSelector> selector) override {
    return inner_->set_port_nop(port, slot, selector);
  }
  void set_frame_budget(std::chrono::nanoseconds budget) override {
    inner_->set_frame_budget(budget);
  }
  std::size_t max_frame_size() const override { return inner_->max_frame_size(); }
  int wait_fd() override { return inner_->wait_fd(); }

 protected:
  Link& inner() noexcept { return *inner_; }
  const Link& inner() const noexcept { return *inner_; }
  // Destroys the inner link now (a wrapper whose members the inner link depends on, destroyed
  // before this base, calls it from its destructor).
  void release_inner() noexcept { inner_.reset(); }

 private:
  std::unique_ptr<Link> inner_;
};

}  // namespace ecat::link
