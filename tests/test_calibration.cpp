// Camera calibration (board.hpp, calibration.hpp) on rendered views of each
// board through a known camera: the board's points where they truly are,
// the camera recovered within what calibrateCamera's own standard
// deviations allow, the views that do not fit turned down with their
// reasons, and the refusals.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numeric>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "calibration_views.hpp"
#include "markerd/detector/board.hpp"
#include "markerd/detector/calibration.hpp"
#include "markerd/detector/view_picker.hpp"
#include "render_test_helpers.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"

namespace markerd::detector {
namespace {

using calibration_test::distortion_disagreement_px;
using calibration_test::model_disagreement_px;
using calibration_test::ViewPlan;

struct RenderedViews {
  std::vector<CalibrationView> views;
  double worst_point_error_px = 0;  // found against true, over every point
  double mean_point_error_px = 0;
};

// Renders the planned views of `board` through `camera`, finds the board in
// each and measures the points found against where they truly are.
RenderedViews render_views(const BoardSpec& board, const CameraModel& camera,
                           const std::vector<ViewPlan>& plans = calibration_test::view_plans(),
                           const std::vector<ViewPlan>& partial_plans = {}) {
  const auto print = calibration_test::board_print(board);
  BoardDetector detector(board);
  RenderedViews out;
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < plans.size() + partial_plans.size(); ++i) {
    const MarkerPose pose = i < plans.size() ? calibration_test::plan_pose(camera, *print, plans[i])
                                             : calibration_test::pose_at(camera, partial_plans[i - plans.size()]);
    const GreyImage image = render_scene(camera, calibration_test::board_scene(print, pose, 100 + i));
    render_test::maybe_dump(image, fmt::format("calibration-{}-{}", to_string(board.type), i));
    CalibrationView view;
    view.name = fmt::format("view {}", i);
    view.points = detector.detect(image);
    auto truth = calibration_test::true_pixels(camera, *print, pose, view.points);
    if (board.type == BoardType::chessboard) truth = calibration_test::as_numbered(board, view.points, truth);
    for (std::size_t k = 0; k < truth.size(); ++k) {
      const double e = distance(truth[k], view.points.image[k]);
      out.worst_point_error_px = std::max(out.worst_point_error_px, e);
      sum += e;
      ++count;
    }
    out.views.push_back(std::move(view));
  }
  out.mean_point_error_px = count > 0 ? sum / static_cast<double>(count) : 0;
  return out;
}

// fx, fy, cx and cy within three of calibrateCamera's standard deviations
// and within 1% of the focal length; the views fitted well.
void expect_intrinsics(const CalibrationResult& r, const CameraModel& truth) {
  const CameraModel& c = r.camera;
  for (const auto& [name, fitted, expected, sigma] :
       {std::tuple{"fx", c.fx, truth.fx, r.std_fx}, std::tuple{"fy", c.fy, truth.fy, r.std_fy},
        std::tuple{"cx", c.cx, truth.cx, r.std_cx}, std::tuple{"cy", c.cy, truth.cy, r.std_cy}}) {
    EXPECT_LT(std::abs(fitted - expected), 3 * sigma)
        << name << " " << fitted << " against " << expected << ", sigma " << sigma;
    EXPECT_LT(std::abs(fitted - expected), 0.01 * truth.fx) << name << " " << fitted << " against " << expected;
  }
  EXPECT_LT(r.rms_px, 0.1);
}

std::string summary(const CalibrationResult& r, const CameraModel& truth, const std::vector<CalibrationView>& views) {
  const CameraModel& c = r.camera;
  return fmt::format(
      "rms {:.4f} px; fx {:.3f} ± {:.3f}, fy {:.3f} ± {:.3f}, cx {:.3f} ± {:.3f}, cy {:.3f} ± {:.3f}; k1 {:.5f} k2 "
      "{:.5f} p1 {:.6f} p2 {:.6f} k3 {:.5f}; distortion off by {:.3f} px at the image's border, {:.3f} px at the "
      "measured area's; the whole model {:.3f} and {:.3f} px",
      r.rms_px, c.fx, r.std_fx, c.fy, r.std_fy, c.cx, r.std_cx, c.cy, r.std_cy, c.dist[0], c.dist[1], c.dist[2],
      c.dist[3], c.dist[4], distortion_disagreement_px(truth, c, calibration_test::whole_image(truth)),
      distortion_disagreement_px(truth, c, calibration_test::measured_area(views)),
      model_disagreement_px(truth, c, calibration_test::whole_image(truth)),
      model_disagreement_px(truth, c, calibration_test::measured_area(views)));
}

class CalibrationOf : public ::testing::TestWithParam<BoardType> {
 protected:
  static BoardSpec board() {
    switch (GetParam()) {
      case BoardType::chessboard: return calibration_test::chessboard();
      case BoardType::charuco: return calibration_test::charuco();
      case BoardType::frame8: return calibration_test::frame8_board();
    }
    return {};
  }
};

// Twelve views of each board through a lens with barrel and tangential
// distortion (k1 -0.2, k2 0.05, p1 0.001, p2 -0.0015).
TEST_P(CalibrationOf, RecoversADistortedCamera) {
  const CameraModel truth = calibration_test::distorted_camera();
  const BoardSpec b = board();
  // A ChArUco or frame8 board also out in the image's corners.
  const bool partial = b.type != BoardType::chessboard;
  const RenderedViews rendered =
      render_views(b, truth, calibration_test::view_plans(),
                   partial ? calibration_test::partial_view_plans() : std::vector<ViewPlan>{});
  for (std::size_t i = 0; i < rendered.views.size(); ++i) {
    // A chessboard is found whole; the others nearly so where all is seen.
    const CalibrationView& v = rendered.views[i];
    EXPECT_GE(v.points.image.size(), static_cast<std::size_t>(b.point_count() * (i < 12 ? 3 : 1) / 4)) << v.name;
  }
  EXPECT_LT(rendered.worst_point_error_px, 0.3);
  EXPECT_LT(rendered.mean_point_error_px, 0.1);

  // k3 free, as OpenCV fits it: the lens agrees with the truth where the
  // views measured it; beyond, in the image's last 30 to 60 pixels, k2 and
  // k3 trade off and the corners are extrapolated.
  const CalibrationResult free = calibrate_camera(rendered.views, truth.width, truth.height);
  EXPECT_EQ(free.used_views(), static_cast<int>(rendered.views.size()));
  EXPECT_EQ(free.coverage(), 1.0);
  expect_intrinsics(free, truth);
  EXPECT_LT(distortion_disagreement_px(truth, free.camera, calibration_test::measured_area(rendered.views)), 0.5);
  std::cout << to_string(b.type) << ", k3 free: " << summary(free, truth, rendered.views) << "\n";

  // k3 held at zero, the model of the truth: it agrees to the image's edge.
  CalibrationOptions options;
  options.fix_k3 = true;
  const CalibrationResult held = calibrate_camera(rendered.views, truth.width, truth.height, options);
  expect_intrinsics(held, truth);
  EXPECT_EQ(held.camera.dist[4], 0.0);
  EXPECT_LT(distortion_disagreement_px(truth, held.camera, calibration_test::whole_image(truth)), 0.5);
  std::cout << to_string(b.type) << ", k3 held: " << summary(held, truth, rendered.views) << "\n";

  // The rational model, for wide-angle lenses: its three more terms fit the
  // same lens where the views measured it.
  options = {};
  options.model = DistortionModel::rational_polynomial;
  const CalibrationResult rational = calibrate_camera(rendered.views, truth.width, truth.height, options);
  EXPECT_EQ(rational.model, DistortionModel::rational_polynomial);
  EXPECT_GT(rational.std_dist[7], 0.0);
  EXPECT_LT(std::abs(rational.camera.fx - truth.fx), 0.01 * truth.fx);
  EXPECT_LT(std::abs(rational.camera.cx - truth.cx), 0.01 * truth.fx);
  EXPECT_LT(distortion_disagreement_px(truth, rational.camera, calibration_test::measured_area(rendered.views)), 0.5);
  std::cout << to_string(b.type) << ", rational: " << summary(rational, truth, rendered.views) << "\n";
  std::cout << to_string(b.type) << ": points found " << rendered.mean_point_error_px
            << " px from the truth on average, " << rendered.worst_point_error_px << " px at most\n";
}

INSTANTIATE_TEST_SUITE_P(Boards, CalibrationOf,
                         ::testing::Values(BoardType::chessboard, BoardType::charuco, BoardType::frame8),
                         [](const auto& p) { return std::string(to_string(p.param)); });

// A lens without distortion: none is found.
TEST(Calibration, RecoversAPinholeCamera) {
  const CameraModel truth = calibration_test::pinhole_camera();
  const RenderedViews rendered = render_views(calibration_test::frame8_board(), truth);
  const CalibrationResult r = calibrate_camera(rendered.views, truth.width, truth.height);
  expect_intrinsics(r, truth);
  EXPECT_LT(distortion_disagreement_px(truth, r.camera, calibration_test::measured_area(rendered.views)), 0.3);
  std::cout << "pinhole: " << summary(r, truth, rendered.views) << "\n";
}

// ------------------------------------------------------------ rejections

std::vector<ViewPlan> first_plans(std::size_t n) {
  auto plans = calibration_test::view_plans();
  plans.resize(n);
  return plans;
}

GreyImage render_board(const BoardSpec& board, const CameraModel& camera, const MarkerPose& pose) {
  return render_scene(camera, calibration_test::board_scene(calibration_test::board_print(board), pose, 7));
}

// A board of another kind, or of another dictionary, gives no points; a view
// that does not fit the others, too few points, points on one line and a
// view turned down before the fit are each reported with their reason,
// and the calibration is made of the rest.
TEST(Calibration, TurnsDownViewsThatDoNotFit) {
  const CameraModel truth = calibration_test::distorted_camera();
  RenderedViews rendered = render_views(calibration_test::frame8_board(), truth, first_plans(8));
  std::vector<CalibrationView>& views = rendered.views;

  const MarkerPose face_on = facing_pose(0.4, 0, 0, 0);
  const GreyImage chessboard_image = render_board(calibration_test::chessboard(), truth, face_on);
  BoardDetector frame8_detector(calibration_test::frame8_board());
  CalibrationView wrong_board{"a chessboard", frame8_detector.detect(chessboard_image), ""};
  EXPECT_TRUE(wrong_board.points.image.empty());
  // The other way round, and a ChArUco board of another dictionary.
  const GreyImage frame8_image = render_board(calibration_test::frame8_board(), truth, face_on);
  EXPECT_TRUE(BoardDetector(calibration_test::chessboard()).detect(frame8_image).image.empty());
  BoardSpec other_dictionary = calibration_test::charuco();
  other_dictionary.dictionary = "5x5_50";
  const GreyImage charuco_image = render_board(calibration_test::charuco(), truth, face_on);
  EXPECT_TRUE(BoardDetector(other_dictionary).detect(charuco_image).image.empty());
  EXPECT_GT(BoardDetector(calibration_test::charuco()).detect(charuco_image).image.size(), 20U);

  // Points moved by up to 2 px, as a board that moved during the exposure.
  CalibrationView moved = views[1];
  moved.name = "moved";
  for (std::size_t k = 0; k < moved.points.image.size(); ++k) {
    moved.points.image[k].x += 2.0 * std::sin(1.7 * static_cast<double>(k));
    moved.points.image[k].y += 2.0 * std::cos(2.3 * static_cast<double>(k));
  }
  CalibrationView few = views[2];
  few.name = "few";
  for (auto* list : {&few.points.image}) list->resize(6);
  few.points.object.resize(6);
  few.points.index.resize(6);
  // The markers' top edges of the first row: eight points on one line.
  CalibrationView line = views[0];
  line.name = "line";
  BoardPoints on_line;
  const double top = line.points.object.front().y();
  for (std::size_t k = 0; k < line.points.object.size(); ++k) {
    if (std::abs(line.points.object[k].y() - top) > 1e-12) continue;
    on_line.image.push_back(line.points.image[k]);
    on_line.object.push_back(line.points.object[k]);
    on_line.index.push_back(line.points.index[k]);
  }
  ASSERT_EQ(on_line.image.size(), 8U);
  line.points = on_line;
  const CalibrationView unreadable{"unreadable", {}, "cannot be read: truncated"};
  for (const auto& extra : {wrong_board, moved, few, line, unreadable}) views.push_back(extra);

  const CalibrationResult r = calibrate_camera(views, truth.width, truth.height);
  EXPECT_EQ(r.used_views(), 8);
  const auto reason = [&](const std::string& name) {
    for (const auto& v : r.views) {
      if (v.name == name) return v.rejected;
    }
    return std::string("(no such view)");
  };
  EXPECT_EQ(reason("a chessboard"), "too few points: 0 (at least 8)");
  EXPECT_EQ(reason("few"), "too few points: 6 (at least 8)");
  EXPECT_EQ(reason("line"), "its points lie on one line");
  EXPECT_EQ(reason("unreadable"), "cannot be read: truncated");
  EXPECT_EQ(reason("moved").rfind("reprojection error ", 0), 0U) << reason("moved");
  EXPECT_NE(reason("moved").find(" px, over 3 times the median view's ("), std::string::npos) << reason("moved");
  // A view turned down is still measured against the calibration, where it can be.
  for (const auto& v : r.views) {
    if (v.name == "moved") {
      EXPECT_GT(v.rms_px.value_or(0), 1.0);
    } else if (v.name == "few") {
      EXPECT_LT(v.rms_px.value_or(1), 0.2);
    } else if (v.name == "a chessboard" || v.name == "unreadable") {
      EXPECT_FALSE(v.rms_px.has_value());
    } else if (v.used()) {
      EXPECT_LT(v.rms_px.value_or(1), 0.1) << v.name;
    }
  }
  EXPECT_LT(std::abs(r.camera.fx - truth.fx), 0.01 * truth.fx);
  EXPECT_LT(r.rms_px, 0.1);

  // One more view required than fit: the refusal says how many were left.
  CalibrationOptions strict;
  strict.min_views = 9;
  try {
    (void)calibrate_camera(views, truth.width, truth.height, strict);
    ADD_FAILURE() << "no refusal";
  } catch (const CalibrationError& e) {
    EXPECT_EQ(std::string(e.what()),
              "8 views are left that fit the others, at least 9 are needed: take more views of the board, tilted and "
              "spread over the image");
    ASSERT_EQ(e.views().size(), views.size());
    EXPECT_EQ(e.views()[9].name, "moved");
    EXPECT_FALSE(e.views()[9].used());
  }
}

TEST(Calibration, TooFewViewsAreRefused) {
  const CameraModel truth = calibration_test::distorted_camera();
  const RenderedViews rendered = render_views(calibration_test::frame8_board(), truth, first_plans(4));
  try {
    (void)calibrate_camera(rendered.views, truth.width, truth.height);
    ADD_FAILURE() << "no refusal";
  } catch (const CalibrationError& e) {
    EXPECT_EQ(std::string(e.what()),
              "4 views are left with the board found, at least 5 are needed: take more views of the board, tilted and "
              "spread over the image");
    EXPECT_EQ(e.views().size(), 4U);
  }
  try {
    (void)calibrate_camera({}, truth.width, truth.height);
    ADD_FAILURE() << "no refusal";
  } catch (const CalibrationError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("no views are left with the board found, at least 5", 0), 0U) << e.what();
  }
}

