// The rig's self-calibration on synthetic views: corners projected exactly
// from a known camera and geometry, with Gaussian noise, fitted from wrong
// start values. Every fitted parameter lands within a few of its stated
// standard deviations of the truth (and the deviations are not inflated
// either), over several seeds and true rigs; parameters that the views
// cannot measure are named; wrong corners hardly move the fit; a run's
// records become views; the fitted geometry, written as a calibration
// file, is what a rig config that names it computes its ground truth with.

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "markerd/detector/frame8.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/rig_calibration.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd::sweep {
namespace {

constexpr double kSide = 0.08 * detector::frame8::hole_fraction;

struct Truth {
  detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  rig::RigGeometry geometry;
};

// A true rig drawn from `seed`: the thesis camera a little off, a geometry
// with every offset and tilt a rig might have.
Truth random_truth(std::uint32_t seed) {
  std::mt19937 rng(seed);
  const auto uniform = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  Truth t;
  t.camera.fx += uniform(-20, 20);
  t.camera.fy = t.camera.fx + uniform(-3, 3);
  t.camera.cx += uniform(-8, 8);
  t.camera.cy += uniform(-8, 8);
  t.camera.dist[0] += uniform(-0.05, 0.05);
  t.camera.dist[1] += uniform(-0.2, 0.2);
  t.geometry.d0_mm = uniform(280, 360);
  t.geometry.yaw0_deg = uniform(-4, 4);
  t.geometry.marker_offset_normal_mm = uniform(-8, 8);
  t.geometry.marker_offset_lateral_mm = uniform(-8, 8);
  t.geometry.camera_offset_x_mm = uniform(-10, 10);
  t.geometry.camera_offset_y_mm = uniform(-10, 10);
  t.geometry.rail_tilt_x_deg = uniform(-0.8, 0.8);
  t.geometry.rail_tilt_y_deg = uniform(-0.8, 0.8);
  return t;
}

// The corners of the marker's hole seen from `truth` at each rail position
// and turntable angle, with noise of `sigma_px` per coordinate.
std::vector<RigView> views_of(const Truth& truth, const std::vector<double>& rails, const std::vector<double>& angles,
                              double sigma_px, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, sigma_px);
  const double h = kSide / 2;
  const std::array<Eigen::Vector3d, 4> model{Eigen::Vector3d(-h, h, 0), Eigen::Vector3d(h, h, 0),
                                             Eigen::Vector3d(h, -h, 0), Eigen::Vector3d(-h, -h, 0)};
  std::vector<RigView> views;
  for (const double rail : rails) {
    for (const double angle : angles) {
      RigView v;
      v.rail = rail;
      v.turntable = angle + truth.geometry.yaw0_deg;
      const rig::MarkerGroundTruth pose = rig::ground_truth(truth.geometry, v.rail, v.turntable);
      for (std::size_t j = 0; j < 4; ++j) {
        const Eigen::Vector3d x = pose.rotation * model[j] + pose.translation;
        const detector::Point2 p = truth.camera.normalized_to_pixel({x.x() / x.z(), x.y() / x.z()});
        v.corners_px[j] = {p.x + noise(rng), p.y + noise(rng)};
      }
      views.push_back(v);
    }
  }
  return views;
}

// The calibration sweep's grid (config/plans/calibrate-rig.toml): the rail
// over a metre and a half, the turntable from -60 to 60 degrees.
const std::vector<double> kRails{0, 150, 350, 650, 1000, 1400};
const std::vector<double> kAngles{-60, -45, -30, -15, 0, 15, 30, 45, 60};

// Start values off as a rig's config would be: d0 off by 12 mm, yaw0 by 2
// degrees, the marker's offset by 5 mm, the focal length by 2 %.
RigCalibrationInput wrong_start(const Truth& truth, std::vector<RigView> views) {
  RigCalibrationInput in;
  in.camera = truth.camera;
  in.camera.fx *= 1.02;
  in.camera.fy *= 1.02;
  in.camera.cx -= 4;
  in.camera.cy += 4;
  in.camera.dist[0] = 0.3495;
  in.camera.dist[1] = -2.2549;
  in.geometry = rig::RigGeometry{};
  in.geometry.d0_mm = truth.geometry.d0_mm + 12;
  in.geometry.yaw0_deg = truth.geometry.yaw0_deg + 2;
  in.geometry.marker_offset_normal_mm = truth.geometry.marker_offset_normal_mm + 5;
  in.square_side_m = kSide;
  in.views = std::move(views);
  return in;
}

