#pragma once
// The V4L2 capture source (a UVC webcam, a capture card, vivid in the tests)
// and the listing of V4L2 capture devices behind `markerctl cameras`. See
// docs/capture.md.
//
// The source streams through mmap buffers. GREY frames, and the Y plane of
// NV12 frames, are lent to the pipeline without a copy: the frame points into
// the mmap buffer and its release hook queues the buffer again. YUYV frames
// are converted into the frame slot's own pixels and the buffer goes back at
// once. MJPEG frames are lent encoded: the pipeline worker that detects one
// decodes it into the slot's pixels and the buffer goes back then
// (Frame::set_encoded), so frames dropped while they wait are never decoded.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "markerd/daemon/capture/capture_source.hpp"

namespace markerd {
class ConfigTable;
}

namespace markerd::daemon {

enum class V4l2PixelFormat : std::uint8_t { grey, yuyv, nv12, mjpg };
[[nodiscard]] std::string_view to_string(V4l2PixelFormat format);  // "GREY", "YUYV", "NV12", "MJPG"
[[nodiscard]] std::uint32_t fourcc_of(V4l2PixelFormat format);     // V4L2_PIX_FMT_*
// "YUYV", "MJPG", or a fourcc's four characters with trailing blanks cut
// ("Y16 " is "Y16"), with "-BE" for a big-endian one.
[[nodiscard]] std::string fourcc_text(std::uint32_t fourcc);

// One entry of [camera.v4l2.controls].
struct V4l2ControlSetting {
  std::string name;  // as v4l2-ctl prints it: exposure_time_absolute, power_line_frequency
  // An integer, a boolean, or the name of a menu item ("50 Hz", or "50_hz").
  std::variant<std::int64_t, bool, std::string> value;
  std::string origin;  // "markerd.toml:14: camera.v4l2.controls.gain": names it in errors at open()
};

struct V4l2Settings {
  // "/dev/video0", a stable link ("/dev/v4l/by-id/usb-...-video-index0"), or
  // the bare name of one, looked up in /dev/v4l/by-id, then /dev/v4l/by-path.
  std::string device;
  V4l2PixelFormat format = V4l2PixelFormat::yuyv;
  int width = 0;
  int height = 0;
  double fps = 0;  // 0: leave the device's frame rate as it is
  int buffers = 4;
  std::optional<int> input;  // VIDIOC_S_INPUT; the device's current input when empty
  std::vector<V4l2ControlSetting> controls;
};

// [camera.v4l2]: device, format (GREY, YUYV, NV12, MJPG), width, height,
// fps, buffers, input, and a [camera.v4l2.controls] table. Throws
// ConfigError naming the file, line and key.
V4l2Settings parse_v4l2_settings(const ConfigTable& table);

// Throws std::runtime_error when TurboJPEG cannot start (MJPG only).
std::unique_ptr<CaptureSource> make_v4l2_source(const V4l2Settings& settings);

// The device node a configured name means: a path is taken as it is (a
// by-id or by-path link opens the node it points at); a bare name is looked
// up in <dev_dir>/v4l/by-id, then <dev_dir>/v4l/by-path. Throws CaptureError
// (not_found) naming both places when a bare name is in neither.
std::filesystem::path resolve_v4l2_device(std::string_view device, const std::filesystem::path& dev_dir = "/dev");

// ---------------------------------------------------------------- listing

struct V4l2Fraction {
  std::uint32_t numerator = 0;
  std::uint32_t denominator = 0;
};

// Frame intervals (seconds per frame) at one size: a list, or a range.
struct V4l2Intervals {
  std::vector<V4l2Fraction> discrete;
  std::optional<V4l2Fraction> min, max, step;  // stepwise or continuous (step 1/1... as the driver says)
};

struct V4l2FrameSize {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  V4l2Intervals intervals;
};

struct V4l2SizeRange {  // VIDIOC_ENUM_FRAMESIZES stepwise or continuous
  std::uint32_t min_width = 0, max_width = 0, step_width = 0;
  std::uint32_t min_height = 0, max_height = 0, step_height = 0;
};

struct V4l2FormatInfo {
  std::uint32_t fourcc = 0;
  std::string fourcc_text;  // "YUYV"
  std::string description;  // the driver's: "YUYV 4:2:2"
  bool compressed = false;
  bool emulated = false;
  std::vector<V4l2FrameSize> sizes;  // discrete sizes, with their intervals
  std::optional<V4l2SizeRange> size_range;
};

struct V4l2MenuItem {
  std::int64_t index = 0;
  std::string name;  // a menu's item name, or an integer menu's value as text
};

struct V4l2ControlInfo {
  std::uint32_t id = 0;
  std::string name;   // as the config names it (v4l2-ctl's): "exposure_time_absolute"
  std::string label;  // the driver's: "Exposure Time, Absolute"
  std::string type;   // "int", "bool", "menu", "intmenu", "button", "int64", "bitmask", "string", or "compound"
  std::int64_t minimum = 0;
  std::int64_t maximum = 0;
  std::uint64_t step = 0;
  std::int64_t default_value = 0;
  std::optional<std::int64_t> value;  // the current value, where one can be read as a number
  std::vector<std::string> flags;     // "read-only", "inactive", "write-only", "volatile", "grabbed"
  std::vector<V4l2MenuItem> menu;
};

struct V4l2InputInfo {
  std::uint32_t index = 0;
  std::string name;
  std::string type;  // "camera", "tuner", "touch"
};

struct V4l2DeviceInfo {
  std::string path;                       // "/dev/video0"
  std::vector<std::string> stable_names;  // the by-id and by-path links that point at it
  // Why the device could not be described (it cannot be opened, it is no
  // V4L2 device); the fields below are then empty.
  std::string error;
  std::string driver, card, bus_info;
  bool multiplanar = false;  // a multi-planar capture device: markerd streams from single-planar ones only
  std::vector<V4l2InputInfo> inputs;
  std::optional<std::uint32_t> current_input;
  // What it is set to now: format, size and frame rate (0: unknown).
  std::string current_format;
  std::uint32_t current_width = 0;
  std::uint32_t current_height = 0;
  double current_fps = 0;
  std::vector<V4l2FormatInfo> formats;  // for the current input
  std::vector<V4l2ControlInfo> controls;
};

// Every video capture node <dev_dir>/video* (in number order; output,
// metadata and other nodes are left out). A node that cannot be opened or
// queried is listed with its error. Changes nothing on the devices.
std::vector<V4l2DeviceInfo> list_v4l2_devices(const std::filesystem::path& dev_dir = "/dev");
// One device by path; `error` says why when it is not a capture device.
V4l2DeviceInfo describe_v4l2_device(const std::filesystem::path& path, const std::filesystem::path& dev_dir = "/dev");

// For markerctl and the control socket.
[[nodiscard]] nlohmann::ordered_json to_json(const V4l2DeviceInfo& device);

// A control's name as v4l2-ctl prints it: lower case, every run of other
// characters one underscore ("Exposure Time, Absolute" is
// "exposure_time_absolute").
[[nodiscard]] std::string v4l2_control_name(std::string_view label);

}  // namespace markerd::daemon
