// Sweeps in markerd, in-process, on the simulated rig and camera: a whole
// sweep against the simulated ground truth; pause, resume and abort; a camera
// unplugged and a drive alarm in the middle of a run, which suspend it and
// from which it resumes by itself; a run that is cut off and resumed from its
// journal by the next daemon. A run's records as Bluesky's documents,
// checked against the event model's schemas; records written before markerd
// gave them uids still read, report and resume.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <sys/resource.h>
#include <unistd.h>

#include <csignal>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <thread>

#include "markerd/base/utc_time.hpp"
#include "markerd/daemon/capture/sim_camera.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/detector/render.hpp"
#include "markerd/rig/sim_drive.hpp"
#include "markerd/sweep/documents.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/report.hpp"
#include "markerd/sweep/runner.hpp"
#include "markerd/sweep/summary.hpp"
#include "support/bluesky.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using daemon::Daemon;
using sweep::RunState;

using test_support::read_file;
using test_support::write_file;

// The sweep of these tests (tests/data/plans/small.toml): four points on the
// rail at angle 0, then two angles at 0.5 m; two measurements of four frames
// each, twelve steps. Tests check the line numbers of its errors: the file
// holds nothing but the plan.
const std::string kPlan = read_file(test_support::kSourceTree / "tests/data/plans/small.toml");

class SweepRunTest : public testing::Test {
 protected:
  void SetUp() override {
    test_support::prepare_markerd_dir(dir_);
    // The example rig with simulated time 100 times faster than real time:
    // homing and the longest move take well under a second.
    test_support::write_sim_rig_config(dir_ / "rig.toml", 100.0);
    test_support::TomlConfig::load(test_support::kSourceTree / "tests/data/markerd-sweep.toml")
        .set("camera.model", (test_support::kSourceTree / "config/cameras/thesis-640x480.yaml").string())
        .write(dir_ / "markerd.toml");
  }

  std::unique_ptr<Daemon> make_daemon() {
    auto d = std::make_unique<Daemon>(daemon::load_daemon_config(dir_ / "markerd.toml"));
    d->start();
    return d;
  }

  static sweep::SweepRunner& runner(Daemon& d) {
    EXPECT_NE(d.sweep(), nullptr);
    return *d.sweep();
  }

  // Waits until `predicate` holds, or fails the test after `timeout`.
  template <class Predicate>
  static bool eventually(Predicate predicate, std::chrono::milliseconds timeout = 30s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      if (predicate()) return true;
      std::this_thread::sleep_for(10ms);
    }
    return predicate();
  }

  static void expect_axes_stopped_and_disabled(Daemon& d) {
    const rig::RigSnapshot s = d.rig()->snapshot();
    EXPECT_EQ(s.rail.state, rig::AxisState::disabled);
    EXPECT_EQ(s.turntable.state, rig::AxisState::disabled);
    EXPECT_FALSE(s.rail.moving);
    EXPECT_FALSE(s.turntable.moving);
  }

  // Every step recorded once, in order.
  static void expect_every_step_once(const sweep::RunRecords& records) {
    ASSERT_EQ(records.points.size(), records.start.steps);
    for (std::size_t i = 0; i < records.points.size(); ++i) EXPECT_EQ(records.points[i].step, i);
    EXPECT_EQ(records.torn_lines, 0U);
  }

  static std::size_t count_events(const sweep::RunRecords& records, std::string_view kind) {
    std::size_t n = 0;
    for (const auto& e : records.events) n += e.kind == kind ? 1 : 0;
    return n;
  }

  const test_support::TempDir temp_{"markerd-sweep"};
  const fs::path dir_ = temp_.path();
};

std::vector<nlohmann::json> read_json_lines(const fs::path& path) {
  std::vector<nlohmann::json> lines;
  std::istringstream in(read_file(path));
  for (std::string line; std::getline(in, line);) lines.push_back(nlohmann::json::parse(line));
  return lines;
}

void write_json_lines(const fs::path& path, const std::vector<nlohmann::json>& lines) {
  std::string text;
  for (const auto& line : lines) text += line.dump() + "\n";
  write_file(path, text);
}

// A run's records as markerd wrote them before they were Bluesky's documents
// (record schema 1): no uids, no descriptor uid, no num_events, times as UTC
// text, exit status done/aborted/failed.
void rewrite_as_schema_1(const fs::path& run) {
  const auto iso = [](const nlohmann::json& seconds) {
    return format_utc(from_unix_seconds(seconds.get<double>()), UtcForm::milliseconds);
  };
  nlohmann::json start = nlohmann::json::parse(read_file(run / "start.json"));
  start["schema"] = 1;
  start.erase("uid");
  start.erase("descriptors");
  start["time"] = iso(start["time"]);
  write_file(run / "start.json", start.dump(2) + "\n");
  for (const char* file : {"points.jsonl", "events.jsonl"}) {
    std::vector<nlohmann::json> lines = read_json_lines(run / file);
    for (auto& line : lines) {
      line["schema"] = 1;
      line.erase("uid");
    }
    write_json_lines(run / file, lines);
  }
  if (fs::exists(run / "stop.json")) {
    nlohmann::json stop = nlohmann::json::parse(read_file(run / "stop.json"));
    stop["schema"] = 1;
    for (const char* key : {"uid", "run_start", "num_events"}) stop.erase(key);
    stop["time"] = iso(stop["time"]);
    const std::map<std::string, std::string> old_words{{"success", "done"}, {"abort", "aborted"}, {"fail", "failed"}};
    stop["exit_status"] = old_words.at(stop["exit_status"].get<std::string>());
    write_file(run / "stop.json", stop.dump(2) + "\n");
  }
  fs::remove(run / "documents.jsonl");
}

