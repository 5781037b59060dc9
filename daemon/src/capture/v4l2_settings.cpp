#include "markerd/daemon/capture/v4l2_settings.hpp"

#include <linux/videodev2.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>

#include "markerd/base/config_table.hpp"

namespace markerd::daemon {

std::string_view to_string(V4l2PixelFormat format) {
  switch (format) {
    case V4l2PixelFormat::grey: return "GREY";
    case V4l2PixelFormat::yuyv: return "YUYV";
    case V4l2PixelFormat::nv12: return "NV12";
    case V4l2PixelFormat::mjpg: return "MJPG";
  }
  return "?";
}

std::uint32_t fourcc_of(V4l2PixelFormat format) {
  switch (format) {
    case V4l2PixelFormat::grey: return V4L2_PIX_FMT_GREY;
    case V4l2PixelFormat::yuyv: return V4L2_PIX_FMT_YUYV;
    case V4l2PixelFormat::nv12: return V4L2_PIX_FMT_NV12;
    case V4l2PixelFormat::mjpg: return V4L2_PIX_FMT_MJPEG;
  }
  return 0;
}

std::string fourcc_text(std::uint32_t fourcc) {
  std::string text;
  for (int i = 0; i < 4; ++i) {
    const auto c = static_cast<char>((fourcc >> (8 * i)) & 0x7f);
    text += std::isprint(static_cast<unsigned char>(c)) != 0 ? c : '.';
  }
  while (!text.empty() && text.back() == ' ') text.pop_back();
  if ((fourcc & (1U << 31)) != 0) text += "-BE";
  return text;
}

std::string v4l2_control_name(std::string_view label) {
  std::string name;
  bool separate = false;
  for (const char c : label) {
    if (std::isalnum(static_cast<unsigned char>(c)) != 0) {
      if (separate) name += '_';
      separate = false;
      name += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    } else if (!name.empty()) {
      separate = true;
    }
  }
  return name;
}

V4l2Settings parse_v4l2_settings(const ConfigTable& table) {
  table.allow_only({"device", "format", "width", "height", "fps", "buffers", "input", "controls"});
  V4l2Settings s;
  s.device = table.required<std::string>("device");
  if (s.device.empty()) {
    table.fail("device", "must not be empty (a path such as /dev/video0, or a /dev/v4l/by-id name)");
  }

  const auto format = table.optional<std::string>("format", "YUYV");
  const std::string upper = [&] {
    std::string u = format;
    std::transform(u.begin(), u.end(), u.begin(), [](unsigned char c) { return std::toupper(c); });
    return u;
  }();
  if (upper == "GREY") {
    s.format = V4l2PixelFormat::grey;
  } else if (upper == "YUYV") {
    s.format = V4l2PixelFormat::yuyv;
  } else if (upper == "NV12") {
    s.format = V4l2PixelFormat::nv12;
  } else if (upper == "MJPG" || upper == "MJPEG") {
    s.format = V4l2PixelFormat::mjpg;
  } else {
    table.fail("format", fmt::format("unknown format '{}' (use GREY, YUYV, NV12 or MJPG)", format));
  }

  constexpr int kMaxSide = 16384;
  s.width = table.required<int>("width");
  if (s.width <= 0 || s.width > kMaxSide) {
    table.fail("width", fmt::format("must be 1 to {}, got {}", kMaxSide, s.width));
  }
  if (s.format == V4l2PixelFormat::yuyv && s.width % 2 != 0) {
    table.fail("width", fmt::format("must be even for YUYV (two pixels share their chroma), got {}", s.width));
  }
  s.height = table.required<int>("height");
  if (s.height <= 0 || s.height > kMaxSide) {
    table.fail("height", fmt::format("must be 1 to {}, got {}", kMaxSide, s.height));
  }
  s.fps = table.optional<double>("fps", 0.0);
  if (table.contains("fps") && !(s.fps > 0 && s.fps <= 1000)) {
    table.fail("fps", fmt::format("must be > 0 and at most 1000 frames per second, got {}", s.fps));
  }
  s.buffers = table.optional<int>("buffers", 4);
  if (s.buffers < 2 || s.buffers > 32) {
    table.fail("buffers", fmt::format("must be 2 to 32, got {} (one is always with the driver)", s.buffers));
  }
  if (const auto input = table.maybe<std::int64_t>("input")) {
    // VIDIOC_S_INPUT takes any index; a driver has a handful of inputs.
    if (*input < 0 || *input > 255) {
      table.fail("input", fmt::format("must be an input's index, 0 to 255, got {}", *input));
    }
    s.input = static_cast<int>(*input);
  }

  if (const auto controls = table.maybe_table("controls")) {
    for (const auto& [key, node] : controls->raw()) {
      const std::string name(key.str());
      if (name.empty() || v4l2_control_name(name) != name) {
        controls->fail(name, fmt::format("write control names as v4l2-ctl prints them: '{}'", v4l2_control_name(name)));
      }
      V4l2ControlSetting setting;
      setting.name = name;
      if (const auto i = node.value_exact<std::int64_t>()) {
        setting.value = *i;
      } else if (const auto b = node.value_exact<bool>()) {
        setting.value = *b;
      } else if (const auto text = node.value_exact<std::string>()) {
        setting.value = *text;
      } else {
        controls->fail(name, "must be an integer, a boolean, or the name of a menu item");
      }
      const auto line = node.source().begin.line;
      setting.origin = line > 0 ? fmt::format("{}:{}: {}.{}", controls->source(), line, controls->key_path(), name)
                                : fmt::format("{}: {}.{}", controls->source(), controls->key_path(), name);
      s.controls.push_back(std::move(setting));
    }
  }
  return s;
}

}  // namespace markerd::daemon
