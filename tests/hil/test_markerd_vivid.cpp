// markerd itself, its own binary, against the kernel's vivid driver. Runs
// inside Debian's kernel under qemu (ctest's hil_markerd_vivid,
// tools/hil/hil-run), as root, with vivid loaded as one capture and one
// output node and the vivid-loop setup step's variables (HIL_VIVID_CAPTURE,
// HIL_VIVID_OUTPUT, HIL_VIVID_PLATFORM). Outside such a guest it skips.
//
// A feeder thread writes rendered frame markers into vivid's HDMI output,
// which vivid loops to the HDMI input of the capture node, where markerd
// captures them through its V4L2 source, detects them and logs them. The
// test checks the detection log against what it rendered (ids and poses:
// without a rig the log carries no truth), then unplugs the camera (unbinds
// vivid's platform device while markerd streams), checks that markerd says
// so on its control socket and keeps running, plugs it back in (binds the
// device again) and checks that markerd streams and logs again by itself,
// with a control set at run time before the unplug set again on the new
// device, and finally stops it with SIGTERM.
//
// markerd opens the camera by a stable name, /dev/v4l/by-path/platform-
// vivid.0-video-index0, which the test makes and removes as udev would on
// a real machine. That is also what keeps the replug deterministic: a new
// vivid device starts its HDMI input at 1280x720 and would scale that test
// pattern to the 640x480 markerd asks for, so the test puts the new capture
// node on the feeder's 640x480 timings first and only then makes the name
// that markerd is waiting for.

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>  // environ (g++ defines _GNU_SOURCE)

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/control/control_client.hpp"
#include "markerd_child.hpp"
#include "vivid_scene_feeder.hpp"