TEST_F(SweepRunTest, ASimulatedSweepMeasuresTheGroundTruth) {
  auto d = make_daemon();
  const fs::path run = runner(*d).start(sweep::parse_plan(kPlan, "small.toml"));
  EXPECT_EQ(runner(*d).wait_finished(120s), RunState::done) << runner(*d).progress().reason;
  expect_axes_stopped_and_disabled(*d);

  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::done);
  EXPECT_EQ(records.start.plan.name, "small");
  EXPECT_EQ(records.start.rig["rail"]["units_per_step"], 0.025);
  EXPECT_EQ(records.start.camera["model"]["width"], 640);
  for (const sweep::PointRecord& p : records.points) {
    SCOPED_TRACE(fmt::format("step {} at {} m, {} deg", p.step, p.distance_m, p.angle_deg));
    // The rig stood where the plan asked, and the truth says so.
    EXPECT_NEAR(p.truth_distance_m, p.distance_m, 1e-6);
    EXPECT_NEAR(p.truth_yaw_deg, p.angle_deg, 1e-6);
    ASSERT_EQ(p.frames.size(), 4U);
    double distance_error_sum_mm = 0;
    for (const sweep::FrameSample& f : p.frames) {
      EXPECT_TRUE(f.detected);
      ASSERT_TRUE(f.has_error);
      // Single noisy frames: the distance within 2%, the rotation of a
      // facing marker (weakly determined: its flip ambiguity) within 5 deg.
      // (The test renders at 2x2 supersampling, for speed: coarser edges
      // than markerd-sim.toml's 4x4, which bias a far marker's distance by
      // up to about 1%.)
      EXPECT_LT(std::abs(f.distance_error_mm), 20 * p.distance_m);
      EXPECT_LT(f.rotation_error_deg, 5.0);
      distance_error_sum_mm += f.distance_error_mm;
    }
    // A measurement, the mean of its frames: within 1.5% of the distance.
    EXPECT_LT(std::abs(distance_error_sum_mm / 4), 15 * p.distance_m);
  }
  EXPECT_EQ(count_events(records, "started"), 1U);
  EXPECT_EQ(count_events(records, "suspended"), 0U);

  // The summary against the simulated truth: every point detected, so the
  // range reaches the last facing point and the angles the last ones swept.
  const sweep::RunSummary summary = sweep::summarize(records);
  EXPECT_EQ(summary.status, "done");
  ASSERT_EQ(summary.points.size(), 6U);
  for (const sweep::PointSummary& p : summary.points) {
    SCOPED_TRACE(fmt::format("point {} at {} m, {} deg", p.point, p.distance_m, p.angle_deg));
    EXPECT_EQ(p.frames, 8);
    EXPECT_EQ(p.rate, 1.0);
    EXPECT_TRUE(p.reached);
    EXPECT_NEAR(p.tvec_m[2].mean, p.truth_tvec_m[2], 0.015 * p.distance_m);
    EXPECT_LT(std::abs(p.distance_error_pct.mean), 1.5);
    ASSERT_EQ(p.measurements.size(), 2U);
  }
  ASSERT_TRUE(summary.max_distance_m.has_value());
  EXPECT_DOUBLE_EQ(*summary.max_distance_m, 1.3);
  ASSERT_FALSE(summary.max_angle.empty());
  EXPECT_DOUBLE_EQ(summary.max_angle.front().distance_m, 0.5);
  ASSERT_TRUE(summary.max_angle.front().positive_deg.has_value());
  EXPECT_DOUBLE_EQ(*summary.max_angle.front().positive_deg, 40.0);
  ASSERT_TRUE(summary.median_distance_error_pct.has_value());
  EXPECT_LT(*summary.median_distance_error_pct, 0.75);
  EXPECT_FALSE(fs::exists(dir_ / "state/sweep-journal.json"));
  // markerd wrote the summary's tables when the run ended.
  EXPECT_TRUE(fs::exists(run / "report/report.md"));
  EXPECT_EQ(read_file(run / "report/summary.csv"), sweep::points_csv(summary));
}

TEST_F(SweepRunTest, PauseHoldsTheRunAndAbortLeavesTheAxesDisabled) {
  auto d = make_daemon();
  auto& r = runner(*d);
  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 2; }));
  r.pause();
  ASSERT_TRUE(eventually([&] { return r.progress().state == RunState::paused; }));
  const std::size_t held = r.progress().steps_done;
  std::this_thread::sleep_for(1s);
  EXPECT_EQ(r.progress().steps_done, held);  // nothing recorded while paused
  const rig::RigSnapshot s = d->rig()->snapshot();
  EXPECT_FALSE(s.rail.moving);
  EXPECT_FALSE(s.turntable.moving);
  EXPECT_THROW(r.pause(), sweep::SweepError);
  EXPECT_THROW(r.start(sweep::parse_plan(kPlan, "again.toml")), sweep::SweepError);

  r.resume();
  ASSERT_TRUE(eventually([&] { return r.progress().steps_done > held; }));
  r.abort("the operator needs the rig");
  EXPECT_EQ(r.wait_finished(10s), RunState::aborted);
  expect_axes_stopped_and_disabled(*d);

  const sweep::RunRecords records = sweep::read_run(run);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::aborted);
  EXPECT_EQ(records.stop->reason, "the operator needs the rig");
  EXPECT_EQ(records.stop->steps_done, records.points.size());
  EXPECT_EQ(count_events(records, "paused"), 1U);
  EXPECT_EQ(count_events(records, "resumed"), 1U);
  for (std::size_t i = 0; i < records.points.size(); ++i) EXPECT_EQ(records.points[i].step, i);
  EXPECT_THROW(r.resume(), sweep::SweepError);
}

TEST_F(SweepRunTest, ACameraUnpluggedMidRunSuspendsItAndItCompletesWhenTheCameraIsBack) {
  auto d = make_daemon();
  auto& r = runner(*d);
  auto* camera = dynamic_cast<daemon::SimCamera*>(&d->source());
  ASSERT_NE(camera, nullptr);
  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 3; }));
  camera->set_unplugged(true);
  ASSERT_TRUE(eventually([&] { return r.progress().state == RunState::suspended; }, 10s));
  EXPECT_NE(r.progress().reason.find("camera"), std::string::npos) << r.progress().reason;
  const std::size_t held = r.progress().steps_done;
  std::this_thread::sleep_for(1s);
  EXPECT_EQ(r.progress().state, RunState::suspended);
  EXPECT_EQ(r.progress().steps_done, held);
  camera->set_unplugged(false);
  EXPECT_EQ(r.wait_finished(120s), RunState::done) << r.progress().reason;

  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  ASSERT_GE(count_events(records, "suspended"), 1U);
  EXPECT_GE(count_events(records, "fault_cleared"), 1U);
  bool named = false;
  for (const auto& e : records.events)
    named |= e.kind == "suspended" && e.reason.find("unplugged") != std::string::npos;
  EXPECT_TRUE(named) << "the suspension's record names the cause";
  for (const auto& p : records.points) {
    for (const auto& f : p.frames) EXPECT_TRUE(f.detected) << "step " << p.step;
  }
}

TEST_F(SweepRunTest, ADriveAlarmMidRunSuspendsItAndItCompletesOnceTheAlarmIsReset) {
  auto d = make_daemon();
  auto& r = runner(*d);
  auto* rail = dynamic_cast<rig::SimDrive*>(&d->rig()->rail().drive());
  ASSERT_NE(rail, nullptr);
  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 3; }));
  rail->inject_alarm_at(0, "overcurrent (simulated)");  // in the past: at once
  ASSERT_TRUE(eventually([&] { return r.progress().state == RunState::suspended; }, 10s));
  EXPECT_NE(r.progress().reason.find("rail"), std::string::npos) << r.progress().reason;
  // The runner resets the alarm (after fault_retry_first), homes the rail
  // again (the open-loop stepper lost its reference) and goes on.
  EXPECT_EQ(r.wait_finished(120s), RunState::done) << r.progress().reason;

  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  bool named = false;
  for (const auto& e : records.events)
    named |= e.kind == "suspended" && e.reason.find("overcurrent") != std::string::npos;
  EXPECT_TRUE(named);
  EXPECT_GE(count_events(records, "fault_cleared"), 1U);
  for (const auto& p : records.points) EXPECT_NEAR(p.truth_distance_m, p.distance_m, 1e-6) << "step " << p.step;
}

