// markerctl cameras: the cameras of this machine with what markerd's config
// can name. Through V4L2 ([camera.v4l2]): the capture devices' stable names,
// inputs, formats, frame sizes and rates, and controls with their ranges,
// menus and current values. Through libcamera ([camera.libcamera]): the
// cameras' ids, properties, stream formats and sizes, and controls. Reads
// the devices directly (no daemon needed) and changes nothing on them.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <type_traits>
#include <variant>
#include <vector>

#include "common.hpp"
#include "markerd/daemon/capture/libcamera_source.hpp"
#include "markerd/daemon/capture/v4l2_listing.hpp"
#include "markerd/daemon/capture/v4l2_source.hpp"

namespace markerctl {
namespace {

using markerd::daemon::LibcameraCameraInfo;
using markerd::daemon::LibcameraValue;
using markerd::daemon::V4l2ControlInfo;
using markerd::daemon::V4l2DeviceInfo;
using markerd::daemon::V4l2Fraction;
using markerd::daemon::V4l2Intervals;

struct CamerasOptions {
  std::vector<std::string> devices;
  std::string backend = "all";
  bool json = false;
};

std::string fps_text(const V4l2Fraction& interval) {
  if (interval.numerator == 0) return "?";
  return fmt::format("{:.4g}", static_cast<double>(interval.denominator) / interval.numerator);
}

std::string intervals_text(const V4l2Intervals& intervals) {
  std::string text;
  for (const auto& f : intervals.discrete) text += (text.empty() ? "" : ", ") + fps_text(f);
  // A range of intervals is a range of rates the other way round.
  if (intervals.min && intervals.max) {
    text = fmt::format("{} to {}", fps_text(*intervals.max), fps_text(*intervals.min));
  }
  return text.empty() ? std::string("rate not listed") : text + " fps";
}

std::string control_text(const V4l2ControlInfo& c) {
  std::string text;
  const auto item_name = [&](std::int64_t index) -> std::string {
    for (const auto& item : c.menu) {
      if (item.index == index) return item.name;
    }
    return "?";
  };
  if (c.type == "int" || c.type == "int64") {
    text = fmt::format("{} to {}, step {}, default {}", c.minimum, c.maximum, c.step, c.default_value);
  } else if (c.type == "bool" || c.type == "bitmask") {
    text = fmt::format("default {}", c.default_value);
  } else if (c.type == "menu" || c.type == "intmenu") {
    text = fmt::format("default {} ({})", c.default_value, item_name(c.default_value));
  }
  if (c.value) {
    text += fmt::format("{}now {}", text.empty() ? "" : "; ", *c.value);
    if (!c.menu.empty()) text += fmt::format(" ({})", item_name(*c.value));
  }
  if (!c.flags.empty()) {
    std::string flags;
    for (const auto& f : c.flags) flags += (flags.empty() ? "" : ", ") + f;
    text += fmt::format("{}[{}]", text.empty() ? "" : " ", flags);
  }
  return text;
}

void print_device(const V4l2DeviceInfo& d) {
  std::cout << d.path;
  if (!d.card.empty()) std::cout << fmt::format("  {} (driver {}, {})", d.card, d.driver, d.bus_info);
  std::cout << '\n';
  for (const auto& name : d.stable_names) std::cout << "  name      " << name << '\n';
  if (!d.error.empty()) {
    std::cout << "  error     " << d.error << "\n\n";
    return;
  }
  if (d.multiplanar) std::cout << "  note      multi-planar: markerd streams from single-planar devices only\n";
  if (!d.inputs.empty()) {
    std::string inputs;
    for (const auto& input : d.inputs) {
      inputs += fmt::format("{}{} \"{}\" ({}{})", inputs.empty() ? "" : ", ", input.index, input.name, input.type,
                            d.current_input == input.index ? ", current" : "");
    }
    std::cout << "  inputs    " << inputs << '\n';
  }
  if (!d.current_format.empty()) {
    std::cout << fmt::format("  now       {} {}x{}", d.current_format, d.current_width, d.current_height);
    if (d.current_fps > 0) std::cout << fmt::format(", {:.4g} fps", d.current_fps);
    std::cout << '\n';
  }
  std::cout << "  formats\n";
  for (const auto& f : d.formats) {
    std::cout << fmt::format("    {:<8}{}{}\n", f.fourcc_text, f.description, f.emulated ? " (emulated)" : "");
    for (const auto& size : f.sizes) {
      std::cout << fmt::format("            {:>11}  {}\n", fmt::format("{}x{}", size.width, size.height),
                               intervals_text(size.intervals));
    }
    if (f.size_range) {
      const auto& r = *f.size_range;
      std::cout << fmt::format("            {}x{} to {}x{} in steps of {}x{}\n", r.min_width, r.min_height, r.max_width,
                               r.max_height, r.step_width, r.step_height);
    }
  }
  if (!d.controls.empty()) std::cout << "  controls\n";
  for (const auto& c : d.controls) {
    std::cout << fmt::format("    {:<34} {:<8} {}\n", c.name, c.type, control_text(c));
    if (!c.menu.empty()) {
      std::string items;
      for (const auto& item : c.menu) {
        items += fmt::format("{}{}: {}", items.empty() ? "" : ", ", item.index, item.name);
      }
      std::cout << fmt::format("    {:<34} {:<8} {}\n", "", "", items);
    }
  }
  std::cout << '\n';
}

std::string value_text(const LibcameraValue& value) {
  return std::visit(
      [](const auto& v) -> std::string {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, std::monostate>) {
          return "";
        } else if constexpr (std::is_same_v<T, bool>) {
          return v ? "true" : "false";
        } else if constexpr (std::is_same_v<T, double>) {
          return fmt::format("{:.4g}", v);
        } else {
          return fmt::format("{}", v);
        }
      },
      value);
}

void print_camera(const LibcameraCameraInfo& c) {
  std::cout << "libcamera " << c.id << '\n';
  if (c.model) std::cout << "  model     " << *c.model << '\n';
  if (c.location) std::cout << "  location  " << *c.location << '\n';
  if (c.rotation) std::cout << "  rotation  " << *c.rotation << " deg\n";
  if (!c.error.empty()) {
    std::cout << "  error     " << c.error << "\n\n";
    return;
  }
  std::cout << "  formats\n";
  for (const auto& f : c.formats) {
    std::string sizes;
    for (const auto& size : f.sizes)
      sizes += fmt::format("{}{}x{}", sizes.empty() ? "" : ", ", size.width, size.height);
    if (sizes.empty()) {
      sizes = fmt::format("{}x{} to {}x{}", f.min_size.width, f.min_size.height, f.max_size.width, f.max_size.height);
    }
    std::cout << fmt::format("    {:<8}{}\n", f.pixel_format, sizes);
  }
  if (!c.controls.empty()) std::cout << "  controls\n";
  for (const auto& control : c.controls) {
    std::string text;
    const std::string min = value_text(control.min), max = value_text(control.max);
    if (!min.empty() || !max.empty()) text = fmt::format("{} to {}", min, max);
    if (const std::string d = value_text(control.default_value); !d.empty()) {
      text += fmt::format("{}default {}", text.empty() ? "" : ", ", d);
    }
    if (!control.values.empty()) {
      std::string values;
      for (const auto& v : control.values) values += (values.empty() ? "" : ", ") + value_text(v);
      text += fmt::format("{}values {}", text.empty() ? "" : "; ", values);
    }
    std::cout << fmt::format("    {:<34} {:<8} {}\n", control.name, control.type, text);
  }
  std::cout << '\n';
}

std::vector<V4l2DeviceInfo> v4l2_devices(const CamerasOptions& o) {
  std::vector<V4l2DeviceInfo> devices;
  if (o.devices.empty()) {
    devices = markerd::daemon::list_v4l2_devices();
  } else {
    for (const auto& name : o.devices) {
      std::filesystem::path path;
      try {
        path = markerd::daemon::resolve_v4l2_device(name);
      } catch (const markerd::daemon::CaptureError& e) {
        throw runtime_error("cameras", e.what());  // names the device and where it was looked for
      }
      auto info = markerd::daemon::describe_v4l2_device(path);
      // Asked for by name, a device that cannot be described is a failure.
      if (!info.error.empty()) throw runtime_error("cameras", fmt::format("{}: {}", path.string(), info.error));
      devices.push_back(std::move(info));
    }
  }
  return devices;
}

std::vector<LibcameraCameraInfo> libcamera_cameras(const CamerasOptions& o) {
  // libcamera logs every pipeline handler it tries at INFO: not a listing's business.
  ::setenv("LIBCAMERA_LOG_LEVELS", "*:ERROR", 0);  // NOLINT(concurrency-mt-unsafe): before libcamera starts
  std::vector<LibcameraCameraInfo> cameras;
  try {
    cameras = markerd::daemon::list_libcamera_cameras();
  } catch (const markerd::daemon::CaptureError& e) {
    throw runtime_error("cameras", fmt::format("libcamera: {}", e.what()));
  }
  if (o.devices.empty()) return cameras;
  std::vector<LibcameraCameraInfo> named;
  for (const auto& id : o.devices) {
    const auto it = std::find_if(cameras.begin(), cameras.end(), [&](const auto& c) { return c.id == id; });
    if (it == cameras.end()) {
      std::string known;
      for (const auto& c : cameras) known += (known.empty() ? "" : ", ") + c.id;
      throw runtime_error("cameras",
                          fmt::format("libcamera has no camera '{}' (it has: {})", id, known.empty() ? "none" : known));
    }
    named.push_back(*it);
  }
  return named;
}

int run_cameras(const CamerasOptions& o) {
  const bool v4l2 = o.backend != "libcamera";
  // DEVICEs name V4L2 devices unless the listing is libcamera's alone.
  const bool libcamera = o.backend != "v4l2" && (o.devices.empty() || !v4l2);
  const auto devices = v4l2 ? v4l2_devices(o) : std::vector<V4l2DeviceInfo>{};
  const auto cameras = libcamera ? libcamera_cameras(o) : std::vector<LibcameraCameraInfo>{};
  if (o.json) {
    for (const auto& d : devices) std::cout << json_line(markerd::daemon::to_json(d)) << '\n';
    for (const auto& c : cameras) std::cout << json_line(markerd::daemon::to_json(c)) << '\n';
    return 0;
  }
  if (v4l2 && devices.empty()) std::cout << "no V4L2 capture devices (no /dev/video* node that captures video)\n";
  for (const auto& d : devices) print_device(d);
  if (libcamera && cameras.empty()) std::cout << "no libcamera cameras\n";
  for (const auto& c : cameras) print_camera(c);
  return 0;
}

}  // namespace

