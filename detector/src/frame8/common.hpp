#pragma once
// Stage 0 of the frame8 detector (docs/architecture.md, "The frame8
// pipeline"): the types and geometry every stage shares. The grid is the
// marker's 10 x 10 cells (0..10 across, y down); a quad's corners run
// clockwise on screen from its top-left.

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include <Eigen/Core>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "markerd/detector/detection.hpp"
#include "markerd/detector/frame8.hpp"
#include "markerd/detector/geometry.hpp"
#include "markerd/detector/image.hpp"

namespace markerd::detector::frame8 {

// Maps the unit square (0,0) (1,0) (1,1) (0,1) onto a quad (Heckbert's closed form).
struct Homography {
  double a = 1, b = 0, c = 0, d = 0, e = 1, f = 0, g = 0, h = 0;

  static bool from_unit_square(const std::array<Point2, 4>& q, Homography& out) {
    const double sx = q[0].x - q[1].x + q[2].x - q[3].x;
    const double sy = q[0].y - q[1].y + q[2].y - q[3].y;
    const double dx1 = q[1].x - q[2].x, dx2 = q[3].x - q[2].x;
    const double dy1 = q[1].y - q[2].y, dy2 = q[3].y - q[2].y;
    const double den = dx1 * dy2 - dx2 * dy1;
    if (std::abs(den) < 1e-12) return false;
    out.g = (sx * dy2 - dx2 * sy) / den;
    out.h = (dx1 * sy - sx * dy1) / den;
    out.a = q[1].x - q[0].x + out.g * q[1].x;
    out.b = q[3].x - q[0].x + out.h * q[3].x;
    out.c = q[0].x;
    out.d = q[1].y - q[0].y + out.g * q[1].y;
    out.e = q[3].y - q[0].y + out.h * q[3].y;
    out.f = q[0].y;
    return true;
  }
  // From a map of grid coordinates (see grid_map() below).
  static Homography from_grid_map(const Eigen::Matrix3d& grid_to_image);

  [[nodiscard]] Point2 map(double u, double v) const {
    const double w = g * u + h * v + 1;
    return {(a * u + b * v + c) / w, (d * u + e * v + f) / w};
  }
  // The quad it maps the unit square onto (a hole's corners), or the
  // rectangle from (u0, v0) to (u1, v1) of it (a hole grown or moved).
  [[nodiscard]] std::array<Point2, 4> quad(double u0 = 0, double v0 = 0, double u1 = 1, double v1 = 1) const {
    return {map(u0, v0), map(u1, v0), map(u1, v1), map(u0, v1)};
  }
};

// Grid coordinates (0..10 across the marker, y down) of the inner square's
// corners, and the map from grid coordinates to the unit square of that quad.
constexpr double kInnerLo = frame8::line_inner;
constexpr double kInnerSide = frame8::grid - 2 * frame8::line_inner;  // 7 cells
inline Point2 grid_point(const Homography& H, double gx, double gy) {
  return H.map((gx - kInnerLo) / kInnerSide, (gy - kInnerLo) / kInnerSide);
}

inline Point2 grid_point(const Homography& H, Point2 g) { return grid_point(H, g.x, g.y); }

// Where along a side (cells, side_point()'s `along`) to sample its line or
// the hole beside it: the middle six cells, clear of the corners' blur.
inline constexpr std::array<double, 6> kSideMiddle{2.5, 3.5, 4.5, 5.5, 6.5, 7.5};

// H as a 3x3 matrix on homogeneous coordinates of its unit square.
inline Eigen::Matrix3d unit_map(const Homography& H) {
  Eigen::Matrix3d unit_to_image;
  unit_to_image << H.a, H.b, H.c, H.d, H.e, H.f, H.g, H.h, 1;
  return unit_to_image;
}

// The map from grid coordinates to the image of a homography onto the
// hole, as a 3x3 matrix on homogeneous grid coordinates.
inline Eigen::Matrix3d grid_map(const Homography& H) {
  const Eigen::Matrix3d unit_to_image = unit_map(H);
  Eigen::Matrix3d grid_to_unit;
  grid_to_unit << 1 / kInnerSide, 0, -kInnerLo / kInnerSide, 0, 1 / kInnerSide, -kInnerLo / kInnerSide, 0, 0, 1;
  return unit_to_image * grid_to_unit;
}

// The map from grid coordinates to the image of a homography onto the
// marker's outer square.
inline Eigen::Matrix3d outer_grid_map(const Homography& H) {
  return unit_map(H) * Eigen::Vector3d(1.0 / frame8::grid, 1.0 / frame8::grid, 1).asDiagonal();
}

inline Homography Homography::from_grid_map(const Eigen::Matrix3d& grid_to_image) {
  Eigen::Matrix3d unit_to_grid;
  unit_to_grid << kInnerSide, 0, kInnerLo, 0, kInnerSide, kInnerLo, 0, 0, 1;
  Eigen::Matrix3d m = grid_to_image * unit_to_grid;
  m /= m(2, 2);
  Homography h;
  h.a = m(0, 0), h.b = m(0, 1), h.c = m(0, 2);
  h.d = m(1, 0), h.e = m(1, 1), h.f = m(1, 2);
  h.g = m(2, 0), h.h = m(2, 1);
  return h;
}

// How uncertain a fitted grid-to-image map is: its change along each of
// the fit's free directions, by one standard deviation of what the fit
// leaves unexplained (the pattern's edges' scatter, the model's pixels').
struct MapNoise {
  std::array<Eigen::Matrix3d, 8> deltas{};
  int count = 0;
};

inline Point2 map_grid(const Eigen::Matrix3d& M, double gx, double gy) {
  const Eigen::Vector3d q = M * Eigen::Vector3d(gx, gy, 1);
  return {q(0) / q(2), q(1) / q(2)};
}

// The marker's outer corners in grid coordinates, clockwise from top left.
inline constexpr std::array<Point2, 4> kOuterGridCorners{
    {{0, 0}, {frame8::grid, 0}, {frame8::grid, frame8::grid}, {0, frame8::grid}}};

// The grid point `in` cells in from the outer edge on a side (0 top, 1
// right, 2 bottom, 3 left), `along` cells along it in the clockwise reading
// order: one description of a position for all four sides.
inline Point2 side_point(int side, double along, double in) {
  switch (side) {
    case 0: return {along, in};
    case 1: return {frame8::grid - in, along};
    case 2: return {frame8::grid - along, frame8::grid - in};
    default: return {in, frame8::grid - along};
  }
}

// A hole read beyond its own component (grown, moved onto edges, a side
// found past the step's first reach, two pieces joined) may be a square of
// a grid (tiles, keys, window panes) taken with the grid's lines round it
// for a ring: one colour from end to end but for a cell or two, read as a
// near-uniform id or with a cell outvoted. Those reads are refused there.
inline bool reads_like_a_grid(const Detection& det) { return near_uniform(det.id) || det.bits_corrected > 0; }

inline double cross(Point2 o, Point2 a, Point2 b) { return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x); }

