// The blur model of a frame8 ring (detector/src/frame8/ring_model.hpp), on
// the renderer's markers with cells of about a pixel and a half.

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "frame8/ring_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/frame8.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::detector {
namespace {

const CameraModel kCamera = CameraModel::thesis_640x480();

Scene far_scene(int id, double dist, double roll, double shift_px, std::uint64_t seed) {
  Scene s;
  s.family = Family::frame8;
  s.id = id;
  s.marker_size_m = 0.08;
  s.pose = facing_pose(dist, 0, 0, roll, shift_px * dist / kCamera.fx, -shift_px * dist / kCamera.fy);
  s.noise_sigma = 2;
  s.blur_sigma_px = 0.6;
  s.seed = seed;
  return s;
}

// The map from grid coordinates (0..10, y down) to pixels through the true
// outer corners, moved by (dx, dy) pixels.
Eigen::Matrix3d grid_map(const Quad& corners, double dx, double dy) {
  const std::vector<cv::Point2d> grid{{0, 0}, {10, 0}, {10, 10}, {0, 10}};
  std::vector<cv::Point2d> image;
  for (const Point2& p : corners) image.emplace_back(p.x + dx, p.y + dy);
  std::vector<cv::Point2f> g(grid.begin(), grid.end()), i(image.begin(), image.end());
  const cv::Mat h = cv::getPerspectiveTransform(g, i);
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m(r, c) = h.at<double>(r, c);
  }
  return m;
}

// The outer corners through a map.
Quad project_quad(const Eigen::Matrix3d& map) {
  static constexpr std::array<std::array<double, 2>, 4> kGrid{{{0, 0}, {10, 0}, {10, 10}, {0, 10}}};
  Quad q{};
  for (std::size_t k = 0; k < 4; ++k) {
    const Eigen::Vector3d p = map * Eigen::Vector3d(kGrid[k][0], kGrid[k][1], 1);
    q[k] = {p(0) / p(2), p(1) / p(2)};
  }
  return q;
}

double mean_corner_error(const Quad& a, const Quad& b) {
  double sum = 0;
  for (std::size_t k = 0; k < 4; ++k) sum += std::hypot(a[k].x - b[k].x, a[k].y - b[k].y);
  return sum / 4;
}

double worst_corner_error(const Eigen::Matrix3d& map, const Quad& truth) {
  static constexpr std::array<std::array<double, 2>, 4> kGrid{{{0, 0}, {10, 0}, {10, 10}, {0, 10}}};
  double worst = 0;
  for (std::size_t k = 0; k < 4; ++k) {
    const Eigen::Vector3d p = map * Eigen::Vector3d(kGrid[k][0], kGrid[k][1], 1);
    worst = std::max(worst, std::hypot(p(0) / p(2) - truth[k].x, p(1) / p(2) - truth[k].y));
  }
  return worst;
}

// Every ring cell on the right side of the midpoint between the darkest and
// the lightest level.
int misread_cells(const frame8::RingModel::Levels& levels, int id) {
  const auto cells = frame8::ring_cells(id);
  float lo = 1e9F, hi = -1e9F;
  for (int i = 0; i < frame8::grid * frame8::grid; ++i) {
    if (cells[static_cast<std::size_t>(i)] == 2) continue;
    lo = std::min(lo, levels.cell[static_cast<std::size_t>(i)]);
    hi = std::max(hi, levels.cell[static_cast<std::size_t>(i)]);
  }
  int wrong = 0;
  for (int i = 0; i < frame8::grid * frame8::grid; ++i) {
    if (cells[static_cast<std::size_t>(i)] == 2) continue;
    const bool white = levels.cell[static_cast<std::size_t>(i)] > 0.5F * (lo + hi);
    wrong += white != (cells[static_cast<std::size_t>(i)] == 1);
  }
  return wrong;
}

