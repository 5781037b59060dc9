// Stage 2, quad fitting: each enclosed light component's convex hull and its
// largest inscribed quadrilateral; what is not a quad is dropped.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace markerd::detector::frame8 {

// The quad of a light component, in working-image coordinates, clockwise on
// screen; or why the component is none.
Rejection Frame8Detector::fit_quad(Component& c, std::array<Point2, 4>& quad) {
  if (c.touches_border) return Rejection::touches_border;
  const double d = decimate_;
  const int bw = c.x1 - c.x0, bh = c.y1 - c.y0 + 1;
  const double min_side = config_.frame8.min_hole_side_px / d;
  // The threshold's local-maximum test takes the blurred pixel on each
  // side of a hole: a hole turned far (75 degrees, 6 px across) comes out
  // 4 px wide, so the narrow side may be that much short, when the long
  // side has cells large enough to read the code along it.
  const int narrow = std::min(bw, bh), wide = std::max(bw, bh);
  if (narrow < min_side && (narrow < min_side - 2 / d || wide < 3 * min_side)) return Rejection::box_size;
  if (bw > work_.width * 0.95 || bh > work_.height * 0.95) return Rejection::box_size;
  const bool sparse = c.area < 0.2 * bw * bh;
  if (sparse && wide < min_open_hole_side()) return Rejection::sparse_component;

  const Component* const whole = &c;
  outline_rows({&whole, 1}, c.y0, bh);
  // The area the component's rows span, dark islands inside it included:
  // a hole may show something darker within it (a socket's recess and
  // pins, clutter behind a cut-out hole) and is whole all the same. Each
  // row's span is bounded by the two edge lines beside it.
  double spanned = 0;
  for (int k = 0; k < bh; ++k) {
    const auto a = static_cast<std::size_t>(k), b = static_cast<std::size_t>(k + 1);
    spanned += std::max(0, std::min(line_max_[a], line_max_[b]) - std::max(line_min_[a], line_min_[b]));
  }
  c.dark_inside = std::max<std::int64_t>(0, static_cast<std::int64_t>(spanned) - c.area);
  // A thin ring of light is no hole, but the ink it encloses may be a
  // marker's (stage 2c: a print's paper margin round a cut-out hole over
  // a dark ground, 3 to 4 mm wide as seen from 1.2 to 1.6 m): its dark
  // pixels are measured first, where it may enclose such a marker.
  if (sparse) return Rejection::sparse_component;
  double quad_area = 0, hull_area = 0;
  if (!largest_quad_of_rows(c.y0, bh, quad, quad_area, hull_area)) return Rejection::not_a_quad;

  // The hull must be a quad, and the component must fill most of it.
  // Pixel staircases make a small hull bigger than the quad by up to about
  // a third of a pixel along the perimeter; beyond that it is not a quad,
  // unless its corners are rounded: glued onto a cover frame, the print's
  // hole follows the opening's rounded corners down its inner roll, a
  // radius r of about a tenth of the hole's side (6.5 mm on a 56 mm socket
  // frame), which leaves the largest quad inside the hull 0.08 to 0.11 of
  // it short (measured on renders from 0.3 to 0.7 m). Rounded corners put
  // the hull's sides evenly outside the quad's, by 0.29 r; turned, the
  // inner roll shown at one corner rounds it more than the others, the
  // quad's side beside it tilts, and the hull stands out by up to 0.09 of
  // a side at the side's other end (socket frame at 25 and 30 deg from
  // 0.5 m), 0.11 where the blur rounds a hole of 35 to 40 px further (30
  // deg from 0.72 m, the hull 0.13 to 0.165 over the quad). A part of
  // something else joined to the hole (clutter behind a cut-out hole)
  // sticks out of one side further, and would place the cells a cell off.
  const double perimeter = quad_perimeter(quad), staircase = hull_staircase(perimeter);
  // Under 20 px a side (cells of 3 px) a hole bulges out of its quad on
  // any mount: a cover frame's hole from 2.2 m, 14 px, by its blurred
  // corners and by a white cell joined through a line under a pixel wide
  // (the socket frame facing at 2.2 m, four seeds: 88 to 96% of frames
  // found, 96 to 100% with these); a paper print's hole turned 30 to 45 deg
  // in the image from 1.6 m, whose blurred corners fall on the pixels'
  // staircase (told it is paper and refusing such holes: 72 to 92% found
  // from 1.6 to 3.0 m, against 96 to 100% to 2.6 m). But a bulge of a
  // pixel or two is also all that two squares of a grid joined show, which
  // read as one: such a hole's read must not look like a grid's.
  // The blur rounds a far socket frame's corners further: its hole of 25
  // to 30 px, turned 30 deg at 0.95 m, falls 0.11 to 0.16 short of its hull.
  constexpr double kRoundedMinSide = 20;
  if (hull_area - quad_area > 0.06 * hull_area + staircase) {
    if (perimeter / 4 < kRoundedMinSide) c.small_and_bulging = true;
    constexpr double kRoundedBulge = 0.11;  // of the mean side, and a pixel of staircase
    if (hull_area - quad_area > kRoundedShortfall * hull_area + staircase) return Rejection::not_a_quad;
    double bulge = 0;
    for (const Point2& p : hull_) {
      for (int i = 0; i < 4; ++i) {
        const Point2 a = quad[static_cast<std::size_t>(i)], b = quad[static_cast<std::size_t>((i + 1) % 4)];
        // Clockwise on screen: the outside of side a-b is where the cross product is negative.
        bulge = std::max(bulge, -cross(a, b, p) / distance(a, b));
      }
    }
    if (bulge > kRoundedBulge * perimeter / 4 + 1.0) return Rejection::not_a_quad;
  }
  // The rows must span most of the quad; the light pixels themselves, a
  // good part of it (a socket's recess takes up to 0.4 of its hole).
  if (spanned < 0.8 * quad_area || c.area < kMinLightShare * quad_area) return Rejection::sparse_component;
  for (int i = 0; i < 4; ++i) {
    const Point2 a = quad[static_cast<std::size_t>(i)];
    const Point2 b = quad[static_cast<std::size_t>((i + 1) % 4)];
    const Point2 p = quad[static_cast<std::size_t>((i + 3) % 4)];
    const double la = distance(a, b), lp = distance(a, p);
    if (la < min_side * 0.5) return Rejection::short_quad_side;
    const double cosang = ((b.x - a.x) * (p.x - a.x) + (b.y - a.y) * (p.y - a.y)) / (la * lp);
    // A corner sharper than 20 degrees or flatter than 160.
    if (std::abs(cosang) > 0.94) return Rejection::sharp_corner;
  }
  return Rejection::none;
}

