// The frame8 detector that runs the stages (docs/architecture.md, "The frame8
// pipeline"): 1 segmentation, 2 quad fitting, 3 edge refinement, 4 decoding
// (4a cells, 4b grey model, 4c orientation, 4d bit votes, 4e structural
// checks), 5 the whole pattern, 6 corners and pose; each in the file of its
// name. Here: the order they run in, and the reads tried again on other
// measurements of a quad whose first read fails.
//
// Memory: every buffer is a member that grows to the largest frame seen and is
// reused, so detect() allocates nothing in steady state (without the debug
// output).

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <system_error>
#include <vector>

#include <fmt/format.h>

#include "frame8_detector.hpp"

namespace markerd::detector::frame8 {

Frame8Detector::Frame8Detector(const DetectorConfig& config) : config_(config) {
  if (config_.frame8.decimate < 0 || config_.frame8.decimate > 8) {
    throw DetectorError("frame8: decimate must be 0 (auto) to 8");
  }
  if (config_.frame8.threshold_offset < Frame8Options::kMinThresholdOffset ||
      config_.frame8.threshold_offset > Frame8Options::kMaxThresholdOffset) {
    throw DetectorError(fmt::format("frame8: threshold_offset must be {}..{} grey levels",
                                    Frame8Options::kMinThresholdOffset, Frame8Options::kMaxThresholdOffset));
  }
  if (!(config_.frame8.blur_sigma_px >= 0 && config_.frame8.blur_sigma_px <= Frame8Options::kMaxBlurSigmaPx)) {
    throw DetectorError(fmt::format("frame8: blur_sigma_px must be 0..{:g} pixels", Frame8Options::kMaxBlurSigmaPx));
  }
  if (!config_.frame8.debug_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(config_.frame8.debug_dir, ec);
    if (ec || !std::filesystem::is_directory(config_.frame8.debug_dir)) {
      throw DetectorError(
          fmt::format("frame8: debug_dir {}: {}", config_.frame8.debug_dir, ec ? ec.message() : "not a directory"));
    }
    debug_ = true;
  }
  const Mounting mounting = config_.frame8.mounting;
  seeks_reshaped_hole_ = mounting != Mounting::paper;
  seeks_ink_outline_ = mounting == Mounting::any || mounting == Mounting::cut_hole;
  hole_printed_blank_ = mounting == Mounting::paper;
  profile_sigma_ = std::sqrt(config_.frame8.blur_sigma_px * config_.frame8.blur_sigma_px + 1.0 / 12 + 1.0 / 8);
  model_candidates_.reserve(kMaxModelCandidates);
}

void Frame8Detector::detect(const GreyView& image, std::vector<Detection>& out) {
  out.clear();
  if (image.empty()) throw DetectorError("frame8: empty image");
  if (image.stride < image.width) throw DetectorError("frame8: image stride is smaller than its width");
  if (config_.camera && (config_.camera->width != image.width || config_.camera->height != image.height)) {
    throw DetectorError("frame8: image size differs from the camera model's");
  }
  if (image.width < 16 || image.height < 16) return;
  full_ = image;
  if (debug_) {
    debug_candidates_.clear();
    debug_second_look_from_ = debug_model_look_from_ = std::numeric_limits<std::size_t>::max();
  }
  model_candidates_.clear();
  make_working_image();
  threshold_tiles();
  look(LocalRule::brightest_neighbour, out);
  // A second look, where the first found nothing, with light ridges kept
  // whole: what the first rule thins to a broken crest (a socket's face
  // round its recess from 2 m, a cut-out hole's margin over a dark ground)
  // is then a hole's outline again.
  if (out.empty()) look(LocalRule::valley, out);
  if (out.empty()) model_look(out);
  remove_nested(out);
  if (debug_) write_debug(out);
}

void Frame8Detector::model_look(std::vector<Detection>& out) {
  if (debug_) debug_model_look_from_ = debug_candidates_.size();
  model_look_ = true;
  for (const ModelCandidate& candidate : model_candidates_) {
    const auto& q = candidate.coarse;
    if (inside_any(out, centre_of(q))) continue;
    rule_ = candidate.rule;
    if (debug_) debug_candidates_.push_back({q, Rejection::none, -1, {}, {}});
    Detection det;
    const Rejection why = refine_and_decode(q, det);
    note_outcome(why, det);
    if (why == Rejection::none) out.push_back(det);
  }
  model_look_ = false;
}

// Stages 1 (from the tiles' thresholds on) to 6 under one local rule.
void Frame8Detector::look(LocalRule rule, std::vector<Detection>& out) {
  rule_ = rule;
  light_pixels_and_runs(rule);
  label_components();
  if (debug_) {
    if (rule == LocalRule::valley) debug_second_look_from_ = debug_candidates_.size();
    write_debug_threshold();
  }
  // Largest first: a marker's light cells and hole are components inside
  // it, and once the marker is read they need no look (a white ring cell of
  // a near marker is a light square with black neighbours, and with small
  // cells of its own it would cost the ring model a fit).
  roots_.clear();
  for (std::int32_t r = 0; r < static_cast<std::int32_t>(runs_.size()); ++r) {
    if (runs_[static_cast<std::size_t>(r)].parent == r) roots_.push_back(r);
  }
  auto box_area = [&](std::int32_t r) {
    const Component& c = components_[static_cast<std::size_t>(r)];
    return static_cast<std::int64_t>(c.x1 - c.x0) * (c.y1 - c.y0 + 1);
  };
  std::sort(roots_.begin(), roots_.end(), [&](std::int32_t a, std::int32_t b) { return box_area(a) > box_area(b); });
  for (const std::int32_t r : roots_) {
    Component& c = components_[static_cast<std::size_t>(r)];
    if (inside_detection(c, out)) {
      c.settled = c.read = true;
    } else {
      consider_component(r, out);
    }
  }
  // Then the holes no quad was: parted in two (2d), open on one side (2b),
  // or no lighter than the line (2c).
  if (seeks_reshaped_hole_) read_hole_fragments(out);
  find_open_holes(out);
}

namespace {

// The quad with each corner moved `by` pixels towards its centre.
std::array<Point2, 4> moved_in(const std::array<Point2, 4>& quad, double by) {
  const Point2 centre = centre_of(quad);
  std::array<Point2, 4> in = quad;
  for (Point2& p : in) {
    const Point2 v = p - centre;
    p = p + (-by / std::hypot(v.x, v.y)) * v;
  }
  return in;
}

}  // namespace

// One light component: its quad (stage 2), then refined and read.
void Frame8Detector::consider_component(std::int32_t root, std::vector<Detection>& out) {
  Component& c = components_[static_cast<std::size_t>(root)];
  // The component's box stands for its quad until fit_quad() finds one.
  std::array<Point2, 4> quad{
      {{c.x0 - 0.5, c.y0 - 0.5}, {c.x1 - 0.5, c.y0 - 0.5}, {c.x1 - 0.5, c.y1 + 0.5}, {c.x0 - 0.5, c.y1 + 0.5}}};
  const Rejection shape = fit_quad(c, quad);
  // Under the valley rule a hole's light pixels reach down its edges' blur
  // to about their middle; the sides are searched from inside the hole.
  if (shape == Rejection::none && rule_ == LocalRule::valley) quad = moved_in(quad, kValleyInset);
  const std::array<Point2, 4> working_quad = quad;
  for (auto& p : quad) p = to_full(p);
  // Components that fail on their box alone are not candidates: the debug
  // output would list every speck of clutter.
  if (debug_ && shape != Rejection::touches_border && shape != Rejection::box_size) {
    debug_candidates_.push_back({quad, shape, -1, {}, {}});
  }
  // Stage 2b looks for open holes in what is left, and stage 2c for a
  // marker's ink among the dark islands of what is left and of the quads
  // not read (a cut-out hole's marker glued on light paper or plastic: the
  // surround is a quad whose island is the marker). A component too small
  // to hold either is left alone, and so is a quad whose islands are not
  // searched or hold too little ink.
  const double min_side = min_open_hole_side();
  c.quad = shape == Rejection::none;
  c.settled =
      std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) < min_side ||
      (c.quad && (!seeks_ink_outline_ || static_cast<double>(c.dark_inside) < kMinInkShare * min_side * min_side));
  if (shape != Rejection::none) return;
  Detection det;
  Rejection why = refine_and_decode(quad, det);
  // A small hole that bulges may be two squares of a grid joined (a key
  // and its neighbour: id 126 once in 7,000 frames of the backgrounds
  // alone), and reads as one.
  if (why == Rejection::none && c.small_and_bulging && reads_like_a_grid(det)) why = Rejection::grid_like_read;
  if (why != Rejection::none && seeks_reshaped_hole_ && read_hole_past_fold(c, working_quad, det)) {
    why = Rejection::none;
  }
  note_outcome(why, det);
  if (why == Rejection::none) {
    out.push_back(det);
    c.settled = c.read = true;
  }
}

