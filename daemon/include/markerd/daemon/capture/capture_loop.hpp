#pragma once
// The capture thread: drives one CaptureSource into the pipeline, stamps
// every frame with the rig's snapshot, and keeps the camera going through
// its failures. A device that vanishes, fails or stalls is reported with its
// cause (spdlog, and status() for the control socket) and reopened with
// exponential backoff, for as long as the daemon runs: a camera unplugged at
// night streams again when it is plugged back in, without a restart.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>

#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/daemon/pipeline.hpp"
#include "markerd/daemon/stats.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

struct CaptureLoopSettings {
  // No frame for this long is a stall: reported, and the device reopened.
  std::chrono::milliseconds frame_timeout{2000};
  // The first reopen waits this long, each failed one twice as long as the
  // one before, up to reopen_max_delay.
  std::chrono::milliseconds reopen_delay{250};
  std::chrono::milliseconds reopen_max_delay{10000};
  std::uint32_t source_id = 0;  // stamped on every frame
};

enum class CaptureState : std::uint8_t {
  opening,    // opening the device (the first time or again)
  streaming,  // frames arrive
  waiting,    // failed or stalled; waiting to reopen
  ended,      // a finite source (a file without loop) delivered its last frame
  stopped,    // run() returned
};
[[nodiscard]] std::string_view to_string(CaptureState state);

struct CaptureStatus {
  CaptureState state = CaptureState::opening;
  std::string source;
  std::uint64_t frames = 0;    // published to the pipeline
  std::uint64_t dropped = 0;   // refused by a live pipeline (the source got its buffer back)
  std::uint64_t corrupt = 0;   // published with status corrupt_frame
  std::uint64_t stalls = 0;    // frame_timeout passed without a frame
  std::uint64_t failures = 0;  // open() or a frame threw
  std::uint64_t reopens = 0;   // successful opens after the first
  std::string last_error;      // the latest failure's words, or empty
  std::chrono::system_clock::time_point last_error_time{};
  std::chrono::steady_clock::time_point last_frame_time{};  // capture time of the latest frame
  // Frames published per second over the last few seconds (RateMeter);
  // nothing until a quarter second has passed since the first.
  std::optional<double> fps;
};

class CaptureLoop {
 public:
  // `rig` may be null (a daemon without a rig). All must outlive the loop.
  CaptureLoop(CaptureSource& source, Pipeline& pipeline, const rig::Rig* rig, CaptureLoopSettings settings);

  // The thread's body: returns when `stop` is requested or the source has
  // ended, with the source closed. Frames it lent may still be in the
  // pipeline: stop the pipeline after this returns.
  void run(const std::stop_token& stop);

  // ---- any thread ----
  [[nodiscard]] CaptureStatus status() const;
  // Streaming, with a frame within frame_timeout.
  [[nodiscard]] bool streaming() const noexcept;
  // The loop itself is alive: it has come round (a frame, a timeout, a
  // backoff slice) within `limit`. A camera that is gone does not make the
  // loop unresponsive, a thread stuck in a driver call or in a full lossless
  // pipeline does: this is what the systemd watchdog asks.
  [[nodiscard]] bool responsive(std::chrono::steady_clock::duration limit) const noexcept;
  [[nodiscard]] CaptureState state() const noexcept { return state_.load(std::memory_order_relaxed); }

 private:
  bool open_source(const std::stop_token& stop);
  void stream(const std::stop_token& stop);
  void fail(std::string_view what, const std::exception& error);
  void wait_before_reopen(const std::stop_token& stop);
  void beat() noexcept;

  CaptureSource& source_;
  Pipeline& pipeline_;
  const rig::Rig* rig_;
  CaptureLoopSettings settings_;
  std::chrono::milliseconds next_delay_;
  bool opened_once_ = false;

  std::atomic<CaptureState> state_{CaptureState::opening};
  std::atomic<std::int64_t> last_frame_ns_{0};  // steady_clock, ns since its epoch
  std::atomic<std::int64_t> heartbeat_ns_{0};   // the same clock: the loop's latest round
  std::atomic<std::uint64_t> frames_{0}, dropped_{0}, corrupt_{0}, stalls_{0}, failures_{0}, reopens_{0};
  RateMeter frame_rate_;  // frames published
  mutable std::mutex error_mutex_;
  std::string last_error_;  // under error_mutex_
  std::chrono::system_clock::time_point last_error_time_{};
};

}  // namespace markerd::daemon
