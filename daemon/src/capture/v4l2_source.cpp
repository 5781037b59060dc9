#include "markerd/daemon/capture/v4l2_source.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/mman.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <utility>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/capture/pixel_convert.hpp"
#include "v4l2_device.hpp"

namespace markerd::daemon {

namespace fs = std::filesystem;
using Kind = CaptureError::Kind;
using namespace v4l2;

namespace {

// ---------------------------------------------------------------- the stream

struct MappedBuffer {
  std::uint8_t* data = nullptr;
  std::size_t length = 0;
};

// One open of the device: its descriptor and mmap buffers. The source holds
// a reference while open, and every frame that borrows one of the buffers
// holds one more; the last to let go unmaps the buffers and closes the
// descriptor. So lent pixels stay valid after close(), and a late release
// hook never reaches a descriptor number that has since been reused for
// another file: the descriptor it uses is still this stream's own.
class Stream {
 public:
  explicit Stream(UniqueFd fd) : fd_(std::move(fd)) {}
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;

  [[nodiscard]] int fd() const noexcept { return fd_.get(); }

  void retain() noexcept { references_.fetch_add(1, std::memory_order_relaxed); }
  void release() noexcept {
    if (references_.fetch_sub(1, std::memory_order_acq_rel) == 1) delete this;
  }

  // Gives a buffer back to the driver; 0 or the errno.
  int queue(std::uint32_t index) noexcept {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    buffer.index = index;
    return xioctl(fd_.get(), VIDIOC_QBUF, &buffer) == 0 ? 0 : errno;
  }

  std::vector<MappedBuffer> buffers;
  // Cleared by close() before it stops streaming: from then on a buffer that
  // comes back from the pipeline is not queued again.
  std::atomic<bool> streaming{false};
  // The first errno of a failed requeue on a pipeline thread, reported by the
  // next wait_frame() on the capture thread.
  std::atomic<int> requeue_error{0};

 private:
  // The buffers are unmapped before the device is closed (fd_ goes after).
  ~Stream() {
    for (const auto& b : buffers) ::munmap(b.data, b.length);
  }

  UniqueFd fd_;
  std::atomic<int> references_{1};
};

// Holds the source's reference during open(), so that a failure part way
// closes everything opened so far.
class StreamHold {
 public:
  explicit StreamHold(Stream* stream) : stream_(stream) {}
  ~StreamHold() {
    if (stream_ != nullptr) stream_->release();
  }
  StreamHold(const StreamHold&) = delete;
  StreamHold& operator=(const StreamHold&) = delete;
  Stream* operator->() const { return stream_; }
  Stream& operator*() const { return *stream_; }
  Stream* give() { return std::exchange(stream_, nullptr); }

 private:
  Stream* stream_;
};

// A lent buffer's release hook (ReleaseHook::release), on whichever pipeline
// thread is last done with the frame.
void requeue_lent(void* context, std::uint64_t token) noexcept {
  auto* stream = static_cast<Stream*>(context);
  if (stream->streaming.load(std::memory_order_acquire)) {
    const int error = stream->queue(static_cast<std::uint32_t>(token));
    if (error != 0 && stream->streaming.load(std::memory_order_acquire)) {
      int none = 0;
      stream->requeue_error.compare_exchange_strong(none, error);
    }
  }
  stream->release();
}

Clock::time_point monotonic_time(const timeval& tv) {
  return Clock::time_point(std::chrono::duration_cast<Clock::duration>(std::chrono::seconds(tv.tv_sec) +
                                                                       std::chrono::microseconds(tv.tv_usec)));
}

// Bytes of a row the format's grey image reads: the Y bytes of a GREY or
// NV12 row, the Y and chroma bytes of a YUYV row; MJPEG has no rows.
std::size_t row_bytes(V4l2PixelFormat format, int width) {
  const auto w = static_cast<std::size_t>(width);
  switch (format) {
    case V4l2PixelFormat::grey:
    case V4l2PixelFormat::nv12: return w;
    case V4l2PixelFormat::yuyv: return 2 * w;
    case V4l2PixelFormat::mjpg: return 0;
  }
  return 0;
}

// ---------------------------------------------------------------- the source

class V4l2Source final : public CaptureSource {
 public:
  explicit V4l2Source(V4l2Settings settings)
      : settings_(std::move(settings)), name_("v4l2 " + settings_.device), label_(name_) {
    geometry_ = configured_geometry();
  }
  ~V4l2Source() override { V4l2Source::close(); }
  V4l2Source(const V4l2Source&) = delete;
  V4l2Source& operator=(const V4l2Source&) = delete;

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override { return geometry_; }
  [[nodiscard]] bool is_open() const noexcept override { return stream_ != nullptr; }

