#pragma once
// Helpers shared by markerctl's subcommands: errors with their exit codes,
// parsing of lengths, angles and ranges, families and camera models.

#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/family.hpp"

namespace CLI {
class App;
}

namespace markerctl {

inline constexpr int exit_runtime = 1;
inline constexpr int exit_usage = 2;

// What main() turns into "markerctl: <context>: <why>" and an exit code, so
// that a subcommand never prints its own fatal error.
class CommandError : public std::runtime_error {
 public:
  CommandError(int exit_code, std::string context, const std::string& why)
      : std::runtime_error(why), exit_code_(exit_code), context_(std::move(context)) {}
  [[nodiscard]] int exit_code() const { return exit_code_; }
  [[nodiscard]] const std::string& context() const { return context_; }

 private:
  int exit_code_;
  std::string context_;
};

[[nodiscard]] inline CommandError usage_error(std::string context, const std::string& why) {
  return {exit_usage, std::move(context), why};
}
[[nodiscard]] inline CommandError runtime_error(std::string context, const std::string& why) {
  return {exit_runtime, std::move(context), why};
}

// A subcommand: its CLI11 app and what runs when it was chosen. Later
// subcommands (daemon control) register the same way.
struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;
};
using Commands = std::vector<Command>;

void add_marker_command(CLI::App& parent, Commands& commands);
void add_render_command(CLI::App& parent, Commands& commands);
void add_detect_command(CLI::App& parent, Commands& commands);
void add_evaluate_command(CLI::App& parent, Commands& commands);
void add_rig_command(CLI::App& parent, Commands& commands);
void add_cameras_command(CLI::App& parent, Commands& commands);
void add_camera_command(CLI::App& parent, Commands& commands);
void add_report_command(CLI::App& parent, Commands& commands);
void add_sweep_command(CLI::App& parent, Commands& commands);
void add_calibrate_command(CLI::App& parent, Commands& commands);

// "80mm" as 80 and "mm" (the unit lower-cased and trimmed, a leading '+'
// allowed); nothing when the text does not start with a finite number.
struct NumberAndUnit {
  double value;
  std::string unit;
};
std::optional<NumberAndUnit> split_number(std::string_view text);

// The unit a bare number means; a print is sized in millimetres, a scene in metres.
enum class BareUnit { millimetre, metre };

// "80mm", "8cm", "0.08m", "3.15in", or a bare number in `bare`. Returns metres;
// throws a usage error naming `option`.
double parse_length_m(std::string_view text, BareUnit bare, std::string_view option);
// "30", "30deg", "0.5rad". Returns degrees.
double parse_angle_deg(std::string_view text, std::string_view option);
// "a:b:step" (b included when the steps reach it), "a,b,c" or "a"; each value
// through `parse_one`.
std::vector<double> parse_values(std::string_view text, std::string_view option,
                                 const std::function<double(std::string_view)>& parse_one);

// "frame8", "aruco4x4_50", "tag36h11"; a usage error names the valid ones.
markerd::detector::Family parse_family(std::string_view name, std::string_view option = "--family");
std::string family_names();  // "frame8, aruco4x4_50, tag36h11"
void check_id(markerd::detector::Family family, int id, std::string_view option = "--id");

// How help texts name CameraModel::thesis_640x480() (docs/frame-marker.md).
inline constexpr const char* thesis_camera_text =
    "640x480, fx 516, fy 515, cx 319, cy 238, distortion k1 0.3495, k2 -2.2549, p1 0, p2 0, k3 4.9959";
// From a calibration file, or the thesis camera when `path` is empty.
markerd::detector::CameraModel load_camera(const std::string& path);

// What a file argument of "-" reads: the whole of standard input, up to
// `max_bytes`; `what` names it in errors ("the plan"). A terminal is refused:
// nothing was piped in, and markerctl would wait for typing that never ends.
inline constexpr const char* standard_input_name = "standard input";
std::string read_standard_input(std::size_t max_bytes, std::string_view what, const std::string& context);

// One line of JSON; bytes of a file name that are not UTF-8 become U+FFFD
// instead of aborting the output.
std::string json_line(const nlohmann::ordered_json& value);

// Rounds to `digits` decimals so JSON output stays readable at a stated precision.
double rounded(double value, int digits);

}  // namespace markerctl
