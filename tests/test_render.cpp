// The renderer is the ground truth of every detector test and benchmark, so
// these tests check it against independent references: OpenCV's projection,
// the frame8 code table, ArUco's drawMarker and libapriltag's own detector.

#include <gtest/gtest.h>

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <opencv2/aruco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <string>
#include <tuple>
#include <vector>

#include <unistd.h>

#include "markerd/detector/frame8.hpp"
#include "markerd/detector/print.hpp"
#include "markerd/detector/render.hpp"
#include "render_test_helpers.hpp"
#include "support/temp_dir.hpp"

namespace markerd::detector {
namespace {

using namespace render_test;  // NOLINT(google-build-using-namespace): the shared helpers

// ------------------------------------------------------------------ poses

TEST(FacingPose, AxesFollowTheContract) {
  const MarkerPose p = facing_pose(0.5, 0);
  Eigen::Matrix3d expected;
  expected << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  EXPECT_TRUE(p.rotation.isApprox(expected, 1e-12));
  EXPECT_EQ(p.translation, Eigen::Vector3d(0, 0, 0.5));

  // Turntable by +90 deg about the marker's Y: the marker's X turns to face
  // away from the camera (camera +z), its Y stays camera -y.
  const MarkerPose yawed = facing_pose(0.5, 90);
  EXPECT_TRUE(yawed.rotation.col(0).isApprox(Eigen::Vector3d(0, 0, 1), 1e-12));
  EXPECT_TRUE(yawed.rotation.col(1).isApprox(Eigen::Vector3d(0, -1, 0), 1e-12));

  const MarkerPose full = facing_pose(0.7, 20, -10, 35, 0.01, -0.02);
  EXPECT_NEAR(full.rotation.determinant(), 1.0, 1e-12);
  EXPECT_TRUE((full.rotation.transpose() * full.rotation).isIdentity(1e-12));
  EXPECT_EQ(full.translation, Eigen::Vector3d(0.01, -0.02, 0.7));
  // Roll is in the marker's plane: it keeps the plane normal.
  EXPECT_TRUE(facing_pose(0.7, 20, -10, 35).rotation.col(2).isApprox(facing_pose(0.7, 20, -10, 0).rotation.col(2)));
}

TEST(ProjectMarkerCorners, FacingMarkerIsUprightAroundTheCentre) {
  Scene s;
  s.pose = facing_pose(0.5, 0);
  s.distort = false;
  const Quad q = project_marker_corners(pinhole_camera(), s);
  // S = 0.08 m at 0.5 m with f = 500: 80 px square centred on (320, 240).
  EXPECT_NEAR(q[0].x, 280, 1e-9);
  EXPECT_NEAR(q[0].y, 200, 1e-9);
  EXPECT_NEAR(q[1].x, 360, 1e-9);
  EXPECT_NEAR(q[1].y, 200, 1e-9);
  EXPECT_NEAR(q[2].x, 360, 1e-9);
  EXPECT_NEAR(q[2].y, 280, 1e-9);
  EXPECT_NEAR(q[3].x, 280, 1e-9);
  EXPECT_NEAR(q[3].y, 280, 1e-9);
  const Quad half = project_marker_corners(pinhole_camera(), s, 0.5);
  EXPECT_NEAR(half[0].x, 300, 1e-9);
  EXPECT_NEAR(half[2].y, 260, 1e-9);
}

TEST(ProjectMarkerCorners, MatchOpenCvProjectPoints) {
  const CameraModel cam = CameraModel::thesis_640x480();
  const cv::Matx33d k(cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
  const std::vector<double> dist(cam.dist.begin(), cam.dist.begin() + 5);
  const std::vector<MarkerPose> poses = {facing_pose(0.4, 0), facing_pose(0.6, 35, 10, 20, 0.05, -0.03),
                                         facing_pose(0.3, -50, 0, 90), facing_pose(0.8, 10, -30, -45, -0.15, 0.1),
                                         facing_pose(0.25, 60, 20, 5)};
  for (const auto& pose : poses) {
    for (bool distort : {true, false}) {
      Scene s;
      s.marker_size_m = 0.08;
      s.pose = pose;
      s.distort = distort;
      const double scale = 0.7;
      const Quad q = project_marker_corners(cam, s, scale);
      const double h = s.marker_size_m * scale / 2;
      const std::vector<cv::Point3d> obj = {{-h, h, 0}, {h, h, 0}, {h, -h, 0}, {-h, -h, 0}};
      cv::Matx33d r;
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) r(i, j) = pose.rotation(i, j);
      }
      cv::Vec3d rvec;
      cv::Rodrigues(r, rvec);
      const cv::Vec3d tvec(pose.translation.x(), pose.translation.y(), pose.translation.z());
      std::vector<cv::Point2d> img;
      cv::projectPoints(obj, rvec, tvec, k, distort ? dist : std::vector<double>{}, img);
      for (std::size_t i = 0; i < 4; ++i) {
        EXPECT_NEAR(q[i].x, img[i].x, 1e-6) << "corner " << i << " distort " << distort;
        EXPECT_NEAR(q[i].y, img[i].y, 1e-6) << "corner " << i << " distort " << distort;
      }
    }
  }
}

// ------------------------------------------------------------------ images

TEST(RenderScene, DeterministicPerSeed) {
  const CameraModel cam = CameraModel::thesis_640x480();
  Scene s;
  s.pose = facing_pose(0.4, 20, 5, 10);
  s.noise_sigma = 3;
  s.blur_sigma_px = 0.8;
  s.seed = 42;
  const GreyImage a = render_scene(cam, s);
  const GreyImage b = render_scene(cam, s);
  ASSERT_EQ(a.width(), 640);
  ASSERT_EQ(a.height(), 480);
  EXPECT_TRUE(same_bytes(a, b));
  Scene other = s;
  other.seed = 43;
  const GreyImage c = render_scene(cam, other);
  // Different clutter and noise: most pixels change.
  EXPECT_GT(count_different(a, c), 640 * 480 / 2);
  // The background alone is deterministic too, and differs between seeds.
  EXPECT_TRUE(same_bytes(render_background(cam, s), render_background(cam, s)));
  EXPECT_GT(count_different(render_background(cam, s), render_background(cam, other)), 640 * 480 / 2);
  maybe_dump(a, "scene_seed42");
}

TEST(RenderScene, ClutterSpreadsGreyLevels) {
  Scene s;
  s.seed = 7;
  const GreyImage bg = render_background(CameraModel::thesis_640x480(), s);
  std::vector<int> hist(256);
  for (int i = 0; i < bg.width() * bg.height(); ++i) ++hist[bg.data()[i]];
  int dark = 0, light = 0, distinct = 0;
  for (int g = 0; g < 256; ++g) {
    if (g < 60) dark += hist[g];
    if (g > 190) light += hist[g];
    if (hist[g] > 0) ++distinct;
  }
  EXPECT_GT(dark, 1000);
  EXPECT_GT(light, 1000);
  EXPECT_GT(distinct, 150);
  s.clutter = false;
  const GreyImage flat = render_background(CameraModel::thesis_640x480(), s);
  EXPECT_EQ(*std::min_element(flat.data(), flat.data() + 640 * 480), 128);
  EXPECT_EQ(*std::max_element(flat.data(), flat.data() + 640 * 480), 128);
}

TEST(RenderBackground, NamesRoundTrip) {
  ASSERT_EQ(all_backgrounds().size(), 7U);
  EXPECT_EQ(all_backgrounds().front(), Background::shapes);
  EXPECT_EQ(Scene{}.background, Background::shapes);
  for (const Background kind : all_backgrounds()) {
    EXPECT_EQ(background_from_string(to_string(kind)), kind) << to_string(kind);
  }
  EXPECT_EQ(background_from_string("clutter"), std::nullopt);
  EXPECT_EQ(background_from_string("Tiles"), std::nullopt);
  EXPECT_EQ(background_from_string(""), std::nullopt);
}

// Each texture is the same again for its seed and another for the next
// seed, and not the shapes of its seed (which share only the gradient under
// them); without clutter the background stays the flat grey.
TEST(RenderBackground, TexturesAreDeterministicPerSeedAndTheirOwn) {
  const CameraModel cam = CameraModel::thesis_640x480();
  constexpr int kPixels = 640 * 480;
  for (const Background kind : all_backgrounds()) {
    if (kind == Background::shapes) continue;
    const std::string name(to_string(kind));
    for (const std::uint64_t seed : {3U, 11U}) {
      Scene s;
      s.seed = seed;
      s.background = kind;
      s.noise_sigma = 2;
      const GreyImage a = render_background(cam, s);
      EXPECT_TRUE(same_bytes(a, render_background(cam, s))) << name << " seed " << seed;
      Scene next = s;
      next.seed = seed + 1;
      EXPECT_GT(count_different(a, render_background(cam, next)), kPixels / 2) << name << " seed " << seed;
      Scene shapes = s;
      shapes.background = Background::shapes;
      EXPECT_GT(count_different(a, render_background(cam, shapes)), kPixels / 10) << name << " seed " << seed;
      maybe_dump(a, "background_" + name + "_seed" + std::to_string(seed));
    }
    Scene flat;
    flat.clutter = false;
    flat.background = kind;
    const GreyImage plain = render_background(cam, flat);
    EXPECT_EQ(*std::min_element(plain.data(), plain.data() + kPixels), 128) << name;
    EXPECT_EQ(*std::max_element(plain.data(), plain.data() + kPixels), 128) << name;
  }
}

// The marker over a texture: drawn the same as over the shapes, only the
// background around it differs.
TEST(RenderBackground, MarkerIsDrawnOverTheTexture) {
  const CameraModel cam = CameraModel::thesis_640x480();
  Scene s;
  s.pose = facing_pose(0.5, 0);
  s.distort = false;
  s.seed = 5;
  s.background = Background::tiles;
  const GreyImage textured = render_scene(cam, s);
  s.background = Background::shapes;
  const GreyImage shapes = render_scene(cam, s);
  const Quad q = project_marker_corners(cam, s);
  for (int y = static_cast<int>(q[0].y) + 2; y < static_cast<int>(q[2].y) - 2; ++y) {
    for (int x = static_cast<int>(q[0].x) + 2; x < static_cast<int>(q[2].x) - 2; ++x) {
      ASSERT_EQ(textured.at(x, y), shapes.at(x, y)) << x << "," << y;
    }
  }
  EXPECT_GT(count_different(textured, shapes), 640 * 480 / 2);
}

struct CellCase {
  int id;
  MarkerPose pose;
  bool distort;
};

TEST(RenderScene, Frame8CellsMatchTheCodeAtTheirProjectedCentres) {
  const CameraModel cam = CameraModel::thesis_640x480();
  const std::vector<CellCase> cases = {
      {165, facing_pose(0.3, 0), true},
      {0, facing_pose(0.3, 30, 0, 0, 0.03, 0.02), true},
      {255, facing_pose(0.35, -35, 15, 20, -0.04, 0.01), true},
      {90, facing_pose(0.3, 10, -20, 90), true},
      {17, facing_pose(0.32, 25, 10, -150, 0.02, -0.03), false},
      {201, facing_pose(0.28, -20, -25, 45), true},
  };
  for (const auto& c : cases) {
    Scene s;
    s.id = c.id;
    s.pose = c.pose;
    s.distort = c.distort;
    s.seed = static_cast<std::uint64_t>(c.id) + 3;
    const GreyImage img = render_scene(cam, s);
    const auto cells = frame8::ring_cells(c.id);
    for (int row = 0; row < 10; ++row) {
      for (int col = 0; col < 10; ++col) {
        const double u = (col + 0.5) / 10 - 0.5, v = 0.5 - (row + 0.5) / 10;
        const Point2 p = project_uv(cam, s, u, v);
        // The pixel must lie wholly inside its cell for an exact level.
        const Point2 q = project_uv(cam, s, u + 0.05, v + 0.05);
        ASSERT_GT(distance(p, q), 3.0) << "cells too small for this test";
        const std::uint8_t got = pixel_at(img, p);
        const std::uint8_t cell = cells[static_cast<std::size_t>(row * 10 + col)];
        if (cell == 2) {
          // Cells 1 and 8 of the inside have the line's inner edge through their centre.
          if (row >= 2 && row <= 7 && col >= 2 && col <= 7) {
            EXPECT_EQ(got, kWhite) << "hole, id " << c.id << " cell " << col << "," << row;
          }
        } else {
          EXPECT_EQ(got, cell != 0 ? kWhite : kBlack) << "id " << c.id << " cell " << col << "," << row;
        }
      }
    }
    // The black line: the middle of the band (1.25 cells in) all round.
    for (double a : {-0.3, -0.1, 0.1, 0.3}) {
      const double m = 0.5 - 0.125;
      for (const auto& [u, v] : std::vector<std::pair<double, double>>{{a, m}, {m, a}, {a, -m}, {-m, a}}) {
        EXPECT_EQ(pixel_at(img, project_uv(cam, s, u, v)), kBlack) << "line, id " << c.id << " at " << u << "," << v;
      }
    }
    maybe_dump(img, "frame8_" + std::to_string(c.id));
  }
}

// A straddling pixel is the area mix of both sides: this checks that pixel
// centres are at integer coordinates and that supersampling covers the pixel.
TEST(RenderScene, EdgePixelIsTheAreaMix) {
  const CameraModel cam = pinhole_camera();
  Scene s;
  s.clutter = false;
  s.distort = false;
  s.supersample = 10;
  // Left edge at x = 320 + (offset - 0.04) * 500 / 0.5 = 100.3.
  s.pose = facing_pose(0.5, 0, 0, 0, -0.1797, 0);
  const Quad q = project_marker_corners(cam, s);
  ASSERT_NEAR(q[0].x, 100.3, 1e-9);
  const GreyImage img = render_scene(cam, s);
  const int y = 204;  // through C0 (black), rows 200..208
  EXPECT_EQ(img.at(99, y), 128);
  // Pixel 100 covers [99.5, 100.5]: 0.2 of it is ink.
  EXPECT_EQ(img.at(100, y), static_cast<int>(std::lround(0.8 * 128 + 0.2 * 0.05 * 255)));
  EXPECT_EQ(img.at(101, y), kBlack);
  // Exposure scales everything, background included.
  s.exposure = 0.5;
  const GreyImage dim = render_scene(cam, s);
  EXPECT_EQ(dim.at(99, y), 64);
  EXPECT_EQ(dim.at(101, y), 6);      // 6.375
  EXPECT_EQ(dim.at(130, 240), 112);  // hole: 0.5 * 224.4
}

// A PlanarPrint (any picture: a calibration board) in place of the marker:
// its texels where the pose puts them, its top towards +Y, its greys
// between ink and paper, nothing beyond its edge; a print is flat only.
TEST(RenderScene, PlanarPrintLiesWhereItsTexelsSay) {
  const CameraModel cam = pinhole_camera();
  auto print = std::make_shared<PlanarPrint>();
  // 200 x 100 mm in texels of 0.25 mm (bilinear reading spreads an edge
  // over one, here a quarter pixel): the left half ink, the right half
  // paper above and mid-grey below.
  print->image = GreyImage(800, 400, 0);
  for (int y = 0; y < 400; ++y) {
    for (int x = 400; x < 800; ++x) print->image.at(x, y) = y < 200 ? 255 : 128;
  }
  print->texel_m = 0.00025;
  Scene s;
  s.print = print;
  s.clutter = false;
  s.distort = false;
  s.supersample = 16;
  // Face on at 0.5 m: 1 mm is a pixel, the picture's centre at (320, 240),
  // moved 0.3 px right and down so that its edges fall inside pixels.
  s.pose = facing_pose(0.5, 0, 0, 0, 0.0003, 0.0003);
  const GreyImage img = render_scene(cam, s);
  EXPECT_EQ(img.at(300, 220), kBlack);
  EXPECT_EQ(img.at(340, 220), kWhite);  // the top half is up in the image
  EXPECT_EQ(img.at(340, 260), static_cast<int>(std::lround((0.05 + 0.83 * 128 / 255.0) * 255)));
  // Pixel 320 covers [319.5, 320.5]; the paper begins at 320.3.
  EXPECT_EQ(img.at(320, 220), static_cast<int>(std::lround(0.8 * 12.75 + 0.2 * 224.4)));
  // The picture spans 220.3 .. 420.3 across and 190.3 .. 290.3 down.
  EXPECT_EQ(img.at(219, 240), 128);
  // The picture's own edge is sharp: 3 of the 16 sample columns (not 3.2).
  EXPECT_EQ(img.at(220, 240), static_cast<int>(std::lround(13.0 / 16 * 128 + 3.0 / 16 * 12.75)));
  EXPECT_EQ(img.at(221, 240), kBlack);
  EXPECT_EQ(img.at(421, 220), 128);
  EXPECT_EQ(img.at(300, 189), 128);
  EXPECT_EQ(img.at(300, 191), kBlack);
  EXPECT_EQ(img.at(300, 289), kBlack);
  EXPECT_EQ(img.at(300, 291), 128);

  // Through a pose, a texel's centre lands on its projection.
  s.pose = facing_pose(0.45, 30, -20, 10, 0.01, -0.02);
  const GreyImage turned = render_scene(cam, s);
  for (const auto& [x_m, y_m, grey] : {std::tuple{-0.05, 0.0, kBlack}, std::tuple{0.05, 0.025, kWhite},
                                       std::tuple{-0.09, 0.04, kBlack}, std::tuple{0.09, 0.04, kWhite}}) {
    const Eigen::Vector3d c = s.pose.rotation * Eigen::Vector3d(x_m, y_m, 0) + s.pose.translation;
    const Point2 px{cam.fx * c.x() / c.z() + cam.cx, cam.fy * c.y() / c.z() + cam.cy};
    EXPECT_EQ(pixel_at(turned, px), grey) << x_m << ", " << y_m;
  }

  Scene bad = s;
  bad.frame = socket_frame();
  EXPECT_THROW((void)render_scene(cam, bad), std::invalid_argument);
  bad = s;
  bad.occluders.push_back(side_occluder(MarkerSide::top, 0.08));
  EXPECT_THROW((void)render_scene(cam, bad), std::invalid_argument);
  auto flat = std::make_shared<PlanarPrint>(*print);
  flat->texel_m = 0;
  bad = s;
  bad.print = flat;
  EXPECT_THROW((void)render_scene(cam, bad), std::invalid_argument);
  bad.print = std::make_shared<PlanarPrint>();
  EXPECT_THROW((void)render_scene(cam, bad), std::invalid_argument);
}

// Off the optical axis the thesis's lens moves the marker by pixels: the
// rendered edges must follow the distorted projection to a small fraction of
// a pixel. The hole's left edge (white hole right of the black line) is read
// back from the straddling pixel's grey level along many rows.
TEST(RenderScene, EdgesFollowTheDistortedProjection) {
  const CameraModel cam = CameraModel::thesis_640x480();
  for (const auto& pose : {facing_pose(0.3, 8, 0, 2, -0.12, -0.08), facing_pose(0.3, -10, 5, -3, -0.1, 0.07)}) {
    Scene s;
    s.pose = pose;
    s.clutter = false;
    s.supersample = 16;
    const GreyImage img = render_scene(cam, s);
    // How far lens distortion moves this edge: the test is void if it does not.
    Scene pinhole = s;
    pinhole.distort = false;
    const double shift = distance(project_uv(cam, s, -0.35, 0), project_uv(cam, pinhole, -0.35, 0));
    EXPECT_GT(shift, 3.0);

    // The edge u = -0.35 as a polyline in the image.
    std::vector<Point2> edge;
    for (int i = 0; i <= 400; ++i) edge.push_back(project_uv(cam, s, -0.35, -0.3 + 0.6 * i / 400));
    int rows = 0;
    for (int y = 0; y < img.height(); ++y) {
      for (std::size_t i = 0; i + 1 < edge.size(); ++i) {
        const Point2 a = edge[i], b = edge[i + 1];
        if ((a.y - y) * (b.y - y) > 0 || a.y == b.y) continue;
        const double xe = a.x + (b.x - a.x) * (y - a.y) / (b.y - a.y);
        const double slope = (b.x - a.x) / (b.y - a.y);
        const int px = static_cast<int>(std::lround(xe));
        const double white = px + 0.5 - xe;  // the hole's share of the pixel
        if (white < 0.2 || white > 0.8 || std::abs(slope) > 0.3) break;
        const double measured = px + 0.5 - (img.at(px, y) - 0.05 * 255) / ((0.88 - 0.05) * 255);
        EXPECT_NEAR(measured, xe, 0.05) << "row " << y;
        EXPECT_EQ(img.at(px - 3, y), kBlack) << "row " << y;
        EXPECT_EQ(img.at(px + 3, y), kWhite) << "row " << y;
        ++rows;
        break;
      }
    }
    EXPECT_GT(rows, 20);
  }
}

TEST(RenderScene, CutHoleShowsTheBackground) {
  const CameraModel cam = CameraModel::thesis_640x480();
  Scene s;
  s.id = 77;
  s.cut_hole = true;
  s.pose = facing_pose(0.3, 25, -10, 15);
  s.noise_sigma = 2.5;
  s.seed = 11;
  const GreyImage cut = render_scene(cam, s);
  const GreyImage bg = render_background(cam, s);
  maybe_dump(cut, "cut_hole");
  // Inside the hole, shrunk by one pixel's worth, the image is the background
  // byte for byte (the same noise stream too).
  int checked = 0, differ = 0;
  for (int i = -30; i <= 30; ++i) {
    for (int j = -30; j <= 30; ++j) {
      const double u = 0.33 * i / 30, v = 0.33 * j / 30;
      const Point2 p = project_uv(cam, s, u, v);
      const int x = static_cast<int>(std::lround(p.x)), y = static_cast<int>(std::lround(p.y));
      ++checked;
      differ += cut.at(x, y) != bg.at(x, y) ? 1 : 0;
    }
  }
  EXPECT_EQ(checked, 61 * 61);
  EXPECT_EQ(differ, 0);
  // Uncut, the same place is paper, and differs from the clutter.
  Scene paper = s;
  paper.cut_hole = false;
  paper.noise_sigma = 0;
  const GreyImage uncut = render_scene(cam, paper);
  EXPECT_EQ(pixel_at(uncut, project_uv(cam, s, 0, 0)), kWhite);
  EXPECT_GT(count_different(cut, uncut), 5000);
  // Far from the marker, scene and background agree even with blur.
  s.blur_sigma_px = 1.5;
  const GreyImage blurred = render_scene(cam, s);
  const GreyImage blurred_bg = render_background(cam, s);
  const Quad q = project_marker_corners(cam, s);
  double minx = 1e9, maxx = -1e9;
  for (const auto& p : q) minx = std::min(minx, p.x), maxx = std::max(maxx, p.x);
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < static_cast<int>(minx) - 10; ++x) ASSERT_EQ(blurred.at(x, y), blurred_bg.at(x, y));
    for (int x = static_cast<int>(maxx) + 10; x < 640; ++x) ASSERT_EQ(blurred.at(x, y), blurred_bg.at(x, y));
  }
}

