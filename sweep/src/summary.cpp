#include "markerd/sweep/summary.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <set>
#include <stdexcept>
#include <utility>

#include "markerd/detector/family.hpp"

namespace markerd::sweep {
namespace {

// Planned values closer than these are the same place: two grids that both
// name 0.95 m may still differ in a float's last digits.
constexpr double kSameDistanceM = 0.0005;
constexpr double kSameAngleDeg = 0.05;
// Table 6.1's rows look the angle sweeps up by the thesis's distances; a plan
// that put its sweep at 0.955 m still answers for 95 cm.
constexpr double kTableDistanceToleranceM = 0.01;

Spread spread_of(const std::vector<double>& values) {
  Spread s;
  s.n = values.size();
  if (s.n == 0) return s;
  s.mean = std::accumulate(values.begin(), values.end(), 0.0) / static_cast<double>(s.n);
  if (s.n > 1) {
    double squares = 0;
    for (const double v : values) squares += (v - s.mean) * (v - s.mean);
    s.stddev = std::sqrt(squares / static_cast<double>(s.n - 1));
  }
  return s;
}

std::optional<double> median_of(std::vector<double> values) {
  if (values.empty()) return std::nullopt;
  const std::size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(middle), values.end());
  const double upper = values[middle];
  if (values.size() % 2 == 1) return upper;
  const double lower = *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(middle));
  return (lower + upper) / 2;
}

