// The frame8 detector.
//
// The thesis found the marker with Canny, contours and approxPolyDP and read
// it by counting pixels per cell against a fixed 127 threshold. Here:
//
//  1. Segmentation on a (possibly decimated) working image: a pixel is dark
//     when it lies a few grey levels under the mean of its neighbourhood (tile
//     means, so the threshold follows light falloff and exposure). Light
//     pixels are grouped into 4-connected components from row runs with
//     union-find; the hole of a marker is a light component enclosed by the
//     black line (8-connected dark, so a line one pixel thin on a diagonal
//     still closes it).
//  2. Each enclosed component's convex hull is fitted with its largest
//     inscribed quadrilateral; components that are not quads are dropped.
//  3. Each side of the quad is refined at full resolution: points along the
//     side search the intensity profile across it for the light-to-dark step
//     into the line, with sub-pixel peak interpolation, and a weighted total
//     least-squares line is fitted (with one round of outlier rejection). The
//     corners are the intersections. With a camera model the same edge points
//     are fitted again in undistorted coordinates, so the corners and the pose
//     are right under lens distortion.
//  4. The ring is sampled at the centre of each cell (the thesis's own future
//     work) through the homography of the refined quad; black and white levels
//     come from the cells themselves (2-means seeded by the corners), each cell
//     gives a soft vote, and every bit is decided over the four edges, each
//     weighted by how well its cells are resolved. A bit with two confident
//     dissenting edges is uncorrectable and rejects the candidate.
//
// Memory: every buffer is a member that grows to the largest frame seen and is
// reused, so detect() allocates nothing in steady state.

#include "frame8_detector.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "frame8_ring_model.hpp"
#include "normal_table.hpp"
#include "markerd/detector/frame8.hpp"

#ifdef FRAME8_DEBUG
#include <cstdio>
#define F8_TRACE(...) std::fprintf(stderr, __VA_ARGS__)
#else
#define F8_TRACE(...) ((void)0)
#endif
#include "markerd/detector/pose.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

namespace markerd {
namespace {

constexpr int kTile = 4;  // threshold tile side, working-image pixels

// ceil(2^32 / n) for every pixel count n of a 3x3-tile neighbourhood. For
// s up to kMaxTileSum, (s * r[n]) >> 32 is s / n exactly: the product
// overshoots s / n by under s / 2^32, less than the 1/n that separates a
// fraction s/n from the next integer.
constexpr int kMaxNeighbourhood = 9 * kTile * kTile;
constexpr std::uint64_t kMaxTileSum = 256ULL * kMaxNeighbourhood;  // the pixels' sum, plus n/2 for rounding
static_assert(kMaxTileSum * kMaxNeighbourhood < (1ULL << 32));
constexpr std::array<std::uint64_t, kMaxNeighbourhood + 1> make_reciprocals() {
  std::array<std::uint64_t, kMaxNeighbourhood + 1> r{};
  for (std::uint64_t n = 1; n <= kMaxNeighbourhood; ++n) r[n] = ((1ULL << 32) + n - 1) / n;
  return r;
}
constexpr std::array<std::uint64_t, kMaxNeighbourhood + 1> kReciprocal = make_reciprocals();

// Maps the unit square (0,0) (1,0) (1,1) (0,1) onto a quad (Heckbert's closed form).
struct Homography {
  double a = 1, b = 0, c = 0, d = 0, e = 1, f = 0, g = 0, h = 0;

  static bool from_unit_square(const std::array<Point2, 4>& q, Homography& out) {
    const double sx = q[0].x - q[1].x + q[2].x - q[3].x;
    const double sy = q[0].y - q[1].y + q[2].y - q[3].y;
    const double dx1 = q[1].x - q[2].x, dx2 = q[3].x - q[2].x;
    const double dy1 = q[1].y - q[2].y, dy2 = q[3].y - q[2].y;
    const double den = dx1 * dy2 - dx2 * dy1;
    if (std::abs(den) < 1e-12) return false;
    out.g = (sx * dy2 - dx2 * sy) / den;
    out.h = (dx1 * sy - sx * dy1) / den;
    out.a = q[1].x - q[0].x + out.g * q[1].x;
    out.b = q[3].x - q[0].x + out.h * q[3].x;
    out.c = q[0].x;
    out.d = q[1].y - q[0].y + out.g * q[1].y;
    out.e = q[3].y - q[0].y + out.h * q[3].y;
    out.f = q[0].y;
    return true;
  }
  // From a map of grid coordinates (see grid_map() below).
  static Homography from_grid_map(const Eigen::Matrix3d& grid_to_image);

  [[nodiscard]] Point2 map(double u, double v) const {
    const double w = g * u + h * v + 1;
    return {(a * u + b * v + c) / w, (d * u + e * v + f) / w};
  }
};

// Grid coordinates (0..10 across the marker, y down) of the inner square's
// corners, and the map from grid coordinates to the unit square of that quad.
constexpr double kInnerLo = frame8::line_inner;
constexpr double kInnerSide = frame8::grid - 2 * frame8::line_inner;  // 7 cells
inline Point2 grid_point(const Homography& H, double gx, double gy) {
  return H.map((gx - kInnerLo) / kInnerSide, (gy - kInnerLo) / kInnerSide);
}

inline Point2 grid_point(const Homography& H, Point2 g) { return grid_point(H, g.x, g.y); }

// The same map as a 3x3 matrix on homogeneous grid coordinates.
Eigen::Matrix3d grid_map(const Homography& H) {
  Eigen::Matrix3d unit_to_image;
  unit_to_image << H.a, H.b, H.c, H.d, H.e, H.f, H.g, H.h, 1;
  Eigen::Matrix3d grid_to_unit;
  grid_to_unit << 1 / kInnerSide, 0, -kInnerLo / kInnerSide, 0, 1 / kInnerSide, -kInnerLo / kInnerSide, 0, 0, 1;
  return unit_to_image * grid_to_unit;
}

Homography Homography::from_grid_map(const Eigen::Matrix3d& grid_to_image) {
  Eigen::Matrix3d unit_to_grid;
  unit_to_grid << kInnerSide, 0, kInnerLo, 0, kInnerSide, kInnerLo, 0, 0, 1;
  Eigen::Matrix3d m = grid_to_image * unit_to_grid;
  m /= m(2, 2);
  Homography h;
  h.a = m(0, 0), h.b = m(0, 1), h.c = m(0, 2);
  h.d = m(1, 0), h.e = m(1, 1), h.f = m(1, 2);
  h.g = m(2, 0), h.h = m(2, 1);
  return h;
}

inline Point2 map_grid(const Eigen::Matrix3d& M, double gx, double gy) {
  const Eigen::Vector3d q = M * Eigen::Vector3d(gx, gy, 1);
  return {q(0) / q(2), q(1) / q(2)};
}

// The grid point `in` cells in from the outer edge on a side (0 top, 1
// right, 2 bottom, 3 left), `along` cells along it in the clockwise reading
// order: one description of a position for all four sides.
inline Point2 side_point(int side, double along, double in) {
  switch (side) {
    case 0: return {along, in};
    case 1: return {frame8::grid - in, along};
    case 2: return {frame8::grid - along, frame8::grid - in};
    default: return {in, frame8::grid - along};
  }
}

inline double cross(Point2 o, Point2 a, Point2 b) { return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x); }

// Bilinear sample; false outside the image.
inline bool sample(const GreyView& img, double x, double y, float& out) {
  if (!(x >= 0 && y >= 0 && x <= img.width - 1.001 && y <= img.height - 1.001)) return false;
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const std::uint8_t* r0 = img.row(y0) + x0;
  const std::uint8_t* r1 = r0 + img.stride;
  const float top = r0[0] + fx * (r0[1] - r0[0]);
  const float bot = r1[0] + fx * (r1[1] - r1[0]);
  out = top + fy * (bot - top);
  return true;
}

struct Line {
  double nx = 0, ny = 0, c = 0;  // nx*x + ny*y = c, |n| = 1
};

// Twice the signed area of a polygon (the shoelace sum): positive when its
// vertices run clockwise on screen (y down).
inline double twice_signed_area(const Point2* v, std::size_t n) {
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Point2 a = v[i], b = v[(i + 1) % n];
    sum += a.x * b.y - b.x * a.y;
  }
  return sum;
}

inline bool intersect(const Line& l1, const Line& l2, Point2& p) {
  const double det = l1.nx * l2.ny - l1.ny * l2.nx;
  if (std::abs(det) < 1e-9) return false;
  p = {(l1.c * l2.ny - l1.ny * l2.c) / det, (l1.nx * l2.c - l1.c * l2.nx) / det};
  return true;
}

struct EdgePoint {
  double x, y, w;
};

// Weighted total least squares; drops points further than `reject` from a
// first fit and fits again.
bool fit_line(EdgePoint* pts, int n, double reject, Line& line) {
  auto fit = [&](Line& out) {
    double sw = 0, mx = 0, my = 0;
    for (int i = 0; i < n; ++i) {
      if (pts[i].w <= 0) continue;
      sw += pts[i].w;
      mx += pts[i].w * pts[i].x;
      my += pts[i].w * pts[i].y;
    }
    if (sw <= 0) return false;
    mx /= sw;
    my /= sw;
    double sxx = 0, sxy = 0, syy = 0;
    int used = 0;
    for (int i = 0; i < n; ++i) {
      if (pts[i].w <= 0) continue;
      const double dx = pts[i].x - mx, dy = pts[i].y - my;
      sxx += pts[i].w * dx * dx;
      sxy += pts[i].w * dx * dy;
      syy += pts[i].w * dy * dy;
      ++used;
    }
    if (used < 2) return false;
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    const double theta = 0.5 * std::atan2(2 * sxy, sxx - syy);  // direction of the line
    out.nx = -std::sin(theta);
    out.ny = std::cos(theta);
    out.c = out.nx * mx + out.ny * my;
    return true;
  };
  if (!fit(line)) return false;
  bool dropped = false;
  for (int i = 0; i < n; ++i) {
    if (pts[i].w > 0 && std::abs(line.nx * pts[i].x + line.ny * pts[i].y - line.c) > reject) {
      pts[i].w = 0;
      dropped = true;
    }
  }
  return dropped ? fit(line) : true;
}

// The size of a cell in pixels: the mean over the quad, and across its
// narrow direction (a marker turned far has cells of a pixel one way and
// of four the other).
struct CellSize {
  double narrow;
  double mean;
};

class Frame8Detector final : public MarkerDetector {
 public:
  explicit Frame8Detector(const DetectorConfig& config) : config_(config) {
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
    profile_sigma_ = std::sqrt(config_.frame8.blur_sigma_px * config_.frame8.blur_sigma_px + 1.0 / 12 + 1.0 / 8);
  }

  [[nodiscard]] Family family() const override { return Family::frame8; }