// The mean and standard deviation of an image's grey levels.
struct GreyStats {
  double mean, sd;
};
GreyStats grey_stats(const GreyImage& img) {
  double sum = 0, sum2 = 0;
  const int n = img.width() * img.height();
  for (int i = 0; i < n; ++i) {
    sum += img.data()[i];
    sum2 += static_cast<double>(img.data()[i]) * img.data()[i];
  }
  const double mean = sum / n;
  return {mean, std::sqrt(sum2 / n - mean * mean)};
}

TEST(RenderScene, NoiseHasTheRequestedSigma) {
  Scene s;
  s.clutter = false;
  s.pose = facing_pose(-1, 0);  // behind the camera: nothing drawn
  s.noise_sigma = 4;
  const auto [mean, sd] = grey_stats(render_scene(pinhole_camera(), s));
  EXPECT_NEAR(mean, 128, 0.05);
  // Rounding adds 1/12 of a level's variance.
  EXPECT_NEAR(sd, std::sqrt(16 + 1.0 / 12), 0.05);
}

// Shot noise: read noise of half the sigma, and in all the sigma at mid-grey;
// darker pixels are cleaner, lighter ones noisier, by the square root of
// the grey.
TEST(RenderScene, ShotNoiseGrowsWithTheGrey) {
  const auto sd_at = [](double grey) {
    Scene s;
    s.clutter = false;
    s.background_grey = grey;
    s.pose = facing_pose(-1, 0);
    s.noise_sigma = 4;
    s.noise_model = NoiseModel::shot;
    return grey_stats(render_scene(pinhole_camera(), s)).sd;
  };
  const auto expected = [](double grey) { return std::sqrt(4.0 + 12.0 * grey / 128 + 1.0 / 12); };
  EXPECT_NEAR(sd_at(128), expected(128), 0.05);
  EXPECT_NEAR(sd_at(32), expected(32), 0.05);
  EXPECT_NEAR(sd_at(224), expected(224), 0.05);
}

