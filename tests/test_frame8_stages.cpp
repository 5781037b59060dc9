// The frame8 detector's stages one at a time (detector/src/frame8/), where a
// stage has a contract of its own: the quad fit on a synthetic contour, the
// edge refinement and the decoding on a clean synthetic marker, and the
// rejections' stages. The whole detector is tested in test_frame8.cpp.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <set>
#include <string>
#include <vector>

#include "frame8/detector.hpp"
#include "markerd/detector/frame8.hpp"

namespace markerd::detector::frame8 {

// A clean marker, axis-aligned: `cell_x` by `cell_y` pixels a cell (a
// marker turned about its vertical axis is narrower across), its outer
// edge from pixel `origin` (pixel centres at integers), ink 30 on paper 220.
GreyImage clean_marker(int id, int cell_x, int cell_y, int origin, int size) {
  GreyImage img(size, size, 220);
  const auto cells = frame8::ring_cells(id);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const double gx = static_cast<double>(x - origin) / cell_x + 0.5 / cell_x;
      const double gy = static_cast<double>(y - origin) / cell_y + 0.5 / cell_y;
      if (gx < 0 || gy < 0 || gx >= frame8::grid || gy >= frame8::grid) continue;
      const int col = static_cast<int>(gx), row = static_cast<int>(gy);
      const std::uint8_t ring = cells[static_cast<std::size_t>(row * frame8::grid + col)];
      bool black = false;
      if (ring != 2) {
        black = ring == 0;
      } else {
        // Between the ring and the hole: the line, from 1.0 to 1.5 cells in.
        const double in = std::min({gx, gy, frame8::grid - gx, frame8::grid - gy});
        black = in < frame8::line_inner;
      }
      if (black) img.row(y)[x] = 30;
    }
  }
  return img;
}

GreyImage clean_marker(int id, int cell = 10, int origin = 50, int size = 200) {
  return clean_marker(id, cell, cell, origin, size);
}

// The same image turned a quarter clockwise.
GreyImage turned(const GreyImage& in) {
  GreyImage out(in.height(), in.width());
  for (int y = 0; y < in.height(); ++y) {
    for (int x = 0; x < in.width(); ++x) out.row(x)[in.height() - 1 - y] = in.row(y)[x];
  }
  return out;
}

// The inner corners (the hole's) of clean_marker(): 1.5 cells in.
std::array<Point2, 4> clean_inner(int cell = 10, int origin = 50) {
  const double lo = origin - 0.5 + 1.5 * cell, hi = origin - 0.5 + 8.5 * cell;
  return {{{lo, lo}, {hi, lo}, {hi, hi}, {lo, hi}}};
}

// Paints the data cell of `bit` on `edge` of clean_marker() one grey.
void paint_cell(GreyImage& img, int edge, int bit, std::uint8_t grey, int cell = 10, int origin = 50) {
  const frame8::Cell c = frame8::data_cell(edge, bit);
  for (int y = origin + cell * c.row; y < origin + cell * (c.row + 1); ++y) {
    for (int x = origin + cell * c.col; x < origin + cell * (c.col + 1); ++x) img.row(y)[x] = grey;
  }
}

// Paints the cell of `bit` on `edge` of clean_marker(id) the other colour.
void flip_cell(GreyImage& img, int id, int edge, int bit) { paint_cell(img, edge, bit, ((id >> bit) & 1) ? 30 : 220); }

class Frame8StageTest : public ::testing::Test {
 protected:
  Frame8Detector detector_{DetectorConfig{}};

  Rejection decode(const GreyImage& img, const std::array<Point2, 4>& inner, double cell_px, Detection& det,
                   int& rotation) {
    detector_.full_ = img.view();
    Homography H;
    if (!Homography::from_unit_square(inner, H)) return Rejection::degenerate_quad;
    return detector_.decode(H, CellSize{cell_px, cell_px}, det, rotation, nullptr);
  }

  Rejection refine(const GreyImage& img, const std::array<Point2, 4>& coarse, double cell_px,
                   std::array<Point2, 4>& inner) {
    detector_.full_ = img.view();
    detector_.decimate_ = 1;
    return detector_.refine_sides(coarse, Frame8Detector::EdgeMode::step, std::nullopt, cell_px, inner);
  }

  // One side's line by the step alone, within its first reach.
  Rejection fit_side_by_step(const GreyImage& img, const std::array<Point2, 4>& coarse, int side, double cell_px) {
    detector_.full_ = img.view();
    detector_.decimate_ = 1;
    Line line;
    return detector_.fit_side(coarse, side, Frame8Detector::EdgeMode::step, std::nullopt, cell_px, line);
  }