// Perspective shortens one end of a far-turned marker below the cosine of
// its turn: 0.12 at 80 degrees, seen from 0.5 m; and a hole's short side
// of a few pixels is measured up to a pixel short.
constexpr double kMinSideRatio = 0.08;
// A read that needed this many of its bits corrected (an edge outvoted on
// each) has spent most of the code's redundancy, and clutter's reads mostly
// look so: the second pass must confirm it at any size. Bench_accuracy
// --false-positives 10000 (the background alone): 3 false detections (ids
// 127, 128, 129; 2 and 3 bits corrected, the second pass failing), none
// with the rule, and no rate lost on paper or socket frames.
constexpr int kUnconfirmedCorrections = 2;
// Below this many pixels a cell (the mean), the second pass must confirm
// every read. There the sides' first measurement is off by up to a tenth
// of the marker where the blur is not the Gaussian the detector assumes:
// the step into a line half a cell wide, cut short by the cell beyond, has
// its centroid inside the hole. A grid a tenth too small samples each
// edge's end cells half on their neighbours, and reads a code whose end
// bits are its neighbours' with every cell clear (189, 10111101, as 60,
// 00111100): bench_accuracy --blur-model disc, 2.2 to 3.1 m, 1200 frames
// a point over two seeds and both blur models, 12 such wrong ids with
// grids 0.86 to 0.95 of the truth, every one read once and its second
// measurement failing. The second pass, measuring each point as the code
// says (the line's centre where a white cell lies beyond), finds the
// hole's true size, and reads the right code or none.
constexpr double kConfirmedCells = kModelCheckedCells;
// From this many pixels per cell, the corners come from the whole pattern
// (stage 5): below it the pattern's edges blur into each other.
constexpr double kPatternCells = 1.0;
// Under this many pixels a cell, the corners come from the ring model's
// fit to every pixel (finish_by_model) where it fits: at 4 px the blur
// (0.6 px, and the pixel's own square) reaches a fifth of the cell beyond
// each edge, and the pattern's edge samples begin to depend on the pixels'
// phase (corner error 0.033 px at 1.4 m against the model's 0.017).
constexpr double kModelGeometryCells = 4.0;

