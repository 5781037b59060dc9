// Stage 4, decoding: the code from the ring cells' grey levels, sampled or
// fitted by the ring model.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>
#include <optional>

namespace markerd::frame8 {

// Decides the code from the ring cells' grey levels: sampled in the image,
// or fitted by the ring model when `model` is given.
int Frame8Detector::decode(const Homography& H, CellSize cell_size, Detection& det, int& rotation,
           const frame8::RingModel::Levels* model) const {
  auto level = [&](frame8::Cell c) {
    if (!model) return sample_cell(H, c, cell_size.narrow);
    const float v = model->cell[static_cast<std::size_t>(c.row * frame8::grid + c.col)];
    return CellSample{v, v, v, true};
  };
  std::array<CellSample, 4> corner{};
  std::array<std::array<CellSample, 8>, 4> cell{};
  for (int k = 0; k < 4; ++k) {
    corner[static_cast<std::size_t>(k)] = level(frame8::corner_cell(k));
    if (!corner[static_cast<std::size_t>(k)].valid) return reject(1);
  }
  int valid_cells = 0;
  for (int e = 0; e < 4; ++e) {
    for (int b = 0; b < 8; ++b) {
      auto& c = cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      c = level(frame8::data_cell(e, b));
      valid_cells += c.valid;
    }
  }
  if (valid_cells < 24) return reject(2);
  // A square's opposite sides differ in the image by the ratio of their
  // depths, which for a marker of a few dozen pixels is a few percent at
  // any focal length: clutter's slivers and trapezoids differ by far more,
  // and with small cells, unmixed (unmix_ring), can read as a code.
  if (cell_size.mean < kMinCells) return reject(23);
  if (cell_size.mean < kResolvedCells) {
    std::array<Point2, 4> outer{};
    for (int k = 0; k < 4; ++k) outer[static_cast<std::size_t>(k)] = grid_point(H, (k == 1 || k == 2) ? frame8::grid : 0, k >= 2 ? frame8::grid : 0);
    for (int k = 0; k < 2; ++k) {
      const double a = distance(outer[static_cast<std::size_t>(k)], outer[static_cast<std::size_t>(k + 1)]);
      const double b = distance(outer[static_cast<std::size_t>(k + 2)], outer[static_cast<std::size_t>((k + 3) % 4)]);
      if (std::max(a, b) > kMaxSmallSideRatio * std::min(a, b)) return reject(22);
    }
  }
  if (!model && cell_size.narrow < kResolvedCells) unmix_ring(H, corner, cell);

  // Grey model: 2-means over the ring, seeded by the corners (three black, one white).
  int white_corner = 0;
  for (int k = 1; k < 4; ++k) {
    if (corner[static_cast<std::size_t>(k)].mean > corner[static_cast<std::size_t>(white_corner)].mean) white_corner = k;
  }
  double black = 0;
  for (int k = 0; k < 4; ++k) {
    if (k != white_corner) black += corner[static_cast<std::size_t>(k)].mean;
  }
  black /= 3;
  double white = corner[static_cast<std::size_t>(white_corner)].mean;
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
    for (const auto& edge : cell) {
      for (const auto& c : edge) add(c);
    }
    if (nb == 0 || nw == 0) return reject(3);
    black = sb / nb;
    white = sw / nw;
  }
  const double contrast = white - black;
  F8_TRACE("  grey model black %.1f white %.1f\n", black, white);
  if (contrast < 3.0 * config_.frame8.threshold_offset || contrast < 20) return reject(4);
  const double thr = 0.5 * (black + white);
  auto soft = [&](double v) { return std::clamp((v - thr) / (0.5 * contrast), -1.0, 1.0); };
  // A cell read clearly and, where resolved, one colour all over; otherwise
  // it is an erasure (an occluder's edge, or clutter that is no cell at all).
  // Blur takes up to half the contrast of a lone cell under two pixels wide:
  // there a weaker read still counts as a vote.
  const double kConfident = cell_size.narrow >= kResolvedCells ? 0.3 : 0.1;
  auto clear = [&](const CellSample& c) {
    const double lo = soft(c.lo), hi = soft(c.hi);
    return c.valid && ((lo > kConfident && hi > kConfident) || (lo < -kConfident && hi < -kConfident));
  };

