// Proving the simulator against captures of real segments:
//
//   ecat sim profile CAPTURE [--out DIR] [--json]
//     rebuilds the slaves a capture shows (SII images, ESC hardware, CoE objects) and writes one
//     SII .bin per slave, ring.yaml and profile.json into DIR (default: the capture's name
//     without extension, in the current folder). Exit 0 written, 1 nothing could be written,
//     2 the capture cannot be read.
//
//   ecat sim verify CAPTURE [--ring FILE] [--json]
//     replays the master's requests of CAPTURE against a simulated segment (the ring file, or
//     the profile rebuilt from the capture itself) and compares every reply; the last line is
//     "datagrams=N wkc_match=A/B data_match=C/D malformed=M". Exit 0 when something was compared,
//     every WKC matches, no frame was malformed and at least
//     99 % of the compared data does, 1 otherwise, 2 when the capture or ring cannot be read.
//
// `ecat sim` (cmd_sim.cpp) carries them through sim_verify_commands.hpp.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include <fmt/format.h>

#include <ecat/sim/capture_profile.hpp>
#include <ecat/sim/capture_verify.hpp>
#include <ecat/sim/ring.hpp>

#include "command.hpp"
#include "sim_verify_commands.hpp"

namespace ecat::tool {

namespace {

struct ProfileOptions {
  std::string capture;
  std::string out;
  bool json = false;
};

struct VerifyCliOptions {
  std::string capture;
  std::string ring;
  bool json = false;
};

void print_error(const Error& error) {
  std::fprintf(stderr, "ecat: %s\n", error.describe().c_str());
}

int run_profile(const ProfileOptions& options) {
  auto trace = sim::load_capture_trace(options.capture);
  if (!trace) {
    print_error(trace.error());
    return 2;
  }
  auto profile = sim::build_capture_profile(*trace);
  if (!profile) {
    print_error(profile.error());
    return 1;
  }
  std::string dir = options.out;
  if (dir.empty()) dir = std::filesystem::path(options.capture).stem().string() + "-profile";
  auto written = sim::write_capture_profile(*profile, dir);
  if (!written) {
    print_error(written.error());
    return 1;
  }
  if (options.json) {
    std::fputs(sim::capture_profile_json(*profile).c_str(), stdout);
    return 0;
  }
  std::printf("%s: %zu slave(s)\n", trace->source.c_str(), profile->slaves.size());
  for (const auto& s : profile->slaves) {
    std::size_t words = 0;
    for (bool r : s.sii_word_read)
      words += r ? 1 : 0;
    std::printf(
        "  %zu %-28s station %-8s ESC type 0x%02X, %u FMMUs, %u SMs, SII words read %zu, "
        "CoE objects %zu%s%s\n",
        s.position, s.name.c_str(), s.station ? fmt::format("0x{:04x}", *s.station).c_str() : "-",
        s.hardware.type, s.hardware.fmmu_count, s.hardware.sync_manager_count, words,
        s.objects.size(), s.device_emulation ? ", device emulation" : "",
        s.dc_system_time ? ", DC system time" : "");
  }
  for (const auto& path : *written)
    std::printf("wrote %s\n", path.c_str());
  return 0;
}

int run_verify(const VerifyCliOptions& options) {
  auto trace = sim::load_capture_trace(options.capture);
  if (!trace) {
    print_error(trace.error());
    return 2;
  }
  std::unique_ptr<sim::Segment> segment;
  if (!options.ring.empty()) {
    auto ring = sim::load_ring(options.ring);
    if (!ring) {
      print_error(ring.error());
      return 2;
    }
    auto built = sim::build_segment(*ring);
    if (!built) {
      print_error(built.error());
      return 2;
    }
    segment = std::move(*built);
  } else {
    auto profile = sim::build_capture_profile(*trace);
    if (!profile) {
      print_error(profile.error());
      return 1;
    }
    auto built = sim::build_capture_segment(*profile);
    if (!built) {
      print_error(built.error());
      return 1;
    }
    segment = std::move(*built);
  }
  auto report = sim::verify_capture(*trace, *segment);
  if (!report) {
    print_error(report.error());
    return 2;
  }
  const std::string text =
      options.json ? sim::verify_report_json(*report) : sim::format_verify_report(*report);
  std::fputs(text.c_str(), stdout);
  return report->passed() ? 0 : 1;
}

}  // namespace

Command add_sim_profile_command(CLI::App& parent, const std::string& name) {
  auto* app = parent.add_subcommand(
      name, "Rebuild simulator profiles (SII images, ring file, JSON) from a capture");
  auto options = std::make_shared<ProfileOptions>();
  app->add_option("CAPTURE", options->capture, "Capture of a real segment (pcap or pcapng)")
      ->required();
  app->add_option("--out", options->out, "Output folder (default: <capture name>-profile)");
  app->add_flag("--json", options->json, "Print the profile as JSON");
  return {app, [options] { return run_profile(*options); }};
}

Command add_sim_verify_command(CLI::App& parent, const std::string& name) {
  auto* app =
      parent.add_subcommand(name,
                            "Replay a capture against the simulator and compare every reply "
                            "(exit 0: all WKC match and >= 99 % of the data)");
  auto options = std::make_shared<VerifyCliOptions>();
  app->add_option("CAPTURE", options->capture, "Capture of a real segment (pcap or pcapng)")
      ->required();
  app->add_option("--ring", options->ring,
                  "Ring file to simulate (default: the profile rebuilt from the capture)");
  app->add_flag("--json", options->json, "Print the report as JSON");
  return {app, [options] { return run_verify(*options); }};
}

}  // namespace ecat::tool
