#include "markerd/daemon/capture/libcamera_source.hpp"

// [camera.libcamera] of the daemon's config.

#include <libcamera/control_ids.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "libcamera_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/libcamera_source.hpp"

namespace markerd::daemon {

using libcam::type_name;

std::string_view to_string(LibcameraPixelFormat format) {
  switch (format) {
    case LibcameraPixelFormat::yuyv: return "YUYV";
    case LibcameraPixelFormat::nv12: return "NV12";
    case LibcameraPixelFormat::r8: return "R8";
    case LibcameraPixelFormat::mjpeg: return "MJPEG";
  }
  return "unknown";
}

LibcameraSettings parse_libcamera_settings(const ConfigTable& table) {
  table.allow_only({"camera", "pixel_format", "width", "height", "fps", "buffers", "controls"});
  LibcameraSettings settings;
  settings.camera = table.optional<std::string>("camera", "");

  const auto format = table.optional<std::string>("pixel_format", "YUYV");
  if (format == "YUYV") {
    settings.format = LibcameraPixelFormat::yuyv;
  } else if (format == "NV12") {
    settings.format = LibcameraPixelFormat::nv12;
  } else if (format == "R8" || format == "GREY") {
    settings.format = LibcameraPixelFormat::r8;
  } else if (format == "MJPEG" || format == "MJPG") {
    settings.format = LibcameraPixelFormat::mjpeg;
  } else {
    table.fail("pixel_format",
               fmt::format("unknown pixel format '{}' (known: YUYV, NV12, R8, GREY, MJPEG, MJPG)", format));
  }

  constexpr int kMaxSide = 16384;
  settings.width = table.required<int>("width");
  settings.height = table.required<int>("height");
  if (settings.width <= 0 || settings.width > kMaxSide) {
    table.fail("width", fmt::format("must be > 0 and at most {}, got {}", kMaxSide, settings.width));
  }
  if (settings.height <= 0 || settings.height > kMaxSide) {
    table.fail("height", fmt::format("must be > 0 and at most {}, got {}", kMaxSide, settings.height));
  }
  if (settings.format == LibcameraPixelFormat::yuyv && settings.width % 2 != 0) {
    table.fail("width", fmt::format("must be even for YUYV (two pixels share their colour), got {}", settings.width));
  }
  settings.fps = table.optional<double>("fps", 0.0);
  // The frame duration (1e6 / fps microseconds) must be a whole, non-zero count.
  if (!std::isfinite(settings.fps) || settings.fps < 0 || settings.fps > 1000) {
    table.fail("fps",
               fmt::format("must be >= 0 (0: the camera's own frame rate) and at most 1000, got {}", settings.fps));
  }
  settings.buffers = table.optional<int>("buffers", 4);
  if (settings.buffers < 1 || settings.buffers > 32) {
    table.fail("buffers", fmt::format("must be between 1 and 32, got {}", settings.buffers));
  }

  if (const auto controls = table.maybe_table("controls")) {
    for (const auto& [key, node] : controls->raw()) {
      const std::string name(key.str());
      const libcamera::ControlId* id = nullptr;
      for (const auto& [number, control] : libcamera::controls::controls) {
        if (control->name() == name) id = control;
      }
      if (id == nullptr) {
        std::vector<std::string> names;
        for (const auto& [number, control] : libcamera::controls::controls) names.push_back(control->name());
        std::sort(names.begin(), names.end());
        std::string known;
        for (const auto& n : names) known += fmt::format("{}{}", known.empty() ? "" : ", ", n);
        controls->fail(name, fmt::format("libcamera has no control '{}' (its controls: {})", name, known));
      }
      if (id->id() == libcamera::controls::FrameDurationLimits.id()) {
        controls->fail(name, "set the frame rate with [camera.libcamera] fps");
      }

      // Array controls (ColourGains, a Span of floats) have their element's
      // type but take a list: not from the config.
      if (id->name() == "ColourGains" || id->name() == "ColourCorrectionMatrix" || id->name() == "SensorBlackLevels") {
        controls->fail(name, "an array control cannot be set from the config");
      }

      LibcameraControlSetting setting;
      setting.name = name;
      const auto line = node.source().begin.line;
      setting.origin = line > 0 ? fmt::format("{}:{}: {}.{}", table.source(), line, controls->key_path(), name)
                                : fmt::format("{}: {}.{}", table.source(), controls->key_path(), name);
      switch (id->type()) {
        case libcamera::ControlTypeBool: setting.value = controls->required<bool>(name); break;
        case libcamera::ControlTypeInteger32: {
          const auto value = controls->required<std::int64_t>(name);
          if (value < std::numeric_limits<std::int32_t>::min() || value > std::numeric_limits<std::int32_t>::max()) {
            controls->fail(name, fmt::format("must be a 32-bit integer, got {}", value));
          }
          setting.value = value;
          break;
        }
        case libcamera::ControlTypeInteger64: setting.value = controls->required<std::int64_t>(name); break;
        case libcamera::ControlTypeFloat: setting.value = controls->required<double>(name); break;
        default: controls->fail(name, fmt::format("a {} control cannot be set from the config", type_name(id->type())));
      }
      settings.controls.push_back(std::move(setting));
    }
  }
  return settings;
}

}  // namespace markerd::daemon