  // Orientation: the one white corner is C1 (top right). Four dark corners
  // are never a marker: that is every dark square frame with a light inside.
  int white_corners = 0;
  for (const auto& c : corner) white_corners += soft(c.mean) > 0;
  F8_TRACE("  corners soft %.2f %.2f %.2f %.2f cell %.2f px\n", soft(corner[0].mean), soft(corner[1].mean), soft(corner[2].mean), soft(corner[3].mean), cell_size.narrow);
  // The bits: soft votes of the four edges, weighted by resolution.
  constexpr double kClearCode = 0.35;
  std::array<double, 4> weight{};
  for (int e = 0; e < 4; ++e) weight[static_cast<std::size_t>(e)] = edge_weight(H, e);
  // The two short edges of a marker turned far have cells of about a
  // pixel along them, blurred into each other, while its two long edges
  // read cleanly: then the short ones have no vote, and their corners are
  // read from their profiles once the code is known. Only for that shape:
  // a lone short edge is no turned marker, and must keep its say.
  int short_side = -1;
  for (int e = 0; e < 2; ++e) {
    const auto s0 = static_cast<std::size_t>(e), s1 = static_cast<std::size_t>(e + 2);
    const auto l0 = static_cast<std::size_t>(e + 1), l1 = static_cast<std::size_t>((e + 3) % 4);
    if (weight[s0] < kVotingEdge && weight[s1] < kVotingEdge && weight[l0] >= 1.0 && weight[l1] >= 1.0) {
      weight[s0] = weight[s1] = 0.0;
      short_side = e;
    }
  }
  F8_TRACE("  weights %.2f %.2f %.2f %.2f\n", weight[0], weight[1], weight[2], weight[3]);
  // Corners decide orientation. Without a clean 3:1 split (an edge covered
  // with its corners) the whitest corner still decides, as the contract
  // says, but only a clearly read code may rely on that.
  std::array<float, 4> sorted{};
  for (int k = 0; k < 4; ++k) sorted[static_cast<std::size_t>(k)] = corner[static_cast<std::size_t>(k)].mean;
  std::sort(sorted.begin(), sorted.end());
  double orientation_clarity = 0.5 * (soft(sorted[3]) - soft(sorted[2]));
  const bool corners_read = white_corners >= 1 && white_corners <= 2 && clear(corner[static_cast<std::size_t>(white_corner)]);
  if (short_side < 0) {
    if (white_corners == 0 || white_corners > 2) return reject(5);
    if (!corners_read) return reject(6);
  }
  // A marker turned far whose corners do not read clearly: its short
  // edges' profiles decide, once the code is known.
  bool by_short_edges = short_side >= 0 && (!corners_read || orientation_clarity < config_.frame8.min_margin);
  int id = 0, corrected = 0, erased = 0;
  std::array<int, 4> outvoted{};  // per edge: its cells the other edges overruled
  double margin = 1.0;
  for (int b = 0; b < 8; ++b) {
    double sum = 0, wsum = 0;
    for (int e = 0; e < 4; ++e) {
      const auto& c = cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      if (!c.valid) continue;
      sum += weight[static_cast<std::size_t>(e)] * soft(c.mean);
      wsum += weight[static_cast<std::size_t>(e)];
    }
    if (wsum <= 0) return reject(7);
    const bool bit = sum > 0;
    int agree = 0, dissent = 0;
    for (int e = 0; e < 4; ++e) {
      const auto& c = cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      if (weight[static_cast<std::size_t>(e)] == 0.0) continue;  // an edge without a vote
      if (!clear(c)) {
        ++erased;
        continue;  // an erasure, not a vote
      }
      if ((soft(c.mean) > 0) == bit) {
        ++agree;
      } else {
        ++dissent;
        ++outvoted[static_cast<std::size_t>(e)];
      }
    }
    F8_TRACE("  bit %d: sum %.2f / %.2f agree %d dissent %d\n", b, sum, wsum, agree, dissent);
    // At most one wrong edge per bit position is correctable; a second is detected.
    if (dissent > 1 || agree < 1 || agree <= dissent) return reject(8);
    corrected += dissent;
    margin = std::min(margin, std::abs(sum) / wsum);
    if (bit) id |= 1 << b;
  }
  // C1 is a whole cell: its two neighbours along the ring (the last cell of
  // the edge before it, the first of the edge after it) never contradict
  // the code. A light blob that merely reaches the spot where C1 is sampled
  // (the diagonal neighbour of a light square in a checkered pattern)
  // spills into both. A neighbour that was itself outvoted, on an edge one
  // colour from end to end, lies under the cover of that whole edge and
  // says nothing; nor does a short edge whose profile placed the corners.
  constexpr double kContradiction = 0.3;
  auto covered = [&](int edge) {
    if (outvoted[static_cast<std::size_t>(edge)] == 0) return false;
    const auto& cells = cell[static_cast<std::size_t>(edge)];
    const bool light = soft(cells[0].mean) > 0;
    return std::all_of(cells.begin(), cells.end(), [&](const CellSample& c) { return clear(c) && (soft(c.mean) > 0) == light; });
  };
  auto contradicts = [&](int edge, bool first_cell) {
    if (covered(edge) || (by_short_edges && weight[static_cast<std::size_t>(edge)] == 0.0)) return false;
    const CellSample& c = cell[static_cast<std::size_t>(edge)][first_cell ? 7U : 0U];
    const bool bit = ((id >> (first_cell ? 7 : 0)) & 1) != 0;
    return c.valid && (bit ? soft(c.mean) < -kContradiction : soft(c.mean) > kContradiction);
  };
  auto c1_contradicted = [&] {
    F8_TRACE("  C1 %d neighbours %.2f (bit0 %d) %.2f (bit7 %d)\n", white_corner, soft(cell[static_cast<std::size_t>((white_corner + 3) % 4)][0].mean), id & 1, soft(cell[static_cast<std::size_t>(white_corner)][7].mean), (id >> 7) & 1);
    return contradicts((white_corner + 3) % 4, false) || contradicts(white_corner, true);
  };
  // Clearly read corners of a marker turned far may still be wrong: the
  // blur mixes each with the background. Its neighbours tell.
  if (short_side >= 0 && !by_short_edges && c1_contradicted()) by_short_edges = true;
  if (by_short_edges) {
    white_corner = white_corner_by_short_edges(H, short_side, id, black, white, orientation_clarity);
    if (white_corner < 0) return reject(25);
  }
  if (c1_contradicted()) return reject(kC1Contradicted);
  rotation = (white_corner + 3) % 4;
  // Where cells are resolved, more erasures than one edge's worth is not
  // a marker with an edge covered but something else.
  if (cell_size.mean >= kResolvedCells && erased > 8) return reject(10);
  if (margin < config_.frame8.min_margin) return reject(11);
  // Outvoting most of an edge (a covered edge) is only believable when the
  // other three read clearly.
  if (corrected >= 4 && margin < kClearCode) return reject(12);
  // A marker of about fifteen pixels with two bits or more outvoted is as
  // likely a dark blob in clutter whose unmixed ring (unmix_ring) shows a
  // light cell or two: measured, 3 false detections in 3000 cluttered
  // scenes without this check, 2 of 40 right reads at 3 m refused with it.
  if (cell_size.mean < kTinyCells && corrected >= 2) return reject(24);
  // Ids 0 and 255 have no structure along the ring: a dark ring with one
  // light corner, or a light ring with three dark ones. Under about three
  // pixels a cell, the bowl of a printed letter looks exactly like that;
  // these two are reported only when asked for, and only where their cells
  // can be verified.
  if (id == 0 || id == 255) {
    if (!config_.frame8.uniform_ids || cell_size.narrow < kResolvedCells) return reject(13);
  }
  // A covered edge is one leniency already: it does not get a second.
  if (orientation_clarity < config_.frame8.min_margin && (margin < kClearCode || corrected >= 4)) return reject(14);
  // Nor below about three pixels a cell, where a covered strip cannot be
  // told from a checkered surround lighting two corners.
  if (orientation_clarity < config_.frame8.min_margin && cell_size.narrow < kResolvedCells) return reject(21);
  margin = std::min(margin, std::max(orientation_clarity, 0.0));

