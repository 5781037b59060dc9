#include "ring_model.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <span>
#include <utility>

#include "markerd/detector/frame8.hpp"
#include "normal_table.hpp"

namespace markerd::detector::frame8 {
namespace {

using detail::normal_table;
using detail::NormalTable;

// Beyond a box of this many pixels, cells are several pixels wide and
// sampling them is better and cheaper. An area, not a side: a marker turned
// far is a tall sliver whose cells are a pixel wide however tall it is.
constexpr double kMaxBoxPx = 72.0 * 72.0;
// To read the levels, a pixel whose footprint lies more than this much
// outside the marker says more about the background than about the ring.
constexpr double kMaxOutsideToRead = 0.5;
// For the geometry, every pixel the marker's edge reaches: its other share
// is the outside's level, which the fit finds too, and without the outer
// half of the edge's blur the outer edge slid outwards as the cells shrank
// (the hole 0.25 % too large at 2.2 m, 0.96 % at 2.8 m). But not the
// pixels beyond: the outside is one level a side, and a marker rolled in
// the image leaves whatever lies beyond its print in its box's corners
// (corner error 0.13 px at 2.3 m rolled 45 deg with every pixel of the
// box; 0.04 with those of a twentieth on the marker at least).
constexpr double kMaxOutsideForGeometry = 0.95;
// Pull of every level towards the mean grey, against the few combinations
// that the pixels leave undetermined (an outside strip barely touched).
constexpr double kRidge = 0.02;
// How far (in footprint widths) a grid line still counts for a pixel.
constexpr double kReach = 3.5;
// A region's share of a pixel (or its slope) under this is left out.
constexpr double kNegligible = 1e-5;
// Steps of the map per alignment, and the step (largest corner
// displacement, pixels) under which it has converged: the alignment places
// cells for their levels, and a twentieth of a pixel is a fortieth of the
// smallest cell it reads. From the pattern's map a fit stopped at 0.01 px
// took 3.4 steps on average; at 0.05, 2.1 (bench_detect's frames), with the
// same reads on the fixed-seed sets to 3 m.
constexpr int kAlignIterations = 4;
constexpr double kAlignConverged = 0.05;
// For the geometry, the map to a hundredth of a pixel: a fifth of the
// corners' error where cells are 2 px. Started from the pattern's map it
// takes two or three steps; a two-hundredth and ten steps gave the same
// median corner errors to within 0.007 px on bench_accuracy's sets, for 2 %
// more instructions.
constexpr int kGeometryIterations = 6;
constexpr double kGeometryConverged = 0.01;

// The lines of the printed pattern along each grid axis, between -inf and
// +inf: every region is a rectangle between two of them on each axis.
constexpr std::array<double, 15> kLines{-1e9, 0, 1, line_inner, 2, 3, 4, 5, 6, 7, 8, grid - line_inner, 9, 10, 1e9};
static_assert(kLines[3] == 1.5 && kLines[11] == 8.5);
constexpr int line_index(double v) {
  for (int i = 0; i < static_cast<int>(kLines.size()); ++i) {
    if (kLines[static_cast<std::size_t>(i)] == v) return i;
  }
  return -1;
}

struct Rect {
  int x0, x1, y0, y1;  // indices into kLines
};

// The rectangle of every region, in the order of RingModel's regions. The
// line's corners go with the top and bottom sides.
constexpr std::array<Rect, RingModel::kRegions> make_rects() {
  std::array<Rect, RingModel::kRegions> rects{};
  for (int row = 0; row < grid; ++row) {
    for (int col = 0; col < grid; ++col) {
      const int r = RingModel::ring_region(col, row);
      if (r < 0) continue;
      rects[static_cast<std::size_t>(r)] = {line_index(col), line_index(col + 1), line_index(row), line_index(row + 1)};
    }
  }
  const int o = line_index(0), i1 = line_index(1), i15 = line_index(1.5), i85 = line_index(8.5), i9 = line_index(9),
            t = line_index(10), lo = 0, hi = static_cast<int>(kLines.size()) - 1;
  rects[RingModel::kLine + 0] = {i1, i9, i1, i15};
  rects[RingModel::kLine + 1] = {i85, i9, i15, i85};
  rects[RingModel::kLine + 2] = {i1, i9, i85, i9};
  rects[RingModel::kLine + 3] = {i1, i15, i15, i85};
  rects[RingModel::kHole] = {i15, i85, i15, i85};
  rects[RingModel::kOutside + 0] = {lo, hi, lo, o};
  rects[RingModel::kOutside + 1] = {t, hi, o, t};
  rects[RingModel::kOutside + 2] = {lo, hi, t, hi};
  rects[RingModel::kOutside + 3] = {lo, o, o, t};
  return rects;
}
constexpr std::array<Rect, RingModel::kRegions> kRects = make_rects();

// The regions lie between the lines: per interval of each axis (between
// kLines[i] and kLines[i + 1]), the regions that cover the cell of the two
// intervals, as bits. A pixel's footprint reaches the intervals of the lines
// it looks up and the one before; or-ing their cells' bits gives its
// regions in ascending order without testing all of them.
constexpr int kIntervals = static_cast<int>(kLines.size()) - 1;
using RegionBits = std::uint64_t;
static_assert(RingModel::kRegions <= 64);
constexpr std::array<std::array<RegionBits, kIntervals>, kIntervals> make_region_bits() {
  std::array<std::array<RegionBits, kIntervals>, kIntervals> bits{};
  for (int r = 0; r < RingModel::kRegions; ++r) {
    const Rect& q = kRects[static_cast<std::size_t>(r)];
    for (int y = q.y0; y < q.y1; ++y) {
      for (int x = q.x0; x < q.x1; ++x) {
        bits[static_cast<std::size_t>(y)][static_cast<std::size_t>(x)] |= RegionBits{1} << r;
      }
    }
  }
  return bits;
}
constexpr std::array<std::array<RegionBits, kIntervals>, kIntervals> kRegionBits = make_region_bits();

// The marker's outer corners in grid coordinates.
constexpr std::array<std::pair<int, int>, 4> kOuterCorners{{{0, 0}, {grid, 0}, {grid, grid}, {0, grid}}};

}  // namespace

bool RingModel::prepare(const GreyView& image, const Eigen::Matrix3d& grid_to_image, double max_outside) {
  double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
  for (const auto& [gx, gy] : kOuterCorners) {
    const Eigen::Vector3d p = grid_to_image * Eigen::Vector3d(gx, gy, 1);
    if (!(p(2) > 0)) return false;
    x0 = std::min(x0, p(0) / p(2));
    x1 = std::max(x1, p(0) / p(2));
    y0 = std::min(y0, p(1) / p(2));
    y1 = std::max(y1, p(1) / p(2));
  }
  if (!((x1 - x0) * (y1 - y0) <= kMaxBoxPx)) return false;
  // Pixels whose footprint reaches the marker; most of those on the rim
  // are dropped again as mostly outside.
  px0_ = static_cast<int>(std::floor(x0));
  px1_ = static_cast<int>(std::ceil(x1));
  py0_ = static_cast<int>(std::floor(y0));
  py1_ = static_cast<int>(std::ceil(y1));
  if (px0_ < 0 || py0_ < 0 || px1_ >= image.width || py1_ >= image.height) return false;
  cx_ = 0.5 * (x0 + x1);
  cy_ = 0.5 * (y0 + y1);
  scale_ = std::max(1.0, 0.5 * std::max(x1 - x0, y1 - y0));
  Eigen::FullPivLU<Eigen::Matrix3d> lu(grid_to_image);
  if (!lu.isInvertible()) return false;
  to_grid_ = lu.inverse() * from_centred();
  if (std::abs(to_grid_(2, 2)) < 1e-12) return false;
  to_grid_ /= to_grid_(2, 2);
  map_moved();
  blur_map_ = to_grid_;
  // The footprint's width in the grid, per pixel: held fixed while the map
  // moves, so the model's slopes are its exact derivatives.
  const int width = px1_ - px0_ + 1;
  width_.resize(static_cast<std::size_t>(width) * (py1_ - py0_ + 1));
  for (int py = py0_; py <= py1_; ++py) {
    for (int px = px0_; px <= px1_; ++px) {
      const double u = (px - cx_) / scale_, v = (py - cy_) / scale_;
      const Eigen::Vector3d g0 = blur_map_ * Eigen::Vector3d(u, v, 1);
      const double w0 = g0(2), gx0 = g0(0) / w0, gy0 = g0(1) / w0;
      const double j00 = (blur_map_(0, 0) - gx0 * blur_map_(2, 0)) / w0 / scale_;
      const double j01 = (blur_map_(0, 1) - gx0 * blur_map_(2, 1)) / w0 / scale_;
      const double j10 = (blur_map_(1, 0) - gy0 * blur_map_(2, 0)) / w0 / scale_;
      const double j11 = (blur_map_(1, 1) - gy0 * blur_map_(2, 1)) / w0 / scale_;
      width_[static_cast<std::size_t>(py - py0_) * width + (px - px0_)] = {
          static_cast<float>(sigma_ * std::hypot(j00, j01)), static_cast<float>(sigma_ * std::hypot(j10, j11))};
    }
  }
  // The pixels the fit uses, decided once: a set that changed with the map
  // would change the sum being minimised under the steps that minimise it.
  // Their mean grey is the levels' prior.
  // The levels' normal equations for this map are summed on the way, as
  // solve_levels() would sum them: the coverages are the ones it needs.
  inside_.assign(static_cast<std::size_t>(width) * (py1_ - py0_ + 1), 1);
  pixel_coverage_.assign(inside_.size(), PixelCoverage{});
  clear_levels_normal();
  double sum = 0;
  for (int py = py0_; py <= py1_; ++py) {
    const std::uint8_t* row = image.row(py);
    for (int px = px0_; px <= px1_; ++px) {
      double gx = 0, gy = 0, w = 0;
      const std::span<const RegionCoverage> regions = coverage(px, py, false, gx, gy, w);
      double outside = 0;
      for (const RegionCoverage& region : regions) {
        if (region.region >= kOutside) outside += region.cover;
      }
      const bool inside = !regions.empty() && outside <= max_outside;
      inside_[static_cast<std::size_t>(py - py0_) * width + (px - px0_)] = inside;
      if (inside) {
        sum += row[px];
        add_pixel_to_levels(regions, row[px]);
      }
    }
  }
  if (normal_.used < 2 * kRegions) return false;
  prior_ = sum / normal_.used;
  return true;
}

Eigen::Matrix3d RingModel::from_centred() const {
  Eigen::Matrix3d m;
  m << scale_, 0, cx_, 0, scale_, cy_, 0, 0, 1;
  return m;
}

Eigen::Matrix3d RingModel::grid_to_image() const { return from_centred() * to_grid_.inverse(); }

std::span<const RingModel::RegionCoverage> RingModel::coverage(int px, int py, bool slopes, double& gx, double& gy,
                                                               double& w) {
  const auto pixel = static_cast<std::size_t>(py - py0_) * (px1_ - px0_ + 1) + (px - px0_);
  if (!inside_[pixel]) return {};
  PixelCoverage& cached = pixel_coverage_[pixel];
  if (cached.version != map_version_) {
    // The first pass with this map: computed, and kept for the next.
    if (covered_version_ != map_version_) {
      covered_.clear();
      covered_version_ = map_version_;
    }
    cached.version = map_version_;
    cached.first = static_cast<std::uint32_t>(covered_.size());
    cached.n = compute_coverage(pixel, px, py, cached.gx, cached.gy, cached.w);
  }
  gx = cached.gx;
  gy = cached.gy;
  w = cached.w;
  const std::span<const RegionCoverage> all(covered_.data() + cached.first, static_cast<std::size_t>(cached.n));
  if (slopes) return all;
  // Without slopes, only the regions whose share matters: rarely fewer.
  const auto negligible = [](const RegionCoverage& region) { return region.cover < kNegligible; };
  if (std::none_of(all.begin(), all.end(), negligible)) return all;
  const auto end = std::remove_copy_if(all.begin(), all.end(), shares_.begin(), negligible);
  return {shares_.data(), static_cast<std::size_t>(end - shares_.begin())};
}

int RingModel::compute_coverage(std::size_t pixel, int px, int py, double& gx, double& gy, double& w) {
  const double u = (px - cx_) / scale_, v = (py - cy_) / scale_;
  const Eigen::Vector3d g = to_grid_ * Eigen::Vector3d(u, v, 1);
  w = g(2);
  if (!(w > 0)) return 0;
  gx = g(0) / w;
  gy = g(1) / w;
  // The footprint is a Gaussian in the image; through the local map it is
  // a Gaussian in the grid too, and (for the rotations, yaw and tilt of a
  // marker in front of a camera) one whose axes are near the grid's: its
  // share of a rectangle is then a product along the two axes.
  const double sx = width_[pixel][0], sy = width_[pixel][1];
  // Only the lines within kReach widths of the footprint are looked up:
  // below them the distribution is taken as 0, above them as 1 (off by
  // under 3e-7), and a region between two lines on the same side has no
  // share and no slope.
  const NormalTable& table = normal_table();
  int x_lo = 0, x_hi = 0, y_lo = 0, y_hi = 0;  // the lines looked up: [lo, hi)
  auto lines_within_reach = [&](double at, double s, int& lo, int& hi) {
    const double reach = kReach * s;
    lo = 0;
    while (lo < static_cast<int>(kLines.size()) && kLines[static_cast<std::size_t>(lo)] <= at - reach) ++lo;
    hi = lo;
    while (hi < static_cast<int>(kLines.size()) && kLines[static_cast<std::size_t>(hi)] < at + reach) ++hi;
  };
  auto axis = [&](double at, double s, int lo, int hi, std::array<double, kLines.size()>& f,
                  std::array<double, kLines.size()>& d) {
    for (int k = lo; k < hi; ++k) {
      double c = 0, p = 0;
      table.at((kLines[static_cast<std::size_t>(k)] - at) / s, c, p);
      f[static_cast<std::size_t>(k)] = c;
      d[static_cast<std::size_t>(k)] = -p / s;  // d/d(at) of Phi((line - at) / s)
    }
    for (int k = hi; k < static_cast<int>(kLines.size()); ++k) f[static_cast<std::size_t>(k)] = 1;
  };
  lines_within_reach(gx, sx, x_lo, x_hi);
  lines_within_reach(gy, sy, y_lo, y_hi);
  // A region with both bounds below the looked-up lines, or both above,
  // has nothing: the ones left span an interval from the one before x_lo
  // to the one before x_hi.
  RegionBits regions = 0;
  for (int y = std::max(0, y_lo - 1); y < std::min(kIntervals, y_hi); ++y) {
    for (int x = std::max(0, x_lo - 1); x < std::min(kIntervals, x_hi); ++x) {
      regions |= kRegionBits[static_cast<std::size_t>(y)][static_cast<std::size_t>(x)];
    }
  }
  // One region (deep in the hole, mostly): its bounds lie beyond the lines
  // within reach, whose values it does not read.
  const bool one_region = (regions & (regions - 1)) == 0;
  std::array<double, kLines.size()> fx{}, fy{}, dx{}, dy{};
  axis(gx, sx, one_region ? x_hi : x_lo, x_hi, fx, dx);
  axis(gy, sy, one_region ? y_hi : y_lo, y_hi, fy, dy);
  int n = 0;
  for (; regions != 0; regions &= regions - 1) {
    const int r = __builtin_ctzll(regions);
    const Rect& q = kRects[static_cast<std::size_t>(r)];
    const auto x0 = static_cast<std::size_t>(q.x0), x1 = static_cast<std::size_t>(q.x1);
    const auto y0 = static_cast<std::size_t>(q.y0), y1 = static_cast<std::size_t>(q.y1);
    const double mx = fx[x1] - fx[x0], my = fy[y1] - fy[y0];
    const double c = mx * my;
    const double sxr = (dx[x1] - dx[x0]) * my, syr = mx * (dy[y1] - dy[y0]);
    if (c < kNegligible && std::abs(sxr) < kNegligible && std::abs(syr) < kNegligible) continue;
    covered_.push_back({r, c, sxr, syr});
    ++n;
  }
  return n;
}

// The levels' rows of the normal equations for one pixel: its regions'
// coverages against each other, the lower triangle only (the regions
// ascend: LDLT reads no more, and this is most of a fit's time), and
// against the pixel's grey (or, aligning, its residual).
template <typename Normal, typename Rhs>
void RingModel::add_levels(std::span<const RegionCoverage> regions, double value, Normal& normal, Rhs& rhs) {
  for (std::size_t a = 0; a < regions.size(); ++a) {
    const int ra = regions[a].region;
    const double ca = regions[a].cover;
    rhs(ra) += ca * value;
    for (std::size_t c = 0; c <= a; ++c) normal(ra, regions[c].region) += ca * regions[c].cover;
  }
}

void RingModel::clear_levels_normal() {
  normal_.ata.setZero();
  normal_.atb.setZero();
  normal_.btb = 0;
  normal_.used = 0;
}

// One pixel's row of: pixel = sum over regions of coverage * level, for
// the regions coverage() gave.
void RingModel::add_pixel_to_levels(std::span<const RegionCoverage> regions, double grey) {
  add_levels(regions, grey, normal_.ata, normal_.atb);
  normal_.btb += grey * grey;
  ++normal_.used;
}

bool RingModel::solve_levels(const GreyView& image) {
  clear_levels_normal();
  for (int py = py0_; py <= py1_; ++py) {
    const std::uint8_t* row = image.row(py);
    for (int px = px0_; px <= px1_; ++px) {
      double gx = 0, gy = 0, w = 0;
      const std::span<const RegionCoverage> regions = coverage(px, py, false, gx, gy, w);
      if (!regions.empty()) add_pixel_to_levels(regions, row[px]);
    }
  }
  return solve_accumulated_levels();
}

bool RingModel::drop_clutter(const GreyView& image) {
  // The outside is one level a side; a pixel partly outside that the model
  // misses by this many times the residuals' rms shows something else
  // there (clutter's own edge beside a bare print).
  // Not less: noise alone puts one pixel in a hundred beyond 2.5 rms, and
  // a drop costs a second alignment (at 2.5, 4 % more instructions for
  // the same corners).
  constexpr double kClutterResiduals = 3.5;
  const double limit = kClutterResiduals * rms_;
  const int width = px1_ - px0_ + 1;
  int dropped = 0;
  for (int py = py0_; py <= py1_; ++py) {
    const std::uint8_t* row = image.row(py);
    for (int px = px0_; px <= px1_; ++px) {
      double gx = 0, gy = 0, w = 0;
      const std::span<const RegionCoverage> regions = coverage(px, py, false, gx, gy, w);
      double model = 0, outside = 0;
      for (const RegionCoverage& region : regions) {
        model += level_(region.region) * region.cover;
        if (region.region >= kOutside) outside += region.cover;
      }
      if (regions.empty() || outside <= 0 || std::abs(row[px] - model) <= limit) continue;
      inside_[static_cast<std::size_t>(py - py0_) * width + (px - px0_)] = 0;
      ++dropped;
    }
  }
  return dropped > 0 && solve_levels(image);
}

bool RingModel::solve_accumulated_levels() {
  if (normal_.used == 0) return false;
  LevelsMatrix regularised = normal_.ata;
  Vector rhs = normal_.atb;
  for (int r = 0; r < kRegions; ++r) {
    regularised(r, r) += kRidge;
    rhs(r) += kRidge * prior_;
  }
  const Eigen::LDLT<LevelsMatrix> solver(regularised);
  if (solver.info() != Eigen::Success) return false;
  level_ = solver.solve(rhs);
  const double sse =
      normal_.btb - 2 * level_.dot(normal_.atb) + level_.dot(normal_.ata.selfadjointView<Eigen::Lower>() * level_);
  rms_ = std::sqrt(std::max(0.0, sse) / normal_.used);
  return true;
}

bool RingModel::align(const GreyView& image, int iterations, double converged) {
  for (int iter = 0; iter < iterations; ++iter) {
    double moved = 0;
    if (!align_step(image, moved)) return false;
    if (moved < converged) break;
  }
  return true;
}

bool RingModel::align_step(const GreyView& image, double& moved) {
  // Gauss-Newton over the levels and the map together: apart, the two trade
  // against each other (a line drawn thinner and darker) and creep.
  // Parameters: the levels, then the eight free entries of the map from
  // centred pixels to the grid (the ninth is 1).
  constexpr int kParams = kStepParams;
  using Matrix = StepMatrix;
  using Params = Eigen::Matrix<double, kParams, 1>;
  // The normal equations in three blocks, each entry summed over the
  // pixels in the same order as one matrix would: the levels' own (lower
  // triangle, as in solve_levels()), the map's against each level, and the
  // map's own, dense, whose loops over eight run without indirection.
  Matrix jtj = Matrix::Zero();
  Params jte = Params::Zero();
  std::array<std::array<double, 8>, kRegions> map_level{};
  std::array<double, 8 * 8> map_map{};
  double squared_residuals = 0;
  int pixels = 0;
  for (int py = py0_; py <= py1_; ++py) {
    const std::uint8_t* row = image.row(py);
    for (int px = px0_; px <= px1_; ++px) {
      double gx = 0, gy = 0, w = 0;
      const std::span<const RegionCoverage> regions = coverage(px, py, true, gx, gy, w);
      if (regions.empty()) continue;
      double model = 0, dgx = 0, dgy = 0;
      for (const RegionCoverage& region : regions) {
        model += level_(region.region) * region.cover;
        dgx += level_(region.region) * region.slope_x;
        dgy += level_(region.region) * region.slope_y;
      }
      const double e = row[px] - model;
      squared_residuals += e * e;
      ++pixels;
      add_levels(regions, e, jtj, jte);
      // Deep in the hole or a cell, no line within reach: the map moves
      // nothing there.
      if (dgx == 0 && dgy == 0) continue;
      const double u = (px - cx_) / scale_, v = (py - cy_) / scale_;
      const double radial = dgx * gx + dgy * gy;
      const std::array<double, 8> geometry{dgx * u / w, dgx * v / w, dgx / w,         dgy * u / w,
                                           dgy * v / w, dgy / w,     -radial * u / w, -radial * v / w};
      // The loops over the map's eight unrolled: they are most of a step's time.
      for (const RegionCoverage& region : regions) {
        auto& row_of = map_level[static_cast<std::size_t>(region.region)];
#pragma GCC unroll 8
        for (int k = 0; k < 8; ++k)
          row_of[static_cast<std::size_t>(k)] += geometry[static_cast<std::size_t>(k)] * region.cover;
      }
#pragma GCC unroll 8
      for (int k = 0; k < 8; ++k) {
        const double jk = geometry[static_cast<std::size_t>(k)];
        jte(kRegions + k) += jk * e;
#pragma GCC unroll 8
        for (int c = 0; c <= k; ++c)
          map_map[static_cast<std::size_t>(8 * k + c)] += jk * geometry[static_cast<std::size_t>(c)];
      }
    }
  }
  for (int k = 0; k < 8; ++k) {
    for (int r = 0; r < kRegions; ++r)
      jtj(kRegions + k, r) = map_level[static_cast<std::size_t>(r)][static_cast<std::size_t>(k)];
    for (int c = 0; c <= k; ++c) jtj(kRegions + k, kRegions + c) = map_map[static_cast<std::size_t>(8 * k + c)];
  }
  for (int r = 0; r < kRegions; ++r) {
    jtj(r, r) += kRidge;
    jte(r) += kRidge * (prior_ - level_(r));
  }
  // Levenberg's damping keeps a step within what the linearisation holds.
  for (int k = kRegions; k < kParams; ++k) jtj(k, k) *= 1.0 + 1e-3;
  step_solver_.compute(jtj);
  if (step_solver_.info() != Eigen::Success) return false;
  const Params d = step_solver_.solve(jte);
  if (!d.allFinite()) return false;
  step_variance_ = pixels > kParams ? squared_residuals / (pixels - kParams) : 0.0;
  level_ += d.head<kRegions>();
  const Eigen::Matrix3d before = grid_to_image();
  to_grid_(0, 0) += d(kRegions + 0);
  to_grid_(0, 1) += d(kRegions + 1);
  to_grid_(0, 2) += d(kRegions + 2);
  to_grid_(1, 0) += d(kRegions + 3);
  to_grid_(1, 1) += d(kRegions + 4);
  to_grid_(1, 2) += d(kRegions + 5);
  to_grid_(2, 0) += d(kRegions + 6);
  to_grid_(2, 1) += d(kRegions + 7);
  map_moved();
  const Eigen::Matrix3d after = grid_to_image();
  moved = 0;
  for (const auto& [gx, gy] : kOuterCorners) {
    const Eigen::Vector3d a = before * Eigen::Vector3d(gx, gy, 1), b = after * Eigen::Vector3d(gx, gy, 1);
    moved = std::max(moved, std::hypot(a(0) / a(2) - b(0) / b(2), a(1) / a(2) - b(1) / b(2)));
  }
  return std::isfinite(moved);
}

void RingModel::map_noise(MapNoise& out) const {
  out.count = 0;
  // The map's block of the last step's inverse normal equations: its
  // covariance per unit of the residuals' variance, the levels solved for
  // with it (the damping, a thousandth of the diagonal, makes it that much
  // smaller).
  Eigen::Matrix<double, kStepParams, 8> unit = Eigen::Matrix<double, kStepParams, 8>::Zero();
  unit.bottomRows<8>().setIdentity();
  const Eigen::Matrix<double, 8, 8> covariance = step_solver_.solve(unit).bottomRows<8>();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 8, 8>> eig(covariance);
  if (eig.info() != Eigen::Success || !(step_variance_ > 0)) return;
  // Along each principal direction the map scatters by the square root of
  // the covariance's eigenvalue; the map to the image moves by
  // -from_centred T^-1 dT T^-1 for a change dT of T, the map from centred
  // pixels to the grid.
  const Eigen::Matrix3d inverse = to_grid_.inverse();
  for (int k = 0; k < 8; ++k) {
    const double spread = eig.eigenvalues()(k);
    if (!(spread > 0)) continue;
    const Eigen::Matrix<double, 8, 1> d = eig.eigenvectors().col(k) * std::sqrt(step_variance_ * spread);
    Eigen::Matrix3d change;
    change << d(0), d(1), d(2), d(3), d(4), d(5), d(6), d(7), 0;
    out.deltas[static_cast<std::size_t>(out.count++)] = -from_centred() * inverse * change * inverse;
  }
}

bool RingModel::fit(const GreyView& image, Eigen::Matrix3d& grid_to_image, double blur_sigma_px, Aim aim, Levels& out,
                    MapNoise* noise) {
  // A pixel's square convolved with the blur: close to a Gaussian whose
  // variance is the sum of the two.
  sigma_ = std::sqrt(1.0 / 12 + blur_sigma_px * blur_sigma_px);
  const bool geometry = aim == Aim::geometry;
  if (!prepare(image, grid_to_image, geometry ? kMaxOutsideForGeometry : kMaxOutsideToRead) ||
      !solve_accumulated_levels())
    return false;
  return finish(image, grid_to_image, aim, out, noise);
}

bool RingModel::align_levels(const GreyView& image, Eigen::Matrix3d& grid_to_image, Levels& out) {
  return finish(image, grid_to_image, Aim::aligned_levels, out, nullptr);
}

bool RingModel::finish(const GreyView& image, Eigen::Matrix3d& grid_to_image, Aim aim, Levels& out, MapNoise* noise) {
  const bool geometry = aim == Aim::geometry;
  if (aim != Aim::levels) {
    const Eigen::Matrix3d start = to_grid_;
    const Vector start_level = level_;
    const double start_rms = rms_;
    const int iterations = geometry ? kGeometryIterations : kAlignIterations;
    const double converged = geometry ? kGeometryConverged : kAlignConverged;
    bool stepped = align(image, iterations, converged);
    if (geometry && stepped && solve_levels(image) && drop_clutter(image)) {
      // Fitted again without the pixels of whatever stood beside the print.
      stepped = align(image, iterations, converged);
    }
    if (!stepped || !solve_levels(image)) return false;
    if (rms_ > start_rms) {
      // The steps wandered off: keep where it started.
      if (geometry) return false;
      to_grid_ = start;
      map_moved();
      level_ = start_level;
      rms_ = start_rms;
    }
    grid_to_image = this->grid_to_image();
    if (noise) map_noise(*noise);
  }

  for (int row = 0; row < grid; ++row) {
    for (int col = 0; col < grid; ++col) {
      const int r = ring_region(col, row);
      out.cell[static_cast<std::size_t>(row * grid + col)] = r >= 0 ? static_cast<float>(level_(r)) : 0.0F;
    }
  }
  for (int s = 0; s < 4; ++s) out.line[static_cast<std::size_t>(s)] = static_cast<float>(level_(kLine + s));
  out.hole = static_cast<float>(level_(kHole));
  out.rms_residual = rms_;
  return true;
}

}  // namespace markerd::detector::frame8