double true_value(const Truth& t, RigParameter p) {
  switch (p) {
    case RigParameter::fx: return t.camera.fx;
    case RigParameter::fy: return t.camera.fy;
    case RigParameter::cx: return t.camera.cx;
    case RigParameter::cy: return t.camera.cy;
    case RigParameter::k1: return t.camera.dist[0];
    case RigParameter::k2: return t.camera.dist[1];
    case RigParameter::p1: return t.camera.dist[2];
    case RigParameter::p2: return t.camera.dist[3];
    case RigParameter::k3: return t.camera.dist[4];
    case RigParameter::d0: return t.geometry.d0_mm;
    case RigParameter::yaw0: return t.geometry.yaw0_deg;
    case RigParameter::marker_offset_normal: return t.geometry.marker_offset_normal_mm;
    case RigParameter::marker_offset_lateral: return t.geometry.marker_offset_lateral_mm;
    case RigParameter::camera_offset_x: return t.geometry.camera_offset_x_mm;
    case RigParameter::camera_offset_y: return t.geometry.camera_offset_y_mm;
    case RigParameter::rail_tilt_x: return t.geometry.rail_tilt_x_deg;
    case RigParameter::rail_tilt_y: return t.geometry.rail_tilt_y_deg;
  }
  return 0;
}

TEST(RigCalibration, RecoversEveryParameterWithinItsStatedUncertainty) {
  double sum_z2 = 0;
  int count = 0;
  for (std::uint32_t seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE(fmt::format("seed {}", seed));
    const Truth truth = random_truth(seed);
    const RigCalibrationResult fit =
        calibrate_rig(wrong_start(truth, views_of(truth, kRails, kAngles, 0.1, seed + 100)));
    EXPECT_TRUE(fit.converged);
    EXPECT_GT(fit.rms_before_px, 5.0);
    EXPECT_LT(fit.rms_after_px, 0.2);
    EXPECT_NEAR(fit.residual_sigma_px, 0.1, 0.02);
    for (const RigParameterEstimate& e : fit.parameters) {
      SCOPED_TRACE(parameter_name(e.parameter));
      if (e.status == RigParameterEstimate::Status::fixed) {
        EXPECT_EQ(e.value, e.initial);
        continue;
      }
      ASSERT_EQ(e.status, RigParameterEstimate::Status::fitted);
      ASSERT_GT(e.sigma, 0);
      const double z = (e.value - true_value(truth, e.parameter)) / e.sigma;
      EXPECT_LT(std::abs(z), 4.0) << "fitted " << e.value << " +- " << e.sigma << ", true "
                                  << true_value(truth, e.parameter);
      sum_z2 += z * z;
      ++count;
    }
    // What the test's wrong start got wrong, recovered to well within what
    // matters to a pose.
    EXPECT_NEAR(fit.geometry.d0_mm, truth.geometry.d0_mm, 2.0);
    EXPECT_NEAR(fit.geometry.yaw0_deg, truth.geometry.yaw0_deg, 0.5);
    EXPECT_NEAR(fit.geometry.marker_offset_normal_mm, truth.geometry.marker_offset_normal_mm, 2.0);
  }
  // The deviations are honest: not so small that the truth falls outside
  // them (above), nor so large that it always falls far inside. With
  // independent normal errors the mean z^2 is 1.
  const double mean_z2 = sum_z2 / count;
  EXPECT_GT(mean_z2, 0.3);
  EXPECT_LT(mean_z2, 3.0);
}

TEST(RigCalibration, ExactViewsAreFittedExactly) {
  const Truth truth = random_truth(7);
  const RigCalibrationResult fit = calibrate_rig(wrong_start(truth, views_of(truth, kRails, kAngles, 0.0, 1)));
  EXPECT_TRUE(fit.converged);
  EXPECT_LT(fit.rms_after_px, 1e-5);
  EXPECT_NEAR(fit.geometry.d0_mm, truth.geometry.d0_mm, 1e-3);
  EXPECT_NEAR(fit.geometry.yaw0_deg, truth.geometry.yaw0_deg, 1e-4);
  EXPECT_NEAR(fit.camera.fx, truth.camera.fx, 1e-3);
  EXPECT_NEAR(fit.geometry.rail_tilt_x_deg, truth.geometry.rail_tilt_x_deg, 1e-4);
}

