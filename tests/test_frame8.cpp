// The frame8 detector against the renderer's ground truth.

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <initializer_list>
#include <numbers>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "markerd/detector/detector.hpp"
#include "markerd/detector/evaluate.hpp"
#include "markerd/detector/frame8.hpp"
#include "markerd/detector/pose.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::detector {
namespace {

const CameraModel kCamera = CameraModel::thesis_640x480();

Scene scene(int id, double dist, double yaw, double roll, std::uint64_t seed) {
  Scene s;
  s.family = Family::frame8;
  s.id = id;
  s.marker_size_m = 0.08;
  s.pose = facing_pose(dist, yaw, 0, roll);
  s.noise_sigma = 2;
  s.blur_sigma_px = 0.6;
  s.seed = seed;
  return s;
}

// A detector with the thesis camera and the 8 cm marker: poses, as markerd's.
DetectorConfig posed_config() {
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  return cfg;
}

// bench_accuracy's scenes: the 8 cm marker, noise sigma 2, blur 0.6 px.
EvalSettings benchmark_settings() {
  EvalSettings settings;
  settings.scene.marker_size_m = 0.08;
  settings.scene.noise_sigma = 2;
  settings.scene.blur_sigma_px = 0.6;
  return settings;
}

// bench_accuracy's counts over points facing the camera at `distances`.
struct Tally {
  int frames = 0, detected = 0, wrong = 0;
};
Tally evaluate_facing(MarkerDetector& det, const EvalSettings& settings, std::initializer_list<double> distances) {
  Tally t;
  for (const double d : distances) {
    const EvalResult r = evaluate_point(det, kCamera, settings, {d, 0});
    t.frames += r.frames;
    t.detected += r.detected;
    t.wrong += r.wrong_id;
  }
  return t;
}

std::vector<Detection> detect(MarkerDetector& det, const GreyImage& img) {
  std::vector<Detection> out;
  det.detect(img, out);
  return out;
}

cv::Mat image_of(const GreyImage& img) {
  return cv::Mat(img.height(), img.width(), CV_8U, const_cast<std::uint8_t*>(img.data())).clone();
}

double max_corner_error(const Quad& found, const Quad& truth) {
  double worst = 0;
  for (std::size_t i = 0; i < 4; ++i) worst = std::max(worst, distance(found[i], truth[i]));
  return worst;
}

double mean_corner_error(const Quad& found, const Quad& truth) {
  double sum = 0;
  for (std::size_t i = 0; i < 4; ++i) sum += distance(found[i], truth[i]);
  return sum / 4;
}

// Every id in every quarter turn: the id, the orientation and the corner order.
// Ids 0 and 255 are read only when asked for (Frame8Options::uniform_ids).
TEST(Frame8, RoundTripAllIdsAllRotations) {
  auto det = make_detector(DetectorConfig{});
  DetectorConfig with_uniform;
  with_uniform.frame8.uniform_ids = true;
  auto uniform = make_detector(with_uniform);
  int failures = 0;
  for (int id = 0; id < 256; ++id) {
    Scene s = scene(id, 0.45, 15, 0, static_cast<std::uint64_t>(id));
    s.supersample = 2;  // enough at this size, and four times faster
    // Without a camera model the detector cannot undo the lens; this test
    // is about the code, so the image has none (the lens: next tests).
    s.distort = false;
    // The quarter turns are the rendered image turned clockwise, the truth
    // with it: exact, and a quarter of the renders.
    cv::Mat image = image_of(render_scene(kCamera, s));
    Quad truth = project_marker_corners(kCamera, s);
    for (int turn = 0; turn < 4; ++turn) {
      if (turn > 0) {
        const int rows = image.rows;
        cv::rotate(image, image, cv::ROTATE_90_CLOCKWISE);
        for (Point2& p : truth) p = {rows - 1 - p.y, p.x};
      }
      GreyImage img(image.cols, image.rows);
      image.copyTo(cv::Mat(img.height(), img.width(), CV_8U, img.data()));
      const bool uniform_id = id == 0 || id == 255;
      const auto found = detect(uniform_id ? *uniform : *det, img);
      const bool ok = found.size() == 1 && found[0].id == id && found[0].quarter_turns == turn &&
                      max_corner_error(found[0].corners, truth) < 0.5;
      if (!ok) {
        ++failures;
        ADD_FAILURE() << "id " << id << " turn " << turn << ": " << found.size() << " detections"
                      << (found.empty() ? ""
                                        : ", first id " + std::to_string(found[0].id) + " turns " +
                                              std::to_string(found[0].quarter_turns));
      }
      if (failures > 10) return;
    }
  }
}

// Paints over ring cells of the rendered marker: the cell polygons are
// projected through the true pose.
void cover_cells(GreyImage& img, const Scene& s, const std::vector<frame8::Cell>& cells, std::uint8_t value) {
  cv::Mat m(img.height(), img.width(), CV_8U, img.data());
  for (const frame8::Cell c : cells) {
    std::vector<cv::Point> poly;
    for (const auto& [gx, gy] :
         {std::pair{c.col, c.row}, {c.col + 1, c.row}, {c.col + 1, c.row + 1}, {c.col, c.row + 1}}) {
      // Grid (0..10, y down) to the marker frame (metres, y up).
      const double u = (gx - 5.0) / 10.0, v = (5.0 - gy) / 10.0;
      const Point2 p = project(kCamera, s.pose, Eigen::Vector3d(u * s.marker_size_m, v * s.marker_size_m, 0));
      poly.emplace_back(static_cast<int>(std::lround(p.x * 16)), static_cast<int>(std::lround(p.y * 16)));
    }
    cv::fillConvexPoly(m, poly, cv::Scalar(value), cv::LINE_AA, 4);
  }
}

// One edge covered, black or white, on its data cells or along its whole
// strip: the other three edges still decide every bit.
// An edge's eight cells painted over, its line whole: outvoted, and read
// from the other three. Not for the near-uniform ids: a key top in its
// bevel, one side's bevel shaded, reads so as 126 (covered_side_unread);
// those are refused, and never read as another id.
TEST(Frame8, OneCoveredEdgeStillDecodes) {
  auto det = make_detector(DetectorConfig{});
  for (const int id : {165, 0x5a, 0x0f, 1, 254}) {
    for (int edge = 0; edge < 4; ++edge) {
      for (const std::uint8_t paint : {std::uint8_t{10}, std::uint8_t{235}}) {
        const Scene s = scene(id, 0.5, 20, 0, 100 + edge);
        GreyImage img = render_scene(kCamera, s);
        std::vector<frame8::Cell> cells;
        for (int bit = 0; bit < 8; ++bit) cells.push_back(frame8::data_cell(edge, bit));
        cover_cells(img, s, cells, paint);
        const auto found = detect(*det, img);
        if (frame8::near_uniform(id)) {
          for (const Detection& d : found) EXPECT_EQ(d.id, id) << "edge " << edge << " paint " << int(paint);
          continue;
        }
        ASSERT_EQ(found.size(), 1u) << "id " << id << " edge " << edge << " paint " << int(paint);
        EXPECT_EQ(found[0].id, id) << "edge " << edge << " paint " << int(paint);
        EXPECT_EQ(found[0].quarter_turns, 0) << "id " << id << " edge " << edge << " paint " << int(paint);
        EXPECT_GT(found[0].bits_corrected, 0) << "id " << id << " edge " << edge;
      }
    }
  }
}

TEST(Frame8, CoveredStripWithItsCornersStillGivesTheId) {
  auto det = make_detector(DetectorConfig{});
  // The bottom and left strips hold black corners only; covered in black,
  // the white corner still orients the marker.
  for (const int edge : {2, 3}) {
    const Scene s = scene(165, 0.5, -20, 0, 200 + edge);
    GreyImage img = render_scene(kCamera, s);
    std::vector<frame8::Cell> cells;
    for (int bit = 0; bit < 8; ++bit) cells.push_back(frame8::data_cell(edge, bit));
    cells.push_back(frame8::corner_cell(edge));
    cells.push_back(frame8::corner_cell((edge + 1) % 4));
    cover_cells(img, s, cells, 10);
    const auto found = detect(*det, img);
    ASSERT_EQ(found.size(), 1u) << "edge " << edge;
    EXPECT_EQ(found[0].id, 165);
    EXPECT_EQ(found[0].quarter_turns, 0);
  }
}

TEST(Frame8, TwoCoveredEdgesAreNotMisread) {
  auto det = make_detector(DetectorConfig{});
  const Scene s = scene(165, 0.5, 10, 0, 300);
  GreyImage img = render_scene(kCamera, s);
  std::vector<frame8::Cell> cells;
  for (int bit = 0; bit < 8; ++bit) {
    cells.push_back(frame8::data_cell(0, bit));
    cells.push_back(frame8::data_cell(1, bit));
  }
  cover_cells(img, s, cells, 235);
  for (const Detection& d : detect(*det, img)) EXPECT_EQ(d.id, 165) << "a misread, not an erasure";
}

// Clean renders (no noise, no blur): the outer corners within 0.2 px on
// average, none beyond 0.3 px where cells are 4 px or more, and a median
// under 0.1 px over all views.
// Lens distortion bows the edges (0.3 px over a marker 120 px wide with the
// thesis's lens), so distorted renders go through the camera model, which
// fits the edges where they are straight; undistorted ones need no model.
TEST(Frame8, CornersWithinAFifthOfAPixelOnCleanRenders) {
  // The renders are sharp, and the detector is told so, as the user of a
  // sharp lens sets [detector.frame8] blur_sigma_px.
  DetectorConfig sharp;
  sharp.frame8.blur_sigma_px = 0;
  DetectorConfig with_lens = sharp;
  with_lens.camera = kCamera;
  with_lens.marker_size_m = 0.08;
  auto lens = make_detector(with_lens);
  auto plain = make_detector(sharp);
  std::vector<double> errors;
  int k = 0;
  for (const bool distort : {false, true}) {
    for (const double dist : {0.35, 0.6, 1.0, 1.5}) {
      for (const double yaw : {0.0, 25.0, -45.0}) {
        for (const double roll : {0.0, 30.0}) {
          Scene s = scene(0x3c + k, dist, yaw, roll, static_cast<std::uint64_t>(400 + k));
          ++k;
          s.noise_sigma = 0;
          s.blur_sigma_px = 0;
          s.distort = distort;
          const auto found = detect(distort ? *lens : *plain, render_scene(kCamera, s));
          ASSERT_EQ(found.size(), 1u) << dist << " m, yaw " << yaw << ", roll " << roll << ", distort " << distort;
          const Quad truth = project_marker_corners(kCamera, s);
          const double err = mean_corner_error(found[0].corners, truth);
          EXPECT_LT(err, 0.2) << dist << " m, yaw " << yaw << ", roll " << roll << ", distort " << distort;
          // At 1.5 m a cell is under 3 px, and under 2 px across when turned
          // 45 degrees: there only the average holds.
          if (dist <= 1.0) {
            EXPECT_LT(max_corner_error(found[0].corners, truth), 0.3)
                << dist << " m, yaw " << yaw << ", roll " << roll << ", distort " << distort;
          }
          errors.push_back(err);
        }
      }
    }
  }
  std::sort(errors.begin(), errors.end());
  EXPECT_LT(errors[errors.size() / 2], 0.1);
  RecordProperty("median_corner_error_px", std::to_string(errors[errors.size() / 2]));
}

// With the camera model: the pose's distance within 1% at 1 m, under noise
// and blur, and the outer corners through the lens model.
TEST(Frame8, PoseDistanceWithinOnePercentAtOneMetre) {
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  auto det = make_detector(cfg);
  for (int k = 0; k < 12; ++k) {
    const double yaw = -40 + 8.0 * k;
    Scene s = scene(17 * k + 3, 1.0, yaw, 5.0 * k, static_cast<std::uint64_t>(500 + k));
    s.pose.translation.x() = 0.02 * (k % 5 - 2);
    const auto found = detect(*det, render_scene(kCamera, s));
    ASSERT_EQ(found.size(), 1u) << "yaw " << yaw;
    ASSERT_TRUE(found[0].pose.has_value());
    const Eigen::Vector3d t = found[0].pose->best.translation;
    const double truth = s.pose.translation.norm();
    EXPECT_LT(std::abs(t.norm() - truth) / truth, 0.01) << "yaw " << yaw;
    EXPECT_LT(max_corner_error(found[0].corners, project_marker_corners(kCamera, s)), 0.5) << "yaw " << yaw;
    // The best solution's rotation is the true one (not IPPE's flip), away from frontal.
    if (std::abs(yaw) > 15) {
      const Eigen::AngleAxisd diff(found[0].pose->best.rotation.transpose() * s.pose.rotation);
      EXPECT_LT(diff.angle() * 180 / std::numbers::pi, 3.0) << "yaw " << yaw;
    }
  }
}

// Cells under 4 px: the corners from the ring model fitted to every pixel
// the marker's edge reaches (finish_by_model), not from the pattern's
// edges, whose places depend on the pixels' phase there. bench_accuracy's
// scenes, the print with its margin, facing and rolled 45 deg (JPEG 75):
// the median corner error within a tenth of a pixel from 1.6 to 2.2 m
// (measured 0.03 to 0.07 px; from the pattern's edges 0.06 to 0.16).
TEST(Frame8, CornersOfSmallCellsAreFoundToATenthOfAPixel) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.01;
  settings.frames_per_point = 30;
  for (const double roll : {5.0, 45.0}) {
    settings.roll_jitter_deg = roll;
    settings.scene.jpeg_quality = roll > 10 ? 75 : 0;
    for (const double distance : {1.6, 1.9, 2.2}) {
      settings.seed = 2026120702 + static_cast<std::uint64_t>(distance * 10 + roll);
      const EvalResult r = evaluate_point(*det, kCamera, settings, {distance, 0});
      EXPECT_GE(r.detected, 29) << distance << " m, roll " << roll;
      EXPECT_EQ(r.wrong_id, 0);
      EXPECT_LT(r.median_corner_error_px, 0.1) << distance << " m, roll " << roll;
      EXPECT_LT(std::abs(r.median_distance_bias_rel), 0.004) << distance << " m, roll " << roll;
    }
  }
}

