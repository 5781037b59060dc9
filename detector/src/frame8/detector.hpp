#pragma once
// The frame8 detector: the stages of docs/architecture.md ("The frame8
// pipeline"), one file each in this directory, run by detector.cpp.
//
// Memory: every buffer is a member that grows to the largest frame seen and is
// reused, so detect() allocates nothing in steady state.

#include <algorithm>
#include <array>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "frame8/common.hpp"
#include "frame8/rejection.hpp"
#include "frame8/ring_read.hpp"
#include "markerd/detector/detector.hpp"
#include "ring_model.hpp"

namespace markerd::detector::frame8 {

class Frame8Detector final : public MarkerDetector {
 public:
  // Stage 2c (ink_outline.cpp): a side of the ink's convex hull, and its
  // length; and a square tried, its corners, each side's stretch of the
  // hull and its line (side t runs from corner t to t + 1).
  struct HullSide {
    Point2 a, b;
    double length = 0;
  };
  struct InkSquare {
    double total = 0;
    std::array<Point2, 4> corners{};
    std::array<HullSide, 4> sides{};
    std::array<Line, 4> lines{};
    // Most of its sides measured as light cells against a dark ground: a
    // bare print on a dark wall, the ink merged with the ground.
    bool dark_ground = false;
  };

  explicit Frame8Detector(const DetectorConfig& config);

  [[nodiscard]] Family family() const override { return Family::frame8; }

  void detect(const GreyView& image, std::vector<Detection>& out) override;

 private:
  // The stage tests (tests/test_frame8_stages.cpp) run single stages.
  friend class Frame8StageTest;

  // Stage 1: segmentation (segmentation.cpp).
  void make_working_image();
  void sum_tiles(int tw, int th);
  // The two local rules a pixel is held to besides its neighbourhood's
  // mean (segmentation.cpp): the first look at a frame takes the first,
  // the second look the other.
  enum class LocalRule : std::uint8_t { brightest_neighbour, valley };
  void threshold_tiles();
  void light_pixels_and_runs(LocalRule rule);
  void brightest_neighbour_row(int y);
  void valley_row(int y);
  // How far below the rule's reference level a pixel may lie and be light:
  // twice the threshold's offset.
  [[nodiscard]] std::uint8_t local_step() const {
    return static_cast<std::uint8_t>(std::min(255, 2 * config_.frame8.threshold_offset));
  }
  // Segmentation under `rule`, then stages 2 to 6 (detector.cpp).
  void look(LocalRule rule, std::vector<Detection>& out);
  // The last look, where the others found nothing: the candidates the
  // ring model might read (model_candidates_), read with it.
  void model_look(std::vector<Detection>& out);
  // How far a quad's corners from the valley rule's pixels are moved in
  // (working pixels) before its sides are searched: about the half width
  // of the edges' blur, which the first rule takes off a hole's outline.
  static constexpr double kValleyInset = 1.0;
  void light_row_bits(const std::uint8_t* row, int w, std::uint64_t* bits);
  void extract_runs(int y, int w, int words);
  std::int32_t find(std::int32_t r);
  void unite(std::int32_t a, std::int32_t b);
  void label_components();

  // Stage 2: quad fitting (quad_fit.cpp).
  Rejection fit_quad(Component& c, std::array<Point2, 4>& quad);
  void outline_rows(std::span<const Component* const> components, int y0, int rows);
  bool largest_quad_of_rows(int y0, int rows, std::array<Point2, 4>& quad, double& quad_area, double& hull_area);
  void convex_hull();
  bool max_area_quad(std::array<Point2, 4>& quad);
  static double quad_perimeter(const std::array<Point2, 4>& quad);
  // Pixel staircases make a small hull bigger than the quad by up to about
  // a third of a pixel along the perimeter.
  static double hull_staircase(double perimeter) { return 0.35 * perimeter; }
  // Glued on a cover frame, the hole's corners are rounded: its hull may
  // exceed its largest quad by this share of the hull's area (quad_fit.cpp).
  static constexpr double kRoundedShortfall = 0.16;
  // The least share of its quad a hole's light pixels cover: a Schuko
  // outlet's recess (39 mm across) in the 56 mm opening of a socket frame
  // takes 0.38 of it, its pin holes a little more, and from about a metre,
  // where the recess is 15 px across, the threshold takes its blurred rim
  // too (at 0.5 the socket was lost from 1.0 m on).
  static constexpr double kMinLightShare = 0.3;

