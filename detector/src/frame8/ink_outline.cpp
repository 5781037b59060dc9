// Stage 2c, a hole no lighter than the line: candidates for markers whose
// hole shows something as dark as the ink, or darker, or parted by
// clutter's edges. A hole cut out of the print (as on any socket frame)
// shows the wall or whatever stands behind it; where that is dark the
// line has no inner edge, the hole's light pixels (where there are any)
// leak out through the black ring cells beside it, and no quad is fitted.
// What stays is the ink's outside: the ring's black cells and the line are
// one dark island in the light paper or plastic around the marker (the
// print's margin, the frame's plastic, a light wall), its outline the
// outer square where the cells are black and the line's outer edge where
// they are white. C0, C2 and C3 are black, so three of the square's
// corners are the island's own and every side has a stretch on it: the
// island's convex hull is the outer square with C1's corner cut off, and
// its four longest sides, extended, give the square.
//
// The ring is read on that square as any quad's (stage 4), only where its
// cells are resolved and with no bit outvoted, and the corners come from
// the pattern's edges that do not need the hole (stage 5): the boundaries
// between ring cells and the line's outer edge beside white cells. That
// measured map must read the same code again.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <utility>
#include <vector>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// A hull vertex this near (traced pixels) the line of the side so far
// extends it: a traced slant's hull steps by a pixel. The cut at C1 may
// turn off the side by only a few degrees (one cell in over eight along,
// id 127), but it leaves the line by a cell.
constexpr double kSideStraightness = 1.5;
// Where perspective takes the square's corners: a marker turned 70 degrees
// and seen off the axis keeps them within 30 to 150 degrees.
constexpr double kMinCornerSine = 0.5;
// Cells (pixels across) the ink's square is read down to: under 3 px its
// cells are unmixed as any quad's (decode_cells.cpp), and the read is
// checked as theirs.
constexpr double kMinInkCells = 2.0;
// A side's stretch on the square under this many cells is turned by the
// side opposite (read_ink_outline).
constexpr double kShortStretchCells = 3;
// Two stretches of the hull measure as one side when their lines are this
// near: in direction (sine), and each stretch's ends from the other's line
// (cells; at least 0.6 px).
constexpr double kSameLineSine = 0.05;
constexpr double kSameLineCells = 0.15;

// The hull with C1's corner cut off fills the square but for that corner:
// half a cell squared where C1's neighbours are black, more where they are
// white (down to about 0.85 for ids with long white runs beside C1).
constexpr double kMinHullShare = 0.8;

}  // namespace