// Far, a marker facing the camera is found tilted by the error in its
// hole's squeeze, and always some (a tilt is a length), and so nearer than
// it is: 0.5 % at 2 m. The pose takes the tilt net of the squeeze's
// variance that the pattern fit's scatter gives (shrink_tilt_by_noise).
// bench_accuracy's scenes facing the camera (the print with its margin),
// each pose compared with the one from the same hole's corners without
// the correction.
TEST(Frame8, AFarMarkerFacingTheCameraIsNotFoundTiltedAndNearer) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.01;
  std::mt19937_64 rng(2026120701);
  std::uniform_real_distribution<double> unit(0, 1);
  const auto view_angle = [](const MarkerPose& p) {
    return std::acos(std::clamp(p.rotation.col(2).dot(-p.translation.normalized()), -1.0, 1.0)) * 180 /
           std::numbers::pi;
  };
  std::vector<double> bias, bias_uncorrected, tilt, tilt_uncorrected;
  for (const double distance : {2.0, 2.1, 2.2}) {
    for (int k = 0; k < 30; ++k) {
      Scene s = settings.scene;
      s.id = 1 + static_cast<int>(unit(rng) * 254);
      // On the optical axis to within a few pixels, at any sub-pixel phase:
      // the marker faces its line of sight.
      s.pose = facing_pose(distance, 0, 0, 10 * (2 * unit(rng) - 1), 0.006 * (2 * unit(rng) - 1),
                           0.006 * (2 * unit(rng) - 1));
      s.seed = rng();
      const auto found = detect(*det, render_scene(kCamera, s));
      if (found.size() != 1 || found[0].id != s.id) continue;
      ASSERT_TRUE(found[0].pose && found[0].inner_corners);
      const auto uncorrected = estimate_square_pose(kCamera, *found[0].inner_corners, 0.08 * 0.7);
      ASSERT_TRUE(uncorrected.has_value());
      const double truth = s.pose.translation.norm();
      bias.push_back(found[0].pose->best.translation.norm() / truth - 1);
      bias_uncorrected.push_back(uncorrected->best.translation.norm() / truth - 1);
      tilt.push_back(view_angle(found[0].pose->best) - view_angle(s.pose));
      tilt_uncorrected.push_back(view_angle(uncorrected->best) - view_angle(s.pose));
    }
  }
  ASSERT_GE(bias.size(), 80U);
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  RecordProperty("median_distance_bias_percent", std::to_string(median(bias) * 100));
  RecordProperty("median_distance_bias_uncorrected_percent", std::to_string(median(bias_uncorrected) * 100));
  // Measured: the tilt's median 6.6 -> 3.4 deg, the distance's -0.54 ->
  // -0.38 %. What is left is not noise but the pattern's edges measured
  // off by the pixels' phase (the same frame without noise is as far off).
  // Measured: the tilt's median 4.2 deg uncorrected, -0.07 corrected; the
  // distance's -0.28 and -0.18 %. (With the corners from the pattern's
  // edges, before the ring model gave them at these sizes: 6.6 and 3.4
  // deg, -0.54 and -0.38 %: the edges measured off by the pixels' phase.)
  EXPECT_GT(median(tilt_uncorrected), 3.0) << "the tilt this is about";
  EXPECT_LT(std::abs(median(tilt)), 1.0);
  EXPECT_LT(median(bias_uncorrected), -0.002);
  EXPECT_LT(std::abs(median(bias)), 0.003);
  EXPECT_GT(median(bias) - median(bias_uncorrected), 0.0005);
}

// At 2.6 m the thesis's 8 cm marker is 16 px wide: a cell is 1.6 px and the
// black line under a pixel, too thin against the blur for its edge to be
// found by the gradient. Read through the fitted edge profiles.
TEST(Frame8, CellsOfOnePointSixPixelsAreRead) {
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  auto det = make_detector(cfg);
  std::mt19937 rng(26);
  std::uniform_int_distribution<int> any_id(1, 254);
  std::uniform_real_distribution<double> jitter(-1, 1);
  constexpr int kFrames = 30;
  int found_right = 0, wrong = 0;
  std::string misreads;
  for (int k = 0; k < kFrames; ++k) {
    Scene s = scene(any_id(rng), 2.6, 0, 5 * jitter(rng), static_cast<std::uint64_t>(2600 + k));
    s.pose.translation.x() = 0.1 * jitter(rng);
    s.pose.translation.y() = 0.1 * jitter(rng);
    for (const Detection& d : detect(*det, render_scene(kCamera, s))) {
      if (d.id == s.id) {
        ++found_right;
        EXPECT_LT(mean_corner_error(d.corners, project_marker_corners(kCamera, s)), 1.0) << "frame " << k;
      } else {
        ++wrong;
        misreads +=
            " frame " + std::to_string(k) + ": id " + std::to_string(d.id) + " for " + std::to_string(s.id) + ";";
      }
    }
  }
  // Measured: 25 found, 1 misread (without the fitted profiles and the
  // unmixed ring samples: 16 found, 4 misread; without the unmixing alone:
  // 20 found, 4 misread).
  EXPECT_GE(found_right, 23);
  EXPECT_LE(wrong, 2) << misreads;
}

// A marker turned 75 to 80 degrees shows its short edges as cells of about
// a pixel, with the background beside its corners: the orientation comes
// from the short edges' profiles where the corners' samples are mixed. The
// benchmark's scenes (bench_accuracy), two seeds: the 80 degrees
// at 0.5 m and 75 at 0.95 m.
TEST(Frame8, MarkerTurnedFarIsOrientedByItsShortEdges) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  int detected = 0, frames = 0, wrong = 0;
  for (const std::uint64_t seed : {1, 3}) {
    settings.seed = seed;
    for (const EvalPoint point : {EvalPoint{0.5, 80}, EvalPoint{0.95, 75}}) {
      const EvalResult r = evaluate_point(*det, kCamera, settings, point);
      detected += r.detected;
      frames += r.frames;
      wrong += r.wrong_id;
    }
  }
  // Measured: 174 of 200 (182 when clearly read corners were taken without
  // the short edges' check, which let a sliver of clutter through:
  // HalfTurnSymmetricSliverIsNotRead).
  EXPECT_GE(detected, 170) << "of " << frames;
  EXPECT_EQ(wrong, 0);
}

