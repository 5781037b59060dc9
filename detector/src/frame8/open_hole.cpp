// Stage 2b, a hole open on one side: candidates for markers whose hole has
// no component of its own. An object in front of one side, as light as the
// hole (a hand, a white cable duct, the paper of a neighbouring print),
// hides that side's ring and line: the hole's light pixels run on into the
// object's, and no quad is fitted (quad_fit.cpp). What is left of the hole
// is the line's three visible sides, a U of an outline whose inside is
// light. After the quads, the outlines of the components that were no quad
// are traced, cut into straight pieces, and each such U handed to the read
// with its open side hidden (hidden_side.cpp).
//
// The tracing runs on the threshold's bits halved in each direction (a
// pixel there is light when all four of its pixels are: the line only
// grows), so that it costs half as much: a cluttered frame's outlines run
// to some 20,000 pixel edges.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

namespace {

// How far a straight piece of an outline may stray from its chord, in
// traced pixels: the staircase of a traced slant and a little noise.
constexpr double kStraightTolerance = 1.5;
// The U's arms: how much of the hole the cover leaves (a cover up to the
// depth read_hidden_side tries leaves 4.5 of the 7 cells), as a share of
// the full side between them, with a marker turned up to about 60 degrees
// either way, which shortens one or the other.
constexpr double kMinArm = 0.3;
constexpr double kMaxArm = 2.5;
// Pieces shorter than this share of the full side, between the arms and
// the full side, are the corners' rounding or blur.
constexpr double kCornerPiece = 0.2;
// The hole's corners are turns of 30 to 150 degrees (the sine of the turn);
// the arms, a square's opposite sides, converge by less than 40 degrees.
constexpr double kMinTurnSine = 0.5;
constexpr double kMinArmsCosine = 0.75;

Point2 project(const Line& l, Point2 p) {
  const double off = l.nx * p.x + l.ny * p.y - l.c;
  return {p.x - off * l.nx, p.y - off * l.ny};
}

// The part of a U's hole that is seen: from the full side v1-v2 down the
// arms (lines through v1 and v2; end_a and end_b where each ends), closed
// parallel to the full side where the shorter arm ends. False when the
// closing line misses the other arm.
bool close_at_shorter_arm(Point2 v1, Point2 v2, const Line& arm_a, const Line& arm_b, Point2 end_a, Point2 end_b,
                          std::array<Point2, 4>& seen) {
  const Point2 along = v2 - v1;
  Point2 p0 = end_a, p3 = end_b;
  if (distance(v1, end_a) <= distance(v2, end_b) ? !intersect(line_through(end_a, end_a + along), arm_b, p3)
                                                 : !intersect(line_through(end_b, end_b + along), arm_a, p0)) {
    return false;
  }
  seen = {p0, v1, v2, p3};
  return true;
}

}  // namespace

// The outline through the left end of the traced pixel (x, y), as the
// pixel corners where it turns (working-image pixel-centre coordinates),
// the light pixels on its right: clockwise on screen around a component,
// anticlockwise around a dark island within it. Components are
// 4-connected: a pixel touching one only by a corner is outside it. Marks
// the left end of every run it passes, so that each outline is traced once.
void Frame8Detector::trace_outline(const TraceBits& t, int start_x, int start_y) {
  outline_.clear();
  // Directions: east, south, west, north (y down); a right turn adds one.
  // Per direction, the step, and the two pixels ahead of the corner
  // reached, left and right of the heading, relative to it.
  constexpr std::array<int, 4> kDx{1, 0, -1, 0}, kDy{0, 1, 0, -1};
  constexpr std::array<int, 4> kLeftX{0, 0, -1, -1}, kLeftY{-1, 0, 0, -1};
  constexpr std::array<int, 4> kRightX{0, -1, -1, 0}, kRightY{0, 0, -1, -1};
  const int sx = start_x, sy = start_y + 1, sd = 3;  // up the pixel's left side
  const double scale = t.scale;
  int x = sx, y = sy, d = sd;
  int x0 = x, x1 = x, y0 = y, y1 = y;
  do {
    const auto du = static_cast<std::size_t>(d);
    if (d == 3) {
      // The crack from (x, y) up to (x, y - 1) is the left end of a run on row y - 1.
      t.passed[t.stride * static_cast<std::size_t>(y - 1) + static_cast<std::size_t>(x >> 6)] |= std::uint64_t{1}
                                                                                                 << (x & 63);
    }
    x += kDx[du];
    y += kDy[du];
    int turn = 0;
    if (!t.light(x + kRightX[du], y + kRightY[du])) {
      turn = 1;
    } else if (t.light(x + kLeftX[du], y + kLeftY[du])) {
      turn = 3;
    }
    if (turn != 0) {
      outline_.push_back({x * scale - 0.5, y * scale - 0.5});
      x0 = std::min(x0, x);
      x1 = std::max(x1, x);
      y0 = std::min(y0, y);
      y1 = std::max(y1, y);
      d = (d + turn) & 3;
    }
  } while (x != sx || y != sy || d != sd);
  outline_extent_ = std::max(x1 - x0, y1 - y0) * t.scale;
}

