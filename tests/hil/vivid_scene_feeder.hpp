#pragma once
// Rendered frame markers fed through vivid's video loop, for what runs in the
// guest against the real driver and needs a camera that sees markers:
// tests/hil/test_markerd_vivid.cpp (markerd itself on the capture node) and
// bench/bench_v4l2_capture.cpp (markerd's capture path against v4l2-ctl).
//
// vivid loops its HDMI output to its HDMI capture input byte for byte when
// both ends have the same DV timings, format and field, the capture has
// "Loop Video" on and its OSD text off, and the output queue never runs dry
// (a dry queue makes the capture fall back to its test pattern): see
// docs/capture.md, "How it is tested". A scene's grey image goes out as YUYV
// with the grey as Y and neutral chroma, so the capture's Y plane is the
// rendered image again.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/detector/render.hpp"
#include "v4l2_node.hpp"

namespace markerd::hil {

// Puts the capture node on its HDMI input with the timings the feeder sends.
// vivid's HDMI input starts at 1280x720p60 and scales that to any size asked
// for, so a reader that opened it first would get a scaled test pattern and
// no loop: this must come before anyone streams from the node.
inline void select_hdmi_input(const std::string& capture) {
  Node n(capture);
  int input = kHdmiInput;
  must(n.fd(), VIDIOC_S_INPUT, &input, "capture VIDIOC_S_INPUT");
  auto timings = timings_640x480p60();
  must(n.fd(), VIDIOC_S_DV_TIMINGS, &timings, "capture VIDIOC_S_DV_TIMINGS");
}

struct VividNodes {
  std::string capture, output;
};

// vivid's capture and output nodes by their sysfs names, as the vivid-loop
// setup step finds them; nothing while the driver has no device bound.
inline std::optional<VividNodes> find_vivid_nodes() {
  namespace fs = std::filesystem;
  VividNodes nodes;
  std::error_code ec;
  for (fs::directory_iterator it("/sys/class/video4linux", ec), end; !ec && it != end; it.increment(ec)) {
    std::ifstream file(it->path() / "name");
    std::string name;
    if (!std::getline(file, name)) continue;
    const auto ends_with = [&](const char* suffix) {
      const std::size_t n = std::strlen(suffix);
      return name.rfind("vivid-", 0) == 0 && name.size() > n && name.compare(name.size() - n, n, suffix) == 0;
    };
    if (ends_with("-vid-cap")) nodes.capture = "/dev/" + it->path().filename().string();
    if (ends_with("-vid-out")) nodes.output = "/dev/" + it->path().filename().string();
  }
  if (nodes.capture.empty() || nodes.output.empty()) return std::nullopt;
  return nodes;
}

// ---------------------------------------------------------------- scenes

// What the feeder shows, in turn: two frame8 markers of different ids at
// 0.5 m, turned away from the camera by different angles (far enough from
// facing it that the pose has no flip ambiguity), over the renderer's
// clutter, through the thesis camera's lens with its distortion. The blur
// and noise of the simulated camera's defaults.
inline std::vector<detector::Scene> feeder_scenes() {
  detector::Scene a;
  a.family = detector::Family::frame8;
  a.id = 165;
  a.marker_size_m = 0.08;
  a.pose = detector::facing_pose(0.5, 30, 0, 0, 0.02, -0.01);
  a.blur_sigma_px = 0.6;
  a.noise_sigma = 2.0;
  a.supersample = 3;
  a.seed = 11;
  detector::Scene b = a;
  b.id = 77;
  b.pose = detector::facing_pose(0.5, -40, 0, 10, -0.03, 0.02);
  b.seed = 12;
  return {a, b};
}

inline detector::CameraModel feeder_camera() { return detector::CameraModel::thesis_640x480(); }

// A grey image as YUYV: Y the grey, U and V 128 (no colour).
inline std::vector<std::uint8_t> to_yuyv(const detector::GreyImage& image) {
  std::vector<std::uint8_t> yuyv(static_cast<std::size_t>(image.width()) * image.height() * 2, 128);
  for (int y = 0; y < image.height(); ++y) {
    const std::uint8_t* in = image.row(y);
    std::uint8_t* out = yuyv.data() + static_cast<std::size_t>(y) * image.width() * 2;
    for (int x = 0; x < image.width(); ++x) out[2 * x] = in[x];
  }
  return yuyv;
}

// ---------------------------------------------------------------- the feeder

// Writes YUYV frames into vivid's HDMI output from a thread of its own,
// queueing each buffer again the moment the driver is done with it: scene 0
// for `frames_per_scene` frames, then scene 1, and so on round. It records
// when each run of a scene was queued, so that a reader can tell which
// scene a frame captured at a given time may show. A buffer is rewritten
// only when its scene changes: steady state costs a DQBUF and a QBUF per
// frame, so the feeder takes little of the guest's one CPU from what is
// measured beside it.
//
// When the device goes away under it (vivid unbound), the thread stops and
// device_gone() says so; the output node is closed by the destructor.
class SceneFeeder {
 public:
  struct Run {
    std::chrono::steady_clock::time_point queued;  // the run's first buffer went into the queue
    std::size_t scene = 0;
  };

