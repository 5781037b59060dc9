#pragma once
// markerd's configuration: one TOML file (reference: docs/daemon.md),
// parsed once into these structs. Every mistake is a ConfigError naming the
// file, the line and the key, and keys nobody reads are mistakes too, so a
// typo cannot pass silently. Nothing deeper than this reads TOML.

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <variant>

#include "markerd/daemon/capture/capture_loop.hpp"
#include "markerd/daemon/capture/file_source.hpp"
#include "markerd/daemon/capture/libcamera_source.hpp"
#include "markerd/daemon/capture/sim_camera.hpp"
#include "markerd/daemon/capture/v4l2_settings.hpp"
#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/log_writer.hpp"
#include "markerd/daemon/pipeline.hpp"
#include "markerd/daemon/web/web_settings.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"

namespace markerd::daemon {

// [marker]: the marker under test, as it stands on the turntable: the print
// and what it is mounted on. A real rig's config says so too: a sweep plan
// naming another mounting is refused (sweep::marker_problem).
struct MarkerSettings {
  detector::Family family = detector::Family::frame8;
  int id = 165;  // what the simulated camera shows
  double size_m = 0.08;
  sweep::Mounting mounting = sweep::Mounting::paper;
  // Whether the config says it (`mounting`, or `cut_hole`): only then is the
  // detector told it, and searches for that mounting's holes alone.
  bool mounting_stated = false;
  // socket, switch: the cover frame (the preset with [marker.frame]'s overrides).
  std::optional<detector::CoverFrame> frame;
  detector::Insert insert = detector::Insert::none;  // what the hole shows, when it is cut out
  double margin_m = 0;                               // white paper beyond the marker's outer edge

  // frame8's hole is cut out (on a frame it always is).
  [[nodiscard]] bool cut_hole() const { return mounting != sweep::Mounting::paper; }
};

// "none", "socket", "rocker": the config's words, markerctl render's --insert.
[[nodiscard]] std::string_view to_string(detector::Insert insert);
// The marker as a run's start record keeps it: family, id, size, mounting,
// the frame's dimensions, the insert, the margin.
[[nodiscard]] nlohmann::json marker_record(const MarkerSettings& marker);

// One alternative per capture backend.
using CameraSourceSettings = std::variant<SimCameraSettings, V4l2Settings, LibcameraSettings, FileSourceSettings>;

struct CameraSettings {
  CameraSourceSettings source;
  std::string source_kind;  // "sim", "v4l2", ...
  // The intrinsics (OpenCV calibration YAML): poses need them, the
  // simulated camera renders through them.
  std::optional<detector::CameraModel> model;
  std::filesystem::path model_path;
  CaptureLoopSettings loop;
};

struct DetectorSettings {
  std::size_t workers = 1;  // detection threads, each with its own detector
  detector::Frame8Options frame8;
};

struct LogSettings {
  std::filesystem::path directory;  // the detection logs; must exist
  std::string prefix = "detections";
  std::uint64_t max_file_bytes = 256ULL << 20;
  FsyncPolicy fsync = FsyncPolicy::interval;
  std::chrono::milliseconds fsync_interval{1000};
  std::string level = "info";  // the daemon's own log: trace, debug, info, warn, error
};

struct ControlConfig {
  std::filesystem::path socket;
  std::string group;  // empty: the daemon's own group
  std::size_t max_clients = 16;
  std::chrono::milliseconds idle_timeout{60'000};
  // "markerd.toml:51: control.socket": where each is set, for the errors
  // check_control_setup() finds after parsing.
  std::string socket_origin;
  std::string group_origin;
  // Not set, and not under systemd: /run/markerd/control.sock, whose
  // directory the unit's RuntimeDirectory= makes when it starts markerd.
  bool socket_is_runtime_default = false;
};

// [sweep]: where runs keep their records and the journal that resumes them.
struct SweepSettings {
  std::filesystem::path directory;  // runs/ and the journal live here; must exist
};

struct DaemonConfig {
  std::string source;                // the file it was read from
  std::filesystem::path config_dir;  // relative paths are relative to it
  MarkerSettings marker;
  CameraSettings camera;
  DetectorSettings detector;
  PipelineConfig pipeline;
  LogSettings log;
  ControlConfig control;
  SweepSettings sweep;
  WebSettings web;                    // [web]: the read-only web page, off by default
  std::optional<rig::RigConfig> rig;  // absent: a daemon that only watches
};

// Reads and checks the whole file. ConfigError on any mistake. Directories
// left unset default to systemd's LOGS_DIRECTORY and RUNTIME_DIRECTORY when
// set (the unit's LogsDirectory=, RuntimeDirectory=, StateDirectory=), else
// /var/log/markerd, /run/markerd and /var/lib/markerd.
DaemonConfig load_daemon_config(const std::filesystem::path& path);
DaemonConfig parse_daemon_config(const ConfigTable& root);

// The control server's settings from [control].
[[nodiscard]] ControlSettings control_settings(const ControlConfig& config);
// What would keep markerd from setting up its control socket (the
// directory missing or closed to this process, a file there that is not a
// socket, a group that does not exist or that this process is not in), as a
// ConfigError naming the file, the line and the key. For --check-config,
// which runs as markerd will (systemd's ExecStartPre): parsing alone does
// not look, so that tools reading the config elsewhere are not refused.
// The default socket's directory, which systemd makes at start, may be
// missing outside systemd.
void check_control_setup(const ControlConfig& config);

// The detector configuration the pipeline's workers are made with.
[[nodiscard]] detector::DetectorConfig detector_config(const DaemonConfig& config);
// Makes a detector from the config as markerd does at start, so that
// --check-config refuses whatever the start would: a ConfigError naming the
// file and the detector's complaint.
void check_detector_setup(const DaemonConfig& config);

}  // namespace markerd::daemon