TEST_F(SweepRunTest, AFaultThatOutlastsTheTimeoutFailsTheRunWithTheAxesStoppedAndDisabled) {
  auto d = make_daemon();
  auto& r = runner(*d);
  auto* rail = dynamic_cast<rig::SimDrive*>(&d->rig()->rail().drive());
  ASSERT_NE(rail, nullptr);
  std::string plan = kPlan;
  plan.replace(plan.find("fault_timeout_s = 60"), 20, "fault_timeout_s = 2");
  const fs::path run = r.start(sweep::parse_plan(plan, "small.toml"));
  ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 2; }));
  rail->set_communication_lost(true);  // the drive stops answering, for good
  // Suspended for the fault timeout (2 s), then failed: a test thread held
  // off the cores that long on a loaded machine sees only the failure.
  ASSERT_TRUE(eventually(
      [&] {
        const RunState state = r.progress().state;
        return state == RunState::suspended || state == RunState::failed;
      },
      10s));
  EXPECT_EQ(r.wait_finished(30s), RunState::failed);
  const std::string reason = r.progress().reason;
  EXPECT_NE(reason.find("rail"), std::string::npos) << reason;
  EXPECT_NE(reason.find("fault_timeout"), std::string::npos) << reason;

  // Stopped and without power: the turntable disabled, the rail (which no
  // longer answers) cut off by its emergency stop, the hard-wired enable.
  const rig::RigSnapshot s = d->rig()->snapshot();
  EXPECT_FALSE(s.rail.moving);
  EXPECT_EQ(s.turntable.state, rig::AxisState::disabled);
  rail->set_communication_lost(false);
  EXPECT_FALSE(rail->status().enabled);

  const sweep::RunRecords records = sweep::read_run(run);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::failed);
  EXPECT_EQ(records.stop->reason, reason);
  EXPECT_EQ(records.stop->steps_done, records.points.size());
  EXPECT_FALSE(fs::exists(dir_ / "state/sweep-journal.json"));
}

TEST_F(SweepRunTest, ARunCutOffIsResumedByTheNextDaemonAtTheStepItWasIn) {
  fs::path run;
  std::size_t done_before = 0;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 3; }));
    d->stop();  // as on SIGTERM: the journal stays
    done_before = sweep::read_run(run).points.size();
  }
  ASSERT_TRUE(fs::exists(dir_ / "state/sweep-journal.json"));
  // A journal write that a full disk cut off leaves an empty temporary
  // beside the journal: it is not the journal.
  write_file(dir_ / "state/sweep-journal.json.tmp", "");
  auto d = make_daemon();
  auto& r = runner(*d);
  EXPECT_EQ(r.progress().run_directory, run);
  EXPECT_EQ(r.wait_finished(120s), RunState::done) << r.progress().reason;
  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  ASSERT_GE(records.events.size(), 2U);
  EXPECT_EQ(count_events(records, "restarted"), 1U);
  // The records say what interrupted the run: markerd was stopped.
  EXPECT_EQ(count_events(records, "stopped"), 1U);
  for (const auto& e : records.events) {
    if (e.kind == "stopped") {
      EXPECT_EQ(e.step, done_before);
      EXPECT_NE(e.reason.find("markerd was stopped"), std::string::npos) << e.reason;
    }
    if (e.kind == "restarted") {
      EXPECT_EQ(e.step, done_before);
      EXPECT_NE(e.reason.find(fmt::format("markerd stopped at step {}", done_before)), std::string::npos) << e.reason;
    }
  }
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::done);
}

TEST_F(SweepRunTest, ARunMarkerdLeftWithoutAWordIsResumedAndItsRecordsSaySo) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 2; }));
    d->stop();
  }
  // What a kill -9 or a power cut leaves: the journal as it was while the
  // run went on, and a temporary cut short beside it.
  write_file(dir_ / "state/sweep-journal.json",
             nlohmann::json{{"run_directory", run.string()}, {"state", "running"}, {"paused", false}}.dump());
  write_file(dir_ / "state/sweep-journal.json.tmp", R"({"run_directory": "/va)");
  auto d = make_daemon();
  auto& r = runner(*d);
  EXPECT_EQ(r.progress().run_directory, run);
  EXPECT_EQ(r.wait_finished(120s), RunState::done) << r.progress().reason;
  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  ASSERT_EQ(count_events(records, "restarted"), 1U);
  for (const auto& e : records.events) {
    if (e.kind == "restarted") {
      EXPECT_NE(e.reason.find("kill -9"), std::string::npos) << e.reason;
    }
  }
}

// A failed run whose stop record a full disk kept off the disk: the journal
// says it failed, so no markerd resumes it, and once there is room its stop
// record says failed and why. The full disk: the temporaries that the
// records and the journal are written through are made /dev/full, where
// every write fails with ENOSPC.
TEST_F(SweepRunTest, AFailedRunWhoseStopRecordCouldNotBeWrittenIsNeverResumed) {
  fs::path run;
  std::string reason;
  std::size_t steps_done = 0;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    auto* rail = dynamic_cast<rig::SimDrive*>(&d->rig()->rail().drive());
    ASSERT_NE(rail, nullptr);
    std::string plan = kPlan;
    plan.replace(plan.find("fault_timeout_s = 60"), 20, "fault_timeout_s = 1");
    run = r.start(sweep::parse_plan(plan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 2; }));
    fs::create_symlink("/dev/full", run / "stop.json.tmp");
    fs::create_symlink("/dev/full", dir_ / "state/sweep-journal.json.tmp");
    rail->set_communication_lost(true);
    ASSERT_EQ(r.wait_finished(30s), RunState::failed);
    reason = r.progress().reason;
    steps_done = r.progress().steps_done;
    EXPECT_NE(r.progress().reason.find("stop record could not be written"), std::string::npos) << r.progress().reason;
    EXPECT_FALSE(fs::exists(run / "stop.json"));
    // The journal could not be replaced, so it was overwritten in place: it
    // says the run failed.
    const auto journal = nlohmann::json::parse(read_file(dir_ / "state/sweep-journal.json"));
    EXPECT_EQ(journal["state"], "failed") << journal.dump();
    EXPECT_EQ(journal["stop"]["exit_status"], "fail") << journal.dump();
    d->stop();
    rail->set_communication_lost(false);
  }
  // markerd starts again on a disk that is still full: the run is not
  // resumed, nothing moves, and the runner says how that run ended.
  fs::remove(dir_ / "state/sweep-journal.json.tmp");
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    EXPECT_EQ(r.progress().state, RunState::failed);
    std::this_thread::sleep_for(500ms);
    const rig::RigSnapshot s = d->rig()->snapshot();
    EXPECT_FALSE(s.rail.homed);
    EXPECT_FALSE(s.rail.moving);
    EXPECT_FALSE(fs::exists(run / "stop.json"));
    EXPECT_TRUE(fs::exists(dir_ / "state/sweep-journal.json"));
    // Nor does a new run take its journal away while it cannot be ended.
    try {
      (void)r.start(sweep::parse_plan(kPlan, "small.toml"));
      ADD_FAILURE() << "a new run replaced the journal of a run whose end is not recorded";
    } catch (const sweep::SweepError& e) {
      EXPECT_NE(std::string(e.what()).find("stop record still cannot be written"), std::string::npos) << e.what();
    }
  }
  // With room on the disk again the next markerd writes the stop record.
  fs::remove(run / "stop.json.tmp");
  auto d = make_daemon();
  auto& r = runner(*d);
  EXPECT_EQ(r.progress().state, RunState::failed);
  EXPECT_EQ(r.progress().run_directory, run);
  EXPECT_FALSE(fs::exists(dir_ / "state/sweep-journal.json"));
  const sweep::RunRecords records = sweep::read_run(run);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::failed);
  EXPECT_NE(records.stop->reason.find("fault_timeout"), std::string::npos) << records.stop->reason;
  EXPECT_NE(records.stop->reason.find("rail"), std::string::npos) << records.stop->reason;
  // The stop record starts with what the runner said when the run failed.
  const std::string failure = reason.substr(0, reason.find(" (its stop record"));
  EXPECT_EQ(records.stop->reason.rfind(failure, 0), 0U) << records.stop->reason << "\n" << failure;
  EXPECT_EQ(records.stop->steps_done, steps_done);
  EXPECT_EQ(records.points.size(), steps_done);
  EXPECT_EQ(count_events(records, "restarted"), 0U);
  EXPECT_FALSE(d->rig()->snapshot().rail.homed);
}

