#pragma once
// The pipeline's FrameSink in the daemon: each frame outcome becomes one line
// of the detection log (detection_record.hpp) with the ground truth its rig
// snapshot implies, appended by a LogWriter, and offered to whoever follows
// the stream live (the control socket's `detections`). It runs on the log
// stage's one thread and allocates nothing per frame once its buffers have
// grown.

#include <atomic>
#include <chrono>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/daemon/detection_record.hpp"
#include "markerd/daemon/frame.hpp"
#include "markerd/daemon/latest_frame.hpp"
#include "markerd/daemon/log_writer.hpp"
#include "markerd/daemon/stats.hpp"
#include "markerd/rig/geometry.hpp"

namespace markerd::daemon {

struct DetectionLogSinkStats {
  LogWriterStats writer;
  std::uint64_t lines_lost = 0;  // records that could not be written (the writer's error was reported)
  std::string last_error;        // the latest write error's words, or empty
};

class DetectionLogSink final : public FrameSink {
 public:
  // `source_names` by frame.source_id. With a rig geometry, every frame with
  // a rig snapshot is logged beside the marker pose the snapshot implies.
  // Opens the log (LogWriteError when it cannot).
  DetectionLogSink(LogWriterConfig writer, std::vector<std::string> source_names,
                   std::optional<rig::RigGeometry> geometry);

  // Called with every formatted line (ending in '\n') on the log stage's
  // thread, whether or not the file took it; must not block. Set before the
  // pipeline starts.
  void set_line_observer(std::function<void(std::string_view line)> observer) { observer_ = std::move(observer); }

  // Called with every frame outcome after its line was appended (the sweep
  // runner collects its frames here), on the log stage's thread; must be
  // brief and must not block. Set before the pipeline starts.
  void set_frame_observer(std::function<void(const FrameRecordInput& frame)> observer) {
    frame_observer_ = std::move(observer);
  }

  // Offered every frame with its pixels, after its line (the snapshot and
  // the web page's preview); must outlive the sink. Set before the pipeline
  // starts.
  void set_latest_frame(LatestFrame* latest) { latest_ = latest; }

  void write(const Frame& frame) override;
  [[nodiscard]] std::chrono::milliseconds idle_period() const override { return std::chrono::milliseconds(100); }
  void idle() override;

  // Any thread (the SIGHUP handler's): the log stage reopens the file at its
  // next frame or idle period, so that logrotate's rename takes effect.
  void request_reopen() noexcept { reopen_requested_.store(true, std::memory_order_relaxed); }
  // Syncs the file now, reporting a failure rather than throwing. Only when
  // the log stage is not running (the pipeline is stopped).
  void sync() noexcept;

  // Any thread.
  [[nodiscard]] DetectionLogSinkStats stats() const;
  // The file lines go to now (a moment's view, for status).
  [[nodiscard]] std::string current_path() const;
  // Frames through detection per second over the last few seconds, counted
  // here, where every detected frame arrives (RateMeter); nothing until a
  // quarter second has passed since the first.
  [[nodiscard]] std::optional<double> frame_rate() const noexcept {
    return frame_rate_.rate(std::chrono::steady_clock::now());
  }

 private:
  void housekeeping();
  void note_path_if_changed();
  void report(const std::exception& error);

  LogWriter writer_;
  DetectionRecordFormatter formatter_;
  std::vector<std::string> source_names_;
  std::optional<rig::RigGeometry> geometry_;
  std::function<void(std::string_view)> observer_;
  std::function<void(const FrameRecordInput&)> frame_observer_;
  LatestFrame* latest_ = nullptr;
  std::atomic<bool> reopen_requested_{false};
  std::atomic<std::uint64_t> lines_lost_{0};
  RateMeter frame_rate_;
  std::uint64_t files_opened_seen_ = 0;
  // Error reports: one per distinct error, then at most one every
  // kReportEvery while it persists, so a full disk does not flood the journal.
  std::string last_reported_;
  std::chrono::steady_clock::time_point last_report_time_{};
  static constexpr std::chrono::seconds kReportEvery{10};
  mutable std::mutex shared_mutex_;  // guards the two below, read by stats()/current_path()
  std::string last_error_;
  std::string path_;
};

}  // namespace markerd::daemon