  bool read_by_ring_alignment(const GreyImage& img, const std::array<Point2, 4>& seen, CellSize size, Detection& det,
                              Homography& H) {
    detector_.full_ = img.view();
    detector_.decimate_ = 1;
    int rotation = 0;
    return detector_.read_by_ring_alignment(seen, size, det, rotation, H);
  }

  // The light pixels of row y under the first local rule, or the valley rule (stage 1).
  std::vector<bool> light_row(const GreyImage& img, bool valley, int y) {
    detector_.full_ = img.view();
    detector_.make_working_image();
    detector_.threshold_tiles();
    detector_.light_pixels_and_runs(valley ? Frame8Detector::LocalRule::valley
                                           : Frame8Detector::LocalRule::brightest_neighbour);
    std::vector<bool> light(static_cast<std::size_t>(img.width()));
    const std::uint64_t* bits = detector_.light_bits_.data() + detector_.light_stride_ * static_cast<std::size_t>(y);
    for (int x = 0; x < img.width(); ++x) light[static_cast<std::size_t>(x)] = (bits[x >> 6] >> (x & 63)) & 1U;
    return light;
  }

  // Each 4x4 tile's threshold (stage 1), row by row.
  std::vector<std::uint8_t> tile_thresholds(const GreyImage& img) {
    detector_.full_ = img.view();
    detector_.make_working_image();
    detector_.threshold_tiles();
    return detector_.tile_threshold_;
  }

  // The valley rule's floor for row y (what a pixel must reach besides the mean).
  std::vector<int> valley_floor(const GreyImage& img, int y) {
    detector_.full_ = img.view();
    detector_.make_working_image();
    detector_.local_floor_.resize(static_cast<std::size_t>(img.width()));
    detector_.valley_row(y);
    return {detector_.local_floor_.begin(), detector_.local_floor_.end()};
  }

  // Stages 1 and 2 for the light component at (x, y) of `img`, by a
  // detector told `mounting`.
  Rejection fit_quad_at(const GreyImage& img, Mounting mounting, int x, int y, double& hull_excess,
                        bool* small_and_bulging = nullptr) {
    DetectorConfig config;
    config.frame8.mounting = mounting;
    Frame8Detector detector(config);
    detector.full_ = img.view();
    detector.make_working_image();
    detector.threshold_tiles();
    detector.light_pixels_and_runs(Frame8Detector::LocalRule::brightest_neighbour);
    detector.label_components();
    const Component* c = detector.component_at(x, y);
    if (c == nullptr) return Rejection::box_size;
    Component component = *c;
    std::array<Point2, 4> quad{};
    const Rejection why = detector.fit_quad(component, quad);
    double quad_area = 0, hull_area = 0;
    detector.largest_quad_of_rows(component.y0, component.y1 - component.y0 + 1, quad, quad_area, hull_area);
    hull_excess = (hull_area - quad_area) / hull_area;
    if (small_and_bulging != nullptr) *small_and_bulging = component.small_and_bulging;
    return why;
  }

  static constexpr int kMinPatternEdges = Frame8Detector::kMinPatternEdges;

  // The pattern's edges collect_pattern_edges() finds on `img` for the
  // code `id` read the right way round, with `hidden` left out.
  int pattern_edges(const GreyImage& img, const std::array<Point2, 4>& inner, int id, double cell_px,
                    const HiddenSide& hidden) {
    detector_.full_ = img.view();
    Homography H;
    if (!Homography::from_unit_square(inner, H)) return 0;
    return detector_.collect_pattern_edges(H, id, 0, cell_px, hidden);
  }

  // convex_hull() then max_area_quad() on contour points sorted by (y, x).
  bool quad_of(const std::vector<Point2>& points, std::array<Point2, 4>& quad, double& hull_area) {
    detector_.points_ = points;
    detector_.convex_hull();
    hull_area = std::abs(twice_signed_area(detector_.hull_.data(), detector_.hull_.size())) / 2;
    return detector_.max_area_quad(quad);
  }
};

// Where each row y crosses a convex polygon: the contour fit_quad() builds
// from a component's runs, sorted by (y, x).
std::vector<Point2> row_crossings(const std::vector<Point2>& polygon) {
  double y0 = polygon[0].y, y1 = polygon[0].y;
  for (const Point2& p : polygon) {
    y0 = std::min(y0, p.y);
    y1 = std::max(y1, p.y);
  }
  std::vector<Point2> out;
  for (double y = std::ceil(y0); y <= y1; y += 1) {
    double lo = 1e9, hi = -1e9;
    for (std::size_t i = 0; i < polygon.size(); ++i) {
      const Point2 a = polygon[i], b = polygon[(i + 1) % polygon.size()];
      if ((a.y - y) * (b.y - y) > 0 || a.y == b.y) continue;
      const double x = a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x);
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
    if (lo > hi) continue;
    out.push_back({lo, y});
    if (hi > lo) out.push_back({hi, y});
  }
  return out;
}