  void open() override;
  void close() noexcept override;
  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override;
  void fill(Frame& frame) override;
  void skip() noexcept override;

  [[nodiscard]] std::vector<CameraControlInfo> read_controls() override;
  void write_control(const CameraControlInfo& control, const ControlValue& value) override;

 private:
  [[nodiscard]] CaptureGeometry configured_geometry() const {
    const bool converts = settings_.format == V4l2PixelFormat::yuyv || settings_.format == V4l2PixelFormat::mjpg;
    return {settings_.width, settings_.height,
            converts ? static_cast<std::size_t>(settings_.width) * static_cast<std::size_t>(settings_.height) : 0,
            settings_.fps};
  }

  [[nodiscard]] CaptureError error(Kind kind, std::string_view what) const {
    return {kind, fmt::format("{}: {}", label_, what)};
  }
  // An ioctl that failed on the open device: ENODEV is the device gone.
  [[nodiscard]] CaptureError ioctl_error(std::string_view ioctl, int error_number) const {
    const Kind kind = error_number == ENODEV ? Kind::vanished : Kind::io;
    return error(kind, fmt::format("{}: {}", ioctl, errno_text(error_number)));
  }

  void check_capabilities(int fd);
  void select_input(int fd, int input);
  void set_format(int fd);
  void set_frame_rate(int fd);
  void set_controls(int fd);
  void map_buffers(Stream& stream);
  bool dequeue();
  void requeue(std::uint32_t index);
  void publish_corrupt(Frame& frame, const char* cause, std::uint32_t index);

  V4l2Settings settings_;
  std::string name_;
  std::string label_;  // the name, and the node it resolved to when that differs
  CaptureGeometry geometry_;
  std::ptrdiff_t stride_ = 0;  // bytes per row of the mmap buffers
  std::size_t min_bytes_ = 0;  // what a buffer must hold for fill() to read the frame

  // Held by open() and close() on the capture thread, and by the control
  // server's thread while it reads or writes a control: never by the frame
  // path (wait_frame, fill, skip), which reads stream_ on the thread that
  // alone changes it. V4L2's control ioctls are safe beside streaming.
  mutable std::mutex device_mutex_;
  Stream* stream_ = nullptr;
  // Controls set at run time (camera.set), set again after the config's at
  // every open. Under device_mutex_.
  std::vector<V4l2ControlSetting> set_at_run_time_;
  v4l2_buffer ready_{};
  bool has_ready_ = false;
  Clock::time_point ready_time_{};
  char cause_[Frame::kCauseCapacity] = {};
};

void V4l2Source::open() {
  close();
  const std::lock_guard lock(device_mutex_);
  geometry_ = configured_geometry();
  const fs::path path = resolve_v4l2_device(settings_.device);
  std::error_code ec;
  const fs::path node = fs::canonical(path, ec);
  label_ = !ec && node.string() != settings_.device ? fmt::format("{} ({})", name_, node.string()) : name_;

  UniqueFd device(::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC));
  if (!device) {
    const int e = errno;
    if (e == ENOENT || e == ENODEV || e == ENXIO) {
      throw error(Kind::not_found, fmt::format("cannot open {}: {} (not plugged in, or its driver not loaded)",
                                               path.string(), errno_text(e)));
    }
    throw error(Kind::io, fmt::format("cannot open {}: {}{}", path.string(), errno_text(e),
                                      e == EACCES ? " (is the user in the group that owns it, usually 'video'?)" : ""));
  }
  const int fd = device.get();
  StreamHold stream(new Stream(std::move(device)));
  check_capabilities(fd);
  if (settings_.input) select_input(fd, *settings_.input);
  set_format(fd);
  set_frame_rate(fd);
  set_controls(fd);
  map_buffers(*stream);
  for (std::uint32_t i = 0; i < stream->buffers.size(); ++i) {
    if (const int e = stream->queue(i); e != 0) throw ioctl_error(fmt::format("VIDIOC_QBUF buffer {}", i), e);
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd, VIDIOC_STREAMON, &type) != 0) throw ioctl_error("VIDIOC_STREAMON", errno);
  stream->streaming.store(true, std::memory_order_release);
  stream_ = stream.give();
}

