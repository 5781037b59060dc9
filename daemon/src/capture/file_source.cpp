#include "markerd/daemon/capture/file_source.hpp"

#include <fmt/format.h>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <opencv2/videoio/registry.hpp>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "markerd/daemon/capture/image_file.hpp"

namespace markerd::daemon {

namespace {

namespace fs = std::filesystem;

// Extensions of the formats ImageFileReader reads; other files in a replay
// directory (notes, a detection log) are not frames.
bool is_image_name(const fs::path& path) {
  static constexpr std::array<std::string_view, 12> kExtensions = {".png", ".jpg", ".jpeg", ".jpe", ".bmp", ".dib",
                                                                   ".pbm", ".pgm", ".ppm",  ".pnm", ".tif", ".tiff"};
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](char c) { return static_cast<char>((c >= 'A' && c <= 'Z') ? c - 'A' + 'a' : c); });
  return std::find(kExtensions.begin(), kExtensions.end(), extension) != kExtensions.end();
}

std::vector<fs::path> list_images(const fs::path& directory) {
  std::vector<fs::path> images;
  std::error_code error;
  for (fs::directory_iterator it(directory, error), end; !error && it != end; it.increment(error)) {
    const std::string name = it->path().filename().string();
    if (name.starts_with('.') || !is_image_name(it->path())) continue;
    std::error_code type_error;
    if (!it->is_regular_file(type_error)) continue;
    images.push_back(it->path());
  }
  if (error) {
    const auto kind =
        error == std::errc::no_such_file_or_directory ? CaptureError::Kind::not_found : CaptureError::Kind::io;
    throw CaptureError(
        kind, fmt::format("file source {}: cannot list the directory: {}", directory.string(), error.message()));
  }
  // Name order, byte by byte: frame_0002.png before frame_0010.png only when
  // the numbers are zero-padded (as recorders write them).
  std::sort(images.begin(), images.end(),
            [](const fs::path& a, const fs::path& b) { return a.filename().native() < b.filename().native(); });
  if (images.empty()) {
    throw CaptureError(CaptureError::Kind::not_found,
                       fmt::format("file source {}: no images in the directory (files ending in .png, .jpg, "
                                   ".jpeg, .bmp, .pgm, .ppm, .pnm, .tif, .tiff, ...)",
                                   directory.string()));
  }
  return images;
}

// The last component of a path, without copying it.
std::string_view file_name_of(const fs::path& path) {
  const std::string_view full = path.native();
  const auto slash = full.rfind('/');
  return slash == std::string_view::npos ? full : full.substr(slash + 1);
}

void throw_missing(const fs::path& path) {
  throw CaptureError(CaptureError::Kind::not_found,
                     fmt::format("file source {}: no such file or directory", path.string()));
}

