// Stage 6, corners and pose: the outer and inner corners from the map of grid
// coordinates, and the pose with a camera.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <span>
#include <vector>

#include "markerd/detector/pose.hpp"

namespace markerd::detector::frame8 {

bool Frame8Detector::convex(const Quad& q) {
  int positive = 0, negative = 0;
  for (std::size_t i = 0; i < 4; ++i) {
    const double c = cross(q[i], q[(i + 1) % 4], q[(i + 2) % 4]);
    positive += c > 0;
    negative += c < 0;
  }
  return positive == 4 || negative == 4;
}

// Fills the corners from a map of grid coordinates to the image (without a
// camera) or to undistorted normalized coordinates (with one), and the
// pose with a camera. Corner j of the marker is quad corner
// (j + rotation) % 4.
namespace {

constexpr std::array<Point2, 4> kInnerGrid{{{kInnerLo, kInnerLo},
                                            {frame8::grid - kInnerLo, kInnerLo},
                                            {frame8::grid - kInnerLo, frame8::grid - kInnerLo},
                                            {kInnerLo, frame8::grid - kInnerLo}}};

// The hole's corners through a map, in the marker's order (TL, TR, BR, BL).
std::array<Eigen::Vector2d, 4> inner_corners(const Eigen::Matrix3d& grid_to_image, int rotation) {
  std::array<Eigen::Vector2d, 4> corners{};
  for (int j = 0; j < 4; ++j) {
    const Point2 g = kInnerGrid[static_cast<std::size_t>((j + rotation) % 4)];
    const Point2 p = map_grid(grid_to_image, g.x, g.y);
    corners[static_cast<std::size_t>(j)] = {p.x, p.y};
  }
  return corners;
}

// The variance of the hole's squeeze (square_tilt_anisotropy) that the
// map's noise makes: the squeeze's change along each of the map's
// directions of noise, squared and summed.
double squeeze_variance(const Eigen::Matrix3d& grid_to_image, int rotation,
                        std::span<const Eigen::Matrix3d> map_deltas) {
  double variance = 0;
  for (const Eigen::Matrix3d& d : map_deltas) {
    const auto plus = square_tilt_anisotropy(inner_corners(grid_to_image + d, rotation));
    const auto minus = square_tilt_anisotropy(inner_corners(grid_to_image - d, rotation));
    if (!plus || !minus) return 0;
    variance += ((*plus - *minus) / 2).squaredNorm();
  }
  return variance;
}

}  // namespace

Rejection Frame8Detector::report(const Eigen::Matrix3d& grid_to_image, int rotation, Detection& det,
                                 const GridMapNoise* noise) const {
  Quad in{}, outq{};
  const std::array<Eigen::Vector2d, 4> model_order = inner_corners(grid_to_image, rotation);
  for (int j = 0; j < 4; ++j) {
    const auto q = static_cast<std::size_t>((j + rotation) % 4);
    const auto jj = static_cast<std::size_t>(j);
    const Point2 inner{model_order[jj].x(), model_order[jj].y()};
    const Point2 outer = map_grid(grid_to_image, kOuterGridCorners[q].x, kOuterGridCorners[q].y);
    in[jj] = config_.camera ? config_.camera->normalized_to_pixel(inner) : inner;
    outq[jj] = config_.camera ? config_.camera->normalized_to_pixel(outer) : outer;
  }
  // A printed square seen through a lens is a convex quad, turned the same
  // way round at every corner. A map that folds it (fitted to clutter that
  // read as some code) has found no marker.
  if (!convex(in) || !convex(outq)) return Rejection::corners_not_convex;
  det.inner_corners = in;
  det.corners = outq;
  if (config_.camera) {
    const double side = config_.marker_size_m * frame8::hole_fraction;
    det.pose = estimate_square_pose_normalized(*config_.camera, model_order, side);
    if (!det.pose) return Rejection::no_pose;
    if (noise) {
      shrink_tilt_by_noise(*config_.camera, model_order, side,
                           squeeze_variance(grid_to_image, rotation,
                                            std::span(noise->deltas.data(), static_cast<std::size_t>(noise->count))),
                           det.pose->best);
    }
  }
  const Point2 top = det.corners[1] - det.corners[0];
  const int quarter = static_cast<int>(std::lround(std::atan2(top.y, top.x) / (std::numbers::pi / 2)));
  det.quarter_turns = ((quarter % 4) + 4) % 4;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