// Views whose points all lie in the left half of the image leave the
// right half's distortion unmeasured.
TEST(Calibration, PoorCoverageIsRefused) {
  const CameraModel truth = calibration_test::distorted_camera();
  RenderedViews rendered = render_views(calibration_test::frame8_board(), truth, first_plans(9));
  for (CalibrationView& v : rendered.views) {
    BoardPoints left;
    for (std::size_t k = 0; k < v.points.image.size(); ++k) {
      if (v.points.image[k].x >= truth.width / 2.0 - 1) continue;
      left.image.push_back(v.points.image[k]);
      left.object.push_back(v.points.object[k]);
      left.index.push_back(v.points.index[k]);
    }
    v.points = left;
  }
  try {
    (void)calibrate_camera(rendered.views, truth.width, truth.height);
    ADD_FAILURE() << "no refusal";
  } catch (const CalibrationError& e) {
    EXPECT_EQ(std::string(e.what()),
              "the views' points reach 8 of the image's 16 regions (4x4), at least 75% are needed; none in the top "
              "edge, the top-right corner, the middle (2 regions), the right edge (2 regions), the bottom edge, the "
              "bottom-right corner: take views with the board there");
  }
  CalibrationOptions lenient;
  lenient.min_coverage = 0.5;
  EXPECT_EQ(calibrate_camera(rendered.views, truth.width, truth.height, lenient).coverage(), 0.5);
}

