#include "markerd/daemon/capture/libcamera_source.hpp"

#include <sys/mman.h>

#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/control_ids.h>
#include <libcamera/controls.h>
#include <libcamera/formats.h>
#include <libcamera/framebuffer.h>
#include <libcamera/framebuffer_allocator.h>
#include <libcamera/request.h>
#include <libcamera/stream.h>

#include <fmt/format.h>
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <utility>

#include "libcamera_support.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/daemon/capture/pixel_convert.hpp"

namespace markerd::daemon {

namespace {

using libcamera::Camera;
using libcamera::CameraManager;
using namespace libcam;

// ---------------------------------------------------------------- a streaming session

// Everything one open() sets up: the acquired camera, its buffers and their
// mappings, the requests, and the queue of completed ones. The source owns
// it while open; a frame that borrows a buffer's Y plane owns it too, until
// its release hook has run, so that the mapping it points into (and the
// camera, which must not be released with buffers allocated) outlives
// close().
class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(std::shared_ptr<CameraManager> manager, std::string name)
      : manager_(std::move(manager)), name_(std::move(name)) {}
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;
  ~Session() { teardown(); }

  void open(const LibcameraSettings& settings);
  // Stops streaming: no request is queued again after this, and every
  // queued one has come back (cancelled).
  void stop() noexcept;

  // ---- the capture thread ----
  // The index of the next completed request, nothing after `timeout`.
  std::optional<std::uint32_t> wait(std::chrono::milliseconds timeout);
  void fill(std::uint32_t index, Frame& frame);
  void requeue(std::uint32_t index) noexcept;

  [[nodiscard]] const std::string& camera_id() const { return camera_id_; }

  // ---- any thread, while open ----
  // The camera's controls and their ranges (fixed once configured).
  [[nodiscard]] const libcamera::ControlInfoMap& controls() const { return camera_->controls(); }
  // The control goes with the next request queued.
  void set_control(unsigned int id, const libcamera::ControlValue& value);

 private:
  struct Mapping {
    void* address = MAP_FAILED;
    std::size_t length = 0;
  };
  struct Slot {
    std::unique_ptr<libcamera::Request> request;
    const libcamera::FrameBuffer* buffer = nullptr;
    const std::uint8_t* pixels = nullptr;  // the first plane: Y of NV12, the whole image of R8, YUYV and MJPEG
    std::size_t length = 0;                // the first plane's bytes
    std::shared_ptr<Session> lent_to;      // set while a frame borrows the slot's pixels
  };

  // The frame borrows the slot's buffer until the pipeline is done with it.
  void lend(std::uint32_t index, Frame& frame);
  static void release_lent(void* context, std::uint64_t token) noexcept;

  void find_camera(const LibcameraSettings& settings);
  void configure(const LibcameraSettings& settings);
  void allocate_and_map();
  libcamera::ControlList start_controls(const LibcameraSettings& settings) const;
  void teardown() noexcept;

  // Signal handlers, on libcamera's thread.
  void on_request_completed(libcamera::Request* request);
  void on_disconnected();
  void on_camera_removed(std::shared_ptr<Camera> camera);

  [[noreturn]] void fail(CaptureError::Kind kind, const std::string& message) const {
    throw CaptureError(kind, fmt::format("{}: {}", name_, message));
  }

  // Destroyed last: the camera and everything from it go first.
  std::shared_ptr<CameraManager> manager_;
  std::string name_;
  std::string camera_id_;
  std::shared_ptr<Camera> camera_;
  bool acquired_ = false;
  bool connected_ = false;
  bool started_ = false;
  std::unique_ptr<libcamera::CameraConfiguration> config_;
  libcamera::Stream* stream_ = nullptr;
  LibcameraPixelFormat format_ = LibcameraPixelFormat::yuyv;
  int width_ = 0;
  int height_ = 0;
  std::size_t stride_ = 0;
  std::size_t first_plane_bytes_ = 0;  // what a frame's first plane must hold (MJPEG: any length)
  std::unique_ptr<libcamera::FrameBufferAllocator> allocator_;
  std::vector<Mapping> mappings_;
  std::vector<Slot> slots_;

