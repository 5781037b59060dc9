#include "markerd/detector/calibration.hpp"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include <fmt/format.h>

namespace markerd::detector {
namespace {

// The views a fit takes, as OpenCV takes them.
struct FitInput {
  std::vector<std::vector<cv::Point3f>> object;
  std::vector<std::vector<cv::Point2f>> image;
};

struct Fit {
  cv::Mat camera_matrix;
  cv::Mat distortion;
  cv::Mat std_intrinsics;
  std::vector<double> view_rms;
  double rms = 0;
};

std::vector<cv::Point3f> object_points(const BoardPoints& p) {
  std::vector<cv::Point3f> out;
  out.reserve(p.object.size());
  for (const auto& o : p.object) {
    out.emplace_back(static_cast<float>(o.x()), static_cast<float>(o.y()), static_cast<float>(o.z()));
  }
  return out;
}

std::vector<cv::Point2f> image_points(const BoardPoints& p) {
  std::vector<cv::Point2f> out;
  out.reserve(p.image.size());
  for (const auto& i : p.image) out.emplace_back(static_cast<float>(i.x), static_cast<float>(i.y));
  return out;
}

Fit fit(const FitInput& in, cv::Size size, const CalibrationOptions& options) {
  Fit f;
  std::vector<cv::Mat> rvecs, tvecs;
  cv::Mat std_extrinsics, per_view;
  int flags = options.model == DistortionModel::rational_polynomial ? cv::CALIB_RATIONAL_MODEL : 0;
  if (options.fix_k3) flags |= cv::CALIB_FIX_K3;
  // More iterations than OpenCV's 30: a strong lens seen from few views
  // may still be moving at 30.
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, DBL_EPSILON);
  f.rms = cv::calibrateCamera(in.object, in.image, size, f.camera_matrix, f.distortion, rvecs, tvecs, f.std_intrinsics,
                              std_extrinsics, per_view, flags, criteria);
  if (!std::isfinite(f.rms) || !cv::checkRange(f.camera_matrix) || !cv::checkRange(f.distortion)) {
    throw std::runtime_error("the fit did not converge (values that are not finite)");
  }
  f.view_rms.assign(per_view.begin<double>(), per_view.end<double>());
  return f;
}

// A view's RMS reprojection error through fixed intrinsics, its pose fitted
// to them: for the views the fit did not take.
std::optional<double> view_rms(const BoardPoints& p, const cv::Mat& camera_matrix, const cv::Mat& distortion) {
  if (p.image.size() < 4) return std::nullopt;
  const auto object = object_points(p);
  const auto image = image_points(p);
  cv::Mat rvec, tvec;
  if (!cv::solvePnP(object, image, camera_matrix, distortion, rvec, tvec)) return std::nullopt;
  std::vector<cv::Point2f> projected;
  cv::projectPoints(object, rvec, tvec, camera_matrix, distortion, projected);
  double sum = 0;
  for (std::size_t i = 0; i < image.size(); ++i) {
    const double dx = projected[i].x - image[i].x, dy = projected[i].y - image[i].y;
    sum += dx * dx + dy * dy;
  }
  return std::sqrt(sum / static_cast<double>(image.size()));
}

// Whether a view's points lie (nearly) on one line: their spread across
// the main direction under a twentieth of their spread along it.
bool on_one_line(const BoardPoints& p) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& o : p.object) mean += o.head<2>();
  mean /= static_cast<double>(p.object.size());
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const auto& o : p.object) {
    const Eigen::Vector2d d = o.head<2>() - mean;
    scatter += d * d.transpose();
  }
  // The scatter's eigenvalues, in closed form for a symmetric 2x2.
  const double mid = (scatter(0, 0) + scatter(1, 1)) / 2;
  const double half = std::hypot((scatter(0, 0) - scatter(1, 1)) / 2, scatter(0, 1));
  const double across = std::max(mid - half, 0.0), along = mid + half;
  return !(std::sqrt(across) >= 0.05 * std::sqrt(along));
}