namespace markerd::hil {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

// 1 s of vivid's 60 Hz per scene: long against the loop's lag below, short
// enough that markerd sees both scenes within a few seconds.
constexpr std::uint32_t kFramesPerScene = 60;
// A frame captured at time t shows a buffer the feeder queued before t (vivid
// stamps a frame with the nominal end of its period, up to a period and a
// scheduler tick ahead of the clock) and at most the output queue's depth
// before it (8 frames, 133 ms at 60 Hz), with room for TCG's scheduling.
constexpr auto kTimestampLead = 50ms;
constexpr auto kLoopLag = 500ms;
// The pose from the sub-pixel corners of an 80 mm marker at 0.5 m, against
// the rendered one. Measured: 0.14 % and 0.05 degrees (docs/hil.md); the
// limits take another detector tuning, not a wrong camera model, scale or
// marker.
constexpr double kMaxTranslationError = 0.03;  // of the distance
constexpr double kMaxRotationErrorDeg = 3.0;
// Generous: markerd loads OpenCV's libraries under TCG (seconds), maybe
// built with the sanitizers, on a loaded 2-core host.
constexpr auto kStartTimeout = 90s;
constexpr auto kPhaseTimeout = 60s;

// What one phase of the log (the frames between two times) showed.
struct PhaseCheck {
  std::size_t frames = 0;
  std::map<int, std::size_t> frames_by_id;
  std::size_t id_changes = 0;
  double max_translation_error = 0;  // of the distance
  double max_rotation_error_deg = 0;
  // How long after the feeder moved on to the next scene a frame still
  // showed the one before (the output queue's depth, and the capture's).
  Clock::duration max_lag{};
};

// Every frame captured in [from, to) has status ok and exactly the one
// marker the feeder was showing then (by `runs`), with a pose close to the
// rendered one; sequence numbers and capture times increase.
PhaseCheck check_phase(const std::vector<json>& lines, Clock::time_point from, Clock::time_point to,
                       const std::vector<SceneFeeder::Run>& runs, const std::vector<detector::Scene>& scenes,
                       const std::string& phase) {
  PhaseCheck check;
  std::optional<std::uint64_t> last_sequence;
  std::optional<Clock::time_point> last_time;
  std::optional<int> last_id;
  for (const json& line : lines) {
    const Clock::time_point captured = capture_time(line);
    if (captured < from || captured >= to) continue;
    const std::uint64_t sequence = line.at("frame").at("sequence").get<std::uint64_t>();
    const std::string where = phase + ", frame " + std::to_string(sequence);
    ++check.frames;
    EXPECT_EQ(line.at("status"), "ok") << where << ": " << line.dump();
    EXPECT_EQ(line.at("frame").at("width"), kWidth) << where;
    EXPECT_EQ(line.at("frame").at("height"), kHeight) << where;
    EXPECT_TRUE(line.at("rig").is_null() && line.at("truth").is_null()) << where << ": no rig, no truth";
    if (last_sequence) {
      EXPECT_GT(sequence, *last_sequence) << where;
    }
    if (last_time) {
      EXPECT_GT(captured, *last_time) << where;
    }
    last_sequence = sequence;
    last_time = captured;

    const json& detections = line.at("detections");
    EXPECT_EQ(detections.size(), 1U) << where << ": the one marker of the scene: " << line.dump();
    for (const json& d : detections) {
      EXPECT_EQ(d.at("family"), "frame8") << where;
      const int id = d.at("id").get<int>();
      const auto scene =
          std::find_if(scenes.begin(), scenes.end(), [&](const detector::Scene& s) { return s.id == id; });
      if (scene == scenes.end()) {
        ADD_FAILURE() << where << ": id " << id << " was never shown: " << d.dump();
        continue;
      }
      const auto scene_index = static_cast<std::size_t>(scene - scenes.begin());
      ++check.frames_by_id[id];
      if (last_id && *last_id != id) ++check.id_changes;
      last_id = id;

      // The feeder was showing this scene when the frame was captured.
      bool shown = false;
      for (std::size_t i = 0; i < runs.size() && !shown; ++i) {
        if (runs[i].scene != scene_index) continue;
        const bool started = runs[i].queued <= captured + kTimestampLead;
        const bool not_over = i + 1 == runs.size() || captured <= runs[i + 1].queued + kLoopLag;
        shown = started && not_over;
        if (shown && i + 1 < runs.size()) check.max_lag = std::max(check.max_lag, captured - runs[i + 1].queued);
      }
      EXPECT_TRUE(shown) << where << ": id " << id << " captured when the feeder was not showing it";

      if (d.at("pose").is_null()) {
        ADD_FAILURE() << where << ": no pose, though the config has the camera model";
        continue;
      }
      const json& best = d.at("pose").at("best");
      const Eigen::Vector3d tvec = vector3(best.at("tvec"));
      const Eigen::Vector3d truth = scene->pose.translation;
      const double translation_error = (tvec - truth).norm() / truth.norm();
      const double rotation_error = rotation_between_deg(rotation_of(vector3(best.at("rvec"))), scene->pose.rotation);
      check.max_translation_error = std::max(check.max_translation_error, translation_error);
      check.max_rotation_error_deg = std::max(check.max_rotation_error_deg, rotation_error);
      EXPECT_LT(translation_error, kMaxTranslationError)
          << where << ": id " << id << " tvec " << tvec.transpose() << ", rendered at " << truth.transpose();
      EXPECT_LT(rotation_error, kMaxRotationErrorDeg) << where << ": id " << id << " rvec " << best.at("rvec").dump();
    }
  }
  std::cout << phase << ": " << check.frames << " frames logged";
  for (const auto& [id, n] : check.frames_by_id) std::cout << ", id " << id << " in " << n;
  std::cout << ", " << check.id_changes << " id changes; worst pose: translation " << 100 * check.max_translation_error
            << " % of the distance, rotation " << check.max_rotation_error_deg << " deg; a scene seen up to "
            << std::chrono::duration_cast<std::chrono::milliseconds>(check.max_lag).count()
            << " ms after the feeder moved on\n";
  return check;
}

// ---------------------------------------------------------------- fixture

class MarkerdVivid : public testing::Test {
 protected:
  void SetUp() override {
    const char* capture = env("HIL_VIVID_CAPTURE");
    const char* output = env("HIL_VIVID_OUTPUT");
    const char* platform = env("HIL_VIVID_PLATFORM");
    if (capture == nullptr || output == nullptr || platform == nullptr) {
      GTEST_SKIP() << "no vivid devices: run through ctest -R hil_markerd_vivid (tools/hil/hil-run)";
    }
    nodes_ = {capture, output};
    platform_ = platform;
    // As udev names a platform device's video node.
    device_name_ = "platform-" + platform_ + "-video-index0";
    link_ = fs::path("/dev/v4l/by-path") / device_name_;

    char dir_template[] = "/tmp/markerd-vivid-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr) << errno_text("mkdtemp");
    dir_ = dir_template;
    fs::create_directory(dir_ / "log");
    config_ = dir_ / "markerd.toml";
    socket_ = dir_ / "control.sock";
    markerd_output_ = dir_ / "markerd.out";

    const auto start = Clock::now();
    scenes_ = feeder_scenes();
    for (const detector::Scene& scene : scenes_)
      frames_.push_back(to_yuyv(detector::render_scene(feeder_camera(), scene)));
    std::cout << "rendered " << scenes_.size() << " scenes in " << seconds_since(start) << " s\n";
  }

