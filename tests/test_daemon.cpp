// markerd in-process: its config (errors name file, line and key; nothing
// starts on a bad one), and the simulated camera + simulated rig + detector +
// detection log end to end: the rig moves, the camera renders what the rig
// shows, and the log holds the right marker with a pose that agrees with the
// ground truth logged beside it.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <grp.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/detector/render.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

using test_support::Outcome;
using test_support::read_file;
using test_support::write_file;

class DaemonTest : public testing::Test {
 protected:
  void SetUp() override {
    test_support::prepare_markerd_dir(dir_);
    // The example rig, with simulated time running 50 times faster than real
    // time, so that homing and moves take about a second.
    test_support::write_sim_rig_config(dir_ / "rig.toml", 50.0);
  }

  [[nodiscard]] std::string base_config() const {
    return fmt::format(R"(rig = "rig.toml"

[marker]
family = "frame8"
id = 165
size_m = 0.08

[camera]
source = "sim"
model = "{}/config/cameras/thesis-640x480.yaml"
frame_timeout_ms = 2000

[camera.sim]
fps = 30
noise_sigma = 2.0
supersample = 2

[pipeline]
policy = "lossless"

[log]
directory = "logs"
fsync = "interval"
fsync_interval_ms = 100

[control]
socket = "control.sock"

[sweep]
directory = "state"
)",
                       MARKERD_SOURCE_DIR);
  }

  // The config with its first `line` replaced; the error it gives, and the
  // file:line that error must begin with.
  std::pair<std::string, std::string> error_with(const std::string& line, const std::string& replacement) {
    std::string text = base_config();
    const auto at = text.find(line);
    EXPECT_NE(at, std::string::npos) << line;
    if (at == std::string::npos) return {};
    text.replace(at, line.size(), replacement);
    const auto number = 1 + std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n');
    const fs::path path = dir_ / "markerd.toml";
    write_file(path, text);
    std::string error = "(no error)";
    try {
      (void)load_daemon_config(path);
    } catch (const ConfigError& e) {
      error = e.what();
    }
    return {error, fmt::format("{}:{}", path.string(), number)};
  }

  // The config with its first `line` replaced (the replacement may span
  // lines); the error it gives, and "file:line" of `at_text`, the part of
  // the replacement the error must name.
  std::pair<std::string, std::string> error_at(const std::string& line, const std::string& replacement,
                                               const std::string& at_text) {
    std::string text = base_config();
    const auto at = text.find(line);
    EXPECT_NE(at, std::string::npos) << line;
    if (at == std::string::npos) return {};
    text.replace(at, line.size(), replacement);
    const auto key_at = text.find(at_text, at);
    EXPECT_NE(key_at, std::string::npos) << at_text;
    const auto number = 1 + std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(key_at), '\n');
    const fs::path path = dir_ / "markerd.toml";
    write_file(path, text);
    std::string error = "(no error)";
    try {
      (void)load_daemon_config(path);
    } catch (const ConfigError& e) {
      error = e.what();
    }
    return {error, fmt::format("{}:{}", path.string(), number)};
  }

  // The config with `line` replaced, loaded.
  DaemonConfig config_with(const std::string& line, const std::string& replacement) {
    std::string text = base_config();
    const auto at = text.find(line);
    EXPECT_NE(at, std::string::npos) << line;
    if (at != std::string::npos) text.replace(at, line.size(), replacement);
    write_file(dir_ / "markerd.toml", text);
    return load_daemon_config(dir_ / "markerd.toml");
  }

  const test_support::TempDir temp_{"markerd-daemon"};
  const fs::path dir_ = temp_.path();
};

TEST_F(DaemonTest, TheExampleConfigLoads) {
  const DaemonConfig c = load_daemon_config(fs::path(MARKERD_SOURCE_DIR) / "config/markerd-sim.toml");
  EXPECT_EQ(c.camera.source_kind, "sim");
  ASSERT_TRUE(c.rig.has_value());
  EXPECT_EQ(c.rig->rail.axis.max_position, 2500.0);
  ASSERT_TRUE(c.camera.model.has_value());
  EXPECT_EQ(c.camera.model->width, 640);
  EXPECT_EQ(c.marker.id, 165);
}