  // Stage 3: edge refinement (edge_refinement.cpp).
  // How collect_edge_points() places each point: at the centroid of the
  // light-to-dark step; or, without a code, each point classified by its own
  // profile (the line alone or merged with a black cell); or the profiles
  // fitted with a model of the blurred line and the cells beyond it
  // (fit_edge_profile), summed over kProfileSegments segments per side;
  // or the step, searched twice as far out (where the first finds none).
  // With the code read (`id`), the step points also know the cell beyond.
  enum class EdgeMode : std::uint8_t { step, classify_by_profile, fit_profile, step_wide };
  int collect_edge_points(const std::array<Point2, 4>& q, int side, EdgeMode mode, std::optional<int> id);
  bool fit_edge_profile(const float* profile, int n, double s0, double step, double cell_px, double& e) const;
  Rejection fit_side(const std::array<Point2, 4>& from, int side, EdgeMode mode, std::optional<int> id, double cell_px,
                     Line& line);
  Rejection refine_sides(const std::array<Point2, 4>& from, EdgeMode mode, std::optional<int> id, double cell_px,
                         std::array<Point2, 4>& inner);
  // A refined corner more than two cells from the coarse one has been
  // fitted to something else.
  [[nodiscard]] bool corner_moved(Point2 refined, Point2 coarse, double cell_px) const {
    return distance(refined, coarse) > 2.0 * cell_px + 2 * decimate_;
  }
  // A working-image point in full-resolution pixels.
  [[nodiscard]] Point2 to_full(Point2 p) const {
    const double d = decimate_;
    return {p.x * d + (d - 1) / 2, p.y * d + (d - 1) / 2};
  }
  Rejection refit_undistorted(int rotation, Detection& det);

