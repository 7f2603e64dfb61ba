#include <array>
#include <cerrno>
#include <cstring>
#include <utility>

#include <fcntl.h>
#include <fmt/format.h>
#include <linux/if.h>
#include <linux/if_tun.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/master/eoe.hpp>
#include <ecat/master/eoe_tap.hpp>
#include <ecat/master/slave.hpp>

namespace ecat::master {

namespace {

constexpr std::size_t kReadBuffer = 2048;  // more than any frame the interface can hand over

Error os_error(Errc code, std::string what) {
  return Error(code, fmt::format("{}: {}", what, std::strerror(errno)));
}

Errc errc_of(int error) {
  return error == EPERM || error == EACCES ? Errc::permission_denied : Errc::io_error;
}

// Up, and the address, through an ordinary socket's interface ioctls.
Result<void> configure(const std::string& name, const EoeTapOptions& options) {
  const int s = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (s < 0) return os_error(Errc::io_error, "EoE TAP: socket for the interface ioctls");
  auto fail = [&](std::string what) {
    const int error = errno;
    ::close(s);
    errno = error;
    return os_error(errc_of(error), fmt::format("EoE TAP {}: {}", name, what));
  };
  ifreq request{};
  std::memcpy(request.ifr_name, name.c_str(), name.size());
  if (options.address) {
    auto set = [&](unsigned long op, std::uint32_t value) {
      sockaddr_in address{};
      address.sin_family = AF_INET;
      address.sin_addr.s_addr = htonl(value);
      std::memcpy(&request.ifr_addr, &address, sizeof(address));
      return ::ioctl(s, op, &request) == 0;
    };
    const std::uint32_t mask = options.prefix_length == 0
                                   ? 0
                                   : ~std::uint32_t{0}
                                         << (32 - std::min<unsigned>(options.prefix_length, 32));
    if (!set(SIOCSIFADDR, *options.address)) return fail("setting the address");
    if (!set(SIOCSIFNETMASK, mask)) return fail("setting the netmask");
  }
  if (options.up) {
    if (::ioctl(s, SIOCGIFFLAGS, &request) != 0) return fail("reading the flags");
    request.ifr_flags = static_cast<short>(request.ifr_flags | IFF_UP);
    if (::ioctl(s, SIOCSIFFLAGS, &request) != 0) return fail("setting it up");
  }
  ::close(s);
  return ok();
}

}  // namespace

Result<std::unique_ptr<EoeTap>> EoeTap::open(Slave& slave, EoeTapOptions options) {
  std::string name = options.name.empty() ? fmt::format("eoe0s{}", slave.position()) : options.name;
  if (name.size() >= IFNAMSIZ) {
    return Error(Errc::invalid_argument,
                 fmt::format("EoE TAP: interface name '{}' is longer than {} characters", name,
                             IFNAMSIZ - 1));
  }
  const int fd = ::open("/dev/net/tun", O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int error = errno;
    if (error == EPERM || error == EACCES) {
      return Error(Errc::permission_denied,
                   fmt::format("EoE TAP {}: opening /dev/net/tun: {} (creating a TAP interface "
                               "needs CAP_NET_ADMIN and access to /dev/net/tun)",
                               name, std::strerror(error)));
    }
    return Error(Errc::io_error, fmt::format("EoE TAP {}: opening /dev/net/tun: {} (is the tun "
                                             "driver available?)",
                                             name, std::strerror(error)));
  }
  ifreq request{};
  request.ifr_flags = IFF_TAP | IFF_NO_PI;
  std::memcpy(request.ifr_name, name.c_str(), name.size());
  if (::ioctl(fd, TUNSETIFF, &request) != 0) {
    const int error = errno;
    ::close(fd);
    if (error == EPERM || error == EACCES) {
      return Error(Errc::permission_denied,
                   fmt::format("EoE TAP {}: creating the interface: {} (needs CAP_NET_ADMIN)", name,
                               std::strerror(error)));
    }
    return Error(Errc::io_error,
                 fmt::format("EoE TAP {}: creating the interface: {}", name, std::strerror(error)));
  }
  name = request.ifr_name;
  if (auto configured = configure(name, options); !configured) {
    ::close(fd);
    return configured.error();
  }
  const int wake = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (wake < 0) {
    auto error = os_error(Errc::io_error, fmt::format("EoE TAP {}: eventfd", name));
    ::close(fd);
    return error;
  }
  return std::unique_ptr<EoeTap>(new EoeTap(slave, fd, wake, std::move(name), std::move(options)));
}

EoeTap::EoeTap(Slave& slave, int fd, int wake, std::string name, EoeTapOptions options)
    : slave_(slave), fd_(fd), wake_(wake), name_(std::move(name)), options_(std::move(options)) {
  reader_ = std::thread([this] { to_slave_loop(); });
  writer_ = std::thread([this] { from_slave_loop(); });
}

EoeTap::~EoeTap() {
  stop();
  ::close(fd_);
  ::close(wake_);
}

void EoeTap::stop() {
  running_ = false;
  const std::uint64_t one = 1;
  (void)!::write(wake_, &one, sizeof(one));
  if (reader_.joinable()) reader_.join();
  if (writer_.joinable()) writer_.join();
}

EoeTapStats EoeTap::stats() const noexcept {
  return {to_slave_.load(),    from_slave_.load(),     dropped_.load(),
          send_errors_.load(), receive_errors_.load(), write_errors_.load()};
}

void EoeTap::to_slave_loop() {
  std::array<std::uint8_t, kReadBuffer> buffer{};
  while (running_) {
    std::array<pollfd, 2> fds{{{fd_, POLLIN, 0}, {wake_, POLLIN, 0}}};
    const int n = ::poll(fds.data(), fds.size(), -1);
    if (n < 0) {
      if (errno == EINTR) continue;
      ++receive_errors_;
      return;
    }
    if (!running_ || (fds[1].revents & POLLIN) != 0) return;
    // Everything the interface has now, one frame per read.
    for (;;) {
      const ssize_t got = ::read(fd_, buffer.data(), buffer.size());
      if (got < 0) break;  // EAGAIN: drained (other errors: poll tells again)
      const auto size = static_cast<std::size_t>(got);
      if (size < kEoeMinFrameSize || size > kEoeMaxFrameSize) {
        ++dropped_;
        continue;
      }
      if (auto sent = slave_.eoe_send(std::span<const std::uint8_t>(buffer.data(), size)); sent) {
        ++to_slave_;
      } else {
        ++send_errors_;
        std::this_thread::sleep_for(options_.error_pause);
        break;
      }
    }
  }
}

void EoeTap::from_slave_loop() {
  while (running_) {
    auto frames = slave_.eoe_receive(options_.receive_timeout);
    if (!frames) {
      ++receive_errors_;
      std::this_thread::sleep_for(options_.error_pause);
      continue;
    }
    for (const auto& frame : *frames) {
      if (::write(fd_, frame.data(), frame.size()) == static_cast<ssize_t>(frame.size())) {
        ++from_slave_;
      } else {
        ++write_errors_;
      }
    }
  }
}

}  // namespace ecat::master
