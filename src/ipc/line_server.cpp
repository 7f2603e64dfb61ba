#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <ecat/ipc/line_server.hpp>

namespace ecat::ipc {

namespace {

// Lines a follower may have queued before it counts as not reading (and is dropped); published
// lines wait here while the server thread is busy with a request.
constexpr std::size_t kMaxPublished = 4096;

Result<sockaddr_un> unix_address(const std::string& path) {
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof address.sun_path) {
    return Error(Errc::invalid_argument, fmt::format("socket path '{}' must be 1 to {} bytes long",
                                                     path, sizeof address.sun_path - 1));
  }
  std::memcpy(address.sun_path, path.data(), path.size());
  return address;
}

void close_fd(int& fd) {
  if (fd >= 0) ::close(fd);
  fd = -1;
}

}  // namespace

bool someone_listens(const std::string& path) {
  auto address = unix_address(path);
  if (!address) return false;
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  const bool ok = ::connect(fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address) == 0;
  ::close(fd);
  return ok;
}

std::string runtime_dir() {
  const char* runtime = std::getenv("XDG_RUNTIME_DIR");
  return runtime != nullptr && *runtime != '\0' ? runtime : "/tmp";
}

std::vector<std::string> find_sockets(std::string_view prefix) {
  std::vector<std::string> dirs;
  if (const char* runtime = std::getenv("XDG_RUNTIME_DIR"); runtime != nullptr && *runtime) {
    dirs.emplace_back(runtime);
  }
  dirs.emplace_back("/tmp");
  std::vector<std::string> alive;
  for (const auto& dir : dirs) {
    std::error_code ec;
    for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (name.size() < prefix.size() + 5 || name.compare(0, prefix.size(), prefix) != 0 ||
          name.compare(name.size() - 5, 5, ".sock") != 0) {
        continue;
      }
      const std::string path = it->path().string();
      struct stat st {};
      if (::lstat(path.c_str(), &st) != 0 || !S_ISSOCK(st.st_mode) || st.st_uid != ::geteuid()) {
        continue;
      }
      if (std::find(alive.begin(), alive.end(), path) == alive.end() && someone_listens(path)) {
        alive.push_back(path);
      }
    }
  }
  return alive;
}

// ---- The server ------------------------------------------------------------------------------

struct LineServer::Impl {
  struct Client {
    int fd = -1;
    Peer peer;
    std::string input;
    std::string output;
    bool closing = false;  // close once the output is flushed
    bool follower = false;
  };

  Handler handler;
  ErrorFormatter errors;
  LineServerOptions options;
  std::string path;
  int listen_fd = -1;
  int wake[2] = {-1, -1};
  std::thread thread;
  std::atomic<bool> stopping{false};
  std::vector<Client> clients;
  std::uint64_t connections = 0;

  mutable std::mutex published_mutex;
  std::deque<std::string> published;  // lines for the followers, not yet queued to them
  std::atomic<std::size_t> follower_count{0};

  ~Impl() {
    for (auto& c : clients)
      close_fd(c.fd);
    close_fd(listen_fd);
    for (int& fd : wake)
      close_fd(fd);
  }

  void poke() {
    const char byte = 1;
    (void)!::write(wake[1], &byte, 1);
  }

