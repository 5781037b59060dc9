#include "markerd/daemon/capture/capture_loop.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <condition_variable>

namespace markerd::daemon {

std::string_view to_string(CaptureError::Kind kind) {
  switch (kind) {
    case CaptureError::Kind::config: return "config";
    case CaptureError::Kind::not_found: return "not_found";
    case CaptureError::Kind::vanished: return "vanished";
    case CaptureError::Kind::io: return "io";
  }
  return "unknown";
}

std::string_view to_string(CaptureState state) {
  switch (state) {
    case CaptureState::opening: return "opening";
    case CaptureState::streaming: return "streaming";
    case CaptureState::waiting: return "waiting";
    case CaptureState::ended: return "ended";
    case CaptureState::stopped: return "stopped";
  }
  return "unknown";
}

CaptureLoop::CaptureLoop(CaptureSource& source, Pipeline& pipeline, const rig::Rig* rig, CaptureLoopSettings settings)
    : source_(source), pipeline_(pipeline), rig_(rig), settings_(settings), next_delay_(settings.reopen_delay) {
  beat();
}

void CaptureLoop::run(const std::stop_token& stop) {
  while (!stop.stop_requested()) {
    if (!open_source(stop)) {
      wait_before_reopen(stop);
      continue;
    }
    stream(stop);
    source_.close();
    if (source_.at_end()) {
      state_.store(CaptureState::ended, std::memory_order_relaxed);
      spdlog::info("camera {}: no more frames", source_.name());
      // Until the daemon stops: a replay that ended is not a fault.
      std::mutex m;
      std::condition_variable_any cv;
      std::unique_lock lock(m);
      while (!stop.stop_requested()) {
        beat();
        cv.wait_for(lock, stop, std::chrono::seconds(1), [] { return false; });
      }
      break;
    }
    if (!stop.stop_requested()) wait_before_reopen(stop);
  }
  source_.close();
  state_.store(CaptureState::stopped, std::memory_order_relaxed);
}

bool CaptureLoop::open_source(const std::stop_token& stop) {
  beat();
  state_.store(CaptureState::opening, std::memory_order_relaxed);
  try {
    source_.open();
  } catch (const std::exception& e) {
    fail("cannot open", e);
    return false;
  }
  if (stop.stop_requested()) return true;  // stream() returns at once; run() closes it
  if (opened_once_) {
    reopens_.fetch_add(1, std::memory_order_relaxed);
    spdlog::info("camera {}: streaming again", source_.name());
  } else {
    spdlog::info("camera {}: streaming", source_.name());
  }
  opened_once_ = true;
  next_delay_ = settings_.reopen_delay;
  // A stall is measured from now, not from the last frame before a failure.
  last_frame_ns_.store(std::chrono::steady_clock::now().time_since_epoch().count(), std::memory_order_relaxed);
  state_.store(CaptureState::streaming, std::memory_order_relaxed);
  return true;
}

void CaptureLoop::stream(const std::stop_token& stop) {
  while (!stop.stop_requested()) {
    beat();
    try {
      if (!source_.wait_frame(settings_.frame_timeout)) {
        if (source_.at_end()) return;
        stalls_.fetch_add(1, std::memory_order_relaxed);
        fail("stalled", CaptureError(CaptureError::Kind::io,
                                     fmt::format("no frame within {} ms", settings_.frame_timeout.count())));
        return;
      }
    } catch (const std::exception& e) {
      fail("lost", e);
      return;
    }
    Frame* frame = pipeline_.acquire(stop);
    if (frame == nullptr) {
      source_.skip();
      if (stop.stop_requested()) return;
      dropped_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    frame->source_id = settings_.source_id;
    if (rig_ != nullptr) frame->rig = rig_->snapshot();
    try {
      source_.fill(*frame);
    } catch (const std::exception& e) {
      pipeline_.abandon(*frame);
      fail("lost", e);
      return;
    }
    if (frame->status == FrameStatus::corrupt_frame) corrupt_.fetch_add(1, std::memory_order_relaxed);
    last_frame_ns_.store(frame->capture_time.time_since_epoch().count(), std::memory_order_relaxed);
    pipeline_.publish(*frame);
    frames_.fetch_add(1, std::memory_order_relaxed);
    frame_rate_.tick(std::chrono::steady_clock::now());
  }
}

void CaptureLoop::fail(std::string_view what, const std::exception& error) {
  failures_.fetch_add(1, std::memory_order_relaxed);
  std::string message = fmt::format("camera {}: {}: {}", source_.name(), what, error.what());
  // The same failure again and again (a camera left unplugged) is worth one
  // warning per change, not one per retry.
  bool repeated = false;
  {
    // The state changes with its reason, under the lock status() reads both
    // under: a reader never sees "waiting" without the words that say why.
    const std::lock_guard lock(error_mutex_);
    repeated = message == last_error_;
    last_error_ = message;
    last_error_time_ = std::chrono::system_clock::now();
    state_.store(CaptureState::waiting, std::memory_order_relaxed);
  }
  if (repeated) {
    spdlog::debug("{}; retrying in {} ms", message, next_delay_.count());
  } else {
    spdlog::warn("{}; retrying in {} ms", message, next_delay_.count());
  }
}

void CaptureLoop::wait_before_reopen(const std::stop_token& stop) {
  source_.close();
  // In slices, so that the loop stays visibly alive through a long backoff.
  std::mutex m;
  std::condition_variable_any cv;
  std::unique_lock lock(m);
  const auto until = std::chrono::steady_clock::now() + next_delay_;
  while (!stop.stop_requested() && std::chrono::steady_clock::now() < until) {
    beat();
    const auto slice = std::min<std::chrono::steady_clock::duration>(until - std::chrono::steady_clock::now(),
                                                                     std::chrono::seconds(1));
    cv.wait_for(lock, stop, slice, [] { return false; });
  }
  next_delay_ = std::min(next_delay_ * 2, settings_.reopen_max_delay);
}

CaptureStatus CaptureLoop::status() const {
  CaptureStatus s;
  s.source = source_.name();
  s.frames = frames_.load(std::memory_order_relaxed);
  s.dropped = dropped_.load(std::memory_order_relaxed);
  s.corrupt = corrupt_.load(std::memory_order_relaxed);
  s.stalls = stalls_.load(std::memory_order_relaxed);
  s.failures = failures_.load(std::memory_order_relaxed);
  s.reopens = reopens_.load(std::memory_order_relaxed);
  s.fps = frame_rate_.rate(std::chrono::steady_clock::now());
  s.last_frame_time = std::chrono::steady_clock::time_point(
      std::chrono::steady_clock::duration(last_frame_ns_.load(std::memory_order_relaxed)));
  const std::lock_guard lock(error_mutex_);
  s.state = state_.load(std::memory_order_relaxed);
  s.last_error = last_error_;
  s.last_error_time = last_error_time_;
  return s;
}

bool CaptureLoop::responsive(std::chrono::steady_clock::duration limit) const noexcept {
  const auto last = std::chrono::steady_clock::time_point(
      std::chrono::steady_clock::duration(heartbeat_ns_.load(std::memory_order_relaxed)));
  return std::chrono::steady_clock::now() - last < limit;
}

void CaptureLoop::beat() noexcept {
  heartbeat_ns_.store(std::chrono::steady_clock::now().time_since_epoch().count(), std::memory_order_relaxed);
}

bool CaptureLoop::streaming() const noexcept {
  if (state_.load(std::memory_order_relaxed) != CaptureState::streaming) return false;
  const auto last = std::chrono::steady_clock::time_point(
      std::chrono::steady_clock::duration(last_frame_ns_.load(std::memory_order_relaxed)));
  return std::chrono::steady_clock::now() - last < settings_.frame_timeout;
}

}  // namespace markerd::daemon
