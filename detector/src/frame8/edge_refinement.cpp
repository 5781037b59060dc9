// Stage 3, edge refinement at full resolution: edge points across each side
// of the quad (the step into the line, or a fit of the blurred line's
// profile), a line through them per side, the corners at their intersections.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <vector>

#include "normal_table.hpp"

namespace markerd::detector::frame8 {

// Edge points along a side, at the least, when the code is known: three
// per cell over the 5.3 cells they span (t from 0.12 to 0.88 of 7 cells).
constexpr int kIdEdgePoints = 16;
// A side shorter than this fraction of its neighbours is a sliver's end.
constexpr double kSliverEnd = 0.35;
// The profile fit moves the measured edge at most this far (pixels): the
// step's centroid is off by a fraction of a cell, under a pixel here.
constexpr double kProfileReach = 1.2;

// Finds the hole-to-line edge along side i of the quad; fills
// edge_points_[i]. Without a code (EdgeMode::step, no id), every point takes
// the centroid of the light-to-dark step. With the code read once, each point knows the
// colour of the cell beyond the line: where it is white and the line is
// thin against the blur, the step is cut short by the white cell and its
// centroid falls inside the hole; the blurred line is then a symmetric dip
// instead, whose centroid is the line's centre, a quarter cell outside the
// edge.
int Frame8Detector::collect_edge_points(const std::array<Point2, 4>& q, int side, EdgeMode mode,
                                        std::optional<int> id) {
  const Point2 a = q[static_cast<std::size_t>(side)];
  const Point2 b = q[static_cast<std::size_t>((side + 1) % 4)];
  const double len = distance(a, b);
  const double dx = (b.x - a.x) / len, dy = (b.y - a.y) / len;
  double nx = dy, ny = -dx;  // outward for a clockwise quad with y down
  // The short ends of a sliver (a marker turned far) come out of the
  // blurred, thresholded hole round, and the quad's corners cut across
  // them: the side found there is askew. Probed along the long sides
  // instead, the points land on the true end whatever its coarse slant.
  // Its corners, blurred round, would pull the few points such an end has:
  // those are taken from its middle half only.
  double t_first = 0.12, t_span = 0.76;
  int count = std::clamp(static_cast<int>(len / 1.5), 4, kMaxEdgePoints);
  bool sliver_end = false;
  {
    const Point2 prev = q[static_cast<std::size_t>((side + 3) % 4)];
    const Point2 next = q[static_cast<std::size_t>((side + 2) % 4)];
    const Point2 along_long = (a - prev) + (b - next);
    const double long_len = 0.5 * (distance(a, prev) + distance(b, next));
    if (len < kSliverEnd * long_len) {
      const double l = std::hypot(along_long.x, along_long.y);
      nx = along_long.x / l;
      ny = along_long.y / l;
      t_first = 0.25;
      t_span = 0.5;
      count = std::max(count, 6);
      sliver_end = true;
    }
  }
  // A cell's size across this side, at either end: foreshortening makes it
  // differ from side to side and along a side.
  const double cell_a = distance(q[static_cast<std::size_t>((side + 3) % 4)], a) / kInnerSide;
  const double cell_b = distance(b, q[static_cast<std::size_t>((side + 2) % 4)]) / kInnerSide;
  constexpr double step = 0.5;
  EdgePoint* pts = edge_points_[static_cast<std::size_t>(side)].data();
  int used = 0;
  const bool fitting = mode == EdgeMode::fit_profile && !sliver_end;
  const double side_cell = 0.5 * (cell_a + cell_b);
  // With the code known, points within 0.15 of a cell of a boundary
  // between cells are left out (below). One point per 1.5 px leaves a side
  // of 1.5 px cells six, half of them there, and the second pass then
  // failed for want of points beyond 2.7 m: three per cell keep two. From
  // 3 px a cell, one per 1.5 px is as many.
  if (id && side_cell < kResolvedCells) count = std::max(count, kIdEdgePoints);
  int fit_steps = 0;
  double fit_reach_in = 0;
  if (fitting) {
    for (auto& prof : segment_profile_) prof.fill(0);
    segment_base_.fill({0, 0});
    segment_count_.fill(0);
  }
  std::array<float, 64> profile{};
  for (int k = 0; k < count; ++k) {
    // Stay clear of the corners, where the line turns.
    const double t = t_first + t_span * (k + 0.5) / count;
    const double px = a.x + t * (b.x - a.x), py = a.y + t * (b.y - a.y);
    const double cell_px = (1 - t) * cell_a + t * cell_b;
    bool white_beyond = false;
    const bool by_profile = mode == EdgeMode::classify_by_profile || mode == EdgeMode::fit_profile;
    if (id) {
      // Cells along a side follow the reading order, the same on every side.
      const double along = 0.5 + kInnerSide * t;
      const double frac = along - std::floor(along);
      if (frac < 0.15 || frac > 0.85) continue;  // two cells share the blur here
      const int bit = 7 - std::clamp(static_cast<int>(along), 0, 7);
      white_beyond = (*id >> bit) & 1;
    }
    // Inward as far as the coarse quad may be off; outward past the line's
    // far side (half a cell) and its blur.
    // The quad is refined already (a mode past the first step, or a code read): a tight window.
    const bool near = (mode != EdgeMode::step && mode != EdgeMode::step_wide) || id.has_value();
    const double reach_in = fitting ? kProfileReach + 1.0
                            : near  ? std::max(1.0, 0.5 * cell_px)
                                    : std::clamp(1.2 * cell_px, 1.5, 2.0 + decimate_);
    const double reach_out = fitting ? kProfileReach + 1.5 * side_cell + 0.5
                             : near  ? 0.75 * cell_px + 1.5
                             : mode == EdgeMode::step_wide
                                 ? 2.0 * cell_px + 1.0 + 0.5 * decimate_
                                 : std::clamp(1.1 * cell_px + 1.0 + 0.5 * decimate_, 1.5, 3.0 + decimate_);
    const int n_steps = std::min(static_cast<int>((reach_in + reach_out) / step) + 1, 64);
    if (!sample_profile(full_, {px, py}, {nx, ny}, -reach_in, step, n_steps, profile.data())) continue;
    if (fitting) {
      // Summed per segment of the side and fitted below: the cells
      // beyond the line differ from point to point, but the model's level
      // for them is free, and the sum of profiles is the profile of their
      // mean. A few fits instead of one per point, each on less noise.
      const auto seg = static_cast<std::size_t>(k * kProfileSegments / count);
      for (int i = 0; i < n_steps; ++i)
        segment_profile_[seg][static_cast<std::size_t>(i)] += profile[static_cast<std::size_t>(i)];
      segment_base_[seg] = segment_base_[seg] + Point2{px, py};
      ++segment_count_[seg];
      fit_steps = n_steps;
      fit_reach_in = reach_in;
      continue;
    }
    auto P = [&](int i) { return static_cast<double>(profile[static_cast<std::size_t>(i)]); };
    // The steepest light-to-dark step going outward.
    int best = -1;
    double best_drop = 0;
    for (int s = 0; s + 1 < n_steps; ++s) {
      if (P(s) - P(s + 1) > best_drop) {
        best_drop = P(s) - P(s + 1);
        best = s;
      }
    }
    if (best < 0 || best_drop < 2.0) continue;
    // The whole step: from where the profile starts falling to where it stops.
    const double floor_drop = 0.05 * best_drop;
    int lo = best, hi = best;
    while (lo > 0 && P(lo - 1) - P(lo) > floor_drop) --lo;
    while (hi + 2 < n_steps && P(hi + 1) - P(hi + 2) > floor_drop) ++hi;
    double off = 0;
    int peak = hi + 1;
    while (peak + 1 < n_steps && P(peak + 1) >= P(peak)) ++peak;
    if (by_profile) {
      // Without the code, the profile tells: the line alone (a white cell
      // beyond) is a dip about half a cell wide plus the blur, that rises
      // again; the line merged with a black cell is three times wider.
      const double valley = P(hi + 1);
      const double half = valley + 0.5 * (std::min(P(lo), P(peak)) - valley);
      int width = 0;
      for (int i = lo; i <= peak; ++i) width += P(i) < half;
      white_beyond = P(peak) - valley > 0.3 * (P(lo) - valley) && width * step <= 1.0 * cell_px + 0.5;
    }
    if (white_beyond && cell_px < kThinLineCells) {
      const double ref = std::min(P(lo), P(peak));
      double sum = 0, moment = 0;
      for (int i = lo; i <= peak; ++i) {
        const double depth = std::max(0.0, ref - P(i));
        sum += depth;
        moment += depth * i;
      }
      if (sum <= 0) continue;
      off = -reach_in + (moment / sum) * step - 0.25 * cell_px;
    } else {
      double sum = 0, moment = 0;
      for (int i = lo; i <= hi; ++i) {
        const double drop = P(i) - P(i + 1);
        sum += drop;
        moment += drop * (i + 0.5);
      }
      off = -reach_in + (moment / sum) * step;
    }
    pts[used++] = {px + off * nx, py + off * ny, best_drop};
  }
  if (fitting) {
    for (std::size_t seg = 0; seg < kProfileSegments; ++seg) {
      const int m = segment_count_[seg];
      if (m == 0) continue;
      std::array<float, 64>& prof = segment_profile_[seg];
      for (int i = 0; i < fit_steps; ++i) prof[static_cast<std::size_t>(i)] /= static_cast<float>(m);
      double e = 0;
      if (!fit_edge_profile(prof.data(), fit_steps, -fit_reach_in, step, side_cell, e)) continue;
      const Point2 base = (1.0 / m) * segment_base_[seg];
      pts[used++] = {base.x + e * nx, base.y + e * ny, static_cast<double>(m)};
    }
  }
  return used;
}

// Gauss-Newton on the edge profile: steps of at most kProfileMaxStep (the
// model is linear in the edge only over a fraction of the blur), until a step
// is under kProfileConverged (a fiftieth of a cell at the smallest cells
// read), in at most kProfileIterations steps (from within a pixel of the
// answer, it converges in two or three).
constexpr double kProfileMaxStep = 0.4;
constexpr double kProfileConverged = 0.03;
constexpr int kProfileIterations = 4;
// How much darker than the hole (grey levels) a fitted line must be: about
// four times the sensor noise, so that noise alone does not make a line.
constexpr double kMinLineContrast = 8.0;

// The edge in a profile across a side, sampled outward from s0 every
// `step` pixels: the offset e at which the hole (level H) meets the line
// (half a cell, level L), followed by the ring cell (a cell, level B:
// black, white or between) and whatever lies outside (level O), all
// blurred by the lens, the pixel and the sampling (profile_sigma_). The
// step's centroid is biased where the cell beyond is white and the cells
// are small (the line alone is then a dip barely darker than its blur,
// cut short by the cell), and classifying each profile as one case or the
// other fails below about two pixels a cell; this model needs neither.
bool Frame8Detector::fit_edge_profile(const float* profile, int n, double s0, double step, double cell_px,
                                      double& e) const {
  const double inv_sigma = 1.0 / profile_sigma_;
  const double w = 0.5 * cell_px, c = cell_px;
  const detail::NormalTable& table = detail::normal_table();
  // Gauss-Newton over the four levels and the edge together, from the
  // edge as measured (within a fraction of a pixel of the answer). The
  // levels start from the profile: the hole where it begins, the line at
  // its darkest, the cell and the outside at the hole's level.
  double p[5] = {};  // hole, line - hole, cell - hole, outside - hole, edge
  p[0] = 0.5 * (profile[0] + profile[1]);
  p[1] = *std::min_element(profile, profile + n) - p[0];
  e = 0;
  constexpr int k = 5;
  for (int iter = 0; iter < kProfileIterations; ++iter) {
    double a[5][5] = {}, g[5] = {};  // lower triangle of J'J, and J'r
    for (int i = 0; i < n; ++i) {
      const double x = s0 + i * step - e;
      double f0 = 0, f1 = 0, f2 = 0, d0 = 0, d1 = 0, d2 = 0;
      table.at(-x * inv_sigma, f0, d0);
      table.at((w - x) * inv_sigma, f1, d1);
      table.at((w + c - x) * inv_sigma, f2, d2);
      const double j[5] = {1.0, f1 - f0, f2 - f1, 1.0 - f2,
                           inv_sigma * (p[1] * (d1 - d0) + p[2] * (d2 - d1) - p[3] * d2)};
      const double r = profile[i] - (p[0] + p[1] * j[1] + p[2] * j[2] + p[3] * j[3]);
      // Unrolled: this is most of the fit's time.
#pragma GCC unroll 5
      for (int u = 0; u < k; ++u) {
        g[u] += r * j[u];
#pragma GCC unroll 5
        for (int v = 0; v <= u; ++v) a[u][v] += j[u] * j[v];
      }
    }
    for (int u = 0; u < 4; ++u) a[u][u] += kProfileRidge;
    a[4][4] *= 1.0 + 1e-3;
    // Cholesky in place, then the two triangular solves.
    for (int u = 0; u < k; ++u) {
      for (int v = 0; v <= u; ++v) {
        double sum = a[u][v];
        for (int q = 0; q < v; ++q) sum -= a[u][q] * a[v][q];
        if (u == v) {
          if (!(sum > 0)) return false;
          a[u][u] = std::sqrt(sum);
        } else {
          a[u][v] = sum / a[v][v];
        }
      }
    }
    double d[5] = {};
    for (int u = 0; u < k; ++u) {
      double sum = g[u];
      for (int q = 0; q < u; ++q) sum -= a[u][q] * d[q];
      d[u] = sum / a[u][u];
    }
    for (int u = k; u-- > 0;) {
      double sum = d[u];
      for (int q = u + 1; q < k; ++q) sum -= a[q][u] * d[q];
      d[u] = sum / a[u][u];
    }
    for (int u = 0; u < 4; ++u) p[u] += d[u];
    const double de = std::clamp(d[4], -kProfileMaxStep, kProfileMaxStep);
    e += de;
    if (std::abs(de) < kProfileConverged) break;
  }
  return std::isfinite(e) && std::abs(e) <= kProfileReach && -p[1] >= kMinLineContrast;
}

// The line of side `side` of quad `from`, through its edge points
// (edge_points_[side], edge_count_[side]).
Rejection Frame8Detector::fit_side(const std::array<Point2, 4>& from, int side, EdgeMode mode, std::optional<int> id,
                                   double cell_px, Line& line) {
  auto& n = edge_count_[static_cast<std::size_t>(side)];
  n = collect_edge_points(from, side, mode, id);
  if (n < 3) return Rejection::few_edge_points;
  if (!fit_line(edge_points_[static_cast<std::size_t>(side)].data(), n, std::max(0.6, 0.25 * cell_px), line)) {
    return Rejection::no_edge_line;
  }
  return Rejection::none;
}

// Refines the four sides from a quad; the inner corners in `inner`.
Rejection Frame8Detector::refine_sides(const std::array<Point2, 4>& from, EdgeMode mode, std::optional<int> id,
                                       double cell_px, std::array<Point2, 4>& inner) {
  std::array<Line, 4> lines{};
  for (int side = 0; side < 4; ++side) {
    Line& line = lines[static_cast<std::size_t>(side)];
    Rejection why = fit_side(from, side, mode, id, cell_px, line);
    // A rounded frame's inner roll, turned towards the camera, shows as a
    // band lighter than the hole between the hole's light component and
    // the line, parted from it by the roll's shaded foot: the line lies up
    // to two cells beyond the quad's side there, past the step's reach.
    if ((why == Rejection::few_edge_points || why == Rejection::no_edge_line) && mode == EdgeMode::step && !id) {
      if (fit_side(from, side, EdgeMode::step_wide, id, cell_px, line) == Rejection::none) {
        why = Rejection::none;
        reached_wide_ = true;
      }
    }
    if (why != Rejection::none) return why;
  }
  for (int i = 0; i < 4; ++i) {
    if (!intersect(lines[static_cast<std::size_t>((i + 3) % 4)], lines[static_cast<std::size_t>(i)],
                   inner[static_cast<std::size_t>(i)])) {
      return Rejection::parallel_sides;
    }
    if (corner_moved(inner[static_cast<std::size_t>(i)], from[static_cast<std::size_t>(i)], cell_px)) {
      return Rejection::corner_moved;
    }
  }
  return Rejection::none;
}

// With a camera: fit the same edge points in undistorted normalized
// coordinates (straight lines there), then map back through the lens.
Rejection Frame8Detector::refit_undistorted(int rotation, Detection& det) {
  const CameraModel& cam = *config_.camera;
  std::array<Line, 4> lines{};
  for (int side = 0; side < 4; ++side) {
    auto& pts = edge_points_[static_cast<std::size_t>(side)];
    const int n = edge_count_[static_cast<std::size_t>(side)];
    for (int i = 0; i < n; ++i) {
      if (pts[static_cast<std::size_t>(i)].w <= 0) continue;
      const Point2 p =
          cam.pixel_to_normalized({pts[static_cast<std::size_t>(i)].x, pts[static_cast<std::size_t>(i)].y});
      pts[static_cast<std::size_t>(i)].x = p.x;
      pts[static_cast<std::size_t>(i)].y = p.y;
    }
    // Outliers were dropped in pixel space already; no second rejection.
    if (!fit_line(pts.data(), n, std::numeric_limits<double>::infinity(), lines[static_cast<std::size_t>(side)])) {
      return Rejection::no_edge_line;
    }
  }
  std::array<Point2, 4> inner_n{};
  for (int i = 0; i < 4; ++i) {
    if (!intersect(lines[static_cast<std::size_t>((i + 3) % 4)], lines[static_cast<std::size_t>(i)],
                   inner_n[static_cast<std::size_t>(i)])) {
      return Rejection::parallel_sides;
    }
  }
  Homography Hn;
  if (!Homography::from_unit_square(inner_n, Hn)) return Rejection::degenerate_quad;
  return report(grid_map(Hn), rotation, det);
}

}  // namespace markerd::detector::frame8
