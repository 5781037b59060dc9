#pragma once
// The client side of markerd's control socket (docs/control.md): connect,
// send a request line, read reply lines, or follow a stream. markerctl and
// the tests speak to the daemon through it. Errors name the socket and say
// what to do ("cannot connect to /run/markerd/control.sock: No such file or
// directory (is markerd running?)").

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>

#include "markerd/base/unique_fd.hpp"

namespace markerd::daemon {

inline constexpr const char* kDefaultControlSocket = "/run/markerd/control.sock";

class ControlClientError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ControlClient {
 public:
  // Connects. ControlClientError naming the path and, where it helps, the
  // likely cause (markerd not running; the group that grants access).
  explicit ControlClient(std::filesystem::path socket_path);
  ~ControlClient() = default;
  ControlClient(const ControlClient&) = delete;
  ControlClient& operator=(const ControlClient&) = delete;

  [[nodiscard]] const std::filesystem::path& socket_path() const { return path_; }

  // Sends one request (an object) as one line. ControlClientError when
  // markerd closes the connection first, with the reason it gave.
  void send(const nlohmann::json& request);

  // The next line the server sent, without its '\n'; nothing when `timeout`
  // passes first (no timeout: wait as long as it takes). ControlClientError
  // when the connection ends or fails.
  [[nodiscard]] std::optional<std::string> read_line(std::optional<std::chrono::milliseconds> timeout);

  // Sends `request` with an "id" of its own (unless it has one) and returns
  // the reply that carries it, as an object. ControlClientError when no
  // reply comes within `timeout`, or the reply is not JSON. An "ok": false
  // reply is returned like any other, and so is markerd's refusal of the
  // connection (a request too large, too many clients), even when it closed
  // the connection before the request was sent whole. `raw_line`, when
  // given, receives the reply's line as it came.
  [[nodiscard]] nlohmann::json call(nlohmann::json request,
                                    std::chrono::milliseconds timeout = std::chrono::seconds(10),
                                    std::string* raw_line = nullptr);

 private:
  [[noreturn]] void fail(const std::string& why) const;
  // False when markerd closed the connection before it took the line.
  [[nodiscard]] bool send_line(const nlohmann::json& request);
  // The {"ok": false, "error": ...} line markerd sent before it closed the
  // connection, if it sent one.
  [[nodiscard]] std::optional<nlohmann::json> refusal_before_close();

  std::filesystem::path path_;
  UniqueFd fd_;
  std::string buffer_;  // received, not yet returned
  std::int64_t next_id_ = 1;
};

}  // namespace markerd::daemon
