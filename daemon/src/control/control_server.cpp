#include "markerd/daemon/control/control_server.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "control_socket.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/base/read_file.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <utility>

namespace markerd::daemon {

using nlohmann::json;
using nlohmann::ordered_json;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

namespace {

// Requests nested deeper than this are refused while they are parsed: the
// reply echoes "id", and serializing a value 30000 arrays deep would recurse
// as deep. No command takes more than a few levels.
constexpr int kMaxRequestDepth = 32;
// Bytes read from a client per read(); the input buffer holds at most one
// partial line (max_request_bytes) and one such chunk.
constexpr std::size_t kReadChunk = 64 * 1024;
// How long a connection being closed (a request too long) may take to
// collect its error reply before it is closed anyway.
constexpr auto kCloseLinger = 2s;
// After accept() runs out of file descriptors, it is retried after this.
constexpr auto kAcceptPause = 100ms;
// Connections taken beyond max_clients at once, for the commands that stop
// the rig; each must send its request within kBeyondLimitIdle. A few, not
// one: a client that connects and sends nothing must not keep the next one,
// with an emergency stop, out; and bounded, since every connection is a file
// descriptor that markerd's camera and logs need too.
constexpr std::size_t kBeyondLimitClients = 4;
constexpr auto kBeyondLimitIdle = 5s;

// nlohmann's messages start with "[json.exception.parse_error.101] ": the
// client needs the rest.
std::string json_error_text(const json::exception& e) {
  std::string_view text = e.what();
  if (const auto end = text.find("] "); text.starts_with("[json.exception.") && end != std::string_view::npos) {
    text.remove_prefix(end + 2);
  }
  return std::string(text);
}

// Where a request stops being JSON, and the token there: parsing again with
// a SAX reader that keeps nothing, since nlohmann's out_of_range (a number
// beyond a double's range) carries neither.
struct FirstJsonError final {
  std::size_t position = 0;  // bytes read, the token included
  std::string token;
  bool null() { return true; }
  bool boolean(bool /*value*/) { return true; }
  bool number_integer(json::number_integer_t /*value*/) { return true; }
  bool number_unsigned(json::number_unsigned_t /*value*/) { return true; }
  bool number_float(json::number_float_t /*value*/, const std::string& /*text*/) { return true; }
  bool string(std::string& /*value*/) { return true; }
  bool binary(json::binary_t& /*value*/) { return true; }
  bool start_object(std::size_t /*size*/) { return true; }
  bool key(std::string& /*value*/) { return true; }
  bool end_object() { return true; }
  bool start_array(std::size_t /*size*/) { return true; }
  bool end_array() { return true; }
  bool parse_error(std::size_t at, const std::string& last_token, const nlohmann::detail::exception& /*error*/) {
    position = at;
    token = last_token;
    return false;
  }
};

// A request that nlohmann refuses other than for its syntax (a number out of
// range), in markerd's words: which token, and where it starts (1-based, as
// the syntax errors' columns).
std::string malformed_json_text(std::string_view line, const json::exception& e) {
  FirstJsonError located;
  if (json::sax_parse(line, &located) || located.token.empty() || located.position < located.token.size()) {
    return fmt::format("malformed JSON: {}", json_error_text(e));
  }
  const std::size_t byte = located.position - located.token.size() + 1;
  if (e.id == 406) {
    return fmt::format("malformed JSON: number {} is out of range (beyond a double's) at byte {}", located.token, byte);
  }
  return fmt::format("malformed JSON: {} at byte {}", json_error_text(e), byte);
}

bool blank(std::string_view line) {
  return std::all_of(line.begin(), line.end(), [](char c) { return c == ' ' || c == '\t' || c == '\r'; });
}

std::string dump_line(const ordered_json& value) {
  std::string text = value.dump(-1, ' ', false, json::error_handler_t::replace);
  text += '\n';
  return text;
}

}  // namespace

// ---------------------------------------------------------------- the server

struct ControlServer::Client {
  UniqueFd fd;
  std::uint64_t id = 0;
  std::string input;              // received, not yet answered; starts at a line's start
  std::size_t input_scanned = 0;  // bytes of `input` known to hold no '\n'
  std::string output;             // to send, from output_sent on
  std::size_t output_sent = 0;
  LineBroadcast* following = nullptr;
  std::uint64_t missed = 0;  // stream lines lost to this client, not yet announced
  bool peer_closed = false;  // read() saw the end
  bool closing = false;      // no more requests: send what is queued, then close
  bool dead = false;         // close now
  Clock::time_point close_deadline{};
  // Accepted, a request received or reply bytes taken: the idle timeout
  // runs from here. Bytes of a request not yet complete do not count, so a
  // client trickling a line cannot hold its connection for ever.
  Clock::time_point last_activity{};
  bool beyond_limit = false;  // taken past max_clients: stop commands only
  bool served = false;        // a request of it has been answered

