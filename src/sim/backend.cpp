#include <fmt/format.h>

#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/open.hpp>
#include <ecat/sim/backend.hpp>
#include <ecat/sim/ring.hpp>

namespace ecat::sim {

namespace {

// The function link of an in-process simulator, keeping that simulator alive as long as the
// master holds the link.
class SimulatorLink final : public link::ForwardingLink {
 public:
  SimulatorLink(std::shared_ptr<SimServer> server, std::string name)
      : ForwardingLink(server->function_link(std::move(name))), server_(std::move(server)) {}
  ~SimulatorLink() override { release_inner(); }  // before the simulator it calls into

 private:
  std::shared_ptr<SimServer> server_;
};

}  // namespace

Result<Backend> open_backend(std::string_view spec) {
  if (spec.substr(0, 4) != "sim:") {
    auto link = link::open_link(spec);
    if (!link) return std::move(link).error();
    return Backend{std::move(*link), nullptr};
  }
  const std::string path(spec.substr(4));
  if (path.empty()) {
    return Error(Errc::invalid_argument,
                 fmt::format("invalid backend '{}': no ring file after 'sim:'", spec));
  }
  auto ring = load_ring(path);
  if (!ring) return std::move(ring).error();
  auto server = make_server(*ring);
  if (!server) return std::move(server).error();
  std::shared_ptr<SimServer> shared(std::move(*server));
  auto link = std::make_unique<SimulatorLink>(shared, std::string(spec));
  return Backend{std::move(link), std::move(shared)};
}

}  // namespace ecat::sim