TEST_F(DaemonTest, ConfigErrorsNameTheFileTheLineAndTheKey) {
  {
    const auto [error, where] = error_with("source = \"sim\"", "source = \"webcam\"");
    EXPECT_EQ(error,
              where + ": camera.source: must be one of \"v4l2\", \"libcamera\", \"file\", \"sim\"; got \"webcam\"");
  }
  {
    const auto [error, where] = error_with("fps = 30", "fps = -1");
    EXPECT_EQ(error, where + ": camera.sim.fps: must be > 0 and <= 1000, got -1");
  }
  {
    // The simulated camera's outages: an outage as long as the period would never end.
    const auto [error, where] = error_with("fps = 30", "outage_s = 3\noutage_every_s = 2\nfps = 30");
    EXPECT_EQ(error, where + ": camera.sim.outage_s: must be shorter than outage_every_s (2 s), got 3 s");
  }
  {
    const auto [error, where] = error_with("fps = 30", "outage_every_s = -1");
    EXPECT_EQ(error, where + ": camera.sim.outage_every_s: must be from 0 to 86400 s, got -1");
  }
  {
    const auto [error, where] = error_with("id = 165", "id = 300");
    EXPECT_EQ(error, where + ": marker.id: must be 0 .. 255 for frame8, got 300");
  }
  {
    const auto [error, where] = error_with("policy = \"lossless\"", "policy = \"fast\"");
    EXPECT_EQ(error, where + ": pipeline.policy: must be \"live\" or \"lossless\", got \"fast\"");
  }
  {
    const auto [error, where] = error_with("fsync = \"interval\"", "fsync = \"sometimes\"");
    EXPECT_EQ(error, where + ": log.fsync: must be \"never\", \"interval\" or \"every_line\", got \"sometimes\"");
  }
  {
    const auto [error, where] = error_with("noise_sigma = 2.0", "noise_sigma = 2.0\nnoise_sigm = 2.0");
    const std::string expected =
        fmt::format("{}:{}: camera.sim.noise_sigm: unknown key", where.substr(0, where.rfind(':')),
                    std::stoi(where.substr(where.rfind(':') + 1)) + 1);
    EXPECT_EQ(error.substr(0, expected.size()), expected) << error;
  }
  {
    const auto [error, where] = error_with("rig = \"rig.toml\"", "rig = \"nowhere.toml\"");
    EXPECT_EQ(error, where + ": rig: no such rig file: " + (dir_ / "nowhere.toml").string());
  }
  {
    // A name longer than the file system takes is the config's error at
    // the key, not std::filesystem's error escaping (a fuzz finding).
    const std::string name = std::string(300, 'r') + ".toml";
    const auto [error, where] = error_with("rig = \"rig.toml\"", "rig = \"" + name + "\"");
    EXPECT_EQ(error, where + ": rig: " + (dir_ / name).string() +
                         ": the rig file cannot be used: a name in its path is 305 bytes long, longer than the "
                         "255 a file system takes");
  }
  {
    // Numbers have ranges: no overflow into a short timeout, no "not an int".
    const auto [error, where] = error_with("frame_timeout_ms = 2000", "frame_timeout_ms = 9223372036854775807");
    EXPECT_EQ(error, where + ": camera.frame_timeout_ms: must be from 1 to 86400000 ms, got 9223372036854775807");
  }
  {
    const auto [error, where] = error_with("size_m = 0.08", "size_m = 1e300");
    EXPECT_EQ(error, where + ": marker.size_m: must be from 0.001 to 10 m, got 1e+300");
  }
  {
    const auto [error, where] = error_with("policy = \"lossless\"", "policy = \"lossless\"\nslots = 4294967298");
    EXPECT_EQ(error, where.substr(0, where.rfind(':')) + ":" +
                         std::to_string(std::stoi(where.substr(where.rfind(':') + 1)) + 1) +
                         ": pipeline.slots: must be from 2 to 256, got 4294967298");
  }
  {
    // A directory where a file belongs is named at the key that names it.
    fs::create_directories(dir_ / "rig.d");
    const auto [error, where] = error_with("rig = \"rig.toml\"", "rig = \"rig.d\"");
    EXPECT_EQ(error, where + ": rig: " + (dir_ / "rig.d").string() + ": the rig file is a directory, not a file");
  }
  {
    const auto [error, where] =
        error_with(fmt::format("model = \"{}/config/cameras/thesis-640x480.yaml\"", MARKERD_SOURCE_DIR),
                   fmt::format("model = \"{}\"", dir_.string()));
    EXPECT_EQ(error, where + ": camera.model: " + dir_.string() + ": the camera model is a directory, not a file");
  }
  {
    const auto [error, where] =
        error_with(fmt::format("model = \"{}/config/cameras/thesis-640x480.yaml\"", MARKERD_SOURCE_DIR), "");
    EXPECT_NE(error.find("camera.model: is required by the simulated camera"), std::string::npos) << error;
  }
  {
    const auto [error, where] = error_with("[camera.sim]", "[camera.v4l2]\ndevice = \"/dev/video0\"\n[camera.sim]");
    EXPECT_NE(error.find("camera.v4l2: is set, but source is \"sim\""), std::string::npos) << error;
  }
  {
    // The rig file's own errors name the rig file.
    test_support::TomlConfig::load(dir_ / "rig.toml").set("rig.rail.max_velocity", -50.0).write(dir_ / "rig.toml");
    const auto [error, where] = error_with("[marker]", "[marker]");
    EXPECT_NE(error.find((dir_ / "rig.toml").string() + ":"), std::string::npos) << error;
    EXPECT_NE(error.find("rig.rail.max_velocity: "), std::string::npos) << error;
  }
}

TEST_F(DaemonTest, TheShippedSocketConfigMountsTheMarkerOnASocketFrame) {
  const DaemonConfig c = load_daemon_config(fs::path(MARKERD_SOURCE_DIR) / "config/markerd-sim-socket.toml");
  EXPECT_EQ(c.marker.mounting, sweep::Mounting::socket);
  ASSERT_TRUE(c.marker.frame.has_value());
  EXPECT_EQ(c.marker.frame->outer_m, detector::socket_frame().outer_m);
  const auto& sim = std::get<SimCameraSettings>(c.camera.source);
  ASSERT_TRUE(sim.frame.has_value());
  EXPECT_EQ(sim.insert, detector::Insert::socket);
  EXPECT_TRUE(sim.cut_hole);
  // The same rig and camera as the paper config: a sweep differs by the marker only.
  const DaemonConfig paper = load_daemon_config(fs::path(MARKERD_SOURCE_DIR) / "config/markerd-sim.toml");
  EXPECT_EQ(paper.marker.mounting, sweep::Mounting::paper);
  EXPECT_EQ(c.camera.model_path.filename(), paper.camera.model_path.filename());
  const auto& paper_sim = std::get<SimCameraSettings>(paper.camera.source);
  EXPECT_EQ(sim.supersample, paper_sim.supersample);
  EXPECT_EQ(sim.noise_sigma, paper_sim.noise_sigma);
  EXPECT_EQ(sim.blur_sigma_px, paper_sim.blur_sigma_px);
  EXPECT_EQ(sim.clutter, paper_sim.clutter);
}