  [[nodiscard]] std::size_t pending() const { return output.size() - output_sent; }
  [[nodiscard]] bool request_waiting() const { return input.find('\n', input_scanned) != std::string::npos; }
};

bool ControlServer::can_serve(const Client& client) const {
  return !client.closing && !client.dead && client.request_waiting() &&
         (client.following != nullptr || client.pending() < settings_.max_output_bytes);
}

ControlServer::ControlServer(ControlSettings settings) : settings_(std::move(settings)) {
  register_command(
      "help",
      [this](const json& request) {
        expect_arguments(request, {});
        return help();
      },
      "the commands this server knows, each with a line of help");
}

ControlServer::~ControlServer() { stop(); }

void ControlServer::register_command(std::string name, CommandHandler handler, std::string help) {
  if (running()) throw std::logic_error("ControlServer: register commands before start()");
  if (name.empty() || !handler) throw std::logic_error("ControlServer: a command needs a name and a handler");
  if (commands_.contains(name)) throw std::logic_error("ControlServer: command '" + name + "' is registered twice");
  commands_.emplace(std::move(name), Command{std::move(handler), nullptr, std::move(help)});
}

void ControlServer::register_stream(LineBroadcast& broadcast, std::string help) {
  if (running()) throw std::logic_error("ControlServer: register streams before start()");
  if (commands_.contains(broadcast.name())) {
    throw std::logic_error("ControlServer: command '" + broadcast.name() + "' is registered twice");
  }
  commands_.emplace(broadcast.name(), Command{{}, &broadcast, std::move(help)});
  streams_.push_back(&broadcast);
}

void ControlServer::serve_beyond_client_limit(std::string_view command) {
  if (running()) throw std::logic_error("ControlServer: mark commands before start()");
  const auto found = commands_.find(command);
  if (found == commands_.end() || found->second.stream != nullptr) {
    throw std::logic_error(fmt::format("ControlServer: '{}' is not a registered command", command));
  }
  found->second.beyond_client_limit = true;
}

json ControlServer::help() const {
  json list = json::array();
  for (const auto& [name, command] : commands_) {
    json entry = {{"name", name}, {"help", command.help}};
    if (command.stream != nullptr) entry["stream"] = true;
    if (command.beyond_client_limit) entry["beyond_client_limit"] = true;
    list.push_back(std::move(entry));
  }
  return {{"commands", std::move(list)}};
}

std::string ControlServer::beyond_limit_commands() const {
  std::string list;
  for (const auto& [name, command] : commands_) {
    if (command.beyond_client_limit) list += fmt::format("{}{}", list.empty() ? "" : ", ", name);
  }
  return list;
}

std::size_t ControlServer::regular_clients() const {
  return static_cast<std::size_t>(
      std::count_if(clients_.begin(), clients_.end(), [](const auto& c) { return !c->beyond_limit; }));
}

void ControlServer::start() {
  if (running() || listen_fd_) throw std::logic_error("ControlServer: started twice");
  set_up_socket();
  thread_ = std::jthread([this](const std::stop_token& stop) { run(stop); });
}

void ControlServer::set_up_socket() {
  ListeningSocket socket = listen_on_control_socket(settings_);
  stop_fd_.reset(::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC));
  if (!stop_fd_) {
    const int error = errno;
    socket.fd.reset();
    ::unlink(settings_.socket_path.c_str());
    throw ControlSocketError(
        fmt::format("control socket {}: eventfd: {}", settings_.socket_path.string(), errno_text(error)));
  }
  socket_dev_ = socket.dev;
  socket_ino_ = socket.ino;
  listen_fd_ = std::move(socket.fd);
  spdlog::info("control socket {}: listening (mode 0{:o}{})", settings_.socket_path.string(),
               static_cast<unsigned>(settings_.mode),
               settings_.group.empty() ? std::string() : ", group " + settings_.group);
}