TEST(RigCalibration, AParameterTheViewsCannotMeasureIsNamedNotGuessed) {
  const Truth truth = random_truth(3);
  // The rail never moves: its tilt only adds a constant to the camera's
  // offsets and d0, which the views cannot tell apart from them.
  {
    const RigCalibrationResult fit = calibrate_rig(wrong_start(truth, views_of(truth, {500}, kAngles, 0.1, 2)));
    for (const RigParameter p : {RigParameter::rail_tilt_x, RigParameter::rail_tilt_y}) {
      SCOPED_TRACE(parameter_name(p));
      const RigParameterEstimate& e = fit.estimate(p);
      EXPECT_EQ(e.status, RigParameterEstimate::Status::not_observable);
      EXPECT_EQ(e.value, e.initial);
      EXPECT_EQ(e.sigma, 0);
      EXPECT_FALSE(e.confounded_with.empty());
    }
    const auto& tilt_x = fit.estimate(RigParameter::rail_tilt_x).confounded_with;
    EXPECT_NE(std::find(tilt_x.begin(), tilt_x.end(), RigParameter::camera_offset_x), tilt_x.end());
    EXPECT_EQ(fit.estimate(RigParameter::d0).status, RigParameterEstimate::Status::fitted);
  }
  // The turntable never turns: the marker's offset from its axis only adds
  // a constant to where the axis is.
  {
    RigCalibrationOptions options = RigCalibrationOptions::defaults();
    const RigCalibrationResult fit = calibrate_rig(wrong_start(truth, views_of(truth, kRails, {0}, 0.1, 2)), options);
    int held = 0;
    for (const RigParameter p : {RigParameter::marker_offset_normal, RigParameter::marker_offset_lateral,
                                 RigParameter::camera_offset_x, RigParameter::d0}) {
      held += fit.estimate(p).status == RigParameterEstimate::Status::not_observable ? 1 : 0;
    }
    EXPECT_GE(held, 2);
    EXPECT_EQ(fit.estimate(RigParameter::marker_offset_normal).status, RigParameterEstimate::Status::not_observable);
    EXPECT_EQ(fit.estimate(RigParameter::marker_offset_lateral).status, RigParameterEstimate::Status::not_observable);
  }
}

TEST(RigCalibration, FixedParametersKeepTheirValues) {
  const Truth truth = random_truth(4);
  RigCalibrationInput in = wrong_start(truth, views_of(truth, kRails, kAngles, 0.1, 5));
  in.camera = truth.camera;
  RigCalibrationOptions options = RigCalibrationOptions::defaults();
  for (const RigParameter p :
       {RigParameter::fx, RigParameter::fy, RigParameter::cx, RigParameter::cy, RigParameter::k1, RigParameter::k2}) {
    options.fixed[static_cast<std::size_t>(p)] = true;
  }
  const RigCalibrationResult fit = calibrate_rig(in, options);
  EXPECT_EQ(fit.camera.fx, truth.camera.fx);
  EXPECT_EQ(fit.camera.dist[1], truth.camera.dist[1]);
  EXPECT_EQ(fit.estimate(RigParameter::cx).status, RigParameterEstimate::Status::fixed);
  EXPECT_EQ(fit.estimate(RigParameter::cx).sigma, 0);
  const RigParameterEstimate& d0 = fit.estimate(RigParameter::d0);
  EXPECT_LT(std::abs(d0.value - truth.geometry.d0_mm), 4 * d0.sigma);
  // Every parameter fixed: nothing to fit.
  options.fixed.fill(true);
  EXPECT_THROW((void)calibrate_rig(in, options), std::invalid_argument);
}

