#pragma once
// Why the frame8 detector turned a candidate down, and the stage of
// docs/architecture.md ("The frame8 pipeline") that did. The debug output
// (Frame8Options::debug_dir) names both for every rejected candidate.

#include <cstdint>

namespace markerd::detector::frame8 {

// The stages in the order a candidate meets them; each has the file of the
// same name in detector/src/frame8/ (stage 4c also short_edges.cpp).
enum class Stage : std::uint8_t {
  segmentation,      // 1  segmentation.cpp
  quad_fit,          // 2  quad_fit.cpp
  edge_refinement,   // 3  edge_refinement.cpp
  cells,             // 4a decode_cells.cpp
  grey_model,        // 4b decode_grey_model.cpp
  orientation,       // 4c decode_orientation.cpp, short_edges.cpp
  bit_votes,         // 4d decode_votes.cpp
  structure,         // 4e decode_checks.cpp
  pattern_fit,       // 5  pattern_fit.cpp
  corners_and_pose,  // 6  corners_and_pose.cpp
};

enum class Rejection : std::uint8_t {
  none,  // read
  // 2. quad fitting (the first two are not candidates: the debug output omits them)
  touches_border,    // the component reaches the image's border
  box_size,          // its box is too small for min_hole_side_px, or nearly the whole image
  sparse_component,  // the component fills too little of its box or of its quad
  not_a_quad,        // its hull is more than a quad
  short_quad_side,   // a side under half the least hole side
  sharp_corner,      // a corner sharper than 20 degrees or flatter than 160
  open_hole_unread,  // 2b: a hole open on one side (open_hole.cpp) that no depth read
  // 2c: a marker's ink outline (ink_outline.cpp)
  ink_outline_unread,    // (not yet read)
  ink_cells_unresolved,  // its cells under kResolvedCells across
  ink_read_corrected,    // its read outvoted a cell
  // 3. edge refinement
  small_hole,       // the quad's mean side under min_hole_side_px
  few_edge_points,  // a side with under three edge points
  no_edge_line,     // a side's points give no line
  parallel_sides,   // two neighbouring sides do not meet
  corner_moved,     // a refined corner moved more than two cells from the coarse one
  sliver,           // a side under kMinSideRatio of the longest
  degenerate_quad,  // no homography maps the unit square onto the quad
  // 4a. the cells
  corner_off_image,  // a corner cell lies outside the image
  cells_off_image,   // fewer than 24 data cells inside the image
  cells_too_small,   // cells under kMinCells pixels
  sides_unequal,     // opposite sides beyond kMaxSideRatio (small cells: kMaxSmallSideRatio)
  // 4b. the grey model
  one_grey_level,  // the ring's levels do not split into black and white
  no_contrast,     // black and white too close
  grey_ink,        // the black cells too light for ink beside the white ones
  // 4c. orientation
  white_corner_count,  // no white corner, or more than two
  white_corner_unclear,
  short_edges_unexplained,  // the short edges' profiles do not fit the code
  c1_contradicted,          // C1's ring neighbours contradict the code
  // 4d. the bit votes
  bit_without_vote,   // no edge voted on a bit
  bit_uncorrectable,  // two dissenting edges, or no agreeing one
  // 4e. structural checks
  many_erasures,              // resolved cells, more erasures than one edge's worth
  low_margin,                 // margin under min_margin
  covered_edge_unclear,       // an edge outvoted, and the other three not read clearly
  tiny_cells_corrected,       // cells under kTinyCells with two bits outvoted
  uniform_id,                 // id 0 or 255 without uniform_ids, or unverifiable
  near_uniform_unconfirmed,   // a near-uniform id (near_uniform) on unresolved cells, not confirmed by the second pass
  near_uniform_outvoted,      // a near-uniform id with a cell outvoted: a grid square beside a row of another colour
  second_leniency,            // orientation unclear on top of a covered edge or a weak code
  unclear_orientation_small,  // orientation unclear and cells under kResolvedCells
  model_line_light,           // the ring model finds the line too light
  line_missing,               // a side without the line's dip
  line_corner_light,          // a corner of the line is light
  line_not_dark,              // the line is not dark all around
  line_not_ink,               // the line is not the black cells' ink
  hole_not_lighter,           // a cell outvoted, and the hole no lighter than its line on two sides or more
  hole_not_blank,             // told paper, the hole not blank paper (a key's glyph, a tile darker than its grout)
  hidden_side_disagrees,      // read again with a covered side hidden, another id
  covered_side_small_cells,   // cells outvoted beside a covered side, too small to read it hidden
  covered_side_unread,        // (second look, near-uniform ids) cells outvoted, the covered side unread hidden
  second_pass_disagrees,      // the sides measured again knowing the code read another id
  unconfirmed_correction,     // bits corrected twice or more, and the second pass fails
  unconfirmed_small_cells,    // cells under 2.5 px read once, the second measurement reading nothing
  unconfirmed_dark_hole,      // a hole as dark as the ink read once, the second measurement reading nothing
  model_disagrees,            // small cells: the ring model, fitted to every pixel, reads otherwise
  model_read_corrected,       // read by the ring model alone, with a cell outvoted
  model_blur_differs,         // read by the ring model alone, a blur a third heavier than the told one fitting better
  grid_like_read,  // a near-uniform id or a cell outvoted, on a hole measured past its first reach, of two pieces, or
                   // seen with a side hidden under 3 px
  outvoted_scattered,  // resolved cells outvoted where no one cover lies (clutter, or a misplaced grid)
  // 5. the whole pattern, 6. corners and pose
  pattern_fit_failed,
  corners_not_convex,  // the outer or inner corners do not make a convex quad
  no_pose,
};

Stage stage_of(Rejection r);
// "4c orientation": the stage's number and name, as in docs/architecture.md.
const char* stage_name(Stage s);
// The enumerator's name ("c1_contradicted").
const char* rejection_name(Rejection r);

// Whether another measurement of the quad (the profile fit, the ring model)
// may read what a sampled read turned down: the read got past the grey
// model (the ring has contrast), or only the quad's shape failed (opposite
// sides unequal, which a remeasured quad may fix).
inline bool worth_remeasuring(Rejection r) { return r == Rejection::sides_unequal || stage_of(r) > Stage::grey_model; }

}  // namespace markerd::detector::frame8
