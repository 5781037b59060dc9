// Stage 1, segmentation: the working image, its adaptive threshold, and the
// light pixels' row runs joined into components.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace markerd::detector::frame8 {

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

void Frame8Detector::make_working_image() {
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
void Frame8Detector::sum_tiles(int tw, int th) {
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

void Frame8Detector::threshold_tiles() {
  const int w = work_.width, h = work_.height;
  const int tw = (w + kTile - 1) / kTile, th = (h + kTile - 1) / kTile;
  tile_sum_.assign(static_cast<std::size_t>(tw) * th, 0);
  sum_tiles(tw, th);
  // Threshold per tile: mean of the 3x3 tiles around it, minus the offset.
  // The 3x3 sums are separable; the pixel count of a neighbourhood is the
  // product of its width and height, and the rounding division by it is a
  // multiplication by its reciprocal (exact for these sums, see kMaxTileSum).
  // Each row's sums of three tiles, with a row of zeros above the first
  // and below the last, so that the column sums below need no test.
  tile_row_sum_.assign(static_cast<std::size_t>(tw) * (th + 2), 0);
  for (int ty = 0; ty < th; ++ty) {
    const std::uint32_t* in = tile_sum_.data() + static_cast<std::size_t>(ty) * tw;
    std::uint32_t* out = tile_row_sum_.data() + static_cast<std::size_t>(ty + 1) * tw;
    out[0] = in[0] + (tw > 1 ? in[1] : 0);
    int tx = 1;
#if defined(__SSE2__)
    for (; tx + 5 <= tw; tx += 4) {
      const __m128i left = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + tx - 1));
      const __m128i here = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + tx));
      const __m128i right = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + tx + 1));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(out + tx), _mm_add_epi32(_mm_add_epi32(left, here), right));
    }
#endif
    for (; tx + 1 < tw; ++tx) out[tx] = in[tx - 1] + in[tx] + in[tx + 1];
    if (tw > 1) out[tw - 1] = in[tw - 2] + in[tw - 1];
  }
  auto span = [](int t, int tiles, int pixels) {  // pixels covered by tiles t-1 .. t+1
    const int lo = std::max(0, t - 1) * kTile;
    const int hi = std::min(tiles, t + 2) * kTile;
    return std::min(hi, pixels) - lo;
  };
  tile_span_x_.resize(static_cast<std::size_t>(tw));
  for (int tx = 0; tx < tw; ++tx)
    tile_span_x_[static_cast<std::size_t>(tx)] = static_cast<std::uint32_t>(span(tx, tw, w));
  tile_threshold_.resize(static_cast<std::size_t>(tw) * th);
  const int offset = config_.frame8.threshold_offset;
  for (int ty = 0; ty < th; ++ty) {
    const std::uint32_t* up = tile_row_sum_.data() + static_cast<std::size_t>(ty) * tw;
    const std::uint32_t* mid = up + tw;
    const std::uint32_t* down = mid + tw;
    const auto rows = static_cast<std::uint32_t>(span(ty, th, h));
    std::uint8_t* out = tile_threshold_.data() + static_cast<std::size_t>(ty) * tw;
    auto threshold = [&](int tx) {
      const std::uint32_t sum = up[tx] + mid[tx] + down[tx];
      const std::uint32_t n = rows * tile_span_x_[static_cast<std::size_t>(tx)];
      const auto mean = static_cast<int>(((sum + n / 2) * kReciprocal[n]) >> 32);
      out[tx] = static_cast<std::uint8_t>(std::clamp(mean - offset, 0, 255));
    };
    threshold(0);
    int tx = 1;
#if defined(__SSE2__)
    // Between the first and the last column every neighbourhood spans three
    // whole tiles across: one pixel count, one reciprocal for the row. The
    // products are 64 bits wide, two lanes at a time.
    if (tw > 2) {
      const std::uint32_t n = rows * tile_span_x_[1];
      const __m128i half = _mm_set1_epi32(static_cast<int>(n / 2));
      const __m128i reciprocal = _mm_set1_epi32(static_cast<int>(kReciprocal[n]));
      const __m128i vo = _mm_set1_epi32(offset);
      const __m128i odd_lanes = _mm_set_epi32(-1, 0, -1, 0);
      // Four tiles' means less the offset, as 32-bit lanes.
      auto four = [&](int at) {
        const __m128i sum = _mm_add_epi32(_mm_add_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(up + at)),
                                                        _mm_loadu_si128(reinterpret_cast<const __m128i*>(mid + at))),
                                          _mm_loadu_si128(reinterpret_cast<const __m128i*>(down + at)));
        const __m128i rounded = _mm_add_epi32(sum, half);
        const __m128i even = _mm_srli_epi64(_mm_mul_epu32(rounded, reciprocal), 32);
        const __m128i odd = _mm_mul_epu32(_mm_srli_epi64(rounded, 32), reciprocal);
        // even's quotients sit in lanes 0 and 2, odd's (its high halves) in 1 and 3.
        return _mm_sub_epi32(_mm_or_si128(even, _mm_and_si128(odd, odd_lanes)), vo);
      };
      // Up to the third last column: the last tile may be partial, and the
      // second last's neighbourhood then spans fewer pixels.
      for (; tx + 10 <= tw; tx += 8) {
        // Signed saturation to 16 bits, then unsigned to 8: the clamp to 0..255.
        const __m128i bytes = _mm_packus_epi16(_mm_packs_epi32(four(tx), four(tx + 4)), _mm_setzero_si128());
        _mm_storel_epi64(reinterpret_cast<__m128i*>(out + tx), bytes);
      }
    }