void V4l2Source::check_capabilities(int fd) {
  v4l2_capability cap{};
  if (xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) {
    const int e = errno;
    if (e == ENOTTY || e == EINVAL) {
      throw error(Kind::config, fmt::format("not a V4L2 device (VIDIOC_QUERYCAP: {})", errno_text(e)));
    }
    throw ioctl_error("VIDIOC_QUERYCAP", e);
  }
  const std::uint32_t caps = device_caps(cap);
  const std::string what = fmt::format("'{}', driver {}", c_text(cap.card), c_text(cap.driver));
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0) {
    if ((caps & V4L2_CAP_VIDEO_CAPTURE_MPLANE) != 0) {
      throw error(Kind::config,
                  fmt::format("{} is a multi-planar capture device; markerd streams from single-planar ones", what));
    }
    throw error(Kind::config, fmt::format("{} is not a video capture device (a camera's other nodes are metadata "
                                          "or output: markerctl cameras lists the capture nodes)",
                                          what));
  }
  if ((caps & V4L2_CAP_STREAMING) == 0) {
    throw error(Kind::config, fmt::format("{} cannot stream (no V4L2_CAP_STREAMING)", what));
  }
}

void V4l2Source::select_input(int fd, int input) {
  if (xioctl(fd, VIDIOC_S_INPUT, &input) == 0) return;
  const int e = errno;
  if (e == EINVAL) {
    throw error(Kind::config, fmt::format("VIDIOC_S_INPUT {}: no such input (it has {})", input, input_list(fd)));
  }
  throw ioctl_error(fmt::format("VIDIOC_S_INPUT {}", input), e);
}

void V4l2Source::set_format(int fd) {
  const std::uint32_t fourcc = fourcc_of(settings_.format);
  const std::string asked = fmt::format("{} {}x{}", to_string(settings_.format), settings_.width, settings_.height);
  v4l2_format f{};
  f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  f.fmt.pix.width = static_cast<std::uint32_t>(settings_.width);
  f.fmt.pix.height = static_cast<std::uint32_t>(settings_.height);
  f.fmt.pix.pixelformat = fourcc;
  f.fmt.pix.field = V4L2_FIELD_NONE;
  if (xioctl(fd, VIDIOC_S_FMT, &f) != 0) {
    const int e = errno;
    if (e == EINVAL) {
      throw error(Kind::config,
                  fmt::format("VIDIOC_S_FMT {}: {} (it offers {})", asked, errno_text(e), offered_formats(fd)));
    }
    if (e == EBUSY) {
      throw error(Kind::io,
                  fmt::format("VIDIOC_S_FMT {}: {} (another program is streaming from it)", asked, errno_text(e)));
    }
    throw ioctl_error(fmt::format("VIDIOC_S_FMT {}", asked), e);
  }
  const auto& pix = f.fmt.pix;
  if (pix.pixelformat != fourcc || static_cast<int>(pix.width) != settings_.width ||
      static_cast<int>(pix.height) != settings_.height) {
    throw error(Kind::config, fmt::format("VIDIOC_S_FMT: asked for {}, the device gives {} {}x{} (it offers {})", asked,
                                          fourcc_text(pix.pixelformat), pix.width, pix.height, offered_formats(fd)));
  }
  const std::size_t row = row_bytes(settings_.format, settings_.width);
  stride_ = static_cast<std::ptrdiff_t>(pix.bytesperline != 0 ? pix.bytesperline : row);
  if (static_cast<std::size_t>(stride_) < row) {
    throw error(Kind::io, fmt::format("VIDIOC_S_FMT {}: the driver gives rows of {} bytes, fewer than a row's {}",
                                      asked, stride_, row));
  }
  // The last row needs only its own bytes, not the padding after it.
  min_bytes_ = row == 0 ? 1 : static_cast<std::size_t>(stride_) * static_cast<std::size_t>(settings_.height - 1) + row;
  geometry_.width = settings_.width;
  geometry_.height = settings_.height;
}