double norm(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

// The rail's step size, from the start document's copy of the rig: the
// records writer puts the rail axis's settings (as the rig config's [rail]
// table names them) at start.rig["rail"], so its step size is
// start.rig["rail"]["units_per_step"], in the rail's user units (mm) per step.
std::optional<double> rail_units_per_step(const nlohmann::json& rig) {
  if (!rig.is_object()) return std::nullopt;
  const auto rail = rig.find("rail");
  if (rail == rig.end() || !rail->is_object()) return std::nullopt;
  const auto ups = rail->find("units_per_step");
  if (ups == rail->end() || !ups->is_number()) return std::nullopt;
  const double value = ups->get<double>();
  if (!std::isfinite(value) || value <= 0) return std::nullopt;
  return value;
}

std::optional<std::int64_t> steps_of(double rail, std::optional<double> units_per_step) {
  if (!units_per_step) return std::nullopt;
  return static_cast<std::int64_t>(std::llround(rail / *units_per_step));
}

// Consecutive items of a sorted range whose key lies within `tolerance` of
// the first item's key form one group.
template <typename T, typename Key>
std::vector<std::vector<T>> group_sorted(const std::vector<T>& sorted, Key key, double tolerance) {
  std::vector<std::vector<T>> groups;
  for (const T& item : sorted) {
    if (groups.empty() || std::abs(key(item) - key(groups.back().front())) > tolerance) groups.emplace_back();
    groups.back().push_back(item);
  }
  return groups;
}

bool all_reached(const std::vector<const PointSummary*>& points) {
  return std::all_of(points.begin(), points.end(), [](const PointSummary* p) { return p->reached; });
}

std::optional<double> max_distance(const std::vector<PointSummary>& points) {
  std::vector<const PointSummary*> facing;
  for (const auto& p : points) {
    if (is_facing(p)) facing.push_back(&p);
  }
  std::stable_sort(facing.begin(), facing.end(),
                   [](const PointSummary* a, const PointSummary* b) { return a->distance_m < b->distance_m; });
  std::optional<double> farthest;
  for (const auto& same_distance : group_sorted(
           facing, [](const PointSummary* p) { return p->distance_m; }, kSameDistanceM)) {
    if (!all_reached(same_distance)) break;
    farthest = same_distance.front()->distance_m;
  }
  return farthest;
}

// One side of an angle sweep at one distance, its points ordered from the
// one nearest facing outwards.
std::optional<double> max_angle_on_side(std::vector<const PointSummary*> side) {
  const bool swept = std::any_of(side.begin(), side.end(), [](const PointSummary* p) { return !is_facing(*p); });
  if (!swept) return std::nullopt;
  std::stable_sort(side.begin(), side.end(), [](const PointSummary* a, const PointSummary* b) {
    return std::abs(a->angle_deg) < std::abs(b->angle_deg);
  });
  std::optional<double> widest;
  for (const auto& same_angle : group_sorted(
           side, [](const PointSummary* p) { return std::abs(p->angle_deg); }, kSameAngleDeg)) {
    if (!all_reached(same_angle)) break;
    widest = std::abs(same_angle.front()->angle_deg);
  }
  return widest;
}

std::vector<MaxAngle> max_angles(const std::vector<PointSummary>& points) {
  std::vector<const PointSummary*> by_distance;
  for (const auto& p : points) by_distance.push_back(&p);
  std::stable_sort(by_distance.begin(), by_distance.end(),
                   [](const PointSummary* a, const PointSummary* b) { return a->distance_m < b->distance_m; });
  std::vector<MaxAngle> result;
  for (const auto& same_distance : group_sorted(
           by_distance, [](const PointSummary* p) { return p->distance_m; }, kSameDistanceM)) {
    // Facing points are one angle, whatever their fraction of a degree.
    std::vector<double> angles;
    for (const auto* p : same_distance) angles.push_back(is_facing(*p) ? 0.0 : p->angle_deg);
    std::sort(angles.begin(), angles.end());
    if (group_sorted(
            angles, [](double a) { return a; }, kSameAngleDeg)
            .size() < 2)
      continue;
    std::vector<const PointSummary*> positive;
    std::vector<const PointSummary*> negative;
    for (const auto* p : same_distance) {
      // The facing point starts both sides.
      if (p->angle_deg > -kFacingToleranceDeg) positive.push_back(p);
      if (p->angle_deg < kFacingToleranceDeg) negative.push_back(p);
    }
    MaxAngle entry;
    entry.distance_m = same_distance.front()->distance_m;
    entry.positive_deg = max_angle_on_side(std::move(positive));
    entry.negative_deg = max_angle_on_side(std::move(negative));
    result.push_back(entry);
  }
  return result;
}

double true_distance_m(const PointRecord& record) {
  return record.truth_distance_m > 0 ? record.truth_distance_m : norm(record.truth_tvec_m);
}

PointSummary summarize_point(const std::vector<const PointRecord*>& records, const RunStart& start,
                             std::optional<double> units_per_step, std::vector<double>& run_translation_errors,
                             std::vector<double>& run_distance_errors_pct, std::vector<double>& run_rotation_errors) {
  const PointRecord& first = *records.front();
  PointSummary s;
  s.point = first.point;
  s.grid = first.grid;
  if (first.grid < start.plan.grids.size()) s.grid_name = start.plan.grids[first.grid].name;
  s.distance_m = first.distance_m;
  s.angle_deg = first.angle_deg;
  s.rail = first.rail;
  s.turntable = first.turntable;
  s.rail_steps = steps_of(first.rail, units_per_step);
  s.truth_tvec_m = first.truth_tvec_m;

  std::array<std::vector<double>, 3> tvec;
  std::vector<double> distance_estimated;
  std::vector<double> translation_error;
  std::vector<double> distance_error;
  std::vector<double> distance_error_pct;
  std::vector<double> abs_distance_error_pct;
  std::vector<double> rotation_error;
  std::vector<double> reprojection_error;
  for (const PointRecord* record : records) {
    MeasurementSummary m;
    m.repeat = record->repeat;
    m.rail_steps = steps_of(record->rail, units_per_step);
    std::array<double, 3> tvec_sum{};
    int with_pose = 0;
    const double truth_m = true_distance_m(*record);
    for (const FrameSample& f : record->frames) {
      ++m.frames;
      s.other_markers += f.other_markers;
      if (f.detected) ++m.detected;
      if (!f.has_pose) continue;
      ++with_pose;
      for (std::size_t i = 0; i < 3; ++i) {
        tvec_sum[i] += f.tvec_m[i];
        tvec[i].push_back(f.tvec_m[i]);
      }
      distance_estimated.push_back(norm(f.tvec_m));
      reprojection_error.push_back(f.reprojection_error_px);
      if (!f.has_error) continue;
      translation_error.push_back(f.translation_error_mm);
      distance_error.push_back(f.distance_error_mm);
      rotation_error.push_back(f.rotation_error_deg);
      run_translation_errors.push_back(f.translation_error_mm);
      run_rotation_errors.push_back(f.rotation_error_deg);
      if (truth_m > 0) {
        const double pct = 100 * f.distance_error_mm / (1000 * truth_m);
        distance_error_pct.push_back(pct);
        abs_distance_error_pct.push_back(std::abs(pct));
        run_distance_errors_pct.push_back(std::abs(pct));
      }
    }
    if (with_pose > 0) {
      std::array<double, 3> mean{};
      for (std::size_t i = 0; i < 3; ++i) mean[i] = tvec_sum[i] / with_pose;
      m.mean_tvec_m = mean;
    }
    s.frames += m.frames;
    s.detected += m.detected;
    s.frames_corrupt += record->frames_corrupt;
    s.measurements.push_back(m);
  }
  for (std::size_t i = 0; i < 3; ++i) s.tvec_m[i] = spread_of(tvec[i]);
  s.distance_m_estimated = spread_of(distance_estimated);
  s.translation_error_mm = spread_of(translation_error);
  s.distance_error_mm = spread_of(distance_error);
  s.distance_error_pct = spread_of(distance_error_pct);
  s.rotation_error_deg = spread_of(rotation_error);
  s.reprojection_error_px = spread_of(reprojection_error);
  s.median_translation_error_mm = median_of(translation_error);
  s.median_distance_error_pct = median_of(abs_distance_error_pct);
  s.median_rotation_error_deg = median_of(rotation_error);
  s.rate = s.frames > 0 ? static_cast<double>(s.detected) / s.frames : 0.0;
  s.reached = s.frames > 0 && s.rate >= start.plan.detection_threshold;
  return s;
}

// CSV: fields quoted only when they must be (RFC 4180).
std::string csv_field(std::string_view text) {
  if (text.find_first_of(",\"\r\n") == std::string_view::npos) return std::string(text);
  std::string quoted = "\"";
  for (const char c : text) {
    if (c == '"') quoted += '"';
    quoted += c;
  }
  return quoted + '"';
}

std::string csv_number(double value, int decimals) { return fmt::format("{:.{}f}", value, decimals); }
std::string csv_number(const std::optional<double>& value, int decimals) {
  return value ? csv_number(*value, decimals) : std::string();
}
std::string csv_mean(const Spread& s, int decimals) { return s.n > 0 ? csv_number(s.mean, decimals) : std::string(); }
std::string csv_stddev(const Spread& s, int decimals) {
  return s.n > 1 ? csv_number(s.stddev, decimals) : std::string();
}
std::string csv_steps(const std::optional<std::int64_t>& steps) {
  return steps ? fmt::format("{}", *steps) : std::string();
}

// Whole numbers without decimals ("120 cm", "45°"), the rest with one.
std::string one_decimal_or_whole(double value) {
  const double rounded_to_tenth = std::round(value * 10) / 10;
  if (std::abs(rounded_to_tenth - std::round(rounded_to_tenth)) < 1e-9) return fmt::format("{:.0f}", rounded_to_tenth);
  return fmt::format("{:.1f}", rounded_to_tenth);
}

std::string table_cell(std::string_view text) {
  std::string cell;
  for (const char c : text) {
    if (c == '|') cell += '\\';
    cell += c;
  }
  return cell;
}

std::string marker_text(const PlanMarker& marker) {
  return fmt::format("{} #{}, {} mm{}", detector::family_info(marker.family).name, marker.id,
                     one_decimal_or_whole(marker.size_m * 1000),
                     marker.mounting ? fmt::format(", {}", mounting_text(*marker.mounting)) : std::string());
}

constexpr std::string_view kNotSwept = "—";
constexpr std::string_view kNotReached = "not reached";

// "≥" marks a limit the sweep did not find: its last point on that axis was
// still detected, so the marker may well be detected beyond it.
constexpr std::string_view kAtSweepEnd = "≥";

std::string max_distance_cell(const RunSummary& run, std::string_view not_swept) {
  std::optional<double> farthest_facing;
  for (const auto& p : run.points) {
    if (is_facing(p)) farthest_facing = std::max(farthest_facing.value_or(p.distance_m), p.distance_m);
  }
  if (!farthest_facing) return std::string(not_swept);
  if (!run.max_distance_m) return std::string(kNotReached);
  const bool at_end = *run.max_distance_m >= *farthest_facing - kSameDistanceM;
  return fmt::format("{}{} cm", at_end ? kAtSweepEnd : "", one_decimal_or_whole(*run.max_distance_m * 100));
}

// One side's maximum angle; `sign` +1 or -1.
std::string side_text(const RunSummary& run, const MaxAngle& entry, double widest, int sign) {
  double widest_swept = 0;
  for (const auto& p : run.points) {
    if (std::abs(p.distance_m - entry.distance_m) > kSameDistanceM || is_facing(p)) continue;
    if ((p.angle_deg > 0) == (sign > 0)) widest_swept = std::max(widest_swept, std::abs(p.angle_deg));
  }
  const bool at_end = widest >= widest_swept - kSameAngleDeg;
  return fmt::format("{}{}°", at_end ? kAtSweepEnd : "", one_decimal_or_whole(widest));
}

std::string max_angle_cell(const RunSummary& run, double distance_m, std::string_view not_swept) {
  const auto entry = std::find_if(run.max_angle.begin(), run.max_angle.end(), [&](const MaxAngle& a) {
    return std::abs(a.distance_m - distance_m) <= kTableDistanceToleranceM;
  });
  if (entry == run.max_angle.end()) return std::string(not_swept);
  const auto& positive = entry->positive_deg;
  const auto& negative = entry->negative_deg;
  if (positive && negative) {
    return fmt::format("+{} / −{}", side_text(run, *entry, *positive, +1), side_text(run, *entry, *negative, -1));
  }
  if (positive) return side_text(run, *entry, *positive, +1);
  if (negative) return "−" + side_text(run, *entry, *negative, -1);
  return std::string(kNotReached);
}

std::string optional_cell(const std::optional<double>& value, std::string_view unit) {
  if (!value) return std::string(kNotSwept);
  return fmt::format("{:.1f}{}", *value, unit);
}

// In cm as the thesis measures; below a centimetre in mm, where one decimal
// of a centimetre would round a simulated rig's errors to nothing.
std::string translation_error_cell(const std::optional<double>& value_mm) {
  if (!value_mm) return std::string(kNotSwept);
  return *value_mm < 10 ? fmt::format("{:.1f} mm", *value_mm) : fmt::format("{:.1f} cm", *value_mm / 10);
}

// A pose error per distance, not pooled: pooled over a sweep, the near
// points' small errors hide the far ones' (a run's 0.1 % over all can be
// 2 % at its reach). The median of the facing points' medians at each of
// `distances` and at the run's maximum distance, then over all the run's
// frames; the pooled figure alone when no facing point lies at any of them.
std::string error_by_distance_cell(const RunSummary& run, const std::vector<double>& distances,
                                   std::optional<double> PointSummary::*field, const std::optional<double>& pooled,
                                   std::string (*text)(const std::optional<double>&)) {
  std::vector<double> where = distances;
  if (run.max_distance_m) where.push_back(*run.max_distance_m);
  std::sort(where.begin(), where.end());
  std::string cell;
  double last = -1;
  for (const double d : where) {
    if (std::abs(d - last) <= kTableDistanceToleranceM) continue;
    last = d;
    std::vector<double> medians;
    for (const auto& p : run.points) {
      if (is_facing(p) && std::abs(p.distance_m - d) <= kTableDistanceToleranceM && (p.*field)) {
        medians.push_back(*(p.*field));
      }
    }
    if (medians.empty()) continue;
    const bool reach = run.max_distance_m && std::abs(d - *run.max_distance_m) <= kTableDistanceToleranceM;
    cell += fmt::format("{}{} at {} cm{}", cell.empty() ? "" : ", ", text(median_of(medians)),
                        one_decimal_or_whole(d * 100), reach ? " (farthest)" : "");
  }
  if (cell.empty()) return text(pooled);
  return fmt::format("{}; {} over all", cell, text(pooled));
}

std::string distance_error_text(const std::optional<double>& pct) { return optional_cell(pct, " %"); }
std::string rotation_error_text(const std::optional<double>& deg) { return optional_cell(deg, "°"); }

// The three error rows of Table 6.1 for one run.
std::array<std::string, 3> error_cells(const RunSummary& run, const std::vector<double>& distances) {
  return {
      error_by_distance_cell(run, distances, &PointSummary::median_distance_error_pct, run.median_distance_error_pct,
                             distance_error_text),
      error_by_distance_cell(run, distances, &PointSummary::median_translation_error_mm,
                             run.median_translation_error_mm, translation_error_cell),
      error_by_distance_cell(run, distances, &PointSummary::median_rotation_error_deg, run.median_rotation_error_deg,
                             rotation_error_text),
  };
}

// A Markdown table: the header's cells, then the rows'.
std::string markdown_table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::string table = "|";
  std::string rule = "|";
  for (const auto& cell : header) {
    table += cell.empty() ? " |" : " " + cell + " |";
    rule += " --- |";
  }
  table += '\n' + rule + '\n';
  for (const auto& row : rows) {
    table += '|';
    for (const auto& cell : row) table += ' ' + cell + " |";
    table += '\n';
  }
  return table;
}