TEST(RigCalibration, WrongCornersHardlyMoveTheFit) {
  const Truth truth = random_truth(5);
  const std::vector<RigView> clean = views_of(truth, kRails, kAngles, 0.1, 9);
  std::vector<RigView> spoiled = clean;
  // One view in ten with a corner 15 px off (a detection that snapped to
  // something else), and one whole view from somewhere else.
  for (std::size_t i = 0; i < spoiled.size(); i += 10) spoiled[i].corners_px[i % 4] += Eigen::Vector2d(15, -9);
  for (auto& c : spoiled[7].corners_px) c += Eigen::Vector2d(-20, 12);
  const RigCalibrationResult reference = calibrate_rig(wrong_start(truth, clean));
  const RigCalibrationResult robust = calibrate_rig(wrong_start(truth, spoiled));
  EXPECT_GE(robust.outliers, spoiled.size() / 10);
  for (const RigParameterEstimate& e : robust.parameters) {
    if (e.status != RigParameterEstimate::Status::fitted) continue;
    SCOPED_TRACE(parameter_name(e.parameter));
    const RigParameterEstimate& r = reference.estimate(e.parameter);
    // Each wrong corner still pulls with the Huber threshold's force, not
    // its full error: the fit moves by a fraction of what it would.
    EXPECT_LT(std::abs(e.value - r.value), 2.5 * r.sigma) << e.value << " vs " << r.value << " +- " << r.sigma;
    EXPECT_LT(std::abs(e.value - true_value(truth, e.parameter)), 4 * e.sigma);
  }
  // Plain least squares (a threshold no corner reaches) is dragged off by them.
  RigCalibrationOptions squares = RigCalibrationOptions::defaults();
  squares.huber_px = 1e6;
  const RigCalibrationResult dragged = calibrate_rig(wrong_start(truth, spoiled), squares);
  double worst = 0;
  for (const RigParameterEstimate& e : dragged.parameters) {
    if (e.status != RigParameterEstimate::Status::fitted) continue;
    const RigParameterEstimate& r = reference.estimate(e.parameter);
    worst = std::max(worst, std::abs(e.value - r.value) / r.sigma);
  }
  EXPECT_GT(worst, 20.0);
}

TEST(RigCalibration, ParameterNames) {
  EXPECT_EQ(parameter_from_name("d0_mm"), RigParameter::d0);
  EXPECT_EQ(parameter_from_name("d0"), RigParameter::d0);
  EXPECT_EQ(parameter_from_name("yaw0"), RigParameter::yaw0);
  EXPECT_EQ(parameter_from_name("rail_tilt_x"), RigParameter::rail_tilt_x);
  EXPECT_EQ(parameter_from_name("k3"), RigParameter::k3);
  EXPECT_EQ(parameter_from_name("k"), std::nullopt);
  EXPECT_EQ(parameter_from_name("d0_"), std::nullopt);
  for (std::size_t i = 0; i < kRigParameterCount; ++i) {
    const auto p = static_cast<RigParameter>(i);
    EXPECT_EQ(parameter_from_name(parameter_name(p)), p);
  }
}

// The shipped calibration plan fits the simulated rig, and its views
// measure every parameter the fit frees by default.
TEST(RigCalibration, TheShippedCalibrationPlanMeasuresEveryParameter) {
  const SweepPlan plan = load_plan(test_support::kSourceTree / "config/plans/calibrate-rig.toml");
  const rig::RigConfig rig = rig::load_rig_config(test_support::kSourceTree / "config/rig-sim.toml");
  const PlanCheck check = check_plan(plan, rig, 30);
  EXPECT_TRUE(check.problems.empty());
  EXPECT_EQ(check.steps.size(), 45U);
  Truth truth = random_truth(9);
  truth.geometry.d0_mm = rig.geometry.d0_mm;
  truth.geometry.yaw0_deg = 0;
  std::vector<RigView> views;
  for (const PlanStep& step : check.steps) {
    const AxisTargets at = axis_targets(rig.geometry, step.distance_m, step.angle_deg);
    const std::vector<RigView> one =
        views_of(truth, {at.rail}, {at.turntable}, 0.1, static_cast<std::uint32_t>(step.index));
    views.push_back(one.front());
  }
  const RigCalibrationResult fit = calibrate_rig(wrong_start(truth, views));
  for (const RigParameterEstimate& e : fit.parameters) {
    SCOPED_TRACE(parameter_name(e.parameter));
    EXPECT_NE(e.status, RigParameterEstimate::Status::not_observable);
    if (e.status == RigParameterEstimate::Status::fitted) {
      EXPECT_LT(std::abs(e.value - true_value(truth, e.parameter)), 4 * e.sigma);
    }
  }
}

