#pragma once
// markerd's control socket: a Unix stream socket (/run/markerd/control.sock,
// mode 0660, a group of the config's choosing) that speaks one line of JSON
// per request and one per reply, and can switch a connection to following a
// stream of lines (the detection log). The protocol: docs/control.md.
//
// One thread serves every client with poll() and non-blocking I/O. Command
// handlers run on that thread, one request at a time: they must return
// promptly (start a motion and return; a status command reports its
// progress). A client that does not read what it is sent never holds the
// server up: its requests wait until it has read its replies, and a stream
// skips the lines it has no room for and tells it how many. A connection
// that neither sends a request nor reads a reply for the idle timeout is
// closed (a follower never is), and a few connections beyond the client
// limit are still taken for the commands that stop the rig, so that no set
// of clients, idle or busy, can keep an emergency stop out.

#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <initializer_list>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/control/command_arguments.hpp"
#include "markerd/daemon/control/line_broadcast.hpp"

namespace markerd::daemon {

// The daemon's [control] table (daemon_config.hpp's ControlConfig) gives
// the path, the group, the client limit and the idle timeout; the rest are
// the defaults here.
struct ControlSettings {
  // Its directory must exist (systemd's RuntimeDirectory=); it is never created here.
  std::filesystem::path socket_path = "/run/markerd/control.sock";
  // The socket file's group, which grants access to it; empty keeps the
  // process's own group. The process must be a member (or root).
  std::string group;
  // The socket file's permissions: never any for other users, since the
  // socket moves the rig.
  mode_t mode = 0660;
  // A request line (without its '\n') longer than this is answered with an
  // error naming the limit, and the connection closed. markerctl's largest
  // request, a 128 KiB plan JSON-escaped, fits.
  std::size_t max_request_bytes = 1024 * 1024;
  // Connections beyond this are served only the commands marked with
  // serve_beyond_client_limit(), and refused anything else.
  std::size_t max_clients = 16;
  // A connection that neither sends a request nor reads a reply for this
  // long is told so and closed; one following a stream never is.
  std::chrono::milliseconds idle_timeout{60'000};
  // Bytes waiting to be sent to one client: past this its further requests
  // wait until it reads, and stream lines are skipped (and counted).
  std::size_t max_output_bytes = 1024 * 1024;
};

// The socket cannot be set up (its directory is missing, another markerd
// listens on it, the group does not exist, ...): what() names the socket
// path and the cause.
class ControlSocketError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// What would keep start() from setting up the socket, found without making
// anything, in words that leave the socket's path to the caller (markerd
// --check-config names the config key): the path too long, its directory
// missing or closed to this process, a file there that is not a socket; a
// group that does not exist or that this process is not a member of.
[[nodiscard]] std::optional<std::string> find_socket_path_problem(const ControlSettings& settings);
[[nodiscard]] std::optional<std::string> find_socket_group_problem(const ControlSettings& settings);

// Takes the whole request object (its "cmd", "id" and arguments) and
// returns the result: an object's members are added to the reply beside
// "id" and "ok"; null adds nothing; any other value becomes "result".
using CommandHandler = std::function<nlohmann::json(const nlohmann::json& request)>;

struct ControlServerStats {
  std::uint64_t connections = 0;     // accepted, in all
  std::uint64_t clients = 0;         // connected now
  std::uint64_t refused = 0;         // connections turned away: too many clients
  std::uint64_t beyond_limit = 0;    // connections taken beyond max_clients, for stop commands
  std::uint64_t idle_closed = 0;     // connections closed for the idle timeout
  std::uint64_t requests = 0;        // request lines answered
  std::uint64_t errors = 0;          // of them, answered with "ok": false
  std::uint64_t oversized = 0;       // connections closed for a request line too long
  std::uint64_t stream_lines = 0;    // stream lines queued to followers
  std::uint64_t stream_dropped = 0;  // stream lines a follower missed (its own backlog, or the stream's)
};

class ControlServer {
 public:
  explicit ControlServer(ControlSettings settings);
  ~ControlServer();  // stop()
  ControlServer(const ControlServer&) = delete;
  ControlServer& operator=(const ControlServer&) = delete;

