#pragma once
// Reading a frame8 ring whose cells are too small to sample.
//
// Under about three pixels a cell, the blur of the lens and the pixel's own
// area mix every cell with its neighbours: the grey at a cell's centre is as
// much its neighbours' colour as its own, and thresholding it fails first on
// the lone cell between two of the other colour. But the mixing is known:
// each pixel is the printed pattern integrated over the pixel's square and
// the blur's Gaussian (together close to one Gaussian), so it is a linear
// combination of the unknown grey levels of the regions it overlaps (the 36 ring cells, the line on each
// side, the hole, and whatever lies beyond each side). The model solves for
// those levels by least squares over every pixel of the marker: a
// deconvolution with a handful of unknowns, well posed down to cells about
// a pixel and a half wide.

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "frame8/common.hpp"
#include "markerd/detector/image.hpp"

namespace markerd::detector::frame8 {

class RingModel {
 public:
  static constexpr int kRingRegions = 36;
  // Regions: the ring cells (in grid order, see ring_region()), the line
  // beside each side (top, right, bottom, left), the hole, and the outside
  // beyond each side.
  static constexpr int kLine = kRingRegions;
  static constexpr int kHole = kLine + 4;
  static constexpr int kOutside = kHole + 1;
  static constexpr int kRegions = kOutside + 4;

  struct Levels {
    std::array<float, 100> cell{};  // grey level of each ring cell, row * 10 + col; others unused
    std::array<float, 4> line{};    // the line along each side
    float hole = 0;
    double rms_residual = 0;  // grey levels, over the pixels used
  };

  // Fits the levels to the pixels covered by the marker whose grid
  // coordinates (0..10 across, y down) map to image pixels through
  // grid_to_image, with a Gaussian blur of blur_sigma_px on top of each
  // pixel's square; with `align`, also moves grid_to_image (a homography)
  // to where the model fits the pixels best, alternating the levels (linear)
  // with Gauss-Newton steps of the map. False when the marker leaves the
  // image or is too large for this model to be the right tool (its cells are
  // then sampled).
  //
  // What the fit is for decides which pixels it takes and how far it goes.
  // To read the levels (`levels`, `aligned_levels`), the pixels mostly on
  // the marker: one mostly outside says more about the background than the
  // ring; the map to a twentieth of a pixel. For the geometry (`geometry`),
  // every pixel the marker's edge reaches (ring_model.cpp says why), and
  // the map to a hundredth. `noise`, with `geometry`: the map's
  // scatter, from the pixels' residuals.
  enum class Aim : std::uint8_t { levels, aligned_levels, geometry };
  bool fit(const GreyView& image, Eigen::Matrix3d& grid_to_image, double blur_sigma_px, Aim aim, Levels& out,
           MapNoise* noise = nullptr);
  // The fit that last returned true, with Aim::levels, carried on as with
  // Aim::aligned_levels: the same result, without preparing the same map
  // again (a fifth of the cost). `image` and `grid_to_image` must be that
  // fit's.
  bool align_levels(const GreyView& image, Eigen::Matrix3d& grid_to_image, Levels& out);

  // Index of a ring cell's region, -1 for a cell that is not on the ring.
  static constexpr int ring_region(int col, int row) {
    if (col < 0 || row < 0 || col >= 10 || row >= 10) return -1;
    if (row == 0) return col;                 // 0..9
    if (row == 9) return 26 + col;            // 26..35
    if (col == 0) return 10 + 2 * (row - 1);  // 10, 12, .. 24
    if (col == 9) return 11 + 2 * (row - 1);  // 11, 13, .. 25
    return -1;
  }

 private:
  using Vector = Eigen::Matrix<double, kRegions, 1>;

  using LevelsMatrix = Eigen::Matrix<double, kRegions, kRegions>;
  // What of a pixel's footprint each region covers, and how fast that
  // changes along the grid's axes, for the regions it touches (ascending).
  struct RegionCoverage {
    int region;
    double cover, slope_x, slope_y;
  };