// A lens out of focus: a disc of radius twice the sigma, which keeps the
// light and spreads a step over the disc's diameter, with edges of its own
// shape (linear-ish, not the Gaussian's S).
TEST(RenderScene, DiscBlurSpreadsAStepOverItsDiameter) {
  const auto row_of = [](BlurModel model) {
    Scene s;
    s.clutter = false;
    s.cut_hole = false;
    s.noise_sigma = 0;
    s.blur_sigma_px = 1.0;
    s.blur_model = model;
    s.pose = facing_pose(0.5, 0);
    const GreyImage img = render_scene(pinhole_camera(), s);
    std::vector<int> row;
    const int y = img.height() / 2;
    for (int x = 0; x < img.width(); ++x) row.push_back(img.row(y)[x]);
    return row;
  };
  const std::vector<int> disc = row_of(BlurModel::disc), gaussian = row_of(BlurModel::gaussian);
  // The marker's left outer edge: background (128) to the black corner
  // cell's ink, then back up. Count the pixels strictly between the two
  // plateaus around the first fall.
  const auto transition = [](const std::vector<int>& row) {
    std::size_t x = 0;
    while (x < row.size() && row[x] >= 126) ++x;
    std::size_t end = x;
    while (end < row.size() && row[end] > row[end + 1] + 1) ++end;
    return end - x;
  };
  EXPECT_LE(transition(disc), 5U) << "radius 2 px: a step spreads over 4 px, 5 with the edge's own pixel";
  long sum_disc = 0, sum_gaussian = 0;
  int differ = 0;
  for (std::size_t x = 0; x < disc.size(); ++x) {
    sum_disc += disc[x];
    sum_gaussian += gaussian[x];
    differ += std::abs(disc[x] - gaussian[x]) > 2;
  }
  EXPECT_GE(differ, 4) << "the disc's edges are not the Gaussian's";
  EXPECT_NEAR(static_cast<double>(sum_disc) / sum_gaussian, 1.0, 0.002) << "both keep the light";
}

