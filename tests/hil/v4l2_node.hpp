#pragma once
// V4L2 device nodes as the HIL tests and their helpers drive them directly,
// past the code under test: the node open for as long as the object lives,
// ioctls retried on EINTR, failures that name the call; the DV timings both
// ends of vivid's HDMI loop are set to, and its output node set up for
// writing frames into the loop.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

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

// vivid's HDMI output node ready to feed the loop: output 0 with the loop's
// timings, 640x480 frames in `fourcc`, and `count` memory-mapped buffers,
// unmapped when the object goes. What goes into the buffers, and when, is
// the owner's; it stops the stream before this object goes.
class LoopOutput {
 public:
  struct Buffer {
    std::uint8_t* data;
    std::size_t length;
  };

  LoopOutput(const std::string& path, std::uint32_t fourcc, std::uint32_t count = 8) : node_(path) {
    const int fd = node_.fd();
    int index = 0;
    must(fd, VIDIOC_S_OUTPUT, &index, "output VIDIOC_S_OUTPUT");
    auto timings = timings_640x480p60();
    must(fd, VIDIOC_S_DV_TIMINGS, &timings, "output VIDIOC_S_DV_TIMINGS");
    v4l2_format f{};
    f.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    f.fmt.pix.width = kWidth;
    f.fmt.pix.height = kHeight;
    f.fmt.pix.pixelformat = fourcc;
    f.fmt.pix.field = V4L2_FIELD_NONE;
    must(fd, VIDIOC_S_FMT, &f, "output VIDIOC_S_FMT");
    if (f.fmt.pix.pixelformat != fourcc || f.fmt.pix.width != kWidth || f.fmt.pix.height != kHeight) {
      std::string name;
      for (int i = 0; i < 4; ++i) name += static_cast<char>((fourcc >> (8 * i)) & 0xff);
      throw std::runtime_error(path + ": vivid's output refuses " + name + " 640x480");
    }
    stride_ = f.fmt.pix.bytesperline;
    size_ = f.fmt.pix.sizeimage;
    v4l2_requestbuffers request{};
    request.count = count;
    request.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    request.memory = V4L2_MEMORY_MMAP;
    must(fd, VIDIOC_REQBUFS, &request, "output VIDIOC_REQBUFS");
    for (std::uint32_t i = 0; i < request.count; ++i) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      b.index = i;
      must(fd, VIDIOC_QUERYBUF, &b, "output VIDIOC_QUERYBUF");
      void* data = ::mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, b.m.offset);
      if (data == MAP_FAILED) throw std::runtime_error(errno_text("output mmap"));
      buffers_.push_back({static_cast<std::uint8_t*>(data), b.length});
    }
  }
  ~LoopOutput() {
    for (const auto& b : buffers_) ::munmap(b.data, b.length);
  }
  LoopOutput(const LoopOutput&) = delete;
  LoopOutput& operator=(const LoopOutput&) = delete;

  // 0, or the errno of VIDIOC_QBUF: buffer `index`, filled, goes to the driver.
  int queue(std::uint32_t index) const {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = index;
    b.bytesused = size_;
    b.field = V4L2_FIELD_NONE;
    return xioctl(node_.fd(), VIDIOC_QBUF, &b) == 0 ? 0 : errno;
  }
  // A buffer the driver is done with, or nothing with errno set (EAGAIN: none yet).
  [[nodiscard]] std::optional<std::uint32_t> dequeue() const {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    b.memory = V4L2_MEMORY_MMAP;
    if (xioctl(node_.fd(), VIDIOC_DQBUF, &b) != 0) return std::nullopt;
    return b.index;
  }
  void stream_on() const {
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    must(node_.fd(), VIDIOC_STREAMON, &type, "output VIDIOC_STREAMON");
  }
  // Fails with ENODEV once the device is gone: nothing to do then.
  void stream_off() const noexcept {
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    xioctl(node_.fd(), VIDIOC_STREAMOFF, &type);
  }

  [[nodiscard]] int fd() const { return node_.fd(); }
  [[nodiscard]] std::uint32_t stride() const { return stride_; }  // bytes per line of the (first) plane
  [[nodiscard]] std::uint32_t size() const { return size_; }      // bytes per frame
  [[nodiscard]] std::uint32_t count() const { return static_cast<std::uint32_t>(buffers_.size()); }
  [[nodiscard]] const Buffer& buffer(std::uint32_t index) const { return buffers_.at(index); }

 private:
  Node node_;
  std::uint32_t stride_ = 0;
  std::uint32_t size_ = 0;
  std::vector<Buffer> buffers_;
};

}  // namespace markerd::hil
