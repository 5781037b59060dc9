// Stage 3b, a hole inset all round: the last read of a quad whose other
// reads failed, after the reads with a side hidden (hidden_side.cpp).

#include "frame8/detector.hpp"

#include <array>

namespace markerd::detector::frame8 {

// A hole inset all round: a switch's rocker, lighter than the frame's
// roll and parted from the line by its shadow, is the light component, a
// fraction of a cell inside the line on every side. The quad is read grown
// by a quarter cell at a time; every size that reads must read the same id
// with no cell outvoted, two sizes at least must read, and the clearest
// read is kept. Near-uniform ids are not read so. (A checkerboard's
// square, read at one size only, gave id 63; the switch frame's rates from
// 0.3 to 1.5 m and turned to 60 deg are the same with two sizes asked.)
constexpr std::array<double, 4> kInsetCells{0.25, 0.5, 0.75, 1.0};

bool Frame8Detector::read_inset(const std::array<Point2, 4>& inner, CellSize cell_size, Detection& det, int& rotation,
                                Homography& H) {
  if (cell_size.mean < kResolvedCells) return false;
  Homography seen;
  if (!Homography::from_unit_square(inner, seen)) return false;
  bool found = false;
  int reads = 0;
  for (const double inset : kInsetCells) {
    if (inset * 2 >= kInnerSide - 1) break;
    const double grow = inset / (kInnerSide - 2 * inset);  // in the seen quad's units
    const std::array<Point2, 4> hole = seen.quad(-grow, -grow, 1 + grow, 1 + grow);
    Homography grown;
    if (!Homography::from_unit_square(hole, grown)) continue;
    const CellSize size = cell_size_of(hole);
    if (size.narrow < kResolvedCells) continue;
    Detection read;
    int read_rotation = 0;
    reading_grown_hole_ = true;
    const Rejection why = decode(grown, size, read, read_rotation, nullptr);
    reading_grown_hole_ = false;
    note_attempt(Read::inset, why);
    // Grown to the next dark edge, a square of a tiled or checkered
    // surface takes in the grout or squares round it, which read as a ring
    // one colour from end to end but for its corners: no near-uniform id
    // is read so (a checkerboard read as 127 once the cells were sampled
    // clear of the ring's outer edge).
    if (why != Rejection::none || reads_like_a_grid(read)) continue;
    if (found && read.id != det.id) return false;
    ++reads;
    if (found && read.margin <= det.margin) continue;
    det = read;
    rotation = read_rotation;
    H = grown;
    found = true;
  }
  return found && reads >= 2;
}

}  // namespace markerd::detector::frame8