void ControlServer::stop() noexcept {
  if (thread_.joinable()) {
    thread_.request_stop();
    const std::uint64_t one = 1;
    [[maybe_unused]] const ssize_t n = ::write(stop_fd_.get(), &one, sizeof one);
    thread_.join();
  }
  clients_.clear();
  counters_.clients.store(0, std::memory_order_relaxed);
  for (LineBroadcast* stream : streams_) stream->set_listening(false);
  if (listen_fd_) {
    listen_fd_.reset();
    // Only our own socket: after a restart race another markerd may have
    // replaced it, and its socket is not ours to remove.
    struct stat st {};
    const auto& path = settings_.socket_path;
    if (::lstat(path.c_str(), &st) == 0 && st.st_dev == socket_dev_ && st.st_ino == socket_ino_) {
      ::unlink(path.c_str());
    }
  }
  stop_fd_.reset();
}

ControlServerStats ControlServer::stats() const noexcept {
  ControlServerStats s;
  s.connections = counters_.connections.load(std::memory_order_relaxed);
  s.clients = counters_.clients.load(std::memory_order_relaxed);
  s.refused = counters_.refused.load(std::memory_order_relaxed);
  s.beyond_limit = counters_.beyond_limit.load(std::memory_order_relaxed);
  s.idle_closed = counters_.idle_closed.load(std::memory_order_relaxed);
  s.requests = counters_.requests.load(std::memory_order_relaxed);
  s.errors = counters_.errors.load(std::memory_order_relaxed);
  s.oversized = counters_.oversized.load(std::memory_order_relaxed);
  s.stream_lines = counters_.stream_lines.load(std::memory_order_relaxed);
  s.stream_dropped = counters_.stream_dropped.load(std::memory_order_relaxed);
  return s;
}

// ---------------------------------------------------------------- the loop

void ControlServer::run(const std::stop_token& stop) {
  std::vector<pollfd> fds;
  std::optional<Clock::time_point> accept_paused_until;
  while (!stop.stop_requested()) {
    const auto now = Clock::now();
    if (accept_paused_until && now >= *accept_paused_until) accept_paused_until.reset();
    std::optional<Clock::time_point> wake_at = accept_paused_until;

    fds.clear();
    fds.push_back({stop_fd_.get(), POLLIN, 0});
    fds.push_back({accept_paused_until ? -1 : listen_fd_.get(), POLLIN, 0});
    for (const LineBroadcast* stream : streams_) fds.push_back({stream->wake_fd(), POLLIN, 0});
    const std::size_t first_client = fds.size();
    bool serve_now = false;
    for (const auto& client : clients_) {
      // Requests that waited for the client to read its replies, and may
      // go on now that it has: no poll() event would announce them.
      serve_now = serve_now || can_serve(*client);
      short events = 0;
      // Input is read while no whole request waits in it (requests wait
      // while the client's replies pile up), so it stays bounded.
      if (!client->closing && !client->peer_closed && !client->request_waiting()) events |= POLLIN;
      if (client->pending() > 0) events |= POLLOUT;
      fds.push_back({client->fd.get(), events, 0});
      std::optional<Clock::time_point> deadline =
          client->closing ? std::optional(client->close_deadline) : idle_deadline(*client);
      if (deadline && (!wake_at || *deadline < *wake_at)) wake_at = deadline;
    }
    int timeout = -1;
    if (serve_now) {
      timeout = 0;
    } else if (wake_at) {
      const auto ms = std::chrono::ceil<std::chrono::milliseconds>(*wake_at - now).count();
      timeout = static_cast<int>(std::clamp<std::int64_t>(ms, 0, 60000));
    }

    if (::poll(fds.data(), fds.size(), timeout) < 0) {
      if (errno == EINTR) continue;
      spdlog::error("control socket {}: poll: {}", settings_.socket_path.string(), errno_text(errno));
      std::this_thread::sleep_for(10ms);
      continue;
    }
    if (fds[0].revents != 0 || stop.stop_requested()) break;

    for (std::size_t i = 0; i < streams_.size(); ++i) {
      if (fds[2 + i].revents != 0) drain_stream(*streams_[i]);
    }
    // Clients accepted below are not in `fds` yet: only the first ones here.
    const std::size_t polled = fds.size() - first_client;
    for (std::size_t i = 0; i < polled; ++i) {
      Client& client = *clients_[i];
      const short revents = fds[first_client + i].revents;
      if ((revents & (POLLERR | POLLNVAL)) != 0) {
        client.dead = true;
        continue;
      }
      if ((revents & (POLLIN | POLLHUP)) != 0) read_from(client);
      if ((revents & (POLLOUT | POLLHUP)) != 0) write_to(client);
    }
    for (auto& client : clients_) {
      serve_buffered(*client);
      if (client->pending() > 0) write_to(*client);
    }

    const auto after = Clock::now();
    for (auto& client : clients_) {
      const auto deadline = idle_deadline(*client);
      if (deadline && after >= *deadline) close_idle(*client, after);
    }
    std::erase_if(clients_, [&](const std::unique_ptr<Client>& c) {
      const bool done = c->dead || (c->closing && (c->pending() == 0 || after >= c->close_deadline)) ||
                        (c->peer_closed && c->pending() == 0 && !c->request_waiting());
      if (done) close_client(*c);
      return done;
    });
    counters_.clients.store(clients_.size(), std::memory_order_relaxed);

    if (fds[1].fd >= 0 && (fds[1].revents & POLLIN) != 0) {
      accept_clients();
      if (std::exchange(accept_failed_, false)) accept_paused_until = Clock::now() + kAcceptPause;
    }
  }
  for (auto& client : clients_) close_client(*client);
  clients_.clear();
  counters_.clients.store(0, std::memory_order_relaxed);
}