  // Requeueing against stopping: a release hook on another thread never
  // queues a request once stop() has begun.
  std::mutex requeue_mutex_;
  bool running_ = false;
  // Controls set at run time, for the next request queued; under requeue_mutex_.
  std::optional<libcamera::ControlList> pending_;

  // Completed requests, from libcamera's thread to the capture thread: a
  // ring with room for every request (each is in it at most once), so
  // pushing never fails and nothing allocates once open.
  std::mutex completed_mutex_;
  std::condition_variable completed_ready_;
  std::vector<std::uint32_t> completed_;
  std::size_t completed_head_ = 0;
  std::size_t completed_count_ = 0;
  bool vanished_ = false;
};

void Session::open(const LibcameraSettings& settings) {
  find_camera(settings);
  configure(settings);
  allocate_and_map();
  const libcamera::ControlList controls = start_controls(settings);
  pending_.emplace(camera_->controls());

  camera_->requestCompleted.connect(this, &Session::on_request_completed);
  camera_->disconnected.connect(this, &Session::on_disconnected);
  manager_->cameraRemoved.connect(this, &Session::on_camera_removed);
  connected_ = true;

  if (const int ret = camera_->start(&controls); ret < 0) {
    fail(CaptureError::Kind::io, fmt::format("cannot start streaming: {}", errno_text(-ret)));
  }
  started_ = true;
  {
    const std::lock_guard lock(requeue_mutex_);
    running_ = true;
  }
  // Some pipeline handlers ignore the controls given to start(): 0.0.3's UVC
  // handler applies only a request's own (found against a real uvcvideo
  // camera in the HIL guest, tests/hil/test_uvc_hil.cpp). The first request
  // carries them too; the device keeps them for the requests after it.
  if (!slots_.empty()) slots_.front().request->controls().merge(controls);
  for (auto& slot : slots_) {
    if (const int ret = camera_->queueRequest(slot.request.get()); ret < 0) {
      fail(CaptureError::Kind::io, fmt::format("cannot queue a request: {}", errno_text(-ret)));
    }
  }
}

void Session::find_camera(const LibcameraSettings& settings) {
  if (settings.camera.empty()) {
    const auto cameras = manager_->cameras();
    if (cameras.empty()) fail(CaptureError::Kind::not_found, "libcamera finds no camera");
    camera_ = cameras.front();
  } else {
    camera_ = manager_->get(settings.camera);
    if (!camera_) {
      fail(CaptureError::Kind::not_found,
           fmt::format("no camera '{}' (libcamera's cameras: {})", settings.camera, camera_ids(*manager_)));
    }
  }
  camera_id_ = camera_->id();
  if (const int ret = camera_->acquire(); ret < 0) {
    fail(CaptureError::Kind::io, fmt::format("cannot acquire camera '{}': {}{}", camera_id_, errno_text(-ret),
                                             ret == -EBUSY ? " (another process or source has it)" : ""));
  }
  acquired_ = true;
}

void Session::configure(const LibcameraSettings& settings) {
  config_ = generate_configuration(*camera_);
  if (!config_) fail(CaptureError::Kind::config, fmt::format("camera '{}' offers no video stream", camera_id_));
  libcamera::StreamConfiguration& stream_config = config_->at(0);
  const libcamera::PixelFormat wanted_format = pixel_format_of(settings.format);
  const libcamera::Size wanted_size(static_cast<unsigned>(settings.width), static_cast<unsigned>(settings.height));
  const std::string offered = offered_formats(stream_config.formats());
  stream_config.pixelFormat = wanted_format;
  stream_config.size = wanted_size;
  stream_config.bufferCount = static_cast<unsigned>(settings.buffers);

  const auto status = config_->validate();
  const auto asked = fmt::format("{} {}x{}", to_string(settings.format), settings.width, settings.height);
  if (status == libcamera::CameraConfiguration::Invalid) {
    fail(CaptureError::Kind::config,
         fmt::format("camera '{}' cannot stream {} (it offers: {})", camera_id_, asked, offered));
  }
  // An adjusted buffer count or colour space is fine; another format or
  // size is not what the config asks for.
  if (stream_config.pixelFormat != wanted_format || stream_config.size != wanted_size) {
    fail(CaptureError::Kind::config,
         fmt::format("camera '{}' cannot stream {}: the nearest it offers is {} {} (it offers: {})", camera_id_, asked,
                     stream_config.pixelFormat.toString(), stream_config.size.toString(), offered));
  }
  if (const int ret = camera_->configure(config_.get()); ret < 0) {
    fail(CaptureError::Kind::io, fmt::format("cannot configure {}: {}", asked, errno_text(-ret)));
  }
  stream_ = stream_config.stream();
  format_ = settings.format;
  width_ = settings.width;
  height_ = settings.height;
  if (format_ == LibcameraPixelFormat::mjpeg) {
    // No rows to check: each frame is as long as its JPEG, and the decoder
    // says what is wrong with one too short.
    first_plane_bytes_ = 0;
    return;
  }
  const std::size_t row_bytes = static_cast<std::size_t>(width_) * (format_ == LibcameraPixelFormat::yuyv ? 2 : 1);
  stride_ = stream_config.stride != 0 ? stream_config.stride : row_bytes;
  if (stride_ < row_bytes) {
    fail(CaptureError::Kind::config,
         fmt::format("camera '{}' reports rows of {} bytes for {}: too short", camera_id_, stride_, asked));
  }
  first_plane_bytes_ = stride_ * static_cast<std::size_t>(height_ - 1) + row_bytes;
}

void Session::allocate_and_map() {
  allocator_ = std::make_unique<libcamera::FrameBufferAllocator>(camera_);
  if (const int ret = allocator_->allocate(stream_); ret < 0) {
    fail(CaptureError::Kind::io, fmt::format("cannot allocate buffers: {}", errno_text(-ret)));
  }
  const auto& buffers = allocator_->buffers(stream_);
  slots_.resize(buffers.size());
  for (std::size_t i = 0; i < buffers.size(); ++i) {
    const libcamera::FrameBuffer& buffer = *buffers[i];
    const auto& planes = buffer.planes();
    if (planes.empty()) fail(CaptureError::Kind::io, "a buffer without planes");
    const auto& first = planes.front();
    if (first.offset == libcamera::FrameBuffer::Plane::kInvalidOffset || first.length < first_plane_bytes_) {
      fail(CaptureError::Kind::io, fmt::format("buffer {}: its first plane holds {} bytes, a frame needs {}", i,
                                               first.length, first_plane_bytes_));
    }
    // Planes of one buffer may share a dmabuf (NV12's Y and UV at two
    // offsets): the first plane's descriptor is mapped from 0 to the end of
    // the furthest plane in it.
    std::size_t length = 0;
    for (const auto& plane : planes) {
      if (plane.fd.get() == first.fd.get()) {
        length = std::max(length, static_cast<std::size_t>(plane.offset) + plane.length);
      }
    }
    void* address = ::mmap(nullptr, length, PROT_READ, MAP_SHARED, first.fd.get(), 0);
    if (address == MAP_FAILED) {
      fail(CaptureError::Kind::io, fmt::format("cannot map buffer {}: {}", i, errno_text(errno)));
    }
    mappings_.push_back({address, length});

    Slot& slot = slots_[i];
    slot.buffer = &buffer;
    slot.pixels = static_cast<const std::uint8_t*>(address) + first.offset;
    slot.length = first.length;
    slot.request = camera_->createRequest(i);
    if (!slot.request) fail(CaptureError::Kind::io, "cannot create a request");
    if (const int ret = slot.request->addBuffer(stream_, buffers[i].get()); ret < 0) {
      fail(CaptureError::Kind::io, fmt::format("cannot add buffer {} to its request: {}", i, errno_text(-ret)));
    }
  }
  completed_.assign(slots_.size(), 0);
}

libcamera::ControlList Session::start_controls(const LibcameraSettings& settings) const {
  const libcamera::ControlInfoMap& available = camera_->controls();
  libcamera::ControlList controls(available);
  for (const auto& setting : settings.controls) {
    const libcamera::ControlId* id = find_control(available, setting.name);
    if (id == nullptr) {
      throw CaptureError(CaptureError::Kind::config,
                         fmt::format("{}: camera '{}' has no control {} (its controls: {})", setting.origin, camera_id_,
                                     setting.name, control_names(available)));
    }
    const libcamera::ControlInfo& info = available.at(id);
    libcamera::ControlValue value;
    switch (id->type()) {
      case libcamera::ControlTypeBool: value = libcamera::ControlValue(std::get<bool>(setting.value)); break;
      case libcamera::ControlTypeInteger32:
        value = libcamera::ControlValue(static_cast<std::int32_t>(std::get<std::int64_t>(setting.value)));
        break;
      case libcamera::ControlTypeInteger64:
        value = libcamera::ControlValue(std::get<std::int64_t>(setting.value));
        break;
      case libcamera::ControlTypeFloat:
        value = libcamera::ControlValue(static_cast<float>(std::get<double>(setting.value)));
        break;
      default:
        // parse_libcamera_settings admits no other type.
        throw CaptureError(CaptureError::Kind::config, fmt::format("{}: a {} control cannot be set from the config",
                                                                   setting.origin, type_name(id->type())));
    }
    if (!info.values().empty()) {
      if (std::find(info.values().begin(), info.values().end(), value) == info.values().end()) {
        std::string allowed;
        for (const auto& v : info.values()) allowed += fmt::format("{}{}", allowed.empty() ? "" : ", ", v.toString());
        throw CaptureError(CaptureError::Kind::config,
                           fmt::format("{}: {} is not one of camera '{}''s values for {}: {}", setting.origin,
                                       text_of(setting.value), camera_id_, setting.name, allowed));
      }
    } else {
      const auto wanted = number_of(value);
      const auto min = number_of(info.min());
      const auto max = number_of(info.max());
      if (wanted && ((min && *wanted < *min) || (max && *wanted > *max))) {
        throw CaptureError(CaptureError::Kind::config,
                           fmt::format("{}: {} is outside camera '{}''s range for {}: {}", setting.origin,
                                       text_of(setting.value), camera_id_, setting.name, info.toString()));
      }
    }
    controls.set(id->id(), value);
  }

  if (settings.fps > 0) {
    const auto& limits = libcamera::controls::FrameDurationLimits;
    const auto found = available.find(limits.id());
    if (found == available.end()) {
      throw CaptureError(CaptureError::Kind::config,
                         fmt::format("{}: camera '{}' has no FrameDurationLimits control, so its frame rate cannot "
                                     "be set (leave fps out to take its own)",
                                     name_, camera_id_));
    }
    const auto frame_us = static_cast<std::int64_t>(std::llround(1e6 / settings.fps));
    const auto min = number_of(found->second.min());
    const auto max = number_of(found->second.max());
    if ((min && static_cast<double>(frame_us) < *min) || (max && static_cast<double>(frame_us) > *max)) {
      throw CaptureError(CaptureError::Kind::config,
                         fmt::format("{}: {} fps is a frame duration of {} us, outside camera '{}''s range {}", name_,
                                     settings.fps, frame_us, camera_id_, found->second.toString()));
    }
    controls.set(limits, {frame_us, frame_us});
  }
  return controls;
}

void Session::stop() noexcept {
  {
    const std::lock_guard lock(requeue_mutex_);
    running_ = false;
  }
  if (started_) {
    // Blocking: the queued requests come back cancelled through
    // on_request_completed before it returns.
    camera_->stop();
    started_ = false;
  }
  if (connected_) {
    camera_->requestCompleted.disconnect(this);
    camera_->disconnected.disconnect(this);
    manager_->cameraRemoved.disconnect(this);
    connected_ = false;
  }
  const std::lock_guard lock(completed_mutex_);
  completed_count_ = 0;
}

void Session::teardown() noexcept {
  stop();
  // Requests before the buffers they hold, the mappings before the buffers
  // they map, the buffers before the camera is released.
  slots_.clear();
  for (const auto& mapping : mappings_) ::munmap(mapping.address, mapping.length);
  mappings_.clear();
  allocator_.reset();
  config_.reset();
  if (acquired_) {
    camera_->release();
    acquired_ = false;
  }
  camera_.reset();
}

std::optional<std::uint32_t> Session::wait(std::chrono::milliseconds timeout) {
  std::unique_lock lock(completed_mutex_);
  completed_ready_.wait_for(lock, timeout, [&] { return completed_count_ > 0 || vanished_; });
  if (vanished_) fail(CaptureError::Kind::vanished, fmt::format("camera '{}' is gone (disconnected)", camera_id_));
  if (completed_count_ == 0) return std::nullopt;
  const std::uint32_t index = completed_[completed_head_];
  completed_head_ = (completed_head_ + 1) % completed_.size();
  --completed_count_;
  return index;
}

void Session::fill(std::uint32_t index, Frame& frame) {
  Slot& slot = slots_[index];
  const libcamera::FrameMetadata& metadata = slot.buffer->metadata();
  frame.sequence = metadata.sequence;
  // libcamera stamps buffers on CLOCK_MONOTONIC, the pipeline's Clock.
  if (metadata.timestamp != 0) {
    frame.capture_time = Clock::time_point(std::chrono::duration_cast<Clock::duration>(
        std::chrono::nanoseconds(static_cast<std::int64_t>(metadata.timestamp))));
  }

  std::size_t bytes_used = 0;
  for (const auto& plane : metadata.planes()) bytes_used += plane.bytesused;
  if (slot.request->status() == libcamera::Request::RequestCancelled ||
      metadata.status == libcamera::FrameMetadata::FrameCancelled) {
    // While streaming, a request comes back cancelled only when the camera
    // refused its buffer: a camera pulled out refuses every one until
    // libcamera hears of the removal from udev, and queueing them again
    // would spin (measured: 77000 a minute, each a corrupt frame).
    fail(CaptureError::Kind::vanished,
         fmt::format("camera '{}' cancelled frame {}: it takes no more buffers (unplugged?)", camera_id_,
                     static_cast<std::int64_t>(static_cast<std::int32_t>(metadata.sequence))));
  }
  if (metadata.status == libcamera::FrameMetadata::FrameError) {
    mark_corrupt(frame, "libcamera camera '{}': frame {} has an error", camera_id_, metadata.sequence);
  } else if (bytes_used < first_plane_bytes_) {
    mark_corrupt(frame, "libcamera camera '{}': frame {} holds {} bytes, a {}x{} {} frame needs {}", camera_id_,
                 metadata.sequence, bytes_used, width_, height_, to_string(format_), first_plane_bytes_);
  } else if (format_ == LibcameraPixelFormat::yuyv || format_ == LibcameraPixelFormat::mjpeg) {
    detector::GreyView grey;
    try {
      grey = frame.use_pixel_buffer(width_, height_);
    } catch (const std::length_error& e) {
      requeue(index);
      fail(CaptureError::Kind::config, e.what());
    }
    if (format_ == LibcameraPixelFormat::mjpeg) {
      // Lent still encoded: the worker that detects the frame decodes it
      // into the slot's pixels and the request goes back then
      // (Frame::set_encoded).
      frame.set_encoded({slot.pixels, std::min(bytes_used, slot.length)}, &decode_mjpeg_frame);
      lend(index, frame);
      return;
    }
    yuyv_to_grey(slot.pixels, static_cast<std::ptrdiff_t>(stride_), width_, height_, frame.pixel_buffer().data(),
                 grey.stride);
  } else {
    // The Y plane (NV12) or the whole image (R8), lent: the request goes
    // back when the pipeline is done with the frame.
    frame.image = detector::GreyView{slot.pixels, width_, height_, static_cast<std::ptrdiff_t>(stride_)};
    lend(index, frame);
    return;
  }
  requeue(index);
}

void Session::lend(std::uint32_t index, Frame& frame) {
  slots_[index].lent_to = shared_from_this();
  frame.set_release(ReleaseHook{&Session::release_lent, this, index});
}

void Session::release_lent(void* context, std::uint64_t token) noexcept {
  auto* session = static_cast<Session*>(context);
  const auto index = static_cast<std::uint32_t>(token);
  // Possibly the last owner, after close(): the session goes with it, once
  // the request is dealt with.
  const std::shared_ptr<Session> keep = std::move(session->slots_[index].lent_to);
  session->requeue(index);
}

void Session::requeue(std::uint32_t index) noexcept {
  const std::lock_guard lock(requeue_mutex_);
  if (!running_) return;
  libcamera::Request& request = *slots_[index].request;
  request.reuse(libcamera::Request::ReuseBuffers);
  if (pending_ && !pending_->empty()) {
    request.controls().merge(*pending_);
    pending_->clear();
  }
  // A failure here (the camera going away) shows as the request not coming
  // back; the camera's disconnection is reported by wait().
  (void)camera_->queueRequest(&request);
}

void Session::set_control(unsigned int id, const libcamera::ControlValue& value) {
  const std::lock_guard lock(requeue_mutex_);
  if (pending_) pending_->set(id, value);
}

void Session::on_request_completed(libcamera::Request* request) {
  const std::lock_guard lock(completed_mutex_);
  if (completed_count_ < completed_.size()) {
    const std::size_t tail = (completed_head_ + completed_count_) % completed_.size();
    completed_[tail] = static_cast<std::uint32_t>(request->cookie());
    ++completed_count_;
  }
  completed_ready_.notify_one();
}

void Session::on_disconnected() {
  const std::lock_guard lock(completed_mutex_);
  vanished_ = true;
  completed_ready_.notify_one();
}

void Session::on_camera_removed(std::shared_ptr<Camera> camera) {
  if (camera.get() == camera_.get()) on_disconnected();
}

// ---------------------------------------------------------------- the source

class LibcameraSource final : public CaptureSource {
 public:
  explicit LibcameraSource(LibcameraSettings settings) : settings_(std::move(settings)) {
    name_ = fmt::format("libcamera {} {} {}x{}", settings_.camera.empty() ? "(first camera)" : settings_.camera,
                        to_string(settings_.format), settings_.width, settings_.height);
    if (settings_.fps > 0) name_ += fmt::format("@{}", settings_.fps);
    for (const auto& c : settings_.controls) {
      asked_[c.name] = std::visit([](auto v) { return ControlValue(v); }, c.value);
    }
  }
  ~LibcameraSource() override { close(); }
  LibcameraSource(const LibcameraSource&) = delete;
  LibcameraSource& operator=(const LibcameraSource&) = delete;

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override {
    const bool converted =
        settings_.format == LibcameraPixelFormat::yuyv || settings_.format == LibcameraPixelFormat::mjpeg;
    return CaptureGeometry{
        settings_.width, settings_.height,
        converted ? static_cast<std::size_t>(settings_.width) * static_cast<std::size_t>(settings_.height) : 0,
        settings_.fps};
  }

