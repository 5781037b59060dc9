#pragma once
// What the libcamera source, its listing and its settings share: the
// process's one camera manager, and the conversions between libcamera's
// types and markerd's. Internal to capture.

#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/controls.h>
#include <libcamera/stream.h>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <variant>

#include "markerd/daemon/capture/libcamera_source.hpp"

namespace markerd::daemon::libcam {

// libcamera aborts the process when a second CameraManager is made while one
// exists, so every user shares this one, started when the first needs it and
// stopped when the last lets go.
std::shared_ptr<libcamera::CameraManager> shared_camera_manager();
// The ids of the manager's cameras, for errors: "'a', 'b'" or "none".
std::string camera_ids(const libcamera::CameraManager& manager);

libcamera::PixelFormat pixel_format_of(LibcameraPixelFormat format);
std::string_view type_name(libcamera::ControlType type);
LibcameraValue value_of(const libcamera::ControlValue& value);
// A number of a control value, for range checks; nothing for other types.
std::optional<double> number_of(const libcamera::ControlValue& value);
std::string text_of(const std::variant<bool, std::int64_t, double>& value);
const libcamera::ControlId* find_control(const libcamera::ControlInfoMap& map, std::string_view name);
// The map's control names, sorted, for errors.
std::string control_names(const libcamera::ControlInfoMap& map);
// "YUYV 640x480 1280x720; MJPEG ...", for errors.
std::string offered_formats(const libcamera::StreamFormats& formats);
// The camera's configuration for one stream: video first, the viewfinder for
// a camera without a video role; nothing if it has neither.
std::unique_ptr<libcamera::CameraConfiguration> generate_configuration(libcamera::Camera& camera);

}  // namespace markerd::daemon::libcam
