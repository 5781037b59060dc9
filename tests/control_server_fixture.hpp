#pragma once
// What the control server's tests share: a client that speaks raw bytes, the
// commands a daemon registers of every kind, and a fixture that runs a server
// on a socket in a temporary directory.

#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/control/line_broadcast.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace markerd::daemon::control_test {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
using markerd::test_support::TempDir;

// A client that speaks bytes, not JSON, so that tests can send what a
// well-behaved client never would.
class RawClient {
 public:
  explicit RawClient(const fs::path& path) {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, path.c_str(), sizeof address.sun_path - 1);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
      const int error = errno;
      ::close(fd_);
      throw std::runtime_error(std::string("connect: ") + std::strerror(error));
    }
  }
  ~RawClient() { close(); }
  RawClient(const RawClient&) = delete;
  RawClient& operator=(const RawClient&) = delete;

  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  void send(std::string_view bytes) const {
    while (!bytes.empty()) {
      const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
      if (n < 0) {
        if (errno == EINTR) continue;
        throw std::runtime_error(std::string("send: ") + std::strerror(errno));
      }
      bytes.remove_prefix(static_cast<std::size_t>(n));
    }
  }
  void request(const json& r) const { send(r.dump() + "\n"); }

  // The next line; nothing at the end of the connection or after `timeout`.
  std::optional<std::string> line(std::chrono::milliseconds timeout = 10s) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (const auto nl = buffer_.find('\n'); nl != std::string::npos) {
        std::string text = buffer_.substr(0, nl);
        buffer_.erase(0, nl + 1);
        return text;
      }
      if (ended_) return std::nullopt;
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
      if (left <= 0) return std::nullopt;
      pollfd pfd{fd_, POLLIN, 0};
      if (::poll(&pfd, 1, static_cast<int>(left)) <= 0) continue;
      char chunk[65536];
      const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
      if (n <= 0) {
        if (n < 0 && errno == EINTR) continue;
        // The end: EOF, or ECONNRESET from a server that closed with bytes unread.
        ended_ = true;
        continue;
      }
      buffer_.append(chunk, static_cast<std::size_t>(n));
    }
  }

  json reply(std::chrono::milliseconds timeout = 10s) {
    const auto text = line(timeout);
    if (!text) {
      ADD_FAILURE() << "no reply line" << (ended_ ? " (the connection ended)" : " (timed out)");
      return json();
    }
    try {
      return json::parse(*text);
    } catch (const json::exception& e) {
      ADD_FAILURE() << "a reply that is not JSON: " << *text;
      return json();
    }
  }

  // True when the server closes the connection within `timeout` (with
  // nothing more to read).
  bool ends(std::chrono::milliseconds timeout = 10s) {
    const auto text = line(timeout);
    if (text) ADD_FAILURE() << "unexpected line before the end: " << *text;
    return ended_;
  }

  [[nodiscard]] int fd() const { return fd_; }

 private:
  int fd_ = -1;
  std::string buffer_;
  bool ended_ = false;
};

// Handlers of every kind a daemon registers.
inline void register_test_commands(ControlServer& server) {
  server.register_command(
      "echo",
      [](const json& request) {
        return json{{"echo", request}};
      },
      "returns the request");
  server.register_command(
      "add",
      [](const json& request) {
        expect_arguments(request, {"a", "b"});
        const auto a = number_argument(request, "a");
        const auto b = number_argument(request, "b");
        if (!a || !b) throw ControlError("add needs a and b");
        return json{{"sum", *a + *b}};
      },
      "a + b");
  server.register_command("fail", [](const json&) -> json { throw std::runtime_error("the handler failed"); });
  server.register_command("refuse", [](const json&) -> json { throw ControlError("refused: not today"); });
  server.register_command("scalar", [](const json&) { return json(42); });
  server.register_command("nothing", [](const json&) { return json(); });
}

// The error a request longer than the fixture's max_request_bytes gets.
inline constexpr const char* kTooLarge =
    "request too large: longer than markerd's limit of 4 KiB (4096 bytes); closing the connection";

class ControlServerTest : public testing::Test {
 protected:
  void SetUp() override {
    settings_.socket_path = dir_.path() / "control.sock";
    settings_.max_request_bytes = 4096;
  }

  ControlServer& start(std::vector<LineBroadcast*> streams = {}) {
    server_ = std::make_unique<ControlServer>(settings_);
    register_test_commands(*server_);
    for (LineBroadcast* stream : streams) server_->register_stream(*stream, "a test stream");
    server_->start();
    return *server_;
  }

  [[nodiscard]] fs::path socket() const { return settings_.socket_path; }

  // A broadcast that outlives the server, as it must.
  LineBroadcast& make_stream(std::size_t capacity = LineBroadcast::kDefaultCapacityBytes) {
    return *streams_.emplace_back(std::make_unique<LineBroadcast>("detections", capacity));
  }

  // Waits until `ready` holds (the server's thread acts on its own time).
  template <class Ready>
  static bool eventually(Ready ready, std::chrono::milliseconds timeout = 10s) {
    const auto deadline = Clock::now() + timeout;
    while (!ready()) {
      if (Clock::now() > deadline) return false;
      std::this_thread::sleep_for(1ms);
    }
    return true;
  }

  TempDir dir_;
  ControlSettings settings_;
  std::vector<std::unique_ptr<LineBroadcast>> streams_;  // before server_: destroyed after it
  std::unique_ptr<ControlServer> server_;
};

}  // namespace markerd::daemon::control_test
