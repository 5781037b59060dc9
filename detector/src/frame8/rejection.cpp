#include "frame8/rejection.hpp"

namespace markerd::detector::frame8 {

Stage stage_of(Rejection r) {
  switch (r) {
    case Rejection::none: return Stage::corners_and_pose;
    case Rejection::touches_border: return Stage::quad_fit;
    case Rejection::box_size: return Stage::quad_fit;
    case Rejection::sparse_component: return Stage::quad_fit;
    case Rejection::not_a_quad: return Stage::quad_fit;
    case Rejection::short_quad_side: return Stage::quad_fit;
    case Rejection::sharp_corner: return Stage::quad_fit;
    case Rejection::small_hole: return Stage::edge_refinement;
    case Rejection::few_edge_points: return Stage::edge_refinement;
    case Rejection::no_edge_line: return Stage::edge_refinement;
    case Rejection::parallel_sides: return Stage::edge_refinement;
    case Rejection::corner_moved: return Stage::edge_refinement;
    case Rejection::sliver: return Stage::edge_refinement;
    case Rejection::degenerate_quad: return Stage::edge_refinement;
    case Rejection::corner_off_image: return Stage::cells;
    case Rejection::cells_off_image: return Stage::cells;
    case Rejection::cells_too_small: return Stage::cells;
    case Rejection::sides_unequal: return Stage::cells;
    case Rejection::one_grey_level: return Stage::grey_model;
    case Rejection::no_contrast: return Stage::grey_model;
    case Rejection::grey_ink: return Stage::grey_model;
    case Rejection::white_corner_count: return Stage::orientation;
    case Rejection::white_corner_unclear: return Stage::orientation;
    case Rejection::short_edges_unexplained: return Stage::orientation;
    case Rejection::c1_contradicted: return Stage::orientation;
    case Rejection::bit_without_vote: return Stage::bit_votes;
    case Rejection::bit_uncorrectable: return Stage::bit_votes;
    case Rejection::many_erasures: return Stage::structure;
    case Rejection::low_margin: return Stage::structure;
    case Rejection::covered_edge_unclear: return Stage::structure;
    case Rejection::tiny_cells_corrected: return Stage::structure;
    case Rejection::uniform_id: return Stage::structure;
    case Rejection::near_uniform_unconfirmed: return Stage::structure;
    case Rejection::near_uniform_outvoted: return Stage::structure;
    case Rejection::second_leniency: return Stage::structure;
    case Rejection::unclear_orientation_small: return Stage::structure;
    case Rejection::model_line_light: return Stage::structure;
    case Rejection::line_missing: return Stage::structure;
    case Rejection::line_corner_light: return Stage::structure;
    case Rejection::line_not_dark: return Stage::structure;
    case Rejection::line_not_ink: return Stage::structure;
    case Rejection::hole_not_lighter: return Stage::structure;
    case Rejection::hole_not_blank: return Stage::structure;
    case Rejection::open_hole_unread: return Stage::quad_fit;
    case Rejection::ink_outline_unread: return Stage::quad_fit;
    case Rejection::ink_cells_unresolved: return Stage::cells;
    case Rejection::ink_read_corrected: return Stage::bit_votes;
    case Rejection::hidden_side_disagrees: return Stage::structure;
    case Rejection::covered_side_small_cells: return Stage::structure;
    case Rejection::covered_side_unread: return Stage::structure;
    case Rejection::second_pass_disagrees: return Stage::structure;
    case Rejection::unconfirmed_correction: return Stage::structure;
    case Rejection::unconfirmed_small_cells: return Stage::structure;
    case Rejection::unconfirmed_dark_hole: return Stage::structure;
    case Rejection::model_disagrees: return Stage::structure;
    case Rejection::model_read_corrected: return Stage::structure;
    case Rejection::model_blur_differs: return Stage::structure;
    case Rejection::grid_like_read: return Stage::structure;
    case Rejection::outvoted_scattered: return Stage::structure;
    case Rejection::pattern_fit_failed: return Stage::pattern_fit;
    case Rejection::corners_not_convex:
    case Rejection::no_pose: return Stage::corners_and_pose;
  }
  return Stage::corners_and_pose;
}

const char* stage_name(Stage s) {
  switch (s) {
    case Stage::segmentation: return "1 segmentation";
    case Stage::quad_fit: return "2 quad fit";
    case Stage::edge_refinement: return "3 edge refinement";
    case Stage::cells: return "4a cells";
    case Stage::grey_model: return "4b grey model";
    case Stage::orientation: return "4c orientation";
    case Stage::bit_votes: return "4d bit votes";
    case Stage::structure: return "4e structure";
    case Stage::pattern_fit: return "5 pattern fit";
    case Stage::corners_and_pose: return "6 corners and pose";
  }
  return "?";
}

const char* rejection_name(Rejection r) {
  switch (r) {
    case Rejection::none: return "none";
    case Rejection::touches_border: return "touches_border";
    case Rejection::box_size: return "box_size";
    case Rejection::sparse_component: return "sparse_component";
    case Rejection::not_a_quad: return "not_a_quad";
    case Rejection::short_quad_side: return "short_quad_side";
    case Rejection::sharp_corner: return "sharp_corner";
    case Rejection::small_hole: return "small_hole";
    case Rejection::few_edge_points: return "few_edge_points";
    case Rejection::no_edge_line: return "no_edge_line";
    case Rejection::parallel_sides: return "parallel_sides";
    case Rejection::corner_moved: return "corner_moved";
    case Rejection::sliver: return "sliver";
    case Rejection::degenerate_quad: return "degenerate_quad";
    case Rejection::corner_off_image: return "corner_off_image";
    case Rejection::cells_off_image: return "cells_off_image";
    case Rejection::cells_too_small: return "cells_too_small";
    case Rejection::sides_unequal: return "sides_unequal";
    case Rejection::one_grey_level: return "one_grey_level";
    case Rejection::no_contrast: return "no_contrast";
    case Rejection::grey_ink: return "grey_ink";
    case Rejection::white_corner_count: return "white_corner_count";
    case Rejection::white_corner_unclear: return "white_corner_unclear";
    case Rejection::short_edges_unexplained: return "short_edges_unexplained";
    case Rejection::c1_contradicted: return "c1_contradicted";
    case Rejection::bit_without_vote: return "bit_without_vote";
    case Rejection::bit_uncorrectable: return "bit_uncorrectable";
    case Rejection::many_erasures: return "many_erasures";
    case Rejection::low_margin: return "low_margin";
    case Rejection::covered_edge_unclear: return "covered_edge_unclear";
    case Rejection::tiny_cells_corrected: return "tiny_cells_corrected";
    case Rejection::uniform_id: return "uniform_id";
    case Rejection::near_uniform_unconfirmed: return "near_uniform_unconfirmed";
    case Rejection::near_uniform_outvoted: return "near_uniform_outvoted";
    case Rejection::second_leniency: return "second_leniency";
    case Rejection::unclear_orientation_small: return "unclear_orientation_small";
    case Rejection::model_line_light: return "model_line_light";
    case Rejection::line_missing: return "line_missing";
    case Rejection::line_corner_light: return "line_corner_light";
    case Rejection::line_not_dark: return "line_not_dark";
    case Rejection::line_not_ink: return "line_not_ink";
    case Rejection::hole_not_blank: return "hole_not_blank";
    case Rejection::hole_not_lighter: return "hole_not_lighter";
    case Rejection::open_hole_unread: return "open_hole_unread";
    case Rejection::grid_like_read: return "grid_like_read";
    case Rejection::outvoted_scattered: return "outvoted_scattered";
    case Rejection::ink_outline_unread: return "ink_outline_unread";
    case Rejection::ink_cells_unresolved: return "ink_cells_unresolved";
    case Rejection::ink_read_corrected: return "ink_read_corrected";
    case Rejection::hidden_side_disagrees: return "hidden_side_disagrees";
    case Rejection::covered_side_small_cells: return "covered_side_small_cells";
    case Rejection::covered_side_unread: return "covered_side_unread";
    case Rejection::second_pass_disagrees: return "second_pass_disagrees";
    case Rejection::unconfirmed_correction: return "unconfirmed_correction";
    case Rejection::unconfirmed_small_cells: return "unconfirmed_small_cells";
    case Rejection::unconfirmed_dark_hole: return "unconfirmed_dark_hole";
    case Rejection::model_disagrees: return "model_disagrees";
    case Rejection::model_read_corrected: return "model_read_corrected";
    case Rejection::model_blur_differs: return "model_blur_differs";
    case Rejection::pattern_fit_failed: return "pattern_fit_failed";
    case Rejection::corners_not_convex: return "corners_not_convex";
    case Rejection::no_pose: return "no_pose";
  }
  return "?";
}

}  // namespace markerd::detector::frame8
