// kill -9 of the real markerd at random moments of a sweep, for several
// seeds; each time markerd is started again with the same config and resumes
// the run from its journal by itself. Afterwards: every step recorded exactly
// once and in order, every line of the run's records and of the detection log
// whole, one "restarted" event per kill that cut the run off (at the step the
// records then held), and a summary equal to that of an uninterrupted run.
// The simulated camera has no noise, so frames at a point are identical and
// the summary is deterministic.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "markerd/daemon/control/control_client.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/summary.hpp"
#include "support/bluesky.hpp"
#include "support/child_process.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using daemon::ControlClient;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

using test_support::describe_wait_status;
using test_support::read_file;

// The sweep markerd runs and is killed in (tests/data/plans/kill.toml): five
// points (three distances facing the camera, two angles at 0.5 m), two
// measurements of four frames each: ten steps.
const std::string kPlan = read_file(test_support::kSourceTree / "tests/data/plans/kill.toml");

// A markerd child process (it does not outlive the guard, nor the test
// process); a failure when it cannot be started or stopped.
class MarkerdProcess {
 public:
  // Starts markerd --config `config`; its stdout and stderr are appended to `output`.
  void start(const fs::path& config, const fs::path& output) {
    ASSERT_NO_THROW(process_.start({MARKERD_PATH, "--config", config.string()}, output));
  }
  [[nodiscard]] bool running() const { return process_.running(); }
  [[nodiscard]] std::optional<int> exited() { return process_.exited(); }
  test_support::ChildProcess& process() { return process_; }
  int kill9() { return process_.kill9(); }

  // SIGTERM and reap, with a SIGKILL after `timeout`; the wait status.
  int terminate(std::chrono::milliseconds timeout) {
    if (const auto status = process_.terminate(timeout)) return *status;
    ADD_FAILURE() << "markerd did not stop within " << timeout.count() << " ms of SIGTERM";
    return process_.kill9();
  }

 private:
  test_support::ChildProcess process_;
};

// One markerd setup in a directory of its own: rig, config, logs/, state/.
struct Workspace {
  fs::path dir;

  explicit Workspace(fs::path directory) : dir(std::move(directory)) {
    fs::create_directories(dir / "logs");
    fs::create_directories(dir / "state");
    // The example rig, its simulated time 100 times faster than real time.
    test_support::write_sim_rig_config(dir / "rig.toml", 100.0);
    // Without noise, frames at a point are identical and the summary deterministic.
    test_support::TomlConfig::load(test_support::kSourceTree / "tests/data/markerd-sweep.toml")
        .set("camera.model", (test_support::kSourceTree / "config/cameras/thesis-640x480.yaml").string())
        .set("camera.sim.noise_sigma", 0.0)
        .write(config());
  }

  [[nodiscard]] fs::path config() const { return dir / "markerd.toml"; }
  [[nodiscard]] fs::path socket() const { return dir / "control.sock"; }
  [[nodiscard]] fs::path output() const { return dir / "markerd.out"; }
  [[nodiscard]] fs::path journal() const { return dir / "state/sweep-journal.json"; }
};

std::string describe(int status) { return describe_wait_status(status); }

// markerd's control socket, once it accepts; fails (and returns nothing)
// when markerd ends first or `timeout` passes.
std::unique_ptr<ControlClient> connect_control(MarkerdProcess& markerd, const Workspace& setup,
                                               std::chrono::milliseconds timeout = 30s) {
  try {
    return test_support::connect_control(markerd.process(), setup.socket(), setup.output(), timeout);
  } catch (const std::runtime_error& e) {
    ADD_FAILURE() << e.what();
    return nullptr;
  }
}

json sweep_status(ControlClient& client) {
  json reply = client.call({{"cmd", "sweep.status"}});
  EXPECT_EQ(reply.value("ok", false), true) << reply.dump();
  return reply;
}

// Polls sweep.status until `done(reply)` holds; the last reply, or nothing
// (a failure) when the run failed, was aborted, or `timeout` passed.
template <class Predicate>
std::optional<json> wait_status(ControlClient& client, Predicate done, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  json reply;
  for (;;) {
    reply = sweep_status(client);
    const std::string state = reply.value("state", "");
    if (state == "failed" || state == "aborted") {
      ADD_FAILURE() << "the run ended " << state << ": " << reply.dump();
      return std::nullopt;
    }
    if (done(reply)) return reply;
    if (Clock::now() > deadline) {
      ADD_FAILURE() << "timed out after " << timeout.count() << " ms; sweep.status: " << reply.dump();
      return std::nullopt;
    }
    std::this_thread::sleep_for(50ms);
  }
}

