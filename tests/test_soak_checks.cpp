// The soak driver's checks (tools/soak/), on files made here: a watched
// JSON-lines file whose logged bytes change or go, or whose lines do not
// parse, is reported; run records with a step twice, a step skipped, no
// stop record, an end other than the one markerd reported, or a kill
// without its restarted event are reported, and a clean run is not.

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "log_watch.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"
#include "run_checks.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd::soak {
namespace {

namespace fs = std::filesystem;

void append(const fs::path& file, const std::string& text) {
  std::ofstream out(file, std::ios::app | std::ios::binary);
  out << text;
}

std::string joined(const std::vector<std::string>& lines) {
  std::string all;
  for (const auto& l : lines) all += l + "\n";
  return all;
}

class SoakChecks : public testing::Test {
 protected:
  const test_support::TempDir temp_{"markerd-soak-checks"};
  const fs::path dir_ = temp_.path();
};

TEST_F(SoakChecks, AWatchedFileKeepsWhatWasLoggedAndEveryLineParses) {
  const fs::path file = dir_ / "log.jsonl";
  LogWatch watch;
  std::vector<std::string> problems;
  append(file, "{\"a\":1}\n{\"a\":2}\n{\"a\":");  // the third line being written
  watch.look(file, problems);
  EXPECT_TRUE(problems.empty()) << joined(problems);
  EXPECT_EQ(watch.totals().lines, 2U);
  append(file, "3}\n");
  watch.look(file, problems);
  EXPECT_TRUE(problems.empty()) << joined(problems);
  EXPECT_EQ(watch.totals().lines, 3U) << "each line counted once";

  append(file, "not json\n[1]\n");
  watch.look(file, problems);
  ASSERT_EQ(problems.size(), 2U) << joined(problems);
  EXPECT_NE(problems[0].find("is not whole JSON: not json"), std::string::npos) << problems[0];
  EXPECT_NE(problems[1].find("is not a JSON object: [1]"), std::string::npos) << problems[1];
  EXPECT_EQ(watch.totals().bad_lines, 2U);

  problems.clear();
  std::string text = test_support::read_file(file);
  text[5] = '9';  // {"a":1} -> {"a":9}: a logged byte changed
  test_support::write_file(file, text);
  watch.look(file, problems);
  ASSERT_GE(problems.size(), 1U);
  EXPECT_NE(problems[0].find("the 37 bytes already logged were changed"), std::string::npos) << problems[0];

  problems.clear();
  fs::resize_file(file, 4);  // logged lines cut
  watch.look(file, problems);
  ASSERT_GE(problems.size(), 1U);
  EXPECT_NE(problems[0].find("were cut"), std::string::npos) << problems[0];
}

TEST_F(SoakChecks, APartialLastLineIsAProblemOnlyWhereTheFileMustEndWhole) {
  const fs::path killed = dir_ / "killed.jsonl";
  const fs::path stopped = dir_ / "stopped.jsonl";
  append(killed, "{\"a\":1}\n{\"a\"");
  append(stopped, "{\"a\":1}\n{\"a\"");
  LogWatch watch;
  std::vector<std::string> problems;
  watch.retire(killed, false, problems);
  EXPECT_TRUE(problems.empty()) << joined(problems);
  EXPECT_EQ(watch.totals().torn_tails, 1U);
  EXPECT_FALSE(watch.watching(killed));
  watch.retire(stopped, true, problems);
  ASSERT_EQ(problems.size(), 1U);
  EXPECT_NE(problems[0].find("ends with a partial line"), std::string::npos) << problems[0];
}

constexpr const char* kPlan = R"(name = "t"
frames_per_point = 2
repeats = 1
[[grid]]
distance_m = [0.5, 1.0, 1.5]
angle_deg = [0.0]
)";

// A run directory with the given steps recorded, in that order, and a stop
// record when `stop` is given.
void make_run(const fs::path& directory, const std::vector<std::size_t>& recorded,
              std::optional<sweep::ExitStatus> stop, const std::string& reason = {},
              const std::vector<std::size_t>& restarted_at = {}) {
  sweep::RunStart start;
  start.run_id = directory.filename().string();
  start.time = std::chrono::system_clock::now();
  start.plan = sweep::parse_plan(kPlan, "t.toml");
  start.steps = sweep::plan_steps(start.plan).size();
  start.config = nlohmann::json::object();
  start.camera = nlohmann::json::object();
  start.rig = nlohmann::json::object();
  sweep::RunRecorder recorder = sweep::RunRecorder::create(directory, start);
  recorder.append_event({start.time, "started", {}, 0});
  for (const std::size_t at : restarted_at) recorder.append_event({start.time, "restarted", "again", at});
  for (const std::size_t step : recorded) {
    sweep::PointRecord p;
    p.step = step;
    p.frames.resize(2);
    p.started = p.finished = start.time;
    recorder.append_point(p);
  }
  if (stop) recorder.finish({start.time, *stop, reason, recorded.size(), "", ""});
}