// What a run's cells mean, under the table.
std::string runs_note(const std::vector<const RunSummary*>& runs, std::string_view not_swept,
                      std::string_view nothing_to_compute) {
  std::set<double> thresholds;
  for (const auto* run : runs) thresholds.insert(run->detection_threshold);
  const std::string threshold = thresholds.size() == 1
                                    ? fmt::format("at least {} %", one_decimal_or_whole(100 * *thresholds.begin()))
                                    : std::string("at least its plan's detection_threshold");
  const std::string missing =
      not_swept == nothing_to_compute
          ? fmt::format("{}: not swept", not_swept)
          : fmt::format(
                "Cells: {}: the runs did not sweep it; {}: no poses to compute it from (the spread needs a "
                "facing point measured twice)",
                not_swept, nothing_to_compute);
  return fmt::format(
      "Runs: a point counts as detected when {} of its frames found the marker. The maximum distance is the "
      "farthest of an unbroken run of such facing points from the nearest outwards; the maximum angle likewise "
      "from facing outwards, per side (+/− turntable direction). Median errors: at each distance named, over "
      "the frames of the facing point there (of several runs' points there, the median of theirs; \"farthest\": "
      "at the maximum distance), then over every frame with a pose in the runs; the distance error as |error| of "
      "the true distance. {}; {}: the first point already failed; {}: the "
      "sweep's last point was still detected, the limit lies beyond it.\n",
      threshold, missing, kNotReached, kAtSweepEnd);
}

