// Summaries and reports from a run's records: records built in memory with
// known samples, so every number asserted here was worked out by hand.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "markerd/sweep/report.hpp"
#include "markerd/sweep/summary.hpp"
#include "support/files.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace {

namespace fs = std::filesystem;
namespace test_support = markerd::test_support;
using namespace markerd::sweep;

FrameSample seen() {
  FrameSample f;
  f.detected = true;
  return f;
}

FrameSample missed() { return FrameSample{}; }

FrameSample posed(std::array<double, 3> tvec, double translation_error_mm, double distance_error_mm,
                  double rotation_error_deg, double reprojection_error_px = 0.5) {
  FrameSample f = seen();
  f.has_pose = true;
  f.tvec_m = tvec;
  f.reprojection_error_px = reprojection_error_px;
  f.has_error = true;
  f.translation_error_mm = translation_error_mm;
  f.distance_error_mm = distance_error_mm;
  f.rotation_error_deg = rotation_error_deg;
  return f;
}

// `detected` of `frames` frames found the marker, without a pose.
std::vector<FrameSample> frames_with(int frames, int detected) {
  std::vector<FrameSample> samples;
  for (int i = 0; i < frames; ++i) samples.push_back(i < detected ? seen() : missed());
  return samples;
}

struct RunBuilder {
  RunRecords records;
  std::size_t step = 0;