// The detector is told the mounting only where the config says it: then it
// searches for that mounting's holes alone; not said, for every kind.
TEST_F(DaemonTest, TheDetectorIsToldTheMountingTheConfigStates) {
  const auto told = [&](const std::string& marker) {
    return detector_config(config_with("size_m = 0.08", "size_m = 0.08" + marker)).frame8.mounting;
  };
  EXPECT_EQ(told(""), detector::Mounting::any);
  EXPECT_EQ(told("\nmounting = \"paper\""), detector::Mounting::paper);
  EXPECT_EQ(told("\nmounting = \"socket\""), detector::Mounting::cover_frame);
  EXPECT_EQ(told("\nmounting = \"switch\""), detector::Mounting::cover_frame);
  EXPECT_EQ(told("\nmounting = \"cut_hole\""), detector::Mounting::cut_hole);
  EXPECT_EQ(told("\ncut_hole = true"), detector::Mounting::cut_hole);
  EXPECT_EQ(told("\ncut_hole = false"), detector::Mounting::paper);
}

TEST_F(DaemonTest, TheMarkersMountingGivesTheSimulatedCameraItsFrameInsertAndMargin) {
  {
    const DaemonConfig c = config_with("size_m = 0.08", "size_m = 0.08");
    EXPECT_EQ(c.marker.mounting, sweep::Mounting::paper);
    EXPECT_FALSE(c.marker.frame.has_value());
    const auto& sim = std::get<SimCameraSettings>(c.camera.source);
    EXPECT_FALSE(sim.cut_hole);
    EXPECT_FALSE(sim.frame.has_value());
    EXPECT_EQ(sim.insert, detector::Insert::none);
    EXPECT_TRUE(sim.cover.empty());
  }
  {
    // The older key still means what it meant.
    const DaemonConfig c = config_with("size_m = 0.08", "size_m = 0.08\ncut_hole = true");
    EXPECT_EQ(c.marker.mounting, sweep::Mounting::cut_hole);
    EXPECT_TRUE(std::get<SimCameraSettings>(c.camera.source).cut_hole);
    EXPECT_EQ(std::get<SimCameraSettings>(c.camera.source).insert, detector::Insert::none);
  }
  {
    const DaemonConfig c = config_with("size_m = 0.08", "size_m = 0.08\nmounting = \"cut_hole\"\ncut_hole = true");
    EXPECT_EQ(c.marker.mounting, sweep::Mounting::cut_hole);
  }
  {
    const DaemonConfig c = config_with("size_m = 0.08", "size_m = 0.08\nmounting = \"socket\"\nmargin_m = 0.005");
    const auto& sim = std::get<SimCameraSettings>(c.camera.source);
    ASSERT_TRUE(sim.frame.has_value());
    EXPECT_EQ(sim.frame->height_m, detector::socket_frame().height_m);
    EXPECT_EQ(sim.insert, detector::Insert::socket);
    EXPECT_TRUE(sim.cut_hole);
    EXPECT_EQ(sim.margin_m, 0.005);
  }
  {
    const DaemonConfig c = config_with("size_m = 0.08", "size_m = 0.08\nmounting = \"switch\"");
    const auto& sim = std::get<SimCameraSettings>(c.camera.source);
    ASSERT_TRUE(sim.frame.has_value());
    EXPECT_EQ(sim.frame->outer_roll_m, detector::switch_frame().outer_roll_m);
    EXPECT_EQ(sim.insert, detector::Insert::rocker);
  }
  {
    // Each dimension overridable, the rest the preset's; the insert too.
    const DaemonConfig c = config_with("size_m = 0.08",
                                       "size_m = 0.08\nmounting = \"socket\"\ninsert = \"none\"\n[marker.frame]\n"
                                       "outer_m = 0.09\nopening_m = 0.055\nheight_m = 0.012\nouter_roll_m = 0.005\n"
                                       "inner_roll_m = 0.004\ncorner_radius_m = 0.008\nreflectance = 0.7");
    const auto& f = c.marker.frame;
    ASSERT_TRUE(f.has_value());
    EXPECT_EQ(f->outer_m, 0.09);
    EXPECT_EQ(f->opening_m, 0.055);
    EXPECT_EQ(f->height_m, 0.012);
    EXPECT_EQ(f->outer_roll_m, 0.005);
    EXPECT_EQ(f->inner_roll_m, 0.004);
    EXPECT_EQ(f->corner_radius_m, 0.008);
    EXPECT_EQ(f->reflectance, 0.7F);
    EXPECT_EQ(std::get<SimCameraSettings>(c.camera.source).insert, detector::Insert::none);
    const nlohmann::json record = marker_record(c.marker);
    EXPECT_EQ(record["mounting"], "socket");
    EXPECT_EQ(record["frame"]["height_m"], 0.012);
    EXPECT_EQ(record["frame"]["reflectance"], 0.7);
    EXPECT_EQ(record["insert"], "none");
  }
  {
    // The scene around the marker is the simulated camera's.
    const DaemonConfig c =
        config_with("supersample = 2",
                    "supersample = 2\ncover = [\"left\", \"top\"]\ncover_depth = 0.25\n"
                    "cover_reflectance = 0.9\ncover_height_m = 0.05\nclutter = false\nbackground_grey = 40\n"
                    "ambient = 0.5");
    const auto& sim = std::get<SimCameraSettings>(c.camera.source);
    EXPECT_EQ(sim.cover, (std::vector{detector::MarkerSide::left, detector::MarkerSide::top}));
    EXPECT_EQ(sim.cover_depth, 0.25);
    EXPECT_EQ(sim.cover_reflectance, 0.9F);
    EXPECT_EQ(sim.cover_height_m, 0.05);
    EXPECT_EQ(sim.background_grey, 40);
    EXPECT_EQ(sim.ambient, 0.5);
  }
}

