#pragma once
// A sweep plan: which (distance, viewing angle) points to visit, in which
// order, how many frames to collect at each, and what counts as "detected".
// Read from TOML (reference: docs/sweep.md); every mistake is a ConfigError
// naming the file, the line and the key. A plan speaks in the rig's ground
// truth (metres from the camera to the turntable axis, degrees from facing),
// not in axis positions: the rig's geometry turns one into the other, so one
// plan runs on any rig.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/rig/rig_config.hpp"

namespace markerd::sweep {

enum class SweepOrder : std::uint8_t {
  grid,   // the slow axis outermost, the fast axis in its given order on every row
  snake,  // the fast axis reverses on every other row (less travel)
};

enum class SweepAxis : std::uint8_t { distance, angle };

// One rectangular block of points: every distance with every angle. A plan
// holds one or more, visited in file order ([[grid]] tables).
struct PlanGrid {
  std::string name;                 // "distance", "angle-50cm": names the block in reports
  std::vector<double> distances_m;  // camera centre to the turntable axis
  std::vector<double> angles_deg;   // viewing angle (turntable - yaw0)
  SweepOrder order = SweepOrder::grid;
  SweepAxis slow_axis = SweepAxis::distance;
};

// What the printed marker is mounted on. The thesis measured it flat on paper
// and glued onto a socket's rounded cover frame (its Table 6.1's two
// columns); the report pairs runs by it.
enum class Mounting : std::uint8_t {
  paper,         // flat, printed on paper, the hole white
  socket,        // cut out and glued onto a socket's rounded cover frame
  light_switch,  // the same on a light switch's frame
  cut_hole,      // flat, its hole cut out: what lies behind shows through
};
// "paper", "socket", "switch", "cut_hole": the plan's words.
[[nodiscard]] std::string_view to_string(Mounting mounting);
[[nodiscard]] std::optional<Mounting> mounting_from_name(std::string_view name);
// "on paper", "on a socket frame", ...: for the report's marker cells.
[[nodiscard]] std::string_view mounting_text(Mounting mounting);
// What the detector is told of it: socket and switch frames are both
// rounded cover frames.
[[nodiscard]] detector::Mounting detector_mounting(Mounting mounting);

struct PlanMarker {
  detector::Family family = detector::Family::frame8;
  int id = 165;
  double size_m = 0.08;
  // Unset: the plan does not say (plans older than the key, or a marker
  // measured on no particular mounting).
  std::optional<Mounting> mounting;
};

struct SweepPlan {
  std::string source;  // the file (or "<string>") it was read from
  std::string text;    // the plan's TOML as read: copied into every run's records
  std::string name;    // "thesis", from the file's `name`
  std::string description;
  PlanMarker marker;
  std::vector<PlanGrid> grids;
  int frames_per_point = 10;                       // frames per measurement
  int repeats = 5;                                 // measurements per point
  std::chrono::milliseconds settle{500};           // after the axes report settled, before collecting
  std::chrono::milliseconds point_timeout{30000};  // move + settle + collect, per measurement
  double detection_threshold = 0.9;                // a point is "detected" when its rate is at least this
  // How long a fault (camera lost, drive alarm, ...) may suspend the run
  // before it fails; 0: wait for ever.
  std::chrono::milliseconds fault_timeout{std::chrono::minutes(10)};
};

// The largest plan text anyone reads or sends: the thesis's plans are a
// few KiB, and lists of thousands of values fit. Every reader of plans holds to it: markerctl before it
// sends a plan, markerd's sweep commands, the loaders here; markerd's control
// requests are long enough for a plan of this size, JSON-escaped.
inline constexpr std::size_t kMaxPlanBytes = 128 * 1024;

// Parses and checks a plan. ConfigError on any mistake, a text over
// kMaxPlanBytes included.
SweepPlan parse_plan(std::string_view text, std::string source = "<string>");
// The text of a plan file: a regular file of at most kMaxPlanBytes
// (ConfigError otherwise, naming the file and saying why: a FIFO, /dev/zero
// or a file too large fails at once).
[[nodiscard]] std::string read_plan_file(const std::filesystem::path& path);
SweepPlan load_plan(const std::filesystem::path& path);
// "big.toml: the plan is 200 KiB (204800 bytes), larger than the 128 KiB allowed"
[[nodiscard]] std::string plan_too_large(std::string_view source, std::size_t bytes);

// Why markerd's detectors, set up as `detector`, cannot measure the plan's
// marker (another family; an id the detector does not report), or the
// marker markerd's config says is on the turntable is mounted otherwise than
// the plan says (`mounted`), or nothing. markerd runs one family's
// detector, from its config: a plan for another family would end "done"
// with nothing detected; a socket plan run on a paper marker would fill the
// report's socket column with paper figures. A plan that does not say its
// mounting matches any. The marker's size is no problem: the runner
// rescales poses to it.
[[nodiscard]] std::optional<std::string> marker_problem(const PlanMarker& marker,
                                                        const detector::DetectorConfig& detector, Mounting mounted);

// One unit of work: a measurement (repeat) at a point. A run is the plan's
// steps in order; the journal records each one done.
struct PlanStep {
  std::size_t index = 0;  // position in the run, 0-based
  std::size_t grid = 0;   // index into SweepPlan::grids
  std::size_t point = 0;  // the point's index within the plan (all grids, in order)
  int repeat = 0;         // 0 .. repeats-1
  double distance_m = 0;
  double angle_deg = 0;
};

// Every step of the plan, in the order it runs: grids in file order, each in
// its order, each point's repeats one after the other.
[[nodiscard]] std::vector<PlanStep> plan_steps(const SweepPlan& plan);

// The axis positions that put the marker at a point, by the rig's geometry
// (the inverse of rig::ground_truth for the rail and turntable).
struct AxisTargets {
  double rail = 0;       // the rail's user units (mm)
  double turntable = 0;  // the turntable's user units (deg)
};
[[nodiscard]] AxisTargets axis_targets(const rig::RigGeometry& geometry, double distance_m, double angle_deg);

// What a dry run tells before anything moves.
struct PlanCheck {
  std::vector<PlanStep> steps;
  std::size_t points = 0;
  // Every point whose axis targets lie outside an axis's soft limits, in words
  // ("point 26 (grid \"distance\": 2.9 m, 0 deg): rail 2600 mm is beyond its
  // max_position 2500 mm"). The runner refuses a plan with problems.
  std::vector<std::string> problems;
  // Every point whose measurement would, by the estimate, outlast the plan's
  // point_timeout (a long move between grids, frames at a slow camera). The
  // run may still go through (the runner retries a timed-out step), but it
  // should not depend on that.
  std::vector<std::string> warnings;
  // Moves by the axes' trapezoidal profiles (scaled by a simulated rig's
  // time scale), the axes' settle times, the plan's settle time and the frames
  // at the camera's frame rate; homing not included.
  std::chrono::duration<double> estimated_duration{0};
  double fps = 0;  // the frame rate the estimate assumed (0: unknown)
  [[nodiscard]] bool ok() const { return problems.empty(); }
};
// `fps`: the camera's frame rate (0: unknown, frames cost nothing in the estimate).
[[nodiscard]] PlanCheck check_plan(const SweepPlan& plan, const rig::RigConfig& rig, double fps);

// The dry run in words, as docs/sweep.md shows it: the plan's grids, the
// estimate, then the problems and warnings, one a line.
[[nodiscard]] std::string format_plan_check(const SweepPlan& plan, const PlanCheck& check);

}  // namespace markerd::sweep
