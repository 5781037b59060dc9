// The control socket's server in-process, over a socket in a temporary
// directory: the protocol (ids, errors that leave the connection usable,
// lines split and joined across writes, requests too long), clients that
// misbehave (disconnect mid-request, never read), the socket file (mode,
// group, a stale socket replaced, a live one refused), the line broadcast
// and its streams (order, drops announced exactly, a producer that never
// waits), stop() with clients connected, the client library, and the real
// markerctl binary (MARKERCTL_PATH) against the server.

#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
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

namespace fs = std::filesystem;
using nlohmann::json;
using namespace markerd::daemon;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using markerd::test_support::Outcome;
using markerd::test_support::TempDir;

namespace {

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
void register_test_commands(ControlServer& server) {
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

// ---------------------------------------------------------------- request and reply

TEST_F(ControlServerTest, RepliesCarryTheRequestsIdAndTheHandlersResult) {
  start();
  RawClient client(socket());
  client.request({{"cmd", "add"}, {"id", 7}, {"a", 2}, {"b", 3.5}});
  json r = client.reply();
  EXPECT_EQ(r, (json{{"id", 7}, {"ok", true}, {"sum", 5.5}}));
  EXPECT_EQ(r.dump().substr(0, 16), R"({"id":7,"ok":tru)") << "id and ok come first";

  client.request({{"cmd", "add"}, {"id", "the-second"}, {"a", 1}, {"b", 1}});
  EXPECT_EQ(client.reply()["id"], "the-second");
  client.request({{"cmd", "add"}, {"a", 1}, {"b", 1}});
  r = client.reply();
  EXPECT_FALSE(r.contains("id")) << r;
  EXPECT_EQ(r["sum"], 2);

  client.request({{"cmd", "scalar"}, {"id", 1}});
  EXPECT_EQ(client.reply(), (json{{"id", 1}, {"ok", true}, {"result", 42}}));
  client.request({{"cmd", "nothing"}, {"id", 2}});
  EXPECT_EQ(client.reply(), (json{{"id", 2}, {"ok", true}}));
  client.request({{"cmd", "echo"}, {"id", 3}, {"x", {1, 2}}});
  EXPECT_EQ(client.reply()["echo"], (json{{"cmd", "echo"}, {"id", 3}, {"x", {1, 2}}}));

  client.request({{"cmd", "help"}, {"id", 4}});
  r = client.reply();
  ASSERT_TRUE(r["ok"].get<bool>()) << r;
  std::vector<std::string> names;
  for (const auto& c : r["commands"]) names.push_back(c["name"]);
  EXPECT_EQ(names, (std::vector<std::string>{"add", "echo", "fail", "help", "nothing", "refuse", "scalar"}));
  EXPECT_EQ(r["commands"][0]["help"], "a + b");

  const ControlServerStats stats = server_->stats();
  EXPECT_EQ(stats.requests, 7U);
  EXPECT_EQ(stats.errors, 0U);
  EXPECT_EQ(stats.clients, 1U);
}

TEST_F(ControlServerTest, ServesSeveralClientsAtOnceEachInItsOwnOrder) {
  start();
  constexpr int kClients = 8;
  constexpr int kRequests = 200;
  std::vector<std::thread> threads;
  std::atomic<int> failures{0};
  for (int c = 0; c < kClients; ++c) {
    threads.emplace_back([&, c] {
      RawClient client(socket());
      // Half the requests are sent ahead of their replies.
      for (int i = 0; i < kRequests; i += 2) {
        client.request({{"cmd", "add"}, {"id", i}, {"a", c}, {"b", i}});
        client.request({{"cmd", "add"}, {"id", i + 1}, {"a", c}, {"b", i + 1}});
        for (int k = i; k < i + 2; ++k) {
          const auto text = client.line();
          const json r = text ? json::parse(*text) : json();
          if (r.value("id", -1) != k || r.value("sum", -1.0) != c + k) ++failures;
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ(server_->stats().requests, static_cast<std::uint64_t>(kClients * kRequests));
  EXPECT_EQ(server_->stats().connections, static_cast<std::uint64_t>(kClients));
}

// ---------------------------------------------------------------- bad requests

TEST_F(ControlServerTest, EveryBadRequestGetsAnErrorNamingTheProblemAndTheConnectionStaysUsable) {
  start();
  RawClient client(socket());
  const auto error_for = [&](std::string_view line) {
    client.send(std::string(line) + "\n");
    const json r = client.reply();
    EXPECT_EQ(r.value("ok", true), false) << line << " -> " << r;
    return r.value("error", std::string());
  };
  EXPECT_EQ(error_for(R"({"cmd": "help")").substr(0, 14), "malformed JSON");
  EXPECT_NE(error_for("{abc").find("malformed JSON: parse error at line 1, column 2"), std::string::npos);
  EXPECT_NE(error_for("not json at all").find("malformed JSON"), std::string::npos);
  EXPECT_EQ(error_for("[1, 2]"), R"(a request must be a JSON object such as {"cmd":"help"}, got an array)");
  EXPECT_EQ(error_for("\"help\""), R"(a request must be a JSON object such as {"cmd":"help"}, got a string)");
  EXPECT_EQ(error_for(R"({"id": 1})"), R"(missing "cmd", the command's name ("help" lists them))");
  EXPECT_EQ(error_for(R"({"cmd": 5})"), R"("cmd" must be a string, got a number)");
  EXPECT_EQ(error_for(R"({"cmd": "launch"})"), R"(unknown command 'launch' ("help" lists the commands))");
  EXPECT_EQ(error_for(R"({"cmd": "add", "a": "2", "b": 3})"), R"(argument 'a' must be a number, got a string ("2"))");
  EXPECT_EQ(error_for(R"({"cmd": "add", "a": 2, "b": 3, "c": 4})"), "unknown argument 'c' (for add: a, b)");
  EXPECT_EQ(error_for(R"({"cmd": "add", "a": 2})"), "add needs a and b");
  EXPECT_EQ(error_for(R"({"cmd": "fail"})"), "the handler failed");
  EXPECT_EQ(error_for(R"({"cmd": "refuse"})"), "refused: not today");
  EXPECT_EQ(error_for(R"({"cmd": "help", "id": [1]})"), R"("id" must be a string or a number, got an array)");
  EXPECT_EQ(error_for(""), R"(empty request: send one JSON object per line, e.g. {"cmd":"help"})");
  EXPECT_EQ(error_for("  \r"), R"(empty request: send one JSON object per line, e.g. {"cmd":"help"})");
  EXPECT_EQ(error_for(R"({"cmd":"echo","x":)" + std::string(40, '[') + std::string(40, ']') + "}"),
            "request nested deeper than 32 levels");
  // A number beyond a double's range: markerd's words, not nlohmann's
  // "[json.exception.out_of_range.406] ..." (found by the fuzzer).
  EXPECT_EQ(error_for(R"({"cmd":"rig.move","rail":1e309})"),
            "malformed JSON: number 1e309 is out of range (beyond a double's) at byte 26");
  EXPECT_EQ(error_for(R"({"cmd":"echo","x":[1,-1e400]})"),
            "malformed JSON: number -1e400 is out of range (beyond a double's) at byte 22");
  // Bytes that are not UTF-8 inside a string.
  EXPECT_NE(error_for("{\"cmd\": \"\xff\xfe\"}").find("malformed JSON"), std::string::npos);

  // The errors echo the id when the request had a usable one.
  client.send(R"({"cmd": "launch", "id": 99})"
              "\n");
  EXPECT_EQ(client.reply()["id"], 99);
  // A line ending in \r\n (a terminal's, socat's) is a request like any other.
  client.send("{\"cmd\": \"add\", \"id\": 100, \"a\": 1, \"b\": 2}\r\n");
  EXPECT_EQ(client.reply(), (json{{"id", 100}, {"ok", true}, {"sum", 3}}));
  EXPECT_EQ(server_->stats().errors, 21U);
  EXPECT_EQ(server_->stats().clients, 1U);
}

TEST_F(ControlServerTest, ALineSplitAcrossManyWritesAndTwoRequestsInOneWrite) {
  start();
  RawClient client(socket());
  const std::string request = R"({"cmd": "add", "id": 1, "a": 20, "b": 22})"
                              "\n";
  for (std::size_t i = 0; i < request.size(); ++i) {
    client.send(request.substr(i, 1));
    if (i % 7 == 0) std::this_thread::sleep_for(2ms);  // separate reads on the server's side
  }
  EXPECT_EQ(client.reply(), (json{{"id", 1}, {"ok", true}, {"sum", 42}}));

  client.send(R"({"cmd":"add","id":2,"a":1,"b":1})"
              "\n"
              R"({"cmd":"add","id":3,"a":1,"b":2})"
              "\n"
              R"({"cmd":"add","id":4,)");
  EXPECT_EQ(client.reply()["id"], 2);
  EXPECT_EQ(client.reply()["id"], 3);
  EXPECT_FALSE(client.line(100ms)) << "the third request is not complete yet";
  client.send(R"("a":2,"b":2})"
              "\n");
  EXPECT_EQ(client.reply(), (json{{"id", 4}, {"ok", true}, {"sum", 4}}));
}

constexpr const char* kTooLarge =
    "request too large: longer than markerd's limit of 4 KiB (4096 bytes); closing the connection";

TEST_F(ControlServerTest, ALineLongerThanTheLimitIsRefusedAndClosesOnlyThatConnection) {
  start();
  RawClient bystander(socket());
  bystander.request({{"cmd", "add"}, {"id", 1}, {"a", 1}, {"b", 1}});
  EXPECT_EQ(bystander.reply()["sum"], 2);

  // Exactly at the limit: served.
  {
    RawClient client(socket());
    std::string request = R"({"cmd": "add", "id": 1, "a": 1, "b": 1)";
    request += std::string(settings_.max_request_bytes - request.size() - 1, ' ') + "}";
    ASSERT_EQ(request.size(), settings_.max_request_bytes);
    client.send(request + "\n");
    EXPECT_EQ(client.reply()["sum"], 2);
  }
  // One byte more, with its newline: refused, then closed.
  {
    RawClient client(socket());
    std::string request = R"({"cmd": "add", "id": 1, "a": 1, "b": 1)";
    request += std::string(settings_.max_request_bytes - request.size(), ' ') + "}";
    client.send(request + "\n" +
                R"({"cmd":"help"})"
                "\n");
    EXPECT_EQ(client.reply(), (json{{"ok", false}, {"error", kTooLarge}}));
    EXPECT_TRUE(client.ends());
  }
  // Far more, and no newline ever: refused once the limit is passed.
  {
    RawClient client(socket());
    client.send(R"({"cmd": "echo", "x": ")" + std::string(3 * settings_.max_request_bytes, 'x'));
    EXPECT_EQ(client.reply()["error"], kTooLarge);
    EXPECT_TRUE(client.ends());
  }
  EXPECT_EQ(server_->stats().oversized, 2U);
  // The others are served as before, and new clients too.
  bystander.request({{"cmd", "add"}, {"id", 2}, {"a", 2}, {"b", 2}});
  EXPECT_EQ(bystander.reply()["sum"], 4);
  RawClient newcomer(socket());
  newcomer.request({{"cmd", "add"}, {"id", 3}, {"a", 3}, {"b", 3}});
  EXPECT_EQ(newcomer.reply()["sum"], 6);
}

TEST_F(ControlServerTest, AClientThatDisconnectsMidRequestIsForgotten) {
  start();
  {
    RawClient client(socket());
    client.send(R"({"cmd": "add", "a": 1,)");
  }
  {
    // Requests complete before the disconnect are still answered (to nobody).
    RawClient client(socket());
    client.send(R"({"cmd": "help"})"
                "\n"
                R"({"cmd": "help"})"
                "\n"
                R"({"cmd":)");
    ::shutdown(client.fd(), SHUT_WR);
    EXPECT_EQ(client.reply()["ok"], true);
    EXPECT_EQ(client.reply()["ok"], true);
    EXPECT_TRUE(client.ends()) << "the server closes once it has answered what it could";
  }
  EXPECT_TRUE(eventually([&] { return server_->stats().clients == 0; }));
  RawClient client(socket());
  client.request({{"cmd", "add"}, {"id", 1}, {"a", 1}, {"b", 1}});
  EXPECT_EQ(client.reply()["sum"], 2);
  EXPECT_EQ(server_->stats().requests, 3U);
}

TEST_F(ControlServerTest, AClientThatDoesNotReadItsRepliesDoesNotHoldUpTheOthers) {
  settings_.max_output_bytes = 64 * 1024;
  start();
  RawClient hoarder(socket());
  constexpr int kRequests = 20000;
  std::string requests;
  for (int i = 0; i < kRequests; ++i) requests += json{{"cmd", "help"}, {"id", i}}.dump() + "\n";
  // Far more replies than the server queues for one client and the socket
  // holds: the writer blocks once the server stops taking its requests.
  std::thread writer([&] { hoarder.send(requests); });

  std::this_thread::sleep_for(200ms);
  RawClient other(socket());
  for (int i = 0; i < 20; ++i) {
    const auto before = Clock::now();
    other.request({{"cmd", "add"}, {"id", i}, {"a", i}, {"b", 1}});
    EXPECT_EQ(other.reply()["sum"], i + 1);
    EXPECT_LT(Clock::now() - before, 2s);
  }
  EXPECT_LT(server_->stats().requests, static_cast<std::uint64_t>(kRequests)) << "the hoarder's requests wait";

  // Once it reads, every reply comes, in order.
  for (int i = 0; i < kRequests; ++i) {
    const json r = hoarder.reply();
    ASSERT_EQ(r.value("id", -1), i) << r;
  }
  writer.join();
}

TEST_F(ControlServerTest, ConnectionsBeyondTheLimitAreToldSoAndClosed) {
  settings_.max_clients = 2;
  start();
  RawClient a(socket());
  RawClient b(socket());
  a.request({{"cmd", "help"}, {"id", 1}});
  b.request({{"cmd", "help"}, {"id", 1}});
  EXPECT_EQ(a.reply()["ok"], true);
  EXPECT_EQ(b.reply()["ok"], true);
  {
    RawClient c(socket());
    EXPECT_EQ(c.reply(), (json{{"ok", false}, {"error", "too many clients (2 connected); try again later"}}));
    EXPECT_TRUE(c.ends());
  }
  EXPECT_EQ(server_->stats().refused, 1U);
  a.close();
  ASSERT_TRUE(eventually([&] { return server_->stats().clients == 1; }));
  RawClient d(socket());
  d.request({{"cmd", "help"}, {"id", 5}});
  EXPECT_EQ(d.reply()["id"], 5);
}

// A stop command, as rig.stop is: served however many clients hold the
// socket. It counts what it was asked to do.
struct StopCommand {
  std::atomic<int> emergency_stops{0};
  void register_with(ControlServer& server) {
    server.register_command("stop", [this](const json& request) {
      expect_arguments(request, {"emergency"});
      if (bool_argument(request, "emergency").value_or(false)) ++emergency_stops;
      return json{{"stopped", true}};
    });
    server.serve_beyond_client_limit("stop");
  }
};

TEST_F(ControlServerTest, AnEmergencyStopGetsThroughWhenIdleClientsHoldEverySlot) {
  ASSERT_EQ(settings_.max_clients, 16U) << "the default";
  server_ = std::make_unique<ControlServer>(settings_);
  register_test_commands(*server_);
  StopCommand stop;
  stop.register_with(*server_);
  EXPECT_THROW(server_->serve_beyond_client_limit("launch"), std::logic_error);
  server_->start();

  // Sixteen clients that connect, ask once, and then say nothing.
  std::vector<std::unique_ptr<RawClient>> idle;
  for (int i = 0; i < 16; ++i) {
    idle.push_back(std::make_unique<RawClient>(socket()));
    idle.back()->request({{"cmd", "help"}, {"id", i}});
    ASSERT_EQ(idle.back()->reply()["id"], i);
  }
  ASSERT_TRUE(eventually([&] { return server_->stats().clients == 16; }));

  // Beyond the limit, anything but a stop is refused, saying what is served, and closed.
  {
    RawClient late(socket());
    late.request({{"cmd", "help"}, {"id", 1}});
    EXPECT_EQ(
        late.reply(),
        (json{{"id", 1},
              {"ok", false},
              {"error", "too many clients (16 connected; beyond the limit only stop is served); try again later"}}));
    EXPECT_TRUE(late.ends());
  }
  // Connections beyond the limit that send nothing do not keep the stop out either.
  std::vector<std::unique_ptr<RawClient>> silent;
  for (int i = 0; i < 8; ++i) silent.push_back(std::make_unique<RawClient>(socket()));

  ControlClient operator_client(socket());
  const json reply = operator_client.call({{"cmd", "stop"}, {"emergency", true}});
  EXPECT_EQ(reply, (json{{"id", 1}, {"ok", true}, {"stopped", true}}));
  EXPECT_EQ(stop.emergency_stops.load(), 1);
  // The connection stays for more stops.
  EXPECT_EQ(operator_client.call({{"cmd", "stop"}})["ok"], true);
  EXPECT_GE(server_->stats().beyond_limit, 1U);

  // The sixteen are still connected and served.
  for (int i = 0; i < 16; ++i) {
    idle[static_cast<std::size_t>(i)]->request({{"cmd", "add"}, {"id", i}, {"a", i}, {"b", 1}});
    EXPECT_EQ(idle[static_cast<std::size_t>(i)]->reply()["sum"], i + 1);
  }
}

TEST_F(ControlServerTest, AnIdleConnectionIsClosedAfterTheIdleTimeoutButAFollowerIsNot) {
  settings_.idle_timeout = 300ms;
  LineBroadcast& stream = make_stream();
  start({&stream});
  RawClient follower(socket());
  follower.request({{"cmd", "detections"}, {"id", 1}});
  EXPECT_EQ(follower.reply(), (json{{"id", 1}, {"ok", true}, {"stream", "detections"}}));

  RawClient idle(socket());
  idle.request({{"cmd", "help"}, {"id", 1}});
  EXPECT_EQ(idle.reply()["ok"], true);
  // A partial request is not activity: the line never ends.
  idle.send(R"({"cmd": "he)");
  EXPECT_EQ(idle.reply(30s),
            (json{{"ok", false}, {"error", "idle for 0.3 s (no request, no reply read); closing the connection"}}));
  EXPECT_TRUE(idle.ends(30s));
  EXPECT_EQ(server_->stats().idle_closed, 1U);

  // The follower outlives several timeouts, and still gets the stream.
  std::this_thread::sleep_for(1s);
  stream.publish(R"({"line":1})");
  EXPECT_EQ(follower.line(), R"({"line":1})");
  follower.request({{"cmd", "stop"}, {"id", 2}});
  EXPECT_EQ(follower.reply(), (json{{"id", 2}, {"ok", true}, {"event", "end"}, {"stream", "detections"}}));
  EXPECT_EQ(server_->stats().idle_closed, 1U);
}

TEST_F(ControlServerTest, CommandsAreRegisteredBeforeStartAndOnce) {
  ControlServer& server = start();
  EXPECT_THROW(server.register_command("late", [](const json&) { return json(); }), std::logic_error);
  ControlServer other(settings_);
  EXPECT_THROW(other.register_command("help", [](const json&) { return json(); }), std::logic_error);
}

// ---------------------------------------------------------------- the socket file

TEST_F(ControlServerTest, TheSocketHasMode0660AndTheConfiguredGroup) {
  // A group other than the process's own where there is one (root may give
  // the socket to any group; another user only to its own groups).
  const ::group* g = ::getuid() == 0 ? ::getgrnam("nogroup") : nullptr;
  if (g == nullptr) g = ::getgrgid(::getegid());
  ASSERT_NE(g, nullptr) << "the process's group has no name";
  const gid_t gid = g->gr_gid;
  settings_.group = g->gr_name;
  start();
  struct stat st {};
  ASSERT_EQ(::lstat(socket().c_str(), &st), 0);
  EXPECT_TRUE(S_ISSOCK(st.st_mode));
  EXPECT_EQ(st.st_mode & 07777, 0660U);
  EXPECT_EQ(st.st_gid, gid);
  server_->stop();
  EXPECT_FALSE(fs::exists(fs::symlink_status(socket()))) << "stop() removes the socket";
}

TEST_F(ControlServerTest, AGroupThatDoesNotExistIsAClearErrorAndLeavesNothingBehind) {
  settings_.group = "markerd-test-no-such-group";
  ControlServer server(settings_);
  try {
    server.start();
    FAIL() << "started with a group that does not exist";
  } catch (const ControlSocketError& e) {
    EXPECT_EQ(std::string(e.what()),
              "control socket " + socket().string() +
                  ": group 'markerd-test-no-such-group' does not exist (create it, e.g. with systemd-sysusers, or "
                  "name another in [control] group)");
  }
  EXPECT_FALSE(fs::exists(fs::symlink_status(socket())));
}

TEST_F(ControlServerTest, AModeThatOpensTheSocketToOtherUsersIsRefused) {
  settings_.mode = 0666;
  ControlServer server(settings_);
  EXPECT_THROW(server.start(), ControlSocketError);
  EXPECT_FALSE(fs::exists(fs::symlink_status(socket())));
}

TEST_F(ControlServerTest, AMissingDirectoryIsNamed) {
  settings_.socket_path = dir_.path() / "no-such-dir" / "control.sock";
  ControlServer server(settings_);
  try {
    server.start();
    FAIL() << "started in a directory that does not exist";
  } catch (const ControlSocketError& e) {
    EXPECT_EQ(std::string(e.what()), "control socket " + settings_.socket_path.string() + ": its directory " +
                                         (dir_.path() / "no-such-dir").string() +
                                         ": No such file or directory (it is not created here: systemd's "
                                         "RuntimeDirectory= does)");
  }
}

TEST_F(ControlServerTest, AStaleSocketIsReplacedAndALiveOneIsRefused) {
  {
    // What a crashed markerd leaves: a socket file nobody listens on.
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, socket().c_str(), sizeof address.sun_path - 1);
    ASSERT_EQ(::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address), 0);
    ::close(fd);
    ASSERT_TRUE(fs::is_socket(socket()));
  }
  start();
  RawClient client(socket());
  client.request({{"cmd", "help"}, {"id", 1}});
  EXPECT_EQ(client.reply()["ok"], true);

  ControlServer second(settings_);
  try {
    second.start();
    FAIL() << "a second server took over a live socket";
  } catch (const ControlSocketError& e) {
    EXPECT_EQ(std::string(e.what()), "control socket " + socket().string() +
                                         ": another process is listening on it (is another markerd running?); it "
                                         "is left alone");
  }
  second.stop();
  // The first server's socket is still there and still its own.
  client.request({{"cmd", "help"}, {"id", 2}});
  EXPECT_EQ(client.reply()["id"], 2);
  RawClient newcomer(socket());
  newcomer.request({{"cmd", "help"}, {"id", 3}});
  EXPECT_EQ(newcomer.reply()["id"], 3);
}

TEST_F(ControlServerTest, AFileThatIsNotASocketIsLeftAlone) {
  std::ofstream(socket()) << "precious\n";
  ControlServer server(settings_);
  try {
    server.start();
    FAIL() << "replaced a regular file";
  } catch (const ControlSocketError& e) {
    EXPECT_EQ(std::string(e.what()),
              "control socket " + socket().string() + ": exists and is not a socket; it is left alone");
  }
  std::ifstream in(socket());
  std::string text;
  std::getline(in, text);
  EXPECT_EQ(text, "precious");
}

TEST_F(ControlServerTest, StopReturnsPromptlyWithClientsConnectedAndRemovesTheSocket) {
  LineBroadcast& stream = make_stream();
  start({&stream});
  std::vector<std::unique_ptr<RawClient>> clients;
  for (int i = 0; i < 5; ++i) clients.push_back(std::make_unique<RawClient>(socket()));
  clients[0]->send(R"({"cmd": "help", )");  // mid-request
  clients[1]->request({{"cmd", "detections"}, {"id", 1}});
  EXPECT_EQ(clients[1]->reply()["stream"], "detections");
  clients[2]->request({{"cmd", "help"}, {"id", 1}});
  EXPECT_EQ(clients[2]->reply()["id"], 1);

  const auto before = Clock::now();
  server_->stop();
  EXPECT_LT(Clock::now() - before, 1s);
  EXPECT_FALSE(fs::exists(fs::symlink_status(socket())));
  for (auto& c : clients) EXPECT_TRUE(c->ends(2s));
  EXPECT_FALSE(stream.listening());
  server_->stop();  // idempotent
}

// ---------------------------------------------------------------- streams

std::string numbered_line(std::uint64_t seq, std::size_t pad) {
  return json{{"seq", seq}, {"pad", std::string(pad, 'p')}}.dump() + "\n";
}

// Reads a stream until `total` lines are accounted for (received, or
// announced as dropped), checking that each line is whole and that every
// gap in the sequence is exactly a dropped notice.
struct StreamTally {
  std::uint64_t received = 0;
  std::uint64_t dropped = 0;
  std::uint64_t notices = 0;
  bool in_order = true;
};
StreamTally follow_until(RawClient& client, std::uint64_t total, std::chrono::milliseconds timeout) {
  StreamTally tally;
  std::uint64_t expected = 0;
  const auto deadline = Clock::now() + timeout;
  while (tally.received + tally.dropped < total && Clock::now() < deadline) {
    const auto text = client.line(1s);
    if (!text) continue;
    const json line = json::parse(*text);
    if (line.contains("event")) {
      EXPECT_EQ(line["event"], "dropped") << line;
      EXPECT_EQ(line["stream"], "detections");
      tally.dropped += line["lines"].get<std::uint64_t>();
      expected += line["lines"].get<std::uint64_t>();
      ++tally.notices;
      continue;
    }
    if (line["seq"].get<std::uint64_t>() != expected) {
      if (tally.in_order) ADD_FAILURE() << "line " << line["seq"] << " where " << expected << " was due";
      tally.in_order = false;
    }
    expected = line["seq"].get<std::uint64_t>() + 1;
    ++tally.received;
  }
  return tally;
}

TEST_F(ControlServerTest, AStreamDeliversLinesWholeAndInOrderUntilTheClientSendsALine) {
  LineBroadcast& stream = make_stream(256 * 1024);
  start({&stream});
  EXPECT_FALSE(stream.publish(numbered_line(0, 10))) << "nobody follows yet";
  EXPECT_EQ(stream.stats().unheard, 1U);

  RawClient client(socket());
  client.request({{"cmd", "detections"}, {"id", "s"}});
  EXPECT_EQ(client.reply(), (json{{"id", "s"}, {"ok", true}, {"stream", "detections"}}));
  EXPECT_TRUE(stream.listening());

  // Lines of many lengths, some far longer than a socket write, published
  // while the client reads; the producer is never held back, so any line it
  // could not store is announced in its place.
  constexpr std::uint64_t kLines = 3000;
  std::thread producer([&] {
    for (std::uint64_t i = 0; i < kLines; ++i) {
      stream.publish(numbered_line(i, (i * 7919) % (i % 50 == 0 ? 60000 : 900)));
      if (i % 64 == 0) std::this_thread::sleep_for(1ms);
    }
  });
  const StreamTally tally = follow_until(client, kLines, 60s);
  producer.join();
  EXPECT_TRUE(tally.in_order);
  EXPECT_EQ(tally.received + tally.dropped, kLines);
  EXPECT_EQ(stream.stats().published + stream.stats().dropped, kLines);
  RecordProperty("received", static_cast<int>(tally.received));

  // Any line ends the stream; the reply to it carries its id, and the
  // connection takes requests again.
  client.request({{"cmd", "stop"}, {"id", 9}});
  EXPECT_EQ(client.reply(), (json{{"id", 9}, {"ok", true}, {"event", "end"}, {"stream", "detections"}}));
  EXPECT_TRUE(eventually([&] { return !stream.listening(); }));
  EXPECT_FALSE(stream.publish(numbered_line(kLines, 10)));
  client.request({{"cmd", "add"}, {"id", 10}, {"a", 1}, {"b", 1}});
  EXPECT_EQ(client.reply(), (json{{"id", 10}, {"ok", true}, {"sum", 2}}));

  // A stream takes no arguments.
  client.request({{"cmd", "detections"}, {"id", 11}, {"since", 5}});
  EXPECT_EQ(client.reply()["error"], "unknown argument 'since': detections takes none");
}

TEST_F(ControlServerTest, AFollowerThatReadsNothingLosesLinesAndIsToldHowManyWhileTheProducerNeverWaits) {
  settings_.max_output_bytes = 64 * 1024;
  LineBroadcast& stream = make_stream(64 * 1024);
  start({&stream});
  RawClient slow(socket());
  RawClient bystander(socket());
  slow.request({{"cmd", "detections"}, {"id", 1}});
  ASSERT_EQ(slow.reply()["stream"], "detections");

  // 100000 lines published as fast as they come (formatted beforehand: the
  // time is publish()'s alone), far more than the server's ring, the
  // follower's backlog and its socket hold, while it reads nothing.
  constexpr std::uint64_t kLines = 100000;
  std::vector<std::string> lines;
  lines.reserve(kLines);
  for (std::uint64_t i = 0; i < kLines; ++i) lines.push_back(numbered_line(i, 80));
  const auto before = Clock::now();
  std::uint64_t stored = 0;
  for (const std::string& line : lines) stored += stream.publish(line) ? 1 : 0;
  const auto took = Clock::now() - before;
  EXPECT_LT(took, 5s) << "publish() waited";
  RecordProperty("publish_ns_per_line",
                 static_cast<int>(std::chrono::duration_cast<std::chrono::nanoseconds>(took).count() / kLines));
  const LineBroadcastStats counts = stream.stats();
  EXPECT_EQ(counts.published, stored);
  EXPECT_EQ(counts.published + counts.dropped, kLines);

  // Meanwhile the server answers everyone else.
  const auto asked = Clock::now();
  bystander.request({{"cmd", "help"}, {"id", 1}});
  EXPECT_EQ(bystander.reply()["ok"], true);
  EXPECT_LT(Clock::now() - asked, 2s);

  // Reading at last, the follower gets lines in order, whole, and a notice
  // for every run it lost, at its place, adding up to every line.
  const StreamTally tally = follow_until(slow, kLines, 60s);
  EXPECT_TRUE(tally.in_order);
  EXPECT_EQ(tally.received + tally.dropped, kLines);
  EXPECT_GT(tally.dropped, kLines / 2) << "a follower that reads nothing cannot get most lines";
  EXPECT_GE(tally.notices, 1U);
  EXPECT_EQ(server_->stats().stream_dropped, tally.dropped);
  RecordProperty("received", static_cast<int>(tally.received));
}

TEST_F(ControlServerTest, ASlowFollowerDoesNotHoldUpAFastOne) {
  LineBroadcast& stream = make_stream();
  start({&stream});
  RawClient slow(socket());
  RawClient fast(socket());
  for (RawClient* c : {&slow, &fast}) {
    c->request({{"cmd", "detections"}, {"id", 1}});
    ASSERT_EQ(c->reply()["stream"], "detections");
  }
  // About 2 MB at 2 MB/s, a pace the server keeps up with: more than the
  // slow follower's backlog (1 MiB) and socket hold, and far less than the
  // fast one reads.
  constexpr std::uint64_t kLines = 20000;
  StreamTally fast_tally;
  std::thread fast_reader([&] { fast_tally = follow_until(fast, kLines, 120s); });
  for (std::uint64_t i = 0; i < kLines; ++i) {
    stream.publish(numbered_line(i, 80));
    if (i % 100 == 99) std::this_thread::sleep_for(5ms);
  }
  fast_reader.join();
  EXPECT_TRUE(fast_tally.in_order);
  EXPECT_EQ(fast_tally.received, kLines) << fast_tally.dropped << " dropped";
  EXPECT_EQ(stream.stats().dropped, 0U) << "the server fell behind the producer";

  const StreamTally slow_tally = follow_until(slow, kLines, 60s);
  EXPECT_TRUE(slow_tally.in_order);
  EXPECT_EQ(slow_tally.received + slow_tally.dropped, kLines);
  EXPECT_GT(slow_tally.dropped, 0U);
  RecordProperty("slow_received", static_cast<int>(slow_tally.received));
}

TEST(LineBroadcast, KeepsLinesWholeAcrossTheRingsEndAndCountsWhatItCannotStore) {
  LineBroadcast stream("s", 4096);
  EXPECT_EQ(stream.capacity(), 4096U);
  stream.set_listening(true);
  std::vector<std::string> lines;
  std::uint64_t drops = 0;
  const auto drain = [&] {
    stream.drain([&](std::string_view line) { lines.emplace_back(line); }, [&](std::uint64_t n) { drops += n; });
  };
  // Lines of odd lengths go round the ring many times.
  std::vector<std::string> sent;
  for (int i = 0; i < 500; ++i) {
    std::string line = std::to_string(i) + ":" + std::string(static_cast<std::size_t>(i * 37 % 700), 'a' + i % 26);
    ASSERT_TRUE(stream.publish(line + "\n")) << i;
    sent.push_back(line);
    if (i % 3 == 2) drain();
  }
  drain();
  EXPECT_EQ(lines, sent);
  EXPECT_EQ(drops, 0U);

  // Full: what does not fit is dropped, counted, and reported in its place.
  lines.clear();
  int stored = 0;
  while (stream.publish(std::string(500, 'x'))) ++stored;  // ends with a drop
  EXPECT_GE(stored, 6);
  while (stream.publish("y")) ++stored;                  // the rest of the room; ends with a drop
  EXPECT_FALSE(stream.publish(std::string(5000, 'z')));  // longer than the ring: never fits
  drain();
  EXPECT_EQ(lines.size(), static_cast<std::size_t>(stored));
  EXPECT_EQ(drops, 3U);
  EXPECT_TRUE(stream.publish("after"));
  drain();
  EXPECT_EQ(lines.back(), "after");
  EXPECT_EQ(drops, 3U) << "a drop is reported once";
  EXPECT_EQ(stream.stats().dropped, 3U);
}

TEST(LineBroadcast, TwoThreadsAgreeOnEveryLine) {
  LineBroadcast stream("s", 8192);
  stream.set_listening(true);
  constexpr std::uint64_t kLines = 200000;
  std::atomic<bool> done{false};
  std::thread producer([&] {
    for (std::uint64_t i = 0; i < kLines; ++i) stream.publish(std::to_string(i) + std::string(i % 97, '.'));
    done = true;
  });
  std::uint64_t expected = 0;
  std::uint64_t received = 0;
  bool whole = true;
  const auto check = [&](std::string_view line) {
    const std::uint64_t seq = std::stoull(std::string(line.substr(0, line.find('.'))));
    whole = whole && seq == expected && line.size() == std::to_string(seq).size() + seq % 97;
    expected = seq + 1;
    ++received;
  };
  pollfd pfd{stream.wake_fd(), POLLIN, 0};
  while (!done || expected < kLines) {
    ::poll(&pfd, 1, 100);
    stream.drain(check, [&](std::uint64_t n) { expected += n; });
    if (done && stream.stats().published + stream.stats().dropped == kLines) {
      stream.drain(check, [&](std::uint64_t n) { expected += n; });
      break;
    }
  }
  producer.join();
  EXPECT_TRUE(whole);
  EXPECT_EQ(expected, kLines);
  EXPECT_EQ(received, stream.stats().published);
}

// ---------------------------------------------------------------- the client library

TEST_F(ControlServerTest, TheClientCallsAndNamesTheSocketWhenItCannotConnect) {
  start();
  ControlClient client(socket());
  json r = client.call({{"cmd", "add"}, {"a", 40}, {"b", 2}});
  EXPECT_EQ(r["sum"], 42);
  EXPECT_EQ(r["id"], 1);
  r = client.call({{"cmd", "refuse"}});
  EXPECT_EQ(r["ok"], false);
  EXPECT_EQ(r["id"], 2);

  const fs::path missing = dir_.path() / "missing.sock";
  try {
    ControlClient nobody(missing);
    FAIL() << "connected to nothing";
  } catch (const ControlClientError& e) {
    EXPECT_EQ(std::string(e.what()),
              "cannot connect to " + missing.string() + ": No such file or directory (is markerd running?)");
  }
}

TEST_F(ControlServerTest, TheClientReportsARequestTooLargeInMarkerdsWords) {
  EXPECT_EQ(ControlSettings{}.max_request_bytes, 1024U * 1024U) << "the default fits a 128 KiB plan, escaped";
  start();
  // Larger than the socket's buffers: markerd closes the connection while
  // the client is still sending.
  const json huge = {{"cmd", "echo"}, {"x", std::string(8 * 1024 * 1024, 'x')}};
  {
    ControlClient client(socket());
    const json reply = client.call(huge);
    EXPECT_EQ(reply, (json{{"ok", false}, {"error", kTooLarge}}));
  }
  {
    ControlClient client(socket());
    try {
      client.send(huge);
      FAIL() << "sent whole";
    } catch (const ControlClientError& e) {
      EXPECT_EQ(std::string(e.what()), socket().string() + ": markerd closed the connection: " + kTooLarge);
    }
  }
  // Just over the limit: sent whole, then refused.
  ControlClient client(socket());
  EXPECT_EQ(client.call({{"cmd", "echo"}, {"x", std::string(5000, 'x')}}), (json{{"ok", false}, {"error", kTooLarge}}));
}

TEST_F(ControlServerTest, ArgumentsAreReadByNameTypeAndRangeWithErrorsThatNameThem) {
  server_ = std::make_unique<ControlServer>(settings_);
  server_->register_command("set", [](const json& request) {
    expect_arguments(request, {"count", "gain", "axis", "label", "on"});
    json result = json::object();
    if (auto v = integer_argument(request, "count", {1, 100})) result["count"] = *v;
    if (auto v = number_argument(request, "gain", {0.0, 2.5, "dB"})) result["gain"] = *v;
    if (auto v = choice_argument(request, "axis", {"rail", "turntable", "both"})) result["axis"] = *v;
    if (auto v = string_argument(request, "label")) result["label"] = *v;
    if (auto v = bool_argument(request, "on")) result["on"] = *v;
    return result;
  });
  // A handler that reads an argument unchecked: still no nlohmann jargon.
  server_->register_command("raw", [](const json& request) {
    return json{{"reason", request.value("reason", std::string("none"))}};
  });
  server_->start();
  ControlClient client(socket());
  const auto error_for = [&](json request) {
    const json reply = client.call(std::move(request));
    EXPECT_EQ(reply.value("ok", true), false) << reply;
    return reply.value("error", std::string());
  };
  EXPECT_EQ(
      client.call(
          {{"cmd", "set"}, {"id", 1}, {"count", 3.0}, {"gain", 2.5}, {"axis", "rail"}, {"label", "x"}, {"on", true}}),
      (json{{"id", 1}, {"ok", true}, {"count", 3}, {"gain", 2.5}, {"axis", "rail"}, {"label", "x"}, {"on", true}}));
  EXPECT_EQ(error_for({{"cmd", "set"}, {"count", "3"}}),
            R"(argument 'count' must be a whole number, got a string ("3"))");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"count", 2.5}}), "argument 'count' must be a whole number, got a number (2.5)");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"count", 0}}), "argument 'count' must be from 1 to 100, got 0");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"count", 18446744073709551615ULL}}),
            "argument 'count' must be from 1 to 100, got 18446744073709551615");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"count", 1e300}}), "argument 'count' must be from 1 to 100, got 1e+300");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"gain", 3}}), "argument 'gain' must be from 0 to 2.5 dB, got 3");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"gain", json::array({1})}}),
            "argument 'gain' must be a number, got an array ([1])");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"axis", "rial"}}),
            "argument 'axis' must be rail, turntable or both, got 'rial'");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"axis", 1}}),
            "argument 'axis' must be rail, turntable or both, got a number (1)");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"label", std::string(100, 'y')}, {"on", "yes"}}),
            R"(argument 'on' must be true or false, got a string ("yes"))");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"label", json::object({{"text", std::string(100, 'y')}})}}),
            "argument 'label' must be a string, got an object ({\"text\":\"" + std::string(51, 'y') + "...)");
  EXPECT_EQ(error_for({{"cmd", "set"}, {"colour", "red"}}),
            "unknown argument 'colour' (for set: count, gain, axis, label, on)");
  EXPECT_EQ(error_for({{"cmd", "help"}, {"verbose", true}}), "unknown argument 'verbose': help takes none");
  EXPECT_EQ(error_for({{"cmd", "raw"}, {"reason", 42}}),
            "raw: an argument has the wrong type or value: type must be string, but is number");
}