  explicit RunBuilder(std::string run_id) {
    records.directory = "/nonexistent/" + run_id;
    records.start.run_id = std::move(run_id);
    records.start.plan.name = "thesis";
    records.start.plan.detection_threshold = 0.9;
    records.start.plan.grids = {PlanGrid{"distance", {}, {}, SweepOrder::grid, SweepAxis::distance},
                                PlanGrid{"angle", {}, {}, SweepOrder::grid, SweepAxis::angle}};
    records.start.rig = {{"rail", {{"units_per_step", 0.025}}}};
    records.start.time = std::chrono::system_clock::from_time_t(1'796'105'700);  // 2026-12-01 06:15:00 UTC
    records.stop = RunStop{std::chrono::system_clock::from_time_t(1'796'109'300), ExitStatus::done, "", 0, "", ""};
  }

  PointRecord& add(std::size_t grid, std::size_t point, double distance_m, double angle_deg,
                   std::vector<FrameSample> frames, int repeat = 0) {
    PointRecord r;
    r.step = step++;
    r.grid = grid;
    r.point = point;
    r.repeat = repeat;
    r.distance_m = distance_m;
    r.angle_deg = angle_deg;
    r.rail = (distance_m - 0.95) * 1000;  // the rail's 0 where the thesis's was: 95 cm
    r.turntable = angle_deg;
    r.truth_distance_m = distance_m;
    r.truth_tvec_m = {0, 0, distance_m};
    r.frames = std::move(frames);
    records.points.push_back(std::move(r));
    return records.points.back();
  }
};

const PointSummary& point_at(const RunSummary& s, std::size_t point) {
  for (const auto& p : s.points) {
    if (p.point == point) return p;
  }
  throw std::runtime_error("no point " + std::to_string(point));
}

// A thesis-shaped run: a distance sweep facing the camera with a gap, and
// angle sweeps at 50 cm and 95 cm.
RunBuilder thesis_shaped_run(const std::string& run_id = "20261201T061500Z-thesis") {
  RunBuilder run(run_id);
  // Distance sweep: 0.50 and 0.70 reached, 0.90 fails, 1.10 reached again.
  run.add(0, 0, 0.50, 0, frames_with(10, 10));
  run.add(0, 1, 0.70, 0, frames_with(10, 9));
  run.add(0, 2, 0.90, 0, frames_with(10, 5));
  run.add(0, 3, 1.10, 0, frames_with(10, 10));
  // Angle sweep at 50 cm: positive side fails at 20 (30 reached after the
  // gap must not count), negative side reaches 30, fails at 40.
  const std::vector<std::pair<double, int>> at_50cm = {{-40, 2}, {-30, 9}, {-20, 10}, {-10, 10},
                                                       {0, 10},  {10, 10}, {20, 3},   {30, 10}};
  std::size_t point = 4;
  for (const auto& [angle, detected] : at_50cm) run.add(1, point++, 0.50, angle, frames_with(10, detected));
  // Angle sweep at 95 cm, one side only, whose point nearest facing fails.
  run.add(1, point++, 0.95, 0, frames_with(10, 4));
  run.add(1, point++, 0.95, 10, frames_with(10, 10));
  run.add(1, point++, 0.95, 20, frames_with(10, 10));
  return run;
}

TEST(SweepSummary, RatesAndReachedMergeTheRepeatsOfAPoint) {
  RunBuilder run("rates");
  run.add(0, 0, 0.5, 0, frames_with(5, 5), 0);
  run.add(0, 1, 0.6, 0, frames_with(10, 8), 0);
  run.add(0, 0, 0.5, 0, frames_with(5, 4), 1);  // point 0's second measurement, later in the file
  run.records.points.back().frames_corrupt = 2;
  const RunSummary s = summarize(run.records);

  ASSERT_EQ(s.points.size(), 2u);
  const PointSummary& merged = s.points[0];
  EXPECT_EQ(merged.point, 0u);
  EXPECT_EQ(merged.grid_name, "distance");
  EXPECT_EQ(merged.frames, 10);
  EXPECT_EQ(merged.detected, 9);
  EXPECT_EQ(merged.frames_corrupt, 2);
  EXPECT_DOUBLE_EQ(merged.rate, 0.9);
  EXPECT_TRUE(merged.reached) << "a rate equal to the threshold reaches it";
  ASSERT_EQ(merged.measurements.size(), 2u);
  EXPECT_EQ(merged.measurements[0].detected, 5);
  EXPECT_EQ(merged.measurements[1].detected, 4);
  EXPECT_FALSE(merged.measurements[0].mean_tvec_m) << "no frame had a pose";

  EXPECT_DOUBLE_EQ(s.points[1].rate, 0.8);
  EXPECT_FALSE(s.points[1].reached);
  EXPECT_EQ(s.status, "done");
  EXPECT_EQ(s.run_id, "rates");
  EXPECT_EQ(s.plan_name, "thesis");
}

TEST(SweepSummary, PointWithoutFramesHasRateZeroAndIsNotReached) {
  RunBuilder run("empty");
  run.records.start.plan.detection_threshold = 0;
  run.add(0, 0, 0.5, 0, {});
  const RunSummary s = summarize(run.records);
  ASSERT_EQ(s.points.size(), 1u);
  EXPECT_EQ(s.points[0].rate, 0);
  EXPECT_FALSE(s.points[0].reached);
}

TEST(SweepSummary, StatusIsIncompleteWithoutStopRecord) {
  RunBuilder run("cut-off");
  run.records.stop.reset();
  EXPECT_EQ(summarize(run.records).status, "incomplete");
  run.records.stop = RunStop{{}, ExitStatus::aborted, "stopped by the operator", 0, "", ""};
  EXPECT_EQ(summarize(run.records).status, "aborted");
}

TEST(SweepSummary, MaxDistanceStopsAtTheFirstFailedFacingPoint) {
  const RunSummary s = summarize(thesis_shaped_run().records);
  ASSERT_TRUE(s.max_distance_m);
  EXPECT_DOUBLE_EQ(*s.max_distance_m, 0.70) << "1.10 m was reached only after 0.90 m failed";
}

TEST(SweepSummary, MaxDistanceIsEmptyWhenTheNearestFacingPointFails) {
  RunBuilder run("near-fails");
  run.add(0, 0, 0.5, 0, frames_with(10, 1));
  run.add(0, 1, 0.7, 0, frames_with(10, 10));
  run.add(1, 2, 0.3, 30, frames_with(10, 10));  // not facing: no part of the distance sweep
  EXPECT_FALSE(summarize(run.records).max_distance_m);
}

TEST(SweepSummary, FacingPointsAtOneDistanceCountOnlyWhenEachIsReached) {
  RunBuilder run("twice");
  run.add(0, 0, 0.5, 0, frames_with(10, 10));
  run.add(0, 1, 0.7, 0, frames_with(10, 10));
  run.add(1, 2, 0.7, 0.2, frames_with(10, 3));  // the angle grid's facing point at 0.7 m
  run.add(0, 3, 0.9, 0, frames_with(10, 10));
  const RunSummary s = summarize(run.records);
  ASSERT_TRUE(s.max_distance_m);
  EXPECT_DOUBLE_EQ(*s.max_distance_m, 0.5);
  EXPECT_TRUE(s.max_angle.empty()) << "0 and 0.2 deg both face the camera: one angle, no angle sweep";
}

TEST(SweepSummary, MaxAnglePerSideWalksOutwardsFromFacing) {
  const RunSummary s = summarize(thesis_shaped_run().records);
  // 0.50 m (the distance sweep's facing point and the angle sweep's) and
  // 0.95 m; 0.70, 0.90 and 1.10 m have one angle each.
  ASSERT_EQ(s.max_angle.size(), 2u);
  const MaxAngle& at_50 = s.max_angle[0];
  EXPECT_DOUBLE_EQ(at_50.distance_m, 0.50);
  ASSERT_TRUE(at_50.positive_deg);
  EXPECT_DOUBLE_EQ(*at_50.positive_deg, 10) << "30 deg was reached only after 20 deg failed";
  ASSERT_TRUE(at_50.negative_deg);
  EXPECT_DOUBLE_EQ(*at_50.negative_deg, 30);

  const MaxAngle& at_95 = s.max_angle[1];
  EXPECT_DOUBLE_EQ(at_95.distance_m, 0.95);
  EXPECT_FALSE(at_95.positive_deg) << "its point nearest facing (0 deg) failed";
  EXPECT_FALSE(at_95.negative_deg) << "only the facing point is on that side: not swept";
}

TEST(SweepSummary, MaxAngleStartsAtTheSweptPointNearestFacing) {
  RunBuilder run("no-zero");
  run.add(1, 0, 0.5, 10, frames_with(10, 10));
  run.add(1, 1, 0.5, 20, frames_with(10, 10));
  run.add(1, 2, 0.5, 40, frames_with(10, 1));
  run.add(1, 3, 0.5, -20, frames_with(10, 0));
  const RunSummary s = summarize(run.records);
  ASSERT_EQ(s.max_angle.size(), 1u);
  ASSERT_TRUE(s.max_angle[0].positive_deg);
  EXPECT_DOUBLE_EQ(*s.max_angle[0].positive_deg, 20);
  EXPECT_FALSE(s.max_angle[0].negative_deg);
}

// Three frames with a pose at 1 m: z 0.9, 1.0, 1.1; translation errors 10,
// 20, 60 mm; distance errors -20, 0, +40 mm (-2, 0, 4 %); rotation errors
// 1, 2, 6 deg. And a frame detected without a pose, which counts for the
// rate only.
RunBuilder spread_run() {
  RunBuilder run("spreads");
  run.add(0, 0, 1.0, 0,
          {posed({0.01, 0.02, 0.9}, 10, -20, 1, 0.2), posed({0.01, 0.02, 1.0}, 20, 0, 2, 0.4),
           posed({0.01, 0.02, 1.1}, 60, 40, 6, 0.6), seen()});
  // A second point, for the run's medians: one more frame, translation error
  // 100 mm, distance error -50 mm of 0.5 m (10 %), rotation 3 deg.
  run.add(0, 1, 0.5, 0, {posed({0, 0, 0.45}, 100, -50, 3)});
  return run;
}

TEST(SweepSummary, SpreadsAreMeansAndSampleStandardDeviations) {
  const RunSummary s = summarize(spread_run().records);
  const PointSummary& p = point_at(s, 0);
  EXPECT_EQ(p.frames, 4);
  EXPECT_EQ(p.detected, 4);
  EXPECT_EQ(p.tvec_m[2].n, 3u);
  EXPECT_NEAR(p.tvec_m[2].mean, 1.0, 1e-12);
  EXPECT_NEAR(p.tvec_m[2].stddev, 0.1, 1e-12);
  EXPECT_NEAR(p.tvec_m[0].mean, 0.01, 1e-12);
  EXPECT_NEAR(p.tvec_m[0].stddev, 0, 1e-12);
  EXPECT_NEAR(p.translation_error_mm.mean, 30, 1e-12);
  EXPECT_NEAR(p.translation_error_mm.stddev, std::sqrt(700.0), 1e-9);  // (400 + 100 + 900) / 2
  EXPECT_NEAR(p.distance_error_mm.mean, 20.0 / 3, 1e-12);
  EXPECT_NEAR(p.distance_error_pct.mean, 2.0 / 3, 1e-12);
  EXPECT_NEAR(p.distance_error_pct.stddev, std::sqrt(28.0 / 3), 1e-12);  // ((8/3)^2 + (2/3)^2 + (10/3)^2) / 2
  EXPECT_NEAR(p.rotation_error_deg.mean, 3, 1e-12);
  EXPECT_NEAR(p.reprojection_error_px.mean, 0.4, 1e-12);
  ASSERT_TRUE(p.median_translation_error_mm);
  EXPECT_DOUBLE_EQ(p.median_translation_error_mm->median, 20);
  EXPECT_FALSE(p.median_translation_error_mm->low) << "3 frames: no two ranks hold the median with 95%";
  ASSERT_TRUE(p.median_distance_error_pct);
  EXPECT_DOUBLE_EQ(p.median_distance_error_pct->median, 2) << "the median of |-2|, |0|, |4|";
  EXPECT_EQ(p.translation_errors_mm, (std::vector<double>{10, 20, 60}));
  ASSERT_TRUE(p.measurements[0].mean_tvec_m);
  EXPECT_NEAR((*p.measurements[0].mean_tvec_m)[2], 1.0, 1e-12);
}

TEST(SweepSummary, RunMediansAreOverEveryFrameWithAnError) {
  const RunSummary s = summarize(spread_run().records);
  // Translation errors 10, 20, 60, 100: an even count takes the mean of the middle two.
  ASSERT_TRUE(s.median_translation_error_mm);
  EXPECT_DOUBLE_EQ(*s.median_translation_error_mm, 40);
  // |distance error| 2, 0, 4, 10 %.
  ASSERT_TRUE(s.median_distance_error_pct);
  EXPECT_NEAR(*s.median_distance_error_pct, 3, 1e-12);
  // Rotation errors 1, 2, 6, 3.
  ASSERT_TRUE(s.median_rotation_error_deg);
  EXPECT_DOUBLE_EQ(*s.median_rotation_error_deg, 2.5);

  const RunSummary no_poses = summarize(thesis_shaped_run().records);
  EXPECT_FALSE(no_poses.median_translation_error_mm);
  EXPECT_FALSE(no_poses.median_rotation_error_deg);
}

TEST(SweepSummary, RailStepsFromTheRigsUnitsPerStep) {
  RunBuilder run("steps");
  run.add(0, 0, 0.95, 0, frames_with(1, 1)).rail = 0;
  run.add(0, 1, 1.07, 0, frames_with(1, 1)).rail = 125.0;   // 5000 steps of 0.025 mm
  run.add(0, 2, 1.20, 0, frames_with(1, 1)).rail = 262.51;  // 10500.4 steps: rounded
  run.add(0, 3, 0.90, 0, frames_with(1, 1)).rail = -12.51;  // -500.4 steps
  RunSummary s = summarize(run.records);
  ASSERT_TRUE(point_at(s, 0).rail_steps);
  EXPECT_EQ(*point_at(s, 0).rail_steps, 0);
  EXPECT_EQ(point_at(s, 1).rail_steps.value_or(-1), 5000);
  EXPECT_EQ(point_at(s, 2).rail_steps.value_or(-1), 10500);
  EXPECT_EQ(point_at(s, 3).rail_steps.value_or(-1), -500);
  EXPECT_EQ(point_at(s, 1).measurements[0].rail_steps.value_or(-1), 5000);

  run.records.start.rig = {{"rail", {{"unit", "mm"}}}};
  s = summarize(run.records);
  EXPECT_FALSE(point_at(s, 1).rail_steps) << "no units_per_step, no steps";
  run.records.start.rig = nlohmann::json();
  EXPECT_FALSE(point_at(summarize(run.records), 1).rail_steps);
}

// ---------------------------------------------------------------------------
// How sure the numbers are: rates' intervals, the threshold calls, medians'
// intervals

constexpr double kZ = 1.959963984540054;

// At 0 of n and n of n Wilson's interval has a closed form, z^2 / (n + z^2)
// from the end: 30 of 30 reaches down to 88.6 %, below a 90 % threshold,
// and 35 frames would lift it above; 50 of 50 is above, 10 of 50 below.
TEST(SweepSummary, RatesHaveWilsonIntervalsAndACallAgainstTheThreshold) {
  RunBuilder run("calls");
  run.add(0, 0, 0.5, 0, frames_with(30, 30));
  run.add(0, 1, 0.6, 0, frames_with(50, 50));
  run.add(0, 2, 0.7, 0, frames_with(50, 10));
  run.add(0, 3, 0.8, 0, frames_with(30, 27));  // on the threshold
  run.add(0, 4, 0.9, 0, {});
  const RunSummary s = summarize(run.records);

  const PointSummary& thirty = point_at(s, 0);
  EXPECT_NEAR(thirty.rate_interval.low, 30 / (30 + kZ * kZ), 1e-12);
  EXPECT_DOUBLE_EQ(thirty.rate_interval.high, 1);
  EXPECT_TRUE(thirty.reached);
  EXPECT_EQ(thirty.call, RateCall::uncertain);
  EXPECT_EQ(thirty.frames_to_decide, 35);

  EXPECT_EQ(point_at(s, 1).call, RateCall::above);
  EXPECT_NEAR(point_at(s, 1).rate_interval.low, 50 / (50 + kZ * kZ), 1e-12);
  EXPECT_EQ(point_at(s, 2).call, RateCall::below);
  EXPECT_LT(point_at(s, 2).rate_interval.high, 0.9);

  EXPECT_EQ(point_at(s, 3).call, RateCall::uncertain);
  EXPECT_EQ(point_at(s, 3).frames_to_decide, std::nullopt) << "no count tells 90 % from 90 %";
  EXPECT_EQ(point_at(s, 4).call, RateCall::uncertain) << "no frames, no call";
  EXPECT_DOUBLE_EQ(point_at(s, 4).rate_interval.low, 0);
  EXPECT_DOUBLE_EQ(point_at(s, 4).rate_interval.high, 1);
}

// The maximum distance of 50-frame points is decided; of 30-frame points at
// 100 %, it is not: 30 of 30 may be below 90 %, so walking over the points
// surely detected stops before the first, and over those that may be goes
// to the 30-frame point at 80 % (its interval [62.7, 90.5] % holds 90 %).
TEST(SweepSummary, ALimitIsUncertainWhereARateOnTheWayHoldsTheThreshold) {
  RunBuilder decided("decided");
  decided.add(0, 0, 0.5, 0, frames_with(50, 50));
  decided.add(0, 1, 0.6, 0, frames_with(50, 50));
  decided.add(0, 2, 0.7, 0, frames_with(50, 10));
  const RunSummary d = summarize(decided.records);
  ASSERT_EQ(d.max_distance_m, 0.6);
  EXPECT_FALSE(d.max_distance_call.uncertain());
  EXPECT_EQ(d.max_distance_call.surely, 0.6);
  EXPECT_EQ(d.max_distance_call.possibly, 0.6);
  EXPECT_TRUE(d.max_distance_call.deciding.empty());

  RunBuilder few("few");
  few.add(0, 0, 0.5, 0, frames_with(30, 30));
  few.add(0, 1, 0.6, 0, frames_with(30, 30));
  few.add(0, 2, 0.7, 0, frames_with(30, 24));
  few.add(0, 3, 0.8, 0, frames_with(30, 3));
  const RunSummary f = summarize(few.records);
  ASSERT_EQ(f.max_distance_m, 0.6);
  const LimitCall& call = f.max_distance_call;
  EXPECT_TRUE(call.uncertain());
  EXPECT_EQ(call.surely, std::nullopt) << "the first point may be below the threshold";
  EXPECT_EQ(call.possibly, 0.7);
  EXPECT_EQ(call.deciding, (std::vector<std::size_t>{0, 1, 2})) << "0.8 m, 3 of 30, is surely below";
  // 100 %: 35 frames; 80 %: z^2 0.09 / 0.01 = 34.6, 35 too.
  EXPECT_EQ(call.frames_to_decide, 35);

  // An angle side the same way: 30 frames at 100 % to 20 deg, none at 30.
  RunBuilder angles("angles");
  angles.add(1, 0, 0.5, 0, frames_with(50, 50));
  angles.add(1, 1, 0.5, 10, frames_with(50, 50));
  angles.add(1, 2, 0.5, 20, frames_with(30, 30));
  angles.add(1, 3, 0.5, 30, frames_with(30, 0));
  angles.add(1, 4, 0.5, -10, frames_with(50, 50));
  angles.add(1, 5, 0.5, -20, frames_with(50, 0));
  const RunSummary a = summarize(angles.records);
  ASSERT_EQ(a.max_angle.size(), 1U);
  EXPECT_EQ(a.max_angle[0].positive_deg, 20.0);
  EXPECT_TRUE(a.max_angle[0].positive_call.uncertain());
  EXPECT_EQ(a.max_angle[0].positive_call.surely, 10.0);
  EXPECT_EQ(a.max_angle[0].positive_call.possibly, 20.0);
  EXPECT_EQ(a.max_angle[0].positive_call.deciding, (std::vector<std::size_t>{2}));
  EXPECT_FALSE(a.max_angle[0].negative_call.uncertain());
  EXPECT_EQ(a.max_angle[0].negative_deg, 10.0);

  // Where a point on the way sits on the threshold, no count decides it.
  few.records.points[1].frames = frames_with(30, 27);
  EXPECT_EQ(summarize(few.records).max_distance_call.frames_to_decide, std::nullopt);
}

TEST(SweepSummary, ThresholdCallsSayWhichLimitsAreUncertainAndWhatWouldDecideThem) {
  RunBuilder few("few");
  few.add(0, 0, 0.5, 0, frames_with(30, 30));
  few.add(0, 1, 0.6, 0, frames_with(30, 0));
  RunBuilder many("many");
  many.add(0, 0, 0.5, 0, frames_with(50, 50));
  many.add(0, 1, 0.6, 0, frames_with(50, 0));
  const RunSummary f = summarize(few.records);
  const RunSummary m = summarize(many.records);
  const std::string text = threshold_calls({&f, &m});
  EXPECT_NE(text.find("| few | Maximum detection distance | 50 cm | uncertain | not reached to 50 cm | 50 cm: 100.0 % "
                      "[88.6, 100.0] of 30 | 35 |"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("| many | Maximum detection distance | 50 cm | decided | — | — | — |"), std::string::npos)
      << text;
  EXPECT_NE(text.find("1 of 2 limits are uncertain; points of 35 frames would decide them."), std::string::npos)
      << text;
  // Table 6.1 says so in its cell.
  EXPECT_NE(table_6_1({f, m}).find("| Maximum detection distance | 120 cm | 50 cm (uncertain) | 50 cm |"),
            std::string::npos)
      << table_6_1({f, m});
  EXPECT_NE(threshold_calls({&m}).find("Every limit here is decided."), std::string::npos);

  // The points in doubt hardest first: on the threshold, then the most frames.
  RunBuilder mixed("mixed");
  mixed.add(0, 0, 0.5, 0, frames_with(30, 30));
  mixed.add(0, 1, 0.6, 0, frames_with(30, 28));  // 93.3 %: 308 frames
  mixed.add(0, 2, 0.7, 0, frames_with(30, 27));  // 90 %
  mixed.add(0, 3, 0.8, 0, frames_with(30, 0));
  const RunSummary x = summarize(mixed.records);
  EXPECT_NE(threshold_calls({&x}).find("| 70 cm: 90.0 % [74.4, 96.5] of 30; 60 cm: 93.3 % [78.7, 98.2] of 30; 50 cm: "
                                       "100.0 % [88.6, 100.0] of 30 | none: a rate is on the threshold |"),
            std::string::npos)
      << threshold_calls({&x});
}

// The median's interval from the order statistics: of 10 values the 2nd and
// 9th (P(B <= 1) = 11/1024 <= 2.5 % < P(B <= 2) = 56/1024); of 6 the
// extremes (1/64); of 5 none (1/32 > 2.5 %).
TEST(SweepSummary, MediansHaveOrderStatisticIntervals) {
  const auto ten = median_estimate({10, 9, 8, 7, 6, 5, 4, 3, 2, 1});
  ASSERT_TRUE(ten);
  EXPECT_EQ(ten->n, 10U);
  EXPECT_DOUBLE_EQ(ten->median, 5.5);
  EXPECT_EQ(ten->low, 2.0);
  EXPECT_EQ(ten->high, 9.0);
  const auto six = median_estimate({6, 1, 5, 2, 4, 3});
  ASSERT_TRUE(six);
  EXPECT_EQ(six->low, 1.0);
  EXPECT_EQ(six->high, 6.0);
  const auto five = median_estimate({1, 2, 3, 4, 5});
  ASSERT_TRUE(five);
  EXPECT_DOUBLE_EQ(five->median, 3);
  EXPECT_FALSE(five->low);
  EXPECT_FALSE(five->high);
  EXPECT_FALSE(median_estimate({}));
  // Many values: ranks near n/2 -+ 0.98 sqrt(n) (the normal approximation).
  std::vector<double> many;
  for (int i = 1; i <= 1000; ++i) many.push_back(i);
  const auto thousand = median_estimate(many);
  ASSERT_TRUE(thousand && thousand->low && thousand->high);
  EXPECT_NEAR(*thousand->low, 469, 2);
  EXPECT_NEAR(*thousand->high, 532, 2);
}

// One point at 95 cm facing, 3 frames: two with a pose, one missed.
RunBuilder csv_run() {
  RunBuilder run("csv");
  auto& r =
      run.add(0, 0, 0.95, 0,
              {posed({0.05, 0.01, 0.85}, 100, -95, 1.0, 0.5), posed({0.06, 0.01, 0.87}, 80, -75, 2.0, 0.7), missed()});
  r.frames[0].other_markers = 1;
  r.frames_corrupt = 2;
  r.rail = 0;
  return run;
}

TEST(SweepSummary, PointsCsvHeaderAndRow) {
  const std::string csv = points_csv(summarize(csv_run().records));
  std::istringstream lines(csv);
  std::string header;
  std::string row;
  std::string extra;
  ASSERT_TRUE(std::getline(lines, header));
  ASSERT_TRUE(std::getline(lines, row));
  EXPECT_FALSE(std::getline(lines, extra)) << "one line per point";
  EXPECT_EQ(header,
            "grid,point,distance_m,angle_deg,rail,rail_steps,turntable,measurements,frames,detected,rate,reached,"
            "frames_corrupt,other_markers,tx_m,ty_m,tz_m,tx_sd_m,ty_sd_m,tz_sd_m,distance_estimated_m,"
            "distance_error_mm,distance_error_sd_mm,distance_error_pct,translation_error_mm,translation_error_sd_mm,"
            "rotation_error_deg,rotation_error_sd_deg,reprojection_error_px,median_translation_error_mm,"
            "median_abs_distance_error_pct,rate_low,rate_high,rate_call,frames_to_decide,distance_estimated_sd_mm,"
            "median_translation_error_low_mm,median_translation_error_high_mm,median_abs_distance_error_low_pct,"
            "median_abs_distance_error_high_pct,median_rotation_error_deg,median_rotation_error_low_deg,"
            "median_rotation_error_high_deg")
      << "the first 31 columns as before, the new ones after them";
  // tz: 0.85, 0.87 (sd 0.02 / sqrt 2 = 0.0141); |t| 0.8515, 0.8721 (sd
  // 14.56 mm); distance errors -95, -75 mm (sd 14.14) = -10 %, -7.89 % of
  // 950 mm; 2 of 3 frames: Wilson [20.8, 93.9] %, which holds 90 %, and 7
  // frames at 2/3 would not (z^2 0.09 / (0.9 - 2/3)^2 = 6.35). Every number
  // in full; no median interval under 6 frames.
  EXPECT_EQ(row,
            "distance,0,0.95,0,0,0,0,1,3,2,0.6666666666666666,false,2,1,0.055,0.01,0.86,0.007071067811865472,0,"
            "0.014142135623730963,0.8618259413550599,-85,14.142135623730951,-8.947368421052632,90,14.142135623730951,"
            "1.5,0.7071067811865476,0.6,90,8.947368421052632,0.20765960080204765,0.9385080552796037,uncertain,7,"
            "14.563434173641753,,,,,1.5,,");
}

// What a CSV holds reads back as the very double the summary has: nothing
// rounded away (a translation vector to 0.1 mm hid the jitter of 3e-5 m).
TEST(SweepSummary, CsvNumbersReadBackExactly) {
  RunBuilder run("precise");
  std::vector<FrameSample> frames;
  for (int i = 0; i < 8; ++i) {
    frames.push_back(posed({0.0123456789, -0.000031, 0.95 + 3e-5 * i}, 0.123456789 * (i + 1), 0.01 * i, 0.00042 * i));
  }
  run.add(0, 0, 0.95, 0, frames);
  const RunSummary s = summarize(run.records);
  const PointSummary& p = s.points[0];
  std::istringstream lines(points_csv(s));
  std::string header;
  std::string row;
  ASSERT_TRUE(std::getline(lines, header));
  ASSERT_TRUE(std::getline(lines, row));
  std::vector<std::string> names;
  std::vector<std::string> fields;
  for (auto [text, out] : {std::pair{&header, &names}, std::pair{&row, &fields}}) {
    std::istringstream split(*text);
    for (std::string field; std::getline(split, field, ',');) out->push_back(field);
  }
  ASSERT_EQ(names.size(), 43U);
  const auto field = [&](const std::string& name) {
    const auto at = std::find(names.begin(), names.end(), name);
    EXPECT_NE(at, names.end()) << name;
    return std::stod(fields.at(static_cast<std::size_t>(at - names.begin())));
  };
  EXPECT_EQ(field("tx_m"), p.tvec_m[0].mean);
  EXPECT_EQ(field("ty_m"), p.tvec_m[1].mean);
  EXPECT_EQ(field("tz_m"), p.tvec_m[2].mean);
  EXPECT_EQ(field("tz_sd_m"), p.tvec_m[2].stddev);
  EXPECT_GT(field("tz_sd_m"), 0) << "3e-5 m of jitter is not 0.0000";
  EXPECT_EQ(field("distance_estimated_sd_mm"), 1000 * p.distance_m_estimated.stddev);
  EXPECT_EQ(field("translation_error_sd_mm"), p.translation_error_mm.stddev);
  EXPECT_EQ(field("rate_low"), p.rate_interval.low);
  EXPECT_EQ(field("median_translation_error_mm"), p.median_translation_error_mm->median);
  EXPECT_EQ(field("median_translation_error_low_mm"), *p.median_translation_error_mm->low);
  EXPECT_EQ(field("median_rotation_error_high_deg"), *p.median_rotation_error_deg->high);

  std::istringstream translation(translation_csv(s));
  ASSERT_TRUE(std::getline(translation, header));
  ASSERT_TRUE(std::getline(translation, row));
  EXPECT_EQ(std::stod(row.substr(row.rfind(',') + 1)),
            std::sqrt(p.tvec_m[0].mean * p.tvec_m[0].mean + p.tvec_m[1].mean * p.tvec_m[1].mean +
                      p.tvec_m[2].mean * p.tvec_m[2].mean));
}

TEST(SweepSummary, PointsCsvQuotesAGridNameWithAComma) {
  RunBuilder run("quoted");
  run.records.start.plan.grids[0].name = "near, \"facing\"";
  run.add(0, 0, 0.5, 0, frames_with(1, 0));
  const std::string csv = points_csv(summarize(run.records));
  EXPECT_NE(csv.find("\n\"near, \"\"facing\"\"\",0,0.5,"), std::string::npos) << csv;
}

TEST(SweepSummary, TranslationCsvHasOneLinePerMeasurement) {
  RunBuilder run = csv_run();
  run.add(0, 0, 0.95, 0, {missed()}, 1).rail = 0;
  const std::string csv = translation_csv(summarize(run.records));
  EXPECT_EQ(csv,
            "grid,point,distance_m,angle_deg,measurement,rail_steps,frames,detected,tx_m,ty_m,tz_m,norm_m\n"
            "distance,0,0.95,0,1,0,3,2,0.055,0.01,0.86,0.8618149453333934\n"
            "distance,0,0.95,0,2,0,1,0,,,,\n");
}

TEST(SweepSummary, Table61HasTheThesisColumnAndOneColumnPerRun) {
  const RunSummary thesis = summarize(thesis_shaped_run().records);
  const RunSummary spreads = summarize(spread_run().records);
  const std::string table = table_6_1({thesis, spreads});
  EXPECT_NE(table.find("| | Thesis: paper marker | 20261201T061500Z-thesis (frame8 #165, 80 mm) | spreads (frame8 "
                       "#165, 80 mm) |"),
            std::string::npos)
      << table;
  // Every point has 10 frames or fewer: 10 of 10 may be below 90 %.
  EXPECT_NE(table.find("| Maximum detection distance | 120 cm | 70 cm (uncertain) | ≥100 cm (uncertain) |"),
            std::string::npos)
      << table;
  // spreads' 0.5 m point only faces (one angle): not swept there.
  EXPECT_NE(table.find("| Maximum viewing angle at 50 cm | 60° | +10° (uncertain) / −30° (uncertain) | — |"),
            std::string::npos)
      << table;
  // 4 of 10 at 95 cm facing is surely below: decided.
  EXPECT_NE(table.find("| Maximum viewing angle at 95 cm | 45° | not reached | — |"), std::string::npos) << table;
  // 95 cm was not measured: interpolated between 50 cm (10 %, 100 mm, 3°)
  // and 100 cm (2 %, 20 mm, 2°), 0.9 of the way. 120 cm lies beyond the
  // sweep. 100 cm is the reach. Not pooled.
  EXPECT_NE(table.find("| Median distance error | 9.2 cm at 95 cm (~9.7%) | — | 2.8 % at 95 cm (interpolated from 50 "
                       "and 100 cm); 2.0 % at 100 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median translation error | not measured | — | 2.8 cm at 95 cm (interpolated from 50 and 100 "
                       "cm); 2.0 cm at 100 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median rotation error | not measured | — | 2.1° at 95 cm (interpolated from 50 and 100 cm); "
                       "2.0° at 100 cm (farthest) |"),
            std::string::npos)
      << table;
  // |t| over the 100 cm point's frames: z 0.9, 1.0, 1.1, about 10 cm; the
  // 50 cm point has one frame, no spread, so 95 cm takes 100 cm's.
  EXPECT_NE(table.find("| Distance jitter (SD over a point's frames) | not measured | — | 10.0 cm at 95 cm (measured "
                       "at 100 cm, the nearest); 10.0 cm at 100 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_EQ(table.find("over all"), std::string::npos) << "nothing pooled: " << table;
  EXPECT_NE(table.find("60° at 50 cm and 45° at 95 cm; this table follows the text"), std::string::npos) << table;
}

TEST(SweepSummary, Table61MarksLimitsTheSweepDidNotFind) {
  RunBuilder run("open-ended");
  run.add(0, 0, 0.5, 0, frames_with(10, 10));
  run.add(0, 1, 0.95, 0, frames_with(10, 10));
  run.add(1, 2, 0.5, 10, frames_with(10, 10));
  run.add(1, 3, 0.5, 20, frames_with(10, 10));
  run.add(1, 4, 0.5, -10, frames_with(10, 10));
  run.add(1, 5, 0.5, -20, frames_with(10, 0));
  run.add(0, 6, 0.95, 0, {posed({0, 0, 0.95}, 2.5, 1, 0.5)});
  const std::string table = table_6_1({summarize(run.records)});
  EXPECT_NE(table.find("| Maximum detection distance | 120 cm | ≥95 cm (uncertain) |"), std::string::npos) << table;
  EXPECT_NE(table.find("| Maximum viewing angle at 50 cm | 60° | +≥20° (uncertain) / −10° (uncertain) |"),
            std::string::npos)
      << table;
  // Below a centimetre the translation error is in millimetres.
  EXPECT_NE(table.find("| Median translation error | not measured | 2.5 mm at 95 cm (farthest) |"), std::string::npos)
      << table;
}

// Pooled over a sweep, the near points' small errors hide the far ones':
// Table 6.1 gives the errors at the thesis's 95 and 120 cm and at the
// run's reach, each the median over that point's frames.
TEST(SweepSummary, Table61GivesThePoseErrorsAtTheThesisDistancesAndAtTheReach) {
  RunBuilder run("far-bias");
  std::size_t point = 0;
  // Distance error 1, 2, 3 mm at each near point: 0.2 % at 50 cm.
  for (const double d : {0.5, 0.6, 0.7, 0.8}) {
    run.add(0, point++, d, 0, {posed({0, 0, d}, 1, 1, 0.1), posed({0, 0, d}, 2, 1, 0.1), posed({0, 0, d}, 3, 1, 0.1)});
  }
  // 95 cm: |-1.9|, 1.9, 3.8 mm of 950: median 0.2 %.
  run.add(0, point++, 0.95, 0,
          {posed({0, 0, 0.95}, 2, -1.9, 0.2), posed({0, 0, 0.95}, 2, 1.9, 0.2), posed({0, 0, 0.95}, 4, 3.8, 0.4)});
  // 120 cm: 6, 6, 12 mm: 0.5 %.
  run.add(0, point++, 1.2, 0,
          {posed({0, 0, 1.2}, 6, 6, 0.5), posed({0, 0, 1.2}, 6, 6, 0.5), posed({0, 0, 1.2}, 12, 12, 1.5)});
  // 250 cm, the farthest detected: -50 mm each, 2 %, 30 mm, 3 deg.
  run.add(0, point++, 2.5, 0, {posed({0, 0, 2.45}, 30, -50, 3), posed({0, 0, 2.45}, 30, -50, 3)});
  run.add(0, point++, 2.7, 0, frames_with(10, 2));
  const std::string table = table_6_1({summarize(run.records)});
  // Small errors keep two significant digits.
  EXPECT_NE(table.find("| Median distance error | 9.2 cm at 95 cm (~9.7%) | 0.20 % at 95 cm; 0.50 % at 120 cm; 2.0 % "
                       "at 250 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median translation error | not measured | 2.0 mm at 95 cm; 6.0 mm at 120 cm; 3.0 cm at "
                       "250 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_NE(
      table.find(
          "| Median rotation error | not measured | 0.20° at 95 cm; 0.50° at 120 cm; 3.0° at 250 cm (farthest) |"),
      std::string::npos)
      << table;
  // Every frame of a point alike: no jitter.
  EXPECT_NE(table.find("| Distance jitter (SD over a point's frames) | not measured | 0.000 mm at 95 cm; 0.000 mm at "
                       "120 cm; 0.000 mm at 250 cm (farthest) |"),
            std::string::npos)
      << table;
}

// With frames enough, each figure has its 95% interval; a thesis distance
// the sweep stepped over is interpolated between its neighbours, and says so.
TEST(SweepSummary, Table61InterpolatesAThesisDistanceNotMeasuredWithItsInterval) {
  RunBuilder run("stepped");
  const auto errors = [](double d, double first_mm) {
    std::vector<FrameSample> frames;
    for (int i = 0; i < 10; ++i) frames.push_back(posed({0, 0, d}, first_mm + i, 0, 0.1 * (i + 1)));
    return frames;
  };
  run.add(0, 0, 0.95, 0, errors(0.95, 1));  // 1..10 mm: median 5.5, ranks 2 and 9
  run.add(0, 1, 1.10, 0, errors(1.10, 1));
  run.add(0, 2, 1.30, 0, errors(1.30, 3));  // 3..12 mm: median 7.5 [4, 11]
  run.add(0, 3, 1.40, 0, frames_with(10, 0));
  const std::string table = table_6_1({summarize(run.records)});
  EXPECT_NE(table.find("| Median translation error | not measured | 5.5 mm [2.0, 9.0] at 95 cm; 6.5 mm [3.0, 10.0] at "
                       "120 cm (interpolated from 110 and 130 cm); 7.5 mm [4.0, 11.0] at 130 cm (farthest) |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median rotation error | not measured | 0.55° [0.20, 0.90] at 95 cm; "), std::string::npos)
      << table;
}

TEST(SweepSummary, Table61MaxDistanceNotReachedWhenTheNearestFails) {
  RunBuilder run("fails");
  run.add(0, 0, 0.5, 0, frames_with(10, 0));
  const std::string table = table_6_1({summarize(run.records)});
  EXPECT_NE(table.find("| Maximum detection distance | 120 cm | not reached |"), std::string::npos) << table;
}

// ---------------------------------------------------------------------------
// The paper and the socket marker compared (Table 6.1's two columns)

RunBuilder marker_run(const std::string& run_id, Mounting mounting) {
  RunBuilder run(run_id);
  run.records.start.plan.name = run_id;
  run.records.start.plan.marker.mounting = mounting;
  return run;
}

// An angle sweep at one distance: `reached_to` and every angle below it
// found in every frame, the angles beyond it in none; 40 frames a point, so
// that each rate's interval decides it (40 of 40: [91.2, 100] %).
RunBuilder angle_run(const std::string& run_id, Mounting mounting, double distance_m, std::vector<double> angles,
                     double reached_to) {
  RunBuilder run = marker_run(run_id, mounting);
  std::size_t point = 0;
  for (const double a : angles) run.add(1, point++, distance_m, a, frames_with(40, a <= reached_to ? 40 : 0));
  return run;
}

// `frames` frames, each with this pose and these errors.
std::vector<FrameSample> posed_frames(int frames, std::array<double, 3> tvec, double translation_error_mm,
                                      double distance_error_mm, double rotation_error_deg) {
  return std::vector<FrameSample>(static_cast<std::size_t>(frames),
                                  posed(tvec, translation_error_mm, distance_error_mm, rotation_error_deg));
}

// The paper marker as the thesis found it: to 120 cm facing, 60° at 50 cm,
// 45° at 95 cm; its 50 cm point measured twice, 2 cm apart in z.
std::vector<RunRecords> paper_runs() {
  RunBuilder distance = marker_run("paper-distance", Mounting::paper);
  distance.add(0, 0, 0.50, 0, posed_frames(20, {0, 0, 0.50}, 4, 2, 1), 0);
  distance.add(0, 0, 0.50, 0, posed_frames(20, {0, 0, 0.52}, 20, 20, 1), 1);
  std::size_t point = 1;
  for (const double d : {0.7, 0.9, 1.1, 1.2}) distance.add(0, point++, d, 0, frames_with(40, 40));
  distance.add(0, point++, 1.3, 0, frames_with(40, 20));
  return {std::move(distance.records),
          angle_run("paper-angle-50cm", Mounting::paper, 0.50, {0, 10, 20, 30, 40, 50, 60, 70}, 60).records,
          angle_run("paper-angle-95cm", Mounting::paper, 0.95, {0, 15, 30, 45, 60}, 45).records};
}

// The socket marker: to 81 cm facing, never found at 95 cm (facing nor
// turned), 45° at 50 cm, 20° at 60 cm; no angle sweep at 72 cm. Its 72 cm
// point measured twice, 5 mm apart in z.
std::vector<RunRecords> socket_runs() {
  RunBuilder distance = marker_run("socket-distance", Mounting::socket);
  distance.add(0, 0, 0.72, 0, posed_frames(20, {0, 0, 0.715}, 10, -5, 2), 0);
  distance.add(0, 0, 0.72, 0, posed_frames(20, {0, 0, 0.720}, 10, -5, 2), 1);
  std::size_t point = 1;
  for (const double d : {0.75, 0.78, 0.81}) distance.add(0, point++, d, 0, frames_with(40, 40));
  distance.add(0, point++, 0.84, 0, frames_with(40, 12));
  distance.add(0, point++, 0.95, 0, frames_with(40, 0));
  return {std::move(distance.records),
          angle_run("socket-angle-50cm", Mounting::socket, 0.50, {0, 15, 30, 45, 60}, 45).records,
          angle_run("socket-angle-60cm", Mounting::socket, 0.60, {0, 10, 20, 30}, 20).records,
          angle_run("socket-angle-95cm", Mounting::socket, 0.95, {0, 15, 30}, -1).records};
}

RunSummary together(const std::vector<RunRecords>& runs) {
  std::vector<const RunRecords*> pointers;
  for (const auto& run : runs) pointers.push_back(&run);
  return summarize_together(pointers);
}

TEST(SweepSummary, RunsOfOneMarkerTogetherAreOneRunOfTheirGrids) {
  const auto runs = socket_runs();
  const RunSummary s = together(runs);
  EXPECT_EQ(s.run_id, "socket-distance, socket-angle-50cm, socket-angle-60cm, socket-angle-95cm");
  EXPECT_EQ(s.marker.mounting, Mounting::socket);
  EXPECT_EQ(s.points.size(), 6U + 5U + 4U + 3U);
  // The angle runs' facing points at 50 and 60 cm lie before the distance
  // sweep's first and were found: the limit is still the distance sweep's.
  ASSERT_TRUE(s.max_distance_m.has_value());
  EXPECT_DOUBLE_EQ(*s.max_distance_m, 0.81);
  ASSERT_EQ(s.max_angle.size(), 3U);
  EXPECT_DOUBLE_EQ(s.max_angle[0].distance_m, 0.5);
  EXPECT_EQ(s.max_angle[0].positive_deg, 45.0);
  EXPECT_EQ(s.max_angle[1].positive_deg, 20.0);
  EXPECT_EQ(s.max_angle[2].positive_deg, std::nullopt);  // 95 cm: not found facing
  ASSERT_TRUE(s.max_tvec_difference_m.has_value());
  EXPECT_NEAR(*s.max_tvec_difference_m, 0.005, 1e-12);
  // Every frame with a pose: 20 at 5 mm in 720.
  ASSERT_TRUE(s.median_distance_error_pct.has_value());
  EXPECT_NEAR(*s.median_distance_error_pct, 100 * 5.0 / 720, 1e-9);
}

// A plan that does not say its mounting ran on what markerd's config said,
// which the start record keeps: the run is told apart by it.
TEST(SweepSummary, APlanWithoutAMountingTakesTheOneMarkerdRecorded) {
  auto runs = socket_runs();
  for (auto& run : runs) {
    run.start.plan.marker.mounting.reset();
    run.start.marker = {{"mounting", "socket"}};
  }
  EXPECT_EQ(runs[0].start.marker_mounting(), Mounting::socket);
  EXPECT_EQ(together(runs).marker.mounting, Mounting::socket);
  EXPECT_EQ(summarize(runs[0]).marker.mounting, Mounting::socket);
  // Measured on paper by markerd's config: not one marker with the socket runs.
  runs[2].start.marker = {{"mounting", "paper"}};
  EXPECT_THROW((void)together(runs), std::invalid_argument);
  // Records older than both say nothing.
  runs[2].start.marker = nlohmann::json::object();
  EXPECT_EQ(runs[2].start.marker_mounting(), std::nullopt);
  EXPECT_NO_THROW((void)together(runs));
}

TEST(SweepSummary, RunsOfDifferentMarkersDoNotGoTogether) {
  auto runs = socket_runs();
  runs[1].start.plan.marker.id = 12;
  try {
    (void)together(runs);
    FAIL() << "a column of two markers";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()),
              "runs socket-distance (frame8 #165, 80 mm, on a socket frame) and socket-angle-50cm (frame8 #12, 80 mm, "
              "on a socket frame) measured different markers");
  }
  runs = socket_runs();
  runs[2].start.plan.marker.mounting = Mounting::paper;
  EXPECT_THROW((void)together(runs), std::invalid_argument);
  runs = socket_runs();
  runs[3].start.plan.detection_threshold = 0.5;
  try {
    (void)together(runs);
    FAIL() << "a column of two thresholds";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("socket-angle-95cm (0.5) count a point as detected at different rates"),
              std::string::npos)
        << e.what();
  }
}

TEST(SweepSummary, Table61ByMarkerSetsEachMarkersRunsBesideTheThesis) {
  const auto paper = paper_runs();
  const auto socket = socket_runs();
  const std::string table = table_6_1_by_marker(
      {MarkerColumn{Mounting::paper, together(paper)}, MarkerColumn{Mounting::socket, together(socket)}});
  const std::vector<std::string> rows = {
      "| | Thesis: paper marker | Paper marker: paper-distance, paper-angle-50cm, paper-angle-95cm (frame8 #165, 80 "
      "mm, "
      "on paper) | Thesis: socket marker | Socket marker: socket-distance, socket-angle-50cm, socket-angle-60cm, "
      "socket-angle-95cm (frame8 #165, 80 mm, on a socket frame) |",
      "| --- | --- | --- | --- | --- |",
      "| Maximum detection distance | 120 cm | 120 cm | 81 cm | 81 cm |",
      "| Maximum viewing angle at 50 cm | 60° | 60° | 45° | 45° |",
      // A distance the thesis did not measure, swept for the socket only.
      "| Maximum viewing angle at 60 cm | not measured | not swept | not measured | 20° |",
      // The socket's 72 cm angle run is missing: said, not made up.
      "| Maximum viewing angle at 72 cm | not measured | not swept | 30° | not swept |",
      "| Maximum viewing angle at 95 cm | 45° (stable to 30°) | 45° | not detected | not reached |",
      "| Translation vector spread | about 2 cm (appendix C: 1.7 cm) | 2.0 cm | about 2 cm (appendix C: 1.9 cm) | 5.0 "
      "mm "
      "|",
      // The socket's errors at the thesis's 72 cm (its 81 cm point has no
      // pose); the paper runs' facing points at 95 and 120 cm have none:
      // over all frames, and said so.
      "| Median distance error | 9.2 cm at 95 cm (~9.7%) | 2.2 % over all frames | 7.7 cm at 72 cm (~10.7%) | 0.69 % "
      "[0.69, 0.69] at 72 cm |",
      "| Median translation error | not measured | 1.2 cm over all frames | not measured | 1.0 cm [1.0, 1.0] at 72 cm "
      "|",
      "| Median rotation error | not measured | 1.0° over all frames | not measured | 2.0° [2.0, 2.0] at 72 cm |",
      // 20 frames at 0.715 m and 20 at 0.720 m: 2.5 mm * sqrt(40 / 39).
      "| Distance jitter (SD over a point's frames) | not measured | — | not measured | 2.5 mm at 72 cm |",
  };
  std::string expected;
  for (const auto& row : rows) expected += row + "\n";
  EXPECT_EQ(table.substr(0, expected.size()), expected) << table;
  EXPECT_NE(table.find("not swept: the runs did not sweep it"), std::string::npos) << table;
}

TEST(SweepSummary, Table61ByMarkerWithOneMarkerHasItsColumnsOnly) {
  const std::string table = table_6_1_by_marker({MarkerColumn{Mounting::socket, together(socket_runs())}});
  EXPECT_EQ(table.find("Thesis: paper marker"), std::string::npos) << table;
  EXPECT_NE(table.find("| Maximum detection distance | 81 cm | 81 cm |\n"), std::string::npos) << table;
}

// ---------------------------------------------------------------------------
// write_report

using test_support::TempDir;

bool on_path(const std::string& program) { return test_support::find_program(program).has_value(); }

RunRecords reported_run() {
  RunBuilder run = thesis_shaped_run();
  run.records.events = {
      RunEvent{run.records.start.time, "started", "", 0},
      RunEvent{run.records.start.time + std::chrono::minutes(3), "suspended", "camera lost: /dev/video0 vanished", 4},
      RunEvent{run.records.start.time + std::chrono::minutes(5), "fault_cleared", "", 4},
  };
  // Poses at the facing points, for appendix C and the error plot.
  for (auto& r : run.records.points) {
    if (r.angle_deg != 0 || r.frames.empty()) continue;
    r.frames[0] = posed({0.05, 0.01, r.distance_m * 0.9}, 10 * r.distance_m, -100 * r.distance_m, 1);
  }
  return std::move(run.records);
}

// A PDF as a reader takes it: the header, a cross-reference table or
// stream, the end-of-file marker; and, where poppler's tools are installed
// (tools/install-deps.sh installs poppler-utils), one page holding `text`.
void expect_a_pdf_with(const fs::path& pdf, const std::string& text) {
  const std::string bytes = test_support::read_file(pdf);
  ASSERT_GT(bytes.size(), 1000U) << pdf;
  EXPECT_EQ(bytes.substr(0, 5), "%PDF-") << pdf;
  EXPECT_NE(bytes.find("startxref", bytes.size() - 1024), std::string::npos) << pdf;
  EXPECT_NE(bytes.find("%%EOF", bytes.size() - 16), std::string::npos) << pdf;
  if (!on_path("pdfinfo") || !on_path("pdftotext")) {
    ADD_FAILURE() << "pdfinfo and pdftotext are not on PATH (tools/install-deps.sh installs poppler-utils)";
    return;
  }
  const auto info = test_support::run_program({"pdfinfo", pdf.string()});
  EXPECT_EQ(info.code, 0) << info.describe();
  const std::size_t pages = info.out.find("Pages:");
  ASSERT_NE(pages, std::string::npos) << info.out;
  EXPECT_EQ(std::stoi(info.out.substr(pages + 6)), 1) << info.out;
  const auto words = test_support::run_program({"pdftotext", pdf.string(), "-"});
  EXPECT_EQ(words.code, 0) << words.describe();
  EXPECT_NE(words.out.find(text), std::string::npos) << pdf << ":\n" << words.out;
}

TEST(SweepReport, WritesTheReportCsvsAndFourPlotsAsSvgAndPdf) {
  if (!on_path("gnuplot")) GTEST_SKIP() << "gnuplot is not on PATH (tools/install-deps.sh installs gnuplot-nox)";
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path() / "report";  // created by write_report
  const ReportFiles files = write_report({reported_run()}, options);

  EXPECT_EQ(files.report, options.output_directory / "report.md");
  const std::string md = test_support::read_file(files.report);
  EXPECT_NE(md.find("# Sweep report: 20261201T061500Z-thesis"), std::string::npos);
  EXPECT_NE(md.find("2026-12-01 06:15:00 UTC"), std::string::npos);
  EXPECT_NE(md.find("| Maximum detection distance | 120 cm | 70 cm (uncertain) |"), std::string::npos) << md;
  EXPECT_NE(md.find("## Appendix C"), std::string::npos);
  // Appendix C's row of the 70 cm point: measurement 1, 250 mm before the
  // rail's 0 (-10000 steps), the pose the frame gave.
  EXPECT_NE(md.find("| 1 | -10000 | 70 cm | [0.0500, 0.0100, 0.6300] |"), std::string::npos) << md;
  EXPECT_NE(md.find("| Norm | | | 0.6321 |"), std::string::npos) << md;
  EXPECT_NE(md.find("camera lost: /dev/video0 vanished"), std::string::npos);
  EXPECT_NE(md.find("1 suspension"), std::string::npos);
  EXPECT_NE(md.find("## Threshold calls\n\n" + files.threshold_calls), std::string::npos) << md;
  EXPECT_NE(files.threshold_calls.find("| 20261201T061500Z-thesis | Maximum detection distance | 70 cm | uncertain |"),
            std::string::npos)
      << files.threshold_calls;
  EXPECT_NE(md.find("| distance | 0.700 | 0 | 10 | 90.0 % [59.6, 98.2] | yes, in doubt (on the threshold) |"),
            std::string::npos)
      << md;
  const std::vector<std::pair<std::string, std::string>> plots = {
      {"rate-vs-distance", "Detection rate of the facing points"},
      {"pose-error-vs-distance", "rotation error"},
      {"pose-error-vs-angle", "viewing angle"},
      {"rate-map", "detection rate against viewing angle"},
  };
  EXPECT_EQ(files.plots.size(), 2 * plots.size());
  for (const auto& [name, text] : plots) {
    EXPECT_NE(md.find("](" + name + ".svg)"), std::string::npos) << name;
    EXPECT_NE(md.find("`" + name + ".pdf`"), std::string::npos) << name;
    const fs::path svg = options.output_directory / (name + ".svg");
    const fs::path pdf = options.output_directory / (name + ".pdf");
    EXPECT_NE(std::find(files.plots.begin(), files.plots.end(), svg), files.plots.end()) << name;
    EXPECT_NE(std::find(files.plots.begin(), files.plots.end(), pdf), files.plots.end()) << name;
    EXPECT_NE(test_support::read_file(svg).find("<svg"), std::string::npos) << name;
    EXPECT_NE(test_support::read_file(svg).find(text), std::string::npos) << name;
    expect_a_pdf_with(pdf, text);
    EXPECT_TRUE(fs::exists(options.output_directory / (name + ".gp"))) << name;
  }
  // Error bars: the rates' Wilson intervals, the medians' intervals.
  const std::string rate = test_support::read_file(options.output_directory / "rate-vs-distance.gp");
  EXPECT_NE(rate.find("'rate-vs-distance-1.dat' using 1:2:3:4 with yerrorlines"), std::string::npos) << rate;
  EXPECT_NE(test_support::read_file(options.output_directory / "rate-vs-distance-1.dat")
                .find("\n0.7 90 59.585 98.2124 10 9\n"),
            std::string::npos);
  const std::string errors = test_support::read_file(options.output_directory / "pose-error-vs-distance.gp");
  for (const char* columns :
       {"using 1:2:3:4 with yerrorlines", "using 1:5:6:7 with yerrorlines", "using 1:8:9:10 with yerrorlines"}) {
    EXPECT_NE(errors.find(columns), std::string::npos) << columns << "\n" << errors;
  }
  EXPECT_EQ(test_support::read_file(options.output_directory / "summary.csv"), points_csv(summarize(reported_run())));
  EXPECT_EQ(test_support::read_file(options.output_directory / "translation.csv"),
            translation_csv(summarize(reported_run())));
  // Thesis-shaped (a row and two columns of distance x angle): curves of rate
  // against angle, one per distance swept, not a heat map.
  const std::string rate_map = test_support::read_file(options.output_directory / "rate-map.gp");
  EXPECT_NE(rate_map.find("'rate-map-1.dat' index 1 using 1:2:4:5 with yerrorlines"), std::string::npos) << rate_map;
  EXPECT_EQ(rate_map.find("boxxyerror"), std::string::npos) << rate_map;
}

TEST(SweepReport, SideBySideHasAColumnAndACurvePerRun) {
  if (!on_path("gnuplot")) GTEST_SKIP() << "gnuplot is not on PATH (tools/install-deps.sh installs gnuplot-nox)";
  // The second run sweeps angle at five distances, too many curves for one
  // panel: a heat map.
  RunBuilder block("20261202T061500Z-block");
  std::size_t point = 0;
  for (const double d : {0.5, 0.75, 1.0, 1.25, 1.5}) {
    for (const double a : {-30.0, 0.0, 30.0}) block.add(0, point++, d, a, frames_with(4, d < 1 ? 4 : 1));
  }
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  const ReportFiles files = write_report({reported_run(), block.records}, options);

  const std::string md = test_support::read_file(files.report);
  EXPECT_NE(md.find("# Sweep report: 20261201T061500Z-thesis, 20261202T061500Z-block"), std::string::npos);
  EXPECT_NE(md.find("| Maximum detection distance | 120 cm | 70 cm (uncertain) | 75 cm (uncertain) |"),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("## Points: 20261202T061500Z-block"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir.path() / "summary-20261201T061500Z-thesis.csv"));
  EXPECT_TRUE(fs::exists(dir.path() / "translation-20261202T061500Z-block.csv"));
  EXPECT_EQ(files.csv.size(), 4u);

  const std::string rate = test_support::read_file(dir.path() / "rate-vs-distance.gp");
  EXPECT_NE(rate.find("'rate-vs-distance-1.dat' using 1:2"), std::string::npos) << rate;
  EXPECT_NE(rate.find("'rate-vs-distance-2.dat' using 1:2"), std::string::npos) << rate;
  EXPECT_NE(rate.find("90 with lines dt 2"), std::string::npos) << "the threshold, dashed: " << rate;
  // The runs reach past 1.2 m: the thesis's maximum distance, dotted.
  EXPECT_NE(rate.find("set arrow 1 from 1.2, graph 0 to 1.2, graph 1 nohead dt 3"), std::string::npos) << rate;
  EXPECT_NE(rate.find("'thesis, paper marker: 120 cm'"), std::string::npos) << rate;
  // Its maximum angles where the runs' angles reach: 50 cm's 60° is beyond
  // the second run's 30°; no line there.
  const std::string angles = test_support::read_file(dir.path() / "pose-error-vs-angle.gp");
  EXPECT_EQ(angles.find("60° at 50 cm"), std::string::npos) << angles;
  const std::string rate_map = test_support::read_file(dir.path() / "rate-map.gp");
  EXPECT_NE(rate_map.find("'rate-map-2.dat' using 1:2:(0.125):(15):3 with boxxyerror"), std::string::npos) << rate_map;
  EXPECT_NE(rate_map.find("set multiplot layout 2,1"), std::string::npos);
}

TEST(SweepReport, ByMarkerHasTheTwoColumnTableAndEveryRun) {
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  options.plots = false;
  const auto paper = paper_runs();
  const auto socket = socket_runs();
  const ReportFiles files =
      write_report_by_marker({MarkerRuns{Mounting::paper, paper}, MarkerRuns{Mounting::socket, socket}}, options);
  EXPECT_EQ(files.table_6_1, table_6_1_by_marker({MarkerColumn{Mounting::paper, together(paper)},
                                                  MarkerColumn{Mounting::socket, together(socket)}}));
  const std::string md = test_support::read_file(files.report);
  EXPECT_NE(md.find("## Table 6.1\n\n" + files.table_6_1), std::string::npos) << md;
  EXPECT_NE(md.find("Runs of the marker on paper: paper-distance, paper-angle-50cm, paper-angle-95cm; runs of the "
                    "marker on a socket frame: socket-distance, "),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| Table 6.1 column | marker on paper | marker on paper | marker on paper | marker on a socket "
                    "frame |"),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| Marker | frame8 #165, 80 mm, on paper |"), std::string::npos) << md;
  EXPECT_NE(md.find("## Points: socket-angle-60cm"), std::string::npos) << md;
  EXPECT_EQ(files.csv.size(), 2 * 7U);
  EXPECT_TRUE(fs::exists(dir.path() / "summary-socket-angle-95cm.csv"));
}

// The reference lines are the thesis's limits for the marker the run
// measured: the socket marker's 81 cm, and 45° at 50 cm, not the paper's.
TEST(SweepReport, ASocketRunIsDrawnAgainstTheThesisSocketMarker) {
  if (!on_path("gnuplot")) GTEST_SKIP() << "gnuplot is not on PATH (tools/install-deps.sh installs gnuplot-nox)";
  const auto socket = socket_runs();
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  (void)write_report({socket[0], socket[1]}, options);
  const std::string rate = test_support::read_file(dir.path() / "rate-vs-distance.gp");
  EXPECT_NE(rate.find("'thesis, socket marker: 81 cm'"), std::string::npos) << rate;
  EXPECT_EQ(rate.find("paper marker"), std::string::npos) << rate;
  const std::string angles = test_support::read_file(dir.path() / "rate-map.gp");
  EXPECT_NE(angles.find("'thesis, socket marker: 45° at 50 cm'"), std::string::npos) << angles;
  EXPECT_EQ(angles.find("paper marker"), std::string::npos) << angles;
  expect_a_pdf_with(dir.path() / "rate-vs-distance.pdf", "thesis, socket marker: 81 cm");
}

TEST(SweepReport, ByMarkerRefusesAMarkerWithoutRuns) {
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path() / "out";
  options.plots = false;
  EXPECT_THROW((void)write_report_by_marker(
                   {MarkerRuns{Mounting::paper, paper_runs()}, MarkerRuns{Mounting::socket, {}}}, options),
               std::invalid_argument);
  EXPECT_FALSE(fs::exists(options.output_directory));
}

TEST(SweepReport, WithoutPlotsNeedsNoGnuplot) {
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  options.plots = false;
  options.gnuplot = "/nonexistent/gnuplot";
  const ReportFiles files = write_report({reported_run()}, options);
  EXPECT_TRUE(files.plots.empty());
  EXPECT_TRUE(fs::exists(files.report));
  EXPECT_EQ(test_support::read_file(files.report).find(".svg"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir.path() / "rate-map.gp"));
}

TEST(SweepReport, FailingGnuplotIsAnErrorNamingIt) {
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  options.gnuplot = "/bin/false";
  try {
    (void)write_report({reported_run()}, options);
    FAIL() << "a gnuplot that fails must fail the report";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("gnuplot"), std::string::npos) << what;
    EXPECT_NE(what.find("/bin/false"), std::string::npos) << what;
    EXPECT_NE(what.find("exit status 1"), std::string::npos) << what;
  }
}

TEST(SweepReport, GnuplotsComplaintIsInTheError) {
  const TempDir dir;
  // A stand-in that complains on stderr the way gnuplot does on a bad script.
  const fs::path fake = dir.path() / "fake-gnuplot";
  fs::create_directories(dir.path());
  {
    std::ofstream script(fake);
    script << "#!/bin/sh\necho \"line 7: unknown terminal type\" >&2\nexit 1\n";
  }
  fs::permissions(fake, fs::perms::owner_all);
  ReportOptions options;
  options.output_directory = dir.path() / "out";
  options.gnuplot = fake.string();
  try {
    (void)write_report({reported_run()}, options);
    FAIL() << "a gnuplot that fails must fail the report";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("gnuplot"), std::string::npos) << what;
    EXPECT_NE(what.find("line 7: unknown terminal type"), std::string::npos) << what;
    EXPECT_NE(what.find("rate-vs-distance.gp"), std::string::npos) << what;
  }
}

TEST(SweepReport, MissingGnuplotSaysHowToDoWithout) {
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path();
  options.gnuplot = "markerd-no-such-gnuplot";
  try {
    (void)write_report({reported_run()}, options);
    FAIL() << "a missing gnuplot must fail the report";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("gnuplot: cannot run 'markerd-no-such-gnuplot'"), std::string::npos) << what;
  }
}

TEST(SweepReport, UnwritableDirectoryIsNamed) {
  const TempDir dir;
  fs::create_directories(dir.path());
  std::ofstream(dir.path() / "a-file") << "x";
  ReportOptions options;
  options.output_directory = dir.path() / "a-file" / "report";
  options.plots = false;
  try {
    (void)write_report({reported_run()}, options);
    FAIL() << "a report directory under a file cannot be made";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find((dir.path() / "a-file" / "report").string()), std::string::npos) << e.what();
  }
}

}  // namespace
