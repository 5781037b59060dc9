// The far side of the emulated USB webcam of the HIL guest: the program that
// a UVC gadget's function driver (usb_f_uvc) needs in user space, on the
// gadget's video output node. The uvc-gadget setup step
// (tools/hil/guest/setup/uvc-gadget.sh) starts it; the host side of the same
// guest sees a webcam through uvcvideo and libcamera.
//
//   uvc_gadget_server --device /dev/videoN --out-dir DIR [--frames-per-scene N]
//                     [--control-interface N] [--streaming-interface N]
//
// usb_f_uvc forwards the host's class requests as V4L2 events and sends the
// frames queued on the output node; everything a camera's firmware would
// answer is answered here:
// - the streaming interface's probe and commit (the format, frame and frame
//   interval the host asks for, clamped to the gadget's two formats, YUYV
//   and MJPEG, each with one frame size, 640x480, and two intervals);
// - the control interface's two controls that usb_f_uvc advertises by
//   default, the camera terminal's auto-exposure mode and the processing
//   unit's brightness, and the request error code; everything else stalls,
//   as a camera without that control would;
// - on STREAMON, frames at the committed interval: feeder_scenes() rendered
//   through the thesis camera (the scenes of the vivid tests), each stamped
//   with its number (uvc_frames.hpp), changing scene every N frames; as
//   YUYV, or as JPEG (stamped_jpeg.hpp) when the host committed MJPEG.
//
// It records every frame it queued and every control request it received
// (uvc_frames.hpp says the format), so that a test can check what arrived
// against what was sent. When the gadget is unbound from its controller
// (an unplug), the node goes away: the server waits for the gadget's node
// to come back and serves it again.

#include <endian.h>
#include <fcntl.h>
#include <linux/videodev2.h>
// g_uvc.h needs videodev2.h's V4L2_EVENT_PRIVATE_START first.
#include <linux/usb/g_uvc.h>
#include <linux/usb/video.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "stamped_jpeg.hpp"
#include "uvc_frames.hpp"
#include "vivid_scene_feeder.hpp"

namespace markerd::hil {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// The gadget as uvc-gadget.sh makes it: its formats in the order they are
// linked into the streaming header, which numbers them (bFormatIndex).
enum class Format : std::uint8_t { yuyv = 1, mjpeg = 2 };
// A YUYV frame's bytes, and the most an MJPEG frame may take (its
// dwMaxVideoFrameBufferSize).
constexpr std::uint32_t kFrameBytes = static_cast<std::uint32_t>(kWidth) * kHeight * 2;
constexpr int kJpegQuality = 90;
constexpr std::uint32_t kIntervalFast = 333333;  // 100 ns units: 30 frames per second
constexpr std::uint32_t kIntervalSlow = 666666;  // 15
constexpr std::uint32_t kMaxPayload = 3072;      // streaming_maxpacket
// usb_f_uvc's entities: camera terminal 1, processing unit 2, output terminal 3.
constexpr std::uint8_t kCameraTerminal = 1;
constexpr std::uint8_t kProcessingUnit = 2;
// The auto-exposure modes this camera offers, as UVC's bitmap: manual (1)
// and aperture priority (8), what most webcams offer and the two libcamera's
// AeEnable switches between.
constexpr std::uint8_t kAeModes = 0x09;
constexpr std::uint8_t kAeModeDefault = 0x08;
constexpr std::int16_t kBrightnessMin = -64, kBrightnessMax = 64, kBrightnessDefault = 0;
const char* format_name(Format format) { return format == Format::mjpeg ? "MJPEG" : "YUYV"; }

// UVC 1.1's request error codes (4.2.1.2).
constexpr std::uint8_t kErrorNone = 0x00, kErrorOutOfRange = 0x04, kErrorInvalidControl = 0x06,
                       kErrorInvalidRequest = 0x07;
constexpr std::uint32_t kBuffers = 4;

std::int64_t monotonic_ns() {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}

std::string request_name(std::uint8_t request) {
  switch (request) {
    case UVC_SET_CUR: return "SET_CUR";
    case UVC_GET_CUR: return "GET_CUR";
    case UVC_GET_MIN: return "GET_MIN";
    case UVC_GET_MAX: return "GET_MAX";
    case UVC_GET_RES: return "GET_RES";
    case UVC_GET_LEN: return "GET_LEN";
    case UVC_GET_INFO: return "GET_INFO";
    case UVC_GET_DEF: return "GET_DEF";
    default: return "0x" + std::to_string(request);
  }
}

// One JSON object a line, each written whole and at once, for a reader that
// follows the file while it grows.
class Record {
 public:
  explicit Record(const fs::path& path) : out_(path, std::ios::trunc) {
    if (!out_) throw std::runtime_error("cannot write " + path.string());
  }
  void write(const json& line) { out_ << line.dump() << '\n' << std::flush; }

