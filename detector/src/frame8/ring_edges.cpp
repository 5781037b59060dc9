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

bool Frame8Detector::read_on_ring_edges(const Homography& seen, CellSize cell_size, Detection& det, int& rotation,
                                        Homography& H) {
  if (cell_size.narrow < kResolvedCells) return false;
  Homography at = seen;
  const Point2 seen_centre = seen.map(0.5, 0.5);
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
    if (distance(fitted.map(0.5, 0.5), seen_centre) > cell_size.mean) return false;
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
    if (why == Rejection::none && read.bits_corrected == 0 && !near_uniform(read.id)) {
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
