// Stage 4e, structural checks: what the code alone does not rule out. Each
// check names the clutter that reads as a code without it.

#include "frame8/detector.hpp"

#include <algorithm>

namespace markerd::detector::frame8 {

// Cells under this many pixels with two bits outvoted are as likely a dark
// blob in clutter (see the check).
constexpr double kTinyCells = 1.5;
// From this many pixels per cell across, the line's darkness is checked:
// narrower, the blur lifts it towards the cells beside it.
constexpr double kCheckedLineCells = 2.0;
// How dark (soft level, -1 = black) the ring model must find the line.
constexpr double kClearLine = 0.5;
// The least margin of a read in the second look (a frame in which the
// first found no marker, segmented again with light ridges kept whole),
// whatever min_margin allows, from kSecondLookClearCells up and for the
// near-uniform ids at any size: its rule makes holes of more of a
// texture's light shapes, and what those read is read faintly (keys and
// windows as 124, 62 and 24 at 2.5 to 3.3 px a cell, margins 0.23 to 0.35;
// window panes and a tile as 126 at 1.4 to 2 px, 0.18 to 0.34: some 1 in
// 3,000 marker-free frames). From 2 px a cell the first look reads a flat
// print, and what the second is there for mostly reads clearly (a socket
// frame from 1.8 to 2.5 m facing, 0.45 and up; a cut-out hole over black,
// 0.55 and up), but socket and switch frames turned 50 to 60 deg from 0.95
// m read a quarter of theirs under it (4 to 12 points there). Under 2 px
// the second look also finds far prints whose line the first look broke,
// a quarter of them under it.
constexpr double kSecondLookMargin = 0.4;
constexpr double kSecondLookClearCells = 2.0;

namespace {

// Whether every outvoted cell lies under one cover: on one edge, or on the
// edges beside it next to its corners. Edge e's bit 0 ends at the corner
// it shares with edge e + 1, whose bit 7 begins there (the bits run
// clockwise).
bool outvoted_by_one_cover(const RingRead& r) {
  constexpr std::uint8_t kFirstCell = 0x80, kLastCell = 0x01;
  for (std::size_t e = 0; e < 4; ++e) {
    const std::uint8_t next = r.outvoted[(e + 1) % 4], opposite = r.outvoted[(e + 2) % 4],
                       prev = r.outvoted[(e + 3) % 4];
    if (opposite == 0 && (next & ~kFirstCell) == 0 && (prev & ~kLastCell) == 0) return true;
  }
  return false;
}

}  // namespace

Rejection Frame8Detector::check_structure(const Homography& H, CellSize cell_size,
                                          const frame8::RingModel::Levels* model, RingRead& r) const {
  // A code whose weakest bit is read this clearly (soft units) may lean on
  // one leniency: an edge outvoted (a covered edge), or an orientation from
  // the whitest corner alone.
  constexpr double kClearCode = 0.35;
  // Where cells are resolved, more erasures than one edge's worth is not
  // a marker with an edge covered but something else.
  if (cell_size.mean >= kResolvedCells && r.erased > 8) return Rejection::many_erasures;
  if (r.margin < config_.frame8.min_margin) return Rejection::low_margin;
  // Outvoting most of an edge (a covered edge) is only believable when the
  // other three read clearly.
  if (r.corrected >= 4 && r.margin < kClearCode) return Rejection::covered_edge_unclear;
  // A cover outvotes one edge, and at most the cell at each end of the edges
  // beside it: two cells outvoted on a second edge are a second leniency (a
  // light bar in clutter beside a dark shape read so, as id 192, with six
  // cells of a barely resolved edge and two of a resolved one outvoted).
  if (r.corrected >= 4) {
    int most = 0;
    for (int e = 1; e < 4; ++e) most = r.outvoted_cells(e) > r.outvoted_cells(most) ? e : most;
    for (int e = 0; e < 4; ++e) {
      if (e != most && r.outvoted_cells(e) >= 2) return Rejection::covered_edge_unclear;
    }
  }
  // Resolved cells are read wrong by a cover, not by noise: a cover over
  // one edge outvotes that edge's cells, and at most the cell next to each
  // of its corners on the edges beside it. Cells outvoted anywhere else
  // are a second fault, from a ring that is not there: clutter, or a grid
  // measured a cell off.
  if (cell_size.mean >= kResolvedCells && r.corrected > 0 && !outvoted_by_one_cover(r)) {
    return Rejection::outvoted_scattered;
  }
  // A marker of about fifteen pixels with two bits or more outvoted is as
  // likely a dark blob in clutter whose unmixed ring (unmix_ring) shows a
  // light cell or two: measured, 3 false detections in 3000 cluttered
  // scenes without this check, 2 of 40 right reads at 3 m refused with it.
  if (cell_size.mean < kTinyCells && r.corrected >= 2) return Rejection::tiny_cells_corrected;
  // The near-uniform ids are the rings of a grid's squares (frame8.hpp),
  // and a square beside a row of another colour reads as one with an edge
  // outvoted, as a marker with that edge covered would. Under 3 px a cell
  // such a read is not taken: keyboards and window grids read so as 126
  // and 129 once the second pass had points enough to agree. From 3 px a
  // marker with such an id and an edge covered is still read (ids 1 and
  // 254 at 0.5 m), and a grid's square read so is left to the other checks.
  if (frame8::near_uniform(r.id) && r.corrected > 0 && cell_size.narrow < kResolvedCells) {
    return Rejection::near_uniform_outvoted;
  }
  // Ids 0 and 255 have no structure along the ring: a dark ring with one
  // light corner, or a light ring with three dark ones. Under about three
  // pixels a cell, the bowl of a printed letter looks exactly like that;
  // these two are reported only when asked for, and only where their cells
  // can be verified.
  if (r.id == 0 || r.id == 255) {
    if (!config_.frame8.uniform_ids || cell_size.narrow < kResolvedCells) return Rejection::uniform_id;
  }
  // The near-uniform ids are what a grid of keys or tiles shows round each
  // of its squares; one whose ring runs off the image has corner cells
  // sampled on whatever is left of them (a key at the image's top edge
  // read as 126): they are read only with the whole ring in the image.
  auto off_image = [&](Point2 g) { return !in_image(full_, grid_point(H, g)); };
  if (near_uniform(r.id) && std::any_of(kOuterGridCorners.begin(), kOuterGridCorners.end(), off_image)) {
    return Rejection::corner_off_image;
  }
  // A side read as hidden must lie in the image: beyond its edge nothing
  // is seen to cover it, and three edges of clutter there agreed on a code
  // (a square at the right edge of the image, read as 32 with its fourth
  // side 6 px outside).
  if (r.hidden.side >= 0 && (off_image(kOuterGridCorners[static_cast<std::size_t>(r.hidden.side)]) ||
                             off_image(kOuterGridCorners[static_cast<std::size_t>((r.hidden.side + 1) % 4)]))) {
    return Rejection::corner_off_image;
  }
  // A covered edge is one leniency already: it does not get a second.
  if (r.orientation_clarity < config_.frame8.min_margin && (r.margin < kClearCode || r.corrected >= 4))
    return Rejection::second_leniency;
  // Nor below about three pixels a cell, where a covered strip cannot be
  // told from a checkered surround lighting two corners.
  if (r.orientation_clarity < config_.frame8.min_margin && cell_size.narrow < kResolvedCells)
    return Rejection::unclear_orientation_small;
  r.margin = std::min(r.margin, std::max(r.orientation_clarity, 0.0));
  if (rule_ == LocalRule::valley && r.margin < kSecondLookMargin &&
      (cell_size.mean >= kSecondLookClearCells || near_uniform(r.id))) {
    return Rejection::low_margin;
  }

  // The line must be there on every side: across it, from the hole's edge
  // out to the ring, the profile dips well under the white cells' level.
  // A light bar between two dark strokes (a sliver quad whose long sides
  // face plain background) has no such dip along its long sides. Where
  // cells are unresolved the blur lifts the half-cell line towards the
  // white of its neighbours, so the bar there is lower: it follows the
  // line's width in pixels on that side, which foreshortening narrows.
  // Glued on a cover frame turned 45 degrees or more, the far side's line
  // lies on the inner roll turned away from the camera, hidden behind the
  // fold, and the cells nearest that side, squeezed and on the bend, may
  // not read clearly. One side without its line is allowed where no cell
  // is outvoted and every bit has two clear votes at least (as for a
  // hidden side, hidden_side.cpp), on cells of 3 px or more and not for
  // the near-uniform ids a grid's squares show: a light bar between two
  // strokes has no such code round it.
  constexpr int kMinVotesWithoutLine = 2;
  const bool code_clear = cell_size.mean >= kResolvedCells && r.corrected == 0 && r.margin >= kClearCode &&
                          r.hidden.side < 0 && !near_uniform(r.id);
  int side_without_line = -1;
  for (int side = 0; side < 4; ++side) {
    if (side == r.hidden.side) continue;
    if (model) {
      // The model measured the line's own level, free of the blur.
      if (r.soft(model->line[static_cast<std::size_t>(side)]) > -kClearLine) return Rejection::model_line_light;
      continue;
    }
    const double line_px =
        distance(grid_point(H, side_point(side, 5, kInnerLo)), grid_point(H, side_point(side, 5, frame8::line_outer)));
    const double line_ceiling = std::clamp(0.8 - 0.9 * (line_px - 0.6), -r.confident, 0.8);
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
      dark += r.soft(darkest) < line_ceiling;
    }
    if (total < 4 || dark < 0.5 * total) {
      if (!code_clear || side_without_line >= 0) return Rejection::line_missing;
      side_without_line = side;
    }
  }
  if (side_without_line >= 0 && r.fewest_agreeing < kMinVotesWithoutLine) return Rejection::line_missing;

