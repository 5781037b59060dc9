#include "markerd/daemon/daemon_config.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>

#include "markerd/base/read_file.hpp"

namespace markerd::daemon {

namespace {

std::filesystem::path resolve(const std::filesystem::path& dir, const std::string& path) {
  const std::filesystem::path p(path);
  return p.is_absolute() ? p : dir / p;
}

// systemd's directory variables may list several paths separated by ':'; the first is ours.
std::filesystem::path from_environment(const char* name, const char* fallback) {
  const char* value = std::getenv(name);  // NOLINT(concurrency-mt-unsafe): read at start, before threads
  if (value == nullptr || *value == '\0') return fallback;
  const std::string_view v(value);
  return std::filesystem::path(std::string(v.substr(0, v.find(':'))));
}

// Integers are read as int64 and cast once in range, so that a huge value is
// reported with its range rather than as "not an int".
int int_in(const ConfigTable& t, std::string_view key, int fallback, std::int64_t min, std::int64_t max,
           std::string_view unit = {}) {
  return static_cast<int>(t.optional<std::int64_t>(key, fallback, {min, max, unit}));
}

std::chrono::milliseconds positive_ms(const ConfigTable& t, std::string_view key, std::chrono::milliseconds fallback) {
  // Up to a day: the clocks' nanosecond counts are far from overflowing.
  return std::chrono::milliseconds(t.optional<std::int64_t>(key, fallback.count(), {1, 24LL * 3600 * 1000, "ms"}));
}

std::optional<detector::Insert> insert_from_name(std::string_view name) {
  for (const detector::Insert insert : {detector::Insert::none, detector::Insert::socket, detector::Insert::rocker}) {
    if (name == to_string(insert)) return insert;
  }
  return std::nullopt;
}

// "marker.mounting (line 12)": the other key of a contradiction, for its error.
std::string key_at(const ConfigTable& t, std::string_view key) {
  const toml::node* node = t.raw().get(key);
  const std::string name = t.key_path().empty() ? std::string(key) : fmt::format("{}.{}", t.key_path(), key);
  if (node != nullptr && node->source().begin.line > 0)
    return fmt::format("{} (line {})", name, node->source().begin.line);
  return name;
}

// [marker.frame]: the preset's dimensions, each overridable, in the ranges of
// the parts there are (SOCKET_FRAME.md: 70 to 95 mm outside, 5 to 15 mm high)
// with room to spare, and the renderer's own rules between them.
detector::CoverFrame parse_frame(const ConfigTable& t, detector::CoverFrame f) {
  t.allow_only({"outer_m", "opening_m", "height_m", "outer_roll_m", "inner_roll_m", "corner_radius_m", "reflectance"});
  f.outer_m = t.optional<double>("outer_m", f.outer_m, {0.01, 0.5, "m"});
  f.opening_m = t.optional<double>("opening_m", f.opening_m, {0.005, 0.5, "m"});
  f.height_m = t.optional<double>("height_m", f.height_m, {0.001, 0.05, "m"});
  f.outer_roll_m = t.optional<double>("outer_roll_m", f.outer_roll_m, {0, 0.05, "m"});
  f.inner_roll_m = t.optional<double>("inner_roll_m", f.inner_roll_m, {0, 0.05, "m"});
  f.corner_radius_m = t.optional<double>("corner_radius_m", f.corner_radius_m, {0, 0.25, "m"});
  f.reflectance = static_cast<float>(t.optional<double>("reflectance", f.reflectance, {0, 1}));
  if (const auto problem = detector::cover_frame_problem(f)) t.fail(problem->field, problem->why);
  return f;
}

MarkerSettings parse_marker(const ConfigTable& t) {
  t.allow_only({"family", "id", "size_m", "cut_hole", "mounting", "frame", "insert", "margin_m"});
  MarkerSettings m;
  const auto family_name = t.optional<std::string>("family", "frame8");
  const auto family = detector::family_from_name(family_name);
  if (!family) t.fail("family", fmt::format("unknown marker family \"{}\"", family_name));
  m.family = *family;
  const detector::FamilyInfo& info = detector::family_info(m.family);
  const auto id = t.optional<std::int64_t>("id", m.id);
  if (id < 0 || id >= info.id_count) {
    t.fail("id", fmt::format("must be 0 .. {} for {}, got {}", info.id_count - 1, info.name, id));
  }
  m.id = static_cast<int>(id);
  // From a printed thumbnail to a poster: beyond these the detector's pixel
  // sizes and the poses mean nothing.
  m.size_m = t.optional<double>("size_m", m.size_m, {0.001, 10, "m"});
  // `cut_hole = true` is older than `mounting` and still means a flat print
  // with its hole cut out; with both, they must tell the same story.
  const auto cut_hole = t.maybe<bool>("cut_hole");
  if (const auto name = t.maybe<std::string>("mounting")) {
    const auto mounting = sweep::mounting_from_name(*name);
    if (!mounting) {
      t.fail("mounting", fmt::format(R"(must be "paper", "socket", "switch" or "cut_hole", got "{}")", *name));
    }
    m.mounting = *mounting;
    m.mounting_stated = true;
    if (cut_hole && *cut_hole != m.cut_hole()) {
      t.fail("cut_hole",
             fmt::format("= {} contradicts {} = \"{}\", whose hole is {} (remove cut_hole: mounting says it)",
                         *cut_hole, key_at(t, "mounting"), *name, m.cut_hole() ? "cut out" : "printed white"));
    }
  } else if (cut_hole) {
    m.mounting = *cut_hole ? sweep::Mounting::cut_hole : sweep::Mounting::paper;
    m.mounting_stated = true;
  }
  const bool on_frame = m.mounting == sweep::Mounting::socket || m.mounting == sweep::Mounting::light_switch;
  if (auto frame = t.maybe_table("frame")) {
    if (!on_frame) {
      t.fail("frame", fmt::format("is set, but mounting is \"{}\" (only mounting = \"socket\" or \"switch\" has a "
                                  "frame)",
                                  to_string(m.mounting)));
    }
    m.frame = parse_frame(*frame,
                          m.mounting == sweep::Mounting::socket ? detector::socket_frame() : detector::switch_frame());
  } else if (on_frame) {
    m.frame = m.mounting == sweep::Mounting::socket ? detector::socket_frame() : detector::switch_frame();
  }
  if (m.frame && !(m.frame->opening_m < m.size_m)) {
    t.fail("size_m",
           fmt::format("({:g} m) must be more than the frame's opening ({:g} m): the print is glued around it",
                       m.size_m, m.frame->opening_m));
  }
  // What a socket or a switch has behind its frame; a cut hole shows the wall.
  m.insert = m.mounting == sweep::Mounting::socket         ? detector::Insert::socket
             : m.mounting == sweep::Mounting::light_switch ? detector::Insert::rocker
                                                           : detector::Insert::none;
  if (const auto name = t.maybe<std::string>("insert")) {
    const auto insert = insert_from_name(*name);
    if (!insert) t.fail("insert", fmt::format(R"(must be "none", "socket" or "rocker", got "{}")", *name));
    if (*insert != detector::Insert::none && !m.cut_hole()) {
      t.fail("insert", fmt::format("= \"{}\" cannot show: the marker is on paper, its hole printed white (set "
                                   "mounting = \"cut_hole\", \"socket\" or \"switch\")",
                                   *name));
    }
    m.insert = *insert;
  }
  m.margin_m = t.optional<double>("margin_m", m.margin_m, {0, 1, "m"});
  return m;
}

CameraSettings parse_camera(const ConfigTable& t, const std::filesystem::path& dir, const MarkerSettings& marker) {
  t.allow_only({"source", "model", "frame_timeout_ms", "reopen_delay_ms", "reopen_max_delay_ms", "sim", "v4l2",
                "libcamera", "file"});
  CameraSettings c;
  if (auto model = t.maybe<std::string>("model")) {
    c.model_path = resolve(dir, *model);
    try {
      // A camera file is a few KiB; OpenCV's reader would take a directory
      // or a FIFO for an empty or endless file.
      (void)check_regular_file(c.model_path, ConfigTable::kMaxFileBytes, "the camera model");
      c.model = detector::CameraModel::load(c.model_path);
    } catch (const std::exception& e) {
      t.fail("model", e.what());
    }
  }
  c.loop.frame_timeout = positive_ms(t, "frame_timeout_ms", c.loop.frame_timeout);
  c.loop.reopen_delay = positive_ms(t, "reopen_delay_ms", c.loop.reopen_delay);
  c.loop.reopen_max_delay = positive_ms(t, "reopen_max_delay_ms", c.loop.reopen_max_delay);
  if (c.loop.reopen_max_delay < c.loop.reopen_delay) {
    t.fail("reopen_max_delay_ms", fmt::format("must be at least reopen_delay_ms ({})", c.loop.reopen_delay.count()));
  }
  c.source_kind = t.required<std::string>("source");
  constexpr std::array kinds{"sim", "v4l2", "libcamera", "file"};
  if (std::find(kinds.begin(), kinds.end(), c.source_kind) == kinds.end()) {
    t.fail("source",
           fmt::format("must be one of \"v4l2\", \"libcamera\", \"file\", \"sim\"; got \"{}\"", c.source_kind));
  }
  // Only the chosen backend's table is read; another one present is a
  // leftover worth pointing out.
  for (const char* kind : kinds) {
    if (kind != c.source_kind && t.contains(kind)) {
      t.fail(kind, fmt::format("is set, but source is \"{}\" (remove the table or change the source)", c.source_kind));
    }
  }
  if (c.source_kind == "sim") {
    SimCameraSettings s;
    if (auto table = t.maybe_table("sim")) s = parse_sim_camera_settings(*table);
    s.family = marker.family;
    s.id = marker.id;
    s.marker_size_m = marker.size_m;
    s.cut_hole = marker.cut_hole();
    s.frame = marker.frame;
    s.insert = marker.insert;
    s.margin_m = marker.margin_m;
    if (!c.model) t.fail("model", "is required by the simulated camera (it renders through the camera model)");
    c.source = s;
  } else if (c.source_kind == "file") {
    const FileSourceSettings f = parse_file_source_settings(t.table("file"), dir);
    // A replay paced slower than the stall timeout would be reopened (and
    // restarted) before each frame.
    if (f.fps > 0 && 1000.0 / f.fps >= static_cast<double>(c.loop.frame_timeout.count())) {
      t.fail("frame_timeout_ms", fmt::format("must be longer than the file source's frame period ({:g} ms at {:g} fps)",
                                             1000.0 / f.fps, f.fps));
    }
    c.source = f;
  } else if (c.source_kind == "v4l2") {
    c.source = parse_v4l2_settings(t.table("v4l2"));
  } else if (c.source_kind == "libcamera") {
    c.source = parse_libcamera_settings(t.table("libcamera"));
  }
  return c;
}

DetectorSettings parse_detector(const ConfigTable& t) {
  t.allow_only({"workers", "frame8"});
  DetectorSettings d;
  d.workers = static_cast<std::size_t>(int_in(t, "workers", 1, 1, 16));
  if (auto f = t.maybe_table("frame8")) {
    f->allow_only({"decimate", "threshold_offset", "min_hole_side_px", "min_margin", "uniform_ids", "model_small_cells",
                   "blur_sigma_px"});
    detector::Frame8Options& o = d.frame8;
    o.decimate = int_in(*f, "decimate", o.decimate, 0, 8, "(0: automatic)");
    o.threshold_offset =
        int_in(*f, "threshold_offset", o.threshold_offset, detector::Frame8Options::kMinThresholdOffset,
               detector::Frame8Options::kMaxThresholdOffset, "grey levels");
    o.min_hole_side_px = f->optional<double>("min_hole_side_px", o.min_hole_side_px, {2, 1000, "px"});
    o.min_margin = f->optional<double>("min_margin", o.min_margin);
    if (!(o.min_margin >= 0 && o.min_margin < 1))
      f->fail("min_margin", fmt::format("must be 0 .. 1, got {}", o.min_margin));
    o.uniform_ids = f->optional<bool>("uniform_ids", o.uniform_ids);
    o.model_small_cells = f->optional<bool>("model_small_cells", o.model_small_cells);
    o.blur_sigma_px =
        f->optional<double>("blur_sigma_px", o.blur_sigma_px, {0, detector::Frame8Options::kMaxBlurSigmaPx, "px"});
  }
  return d;
}

PipelineConfig parse_pipeline(const ConfigTable& t) {
  t.allow_only({"policy", "slots"});
  PipelineConfig p;
  const auto policy = t.optional<std::string>("policy", "live");
  if (policy == "live") {
    p.policy = DropPolicy::live;
  } else if (policy == "lossless") {
    p.policy = DropPolicy::lossless;
  } else {
    t.fail("policy", fmt::format("must be \"live\" or \"lossless\", got \"{}\"", policy));
  }
  p.pool.slots = static_cast<std::size_t>(int_in(t, "slots", 8, 2, 256));
  return p;
}

LogSettings parse_log(const ConfigTable& t, const std::filesystem::path& dir) {
  t.allow_only({"directory", "prefix", "max_file_mb", "fsync", "fsync_interval_ms", "level"});
  LogSettings l;
  if (auto d = t.maybe<std::string>("directory")) {
    l.directory = resolve(dir, *d);
  } else {
    l.directory = from_environment("LOGS_DIRECTORY", "/var/log/markerd");
  }
  l.prefix = t.optional<std::string>("prefix", l.prefix);
  if (l.prefix.empty() || l.prefix.find_first_of("/\n") != std::string::npos || l.prefix.front() == '.') {
    t.fail("prefix",
           fmt::format("must be a file name prefix without '/', not starting with '.', got \"{}\"", l.prefix));
  }
  const auto mb = t.optional<std::int64_t>("max_file_mb", 256, {0, 1'000'000, "MiB (0: no limit)"});
  l.max_file_bytes = static_cast<std::uint64_t>(mb) << 20;
  const auto fsync = t.optional<std::string>("fsync", "interval");
  const auto policy = fsync_policy_from_name(fsync);
  if (!policy) t.fail("fsync", fmt::format("must be \"never\", \"interval\" or \"every_line\", got \"{}\"", fsync));
  l.fsync = *policy;
  l.fsync_interval = positive_ms(t, "fsync_interval_ms", l.fsync_interval);
  l.level = t.optional<std::string>("level", l.level);
  if (l.level != "trace" && l.level != "debug" && l.level != "info" && l.level != "warn" && l.level != "error") {
    t.fail("level", fmt::format("must be trace, debug, info, warn or error; got \"{}\"", l.level));
  }
  return l;
}

// "markerd.toml:51: control.socket", or without the line for a key not set.
std::string control_origin(const ConfigTable& t, std::string_view key) {
  const toml::node* node = t.raw().get(key);
  if (node != nullptr && node->source().begin.line > 0) {
    return fmt::format("{}:{}: control.{}", t.source(), node->source().begin.line, key);
  }
  return fmt::format("{}: control.{}", t.source(), key);
}

ControlConfig parse_control(const ConfigTable& t, const std::filesystem::path& dir) {
  t.allow_only({"socket", "group", "max_clients", "idle_timeout_ms"});
  ControlConfig c;
  if (auto s = t.maybe<std::string>("socket")) {
    c.socket = resolve(dir, *s);
  } else {
    c.socket = from_environment("RUNTIME_DIRECTORY", "/run/markerd") / "control.sock";
    c.socket_is_runtime_default = std::getenv("RUNTIME_DIRECTORY") == nullptr;  // NOLINT(concurrency-mt-unsafe)
  }
  // sockaddr_un's path holds 107 characters and a NUL.
  if (c.socket.string().size() > 107)
    t.fail("socket", fmt::format("is longer than 107 characters: {}", c.socket.string()));
  c.group = t.optional<std::string>("group", "");
  // Each client is a file descriptor and up to 2 MiB of buffers.
  c.max_clients = static_cast<std::size_t>(t.optional<int>("max_clients", 16, {1, 256, "clients"}));
  // Long enough for a person typing into socat; at most a day.
  c.idle_timeout = std::chrono::milliseconds(
      t.optional<std::int64_t>("idle_timeout_ms", c.idle_timeout.count(), {1000, 86'400'000, "ms"}));
  c.socket_origin = control_origin(t, "socket");
  c.group_origin = control_origin(t, "group");
  return c;
}

SweepSettings parse_sweep(const ConfigTable& t, const std::filesystem::path& dir) {
  t.allow_only({"directory"});
  SweepSettings s;
  if (auto d = t.maybe<std::string>("directory")) {
    s.directory = resolve(dir, *d);
  } else {
    s.directory = from_environment("STATE_DIRECTORY", "/var/lib/markerd");
  }
  return s;
}

}  // namespace

std::string_view to_string(detector::Insert insert) {
  switch (insert) {
    case detector::Insert::none: return "none";
    case detector::Insert::socket: return "socket";
    case detector::Insert::rocker: return "rocker";
  }
  return "?";
}

nlohmann::json marker_record(const MarkerSettings& marker) {
  nlohmann::json j{{"family", detector::family_info(marker.family).name},
                   {"id", marker.id},
                   {"size_m", marker.size_m},
                   {"mounting", sweep::to_string(marker.mounting)},
                   {"frame", nullptr},
                   {"insert", to_string(marker.insert)},
                   {"margin_m", marker.margin_m}};
  if (marker.frame) {
    const detector::CoverFrame& f = *marker.frame;
    j["frame"] = {{"outer_m", f.outer_m},
                  {"opening_m", f.opening_m},
                  {"height_m", f.height_m},
                  {"outer_roll_m", f.outer_roll_m},
                  {"inner_roll_m", f.inner_roll_m},
                  {"corner_radius_m", f.corner_radius_m},
                  // As written in the config, not as the float it is kept in.
                  {"reflectance", std::round(static_cast<double>(f.reflectance) * 1e6) / 1e6}};
  }
  return j;
}

DaemonConfig parse_daemon_config(const ConfigTable& root) {
  root.allow_only({"marker", "camera", "detector", "pipeline", "log", "control", "sweep", "web", "rig"});
  DaemonConfig config;
  config.source = root.source();
  config.config_dir = std::filesystem::path(root.source()).parent_path();
  const auto& dir = config.config_dir;
  // The rig inline ([rig] tables), or `rig = "FILE"`: a rig file of its own,
  // the one `markerctl rig --config` brings the rig up with.
  const toml::node* rig = root.raw().get("rig");
  if (rig != nullptr && rig->is_string()) {
    const std::filesystem::path file = resolve(dir, root.required<std::string>("rig"));
    // A missing file, a directory, a FIFO or a name too long is reported
    // here, at the key that names it.
    try {
      (void)check_regular_file(file, ConfigTable::kMaxFileBytes, "the rig file");
    } catch (const FileError& e) {
      if (e.missing()) root.fail("rig", fmt::format("no such rig file: {}", file.string()));
      root.fail("rig", e.what());
    }
    config.rig = rig::load_rig_config(file);
  } else if (rig != nullptr) {
    config.rig = rig::parse_rig_config(root);
  }
  if (auto t = root.maybe_table("marker")) config.marker = parse_marker(*t);
  config.camera = parse_camera(root.table("camera"), dir, config.marker);
  if (auto t = root.maybe_table("detector")) config.detector = parse_detector(*t);
  if (auto t = root.maybe_table("pipeline")) config.pipeline = parse_pipeline(*t);
  config.log = parse_log(root.maybe_table("log").value_or(ConfigTable::parse("", root.source())), dir);
  config.control = parse_control(root.maybe_table("control").value_or(ConfigTable::parse("", root.source())), dir);
  config.sweep = parse_sweep(root.maybe_table("sweep").value_or(ConfigTable::parse("", root.source())), dir);
  if (auto t = root.maybe_table("web")) config.web = parse_web_settings(*t);
  return config;
}

DaemonConfig load_daemon_config(const std::filesystem::path& path) {
  return parse_daemon_config(ConfigTable::load_file(path));
}

ControlSettings control_settings(const ControlConfig& config) {
  ControlSettings settings;
  settings.socket_path = config.socket;
  settings.group = config.group;
  settings.max_clients = config.max_clients;
  settings.idle_timeout = config.idle_timeout;
  return settings;
}

void check_control_setup(const ControlConfig& config) {
  const ControlSettings settings = control_settings(config);
  // The default directory outside systemd: the unit's RuntimeDirectory=
  // makes it when the service starts (and ExecStartPre's check sees it).
  const bool made_at_start = config.socket_is_runtime_default && !std::filesystem::exists(config.socket.parent_path());
  if (!made_at_start) {
    if (const auto problem = find_socket_path_problem(settings)) {
      throw ConfigError(fmt::format("{}: {}: {}", config.socket_origin, config.socket.string(), *problem));
    }
  }
  if (const auto problem = find_socket_group_problem(settings)) {
    throw ConfigError(fmt::format("{}: {}", config.group_origin, *problem));
  }
}

detector::DetectorConfig detector_config(const DaemonConfig& config) {
  detector::DetectorConfig d;
  d.family = config.marker.family;
  d.frame8 = config.detector.frame8;
  if (config.marker.mounting_stated) d.frame8.mounting = sweep::detector_mounting(config.marker.mounting);
  d.camera = config.camera.model;
  // Without a camera model there is no pose (docs/daemon.md): the detector
  // takes a marker size only together with a model.
  if (d.camera) d.marker_size_m = config.marker.size_m;
  return d;
}

void check_detector_setup(const DaemonConfig& config) {
  try {
    (void)detector::make_detector(detector_config(config));
  } catch (const detector::DetectorError& e) {
    throw ConfigError(fmt::format("{}: the detector cannot be made from [marker], [camera] and [detector]: {}",
                                  config.source, e.what()));
  }
}

}  // namespace markerd::daemon