// ---------------------------------------------------------------- markerctl

// Runs the real markerctl with MARKERD_SOCKET set to `socket_env` or unset;
// `uid` runs it as that user.
Outcome run_markerctl(const std::vector<std::string>& args, std::optional<uid_t> uid = {},
                      const std::optional<std::string>& socket_env = {}, std::chrono::seconds timeout = 60s) {
  std::vector<std::string> argv{MARKERCTL_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  markerd::test_support::ProcessOptions options;
  options.environment = {socket_env ? "MARKERD_SOCKET=" + *socket_env : "MARKERD_SOCKET"};
  options.user = uid;
  const Outcome outcome = markerd::test_support::run_program(argv, options, timeout);
  if (outcome.timed_out) ADD_FAILURE() << "markerctl did not finish within " << timeout.count() << " s";
  return outcome;
}

class MarkerctlAgainstTheServer : public ControlServerTest {
 protected:
  void SetUp() override {
    ControlServerTest::SetUp();
    // The markerctl a test runs as another user must reach the socket's directory.
    fs::permissions(dir_.path(), fs::perms::owner_all | fs::perms::group_exec | fs::perms::others_exec);
  }
};

TEST_F(MarkerctlAgainstTheServer, CallSendsACommandWithArgumentsAndPrintsTheReply) {
  start();
  Outcome r = run_markerctl({"call", "add", R"({"a": 2, "b": 40})", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json reply = json::parse(r.out);
  EXPECT_EQ(reply["ok"], true);
  EXPECT_EQ(reply["sum"], 42);
  EXPECT_EQ(r.err, "");

  r = run_markerctl({"call", "refuse", "--socket", socket().string()});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(json::parse(r.out)["ok"], false);
  EXPECT_EQ(r.err, "markerctl: call refuse: refused: not today\n");

  r = run_markerctl({"call", "add", "[1, 2]", "--socket", socket().string()});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: call: the arguments must be a JSON object, e.g. '{\"axis\": \"rail\"}', got '[1, 2]'\n");
  r = run_markerctl({"call", "add", "{a: 1}", "--socket", socket().string()});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_NE(r.err.find("markerctl: call: the arguments are not JSON:"), std::string::npos) << r.err;
}

TEST_F(MarkerctlAgainstTheServer, StatusPrintsTheDaemonsStatus) {
  server_ = std::make_unique<ControlServer>(settings_);
  server_->register_command("status", [](const json&) {
    return json{{"version", "0.1.0"}, {"capture", {{"frames", 120}, {"source", "sim"}}}, {"rig", nullptr}};
  });
  server_->start();
  Outcome r = run_markerctl({"status", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out, "capture:\n  frames: 120\n  source: sim\nrig: null\nversion: 0.1.0\n");
  r = run_markerctl({"status", "--json", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json status = json::parse(r.out);
  EXPECT_EQ(status["capture"]["frames"], 120);
  EXPECT_FALSE(status.contains("ok"));
  EXPECT_FALSE(status.contains("id"));
}

TEST_F(MarkerctlAgainstTheServer, DetectionsFollowsTheStreamForCountLines) {
  LineBroadcast& stream = make_stream();
  start({&stream});
  std::atomic<bool> stop{false};
  std::thread producer([&] {
    std::uint64_t seq = 0;
    while (!stop) {
      if (stream.listening()) stream.publish(numbered_line(seq++, 20));
      std::this_thread::sleep_for(1ms);
    }
  });
  const Outcome r = run_markerctl({"detections", "--count", "25", "--socket", socket().string()});
  stop = true;
  producer.join();
  ASSERT_EQ(r.code, 0) << r.describe();
  std::istringstream lines(r.out);
  std::string line;
  int count = 0;
  std::int64_t last = -1;
  while (std::getline(lines, line)) {
    const json j = json::parse(line);
    EXPECT_GT(j["seq"].get<std::int64_t>(), last);
    last = j["seq"].get<std::int64_t>();
    ++count;
  }
  EXPECT_EQ(count, 25);
}

TEST_F(MarkerctlAgainstTheServer, ErrorsNameTheSocketAndTheGroupThatGrantsAccess) {
  Outcome r = run_markerctl({"status", "--socket", socket().string()});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err, "markerctl: status: cannot connect to " + socket().string() +
                       ": No such file or directory (is markerd running?)\n");

  // MARKERD_SOCKET is the default for --socket.
  start();
  r = run_markerctl({"call", "add", R"({"a": 1, "b": 2})"}, {}, socket().string());
  EXPECT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(json::parse(r.out)["sum"], 3);

  if (::getuid() != 0) GTEST_SKIP() << "running a client as another user needs root";
  const ::group* g = ::getgrnam("nogroup");
  if (g == nullptr) GTEST_SKIP() << "no group 'nogroup' to give the socket to";
  server_->stop();
  settings_.group = g->gr_name;
  start();
  r = run_markerctl({"status", "--socket", socket().string()}, uid_t{65534 - 1});  // not in nogroup
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err, "markerctl: status: cannot connect to " + socket().string() +
                       ": Permission denied (the socket is open to the group 'nogroup': add your user to it, e.g. "
                       "sudo usermod -aG nogroup $USER, then log in again)\n");
}

}  // namespace