// The thesis's numbers for one of its two markers (sections 6.2.2 to 6.2.4,
// appendix C). The distance errors are appendix C's first distance: paper
// |t| 85.8 cm at 95 cm, socket 64.3 cm at 72 cm. The translation vector
// spreads, "about 0.02" in the text, are appendix C's largest: paper z at
// 95 cm (0.8487 to 0.8652), socket z at 78 cm (0.6850 to 0.7036).
struct ThesisColumn {
  std::string_view name;
  std::string_view max_distance;
  std::vector<std::pair<double, std::string_view>> max_angle;  // by distance in m
  std::string_view tvec_difference;
  std::string_view distance_error;
  // Where Table 6.1 quotes the pose errors: the thesis's distance error's
  // distance and its maximum distance (the run's own reach is added).
  std::vector<double> error_distances_m;
};

// The paper marker's, also for a table without a thesis column.
const std::vector<double> kPaperErrorDistancesM = {0.95, 1.20};

const ThesisColumn* thesis_column(Mounting mounting) {
  static const ThesisColumn paper{"paper marker",
                                  "120 cm",
                                  {{0.50, "60°"}, {0.95, "45° (stable to 30°)"}},
                                  "about 2 cm (appendix C: 1.7 cm)",
                                  "9.2 cm at 95 cm (~9.7%)",
                                  kPaperErrorDistancesM};
  static const ThesisColumn socket{"socket marker",
                                   "81 cm",
                                   {{0.50, "45°"}, {0.72, "30°"}, {0.95, "not detected"}},
                                   "about 2 cm (appendix C: 1.9 cm)",
                                   "7.7 cm at 72 cm (~10.7%)",
                                   {0.72, 0.81}};
  switch (mounting) {
    case Mounting::paper: return &paper;
    case Mounting::socket: return &socket;
    case Mounting::light_switch:
    case Mounting::cut_hole: return nullptr;  // the thesis measured neither
  }
  return nullptr;
}