// The mean of a quad's corners.
inline Point2 centre_of(const Quad& q) { return 0.25 * (q[0] + q[1] + q[2] + q[3]); }

// Whether a point lies on the image (within its first and last pixel
// centres).
inline bool in_image(const GreyView& img, Point2 p) {
  return p.x >= 0 && p.y >= 0 && p.x <= img.width - 1 && p.y <= img.height - 1;
}

// Whether a bilinear sample at (x, y) lies inside the image; the samples
// along a segment do when both its ends do.
inline bool samples_inside(const GreyView& img, double x, double y) {
  return x >= 0 && y >= 0 && x <= img.width - 1.001 && y <= img.height - 1.001;
}

// Bilinear sample at a point samples_inside() accepts.
inline float sample_inside(const GreyView& img, double x, double y) {
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const std::uint8_t* r0 = img.row(y0) + x0;
  const std::uint8_t* r1 = r0 + img.stride;
  const float top = r0[0] + fx * (r0[1] - r0[0]);
  const float bot = r1[0] + fx * (r1[1] - r1[0]);
  return top + fy * (bot - top);
}

// Bilinear sample; false outside the image.
inline bool sample(const GreyView& img, double x, double y, float& out) {
  if (!samples_inside(img, x, y)) return false;
  out = sample_inside(img, x, y);
  return true;
}

