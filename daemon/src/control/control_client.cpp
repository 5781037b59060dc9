#include "markerd/daemon/control/control_client.hpp"

#include <grp.h>
#include <poll.h>
#include <pwd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cerrno>
#include <cstring>
#include <vector>

#include "markerd/base/errno_text.hpp"

namespace markerd::daemon {

using Clock = std::chrono::steady_clock;

namespace {

std::string group_name(gid_t gid) {
  long size = ::sysconf(_SC_GETGR_R_SIZE_MAX);
  std::vector<char> buffer(size > 0 ? static_cast<std::size_t>(size) : 16384);
  for (;;) {
    group entry{};
    group* found = nullptr;
    const int error = ::getgrgid_r(gid, &entry, buffer.data(), buffer.size(), &found);
    if (error == ERANGE) {
      buffer.resize(buffer.size() * 2);
      continue;
    }
    if (error != 0 || found == nullptr) return std::to_string(gid);
    return found->gr_name;
  }
}

// Why a connect() failed, in words for whoever runs markerctl.
std::string connect_hint(const std::filesystem::path& path, int error) {
  switch (error) {
    case ENOENT: return " (is markerd running?)";
    case ECONNREFUSED: return " (is markerd running? nothing listens on the socket)";
    case EACCES:
    case EPERM: {
      struct stat st {};
      if (::stat(path.c_str(), &st) != 0) {
        return fmt::format(" (the directory {} is not open to you)", path.parent_path().string());
      }
      return fmt::format(
          " (the socket is open to the group '{}': add your user to it, e.g. sudo usermod -aG {} $USER, "
          "then log in again)",
          group_name(st.st_gid), group_name(st.st_gid));
    }
    default: return "";
  }
}

}  // namespace

ControlClient::ControlClient(std::filesystem::path socket_path) : path_(std::move(socket_path)) {
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  if (path_.native().size() >= sizeof address.sun_path) {
    fail(fmt::format("the path is longer than {} bytes, the limit of a Unix socket", sizeof address.sun_path - 1));
  }
  std::memcpy(address.sun_path, path_.c_str(), path_.native().size() + 1);
  fd_.reset(::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0));
  if (!fd_) throw ControlClientError(fmt::format("socket(): {}", errno_text(errno)));
  if (::connect(fd_.get(), reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
    const int error = errno;
    fd_.reset();
    throw ControlClientError(
        fmt::format("cannot connect to {}: {}{}", path_.string(), errno_text(error), connect_hint(path_, error)));
  }
}

void ControlClient::fail(const std::string& why) const {
  throw ControlClientError(fmt::format("{}: {}", path_.string(), why));
}

bool ControlClient::send_line(const nlohmann::json& request) {
  std::string line = request.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  line += '\n';
  std::size_t sent = 0;
  while (sent < line.size()) {
    const ssize_t n = ::send(fd_.get(), line.data() + sent, line.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EPIPE || errno == ECONNRESET) return false;
      fail(fmt::format("cannot send: {}", errno_text(errno)));
    }
    sent += static_cast<std::size_t>(n);
  }
  return true;
}

std::optional<nlohmann::json> ControlClient::refusal_before_close() {
  // markerd writes its last line before it closes: it is here already, or
  // the end is.
  const auto deadline = Clock::now() + std::chrono::seconds(2);
  for (;;) {
    std::optional<std::string> line;
    try {
      line = read_line(std::max(std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now()),
                                std::chrono::milliseconds(0)));
    } catch (const ControlClientError&) {
      return std::nullopt;  // the end, with no refusal before it
    }
    if (!line) return std::nullopt;
    nlohmann::json reply = nlohmann::json::parse(*line, nullptr, false);
    if (reply.is_object() && reply.contains("ok") && reply["ok"] == false && reply.contains("error")) return reply;
  }
}

void ControlClient::send(const nlohmann::json& request) {
  if (send_line(request)) return;
  const auto refusal = refusal_before_close();
  if (refusal && (*refusal)["error"].is_string()) {
    fail(fmt::format("markerd closed the connection: {}", (*refusal)["error"].get<std::string>()));
  }
  fail("markerd closed the connection");
}

std::optional<std::string> ControlClient::read_line(std::optional<std::chrono::milliseconds> timeout) {
  const auto deadline = timeout ? std::optional(Clock::now() + *timeout) : std::nullopt;
  for (;;) {
    if (const auto newline = buffer_.find('\n'); newline != std::string::npos) {
      std::string line = buffer_.substr(0, newline);
      buffer_.erase(0, newline + 1);
      return line;
    }
    int wait_ms = -1;
    if (deadline) {
      const auto left = std::chrono::ceil<std::chrono::milliseconds>(*deadline - Clock::now()).count();
      if (left <= 0) return std::nullopt;
      wait_ms = static_cast<int>(std::min<std::int64_t>(left, 60000));
    }
    pollfd pfd{fd_.get(), POLLIN, 0};
    const int ready = ::poll(&pfd, 1, wait_ms);
    if (ready < 0) {
      if (errno == EINTR) continue;
      fail(fmt::format("poll: {}", errno_text(errno)));
    }
    if (ready == 0) continue;  // the deadline is checked above
    char chunk[65536];
    const ssize_t n = ::recv(fd_.get(), chunk, sizeof chunk, 0);
    if (n < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      fail(errno == ECONNRESET ? std::string("markerd closed the connection")
                               : fmt::format("cannot read: {}", errno_text(errno)));
    }
    if (n == 0) fail("markerd closed the connection");
    buffer_.append(chunk, static_cast<std::size_t>(n));
  }
}

nlohmann::json ControlClient::call(nlohmann::json request, std::chrono::milliseconds timeout, std::string* raw_line) {
  if (!request.is_object()) fail("a request must be a JSON object");
  if (!request.contains("id")) request["id"] = next_id_++;
  const nlohmann::json id = request["id"];
  if (!send_line(request)) {
    // Closed before it took the whole request (one too large, say): its
    // reason is the reply.
    if (auto refusal = refusal_before_close()) {
      if (raw_line != nullptr) *raw_line = refusal->dump();
      return std::move(*refusal);
    }
    fail("markerd closed the connection");
  }
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now());
    const auto line = read_line(std::max(left, std::chrono::milliseconds(0)));
    if (!line) {
      fail(fmt::format("no reply to {} within {} s", request.value("cmd", std::string("the request")),
                       std::chrono::duration<double>(timeout).count()));
    }
    nlohmann::json reply;
    try {
      reply = nlohmann::json::parse(*line);
    } catch (const nlohmann::json::exception&) {
      fail(fmt::format("the reply is not JSON: {}", line->substr(0, 200)));
    }
    if (!reply.is_object()) fail(fmt::format("the reply is not a JSON object: {}", line->substr(0, 200)));
    // A refusal of the connection itself (too many clients, a request too
    // large, an idle connection closed) carries no id; anything else is a stream's line or a reply to
    // an earlier request, and not this one's.
    if ((reply.contains("id") && reply["id"] == id) ||
        (!reply.contains("id") && reply.contains("ok") && reply["ok"] == false)) {
      if (raw_line != nullptr) *raw_line = *line;
      return reply;
    }
  }
}

}  // namespace markerd::daemon