constexpr std::string_view kNotMeasured = "not measured";
constexpr std::string_view kNotSweptWords = "not swept";

std::string_view thesis_angle(const ThesisColumn* thesis, double distance_m) {
  if (thesis == nullptr) return kNotMeasured;
  for (const auto& [at, angle] : thesis->max_angle) {
    if (std::abs(at - distance_m) <= kTableDistanceToleranceM) return angle;
  }
  return kNotMeasured;
}

std::string capitalised(std::string text) {
  if (!text.empty() && text.front() >= 'a' && text.front() <= 'z') text.front() = static_cast<char>(text.front() - 32);
  return text;
}

// The largest difference of one component between two measurements' mean
// translation vectors at one facing point.
std::optional<double> max_tvec_difference(const std::vector<PointSummary>& points) {
  std::optional<double> widest;
  for (const auto& p : points) {
    if (!is_facing(p)) continue;
    for (std::size_t i = 0; i < 3; ++i) {
      std::vector<double> component;
      for (const auto& m : p.measurements) {
        if (m.mean_tvec_m) component.push_back((*m.mean_tvec_m)[i]);
      }
      if (component.size() < 2) continue;
      const auto [low, high] = std::minmax_element(component.begin(), component.end());
      widest = std::max(widest.value_or(0.0), *high - *low);
    }
  }
  return widest;
}

