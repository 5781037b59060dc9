#include "markerd/daemon/capture/libcamera_source.hpp"

// The listing of libcamera's cameras behind `markerctl cameras`.

#include <libcamera/property_ids.h>

#include <fmt/format.h>

#include <algorithm>
#include <nlohmann/json.hpp>
#include <type_traits>
#include <vector>

#include "libcamera_support.hpp"

namespace markerd::daemon {

namespace {

using libcamera::Camera;
using namespace libcam;

LibcameraCameraInfo describe(Camera& camera) {
  LibcameraCameraInfo info;
  info.id = camera.id();
  const libcamera::ControlList& properties = camera.properties();
  info.model = properties.get(libcamera::properties::Model);
  if (const auto location = properties.get(libcamera::properties::Location)) {
    switch (*location) {
      case libcamera::properties::CameraLocationFront: info.location = "front"; break;
      case libcamera::properties::CameraLocationBack: info.location = "back"; break;
      case libcamera::properties::CameraLocationExternal: info.location = "external"; break;
      default: info.location = fmt::format("{}", *location); break;
    }
  }
  if (const auto rotation = properties.get(libcamera::properties::Rotation)) info.rotation = *rotation;

  if (auto config = generate_configuration(camera)) {
    const libcamera::StreamFormats& formats = config->at(0).formats();
    for (const auto& pixel_format : formats.pixelformats()) {
      LibcameraStreamFormat format;
      format.pixel_format = pixel_format.toString();
      for (const auto& size : formats.sizes(pixel_format)) format.sizes.push_back({size.width, size.height});
      const libcamera::SizeRange range = formats.range(pixel_format);
      format.min_size = {range.min.width, range.min.height};
      format.max_size = {range.max.width, range.max.height};
      info.formats.push_back(std::move(format));
    }
  } else {
    info.error = "it generates no configuration for video or viewfinder";
  }

  for (const auto& [id, control] : camera.controls()) {
    LibcameraControlInfo entry;
    entry.name = id->name();
    entry.type = type_name(id->type());
    entry.min = value_of(control.min());
    entry.max = value_of(control.max());
    entry.default_value = value_of(control.def());
    for (const auto& value : control.values()) entry.values.push_back(value_of(value));
    info.controls.push_back(std::move(entry));
  }
  std::sort(info.controls.begin(), info.controls.end(),
            [](const LibcameraControlInfo& a, const LibcameraControlInfo& b) { return a.name < b.name; });
  return info;
}

nlohmann::ordered_json json_of(const LibcameraValue& value) {
  return std::visit(
      [](const auto& v) -> nlohmann::ordered_json {
        if constexpr (std::is_same_v<std::decay_t<decltype(v)>, std::monostate>) {
          return nullptr;
        } else {
          return v;
        }
      },
      value);
}

}  // namespace

std::vector<LibcameraCameraInfo> list_libcamera_cameras() {
  const auto manager = shared_camera_manager();
  std::vector<LibcameraCameraInfo> cameras;
  for (const auto& camera : manager->cameras()) cameras.push_back(describe(*camera));
  return cameras;
}

nlohmann::ordered_json to_json(const LibcameraCameraInfo& camera) {
  nlohmann::ordered_json json;
  json["backend"] = "libcamera";
  json["id"] = camera.id;
  json["model"] = camera.model ? nlohmann::ordered_json(*camera.model) : nlohmann::ordered_json(nullptr);
  json["location"] = camera.location ? nlohmann::ordered_json(*camera.location) : nlohmann::ordered_json(nullptr);
  json["rotation"] = camera.rotation ? nlohmann::ordered_json(*camera.rotation) : nlohmann::ordered_json(nullptr);
  if (!camera.error.empty()) json["error"] = camera.error;
  auto formats = nlohmann::ordered_json::array();
  for (const auto& format : camera.formats) {
    auto sizes = nlohmann::ordered_json::array();
    for (const auto& size : format.sizes) sizes.push_back({{"width", size.width}, {"height", size.height}});
    formats.push_back({{"pixel_format", format.pixel_format},
                       {"sizes", sizes},
                       {"min_size", {{"width", format.min_size.width}, {"height", format.min_size.height}}},
                       {"max_size", {{"width", format.max_size.width}, {"height", format.max_size.height}}}});
  }
  json["formats"] = formats;
  auto controls = nlohmann::ordered_json::array();
  for (const auto& control : camera.controls) {
    nlohmann::ordered_json entry;
    entry["name"] = control.name;
    entry["type"] = control.type;
    entry["min"] = json_of(control.min);
    entry["max"] = json_of(control.max);
    entry["default"] = json_of(control.default_value);
    if (!control.values.empty()) {
      auto values = nlohmann::ordered_json::array();
      for (const auto& value : control.values) values.push_back(json_of(value));
      entry["values"] = values;
    }
    controls.push_back(entry);
  }
  json["controls"] = controls;
  return json;
}

}  // namespace markerd::daemon