  void open() override {
    close();
    // The config's controls, then those set at run time since markerd
    // started, each in place of the config's of its name.
    LibcameraSettings settings = settings_;
    {
      const std::lock_guard lock(controls_mutex_);
      for (const auto& set : set_at_run_time_) {
        const auto it = std::find_if(settings.controls.begin(), settings.controls.end(),
                                     [&](const auto& c) { return c.name == set.name; });
        if (it == settings.controls.end()) {
          settings.controls.push_back(set);
        } else {
          *it = set;
        }
      }
    }
    auto session = std::make_shared<Session>(shared_camera_manager(), name_);
    session->open(settings);
    const std::lock_guard lock(controls_mutex_);
    session_ = std::move(session);
  }

  void close() noexcept override {
    ready_.reset();
    std::shared_ptr<Session> session;
    {
      const std::lock_guard lock(controls_mutex_);
      session = std::move(session_);
    }
    if (!session) return;
    session->stop();
    // Frames still borrowing its buffers keep the session (and the camera)
    // until their release hooks have run.
  }

  [[nodiscard]] std::vector<CameraControlInfo> read_controls() override;
  void write_control(const CameraControlInfo& control, const ControlValue& value) override;

  [[nodiscard]] bool is_open() const noexcept override { return session_ != nullptr; }

  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override {
    if (!session_) throw CaptureError(CaptureError::Kind::io, fmt::format("{}: wait_frame() while closed", name_));
    if (ready_) return true;
    ready_ = session_->wait(timeout);
    return ready_.has_value();
  }

