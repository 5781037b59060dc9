#pragma once
// A frame as it flows through the pipeline: one slot of the frame pool that
// a capture source fills, the detection stage completes and the log stage
// hands to a FrameSink. See docs/pipeline.md for who owns a frame when.

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "markerd/daemon/detection_record.hpp"
#include "markerd/detector/detection.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

// The pipeline's clock. libstdc++'s steady_clock is CLOCK_MONOTONIC, the
// clock V4L2 stamps buffers with (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC) and the
// rig stamps its snapshots with, so all three compare directly.
using Clock = std::chrono::steady_clock;

// How a source whose pixels the frame borrows (a V4L2 mmap buffer, say) gets
// them back: called once, from whichever pipeline thread is last done with
// the frame, and must not block (requeueing a V4L2 buffer from another
// thread than the one that polls is fine: VIDIOC_QBUF is thread-safe). A
// function pointer and two words rather than std::function, so that setting
// one never allocates.
struct ReleaseHook {
  void (*release)(void* context, std::uint64_t token) noexcept = nullptr;
  void* context = nullptr;
  std::uint64_t token = 0;  // e.g. the V4L2 buffer index

  explicit operator bool() const noexcept { return release != nullptr; }
};

class Frame;

// Turns an encoded frame (MJPEG) into its grey image: writes the image where
// the frame's `image` points (its pixel_buffer(), which the source set up)
// from Frame::encoded(), or marks the frame corrupt_frame with a cause and
// an empty image. Runs on the pipeline worker that takes the frame, so it
// must be safe to run on several threads at once, and it must not throw: a
// failure is the frame's, not the pipeline's.
using DecodeFunction = void (*)(Frame& frame) noexcept;

// When the frame passed each stage boundary, on Clock.
struct StageTimes {
  Clock::time_point published{};  // handed to detection
  Clock::time_point detect_start{};
  Clock::time_point detect_end{};
  Clock::time_point log_start{};  // handed to the sink
};

class Frame {
 public:
  // ---- set by the capture source between Pipeline::acquire and publish ----
  std::uint64_t sequence = 0;        // the source's own (V4L2's buffer sequence)
  Clock::time_point capture_time{};  // acquire() stamps "now"; a driver's timestamp is better
  std::uint32_t source_id = 0;
  std::optional<rig::RigSnapshot> rig;  // the rig at capture time; empty without a rig
  detector::GreyView image{};           // into pixel_buffer() or into the source's own memory
  // A source that delivers an unreadable frame (a broken MJPEG) publishes it
  // with corrupt_frame and a cause, so that the log records it; detection
  // skips it.
  FrameStatus status = FrameStatus::ok;

  // ---- set by the pipeline ----
  // Cleared and refilled by the detector; its capacity is kept from frame to
  // frame, so it allocates only when a frame holds more markers than any
  // frame before it in this slot.
  std::vector<detector::Detection> detections;
  StageTimes times;

  // Why the frame is not ok (the source's or the detector's words), cut to
  // kCauseCapacity bytes.
  [[nodiscard]] std::string_view cause() const noexcept { return {cause_.data(), cause_length_}; }
  void set_cause(std::string_view cause) noexcept;
  static constexpr std::size_t kCauseCapacity = 200;
  // Publishes the frame as unreadable: no image, corrupt_frame, the cause.
  void mark_corrupt(std::string_view cause) noexcept;

  // The slot's own pixel memory, for sources that write the grey image
  // themselves (a renderer, a YUYV or MJPEG conversion); empty when the pool
  // was made without pixel buffers. 64-byte aligned.
  [[nodiscard]] std::span<std::uint8_t> pixel_buffer() const noexcept { return pixel_buffer_; }
  // Points `image` at pixel_buffer() with rows of `width` bytes; throws
  // std::length_error when the image does not fit.
  detector::GreyView use_pixel_buffer(int width, int height);

  // Lends the frame the source's pixels: `hook` runs once when the pipeline
  // is done with the frame (written, dropped or discarded).
  void set_release(ReleaseHook hook) noexcept;

  // Lends the frame an encoded image (a source's MJPEG buffer, given back by
  // the release hook) that decode() turns into `image` with `decoder`. The
  // pipeline decodes only the frames it detects, on the worker that detects
  // them: a frame dropped while it waits costs no decoding, and the capture
  // thread never waits for a decoder.
  void set_encoded(std::span<const std::uint8_t> data, DecodeFunction decoder) noexcept;
  [[nodiscard]] std::span<const std::uint8_t> encoded() const noexcept { return encoded_; }
  [[nodiscard]] bool is_encoded() const noexcept { return decode_ != nullptr; }
  // Decodes an encoded frame into `image` (or marks it corrupt_frame) and
  // gives the encoded buffer back to its source at once (release_source()).
  // Does nothing for a frame that is not encoded, or already decoded.
  void decode() noexcept;
  [[nodiscard]] bool has_release() const noexcept { return static_cast<bool>(release_); }

  // Runs the release hook, if any, and forgets it: a second call does nothing.
  void release_source() noexcept;

  Frame() = default;
  Frame(const Frame&) = delete;
  Frame& operator=(const Frame&) = delete;

 private:
  friend class FramePool;
  friend class Pipeline;

  // Back to the state acquire() hands out; keeps the detections' capacity.
  void reset() noexcept;

  std::span<std::uint8_t> pixel_buffer_;
  ReleaseHook release_;
  std::span<const std::uint8_t> encoded_;
  DecodeFunction decode_ = nullptr;
  std::array<char, kCauseCapacity> cause_{};
  std::size_t cause_length_ = 0;
  // The pipeline's own: the frame's place in publication order, and whether
  // it is being discarded rather than detected (a live pipeline stopping).
  std::uint64_t ticket_ = 0;
  bool discarded_ = false;
};

// What the log stage hands each detected frame to (the detection log writer,
// a test's recorder). Called from the log stage's one thread, in publication
// order; the frame and its pixels are valid only during the call. An
// exception is counted (log.failed) and the stage goes on: a sink reports its
// own errors, naming its file.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual void write(const Frame& frame) = 0;

  // Housekeeping on the log stage's thread while no frame comes: idle() runs
  // whenever the stage has waited idle_period() for a frame (never when the
  // period is zero). The detection log syncs by its policy's deadline and
  // reopens its files after a SIGHUP here, when a camera is lost and no
  // frames arrive to do it. The sink reports its own errors: an exception
  // from idle() is not a frame's, and is neither counted nor passed on.
  [[nodiscard]] virtual std::chrono::milliseconds idle_period() const { return std::chrono::milliseconds{0}; }
  virtual void idle() {}
};

// Frame::mark_corrupt with a cause formatted on the stack: sources call it on
// their capture thread, which must not allocate.
template <class... Args>
void mark_corrupt(Frame& frame, fmt::format_string<Args...> format, Args&&... args) {
  std::array<char, Frame::kCauseCapacity> text{};
  const auto written = fmt::format_to_n(text.data(), text.size(), format, std::forward<Args>(args)...);
  frame.mark_corrupt({text.data(), std::min(written.size, text.size())});
}

}  // namespace markerd::daemon
