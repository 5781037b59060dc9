// Stage 2, a hole parted by a cover frame's fold: a quad whose reads failed
// is grown over a light band beyond one side, and read again.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace markerd::detector::frame8 {

namespace {

// Where the band is looked for, working pixels out from the quad's side:
// past the fold's dark pixels (one or two), short of where a white ring
// cell would begin beyond a line half a cell wide.
constexpr std::array<double, 3> kProbeOut{1.5, 2.5, 3.5};
constexpr int kProbes = 5;
// The band beside at least this many probes, one component.
constexpr int kMinProbeHits = 3;
// It lies along at least this share of the side, and reaches out at most
// this many cells of the quad grown over it (a seventh of its side
// across): the fold and the roll seen from 0.5 m reach 1.4 cells at 40
// deg, 1.6 at 45. A run of white ring cells beyond a quad that ends at the
// line reaches as far; grown over it, the quad's cells fall more than a
// cell off on that side and the read fails.
constexpr double kMinBandCover = 0.5;
constexpr double kMaxBandCells = 1.8;

}  // namespace

// Glued on a cover frame turned 35 deg or more, the print's line lies on
// the inner roll; the roll on the side facing the camera shows as a band
// as light as the hole, parted from it by the roll's shaded fold, and the
// hole's component ends at the fold, a cell short of the line. No read of
// that quad places the ring's cells. The band is its own light component,
// thin, along the whole side just beyond the fold: the side is moved out
// to the band's far edge and the quad read again.
bool Frame8Detector::read_hole_past_fold(const Component& hole, const std::array<Point2, 4>& quad, Detection& det) {
  // Cells of 3 px at least, in full-resolution pixels: a read of fewer
  // would not tell a cell's colour across the roll.
  if (cell_size_of(quad).mean * decimate_ < kResolvedCells) return false;
  for (int side = 0; side < 4; ++side) {
    const Point2 a = quad[static_cast<std::size_t>(side)];
    const Point2 b = quad[static_cast<std::size_t>((side + 1) % 4)];
    const double len = distance(a, b);
    const Point2 along{(b.x - a.x) / len, (b.y - a.y) / len};
    const Point2 out{along.y, -along.x};  // outward for a clockwise quad with y down
    const Component* band = nullptr;
    int hits = 0;
    for (int k = 0; k < kProbes; ++k) {
      const double t = 0.15 + 0.7 * k / (kProbes - 1);
      for (const double off : kProbeOut) {
        const int x = static_cast<int>(std::lround(a.x + t * (b.x - a.x) + off * out.x));
        const int y = static_cast<int>(std::lround(a.y + t * (b.y - a.y) + off * out.y));
        if (x < 0 || y < 0 || x >= work_.width || y >= work_.height) continue;
        const Component* c = component_at(x, y);
        if (c == nullptr || c == &hole) continue;
        if (band == nullptr) band = c;
        if (c == band) {
          ++hits;
          break;
        }
      }
    }
    if (band == nullptr || hits < kMinProbeHits || band->area > hole.area / 2) continue;
    // How far the band reaches out from the side, and how much of it it lies along.
    double reach = 0, lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (std::int32_t r = band->first; r >= 0; r = runs_[static_cast<std::size_t>(r)].next) {
      const Run& run = runs_[static_cast<std::size_t>(r)];
      for (const double x : {run.x0 - 0.5, run.x1 - 0.5}) {
        const Point2 p{x - a.x, run.y - a.y};
        reach = std::max(reach, p.x * out.x + p.y * out.y + 0.5);
        const double s = p.x * along.x + p.y * along.y;
        lo = std::min(lo, s);
        hi = std::max(hi, s);
      }
    }
    const double across = 0.5 * (distance(quad[static_cast<std::size_t>((side + 3) % 4)], a) +
                                 distance(b, quad[static_cast<std::size_t>((side + 2) % 4)]));
    if (std::min(hi, len) - std::max(lo, 0.0) < kMinBandCover * len) continue;
    if (reach * (kInnerSide - kMaxBandCells) > kMaxBandCells * across) continue;
    // The side moved out by the band's reach, along the neighbouring sides.
    std::array<Point2, 4> grown = quad;
    const Line moved = line_through(a + reach * out, b + reach * out);
    const Line before = line_through(quad[static_cast<std::size_t>((side + 3) % 4)], a);
    const Line after = line_through(b, quad[static_cast<std::size_t>((side + 2) % 4)]);
    if (!intersect(before, moved, grown[static_cast<std::size_t>(side)]) ||
        !intersect(moved, after, grown[static_cast<std::size_t>((side + 1) % 4)])) {
      continue;
    }
    for (auto& p : grown) p = to_full(p);
    if (refine_and_decode(grown, det) == Rejection::none) return true;
  }
  return false;
}

}  // namespace markerd::detector::frame8
