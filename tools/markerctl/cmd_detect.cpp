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

#include "common.hpp"
#include "markerd/daemon/capture/image_file.hpp"
#include "markerd/daemon/detection_record.hpp"
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

// When the image was made, as near as a file tells: its modification time;
// an image from standard input, the time it was read.
std::chrono::system_clock::time_point image_time(const std::string& path) {
  if (path == "-") return std::chrono::system_clock::now();
  std::error_code ec;
  const auto written = std::filesystem::last_write_time(path, ec);
  if (ec) return std::chrono::system_clock::now();
  return std::chrono::time_point_cast<std::chrono::system_clock::duration>(std::chrono::file_clock::to_sys(written));
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
  markerd::daemon::DetectionRecordFormatter formatter;
  for (std::size_t index = 0; index < o.images.size(); ++index) {
    const std::string& path = o.images[index];
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
    std::chrono::nanoseconds detection_time{0};
    try {
      const auto start = std::chrono::steady_clock::now();
      detector->detect(view, detections);
      detection_time = std::chrono::steady_clock::now() - start;
    } catch (const markerd::detector::DetectorError& e) {
      report(fmt::format("{}: {}", path, e.what()));
      continue;
    }
    if (!o.debug_dir.empty()) {
      std::cerr << fmt::format("markerctl: {}: debug output {}/{:04}-*\n", path, o.debug_dir, debug_frame++);
    }
    if (detections.empty() && !o.verbose) continue;
    // The detection log's record (docs/detection-log.md), so that one reader
    // takes both; an image has no rig, no truth and no monotonic capture time.
    markerd::daemon::FrameRecordInput record;
    record.sequence = index;
    record.capture_utc = image_time(path);
    record.source = path;
    record.width = view.width;
    record.height = view.height;
    record.detection_time = detection_time;
    record.detections = detections;
    std::cout << formatter.format(record) << std::flush;
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
  CLI::App* app = parent.add_subcommand("detect", "Detect markers in image files; one JSON line per image");
  app->footer(
      "Detect markers in image files and print, per image with detections, one line of JSON: the\n"
      "detection log's record (docs/detection-log.md), as markerd logs a frame:\n"
      "  {\"schema\", \"status\", \"cause\", \"frame\": {\"sequence\" (the image's place, from 0), \"source\" (its\n"
      "   path; - standard input), \"width\", \"height\", ...}, \"detection_time_ms\", \"rig\": null,\n"
      "   \"truth\": null, \"detections\": [{\"family\", \"id\", \"corners\", \"inner_corners\", \"quarter_turns\",\n"
      "   \"orientation_ambiguous\", \"bits_corrected\", \"margin\", \"pose\": {\"ambiguous\", \"best\": {\"rvec\",\n"
      "   \"quaternion\", \"tvec\", \"reprojection_error_px\", \"error\"}, \"alternative\"}}]}\n"
      "Corners are pixels (pixel centres at integers), TL TR BR BL of the outer printed square, to 1e-4 px.\n"
      "pose is null unless both --camera and --size are given. With --verbose an image without\n"
      "detections prints its record too (\"detections\": []). Images (PNG, JPEG, PNM, BMP, TIFF) are read\n"
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
      ->check(CLI::Range(markerd::detector::Frame8Options::kMinThresholdOffset,
                         markerd::detector::Frame8Options::kMaxThresholdOffset));
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
  app->add_flag("-v,--verbose", o->verbose, "Also print the record of each image without detections");
  app->add_flag("--json", o->json, "JSON lines (the output is JSON lines with or without it)");
  app->add_option("images", o->images,
                  "Image files (PNG, JPEG, PGM/PPM/PBM, BMP, TIFF); - reads one from standard input")
      ->type_name("IMAGE")
      ->required();
  commands.push_back({app, [o] { return run_detect(*o); }});
}

}  // namespace markerctl
