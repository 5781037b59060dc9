#include "markerd/sweep/rig_calibration.hpp"

#include <fmt/format.h>

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include "markerd/detector/frame8.hpp"

namespace markerd::sweep {

namespace {

using Vector = Eigen::VectorXd;
using Matrix = Eigen::MatrixXd;
using Parameters = std::array<double, kRigParameterCount>;

constexpr std::array<RigParameter, kRigParameterCount> kAll = {
    RigParameter::fx,
    RigParameter::fy,
    RigParameter::cx,
    RigParameter::cy,
    RigParameter::k1,
    RigParameter::k2,
    RigParameter::p1,
    RigParameter::p2,
    RigParameter::k3,
    RigParameter::d0,
    RigParameter::yaw0,
    RigParameter::marker_offset_normal,
    RigParameter::marker_offset_lateral,
    RigParameter::camera_offset_x,
    RigParameter::camera_offset_y,
    RigParameter::rail_tilt_x,
    RigParameter::rail_tilt_y,
};

// When a combination of parameters is not measured, which one is held: the
// first of them in this list, the parameters a rig measures least directly
// first (a marker's offset from the turntable axis only shows when the
// turntable turns; without that the axis is wherever the marker is).
constexpr std::array<RigParameter, kRigParameterCount> kHeldFirst = {
    RigParameter::rail_tilt_y,
    RigParameter::rail_tilt_x,
    RigParameter::marker_offset_lateral,
    RigParameter::marker_offset_normal,
    RigParameter::camera_offset_y,
    RigParameter::camera_offset_x,
    RigParameter::k3,
    RigParameter::p2,
    RigParameter::p1,
    RigParameter::k2,
    RigParameter::k1,
    RigParameter::cy,
    RigParameter::cx,
    RigParameter::fy,
    RigParameter::fx,
    RigParameter::yaw0,
    RigParameter::d0,
};

std::size_t index(RigParameter p) { return static_cast<std::size_t>(p); }

// The largest |v_i| (0 for an empty v). A loop: g++ 12 at -O2 warns of a
// null dereference inside Eigen's maxCoeff() on a dynamic vector.
double largest_magnitude(const Vector& v) {
  double m = 0;
  for (Eigen::Index i = 0; i < v.size(); ++i) m = std::max(m, std::abs(v[i]));
  return m;
}

// A typical magnitude of each parameter, for the numerical derivatives' steps.
double typical(RigParameter p) {
  switch (p) {
    case RigParameter::fx:
    case RigParameter::fy:
    case RigParameter::cx:
    case RigParameter::cy: return 100.0;
    case RigParameter::k1:
    case RigParameter::k2:
    case RigParameter::p1:
    case RigParameter::p2:
    case RigParameter::k3: return 0.1;
    case RigParameter::d0:
    case RigParameter::marker_offset_normal:
    case RigParameter::marker_offset_lateral:
    case RigParameter::camera_offset_x:
    case RigParameter::camera_offset_y: return 100.0;
    case RigParameter::yaw0:
    case RigParameter::rail_tilt_x:
    case RigParameter::rail_tilt_y: return 1.0;
  }
  return 1.0;
}

Parameters parameters_of(const detector::CameraModel& c, const rig::RigGeometry& g) {
  Parameters p{};
  p[index(RigParameter::fx)] = c.fx;
  p[index(RigParameter::fy)] = c.fy;
  p[index(RigParameter::cx)] = c.cx;
  p[index(RigParameter::cy)] = c.cy;
  p[index(RigParameter::k1)] = c.dist[0];
  p[index(RigParameter::k2)] = c.dist[1];
  p[index(RigParameter::p1)] = c.dist[2];
  p[index(RigParameter::p2)] = c.dist[3];
  p[index(RigParameter::k3)] = c.dist[4];
  p[index(RigParameter::d0)] = g.d0_mm;
  p[index(RigParameter::yaw0)] = g.yaw0_deg;
  p[index(RigParameter::marker_offset_normal)] = g.marker_offset_normal_mm;
  p[index(RigParameter::marker_offset_lateral)] = g.marker_offset_lateral_mm;
  p[index(RigParameter::camera_offset_x)] = g.camera_offset_x_mm;
  p[index(RigParameter::camera_offset_y)] = g.camera_offset_y_mm;
  p[index(RigParameter::rail_tilt_x)] = g.rail_tilt_x_deg;
  p[index(RigParameter::rail_tilt_y)] = g.rail_tilt_y_deg;
  return p;
}

// The camera and the geometry with `p`'s values; everything p has no slot
// for (the image size, k4 and beyond, rail_sign) from the templates.
detector::CameraModel camera_of(const Parameters& p, detector::CameraModel c) {
  c.fx = p[index(RigParameter::fx)];
  c.fy = p[index(RigParameter::fy)];
  c.cx = p[index(RigParameter::cx)];
  c.cy = p[index(RigParameter::cy)];
  c.dist[0] = p[index(RigParameter::k1)];
  c.dist[1] = p[index(RigParameter::k2)];
  c.dist[2] = p[index(RigParameter::p1)];
  c.dist[3] = p[index(RigParameter::p2)];
  c.dist[4] = p[index(RigParameter::k3)];
  return c;
}

rig::RigGeometry geometry_of(const Parameters& p, rig::RigGeometry g) {
  g.d0_mm = p[index(RigParameter::d0)];
  g.yaw0_deg = p[index(RigParameter::yaw0)];
  g.marker_offset_normal_mm = p[index(RigParameter::marker_offset_normal)];
  g.marker_offset_lateral_mm = p[index(RigParameter::marker_offset_lateral)];
  g.camera_offset_x_mm = p[index(RigParameter::camera_offset_x)];
  g.camera_offset_y_mm = p[index(RigParameter::camera_offset_y)];
  g.rail_tilt_x_deg = p[index(RigParameter::rail_tilt_x)];
  g.rail_tilt_y_deg = p[index(RigParameter::rail_tilt_y)];
  return g;
}

// The problem: the residuals (predicted minus detected, x and y of every
// corner of every view) for a full parameter vector.
class Problem {
 public:
  explicit Problem(const RigCalibrationInput& input) : input_(input) {
    const double h = input.square_side_m / 2;
    model_ = {Eigen::Vector3d(-h, h, 0), Eigen::Vector3d(h, h, 0), Eigen::Vector3d(h, -h, 0),
              Eigen::Vector3d(-h, -h, 0)};
  }

