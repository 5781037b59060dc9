#include "markerd/detector/evaluate.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>
#include <vector>

namespace markerd::detector {
namespace {

// splitmix64's finaliser: spreads the bits of seed, distance and yaw so that
// neighbouring points do not get correlated streams.
std::uint64_t mix(std::uint64_t h, std::uint64_t v) {
  std::uint64_t z = h ^ (v + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2));
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// [0, 1) from the top 53 bits; std::uniform_real_distribution would do, but
// its output is not specified across standard libraries and the figures
// should not move with the toolchain.
double unit(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

double median(std::vector<double>& v) {
  if (v.empty()) return 0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  if (v.size() % 2) return *mid;
  const double upper = *mid;
  const double lower = *std::max_element(v.begin(), mid);
  return 0.5 * (lower + upper);
}

double mean_corner_error(const Quad& a, const Quad& b) {
  double sum = 0;
  for (std::size_t k = 0; k < 4; ++k) sum += distance(a[k], b[k]);
  return sum / 4;
}

}  // namespace

EvalResult evaluate_point(MarkerDetector& detector, const CameraModel& camera, const EvalSettings& settings,
                          const EvalPoint& point) {
  if (detector.family() != settings.scene.family) {
    throw std::invalid_argument("evaluate_point: the scene shows another family than the detector reads");
  }
  const FamilyInfo& family = family_info(settings.scene.family);
  const int id_count = family.default_id_count();

  std::uint64_t h = mix(0, settings.seed);
  h = mix(h, std::bit_cast<std::uint64_t>(point.distance_m));
  h = mix(h, std::bit_cast<std::uint64_t>(point.yaw_deg));
  std::mt19937_64 rng(h);

  EvalResult result;
  result.point = point;
  std::vector<double> corner_errors, distance_errors, distance_biases, times;
  const auto n = static_cast<std::size_t>(std::max(settings.frames_per_point, 0));
  corner_errors.reserve(n);
  distance_errors.reserve(n);
  times.reserve(n);
  std::vector<Detection> found;

  for (int frame = 0; frame < settings.frames_per_point; ++frame) {
    // The same number of draws for every family, so that two families
    // evaluated with the same seed see the same poses and backgrounds.
    const double r = settings.position_jitter_px * std::sqrt(unit(rng));  // uniform over the disc
    const double phi = 2 * std::numbers::pi * unit(rng);
    const double roll = settings.roll_jitter_deg * (2 * unit(rng) - 1);
    const double id_draw = unit(rng);
    const std::uint64_t scene_seed = rng();

    Scene scene = settings.scene;
    // Pixels off the principal point to metres in the marker's plane: the
    // pinhole is enough for a jitter whose only job is to vary the frames.
    const double dx_m = r * std::cos(phi) * point.distance_m / camera.fx;
    const double dy_m = r * std::sin(phi) * point.distance_m / camera.fy;
    scene.pose = facing_pose(point.distance_m, point.yaw_deg, 0, roll, dx_m, dy_m);
    if (settings.random_ids) {
      scene.id = family.first_default_id + std::min(static_cast<int>(id_draw * id_count), id_count - 1);
    }
    scene.seed = scene_seed;
    if (!settings.occluder_turns.empty()) {
      const auto& turn = settings.occluder_turns[static_cast<std::size_t>(frame) % settings.occluder_turns.size()];
      scene.occluders.insert(scene.occluders.end(), turn.begin(), turn.end());
    }
    if (!settings.background_turns.empty()) {
      scene.background = settings.background_turns[static_cast<std::size_t>(frame) % settings.background_turns.size()];
    }

    const GreyImage image = render_scene(camera, scene);
    const auto t0 = std::chrono::steady_clock::now();
    detector.detect(image.view(), found);
    const auto t1 = std::chrono::steady_clock::now();
    times.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
    ++result.frames;

    if (settings.on_wrong_id &&
        std::any_of(found.begin(), found.end(), [&](const Detection& d) { return d.id != scene.id; })) {
      settings.on_wrong_id(image, scene, found);
    }
    const Detection* best = nullptr;
    double best_error = 0;
    const Quad truth = project_marker_corners(camera, scene);
    for (const Detection& d : found) {
      if (d.id != scene.id) {
        ++result.wrong_id;
        continue;
      }
      // A marker found twice counts once, by its better reading.
      const double e = mean_corner_error(d.corners, truth);
      if (!best || e < best_error) {
        best = &d;
        best_error = e;
      }
    }
    if (!best) {
      if (settings.on_miss) settings.on_miss(image, scene);
      continue;
    }
    ++result.detected;
    corner_errors.push_back(best_error);
    if (best->pose) {
      const double t_true = scene.pose.translation.norm();
      const double t_est = best->pose->best.translation.norm();
      distance_errors.push_back(std::abs(t_est - t_true) / t_true);
      distance_biases.push_back((t_est - t_true) / t_true);
    }
  }

  result.median_corner_error_px = median(corner_errors);
  result.median_distance_error_rel = median(distance_errors);
  result.median_distance_bias_rel = median(distance_biases);
  // Over every frame, not only the detected ones: a miss costs time too, and
  // at the far end there may be no detections to take a median over.
  result.median_time_ms = median(times);
  return result;
}

}  // namespace markerd::detector
