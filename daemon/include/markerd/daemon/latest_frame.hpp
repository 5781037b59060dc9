#pragma once
// The newest frame, copied out of the pipeline for whoever wants to look at
// it: `markerctl snapshot` over the control socket and the web page's
// preview. The log stage offers every frame after its line is written; the
// slot copies one now and then (ten a second while someone looks, two a
// second otherwise) into one of a few buffers allocated once, and readers
// hold the copy they got by reference count, as long as they like, while the
// log stage writes the next copy into a buffer no reader holds. Neither
// side waits for the other: the log stage takes a lock only to pick a buffer
// and to swap it in (a few pointer copies), a reader only to take its
// reference; when readers hold every spare buffer, the frame is not copied.
// Design: docs/web.md.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "markerd/daemon/detection_record.hpp"
#include "markerd/detector/detection.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

struct LatestFrameSettings {
  // How often a frame is copied while someone has looked within
  // `watch_window`, and otherwise: a preview at ten frames a second, and a
  // snapshot at most half a second behind the pipeline when nobody watches.
  std::chrono::milliseconds watched_interval{100};
  std::chrono::milliseconds unwatched_interval{500};
  std::chrono::milliseconds watch_window{5000};
  // The copy readers see, and spares to write the next one into while
  // readers hold older ones.
  std::size_t buffers = 4;
};

// One frame as the log stage saw it: its pixels, its detections, the rig at
// capture time and the ground truth that implies.
struct HeldFrame {
  std::uint64_t copy = 0;  // 1 for the slot's first copy, then counting up: the frame counter
  std::uint64_t sequence = 0;
  std::chrono::steady_clock::time_point capture_time{};
  std::chrono::system_clock::time_point capture_utc{};
  FrameStatus status = FrameStatus::ok;
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;  // rows of `width` bytes
  std::vector<detector::Detection> detections;
  std::optional<rig::RigSnapshot> rig;
  std::optional<rig::MarkerGroundTruth> truth;

  [[nodiscard]] detector::GreyView image() const { return {pixels.data(), width, height, width}; }
};

struct LatestFrameStats {
  std::uint64_t offered = 0;  // frames the log stage offered
  std::uint64_t copied = 0;   // of them, copied
  std::uint64_t busy = 0;     // due, but readers held every spare buffer
};

class LatestFrame {
 public:
  explicit LatestFrame(LatestFrameSettings settings = {});
  LatestFrame(const LatestFrame&) = delete;
  LatestFrame& operator=(const LatestFrame&) = delete;

  // ---- the log stage (one thread) ----
  // Copies the frame when one is due and a buffer is free; otherwise returns
  // at once. Frames without pixels (unreadable ones) are not copied. Never
  // waits for a reader; allocates only while a buffer grows to a larger frame
  // or more detections than it held before.
  void offer(const FrameRecordInput& record, detector::GreyView image) noexcept;

  // ---- any thread ----
  // The newest copy, or null before the first. Counts as looking (see
  // LatestFrameSettings).
  [[nodiscard]] std::shared_ptr<const HeldFrame> latest() const;
  // The newest copy once its `copy` is beyond `after`; waits for it until
  // `deadline` or wake_all(), then returns what there is (maybe null).
  [[nodiscard]] std::shared_ptr<const HeldFrame> wait_newer(std::uint64_t after,
                                                            std::chrono::steady_clock::time_point deadline) const;
  // Ends every wait_newer() now (a server stopping).
  void wake_all() const;
  [[nodiscard]] LatestFrameStats stats() const noexcept;

 private:
  using Clock = std::chrono::steady_clock;
  void note_reader() const noexcept;

  const LatestFrameSettings settings_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  mutable std::uint64_t wakes_ = 0;  // under mutex_: wake_all() calls
  std::vector<std::shared_ptr<HeldFrame>> buffers_;
  std::shared_ptr<HeldFrame> newest_;  // under mutex_; one of buffers_, or null
  // The log stage's own.
  Clock::time_point next_copy_{};
  std::uint64_t copies_ = 0;
  // Nanoseconds on Clock of the last reader's look.
  mutable std::atomic<std::int64_t> last_read_ns_{0};
  std::atomic<std::uint64_t> offered_{0};
  std::atomic<std::uint64_t> copied_{0};
  std::atomic<std::uint64_t> busy_{0};
};

}  // namespace markerd::daemon