TEST_F(SoakChecks, ACleanRunPassesAndEachKindOfLieIsReported) {
  make_run(dir_ / "a-clean", {0, 1, 2}, sweep::ExitStatus::done, {}, {1});
  make_run(dir_ / "b-twice", {0, 1, 1, 2}, sweep::ExitStatus::done);
  make_run(dir_ / "c-skipped", {0, 2}, sweep::ExitStatus::failed, "the disk is full");
  make_run(dir_ / "d-unended", {0}, std::nullopt);
  make_run(dir_ / "e-came-back", {0, 1, 2}, sweep::ExitStatus::done);
  make_run(dir_ / "f-unrestarted", {0, 1, 2}, sweep::ExitStatus::done);
  make_run(dir_ / "g-no-cause", {0}, sweep::ExitStatus::aborted, "");
  std::map<std::string, RunObservation> seen;
  seen["a-clean"].cut_at = {1};
  seen["a-clean"].ended_as = "done";
  seen["a-clean"].most_steps_seen = 3;
  seen["e-came-back"].ended_as = "failed";
  seen["e-came-back"].ended_reason = "no space";
  seen["f-unrestarted"].cut_at = {2};
  seen["f-unrestarted"].most_steps_seen = 3;

  std::vector<std::string> problems;
  const RunTotals totals = check_runs(dir_, seen, problems);
  const std::string all = joined(problems);
  EXPECT_EQ(all.find("run a-clean"), std::string::npos) << all;
  EXPECT_NE(all.find("run b-twice: step 1 recorded 2 times"), std::string::npos) << all;
  EXPECT_NE(all.find("run b-twice: done with 4 of 3 steps recorded"), std::string::npos) << all;
  EXPECT_NE(all.find("run c-skipped: step 1 has no record, though later steps have"), std::string::npos) << all;
  EXPECT_NE(all.find("run d-unended: no stop record"), std::string::npos) << all;
  EXPECT_NE(all.find("run e-came-back: markerd reported it failed (no space), but its stop record says done"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("run f-unrestarted: restarted events at steps [], the kills cut it off at steps [2]"),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("run g-no-cause: aborted without a cause"), std::string::npos) << all;
  EXPECT_EQ(totals.runs, 7U);
  EXPECT_EQ(totals.done, 4U);
  EXPECT_EQ(totals.failed, 1U);
  EXPECT_EQ(totals.aborted, 1U);
  EXPECT_EQ(totals.unended, 1U);
  EXPECT_EQ(totals.duplicates, 1U);
  EXPECT_EQ(totals.missing, 1U);
  EXPECT_EQ(totals.planned, 21U);
  EXPECT_EQ(totals.recorded, 3U + 4U + 2U + 1U + 3U + 3U + 1U);
  EXPECT_EQ(totals.failure_causes.at("the disk is full"), 1U);
}

// The soak's markerd must lock its rig in the soak's own directory
// (MARKERD_LOCK_DIR), never the machine's: no lock file there is a problem
// naming the device and the file; the lock markerd takes is none.
TEST_F(SoakChecks, MarkerdsDeviceLocksMustBeInTheSoaksOwnDirectory) {
  const fs::path rig = test_support::write_sim_rig_config(dir_ / "rig.toml", 20.0);
  const fs::path locks = dir_ / "locks";
  fs::create_directories(locks);
  const auto claims = rig::device_claims(rig::load_rig_config(rig));
  ASSERT_EQ(claims.size(), 1U) << "a simulated rig: its config file";
  const auto problem = lock_directory_problem(locks, rig);
  ASSERT_TRUE(problem.has_value());
  EXPECT_EQ(*problem, fmt::format("markerd did not lock {} in the soak's lock directory (no {}): it locks elsewhere, "
                                  "where the machine's own markerd or a markerctl rig session would meet it",
                                  claims.front().what, rig::DeviceLock::file_for(claims.front(), locks).string()));
  {
    const rig::DeviceLock lock(claims, locks);  // as the soak's markerd takes it
    EXPECT_EQ(lock_directory_problem(locks, rig), std::nullopt);
  }
  EXPECT_EQ(lock_directory_problem(locks, rig), std::nullopt) << "the file stays once the lock is let go";
  EXPECT_NE(lock_directory_problem(locks, dir_ / "no-rig.toml"), std::nullopt);
}

}  // namespace
}  // namespace markerd::soak