// A ChArUco or frame8 board partly out of the image gives the points in it.
// A 6x4 grid of board points, 40 px apart from (x, y), shifted by `dx`
// and with the points from `first` on only.
BoardPoints grid_points(double x, double y, double dx = 0, int first = 0) {
  BoardPoints p;
  for (int i = first; i < 24; ++i) {
    p.index.push_back(i);
    p.image.push_back({x + dx + 40.0 * (i % 6), y + 40.0 * (i / 6)});
    p.object.emplace_back(0.04 * (i % 6), 0.04 * (i / 6), 0);
  }
  return p;
}

TEST(ViewPicker, KeepsABoardHeldStillAndApartFromTheViewsKept) {
  ViewPicker picker(640, 480);  // 5% of the diagonal: 40 px
  EXPECT_EQ(picker.offer({}).verdict, PickVerdict::no_board);
  // The first frame has no frame before it to be still against.
  Pick pick = picker.offer(grid_points(100, 100));
  EXPECT_EQ(pick.verdict, PickVerdict::moving);
  EXPECT_FALSE(pick.moved_px.has_value()) << "nothing shared with the frame before";
  pick = picker.offer(grid_points(100, 100, 0.6));
  ASSERT_EQ(pick.verdict, PickVerdict::kept);
  EXPECT_EQ(pick.view, 0U);
  // Still again, but where the view just kept is: like it.
  pick = picker.offer(grid_points(100, 100, 0.9));
  EXPECT_EQ(pick.verdict, PickVerdict::like_a_kept_view);
  EXPECT_EQ(pick.view, 0U);
  // Moving: 3 px since the frame before.
  pick = picker.offer(grid_points(100, 100, 3.9));
  EXPECT_EQ(pick.verdict, PickVerdict::moving);
  EXPECT_NEAR(*pick.moved_px, 3.0, 1e-9);
  // Still 39 px from the view kept: still like it; 41 px: a view of its own.
  EXPECT_EQ(picker.offer(grid_points(139, 100)).verdict, PickVerdict::moving);
  EXPECT_EQ(picker.offer(grid_points(139, 100)).verdict, PickVerdict::like_a_kept_view);
  EXPECT_EQ(picker.offer(grid_points(141, 100)).verdict, PickVerdict::moving);
  pick = picker.offer(grid_points(141, 100));
  EXPECT_EQ(pick.verdict, PickVerdict::kept);
  EXPECT_EQ(pick.view, 1U);
  // Fewer points than a view needs (8).
  EXPECT_EQ(picker.offer(grid_points(300, 300, 0, 20)).verdict, PickVerdict::too_few_points);
  // Half the board out of view: the points shared with the frame before are
  // too few to call it still, however little they moved.
  pick = picker.offer(grid_points(300, 300, 0, 16));
  EXPECT_EQ(pick.verdict, PickVerdict::moving);
  EXPECT_EQ(pick.moved_px, 0.0);
  EXPECT_EQ(picker.offer(grid_points(300, 300, 0, 16)).verdict, PickVerdict::kept);
  ASSERT_EQ(picker.kept().size(), 3U);
  EXPECT_EQ(picker.kept()[2].image.size(), 8U);
  // Every kept point counted in its region, and the regions none reached named.
  EXPECT_EQ(std::accumulate(picker.region_points().begin(), picker.region_points().end(), 0), 24 + 24 + 8);
  EXPECT_EQ(picker.region_points()[0], 2 + 1) << "(100, 100), (140, 100) and (141, 100)";
  EXPECT_EQ(empty_regions(picker.region_points()),
            "the top-right corner, the right edge (2 regions), the left edge, the middle (2 regions), the bottom-left "
            "corner");
}