TEST_F(DaemonTest, MountingAndSceneErrorsNameTheFileTheLineAndTheKey) {
  const std::string m = "size_m = 0.08";
  const auto expect = [&](const std::string& line, const std::string& replacement, const std::string& at_text,
                          const std::string& message) {
    const auto [error, where] = error_at(line, replacement, at_text);
    EXPECT_EQ(error, where + ": " + message) << replacement;
  };
  expect(m, m + "\nmounting = \"wall\"", "mounting",
         "marker.mounting: must be \"paper\", \"socket\", \"switch\" or \"cut_hole\", got \"wall\"");
  expect(m, m + "\nmounting = \"paper\"\ncut_hole = true", "cut_hole",
         "marker.cut_hole: = true contradicts marker.mounting (line 7) = \"paper\", whose hole is printed white "
         "(remove cut_hole: mounting says it)");
  expect(m, m + "\nmounting = \"socket\"\ncut_hole = false", "cut_hole",
         "marker.cut_hole: = false contradicts marker.mounting (line 7) = \"socket\", whose hole is cut out (remove "
         "cut_hole: mounting says it)");
  expect(m, m + "\ncut_hole = true\nmounting = \"paper\"", "cut_hole",
         "marker.cut_hole: = true contradicts marker.mounting (line 8) = \"paper\", whose hole is printed white "
         "(remove cut_hole: mounting says it)");
  expect(m, m + "\n[marker.frame]\nheight_m = 0.01", "[marker.frame]",
         "marker.frame: is set, but mounting is \"paper\" (only mounting = \"socket\" or \"switch\" has a frame)");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\nheight_m = 0.2", "height_m",
         "marker.frame.height_m: must be from 0.001 to 0.05 m, got 0.2");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\nheigth_m = 0.01", "heigth_m",
         "marker.frame.heigth_m: unknown key (known here: outer_m, opening_m, height_m, outer_roll_m, inner_roll_m, "
         "corner_radius_m, reflectance)");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\nopening_m = 0.09", "opening_m",
         "marker.frame.opening_m: must be less than outer_m (0.086 m), got 0.09 m");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\nouter_roll_m = 0.012", "outer_roll_m",
         "marker.frame.outer_roll_m: must not exceed height_m (0.01 m), got 0.012 m");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\ninner_roll_m = 0.01", "inner_roll_m",
         "marker.frame.inner_roll_m: with outer_roll_m (0.006 m) must not exceed the band's width, (outer_m - "
         "opening_m) / 2 = 0.015 m, got 0.01 m");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\ncorner_radius_m = 0.05", "corner_radius_m",
         "marker.frame.corner_radius_m: must not exceed half of outer_m (0.043 m), got 0.05 m");
  expect(m, m + "\nmounting = \"socket\"\n[marker.frame]\nreflectance = 1.5", "reflectance",
         "marker.frame.reflectance: must be from 0 to 1, got 1.5");
  expect(m, "size_m = 0.05\nmounting = \"socket\"", "size_m",
         "marker.size_m: (0.05 m) must be more than the frame's opening (0.056 m): the print is glued around it");
  expect(m, m + "\nmounting = \"socket\"\ninsert = \"plug\"", "insert",
         "marker.insert: must be \"none\", \"socket\" or \"rocker\", got \"plug\"");
  expect(m, m + "\ninsert = \"socket\"", "insert",
         "marker.insert: = \"socket\" cannot show: the marker is on paper, its hole printed white (set mounting = "
         "\"cut_hole\", \"socket\" or \"switch\")");
  expect(m, m + "\nmargin_m = -0.01", "margin_m", "marker.margin_m: must be from 0 to 1 m, got -0.01");

  const std::string s = "supersample = 2";
  expect(s, s + "\ncover = [\"middle\"]", "cover",
         "camera.sim.cover: sides are \"top\", \"right\", \"bottom\", \"left\"; got \"middle\"");
  expect(s, s + "\ncover = \"left\"", "cover", "camera.sim.cover: must be a list of sides, e.g. [\"left\"]");
  expect(s, s + "\ncover = [\"left\", \"left\"]", "cover", "camera.sim.cover: names \"left\" twice");
  expect(s, s + "\ncover = [\"left\"]\ncover_depth = 2", "cover_depth",
         "camera.sim.cover_depth: must be from 0.01 to 1 of the marker's size, got 2");
  expect(s, s + "\ncover_depth = 0.2", "cover_depth",
         "camera.sim.cover_depth: is set, but nothing is covered (cover = [\"left\"], ... names the sides)");
  expect(s, s + "\ncover = [\"top\"]\ncover_reflectance = -1", "cover_reflectance",
         "camera.sim.cover_reflectance: must be from 0 to 1, got -1");
  expect(s, s + "\ncover = [\"top\"]\ncover_height_m = 0", "cover_height_m",
         "camera.sim.cover_height_m: must be from 0.001 to 1 m, got 0");
  expect(s, s + "\nbackground_grey = 40", "background_grey",
         "camera.sim.background_grey: is the plain background's grey, but clutter = true draws random shapes "
         "instead (set clutter = false, or remove background_grey)");
  expect(s, s + "\nclutter = false\nbackground_grey = 300", "background_grey",
         "camera.sim.background_grey: must be from 0 to 255 grey levels, got 300");
  expect(s, s + "\nambient = 0", "ambient", "camera.sim.ambient: must be from 0.01 to 1, got 0");
}

