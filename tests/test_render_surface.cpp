// The renderer's solid marker: the print glued onto a rounded cover frame,
// what shows through the opening, a paper margin and objects in front.
// Checked against geometry worked out here by hand (arc lengths, roll
// heights, ray-plane cuts), not against the renderer's own functions.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "markerd/detector/render.hpp"
#include "render_test_helpers.hpp"

namespace markerd::detector {
namespace {

using namespace render_test;  // NOLINT(google-build-using-namespace): the shared helpers

// A marker-frame point (metres, any depth) as a pixel, without distortion.
Point2 project_xyz(const CameraModel& cam, const Scene& scene, double x, double y, double z) {
  const Eigen::Vector3d p = scene.pose.rotation * Eigen::Vector3d(x, y, z) + scene.pose.translation;
  return {cam.fx * p.x() / p.z() + cam.cx, cam.fy * p.y() / p.z() + cam.cy};
}

// A long lens, so that a millimetre on the marker is several pixels.
CameraModel long_lens() {
  CameraModel c = pinhole_camera();
  c.fx = 2000;
  c.fy = 2000;
  return c;
}

std::uint64_t fnv1a(const GreyImage& img) {
  std::uint64_t h = 1469598103934665603ULL;
  for (int i = 0; i < img.width() * img.height(); ++i) {
    h ^= img.data()[i];
    h *= 1099511628211ULL;
  }
  return h;
}

Scene plain(const MarkerPose& pose) {
  Scene s;
  s.pose = pose;
  s.clutter = false;
  s.distort = false;
  return s;
}

// ------------------------------------------------------------------ flat

// Hashes of these renders made by main before the solid marker existed: a
// flat print must still render byte for byte as it did.
TEST(RenderSurface, FlatPrintRendersAsBefore) {
  struct Case {
    double dist, yaw, pitch, roll, ox, oy;
    bool distort, cut, clutter;
    Family family;
    int id;
    std::uint64_t hash;
  };
  const std::vector<Case> cases = {
      {0.3, 0, 0, 0, 0, 0, true, false, true, Family::frame8, 165, 0x1513a6f380f7c5cdULL},
      {0.5, 35, -10, 20, 0.03, -0.02, true, true, true, Family::frame8, 77, 0x9e881b20342a4e9eULL},
      {0.25, -50, 15, 90, -0.05, 0.04, false, false, false, Family::frame8, 3, 0x3ff964898c1c2269ULL},
      {0.7, 20, 5, -30, 0.1, 0.05, true, true, false, Family::frame8, 255, 0x88fde0a92606b8f4ULL},
      {0.4, 10, -20, 45, 0, 0, false, true, true, Family::frame8, 0, 0x46240301cc53410bULL},
      {0.35, -25, 10, 200, -0.03, 0.02, true, false, true, Family::tag36h11, 7, 0x78e90ee40fd5e689ULL},
      {0.3, 30, 0, 0, 0.02, 0.01, false, false, true, Family::aruco4x4_50, 23, 0xb79a63437d3a6f6dULL},
  };
  const CameraModel cam = CameraModel::thesis_640x480();
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    Scene s;
    s.family = c.family;
    s.id = c.id;
    s.pose = facing_pose(c.dist, c.yaw, c.pitch, c.roll, c.ox, c.oy);
    s.distort = c.distort;
    s.cut_hole = c.cut;
    s.clutter = c.clutter;
    s.noise_sigma = 2;
    s.blur_sigma_px = 0.6;
    s.seed = 9;
    EXPECT_EQ(fnv1a(render_scene(cam, s)), c.hash) << "case " << i;
    // The light, the ambient share and an insert hidden behind an uncut
    // print change nothing on a flat print.
    s.light = Eigen::Vector3d(0.7, 0.2, -0.3);
    s.ambient = 0.05;
    if (!c.cut) s.insert = Insert::socket;
    EXPECT_EQ(fnv1a(render_scene(cam, s)), c.hash) << "case " << i << " with another light";
  }
}

// ------------------------------------------------------------------ frame

// Along image row y, the first x from x_from stepping by `dir` where the
// level crosses from ink towards `light`; returns the edge's sub-pixel
// position from the straddling pixel's area mix of ink and `light`.
double ink_edge(const GreyImage& img, int y, int x_from, int dir, double light) {
  const double ink = 0.05 * 255;
  for (int x = x_from; x >= 0 && x < img.width(); x += dir) {
    const double v = img.at(x, y);
    if (v > ink + 2) {
      const double ink_share = (light - v) / (light - ink);
      // The pixel spans x - 0.5 .. x + 0.5; its ink lies on the side we came from.
      return dir > 0 ? x - 0.5 + ink_share : x + 0.5 - ink_share;
    }
  }
  return std::nan("");
}

// Facing, the print follows the inner roll: its hole's edge (print
// coordinate 28 mm from the centre, the line's inner edge) lies 6 mm of
// arc down the 6 mm roll from the band's inner edge at 34 mm, i.e. at
// phi = 1 rad: in plan at 34 - 6 sin(1) = 28.95 mm, at depth
// 6 (1 - cos 1) = 2.76 mm. The paper cannot stretch, so the line's inner
// edge lies further out than the flat print's: the hole looks larger and
// the line narrower (it spans 28.95..32.04 mm in plan instead of 28..32).
TEST(RenderSurface, FacingFramePutsTheLinesInnerEdgeOnTheRoll) {
  const CameraModel cam = long_lens();
  Scene flat = plain(facing_pose(0.3, 0));
  flat.supersample = 6;
  Scene framed = flat;
  framed.frame = socket_frame();
  framed.insert = Insert::socket;
  framed.ambient = 1;  // no shading: the plastic is one level all over
  const GreyImage paper = render_scene(cam, flat);
  const GreyImage glued = render_scene(cam, framed);
  maybe_dump(glued, "frame_facing");

  const double phi = 1.0;
  const double plan = 0.034 - 0.006 * std::sin(phi), depth = 0.006 * (1 - std::cos(phi));
  const double expected_left = project_xyz(cam, framed, -plan, 0, -depth).x;
  const double expected_right = project_xyz(cam, framed, plan, 0, -depth).x;
  const double flat_left = project_xyz(cam, flat, -0.028, 0, 0).x;
  ASSERT_NEAR(expected_left, 128.75, 0.01);
  ASSERT_NEAR(flat_left, 133.33, 0.01);
  // Start in the middle of the line, at print coordinate 30 mm.
  const int mid_left = static_cast<int>(project_xyz(cam, framed, -0.0303, 0, -0.0013).x);
  const int mid_right = static_cast<int>(project_xyz(cam, framed, 0.0303, 0, -0.0013).x) + 1;
  const double plastic = 0.85 * 255;
  EXPECT_NEAR(ink_edge(glued, 240, mid_left, 1, plastic), expected_left, 0.1);
  EXPECT_NEAR(ink_edge(glued, 240, mid_right, -1, plastic), expected_right, 0.1);
  // The flat print's edge where it always was (white hole: paper).
  EXPECT_NEAR(ink_edge(paper, 240, mid_left, 1, 0.88 * 255), flat_left, 0.1);
  EXPECT_NEAR(ink_edge(paper, 240, 640 - mid_left, -1, 0.88 * 255), 640 - flat_left, 0.1);

  // Normalised shading: under the default light the flat band shows the
  // print exactly as a flat print does, and the rolls do not.
  framed.ambient = Scene{}.ambient;
  const GreyImage shaded = render_scene(cam, framed);
  int band_pixels = 0;
  for (double y : {-0.02, -0.008, 0.0, 0.011, 0.02}) {
    for (double x : {-0.0355, 0.0355}) {
      const Point2 p = project_xyz(cam, framed, x, y, 0);
      EXPECT_EQ(pixel_at(shaded, p), pixel_at(paper, p)) << x << "," << y;
      ++band_pixels;
    }
  }
  EXPECT_EQ(band_pixels, 10);
  // The outer roll beyond the print: plastic, lit on the left (towards the
  // light), darker on the right.
  const Point2 left_roll = project_xyz(cam, framed, -0.0415, 0, -0.0015);
  const Point2 right_roll = project_xyz(cam, framed, 0.0415, 0, -0.0015);
  EXPECT_LT(pixel_at(shaded, right_roll), static_cast<int>(plastic) - 40);
  EXPECT_GT(pixel_at(shaded, left_roll), pixel_at(shaded, right_roll) + 40);
}

// Turned, the camera looks over the near side's inner roll: the roll is
// turned away from it beyond the silhouette, where the camera's ray grazes
// it, so the print there (the line's innermost part) is hidden and the
// insert shows beyond. On the far side the roll faces the camera and the
// whole line shows, wider than on the flat print.
TEST(RenderSurface, TurnedFrameHidesTheNearSidesLineBehindTheRoll) {
  const CameraModel cam = long_lens();
  Scene flat = plain(facing_pose(0.3, 55));
  flat.supersample = 4;
  Scene framed = flat;
  framed.frame = socket_frame();
  framed.insert = Insert::socket;
  framed.ambient = 1;
  const GreyImage paper = render_scene(cam, flat);
  const GreyImage glued = render_scene(cam, framed);
  maybe_dump(glued, "frame_turned_55");
  const Eigen::Vector3d eye = -(framed.pose.rotation.transpose() * framed.pose.translation);
  ASSERT_LT(eye.x(), -0.1);  // the camera is on the marker's -X side: that side is near

  // The roll's point at angle phi on the near (-X) side at row y = 0, and
  // the silhouette: where the roll's normal is square to the view.
  const auto roll_point = [](double phi) {
    return Eigen::Vector3d(-(0.034 - 0.006 * std::sin(phi)), 0, -0.006 * (1 - std::cos(phi)));
  };
  const auto facing_eye = [&](double phi) {
    const Eigen::Vector3d normal(std::sin(phi), 0, std::cos(phi));
    return normal.dot(eye - roll_point(phi));
  };
  double lo = 0, hi = std::numbers::pi / 2;
  for (int i = 0; i < 60; ++i) (facing_eye(0.5 * (lo + hi)) > 0 ? lo : hi) = 0.5 * (lo + hi);
  const double silhouette = lo;
  // The paper reaches phi = 1 (see the facing test): the silhouette hides a part of it.
  ASSERT_LT(silhouette, 0.85);
  const Eigen::Vector3d seen = roll_point(silhouette), paper_end = roll_point(1.0);
  const double seen_x = project_xyz(cam, framed, seen.x(), 0, seen.z()).x;
  const double paper_end_x = project_xyz(cam, framed, paper_end.x(), 0, paper_end.z()).x;
  const double flat_x = project_xyz(cam, flat, -0.028, 0, 0).x;
  // The paper beyond the silhouette would project back over the visible
  // line: the line ends at the silhouette, not at the paper's end.
  ASSERT_GT(seen_x - paper_end_x, 1.5) << seen_x << " " << paper_end_x << " " << flat_x;
  const int line_middle = static_cast<int>(project_xyz(cam, framed, -0.031, 0, -0.0005).x);
  EXPECT_NEAR(ink_edge(glued, 240, line_middle, 1, 0.85 * 255), seen_x, 0.15);
  // Pixels that show the line on the flat print show the insert.
  int hidden = 0;
  for (int x = static_cast<int>(std::ceil(seen_x + 0.5)); x < flat_x - 0.5; ++x) {
    EXPECT_LT(paper.at(x, 240), 20) << x;
    // Seen at a slant past the silhouette: the plate or, this steep, the
    // socket's recess (0.3 of the plastic's level, 65).
    EXPECT_GT(glued.at(x, 240), 50) << x;
    ++hidden;
  }
  EXPECT_GE(hidden, 4);

  // The far side: the paper's end, at phi = 1, in full view.
  const Eigen::Vector3d far_end(-paper_end.x(), 0, paper_end.z());
  const double far_x = project_xyz(cam, framed, far_end.x(), 0, far_end.z()).x;
  const int far_middle = static_cast<int>(project_xyz(cam, framed, 0.031, 0, -0.0005).x) + 1;
  EXPECT_NEAR(ink_edge(glued, 240, far_middle, -1, 0.85 * 255), far_x, 0.15);
}

// ------------------------------------------------------------------ insert

TEST(RenderSurface, SocketRecessAndPinHolesAreDark) {
  const CameraModel cam = pinhole_camera();
  Scene s = plain(facing_pose(0.3, 0));
  s.frame = socket_frame();
  s.insert = Insert::socket;
  const GreyImage img = render_scene(cam, s);
  maybe_dump(img, "socket_facing");
  // The default frame's inner roll ends 6 mm down; the plate lies 2 mm
  // below, the recess 17.5 mm below that.
  const double plate = -0.008, floor = plate - 0.0175;
  const int plastic = static_cast<int>(std::lround(0.85 * 255));
  EXPECT_EQ(pixel_at(img, project_xyz(cam, s, 0.024, 0.024, plate)), plastic);
  EXPECT_EQ(pixel_at(img, project_xyz(cam, s, 0.0, 0.012, floor)), 65);  // 0.3 of the plastic
  EXPECT_EQ(pixel_at(img, project_xyz(cam, s, -0.012, -0.008, floor)), 65);
  for (double x : {-0.0095, 0.0095}) EXPECT_LT(pixel_at(img, project_xyz(cam, s, x, 0, floor)), 10) << x;

  // A cut hole without a frame: the socket where a default frame holds it.
  Scene cut = plain(facing_pose(0.3, 0));
  cut.cut_hole = true;
  cut.insert = Insert::socket;
  const GreyImage through = render_scene(cam, cut);
  EXPECT_EQ(pixel_at(through, project_xyz(cam, cut, 0.0, 0.012, floor)), 65);
  EXPECT_LT(pixel_at(through, project_xyz(cam, cut, 0.0095, 0, floor)), 10);
  EXPECT_EQ(pixel_at(through, project_xyz(cam, cut, 0.024, 0.024, plate)), plastic);
  // Without an insert the hole shows the background, as it always did.
  cut.insert = Insert::none;
  EXPECT_EQ(pixel_at(render_scene(cam, cut), project_xyz(cam, cut, 0.0, 0.012, 0)), 128);

  // A rocker fills the opening near the band's level.
  s.insert = Insert::rocker;
  const GreyImage rocker = render_scene(cam, s);
  EXPECT_EQ(pixel_at(rocker, project_xyz(cam, s, 0.0, 0.0, -0.002)), plastic);
  EXPECT_EQ(pixel_at(rocker, project_xyz(cam, s, 0.015, -0.02, -0.002)), plastic);

  // The switch frame's 3 mm rolls leave the band from 31 to 40 mm out:
  // the line's outer part (31..32 mm) lies on the band, as flat as paper;
  // its rocker stands 1 mm below the band.
  s.frame = switch_frame();
  const GreyImage flatter = render_scene(cam, s);
  maybe_dump(flatter, "switch_facing");
  EXPECT_EQ(pixel_at(flatter, project_xyz(cam, s, -0.0315, 0.0, 0)), kBlack);
  EXPECT_EQ(pixel_at(flatter, project_xyz(cam, s, 0.0, 0.0, -0.001)), plastic);
}

// ------------------------------------------------------------------ occluders

// Whether the pixel's whole footprint (its four corners) sees the
// rectangle lo..hi at height z, by cutting its corner rays with that plane.
int corners_inside(const CameraModel& cam, const Scene& s, int x, int y, Eigen::Vector2d lo, Eigen::Vector2d hi,
                   double z) {
  const Eigen::Matrix3d rt = s.pose.rotation.transpose();
  const Eigen::Vector3d eye = -(rt * s.pose.translation);
  int n = 0;
  for (double dx : {-0.5, 0.5}) {
    for (double dy : {-0.5, 0.5}) {
      const Eigen::Vector3d d = rt * Eigen::Vector3d((x + dx - cam.cx) / cam.fx, (y + dy - cam.cy) / cam.fy, 1);
      const Eigen::Vector3d p = eye + d * ((z - eye.z()) / d.z());
      n += p.x() > lo.x() && p.x() < hi.x() && p.y() > lo.y() && p.y() < hi.y() ? 1 : 0;
    }
  }
  return n;
}

TEST(RenderSurface, OccluderCoversOneSideAndNothingElse) {
  const Occluder left = side_occluder(MarkerSide::left, 0.08, 0.2, 0.2F, 0.03);
  ASSERT_EQ(left.polygon.size(), 4U);
  // It reaches 0.2 of the size in from the left edge (x = -0.04 + 0.016).
  Eigen::Vector2d lo = left.polygon[0], hi = left.polygon[0];
  for (const auto& p : left.polygon) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  EXPECT_NEAR(hi.x(), -0.024, 1e-12);
  EXPECT_LT(lo.x(), -0.1);
  EXPECT_LT(lo.y(), -0.1);
  EXPECT_GT(hi.y(), 0.1);

  const CameraModel cam = pinhole_camera();
  for (bool framed : {false, true}) {
    Scene s = plain(facing_pose(0.4, 20, 5));
    if (framed) s.frame = socket_frame(), s.insert = Insert::socket;
    const GreyImage open = render_scene(cam, s);
    s.occluders.push_back(left);
    const GreyImage covered = render_scene(cam, s);
    maybe_dump(covered, framed ? "occluded_frame" : "occluded_flat");
    int in = 0, out = 0;
    for (int y = 0; y < 480; ++y) {
      for (int x = 0; x < 640; ++x) {
        const int corners = corners_inside(cam, s, x, y, lo, hi, left.z_m);
        if (corners == 4) {
          ASSERT_EQ(covered.at(x, y), 51) << x << "," << y << " framed " << framed;  // 0.2 * 255, not shaded
          ++in;
        } else if (corners == 0) {
          ASSERT_EQ(covered.at(x, y), open.at(x, y)) << x << "," << y << " framed " << framed;
          ++out;
        }
      }
    }
    EXPECT_GT(in, 10000);
    EXPECT_GT(out, 100000);
    // And it does cover the marker: its left side's line was there before.
    EXPECT_LT(pixel_at(open, project_xyz(cam, s, -0.03, 0.0, framed ? -0.001 : 0)), 20);
    EXPECT_EQ(pixel_at(covered, project_xyz(cam, s, -0.03, 0.0, 0)), 51);
  }
}

// ------------------------------------------------------------------ paper

TEST(RenderSurface, PaperMarginIsWhiteAroundThePrint) {
  const CameraModel cam = pinhole_camera();
  Scene s = plain(facing_pose(0.4, 15, -10));
  const GreyImage bare = render_scene(cam, s);
  s.paper_margin_m = 0.01;
  const GreyImage margin = render_scene(cam, s);
  maybe_dump(margin, "paper_margin");
  for (const auto& [x, y] : std::vector<std::pair<double, double>>{
           {0.045, 0}, {-0.045, 0.01}, {0.0, 0.045}, {0.02, -0.045}, {0.047, 0.047}, {-0.047, -0.047}}) {
    const Point2 p = project_xyz(cam, s, x, y, 0);
    EXPECT_EQ(pixel_at(margin, p), kWhite) << x << "," << y;
    EXPECT_EQ(pixel_at(bare, p), 128) << x << "," << y;
  }
  // Beyond the paper, the background.
  EXPECT_EQ(pixel_at(margin, project_xyz(cam, s, 0.053, 0, 0)), 128);
  EXPECT_EQ(pixel_at(margin, project_xyz(cam, s, 0.0, -0.053, 0)), 128);
  // The print itself is unchanged: every pixel well inside its outline.
  int inside = 0;
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 640; ++x) {
      if (bare.at(x, y) == 128) continue;  // outside the print
      bool deep = true;
      for (int k = -2; k <= 2 && deep; ++k) deep = bare.at(x + k, y) != 128 && bare.at(x, y + k) != 128;
      if (!deep) continue;
      ASSERT_EQ(margin.at(x, y), bare.at(x, y)) << x << "," << y;
      ++inside;
    }
  }
  EXPECT_GT(inside, 3000);

  // On a frame the paper follows the outer roll down to the outline:
  // beyond the print, white paper where the plastic showed.
  Scene framed = plain(facing_pose(0.3, 0));
  framed.frame = socket_frame();
  framed.ambient = 1;
  const Point2 roll = project_xyz(cam, framed, 0.0415, 0.0, -0.0015);
  const int plastic = static_cast<int>(std::lround(0.85 * 255));
  EXPECT_EQ(pixel_at(render_scene(cam, framed), roll), plastic);
  framed.paper_margin_m = 0.01;
  EXPECT_EQ(pixel_at(render_scene(cam, framed), roll), kWhite);
}

