#pragma once
// A run's results, computed from its records alone (records.hpp): per point
// the detection rate with its 95% interval, and the median pose error
// against the ground truth with its 95% interval and the spread of the pose
// over the frames; the maximum detection distance and the maximum viewing
// angle at each distance, and whether the rates' intervals decide them; the
// thesis's Table 6.1 and its appendix C table. Only the records go in, so
// `markerctl report` can summarise a run at any time after (or during) it,
// on any machine.
//
// The frames at a point are of one scene that does not move: their spread
// (Spread::stddev) is the jitter of the measurement, how well it repeats,
// not how far it is from the truth. The median error is the accuracy at the
// point, and its interval says how well the frames pin that median down.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "markerd/base/proportion.hpp"
#include "markerd/sweep/records.hpp"

namespace markerd::sweep {

// Mean and sample standard deviation of the values seen (n = 0: both 0).
// Over a point's frames the standard deviation is the jitter.
struct Spread {
  std::size_t n = 0;
  double mean = 0;
  double stddev = 0;
};

// The median of some values with its 95% interval from their order
// statistics (distribution-free: the ranks k and n + 1 - k between which the
// median lies with at least 95% confidence, by the binomial distribution of
// how many values fall below it). Below 6 values no two ranks give 95%: no
// interval. Over a point's frames the values are not independent draws of
// the rig's error (the scene does not move), so the interval covers the
// frames' jitter only, not a bias every frame shares.
struct MedianEstimate {
  std::size_t n = 0;
  double median = 0;
  std::optional<double> low;
  std::optional<double> high;
};

// Empty without values.
[[nodiscard]] std::optional<MedianEstimate> median_estimate(std::vector<double> values);

// A rate's call against the threshold, by its 95% interval: above when the
// whole interval is at or above it, below when the whole interval is below,
// uncertain when it holds the threshold (more frames would tell).
enum class RateCall : std::uint8_t { above, below, uncertain };
[[nodiscard]] std::string_view to_string(RateCall call);

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
  double rate = 0;                         // detected / frames (0 without frames)
  bool reached = false;                    // rate >= the plan's detection_threshold
  base::ProportionInterval rate_interval;  // 95%, Wilson ([0, 1] without frames)
  RateCall call = RateCall::uncertain;
  // The frames a point at this rate would need for its interval to leave the
  // threshold out (base::wilson_trials_to_exclude); empty when the rate is
  // the threshold.
  std::optional<std::int64_t> frames_to_decide;
  std::array<Spread, 3> tvec_m{};  // x, y, z
  Spread distance_m_estimated;     // |t|
  Spread translation_error_mm;
  Spread distance_error_mm;   // signed
  Spread distance_error_pct;  // signed, of the true distance
  Spread rotation_error_deg;
  Spread reprojection_error_px;
  // Medians over the point's frames with a pose error: what the tables and
  // plots give, since one wrong pose among a few dozen would drag a mean.
  std::optional<MedianEstimate> median_translation_error_mm;
  std::optional<MedianEstimate> median_distance_error_pct;  // of |error|
  std::optional<MedianEstimate> median_rotation_error_deg;
  // Every frame's errors, ascending: what the medians of several points
  // together are taken over.
  std::vector<double> translation_errors_mm;
  std::vector<double> abs_distance_errors_pct;
  std::vector<double> rotation_errors_deg;
  std::vector<MeasurementSummary> measurements;
};

// Within this of 0 a point faces the camera (the distance sweep's points).
inline constexpr double kFacingToleranceDeg = 0.5;
[[nodiscard]] inline bool is_facing(const PointSummary& point) {
  return point.angle_deg > -kFacingToleranceDeg && point.angle_deg < kFacingToleranceDeg;
}

