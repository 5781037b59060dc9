#pragma once
// What the calibration tests share (test_calibration.cpp,
// test_markerctl_calibrate.cpp): a known camera with and without lens
// distortion, a board of each type, and rendered views of a board's print
// through the camera at poses that tilt it up to 45 degrees, at several
// distances, spread over the whole image.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <vector>

#include "markerd/detector/board.hpp"
#include "markerd/detector/calibration.hpp"
#include "markerd/detector/print.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::detector::calibration_test {

// 640x480, a little wider than the thesis camera, barrel distortion with
// some tangential.
inline CameraModel distorted_camera() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = 560;
  c.fy = 556;
  c.cx = 323.5;
  c.cy = 236.0;
  c.dist = {-0.2, 0.05, 0.001, -0.0015, 0.0};
  return c;
}

inline CameraModel pinhole_camera() {
  CameraModel c = distorted_camera();
  c.dist = {};
  return c;
}

inline BoardSpec chessboard() {
  BoardSpec b;
  b.type = BoardType::chessboard;
  b.cols = 9;
  b.rows = 7;
  b.size_m = 0.02;
  return b;
}

inline BoardSpec charuco() {
  BoardSpec b;
  b.type = BoardType::charuco;
  b.cols = 7;
  b.rows = 5;
  b.size_m = 0.025;
  b.marker_size_m = 0.015;
  b.dictionary = "4x4_50";
  return b;
}

inline BoardSpec frame8_board() {
  BoardSpec b;
  b.type = BoardType::frame8;
  b.cols = 4;
  b.rows = 3;
  b.size_m = 0.036;
  b.spacing_m = 0.009;
  b.ids = frame8_board_ids(0, 12);
  return b;
}

// The board's printed page, 0.1 mm a texel: every edge of these boards
// falls on a texel's side.
constexpr double kPxPerM = 10000;
constexpr double kMarginMm = 10;

inline std::shared_ptr<const PlanarPrint> board_print(const BoardSpec& board) {
  BoardPrintSpec spec;
  spec.board = board;
  spec.margin_mm = kMarginMm;
  auto print = std::make_shared<PlanarPrint>();
  print->image = board_page_image(spec, kPxPerM);
  print->texel_m = 1.0 / kPxPerM;
  return print;
}

// A board-frame point (x right, y down the print, from the pattern's
// top-left corner) in the marker frame of a scene showing board_print():
// the page is centred on the marker frame's origin, its top towards +Y.
inline Eigen::Vector3d board_to_marker(const PlanarPrint& print, const Eigen::Vector3d& p) {
  const double w = print.image.width() * print.texel_m, h = print.image.height() * print.texel_m;
  const double m = kMarginMm * 1e-3;
  return {p.x() + m - w / 2, h / 2 - (p.y() + m), 0};
}

inline Point2 pixel_of(const CameraModel& camera, const MarkerPose& pose, const Eigen::Vector3d& marker_point) {
  const Eigen::Vector3d c = pose.rotation * marker_point + pose.translation;
  return camera.normalized_to_pixel({c.x() / c.z(), c.y() / c.z()});
}

// The view's tilt and where in the image its centre goes.
struct ViewPlan {
  double yaw_deg;
  double pitch_deg;
  double roll_deg;
  double at_x;  // the board's centre, as a share of the image's width from the left
  double at_y;  // and of its height from the top
  double distance_m;
};

// Twelve views: face on and tilted by 25 to 45 degrees each way, near
// every corner and edge of the image and in the middle, from 0.28 m up.
inline std::vector<ViewPlan> view_plans() {
  return {
      {0, 0, 0, 0.5, 0.5, 0.30},        {40, 0, 5, 0.28, 0.5, 0.30},     {-40, 0, -5, 0.72, 0.5, 0.30},
      {0, 40, 10, 0.5, 0.28, 0.30},     {0, -40, -10, 0.5, 0.72, 0.30},  {30, 30, 20, 0.22, 0.22, 0.28},
      {-30, 30, -20, 0.78, 0.22, 0.28}, {30, -30, 15, 0.22, 0.78, 0.28}, {-30, -30, -15, 0.78, 0.78, 0.28},
      {25, -15, 90, 0.35, 0.4, 0.35},   {-20, 25, 180, 0.6, 0.6, 0.40},  {45, 10, -30, 0.5, 0.5, 0.36},
  };
}

// Four more for a board that may be seen in part (ChArUco, frame8): its
// centre near each of the image's corners, tilted, part of it out of the
// image, so that its points reach into the very corners.
inline std::vector<ViewPlan> partial_view_plans() {
  return {
      {25, 20, 10, 0.9, 0.88, 0.30},
      {-25, 20, -10, 0.1, 0.88, 0.30},
      {25, -20, -10, 0.9, 0.12, 0.30},
      {-25, -20, 10, 0.1, 0.12, 0.30},
  };
}

// A plan's pose, the board's centre on the ray through its image point.
inline MarkerPose pose_at(const CameraModel& camera, const ViewPlan& plan) {
  const Point2 n = camera.pixel_to_normalized({plan.at_x * camera.width, plan.at_y * camera.height});
  const double d = plan.distance_m;
  return facing_pose(d, plan.yaw_deg, plan.pitch_deg, plan.roll_deg, n.x * d, n.y * d);
}