std::vector<Point2> regular_polygon(int corners, double radius, double turn_deg) {
  std::vector<Point2> out;
  for (int k = 0; k < corners; ++k) {
    const double a = (turn_deg + 360.0 * k / corners) * std::numbers::pi / 180;
    out.push_back({100 + radius * std::cos(a), 100 + radius * std::sin(a)});
  }
  return out;
}

// A light ridge four pixels wide on a dark ground (a socket's face between
// the line and its recess, blurred), beside a line one pixel and a line two
// pixels wide between light areas (a far marker's line between the hole and
// a white cell). The first rule leaves the ridge its crest alone; the
// valley rule keeps it whole; both keep the lines dark.
TEST_F(Frame8StageTest, SegmentationsValleyRuleKeepsARidgeWholeAndLinesDark) {
  constexpr std::array<std::uint8_t, 28> kProfile{60,  60,  60,  60,  120, 205, 220, 208, 60,  60,  60,  200, 200, 200,
                                                  150, 190, 190, 190, 60,  60,  200, 200, 160, 150, 190, 190, 60,  60};
  GreyImage img(static_cast<int>(kProfile.size()) * 2, 48);
  for (int y = 0; y < img.height(); ++y) {
    for (int x = 0; x < img.width(); ++x) img.at(x, y) = kProfile[static_cast<std::size_t>(x) % kProfile.size()];
  }
  const int y = 24;
  const auto crest = light_row(img, false, y);
  const auto valley = light_row(img, true, y);
  const auto count = [&](const std::vector<bool>& light, int from, int to) {
    int n = 0;
    for (int x = from; x < to; ++x) n += light[static_cast<std::size_t>(x)] ? 1 : 0;
    return n;
  };
  // The ridge: columns 4 to 7.
  EXPECT_EQ(count(crest, 4, 8), 2);
  EXPECT_EQ(count(valley, 4, 8), 4);
  // The lines: column 14, columns 22 and 23.
  for (const auto* light : {&crest, &valley}) {
    EXPECT_FALSE((*light)[14]);
    EXPECT_FALSE((*light)[22]);
    EXPECT_FALSE((*light)[23]);
    EXPECT_TRUE((*light)[13]);
    EXPECT_TRUE((*light)[15]);
  }
}

// The valley rule's floor, sixteen pixels at a time, is its definition
// pixel by pixel: on noise, at every column, the borders included.
TEST_F(Frame8StageTest, SegmentationsValleyFloorIsTheRulesDefinition) {
  GreyImage img(83, 9);
  std::uint32_t state = 12345;
  for (int y = 0; y < img.height(); ++y) {
    for (int x = 0; x < img.width(); ++x) {
      state = state * 1664525U + 1013904223U;
      img.at(x, y) = static_cast<std::uint8_t>(state >> 24);
    }
  }
  const int step = 2 * DetectorConfig{}.frame8.threshold_offset;
  for (const int y : {0, 1, 4, 7, 8}) {
    const std::vector<int> floor = valley_floor(img, y);
    auto at = [&](int dy, int x) {
      return static_cast<int>(img.at(std::clamp(x, 0, img.width() - 1), std::clamp(y + dy, 0, img.height() - 1)));
    };
    for (int x = 0; x < img.width(); ++x) {
      // Along the row, the column and the two diagonals: the darker of
      // the brightest within two on either side.
      int best = 0;
      for (const auto& [dx, dy] : {std::pair{1, 0}, std::pair{0, 1}, std::pair{1, 1}, std::pair{-1, 1}}) {
        const int before = std::max(at(-dy, x - dx), at(-2 * dy, x - 2 * dx));
        const int after = std::max(at(dy, x + dx), at(2 * dy, x + 2 * dx));
        best = std::max(best, std::min(before, after));
      }
      EXPECT_EQ(floor[static_cast<std::size_t>(x)], std::max(0, best - step)) << "x " << x << ", y " << y;
    }
  }
}