TEST_F(SweepRunTest, AnAbortedRunWhoseStopRecordCouldNotBeWrittenIsNeverResumed) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 1; }));
    fs::create_symlink("/dev/full", run / "stop.json.tmp");
    r.abort("the operator needs the rig");
    ASSERT_EQ(r.wait_finished(10s), RunState::aborted);
    EXPECT_FALSE(fs::exists(run / "stop.json"));
    EXPECT_EQ(nlohmann::json::parse(read_file(dir_ / "state/sweep-journal.json"))["state"], "aborted");
  }
  fs::remove(run / "stop.json.tmp");
  auto d = make_daemon();
  EXPECT_EQ(runner(*d).progress().state, RunState::aborted);
  const sweep::RunRecords records = sweep::read_run(run);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::aborted);
  EXPECT_EQ(records.stop->reason.rfind("the operator needs the rig", 0), 0U) << records.stop->reason;
  EXPECT_EQ(count_events(records, "restarted"), 0U);
  EXPECT_FALSE(fs::exists(dir_ / "state/sweep-journal.json"));
}

// When not even the journal can record the end, it is removed: the run is
// not resumed, and its records end without a stop record (incomplete).
TEST_F(SweepRunTest, ARunWhoseEndNothingCanRecordIsNotResumedEither) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 1; }));
    fs::create_symlink("/dev/full", run / "stop.json.tmp");
    fs::create_symlink("/dev/full", dir_ / "state/sweep-journal.json.tmp");
    // The journal itself a file no write reaches.
    const fs::path journal = dir_ / "state/sweep-journal.json";
    fs::remove(journal);
    fs::create_symlink("/dev/full", journal);
    r.abort("the operator needs the rig");
    ASSERT_EQ(r.wait_finished(10s), RunState::aborted);
    EXPECT_NE(r.progress().reason.find("so that the run is not resumed"), std::string::npos) << r.progress().reason;
    EXPECT_FALSE(fs::exists(journal) || fs::is_symlink(journal));
  }
  fs::remove(run / "stop.json.tmp");
  fs::remove(dir_ / "state/sweep-journal.json.tmp");
  auto d = make_daemon();
  EXPECT_EQ(runner(*d).progress().state, RunState::idle);
  std::this_thread::sleep_for(300ms);
  EXPECT_FALSE(d->rig()->snapshot().rail.homed);
  const sweep::RunRecords records = sweep::read_run(run);
  EXPECT_FALSE(records.stop.has_value());
  EXPECT_EQ(count_events(records, "restarted"), 0U);
}

// The simulated camera renders the config's 80 mm marker; a plan that says
// its marker is 160 mm gets poses for a 160 mm marker: twice as far.
TEST_F(SweepRunTest, ThePlansMarkerSizeIsWhatThePosesAreFor) {
  auto d = make_daemon();
  auto& r = runner(*d);
  std::string plan = kPlan;
  plan.replace(plan.find("size_m = 0.08"), 13, "size_m = 0.16");
  plan.replace(plan.find("repeats = 2"), 11, "repeats = 1");
  plan.replace(plan.find("[0.4, 0.7, 1.0, 1.3]"), 20, "[0.5]");
  plan.resize(plan.find("[[grid]]\nname = \"angle\""));
  const fs::path run = r.start(sweep::parse_plan(plan, "big-marker.toml"));
  ASSERT_EQ(r.wait_finished(60s), RunState::done) << r.progress().reason;
  const sweep::RunRecords records = sweep::read_run(run);
  ASSERT_EQ(records.points.size(), 1U);
  const sweep::PointRecord& p = records.points.front();
  ASSERT_EQ(p.frames.size(), 4U);
  for (const sweep::FrameSample& f : p.frames) {
    ASSERT_TRUE(f.detected);
    ASSERT_TRUE(f.has_pose);
    EXPECT_NEAR(f.tvec_m[2], 2 * p.truth_tvec_m[2], 0.03 * p.truth_tvec_m[2]);
    EXPECT_NEAR(f.distance_error_mm, 1000 * std::hypot(p.truth_tvec_m[0], p.truth_tvec_m[1], p.truth_tvec_m[2]),
                30 * p.distance_m);
  }
}

