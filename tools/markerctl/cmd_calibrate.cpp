// markerctl calibrate: a camera's intrinsics and lens distortion from image
// files of a calibration board (board.hpp, calibration.hpp): the board's
// points found in each image, cv::calibrateCamera on them, the views that do
// not fit turned down, and the result written as OpenCV's calibration YAML
// and ROS's camera_info YAML (docs/calibration.md).

#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "board_options.hpp"
#include "calibrate_live.hpp"
#include "cmd_calibrate_rig.hpp"
#include "common.hpp"
#include "live_line.hpp"
#include "markerd/daemon/capture/image_file.hpp"
#include "markerd/detector/calibration.hpp"

namespace markerctl {
namespace {

namespace det = markerd::detector;

struct CalibrateOptions {
  BoardOptions board;
  std::string model = "plumb_bob";
  bool fix_k3 = false;
  int min_views = det::CalibrationOptions{}.min_views;
  double min_coverage = det::CalibrationOptions{}.min_coverage;
  std::string output;  // OpenCV's YAML
  std::string ros;     // ROS's camera_info YAML
  std::string camera_name = "camera";
  bool json = false;
  std::vector<std::string> images;
  LiveCalibrationOptions live;  // --live N: the views from markerd's frames instead
  RigCalibrationArguments rig;  // --rig: the camera and the rig from a sweep run instead
};

// The relative standard deviation of a focal length above which the views
// are said to determine it poorly: a board seen only face on leaves the
// focal length and the distance to the board trading off.
constexpr double kUncertainFocalShare = 0.01;

// Each image's board points, or why it gave none. The images must share one
// size: the first that reads sets it.
std::vector<det::CalibrationView> find_board(const CalibrateOptions& o, det::BoardDetector& detector, int& width,
                                             int& height) {
  std::vector<det::CalibrationView> views;
  markerd::daemon::ImageFileReader reader;
  det::GreyImage grey;
  LiveLine live(std::cerr, STDERR_FILENO);
  for (std::size_t i = 0; i < o.images.size(); ++i) {
    const std::string& path = o.images[i];
    live.show(fmt::format("calibrate: finding the board in image {} of {}: {}", i + 1, o.images.size(), path));
    det::CalibrationView& view = views.emplace_back();
    view.name = path;
    try {
      const markerd::daemon::ImageSize size = reader.open(path);
      if (width == 0) {
        width = size.width;
        height = size.height;
      }
      if (size.width != width || size.height != height) {
        view.rejected = fmt::format("the image is {}x{}, the first one {}x{}", size.width, size.height, width, height);
        continue;
      }
      if (grey.width() != width || grey.height() != height) grey = det::GreyImage(width, height);
      reader.decode(grey.data(), width);
    } catch (const markerd::daemon::ImageFileError& e) {
      // The error names the file, which the report names already.
      std::string why = e.what();
      if (why.rfind(path + ": ", 0) == 0) why.erase(0, path.size() + 2);
      view.rejected = "cannot be read: " + why;
      continue;
    }
    view.points = detector.detect(grey.view());
    if (view.points.image.empty()) view.rejected = "no board found";
  }
  return views;
}

nlohmann::ordered_json board_json(const det::BoardSpec& b) {
  nlohmann::ordered_json j;
  j["type"] = to_string(b.type);
  j["cols"] = b.cols;
  j["rows"] = b.rows;
  j["size_m"] = b.size_m;
  if (b.type == det::BoardType::charuco) {
    j["marker_size_m"] = b.marker_size_m;
    j["dictionary"] = b.dictionary;
  }
  if (b.type == det::BoardType::frame8) {
    j["spacing_m"] = b.spacing_m;
    j["ids"] = b.ids;
  }
  j["points"] = b.point_count();
  return j;
}

nlohmann::ordered_json views_json(const std::vector<det::ViewResult>& views) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (const det::ViewResult& v : views) {
    nlohmann::ordered_json j;
    j["image"] = v.name;
    j["points"] = v.points;
    j["rms_px"] = v.rms_px ? nlohmann::ordered_json(rounded(*v.rms_px, 4)) : nlohmann::ordered_json(nullptr);
    j["used"] = v.used();
    j["rejected"] = v.used() ? nlohmann::ordered_json(nullptr) : nlohmann::ordered_json(v.rejected);
    list.push_back(std::move(j));
  }
  return list;
}

std::size_t coefficient_count(det::DistortionModel model) {
  return model == det::DistortionModel::rational_polynomial ? 8 : 5;
}

constexpr std::array<const char*, 8> kCoefficientNames{"k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"};

void print_views(const std::vector<det::ViewResult>& views) {
  std::size_t name_width = 5;
  for (const auto& v : views) name_width = std::max(name_width, display_columns(v.name));
  std::cout << fmt::format("{:<{}}  points  rms px\n", "image", name_width);
  for (const auto& v : views) {
    const std::string rms = v.rms_px ? fmt::format("{:.3f}", *v.rms_px) : std::string("-");
    std::cout << fmt::format("{}{:<{}}  {:>6}  {:>6}{}\n", v.name, "", name_width - display_columns(v.name), v.points,
                             rms, v.used() ? std::string() : "  rejected: " + v.rejected);
  }
}

void print_result(const det::CalibrationResult& r, const CalibrateOptions& o) {
  print_views(r.views);
  const det::CameraModel& c = r.camera;
  std::cout << fmt::format("{} of {} views used, {}x{}; RMS reprojection error {:.3f} px\n", r.used_views(),
                           r.views.size(), c.width, c.height, r.rms_px);
  std::cout << fmt::format(
      "fx {:.3f} ± {:.3f}  fy {:.3f} ± {:.3f}  cx {:.3f} ± {:.3f}  cy {:.3f} ± {:.3f}  (px, ± one "
      "standard deviation)\n",
      c.fx, r.std_fx, c.fy, r.std_fy, c.cx, r.std_cx, c.cy, r.std_cy);
  std::string coefficients;
  for (std::size_t i = 0; i < coefficient_count(r.model); ++i) {
    const bool held = i == 4 && o.fix_k3;
    coefficients +=
        fmt::format("{}{} {}", i == 0 ? "" : ", ", kCoefficientNames[i],
                    held ? std::string("0 (held)") : fmt::format("{:.6g} ± {:.2g}", c.dist[i], r.std_dist[i]));
  }
  std::cout << fmt::format("distortion ({}): {}\n", to_string(r.model), coefficients);
  constexpr int regions = det::kCoverageGrid * det::kCoverageGrid;
  std::cout << fmt::format("coverage: points in {} of the image's {} regions ({}x{})\n",
                           std::lround(r.coverage() * regions), regions, det::kCoverageGrid, det::kCoverageGrid);
  if (!o.output.empty()) std::cout << fmt::format("wrote {} (OpenCV's calibration YAML)\n", o.output);
  if (!o.ros.empty()) std::cout << fmt::format("wrote {} (ROS camera_info YAML)\n", o.ros);
}

nlohmann::ordered_json result_json(const det::CalibrationResult& r, const CalibrateOptions& o,
                                   const det::BoardSpec& board) {
  nlohmann::ordered_json j;
  j["board"] = board_json(board);
  j["image_width"] = r.camera.width;
  j["image_height"] = r.camera.height;
  j["views"] = views_json(r.views);
  j["views_used"] = r.used_views();
  j["rms_px"] = rounded(r.rms_px, 4);
  const std::size_t n = coefficient_count(r.model);
  nlohmann::ordered_json camera;
  camera["fx"] = r.camera.fx;
  camera["fy"] = r.camera.fy;
  camera["cx"] = r.camera.cx;
  camera["cy"] = r.camera.cy;
  camera["distortion_model"] = to_string(r.model);
  camera["distortion"] = std::vector<double>(r.camera.dist.begin(), r.camera.dist.begin() + static_cast<long>(n));
  j["camera"] = std::move(camera);
  nlohmann::ordered_json std_dev;
  std_dev["fx"] = r.std_fx;
  std_dev["fy"] = r.std_fy;
  std_dev["cx"] = r.std_cx;
  std_dev["cy"] = r.std_cy;
  std_dev["distortion"] = std::vector<double>(r.std_dist.begin(), r.std_dist.begin() + static_cast<long>(n));
  j["std_dev"] = std::move(std_dev);
  nlohmann::ordered_json coverage;
  coverage["grid"] = det::kCoverageGrid;
  coverage["share"] = rounded(r.coverage(), 4);
  nlohmann::ordered_json rows = nlohmann::ordered_json::array();
  for (int row = 0; row < det::kCoverageGrid; ++row) {
    const auto* first = r.region_points.data() + static_cast<std::ptrdiff_t>(row) * det::kCoverageGrid;
    rows.push_back(std::vector<int>(first, first + det::kCoverageGrid));
  }
  coverage["points"] = std::move(rows);
  j["coverage"] = std::move(coverage);
  j["output"] = o.output.empty() ? nlohmann::ordered_json(nullptr) : nlohmann::ordered_json(o.output);
  j["ros"] = o.ros.empty() ? nlohmann::ordered_json(nullptr) : nlohmann::ordered_json(o.ros);
  return j;
}

int run_calibrate(const CalibrateOptions& o) {
  if (!o.rig.run.empty()) {
    // A sweep run's views, not a board's images: the options of one do not apply to the other.
    if (!o.images.empty()) throw usage_error("--rig", "takes no images: the run's records are its views");
    if (!o.board.board.empty()) throw usage_error("--rig", "takes no --board: the marker the run saw is the target");
    if (!o.ros.empty()) throw usage_error("--rig", "writes OpenCV's YAML with -o; --ros is for board calibrations");
    if (o.live.views > 0) throw usage_error("--rig", "takes no --live: the run's records are its views");
    return run_rig_calibration(o.rig, o.output, o.json);
  }
  if (!o.rig.rig_out.empty() || !o.rig.fix.empty() || !o.rig.free.empty()) {
    throw usage_error("calibrate", "--rig-out, --fix and --free are for --rig RUN_DIR");
  }
  if (o.board.board.empty()) {
    throw usage_error("--board",
                      "give the board: COLSxROWS with --board-type and --size (as markerctl marker "
                      "--board printed it), or its board file");
  }
  const det::BoardSpec board = board_from_options(o.board, true);
  const bool live = o.live.views > 0;
  if (live && !o.images.empty()) {
    throw usage_error("--live", "takes its views from markerd's frames: give no image files with it");
  }
  if (!live && (!o.live.keep_dir.empty() || !o.live.socket.empty())) {
    throw usage_error(o.live.keep_dir.empty() ? "--socket" : "--keep", "is for --live N");
  }
  if (live && o.live.views < o.min_views) {
    throw usage_error("--live", fmt::format("{} views are fewer than --min-views {}", o.live.views, o.min_views));
  }
  if (!live && o.images.empty()) {
    throw usage_error("calibrate",
                      "no images given: the board's views, 10 to 30 of them (or --live N to take them from markerd)");
  }
  if (std::find(o.images.begin(), o.images.end(), "-") != o.images.end()) {
    throw usage_error("calibrate", "'-': the views are read from files, not from standard input");
  }
  if (!o.ros.empty() && !det::CameraModel::is_ros_camera_name(o.camera_name)) {
    throw usage_error("--camera-name",
                      fmt::format("'{}' must be letters, digits and _ (then also - . /)", o.camera_name));
  }
  if (!o.output.empty() && o.output == o.ros) throw usage_error("--ros", "names the same file as -o");
  // Checked before the images are read: a calibration is not to be lost to
  // a mistyped directory at the end.
  for (const auto& [file, option] : {std::pair{o.output, "-o"}, std::pair{o.ros, "--ros"}}) {
    if (file.empty()) continue;
    const std::filesystem::path parent = std::filesystem::path(file).parent_path();
    std::error_code ec;
    if (!parent.empty() && !std::filesystem::is_directory(parent, ec)) {
      throw usage_error(option, fmt::format("{}: the directory {} does not exist", file, parent.string()));
    }
  }
  det::CalibrationOptions options;
  options.model = *det::distortion_model_from_string(o.model);
  options.fix_k3 = o.fix_k3;
  options.min_views = o.min_views;
  options.min_coverage = o.min_coverage;

  det::BoardDetector detector(board);
  int width = 0, height = 0;
  std::vector<det::CalibrationView> views;
  if (live) {
    LiveViews gathered = gather_live_views(o.live, detector, options.min_points);
    views = std::move(gathered.views);
    width = gathered.width;
    height = gathered.height;
    if (views.empty()) throw runtime_error("calibrate", "no view was kept: nothing to calibrate from");
  } else {
    views = find_board(o, detector, width, height);
  }
  if (width == 0) {
    throw runtime_error("calibrate", fmt::format("none of the {} image{} could be read", o.images.size(),
                                                 o.images.size() == 1 ? "" : "s"));
  }
  det::CalibrationResult result;
  try {
    result = det::calibrate_camera(views, width, height, options);
  } catch (const det::CalibrationError& e) {
    if (o.json) {
      nlohmann::ordered_json j;
      j["board"] = board_json(board);
      j["image_width"] = width;
      j["image_height"] = height;
      j["views"] = views_json(e.views());
      j["camera"] = nullptr;
      j["error"] = e.what();
      std::cout << json_line(j) << '\n';
    } else {
      print_views(e.views());
    }
    throw runtime_error("calibrate", e.what());
  }
  if (!o.output.empty()) result.camera.save(o.output, det::CameraFileFormat::opencv);
  if (!o.ros.empty()) result.camera.save(o.ros, det::CameraFileFormat::ros, o.camera_name);
  if (o.json) {
    std::cout << json_line(result_json(result, o, board)) << '\n';
  } else {
    print_result(result, o);
  }
  const double focal_share = std::max(result.std_fx / result.camera.fx, result.std_fy / result.camera.fy);
  if (focal_share > kUncertainFocalShare) {
    std::cout.flush();
    std::cerr << fmt::format(
        "markerctl: note: the focal length is known to {:.1f}% only (one standard deviation): add views with the "
        "board tilted 30 to 45 degrees, towards every side\n",
        focal_share * 100);
  }
  return 0;
}

}  // namespace