TEST(RingModel, RegionsCoverTheRingOnce) {
  std::array<int, frame8::RingModel::kRingRegions> seen{};
  for (int row = 0; row < frame8::grid; ++row) {
    for (int col = 0; col < frame8::grid; ++col) {
      const int r = frame8::RingModel::ring_region(col, row);
      const bool ring = row == 0 || col == 0 || row == frame8::grid - 1 || col == frame8::grid - 1;
      ASSERT_EQ(r >= 0, ring) << col << "," << row;
      if (r >= 0) ++seen[static_cast<std::size_t>(r)];
    }
  }
  for (int n : seen) EXPECT_EQ(n, 1);
}

// At 2.6 m a cell is 1.6 px: the grey at a cell's centre is as much its
// neighbours' as its own, but the levels the model fits are the cells'.
TEST(RingModel, LevelsOfCellsOfOnePointSixPixels) {
  for (int id : {48, 165, 90, 201}) {
    const Scene s = far_scene(id, 2.6, 3, 10, static_cast<std::uint64_t>(id));
    const GreyImage img = render_scene(kCamera, s);
    Eigen::Matrix3d map = grid_map(project_marker_corners(kCamera, s), 0, 0);
    frame8::RingModel model;
    frame8::RingModel::Levels levels;
    ASSERT_TRUE(model.fit(img, map, 0.6, frame8::RingModel::Aim::levels, levels)) << id;
    EXPECT_EQ(misread_cells(levels, id), 0) << id;
    // Noise 2 plus what the Gaussian footprint leaves out of a square pixel.
    EXPECT_LT(levels.rms_residual, 8.0) << id;
    for (float line : levels.line) EXPECT_LT(line, levels.hole - 150) << id;
  }
}

// Started a third of a pixel off, the fit moves the map towards the
// marker and reads every cell. Measured: it lands 0.08 to 0.26 px from the
// true corners (the Gaussian stands in for the pixel's square, and the
// misfit that leaves, about 5 grey levels rms, has minima of its own).
TEST(RingModel, AlignmentMovesTowardsTheMarker) {
  double sum_after = 0;
  int n = 0;
  for (int id : {48, 165, 90, 201}) {
    const Scene s = far_scene(id, 2.6, -4, -20, 100 + static_cast<std::uint64_t>(id));
    const GreyImage img = render_scene(kCamera, s);
    const Quad truth = project_marker_corners(kCamera, s);
    Eigen::Matrix3d map = grid_map(truth, 0.3, -0.2);
    const double before = worst_corner_error(map, truth);
    frame8::RingModel model;
    frame8::RingModel::Levels levels;
    ASSERT_TRUE(model.fit(img, map, 0.6, frame8::RingModel::Aim::aligned_levels, levels)) << id;
    const double after = worst_corner_error(map, truth);
    EXPECT_LT(after, 0.8 * before) << id;
    EXPECT_EQ(misread_cells(levels, id), 0) << id;
    sum_after += after;
    ++n;
  }
  EXPECT_LT(sum_after / n, 0.2);
}