  // Before start() only (std::logic_error after it, or for a name taken).
  // `help` is the command's line in the built-in "help".
  void register_command(std::string name, CommandHandler handler, std::string help = {});
  // A command, the broadcast's name, that switches the connection to
  // following the broadcast's lines. The broadcast must outlive the server;
  // the server is its one consumer.
  void register_stream(LineBroadcast& broadcast, std::string help = {});
  // The command (registered already) is served to connections beyond
  // max_clients too: one that stops the rig, or says where it stands, must
  // get through whoever holds the other connections. Before start() only.
  void serve_beyond_client_limit(std::string_view command);

  // Sets up the socket (ControlSocketError on failure, nothing left behind)
  // and starts serving. Once only.
  void start();
  // Closes every connection and removes the socket file (when it is still
  // the one this server made). Returns promptly whatever the clients do.
  // Idempotent.
  void stop() noexcept;

  [[nodiscard]] const ControlSettings& settings() const noexcept { return settings_; }
  [[nodiscard]] bool running() const noexcept { return thread_.joinable(); }
  // Any thread.
  [[nodiscard]] ControlServerStats stats() const noexcept;

 private:
  using Clock = std::chrono::steady_clock;
  struct Client;
  struct Command {
    CommandHandler handler;
    LineBroadcast* stream = nullptr;
    std::string help;
    bool beyond_client_limit = false;
  };

  void set_up_socket();
  void run(const std::stop_token& stop);
  void accept_clients();
  void read_from(Client& client);
  void serve_buffered(Client& client);
  [[nodiscard]] bool can_serve(const Client& client) const;
  void write_to(Client& client);
  void handle_line(Client& client, std::string_view line);
  [[nodiscard]] nlohmann::ordered_json answer(Client& client, std::string_view line);
  [[nodiscard]] nlohmann::json help() const;
  [[nodiscard]] std::string beyond_limit_commands() const;
  [[nodiscard]] std::string too_many_clients() const;
  [[nodiscard]] bool make_room_beyond_limit();
  [[nodiscard]] std::size_t regular_clients() const;
  [[nodiscard]] std::optional<Clock::time_point> idle_deadline(const Client& client) const;
  void close_idle(Client& client, Clock::time_point now);
  void close_after(Client& client, const nlohmann::ordered_json& reply);
  void queue_reply(Client& client, const nlohmann::ordered_json& reply);
  void queue_notice(Client& client);
  void drain_stream(LineBroadcast& broadcast);
  void follow(Client& client, LineBroadcast& broadcast);
  void unfollow(Client& client);
  void close_client(Client& client);

  ControlSettings settings_;
  std::map<std::string, Command, std::less<>> commands_;
  std::vector<LineBroadcast*> streams_;

  UniqueFd listen_fd_;
  UniqueFd stop_fd_;  // an eventfd that ends poll() for stop()
  dev_t socket_dev_ = 0;
  ino_t socket_ino_ = 0;
  // The server thread's own.
  std::vector<std::unique_ptr<Client>> clients_;
  std::vector<Client*> followers_;  // drain_stream()'s scratch list
  std::uint64_t next_client_id_ = 1;
  bool accept_failed_ = false;  // accept() ran out of descriptors or memory

  struct Counters {
    std::atomic<std::uint64_t> connections{0};
    std::atomic<std::uint64_t> clients{0};
    std::atomic<std::uint64_t> refused{0};
    std::atomic<std::uint64_t> beyond_limit{0};
    std::atomic<std::uint64_t> idle_closed{0};
    std::atomic<std::uint64_t> requests{0};
    std::atomic<std::uint64_t> errors{0};
    std::atomic<std::uint64_t> oversized{0};
    std::atomic<std::uint64_t> stream_lines{0};
    std::atomic<std::uint64_t> stream_dropped{0};
  } counters_;

  std::jthread thread_;
};

}  // namespace markerd::daemon
