// markerctl evaluate: the detectors on rendered scenes, over a distance sweep
// and yaw sweeps, as readable tables (or JSON lines). The end-to-end
// demonstration of the library until the daemon exists.

#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>

#include "common.hpp"
#include "markerd/detector/evaluate.hpp"

namespace markerctl {
namespace {

struct EvaluateOptions {
  std::string family = "all";
  std::string dist = "0.3:3.0:0.3";
  std::string yaw = "0:80:10";
  std::string yaw_at = "0.5,0.95";
  int frames = 20;
  double noise = 2;
  double blur = 0.6;
  int supersample = 4;
  std::string camera;
  std::string size = "0.08";
  std::uint64_t seed = 1;
  bool json = false;
  bool quiet = false;
};

constexpr double good_rate = 0.9;

struct Sweep {
  std::string title;
  bool over_yaw = false;
  double at_distance = 0;  // yaw sweeps only
  std::vector<markerd::detector::EvalPoint> points;
  std::vector<markerd::detector::EvalResult> results;
};

std::string cell(const markerd::detector::EvalResult& r, double value, int decimals) {
  if (r.detected == 0) return "-";
  return fmt::format("{:.{}f}", value, decimals);
}

void print_table(const std::string& family, const Sweep& sweep) {
  std::cout << fmt::format("{}: {}\n", family, sweep.title);
  std::cout << fmt::format("  {:>8} {:>7} {:>6} {:>10} {:>11} {:>8}\n", sweep.over_yaw ? "yaw deg" : "dist m", "rate %",
                           "wrong", "corner px", "dist err %", "time ms");
  for (const auto& r : sweep.results) {
    const double x = sweep.over_yaw ? r.point.yaw_deg : r.point.distance_m;
    std::cout << fmt::format("  {:>8} {:>7.1f} {:>6} {:>10} {:>11} {:>8.2f}\n",
                             fmt::format("{:.{}f}", x, sweep.over_yaw ? 0 : 2), 100 * r.rate(), r.wrong_id,
                             cell(r, r.median_corner_error_px, 3), cell(r, 100 * r.median_distance_error_rel, 2),
                             r.median_time_ms);
  }
  std::cout << '\n';
}

std::string summary(const std::string& family, const std::vector<Sweep>& sweeps) {
  std::string out = family + ":";
  for (const auto& sweep : sweeps) {
    std::optional<double> best;
    for (const auto& r : sweep.results) {
      const double x = sweep.over_yaw ? r.point.yaw_deg : r.point.distance_m;
      if (r.rate() >= good_rate && (!best || x > *best)) best = x;
    }
    if (!sweep.over_yaw) {
      out += best ? fmt::format(" max distance {:.2f} m", *best) : std::string(" max distance none");
    } else {
      out += best ? fmt::format("; max yaw {:.0f} deg at {:.2f} m", *best, sweep.at_distance)
                  : fmt::format("; max yaw none at {:.2f} m", sweep.at_distance);
    }
  }
  return out + fmt::format(" (detection rate >= {:.0f}%)", 100 * good_rate);
}

nlohmann::ordered_json result_json(const std::string& family, const markerd::detector::EvalResult& r) {
  nlohmann::ordered_json j;
  j["family"] = family;
  j["distance_m"] = rounded(r.point.distance_m, 6);
  j["yaw_deg"] = rounded(r.point.yaw_deg, 6);
  j["frames"] = r.frames;
  j["detected"] = r.detected;
  j["wrong_id"] = r.wrong_id;
  j["rate"] = rounded(r.rate(), 6);
  j["median_corner_error_px"] = rounded(r.median_corner_error_px, 6);
  j["median_distance_error_rel"] = rounded(r.median_distance_error_rel, 6);
  j["median_time_ms"] = rounded(r.median_time_ms, 4);
  return j;
}

int run_evaluate(const EvaluateOptions& o) {
  std::vector<markerd::detector::Family> families;
  if (o.family == "all") {
    for (const auto& info : markerd::detector::all_families()) families.push_back(info.family);
  } else {
    families.push_back(parse_family(o.family));
  }
  const auto length = [](std::string_view option) {
    return [option](std::string_view s) { return parse_length_m(s, BareUnit::metre, option); };
  };
  const std::vector<double> distances = parse_values(o.dist, "--dist", length("--dist"));
  std::vector<double> yaw_distances;
  if (o.yaw_at != "none") yaw_distances = parse_values(o.yaw_at, "--yaw-at", length("--yaw-at"));
  const std::vector<double> yaws =
      parse_values(o.yaw, "--yaw", [](std::string_view s) { return parse_angle_deg(s, "--yaw"); });
  for (double d : distances) {
    if (!(d > 0)) throw usage_error("--dist", fmt::format("distances must be more than zero ({:g})", d));
  }
  for (double d : yaw_distances) {
    if (!(d > 0)) throw usage_error("--yaw-at", fmt::format("distances must be more than zero ({:g})", d));
  }
  const double size = parse_length_m(o.size, BareUnit::metre, "--size");
  if (!(size > 0)) throw usage_error("--size", fmt::format("'{}' must be more than zero", o.size));
  const markerd::detector::CameraModel camera = load_camera(o.camera);

  std::vector<Sweep> plan;
  {
    Sweep s;
    s.title = fmt::format("distance sweep at yaw 0 deg");
    for (double d : distances) s.points.push_back({d, 0});
    plan.push_back(std::move(s));
  }
  for (double d : yaw_distances) {
    Sweep s;
    s.title = fmt::format("yaw sweep at {:.2f} m", d);
    s.over_yaw = true;
    s.at_distance = d;
    for (double y : yaws) s.points.push_back({d, y});
    plan.push_back(std::move(s));
  }
  std::size_t points_per_family = 0;
  for (const auto& s : plan) points_per_family += s.points.size();

  if (!o.json) {
    std::cout << fmt::format(
        "markerctl evaluate: {} frames per point, marker {:g} m, noise {:g}, blur {:g} px, supersample {}, "
        "camera {}\n"
        "rate: frames with the right id found once; wrong: detections of another id; corner px and dist err %:\n"
        "medians over the detected frames; time: median detection time per frame.\n\n",
        o.frames, size, o.noise, o.blur, o.supersample, o.camera.empty() ? "thesis 640x480" : o.camera);
  }

  const bool tty = isatty(fileno(stderr)) != 0;
  std::vector<std::string> summaries;
  for (const markerd::detector::Family family : families) {
    const std::string name(markerd::detector::family_info(family).name);
    markerd::detector::DetectorConfig config;
    config.family = family;
    config.camera = camera;
    config.marker_size_m = size;
    const auto detector = markerd::detector::make_detector(config);

    markerd::detector::EvalSettings settings;
    settings.scene.family = family;
    settings.scene.id = family == markerd::detector::Family::frame8 ? 165 : 0;
    settings.scene.marker_size_m = size;
    settings.scene.noise_sigma = o.noise;
    settings.scene.blur_sigma_px = o.blur;
    settings.scene.supersample = o.supersample;
    settings.frames_per_point = o.frames;
    settings.seed = o.seed;

    const auto start = std::chrono::steady_clock::now();
    std::vector<Sweep> sweeps = plan;
    std::size_t done = 0;
    for (auto& sweep : sweeps) {
      for (const auto& point : sweep.points) {
        if (!o.quiet) {
          std::cerr << fmt::format("{}evaluating {}: {:.2f} m, yaw {:.0f} deg ({}/{}){}", tty ? "\r\033[K" : "", name,
                                   point.distance_m, point.yaw_deg, ++done, points_per_family, tty ? "" : "\n");
          std::cerr.flush();
        }
        sweep.results.push_back(markerd::detector::evaluate_point(*detector, camera, settings, point));
        if (o.json) {
          std::cout << json_line(result_json(name, sweep.results.back())) << '\n';
          std::cout.flush();
        }
      }
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (!o.quiet) {
      std::cerr << fmt::format("{}evaluated {}: {} points in {:.1f} s\n", tty ? "\r\033[K" : "", name,
                               points_per_family, seconds);
    }
    if (!o.json) {
      for (const auto& sweep : sweeps) print_table(name, sweep);
      std::cout.flush();
    }
    summaries.push_back(summary(name, sweeps));
  }
  if (!o.json) {
    std::cout << "Summary\n";
    for (const auto& s : summaries) std::cout << "  " << s << '\n';
  }
  return 0;
}

}  // namespace

void add_evaluate_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<EvaluateOptions>();
  CLI::App* app = parent.add_subcommand("evaluate", "Evaluate the detectors on rendered scenes (tables)");
  app->footer(
      std::string("Evaluate the detectors on rendered scenes. For each point of a distance sweep (marker facing\n"
                  "the camera) and of a yaw sweep at each --yaw-at distance, render --frames views (the marker\n"
                  "jittered in position, roll and id; noise, blur and background clutter), detect them and compare\n"
                  "with the truth. Prints per family a table per sweep: distance or yaw, detection rate %, wrong\n"
                  "ids, median corner error px, median distance error %, median detection time ms; then a summary\n"
                  "line per family: the largest distance, and the largest yaw at each --yaw-at distance, with a\n"
                  "detection rate of at least 90%. Progress goes to stderr, the tables to stdout; --json prints one\n"
                  "JSON object per point instead. Ranges: first:last:step or a comma list.\n"
                  "Without --camera, the thesis camera is used:\n  ") +
      thesis_camera_text + ".");
  app->add_option("--family", o->family, "Family to evaluate: " + family_names() + " or all")
      ->type_name("NAME")
      ->capture_default_str();
  app->add_option("--dist", o->dist, "Distances of the distance sweep, metres")
      ->type_name("RANGE")
      ->capture_default_str();
  app->add_option("--yaw", o->yaw, "Yaw angles of the yaw sweeps, degrees")->type_name("RANGE")->capture_default_str();
  app->add_option("--yaw-at", o->yaw_at, "Distances of the yaw sweeps, metres ('none': no yaw sweep)")
      ->type_name("LIST")
      ->capture_default_str();
  app->add_option("--frames", o->frames, "Rendered frames per point")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app->add_option("--noise", o->noise, "Gaussian noise, grey levels (sigma)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 255.0));
  app->add_option("--blur", o->blur, "Gaussian blur, pixels (sigma)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app->add_option("--supersample", o->supersample, "Render samples per pixel along each axis")
      ->capture_default_str()
      ->check(CLI::Range(1, 16));
  app->add_option("--camera", o->camera,
                  "Camera calibration (OpenCV's YAML or ROS camera_info); default: the thesis camera")
      ->type_name("FILE");
  app->add_option("--size", o->size, "Marker size (frame8: outer edge; others: black border)")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--seed", o->seed, "Seed of the renders and the jitter")->capture_default_str();
  app->add_flag("--json", o->json, "One JSON object per point on stdout instead of the tables");
  app->add_flag("-q,--quiet", o->quiet, "No progress on stderr");
  commands.push_back({app, [o] { return run_evaluate(*o); }});
}

}  // namespace markerctl