// For the geometry the fit takes every pixel the marker's edge reaches
// (but those that clutter beside a bare print makes it miss by far), and
// goes on to a hundredth of a pixel. From a map 0.36 px off, at
// 1.6 and 2.2 m (cells of 2.6 and 1.9 px), rolled a little or 45 degrees,
// on clutter and on the print's paper margin, its corners land nearer the
// truth than the read's alignment puts them (half the pixels, a twentieth
// of a pixel); its noise is eight directions of the map, each moving the
// corners by a small fraction of a pixel.
TEST(RingModel, TheGeometrysFitFindsTheCornersNearerThanTheReadsAlignment) {
  double geometry_error = 0, read_error = 0;
  int n = 0;
  for (const double dist : {1.6, 2.2}) {
    for (const double roll : {-4.0, 45.0}) {
      for (const double margin : {0.0, 0.01}) {
        for (int id : {48, 201}) {
          Scene s = far_scene(id, dist, roll, 17, 300 + static_cast<std::uint64_t>(n));
          s.paper_margin_m = margin;
          const GreyImage img = render_scene(kCamera, s);
          const Quad truth = project_marker_corners(kCamera, s);
          frame8::RingModel model;
          frame8::RingModel::Levels levels;
          Eigen::Matrix3d read_map = grid_map(truth, 0.3, -0.2);
          ASSERT_TRUE(model.fit(img, read_map, 0.6, frame8::RingModel::Aim::aligned_levels, levels)) << id;
          read_error += mean_corner_error(project_quad(read_map), truth);
          Eigen::Matrix3d map = grid_map(truth, 0.3, -0.2);
          frame8::MapNoise noise;
          ASSERT_TRUE(model.fit(img, map, 0.6, frame8::RingModel::Aim::geometry, levels, &noise)) << id;
          geometry_error += mean_corner_error(project_quad(map), truth);
          EXPECT_EQ(misread_cells(levels, id), 0) << id;
          ASSERT_EQ(noise.count, 8);
          for (const Eigen::Matrix3d& d : noise.deltas) {
            const double moved = worst_corner_error(map + d, project_quad(map));
            EXPECT_GT(moved, 1e-4);
            EXPECT_LT(moved, 0.1);
          }
          ++n;
        }
      }
    }
  }
  RecordProperty("mean_corner_error_geometry_px", std::to_string(geometry_error / n));
  RecordProperty("mean_corner_error_read_px", std::to_string(read_error / n));
  // Measured: 0.070 px against the alignment's 0.074 on average; without
  // the clutter's pixels dropped, 0.082 (a bare print at 2.2 m rolled 45
  // deg: 0.31 px, shapes beside its edge taken for the outside's level).
  EXPECT_LT(geometry_error, read_error);
  EXPECT_LT(geometry_error / n, 0.1);
}

TEST(RingModel, RefusesWhatItCannotFit) {
  const Scene s = far_scene(165, 0.5, 0, 0, 1);
  const GreyImage img = render_scene(kCamera, s);
  frame8::RingModel model;
  frame8::RingModel::Levels levels;
  // Cells of 8 px: sampling is the right tool there.
  Eigen::Matrix3d map = grid_map(project_marker_corners(kCamera, s), 0, 0);
  EXPECT_FALSE(model.fit(img, map, 0.6, frame8::RingModel::Aim::aligned_levels, levels));
  // Leaving the image.
  Eigen::Matrix3d off = Eigen::Matrix3d::Identity();
  off(0, 2) = -5;
  EXPECT_FALSE(model.fit(img, off, 0.6, frame8::RingModel::Aim::levels, levels));
}

// The detector with the model (its default) reads markers too far away to
// sample their cells reliably (2.9 m: a cell of 1.4 px).
TEST(RingModel, DetectorReadsFartherWithTheModel) {
  DetectorConfig modelled;
  modelled.camera = kCamera;
  modelled.marker_size_m = 0.08;
  DetectorConfig plain = modelled;
  plain.frame8.model_small_cells = false;
  auto sampled_only = make_detector(plain);
  auto with_model = make_detector(modelled);
  int found_sampled = 0, found_model = 0, wrong = 0;
  constexpr int kFrames = 20;
  constexpr double kDistance = 2.9;
  for (int k = 0; k < kFrames; ++k) {
    const int id = 1 + (k * 37) % 254;
    Scene s = far_scene(id, kDistance, -5 + k % 10, (k % 7) * 6 - 18, 500 + static_cast<std::uint64_t>(k));
    s.clutter = true;
    const GreyImage img = render_scene(kCamera, s);
    std::vector<Detection> out;
    sampled_only->detect(img, out);
    for (const auto& d : out) found_sampled += d.id == id;
    with_model->detect(img, out);
    for (const auto& d : out) {
      found_model += d.id == id;
      wrong += d.id != id;
    }
  }
  EXPECT_GE(found_model, kFrames * 8 / 10);
  EXPECT_GT(found_model, found_sampled);
  // Measured here: 17 against 15, none misread.
  EXPECT_EQ(wrong, 0);
}

}  // namespace
}  // namespace markerd::detector
