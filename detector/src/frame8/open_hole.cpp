// Stage 2b, a hole open on one side: candidates for markers whose hole has
// no component of its own. An object in front of one side, as light as the
// hole (a hand, a white cable cover, the paper of a neighbouring print),
// hides that side's ring and line: the hole's light pixels run on into the
// object's, and no quad is fitted (quad_fit.cpp). What is left of the hole
// is the line's three visible sides, a U of the component's outline whose
// inside is light. The outline of every component that is not a quad is
// traced, cut into straight pieces, and each such U handed to the read with
// its open side hidden (hidden_side.cpp).

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// How far a straight piece of an outline may stray from its chord, in
// working pixels: the staircase of a traced slant and a little noise.
constexpr double kStraightTolerance = 1.5;
// The U's arms: how much of the hole the cover leaves (a cover up to the
// depth read_hidden_side tries leaves 4.5 of the 7 cells), as a share of
// the full side between them, with a marker turned up to about 60 degrees
// either way, which shortens one or the other.
constexpr double kMinArm = 0.3;
constexpr double kMaxArm = 2.5;
// Pieces shorter than this share of the full side, between the arms and
// the full side, are the corners' rounding or blur.
constexpr double kCornerPiece = 0.2;
// The hole's corners are turns of 30 to 150 degrees (the sine of the turn);
// the arms, a square's opposite sides, converge by less than 40 degrees.
constexpr double kMinTurnSine = 0.5;
constexpr double kMinArmsCosine = 0.75;

Line line_through(Point2 a, Point2 b) {
  const double len = distance(a, b);
  Line l;
  l.nx = -(b.y - a.y) / len;
  l.ny = (b.x - a.x) / len;
  l.c = l.nx * a.x + l.ny * a.y;
  return l;
}

Point2 project(const Line& l, Point2 p) {
  const double off = l.nx * p.x + l.ny * p.y - l.c;
  return {p.x - off * l.nx, p.y - off * l.ny};
}

}  // namespace

// The outline through the left end of run `start`, as the pixel corners
// where it turns (pixel-centre coordinates of the working image), the
// component on its right: clockwise on screen around the component,
// anticlockwise around a dark island within it. The component is
// 4-connected, so a pixel touching it only by a corner is outside it; and
// every light pixel the walk looks at is a side neighbour of one of the
// component's, so its light bit alone says whether it belongs. Marks the
// left end of every run it passes, so that each outline is traced once.
void Frame8Detector::trace_outline(std::int32_t start) {
  outline_.clear();
  // Directions: east, south, west, north (y down); a right turn adds one.
  // Per direction, the step, and the two pixels ahead of the corner
  // reached, left and right of the heading, relative to it.
  constexpr std::array<int, 4> kDx{1, 0, -1, 0}, kDy{0, 1, 0, -1};
  constexpr std::array<int, 4> kLeftX{0, 0, -1, -1}, kLeftY{-1, 0, 0, -1};
  constexpr std::array<int, 4> kRightX{0, -1, -1, 0}, kRightY{0, 0, -1, -1};
  const Run& s = runs_[static_cast<std::size_t>(start)];
  const int sx = s.x0, sy = s.y + 1, sd = 3;  // up the run's left end
  int x = sx, y = sy, d = sd;
  int x0 = x, x1 = x, y0 = y, y1 = y;
  do {
    const auto du = static_cast<std::size_t>(d);
    if (d == 3) {
      // The crack from (x, y) up to (x, y - 1) is the left end of a run on row y - 1.
      outline_traced_[light_stride_ * static_cast<std::size_t>(y - 1) + static_cast<std::size_t>(x >> 6)] |=
          std::uint64_t{1} << (x & 63);
    }
    x += kDx[du];
    y += kDy[du];
    int turn = 0;
    if (!light_at(x + kRightX[du], y + kRightY[du])) {
      turn = 1;
    } else if (light_at(x + kLeftX[du], y + kLeftY[du])) {
      turn = 3;
    }
    if (turn != 0) {
      outline_.push_back({x - 0.5, y - 0.5});
      x0 = std::min(x0, x);
      x1 = std::max(x1, x);
      y0 = std::min(y0, y);
      y1 = std::max(y1, y);
      d = (d + turn) & 3;
    }
  } while (x != sx || y != sy || d != sd);
  outline_extent_ = std::max(x1 - x0, y1 - y0);
}