void ControlServer::accept_clients() {
  for (;;) {
    UniqueFd fd(::accept4(listen_fd_.get(), nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC));
    if (!fd) {
      const int error = errno;
      if (error == EAGAIN || error == EWOULDBLOCK) return;
      if (error == EINTR || error == ECONNABORTED) continue;
      // Out of descriptors or memory: the pending connection stays queued
      // and poll() would report it at once again; wait a little instead.
      spdlog::warn("control socket {}: accept: {}", settings_.socket_path.string(), errno_text(error));
      accept_failed_ = true;
      return;
    }
    counters_.connections.fetch_add(1, std::memory_order_relaxed);
    const std::uint64_t id = next_client_id_++;
    ucred peer{};
    socklen_t peer_size = sizeof peer;
    if (::getsockopt(fd.get(), SOL_SOCKET, SO_PEERCRED, &peer, &peer_size) != 0) peer = {};
    const bool beyond_limit = regular_clients() >= settings_.max_clients;
    // Without commands to serve beyond the limit, nothing is gained by taking the connection.
    if (beyond_limit && (beyond_limit_commands().empty() || !make_room_beyond_limit())) {
      counters_.refused.fetch_add(1, std::memory_order_relaxed);
      const std::string line = dump_line({{"ok", false}, {"error", too_many_clients()}});
      // A fresh socket's buffer takes the line; if not, it is lost with the connection.
      [[maybe_unused]] const ssize_t n = ::send(fd.get(), line.data(), line.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      spdlog::warn("control socket: refused a connection from pid {} (uid {}): {} clients connected", peer.pid,
                   peer.uid, clients_.size());
      continue;
    }
    auto client = std::make_unique<Client>();
    client->fd = std::move(fd);
    client->id = id;
    client->last_activity = Clock::now();
    client->beyond_limit = beyond_limit;
    if (beyond_limit) {
      counters_.beyond_limit.fetch_add(1, std::memory_order_relaxed);
      spdlog::info("control: client {} (pid {}, uid {}) connected beyond the limit of {}: served {} only", id, peer.pid,
                   peer.uid, settings_.max_clients, beyond_limit_commands());
    } else {
      spdlog::debug("control: client {} connected (pid {}, uid {})", id, peer.pid, peer.uid);
    }
    clients_.push_back(std::move(client));
  }
}

bool ControlServer::make_room_beyond_limit() {
  const auto taken = [this] {
    return std::count_if(clients_.begin(), clients_.end(),
                         [](const auto& c) { return c->beyond_limit && !c->closing && !c->dead; });
  };
  // The oldest that has sent nothing gives way, after a last look at what it
  // may have sent meanwhile (which is served, stop requests included).
  for (auto& client : clients_) {
    if (static_cast<std::size_t>(taken()) < kBeyondLimitClients) return true;
    if (!client->beyond_limit || client->closing || client->dead || client->served) continue;
    read_from(*client);
    serve_buffered(*client);
    if (client->served || client->closing || client->dead) continue;
    counters_.refused.fetch_add(1, std::memory_order_relaxed);
    close_after(*client, {{"ok", false}, {"error", too_many_clients()}});
  }
  return static_cast<std::size_t>(taken()) < kBeyondLimitClients;
}

std::string ControlServer::too_many_clients() const {
  const std::string commands = beyond_limit_commands();
  if (commands.empty()) return fmt::format("too many clients ({} connected); try again later", regular_clients());
  return fmt::format("too many clients ({} connected; beyond the limit only {} {} served); try again later",
                     regular_clients(), commands, commands.find(',') == std::string::npos ? "is" : "are");
}

std::optional<std::chrono::steady_clock::time_point> ControlServer::idle_deadline(const Client& client) const {
  if (client.following != nullptr || client.closing || client.dead) return std::nullopt;
  const auto timeout = client.beyond_limit
                           ? std::min<std::chrono::milliseconds>(kBeyondLimitIdle, settings_.idle_timeout)
                           : settings_.idle_timeout;
  return client.last_activity + timeout;
}

void ControlServer::close_idle(Client& client, Clock::time_point now) {
  if (client.beyond_limit && !client.served) {
    counters_.refused.fetch_add(1, std::memory_order_relaxed);
    close_after(client, {{"ok", false}, {"error", too_many_clients()}});
    return;
  }
  counters_.idle_closed.fetch_add(1, std::memory_order_relaxed);
  const double seconds = std::chrono::duration<double>(now - client.last_activity).count();
  spdlog::info("control: client {}: no request and no reply read for {:.0f} s; connection closed", client.id, seconds);
  close_after(client, {{"ok", false},
                       {"error", fmt::format("idle for {:g} s (no request, no reply read); closing the connection",
                                             std::chrono::duration<double>(settings_.idle_timeout).count())}});
}

void ControlServer::close_after(Client& client, const ordered_json& reply) {
  queue_reply(client, reply);
  client.closing = true;
  client.close_deadline = Clock::now() + kCloseLinger;
  write_to(client);
}

void ControlServer::read_from(Client& client) {
  if (client.closing || client.peer_closed) return;
  const std::size_t old_size = client.input.size();
  client.input.resize(old_size + kReadChunk);
  const ssize_t n = ::recv(client.fd.get(), client.input.data() + old_size, kReadChunk, MSG_DONTWAIT);
  client.input.resize(old_size + static_cast<std::size_t>(std::max<ssize_t>(n, 0)));
  if (n > 0) return;
  if (n < 0) {
    if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) return;
    spdlog::debug("control: client {}: read: {}", client.id, errno_text(errno));
    client.dead = true;
    return;
  }
  client.peer_closed = true;
  // What follows the last '\n' is a request cut off by the disconnect: dropped.
}