  // The line must be there on every side: across it, from the hole's edge
  // out to the ring, the profile dips well under the white cells' level.
  // A light bar between two dark strokes (a sliver quad whose long sides
  // face plain background) has no such dip along its long sides. Where
  // cells are unresolved the blur lifts the half-cell line towards the
  // white of its neighbours, so the bar there is lower: it follows the
  // line's width in pixels on that side, which foreshortening narrows.
  for (int side = 0; side < 4; ++side) {
    if (model) {
      // The model measured the line's own level, free of the blur.
      if (soft(model->line[static_cast<std::size_t>(side)]) > -kClearLine) return reject(19);
      continue;
    }
    const double line_px = distance(grid_point(H, side_point(side, 5, kInnerLo)), grid_point(H, side_point(side, 5, frame8::line_outer)));
    const double line_ceiling = std::clamp(0.8 - 0.9 * (line_px - 0.6), -kConfident, 0.8);
    int dark = 0, total = 0;
    for (int k = 0; k < 7; ++k) {
      const double along = kInnerLo + 0.5 + k;
      float darkest = 255;
      bool any = false;
      for (const double across : {1.6, 1.45, 1.3, 1.15, 1.0, 0.85}) {
        const Point2 p = grid_point(H, side_point(side, along, across));
        float v = 0;
        if (!sample(full_, p.x, p.y, v)) continue;
        darkest = std::min(darkest, v);
        any = true;
      }
      if (!any) continue;
      ++total;
      dark += soft(darkest) < line_ceiling;
    }
    if (total < 4 || dark < 0.5 * total) return reject(18);
  }

