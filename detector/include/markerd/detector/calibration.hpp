#pragma once
// Camera calibration from views of a board (board.hpp): cv::calibrateCamera
// on the board's points, views that do not fit turned down one at a time,
// and the checks that what is left can determine the lens: enough views, and
// points over most of the image. The rules are docs/calibration.md's.

#include <array>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/detector/board.hpp"
#include "markerd/detector/camera_model.hpp"

namespace markerd::detector {

// OpenCV's model with 5 coefficients (k1 k2 p1 p2 k3; ROS's plumb_bob) or
// 8 (k4 k5 k6 too; ROS's rational_polynomial).
enum class DistortionModel { plumb_bob, rational_polynomial };

std::string_view to_string(DistortionModel model);
std::optional<DistortionModel> distortion_model_from_string(std::string_view name);

// One image's share: its name in reports, the board's points found in it,
// and, when it was turned down before the fit (unreadable, no board), why.
struct CalibrationView {
  std::string name;
  BoardPoints points;
  std::string rejected;
};

struct CalibrationOptions {
  DistortionModel model = DistortionModel::plumb_bob;
  // k3 held at zero (OpenCV's CALIB_FIX_K3; ROS camera_calibration's
  // default of two radial terms): a lens of moderate distortion needs no
  // k3, and a k3 fitted trades off against k2 beyond the points the views
  // reach, in the image's corners.
  bool fix_k3 = false;
  // Fewer views left than this after the rejections: no calibration.
  int min_views = 5;
  // A view with fewer points, or with its points on one line, is turned
  // down before the fit: it holds too little of the lens.
  int min_points = 8;
  // After each fit the worst view goes when its RMS reprojection error is
  // more than reject_factor times the median view's and more than
  // reject_floor_px; the fit is made again, until no view goes.
  double reject_factor = 3;
  double reject_floor_px = 0.5;
  // The image is cut into coverage_grid x coverage_grid regions; the views
  // used must put a point into at least this share of them, or the lens's
  // edges are guessed rather than measured.
  double min_coverage = 0.75;
};

inline constexpr int kCoverageGrid = 4;
using RegionPoints = std::array<int, kCoverageGrid * kCoverageGrid>;

// The coverage region a point of a width x height image falls in, row by
// row from the top left.
std::size_t coverage_region(const Point2& p, int width, int height);

// The regions without points, in words ("the top-left corner, the left edge
// (2 regions)"); empty when every region has some.
std::string empty_regions(const RegionPoints& region_points);

struct ViewResult {
  std::string name;
  int points = 0;
  // RMS reprojection error over the view's points through the calibration
  // (a view turned down: through its intrinsics and the view's own pose
  // fitted to them); none where there was nothing to measure.
  std::optional<double> rms_px;
  std::string rejected;  // empty when the view was used
  [[nodiscard]] bool used() const { return rejected.empty(); }
};

struct CalibrationResult {
  CameraModel camera;
  DistortionModel model = DistortionModel::plumb_bob;
  double rms_px = 0;              // over every point of the views used
  std::vector<ViewResult> views;  // in the input's order
  // calibrateCamera's standard deviations: of fx, fy, cx, cy, and of each
  // distortion coefficient in camera.dist's order (0 where not fitted).
  double std_fx = 0, std_fy = 0, std_cx = 0, std_cy = 0;
  std::array<double, 12> std_dist{};
  // Points of the views used in each region, row by row from the top left.
  RegionPoints region_points{};
  [[nodiscard]] double coverage() const;
  [[nodiscard]] int used_views() const;
};

// Refusals (too few views, too little of the image covered), with the
// views as far as they got so that a report can say which went and why.
class CalibrationError : public std::runtime_error {
 public:
  CalibrationError(const std::string& why, std::vector<ViewResult> views)
      : std::runtime_error(why), views_(std::move(views)) {}
  [[nodiscard]] const std::vector<ViewResult>& views() const { return views_; }

 private:
  std::vector<ViewResult> views_;
};

// Calibrates a camera of width x height pixels. Throws CalibrationError.
CalibrationResult calibrate_camera(const std::vector<CalibrationView>& views, int width, int height,
                                   const CalibrationOptions& options = {});

}  // namespace markerd::detector