void ControlServer::serve_buffered(Client& client) {
  std::size_t start = 0;
  while (!client.closing && !client.dead) {
    const std::size_t from = std::max(start, client.input_scanned);
    const std::size_t newline = client.input.find('\n', from);
    const std::size_t line_end = newline == std::string::npos ? client.input.size() : newline;
    if (line_end - start > settings_.max_request_bytes) {
      // The rest of the line cannot be trusted to be what the client meant
      // (nor can where the next request starts): refuse, then close.
      counters_.oversized.fetch_add(1, std::memory_order_relaxed);
      counters_.requests.fetch_add(1, std::memory_order_relaxed);
      counters_.errors.fetch_add(1, std::memory_order_relaxed);
      spdlog::warn("control: client {}: a request longer than {} bytes; connection closed", client.id,
                   settings_.max_request_bytes);
      close_after(client,
                  {{"ok", false},
                   {"error", fmt::format("request too large: longer than markerd's limit of {} ({} bytes); "
                                         "closing the connection",
                                         format_bytes(settings_.max_request_bytes), settings_.max_request_bytes)}});
      start = client.input.size();
      break;
    }
    if (newline == std::string::npos) break;
    // A follower's next line ends its stream, however full its output; any
    // other request waits until the client has read its earlier replies.
    if (client.following == nullptr && client.pending() >= settings_.max_output_bytes) {
      client.input_scanned = newline;
      break;
    }
    handle_line(client, std::string_view(client.input).substr(start, newline - start));
    start = newline + 1;
  }
  if (start > 0) {
    client.input.erase(0, std::min(start, client.input.size()));
    client.input_scanned = 0;
  }
  // Nothing left of a request to scan again: remember how far it was read.
  if (client.input.find('\n') == std::string::npos) client.input_scanned = client.input.size();
}