#endif
    for (; tx < tw; ++tx) threshold(tx);
  }
}

void Frame8Detector::light_pixels_and_runs(LocalRule rule) {
  const int w = work_.width, h = work_.height;
  const int tw = (w + kTile - 1) / kTile;
  runs_.clear();
  row_first_.resize(static_cast<std::size_t>(h) + 1);
  pixel_threshold_.resize(static_cast<std::size_t>(w) + 16);
  column_max_.resize(static_cast<std::size_t>(w) + 2);
  local_floor_.resize(static_cast<std::size_t>(w));
  const int words = (w + 63) / 64;
  // Every row's bits are kept: the outlines of components that are no
  // quad are traced on them (open_hole.cpp).
  light_stride_ = static_cast<std::size_t>(words) + 1;
  light_bits_.resize(light_stride_ * static_cast<std::size_t>(h));
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
    if (rule == LocalRule::brightest_neighbour) {
      brightest_neighbour_row(y);
    } else {
      valley_row(y);
    }
    light_row_bits(work_.row(y), w, light_bits_.data() + light_stride_ * static_cast<std::size_t>(y));
    extract_runs(y, w, words);
  }
  row_first_[static_cast<std::size_t>(h)] = static_cast<std::int32_t>(runs_.size());
}

// The local rules (docs/architecture.md, stage 1): local_floor_[x], the
// level pixel (x, y) of the row must reach, besides its neighbourhood's
// mean, to be light.
//
// brightest_neighbour: the brightest pixel of the 3x3 neighbourhood less
// the step. A pixel under it sits on the dark side of a sharp edge: a
// marker's line one pixel thin, which the wide mean misses when the
// background around a small marker drags the mean down. It also takes the
// shoulders of a light ridge, and leaves a ridge two or three pixels wide
// (a socket's face between the line and its recess at 2 m, a print's
// margin round a cut-out hole over a dark ground) its crest alone, a
// pixel wide, which noise and the crest's own wander break.
void Frame8Detector::brightest_neighbour_row(int y) {
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
  const std::uint8_t step = local_step();
  std::uint8_t* out = local_floor_.data();
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

// valley: the darker of the brightest pixels within two on either side,
// along the row, the column or a diagonal, whichever is brightest, less
// the step: a pixel is dark by it only in a valley, brighter on both
// sides, as a line between two light areas is; a ridge's shoulders, on a
// slope, are not.
void Frame8Detector::valley_row(int y) {
  const int w = work_.width, h = work_.height;
  std::array<const std::uint8_t*, 5> r{};
  for (int k = 0; k < 5; ++k) r[static_cast<std::size_t>(k)] = work_.row(std::clamp(y - 2 + k, 0, h - 1));
  const std::uint8_t step = local_step();
  std::uint8_t* out = local_floor_.data();
  auto at = [&](int k, int x) { return r[static_cast<std::size_t>(k)][std::clamp(x, 0, w - 1)]; };
  auto side = [&](int k1, int x1, int k2, int x2) { return std::max(at(k1, x1), at(k2, x2)); };
  auto scalar = [&](int x) {
    const int m = std::max({std::min(side(2, x - 1, 2, x - 2), side(2, x + 1, 2, x + 2)),
                            std::min(side(1, x, 0, x), side(3, x, 4, x)),
                            std::min(side(1, x - 1, 0, x - 2), side(3, x + 1, 4, x + 2)),
                            std::min(side(1, x + 1, 0, x + 2), side(3, x - 1, 4, x - 2))});
    out[x] = static_cast<std::uint8_t>(std::max(0, m - step));
  };
  int x = 0;
  for (; x < std::min(2, w); ++x) scalar(x);
#if defined(__SSE2__)
  auto load = [&](int k, int at_x) {
    return _mm_loadu_si128(reinterpret_cast<const __m128i*>(r[static_cast<std::size_t>(k)] + at_x));
  };
  auto valley = [](__m128i a1, __m128i a2, __m128i b1, __m128i b2) {
    return _mm_min_epu8(_mm_max_epu8(a1, a2), _mm_max_epu8(b1, b2));
  };
  const __m128i vstep = _mm_set1_epi8(static_cast<char>(step));
  for (; x + 18 <= w; x += 16) {
    const __m128i along_row = valley(load(2, x - 1), load(2, x - 2), load(2, x + 1), load(2, x + 2));
    const __m128i along_column = valley(load(1, x), load(0, x), load(3, x), load(4, x));
    const __m128i down_right = valley(load(1, x - 1), load(0, x - 2), load(3, x + 1), load(4, x + 2));
    const __m128i down_left = valley(load(1, x + 1), load(0, x + 2), load(3, x - 1), load(4, x - 2));
    const __m128i m = _mm_max_epu8(_mm_max_epu8(along_row, along_column), _mm_max_epu8(down_right, down_left));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), _mm_subs_epu8(m, vstep));
  }