  [[nodiscard]] Eigen::Index size() const { return static_cast<Eigen::Index>(input_.views.size() * 8); }

  // False when a corner falls behind the camera (or the projection is not finite).
  bool residuals(const Parameters& p, Vector& r) const {
    const detector::CameraModel camera = camera_of(p, input_.camera);
    const rig::RigGeometry geometry = geometry_of(p, input_.geometry);
    r.resize(size());
    Eigen::Index at = 0;
    for (const RigView& view : input_.views) {
      const rig::MarkerGroundTruth truth = rig::ground_truth(geometry, view.rail, view.turntable);
      for (std::size_t j = 0; j < 4; ++j) {
        const Eigen::Vector3d x = truth.rotation * model_[j] + truth.translation;
        if (!(x.z() > 1e-6)) return false;
        const detector::Point2 pixel = camera.normalized_to_pixel({x.x() / x.z(), x.y() / x.z()});
        r[at++] = pixel.x - view.corners_px[j].x();
        r[at++] = pixel.y - view.corners_px[j].y();
      }
    }
    return r.allFinite();
  }

  // Central differences for the columns of `free`.
  bool jacobian(const Parameters& p, const std::vector<RigParameter>& free, Matrix& jac) const {
    jac.resize(size(), static_cast<Eigen::Index>(free.size()));
    Vector plus;
    Vector minus;
    for (std::size_t k = 0; k < free.size(); ++k) {
      const std::size_t i = index(free[k]);
      const double h = 1e-6 * std::max(std::abs(p[i]), typical(free[k]));
      Parameters a = p;
      Parameters b = p;
      a[i] += h;
      b[i] -= h;
      if (!residuals(a, plus) || !residuals(b, minus)) return false;
      jac.col(static_cast<Eigen::Index>(k)) = (plus - minus) / (2 * h);
    }
    return true;
  }