// Stages 3 to 6 for one coarse quad (full-resolution pixels): the sides
// refined, the ring read (by several measurements where cells are small),
// the corners and the pose. Rejection::none when `det` holds a detection;
// otherwise the first read's rejection, or the stage that failed before it.
Rejection Frame8Detector::refine_and_decode(const std::array<Point2, 4>& coarse, Detection& det) {
  reached_wide_ = false;
  model_wanted_ = false;
  const Rejection why = measure_and_read(coarse, det);
  // The second look finds most of the first's holes again, each quad moved
  // in by a pixel: both are noted, since the model reads either one where
  // the other fails (noting a hole once cut the print with its margin from
  // 97 to 93% at 2.7 m, and JPEG rolled 45 deg from 86 to 78%).
  if (why != Rejection::none && model_wanted_ && model_candidates_.size() < kMaxModelCandidates) {
    model_candidates_.push_back({coarse, rule_});
  }
  // A side found only past the step's first reach may be a grid's next line.
  if (why == Rejection::none && reached_wide_ && reads_like_a_grid(det)) return Rejection::grid_like_read;
  return why;
}

Rejection Frame8Detector::measure_and_read(const std::array<Point2, 4>& coarse, Detection& det) {
  double perimeter = 0;
  for (int i = 0; i < 4; ++i) {
    perimeter += distance(coarse[static_cast<std::size_t>(i)], coarse[static_cast<std::size_t>((i + 1) % 4)]);
  }
  double cell_px = perimeter / 4 / kInnerSide;
  if (perimeter / 4 < config_.frame8.min_hole_side_px) return Rejection::small_hole;

  std::array<Point2, 4> inner{};
  if (const Rejection why = refine_sides(coarse, EdgeMode::step, std::nullopt, cell_px, inner);
      why != Rejection::none) {
    return why;
  }
  // The coarse quad lies inside the hole; the refined one gives the scale.
  perimeter = 0;
  for (int i = 0; i < 4; ++i) {
    perimeter += distance(inner[static_cast<std::size_t>(i)], inner[static_cast<std::size_t>((i + 1) % 4)]);
  }
  cell_px = perimeter / 4 / kInnerSide;
  // Below a few pixels a cell the profile classification does better on
  // the whole, but can take a line merged with a black cell for the line
  // alone; the step-only quad is the fallback when its read fails.
  std::array<Point2, 4> step_only = inner;
  bool have_fallback = false;
  if (cell_px < kThinLineCells) {
    std::array<Point2, 4> by_profile{};
    if (refine_sides(inner, EdgeMode::classify_by_profile, std::nullopt, cell_px, by_profile) == Rejection::none) {
      inner = by_profile;
      have_fallback = true;
    }
  }
  // A square seen at up to about 82 degrees keeps its short sides above a
  // tenth of its long ones (kMinSideRatio); slivers beyond that are not
  // worth a read.
  if (short_to_long_sides(inner) < kMinSideRatio) return Rejection::sliver;
  const CellSize cell_size = cell_size_of(inner);
  Homography H;
  if (!Homography::from_unit_square(inner, H)) return Rejection::degenerate_quad;
  int rotation = 0;
  bool by_model = false;
  const Rejection sampled = decode(H, cell_size, det, rotation, nullptr);
  note_attempt(Read::sampled, sampled);
  if (sampled != Rejection::none) {
    // The step-only quad, where the profile classification moved the sides.
    bool read = false;
    bool worth_it = worth_remeasuring(sampled);
    Homography step_H;
    if (have_fallback && Homography::from_unit_square(step_only, step_H)) {
      const Rejection step_sampled = decode(step_H, cell_size, det, rotation, nullptr);
      note_attempt(Read::step_only, step_sampled);
      if (step_sampled == Rejection::none) {
        H = step_H;
        inner = step_only;
        read = true;
      }
      worth_it = worth_it || worth_remeasuring(step_sampled);
    }
    // Then the sides measured by the profile fit (which sets H and inner
    // when it reads), then the ring model.
    if (!read && worth_it) read = read_by_profile_fit(step_only, cell_px, cell_size, det, rotation, H, inner);
    if (!read) read = by_model = read_by_model(H, cell_size, worth_it, det, rotation);
    HiddenSide hidden;
    if (!read && worth_it && read_with_side_hidden(inner, det, rotation, hidden, H)) {
      return finish_from_hole(H, hidden, rotation, cell_px, det);
    }
    // Then the reads of a hole the mounting may have reshaped: displaced by
    // a frame's roll, inset by a switch's rocker.
    const bool seek_reshaped = !read && worth_it && seeks_reshaped_hole_;
    if (seek_reshaped && read_inset(inner, cell_size, det, rotation, H)) {
      return finish_from_hole(H, HiddenSide{}, rotation, cell_px, det);
    }
    if (seek_reshaped && read_on_ring_edges(H, cell_size, det, rotation, H)) {
      read = true;
      inner = H.quad();
    }
    if (seek_reshaped && !read && read_by_ring_alignment(inner, cell_size, det, rotation, H)) {
      read = true;
      inner = H.quad();
    }
    if (!read) return sampled;
  }
  // A quad that ends at something dark in front of the marker may have
  // read the code with its cells a cell or more off: the hole goes on
  // behind it. Where cells are resolved it is read again with that side
  // hidden: another id rejects the candidate, and so does no read at all
  // where the first outvoted cells, in the second look or for a
  // near-uniform id (a key top in its bevel, the shadow of its edge for the
  // line and a shaded bevel for a covered side, read as 126 with that
  // side's six cells outvoted, 7 of 9 false detections in 30,000
  // marker-free frames; no covered marker in the cover sets read so, but a
  // print with one edge's cells painted over does, its line whole, and the
  // first look finds it unless its id is near-uniform); with a camera, a hole found
  // to reach further (more nearly a square in perspective) replaces the
  // read (without one, an edge painted over reads at several depths as
  // well as the quad seen, which is kept). Where they are not, a read that
  // outvoted cells beside such a side is not to be trusted: a marker far
  // off with half its hole behind a dark object read one bit wrong so.
  if (const bool covered = any_side_looks_covered(H); covered && cell_size.narrow < kResolvedCells) {
    if (det.bits_corrected > 0) return Rejection::covered_side_small_cells;
  } else if (covered) {
    Detection again;
    int again_rotation = 0;
    HiddenSide hidden;
    Homography again_H;
    if (read_with_side_hidden(inner, again, again_rotation, hidden, again_H)) {
      if (again.id != det.id) return Rejection::hidden_side_disagrees;
      if (config_.camera && hidden.depth > kInnerLo) {
        det = again;
        return finish_from_hole(again_H, hidden, again_rotation, cell_px, det);
      }
    } else if (det.bits_corrected > 0 && (rule_ == LocalRule::valley || near_uniform(det.id))) {
      return Rejection::covered_side_unread;
    }
  }
  bool second_pass_agrees = false;
  if (cell_px < kThinLineCells && !by_model) {
    // Measure again knowing which cells are white, then read again.
    std::array<Point2, 4> second{};
    Homography H2;
    Detection det2;
    int rotation2 = 0;
    Rejection second_read = refine_sides(inner, EdgeMode::step, det.id, cell_px, second);
    if (second_read == Rejection::none && !Homography::from_unit_square(second, H2)) {
      second_read = Rejection::degenerate_quad;
    }
    if (second_read == Rejection::none) second_read = decode(H2, cell_size, det2, rotation2, nullptr);
    note_attempt(Read::second_pass, second_read);
    Rejection unconfirmed = Rejection::none;
    if (second_read == Rejection::none && det2.id != det.id) {
      unconfirmed = Rejection::second_pass_disagrees;  // two measurements, two ids: neither is trusted
    } else if (second_read != Rejection::none && det.bits_corrected >= kUnconfirmedCorrections) {
      unconfirmed = Rejection::unconfirmed_correction;
    } else if (second_read != Rejection::none && confirming_cell_size(H, cell_size) < kConfirmedCells) {
      unconfirmed = Rejection::unconfirmed_small_cells;
    } else if (second_read != Rejection::none && hole_as_dark_as_ink(H, cell_size)) {
      // A hole as dark as the ink (a cut-out hole over a dark ground) has
      // no edge where the quad's sides were measured: the read is placed
      // by nothing the second measurement found again (over grey 30 at
      // 1.6 m, 194 read as 195 so, 1 in 200 frames). A socket's hole
      // turned 60 deg, no lighter than the line on the shaded roll but
      // lighter than ink, reads right.
      unconfirmed = Rejection::unconfirmed_dark_hole;
    }
    if (second_read == Rejection::none && unconfirmed == Rejection::none) {
      second_pass_agrees = true;
      inner = second;
      H = H2;
      det = det2;
      rotation = rotation2;
    } else {
      // (restores the first pass's edge points for the camera refit)
      if (const Rejection why = refine_sides(coarse, EdgeMode::step, std::nullopt, cell_px, inner);
          why != Rejection::none) {
        return why;
      }
      // What the sampled reads could not confirm, the ring model (where it
      // is on) may still read from every pixel.
      if (unconfirmed != Rejection::none) {
        if (!read_by_model(H, cell_size, true, det, rotation)) return unconfirmed;
        by_model = true;
      }
    }
  }

  if (near_uniform(det.id) && cell_size.narrow < kResolvedCells && !second_pass_agrees) {
    return Rejection::near_uniform_unconfirmed;
  }
  if (hole_printed_blank_ && !hole_is_blank_paper(H, H, -1)) return Rejection::hole_not_blank;

  // With the code known, every edge of the printed pattern is a measurement.
  const bool by_pattern =
      cell_px >= kPatternCells && collect_pattern_edges(H, det.id, rotation, cell_px) >= kMinPatternEdges;
  // A near-uniform ring under 3 px a cell is also what a grid's squares
  // show, and a measurement twice alike (a light tile in light grout, read
  // as 129 at 2.8 px): the model must read it too, with its line ink.
  const bool model_checked = confirming_cell_size(H, cell_size) < kModelCheckedCells ||
                             (near_uniform(det.id) && cell_size.narrow < kResolvedCells);
  const bool confirm = model_checked && !by_model;
  const bool model_geometry = cell_px < kModelGeometryCells || by_model;
  // The model aligns its own map; started from the pattern's (where the
  // quad's outer corners are up to a pixel off, the pattern's are a tenth
  // of that), it needs one or two steps instead of four.
  std::optional<Eigen::Matrix3d> pattern_map;
  if (Eigen::Matrix3d M; by_pattern && (confirm || model_geometry) && fit_grid_map(M)) pattern_map = M;
  // Where the corners come from the model, its fit comes first: the
  // confirmation then reads the levels at the map it aligned (to a
  // hundredth of a pixel, on every pixel the marker reaches), and aligns a
  // map of its own (to a twentieth, on the pixels mostly on the marker)
  // only where that read disagrees: beside a bare print or on a socket
  // frame, whose outside is no one level a side, the geometry's map may
  // lean on it (without the second try, 11 of some 5,400 frames of the
  // bare print to 3 m, and 3 of 50 socket frames at 2.5 m, were lost). But
  // a near-uniform read, the class a grid's squares and a far marker's
  // blur both give, must be read at both maps: a disc-blurred marker at
  // 3 m, id 213, read 128 sampled twice and at the model's own map, not at
  // the geometry's; a light tile in its grout, 129, at the geometry's and
  // not at the model's own.
  std::optional<Eigen::Matrix3d> model_map;
  MapNoise model_noise;
  if (Eigen::Matrix3d M = pattern_map.value_or(grid_map(H)); model_geometry && fit_model_geometry(M, model_noise)) {
    model_map = M;
  }
  if (confirm) {
    // A wrong code finds few of the edges it predicts where there are none,
    // and the fit drops those it finds off the others: its map is the
    // ring's all the same, and the model's levels, free of any code, still
    // read.
    const Homography start = pattern_map ? Homography::from_grid_map(*pattern_map) : H;
    Rejection why = Rejection::none;
    if (!model_map) {
      why = confirm_by_model(start, cell_size, det, rotation);
    } else {
      why = confirm_at_model_map(*model_map, cell_size, det, rotation);
      // A near-uniform read must stand at both maps, any other at either.
      if (near_uniform(det.id) ? why == Rejection::none : why != Rejection::none) {
        why = confirm_by_model(start, cell_size, det, rotation);
      }
    }
    if (why != Rejection::none) return why;
  }
  // The model's own read stands on what a sampled read is confirmed by:
  // the model's levels at the geometry fit's map, which takes every pixel
  // the marker reaches, to a hundredth of a pixel; there the blur it was
  // told must fit (confirm_at_told_blur). Nothing else measured it, so it
  // may outvote no cell: an edge outvoted is an edge that read otherwise,
  // and no second measurement says which was right (before cells under
  // 1.2 px were left to the sampled reads, a marker 2.5 m off turned 55
  // deg under a disc blur, its cells 0.9 px across, read 253 as 252 at
  // both maps, a cell outvoted).
  if (by_model) {
    if (!model_map) return Rejection::model_disagrees;
    if (const Rejection why = confirm_at_told_blur(*model_map, cell_size, det, rotation); why != Rejection::none) {
      return why;
    }
    if (det.bits_corrected > 0) return Rejection::model_read_corrected;
  }
  if (model_map && finish_by_model(*model_map, model_noise, rotation, det)) return Rejection::none;
  if (by_pattern) return finish_by_pattern(rotation, det);

  if (!config_.camera) return report(grid_map(H), rotation, det);
  return refit_undistorted(rotation, det);
}