TEST(BoardDetector, FindsTheSeenPartOfAChArUcoOrFrame8Board) {
  const CameraModel camera = calibration_test::distorted_camera();
  for (const BoardSpec& board : {calibration_test::charuco(), calibration_test::frame8_board()}) {
    const auto print = calibration_test::board_print(board);
    const Point2 corner = camera.pixel_to_normalized({0.92 * camera.width, 0.9 * camera.height});
    const MarkerPose pose = facing_pose(0.25, -15, 10, 5, corner.x * 0.25, corner.y * 0.25);
    const GreyImage image = render_scene(camera, calibration_test::board_scene(print, pose, 3));
    BoardDetector detector(board);
    const BoardPoints found = detector.detect(image);
    EXPECT_GE(found.image.size(), 6U) << to_string(board.type);
    EXPECT_LT(found.image.size(), static_cast<std::size_t>(board.point_count() / 2)) << to_string(board.type);
    const auto truth = calibration_test::true_pixels(camera, *print, pose, found);
    for (std::size_t k = 0; k < truth.size(); ++k) {
      EXPECT_LT(distance(truth[k], found.image[k]), 0.3) << to_string(board.type) << " point " << found.index[k];
    }
  }
}

// ----------------------------------------------------------- board files

TEST(BoardFile, RoundTripsEachBoard) {
  const test_support::TempDir dir;
  for (const BoardSpec& board :
       {calibration_test::chessboard(), calibration_test::charuco(), calibration_test::frame8_board()}) {
    const auto path = dir / (std::string(to_string(board.type)) + ".toml");
    save_board(board, path);
    const BoardSpec back = load_board(path);
    EXPECT_EQ(back.type, board.type);
    EXPECT_EQ(back.cols, board.cols);
    EXPECT_EQ(back.rows, board.rows);
    EXPECT_EQ(back.size_m, board.size_m);
    EXPECT_EQ(back.marker_size_m, board.marker_size_m);
    EXPECT_EQ(back.spacing_m, board.spacing_m);
    EXPECT_EQ(back.dictionary, board.dictionary);
    EXPECT_EQ(back.ids, board.ids);
  }
  EXPECT_EQ(board_file_text(calibration_test::frame8_board()),
            "# A calibration board, as `markerctl marker --board` printed it: markerctl\n"
            "# calibrate --board FILE reads it (docs/calibration.md). Lengths in metres.\n"
            "# Measure the print: where the printer scaled it, write what the ruler says.\n"
            "type = \"frame8\"\ncols = 4\nrows = 3\nsize_m = 0.036  # a marker's outer edge\n"
            "spacing_m = 0.009  # paper between markers\n"
            "ids = [2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]  # row by row from the top left\n");
}

