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
  EXPECT_DOUBLE_EQ(*p.median_translation_error_mm, 20);
  ASSERT_TRUE(p.median_distance_error_pct);
  EXPECT_DOUBLE_EQ(*p.median_distance_error_pct, 2) << "the median of |-2|, |0|, |4|";
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
            "median_abs_distance_error_pct");
  // tz: 0.85, 0.87 (sd 0.02 / sqrt 2 = 0.0141); |t| 0.8515, 0.8721; distance
  // errors -95, -75 mm (sd 14.14) = -10 %, -7.89 % of 950 mm.
  EXPECT_EQ(row,
            "distance,0,0.950,0.00,0.000,0,0.000,1,3,2,0.6667,false,2,1,0.0550,0.0100,0.8600,0.0071,0.0000,0.0141,"
            "0.8618,-85.00,14.14,-8.95,90.00,14.14,1.500,0.707,0.600,90.00,8.95");
}

TEST(SweepSummary, PointsCsvQuotesAGridNameWithAComma) {
  RunBuilder run("quoted");
  run.records.start.plan.grids[0].name = "near, \"facing\"";
  run.add(0, 0, 0.5, 0, frames_with(1, 0));
  const std::string csv = points_csv(summarize(run.records));
  EXPECT_NE(csv.find("\n\"near, \"\"facing\"\"\",0,0.500,"), std::string::npos) << csv;
}

TEST(SweepSummary, TranslationCsvHasOneLinePerMeasurement) {
  RunBuilder run = csv_run();
  run.add(0, 0, 0.95, 0, {missed()}, 1).rail = 0;
  const std::string csv = translation_csv(summarize(run.records));
  EXPECT_EQ(csv,
            "grid,point,distance_m,angle_deg,measurement,rail_steps,frames,detected,tx_m,ty_m,tz_m,norm_m\n"
            "distance,0,0.950,0.00,1,0,3,2,0.0550,0.0100,0.8600,0.8618\n"
            "distance,0,0.950,0.00,2,0,1,0,,,,\n");
}

