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

// Fills the corners from a map of grid coordinates to the image (without a
// camera) or to undistorted normalized coordinates (with one), and the
// pose with a camera. Corner j of the marker is quad corner
// (j + rotation) % 4.
Rejection Frame8Detector::report(const Eigen::Matrix3d& grid_to_image, int rotation, Detection& det) const {
  static constexpr std::array<Point2, 4> kInnerGrid{{{kInnerLo, kInnerLo},
                                                     {frame8::grid - kInnerLo, kInnerLo},
                                                     {frame8::grid - kInnerLo, frame8::grid - kInnerLo},
                                                     {kInnerLo, frame8::grid - kInnerLo}}};
  Quad in{}, outq{};
  std::array<Eigen::Vector2d, 4> model_order{};
  for (int j = 0; j < 4; ++j) {
    const auto q = static_cast<std::size_t>((j + rotation) % 4);
    const auto jj = static_cast<std::size_t>(j);
    const Point2 inner = map_grid(grid_to_image, kInnerGrid[q].x, kInnerGrid[q].y);
    const Point2 outer = map_grid(grid_to_image, kOuterGridCorners[q].x, kOuterGridCorners[q].y);
    model_order[jj] = {inner.x, inner.y};
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
    det.pose =
        estimate_square_pose_normalized(*config_.camera, model_order, config_.marker_size_m * frame8::hole_fraction);
    if (!det.pose) return Rejection::no_pose;
  }
  const Point2 top = det.corners[1] - det.corners[0];
  const int quarter = static_cast<int>(std::lround(std::atan2(top.y, top.x) / (std::numbers::pi / 2)));
  det.quarter_turns = ((quarter % 4) + 4) % 4;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
