// Stage 3b, a side hidden: the last read of a quad whose other reads failed.
// Something in front of the marker (a finger, a cable, the edge of a cover)
// hides one side's ring, perhaps its line, and perhaps reaches into the
// hole: then the hole's component ends at the cover's edge, up to a few
// cells short of the line, and the quad's map puts every cell off by as
// much. Each side is tried hidden to a series of depths, the hole extended
// beyond the quad where the side looks covered, the hidden cells left out
// of the read (RingRead::hidden). The three edges left vote every bit;
// every depth that reads must read the same code, and the best read is kept.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <limits>
#include <span>

#include "markerd/detector/pose.hpp"

namespace markerd::detector::frame8 {

// How far the hidden part reaches in from the marker's outer edge, in
// cells: the ring alone, the ring and the line, then on into the hole a
// quarter cell at a time, to 0.4 of the marker's size (an object 0.2 deep
// and 3 cm in front, seen turned 30 deg, reaches that far). Deeper, bits
// would be left with a single vote: each neighbouring edge has lost four
// cells, and every bit is still read on the opposite edge and one other.
constexpr std::array<double, 12> kHiddenDepth{1.0, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.25, 3.5, 3.75, 4.0};

// A hole read with a side hidden and its white corner hidden too (two
// orientations fit) has its short sides at least this share of its long
// ones (turned up to about 65 deg): two leniencies on a squeezed hole were
// a quad three keys of a keyboard tall and one wide (0.32), read as 94. A
// covered print or a socket frame read so showed 0.68 at least; a switch
// frame turned to 80 deg and read with a side hidden, 0.30, but with its
// white corner seen.
constexpr double kMinAmbiguousHiddenSideRatio = 0.4;

// Beyond a seen side the line gives way to the ring, whose light cells
// are as light as the hole; beyond a covered side, out to where the ring
// would be, all is the cover's one grey, darker than the hole. `into_hole`:
// the quad's side may be the cover's edge (the samples from the line out,
// clear of the neighbouring sides); otherwise the ring's outer half from
// corner to corner, where a cover that leaves the hole whole still lies
// (every id but 0 has a light cell there on every side).
bool Frame8Detector::looks_covered(const Homography& H, int side, bool into_hole) const {
  constexpr std::array<double, 10> kWhole{0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5};
  constexpr std::array<double, 3> kBeyondQuad{1.2, 0.8, 0.4};
  constexpr std::array<double, 1> kOuterRing{0.25};
  const auto along = into_hole ? std::span<const double>(kSideMiddle) : std::span<const double>(kWhole);
  const auto beyond = into_hole ? std::span<const double>(kBeyondQuad) : std::span<const double>(kOuterRing);
  // The cover's grey may vary by this share of its contrast with the hole.
  constexpr float kUniform = 0.3F;
  constexpr float kMinContrast = 30;
  std::array<float, kSideMiddle.size()> hole{};
  for (std::size_t k = 0; k < kSideMiddle.size(); ++k) {
    const Point2 p = grid_point(H, side_point(side, kSideMiddle[k], kInnerLo + 0.5));
    if (!sample(full_, p.x, p.y, hole[k])) return false;
  }
  float lo = 255, hi = 0;
  for (const double a : along) {
    for (const double in : beyond) {
      const Point2 q = grid_point(H, side_point(side, a, in));
      float v = 0;
      if (!sample(full_, q.x, q.y, v)) return false;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  // The median: the hole may hold an insert's darker parts.
  std::nth_element(hole.begin(), hole.begin() + hole.size() / 2, hole.end());
  const float hole_level = hole[hole.size() / 2];
  if (hole_level - lo >= kMinContrast && hi - lo <= kUniform * (hole_level - lo)) return true;
  if (into_hole) return false;
  // A cover as light as the hole over the ring alone, the line still seen:
  // a side's ring is never all white (its corners C0, C2 and C3 are black,
  // and only id 255 has no black data cell), so a ring as light as the
  // hole from corner to corner, beside a dark line, is hidden.
  std::array<float, kSideMiddle.size()> line{};
  for (std::size_t k = 0; k < kSideMiddle.size(); ++k) {
    const Point2 p = grid_point(H, side_point(side, kSideMiddle[k], kInnerLo - 0.25));
    if (!sample(full_, p.x, p.y, line[k])) return false;
  }
  std::nth_element(line.begin(), line.begin() + line.size() / 2, line.end());
  const float line_level = line[line.size() / 2];
  return hole_level - line_level >= kMinContrast && hole_level - lo <= kUniform * (hole_level - line_level);
}

// How far a hole's corners (pixels) are from any square's seen through the
// camera: the pose's reprojection error. 0 without a camera model.
double Frame8Detector::square_misfit(const std::array<Point2, 4>& hole) const {
  if (!config_.camera) return 0;
  std::array<Eigen::Vector2d, 4> normalized{};
  for (std::size_t j = 0; j < 4; ++j) {
    const Point2 p = config_.camera->pixel_to_normalized(hole[j]);
    normalized[j] = {p.x, p.y};
  }
  const auto pose = estimate_square_pose_normalized(*config_.camera, normalized, 1.0);
  return pose ? pose->best.reprojection_error_px : std::numeric_limits<double>::infinity();
}

bool Frame8Detector::read_with_side_hidden(const std::array<Point2, 4>& inner, Detection& det, int& rotation,
                                           HiddenSide& hidden, Homography& H) {
  Homography seen;
  if (!Homography::from_unit_square(inner, seen)) return false;
  // One side hidden, the other three showing their rings: a light patch
  // on a dark ground looks covered all round, and is no marker to read so.
  int side = -1;
  for (int s = 0; s < 4; ++s) {
    if (!looks_covered(seen, s, false)) continue;
    if (side >= 0) return false;
    side = s;
  }
  if (side < 0) return false;
  return read_hidden_side(inner, side, HoleEnd::at_cover, det, rotation, hidden, H);
}

bool Frame8Detector::read_hidden_side(const std::array<Point2, 4>& inner, int side, HoleEnd end, Detection& det,
                                      int& rotation, HiddenSide& hidden, Homography& H) {
  // Cells are read down to kHiddenSideCells: under three pixels by their
  // blur with the neighbours, which a cover's edge mixes into the cells
  // beside it (one vote of three on two bits, which the others outvote).
  // A marker covered by a fifth of its size from 1.2 m and turned 30 deg,
  // or from 1.4 m facing, has cells of 2.9 to 3 px. The quad seen is cut
  // short across the hidden side; along it, its longest side still spans
  // the whole hole.
  double longest = 0;
  for (std::size_t i = 0; i < 4; ++i) longest = std::max(longest, distance(inner[i], inner[(i + 1) % 4]));
  if (longest / kInnerSide < kHiddenSideCells) return false;
  Homography seen;
  if (!Homography::from_unit_square(inner, seen)) return false;
  // The hole when `side` is hidden `depth` cells deep: the quad's unit
  // square is the part seen, kInnerSide - h cells deep, and the whole hole
  // reaches this far in its units.
  auto hole_for = [&](double depth, std::array<Point2, 4>& hole) {
    const double reach = kInnerSide / (kInnerSide - std::max(depth - kInnerLo, 0.0));
    double u0 = 0, u1 = 1, v0 = 0, v1 = 1;
    switch (side) {
      case 0: v0 = 1 - reach; break;
      case 1: u1 = reach; break;
      case 2: v1 = reach; break;
      default: u0 = 1 - reach; break;
    }
    hole = {seen.map(u0, v0), seen.map(u1, v0), seen.map(u1, v1), seen.map(u0, v1)};
    return Homography::from_unit_square(hole, H);
  };
  Rejection last_why = Rejection::none;
  auto read_at = [&](double depth, Detection& read, int& read_rotation, std::array<Point2, 4>& hole) {
    hidden = HiddenSide{side, depth};
    if (!hole_for(hidden.depth, hole)) return false;
    const CellSize size = cell_size_of(hole);
    if (size.narrow < kHiddenSideCells) return false;
    Rejection why = decode(H, size, read, read_rotation, nullptr, hidden);
    // Under three pixels a cell, with three edges to vote and no second
    // measurement, clutter's open shapes read too: a letter C as id 1, a
    // square among others as 129 (covered prints over clutter, 1.2 to 1.4
    // m), each a near-uniform id, as a grid's squares read.
    if (why == Rejection::none && size.narrow < kResolvedCells && reads_like_a_grid(read)) {
      why = Rejection::grid_like_read;
    }
    if (why == Rejection::none && read.orientation_ambiguous &&
        short_to_long_sides(hole) < kMinAmbiguousHiddenSideRatio) {
      why = Rejection::second_leniency;
    }
    note_attempt(Read::side_hidden, why);
    last_why = why;
    // Ids 0 and 255 are one colour all round: with a side hidden, any
    // dark frame around a light patch reads as one of them.
    return why == Rejection::none && read.id != 0 && read.id != 255;
  };
  // Where the neighbouring edges' cells change colour, only the right
  // depth reads; where they do not (id 254: all white), a run of depths
  // does. With a camera the hole most nearly a square seen in perspective
  // is taken; without one, the middle of the run.
  unsigned reads = 0;  // a bit per depth that read
  int id = -1;
  std::size_t best_k = 0;
  double best_misfit = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < kHiddenDepth.size(); ++k) {
    // A hole that reaches beyond what the quad saw needs the cover over the line too.
    if (end == HoleEnd::at_cover && kHiddenDepth[k] > kInnerLo && k > 0 && kHiddenDepth[k - 1] <= kInnerLo &&
        !looks_covered(seen, side, true)) {
      break;
    }
    Detection read;
    int read_rotation = 0;
    std::array<Point2, 4> hole{};
    if (!read_at(kHiddenDepth[k], read, read_rotation, hole)) {
      // An open U of clutter: where the ring has no black and white at
      // the first depth, the cover's depth will not give it any.
      if (end == HoleEnd::open && id < 0 && k == 0 && !worth_remeasuring(last_why)) return false;
      continue;
    }
    // Two codes that fit the same quad, each with its own cover: neither is trusted.
    if (id >= 0 && read.id != id) return false;
    id = read.id;
    reads |= 1U << k;
    const double misfit = square_misfit(hole);
    if (misfit < best_misfit) {
      best_misfit = misfit;
      best_k = k;
    }
  }
  if (id < 0) return false;
  if (hole_printed_blank_) {
    // H, the whole hole at the depth that read best, gives the line's and
    // the ring's grey; the part seen, the hole's.
    std::array<Point2, 4> whole{};
    if (!hole_for(kHiddenDepth[best_k], whole) || !hole_is_blank_paper(seen, H, side)) {
      note_attempt(Read::side_hidden, Rejection::hole_not_blank);
      return false;
    }
  }
  if (!config_.camera) {
    unsigned rest = reads;
    for (int skip = (std::popcount(reads) - 1) / 2; skip > 0; --skip) rest &= rest - 1;
    best_k = static_cast<std::size_t>(std::countr_zero(rest));
  }
  std::array<Point2, 4> hole{};
  double depth = kHiddenDepth[best_k];
  if (config_.camera && depth > kInnerLo) {
    // Between the quarter cells, the depth at which the hole is most
    // nearly a square: a quarter cell off tilts the pose, and the seen
    // side's outer corners with it, by up to a pixel at half a metre.
    constexpr double kInvPhi = 0.6180339887498949;
    constexpr int kSteps = 8;  // the interval down to a hundredth of a cell
    double lo = std::max(kInnerLo, depth - 0.25), hi = depth + 0.25;
    auto misfit_at = [&](double at) { return hole_for(at, hole) ? square_misfit(hole) : best_misfit + 1; };
    double a = hi - kInvPhi * (hi - lo), b = lo + kInvPhi * (hi - lo);
    double fa = misfit_at(a), fb = misfit_at(b);
    for (int i = 0; i < kSteps; ++i) {
      if (fa < fb) {
        hi = b;
        b = a;
        fb = fa;
        a = hi - kInvPhi * (hi - lo);
        fa = misfit_at(a);
      } else {
        lo = a;
        a = b;
        fa = fb;
        b = lo + kInvPhi * (hi - lo);
        fb = misfit_at(b);
      }
    }
    const double refined = fa < fb ? a : b;
    Detection read;
    int read_rotation = 0;
    if (std::min(fa, fb) < best_misfit && read_at(refined, read, read_rotation, hole) && read.id == id) {
      det = read;
      rotation = read_rotation;
      return true;
    }
  }
  return read_at(depth, det, rotation, hole);
}

// The corners of a hole read beyond the quad seen (a side hidden, or grown
// all round: inset_hole.cpp): from the pattern's edges clear of the hidden
// side (they fix how far the hole reaches better than the quarter cells
// tried); failing that, from the hole itself, undistorted with a camera.
Rejection Frame8Detector::finish_from_hole(const Homography& H, const HiddenSide& hidden, int rotation, double cell_px,
                                           Detection& det) {
  // The pattern's fit may move the hole's corners by the part of a cell the
  // quarter cells missed, no more: beyond that it has fitted something else.
  // Under three pixels a cell, by as much again: the sides were measured
  // once, by the step into the line, whose centroid a white cell beyond
  // pulls into the hole (no second measurement knowing the code follows a
  // read with a side hidden). Covered markers from 1.2 m turned 30 deg
  // moved by up to 0.75 of a cell; clutter read so, by 5.
  constexpr double kMaxCornerMove = 0.5;
  const bool unresolved = hidden.side >= 0 && cell_size_of(H.quad()).narrow < kResolvedCells;
  if (collect_pattern_edges(H, det.id, rotation, cell_px, hidden) >= kMinPatternEdges) {
    Detection by_pattern = det;
    if (finish_by_pattern(rotation, by_pattern) == Rejection::none && by_pattern.inner_corners) {
      const std::array<Point2, 4> hole = H.quad();
      const double limit = (unresolved ? 2 : 1) * kMaxCornerMove * cell_px;
      bool near = true;
      for (int j = 0; j < 4; ++j) {
        // Corner j of the marker is the quad's corner j + rotation.
        const Point2 expected = hole[static_cast<std::size_t>((j + rotation) % 4)];
        near = near && distance((*by_pattern.inner_corners)[static_cast<std::size_t>(j)], expected) <= limit;
      }
      if (near) {
        det = by_pattern;
        return Rejection::none;
      }
    }
  }
  // Under three pixels a cell, a read with a side hidden stands only where
  // the whole pattern it predicts is found there: clutter's open shapes and
  // keys read so (ids 64 and 124 in 7,000 frames of the backgrounds alone),
  // their white corner hidden.
  if (unresolved) return Rejection::pattern_fit_failed;
  if (!config_.camera) return report(grid_map(H), rotation, det);
  std::array<Point2, 4> hole = H.quad();
  for (Point2& p : hole) p = config_.camera->pixel_to_normalized(p);
  Homography normalized;
  if (!Homography::from_unit_square(hole, normalized)) return Rejection::degenerate_quad;
  return report(grid_map(normalized), rotation, det);
}

}  // namespace markerd::detector::frame8
