#include "render_surface.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

#include <fmt/format.h>

namespace markerd::detector {

CoverFrame socket_frame() { return CoverFrame{}; }

CoverFrame switch_frame() {
  CoverFrame f;
  f.height_m = 0.008;
  f.outer_roll_m = 0.003;
  f.inner_roll_m = 0.003;
  f.corner_radius_m = 0.008;
  return f;
}

std::optional<FrameProblem> cover_frame_problem(const CoverFrame& f) {
  if (!(f.opening_m < f.outer_m)) {
    return FrameProblem{"opening_m",
                        fmt::format("must be less than outer_m ({:g} m), got {:g} m", f.outer_m, f.opening_m)};
  }
  if (f.corner_radius_m > f.outer_m / 2) {
    return FrameProblem{"corner_radius_m", fmt::format("must not exceed half of outer_m ({:g} m), got {:g} m",
                                                       f.outer_m / 2, f.corner_radius_m)};
  }
  if (f.outer_roll_m > f.height_m) {
    return FrameProblem{"outer_roll_m",
                        fmt::format("must not exceed height_m ({:g} m), got {:g} m", f.height_m, f.outer_roll_m)};
  }
  if (f.inner_roll_m > f.height_m) {
    return FrameProblem{"inner_roll_m",
                        fmt::format("must not exceed height_m ({:g} m), got {:g} m", f.height_m, f.inner_roll_m)};
  }
  const double band = (f.outer_m - f.opening_m) / 2;
  if (f.outer_roll_m + f.inner_roll_m > band) {
    return FrameProblem{"inner_roll_m", fmt::format("with outer_roll_m ({:g} m) must not exceed the band's width, "
                                                    "(outer_m - opening_m) / 2 = {:g} m, got {:g} m",
                                                    f.outer_roll_m, band, f.inner_roll_m)};
  }
  return std::nullopt;
}

Occluder side_occluder(MarkerSide side, double marker_size_m, double depth_fraction, float reflectance, double z_m) {
  if (!(marker_size_m > 0) || !std::isfinite(marker_size_m)) {
    throw std::invalid_argument(
        fmt::format("side_occluder: marker_size_m must be more than zero, got {}", marker_size_m));
  }
  if (!(depth_fraction > 0 && depth_fraction <= 1)) {
    throw std::invalid_argument(
        fmt::format("side_occluder: depth_fraction must be from 0 to 1, got {}", depth_fraction));
  }
  // It reaches one marker size beyond the outer edge and along the side:
  // past any margin or frame, so that only its inner edge is seen.
  const double h = marker_size_m / 2, far = h + marker_size_m, in = h - depth_fraction * marker_size_m;
  Occluder o;
  o.z_m = z_m;
  o.reflectance = reflectance;
  switch (side) {
    case MarkerSide::top: o.polygon = {{-far, in}, {far, in}, {far, far}, {-far, far}}; break;
    case MarkerSide::right: o.polygon = {{in, -far}, {far, -far}, {far, far}, {in, far}}; break;
    case MarkerSide::bottom: o.polygon = {{-far, -far}, {far, -far}, {far, -in}, {-far, -in}}; break;
    case MarkerSide::left: o.polygon = {{-far, -far}, {-in, -far}, {-in, far}, {-far, far}}; break;
  }
  return o;
}

namespace surface {
namespace {

// The Schuko outlet (SOCKET_FRAME.md): its recess and pin holes.
constexpr double kRecessRadius = 0.039 / 2;
constexpr double kRecessDepth = 0.0175;
constexpr double kPinRadius = 0.0048 / 2;
constexpr double kPinOffset = 0.019 / 2;
// Pin holes are open to the contacts behind: deep enough that no view
// reaches their bottom except straight in, where it is as dark as the sides.
constexpr double kPinDepth = 0.02;
// The plate lies this far below the frame's inner roll, so that a short
// vertical drop of the frame's plastic shows at a slant, as on real parts.
constexpr double kPlateBelowRoll = 0.002;
// The rocker leaves a gap to the opening's edge all round.
constexpr double kRockerGap = 0.002;
constexpr double kGapBelowRoll = 0.003;
// No shadow rays are cast: the recess, the pin holes and the rocker's gap
// get the darkness that their walls' shadow and the scattering inside give
// real parts as their material.
constexpr float kRecessShare = 0.3F;
constexpr float kPinReflectance = 0.02F;
constexpr float kGapShare = 0.3F;

// Plan step of the ray march: a quarter of the pin holes' radius, and finer
// than a supersample at 0.3 m with the thesis camera (0.15 mm), so that no
// roll's edge is stepped over by more than a sample's width.
constexpr double kMarchStep = 0.00025;
// The crossing is refined until it is known to this length along the ray,
// or lies this close to a continuous surface (a roll).
constexpr double kHitTolerance = 1e-6;
constexpr double kSurfaceTolerance = 1e-7;
constexpr int kMaxRefinements = 60;
// A hit this far below the height field at its plan position lies on a
// vertical face (a frame side, the opening's wall, a recess or rocker side).
constexpr double kFaceTolerance = 2e-6;

// The height of a quarter-circle roll of radius r at plan distance `in`
// (0..r) in from its foot's edge: 0 at the band, -r at the foot.
double roll_z(double r, double in) {
  const double c = r - in;
  return -r + std::sqrt(std::max(0.0, r * r - c * c));
}

[[noreturn]] void bad(const std::string& field, const std::string& why) {
  throw std::invalid_argument(fmt::format("render: {} {}", field, why));
}

void check_positive(const std::string& field, double v) {
  if (!std::isfinite(v) || !(v > 0)) bad(field, fmt::format("must be more than zero, got {}", v));
}
void check_non_negative(const std::string& field, double v) {
  if (!std::isfinite(v) || !(v >= 0)) bad(field, fmt::format("must not be negative, got {}", v));
}
void check_unit(const std::string& field, double v) {
  if (!(v >= 0 && v <= 1)) bad(field, fmt::format("must be from 0 to 1, got {}", v));
}

}  // namespace

void check_surface_inputs(const Scene& scene) {
  if (scene.frame) {
    const CoverFrame& f = *scene.frame;
    check_positive("frame.outer_m", f.outer_m);
    check_positive("frame.opening_m", f.opening_m);
    check_positive("frame.height_m", f.height_m);
    check_non_negative("frame.outer_roll_m", f.outer_roll_m);
    check_non_negative("frame.inner_roll_m", f.inner_roll_m);
    check_non_negative("frame.corner_radius_m", f.corner_radius_m);
    check_unit("frame.reflectance", f.reflectance);
    if (const auto problem = cover_frame_problem(f)) bad("frame." + problem->field, problem->why);
  }
  check_unit("insert_reflectance", scene.insert_reflectance);
  check_non_negative("paper_margin_m", scene.paper_margin_m);
  for (std::size_t i = 0; i < scene.occluders.size(); ++i) {
    const Occluder& o = scene.occluders[i];
    const std::string name = fmt::format("occluders[{}]", i);
    if (o.polygon.size() < 3) bad(name + ".polygon", fmt::format("needs at least 3 points, got {}", o.polygon.size()));
    for (const auto& p : o.polygon) {
      if (!p.allFinite()) bad(name + ".polygon", "has a point that is not finite");
    }
    check_positive(name + ".z_m", o.z_m);
    check_unit(name + ".reflectance", o.reflectance);
  }
  if (!(scene.background_grey >= 0 && scene.background_grey <= 255)) {
    bad("background_grey", fmt::format("must be from 0 to 255, got {}", scene.background_grey));
  }
  if (!scene.light.allFinite() || !(scene.light.norm() > 0)) bad("light", "must be a finite direction, not zero");
  // The shading is normalised by the light on the marker's plane: without
  // any ambient light a plane turned away from the light would divide by 0.
  if (!(scene.ambient > 0 && scene.ambient <= 1)) {
    bad("ambient", fmt::format("must be more than 0 and at most 1, got {}", scene.ambient));
  }
}

bool is_flat_print(const Scene& scene) {
  return !scene.frame && scene.occluders.empty() && scene.paper_margin_m == 0 &&
         (scene.insert == Insert::none || !scene.cut_hole);
}

double SurfaceModel::RoundedSquare::distance(double x, double y) const {
  const double qx = std::abs(x) - (half - radius), qy = std::abs(y) - (half - radius);
  // The inner loop of the march: a root only off the corners' arcs, and
  // sqrt, not hypot, since no operand comes near overflow.
  if (qx > 0 && qy > 0) return std::sqrt(qx * qx + qy * qy) - radius;
  return std::max(qx, qy) - radius;
}

Eigen::Vector2d SurfaceModel::RoundedSquare::outward(double x, double y) const {
  const double qx = std::abs(x) - (half - radius), qy = std::abs(y) - (half - radius);
  const double sx = x < 0 ? -1 : 1, sy = y < 0 ? -1 : 1;
  if (qx > 0 && qy > 0) {
    const double n = std::hypot(qx, qy);
    return {sx * qx / n, sy * qy / n};
  }
  return qx > qy ? Eigen::Vector2d(sx, 0) : Eigen::Vector2d(0, sy);
}

SurfaceModel::SurfaceModel(const Scene& scene, const MarkerPattern& pattern)
    : pattern_(pattern),
      size_m_(scene.marker_size_m),
      print_half_m_(pattern.printed_half_extent() * scene.marker_size_m),
      paper_half_m_(print_half_m_ + scene.paper_margin_m),
      has_frame_(scene.frame.has_value()),
      frame_(scene.frame.value_or(CoverFrame{})),
      insert_(scene.insert),
      insert_reflectance_(scene.insert_reflectance),
      ambient_(scene.ambient) {
  outer_ = {frame_.outer_m / 2, frame_.corner_radius_m};
  // The opening's corners are the outer ones scaled, as on moulded frames
  // whose band is about as wide at the corners as along the sides.
  opening_ = {frame_.opening_m / 2, frame_.corner_radius_m * frame_.opening_m / frame_.outer_m};
  rocker_ = {opening_.half - kRockerGap, opening_.radius * (opening_.half - kRockerGap) / opening_.half};

  // Without a frame the insert stands where it would behind the default one.
  const double foot = -frame_.inner_roll_m;
  plate_z_ = foot - kPlateBelowRoll;
  recess_z_ = plate_z_ - kRecessDepth;
  pin_z_ = recess_z_ - kPinDepth;
  // "A few millimetres proud of the frame's inner edge": two thirds of the
  // roll's drop above its foot, below the band whatever the roll.
  rocker_z_ = foot / 3;
  gap_z_ = foot - kGapBelowRoll;
  lowest_z_ = has_frame_ ? -frame_.height_m : 0.0;
  if (insert_ == Insert::socket) lowest_z_ = std::min(lowest_z_, pin_z_);
  if (insert_ == Insert::rocker) lowest_z_ = std::min(lowest_z_, gap_z_);

  light_ = scene.pose.rotation.transpose() * scene.light.normalized();
  flat_shade_ = ambient_ + (1 - ambient_) * std::max(0.0, light_.z());

  for (const Occluder& o : scene.occluders) {
    Polygon p{o.polygon, o.polygon.front(), o.polygon.front(), o.z_m, o.reflectance};
    for (const auto& v : o.polygon) p.lo = p.lo.cwiseMin(v), p.hi = p.hi.cwiseMax(v);
    occluders_.push_back(std::move(p));
  }
}

SurfaceModel::Height SurfaceModel::insert_height(double x, double y) const {
  constexpr double kUnbounded = 1e9;
  switch (insert_) {
    case Insert::none: return {lowest_z_, Region::wall, kUnbounded};
    case Insert::socket: {
      const double r = std::sqrt(x * x + y * y);
      if (r > kRecessRadius) return {plate_z_, Region::plate, r - kRecessRadius};
      const double ax = std::abs(x) - kPinOffset;
      const double to_pin = std::sqrt(ax * ax + y * y) - kPinRadius;
      if (to_pin < 0) return {pin_z_, Region::pin, -to_pin};
      return {recess_z_, Region::recess, std::min(to_pin, kRecessRadius - r)};
    }
    case Insert::rocker: {
      const double to_edge = rocker_.distance(x, y);
      return to_edge <= 0 ? Height{rocker_z_, Region::rocker, -to_edge} : Height{gap_z_, Region::gap, to_edge};
    }
  }
  return {lowest_z_, Region::wall, 0};
}

SurfaceModel::Height SurfaceModel::frame_height(double x, double y) const {
  const double outside = outer_.distance(x, y);
  if (outside > 0) return {-frame_.height_m, Region::wall, outside};
  const double from_opening = opening_.distance(x, y);
  if (from_opening < 0) {
    Height h = insert_ == Insert::none ? Height{-frame_.height_m, Region::wall, 1e9} : insert_height(x, y);
    h.free = std::min(h.free, -from_opening);
    return h;
  }
  double z = 0;
  if (-outside < frame_.outer_roll_m) z = roll_z(frame_.outer_roll_m, -outside);
  if (from_opening < frame_.inner_roll_m) z = std::min(z, roll_z(frame_.inner_roll_m, from_opening));
  return {z, Region::frame, 0};
}

float SurfaceModel::shading(const Eigen::Vector3d& normal) const {
  return static_cast<float>((ambient_ + (1 - ambient_) * std::max(0.0, normal.dot(light_))) / flat_shade_);
}

float SurfaceModel::print_or(const Eigen::Vector2d& print_xy, float otherwise) const {
  const double extent = std::max(std::abs(print_xy.x()), std::abs(print_xy.y()));
  if (extent <= print_half_m_) {
    const auto rf = pattern_.reflectance(print_xy.x() / size_m_, print_xy.y() / size_m_);
    return rf ? *rf : otherwise;  // the hole, cut out
  }
  return extent <= paper_half_m_ ? kPaper : otherwise;
}

bool SurfaceModel::occluded(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double before_s,
                            float& reflectance) const {
  double nearest = before_s;
  bool hit = false;
  for (const Polygon& poly : occluders_) {
    if (d.z() == 0) continue;
    const double s = (poly.z - o.z()) / d.z();
    if (!(s > 0 && s < nearest)) continue;
    const double x = o.x() + s * d.x(), y = o.y() + s * d.y();
    if (x < poly.lo.x() || y < poly.lo.y() || x > poly.hi.x() || y > poly.hi.y()) continue;
    // Even-odd crossings of a ray towards +x.
    bool inside = false;
    const std::size_t n = poly.points.size();
    for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
      const Eigen::Vector2d& a = poly.points[i];
      const Eigen::Vector2d& b = poly.points[j];
      if ((a.y() > y) != (b.y() > y) && x < a.x() + (b.x() - a.x()) * (y - a.y()) / (b.y() - a.y())) inside = !inside;
    }
    if (inside) {
      nearest = s;
      hit = true;
      // Parallel to the marker's plane: shaded as the print is, i.e. not at all.
      reflectance = poly.reflectance;
    }
  }
  return hit;
}

RaySample SurfaceModel::trace(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  constexpr double kNever = std::numeric_limits<double>::infinity();
  float occluder = 0;
  if (!(o.z() > 0)) {
    // Seen from behind: the blank back of the paper, as a flat print shows
    // it (a frame hides its back against the wall; this is only for poses
    // that turn the marker away).
    double s = kNever;
    if (d.z() > 0) {
      s = -o.z() / d.z();
      const Eigen::Vector2d p = o.head<2>() + s * d.head<2>();
      if (print_or(p, -1.0F) < 0) s = kNever;
    }
    if (occluded(o, d, s, occluder)) return {false, occluder};
    return s < kNever ? RaySample{false, kPaper} : RaySample{};
  }
  if (occluded(o, d, kNever, occluder)) return {false, occluder};
  if (!(d.z() < 0)) return {};
  const double s0 = -o.z() / d.z();
  const Eigen::Vector3d p0(o.x() + s0 * d.x(), o.y() + s0 * d.y(), 0.0);
  // Just below the lowest level, so that the march always ends in a hit.
  const double s1 = (lowest_z_ - 1e-6 - o.z()) / d.z();
  if (has_frame_) {
    // Most rays end here, on the flat band.
    const Height h = frame_height(p0.x(), p0.y());
    if (h.region == Region::frame && h.z >= 0) return {false, print_or(p0.head<2>(), frame_.reflectance)};
    return march(o, d, s0, s1, h);
  }
  // A thin sheet of paper: what is not paper lets the ray through to the
  // insert behind the hole, or to the background.
  const double extent = std::max(std::abs(p0.x()), std::abs(p0.y()));
  if (extent > paper_half_m_) return {};
  const float paper = print_or(p0.head<2>(), -1.0F);
  if (paper >= 0) return {false, paper};
  if (insert_ == Insert::none) return {};
  return march(o, d, s0, s1, insert_height(p0.x(), p0.y()));
}

RaySample SurfaceModel::march(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double s0, double s1,
                              Height h0) const {
  // Every height is looked up once: this is the renderer's inner loop.
  struct Probe {
    Eigen::Vector3d p;
    Height h;
    [[nodiscard]] double clearance() const { return p.z() - h.z; }  // above the height field where positive
  };
  const auto probe = [&](double s) {
    const Eigen::Vector3d p = o + s * d;
    return Probe{p, height(p.x(), p.y())};
  };
  Probe prev{o + s0 * d, h0};
  if (prev.clearance() <= 0) return shade_hit(prev.p, prev.h);
  // Over a level region the ray goes straight to where the height may
  // change (Height::free) or to below that level; over a roll, in fixed
  // plan steps.
  const double plan_per_s = std::sqrt(d.x() * d.x() + d.y() * d.y());
  double s_prev = s0;
  while (s_prev < s1) {
    const double step = std::max(prev.h.free, kMarchStep);
    const double s = plan_per_s * (s1 - s_prev) <= step ? s1 : s_prev + step / plan_per_s;
    const Probe at = probe(s);
    if (at.clearance() > 0) {
      prev = at;
      s_prev = s;
      continue;
    }
    // Most hits are on a level face (band, plate, recess floor, rocker,
    // wall): there the crossing is exact without refining, if the ray
    // reaches that level over the same region within this step.
    if (at.h.region != Region::frame || at.h.z == 0) {
      const double s_level = (at.h.z - o.z()) / d.z();
      if (s_level >= s_prev && s_level <= s) {
        Probe there = probe(s_level);
        if (there.h.region == at.h.region && there.h.z == at.h.z) {
          there.p.z() = at.h.z;
          return shade_hit(there.p, there.h);
        }
      }
    }
    // Regula falsi, Illinois variant: on a roll the clearance is smooth
    // and a few steps find it (a facing ray's clearance is nearly linear
    // in s); across a vertical face it jumps, and the halving of the
    // stale end's value shrinks the bracket geometrically all the same.
    double lo = s_prev, hi = s;
    double f_lo = prev.clearance(), f_hi = at.clearance();
    Probe best = at;  // the last point found below the surface
    const double length = d.norm();
    int stale = 0;  // which end stayed last time: -1 lo, +1 hi
    for (int k = 0; k < kMaxRefinements && (hi - lo) * length > kHitTolerance && best.clearance() < -kSurfaceTolerance;
         ++k) {
      double mid = hi - f_hi * (hi - lo) / (f_hi - f_lo);
      if (!(mid > lo && mid < hi)) mid = 0.5 * (lo + hi);
      const Probe m = probe(mid);
      if (m.clearance() <= 0) {
        hi = mid, f_hi = m.clearance(), best = m;
        if (stale == -1) f_lo *= 0.5;
        stale = -1;
      } else {
        lo = mid, f_lo = m.clearance();
        if (stale == 1) f_hi *= 0.5;
        stale = 1;
      }
    }
    return shade_hit(best.p, best.h);
  }
  return {};
}

RaySample SurfaceModel::shade_hit(const Eigen::Vector3d& p, const Height& h) const {
  const bool on_face = p.z() < h.z - kFaceTolerance;
  const Eigen::Vector3d up(0, 0, 1);
  const auto sideways = [](const Eigen::Vector2d& v) { return Eigen::Vector3d(v.x(), v.y(), 0); };
  switch (h.region) {
    case Region::wall: return {};
    case Region::frame: return shade_frame(p, on_face);
    case Region::plate: {
      if (!on_face) return {false, insert_reflectance_ * shading(up)};
      // The recess's wall, facing its axis.
      const Eigen::Vector2d in = -p.head<2>().normalized();
      return {false, insert_reflectance_ * kRecessShare * shading(sideways(in))};
    }
    case Region::recess: {
      if (!on_face) return {false, insert_reflectance_ * kRecessShare * shading(up)};
      return {false, kPinReflectance};  // a pin hole's wall
    }
    case Region::pin: return {false, kPinReflectance};
    case Region::rocker: {
      const Eigen::Vector3d n = on_face ? sideways(rocker_.outward(p.x(), p.y())) : up;
      return {false, insert_reflectance_ * shading(n)};
    }
    case Region::gap: return {false, insert_reflectance_ * kGapShare * shading(up)};
  }
  return {};
}

// The print follows the frame: on the flat band its coordinates are the
// plan's, and over a roll the paper, which does not stretch, covers the
// roll's arc length. So a print point lies further out (outer roll) or
// further in (inner roll) than the plan point under it by the arc's length
// less its plan width, along the roll's direction in plan.
RaySample SurfaceModel::shade_frame(const Eigen::Vector3d& p, bool on_face) const {
  const double from_outline = -outer_.distance(p.x(), p.y());
  const double from_opening = opening_.distance(p.x(), p.y());
  const double ro = frame_.outer_roll_m, ri = frame_.inner_roll_m;
  const Eigen::Vector2d xy = p.head<2>();
  if (on_face) {
    if (from_outline <= from_opening) {
      // The frame's outer side: the paper ends at the outline.
      const Eigen::Vector2d out = outer_.outward(p.x(), p.y());
      return {false, frame_.reflectance * shading(Eigen::Vector3d(out.x(), out.y(), 0))};
    }
    // The drop below the inner roll: the paper goes on down it, if it reaches.
    const Eigen::Vector2d out = opening_.outward(p.x(), p.y());
    const double arc_beyond = ri * (std::numbers::pi / 2 - 1) + (-ri - p.z());
    const float r = print_or(xy - arc_beyond * out, frame_.reflectance);
    return {false, r * shading(Eigen::Vector3d(-out.x(), -out.y(), 0))};
  }
  const double outer_z = from_outline < ro ? roll_z(ro, from_outline) : 0.0;
  const double inner_z = from_opening < ri ? roll_z(ri, from_opening) : 0.0;
  if (outer_z == 0 && inner_z == 0) return {false, print_or(xy, frame_.reflectance)};
  const bool outer = outer_z <= inner_z;
  const double r = outer ? ro : ri;
  const double sin_phi = std::clamp((r - (outer ? from_outline : from_opening)) / r, 0.0, 1.0);
  const double phi = std::asin(sin_phi);
  // Towards the roll's foot, in plan.
  const Eigen::Vector2d foot = outer ? outer_.outward(p.x(), p.y()) : Eigen::Vector2d(-opening_.outward(p.x(), p.y()));
  const Eigen::Vector2d print_xy = xy + r * (phi - sin_phi) * foot;
  const Eigen::Vector3d normal(sin_phi * foot.x(), sin_phi * foot.y(), std::cos(phi));
  return {false, print_or(print_xy, frame_.reflectance) * shading(normal)};
}

std::vector<std::vector<Eigen::Vector3d>> SurfaceModel::outlines() const {
  const auto square = [](double half, double z) {
    return std::vector<Eigen::Vector3d>{{-half, half, z}, {half, half, z}, {half, -half, z}, {-half, -half, z}};
  };
  std::vector<std::vector<Eigen::Vector3d>> out;
  out.push_back(square(std::max(paper_half_m_, has_frame_ ? outer_.half : 0.0), 0));
  if (has_frame_) {
    out.push_back(square(outer_.half, -frame_.height_m));
    if (insert_ != Insert::none) out.push_back(square(opening_.half, lowest_z_));
  }
  // Without a frame, the insert is only seen through the hole: inside the paper's outline.
  for (const Polygon& poly : occluders_) {
    std::vector<Eigen::Vector3d> line;
    for (const auto& v : poly.points) line.emplace_back(v.x(), v.y(), poly.z);
    out.push_back(std::move(line));
  }
  return out;
}

}  // namespace surface
}  // namespace markerd::detector