// A tile's threshold, eight tiles at a time, is its definition: the
// rounded mean of the pixels of its 3x3 tiles (fewer at the borders, and
// partial tiles where the image is not a multiple of four), less the
// offset, at least 0; on noise, for widths and heights on either side of
// the vector steps.
TEST_F(Frame8StageTest, SegmentationsTileThresholdIsTheNeighbourhoodsMeanLessTheOffset) {
  const int offset = DetectorConfig{}.frame8.threshold_offset;
  std::uint32_t state = 4321;
  for (const auto& [w, h] : {std::pair{640, 480}, std::pair{643, 481}, std::pair{37, 29}, std::pair{41, 17},
                             std::pair{16, 16}, std::pair{18, 21}}) {
    GreyImage img(w, h);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        state = state * 1664525U + 1013904223U;
        // Dark and light patches as well as noise: means from 0 to 255.
        const int patch = ((x / 24) + (y / 20)) % 3;
        img.at(x, y) = static_cast<std::uint8_t>(patch == 0   ? state >> 29
                                                 : patch == 1 ? 255 - (state >> 29)
                                                              : state >> 24);
      }
    }
    const std::vector<std::uint8_t> thresholds = tile_thresholds(img);
    const int tw = (w + 3) / 4, th = (h + 3) / 4;
    ASSERT_GE(thresholds.size(), static_cast<std::size_t>(tw * th));
    for (int ty = 0; ty < th; ++ty) {
      for (int tx = 0; tx < tw; ++tx) {
        int sum = 0, n = 0;
        for (int y = std::max(0, ty - 1) * 4; y < std::min(h, (ty + 2) * 4); ++y) {
          for (int x = std::max(0, tx - 1) * 4; x < std::min(w, (tx + 2) * 4); ++x) {
            sum += img.at(x, y);
            ++n;
          }
        }
        const int expected = std::clamp((sum + n / 2) / n - offset, 0, 255);
        EXPECT_EQ(thresholds[static_cast<std::size_t>(ty * tw + tx)], expected)
            << w << "x" << h << ", tile " << tx << "," << ty;
      }
    }
  }
}

TEST_F(Frame8StageTest, QuadFitFindsTheCornersOfATurnedSquare) {
  const std::vector<Point2> square = regular_polygon(4, 40, 20);
  std::array<Point2, 4> quad{};
  double hull_area = 0;
  ASSERT_TRUE(quad_of(row_crossings(square), quad, hull_area));
  // Each true corner has a quad corner within the row spacing.
  for (const Point2& corner : square) {
    double nearest = 1e9;
    for (const Point2& q : quad) nearest = std::min(nearest, distance(q, corner));
    EXPECT_LT(nearest, 1.0) << corner.x << "," << corner.y;
  }
  // The rows cut the square's corners off the hull a little: well within
  // the 6% that fit_quad() allows a quad.
  EXPECT_NEAR(std::abs(twice_signed_area(quad.data(), quad.size())) / 2, hull_area, 0.04 * hull_area);
}

TEST_F(Frame8StageTest, QuadFitLeavesAHexagonAThirdShort) {
  // A hexagon's largest inscribed quad covers two thirds of it: fit_quad()
  // turns away anything whose quad leaves more than a few percent uncovered.
  std::array<Point2, 4> quad{};
  double hull_area = 0;
  ASSERT_TRUE(quad_of(row_crossings(regular_polygon(6, 40, 5)), quad, hull_area));
  const double quad_area = std::abs(twice_signed_area(quad.data(), quad.size())) / 2;
  EXPECT_NEAR(quad_area / hull_area, 2.0 / 3.0, 0.03);
}

// A hole 14 px across with light bumps two pixels beyond two of its sides:
// a cover frame's opening seen from 2.2 m or more, its blurred rounded
// corner and a white cell joined through a line under a pixel wide (a
// paper print's hole turned 30 to 45 deg in the image bulges alike by its
// blurred corners). Its hull exceeds its largest quad by more than 6% and
// the pixels' staircase, less than a rounded hole may: a quad on any
// mount, marked as bulging.
TEST_F(Frame8StageTest, QuadFitTakesASmallBulgingHoleOnAnyMountAndMarksIt) {
  GreyImage img(64, 64, 50);
  auto light = [&](int x0, int y0, int x1, int y1) {
    for (int y = y0; y < y1; ++y) {
      for (int x = x0; x < x1; ++x) img.row(y)[x] = 210;
    }
  };
  light(24, 24, 38, 38);
  light(38, 31, 40, 35);  // a white cell through the line
  light(27, 38, 31, 40);  // and the blurred roll
  double excess = 0;
  // Marked so: a grid's two squares joined bulge alike, and such a quad
  // reading a near-uniform id or outvoting a cell is refused.
  for (const Mounting mounting : {Mounting::paper, Mounting::cover_frame, Mounting::any}) {
    bool bulging = false;
    EXPECT_EQ(fit_quad_at(img, mounting, 30, 30, excess, &bulging), Rejection::none);
    EXPECT_GT(excess, 0.06);  // 0.155
    EXPECT_TRUE(bulging);
  }
  // A square without the bumps is no such quad.
  bool bulging = false;
  GreyImage square(64, 64, 50);
  for (int y = 24; y < 38; ++y) {
    for (int x = 24; x < 38; ++x) square.row(y)[x] = 210;
  }
  EXPECT_EQ(fit_quad_at(square, Mounting::any, 30, 30, excess, &bulging), Rejection::none);
  EXPECT_FALSE(bulging);
}

