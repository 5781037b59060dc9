// The live view: the slot that holds markerd's newest frame (copies, spare
// buffers held by readers, threads), the annotation drawn where the
// detection and the truth are, `snapshot` over the control socket and
// markerctl snapshot, the web page's endpoints through cpp-httplib's client
// (the page, the state, the snapshot, the MJPEG preview, the report files
// with path traversal refused, read-only), [web] off by default and on the
// loopback address unless the config names another, and a stop with a
// preview streaming. The page in a browser: tests/web/check_page.py.

#include <gtest/gtest.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <thread>
#include <vector>

#include "markerd/base/base64.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/daemon/frame_annotation.hpp"
#include "markerd/daemon/latest_frame.hpp"
#include "markerd/daemon/web/web_server.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"
#include "markerd/rig/geometry.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

// Last: it brings in <resolv.h>, whose _res macro breaks Eigen's headers
// when they come after it.
#include <httplib.h>

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------- the slot

// A frame whose every pixel and whose detection count say which it is.
struct TestFrame {
  explicit TestFrame(std::uint64_t sequence, int width = 64, int height = 48)
      : pixels(static_cast<std::size_t>(width) * height, static_cast<std::uint8_t>(sequence % 251)),
        detections(sequence % 5) {
    record.sequence = sequence;
    record.detections = detections;
    for (auto& d : detections) d.id = static_cast<int>(sequence % 256);
    view = {pixels.data(), width, height, width};
  }
  std::vector<std::uint8_t> pixels;
  std::vector<detector::Detection> detections;
  FrameRecordInput record;
  detector::GreyView view;
};

bool consistent(const HeldFrame& f) {
  const auto value = static_cast<std::uint8_t>(f.sequence % 251);
  if (f.detections.size() != f.sequence % 5) return false;
  for (const auto& d : f.detections) {
    if (d.id != static_cast<int>(f.sequence % 256)) return false;
  }
  return std::all_of(f.pixels.begin(), f.pixels.end(), [&](std::uint8_t p) { return p == value; });
}

LatestFrameSettings every_frame(std::size_t buffers = 4) {
  LatestFrameSettings s;
  s.watched_interval = 0ms;
  s.unwatched_interval = 0ms;
  s.buffers = buffers;
  return s;
}

TEST(LatestFrame, HoldsTheNewestCopyAndNothingBeforeTheFirst) {
  LatestFrame slot(every_frame());
  EXPECT_EQ(slot.latest(), nullptr);
  const TestFrame a(7);
  slot.offer(a.record, a.view);
  const auto held = slot.latest();
  ASSERT_NE(held, nullptr);
  EXPECT_EQ(held->sequence, 7U);
  EXPECT_EQ(held->copy, 1U);
  EXPECT_EQ(held->width, 64);
  EXPECT_EQ(held->height, 48);
  EXPECT_TRUE(consistent(*held));
  // An unreadable frame (no pixels) is not copied: the slot keeps the last picture.
  FrameRecordInput corrupt;
  corrupt.sequence = 8;
  corrupt.status = FrameStatus::corrupt_frame;
  slot.offer(corrupt, {});
  EXPECT_EQ(slot.latest()->sequence, 7U);
  EXPECT_EQ(slot.stats().offered, 2U);
  EXPECT_EQ(slot.stats().copied, 1U);
}

TEST(LatestFrame, AFrameIsCopiedOnlyWhenOneIsDue) {
  LatestFrameSettings s;
  s.watched_interval = std::chrono::hours(1);
  s.unwatched_interval = std::chrono::hours(1);
  LatestFrame slot(s);
  for (std::uint64_t seq = 1; seq <= 20; ++seq) {
    const TestFrame f(seq);
    slot.offer(f.record, f.view);
  }
  EXPECT_EQ(slot.stats().offered, 20U);
  EXPECT_EQ(slot.stats().copied, 1U);
  EXPECT_EQ(slot.latest()->sequence, 1U);
}

