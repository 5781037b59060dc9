#pragma once
// The libcamera capture source (Debian's libcamera 0.0.3), for cameras that
// only libcamera drives, and the listing of libcamera's cameras behind
// `markerctl cameras`. See docs/capture.md.
//
// NV12 and R8 frames lend their Y plane to the pipeline without a copy: the
// frame points into the mapped buffer and its release hook queues the
// request again. YUYV frames are converted into the frame slot's own pixels
// in one pass and the request goes back at once. MJPEG frames are lent
// encoded and decoded into the slot's pixels by the pipeline worker that
// detects them (Frame::set_encoded; TurboJPEG, the Y component only).
//
// libcamera allows one CameraManager per process: the source and the listing
// share one, started when the first of them needs it and stopped when the
// last lets go.

#include <cstdint>
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

enum class LibcameraPixelFormat : std::uint8_t { yuyv, nv12, r8, mjpeg };
[[nodiscard]] std::string_view to_string(LibcameraPixelFormat format);  // "YUYV", "NV12", "R8", "MJPEG"

// One entry of [camera.libcamera.controls].
struct LibcameraControlSetting {
  std::string name;  // libcamera's control name: ExposureTime, AnalogueGain, AeEnable
  std::variant<bool, std::int64_t, double> value;
  std::string origin;  // "markerd.toml:14: camera.libcamera.controls.ExposureTime": names it in errors at open()
};

struct LibcameraSettings {
  std::string camera;  // an id as `cam -l` prints it; empty: the first camera libcamera lists
  LibcameraPixelFormat format = LibcameraPixelFormat::yuyv;
  int width = 0;
  int height = 0;
  double fps = 0;  // 0: the camera's own frame rate; > 0: set through FrameDurationLimits
  int buffers = 4;
  std::vector<LibcameraControlSetting> controls;
};

// [camera.libcamera]: camera, pixel_format (YUYV, NV12, R8 or GREY, MJPEG or MJPG), width,
// height, fps, buffers, and a [camera.libcamera.controls] table by libcamera
// control name. A name libcamera does not know, or a value of the wrong type,
// is a ConfigError here (file, line, key); whether the camera has the control
// and the value is in its range is checked at open().
LibcameraSettings parse_libcamera_settings(const ConfigTable& table);

std::unique_ptr<CaptureSource> make_libcamera_source(const LibcameraSettings& settings);

// ---------------------------------------------------------------- listing

// A control value as the listing shows it: none, a boolean, an integer, a
// number, or libcamera's text for anything else (arrays, rectangles, sizes).
using LibcameraValue = std::variant<std::monostate, bool, std::int64_t, double, std::string>;

struct LibcameraControlInfo {
  std::string name;
  std::string type;  // "bool", "byte", "int32", "int64", "float", "string", "rectangle", "size"
  LibcameraValue min, max, default_value;
  std::vector<LibcameraValue> values;  // the allowed values of an enumerated control; empty otherwise
};

struct LibcameraSize {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
};

struct LibcameraStreamFormat {
  std::string pixel_format;          // libcamera's name: "YUYV", "NV12", "MJPEG"
  std::vector<LibcameraSize> sizes;  // the discrete sizes
  LibcameraSize min_size, max_size;  // the range they span
};

struct LibcameraCameraInfo {
  std::string id;
  std::optional<std::string> model;      // properties::Model
  std::optional<std::string> location;   // properties::Location: "front", "back", "external"
  std::optional<std::int64_t> rotation;  // properties::Rotation, degrees
  // What a generated configuration offers (StreamRole::VideoRecording, or
  // Viewfinder where the camera has no video role).
  std::vector<LibcameraStreamFormat> formats;
  std::vector<LibcameraControlInfo> controls;  // by name
  std::string error;                           // why the formats could not be listed; empty otherwise
};

// Every camera libcamera finds, in its order. Changes nothing on the
// cameras (none is acquired). Throws CaptureError (io) when the camera
// manager cannot start.
std::vector<LibcameraCameraInfo> list_libcamera_cameras();

// For markerctl and the control socket.
[[nodiscard]] nlohmann::ordered_json to_json(const LibcameraCameraInfo& camera);

}  // namespace markerd::daemon
