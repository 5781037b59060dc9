#include "markerd/detector/pose.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>

// IPPE for a square, after Collins and Bartoli, "Infinitesimal Plane-based
// Pose Estimation", IJCV 109(3), 2014: the homography from the model square to
// the image fixes, at the square's centre, the line of sight and the 2x2
// Jacobian of the plane-to-image map. A rotation that reproduces that Jacobian
// is determined up to the sign of its third row, which gives the two
// solutions; each then gets its translation by linear least squares. Both are
// polished with Levenberg-Marquardt on the pixel error through the camera's
// full distortion model. Everything is fixed-size: this runs per detection.
//
// OpenCV's own SOLVEPNP_IPPE_SQUARE is not used because its conversion of the
// IPPE rotation to a Rodrigues vector breaks down at rotation angles near pi,
// which is exactly where a marker facing the camera and turned about its own
// vertical axis (the rig's ground truth) lies; see tests/test_pose.cpp.

namespace markerd::detector {
namespace {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Mat2 = Eigen::Matrix2d;
using Mat3 = Eigen::Matrix3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;
using Mat23 = Eigen::Matrix<double, 2, 3>;
using Mat26 = Eigen::Matrix<double, 2, 6>;
using Corners2 = std::array<Vec2, 4>;

// Assumed standard deviation of a detected corner, per coordinate, in pixels:
// what sub-pixel refinement of a clean edge typically achieves.
constexpr double kCornerSigmaPx = 0.25;
// See decide_ambiguity(): with the alternative's excess error below
// kAmbiguityZ * kCornerSigmaPx, corner noise of that size picks the wrong
// solution with a probability above about 2 percent.
constexpr double kAmbiguityZ = 2.0;

double cross2(const Vec2& a, const Vec2& b) { return a.x() * b.y() - a.y() * b.x(); }

bool all_finite(const Corners2& p) {
  return std::all_of(p.begin(), p.end(), [](const Vec2& v) { return v.allFinite(); });
}

std::array<Vec3, 4> model_corners(double side) {
  const double h = side / 2;
  return {Vec3(-h, h, 0), Vec3(h, h, 0), Vec3(h, -h, 0), Vec3(-h, -h, 0)};
}

Mat3 skew(const Vec3& v) {
  Mat3 m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Mat3 exp_so3(const Vec3& w) {
  const double angle = w.norm();
  if (!(angle > 0)) return Mat3::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// The image of a square in front of a camera is a convex quadrilateral, and no
// three of its corners are collinear. Anything else (repeated corners, a
// bow-tie, a corner across the horizon) has no pose.
bool is_proper_quad(const Corners2& p) {
  double scale2 = 0;
  for (int i = 0; i < 4; ++i) {
    scale2 =
        std::max(scale2, (p[static_cast<std::size_t>((i + 2) % 4)] - p[static_cast<std::size_t>(i)]).squaredNorm());
  }
  if (!(scale2 > 0) || !std::isfinite(scale2)) return false;
  // Relative to the squared diagonal, a marker slanted at 89 degrees still
  // leaves areas far above this; below it the homography is noise.
  const double min_area = 1e-10 * scale2;
  int sign = 0;
  for (int i = 0; i < 4; ++i) {
    const Vec2& a = p[static_cast<std::size_t>(i)];
    const Vec2& b = p[static_cast<std::size_t>((i + 1) % 4)];
    const Vec2& c = p[static_cast<std::size_t>((i + 2) % 4)];
    const double area = cross2(b - a, c - b);
    if (!(std::abs(area) > min_area)) return false;
    const int s = area > 0 ? 1 : -1;
    if (sign != 0 && s != sign) return false;
    sign = s;
  }
  return true;
}

// Homography from the model square (side `side`, centred) to the image quad,
// scaled so that H(2,2) = 1. Closed form: the projective map of the unit
// square onto a quad (Heckbert 1989), composed with the affine map from the
// model square onto the unit square.
bool square_homography(const Corners2& p, double side, Mat3& h_out) {
  const double x0 = p[0].x(), y0 = p[0].y(), x1 = p[1].x(), y1 = p[1].y();
  const double x2 = p[2].x(), y2 = p[2].y(), x3 = p[3].x(), y3 = p[3].y();
  const double dx1 = x1 - x2, dy1 = y1 - y2, dx2 = x3 - x2, dy2 = y3 - y2;
  const double sx = x0 - x1 + x2 - x3, sy = y0 - y1 + y2 - y3;
  const double den = dx1 * dy2 - dx2 * dy1;
  if (den == 0) return false;
  const double g = (sx * dy2 - dx2 * sy) / den;
  const double h = (dx1 * sy - sx * dy1) / den;
  // Homogeneous scale at the unit square's corners (0,0) (1,0) (1,1) (0,1): a
  // sign change means the plane crosses the camera's focal plane between
  // corners, i.e. some corner would lie behind the camera.
  if (!(1 + g > 0) || !(1 + h > 0) || !(1 + g + h > 0)) return false;
  Mat3 unit;
  unit << x1 - x0 + g * x1, x3 - x0 + h * x3, x0,  //
      y1 - y0 + g * y1, y3 - y0 + h * y3, y0,      //
      g, h, 1;
  // Model (X, Y) -> unit square (u, v): u along TL->TR, v along TL->BL.
  Mat3 to_unit;
  to_unit << 1 / side, 0, 0.5, 0, -1 / side, 0.5, 0, 0, 1;
  Mat3 hm = unit * to_unit;
  if (!(hm(2, 2) > 0)) return false;
  hm /= hm(2, 2);
  if (!hm.allFinite()) return false;
  h_out = hm;
  return true;
}

// A 2x2 matrix as a similarity (q: scale and rotation) plus a reflected
// similarity (r), each as its two free entries. Its singular values are
// (|q| + |r|) / 2 and ||q| - |r|| / 2.
struct SimilarityParts {
  Vec2 q, r;
};
SimilarityParts similarity_parts(const Mat2& a) {
  return {Vec2(a(0, 0) + a(1, 1), a(1, 0) - a(0, 1)), Vec2(a(0, 0) - a(1, 1), a(1, 0) + a(0, 1))};
}

// Largest singular value of a 2x2 matrix, in the form that stays accurate when
// the two singular values are close (a frontal marker).
double largest_singular_value(const Mat2& a) {
  const SimilarityParts parts = similarity_parts(a);
  return 0.5 * (std::hypot(parts.q.x(), parts.q.y()) + std::hypot(parts.r.x(), parts.r.y()));
}

// Pixels of ideal normalized points, through the camera's distortion.
Corners2 pixels_of(const CameraModel& camera, const Corners2& normalized) {
  Corners2 pixels;
  for (std::size_t i = 0; i < 4; ++i) {
    const Point2 px = camera.normalized_to_pixel({normalized[i].x(), normalized[i].y()});
    pixels[i] = Vec2(px.x, px.y);
  }
  return pixels;
}

// Translation that best aligns R * model with the rays of the normalized
// points: linear least squares on x (R m + t)_z = (R m + t)_x and the same in y.
bool solve_translation(const Mat3& r, const std::array<Vec3, 4>& model, const Corners2& q, Vec3& t_out) {
  Mat3 ata = Mat3::Zero();
  Vec3 atb = Vec3::Zero();
  for (std::size_t i = 0; i < 4; ++i) {
    const Vec3 p = r * model[i];
    Mat23 a;
    a << 1, 0, -q[i].x(), 0, 1, -q[i].y();
    const Vec2 b(q[i].x() * p.z() - p.x(), q[i].y() * p.z() - p.y());
    ata.noalias() += a.transpose() * a;
    atb.noalias() += a.transpose() * b;
  }
  const Eigen::LDLT<Mat3> ldlt(ata);
  if (ldlt.info() != Eigen::Success) return false;
  const Vec3 t = ldlt.solve(atb);
  if (!t.allFinite()) return false;
  t_out = t;
  return true;
}

bool in_front(const MarkerPose& pose, const std::array<Vec3, 4>& model) {
  return std::all_of(model.begin(), model.end(),
                     [&](const Vec3& m) { return (pose.rotation * m + pose.translation).z() > 0; });
}

// Two poses closer than this (radians, and relative translation) are one.
constexpr double kSamePoseRad = 1e-6;

double rotation_angle_between(const Mat3& a, const Mat3& b) { return Eigen::AngleAxisd(a.transpose() * b).angle(); }

bool same_pose(const MarkerPose& a, const MarkerPose& b) {
  return rotation_angle_between(a.rotation, b.rotation) < kSamePoseRad &&
         (a.translation - b.translation).norm() < kSamePoseRad * a.translation.norm();
}

// The plane-to-image map at the square's centre, in IPPE's frame.
struct CentreJacobian {
  Mat3 rv;  // turns the optical axis onto the line of sight through the centre
  Mat2 a;   // the Jacobian there, in that frame: its rotation's top 2x2 block, over the depth
};

std::optional<CentreJacobian> centre_jacobian(const Corners2& q, double side) {
  Mat3 h;
  if (!square_homography(q, side, h)) return std::nullopt;

  // Where the centre of the square lands, and the Jacobian of the
  // plane-to-image map there (the homography's derivative at the origin).
  const Vec2 v(h(0, 2), h(1, 2));
  Mat2 jac;
  jac << h(0, 0) - h(2, 0) * v.x(), h(0, 1) - h(2, 1) * v.x(),  //
      h(1, 0) - h(2, 0) * v.y(), h(1, 1) - h(2, 1) * v.y();

  // Rv turns the optical axis onto the line of sight through the centre. In
  // that rotated frame the projection's Jacobian at the centre is B (2x2), so
  // the first two columns of the rotation, expressed in it, have the top 2x2
  // block A/gamma with A = B^-1 J, gamma = 1/depth its largest singular value.
  const Vec3 sight = Vec3(v.x(), v.y(), 1).normalized();
  CentreJacobian c;
  c.rv = Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), sight).toRotationMatrix();
  Mat23 proj;
  proj << 1, 0, -v.x(), 0, 1, -v.y();
  const Mat2 b = proj * c.rv.leftCols<2>();
  if (!(std::abs(b.determinant()) > 1e-12)) return std::nullopt;
  c.a = b.inverse() * jac;
  if (!c.a.allFinite()) return std::nullopt;
  return c;
}

struct IppeResult {
  std::array<MarkerPose, 2> poses;
  std::array<bool, 2> valid{};  // finite and every corner in front of the camera
  bool coincide = false;        // both branches are the same rotation (frontal)
};

std::optional<IppeResult> ippe_impl(const Corners2& q, double side) {
  if (!(side > 0) || !std::isfinite(side) || !all_finite(q) || !is_proper_quad(q)) return std::nullopt;
  const auto centre = centre_jacobian(q, side);
  if (!centre) return std::nullopt;
  const Mat3& rv = centre->rv;
  const Mat2& a = centre->a;
  const double gamma = largest_singular_value(a);
  if (!(gamma > 0) || !std::isfinite(gamma)) return std::nullopt;
  const Mat2 r22 = a / gamma;

  // The bottom row (b0, b1) of the two orthonormal columns: b b^T = I - R22^T R22,
  // a rank-one matrix whose square root is defined up to sign, the two IPPE
  // solutions. Only the larger diagonal entry goes through the square root;
  // the other component comes from the off-diagonal. The square root of an
  // entry at rounding level (1e-16) would be 1e-8, and the columns would no
  // longer be orthogonal.
  const Mat2 rest = Mat2::Identity() - r22.transpose() * r22;
  double b0 = 0, b1 = 0;
  if (rest(0, 0) >= rest(1, 1)) {
    b0 = std::sqrt(std::max(0.0, rest(0, 0)));
    b1 = b0 > 0 ? rest(0, 1) / b0 : 0.0;
  } else {
    b1 = std::sqrt(std::max(0.0, rest(1, 1)));
    b0 = b1 > 0 ? rest(0, 1) / b1 : 0.0;
  }

  const auto model = model_corners(side);
  IppeResult out;
  for (int k = 0; k < 2; ++k) {
    const double sign = k == 0 ? 1.0 : -1.0;
    const Vec3 c0(r22(0, 0), r22(1, 0), sign * b0);
    const Vec3 c1(r22(0, 1), r22(1, 1), sign * b1);
    Mat3 local;
    local.col(0) = c0;
    local.col(1) = c1;
    local.col(2) = c0.cross(c1);
    MarkerPose& pose = out.poses[static_cast<std::size_t>(k)];
    // Rounding in R22 leaves the columns orthonormal only to about 1e-16;
    // the polish multiplies onto this matrix, so make it a rotation exactly.
    pose.rotation = Eigen::Quaterniond(rv * local).normalized().toRotationMatrix();
    Vec3 t;
    const bool ok = pose.rotation.allFinite() && solve_translation(pose.rotation, model, q, t);
    pose.translation = ok ? t : Vec3::Zero();
    out.valid[static_cast<std::size_t>(k)] = ok && in_front(pose, model);
  }
  if (!out.valid[0] && !out.valid[1]) return std::nullopt;
  // At a frontal view b is zero up to the square root of rounding (1e-8):
  // the two branches are one rotation.
  out.coincide = rotation_angle_between(out.poses[0].rotation, out.poses[1].rotation) < kSamePoseRad;
  return out;
}

// d(distorted normalized) / d(ideal normalized) for OpenCV's 12-coefficient
// model, the derivative of CameraModel::distort().
Mat2 distortion_jacobian(const CameraModel& cam, const Vec2& n) {
  const auto& k = cam.dist;
  const double x = n.x(), y = n.y();
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double num = 1 + k[0] * r2 + k[1] * r4 + k[4] * r6;
  const double den = 1 + k[5] * r2 + k[6] * r4 + k[7] * r6;
  const double dnum = k[0] + 2 * k[1] * r2 + 3 * k[4] * r4;
  const double dden = k[5] + 2 * k[6] * r2 + 3 * k[7] * r4;
  const double radial = num / den;
  const double dradial = (dnum * den - num * dden) / (den * den);  // d radial / d r2
  const double dpx = k[8] + 2 * k[9] * r2;                         // d prism_x / d r2
  const double dpy = k[10] + 2 * k[11] * r2;
  Mat2 j;
  j(0, 0) = radial + 2 * x * x * dradial + 2 * k[2] * y + 6 * k[3] * x + 2 * x * dpx;
  j(0, 1) = 2 * x * y * dradial + 2 * k[2] * x + 2 * k[3] * y + 2 * y * dpx;
  j(1, 0) = 2 * x * y * dradial + 2 * k[2] * x + 2 * k[3] * y + 2 * x * dpy;
  j(1, 1) = radial + 2 * y * y * dradial + 6 * k[2] * y + 2 * k[3] * x + 2 * y * dpy;
  return j;
}

Vec2 to_pixel(const CameraModel& cam, const Vec3& p) {
  const Point2 px = cam.normalized_to_pixel({p.x() / p.z(), p.y() / p.z()});
  return {px.x, px.y};
}

// Sum of squared pixel residuals; infinity when a corner is not in front.
double cost_of(const CameraModel& cam, const Mat3& r, const Vec3& t, const std::array<Vec3, 4>& model,
               const Corners2& obs) {
  double cost = 0;
  for (std::size_t i = 0; i < 4; ++i) {
    const Vec3 p = r * model[i] + t;
    if (!(p.z() > 0)) return std::numeric_limits<double>::infinity();
    cost += (to_pixel(cam, p) - obs[i]).squaredNorm();
  }
  return std::isfinite(cost) ? cost : std::numeric_limits<double>::infinity();
}

// Levenberg-Marquardt over a rotation increment (left, in the camera frame)
// and the translation, on the pixel reprojection error. Marquardt's diagonal
// scaling keeps radians and metres comparable at any distance.
MarkerPose polish(const CameraModel& cam, const MarkerPose& start, const std::array<Vec3, 4>& model,
                  const Corners2& obs) {
  Mat3 r = start.rotation;
  Vec3 t = start.translation;
  double cost = cost_of(cam, r, t, model, obs);
  if (std::isfinite(cost)) {
    const Eigen::DiagonalMatrix<double, 2> focal(cam.fx, cam.fy);
    double lambda = 1e-3;
    for (int iter = 0; iter < 50 && cost > 0; ++iter) {
      Mat6 hess = Mat6::Zero();
      Vec6 grad = Vec6::Zero();
      for (std::size_t i = 0; i < 4; ++i) {
        const Vec3 rm = r * model[i];
        const Vec3 p = rm + t;
        const double iz = 1 / p.z();
        const Vec2 n(p.x() * iz, p.y() * iz);
        Mat23 dn;
        dn << iz, 0, -n.x() * iz, 0, iz, -n.y() * iz;
        const Mat23 dpix = focal * distortion_jacobian(cam, n) * dn;
        Mat26 j;
        j.leftCols<3>() = -dpix * skew(rm);
        j.rightCols<3>() = dpix;
        const Vec2 res = to_pixel(cam, p) - obs[i];
        hess.noalias() += j.transpose() * j;
        grad.noalias() += j.transpose() * res;
      }
      bool stepped = false;
      bool converged = false;
      while (lambda < 1e12) {
        Mat6 damped = hess;
        // The tiny floor keeps a parameter the corners do not see (a zero
        // column) from making the damped system singular.
        damped.diagonal() += lambda * (hess.diagonal().array() + 1e-300).matrix();
        const Eigen::LDLT<Mat6> ldlt(damped);
        const Vec6 delta = -ldlt.solve(grad);
        if (ldlt.info() != Eigen::Success || !delta.allFinite()) {
          lambda *= 10;
          continue;
        }
        const Mat3 r_new = exp_so3(delta.head<3>()) * r;
        const Vec3 t_new = t + delta.tail<3>();
        const double cost_new = cost_of(cam, r_new, t_new, model, obs);
        // A step this small moves the corners by far less than 1e-9 px: the
        // minimum is reached, whether or not rounding lets the cost drop.
        const bool tiny = delta.head<3>().norm() < 1e-13 && delta.tail<3>().norm() < 1e-13 * t.norm();
        if (cost_new < cost) {
          converged = tiny;
          r = r_new;
          t = t_new;
          cost = cost_new;
          lambda = std::max(lambda / 10, 1e-12);
          stepped = true;
          break;
        }
        if (tiny) break;
        lambda *= 10;
      }
      if (!stepped || converged) break;
    }
  }
  MarkerPose out;
  // Products of many small rotations drift off SO(3) by rounding.
  out.rotation = Eigen::Quaterniond(r).normalized().toRotationMatrix();
  out.translation = t;
  const double final_cost = cost_of(cam, out.rotation, out.translation, model, obs);
  out.reprojection_error_px = std::sqrt(final_cost / 4);
  return out;
}

// The flip ambiguity, in pixels. If the best pose is the truth, the other
// solution's predicted corners lie d_i away from it, and with corner noise of
// sigma per coordinate the difference of the two costs is sum |d_i|^2 plus a
// Gaussian term of standard deviation 2 sigma sqrt(sum |d_i|^2): the noise
// prefers the wrong solution with probability Phi(-rms(d) / sigma). The
// observed excess sqrt(e_alt^2 - e_best^2) (RMS over the corners) estimates
// rms(d). Ambiguous when it is under kAmbiguityZ sigma, i.e. when noise of a
// quarter pixel would swap the solutions more than about 2 percent of the time.
bool decide_ambiguity(const MarkerPose& best, const MarkerPose& alt) {
  const double excess = std::sqrt(std::max(0.0, alt.reprojection_error_px * alt.reprojection_error_px -
                                                    best.reprojection_error_px * best.reprojection_error_px));
  return excess < kAmbiguityZ * kCornerSigmaPx;
}

std::optional<PoseEstimate> estimate_impl(const CameraModel& camera, const Corners2& normalized,
                                          const Corners2& observed_px, double side) {
  if (!(camera.fx > 0) || !(camera.fy > 0) || !all_finite(observed_px)) return std::nullopt;
  const auto ippe = ippe_impl(normalized, side);
  if (!ippe) return std::nullopt;
  const auto model = model_corners(side);

  std::array<MarkerPose, 2> polished;
  std::array<bool, 2> ok{};
  for (std::size_t k = 0; k < 2; ++k) {
    if (!ippe->valid[k]) continue;
    polished[k] = polish(camera, ippe->poses[k], model, observed_px);
    ok[k] = polished[k].rotation.allFinite() && polished[k].translation.allFinite();
  }
  if (!ok[0] && !ok[1]) return std::nullopt;

  if (ok[0] && ok[1] && !ippe->coincide && same_pose(polished[0], polished[1])) {
    // The flip has no minimum of its own (typical of a nearly frontal marker
    // seen close): polishing carried it into the other solution. Keep IPPE's
    // flip as it was, so that the alternative still is the mirrored tilt and
    // its error says how well that hypothesis explains the corners.
    const std::size_t flip = rotation_angle_between(ippe->poses[0].rotation, polished[0].rotation) >
                                     rotation_angle_between(ippe->poses[1].rotation, polished[1].rotation)
                                 ? 0
                                 : 1;
    polished[flip] = ippe->poses[flip];
    polished[flip].reprojection_error_px =
        std::sqrt(cost_of(camera, polished[flip].rotation, polished[flip].translation, model, observed_px) / 4);
  }

  PoseEstimate est;
  if (ok[0] && ok[1]) {
    const bool swap = polished[1].reprojection_error_px < polished[0].reprojection_error_px;
    est.best = polished[swap ? 1 : 0];
    est.alternative = polished[swap ? 0 : 1];
    // A frontal marker's two branches are one pose: ambiguous, since the
    // slightest noise splits them into two equally good answers.
    est.ambiguous = decide_ambiguity(est.best, *est.alternative);
  } else {
    est.best = polished[ok[0] ? 0 : 1];
  }
  return est;
}

}  // namespace

Eigen::Vector3d MarkerPose::rvec() const {
  // Through the quaternion: stable at angle 0 (axis undefined, vector zero)
  // and at angle pi (where the trace formula's sin(angle) vanishes).
  const Eigen::AngleAxisd aa(Eigen::Quaterniond(rotation).normalized());
  return aa.angle() * aa.axis();
}

Eigen::Quaterniond MarkerPose::quaternion() const {
  Eigen::Quaterniond q(rotation);
  q.normalize();
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  return q;
}

std::optional<std::array<MarkerPose, 2>> ippe_square(const std::array<Eigen::Vector2d, 4>& normalized, double side) {
  // Both or nothing: a solution with a corner behind the camera is no pose.
  // (estimate_square_pose keeps the other one alone.)
  const auto result = ippe_impl(normalized, side);
  if (!result || !result->valid[0] || !result->valid[1]) return std::nullopt;
  return result->poses;
}

std::optional<PoseEstimate> estimate_square_pose(const CameraModel& camera, const Quad& corners_px, double side) {
  // IPPE needs ideal coordinates; the polish compares against the measured
  // pixels themselves rather than their undistort-distort round trip.
  Corners2 normalized;
  Corners2 observed;
  for (std::size_t i = 0; i < 4; ++i) {
    const Point2 n = camera.pixel_to_normalized(corners_px[i]);
    normalized[i] = Vec2(n.x, n.y);
    observed[i] = Vec2(corners_px[i].x, corners_px[i].y);
  }
  return estimate_impl(camera, normalized, observed, side);
}

std::optional<PoseEstimate> estimate_square_pose_normalized(const CameraModel& camera,
                                                            const std::array<Eigen::Vector2d, 4>& normalized,
                                                            double side) {
  return estimate_impl(camera, normalized, pixels_of(camera, normalized), side);
}

std::optional<Eigen::Vector2d> square_tilt_anisotropy(const std::array<Eigen::Vector2d, 4>& normalized) {
  if (!all_finite(normalized) || !is_proper_quad(normalized)) return std::nullopt;
  const auto centre = centre_jacobian(normalized, 1.0);
  if (!centre) return std::nullopt;
  // A 2x2 matrix is a similarity (q) plus a reflected similarity (r); a
  // rotation's top-left block, scaled, is one of them plus a smaller other,
  // whose share is tan^2 of half the tilt (sigma2 / sigma1 = cos(tilt)).
  // Which one is the larger depends only on the handedness of the frames.
  const auto [q, r] = similarity_parts(centre->a);
  const double q_norm = q.norm(), r_norm = r.norm();
  const double larger = std::max(q_norm, r_norm);
  if (!(larger > 0)) return std::nullopt;
  return (q_norm >= r_norm ? r : q) / larger;
}

void shrink_tilt_by_noise(const CameraModel& camera, const std::array<Eigen::Vector2d, 4>& normalized, double side,
                          double anisotropy_variance, MarkerPose& pose) {
  if (!(anisotropy_variance > 0) || !std::isfinite(anisotropy_variance)) return;
  const auto anisotropy = square_tilt_anisotropy(normalized);
  if (!anisotropy) return;
  // Half-tilt tangents squared: the share measured, and what is left of it
  // once the noise's expected square is taken away.
  const double measured = anisotropy->norm();
  const double corrected = std::sqrt(std::max(0.0, measured * measured - anisotropy_variance));
  const double tilt_measured = 2 * std::atan(std::sqrt(measured));
  if (!(tilt_measured > 0)) return;
  const double tilt_corrected = 2 * std::atan(std::sqrt(corrected));

  const Vec3 normal = pose.rotation.col(2);  // out of the printed face, towards the camera
  const Vec3 towards_camera = -pose.translation.normalized();
  const Vec3 axis = normal.cross(towards_camera);
  const double tilt = std::atan2(axis.norm(), normal.dot(towards_camera));
  if (!(axis.norm() > 0) || !std::isfinite(tilt)) return;
  // The polished pose's tilt, shrunk in the proportion the measurement's is.
  const double turn = tilt * (1 - tilt_corrected / tilt_measured);
  const Mat3 rotation = Eigen::AngleAxisd(turn, axis.normalized()).toRotationMatrix() * pose.rotation;

  // The translation that puts the square, so turned, onto its corners.
  const auto model = model_corners(side);
  Vec3 t;
  if (!solve_translation(rotation, model, normalized, t)) return;
  for (int iter = 0; iter < 3; ++iter) {
    Mat3 jtj = Mat3::Zero();
    Vec3 jtr = Vec3::Zero();
    for (std::size_t i = 0; i < 4; ++i) {
      const Vec3 p = rotation * model[i] + t;
      const double iz = 1 / p.z();
      Mat23 j;
      j << iz, 0, -p.x() * iz * iz, 0, iz, -p.y() * iz * iz;
      const Vec2 res = Vec2(p.x() * iz, p.y() * iz) - normalized[i];
      jtj.noalias() += j.transpose() * j;
      jtr.noalias() += j.transpose() * res;
    }
    const Eigen::LDLT<Mat3> ldlt(jtj);
    const Vec3 step = ldlt.solve(jtr);
    if (ldlt.info() != Eigen::Success || !step.allFinite()) return;
    t -= step;
  }
  MarkerPose shrunk;
  shrunk.rotation = Eigen::Quaterniond(rotation).normalized().toRotationMatrix();
  shrunk.translation = t;
  const double cost = cost_of(camera, shrunk.rotation, shrunk.translation, model, pixels_of(camera, normalized));
  if (!std::isfinite(cost)) return;
  shrunk.reprojection_error_px = std::sqrt(cost / 4);
  pose = shrunk;
}

Point2 project(const CameraModel& camera, const MarkerPose& pose, const Eigen::Vector3d& marker_point) {
  const Vec3 p = pose.rotation * marker_point + pose.translation;
  return camera.normalized_to_pixel({p.x() / p.z(), p.y() / p.z()});
}

}  // namespace markerd::detector
