// The capture loop against a scripted source: it publishes what the source
// delivers with the source id and rig snapshot, reports and outlives a
// camera that is missing at start, vanishes, fails a frame or stalls,
// reopening with backoff, and ends with a finite source. And the simulated
// camera: what it renders, when it renders, its noise and its pace, and its
// scheduled outages.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <mutex>
#include <numeric>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/capture/capture_loop.hpp"
#include "markerd/daemon/capture/sim_camera.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;

// How long a simulated camera's next frame may take to come where a test
// needs it: its period is a millisecond, but a loaded machine (the HIL
// tests' qemu beside it, the sanitizers) has descheduled the test thread
// for over a second. Only a failing test waits this long.
constexpr auto kFrameComes = 10s;

// What the scripted source does at each step.
enum class Step { frame, corrupt, stall, vanish, fail_fill };

class ScriptedSource final : public CaptureSource {
 public:
  // open_failures: how many open() calls throw not_found before one works.
  ScriptedSource(int open_failures, std::vector<Step> script, bool finite)
      : open_failures_(open_failures), script_(std::move(script)), finite_(finite) {}

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override { return {4, 4, 16, 0}; }
  void open() override {
    ++opens;
    if (open_failures_ > 0) {
      --open_failures_;
      throw CaptureError(CaptureError::Kind::not_found, "scripted: /dev/video9: No such file or directory");
    }
    open_ = true;
  }
  void close() noexcept override {
    if (open_) ++closes;
    open_ = false;
  }
  [[nodiscard]] bool is_open() const noexcept override { return open_; }
  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override {
    if (!open_) throw CaptureError(CaptureError::Kind::io, "scripted: not open");
    if (next_ >= script_.size()) {
      if (finite_) {
        ended_ = true;
        return false;
      }
      // Past the script: a camera that streams on.
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
      current_ = Step::frame;
      return true;
    }
    const Step step = script_[next_++];
    switch (step) {
      case Step::stall: std::this_thread::sleep_for(timeout); return false;
      case Step::vanish: throw CaptureError(CaptureError::Kind::vanished, "scripted: /dev/video9: No such device");
      default: current_ = step; return true;
    }
  }
  void fill(Frame& frame) override {
    if (current_ == Step::fail_fill)
      throw CaptureError(CaptureError::Kind::io, "scripted: VIDIOC_DQBUF: Input/output error");
    frame.sequence = sequence_++;
    if (current_ == Step::corrupt) {
      frame.status = FrameStatus::corrupt_frame;
      frame.set_cause("scripted: short buffer");
      return;
    }
    frame.use_pixel_buffer(4, 4);
  }
  void skip() noexcept override { ++sequence_; }
  [[nodiscard]] bool at_end() const noexcept override { return ended_; }

  std::atomic<int> opens{0};
  std::atomic<int> closes{0};

 private:
  std::string name_ = "scripted";
  int open_failures_;
  std::vector<Step> script_;
  bool finite_;
  std::size_t next_ = 0;
  Step current_ = Step::frame;
  std::uint64_t sequence_ = 0;
  bool open_ = false;
  bool ended_ = false;
};

class NothingDetector : public detector::MarkerDetector {
 public:
  [[nodiscard]] detector::Family family() const override { return detector::Family::frame8; }
  void detect(const detector::GreyView&, std::vector<detector::Detection>& out) override { out.clear(); }
};

struct Logged {
  std::uint64_t sequence;
  std::uint32_t source_id;
  FrameStatus status;
  std::string cause;
};

class RecordingSink : public FrameSink {
 public:
  void write(const Frame& frame) override {
    const std::lock_guard lock(mutex);
    logged.push_back({frame.sequence, frame.source_id, frame.status, std::string(frame.cause())});
  }
  std::vector<Logged> copy() {
    const std::lock_guard lock(mutex);
    return logged;
  }
  std::mutex mutex;
  std::vector<Logged> logged;
};

std::unique_ptr<Pipeline> lossless_pipeline(RecordingSink& sink) {
  PipelineConfig config;
  config.policy = DropPolicy::lossless;
  config.pool = {4, 16, 4};
  std::vector<std::unique_ptr<detector::MarkerDetector>> detectors;
  detectors.push_back(std::make_unique<NothingDetector>());
  return std::make_unique<Pipeline>(config, std::move(detectors), sink);
}