  SceneFeeder(const std::string& output, std::vector<std::vector<std::uint8_t>> frames, std::uint32_t frames_per_scene)
      : output_(output, V4L2_PIX_FMT_YUYV),
        frames_(std::move(frames)),
        frames_per_scene_(frames_per_scene),
        scene_in_buffer_(output_.count(), kNoScene) {
    if (frames_.empty() || frames_per_scene_ == 0) throw std::invalid_argument("SceneFeeder: no frames to feed");
    for (const auto& frame : frames_) {
      if (frame.size() != static_cast<std::size_t>(kWidth) * kHeight * 2) {
        throw std::invalid_argument("SceneFeeder: a frame is not YUYV 640x480");
      }
    }
    for (std::uint32_t i = 0; i < output_.count(); ++i) {
      if (const int e = queue(i); e != 0) {
        throw std::runtime_error("output VIDIOC_QBUF: " + std::string(std::strerror(e)));
      }
    }
    output_.stream_on();
    thread_ = std::jthread([this](const std::stop_token& stop) { run(stop); });
  }

  ~SceneFeeder() {
    thread_.request_stop();
    thread_.join();
    output_.stream_off();
  }
  SceneFeeder(const SceneFeeder&) = delete;
  SceneFeeder& operator=(const SceneFeeder&) = delete;

  [[nodiscard]] std::uint32_t queued() const { return next_.load(); }
  [[nodiscard]] bool device_gone() const { return gone_.load(); }
  [[nodiscard]] std::vector<Run> runs() const {
    const std::lock_guard lock(mutex_);
    return runs_;
  }
  // What stopped the thread other than the device going away; empty if nothing.
  [[nodiscard]] std::string error() const {
    const std::lock_guard lock(mutex_);
    return error_;
  }

 private:
  static constexpr std::size_t kNoScene = static_cast<std::size_t>(-1);

  // 0, or the errno of VIDIOC_QBUF.
  int queue(std::uint32_t index) {
    const std::uint32_t number = next_.fetch_add(1);
    const std::size_t scene = (number / frames_per_scene_) % frames_.size();
    if (number % frames_per_scene_ == 0) {
      const std::lock_guard lock(mutex_);
      runs_.push_back({std::chrono::steady_clock::now(), scene});
    }
    if (scene_in_buffer_[index] != scene) {
      std::uint8_t* out = output_.buffer(index).data;
      const std::uint8_t* in = frames_[scene].data();
      for (int y = 0; y < kHeight; ++y) {
        std::memcpy(out + static_cast<std::size_t>(y) * output_.stride(), in + static_cast<std::size_t>(y) * kWidth * 2,
                    static_cast<std::size_t>(kWidth) * 2);
      }
      scene_in_buffer_[index] = scene;
    }
    return output_.queue(index);
  }

  void run(const std::stop_token& stop) {
    const auto failed = [this](const char* what, int e) {
      if (e == ENODEV) {
        gone_.store(true);
      } else {
        const std::lock_guard lock(mutex_);
        error_ = std::string(what) + ": " + std::strerror(e);
      }
    };
    while (!stop.stop_requested()) {
      pollfd p{output_.fd(), POLLOUT, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      const auto done = output_.dequeue();
      if (!done) {
        if (errno == EAGAIN) continue;
        return failed("output VIDIOC_DQBUF", errno);
      }
      if (const int e = queue(*done); e != 0) return failed("output VIDIOC_QBUF", e);
    }
  }

  LoopOutput output_;
  std::vector<std::vector<std::uint8_t>> frames_;
  std::uint32_t frames_per_scene_;
  std::vector<std::size_t> scene_in_buffer_;  // what each buffer holds now
  std::atomic<std::uint32_t> next_{0};
  std::atomic<bool> gone_{false};
  mutable std::mutex mutex_;
  std::vector<Run> runs_;  // under mutex_
  std::string error_;      // under mutex_
  std::jthread thread_;
};

}  // namespace markerd::hil