// A read with a side hidden under 3 px a cell stands only where the
// pattern it predicts shows at least kMinPatternEdges of its edges
// (hidden_side.cpp). Cells of 2.9 px (a covered marker from 1.2 m turned
// 30 deg) are sampled twice each, as about one point per 1.5 px has it:
// a clean marker with its top side hidden, whose white cells beside the
// line (under 1.5 px there) give no edge, shows 26; sampled once each, 13.
TEST_F(Frame8StageTest, AHiddenSidesPatternCheckFindsEnoughEdgesOnSmallCells) {
  constexpr int kId = 239;  // 11101111: two white runs, few boundaries
  const GreyImage img = clean_marker(kId, 3, 60, 120);
  const std::array<Point2, 4> inner = clean_inner(3, 60);
  const HiddenSide top{0, 1.5};
  EXPECT_GE(pattern_edges(img, inner, kId, 2.9, top), kMinPatternEdges);
}

TEST_F(Frame8StageTest, EdgeRefinementPutsTheSidesOnTheHolesEdge) {
  const GreyImage img = clean_marker(165);
  const std::array<Point2, 4> truth = clean_inner();
  // The coarse quad of a thresholded hole: a pixel or so inside it, askew.
  const std::array<Point2, 4> coarse{{{truth[0].x + 1.2, truth[0].y + 0.8},
                                      {truth[1].x - 0.7, truth[1].y + 1.3},
                                      {truth[2].x - 1.1, truth[2].y - 0.6},
                                      {truth[3].x + 0.9, truth[3].y - 1.2}}};
  std::array<Point2, 4> inner{};
  ASSERT_EQ(refine(img, coarse, 10, inner), Rejection::none);
  for (std::size_t k = 0; k < 4; ++k) {
    EXPECT_LT(distance(inner[k], truth[k]), 0.05) << "corner " << k << " at " << inner[k].x << "," << inner[k].y;
  }
}

// A cover frame's inner roll turned towards the camera shows as a band
// lighter than the hole between the hole's component and the line: the
// quad's side lies short of the line by up to two cells, beyond the step's
// first reach, and is searched again further out.
TEST_F(Frame8StageTest, EdgeRefinementFindsTheLineBeyondALighterBand) {
  GreyImage img = clean_marker(165);
  const std::array<Point2, 4> truth = clean_inner();
  // The band: the hole's last 8 px before the right side's line.
  for (int y = 65; y <= 134; ++y) {
    for (int x = 127; x <= 134; ++x) img.row(y)[x] = 250;
  }
  std::array<Point2, 4> coarse = truth;
  coarse[1].x -= 8;
  coarse[2].x -= 8;
  EXPECT_EQ(fit_side_by_step(img, coarse, 1, 10), Rejection::few_edge_points);
  std::array<Point2, 4> inner{};
  ASSERT_EQ(refine(img, coarse, 10, inner), Rejection::none);
  for (std::size_t k = 0; k < 4; ++k) {
    EXPECT_LT(distance(inner[k], truth[k]), 0.3) << "corner " << k << " at " << inner[k].x << "," << inner[k].y;
  }
}

// A marker turned 55 degrees on a cover frame, as clean_marker() draws it
// narrower across (cells 4 px by 10): its hole, and the hole seen, off on
// both sides across the turn. On the far side the line is hidden by its
// roll and the hole seen reaches the ring (half a cell too far); on the
// near side the lit roll lies between it and the line (1.75 cells short).
struct TurnedHole {
  static constexpr int kCellX = 4, kCellY = 10, kOrigin = 50;
  double left = kOrigin - 0.5 + 1.5 * kCellX, right = kOrigin - 0.5 + 8.5 * kCellX;
  double top = kOrigin - 0.5 + 1.5 * kCellY, bottom = kOrigin - 0.5 + 8.5 * kCellY;
  [[nodiscard]] std::array<Point2, 4> truth() const {
    return {{{left, top}, {right, top}, {right, bottom}, {left, bottom}}};
  }
  [[nodiscard]] std::array<Point2, 4> seen() const {
    const double far = left - 0.5 * kCellX, near = right - 1.75 * kCellX;
    return {{{far, top}, {near, top}, {near, bottom}, {far, bottom}}};
  }
  static GreyImage image(int id) { return clean_marker(id, kCellX, kCellY, kOrigin, 200); }
  static constexpr CellSize kSize{kCellX, 7.0};
};

// The search of the two sides across the turn finds where the ring's cells
// are clearest, and reads.
TEST_F(Frame8StageTest, RingAlignmentReadsAHoleSeenOffOnBothSidesOfATurn) {
  const TurnedHole hole;
  for (const int id : {165, 77, 200, 51}) {
    Detection det;
    Homography H;
    ASSERT_TRUE(read_by_ring_alignment(TurnedHole::image(id), hole.seen(), TurnedHole::kSize, det, H)) << "id " << id;
    EXPECT_EQ(det.id, id);
    const std::array<Point2, 4> found = H.quad(), truth = hole.truth();
    for (std::size_t k = 0; k < 4; ++k) {
      EXPECT_LT(distance(found[k], truth[k]), 0.3 * TurnedHole::kCellX) << "id " << id << " corner " << k;
    }
  }
}

