// The control socket's server in-process, over a socket in a temporary
// directory: the protocol (ids, errors that leave the connection usable,
// lines split and joined across writes, requests too long, idle and surplus
// connections, the emergency stop that always gets through) and the socket
// file (mode, group, a stale socket replaced, a live one refused, stop() with
// clients connected). Streams, the client library and markerctl are in
// test_control_streams.cpp.

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

#include "control_server_fixture.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using namespace markerd::daemon;
using namespace markerd::daemon::control_test;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using markerd::test_support::Outcome;
using markerd::test_support::TempDir;

namespace {

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

}  // namespace
