#pragma once
// markerd assembled: the rig, the camera and its capture thread, the
// detection pipeline and the detection log, built from one DaemonConfig.
// markerd's main() (daemon/markerd_main.cpp) owns one, wires it to systemd
// and to the signals; the end-to-end tests run one in-process.

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "markerd/daemon/capture/capture_loop.hpp"
#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/control/line_broadcast.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/daemon/detection_log_sink.hpp"
#include "markerd/daemon/frame_annotation.hpp"
#include "markerd/daemon/latest_frame.hpp"
#include "markerd/daemon/pipeline.hpp"
#include "markerd/daemon/web/web_server.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/sweep/runner.hpp"

namespace markerd::daemon {

// The camera backend a config names.
std::unique_ptr<CaptureSource> make_capture_source(const CameraSettings& camera,
                                                   const std::optional<rig::RigConfig>& rig);

class Daemon {
 public:
  // Builds everything and opens what must be there at start (the rig's
  // devices, the detection log); throws (rig::DeviceLockError when another
  // process holds one of the rig's devices, rig::DriveError, LogWriteError,
  // CaptureError of kind config, ...) naming what failed. A camera that is
  // not there yet is no reason to fail: the capture loop waits for it.
  explicit Daemon(DaemonConfig config);
  // The same with the rig's device locks taken already, or none to take
  // them here: markerd's main() waits for them while another process holds
  // one, rather than failing.
  Daemon(DaemonConfig config, std::optional<rig::DeviceLock> rig_lock);
  ~Daemon();  // stop()
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Opens the control socket (ControlSocketError when it cannot: another
  // markerd on it, a missing group) and, when [web] enables it, the web page
  // (WebServerError when it cannot listen), starts the capture thread, and
  // resumes the sweep the journal names, if one was cut off.
  void start();
  // Closes the control socket, stops capture, detects and logs what is in
  // flight (by the pipeline's policy), stops the axes and disables them, and
  // syncs the log. Idempotent.
  void stop();
  // SIGHUP: the detection log reopens its file (logrotate renamed it).
  void reopen_logs() noexcept { sink_->request_reopen(); }

  // The threads that must keep going are going: the capture loop comes
  // round, and the rig publishes snapshots. What the systemd watchdog is
  // pinged on; a lost camera is no reason to be restarted, a hung thread is.
  [[nodiscard]] bool responsive() const;
  // One line for systemd's STATUS=.
  [[nodiscard]] std::string status_line() const;

  [[nodiscard]] const DaemonConfig& config() const { return config_; }
  [[nodiscard]] rig::Rig* rig() { return rig_.get(); }
  [[nodiscard]] const rig::Rig* rig() const { return rig_.get(); }
  [[nodiscard]] const CaptureLoop& capture() const { return *capture_loop_; }
  [[nodiscard]] const CaptureSource& source() const { return *source_; }
  [[nodiscard]] CaptureSource& source() { return *source_; }  // fault injection (the tests)
  [[nodiscard]] const Pipeline& pipeline() const { return *pipeline_; }
  [[nodiscard]] DetectionLogSink& log() { return *sink_; }
  [[nodiscard]] const DetectionLogSink& log() const { return *sink_; }
  [[nodiscard]] const ControlServer& control() const { return *control_; }
  // The newest frame, as `snapshot` and the web page see it.
  [[nodiscard]] const LatestFrame& latest_frame() const { return *latest_; }
  // What annotating a frame needs: the camera model, the marker's size, the axes' units.
  [[nodiscard]] AnnotationContext annotation_context() const;
  // The web page's server; null unless [web] enables it.
  [[nodiscard]] const WebServer* web() const { return web_.get(); }
  // The sweep runner; null without a rig.
  [[nodiscard]] sweep::SweepRunner* sweep() { return sweep_.get(); }
  [[nodiscard]] const sweep::SweepRunner* sweep() const { return sweep_.get(); }

 private:
  void stop_motion() noexcept;
  void register_commands();
  class SweepEnvironment;

  DaemonConfig config_;
  // Taken before the rig opens its devices and released after it has closed
  // them (members are destroyed in reverse order): no other process drives
  // the rig's motors while this one may.
  std::optional<rig::DeviceLock> rig_lock_;
  std::unique_ptr<rig::Rig> rig_;
  std::unique_ptr<CaptureSource> source_;
  std::unique_ptr<LatestFrame> latest_;  // before the sink that offers it frames
  std::unique_ptr<DetectionLogSink> sink_;
  std::unique_ptr<Pipeline> pipeline_;
  std::unique_ptr<CaptureLoop> capture_loop_;
  // The detection log's lines, as `markerctl detections` follows them.
  std::unique_ptr<LineBroadcast> detections_;
  std::unique_ptr<ControlServer> control_;
  std::unique_ptr<SweepEnvironment> sweep_environment_;
  std::unique_ptr<sweep::SweepRunner> sweep_;  // after everything it uses
  std::unique_ptr<WebServer> web_;             // after everything it shows
  std::jthread capture_thread_;
  bool stopped_ = false;
};

}  // namespace markerd::daemon