// Small cells, third try: the sides measured again by fitting each side's
// profiles with the blurred line and the cells beyond it
// (fit_edge_profile), then read.
bool Frame8Detector::read_by_profile_fit(const std::array<Point2, 4>& from, double cell_px, CellSize cell_size,
                                         Detection& det, int& rotation, Homography& H, std::array<Point2, 4>& inner) {
  if (cell_px >= kResolvedCells || cell_px < kMinCells) return false;
  std::array<Point2, 4> fitted{};
  Homography fitted_H;
  Rejection fit = refine_sides(from, EdgeMode::fit_profile, std::nullopt, cell_px, fitted);
  if (fit == Rejection::none && !Homography::from_unit_square(fitted, fitted_H)) fit = Rejection::degenerate_quad;
  if (fit == Rejection::none) fit = decode(fitted_H, cell_size, det, rotation, nullptr);
  note_attempt(Read::profile_fit, fit);
  if (fit != Rejection::none) return false;
  H = fitted_H;
  inner = fitted;
  return true;
}

bool Frame8Detector::inside_detection(const Component& c, const std::vector<Detection>& found) const {
  const double d = decimate_;
  const Point2 centre{(c.x0 + c.x1 - 1) * 0.5 * d + (d - 1) / 2, (c.y0 + c.y1) * 0.5 * d + (d - 1) / 2};
  return inside_any(found, centre);
}