// The ring of a marker squashed into a sliver (the width of a marker turned
// about 84 degrees) but symmetric under a half turn, with four dark
// corners: both long edges read the same code, as a light outline in
// clutter does, and only the short edges could tell it from a marker,
// whose cells here are finer than a pixel. Found in the benchmark's
// clutter (seed 1, 0.5 m, frame 31: id 126 reported for a white outline).
TEST(Frame8, HalfTurnSymmetricSliverIsNotRead) {
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  auto det = make_detector(cfg);
  std::mt19937 rng(7);
  int reported = 0;
  for (int trial = 0; trial < 60; ++trial) {
    // Cells: 0 black, 1 white; the ring's top row is random and the rest
    // follows from the half turn; the line black, the hole white.
    std::array<std::array<int, 10>, 10> cell{};
    for (auto& row : cell) row.fill(1);
    for (int c = 1; c <= 8; ++c) cell[0][static_cast<std::size_t>(c)] = static_cast<int>(rng() & 1U);
    for (int r = 1; r <= 8; ++r) cell[static_cast<std::size_t>(r)][0] = static_cast<int>(rng() & 1U);
    cell[0][0] = cell[0][9] = 0;
    for (int r = 0; r < 10; ++r) {
      for (int c = 0; c < 10; ++c) {
        if (r == 0 || c == 0)
          cell[static_cast<std::size_t>(9 - r)][static_cast<std::size_t>(9 - c)] =
              cell[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)];
      }
    }
    const double width = std::uniform_real_distribution<double>(6.5, 10.0)(rng);
    const double height = std::uniform_real_distribution<double>(45.0, 75.0)(rng);
    const double angle = std::uniform_real_distribution<double>(-0.4, 0.4)(rng);
    const double dark = std::uniform_real_distribution<double>(10, 60)(rng);
    const double light = std::uniform_real_distribution<double>(170, 240)(rng);
    const double background = std::uniform_real_distribution<double>(20, 200)(rng);
    const double cx = 320 + std::uniform_real_distribution<double>(-0.5, 0.5)(rng), cy = 240;
    cv::Mat img(480, 640, CV_32F, cv::Scalar(background));
    const double ca = std::cos(angle), sa = std::sin(angle);
    constexpr int kSamples = 4;
    for (int y = 150; y < 330; ++y) {
      for (int x = 260; x < 380; ++x) {
        double sum = 0;
        for (int j = 0; j < kSamples; ++j) {
          for (int i = 0; i < kSamples; ++i) {
            const double dx = x - 0.5 + (i + 0.5) / kSamples - cx, dy = y - 0.5 + (j + 0.5) / kSamples - cy;
            const double gx = (ca * dx + sa * dy) / width * 10 + 5, gy = (-sa * dx + ca * dy) / height * 10 + 5;
            double v = background;
            if (gx >= 0 && gx < 10 && gy >= 0 && gy < 10) {
              const double in = std::min(std::min(gx, 10 - gx), std::min(gy, 10 - gy));
              if (in >= 1.5) {
                v = light;
              } else if (in >= 1.0) {
                v = dark;
              } else {
                v = cell[static_cast<std::size_t>(gy)][static_cast<std::size_t>(gx)] ? light : dark;
              }
            }
            sum += v;
          }
        }
        img.at<float>(y, x) = static_cast<float>(sum / (kSamples * kSamples));
      }
    }
    cv::GaussianBlur(img, img, cv::Size(0, 0), 0.6);
    cv::Mat noise(img.size(), CV_32F);
    cv::randn(noise, 0, 2);
    img += noise;
    GreyImage grey(640, 480);
    for (int y = 0; y < 480; ++y) {
      for (int x = 0; x < 640; ++x) {
        grey.row(y)[x] = static_cast<std::uint8_t>(std::clamp(std::lround(img.at<float>(y, x)), 0L, 255L));
      }
    }
    for (const Detection& d : detect(*det, grey)) {
      ++reported;
      ADD_FAILURE() << "trial " << trial << ": " << width << " x " << height << " px read as id " << d.id;
    }
  }
  EXPECT_EQ(reported, 0);
}

// The benchmark's scene in which the sliver above was found: nothing but
// the marker, and never another id.
TEST(Frame8, BenchmarkClutterGivesNoWrongIdAtHalfAMetre) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.seed = 1;
  const EvalResult r = evaluate_point(*det, kCamera, settings, {0.5, 0});
  EXPECT_EQ(r.wrong_id, 0);
  EXPECT_EQ(r.detected, r.frames);
}

// bench_accuracy's scenes with the print glued onto a cover frame, the
// insert behind its opening, `frames` a point from `seed`.
EvalSettings on_cover_frame(const CoverFrame& frame, Insert insert, int frames, std::uint64_t seed) {
  EvalSettings settings = benchmark_settings();
  settings.scene.frame = frame;
  settings.scene.insert = insert;
  settings.frames_per_point = frames;
  settings.seed = seed;
  return settings;
}

// The print glued onto a socket's rounded cover frame (issue 18): its hole
// shows the outlet's plate with the dark recess and pins inside, its line
// lies on the inner roll and its hole's corners are rounded. Facing, from
// 0.4 to 1.4 m, every id class: found, never another id, and the pose's
// distance (to the plane of the frame's flat band) within 2%.
TEST(Frame8, MarkerOnASocketFrameFacing) {
  auto det = make_detector(posed_config());
  const EvalSettings settings = on_cover_frame(socket_frame(), Insert::socket, 10, 11);
  int detected = 0, frames = 0, wrong = 0;
  for (const double d : {0.4, 0.6, 0.8, 1.1, 1.4, 1.7, 1.75}) {
    const EvalResult r = evaluate_point(*det, kCamera, settings, {d, 0});
    detected += r.detected;
    frames += r.frames;
    wrong += r.wrong_id;
    if (r.detected > 0) {
      EXPECT_LT(r.median_distance_error_rel, 0.02) << d << " m";
    }
  }
  // Measured: 68 of 70 (none before the hole's quad allowed rounded
  // corners and a dark recess inside it). From 1.7 m cells are under
  // 2.5 px and the ring model confirms each read: bench_accuracy found 38%
  // at 1.7 m (96% now) while the check also held the socket's shaded line
  // to be as dark as ink.
  EXPECT_GE(detected, 62) << "of " << frames;
  EXPECT_EQ(wrong, 0);
}

// The socket frame facing from 2.0 and 2.2 m: the hole, 14 px across, is
// the outlet's face round its dark recess, a light ridge two or three
// pixels wide that the first look's threshold thins to its crest and
// breaks; the second look keeps it whole (segmentation.cpp, the valley
// rule).
TEST(Frame8, MarkerOnASocketFrameFromTwoMetres) {
  auto det = make_detector(posed_config());
  const Tally t = evaluate_facing(*det, on_cover_frame(socket_frame(), Insert::socket, 20, 21), {2.0, 2.2});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 38 of 40 (17 with the first look alone).
  EXPECT_GE(t.detected, 34) << "of " << t.frames;
}

// The print on a light switch's frame (issue 18), near: the rocker, lighter
// than the frame's roll and parted from the line by its shadow, is the hole's
// light component, a fraction of a cell inside the line all round; read
// grown by a quarter cell at a time. 0.3 to 0.6 m, every id class.
TEST(Frame8, MarkerOnASwitchFrameNear) {
  auto det = make_detector(posed_config());
  const Tally t = evaluate_facing(*det, on_cover_frame(switch_frame(), Insert::rocker, 10, 12), {0.3, 0.4, 0.5, 0.6});
  // Measured: 38 of 40; 5 before the grown reads.
  EXPECT_GE(t.detected, 34) << "of " << t.frames;
  EXPECT_EQ(t.wrong, 0);
}

// A socket frame turned: `per_view` frames at each distance and yaw, ids
// and seeds running on from `seed`. A read counts when it has the right id
// and orientation and its corners lie within `corner_cells` of the truth
// (the print's outer edge lies on the outer roll, bent away from the flat
// band whose square the corners are extrapolated on: up to 3.5 px off at
// 0.5 m and 30 deg); any other read is a failure.
struct SocketView {
  double distance, yaw;
};
struct SocketReads {
  int frames = 0, detected = 0, wrong = 0;
};
SocketReads read_turned_socket(std::initializer_list<SocketView> views, int per_view, std::uint64_t seed,
                               double corner_cells = 0.5) {
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  auto det = make_detector(cfg);
  SocketReads reads;
  for (const SocketView v : views) {
    for (int k = 0; k < per_view; ++k) {
      const int id = static_cast<int>((seed * 37) % 254) + 1;
      Scene s = scene(id, v.distance, v.yaw, 0, ++seed);
      s.frame = socket_frame();
      s.insert = Insert::socket;
      const Quad truth = project_marker_corners(kCamera, s);
      const double tolerance = corner_cells * distance(truth[0], truth[3]) / frame8::grid;
      ++reads.frames;
      for (const Detection& f : detect(*det, render_scene(kCamera, s))) {
        if (f.id != id || f.quarter_turns != 0 || max_corner_error(f.corners, truth) > tolerance) {
          ++reads.wrong;
          ADD_FAILURE() << "id " << f.id << " for " << id << " turns " << f.quarter_turns << " at " << v.distance
                        << " m, yaw " << v.yaw << ", corners off by " << max_corner_error(f.corners, truth);
          continue;
        }
        ++reads.detected;
      }
    }
  }
  return reads;
}