  void flush(Client& c) {
    while (!c.output.empty()) {
      const ssize_t n = ::send(c.fd, c.output.data(), c.output.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
      if (n > 0) {
        c.output.erase(0, static_cast<std::size_t>(n));
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
      c.output.clear();
      c.closing = true;
      c.input.clear();
      return;
    }
  }

  // Returns false when the client is gone.
  bool read_client(Client& c) {
    char chunk[4096];
    const ssize_t n = ::recv(c.fd, chunk, sizeof chunk, MSG_DONTWAIT);
    if (n == 0) return false;
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    if (c.closing) return true;
    c.input.append(chunk, static_cast<std::size_t>(n));
    std::size_t start = 0;
    while (!c.closing) {
      const auto newline = c.input.find('\n', start);
      if (newline == std::string::npos) break;
      std::string_view line(c.input.data() + start, newline - start);
      if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
      if (line.size() > options.max_line) {
        refuse_line(c);
        break;
      }
      if (line.find_first_not_of(" \t") != std::string_view::npos) {
        Reply reply = handler(line, c.peer);
        c.output += reply.line;
        c.output += '\n';
        if (reply.follow && !c.follower) {
          c.follower = true;
          follower_count.fetch_add(1);
        }
      }
      start = newline + 1;
    }
    if (!c.closing) c.input.erase(0, start);
    if (!c.closing && c.input.size() > options.max_line) refuse_line(c);
    return c.output.size() <= options.max_pending_output;  // a client that never reads
  }

  void refuse_line(Client& c) {
    c.output +=
        errors(fmt::format("request: line longer than {} bytes; closing", options.max_line));
    c.output += '\n';
    c.input.clear();
    c.closing = true;
  }

  void accept_client() {
    const int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd < 0) return;
    if (clients.size() >= options.max_clients) {
      const std::string busy =
          errors(fmt::format("too many clients (at most {})", options.max_clients)) + "\n";
      (void)::send(fd, busy.data(), busy.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
      ::close(fd);
      return;
    }
    Client c;
    c.fd = fd;
    c.peer.connection = ++connections;
    ucred cred{};
    socklen_t size = sizeof cred;
    if (::getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &size) == 0) {
      c.peer.pid = cred.pid;
      c.peer.uid = cred.uid;
      c.peer.gid = cred.gid;
    }
    clients.push_back(std::move(c));
  }

  // Moves the published lines to the followers' output.
  void deliver_published() {
    std::deque<std::string> lines;
    {
      std::lock_guard lock(published_mutex);
      lines.swap(published);
    }
    if (lines.empty()) return;
    for (auto& c : clients) {
      if (!c.follower || c.closing) continue;
      for (const auto& line : lines) {
        c.output += line;
        c.output += '\n';
      }
    }
  }

  void drain_wake() {
    char buffer[64];
    while (::read(wake[0], buffer, sizeof buffer) > 0) {
    }
  }

  void run() {
    std::vector<pollfd> fds;
    while (!stopping.load()) {
      deliver_published();
      fds.clear();
      fds.push_back({wake[0], POLLIN, 0});
      fds.push_back({listen_fd, POLLIN, 0});
      for (auto& c : clients) {
        flush(c);
        short events = POLLIN;
        if (!c.output.empty()) events |= POLLOUT;
        fds.push_back({c.fd, events, 0});
      }
      if (::poll(fds.data(), fds.size(), -1) < 0) {
        if (errno == EINTR) continue;
        break;
      }
      if (fds[0].revents != 0) drain_wake();
      if (stopping.load()) break;
      if ((fds[1].revents & POLLIN) != 0) accept_client();
      // fds[2 + i] belongs to clients[i] as they were before accepting.
      const std::size_t polled = fds.size() - 2;
      std::vector<std::size_t> gone;
      for (std::size_t i = 0; i < polled; ++i) {
        Client& c = clients[i];
        const short revents = fds[2 + i].revents;
        bool alive = true;
        if ((revents & POLLIN) != 0) alive = read_client(c);
        if (alive && (revents & (POLLERR | POLLNVAL)) != 0) alive = false;
        if (alive && (revents & POLLHUP) != 0 && (revents & POLLIN) == 0) alive = false;
        if (alive) flush(c);
        if (alive && c.output.size() > options.max_pending_output) alive = false;
        if (alive && c.closing && c.output.empty()) alive = false;
        if (!alive) gone.push_back(i);
      }
      for (auto it = gone.rbegin(); it != gone.rend(); ++it) {
        Client& c = clients[*it];
        if (c.follower) follower_count.fetch_sub(1);
        close_fd(c.fd);
        clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(*it));
      }
    }
  }
};

LineServer::LineServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

LineServer::~LineServer() {
  stop();
}

const std::string& LineServer::path() const noexcept {
  return impl_->path;
}

std::size_t LineServer::followers() const noexcept {
  return impl_->follower_count.load();
}

void LineServer::publish(std::string line) {
  if (impl_->follower_count.load() == 0) return;
  {
    std::lock_guard lock(impl_->published_mutex);
    // Bounded: while the server thread is held up, the oldest lines go first (a follower that
    // needs every line reads fast enough, or resumes from the event sequence numbers).
    if (impl_->published.size() >= kMaxPublished) impl_->published.pop_front();
    impl_->published.push_back(std::move(line));
  }
  impl_->poke();
}

Result<std::unique_ptr<LineServer>> LineServer::start(std::string path, Handler handler,
                                                      ErrorFormatter errors,
                                                      LineServerOptions options) {
  auto address = unix_address(path);
  if (!address) return std::move(address).error();
  if (!handler || !errors) {
    return Error(Errc::invalid_argument, "a line server needs a handler and an error formatter");
  }
  if (options.max_clients == 0 || options.max_line == 0) {
    return Error(Errc::invalid_argument, "max_clients and max_line must be at least 1");
  }
  if ((options.mode & ~0777u) != 0) {
    return Error(Errc::invalid_argument,
                 fmt::format("socket mode {:o} has bits beyond 0777", options.mode));
  }
  struct stat info {};
  if (::lstat(path.c_str(), &info) == 0) {
    if (!S_ISSOCK(info.st_mode)) {
      return Error(Errc::busy,
                   fmt::format("{} path '{}' exists and is not a socket", options.what, path));
    }
    if (someone_listens(path)) {
      return Error(Errc::busy,
                   fmt::format("another {} already listens on '{}'", options.what, path));
    }
    ::unlink(path.c_str());
  }
  auto impl = std::make_unique<Impl>();
  impl->handler = std::move(handler);
  impl->errors = std::move(errors);
  impl->options = std::move(options);
  impl->path = path;
  impl->listen_fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (impl->listen_fd < 0) {
    return Error(Errc::io_error,
                 fmt::format("{} socket: {}", impl->options.what, std::strerror(errno)));
  }
  // The file is created owner-only and opened up to the chosen mode afterwards: nobody else can
  // connect in between.
  const mode_t old_mask = ::umask(0077);
  const int bound =
      ::bind(impl->listen_fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address);
  const int bind_errno = errno;
  ::umask(old_mask);
  if (bound != 0) {
    return Error(bind_errno == EACCES ? Errc::permission_denied : Errc::io_error,
                 fmt::format("cannot bind the {} socket '{}': {}", impl->options.what, path,
                             std::strerror(bind_errno)));
  }
  if (::chmod(path.c_str(), static_cast<mode_t>(impl->options.mode)) != 0 ||
      ::listen(impl->listen_fd, 8) != 0 || ::pipe2(impl->wake, O_CLOEXEC | O_NONBLOCK) != 0) {
    const int err = errno;
    ::unlink(path.c_str());
    return Error(Errc::io_error,
                 fmt::format("{} socket '{}': {}", impl->options.what, path, std::strerror(err)));
  }
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->run(); });
  return std::unique_ptr<LineServer>(new LineServer(std::move(impl)));
}