// The detector's ranges are the config's: what the config accepts, markerd
// can start with (the fuzzer found threshold_offset = 0 and blur_sigma_px =
// 7.5 accepted here and refused by the detector at start).
TEST_F(DaemonTest, TheDetectorOptionsRangesAreTheDetectors) {
  const auto line_after = [](const std::string& where) {
    return where.substr(0, where.rfind(':')) + ":" + std::to_string(std::stoi(where.substr(where.rfind(':') + 1)) + 1);
  };
  {
    const auto [error, where] = error_with("[pipeline]", "[detector.frame8]\nthreshold_offset = 0\n[pipeline]");
    EXPECT_EQ(error,
              line_after(where) + ": detector.frame8.threshold_offset: must be from 1 to 100 grey levels, got 0");
  }
  {
    const auto [error, where] = error_with("[pipeline]", "[detector.frame8]\nthreshold_offset = 101\n[pipeline]");
    EXPECT_EQ(error,
              line_after(where) + ": detector.frame8.threshold_offset: must be from 1 to 100 grey levels, got 101");
  }
  {
    const auto [error, where] = error_with("[pipeline]", "[detector.frame8]\nblur_sigma_px = 7.5\n[pipeline]");
    EXPECT_EQ(error, line_after(where) + ": detector.frame8.blur_sigma_px: must be from 0 to 5 px, got 7.5");
  }
  // The limits themselves are accepted, by the config and by the detector.
  std::string text = base_config();
  text.replace(text.find("[pipeline]"), 10, "[detector.frame8]\nthreshold_offset = 100\nblur_sigma_px = 5\n[pipeline]");
  const DaemonConfig config = parse_daemon_config(ConfigTable::parse(text, (dir_ / "markerd.toml").string()));
  EXPECT_NO_THROW(check_detector_setup(config));
  EXPECT_NE(detector::make_detector(detector_config(config)), nullptr);
}

// docs/daemon.md: camera.model is optional for a real camera; without it the
// detections carry no pose. markerd could not start so ("a pose needs both a
// camera model and a marker size") while --check-config passed it.
TEST_F(DaemonTest, AConfigWithoutACameraModelMakesDetectorsWithoutPoses) {
  const std::string text = R"([marker]
family = "tag36h11"
id = 3
size_m = 0.1

[camera]
source = "libcamera"

[camera.libcamera]
camera = "/base/soc/i2c0mux/i2c@1/imx219@10"
width = 1280
height = 720
fps = 60
)";
  const DaemonConfig config = parse_daemon_config(ConfigTable::parse(text, (dir_ / "markerd.toml").string()));
  ASSERT_FALSE(config.camera.model.has_value());
  const detector::DetectorConfig detector = detector_config(config);
  EXPECT_FALSE(detector.camera.has_value());
  EXPECT_EQ(detector.marker_size_m, 0.0);
  EXPECT_NO_THROW(check_detector_setup(config));
  EXPECT_NE(detector::make_detector(detector), nullptr);

  // With the model, the marker size goes with it: poses.
  const DaemonConfig with_model =
      parse_daemon_config(ConfigTable::parse(base_config(), (dir_ / "markerd.toml").string()));
  EXPECT_EQ(detector_config(with_model).marker_size_m, 0.08);
}

// check_detector_setup (what --check-config runs) refuses whatever the
// detector refuses, in the config's words, so the check and the start agree
// even where the config's own checks fall short.
TEST_F(DaemonTest, TheDetectorCheckRefusesWhatMakeDetectorRefuses) {
  const fs::path path = dir_ / "markerd.toml";
  DaemonConfig config = parse_daemon_config(ConfigTable::parse(base_config(), path.string()));
  config.detector.frame8.threshold_offset = 0;
  try {
    check_detector_setup(config);
    ADD_FAILURE() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), path.string() +
                                         ": the detector cannot be made from [marker], [camera] and [detector]: "
                                         "frame8: threshold_offset must be 1..100 grey levels");
  }
}

