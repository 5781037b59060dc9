// Stage 4a, the ring cells: sampled through the homography and, where the
// blur mixes them, unmixed.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "normal_table.hpp"

namespace markerd::detector::frame8 {

// Samples a ring cell at its centre; where cells are resolved, at four
// points around the centre instead (less noise, and a cell that is not one
// colour all over shows itself).
CellSample Frame8Detector::sample_cell(const Homography& H, frame8::Cell cell, double cell_px) const {
  CellSample out;
  const double cx = cell.col + 0.5, cy = cell.row + 0.5;
  if (cell_px < kResolvedCells) {
    const Point2 p = grid_point(H, cx, cy);
    out.valid = sample(full_, p.x, p.y, out.mean);
    out.lo = out.hi = out.mean;
    return out;
  }
  // Four samples, a quarter cell from the cell's edges along the ring and
  // 0.3 and 0.4 cell from its inner and outer edges across it: glued on a
  // cover frame, the print's outer few millimetres bend over the frame's
  // outer roll (3 of an 8 mm cell on an 86 mm socket frame), shaded, and
  // on a frame turned away the cells' outer quarters read grey. (Nearer
  // the line than 0.3 cell, the blur darkens a white cell of 3 px.)
  auto offsets = [](int index) {
    if (index == 0) return std::array<double, 2>{-0.1, 0.2};  // outer edge at 0
    if (index == frame8::grid - 1) return std::array<double, 2>{-0.2, 0.1};
    return std::array<double, 2>{-0.25, 0.25};
  };
  const auto along_x = offsets(cell.col), along_y = offsets(cell.row);
  float sum = 0;
  out.lo = 255;
  out.hi = 0;
  for (int k = 0; k < 4; ++k) {
    const Point2 p = grid_point(H, cx + along_x[(k & 1) ? 1U : 0U], cy + along_y[(k & 2) ? 1U : 0U]);
    float v = 0;
    if (!sample(full_, p.x, p.y, v)) return out;
    sum += v;
    out.lo = std::min(out.lo, v);
    out.hi = std::max(out.hi, v);
  }
  out.mean = sum / 4;
  out.valid = true;
  return out;
}

// unmix_ring()'s Jacobi steps: each spreads a correction one cell along the
// ring, and three reach the neighbours' neighbours, all the blur touches.
constexpr int kUnmixSteps = 3;
// The most a cell's neighbours may weigh against its own share: beyond it
// the Jacobi steps diverge.
constexpr double kMaxNeighbourShare = 0.7;

// Under about three pixels a cell, the blur mixes a ring cell's centre
// sample with what surrounds it: its neighbours along the ring, the black
// line and the hole inward, the background outward. A white cell between
// two black ones (a bit beside a black corner) or against a dark
// background reads grey, on every edge alike, and the repetition code
// cannot correct what all four edges get wrong. The shares are known from
// the cells' size in the image and the blur; the hole and the background
// are sampled clear of the ring, the line is as dark as the black corners,
// and the ring cells are unmixed by a few Jacobi steps.
void Frame8Detector::unmix_ring(const Homography& H, std::array<CellSample, 4>& corner,
                                std::array<std::array<CellSample, 8>, 4>& cell) const {
  constexpr int kRing = 36;
  struct Mix {
    double self = 1, prev = 0, next = 0, line = 0, known = 0;  // known: hole and outside, sampled
  };
  std::array<CellSample*, kRing> ring{};
  std::array<frame8::Cell, kRing> where{};
  // Clockwise: C0, the top edge's bits 7..0, C1, the right edge's, C2, ...
  for (int k = 0; k < 4; ++k) {
    const auto at = static_cast<std::size_t>(9 * k);
    ring[at] = &corner[static_cast<std::size_t>(k)];
    where[at] = frame8::corner_cell(k);
    for (int b = 7; b >= 0; --b) {
      const auto i = at + static_cast<std::size_t>(8 - b);
      ring[i] = &cell[static_cast<std::size_t>(k)][static_cast<std::size_t>(b)];
      where[i] = frame8::data_cell(k, b);
    }
  }
  const detail::NormalTable& table = detail::normal_table();
  auto cdf = [&](double z) { return table.cdf(z); };
  constexpr int last = frame8::grid - 1;
  std::array<Mix, kRing> mix{};
  std::array<double, kRing> seen{}, value{};
  for (std::size_t i = 0; i < kRing; ++i) {
    if (!ring[i]->valid) continue;
    const frame8::Cell c = where[i];
    const double u = c.col + 0.5, v = c.row + 0.5;
    // The blur in grid units along each axis, at this cell.
    const double sigma_u = profile_sigma_ / distance(grid_point(H, u - 0.5, v), grid_point(H, u + 0.5, v));
    const double sigma_v = profile_sigma_ / distance(grid_point(H, u, v - 0.5), grid_point(H, u, v + 0.5));
    // Per axis: +1 or -1 when the cell lies on the marker's outer edge
    // across that axis (the way out), 0 along the ring.
    const int out_u = c.col == 0 ? -1 : c.col == last ? 1 : 0;
    const int out_v = c.row == 0 ? -1 : c.row == last ? 1 : 0;
    auto outside_point = [&](int out, double sigma) { return out * (0.5 + std::max(0.5, 2 * sigma)); };
    Mix& m = mix[i];
    double outside = 0, hole = 0;
    if (out_u != 0 && out_v != 0) {
      // A corner: out on both axes; inward on each, a ring neighbour; inward
      // on both, the line's corner.
      const double o_u = cdf(-0.5 / sigma_u), s_u = cdf(0.5 / sigma_u) - o_u, in_u = 1 - o_u - s_u;
      const double o_v = cdf(-0.5 / sigma_v), s_v = cdf(0.5 / sigma_v) - o_v, in_v = 1 - o_v - s_v;
      m.self = s_u * s_v;
      const double along_u = in_u * s_v, along_v = s_u * in_v;
      // The ring neighbour in the same row lies along u.
      const frame8::Cell p = where[(i + kRing - 1) % kRing];
      m.prev = p.row == c.row ? along_u : along_v;
      m.next = p.row == c.row ? along_v : along_u;
      m.line = in_u * in_v;
      float a = 0, b = 0;
      const Point2 pa = grid_point(H, u + outside_point(out_u, sigma_u), v);
      const Point2 pb = grid_point(H, u, v + outside_point(out_v, sigma_v));
      if (!sample(full_, pa.x, pa.y, a) || !sample(full_, pb.x, pb.y, b)) continue;
      outside = (1 - (s_u + in_u) * (s_v + in_v)) * 0.5 * (a + b);
    } else {
      // An edge cell: across the ring (out, cell, line, hole), along it
      // (the two neighbours and the cells beyond them, lumped in).
      const bool across_u = out_u != 0;
      const double sa = across_u ? sigma_u : sigma_v, sl = across_u ? sigma_v : sigma_u;
      const int out = across_u ? out_u : out_v;
      const double o = cdf(-0.5 / sa), in_cell = cdf(0.5 / sa) - o, line = cdf(1.0 / sa) - cdf(0.5 / sa);
      const double inner = 1 - o - in_cell - line;
      const double side = cdf(-0.5 / sl);
      m.self = in_cell * (1 - 2 * side);
      m.prev = m.next = in_cell * side;
      m.line = line;
      float a = 0, b = 0;
      const double to_out = outside_point(out, sa), to_hole = -out * (1.0 + std::max(0.5, 2 * sa));
      const Point2 pa = grid_point(H, u + (across_u ? to_out : 0), v + (across_u ? 0 : to_out));
      const Point2 pb = grid_point(H, u + (across_u ? to_hole : 0), v + (across_u ? 0 : to_hole));
      if (!sample(full_, pa.x, pa.y, a) || !sample(full_, pb.x, pb.y, b)) continue;
      outside = o * a;
      hole = inner * b;
    }
    m.known = outside + hole;
    // The steps diverge once the neighbours' shares outweigh the cell's
    // own: cells under a pixel along the ring are left partly mixed.
    const double neighbours = m.prev + m.next;
    if (neighbours > kMaxNeighbourShare * m.self) {
      const double scale = kMaxNeighbourShare * m.self / neighbours;
      m.prev *= scale;
      m.next *= scale;
    }
  }
  for (std::size_t i = 0; i < kRing; ++i) seen[i] = value[i] = ring[i]->mean;
  // The line: first as dark as the darkest sample, then as the black corners unmixed.
  double line = *std::min_element(seen.begin(), seen.end());
  for (int pass = 0; pass < 2; ++pass) {
    for (int iter = 0; iter < kUnmixSteps; ++iter) {
      std::array<double, kRing> next_value{};
      for (std::size_t i = 0; i < kRing; ++i) {
        const Mix& m = mix[i];
        const double nb = m.prev * value[(i + kRing - 1) % kRing] + m.next * value[(i + 1) % kRing];
        next_value[i] = ring[i]->valid ? (seen[i] - nb - m.line * line - m.known) / m.self : seen[i];
      }
      value = next_value;
    }
    std::array<double, 4> corners{value[0], value[9], value[18], value[27]};
    std::sort(corners.begin(), corners.end());
    line = (corners[0] + corners[1] + corners[2]) / 3;
  }
  for (std::size_t i = 0; i < kRing; ++i) {
    if (!ring[i]->valid) continue;
    const auto v = static_cast<float>(std::clamp(value[i], -64.0, 320.0));
    ring[i]->mean = ring[i]->lo = ring[i]->hi = v;
  }
}

// Opposite sides of a marker with cells under kResolvedCells: at most
// this ratio (1.06 for 30 px seen at a focal length of 500 px).
constexpr double kMaxSmallSideRatio = 1.3;
// Opposite sides of any marker: at most this ratio, that of a square's
// edges when it is turned edge-on 1.5 of its size from the lens (at 0.3 m
// an 8 cm marker's is 1.3 at most).
constexpr double kMaxSideRatio = 2.0;

// Reads the ring's cells: sampled in the image through H or, with `model`,
// the ring model's levels. Under kResolvedCells the samples are unmixed.
Rejection Frame8Detector::read_cells(const Homography& H, CellSize cell_size, const frame8::RingModel::Levels* model,
                                     RingRead& r) const {
  auto level = [&](frame8::Cell c) {
    if (!model) return sample_cell(H, c, cell_size.narrow);
    const float v = model->cell[static_cast<std::size_t>(c.row * frame8::grid + c.col)];
    return CellSample{v, v, v, true};
  };
  // Hidden cells are no samples: they say nothing of the code.
  for (int k = 0; k < 4; ++k) {
    auto& c = r.corner[static_cast<std::size_t>(k)];
    if (r.hidden.covers(frame8::corner_cell(k))) {
      c = CellSample{};
      continue;
    }
    c = level(frame8::corner_cell(k));
    if (!c.valid) return Rejection::corner_off_image;
  }
  int valid_cells = 0;
  for (int e = 0; e < 4; ++e) {
    for (int b = 0; b < 8; ++b) {
      auto& c = r.cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      const frame8::Cell where = frame8::data_cell(e, b);
      c = r.hidden.covers(where) ? CellSample{} : level(where);
      valid_cells += c.valid;
    }
  }
  // With a side hidden, its eight cells and up to four of each
  // neighbouring edge's are left out: every bit still has two votes.
  if (valid_cells < (r.hidden.side < 0 ? 24 : 16)) return Rejection::cells_off_image;
  // A square's opposite sides differ in the image by the ratio of their
  // depths, which for a marker of a few dozen pixels is a few percent at
  // any focal length: clutter's slivers and trapezoids differ by far more,
  // and with small cells, unmixed (unmix_ring), can read as a code. Larger
  // ones, by more only where the marker is close: a quad with a side hidden
  // across three keys of a keyboard, 13 px on one side and 73 on the
  // other, read as 131.
  if (cell_size.mean < kMinCells) return Rejection::cells_too_small;
  const double max_ratio = cell_size.mean < kResolvedCells ? kMaxSmallSideRatio : kMaxSideRatio;
  std::array<Point2, 4> outer{};
  for (int k = 0; k < 4; ++k) {
    outer[static_cast<std::size_t>(k)] =
        grid_point(H, (k == 1 || k == 2) ? frame8::grid : 0, k >= 2 ? frame8::grid : 0);
  }
  for (int k = 0; k < 2; ++k) {
    const double a = distance(outer[static_cast<std::size_t>(k)], outer[static_cast<std::size_t>(k + 1)]);
    const double b = distance(outer[static_cast<std::size_t>(k + 2)], outer[static_cast<std::size_t>((k + 3) % 4)]);
    if (std::max(a, b) > max_ratio * std::min(a, b)) return Rejection::sides_unequal;
  }
  if (!model && cell_size.narrow < kResolvedCells) unmix_ring(H, r.corner, r.cell);
  return Rejection::none;
}

// A sample at each data cell's centre. Every id but 0 and 255 has at
// least three of each colour among the 32 (ids 1 and 254: four), but the
// map may be a pixel or two off, and a cell's sample then grey.
bool Frame8Detector::ring_shows_cells(const Eigen::Matrix3d& grid_to_image) const {
  std::array<float, 32> v{};
  std::size_t n = 0;
  for (int side = 0; side < 4; ++side) {
    for (int k = 1; k <= 8; ++k) {
      const Point2 g = side_point(side, k + 0.5, 0.5);
      const Point2 p = map_grid(grid_to_image, g.x, g.y);
      if (!sample(full_, p.x, p.y, v[n])) return false;
      ++n;
    }
  }
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  constexpr float kMinContrast = 40;
  if (*hi - *lo < kMinContrast) return false;
  const float mid = 0.5F * (*lo + *hi);
  const auto light = std::count_if(v.begin(), v.end(), [&](float x) { return x > mid; });
  constexpr int kMinEach = 3;
  return light >= kMinEach && static_cast<int>(v.size()) - light >= kMinEach;
}

}  // namespace markerd::detector::frame8
