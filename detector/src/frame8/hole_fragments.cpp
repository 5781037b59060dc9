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
#include <initializer_list>
#include <limits>
#include <vector>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// The pieces' ends across the parting line up to this share of the span
// (a marker turned in its plane by up to about 15 degrees). Along the
// parting their boxes may overlap, even one hold the other: turned far,
// an outlet's face is one piece, and the insert's side wall with the strip
// below the face another, an L round it.
constexpr double kEndsAlign = 0.25;
// A third piece, the insert's side wall, shares the parting edge with the
// face the pair makes, along the hole's whole side: its ends line up with
// the pair's as closely as the hole's side is measured.
constexpr double kWallEndsAlign = 0.125;
// The shaded edge between the wall and the face: at most a pixel, or this
// share of the hole where the hole is large.
constexpr double kWallEdge = 0.05;
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
// the hole and the recess the rest (their boxes overlap where it is round,
// or where one piece wraps the other).
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
    const bool one_hole = ends <= kEndsAlign && gap <= kMaxGap * extent;
    return one_hole ? ends : kNone;
  };
  return std::min(mismatch(a.x0, a.x1, b.x0, b.x1, a.y0, a.y1 + 1, b.y0, b.y1 + 1),
                  mismatch(a.y0, a.y1 + 1, b.y0, b.y1 + 1, a.x0, a.x1, b.x0, b.x1));
}

}  // namespace

void Frame8Detector::read_hole_fragments(std::vector<Detection>& out) {
  const double min_side = config_.frame8.min_hole_side_px / decimate_;
  // Components large enough to be a piece of a hole; the concave ones
  // among them are paired, any of them may be a third.
  sized_pieces_.clear();
  pieces_.clear();
  for (const std::int32_t r : roots_) {
    const Component& c = components_[static_cast<std::size_t>(r)];
    if (c.read || c.touches_border || std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) < 0.5 * min_side) continue;
    sized_pieces_.push_back(r);
    if (box_fill(c) <= kMaxPieceFill) pieces_.push_back(r);
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
    if (read_pieces({&a, &b}, out)) continue;
    // Turned far, the insert's side wall shows beside the face as a third
    // piece, a strip parted from both by shaded edges: the pair is then
    // the face round the recess, and the strip lies beside the pair's box
    // as another piece would.
    Component pair = a;
    pair.x0 = std::min(a.x0, b.x0);
    pair.x1 = std::max(a.x1, b.x1);
    pair.y0 = std::min(a.y0, b.y0);
    pair.y1 = std::max(a.y1, b.y1);
    Component* third = nullptr;
    double best = std::numeric_limits<double>::infinity();
    for (const std::int32_t r : sized_pieces_) {
      Component& c = components_[static_cast<std::size_t>(r)];
      if (&c == &a || &c == &b || c.read) continue;
      // Only the parting's shaded edge lies between them.
      const int apart = std::max(std::max(pair.x0, c.x0) - std::min(pair.x1, c.x1),
                                 std::max(pair.y0, c.y0) - std::min(pair.y1, c.y1) - 1);
      if (apart > std::max(1.0, kWallEdge * std::max(pair.x1 - pair.x0, pair.y1 - pair.y0 + 1))) continue;
      const double mismatch = pieces_mismatch(pair, c, min_side);
      if (mismatch < best) {
        best = mismatch;
        third = &c;
      }
    }
    if (third != nullptr && best <= kWallEndsAlign) read_pieces({&a, &b, third}, out);
  }
}

// Reads the hull of a hole's pieces as any quad's; true when it read.
bool Frame8Detector::read_pieces(std::initializer_list<Component*> pieces, std::vector<Detection>& out) {
  std::array<Point2, 4> quad{};
  if (!fit_pieces_quad(pieces, quad)) return false;
  for (auto& p : quad) p = to_full(p);
  const Point2 centre = centre_of(quad);
  if (inside_any(out, centre)) return false;
  // Clutter's neighbouring shapes make most such pairs: a look at where
  // the ring would be costs less than measuring the sides.
  Homography H;
  if (!Homography::from_unit_square(quad, H) || !ring_shows_cells(grid_map(H))) return false;
  if (debug_) debug_candidates_.push_back({quad, Rejection::none, -1, {}, {}});
  Detection det;
  Rejection why = refine_and_decode(quad, det);
  // Two squares of a grid side by side make such a pair.
  if (why == Rejection::none && reads_like_a_grid(det)) why = Rejection::grid_like_read;
  note_outcome(why, det);
  if (why != Rejection::none) return false;
  out.push_back(det);
  for (Component* c : pieces) c->settled = c->read = true;
  return true;
}

// The largest quad in the hull of a hole's pieces (working image,
// clockwise on screen), when the hull is nearly that quad and the pieces'
// light pixels fill enough of it.
bool Frame8Detector::fit_pieces_quad(std::initializer_list<Component*> pieces, std::array<Point2, 4>& quad) {
  std::array<const Component*, 3> list{};
  std::size_t n = 0;
  int y0 = std::numeric_limits<int>::max(), y1 = std::numeric_limits<int>::min();
  std::int64_t area = 0;
  for (const Component* c : pieces) {
    list.at(n++) = c;
    y0 = std::min(y0, c->y0);
    y1 = std::max(y1, c->y1);
    area += c->area;
  }
  const int rows = y1 - y0 + 1;
  outline_rows({list.data(), n}, y0, rows);
  double quad_area = 0, hull_area = 0;
  if (!largest_quad_of_rows(y0, rows, quad, quad_area, hull_area)) return false;
  // As a hole's with rounded corners (quad_fit.cpp): pieces of clutter
  // lying apart make a hull that the quad fills far less. The pieces'
  // light pixels, as a hole's round a recess.
  return hull_area - quad_area <= kRoundedShortfall * hull_area + hull_staircase(quad_perimeter(quad)) &&
         static_cast<double>(area) >= kMinLightShare * quad_area;
}

}  // namespace markerd::detector::frame8
