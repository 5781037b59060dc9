// Stage 4c, orientation: the one white corner is C1 (top right). The
// corners are read before the bits are voted (read_corners); once the code
// is known, C1's neighbours check them and, for a marker turned far, the
// short edges' profiles decide them (settle_orientation, short_edges.cpp).

#include "frame8/detector.hpp"

#include <algorithm>
#include <cmath>

namespace markerd::detector::frame8 {

// With a side hidden, its two corners are: the two left must be clearly
// read, and at most one of them white. When neither is, C1 is one of the
// two hidden corners, and the orientation is reported as ambiguous rather
// than guessed; the code, the same along every edge, holds either way.
static Rejection read_corners_beside_hidden_side(RingRead& r) {
  const int first_hidden = r.hidden.side, second_hidden = (r.hidden.side + 1) % 4;
  int white = -1, whites = 0;
  double clarity = 1.0;
  for (int k = 0; k < 4; ++k) {
    if (k == first_hidden || k == second_hidden) continue;
    const CellSample& c = r.corner[static_cast<std::size_t>(k)];
    if (!r.clear(c)) return Rejection::white_corner_unclear;
    clarity = std::min(clarity, std::abs(r.soft(c.mean)));
    if (r.soft(c.mean) > 0) {
      white = k;
      ++whites;
    }
  }
  if (whites > 1) return Rejection::white_corner_count;
  r.orientation_ambiguous = whites == 0;
  r.white_corner = whites == 1 ? white : second_hidden;
  r.orientation_clarity = clarity;
  r.corners_read = true;
  r.by_short_edges = false;
  return Rejection::none;
}

Rejection Frame8Detector::read_corners(RingRead& r) const {
  if (r.hidden.side >= 0) {
    // A marker turned far has no votes left with a side hidden as well.
    if (r.short_side >= 0) return Rejection::white_corner_unclear;
    return read_corners_beside_hidden_side(r);
  }
  const auto& corner = r.corner;
  // Four dark corners are never a marker: that is every dark square frame
  // with a light inside.
  int white_corners = 0;
  for (const auto& c : corner) white_corners += r.soft(c.mean) > 0;
  // Corners decide orientation. Without a clean 3:1 split (an edge covered
  // with its corners) the whitest corner still decides, as the contract
  // says, but only a clearly read code may rely on that.
  std::array<float, 4> sorted{};
  for (int k = 0; k < 4; ++k) sorted[static_cast<std::size_t>(k)] = corner[static_cast<std::size_t>(k)].mean;
  std::sort(sorted.begin(), sorted.end());
  r.orientation_clarity = 0.5 * (r.soft(sorted[3]) - r.soft(sorted[2]));
  r.corners_read =
      white_corners >= 1 && white_corners <= 2 && r.clear(corner[static_cast<std::size_t>(r.white_corner)]);
  if (r.short_side < 0) {
    if (white_corners == 0 || white_corners > 2) return Rejection::white_corner_count;
    if (!r.corners_read) return Rejection::white_corner_unclear;
  }
  // A marker turned far: its short edges' profiles decide, once the code
  // is known, even where its corners read clearly. With only the two long
  // edges voting, any shape with a half-turn's symmetry (a light outline, a
  // bar) reads the same code on both, and corner cells a pixel deep mix
  // with whatever lies beside them and can read clearly white by chance
  // (a white outline in clutter was reported so, as id 126): the short
  // edges are the only check left on the code.
  r.by_short_edges = r.short_side >= 0;
  return Rejection::none;
}

Rejection Frame8Detector::settle_orientation(const Homography& H, RingRead& r) const {
  // C1 is a whole cell: its two neighbours along the ring (the last cell of
  // the edge before it, the first of the edge after it) never contradict
  // the code. A light blob that merely reaches the spot where C1 is sampled
  // (the diagonal neighbour of a light square in a checkered pattern)
  // spills into both. A neighbour that was itself outvoted, on an edge one
  // colour from end to end, lies under the cover of that whole edge and
  // says nothing; nor does a short edge whose profile placed the corners.
  // A neighbour contradicts when its soft level is this far on the wrong side.
  constexpr double kContradiction = 0.3;
  auto covered = [&](int edge) {
    if (r.outvoted_cells(edge) == 0) return false;
    const auto& cells = r.cell[static_cast<std::size_t>(edge)];
    const bool light = r.soft(cells[0].mean) > 0;
    return std::all_of(cells.begin(), cells.end(),
                       [&](const CellSample& c) { return r.clear(c) && (r.soft(c.mean) > 0) == light; });
  };
  auto contradicts = [&](int edge, bool first_cell) {
    if (covered(edge) || (r.by_short_edges && r.weight[static_cast<std::size_t>(edge)] == 0.0)) return false;
    const CellSample& c = r.cell[static_cast<std::size_t>(edge)][first_cell ? 7U : 0U];
    const bool bit = ((r.id >> (first_cell ? 7 : 0)) & 1) != 0;
    return c.valid && (bit ? r.soft(c.mean) < -kContradiction : r.soft(c.mean) > kContradiction);
  };
  auto c1_contradicted = [&] {
    return contradicts((r.white_corner + 3) % 4, false) || contradicts(r.white_corner, true);
  };
  // Clearly read corners of a marker turned far may still be wrong: the
  // blur mixes each with the background. Its neighbours tell.
  if (r.short_side >= 0 && !r.by_short_edges && c1_contradicted()) r.by_short_edges = true;
  if (r.by_short_edges) {
    r.white_corner = white_corner_by_short_edges(H, r.short_side, r.id, r.black, r.white, r.orientation_clarity);
    if (r.white_corner < 0) return Rejection::short_edges_unexplained;
  }
  if (c1_contradicted()) return Rejection::c1_contradicted;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