// A profile across an edge: `count` samples from `at` + `from` * `across`,
// `step` apart along `across` (a unit vector). False, with nothing
// sampled, when any sample would fall outside the image: the samples lie
// on a segment, so its two ends decide. The segment is under 64 pixels long.
inline bool sample_profile(const GreyView& img, Point2 at, Point2 across, double from, double step, int count,
                           float* out) {
  const double to = from + (count - 1) * step;
  assert(std::abs(to - from) < 64);
  if (!samples_inside(img, at.x + from * across.x, at.y + from * across.y) ||
      !samples_inside(img, at.x + to * across.x, at.y + to * across.y)) {
    return false;
  }
  int s = 0;
#if defined(__SSE2__)
  // Four samples at a time: this is most of the edge refinement's time.
  // Positions are taken in float relative to a pixel 64 to the left and
  // above the first (every sample lies within 64 pixels of it), which
  // keeps them positive, so truncation floors, and exact to 1e-5 pixels.
  // A count that is no multiple of four ends with four that overlap the
  // ones before.
  if (count >= 4) {
    const double bx = at.x + from * across.x, by = at.y + from * across.y;
    const int ox = static_cast<int>(bx) - 64, oy = static_cast<int>(by) - 64;
    const __m128 rx0 = _mm_set1_ps(static_cast<float>(bx - ox)), ry0 = _mm_set1_ps(static_cast<float>(by - oy));
    const __m128 sx = _mm_set1_ps(static_cast<float>(step * across.x)),
                 sy = _mm_set1_ps(static_cast<float>(step * across.y));
    const __m128i low_byte = _mm_set1_epi32(0xFF);
    const std::uint8_t* origin = img.data + static_cast<std::ptrdiff_t>(oy) * img.stride + ox;
    const std::ptrdiff_t stride = img.stride;
    auto pair_at = [](const std::uint8_t* p) {
      std::uint16_t pair = 0;  // two neighbours, little-endian as SSE2's x86 is
      std::memcpy(&pair, p, 2);
      return static_cast<int>(pair);
    };
    for (;;) {
      const __m128 k = _mm_add_ps(_mm_set1_ps(static_cast<float>(s)), _mm_setr_ps(0, 1, 2, 3));
      const __m128 rx = _mm_add_ps(rx0, _mm_mul_ps(k, sx)), ry = _mm_add_ps(ry0, _mm_mul_ps(k, sy));
      const __m128i ix = _mm_cvttps_epi32(rx), iy = _mm_cvttps_epi32(ry);
      const __m128 fx = _mm_sub_ps(rx, _mm_cvtepi32_ps(ix)), fy = _mm_sub_ps(ry, _mm_cvtepi32_ps(iy));
      alignas(16) std::array<std::int32_t, 4> xs{}, ys{};
      _mm_store_si128(reinterpret_cast<__m128i*>(xs.data()), ix);
      _mm_store_si128(reinterpret_cast<__m128i*>(ys.data()), iy);
      const std::uint8_t* p0 = origin + ys[0] * stride + xs[0];
      const std::uint8_t* p1 = origin + ys[1] * stride + xs[1];
      const std::uint8_t* p2 = origin + ys[2] * stride + xs[2];
      const std::uint8_t* p3 = origin + ys[3] * stride + xs[3];
      const __m128i t = _mm_setr_epi32(pair_at(p0), pair_at(p1), pair_at(p2), pair_at(p3));
      const __m128i b =
          _mm_setr_epi32(pair_at(p0 + stride), pair_at(p1 + stride), pair_at(p2 + stride), pair_at(p3 + stride));
      const __m128 t0 = _mm_cvtepi32_ps(_mm_and_si128(t, low_byte)), t1 = _mm_cvtepi32_ps(_mm_srli_epi32(t, 8));
      const __m128 b0 = _mm_cvtepi32_ps(_mm_and_si128(b, low_byte)), b1 = _mm_cvtepi32_ps(_mm_srli_epi32(b, 8));
      const __m128 upper = _mm_add_ps(t0, _mm_mul_ps(fx, _mm_sub_ps(t1, t0)));
      const __m128 lower = _mm_add_ps(b0, _mm_mul_ps(fx, _mm_sub_ps(b1, b0)));
      _mm_storeu_ps(out + s, _mm_add_ps(upper, _mm_mul_ps(fy, _mm_sub_ps(lower, upper))));
      if (s + 4 == count) break;
      s = std::min(s + 4, count - 4);
    }
    return true;
  }
#endif
  for (; s < count; ++s) {
    const double off = from + s * step;
    out[s] = sample_inside(img, at.x + off * across.x, at.y + off * across.y);
  }
  return true;
}

struct Line {
  double nx = 0, ny = 0, c = 0;  // nx*x + ny*y = c, |n| = 1
};

// Twice the signed area of a polygon (the shoelace sum): positive when its
// vertices run clockwise on screen (y down).
inline double twice_signed_area(const Point2* v, std::size_t n) {
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Point2 a = v[i], b = v[(i + 1) % n];
    sum += a.x * b.y - b.x * a.y;
  }
  return sum;
}

