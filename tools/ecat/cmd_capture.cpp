// ecat capture --attach [NAME] -o FILE [--seconds S]: writes a running master's flight recorder
// (the frames of its last seconds, `ecat serve --flight-recorder`) to a pcapng file, with times
// and directions, for `ecat decode`, Wireshark or tshark.
//
// The master's endpoint answers "capture.frames" with the frames as JSON (the master layer knows
// no file formats); the file is written here.
//
// Exit codes: 0 written; 1 the master has no recorder, is not there, or the file failed; 2 bad
// arguments.
#include <chrono>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/ipc/line_server.hpp>
#include <ecat/link/recording_link.hpp>
#include <ecat/master/control_endpoint.hpp>

#include "command.hpp"
#include "live_capture.hpp"

namespace {

using namespace std::chrono_literals;
using Json = nlohmann::json;

struct Options {
  std::optional<std::string> attach;
  std::string output;
  std::optional<double> seconds;
};

std::optional<std::vector<std::uint8_t>> from_hex(const std::string& text) {
  if (text.size() % 2 != 0) return std::nullopt;
  std::vector<std::uint8_t> out(text.size() / 2);
  for (std::size_t i = 0; i < out.size(); ++i) {
    unsigned value = 0;
    for (int k = 0; k < 2; ++k) {
      const char c = text[2 * i + static_cast<std::size_t>(k)];
      const int digit = c >= '0' && c <= '9'   ? c - '0'
                        : c >= 'a' && c <= 'f' ? c - 'a' + 10
                        : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                               : -1;
      if (digit < 0) return std::nullopt;
      value = value * 16 + static_cast<unsigned>(digit);
    }
    out[i] = static_cast<std::uint8_t>(value);
  }
  return out;
}

int fail(const std::string& message) {
  fmt::print(stderr, "ecat capture: {}\n", message);
  return 1;
}

int run(const Options& o) {
  if (!o.attach) {
    fmt::print(stderr, "ecat capture: give --attach [NAME] (a running `ecat serve`)\n");
    return 2;
  }
  auto path = ecat::master::find_control_endpoint(*o.attach);
  if (!path) return fail(path.error().describe());
  Json request{{"op", "capture.frames"}};
  if (o.seconds) request["seconds"] = *o.seconds;
  auto answered = ecat::ipc::call(*path, request.dump(), 60s, "master");
  if (!answered) return fail(answered.error().describe());
  const Json reply = Json::parse(*answered, nullptr, false);
  if (reply.is_discarded() || !reply.is_object()) return fail("the master's reply is not JSON");
  if (!reply.value("ok", false)) return fail(reply.value("error", std::string("failed")));
  const auto frames_it = reply.find("frames");
  if (frames_it == reply.end() || !frames_it->is_array()) {
    return fail("the master's reply holds no frames");
  }
  std::vector<ecat::link::RecordedFrame> frames;
  frames.reserve(frames_it->size());
  for (const auto& f : *frames_it) {
    if (!f.is_object() || !f.contains("data") || !f["data"].is_string() || !f.contains("t_ns") ||
        !f["t_ns"].is_number_integer()) {
      return fail(fmt::format("frame {} of the master's reply is malformed", frames.size() + 1));
    }
    auto data = from_hex(f["data"].get<std::string>());
    if (!data) return fail(fmt::format("frame {}: data is not hex", frames.size() + 1));
    ecat::link::RecordedFrame frame;
    frame.realtime_ns = f["t_ns"].get<std::int64_t>();
    frame.steady_ns = f.value("steady_ns", std::int64_t{0});
    frame.direction = f.value("direction", std::string()) == "inbound"
                          ? ecat::link::FrameDirection::inbound
                          : ecat::link::FrameDirection::outbound;
    frame.original_length = f.value("length", static_cast<std::uint32_t>(data->size()));
    frame.data = std::move(*data);
    frames.push_back(std::move(frame));
  }
  if (auto written = ecat::tool::write_recorded_frames(o.output, frames, *path); !written) {
    return fail(written.error().describe());
  }
  fmt::print(stderr, "ecat capture: {} frames of the last {:.1f} s written to {}{}\n",
             frames.size(), reply.value("seconds", 0.0), o.output,
             reply.value("complete", true) ? "" : " (the oldest left out: the reply's size limit)");
  return 0;
}

ecat::tool::Command setup(CLI::App& parent) {
  auto o = std::make_shared<Options>();
  auto* app = parent.add_subcommand(
      "capture", "Write a running master's flight recorder (its last seconds) to a pcapng file");
  app->add_option("--attach", o->attach,
                  "The running master: its control endpoint NAME or socket PATH (empty: the one "
                  "running)")
      ->expected(0, 1);
  app->add_option("-o,--output", o->output, "The pcapng file to write")->required();
  app->add_option("--seconds", o->seconds,
                  "How far back (default: all the recorder keeps, its --flight-recorder)")
      ->check(ecat::tool::number_in(0, 3600, "seconds", true));
  return {app, [o] { return run(*o); }};
}

const bool registered = ecat::tool::register_command(&setup);

}  // namespace
