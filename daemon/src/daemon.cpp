#include "markerd/daemon/daemon.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <thread>
#include <type_traits>
#include <utility>

namespace markerd::daemon {

namespace {

void name_this_thread(const char* name) { pthread_setname_np(pthread_self(), name); }

}  // namespace

std::unique_ptr<CaptureSource> make_capture_source(const CameraSettings& camera,
                                                   const std::optional<rig::RigConfig>& rig) {
  return std::visit(
      [&](const auto& settings) -> std::unique_ptr<CaptureSource> {
        using T = std::decay_t<decltype(settings)>;
        if constexpr (std::is_same_v<T, SimCameraSettings>) {
          // Without a rig the simulated camera shows its fixed positions
          // through the default geometry.
          return std::make_unique<SimCamera>(settings, *camera.model, rig ? rig->geometry : rig::RigGeometry{});
        }
      },
      camera.source);
}

Daemon::Daemon(DaemonConfig config) : config_(std::move(config)) {
  if (config_.rig) rig_ = rig::make_rig(*config_.rig);
  source_ = make_capture_source(config_.camera, config_.rig);

  LogWriterConfig writer;
  writer.directory = config_.log.directory;
  writer.prefix = config_.log.prefix;
  writer.run_id = make_run_id(std::chrono::system_clock::now());
  writer.max_bytes = config_.log.max_file_bytes;
  writer.fsync = config_.log.fsync;
  writer.fsync_interval = config_.log.fsync_interval;
  sink_ = std::make_unique<DetectionLogSink>(std::move(writer), std::vector<std::string>{source_->name()},
                                             config_.rig ? std::optional(config_.rig->geometry) : std::nullopt);

  PipelineConfig pipeline = config_.pipeline;
  pipeline.pool.pixel_bytes = source_->geometry().slot_pixel_bytes;
  std::vector<std::unique_ptr<MarkerDetector>> detectors;
  const DetectorConfig detector = detector_config(config_);
  for (std::size_t i = 0; i < config_.detector.workers; ++i) detectors.push_back(make_detector(detector));
  pipeline_ = std::make_unique<Pipeline>(pipeline, std::move(detectors), *sink_);
  capture_loop_ = std::make_unique<CaptureLoop>(*source_, *pipeline_, rig_.get(), config_.camera.loop);
}

Daemon::~Daemon() { stop(); }

void Daemon::start() {
  capture_thread_ = std::jthread([this](const std::stop_token& stop) {
    name_this_thread("markerd-capture");
    capture_loop_->run(stop);
  });
}

void Daemon::stop() {
  if (stopped_) return;
  stopped_ = true;
  if (capture_thread_.joinable()) {
    capture_thread_.request_stop();
    capture_thread_.join();
  }
  pipeline_->stop();
  stop_motion();
  sink_->sync();  // lines already written are on disk before markerd says it has stopped
}

void Daemon::stop_motion() noexcept {
  if (!rig_) return;
  // A controlled stop first (a stepper that is decelerated keeps its
  // position), then both drives disabled; whatever fails, the emergency stop.
  try {
    rig_->rail().stop();
    rig_->turntable().stop();
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    for (;;) {
      const rig::RigSnapshot s = rig_->snapshot();
      const bool still = !s.rail.moving && !s.turntable.moving;
      if (still || std::chrono::steady_clock::now() > deadline) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    rig_->rail().disable();
    rig_->turntable().disable();
  } catch (const std::exception& e) {
    spdlog::error("rig: stopping failed ({}); emergency stop", e.what());
    rig_->emergency_stop();
  }
}

bool Daemon::responsive() const {
  const auto limit = config_.camera.loop.frame_timeout + std::chrono::seconds(5);
  if (!capture_loop_->responsive(limit)) return false;
  if (rig_) {
    // The publisher refreshes the snapshot every few milliseconds.
    const auto age = std::chrono::steady_clock::now() - rig_->snapshot().time;
    if (age > std::chrono::seconds(5)) return false;
  }
  return true;
}

std::string Daemon::status_line() const {
  const CaptureStatus c = capture_loop_->status();
  const PipelineStats p = pipeline_->stats();
  std::string line = fmt::format("camera {}: {}, {} frames, {} dropped", c.source, to_string(c.state), c.frames,
                                 p.dropped());
  if (c.state == CaptureState::waiting && !c.last_error.empty()) line += fmt::format(" ({})", c.last_error);
  if (rig_) {
    const rig::RigSnapshot s = rig_->snapshot();
    line += fmt::format("; rig: rail {:.1f} mm ({}), turntable {:.2f} deg ({})", s.rail.position,
                        rig::to_string(s.rail.state), s.turntable.position, rig::to_string(s.turntable.state));
  }
  // One line: systemd's notification protocol separates assignments by newlines.
  std::replace(line.begin(), line.end(), '\n', ' ');
  return line;
}

}  // namespace markerd::daemon