  // The line must be dark where it is resolved, all around and at each of
  // its four corners: a light square among the bits of a checkered pattern
  // reads as id 0 when a diagonal neighbour lands on C1, but that neighbour
  // also covers the line's corner.
  // A marker turned far keeps a line of a pixel or more across its narrow
  // direction, enough to be checked.
  if (cell_size.mean >= kResolvedCells && cell_size.narrow >= kCheckedLineCells) {
    static constexpr std::array<Point2, 4> kLineCorners{{{1.25, 1.25}, {8.75, 1.25}, {8.75, 8.75}, {1.25, 8.75}}};
    for (const Point2& g : kLineCorners) {
      float v = 0;
      const Point2 p = grid_point(H, g.x, g.y);
      if (!sample(full_, p.x, p.y, v) || soft(v) > -kConfident) return reject(15);
    }
    int dark = 0, total = 0;
    double line_sum = 0;
    for (int k = 0; k < 7; ++k) {
      const double along = kInnerLo + 0.5 + k;
      for (int side = 0; side < 4; ++side) {
        float v = 0;
        const Point2 p = grid_point(H, side_point(side, along, 1.25));
        if (!sample(full_, p.x, p.y, v)) continue;
        ++total;
        dark += v < thr;
        line_sum += v;
      }
    }
    if (total < 14 || dark < 0.75 * total) return reject(16);
    // The line and the black cells are the same ink. A thin dark outline
    // around a light patch, read against a mid-grey surround taken for
    // "black" cells, is not.
    if (std::abs(line_sum / total - black) > 0.3 * contrast) return reject(17);
  }

  det.family = Family::frame8;
  det.id = id;
  det.bits_corrected = corrected;
  det.margin = margin;
  return kRead;
}

// Reads cells too small to sample from the blur model of the ring, given
// why reading them from samples failed (`sampled`); with the map moved to
// where the model fits best, H follows it.
bool Frame8Detector::read_by_model(Homography& H, CellSize cell_size, int sampled, Detection& det, int& rotation) {
  // The model costs a few hundred microseconds: only for small cells, and
  // only for what has a ring of dark and light cells (clutter mostly
  // fails on contrast already).
  if (!config_.frame8.model_small_cells || cell_size.narrow >= kResolvedCells || sampled <= kNoContrast) return false;
  F8_TRACE("  model fit, sampled check %d, narrow cell %.2f px\n", sampled, cell_size.narrow);
  Eigen::Matrix3d M = grid_map(H);
  // First the levels where the quad puts the cells (a tenth of the cost):
  // enough when the quad is right, and to turn away what has no line.
  if (!ring_model_.fit(full_, M, config_.frame8.blur_sigma_px, false, levels_)) return false;
  const int unaligned = decode(H, cell_size, det, rotation, &levels_);
  if (unaligned == kRead) return true;
  // A light cell beside C1 that the code says is dark is the mark of a
  // light patch in a checkered surround, not of a ring a fraction of a
  // cell off: not worth moving the map for.
  if (unaligned <= kNoContrast || unaligned == kC1Contradicted) return false;
  F8_TRACE("  model alignment, unaligned check %d\n", unaligned);
  if (!ring_model_.fit(full_, M, config_.frame8.blur_sigma_px, true, levels_)) return false;
#ifdef FRAME8_DEBUG
  F8_TRACE("  model rms %.1f line %.0f %.0f %.0f %.0f hole %.0f\n", levels_.rms_residual, levels_.line[0], levels_.line[1], levels_.line[2], levels_.line[3], levels_.hole);
  for (int e = 0; e < 4; ++e) {
    F8_TRACE("   edge %d:", e);
    for (int b = 7; b >= 0; --b) { const auto c = frame8::data_cell(e, b); F8_TRACE(" %4.0f", levels_.cell[static_cast<std::size_t>(c.row * 10 + c.col)]); }
    const auto k = frame8::corner_cell(e); F8_TRACE("  corner %4.0f\n", levels_.cell[static_cast<std::size_t>(k.row * 10 + k.col)]);
  }
#endif
  const Homography aligned = Homography::from_grid_map(M);
  if (decode(aligned, cell_size, det, rotation, &levels_) != kRead) return false;
  H = aligned;
  return true;
}

}  // namespace markerd::frame8