  // Whether a ring shows light and dark cells where a map (grid coordinates
  // to full-resolution pixels) puts them (decode_cells.cpp): a look that
  // costs less than measuring a quad's sides or reading it, and that most
  // of clutter's shapes fail.
  [[nodiscard]] bool ring_shows_cells(const Eigen::Matrix3d& grid_to_image) const;
  // Stage 4: decoding (decode.cpp), through 4a to 4e.
  Rejection decode(const Homography& H, CellSize cell_size, Detection& det, int& rotation,
                   const frame8::RingModel::Levels* model, const HiddenSide& hidden = {}) const;
  // Stages 4a to 4d: the code and its orientation in `r`, before the structural checks.
  Rejection read_code(const Homography& H, CellSize cell_size, const frame8::RingModel::Levels* model,
                      RingRead& r) const;
  bool read_by_model(Homography& H, CellSize cell_size, bool sampled_worth_it, Detection& det, int& rotation);
  Rejection confirm_by_model(const Homography& H, CellSize cell_size, const Detection& det, int rotation);
  Rejection confirm_at_model_map(const Eigen::Matrix3d& aligned, CellSize cell_size, const Detection& det,
                                 int rotation);
  Rejection confirm_at_told_blur(const Eigen::Matrix3d& aligned, CellSize cell_size, const Detection& det,
                                 int rotation);
  Rejection judge_model_read(const Eigen::Matrix3d& M, CellSize cell_size, const Detection& det, int rotation);
  // 4a: the cells (decode_cells.cpp).
  Rejection read_cells(const Homography& H, CellSize cell_size, const frame8::RingModel::Levels* model,
                       RingRead& r) const;
  CellSample sample_cell(const Homography& H, frame8::Cell cell, double cell_px) const;
  void unmix_ring(const Homography& H, std::array<CellSample, 4>& corner,
                  std::array<std::array<CellSample, 8>, 4>& cell) const;
  // 4b: the grey model (decode_grey_model.cpp).
  Rejection fit_grey_model(CellSize cell_size, RingRead& r) const;
  // 4c: orientation (decode_orientation.cpp, short_edges.cpp).
  Rejection read_corners(RingRead& r) const;
  Rejection settle_orientation(const Homography& H, RingRead& r) const;
  // 4d: the bit votes (decode_votes.cpp).
  static double edge_weight(const Homography& H, int edge);
  static void weigh_edges(const Homography& H, RingRead& r);
  // The cell size that decides whether a read must be confirmed (by the
  // second measurement, by the ring model): the mean, unless no edge's
  // cells are that far apart along it. Turned far about one of its axes,
  // a marker keeps two edges whose cells are parted by many pixels, which
  // read its code cleanly. Rolled in the image and then turned, it is
  // squeezed across a diagonal: every cell is parted from its neighbours
  // along every edge by little more than a pixel, though the edges stay
  // long, and each cell mixes with the next (at 0.95 m turned 75 deg,
  // rolled 45 deg, JPEG 75: 252 read as 124, cells of 2.8 px on average
  // and 1.4 px apart).
  static double confirming_cell_size(const Homography& H, CellSize size);
  static Rejection vote_bits(RingRead& r);
  // 4e: structural checks (decode_checks.cpp).
  bool hole_lighter_than_line(const Homography& H, const RingRead& r) const;
  bool hole_as_dark_as_ink(const Homography& H, CellSize cell_size) const;
  Rejection check_structure(const Homography& H, CellSize cell_size, const frame8::RingModel::Levels* model,
                            RingRead& r) const;
  bool fit_short_edge(const Homography& H, int side, int id, double black, double white, ShortEdgeFit& fit) const;
  int white_corner_by_short_edges(const Homography& H, int side, int id, double black, double white,
                                  double& clarity) const;

  // Stage 5: the whole pattern (pattern_fit.cpp).
  bool locate_edge(const Homography& H, Point2 g0, Point2 normal, double half, bool dip, double& offset,
                   double& strength) const;
  // Where the hole is not known to be lighter than the line (stage 2c),
  // its edge is left out, and the line's outer edge beside white cells
  // measured instead.
  enum class HoleEdge : std::uint8_t { measured, unknown };
  // The ring's colours in a quad's grid, a cell each, row by row: white,
  // black, or 0 (the line and hole, or a ring cell of unknown colour).
  using CellColours = std::array<std::int8_t, frame8::grid * frame8::grid>;
  static constexpr std::int8_t kWhiteCell = 1, kBlackCell = -1;
  static CellColours colours_of_code(int id, int rotation);
  int collect_pattern_edges(const Homography& H, int id, int rotation, double cell_px, const HiddenSide& hidden = {},
                            HoleEdge hole_edge = HoleEdge::measured);
  int collect_pattern_edges(const Homography& H, const CellColours& colours, double cell_px,
                            const HiddenSide& hidden = {}, HoleEdge hole_edge = HoleEdge::measured);
  bool fit_grid_map(Eigen::Matrix3d& grid_to_image, MapNoise* noise = nullptr);
  Rejection finish_by_pattern(int rotation, Detection& det);
  // Small cells: the ring model's map aligned to every pixel the marker
  // reaches (RingModel::Aim::geometry), started from `map` (grid to image
  // pixels), with its noise; false when the model does not fit. Then the
  // corners (and the pose) from it: false, with `det` as it was, when they
  // are no marker's.
  bool fit_model_geometry(Eigen::Matrix3d& map, MapNoise& noise);
  bool finish_by_model(const Eigen::Matrix3d& map, const MapNoise& noise, int rotation, Detection& det);

