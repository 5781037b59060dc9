#include "v4l2_device.hpp"

#include "markerd/daemon/capture/v4l2_settings.hpp"

#include <sys/ioctl.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>

namespace markerd::daemon::v4l2 {

int xioctl(int fd, unsigned long request, void* arg) noexcept {
  int result = 0;
  do {
    result = ::ioctl(fd, request, arg);
  } while (result == -1 && errno == EINTR);
  return result;
}

std::uint32_t device_caps(const v4l2_capability& cap) {
  return (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
}

namespace {

V4l2Intervals enum_intervals(int fd, std::uint32_t fourcc, std::uint32_t width, std::uint32_t height) {
  V4l2Intervals intervals;
  for (std::uint32_t i = 0; i < 256; ++i) {
    v4l2_frmivalenum e{};
    e.index = i;
    e.pixel_format = fourcc;
    e.width = width;
    e.height = height;
    if (xioctl(fd, VIDIOC_ENUM_FRAMEINTERVALS, &e) != 0) break;
    if (e.type == V4L2_FRMIVAL_TYPE_DISCRETE) {
      intervals.discrete.push_back({e.discrete.numerator, e.discrete.denominator});
    } else {
      intervals.min = V4l2Fraction{e.stepwise.min.numerator, e.stepwise.min.denominator};
      intervals.max = V4l2Fraction{e.stepwise.max.numerator, e.stepwise.max.denominator};
      intervals.step = V4l2Fraction{e.stepwise.step.numerator, e.stepwise.step.denominator};
      break;
    }
  }
  return intervals;
}

}  // namespace

std::vector<V4l2FormatInfo> enum_formats(int fd, std::uint32_t buffer_type) {
  std::vector<V4l2FormatInfo> formats;
  for (std::uint32_t i = 0; i < 256; ++i) {
    v4l2_fmtdesc desc{};
    desc.index = i;
    desc.type = buffer_type;
    if (xioctl(fd, VIDIOC_ENUM_FMT, &desc) != 0) break;
    V4l2FormatInfo format;
    format.fourcc = desc.pixelformat;
    format.fourcc_text = fourcc_text(desc.pixelformat);
    format.description = c_text(desc.description);
    format.compressed = (desc.flags & V4L2_FMT_FLAG_COMPRESSED) != 0;
    format.emulated = (desc.flags & V4L2_FMT_FLAG_EMULATED) != 0;
    for (std::uint32_t j = 0; j < 256; ++j) {
      v4l2_frmsizeenum size{};
      size.index = j;
      size.pixel_format = desc.pixelformat;
      if (xioctl(fd, VIDIOC_ENUM_FRAMESIZES, &size) != 0) break;
      if (size.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
        format.sizes.push_back({size.discrete.width, size.discrete.height,
                                enum_intervals(fd, desc.pixelformat, size.discrete.width, size.discrete.height)});
      } else {
        const auto& s = size.stepwise;
        format.size_range =
            V4l2SizeRange{s.min_width, s.max_width, s.step_width, s.min_height, s.max_height, s.step_height};
        break;
      }
    }
    formats.push_back(std::move(format));
  }
  return formats;
}

std::vector<V4l2InputInfo> enum_inputs(int fd) {
  std::vector<V4l2InputInfo> inputs;
  for (std::uint32_t i = 0; i < 64; ++i) {
    v4l2_input input{};
    input.index = i;
    if (xioctl(fd, VIDIOC_ENUMINPUT, &input) != 0) break;
    const char* type = input.type == V4L2_INPUT_TYPE_TUNER   ? "tuner"
                       : input.type == V4L2_INPUT_TYPE_TOUCH ? "touch"
                                                             : "camera";
    inputs.push_back({input.index, c_text(input.name), type});
  }
  return inputs;
}

namespace {

const char* control_type_name(std::uint32_t type) {
  switch (type) {
    case V4L2_CTRL_TYPE_INTEGER: return "int";
    case V4L2_CTRL_TYPE_BOOLEAN: return "bool";
    case V4L2_CTRL_TYPE_MENU: return "menu";
    case V4L2_CTRL_TYPE_INTEGER_MENU: return "intmenu";
    case V4L2_CTRL_TYPE_BUTTON: return "button";
    case V4L2_CTRL_TYPE_INTEGER64: return "int64";
    case V4L2_CTRL_TYPE_BITMASK: return "bitmask";
    case V4L2_CTRL_TYPE_STRING: return "string";
    default: return "compound";
  }
}

bool has_numeric_value(std::uint32_t type) {
  switch (type) {
    case V4L2_CTRL_TYPE_INTEGER:
    case V4L2_CTRL_TYPE_BOOLEAN:
    case V4L2_CTRL_TYPE_MENU:
    case V4L2_CTRL_TYPE_INTEGER_MENU:
    case V4L2_CTRL_TYPE_INTEGER64:
    case V4L2_CTRL_TYPE_BITMASK: return true;
    default: return false;
  }
}

std::vector<std::string> control_flag_names(std::uint32_t flags) {
  std::vector<std::string> names;
  const std::pair<std::uint32_t, const char*> known[] = {{V4L2_CTRL_FLAG_READ_ONLY, "read-only"},
                                                         {V4L2_CTRL_FLAG_INACTIVE, "inactive"},
                                                         {V4L2_CTRL_FLAG_WRITE_ONLY, "write-only"},
                                                         {V4L2_CTRL_FLAG_VOLATILE, "volatile"},
                                                         {V4L2_CTRL_FLAG_GRABBED, "grabbed"}};
  for (const auto& [flag, name] : known) {
    if ((flags & flag) != 0) names.emplace_back(name);
  }
  return names;
}

// One control's description; false when the driver knows no control past `id`.
bool query_control(int fd, std::uint32_t id, bool extended, v4l2_query_ext_ctrl& out) {
  out = {};
  out.id = id;
  if (extended) return xioctl(fd, VIDIOC_QUERY_EXT_CTRL, &out) == 0;
  // Drivers without the control framework know only the old query.
  v4l2_queryctrl old{};
  old.id = id;
  if (xioctl(fd, VIDIOC_QUERYCTRL, &old) != 0) return false;
  out.id = old.id;
  out.type = old.type;
  std::memcpy(out.name, old.name, std::min(sizeof out.name, sizeof old.name));
  out.minimum = old.minimum;
  out.maximum = old.maximum;
  out.step = static_cast<std::uint64_t>(old.step);
  out.default_value = old.default_value;
  out.flags = old.flags;
  return true;
}

std::optional<std::int64_t> read_control(int fd, std::uint32_t id, std::uint32_t type) {
  v4l2_ext_control control{};
  control.id = id;
  v4l2_ext_controls controls{};
  controls.which = V4L2_CTRL_WHICH_CUR_VAL;
  controls.count = 1;
  controls.controls = &control;
  if (xioctl(fd, VIDIOC_G_EXT_CTRLS, &controls) == 0) {
    // Copies: the fields are packed, and optional's constructor takes a reference.
    if (type == V4L2_CTRL_TYPE_INTEGER64) return std::int64_t{control.value64};
    // A bitmask is 32 bits unsigned in the same field.
    if (type == V4L2_CTRL_TYPE_BITMASK) return std::int64_t{static_cast<std::uint32_t>(control.value)};
    return std::int64_t{control.value};
  }
  if (errno != ENOTTY || type == V4L2_CTRL_TYPE_INTEGER64) return std::nullopt;
  v4l2_control old{id, 0};
  if (xioctl(fd, VIDIOC_G_CTRL, &old) != 0) return std::nullopt;
  if (type == V4L2_CTRL_TYPE_BITMASK) return std::int64_t{static_cast<std::uint32_t>(old.value)};
  return std::int64_t{old.value};
}

}  // namespace

std::vector<V4l2ControlInfo> enum_controls(int fd) {
  std::vector<V4l2ControlInfo> controls;
  constexpr std::uint32_t next = V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND;
  v4l2_query_ext_ctrl probe{};
  probe.id = next;
  bool extended = xioctl(fd, VIDIOC_QUERY_EXT_CTRL, &probe) == 0 || errno != ENOTTY;
  std::uint32_t id = extended ? next : V4L2_CTRL_FLAG_NEXT_CTRL;
  v4l2_query_ext_ctrl q{};
  for (int guard = 0; guard < 4096 && query_control(fd, id, extended, q); ++guard) {
    id = q.id | (extended ? next : V4L2_CTRL_FLAG_NEXT_CTRL);
    if (q.type == V4L2_CTRL_TYPE_CTRL_CLASS || (q.flags & V4L2_CTRL_FLAG_DISABLED) != 0) continue;
    V4l2ControlInfo c;
    c.id = q.id;
    c.label = c_text(q.name);
    c.name = v4l2_control_name(c.label);
    c.type = control_type_name(q.type);
    c.minimum = q.minimum;
    c.maximum = q.maximum;
    c.step = q.step;
    c.default_value = q.default_value;
    c.flags = control_flag_names(q.flags);
    if (has_numeric_value(q.type) && (q.flags & V4L2_CTRL_FLAG_WRITE_ONLY) == 0 && q.nr_of_dims == 0) {
      c.value = read_control(fd, q.id, q.type);
    }
    if (q.type == V4L2_CTRL_TYPE_MENU || q.type == V4L2_CTRL_TYPE_INTEGER_MENU) {
      for (std::int64_t i = std::max<std::int64_t>(q.minimum, 0); i <= q.maximum && i < 1024; ++i) {
        v4l2_querymenu item{};
        item.id = q.id;
        item.index = static_cast<std::uint32_t>(i);
        if (xioctl(fd, VIDIOC_QUERYMENU, &item) != 0) continue;  // a gap in the menu
        c.menu.push_back({i, q.type == V4L2_CTRL_TYPE_MENU ? c_text(item.name) : std::to_string(item.value)});
      }
    }
    controls.push_back(std::move(c));
  }
  return controls;
}

CameraControlInfo camera_control(const V4l2ControlInfo& c) {
  CameraControlInfo info;
  info.name = c.name;
  info.id = c.id;
  info.type = c.type;
  info.flags = c.flags;
  if (c.value) info.value = *c.value;
  if (c.type == "int" || c.type == "int64") {
    info.kind = ControlKind::integer;
    info.step = c.step;
  } else if (c.type == "bool") {
    info.kind = ControlKind::boolean;
  } else if (c.type == "menu" || c.type == "intmenu") {
    info.kind = ControlKind::menu;
    for (const auto& item : c.menu) info.menu.push_back({item.index, item.name});
  } else if (c.type == "bitmask") {
    info.kind = ControlKind::bitmask;
  } else {
    info.kind = ControlKind::other;
    info.why_not_settable = c.type == "button" ? "a button (an action, not a setting)"
                                               : fmt::format(
                                                     "a {} control: markerd sets numbers, booleans and "
                                                     "menu items only",
                                                     c.type);
  }
  if (info.kind == ControlKind::boolean) {
    info.minimum = c.minimum != 0;
    info.maximum = c.maximum != 0;
    info.default_value = c.default_value != 0;
    if (c.value) info.value = *c.value != 0;
  } else if (info.kind != ControlKind::other) {
    info.minimum = c.minimum;
    info.maximum = c.maximum;
    info.default_value = c.default_value;
  }
  return info;
}

int write_control(int fd, std::uint32_t id, bool int64, std::int64_t value) noexcept {
  v4l2_ext_control control{};
  control.id = id;
  if (int64) {
    control.value64 = value;
  } else {
    control.value = static_cast<std::int32_t>(value);
  }
  v4l2_ext_controls list{};
  list.which = V4L2_CTRL_WHICH_CUR_VAL;
  list.count = 1;
  list.controls = &control;
  int result = xioctl(fd, VIDIOC_S_EXT_CTRLS, &list);
  if (result != 0 && errno == ENOTTY && !int64) {
    v4l2_control old{id, static_cast<std::int32_t>(value)};
    result = xioctl(fd, VIDIOC_S_CTRL, &old);
  }
  return result == 0 ? 0 : errno;
}

int write_control(int fd, const V4l2ControlInfo& control, std::int64_t value) noexcept {
  return write_control(fd, control.id, control.type == "int64", value);
}

std::string offered_formats(int fd) {
  std::string text;
  for (const auto& format : enum_formats(fd, V4L2_BUF_TYPE_VIDEO_CAPTURE)) {
    if (!text.empty()) text += ", ";
    text += format.fourcc_text;
    for (const auto& size : format.sizes) text += fmt::format(" {}x{}", size.width, size.height);
    if (format.size_range) {
      const auto& r = *format.size_range;
      text += fmt::format(" {}x{} to {}x{}", r.min_width, r.min_height, r.max_width, r.max_height);
    }
  }
  return text.empty() ? std::string("nothing it lists") : text;
}

std::string input_list(int fd) {
  std::string text;
  for (const auto& input : enum_inputs(fd)) {
    text += fmt::format("{}{} \"{}\"", text.empty() ? "" : ", ", input.index, input.name);
  }
  return text.empty() ? std::string("none it lists") : text;
}

}  // namespace markerd::daemon::v4l2