// The outline's corners (indices into outline_, in order): its straight
// pieces, each grown from the end of the last as long as one line through
// its ends passes every point between within kStraightTolerance (the
// directions that do form a cone from the piece's start, narrowed at each
// point). One pass, linear in the outline: the outlines of a cluttered
// frame run to thousands of pixels. The first piece starts anywhere, so
// the pieces are taken from its end round to it again.
void Frame8Detector::simplify_outline() {
  outline_corners_.clear();
  const auto n = static_cast<std::int32_t>(outline_.size());
  if (n < 4) return;
  auto at = [&](std::int32_t i) { return outline_[static_cast<std::size_t>(i % n)]; };
  const double tolerance = kStraightTolerance * kTraceScale;
  // The last index a straight piece from `from` reaches (at most from + n).
  auto piece_end = [&](std::int32_t from) {
    const Point2 o = at(from);
    Point2 lo{}, hi{};  // the cone's edges, as directions
    bool open = false;
    std::int32_t end = from + 1;
    for (std::int32_t i = from + 1; i <= from + n; ++i) {
      const Point2 v = at(i) - o;
      const double r2 = v.x * v.x + v.y * v.y;
      if (r2 <= tolerance * tolerance) {
        end = i;
        continue;
      }
      if (open && (lo.x * v.y - lo.y * v.x < 0 || v.x * hi.y - v.y * hi.x < 0)) break;
      end = i;
      // The directions within the tolerance of this point: v turned by
      // +-asin(tol / r), scaled by r (only their sides of each other count).
      const double s = tolerance, c = std::sqrt(r2 - s * s);
      const Point2 vlo{c * v.x + s * v.y, -s * v.x + c * v.y}, vhi{c * v.x - s * v.y, s * v.x + c * v.y};
      if (!open) {
        lo = vlo;
        hi = vhi;
        open = true;
        continue;
      }
      if (lo.x * vlo.y - lo.y * vlo.x > 0) lo = vlo;
      if (vhi.x * hi.y - vhi.y * hi.x > 0) hi = vhi;
      if (lo.x * hi.y - lo.y * hi.x < 0) break;
    }
    return end;
  };
  const std::int32_t first = piece_end(0) % n;
  for (std::int32_t i = first; i < first + n;) {
    outline_corners_.push_back(i % n);
    i = piece_end(i);
  }
}

