// Stage 4, decoding: the code from the ring cells' grey levels, sampled or
// fitted by the ring model, through its sub-stages 4a to 4e.

#include "frame8/detector.hpp"

#include <algorithm>

namespace markerd::detector::frame8 {

namespace {
// In the ring model's levels, as the read's soft grey (-1 black, +1 white):
// a hole at least this light is paper (an outlet's face in the roll's
// shade showed 0.7 at most, far and turned; a paper hole 0.5 and up).
constexpr double kPaperHole = 0.8;
// On a flat print the model's line stays under this on every side, and
// under the middle grey (0) on all sides but one (over some 1,600
// near-uniform reads from 2 to 3.2 m and turned to 80 deg, Gaussian and
// disc blur, shot noise, JPEG 75: 0.22 at most on one side, -0.25 on the
// next); grout beside a light tile read 0.4 to 1 on one side, or 0.15 to
// 0.2 on three.
constexpr double kFlatLineCeiling = 0.4;
// Told a lighter blur than this (or none), the model's own reads are
// checked against a blur a third heavier than this one: a sharp lens still
// spreads a cell over its neighbours by a few tenths of a pixel.
constexpr double kMinModelBlurPx = 0.3;
}  // namespace

// Decides the code from the ring cells' grey levels: sampled in the image,
// or fitted by the ring model when `model` is given. `rotation` is set once
// the orientation is (even when a structural check then rejects the read).
Rejection Frame8Detector::decode(const Homography& H, CellSize cell_size, Detection& det, int& rotation,
                                 const frame8::RingModel::Levels* model, const HiddenSide& hidden) const {
  RingRead r;
  r.hidden = hidden;
  if (const Rejection why = read_code(H, cell_size, model, r); why != Rejection::none) return why;
  rotation = (r.white_corner + 3) % 4;
  if (const Rejection why = check_structure(H, cell_size, model, r); why != Rejection::none) return why;
  det.family = Family::frame8;
  det.id = r.id;
  det.bits_corrected = r.corrected;
  det.margin = r.margin;
  det.orientation_ambiguous = r.orientation_ambiguous;
  return Rejection::none;
}

Rejection Frame8Detector::read_code(const Homography& H, CellSize cell_size, const frame8::RingModel::Levels* model,
                                    RingRead& r) const {
  if (const Rejection why = read_cells(H, cell_size, model, r); why != Rejection::none) return why;
  if (const Rejection why = fit_grey_model(cell_size, r); why != Rejection::none) return why;
  weigh_edges(H, r);
  if (const Rejection why = read_corners(r); why != Rejection::none) return why;
  if (const Rejection why = vote_bits(r); why != Rejection::none) return why;
  return settle_orientation(H, r);
}

// Reads cells too small to sample from the blur model of the ring, when the
// sampled reads were worth another measurement (worth_remeasuring); with the
// map moved to where the model fits best, H follows it. Outside the model's
// own look (model_look) it only notes that the quad is worth that look.
bool Frame8Detector::read_by_model(Homography& H, CellSize cell_size, bool sampled_worth_it, Detection& det,
                                   int& rotation) {
  // The model costs a few million instructions: only for small cells, not
  // under the least that is read at all, and only for what has a ring of
  // dark and light cells where the quad puts them (clutter mostly fails on
  // contrast already; of the rest, a third shows no such ring, and no
  // marker the model read at 2.5 to 2.7 m failed to).
  if (!config_.frame8.model_small_cells || cell_size.narrow >= kResolvedCells || cell_size.narrow < kMinCells ||
      !sampled_worth_it) {
    return false;
  }
  Eigen::Matrix3d M = grid_map(H);
  if (!model_look_) {
    model_wanted_ = model_wanted_ || ring_shows_cells(M);
    return false;
  }
  // First the levels where the quad puts the cells (a tenth of the cost):
  // enough when the quad is right, and to turn away what has no line.
  if (!ring_model_.fit(full_, M, config_.frame8.blur_sigma_px, RingModel::Aim::levels, levels_)) return false;
  const Rejection unaligned = decode(H, cell_size, det, rotation, &levels_);
  note_attempt(Read::ring_model, unaligned);
  if (unaligned == Rejection::none) return true;
  // A light cell beside C1 that the code says is dark is the mark of a
  // light patch in a checkered surround, not of a ring a fraction of a
  // cell off: not worth moving the map for.
  if (!worth_remeasuring(unaligned) || unaligned == Rejection::c1_contradicted) return false;
  if (!ring_model_.align_levels(full_, M, levels_)) return false;
  const Homography aligned = Homography::from_grid_map(M);
  const Rejection aligned_read = decode(aligned, cell_size, det, rotation, &levels_);
  note_attempt(Read::aligned_ring_model, aligned_read);
  if (aligned_read != Rejection::none) return false;
  H = aligned;
  return true;
}

// Cells too small to sample cleanly are read from grey levels that are as
// much their neighbours' as their own: a lone cell beside two of the other
// colour, the paper beyond the ring and a corner, read wrong on all four
// edges alike, and the votes cannot see it. The ring model, fitted to every
// pixel of the marker with its map aligned, undoes that mixing: a sampled
// read stands only where it reads the same code the same way round. The
// map must be aligned: the model's levels where the quad puts the cells (a
// tenth of the cost) confirmed 4 of the 14 wrong reads.
Rejection Frame8Detector::confirm_by_model(const Homography& H, CellSize cell_size, const Detection& det,
                                           int rotation) {
  Eigen::Matrix3d M = grid_map(H);
  if (!ring_model_.fit(full_, M, config_.frame8.blur_sigma_px, RingModel::Aim::aligned_levels, levels_))
    return Rejection::model_disagrees;
  return judge_model_read(M, cell_size, det, rotation);
}

// The same at a map the ring model has aligned already (its geometry's
// fit): the levels alone, a fraction of an alignment's cost.
Rejection Frame8Detector::confirm_at_model_map(const Eigen::Matrix3d& aligned, CellSize cell_size, const Detection& det,
                                               int rotation) {
  Eigen::Matrix3d M = aligned;
  if (!ring_model_.fit(full_, M, config_.frame8.blur_sigma_px, RingModel::Aim::levels, levels_))
    return Rejection::model_disagrees;
  return judge_model_read(M, cell_size, det, rotation);
}

// The same, where the blur the detector was told fits the pixels better
// than one a third heavier (Rejection::model_blur_differs otherwise). Under
// a blur heavier than told the model spreads each cell too little, and a
// lone cell takes its neighbours' colour on every edge alike: discs of 1.6
// to 2 px over cells of 1.6 px at 2.4 to 2.7 m, told a Gaussian of 0.6 px,
// gave 43 wrong ids in 2,400 frames (one model read in eight); read
// at the blur of least residual instead, 25. There the blur a third
// heavier fitted with 0.52 to 0.73 of the told one's residual, and on the
// print as told (Gaussian 0.6 px, 2.4 to 2.9 m) with 1.55 to 1.92 of it. A
// lighter blur than told spreads the cells too much, which the reads bear
// (the print as told fits a blur a third lighter about as well).
Rejection Frame8Detector::confirm_at_told_blur(const Eigen::Matrix3d& aligned, CellSize cell_size, const Detection& det,
                                               int rotation) {
  constexpr double kBlurStep = 4.0 / 3;
  const double heavier = std::max(config_.frame8.blur_sigma_px, kMinModelBlurPx) * kBlurStep;
  Eigen::Matrix3d M = aligned;
  if (!ring_model_.fit(full_, M, heavier, RingModel::Aim::levels, levels_)) return Rejection::model_disagrees;
  const double heavier_residual = levels_.rms_residual;
  // The read at the told blur; its fit's residual is left in levels_ (a
  // failed fit leaves the heavier one's, which is no less than itself).
  const Rejection why = confirm_at_model_map(aligned, cell_size, det, rotation);
  if (heavier_residual < levels_.rms_residual) return Rejection::model_blur_differs;
  return why;
}

// The read of the model's levels (levels_) at its map M, against the
// sampled read `det`.
Rejection Frame8Detector::judge_model_read(const Eigen::Matrix3d& M, CellSize cell_size, const Detection& det,
                                           int rotation) {
  // The code and its orientation are compared: the structural checks are
  // the sampled read's, and the model's own test of the line (as dark as
  // the black cells) does not hold on a socket frame, whose line lies on
  // the inner roll, mixed with the hole and the fold where it turns away
  // (a side's line up to the white cells' level in a third of far socket
  // reads).
  RingRead r;
  const Rejection why = read_code(Homography::from_grid_map(M), cell_size, &levels_, r);
  note_attempt(Read::model_check, why);
  if (why != Rejection::none || r.id != det.id || (r.white_corner + 3) % 4 != rotation) {
    return Rejection::model_disagrees;
  }
  // A hole as light as the paper is no cover frame's insert (an outlet's
  // face lies in the roll's shade): the print is flat, and its line ink on
  // every side. A light tile among grey ones, its grout for the line, reads
  // as a near-uniform ring with a side's line as light as the white cells.
  if (near_uniform(det.id) && r.soft(levels_.hole) >= kPaperHole) {
    int light_sides = 0;
    for (const float line : levels_.line) {
      if (r.soft(line) > kFlatLineCeiling) return Rejection::model_line_light;
      light_sides += r.soft(line) > 0;
    }
    if (light_sides > 1) return Rejection::model_line_light;
  }
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