// A run's records as markerd writes them: one view per measurement, its
// corners the median of its frames', the start values from the start record.
TEST(RigCalibration, ARunsRecordsBecomeViews) {
  const Truth truth = random_truth(6);
  const std::vector<RigView> views = views_of(truth, {0, 400}, {-30, 30}, 0.0, 1);
  RunRecords run;
  run.start.plan.marker.size_m = 0.08;
  run.start.camera = {{"model",
                       {{"width", 640},
                        {"height", 480},
                        {"fx", 500.0},
                        {"fy", 501.0},
                        {"cx", 320.0},
                        {"cy", 240.0},
                        {"distortion", {0.1, -0.2, 0.0, 0.0, 0.3}}}}};
  run.start.rig = {{"geometry",
                    {{"d0_mm", 310.0},
                     {"yaw0_deg", 1.5},
                     {"rail_sign", 1},
                     {"camera_offset_x_mm", 1.0},
                     {"camera_offset_y_mm", 2.0},
                     {"marker_offset_normal_mm", 3.0},
                     {"marker_offset_lateral_mm", 4.0}}}};
  for (const RigView& v : views) {
    PointRecord p;
    p.rail = v.rail;
    p.turntable = v.turntable;
    for (int f = 0; f < 3; ++f) {
      FrameSample s;
      s.detected = true;
      ImageCorners c{};
      for (std::size_t j = 0; j < 4; ++j) c[j] = {v.corners_px[j].x() + (f == 1 ? 50 : 0), v.corners_px[j].y()};
      s.inner_corners_px = c;
      s.corners_px = c;
      p.frames.push_back(s);
    }
    p.frames.push_back(FrameSample{});  // a frame that missed the marker
    run.points.push_back(p);
  }
  run.points.push_back(PointRecord{});  // a measurement that found nothing

  const RigCalibrationRun r = rig_calibration_input(run);
  EXPECT_EQ(r.measurements, 5U);
  EXPECT_EQ(r.frames, 12U);
  EXPECT_EQ(r.corners, "frame8's hole");
  ASSERT_EQ(r.input.views.size(), 4U);
  EXPECT_DOUBLE_EQ(r.input.square_side_m, kSide);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(r.input.views[i].rail, views[i].rail);
    EXPECT_EQ(r.input.views[i].turntable, views[i].turntable);
    // The frame 50 px off is outvoted.
    EXPECT_NEAR((r.input.views[i].corners_px[2] - views[i].corners_px[2]).norm(), 0, 1e-9);
  }
  EXPECT_EQ(r.input.camera.fy, 501.0);
  EXPECT_EQ(r.input.camera.dist[4], 0.3);
  EXPECT_EQ(r.input.geometry.d0_mm, 310.0);
  EXPECT_EQ(r.input.geometry.marker_offset_lateral_mm, 4.0);
  EXPECT_EQ(r.input.geometry.rail_tilt_x_deg, 0.0);  // records from before the tilt

  // Records without corners (from before markerd kept them) are refused, saying so.
  for (auto& p : run.points) {
    for (auto& f : p.frames) f.inner_corners_px.reset();
  }
  try {
    (void)rig_calibration_input(run);
    ADD_FAILURE() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("keep no corners"), std::string::npos) << e.what();
  }
  run.start.camera = nlohmann::json::object();
  EXPECT_THROW((void)rig_calibration_input(run), std::runtime_error);
}

// The fitted geometry written as a calibration file and named by a rig
// config's [rig.geometry] calibration: the config's ground truth is the fit's.
TEST(RigCalibration, TheCalibrationFileIsWhatTheRigConfigUses) {
  const Truth truth = random_truth(8);
  const RigCalibrationResult fit = calibrate_rig(wrong_start(truth, views_of(truth, kRails, kAngles, 0.1, 3)));
  const test_support::TempDir dir("markerd-rigcal");
  dir.write("rig-geometry.toml", rig_geometry_toml(fit, "markerctl calibrate --rig test\nsecond line"));
  const std::string text = test_support::read_file(dir / "rig-geometry.toml");
  EXPECT_EQ(text.rfind("# markerctl calibrate --rig test\n# second line\n[rig.geometry]\n", 0), 0U) << text;

  test_support::write_sim_rig_config(dir / "rig.toml", 1.0);
  std::string rig = test_support::read_file(dir / "rig.toml");
  rig.replace(rig.find("[rig.geometry]\n"), 15, "[rig.geometry]\ncalibration = \"rig-geometry.toml\"\n");
  dir.write("rig.toml", rig);
  const rig::RigConfig config = rig::load_rig_config(dir / "rig.toml");
  EXPECT_EQ(config.geometry_calibration, dir / "rig-geometry.toml");
  EXPECT_NEAR(config.geometry.d0_mm, fit.geometry.d0_mm, 1e-5);
  EXPECT_NEAR(config.geometry.yaw0_deg, fit.geometry.yaw0_deg, 1e-5);
  EXPECT_NEAR(config.geometry.rail_tilt_y_deg, fit.geometry.rail_tilt_y_deg, 1e-5);
  EXPECT_NEAR(config.geometry.marker_offset_lateral_mm, fit.geometry.marker_offset_lateral_mm, 1e-5);
  EXPECT_EQ(config.configured_geometry.d0_mm, 300.0);  // rig-sim.toml's own
}

}  // namespace
}  // namespace markerd::sweep
