#include "libcamera_support.hpp"

#include <libcamera/formats.h>

#include <fmt/format.h>

#include <algorithm>
#include <condition_variable>
#include <mutex>
#include <vector>

#include "markerd/base/errno_text.hpp"

namespace markerd::daemon::libcam {

using libcamera::Camera;
using libcamera::CameraManager;

namespace {

// libcamera aborts the process when a second CameraManager is made while one
// exists, so every user shares this one. A new one may only be made once the
// old one is gone: the deleter stops it outside the lock and then says so.
struct ManagerHolder {
  std::mutex mutex;
  std::condition_variable gone;
  std::weak_ptr<CameraManager> current;
  bool alive = false;
};

ManagerHolder& manager_holder() {
  static ManagerHolder holder;
  return holder;
}

}  // namespace

std::shared_ptr<CameraManager> shared_camera_manager() {
  ManagerHolder& holder = manager_holder();
  std::unique_lock lock(holder.mutex);
  if (auto manager = holder.current.lock()) return manager;
  holder.gone.wait(lock, [&] { return !holder.alive; });

  auto manager = std::make_unique<CameraManager>();
  if (const int ret = manager->start(); ret < 0) {
    throw CaptureError(CaptureError::Kind::io,
                       fmt::format("libcamera: cannot start the camera manager: {}", errno_text(-ret)));
  }
  std::shared_ptr<CameraManager> shared(manager.release(), [](CameraManager* m) {
    m->stop();
    delete m;
    ManagerHolder& h = manager_holder();
    const std::lock_guard guard(h.mutex);
    h.alive = false;
    h.gone.notify_all();
  });
  holder.alive = true;
  holder.current = shared;
  return shared;
}

std::string camera_ids(const CameraManager& manager) {
  std::string ids;
  for (const auto& camera : manager.cameras()) ids += fmt::format("{}'{}'", ids.empty() ? "" : ", ", camera->id());
  return ids.empty() ? "none" : ids;
}

libcamera::PixelFormat pixel_format_of(LibcameraPixelFormat format) {
  switch (format) {
    case LibcameraPixelFormat::yuyv: return libcamera::formats::YUYV;
    case LibcameraPixelFormat::nv12: return libcamera::formats::NV12;
    case LibcameraPixelFormat::r8: return libcamera::formats::R8;
    case LibcameraPixelFormat::mjpeg: return libcamera::formats::MJPEG;
  }
  return {};
}

std::string_view type_name(libcamera::ControlType type) {
  switch (type) {
    case libcamera::ControlTypeNone: return "none";
    case libcamera::ControlTypeBool: return "bool";
    case libcamera::ControlTypeByte: return "byte";
    case libcamera::ControlTypeInteger32: return "int32";
    case libcamera::ControlTypeInteger64: return "int64";
    case libcamera::ControlTypeFloat: return "float";
    case libcamera::ControlTypeString: return "string";
    case libcamera::ControlTypeRectangle: return "rectangle";
    case libcamera::ControlTypeSize: return "size";
  }
  return "unknown";
}

LibcameraValue value_of(const libcamera::ControlValue& value) {
  if (value.isNone()) return std::monostate{};
  if (value.isArray()) return value.toString();
  switch (value.type()) {
    case libcamera::ControlTypeBool: return value.get<bool>();
    case libcamera::ControlTypeByte: return static_cast<std::int64_t>(value.get<std::uint8_t>());
    case libcamera::ControlTypeInteger32: return static_cast<std::int64_t>(value.get<std::int32_t>());
    case libcamera::ControlTypeInteger64: return value.get<std::int64_t>();
    case libcamera::ControlTypeFloat: return static_cast<double>(value.get<float>());
    default: return value.toString();
  }
}

// A number of a control value, for range checks; nothing for other types.
std::optional<double> number_of(const libcamera::ControlValue& value) {
  if (value.isNone() || value.isArray()) return std::nullopt;
  switch (value.type()) {
    case libcamera::ControlTypeBool: return value.get<bool>() ? 1.0 : 0.0;
    case libcamera::ControlTypeByte: return value.get<std::uint8_t>();
    case libcamera::ControlTypeInteger32: return value.get<std::int32_t>();
    case libcamera::ControlTypeInteger64: return static_cast<double>(value.get<std::int64_t>());
    case libcamera::ControlTypeFloat: return value.get<float>();
    default: return std::nullopt;
  }
}

std::string text_of(const std::variant<bool, std::int64_t, double>& value) {
  return std::visit([](auto v) { return fmt::format("{}", v); }, value);
}

const libcamera::ControlId* find_control(const libcamera::ControlInfoMap& map, std::string_view name) {
  for (const auto& [id, info] : map) {
    if (id->name() == name) return id;
  }
  return nullptr;
}

std::string control_names(const libcamera::ControlInfoMap& map) {
  std::vector<std::string> names;
  for (const auto& [id, info] : map) names.push_back(id->name());
  std::sort(names.begin(), names.end());
  std::string list;
  for (const auto& name : names) list += fmt::format("{}{}", list.empty() ? "" : ", ", name);
  return list.empty() ? "none" : list;
}

std::string offered_formats(const libcamera::StreamFormats& formats) {
  std::string text;
  for (const auto& pixel_format : formats.pixelformats()) {
    std::string sizes;
    for (const auto& size : formats.sizes(pixel_format)) {
      sizes += fmt::format("{}{}x{}", sizes.empty() ? "" : " ", size.width, size.height);
    }
    text += fmt::format("{}{} {}", text.empty() ? "" : "; ", pixel_format.toString(), sizes);
  }
  return text.empty() ? "nothing" : text;
}

// The camera's configuration for one stream: video first, the viewfinder for
// a camera without a video role.
std::unique_ptr<libcamera::CameraConfiguration> generate_configuration(Camera& camera) {
  for (const auto role : {libcamera::StreamRole::VideoRecording, libcamera::StreamRole::Viewfinder}) {
    auto config = camera.generateConfiguration({role});
    if (config && !config->empty()) return config;
  }
  return nullptr;
}

}  // namespace markerd::daemon::libcam
