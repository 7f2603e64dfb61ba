#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <utility>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <ecat/log.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/master/mailbox_gateway.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_gateway.hpp>

namespace ecat::master {

namespace {

// Room for any gateway message (2 + 2047 bytes) and padding after it; a datagram longer than this
// is not one (MSG_TRUNC tells its real size).
constexpr std::size_t kReceiveBuffer = 4096;

class Fd {
 public:
  Fd() = default;
  explicit Fd(int fd) noexcept : fd_(fd) {}
  Fd(Fd&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}
  Fd& operator=(Fd&& other) noexcept {
    if (this != &other) {
      close();
      fd_ = std::exchange(other.fd_, -1);
    }
    return *this;
  }
  ~Fd() { close(); }
  int get() const noexcept { return fd_; }
  void close() noexcept {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

 private:
  int fd_ = -1;
};

Error os_error(Errc code, std::string what, int err) {
  return Error(code, fmt::format("{}: {}", what, std::strerror(err)));
}

struct Request {
  sockaddr_in from{};
  wire::MailboxHeader header{};  // as the tool sent it
  std::vector<std::uint8_t> data;
  std::string slave;  // the slave's name in the session
};

}  // namespace

struct MailboxGateway::Impl {
  Impl(Master& m, MailboxGatewayConfig c) : master(m), config(std::move(c)) {}

  Master& master;
  MailboxGatewayConfig config;
  Fd socket;
  Fd wake;  // eventfd: stop() wakes the receiver
  std::string address;
  std::uint16_t port = 0;

  std::thread receiver;
  std::vector<std::thread> workers;
  mutable std::mutex mutex;
  std::condition_variable changed;
  bool stopping = false;
  std::deque<Request> queue;
  std::set<std::uint16_t> busy;  // stations with a request in flight
  MailboxGatewayStats stats;

  Result<void> open() {
    sockaddr_in local{};
    local.sin_family = AF_INET;
    local.sin_port = htons(config.port);
    if (config.address.empty()) {
      local.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    } else if (config.address == "*") {
      local.sin_addr.s_addr = htonl(INADDR_ANY);
    } else if (::inet_pton(AF_INET, config.address.c_str(), &local.sin_addr) != 1) {
      return Error(
          Errc::invalid_argument,
          fmt::format("mailbox gateway: '{}' is not an IPv4 address (or \"*\")", config.address));
    }
    socket = Fd(::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0));
    if (socket.get() < 0) return os_error(Errc::io_error, "mailbox gateway: socket()", errno);
    char text[INET_ADDRSTRLEN] = {};
    ::inet_ntop(AF_INET, &local.sin_addr, text, sizeof text);
    address = text;
    if (::bind(socket.get(), reinterpret_cast<const sockaddr*>(&local), sizeof local) != 0) {
      const int err = errno;
      const std::string where = fmt::format("mailbox gateway: binding {}:{}", address, config.port);
      if (err == EADDRINUSE) {
        return Error(Errc::busy,
                     fmt::format("{}: the port is in use (another gateway, or an `ecat sim "
                                 "--udp` on the same port?); choose another port",
                                 where));
      }
      if (err == EACCES) return os_error(Errc::permission_denied, where, err);
      return os_error(err == EADDRNOTAVAIL ? Errc::invalid_argument : Errc::io_error, where, err);
    }
    sockaddr_in bound{};
    socklen_t length = sizeof bound;
    if (::getsockname(socket.get(), reinterpret_cast<sockaddr*>(&bound), &length) == 0) {
      port = ntohs(bound.sin_port);
    }
    wake = Fd(::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK));
    if (wake.get() < 0) return os_error(Errc::io_error, "mailbox gateway: eventfd()", errno);
    return ok();
  }

  void send(const sockaddr_in& to, const wire::MailboxHeader& header, wire::Bytes data) {
    std::array<std::uint8_t, wire::kMailboxGatewayHeaderSize + wire::kMaxGatewayMailboxSize> out{};
    auto size = wire::encode_gateway_message(header, data, out);
    bool sent = false;
    if (size) {
      sent = ::sendto(socket.get(), out.data(), *size, MSG_DONTWAIT,
                      reinterpret_cast<const sockaddr*>(&to),
                      sizeof to) == static_cast<ssize_t>(*size);
    }
    std::lock_guard lock(mutex);
    if (!sent) ++stats.send_errors;
  }