TEST(BoardFile, ErrorsNameTheFileLineAndKey) {
  const test_support::TempDir dir;
  const auto error = [&](const std::string& text) {
    const auto path = dir.write("board.toml", text);
    try {
      (void)load_board(path);
    } catch (const BoardError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind(path.string() + ":", 0), 0U) << what;
      return what.substr(path.string().size());
    }
    return std::string("(no error)");
  };
  const std::string chess = "type = \"chessboard\"\ncols = 9\nrows = 7\n";
  EXPECT_EQ(error(chess + "size_m = 0.02\ncolour = 1\n"),
            ":5: colour: unknown key (known here: type, cols, rows, size_m)");
  EXPECT_EQ(error(chess), ": missing key 'size_m' (a number)");
  EXPECT_EQ(error("type = \"hexboard\"\n"), ":1: type: must be \"chessboard\", \"charuco\" or \"frame8\"");
  EXPECT_EQ(error("type = \"chessboard\"\ncols = 2\nrows = 7\nsize_m = 0.02\n"),
            ":2: cols: must be from 3 to 100 (squares), got 2");
  const std::string charuco = "type = \"charuco\"\ncols = 7\nrows = 5\nsize_m = 0.02\n";
  EXPECT_EQ(error(charuco + "marker_size_m = 0.02\ndictionary = \"4x4_50\"\n"),
            ":5: marker_size_m: must be more than zero and less than the square (0.02 m), got 0.02 m");
  EXPECT_EQ(error(charuco + "marker_size_m = 0.015\ndictionary = \"4x4_5\"\n").substr(0, 45),
            ":6: dictionary: must be one of 4x4_50, 4x4_10");
  const std::string frame8 = "type = \"frame8\"\ncols = 2\nrows = 1\nsize_m = 0.04\nspacing_m = 0.01\n";
  EXPECT_EQ(error(frame8 + "ids = [5, 5]\n"), ":6: ids: id 5 is given twice");
  EXPECT_EQ(error(frame8 + "ids = [5]\n"), ":6: ids: must give one id for each of the 2x1 markers (2), got 1");
  EXPECT_EQ(error(frame8 + "ids = [5, 128]\n").substr(0, 30), ":6: ids: id 128 is near-unifor");
  EXPECT_EQ(error(frame8 + "ids = [5, \"x\"]\n"), ":6: ids: must be a list of whole numbers (frame8 ids, 0 to 255)");
  EXPECT_EQ(error("cols = [").rfind(":1:", 0), 0U);
}