double median(std::vector<double> values) {
  const std::size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid), values.end());
  if (values.size() % 2 == 1) return values[mid];
  const double upper = values[mid];
  return (upper + *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid))) / 2;
}

std::string region_name(int col, int row) {
  constexpr int last = kCoverageGrid - 1;
  const bool left = col == 0, right = col == last, top = row == 0, bottom = row == last;
  if ((left || right) && (top || bottom)) {
    return fmt::format("the {}-{} corner", top ? "top" : "bottom", left ? "left" : "right");
  }
  if (top) return "the top edge";
  if (bottom) return "the bottom edge";
  if (left) return "the left edge";
  if (right) return "the right edge";
  return "the middle";
}

}  // namespace

std::string_view to_string(DistortionModel model) {
  return model == DistortionModel::rational_polynomial ? "rational_polynomial" : "plumb_bob";
}

std::optional<DistortionModel> distortion_model_from_string(std::string_view name) {
  if (name == "plumb_bob") return DistortionModel::plumb_bob;
  if (name == "rational_polynomial") return DistortionModel::rational_polynomial;
  return std::nullopt;
}

std::string empty_regions(const RegionPoints& region_points) {
  std::vector<std::pair<std::string, int>> places;
  for (int row = 0; row < kCoverageGrid; ++row) {
    for (int col = 0; col < kCoverageGrid; ++col) {
      if (region_points[static_cast<std::size_t>(row * kCoverageGrid + col)] > 0) continue;
      const std::string name = region_name(col, row);
      const auto it = std::find_if(places.begin(), places.end(), [&](const auto& p) { return p.first == name; });
      if (it == places.end()) {
        places.emplace_back(name, 1);
      } else {
        ++it->second;
      }
    }
  }
  std::string text;
  for (const auto& [name, count] : places) {
    text += fmt::format("{}{}{}", text.empty() ? "" : ", ", name,
                        count > 1 ? fmt::format(" ({} regions)", count) : std::string());
  }
  return text;
}

std::size_t coverage_region(const Point2& p, int width, int height) {
  const int col = std::clamp(static_cast<int>(std::floor((p.x + 0.5) * kCoverageGrid / width)), 0, kCoverageGrid - 1);
  const int row = std::clamp(static_cast<int>(std::floor((p.y + 0.5) * kCoverageGrid / height)), 0, kCoverageGrid - 1);
  return static_cast<std::size_t>(row * kCoverageGrid + col);
}

double CalibrationResult::coverage() const {
  const auto covered = std::count_if(region_points.begin(), region_points.end(), [](int n) { return n > 0; });
  return static_cast<double>(covered) / static_cast<double>(region_points.size());
}

int CalibrationResult::used_views() const {
  return static_cast<int>(std::count_if(views.begin(), views.end(), [](const ViewResult& v) { return v.used(); }));
}

