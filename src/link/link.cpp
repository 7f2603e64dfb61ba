// The Link interface's defaults (link.hpp keeps the frame codecs out of the application's
// headers, so they live here).
#include <type_traits>

#include <ecat/link/link.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {

static_assert(std::is_same_v<decltype(ReceivedFrame::source), wire::MacAddress>,
              "a received frame's source is a MAC address");

std::size_t Link::max_frame_size() const {
  return wire::kMaxFrameSize;
}

void Link::set_frame_budget(std::chrono::nanoseconds) {}

int Link::wait_fd() {
  return -1;
}

Result<void> Link::set_port_nop(Port, NopSlot, std::optional<DatagramSelector>) {
  return Error(Errc::unsupported,
               "link " + name() + " has one port: per-port frame contents need a redundant link");
}

}  // namespace ecat::link