// The line through a and b (distinct points).
inline Line line_through(Point2 a, Point2 b) {
  const double len = distance(a, b);
  Line l;
  l.nx = -(b.y - a.y) / len;
  l.ny = (b.x - a.x) / len;
  l.c = l.nx * a.x + l.ny * a.y;
  return l;
}

inline bool intersect(const Line& l1, const Line& l2, Point2& p) {
  const double det = l1.nx * l2.ny - l1.ny * l2.nx;
  if (std::abs(det) < 1e-9) return false;
  p = {(l1.c * l2.ny - l1.ny * l2.c) / det, (l1.nx * l2.c - l1.c * l2.nx) / det};
  return true;
}

struct EdgePoint {
  double x, y, w;
};

// Weighted total least squares; drops points further than `reject` from a
// first fit and fits again.
inline bool fit_line(EdgePoint* pts, int n, double reject, Line& line) {
  auto fit = [&](Line& out) {
    double sw = 0, mx = 0, my = 0;
    for (int i = 0; i < n; ++i) {
      if (pts[i].w <= 0) continue;
      sw += pts[i].w;
      mx += pts[i].w * pts[i].x;
      my += pts[i].w * pts[i].y;
    }
    if (sw <= 0) return false;
    mx /= sw;
    my /= sw;
    double sxx = 0, sxy = 0, syy = 0;
    int used = 0;
    for (int i = 0; i < n; ++i) {
      if (pts[i].w <= 0) continue;
      const double dx = pts[i].x - mx, dy = pts[i].y - my;
      sxx += pts[i].w * dx * dx;
      sxy += pts[i].w * dx * dy;
      syy += pts[i].w * dy * dy;
      ++used;
    }
    if (used < 2) return false;
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    const double theta = 0.5 * std::atan2(2 * sxy, sxx - syy);  // direction of the line
    out.nx = -std::sin(theta);
    out.ny = std::cos(theta);
    out.c = out.nx * mx + out.ny * my;
    return true;
  };
  if (!fit(line)) return false;
  bool dropped = false;
  for (int i = 0; i < n; ++i) {
    if (pts[i].w > 0 && std::abs(line.nx * pts[i].x + line.ny * pts[i].y - line.c) > reject) {
      pts[i].w = 0;
      dropped = true;
    }
  }
  return dropped ? fit(line) : true;
}

// The size of a cell in pixels: the mean over the quad, and across its
// narrow direction (a marker turned far has cells of a pixel one way and
// of four the other).
struct CellSize {
  double narrow;
  double mean;
};

// The cell size of a hole's quad. Whether cells are resolved is decided by
// their narrow side: a marker turned far shows cells of a pixel across
// beside cells of four. Its two short sides are opposite each other; one
// short side alone is no such marker, and says nothing of the cells. The
// width across a pair of sides is the area over their mean length: a short
// side that slopes (a marker turned far and seen off the axis) is longer
// than the marker is wide, by up to a half at 80 degrees.
inline CellSize cell_size_of(const std::array<Point2, 4>& hole) {
  std::array<double, 4> side_len{};
  for (std::size_t i = 0; i < 4; ++i) side_len[i] = distance(hole[i], hole[(i + 1) % 4]);
  const double area = std::abs(twice_signed_area(hole.data(), hole.size())) / 2;
  const double across = 2 * area / std::max(side_len[0] + side_len[2], side_len[1] + side_len[3]);
  const double perimeter = side_len[0] + side_len[1] + side_len[2] + side_len[3];
  return {across / kInnerSide, perimeter / 4 / kInnerSide};
}

// A quad's shortest side over its longest: how far a square seen so is
// squeezed (a tenth at about 82 deg).
inline double short_to_long_sides(const std::array<Point2, 4>& quad) {
  double shortest = std::numeric_limits<double>::infinity(), longest = 0;
  for (std::size_t i = 0; i < 4; ++i) {
    const double len = distance(quad[i], quad[(i + 1) % 4]);
    shortest = std::min(shortest, len);
    longest = std::max(longest, len);
  }
  return shortest / longest;
}

// The cell sizes (pixels per cell) at which stages change how they work.
// Cells below kMinCells (the mean over the marker) are not read: beyond
// 3.3 m for the thesis's marker and camera. Clutter offers many such small
// holes, and what their rings read as is noise.
constexpr double kMinCells = 1.2;
// From kResolvedCells, a cell is sampled at four points and is subject to
// the stricter checks; below it the samples are unmixed.
constexpr double kResolvedCells = 3.0;
// Below kThinLineCells the black line (half a cell) is thin against a
// typical blur, and the edges are measured a second time.
constexpr double kThinLineCells = 8.0;