void V4l2Source::set_frame_rate(int fd) {
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd, VIDIOC_G_PARM, &parm) != 0) {
    if (errno == ENODEV) throw ioctl_error("VIDIOC_G_PARM", ENODEV);
    if (settings_.fps > 0) {
      spdlog::warn("{}: cannot set the frame rate to {} fps: VIDIOC_G_PARM: {}", label_, settings_.fps,
                   errno_text(errno));
    }
    geometry_.frame_rate = 0;
    return;
  }
  auto& capture = parm.parm.capture;
  if (settings_.fps > 0 && (capture.capability & V4L2_CAP_TIMEPERFRAME) != 0) {
    capture.timeperframe = {1000, static_cast<std::uint32_t>(std::lround(settings_.fps * 1000))};
    if (xioctl(fd, VIDIOC_S_PARM, &parm) != 0) {
      throw ioctl_error(fmt::format("VIDIOC_S_PARM {} fps", settings_.fps), errno);
    }
  }
  const auto& tpf = capture.timeperframe;
  geometry_.frame_rate = tpf.numerator != 0 ? static_cast<double>(tpf.denominator) / tpf.numerator : 0;
  if (settings_.fps > 0 && std::abs(geometry_.frame_rate - settings_.fps) > 0.01 * settings_.fps) {
    spdlog::warn("{}: asked for {} fps, the device runs at {}", label_, settings_.fps,
                 geometry_.frame_rate > 0 ? fmt::format("{:.4g} fps", geometry_.frame_rate)
                                          : std::string("a rate it does not tell"));
  }
}

// The value to write for a configured control; a config error when the
// device's control cannot take it.
std::int64_t control_value(const V4l2ControlSetting& setting, const V4l2ControlInfo& c, const std::string& label) {
  const ControlInput input = std::visit([](const auto& v) { return ControlInput(v); }, setting.value);
  ControlValue value;
  try {
    value = check_control_value(camera_control(c), input);
  } catch (const ControlValueError& e) {
    throw CaptureError(Kind::config,
                       fmt::format("{}: control {} ({}): {}", label, setting.name, setting.origin, e.what()));
  }
  if (const auto* b = std::get_if<bool>(&value)) return *b ? 1 : 0;
  return std::get<std::int64_t>(value);
}