bool Frame8Detector::inside_any(const std::vector<Detection>& found, Point2 p) {
  return std::any_of(found.begin(), found.end(), [&](const Detection& det) { return inside(det.corners, p); });
}

bool Frame8Detector::inside(const Quad& q, Point2 p) {
  for (int i = 0; i < 4; ++i) {
    if (cross(q[static_cast<std::size_t>(i)], q[static_cast<std::size_t>((i + 1) % 4)], p) < 0) return false;
  }
  return true;
}

// A marker has one hole, but a white cell enclosed by black neighbours (or
// the line) is a small light square too, and may read as some code. Any
// detection lying within a larger one is such a part of it, and is dropped.
void Frame8Detector::remove_nested(std::vector<Detection>& out) {
  auto area = [](const Quad& q) {
    double a = 0;
    for (int i = 0; i < 4; ++i)
      a += q[static_cast<std::size_t>(i)].x * q[static_cast<std::size_t>((i + 1) % 4)].y -
           q[static_cast<std::size_t>((i + 1) % 4)].x * q[static_cast<std::size_t>(i)].y;
    return std::abs(a) / 2;
  };
  for (std::size_t i = out.size(); i-- > 0;) {
    const Point2 centre = centre_of(out[i].corners);
    const double a = area(out[i].corners);
    for (std::size_t j = 0; j < out.size(); ++j) {
      // A cell is a seventh of the hole's side: its "marker" is tiny beside the real one.
      if (j != i && a < 0.1 * area(out[j].corners) && inside(out[j].corners, centre)) {
        out.erase(out.begin() + static_cast<std::ptrdiff_t>(i));
        break;
      }
    }
  }
}

}  // namespace markerd::detector::frame8

namespace markerd::detector {

std::unique_ptr<MarkerDetector> make_frame8_detector(const DetectorConfig& config) {
  return std::make_unique<frame8::Frame8Detector>(config);
}

}  // namespace markerd::detector