TEST(BoardSpec, Frame8IdsLeaveOutTheNearUniformOnes) {
  EXPECT_EQ(frame8_board_ids(0, 4), (std::vector<int>{2, 3, 4, 5}));
  EXPECT_EQ(frame8_board_ids(124, 5), (std::vector<int>{124, 125, 130, 131, 132}));
  EXPECT_EQ(frame8_board_ids(0, 300).size(), 248U);
  EXPECT_EQ(calibration_test::chessboard().point_count(), 48);
  EXPECT_EQ(calibration_test::charuco().point_count(), 24);
  EXPECT_EQ(calibration_test::frame8_board().point_count(), 48);
  EXPECT_NEAR(calibration_test::frame8_board().width_m(), 4 * 0.036 + 3 * 0.009, 1e-15);
}

// ---------------------------------------------------------------- prints

TEST(PrintableBoard, PagesAreTrueToSize) {
  const test_support::TempDir dir;
  BoardPrintSpec spec;
  spec.board = calibration_test::chessboard();  // 180 x 140 mm, with 10 mm margins 200 x 160
  spec.margin_mm = 10;
  spec.dpi = 254;  // 10 px a millimetre
  EXPECT_DOUBLE_EQ(board_page_width_mm(spec), 200);
  EXPECT_DOUBLE_EQ(board_page_height_mm(spec), 160);
  write_printable_board(spec, dir / "board.svg");
  const std::string svg = test_support::read_file(dir / "board.svg");
  EXPECT_NE(svg.find("width=\"200mm\""), std::string::npos) << svg.substr(0, 300);
  EXPECT_NE(svg.find("height=\"160mm\""), std::string::npos) << svg.substr(0, 300);
  write_printable_board(spec, dir / "board.pdf");
  EXPECT_NE(test_support::read_file(dir / "board.pdf").find("/MediaBox [ 0 0 566.929134 453.543307 ]"),
            std::string::npos);
  write_printable_board(spec, dir / "board.png");
  const cv::Mat png = cv::imread((dir / "board.png").string(), cv::IMREAD_GRAYSCALE);
  ASSERT_EQ(png.cols, 2000);
  ASSERT_EQ(png.rows, 1600);
  // The same page as the renderer's picture, pixel for pixel.
  const GreyImage page = board_page_image(spec, 10000);
  ASSERT_EQ(page.width(), 2000);
  ASSERT_EQ(page.height(), 1600);
  int differ = 0;
  for (int y = 0; y < page.height(); ++y) {
    for (int x = 0; x < page.width(); ++x) differ += std::abs(page.at(x, y) - png.at<std::uint8_t>(y, x)) > 2 ? 1 : 0;
  }
  EXPECT_EQ(differ, 0);
  // The first square (top left) is ink, the next paper, from the margin on.
  EXPECT_EQ(page.at(105, 105), 0);
  EXPECT_EQ(page.at(305, 105), 255);
  EXPECT_EQ(page.at(95, 105), 255);
  EXPECT_EQ(page.at(1895, 1495), 0);  // the last: 9 x 7, both odd

  // The ink of each board: a chessboard's every other square; a ChArUco
  // board's black squares with a marker in each white one; frame8's rings.
  EXPECT_EQ(board_ink(calibration_test::chessboard()).size(), 32U);
  const auto charuco_ink = board_ink(calibration_test::charuco());
  EXPECT_EQ(std::count_if(charuco_ink.begin(), charuco_ink.end(), [](const InkRect& r) { return r.width == 0.025; }),
            18);

  EXPECT_THROW(write_printable_board(spec, dir / "board.jpg"), PrintError);
  spec.margin_mm = 2;
  EXPECT_THROW(write_printable_board(spec, dir / "board.pdf"), PrintError);
  spec.margin_mm = 10;
  spec.board.cols = 1;
  EXPECT_THROW(write_printable_board(spec, dir / "board.pdf"), BoardError);
}

}  // namespace
}  // namespace markerd::detector