// The socket frame turned (issue 18), 10 and 20 deg either way, at 0.5
// and 0.95 m.
TEST(Frame8, MarkerOnASocketFrameTurned) {
  const SocketReads r = read_turned_socket(
      {{0.5, -20}, {0.5, -10}, {0.5, 10}, {0.5, 20}, {0.95, -20}, {0.95, -10}, {0.95, 10}, {0.95, 20}}, 4, 70);
  // Measured: 30 of 32 since a hole read off its ring is read again on
  // the grid fitted to the ring's own edges (ring_edges.cpp); 24 before.
  EXPECT_GE(r.detected, 28) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

// The socket frame turned further, 25 and 30 deg either way at 0.5 m, 30
// and 35 deg at 0.95 m: the line's corner nearest the camera lies on the
// inner roll's bend, lit or shaded unlike the rest of the line, and one
// such light corner of four is allowed, or two on one side
// (decode_checks.cpp); the hole seen is shifted against the ring by the
// roll shown on one side and hidden on the other, and its rounded corners
// come out unevenly (quad_fit.cpp).
TEST(Frame8, MarkerOnASocketFrameTurnedFurther) {
  const SocketReads r = read_turned_socket(
      {{0.5, -30}, {0.5, -25}, {0.5, 25}, {0.5, 30}, {0.95, -35}, {0.95, -30}, {0.95, 30}, {0.95, 35}}, 8, 170);
  // Measured: 64 of 64 (58 before one side was allowed without its line,
  // decode_checks.cpp). At 0.5 m 32 of 32 (27 before a hole read off its
  // ring was read again on the ring's own edges, ring_edges.cpp; 23 before
  // the ring cells were sampled clear of the outer roll and two light
  // corners on one side allowed; 11 before one light corner was); at
  // 0.95 m 32 of 32 (bench_accuracy found 40% at 30 deg and 72% at 35
  // before holes of 20 to 30 px could have rounded corners).
  EXPECT_GE(r.detected, 60) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

// The socket frame turned 40 and 45 deg either way at 0.5 m: the inner
// roll facing the camera shows as a light band parted from the hole by
// the roll's shaded fold, and the hole's component ends a cell short of
// the line on that side; grown over the band, it reads (roll_fold.cpp).
// The corners within a cell: the outer roll, bent away, lies across a
// third of the ring's cells and the pattern fit leans on the rest (0.8
// of a cell off at worst here, 0.4 mostly).
TEST(Frame8, MarkerOnASocketFrameTurnedPastTheFold) {
  const SocketReads r = read_turned_socket({{0.5, -45}, {0.5, -40}, {0.5, 40}, {0.5, 45}}, 8, 270, 1.0);
  // Measured: 32 of 32 (24 before one side was allowed without its line,
  // decode_checks.cpp; none before the hole was grown over the band;
  // bench_accuracy: 4% at 40 and 45 deg before, 96 and 100% now).
  EXPECT_GE(r.detected, 29) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

// The socket frame turned 50 deg either way at 0.5 m: the far side's line
// lies on the inner roll turned away from the camera, hidden behind the
// fold, and a read with no cell outvoted and two clear votes for every bit
// is taken without it (decode_checks.cpp).
TEST(Frame8, MarkerOnASocketFrameTurnedWithTheFarLineHidden) {
  const SocketReads r = read_turned_socket({{0.5, -50}, {0.5, 50}}, 16, 370, 1.0);
  // Measured: 27 of 32 (11 before).
  EXPECT_GE(r.detected, 23) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

// The socket frame turned 60 deg either way at 0.5 m: the outlet's face
// round its recess and the insert's side wall beside it, parted by shaded
// edges that meet the line, leave the hole in two or three pieces, which
// are read as one (hole_fragments.cpp).
TEST(Frame8, MarkerOnASocketFrameTurnedWithTheHoleInPieces) {
  const SocketReads r = read_turned_socket({{0.5, -60}, {0.5, 60}}, 16, 570, 1.0);
  // Measured: 27 of 32 (23 while the ring-edge fit started from the hole
  // moved back 0.6 of a cell times the turn's tangent, ring_edges.cpp; 11
  // before boxes could overlap along the parting and a third piece
  // complete a pair).
  EXPECT_GE(r.detected, 25) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

// The socket frame turned 40 deg at 0.95 m and 45 deg at 0.72 m, either
// way: the hole seen is the line's inner edge on the inner roll, below the
// ring's plane, and seen turned it lies 0.3 to 0.5 of a cell towards the
// far side; the grid is fitted to the ring's edges from the hole moved
// back by the roll's depth (ring_edges.cpp).
TEST(Frame8, MarkerOnASocketFrameTurnedWithTheHoleDisplacedByTheRoll) {
  const SocketReads r = read_turned_socket({{0.95, -40}, {0.95, 40}, {0.72, -45}, {0.72, 45}}, 8, 470, 1.0);
  // Measured: 32 of 32 (22 before the fit started from the hole moved back).
  EXPECT_GE(r.detected, 28) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
}

struct CoveredSideReads {
  int frames = 0, detected = 0, wrong = 0, ambiguity_wrong = 0, corners_off = 0;
};

// Each side covered, six ids, at each of `distances` and `yaws` (by
// default 0.5 to 1.1 m, yaw -15 to 15 deg), the marker rolled by
// `roll_deg` in its plane; with the thesis camera or without a camera model
// (the image then without the lens's distortion). The object has the given
// reflectance (paper's is 0.88), and the print a paper margin of `margin_m`
// around the marker; the detector segments an image decimated by
// `decimate` (0: its own choice). With a camera the seen side's corners
// must be within `camera_corner_px` of the truth.
CoveredSideReads read_covered_sides(bool with_camera, double roll_deg, float reflectance = 0.1F, double margin_m = 0,
                                    int decimate = 0, double camera_corner_px = 1.0,
                                    std::initializer_list<double> distances = {0.5, 0.8, 1.1},
                                    std::initializer_list<double> yaws = {-15.0, 0.0, 15.0},
                                    Mounting mounting = Mounting::any) {
  DetectorConfig cfg;
  cfg.frame8.decimate = decimate;
  cfg.frame8.mounting = mounting;
  if (with_camera) {
    cfg.camera = kCamera;
    cfg.marker_size_m = 0.08;
  }
  auto det = make_detector(cfg);
  constexpr std::array<int, 6> kIds{3, 77, 128, 165, 200, 254};
  CoveredSideReads out;
  std::uint64_t seed = 40;
  for (const MarkerSide side : {MarkerSide::top, MarkerSide::right, MarkerSide::bottom, MarkerSide::left}) {
    // C1, the white corner, is the top-right one.
    const bool c1_hidden = side == MarkerSide::top || side == MarkerSide::right;
    for (const double d : distances) {
      for (const double yaw : yaws) {
        const int id = kIds[static_cast<std::size_t>(seed % kIds.size())];
        Scene s = scene(id, d, yaw, roll_deg, ++seed);
        s.distort = with_camera;
        s.paper_margin_m = margin_m;
        s.occluders.push_back(side_occluder(side, s.marker_size_m, 0.2, reflectance));
        const Quad truth = project_marker_corners(kCamera, s);
        ++out.frames;
        bool found = false;
        for (const Detection& f : detect(*det, render_scene(kCamera, s))) {
          if (f.id != id) {
            ++out.wrong;
            ADD_FAILURE() << "id " << f.id << " for " << id << " at " << d << " m, yaw " << yaw << ", roll " << roll_deg
                          << ", side " << static_cast<int>(side) << ", reflectance " << reflectance;
            continue;
          }
          found = true;
          // Ambiguous only where the white corner is hidden. An object in
          // front, seen turned, may leave the corner in view: an
          // orientation stated then must be the marker's (the corners below).
          if (f.orientation_ambiguous && !c1_hidden) {
            ++out.ambiguity_wrong;
            ADD_FAILURE() << "orientation ambiguous with C1 seen: side " << static_cast<int>(side) << " at " << d
                          << " m, yaw " << yaw << ", roll " << roll_deg;
          }
          if (f.orientation_ambiguous) continue;
          // The seen side's corners are measured (in the marker's own
          // order: right only when the orientation is); the hidden side's
          // follow from how far the hole reaches behind the cover, which
          // the neighbouring edges' cells fix only where they change colour
          // (measured here: up to 0.8 of a cell off; not asserted).
          const auto s_index = static_cast<std::size_t>(side);
          const std::size_t seen_a = (s_index + 2) % 4, seen_b = (s_index + 3) % 4;
          const double seen_error =
              std::max(distance(f.corners[seen_a], truth[seen_a]), distance(f.corners[seen_b], truth[seen_b]));
          // Without a camera the hole's perspective beyond the cover is
          // extrapolated from the quad seen, which tilts the seen side's
          // corners too: under a third of a cell (measured: up to 0.28,
          // 0.18 before the ring cells were sampled clear of their outer
          // quarter, which moves the run of depths that read).
          const double cell_px = distance(truth[0], truth[1]) / frame8::grid;
          if (seen_error > (with_camera ? camera_corner_px : 0.33 * cell_px)) {
            ++out.corners_off;
            ADD_FAILURE() << "side " << static_cast<int>(side) << " at " << d << " m, yaw " << yaw << ", roll "
                          << roll_deg << ": seen corners off by " << seen_error << " px";
          }
        }
        out.detected += found;
      }
    }
  }
  return out;
}

// One side of the marker hidden by a dark object in front of it (issue 18):
// its ring, its line and half a cell of the hole, as the figure
// has it. The hole's component then ends at the object's edge; the other
// three edges still vote every bit. Each side, ids of every kind, near and
// far, turned either way: found, never another id. Where the white corner
// is hidden the orientation is one of two and must say so; where it is seen
// the orientation and the corners are the marker's.
TEST(Frame8, MarkerWithOneSideCoveredByADarkObject) {
  const CoveredSideReads r = read_covered_sides(true, 0);
  // Measured: 34 of 36. Before the reads with a side hidden, the same
  // covers in bench_accuracy (--cover each) were found in 15 to 20% of frames.
  EXPECT_GE(r.detected, 31) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
  EXPECT_EQ(r.ambiguity_wrong, 0);
  EXPECT_EQ(r.corners_off, 0);
}

// The same without a camera model, and the marker in each of its other
// orientations (rolled a quarter turn at a time).
TEST(Frame8, MarkerWithOneSideCoveredWithoutACameraInEveryOrientation) {
  for (const double roll : {90.0, 180.0, 270.0}) {
    const CoveredSideReads r = read_covered_sides(false, roll);
    // Measured: 34, 34 and 35 of 36.
    EXPECT_GE(r.detected, 31) << "of " << r.frames << ", roll " << roll;
    EXPECT_EQ(r.wrong, 0) << "roll " << roll;
    EXPECT_EQ(r.ambiguity_wrong, 0) << "roll " << roll;
    EXPECT_EQ(r.corners_off, 0) << "roll " << roll;
  }
}

// One side hidden by an object as light as the paper (issue 18), over a
// print with its paper margin: the hole's light pixels run on into the
// object's and the margin's, so the hole has no component of its own and
// no quad. It is found as the U of the line's three visible sides
// (open_hole.cpp) and read with the open side hidden.
TEST(Frame8, MarkerWithOneSideCoveredByALightObject) {
  const CoveredSideReads r = read_covered_sides(true, 0, 0.8F, 0.01);
  // Measured: 34 of 36 (before the open holes and the light ring taken
  // for covered: 29, each found where parallax left the line in view).
  EXPECT_GE(r.detected, 31) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
  EXPECT_EQ(r.ambiguity_wrong, 0);
  EXPECT_EQ(r.corners_off, 0);
}

TEST(Frame8, MarkerWithOneSideCoveredByALightObjectWithoutACameraInEveryOrientation) {
  for (const double roll : {90.0, 180.0, 270.0}) {
    const CoveredSideReads r = read_covered_sides(false, roll, 0.8F, 0.01);
    // Measured: 33 of 36 at each roll.
    EXPECT_GE(r.detected, 31) << "of " << r.frames << ", roll " << roll;
    EXPECT_EQ(r.wrong, 0) << "roll " << roll;
    EXPECT_EQ(r.ambiguity_wrong, 0) << "roll " << roll;
    EXPECT_EQ(r.corners_off, 0) << "roll " << roll;
  }
}

// The same on a working image decimated by 2, as for frames of over 1.3
// megapixels. Outlines are traced on it halved again, and an open hole must
// span 40 px there (cells of 5.7 px: a 1920x1440 camera's marker to about
// 2 m): of these frames, those at 0.5 m (58 px). The seen corners were
// measured up to 1.08 px off at 0.5 m (a seventh of a cell): the hole's far
// side behind the object is placed less well from the coarser outline.
TEST(Frame8, MarkerWithOneSideCoveredByALightObjectOnADecimatedImage) {
  const CoveredSideReads r = read_covered_sides(true, 0, 0.8F, 0.01, 2, 1.5);
  // Measured: 15 of 36 (34 at full resolution, above): the twelve at
  // 0.5 m, and three further off whose line the object left in view.
  EXPECT_GE(r.detected, 12) << "of " << r.frames;
  EXPECT_EQ(r.wrong, 0);
  EXPECT_EQ(r.ambiguity_wrong, 0);
  EXPECT_EQ(r.corners_off, 0);
}

// Covered far and turned: from 1.2 m turned 30 deg either way, and from
// 1.4 m facing, the cells are 2.9 to 3 px across, read with the covered
// side hidden only where the whole pattern the read predicts is found
// (hidden_side.cpp). Dark and light objects, the latter over the print's
// margin.
TEST(Frame8, MarkerWithOneSideCoveredFarAndTurned) {
  const CoveredSideReads dark = read_covered_sides(true, 0, 0.1F, 0, 0, 1.0, {1.2}, {-30.0, -27.0, 27.0, 30.0});
  const CoveredSideReads dark_far = read_covered_sides(true, 0, 0.1F, 0, 0, 1.0, {1.4}, {-5.0, 0.0, 5.0});
  const CoveredSideReads light = read_covered_sides(true, 0, 0.8F, 0.01, 0, 1.0, {1.2}, {-30.0, -27.0, 27.0, 30.0});
  const CoveredSideReads light_far = read_covered_sides(true, 0, 0.8F, 0.01, 0, 1.0, {1.4}, {-5.0, 0.0, 5.0});
  const int detected = dark.detected + dark_far.detected + light.detected + light_far.detected;
  const int frames = dark.frames + dark_far.frames + light.frames + light_far.frames;
  // Measured: 42 of 56 (17 while cells under 3 px were not read with a
  // side hidden).
  EXPECT_GE(detected, 37) << "of " << frames;
  for (const CoveredSideReads& r : {dark, dark_far, light, light_far}) {
    EXPECT_EQ(r.wrong, 0);
    EXPECT_EQ(r.ambiguity_wrong, 0);
    EXPECT_EQ(r.corners_off, 0);
  }
}

// The benchmark's covered sides far off and turned (bench_accuracy --cover
// each, seed 1, 1.2 m): turned 30 deg, the dark object 3 cm in front hides
// more than half the hole, and a quad of what is left read id 64 for 80,
// one bit wrong, by outvoting the covered edge with cells 1.6 px across.
TEST(Frame8, CoveredSideFarOffGivesNoWrongId) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.clutter = true;
  settings.frames_per_point = 20;
  settings.seed = 1;
  for (const MarkerSide side : {MarkerSide::top, MarkerSide::right, MarkerSide::bottom, MarkerSide::left}) {
    settings.occluder_turns.push_back({side_occluder(side, 0.08)});
  }
  int wrong = 0;
  for (const double yaw : {0.0, 10.0, 20.0, 30.0})
    wrong += evaluate_point(*det, kCamera, settings, {1.2, yaw}).wrong_id;
  EXPECT_EQ(wrong, 0);
}

// Far off (2.6 to 3.0 m, cells of 1.4 to 1.6 px), a quad whose first read
// fails is measured again (the step-only sides, the profile fit), and a
// read of that second measurement alone put all four edges on a wrong code
// about once in a hundred frames (bench_accuracy, seeds 1 to 4 at 2.3 to
// 3.0 m: 10 wrong ids in 1600 frames). They were refused where the second
// pass could not confirm them (340 of these 400 found); now the ring
// model confirms every read under 2.5 px a cell instead. These are seed
// 4's frames, which held 2 of them.
TEST(Frame8, FarReadsOfARemeasuredQuadGiveNoWrongId) {
  DetectorConfig cfg = posed_config();
  cfg.frame8.blur_sigma_px = 0.6;
  auto det = make_detector(cfg);
  EvalSettings settings = benchmark_settings();
  settings.scene.clutter = true;
  settings.frames_per_point = 50;
  settings.seed = 4;
  const Tally t = evaluate_facing(*det, settings, {2.3, 2.4, 2.5, 2.6, 2.7, 2.8, 2.9, 3.0});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 367 of 400.
  EXPECT_GE(t.detected, 340);
}

// The print as `markerctl marker` makes it, 10 mm of white paper around the
// marker, far off (2.2 to 2.7 m, cells of 1.5 to 1.9 px): a lone cell
// between the paper, a corner and a cell of the other colour was sampled
// wrong on all four edges alike, and clutter folded into a quad read as id
// 1 or 128. Bench_accuracy, seed 1, 500 frames a point at 2.0 to 3.0 m:
// 14 wrong ids in 5,500 frames; in the first 300 frames at 2.2, 2.6 and
// 2.7 m (these), 5. The ring model must confirm small cells' reads, and
// the corners must make a convex quad.
TEST(Frame8, FarMarkersPrintedWithAPaperMarginGiveNoWrongId) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.010;
  settings.frames_per_point = 300;
  const Tally t = evaluate_facing(*det, settings, {2.2, 2.6, 2.7});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 745 of 900 (703 before the second pass took three points a
  // cell; 706 and 5 wrong ids without the checks).
  EXPECT_GE(t.detected, 660) << "of " << t.frames;
}

// A marker rolled 45 deg in the image and then turned far is squeezed
// across a diagonal: every cell is narrow (1.4 px at 0.95 m turned 75 deg)
// while the sides stay long, all four edges vote, and no short edge's
// profile checks the code. bench_accuracy --roll 45 --jpeg 75 --margin 10
// --seed 103: 252 read as 124 there, with cells of 2.8 px on average.
// Such reads are confirmed as small cells' are (confirming_cell_size).
TEST(Frame8, MarkersSqueezedAcrossADiagonalGiveNoWrongId) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.010;
  settings.scene.jpeg_quality = 75;
  settings.scene.clutter = true;
  settings.roll_jitter_deg = 45;
  settings.frames_per_point = 25;
  settings.seed = 103;
  int wrong = 0, detected = 0, frames = 0;
  for (const double yaw : {70.0, 75.0, 80.0}) {
    const EvalResult r = evaluate_point(*det, kCamera, settings, {0.95, yaw});
    wrong += r.wrong_id;
    detected += r.detected;
    frames += r.frames;
  }
  EXPECT_EQ(wrong, 0);
  // Measured: 33 of 75 (34 and the wrong id without the confirmation).
  EXPECT_GE(detected, 30) << "of " << frames;
}

// The print with its 10 mm margin under a lens out of focus, 300 frames a point.
EvalSettings print_under_a_defocus_disc() {
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.010;
  settings.scene.blur_model = BlurModel::disc;
  settings.frames_per_point = 300;
  return settings;
}

// Beyond 2.7 m (cells of 1.5 px and less) under a lens out of focus (a
// disc of 1.2 px), the sides' first measurement comes out up to a tenth
// of the marker small, and a grid so placed reads each edge's end cells
// half on their neighbours: 189 as 60, every cell clear. Such a read must
// be confirmed by the second measurement, which follows the code. Seed 1,
// 300 frames a point: 4 wrong ids without it.
TEST(Frame8, FarMarkersUnderADefocusDiscGiveNoWrongId) {
  auto det = make_detector(posed_config());
  const Tally t = evaluate_facing(*det, print_under_a_defocus_disc(), {2.7, 2.9, 3.0});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 204 of 900 (285 and 4 wrong ids without the confirmation).
  EXPECT_GE(t.detected, 180) << "of " << t.frames;
}

// The ring model's own reads (its look, where the others found nothing)
// under a lens further out of focus than the detector was told: a disc of
// 1.6 px over cells of 1.6 px, told a Gaussian of 0.6 px. The model then
// spreads each cell too little, and a lone cell reads as its neighbours on
// every edge alike: 7 wrong ids in these 400 frames without the check that
// the told blur fits the pixels better than a heavier one
// (confirm_at_told_blur).
TEST(Frame8, ModelReadsUnderABlurHeavierThanToldGiveNoWrongId) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.blur_model = BlurModel::disc;
  settings.scene.blur_sigma_px = 0.8;
  settings.roll_jitter_deg = 45;
  settings.frames_per_point = 200;
  settings.seed = 7;
  const Tally t = evaluate_facing(*det, settings, {2.5, 2.6});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 70 of 400, the sampled reads' (the model's are refused).
  EXPECT_GE(t.detected, 50) << "of " << t.frames;
}

// Cells of 3.1 to 3.4 px (1.20 to 1.35 m) under a lens out of focus (a disc
// of 1.2 px), the print with its paper margin: the blur reaches the cell
// samples a quarter cell from the centre, and a fifth of the markers had
// too few confident votes (81 to 91% at 100 frames a point, 100% at 1.0
// and 1.4 m). Every id, 50 frames a point.
TEST(Frame8, CellsOfThreeToFourPixelsUnderADefocusDiscAreRead) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.paper_margin_m = 0.010;
  settings.scene.blur_model = BlurModel::disc;
  const Tally t = evaluate_facing(*det, settings, {1.20, 1.25, 1.30, 1.35});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 200 of 200 (173 with the confident share of resolved cells).
  EXPECT_GE(t.detected, 194) << "of " << t.frames;
}

