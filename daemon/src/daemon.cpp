#include "markerd/daemon/daemon.hpp"

#include "markerd/base/config_table.hpp"
#include "markerd/base/read_file.hpp"
#include "markerd/daemon/capture/v4l2_listing.hpp"
#include "markerd/daemon/capture/v4l2_source.hpp"
#include "markerd/daemon/control/camera_commands.hpp"
#include "markerd/daemon/control/rig_commands.hpp"
#include "markerd/daemon/control/snapshot_command.hpp"
#include "markerd/daemon/control/sweep_commands.hpp"
#include "markerd/daemon/daemon_status.hpp"
#include "markerd/daemon/web/web_state.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <thread>
#include <type_traits>
#include <utility>

namespace markerd::daemon {

namespace {

void name_this_thread(const char* name) { pthread_setname_np(pthread_self(), name); }

double configured_fps(const CameraSourceSettings& source) {
  return std::visit([](const auto& settings) { return settings.fps; }, source);
}

}  // namespace

// What the sweep runner asks of the daemon around it.
class Daemon::SweepEnvironment final : public sweep::SweepEnvironment {
 public:
  explicit SweepEnvironment(const Daemon& daemon) : daemon_(daemon) {
    try {
      config_text_ = read_regular_file(daemon.config_.source, ConfigTable::kMaxFileBytes, "the config file");
    } catch (const std::exception&) {
      // A config given as text (the tests) has no file: the record keeps its name only.
    }
  }

  [[nodiscard]] std::optional<std::string> camera_problem() const override {
    const CaptureStatus s = daemon_.capture_loop_->status();
    switch (s.state) {
      case CaptureState::streaming:
        // A frame that is slow to come is no fault: the capture loop
        // declares a stall itself at frame_timeout (waiting), and a slow
        // frame (the simulated camera rendering a moving rig) is only slow.
        return std::nullopt;
      case CaptureState::opening:
        // Starting up is no fault; opening again after a loss is.
        if (s.failures == 0 && s.stalls == 0) return std::nullopt;
        [[fallthrough]];
      case CaptureState::waiting:
        return fmt::format("{}: {}", s.source, s.last_error.empty() ? std::string(to_string(s.state)) : s.last_error);
      case CaptureState::ended:
      case CaptureState::stopped: return fmt::format("{}: {}", s.source, to_string(s.state));
    }
    return std::nullopt;
  }

  [[nodiscard]] double camera_fps() const override { return configured_fps(daemon_.config_.camera.source); }

  [[nodiscard]] detector::DetectorConfig detector_config() const override {
    return daemon::detector_config(daemon_.config_);
  }

  [[nodiscard]] sweep::Mounting marker_mounting() const override { return daemon_.config_.marker.mounting; }

  [[nodiscard]] nlohmann::json marker_record() const override { return daemon::marker_record(daemon_.config_.marker); }

  [[nodiscard]] nlohmann::json config_record() const override {
    return {{"file", daemon_.config_.source}, {"text", config_text_}};
  }

  [[nodiscard]] nlohmann::json camera_record() const override {
    const CameraSettings& camera = daemon_.config_.camera;
    nlohmann::json j{{"source", daemon_.source_->name()}, {"kind", camera.source_kind}, {"fps", camera_fps()}};
    if (camera.model) {
      const detector::CameraModel& m = *camera.model;
      j["model"] = {{"file", camera.model_path.string()},
                    {"width", m.width},
                    {"height", m.height},
                    {"fx", m.fx},
                    {"fy", m.fy},
                    {"cx", m.cx},
                    {"cy", m.cy},
                    {"distortion", m.dist}};
    } else {
      j["model"] = nullptr;
    }
    // What the simulated camera draws around the marker: a run behind a
    // covered side is told apart from an open one by its records alone.
    if (const auto* sim = std::get_if<SimCameraSettings>(&camera.source)) {
      nlohmann::json cover = nlohmann::json::array();
      for (const detector::MarkerSide side : sim->cover) cover.push_back(to_string(side));
      j["scene"] = {{"cover", cover},
                    {"cover_depth", sim->cover_depth},
                    {"cover_reflectance", std::round(static_cast<double>(sim->cover_reflectance) * 1e6) / 1e6},
                    {"cover_height_m", sim->cover_height_m},
                    {"clutter", sim->clutter},
                    {"background_grey", sim->background_grey},
                    {"ambient", sim->ambient}};
    }
    return j;
  }

  [[nodiscard]] std::string detection_log_path() const override { return daemon_.sink_->current_path(); }