// Home, move to a point of the thesis's viewing-angle sweep, and read the
// log: every line whole, the settled frames show marker 165 where the truth
// says it is.
TEST_F(DaemonTest, SimulatedCameraRigDetectorAndLogEndToEnd) {
  const fs::path path = dir_ / "markerd.toml";
  write_file(path, base_config());
  Daemon daemon(load_daemon_config(path));
  daemon.start();
  rig::Rig& rig = *daemon.rig();
  rig.rail().enable();
  rig.turntable().enable();
  rig.rail().home();
  rig.turntable().home();
  ASSERT_TRUE(rig.rail().wait_settled(60s)) << rig.rail().status().fault;
  ASSERT_TRUE(rig.turntable().wait_settled(60s)) << rig.turntable().status().fault;
  rig.rail().move_to(650.0);  // d = 300 + 650 mm
  rig.turntable().move_to(30.0);
  ASSERT_TRUE(rig.rail().wait_settled(60s));
  ASSERT_TRUE(rig.turntable().wait_settled(60s));
  const std::uint64_t settled_at = daemon.capture().status().frames;
  const auto deadline = std::chrono::steady_clock::now() + 60s;
  while (daemon.capture().status().frames < settled_at + 15 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(10ms);
  }
  EXPECT_TRUE(daemon.responsive());
  EXPECT_NE(daemon.status_line().find("camera sim 640x480@30: streaming"), std::string::npos) << daemon.status_line();

  // The control socket: status, the rig, and the detection stream, live.
  {
    ControlClient client(dir_ / "control.sock");
    const nlohmann::json status = client.call({{"cmd", "status"}});
    ASSERT_EQ(status["ok"], true) << status.dump();
    EXPECT_EQ(status["camera"]["state"], "streaming");
    EXPECT_EQ(status["camera"]["source"], "sim 640x480@30");
    EXPECT_GE(status["camera"]["frames"].get<std::uint64_t>(), settled_at + 15);
    EXPECT_EQ(status["pipeline"]["policy"], "lossless");
    EXPECT_EQ(status["log"]["file"], daemon.log().current_path());
    EXPECT_EQ(status["responsive"], true);
    // The frame rates over the last seconds: frames came, so both are
    // measured and above 0 (what they are depends on this machine).
    nlohmann::json rates = status;
    for (int i = 0; i < 300 && !(rates["camera"]["fps"].is_number() && rates["camera"]["fps"] > 0 &&
                                 rates["pipeline"]["detect_fps"].is_number() && rates["pipeline"]["detect_fps"] > 0);
         ++i) {
      std::this_thread::sleep_for(100ms);
      rates = client.call({{"cmd", "status"}});
    }
    EXPECT_GT(rates["camera"]["fps"].get<double>(), 0) << rates.dump();
    EXPECT_GT(rates["pipeline"]["detect_fps"].get<double>(), 0) << rates.dump();
    const nlohmann::json rig_status = client.call({{"cmd", "rig.status"}});
    ASSERT_EQ(rig_status["ok"], true) << rig_status.dump();
    EXPECT_NE(rig_status.dump().find("650"), std::string::npos) << rig_status.dump();
    const nlohmann::json cameras = client.call({{"cmd", "cameras"}});
    ASSERT_EQ(cameras["ok"], true) << cameras.dump();
    EXPECT_TRUE(cameras["v4l2"].is_array());
    EXPECT_TRUE(cameras["libcamera"].is_array());

    ControlClient follower(dir_ / "control.sock");
    follower.send({{"cmd", "detections"}});
    int records = 0;
    for (int lines = 0; records < 3 && lines < 20; ++lines) {
      const auto line = follower.read_line(std::chrono::milliseconds(10000));
      ASSERT_TRUE(line.has_value());
      const auto record = nlohmann::json::parse(*line);
      if (!record.contains("schema")) continue;  // the stream's own acknowledgement
      ++records;
      EXPECT_EQ(record["detections"][0]["id"], 165) << *line;
    }
    EXPECT_EQ(records, 3);
  }
  const std::string log_path = daemon.log().current_path();
  daemon.stop();

  // Motion stopped and disabled.
  EXPECT_EQ(rig.rail().status().state, rig::AxisState::disabled);
  EXPECT_EQ(rig.turntable().status().state, rig::AxisState::disabled);

  const std::string text = read_file(log_path);
  ASSERT_FALSE(text.empty());
  ASSERT_EQ(text.back(), '\n');
  std::istringstream lines(text);
  std::string line;
  int total = 0, at_point = 0, detected = 0;
  std::uint64_t previous_sequence = 0;
  while (std::getline(lines, line)) {
    const auto record = nlohmann::json::parse(line);  // throws on a torn line
    const auto sequence = record["frame"]["sequence"].get<std::uint64_t>();
    if (total > 0) {
      EXPECT_GT(sequence, previous_sequence);
    }
    previous_sequence = sequence;
    ++total;
    EXPECT_EQ(record["status"], "ok") << line;
    const auto& r = record["rig"];
    ASSERT_TRUE(r.is_object()) << line;
    if (!(r["settled"].get<bool>() && std::abs(r["rail"]["position_mm"].get<double>() - 650.0) < 1e-6 &&
          std::abs(r["turntable"]["position_deg"].get<double>() - 30.0) < 1e-6)) {
      continue;
    }
    ++at_point;
    EXPECT_NEAR(record["truth"]["distance_m"].get<double>(), 0.95, 1e-9);
    EXPECT_NEAR(record["truth"]["yaw_deg"].get<double>(), 30.0, 1e-9);
    for (const auto& d : record["detections"]) {
      if (d["id"] != 165) continue;
      ++detected;
      const auto& error = d["pose"]["best"]["error"];
      EXPECT_LT(error["translation_pct"].get<double>(), 2.0) << line;
      break;
    }
  }
  EXPECT_GE(at_point, 15);
  EXPECT_GE(detected, at_point * 9 / 10) << detected << " of " << at_point;
}