  // Pixels of the footprint, the map from (centred) pixels to the grid, and
  // the pixels the fit uses with their mean grey; the levels' normal
  // equations for that map.
  bool prepare(const GreyView& image, const Eigen::Matrix3d& grid_to_image, double max_outside);
  // fit() once its map is prepared and its levels solved.
  bool finish(const GreyView& image, Eigen::Matrix3d& grid_to_image, Aim aim, Levels& out, MapNoise* noise);
  // The levels for the current map (solve_levels), or for the normal
  // equations summed already.
  bool solve_levels(const GreyView& image);
  bool solve_accumulated_levels();
  void clear_levels_normal();
  void add_pixel_to_levels(std::span<const RegionCoverage> regions, double grey);
  // Gauss-Newton steps of the map until one moves it less than `converged`
  // pixels, `iterations` at most; false when a step cannot be taken.
  bool align(const GreyView& image, int iterations, double converged);
  // One Gauss-Newton step of the map for the current levels; false when it
  // cannot be taken. `moved` is the largest displacement it makes, pixels.
  // Its factored normal equations are kept for map_noise().
  bool align_step(const GreyView& image, double& moved);
  // The geometry's fit: drops the pixels partly outside the marker that the
  // model misses by far, and solves the levels again. False when none went.
  bool drop_clutter(const GreyView& image);
  // The map's scatter at the last align_step(): its covariance as one
  // standard deviation along each principal direction.
  void map_noise(MapNoise& out) const;
  // The regions the pixel's footprint touches, with their slopes when
  // `slopes` (otherwise only those whose share matters); the pixel's grid
  // coordinates in gx, gy, and the map's denominator in w. Empty for a
  // pixel the fit does not use. Valid until the next call.
  std::span<const RegionCoverage> coverage(int px, int py, bool slopes, double& gx, double& gy, double& w);
  // The same for the pixel at `pixel` (index in the box) as the map is now,
  // appended to covered_; the number of regions.
  int compute_coverage(std::size_t pixel, int px, int py, double& gx, double& gy, double& w);
  // The map (to_grid_) moved: coverages computed before are stale.
  void map_moved() { ++map_version_; }
  // Adds the regions' row to the levels' normal equations (`normal`'s
  // levels block, lower triangle) with `value` on the right.
  template <typename Normal, typename Rhs>
  static void add_levels(std::span<const RegionCoverage> regions, double value, Normal& normal, Rhs& rhs);
  [[nodiscard]] Eigen::Matrix3d grid_to_image() const;
  [[nodiscard]] Eigen::Matrix3d from_centred() const;  // centred pixel -> pixel

  double sigma_ = 0.6;  // the footprint's Gaussian, pixels
  int px0_ = 0, py0_ = 0, px1_ = 0, py1_ = 0;
  double cx_ = 0, cy_ = 0, scale_ = 1;                      // centred pixel coordinates: (x - cx) / scale
  Eigen::Matrix3d to_grid_ = Eigen::Matrix3d::Identity();   // centred pixel -> grid
  Eigen::Matrix3d blur_map_ = Eigen::Matrix3d::Identity();  // to_grid_ as prepared: the footprint's width
  std::vector<std::uint8_t> inside_;                        // per pixel of the box: used by the fit
  // Per pixel of the box: the footprint's width along the grid's axes, in
  // grid units; fixed at prepare() with the map it started from.
  std::vector<std::array<float, 2>> width_;
  double prior_ = 0;  // their mean grey, which every level is pulled towards
  // What coverage() computed for each pixel of the box, for the map it was
  // computed with: a fit passes over the pixels several times with one map
  // (the levels solved, the clutter dropped, the levels again, the first
  // step of an alignment), and this is most of each pass's time. A
  // pixel's regions lie in covered_, from its `first`, for the map of
  // version map_version_ when `version` is it.
  struct PixelCoverage {
    std::uint32_t version = 0;
    std::uint32_t first = 0;
    int n = 0;
    double gx = 0, gy = 0, w = 0;
  };
  std::vector<PixelCoverage> pixel_coverage_;
  std::vector<RegionCoverage> covered_;
  std::array<RegionCoverage, kRegions> shares_{};  // coverage()'s regions without slopes, where fewer
  std::uint32_t map_version_ = 1, covered_version_ = 0;
  // The levels' normal equations (lower triangle), summed over the pixels used.
  struct LevelsNormal {
    LevelsMatrix ata = LevelsMatrix::Zero();
    Vector atb = Vector::Zero();
    double btb = 0;
    int used = 0;
  } normal_;
  Vector level_ = Vector::Zero();
  double rms_ = 0;
  // The last align_step()'s normal equations, factored, and its residuals'
  // variance: the map's covariance, for the geometry's fit when its noise
  // is asked for, is solved from them once the fit has settled.
  static constexpr int kStepParams = kRegions + 8;
  using StepMatrix = Eigen::Matrix<double, kStepParams, kStepParams>;
  Eigen::LDLT<StepMatrix> step_solver_;
  double step_variance_ = 0;
};

}  // namespace markerd::detector::frame8