// The pose of a plan: the board's centre on the ray through its image
// point, moved back until its page's corners (the chessboard's white
// border included) are all in the image.
inline MarkerPose plan_pose(const CameraModel& camera, const PlanarPrint& print, const ViewPlan& plan) {
  const Point2 n = camera.pixel_to_normalized({plan.at_x * camera.width, plan.at_y * camera.height});
  const double hw = print.image.width() * print.texel_m / 2, hh = print.image.height() * print.texel_m / 2;
  double d = plan.distance_m;
  for (int tries = 0; tries < 60; ++tries, d *= 1.05) {
    MarkerPose pose = facing_pose(d, plan.yaw_deg, plan.pitch_deg, plan.roll_deg, n.x * d, n.y * d);
    bool inside = true;
    for (const auto& corner :
         std::array<Eigen::Vector3d, 4>{Eigen::Vector3d(-hw, hh, 0), Eigen::Vector3d(hw, hh, 0),
                                        Eigen::Vector3d(hw, -hh, 0), Eigen::Vector3d(-hw, -hh, 0)}) {
      const Point2 p = pixel_of(camera, pose, corner);
      inside = inside && p.x >= 2 && p.y >= 2 && p.x <= camera.width - 3 && p.y <= camera.height - 3;
    }
    if (inside) return pose;
  }
  ADD_FAILURE() << "no distance fits the board in the image for yaw " << plan.yaw_deg << " pitch " << plan.pitch_deg;
  return facing_pose(d, plan.yaw_deg, plan.pitch_deg, plan.roll_deg);
}

// A view as a camera sees it: focus blur, sensor noise, a cluttered room.
inline Scene board_scene(const std::shared_ptr<const PlanarPrint>& print, const MarkerPose& pose, std::uint64_t seed) {
  Scene scene;
  scene.print = print;
  scene.pose = pose;
  scene.blur_sigma_px = 0.6;
  scene.noise_sigma = 2.0;
  scene.seed = seed;
  return scene;
}

// The board's points where they truly are in a view (board frame and pixel).
inline std::vector<Point2> true_pixels(const CameraModel& camera, const PlanarPrint& print, const MarkerPose& pose,
                                       const BoardPoints& found) {
  std::vector<Point2> truth;
  for (const auto& p : found.object) truth.push_back(pixel_of(camera, pose, board_to_marker(print, p)));
  return truth;
}

// A chessboard's corners may be numbered from any of its corners (the
// grid looks the same turned half round, and mirrored): of the truths so
// renumbered, the one nearest to what was found.
inline std::vector<Point2> as_numbered(const BoardSpec& board, const BoardPoints& found,
                                       const std::vector<Point2>& truth) {
  const int per_row = board.cols - 1, per_col = board.rows - 1;
  std::vector<Point2> best = truth;
  double best_sum = 1e300;
  for (const bool flip_x : {false, true}) {
    for (const bool flip_y : {false, true}) {
      std::vector<Point2> renumbered(truth.size());
      double sum = 0;
      for (std::size_t k = 0; k < truth.size(); ++k) {
        const int i = static_cast<int>(k) % per_row, j = static_cast<int>(k) / per_row;
        const int from = (flip_y ? per_col - 1 - j : j) * per_row + (flip_x ? per_row - 1 - i : i);
        renumbered[k] = truth[static_cast<std::size_t>(from)];
        sum += distance(renumbered[k], found.image[k]);
      }
      if (sum < best_sum) {
        best_sum = sum;
        best = renumbered;
      }
    }
  }
  return best;
}

struct Rect {
  double x0, y0, x1, y1;
};

// Points along a rectangle's border, its corners included.
inline std::vector<Point2> border_points(const Rect& r) {
  std::vector<Point2> points;
  constexpr int kSteps = 16;
  for (int i = 0; i <= kSteps; ++i) {
    const double x = r.x0 + (r.x1 - r.x0) * i / kSteps, y = r.y0 + (r.y1 - r.y0) * i / kSteps;
    for (const Point2 p : {Point2{x, r.y0}, Point2{x, r.y1}, Point2{r.x0, y}, Point2{r.x1, y}}) points.push_back(p);
  }
  return points;
}

// How far two lenses' distortions disagree, in pixels: the largest
// difference, over the rectangle's border, between the displacement each
// model's distortion gives the same ray (through the truth's pixel there).
// The intrinsics' own errors, which calibrateCamera's standard deviations
// bound, are left out.
inline double distortion_disagreement_px(const CameraModel& truth, const CameraModel& fitted, const Rect& r) {
  double worst = 0;
  for (const Point2 pixel : border_points(r)) {
    const Point2 n = truth.pixel_to_normalized(pixel);
    const Point2 t = truth.distort(n) - n, f = fitted.distort(n) - n;
    worst = std::max(worst, std::hypot(truth.fx * t.x - fitted.fx * f.x, truth.fy * t.y - fitted.fy * f.y));
  }
  return worst;
}

// Where two camera models send the same ray, intrinsics and distortion
// together: the largest distance over the rectangle's border.
inline double model_disagreement_px(const CameraModel& truth, const CameraModel& fitted, const Rect& r) {
  double worst = 0;
  for (const Point2 pixel : border_points(r)) {
    worst = std::max(worst, distance(pixel, fitted.normalized_to_pixel(truth.pixel_to_normalized(pixel))));
  }
  return worst;
}

inline Rect whole_image(const CameraModel& c) { return {0, 0, c.width - 1.0, c.height - 1.0}; }

// The rectangle the views' points span: where the lens was measured.
inline Rect measured_area(const std::vector<CalibrationView>& views) {
  Rect r{1e9, 1e9, -1e9, -1e9};
  for (const auto& v : views) {
    for (const Point2& p : v.points.image) {
      r = {std::min(r.x0, p.x), std::min(r.y0, p.y), std::max(r.x1, p.x), std::max(r.y1, p.y)};
    }
  }
  return r;
}

}  // namespace markerd::detector::calibration_test
