// The rig calibrates itself, end to end on the simulated rig: the simulated
// world stands where [rig.sim.geometry] puts it (d0 12 mm further, yaw0 2
// degrees and the marker 5 mm in front of the turntable axis), while the
// rig config states rig-sim.toml's own, wrong, geometry. markerd sweeps a
// short calibration plan; `markerctl calibrate --rig RUN` recovers the true
// values within their stated uncertainty and writes the camera model and
// the geometry's calibration file; a later run whose rig config names that
// file measures the marker with a smaller pose error than the first.

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/runner.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

// Where the simulated world really is: rig-sim.toml states d0 300 mm, yaw0
// 0 and no marker offset.
constexpr double kTrueD0 = 312.0;
constexpr double kTrueYaw0 = 2.0;
constexpr double kTrueOffsetNormal = 5.0;

// Three distances by five angles, three frames each: a quick run that still
// turns the turntable both ways and moves the rail by half a metre.
constexpr const char* kPlan = R"(name = "calibrate-rig-short"
frames_per_point = 3
repeats = 1
settle_s = 0.1
point_timeout_s = 20

[marker]
family = "frame8"
id = 165
size_m = 0.08

[[grid]]
name = "calibration"
distance_m = [0.35, 0.55, 0.85]
angle_deg = [-50, -25, 0, 25, 50]
order = "snake"
)";

class RigCalibrationRun : public testing::Test {
 protected:
  void SetUp() override {
    test_support::prepare_markerd_dir(dir_);
    test_support::write_sim_rig_config(dir_ / "rig.toml", 100.0);
    rig_text_ = test_support::read_file(dir_ / "rig.toml") +
                fmt::format("\n[rig.sim.geometry]\nd0_mm = {}\nyaw0_deg = {}\nmarker_offset_normal_mm = {}\n", kTrueD0,
                            kTrueYaw0, kTrueOffsetNormal);
    test_support::write_file(dir_ / "rig.toml", rig_text_);
    test_support::TomlConfig::load(test_support::kSourceTree / "tests/data/markerd-sweep.toml")
        .set("camera.model", (test_support::kSourceTree / "config/cameras/thesis-640x480.yaml").string())
        // markerd-sim.toml's 4x4 samples per pixel: the tests' usual 2x2
        // renders edges coarse enough to bias the corners by hundredths of a
        // pixel from view to view, a bias the fit then finds as a tenth of a
        // millimetre of marker offset.
        .set("camera.sim.supersample", 4)
        .write(dir_ / "markerd.toml");
  }

  // A run of the plan with markerd's config as it is now; its records.
  sweep::RunRecords sweep_once() {
    daemon::Daemon d(daemon::load_daemon_config(dir_ / "markerd.toml"));
    d.start();
    EXPECT_NE(d.sweep(), nullptr);
    const fs::path run = d.sweep()->start(sweep::parse_plan(kPlan, "calibrate-rig-short.toml"));
    EXPECT_EQ(d.sweep()->wait_finished(180s), sweep::RunState::done) << d.sweep()->progress().reason;
    d.stop();
    return sweep::read_run(run);
  }

  static double mean_translation_error_mm(const sweep::RunRecords& run) {
    double sum = 0;
    int n = 0;
    for (const auto& p : run.points) {
      for (const auto& f : p.frames) {
        if (!f.has_error) continue;
        sum += f.translation_error_mm;
        ++n;
      }
    }
    EXPECT_GT(n, 0);
    return n > 0 ? sum / n : 0;
  }

  const test_support::TempDir temp_{"markerd-rigcal-run"};
  const fs::path dir_ = temp_.path();
  std::string rig_text_;
};

const nlohmann::json& parameter(const nlohmann::json& fit, const std::string& name) {
  for (const auto& p : fit["parameters"]) {
    if (p["name"] == name) return p;
  }
  throw std::runtime_error("no parameter " + name);
}