// Every line of `file` whole: the file ends with '\n' (or is empty) and every
// line is a JSON document.
void expect_whole_json_lines(const fs::path& file) {
  SCOPED_TRACE(file.string());
  const test_support::JsonLines lines = test_support::check_json_lines_file(file);
  EXPECT_TRUE(lines.ends_whole) << "the last line is torn: ..." << lines.tail.substr(0, 200);
  EXPECT_EQ(lines.objects, lines.lines);
  for (const std::string& problem : lines.problems) ADD_FAILURE() << problem;
}

std::size_t count_events(const sweep::RunRecords& records, std::string_view kind) {
  std::size_t n = 0;
  for (const auto& e : records.events) n += e.kind == kind ? 1 : 0;
  return n;
}

class SweepKillTest : public testing::Test {
 protected:
  void SetUp() override {
    // markerd locks its rig's devices (here the simulated rig's file): in a
    // directory of the test's own, not the machine's /run/lock/markerd.
    ::setenv("MARKERD_LOCK_DIR", (root_ / "locks").c_str(), 1);  // NOLINT(concurrency-mt-unsafe): no threads yet
  }

  static int failures() { return testing::UnitTest::GetInstance()->current_test_info()->result()->total_part_count(); }

  // Starts the plan; the run's directory, or empty (a failure).
  static fs::path start_sweep(ControlClient& client) {
    const json reply = client.call({{"cmd", "sweep.start"}, {"plan", kPlan}, {"source", "kill.toml"}});
    EXPECT_EQ(reply.value("ok", false), true) << reply.dump();
    if (!reply.value("ok", false)) return {};
    return reply.value("run_directory", "");
  }

  // Waits until the run has ended (done), then stops markerd with SIGTERM:
  // exit status 0.
  static void finish(MarkerdProcess& markerd, ControlClient& client, const fs::path& run) {
    // "idle": this markerd found the run already finished (its journal stale).
    const auto ended = wait_status(
        client,
        [&](const json& s) {
          const std::string state = s.value("state", "");
          return state == "done" || (state == "idle" && fs::exists(run / "stop.json"));
        },
        120s);
    EXPECT_TRUE(ended.has_value());
    const int status = markerd.terminate(30s);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << describe(status);
  }

  // The run's records after markerd stopped: complete, whole, done.
  static sweep::RunRecords check_records(const Workspace& setup, const fs::path& run) {
    sweep::RunRecords records = sweep::read_run(run);
    EXPECT_EQ(records.start.steps, 10U);
    EXPECT_EQ(records.points.size(), records.start.steps) << "every step recorded";
    for (std::size_t i = 0; i < records.points.size(); ++i) {
      EXPECT_EQ(records.points[i].step, i) << "every step exactly once, in order";
    }
    EXPECT_EQ(records.torn_lines, 0U);
    EXPECT_TRUE(records.stop.has_value());
    if (records.stop) {
      EXPECT_EQ(records.stop->status, sweep::ExitStatus::done) << records.stop->reason;
      EXPECT_EQ(records.stop->steps_done, records.start.steps);
    }
    EXPECT_EQ(count_events(records, "started"), 1U);
    // However often markerd was killed, Bluesky's documents are one run:
    // one start, its events numbered 1 to 10 once each, the stop counting them.
    const test_support::Outcome documents = test_support::check_bluesky_documents(run / "documents.jsonl");
    EXPECT_EQ(documents.code, 0) << documents.describe();
    EXPECT_FALSE(fs::exists(setup.journal())) << "a finished run's journal is removed";
    expect_whole_json_lines(run / "points.jsonl");
    expect_whole_json_lines(run / "events.jsonl");
    std::size_t logs = 0;
    for (const auto& entry : fs::directory_iterator(setup.dir / "logs")) {
      ++logs;
      expect_whole_json_lines(entry.path());
    }
    EXPECT_GE(logs, 1U);
    return records;
  }

  const test_support::TempDir temp_{"markerd-kill"};
  const fs::path root_ = temp_.path();
};

