#pragma once
#include <array>
#include <cmath>

namespace markerd::detector {

// Image point in pixels; pixel centres at integer coordinates (OpenCV's convention).
struct Point2 {
  double x = 0;
  double y = 0;
  friend Point2 operator+(Point2 a, Point2 b) { return {a.x + b.x, a.y + b.y}; }
  friend Point2 operator-(Point2 a, Point2 b) { return {a.x - b.x, a.y - b.y}; }
  friend Point2 operator*(double s, Point2 a) { return {s * a.x, s * a.y}; }
};

// Image distances never come near overflow: std::hypot's care for it costs
// a library call, and the detectors take thousands of distances a frame.
inline double distance(Point2 a, Point2 b) {
  const double dx = a.x - b.x, dy = a.y - b.y;
  return std::sqrt(dx * dx + dy * dy);
}

// Four corners in the marker frame's order: top-left, top-right, bottom-right, bottom-left.
using Quad = std::array<Point2, 4>;

}  // namespace markerd::detector