TEST(LatestFrame, AReadersCopyStaysWholeAndTheSlotSkipsFramesWhenReadersHoldEverySpare) {
  LatestFrame slot(every_frame(2));
  const TestFrame a(1);
  const TestFrame b(2);
  const TestFrame c(3);
  const TestFrame d(4);
  slot.offer(a.record, a.view);
  auto held_a = slot.latest();        // the reader holds the first buffer
  slot.offer(b.record, b.view);       // into the second
  const auto held_b = slot.latest();  // and now holds both
  slot.offer(c.record, c.view);       // no buffer free: skipped, not waited for
  EXPECT_EQ(slot.stats().busy, 1U);
  EXPECT_EQ(slot.latest()->sequence, 2U);
  EXPECT_EQ(held_a->sequence, 1U);
  EXPECT_TRUE(consistent(*held_a)) << "a held copy is never written to";
  EXPECT_TRUE(consistent(*held_b));
  held_a.reset();
  slot.offer(d.record, d.view);  // the first buffer is free again
  EXPECT_EQ(slot.latest()->sequence, 4U);
  EXPECT_EQ(held_b->sequence, 2U);
  EXPECT_TRUE(consistent(*held_b));
}

TEST(LatestFrame, ReadersOnOtherThreadsAlwaysSeeWholeFramesInOrder) {
  LatestFrame slot(every_frame(3));
  constexpr std::uint64_t kFrames = 4000;
  std::atomic<bool> done{false};
  std::atomic<int> torn{0};
  std::atomic<int> backwards{0};
  std::atomic<std::uint64_t> reads{0};
  std::vector<std::thread> readers;
  for (int r = 0; r < 3; ++r) {
    readers.emplace_back([&, r] {
      std::uint64_t last = 0;
      std::vector<std::shared_ptr<const HeldFrame>> kept;
      while (!done.load()) {
        auto f = r == 0 ? slot.wait_newer(last, Clock::now() + 100ms) : slot.latest();
        if (!f) continue;
        reads.fetch_add(1);
        if (!consistent(*f)) torn.fetch_add(1);
        if (f->copy < last) backwards.fetch_add(1);
        last = f->copy;
        // Holding copies for a while takes buffers from the writer.
        if (r == 2) {
          kept.push_back(std::move(f));
          if (kept.size() > 2) kept.erase(kept.begin());
        }
      }
      for (const auto& f : kept) {
        if (!consistent(*f)) torn.fetch_add(1);
      }
    });
  }
  // At least kFrames, and on until the readers have read a few hundred
  // times: the two sides overlap however the threads are scheduled.
  std::uint64_t offered = 0;
  while (offered < kFrames || reads.load() < 300) {
    ++offered;
    const TestFrame f(offered, 32 + static_cast<int>(offered % 3) * 16, 24);  // sizes change too
    slot.offer(f.record, f.view);
  }
  done = true;
  slot.wake_all();
  for (auto& t : readers) t.join();
  EXPECT_EQ(torn.load(), 0);
  EXPECT_EQ(backwards.load(), 0);
  const LatestFrameStats stats = slot.stats();
  EXPECT_EQ(stats.offered, offered);
  EXPECT_EQ(stats.copied + stats.busy, offered);
  EXPECT_EQ(slot.latest()->copy, stats.copied);
}

TEST(LatestFrame, WaitNewerReturnsANewerFrameAtOnceAndEndsOnWakeAll) {
  LatestFrame slot(every_frame());
  const TestFrame a(1);
  slot.offer(a.record, a.view);
  const auto start = Clock::now();
  EXPECT_EQ(slot.wait_newer(0, start + 60s)->sequence, 1U);
  std::thread waker([&] {
    std::this_thread::sleep_for(50ms);
    slot.wake_all();
  });
  const auto f = slot.wait_newer(1, Clock::now() + 60s);  // nothing newer comes: the wake ends it
  waker.join();
  ASSERT_NE(f, nullptr);
  EXPECT_EQ(f->copy, 1U);
  EXPECT_LT(Clock::now() - start, 50s) << "hang guard";
}

// ---------------------------------------------------------------- annotation

struct RenderedFrame {
  HeldFrame frame;
  detector::CameraModel camera = detector::CameraModel::thesis_640x480();
};

// The thesis camera sees the marker at 0.5 m, turned 20 deg; detected, with its pose.
RenderedFrame rendered_frame() {
  RenderedFrame r;
  detector::Scene scene;
  scene.id = 165;
  scene.marker_size_m = 0.08;
  scene.pose = detector::facing_pose(0.5, 20);
  scene.supersample = 2;
  scene.seed = 3;
  const detector::GreyImage image = detector::render_scene(r.camera, scene);
  detector::DetectorConfig config;
  config.camera = r.camera;
  config.marker_size_m = 0.08;
  auto detector = detector::make_detector(config);
  detector->detect(image, r.frame.detections);
  r.frame.width = image.width();
  r.frame.height = image.height();
  r.frame.pixels.assign(image.data(), image.data() + static_cast<std::size_t>(image.width()) * image.height());
  r.frame.sequence = 42;
  r.frame.copy = 1;
  rig::RigSnapshot snapshot;
  snapshot.rail.position = 200;
  snapshot.rail.state = rig::AxisState::idle;
  snapshot.rail.homed = true;
  snapshot.rail.settled = true;
  snapshot.turntable.position = 20;
  snapshot.turntable.homed = true;
  r.frame.rig = snapshot;
  return r;
}

