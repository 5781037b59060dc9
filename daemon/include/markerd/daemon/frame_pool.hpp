#pragma once
// The frames of a pipeline, all allocated at start: a fixed number of slots,
// each with its detections' capacity reserved and, for sources that write
// their own grey image, its pixel buffer. Slots circulate through a lock-free
// ring of free slots: one thread takes them (the capture), one thread gives
// them back (the log stage), and neither locks nor allocates.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <stop_token>

#include "markerd/daemon/frame.hpp"
#include "markerd/daemon/spsc_ring.hpp"

namespace markerd::daemon {

struct FramePoolConfig {
  std::size_t slots = 8;
  // Per slot; 0 for sources that lend their own pixels (V4L2 GREY or the Y
  // plane of NV12, straight from the mmap buffer).
  std::size_t pixel_bytes = 0;
  // Detections reserved per frame: more than a scene holds, so that the
  // vectors never grow once running.
  std::size_t detections = 16;
};

class FramePool {
 public:
  // Throws std::invalid_argument for zero slots.
  explicit FramePool(const FramePoolConfig& config);
  FramePool(const FramePool&) = delete;
  FramePool& operator=(const FramePool&) = delete;

  // ---- the taking thread ----
  // A free slot, reset (see Frame::reset), or null when none is free.
  [[nodiscard]] Frame* try_acquire() noexcept;
  // Waits for a free slot; null when `stop` is requested first.
  [[nodiscard]] Frame* acquire(const std::stop_token& stop);

  // ---- the returning thread ----
  // Runs the frame's release hook, then frees the slot.
  void release(Frame& frame) noexcept;

  // ---- any thread ----
  [[nodiscard]] std::size_t size() const noexcept { return slot_count_; }
  // Free slots; a moment's view when the pipeline runs, exact when it is stopped.
  [[nodiscard]] std::size_t available() const noexcept { return free_.size(); }
  [[nodiscard]] bool owns(const Frame& frame) const noexcept;

 private:
  struct PixelsDeleter {
    void operator()(std::uint8_t* p) const noexcept;
  };

  std::size_t slot_count_;
  std::unique_ptr<std::uint8_t, PixelsDeleter> pixels_;
  std::unique_ptr<Frame[]> frames_;
  SpscRing<Frame*> free_;
};

}  // namespace markerd::daemon
