#pragma once
// A run's results, computed from its records alone (records.hpp): per point
// the detection rate and the mean and spread of the pose and of its error
// against the ground truth; the maximum detection distance and the maximum
// viewing angle at each distance; the thesis's Table 6.1 and its appendix C
// table. Only the records go in, so `markerctl report` can summarise a run
// at any time after (or during) it, on any machine.

#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "markerd/sweep/records.hpp"

namespace markerd::sweep {

// Mean and sample standard deviation of the values seen (n = 0: both 0).
struct Spread {
  std::size_t n = 0;
  double mean = 0;
  double stddev = 0;
};

// One of the measurements (repeats) at a point: appendix C's rows.
struct MeasurementSummary {
  int repeat = 0;
  int frames = 0;
  int detected = 0;
  std::optional<std::int64_t> rail_steps;            // this measurement's rail position, in steps
  std::optional<std::array<double, 3>> mean_tvec_m;  // over the frames with a pose
};

struct PointSummary {
  std::size_t point = 0;  // PlanStep::point
  std::size_t grid = 0;
  std::string grid_name;
  double distance_m = 0;  // planned
  double angle_deg = 0;
  double rail = 0;  // as recorded (the first measurement's)
  double turntable = 0;
  std::optional<std::int64_t> rail_steps;  // rail / units_per_step, when the start record has it
  std::array<double, 3> truth_tvec_m{};
  int frames = 0;
  int detected = 0;
  int frames_corrupt = 0;
  int other_markers = 0;
  double rate = 0;                 // detected / frames (0 without frames)
  bool reached = false;            // rate >= the plan's detection_threshold
  std::array<Spread, 3> tvec_m{};  // x, y, z
  Spread distance_m_estimated;     // |t|
  Spread translation_error_mm;
  Spread distance_error_mm;   // signed
  Spread distance_error_pct;  // signed, of the true distance
  Spread rotation_error_deg;
  Spread reprojection_error_px;
  // Medians over the point's frames with a pose error: what the plots draw,
  // since one wrong pose among a few dozen would drag a mean.
  std::optional<double> median_translation_error_mm;
  std::optional<double> median_distance_error_pct;  // of |error|
  std::optional<double> median_rotation_error_deg;
  std::vector<MeasurementSummary> measurements;
};

// Within this of 0 a point faces the camera (the distance sweep's points).
inline constexpr double kFacingToleranceDeg = 0.5;
[[nodiscard]] inline bool is_facing(const PointSummary& point) {
  return point.angle_deg > -kFacingToleranceDeg && point.angle_deg < kFacingToleranceDeg;
}

struct MaxAngle {
  double distance_m = 0;
  // The largest |angle| on each side of 0 reached by an unbroken run of
  // points (from the one nearest 0 outwards) at or above the threshold;
  // empty when the side was not swept or its first point failed. Both are
  // magnitudes (>= 0). A side holding only the facing point (|angle| < 0.5)
  // was not swept. Points at the same distance and angle (two grids visiting
  // it) count as reached only when each of them is.
  std::optional<double> positive_deg;
  std::optional<double> negative_deg;
};

struct RunSummary {
  std::string run_id;
  std::string plan_name;
  PlanMarker marker;
  std::string status;  // "done", "aborted", "failed", "incomplete" (no stop record)
  double detection_threshold = 0.9;
  std::vector<PointSummary> points;  // in plan order, one per point (repeats merged)
  // The farthest distance reached by an unbroken run of facing points
  // (|angle| < 0.5 deg), from the nearest outwards; empty when none. Facing
  // points at the same distance count as reached only when each of them is.
  std::optional<double> max_distance_m;
  std::vector<MaxAngle> max_angle;  // one per distance swept at more than one angle, ascending
  // Over every frame with a pose error in the run.
  std::optional<double> median_translation_error_mm;
  std::optional<double> median_distance_error_pct;  // of |error|
  std::optional<double> median_rotation_error_deg;
  // The thesis's translation vector spread (6.2.4, "the maximum differences
  // of the translation vector components", about 2 cm): at each facing
  // point, the largest difference of one component between two of its
  // measurements' mean translation vectors; the largest over the points.
  // Empty without a facing point measured twice with a pose.
  std::optional<double> max_tvec_difference_m;
};

[[nodiscard]] RunSummary summarize(const RunRecords& records);

// Several runs of one marker (its distance sweep in one run, its angle
// sweeps in others) as one run of their grids together: the points of all,
// the maxima and medians over all. run_id and plan_name list the runs'.
// std::invalid_argument when the runs measured different markers (family,
// id, size or a stated mounting) or count a point as detected at different
// thresholds: one column of Table 6.1 cannot mix them.
[[nodiscard]] RunSummary summarize_together(const std::vector<const RunRecords*>& runs);

// CSV, one header line then one line per point (summary.csv), and appendix
// C's table, one line per measurement (translation.csv).
[[nodiscard]] std::string points_csv(const RunSummary& summary);
[[nodiscard]] std::string translation_csv(const RunSummary& summary);

// The thesis's Table 6.1 as Markdown: maximum detection distance, maximum
// viewing angle at 50 cm and 95 cm, median pose errors; the thesis's paper
// marker in the first column, each run in one more.
[[nodiscard]] std::string table_6_1(const std::vector<RunSummary>& runs);

// One marker's column of Table 6.1: its runs, together (summarize_together).
struct MarkerColumn {
  Mounting mounting = Mounting::paper;
  RunSummary runs;
};

// The thesis's Table 6.1 as it compares its two markers: for each marker
// (paper, socket), the thesis's column for it and the runs' beside it. Rows:
// the maximum detection distance, the maximum viewing angle at 50, 72 and
// 95 cm and at any other distance a run swept in angle, the translation
// vector spread, the median pose errors. A cell a marker's runs did not
// measure says "not swept"; a number is never carried over from elsewhere.
[[nodiscard]] std::string table_6_1_by_marker(const std::vector<MarkerColumn>& markers);

}  // namespace markerd::sweep
