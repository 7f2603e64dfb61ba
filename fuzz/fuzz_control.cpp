// The control channel's request handling (JSON parser, request schema, fault vocabulary and the
// injection itself) must answer every input with one line of valid JSON and never crash. Each
// input runs against a small simulator; a frame passes after it so that injected faults act, and
// the faults are cleared so that state does not pile up across inputs.
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include <ecat/sim/control.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

namespace {

std::int64_t fake_time = 1'000'000'000;

ecat::sim::SimServer& server() {
  static std::unique_ptr<ecat::sim::SimServer> instance = [] {
    auto segment = std::make_unique<ecat::sim::Segment>();
    for (const char* name : {"a", "b", "c"}) {
      auto esc = ecat::sim::make_device(ecat::sim::DeviceConfig{});
      if (!esc.ok() || !segment->add_slave(name, std::move(*esc)).ok()) std::abort();
    }
    ecat::sim::DeviceConfig mailbox;
    mailbox.profile = "mailbox";
    if (auto esc = ecat::sim::make_device(mailbox); esc.ok()) {
      (void)segment->add_slave("m", std::move(*esc));
    }
    ecat::sim::SimServerOptions options;
    options.clock = [] { return fake_time; };
    return std::make_unique<ecat::sim::SimServer>(std::move(segment), options);
  }();
  return *instance;
}

std::vector<std::uint8_t> probe_frame() {
  std::array<std::uint8_t, 128> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  ecat::wire::DatagramHeader brd;
  brd.command = ecat::wire::Command::brd;
  brd.address = ecat::wire::physical_address(0, ecat::wire::reg::kAlStatus);
  brd.length = 2;
  (void)builder.add(brd);
  ecat::wire::DatagramHeader lrw;
  lrw.command = ecat::wire::Command::lrw;
  lrw.index = 1;
  lrw.length = 8;
  (void)builder.add(lrw);
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

// One line, an object that leads with "ok", and valid JSON throughout (accept() also refuses text
// that is not UTF-8, which an echoed name or error could otherwise carry).
bool plausible_json_object(const std::string& reply) {
  return reply.size() >= 2 && reply.front() == '{' && reply.back() == '}' &&
         reply.find('\n') == std::string::npos &&
         (reply.rfind("{\"ok\":true", 0) == 0 || reply.rfind("{\"ok\":false", 0) == 0) &&
         nlohmann::json::accept(reply);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  auto& sim = server();
  const std::string_view request(reinterpret_cast<const char*>(data), size);
  const std::string reply = ecat::sim::handle_control_request(sim, request);
  if (!plausible_json_object(reply)) std::abort();
  fake_time += 1'000'000;
  static const auto frame = probe_frame();
  (void)sim.exchange(frame);
  fake_time += 1'000'000;
  (void)sim.exchange(frame);
  sim.clear_faults();
  sim.set_master_link(true);
  return 0;
}
