#pragma once
// A camera's controls at run time, whatever its backend: what `camera.get`
// lists (each control's value, range, step, default, menu) and how a value
// given for one is checked against them before anything is written
// (`camera.set`, and the config's [camera.v4l2.controls] when the camera
// opens). The checks are pure functions over a control's description; each
// backend reads and writes its own device (CaptureSource::read_controls and
// write_control). See docs/capture.md#controls-at-run-time.

#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace markerd::daemon {

class CaptureSource;

// A control's value: a boolean, a whole number (integers, menu items,
// bitmasks) or a real number.
using ControlValue = std::variant<bool, std::int64_t, double>;
// A value given for a control (from the config or camera.set): one of those,
// or a word, a menu item's name.
using ControlInput = std::variant<bool, std::int64_t, double, std::string>;

struct ControlMenuItem {
  std::int64_t index = 0;
  std::string name;  // a menu's item name, or an integer menu's value as text
};

enum class ControlKind : std::uint8_t {
  integer,  // whole numbers from minimum to maximum, on minimum + a multiple of step
  boolean,
  menu,     // one of the menu's items, by index or by name
  bitmask,  // bits within maximum
  real,     // any number from minimum to maximum
  other,    // read, but not set by markerd (a button, a string, an array, a rectangle)
};

struct CameraControlInfo {
  std::string name;      // as the config and camera.set name it
  std::uint32_t id = 0;  // the backend's own number for it (V4L2's control id, libcamera's ControlId)
  std::string type;      // the backend's word: "int", "bool", "menu", "float", "int32", "button", ...
  ControlKind kind = ControlKind::other;
  std::optional<ControlValue> value;  // now; none where it cannot be read (write-only)
  std::optional<ControlValue> minimum, maximum, default_value;
  std::uint64_t step = 0;             // integer: 0 or 1 takes any whole number
  std::vector<ControlMenuItem> menu;  // menu
  std::vector<ControlValue> allowed;  // an enumerated control's only values (libcamera's)
  std::vector<std::string> flags;     // "read-only", "inactive", "write-only", "volatile", "grabbed"
  std::string why_not_settable;       // other: why ("a button (an action, not a setting)")
};

[[nodiscard]] bool has_flag(const CameraControlInfo& control, std::string_view flag);
// An automatic mode (auto_exposure, white_balance_automatic, AeEnable, ...):
// set before the others, since it decides whether they take effect.
[[nodiscard]] bool is_automatic_mode(std::string_view name);

// Why a value cannot be written to a control, in words meant for whoever gave
// it ("300 is out of its range 0 to 255"): the caller names the control and
// where the value came from.
class ControlValueError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The value to write to `control` for `input`: a boolean control takes true,
// false, 1 or 0; an integer one a whole number in its range and on its steps
// (2.0 counts, 2.5 does not); a menu an item's index or name (case and
// punctuation aside: "50 Hz" or "50_hz"); a real one any number in its range;
// an enumerated one only its values. ControlValueError for anything else and
// for a read-only control, naming the range or the items.
[[nodiscard]] ControlValue check_control_value(const CameraControlInfo& control, const ControlInput& input);

// "0 to 255", "25 to 400 in steps of 25", "0.01 to 4", "true or false",
// "0: Manual Mode, 1: Aperture Priority Mode", "one of 0, 1, 2".
[[nodiscard]] std::string describe_range(const CameraControlInfo& control);
// "200", "true", "0.5", "\"50 Hz\"".
[[nodiscard]] std::string to_text(const ControlInput& value);
[[nodiscard]] std::string to_text(const ControlValue& value);
// A value with its menu item where it has one: "1 (Manual Mode)".
[[nodiscard]] std::string value_text(const CameraControlInfo& control, const ControlValue& value);

[[nodiscard]] nlohmann::json to_json(const ControlValue& value);
// camera.get's entry: name, type, value, min, max, step, default, menu or
// values where it has them, flags.
[[nodiscard]] nlohmann::json to_json(const CameraControlInfo& control);
// A value from camera.set's JSON: a boolean, a whole number, a number or a
// string; ControlValueError naming what was given otherwise.
[[nodiscard]] ControlInput control_input_from_json(const nlohmann::json& value);

struct ControlAssignment {
  std::string name;
  ControlInput value;
};

struct ControlChange {
  CameraControlInfo control;  // as it was before the change
  std::optional<ControlValue> old_value;
  ControlValue new_value;
};

// Sets every assignment on `source`, or none: each is checked against the
// control's description (check_control_value) before anything is written;
// then they are written one at a time, automatic modes first, each control
// read again first so that one an earlier write made inactive or active is
// seen as it is now. A refusal (an unknown control, a value it cannot take,
// a control inactive now, the device's own refusal) puts back the ones
// written before it and throws ControlValueError naming the control, the
// value and what it takes. Any thread: the sources guard their devices.
std::vector<ControlChange> set_camera_controls(CaptureSource& source, std::span<const ControlAssignment> assignments);

}  // namespace markerd::daemon