 private:
  std::ofstream out_;
};

struct Options {
  std::string device;
  fs::path out_dir;
  std::uint32_t frames_per_scene = 30;
  int control_interface = 0;  // usb_f_uvc numbers its control interface first
  int streaming_interface = 1;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (i + 1 >= argc) throw std::invalid_argument(arg + " needs a value");
    const std::string value = argv[++i];
    if (arg == "--device") {
      o.device = value;
    } else if (arg == "--out-dir") {
      o.out_dir = value;
    } else if (arg == "--frames-per-scene") {
      o.frames_per_scene = static_cast<std::uint32_t>(std::stoul(value));
    } else if (arg == "--control-interface") {
      o.control_interface = std::stoi(value);
    } else if (arg == "--streaming-interface") {
      o.streaming_interface = std::stoi(value);
    } else {
      throw std::invalid_argument("unknown option " + arg);
    }
  }
  if (o.device.empty() || o.out_dir.empty() || o.frames_per_scene == 0) {
    throw std::invalid_argument("usage: uvc_gadget_server --device NODE --out-dir DIR [--frames-per-scene N]");
  }
  return o;
}

// The gadget device a video node belongs to, which outlives the node: the
// node goes with the function's unbind and comes back, maybe under another
// number, when the gadget is bound again.
fs::path node_device(const std::string& node) {
  return fs::canonical(fs::path("/sys/class/video4linux") / fs::path(node).filename() / "device");
}