  void fill(Frame& frame) override {
    if (!session_ || !ready_) {
      throw CaptureError(CaptureError::Kind::io, fmt::format("{}: fill() without a ready frame", name_));
    }
    const std::uint32_t index = *ready_;
    ready_.reset();
    session_->fill(index, frame);
  }

  void skip() noexcept override {
    if (session_ && ready_) session_->requeue(*ready_);
    ready_.reset();
  }

 private:
  // The session while open, for the control server's thread: taken under
  // controls_mutex_ there; the capture thread, which alone changes it,
  // reads it without.
  [[nodiscard]] std::shared_ptr<Session> open_session(std::string_view doing) const {
    const std::lock_guard lock(controls_mutex_);
    if (!session_) {
      throw CaptureError(CaptureError::Kind::io,
                         fmt::format("{}: not open: its controls are {} while it streams", name_, doing));
    }
    return session_;
  }

  LibcameraSettings settings_;
  std::string name_;
  mutable std::mutex controls_mutex_;  // guards session_'s changes and the two below
  std::shared_ptr<Session> session_;
  // Controls set at run time (camera.set), set again at every open.
  std::vector<LibcameraControlSetting> set_at_run_time_;
  // What markerd asked each control for, by the config or at run time:
  // libcamera reports no current values outside a request's metadata.
  std::map<std::string, ControlValue, std::less<>> asked_;
  std::optional<std::uint32_t> ready_;  // a completed request, waiting for fill() or skip()
};

// Arrays and the frame rate are not markerd's to set here.
std::string why_not_settable(const libcamera::ControlId& id) {
  if (id.id() == libcamera::controls::FrameDurationLimits.id()) {
    return "set the frame rate with [camera.libcamera] fps";
  }
  if (id.name() == "ColourGains" || id.name() == "ColourCorrectionMatrix" || id.name() == "SensorBlackLevels") {
    return "an array control: markerd sets single values only";
  }
  switch (id.type()) {
    case libcamera::ControlTypeBool:
    case libcamera::ControlTypeByte:
    case libcamera::ControlTypeInteger32:
    case libcamera::ControlTypeInteger64:
    case libcamera::ControlTypeFloat: return {};
    default: return fmt::format("a {} control: markerd sets numbers and booleans only", type_name(id.type()));
  }
}

std::optional<ControlValue> control_value_of(const libcamera::ControlValue& value) {
  const LibcameraValue v = value_of(value);
  if (const auto* b = std::get_if<bool>(&v)) return *b;
  if (const auto* i = std::get_if<std::int64_t>(&v)) return *i;
  if (const auto* d = std::get_if<double>(&v)) return *d;
  return std::nullopt;
}

std::vector<CameraControlInfo> LibcameraSource::read_controls() {
  const std::shared_ptr<Session> session = open_session("read");
  std::vector<CameraControlInfo> controls;
  for (const auto& [id, info] : session->controls()) {
    CameraControlInfo c;
    c.name = id->name();
    c.id = id->id();
    c.type = type_name(id->type());
    c.why_not_settable = why_not_settable(*id);
    if (c.why_not_settable.empty()) {
      switch (id->type()) {
        case libcamera::ControlTypeBool: c.kind = ControlKind::boolean; break;
        case libcamera::ControlTypeFloat: c.kind = ControlKind::real; break;
        default: c.kind = ControlKind::integer; break;
      }
    }
    c.minimum = control_value_of(info.min());
    c.maximum = control_value_of(info.max());
    c.default_value = control_value_of(info.def());
    // Where the camera gives no range, the type's.
    if (id->type() == libcamera::ControlTypeByte) {
      if (!c.minimum) c.minimum = std::int64_t{0};
      if (!c.maximum) c.maximum = std::int64_t{255};
    } else if (id->type() == libcamera::ControlTypeInteger32) {
      if (!c.minimum) c.minimum = std::int64_t{std::numeric_limits<std::int32_t>::min()};
      if (!c.maximum) c.maximum = std::int64_t{std::numeric_limits<std::int32_t>::max()};
    }
    for (const auto& value : info.values()) {
      if (auto v = control_value_of(value)) c.allowed.push_back(*v);
    }
    const std::lock_guard lock(controls_mutex_);
    if (const auto it = asked_.find(c.name); it != asked_.end()) c.value = it->second;
    controls.push_back(std::move(c));
  }
  std::sort(controls.begin(), controls.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  return controls;
}

void LibcameraSource::write_control(const CameraControlInfo& control, const ControlValue& value) {
  const std::shared_ptr<Session> session = open_session("set");
  const libcamera::ControlId* id = find_control(session->controls(), control.name);
  if (id == nullptr) {
    throw CaptureError(CaptureError::Kind::config, fmt::format("{}: no control {}", name_, control.name));
  }
  libcamera::ControlValue written;
  LibcameraControlSetting setting;
  setting.name = control.name;
  setting.origin = "set at run time (camera.set)";
  const auto whole = [&] {
    if (const auto* b = std::get_if<bool>(&value)) return std::int64_t{*b ? 1 : 0};
    if (const auto* i = std::get_if<std::int64_t>(&value)) return *i;
    return static_cast<std::int64_t>(std::llround(std::get<double>(value)));
  };
  switch (id->type()) {
    case libcamera::ControlTypeBool:
      written = libcamera::ControlValue(whole() != 0);
      setting.value = whole() != 0;
      break;
    case libcamera::ControlTypeByte:
      written = libcamera::ControlValue(static_cast<std::uint8_t>(whole()));
      setting.value = whole();
      break;
    case libcamera::ControlTypeInteger32:
      written = libcamera::ControlValue(static_cast<std::int32_t>(whole()));
      setting.value = whole();
      break;
    case libcamera::ControlTypeInteger64:
      written = libcamera::ControlValue(whole());
      setting.value = whole();
      break;
    case libcamera::ControlTypeFloat: {
      const double number = std::visit([](auto v) { return static_cast<double>(v); }, value);
      written = libcamera::ControlValue(static_cast<float>(number));
      setting.value = number;
      break;
    }
    default:
      throw CaptureError(CaptureError::Kind::config,
                         fmt::format("{}: control {}: {}", name_, control.name, why_not_settable(*id)));
  }
  session->set_control(id->id(), written);
  const std::lock_guard lock(controls_mutex_);
  asked_[control.name] = value;
  const auto it = std::find_if(set_at_run_time_.begin(), set_at_run_time_.end(),
                               [&](const auto& c) { return c.name == control.name; });
  if (it == set_at_run_time_.end()) {
    set_at_run_time_.push_back(std::move(setting));
  } else {
    *it = std::move(setting);
  }
}

}  // namespace

std::unique_ptr<CaptureSource> make_libcamera_source(const LibcameraSettings& settings) {
  return std::make_unique<LibcameraSource>(settings);
}

}  // namespace markerd::daemon