// Every frame's pose errors over a run (or several), for the medians.
struct FrameErrors {
  std::vector<double> translation_mm;
  std::vector<double> distance_pct;  // |error|
  std::vector<double> rotation_deg;
};

// The run's points, one per point (repeats merged), in plan order, appended to `points`.
void add_points(const RunRecords& records, std::vector<PointSummary>& points, FrameErrors& errors) {
  // Repeats are measurements of one point: merged by the point's index,
  // which orders points as the plan lists them.
  std::map<std::size_t, std::vector<const PointRecord*>> by_point;
  for (const auto& record : records.points) by_point[record.point].push_back(&record);

  const auto units_per_step = rail_units_per_step(records.start.rig);
  for (auto& [point, measurements] : by_point) {
    std::stable_sort(measurements.begin(), measurements.end(),
                     [](const PointRecord* a, const PointRecord* b) { return a->repeat < b->repeat; });
    points.push_back(summarize_point(measurements, records.start, units_per_step, errors.translation_mm,
                                     errors.distance_pct, errors.rotation_deg));
  }
}

// The figures over all the points: the maxima, the medians.
void finish(RunSummary& summary, FrameErrors errors) {
  summary.max_distance_m = max_distance(summary.points);
  summary.max_angle = max_angles(summary.points);
  summary.median_translation_error_mm = median_of(std::move(errors.translation_mm));
  summary.median_distance_error_pct = median_of(std::move(errors.distance_pct));
  summary.median_rotation_error_deg = median_of(std::move(errors.rotation_deg));
  summary.max_tvec_difference_m = max_tvec_difference(summary.points);
}

void header_from(RunSummary& summary, const RunRecords& records) {
  const RunStart& start = records.start;
  summary.run_id = start.run_id;
  summary.plan_name = start.plan.name;
  summary.marker = start.plan.marker;
  summary.marker.mounting = start.marker_mounting();
  summary.status = records.stop ? std::string(to_string(records.stop->status)) : std::string("incomplete");
  summary.detection_threshold = start.plan.detection_threshold;
}

}  // namespace

RunSummary summarize(const RunRecords& records) {
  RunSummary summary;
  header_from(summary, records);
  FrameErrors errors;
  add_points(records, summary.points, errors);
  finish(summary, std::move(errors));
  return summary;
}

RunSummary summarize_together(const std::vector<const RunRecords*>& runs) {
  if (runs.empty()) throw std::invalid_argument("summarize_together: no runs");
  const RunRecords& first = *runs.front();
  RunSummary summary;
  header_from(summary, first);
  FrameErrors errors;
  for (const RunRecords* run : runs) {
    PlanMarker marker = run->start.plan.marker;
    marker.mounting = run->start.marker_mounting();
    if (run != runs.front()) {
      PlanMarker expected = first.start.plan.marker;
      expected.mounting = first.start.marker_mounting();
      const bool same_marker = marker.family == expected.family && marker.id == expected.id &&
                               std::abs(marker.size_m - expected.size_m) < 1e-9 &&
                               (!marker.mounting || !expected.mounting || marker.mounting == expected.mounting);
      if (!same_marker) {
        throw std::invalid_argument(fmt::format("runs {} ({}) and {} ({}) measured different markers",
                                                first.start.run_id, marker_text(expected), run->start.run_id,
                                                marker_text(marker)));
      }
      if (run->start.plan.detection_threshold != first.start.plan.detection_threshold) {
        throw std::invalid_argument(
            fmt::format("runs {} (detection_threshold {}) and {} ({}) count a point as detected at different rates",
                        first.start.run_id, first.start.plan.detection_threshold, run->start.run_id,
                        run->start.plan.detection_threshold));
      }
      summary.run_id += ", " + run->start.run_id;
      if (summary.plan_name.find(run->start.plan.name) == std::string::npos) {
        summary.plan_name += ", " + run->start.plan.name;
      }
      const std::string status = run->stop ? std::string(to_string(run->stop->status)) : std::string("incomplete");
      if (status != "done") summary.status = status;  // one unfinished run leaves the column unfinished
    }
    if (!summary.marker.mounting) summary.marker.mounting = marker.mounting;
    add_points(*run, summary.points, errors);
  }
  finish(summary, std::move(errors));
  return summary;
}