// Through JPEG at quality 75 the frame keeps its shape and its greys to a
// few levels, and is not the same frame.
TEST(RenderScene, JpegQualityPassesTheFrameThroughTheCodec) {
  Scene s;
  s.pose = facing_pose(0.5, 0);
  s.noise_sigma = 2;
  const GreyImage raw = render_scene(pinhole_camera(), s);
  s.jpeg_quality = 75;
  const GreyImage jpeg = render_scene(pinhole_camera(), s);
  ASSERT_EQ(jpeg.width(), raw.width());
  ASSERT_EQ(jpeg.height(), raw.height());
  double changed = 0, abs_sum = 0;
  const int n = raw.width() * raw.height();
  for (int i = 0; i < n; ++i) {
    const int d = std::abs(static_cast<int>(jpeg.data()[i]) - raw.data()[i]);
    changed += d > 0;
    abs_sum += d;
  }
  EXPECT_GT(changed / n, 0.3);
  EXPECT_LT(abs_sum / n, 4.0);
  s.jpeg_quality = 101;
  EXPECT_THROW((void)render_scene(pinhole_camera(), s), std::invalid_argument);
}

// ------------------------------------------------------------------ peers

TEST(RenderScene, AprilTagDetectorReadsRenderedTag36h11) {
  const CameraModel cam = pinhole_camera();
  const std::unique_ptr<apriltag_family_t, void (*)(apriltag_family_t*)> fam(tag36h11_create(), tag36h11_destroy);
  const std::unique_ptr<apriltag_detector_t, void (*)(apriltag_detector_t*)> det(apriltag_detector_create(),
                                                                                 apriltag_detector_destroy);
  apriltag_detector_add_family(det.get(), fam.get());
  det->nthreads = 1;
  det->quad_decimate = 1;

  for (const double roll : {0.0, 90.0, -35.0}) {
    Scene s;
    s.family = Family::tag36h11;
    s.id = 7;
    s.distort = false;
    s.pose = facing_pose(0.3, 20, -10, roll, 0.02, -0.01);
    s.seed = 5;
    const GreyImage img = render_scene(cam, s);
    if (roll == 0.0) maybe_dump(img, "tag36h11_7");
    image_u8_t im{img.width(), img.height(), img.width(), const_cast<std::uint8_t*>(img.data())};
    zarray_t* found = apriltag_detector_detect(det.get(), &im);
    const Quad truth = project_marker_corners(cam, s);
    bool seen = false;
    for (int i = 0; i < zarray_size(found); ++i) {
      apriltag_detection_t* d = nullptr;
      zarray_get(found, i, &d);
      if (d->id != 7) continue;
      seen = true;
      // libapriltag's corners wrap counter-clockwise from the tag's
      // bottom-left: ours (TL, TR, BR, BL) are its p[3], p[2], p[1], p[0].
      // It puts pixel centres at +0.5 (pixel i spans [i, i+1)), we at
      // integers: a renderer off by half a pixel fails here.
      double mean_x = 0, mean_y = 0;
      for (int k = 0; k < 4; ++k) {
        const Point2 p{d->p[3 - k][0] - 0.5, d->p[3 - k][1] - 0.5};
        const Point2 t = truth[static_cast<std::size_t>(k)];
        EXPECT_LT(distance(p, t), 0.15) << "roll " << roll << " corner " << k << ": " << p.x << "," << p.y << " vs "
                                        << t.x << "," << t.y;
        mean_x += (p.x - t.x) / 4;
        mean_y += (p.y - t.y) / 4;
      }
      EXPECT_LT(std::abs(mean_x), 0.05) << "roll " << roll;
      EXPECT_LT(std::abs(mean_y), 0.05) << "roll " << roll;
      EXPECT_EQ(d->hamming, 0);
    }
    EXPECT_TRUE(seen) << "roll " << roll;
    apriltag_detections_destroy(found);
  }
}