void V4l2Source::set_controls(int fd) {
  // The config's, then those set at run time since markerd started, each
  // in place of the config's of its name.
  std::vector<V4l2ControlSetting> settings = settings_.controls;
  for (const auto& set : set_at_run_time_) {
    const auto it = std::find_if(settings.begin(), settings.end(), [&](const auto& s) { return s.name == set.name; });
    if (it == settings.end()) {
      settings.push_back(set);
    } else {
      *it = set;
    }
  }
  if (settings.empty()) return;
  const auto controls = enum_controls(fd);
  const auto find = [&](const std::string& name) -> const V4l2ControlInfo* {
    for (const auto& c : controls) {
      if (c.name == name) return &c;
    }
    return nullptr;
  };
  // Automatic modes first: exposure_time_absolute is refused or ignored
  // while auto_exposure still says automatic, whatever order the file has.
  std::vector<const V4l2ControlSetting*> order;
  for (const auto& s : settings) order.push_back(&s);
  std::stable_partition(order.begin(), order.end(),
                        [&](const V4l2ControlSetting* s) { return is_automatic_mode(s->name); });
  for (const auto* setting : order) {
    const auto* c = find(setting->name);
    if (c == nullptr) {
      std::string names;
      for (const auto& known : controls) names += fmt::format("{}{}", names.empty() ? "" : ", ", known.name);
      throw error(Kind::config, fmt::format("control {} ({}): the device has no such control (it has: {})",
                                            setting->name, setting->origin, names.empty() ? "none" : names));
    }
    const std::int64_t value = control_value(*setting, *c, label_);
    if (const int e = v4l2::write_control(fd, *c, value); e != 0) {
      const std::string what = fmt::format("control {} ({}) = {}: VIDIOC_S_EXT_CTRLS: {}", setting->name,
                                           setting->origin, value, errno_text(e));
      if (e == EACCES) throw error(Kind::config, what + " (the device refuses it now: an automatic mode holds it?)");
      if (e == EINVAL || e == ERANGE) throw error(Kind::config, what);
      throw error(e == ENODEV ? Kind::vanished : Kind::io, what);
    }
  }
}

std::vector<CameraControlInfo> V4l2Source::read_controls() {
  const std::lock_guard lock(device_mutex_);
  if (stream_ == nullptr) throw error(Kind::io, "not open: its controls are read while it streams");
  std::vector<CameraControlInfo> controls;
  for (const auto& c : enum_controls(stream_->fd())) controls.push_back(camera_control(c));
  return controls;
}

void V4l2Source::write_control(const CameraControlInfo& control, const ControlValue& value) {
  const std::lock_guard lock(device_mutex_);
  if (stream_ == nullptr) throw error(Kind::io, "not open: its controls are set while it streams");
  std::int64_t number = 0;
  if (const auto* b = std::get_if<bool>(&value)) {
    number = *b ? 1 : 0;
  } else if (const auto* i = std::get_if<std::int64_t>(&value)) {
    number = *i;
  } else {
    throw error(Kind::config,
                fmt::format("control {}: V4L2 controls take whole numbers, not {}", control.name, to_text(value)));
  }
  if (const int e = v4l2::write_control(stream_->fd(), control.id, control.type == "int64", number); e != 0) {
    std::string what = fmt::format("control {} = {}: VIDIOC_S_EXT_CTRLS: {}", control.name, number, errno_text(e));
    if (e == EACCES) what += " (the device refuses it now: an automatic mode holds it?)";
    if (e == EBUSY) what += " (the device cannot change it while streaming)";
    throw error(e == ENODEV ? Kind::vanished : Kind::config, what);
  }
  V4l2ControlSetting setting;
  setting.name = control.name;
  if (const auto* b = std::get_if<bool>(&value)) {
    setting.value = *b;
  } else {
    setting.value = number;
  }
  setting.origin = "set at run time (camera.set)";
  const auto it = std::find_if(set_at_run_time_.begin(), set_at_run_time_.end(),
                               [&](const auto& s) { return s.name == control.name; });
  if (it == set_at_run_time_.end()) {
    set_at_run_time_.push_back(std::move(setting));
  } else {
    *it = std::move(setting);
  }
}

