// Stage 3b, the grid fitted to the ring's own edges: the last read of a quad
// whose other reads failed, after the hole inset all round (inset_hole.cpp).

#include "frame8/detector.hpp"

#include <array>
#include <cmath>

namespace markerd::detector::frame8 {

// A print glued on a cover frame has its line and the ring's inner edge on
// the inner roll, down into the opening: a turned frame shows one side's
// roll and hides the opposite one behind the flat band, and the hole seen
// is shifted and shrunk by up to half a cell against the ring. Sampled
// through it, the ring's cells read mixed, mostly at the corners, and the
// white corner does not read. The cells read clearly still say where the
// ring's own edges are: the boundaries between cells of two colours and the
// line's outer edge beside white cells. The grid is fitted to those (as
// stage 5 fits it to a known code's) and the ring read again; a second
// round takes the cells that read clearly on the first fit.
constexpr int kRounds = 2;

// The hole seen on a cover frame is the line's inner edge on the inner
// roll, below the plane of the ring: turned by an angle t, it is displaced
// towards the far side, the same for all its sides, by about this many
// cells times tan t. The displacement grows more slowly than tan t, as the
// edge seen moves round the roll: 0.3 to 0.5 of a cell at 40 deg from
// 0.95 m, about half a cell at 60 deg from 0.5 m (the quad there lay 2 px
// off with cells of 3.9). The fit to the ring's edges pulls a start within
// about a third of a cell in: a depth of 0.6 started 1.04 cells off at 60
// deg, and those markers did not read (0.5 m, 60 deg: 86% then, 90% now).
constexpr double kRollDepthCells = 0.3;
// Turned less than this (tan 27 deg), the fit to the ring's edges undoes
// the displacement from the hole seen.
constexpr double kMinTurnTan = 0.5;

namespace {

// The map moved by `along_u`, `along_v` cells across the hole's unit square.
bool moved(const Homography& H, double along_u, double along_v, Homography& out) {
  const double du = along_u / kInnerSide, dv = along_v / kInnerSide;
  return Homography::from_unit_square(H.quad(du, dv, 1 + du, 1 + dv), out);
}

}  // namespace

bool Frame8Detector::read_on_ring_edges(const Homography& seen, CellSize cell_size, Detection& det, int& rotation,
                                        Homography& H) {
  if (cell_size.narrow < kResolvedCells) return false;
  // The fit starts from the hole seen and, turned far, from the hole moved
  // back either way along the direction foreshortened (which way is far is
  // not told reliably by a hole of a few dozen pixels with rounded
  // corners; the wrong way reads no code). The turn is the square's
  // foreshortening.
  const double across_u = distance(seen.map(0, 0.5), seen.map(1, 0.5));
  const double across_v = distance(seen.map(0.5, 0), seen.map(0.5, 1));
  const double cos_turn = std::min(across_u, across_v) / std::max(across_u, across_v);
  const double tan_turn = std::sqrt(1 - cos_turn * cos_turn) / cos_turn;
  const double back = kRollDepthCells * tan_turn;
  std::array<Homography, 3> starts{seen, seen, seen};
  int start_count = 1;
  if (tan_turn >= kMinTurnTan) {
    const bool along_u = across_u < across_v;
    for (const double sign : {1.0, -1.0}) {
      if (moved(seen, along_u ? sign * back : 0, along_u ? 0 : sign * back,
                starts[static_cast<std::size_t>(start_count)])) {
        ++start_count;
      }
    }
  }
  for (int start = 0; start < start_count; ++start) {
    if (read_from_ring_edges(starts[static_cast<std::size_t>(start)], cell_size, det, rotation, H)) return true;
  }
  return false;
}

bool Frame8Detector::read_from_ring_edges(const Homography& start, CellSize cell_size, Detection& det, int& rotation,
                                          Homography& H) {
  Homography at = start;
  const Point2 start_centre = start.map(0.5, 0.5);
  for (int round = 0; round < kRounds; ++round) {
    RingRead r;
    if (read_cells(at, cell_size, nullptr, r) != Rejection::none) return false;
    if (fit_grey_model(cell_size, r) != Rejection::none) return false;
    CellColours colours{};
    auto colour = [&](frame8::Cell cell, const CellSample& s) {
      if (!r.clear(s)) return;
      colours[static_cast<std::size_t>(cell.row * frame8::grid + cell.col)] =
          r.soft(s.mean) > 0 ? kWhiteCell : kBlackCell;
    };
    for (int k = 0; k < 4; ++k) colour(frame8::corner_cell(k), r.corner[static_cast<std::size_t>(k)]);
    for (int edge = 0; edge < 4; ++edge) {
      for (int bit = 0; bit < 8; ++bit) {
        colour(frame8::data_cell(edge, bit), r.cell[static_cast<std::size_t>(edge)][static_cast<std::size_t>(bit)]);
      }
    }
    if (collect_pattern_edges(at, colours, cell_size.mean, {}, HoleEdge::unknown) < kMinPatternEdges) return false;
    Eigen::Matrix3d M;
    if (!fit_grid_map(M)) return false;
    const Homography fitted = Homography::from_grid_map(M);
    // The ring's edges move the grid by a fraction of a cell; a fit that
    // moved it by more found other edges.
    if (distance(fitted.map(0.5, 0.5), start_centre) > cell_size.mean) return false;
    const std::array<Point2, 4> hole = fitted.quad();
    if (!convex(hole)) return false;
    const CellSize size = cell_size_of(hole);
    if (size.narrow < kResolvedCells) return false;
    Detection read;
    int read_rotation = 0;
    const Rejection why = decode(fitted, size, read, read_rotation, nullptr);
    note_attempt(Read::ring_edges, why);
    // Moved onto the edges of a tiled or checkered surface, a square's
    // grid reads the ring of tiles round it as one colour from end to end
    // but for its corners: no near-uniform id, and no cell outvoted, is
    // read so (as of a hole inset all round).
    if (why == Rejection::none && !reads_like_a_grid(read)) {
      det = read;
      rotation = read_rotation;
      H = fitted;
      return true;
    }
    at = fitted;
  }
  return false;
}

}  // namespace markerd::detector::frame8
