#include "markerd/daemon/latest_frame.hpp"

#include <algorithm>
#include <cstring>

namespace markerd::daemon {

LatestFrame::LatestFrame(LatestFrameSettings settings) : settings_(settings) {
  // One the readers see, at least one to write into.
  const std::size_t count = std::max<std::size_t>(settings_.buffers, 2);
  buffers_.reserve(count);
  for (std::size_t i = 0; i < count; ++i) buffers_.push_back(std::make_shared<HeldFrame>());
}

void LatestFrame::note_reader() const noexcept {
  last_read_ns_.store(Clock::now().time_since_epoch().count(), std::memory_order_relaxed);
}

void LatestFrame::offer(const FrameRecordInput& record, detector::GreyView image) noexcept {
  offered_.fetch_add(1, std::memory_order_relaxed);
  if (image.empty()) return;
  const Clock::time_point now = Clock::now();
  if (now < next_copy_) return;
  const Clock::time_point last_read{Clock::duration(last_read_ns_.load(std::memory_order_relaxed))};
  const bool watched = last_read.time_since_epoch().count() != 0 && now - last_read < settings_.watch_window;
  next_copy_ = now + (watched ? settings_.watched_interval : settings_.unwatched_interval);

  HeldFrame* target = nullptr;
  {
    const std::lock_guard lock(mutex_);
    for (const auto& buffer : buffers_) {
      // Readers get references only to newest_, under this lock: a buffer
      // that is not newest_ and has no reference but this slot's gains none
      // until it is swapped in below.
      if (buffer != newest_ && buffer.use_count() == 1) {
        target = buffer.get();
        break;
      }
    }
  }
  if (target == nullptr) {
    busy_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  // The last reader's release of this buffer (an acq_rel decrement) happens
  // before the writes below: use_count() read it with a relaxed load.
  std::atomic_thread_fence(std::memory_order_acquire);
  try {
    HeldFrame& f = *target;
    f.copy = ++copies_;
    f.sequence = record.sequence;
    f.capture_time = record.capture_time;
    f.capture_utc = record.capture_utc;
    f.status = record.status;
    f.width = image.width;
    f.height = image.height;
    f.pixels.resize(static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height));
    for (int y = 0; y < image.height; ++y) {
      std::memcpy(f.pixels.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(image.width), image.row(y),
                  static_cast<std::size_t>(image.width));
    }
    f.detections.assign(record.detections.begin(), record.detections.end());
    f.rig = record.rig;
    f.truth = record.truth;
  } catch (...) {
    // Out of memory growing a buffer: this copy is skipped; the buffer is
    // not swapped in, so no reader sees it half written.
    busy_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  {
    const std::lock_guard lock(mutex_);
    for (const auto& buffer : buffers_) {
      if (buffer.get() == target) newest_ = buffer;
    }
  }
  copied_.fetch_add(1, std::memory_order_relaxed);
  changed_.notify_all();
}

std::shared_ptr<const HeldFrame> LatestFrame::latest() const {
  note_reader();
  const std::lock_guard lock(mutex_);
  return newest_;
}

std::shared_ptr<const HeldFrame> LatestFrame::wait_newer(std::uint64_t after, Clock::time_point deadline) const {
  note_reader();
  std::unique_lock lock(mutex_);
  const std::uint64_t wakes = wakes_;
  changed_.wait_until(lock, deadline, [&] { return (newest_ && newest_->copy > after) || wakes_ != wakes; });
  return newest_;
}

void LatestFrame::wake_all() const {
  {
    const std::lock_guard lock(mutex_);
    ++wakes_;
  }
  changed_.notify_all();
}

LatestFrameStats LatestFrame::stats() const noexcept {
  return {offered_.load(std::memory_order_relaxed), copied_.load(std::memory_order_relaxed),
          busy_.load(std::memory_order_relaxed)};
}

}  // namespace markerd::daemon