TEST(RenderScene, ArucoDetectsRenderedMarker) {
  const CameraModel cam = pinhole_camera();
  const auto dict = cv::aruco::getPredefinedDictionary(cv::aruco::DICT_4X4_50);
  const auto params = cv::aruco::DetectorParameters::create();
  params->cornerRefinementMethod = cv::aruco::CORNER_REFINE_SUBPIX;
  for (const double roll : {0.0, 90.0, 200.0}) {
    Scene s;
    s.family = Family::aruco4x4_50;
    s.id = 23;
    s.distort = false;
    s.pose = facing_pose(0.3, -25, 10, roll, -0.03, 0.02);
    s.seed = 9;
    const GreyImage img = render_scene(cam, s);
    if (roll == 0.0) maybe_dump(img, "aruco_23");
    std::vector<std::vector<cv::Point2f>> corners;
    std::vector<int> ids;
    cv::aruco::detectMarkers(as_mat(img), dict, corners, ids, params);
    const auto it = std::find(ids.begin(), ids.end(), 23);
    ASSERT_NE(it, ids.end()) << "roll " << roll;
    const auto& c = corners[static_cast<std::size_t>(it - ids.begin())];
    const Quad truth = project_marker_corners(cam, s);
    double mean_x = 0, mean_y = 0;
    for (std::size_t k = 0; k < 4; ++k) {
      // ArUco's corners are pixel-centred like ours, and in our order.
      EXPECT_LT(distance({c[k].x, c[k].y}, truth[k]), 0.5) << "roll " << roll << " corner " << k;
      mean_x += (c[k].x - truth[k].x) / 4;
      mean_y += (c[k].y - truth[k].y) / 4;
    }
    EXPECT_LT(std::abs(mean_x), 0.15) << "roll " << roll;
    EXPECT_LT(std::abs(mean_y), 0.15) << "roll " << roll;
  }
}

