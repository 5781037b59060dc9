// Stage 2d, a hole parted by what it shows: a socket outlet's recess takes
// 39 mm of the 56 mm opening, and where it comes within a pixel or two of
// the line (the marker turned, or far, and blurred) the threshold joins
// the two: the hole's light pixels are then pieces above and below the
// recess, or beside it, none a quad of its own (or a quad whose refined
// sides and cells are a piece's, not the hole's). After the quads, pairs
// of such pieces lying one above the other or side by side are taken as
// one component: the hull of both and its largest quad, read as any
// quad's (stages 3 to 6). No near-uniform id is read so, nor a read that
// outvoted a cell: two squares of a grid make such a pair too.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// The pieces' ends across the parting line up to this share of the span
// (a marker turned in its plane by up to about 15 degrees), and the
// pieces overlap along the parting by less than this share of the shorter
// one's extent.
constexpr double kEndsAlign = 0.25;
constexpr double kMaxOverlap = 0.5;
// What parts them takes at most this share of the hole along the
// parting: the recess is 0.7 of the opening, and the pieces beside it
// the rest.
constexpr double kMaxGap = 0.75;
// A piece beside a round recess is concave: a disc of 0.56 of the hole
// across or more (a Schuko outlet's is 0.7) leaves each piece filling at
// most 1 - pi/4 * 0.56^2 = 0.75 of its box, less where the threshold takes
// the recess's blurred rim too. Grid squares (window panes, tiles, keys)
// and most of clutter's shapes fill theirs.
constexpr double kMaxPieceFill = 0.75;

double box_fill(const Component& c) {
  return static_cast<double>(c.area) / (static_cast<double>(c.x1 - c.x0) * (c.y1 - c.y0 + 1));
}

// How far two components' ends fail to line up across the parting, as a
// share of their span (the lesser of one above the other and side by side);
// infinity where they are no pieces of one hole. The pieces span the hole
// across the parting (the two pieces above and below a recess each reach
// from the hole's left side to its right). Along it, each takes some of
// the hole and the recess the rest (their boxes overlap where it is round).
double pieces_mismatch(const Component& a, const Component& b, double min_side) {
  constexpr double kNone = std::numeric_limits<double>::infinity();
  const int x0 = std::min(a.x0, b.x0), x1 = std::max(a.x1, b.x1);
  const int y0 = std::min(a.y0, b.y0), y1 = std::max(a.y1, b.y1);
  if (std::min(x1 - x0, y1 - y0 + 1) < min_side) return kNone;
  // [a0, a1) and [b0, b1): the pieces across the parting; [c0, c1) and
  // [d0, d1): along it.
  auto mismatch = [&](int a0, int a1, int b0, int b1, int c0, int c1, int d0, int d1) {
    const double span = std::max(a1, b1) - std::min(a0, b0);
    const double ends = std::max(std::abs(a0 - b0), std::abs(a1 - b1)) / span;
    const int extent = std::max(c1, d1) - std::min(c0, d0);
    const int gap = std::max(c0, d0) - std::min(c1, d1);  // negative where they overlap
    const bool one_hole =
        ends <= kEndsAlign && gap <= kMaxGap * extent && -gap < kMaxOverlap * std::min(c1 - c0, d1 - d0);
    return one_hole ? ends : kNone;
  };
  return std::min(mismatch(a.x0, a.x1, b.x0, b.x1, a.y0, a.y1 + 1, b.y0, b.y1 + 1),
                  mismatch(a.y0, a.y1 + 1, b.y0, b.y1 + 1, a.x0, a.x1, b.x0, b.x1));
}

}  // namespace

void Frame8Detector::read_hole_fragments(std::vector<Detection>& out) {
  const double min_side = config_.frame8.min_hole_side_px / decimate_;
  pieces_.clear();
  for (const std::int32_t r : roots_) {
    const Component& c = components_[static_cast<std::size_t>(r)];
    if (c.read || c.touches_border) continue;
    if (std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) < 0.5 * min_side || box_fill(c) > kMaxPieceFill) continue;
    pieces_.push_back(r);
  }
  // Each piece is paired with the one whose ends line up best with its
  // own: the other piece of its hole, where it is one (clutter's pieces
  // would pair with every neighbour, and each pair costs a read).
  best_piece_.assign(pieces_.size(), {std::numeric_limits<double>::infinity(), 0});
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const Component& a = components_[static_cast<std::size_t>(pieces_[i])];
    for (std::size_t j = i + 1; j < pieces_.size(); ++j) {
      const double mismatch = pieces_mismatch(a, components_[static_cast<std::size_t>(pieces_[j])], min_side);
      if (mismatch < best_piece_[i].first) best_piece_[i] = {mismatch, j};
      if (mismatch < best_piece_[j].first) best_piece_[j] = {mismatch, i};
    }
  }
  for (std::size_t i = 0; i < pieces_.size(); ++i) {
    const std::size_t j = best_piece_[i].second;
    // Each pair once: a pair that is both pieces' best was read from the first.
    if (!std::isfinite(best_piece_[i].first) || (j < i && best_piece_[j].second == i)) continue;
    Component& a = components_[static_cast<std::size_t>(pieces_[i])];
    Component& b = components_[static_cast<std::size_t>(pieces_[j])];
    if (a.read || b.read) continue;
    std::array<Point2, 4> quad{};
    if (!fit_pieces_quad(a, b, quad)) continue;
    for (auto& p : quad) p = to_full(p);
    const Point2 centre = 0.25 * (quad[0] + quad[1] + quad[2] + quad[3]);
    if (inside_any(out, centre)) continue;
    // Clutter's neighbouring shapes make most such pairs: a look at where
    // the ring would be costs less than measuring the sides.
    Homography H;
    if (!Homography::from_unit_square(quad, H) || !ring_shows_cells(grid_map(H))) continue;
    if (debug_) debug_candidates_.push_back({quad, Rejection::none, -1, {}, {}});
    Detection det;
    Rejection why = refine_and_decode(quad, det);
    // Two squares of a grid side by side make such a pair.
    if (why == Rejection::none && reads_like_a_grid(det)) why = Rejection::grid_like_read;
    note_outcome(why, det);
    if (why == Rejection::none) {
      out.push_back(det);
      a.settled = b.settled = a.read = b.read = true;
    }
  }
}

// The largest quad in the hull of two components (working image,
// clockwise on screen), when the hull is nearly that quad and the pieces'
// light pixels fill enough of it.
bool Frame8Detector::fit_pieces_quad(const Component& a, const Component& b, std::array<Point2, 4>& quad) {
  const int y0 = std::min(a.y0, b.y0), rows = std::max(a.y1, b.y1) - y0 + 1;
  outline_rows({&a, &b}, y0, rows);
  double quad_area = 0, hull_area = 0;
  if (!largest_quad_of_rows(y0, rows, quad, quad_area, hull_area)) return false;
  // As a hole's with rounded corners (quad_fit.cpp): two pieces of clutter
  // lying apart make a hull that the quad fills far less. The pieces'
  // light pixels, as a hole's round a recess.
  return hull_area - quad_area <= kRoundedShortfall * hull_area + hull_staircase(quad_perimeter(quad)) &&
         static_cast<double>(a.area + b.area) >= kMinLightShare * quad_area;
}

}  // namespace markerd::detector::frame8
