// Stage 3b, the hole's far and near sides searched for where the ring's
// cells are clearest: the last read of a quad whose other reads failed,
// after the grid fitted to the ring's edges (ring_edges.cpp).

#include <algorithm>
#include <array>
#include <cmath>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// A print glued on a cover frame and turned 45 degrees or more shows its
// hole off on both sides across the turn, in opposite ways: on the far
// side the line lies on the inner roll turned away and is hidden, and the
// hole seen reaches the ring (half a cell too far); on the near side the
// roll faces the camera, lit, a band lighter than the hole between the
// hole seen and the line (up to two cells short). ring_edges.cpp moves
// the hole seen as a whole by the roll's depth, which holds to about 45
// degrees. Here each of the two sides is searched on its own, from a cell
// in to three out, for where the ring's 36 cells split most clearly into
// black and white with one white corner; the best few are read.
constexpr double kLeast = -1.0, kMost = 3.0;
constexpr double kCoarseStep = 0.5, kFineStep = 0.25;
// Only holes foreshortened to this share or less (turned about 37 degrees
// or more) are searched: less turned, the roll's shift is what
// ring_edges.cpp undoes.
constexpr double kMaxForeshortening = 0.8;
// The best this many placements, a cell apart at least, are read: where
// cells are three pixels across, a whole cell's shift may split the cells
// nearly as clearly.
constexpr int kPlacementsRead = 3;
// The line beside a side seen is this much darker than the hole (grey
// levels): several times the sensor's noise.
constexpr float kMinLineContrast = 30;

struct Placement {
  double near = 0, far = 0;  // cells outward, the two sides across the turn
  double separation = -1;
};

}  // namespace

// How clearly the ring's 36 cells, sampled through H at two points each,
// a fifth of a cell either side of their centres across the turn (`across_u`:
// along grid x), split into two levels: Otsu's between-class variance over
// the total, 0 to 1. 0 unless the corners' means split one light and three
// dark. A placement a quarter cell or more off puts one of a cell's two
// samples on its neighbour wherever the colour changes, and splits less
// clearly (a sharp image's single samples split perfectly anywhere within
// half a cell).
double Frame8Detector::ring_separation(const Homography& H, bool across_u) const {
  constexpr double kSpread = 0.2;
  std::array<float, 72> v{};
  std::array<float, 4> corner{};
  std::size_t n = 0;
  double sum = 0, sum2 = 0;
  for (int row = 0; row < frame8::grid; ++row) {
    for (int col = 0; col < frame8::grid; ++col) {
      if (row != 0 && row != frame8::grid - 1 && col != 0 && col != frame8::grid - 1) continue;
      float cell = 0;
      for (const double d : {-kSpread, kSpread}) {
        const Point2 p = grid_point(H, col + 0.5 + (across_u ? d : 0), row + 0.5 + (across_u ? 0 : d));
        float x = 0;
        if (!sample(full_, p.x, p.y, x)) return 0;
        v[n++] = x;
        cell += x;
        sum += x;
        sum2 += static_cast<double>(x) * x;
      }
      if ((row == 0 || row == frame8::grid - 1) && (col == 0 || col == frame8::grid - 1)) {
        corner[static_cast<std::size_t>((row != 0 ? 2 : 0) + (col != 0 ? 1 : 0))] = cell / 2;
      }
    }
  }
  std::sort(v.begin(), v.end());
  double best = 0, threshold = 0, below = 0;
  const double count = static_cast<double>(v.size());
  for (std::size_t k = 1; k < v.size(); ++k) {
    below += v[k - 1];
    const double m0 = below / static_cast<double>(k), m1 = (sum - below) / (count - static_cast<double>(k));
    const double between = static_cast<double>(k) * (count - static_cast<double>(k)) * (m1 - m0) * (m1 - m0);
    if (between > best) {
      best = between;
      threshold = 0.5 * (v[k - 1] + v[k]);
    }
  }
  if (std::count_if(corner.begin(), corner.end(), [&](float c) { return c > threshold; }) != 1) return 0;
  const double total = count * sum2 - sum * sum;
  return total > 0 ? best / total : 0;
}