void ControlServer::write_to(Client& client) {
  while (client.pending() > 0 && !client.dead) {
    const ssize_t n = ::send(client.fd.get(), client.output.data() + client.output_sent, client.pending(),
                             MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      spdlog::debug("control: client {}: write: {}", client.id, errno_text(errno));
      client.dead = true;
      return;
    }
    client.output_sent += static_cast<std::size_t>(n);
    if (n > 0) client.last_activity = Clock::now();
  }
  if (client.output_sent == client.output.size()) {
    client.output.clear();
    client.output_sent = 0;
  } else if (client.output_sent >= kReadChunk && client.output_sent * 2 >= client.output.size()) {
    client.output.erase(0, client.output_sent);
    client.output_sent = 0;
  }
  // Lines lost at the end of a burst are announced once there is room,
  // without waiting for the stream's next line.
  if (client.following != nullptr && client.missed > 0 && client.pending() < settings_.max_output_bytes / 2) {
    queue_notice(client);
  }
}

void ControlServer::close_client(Client& client) {
  if (client.following != nullptr) unfollow(client);
  // Unread bytes in the receive queue would make the client's read fail
  // with ECONNRESET instead of reading the reply and then the end: discard
  // what has arrived (a bounded amount) before closing.
  std::array<char, 4096> sink{};
  for (int i = 0; i < 256 && ::recv(client.fd.get(), sink.data(), sink.size(), MSG_DONTWAIT) > 0; ++i) {
  }
  client.fd.reset();
  spdlog::debug("control: client {} disconnected", client.id);
}

// ---------------------------------------------------------------- requests

void ControlServer::handle_line(Client& client, std::string_view line) {
  counters_.requests.fetch_add(1, std::memory_order_relaxed);
  client.last_activity = Clock::now();
  if (client.following != nullptr) {
    // Any line ends a stream. It is not run as a command: a client that
    // wants the stream to end may not know what else might arrive first.
    ordered_json reply;
    try {
      const json request = json::parse(line);
      if (request.is_object() && request.contains("id") && !request["id"].is_structured()) reply["id"] = request["id"];
    } catch (const json::exception&) {
      // Not JSON: the stream ends all the same.
    }
    const std::string name = client.following->name();
    unfollow(client);
    reply["ok"] = true;
    reply["event"] = "end";
    reply["stream"] = name;
    queue_reply(client, reply);
    return;
  }
  const ordered_json reply = answer(client, line);
  if (!reply.value("ok", false)) counters_.errors.fetch_add(1, std::memory_order_relaxed);
  client.served = true;
  queue_reply(client, reply);
}