TEST_F(SweepRunTest, APlanForAFamilyTheDaemonDoesNotDetectIsRefusedAtCheckAndStart) {
  auto d = make_daemon();
  auto& r = runner(*d);
  std::string text = kPlan;
  text.replace(text.find("family = \"frame8\""), 17, "family = \"tag36h11\"");
  const sweep::SweepPlan plan = sweep::parse_plan(text, "tag.toml");
  for (const auto& attempt :
       {std::function<void()>([&] { (void)r.check(plan); }), std::function<void()>([&] { (void)r.start(plan); })}) {
    try {
      attempt();
      ADD_FAILURE() << "a tag36h11 plan passed on a frame8 markerd";
    } catch (const sweep::SweepError& e) {
      EXPECT_NE(std::string(e.what()).find("tag36h11"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("frame8"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(r.progress().state, RunState::idle);
  EXPECT_TRUE(fs::is_empty(dir_ / "state/runs"));

  daemon::ControlClient client(dir_ / "control.sock");
  for (const char* command : {"sweep.check", "sweep.start"}) {
    const nlohmann::json reply = client.call({{"cmd", command}, {"plan", text}, {"source", "tag.toml"}});
    EXPECT_FALSE(reply.value("ok", true)) << reply.dump();
    const std::string error = reply.value("error", std::string());
    EXPECT_NE(error.find("tag36h11"), std::string::npos) << reply.dump();
    EXPECT_NE(error.find("frame8"), std::string::npos) << reply.dump();
  }
}

// A socket plan on a markerd whose marker is on paper (and the reverse)
// would fill the report's socket column with paper figures.
TEST_F(SweepRunTest, APlanForAnotherMountingIsRefusedAtCheckAndStart) {
  auto d = make_daemon();  // markerd-sweep.toml says no mounting: paper
  auto& r = runner(*d);
  std::string text = kPlan;
  text.replace(text.find("size_m = 0.08\n"), 14, "size_m = 0.08\nmounting = \"socket\"\n");
  const sweep::SweepPlan plan = sweep::parse_plan(text, "socket.toml");
  for (const auto& attempt :
       {std::function<void()>([&] { (void)r.check(plan); }), std::function<void()>([&] { (void)r.start(plan); })}) {
    try {
      attempt();
      ADD_FAILURE() << "a socket plan passed on a markerd whose marker is on paper";
    } catch (const sweep::SweepError& e) {
      EXPECT_NE(std::string(e.what()).find("mounted \"socket\""), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("mounted \"paper\""), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(r.progress().state, RunState::idle);
  EXPECT_TRUE(fs::is_empty(dir_ / "state/runs"));

  daemon::ControlClient client(dir_ / "control.sock");
  for (const char* command : {"sweep.check", "sweep.start"}) {
    const nlohmann::json reply = client.call({{"cmd", command}, {"plan", text}, {"source", "socket.toml"}});
    EXPECT_FALSE(reply.value("ok", true)) << reply.dump();
    const std::string error = reply.value("error", std::string());
    EXPECT_NE(error.find("mounted \"socket\""), std::string::npos) << reply.dump();
    EXPECT_NE(error.find("mounted \"paper\""), std::string::npos) << reply.dump();
  }
  // A plan that does not say its mounting runs on any.
  EXPECT_NO_THROW((void)r.check(sweep::parse_plan(kPlan, "small.toml")));
}

// The start record says what the marker was mounted on, with the frame's
// dimensions, so that runs on paper and on a socket are told apart by their
// records alone; and the socket plan runs on a socket markerd.
TEST_F(SweepRunTest, TheStartRecordCarriesTheMarkersMounting) {
  std::string config = read_file(dir_ / "markerd.toml");
  config.replace(config.find("[marker]\n"), 9, "[marker]\nmounting = \"socket\"\n");
  write_file(dir_ / "markerd.toml", config);
  auto d = make_daemon();
  auto& r = runner(*d);
  std::string text = kPlan;
  text.replace(text.find("size_m = 0.08\n"), 14, "size_m = 0.08\nmounting = \"socket\"\n");
  const fs::path run = r.start(sweep::parse_plan(text, "socket.toml"));
  r.abort("the record is all this test needs");
  EXPECT_EQ(r.wait_finished(30s), RunState::aborted);
  const sweep::RunRecords records = sweep::read_run(run);
  const nlohmann::json& marker = records.start.marker;
  EXPECT_EQ(marker.value("mounting", ""), "socket") << marker.dump();
  EXPECT_EQ(marker.value("family", ""), "frame8") << marker.dump();
  EXPECT_EQ(marker.value("insert", ""), "socket") << marker.dump();
  ASSERT_TRUE(marker.contains("frame") && marker["frame"].is_object()) << marker.dump();
  EXPECT_DOUBLE_EQ(marker["frame"].value("outer_m", 0.0), detector::socket_frame().outer_m);
  EXPECT_DOUBLE_EQ(marker["frame"].value("height_m", 0.0), detector::socket_frame().height_m);
  EXPECT_DOUBLE_EQ(marker["frame"].value("reflectance", 0.0), 0.85);
  ASSERT_TRUE(records.start.camera.contains("scene")) << records.start.camera.dump();
  EXPECT_EQ(records.start.camera["scene"]["cover"], nlohmann::json::array());
  // Written to start.json, not only kept in memory.
  const nlohmann::json start = nlohmann::json::parse(read_file(run / "start.json"));
  EXPECT_EQ(start["marker"]["mounting"], "socket");
}

TEST_F(SweepRunTest, WrongTypedSweepArgumentsAreNamed) {
  auto d = make_daemon();
  daemon::ControlClient client(dir_ / "control.sock");
  const auto error_of = [&](const nlohmann::json& request) {
    const nlohmann::json reply = client.call(request);
    EXPECT_FALSE(reply.value("ok", true)) << reply.dump();
    return reply.value("error", std::string());
  };
  for (const char* command : {"sweep.check", "sweep.start"}) {
    const std::string source = error_of({{"cmd", command}, {"plan", kPlan}, {"source", 3}});
    EXPECT_NE(source.find("'source'"), std::string::npos) << source;
    EXPECT_EQ(source.find("json.exception"), std::string::npos) << source;
    const std::string plan = error_of({{"cmd", command}, {"plan", 3}});
    EXPECT_NE(plan.find("'plan'"), std::string::npos) << plan;
  }
  const fs::path run = runner(*d).start(sweep::parse_plan(kPlan, "small.toml"));
  const std::string reason = error_of({{"cmd", "sweep.abort"}, {"reason", 5}});
  EXPECT_NE(reason.find("'reason'"), std::string::npos) << reason;
  EXPECT_EQ(reason.find("json.exception"), std::string::npos) << reason;
  EXPECT_NE(runner(*d).progress().state, RunState::aborted);
  runner(*d).abort();
  EXPECT_EQ(runner(*d).wait_finished(10s), RunState::aborted);
}

TEST_F(SweepRunTest, AJournalNamingARunThatNeverStartedIsForgotten) {
  // markerd killed inside sweep.start, after the journal and before the
  // run's start record.
  fs::create_directories(dir_ / "state/runs/20261201T000000Z-small");
  write_file(dir_ / "state/sweep-journal.json", fmt::format(R"({{"run_directory": "{}", "paused": false}})",
                                                            (dir_ / "state/runs/20261201T000000Z-small").string()));
  auto d = make_daemon();
  EXPECT_EQ(runner(*d).progress().state, RunState::idle);
  EXPECT_FALSE(fs::exists(dir_ / "state/sweep-journal.json"));
  // And the runner takes a new run.
  const fs::path run = runner(*d).start(sweep::parse_plan(kPlan, "small.toml"));
  EXPECT_TRUE(fs::exists(run / "start.json"));
  runner(*d).abort();
  EXPECT_EQ(runner(*d).wait_finished(10s), RunState::aborted);
}

TEST_F(SweepRunTest, AJournalNamingAnEndedRunWhoseRecordsAreGoneDoesNotBlockANewRun) {
  auto d = make_daemon();
  auto& r = runner(*d);
  // A run that ended without its stop record, whose directory the operator
  // has since removed.
  const nlohmann::json stop{{"schema", 1},
                            {"time", "2026-12-01T00:00:00.000Z"},
                            {"exit_status", "failed"},
                            {"reason", "no space left"},
                            {"steps_done", 3}};
  write_file(
      dir_ / "state/sweep-journal.json",
      nlohmann::json{
          {"run_directory", (dir_ / "state/runs/20261201T000000Z-gone").string()}, {"state", "failed"}, {"stop", stop}}
          .dump());
  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  EXPECT_TRUE(fs::exists(run / "start.json"));
  EXPECT_EQ(nlohmann::json::parse(read_file(dir_ / "state/sweep-journal.json"))["run_directory"], run.string());
  r.abort();
  EXPECT_EQ(r.wait_finished(10s), RunState::aborted);
}

// A journal whose fields are not what markerd writes (edited, damaged) is
// refused naming the journal and the field, never with nlohmann's message;
// and it does not keep a new run from starting.
TEST_F(SweepRunTest, AJournalFieldOfTheWrongTypeIsNamed) {
  const fs::path journal = dir_ / "state/sweep-journal.json";
  write_file(journal, R"({"run_directory": 5, "state": "running", "paused": false})");
  auto d = make_daemon();
  auto& r = runner(*d);
  EXPECT_EQ(r.progress().state, RunState::idle);
  try {
    (void)r.resume_from_journal();
    ADD_FAILURE() << "the journal was read";
  } catch (const std::exception& e) {
    const std::string error = e.what();
    EXPECT_NE(error.find(journal.string()), std::string::npos) << error;
    EXPECT_NE(error.find(R"("run_directory" must be a string, got 5)"), std::string::npos) << error;
    EXPECT_EQ(error.find("json.exception"), std::string::npos) << error;
  }
  write_file(journal, R"({"run_directory": "x", "paused": "no"})");
  try {
    (void)r.resume_from_journal();
    ADD_FAILURE() << "the journal was read";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find(R"("paused" must be true or false, got "no")"), std::string::npos) << e.what();
  }
  // An ended run's journal with a stop record, its directory a number: as
  // unreadable, it does not block a new run.
  write_file(journal, R"({"run_directory": 5, "state": "failed", "stop": {"exit_status": "failed"}})");
  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  EXPECT_TRUE(fs::exists(run / "start.json"));
  r.abort();
  EXPECT_EQ(r.wait_finished(10s), RunState::aborted);
}

// A start that fails part way (here a file-size limit, as a full disk
// would) leaves no half-made run directory behind, nor a journal naming it:
// the run never started, and the client was told why.
TEST_F(SweepRunTest, AStartThatFailsPartWayLeavesNoHalfMadeRun) {
  auto d = make_daemon();
  auto& r = runner(*d);
  const auto files_under_state = [&] {
    std::vector<std::string> names;
    for (const auto& entry : fs::recursive_directory_iterator(dir_ / "state")) {
      names.push_back(fs::relative(entry.path(), dir_ / "state").string());
    }
    return names;
  };
  const auto before = files_under_state();
  // start.json (about 3 kB) cannot be written past 1 kB; the plan and the
  // journal fit. Writes past the limit fail with EFBIG instead of SIGXFSZ.
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  rlimit old_limit{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  rlimit limit = old_limit;
  limit.rlim_cur = 1000;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &limit), 0);
  std::string error;
  try {
    (void)r.start(sweep::parse_plan(kPlan, "small.toml"));
  } catch (const std::exception& e) {
    error = e.what();
  }
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &old_limit), 0);
  std::signal(SIGXFSZ, old_handler);
  EXPECT_NE(error.find("start.json.tmp"), std::string::npos) << error;
  EXPECT_EQ(files_under_state(), before);
  // Nor a runner that says a run is going: no later start could replace it.
  EXPECT_EQ(r.progress().state, RunState::idle);

  const fs::path run = r.start(sweep::parse_plan(kPlan, "small.toml"));
  EXPECT_TRUE(fs::exists(run / "start.json"));
  r.abort();
  EXPECT_EQ(r.wait_finished(10s), RunState::aborted);
}

// The records' times: a year outside what system_clock's nanoseconds hold
// overflowed into a wrong time (found by the fuzzer); now an error naming
// the file (and line) and the year. Fields of the wrong type name the field.
TEST_F(SweepRunTest, RecordsOutsideTheClocksYearsOrOfTheWrongTypeAreNamed) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 1; }));
    r.abort();
    EXPECT_EQ(r.wait_finished(10s), RunState::aborted);
  }
  const auto error_reading = [&] {
    try {
      (void)sweep::read_run(run);
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  const auto replace_in = [](const fs::path& path, const std::string& from, const std::string& to) {
    std::string text = read_file(path);
    const auto at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from << " in " << text;
    text.replace(at, from.size(), to);
    write_file(path, text);
  };
  ASSERT_EQ(error_reading(), "(no error)");
  // start.json's time is Bluesky's, UNIX seconds.
  const std::string bluesky_start = read_file(run / "start.json");
  const auto set_start_time = [&](const nlohmann::json& time) {
    nlohmann::json start = nlohmann::json::parse(bluesky_start);
    start["time"] = time;
    write_file(run / "start.json", start.dump(2));
  };
  set_start_time(1e10);
  EXPECT_EQ(error_reading(), (run / "start.json").string() +
                                 ": \"time\": 10000000000 seconds since 1970 is outside 1678 to 2261, the years "
                                 "markerd's clock holds");
  set_start_time("2026-12-01T06:15:00.000Z");
  EXPECT_EQ(error_reading(), (run / "start.json").string() +
                                 ": \"time\" must be seconds since 1970 (a number), got \"2026-12-01T06:15:00.000Z\"");
  set_start_time(-9.3e9);  // 1675
  EXPECT_NE(error_reading().find("is outside 1678 to 2261"), std::string::npos) << error_reading();
  write_file(run / "start.json", bluesky_start);
  ASSERT_EQ(error_reading(), "(no error)");
  // Records of schema 1 keep UTC text, with the years it can say.
  rewrite_as_schema_1(run);
  const std::string start = read_file(run / "start.json");
  const auto time_at = start.find("\"time\": \"");
  ASSERT_NE(time_at, std::string::npos) << start;
  const std::string time = start.substr(time_at + 9, 24);

  replace_in(run / "start.json", "\"time\": \"" + time.substr(0, 4), "\"time\": \"1013");
  EXPECT_EQ(error_reading(),
            fmt::format("{}: year 1013 is outside 1678 to 2261, the years markerd's clock holds: \"1013{}\"",
                        (run / "start.json").string(), time.substr(4)));
  replace_in(run / "start.json", "\"time\": \"1013", "\"time\": \"2262");
  EXPECT_NE(error_reading().find("year 2262 is outside 1678 to 2261"), std::string::npos) << error_reading();
  replace_in(run / "start.json", "\"time\": \"2262", "\"time\": \"1678");
  EXPECT_EQ(error_reading(), "(no error)");
  const std::string day = "\"time\": \"1678" + time.substr(4, 7);
  for (const std::string clock : {"25:00:00.000Z", "06:-15:00.000Z", "06:15:60.000Z", "06:15:00.-12Z"}) {
    write_file(run / "start.json", start);
    replace_in(run / "start.json", "\"time\": \"" + time, day + clock);
    EXPECT_NE(error_reading().find("not a time of day: \"1678" + time.substr(4, 7) + clock + "\""), std::string::npos)
        << error_reading();
  }
  write_file(run / "start.json", start);
  replace_in(run / "start.json", "\"run_id\": \"", "\"run_id\": 7, \"was\": \"");
  EXPECT_EQ(error_reading(), (run / "start.json").string() + ": \"run_id\" must be a string, got 7");
  write_file(run / "start.json", start);

  const std::string points = read_file(run / "points.jsonl");
  replace_in(run / "points.jsonl", "\"started\":\"", "\"started\":\"9999");
  EXPECT_NE(error_reading().find((run / "points.jsonl").string() + ":1: not a record: year 9999"), std::string::npos)
      << error_reading();
  write_file(run / "points.jsonl", points);
  replace_in(run / "points.jsonl", "\"repeat\":", "\"repeat\":\"one\",\"was\":");
  EXPECT_EQ(error_reading(),
            (run / "points.jsonl").string() + ":1: not a record: \"repeat\" must be a whole number, got \"one\"");
}

TEST_F(SweepRunTest, TheControlSocketsSweepCommands) {
  auto d = make_daemon();
  daemon::ControlClient client(dir_ / "control.sock");
  using nlohmann::json;

  json check = client.call({{"cmd", "sweep.check"}, {"plan", kPlan}, {"source", "small.toml"}});
  ASSERT_TRUE(check.value("ok", false)) << check.dump();
  EXPECT_EQ(check["points"], 6);
  EXPECT_EQ(check["steps"], 12);
  EXPECT_EQ(check["fits"], true);
  EXPECT_NE(check["text"].get<std::string>().find("6 points in 2 grids"), std::string::npos) << check.dump();

  // A plan with a mistake: the error names the plan's source, line and key.
  std::string bad = kPlan;
  bad.replace(bad.find("repeats = 2"), 11, "repeats = 0");
  json refused = client.call({{"cmd", "sweep.start"}, {"plan", bad}, {"source", "bad.toml"}});
  EXPECT_FALSE(refused.value("ok", true));
  EXPECT_EQ(refused.value("error", std::string()).rfind("bad.toml:3: repeats", 0), 0U) << refused.dump();
  json no_plan = client.call({{"cmd", "sweep.start"}});
  EXPECT_FALSE(no_plan.value("ok", true)) << no_plan.dump();
  json nothing_to_pause = client.call({{"cmd", "sweep.pause"}});
  EXPECT_FALSE(nothing_to_pause.value("ok", true));
  EXPECT_NE(nothing_to_pause.value("error", std::string()).find("idle"), std::string::npos) << nothing_to_pause.dump();

  json started = client.call({{"cmd", "sweep.start"}, {"plan", kPlan}, {"source", "small.toml"}});
  ASSERT_TRUE(started.value("ok", false)) << started.dump();
  EXPECT_EQ(started["steps"], 12);
  const fs::path run = started["run_directory"].get<std::string>();
  EXPECT_TRUE(fs::exists(run / "start.json"));
  ASSERT_TRUE(eventually([&] { return client.call({{"cmd", "sweep.status"}})["steps_done"].get<int>() >= 1; }));
  EXPECT_TRUE(client.call({{"cmd", "sweep.pause"}}).value("ok", false));
  ASSERT_TRUE(eventually([&] { return client.call({{"cmd", "sweep.status"}})["state"] == "paused"; }));
  EXPECT_TRUE(client.call({{"cmd", "sweep.resume"}}).value("ok", false));
  EXPECT_TRUE(client.call({{"cmd", "sweep.abort"}, {"reason", "end of the test"}}).value("ok", false));
  ASSERT_TRUE(eventually([&] { return client.call({{"cmd", "sweep.status"}})["state"] == "aborted"; }));
  const json status = client.call({{"cmd", "sweep.status"}});
  EXPECT_EQ(status["reason"], "end of the test");
  EXPECT_EQ(status["run_directory"], run.string());
  EXPECT_EQ(status["step"], nullptr);
  // markerd's status carries the run too.
  EXPECT_EQ(client.call({{"cmd", "status"}})["sweep"]["state"], "aborted");
}

TEST_F(SweepRunTest, APlanBeyondTheRigsLimitsIsRefusedBeforeAnythingMoves) {
  auto d = make_daemon();
  auto& r = runner(*d);
  std::string plan = kPlan;
  plan.replace(plan.find("1.3]"), 4, "3.3]");
  try {
    r.start(sweep::parse_plan(plan, "far.toml"));
    FAIL() << "a point beyond the rail was accepted";
  } catch (const sweep::SweepError& e) {
    EXPECT_NE(std::string(e.what()).find("3.3"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("rail"), std::string::npos) << e.what();
  }
  EXPECT_EQ(r.progress().state, RunState::idle);
  EXPECT_TRUE(fs::is_empty(dir_ / "state/runs"));
  const rig::RigSnapshot s = d->rig()->snapshot();
  EXPECT_FALSE(s.rail.moving);
}

// A run's documents.jsonl is Bluesky's event model: every document valid by
// the model's schemas, and together one run (check_documents.py). A run cut
// off and resumed is one run still: its start uid stays, its events count on.
TEST_F(SweepRunTest, ARunsDocumentsAreBlueskysEventModel) {
  fs::path run;
  std::string start_uid;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 3; }));
    d->stop();
    start_uid = nlohmann::json::parse(read_file(run / "start.json"))["uid"];
  }
  auto d = make_daemon();
  ASSERT_EQ(runner(*d).wait_finished(120s), RunState::done) << runner(*d).progress().reason;
  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  EXPECT_EQ(records.start.uid, start_uid);

  const fs::path documents = run / sweep::kDocumentsFile;
  ASSERT_TRUE(fs::exists(documents));
  const test_support::Outcome checked = test_support::check_bluesky_documents(documents);
  EXPECT_EQ(checked.code, 0) << checked.describe();
  EXPECT_NE(checked.out.find(fmt::format("{} documents, all valid", records.points.size() + 3)), std::string::npos)
      << checked.describe();

  const std::vector<nlohmann::json> lines = read_json_lines(documents);
  ASSERT_EQ(lines.size(), records.points.size() + 3);
  // start.json and stop.json are the documents themselves: one source.
  EXPECT_EQ(lines.front()[0], "start");
  EXPECT_EQ(lines.front()[1], nlohmann::json::parse(read_file(run / "start.json")));
  EXPECT_EQ(lines.front()[1]["uid"], start_uid);
  EXPECT_EQ(lines[1][0], "descriptor");
  EXPECT_EQ(lines[1][1]["name"], "primary");
  EXPECT_EQ(lines[1][1]["data_keys"]["rail"]["units"], "mm");
  EXPECT_EQ(lines.back()[0], "stop");
  EXPECT_EQ(lines.back()[1], nlohmann::json::parse(read_file(run / "stop.json")));
  EXPECT_EQ(lines.back()[1]["exit_status"], "success");
  EXPECT_EQ(lines.back()[1]["num_events"]["primary"], records.points.size());
  // An event per point, carrying the point's uid and its measurement.
  for (std::size_t i = 0; i < records.points.size(); ++i) {
    const sweep::PointRecord& p = records.points[i];
    const nlohmann::json& event = lines[i + 2];
    SCOPED_TRACE(event.dump());
    EXPECT_EQ(event[0], "event");
    EXPECT_EQ(event[1]["uid"], p.uid);
    EXPECT_EQ(event[1]["seq_num"], i + 1);
    EXPECT_EQ(event[1]["data"]["step"], p.step);
    EXPECT_DOUBLE_EQ(event[1]["data"]["truth_distance_m"].get<double>(), p.truth_distance_m);
    EXPECT_EQ(event[1]["data"]["frames"], 4);
    EXPECT_EQ(event[1]["data"]["detection_rate"], 1.0);
    EXPECT_LT(std::abs(event[1]["data"]["distance_error_mm"].get<double>()), 20 * p.distance_m);
  }
  // The documents made again are the same documents.
  EXPECT_EQ(sweep::documents_jsonl(sweep::run_documents(records)), read_file(documents));

  // The check fails what Bluesky's tools would refuse or misread.
  const fs::path broken = dir_ / "broken.jsonl";
  const auto check_broken = [&](const std::function<void(std::vector<nlohmann::json>&)>& breaking,
                                const std::string& problem) {
    std::vector<nlohmann::json> copy = lines;
    breaking(copy);
    write_json_lines(broken, copy);
    const test_support::Outcome outcome = test_support::check_bluesky_documents(broken);
    EXPECT_EQ(outcome.code, 1) << outcome.describe();
    EXPECT_NE(outcome.out.find(problem), std::string::npos) << problem << "\n" << outcome.describe();
  };
  check_broken([](auto& c) { c.back()[1]["exit_status"] = "done"; }, "stop exit_status: 'done' is not one of");
  check_broken([](auto& c) { c.front()[1].erase("uid"); }, "'uid' is a required property");
  check_broken([](auto& c) { c[2][1]["schema"] = 2; }, "Additional properties are not allowed ('schema'");
  check_broken([](auto& c) { c[2][1]["time"] = "2026-12-01T06:15:00.000Z"; }, "is not of type 'number'");
  check_broken([](auto& c) { c[1][1]["data_keys"]["rail"]["dtype"] = "float"; }, "'float' is not one of");
  check_broken([](auto& c) { c.front()[1]["config"]["a.b"] = 1; }, "'a.b' does not match");
  check_broken([](auto& c) { c[1][1]["run_start"] = "another run"; }, "descriptor names run_start another run");
  check_broken([](auto& c) { c[3][1]["descriptor"] = "nowhere"; }, "event names descriptor nowhere, none before it");
  check_broken([](auto& c) { c.erase(c.begin() + 4); }, "seq_num 4, expected 3");
  check_broken([](auto& c) { c.back()[1]["num_events"]["primary"] = 11; }, "num_events says 11 in 'primary'");
  check_broken([](auto& c) { c[3][1]["uid"] = c[2][1]["uid"]; }, "is line 3's too");
  check_broken([](auto& c) { c[3][1]["data"].erase("rail"); }, "the descriptor's are");
}