#endif
  for (; x < w; ++x) scalar(x);
}

// Bit x of light_bits_ is set when pixel x is light: not below the mean of
// its neighbourhood (minus the offset) and not under the local rule's
// floor.
void Frame8Detector::light_row_bits(const std::uint8_t* row, int w, std::uint64_t* bits) {
  std::fill(bits, bits + light_stride_, 0);
  const std::uint8_t* thr = pixel_threshold_.data();
  const std::uint8_t* lmax = local_floor_.data();
  int x = 0;
#if defined(__SSE2__)
  for (; x + 16 <= w; x += 16) {
    const __m128i p = _mm_loadu_si128(reinterpret_cast<const __m128i*>(row + x));
    const __m128i t = _mm_max_epu8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(thr + x)),
                                   _mm_loadu_si128(reinterpret_cast<const __m128i*>(lmax + x)));
    const __m128i light = _mm_cmpeq_epi8(_mm_max_epu8(p, t), p);  // p >= t
    const auto mask = static_cast<std::uint64_t>(static_cast<std::uint32_t>(_mm_movemask_epi8(light)));
    bits[x >> 6] |= mask << (x & 63);
  }
#endif
  for (; x < w; ++x) {
    if (row[x] >= std::max(thr[x], lmax[x])) bits[x >> 6] |= std::uint64_t{1} << (x & 63);
  }
}

void Frame8Detector::extract_runs(int y, int w, int words) {
  const std::uint64_t* bits = light_bits_.data() + light_stride_ * static_cast<std::size_t>(y);
  int x = 0;
  while (x < w) {
    // Find the next set bit at or after x.
    int wi = x >> 6;
    std::uint64_t word = bits[wi] & (~std::uint64_t{0} << (x & 63));
    while (word == 0 && ++wi < words) word = bits[wi];
    if (word == 0) break;
    const int start = (wi << 6) + __builtin_ctzll(word);
    if (start >= w) break;
    // Find the next clear bit after start.
    wi = start >> 6;
    word = ~bits[wi] & (~std::uint64_t{0} << (start & 63));
    while (word == 0 && ++wi < words) word = ~bits[wi];
    int end = word == 0 ? w : (wi << 6) + __builtin_ctzll(word);
    end = std::min(end, w);
    const auto index = static_cast<std::int32_t>(runs_.size());
    runs_.push_back({start, end, y, index, -1});
    x = end;
  }
}

std::int32_t Frame8Detector::find(std::int32_t r) {
  while (runs_[static_cast<std::size_t>(r)].parent != r) {
    auto& run = runs_[static_cast<std::size_t>(r)];
    run.parent = runs_[static_cast<std::size_t>(run.parent)].parent;
    r = run.parent;
  }
  return r;
}

void Frame8Detector::unite(std::int32_t a, std::int32_t b) {
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

void Frame8Detector::label_components() {
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

}  // namespace markerd::detector::frame8