// Per horizontal pixel-edge line k (between rows y0-1+k and y0+k), the
// extreme boundary x of the components' rows touching it: their outline.
void Frame8Detector::outline_rows(std::span<const Component* const> components, int y0, int rows) {
  line_min_.assign(static_cast<std::size_t>(rows) + 1, std::numeric_limits<std::int32_t>::max());
  line_max_.assign(static_cast<std::size_t>(rows) + 1, std::numeric_limits<std::int32_t>::min());
  for (const Component* c : components) {
    for (std::int32_t r = c->first; r >= 0; r = runs_[static_cast<std::size_t>(r)].next) {
      const Run& run = runs_[static_cast<std::size_t>(r)];
      const auto k = static_cast<std::size_t>(run.y - y0);
      for (std::size_t kk = k; kk <= k + 1; ++kk) {
        line_min_[kk] = std::min(line_min_[kk], run.x0);
        line_max_[kk] = std::max(line_max_[kk], run.x1);
      }
    }
  }
}

// The largest quad in the convex hull of the outline (outline_rows()),
// clockwise on screen, and the two areas.
bool Frame8Detector::largest_quad_of_rows(int y0, int rows, std::array<Point2, 4>& quad, double& quad_area,
                                          double& hull_area) {
  // Andrew's monotone chain over points already sorted by (y, x).
  points_.clear();
  for (int k = 0; k <= rows; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    if (line_min_[kk] > line_max_[kk]) continue;  // between two components' rows
    const double y = y0 + k - 0.5;
    points_.push_back({line_min_[kk] - 0.5, y});
    if (line_max_[kk] != line_min_[kk]) points_.push_back({line_max_[kk] - 0.5, y});
  }
  convex_hull();
  if (!max_area_quad(quad)) return false;
  hull_area = std::abs(twice_signed_area(hull_.data(), hull_.size())) / 2;
  quad_area = twice_signed_area(quad.data(), quad.size());
  if (quad_area < 0) std::swap(quad[1], quad[3]);  // clockwise on screen (y down)
  quad_area = std::abs(quad_area) / 2;
  return true;
}

