// Detection rate, corner error, distance error and time against distance and
// yaw, per family, on rendered scenes of the thesis camera. Prints Markdown:
// the figures of the closing note come from this program, so its output
// format is kept stable.
//
//   bench_accuracy --family all --frames 50 --dist 0.3:3.0:0.1
//                  --yaw-at 0.5,0.95 --yaw 0:85:5 [--camera calib.yaml]
//                  [--mount paper|cut-hole|socket|switch] [--tell-mounting]
//                  [--insert none|socket|rocker]
//                  [--background KIND|all|GREY] [--cover top|right|bottom|left|each]
//                  [--margin MM] [--false-positives N] [--blur-model gaussian|disc]
//                  [--noise-model gaussian|shot] [--jpeg Q] [--supersample N] [--no-distort]
//
// --background is the clutter's kind (shapes, the default, also called
// clutter; tiles, keyboard, checkerboard, windows, text, outlets: textures
// that look like markers), all of them in turn frame by frame, or a plain
// grey level. It applies to the marker scenes and the --false-positives
// frames alike; with all, the false positives are also counted per kind.

#include <unistd.h>

#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <numbers>
#include <opencv2/core/utility.hpp>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "markerd/base/proportion.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/evaluate.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/render.hpp"

namespace {

using markerd::detector::Family;

constexpr double kGoodRate = 0.9;

// "start:stop:step", stop included when the steps land on it (to within
// rounding, so 0.3:3.0:0.1 ends at 3.0).
std::vector<double> parse_range(const std::string& text, const char* what) {
  double start = 0, stop = 0, step = 0;
  char c1 = 0, c2 = 0;
  std::istringstream in(text);
  if (!(in >> start >> c1 >> stop >> c2 >> step) || c1 != ':' || c2 != ':' || !in.eof() || !(step > 0) ||
      stop < start) {
    throw CLI::ValidationError(what, "expected start:stop:step with step > 0 and stop >= start, got '" + text + "'");
  }
  const auto n = static_cast<int>(std::floor((stop - start) / step + 1e-6)) + 1;
  std::vector<double> values;
  for (int i = 0; i < n; ++i) values.push_back(std::round((start + i * step) * 1e9) / 1e9);
  return values;
}

std::vector<double> parse_list(const std::string& text, const char* what) {
  std::vector<double> values;
  std::istringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    try {
      std::size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw CLI::ValidationError(what, "expected comma-separated numbers, got '" + text + "'");
    }
  }
  if (values.empty()) throw CLI::ValidationError(what, "expected at least one number");
  return values;
}

// Frames of the background alone and what was found in them.
struct BackgroundTally {
  int frames = 0;
  int frames_with_detections = 0;
  int detections = 0;
};

struct Sweeps {
  std::vector<markerd::detector::EvalResult> by_distance;
  std::vector<std::vector<markerd::detector::EvalResult>> by_yaw;  // one per --yaw-at distance
  // Frames of the background alone, per kind in the order of all_backgrounds().
  std::vector<BackgroundTally> by_background;

  [[nodiscard]] BackgroundTally background_total() const {
    BackgroundTally total;
    for (const BackgroundTally& t : by_background) {
      total.frames += t.frames;
      total.frames_with_detections += t.frames_with_detections;
      total.detections += t.detections;
    }
    return total;
  }
};

// The farthest value reached by an unbroken run of points at >= 90% from the
// first, as text: "-" when the first point already falls short, and marked
// ">=" when the run lasts to the end of the sweep (the sweep, not the
// detector, set the limit).
std::string reach(const std::vector<markerd::detector::EvalResult>& points, bool by_yaw) {
  std::optional<double> last;
  std::size_t good = 0;
  for (const auto& r : points) {
    if (r.rate() < kGoodRate) break;
    last = by_yaw ? r.point.yaw_deg : r.point.distance_m;
    ++good;
  }
  if (!last) return "-";
  const std::string value = by_yaw ? fmt::format("{:.0f} deg", *last) : fmt::format("{:.2f} m", *last);
  return good == points.size() ? ">= " + value : value;
}