bool near_colour(const cv::Vec3b& pixel, const std::uint8_t (&bgr)[3], int tolerance) {
  for (int c = 0; c < 3; ++c) {
    if (std::abs(int(pixel[c]) - int(bgr[c])) > tolerance) return false;
  }
  return true;
}

// Whether a pixel within `radius` of (x, y) has the colour: lines are
// anti-aliased, so the exact pixel may be blended.
bool colour_near(const cv::Mat& image, double x, double y, const std::uint8_t (&bgr)[3], int radius = 1) {
  for (int dy = -radius; dy <= radius; ++dy) {
    for (int dx = -radius; dx <= radius; ++dx) {
      const int px = static_cast<int>(std::lround(x)) + dx;
      const int py = static_cast<int>(std::lround(y)) + dy;
      if (px < 0 || py < 0 || px >= image.cols || py >= image.rows) continue;
      if (near_colour(image.at<cv::Vec3b>(py, px), bgr, 40)) return true;
    }
  }
  return false;
}

TEST(FrameAnnotation, TheOutlineIsDrawnWhereTheDetectionIsAndTheTruthWhereTheRigPutsIt) {
  RenderedFrame r = rendered_frame();
  ASSERT_EQ(r.frame.detections.size(), 1U);
  const detector::Detection& d = r.frame.detections.front();
  ASSERT_EQ(d.id, 165);
  ASSERT_TRUE(d.pose.has_value());
  // The truth 3 cm to the camera's left of the marker: its own outline.
  const detector::MarkerPose truth_pose = detector::facing_pose(0.5, 20);
  rig::MarkerGroundTruth truth;
  truth.rotation = truth_pose.rotation;
  truth.translation = truth_pose.translation + Eigen::Vector3d(-0.03, 0, 0);
  truth.distance_m = 0.5;
  truth.yaw_deg = 20;
  r.frame.truth = truth;
  AnnotationContext context;
  context.camera = r.camera;
  context.marker_size_m = 0.08;

  const cv::Mat image = annotated_image(r.frame, context);
  ASSERT_EQ(image.type(), CV_8UC3);
  ASSERT_EQ(image.cols, 640);
  ASSERT_EQ(image.rows, 480);
  // Along each side, a third of the way (away from the id's label at the
  // first corner, and from the axes, which end at the sides' middles).
  for (std::size_t i = 1; i < 4; ++i) {
    const auto& a = d.corners[i];
    const auto& b = d.corners[(i + 1) % 4];
    const double x = a.x + (b.x - a.x) / 3;
    const double y = a.y + (b.y - a.y) / 3;
    EXPECT_TRUE(colour_near(image, x, y, AnnotationColours::kOutline)) << "side " << i << " at " << x << ", " << y;
  }
  // The truth's left side, projected through the camera: magenta there.
  detector::MarkerPose tp;
  tp.rotation = truth.rotation;
  tp.translation = truth.translation;
  const detector::Point2 left_middle = detector::project(r.camera, tp, Eigen::Vector3d(-0.04, 0, 0));
  EXPECT_TRUE(colour_near(image, left_middle.x, left_middle.y, AnnotationColours::kTruth, 2))
      << left_middle.x << ", " << left_middle.y;
  // The pose's x axis from the marker's centre, red, halfway along.
  const detector::Point2 x_axis = detector::project(r.camera, d.pose->best, Eigen::Vector3d(0.02, 0, 0));
  EXPECT_TRUE(colour_near(image, x_axis.x, x_axis.y, AnnotationColours::kAxisX, 2)) << x_axis.x << ", " << x_axis.y;
  // Far from all of it the frame is untouched: grey, as the camera saw it.
  const cv::Vec3b corner = image.at<cv::Vec3b>(470, 630);
  EXPECT_EQ(corner[0], corner[1]);
  EXPECT_EQ(corner[1], corner[2]);
  EXPECT_EQ(corner[0], r.frame.pixels[470 * 640 + 630]);

  const std::vector<std::string> lines = annotation_text(r.frame, context);
  ASSERT_GE(lines.size(), 4U);
  EXPECT_EQ(lines[0], "frame 42  640x480");
  EXPECT_EQ(lines[1].rfind("rail 200.0 mm (idle, settled)  turntable 20.0 deg (", 0), 0U) << lines[1];
  EXPECT_EQ(lines[2], "truth: distance 0.500 m, yaw 20.0 deg");
  EXPECT_EQ(lines[3].rfind("1 detected: frame8 165 at 0.", 0), 0U) << lines[3];
  EXPECT_NEAR(std::stod(lines[3].substr(lines[3].rfind(" at ") + 4)), 0.5, 0.01) << lines[3];
}