// How sure a limit found by walking points outwards (the maximum distance,
// a maximum angle) is, by the points' rate intervals: walked again counting
// only the points surely above the threshold, then every point that may be.
// Where the two walks end differently the limit is uncertain: some point on
// the way holds the threshold in its interval.
struct LimitCall {
  std::optional<double> surely;    // empty: not even the first point is surely reached
  std::optional<double> possibly;  // empty: the first point is surely below
  [[nodiscard]] bool uncertain() const { return surely != possibly; }
  // Uncertain: the points walked to find the limit (to the first that
  // failed) whose intervals hold the threshold, as indices into
  // RunSummary::points; and the most frames one of them needs
  // (PointSummary::frames_to_decide), empty when one's rate is the threshold.
  std::vector<std::size_t> deciding;
  std::optional<std::int64_t> frames_to_decide;
};

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
  LimitCall positive_call;  // of magnitudes, as the limits
  LimitCall negative_call;
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
  LimitCall max_distance_call;
  std::vector<MaxAngle> max_angle;  // one per distance swept at more than one angle, ascending
  // Over every frame with a pose error in the run: pooled over near and
  // far points, so Table 6.1 gives them only for a run without a facing
  // point to quote by distance.
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

// The run's points facing the camera (is_facing), nearest first.
[[nodiscard]] std::vector<const PointSummary*> facing_by_distance(const RunSummary& run);

// Several runs of one marker (its distance sweep in one run, its angle
// sweeps in others) as one run of their grids together: the points of all,
// the maxima and medians over all. run_id and plan_name list the runs'.
// std::invalid_argument when the runs measured different markers (family,
// id, size or a stated mounting) or count a point as detected at different
// thresholds: one column of Table 6.1 cannot mix them.
[[nodiscard]] RunSummary summarize_together(const std::vector<const RunRecords*>& runs);

// CSV, one header line then one line per point (summary.csv), and appendix
// C's table, one line per measurement (translation.csv). Numbers in full
// (the shortest text that reads back as the same double).
[[nodiscard]] std::string points_csv(const RunSummary& summary);
[[nodiscard]] std::string translation_csv(const RunSummary& summary);

// The thesis's Table 6.1 as Markdown: maximum detection distance, maximum
// viewing angle at 50 cm and 95 cm (each "(uncertain)" when the rates'
// intervals do not decide it), the median pose errors with their 95%
// intervals and the distance's jitter at the thesis's 95 and 120 cm and at
// the run's reach (interpolated, or the nearest, where no facing point was
// measured, and saying so); the thesis's paper marker in the first column,
// each run in one more.
[[nodiscard]] std::string table_6_1(const std::vector<RunSummary>& runs);

// The thesis's own limits for one of its markers (sections 6.2.2 and
// 6.2.3), for the reports' reference lines; nullptr for a mounting the
// thesis did not measure.
struct ThesisLimits {
  std::string_view marker;  // "paper marker"
  double max_distance_m = 0;
  std::vector<std::pair<double, double>> max_angle_deg;  // distance (m), angle (deg)
};
[[nodiscard]] const ThesisLimits* thesis_limits(Mounting mounting);

// The threshold calls behind Table 6.1's limits, as Markdown: per run (or
// column), the maximum distance and each maximum angle, whether the rates'
// 95% intervals decide them, the points that do not and the frames a point
// would need.
[[nodiscard]] std::string threshold_calls(const std::vector<const RunSummary*>& runs);

// One marker's column of Table 6.1: its runs, together (summarize_together).
struct MarkerColumn {
  Mounting mounting = Mounting::paper;
  RunSummary runs;
};

// The thesis's Table 6.1 as it compares its two markers: for each marker
// (paper, socket), the thesis's column for it and the runs' beside it. Rows:
// the maximum detection distance, the maximum viewing angle at 50, 72 and
// 95 cm and at any other distance a run swept in angle, the translation
// vector spread, the median pose errors and the jitter at the thesis's
// distances for that marker (95 and 120 cm on paper, 72 and 81 cm on the
// socket) and at the runs' reach, as table_6_1 gives them. A cell a marker's
// runs did not measure says "not swept"; a number is never carried over from
// another distance farther than interpolation between two measured ones.
[[nodiscard]] std::string table_6_1_by_marker(const std::vector<MarkerColumn>& markers);

}  // namespace markerd::sweep
