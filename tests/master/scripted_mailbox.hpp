// A protocol client's tests against a scripted slave: the simulator's `mailbox` device with a
// handler for one mailbox type that records every request and answers from a script (one entry
// of replies per request, in order; none left: no reply). The EoE and SoE client tests use it.
#pragma once

#include <deque>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/mailbox.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/faults.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master::test {

template <wire::MailboxType Type>
class ScriptedMailboxTest : public ::testing::Test {
 protected:
  using Bytes = std::vector<std::uint8_t>;

  struct Script {
    std::vector<Bytes> requests;             // the mailbox data of every request, as it arrived
    std::deque<std::vector<Bytes>> answers;  // per request, in order; none left: no reply
  };

  void SetUp() override {
    bench_ =
        SimBench::make("version: 1\nsimulator:\n  slaves:\n    - {name: mbx, profile: mailbox}\n");
    ASSERT_TRUE(bench_);
    auto configs = bench_->run(bring_all_to_preop(bench_->loop, *bench_->bus, 1));
    ASSERT_TRUE(configs.ok()) << configs.error().describe();
    mailbox_ =
        std::make_unique<Mailbox>(bench_->loop, *bench_->bus, station_at(0), configs->front());
    script_ = std::make_shared<Script>();
    bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      sim::coe_server_of(segment.esc(0))
          ->set_protocol_handler(
              Type, [script = script_](sim::Esc&, const wire::MailboxHeader&, wire::Bytes data) {
                script->requests.emplace_back(data.begin(), data.end());
                std::vector<sim::MailboxReply> replies;
                if (script->answers.empty()) return replies;
                for (auto& a : script->answers.front())
                  replies.push_back({Type, a});
                script->answers.pop_front();
                return replies;
              });
      return 0;
    });
  }

  void answer(std::vector<Bytes> replies) {
    bench_->server->with_segment([&](sim::Segment&, sim::FaultInjector&) {
      script_->answers.push_back(std::move(replies));
      return 0;
    });
  }
  std::vector<Bytes> requests() {
    return bench_->server->with_segment(
        [&](sim::Segment&, sim::FaultInjector&) { return script_->requests; });
  }
  template <class T>
  T run(exec::Task<T> task) {
    return bench_->run(std::move(task));
  }

  std::unique_ptr<SimBench> bench_;
  std::unique_ptr<Mailbox> mailbox_;
  std::shared_ptr<Script> script_;
};

}  // namespace ecat::master::test