// Columns: the point (grid name, index, planned distance and angle, the axes'
// positions), its frames and detection rate, then means (and sample standard
// deviations, "_sd") over the frames with a pose or a pose error, and the
// medians the plots draw. Empty cells: nothing to average (a standard
// deviation needs two values). Translation vectors keep 0.1 mm, as the
// thesis's appendix C does.
std::string points_csv(const RunSummary& summary) {
  std::string csv =
      "grid,point,distance_m,angle_deg,rail,rail_steps,turntable,measurements,frames,detected,rate,reached,"
      "frames_corrupt,other_markers,tx_m,ty_m,tz_m,tx_sd_m,ty_sd_m,tz_sd_m,distance_estimated_m,"
      "distance_error_mm,distance_error_sd_mm,distance_error_pct,translation_error_mm,translation_error_sd_mm,"
      "rotation_error_deg,rotation_error_sd_deg,reprojection_error_px,median_translation_error_mm,"
      "median_abs_distance_error_pct\n";
  for (const auto& p : summary.points) {
    csv += fmt::format(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
        csv_field(p.grid_name), p.point, csv_number(p.distance_m, 3), csv_number(p.angle_deg, 2), csv_number(p.rail, 3),
        csv_steps(p.rail_steps), csv_number(p.turntable, 3), p.measurements.size(), p.frames, p.detected,
        csv_number(p.rate, 4), p.reached ? "true" : "false", p.frames_corrupt, p.other_markers,
        csv_mean(p.tvec_m[0], 4), csv_mean(p.tvec_m[1], 4), csv_mean(p.tvec_m[2], 4), csv_stddev(p.tvec_m[0], 4),
        csv_stddev(p.tvec_m[1], 4), csv_stddev(p.tvec_m[2], 4), csv_mean(p.distance_m_estimated, 4),
        csv_mean(p.distance_error_mm, 2), csv_stddev(p.distance_error_mm, 2), csv_mean(p.distance_error_pct, 2),
        csv_mean(p.translation_error_mm, 2), csv_stddev(p.translation_error_mm, 2), csv_mean(p.rotation_error_deg, 3),
        csv_stddev(p.rotation_error_deg, 3), csv_mean(p.reprojection_error_px, 3),
        csv_number(p.median_translation_error_mm, 2), csv_number(p.median_distance_error_pct, 2));
  }
  return csv;
}

// One line per measurement as appendix C lists them (measurements numbered
// from 1 at each point), the mean translation vector over its frames with a
// pose and that vector's norm.
std::string translation_csv(const RunSummary& summary) {
  std::string csv = "grid,point,distance_m,angle_deg,measurement,rail_steps,frames,detected,tx_m,ty_m,tz_m,norm_m\n";
  for (const auto& p : summary.points) {
    for (const auto& m : p.measurements) {
      std::string vector = ",,,";
      if (m.mean_tvec_m) {
        const auto& t = *m.mean_tvec_m;
        vector = fmt::format("{:.4f},{:.4f},{:.4f},{:.4f}", t[0], t[1], t[2], norm(t));
      }
      csv +=
          fmt::format("{},{},{},{},{},{},{},{},{}\n", csv_field(p.grid_name), p.point, csv_number(p.distance_m, 3),
                      csv_number(p.angle_deg, 2), m.repeat + 1, csv_steps(m.rail_steps), m.frames, m.detected, vector);
    }
  }
  return csv;
}

std::string table_6_1(const std::vector<RunSummary>& runs) {
  std::vector<std::vector<std::string>> rows = {
      {"Maximum detection distance", "120 cm"},     {"Maximum viewing angle at 50 cm", "60°"},
      {"Maximum viewing angle at 95 cm", "45°"},    {"Median distance error", "9.2 cm at 95 cm (~9.7%)"},
      {"Median translation error", "not measured"}, {"Median rotation error", "not measured"},
  };
  std::vector<std::string> header = {"", "Thesis: paper marker"};
  for (const auto& run : runs) {
    header.push_back(fmt::format("{} ({})", table_cell(run.run_id), table_cell(marker_text(run.marker))));
    rows[0].push_back(max_distance_cell(run, kNotSwept));
    rows[1].push_back(max_angle_cell(run, 0.50, kNotSwept));
    rows[2].push_back(max_angle_cell(run, 0.95, kNotSwept));
    auto errors = error_cells(run, kPaperErrorDistancesM);
    for (std::size_t i = 0; i < errors.size(); ++i) rows[3 + i].push_back(std::move(errors[i]));
  }
  std::string table = markdown_table(header, rows);
  table +=
      "\nThesis: sections 6.2.2 to 6.2.4, measured by hand. Its Table 6.1 gives 45° as the viewing angle at 50 cm, "
      "but its text (6.2.3) has 60° at 50 cm and 45° at 95 cm; this table follows the text.\n\n";
  if (!runs.empty()) {
    std::vector<const RunSummary*> all;
    for (const auto& run : runs) all.push_back(&run);
    table += runs_note(all, kNotSwept, kNotSwept);
  }
  return table;
}