// The outline's corners (indices into outline_, in order): its straight
// pieces, each grown from the end of the last as long as one line through
// its ends passes every point between within kStraightTolerance (the
// directions that do form a cone from the piece's start, narrowed at each
// point). One pass, linear in the outline: the outlines of a cluttered
// frame run to thousands of pixels. The first piece starts anywhere, so
// the pieces are taken from its end round to it again.
void Frame8Detector::simplify_outline() {
  outline_corners_.clear();
  const auto n = static_cast<std::int32_t>(outline_.size());
  if (n < 4) return;
  auto at = [&](std::int32_t i) { return outline_[static_cast<std::size_t>(i % n)]; };
  // The last index a straight piece from `from` reaches (at most from + n).
  auto piece_end = [&](std::int32_t from) {
    const Point2 o = at(from);
    Point2 lo{}, hi{};  // the cone's edges, as directions
    bool open = false;
    std::int32_t end = from + 1;
    for (std::int32_t i = from + 1; i <= from + n; ++i) {
      const Point2 v = at(i) - o;
      const double r2 = v.x * v.x + v.y * v.y;
      constexpr double kTol2 = kStraightTolerance * kStraightTolerance;
      if (r2 <= kTol2) {
        end = i;
        continue;
      }
      if (open && (lo.x * v.y - lo.y * v.x < 0 || v.x * hi.y - v.y * hi.x < 0)) break;
      end = i;
      // The directions within the tolerance of this point: v turned by
      // +-asin(tol / r).
      const double s = kStraightTolerance / std::sqrt(r2), c = std::sqrt(1 - s * s);
      const Point2 vlo{c * v.x + s * v.y, -s * v.x + c * v.y}, vhi{c * v.x - s * v.y, s * v.x + c * v.y};
      if (!open) {
        lo = vlo;
        hi = vhi;
        open = true;
        continue;
      }
      if (lo.x * vlo.y - lo.y * vlo.x > 0) lo = vlo;
      if (vhi.x * hi.y - vhi.y * hi.x > 0) hi = vhi;
      if (lo.x * hi.y - lo.y * hi.x < 0) break;
    }
    return end;
  };
  const std::int32_t first = piece_end(0) % n;
  for (std::int32_t i = first; i < first + n;) {
    outline_corners_.push_back(i % n);
    i = piece_end(i);
  }
}