void add_calibrate_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<CalibrateOptions>();
  CLI::App* app = parent.add_subcommand("calibrate", "Calibrate a camera from images of a calibration board");
  app->footer(
      "Calibrate a camera (intrinsics and lens distortion) from images of a calibration board, as\n"
      "markerctl marker --board prints it (docs/calibration.md). The board is given as it was printed:\n"
      "--board COLSxROWS with --board-type, --size and the type's options, or --board FILE, the board\n"
      "file written beside the print. In each image the board's points are found (a chessboard whole;\n"
      "a ChArUco or frame8 board also in part), then cv::calibrateCamera fits the camera to them.\n"
      "Views are rejected, each with its reason: unreadable, another size than the first image, no\n"
      "board found, fewer than 8 points or all on one line, and, after each fit, the worst view while\n"
      "its RMS reprojection error is over 3 times the median view's and over 0.5 px (then fitted\n"
      "again). Refused, exit 1: fewer than --min-views views left, or their points in less than\n"
      "--min-coverage of the image's 16 regions (4x4). Prints each view's points and RMS error, the\n"
      "overall RMS error, the intrinsics and distortion with their standard deviations, and writes\n"
      "-o FILE (OpenCV's calibration YAML) and --ros FILE (ROS camera_info YAML); --camera of every\n"
      "command reads both.\n"
      "--live N takes the views from a running markerd instead of files: move the board before the camera\n"
      "and hold it still at each pose; a frame becomes a view when the board's points moved under 1 px since\n"
      "the frame before and, on average, over 5% of the image's diagonal from every view kept so far. A live\n"
      "line says what each frame lacks and which regions of the image have no points yet; Ctrl-C ends the\n"
      "gathering early and calibrates from the views kept; --keep DIR saves them as files.\n"
      "--rig RUN_DIR instead fits the camera's intrinsics and the rig's geometry (d0_mm, yaw0_deg, the marker's\n"
      "and the camera's offsets, the rail's tilt) to the marker's corners a sweep run detected at its rail\n"
      "positions and turntable angles, with their standard deviations (docs/calibration-rig.md); -o writes the\n"
      "camera model, --rig-out the geometry for [rig.geometry] calibration = \"FILE\".");
  add_board_options(app, o->board,
                    "The board: COLS x ROWS squares (frame8: markers) with the options below, or the board file "
                    "markerctl marker --board wrote",
                    "COLSxROWS|FILE");
  o->board.size_option = app->add_option("--size", o->board.size,
                                         "A square's side, or a frame8 marker's outer edge (25mm, 2.5cm, 0.025m; a "
                                         "bare number is mm)")
                             ->type_name("LENGTH");
  app->add_option("--model", o->model,
                  "Lens model: plumb_bob (k1 k2 p1 p2 k3) or rational_polynomial (k1 to k6, p1, p2; wide-angle "
                  "lenses)")
      ->type_name("NAME")
      ->check(CLI::IsMember({"plumb_bob", "rational_polynomial"}))
      ->capture_default_str();
  app->add_flag("--fix-k3", o->fix_k3,
                "Hold k3 at zero (OpenCV's CALIB_FIX_K3; ROS's default): for a lens of moderate distortion");
  app->add_option("--min-views", o->min_views, "Fewest views that must be left after the rejections")
      ->capture_default_str()
      ->check(CLI::Range(3, 1000));
  app->add_option("--min-coverage", o->min_coverage,
                  "Least share of the image's 4x4 regions that the views' points must reach (0 to 1)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app->add_option("-o,--output", o->output, "Write the calibration as OpenCV's calibration YAML")->type_name("FILE");
  app->add_option("--ros", o->ros, "Write the calibration as ROS camera_info YAML")->type_name("FILE");
  app->add_option("--camera-name", o->camera_name, "camera_name in the ROS file")
      ->type_name("NAME")
      ->capture_default_str();
  app->add_flag("--json", o->json, "The result as one JSON object instead of text");
  app->add_option("--live", o->live.views,
                  "Take N views from markerd's frames (its control socket) while the board is moved before the "
                  "camera, instead of image files")
      ->type_name("N")
      ->check(CLI::Range(1, 1000));
  app->add_option("--keep", o->live.keep_dir, "With --live: save the views kept as PNG in DIR (made if missing)")
      ->type_name("DIR");
  app->add_option("--socket", o->live.socket,
                  "With --live: markerd's control socket (default: $MARKERD_SOCKET, else /run/markerd/control.sock)")
      ->type_name("PATH");
  add_rig_calibration_options(*app, o->rig);
  // Not required by CLI11: run_calibrate names what is missing, in words.
  app->add_option("images", o->images, "Image files of the board (PNG, JPEG, PGM/PPM/PBM, BMP, TIFF)")
      ->type_name("IMAGE");
  commands.push_back({app, [o] { return run_calibrate(*o); }});
}

}  // namespace markerctl