  void TearDown() override {
    if (HasFailure() && !markerd_output_.empty() && fs::exists(markerd_output_)) {
      std::cout << "---- markerd's output (" << markerd_output_.string() << ")\n"
                << read_file(markerd_output_) << "---- end of markerd's output\n";
    }
    std::error_code ec;
    fs::remove(link_, ec);
  }

  void write_config() const {
    std::ofstream out(config_);
    out << "# hil_markerd_vivid: markerd on vivid's HDMI capture, looped from its output\n"
        << "[marker]\nfamily = \"frame8\"\nsize_m = 0.08\n"
        << "[camera]\nsource = \"v4l2\"\nmodel = \"" << MARKERD_CAMERA_MODEL << "\"\n"
        << "frame_timeout_ms = 2000\nreopen_delay_ms = 100\nreopen_max_delay_ms = 400\n"
        << "[camera.v4l2]\ndevice = \"" << device_name_ << "\"\nformat = \"YUYV\"\nwidth = " << kWidth
        << "\nheight = " << kHeight << "\ninput = " << kHdmiInput << "\n"
        << "[camera.v4l2.controls]\nloop_video = true\nosd_text_mode = \"None\"\n"
        << "[log]\ndirectory = \"" << (dir_ / "log").string() << "\"\n"
        << "[control]\nsocket = \"" << socket_.string() << "\"\ngroup = \"\"\n";
    ASSERT_TRUE(out.flush()) << "cannot write " << config_;
  }

  // The capture node on the feeder's timings, then the name markerd opens
  // (udev's part on a real machine).
  void plug_in(const VividNodes& nodes) {
    select_hdmi_input(nodes.capture);
    feeder_ = std::make_unique<SceneFeeder>(nodes.output, frames_, kFramesPerScene);
    fs::create_directories(link_.parent_path());
    fs::create_symlink(nodes.capture, link_);
  }

  [[nodiscard]] json status() const {
    daemon::ControlClient client(socket_);
    return client.call({{"cmd", "status"}}, 20s);
  }

  // Polls the status until `done` holds for it; the last status either way.
  json wait_for_status(const std::function<bool(const json&)>& done, std::chrono::milliseconds timeout,
                       MarkerdProcess& markerd) const {
    return hil::wait_for_status([this] { return status(); }, done, timeout, markerd);
  }

  // Waits until the log holds frames captured after `from` of every scene.
  bool wait_for_both_ids(Clock::time_point from, MarkerdProcess& markerd) const {
    return wait_until(
        [&] {
          if (!markerd.running()) return true;
          std::set<int> seen;
          for (const json& line : read_log(dir_ / "log").lines) {
            if (capture_time(line) < from) continue;
            for (const json& d : line.at("detections")) seen.insert(d.at("id").get<int>());
          }
          return seen.size() >= scenes_.size();
        },
        kPhaseTimeout, 200ms);
  }