  void detect(const GreyView& image, std::vector<Detection>& out) override {
    out.clear();
    if (image.empty()) throw DetectorError("frame8: empty image");
    if (image.stride < image.width) throw DetectorError("frame8: image stride is smaller than its width");
    if (config_.camera && (config_.camera->width != image.width || config_.camera->height != image.height)) {
      throw DetectorError("frame8: image size differs from the camera model's");
    }
    if (image.width < 16 || image.height < 16) return;
    full_ = image;
    make_working_image();
    threshold_and_runs();
    label_components();
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
      if (!inside_detection(components_[static_cast<std::size_t>(r)], out)) consider_component(r, out);
    }
    remove_nested(out);
  }

 private:
  struct Run {
    std::int32_t x0, x1;  // light pixels x0 .. x1-1
    std::int32_t y;
    std::int32_t parent;
    std::int32_t next;  // next run of the same component, -1 at the end
  };
  struct Component {
    std::int64_t area = 0;
    std::int32_t x0 = 0, x1 = 0, y0 = 0, y1 = 0;
    std::int32_t first = -1, last = -1;
    bool touches_border = false;
  };

  // --- 1. segmentation ------------------------------------------------------

  void make_working_image() {
    int d = config_.frame8.decimate;
    if (d == 0) d = (static_cast<long>(full_.width) * full_.height > 1'300'000) ? 2 : 1;
    decimate_ = d;
    if (d == 1) {
      work_ = full_;
      return;
    }
    const int w = full_.width / d, h = full_.height / d;
    decimated_.resize(static_cast<std::size_t>(w) * h);
    for (int y = 0; y < h; ++y) {
      std::uint8_t* dst = decimated_.data() + static_cast<std::size_t>(y) * w;
      if (d == 2) {
        const std::uint8_t* a = full_.row(2 * y);
        const std::uint8_t* b = a + full_.stride;
        for (int x = 0; x < w; ++x) {
          dst[x] = static_cast<std::uint8_t>((a[2 * x] + a[2 * x + 1] + b[2 * x] + b[2 * x + 1] + 2) >> 2);
        }
      } else {
        for (int x = 0; x < w; ++x) {
          int s = 0;
          for (int j = 0; j < d; ++j) {
            const std::uint8_t* r = full_.row(d * y + j) + d * x;
            for (int i = 0; i < d; ++i) s += r[i];
          }
          dst[x] = static_cast<std::uint8_t>((s + d * d / 2) / (d * d));
        }
      }
    }
    work_ = {decimated_.data(), w, h, w};
  }

  // Sums each kTile x kTile tile of the working image into tile_sum_
  // (tiles at the right and bottom edges may be partial).
  void sum_tiles(int tw, int th) {
    const int w = work_.width, h = work_.height;
    const int full_tiles = w / kTile;
    for (int ty = 0; ty < th; ++ty) {
      std::uint32_t* sums = tile_sum_.data() + static_cast<std::size_t>(ty) * tw;
      const int y0 = ty * kTile, y1 = std::min(h, y0 + kTile);
      int t = 0;
#if defined(__SSE2__)
      // Four tiles per 16 bytes: each mask keeps every other group of four
      // bytes, and _mm_sad_epu8 against zero sums each half's kept group.
      const __m128i even = _mm_set_epi32(0, -1, 0, -1), odd = _mm_set_epi32(-1, 0, -1, 0), zero = _mm_setzero_si128();
      for (; t + 4 <= full_tiles; t += 4) {
        __m128i a = zero, b = zero;
        for (int y = y0; y < y1; ++y) {
          const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(work_.row(y) + t * kTile));
          a = _mm_add_epi64(a, _mm_sad_epu8(_mm_and_si128(v, even), zero));
          b = _mm_add_epi64(b, _mm_sad_epu8(_mm_and_si128(v, odd), zero));
        }
        sums[t] = static_cast<std::uint32_t>(_mm_cvtsi128_si32(a));
        sums[t + 1] = static_cast<std::uint32_t>(_mm_cvtsi128_si32(b));
        sums[t + 2] = static_cast<std::uint32_t>(_mm_cvtsi128_si32(_mm_srli_si128(a, 8)));
        sums[t + 3] = static_cast<std::uint32_t>(_mm_cvtsi128_si32(_mm_srli_si128(b, 8)));
      }
#endif
      for (int y = y0; y < y1; ++y) {
        const std::uint8_t* row = work_.row(y);
        for (int tt = t; tt < full_tiles; ++tt) {
          const std::uint8_t* p = row + tt * kTile;
          sums[tt] += static_cast<std::uint32_t>(p[0] + p[1] + p[2] + p[3]);
        }
        for (int x = full_tiles * kTile; x < w; ++x) sums[full_tiles] += row[x];
      }
    }
  }

  void threshold_and_runs() {
    const int w = work_.width, h = work_.height;
    const int tw = (w + kTile - 1) / kTile, th = (h + kTile - 1) / kTile;
    tile_sum_.assign(static_cast<std::size_t>(tw) * th, 0);
    sum_tiles(tw, th);
    // Threshold per tile: mean of the 3x3 tiles around it, minus the offset.
    // The 3x3 sums are separable; the pixel count of a neighbourhood is the
    // product of its width and height, and the rounding division by it is a
    // multiplication by its reciprocal (exact for these sums, see kMaxTileSum).
    tile_row_sum_.resize(static_cast<std::size_t>(tw) * th);
    for (int ty = 0; ty < th; ++ty) {
      const std::uint32_t* in = tile_sum_.data() + static_cast<std::size_t>(ty) * tw;
      std::uint32_t* out = tile_row_sum_.data() + static_cast<std::size_t>(ty) * tw;
      for (int tx = 0; tx < tw; ++tx) {
        out[tx] = in[tx] + (tx > 0 ? in[tx - 1] : 0) + (tx + 1 < tw ? in[tx + 1] : 0);
      }
    }
    auto span = [](int t, int tiles, int pixels) {  // pixels covered by tiles t-1 .. t+1
      const int lo = std::max(0, t - 1) * kTile;
      const int hi = std::min(tiles, t + 2) * kTile;
      return std::min(hi, pixels) - lo;
    };
    tile_threshold_.resize(static_cast<std::size_t>(tw) * th);
    const int offset = config_.frame8.threshold_offset;
    for (int ty = 0; ty < th; ++ty) {
      const std::uint32_t* mid = tile_row_sum_.data() + static_cast<std::size_t>(ty) * tw;
      const std::uint32_t* up = ty > 0 ? mid - tw : nullptr;
      const std::uint32_t* down = ty + 1 < th ? mid + tw : nullptr;
      const int rows = span(ty, th, h);
      std::uint8_t* out = tile_threshold_.data() + static_cast<std::size_t>(ty) * tw;
      for (int tx = 0; tx < tw; ++tx) {
        const std::uint32_t sum = mid[tx] + (up ? up[tx] : 0) + (down ? down[tx] : 0);
        const auto n = static_cast<std::uint32_t>(rows * span(tx, tw, w));
        const auto mean = static_cast<int>(((sum + n / 2) * kReciprocal[n]) >> 32);
        out[tx] = static_cast<std::uint8_t>(std::clamp(mean - offset, 0, 255));
      }
    }

    runs_.clear();
    row_first_.resize(static_cast<std::size_t>(h) + 1);
    pixel_threshold_.resize(static_cast<std::size_t>(w) + 16);
    column_max_.resize(static_cast<std::size_t>(w) + 2);
    local_max_.resize(static_cast<std::size_t>(w));
    const int words = (w + 63) / 64;
    light_bits_.resize(static_cast<std::size_t>(words) + 1);
    for (int y = 0; y < h; ++y) {
      if (y % kTile == 0) {
        static_assert(kTile == 4);  // one tile's threshold fills one 32-bit word
        const std::uint8_t* t = tile_threshold_.data() + static_cast<std::size_t>(y / kTile) * tw;
        for (int tx = 0; tx < tw; ++tx) {
          const std::uint32_t four = t[tx] * 0x01010101U;
          std::memcpy(pixel_threshold_.data() + static_cast<std::size_t>(tx) * kTile, &four, sizeof four);
        }
      }
      row_first_[static_cast<std::size_t>(y)] = static_cast<std::int32_t>(runs_.size());
      local_max_row(y);
      light_row_bits(work_.row(y), w);
      extract_runs(y, w, words);
    }
    row_first_[static_cast<std::size_t>(h)] = static_cast<std::int32_t>(runs_.size());
  }

  // local_max_[x] = (brightest pixel of the 3x3 neighbourhood of (x, y)) - step,
  // saturated at 0. A pixel under it sits on the dark side of a sharp edge: a
  // marker's line one pixel thin, which the wide mean misses when the
  // background around a small marker drags the mean down.
  void local_max_row(int y) {
    const int w = work_.width;
    const std::uint8_t* above = work_.row(std::max(0, y - 1));
    const std::uint8_t* here = work_.row(y);
    const std::uint8_t* below = work_.row(std::min(work_.height - 1, y + 1));
    std::uint8_t* colmax = column_max_.data() + 1;  // colmax[-1] and colmax[w] pad the borders
    int x = 0;
#if defined(__SSE2__)
    for (; x + 16 <= w; x += 16) {
      const __m128i a = _mm_loadu_si128(reinterpret_cast<const __m128i*>(above + x));
      const __m128i b = _mm_loadu_si128(reinterpret_cast<const __m128i*>(here + x));
      const __m128i c = _mm_loadu_si128(reinterpret_cast<const __m128i*>(below + x));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(colmax + x), _mm_max_epu8(_mm_max_epu8(a, b), c));
    }
#endif
    for (; x < w; ++x) colmax[x] = std::max({above[x], here[x], below[x]});
    colmax[-1] = colmax[0];
    colmax[w] = colmax[w - 1];
    const auto step = static_cast<std::uint8_t>(std::min(255, 2 * config_.frame8.threshold_offset));
    std::uint8_t* out = local_max_.data();
    x = 0;
#if defined(__SSE2__)
    const __m128i vstep = _mm_set1_epi8(static_cast<char>(step));
    for (; x + 16 <= w; x += 16) {
      const __m128i l = _mm_loadu_si128(reinterpret_cast<const __m128i*>(colmax + x - 1));
      const __m128i m = _mm_loadu_si128(reinterpret_cast<const __m128i*>(colmax + x));
      const __m128i r = _mm_loadu_si128(reinterpret_cast<const __m128i*>(colmax + x + 1));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm_subs_epu8(_mm_max_epu8(_mm_max_epu8(l, m), r), vstep));
    }
#endif
    for (; x < w; ++x) {
      const int m = std::max({colmax[x - 1], colmax[x], colmax[x + 1]});
      out[x] = static_cast<std::uint8_t>(std::max(0, m - step));
    }
  }

  // Bit x of light_bits_ is set when pixel x is light: not below the mean of
  // its neighbourhood (minus the offset) and not under the local maximum
  // (minus the step).
  void light_row_bits(const std::uint8_t* row, int w) {
    std::fill(light_bits_.begin(), light_bits_.end(), 0);
    const std::uint8_t* thr = pixel_threshold_.data();
    const std::uint8_t* lmax = local_max_.data();
    int x = 0;
#if defined(__SSE2__)
    for (; x + 16 <= w; x += 16) {
      const __m128i p = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + x));
      const __m128i t = _mm_max_epu8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(thr + x)),
                                     _mm_loadu_si128(reinterpret_cast<const __m128i*>(lmax + x)));
      const __m128i light = _mm_cmpeq_epi8(_mm_max_epu8(p, t), p);  // p >= t
      const auto mask = static_cast<std::uint64_t>(static_cast<std::uint32_t>(_mm_movemask_epi8(light)));
      light_bits_[static_cast<std::size_t>(x >> 6)] |= mask << (x & 63);
    }