// A run recorded before markerd wrote Bluesky's documents (record schema 1:
// no uids, UTC text times, exit status "aborted") still reads, summarises
// and reports; its documents are refused, naming why.
TEST_F(SweepRunTest, AnEndedRunRecordedBeforeUidsStillReports) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 2; }));
    r.abort("enough");
    ASSERT_EQ(r.wait_finished(10s), RunState::aborted);
  }
  // An aborted run's documents say so in Bluesky's word.
  const test_support::Outcome checked = test_support::check_bluesky_documents(run / sweep::kDocumentsFile);
  EXPECT_EQ(checked.code, 0) << checked.describe();
  EXPECT_EQ(read_json_lines(run / sweep::kDocumentsFile).back()[1]["exit_status"], "abort");

  const sweep::RunRecords before = sweep::read_run(run);
  rewrite_as_schema_1(run);
  ASSERT_EQ(nlohmann::json::parse(read_file(run / "stop.json"))["exit_status"], "aborted");
  const sweep::RunRecords records = sweep::read_run(run);
  EXPECT_TRUE(records.start.uid.empty());
  EXPECT_EQ(records.start.time, std::chrono::floor<std::chrono::milliseconds>(before.start.time));
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::aborted);
  EXPECT_EQ(records.stop->reason, "enough");
  EXPECT_EQ(records.points.size(), before.points.size());
  EXPECT_EQ(sweep::summarize(records).status, "aborted");
  sweep::ReportOptions options;
  options.output_directory = dir_ / "report";
  options.plots = false;
  (void)sweep::write_report({records}, options);
  EXPECT_NE(read_file(dir_ / "report/report.md").find("aborted: enough"), std::string::npos);
  try {
    (void)sweep::run_documents(records);
    ADD_FAILURE() << "documents made of records without uids";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("start.json has no uid"), std::string::npos) << e.what();
  }
  // Every old exit status reads as the new one.
  for (const auto& [old_word, status] :
       std::map<std::string, sweep::ExitStatus>{{"done", sweep::ExitStatus::done},
                                                {"aborted", sweep::ExitStatus::aborted},
                                                {"failed", sweep::ExitStatus::failed}}) {
    EXPECT_EQ(
        sweep::stop_from_json({{"schema", 1}, {"time", "2026-12-01T06:15:00.000Z"}, {"exit_status", old_word}}).status,
        status);
  }
}

