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
  // A failure here (the camera going away) shows as the request not coming
  // back; the camera's disconnection is reported by wait().
  (void)camera_->queueRequest(&request);
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
    auto session = std::make_shared<Session>(shared_camera_manager(), name_);
    session->open(settings_);
    session_ = std::move(session);
  }

  void close() noexcept override {
    ready_.reset();
    if (!session_) return;
    session_->stop();
    // Frames still borrowing its buffers keep the session (and the camera)
    // until their release hooks have run.
    session_.reset();
  }

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
  LibcameraSettings settings_;
  std::string name_;
  std::shared_ptr<Session> session_;
  std::optional<std::uint32_t> ready_;  // a completed request, waiting for fill() or skip()
};

}  // namespace

std::unique_ptr<CaptureSource> make_libcamera_source(const LibcameraSettings& settings) {
  return std::make_unique<LibcameraSource>(settings);
}

}  // namespace markerd::daemon
