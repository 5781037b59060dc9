#include "markerd/detector/view_picker.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>
#include <utility>

namespace markerd::detector {

namespace {

// The points two boards share (by their index on the board): how many, the
// largest move and the mean move between them.
struct Shared {
  int count = 0;
  double max_px = 0;
  double mean_px = 0;
};

Shared shared_points(const BoardPoints& a, const BoardPoints& b) {
  std::unordered_map<int, std::size_t> where;
  where.reserve(a.index.size());
  for (std::size_t i = 0; i < a.index.size(); ++i) where.emplace(a.index[i], i);
  Shared s;
  double sum = 0;
  for (std::size_t j = 0; j < b.index.size(); ++j) {
    const auto it = where.find(b.index[j]);
    if (it == where.end()) continue;
    const Point2& p = a.image[it->second];
    const Point2& q = b.image[j];
    const double move = std::hypot(p.x - q.x, p.y - q.y);
    ++s.count;
    sum += move;
    s.max_px = std::max(s.max_px, move);
  }
  if (s.count > 0) s.mean_px = sum / s.count;
  return s;
}

}  // namespace

ViewPicker::ViewPicker(int width, int height, ViewPickerOptions options)
    : width_(width), height_(height), options_(options) {}

Pick ViewPicker::offer(const BoardPoints& points) {
  Pick pick;
  // The frame before is always this one from now on: stillness is between
  // neighbours, whatever became of the frame.
  BoardPoints before = std::exchange(previous_, points);
  if (points.image.empty()) return pick;
  if (std::cmp_less(points.image.size(), options_.min_points)) {
    pick.verdict = PickVerdict::too_few_points;
    return pick;
  }
  const Shared motion = shared_points(before, points);
  if (motion.count > 0) pick.moved_px = motion.max_px;
  // A board half out of the frame before is not known to be still.
  if (motion.count < options_.min_points || motion.max_px > options_.still_px) {
    pick.verdict = PickVerdict::moving;
    return pick;
  }
  const double min_move_px = options_.min_move_share * std::hypot(width_, height_);
  for (std::size_t k = 0; k < kept_.size(); ++k) {
    const Shared s = shared_points(kept_[k], points);
    if (s.count >= options_.min_points && s.mean_px < min_move_px) {
      pick.verdict = PickVerdict::like_a_kept_view;
      pick.view = k;
      return pick;
    }
  }
  pick.verdict = PickVerdict::kept;
  pick.view = kept_.size();
  kept_.push_back(points);
  for (const Point2& p : points.image) ++region_points_[coverage_region(p, width_, height_)];
  return pick;
}

}  // namespace markerd::detector
