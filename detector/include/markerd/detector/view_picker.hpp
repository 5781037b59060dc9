#pragma once
// Which frames of a live camera become calibration views (markerctl
// calibrate --live): a person moves a board before the camera, and a frame
// is kept when the board in it is held still and stands apart from every
// view kept so far. Still, because a board moving during the exposure is
// blurred along its motion and its points are pulled with it, which no
// reprojection error shows; apart, because twenty views of one pose
// determine the lens no better than one.

#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "markerd/detector/board.hpp"
#include "markerd/detector/calibration.hpp"

namespace markerd::detector {

struct ViewPickerOptions {
  // The board counts as still when no point it shares with the frame before
  // moved further than this.
  double still_px = 1.0;
  // A frame stands apart from a kept view when the points they share moved
  // this share of the image's diagonal on average (32 px at 640x480), or
  // when they share fewer than min_points.
  double min_move_share = 0.05;
  // Fewer points than this and the frame is no view (CalibrationOptions'
  // min_points: calibrate_camera would turn it down).
  int min_points = CalibrationOptions{}.min_points;
};

enum class PickVerdict {
  no_board,          // nothing of the board found
  too_few_points,    // found, but fewer than min_points
  moving,            // the board moved since the frame before (or there was none to compare)
  like_a_kept_view,  // still, but too like a view already kept
  kept,              // a new view
};

struct Pick {
  PickVerdict verdict = PickVerdict::no_board;
  // kept: its index among the kept views; like_a_kept_view: the view it is like.
  std::size_t view = 0;
  // moving: the largest point's move since the frame before, in pixels (none
  // when there was no frame before with points in common).
  std::optional<double> moved_px;
};

class ViewPicker {
 public:
  ViewPicker(int width, int height, ViewPickerOptions options = {});

  // The next frame's board points; frames must come in the camera's order.
  Pick offer(const BoardPoints& points);

  [[nodiscard]] const std::vector<BoardPoints>& kept() const { return kept_; }
  // Points of the kept views in each of the image's coverage regions (as
  // CalibrationResult::region_points counts them).
  [[nodiscard]] const std::array<int, kCoverageGrid * kCoverageGrid>& region_points() const { return region_points_; }

 private:
  int width_;
  int height_;
  ViewPickerOptions options_;
  BoardPoints previous_;
  std::vector<BoardPoints> kept_;
  std::array<int, kCoverageGrid * kCoverageGrid> region_points_{};
};

}  // namespace markerd::detector