void Frame8Detector::find_marker_on_ink_outline(int scale, std::vector<Detection>& out) {
  points_.assign(outline_.begin(), outline_.end());
  std::sort(points_.begin(), points_.end(), [](Point2 p, Point2 q) { return p.y < q.y || (p.y == q.y && p.x < q.x); });
  convex_hull();
  const auto n = static_cast<int>(hull_.size());
  if (n < 4) return;
  if (twice_signed_area(hull_.data(), hull_.size()) < 0) std::reverse(hull_.begin(), hull_.end());
  const double hull_area = twice_signed_area(hull_.data(), hull_.size()) / 2;
  auto at = [&](int i) { return hull_[static_cast<std::size_t>(((i % n) + n) % n)]; };
  auto turn_sine = [](Point2 d1, Point2 d2) {
    return (d1.x * d2.y - d1.y * d2.x) / (std::hypot(d1.x, d1.y) * std::hypot(d2.x, d2.y));
  };
  // Start at the hull's sharpest turn, so that no side wraps round the start.
  int start = 0;
  double sharpest = -1;
  for (int i = 0; i < n; ++i) {
    const double t = std::abs(turn_sine(at(i) - at(i - 1), at(i + 1) - at(i)));
    if (t > sharpest) {
      sharpest = t;
      start = i;
    }
  }
  // The hull's sides: consecutive edges that keep the direction of the
  // side so far (its chord, once it is longer than the staircase).
  std::array<HullSide, 16> sides{};
  int count = 0;
  for (int i = start; i < start + n && count < static_cast<int>(sides.size());) {
    const Point2 a = at(i);
    int j = i + 1;
    const double straightness = kSideStraightness * scale;
    // Every vertex passed must stay near the chord to the next: measured
    // against the last chord only, a shallow cut at C1 and the short
    // stretch after it drift into one side a vertex at a time.
    auto straight_to = [&](int end) {
      const Point2 b = at(end);
      const double chord = distance(a, b);
      if (chord <= straightness) return true;
      for (int k = i + 1; k < end; ++k) {
        if (std::abs(cross(a, b, at(k))) > straightness * chord) return false;
      }
      return true;
    };
    while (j < start + n && straight_to(j + 1)) ++j;
    sides[static_cast<std::size_t>(count++)] = {a, at(j), distance(a, at(j))};
    i = j;
  }
  if (count < 4) return;
  // In full-resolution pixels from here.
  for (int k = 0; k < count; ++k) {
    HullSide& side = sides[static_cast<std::size_t>(k)];
    side.a = to_full(side.a);
    side.b = to_full(side.b);
    side.length *= decimate_;
  }
  const double area_full = hull_area * decimate_ * decimate_;
  std::array<Line, 16> lines{};
  for (int k = 0; k < count; ++k) {
    const HullSide& side = sides[static_cast<std::size_t>(k)];
    lines[static_cast<std::size_t>(k)] = line_through(side.a, side.b);
  }
  // The step's sense per side: +1 ink to light outwards (the print's
  // margin, a frame's plastic), -1 light to dark (white cells against a
  // dark ground round a bare print), 0 not measured.
  std::array<int, 16> sense{};
  std::array<InkSquare, kTried> tries{};
  const std::size_t traced = pick_squares(sides.data(), lines.data(), sense.data(), count, area_full, tries);
  // Most islands are clutter's dark shapes, dark all over where a ring
  // would be: a look at its cells costs less than measuring the sides.
  if (std::none_of(tries.begin(), tries.begin() + static_cast<std::ptrdiff_t>(traced), [&](const InkSquare& square) {
        Homography to_outer;
        return Homography::from_unit_square(square.corners, to_outer) && ring_shows_cells(outer_grid_map(to_outer));
      })) {
    return;
  }
  // Each side measured where the ink meets the light, along its stretch
  // of the hull: black cells there (beside a white cell the step within
  // reach may be the line's, a cell in). Neighbouring stretches that the
  // threshold's rims bent apart by a pixel or two (cells of 4 px) measure
  // as one line, and are one side.
  const double cell = std::sqrt(area_full) / frame8::grid;
  int merged = 0;
  for (int k = 0; k < count; ++k) {
    HullSide side = sides[static_cast<std::size_t>(k)];
    Line line = lines[static_cast<std::size_t>(k)];
    const int side_sense = fit_outer_side(side.a, side.b, cell, {1, -1}, line);
    if (merged > 0 && side_sense != 0 && sense[static_cast<std::size_t>(merged - 1)] == side_sense) {
      HullSide& last = sides[static_cast<std::size_t>(merged - 1)];
      const Line& last_line = lines[static_cast<std::size_t>(merged - 1)];
      auto off = [](const Line& l, Point2 p) { return std::abs(l.nx * p.x + l.ny * p.y - l.c); };
      const double reach = std::max(0.6, kSameLineCells * cell);
      if (std::abs(line.nx * last_line.ny - line.ny * last_line.nx) < kSameLineSine && off(last_line, side.a) < reach &&
          off(last_line, side.b) < reach && off(line, last.a) < reach && off(line, last.b) < reach) {
        const HullSide joined{last.a, side.b, last.length + side.length};
        Line joined_line = last_line;
        if (fit_outer_side(joined.a, joined.b, cell, {side_sense}, joined_line) != 0) {
          last = joined;
          lines[static_cast<std::size_t>(merged - 1)] = joined_line;
          continue;
        }
      }
    }
    sides[static_cast<std::size_t>(merged)] = side;
    lines[static_cast<std::size_t>(merged)] = line;
    sense[static_cast<std::size_t>(merged)] = side_sense;
    ++merged;
  }
  const std::size_t found = pick_squares(sides.data(), lines.data(), sense.data(), merged, area_full, tries);
  for (std::size_t k = 0; k < found; ++k) {
    const InkSquare& square = tries[k];
    const std::array<Point2, 4>& outer = square.corners;
    if (distance(outer[0], outer[2]) + distance(outer[1], outer[3]) <
        2 * std::sqrt(2.0) * kMinInkCells * frame8::grid) {
      return;
    }
    if (!std::all_of(outer.begin(), outer.end(), [&](Point2 p) { return in_image(full_, p); })) return;
    const Point2 centre = centre_of(outer);
    if (inside_any(out, centre)) return;
    if (debug_) debug_candidates_.push_back({outer, Rejection::ink_outline_unread, -1, {}, {}});
    Detection det;
    const Rejection why = read_ink_outline(square, det);
    note_outcome(why, det);
    if (why == Rejection::none) {
      out.push_back(det);
      return;
    }
  }
}