#endif
    for (; x < w; ++x) {
      if (row[x] >= std::max(thr[x], lmax[x])) light_bits_[static_cast<std::size_t>(x >> 6)] |= std::uint64_t{1} << (x & 63);
    }
  }

  void extract_runs(int y, int w, int words) {
    int x = 0;
    while (x < w) {
      // Find the next set bit at or after x.
      int wi = x >> 6;
      std::uint64_t word = light_bits_[static_cast<std::size_t>(wi)] & (~std::uint64_t{0} << (x & 63));
      while (word == 0 && ++wi < words) word = light_bits_[static_cast<std::size_t>(wi)];
      if (word == 0) break;
      const int start = (wi << 6) + __builtin_ctzll(word);
      if (start >= w) break;
      // Find the next clear bit after start.
      wi = start >> 6;
      word = ~light_bits_[static_cast<std::size_t>(wi)] & (~std::uint64_t{0} << (start & 63));
      while (word == 0 && ++wi < words) word = ~light_bits_[static_cast<std::size_t>(wi)];
      int end = word == 0 ? w : (wi << 6) + __builtin_ctzll(word);
      end = std::min(end, w);
      const auto index = static_cast<std::int32_t>(runs_.size());
      runs_.push_back({start, end, y, index, -1});
      x = end;
    }
  }

  std::int32_t find(std::int32_t r) {
    while (runs_[static_cast<std::size_t>(r)].parent != r) {
      auto& run = runs_[static_cast<std::size_t>(r)];
      run.parent = runs_[static_cast<std::size_t>(run.parent)].parent;
      r = run.parent;
    }
    return r;
  }

  void unite(std::int32_t a, std::int32_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    // The earlier run becomes the root, so a component's root is its first run.
    if (a < b) {
      runs_[static_cast<std::size_t>(b)].parent = a;
    } else {
      runs_[static_cast<std::size_t>(a)].parent = b;
    }
  }

  void label_components() {
    const int h = work_.height, w = work_.width;
    for (int y = 1; y < h; ++y) {
      int i = row_first_[static_cast<std::size_t>(y - 1)], j = row_first_[static_cast<std::size_t>(y)];
      const int i_end = row_first_[static_cast<std::size_t>(y)], j_end = row_first_[static_cast<std::size_t>(y) + 1];
      while (i < i_end && j < j_end) {
        const Run& a = runs_[static_cast<std::size_t>(i)];
        const Run& b = runs_[static_cast<std::size_t>(j)];
        if (a.x0 < b.x1 && b.x0 < a.x1) unite(i, j);
        if (a.x1 < b.x1) {
          ++i;
        } else {
          ++j;
        }
      }
    }
    components_.resize(runs_.size());
    for (std::int32_t r = 0; r < static_cast<std::int32_t>(runs_.size()); ++r) {
      const std::int32_t root = find(r);
      Run& run = runs_[static_cast<std::size_t>(r)];
      run.parent = root;
      Component& c = components_[static_cast<std::size_t>(root)];
      if (root == r) {
        c = Component{0, run.x0, run.x1, run.y, run.y, r, r, false};
      } else {
        runs_[static_cast<std::size_t>(c.last)].next = r;
        c.last = r;
        c.x0 = std::min(c.x0, run.x0);
        c.x1 = std::max(c.x1, run.x1);
        c.y1 = run.y;  // runs come in row order
      }
      c.area += run.x1 - run.x0;
      if (run.x0 == 0 || run.x1 == w || run.y == 0 || run.y == h - 1) c.touches_border = true;
    }
  }

  // --- 2. quads -------------------------------------------------------------

  // Largest-area quadrilateral on the vertices of a convex polygon (hull_),
  // by rotating the two free vertices monotonically for each diagonal.
  bool max_area_quad(std::array<Point2, 4>& quad) {
    const int n = static_cast<int>(hull_.size());
    if (n < 4) return false;
    // Indices run up to 2n - 1: the hull twice over instead of i % n, whose
    // division would cost more than the cross products of this O(n^2) walk.
    hull_twice_.assign(hull_.begin(), hull_.end());
    hull_twice_.insert(hull_twice_.end(), hull_.begin(), hull_.end());
    auto at = [&](int i) { return hull_twice_[static_cast<std::size_t>(i)]; };
    double best = 0;
    for (int i = 0; i < n; ++i) {
      int k = i + 1;
      int l = i + 3;
      for (int j = i + 2; j < i + n - 1; ++j) {
        if (k >= j) k = j - 1;
        while (k + 1 < j && std::abs(cross(at(i), at(k + 1), at(j))) >= std::abs(cross(at(i), at(k), at(j)))) ++k;
        if (l <= j) l = j + 1;
        while (l + 1 < i + n && std::abs(cross(at(j), at(l + 1), at(i))) >= std::abs(cross(at(j), at(l), at(i)))) ++l;
        const double area = std::abs(cross(at(i), at(k), at(j))) + std::abs(cross(at(j), at(l), at(i)));
        if (area > best) {
          best = area;
          quad = {at(i), at(k), at(j), at(l)};
        }
      }
    }
    return best > 0;
  }

  void consider_component(std::int32_t root, std::vector<Detection>& out) {
    const Component& c = components_[static_cast<std::size_t>(root)];
    if (c.touches_border) return;
    const double d = decimate_;
    const int bw = c.x1 - c.x0, bh = c.y1 - c.y0 + 1;
    const double min_side = config_.frame8.min_hole_side_px / d;
    // The threshold's local-maximum test takes the blurred pixel on each
    // side of a hole: a hole turned far (75 degrees, 6 px across) comes out
    // 4 px wide, so the narrow side may be that much short, when the long
    // side has cells large enough to read the code along it.
    const int narrow = std::min(bw, bh), wide = std::max(bw, bh);
    if (narrow < min_side && (narrow < min_side - 2 / d || wide < 3 * min_side)) return;
    if (bw > work_.width * 0.95 || bh > work_.height * 0.95) return;
    if (c.area < 0.2 * bw * bh) return;
    F8_TRACE("component at %d,%d size %dx%d area %ld\n", c.x0, c.y0, bw, bh, static_cast<long>(c.area));

    // Per horizontal pixel-edge line k (between rows y0-1+k and y0+k), the
    // extreme boundary x of the rows touching it: the component's outline.
    line_min_.assign(static_cast<std::size_t>(bh) + 1, std::numeric_limits<std::int32_t>::max());
    line_max_.assign(static_cast<std::size_t>(bh) + 1, std::numeric_limits<std::int32_t>::min());
    for (std::int32_t r = c.first; r >= 0; r = runs_[static_cast<std::size_t>(r)].next) {
      const Run& run = runs_[static_cast<std::size_t>(r)];
      const auto k = static_cast<std::size_t>(run.y - c.y0);
      for (std::size_t kk = k; kk <= k + 1; ++kk) {
        line_min_[kk] = std::min(line_min_[kk], run.x0);
        line_max_[kk] = std::max(line_max_[kk], run.x1);
      }
    }
    // Andrew's monotone chain over points already sorted by (y, x).
    hull_.clear();
    points_.clear();
    for (int k = 0; k <= bh; ++k) {
      const double y = c.y0 + k - 0.5;
      points_.push_back({line_min_[static_cast<std::size_t>(k)] - 0.5, y});
      if (line_max_[static_cast<std::size_t>(k)] != line_min_[static_cast<std::size_t>(k)]) {
        points_.push_back({line_max_[static_cast<std::size_t>(k)] - 0.5, y});
      }
    }
    convex_hull();
    std::array<Point2, 4> quad{};
    if (!max_area_quad(quad)) return;

    // The hull must be a quad, and the component must fill most of it.
    const double hull_area = std::abs(twice_signed_area(hull_.data(), hull_.size())) / 2;
    double quad_area = twice_signed_area(quad.data(), quad.size());
    if (quad_area < 0) std::swap(quad[1], quad[3]);  // clockwise on screen (y down)
    quad_area = std::abs(quad_area) / 2;
    F8_TRACE("  quad area %.1f hull %.1f\n", quad_area, hull_area);
    // Pixel staircases make a small hull bigger than the quad by up to about
    // a third of a pixel along the perimeter; beyond that it is not a quad.
    double perimeter = 0;
    for (int i = 0; i < 4; ++i) {
      perimeter += distance(quad[static_cast<std::size_t>(i)], quad[static_cast<std::size_t>((i + 1) % 4)]);
    }
    if (hull_area - quad_area > 0.06 * hull_area + 0.35 * perimeter || c.area < 0.8 * quad_area) return;
    for (int i = 0; i < 4; ++i) {
      const Point2 a = quad[static_cast<std::size_t>(i)];
      const Point2 b = quad[static_cast<std::size_t>((i + 1) % 4)];
      const Point2 p = quad[static_cast<std::size_t>((i + 3) % 4)];
      const double la = distance(a, b), lp = distance(a, p);
      if (la < min_side * 0.5) return;
      const double cosang = ((b.x - a.x) * (p.x - a.x) + (b.y - a.y) * (p.y - a.y)) / (la * lp);
      if (std::abs(cosang) > 0.94) return;  // a corner sharper than 20 degrees or flatter than 160
    }
    for (auto& p : quad) p = {p.x * d + (d - 1) / 2, p.y * d + (d - 1) / 2};

    Detection det;
    F8_TRACE("  candidate quad (%.1f,%.1f) (%.1f,%.1f) (%.1f,%.1f) (%.1f,%.1f)\n", quad[0].x, quad[0].y, quad[1].x,
             quad[1].y, quad[2].x, quad[2].y, quad[3].x, quad[3].y);
    if (refine_and_decode(quad, det)) {
      F8_TRACE("  reported id %d\n", det.id);
      out.push_back(det);
    }
  }

  void convex_hull() {
    const int n = static_cast<int>(points_.size());
    hull_.resize(static_cast<std::size_t>(2 * n));
    int k = 0;
    // Points are sorted by (y, x); build both chains.
    for (int i = 0; i < n; ++i) {
      while (k >= 2 && cross(hull_[static_cast<std::size_t>(k - 2)], hull_[static_cast<std::size_t>(k - 1)],
                             points_[static_cast<std::size_t>(i)]) <= 0) {
        --k;
      }
      hull_[static_cast<std::size_t>(k++)] = points_[static_cast<std::size_t>(i)];
    }
    for (int i = n - 2, t = k + 1; i >= 0; --i) {
      while (k >= t && cross(hull_[static_cast<std::size_t>(k - 2)], hull_[static_cast<std::size_t>(k - 1)],
                             points_[static_cast<std::size_t>(i)]) <= 0) {
        --k;
      }
      hull_[static_cast<std::size_t>(k++)] = points_[static_cast<std::size_t>(i)];
    }
    hull_.resize(static_cast<std::size_t>(std::max(0, k - 1)));
  }

  // --- 3. edges at full resolution -------------------------------------------

  // Finds the hole-to-line edge along side i of the quad; fills
  // edge_points_[i]. Without a code (id < 0), every point takes the centroid
  // of the light-to-dark step. With the code read once, each point knows the
  // colour of the cell beyond the line: where it is white and the line is
  // thin against the blur, the step is cut short by the white cell and its
  // centroid falls inside the hole; the blurred line is then a symmetric dip
  // instead, whose centroid is the line's centre, a quarter cell outside the
  // edge.
  int collect_edge_points(const std::array<Point2, 4>& q, int side, int id) {
    const Point2 a = q[static_cast<std::size_t>(side)];
    const Point2 b = q[static_cast<std::size_t>((side + 1) % 4)];
    const double len = distance(a, b);
    const double dx = (b.x - a.x) / len, dy = (b.y - a.y) / len;
    double nx = dy, ny = -dx;  // outward for a clockwise quad with y down
    // The short ends of a sliver (a marker turned far) come out of the
    // blurred, thresholded hole round, and the quad's corners cut across
    // them: the side found there is askew. Probed along the long sides
    // instead, the points land on the true end whatever its coarse slant.
    // Its corners, blurred round, would pull the few points such an end has:
    // those are taken from its middle half only.
    double t_first = 0.12, t_span = 0.76;
    int count = std::clamp(static_cast<int>(len / 1.5), 4, kMaxEdgePoints);
    bool sliver_end = false;
    {
      const Point2 prev = q[static_cast<std::size_t>((side + 3) % 4)];
      const Point2 next = q[static_cast<std::size_t>((side + 2) % 4)];
      const Point2 along_long = (a - prev) + (b - next);
      const double long_len = 0.5 * (distance(a, prev) + distance(b, next));
      if (len < kSliverEnd * long_len) {
        const double l = std::hypot(along_long.x, along_long.y);
        nx = along_long.x / l;
        ny = along_long.y / l;
        t_first = 0.25;
        t_span = 0.5;
        count = std::max(count, 6);
        sliver_end = true;
      }
    }
    // A cell's size across this side, at either end: foreshortening makes it
    // differ from side to side and along a side.
    const double cell_a = distance(q[static_cast<std::size_t>((side + 3) % 4)], a) / kInnerSide;
    const double cell_b = distance(b, q[static_cast<std::size_t>((side + 2) % 4)]) / kInnerSide;
    constexpr double step = 0.5;
    EdgePoint* pts = edge_points_[static_cast<std::size_t>(side)].data();
    int used = 0;
    const bool fitting = id == kFitProfile && !sliver_end;
    const double side_cell = 0.5 * (cell_a + cell_b);
    int fit_steps = 0;
    double fit_reach_in = 0;
    if (fitting) {
      for (auto& prof : segment_profile_) prof.fill(0);
      segment_base_.fill({0, 0});
      segment_count_.fill(0);
    }
    std::array<float, 64> profile{};
    for (int k = 0; k < count; ++k) {
      // Stay clear of the corners, where the line turns.
      const double t = t_first + t_span * (k + 0.5) / count;
      const double px = a.x + t * (b.x - a.x), py = a.y + t * (b.y - a.y);
      const double cell_px = (1 - t) * cell_a + t * cell_b;
      bool white_beyond = false;
      const bool by_profile = id == kClassifyByProfile || id == kFitProfile;
      if (id >= 0) {
        // Cells along a side follow the reading order, the same on every side.
        const double along = 0.5 + kInnerSide * t;
        const double frac = along - std::floor(along);
        if (frac < 0.15 || frac > 0.85) continue;  // two cells share the blur here
        const int bit = 7 - std::clamp(static_cast<int>(along), 0, 7);
        white_beyond = (id >> bit) & 1;
      }
      // Inward as far as the coarse quad may be off; outward past the line's
      // far side (half a cell) and its blur.
      const bool near = id != kNoCode;  // the quad is refined already: a tight window
      const double reach_in = fitting ? kProfileReach + 1.0
                              : near  ? std::max(1.0, 0.5 * cell_px)
                                      : std::clamp(1.2 * cell_px, 1.5, 2.0 + decimate_);
      const double reach_out = fitting ? kProfileReach + 1.5 * side_cell + 0.5
                               : near  ? 0.75 * cell_px + 1.5
                                       : std::clamp(1.1 * cell_px + 1.0 + 0.5 * decimate_, 1.5, 3.0 + decimate_);
      const int n_steps = std::min(static_cast<int>((reach_in + reach_out) / step) + 1, 64);
      bool ok = true;
      for (int s = 0; s < n_steps && ok; ++s) {
        const double off = -reach_in + s * step;
        ok = sample(full_, px + off * nx, py + off * ny, profile[static_cast<std::size_t>(s)]);
      }
      if (!ok) continue;
      if (fitting) {
        // Summed per segment of the side and fitted below: the cells
        // beyond the line differ from point to point, but the model's level
        // for them is free, and the sum of profiles is the profile of their
        // mean. A few fits instead of one per point, each on less noise.
        const auto seg = static_cast<std::size_t>(k * kProfileSegments / count);
        for (int i = 0; i < n_steps; ++i) segment_profile_[seg][static_cast<std::size_t>(i)] += profile[static_cast<std::size_t>(i)];
        segment_base_[seg] = segment_base_[seg] + Point2{px, py};
        ++segment_count_[seg];
        fit_steps = n_steps;
        fit_reach_in = reach_in;
        continue;
      }
      auto P = [&](int i) { return static_cast<double>(profile[static_cast<std::size_t>(i)]); };
      // The steepest light-to-dark step going outward.
      int best = -1;
      double best_drop = 0;
      for (int s = 0; s + 1 < n_steps; ++s) {
        if (P(s) - P(s + 1) > best_drop) {
          best_drop = P(s) - P(s + 1);
          best = s;
        }
      }
      if (best < 0 || best_drop < 2.0) continue;
      // The whole step: from where the profile starts falling to where it stops.
      const double floor_drop = 0.05 * best_drop;
      int lo = best, hi = best;
      while (lo > 0 && P(lo - 1) - P(lo) > floor_drop) --lo;
      while (hi + 2 < n_steps && P(hi + 1) - P(hi + 2) > floor_drop) ++hi;
      double off = 0;
      int peak = hi + 1;
      while (peak + 1 < n_steps && P(peak + 1) >= P(peak)) ++peak;
      if (by_profile) {
        // Without the code, the profile tells: the line alone (a white cell
        // beyond) is a dip about half a cell wide plus the blur, that rises
        // again; the line merged with a black cell is three times wider.
        const double valley = P(hi + 1);
        const double half = valley + 0.5 * (std::min(P(lo), P(peak)) - valley);
        int width = 0;
        for (int i = lo; i <= peak; ++i) width += P(i) < half;
        white_beyond = P(peak) - valley > 0.3 * (P(lo) - valley) && width * step <= 1.0 * cell_px + 0.5;
      }
      if (white_beyond && cell_px < kThinLineCells) {
        const double ref = std::min(P(lo), P(peak));
        double sum = 0, moment = 0;
        for (int i = lo; i <= peak; ++i) {
          const double depth = std::max(0.0, ref - P(i));
          sum += depth;
          moment += depth * i;
        }
        if (sum <= 0) continue;
        off = -reach_in + (moment / sum) * step - 0.25 * cell_px;
      } else {
        double sum = 0, moment = 0;
        for (int i = lo; i <= hi; ++i) {
          const double drop = P(i) - P(i + 1);
          sum += drop;
          moment += drop * (i + 0.5);
        }
        off = -reach_in + (moment / sum) * step;
      }
      pts[used++] = {px + off * nx, py + off * ny, best_drop};
    }
    if (fitting) {
      for (std::size_t seg = 0; seg < kProfileSegments; ++seg) {
        const int m = segment_count_[seg];
        if (m == 0) continue;
        std::array<float, 64>& prof = segment_profile_[seg];
        for (int i = 0; i < fit_steps; ++i) prof[static_cast<std::size_t>(i)] /= static_cast<float>(m);
        double e = 0;
        if (!fit_edge_profile(prof.data(), fit_steps, -fit_reach_in, step, side_cell, e)) continue;
        const Point2 base = (1.0 / m) * segment_base_[seg];
        F8_TRACE("    fitted side %d segment %zu -> (%.2f,%.2f)\n", side, seg, base.x + e * nx, base.y + e * ny);
        pts[used++] = {base.x + e * nx, base.y + e * ny, static_cast<double>(m)};
      }
    }
    return used;
  }

  // The edge in a profile across a side, sampled outward from s0 every
  // `step` pixels: the offset e at which the hole (level H) meets the line
  // (half a cell, level L), followed by the ring cell (a cell, level B:
  // black, white or between) and whatever lies outside (level O), all
  // blurred by the lens, the pixel and the sampling (profile_sigma_). The
  // step's centroid is biased where the cell beyond is white and the cells
  // are small (the line alone is then a dip barely darker than its blur,
  // cut short by the cell), and classifying each profile as one case or the
  // other fails below about two pixels a cell; this model needs neither.
  bool fit_edge_profile(const float* profile, int n, double s0, double step, double cell_px, double& e) const {
    const double inv_sigma = 1.0 / profile_sigma_;
    const double w = 0.5 * cell_px, c = cell_px;
    const detail::NormalTable& table = detail::normal_table();
    // Gauss-Newton over the four levels and the edge together, from the
    // edge as measured (within a fraction of a pixel of the answer). The
    // levels start from the profile: the hole where it begins, the line at
    // its darkest, the cell and the outside at the hole's level.
    double p[5] = {};  // hole, line - hole, cell - hole, outside - hole, edge
    p[0] = 0.5 * (profile[0] + profile[1]);
    p[1] = *std::min_element(profile, profile + n) - p[0];
    e = 0;
    constexpr int k = 5;
    for (int iter = 0; iter < kProfileIterations; ++iter) {
      double a[5][5] = {}, g[5] = {};  // lower triangle of J'J, and J'r
      for (int i = 0; i < n; ++i) {
        const double x = s0 + i * step - e;
        double f0 = 0, f1 = 0, f2 = 0, d0 = 0, d1 = 0, d2 = 0;
        table.at(-x * inv_sigma, f0, d0);
        table.at((w - x) * inv_sigma, f1, d1);
        table.at((w + c - x) * inv_sigma, f2, d2);
        const double j[5] = {1.0, f1 - f0, f2 - f1, 1.0 - f2, inv_sigma * (p[1] * (d1 - d0) + p[2] * (d2 - d1) - p[3] * d2)};
        const double r = profile[i] - (p[0] + p[1] * j[1] + p[2] * j[2] + p[3] * j[3]);
        for (int u = 0; u < k; ++u) {
          g[u] += r * j[u];
          for (int v = 0; v <= u; ++v) a[u][v] += j[u] * j[v];
        }
      }
      for (int u = 0; u < 4; ++u) a[u][u] += kProfileRidge;
      a[4][4] *= 1.0 + 1e-3;
      // Cholesky in place, then the two triangular solves.
      for (int u = 0; u < k; ++u) {
        for (int v = 0; v <= u; ++v) {
          double sum = a[u][v];
          for (int q = 0; q < v; ++q) sum -= a[u][q] * a[v][q];
          if (u == v) {
            if (!(sum > 0)) return false;
            a[u][u] = std::sqrt(sum);
          } else {
            a[u][v] = sum / a[v][v];
          }
        }
      }
      double d[5] = {};
      for (int u = 0; u < k; ++u) {
        double sum = g[u];
        for (int q = 0; q < u; ++q) sum -= a[u][q] * d[q];
        d[u] = sum / a[u][u];
      }
      for (int u = k; u-- > 0;) {
        double sum = d[u];
        for (int q = u + 1; q < k; ++q) sum -= a[q][u] * d[q];
        d[u] = sum / a[u][u];
      }
      for (int u = 0; u < 4; ++u) p[u] += d[u];
      const double de = std::clamp(d[4], -kProfileMaxStep, kProfileMaxStep);
      e += de;
      if (std::abs(de) < kProfileConverged) break;
    }
    return std::isfinite(e) && std::abs(e) <= kProfileReach && -p[1] >= kMinLineContrast;
  }

  // Small cells, third try: the sides measured again by fitting each side's
  // profiles with the blurred line and the cells beyond it
  // (fit_edge_profile), then read.
  bool read_by_profile_fit(const std::array<Point2, 4>& from, double cell_px, CellSize cell_size, Detection& det,
                           int& rotation, Homography& H, std::array<Point2, 4>& inner) {
    if (cell_px >= kResolvedCells || cell_px < kMinCells) return false;
    std::array<Point2, 4> fitted{};
    Homography fitted_H;
    if (!refine_sides(from, kFitProfile, cell_px, fitted) || !Homography::from_unit_square(fitted, fitted_H) ||
        decode(fitted_H, cell_size, det, rotation, nullptr) != kRead) {
      return false;
    }
    F8_TRACE("  read by profile fit: id %d\n", det.id);
    H = fitted_H;
    inner = fitted;
    return true;
  }

  // Refines the four sides from a quad; the inner corners in `inner`.
  bool refine_sides(const std::array<Point2, 4>& from, int id, double cell_px, std::array<Point2, 4>& inner) {
    std::array<Line, 4> lines{};
    for (int side = 0; side < 4; ++side) {
      auto& n = edge_count_[static_cast<std::size_t>(side)];
      n = collect_edge_points(from, side, id);
      F8_TRACE("  side %d: %d edge points\n", side, n);
      if (n < 3) return false;
      if (!fit_line(edge_points_[static_cast<std::size_t>(side)].data(), n, std::max(0.6, 0.25 * cell_px),
                    lines[static_cast<std::size_t>(side)])) {
        return false;
      }
    }
    for (int i = 0; i < 4; ++i) {
      if (!intersect(lines[static_cast<std::size_t>((i + 3) % 4)], lines[static_cast<std::size_t>(i)],
                     inner[static_cast<std::size_t>(i)])) {
        return false;
      }
      if (distance(inner[static_cast<std::size_t>(i)], from[static_cast<std::size_t>(i)]) > 2.0 * cell_px + 2 * decimate_) {
        F8_TRACE("  corner %d moved %.1f px\n", i, distance(inner[static_cast<std::size_t>(i)], from[static_cast<std::size_t>(i)]));
        return false;
      }
    }
    return true;
  }

  bool refine_and_decode(const std::array<Point2, 4>& coarse, Detection& det) {
    double perimeter = 0;
    for (int i = 0; i < 4; ++i) {
      perimeter += distance(coarse[static_cast<std::size_t>(i)], coarse[static_cast<std::size_t>((i + 1) % 4)]);
    }
    double cell_px = perimeter / 4 / kInnerSide;
    if (perimeter / 4 < config_.frame8.min_hole_side_px) return false;

    std::array<Point2, 4> inner{};
    if (!refine_sides(coarse, kNoCode, cell_px, inner)) return false;
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
      if (refine_sides(inner, kClassifyByProfile, cell_px, by_profile)) {
        inner = by_profile;
        have_fallback = true;
      }
    }
    // A square seen at up to about 82 degrees keeps its short sides above a
    // tenth of its long ones (kMinSideRatio); slivers beyond that are not
    // worth a read.
    double shortest = std::numeric_limits<double>::infinity(), longest = 0;
    for (int i = 0; i < 4; ++i) {
      const double len = distance(inner[static_cast<std::size_t>(i)], inner[static_cast<std::size_t>((i + 1) % 4)]);
      shortest = std::min(shortest, len);
      longest = std::max(longest, len);
    }
    F8_TRACE("  inner (%.1f,%.1f) (%.1f,%.1f) (%.1f,%.1f) (%.1f,%.1f) sides %.1f..%.1f\n", inner[0].x, inner[0].y, inner[1].x, inner[1].y, inner[2].x, inner[2].y, inner[3].x, inner[3].y, shortest, longest);
    if (shortest < kMinSideRatio * longest) return false;
    // Whether cells are resolved is decided by their narrow side: a marker
    // turned far shows cells of a pixel across beside cells of four. Its two
    // short sides are opposite each other; one short side alone is no such
    // marker, and says nothing of the cells. The width across a pair of
    // sides is the area over their mean length: a short side that slopes
    // (a marker turned far and seen off the axis) is longer than the marker
    // is wide, by up to a half at 80 degrees.
    std::array<double, 4> side_len{};
    for (int i = 0; i < 4; ++i) side_len[static_cast<std::size_t>(i)] = distance(inner[static_cast<std::size_t>(i)], inner[static_cast<std::size_t>((i + 1) % 4)]);
    const double area = std::abs(twice_signed_area(inner.data(), inner.size())) / 2;
    const double across = 2 * area / std::max(side_len[0] + side_len[2], side_len[1] + side_len[3]);
    const CellSize cell_size{across / kInnerSide, cell_px};
    Homography H;
    if (!Homography::from_unit_square(inner, H)) return false;
    int rotation = 0;
    bool by_model = false;
    if (const int sampled = decode(H, cell_size, det, rotation, nullptr); sampled != kRead) {
      Homography step_H;
      int step_sampled = kNoContrast;
      if (have_fallback && Homography::from_unit_square(step_only, step_H) &&
          (step_sampled = decode(step_H, cell_size, det, rotation, nullptr)) == kRead) {
        H = step_H;
        inner = step_only;
      } else if (std::max(sampled, step_sampled) > kNoContrast &&
                 read_by_profile_fit(step_only, cell_px, cell_size, det, rotation, H, inner)) {
        // read_by_profile_fit() has set H and inner to the fitted quad.
      } else if (read_by_model(H, cell_size, std::max(sampled, step_sampled), det, rotation)) {
        by_model = true;
      } else {
        return false;
      }
    }
    if (cell_px < kThinLineCells && !by_model) {
      // Measure again knowing which cells are white, then read again.
      std::array<Point2, 4> second{};
      Homography H2;
      Detection det2;
      int rotation2 = 0;
      if (refine_sides(inner, det.id, cell_px, second) && Homography::from_unit_square(second, H2) &&
          decode(H2, cell_size, det2, rotation2, nullptr) == kRead) {
        inner = second;
        H = H2;
        det = det2;
        rotation = rotation2;
      } else if (!refine_sides(coarse, kNoCode, cell_px, inner)) {
        return false;  // (restores the first pass's edge points for the camera refit)
      }
    }

    // With the code known, every edge of the printed pattern is a measurement.
    if (cell_px >= kPatternCells && collect_pattern_edges(H, det.id, rotation, cell_px) >= kMinPatternEdges) {
      return finish_by_pattern(rotation, det);
    }

    if (!config_.camera) return report(grid_map(H), rotation, det);
    return refit_undistorted(rotation, det);
  }

  // Fills the corners from a map of grid coordinates to the image (without a
  // camera) or to undistorted normalized coordinates (with one), and the
  // pose with a camera. Corner j of the marker is quad corner
  // (j + rotation) % 4.
  bool report(const Eigen::Matrix3d& grid_to_image, int rotation, Detection& det) const {
    static constexpr std::array<Point2, 4> kInnerGrid{{{kInnerLo, kInnerLo},
                                                       {frame8::grid - kInnerLo, kInnerLo},
                                                       {frame8::grid - kInnerLo, frame8::grid - kInnerLo},
                                                       {kInnerLo, frame8::grid - kInnerLo}}};
    static constexpr std::array<Point2, 4> kOuterGrid{{{0, 0}, {frame8::grid, 0}, {frame8::grid, frame8::grid}, {0, frame8::grid}}};
    Quad in{}, outq{};
    std::array<Eigen::Vector2d, 4> model_order{};
    for (int j = 0; j < 4; ++j) {
      const auto q = static_cast<std::size_t>((j + rotation) % 4);
      const auto jj = static_cast<std::size_t>(j);
      const Point2 inner = map_grid(grid_to_image, kInnerGrid[q].x, kInnerGrid[q].y);
      const Point2 outer = map_grid(grid_to_image, kOuterGrid[q].x, kOuterGrid[q].y);
      model_order[jj] = {inner.x, inner.y};
      in[jj] = config_.camera ? config_.camera->normalized_to_pixel(inner) : inner;
      outq[jj] = config_.camera ? config_.camera->normalized_to_pixel(outer) : outer;
    }
    det.inner_corners = in;
    det.corners = outq;
    if (config_.camera) {
      det.pose = estimate_square_pose_normalized(*config_.camera, model_order, config_.marker_size_m * frame8::hole_fraction);
      if (!det.pose) return false;
    }
    const Point2 top = det.corners[1] - det.corners[0];
    const int quarter = static_cast<int>(std::lround(std::atan2(top.y, top.x) / (std::numbers::pi / 2)));
    det.quarter_turns = ((quarter % 4) + 4) % 4;
    return true;
  }

  // --- 3b. the whole pattern ------------------------------------------------

  // An edge of the printed pattern seen in the image: the point lies on the
  // grid line `value` of the given axis (0: x = value, 1: y = value).
  struct PatternEdge {
    double x, y, w;
    int axis;
    double value;
  };

  // The edge along `axis_normal` through grid point g0: searched across the
  // edge within +-half (grid units) through the homography. A step is
  // light-to-dark along the normal and located at its gradient centroid; a
  // dip (the half-cell line between the hole and a white cell) at the
  // centroid of its depth, the line's centre. Returns false when nothing
  // clear is there.
  bool locate_edge(const Homography& H, Point2 g0, Point2 normal, double half, bool dip, double& offset, double& strength) const {
    constexpr int kSamples = 17;
    std::array<float, kSamples> v{};
    for (int i = 0; i < kSamples; ++i) {
      const double s = -half + 2 * half * i / (kSamples - 1);
      const Point2 p = grid_point(H, g0.x + s * normal.x, g0.y + s * normal.y);
      if (!sample(full_, p.x, p.y, v[static_cast<std::size_t>(i)])) return false;
    }
    const double ds = 2 * half / (kSamples - 1);
    double sum = 0, moment = 0, peak = 0;
    if (dip) {
      const double ref = std::min(v.front(), v.back());
      for (int i = 0; i < kSamples; ++i) peak = std::max(peak, ref - v[static_cast<std::size_t>(i)]);
      const double floor = 0.1 * peak;
      for (int i = 0; i < kSamples; ++i) {
        const double depth = ref - v[static_cast<std::size_t>(i)] - floor;
        if (depth <= 0) continue;
        sum += depth;
        moment += depth * (-half + i * ds);
      }
    } else {
      for (int i = 0; i + 1 < kSamples; ++i) peak = std::max(peak, static_cast<double>(v[static_cast<std::size_t>(i)] - v[static_cast<std::size_t>(i + 1)]));
      const double floor = 0.1 * peak;
      for (int i = 0; i + 1 < kSamples; ++i) {
        const double drop = v[static_cast<std::size_t>(i)] - v[static_cast<std::size_t>(i + 1)] - floor;
        if (drop <= 0) continue;
        sum += drop;
        moment += drop * (-half + (i + 0.5) * ds);
      }
      peak *= (kSamples - 1) / (2 * half);  // per grid unit, comparable with a dip's depth
      peak = std::min(peak, static_cast<double>(v.front() - v.back()));
    }
    if (sum <= 0 || peak < 12) return false;
    offset = moment / sum;
    strength = peak;
    return true;
  }

  // Collects the pattern's edges for the code `id` read with `rotation`:
  // the hole's edge (a step where the ring cell beyond is black, the line's
  // centre where it is white) and every boundary between ring cells of
  // different colours. The outer edge is left out: what lies beyond it is
  // unknown.
  int collect_pattern_edges(const Homography& H, int id, int rotation, double cell_px) {
    const auto cells = frame8::ring_cells(id);
    // White at a grid point of the quad: turned back into the marker's own
    // grid, where the marker's corner j sits at the quad's corner j + rotation.
    auto white_at = [&](Point2 g) {
      for (int r = 0; r < rotation; ++r) g = {g.y, frame8::grid - g.x};
      const int col = std::clamp(static_cast<int>(g.x), 0, frame8::grid - 1);
      const int row = std::clamp(static_cast<int>(g.y), 0, frame8::grid - 1);
      return cells[static_cast<std::size_t>(row * frame8::grid + col)] == 1;
    };
    static constexpr std::array<Point2, 4> kOutward{{{0, -1}, {1, 0}, {0, 1}, {-1, 0}}};
    // Points per cell along an edge: about one per 1.5 px.
    const int per_cell = std::clamp(static_cast<int>(cell_px / 1.5), 1, 4);
    pattern_count_ = 0;
    auto add = [&](Point2 g, Point2 normal, double half, bool dip, int axis) {
      if (pattern_count_ >= kMaxPatternEdges) return;
      double off = 0, strength = 0;
      if (!locate_edge(H, g, normal, half, dip, off, strength)) return;
      const Point2 p = grid_point(H, g.x + off * normal.x, g.y + off * normal.y);
      pattern_edges_[static_cast<std::size_t>(pattern_count_++)] = {p.x, p.y, strength, axis, axis == 1 ? g.y : g.x};
    };
    for (int side = 0; side < 4; ++side) {
      const int axis = side % 2 == 0 ? 1 : 0;  // the coordinate that is constant along the side
      const Point2 outward = kOutward[static_cast<std::size_t>(side)];
      // The hole's edge, beside ring cells 1..8 of the side.
      for (int k = 1; k <= 8; ++k) {
        for (int j = 0; j < per_cell; ++j) {
          const double along = k + (j + 0.5) / per_cell;
          if (along < kInnerLo + 0.2 || along > frame8::grid - kInnerLo - 0.2) continue;  // clear of the line's corners
          const double frac = along - k;
          if (frac < 0.15 || frac > 0.85) continue;  // two cells share the blur here
          if (white_at(side_point(side, along, 0.5))) {
            add(side_point(side, along, 1.25), outward, 0.65, true, axis);
          } else {
            add(side_point(side, along, kInnerLo), outward, 0.45, false, axis);
          }
        }
      }
      // Boundaries between neighbouring ring cells of different colours, across the ring.
      for (int boundary = 1; boundary < frame8::grid; ++boundary) {
        const bool before_white = white_at(side_point(side, boundary - 0.5, 0.5));
        if (before_white == white_at(side_point(side, boundary + 0.5, 0.5))) continue;
        // The normal points from the white cell to the black one.
        const Point2 forward = side_point(side, boundary + 1, 0) - side_point(side, boundary, 0);
        const Point2 normal = before_white ? forward : Point2{-forward.x, -forward.y};
        for (int j = 0; j < per_cell; ++j) {
          const double in = 0.15 + 0.7 * (j + 0.5) / per_cell;  // within the ring's width, clear of its edges
          add(side_point(side, boundary, in), normal, 0.45, false, 1 - axis);
        }
      }
    }
    return pattern_count_;
  }

  // Fits the map from grid coordinates to the image (or, with a camera, to
  // undistorted normalized coordinates) to the pattern's edges: each edge
  // point must lie on its grid line. The constraint is linear in the inverse
  // map, solved as a 9x9 eigenproblem and reweighted towards grid-unit
  // residuals, with one round of outlier rejection.
  bool fit_grid_map(Eigen::Matrix3d& grid_to_image) {
    const int n = pattern_count_;
    double mx = 0, my = 0, sw = 0;
    for (int i = 0; i < n; ++i) {
      mx += pattern_edges_[static_cast<std::size_t>(i)].x;
      my += pattern_edges_[static_cast<std::size_t>(i)].y;
    }
    mx /= n;
    my /= n;
    for (int i = 0; i < n; ++i) {
      sw += std::abs(pattern_edges_[static_cast<std::size_t>(i)].x - mx) + std::abs(pattern_edges_[static_cast<std::size_t>(i)].y - my);
    }
    const double scale = sw > 0 ? n / sw : 1.0;  // points normalised to a spread of about 1
    Eigen::Matrix<double, 3, 3> G;  // normalised image -> grid (homogeneous)
    std::array<double, kMaxPatternEdges> weight{};
    for (int i = 0; i < n; ++i) weight[static_cast<std::size_t>(i)] = pattern_edges_[static_cast<std::size_t>(i)].w;
    bool have = false;
    for (int iter = 0; iter < 3; ++iter) {
      Eigen::Matrix<double, 9, 9> ata = Eigen::Matrix<double, 9, 9>::Zero();
      int used = 0;
      for (int i = 0; i < n; ++i) {
        const PatternEdge& e = pattern_edges_[static_cast<std::size_t>(i)];
        double w = weight[static_cast<std::size_t>(i)];
        if (w <= 0) continue;
        const Eigen::Vector3d p((e.x - mx) * scale, (e.y - my) * scale, 1);
        if (have) {
          const double denom = G.row(2).dot(p);
          w /= denom * denom;  // algebraic to grid-unit residuals
        }
        Eigen::Matrix<double, 9, 1> row = Eigen::Matrix<double, 9, 1>::Zero();
        row.segment<3>(e.axis * 3) = p;
        row.segment<3>(6) = -e.value * p;
        ata.noalias() += w * row * row.transpose();
        ++used;
      }
      if (used < kMinPatternEdges) return false;
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(ata);
      if (eig.info() != Eigen::Success) return false;
      const Eigen::Matrix<double, 9, 1> g = eig.eigenvectors().col(0);
      G << g(0), g(1), g(2), g(3), g(4), g(5), g(6), g(7), g(8);
      have = true;
      if (iter == 1) {
        // Drop edges a fifth of a cell off the fit: a cell that is not what
        // the code says (an occluder, a covered edge).
        for (int i = 0; i < n; ++i) {
          const PatternEdge& e = pattern_edges_[static_cast<std::size_t>(i)];
          const Eigen::Vector3d p((e.x - mx) * scale, (e.y - my) * scale, 1);
          const Eigen::Vector3d q = G * p;
          if (std::abs(q(e.axis) / q(2) - e.value) > 0.2) weight[static_cast<std::size_t>(i)] = 0;
        }
      }
    }
    Eigen::Matrix3d denorm;
    denorm << 1 / scale, 0, mx, 0, 1 / scale, my, 0, 0, 1;
    Eigen::FullPivLU<Eigen::Matrix3d> lu(G);
    if (!lu.isInvertible()) return false;
    grid_to_image = denorm * lu.inverse();
    return true;
  }

  // Corners (and, with a camera, the pose) from the pattern's edges.
  bool finish_by_pattern(int rotation, Detection& det) {
    if (config_.camera) {
      for (int i = 0; i < pattern_count_; ++i) {
        auto& e = pattern_edges_[static_cast<std::size_t>(i)];
        const Point2 p = config_.camera->pixel_to_normalized({e.x, e.y});
        e.x = p.x;
        e.y = p.y;
      }
    }
    Eigen::Matrix3d M;
    return fit_grid_map(M) && report(M, rotation, det);
  }

  // With a camera: fit the same edge points in undistorted normalized
  // coordinates (straight lines there), then map back through the lens.
  bool refit_undistorted(int rotation, Detection& det) {
    const CameraModel& cam = *config_.camera;
    std::array<Line, 4> lines{};
    for (int side = 0; side < 4; ++side) {
      auto& pts = edge_points_[static_cast<std::size_t>(side)];
      const int n = edge_count_[static_cast<std::size_t>(side)];
      for (int i = 0; i < n; ++i) {
        if (pts[static_cast<std::size_t>(i)].w <= 0) continue;
        const Point2 p = cam.pixel_to_normalized({pts[static_cast<std::size_t>(i)].x, pts[static_cast<std::size_t>(i)].y});
        pts[static_cast<std::size_t>(i)].x = p.x;
        pts[static_cast<std::size_t>(i)].y = p.y;
      }
      // Outliers were dropped in pixel space already; no second rejection.
      if (!fit_line(pts.data(), n, std::numeric_limits<double>::infinity(), lines[static_cast<std::size_t>(side)])) {
        return false;
      }
    }
    std::array<Point2, 4> inner_n{};
    for (int i = 0; i < 4; ++i) {
      if (!intersect(lines[static_cast<std::size_t>((i + 3) % 4)], lines[static_cast<std::size_t>(i)],
                     inner_n[static_cast<std::size_t>(i)])) {
        return false;
      }
    }
    Homography Hn;
    return Homography::from_unit_square(inner_n, Hn) && report(grid_map(Hn), rotation, det);
  }

  // --- 4. the code ----------------------------------------------------------

  // What decode() made of a candidate: read, or the check that turned it
  // down (traced in debug builds).
  static constexpr int kRead = 0;
  static constexpr int kNoContrast = 4;  // the last check before the code itself
  static constexpr int kC1Contradicted = 9;
  static int reject(int check) {
    F8_TRACE("  rejected at check %d\n", check);
    return check;
  }

  struct CellSample {
    float mean = 0, lo = 0, hi = 0;  // over the points sampled in the cell
    bool valid = false;
  };

  // Samples a ring cell at its centre; where cells are resolved, at four
  // points around the centre instead (less noise, and a cell that is not one
  // colour all over shows itself).
  CellSample sample_cell(const Homography& H, frame8::Cell cell, double cell_px) const {
    CellSample out;
    const double cx = cell.col + 0.5, cy = cell.row + 0.5;
    if (cell_px < kResolvedCells) {
      const Point2 p = grid_point(H, cx, cy);
      out.valid = sample(full_, p.x, p.y, out.mean);
      out.lo = out.hi = out.mean;
      return out;
    }
    float sum = 0;
    out.lo = 255;
    out.hi = 0;
    for (int k = 0; k < 4; ++k) {
      const Point2 p = grid_point(H, cx + ((k & 1) ? 0.25 : -0.25), cy + ((k & 2) ? 0.25 : -0.25));
      float v = 0;
      if (!sample(full_, p.x, p.y, v)) return out;
      sum += v;
      out.lo = std::min(out.lo, v);
      out.hi = std::max(out.hi, v);
    }
    out.mean = sum / 4;
    out.valid = true;
    return out;
  }

  // Under about three pixels a cell, the blur mixes a ring cell's centre
  // sample with what surrounds it: its neighbours along the ring, the black
  // line and the hole inward, the background outward. A white cell between
  // two black ones (a bit beside a black corner) or against a dark
  // background reads grey, on every edge alike, and the repetition code
  // cannot correct what all four edges get wrong. The shares are known from
  // the cells' size in the image and the blur; the hole and the background
  // are sampled clear of the ring, the line is as dark as the black corners,
  // and the ring cells are unmixed by a few Jacobi steps.
  void unmix_ring(const Homography& H, std::array<CellSample, 4>& corner,
                  std::array<std::array<CellSample, 8>, 4>& cell) const {
    constexpr int kRing = 36;
    struct Mix {
      double self = 1, prev = 0, next = 0, line = 0, known = 0;  // known: hole and outside, sampled
    };
    std::array<CellSample*, kRing> ring{};
    std::array<frame8::Cell, kRing> where{};
    // Clockwise: C0, the top edge's bits 7..0, C1, the right edge's, C2, ...
    for (int k = 0; k < 4; ++k) {
      const auto at = static_cast<std::size_t>(9 * k);
      ring[at] = &corner[static_cast<std::size_t>(k)];
      where[at] = frame8::corner_cell(k);
      for (int b = 7; b >= 0; --b) {
        const auto i = at + static_cast<std::size_t>(8 - b);
        ring[i] = &cell[static_cast<std::size_t>(k)][static_cast<std::size_t>(b)];
        where[i] = frame8::data_cell(k, b);
      }
    }
    const detail::NormalTable& table = detail::normal_table();
    auto cdf = [&](double z) {
      double c = 0, unused = 0;
      table.at(z, c, unused);
      return c;
    };
    constexpr int last = frame8::grid - 1;
    std::array<Mix, kRing> mix{};
    std::array<double, kRing> seen{}, value{};
    for (std::size_t i = 0; i < kRing; ++i) {
      if (!ring[i]->valid) continue;
      const frame8::Cell c = where[i];
      const double u = c.col + 0.5, v = c.row + 0.5;
      // The blur in grid units along each axis, at this cell.
      const double sigma_u = profile_sigma_ / distance(grid_point(H, u - 0.5, v), grid_point(H, u + 0.5, v));
      const double sigma_v = profile_sigma_ / distance(grid_point(H, u, v - 0.5), grid_point(H, u, v + 0.5));
      // Per axis: +1 or -1 when the cell lies on the marker's outer edge
      // across that axis (the way out), 0 along the ring.
      const int out_u = c.col == 0 ? -1 : c.col == last ? 1 : 0;
      const int out_v = c.row == 0 ? -1 : c.row == last ? 1 : 0;
      auto outside_point = [&](int out, double sigma) { return out * (0.5 + std::max(0.5, 2 * sigma)); };
      Mix& m = mix[i];
      double outside = 0, hole = 0;
      if (out_u != 0 && out_v != 0) {
        // A corner: out on both axes; inward on each, a ring neighbour; inward
        // on both, the line's corner.
        const double o_u = cdf(-0.5 / sigma_u), s_u = cdf(0.5 / sigma_u) - o_u, in_u = 1 - o_u - s_u;
        const double o_v = cdf(-0.5 / sigma_v), s_v = cdf(0.5 / sigma_v) - o_v, in_v = 1 - o_v - s_v;
        m.self = s_u * s_v;
        const double along_u = in_u * s_v, along_v = s_u * in_v;
        // The ring neighbour in the same row lies along u.
        const frame8::Cell p = where[(i + kRing - 1) % kRing];
        m.prev = p.row == c.row ? along_u : along_v;
        m.next = p.row == c.row ? along_v : along_u;
        m.line = in_u * in_v;
        float a = 0, b = 0;
        const Point2 pa = grid_point(H, u + outside_point(out_u, sigma_u), v);
        const Point2 pb = grid_point(H, u, v + outside_point(out_v, sigma_v));
        if (!sample(full_, pa.x, pa.y, a) || !sample(full_, pb.x, pb.y, b)) continue;
        outside = (1 - (s_u + in_u) * (s_v + in_v)) * 0.5 * (a + b);
      } else {
        // An edge cell: across the ring (out, cell, line, hole), along it
        // (the two neighbours and the cells beyond them, lumped in).
        const bool across_u = out_u != 0;
        const double sa = across_u ? sigma_u : sigma_v, sl = across_u ? sigma_v : sigma_u;
        const int out = across_u ? out_u : out_v;
        const double o = cdf(-0.5 / sa), in_cell = cdf(0.5 / sa) - o, line = cdf(1.0 / sa) - cdf(0.5 / sa);
        const double inner = 1 - o - in_cell - line;
        const double side = cdf(-0.5 / sl);
        m.self = in_cell * (1 - 2 * side);
        m.prev = m.next = in_cell * side;
        m.line = line;
        float a = 0, b = 0;
        const double to_out = outside_point(out, sa), to_hole = -out * (1.0 + std::max(0.5, 2 * sa));
        const Point2 pa = grid_point(H, u + (across_u ? to_out : 0), v + (across_u ? 0 : to_out));
        const Point2 pb = grid_point(H, u + (across_u ? to_hole : 0), v + (across_u ? 0 : to_hole));
        if (!sample(full_, pa.x, pa.y, a) || !sample(full_, pb.x, pb.y, b)) continue;
        outside = o * a;
        hole = inner * b;
      }
      m.known = outside + hole;
      // The steps diverge once the neighbours' shares outweigh the cell's
      // own: cells under a pixel along the ring are left partly mixed.
      const double neighbours = m.prev + m.next;
      if (neighbours > kMaxNeighbourShare * m.self) {
        const double scale = kMaxNeighbourShare * m.self / neighbours;
        m.prev *= scale;
        m.next *= scale;
      }
    }
    for (std::size_t i = 0; i < kRing; ++i) seen[i] = value[i] = ring[i]->mean;
    // The line: first as dark as the darkest sample, then as the black corners unmixed.
    double line = *std::min_element(seen.begin(), seen.end());
    for (int pass = 0; pass < 2; ++pass) {
      for (int iter = 0; iter < kUnmixSteps; ++iter) {
        std::array<double, kRing> next_value{};
        for (std::size_t i = 0; i < kRing; ++i) {
          const Mix& m = mix[i];
          const double nb = m.prev * value[(i + kRing - 1) % kRing] + m.next * value[(i + 1) % kRing];
          next_value[i] = ring[i]->valid ? (seen[i] - nb - m.line * line - m.known) / m.self : seen[i];
        }
        value = next_value;
      }
      std::array<double, 4> corners{value[0], value[9], value[18], value[27]};
      std::sort(corners.begin(), corners.end());
      line = (corners[0] + corners[1] + corners[2]) / 3;
    }
    for (std::size_t i = 0; i < kRing; ++i) {
      if (!ring[i]->valid) continue;
      const auto v = static_cast<float>(std::clamp(value[i], -64.0, 320.0));
      ring[i]->mean = ring[i]->lo = ring[i]->hi = v;
    }
  }

  // The two short edges of a marker turned far hold all four corners, as
  // cells of about a pixel along the edge, with the background beyond them:
  // a corner's centre sample is a mix no fixed share can undo. Along the
  // edge, though, the profile of the ten cells is known once the code is:
  // fitted to it with the corners coloured each way, the right colouring
  // leaves the least residual. Per colouring of the edge's first and last
  // cell (0: both black, 1: the first white, 2: the last white): the
  // residual sum of squares, and what a corner's colour is worth in it (the
  // residual that taking a right-coloured corner for the wrong colour adds,
  // per unit of contrast squared).
  struct ShortEdgeFit {
    std::array<double, 3> residual{};
    std::array<double, 2> corner_worth{};
    double spread = 0;  // the profile's sum of squares about its mean
  };

  bool fit_short_edge(const Homography& H, int side, int id, double black, double white, ShortEdgeFit& fit) const {
    constexpr int kPerCell = 4;
    constexpr int kSamples = (frame8::grid + 2) * kPerCell + 1;  // from a cell outside to a cell beyond
    static constexpr std::array<double, 3> kAcross{0.3, 0.5, 0.7};
    std::array<double, kSamples> level{}, inv_sigma{};
    for (int i = 0; i < kSamples; ++i) {
      const double t = -1.0 + static_cast<double>(i) / kPerCell;
      float sum = 0;
      for (const double in : kAcross) {
        const Point2 p = grid_point(H, side_point(side, t, in));
        float v = 0;
        if (!sample(full_, p.x, p.y, v)) return false;
        sum += v;
      }
      level[static_cast<std::size_t>(i)] = sum / static_cast<double>(kAcross.size());
      const double px = distance(grid_point(H, side_point(side, t - 0.5, 0.5)), grid_point(H, side_point(side, t + 0.5, 0.5)));
      inv_sigma[static_cast<std::size_t>(i)] = px / profile_sigma_;
    }
    // The background beyond each end, measured a little further out, where
    // the corner's blur has faded: the corner and a free outside level would
    // otherwise trade their shares of the end samples.
    std::array<double, 2> outside{};
    for (int end = 0; end < 2; ++end) {
      const Point2 p = grid_point(H, side_point(side, end ? frame8::grid + kOutsideGap : -kOutsideGap, 0.5));
      float v = 0;
      if (!sample(full_, p.x, p.y, v)) return false;
      outside[static_cast<std::size_t>(end)] = v;
    }
    double mean = 0, yy = 0;
    for (const double y : level) {
      mean += y;
      yy += y * y;
    }
    mean /= kSamples;
    fit.spread = yy - kSamples * mean * mean;

    // Each sample is a blend of six parts: the black data cells, the white
    // ones, the first corner, the last corner, the outside before and the
    // outside after. For cell boundaries placed by a stretch and a shift
    // about the edge's middle (the quad's short sides are measured to a
    // fraction of a cell only), the parts' moments over the profile; any
    // model that colours the parts is a linear map of them.
    using Vector6 = Eigen::Matrix<double, 6, 1>;
    struct Moments {
      Eigen::Matrix<double, 6, 6> gram;
      Vector6 cross;
    };
    const detail::NormalTable& table = detail::normal_table();
    auto moments = [&](double stretch, double shift, Moments& m) {
      m.gram.setZero();
      m.cross.setZero();
      for (int i = 0; i < kSamples; ++i) {
        const double t = -1.0 + static_cast<double>(i) / kPerCell;
        const double is = inv_sigma[static_cast<std::size_t>(i)];
        Vector6 part = Vector6::Zero();
        double below = 0, unused = 0;
        table.at((5 + shift - 5 * stretch - t) * is, below, unused);
        part(4) = below;
        for (int c = 0; c < frame8::grid; ++c) {
          double upto = 0;
          table.at((5 + shift + stretch * (c - 4) - t) * is, upto, unused);
          const int to = c == 0 ? 2 : c == frame8::grid - 1 ? 3 : ((id >> (8 - c)) & 1);
          part(to) += upto - below;
          below = upto;
        }
        part(5) = 1 - below;
        m.gram.selfadjointView<Eigen::Lower>().rankUpdate(part);
        m.cross += part * level[static_cast<std::size_t>(i)];
      }
      m.gram = m.gram.selfadjointView<Eigen::Lower>();
    };
    // Black, white and the outside levels are held near the ring's levels
    // and the measured background by as much as a few samples would: no
    // colouring fits by turning the contrast down or over, or by trading
    // the corner for the background.
    const Eigen::Vector4d prior(black, white, outside[0], outside[1]);
    auto residual = [&](const Moments& m, const Eigen::Matrix<double, 6, 4>& model) {
      Eigen::Matrix4d normal = model.transpose() * m.gram * model;
      normal.diagonal().array() += kLevelPrior + kProfileRidge;
      const Eigen::Vector4d rhs = model.transpose() * m.cross + kLevelPrior * prior;
      const Eigen::Vector4d x = normal.ldlt().solve(rhs);
      return std::max(yy + kLevelPrior * prior.squaredNorm() - x.dot(rhs), 0.0);
    };
    // The model of a colouring: 0 both corners black, 1 the first white, 2 the last white.
    auto coloured = [](int colouring) {
      Eigen::Matrix<double, 6, 4> model = Eigen::Matrix<double, 6, 4>::Zero();
      model(0, 0) = model(1, 1) = model(4, 2) = model(5, 3) = 1;
      model(2, colouring == 1 ? 1 : 0) = 1;
      model(3, colouring == 2 ? 1 : 0) = 1;
      return model;
    };
    // First the alignment, with the corners free: the eight data cells,
    // known, place the boundaries without favouring any colouring.
    auto free_corners = [&](const Moments& m) {
      Eigen::Matrix<double, 6, 6> normal = m.gram;
      normal.diagonal().array() += kProfileRidge;
      Vector6 rhs = m.cross;
      static constexpr std::array<int, 4> kHeld{0, 1, 4, 5};  // the parts the prior holds, in its order
      for (int k = 0; k < 4; ++k) {
        const int part = kHeld[static_cast<std::size_t>(k)];
        normal(part, part) += kLevelPrior;
        rhs(part) += kLevelPrior * prior(k);
      }
      const Vector6 x = normal.ldlt().solve(rhs);
      return yy + kLevelPrior * prior.squaredNorm() - x.dot(rhs);
    };
    Moments m;
    double best_stretch = 1, best_shift = 0, best = std::numeric_limits<double>::infinity();
    for (int i = 0; i < kStretchSteps; ++i) {
      const double stretch = kMinStretch + i * kStretchStep;
      for (int j = -kShiftSteps; j <= kShiftSteps; ++j) {
        const double shift = j * kShiftStep;
        moments(stretch, shift, m);
        if (const double r = free_corners(m); r < best) {
          best = r;
          best_stretch = stretch;
          best_shift = shift;
        }
      }
    }
    // Then each colouring at its best, near there.
    fit.residual.fill(std::numeric_limits<double>::infinity());
    for (int i = -1; i <= 1; ++i) {
      for (int j = -1; j <= 1; ++j) {
        moments(best_stretch + 0.5 * i * kStretchStep, best_shift + 0.5 * j * kShiftStep, m);
        for (int colouring = 0; colouring < 3; ++colouring) {
          const double r = residual(m, coloured(colouring));
          if (r < fit.residual[static_cast<std::size_t>(colouring)]) {
            fit.residual[static_cast<std::size_t>(colouring)] = r;
            if (colouring > 0) fit.corner_worth[static_cast<std::size_t>(colouring - 1)] = m.gram(colouring + 1, colouring + 1);
          }
        }
      }
    }
    F8_TRACE("   side %d: stretch %.2f shift %.2f residual %.0f %.0f %.0f\n", side, best_stretch, best_shift, fit.residual[0], fit.residual[1], fit.residual[2]);
    return true;
  }

  // The white corner of a marker whose short edges are `side` and side + 2,
  // from their profiles (fit_short_edge), with `clarity` the margin to the
  // next best colouring in units of what a corner's colour is worth; -1
  // when the code leaves either profile unexplained. With only the two long
  // edges voting, the code has no redundancy left: the short edges are its
  // check.
  int white_corner_by_short_edges(const Homography& H, int side, int id, double black, double white, double& clarity) const {
    std::array<ShortEdgeFit, 2> fit{};
    if (!fit_short_edge(H, side, id, black, white, fit[0]) || !fit_short_edge(H, side + 2, id, black, white, fit[1])) return -1;
    const double contrast = white - black;
    // Residual and worth when corner k is the white one (k = 4: none is).
    auto colouring = [&](int edge, int k) {
      const int first = side + 2 * edge, last = (first + 1) % 4;
      return k == first ? 1 : k == last ? 2 : 0;
    };
    std::array<double, 5> residual{}, worth{};
    for (int k = 0; k < 5; ++k) {
      for (int edge = 0; edge < 2; ++edge) {
        const auto& f = fit[static_cast<std::size_t>(edge)];
        const int c = colouring(edge, k);
        residual[static_cast<std::size_t>(k)] += f.residual[static_cast<std::size_t>(c)];
        if (c != 0) worth[static_cast<std::size_t>(k)] = f.corner_worth[static_cast<std::size_t>(c - 1)];
      }
    }
    int best = 0;
    for (int k = 1; k < 4; ++k) {
      if (residual[static_cast<std::size_t>(k)] < residual[static_cast<std::size_t>(best)]) best = k;
    }
    clarity = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 5; ++k) {
      if (k == best) continue;
      const double expected = contrast * contrast * (worth[static_cast<std::size_t>(best)] + worth[static_cast<std::size_t>(k)]);
      clarity = std::min(clarity, (residual[static_cast<std::size_t>(k)] - residual[static_cast<std::size_t>(best)]) / expected);
    }
    // Each edge's profile is the code's, to what the model misses of the
    // optics: clutter's profiles fit the code no better than any other.
    double unexplained = 0;
    for (int edge = 0; edge < 2; ++edge) {
      const auto& f = fit[static_cast<std::size_t>(edge)];
      unexplained = std::max(unexplained, f.residual[static_cast<std::size_t>(colouring(edge, best))] / f.spread);
    }
    F8_TRACE("  short edges %d,%d: residual %.0f %.0f %.0f %.0f none %.0f, corner %d clarity %.2f unexplained %.3f\n", side, side + 2,
             residual[0], residual[1], residual[2], residual[3], residual[4], best, clarity, unexplained);
    if (!(unexplained < kMaxUnexplained)) return -1;
    return best;
  }

  // How well an edge's cells are resolved along the edge, 0..1: a cell under
  // a pixel wide is blurred into its neighbours.
  static double edge_weight(const Homography& H, int edge) {
    const frame8::Cell a = frame8::data_cell(edge, 6), b = frame8::data_cell(edge, 1);
    const double pitch = distance(grid_point(H, a.col + 0.5, a.row + 0.5), grid_point(H, b.col + 0.5, b.row + 0.5)) / 5.0;
    return std::clamp((pitch - 0.7) / 1.3, 0.02, 1.0);
  }

  // Reads cells too small to sample from the blur model of the ring, given
  // why reading them from samples failed (`sampled`); with the map moved to
  // where the model fits best, H follows it.
  bool read_by_model(Homography& H, CellSize cell_size, int sampled, Detection& det, int& rotation) {
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

  // Decides the code from the ring cells' grey levels: sampled in the image,
  // or fitted by the ring model when `model` is given.
  int decode(const Homography& H, CellSize cell_size, Detection& det, int& rotation,
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

  [[nodiscard]] bool inside_detection(const Component& c, const std::vector<Detection>& found) const {
    const double d = decimate_;
    const Point2 centre{(c.x0 + c.x1 - 1) * 0.5 * d + (d - 1) / 2, (c.y0 + c.y1) * 0.5 * d + (d - 1) / 2};
    for (const Detection& det : found) {
      if (inside(det.corners, centre)) return true;
    }
    return false;
  }

  static bool inside(const Quad& q, Point2 p) {
    for (int i = 0; i < 4; ++i) {
      if (cross(q[static_cast<std::size_t>(i)], q[static_cast<std::size_t>((i + 1) % 4)], p) < 0) return false;
    }
    return true;
  }

  // A marker has one hole, but a white cell enclosed by black neighbours (or
  // the line) is a small light square too, and may read as some code. Any
  // detection lying within a larger one is such a part of it, and is dropped.
  static void remove_nested(std::vector<Detection>& out) {
    auto area = [](const Quad& q) {
      double a = 0;
      for (int i = 0; i < 4; ++i) a += q[static_cast<std::size_t>(i)].x * q[static_cast<std::size_t>((i + 1) % 4)].y - q[static_cast<std::size_t>((i + 1) % 4)].x * q[static_cast<std::size_t>(i)].y;
      return std::abs(a) / 2;
    };
    for (std::size_t i = out.size(); i-- > 0;) {
      const Point2 centre = 0.25 * (out[i].corners[0] + out[i].corners[1] + out[i].corners[2] + out[i].corners[3]);
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

  static constexpr int kMaxEdgePoints = 48;
  // collect_edge_points() without a code: the step's centroid everywhere, or
  // each point classified by its own profile.
  static constexpr int kNoCode = -1;
  static constexpr int kClassifyByProfile = -2;
  // ... or the profiles fitted with a model of the blurred line and the
  // cells beyond it (fit_edge_profile), in kProfileSegments sums per side.
  static constexpr int kFitProfile = -3;
  static constexpr std::size_t kProfileSegments = 4;
  // The fit moves the measured edge at most this far (pixels), in steps of
  // at most kProfileMaxStep, until a step is under kProfileConverged.
  static constexpr double kProfileReach = 1.2;
  static constexpr double kProfileMaxStep = 0.4;
  static constexpr double kProfileConverged = 0.03;
  static constexpr int kProfileIterations = 4;
  // Keeps the levels' normal equations solvable where a basis barely shows
  // (the outside, at the end of a short profile).
  static constexpr double kProfileRidge = 1e-3;
  // How much darker than the hole (grey levels) a fitted line must be.
  static constexpr double kMinLineContrast = 8.0;
  // Cells below this many pixels (the mean over the marker) are not read:
  // beyond 3.3 m for the thesis's marker and camera. Clutter offers many
  // such small holes, and what their rings read as is noise.
  static constexpr double kMinCells = 1.2;
  static constexpr double kTinyCells = 1.5;
  // Below this many pixels per cell the black line (half a cell) is thin
  // against a typical blur, and the edges are measured a second time.
  static constexpr double kThinLineCells = 8.0;
  // From this many pixels per cell, a cell is sampled at four points.
  static constexpr double kResolvedCells = 3.0;
  // From this many pixels per cell across, the line's darkness is checked.
  static constexpr double kCheckedLineCells = 2.0;
  // Perspective shortens one end of a far-turned marker below the cosine of
  // its turn: 0.12 at 80 degrees, seen from 0.5 m; and a hole's short side
  // of a few pixels is measured up to a pixel short.
  static constexpr double kMinSideRatio = 0.08;
  // The edge_weight() an edge needs to vote when others are resolved (cells of 1.2 px).
  static constexpr double kVotingEdge = 0.38;
  // A side shorter than this fraction of its neighbours is a sliver's end.
  static constexpr double kSliverEnd = 0.35;
  // From this many pixels per cell, the corners come from the whole pattern.
  static constexpr double kPatternCells = 1.0;
  static constexpr int kMinPatternEdges = 16;
  static constexpr int kMaxPatternEdges = 384;
  // unmix_ring()'s Jacobi steps, and the most its neighbours may weigh
  // against a cell's own share.
  static constexpr int kUnmixSteps = 3;
  // Opposite sides of a marker with cells under kResolvedCells: at most
  // this ratio (1.06 for 30 px seen at a focal length of 500 px).
  static constexpr double kMaxSmallSideRatio = 1.3;
  static constexpr double kMaxNeighbourShare = 0.7;
  // How many profile samples' worth the ring's grey levels weigh in a short
  // edge's fit (fit_short_edge).
  static constexpr double kLevelPrior = 4.0;
  // How far beyond a short edge's end (in cells) its background is measured.
  static constexpr double kOutsideGap = 1.75;
  // The search for a short edge's cell boundaries: stretches from
  // kMinStretch in kStretchSteps, shifts (cells) within kShiftSteps steps
  // either way; the hole's short side, of a few pixels, is often measured
  // a pixel short.
  static constexpr double kMinStretch = 0.86;
  static constexpr double kStretchStep = 0.06;
  static constexpr int kStretchSteps = 10;
  static constexpr double kShiftStep = 0.15;
  static constexpr int kShiftSteps = 4;
  // The most of a short edge's profile (its sum of squares about its mean)
  // that the code's fit may leave unexplained.
  static constexpr double kMaxUnexplained = 0.1;
  // How dark (soft level, -1 = black) the ring model must find the line.
  static constexpr double kClearLine = 0.5;

  DetectorConfig config_;
  // The blur an edge profile sees: the lens, the pixel's area and the
  // bilinear sampling of the profile (a quarter pixel squared on average).
  double profile_sigma_ = 0.7;
  GreyView full_{};
  GreyView work_{};
  int decimate_ = 1;
  std::vector<std::uint8_t> decimated_;
  std::vector<std::uint32_t> tile_sum_;
  std::vector<std::uint32_t> tile_row_sum_;
  std::vector<std::uint8_t> tile_threshold_;
  std::vector<std::uint8_t> pixel_threshold_;
  std::vector<std::uint8_t> column_max_, local_max_;
  std::vector<std::uint64_t> light_bits_;
  std::array<std::array<float, 64>, kProfileSegments> segment_profile_{};
  std::array<Point2, kProfileSegments> segment_base_{};
  std::array<int, kProfileSegments> segment_count_{};
  std::vector<Run> runs_;
  std::vector<std::int32_t> row_first_;
  std::vector<Component> components_;
  std::vector<std::int32_t> roots_;
  std::vector<std::int32_t> line_min_, line_max_;
  std::vector<Point2> points_, hull_, hull_twice_;
  std::array<std::array<EdgePoint, kMaxEdgePoints>, 4> edge_points_{};
  std::array<int, 4> edge_count_{};
  std::array<PatternEdge, kMaxPatternEdges> pattern_edges_{};
  int pattern_count_ = 0;
  frame8::RingModel ring_model_;
  frame8::RingModel::Levels levels_;
};

}  // namespace

std::unique_ptr<MarkerDetector> make_frame8_detector(const DetectorConfig& config) {
  return std::make_unique<Frame8Detector>(config);
}

}  // namespace markerd
