// Stage 6, corners and pose: the outer and inner corners from the map of grid
// coordinates, and the pose with a camera.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
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

namespace {

constexpr std::array<Point2, 4> kInnerGrid{{{kInnerLo, kInnerLo},
                                            {frame8::grid - kInnerLo, kInnerLo},
                                            {frame8::grid - kInnerLo, frame8::grid - kInnerLo},
                                            {kInnerLo, frame8::grid - kInnerLo}}};

}  // namespace

// Fills the corners from a map of grid coordinates, and the pose with a
// camera. Corner j of the marker is quad corner (j + rotation) % 4.
Rejection Frame8Detector::report(const Eigen::Matrix3d& grid_to_image, int rotation, Detection& det,
                                 const MapNoise* noise, MapSpace space) const {
  const CameraModel* camera = config_.camera ? &*config_.camera : nullptr;
  // A point of the map in pixels, and in undistorted normalized coordinates (with a camera).
  const auto to_pixels = [&](Point2 p) {
    return camera && space == MapSpace::undistorted ? camera->normalized_to_pixel(p) : p;
  };
  const auto to_normalized = [&](Point2 p) {
    return camera && space == MapSpace::pixels ? camera->pixel_to_normalized(p) : p;
  };
  // The hole's corners through a map, in the marker's order (TL, TR, BR, BL), normalized.
  const auto hole_corners = [&](const Eigen::Matrix3d& map) {
    std::array<Eigen::Vector2d, 4> corners{};
    for (int j = 0; j < 4; ++j) {
      const Point2 g = kInnerGrid[static_cast<std::size_t>((j + rotation) % 4)];
      const Point2 p = to_normalized(map_grid(map, g.x, g.y));
      corners[static_cast<std::size_t>(j)] = {p.x, p.y};
    }
    return corners;
  };
  Quad in{}, outq{};
  for (int j = 0; j < 4; ++j) {
    const auto q = static_cast<std::size_t>((j + rotation) % 4);
    const auto jj = static_cast<std::size_t>(j);
    in[jj] = to_pixels(map_grid(grid_to_image, kInnerGrid[q].x, kInnerGrid[q].y));
    outq[jj] = to_pixels(map_grid(grid_to_image, kOuterGridCorners[q].x, kOuterGridCorners[q].y));
  }
  // A printed square seen through a lens is a convex quad, turned the same
  // way round at every corner. A map that folds it (fitted to clutter that
  // read as some code) has found no marker.
  if (!convex(in) || !convex(outq)) return Rejection::corners_not_convex;
  det.inner_corners = in;
  det.corners = outq;
  if (camera) {
    const double side = config_.marker_size_m * frame8::hole_fraction;
    const std::array<Eigen::Vector2d, 4> hole = hole_corners(grid_to_image);
    det.pose = estimate_square_pose_normalized(*camera, hole, side);
    if (!det.pose) return Rejection::no_pose;
    if (noise) {
      // The variance of the hole's squeeze that the map's noise makes: the
      // squeeze's change along each of the map's directions of noise,
      // squared and summed.
      double variance = 0;
      for (int k = 0; k < noise->count; ++k) {
        const Eigen::Matrix3d& d = noise->deltas[static_cast<std::size_t>(k)];
        const auto plus = square_tilt_anisotropy(hole_corners(grid_to_image + d));
        const auto minus = square_tilt_anisotropy(hole_corners(grid_to_image - d));
        if (plus && minus) variance += ((*plus - *minus) / 2).squaredNorm();
      }
      shrink_tilt_by_noise(*camera, hole, side, variance, det.pose->best);
    }
  }
  const Point2 top = det.corners[1] - det.corners[0];
  const int quarter = static_cast<int>(std::lround(std::atan2(top.y, top.x) / (std::numbers::pi / 2)));
  det.quarter_turns = ((quarter % 4) + 4) % 4;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
