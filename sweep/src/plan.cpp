#include "markerd/sweep/plan.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <utility>
#include <variant>

#include "markerd/base/read_file.hpp"
#include "markerd/rig/motion_profile.hpp"

namespace markerd::sweep {

namespace {

// Past these a plan is a slip of the keyboard (a step of 0.0001, repeats =
// 50000), not an experiment: better refused than expanded into gigabytes.
constexpr std::size_t kMaxValuesPerAxis = 10000;
constexpr std::size_t kMaxSteps = 1000000;
// Plan names end up in run directory names, grid names in report files.
constexpr std::size_t kMaxNameLength = 64;

// The ranges in which a plan's numbers mean something physically. A rig's
// rail is a few metres long and resolves hundredths of a millimetre; a
// printed marker is a few millimetres to a poster; a measurement takes
// seconds, and a fault worth waiting for hours, not months.
constexpr ConfigTable::Range<int> kFramesPerPoint{1, 10000, "frames"};
constexpr ConfigTable::Range<int> kRepeats{1, 1000, "measurements per point"};
constexpr ConfigTable::Range<double> kSettleSeconds{0, 600, "s"};
constexpr ConfigTable::Range<double> kPointTimeoutSeconds{0.1, 86400, "s"};
constexpr ConfigTable::Range<double> kFaultTimeoutSeconds{0, 7 * 86400, "s (0: wait for ever)"};
constexpr ConfigTable::Range<double> kMarkerSize{0.005, 2, "m"};
constexpr double kMinDistance = 0.01;  // metres: a camera touching the marker sees no marker
constexpr double kMaxDistance = 100;
constexpr ConfigTable::Range<double> kDistanceStep{0.0001, 100, "m"};
constexpr ConfigTable::Range<double> kAngleStep{0.001, 180, "deg"};

bool valid_name(std::string_view name) {
  const auto allowed = [](char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == '-';
  };
  return !name.empty() && name.size() <= kMaxNameLength && std::all_of(name.begin(), name.end(), allowed);
}

std::string read_name(const ConfigTable& t, std::string_view key, std::string name, std::string_view used_for) {
  if (!valid_name(name)) {
    t.fail(key, fmt::format("must be 1 to {} of A-Z a-z 0-9 . _ - (it names {}), got \"{}\"", kMaxNameLength, used_for,
                            name));
  }
  return name;
}

// A number of seconds in `range`, kept as milliseconds.
std::chrono::milliseconds read_seconds(const ConfigTable& t, std::string_view key, std::chrono::milliseconds fallback,
                                       ConfigTable::Range<double> range) {
  const auto seconds = t.maybe<double>(key, range);
  if (!seconds) return fallback;
  return std::chrono::milliseconds(std::llround(*seconds * 1000));
}

PlanMarker parse_marker(const ConfigTable& root) {
  PlanMarker marker;
  const auto t = root.maybe_table("marker");
  if (!t) return marker;
  t->allow_only({"family", "id", "size_m", "mounting"});
  if (const auto name = t->maybe<std::string>("family")) {
    const auto family = detector::family_from_name(*name);
    if (!family) {
      std::string known;
      for (const detector::FamilyInfo& info : detector::all_families())
        known += fmt::format("{}{}", known.empty() ? "" : ", ", info.name);
      t->fail("family", fmt::format("unknown family '{}' (known: {})", *name, known));
    }
    marker.family = *family;
  }
  const bool id_given = t->contains("id");
  marker.id = t->optional<int>("id", marker.id);
  const detector::FamilyInfo& info = detector::family_info(marker.family);
  if (marker.id < 0 || marker.id >= info.id_count) {
    t->fail("id", fmt::format("must be 0 .. {} for {}, got {}{}", info.id_count - 1, info.name, marker.id,
                              id_given ? "" : " (the default: give the marker's id)"));
  }
  marker.size_m = t->optional<double>("size_m", marker.size_m, kMarkerSize);
  if (const auto name = t->maybe<std::string>("mounting")) {
    marker.mounting = mounting_from_name(*name);
    if (!marker.mounting) {
      t->fail("mounting", fmt::format("unknown mounting '{}' (known: paper, socket, switch, cut_hole)", *name));
    }
  }
  return marker;
}

enum class Quantity { distance, angle };

// What is wrong with one value of an axis, if anything.
std::optional<std::string> value_problem(Quantity quantity, double value) {
  if (!std::isfinite(value)) return fmt::format("must be a finite number, got {}", value);
  if (quantity == Quantity::distance && !(value >= kMinDistance && value <= kMaxDistance)) {
    return fmt::format("must be from {} to {} m (from the camera to the turntable axis), got {}", kMinDistance,
                       kMaxDistance, value);
  }
  // At 90 deg the marker is seen edge on: nothing to detect, and ground_truth's
  // pose would be degenerate.
  if (quantity == Quantity::angle && !(std::abs(value) < 90)) {
    return fmt::format("must lie strictly between -90 and 90 (degrees from facing the camera), got {}", value);
  }
  return std::nullopt;
}

// Snaps away the float drift of from + i * step (0.3 + 25 * 0.1 is
// 2.8000000000000003): a nanometre or a nanodegree is far below anything the
// rig resolves, and plans, records and reports then all print "2.8".
double snap(double value) { return std::round(value * 1e9) / 1e9; }

std::vector<double> parse_range(const ConfigTable& range, Quantity quantity) {
  range.allow_only({"from", "to", "step"});
  const double from = range.required<double>("from");
  const double to = range.required<double>("to");
  // A step below what any rig resolves is a typo (1e-300 would make a count
  // of 300 digits).
  const double step = range.required<double>("step", quantity == Quantity::distance ? kDistanceStep : kAngleStep);
  if (auto problem = value_problem(quantity, from)) range.fail("from", *problem);
  if (!std::isfinite(to)) range.fail("to", fmt::format("must be a finite number, got {}", to));
  if (!(from <= to)) {
    range.fail("to", fmt::format("must be >= from ({}), got {} (a range ascends; for another order list the values)",
                                 from, to));
  }
  // Reaching `to` within a billionth of a step counts: (2.8 - 0.3) / 0.1 is
  // 24.999999999999996, and 2.8 belongs to the range.
  const double steps_to_end = (to - from) / step + 1e-9;
  if (!(steps_to_end < static_cast<double>(kMaxValuesPerAxis))) {
    // {:.7g}: exact up to ten million, and a far `to` prints as 1e+300, not 300 digits.
    range.fail("step", fmt::format("makes {:.7g} values from {} to {}, more than {}", std::floor(steps_to_end) + 1,
                                   from, to, kMaxValuesPerAxis));
  }
  const auto last = static_cast<std::size_t>(std::floor(steps_to_end));
  std::vector<double> values;
  values.reserve(last + 1);
  for (std::size_t i = 0; i <= last; ++i) values.push_back(snap(from + static_cast<double>(i) * step));
  if (auto problem = value_problem(quantity, values.back())) {
    range.fail("to", fmt::format("the range reaches {}: {}", values.back(), *problem));
  }
  return values;
}

// `distance_m` or `angle_deg` of a grid: a list, visited in its order, or a
// range table.
std::vector<double> parse_axis_values(const ConfigTable& grid, std::string_view key, Quantity quantity) {
  const toml::node* node = grid.raw().get(key);
  if (node == nullptr) {
    grid.fail(
        fmt::format("missing key '{}.{}' (a list of numbers, or a range {{ from, to, step }})", grid.key_path(), key));
  }
  if (node->is_table()) return parse_range(grid.table(key), quantity);
  const toml::array* list = node->as_array();
  if (list == nullptr) {
    grid.fail(key, "must be a list of numbers ([0.5, 0.95]) or a range ({ from = 0.3, to = 2.8, step = 0.1 })");
  }
  if (list->empty()) grid.fail(key, "is empty: a grid needs at least one value on each axis");
  if (list->size() > kMaxValuesPerAxis) {
    grid.fail(key, fmt::format("lists {} values, more than {}", list->size(), kMaxValuesPerAxis));
  }
  std::vector<double> values;
  values.reserve(list->size());
  for (std::size_t i = 0; i < list->size(); ++i) {
    const toml::node& element = (*list)[i];
    if (!element.is_number()) grid.fail(key, fmt::format("element {} must be a number", i));
    const double value = *element.value<double>();
    if (auto problem = value_problem(quantity, value)) grid.fail(key, fmt::format("element {}: {}", i, *problem));
    // Within a grid a point visited twice is a typo; the summaries would
    // merge the two anyway.
    if (std::find(values.begin(), values.end(), value) != values.end()) {
      grid.fail(key, fmt::format("lists {} twice", value));
    }
    values.push_back(value);
  }
  return values;
}

PlanGrid parse_grid(const ConfigTable& t, std::size_t index) {
  t.allow_only({"name", "distance_m", "angle_deg", "order", "slow_axis"});
  PlanGrid grid;
  grid.name =
      read_name(t, "name", t.optional<std::string>("name", fmt::format("grid{}", index)), "the grid in reports");
  grid.distances_m = parse_axis_values(t, "distance_m", Quantity::distance);
  grid.angles_deg = parse_axis_values(t, "angle_deg", Quantity::angle);
  const auto order = t.optional<std::string>("order", "grid");
  if (order == "grid") {
    grid.order = SweepOrder::grid;
  } else if (order == "snake") {
    grid.order = SweepOrder::snake;
  } else {
    t.fail("order", fmt::format("must be \"grid\" or \"snake\", got \"{}\"", order));
  }
  const auto slow_axis = t.optional<std::string>("slow_axis", "distance");
  if (slow_axis == "distance") {
    grid.slow_axis = SweepAxis::distance;
  } else if (slow_axis == "angle") {
    grid.slow_axis = SweepAxis::angle;
  } else {
    t.fail("slow_axis", fmt::format("must be \"distance\" or \"angle\", got \"{}\"", slow_axis));
  }
  return grid;
}

std::vector<PlanGrid> parse_grids(const ConfigTable& root, std::string_view text, const std::string& source) {
  const toml::node* node = root.raw().get("grid");
  if (node == nullptr) root.fail("missing [[grid]]: a plan visits the points of one or more grids");
  const toml::array* array = node->as_array();
  if (array == nullptr || array->empty() || !array->is_array_of_tables()) {
    root.fail("grid", "must be one or more [[grid]] tables (two brackets)");
  }
  // ConfigTable reads tables, not arrays of them. The grid tables are moved
  // out of a second parse of the text (a copy would lose their lines) into a
  // table of their own under the keys "grid[0]", "grid[1]", ..., so that their
  // errors name "grid[1].angle_deg.step" and its line like any other key's.
  toml::table document = toml::parse(text, source);  // parsed once already: it cannot fail
  toml::array& tables = *document.get_as<toml::array>("grid");
  auto by_index = std::make_shared<toml::table>();
  for (std::size_t i = 0; i < tables.size(); ++i) {
    by_index->insert(fmt::format("grid[{}]", i), std::move(*tables[i].as_table()));
  }
  const ConfigTable grid_tables(std::move(by_index), source);

  std::vector<PlanGrid> grids;
  for (std::size_t i = 0; i < tables.size(); ++i) {
    const ConfigTable t = grid_tables.table(fmt::format("grid[{}]", i));
    PlanGrid grid = parse_grid(t, i);
    for (const PlanGrid& other : grids) {
      if (other.name == grid.name) t.fail("name", fmt::format("\"{}\" names an earlier grid already", grid.name));
    }
    grids.push_back(std::move(grid));
  }
  return grids;
}

// A number for people: at most three decimals, no trailing zeros ("2.9",
// "2600", "-0.2").
std::string short_number(double value) {
  std::string text = fmt::format("{:.3f}", value);
  text.erase(text.find_last_not_of('0') + 1);
  if (text.back() == '.') text.pop_back();
  if (text == "-0") text = "0";
  return text;
}

std::string describe_point(const SweepPlan& plan, const PlanStep& step) {
  return fmt::format("point {} (grid \"{}\": {} m, {} deg)", step.point, plan.grids[step.grid].name,
                     short_number(step.distance_m), short_number(step.angle_deg));
}

// Why a target lies outside an axis's soft limits, or nothing.
std::optional<std::string> limit_problem(const rig::AxisSettings& axis, double target) {
  if (target > axis.max_position) {
    return fmt::format("{} {} {} is beyond its max_position {} {}", axis.name, short_number(target), axis.unit,
                       short_number(axis.max_position), axis.unit);
  }
  if (target < axis.min_position) {
    return fmt::format("{} {} {} is below its min_position {} {}", axis.name, short_number(target), axis.unit,
                       short_number(axis.min_position), axis.unit);
  }
  return std::nullopt;
}

// Seconds from the moment one axis is told to go from `from` to `to` until it
// reports settled, as Axis::begin_move does it: one leg along the trapezoid,
// or, when backlash compensation makes it arrive from the other side, a leg to
// the overshoot and a leg back. The drive's poll latency between the legs is
// left out. A simulated drive moves in simulated time; settling is counted by
// the Axis in real time.
double axis_seconds(const rig::AxisConfig& config, double from, double to, double time_scale) {
  const rig::AxisSettings& a = config.axis;
  // The Axis compares targets in motor steps: a difference below a step is no move.
  if (std::llround(from / a.units_per_step) == std::llround(to / a.units_per_step)) return 0;
  const auto leg = [&](double start, double end) {
    return rig::TrapezoidProfile(std::abs(end - start), a.max_velocity, a.acceleration).duration();
  };
  double moving = 0;
  if (a.backlash > 0 && (to - from) * a.approach_direction < 0) {
    const double overshoot = std::clamp(to - a.approach_direction * a.backlash, a.min_position, a.max_position);
    moving = leg(from, overshoot) + leg(overshoot, to);
  } else {
    moving = leg(from, to);
  }
  if (std::holds_alternative<rig::SimDriveSettings>(config.drive)) moving /= time_scale;
  return moving + std::chrono::duration<double>(a.settle_time).count();
}

std::string format_duration(std::chrono::duration<double> duration) {
  const double seconds = duration.count();
  if (seconds >= 3600) {
    const auto minutes = std::llround(seconds / 60);
    return fmt::format("{} h {:02} min", minutes / 60, minutes % 60);
  }
  if (seconds >= 60) {
    const auto whole = std::llround(seconds);
    return fmt::format("{} min {:02} s", whole / 60, whole % 60);
  }
  return fmt::format("{:.1f} s", seconds);
}

std::string describe_values(const std::vector<double>& values, std::string_view unit, std::string_view what) {
  if (values.size() == 1) return fmt::format("{} {}", short_number(values.front()), unit);
  return fmt::format("{} {} {} .. {} {}", values.size(), what, short_number(values.front()),
                     short_number(values.back()), unit);
}

}  // namespace

std::string_view to_string(Mounting mounting) {
  switch (mounting) {
    case Mounting::paper: return "paper";
    case Mounting::socket: return "socket";
    case Mounting::light_switch: return "switch";
    case Mounting::cut_hole: return "cut_hole";
  }
  return "?";
}

std::optional<Mounting> mounting_from_name(std::string_view name) {
  for (const Mounting m : {Mounting::paper, Mounting::socket, Mounting::light_switch, Mounting::cut_hole}) {
    if (name == to_string(m)) return m;
  }
  return std::nullopt;
}

std::string_view mounting_text(Mounting mounting) {
  switch (mounting) {
    case Mounting::paper: return "on paper";
    case Mounting::socket: return "on a socket frame";
    case Mounting::light_switch: return "on a switch frame";
    case Mounting::cut_hole: return "hole cut out";
  }
  return "?";
}

detector::Mounting detector_mounting(Mounting mounting) {
  switch (mounting) {
    case Mounting::paper: return detector::Mounting::paper;
    case Mounting::socket:
    case Mounting::light_switch: return detector::Mounting::cover_frame;
    case Mounting::cut_hole: return detector::Mounting::cut_hole;
  }
  return detector::Mounting::any;
}

SweepPlan parse_plan(std::string_view text, std::string source) {
  if (text.size() > kMaxPlanBytes) throw ConfigError(plan_too_large(source, text.size()));
  const ConfigTable root = ConfigTable::parse(text, source);
  root.allow_only({"name", "description", "frames_per_point", "repeats", "settle_s", "point_timeout_s",
                   "detection_threshold", "fault_timeout_s", "marker", "grid"});
  SweepPlan plan;
  plan.source = source;
  plan.text = std::string(text);
  plan.name = read_name(root, "name", root.required<std::string>("name"), "the plan's runs");
  plan.description = root.optional<std::string>("description", "");
  plan.frames_per_point = root.optional<int>("frames_per_point", plan.frames_per_point, kFramesPerPoint);
  plan.repeats = root.optional<int>("repeats", plan.repeats, kRepeats);
  plan.settle = read_seconds(root, "settle_s", plan.settle, kSettleSeconds);
  plan.point_timeout = read_seconds(root, "point_timeout_s", plan.point_timeout, kPointTimeoutSeconds);
  plan.fault_timeout = read_seconds(root, "fault_timeout_s", plan.fault_timeout, kFaultTimeoutSeconds);
  plan.detection_threshold = root.optional<double>("detection_threshold", plan.detection_threshold);
  if (!(plan.detection_threshold > 0 && plan.detection_threshold <= 1)) {
    root.fail("detection_threshold",
              fmt::format("must lie in (0, 1] (a share of the frames), got {}", plan.detection_threshold));
  }
  plan.marker = parse_marker(root);
  plan.grids = parse_grids(root, text, source);

  // Each grid is bounded (values per axis, repeats), so the sum cannot
  // overflow before it passes the limit.
  std::size_t steps = 0;
  for (const PlanGrid& grid : plan.grids) {
    steps += grid.distances_m.size() * grid.angles_deg.size() * static_cast<std::size_t>(plan.repeats);
    if (steps > kMaxSteps) break;
  }
  if (steps > kMaxSteps) {
    root.fail(fmt::format("the plan makes {}{} measurements (points times repeats), more than {}",
                          plan.grids.size() > 1 ? "at least " : "", steps, kMaxSteps));
  }
  return plan;
}

std::string plan_too_large(std::string_view source, std::size_t bytes) {
  return fmt::format("{}: the plan is {} ({} bytes), larger than the {} allowed", source, format_bytes(bytes), bytes,
                     format_bytes(kMaxPlanBytes));
}

std::string read_plan_file(const std::filesystem::path& path) {
  try {
    return read_regular_file(path, kMaxPlanBytes, "the plan");
  } catch (const FileError& e) {
    throw ConfigError(e.what());
  }
}

SweepPlan load_plan(const std::filesystem::path& path) {
  // Read here rather than by ConfigTable::load_file: the text goes into the
  // run's records verbatim, and is parsed again from there.
  return parse_plan(read_plan_file(path), path.string());
}

std::optional<std::string> marker_problem(const PlanMarker& marker, const detector::DetectorConfig& detector,
                                          Mounting mounted) {
  const detector::FamilyInfo& info = detector::family_info(marker.family);
  if (marker.family != detector.family) {
    return fmt::format(
        "the plan's marker is {} #{}, but markerd detects {} (its config's [marker] family): run the "
        "plan on a markerd configured for {}, or give the plan the family markerd detects",
        info.name, marker.id, detector::family_info(detector.family).name, info.name);
  }
  const bool reported = marker.id >= info.first_default_id && marker.id <= info.last_default_id;
  if (!reported && !(marker.family == detector::Family::frame8 && detector.frame8.uniform_ids)) {
    return fmt::format(
        "the plan's marker is {} #{}, an id markerd's detector does not report (frame8's 0 and 255 "
        "need [detector.frame8] uniform_ids = true in markerd's config)",
        info.name, marker.id);
  }
  if (marker.mounting && *marker.mounting != mounted) {
    return fmt::format(
        "the plan's marker is mounted \"{}\" ([marker] mounting), but markerd's is mounted \"{}\" (its config's "
        "[marker] mounting): run the plan on a markerd configured with mounting = \"{}\", or give the plan the "
        "mounting markerd has",
        to_string(*marker.mounting), to_string(mounted), to_string(*marker.mounting));
  }
  return std::nullopt;
}

std::vector<PlanStep> plan_steps(const SweepPlan& plan) {
  std::size_t total = 0;
  for (const PlanGrid& grid : plan.grids) total += grid.distances_m.size() * grid.angles_deg.size();
  std::vector<PlanStep> steps;
  steps.reserve(total * static_cast<std::size_t>(std::max(plan.repeats, 0)));
  std::size_t point = 0;
  for (std::size_t g = 0; g < plan.grids.size(); ++g) {
    const PlanGrid& grid = plan.grids[g];
    const bool distance_slow = grid.slow_axis == SweepAxis::distance;
    const std::vector<double>& slow = distance_slow ? grid.distances_m : grid.angles_deg;
    const std::vector<double>& fast = distance_slow ? grid.angles_deg : grid.distances_m;
    for (std::size_t row = 0; row < slow.size(); ++row) {
      const bool reversed = grid.order == SweepOrder::snake && row % 2 == 1;
      for (std::size_t column = 0; column < fast.size(); ++column) {
        const double fast_value = fast[reversed ? fast.size() - 1 - column : column];
        const double distance = distance_slow ? slow[row] : fast_value;
        const double angle = distance_slow ? fast_value : slow[row];
        for (int repeat = 0; repeat < plan.repeats; ++repeat) {
          steps.push_back(PlanStep{steps.size(), g, point, repeat, distance, angle});
        }
        ++point;
      }
    }
  }
  return steps;
}

AxisTargets axis_targets(const rig::RigGeometry& geometry, double distance_m, double angle_deg) {
  // ground_truth: d = d0 + rail_sign * rail * cos(tilt) and yaw = turntable
  // - yaw0. The mount offsets place the camera and the marker beside the
  // turntable axis; they do not change d (along the optical axis, to the
  // turntable axis) or the yaw, so the inverse is exact.
  return {rig::rail_for_distance_mm(geometry, distance_m * 1000.0), angle_deg + geometry.yaw0_deg};
}

PlanCheck check_plan(const SweepPlan& plan, const rig::RigConfig& rig, double fps) {
  PlanCheck check;
  check.steps = plan_steps(plan);
  check.points = check.steps.empty() ? 0 : check.steps.back().point + 1;
  check.fps = std::isfinite(fps) && fps > 0 ? fps : 0;

  const double settle_s = std::chrono::duration<double>(plan.settle).count();
  const double frames_s = check.fps > 0 ? plan.frames_per_point / check.fps : 0;
  const double timeout_s = std::chrono::duration<double>(plan.point_timeout).count();
  double total_s = 0;
  // Where the axes stand before the first step is unknown until they are
  // homed: the estimate starts at the first point, its move not counted.
  std::optional<AxisTargets> previous;
  for (const PlanStep& step : check.steps) {
    const AxisTargets targets = axis_targets(rig.geometry, step.distance_m, step.angle_deg);
    double motion_s = 0;
    if (previous) {
      // Both axes move at once; the step goes on when the later one has settled.
      motion_s = std::max(axis_seconds(rig.rail, previous->rail, targets.rail, rig.sim.time_scale),
                          axis_seconds(rig.turntable, previous->turntable, targets.turntable, rig.sim.time_scale));
    }
    previous = targets;
    const double step_s = motion_s + settle_s + frames_s;
    total_s += step_s;
    // One line per point: only its first measurement moves, so it is the longest.
    if (step.repeat != 0) continue;

    std::string outside;
    for (const auto& problem :
         {limit_problem(rig.rail.axis, targets.rail), limit_problem(rig.turntable.axis, targets.turntable)}) {
      if (problem) outside += (outside.empty() ? "" : "; ") + *problem;
    }
    if (!outside.empty()) check.problems.push_back(fmt::format("{}: {}", describe_point(plan, step), outside));
  }
  // The runner gives a move its own allowance (from the same profiles) and
  // the point timeout to what follows it: settling and frames, the same for
  // every measurement.
  if (settle_s + frames_s > timeout_s) {
    check.warnings.push_back(
        fmt::format("every measurement's settling and frames take about {:.1f} s, longer than "
                    "point_timeout_s = {}: each will time out",
                    settle_s + frames_s, short_number(timeout_s)));
  }
  check.estimated_duration = std::chrono::duration<double>(total_s);
  return check;
}

std::string format_plan_check(const SweepPlan& plan, const PlanCheck& check) {
  std::string out = fmt::format(
      "plan \"{}\" ({}): {} points in {} grid{}, {} measurement{} of {} frames each: {} "
      "measurements\n",
      plan.name, plan.source, check.points, plan.grids.size(), plan.grids.size() == 1 ? "" : "s", plan.repeats,
      plan.repeats == 1 ? "" : "s", plan.frames_per_point, check.steps.size());
  for (std::size_t g = 0; g < plan.grids.size(); ++g) {
    const PlanGrid& grid = plan.grids[g];
    const std::size_t points = grid.distances_m.size() * grid.angles_deg.size();
    out += fmt::format("  grid {} \"{}\": {} point{}: {} x {}, {} order, slow axis {}\n", g, grid.name, points,
                       points == 1 ? "" : "s", describe_values(grid.distances_m, "m", "distances"),
                       describe_values(grid.angles_deg, "deg", "angles"),
                       grid.order == SweepOrder::snake ? "snake" : "grid",
                       grid.slow_axis == SweepAxis::distance ? "distance" : "angle");
  }
  out += fmt::format("estimated duration: {} (moves, settling, {}; homing not included)\n",
                     format_duration(check.estimated_duration),
                     check.fps > 0 ? fmt::format("frames at {} fps", short_number(check.fps))
                                   : std::string("frames not counted: frame rate unknown"));
  if (check.problems.empty()) {
    out += "every point lies within the axes' soft limits\n";
  } else {
    out += fmt::format("{} point{} outside the axes' soft limits:\n", check.problems.size(),
                       check.problems.size() == 1 ? "" : "s");
    for (const std::string& problem : check.problems) out += fmt::format("  {}\n", problem);
  }
  if (!check.warnings.empty()) {
    out += fmt::format("{} warning{}:\n", check.warnings.size(), check.warnings.size() == 1 ? "" : "s");
    for (const std::string& warning : check.warnings) out += fmt::format("  {}\n", warning);
  }
  return out;
}

}  // namespace markerd::sweep
