#pragma once
// The V4L2 device queries that the source and the listing share: ioctl
// without EINTR, the formats, inputs and controls a device offers, and
// their names for errors. Internal to capture.

#include <linux/videodev2.h>

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/daemon/capture/camera_controls.hpp"
#include "markerd/daemon/capture/v4l2_listing.hpp"

namespace markerd::daemon::v4l2 {

// ioctl(2), repeated when a signal interrupts it.
int xioctl(int fd, unsigned long request, void* arg) noexcept;

// A fixed-size, NUL-padded field of a V4L2 struct as a string.
template <std::size_t N>
std::string c_text(const std::uint8_t (&chars)[N]) {
  const auto* begin = reinterpret_cast<const char*>(chars);
  return {begin, strnlen(begin, N)};
}
template <std::size_t N>
std::string c_text(const char (&chars)[N]) {
  return {chars, strnlen(chars, N)};
}

// The capabilities of the node opened (device_caps where the driver gives them).
std::uint32_t device_caps(const v4l2_capability& cap);
// Every format of a buffer type, with its sizes and frame intervals.
std::vector<V4l2FormatInfo> enum_formats(int fd, std::uint32_t buffer_type);
std::vector<V4l2InputInfo> enum_inputs(int fd);
// Every control, with its range, menu and current value.
std::vector<V4l2ControlInfo> enum_controls(int fd);
// A control as camera.get and the value checks see it.
CameraControlInfo camera_control(const V4l2ControlInfo& control);
// Sets one control (VIDIOC_S_EXT_CTRLS, or VIDIOC_S_CTRL on a driver without
// the control framework): 0, or the errno.
int write_control(int fd, const V4l2ControlInfo& control, std::int64_t value) noexcept;
int write_control(int fd, std::uint32_t id, bool int64, std::int64_t value) noexcept;

// "YUYV 640x480 320x240, GREY 16x16 to 4096x2160": what a refusal of the
// configured format lists (what S_FMT can choose from).
std::string offered_formats(int fd);
// `0 "Camera 1", 1 "Composite"`: what a refusal of the configured input lists.
std::string input_list(int fd);

}  // namespace markerd::daemon::v4l2