  // The line must be dark where it is resolved, all around and at each of
  // its four corners: a light square among the bits of a checkered pattern
  // reads as r.id 0 when a diagonal neighbour lands on C1, but that neighbour
  // also covers the line's corner.
  // A marker turned far keeps a line of a pixel or more across its narrow
  // direction, enough to be checked.
  if (cell_size.mean >= kResolvedCells && cell_size.narrow >= kCheckedLineCells) {
    static constexpr std::array<Point2, 4> kLineCorners{{{1.25, 1.25}, {8.75, 1.25}, {8.75, 8.75}, {1.25, 8.75}}};
    // On a cover frame turned away, the corner nearest the camera lies on
    // the inner roll's bend, shaded or lit differently from the rest of the
    // line: one light corner of four is allowed, but not the white corner's
    // (the checkered pattern's diagonal neighbour), nor beside a hidden side,
    // nor on a hole read grown beyond its component (inset_hole.cpp: the
    // middle of a large dark square, light to the adaptive threshold, grown
    // to the square's edge, read as 254 with one light corner). Turned
    // further (25 degrees and more), the side of the line nearest the camera
    // lies on the roll seen face on and both its corners come out grey: two
    // light corners are allowed where they are one side's.
    int seen = 0, light = 0;
    std::array<bool, 4> light_at{};
    for (std::size_t j = 0; j < kLineCorners.size(); ++j) {
      const Point2 g = kLineCorners[j];
      if (r.hidden.covers(g)) continue;
      float v = 0;
      const Point2 p = grid_point(H, g.x, g.y);
      if (!sample(full_, p.x, p.y, v)) return Rejection::line_corner_light;
      ++seen;
      if (r.soft(v) <= -r.confident) continue;
      if (static_cast<int>(j) == r.white_corner) return Rejection::line_corner_light;
      ++light;
      light_at[j] = true;
    }
    const bool one_side = light == 2 && (light_at[0] == light_at[1] || light_at[1] == light_at[2]);
    if (light > (seen == 4 && !reading_grown_hole_ ? 1 : 0) && !(one_side && seen == 4 && !reading_grown_hole_)) {
      return Rejection::line_corner_light;
    }
    int dark = 0, total = 0;
    double line_sum = 0;
    for (int k = 0; k < 7; ++k) {
      const double along = kInnerLo + 0.5 + k;
      for (int side = 0; side < 4; ++side) {
        if (r.hidden.covers(side_point(side, along, 1.25))) continue;
        float v = 0;
        const Point2 p = grid_point(H, side_point(side, along, 1.25));
        if (!sample(full_, p.x, p.y, v)) continue;
        ++total;
        dark += v < r.thr;
        line_sum += v;
      }
    }
    if (total < 14 || dark < 0.75 * total) return Rejection::line_not_dark;
    // The line and the r.black cells are the same ink. A thin dark outline
    // around a light patch, read against a mid-grey surround taken for
    // "r.black" cells, is not.
    if (std::abs(line_sum / total - r.black) > 0.3 * r.contrast) return Rejection::line_not_ink;
    // A read that outvoted a cell leans on its grid: its hole must be lighter than its line.
    if (r.corrected > 0 && !hole_lighter_than_line(H, r)) return Rejection::hole_not_lighter;
  }
  return Rejection::none;
}