// ------------------------------------------------------------------ print

TEST(IdealMarkerImage, Frame8MatchesTheRingCells) {
  for (int id : {0, 165, 255}) {
    const GreyImage img = ideal_marker_image(Family::frame8, id, 200);
    ASSERT_EQ(img.width(), 200);
    ASSERT_EQ(img.height(), 200);
    const auto cells = frame8::ring_cells(id);
    for (int y = 0; y < 200; ++y) {
      for (int x = 0; x < 200; ++x) {
        const std::uint8_t cell = cells[static_cast<std::size_t>((y / 20) * 10 + x / 20)];
        int expected = 0;
        if (cell == 2) {
          // Line from 1.0 to 1.5 cells (20 to 30 px) in from the edge.
          const int in = std::min({x, 199 - x, y, 199 - y});
          expected = in < 30 ? 0 : 255;
        } else {
          expected = cell != 0 ? 255 : 0;
        }
        ASSERT_EQ(img.at(x, y), expected) << "id " << id << " at " << x << "," << y;
      }
    }
  }
  // frame8 has no quiet zone.
  EXPECT_EQ(ideal_marker_image(Family::frame8, 3, 100, true).width(), 100);
}

TEST(IdealMarkerImage, ArucoMatchesDrawMarker) {
  const auto dict = cv::aruco::getPredefinedDictionary(cv::aruco::DICT_4X4_50);
  for (int id : {0, 7, 23, 49}) {
    cv::Mat ref;
    cv::aruco::drawMarker(dict, id, 60, ref, 1);
    const GreyImage img = ideal_marker_image(Family::aruco4x4_50, id, 60, false);
    ASSERT_EQ(img.width(), 60);
    EXPECT_EQ(cv::countNonZero(ref != as_mat(img)), 0) << "id " << id;
    // With the quiet zone: one white cell (10 px) all round.
    const GreyImage qz = ideal_marker_image(Family::aruco4x4_50, id, 60, true);
    ASSERT_EQ(qz.width(), 80);
    EXPECT_EQ(cv::countNonZero(ref != as_mat(qz)(cv::Rect(10, 10, 60, 60))), 0);
    EXPECT_EQ(cv::countNonZero(as_mat(qz)(cv::Rect(0, 0, 80, 10)) != 255), 0);
  }
  EXPECT_THROW(ideal_marker_image(Family::aruco4x4_50, 50, 60), PrintError);
}

