#include "markerd/daemon/detection_log_sink.hpp"

#include <spdlog/spdlog.h>

#include <mutex>
#include <utility>

namespace markerd::daemon {

DetectionLogSink::DetectionLogSink(LogWriterConfig writer, std::vector<std::string> source_names,
                                   std::optional<rig::RigGeometry> geometry)
    : writer_(std::move(writer)), source_names_(std::move(source_names)), geometry_(geometry) {
  note_path_if_changed();
}

void DetectionLogSink::note_path_if_changed() {
  const std::uint64_t opened = writer_.stats().files_opened;
  if (opened == files_opened_seen_) return;
  files_opened_seen_ = opened;
  const std::lock_guard lock(shared_mutex_);
  path_ = writer_.current_path().string();
}

void DetectionLogSink::write(const Frame& frame) {
  frame_rate_.tick(Clock::now());
  housekeeping();
  FrameRecordInput in;
  in.status = frame.status;
  in.cause = frame.cause();
  in.sequence = frame.sequence;
  in.capture_time = frame.capture_time;
  // The monotonic capture time on the wall clock, by the two clocks' offset
  // now (a step of the wall clock between capture and now moves it, as it
  // would any reading).
  in.capture_utc = std::chrono::system_clock::now() -
                   std::chrono::duration_cast<std::chrono::system_clock::duration>(Clock::now() - frame.capture_time);
  if (frame.source_id < source_names_.size()) in.source = source_names_[frame.source_id];
  in.width = frame.image.width;
  in.height = frame.image.height;
  in.detection_time = frame.times.detect_end - frame.times.detect_start;
  in.detections = frame.detections;
  in.rig = frame.rig;
  if (frame.rig && geometry_) {
    in.truth = rig::ground_truth(*geometry_, frame.rig->rail.position, frame.rig->turntable.position);
  }
  const std::string_view line = formatter_.format(in);
  if (observer_) observer_(line);
  try {
    writer_.append(line);
  } catch (const std::exception& e) {
    lines_lost_.fetch_add(1, std::memory_order_relaxed);
    report(e);
  }
  if (frame_observer_) frame_observer_(in);
  if (latest_ != nullptr) latest_->offer(in, frame.image);
  note_path_if_changed();  // rotated
}

void DetectionLogSink::idle() {
  housekeeping();
  try {
    writer_.sync_if_due();
  } catch (const std::exception& e) {
    report(e);
  }
}

void DetectionLogSink::sync() noexcept {
  try {
    writer_.sync();
  } catch (const std::exception& e) {
    report(e);
  }
}

void DetectionLogSink::housekeeping() {
  if (!reopen_requested_.exchange(false, std::memory_order_relaxed)) return;
  try {
    writer_.reopen();
    spdlog::info("detection log: reopened {}", writer_.current_path().string());
  } catch (const std::exception& e) {
    report(e);
  }
  note_path_if_changed();
}

void DetectionLogSink::report(const std::exception& error) {
  const std::string message = error.what();
  const auto now = std::chrono::steady_clock::now();
  if (message != last_reported_ || now - last_report_time_ >= kReportEvery) {
    spdlog::error("{} ({} records lost so far; the lines before them are intact)", message,
                  lines_lost_.load(std::memory_order_relaxed));
    last_reported_ = message;
    last_report_time_ = now;
  }
  const std::lock_guard lock(shared_mutex_);
  last_error_ = message;
}

DetectionLogSinkStats DetectionLogSink::stats() const {
  DetectionLogSinkStats s;
  s.writer = writer_.stats();
  s.lines_lost = lines_lost_.load(std::memory_order_relaxed);
  const std::lock_guard lock(shared_mutex_);
  s.last_error = last_error_;
  return s;
}

std::string DetectionLogSink::current_path() const {
  const std::lock_guard lock(shared_mutex_);
  return path_;
}

}  // namespace markerd::daemon