TEST_F(DaemonTest, ReopeningTheLogAfterARenameStartsANewFile) {
  const fs::path path = dir_ / "markerd.toml";
  std::string text = base_config();
  text.replace(text.find("rig = \"rig.toml\""), 16, "");  // a daemon without a rig
  write_file(path, text);
  Daemon daemon(load_daemon_config(path));
  EXPECT_EQ(daemon.rig(), nullptr);
  daemon.start();
  const fs::path first = daemon.log().current_path();
  const auto wait_for_lines = [&](const fs::path& file, std::size_t lines) {
    const auto deadline = std::chrono::steady_clock::now() + 30s;
    while (std::chrono::steady_clock::now() < deadline) {
      const std::string t = read_file(file);
      if (static_cast<std::size_t>(std::count(t.begin(), t.end(), '\n')) >= lines) return true;
      std::this_thread::sleep_for(10ms);
    }
    return false;
  };
  ASSERT_TRUE(wait_for_lines(first, 3));
  fs::rename(first, dir_ / "logs" / "rotated.jsonl");  // what logrotate does
  daemon.reopen_logs();
  ASSERT_TRUE(wait_for_lines(first, 3));  // the same name, a new file
  daemon.stop();
  const std::string rotated = read_file(dir_ / "logs" / "rotated.jsonl");
  ASSERT_FALSE(rotated.empty());
  EXPECT_EQ(rotated.back(), '\n');
  // Without a rig: "rig":null and no truth.
  const auto record = nlohmann::json::parse(rotated.substr(0, rotated.find('\n')));
  EXPECT_TRUE(record["rig"].is_null());
  EXPECT_TRUE(record["truth"].is_null());
}