TEST(IdealMarkerImage, Tag36h11MatchesLibapriltag) {
  const std::unique_ptr<apriltag_family_t, void (*)(apriltag_family_t*)> fam(tag36h11_create(), tag36h11_destroy);
  for (int id : {0, 7, 586}) {
    // image_u8_destroy is in libapriltag-utils, which is not linked; it
    // frees the buffer and the struct, both calloc'd.
    const auto destroy = [](image_u8_t* im) {
      std::free(im->buf);
      std::free(im);
    };
    const std::unique_ptr<image_u8_t, decltype(destroy)> ref(apriltag_to_image(fam.get(), id), destroy);
    const GreyImage img = ideal_marker_image(Family::tag36h11, id, 80, true);  // 10 px per cell
    ASSERT_EQ(img.width(), 100);
    for (int y = 0; y < 100; ++y) {
      for (int x = 0; x < 100; ++x) {
        ASSERT_EQ(img.at(x, y), ref->buf[(y / 10) * ref->stride + x / 10]) << "id " << id << " at " << x << "," << y;
      }
    }
  }
}

TEST(IdealMarkerImage, AreaCoverageOffTheGrid) {
  // 15 px for 10 cells: cell edges fall mid-pixel and straddling pixels are grey.
  const GreyImage img = ideal_marker_image(Family::frame8, 165, 15);
  ASSERT_EQ(img.width(), 15);
  bool grey = false;
  for (int i = 0; i < 15 * 15; ++i) grey = grey || (img.data()[i] != 0 && img.data()[i] != 255);
  EXPECT_TRUE(grey);
  EXPECT_EQ(img.at(0, 0), 0);     // C0
  EXPECT_EQ(img.at(14, 0), 255);  // C1
  EXPECT_EQ(img.at(7, 7), 255);   // hole
}

std::string read_all(const std::filesystem::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::string s(static_cast<std::size_t>(std::filesystem::file_size(p)), '\0');
  f.read(s.data(), static_cast<std::streamsize>(s.size()));
  return s;
}

// One scratch directory per process, removed at exit.
std::filesystem::path temp_dir() {
  static const test_support::TempDir scratch{"markerd-test-render"};
  return scratch.path();
}

std::uint32_t be32(const std::string& s, std::size_t at) {
  return (static_cast<std::uint32_t>(static_cast<unsigned char>(s[at])) << 24) |
         (static_cast<std::uint32_t>(static_cast<unsigned char>(s[at + 1])) << 16) |
         (static_cast<std::uint32_t>(static_cast<unsigned char>(s[at + 2])) << 8) |
         static_cast<std::uint32_t>(static_cast<unsigned char>(s[at + 3]));
}

TEST(PrintableMarker, SvgHasThePhysicalSize) {
  const auto path = temp_dir() / "m.svg";
  write_printable_marker({Family::frame8, 165, 80, 10, 300}, path);
  const std::string svg = read_all(path);
  EXPECT_NE(svg.find("width=\"100mm\""), std::string::npos) << svg.substr(0, 400);
  EXPECT_NE(svg.find("height=\"100mm\""), std::string::npos);
  EXPECT_NE(svg.find("viewBox=\"0 0 100 100\""), std::string::npos);
  // The cut line is there (red hairline stroke).
  EXPECT_NE(svg.find("rgb(100%,0%,0%)"), std::string::npos);

  // ArUco's margin counts from its quiet zone: 60 mm + 2 * 10 mm + 2 * 10 mm.
  const auto aruco = temp_dir() / "a.svg";
  write_printable_marker({Family::aruco4x4_50, 3, 60, 10, 300}, aruco);
  EXPECT_NE(read_all(aruco).find("width=\"100mm\""), std::string::npos);
}