ordered_json ControlServer::answer(Client& client, std::string_view line) {
  ordered_json reply;
  const auto refuse = [&reply](const std::string& why) {
    reply["ok"] = false;
    reply["error"] = why;
    return reply;
  };
  if (blank(line)) return refuse(R"(empty request: send one JSON object per line, e.g. {"cmd":"help"})");
  json request;
  try {
    request = json::parse(line, [](int depth, json::parse_event_t, json&) {
      if (depth > kMaxRequestDepth) {
        throw ControlError(fmt::format("request nested deeper than {} levels", kMaxRequestDepth));
      }
      return true;
    });
  } catch (const json::parse_error& e) {
    return refuse("malformed JSON: " + json_error_text(e));
  } catch (const ControlError& e) {
    return refuse(e.what());
  } catch (const json::exception& e) {
    return refuse(malformed_json_text(line, e));
  }
  if (!request.is_object()) {
    return refuse(
        fmt::format(R"(a request must be a JSON object such as {{"cmd":"help"}}, got {})", json_type_name(request)));
  }
  if (const auto id = request.find("id"); id != request.end()) {
    if (id->is_structured())
      return refuse(fmt::format("\"id\" must be a string or a number, got {}", json_type_name(*id)));
    reply["id"] = *id;
  }
  const auto cmd = request.find("cmd");
  if (cmd == request.end()) return refuse(R"(missing "cmd", the command's name ("help" lists them))");
  if (!cmd->is_string()) return refuse(fmt::format("\"cmd\" must be a string, got {}", json_type_name(*cmd)));
  const std::string& name = cmd->get_ref<const std::string&>();
  const auto found = commands_.find(name);
  if (client.beyond_limit && (found == commands_.end() || !found->second.beyond_client_limit)) {
    counters_.refused.fetch_add(1, std::memory_order_relaxed);
    client.closing = true;
    client.close_deadline = Clock::now() + kCloseLinger;
    return refuse(too_many_clients());
  }
  if (found == commands_.end()) {
    return refuse(fmt::format(R"(unknown command '{}' ("help" lists the commands))", name));
  }
  const Command& command = found->second;
  if (command.stream != nullptr) {
    try {
      expect_arguments(request, {});
    } catch (const ControlError& e) {
      return refuse(e.what());
    }
    follow(client, *command.stream);
    reply["ok"] = true;
    reply["stream"] = name;
    return reply;
  }
  json result;
  try {
    result = command.handler(request);
  } catch (const ControlError& e) {
    return refuse(e.what());
  } catch (const json::exception& e) {
    // A handler that read an argument without the readers of
    // command_arguments.hpp: nlohmann cannot say which one.
    spdlog::warn("control: {}: an argument read unchecked: {}", name, e.what());
    return refuse(fmt::format("{}: an argument has the wrong type or value: {}", name, json_error_text(e)));
  } catch (const std::exception& e) {
    spdlog::warn("control: {} failed: {}", name, e.what());
    return refuse(e.what());
  } catch (...) {
    spdlog::error("control: {} threw something that is not an exception", name);
    return refuse(fmt::format("{} failed (an internal error)", name));
  }
  reply["ok"] = true;
  if (result.is_object()) {
    for (auto& [key, value] : result.items()) {
      if (key != "id" && key != "ok") reply[key] = value;  // json to ordered_json: a copy either way
    }
  } else if (!result.is_null()) {
    reply["result"] = result;
  }
  return reply;
}

void ControlServer::queue_reply(Client& client, const ordered_json& reply) { client.output += dump_line(reply); }

void ControlServer::queue_notice(Client& client) {
  if (client.following == nullptr || client.missed == 0) return;
  client.output += dump_line({{"event", "dropped"}, {"stream", client.following->name()}, {"lines", client.missed}});
  client.missed = 0;
}

// ---------------------------------------------------------------- streams

void ControlServer::follow(Client& client, LineBroadcast& broadcast) {
  // Lines published before this client asked belong to the followers that
  // were there: hand them out first.
  drain_stream(broadcast);
  client.following = &broadcast;
  client.missed = 0;
  broadcast.set_listening(true);
}

void ControlServer::unfollow(Client& client) {
  LineBroadcast* broadcast = client.following;
  if (broadcast == nullptr) return;
  queue_notice(client);
  client.following = nullptr;
  client.missed = 0;
  const bool others = std::any_of(clients_.begin(), clients_.end(),
                                  [&](const auto& c) { return c.get() != &client && c->following == broadcast; });
  broadcast->set_listening(others);
}

void ControlServer::drain_stream(LineBroadcast& broadcast) {
  followers_.clear();
  for (auto& client : clients_) {
    if (client->following == &broadcast && !client->dead) followers_.push_back(client.get());
  }
  const std::size_t limit = settings_.max_output_bytes;
  std::uint64_t sent = 0;
  std::uint64_t missed = 0;
  broadcast.drain(
      [&](std::string_view line) {
        for (Client* client : followers_) {
          if (client->pending() + line.size() + 1 > limit) {
            ++client->missed;
            ++missed;
            continue;
          }
          queue_notice(*client);
          client->output.append(line);
          client->output += '\n';
          ++sent;
        }
      },
      [&](std::uint64_t count) {
        for (Client* client : followers_) client->missed += count;
        missed += count * followers_.size();
      });
  counters_.stream_lines.fetch_add(sent, std::memory_order_relaxed);
  counters_.stream_dropped.fetch_add(missed, std::memory_order_relaxed);
}

}  // namespace markerd::daemon