std::optional<std::string> find_node_of(const fs::path& device) {
  std::error_code ec;
  for (fs::directory_iterator it("/sys/class/video4linux", ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code e;
    if (fs::canonical(it->path() / "device", e) == device && !e) {
      const std::string node = "/dev/" + it->path().filename().string();
      if (fs::exists(node)) return node;
    }
  }
  return std::nullopt;
}

class DeviceGone : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A scene as the gadget sends it, in either format.
struct SceneFrames {
  int id = -1;
  std::vector<std::uint8_t> yuyv;
  StampedJpeg jpeg;
};

class Server {
 public:
  Server(Options options, std::vector<SceneFrames> scenes)
      : options_(std::move(options)),
        scenes_(std::move(scenes)),
        frames_record_(options_.out_dir / kFramesRecord),
        controls_record_(options_.out_dir / kControlsRecord) {
    probe_ = streaming_control(Format::yuyv, kIntervalFast);
    commit_ = probe_;
  }

  // Serves the node until it goes away; then waits for it to come back.
  [[noreturn]] void run() {
    const fs::path device = node_device(options_.device);
    std::string node = options_.device;
    for (;;) {
      try {
        open(node);
        serve();
      } catch (const DeviceGone& e) {
        std::cerr << "uvc_gadget_server: " << e.what() << ": waiting for the gadget's node to come back" << std::endl;
      }
      stop_streaming();
      close();
      for (;;) {
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        if (auto found = find_node_of(device)) {
          node = *found;
          break;
        }
      }
    }
  }

 private:
  struct Buffer {
    std::uint8_t* data = nullptr;
    std::size_t length = 0;
    std::optional<std::uint32_t> frame;  // queued with this frame
  };

  // ---------------------------------------------------------------- the node

  // usb_f_uvc's VIDIOC_REQBUFS returns the buffer count: only a negative
  // result is a failure.
  void check(int result, const std::string& what) const {
    if (result >= 0) return;
    if (errno == ENODEV) throw DeviceGone(node_ + ": " + what + ": " + std::strerror(errno));
    throw std::runtime_error(errno_text(node_ + ": " + what));
  }

  void open(const std::string& node) {
    node_ = node;
    fd_ = ::open(node.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd_ < 0) {
      if (errno == ENODEV || errno == ENOENT) throw DeviceGone(errno_text("open " + node));
      throw std::runtime_error(errno_text("open " + node));
    }
    // SETUP last: subscribing to it is what makes usb_f_uvc connect the
    // gadget to the bus, and the host's first requests follow at once.
    for (std::uint32_t type : {UVC_EVENT_CONNECT, UVC_EVENT_DISCONNECT, UVC_EVENT_STREAMON, UVC_EVENT_STREAMOFF,
                               UVC_EVENT_DATA, UVC_EVENT_SETUP}) {
      v4l2_event_subscription sub{};
      sub.type = type;
      check(xioctl(fd_, VIDIOC_SUBSCRIBE_EVENT, &sub), "VIDIOC_SUBSCRIBE_EVENT");
    }
    std::cerr << "uvc_gadget_server: serving " << node << std::endl;
  }

  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  void serve() {
    for (;;) {
      int timeout_ms = 100;
      if (streaming_) {
        const std::int64_t wait = next_due_ns_ - monotonic_ns();
        timeout_ms = free_buffer() ? static_cast<int>(std::clamp<std::int64_t>(wait / 1000000, 0, 100)) : 100;
      }
      pollfd p{fd_, static_cast<short>(POLLPRI | (streaming_ ? POLLOUT : 0)), 0};
      const int n = ::poll(&p, 1, timeout_ms);
      if (n < 0 && errno != EINTR) throw std::runtime_error(errno_text("poll"));
      // A node whose device was unregistered polls as POLLPRI | POLLERR, and
      // VIDIOC_DQEVENT then fails with ENODEV.
      if ((p.revents & POLLPRI) != 0) events();
      if (streaming_ && (p.revents & POLLOUT) != 0) reclaim();
      if (streaming_) send_due();
    }
  }

  // ---------------------------------------------------------------- events

  void events() {
    for (;;) {
      v4l2_event event{};
      if (xioctl(fd_, VIDIOC_DQEVENT, &event) != 0) {
        if (errno == ENOENT || errno == EAGAIN) return;
        check(-1, "VIDIOC_DQEVENT");
      }
      uvc_event uvc{};
      std::memcpy(&uvc, event.u.data, sizeof uvc);
      switch (event.type) {
        case UVC_EVENT_CONNECT: std::cerr << "uvc_gadget_server: connected" << std::endl; break;
        case UVC_EVENT_DISCONNECT:
          // Unbinding the gadget waits (up to 1.5 s) for the node to be
          // closed before it removes the node: let it go at once.
          throw DeviceGone(node_ + ": disconnected");
        case UVC_EVENT_SETUP: setup(uvc.req); break;
        case UVC_EVENT_DATA: data(uvc.data); break;
        case UVC_EVENT_STREAMON: start_streaming(); break;
        case UVC_EVENT_STREAMOFF: stop_streaming(); break;
        default: break;
      }
    }
  }

  void respond(const uvc_request_data& response) {
    check(xioctl(fd_, UVCIOC_SEND_RESPONSE, const_cast<uvc_request_data*>(&response)), "UVCIOC_SEND_RESPONSE");
  }

  void stall(std::uint8_t error_code, json& line) {
    error_code_ = error_code;
    uvc_request_data response{};
    response.length = -EL2HLT;  // usb_f_uvc halts ep0 for a negative length
    respond(response);
    line["stalled"] = true;
  }

  template <typename T>
  void answer(const T& value, std::uint16_t length) {
    uvc_request_data response{};
    response.length = std::min<int>(length, sizeof value);
    std::memcpy(response.data, &value, static_cast<std::size_t>(response.length));
    respond(response);
    error_code_ = kErrorNone;
  }

  void setup(const usb_ctrlrequest& req) {
    const std::uint16_t value = le16toh(req.wValue);
    const std::uint16_t index = le16toh(req.wIndex);
    const std::uint16_t length = le16toh(req.wLength);
    const int interface = index & 0xff;
    const std::uint8_t entity = index >> 8;
    const std::uint8_t selector = value >> 8;
    json line = {{"t_ns", monotonic_ns()},
                 {"request", request_name(req.bRequest)},
                 {"interface", interface == options_.streaming_interface ? "streaming"
                               : interface == options_.control_interface ? "control"
                                                                         : "other"},
                 {"entity", entity},
                 {"selector", selector},
                 {"length", length},
                 {"stalled", false}};
    if ((req.bRequestType & USB_TYPE_MASK) != USB_TYPE_CLASS) {
      line["name"] = "unknown";
      stall(kErrorInvalidRequest, line);
    } else if (interface == options_.streaming_interface && entity == 0) {
      streaming_request(req.bRequest, selector, length, line);
    } else if (interface == options_.control_interface) {
      control_request(req.bRequest, entity, selector, length, line);
    } else {
      line["name"] = "unknown";
      stall(kErrorInvalidRequest, line);
    }
    controls_record_.write(line);
  }

  // A SET_CUR is answered with its length: usb_f_uvc then reads the data
  // stage and hands it over as the next DATA event.
  void expect_data(const std::string& name, std::uint16_t length) {
    pending_set_ = name;
    uvc_request_data response{};
    response.length = length;
    respond(response);
  }

  void streaming_request(std::uint8_t request, std::uint8_t selector, std::uint16_t length, json& line) {
    if (selector != UVC_VS_PROBE_CONTROL && selector != UVC_VS_COMMIT_CONTROL) {
      line["name"] = "unknown";
      return stall(kErrorInvalidControl, line);
    }
    const bool probe = selector == UVC_VS_PROBE_CONTROL;
    line["name"] = probe ? "probe" : "commit";
    switch (request) {
      case UVC_SET_CUR: return expect_data(probe ? "probe" : "commit", length);
      case UVC_GET_CUR: return answer(probe ? probe_ : commit_, length);
      case UVC_GET_MIN:
      case UVC_GET_DEF: return answer(streaming_control(format_of(probe_), kIntervalFast), length);
      case UVC_GET_MAX: return answer(streaming_control(format_of(probe_), kIntervalSlow), length);
      case UVC_GET_RES: return answer(uvc_streaming_control{}, length);
      case UVC_GET_LEN: return answer(static_cast<std::uint16_t>(sizeof(uvc_streaming_control)), length);
      case UVC_GET_INFO: return answer(std::uint8_t{0x03}, length);  // GET and SET supported
      default: return stall(kErrorInvalidRequest, line);
    }
  }

  void control_request(std::uint8_t request, std::uint8_t entity, std::uint8_t selector, std::uint16_t length,
                       json& line) {
    if (entity == 0 && selector == UVC_VC_REQUEST_ERROR_CODE_CONTROL) {
      line["name"] = "request_error_code";
      // Answered without resetting it: this request is how the host asks
      // why the last one stalled.
      const std::uint8_t code = error_code_;
      if (request == UVC_GET_CUR) {
        answer(code, length);
      } else if (request == UVC_GET_INFO) {
        answer(std::uint8_t{0x01}, length);
      } else {
        return stall(kErrorInvalidRequest, line);
      }
      line["value"] = code;
      return;
    }
    if (entity == kProcessingUnit && selector == UVC_PU_BRIGHTNESS_CONTROL) {
      line["name"] = "brightness";
      switch (request) {
        case UVC_SET_CUR: return expect_data("brightness", length);
        case UVC_GET_CUR: return answer(brightness_, length);
        case UVC_GET_MIN: return answer(kBrightnessMin, length);
        case UVC_GET_MAX: return answer(kBrightnessMax, length);
        case UVC_GET_DEF: return answer(kBrightnessDefault, length);
        case UVC_GET_RES: return answer(std::int16_t{1}, length);
        case UVC_GET_LEN: return answer(std::uint16_t{2}, length);
        case UVC_GET_INFO: return answer(std::uint8_t{0x03}, length);
        default: return stall(kErrorInvalidRequest, line);
      }
    }
    if (entity == kCameraTerminal && selector == UVC_CT_AE_MODE_CONTROL) {
      line["name"] = "ae_mode";
      switch (request) {
        case UVC_SET_CUR: return expect_data("ae_mode", length);
        case UVC_GET_CUR: return answer(ae_mode_, length);
        case UVC_GET_DEF: return answer(kAeModeDefault, length);
        case UVC_GET_RES: return answer(kAeModes, length);  // a bitmap control's RES: the modes it has
        case UVC_GET_LEN: return answer(std::uint16_t{1}, length);
        case UVC_GET_INFO: return answer(std::uint8_t{0x03}, length);
        default: return stall(kErrorInvalidRequest, line);
      }
    }
    line["name"] = "unknown";
    stall(kErrorInvalidControl, line);
  }

  void data(const uvc_request_data& data) {
    const std::string name = pending_set_;
    pending_set_.clear();
    json line = {
        {"t_ns", monotonic_ns()}, {"request", "SET_CUR"}, {"name", name}, {"length", data.length}, {"stalled", false}};
    const auto bytes = static_cast<std::size_t>(std::clamp(data.length, 0, static_cast<int>(sizeof data.data)));
    if (name == "probe" || name == "commit") {
      uvc_streaming_control control{};
      std::memcpy(&control, data.data, std::min(bytes, sizeof control));
      const std::uint32_t requested = control.dwFrameInterval;
      const std::uint32_t interval = requested >= (kIntervalFast + kIntervalSlow) / 2 ? kIntervalSlow : kIntervalFast;
      const Format format = format_of(control);
      (name == "probe" ? probe_ : commit_) = streaming_control(format, interval);
      line["frame_interval"] = interval;
      line["requested_interval"] = requested;
      line["format"] = format_name(format);
      line["requested_format_index"] = control.bFormatIndex;
    } else if (name == "brightness" && bytes >= 2) {
      std::int16_t v = 0;
      std::memcpy(&v, data.data, sizeof v);
      line["value"] = v;
      if (v < kBrightnessMin || v > kBrightnessMax) {
        error_code_ = kErrorOutOfRange;
      } else {
        brightness_ = v;
        error_code_ = kErrorNone;
      }
    } else if (name == "ae_mode" && bytes >= 1) {
      const std::uint8_t v = data.data[0];
      line["value"] = v;
      // One bit, and one of the modes this camera has.
      if ((v & (v - 1)) != 0 || (v & kAeModes) == 0) {
        error_code_ = kErrorOutOfRange;
      } else {
        ae_mode_ = v;
        error_code_ = kErrorNone;
      }
    }
    controls_record_.write(line);
  }

  // A format index the gadget does not have is clamped to the first, as
  // a camera answers a probe with the nearest it can do.
  static Format format_of(const uvc_streaming_control& control) {
    return control.bFormatIndex == static_cast<std::uint8_t>(Format::mjpeg) ? Format::mjpeg : Format::yuyv;
  }

  static uvc_streaming_control streaming_control(Format format, std::uint32_t interval) {
    uvc_streaming_control c{};
    c.bmHint = 1;  // the frame interval is what the host asked to keep
    c.bFormatIndex = static_cast<std::uint8_t>(format);
    c.bFrameIndex = 1;
    c.dwFrameInterval = interval;
    c.dwMaxVideoFrameSize = kFrameBytes;
    c.dwMaxPayloadTransferSize = kMaxPayload;
    c.bmFramingInfo = 3;
    c.bPreferedVersion = 1;
    c.bMinVersion = 1;
    c.bMaxVersion = 1;
    return c;
  }

  // ---------------------------------------------------------------- streaming

  // The output node's format sizes its buffers (usb_f_uvc takes MJPEG's
  // sizeimage as given) and says how the gadget sends them.
  void set_format(Format format) {
    // usb_f_uvc 6.1 computes bytesperline from the width it had before this
    // call: the second call is the one that is right.
    for (int i = 0; i < 2; ++i) {
      v4l2_format f{};
      f.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      f.fmt.pix.width = kWidth;
      f.fmt.pix.height = kHeight;
      f.fmt.pix.pixelformat = format == Format::mjpeg ? V4L2_PIX_FMT_MJPEG : V4L2_PIX_FMT_YUYV;
      f.fmt.pix.field = V4L2_FIELD_NONE;
      f.fmt.pix.sizeimage = kFrameBytes;
      check(xioctl(fd_, VIDIOC_S_FMT, &f), "VIDIOC_S_FMT");
      stride_ = f.fmt.pix.bytesperline;
    }
    if (format == Format::yuyv && stride_ != kWidth * 2) {
      throw std::runtime_error(node_ + ": bytesperline " + std::to_string(stride_));
    }
    format_ = format;
  }

  void start_streaming() {
    stop_streaming();
    set_format(format_of(commit_));
    v4l2_requestbuffers request{};
    request.count = kBuffers;
    request.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    request.memory = V4L2_MEMORY_MMAP;
    check(xioctl(fd_, VIDIOC_REQBUFS, &request), "VIDIOC_REQBUFS");
    for (std::uint32_t i = 0; i < request.count; ++i) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      b.index = i;
      check(xioctl(fd_, VIDIOC_QUERYBUF, &b), "VIDIOC_QUERYBUF");
      void* data = ::mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, b.m.offset);
      if (data == MAP_FAILED) throw std::runtime_error(errno_text(node_ + ": mmap"));
      buffers_.push_back({static_cast<std::uint8_t*>(data), b.length, std::nullopt});
    }
    interval_ns_ = static_cast<std::int64_t>(commit_.dwFrameInterval) * 100;
    next_due_ns_ = monotonic_ns();
    streaming_ = true;
    send_due();  // a buffer is queued before STREAMON
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    check(xioctl(fd_, VIDIOC_STREAMON, &type), "VIDIOC_STREAMON");
    std::cerr << "uvc_gadget_server: streaming " << format_name(format_) << " at " << commit_.dwFrameInterval
              << " x 100 ns per frame" << std::endl;
  }

  void stop_streaming() {
    if (!streaming_) return;
    streaming_ = false;
    int type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    xioctl(fd_, VIDIOC_STREAMOFF, &type);  // ENODEV when the gadget went away: the buffers go all the same
    for (auto& b : buffers_) {
      if (b.frame) frames_record_.write({{"frame", *b.frame}, {"done_ns", monotonic_ns()}, {"error", true}});
      ::munmap(b.data, b.length);
    }
    buffers_.clear();
    v4l2_requestbuffers request{};
    request.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    request.memory = V4L2_MEMORY_MMAP;
    xioctl(fd_, VIDIOC_REQBUFS, &request);
    std::cerr << "uvc_gadget_server: stopped streaming after frame " << next_frame_ << std::endl;
  }

  Buffer* free_buffer() {
    for (auto& b : buffers_) {
      if (!b.frame) return &b;
    }
    return nullptr;
  }

  void reclaim() {
    for (;;) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
      b.memory = V4L2_MEMORY_MMAP;
      if (xioctl(fd_, VIDIOC_DQBUF, &b) != 0) {
        if (errno == EAGAIN || errno == EINVAL) return;  // EINVAL: streaming stopped under us
        check(-1, "VIDIOC_DQBUF");
      }
      Buffer& buffer = buffers_.at(b.index);
      if (buffer.frame) {
        frames_record_.write(
            {{"frame", *buffer.frame}, {"done_ns", monotonic_ns()}, {"error", (b.flags & V4L2_BUF_FLAG_ERROR) != 0}});
      }
      buffer.frame.reset();
    }
  }

  // Queues the next frame once its time has come. A frame whose time has
  // passed while every buffer was still being sent goes as soon as one is
  // free, and the clock restarts from then: the bus, not the schedule, sets
  // the pace when it cannot keep up.
  void send_due() {
    const std::int64_t now = monotonic_ns();
    if (now < next_due_ns_) return;
    Buffer* buffer = free_buffer();
    if (buffer == nullptr) return;
    const std::uint32_t number = next_frame_;
    const std::size_t scene = scene_of(number, options_.frames_per_scene, scenes_.size());
    std::size_t bytes = kFrameBytes;
    if (format_ == Format::mjpeg) {
      bytes = scenes_[scene].jpeg.write(number, {buffer->data, buffer->length});
    } else {
      std::memcpy(buffer->data, scenes_[scene].yuyv.data(), kFrameBytes);
      stamp_yuyv(buffer->data, stride_, number);
    }
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_OUTPUT;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = static_cast<std::uint32_t>(buffer - buffers_.data());
    b.bytesused = static_cast<std::uint32_t>(bytes);
    b.field = V4L2_FIELD_NONE;
    if (xioctl(fd_, VIDIOC_QBUF, &b) != 0) {
      // The host stopped streaming: usb_f_uvc refuses buffers until the
      // STREAMOFF event, which is on its way.
      if (errno == ENODEV) return;
      check(-1, "VIDIOC_QBUF");
    }
    buffer->frame = number;
    ++next_frame_;
    frames_record_.write({{"frame", number},
                          {"scene", scene},
                          {"id", scenes_[scene].id},
                          {"format", format_name(format_)},
                          {"bytes", bytes},
                          {"queued_ns", now}});
    next_due_ns_ = now - next_due_ns_ > interval_ns_ ? now + interval_ns_ : next_due_ns_ + interval_ns_;
  }

  Options options_;
  std::vector<SceneFrames> scenes_;
  Record frames_record_;
  Record controls_record_;
  std::string node_;
  int fd_ = -1;
  std::uint32_t stride_ = 0;

  uvc_streaming_control probe_{}, commit_{};
  std::string pending_set_;  // what the next DATA event is for
  std::uint8_t error_code_ = kErrorNone;
  std::int16_t brightness_ = kBrightnessDefault;
  std::uint8_t ae_mode_ = kAeModeDefault;

  bool streaming_ = false;
  Format format_ = Format::yuyv;
  std::vector<Buffer> buffers_;
  std::int64_t interval_ns_ = 0;
  std::int64_t next_due_ns_ = 0;
  std::uint32_t next_frame_ = 0;  // counts on across streams, so that each frame has one number
};

}  // namespace
}  // namespace markerd::hil

int main(int argc, char** argv) {
  using namespace markerd;
  using namespace markerd::hil;
  try {
    const Options options = parse(argc, argv);
    fs::create_directories(options.out_dir);
    std::vector<SceneFrames> scenes;
    for (const detector::Scene& scene : feeder_scenes()) {
      std::vector<std::uint8_t> yuyv = to_yuyv(detector::render_scene(feeder_camera(), scene));
      StampedJpeg jpeg(yuyv, kWidth, kHeight, kJpegQuality);
      scenes.push_back({scene.id, std::move(yuyv), std::move(jpeg)});
    }
    Server server(options, std::move(scenes));
    server.run();
  } catch (const std::exception& e) {
    std::cerr << "uvc_gadget_server: " << e.what() << std::endl;
    return 1;
  }
}