TEST(PrintableMarker, PdfMediaBoxIsTheSizeInPoints) {
  for (const auto& spec : {PrintSpec{Family::frame8, 0, 80, 10, 300}, PrintSpec{Family::frame8, 255, 52.5, 7.5, 300},
                           PrintSpec{Family::tag36h11, 7, 64, 10, 300}}) {
    const auto path = temp_dir() / "m.pdf";
    write_printable_marker(spec, path);
    const std::string pdf = read_all(path);
    ASSERT_EQ(pdf.rfind("%PDF", 0), 0U);
    std::smatch m;
    const std::regex box(R"(/MediaBox\s*\[\s*([-0-9.]+)\s+([-0-9.]+)\s+([-0-9.]+)\s+([-0-9.]+)\s*\])");
    ASSERT_TRUE(std::regex_search(pdf, m, box));
    const FamilyInfo& info = family_info(spec.family);
    const double page_mm =
        spec.size_mm * (info.size_cells + 2 * info.quiet_zone_cells) / info.size_cells + 2 * spec.margin_mm;
    EXPECT_NEAR(std::stod(m[1]), 0, 0.01);
    EXPECT_NEAR(std::stod(m[2]), 0, 0.01);
    EXPECT_NEAR(std::stod(m[3]), page_mm * 72 / 25.4, 0.01);
    EXPECT_NEAR(std::stod(m[4]), page_mm * 72 / 25.4, 0.01);
  }
}

TEST(PrintableMarker, PngHasDpiSizeAndPhys) {
  const auto path = temp_dir() / "m.png";
  write_printable_marker({Family::frame8, 165, 80, 10, 300}, path);
  const std::string png = read_all(path);
  ASSERT_GT(png.size(), 60U);
  ASSERT_EQ(png.compare(0, 8, "\x89PNG\r\n\x1a\n"), 0);
  ASSERT_EQ(png.compare(12, 4, "IHDR"), 0);
  const int px = static_cast<int>(std::lround(100 / 25.4 * 300));  // 1181
  EXPECT_EQ(be32(png, 16), static_cast<std::uint32_t>(px));
  EXPECT_EQ(be32(png, 20), static_cast<std::uint32_t>(px));
  // pHYs right after IHDR, with the pixels per metre and a valid CRC.
  ASSERT_EQ(be32(png, 33), 9U);
  ASSERT_EQ(png.compare(37, 4, "pHYs"), 0);
  EXPECT_EQ(be32(png, 41), static_cast<std::uint32_t>(std::lround(300 / 0.0254)));
  EXPECT_EQ(be32(png, 45), 11811U);
  EXPECT_EQ(png[49], 1);
  const cv::Mat crc_in(1, 13, CV_8U, const_cast<char*>(png.data() + 37));
  std::uint32_t crc = 0xFFFFFFFFU;
  for (int i = 0; i < 13; ++i) {
    crc ^= crc_in.at<std::uint8_t>(0, i);
    for (int k = 0; k < 8; ++k) crc = (crc & 1U) ? 0xEDB88320U ^ (crc >> 1) : crc >> 1;
  }
  EXPECT_EQ(be32(png, 50), ~crc);
  EXPECT_EQ(png.find("pHYs", 54), std::string::npos);

  // The decoded page has the marker where the layout puts it: 10 mm margin,
  // 8 mm cells, at 300 / 25.4 px per mm.
  const cv::Mat img = cv::imread(path.string(), cv::IMREAD_GRAYSCALE);
  ASSERT_EQ(img.cols, px);
  const auto at_mm = [&](double x, double y) {
    return img.at<std::uint8_t>(static_cast<int>(y * 300 / 25.4), static_cast<int>(x * 300 / 25.4));
  };
  EXPECT_LT(at_mm(14, 14), 30);    // C0 black
  EXPECT_GT(at_mm(86, 14), 225);   // C1 white
  EXPECT_LT(at_mm(86, 86), 30);    // C2 black
  EXPECT_LT(at_mm(50, 20), 30);    // the line, 1.0..1.5 cells in: 18..22 mm
  EXPECT_GT(at_mm(50, 50), 225);   // hole
  EXPECT_GT(at_mm(9.7, 50), 225);  // just outside the marker's left edge
  EXPECT_LT(at_mm(10.3, 50), 30);  // just inside: left edge row 5 is bit 4 of 165, black
  // The scale bar: 10 mm of ink starting at the margin, in the bottom margin.
  EXPECT_LT(at_mm(15, 95), 60);
  EXPECT_GT(at_mm(15, 93), 200);
}

TEST(PrintableMarker, RejectsBadInput) {
  const auto dir = temp_dir();
  try {
    write_printable_marker({}, dir / "marker.jpg");
    FAIL() << "no throw";
  } catch (const PrintError& e) {
    EXPECT_NE(std::string(e.what()).find("marker.jpg"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'.jpg'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(write_printable_marker({}, dir / "marker"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, 256, 80, 10, 300}, dir / "m.svg"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, -1, 80, 10, 300}, dir / "m.svg"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::aruco4x4_50, 50, 80, 10, 300}, dir / "m.pdf"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::tag36h11, 587, 80, 10, 300}, dir / "m.pdf"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, 1, 0, 10, 300}, dir / "m.svg"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, 1, 80, 1, 300}, dir / "m.svg"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, 1, 80, 10, 0}, dir / "m.png"), PrintError);
  EXPECT_THROW(write_printable_marker({Family::frame8, 1, 80, 10, 300}, dir / "no_such_dir" / "m.svg"), PrintError);
  EXPECT_NO_THROW(write_printable_marker({Family::tag36h11, 586, 80, 10, 300}, dir / "M.PNG"));
}

}  // namespace
}  // namespace markerd::detector