// The markerd binary's --check-config, what systemd's ExecStartPre runs:
// exit 0 and a summary for a good file, 1 and the file:line:key for a bad one.
Outcome run_markerd(const std::vector<std::string>& args) {
  std::vector<std::string> argv{MARKERD_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  Outcome r = test_support::run_program(argv);
  if (r.timed_out) ADD_FAILURE() << "markerd did not finish: " << r.describe();
  return r;
}

TEST_F(DaemonTest, CheckConfigSaysWhatIsWrongAndStartsNothing) {
  const fs::path path = dir_ / "markerd.toml";
  write_file(path, base_config());
  const Outcome good = run_markerd({"--check-config", "--config", path.string()});
  EXPECT_EQ(good.code, 0) << good.err;
  EXPECT_EQ(good.out.rfind(path.string() + ": ok (camera: sim, marker: frame8 id 165 0.08 m on paper,", 0), 0U)
      << good.out;
  // The mounting is part of what it says it sets up.
  std::string socket = base_config();
  socket.replace(socket.find("size_m = 0.08"), 13, "size_m = 0.08\nmounting = \"socket\"");
  write_file(path, socket);
  const Outcome on_socket = run_markerd({"--check-config", "--config", path.string()});
  EXPECT_EQ(on_socket.code, 0) << on_socket.err;
  EXPECT_NE(on_socket.out.find("marker: frame8 id 165 0.08 m on a socket frame,"), std::string::npos) << on_socket.out;

  std::string text = base_config();
  text.replace(text.find("fps = 30"), 8, "fps = -1");
  write_file(path, text);
  const Outcome bad = run_markerd({"--check-config", "--config", path.string()});
  EXPECT_EQ(bad.code, 1);
  EXPECT_NE(bad.err.find(path.string() + ":"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("camera.sim.fps: must be > 0 and <= 1000, got -1"), std::string::npos) << bad.err;
  // Nothing started: no detection log, no socket.
  EXPECT_TRUE(fs::is_empty(dir_ / "logs"));
  EXPECT_FALSE(fs::exists(dir_ / "control.sock"));

  // Run for real with the bad file: the same error, exit 1, nothing written.
  const Outcome start = run_markerd({"--config", path.string()});
  EXPECT_EQ(start.code, 1);
  EXPECT_NE(start.err.find("camera.sim.fps: must be > 0 and <= 1000, got -1"), std::string::npos) << start.err;
  EXPECT_TRUE(fs::is_empty(dir_ / "logs"));

  const Outcome usage = run_markerd({"--no-such-option"});
  EXPECT_EQ(usage.code, 2);
}

// A config without a camera model passes --check-config because markerd
// starts with it: the check makes the detectors as the start does.
TEST_F(DaemonTest, CheckConfigPassesAConfigWithoutACameraModel) {
  const fs::path path = dir_ / "markerd.toml";
  std::string text = base_config();
  const std::string model = fmt::format("model = \"{}/config/cameras/thesis-640x480.yaml\"\n", MARKERD_SOURCE_DIR);
  text.replace(text.find(model), model.size(), "");
  const std::string sim = "source = \"sim\"";
  text.replace(text.find(sim), sim.size(), "source = \"file\"");
  const std::string sim_table = "[camera.sim]\nfps = 30\nnoise_sigma = 2.0\nsupersample = 2\n";
  text.replace(text.find(sim_table), sim_table.size(),
               fmt::format("[camera.file]\npath = \"{}/tests\"\n", MARKERD_SOURCE_DIR));
  write_file(path, text);
  const Outcome outcome = run_markerd({"--check-config", "--config", path.string()});
  EXPECT_EQ(outcome.code, 0) << outcome.err;
  EXPECT_EQ(outcome.out.rfind(path.string() + ": ok (camera: file", 0), 0U) << outcome.out << outcome.err;
}

// What would keep the control socket from being set up is found by
// --check-config (systemd's ExecStartPre), naming the file, line and key,
// rather than by the start that follows it.
TEST_F(DaemonTest, CheckConfigFindsWhatWouldKeepTheControlSocketFromStarting) {
  const fs::path path = dir_ / "markerd.toml";
  const std::string control = "socket = \"control.sock\"";
  const auto check_with = [&](const std::string& lines) {
    std::string text = base_config();
    const auto at = text.find(control);
    text.replace(at, control.size(), lines);
    write_file(path, text);
    const auto first = 1 + std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n');
    return std::pair(run_markerd({"--check-config", "--config", path.string()}), first);
  };
  {
    const auto [outcome, line] = check_with("socket = \"control.sock\"\ngroup = \"markerd-test-no-such-group\"");
    EXPECT_EQ(outcome.code, 1);
    EXPECT_NE(outcome.err.find(fmt::format("{}:{}: control.group: group 'markerd-test-no-such-group' does not exist",
                                           path.string(), line + 1)),
              std::string::npos)
        << outcome.err;
  }
  {
    const auto [outcome, line] = check_with("socket = \"nodir/c.sock\"");
    EXPECT_EQ(outcome.code, 1);
    EXPECT_NE(
        outcome.err.find(fmt::format("{}:{}: control.socket: {}: its directory {}: No such file or directory",
                                     path.string(), line, (dir_ / "nodir/c.sock").string(), (dir_ / "nodir").string())),
        std::string::npos)
        << outcome.err;
  }
  {
    write_file(dir_ / "not-a-socket", "text");
    const auto [outcome, line] = check_with("socket = \"not-a-socket\"");
    EXPECT_EQ(outcome.code, 1);
    EXPECT_NE(outcome.err.find(fmt::format("{}:{}: control.socket: {}: exists and is not a socket", path.string(), line,
                                           (dir_ / "not-a-socket").string())),
              std::string::npos)
        << outcome.err;
  }
  {
    const auto [outcome, line] = check_with("socket = \"control.sock\"\nidle_timeout_ms = 10");
    EXPECT_EQ(outcome.code, 1);
    EXPECT_NE(outcome.err.find(fmt::format("{}:{}: control.idle_timeout_ms: must be from 1000 to 86400000 ms, got 10",
                                           path.string(), line + 1)),
              std::string::npos)
        << outcome.err;
  }
  {
    const auto [outcome, line] = check_with("socket = \"control.sock\"\nmax_clients = 0");
    EXPECT_EQ(outcome.code, 1);
    EXPECT_NE(outcome.err.find(fmt::format("{}:{}: control.max_clients: must be from 1 to 256 clients, got 0",
                                           path.string(), line + 1)),
              std::string::npos)
        << outcome.err;
  }
  // The process's own group, and settings in range: fine.
  const group* own = ::getgrgid(::getegid());
  ASSERT_NE(own, nullptr);
  const auto [good, line] = check_with(
      fmt::format("socket = \"control.sock\"\ngroup = \"{}\"\nmax_clients = 4\nidle_timeout_ms = 5000", own->gr_name));
  EXPECT_EQ(good.code, 0) << good.err;
  const DaemonConfig config = load_daemon_config(path);
  EXPECT_EQ(config.control.max_clients, 4U);
  EXPECT_EQ(config.control.idle_timeout, 5s);
  EXPECT_FALSE(fs::exists(dir_ / "control.sock")) << "a check makes nothing";

  // The default socket outside systemd: its directory is the unit's
  // RuntimeDirectory=, made at start, so its absence is no error here.
  ControlConfig runtime_default;
  runtime_default.socket = dir_ / "run-markerd" / "control.sock";
  runtime_default.socket_is_runtime_default = true;
  EXPECT_NO_THROW(check_control_setup(runtime_default));
  runtime_default.socket_is_runtime_default = false;
  EXPECT_THROW(check_control_setup(runtime_default), ConfigError);
}

// Every command markerd serves, its own, the rig's, the sweep's and the
// server's, refuses an argument it does not take, naming it, before it does
// anything; the ones that stop the rig are served beyond the client limit.
TEST_F(DaemonTest, EveryCommandRefusesAnArgumentItDoesNotTake) {
  const fs::path path = dir_ / "markerd.toml";
  write_file(path, base_config());
  Daemon daemon(load_daemon_config(path));
  daemon.start();
  ControlClient client(dir_ / "control.sock");
  const nlohmann::json help = client.call({{"cmd", "help"}});
  ASSERT_EQ(help["ok"], true) << help.dump();
  std::vector<std::string> beyond_limit;
  for (const auto& command : help["commands"]) {
    const std::string name = command["name"];
    const nlohmann::json reply = client.call({{"cmd", name}, {"no_such_argument", 1}});
    EXPECT_EQ(reply["ok"], false) << name << ": " << reply.dump();
    EXPECT_EQ(reply.value("error", std::string()).rfind("unknown argument 'no_such_argument'", 0), 0U)
        << name << ": " << reply.dump();
    if (command.value("beyond_client_limit", false)) beyond_limit.push_back(name);
  }
  EXPECT_GE(help["commands"].size(), 13U);
  EXPECT_EQ(beyond_limit, (std::vector<std::string>{"rig.status", "rig.stop", "sweep.abort", "sweep.pause"}));
  EXPECT_EQ(daemon.rig()->rail().status().state, rig::AxisState::disabled) << "nothing was done";
}

}  // namespace
}  // namespace markerd::daemon