std::string table_6_1_by_marker(const std::vector<MarkerColumn>& markers) {
  // The thesis's distances, then any other a run swept in angle: each its own row.
  std::vector<double> angle_distances = {0.50, 0.72, 0.95};
  for (const auto& marker : markers) {
    for (const auto& entry : marker.runs.max_angle) {
      const bool listed = std::any_of(angle_distances.begin(), angle_distances.end(), [&](double d) {
        return std::abs(d - entry.distance_m) <= kTableDistanceToleranceM;
      });
      if (!listed) angle_distances.push_back(entry.distance_m);
    }
  }
  std::sort(angle_distances.begin(), angle_distances.end());

  std::vector<std::vector<std::string>> rows;
  rows.push_back({"Maximum detection distance"});
  for (const double d : angle_distances) {
    rows.push_back({fmt::format("Maximum viewing angle at {} cm", one_decimal_or_whole(d * 100))});
  }
  rows.push_back({"Translation vector spread"});
  rows.push_back({"Median distance error"});
  rows.push_back({"Median translation error"});
  rows.push_back({"Median rotation error"});

  std::vector<std::string> header = {""};
  for (const auto& marker : markers) {
    const ThesisColumn* thesis = thesis_column(marker.mounting);
    const std::string name =
        thesis != nullptr ? std::string(thesis->name) : fmt::format("marker {}", mounting_text(marker.mounting));
    const RunSummary& run = marker.runs;
    header.push_back(fmt::format("Thesis: {}", name));
    header.push_back(
        fmt::format("{}: {} ({})", capitalised(name), table_cell(run.run_id), table_cell(marker_text(run.marker))));
    std::size_t row = 0;
    const auto add = [&](std::string_view from_thesis, std::string measured) {
      rows[row].emplace_back(from_thesis);
      rows[row].push_back(std::move(measured));
      ++row;
    };
    add(thesis != nullptr ? thesis->max_distance : kNotMeasured, max_distance_cell(run, kNotSweptWords));
    for (const double d : angle_distances) add(thesis_angle(thesis, d), max_angle_cell(run, d, kNotSweptWords));
    add(thesis != nullptr ? thesis->tvec_difference : kNotMeasured,
        translation_error_cell(run.max_tvec_difference_m ? std::optional(*run.max_tvec_difference_m * 1000)
                                                         : std::nullopt));
    auto errors = error_cells(run, thesis != nullptr ? thesis->error_distances_m : kPaperErrorDistancesM);
    add(thesis != nullptr ? thesis->distance_error : kNotMeasured, std::move(errors[0]));
    add(kNotMeasured, std::move(errors[1]));
    add(kNotMeasured, std::move(errors[2]));
  }
  std::string table = markdown_table(header, rows);
  table +=
      "\nThesis: sections 6.2.2 to 6.2.4 and appendix C, measured by hand. Its Table 6.1 swaps the two markers' "
      "angles at 50 cm; its text (6.2.3) has 60° on paper and 45° on the socket, and this table follows the text. "
      "It measured the paper marker's angles at 50 and 95 cm, the socket marker's at 50 and 72 cm (at 95 cm the "
      "socket marker was not found facing). Its distance errors are appendix C's at the nearest distance measured. "
      "Translation vector spread: the largest difference of one component of the mean translation vector between "
      "two measurements at one facing point (the thesis's \"maximum differences of the translation vector "
      "components\", about 0.02 m for both markers).\n\n";
  if (!markers.empty()) {
    std::vector<const RunSummary*> all;
    for (const auto& marker : markers) all.push_back(&marker.runs);
    table += runs_note(all, kNotSweptWords, kNotSwept);
  }
  return table;
}

}  // namespace markerd::sweep
