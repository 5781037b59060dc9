#pragma once
// V4L2 device nodes as the HIL tests and their helpers drive them directly,
// past the code under test: the node open for as long as the object lives,
// ioctls retried on EINTR, failures that name the call; and the DV timings
// both ends of vivid's HDMI loop are set to.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <string>

namespace markerd::hil {

constexpr int kWidth = 640;
constexpr int kHeight = 480;
constexpr int kHdmiInput = 1;  // vivid's capture inputs with input_types=0x0c: 0 a webcam, 1 HDMI

inline std::string errno_text(const std::string& what) { return what + ": " + std::strerror(errno); }

inline int xioctl(int fd, unsigned long request, void* arg) {
  int result = 0;
  do {
    result = ::ioctl(fd, request, arg);
  } while (result == -1 && errno == EINTR);
  return result;
}

inline void must(int fd, unsigned long request, void* arg, const std::string& what) {
  if (xioctl(fd, request, arg) != 0) throw std::runtime_error(errno_text(what));
}

class Node {
 public:
  explicit Node(const std::string& path) : fd_(::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC)) {
    if (fd_ < 0) throw std::runtime_error(errno_text("open " + path));
  }
  ~Node() { ::close(fd_); }
  Node(const Node&) = delete;
  Node& operator=(const Node&) = delete;
  [[nodiscard]] int fd() const { return fd_; }

 private:
  int fd_;
};

// 640x480 progressive at 60 Hz (V4L2_DV_BT_DMT_640X480P60), on both HDMI ends.
inline v4l2_dv_timings timings_640x480p60() {
  v4l2_dv_timings t{};
  t.type = V4L2_DV_BT_656_1120;
  t.bt.width = kWidth;
  t.bt.height = kHeight;
  t.bt.pixelclock = 25175000;
  t.bt.hfrontporch = 16;
  t.bt.hsync = 96;
  t.bt.hbackporch = 48;
  t.bt.vfrontporch = 10;
  t.bt.vsync = 2;
  t.bt.vbackporch = 33;
  t.bt.standards = V4L2_DV_BT_STD_DMT | V4L2_DV_BT_STD_CEA861;
  t.bt.flags = V4L2_DV_FL_HAS_CEA861_VIC;
  t.bt.cea861_vic = 1;
  return t;
}

}  // namespace markerd::hil