  // Stage 6: corners and pose (corners_and_pose.cpp). The map goes from the
  // grid to where the detector works (undistorted: normalized coordinates
  // with a camera, pixels without), or to the image's pixels as they are.
  // With the map's noise, the pose's tilt is taken net of it
  // (shrink_tilt_by_noise, pose.hpp).
  enum class MapSpace : std::uint8_t { undistorted, pixels };
  Rejection report(const Eigen::Matrix3d& grid_to_image, int rotation, Detection& det, const MapNoise* noise = nullptr,
                   MapSpace space = MapSpace::undistorted) const;

  // The detector that runs them (detector.cpp).
  void consider_component(std::int32_t root, std::vector<Detection>& out);
  Rejection refine_and_decode(const std::array<Point2, 4>& coarse, Detection& det);
  Rejection measure_and_read(const std::array<Point2, 4>& coarse, Detection& det);
  // Set when a side of the quad being read was found only past the step's
  // first reach (EdgeMode::step_wide).
  bool reached_wide_ = false;
  // Stage 3b, a side hidden (hidden_side.cpp) or the hole inset all round
  // (inset_hole.cpp): the last reads of a quad.
  [[nodiscard]] bool looks_covered(const Homography& H, int side, bool into_hole) const;
  [[nodiscard]] bool any_side_looks_covered(const Homography& H) const {
    for (int side = 0; side < 4; ++side) {
      if (looks_covered(H, side, true)) return true;
    }
    return false;
  }
  [[nodiscard]] double square_misfit(const std::array<Point2, 4>& hole) const;
  // Whether the hole seen (its unit square; through H, the whole hole,
  // whose line gives the contrast and ring the paper's grey; hidden_side -1
  // or the side hidden) is blank paper (blank_hole.cpp).
  [[nodiscard]] bool hole_is_blank_paper(const Homography& seen, const Homography& H, int hidden_side) const;
  bool read_with_side_hidden(const std::array<Point2, 4>& inner, Detection& det, int& rotation, HiddenSide& hidden,
                             Homography& H);
  // Where the quad seen ends across its hidden side: at the cover's edge,
  // which hides the line (a hole that reaches further must show the cover
  // over the line); or open, the hole running on into a cover as light as
  // it (open_hole.cpp).
  enum class HoleEnd : std::uint8_t { at_cover, open };
  bool read_hidden_side(const std::array<Point2, 4>& inner, int side, HoleEnd end, Detection& det, int& rotation,
                        HiddenSide& hidden, Homography& H);
  // Stage 2b, a hole open on one side (open_hole.cpp), after every quad.
  // Outlines are traced on the working image's light bits halved each way
  // (kTraceScale), where a hole must span kMinTracedSide pixels to be cut
  // into straight pieces; a read with a side hidden needs cells of
  // kResolvedCells besides (it checks them at full resolution). The least
  // side of an open hole worth reading, in working pixels: 21 at 640x480,
  // 20 (40 full-resolution pixels, cells of 5.7) on frames decimated by 2,
  // of over 1.3 megapixels. The traced outline comes out up to a pixel
  // short at either end, and its straight pieces stop a traced pixel short
  // of the hole's blurred corners.
  static constexpr int kTraceScale = 2;
  static constexpr int kMinTracedSide = 10;
  [[nodiscard]] double min_open_hole_side() const {
    return std::max(kResolvedCells * kInnerSide / decimate_, double{kTraceScale * kMinTracedSide}) - 4;
  }
  void make_traced_bits();
  // Pixels an outline is traced on: light bits, a row of `stride` words
  // each, `scale` working pixels to a bit each way, and a bit per pixel
  // marking the left ends of runs an outline has passed.
  struct TraceBits {
    const std::uint64_t* bits;
    std::uint64_t* passed;
    std::size_t stride;
    int w, h, scale;
    [[nodiscard]] bool light(int x, int y) const {
      if (static_cast<unsigned>(x) >= static_cast<unsigned>(w) ||
          static_cast<unsigned>(y) >= static_cast<unsigned>(h)) {
        return false;
      }
      return (bits[stride * static_cast<std::size_t>(y) + static_cast<std::size_t>(x >> 6)] >> (x & 63)) & 1U;
    }
    [[nodiscard]] bool was_passed(int x, int y) const {
      return (passed[stride * static_cast<std::size_t>(y) + static_cast<std::size_t>(x >> 6)] >> (x & 63)) & 1U;
    }
  };
  void trace_outline(const TraceBits& t, int start_x, int start_y);
  // The component of the working image's light pixel (x, y).
  [[nodiscard]] const Component* component_at(int x, int y) const;
  // Stage 2c on the working image's own bits: the islands of components
  // small enough that halving the bits could cut the light band round a
  // marker's ink (the print's margin, a cover frame's plastic).
  void find_ink_islands_unhalved(double min_side, std::vector<Detection>& out);
  void simplify_outline();
  [[nodiscard]] bool ring_shows_both_colours(Point2 a, Point2 b) const;
  // Stage 2d, a hole parted by its insert (hole_fragments.cpp), after every
  // quad: two pieces of a hole read as one quad.
  void read_hole_fragments(std::vector<Detection>& out);
  bool read_pieces(std::initializer_list<Component*> pieces, std::vector<Detection>& out);
  bool fit_pieces_quad(std::initializer_list<Component*> pieces, std::array<Point2, 4>& quad);
  void find_open_holes(std::vector<Detection>& out);
  void find_open_holes_on_outline(double min_side, std::vector<Detection>& out);
  Rejection read_open_hole(const std::array<Point2, 4>& coarse, Detection& det);
  // Stage 2c, a hole no lighter than the line (ink_outline.cpp): the dark
  // island of a marker's ink (ring's black cells and line) within a light
  // surround, its outer square taken from the island's convex hull. An
  // island is worth tracing when its dark pixels take this share of the
  // least side squared (the ink alone, around a light hole, takes 0.36 of
  // the outer square).
  static constexpr double kMinInkShare = 0.25;
  void find_marker_on_ink_outline(int scale, std::vector<Detection>& out);
  static constexpr std::size_t kTried = 3;
  std::size_t pick_squares(const HullSide* sides, const Line* lines, const int* sense, int count, double hull_area,
                           std::array<InkSquare, kTried>& tries);
  int fit_outer_side(Point2 a, Point2 b, double cell_px, std::initializer_list<int> signs, Line& line);
  Rejection read_ink_outline(const InkSquare& square, Detection& det);
  Rejection read_outer_square(const std::array<Point2, 4>& traced, const std::array<Line, 4>& lines, bool dark_ground,
                              Detection& det);
  bool read_inset(const std::array<Point2, 4>& inner, CellSize cell_size, Detection& det, int& rotation, Homography& H);
  bool read_on_ring_edges(const Homography& seen, CellSize cell_size, Detection& det, int& rotation, Homography& H);
  bool read_from_ring_edges(const Homography& start, CellSize cell_size, Detection& det, int& rotation, Homography& H);
  // The two sides across a far turn searched for the clearest ring
  // (ring_alignment.cpp).
  bool read_by_ring_alignment(const std::array<Point2, 4>& inner, CellSize cell_size, Detection& det, int& rotation,
                              Homography& H);
  [[nodiscard]] double ring_separation(const Homography& H, bool across_u) const;
  [[nodiscard]] bool line_seen(const Homography& H, int side) const;
  // Stage 2, a hole parted by a cover frame's fold (roll_fold.cpp); `quad`
  // in working-image pixels.
  bool read_hole_past_fold(const Component& hole, const std::array<Point2, 4>& quad, Detection& det);
  Rejection finish_from_hole(const Homography& H, const HiddenSide& hidden, int rotation, double cell_px,
                             Detection& det);
  bool read_by_profile_fit(const std::array<Point2, 4>& from, double cell_px, CellSize cell_size, Detection& det,
                           int& rotation, Homography& H, std::array<Point2, 4>& inner);
  [[nodiscard]] bool inside_detection(const Component& c, const std::vector<Detection>& found) const;
  static bool inside(const Quad& q, Point2 p);
  // Whether `p` lies inside any detection's quad: a candidate there is part of it.
  static bool inside_any(const std::vector<Detection>& found, Point2 p);
  static bool convex(const Quad& q);
  static void remove_nested(std::vector<Detection>& out);