  VividNodes nodes_;
  std::string platform_;
  std::string device_name_;
  fs::path link_;
  fs::path dir_;
  fs::path config_;
  fs::path socket_;
  fs::path markerd_output_;
  std::vector<detector::Scene> scenes_;
  std::vector<std::vector<std::uint8_t>> frames_;
  std::unique_ptr<SceneFeeder> feeder_;
};

TEST_F(MarkerdVivid, LogsTheMarkersShownSurvivesAnUnplugAndStopsCleanly) {
  const auto test_start = Clock::now();
  write_config();
  plug_in(nodes_);
  MarkerdProcess markerd(MARKERD_PATH, config_, markerd_output_);

  // ---- streaming: the right ids and poses in the log
  ASSERT_TRUE(wait_until([&] { return fs::exists(socket_) || !markerd.running(); }, kStartTimeout))
      << "no control socket " << socket_ << " after " << kStartTimeout.count() << " s";
  ASSERT_TRUE(markerd.running()) << "markerd exited: " << describe_wait_status(*markerd.exit_status());
  std::cout << "markerd's control socket up after " << seconds_since(test_start) << " s\n";
  json s =
      wait_for_status([](const json& j) { return j.value("camera", json::object()).value("state", "") == "streaming"; },
                      kStartTimeout, markerd);
  ASSERT_EQ(s["camera"]["state"], "streaming") << s.dump();
  EXPECT_EQ(s["camera"]["source"], "v4l2 " + device_name_);
  const auto streaming_since = Clock::now();
  ASSERT_TRUE(wait_for_both_ids(test_start, markerd)) << "not both ids logged within " << kPhaseTimeout.count() << " s";
  ASSERT_TRUE(markerd.running()) << "markerd exited: " << describe_wait_status(*markerd.exit_status());
  std::cout << "both ids logged " << seconds_since(streaming_since) << " s after streaming began\n";
  // A little more, for a scene change or two in the log.
  std::this_thread::sleep_for(2s);

  // ---- a control set at run time, through the socket: refused out of its
  // range (vivid's brightness has another on the HDMI input than on the
  // webcam's), taken in it, and set again on the new device after the replug
  int brightness = 0;
  {
    daemon::ControlClient client(socket_);
    json reply = client.call({{"cmd", "camera.get"}, {"names", {"brightness"}}}, 20s);
    ASSERT_EQ(reply["ok"], true) << reply.dump();
    const int min = reply["controls"][0]["min"];
    const int max = reply["controls"][0]["max"];
    reply = client.call({{"cmd", "camera.set"}, {"controls", {{"brightness", max + 1}}}}, 20s);
    EXPECT_EQ(reply["ok"], false) << reply.dump();
    EXPECT_EQ(reply.value("error", ""), "brightness: " + std::to_string(max + 1) + " is out of its range " +
                                            std::to_string(min) + " to " + std::to_string(max) +
                                            "; nothing was changed");
    brightness = min + (max - min) / 3;
    reply = client.call({{"cmd", "camera.set"}, {"controls", {{"brightness", brightness}}}}, 20s);
    ASSERT_EQ(reply["ok"], true) << reply.dump();
    EXPECT_EQ(reply["changed"][0]["new"], brightness) << reply.dump();
    reply = client.call({{"cmd", "camera.get"}, {"names", {"brightness"}}}, 20s);
    EXPECT_EQ(reply["controls"][0]["value"], brightness) << reply.dump();
  }

  // ---- unplugged while streaming: vivid lets go of the device under the
  // open files, and udev would remove the name
  {
    std::ofstream unbind("/sys/bus/platform/drivers/vivid/unbind");
    unbind << platform_ << std::flush;
    ASSERT_TRUE(unbind) << "cannot unbind " << platform_;
  }
  // Gone once the write returns; the last frames before it may be stamped
  // up to kTimestampLead later.
  const auto unbound = Clock::now();
  const auto unplugged = unbound + kTimestampLead;
  fs::remove(link_);
  ASSERT_TRUE(wait_until([&] { return feeder_->device_gone(); }, 10s)) << "the feeder's output did not go away";
  EXPECT_EQ(feeder_->error(), "");
  const auto runs_before = feeder_->runs();
  feeder_.reset();

  s = wait_for_status([](const json& j) { return j.value("camera", json::object()).value("state", "") != "streaming"; },
                      20s, markerd);
  ASSERT_TRUE(markerd.running()) << "markerd exited on the unplug: " << describe_wait_status(*markerd.exit_status());
  ASSERT_TRUE(s.contains("camera")) << s.dump();
  std::cout << "unplugged: status after " << seconds_since(unbound) << " s: " << s["camera"].dump() << '\n';
  EXPECT_NE(s["camera"]["state"], "streaming");
  ASSERT_TRUE(s["camera"]["last_error"].is_string()) << s.dump();
  const std::string lost = s["camera"]["last_error"];
  EXPECT_NE(lost.find("v4l2 " + device_name_), std::string::npos) << "names the device: " << lost;
  EXPECT_TRUE(lost.find("No such device") != std::string::npos || lost.find("no such device") != std::string::npos)
      << "says why: " << lost;
  EXPECT_GE(s["camera"]["failures"].get<int>(), 1);
  // While the camera is away markerd keeps trying, and keeps running.
  s = wait_for_status([](const json& j) { return j.value("camera", json::object()).value("failures", 0) >= 3; }, 20s,
                      markerd);
  ASSERT_TRUE(markerd.running()) << "markerd exited: " << describe_wait_status(*markerd.exit_status());
  EXPECT_GE(s["camera"]["failures"].get<int>(), 3) << s.dump();
  EXPECT_NE(s["camera"]["state"], "streaming") << s.dump();
  EXPECT_EQ(s["responsive"], true) << "a lost camera is no hung daemon: " << s.dump();
  std::cout << "while unplugged: " << s["camera"]["last_error"].get<std::string>() << '\n';
  const std::string output_so_far = read_file(markerd_output_);
  EXPECT_NE(output_so_far.find(": lost: v4l2 " + device_name_ + " (" + nodes_.capture + "): "), std::string::npos)
      << "markerd's log reports the loss while streaming, naming the device:\n"
      << output_so_far;

  // ---- plugged back in: a new vivid device, new nodes
  const auto replugged = Clock::now();
  {
    std::ofstream bind("/sys/bus/platform/drivers/vivid/bind");
    bind << platform_ << std::flush;
    ASSERT_TRUE(bind) << "cannot bind " << platform_;
  }
  std::optional<VividNodes> again;
  ASSERT_TRUE(wait_until(
      [&] {
        again = find_vivid_nodes();
        return again && fs::exists(again->capture) && fs::exists(again->output);
      },
      10s))
      << "vivid's nodes did not come back";
  std::cout << "plugged back in: capture " << again->capture << ", output " << again->output << '\n';
  plug_in(*again);
  s = wait_for_status(
      [](const json& j) {
        const json camera = j.value("camera", json::object());
        return camera.value("state", "") == "streaming" && camera.value("reopens", 0) >= 1;
      },
      kPhaseTimeout, markerd);
  ASSERT_TRUE(markerd.running()) << "markerd exited: " << describe_wait_status(*markerd.exit_status());
  ASSERT_EQ(s["camera"]["state"], "streaming") << s.dump();
  EXPECT_GE(s["camera"]["reopens"].get<int>(), 1) << s.dump();
  std::cout << "streaming again " << seconds_since(replugged) << " s after the replug\n";
  {
    daemon::ControlClient client(socket_);
    const json reply = client.call({{"cmd", "camera.get"}, {"names", {"brightness"}}}, 20s);
    EXPECT_EQ(reply["controls"][0]["value"], brightness)
        << "the new device got the value set at run time: " << reply.dump();
  }
  ASSERT_TRUE(wait_for_both_ids(replugged, markerd))
      << "not both ids logged within " << kPhaseTimeout.count() << " s of the replug";
  std::this_thread::sleep_for(1s);
  const auto runs_after = feeder_->runs();

  // ---- SIGTERM: exit 0, the log whole
  const auto stopping = Clock::now();
  const auto exit_status = markerd.terminate(20s);
  ASSERT_TRUE(exit_status.has_value()) << "markerd did not exit within 20 s of SIGTERM";
  EXPECT_TRUE(WIFEXITED(*exit_status) && WEXITSTATUS(*exit_status) == 0) << describe_wait_status(*exit_status);
  std::cout << "markerd exited " << seconds_since(stopping)
            << " s after SIGTERM: " << describe_wait_status(*exit_status) << '\n';
  EXPECT_FALSE(fs::exists(socket_)) << "markerd removes its socket when it stops";
  feeder_.reset();

  const LogFile log = read_log(dir_ / "log");
  EXPECT_TRUE(log.ends_whole) << "the log's last line is cut off";
  EXPECT_EQ(log.unparsable, 0U);
  ASSERT_FALSE(log.lines.empty());
  const auto before =
      check_phase(log.lines, Clock::time_point::min(), unplugged, runs_before, scenes_, "before the unplug");
  const auto after =
      check_phase(log.lines, replugged, Clock::time_point::max(), runs_after, scenes_, "after the replug");
  for (const auto* phase : {&before, &after}) {
    EXPECT_GE(phase->frames, 4U);
    for (const detector::Scene& scene : scenes_) {
      EXPECT_GE(phase->frames_by_id.count(scene.id), 1U) << "id " << scene.id << " never logged";
    }
    EXPECT_GE(phase->id_changes, 1U) << "the log follows the feeder's scene changes";
  }
  const auto between = std::count_if(log.lines.begin(), log.lines.end(), [&](const json& line) {
    return capture_time(line) >= unplugged && capture_time(line) < replugged;
  });
  EXPECT_EQ(between, 0) << "frames while the camera was unplugged";
  EXPECT_EQ(before.frames + after.frames, log.lines.size());
  std::cout << "the whole test: " << seconds_since(test_start) << " s\n";
}

}  // namespace
}  // namespace markerd::hil
