// The control server's streams and clients: the line broadcast and its
// followers (order, drops announced exactly, a producer that never waits),
// the client library, and the real markerctl binary (MARKERCTL_PATH) against
// an in-process server.

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
#include "support/tmux.hpp"

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
// `input` is its standard input (else /dev/null).
Outcome run_markerctl(const std::vector<std::string>& args, std::optional<uid_t> uid = {},
                      const std::optional<std::string>& socket_env = {}, std::chrono::seconds timeout = 60s,
                      const std::optional<fs::path>& input = {}) {
  std::vector<std::string> argv{MARKERCTL_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  markerd::test_support::ProcessOptions options;
  options.environment = {socket_env ? "MARKERD_SOCKET=" + *socket_env : "MARKERD_SOCKET"};
  options.user = uid;
  options.input = input;
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

TEST_F(MarkerctlAgainstTheServer, CallReadsItsArgumentsFromStandardInput) {
  start();
  const fs::path arguments = dir_.path() / "arguments.json";
  {
    std::ofstream out(arguments);
    out << R"({"a": 2, "b": 40})" << '\n';
  }
  const Outcome r = run_markerctl({"call", "add", "-", "--socket", socket().string()}, {}, {}, 60s, arguments);
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(json::parse(r.out)["sum"], 42) << r.out;
}

// --follow --json: sweep.status's reply a line each time it changes, to the
// run's end (JSON Lines), and nothing that is not JSON.
TEST_F(MarkerctlAgainstTheServer, SweepStatusFollowJsonPrintsOneObjectALine) {
  server_ = std::make_unique<ControlServer>(settings_);
  auto calls = std::make_shared<std::atomic<int>>(0);
  server_->register_command("sweep.status", [calls](const json&) {
    const int n = ++*calls;
    const std::size_t done = n >= 4 ? 3 : static_cast<std::size_t>(n - 1);
    return json{{"state", n >= 4 ? "done" : "running"},
                {"run_id", "R1"},
                {"run_directory", "/runs/R1"},
                {"steps_done", done},
                {"steps_total", 3},
                {"phase", "collecting"}};
  });
  server_->start();
  const Outcome r = run_markerctl({"sweep", "status", "--follow", "--json", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  std::istringstream lines(r.out);
  std::string line;
  std::vector<json> objects;
  while (std::getline(lines, line)) objects.push_back(json::parse(line));  // throws on a line that is not JSON
  ASSERT_EQ(objects.size(), 4u) << r.out;
  for (std::size_t i = 0; i < objects.size(); ++i) EXPECT_EQ(objects[i]["steps_done"], std::min<std::size_t>(i, 3));
  EXPECT_EQ(objects.back()["state"], "done");
}

// The sweep's progress line on an 80-column terminal, as the user follows a
// run: whole it is wider than that (about 100 columns), so the bar narrows
// and the rate and the phase are left out, keeping the steps, the point and
// the time left; each redraw replaces the line instead of leaving a stale
// row.
TEST_F(MarkerctlAgainstTheServer, SweepProgressFitsAnEightyColumnTerminal) {
  server_ = std::make_unique<ControlServer>(settings_);
  auto calls = std::make_shared<std::atomic<int>>(0);
  static constexpr int kSteps = 30;
  server_->register_command("sweep.status", [calls](const json&) {
    const int n = std::min(++*calls, kSteps);
    return json{{"state", n == kSteps ? "done" : "running"},
                {"run_id", "20261201T071545Z-thesis"},
                {"run_directory", "/var/lib/markerd/runs/20261201T071545Z-thesis"},
                {"steps_done", n},
                {"steps_total", kSteps},
                {"step", {{"distance_m", 0.95}, {"angle_deg", 2.5 * n}, {"repeat", 2}}},
                {"phase", "collecting"},
                {"frames_collected", n % 6},
                {"frames_per_point", 6},
                {"last_rate", 1.0},
                {"remaining_s", 130.0 - n}};
  });
  server_->start();
  std::unique_ptr<markerd::test_support::TmuxScreen> screen;
  ASSERT_NO_THROW(
      screen = std::make_unique<markerd::test_support::TmuxScreen>(
          std::vector<std::string>{MARKERCTL_PATH, "sweep", "status", "--follow", "--socket", socket().string()},
          std::vector<std::string>{}, 80, 24, dir_.path()));
  // While it runs: the steps done, the point and the time left are there.
  ASSERT_TRUE(screen->wait_for(" left")) << screen->text();
  {
    std::string live;
    for (const std::string& line : screen->lines()) {
      if (line.find("[#") != std::string::npos || line.find("[-") != std::string::npos) live = line;
    }
    EXPECT_NE(live.find("/30"), std::string::npos) << live;
    EXPECT_NE(live.find("running  0.95 m "), std::string::npos) << live;
    EXPECT_NE(live.find(" deg #3  about "), std::string::npos) << live;
    EXPECT_EQ(live.find("rate"), std::string::npos) << "the rate is left out first: " << live;
    EXPECT_LE(live.size(), 79U) << live;
  }
  ASSERT_TRUE(screen->wait_for("[exit 0]")) << screen->text();
  const auto lines = screen->lines();
  int bars = 0;
  for (const std::string& line : lines) {
    EXPECT_LE(line.size(), 80u) << "a line wider than the terminal:\n" << line << "\nscreen:\n" << screen->text();
    if (line.find("[#") != std::string::npos) ++bars;
  }
  EXPECT_EQ(bars, 1) << "the progress line once, its last state kept:\n" << screen->text();
  EXPECT_NE(screen->text().find("30/30"), std::string::npos) << screen->text();
  EXPECT_NE(screen->text().find("run 20261201T071545Z-thesis: done\nrecords in "), std::string::npos) << screen->text();
  EXPECT_GE(calls->load(), kSteps) << "followed to the end";
}

TEST_F(MarkerctlAgainstTheServer, StatusPrintsTheDaemonsStatus) {
  server_ = std::make_unique<ControlServer>(settings_);
  // markerd's status document as daemon_status.cpp makes it, in part (a
  // summary must take a document without some parts), with a running sweep.
  server_->register_command("status", [](const json&) {
    return json::parse(R"({"responsive": true,
      "camera": {"state": "streaming", "source": "sim 640x480@30", "frames": 1200, "corrupt": 0,
                 "last_frame_age_ms": 12.5, "last_error": null, "fps": 29.97},
      "pipeline": {"dropped": 3, "detect": {"in": 1200, "out": 1197, "dropped": 0, "failed": 0},
                   "latency": {"detect": {"p50_ms": 2.84, "p99_ms": 3.71}}, "workers": 2, "policy": "live",
                   "detect_fps": 29.5},
      "log": {"file": "/var/log/markerd/detections-R-000.jsonl", "lines": 1197, "lines_lost": 0, "last_error": null},
      "rig": {"rail": {"position": 250.0, "unit": "mm", "state": "idle", "homed": true, "settled": true,
                       "fault": null},
              "turntable": {"position": 30.0, "unit": "deg", "state": "moving", "homed": true, "settled": false,
                            "fault": null},
              "ground_truth": {"distance_m": 0.55, "yaw_deg": 30.0}},
      "sweep": {"state": "running", "run_id": "R", "steps_done": 6, "steps_total": 24, "phase": "moving",
                "step": {"distance_m": 0.5, "angle_deg": 30.0, "repeat": 0}, "last_rate": 1.0,
                "remaining_s": 130.0},
      "control": {"socket": "/run/markerd/control.sock", "clients": 1},
      "status": "camera sim 640x480@30: streaming, 1200 frames, 3 dropped"})");
  });
  server_->start();
  Outcome r = run_markerctl({"status", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out,
            "markerd    responsive\n"
            "camera     streaming, sim 640x480@30; 30.0 fps, 1200 frames\n"
            "detector   29.5 fps, 1197 frames, 0 failed; 2.8 ms p50, 3.7 ms p99\n"
            "pipeline   live, 2 workers; 3 dropped\n"
            "log        /var/log/markerd/detections-R-000.jsonl; 1197 lines\n"
            "rail       250.000 mm, idle, homed, settled\n"
            "turntable  30.000 deg, moving, homed\n"
            "truth      distance 0.5500 m, yaw 30.000 deg\n"
            "sweep      run R\n"
            "           [##--------]    6/24   running  0.50 m 30.0 deg #1  about 2m10s left\n"
            "control    /run/markerd/control.sock, 1 client\n");
  // One screen at 80 columns: no line wraps.
  std::istringstream lines(r.out);
  for (std::string line; std::getline(lines, line);) EXPECT_LE(line.size(), 80u) << line;

  r = run_markerctl({"status", "--json", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json status = json::parse(r.out);
  EXPECT_EQ(status["camera"]["frames"], 1200);
  EXPECT_EQ(status["pipeline"]["latency"]["detect"]["p99_ms"], 3.71) << "everything, as markerd sent it";
  EXPECT_FALSE(status.contains("ok"));
  EXPECT_FALSE(status.contains("id"));
}

// A camera whose frames stopped: its rate falls to 0 and the last frame's
// age is named; counts agree with their nouns; a status from a markerd
// that measures no rates shows "?" where they would be.
TEST_F(MarkerctlAgainstTheServer, StatusSaysWhenTheFramesStoppedAndCountsInWords) {
  server_ = std::make_unique<ControlServer>(settings_);
  auto calls = std::make_shared<std::atomic<int>>(0);
  server_->register_command("status", [calls](const json&) {
    json s = json::parse(R"({"responsive": true,
      "camera": {"state": "streaming", "source": "v4l2 /dev/video0", "frames": 5, "last_frame_age_ms": 3250.0,
                 "fps": 0.0},
      "pipeline": {"dropped": 0, "detect": {"out": 5, "failed": 0}, "detect_fps": 0.0,
                   "latency": {"detect": {"p50_ms": 2.0, "p99_ms": 2.0}}, "workers": 1, "policy": "lossless"},
      "control": {"socket": "/run/markerd/control.sock", "clients": 2}})");
    if (++*calls > 1) {
      s["camera"].erase("fps");
      s["pipeline"].erase("detect_fps");
    }
    return s;
  });
  server_->start();
  Outcome r = run_markerctl({"status", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NE(r.out.find("camera     streaming, v4l2 /dev/video0; 0.0 fps, 5 frames, last frame 3.2 s ago\n"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("detector   0.0 fps, 5 frames, 0 failed;"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pipeline   lossless, 1 worker; 0 dropped\n"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("control    /run/markerd/control.sock, 2 clients\n"), std::string::npos) << r.out;

  r = run_markerctl({"status", "--socket", socket().string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NE(r.out.find("camera     streaming, v4l2 /dev/video0; ? fps, 5 frames,"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("detector   ? fps, 5 frames,"), std::string::npos) << r.out;
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