class FileSource final : public CaptureSource {
 public:
  explicit FileSource(const FileSourceSettings& settings) : settings_(settings) {
    if (!(settings_.fps >= 0) || !std::isfinite(settings_.fps)) {
      throw CaptureError(CaptureError::Kind::config, fmt::format("file source {}: fps must be >= 0, got {}",
                                                                 settings_.path.string(), settings_.fps));
    }
    name_ = fmt::format("file {}", settings_.path.string());
    if (settings_.fps > 0) {
      period_ = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / settings_.fps));
      name_ += fmt::format(" @{}", settings_.fps);
    }
    if (settings_.loop) name_ += " loop";

    std::error_code error;
    const auto type = fs::status(settings_.path, error).type();
    if (type == fs::file_type::not_found) throw_missing(settings_.path);
    if (type == fs::file_type::directory) {
      video_ = false;
      probe_images();
    } else if (type == fs::file_type::regular) {
      video_ = true;
      probe_video();
    } else {
      throw CaptureError(CaptureError::Kind::config,
                         fmt::format("file source {}: neither a directory of images nor a video file{}",
                                     settings_.path.string(), error ? ": " + error.message() : std::string()));
    }
  }

  ~FileSource() override { close(); }
  FileSource(const FileSource&) = delete;
  FileSource& operator=(const FileSource&) = delete;

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override {
    return CaptureGeometry{width_, height_, static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_),
                           settings_.fps};
  }

  void open() override {
    close();
    std::error_code error;
    if (!fs::exists(settings_.path, error)) throw_missing(settings_.path);
    if (video_) {
      open_video();
    } else {
      // Listed again: a reopen replays the directory as it is now.
      images_ = list_images(settings_.path);
      next_image_ = 0;
    }
    sequence_ = 0;
    ended_.store(false, std::memory_order_relaxed);
    next_due_ = Clock::now();
    open_ = true;
  }

  void close() noexcept override {
    if (video_) capture_.release();
    open_ = false;
    ready_ = false;
    grabbed_ = false;
  }

  [[nodiscard]] bool is_open() const noexcept override { return open_; }

  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override {
    if (!open_) throw CaptureError(CaptureError::Kind::io, fmt::format("{}: wait_frame() while closed", name_));
    if (ready_) return true;
    if (ended_.load(std::memory_order_relaxed)) return false;
    if (!next_available()) return false;

    if (period_ > Clock::duration::zero()) {
      const auto now = Clock::now();
      if (next_due_ > now + timeout) {
        std::this_thread::sleep_for(timeout);
        return false;
      }
      std::this_thread::sleep_until(next_due_);
      // A frame every period while the pipeline keeps up; a pipeline that
      // fell behind (lossless, waiting for a slot) gets the next frame a
      // period after this one rather than a burst to catch up.
      const auto delivered = std::max(next_due_, Clock::now() - period_);
      next_due_ = delivered + period_;
    }
    ready_time_ = Clock::now();
    ready_ = true;
    return true;
  }

  void fill(Frame& frame) override {
    if (!ready_) throw CaptureError(CaptureError::Kind::io, fmt::format("{}: fill() without a ready frame", name_));
    frame.sequence = sequence_;
    frame.capture_time = ready_time_;
    try {
      frame.use_pixel_buffer(width_, height_);
    } catch (const std::length_error& e) {
      throw CaptureError(CaptureError::Kind::config, fmt::format("{}: {}", name_, e.what()));
    }
    // The decoders write straight into the slot through this header; OpenCV
    // keeps a header's memory when the size and type it asks for match.
    cv::Mat slot(height_, width_, CV_8UC1, frame.pixel_buffer().data());
    if (video_) {
      fill_from_video(frame, slot);
    } else {
      fill_from_image(frame, slot);
    }
    consume();
  }

  void skip() noexcept override {
    if (ready_) consume();
  }

  [[nodiscard]] bool at_end() const noexcept override { return ended_.load(std::memory_order_relaxed); }

 private:
  void probe_images() {
    images_ = list_images(settings_.path);
    // The first image whose header reads sets the size (and so the pool's
    // slots); unreadable ones before it are corrupt frames when their turn
    // comes.
    std::string first_problem;
    for (const auto& image : images_) {
      try {
        const ImageSize size = reader_.open(image);
        width_ = size.width;
        height_ = size.height;
        reference_ = image.filename().string();
        return;
      } catch (const ImageFileError& e) {
        if (first_problem.empty()) first_problem = e.what();
      }
    }
    throw CaptureError(CaptureError::Kind::config,
                       fmt::format("file source {}: none of its {} images can be read (the first: {})",
                                   settings_.path.string(), images_.size(), first_problem));
  }

  void probe_video() {
    open_video();
    cv::Mat first;
    const bool read = capture_.read(first);
    capture_.release();
    if (!read || first.empty()) {
      throw CaptureError(
          CaptureError::Kind::config,
          fmt::format("file source {}: the video has no frame OpenCV can decode", settings_.path.string()));
    }
    width_ = first.cols;
    height_ = first.rows;
    reference_ = "first frame";
  }

  void open_video() {
    // File readers only: CAP_ANY would also offer the path to camera
    // backends (gPhoto2 probes the USB bus, and leaks doing it), and
    // GStreamer reads nothing FFmpeg does not, noisily.
    static constexpr std::array<int, 2> kFileBackends = {cv::CAP_FFMPEG, cv::CAP_OPENCV_MJPEG};
    std::string failures;
    for (const int backend : kFileBackends) {
      const auto api = static_cast<cv::VideoCaptureAPIs>(backend);
      if (!cv::videoio_registry::hasBackend(api)) continue;
      try {
        if (capture_.open(settings_.path.string(), backend)) {
          video_frame_index_ = 0;
          return;
        }
      } catch (const cv::Exception& e) {
        failures += fmt::format("; {}: {}", cv::videoio_registry::getBackendName(api), e.err);
      }
    }
    throw CaptureError(CaptureError::Kind::config,
                       fmt::format("file source {}: neither a directory of images nor a video OpenCV can read "
                                   "(tried FFmpeg and OpenCV's MJPEG reader){}",
                                   settings_.path.string(), failures));
  }

  // Whether another frame is there; ends the source, or starts it over when
  // looping, after the last one.
  bool next_available() {
    if (!video_) {
      if (next_image_ < images_.size()) return true;
      if (!settings_.loop) {
        ended_.store(true, std::memory_order_relaxed);
        return false;
      }
      next_image_ = 0;
      return true;
    }
    if (grabbed_) return true;
    grabbed_ = grab_video_frame();
    if (!grabbed_ && settings_.loop) {
      // Reopening rewinds every backend; seeking to frame 0 does not always.
      capture_.release();
      open_video();
      grabbed_ = grab_video_frame();
      if (!grabbed_) {
        throw CaptureError(CaptureError::Kind::io, fmt::format("{}: no frame after starting the video over", name_));
      }
    }
    if (!grabbed_) ended_.store(true, std::memory_order_relaxed);
    return grabbed_;
  }

  bool grab_video_frame() {
    try {
      return capture_.grab();
    } catch (const cv::Exception& e) {
      throw CaptureError(CaptureError::Kind::io, fmt::format("{}: reading the video: {}", name_, e.err));
    }
  }

  void fill_from_image(Frame& frame, cv::Mat& slot) {
    const fs::path& path = images_[next_image_];
    const std::string_view file = file_name_of(path);
    try {
      // The size the header declares is checked before anything is decoded.
      const ImageSize size = reader_.open(path);
      if (size.width != width_ || size.height != height_) {
        return mark_corrupt(frame, "image {}: {}x{}, not the {}x{} of {}", file, size.width, size.height, width_,
                            height_, reference_);
      }
      reader_.decode(slot.data, static_cast<std::ptrdiff_t>(slot.step[0]));
    } catch (const ImageFileError& e) {
      return mark_corrupt(frame, "image {}: {}", file, e.cause());
    }
  }

  void fill_from_video(Frame& frame, cv::Mat& slot) {
    const std::uint64_t index = video_frame_index_;
    bool retrieved = false;
    try {
      retrieved = capture_.retrieve(video_frame_);
    } catch (const cv::Exception& e) {
      return mark_corrupt(frame, "video frame {}: cannot be decoded: {}", index, e.err);
    }
    if (!retrieved || video_frame_.empty()) return mark_corrupt(frame, "video frame {}: cannot be decoded", index);
    if (video_frame_.cols != width_ || video_frame_.rows != height_) {
      return mark_corrupt(frame, "video frame {}: {}x{}, not the {}x{} of the first frame", index, video_frame_.cols,
                          video_frame_.rows, width_, height_);
    }
    // One pass from the backend's frame (BGR for most) into the slot.
    switch (video_frame_.type()) {
      case CV_8UC1: video_frame_.copyTo(slot); break;
      case CV_8UC3: cv::cvtColor(video_frame_, slot, cv::COLOR_BGR2GRAY); break;
      case CV_8UC4: cv::cvtColor(video_frame_, slot, cv::COLOR_BGRA2GRAY); break;
      default:
        return mark_corrupt(frame, "video frame {}: pixel type {} is not 8-bit grey, BGR or BGRA", index,
                            video_frame_.type());
    }
  }

  void consume() noexcept {
    ready_ = false;
    ++sequence_;
    if (video_) {
      grabbed_ = false;
      ++video_frame_index_;
      return;
    }
    ++next_image_;
    if (next_image_ >= images_.size() && !settings_.loop) ended_.store(true, std::memory_order_relaxed);
  }

  FileSourceSettings settings_;
  std::string name_;
  bool video_ = false;
  int width_ = 0;
  int height_ = 0;
  std::string reference_;  // what set the size, for the errors of frames that differ
  Clock::duration period_{0};

  bool open_ = false;
  bool ready_ = false;
  std::atomic<bool> ended_{false};
  std::uint64_t sequence_ = 0;
  Clock::time_point next_due_{};
  Clock::time_point ready_time_{};

  std::vector<fs::path> images_;
  std::size_t next_image_ = 0;
  ImageFileReader reader_;

  cv::VideoCapture capture_;
  cv::Mat video_frame_;  // the backend's frame, reused while the size holds
  bool grabbed_ = false;
  std::uint64_t video_frame_index_ = 0;
};

}  // namespace

FileSourceSettings parse_file_source_settings(const ConfigTable& table, const std::filesystem::path& config_dir) {
  table.allow_only({"path", "fps", "loop"});
  FileSourceSettings settings;
  const auto path = table.required<std::string>("path");
  if (path.empty()) table.fail("path", "must name a directory of images or a video file");
  settings.path = fs::path(path);
  if (settings.path.is_relative()) settings.path = config_dir / settings.path;
  settings.path = settings.path.lexically_normal();
  settings.fps = table.optional<double>("fps", 0.0);
  // A camera's rates: a thousand frames per second is far beyond any replay.
  if (!std::isfinite(settings.fps) || settings.fps < 0 || settings.fps > 1000) {
    table.fail("fps", fmt::format("must be >= 0 (0: as fast as the pipeline takes frames) and at most 1000, got {}",
                                  settings.fps));
  }
  settings.loop = table.optional<bool>("loop", false);
  return settings;
}

std::unique_ptr<CaptureSource> make_file_source(const FileSourceSettings& settings) {
  return std::make_unique<FileSource>(settings);
}

}  // namespace markerd::daemon
