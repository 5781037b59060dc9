// markerctl marker --board and markerctl calibrate end to end: the real
// binary (MARKERCTL_PATH) prints a board and its board file, and calibrates
// from rendered views of that board through a known camera written as
// image files, some of them unreadable or of another board; what it wrote
// (OpenCV's and ROS's YAML) reads back the same, and every command that
// takes --camera reads both; and --live takes the views from a running
// markerd instead.

#include <gtest/gtest.h>
#include <signal.h>

#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <thread>
#include <vector>

#include "calibration_views.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/detector/camera_model.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace markerd::detector {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test_support::Outcome;

Outcome markerctl(const std::vector<std::string>& args) {
  std::vector<std::string> argv{MARKERCTL_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  Outcome r = test_support::run_program(argv);
  if (r.timed_out) ADD_FAILURE() << "markerctl did not finish: " << r.describe();
  return r;
}

void write_png(const fs::path& path, const GreyImage& image) {
  const cv::Mat mat(image.height(), image.width(), CV_8U, const_cast<std::uint8_t*>(image.data()));
  ASSERT_TRUE(cv::imwrite(path.string(), mat)) << path;
}

class MarkerctlCalibrate : public ::testing::Test {
 protected:
  [[nodiscard]] std::string path(const std::string& name) const { return (dir_ / name).string(); }

  // Twelve views of the frame8 board through the distorted camera.
  std::vector<std::string> write_views() const {
    const CameraModel camera = calibration_test::distorted_camera();
    const auto print = calibration_test::board_print(calibration_test::frame8_board());
    std::vector<std::string> files;
    const auto plans = calibration_test::view_plans();
    for (std::size_t i = 0; i < plans.size(); ++i) {
      const MarkerPose pose = calibration_test::plan_pose(camera, *print, plans[i]);
      files.push_back(path("view-" + std::to_string(i) + ".png"));
      write_png(files.back(), render_scene(camera, calibration_test::board_scene(print, pose, 40 + i)));
    }
    return files;
  }

  test_support::TempDir dir_{"markerd-test-calibrate"};
};

TEST_F(MarkerctlCalibrate, MarkerPrintsABoardAndItsBoardFile) {
  const Outcome r = markerctl({"marker", "--board-type", "frame8", "--board", "4x3", "--size", "36mm", "--spacing",
                               "9mm", "-o", path("board.pdf"), "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json j = json::parse(r.out);
  EXPECT_EQ(j["board_file"], path("board.toml"));
  EXPECT_EQ(j["ids"], json::parse("[2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]"));
  EXPECT_EQ(j["page_width_mm"], 191.0);
  EXPECT_EQ(j["page_height_mm"], 146.0);
  EXPECT_EQ(j["points"], 48);
  EXPECT_EQ(test_support::read_file(path("board.toml")), board_file_text(calibration_test::frame8_board()));
  EXPECT_EQ(test_support::read_file(path("board.pdf")).rfind("%PDF", 0), 0U);

  const Outcome charuco = markerctl({"marker", "--board-type", "charuco", "--board", "7x5", "--size", "25mm",
                                     "--marker-size", "19mm", "-o", path("charuco.svg")});
  ASSERT_EQ(charuco.code, 0) << charuco.describe();
  EXPECT_EQ(charuco.out, path("charuco.svg") +
                             ": charuco 7x5, square 25 mm, marker 19 mm, 4x4_50, 10 mm margin, page "
                             "195 x 145 mm\n" +
                             path("charuco.toml") + ": the board file (markerctl calibrate --board " +
                             path("charuco.toml") + ")\n");
  EXPECT_EQ(load_board(path("charuco.toml")).marker_size_m, 0.019);

  struct Case {
    std::vector<std::string> args;
    std::string error;
  };
  const Case cases[] = {
      {{"--board", "9x7"}, "markerctl: --size: a chessboard needs the size of its squares (for example --size 25mm)\n"},
      {{"--board", "9x7", "--size", "20mm", "--id", "3"}, "markerctl: --id: is for a single marker, not a --board\n"},
      {{"--board", "9x7", "--size", "20mm", "--dictionary", "5x5_50"},
       "markerctl: --dictionary: is for a ChArUco board, not a chessboard\n"},
      {{"--board", "2x7", "--size", "20mm"}, "markerctl: --board: must be from 3 to 100 (squares), got 2\n"},
      {{"--board", "nine", "--size", "20mm"}, "markerctl: --board: 'nine' is not COLSxROWS (for example 9x6)\n"},
      {{"--spacing", "5mm", "--id", "3", "--size", "20mm"},
       "markerctl: --spacing: is for a calibration board: give --board too\n"},
      {{"--size", "20mm"},
       "markerctl: --id: a marker needs its id, e.g. --id 165 (or --board COLSxROWS for a calibration board)\n"},
      {{"--board-type", "frame8", "--board", "20x20", "--size", "20mm"},
       "markerctl: --first-id: a 20x20 board needs 400 ids; from 0 up there are 248 that are not near-uniform\n"},
      {{"--board-type", "frame8", "--board", "3x3", "--size", "20mm", "--spacing", "1mm"},
       "markerctl: --spacing: must be from a tenth (a cell) to ten times the marker's size (2 to 200 mm), got 1 mm\n"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args{"marker", "-o", path("x.pdf")};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome bad = markerctl(args);
    EXPECT_EQ(bad.code, 2) << bad.describe();
    EXPECT_EQ(bad.err, c.error) << bad.describe();
  }
  EXPECT_FALSE(fs::exists(path("x.pdf")));
}

TEST_F(MarkerctlCalibrate, CalibratesFromImagesAndWritesBothFormats) {
  ASSERT_EQ(markerctl({"marker", "--board-type", "frame8", "--board", "4x3", "--size", "36mm", "--spacing", "9mm", "-o",
                       path("board.pdf")})
                .code,
            0);
  std::vector<std::string> images = write_views();
  // A truncated file, a view of another board, and an image of another size.
  const std::string png = test_support::read_file(images[0]);
  images.push_back(dir_.write("truncated.png", png.substr(0, png.size() / 3)).string());
  const CameraModel camera = calibration_test::distorted_camera();
  const auto chessboard = calibration_test::board_print(calibration_test::chessboard());
  images.push_back(path("chessboard.png"));
  write_png(images.back(), render_scene(camera, calibration_test::board_scene(chessboard, facing_pose(0.4, 0, 0), 1)));
  images.push_back(path("small.png"));
  write_png(images.back(), GreyImage(320, 240, 128));

  std::vector<std::string> args{"calibrate", "--board",        path("board.toml"), "-o",   path("camera.yaml"),
                                "--ros",     path("ros.yaml"), "--camera-name",    "rail", "--json"};
  args.insert(args.end(), images.begin(), images.end());
  const Outcome r = markerctl(args);
  ASSERT_EQ(r.code, 0) << r.describe();
  const json j = json::parse(r.out);
  EXPECT_EQ(j["board"]["type"], "frame8");
  EXPECT_EQ(j["image_width"], 640);
  EXPECT_EQ(j["views_used"], 12);
  ASSERT_EQ(j["views"].size(), 15U);
  for (std::size_t i = 0; i < 12; ++i) {
    EXPECT_EQ(j["views"][i]["used"], true) << j["views"][i];
    EXPECT_EQ(j["views"][i]["points"], 48) << j["views"][i];
    EXPECT_LT(j["views"][i]["rms_px"].get<double>(), 0.1) << j["views"][i];
  }
  EXPECT_EQ(j["views"][12]["rejected"].get<std::string>().rfind("cannot be read: ", 0), 0U) << j["views"][12];
  EXPECT_EQ(j["views"][13]["rejected"], "no board found");
  EXPECT_EQ(j["views"][14]["rejected"], "the image is 320x240, the first one 640x480");
  EXPECT_TRUE(j["views"][14]["rms_px"].is_null());
  EXPECT_LT(j["rms_px"].get<double>(), 0.1);
  EXPECT_EQ(j["camera"]["distortion_model"], "plumb_bob");
  EXPECT_EQ(j["camera"]["distortion"].size(), 5U);
  EXPECT_EQ(j["std_dev"]["distortion"].size(), 5U);
  EXPECT_EQ(j["coverage"]["share"], 1.0);
  const double fx = j["camera"]["fx"];
  EXPECT_LT(std::abs(fx - camera.fx), 3 * j["std_dev"]["fx"].get<double>());
  EXPECT_LT(std::abs(j["camera"]["cy"].get<double>() - camera.cy), 3 * j["std_dev"]["cy"].get<double>());

  // Both files read back to the same model, the one printed.
  const CameraModel opencv = CameraModel::load(path("camera.yaml"));
  const CameraModel ros = CameraModel::load(path("ros.yaml"));
  EXPECT_EQ(opencv.fx, fx);
  EXPECT_EQ(ros.width, opencv.width);
  EXPECT_EQ(ros.height, opencv.height);
  EXPECT_EQ(ros.fx, opencv.fx);
  EXPECT_EQ(ros.fy, opencv.fy);
  EXPECT_EQ(ros.cx, opencv.cx);
  EXPECT_EQ(ros.cy, opencv.cy);
  EXPECT_EQ(ros.dist, opencv.dist);
  EXPECT_NE(test_support::read_file(path("ros.yaml")).find("camera_name: rail\n"), std::string::npos);

  // Every command that takes --camera reads either.
  for (const std::string& file : {path("camera.yaml"), path("ros.yaml")}) {
    const Outcome rendered = markerctl({"render", "--camera", file, "--dist", "0.5", "-o", path("frame.png")});
    EXPECT_EQ(rendered.code, 0) << rendered.describe();
    const Outcome detected = markerctl({"detect", "--camera", file, "--size", "0.08", path("frame.png")});
    EXPECT_EQ(detected.code, 0) << detected.describe();
    EXPECT_NE(detected.out.find("\"tvec\""), std::string::npos) << detected.describe();
    const Outcome evaluated = markerctl({"evaluate", "--camera", file, "--family", "frame8", "--frames", "1", "--dist",
                                         "0.5", "--yaw-at", "none", "--json", "--quiet"});
    EXPECT_EQ(evaluated.code, 0) << evaluated.describe();
  }

  // The same as text, with k3 held: each view on a line, then the result.
  std::vector<std::string> text_args{"calibrate", "--board", path("board.toml"), "--fix-k3"};
  text_args.insert(text_args.end(), images.begin(), images.end());
  const Outcome text = markerctl(text_args);
  ASSERT_EQ(text.code, 0) << text.describe();
  EXPECT_NE(text.out.find("12 of 15 views used, 640x480; RMS reprojection error "), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("  rejected: no board found\n"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find(", k3 0 (held)\n"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("  rejected: cannot be read: the PNG is truncated"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("coverage: points in 16 of the image's 16 regions (4x4)\n"), std::string::npos) << text.out;
}

TEST_F(MarkerctlCalibrate, RefusesTooFewViewsAndNamesWrongOptions) {
  ASSERT_EQ(markerctl({"marker", "--board-type", "frame8", "--board", "4x3", "--size", "36mm", "--spacing", "9mm", "-o",
                       path("board.pdf")})
                .code,
            0);
  const CameraModel camera = calibration_test::distorted_camera();
  const auto print = calibration_test::board_print(calibration_test::frame8_board());
  std::vector<std::string> images;
  for (std::size_t i = 0; i < 2; ++i) {
    images.push_back(path("view-" + std::to_string(i) + ".png"));
    const MarkerPose pose = calibration_test::plan_pose(camera, *print, calibration_test::view_plans()[i]);
    write_png(images.back(), render_scene(camera, calibration_test::board_scene(print, pose, i)));
  }
  const Outcome few =
      markerctl({"calibrate", "--board", path("board.toml"), images[0], images[1], "-o", path("camera.yaml")});
  EXPECT_EQ(few.code, 1) << few.describe();
  EXPECT_EQ(few.err,
            "markerctl: calibrate: 2 views are left with the board found, at least 5 are needed: take more views of "
            "the board, tilted and spread over the image\n");
  EXPECT_NE(few.out.find(images[1]), std::string::npos) << few.describe();
  EXPECT_FALSE(fs::exists(path("camera.yaml")));
  const Outcome few_json = markerctl({"calibrate", "--board", path("board.toml"), images[0], "--json"});
  EXPECT_EQ(few_json.code, 1) << few_json.describe();
  const json j = json::parse(few_json.out);
  EXPECT_TRUE(j["camera"].is_null());
  EXPECT_EQ(j["error"].get<std::string>().rfind("1 view is left with the board found", 0), 0U) << j;

  struct Case {
    std::vector<std::string> args;
    std::string error;
  };
  const std::string board = path("board.toml");
  const Case cases[] = {
      {{images[0]},
       "markerctl: --board: give the board: COLSxROWS with --board-type and --size (as markerctl marker --board "
       "printed it), or its board file\n"},
      {{"--board", board},
       "markerctl: calibrate: no images given: the board's views, 10 to 30 of them (or --live N to take them from "
       "markerd)\n"},
      {{"--board", board, "--live", "10", images[0]},
       "markerctl: --live: takes its views from markerd's frames: give no image files with it\n"},
      {{"--board", board, "--live", "3"}, "markerctl: --live: 3 views are fewer than --min-views 5\n"},
      {{"--board", board, "--keep", path("kept"), images[0]}, "markerctl: --keep: is for --live N\n"},
      {{"--board", board, "--size", "20mm", images[0]},
       "markerctl: --size: the board file " + board + " gives the board's geometry\n"},
      {{"--board", board, "--board-type", "charuco", images[0]},
       "markerctl: --board-type: 'charuco', but the board file " + board + " is a frame8 board\n"},
      {{"--board", path("nothing.toml"), images[0]},
       "markerctl: --board: '" + path("nothing.toml") + "' is neither COLSxROWS (for example 9x6) nor a board file\n"},
      {{"--board", board, "--ros", path("r.yaml"), "--camera-name", "two words", images[0]},
       "markerctl: --camera-name: 'two words' must be letters, digits and _ (then also - . /)\n"},
      {{"--board", board, "--ros", path("r.yaml"), "-o", path("r.yaml"), images[0]},
       "markerctl: --ros: names the same file as -o\n"},
      {{"--board", board, "-o", path("no-such-dir/camera.yaml"), images[0]},
       "markerctl: -o: " + path("no-such-dir/camera.yaml") + ": the directory " + path("no-such-dir") +
           " does not exist\n"},
      {{"--board", "9x7", images[0]},
       "markerctl: --size: a chessboard needs the size of its squares (for example --size 25mm)\n"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args{"calibrate"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome bad = markerctl(args);
    EXPECT_EQ(bad.code, 2) << bad.describe();
    EXPECT_EQ(bad.err, c.error) << bad.describe();
  }
  // A board file that is wrong is named with its line.
  const fs::path wrong = dir_.write("wrong.toml", "type = \"frame8\"\ncols = 4\nrows = 3\nsize_m = 0.036\n");
  const Outcome bad_file = markerctl({"calibrate", "--board", wrong.string(), images[0]});
  EXPECT_EQ(bad_file.code, 1) << bad_file.describe();
  EXPECT_EQ(bad_file.err, "markerctl: --board: " + wrong.string() + ": missing key 'spacing_m' (a number)\n");
  // --live with no markerd to ask.
  const Outcome no_daemon =
      markerctl({"calibrate", "--board", board, "--live", "10", "--socket", path("no-such.sock")});
  EXPECT_EQ(no_daemon.code, 1) << no_daemon.describe();
  EXPECT_EQ(no_daemon.err.rfind("markerctl: calibrate: cannot connect to " + path("no-such.sock"), 0), 0U)
      << no_daemon.describe();
}

// --live: markerd replays the twelve views as a camera would see a board
// moved from pose to pose and held still at each (a file source, each view
// for 8 frames at 10 a second, round and round); markerctl keeps each pose
// once, still, and calibrates as from the files.
TEST_F(MarkerctlCalibrate, LiveTakesEachStillPoseOnceFromMarkerd) {
  ASSERT_EQ(markerctl({"marker", "--board-type", "frame8", "--board", "4x3", "--size", "36mm", "--spacing", "9mm", "-o",
                       path("board.pdf")})
                .code,
            0);
  const std::vector<std::string> views = write_views();
  fs::create_directories(path("frames"));
  for (std::size_t i = 0; i < views.size(); ++i) {
    for (int k = 0; k < 8; ++k) fs::copy_file(views[i], path(fmt::format("frames/f{:02}-{}.png", i, k)));
  }
  test_support::prepare_markerd_dir(dir_.path());
  test_support::write_file(dir_.path() / "markerd.toml", R"([marker]
family = "frame8"
id = 165
size_m = 0.08

[camera]
source = "file"

[camera.file]
path = "frames"
fps = 10
loop = true

[log]
directory = "logs"

[control]
socket = "control.sock"
)");
  daemon::Daemon markerd(daemon::load_daemon_config(dir_.path() / "markerd.toml"));
  markerd.start();

  const std::string board = path("board.toml");
  const Outcome r = markerctl({"calibrate", "--board", board, "--live", "10", "--keep", path("kept"), "--socket",
                               path("control.sock"), "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json j = json::parse(r.out);
  EXPECT_EQ(j["views_used"], 10);
  ASSERT_EQ(j["views"].size(), 10U);
  std::vector<std::string> kept;
  for (std::size_t i = 0; i < 10; ++i) {
    kept.push_back(path(fmt::format("kept/view-{:02}.png", i + 1)));
    EXPECT_EQ(j["views"][i]["image"], kept.back());
    EXPECT_EQ(j["views"][i]["points"], 48) << j["views"][i];
    EXPECT_TRUE(fs::exists(kept.back()));
  }
  // Each pose once: no two kept views are the same picture.
  for (std::size_t a = 0; a < kept.size(); ++a) {
    for (std::size_t b = a + 1; b < kept.size(); ++b) {
      EXPECT_NE(test_support::read_file(kept[a]), test_support::read_file(kept[b])) << a << " " << b;
    }
  }
  const CameraModel camera = calibration_test::distorted_camera();
  EXPECT_LT(std::abs(j["camera"]["fx"].get<double>() - camera.fx), 3 * j["std_dev"]["fx"].get<double>());
  EXPECT_LT(std::abs(j["camera"]["cx"].get<double>() - camera.cx), 3 * j["std_dev"]["cx"].get<double>());
  EXPECT_NE(r.err.find("calibrate: view 10 of 10 kept: " + kept.back() + ", 48 points; "), std::string::npos) << r.err;

  // The kept files calibrate to the same camera.
  std::vector<std::string> args{"calibrate", "--board", board, "--json"};
  args.insert(args.end(), kept.begin(), kept.end());
  const Outcome again = markerctl(args);
  ASSERT_EQ(again.code, 0) << again.describe();
  EXPECT_EQ(json::parse(again.out)["camera"], j["camera"]);

  // Interrupted once it has kept enough: it calibrates from what it kept.
  test_support::CapturedProcess live(
      {MARKERCTL_PATH, "calibrate", "--board", board, "--live", "40", "--socket", path("control.sock")});
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(3);
  while (live.err().find("view 10 of 40 kept") == std::string::npos && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ::kill(live.pid(), SIGINT);
  const Outcome stopped = live.wait();
  EXPECT_EQ(stopped.code, 0) << stopped.describe();
  EXPECT_NE(stopped.err.find("calibrate: SIGINT: taking no more views, 10 kept"), std::string::npos)
      << stopped.describe();
  EXPECT_NE(stopped.out.find("10 of 10 views used, 640x480"), std::string::npos) << stopped.describe();
}

}  // namespace
}  // namespace markerd::detector