TEST(FrameAnnotation, ImagesEncodeAndDecodeAsTheFormatSays) {
  const RenderedFrame r = rendered_frame();
  const cv::Mat grey = grey_image(r.frame);
  for (const ImageFormat format : {ImageFormat::png, ImageFormat::pgm}) {
    const auto bytes = encode_image(grey, format);
    const cv::Mat back = cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
    ASSERT_EQ(back.type(), CV_8UC1) << to_string(format);
    EXPECT_EQ(cv::norm(back, grey, cv::NORM_INF), 0) << "lossless: " << to_string(format);
  }
  const cv::Mat colour = annotated_image(r.frame, AnnotationContext{});
  const cv::Mat jpeg = cv::imdecode(encode_image(colour, ImageFormat::jpeg), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(jpeg.type(), CV_8UC3);
  EXPECT_EQ(jpeg.cols, 640);
  EXPECT_THROW((void)encode_image(colour, ImageFormat::pgm), std::invalid_argument);
  EXPECT_EQ(image_format_from_name("JPG"), ImageFormat::jpeg);
  EXPECT_EQ(image_format_from_name("bmp"), std::nullopt);
}

// ---------------------------------------------------------------- markerd

class LiveViewTest : public testing::Test {
 protected:
  void SetUp() override {
    test_support::prepare_markerd_dir(dir_);
    test_support::write_sim_rig_config(dir_ / "rig.toml", 50.0);
  }

  [[nodiscard]] std::string config_text(const std::string& web) const {
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

[log]
directory = "logs"

[control]
socket = "control.sock"

[sweep]
directory = "state"
{})",
                       MARKERD_SOURCE_DIR, web);
  }

  [[nodiscard]] int base_lines() const {
    const std::string text = config_text("");
    return static_cast<int>(std::count(text.begin(), text.end(), '\n'));
  }

  DaemonConfig config(const std::string& web = "") {
    test_support::write_file(dir_ / "markerd.toml", config_text(web));
    return load_daemon_config(dir_ / "markerd.toml");
  }

  std::string config_error(const std::string& web) {
    try {
      (void)config(web);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "(no error)";
  }

  // The first snapshot markerd can give, once its camera has delivered a frame.
  json first_snapshot(ControlClient& client, const json& request) {
    const auto deadline = Clock::now() + 60s;
    for (;;) {
      json reply = client.call(request, 30s);
      if (reply.value("ok", false) || Clock::now() > deadline) return reply;
      std::this_thread::sleep_for(20ms);
    }
  }

  const test_support::TempDir temp_{"markerd-live"};
  const fs::path dir_ = temp_.path();
};

cv::Mat decode(const json& image) {
  const auto bytes = base64_decode(image.value("data", std::string()));
  if (!bytes) return {};
  return cv::imdecode(*bytes, cv::IMREAD_UNCHANGED);
}