// A run cut off while markerd wrote schema 1 records, resumed by this
// markerd: it goes on to its end, its stop record in Bluesky's words, its
// start record as it was (it has no uid to keep), and no documents.jsonl.
TEST_F(SweepRunTest, ARunRecordedBeforeUidsIsResumed) {
  fs::path run;
  {
    auto d = make_daemon();
    auto& r = runner(*d);
    run = r.start(sweep::parse_plan(kPlan, "small.toml"));
    ASSERT_TRUE(eventually([&] { return r.progress().steps_done >= 3; }));
    d->stop();
  }
  rewrite_as_schema_1(run);
  const std::string old_start = read_file(run / "start.json");
  const std::size_t old_points = sweep::read_run(run).points.size();
  auto d = make_daemon();
  ASSERT_EQ(runner(*d).wait_finished(120s), RunState::done) << runner(*d).progress().reason;
  const sweep::RunRecords records = sweep::read_run(run);
  expect_every_step_once(records);
  EXPECT_EQ(read_file(run / "start.json"), old_start);
  ASSERT_TRUE(records.stop.has_value());
  EXPECT_EQ(records.stop->status, sweep::ExitStatus::done);
  const nlohmann::json stop = nlohmann::json::parse(read_file(run / "stop.json"));
  EXPECT_EQ(stop["exit_status"], "success");
  EXPECT_FALSE(stop.contains("run_start")) << stop.dump();
  for (std::size_t i = 0; i < records.points.size(); ++i) EXPECT_EQ(records.points[i].uid.empty(), i < old_points);
  EXPECT_FALSE(fs::exists(run / sweep::kDocumentsFile));
  EXPECT_TRUE(fs::exists(run / "report/report.md"));
}

}  // namespace
}  // namespace markerd