// Ids of each bit pattern: top bit set and clear, runs of white and of
// black cells, alternating.
constexpr std::array<int, 6> kBitPatternIds{0b10000001, 0b01111110, 0b11110000, 0b00001111, 0b10101010, 0b01010101};

// The phase tests' count: frames of one marker each, found with its id or
// not, and any other id read.
struct PhaseTally {
  int frames = 0, found = 0, wrong = 0;
  std::string missed;

  void look(MarkerDetector& det, const Scene& s, const std::string& where) {
    ++frames;
    bool right = false;
    for (const Detection& d : detect(det, render_scene(kCamera, s))) {
      right = right || d.id == s.id;
      wrong += d.id != s.id;
    }
    found += right;
    if (!right) missed += " id " + std::to_string(s.id) + " " + where + ";";
  }
};

// Issue 19's phase invariance: a marker moved across a whole pixel in
// steps of 0.05 px, in x and in y, is found at every phase, for ids of
// each bit pattern: top bit set and clear, runs of white and of black
// cells, alternating. At 1.25 m a cell is 3.3 px (the band where a blur of
// a pixel reaches the samples), printed with its paper margin, under the
// Gaussian blur and a defocus disc; and at 1.9 m, 2.2 px.
TEST(Frame8, EverySubPixelPhaseIsReadForEveryBitPattern) {
  auto det = make_detector(posed_config());
  struct Case {
    double distance_m;
    BlurModel blur;
  };
  PhaseTally t;
  for (const Case c : {Case{1.25, BlurModel::gaussian}, Case{1.25, BlurModel::disc}, Case{1.9, BlurModel::gaussian}}) {
    for (const int id : kBitPatternIds) {
      for (int axis = 0; axis < 2; ++axis) {
        for (int step = 0; step < 20; ++step) {
          const double shift_m = 0.05 * step * c.distance_m / kCamera.fx;
          Scene s = scene(id, c.distance_m, 0, 0, 1000 + static_cast<std::uint64_t>(t.frames));
          s.pose = facing_pose(c.distance_m, 0, 0, 0, axis == 0 ? shift_m : 0, axis == 1 ? shift_m : 0);
          s.paper_margin_m = 0.010;
          s.blur_model = c.blur;
          t.look(*det, s,
                 std::to_string(c.distance_m) + " m" + (axis ? " y+" : " x+") + std::to_string(0.05 * step) + " px");
        }
      }
    }
  }
  EXPECT_EQ(t.wrong, 0);
  // 99% at every phase: at most 7 misses in the 720 frames. Measured: 717
  // (694 with the confident share of resolved cells from 3 px).
  EXPECT_GE(t.found, t.frames - t.frames / 100) << "of " << t.frames << ", missed:" << t.missed;
}