  // A mailbox error message (ETG.1000.6 §5.6: type 0, service 0x0001, the detail) to `to`,
  // addressed as the request was. `counter` picks the cause's counter in stats.
  void send_error(const sockaddr_in& to, std::uint16_t station, wire::MailboxErrorCode code,
                  std::uint64_t MailboxGatewayStats::*counter) {
    {
      std::lock_guard lock(mutex);
      ++stats.error_replies;
      ++(stats.*counter);
    }
    wire::MailboxHeader header;
    header.address = station;
    header.type = wire::MailboxType::error;
    std::array<std::uint8_t, wire::kMailboxErrorReplySize> body{};
    wire::ByteWriter w(body);
    (void)wire::encode_mailbox_error({static_cast<std::uint16_t>(code)}, w);
    send(to, header, body);
  }

  void count(std::uint64_t MailboxGatewayStats::*counter) {
    std::lock_guard lock(mutex);
    ++(stats.*counter);
  }

  void receive_loop() {
    std::vector<std::uint8_t> buffer(kReceiveBuffer);
    for (;;) {
      std::array<pollfd, 2> fds{{{socket.get(), POLLIN, 0}, {wake.get(), POLLIN, 0}}};
      if (::poll(fds.data(), fds.size(), -1) < 0) {
        if (errno == EINTR) continue;
        ECAT_LOG(LogLevel::error, "gateway", fmt::format("poll failed: {}", std::strerror(errno)));
        return;
      }
      if (fds[1].revents != 0) return;
      if ((fds[0].revents & POLLIN) == 0) continue;
      sockaddr_in from{};
      socklen_t from_length = sizeof from;
      const ssize_t n =
          ::recvfrom(socket.get(), buffer.data(), buffer.size(), MSG_DONTWAIT | MSG_TRUNC,
                     reinterpret_cast<sockaddr*>(&from), &from_length);
      if (n < 0) continue;  // EAGAIN, or an ICMP error of an earlier reply
      count(&MailboxGatewayStats::datagrams);
      if (static_cast<std::size_t>(n) > buffer.size()) {
        count(&MailboxGatewayStats::malformed);
        continue;
      }
      take(from, wire::Bytes(buffer.data(), static_cast<std::size_t>(n)));
    }
  }

  void take(const sockaddr_in& from, wire::Bytes datagram) {
    auto message = wire::decode_gateway_message(datagram);
    if (!message) {
      count(&MailboxGatewayStats::malformed);
      return;
    }
    const std::uint16_t station = message->header.address;
    if (station == 0) {
      send_error(from, station, wire::MailboxErrorCode::unsupported_protocol,
                 &MailboxGatewayStats::unknown_station);
      return;
    }
    std::string name;
    for (const auto& s : master.slaves()) {
      if (s.station == station) name = s.name;
    }
    if (name.empty()) {
      send_error(from, station, wire::MailboxErrorCode::syntax,
                 &MailboxGatewayStats::unknown_station);
      return;
    }
    {
      std::lock_guard lock(mutex);
      if (queue.size() < config.max_queued) {
        queue.push_back(
            Request{from, message->header,
                    std::vector<std::uint8_t>(message->data.begin(), message->data.end()),
                    std::move(name)});
        changed.notify_all();
        return;
      }
    }
    send_error(from, station, wire::MailboxErrorCode::no_more_memory,
               &MailboxGatewayStats::queue_full);
  }

  // The oldest request whose slave has none in flight; waits for one.
  std::optional<Request> next() {
    std::unique_lock lock(mutex);
    for (;;) {
      if (stopping) return std::nullopt;
      auto it = std::find_if(queue.begin(), queue.end(),
                             [this](const Request& r) { return !busy.contains(r.header.address); });
      if (it != queue.end()) {
        Request request = std::move(*it);
        queue.erase(it);
        busy.insert(request.header.address);
        ++stats.forwarded;
        return request;
      }
      changed.wait(lock);
    }
  }

  void work() {
    while (auto request = next()) {
      serve(*request);
      std::lock_guard lock(mutex);
      busy.erase(request->header.address);
      changed.notify_all();
    }
  }