// The hole's quad is the step from the hole into the line: whether the
// hole is lighter than the line beside it, half a cell in from the line's
// inner edge, on three sides at least (a fourth may be covered, or show
// something dark through a cut-out hole). A hole cut out over a dark
// ground is as dark as the line: the adaptive threshold takes its flat
// middle for light, and its quad's sides lie on whatever edges are near.
// Mostly those are the line's, and the code reads whole (the print with
// its margin over black, 0.5 to 1.25 m: 78 to 100%); once in some 3000
// frames they were the white cells' inner edges, a cell out, and 178 read
// as 1 with a cell outvoted.
bool Frame8Detector::hole_lighter_than_line(const Homography& H, const RingRead& r) const {
  constexpr double kMinStep = 0.25;  // of the ring's contrast, in the median along a side
  int lighter = 0, sides = 0;
  for (int side = 0; side < 4; ++side) {
    if (side == r.hidden.side) continue;
    std::array<float, 7> step{};
    std::size_t n = 0;
    for (int k = 0; k < 7; ++k) {
      const double along = kInnerLo + 0.5 + k;
      const Point2 line = grid_point(H, side_point(side, along, 0.5 * (frame8::line_outer + kInnerLo)));
      const Point2 hole = grid_point(H, side_point(side, along, kInnerLo + 0.5));
      float l = 0, h = 0;
      if (!sample(full_, line.x, line.y, l) || !sample(full_, hole.x, hole.y, h)) continue;
      step[n++] = h - l;
    }
    if (n < 4) continue;
    ++sides;
    std::nth_element(step.begin(), step.begin() + static_cast<std::ptrdiff_t>(n / 2),
                     step.begin() + static_cast<std::ptrdiff_t>(n));
    lighter += step[n / 2] >= kMinStep * r.contrast;
  }
  return lighter >= std::min(sides, 3);
}

// Whether the hole, half a cell in from its sides, is as dark as the ring's
// black cells (within a quarter of the ring's contrast, in the median): a
// cut-out hole over a dark ground. Its ring read again through H.
bool Frame8Detector::hole_as_dark_as_ink(const Homography& H, CellSize cell_size) const {
  constexpr double kInkShare = 0.25;
  RingRead r;
  if (read_code(H, cell_size, nullptr, r) != Rejection::none) return false;
  std::array<float, 28> hole{};
  std::size_t n = 0;
  for (int side = 0; side < 4; ++side) {
    for (int k = 0; k < 7; ++k) {
      const Point2 p = grid_point(H, side_point(side, kInnerLo + 0.5 + k, kInnerLo + 0.5));
      if (sample(full_, p.x, p.y, hole[n])) ++n;
    }
  }
  if (n == 0) return false;
  std::nth_element(hole.begin(), hole.begin() + static_cast<std::ptrdiff_t>(n / 2),
                   hole.begin() + static_cast<std::ptrdiff_t>(n));
  return hole[n / 2] <= r.black + kInkShare * r.contrast;
}

}  // namespace markerd::detector::frame8