TEST_F(RigCalibrationRun, TheFitRecoversTheTrueGeometryAndLaterRunsMeasureBetterWithIt) {
  const sweep::RunRecords first = sweep_once();
  ASSERT_EQ(first.points.size(), 15U);
  // The records say what the simulated world was.
  EXPECT_EQ(first.start.rig["sim_geometry"]["d0_mm"], kTrueD0);
  EXPECT_EQ(first.start.rig["geometry"]["d0_mm"], 300.0);
  for (const auto& p : first.points) {
    for (const auto& f : p.frames) {
      ASSERT_TRUE(f.detected);
      ASSERT_TRUE(f.corners_px.has_value());
      ASSERT_TRUE(f.inner_corners_px.has_value());
    }
  }

  const fs::path camera_file = dir_ / "camera.yaml";
  const fs::path geometry_file = dir_ / "rig-geometry.toml";
  const test_support::Outcome out =
      test_support::run_program({MARKERCTL_PATH, "calibrate", "--rig", first.directory.string(), "-o",
                                 camera_file.string(), "--rig-out", geometry_file.string(), "--json"});
  ASSERT_EQ(out.code, 0) << out.describe();
  const nlohmann::json fit = nlohmann::json::parse(out.out);
  EXPECT_EQ(fit["views"], 15);
  EXPECT_TRUE(fit["converged"].get<bool>());
  EXPECT_GT(fit["rms_before_px"].get<double>(), 3.0);
  EXPECT_LT(fit["rms_after_px"].get<double>(), 0.5);

  // Within three of their stated standard deviations of the truth, and
  // within what a rig's ground truth must be to judge a detector by.
  const auto expect_recovered = [&](const std::string& name, double truth, double bound) {
    const nlohmann::json& p = parameter(fit, name);
    SCOPED_TRACE(fmt::format("{}: {} +- {} (true {})", name, p["value"].dump(), p["sigma"].dump(), truth));
    ASSERT_EQ(p["status"], "fitted");
    const double value = p["value"].get<double>();
    const double sigma = p["sigma"].get<double>();
    EXPECT_LT(std::abs(value - truth), 3 * sigma);
    EXPECT_LT(std::abs(value - truth), bound);
    EXPECT_LT(sigma, bound);
  };
  expect_recovered("d0_mm", kTrueD0, 3.0);
  expect_recovered("yaw0_deg", kTrueYaw0, 0.7);
  expect_recovered("marker_offset_normal_mm", kTrueOffsetNormal, 2.0);
  expect_recovered("marker_offset_lateral_mm", 0.0, 2.0);

  // What was written: the camera model markerd reads, and a calibration
  // file the rig config takes.
  const detector::CameraModel camera = detector::CameraModel::load(camera_file);
  EXPECT_EQ(camera.width, 640);
  EXPECT_NEAR(camera.fx, parameter(fit, "fx")["value"].get<double>(), 1e-6);
  std::string rig = rig_text_;
  rig.replace(rig.find("[rig.geometry]\n"), 15, "[rig.geometry]\ncalibration = \"rig-geometry.toml\"\n");
  test_support::write_file(dir_ / "rig.toml", rig);
  const rig::RigConfig calibrated = rig::load_rig_config(dir_ / "rig.toml");
  EXPECT_NEAR(calibrated.geometry.d0_mm, parameter(fit, "d0_mm")["value"].get<double>(), 1e-5);

  // The same sweep again, its ground truth now from the calibration (the
  // simulated world is where it was: [rig.sim.geometry] and the camera
  // model the simulated camera renders through are unchanged).
  const sweep::RunRecords second = sweep_once();
  EXPECT_EQ(second.start.rig["geometry_calibration"], geometry_file.string());
  const double before = mean_translation_error_mm(first);
  const double after = mean_translation_error_mm(second);
  EXPECT_GT(before, 5.0);  // d0 12 mm further, the marker 5 mm nearer: 7 mm when it faces the camera
  EXPECT_LT(after, before / 2) << "mean translation error " << before << " mm before, " << after << " mm after";
}

TEST_F(RigCalibrationRun, ARunThatCannotBeFittedIsNamedInTheError) {
  const test_support::Outcome missing =
      test_support::run_program({MARKERCTL_PATH, "calibrate", "--rig", (dir_ / "no-such-run").string()});
  EXPECT_EQ(missing.code, 1) << missing.describe();
  EXPECT_NE(missing.err.find("no-such-run: no such run directory"), std::string::npos) << missing.err;

  const test_support::Outcome wrong_name =
      test_support::run_program({MARKERCTL_PATH, "calibrate", "--rig", dir_.string(), "--fix", "d0,focal"});
  EXPECT_EQ(wrong_name.code, 2) << wrong_name.describe();
  EXPECT_NE(wrong_name.err.find("--fix focal: no such parameter"), std::string::npos) << wrong_name.err;
}

}  // namespace
}  // namespace markerd