// A grid's squares, moved onto its lines, read as near-uniform ids: none
// is read so, the marker's own neither.
TEST_F(Frame8StageTest, RingAlignmentReadsNoNearUniformId) {
  const TurnedHole hole;
  Detection det;
  Homography H;
  EXPECT_FALSE(read_by_ring_alignment(TurnedHole::image(254), hole.seen(), TurnedHole::kSize, det, H));
}

// A dark oval in clean_marker()'s hole reaching the line on its left and
// right sides (a socket's recess, blurred into the line): the hole's light
// pixels above and below it are two pieces.
void part_hole(GreyImage& img) {
  for (int y = 65; y < 135; ++y) {
    for (int x = 65; x < 135; ++x) {
      const double u = (x - 99.5) / 35.5, v = (y - 99.5) / 25.0;
      if (u * u + v * v <= 1) img.row(y)[x] = 30;
    }
  }
}

// clean_marker(165) with its hole painted into pieces is read as one hole,
// upright and turned a quarter (its first corner then the next one).
void expect_read_as_one_hole(Frame8Detector& detector, const GreyImage& img) {
  const Quad outer{{{49.5, 49.5}, {149.5, 49.5}, {149.5, 149.5}, {49.5, 149.5}}};
  for (const GreyImage& view : {img, turned(img)}) {
    std::vector<Detection> found;
    detector.detect(view.view(), found);
    ASSERT_EQ(found.size(), 1U);
    EXPECT_EQ(found[0].id, 165);
    for (const Point2& corner : found[0].corners) {
      const double nearest = std::min({distance(corner, outer[0]), distance(corner, outer[1]),
                                       distance(corner, outer[2]), distance(corner, outer[3])});
      EXPECT_LT(nearest, 0.5);
    }
  }
}

// Where a socket's recess reaches the line on two opposite sides, the
// hole's light pixels are two pieces, neither the hole: the pieces are
// read as one, parted either way.
TEST_F(Frame8StageTest, AHolePartedInTwoIsReadAsOne) {
  GreyImage img = clean_marker(165);
  part_hole(img);
  expect_read_as_one_hole(detector_, img);
}

// Turned far, an outlet's recess lies in its face and the insert's side
// wall shows beside the face, parted from it by a shaded edge that meets
// the line: the face is one piece, and the wall with the strip below the
// face another, an L whose box holds the face's. The two are read as one.
TEST_F(Frame8StageTest, AHoleWrappedByThePieceBesideItIsReadAsOne) {
  GreyImage img = clean_marker(165);
  for (int y = 65; y < 135; ++y) {
    for (int x = 65; x < 135; ++x) {
      const double u = (x - 90.5) / 15.0, v = (y - 92.5) / 18.0;
      const bool edge = (x >= 118 && x < 122 && y < 124) || (y >= 120 && y < 124 && x < 122);
      if (edge || u * u + v * v <= 1) img.row(y)[x] = 30;
    }
  }
  expect_read_as_one_hole(detector_, img);
}

// Turned far, the face round the recess is parted by it into two pieces,
// and the insert's side wall beside them is a third, a strip parted from
// both by a shaded edge: the three are read as one.
TEST_F(Frame8StageTest, AHoleInThreePiecesIsReadAsOne) {
  GreyImage img = clean_marker(165);
  for (int y = 65; y < 135; ++y) {
    for (int x = 65; x < 135; ++x) {
      const double u = (x - 91.0) / 26.5, v = (y - 99.5) / 25.0;
      if ((x >= 117 && x < 119) || u * u + v * v <= 1) img.row(y)[x] = 30;
    }
  }
  expect_read_as_one_hole(detector_, img);
}

// Two squares of a grid side by side make the same pair, the grid's lines
// round them a ring of one colour but for a cell or two: no near-uniform
// id is read from two pieces.
TEST_F(Frame8StageTest, APartedHoleReadsNoNearUniformId) {
  GreyImage img = clean_marker(254);
  part_hole(img);
  std::vector<Detection> found;
  detector_.detect(img.view(), found);
  EXPECT_TRUE(found.empty());
  // Whole, the hole reads.
  detector_.detect(clean_marker(254).view(), found);
  ASSERT_EQ(found.size(), 1U);
  EXPECT_EQ(found[0].id, 254);
}