// Whether the ring beyond a full side of the hole, from corner `a` to `b`
// (working image, clockwise), shows black and white cells: every id but 0
// and 255 has both among each edge's eight data cells, one cell out from
// the hole. Clutter's U shapes mostly have neither, and this costs nine
// samples against up to a dozen reads. The samples are grey levels: the
// threshold takes a small white cell's inner pixels, next to the line, for
// dark. Half a pixel further out, as the outline lies a little inside the
// hole's edge.
bool Frame8Detector::ring_shows_both_colours(Point2 a, Point2 b) const {
  const double d = decimate_;
  a = {a.x * d + (d - 1) / 2, a.y * d + (d - 1) / 2};
  b = {b.x * d + (d - 1) / 2, b.y * d + (d - 1) / 2};
  const Point2 along = b - a;
  const double len = std::hypot(along.x, along.y);
  const Point2 out = ((len / kInnerSide + 0.5) / len) * Point2{along.y, -along.x};
  float hole = 0;
  if (!sample(full_, a.x + 0.5 * along.x - 0.5 * out.x, a.y + 0.5 * along.y - 0.5 * out.y, hole)) return false;
  float lo = 255, hi = 0;
  for (int k = 0; k < 8; ++k) {
    const Point2 p = a + (static_cast<double>(k) / kInnerSide) * along + out;
    float v = 0;
    if (!sample(full_, p.x, p.y, v)) return false;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  // White cells come up to the hole's level, black ones well below it.
  constexpr float kMinContrast = 30;
  return hole - lo >= kMinContrast && hi - lo >= 0.5F * (hole - lo);
}

void Frame8Detector::consider_open_holes(std::int32_t root, std::vector<Detection>& out) {
  const Component& c = components_[static_cast<std::size_t>(root)];
  const double d = decimate_;
  // A hole read with a side hidden needs cells of kResolvedCells.
  const double min_side = kResolvedCells * kInnerSide / d;
  if (std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) < min_side) return;
  for (std::int32_t r = c.first; r >= 0; r = runs_[static_cast<std::size_t>(r)].next) {
    const Run& run = runs_[static_cast<std::size_t>(r)];
    if ((outline_traced_[light_stride_ * static_cast<std::size_t>(run.y) + static_cast<std::size_t>(run.x0 >> 6)] >>
         (run.x0 & 63)) &
        1U) {
      continue;
    }
    trace_outline(r);
    if (outline_extent_ < min_side) continue;
    simplify_outline();
    const auto m = static_cast<std::int32_t>(outline_corners_.size());
    if (m < 3) continue;
    auto corner = [&](std::int32_t k) {
      return outline_[static_cast<std::size_t>(outline_corners_[static_cast<std::size_t>(((k % m) + m) % m)])];
    };
    auto piece = [&](std::int32_t k) { return distance(corner(k), corner(k + 1)); };
    for (std::int32_t j = 0; j < m; ++j) {
      const double side = piece(j);
      if (side < min_side) continue;
      // The arms: the nearest pieces before and after that are not a corner's rounding.
      std::int32_t a = j - 1, b = j + 1;
      double rounding = 0;
      while (a > j - m && piece(a) < kCornerPiece * side) rounding += piece(a--);
      while (b < j + m && piece(b) < kCornerPiece * side) rounding += piece(b++);
      if (rounding > kCornerPiece * side || a <= j - m || b >= j + m || (a + m) % m == (b % m)) continue;
      const Point2 a0 = corner(a), a1 = corner(a + 1), s0 = corner(j), s1 = corner(j + 1), b0 = corner(b),
                   b1 = corner(b + 1);
      // Both turns to the right: the component is inside the U.
      const Point2 da = a1 - a0, ds = s1 - s0, db = b1 - b0;
      const double la = std::hypot(da.x, da.y), lb = std::hypot(db.x, db.y);
      if ((da.x * ds.y - da.y * ds.x) / (la * side) < kMinTurnSine) continue;
      if ((ds.x * db.y - ds.y * db.x) / (side * lb) < kMinTurnSine) continue;
      if (-(da.x * db.x + da.y * db.y) / (la * lb) < kMinArmsCosine) continue;
      const Line arm_a = line_through(a0, a1), full = line_through(s0, s1), arm_b = line_through(b0, b1);
      Point2 v1, v2;
      if (!intersect(arm_a, full, v1) || !intersect(full, arm_b, v2)) continue;
      const Point2 end_a = project(arm_a, a0), end_b = project(arm_b, b1);
      const double reach_a = distance(v1, end_a), reach_b = distance(v2, end_b), width = distance(v1, v2);
      if (std::min(reach_a, reach_b) < kMinArm * width || std::max(reach_a, reach_b) > kMaxArm * width) continue;
      if (!ring_shows_both_colours(v1, v2)) continue;
      // The part of the hole seen: across the arms, parallel to the full
      // side, where the shorter arm ends.
      Point2 p0 = end_a, p3 = end_b;
      const Line across_a = line_through(end_a, end_a + ds), across_b = line_through(end_b, end_b + ds);
      if (reach_a <= reach_b ? !intersect(across_a, arm_b, p3) : !intersect(across_b, arm_a, p0)) continue;
      std::array<Point2, 4> seen{p0, v1, v2, p3};
      for (auto& p : seen) p = {p.x * d + (d - 1) / 2, p.y * d + (d - 1) / 2};
      // The ring lies 1.5 cells beyond the hole's corners: where that is
      // off the image (the image's own border makes straight outlines and
      // right angles), there is nothing to read.
      const double ring = kInnerLo * distance(seen[1], seen[2]) / kInnerSide;
      auto in_image = [&](Point2 p) {
        return p.x >= ring && p.y >= ring && p.x <= full_.width - 1 - ring && p.y <= full_.height - 1 - ring;
      };
      if (!in_image(seen[1]) || !in_image(seen[2])) continue;
      const Point2 centre = 0.25 * (seen[0] + seen[1] + seen[2] + seen[3]);
      if (std::any_of(out.begin(), out.end(), [&](const Detection& f) { return inside(f.corners, centre); })) continue;
      if (debug_) debug_candidates_.push_back({seen, Rejection::open_hole_unread, -1, {}, {}});
      Detection det;
      if (read_open_hole(seen, det) == Rejection::none) {
        if (debug_) {
          debug_candidates_.back().why = Rejection::none;
          debug_candidates_.back().id = det.id;
          debug_candidates_.back().first_corner = det.corners[0];
        }
        out.push_back(det);
      }
    }
  }
}

