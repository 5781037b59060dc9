// markerctl detect: markers in image files, one JSON line per detection. An
// image that cannot be read or does not decode whole is reported and skipped;
// the exit status says whether any was.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "common.hpp"
#include "markerd/daemon/capture/image_file.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/sweep/plan.hpp"

namespace markerctl {
namespace {

struct DetectOptions {
  std::string camera;
  std::string size;
  std::string family = "frame8";
  int decimate = 0;
  int threshold_offset = markerd::detector::Frame8Options{}.threshold_offset;
  double min_margin = markerd::detector::Frame8Options{}.min_margin;
  bool uniform_ids = false;
  double blur_sigma_px = markerd::detector::Frame8Options{}.blur_sigma_px;
  std::string mounting;
  std::string debug_dir;
  bool verbose = false;
  bool json = false;  // the output is JSON either way; accepted as every command with output accepts it
  std::vector<std::string> images;
};

nlohmann::ordered_json quad_json(const markerd::detector::Quad& quad) {
  auto out = nlohmann::ordered_json::array();
  // 1e-4 px: ten times finer than the detectors' best sub-pixel accuracy.
  for (const auto& p : quad) out.push_back({rounded(p.x, 4), rounded(p.y, 4)});
  return out;
}

nlohmann::ordered_json detection_json(const std::string& file, const markerd::detector::Detection& d, double time_ms) {
  nlohmann::ordered_json j;
  j["file"] = file;
  j["family"] = markerd::detector::family_info(d.family).name;
  j["id"] = d.id;
  j["corners"] = quad_json(d.corners);
  if (d.inner_corners) j["inner_corners"] = quad_json(*d.inner_corners);
  j["quarter_turns"] = d.quarter_turns;
  j["orientation_ambiguous"] = d.orientation_ambiguous;
  j["bits_corrected"] = d.bits_corrected;
  j["margin"] = rounded(d.margin, 4);
  if (d.pose) {
    const markerd::detector::MarkerPose& pose = d.pose->best;
    const Eigen::Vector3d r = pose.rvec();
    const Eigen::Quaterniond q = pose.quaternion();
    const Eigen::Vector3d& t = pose.translation;
    j["rvec"] = {rounded(r.x(), 7), rounded(r.y(), 7), rounded(r.z(), 7)};
    j["tvec"] = {rounded(t.x(), 7), rounded(t.y(), 7), rounded(t.z(), 7)};
    j["quaternion"] = {rounded(q.w(), 7), rounded(q.x(), 7), rounded(q.y(), 7), rounded(q.z(), 7)};
    j["reprojection_error_px"] = rounded(pose.reprojection_error_px, 4);
    j["ambiguous"] = d.pose->ambiguous;
  }
  j["time_ms"] = rounded(time_ms, 3);
  return j;
}

int run_detect(const DetectOptions& o) {
  const markerd::detector::Family family = parse_family(o.family);
  if (std::count(o.images.begin(), o.images.end(), "-") > 1) {
    throw usage_error("detect", "'-' (standard input) can be given once");
  }
  if (o.camera.empty() != o.size.empty()) {
    throw usage_error(o.camera.empty() ? "--size" : "--camera",
                      "the pose needs both --camera and --size (give both or neither)");
  }
  markerd::detector::DetectorConfig config;
  config.family = family;
  config.frame8.decimate = o.decimate;
  config.frame8.threshold_offset = o.threshold_offset;
  config.frame8.min_margin = o.min_margin;
  config.frame8.uniform_ids = o.uniform_ids;
  config.frame8.blur_sigma_px = o.blur_sigma_px;
  if (!o.mounting.empty()) {
    config.frame8.mounting = markerd::sweep::detector_mounting(*markerd::sweep::mounting_from_name(o.mounting));
  }
  if (!o.debug_dir.empty() && family != markerd::detector::Family::frame8) {
    throw usage_error("--debug", "only the frame8 detector has a debug output");
  }
  config.frame8.debug_dir = o.debug_dir;
  if (!o.camera.empty()) {
    config.marker_size_m = parse_length_m(o.size, BareUnit::metre, "--size");
    if (!(config.marker_size_m > 0)) throw usage_error("--size", fmt::format("'{}' must be more than zero", o.size));
    config.camera = load_camera(o.camera);
  }
  const auto detector = markerd::detector::make_detector(config);

  int failed = 0;
  const auto report = [&failed](const std::string& message) {
    std::cout.flush();
    std::cerr << fmt::format("markerctl: {}\n", message);
    ++failed;
  };
  std::vector<markerd::detector::Detection> detections;
  markerd::daemon::ImageFileReader reader;
  markerd::detector::GreyImage grey;
  int debug_frame = 0;  // the detector numbers its debug output by detect() call
  for (const std::string& path : o.images) {
    try {
      // The size the header declares is checked before anything is decoded.
      const markerd::daemon::ImageSize size =
          path == "-"
              ? reader.open_bytes(read_standard_input(markerd::daemon::kMaxImageFileBytes, "the image", "detect"),
                                  standard_input_name)
              : reader.open(path);
      if (config.camera && (size.width != config.camera->width || size.height != config.camera->height)) {
        report(fmt::format("{}: the image is {}x{} but the camera model {} is {}x{}", path, size.width, size.height,
                           o.camera, config.camera->width, config.camera->height));
        continue;
      }
      if (grey.width() != size.width || grey.height() != size.height) {
        grey = markerd::detector::GreyImage(size.width, size.height);
      }
      reader.decode(grey.data(), size.width);
    } catch (const markerd::daemon::ImageFileError& e) {
      report(e.what());
      continue;
    }
    const markerd::detector::GreyView view = grey.view();
    double time_ms = 0;
    try {
      const auto start = std::chrono::steady_clock::now();
      detector->detect(view, detections);
      time_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    } catch (const markerd::detector::DetectorError& e) {
      report(fmt::format("{}: {}", path, e.what()));
      continue;
    }
    if (!o.debug_dir.empty()) {
      std::cerr << fmt::format("markerctl: {}: debug output {}/{:04}-*\n", path, o.debug_dir, debug_frame++);
    }
    for (const auto& d : detections) std::cout << json_line(detection_json(path, d, time_ms)) << '\n';
    if (o.verbose && detections.empty()) {
      nlohmann::ordered_json j;
      j["file"] = path;
      j["detections"] = 0;
      j["time_ms"] = rounded(time_ms, 3);
      std::cout << json_line(j) << '\n';
    }
    std::cout.flush();
  }
  if (failed > 0) {
    throw runtime_error("detect", fmt::format("{} of {} image{} could not be processed", failed, o.images.size(),
                                              o.images.size() == 1 ? "" : "s"));
  }
  return 0;
}

}  // namespace

void add_detect_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<DetectOptions>();
  CLI::App* app = parent.add_subcommand("detect", "Detect markers in image files; one JSON line per detection");
  app->footer(
      "Detect markers in image files and print one JSON object per detection per line:\n"
      "  {\"file\", \"family\", \"id\", \"corners\": [[x,y] x4], \"inner_corners\" (frame8), \"quarter_turns\",\n"
      "   \"orientation_ambiguous\" (frame8: the white corner hidden, quarter_turns one of two),\n"
      "   \"bits_corrected\", \"margin\", \"rvec\", \"tvec\", \"quaternion\" [w,x,y,z], \"reprojection_error_px\",\n"
      "   \"ambiguous\", \"time_ms\"}\n"
      "Corners are pixels (pixel centres at integers), TL TR BR BL of the outer printed square, to 1e-4 px.\n"
      "The pose fields (tvec in metres) appear only with both --camera and --size. time_ms is the\n"
      "detection time of that image. An image without detections prints nothing (with --verbose a\n"
      "{\"file\", \"detections\": 0, \"time_ms\"} line). Images (PNG, JPEG, PNM, BMP, TIFF) are read\n"
      "as 8-bit grey, colour converted as cv::imread(IMREAD_GRAYSCALE) converts it, as stored (EXIF\n"
      "orientation ignored), at most 64 megapixels (checked in the header before decoding).\n"
      "A file that cannot be read or does not decode whole (truncated, corrupt) is reported on stderr\n"
      "and skipped; the others are still processed and the exit status is then 1. The camera model\n"
      "must have the images' size.\n"
      "--debug DIR (frame8) writes, per image, DIR/NNNN-threshold.png (the light pixels segmentation\n"
      "saw), DIR/NNNN-candidates.png (every candidate quad: green read, red rejected, with its index)\n"
      "and DIR/NNNN-candidates.json (per candidate: corners, and the stage and reason that rejected it);\n"
      "stderr names each image's NNNN. For when a marker is not found; it slows detection down.");
  app->add_option("--family", o->family, "Marker family: " + family_names())->type_name("NAME")->capture_default_str();
  app->add_option("--camera", o->camera, "Camera calibration (OpenCV's YAML or ROS camera_info), for the pose")
      ->type_name("FILE");
  app->add_option("--size", o->size, "Marker size for the pose (0.08, 8cm; frame8: outer edge)")->type_name("LENGTH");
  app->add_option("--decimate", o->decimate, "frame8: segmentation decimation (0: from the image size)")
      ->capture_default_str()
      ->check(CLI::Range(0, 8));
  app->add_option("--threshold-offset", o->threshold_offset, "frame8: adaptive threshold offset, grey levels")
      ->capture_default_str()
      ->check(CLI::Range(0, 255));
  app->add_option("--min-margin", o->min_margin, "frame8: least decoding margin (0..1)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app->add_option(
         "--blur-sigma", o->blur_sigma_px,
         "frame8: the camera's blur, pixels (sigma), for reading small cells ([detector.frame8] blur_sigma_px)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, markerd::detector::Frame8Options::kMaxBlurSigmaPx));
  app->add_option("--mounting", o->mounting,
                  "frame8: what the print is mounted on (paper, socket, switch, cut_hole: [marker] mounting); "
                  "the detector then searches only for the holes it can show. Not given: every kind")
      ->type_name("NAME")
      ->check(CLI::IsMember({"paper", "socket", "switch", "cut_hole"}));
  app->add_flag("--uniform-ids", o->uniform_ids,
                "frame8: also report ids 0 and 255 (rings without structure, easily mimicked by clutter)");
  app->add_option("--debug", o->debug_dir,
                  "frame8: write the threshold image and the candidates, and why each was rejected, into DIR")
      ->type_name("DIR");
  app->add_flag("-v,--verbose", o->verbose, "Also print a line for each image without detections");
  app->add_flag("--json", o->json, "JSON lines (the output is JSON lines with or without it)");
  app->add_option("images", o->images,
                  "Image files (PNG, JPEG, PGM/PPM/PBM, BMP, TIFF); - reads one from standard input")
      ->type_name("IMAGE")
      ->required();
  commands.push_back({app, [o] { return run_detect(*o); }});
}

}  // namespace markerctl
