// Stage 4b, the grey model: the ring's black and white levels from its own
// cells (2-means seeded by the corners), and the contrast between them.

#include "frame8/detector.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace markerd::detector::frame8 {

Rejection Frame8Detector::fit_grey_model(CellSize cell_size, RingRead& r) const {
  // Seeded by the corners: three black, one white.
  // With a side hidden, two corners are left, perhaps both black: then
  // the lightest cell stands in for the white seed.
  const auto& corner = r.corner;
  int white_corner = -1;
  for (int k = 0; k < 4; ++k) {
    if (corner[static_cast<std::size_t>(k)].valid &&
        (white_corner < 0 ||
         corner[static_cast<std::size_t>(k)].mean > corner[static_cast<std::size_t>(white_corner)].mean)) {
      white_corner = k;
    }
  }
  if (white_corner < 0) return Rejection::white_corner_count;
  double black = 0;
  int black_seeds = 0;
  for (int k = 0; k < 4; ++k) {
    if (k == white_corner || !corner[static_cast<std::size_t>(k)].valid) continue;
    black += corner[static_cast<std::size_t>(k)].mean;
    ++black_seeds;
  }
  if (black_seeds == 0) return Rejection::white_corner_count;
  black /= black_seeds;
  double white = corner[static_cast<std::size_t>(white_corner)].mean;
  if (r.hidden.side >= 0) {
    for (const auto& edge : r.cell) {
      for (const auto& c : edge) {
        if (c.valid) white = std::max(white, static_cast<double>(c.mean));
      }
    }
  }
  for (int iter = 0; iter < 3; ++iter) {
    const double thr = 0.5 * (black + white);
    double sb = 0, sw = 0;
    int nb = 0, nw = 0;
    auto add = [&](const CellSample& c) {
      if (!c.valid) return;
      if (c.mean < thr) {
        sb += c.mean;
        ++nb;
      } else {
        sw += c.mean;
        ++nw;
      }
    };
    for (const auto& c : corner) add(c);
    for (const auto& edge : r.cell) {
      for (const auto& c : edge) add(c);
    }
    if (nb == 0 || nw == 0) return Rejection::one_grey_level;
    black = sb / nb;
    white = sw / nw;
  }
  r.white_corner = white_corner;
  r.black = black;
  r.white = white;
  r.contrast = white - black;
  // Under the threshold's own offset a few times over, or 20 grey levels,
  // the ring is no printed black and white: clutter mostly ends here.
  if (r.contrast < 3.0 * config_.frame8.threshold_offset || r.contrast < 20) return Rejection::no_contrast;
  // Ink reflects a tenth of what paper does or less; glare and a camera's
  // black offset may lift it to half the white cells' level, and the blur
  // a share of the rest, that of a lone black cell's centre, for cells of a
  // pixel or two (kInkShare + (1 - kInkShare) * erfc(w / (2 sqrt 2 sigma))).
  // bench_accuracy's reads (paper, print margin, defocus disc, JPEG with
  // shot noise, socket and switch frames, covered sides; 0.3 to 3.0 m, yaw
  // to 80 deg) reach 0.52 at 1.5 px a cell under the disc (the bound there
  // 0.66) and 0.42 from three pixels (0.52). The grout between tiles, read
  // as id 126 with the lines' crossings for its black cells, gives 0.5 to
  // 0.9: a grey pattern on a grey ground, not a print.
  constexpr double kInkShare = 0.5;
  const double lift = std::erfc(cell_size.narrow / (2 * std::numbers::sqrt2 * profile_sigma_));
  if (black > (kInkShare + (1 - kInkShare) * lift) * white) return Rejection::grey_ink;
  r.thr = 0.5 * (black + white);
  // Blur takes up to half the contrast of a lone cell under two pixels wide:
  // there a weaker read still counts as a vote. And under four: a blur of a
  // pixel (a Gaussian of 0.6 px, or a lens out of focus, a disc of 1.2 px)
  // reaches a quarter cell into a 3 px cell from each side, where its
  // samples lie, and with the stricter share a fifth of the markers at 3.1
  // to 3.4 px a cell had too few votes (bench_accuracy --blur-model disc
  // --margin 10, 100 frames a point: 81 to 91% at 1.20 to 1.35 m, 100% at
  // 1.0 and 1.4 m; 98 to 100% with this).
  constexpr double kConfidentCells = 4.0;
  r.confident = cell_size.narrow >= kConfidentCells ? 0.3 : 0.1;
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