// The U's three sides measured at full resolution as any quad's (stage 3),
// the open side (3) left where the shorter arm ends, then read with that
// side hidden to each depth.
Rejection Frame8Detector::read_open_hole(const std::array<Point2, 4>& coarse, Detection& det) {
  std::array<Line, 3> lines{};
  const double cell_px = distance(coarse[1], coarse[2]) / kInnerSide;
  for (int side = 0; side < 3; ++side) {
    auto& n = edge_count_[static_cast<std::size_t>(side)];
    n = collect_edge_points(coarse, side, EdgeMode::step, std::nullopt);
    if (n < 3) return Rejection::few_edge_points;
    if (!fit_line(edge_points_[static_cast<std::size_t>(side)].data(), n, std::max(0.6, 0.25 * cell_px),
                  lines[static_cast<std::size_t>(side)])) {
      return Rejection::no_edge_line;
    }
  }
  Point2 v1, v2;
  if (!intersect(lines[0], lines[1], v1) || !intersect(lines[1], lines[2], v2)) return Rejection::parallel_sides;
  if (distance(v1, coarse[1]) > 2.0 * cell_px + 2 * decimate_ ||
      distance(v2, coarse[2]) > 2.0 * cell_px + 2 * decimate_) {
    return Rejection::corner_moved;
  }
  const Point2 end_a = project(lines[0], coarse[0]), end_b = project(lines[2], coarse[3]);
  Point2 p0 = end_a, p3 = end_b;
  const Point2 ds = v2 - v1;
  if (distance(v1, end_a) <= distance(v2, end_b) ? !intersect(line_through(end_a, end_a + ds), lines[2], p3)
                                                 : !intersect(line_through(end_b, end_b + ds), lines[0], p0)) {
    return Rejection::parallel_sides;
  }
  const std::array<Point2, 4> seen{p0, v1, v2, p3};
  if (!convex(seen)) return Rejection::corners_not_convex;
  int rotation = 0;
  HiddenSide hidden;
  Homography H;
  if (!read_hidden_side(seen, 3, HoleEnd::open, det, rotation, hidden, H)) return Rejection::open_hole_unread;
  return finish_from_hole(H, hidden, rotation, cell_px, det);
}

}  // namespace markerd::detector::frame8