TEST_F(SweepKillTest, KilledAtRandomMomentsTheRunCompletesAsIfUninterrupted) {
  // The reference: one run, uninterrupted.
  std::string reference_csv;               // per point
  std::string reference_measurements_csv;  // per measurement (appendix C)
  {
    const Workspace setup(root_ / "reference");
    MarkerdProcess markerd;
    ASSERT_NO_FATAL_FAILURE(markerd.start(setup.config(), setup.output()));
    auto client = connect_control(markerd, setup);
    ASSERT_NE(client, nullptr);
    const fs::path run = start_sweep(*client);
    ASSERT_FALSE(run.empty());
    ASSERT_NO_FATAL_FAILURE(finish(markerd, *client, run));
    const sweep::RunRecords records = check_records(setup, run);
    ASSERT_FALSE(HasFailure()) << read_file(setup.output());
    EXPECT_EQ(count_events(records, "restarted"), 0U);
    const sweep::RunSummary summary = sweep::summarize(records);
    ASSERT_EQ(summary.status, "done");
    ASSERT_EQ(summary.points.size(), 5U);
    for (const auto& p : summary.points) {
      EXPECT_EQ(p.frames, 8) << "point " << p.point;
      EXPECT_EQ(p.detected, 8) << "point " << p.point;
    }
    reference_csv = sweep::points_csv(summary);
    reference_measurements_csv = sweep::translation_csv(summary);
  }

  std::size_t runs_cut_off = 0;
  for (const unsigned seed : {1U, 2U, 3U}) {
    SCOPED_TRACE(fmt::format("seed {}", seed));
    const int failures_before = failures();
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> pause_ms(300, 2500);
    const Workspace setup(root_ / fmt::format("seed{}", seed));
    MarkerdProcess markerd;
    ASSERT_NO_FATAL_FAILURE(markerd.start(setup.config(), setup.output()));
    auto client = connect_control(markerd, setup);
    ASSERT_NE(client, nullptr);
    const fs::path run = start_sweep(*client);
    ASSERT_FALSE(run.empty());

    // The step each restarted event must name: what the records held when
    // markerd was killed, for each kill that cut the run off.
    std::vector<std::size_t> cut_at;
    std::vector<std::string> moments;
    for (int k = 0; k < 2; ++k) {
      const auto pause = std::chrono::milliseconds(pause_ms(rng));
      std::this_thread::sleep_for(pause);
      client.reset();
      const int status = markerd.kill9();
      ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << describe(status) << "\n"
                                                                      << read_file(setup.output());
      const sweep::RunRecords at_kill = sweep::read_run(run);
      const bool cut_off = !at_kill.stop.has_value();
      moments.push_back(fmt::format("kill {} after {} ms: {} of {} steps recorded, {} torn line(s){}", k + 1,
                                    pause.count(), at_kill.points.size(), at_kill.start.steps, at_kill.torn_lines,
                                    cut_off ? "" : ", the run had ended"));
      if (cut_off) cut_at.push_back(at_kill.points.size());

      // Again, with the same config: it resumes the run from its journal.
      ASSERT_NO_FATAL_FAILURE(markerd.start(setup.config(), setup.output()));
      client = connect_control(markerd, setup);
      ASSERT_NE(client, nullptr);
      // Until the new markerd has taken the run up again (its "restarted"
      // event written), so that every later kill lands in the run itself.
      const auto resumed = wait_status(
          *client,
          [&](const json& s) {
            const std::string state = s.value("state", "");
            if (!cut_off) return state == "idle" || state == "done";
            return state != "idle" && s.value("run_directory", "") == run.string();
          },
          30s);
      ASSERT_TRUE(resumed.has_value()) << read_file(setup.output());
    }
    runs_cut_off += cut_at.size();
    SCOPED_TRACE(fmt::format("{}; {}", moments[0], moments[1]));
    fmt::print("seed {}: {}; {}\n", seed, moments[0], moments[1]);
    ASSERT_NO_FATAL_FAILURE(finish(markerd, *client, run));
    client.reset();

    const sweep::RunRecords records = check_records(setup, run);
    std::vector<std::size_t> restarted_at;
    for (const auto& e : records.events) {
      if (e.kind != "restarted") continue;
      restarted_at.push_back(e.step);
      // The records name the interruption: markerd ended without a word.
      EXPECT_NE(e.reason.find("kill -9"), std::string::npos) << e.reason;
    }
    EXPECT_EQ(restarted_at, cut_at) << "one restarted event per kill that cut the run off, at the step it was in";
    const sweep::RunSummary summary = sweep::summarize(records);
    EXPECT_EQ(summary.status, "done");
    EXPECT_EQ(sweep::points_csv(summary), reference_csv);
    EXPECT_EQ(sweep::translation_csv(summary), reference_measurements_csv);
    if (failures() != failures_before) ADD_FAILURE() << "markerd's output:\n" << read_file(setup.output());
  }
  // Kills that all came after the runs had ended would have shown nothing.
  EXPECT_GT(runs_cut_off, 0U) << "no kill cut a run off: the runs are too short for the kills' times";
}

}  // namespace
}  // namespace markerd