// Four sides in the hull's order whose lines make a convex quad with
// corners of a square in perspective, which the hull fills. The longest
// such four are the square's sides but where C1's cut is long and shallow
// (a white run beside it): the cut's line then makes as good a quad with
// the three sides beside it. The reads decide, the longest first.
std::size_t Frame8Detector::pick_squares(const HullSide* sides, const Line* lines, const int* sense, int count,
                                         double hull_area, std::array<InkSquare, kTried>& tries) {
  auto turn_sine = [](Point2 d1, Point2 d2) {
    return (d1.x * d2.y - d1.y * d2.x) / (std::hypot(d1.x, d1.y) * std::hypot(d2.x, d2.y));
  };
  std::size_t found = 0;
  std::array<int, 4> pick{};
  for (pick[0] = 0; pick[0] < count; ++pick[0]) {
    for (pick[1] = pick[0] + 1; pick[1] < count; ++pick[1]) {
      for (pick[2] = pick[1] + 1; pick[2] < count; ++pick[2]) {
        for (pick[3] = pick[2] + 1; pick[3] < count; ++pick[3]) {
          double total = 0;
          for (const int k : pick) total += sides[k].length;
          if (found == kTried && total <= tries[kTried - 1].total) continue;
          std::array<Point2, 4> q{};
          bool ok = true;
          for (int t = 0; t < 4 && ok; ++t) {
            const int k1 = pick[static_cast<std::size_t>(t)], k2 = pick[static_cast<std::size_t>((t + 1) % 4)];
            ok = turn_sine(sides[k1].b - sides[k1].a, sides[k2].b - sides[k2].a) >= kMinCornerSine &&
                 intersect(lines[k1], lines[k2], q[static_cast<std::size_t>((t + 1) % 4)]);
          }
          if (!ok || !convex(q)) continue;
          const double area = twice_signed_area(q.data(), q.size()) / 2;
          if (area <= 0 || hull_area < kMinHullShare * area) continue;
          // Into the list, longest first. Side t runs from corner t to t + 1.
          std::size_t at = std::min(found, kTried - 1);
          tries[at].total = total;
          tries[at].corners = q;
          int dark_sides = 0;
          for (int t = 0; t < 4; ++t) {
            const int k = pick[static_cast<std::size_t>(t)];
            tries[at].sides[static_cast<std::size_t>(t)] = sides[k];
            tries[at].lines[static_cast<std::size_t>(t)] = lines[k];
            dark_sides += sense[k] < 0;
          }
          tries[at].dark_ground = dark_sides >= 2;
          for (; at > 0 && tries[at - 1].total < tries[at].total; --at) std::swap(tries[at - 1], tries[at]);
          found = std::min(found + 1, kTried);
        }
      }
    }
  }
  return found;
}

