#pragma once
// What V4L2 capture devices there are and what each offers (formats, sizes,
// rates, inputs, controls): `markerctl cameras` and the control socket's
// `cameras`. Listing changes nothing on the devices.

#include <cstdint>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

namespace markerd::daemon {

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

}  // namespace markerd::daemon