double Frame8Detector::quad_perimeter(const std::array<Point2, 4>& quad) {
  double perimeter = 0;
  for (std::size_t i = 0; i < 4; ++i) perimeter += distance(quad[i], quad[(i + 1) % 4]);
  return perimeter;
}

// Largest-area quadrilateral on the vertices of a convex polygon (hull_),
// by rotating the two free vertices monotonically for each diagonal.
bool Frame8Detector::max_area_quad(std::array<Point2, 4>& quad) {
  const int n = static_cast<int>(hull_.size());
  if (n < 4) return false;
  // Indices run up to 2n - 1: the hull twice over instead of i % n, whose
  // division would cost more than the cross products of this O(n^2) walk.
  hull_twice_.assign(hull_.begin(), hull_.end());
  hull_twice_.insert(hull_twice_.end(), hull_.begin(), hull_.end());
  auto at = [&](int i) { return hull_twice_[static_cast<std::size_t>(i)]; };
  double best = 0;
  for (int i = 0; i < n; ++i) {
    int k = i + 1;
    int l = i + 3;
    for (int j = i + 2; j < i + n - 1; ++j) {
      // Each triangle's area carried along as its apex walks on.
      if (k >= j) k = j - 1;
      double area_k = std::abs(cross(at(i), at(k), at(j)));
      for (; k + 1 < j; ++k) {
        const double next = std::abs(cross(at(i), at(k + 1), at(j)));
        if (next < area_k) break;
        area_k = next;
      }
      if (l <= j) l = j + 1;
      double area_l = std::abs(cross(at(j), at(l), at(i)));
      for (; l + 1 < i + n; ++l) {
        const double next = std::abs(cross(at(j), at(l + 1), at(i)));
        if (next < area_l) break;
        area_l = next;
      }
      const double area = area_k + area_l;
      if (area > best) {
        best = area;
        quad = {at(i), at(k), at(j), at(l)};
      }
    }
  }
  return best > 0;
}

void Frame8Detector::convex_hull() {
  const int n = static_cast<int>(points_.size());
  hull_.resize(static_cast<std::size_t>(2 * n));
  int k = 0;
  // Points are sorted by (y, x); build both chains.
  for (int i = 0; i < n; ++i) {
    while (k >= 2 && cross(hull_[static_cast<std::size_t>(k - 2)], hull_[static_cast<std::size_t>(k - 1)],
                           points_[static_cast<std::size_t>(i)]) <= 0) {
      --k;
    }
    hull_[static_cast<std::size_t>(k++)] = points_[static_cast<std::size_t>(i)];
  }
  for (int i = n - 2, t = k + 1; i >= 0; --i) {
    while (k >= t && cross(hull_[static_cast<std::size_t>(k - 2)], hull_[static_cast<std::size_t>(k - 1)],
                           points_[static_cast<std::size_t>(i)]) <= 0) {
      --k;
    }
    hull_[static_cast<std::size_t>(k++)] = points_[static_cast<std::size_t>(i)];
  }
  hull_.resize(static_cast<std::size_t>(std::max(0, k - 1)));
}

}  // namespace markerd::detector::frame8
