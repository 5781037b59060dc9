// Stage 4d, short-edge orientation: the corners of a marker turned far, from
// the profiles of its two short edges.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Cholesky>
#include "normal_table.hpp"

namespace markerd::detector::frame8 {

// How many profile samples' worth the ring's grey levels weigh in a short
// edge's fit: enough that no colouring fits by turning the contrast down.
constexpr double kLevelPrior = 4.0;
// How far beyond a short edge's end (in cells) its background is measured:
// where the corner's blur has faded.
constexpr double kOutsideGap = 1.75;
// The search for a short edge's cell boundaries: stretches from
// kMinStretch in kStretchSteps, shifts (cells) within kShiftSteps steps
// either way; the hole's short side, of a few pixels, is often measured
// a pixel short.
constexpr double kMinStretch = 0.86;
constexpr double kStretchStep = 0.06;
constexpr int kStretchSteps = 10;
constexpr double kShiftStep = 0.15;
constexpr int kShiftSteps = 4;
// The most of a short edge's profile (its sum of squares about its mean)
// that the code's fit may leave unexplained: the optics the model misses
// leave a few percent; clutter fits the code no better than any other.
constexpr double kMaxUnexplained = 0.1;

// The profile of a short edge fitted with the code's cells and each
// colouring of its corners (ShortEdgeFit).
bool Frame8Detector::fit_short_edge(const Homography& H, int side, int id, double black, double white,
                                    ShortEdgeFit& fit) const {
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
    const double px =
        distance(grid_point(H, side_point(side, t - 0.5, 0.5)), grid_point(H, side_point(side, t + 0.5, 0.5)));
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
  // The part each cell's share goes to: the code's colour, or its corner's.
  std::array<int, frame8::grid> part_of{};
  for (int c = 0; c < frame8::grid; ++c) {
    part_of[static_cast<std::size_t>(c)] = c == 0 ? 2 : c == frame8::grid - 1 ? 3 : ((id >> (8 - c)) & 1);
  }
  // The profile fits below take this some forty times an edge, for every
  // read of a marker turned far: its loops are the fit's time.
  auto moments = [&](double stretch, double shift, Moments& m) {
    std::array<double, 21> gram{};  // the lower triangle, row by row
    std::array<double, 6> cross{};
    // The edge's first boundary, then the end of each cell along it.
    const double first = 5 + shift - 5 * stretch;
    std::array<double, frame8::grid> end{};
    for (int c = 0; c < frame8::grid; ++c) end[static_cast<std::size_t>(c)] = 5 + shift + stretch * (c - 4);
    for (int i = 0; i < kSamples; ++i) {
      const double t = -1.0 + static_cast<double>(i) / kPerCell;
      const double is = inv_sigma[static_cast<std::size_t>(i)];
      std::array<double, 6> part{};
      double below = table.cdf((first - t) * is);
      part[4] = below;
      for (int c = 0; c < frame8::grid; ++c) {
        const double z = (end[static_cast<std::size_t>(c)] - t) * is;
        const double upto = table.cdf(z);
        part[static_cast<std::size_t>(part_of[static_cast<std::size_t>(c)])] += upto - below;
        below = upto;
        // Every boundary further on is as far past the table's end, its
        // share exactly 0.
        if (z >= detail::NormalTable::kRange) break;
      }
      part[5] = 1 - below;
      std::size_t k = 0;
#pragma GCC unroll 6
      for (std::size_t a = 0; a < 6; ++a) {
#pragma GCC unroll 6
        for (std::size_t b = 0; b <= a; ++b) gram[k++] += part[a] * part[b];
      }
      const double y = level[static_cast<std::size_t>(i)];
#pragma GCC unroll 6
      for (std::size_t a = 0; a < 6; ++a) cross[a] += part[a] * y;
    }
    std::size_t k = 0;
    for (int a = 0; a < 6; ++a) {
      for (int b = 0; b <= a; ++b) m.gram(a, b) = m.gram(b, a) = gram[k++];
      m.cross(a) = cross[static_cast<std::size_t>(a)];
    }
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
  int best_i = 0, best_j = 0;
  auto try_at = [&](int i, int j) {
    const double stretch = kMinStretch + i * kStretchStep, shift = j * kShiftStep;
    moments(stretch, shift, m);
    if (const double r = free_corners(m); r < best) {
      best = r;
      best_stretch = stretch;
      best_shift = shift;
      best_i = i;
      best_j = j;
    }
  };
  // Every other step first, then the steps beside the best: the profile is
  // blurred over a cell, and its fit varies smoothly over a step.
  for (int i = 0; i < kStretchSteps; i += 2) {
    for (int j = -kShiftSteps; j <= kShiftSteps; j += 2) try_at(i, j);
  }
  const int coarse_i = best_i, coarse_j = best_j;
  for (int i = std::max(0, coarse_i - 1); i <= std::min(kStretchSteps - 1, coarse_i + 1); ++i) {
    for (int j = std::max(-kShiftSteps, coarse_j - 1); j <= std::min(kShiftSteps, coarse_j + 1); ++j) {
      if ((i - coarse_i) % 2 != 0 || (j - coarse_j) % 2 != 0) try_at(i, j);
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
          if (colouring > 0)
            fit.corner_worth[static_cast<std::size_t>(colouring - 1)] = m.gram(colouring + 1, colouring + 1);
        }
      }
    }
  }
  return true;
}

// The white corner of a marker whose short edges are `side` and side + 2,
// from their profiles (fit_short_edge), with `clarity` the margin to the
// next best colouring in units of what a corner's colour is worth; -1
// when the code leaves either profile unexplained. With only the two long
// edges voting, the code has no redundancy left: the short edges are its
// check.
int Frame8Detector::white_corner_by_short_edges(const Homography& H, int side, int id, double black, double white,
                                                double& clarity) const {
  std::array<ShortEdgeFit, 2> fit{};
  if (!fit_short_edge(H, side, id, black, white, fit[0])) return -1;
  // A profile that no colouring of its corners explains fails the check
  // below whatever the other edge says: clutter mostly stops here, at
  // half the cost.
  if (std::all_of(fit[0].residual.begin(), fit[0].residual.end(),
                  [&](double r) { return r / fit[0].spread >= kMaxUnexplained; })) {
    return -1;
  }
  if (!fit_short_edge(H, side + 2, id, black, white, fit[1])) return -1;
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
    const double expected =
        contrast * contrast * (worth[static_cast<std::size_t>(best)] + worth[static_cast<std::size_t>(k)]);
    clarity = std::min(clarity,
                       (residual[static_cast<std::size_t>(k)] - residual[static_cast<std::size_t>(best)]) / expected);
  }
  // Each edge's profile is the code's, to what the model misses of the
  // optics: clutter's profiles fit the code no better than any other.
  double unexplained = 0;
  for (int edge = 0; edge < 2; ++edge) {
    const auto& f = fit[static_cast<std::size_t>(edge)];
    unexplained = std::max(unexplained, f.residual[static_cast<std::size_t>(colouring(edge, best))] / f.spread);
  }
  if (!(unexplained < kMaxUnexplained)) return -1;
  return best;
}

}  // namespace markerd::detector::frame8