TEST_F(Frame8StageTest, DecodingReadsACleanPatternInEachOrientation) {
  for (const int id : {1, 77, 165, 254}) {
    GreyImage img = clean_marker(id);
    for (int quarter = 0; quarter < 4; ++quarter) {
      Detection det;
      int rotation = -1;
      ASSERT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::none) << "id " << id << " turn " << quarter;
      EXPECT_EQ(det.id, id);
      EXPECT_EQ(det.bits_corrected, 0);
      EXPECT_GT(det.margin, 0.9);
      // The image turned a quarter clockwise moves the marker's corner 0
      // to the quad's corner 1: the quad's corner j is the marker's j - rotation.
      EXPECT_EQ(rotation, quarter) << "id " << id;
      img = turned(img);
    }
  }
}

TEST_F(Frame8StageTest, DecodingCorrectsOneEdgeAndRejectsTwo) {
  const int id = 165;
  GreyImage img = clean_marker(id);
  flip_cell(img, id, 1, 3);
  Detection det;
  int rotation = 0;
  ASSERT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::none);
  EXPECT_EQ(det.id, id);
  EXPECT_EQ(det.bits_corrected, 1);
  flip_cell(img, id, 2, 3);  // a second edge against the same bit: two dissenters
  EXPECT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::bit_uncorrectable);
}

// A cover outvotes the cells of one edge, and at most the cell next to each
// of its corners on the edges beside it. Where cells are resolved, a cell
// outvoted anywhere else is a second fault, refused even where the code is
// the right one: clutter reads so, and so does a grid measured a cell off.
TEST_F(Frame8StageTest, DecodingLetsACoverOutvoteOneEdgeButNotASecond) {
  constexpr int id = 165;  // 10100101: a dark cover outvotes its four white cells
  static_assert(((id >> 3) & 1) == 0 && ((id >> 6) & 1) == 0 && (id & 1) == 1 && ((id >> 7) & 1) == 1);
  GreyImage covered = clean_marker(id);
  for (int bit = 0; bit < 8; ++bit) paint_cell(covered, 2, bit, 30);
  Detection det;
  int rotation = 0;
  ASSERT_EQ(decode(covered, clean_inner(), 10, det, rotation), Rejection::none);
  EXPECT_EQ(det.id, id);
  EXPECT_EQ(det.bits_corrected, 4);
  GreyImage mid = covered;
  flip_cell(mid, id, 1, 3);  // the middle of the edge beside: no cover of edge 2 reaches it
  EXPECT_EQ(decode(mid, clean_inner(), 10, det, rotation), Rejection::outvoted_scattered);
  flip_cell(mid, id, 1, 6);  // a second cell there
  EXPECT_NE(decode(mid, clean_inner(), 10, det, rotation), Rejection::none);
  // A cover over the corner edges 1 and 2 share: edge 2's first four
  // cells, and edge 1's last cell next to them.
  GreyImage corner = clean_marker(id);
  for (int bit = 4; bit < 8; ++bit) paint_cell(corner, 2, bit, 30);
  paint_cell(corner, 1, 0, 30);
  ASSERT_EQ(decode(corner, clean_inner(), 10, det, rotation), Rejection::none);
  EXPECT_EQ(det.id, id);
  EXPECT_EQ(det.bits_corrected, 3);
}

// Two single cells outvoted on opposite edges: each bit still has three
// votes to one, but no one cover explains both.
TEST_F(Frame8StageTest, DecodingRefusesResolvedCellsOutvotedOnOppositeEdges) {
  constexpr int id = 165;
  GreyImage img = clean_marker(id);
  flip_cell(img, id, 0, 4);
  Detection det;
  int rotation = 0;
  ASSERT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::none);
  EXPECT_EQ(det.id, id);
  flip_cell(img, id, 0, 2);  // a second cell on the same edge: one cover
  ASSERT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::none);
  EXPECT_EQ(det.bits_corrected, 2);
  flip_cell(img, id, 2, 5);  // and one on the opposite edge
  EXPECT_EQ(decode(img, clean_inner(), 10, det, rotation), Rejection::outvoted_scattered);
}

// The near-uniform ids are the rings of a grid's squares, and a square
// beside a row of another colour reads as one with an edge outvoted: under
// 3 px a cell, where the line and its corners are not checked, such a read
// is refused; the same edge outvoted for another id is read.
TEST_F(Frame8StageTest, DecodingRefusesANearUniformIdWithAnEdgeOutvotedUnderThreePixels) {
  constexpr int cell = 2;
  for (const int id : {126, 129, 165}) {
    SCOPED_TRACE(id);
    GreyImage img = clean_marker(id, cell);
    for (int bit = 1; bit < 7; ++bit) paint_cell(img, 1, bit, ((id >> bit) & 1) ? 30 : 220, cell);
    Detection det;
    int rotation = 0;
    const Rejection why = decode(img, clean_inner(cell), cell, det, rotation);
    if (frame8::near_uniform(id)) {
      EXPECT_EQ(why, Rejection::near_uniform_outvoted);
    } else {
      ASSERT_EQ(why, Rejection::none);
      EXPECT_EQ(det.id, id);
      EXPECT_GT(det.bits_corrected, 0);
    }
  }
}