 private:
  const Daemon& daemon_;
  std::string config_text_;
};

std::unique_ptr<CaptureSource> make_capture_source(const CameraSettings& camera,
                                                   const std::optional<rig::RigConfig>& rig) {
  return std::visit(
      [&](const auto& settings) -> std::unique_ptr<CaptureSource> {
        using T = std::decay_t<decltype(settings)>;
        if constexpr (std::is_same_v<T, SimCameraSettings>) {
          // Without a rig the simulated camera shows its fixed positions
          // through the default geometry. With one, the simulated world is
          // what the rig's config says before any calibration file, unless
          // [rig.sim.geometry] makes it another.
          return std::make_unique<SimCamera>(
              settings, *camera.model, rig ? rig->sim.geometry.value_or(rig->configured_geometry) : rig::RigGeometry{});
        } else if constexpr (std::is_same_v<T, V4l2Settings>) {
          return make_v4l2_source(settings);
        } else if constexpr (std::is_same_v<T, LibcameraSettings>) {
          return make_libcamera_source(settings);
        } else {
          static_assert(std::is_same_v<T, FileSourceSettings>);
          return make_file_source(settings);
        }
      },
      camera.source);
}

Daemon::Daemon(DaemonConfig config) : Daemon(std::move(config), std::nullopt) {}

Daemon::Daemon(DaemonConfig config, std::optional<rig::DeviceLock> rig_lock) : config_(std::move(config)) {
  if (config_.rig) {
    if (rig_lock) {
      rig_lock_ = std::move(rig_lock);
    } else {
      rig_lock_.emplace(rig::lock_rig_devices(*config_.rig));
    }
    rig_ = rig::make_rig(*config_.rig);
  }
  source_ = make_capture_source(config_.camera, config_.rig);
  const CaptureGeometry geometry = source_->geometry();
  if (config_.camera.model && geometry.width > 0 &&
      (geometry.width != config_.camera.model->width || geometry.height != config_.camera.model->height)) {
    // Poses through a calibration of another resolution would be wrong, not just imprecise.
    throw ConfigError(fmt::format("{}: camera.model: {} is calibrated for {}x{}, but the camera ({}) delivers {}x{}",
                                  config_.source, config_.camera.model_path.string(), config_.camera.model->width,
                                  config_.camera.model->height, source_->name(), geometry.width, geometry.height));
  }

  LogWriterConfig writer;
  writer.directory = config_.log.directory;
  writer.prefix = config_.log.prefix;
  writer.run_id = make_run_id(std::chrono::system_clock::now());
  writer.max_bytes = config_.log.max_file_bytes;
  writer.fsync = config_.log.fsync;
  writer.fsync_interval = config_.log.fsync_interval;
  sink_ = std::make_unique<DetectionLogSink>(std::move(writer), std::vector<std::string>{source_->name()},
                                             config_.rig ? std::optional(config_.rig->geometry) : std::nullopt);

  LatestFrameSettings latest;
  if (config_.web.enabled) {
    // While someone watches, a frame is copied as often as the preview shows one.
    latest.watched_interval = std::chrono::duration_cast<std::chrono::milliseconds>(
        std::chrono::duration<double>(1.0 / config_.web.preview_fps));
    latest.watched_interval = std::min(latest.watched_interval, LatestFrameSettings{}.watched_interval);
  }
  latest_ = std::make_unique<LatestFrame>(latest);
  sink_->set_latest_frame(latest_.get());

  PipelineConfig pipeline = config_.pipeline;
  pipeline.pool.pixel_bytes = source_->geometry().slot_pixel_bytes;
  std::vector<std::unique_ptr<detector::MarkerDetector>> detectors;
  const detector::DetectorConfig detector = detector_config(config_);
  for (std::size_t i = 0; i < config_.detector.workers; ++i) detectors.push_back(detector::make_detector(detector));
  pipeline_ = std::make_unique<Pipeline>(pipeline, std::move(detectors), *sink_);
  capture_loop_ = std::make_unique<CaptureLoop>(*source_, *pipeline_, rig_.get(), config_.camera.loop);

  detections_ = std::make_unique<LineBroadcast>("detections");
  sink_->set_line_observer([broadcast = detections_.get()](std::string_view line) { broadcast->publish(line); });
  control_ = std::make_unique<ControlServer>(control_settings(config_.control));

  if (rig_) {
    sweep::RunnerSettings runner;
    runner.runs_directory = config_.sweep.directory / "runs";
    runner.journal = config_.sweep.directory / "sweep-journal.json";
    runner.software_version = MARKERD_VERSION;
    std::error_code ec;
    std::filesystem::create_directory(runner.runs_directory, ec);
    if (ec) {
      throw ConfigError(fmt::format("{}: sweep.directory: cannot create {}: {}", config_.source,
                                    runner.runs_directory.string(), ec.message()));
    }
    sweep_environment_ = std::make_unique<SweepEnvironment>(*this);
    sweep_ = std::make_unique<sweep::SweepRunner>(*rig_, *config_.rig, *sweep_environment_, std::move(runner));
    sink_->set_frame_observer([runner = sweep_.get()](const FrameRecordInput& frame) {
      sweep::FrameObservation o;
      o.capture_time = frame.capture_time;
      o.sequence = frame.sequence;
      o.readable = frame.status == FrameStatus::ok;
      o.rig = frame.rig;
      o.truth = frame.truth;
      o.detections = frame.detections;
      runner->observe(o);
    });
  }
  if (config_.web.enabled) {
    WebSources sources;
    sources.latest = latest_.get();
    sources.annotation = annotation_context();
    sources.state = [this] { return web_state_json(*this); };
    sources.report = [this] { return last_report(*this); };
    web_ = std::make_unique<WebServer>(config_.web, std::move(sources));
  }
  register_commands();
}

void Daemon::register_commands() {
  control_->register_command(
      "status",
      [this](const nlohmann::json& request) {
        expect_arguments(request, {});
        return status_json(*this);
      },
      "the camera, the pipeline's counters and latencies, the detection log, the rig");
  control_->register_command(
      "cameras",
      [](const nlohmann::json& request) {
        expect_arguments(request, {});
        nlohmann::json v4l2 = nlohmann::json::array();
        for (const auto& device : list_v4l2_devices()) v4l2.push_back(nlohmann::json(to_json(device)));
        nlohmann::json libcamera = nlohmann::json::array();
        for (const auto& camera : list_libcamera_cameras()) libcamera.push_back(nlohmann::json(to_json(camera)));
        return nlohmann::json{{"v4l2", std::move(v4l2)}, {"libcamera", std::move(libcamera)}};
      },
      "the cameras this machine has, through V4L2 and libcamera: formats, sizes, intervals, controls");
  register_snapshot_command(*control_, *latest_, annotation_context());
  control_->register_stream(*detections_, "follow the detection log live: one JSON line per frame");
  register_camera_commands(*control_, *source_, *capture_loop_, [this](const std::string& change) {
    if (sweep_) sweep_->record_event("camera_control", change);
  });
  if (rig_) register_rig_commands(*control_, *rig_);
  if (sweep_) {
    register_sweep_commands(*control_, *sweep_);
    // Like rig.stop (register_rig_commands), they stop the rig: served
    // however many clients hold the socket.
    control_->serve_beyond_client_limit("sweep.pause");
    control_->serve_beyond_client_limit("sweep.abort");
  }
}

AnnotationContext Daemon::annotation_context() const {
  AnnotationContext context;
  context.camera = config_.camera.model;
  context.marker_size_m = config_.marker.size_m;
  if (config_.rig) {
    context.rail_unit = config_.rig->rail.axis.unit;
    context.turntable_unit = config_.rig->turntable.axis.unit;
  }
  return context;
}

Daemon::~Daemon() { stop(); }

void Daemon::start() {
  capture_thread_ = std::jthread([this](const std::stop_token& stop) {
    name_this_thread("markerd-capture");
    capture_loop_->run(stop);
  });
  if (sweep_) {
    // A journal that cannot be read is reported, not fatal: markerd keeps
    // serving, and the operator decides what becomes of that run.
    try {
      sweep_->resume_from_journal();
    } catch (const std::exception& e) {
      spdlog::error("sweep: the interrupted run cannot be resumed: {}", e.what());
    }
  }
  // Last: no command can start a run before an interrupted one is resumed.
  control_->start();
  if (web_) web_->start();
}

void Daemon::stop() {
  if (stopped_) return;
  stopped_ = true;
  if (web_) web_->stop();  // first: it reads everything below
  control_->stop();
  if (sweep_) sweep_->stop();  // the run stays in the journal, to be resumed
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
  std::string line =
      fmt::format("camera {}: {}, {} frames, {} dropped", c.source, to_string(c.state), c.frames, p.dropped());
  if (c.state == CaptureState::waiting && !c.last_error.empty()) line += fmt::format(" ({})", c.last_error);
  if (rig_) {
    const rig::RigSnapshot s = rig_->snapshot();
    line += fmt::format("; rig: rail {:.1f} mm ({}), turntable {:.2f} deg ({})", s.rail.position,
                        rig::to_string(s.rail.state), s.turntable.position, rig::to_string(s.turntable.state));
  }
  if (sweep_) {
    const sweep::SweepProgress run = sweep_->progress();
    if (run.state != sweep::RunState::idle) {
      line += fmt::format("; sweep {}: {}, step {}/{}", run.run_id, sweep::to_string(run.state), run.steps_done,
                          run.steps_total);
    }
  }
  // One line: systemd's notification protocol separates assignments by newlines.
  std::replace(line.begin(), line.end(), '\n', ' ');
  return line;
}

}  // namespace markerd::daemon
