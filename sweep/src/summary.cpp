#include "markerd/sweep/summary.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <stdexcept>
#include <tuple>
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

// The largest rank k (from 1) with P(B < k) <= 2.5% for B ~ Bin(n, 1/2):
// the values of ranks k and n + 1 - k hold the median with at least 95%.
// 0 when even the extremes do not (n < 6).
std::size_t median_interval_rank(std::size_t n) {
  const auto count = static_cast<double>(n);
  const double log_half_n = count * std::log(0.5);
  double below = 0;  // P(B <= i - 1)
  std::size_t i = 0;
  for (; i < n; ++i) {
    const auto k = static_cast<double>(i);
    const double pmf = std::exp(std::lgamma(count + 1) - std::lgamma(k + 1) - std::lgamma(count - k + 1) + log_half_n);
    if (below + pmf > 0.025) break;
    below += pmf;
  }
  return i;
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

using Group = std::vector<const PointSummary*>;

// The groups of points met walking outwards, a group a place (points at the
// same place count as reached only when each of them is).
struct Walk {
  std::optional<double> limit;    // the last group reached's key
  std::size_t groups_walked = 0;  // up to and with the first group that failed
};

template <typename Passes, typename Key>
Walk walk_outwards(const std::vector<Group>& groups, Passes passes, Key key) {
  Walk walk;
  for (const auto& group : groups) {
    ++walk.groups_walked;
    if (!std::all_of(group.begin(), group.end(), [&](const PointSummary* p) { return passes(*p); })) break;
    walk.limit = key(group.front());
  }
  return walk;
}

// The walk as the threshold decides it, and its call by the rates' intervals.
template <typename Key>
std::pair<std::optional<double>, LimitCall> limit_of(const std::vector<Group>& groups, Key key,
                                                     const std::vector<PointSummary>& points) {
  const Walk estimate = walk_outwards(
      groups, [](const PointSummary& p) { return p.reached; }, key);
  LimitCall call;
  call.surely = walk_outwards(
                    groups, [](const PointSummary& p) { return p.call == RateCall::above; }, key)
                    .limit;
  call.possibly = walk_outwards(
                      groups, [](const PointSummary& p) { return p.call != RateCall::below; }, key)
                      .limit;
  if (call.uncertain()) {
    bool decidable = true;
    std::int64_t most = 0;
    for (std::size_t g = 0; g < estimate.groups_walked; ++g) {
      for (const PointSummary* p : groups[g]) {
        if (p->call != RateCall::uncertain) continue;
        call.deciding.push_back(static_cast<std::size_t>(p - points.data()));
        if (p->frames_to_decide) {
          most = std::max(most, *p->frames_to_decide);
        } else {
          decidable = false;
        }
      }
    }
    if (decidable && !call.deciding.empty()) call.frames_to_decide = most;
  }
  return {estimate.limit, std::move(call)};
}

std::vector<const PointSummary*> facing_nearest_first(const std::vector<PointSummary>& points) {
  std::vector<const PointSummary*> facing;
  for (const auto& p : points) {
    if (is_facing(p)) facing.push_back(&p);
  }
  std::stable_sort(facing.begin(), facing.end(),
                   [](const PointSummary* a, const PointSummary* b) { return a->distance_m < b->distance_m; });
  return facing;
}

std::pair<std::optional<double>, LimitCall> max_distance(const std::vector<PointSummary>& points) {
  const auto facing = facing_nearest_first(points);
  const auto distance = [](const PointSummary* p) { return p->distance_m; };
  return limit_of(group_sorted(facing, distance, kSameDistanceM), distance, points);
}

// One side of an angle sweep at one distance, its points ordered from the
// one nearest facing outwards.
std::pair<std::optional<double>, LimitCall> max_angle_on_side(std::vector<const PointSummary*> side,
                                                              const std::vector<PointSummary>& points) {
  const bool swept = std::any_of(side.begin(), side.end(), [](const PointSummary* p) { return !is_facing(*p); });
  if (!swept) return {};
  std::stable_sort(side.begin(), side.end(), [](const PointSummary* a, const PointSummary* b) {
    return std::abs(a->angle_deg) < std::abs(b->angle_deg);
  });
  const auto magnitude = [](const PointSummary* p) { return std::abs(p->angle_deg); };
  return limit_of(group_sorted(side, magnitude, kSameAngleDeg), magnitude, points);
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
    std::tie(entry.positive_deg, entry.positive_call) = max_angle_on_side(std::move(positive), points);
    std::tie(entry.negative_deg, entry.negative_call) = max_angle_on_side(std::move(negative), points);
    result.push_back(std::move(entry));
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
  std::sort(translation_error.begin(), translation_error.end());
  std::sort(abs_distance_error_pct.begin(), abs_distance_error_pct.end());
  std::sort(rotation_error.begin(), rotation_error.end());
  s.median_translation_error_mm = median_estimate(translation_error);
  s.median_distance_error_pct = median_estimate(abs_distance_error_pct);
  s.median_rotation_error_deg = median_estimate(rotation_error);
  s.translation_errors_mm = std::move(translation_error);
  s.abs_distance_errors_pct = std::move(abs_distance_error_pct);
  s.rotation_errors_deg = std::move(rotation_error);

  const double threshold = start.plan.detection_threshold;
  s.rate = s.frames > 0 ? static_cast<double>(s.detected) / s.frames : 0.0;
  s.reached = s.frames > 0 && s.rate >= threshold;
  s.rate_interval = base::wilson_interval(s.detected, s.frames);
  if (s.frames > 0 && s.rate_interval.low >= threshold) {
    s.call = RateCall::above;
  } else if (s.frames > 0 && s.rate_interval.high < threshold) {
    s.call = RateCall::below;
  }
  s.frames_to_decide = base::wilson_trials_to_exclude(s.rate, threshold);
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

// Numbers in full: the shortest text that reads back as the same double,
// so a CSV loses nothing of what was measured (a spread of 3e-05 m is not
// "0.0000").
std::string csv_number(double value) { return fmt::format("{}", value); }
std::string csv_number(const std::optional<double>& value) { return value ? csv_number(*value) : std::string(); }
std::string csv_mean(const Spread& s) { return s.n > 0 ? csv_number(s.mean) : std::string(); }
std::string csv_stddev(const Spread& s) { return s.n > 1 ? csv_number(s.stddev) : std::string(); }
std::string csv_stddev(const Spread& s, double scale) { return s.n > 1 ? csv_number(s.stddev * scale) : std::string(); }
// The median and its interval's ends, three fields.
std::string csv_median(const std::optional<MedianEstimate>& m) {
  if (!m) return ",,";
  return fmt::format("{},{},{}", csv_number(m->median), csv_number(m->low), csv_number(m->high));
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

constexpr std::string_view kUncertain = " (uncertain)";

std::string_view uncertain_mark(const LimitCall& call) { return call.uncertain() ? kUncertain : ""; }

std::string max_distance_cell(const RunSummary& run, std::string_view not_swept) {
  std::optional<double> farthest_facing;
  for (const auto& p : run.points) {
    if (is_facing(p)) farthest_facing = std::max(farthest_facing.value_or(p.distance_m), p.distance_m);
  }
  if (!farthest_facing) return std::string(not_swept);
  if (!run.max_distance_m) return fmt::format("{}{}", kNotReached, uncertain_mark(run.max_distance_call));
  const bool at_end = *run.max_distance_m >= *farthest_facing - kSameDistanceM;
  return fmt::format("{}{} cm{}", at_end ? kAtSweepEnd : "", one_decimal_or_whole(*run.max_distance_m * 100),
                     uncertain_mark(run.max_distance_call));
}

// One side's maximum angle; `sign` +1 or -1.
std::string side_text(const RunSummary& run, const MaxAngle& entry, double widest, int sign) {
  double widest_swept = 0;
  for (const auto& p : run.points) {
    if (std::abs(p.distance_m - entry.distance_m) > kSameDistanceM || is_facing(p)) continue;
    if ((p.angle_deg > 0) == (sign > 0)) widest_swept = std::max(widest_swept, std::abs(p.angle_deg));
  }
  const bool at_end = widest >= widest_swept - kSameAngleDeg;
  return fmt::format("{}{}°{}", at_end ? kAtSweepEnd : "", one_decimal_or_whole(widest),
                     uncertain_mark(sign > 0 ? entry.positive_call : entry.negative_call));
}

const MaxAngle* max_angle_at(const RunSummary& run, double distance_m) {
  const auto entry = std::find_if(run.max_angle.begin(), run.max_angle.end(), [&](const MaxAngle& a) {
    return std::abs(a.distance_m - distance_m) <= kTableDistanceToleranceM;
  });
  return entry == run.max_angle.end() ? nullptr : &*entry;
}

std::string max_angle_cell(const RunSummary& run, double distance_m, std::string_view not_swept) {
  const MaxAngle* entry = max_angle_at(run, distance_m);
  if (entry == nullptr) return std::string(not_swept);
  const auto& positive = entry->positive_deg;
  const auto& negative = entry->negative_deg;
  if (positive && negative) {
    return fmt::format("+{} / −{}", side_text(run, *entry, *positive, +1), side_text(run, *entry, *negative, -1));
  }
  if (positive) return side_text(run, *entry, *positive, +1);
  if (negative) return "−" + side_text(run, *entry, *negative, -1);
  const bool uncertain = entry->positive_call.uncertain() || entry->negative_call.uncertain();
  return fmt::format("{}{}", kNotReached, uncertain ? kUncertain : "");
}

// A figure Table 6.1 quotes: a median with its 95% interval when it has one
// (or a value without, the jitter).
struct Figure {
  double value = 0;
  std::optional<double> low;
  std::optional<double> high;
};

std::optional<Figure> figure_of(const std::optional<MedianEstimate>& m) {
  if (!m) return std::nullopt;
  return Figure{m->median, m->low, m->high};
}

// Decimals enough for two significant digits of small errors, one decimal
// from 1 up: a simulated rig's 0.04 % does not round to 0.0.
int decimals_for(double value) {
  const double magnitude = std::abs(value);
  return magnitude >= 1 ? 1 : magnitude >= 0.1 ? 2 : 3;
}

std::string figure_text(const Figure& f, double scale, std::string_view unit) {
  const int decimals = decimals_for(f.value * scale);
  std::string text = fmt::format("{:.{}f}{}", f.value * scale, decimals, unit);
  if (f.low && f.high) text += fmt::format(" [{:.{}f}, {:.{}f}]", *f.low * scale, decimals, *f.high * scale, decimals);
  return text;
}

std::string percent_text(const Figure& f) { return figure_text(f, 1, " %"); }
std::string degrees_text(const Figure& f) { return figure_text(f, 1, "°"); }
// In cm as the thesis measures; below a centimetre in mm, where one decimal
// of a centimetre would round a simulated rig's errors to nothing.
std::string millimetres_text(const Figure& f) {
  return f.value < 10 ? figure_text(f, 1, " mm") : figure_text(f, 0.1, " cm");
}

// How one row of Table 6.1 takes its figure from the facing points at one
// distance (several when runs or grids share it).
using FigureOf = std::optional<Figure> (*)(const std::vector<const PointSummary*>&);

std::vector<double> pooled(const std::vector<const PointSummary*>& points, std::vector<double> PointSummary::*values) {
  std::vector<double> all;
  for (const auto* p : points) all.insert(all.end(), (p->*values).begin(), (p->*values).end());
  return all;
}

std::optional<Figure> distance_error_of(const std::vector<const PointSummary*>& points) {
  return figure_of(median_estimate(pooled(points, &PointSummary::abs_distance_errors_pct)));
}
std::optional<Figure> translation_error_of(const std::vector<const PointSummary*>& points) {
  return figure_of(median_estimate(pooled(points, &PointSummary::translation_errors_mm)));
}
std::optional<Figure> rotation_error_of(const std::vector<const PointSummary*>& points) {
  return figure_of(median_estimate(pooled(points, &PointSummary::rotation_errors_deg)));
}
// The standard deviation of the estimated distance over a point's frames,
// in mm; of several points, pooled (the root of their mean variance,
// weighted by their degrees of freedom).
std::optional<Figure> distance_jitter_of(const std::vector<const PointSummary*>& points) {
  double squares = 0;
  double freedom = 0;
  for (const auto* p : points) {
    const Spread& s = p->distance_m_estimated;
    if (s.n < 2) continue;
    squares += s.stddev * s.stddev * static_cast<double>(s.n - 1);
    freedom += static_cast<double>(s.n - 1);
  }
  if (freedom == 0) return std::nullopt;
  return Figure{1000 * std::sqrt(squares / freedom), std::nullopt, std::nullopt};
}

// The facing points grouped by distance, nearest first.
std::vector<Group> facing_groups(const RunSummary& run) {
  return group_sorted(
      facing_by_distance(run), [](const PointSummary* p) { return p->distance_m; }, kSameDistanceM);
}

// One figure at distance `d`: from the facing points there (within 1 cm);
// else interpolated linearly between the nearest measured below and above
// (the interval's ends too, when both have one); else from the nearest
// within 5 cm. Said which in `how`.
std::optional<std::pair<Figure, std::string>> figure_at(const std::vector<Group>& groups, double d,
                                                        FigureOf figure_of_points) {
  constexpr double kNearestWithinM = 0.05;
  Group at_d;
  for (const auto& group : groups) {
    if (std::abs(group.front()->distance_m - d) <= kTableDistanceToleranceM) {
      at_d.insert(at_d.end(), group.begin(), group.end());
    }
  }
  if (const auto figure = figure_of_points(at_d)) return std::pair{*figure, std::string()};
  std::optional<std::pair<double, Figure>> below;
  std::optional<std::pair<double, Figure>> above;
  for (const auto& group : groups) {
    const double at = group.front()->distance_m;
    const auto figure = figure_of_points(group);
    if (!figure || std::abs(at - d) <= kTableDistanceToleranceM) continue;
    if (at < d) below = std::pair{at, *figure};
    if (at > d && !above) above = std::pair{at, *figure};
  }
  const auto cm = [](double m) { return one_decimal_or_whole(m * 100); };
  if (below && above) {
    const double t = (d - below->first) / (above->first - below->first);
    const auto lerp = [t](double a, double b) { return a + t * (b - a); };
    const Figure& a = below->second;
    const Figure& b = above->second;
    Figure f{lerp(a.value, b.value), std::nullopt, std::nullopt};
    if (a.low && b.low && a.high && b.high) {
      f.low = lerp(*a.low, *b.low);
      f.high = lerp(*a.high, *b.high);
    }
    return std::pair{f, fmt::format("interpolated from {} and {} cm", cm(below->first), cm(above->first))};
  }
  for (const auto& side : {below, above}) {
    if (side && std::abs(side->first - d) <= kNearestWithinM + 1e-9) {
      return std::pair{side->second, fmt::format("measured at {} cm, the nearest", cm(side->first))};
    }
  }
  return std::nullopt;
}

// A pose error per distance, not pooled: pooled over a sweep, the near
// points' small errors hide the far ones' (a run's 0.1 % over all can be
// 4 % at its reach). The median over the frames of the facing points at
// each of `distances` and at the run's maximum distance, with its 95%
// interval; the pooled median over every frame only when no facing point
// has one near any of them.
std::string error_by_distance_cell(const RunSummary& run, const std::vector<double>& distances,
                                   FigureOf figure_of_points, const std::optional<double>& pooled_median,
                                   std::string (*text)(const Figure&)) {
  std::vector<double> where = distances;
  if (run.max_distance_m) where.push_back(*run.max_distance_m);
  std::sort(where.begin(), where.end());
  const auto groups = facing_groups(run);
  std::string cell;
  double last = -1;
  for (const double d : where) {
    if (std::abs(d - last) <= kTableDistanceToleranceM) continue;
    last = d;
    const auto figure = figure_at(groups, d, figure_of_points);
    if (!figure) continue;
    const bool reach = run.max_distance_m && std::abs(d - *run.max_distance_m) <= kTableDistanceToleranceM;
    std::string notes = figure->second;
    if (reach) notes = notes.empty() ? "farthest" : "farthest, " + notes;
    cell += fmt::format("{}{} at {} cm{}", cell.empty() ? "" : "; ", text(figure->first), one_decimal_or_whole(d * 100),
                        notes.empty() ? "" : " (" + notes + ")");
  }
  if (!cell.empty()) return cell;
  if (!pooled_median) return std::string(kNotSwept);
  return fmt::format("{} over all frames", text(Figure{*pooled_median, std::nullopt, std::nullopt}));
}

// The four error rows of Table 6.1 for one run.
std::array<std::string, 4> error_cells(const RunSummary& run, const std::vector<double>& distances) {
  return {
      error_by_distance_cell(run, distances, distance_error_of, run.median_distance_error_pct, percent_text),
      error_by_distance_cell(run, distances, translation_error_of, run.median_translation_error_mm, millimetres_text),
      error_by_distance_cell(run, distances, rotation_error_of, run.median_rotation_error_deg, degrees_text),
      error_by_distance_cell(run, distances, distance_jitter_of, std::nullopt, millimetres_text),
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
      "from facing outwards, per side (+/− turntable direction); \"(uncertain)\": the 95% interval of a rate on "
      "the way holds the threshold, and more frames would tell (the threshold calls below). Median errors, not "
      "pooled over the sweep: at each distance named (\"farthest\": the maximum distance), the median over the "
      "frames of the facing points there, with its 95% interval in brackets; where no facing point was measured, "
      "interpolated between the nearest below and above, or the nearest within 5 cm, as said; over every frame "
      "of the runs only when no facing point has a pose near any of them. The distance error is |error| of the "
      "true distance. The frames at a point are of one scene that does not move: the interval says how well "
      "they pin down that point's median, not a bias they all share. The jitter, the standard deviation of the "
      "estimated distance over a point's frames, is how well a measurement repeats, not how accurate it is. "
      "{}; {}: the first point already failed; {}: the sweep's last point was still detected, the limit lies "
      "beyond it.\n",
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
  std::tie(summary.max_distance_m, summary.max_distance_call) = max_distance(summary.points);
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

std::optional<MedianEstimate> median_estimate(std::vector<double> values) {
  if (values.empty()) return std::nullopt;
  std::sort(values.begin(), values.end());
  MedianEstimate estimate;
  estimate.n = values.size();
  const std::size_t middle = values.size() / 2;
  estimate.median = values.size() % 2 == 1 ? values[middle] : (values[middle - 1] + values[middle]) / 2;
  const std::size_t rank = median_interval_rank(values.size());
  if (rank > 0) {
    estimate.low = values[rank - 1];
    estimate.high = values[values.size() - rank];
  }
  return estimate;
}

const ThesisLimits* thesis_limits(Mounting mounting) {
  // As thesis_column's words: 6.2.2's distances, 6.2.3's angles.
  static const ThesisLimits paper{"paper marker", 1.20, {{0.50, 60}, {0.95, 45}}};
  static const ThesisLimits socket{"socket marker", 0.81, {{0.50, 45}, {0.72, 30}}};
  switch (mounting) {
    case Mounting::paper: return &paper;
    case Mounting::socket: return &socket;
    case Mounting::light_switch:
    case Mounting::cut_hole: return nullptr;
  }
  return nullptr;
}

std::string threshold_calls(const std::vector<const RunSummary*>& runs) {
  std::vector<std::vector<std::string>> rows;
  std::size_t uncertain = 0;
  std::optional<std::int64_t> most_frames;
  bool undecidable = false;
  for (const RunSummary* run : runs) {
    const auto add = [&](std::string limit, const std::optional<double>& found, const LimitCall& call,
                         std::string (*where)(const PointSummary&), std::string (*value)(double)) {
      std::vector<std::string> row = {table_cell(run->run_id), std::move(limit),
                                      found ? value(*found) : std::string(kNotReached)};
      if (!call.uncertain()) {
        row.insert(row.end(), {"decided", std::string(kNotSwept), std::string(kNotSwept), std::string(kNotSwept)});
        rows.push_back(std::move(row));
        return;
      }
      ++uncertain;
      row.emplace_back("uncertain");
      row.push_back(fmt::format("{} to {}", call.surely ? value(*call.surely) : std::string(kNotReached),
                                call.possibly ? value(*call.possibly) : std::string(kNotReached)));
      // The hardest first: a rate on the threshold, then those needing the
      // most frames, which are the ones nearest it.
      std::vector<std::size_t> deciding = call.deciding;
      std::stable_sort(deciding.begin(), deciding.end(), [&](std::size_t a, std::size_t b) {
        constexpr std::int64_t kNever = std::numeric_limits<std::int64_t>::max();
        return run->points[a].frames_to_decide.value_or(kNever) > run->points[b].frames_to_decide.value_or(kNever);
      });
      constexpr std::size_t kMostListed = 4;
      std::string doubt;
      for (std::size_t i = 0; i < deciding.size() && i < kMostListed; ++i) {
        const PointSummary& p = run->points[deciding[i]];
        doubt += fmt::format("{}{}: {:.1f} % [{:.1f}, {:.1f}] of {}", doubt.empty() ? "" : "; ", where(p), 100 * p.rate,
                             100 * p.rate_interval.low, 100 * p.rate_interval.high, p.frames);
      }
      if (call.deciding.size() > kMostListed) doubt += fmt::format("; {} more", call.deciding.size() - kMostListed);
      row.push_back(std::move(doubt));
      if (call.frames_to_decide) {
        row.push_back(fmt::format("{}", *call.frames_to_decide));
        most_frames = std::max(most_frames.value_or(0), *call.frames_to_decide);
      } else {
        row.emplace_back("none: a rate is on the threshold");
        undecidable = true;
      }
      rows.push_back(std::move(row));
    };
    const auto cm = [](double m) { return one_decimal_or_whole(m * 100) + " cm"; };
    const auto degrees = [](double deg) { return one_decimal_or_whole(deg) + "°"; };
    const auto at_distance = [](const PointSummary& p) { return one_decimal_or_whole(p.distance_m * 100) + " cm"; };
    const auto at_angle = [](const PointSummary& p) { return one_decimal_or_whole(p.angle_deg) + "°"; };
    if (std::any_of(run->points.begin(), run->points.end(), [](const PointSummary& p) { return is_facing(p); })) {
      add("Maximum detection distance", run->max_distance_m, run->max_distance_call, at_distance, cm);
    }
    for (const auto& entry : run->max_angle) {
      for (const int sign : {+1, -1}) {
        const bool swept = std::any_of(run->points.begin(), run->points.end(), [&](const PointSummary& p) {
          return std::abs(p.distance_m - entry.distance_m) <= kSameDistanceM && !is_facing(p) &&
                 (p.angle_deg > 0) == (sign > 0);
        });
        if (!swept) continue;
        add(fmt::format("Maximum viewing angle at {} cm, {} side", one_decimal_or_whole(entry.distance_m * 100),
                        sign > 0 ? "+" : "−"),
            sign > 0 ? entry.positive_deg : entry.negative_deg, sign > 0 ? entry.positive_call : entry.negative_call,
            at_angle, degrees);
      }
    }
  }
  if (rows.empty()) return "No limit to call: the runs have no facing point and no angle sweep.\n";
  std::string text = markdown_table({"Run", "Limit", "Found", "Call", "The intervals allow",
                                     "Points in doubt: rate [95% interval] of frames", "Frames a point needs"},
                                    rows);
  text += fmt::format(
      "\nA point's rate has a 95% interval (Wilson). The point is surely detected when its whole interval is at "
      "or above the threshold, surely not when its whole interval is below, and in doubt otherwise: 30 frames of "
      "30 (interval [88.6, 100] %) cannot tell a rate of 100 % from one of 90 %. A limit is decided when walking "
      "out over the points surely detected ends where walking over every point that may be does; otherwise it "
      "is uncertain, somewhere in the range the intervals allow. Frames a point needs: the most any point in doubt "
      "would need, its rate staying as measured, for its interval to leave the threshold out (n = z² t (1 − t) / "
      "(p − t)²). {}\n",
      uncertain == 0
          ? std::string("Every limit here is decided.")
          : fmt::format("{} of {} limits are uncertain{}.", uncertain, rows.size(),
                        most_frames ? fmt::format("; points of {} frames would decide {}", *most_frames,
                                                  undecidable ? "those whose rates are not on the threshold" : "them")
                                    : std::string("; a rate on the threshold is not decided by more frames")));
  return text;
}

std::vector<const PointSummary*> facing_by_distance(const RunSummary& run) { return facing_nearest_first(run.points); }

std::string_view to_string(RateCall call) {
  switch (call) {
    case RateCall::above: return "above";
    case RateCall::below: return "below";
    case RateCall::uncertain: return "uncertain";
  }
  return "?";
}

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
// deviations over the frames, "_sd": the jitter) over the frames with a pose
// or a pose error, and the medians; then, added later and so at the end, the
// rate's 95% interval and call, the frames that would decide it, and the
// medians' 95% intervals. Empty cells: nothing to average (a standard
// deviation needs two values, a median's interval six).
std::string points_csv(const RunSummary& summary) {
  std::string csv =
      "grid,point,distance_m,angle_deg,rail,rail_steps,turntable,measurements,frames,detected,rate,reached,"
      "frames_corrupt,other_markers,tx_m,ty_m,tz_m,tx_sd_m,ty_sd_m,tz_sd_m,distance_estimated_m,"
      "distance_error_mm,distance_error_sd_mm,distance_error_pct,translation_error_mm,translation_error_sd_mm,"
      "rotation_error_deg,rotation_error_sd_deg,reprojection_error_px,median_translation_error_mm,"
      "median_abs_distance_error_pct,rate_low,rate_high,rate_call,frames_to_decide,distance_estimated_sd_mm,"
      "median_translation_error_low_mm,median_translation_error_high_mm,median_abs_distance_error_low_pct,"
      "median_abs_distance_error_high_pct,median_rotation_error_deg,median_rotation_error_low_deg,"
      "median_rotation_error_high_deg\n";
  const auto median = [](const std::optional<MedianEstimate>& m) { return m ? csv_number(m->median) : std::string(); };
  const auto interval = [](const std::optional<MedianEstimate>& m) {
    return m ? fmt::format("{},{}", csv_number(m->low), csv_number(m->high)) : std::string(",");
  };
  for (const auto& p : summary.points) {
    csv += fmt::format(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},",
        csv_field(p.grid_name), p.point, csv_number(p.distance_m), csv_number(p.angle_deg), csv_number(p.rail),
        csv_steps(p.rail_steps), csv_number(p.turntable), p.measurements.size(), p.frames, p.detected,
        csv_number(p.rate), p.reached ? "true" : "false", p.frames_corrupt, p.other_markers, csv_mean(p.tvec_m[0]),
        csv_mean(p.tvec_m[1]), csv_mean(p.tvec_m[2]), csv_stddev(p.tvec_m[0]), csv_stddev(p.tvec_m[1]),
        csv_stddev(p.tvec_m[2]), csv_mean(p.distance_m_estimated), csv_mean(p.distance_error_mm),
        csv_stddev(p.distance_error_mm), csv_mean(p.distance_error_pct), csv_mean(p.translation_error_mm),
        csv_stddev(p.translation_error_mm), csv_mean(p.rotation_error_deg), csv_stddev(p.rotation_error_deg),
        csv_mean(p.reprojection_error_px), median(p.median_translation_error_mm), median(p.median_distance_error_pct));
    csv += fmt::format("{},{},{},{},{},{},{},{}\n", csv_number(p.rate_interval.low), csv_number(p.rate_interval.high),
                       to_string(p.call), p.frames_to_decide ? fmt::format("{}", *p.frames_to_decide) : std::string(),
                       csv_stddev(p.distance_m_estimated, 1000), interval(p.median_translation_error_mm),
                       interval(p.median_distance_error_pct), csv_median(p.median_rotation_error_deg));
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
        vector = fmt::format("{},{},{},{}", csv_number(t[0]), csv_number(t[1]), csv_number(t[2]), csv_number(norm(t)));
      }
      csv += fmt::format("{},{},{},{},{},{},{},{},{}\n", csv_field(p.grid_name), p.point, csv_number(p.distance_m),
                         csv_number(p.angle_deg), m.repeat + 1, csv_steps(m.rail_steps), m.frames, m.detected, vector);
    }
  }
  return csv;
}

std::string table_6_1(const std::vector<RunSummary>& runs) {
  std::vector<std::vector<std::string>> rows = {
      {"Maximum detection distance", "120 cm"},
      {"Maximum viewing angle at 50 cm", "60°"},
      {"Maximum viewing angle at 95 cm", "45°"},
      {"Median distance error", "9.2 cm at 95 cm (~9.7%)"},
      {"Median translation error", "not measured"},
      {"Median rotation error", "not measured"},
      {"Distance jitter (SD over a point's frames)", "not measured"},
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
  rows.push_back({"Distance jitter (SD over a point's frames)"});

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
        run.max_tvec_difference_m ? millimetres_text(Figure{*run.max_tvec_difference_m * 1000, {}, {}})
                                  : std::string(kNotSwept));
    auto errors = error_cells(run, thesis != nullptr ? thesis->error_distances_m : kPaperErrorDistancesM);
    add(thesis != nullptr ? thesis->distance_error : kNotMeasured, std::move(errors[0]));
    add(kNotMeasured, std::move(errors[1]));
    add(kNotMeasured, std::move(errors[2]));
    add(kNotMeasured, std::move(errors[3]));
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