CaptureLoopSettings fast_settings() {
  CaptureLoopSettings s;
  s.frame_timeout = 50ms;
  s.reopen_delay = 5ms;
  s.reopen_max_delay = 20ms;
  s.source_id = 3;
  return s;
}

bool wait_until(const std::function<bool()>& done, std::chrono::seconds limit = 30s) {
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

TEST(CaptureLoop, OutlivesACameraThatIsMissingVanishesFailsAndStalls) {
  using enum Step;
  ScriptedSource source(2, {frame, frame, vanish, frame, corrupt, fail_fill, frame, stall, frame, frame}, false);
  RecordingSink sink;
  auto pipeline = lossless_pipeline(sink);
  CaptureLoop loop(source, *pipeline, nullptr, fast_settings());
  std::jthread thread([&](const std::stop_token& stop) { loop.run(stop); });

  ASSERT_TRUE(wait_until([&] { return loop.status().frames >= 7; }));
  EXPECT_TRUE(wait_until([&] { return loop.streaming(); }));
  EXPECT_TRUE(loop.responsive(1s));
  thread.request_stop();
  thread.join();
  pipeline->stop();

  const CaptureStatus s = loop.status();
  EXPECT_EQ(s.state, CaptureState::stopped);
  EXPECT_EQ(s.source, "scripted");
  // Two failed opens, a vanish, a failed fill, a stall.
  EXPECT_EQ(s.failures, 5U);
  EXPECT_EQ(s.stalls, 1U);
  EXPECT_EQ(s.reopens, 3U);  // after the vanish, the failed fill and the stall
  EXPECT_EQ(s.corrupt, 1U);
  EXPECT_EQ(source.opens.load(), 6);
  EXPECT_EQ(source.closes.load(), source.opens.load() - 2);  // every successful open closed again
  EXPECT_NE(s.last_error.find("stalled: no frame within 50 ms"), std::string::npos) << s.last_error;

  const auto logged = sink.copy();
  ASSERT_GE(logged.size(), 7U);
  EXPECT_EQ(logged.size(), s.frames);
  // Every frame published is logged, in order; the failed fill's frame was
  // abandoned, not logged.
  for (std::size_t i = 0; i < logged.size(); ++i) {
    EXPECT_EQ(logged[i].sequence, i) << i;
    EXPECT_EQ(logged[i].source_id, 3U) << i;
  }
  EXPECT_EQ(logged[3].status, FrameStatus::corrupt_frame);
  EXPECT_EQ(logged[3].cause, "scripted: short buffer");
}

TEST(CaptureLoop, TheErrorNamesTheCameraAndTheCause) {
  ScriptedSource source(1000, {}, false);
  RecordingSink sink;
  auto pipeline = lossless_pipeline(sink);
  CaptureLoop loop(source, *pipeline, nullptr, fast_settings());
  std::jthread thread([&](const std::stop_token& stop) { loop.run(stop); });
  ASSERT_TRUE(wait_until([&] { return loop.status().failures >= 3; }));
  const CaptureStatus s = loop.status();
  EXPECT_EQ(s.last_error, "camera scripted: cannot open: scripted: /dev/video9: No such file or directory");
  EXPECT_FALSE(loop.streaming());
  // Waiting for a camera is not being stuck.
  EXPECT_TRUE(loop.responsive(1s));
  thread.request_stop();
  thread.join();
  EXPECT_EQ(loop.state(), CaptureState::stopped);
}

TEST(CaptureLoop, AFiniteSourceEndsAndTheLoopWaitsForStop) {
  ScriptedSource source(0, {Step::frame, Step::frame, Step::frame}, true);
  RecordingSink sink;
  auto pipeline = lossless_pipeline(sink);
  CaptureLoop loop(source, *pipeline, nullptr, fast_settings());
  std::jthread thread([&](const std::stop_token& stop) { loop.run(stop); });
  ASSERT_TRUE(wait_until([&] { return loop.state() == CaptureState::ended; }));
  EXPECT_EQ(loop.status().stalls, 0U);
  EXPECT_EQ(loop.status().failures, 0U);
  EXPECT_FALSE(source.is_open());
  thread.request_stop();
  thread.join();
  pipeline->stop();
  EXPECT_EQ(sink.copy().size(), 3U);
}

// ---- the simulated camera ----

SimCameraSettings quiet_settings() {
  SimCameraSettings s;
  s.fps = 1000;
  s.noise_sigma = 0;
  s.supersample = 2;
  return s;
}

rig::RigSnapshot snapshot_at(double rail_mm, double turntable_deg) {
  rig::RigSnapshot s;
  s.sequence = 1;
  s.rail.position = rail_mm;
  s.turntable.position = turntable_deg;
  return s;
}

TEST(SimCamera, RendersThePoseTheRigSnapshotImpliesAndOnlyWhenItChanges) {
  const detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  rig::RigGeometry geometry;
  geometry.d0_mm = 300;
  SimCamera sim(quiet_settings(), camera, geometry);
  EXPECT_EQ(sim.name(), "sim 640x480@1000");
  EXPECT_EQ(sim.geometry().slot_pixel_bytes, 640U * 480U);
  FramePool pool({2, 640 * 480, 4});
  sim.open();

  detector::Scene scene;
  scene.pose = detector::facing_pose(0.95, 30);
  scene.blur_sigma_px = 0.6;
  scene.supersample = 2;
  const detector::GreyImage expected = detector::render_scene(camera, scene);

  for (int k = 0; k < 3; ++k) {
    ASSERT_TRUE(sim.wait_frame(kFrameComes));
    Frame* frame = pool.try_acquire();
    ASSERT_NE(frame, nullptr);
    frame->rig = snapshot_at(650, 30);  // d = 300 + 650 mm, yaw 30 deg
    sim.fill(*frame);
    EXPECT_EQ(frame->sequence, static_cast<std::uint64_t>(k));
    ASSERT_EQ(frame->image.width, 640);
    ASSERT_EQ(frame->image.height, 480);
    EXPECT_TRUE(std::equal(expected.data(), expected.data() + 640 * 480, frame->image.data));
    pool.release(*frame);
  }
  EXPECT_EQ(sim.renders(), 1U);

  ASSERT_TRUE(sim.wait_frame(kFrameComes));
  Frame* moved = pool.try_acquire();
  moved->rig = snapshot_at(200, 0);
  sim.fill(*moved);
  EXPECT_EQ(sim.renders(), 2U);
  auto detector = detector::make_detector({});
  std::vector<detector::Detection> found;
  detector->detect(moved->image, found);
  ASSERT_EQ(found.size(), 1U);
  EXPECT_EQ(found[0].id, 165);
  pool.release(*moved);
}

// The frame at rail 650 mm, turntable 30 deg of a simulated camera.
std::vector<std::uint8_t> frame_of(const SimCameraSettings& settings) {
  const detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  rig::RigGeometry geometry;
  geometry.d0_mm = 300;
  SimCamera sim(settings, camera, geometry);
  FramePool pool({1, 640 * 480, 4});
  sim.open();
  EXPECT_TRUE(sim.wait_frame(kFrameComes));
  Frame* frame = pool.try_acquire();
  frame->rig = snapshot_at(650, 30);
  sim.fill(*frame);
  std::vector<std::uint8_t> pixels(frame->image.data, frame->image.data + 640 * 480);
  pool.release(*frame);
  return pixels;
}

// The scene the simulated camera is to draw at rail 650 mm, turntable 30 deg.
detector::GreyImage expected_at_650_30(detector::Scene scene) {
  scene.pose = detector::facing_pose(0.95, 30);
  scene.blur_sigma_px = 0.6;
  scene.supersample = 2;
  return detector::render_scene(detector::CameraModel::thesis_640x480(), scene);
}

std::size_t differing_pixels(const std::vector<std::uint8_t>& a, const detector::GreyImage& b) {
  std::size_t n = 0;
  for (std::size_t i = 0; i < a.size(); ++i) n += a[i] != b.data()[i] ? 1 : 0;
  return n;
}

// A sweep measures a socket marker as it measures a paper one: the same rig
// position shows the print on its frame, the outlet through the opening, or
// a side covered, exactly as the renderer draws that scene; a paper marker
// is drawn as it always was.
TEST(SimCamera, DrawsTheMarkerOnWhatItIsMountedOnAndTheSceneAroundIt) {
  const std::vector<std::uint8_t> paper = frame_of(quiet_settings());
  EXPECT_EQ(differing_pixels(paper, expected_at_650_30({})), 0U);

  SimCameraSettings socket = quiet_settings();
  socket.cut_hole = true;
  socket.frame = detector::socket_frame();
  socket.insert = detector::Insert::socket;
  socket.margin_m = 0.003;
  const std::vector<std::uint8_t> on_socket = frame_of(socket);
  detector::Scene socket_scene;
  socket_scene.cut_hole = true;
  socket_scene.frame = detector::socket_frame();
  socket_scene.insert = detector::Insert::socket;
  socket_scene.paper_margin_m = 0.003;
  EXPECT_EQ(differing_pixels(on_socket, expected_at_650_30(socket_scene)), 0U);
  // The frame, its shading and the outlet differ from a flat white hole over
  // thousands of pixels (the marker spans some 60 x 50 here).
  EXPECT_GT(differing_pixels(on_socket, expected_at_650_30({})), 500U);

  SimCameraSettings covered = quiet_settings();
  covered.cover = {detector::MarkerSide::left};
  covered.cover_reflectance = 0.9F;
  covered.clutter = false;
  covered.background_grey = 60;
  covered.ambient = 0.5;
  detector::Scene covered_scene;
  covered_scene.occluders.push_back(detector::side_occluder(detector::MarkerSide::left, 0.08, 0.2, 0.9F, 0.03));
  covered_scene.clutter = false;
  covered_scene.background_grey = 60;
  covered_scene.ambient = 0.5;
  const std::vector<std::uint8_t> on_covered = frame_of(covered);
  EXPECT_EQ(differing_pixels(on_covered, expected_at_650_30(covered_scene)), 0U);
  covered_scene.occluders.clear();
  EXPECT_GT(differing_pixels(on_covered, expected_at_650_30(covered_scene)), 100U);
}

TEST(SimCamera, AddsFreshNoiseOfTheSetSigmaToEveryFrame) {
  SimCameraSettings settings = quiet_settings();
  settings.noise_sigma = 3.0;
  const detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  SimCamera noisy(settings, camera, {});
  SimCamera clean(quiet_settings(), camera, {});
  FramePool pool({3, 640 * 480, 4});
  noisy.open();
  clean.open();
  std::vector<std::vector<int>> differences;
  Frame* reference = pool.try_acquire();
  ASSERT_TRUE(clean.wait_frame(kFrameComes));
  clean.fill(*reference);
  for (int k = 0; k < 2; ++k) {
    Frame* frame = pool.try_acquire();
    ASSERT_TRUE(noisy.wait_frame(kFrameComes));
    noisy.fill(*frame);
    std::vector<int> d(640 * 480);
    for (std::size_t i = 0; i < d.size(); ++i) d[i] = int{frame->image.data[i]} - int{reference->image.data[i]};
    differences.push_back(std::move(d));
    pool.release(*frame);
  }
  for (const auto& d : differences) {
    const double mean = std::accumulate(d.begin(), d.end(), 0.0) / static_cast<double>(d.size());
    double var = 0;
    for (int v : d) var += (v - mean) * (v - mean);
    const double sigma = std::sqrt(var / static_cast<double>(d.size()));
    EXPECT_NEAR(mean, 0.0, 0.1);
    EXPECT_NEAR(sigma, 3.0, 0.15);  // rounding adds 1/12 of a level's variance
  }
  EXPECT_NE(differences[0], differences[1]);  // not the same noise twice
  pool.release(*reference);
}

TEST(SimCamera, KeepsItsFrameRate) {
  SimCameraSettings settings = quiet_settings();
  settings.fps = 100;
  SimCamera sim(settings, detector::CameraModel::thesis_640x480(), {});
  sim.open();
  ASSERT_TRUE(sim.wait_frame(kFrameComes));
  const auto start = std::chrono::steady_clock::now();
  for (int k = 0; k < 10; ++k) ASSERT_TRUE(sim.wait_frame(kFrameComes));
  const auto elapsed = std::chrono::steady_clock::now() - start;
  EXPECT_GE(elapsed, 95ms);  // ten periods of 10 ms; never early
}

// A timeout shorter than the time to the next frame is a wait without a
// frame. The period is a second, so that the test holds however late the
// test thread gets to ask (at 10 ms a period, a thread held up by 9 ms on
// a loaded machine found the next frame due).
TEST(SimCamera, AWaitShorterThanThePeriodEndsWithoutAFrame) {
  SimCameraSettings settings = quiet_settings();
  settings.fps = 1;
  SimCamera sim(settings, detector::CameraModel::thesis_640x480(), {});
  sim.open();
  ASSERT_TRUE(sim.wait_frame(kFrameComes));
  EXPECT_FALSE(sim.wait_frame(1ms));
}

// What a capture loop sees of a camera with scheduled outages: it opens and
// streams, the camera vanishes at a frame, refuses to open while the outage
// lasts, opens again after it and streams; and again at the next outage.
// The schedule runs from the camera's creation, so a test thread held up on
// a loaded machine may meet an outage at its first open(), or sleep through a
// whole one: what must hold is the order of events and that outages are
// numbered forward, not which outage comes first.
TEST(SimCamera, DropsOutOnItsScheduleAndComesBack) {
  SimCameraSettings settings = quiet_settings();
  settings.outage_every = 300ms;
  settings.outage_for = 100ms;
  SimCamera sim(settings, detector::CameraModel::thesis_640x480(), {});
  FramePool pool({1, 640 * 480, 4});
  // What happened, with repeats collapsed: "opened", "frame", "vanished: ...".
  // The refusals to open while an outage lasts are checked where they
  // happen, not counted.
  std::vector<std::string> seen;
  const auto note = [&](const std::string& what) {
    if (seen.empty() || seen.back() != what) seen.push_back(what);
  };
  // The outage's number in a refusal or vanishing message.
  const auto outage = [](const std::string& message) {
    const std::string prefix = "sim 640x480@1000: dropped out (simulated outage ";
    EXPECT_EQ(message.rfind(prefix, 0), 0U) << message;
    const std::size_t colon = message.find(": 0.1 s every 0.3 s)", prefix.size());
    EXPECT_NE(colon, std::string::npos) << message;
    return std::stoi(message.substr(prefix.size(), colon - prefix.size()));
  };
  const auto vanishings = [&] {
    return std::count_if(seen.begin(), seen.end(), [](const std::string& e) { return e.rfind("vanished", 0) == 0; });
  };
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  std::string last_vanish;
  while (vanishings() < 2 || seen.back() != "frame") {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "events so far: " << testing::PrintToString(seen);
    if (!sim.is_open()) {
      try {
        sim.open();
        note("opened");
      } catch (const CaptureError& e) {
        EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
        // Still the outage it vanished in, unless the thread slept through it.
        if (!last_vanish.empty()) {
          EXPECT_GE(outage(e.what()), outage(last_vanish));
        }
        std::this_thread::sleep_for(5ms);
      }
      continue;
    }
    try {
      if (!sim.wait_frame(1s)) continue;
    } catch (const CaptureError& e) {
      EXPECT_EQ(e.kind(), CaptureError::Kind::vanished);
      EXPECT_FALSE(sim.is_open());
      last_vanish = e.what();
      note("vanished: " + last_vanish);
      continue;
    }
    Frame* frame = pool.try_acquire();
    ASSERT_NE(frame, nullptr);
    sim.fill(*frame);
    EXPECT_EQ(frame->status, FrameStatus::ok);
    pool.release(*frame);
    note("frame");
  }
  ASSERT_EQ(seen.size(), 8U) << testing::PrintToString(seen);
  const std::size_t vanished = std::string("vanished: ").size();
  const int first = outage(seen[2].substr(vanished));
  const int second = outage(seen[5].substr(vanished));
  EXPECT_GE(first, 1);
  EXPECT_GT(second, first);
  const std::vector<std::string> expected{"opened", "frame", seen[2], "opened", "frame", seen[5], "opened", "frame"};
  EXPECT_EQ(seen, expected);
  EXPECT_GE(sim.outages(), 2U);  // one more if the first open() met an outage
}

}  // namespace
}  // namespace markerd::daemon