// Whether the middle of a side of the hole seen (through H) has the line
// beyond it: darker than the hole beside it by kMinLineContrast, in the
// median of five samples each.
bool Frame8Detector::line_seen(const Homography& H, int side) const {
  std::array<float, 5> line{}, hole{};
  for (std::size_t k = 0; k < line.size(); ++k) {
    const double along = 3.0 + static_cast<double>(k);
    const Point2 l = grid_point(H, side_point(side, along, 0.5 * (kInnerLo + frame8::line_outer)));
    const Point2 h = grid_point(H, side_point(side, along, kInnerLo + 0.75));
    if (!sample(full_, l.x, l.y, line[k]) || !sample(full_, h.x, h.y, hole[k])) return false;
  }
  std::nth_element(line.begin(), line.begin() + 2, line.end());
  std::nth_element(hole.begin(), hole.begin() + 2, hole.end());
  return hole[2] - line[2] >= kMinLineContrast;
}

bool Frame8Detector::read_by_ring_alignment(const std::array<Point2, 4>& inner, CellSize cell_size, Detection& det,
                                            int& rotation, Homography& H) {
  if (cell_size.narrow < kResolvedCells) return false;
  Homography seen;
  if (!Homography::from_unit_square(inner, seen)) return false;
  const double across_u = distance(seen.map(0, 0.5), seen.map(1, 0.5));
  const double across_v = distance(seen.map(0.5, 0), seen.map(0.5, 1));
  if (std::min(across_u, across_v) > kMaxForeshortening * std::max(across_u, across_v)) return false;
  // The turn foreshortens the direction across which the hole is narrower.
  const bool turned_along_u = across_u < across_v;
  // The two sides along the turn are where they are seen, and show the
  // line: clutter's shapes mostly do not (and cost the search).
  for (const int side : turned_along_u ? std::array<int, 2>{0, 2} : std::array<int, 2>{1, 3}) {
    if (!line_seen(seen, side)) return false;
  }
  auto placed = [&](const Placement& p, Homography& out) {
    const double lo = -p.near / kInnerSide, hi = 1 + p.far / kInnerSide;
    return Homography::from_unit_square(turned_along_u ? seen.quad(lo, 0, hi, 1) : seen.quad(0, lo, 1, hi), out);
  };
  // The best placements found, best first.
  std::array<Placement, kPlacementsRead> best{};
  auto consider = [&](double near, double far) {
    Placement p{near, far};
    Homography h;
    if (!placed(p, h)) return;
    p.separation = ring_separation(h, turned_along_u);
    // One placement kept per cell: a better one replaces its neighbour.
    for (Placement& b : best) {
      if (std::abs(b.near - near) < 1 && std::abs(b.far - far) < 1) {
        if (p.separation > b.separation) b = p;
        std::sort(best.begin(), best.end(),
                  [](const Placement& x, const Placement& y) { return x.separation > y.separation; });
        return;
      }
    }
    if (p.separation > best.back().separation) {
      best.back() = p;
      std::sort(best.begin(), best.end(),
                [](const Placement& x, const Placement& y) { return x.separation > y.separation; });
    }
  };
  for (double near = kLeast; near <= kMost; near += kCoarseStep) {
    for (double far = kLeast; far <= kMost; far += kCoarseStep) consider(near, far);
  }
  // Each kept placement refined by a quarter cell either way.
  const std::array<Placement, kPlacementsRead> coarse = best;
  for (const Placement& c : coarse) {
    if (c.separation <= 0) continue;
    for (const double dn : {-kFineStep, 0.0, kFineStep}) {
      for (const double df : {-kFineStep, 0.0, kFineStep}) {
        if (dn != 0 || df != 0) consider(c.near + dn, c.far + df);
      }
    }
  }
  for (const Placement& p : best) {
    Homography at;
    if (p.separation <= 0 || !placed(p, at)) continue;
    const CellSize size = cell_size_of(at.quad());
    Rejection why = decode(at, size, det, rotation, nullptr);
    // Moved onto a grid's lines, a square's ring reads so.
    if (why == Rejection::none && reads_like_a_grid(det)) why = Rejection::grid_like_read;
    note_attempt(Read::ring_alignment, why);
    if (why == Rejection::none) {
      H = at;
      return true;
    }
    // Read clearly enough to name its cells, the ring's own edges place it.
    if (worth_remeasuring(why) && read_from_ring_edges(at, size, det, rotation, H)) return true;
  }
  return false;
}

}  // namespace markerd::detector::frame8