// Issue 19's phase invariance through distance and in-plane turns: the
// marker moved away in 1 mm steps across 1.09 to 1.13 m (cells of 3.6 to
// 3.7 px, where a renderer this project did not write showed a band of
// misses at 1.10 m for ids with the top bit set), and turned in the image
// plane by 3 deg steps through a quarter turn (every in-plane turn, up to
// the code's own quarter turns) at 1.1 and 1.3 m, for ids of each bit
// pattern, printed with the paper margin.
TEST(Frame8, EveryMillimetreAndInPlaneTurnIsReadForEveryBitPattern) {
  auto det = make_detector(posed_config());
  PhaseTally t;
  auto look_at = [&](int id, double distance_m, double roll_deg) {
    Scene s = scene(id, distance_m, 0, roll_deg, 5000 + static_cast<std::uint64_t>(t.frames));
    s.paper_margin_m = 0.010;
    t.look(*det, s, "at " + std::to_string(distance_m) + " m, roll " + std::to_string(roll_deg));
  };
  for (const int id : kBitPatternIds) {
    for (int mm = 1090; mm <= 1130; ++mm) look_at(id, mm / 1000.0, 0);
    for (const double distance_m : {1.1, 1.3}) {
      for (int roll = 0; roll < 90; roll += 3) look_at(id, distance_m, roll);
    }
  }
  EXPECT_EQ(t.wrong, 0);
  EXPECT_GE(t.found, t.frames - t.frames / 100) << "of " << t.frames << ", missed:" << t.missed;
}

// The print with its hole cut out (issue 18), the ground showing through:
// over a light ground it is the printed hole, and found as on paper; the
// bare marker (no paper margin) over a dark ground or clutter has no light
// region round its ink either, and is mostly missed (README), but what is
// read must be the marker's id.
TEST(Frame8, CutHoleOverLightDarkAndClutteredGrounds) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.scene.cut_hole = true;
  settings.frames_per_point = 10;
  settings.seed = 21;
  struct Ground {
    bool clutter;
    double grey;
  };
  for (const Ground ground : {Ground{false, 200}, Ground{false, 30}, Ground{true, 128}}) {
    settings.scene.clutter = ground.clutter;
    settings.scene.background_grey = ground.grey;
    const Tally t = evaluate_facing(*det, settings, {0.4, 0.8, 1.2, 1.6});
    const std::string name = ground.clutter ? "clutter" : "grey " + std::to_string(static_cast<int>(ground.grey));
    EXPECT_EQ(t.wrong, 0) << name;
    if (!ground.clutter && ground.grey > 128) {
      EXPECT_GE(t.detected, t.frames - 2) << name;
    }
  }
}

// The print as `markerctl marker` makes it (10 mm of paper round the
// marker), its hole cut out over black, dark grey and clutter: the hole is
// no lighter than the line, and the marker is found by its ink's outline
// in the paper (stage 2c), for ids of every pattern (long white runs
// beside C1, which cut its corner long and shallow, runs of black, single
// cells), turned and rolled, where cells are 4 px or more. Its corners
// come from the pattern's edges that do not need the hole.
TEST(Frame8, CutHoleMarkerWithItsPaperMarginIsFoundOverDarkAndClutteredGrounds) {
  auto det = make_detector(posed_config());
  struct Ground {
    bool clutter;
    double grey;
  };
  int frames = 0, found = 0, wrong = 0;
  double worst_corner_px = 0;
  std::string missed;
  for (const Ground ground : {Ground{false, 0}, Ground{false, 30}, Ground{true, 128}}) {
    for (const int id : {127, 254, 15, 240, 165, 3, 96}) {
      for (const double dist : {0.4, 0.7, 1.0}) {
        const double yaw = (frames % 3 - 1) * 20.0, roll = (frames % 4) * 90.0 + 7;
        Scene s = scene(id, dist, yaw, roll, 300 + static_cast<std::uint64_t>(frames));
        s.cut_hole = true;
        s.paper_margin_m = 0.010;
        s.clutter = ground.clutter;
        s.background_grey = ground.grey;
        ++frames;
        const Quad truth = project_marker_corners(kCamera, s);
        bool right = false;
        for (const Detection& d : detect(*det, render_scene(kCamera, s))) {
          if (d.id != id) {
            ++wrong;
            continue;
          }
          right = true;
          worst_corner_px = std::max(worst_corner_px, max_corner_error(d.corners, truth));
        }
        found += right;
        if (!right) {
          missed += " grey " + std::to_string(static_cast<int>(ground.grey)) + (ground.clutter ? " clutter" : "") +
                    " id " + std::to_string(id) + " " + std::to_string(dist) + " m;";
        }
      }
    }
  }
  EXPECT_EQ(wrong, 0);
  // Measured: 59 of 63 (none of them read before stage 2c), the worst
  // corner 0.95 px off. Missed: ids 127 and 254 over clutter near and at
  // 1.0 m, whose white runs leave a side only a cell or two on the square.
  EXPECT_GE(found, frames - 6) << "of " << frames << ", missed:" << missed;
  EXPECT_LT(worst_corner_px, 1.5);
}

// The print with its margin, its hole cut out over a dark ground: the
// adaptive threshold takes the hole's flat dark middle for light, and a
// quad whose sides then lay on the white cells' inner edges, a cell out,
// read 178 as 1 with a cell outvoted (bench_accuracy --mount cut-hole
// --margin 10 --background 15 --seed 4, the 50 frames at 0.75 m). A read
// that outvoted a cell must have its hole lighter than its line.
// The print with its 10 mm margin, its hole cut out, over a plain ground.
EvalSettings cut_hole_over(double grey, std::uint64_t seed) {
  EvalSettings settings = benchmark_settings();
  settings.scene.cut_hole = true;
  settings.scene.paper_margin_m = 0.010;
  settings.scene.clutter = false;
  settings.scene.background_grey = grey;
  settings.seed = seed;
  return settings;
}

// The cut hole over a plain `grey` ground facing at `distance`, `frames`
// frames: no wrong id, and at least `least` found.
void expect_cut_hole_reads(double grey, std::uint64_t seed, double distance, int least, int frames = 50) {
  auto det = make_detector(posed_config());
  EvalSettings settings = cut_hole_over(grey, seed);
  settings.frames_per_point = frames;
  const Tally t = evaluate_facing(*det, settings, {distance});
  EXPECT_EQ(t.wrong, 0);
  EXPECT_GE(t.detected, least) << "of " << t.frames;
}

TEST(Frame8, CutHoleOverADarkGroundGivesNoWrongIdFromAHoleAsDarkAsItsLine) {
  // Measured: 50 of 50 (49 and the wrong id without the rule).
  expect_cut_hole_reads(15, 4, 0.75, 48);
}

// The print with its margin, its hole cut out over black, at 1.5 m: the
// margin, 3.4 px wide, is a thin ring of light that the threshold's
// local-maximum test leaves a pixel or two wide, too sparse to be a hole;
// the ink it encloses is measured all the same (stage 2c).
TEST(Frame8, CutHoleOverBlackIsFoundWithinAThinMargin) {
  // Measured: 43 of 50 since the second look (39 before it; 30 before the
  // ink within a thin margin was measured).
  expect_cut_hole_reads(0, 12, 1.5, 35);
}

