#include "markerd/daemon/capture/v4l2_listing.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <map>
#include <nlohmann/json.hpp>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/capture/v4l2_settings.hpp"
#include "v4l2_device.hpp"

namespace markerd::daemon {

namespace fs = std::filesystem;
using namespace v4l2;

namespace {

// node (canonical) -> the by-id and by-path links that point at it.
std::map<std::string, std::vector<std::string>> stable_links(const fs::path& dev_dir) {
  std::map<std::string, std::vector<std::string>> links;
  for (const char* kind : {"by-id", "by-path"}) {
    std::error_code ec;
    for (fs::directory_iterator it(dev_dir / "v4l" / kind, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code link_ec;
      if (!it->is_symlink(link_ec)) continue;
      const fs::path target = fs::canonical(it->path(), link_ec);
      if (link_ec) continue;
      links[target.string()].push_back(it->path().string());
    }
  }
  for (auto& [node, names] : links) std::sort(names.begin(), names.end());
  return links;
}

V4l2DeviceInfo describe(const fs::path& path, const std::map<std::string, std::vector<std::string>>& links,
                        bool& capture) {
  capture = false;
  V4l2DeviceInfo info;
  info.path = path.string();
  std::error_code ec;
  if (const fs::path node = fs::canonical(path, ec); !ec) {
    if (const auto it = links.find(node.string()); it != links.end()) info.stable_names = it->second;
  }
  UniqueFd device(::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC));
  if (!device && errno == EACCES) device.reset(::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC));
  if (!device) {
    info.error = fmt::format("cannot open: {}", errno_text(errno));
    capture = true;  // it may be one; the error says why it is not described
    return info;
  }
  const int fd = device.get();
  v4l2_capability cap{};
  if (xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) {
    info.error = fmt::format("not a V4L2 device (VIDIOC_QUERYCAP: {})", errno_text(errno));
    capture = true;
    return info;
  }
  info.driver = c_text(cap.driver);
  info.card = c_text(cap.card);
  info.bus_info = c_text(cap.bus_info);
  const std::uint32_t caps = device_caps(cap);
  if ((caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE)) == 0) {
    info.error = "not a video capture device";
    return info;
  }
  capture = true;
  info.multiplanar = (caps & V4L2_CAP_VIDEO_CAPTURE) == 0;
  const std::uint32_t type = info.multiplanar ? V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE : V4L2_BUF_TYPE_VIDEO_CAPTURE;
  info.inputs = enum_inputs(fd);
  if (int input = 0; xioctl(fd, VIDIOC_G_INPUT, &input) == 0) info.current_input = static_cast<std::uint32_t>(input);
  v4l2_format f{};
  f.type = type;
  if (xioctl(fd, VIDIOC_G_FMT, &f) == 0) {
    if (info.multiplanar) {
      info.current_format = fourcc_text(f.fmt.pix_mp.pixelformat);
      info.current_width = f.fmt.pix_mp.width;
      info.current_height = f.fmt.pix_mp.height;
    } else {
      info.current_format = fourcc_text(f.fmt.pix.pixelformat);
      info.current_width = f.fmt.pix.width;
      info.current_height = f.fmt.pix.height;
    }
  }
  v4l2_streamparm parm{};
  parm.type = type;
  if (xioctl(fd, VIDIOC_G_PARM, &parm) == 0 && parm.parm.capture.timeperframe.numerator != 0) {
    info.current_fps =
        static_cast<double>(parm.parm.capture.timeperframe.denominator) / parm.parm.capture.timeperframe.numerator;
  }
  info.formats = enum_formats(fd, type);
  info.controls = enum_controls(fd);
  return info;
}

nlohmann::ordered_json fraction_json(const V4l2Fraction& f) {
  nlohmann::ordered_json j{{"numerator", f.numerator}, {"denominator", f.denominator}};
  if (f.numerator != 0) j["fps"] = std::round(1000.0 * f.denominator / f.numerator) / 1000.0;
  return j;
}