// Whether the ring beyond a full side of the hole, from corner `a` to `b`
// (working image, clockwise), shows black and white cells: every id but 0
// and 255 has both among each edge's eight data cells, one cell out from
// the hole. Clutter's U shapes mostly have neither, and this costs a few
// samples against up to a dozen reads. The samples are grey levels (the
// threshold takes a small white cell's inner pixels, next to the line, for
// dark), four spread over each cell: the traced outline lies up to half a
// traced pixel inside the hole's edge, which at 3 px a cell puts a single
// sample on the line's blur, and a near-uniform id's one cell of the other
// colour lies at the end of the edge, beside the corner.
bool Frame8Detector::ring_shows_both_colours(Point2 a, Point2 b) const {
  const double d = decimate_;
  a = to_full(a);
  b = to_full(b);
  const Point2 along = b - a;
  const double len = std::hypot(along.x, along.y), cell = len / kInnerSide;
  const Point2 out{along.y / len, -along.x / len};  // a pixel outward
  const double bias = 0.5 * kTraceScale * d;
  float hole = 0;
  const Point2 middle = a + 0.5 * along + (-cell) * out;
  if (!sample(full_, middle.x, middle.y, hole)) return false;
  float lo = 255, hi = 0;
  for (int k = 0; k < 8; ++k) {
    for (const double along_cell : {-0.2, 0.2}) {
      for (const double across : {0.85, 1.15}) {
        const Point2 p = a + ((k + along_cell) / kInnerSide) * along + (across * cell + bias) * out;
        float v = 0;
        if (!sample(full_, p.x, p.y, v)) return false;
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
  }
  // White cells come up to the hole's level, black ones well below it.
  constexpr float kMinContrast = 30;
  return hole - lo >= kMinContrast && hi - lo >= 0.5F * (hole - lo);
}

// The pixels outlines are traced on: the working image's light bits halved
// in each direction (a pixel light when its four are).
void Frame8Detector::make_traced_bits() {
  static_assert(kTraceScale == 2);
  trace_w_ = work_.width / 2;
  trace_h_ = work_.height / 2;
  trace_stride_ = static_cast<std::size_t>((trace_w_ + 63) / 64) + 1;
  traced_bits_.assign(trace_stride_ * static_cast<std::size_t>(trace_h_), 0);
  traced_.assign(traced_bits_.size(), 0);
  // Bits 2i and 2i + 1 of the two rows, ANDed, to bit i: the even bits of
  // (a & a >> 1) gathered into the low half, a shift-and-mask step at a time.
  auto gather_even = [](std::uint64_t v) {
    v &= 0x5555555555555555ULL;
    v = (v | (v >> 1)) & 0x3333333333333333ULL;
    v = (v | (v >> 2)) & 0x0F0F0F0F0F0F0F0FULL;
    v = (v | (v >> 4)) & 0x00FF00FF00FF00FFULL;
    v = (v | (v >> 8)) & 0x0000FFFF0000FFFFULL;
    v = (v | (v >> 16)) & 0x00000000FFFFFFFFULL;
    return v;
  };
  const std::size_t words = (static_cast<std::size_t>(work_.width) + 63) / 64;
  for (int y = 0; y < trace_h_; ++y) {
    const std::uint64_t* a = light_bits_.data() + light_stride_ * static_cast<std::size_t>(2 * y);
    const std::uint64_t* b = a + light_stride_;
    std::uint64_t* out = traced_bits_.data() + trace_stride_ * static_cast<std::size_t>(y);
    for (std::size_t i = 0; i < words; ++i) {
      const std::uint64_t both = a[i] & b[i];
      out[i / 2] |= gather_even(both & (both >> 1)) << (32 * (i % 2));
    }
    // An odd width leaves a last half pixel: not light.
    if (trace_w_ % 64 != 0) out[trace_w_ / 64] &= (std::uint64_t{1} << (trace_w_ % 64)) - 1;
  }
}

// Components up to this size (working pixels) have their islands traced
// on the unhalved bits: a print's 10 mm margin is 4 px at 1.2 m, less the
// threshold's rims, and halved it is gone.
constexpr int kUnhalvedIslandsBox = 256;
namespace {
bool unhalved_islands(const Component& c) { return std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) <= kUnhalvedIslandsBox; }
}  // namespace

void Frame8Detector::find_open_holes(std::vector<Detection>& out) {
  make_traced_bits();
  const int s = kTraceScale;
  const double min_side = min_open_hole_side();
  if (seeks_ink_outline_) find_ink_islands_unhalved(min_side, out);
  const TraceBits halved{traced_bits_.data(), traced_.data(), trace_stride_, trace_w_, trace_h_, kTraceScale};
  for (int y = 0; y < trace_h_; ++y) {
    const std::uint64_t* row = traced_bits_.data() + trace_stride_ * static_cast<std::size_t>(y);
    std::uint64_t carry = 0;
    for (std::size_t i = 0; i < trace_stride_; ++i) {
      // The left ends of the row's runs of light pixels.
      std::uint64_t ends = row[i] & ~((row[i] << 1) | carry);
      carry = row[i] >> 63;
      for (; ends != 0; ends &= ends - 1) {
        const int x = static_cast<int>(i * 64) + __builtin_ctzll(ends);
        if ((traced_[trace_stride_ * static_cast<std::size_t>(y) + i] >> (x & 63)) & 1U) continue;
        // Its component was read, lies in a detection, or is a quad
        // without a dark island worth a look.
        const Component* c = component_at(x * s, y * s);
        if (c == nullptr || c->settled) continue;
        // A small quad's islands were traced unhalved, and its own outline
        // holds no open hole: nothing here to trace it for.
        if (c->quad && unhalved_islands(*c)) continue;
        trace_outline(halved, x, y);
        if (outline_extent_ < min_side) continue;
        // Clockwise round the component itself, anticlockwise round an
        // island within it.
        const bool island = twice_signed_area(outline_.data(), outline_.size()) < 0;
        if (island && seeks_ink_outline_ && !unhalved_islands(*c)) find_marker_on_ink_outline(kTraceScale, out);
        // A quad's outline and its islands' have been measured as a
        // quad's already.
        if (c->quad) continue;
        simplify_outline();
        find_open_holes_on_outline(min_side, out);
      }
    }
  }
}

void Frame8Detector::find_ink_islands_unhalved(double min_side, std::vector<Detection>& out) {
  passed_unhalved_.assign(light_bits_.size(), 0);
  const TraceBits unhalved{light_bits_.data(), passed_unhalved_.data(), light_stride_, work_.width, work_.height, 1};
  const double min_island_area = kMinInkShare * min_side * min_side;
  for (const std::int32_t root : roots_) {
    const Component& c = components_[static_cast<std::size_t>(root)];
    if (c.settled || !unhalved_islands(c) || std::max(c.x1 - c.x0, c.y1 - c.y0 + 1) < min_side) continue;
    // Its rows' spans must hold dark pixels enough for a marker's ink
    // (what fit_quad() measured; a component it turned down on its box
    // alone has none worth a look).
    if (static_cast<double>(c.dark_inside) < min_island_area) continue;
    // An island's outline passes the left end of a run of the component
    // that has dark pixels to its left within the component's box.
    for (std::int32_t r = c.first; r >= 0; r = runs_[static_cast<std::size_t>(r)].next) {
      const Run& run = runs_[static_cast<std::size_t>(r)];
      if (run.x0 <= c.x0 || unhalved.was_passed(run.x0, run.y)) continue;
      trace_outline(unhalved, run.x0, run.y);
      if (outline_extent_ < min_side) continue;
      if (twice_signed_area(outline_.data(), outline_.size()) < 0) find_marker_on_ink_outline(1, out);
    }
  }
}

const Component* Frame8Detector::component_at(int x, int y) const {
  const auto first = runs_.begin() + row_first_[static_cast<std::size_t>(y)];
  const auto last = runs_.begin() + row_first_[static_cast<std::size_t>(y) + 1];
  auto it = std::upper_bound(first, last, x, [](int value, const Run& r) { return value < r.x0; });
  if (it == first) return nullptr;
  --it;
  return x < it->x1 ? &components_[static_cast<std::size_t>(it->parent)] : nullptr;
}

void Frame8Detector::find_open_holes_on_outline(double min_side, std::vector<Detection>& out) {
  const auto m = static_cast<std::int32_t>(outline_corners_.size());
  if (m < 3) return;
  auto corner = [&](std::int32_t k) {
    return outline_[static_cast<std::size_t>(outline_corners_[static_cast<std::size_t>(((k % m) + m) % m)])];
  };
  auto piece = [&](std::int32_t k) { return distance(corner(k), corner(k + 1)); };
  for (std::int32_t j = 0; j < m; ++j) {
    const double side = piece(j);
    if (side < min_side) continue;
    // The arms: the nearest pieces before and after that are not a corner's rounding.
    std::int32_t a = j - 1, b = j + 1;
    double rounding = 0;
    while (a > j - m && piece(a) < kCornerPiece * side) rounding += piece(a--);
    while (b < j + m && piece(b) < kCornerPiece * side) rounding += piece(b++);
    if (rounding > kCornerPiece * side || a <= j - m || b >= j + m || (a + m) % m == (b % m)) continue;
    const Point2 a0 = corner(a), a1 = corner(a + 1), s0 = corner(j), s1 = corner(j + 1), b0 = corner(b),
                 b1 = corner(b + 1);
    // Both turns to the right: the component is inside the U.
    const Point2 da = a1 - a0, ds = s1 - s0, db = b1 - b0;
    const double la = std::hypot(da.x, da.y), lb = std::hypot(db.x, db.y);
    if ((da.x * ds.y - da.y * ds.x) / (la * side) < kMinTurnSine) continue;
    if ((ds.x * db.y - ds.y * db.x) / (side * lb) < kMinTurnSine) continue;
    if (-(da.x * db.x + da.y * db.y) / (la * lb) < kMinArmsCosine) continue;
    const Line arm_a = line_through(a0, a1), full = line_through(s0, s1), arm_b = line_through(b0, b1);
    Point2 v1, v2;
    if (!intersect(arm_a, full, v1) || !intersect(full, arm_b, v2)) continue;
    const Point2 end_a = project(arm_a, a0), end_b = project(arm_b, b1);
    const double reach_a = distance(v1, end_a), reach_b = distance(v2, end_b), width = distance(v1, v2);
    if (std::min(reach_a, reach_b) < kMinArm * width || std::max(reach_a, reach_b) > kMaxArm * width) continue;
    if (!ring_shows_both_colours(v1, v2)) continue;
    std::array<Point2, 4> seen{};
    if (!close_at_shorter_arm(v1, v2, arm_a, arm_b, end_a, end_b, seen)) continue;
    for (auto& p : seen) p = to_full(p);
    // The ring lies 1.5 cells beyond the hole's corners: where that is
    // off the image (the image's own border makes straight outlines and
    // right angles), there is nothing to read.
    const double ring = kInnerLo * distance(seen[1], seen[2]) / kInnerSide;
    auto in_image = [&](Point2 p) {
      return p.x >= ring && p.y >= ring && p.x <= full_.width - 1 - ring && p.y <= full_.height - 1 - ring;
    };
    if (!in_image(seen[1]) || !in_image(seen[2])) continue;
    const Point2 centre = centre_of(seen);
    if (inside_any(out, centre)) continue;
    if (debug_) debug_candidates_.push_back({seen, Rejection::open_hole_unread, -1, {}, {}});
    Detection det;
    if (read_open_hole(seen, det) == Rejection::none) {
      note_outcome(Rejection::none, det);
      out.push_back(det);
    }
  }
}

// The U's three sides measured at full resolution as any quad's (stage 3),
// the open side (3) left where the shorter arm ends, then read with that
// side hidden to each depth.
Rejection Frame8Detector::read_open_hole(const std::array<Point2, 4>& coarse, Detection& det) {
  std::array<Line, 3> lines{};
  const double cell_px = distance(coarse[1], coarse[2]) / kInnerSide;
  for (int side = 0; side < 3; ++side) {
    if (const Rejection why =
            fit_side(coarse, side, EdgeMode::step, std::nullopt, cell_px, lines[static_cast<std::size_t>(side)]);
        why != Rejection::none) {
      return why;
    }
  }
  Point2 v1, v2;
  if (!intersect(lines[0], lines[1], v1) || !intersect(lines[1], lines[2], v2)) return Rejection::parallel_sides;
  if (corner_moved(v1, coarse[1], cell_px) || corner_moved(v2, coarse[2], cell_px)) return Rejection::corner_moved;
  std::array<Point2, 4> seen{};
  if (!close_at_shorter_arm(v1, v2, lines[0], lines[2], project(lines[0], coarse[0]), project(lines[2], coarse[3]),
                            seen)) {
    return Rejection::parallel_sides;
  }
  if (!convex(seen)) return Rejection::corners_not_convex;
  int rotation = 0;
  HiddenSide hidden;
  Homography H;
  if (!read_hidden_side(seen, 3, HoleEnd::open, det, rotation, hidden, H)) return Rejection::open_hole_unread;
  return finish_from_hole(H, hidden, rotation, cell_px, det);
}

}  // namespace markerd::detector::frame8