  void serve(Request& request) {
    const std::uint16_t station = request.header.address;
    auto slave = master.slave(request.slave);
    if (!slave) {
      count(&MailboxGatewayStats::failed);  // the session ended since the request came
      return;
    }
    auto reply = (*slave)->mailbox_exchange(request.header.type, std::move(request.data),
                                            config.request_timeout);
    if (reply) {
      wire::MailboxHeader header = reply->header;
      header.address = station;
      if (wire::kMailboxHeaderSize + reply->data.size() > wire::kMaxGatewayMailboxSize) {
        count(&MailboxGatewayStats::failed);  // a mailbox beyond what the header can frame
        return;
      }
      count(&MailboxGatewayStats::replies);
      send(request.from, header, reply->data);
      return;
    }
    const Error& error = reply.error();
    if (error.code() == Errc::mailbox_error && error.value()) {
      // The slave's own mailbox error reply, passed on.
      count(&MailboxGatewayStats::replies);
      wire::MailboxHeader header;
      header.address = station;
      header.type = wire::MailboxType::error;
      std::array<std::uint8_t, wire::kMailboxErrorReplySize> body{};
      wire::ByteWriter w(body);
      (void)wire::encode_mailbox_error({static_cast<std::uint16_t>(*error.value())}, w);
      send(request.from, header, body);
      return;
    }
    switch (error.code()) {
      case Errc::unsupported:
        send_error(request.from, station, wire::MailboxErrorCode::unsupported_protocol,
                   &MailboxGatewayStats::unsupported);
        return;
      case Errc::invalid_argument:
        send_error(request.from, station, wire::MailboxErrorCode::invalid_size,
                   &MailboxGatewayStats::too_large);
        return;
      case Errc::timeout:
        count(&MailboxGatewayStats::timeouts);
        break;
      default:
        count(&MailboxGatewayStats::failed);
        break;
    }
    ECAT_LOG(
        LogLevel::debug, "gateway",
        fmt::format("no reply to the request for station {:#06x}: {}", station, error.message()));
  }

  void stop() {
    {
      std::lock_guard lock(mutex);
      if (stopping) return;
      stopping = true;
      queue.clear();
      changed.notify_all();
    }
    const std::uint64_t one = 1;
    if (wake.get() >= 0) (void)!::write(wake.get(), &one, sizeof one);
    if (receiver.joinable()) receiver.join();
    for (auto& w : workers) {
      if (w.joinable()) w.join();
    }
  }
};

Result<void> parse_mailbox_gateway_address(std::string_view text, MailboxGatewayConfig& config) {
  const auto bad = [&](std::string_view why) {
    return Error(Errc::invalid_argument,
                 fmt::format("mailbox gateway address '{}': {} (ADDR:PORT, ADDR or PORT; ADDR an "
                             "IPv4 address or *)",
                             text, why));
  };
  const auto is_port = [](std::string_view t) {
    return !t.empty() && t.size() <= 5 && t.find_first_not_of("0123456789") == t.npos;
  };
  std::string_view host = text;
  std::string_view port;
  if (const auto colon = text.rfind(':'); colon != text.npos) {
    host = text.substr(0, colon);
    port = text.substr(colon + 1);
    if (!is_port(port)) return bad("the port is not a number");
  } else if (is_port(text)) {
    host = {};
    port = text;
  }
  std::uint16_t number = wire::kMailboxGatewayPort;
  if (!port.empty()) {
    const unsigned long value = std::stoul(std::string(port));
    if (value > 0xFFFF) return bad("the port is beyond 65535");
    number = static_cast<std::uint16_t>(value);
  }
  if (!host.empty() && host != "*") {
    in_addr probe{};
    if (::inet_pton(AF_INET, std::string(host).c_str(), &probe) != 1) {
      return bad("not an IPv4 address");
    }
  }
  config.address = std::string(host);
  config.port = number;
  return ok();
}

MailboxGateway::MailboxGateway(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

MailboxGateway::~MailboxGateway() {
  stop();
}

Result<std::unique_ptr<MailboxGateway>> MailboxGateway::start(Master& master,
                                                              MailboxGatewayConfig config) {
  if (config.workers == 0 || config.max_queued == 0) {
    return Error(Errc::invalid_argument, "mailbox gateway: workers and max_queued must be > 0");
  }
  auto impl = std::make_unique<Impl>(master, std::move(config));
  if (auto opened = impl->open(); !opened) return opened.error();
  std::unique_ptr<MailboxGateway> gateway(new MailboxGateway(std::move(impl)));
  Impl& i = *gateway->impl_;
  i.receiver = std::thread([&i] { i.receive_loop(); });
  for (std::size_t n = 0; n < i.config.workers; ++n)
    i.workers.emplace_back([&i] { i.work(); });
  return gateway;
}

void MailboxGateway::stop() {
  impl_->stop();
}

const MailboxGatewayConfig& MailboxGateway::config() const noexcept {
  return impl_->config;
}

MailboxGatewayStatus MailboxGateway::status() const {
  std::lock_guard lock(impl_->mutex);
  return {impl_->address, impl_->port, impl_->queue.size(), impl_->busy.size(), impl_->stats};
}

}  // namespace ecat::master