// Glued on a cover frame turned far, the far side's line lies on the inner
// roll turned away from the camera, and the cells nearest it may not read
// clearly: one side without its line is read where no cell is outvoted and
// every bit has two clear votes. Not two sides without, nor one beside a
// cell outvoted or a bit with one clear vote.
TEST_F(Frame8StageTest, DecodingAllowsOneSideWithoutItsLineOnlyForAnAgreedCode) {
  constexpr int id = 165;
  const GreyImage clean = clean_marker(id);
  // Paints the middle of one side's line (clear of its corners) as paper.
  auto whiten_line = [](GreyImage& img, bool horizontal, int across_from) {
    for (int a = 50 + 15; a < 50 + 85; ++a) {
      for (int b = across_from; b < across_from + 5; ++b) (horizontal ? img.row(b)[a] : img.row(a)[b]) = 220;
    }
  };
  // A cell painted grey 112, a little darker than midway between ink 30
  // and paper 220 (bit 4 is black), reads unclear but leaning the right way.
  constexpr std::uint8_t kUnclear = 112;
  static_assert(((id >> 4) & 1) == 0);
  const auto read = [this](const GreyImage& img) {
    Detection det;
    int rotation = 0;
    const Rejection why = decode(img, clean_inner(), 10, det, rotation);
    EXPECT_TRUE(why != Rejection::none || det.id == id);
    return why;
  };
  GreyImage top_unlined = clean;
  whiten_line(top_unlined, true, 50 + 10);  // the top side's line, 1.0 to 1.5 cells in
  EXPECT_EQ(read(top_unlined), Rejection::none);
  // Two cells of bit 4 unclear: two clear votes left.
  GreyImage img = top_unlined;
  paint_cell(img, 0, 4, kUnclear);
  paint_cell(img, 1, 4, kUnclear);
  EXPECT_EQ(read(img), Rejection::none);
  // Three unclear: one clear vote left. With the line all round, the code
  // still reads.
  img = clean;
  for (const int edge : {0, 1, 2}) paint_cell(img, edge, 4, kUnclear);
  ASSERT_EQ(read(img), Rejection::none);
  whiten_line(img, true, 50 + 10);
  EXPECT_EQ(read(img), Rejection::line_missing);
  // A cell outvoted.
  img = top_unlined;
  flip_cell(img, id, 2, 3);
  EXPECT_EQ(read(img), Rejection::line_missing);
  // The right side's line missing too.
  img = top_unlined;
  whiten_line(img, false, 50 + 85);
  EXPECT_EQ(read(img), Rejection::line_missing);
}

TEST_F(Frame8StageTest, DecodingRejectsAFlatRingAtTheGreyModel) {
  const GreyImage flat(200, 200, 128);
  Detection det;
  int rotation = 0;
  const Rejection why = decode(flat, clean_inner(), 10, det, rotation);
  EXPECT_EQ(stage_of(why), Stage::grey_model) << rejection_name(why);
}

TEST(Frame8Rejection, EveryRejectionHasAStageAndADistinctName) {
  std::set<std::string> names;
  for (int r = 0; r <= static_cast<int>(Rejection::no_pose); ++r) {
    const auto why = static_cast<Rejection>(r);
    EXPECT_TRUE(names.insert(rejection_name(why)).second) << rejection_name(why);
    EXPECT_NE(std::string(stage_name(stage_of(why))), "?") << rejection_name(why);
  }
  EXPECT_EQ(stage_of(Rejection::no_contrast), Stage::grey_model);
  EXPECT_EQ(stage_of(Rejection::c1_contradicted), Stage::orientation);
  // Another measurement is worth it past the grey model, or for a quad
  // whose sides alone were off; not for cells too small or no contrast.
  EXPECT_TRUE(worth_remeasuring(Rejection::sides_unequal));
  EXPECT_TRUE(worth_remeasuring(Rejection::bit_uncorrectable));
  EXPECT_FALSE(worth_remeasuring(Rejection::cells_too_small));
  EXPECT_FALSE(worth_remeasuring(Rejection::no_contrast));
}

// The rings a grid of light squares shows around one square: every edge one
// colour but for a cell at either end.
TEST(Frame8Rejection, NearUniformIdsAreTheRingsOfAGridsSquares) {
  std::set<int> ids;
  for (int id = 0; id < 256; ++id) {
    if (near_uniform(id)) ids.insert(id);
  }
  EXPECT_EQ(ids, (std::set<int>{0, 1, 126, 127, 128, 129, 254, 255}));
}

}  // namespace markerd::detector::frame8