// Told the mounting (Frame8Options::mounting), the detector leaves out the
// searches for the holes only other mountings show: on its own mounting it
// finds what the detector not told finds, the same corners; and a search
// left out is left out (a cut hole over black, found by its ink outline,
// is not searched for on paper).
TEST(Frame8, ToldItsMountingTheDetectorFindsWhatItFindsUntold) {
  auto untold = make_detector(posed_config());
  const auto told = [](Mounting mounting) {
    DetectorConfig cfg = posed_config();
    cfg.frame8.mounting = mounting;
    return make_detector(cfg);
  };
  int compared = 0;
  const auto expect_same = [&](MarkerDetector& det, const Scene& s) {
    const GreyImage image = render_scene(kCamera, s);
    const std::vector<Detection> a = detect(*untold, image), b = detect(det, image);
    ASSERT_EQ(a.size(), b.size()) << "id " << s.id << " seed " << s.seed;
    for (std::size_t i = 0; i < a.size(); ++i) {
      EXPECT_EQ(a[i].id, b[i].id);
      EXPECT_LT(max_corner_error(a[i].corners, b[i].corners), 1e-9) << "id " << s.id << " seed " << s.seed;
    }
    compared += static_cast<int>(a.size());
  };
  auto paper = told(Mounting::paper);
  std::uint64_t seed = 880;
  for (const double d : {0.5, 1.2, 1.9, 2.6}) {
    for (const double yaw : {0.0, 35.0, 65.0}) {
      ++seed;
      Scene s = scene(static_cast<int>((seed * 37) % 254) + 1, d, yaw, 7, seed);
      s.clutter = true;
      s.paper_margin_m = 0.01;
      expect_same(*paper, s);
    }
  }
  // Far and turned in the image, the hole bulges out of its quad by its
  // blurred corners: told paper, it once refused such holes.
  for (const double d : {1.8, 2.2, 2.6}) {
    for (const double roll : {-45.0, -38.0, 33.0, 40.0}) {
      ++seed;
      Scene s = scene(static_cast<int>((seed * 37) % 254) + 1, d, 0, roll, seed);
      s.clutter = true;
      s.paper_margin_m = 0.01;
      expect_same(*paper, s);
    }
  }
  auto cover = told(Mounting::cover_frame);
  for (const double yaw : {-60.0, -45.0, 45.0, 60.0}) {
    ++seed;
    Scene s = scene(static_cast<int>((seed * 37) % 254) + 1, 0.6, yaw, 0, seed);
    s.frame = socket_frame();
    s.insert = Insert::socket;
    expect_same(*cover, s);
  }
  // Measured: markers found in 24 of the 28 scenes, by both alike.
  EXPECT_GE(compared, 20);
  auto cut = told(Mounting::cut_hole);
  const Tally all = evaluate_facing(*untold, cut_hole_over(0, 12), {1.5});
  EXPECT_EQ(evaluate_facing(*cut, cut_hole_over(0, 12), {1.5}).detected, all.detected);
  EXPECT_LT(evaluate_facing(*paper, cut_hole_over(0, 12), {1.5}).detected, all.detected / 2);
}

// A cut-out hole over black from 1.8 m: the print's 10 mm margin is a
// light ring three pixels wide round the marker's ink, broken by the first
// look's threshold and whole in the second's.
TEST(Frame8, CutHoleOverBlackIsFoundFromOnePointEightMetres) {
  // Measured: 38 of 50 (1 with the first look alone).
  expect_cut_hole_reads(0, 14, 1.8, 33);
}

// A cut-out hole over a ground as dark as the ink (grey 30) at 1.6 m: a
// quad inside the hole, with no edge where its sides were measured, read
// 194 as 195 with one pass and the second failing. A read whose hole is
// as dark as the ink must be measured twice alike.
TEST(Frame8, CutHoleOverAGroundAsDarkAsInkIsReadOnlyWhenMeasuredTwiceAlike) {
  // Measured: 176 of 200, as with the wrong read.
  expect_cut_hole_reads(30, 7, 1.6, 165, 200);
}

// A square of clutter at the image's right edge, its fourth side 6 px
// outside the image, read with that side hidden as id 32 (bench_accuracy
// --margin 10 --blur-model disc --seed 4, 300 frames at 2.2 m): a side
// beyond the image is not seen to be covered, and is not read as hidden.
TEST(Frame8, NoSideIsReadAsHiddenBeyondTheImagesEdge) {
  auto det = make_detector(posed_config());
  EvalSettings settings = print_under_a_defocus_disc();
  settings.seed = 4;
  const Tally t = evaluate_facing(*det, settings, {2.2});
  EXPECT_EQ(t.wrong, 0);
  // Measured: 281 of 300, as without the rule.
  EXPECT_GE(t.detected, 270) << "of " << t.frames;
}

// The backgrounds alone in which bench_accuracy --false-positives 10000
// found its 3 false detections (ids 127, 128 and 129, read with two and
// three bits corrected and not confirmed by the second pass), with the
// camera model as there: nothing.
TEST(Frame8, ClutterReadWithCorrectionsTheSecondPassCannotConfirmIsNoDetection) {
  auto det = make_detector(posed_config());
  Scene s = benchmark_settings().scene;
  for (const std::uint64_t seed : {1003205U, 1003375U, 1008927U}) {
    s.seed = seed;
    for (const Detection& d : detect(*det, render_background(kCamera, s))) {
      ADD_FAILURE() << "seed " << seed << ": id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y;
    }
  }
}

// Ink is black beside the paper: a marker whose "black" is half as light
// as its white or more is a grey pattern on a grey ground (the grout
// between tiles, read as id 126 with the lines' crossings for its black
// cells). The same prints, their contrast squeezed towards the paper's
// white: kept at 0.7 of it (black at a third of white), refused at 0.35
// (black at two thirds), which the contrast alone (75 grey levels) let through.
TEST(Frame8, APrintWhoseBlackIsGreyIsNoMarker) {
  auto det = make_detector(posed_config());
  int found_clear = 0, found_grey = 0, points = 0;
  for (const double dist : {0.5, 1.0, 1.5}) {
    for (const int id : {1, 126, 165, 254}) {
      Scene s = scene(id, dist, 20, 3, static_cast<std::uint64_t>(id) + 7);
      s.clutter = false;
      s.background_grey = 90;
      const GreyImage img = render_scene(kCamera, s);
      auto squeezed = [&](double kept) {
        GreyImage out = img;
        constexpr double kPaper = 225;
        for (int y = 0; y < out.height(); ++y) {
          for (int x = 0; x < out.width(); ++x) {
            const double v = kPaper - (kPaper - img.at(x, y)) * kept;
            out.at(x, y) = static_cast<std::uint8_t>(std::clamp(v, 0.0, 255.0));
          }
        }
        return out;
      };
      ++points;
      for (const Detection& d : detect(*det, squeezed(0.7))) found_clear += d.id == id;
      for (const Detection& d : detect(*det, squeezed(0.35))) {
        ++found_grey;
        ADD_FAILURE() << "id " << id << " at " << dist << " m read as " << d.id << " with its black grey";
      }
    }
  }
  EXPECT_EQ(found_clear, points);
  EXPECT_EQ(found_grey, 0);
}

// A keyboard's keys, parted by dark gaps, each show a near-uniform ring
// (near_uniform): id 126, the gaps' crossings for its end cells. The 19
// keyboard frames of bench_accuracy --background all --false-positives
// 10000 in which it was read (cells of 1.6 to 2.7 px), but seed 1009210,
// whose second pass agrees and which is read still: where cells are
// unresolved, such an id is reported only when the second pass confirms it.
TEST(Frame8, KeysOfAKeyboardAreNoNearUniformMarkers) {
  auto det = make_detector(posed_config());
  Scene s = benchmark_settings().scene;
  s.background = Background::keyboard;
  int false_positives = 0;
  for (const std::uint64_t seed :
       {1000376U, 1000656U, 1000922U, 1000936U, 1001160U, 1001195U, 1001573U, 1001720U, 1001776U, 1002007U, 1002014U,
        1002413U, 1003435U, 1005283U, 1007558U, 1009196U, 1009455U, 1009952U}) {
    s.seed = seed;
    for (const Detection& d : detect(*det, render_background(kCamera, s))) {
      ++false_positives;
      ADD_FAILURE() << "seed " << seed << ": id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y;
    }
  }
  EXPECT_EQ(false_positives, 0);
}

// Told the print is paper, the detector knows its hole is blank paper: a
// key of a keyboard, a light square between dark gaps with its neighbours
// for a ring, shows its glyph; a window pane, its frame's bars; a grey
// tile is darker than the light grout's crossings it takes for white
// cells. Frames of bench_accuracy --false-positives 10000 read untold, and
// told paper before the checks: seed 9's key read as 124 with a side
// hidden and its pane read as 126 twice, seed 21's keys read as 62, 240
// and 62 (--background keyboard), seed 11's pane read as 1 and seed 13's
// tile as 126 (--tell-mounting). Seed 9's pane is refused untold too now:
// a near-uniform read must stand at the ring model's geometry map. Covered
// prints, the part of whose hole is seen blank, are read told paper as
// untold.
TEST(Frame8, ToldPaperAKeyShowingItsGlyphIsNoMarker) {
  auto untold = make_detector(posed_config());
  DetectorConfig cfg = posed_config();
  cfg.frame8.mounting = Mounting::paper;
  auto paper = make_detector(cfg);
  int untold_reads = 0;
  const std::array<std::pair<Background, std::uint64_t>, 7> frames{{{Background::keyboard, 9003382},
                                                                    {Background::windows, 9006394},
                                                                    {Background::keyboard, 21000289},
                                                                    {Background::keyboard, 21001122},
                                                                    {Background::keyboard, 21002288},
                                                                    {Background::windows, 11009011},
                                                                    {Background::tiles, 13007404}}};
  for (const auto& [background, seed] : frames) {
    Scene s = benchmark_settings().scene;
    s.background = background;
    s.seed = seed;
    const GreyImage image = render_background(kCamera, s);
    untold_reads += static_cast<int>(detect(*untold, image).size());
    for (const Detection& d : detect(*paper, image)) {
      ADD_FAILURE() << "seed " << seed << ": id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y;
    }
  }
  EXPECT_EQ(untold_reads, 6);
  for (const float reflectance : {0.1F, 0.8F}) {
    const CoveredSideReads a = read_covered_sides(true, 0, reflectance, 0.01);
    const CoveredSideReads b =
        read_covered_sides(true, 0, reflectance, 0.01, 0, 1.0, {0.5, 0.8, 1.1}, {-15.0, 0.0, 15.0}, Mounting::paper);
    EXPECT_EQ(b.detected, a.detected) << "reflectance " << reflectance;
    EXPECT_EQ(b.wrong, 0);
  }
}