double median_of(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

std::string percent(double rate) { return fmt::format("{:.1f}%", 100 * rate); }

// The rate's 95% interval (Wilson), in percent.
std::string interval(int successes, int trials) {
  const markerd::base::ProportionInterval i = markerd::base::wilson_interval(successes, trials);
  return fmt::format("{:.1f}-{:.1f}", 100 * i.low, 100 * i.high);
}
std::string or_dash(bool present, const std::string& s) { return present ? s : "-"; }

void print_family(const markerd::detector::FamilyInfo& info, const Sweeps& s, const std::vector<double>& yaw_at) {
  fmt::print("## {}\n\n", info.name);
  fmt::print("### Against distance (yaw 0 deg)\n\n");
  fmt::print(
      "| distance (m) | rate | 95% interval | wrong ids | corner error (px) | distance error (%) | distance bias (%) "
      "| time (ms) |\n");
  fmt::print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n");
  for (const auto& r : s.by_distance) {
    const bool any = r.detected > 0;
    fmt::print("| {:.2f} | {} | {} | {} | {} | {} | {} | {:.3f} |\n", r.point.distance_m, percent(r.rate()),
               interval(r.detected, r.frames), r.wrong_id,
               or_dash(any, fmt::format("{:.3f}", r.median_corner_error_px)),
               or_dash(any, fmt::format("{:.2f}", 100 * r.median_distance_error_rel)),
               or_dash(any, fmt::format("{:+.2f}", 100 * r.median_distance_bias_rel)), r.median_time_ms);
  }
  if (s.by_yaw.empty()) {
    fmt::print("\n");
    return;
  }
  fmt::print("\n### Against yaw (rate)\n\n| yaw (deg) |");
  for (double d : yaw_at) fmt::print(" at {:.2f} m |", d);
  fmt::print("\n| ---: |");
  for (std::size_t i = 0; i < yaw_at.size(); ++i) fmt::print(" ---: |");
  fmt::print("\n");
  int wrong = 0;
  for (std::size_t row = 0; row < s.by_yaw.front().size(); ++row) {
    fmt::print("| {:.0f} |", s.by_yaw.front()[row].point.yaw_deg);
    for (const auto& sweep : s.by_yaw) {
      fmt::print(" {} |", percent(sweep[row].rate()));
      wrong += sweep[row].wrong_id;
    }
    fmt::print("\n");
  }
  // A wrong id anywhere matters more than a rate: the yaw points' too.
  fmt::print("\nWrong ids in the yaw sweeps: {}\n", wrong);
  const int n = s.by_yaw.front().front().frames;
  fmt::print("\nAt {} frames a point, 100% is {}% and 90% is {}% at 95% confidence (Wilson).\n\n", n, interval(n, n),
             interval((9 * n + 5) / 10, n));
}

std::string summary_row(const markerd::detector::FamilyInfo& info, const Sweeps& s) {
  std::string row = fmt::format("| {} |", info.name);
  row += fmt::format(" {} |", reach(s.by_distance, false));
  for (const auto& sweep : s.by_yaw) row += fmt::format(" {} |", reach(sweep, true));
  std::vector<double> corner, dist, time;
  for (const auto& r : s.by_distance) {
    time.push_back(r.median_time_ms);
    if (r.detected == 0) continue;
    corner.push_back(r.median_corner_error_px);
    dist.push_back(r.median_distance_error_rel);
  }
  const auto num = [](double v, const char* f) {
    return std::isnan(v) ? std::string("-") : fmt::format(fmt::runtime(f), v);
  };
  row += fmt::format(" {} | {} | {} |", num(median_of(corner), "{:.3f}"), num(100 * median_of(dist), "{:.2f}"),
                     num(median_of(time), "{:.3f}"));
  return row;
}

// A binary PGM: readable by markerctl detect and any image viewer.
// The frame, with the marker's true outer corners (TL, TR, BR, BL, pixels)
// in a comment where it shows one: what a look at a missed or misread frame
// compares with.
void write_pgm(const std::string& path, const markerd::detector::GreyImage& image,
               const std::optional<markerd::detector::Quad>& truth = std::nullopt) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) {
    std::fprintf(stderr, "bench_accuracy: cannot write %s\n", path.c_str());
    return;
  }
  std::fprintf(f, "P5\n");
  if (truth) {
    const markerd::detector::Quad& q = *truth;
    std::fprintf(f, "# truth corners %.3f %.3f %.3f %.3f %.3f %.3f %.3f %.3f\n", q[0].x, q[0].y, q[1].x, q[1].y, q[2].x,
                 q[2].y, q[3].x, q[3].y);
  }
  std::fprintf(f, "%d %d\n255\n", image.width(), image.height());
  const auto view = image.view();
  for (int y = 0; y < view.height; ++y) std::fwrite(view.row(y), 1, static_cast<std::size_t>(view.width), f);
  std::fclose(f);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Detection rate and accuracy on rendered scenes, as Markdown tables"};
  std::string family_name = "all";
  int frames = 50;
  std::string dist_text = "0.3:3.0:0.1";
  std::string yaw_at_text = "0.5,0.95";
  std::string yaw_text = "0:85:5";
  std::string camera_path;
  double size_m = 0.08;
  double noise = 2;
  double blur = 0.6;
  std::uint64_t seed = 1;
  app.add_option("--family", family_name, "frame8, aruco4x4_50, tag36h11 or all")
      ->check(CLI::IsMember({"frame8", "aruco4x4_50", "tag36h11", "all"}))
      ->capture_default_str();
  app.add_option("--frames", frames, "frames per point")->check(CLI::Range(1, 100000))->capture_default_str();
  app.add_option("--dist", dist_text, "distance sweep, metres, start:stop:step")->capture_default_str();
  app.add_option("--yaw-at", yaw_at_text, "distances (m) of the yaw sweeps, comma-separated")->capture_default_str();
  app.add_option("--yaw", yaw_text, "yaw sweep, degrees, start:stop:step")->capture_default_str();
  app.add_option("--camera", camera_path, "OpenCV calibration file (default: the thesis camera)")
      ->check(CLI::ExistingFile);
  app.add_option("--size", size_m, "marker size, metres (the family's size)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--noise", noise, "sensor noise sigma, grey levels")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--blur", blur, "blur sigma, pixels")->check(CLI::NonNegativeNumber)->capture_default_str();
  std::string blur_model = "gaussian";
  app.add_option("--blur-model", blur_model, "gaussian, or disc (a lens out of focus: a disc of radius 2 sigma)")
      ->check(CLI::IsMember({"gaussian", "disc"}))
      ->capture_default_str();
  std::string noise_model = "gaussian";
  app.add_option("--noise-model", noise_model,
                 "gaussian (the same sigma at every grey), or shot (shot noise on read noise, sigma at mid-grey)")
      ->check(CLI::IsMember({"gaussian", "shot"}))
      ->capture_default_str();
  int jpeg_quality = 0;
  app.add_option("--jpeg", jpeg_quality, "pass each frame through JPEG at this quality, 1..100 (0: not)")
      ->check(CLI::Range(0, 100))
      ->capture_default_str();
  int supersample = 4;
  app.add_option("--supersample", supersample, "the renderer's samples per pixel along each axis")
      ->check(CLI::Range(1, 16))
      ->capture_default_str();
  bool no_distort = false;
  app.add_flag("--no-distort", no_distort, "a lens without distortion: the camera's distortion set to zero");
  app.add_option("--seed", seed, "seed of the jitter, ids and backgrounds")->capture_default_str();
  double roll_jitter = 5;
  app.add_option("--roll", roll_jitter,
                 "the marker turned in the image plane by up to this many degrees either way, at random (45: every "
                 "in-plane turn)")
      ->check(CLI::Range(0.0, 180.0))
      ->capture_default_str();
  int fixed_id = -1;
  app.add_option("--id", fixed_id,
                 "every frame shows this id (one family only) instead of random ones: to measure one id class, "
                 "such as the near-uniform rings (1, 126, 127, 128, 129, 254)")
      ->check(CLI::NonNegativeNumber);
  bool sampled_only = false;
  bool cut_hole = false;
  app.add_flag("--cut-hole", cut_hole,
               "frame8: the hole cut out, the background showing through it (--mount cut-hole)");
  std::string mount = "paper";
  app.add_option("--mount", mount,
                 "what the print is: paper (flat, hole printed white), cut-hole (flat, hole cut out), socket or "
                 "switch (glued on a rounded cover frame, the outlet or rocker in the opening)")
      ->check(CLI::IsMember({"paper", "cut-hole", "socket", "switch"}))
      ->capture_default_str();
  bool tell_mounting = false;
  app.add_flag("--tell-mounting", tell_mounting,
               "frame8: tell the detector the mount, as markerd does when [marker] mounting says it (it then "
               "searches for that mounting's holes alone); without it the detector is not told, as a new user runs "
               "markerctl detect");
  std::string insert_name;
  app.add_option("--insert", insert_name,
                 "what the opening shows: none (the background), socket, rocker (default: the mount's)")
      ->check(CLI::IsMember({"none", "socket", "rocker"}));
  std::string background = "shapes";
  app.add_option("--background", background,
                 "the clutter: shapes (random shapes; also: clutter), or a texture that looks like markers: tiles, "
                 "keyboard, checkerboard, windows, text, outlets; all (each in turn, frame by frame); or a plain "
                 "grey level 0..255")
      ->capture_default_str();
  double margin_mm = 0;
  app.add_option("--margin", margin_mm,
                 "white paper around the marker, mm (the print as markerctl marker makes it: 10; 0 for the bare "
                 "marker on the background)")
      ->check(CLI::Range(0.0, 1000.0))
      ->capture_default_str();
  std::string cover;
  app.add_option("--cover", cover,
                 "an object over one side: top, right, bottom, left, or each (in turn, frame by frame)")
      ->check(CLI::IsMember({"top", "right", "bottom", "left", "each"}));
  double cover_depth = 0.2;
  app.add_option("--cover-depth", cover_depth, "how far the object reaches in from the outer edge, in marker sizes")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  double cover_grey = 0.1;
  app.add_option("--cover-reflectance", cover_grey, "the object's reflectance, 0 (black) .. 1 (paper is 0.88)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  std::string dump_wrong;
  app.add_option("--dump-wrong", dump_wrong,
                 "write each frame with a wrong id into this directory, as PGM named by distance, yaw, ids and seed")
      ->check(CLI::ExistingDirectory);
  int false_positive_frames = 0;
  app.add_option("--false-positives", false_positive_frames,
                 "also detect in this many frames of the background alone (no marker), and count what is found")
      ->check(CLI::Range(0, 10000000))
      ->capture_default_str();
  std::string dump_missed;
  app.add_option("--dump-missed", dump_missed,
                 "write each frame whose marker was not found into this directory, as PGM named as for --dump-wrong "
                 "(with the marker's true corners in a comment)")
      ->check(CLI::ExistingDirectory);
  app.add_flag("--no-model-small-cells", sampled_only,
               "frame8: read cells under 3 px by sampling alone, never by fitting the blurred ring "
               "(Frame8Options::model_small_cells off)");

  std::vector<double> distances, yaw_at, yaws;
  try {
    app.parse(argc, argv);
    distances = parse_range(dist_text, "--dist");
    yaw_at = parse_list(yaw_at_text, "--yaw-at");
    yaws = parse_range(yaw_text, "--yaw");
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }

  // Times are of one thread, as the daemon runs a detector per worker.
  cv::setNumThreads(1);

  markerd::detector::CameraModel camera = markerd::detector::CameraModel::thesis_640x480();
  if (!camera_path.empty()) {
    try {
      camera = markerd::detector::CameraModel::load(camera_path);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_accuracy: %s\n", e.what());
      return 2;
    }
  }
  if (no_distort) camera.dist = {};

  std::vector<markerd::detector::FamilyInfo> families;
  for (const auto& info : markerd::detector::all_families()) {
    if (family_name == "all" || info.name == family_name) families.push_back(info);
  }

  if (fixed_id >= 0) {
    if (families.size() != 1) {
      fmt::print(stderr, "bench_accuracy: --id needs one --family\n");
      return 2;
    }
    if (fixed_id >= families.front().id_count) {
      fmt::print(stderr, "bench_accuracy: --id {}: {} has ids 0 to {}\n", fixed_id, families.front().name,
                 families.front().id_count - 1);
      return 2;
    }
  }

  markerd::detector::EvalSettings settings;
  settings.frames_per_point = frames;
  settings.random_ids = fixed_id < 0;
  if (fixed_id >= 0) settings.scene.id = fixed_id;
  settings.seed = seed;
  settings.roll_jitter_deg = roll_jitter;
  settings.scene.marker_size_m = size_m;
  settings.scene.noise_sigma = noise;
  settings.scene.blur_sigma_px = blur;
  settings.scene.blur_model =
      blur_model == "disc" ? markerd::detector::BlurModel::disc : markerd::detector::BlurModel::gaussian;
  settings.scene.noise_model =
      noise_model == "shot" ? markerd::detector::NoiseModel::shot : markerd::detector::NoiseModel::gaussian;
  settings.scene.jpeg_quality = jpeg_quality;
  settings.scene.supersample = supersample;
  settings.scene.clutter = true;
  if (cut_hole) mount = "cut-hole";
  using markerd::detector::Insert;
  if (mount == "cut-hole") {
    settings.scene.cut_hole = true;
  } else if (mount == "socket") {
    settings.scene.frame = markerd::detector::socket_frame();
    settings.scene.insert = Insert::socket;
  } else if (mount == "switch") {
    settings.scene.frame = markerd::detector::switch_frame();
    settings.scene.insert = Insert::rocker;
  }
  settings.scene.paper_margin_m = margin_mm / 1000;
  if (!insert_name.empty()) {
    settings.scene.insert = insert_name == "socket"   ? Insert::socket
                            : insert_name == "rocker" ? Insert::rocker
                                                      : Insert::none;
  }
  using markerd::detector::Background;
  const std::span<const Background> kinds = markerd::detector::all_backgrounds();
  const bool every_kind = background == "all";
  if (every_kind) {
    settings.background_turns.assign(kinds.begin(), kinds.end());
  } else if (const auto kind =
                 markerd::detector::background_from_string(background == "clutter" ? "shapes" : background)) {
    settings.scene.background = *kind;
  } else {
    try {
      std::size_t used = 0;
      settings.scene.background_grey = std::stod(background, &used);
      if (used != background.size() ||
          !(settings.scene.background_grey >= 0 && settings.scene.background_grey <= 255)) {
        throw std::invalid_argument(background);
      }
    } catch (const std::exception&) {
      std::fprintf(stderr,
                   "bench_accuracy: --background: expected shapes, tiles, keyboard, checkerboard, windows, text, "
                   "outlets, all or a grey level 0..255, got '%s'\n",
                   background.c_str());
      return 2;
    }
    settings.scene.clutter = false;
  }
  if (!cover.empty()) {
    using markerd::detector::MarkerSide;
    static constexpr std::array<std::pair<const char*, MarkerSide>, 4> kSides{{{"top", MarkerSide::top},
                                                                               {"right", MarkerSide::right},
                                                                               {"bottom", MarkerSide::bottom},
                                                                               {"left", MarkerSide::left}}};
    for (const auto& [name, side] : kSides) {
      if (cover == "each" || cover == name) {
        settings.occluder_turns.push_back(
            {markerd::detector::side_occluder(side, size_m, cover_depth, static_cast<float>(cover_grey))});
      }
    }
  }

  fmt::print("# Detection on rendered scenes\n\n");
  fmt::print("- camera: {}x{}, fx {:.1f}, fy {:.1f}, cx {:.1f}, cy {:.1f}, k1 k2 p1 p2 k3 {} {} {} {} {}{}\n",
             camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, camera.dist[0], camera.dist[1],
             camera.dist[2], camera.dist[3], camera.dist[4], camera_path.empty() ? " (the thesis camera)" : "");
  fmt::print("- marker: {:.1f} cm (frame8: the outer edge; aruco4x4_50, tag36h11: the outer black border)\n",
             100 * size_m);
  // The shapes are "clutter", as this line always said.
  std::string ground = "plain grey " + background;
  if (every_kind) {
    ground = "clutter of each kind in turn (";
    for (const Background kind : kinds) {
      ground += fmt::format("{}{}", kind == kinds.front() ? "" : ", ", markerd::detector::to_string(kind));
    }
    ground += ")";
  } else if (settings.scene.clutter) {
    ground = settings.scene.background == Background::shapes
                 ? std::string("clutter")
                 : fmt::format("clutter: {}", markerd::detector::to_string(settings.scene.background));
  }
  fmt::print("- imaging: {} noise sigma {:.1f}, {} blur sigma {:.2f} px{}, {}, {}, supersampling {}\n", noise_model,
             noise, blur_model, blur, jpeg_quality > 0 ? fmt::format(", JPEG quality {}", jpeg_quality) : "", ground,
             no_distort ? "no lens distortion" : "lens distortion", settings.scene.supersample);
  fmt::print("- mount: {}{}{}\n", mount,
             settings.scene.insert == markerd::detector::Insert::socket   ? ", a socket outlet in the opening"
             : settings.scene.insert == markerd::detector::Insert::rocker ? ", a switch's rocker in the opening"
                                                                          : "",
             margin_mm > 0 ? fmt::format(", {:g} mm of white paper around the marker", margin_mm) : std::string());
  if (!cover.empty()) {
    fmt::print("- covered: {} side{}, {:.2f} of the size in from the outer edge, reflectance {:.2f}, 3 cm in front\n",
               cover, cover == "each" ? " in turn" : "", cover_depth, cover_grey);
  }
  if (tell_mounting) fmt::print("- frame8 is told the mount\n");
  if (sampled_only) fmt::print("- frame8 reads cells under 3 px by sampling alone, not with the ring model\n");
  fmt::print(
      "- {} frames per point, marker centre within {:.0f} px of the principal point, roll within +-{:.0f} deg, "
      "{}, seed {}\n",
      frames, settings.position_jitter_px, settings.roll_jitter_deg,
      fixed_id < 0 ? std::string("random ids") : fmt::format("id {}", fixed_id), seed);
  fmt::print(
      "- rate: frames with the right id found; wrong ids: detections with another id, summed; errors and "
      "time: medians (errors over detected frames, time of detect() alone over all frames)\n\n");
  std::fflush(stdout);

  // A dumped frame's distance and turn, for its name: "0.95m-45deg" (the
  // angle between the marker's normal and the optical axis).
  const auto where = [](const markerd::detector::Scene& scene) {
    const double turn = std::acos(std::clamp(std::abs(scene.pose.rotation(2, 2)), 0.0, 1.0)) * 180 / std::numbers::pi;
    return fmt::format("{:.2f}m-{:.0f}deg", scene.pose.translation.norm(), turn);
  };
  const bool progress = isatty(STDERR_FILENO) != 0;
  std::vector<std::string> summary;
  for (const auto& info : families) {
    settings.scene.family = info.family;
    Sweeps s;
    try {
      markerd::detector::DetectorConfig config;
      config.family = info.family;
      config.camera = camera;
      config.marker_size_m = size_m;
      config.frame8.model_small_cells = !sampled_only;
      config.frame8.blur_sigma_px = blur;
      if (tell_mounting) {
        using markerd::detector::Mounting;
        config.frame8.mounting = mount == "paper"      ? Mounting::paper
                                 : mount == "cut-hole" ? Mounting::cut_hole
                                                       : Mounting::cover_frame;
      }
      auto detector = markerd::detector::make_detector(config);
      if (!dump_wrong.empty()) {
        settings.on_wrong_id = [&](const markerd::detector::GreyImage& image, const markerd::detector::Scene& scene,
                                   const std::vector<markerd::detector::Detection>& found) {
          int wrong = -1;
          for (const auto& d : found) wrong = d.id != scene.id ? d.id : wrong;
          const std::string path = fmt::format("{}/{}-{}-id{}-read{}-seed{}.pgm", dump_wrong, info.name, where(scene),
                                               scene.id, wrong, scene.seed);
          write_pgm(path, image, markerd::detector::project_marker_corners(camera, scene));
          std::fprintf(stderr, "bench_accuracy: wrong id, frame written to %s\n", path.c_str());
        };
      }
      if (!dump_missed.empty()) {
        settings.on_miss = [&](const markerd::detector::GreyImage& image, const markerd::detector::Scene& scene) {
          const std::string path = fmt::format("{}/{}-{}-id{}-missed-seed{}.pgm", dump_missed, info.name, where(scene),
                                               scene.id, scene.seed);
          write_pgm(path, image, markerd::detector::project_marker_corners(camera, scene));
        };
      }
      const auto run = [&](double d, double yaw) {
        if (progress) std::fprintf(stderr, "\r%s: %.2f m, %.0f deg   ", std::string(info.name).c_str(), d, yaw);
        return markerd::detector::evaluate_point(*detector, camera, settings, {d, yaw});
      };
      for (double d : distances) s.by_distance.push_back(run(d, 0));
      for (double d : yaw_at) {
        auto& sweep = s.by_yaw.emplace_back();
        for (double yaw : yaws) sweep.push_back(run(d, yaw));
      }
      s.by_background.assign(kinds.size(), {});
      for (int k = 0; k < false_positive_frames; ++k) {
        if (progress && k % 100 == 0) {
          std::fprintf(stderr, "\r%s: background %d of %d   ", std::string(info.name).c_str(), k,
                       false_positive_frames);
        }
        markerd::detector::Scene scene = settings.scene;
        scene.seed = seed * 1000003ULL + static_cast<std::uint64_t>(k);
        if (!settings.background_turns.empty()) {
          scene.background = settings.background_turns[static_cast<std::size_t>(k) % settings.background_turns.size()];
        }
        const markerd::detector::GreyImage image = markerd::detector::render_background(camera, scene);
        std::vector<markerd::detector::Detection> found;
        detector->detect(image.view(), found);
        const auto kind_index = std::find(kinds.begin(), kinds.end(), scene.background) - kinds.begin();
        BackgroundTally& tally = s.by_background[static_cast<std::size_t>(kind_index)];
        ++tally.frames;
        tally.detections += static_cast<int>(found.size());
        tally.frames_with_detections += found.empty() ? 0 : 1;
        if (!found.empty() && !dump_wrong.empty()) {
          const std::string path =
              fmt::format("{}/{}-background-{}-read{}-seed{}.pgm", dump_wrong, info.name,
                          markerd::detector::to_string(scene.background), found.front().id, scene.seed);
          write_pgm(path, image);
          std::fprintf(stderr, "bench_accuracy: false detection, frame written to %s\n", path.c_str());
        }
      }
      if (progress) std::fprintf(stderr, "\r%60s\r", "");
    } catch (const std::exception& e) {
      if (progress) std::fprintf(stderr, "\n");
      fmt::print("## {}\n\nnot measured: {}\n\n", info.name, e.what());
      std::fflush(stdout);
      continue;
    }
    print_family(info, s, yaw_at);
    if (false_positive_frames > 0) {
      const BackgroundTally total = s.background_total();
      const markerd::base::ProportionInterval i =
          markerd::base::wilson_interval(total.frames_with_detections, total.frames);
      fmt::print(
          "### The background alone\n\n{} detections in {} of {} frames without a marker: {:.2f} per 10,000 "
          "frames (95% interval {:.2f}-{:.2f})\n\n",
          total.detections, total.frames_with_detections, total.frames,
          1e4 * total.frames_with_detections / total.frames, 1e4 * i.low, 1e4 * i.high);
      if (every_kind) {
        fmt::print("| background | frames | frames with a detection | detections |\n| --- | ---: | ---: | ---: |\n");
        for (std::size_t k = 0; k < kinds.size(); ++k) {
          const BackgroundTally& t = s.by_background[k];
          fmt::print("| {} | {} | {} | {} |\n", markerd::detector::to_string(kinds[k]), t.frames,
                     t.frames_with_detections, t.detections);
        }
        fmt::print("\n");
      }
    }
    summary.push_back(summary_row(info, s));
    std::fflush(stdout);
  }

  fmt::print("## Summary\n\n| family | max distance, rate >= 90% |");
  for (double d : yaw_at) fmt::print(" max yaw at {:.2f} m |", d);
  fmt::print(" corner error (px) | distance error (%) | time (ms) |\n| --- | ---: |");
  for (std::size_t i = 0; i < yaw_at.size(); ++i) fmt::print(" ---: |");
  fmt::print(" ---: | ---: | ---: |\n");
  for (const auto& row : summary) fmt::print("{}\n", row);
  fmt::print(
      "\nMax distance and max yaw: the farthest point of an unbroken run of points at >= 90% from the nearest "
      "(from yaw 0); \">=\" when that run lasts to the end of the sweep. Errors and time: the median of "
      "the per-distance medians (points with detections for the errors).\n");
  return 0;
}