 private:
  const RigCalibrationInput& input_;
  std::array<Eigen::Vector3d, 4> model_{};
};

// Each corner's reprojection error (the length of its x, y residual).
std::vector<double> corner_errors(const Vector& r) {
  std::vector<double> e(static_cast<std::size_t>(r.size() / 2));
  for (std::size_t c = 0; c < e.size(); ++c) {
    const auto i = static_cast<Eigen::Index>(2 * c);
    e[c] = std::hypot(r[i], r[i + 1]);
  }
  return e;
}

double rms(const std::vector<double>& errors) {
  double sum = 0;
  for (const double e : errors) sum += e * e;
  return errors.empty() ? 0 : std::sqrt(sum / static_cast<double>(errors.size()));
}

// A robust standard deviation per coordinate from the corners' errors: for
// two independent normal coordinates the error's median is 1.1774 sigma.
double robust_sigma(std::vector<double> errors) {
  if (errors.empty()) return 0;
  const auto middle = errors.begin() + static_cast<std::ptrdiff_t>(errors.size() / 2);
  std::nth_element(errors.begin(), middle, errors.end());
  return *middle / 1.1774;
}

// The Huber loss of a corner's error and its weight in the normal equations.
double huber_loss(double e, double delta) { return e <= delta ? e * e : 2 * delta * e - delta * delta; }
double huber_weight(double e, double delta) { return e <= delta ? 1.0 : delta / e; }

double total_loss(const std::vector<double>& errors, double delta) {
  double sum = 0;
  for (const double e : errors) sum += huber_loss(e, delta);
  return sum;
}

// The normal equations' pieces with the Huber weights of `errors`: J^T W J and J^T W r.
void normal_equations(const Matrix& jac, const Vector& r, const std::vector<double>& errors, double delta, Matrix& a,
                      Vector& g) {
  Vector w(r.size());
  for (std::size_t c = 0; c < errors.size(); ++c) {
    const double weight = huber_weight(errors[c], delta);
    w[static_cast<Eigen::Index>(2 * c)] = weight;
    w[static_cast<Eigen::Index>(2 * c + 1)] = weight;
  }
  a = jac.transpose() * w.asDiagonal() * jac;
  g = jac.transpose() * w.asDiagonal() * r;
}

// The covariance from the views' own scatter: the "sandwich" A^-1 B A^-1
// with B the sum over views of each view's gradient contribution's outer
// product (a cluster-robust estimate, clustered by view, with the usual
// small-sample factor). The model-based covariance assumes every corner
// coordinate's error independent; a view's corners share its pose's
// perspective, blur and detection bias, and this estimate does not assume
// otherwise. Nothing when there are too few views for it to mean anything.
std::optional<Matrix> view_clustered_covariance(const Matrix& a_inverse, const Matrix& jac, const Vector& r,
                                                const std::vector<double>& errors, double delta, std::size_t views) {
  const auto parameters = static_cast<std::size_t>(jac.cols());
  if (views <= parameters + 1) return std::nullopt;
  Matrix b = Matrix::Zero(jac.cols(), jac.cols());
  Vector score(jac.cols());
  for (std::size_t v = 0; v < views; ++v) {
    score.setZero();
    for (std::size_t row = 8 * v; row < 8 * v + 8; ++row) {
      const auto at = static_cast<Eigen::Index>(row);
      score += jac.row(at).transpose() * (huber_weight(errors[row / 2], delta) * r[at]);
    }
    b += score * score.transpose();
  }
  const double g = static_cast<double>(views);
  const auto n = static_cast<double>(r.size());
  const auto p = static_cast<double>(parameters);
  return Matrix(a_inverse * b * a_inverse * (g / (g - 1) * (n - 1) / (n - p)));
}

// Below this ratio of the smallest to the largest singular value of the
// column-normalised Jacobian a combination of parameters is not measured:
// its changes move the corners by less than the numerical derivatives' own error.
constexpr double kSingularRatio = 1e-7;

// Parameters whose columns are zero, or that make up a combination the
// Jacobian does not see, one at a time: each named with the parameters it
// could not be told from, and held from then on. Returns the held ones.
std::vector<RigParameterEstimate> unobservable(const Problem& problem, const Parameters& p,
                                               std::vector<RigParameter>& free) {
  std::vector<RigParameterEstimate> held;
  Matrix jac;
  while (!free.empty()) {
    if (!problem.jacobian(p, free, jac)) break;
    const Eigen::Index n = jac.cols();
    Vector norms(n);
    for (Eigen::Index k = 0; k < n; ++k) norms[k] = jac.col(k).norm();
    const double largest = largest_magnitude(norms);
    std::optional<std::size_t> drop;
    std::vector<RigParameter> with;
    for (Eigen::Index k = 0; k < n; ++k) {
      if (!(norms[k] > kSingularRatio * largest)) {
        drop = static_cast<std::size_t>(k);  // moves no corner at all
        break;
      }
    }
    if (!drop) {
      const Matrix scaled = jac * norms.cwiseInverse().asDiagonal();
      const Eigen::JacobiSVD<Matrix> svd(scaled, Eigen::ComputeThinV);
      const Vector& s = svd.singularValues();
      if (s[n - 1] >= kSingularRatio * s[0]) break;
      const Vector v = svd.matrixV().col(n - 1);
      const double top = largest_magnitude(v);
      std::vector<std::size_t> involved;
      for (Eigen::Index k = 0; k < n; ++k) {
        if (std::abs(v[k]) >= 0.2 * top) involved.push_back(static_cast<std::size_t>(k));
      }
      for (const RigParameter candidate : kHeldFirst) {
        for (const std::size_t k : involved) {
          if (!drop && free[k] == candidate) drop = k;
        }
      }
      for (const std::size_t k : involved) {
        if (k != *drop) with.push_back(free[k]);
      }
    }
    RigParameterEstimate e;
    e.parameter = free[*drop];
    e.status = RigParameterEstimate::Status::not_observable;
    e.confounded_with = std::move(with);
    held.push_back(std::move(e));
    free.erase(free.begin() + static_cast<std::ptrdiff_t>(*drop));
  }
  return held;
}

}  // namespace

std::string_view parameter_name(RigParameter p) {
  switch (p) {
    case RigParameter::fx: return "fx";
    case RigParameter::fy: return "fy";
    case RigParameter::cx: return "cx";
    case RigParameter::cy: return "cy";
    case RigParameter::k1: return "k1";
    case RigParameter::k2: return "k2";
    case RigParameter::p1: return "p1";
    case RigParameter::p2: return "p2";
    case RigParameter::k3: return "k3";
    case RigParameter::d0: return "d0_mm";
    case RigParameter::yaw0: return "yaw0_deg";
    case RigParameter::marker_offset_normal: return "marker_offset_normal_mm";
    case RigParameter::marker_offset_lateral: return "marker_offset_lateral_mm";
    case RigParameter::camera_offset_x: return "camera_offset_x_mm";
    case RigParameter::camera_offset_y: return "camera_offset_y_mm";
    case RigParameter::rail_tilt_x: return "rail_tilt_x_deg";
    case RigParameter::rail_tilt_y: return "rail_tilt_y_deg";
  }
  return "?";
}

std::string_view parameter_unit(RigParameter p) {
  switch (p) {
    case RigParameter::fx:
    case RigParameter::fy:
    case RigParameter::cx:
    case RigParameter::cy: return "px";
    case RigParameter::k1:
    case RigParameter::k2:
    case RigParameter::p1:
    case RigParameter::p2:
    case RigParameter::k3: return "";
    case RigParameter::yaw0:
    case RigParameter::rail_tilt_x:
    case RigParameter::rail_tilt_y: return "deg";
    default: return "mm";
  }
}

std::optional<RigParameter> parameter_from_name(std::string_view name) {
  for (const RigParameter p : kAll) {
    const std::string_view full = parameter_name(p);
    // The geometry's keys also without their unit: "d0", "yaw0".
    const std::string_view unit = parameter_unit(p);
    const bool bare =
        !is_intrinsic(p) && full.size() > unit.size() + 1 && full.substr(0, full.size() - unit.size() - 1) == name;
    if (full == name || bare) return p;
  }
  return std::nullopt;
}

bool is_intrinsic(RigParameter p) { return index(p) <= index(RigParameter::k3); }

std::string_view to_string(RigParameterEstimate::Status status) {
  switch (status) {
    case RigParameterEstimate::Status::fitted: return "fitted";
    case RigParameterEstimate::Status::fixed: return "fixed";
    case RigParameterEstimate::Status::not_observable: return "not observable";
  }
  return "?";
}

RigCalibrationOptions RigCalibrationOptions::defaults() {
  RigCalibrationOptions o;
  for (const RigParameter p : {RigParameter::p1, RigParameter::p2, RigParameter::k3}) o.fixed[index(p)] = true;
  return o;
}

RigCalibrationResult calibrate_rig(const RigCalibrationInput& input, const RigCalibrationOptions& options) {
  if (!(input.square_side_m > 0)) {
    throw std::invalid_argument(fmt::format("the marker's square side must be > 0 m, got {}", input.square_side_m));
  }
  const Problem problem(input);
  const Parameters initial = parameters_of(input.camera, input.geometry);
  Parameters p = initial;

  RigCalibrationResult result;
  result.views = input.views.size();
  result.corners = input.views.size() * 4;
  Vector r;
  if (!problem.residuals(p, r)) {
    throw std::invalid_argument(
        "the initial camera and geometry put the marker behind the camera in some view: the start "
        "values are too far off to fit from");
  }
  result.rms_before_px = rms(corner_errors(r));

  std::vector<RigParameter> free;
  for (const RigParameter q : kAll) {
    if (!options.fixed[index(q)]) free.push_back(q);
  }
  if (free.empty()) throw std::invalid_argument("every parameter is fixed: there is nothing to fit");
  std::vector<RigParameterEstimate> held = unobservable(problem, p, free);
  if (free.empty()) throw std::invalid_argument("the views measure none of the free parameters");
  if (static_cast<Eigen::Index>(free.size()) >= r.size()) {
    throw std::invalid_argument(fmt::format("{} views give {} corner coordinates, too few for {} free parameters",
                                            input.views.size(), r.size(), free.size()));
  }

  // Levenberg-Marquardt with Marquardt's scaling, on the Huber loss of the
  // corners' errors; the weights and (with huber_px 0) the threshold are
  // those of the present residuals at each iteration.
  const auto threshold = [&](const std::vector<double>& errors) {
    return options.huber_px > 0 ? options.huber_px : std::max(2.0 * robust_sigma(errors), 1e-9);
  };
  double lambda = 1e-3;
  Matrix jac;
  Matrix a;
  Vector g;
  Vector trial_r;
  for (result.iterations = 0; result.iterations < options.max_iterations; ++result.iterations) {
    const std::vector<double> errors = corner_errors(r);
    const double delta = threshold(errors);
    const double loss = total_loss(errors, delta);
    if (!problem.jacobian(p, free, jac)) break;
    normal_equations(jac, r, errors, delta, a, g);
    bool improved = false;
    bool converged = false;
    while (lambda < 1e12) {
      Matrix damped = a;
      damped.diagonal() += lambda * a.diagonal().cwiseMax(1e-12 * largest_magnitude(a.diagonal()));
      const Vector step = damped.ldlt().solve(-g);
      Parameters trial = p;
      for (std::size_t k = 0; k < free.size(); ++k) trial[index(free[k])] += step[static_cast<Eigen::Index>(k)];
      if (problem.residuals(trial, trial_r)) {
        const double trial_loss = total_loss(corner_errors(trial_r), delta);
        if (trial_loss < loss) {
          // Converged when the step changes the loss, or every parameter, by
          // no more than the arithmetic can tell.
          double largest_change = 0;
          for (std::size_t k = 0; k < free.size(); ++k) {
            const std::size_t i = index(free[k]);
            largest_change =
                std::max(largest_change, std::abs(trial[i] - p[i]) / std::max(std::abs(p[i]), typical(free[k])));
          }
          converged = loss - trial_loss <= 1e-12 * loss || largest_change < 1e-12;
          p = trial;
          r = trial_r;
          lambda = std::max(lambda / 10, 1e-12);
          improved = true;
          break;
        }
      }
      lambda *= 10;
    }
    if (!improved || converged) {
      // No step lowers the loss any more: at the minimum, as far as the
      // arithmetic can tell.
      result.converged = true;
      ++result.iterations;
      break;
    }
  }

  // The uncertainties, at the solution: (J^T W J)^-1 scaled by the weighted
  // residuals' variance, or the views' own scatter where that is larger
  // (view_clustered_covariance). Parameters the views cannot tell apart at
  // the solution are held too (a combination that only vanished there).
  std::vector<RigParameterEstimate> held_late = unobservable(problem, p, free);
  held.insert(held.end(), std::make_move_iterator(held_late.begin()), std::make_move_iterator(held_late.end()));
  for (const RigParameterEstimate& h : held_late) p[index(h.parameter)] = initial[index(h.parameter)];
  problem.residuals(p, r);
  const std::vector<double> errors = corner_errors(r);
  const double delta = threshold(errors);
  Matrix covariance = Matrix::Zero(static_cast<Eigen::Index>(free.size()), static_cast<Eigen::Index>(free.size()));
  std::optional<Matrix> covariance_by_view;
  double weighted = 0;
  for (const double e : errors) weighted += huber_weight(e, delta) * e * e;
  const double dof = static_cast<double>(r.size()) - static_cast<double>(free.size());
  result.residual_sigma_px = std::sqrt(weighted / std::max(dof, 1.0));
  if (!free.empty() && problem.jacobian(p, free, jac)) {
    normal_equations(jac, r, errors, delta, a, g);
    // Through the normalised matrix, so that parameters of very different
    // scales (pixels, k3) do not cost the inverse its precision.
    const Vector scale = a.diagonal().cwiseSqrt().cwiseMax(1e-300).cwiseInverse();
    const Matrix normalised = scale.asDiagonal() * a * scale.asDiagonal();
    const Eigen::JacobiSVD<Matrix> svd(normalised, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Matrix inverse = svd.solve(Matrix::Identity(normalised.rows(), normalised.cols()));
    covariance =
        result.residual_sigma_px * result.residual_sigma_px * scale.asDiagonal() * inverse * scale.asDiagonal();
    covariance_by_view = view_clustered_covariance(scale.asDiagonal() * inverse * scale.asDiagonal(), jac, r, errors,
                                                   delta, input.views.size());
  }
  result.huber_px = delta;
  result.rms_after_px = rms(errors);
  for (const double e : errors) result.outliers += e > 5 * result.residual_sigma_px ? 1 : 0;

  result.camera = camera_of(p, input.camera);
  result.geometry = geometry_of(p, input.geometry);
  for (const RigParameter q : kAll) {
    RigParameterEstimate e;
    e.parameter = q;
    e.initial = initial[index(q)];
    e.value = p[index(q)];
    e.status = options.fixed[index(q)] ? RigParameterEstimate::Status::fixed : RigParameterEstimate::Status::fitted;
    for (const RigParameterEstimate& h : held) {
      if (h.parameter == q) {
        e.status = h.status;
        e.confounded_with = h.confounded_with;
      }
    }
    result.parameters.push_back(std::move(e));
  }
  for (std::size_t k = 0; k < free.size(); ++k) {
    const auto i = static_cast<Eigen::Index>(k);
    const double by_view = covariance_by_view ? (*covariance_by_view)(i, i) : 0.0;
    result.parameters[index(free[k])].sigma = std::sqrt(std::max({covariance(i, i), by_view, 0.0}));
    for (std::size_t m = 0; m < k; ++m) {
      const auto j = static_cast<Eigen::Index>(m);
      const double rho = covariance(i, j) / std::sqrt(covariance(i, i) * covariance(j, j));
      if (std::abs(rho) > 0.95) result.strong_correlations.push_back({free[m], free[k], rho});
    }
  }
  return result;
}

namespace {

double median(std::vector<double> values) {
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  if (values.size() % 2 == 1) return *middle;
  return (*middle + *std::max_element(values.begin(), middle)) / 2;
}

double json_number(const nlohmann::json& json, const char* key, const std::string& where) {
  const auto at = json.find(key);
  if (at == json.end() || !at->is_number()) {
    throw std::runtime_error(fmt::format("{} has no number \"{}\"", where, key));
  }
  return at->get<double>();
}

}  // namespace

RigCalibrationRun rig_calibration_input(const RunRecords& run) {
  RigCalibrationRun out;
  RigCalibrationInput& in = out.input;
  const RunStart& start = run.start;

  const nlohmann::json& model =
      start.camera.is_object() && start.camera.contains("model") ? start.camera["model"] : nlohmann::json(nullptr);
  if (!model.is_object()) {
    throw std::runtime_error(
        "the run's start record has no camera model (markerd ran without [camera] model): the fit needs "
        "intrinsics to start from");
  }
  const std::string where = "the start record's camera model";
  in.camera.width = static_cast<int>(json_number(model, "width", where));
  in.camera.height = static_cast<int>(json_number(model, "height", where));
  in.camera.fx = json_number(model, "fx", where);
  in.camera.fy = json_number(model, "fy", where);
  in.camera.cx = json_number(model, "cx", where);
  in.camera.cy = json_number(model, "cy", where);
  const auto dist = model.find("distortion");
  if (dist == model.end() || !dist->is_array() || dist->size() > in.camera.dist.size()) {
    throw std::runtime_error(fmt::format("{} has no \"distortion\" coefficients", where));
  }
  for (std::size_t i = 0; i < dist->size(); ++i) {
    if (!(*dist)[i].is_number()) throw std::runtime_error(fmt::format("{}: \"distortion\" must be numbers", where));
    in.camera.dist[i] = (*dist)[i].get<double>();
  }

  const nlohmann::json& rig = start.rig;
  if (!rig.is_object() || !rig.contains("geometry") || !rig["geometry"].is_object()) {
    throw std::runtime_error("the run's start record has no rig geometry (markerd ran without a rig)");
  }
  const nlohmann::json& g = rig["geometry"];
  const std::string gwhere = "the start record's rig geometry";
  in.geometry.d0_mm = json_number(g, "d0_mm", gwhere);
  in.geometry.yaw0_deg = json_number(g, "yaw0_deg", gwhere);
  in.geometry.rail_sign = json_number(g, "rail_sign", gwhere) < 0 ? -1 : 1;
  in.geometry.camera_offset_x_mm = json_number(g, "camera_offset_x_mm", gwhere);
  in.geometry.camera_offset_y_mm = json_number(g, "camera_offset_y_mm", gwhere);
  in.geometry.marker_offset_normal_mm = json_number(g, "marker_offset_normal_mm", gwhere);
  in.geometry.marker_offset_lateral_mm = json_number(g, "marker_offset_lateral_mm", gwhere);
  // Records from before the rail had a tilt: none.
  if (g.contains("rail_tilt_x_deg")) in.geometry.rail_tilt_x_deg = json_number(g, "rail_tilt_x_deg", gwhere);
  if (g.contains("rail_tilt_y_deg")) in.geometry.rail_tilt_y_deg = json_number(g, "rail_tilt_y_deg", gwhere);

  const bool hole = start.plan.marker.family == detector::Family::frame8;
  in.square_side_m = start.plan.marker.size_m * (hole ? detector::frame8::hole_fraction : 1.0);
  out.corners = hole ? "frame8's hole" : "the outer square";
  out.measurements = run.points.size();
  bool any_detected = false;
  for (const PointRecord& point : run.points) {
    std::array<std::vector<double>, 8> coordinates;
    for (const FrameSample& f : point.frames) {
      any_detected = any_detected || f.detected;
      const std::optional<ImageCorners>& corners = hole ? f.inner_corners_px : f.corners_px;
      if (!corners) continue;
      for (std::size_t j = 0; j < 4; ++j) {
        coordinates[2 * j].push_back((*corners)[j][0]);
        coordinates[2 * j + 1].push_back((*corners)[j][1]);
      }
      ++out.frames;
    }
    if (coordinates[0].empty()) continue;
    RigView view;
    view.rail = point.rail;
    view.turntable = point.turntable;
    for (std::size_t j = 0; j < 4; ++j) {
      view.corners_px[j] = {median(coordinates[2 * j]), median(coordinates[2 * j + 1])};
    }
    in.views.push_back(view);
  }
  if (in.views.empty()) {
    throw std::runtime_error(any_detected ? "the run's records keep no corners of the marker (recorded before "
                                            "markerd kept them): run the sweep again"
                                          : "the run's marker was never detected: there are no corners to fit");
  }
  return out;
}

std::string rig_geometry_toml(const RigCalibrationResult& result, const std::string& header) {
  std::string out;
  std::size_t begin = 0;
  while (begin < header.size()) {
    const std::size_t end = std::min(header.find('\n', begin), header.size());
    out += fmt::format("# {}\n", header.substr(begin, end - begin));
    begin = end + 1;
  }
  out += "[rig.geometry]\n";
  for (const RigParameterEstimate& e : result.parameters) {
    if (is_intrinsic(e.parameter)) continue;
    std::string note;
    switch (e.status) {
      case RigParameterEstimate::Status::fitted: note = fmt::format("+- {:.3g} (1 sigma)", e.sigma); break;
      case RigParameterEstimate::Status::fixed: note = "fixed: as configured"; break;
      case RigParameterEstimate::Status::not_observable: note = "not observable: as configured"; break;
    }
    out += fmt::format("{} = {:.6f}  # {}\n", parameter_name(e.parameter), e.value, note);
  }
  return out;
}

}  // namespace markerd::sweep
