// The control protocol (control_server.cpp): whatever a client sends, as
// lines on a real socket to a real ControlServer in this process, with the
// rig's commands on the shipped simulated rig (config/rig-sim.toml, in
// scaled time), a stream to follow, and a command that takes one argument
// of each kind through the argument helpers every handler uses.
//
// Each input is sent on one connection (kept while the server keeps it),
// its last line ended, then a line asking for a reply with a fresh id; the
// replies are read up to that one. The request limit is lowered to 512
// bytes so that the refusal of a request too long (and the connection's
// close) is within reach of small inputs. A finding is a crash, a hang (no
// reply within 10 s), a reply line that is not a JSON object, a reply
// without "ok" (only stream lines may lack it), or an error that passes on
// nlohmann's raw message instead of saying what was wrong.

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <memory>
#include <string>
#include <thread>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "fuzz_support.hpp"
#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/control/line_broadcast.hpp"
#include "markerd/daemon/control/rig_commands.hpp"
#include "markerd/rig/rig_config.hpp"

namespace {

using nlohmann::json;
using namespace std::chrono_literals;
using markerd::fuzz::finding;

constexpr std::size_t kMaxRequestBytes = 512;
constexpr int kReplyTimeoutMs = 10000;

markerd::daemon::ControlSettings settings() {
  markerd::daemon::ControlSettings s;
  s.socket_path = markerd::fuzz::scratch_dir() / "control.sock";
  s.max_request_bytes = kMaxRequestBytes;
  return s;
}

std::unique_ptr<markerd::rig::Rig> make_sim_rig() {
  markerd::rig::RigConfig config = markerd::rig::load_rig_config(markerd::fuzz::config_dir() / "rig-sim.toml");
  // Homing and moves finish within a second or two of real time.
  config.sim.time_scale = 100;
  return markerd::rig::make_rig(config);
}

json arguments(const json& request) {
  markerd::daemon::expect_arguments(request, {"text", "number", "flag"});
  json out = json::object();
  if (const auto text = markerd::daemon::string_argument(request, "text")) out["text"] = *text;
  if (const auto number = markerd::daemon::number_argument(request, "number")) out["number"] = *number;
  if (const auto flag = markerd::daemon::bool_argument(request, "flag")) out["flag"] = *flag;
  return out;
}

class Harness {
 public:
  Harness() : rig_(make_sim_rig()), stream_("fuzz.stream", 4096), server_(settings()) {
    server_.register_command("fuzz.arguments", arguments, "text: a string, number: a number, flag: a boolean");
    server_.register_command(
        "fuzz.sync", [](const json&) { return json(); }, "replies, with nothing");
    server_.register_stream(stream_, "a line per input while followed");
    markerd::daemon::register_rig_commands(server_, *rig_);
    server_.start();
  }
  ~Harness() { close_connection(); }
  Harness(const Harness&) = delete;
  Harness& operator=(const Harness&) = delete;

  void run(std::string_view input) {
    if (fd_ < 0) connect();
    stream_.publish(R"({"fuzz":"a stream line"})");
    const std::string id = fmt::format("fuzz-sync-{}", ++sync_);
    std::string bytes(input);
    bytes += '\n';
    bytes += fmt::format(R"({{"cmd":"fuzz.sync","id":"{}"}})", id);
    bytes += '\n';
    if (!send_all(bytes)) {
      close_connection();  // the server closed it (a request too long): the next input connects again
      return;
    }
    read_replies(id);
  }

 private:
  void connect() {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    const std::string path = settings().socket_path.string();
    std::memcpy(address.sun_path, path.c_str(), path.size() + 1);
    if (fd_ < 0 || ::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
      finding(fmt::format("cannot connect to {}: {}", path, std::strerror(errno)));
    }
  }

  void close_connection() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    pending_.clear();
  }

  bool send_all(std::string_view bytes) {
    while (!bytes.empty()) {
      const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return false;
      bytes.remove_prefix(static_cast<std::size_t>(n));
    }
    return true;
  }

  // Reads reply lines until the one with `id`, or the end of the connection.
  void read_replies(const std::string& id) {
    for (;;) {
      for (std::size_t newline; (newline = pending_.find('\n')) != std::string::npos;) {
        const std::string line = pending_.substr(0, newline);
        pending_.erase(0, newline + 1);
        if (check_line(line, id)) return;
      }
      pollfd p{fd_, POLLIN, 0};
      const int ready = ::poll(&p, 1, kReplyTimeoutMs);
      if (ready == 0) finding(fmt::format("no reply to the request with id {} within {} ms", id, kReplyTimeoutMs));
      char chunk[65536];
      const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        // The server closed the connection: only after a request too long.
        close_connection();
        return;
      }
      pending_.append(chunk, static_cast<std::size_t>(n));
    }
  }

  // True for the reply with `id`.
  static bool check_line(const std::string& line, const std::string& id) {
    json reply;
    try {
      reply = json::parse(line);
    } catch (const json::exception& e) {
      finding(fmt::format("a reply line that is not JSON ({}): {}", e.what(), line));
    }
    if (!reply.is_object()) finding("a reply line that is not an object: " + line);
    const auto event = reply.find("event");
    const bool stream_line = reply.contains("fuzz") || (event != reply.end() && *event == "dropped");
    if (!stream_line && !reply.contains("ok")) finding("a reply without \"ok\": " + line);
    if (const auto error = reply.find("error"); error != reply.end()) {
      if (!error->is_string()) finding("an error that is not a string: " + line);
      // nlohmann's messages start with their id; further on, an error may
      // quote the request (a parse error's "last read: ..."), which may hold anything.
      if (error->get<std::string>().substr(0, 40).find("[json.exception.") != std::string::npos) {
        finding("an error passes on nlohmann's own message: " + line);
      }
    }
    const auto reply_id = reply.find("id");
    return reply_id != reply.end() && reply_id->is_string() && reply_id->get<std::string>() == id;
  }

  std::unique_ptr<markerd::rig::Rig> rig_;
  markerd::daemon::LineBroadcast stream_;
  markerd::daemon::ControlServer server_;  // after what its commands use: stopped before they go
  int fd_ = -1;
  std::string pending_;
  std::uint64_t sync_ = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static Harness harness;
  harness.run(markerd::fuzz::as_text(data, size));
  return 0;
}