TEST(RenderSurface, FlatBackgroundTakesItsGrey) {
  Scene s = plain(facing_pose(0.4, 0));
  s.background_grey = 90;
  const GreyImage bg = render_background(pinhole_camera(), s);
  EXPECT_EQ(*std::min_element(bg.data(), bg.data() + 640 * 480), 90);
  EXPECT_EQ(*std::max_element(bg.data(), bg.data() + 640 * 480), 90);
  s.exposure = 0.5;
  EXPECT_EQ(render_background(pinhole_camera(), s).at(10, 10), 45);
}

// ------------------------------------------------------------------ inputs

void expect_rejected(const Scene& s, const std::string& field) {
  try {
    (void)render_scene(pinhole_camera(), s);
    ADD_FAILURE() << "no throw for " << field;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

TEST(RenderSurface, RejectsBadInputNamingTheField) {
  const Scene good = [] {
    Scene s = plain(facing_pose(0.4, 0));
    s.frame = socket_frame();
    s.insert = Insert::socket;
    s.occluders.push_back(side_occluder(MarkerSide::top, 0.08));
    return s;
  }();
  EXPECT_NO_THROW((void)render_scene(pinhole_camera(), good));
  const auto with_frame = [&](auto edit) {
    Scene s = good;
    edit(*s.frame);
    return s;
  };
  expect_rejected(with_frame([](CoverFrame& f) { f.outer_m = -0.086; }), "frame.outer_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.opening_m = 0; }), "frame.opening_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.height_m = -0.01; }), "frame.height_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.opening_m = 0.09; }), "frame.opening_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.outer_roll_m = -0.001; }), "frame.outer_roll_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.inner_roll_m = 0.011; }), "frame.inner_roll_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.outer_roll_m = 0.009, f.inner_roll_m = 0.009; }),
                  "frame.inner_roll_m with outer_roll_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.corner_radius_m = 0.05; }), "frame.corner_radius_m");
  expect_rejected(with_frame([](CoverFrame& f) { f.reflectance = 1.5F; }), "frame.reflectance");
  Scene s = good;
  s.occluders.push_back({{{0, 0}, {0.01, 0}}, 0.03, 0.1F});
  expect_rejected(s, "occluders[1].polygon");
  s = good;
  s.occluders[0].z_m = -0.01;
  expect_rejected(s, "occluders[0].z_m");
  s = good;
  s.paper_margin_m = -0.01;
  expect_rejected(s, "paper_margin_m");
  s = good;
  s.insert_reflectance = -0.1F;
  expect_rejected(s, "insert_reflectance");
  s = good;
  s.background_grey = 256;
  expect_rejected(s, "background_grey");
  s = good;
  s.ambient = 0;
  expect_rejected(s, "ambient");
  s = good;
  s.light = Eigen::Vector3d::Zero();
  expect_rejected(s, "light");
  EXPECT_THROW(side_occluder(MarkerSide::left, 0.08, 1.5), std::invalid_argument);
  EXPECT_THROW(side_occluder(MarkerSide::left, -0.08), std::invalid_argument);
}

}  // namespace
}  // namespace markerd::detector