// Under 2.5 px a cell the ring model confirms a read; a near-uniform read
// (the class of a grid's squares and of a far marker's blur) must be
// confirmed both at the map of the model's geometry fit and at the map it
// aligns on the pixels mostly on the marker. bench_accuracy --tell-mounting
// --margin 10 --blur-model disc --noise-model shot --seed 602 at 3.0 m: id
// 213 read as 128, sampled twice and at the model's own map alike; and a
// window pane read as 126 twice not told the mounting (--false-positives,
// seed 9).
TEST(Frame8, NearUniformReadMustStandAtBothModelMaps) {
  DetectorConfig cfg = posed_config();
  cfg.frame8.mounting = Mounting::paper;
  auto paper = make_detector(cfg);
  EvalSettings settings = benchmark_settings();
  settings.frames_per_point = 40;
  settings.seed = 602;
  settings.scene.clutter = true;
  settings.scene.paper_margin_m = 0.01;
  settings.scene.blur_model = BlurModel::disc;
  settings.scene.noise_model = NoiseModel::shot;
  EXPECT_EQ(evaluate_point(*paper, kCamera, settings, {3.0, 0}).wrong_id, 0);

  auto untold = make_detector(posed_config());
  Scene s = benchmark_settings().scene;
  s.background = Background::windows;
  s.seed = 9006394;
  for (const Detection& d : detect(*untold, render_background(kCamera, s))) {
    ADD_FAILURE() << "id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y;
  }
}

// Clutter with dark frames, checkered patches and text: nothing.
TEST(Frame8, NoDetectionOnClutter) {
  auto det = make_detector(DetectorConfig{});
  int false_positives = 0;
  for (std::uint64_t seed = 1; seed <= 100; ++seed) {
    Scene s = scene(0, 1, 0, 0, seed);
    for (const Detection& d : detect(*det, render_background(kCamera, s))) {
      ++false_positives;
      ADD_FAILURE() << "seed " << seed << ": id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y;
    }
  }
  EXPECT_EQ(false_positives, 0);
}

// Textures that look like markers, without one (issue 19: none in 10,000
// frames): 40 frames of each kind in bench_accuracy's imaging, through
// markerd's detector. Tiles are not among them yet: the detector reads
// markers in them, id 126 where the grout is dark, as in seed 10 here (a
// light tile in its grout, the grout that crosses each end of an edge
// darkening the ring cell there), and the frames of TileFrames below.
class Frame8OnBackground : public ::testing::TestWithParam<Background> {};

int false_positives_on(MarkerDetector& det, Background background, const std::vector<std::uint64_t>& seeds) {
  Scene s = benchmark_settings().scene;
  s.background = background;
  int false_positives = 0;
  for (const std::uint64_t seed : seeds) {
    s.seed = seed;
    for (const Detection& d : detect(det, render_background(kCamera, s))) {
      ++false_positives;
      ADD_FAILURE() << "seed " << seed << ": id " << d.id << " at " << d.corners[0].x << "," << d.corners[0].y << " "
                    << d.corners[1].x << "," << d.corners[1].y << " " << d.corners[2].x << "," << d.corners[2].y << " "
                    << d.corners[3].x << "," << d.corners[3].y;
    }
  }
  return false_positives;
}

TEST_P(Frame8OnBackground, NoDetection) {
  auto det = make_detector(posed_config());
  std::vector<std::uint64_t> seeds(40);
  std::iota(seeds.begin(), seeds.end(), 1);
  EXPECT_EQ(false_positives_on(*det, GetParam(), seeds), 0);
}

INSTANTIATE_TEST_SUITE_P(Kinds, Frame8OnBackground,
                         ::testing::Values(Background::shapes, Background::keyboard, Background::checkerboard,
                                           Background::windows, Background::text, Background::outlets),
                         [](const auto& p) { return std::string(to_string(p.param)); });

// Frames of bench_accuracy --background all --false-positives 10000 (seeds
// 1 to 5 and 43; the frame's seed is 1000003 times the run's plus the
// frame's index) where a texture read as a marker, each refused since by
// the rule named.
TEST(Frame8, MarkerLikeTexturesOnceReadAreNoMarkers) {
  auto det = make_detector(posed_config());
  // A light tile among grey ones, its light grout taken for the line, read
  // as 129 with cells of 2.1 px: the ring model confirmed the code, its line
  // as light as the white cells on a side or two (model_line_light).
  EXPECT_EQ(false_positives_on(*det, Background::tiles, {1000018, 1003595}), 0);
  // The same at 2.8 px, where the model was not asked: a near-uniform ring
  // under 3 px is a grid's square measured twice alike.
  EXPECT_EQ(false_positives_on(*det, Background::tiles, {2009345, 43002244}), 0);
  // Key tops in their bevels in the second look, the shadow of a key's edge
  // taken for the line, read as 126 with a side's six cells outvoted, and
  // nothing read with that side hidden (covered_side_unread).
  EXPECT_EQ(false_positives_on(*det, Background::keyboard, {2000561, 2002549, 2009661}), 0);
  // Three keys with a side taken for hidden: a trapezoid 13 px on one side
  // and 73 on the other, read as 131 (sides_unequal), and a quad three keys
  // tall and one wide, read as 94 (its short sides 0.32 of its long ones).
  EXPECT_EQ(false_positives_on(*det, Background::keyboard, {2006707, 2006392}), 0);
  // In the second look, which segments the frame again with light ridges
  // kept whole: window panes and keys read faintly as 126, 24, 124 and 62,
  // a tile as 126 (margins 0.18 to 0.34; kSecondLookMargin).
  EXPECT_EQ(false_positives_on(*det, Background::windows, {2001242, 43005698, 4000310, 4007289}), 0);
  EXPECT_EQ(false_positives_on(*det, Background::keyboard, {5005904, 2000743}), 0);
  EXPECT_EQ(false_positives_on(*det, Background::tiles, {3008634}), 0);
}

// bench_accuracy --background all: frame i of a point shows kind i % n.
// The marker is out of reach, so that every frame is a miss and seen.
TEST(Frame8, EvaluationBackgroundsTakeTurnsFrameByFrame) {
  auto det = make_detector(posed_config());
  EvalSettings settings = benchmark_settings();
  settings.frames_per_point = 5;
  settings.background_turns = {Background::tiles, Background::text, Background::outlets};
  std::vector<Background> seen;
  settings.on_miss = [&](const GreyImage&, const Scene& scene) { seen.push_back(scene.background); };
  const EvalResult r = evaluate_point(*det, kCamera, settings, {40, 0});
  EXPECT_EQ(r.detected, 0);
  EXPECT_EQ(seen, (std::vector<Background>{Background::tiles, Background::text, Background::outlets, Background::tiles,
                                           Background::text}));
}

TEST(Frame8, BadImagesGiveErrorsNotCrashes) {
  auto det = make_detector(DetectorConfig{});
  std::vector<Detection> out;
  EXPECT_THROW(det->detect(GreyView{}, out), DetectorError);
  const GreyImage img(64, 48, 128);
  GreyView narrow = img.view();
  narrow.stride = 10;
  EXPECT_THROW(det->detect(narrow, out), DetectorError);

  // Tiny, flat, saturated and pure-noise frames: no crash, nothing found.
  for (const auto& [w, h] : {std::pair{1, 1}, {15, 15}, {16, 16}, {3, 2000}, {2000, 3}}) {
    const GreyImage tiny(w, h, 200);
    EXPECT_NO_THROW(det->detect(tiny, out));
    EXPECT_TRUE(out.empty());
  }
  std::mt19937 rng(7);
  GreyImage noise(640, 480);
  for (int y = 0; y < noise.height(); ++y) {
    for (int x = 0; x < noise.width(); ++x) noise.at(x, y) = static_cast<std::uint8_t>(rng() & 0xff);
  }
  EXPECT_NO_THROW(det->detect(noise, out));
  EXPECT_TRUE(out.empty());
  for (const std::uint8_t level : {std::uint8_t{0}, std::uint8_t{255}}) {
    EXPECT_NO_THROW(det->detect(GreyImage(640, 480, level), out));
    EXPECT_TRUE(out.empty());
  }

  // A camera model of another size than the image.
  DetectorConfig cfg;
  cfg.camera = kCamera;
  cfg.marker_size_m = 0.08;
  auto posed = make_detector(cfg);
  EXPECT_THROW(posed->detect(GreyImage(320, 240, 128), out), DetectorError);
  // A pose needs both a camera and a size.
  cfg.marker_size_m = 0;
  EXPECT_THROW(make_detector(cfg), DetectorError);
}

// Ids 0 and 255 are a dark frame with one light corner and a light outline
// with three dark ones: reported only when asked for.
TEST(Frame8, UniformIdsOnlyWhenAskedFor) {
  auto plain = make_detector(DetectorConfig{});
  DetectorConfig cfg;
  cfg.frame8.uniform_ids = true;
  auto uniform = make_detector(cfg);
  for (const int id : {0, 255}) {
    const GreyImage img = render_scene(kCamera, scene(id, 0.6, 10, 0, 700 + static_cast<std::uint64_t>(id)));
    EXPECT_TRUE(detect(*plain, img).empty()) << "id " << id;
    const auto found = detect(*uniform, img);
    ASSERT_EQ(found.size(), 1u) << "id " << id;
    EXPECT_EQ(found[0].id, id);
  }
}

// A marker partly outside the frame is either found right or not at all.
TEST(Frame8, MarkerAtTheImageBorder) {
  auto det = make_detector(DetectorConfig{});
  for (int k = 0; k < 8; ++k) {
    Scene s = scene(165, 0.4, 0, 0, static_cast<std::uint64_t>(600 + k));
    s.pose.translation.x() = 0.20 + 0.005 * k;  // sliding out of the right edge
    for (const Detection& d : detect(*det, render_scene(kCamera, s))) EXPECT_EQ(d.id, 165);
  }
}

}  // namespace
}  // namespace markerd::detector