// The outer square's side through a and b (clockwise, full-resolution
// pixels) where the ink meets the light beyond it: at each point the steepest
// step going outward in the sense of each of `signs` in turn (+1 dark to
// light, -1 light to dark), within about half a cell of the side traced (the
// line's outer edge, a cell in, stays out of reach). Beside white cells
// there is no step: those points drop out. Returns the sense whose points
// gave `line`, 0 for none. The profiles are sampled once for every sense.
int Frame8Detector::fit_outer_side(Point2 a, Point2 b, double cell_px, std::initializer_list<int> signs, Line& line) {
  const double len = distance(a, b);
  const double dx = (b.x - a.x) / len, dy = (b.y - a.y) / len;
  const double nx = dy, ny = -dx;  // outward for a clockwise quad with y down
  const int count = std::clamp(static_cast<int>(len / 1.5), 8, kMaxEdgePoints);
  constexpr double step = 0.5;
  // The hull lies on the ink's outside or a pixel beyond: inward, the
  // search stops short of the line's outer edge (a cell in, beside a
  // white cell).
  const double reach = 0.4 * cell_px + 1.0, reach_out = 0.6 * cell_px + 1.0;
  const int n_steps = std::min(static_cast<int>((reach + reach_out) / step) + 1, kMaxProfileSteps);
  std::array<Point2, kMaxEdgePoints> base{};
  int sampled = 0;
  for (int k = 0; k < count; ++k) {
    // Clear of the stretch's ends, which the blur rounds (a corner of the
    // square, or the end of a black run).
    const double t = 0.1 + 0.8 * (k + 0.5) / count;
    const double px = a.x + t * (b.x - a.x), py = a.y + t * (b.y - a.y);
    if (sample_profile(full_, {px, py}, {nx, ny}, -reach, step, n_steps,
                       outer_profiles_[static_cast<std::size_t>(sampled)].data())) {
      base[static_cast<std::size_t>(sampled++)] = {px, py};
    }
  }
  EdgePoint* pts = edge_points_[0].data();
  for (const int sign : signs) {
    int used = 0;
    for (int k = 0; k < sampled; ++k) {
      const std::array<float, kMaxProfileSteps>& profile = outer_profiles_[static_cast<std::size_t>(k)];
      auto rise = [&](int s) {
        return static_cast<double>(static_cast<float>(sign) *
                                   (profile[static_cast<std::size_t>(s + 1)] - profile[static_cast<std::size_t>(s)]));
      };
      int best = -1;
      double best_rise = 0;
      for (int s = 0; s + 1 < n_steps; ++s) {
        if (rise(s) > best_rise) {
          best_rise = rise(s);
          best = s;
        }
      }
      // Noise of a few grey levels makes steps of a few grey levels a half pixel.
      constexpr double kMinRise = 8;
      // A rise at the window's inner end is the start of the line's step
      // beside a white cell, not the ink's outside.
      if (best <= 0 || best_rise < kMinRise) continue;
      int lo = best, hi = best;
      while (lo > 0 && rise(lo - 1) > 0.05 * best_rise) --lo;
      while (hi + 2 < n_steps && rise(hi + 1) > 0.05 * best_rise) ++hi;
      double sum = 0, moment = 0;
      for (int s = lo; s <= hi; ++s) {
        sum += rise(s);
        moment += rise(s) * (-reach + (s + 0.5) * step);
      }
      const double off = moment / sum;
      const Point2 p = base[static_cast<std::size_t>(k)];
      pts[used++] = {p.x + off * nx, p.y + off * ny, best_rise};
    }
    if (used >= 4 && fit_line(pts, used, std::max(0.6, 0.2 * cell_px), line)) return sign;
  }
  return 0;
}

// The ring read on the outer square found (full-resolution pixels), then
// measured by the pattern's edges clear of the hole and read again there.
Rejection Frame8Detector::read_ink_outline(const InkSquare& square, Detection& det) {
  std::array<Line, 4> lines = square.lines;
  const std::array<Point2, 4>& traced = square.corners;
  const std::array<HullSide, 4>& flush = square.sides;
  const Rejection measured = read_outer_square(traced, lines, square.dark_ground, det);
  if (measured == Rejection::none) return measured;
  // A stretch of a cell or two (C2 or C0 and one black cell beside it,
  // the rest of the side white) places its side but turns it only
  // roughly: a degree off moves the far corner, C1's, by a pixel a cell.
  // Turned as the side opposite instead (parallel to it but for the
  // perspective, a few degrees near and turned), where that side's stretch
  // is longer, it may read.
  bool turned = false;
  for (int side = 0; side < 4; ++side) {
    const HullSide& on = flush[static_cast<std::size_t>(side)];
    const HullSide& facing = flush[static_cast<std::size_t>((side + 2) % 4)];
    const double cell =
        distance(traced[static_cast<std::size_t>(side)], traced[static_cast<std::size_t>((side + 1) % 4)]) /
        frame8::grid;
    if (on.length >= kShortStretchCells * cell || facing.length <= on.length) continue;
    Line& l = lines[static_cast<std::size_t>(side)];
    const Line& f = lines[static_cast<std::size_t>((side + 2) % 4)];
    const Point2 mid = 0.5 * (on.a + on.b);
    const double off = l.nx * mid.x + l.ny * mid.y - l.c;
    const Point2 through{mid.x - off * l.nx, mid.y - off * l.ny};
    l = {-f.nx, -f.ny, -f.nx * through.x - f.ny * through.y};
    turned = true;
  }
  if (!turned) return measured;
  return read_outer_square(traced, lines, square.dark_ground, det);
}

