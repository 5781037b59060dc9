#pragma once
// What a config says of a V4L2 camera ([camera.v4l2]): the device, the pixel
// format, the size, the rate, the buffers, the input and the controls. See
// docs/capture.md.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

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

// A control's name as v4l2-ctl prints it: lower case, every run of other
// characters one underscore ("Exposure Time, Absolute" is
// "exposure_time_absolute").
[[nodiscard]] std::string v4l2_control_name(std::string_view label);

}  // namespace markerd::daemon