void V4l2Source::map_buffers(Stream& stream) {
  v4l2_requestbuffers request{};
  request.count = static_cast<std::uint32_t>(settings_.buffers);
  request.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  request.memory = V4L2_MEMORY_MMAP;
  if (xioctl(stream.fd(), VIDIOC_REQBUFS, &request) != 0) {
    const int e = errno;
    if (e == EINVAL) {
      throw error(Kind::config, fmt::format("VIDIOC_REQBUFS {}: {} (it cannot stream through mmap buffers)",
                                            settings_.buffers, errno_text(e)));
    }
    if (e == EBUSY) {
      throw error(Kind::io, fmt::format("VIDIOC_REQBUFS {}: {} (another program is streaming from it)",
                                        settings_.buffers, errno_text(e)));
    }
    throw ioctl_error(fmt::format("VIDIOC_REQBUFS {}", settings_.buffers), e);
  }
  if (request.count == 0) throw error(Kind::io, "VIDIOC_REQBUFS: the driver gave no buffers");
  stream.buffers.reserve(request.count);
  for (std::uint32_t i = 0; i < request.count; ++i) {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    buffer.index = i;
    if (xioctl(stream.fd(), VIDIOC_QUERYBUF, &buffer) != 0) {
      throw ioctl_error(fmt::format("VIDIOC_QUERYBUF buffer {}", i), errno);
    }
    if (buffer.length < min_bytes_) {
      throw error(Kind::io, fmt::format("buffer {} holds {} bytes, fewer than a {} frame's {}", i, buffer.length,
                                        to_string(settings_.format), min_bytes_));
    }
    void* data = ::mmap(nullptr, buffer.length, PROT_READ, MAP_SHARED, stream.fd(), buffer.m.offset);
    if (data == MAP_FAILED) throw ioctl_error(fmt::format("mmap buffer {}", i), errno);
    stream.buffers.push_back({static_cast<std::uint8_t*>(data), buffer.length});
  }
}

void V4l2Source::close() noexcept {
  has_ready_ = false;
  const std::lock_guard lock(device_mutex_);
  if (stream_ == nullptr) return;
  stream_->streaming.store(false, std::memory_order_release);
  // Both fail with ENODEV on a device that is gone, which changes nothing.
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  xioctl(stream_->fd(), VIDIOC_STREAMOFF, &type);
  // Gives up the queue, so that the next open() can take it while frames
  // still borrow these buffers: videobuf2 keeps the memory of a buffer that
  // is still mapped (it orphans it) until the mapping goes.
  v4l2_requestbuffers none{};
  none.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  none.memory = V4L2_MEMORY_MMAP;
  xioctl(stream_->fd(), VIDIOC_REQBUFS, &none);
  std::exchange(stream_, nullptr)->release();
}

bool V4l2Source::dequeue() {
  v4l2_buffer buffer{};
  buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buffer.memory = V4L2_MEMORY_MMAP;
  if (xioctl(stream_->fd(), VIDIOC_DQBUF, &buffer) != 0) {
    const int e = errno;
    if (e == EAGAIN) return false;
    if (e == EIO) throw error(Kind::io, "VIDIOC_DQBUF: the driver reports a streaming error (EIO)");
    throw ioctl_error("VIDIOC_DQBUF", e);
  }
  if (buffer.index >= stream_->buffers.size()) {
    throw error(Kind::io, fmt::format("VIDIOC_DQBUF: buffer index {} of {}", buffer.index, stream_->buffers.size()));
  }
  ready_ = buffer;
  ready_time_ = Clock::now();
  has_ready_ = true;
  return true;
}

bool V4l2Source::wait_frame(std::chrono::milliseconds timeout) {
  if (stream_ == nullptr) throw std::logic_error(name_ + ": wait_frame() while not open");
  if (has_ready_) return true;
  if (const int e = stream_->requeue_error.exchange(0); e != 0) {
    throw ioctl_error("VIDIOC_QBUF of a buffer back from the pipeline", e);
  }
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    // A frame may be done already: then there is no need to poll.
    if (dequeue()) return true;
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return false;
    pollfd p{stream_->fd(), POLLIN, 0};
    const int n = ::poll(&p, 1, static_cast<int>(left.count()));
    if (n < 0) {
      if (errno == EINTR) continue;
      throw ioctl_error("poll", errno);
    }
    if (n == 0) return false;
    if ((p.revents & POLLIN) == 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
      if (dequeue()) return true;
      // videobuf2 and the V4L2 core say POLLERR when the device is
      // unregistered or the queue stopped; DQBUF normally names which.
      throw error(Kind::vanished, fmt::format("poll reports {} and no frame is ready: the device stopped streaming "
                                              "or went away",
                                              (p.revents & POLLHUP) != 0 ? "POLLHUP" : "POLLERR"));
    }
  }
}

