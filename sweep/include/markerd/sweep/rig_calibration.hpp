#pragma once
// The rig calibrates itself: a sweep's known motions (rail positions,
// turntable angles) and the marker's corners detected over them fit, in one
// least-squares problem, the camera's intrinsics and the rig's own geometry
// (docs/calibration-rig.md). Each view's corners are predicted by placing the
// marker where rig::ground_truth puts it for the view's axis positions and
// projecting its corners through the camera model; the fit moves the free
// parameters until the predictions meet the detections (Levenberg-Marquardt
// on a Huber loss, so that a wrong corner pulls little), and their
// covariance, (J^T W J)^-1 scaled by the residuals' variance, gives each an
// uncertainty. A parameter the views cannot tell from others (a rail tilt
// from a camera offset when the rail never moved) is named and left at its
// initial value instead of being given a meaningless number.

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/sweep/records.hpp"

namespace markerd::sweep {

// The parameters of the fit: the camera's intrinsics (OpenCV's model: focal
// lengths, principal point, radial k1 k2 k3 and tangential p1 p2 distortion)
// and the rig's geometry (rig::RigGeometry; rail_sign is wiring, not fitted).
enum class RigParameter : std::uint8_t {
  fx,
  fy,
  cx,
  cy,
  k1,
  k2,
  p1,
  p2,
  k3,
  d0,
  yaw0,
  marker_offset_normal,
  marker_offset_lateral,
  camera_offset_x,
  camera_offset_y,
  rail_tilt_x,
  rail_tilt_y,
};
inline constexpr std::size_t kRigParameterCount = 17;

// The camera file's names for the intrinsics ("fx", "k1") and the rig
// config's keys for the geometry ("d0_mm", "yaw0_deg").
[[nodiscard]] std::string_view parameter_name(RigParameter parameter);
[[nodiscard]] std::string_view parameter_unit(RigParameter parameter);  // "px", "", "mm", "deg"
[[nodiscard]] std::optional<RigParameter> parameter_from_name(std::string_view name);
[[nodiscard]] bool is_intrinsic(RigParameter parameter);

// One view of the marker: where the axes stood, and where its corners were
// seen (TL, TR, BR, BL of the marker frame, a square of side
// RigCalibrationInput::square_side_m centred on the marker's origin).
struct RigView {
  double rail = 0;       // the rail's position (mm)
  double turntable = 0;  // the turntable's (deg)
  std::array<Eigen::Vector2d, 4> corners_px{};
};

struct RigCalibrationInput {
  detector::CameraModel camera;  // the initial intrinsics, and the image size
  rig::RigGeometry geometry;     // the initial geometry (and rail_sign)
  double square_side_m = 0;      // the side of the square whose corners the views hold
  std::vector<RigView> views;
};

struct RigCalibrationOptions {
  // Parameters kept at their initial values. By default p1, p2 and k3: a
  // marker near the image centre hardly measures them, and k3 trades
  // against k1 and k2 wherever the image is not covered to its corners.
  std::array<bool, kRigParameterCount> fixed{};
  // The Huber loss's threshold on a corner's reprojection error, pixels:
  // corners further off count linearly, not squared. 0: twice the
  // residuals' robust standard deviation (from their median), re-estimated
  // as the fit goes, so that a wrong start does not mark every corner an outlier.
  double huber_px = 0;
  int max_iterations = 200;

  [[nodiscard]] static RigCalibrationOptions defaults();
};

struct RigParameterEstimate {
  enum class Status : std::uint8_t {
    fitted,
    fixed,           // held by the options
    not_observable,  // the views cannot tell it from `confounded_with`: held at its initial value
  };
  RigParameter parameter = RigParameter::fx;
  Status status = Status::fitted;
  double initial = 0;
  double value = 0;
  double sigma = 0;  // one standard deviation; 0 unless fitted
  std::vector<RigParameter> confounded_with;
};
[[nodiscard]] std::string_view to_string(RigParameterEstimate::Status status);

struct RigCalibrationResult {
  detector::CameraModel camera;                  // the fitted intrinsics (the input's image size)
  rig::RigGeometry geometry;                     // the fitted geometry
  std::vector<RigParameterEstimate> parameters;  // every parameter, in RigParameter's order
  // Pairs of fitted parameters whose estimates are correlated beyond 0.95:
  // the views measure their combination better than either.
  struct Correlation {
    RigParameter a = RigParameter::fx;
    RigParameter b = RigParameter::fx;
    double rho = 0;
  };
  std::vector<Correlation> strong_correlations;
  std::size_t views = 0;
  std::size_t corners = 0;
  double rms_before_px = 0;      // the corners' RMS reprojection error with the initial values
  double rms_after_px = 0;       // ... with the fitted ones
  double residual_sigma_px = 0;  // the residuals' standard deviation per coordinate, the covariance's scale
  double huber_px = 0;           // the Huber threshold at the end
  std::size_t outliers = 0;      // corners further off than 5 residual sigmas at the end
  int iterations = 0;
  bool converged = false;

  [[nodiscard]] const RigParameterEstimate& estimate(RigParameter parameter) const {
    return parameters[static_cast<std::size_t>(parameter)];
  }
};

// Fits. std::invalid_argument when the input cannot be fitted: no free
// parameter, fewer corner coordinates than free parameters, a view the
// initial values put behind the camera, a square side that is not > 0.
[[nodiscard]] RigCalibrationResult calibrate_rig(
    const RigCalibrationInput& input, const RigCalibrationOptions& options = RigCalibrationOptions::defaults());

// What a run's records give the fit: one view per measurement whose frames
// found the plan's marker, its corners the per-coordinate median over those
// frames (the frames of a measurement share its pose and its rendering or
// optics' bias, so they are one observation, not several; the median drops
// a frame's wrong corner); frame8's hole corners (what it measures), other
// families' outer square. The initial values are the camera model and the
// geometry the run's start record states. std::runtime_error naming what
// the records lack (a camera model, corners: a run recorded before markerd
// kept them).
struct RigCalibrationRun {
  RigCalibrationInput input;
  std::size_t measurements = 0;  // point records
  std::size_t frames = 0;        // frames with the marker's corners, over the views
  std::string corners;           // "frame8's hole" or "the outer square"
};
[[nodiscard]] RigCalibrationRun rig_calibration_input(const RunRecords& run);

// The rig config's [rig.geometry] calibration file: the fitted geometry's
// measured keys, each with its uncertainty in a comment. `header` lines go
// on top as comments.
[[nodiscard]] std::string rig_geometry_toml(const RigCalibrationResult& result, const std::string& header);

}  // namespace markerd::sweep