nlohmann::ordered_json intervals_json(const V4l2Intervals& intervals) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  if (!intervals.discrete.empty() || !intervals.min) {
    j["discrete"] = nlohmann::ordered_json::array();
    for (const auto& f : intervals.discrete) j["discrete"].push_back(fraction_json(f));
  }
  if (intervals.min) j["min"] = fraction_json(*intervals.min);
  if (intervals.max) j["max"] = fraction_json(*intervals.max);
  if (intervals.step) j["step"] = fraction_json(*intervals.step);
  return j;
}

}  // namespace

std::vector<V4l2DeviceInfo> list_v4l2_devices(const fs::path& dev_dir) {
  std::vector<std::pair<unsigned long, fs::path>> nodes;
  std::error_code ec;
  for (fs::directory_iterator it(dev_dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string file = it->path().filename().string();
    if (file.size() <= 5 || file.compare(0, 5, "video") != 0) continue;
    unsigned long number = 0;
    const auto [rest, parse_error] = std::from_chars(file.data() + 5, file.data() + file.size(), number);
    if (parse_error != std::errc{} || rest != file.data() + file.size()) continue;
    nodes.emplace_back(number, it->path());
  }
  std::sort(nodes.begin(), nodes.end());
  const auto links = stable_links(dev_dir);
  std::vector<V4l2DeviceInfo> devices;
  for (const auto& [number, path] : nodes) {
    bool capture = false;
    auto info = describe(path, links, capture);
    if (capture) devices.push_back(std::move(info));
  }
  return devices;
}

V4l2DeviceInfo describe_v4l2_device(const fs::path& path, const fs::path& dev_dir) {
  bool capture = false;
  return describe(path, stable_links(dev_dir), capture);
}

nlohmann::ordered_json to_json(const V4l2DeviceInfo& d) {
  using json = nlohmann::ordered_json;
  json j{{"backend", "v4l2"}, {"path", d.path}, {"stable_names", d.stable_names}};
  if (!d.error.empty()) {
    j["error"] = d.error;
    if (d.driver.empty()) return j;
  }
  j["driver"] = d.driver;
  j["card"] = d.card;
  j["bus_info"] = d.bus_info;
  if (!d.error.empty()) return j;
  j["multiplanar"] = d.multiplanar;
  j["inputs"] = json::array();
  for (const auto& input : d.inputs) {
    j["inputs"].push_back({{"index", input.index}, {"name", input.name}, {"type", input.type}});
  }
  j["current_input"] = d.current_input ? json(*d.current_input) : json(nullptr);
  j["current"] = {{"format", d.current_format},
                  {"width", d.current_width},
                  {"height", d.current_height},
                  {"fps", std::round(d.current_fps * 1000.0) / 1000.0}};
  j["formats"] = json::array();
  for (const auto& f : d.formats) {
    json format{{"fourcc", f.fourcc_text}, {"description", f.description}};
    if (f.compressed) format["compressed"] = true;
    if (f.emulated) format["emulated"] = true;
    format["sizes"] = json::array();
    for (const auto& size : f.sizes) {
      format["sizes"].push_back(
          {{"width", size.width}, {"height", size.height}, {"intervals", intervals_json(size.intervals)}});
    }
    if (f.size_range) {
      const auto& r = *f.size_range;
      format["size_range"] = {{"min_width", r.min_width},   {"max_width", r.max_width},
                              {"step_width", r.step_width}, {"min_height", r.min_height},
                              {"max_height", r.max_height}, {"step_height", r.step_height}};
    }
    j["formats"].push_back(std::move(format));
  }
  j["controls"] = json::array();
  for (const auto& c : d.controls) {
    json control{{"name", c.name},   {"label", c.label}, {"id", c.id},     {"type", c.type},
                 {"min", c.minimum}, {"max", c.maximum}, {"step", c.step}, {"default", c.default_value}};
    control["value"] = c.value ? json(*c.value) : json(nullptr);
    control["flags"] = c.flags;
    if (!c.menu.empty()) {
      control["menu"] = json::array();
      for (const auto& item : c.menu) control["menu"].push_back({{"index", item.index}, {"name", item.name}});
    }
    j["controls"].push_back(std::move(control));
  }
  return j;
}

}  // namespace markerd::daemon