void V4l2Source::requeue(std::uint32_t index) {
  if (const int e = stream_->queue(index); e != 0) throw ioctl_error("VIDIOC_QBUF", e);
}

void V4l2Source::publish_corrupt(Frame& frame, const char* cause, std::uint32_t index) {
  frame.mark_corrupt(cause);
  requeue(index);
}

void V4l2Source::fill(Frame& frame) {
  if (!has_ready_) throw std::logic_error(name_ + ": fill() without a frame from wait_frame()");
  has_ready_ = false;
  const v4l2_buffer& b = ready_;
  frame.sequence = b.sequence;
  frame.capture_time = (b.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
                           ? monotonic_time(b.timestamp)
                           : ready_time_;
  const MappedBuffer& buffer = stream_->buffers[b.index];
  const std::size_t bytes = std::min<std::size_t>(b.bytesused, buffer.length);
  if ((b.flags & V4L2_BUF_FLAG_ERROR) != 0) {
    publish_corrupt(frame, "the driver marked the frame broken (V4L2_BUF_FLAG_ERROR)", b.index);
    return;
  }
  if (bytes < min_bytes_) {
    std::snprintf(cause_, sizeof cause_, "short frame: %zu bytes, a %dx%d %s frame needs %zu", bytes, settings_.width,
                  settings_.height, to_string(settings_.format).data(), min_bytes_);
    publish_corrupt(frame, cause_, b.index);
    return;
  }
  const int w = settings_.width;
  const int h = settings_.height;
  if (settings_.format == V4l2PixelFormat::grey || settings_.format == V4l2PixelFormat::nv12) {
    // The grey image is the buffer itself (NV12's Y plane comes first).
    frame.image = detector::GreyView{buffer.data, w, h, stride_};
    stream_->retain();
    frame.set_release({&requeue_lent, stream_, b.index});
    return;
  }
  try {
    frame.use_pixel_buffer(w, h);
  } catch (const std::length_error& e) {
    // The frame pool was made for another size: no reopen mends that.
    stream_->queue(b.index);
    throw error(Kind::config, e.what());
  }
  if (settings_.format == V4l2PixelFormat::mjpg) {
    // Lent still encoded: the worker that detects the frame decodes it into
    // the slot's pixels and gives the buffer back (Frame::set_encoded).
    frame.set_encoded({buffer.data, bytes}, &decode_mjpeg_frame);
    stream_->retain();
    frame.set_release({&requeue_lent, stream_, b.index});
    return;
  }
  yuyv_to_grey(buffer.data, stride_, w, h, frame.pixel_buffer().data(), w);
  requeue(b.index);
}

void V4l2Source::skip() noexcept {
  if (!has_ready_ || stream_ == nullptr) return;
  has_ready_ = false;
  if (const int e = stream_->queue(ready_.index); e != 0) {
    int none = 0;
    stream_->requeue_error.compare_exchange_strong(none, e);
  }
}

}  // namespace

std::unique_ptr<CaptureSource> make_v4l2_source(const V4l2Settings& settings) {
  return std::make_unique<V4l2Source>(settings);
}

fs::path resolve_v4l2_device(std::string_view device, const fs::path& dev_dir) {
  if (device.empty()) throw CaptureError(Kind::config, "v4l2: no device given");
  if (device.find('/') != std::string_view::npos) return fs::path(device);
  std::vector<fs::path> tried;
  for (const fs::path& dir : {dev_dir / "v4l" / "by-id", dev_dir / "v4l" / "by-path", dev_dir}) {
    fs::path candidate = dir / device;
    std::error_code ec;
    if (fs::exists(fs::symlink_status(candidate, ec))) return candidate;
    tried.push_back(std::move(candidate));
  }
  throw CaptureError(Kind::not_found,
                     fmt::format("v4l2 {}: no such device: none of {}, {}, {} exists (not plugged in, or named "
                                 "otherwise: markerctl cameras lists the names)",
                                 device, tried[0].string(), tried[1].string(), tried[2].string()));
}

}  // namespace markerd::daemon