void LineServer::stop() {
  if (!impl_ || !impl_->thread.joinable()) return;
  impl_->stopping = true;
  impl_->poke();
  impl_->thread.join();
  ::unlink(impl_->path.c_str());
}

// ---- Clients -----------------------------------------------------------------------------------

namespace {

Result<int> connect_to(const std::string& path, std::string_view what) {
  auto address = unix_address(path);
  if (!address) return std::move(address).error();
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return Error(Errc::io_error, fmt::format("socket: {}", std::strerror(errno)));
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address) != 0) {
    const int err = errno;
    ::close(fd);
    const Errc code = err == ENOENT || err == ECONNREFUSED ? Errc::not_found
                      : err == EACCES                      ? Errc::permission_denied
                                                           : Errc::io_error;
    return Error(code,
                 fmt::format("cannot reach the {} at '{}': {}", what, path, std::strerror(err)));
  }
  return fd;
}

}  // namespace

LineClient::LineClient(int fd, std::string path, std::string what)
    : fd_(fd), path_(std::move(path)), what_(std::move(what)) {}

LineClient::LineClient(LineClient&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)),
      path_(std::move(other.path_)),
      what_(std::move(other.what_)),
      buffer_(std::move(other.buffer_)) {}

LineClient& LineClient::operator=(LineClient&& other) noexcept {
  if (this != &other) {
    close_fd(fd_);
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
    what_ = std::move(other.what_);
    buffer_ = std::move(other.buffer_);
  }
  return *this;
}

LineClient::~LineClient() {
  close_fd(fd_);
}

Result<LineClient> LineClient::connect(const std::string& path, std::string_view what) {
  auto fd = connect_to(path, what);
  if (!fd) return std::move(fd).error();
  return LineClient(*fd, path, std::string(what));
}

Result<void> LineClient::send(std::string_view request) {
  std::string line(request);
  while (!line.empty() && (line.back() == '\n' || line.back() == '\r'))
    line.pop_back();
  if (line.find('\n') != std::string::npos) {
    return Error(Errc::invalid_argument, "a request is one line");
  }
  line += '\n';
  for (std::size_t sent = 0; sent < line.size();) {
    const ssize_t n = ::send(fd_, line.data() + sent, line.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Error(Errc::io_error, fmt::format("sending to the {} at '{}': {}", what_, path_,
                                               std::strerror(errno)));
    }
    sent += static_cast<std::size_t>(n);
  }
  return ok();
}

Result<std::optional<std::string>> LineClient::read_line(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  char chunk[8192];
  while (true) {
    if (const auto newline = buffer_.find('\n'); newline != std::string::npos) {
      std::string line = buffer_.substr(0, newline);
      buffer_.erase(0, newline + 1);
      return std::optional<std::string>(std::move(line));
    }
    if (buffer_.size() > (64u << 20)) {
      return Error(Errc::malformed,
                   fmt::format("a line from the {} at '{}' is longer than 64 MiB", what_, path_));
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(std::max<std::int64_t>(0, left.count())));
    if (ready < 0 && errno == EINTR) continue;
    if (ready <= 0) return std::optional<std::string>();
    const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return Error(Errc::closed, fmt::format("the {} at '{}' closed the connection", what_, path_));
    }
    buffer_.append(chunk, static_cast<std::size_t>(n));
  }
}

Result<std::string> LineClient::request(std::string_view line, std::chrono::milliseconds timeout) {
  if (auto sent = send(line); !sent) return std::move(sent).error();
  auto reply = read_line(timeout);
  if (!reply) return std::move(reply).error();
  if (!*reply) {
    return Error(Errc::timeout, fmt::format("no reply from the {} at '{}' within {} ms", what_,
                                            path_, timeout.count()));
  }
  return std::move(**reply);
}

Result<std::string> call(const std::string& path, std::string_view request,
                         std::chrono::milliseconds timeout, std::string_view what) {
  auto client = LineClient::connect(path, what);
  if (!client) return std::move(client).error();
  return client->request(request, timeout);
}

}  // namespace ecat::ipc