TEST(SweepSummary, Table61HasTheThesisColumnAndOneColumnPerRun) {
  const RunSummary thesis = summarize(thesis_shaped_run().records);
  const RunSummary spreads = summarize(spread_run().records);
  const std::string table = table_6_1({thesis, spreads});
  EXPECT_NE(table.find("| | Thesis: paper marker | 20261201T061500Z-thesis (frame8 #165, 80 mm) | spreads (frame8 "
                       "#165, 80 mm) |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Maximum detection distance | 120 cm | 70 cm | ≥100 cm |"), std::string::npos) << table;
  // spreads' 0.5 m point only faces (one angle): not swept there.
  EXPECT_NE(table.find("| Maximum viewing angle at 50 cm | 60° | +10° / −30° | — |"), std::string::npos) << table;
  EXPECT_NE(table.find("| Maximum viewing angle at 95 cm | 45° | not reached | — |"), std::string::npos) << table;
  EXPECT_NE(table.find(
                "| Median distance error | 9.2 cm at 95 cm (~9.7%) | — | 2.0 % at 100 cm (farthest); 3.0 % over all |"),
            std::string::npos)
      << table;
  EXPECT_NE(
      table.find("| Median translation error | not measured | — | 2.0 cm at 100 cm (farthest); 4.0 cm over all |"),
      std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median rotation error | not measured | — | 2.0° at 100 cm (farthest); 2.5° over all |"),
            std::string::npos)
      << table;
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
  EXPECT_NE(table.find("| Maximum detection distance | 120 cm | ≥95 cm |"), std::string::npos) << table;
  EXPECT_NE(table.find("| Maximum viewing angle at 50 cm | 60° | +≥20° / −10° |"), std::string::npos) << table;
  // Below a centimetre the translation error is in millimetres.
  EXPECT_NE(table.find("| Median translation error | not measured | 2.5 mm at 95 cm (farthest); 2.5 mm over all |"),
            std::string::npos)
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
  // Over all 20 frames: |error| % sorted, the 10th and 11th are 0.2 %; the
  // translation errors' 2 and 3 mm.
  EXPECT_NE(table.find("| Median distance error | 9.2 cm at 95 cm (~9.7%) | 0.2 % at 95 cm, 0.5 % at 120 cm, 2.0 % "
                       "at 250 cm (farthest); 0.2 % over all |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| Median translation error | not measured | 2.0 mm at 95 cm, 6.0 mm at 120 cm, 3.0 cm at "
                       "250 cm (farthest); 2.5 mm over all |"),
            std::string::npos)
      << table;
  EXPECT_NE(
      table.find("| Median rotation error | not measured | 0.2° at 95 cm, 0.5° at 120 cm, 3.0° at 250 cm (farthest); "),
      std::string::npos)
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
// found in every frame, the angles beyond it in none.
RunBuilder angle_run(const std::string& run_id, Mounting mounting, double distance_m, std::vector<double> angles,
                     double reached_to) {
  RunBuilder run = marker_run(run_id, mounting);
  std::size_t point = 0;
  for (const double a : angles) run.add(1, point++, distance_m, a, frames_with(10, a <= reached_to ? 10 : 0));
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
  distance.add(0, 0, 0.50, 0, posed_frames(10, {0, 0, 0.50}, 4, 2, 1), 0);
  distance.add(0, 0, 0.50, 0, posed_frames(10, {0, 0, 0.52}, 20, 20, 1), 1);
  std::size_t point = 1;
  for (const double d : {0.7, 0.9, 1.1, 1.2}) distance.add(0, point++, d, 0, frames_with(10, 10));
  distance.add(0, point++, 1.3, 0, frames_with(10, 5));
  return {std::move(distance.records),
          angle_run("paper-angle-50cm", Mounting::paper, 0.50, {0, 10, 20, 30, 40, 50, 60, 70}, 60).records,
          angle_run("paper-angle-95cm", Mounting::paper, 0.95, {0, 15, 30, 45, 60}, 45).records};
}

// The socket marker: to 81 cm facing, never found at 95 cm (facing nor
// turned), 45° at 50 cm, 20° at 60 cm; no angle sweep at 72 cm. Its 72 cm
// point measured twice, 5 mm apart in z.
std::vector<RunRecords> socket_runs() {
  RunBuilder distance = marker_run("socket-distance", Mounting::socket);
  distance.add(0, 0, 0.72, 0, posed_frames(10, {0, 0, 0.715}, 10, -5, 2), 0);
  distance.add(0, 0, 0.72, 0, posed_frames(10, {0, 0, 0.720}, 10, -5, 2), 1);
  std::size_t point = 1;
  for (const double d : {0.75, 0.78, 0.81}) distance.add(0, point++, d, 0, frames_with(10, 10));
  distance.add(0, point++, 0.84, 0, frames_with(10, 3));
  distance.add(0, point++, 0.95, 0, frames_with(10, 0));
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
      // The socket's errors at the thesis's 72 cm; the paper runs' facing
      // points at 95 and 120 cm have no pose: pooled only.
      "| Median distance error | 9.2 cm at 95 cm (~9.7%) | 2.2 % | 7.7 cm at 72 cm (~10.7%) | 0.7 % at 72 cm; 0.7 % "
      "over all |",
      "| Median translation error | not measured | 1.2 cm | not measured | 1.0 cm at 72 cm; 1.0 cm over all |",
      "| Median rotation error | not measured | 1.0° | not measured | 2.0° at 72 cm; 2.0° over all |",
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

TEST(SweepReport, WritesTheReportCsvsAndThreePlots) {
  if (!on_path("gnuplot")) GTEST_SKIP() << "gnuplot is not on PATH (tools/install-deps.sh installs gnuplot-nox)";
  const TempDir dir;
  ReportOptions options;
  options.output_directory = dir.path() / "report";  // created by write_report
  const ReportFiles files = write_report({reported_run()}, options);

  EXPECT_EQ(files.report, options.output_directory / "report.md");
  const std::string md = test_support::read_file(files.report);
  EXPECT_NE(md.find("# Sweep report: 20261201T061500Z-thesis"), std::string::npos);
  EXPECT_NE(md.find("2026-12-01 06:15:00 UTC"), std::string::npos);
  EXPECT_NE(md.find("| Maximum detection distance | 120 cm | 70 cm |"), std::string::npos) << md;
  EXPECT_NE(md.find("## Appendix C"), std::string::npos);
  // Appendix C's row of the 70 cm point: measurement 1, 250 mm before the
  // rail's 0 (-10000 steps), the pose the frame gave.
  EXPECT_NE(md.find("| 1 | -10000 | 70 cm | [0.0500, 0.0100, 0.6300] |"), std::string::npos) << md;
  EXPECT_NE(md.find("| Norm | | | 0.6321 |"), std::string::npos) << md;
  EXPECT_NE(md.find("camera lost: /dev/video0 vanished"), std::string::npos);
  EXPECT_NE(md.find("1 suspension"), std::string::npos);
  for (const char* name : {"rate-vs-distance", "pose-error-vs-distance", "rate-map"}) {
    EXPECT_NE(md.find(std::string("](") + name + ".svg)"), std::string::npos) << name;
    const fs::path svg = options.output_directory / (std::string(name) + ".svg");
    EXPECT_NE(std::find(files.plots.begin(), files.plots.end(), svg), files.plots.end()) << name;
    EXPECT_NE(test_support::read_file(svg).find("<svg"), std::string::npos) << name;
    EXPECT_TRUE(fs::exists(options.output_directory / (std::string(name) + ".gp"))) << name;
  }
  EXPECT_EQ(test_support::read_file(options.output_directory / "summary.csv"), points_csv(summarize(reported_run())));
  EXPECT_EQ(test_support::read_file(options.output_directory / "translation.csv"),
            translation_csv(summarize(reported_run())));
  // Thesis-shaped (a row and two columns of distance x angle): curves of rate
  // against angle, one per distance swept, not a heat map.
  const std::string rate_map = test_support::read_file(options.output_directory / "rate-map.gp");
  EXPECT_NE(rate_map.find("'rate-map-1.dat' index 1 using 1:2"), std::string::npos) << rate_map;
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
  EXPECT_NE(md.find("| Maximum detection distance | 120 cm | 70 cm | 75 cm |"), std::string::npos) << md;
  EXPECT_NE(md.find("## Points: 20261202T061500Z-block"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir.path() / "summary-20261201T061500Z-thesis.csv"));
  EXPECT_TRUE(fs::exists(dir.path() / "translation-20261202T061500Z-block.csv"));
  EXPECT_EQ(files.csv.size(), 4u);

  const std::string rate = test_support::read_file(dir.path() / "rate-vs-distance.gp");
  EXPECT_NE(rate.find("'rate-vs-distance-1.dat' using 1:2"), std::string::npos) << rate;
  EXPECT_NE(rate.find("'rate-vs-distance-2.dat' using 1:2"), std::string::npos) << rate;
  EXPECT_NE(rate.find("90 with lines dt 2"), std::string::npos) << "the threshold, dashed: " << rate;
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