CalibrationResult calibrate_camera(const std::vector<CalibrationView>& views, int width, int height,
                                   const CalibrationOptions& options) {
  if (width <= 0 || height <= 0) throw std::invalid_argument("calibrate_camera: the image has no size");
  CalibrationResult result;
  result.model = options.model;
  result.views.resize(views.size());
  std::vector<std::size_t> used;
  for (std::size_t i = 0; i < views.size(); ++i) {
    const CalibrationView& v = views[i];
    ViewResult& r = result.views[i];
    r.name = v.name;
    r.points = static_cast<int>(v.points.image.size());
    if (v.points.image.size() != v.points.object.size()) {
      throw std::invalid_argument(fmt::format("calibrate_camera: {}: image and board points differ in number", v.name));
    }
    if (!v.rejected.empty()) {
      r.rejected = v.rejected;
    } else if (r.points < options.min_points) {
      r.rejected = fmt::format("too few points: {} (at least {})", r.points, options.min_points);
    } else if (on_one_line(v.points)) {
      r.rejected = "its points lie on one line";
    } else {
      used.push_back(i);
    }
  }
  const auto too_few = [&](std::string_view stage) {
    return CalibrationError(
        fmt::format("{} view{} {} {}, at least {} are needed: take more views of the board, tilted and spread over "
                    "the image",
                    used.empty() ? std::string("no") : std::to_string(used.size()), used.size() == 1 ? "" : "s",
                    used.size() == 1 ? "is" : "are", stage, options.min_views),
        result.views);
  };
  if (static_cast<int>(used.size()) < options.min_views) throw too_few("left with the board found");

  const cv::Size size(width, height);
  Fit f;
  // The worst view goes while it is far above the median; each removal
  // changes the fit, so the rest are judged again by the next one.
  for (;;) {
    FitInput in;
    for (const std::size_t i : used) {
      in.object.push_back(object_points(views[i].points));
      in.image.push_back(image_points(views[i].points));
    }
    try {
      f = fit(in, size, options);
    } catch (const cv::Exception& e) {
      throw CalibrationError(fmt::format("cv::calibrateCamera failed on {} views: {}", used.size(), e.err),
                             result.views);
    } catch (const std::runtime_error& e) {
      throw CalibrationError(fmt::format("cv::calibrateCamera failed on {} views: {}", used.size(), e.what()),
                             result.views);
    }
    for (std::size_t k = 0; k < used.size(); ++k) result.views[used[k]].rms_px = f.view_rms[k];
    const double mid = median(f.view_rms);
    const auto worst =
        static_cast<std::size_t>(std::max_element(f.view_rms.begin(), f.view_rms.end()) - f.view_rms.begin());
    const double limit = std::max(options.reject_factor * mid, options.reject_floor_px);
    if (!(f.view_rms[worst] > limit)) break;
    result.views[used[worst]].rejected =
        fmt::format("reprojection error {:.3f} px, over {:g} times the median view's ({:.3f} px) and over {:g} px",
                    f.view_rms[worst], options.reject_factor, mid, options.reject_floor_px);
    used.erase(used.begin() + static_cast<std::ptrdiff_t>(worst));
    if (static_cast<int>(used.size()) < options.min_views) throw too_few("left that fit the others");
  }

  const auto* k = f.camera_matrix.ptr<double>();
  result.camera.width = width;
  result.camera.height = height;
  result.camera.fx = k[0];
  result.camera.fy = k[4];
  result.camera.cx = k[2];
  result.camera.cy = k[5];
  const std::size_t coefficients = std::min<std::size_t>(f.distortion.total(), result.camera.dist.size());
  for (std::size_t i = 0; i < coefficients; ++i) {
    result.camera.dist[i] = f.distortion.at<double>(static_cast<int>(i));
  }
  // stdDeviationsIntrinsics: fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 s1..s4 tauX tauY.
  const auto* s = f.std_intrinsics.ptr<double>();
  result.std_fx = s[0];
  result.std_fy = s[1];
  result.std_cx = s[2];
  result.std_cy = s[3];
  for (std::size_t i = 0; i < coefficients; ++i) result.std_dist[i] = s[4 + i];
  result.rms_px = f.rms;

  for (std::size_t i = 0; i < views.size(); ++i) {
    ViewResult& r = result.views[i];
    if (!r.used() && views[i].rejected.empty()) r.rms_px = view_rms(views[i].points, f.camera_matrix, f.distortion);
  }
  for (const std::size_t i : used) {
    for (const Point2& p : views[i].points.image) ++result.region_points[coverage_region(p, width, height)];
  }
  if (result.coverage() < options.min_coverage) {
    constexpr int regions = kCoverageGrid * kCoverageGrid;
    const auto covered = static_cast<int>(std::lround(result.coverage() * regions));
    throw CalibrationError(
        fmt::format("the views' points reach {} of the image's {} regions ({}x{}), at least {:.0f}% are needed; none "
                    "in {}: take views with the board there",
                    covered, regions, kCoverageGrid, kCoverageGrid, options.min_coverage * 100,
                    empty_regions(result.region_points)),
        result.views);
  }
  return result;
}

}  // namespace markerd::detector