  // The debug output (debug.cpp), only with Frame8Options::debug_dir: per
  // candidate its quad, what became of it and each read tried.
  enum class Read : std::uint8_t {
    sampled,
    step_only,
    profile_fit,
    ring_model,
    aligned_ring_model,
    second_pass,
    side_hidden,
    inset,
    ring_edges,
    ring_alignment,
    model_check
  };
  static const char* read_name(Read how);
  struct DebugCandidate {
    std::array<Point2, 4> quad{};  // full-resolution pixels
    Rejection why = Rejection::none;
    int id = -1;            // read: the id,
    Point2 first_corner{};  // and its detection's first corner
    std::vector<std::pair<Read, Rejection>> attempts;
  };
  void note_attempt(Read how, Rejection why) {
    if (debug_ && !debug_candidates_.empty()) debug_candidates_.back().attempts.emplace_back(how, why);
  }
  // What became of the last candidate: `det` where it read.
  void note_outcome(Rejection why, const Detection& det) {
    if (!debug_ || debug_candidates_.empty()) return;
    DebugCandidate& candidate = debug_candidates_.back();
    candidate.why = why;
    if (why == Rejection::none) {
      candidate.id = det.id;
      candidate.first_corner = det.corners[0];
    }
  }
  void write_debug(const std::vector<Detection>& out);
  void write_debug_threshold() const;