// Below this many pixels per cell (the mean of both directions, or across
// the narrow one where no short edges check the code:
// Frame8Detector::confirming_cell_size), a sampled read must be confirmed
// by the ring model (confirm_by_model). Bench_accuracy
// with the print's 10 mm paper margin, 500 frames a point, 2.0 to 3.0 m
// (1.4 to 2.1 px a cell): 14 wrong ids, none left with the check (and with
// the corners' convexity), for 0 to 1.2 points of rate. None was seen
// from here up; a marker turned far, whose short edges' cells are a pixel
// while the long ones' are four, is read by its short edges' profiles,
// which the model does not know.
constexpr double kModelCheckedCells = 2.5;
// The least cells (pixels, across and along) read with a side hidden
// (hidden_side.cpp): from here every read of the three edges left stands
// without the ring model's confirmation.
constexpr double kHiddenSideCells = kModelCheckedCells;
// Keeps the levels' normal equations of the profile fits solvable where a
// basis barely shows (the outside, at the end of a short profile).
constexpr double kProfileRidge = 1e-3;

// Stage 1's output: light pixels of the working image as row runs, joined
// into components.
struct Run {
  std::int32_t x0, x1;  // light pixels x0 .. x1-1
  std::int32_t y;
  std::int32_t parent;
  std::int32_t next;  // next run of the same component, -1 at the end
};
struct Component {
  std::int64_t area = 0;
  std::int32_t x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  std::int32_t first = -1, last = -1;
  bool touches_border = false;
  // It lies within a detection, is too small to hold an open hole, or is
  // a quad with no dark island large enough to be a marker's ink: stage
  // 2b leaves it alone.
  bool settled = false;
  // It lies within a detection, or was read: no piece of another hole
  // (stage 2d).
  bool read = false;
  // A quad was fitted to it: its outline is no open hole, but a dark
  // island inside it may be a marker's ink (stage 2c).
  bool quad = false;
  // The dark pixels within its rows' spans (quad fitting measures them).
  std::int64_t dark_inside = 0;
  // Its quad is under 20 px a side and bulges as only a cover frame's
  // rounded hole may (quad_fit.cpp): a grid's square joined to its
  // neighbour bulges so too.
  bool small_and_bulging = false;
};

// An edge of the printed pattern seen in the image: the point lies on the
// grid line `value` of the given axis (0: x = value, 1: y = value).
struct PatternEdge {
  double x, y, w;
  int axis;
  double value;
};

// One side of the marker hidden by something in front of it: its ring, its
// line and perhaps some of the hole, `depth` cells in from the outer edge of
// the quad's `side` (0 top, 1 right, 2 bottom, 3 left; -1: nothing hidden).
struct HiddenSide {
  int side = -1;
  double depth = 0;
  // How far a grid point lies in from the hidden side's outer edge.
  [[nodiscard]] double in_from_side(Point2 g) const {
    switch (side) {
      case 0: return g.y;
      case 1: return frame8::grid - g.x;
      case 2: return frame8::grid - g.y;
      default: return g.x;
    }
  }
  [[nodiscard]] bool covers(Point2 g) const { return side >= 0 && in_from_side(g) < depth; }
  // Any part of the cell: a cell half under the cover reads as neither colour.
  [[nodiscard]] bool covers(frame8::Cell c) const {
    if (side < 0) return false;
    const double nearest = side == 0   ? c.row
                           : side == 1 ? frame8::grid - 1 - c.col
                           : side == 2 ? frame8::grid - 1 - c.row
                                       : c.col;
    return nearest < depth;
  }
};

struct CellSample {
  float mean = 0, lo = 0, hi = 0;  // over the points sampled in the cell
  bool valid = false;
};

// The two short edges of a marker turned far hold all four corners, as
// cells of about a pixel along the edge, with the background beyond them:
// a corner's centre sample is a mix no fixed share can undo. Along the
// edge, though, the profile of the ten cells is known once the code is:
// fitted to it with the corners coloured each way, the right colouring
// leaves the least residual. Per colouring of the edge's first and last
// cell (0: both black, 1: the first white, 2: the last white): the
// residual sum of squares, and what a corner's colour is worth in it (the
// residual that taking a right-coloured corner for the wrong colour adds,
// per unit of contrast squared).
struct ShortEdgeFit {
  std::array<double, 3> residual{};
  std::array<double, 2> corner_worth{};
  double spread = 0;  // the profile's sum of squares about its mean
};

}  // namespace markerd::detector::frame8
