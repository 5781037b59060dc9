// Stage 4e, the hole of a paper print: blank paper, nothing printed in it,
// and as light as the paper of the ring's white cells.
//
// Told the print is paper, a quad whose hole shows something dark inside,
// or is darker than the ring's lightest cells, is no marker. The keys of a
// keyboard are light squares between dark gaps with their neighbours for a
// ring, and read as 62, 124 and 126 (a key beside the numeric pad's gap
// read with a side hidden, or read once and its second measurement
// failing), once in about 900 keyboard frames: each key shows its glyph. A
// grey tile in light grout read as 129 is darker than the grout's crossings
// it took for white cells. Untold, a hole may hold a socket's outlet or
// whatever a cut-out hole shows, and neither check applies.

#include <algorithm>
#include <array>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

bool Frame8Detector::hole_is_blank_paper(const Homography& seen, const Homography& H, int hidden_side) const {
  // The line's grey beside each side seen, for the hole's contrast.
  std::array<float, 4 * kSideMiddle.size()> line{};
  std::size_t lines = 0;
  for (int side = 0; side < 4; ++side) {
    if (side == hidden_side) continue;
    for (const double along : kSideMiddle) {
      const Point2 q = grid_point(H, side_point(side, along, kInnerLo - 0.25));
      if (!sample(full_, q.x, q.y, line[lines++])) return false;
    }
  }
  std::nth_element(line.begin(), line.begin() + static_cast<std::ptrdiff_t>(lines / 2),
                   line.begin() + static_cast<std::ptrdiff_t>(lines));
  const float line_level = line[lines / 2];
  // The hole seen, on a grid clear of its edges' blur: a cell in, and two
  // pixels at least.
  const std::array<Point2, 4> q = seen.quad();
  double shortest = distance(q[3], q[0]);
  for (std::size_t i = 0; i + 1 < q.size(); ++i) shortest = std::min(shortest, distance(q[i], q[i + 1]));
  if (!(shortest > 0)) return false;
  const double clear = std::max(1.0 / kInnerSide, 2.0 / shortest);
  if (clear >= 0.4) return true;  // too small a hole to hold anything the blur leaves
  constexpr int kSteps = 12;
  std::array<float, kSteps * kSteps> hole{};
  std::size_t n = 0;
  for (int i = 0; i < kSteps; ++i) {
    for (int j = 0; j < kSteps; ++j) {
      const double u = clear + (1 - 2 * clear) * i / (kSteps - 1), v = clear + (1 - 2 * clear) * j / (kSteps - 1);
      const Point2 p = seen.map(u, v);
      if (!sample(full_, p.x, p.y, hole[n++])) return false;
    }
  }
  // Its darkest samples, a fiftieth of them (noise alone: 0.03 of the
  // contrast at sigma 2), against its median. Covered prints from 0.5 to
  // 2 m, turned to 35 deg, under Gaussian and disc blur: under 0.1 in 446
  // reads; the keys read, 0.26 to 1.08 (their glyphs).
  constexpr double kMaxBlemish = 0.2;
  std::sort(hole.begin(), hole.end());
  const float median = hole[hole.size() / 2], dark = hole[hole.size() / 50];
  const float contrast = median - line_level;
  if (!(contrast > 0 && median - dark <= kMaxBlemish * contrast)) return false;
  // The ring's lightest cells (at their centres, on the sides seen: the
  // tenth lightest of them) are paper too, blurred with their neighbours:
  // never lighter than the hole. On printed markers from 0.3 to 3 m,
  // turned to 80 deg, disc and Gaussian blur, shot noise, bare and with a
  // margin (1,951 reads), the hole's contrast with the line was 0.985 of
  // theirs at least; the tile, 0.84.
  constexpr double kMinLightness = 0.9;
  std::array<float, 4 * frame8::grid> ring{};
  std::size_t cells = 0;
  for (int side = 0; side < 4; ++side) {
    if (side == hidden_side) continue;
    for (int c = 0; c < frame8::grid; ++c) {
      const Point2 p = grid_point(H, side_point(side, c + 0.5, 0.5));
      if (!sample(full_, p.x, p.y, ring[cells++])) return false;
    }
  }
  const auto lightest = ring.begin() + static_cast<std::ptrdiff_t>(cells - 1 - cells / 10);
  std::nth_element(ring.begin(), lightest, ring.begin() + static_cast<std::ptrdiff_t>(cells));
  return contrast >= kMinLightness * (*lightest - line_level);
}

}  // namespace markerd::detector::frame8