  // Edge points per side: about one per 1.5 px along a side of up to 72 px;
  // longer sides need no more to place a line.
  static constexpr int kMaxEdgePoints = 48;
  // The profiles across an outer side of the ink (fit_outer_side), kept
  // for each sense of its step tried on them.
  static constexpr int kMaxProfileSteps = 64;
  std::array<std::array<float, kMaxProfileSteps>, kMaxEdgePoints> outer_profiles_{};
  // The profile fit's sums per side (EdgeMode::fit_profile): a few fits
  // instead of one per point, each on less noise.
  static constexpr std::size_t kProfileSegments = 4;
  // The whole pattern's edges: at most 4 points per cell edge, and under 16
  // the 8 parameters of the map are not worth fitting.
  static constexpr int kMinPatternEdges = 16;
  static constexpr int kMaxPatternEdges = 384;

  DetectorConfig config_;
  // What the mounting told (Frame8Options::mounting) can show. A hole
  // reshaped: displaced by a frame's roll, parted by what shows through a
  // cut-out hole, inset by a switch's rocker (the fold, stage 2d, the
  // inset, the ring's edges and the ring's alignment search for those). An
  // ink outline: a cut-out hole no lighter than the line (stage 2c).
  bool seeks_reshaped_hole_ = true;
  bool seeks_ink_outline_ = true;
  // Told paper, the hole is blank paper (blank_hole.cpp).
  bool hole_printed_blank_ = false;
  LocalRule rule_ = LocalRule::brightest_neighbour;  // the look under way
  // The blur an edge profile sees: the lens, the pixel's area and the
  // bilinear sampling of the profile (a quarter pixel squared on average).
  double profile_sigma_ = 0.7;
  GreyView full_{};
  GreyView work_{};
  int decimate_ = 1;
  std::vector<std::uint8_t> decimated_;
  std::vector<std::uint32_t> tile_sum_;
  std::vector<std::uint32_t> tile_row_sum_;  // padded with a row of zeros above and below
  std::vector<std::uint32_t> tile_span_x_;   // per tile column, the pixels its 3x3 neighbourhood spans
  std::vector<std::uint8_t> tile_threshold_;
  std::vector<std::uint8_t> pixel_threshold_;
  std::vector<std::uint8_t> column_max_, local_floor_;
  std::vector<std::uint64_t> light_bits_;  // a bit per pixel of the working image, light_stride_ words a row
  std::size_t light_stride_ = 0;
  std::array<std::array<float, 64>, kProfileSegments> segment_profile_{};
  std::array<Point2, kProfileSegments> segment_base_{};
  std::array<int, kProfileSegments> segment_count_{};
  std::vector<Run> runs_;
  std::vector<std::int32_t> row_first_;
  std::vector<Component> components_;
  std::vector<std::int32_t> roots_;
  // Stage 2d: the components that may be a parted hole's, and each one's
  // best match among them (how far their ends fail to line up, its index).
  std::vector<std::int32_t> sized_pieces_, pieces_;
  std::vector<std::pair<double, std::size_t>> best_piece_;
  std::vector<std::int32_t> line_min_, line_max_;
  std::vector<Point2> points_, hull_, hull_twice_;
  // Stage 2b: the pixels outlines are traced on (kTraceScale working
  // pixels each way), the runs' left ends an outline passed, and the
  // outline being cut.
  int trace_w_ = 0, trace_h_ = 0;
  std::size_t trace_stride_ = 0;
  std::vector<std::uint64_t> traced_bits_, traced_;
  std::vector<std::uint64_t> passed_unhalved_;  // TraceBits::passed on light_bits_
  std::vector<Point2> outline_;                 // where the outline turns
  int outline_extent_ = 0;                      // its box's longer side, working pixels
  std::vector<std::int32_t> outline_corners_;   // its straight pieces' ends
  std::array<std::array<EdgePoint, kMaxEdgePoints>, 4> edge_points_{};
  std::array<int, 4> edge_count_{};
  std::array<PatternEdge, kMaxPatternEdges> pattern_edges_{};
  int pattern_count_ = 0;
  frame8::RingModel ring_model_;
  frame8::RingModel::Levels levels_;
  // Set while read_inset() decodes a hole grown beyond its component: the
  // structural checks then allow no light corner of the line.
  bool reading_grown_hole_ = false;
  // The ring model's read of small cells costs a few million instructions,
  // and clutter offers several candidates a frame that reach it; the true
  // marker, where the model is all that reads it, leaves every other look
  // empty. So the looks only note such a candidate (its coarse quad, and
  // the rule it was found under), and the model reads them in a look of
  // its own once the others found nothing: the candidates that measured as
  // a quad and read well enough to be worth it (worth_remeasuring), largest
  // first, at most kMaxModelCandidates a frame.
  struct ModelCandidate {
    std::array<Point2, 4> coarse{};
    LocalRule rule = LocalRule::brightest_neighbour;
  };
  static constexpr std::size_t kMaxModelCandidates = 16;
  std::vector<ModelCandidate> model_candidates_;
  bool model_look_ = false;    // the model's look is under way: it reads
  bool model_wanted_ = false;  // the quad being read would have been read by the model
  bool debug_ = false;
  int debug_frame_ = 0;
  std::vector<DebugCandidate> debug_candidates_;
  // The second look's first candidate (none: no second look), and the
  // model's look's.
  std::size_t debug_second_look_from_ = std::numeric_limits<std::size_t>::max();
  std::size_t debug_model_look_from_ = std::numeric_limits<std::size_t>::max();
};

}  // namespace markerd::detector::frame8