void add_cameras_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<CamerasOptions>();
  CLI::App* app = parent.add_subcommand(
      "cameras", "List the cameras, through V4L2 and libcamera: formats, sizes, frame rates, controls");
  app->footer(
      "Through V4L2: every video capture node (/dev/video*), or the DEVICEs given, with its stable names\n"
      "(/dev/v4l/by-id and by-path links, which survive replugging), inputs, current format, formats with\n"
      "their frame sizes and rates, and controls with type, range, default, current value and menu items.\n"
      "Control names are as markerd's [camera.v4l2.controls] takes them (and as v4l2-ctl prints them).\n"
      "A DEVICE is a path, a by-id or by-path link, or such a link's bare name.\n"
      "Through libcamera: every camera libcamera finds (or, with --backend libcamera, the camera ids\n"
      "given), with the id [camera.libcamera] names it by, its model and location, the stream formats\n"
      "and sizes a video configuration offers, and its controls (frame rates: FrameDurationLimits) as\n"
      "[camera.libcamera.controls] takes them. Given DEVICEs, the listing is V4L2's only.\n"
      "--json prints one JSON object per device or camera, a line each, its \"backend\" saying which.\n"
      "Needs read access to the devices (the group 'video'); changes nothing on them.");
  app->add_option("device", o->devices, "Only these devices, or camera ids with --backend libcamera")
      ->type_name("DEVICE");
  app->add_option("--backend", o->backend, "v4l2, libcamera or all")
      ->check(CLI::IsMember({"v4l2", "libcamera", "all"}))
      ->capture_default_str();
  app->add_flag("--json", o->json, "One JSON object per device, a line each");
  commands.push_back({app, [o] { return run_cameras(*o); }});
}

}  // namespace markerctl