TEST_F(LiveViewTest, SnapshotOverTheControlSocketIsTheNewestFrameAsADecodableImage) {
  Daemon daemon(config());
  EXPECT_EQ(daemon.web(), nullptr) << "the web page is off unless the config turns it on";
  daemon.start();
  ControlClient client(dir_ / "control.sock");
  const json reply = first_snapshot(client, {{"cmd", "snapshot"}});
  ASSERT_EQ(reply["ok"], true) << reply.dump().substr(0, 500);
  EXPECT_EQ(reply["frame"]["width"], 640);
  EXPECT_EQ(reply["frame"]["height"], 480);
  EXPECT_EQ(reply["frame"]["status"], "ok");
  EXPECT_EQ(reply["image"]["format"], "png");
  EXPECT_EQ(reply["image"]["annotated"], false);
  ASSERT_TRUE(reply["rig"].is_object()) << "the rig's snapshot stamped on the frame";
  ASSERT_TRUE(reply["truth"].is_object());
  // The truth of the positions stamped on the frame: d = d0 + rail, d0 = 300 mm.
  EXPECT_NEAR(reply["truth"]["distance_m"].get<double>(), 0.3 + reply["rig"]["rail"]["position"].get<double>() / 1000,
              1e-5);
  const cv::Mat image = decode(reply["image"]);
  ASSERT_EQ(image.type(), CV_8UC1);
  EXPECT_EQ(image.cols, 640);
  EXPECT_EQ(image.rows, 480);
  EXPECT_EQ(reply["image"]["bytes"].get<std::size_t>(),
            base64_decode(reply["image"]["data"].get<std::string>())->size());
  // The frame the slot holds, pixel for pixel, when it is still that one.
  const auto held = daemon.latest_frame().latest();
  if (held->copy == reply["frame"]["copy"].get<std::uint64_t>()) {
    EXPECT_EQ(cv::norm(image, grey_image(*held), cv::NORM_INF), 0);
  }
  for (const auto& d : reply["detections"]) EXPECT_EQ(d["id"], 165) << "the simulated camera shows one marker";

  const json annotated = client.call({{"cmd", "snapshot"}, {"format", "jpg"}, {"annotate", true}}, 30s);
  ASSERT_EQ(annotated["ok"], true) << annotated.dump().substr(0, 500);
  EXPECT_EQ(annotated["image"]["format"], "jpeg");
  const cv::Mat colour = decode(annotated["image"]);
  EXPECT_EQ(colour.type(), CV_8UC3);
  EXPECT_EQ(colour.cols, 640);

  const json pgm = client.call({{"cmd", "snapshot"}, {"format", "pgm"}, {"annotate", true}});
  EXPECT_EQ(pgm["ok"], false);
  EXPECT_EQ(pgm["error"], "an annotated snapshot is in colour: format png or jpeg, not pgm");
  const json bmp = client.call({{"cmd", "snapshot"}, {"format", "bmp"}});
  EXPECT_EQ(bmp["ok"], false);
  EXPECT_NE(bmp.value("error", std::string()).find("'format' must be png, jpeg, jpg or pgm"), std::string::npos)
      << bmp.dump();

  // markerctl snapshot writes the file its extension names.
  const std::string socket = (dir_ / "control.sock").string();
  const auto outcome = test_support::run_program(
      {MARKERCTL_PATH, "snapshot", "--socket", socket, "--annotate", "--json", "-o", (dir_ / "aim.png").string()});
  ASSERT_EQ(outcome.code, 0) << outcome.describe();
  const json printed = json::parse(outcome.out);
  EXPECT_EQ(printed["file"], (dir_ / "aim.png").string());
  EXPECT_FALSE(printed["image"].contains("data")) << "--json prints what is known, not the pixels";
  const cv::Mat file = cv::imread((dir_ / "aim.png").string(), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(file.type(), CV_8UC3);
  EXPECT_EQ(file.cols, 640);
  const auto plain =
      test_support::run_program({MARKERCTL_PATH, "snapshot", "--socket", socket, "-o", (dir_ / "plain.pgm").string()});
  ASSERT_EQ(plain.code, 0) << plain.describe();
  EXPECT_NE(plain.out.find("plain.pgm: frame "), std::string::npos) << plain.out;
  EXPECT_EQ(cv::imread((dir_ / "plain.pgm").string(), cv::IMREAD_UNCHANGED).type(), CV_8UC1);
  const auto bad = test_support::run_program({MARKERCTL_PATH, "snapshot", "--socket", socket, "-o", "x.bmp"});
  EXPECT_EQ(bad.code, 2) << bad.describe();
  EXPECT_EQ(bad.err,
            "markerctl: snapshot: -o x.bmp: the format comes from the extension, which must be .png, .jpg, .jpeg or "
            ".pgm\n");
  EXPECT_FALSE(fs::exists("x.bmp"));
}

TEST_F(LiveViewTest, TheWebPageIsOffByDefaultAndOnTheLoopbackUnlessConfiguredOtherwise) {
  const DaemonConfig off = config();
  EXPECT_FALSE(off.web.enabled);
  EXPECT_EQ(off.web.host, "127.0.0.1");
  EXPECT_TRUE(off.web.loopback());
  const DaemonConfig on = config("\n[web]\nenabled = true\n");
  EXPECT_TRUE(on.web.enabled);
  EXPECT_EQ(on.web.host, "127.0.0.1");
  EXPECT_EQ(on.web.port, 8080);
  EXPECT_TRUE(on.web.loopback());
  const DaemonConfig any = config("\n[web]\nenabled = true\nlisten = \"0.0.0.0:8081\"\npreview_fps = 5\n");
  EXPECT_EQ(any.web.host, "0.0.0.0");
  EXPECT_EQ(any.web.port, 8081);
  EXPECT_FALSE(any.web.loopback());
  EXPECT_EQ(any.web.preview_fps, 5);
  const DaemonConfig v6 = config("\n[web]\nenabled = true\nlisten = \"[::1]:0\"\n");
  EXPECT_EQ(v6.web.host, "::1");
  EXPECT_EQ(v6.web.port, 0);
  EXPECT_TRUE(v6.web.loopback());

  const std::string file = (dir_ / "markerd.toml").string();
  const int line = base_lines() + 3;  // [web]'s first key: after an empty line and the table's header
  EXPECT_EQ(config_error("\n[web]\nlisten = \"localhost:8080\"\n"),
            fmt::format("{}:{}: web.listen: must be \"ADDRESS:PORT\" with a numeric address (\"127.0.0.1:8080\", "
                        "\"[::1]:8080\"; \"0.0.0.0:8080\" for every interface), got \"localhost:8080\": \"localhost\" "
                        "is not an IPv4 address",
                        file, line));
  EXPECT_NE(config_error("\n[web]\nlisten = \"127.0.0.1:70000\"\n").find("the port must be 0 to 65535, got \"70000\""),
            std::string::npos);
  EXPECT_NE(config_error("\n[web]\nlisten = \"127.0.0.1\"\n").find(": no port"), std::string::npos);
  EXPECT_NE(config_error("\n[web]\nlisten = \"::1:80\"\n").find("an IPv6 address goes in brackets"), std::string::npos);
  EXPECT_EQ(config_error("\n[web]\npreview_fps = 100\n"),
            fmt::format("{}:{}: web.preview_fps: must be from 0.5 to 30 frames per second, got 100", file, line));
  EXPECT_EQ(
      config_error("\n[web]\nenable = true\n")
          .rfind(fmt::format("{}:{}: web.enable: unknown key (known here: enabled, listen, preview_fps)", file, line),
                 0),
      0U)
      << config_error("\n[web]\nenable = true\n");
}

class WebPageTest : public LiveViewTest {
 protected:
  void SetUp() override {
    LiveViewTest::SetUp();
    daemon_ = std::make_unique<Daemon>(config("\n[web]\nenabled = true\nlisten = \"127.0.0.1:0\"\n"));
    daemon_->start();
    ASSERT_NE(daemon_->web(), nullptr);
    port_ = daemon_->web()->port();
    ASSERT_GT(port_, 0);
  }

  [[nodiscard]] httplib::Client client() const {
    httplib::Client c("127.0.0.1", port_);
    c.set_read_timeout(30, 0);
    c.set_connection_timeout(30, 0);
    return c;
  }

  // The page's state once markerd holds a frame.
  json state_with_frame() {
    auto c = client();
    const auto deadline = Clock::now() + 60s;
    for (;;) {
      const auto result = c.Get("/state.json");
      if (!result || result->status != 200) return json();
      json state = json::parse(result->body);
      if (!state["frame"].is_null() || Clock::now() > deadline) return state;
      std::this_thread::sleep_for(20ms);
    }
  }

  std::unique_ptr<Daemon> daemon_;
  int port_ = 0;
};

TEST_F(WebPageTest, ThePageTheStateAndTheSnapshot) {
  auto c = client();
  const auto page = c.Get("/");
  ASSERT_TRUE(page) << httplib::to_string(page.error());
  EXPECT_EQ(page->status, 200);
  EXPECT_EQ(page->get_header_value("Content-Type"), "text/html; charset=utf-8");
  EXPECT_NE(page->body.find("<img id=\"preview\" src=\"/preview.mjpg\""), std::string::npos);
  EXPECT_NE(page->get_header_value("Content-Security-Policy").find("script-src 'self'"), std::string::npos);
  for (const char* path : {"/app.js", "/style.css"}) {
    const auto file = c.Get(path);
    ASSERT_TRUE(file) << path;
    EXPECT_EQ(file->status, 200) << path;
    EXPECT_GT(file->body.size(), 500U) << path;
  }
  const json state = state_with_frame();
  ASSERT_TRUE(state["frame"].is_object()) << state.dump();
  EXPECT_EQ(state["frame"]["frame"]["width"], 640);
  EXPECT_TRUE(state["rig"]["rail"].is_object());
  EXPECT_EQ(state["sweep"]["state"], "idle");
  EXPECT_TRUE(state["report"].is_null());
  EXPECT_EQ(state["web"]["max_previews"], WebServer::kMaxPreviews);

  const auto jpeg = c.Get("/snapshot.jpg");
  ASSERT_TRUE(jpeg);
  EXPECT_EQ(jpeg->status, 200);
  EXPECT_EQ(jpeg->get_header_value("Content-Type"), "image/jpeg");
  const cv::Mat annotated =
      cv::imdecode(std::vector<std::uint8_t>(jpeg->body.begin(), jpeg->body.end()), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(annotated.type(), CV_8UC3) << "annotated by default";
  EXPECT_EQ(annotated.cols, 640);
  const auto png = c.Get("/snapshot.png?annotate=0");
  ASSERT_TRUE(png);
  const cv::Mat grey =
      cv::imdecode(std::vector<std::uint8_t>(png->body.begin(), png->body.end()), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(grey.type(), CV_8UC1);
  EXPECT_EQ(grey.rows, 480);

  // The control socket's status says where the page is.
  ControlClient control(dir_ / "control.sock");
  const json status = control.call({{"cmd", "status"}});
  EXPECT_EQ(status["web"]["url"], fmt::format("http://127.0.0.1:{}/", port_));
  EXPECT_EQ(status["web"]["listen_loopback"], true);
}

TEST_F(WebPageTest, ThePreviewStreamsJpegFramesOneAfterAnother) {
  auto c = client();
  std::string content_type;
  std::string body;
  int parts = 0;
  const auto result = c.Get(
      "/preview.mjpg",
      [&](const httplib::Response& response) {
        content_type = response.get_header_value("Content-Type");
        return true;
      },
      [&](const char* data, std::size_t length) {
        body.append(data, length);
        parts = 0;
        for (std::size_t at = body.find("--markerdframe\r\n"); at != std::string::npos;
             at = body.find("--markerdframe\r\n", at + 1)) {
          ++parts;
        }
        return parts < 3;  // two whole parts, and the start of a third
      });
  EXPECT_EQ(content_type, "multipart/x-mixed-replace; boundary=markerdframe");
  ASSERT_GE(parts, 3) << body.size() << " bytes";
  // The first part: its headers, then as many bytes of JPEG as it says.
  const std::size_t length_at = body.find("Content-Length: ");
  ASSERT_NE(length_at, std::string::npos);
  const std::size_t length = std::stoul(body.substr(length_at + 16));
  const std::size_t data_at = body.find("\r\n\r\n", length_at) + 4;
  ASSERT_LE(data_at + length, body.size());
  const cv::Mat frame =
      cv::imdecode(std::vector<std::uint8_t>(body.begin() + static_cast<std::ptrdiff_t>(data_at),
                                             body.begin() + static_cast<std::ptrdiff_t>(data_at + length)),
                   cv::IMREAD_UNCHANGED);
  EXPECT_EQ(frame.cols, 640);
  EXPECT_EQ(frame.rows, 480);
  // Each part is another frame.
  std::vector<std::string> numbers;
  for (std::size_t at = body.find("X-Markerd-Frame: "); at != std::string::npos;
       at = body.find("X-Markerd-Frame: ", at + 1)) {
    numbers.push_back(body.substr(at + 17, body.find("\r\n", at) - at - 17));
  }
  ASSERT_GE(numbers.size(), 2U);
  EXPECT_NE(numbers[0], numbers[1]);
  (void)result;  // cancelled by the receiver, as a browser closing the page
}

TEST_F(WebPageTest, TheReportIsServedAndNothingOutsideIt) {
  const fs::path run = dir_ / "state" / "runs" / "20261201T071545Z-thesis";
  fs::create_directories(run / "report");
  test_support::write_file(run / "report" / "report.md", "# Table 6.1\n");
  test_support::write_file(run / "report" / "detection-rate.svg", "<svg xmlns=\"http://www.w3.org/2000/svg\"/>\n");
  test_support::write_file(run / "records.jsonl", "not for the page\n");
  test_support::write_file(dir_ / "secret.txt", "outside\n");
  fs::create_symlink(dir_ / "secret.txt", run / "report" / "linked.md");
  auto c = client();

  const auto index = c.Get("/report/index.json");
  ASSERT_TRUE(index);
  EXPECT_EQ(json::parse(index->body),
            (json{{"run_id", "20261201T071545Z-thesis"}, {"files", {"detection-rate.svg", "report.md"}}}));
  const auto md = c.Get("/report/report.md");
  ASSERT_TRUE(md);
  EXPECT_EQ(md->status, 200);
  EXPECT_EQ(md->body, "# Table 6.1\n");
  const auto svg = c.Get("/report/detection-rate.svg");
  ASSERT_TRUE(svg);
  EXPECT_EQ(svg->get_header_value("Content-Type"), "image/svg+xml");
  EXPECT_EQ(svg->get_header_value("Content-Security-Policy").rfind("sandbox", 0), 0U);
  EXPECT_EQ(svg->get_header_value_count("Content-Security-Policy"), 1U);
  const auto listing = c.Get("/report/");
  ASSERT_TRUE(listing);
  EXPECT_NE(listing->body.find("<h1>Run 20261201T071545Z-thesis</h1>"), std::string::npos) << listing->body;
  EXPECT_NE(listing->body.find("<a href=\"report.md\">report.md</a>"), std::string::npos) << listing->body;
  EXPECT_NE(json::parse(c.Get("/state.json")->body)["report"], nullptr);

  for (const char* path :
       {"/report/../records.jsonl", "/report/..%2frecords.jsonl", "/report/%2e%2e/records.jsonl",
        "/report/..%2F..%2F..%2Fsecret.txt", "/report/linked.md", "/report/.hidden", "/report/report.md%00",
        "/report/report.md/", "/../secret.txt", "/report//etc/passwd", "/report/%2Fetc%2Fpasswd"}) {
    const auto refused = c.Get(path);
    ASSERT_TRUE(refused) << path;
    EXPECT_EQ(refused->status, 404) << path << ": " << refused->body;
    EXPECT_EQ(refused->body.find("outside"), std::string::npos) << path;
    EXPECT_EQ(refused->body.find("not for the page"), std::string::npos) << path;
    EXPECT_EQ(refused->body.find("root:"), std::string::npos) << path;
  }
}

TEST_F(WebPageTest, OnlyGetAndHeadAreServed) {
  auto c = client();
  for (const auto& result : {c.Post("/", "x", "text/plain"), c.Put("/state.json", "{}", "application/json"),
                             c.Delete("/report/report.md"), c.Patch("/", "x", "text/plain")}) {
    ASSERT_TRUE(result);
    EXPECT_EQ(result->status, 405);
    EXPECT_EQ(result->get_header_value("Allow"), "GET, HEAD");
  }
  const auto head = c.Head("/state.json");
  ASSERT_TRUE(head);
  EXPECT_EQ(head->status, 200);
  const auto missing = c.Get("/admin");
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->status, 404);
}

TEST_F(WebPageTest, AnotherServerOnTheSamePortIsRefusedByName) {
  WebSettings settings = daemon_->config().web;
  settings.port = port_;
  WebServer second(settings, WebSources{});
  try {
    second.start();
    ADD_FAILURE() << "a second server listened on port " << port_;
  } catch (const WebServerError& e) {
    EXPECT_EQ(std::string(e.what()),
              fmt::format("{}:{}: web.listen: the web page cannot listen on 127.0.0.1:{}: Address already in use",
                          (dir_ / "markerd.toml").string(), base_lines() + 4, port_));
  }
}

TEST_F(WebPageTest, StoppingEndsAPreviewThatIsStreaming) {
  std::atomic<int> chunks{0};
  std::atomic<bool> returned{false};
  std::thread viewer([&] {
    auto c = client();
    (void)c.Get("/preview.mjpg", [&](const char*, std::size_t) {
      chunks.fetch_add(1);
      return true;  // watches for ever
    });
    returned = true;
  });
  const auto deadline = Clock::now() + 60s;
  while (chunks.load() < 3 && Clock::now() < deadline) std::this_thread::sleep_for(10ms);
  EXPECT_GE(chunks.load(), 3);
  EXPECT_EQ(daemon_->web()->previews(), 1U);
  daemon_->stop();  // what SIGTERM does
  viewer.join();
  EXPECT_TRUE(returned.load());
}

}  // namespace
}  // namespace markerd::daemon