Rejection Frame8Detector::read_outer_square(const std::array<Point2, 4>& traced, const std::array<Line, 4>& lines,
                                            bool dark_ground, Detection& det) {
  std::array<Point2, 4> outer{};
  for (int side = 0; side < 4; ++side) {
    Point2& p = outer[static_cast<std::size_t>(side)];
    if (!intersect(lines[static_cast<std::size_t>((side + 3) % 4)], lines[static_cast<std::size_t>(side)], p)) {
      return Rejection::parallel_sides;
    }
    // A square cut by the image's border (a key of a keyboard there read
    // as 126) is not read.
    if (!in_image(full_, p)) return Rejection::corner_off_image;
    if (corner_moved(outer[static_cast<std::size_t>(side)], traced[static_cast<std::size_t>(side)],
                     distance(traced[0], traced[2]) / (std::sqrt(2.0) * frame8::grid))) {
      return Rejection::corner_moved;
    }
  }
  if (!convex(outer)) return Rejection::corners_not_convex;
  Homography to_outer;
  if (!Homography::from_unit_square(outer, to_outer)) return Rejection::degenerate_quad;
  constexpr double lo = kInnerLo / frame8::grid, hi = 1 - lo;
  const std::array<Point2, 4> inner{to_outer.map(lo, lo), to_outer.map(hi, lo), to_outer.map(hi, hi),
                                    to_outer.map(lo, hi)};
  Homography H;
  if (!Homography::from_unit_square(inner, H)) return Rejection::degenerate_quad;
  const CellSize cell_size = cell_size_of(inner);
  if (cell_size.narrow < kMinInkCells) return Rejection::ink_cells_unresolved;
  int rotation = 0;
  if (const Rejection why = decode(H, cell_size, det, rotation, nullptr); why != Rejection::none) return why;
  if (det.bits_corrected > 0) return Rejection::ink_read_corrected;
  // Under resolved cells the checks of any quad's read (detector.cpp): a
  // near-uniform ring only where cells are resolved, and under 2.5 px the
  // ring model, fitted to every pixel, must read the same.
  if (near_uniform(det.id) && cell_size.narrow < kResolvedCells) return Rejection::near_uniform_unconfirmed;
  // White cells alone on a dark ground, with no light round the ink, are
  // what a grid of light keys or tiles shows too, around each of its
  // squares: one colour from end to end but for the corners.
  if (near_uniform(det.id) && dark_ground) return Rejection::near_uniform_unconfirmed;
  if (cell_size.mean < kModelCheckedCells) {
    if (const Rejection why = confirm_by_model(H, cell_size, det, rotation); why != Rejection::none) return why;
  }
  if (collect_pattern_edges(H, det.id, rotation, cell_size.mean, {}, HoleEdge::unknown) < kMinPatternEdges) {
    return Rejection::pattern_fit_failed;
  }
  Detection measured = det;
  if (const Rejection why = finish_by_pattern(rotation, measured); why != Rejection::none) return why;
  if (!measured.inner_corners) return Rejection::pattern_fit_failed;
  // The hole as the pattern places it, in the quad's order, read again.
  std::array<Point2, 4> hole{};
  for (int j = 0; j < 4; ++j) {
    hole[static_cast<std::size_t>((j + rotation) % 4)] = (*measured.inner_corners)[static_cast<std::size_t>(j)];
  }
  Homography again_H;
  if (!Homography::from_unit_square(hole, again_H)) return Rejection::degenerate_quad;
  Detection again;
  int again_rotation = 0;
  const Rejection again_read = decode(again_H, cell_size_of(hole), again, again_rotation, nullptr);
  note_attempt(Read::second_pass, again_read);
  if (again_read != Rejection::none || again.id != det.id || again_rotation != rotation || again.bits_corrected > 0) {
    return Rejection::second_pass_disagrees;
  }
  det = measured;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
