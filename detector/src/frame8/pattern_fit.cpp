// Stage 5, the whole pattern: with the code known, every edge of the printed
// pattern measured, and one grid-to-image map fitted to all of them.

#include "frame8/detector.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

namespace markerd::detector::frame8 {

// The edge along `axis_normal` through grid point g0: searched across the
// edge within +-half (grid units) through the homography. A step is
// light-to-dark along the normal and located at its gradient centroid; a
// dip (the half-cell line between the hole and a white cell) at the
// centroid of its depth, the line's centre. Returns false when nothing
// clear is there.
bool Frame8Detector::locate_edge(const Homography& H, Point2 g0, Point2 normal, double half, bool dip, double& offset,
                                 double& strength) const {
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
    const auto ref = [&](int i) { return v.front() + (v.back() - v.front()) * i / (kSamples - 1.0); };
    for (int i = 0; i < kSamples; ++i) peak = std::max(peak, ref(i) - v[static_cast<std::size_t>(i)]);
    const double floor = 0.1 * peak;
    for (int i = 0; i < kSamples; ++i) {
      const double depth = ref(i) - v[static_cast<std::size_t>(i)] - floor;
      if (depth <= 0) continue;
      sum += depth;
      moment += depth * (-half + i * ds);
    }
  } else {
    for (int i = 0; i + 1 < kSamples; ++i)
      peak = std::max(peak, static_cast<double>(v[static_cast<std::size_t>(i)] - v[static_cast<std::size_t>(i + 1)]));
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

// The ring's colours for the code `id` read with `rotation`, in the quad's
// grid: the marker's corner j sits at the quad's corner j + rotation.
Frame8Detector::CellColours Frame8Detector::colours_of_code(int id, int rotation) {
  const auto cells = frame8::ring_cells(id);
  CellColours colours{};
  for (int row = 0; row < frame8::grid; ++row) {
    for (int col = 0; col < frame8::grid; ++col) {
      Point2 g{col + 0.5, row + 0.5};
      for (int r = 0; r < rotation; ++r) g = {g.y, frame8::grid - g.x};
      const auto cell = cells[static_cast<std::size_t>(static_cast<int>(g.y) * frame8::grid + static_cast<int>(g.x))];
      colours[static_cast<std::size_t>(row * frame8::grid + col)] = cell == 1 ? kWhiteCell : cell == 0 ? kBlackCell : 0;
    }
  }
  return colours;
}

int Frame8Detector::collect_pattern_edges(const Homography& H, int id, int rotation, double cell_px,
                                          const HiddenSide& hidden, HoleEdge hole_edge) {
  return collect_pattern_edges(H, colours_of_code(id, rotation), cell_px, hidden, hole_edge);
}

// Collects the pattern's edges for the ring's `colours`: the hole's edge (a
// step where the ring cell beyond is black, the line's centre where it is
// white) and every boundary between ring cells of different colours. A
// cell of unknown colour gives none. The outer edge is left out: what lies
// beyond it is unknown; so is everything near a hidden side.
int Frame8Detector::collect_pattern_edges(const Homography& H, const CellColours& colours, double cell_px,
                                          const HiddenSide& hidden, HoleEdge hole_edge) {
  auto colour_at = [&](Point2 g) {
    const int col = std::clamp(static_cast<int>(g.x), 0, frame8::grid - 1);
    const int row = std::clamp(static_cast<int>(g.y), 0, frame8::grid - 1);
    return colours[static_cast<std::size_t>(row * frame8::grid + col)];
  };
  auto white_at = [&](Point2 g) { return colour_at(g) == kWhiteCell; };
  auto black_at = [&](Point2 g) { return colour_at(g) == kBlackCell; };
  static constexpr std::array<Point2, 4> kOutward{{{0, -1}, {1, 0}, {0, 1}, {-1, 0}}};
  // The line beside a white cell is half a cell wide. Narrower than the
  // blurred edge (two profile sigmas: 1.5 px with the default blur), its dip
  // is shaped as much by the cells beside it as by the line: a black cell
  // beside the white one darkens one flank, and the centre comes out up to
  // a fiftieth of a cell outwards (2 px cells: 0.02), which grew the hole
  // and put a far marker up to 0.3 % too near. There the hole's edge is
  // left to the steps beside black cells and to the boundaries.
  const double min_dip_line_px = 2 * profile_sigma_;
  const double line_px = (kInnerLo - frame8::line_outer) * cell_px;
  // Points per cell along an edge: about one per 1.5 px. Where a side is
  // hidden the edges found are a check of the read as well (at least
  // kMinPatternEdges, hidden_side.cpp), and cells of 2.9 px, a covered
  // marker's from 1.2 m turned 30 deg, take two each, not one.
  const double per_cell_px = cell_px / 1.5;
  const int per_cell =
      std::clamp(static_cast<int>(hidden.side >= 0 ? std::lround(per_cell_px) : std::floor(per_cell_px)), 1, 4);
  pattern_count_ = 0;
  auto add = [&](Point2 g, Point2 normal, double half, bool dip, int axis) {
    if (pattern_count_ >= kMaxPatternEdges) return;
    // Clear of a hidden side by a third of a cell: its edge is the cover's.
    if (hidden.side >= 0 && hidden.in_from_side(g) < hidden.depth + 0.35) return;
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
        if (hole_edge == HoleEdge::unknown) {
          // The step from a white cell into the line, inwards.
          if (white_at(side_point(side, along, 0.5))) {
            add(side_point(side, along, frame8::line_outer), {-outward.x, -outward.y}, 0.45, false, axis);
          }
          continue;
        }
        if (white_at(side_point(side, along, 0.5))) {
          if (line_px < min_dip_line_px) continue;
          add(side_point(side, along, 1.25), outward, 0.65, true, axis);
        } else if (black_at(side_point(side, along, 0.5))) {
          add(side_point(side, along, kInnerLo), outward, 0.45, false, axis);
        }
      }
    }
    // Boundaries between neighbouring ring cells of different colours, across the ring.
    for (int boundary = 1; boundary < frame8::grid; ++boundary) {
      const int before = colour_at(side_point(side, boundary - 0.5, 0.5));
      const int after = colour_at(side_point(side, boundary + 0.5, 0.5));
      if (before == 0 || after == 0 || before == after) continue;
      const bool before_white = before == kWhiteCell;
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
bool Frame8Detector::fit_grid_map(Eigen::Matrix3d& grid_to_image, MapNoise* noise) {
  const int n = pattern_count_;
  double mx = 0, my = 0, sw = 0;
  for (int i = 0; i < n; ++i) {
    mx += pattern_edges_[static_cast<std::size_t>(i)].x;
    my += pattern_edges_[static_cast<std::size_t>(i)].y;
  }
  mx /= n;
  my /= n;
  for (int i = 0; i < n; ++i) {
    sw += std::abs(pattern_edges_[static_cast<std::size_t>(i)].x - mx) +
          std::abs(pattern_edges_[static_cast<std::size_t>(i)].y - my);
  }
  const double scale = sw > 0 ? n / sw : 1.0;  // points normalised to a spread of about 1
  Eigen::Matrix<double, 3, 3> G;               // normalised image -> grid (homogeneous)
  std::array<double, kMaxPatternEdges> weight{};
  for (int i = 0; i < n; ++i) weight[static_cast<std::size_t>(i)] = pattern_edges_[static_cast<std::size_t>(i)].w;
  bool have = false;
  Eigen::Matrix<double, 9, 1> spread = Eigen::Matrix<double, 9, 1>::Zero();  // the last fit's eigenvalues
  Eigen::Matrix<double, 9, 9> directions;                                    // and their directions
  int last_used = 0;
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
    spread = eig.eigenvalues();
    directions = eig.eigenvectors();
    last_used = used;
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
  const Eigen::Matrix3d G_inverse = lu.inverse();
  grid_to_image = denorm * G_inverse;
  if (noise) {
    // Weighted least squares: the residuals' variance per unit weight is
    // the smallest eigenvalue (the weighted sum of squares at the solution)
    // over the degrees of freedom left, and along each other direction the
    // solution scatters by that variance over its eigenvalue. The map moves
    // by -G^-1 dG G^-1 for a change dG of its inverse.
    noise->count = 0;
    const double variance = spread(0) / std::max(1, last_used - 8);
    for (int k = 1; k < 9; ++k) {
      if (!(spread(k) > 0)) continue;
      const Eigen::Matrix<double, 9, 1> d = directions.col(k) * std::sqrt(variance / spread(k));
      Eigen::Matrix3d dG;
      dG << d(0), d(1), d(2), d(3), d(4), d(5), d(6), d(7), d(8);
      noise->deltas[static_cast<std::size_t>(noise->count++)] = -denorm * G_inverse * dG * G_inverse;
    }
  }
  return true;
}

// Corners (and, with a camera, the pose) from the pattern's edges.
Rejection Frame8Detector::finish_by_pattern(int rotation, Detection& det) {
  if (config_.camera) {
    for (int i = 0; i < pattern_count_; ++i) {
      auto& e = pattern_edges_[static_cast<std::size_t>(i)];
      const Point2 p = config_.camera->pixel_to_normalized({e.x, e.y});
      e.x = p.x;
      e.y = p.y;
    }
  }
  Eigen::Matrix3d M;
  MapNoise noise;
  if (!fit_grid_map(M, &noise)) return Rejection::pattern_fit_failed;
  return report(M, rotation, det, &noise);
}

// Small cells: the pattern's edges are located from samples of a few
// pixels, and where the blur spans a cell their places depend on how the
// edge falls on the pixels (at 2.2 m, id 17 came out squeezed by 0.8 %, the
// same frame without noise by as much: no noise, but the phase). The ring
// model fits the blurred print to every pixel at once instead: half the
// pattern's corner error from 1.4 m out.
bool Frame8Detector::fit_model_geometry(Eigen::Matrix3d& map, MapNoise& noise) {
  RingModel::Levels levels;
  return ring_model_.fit(full_, map, config_.frame8.blur_sigma_px, RingModel::Aim::geometry, levels, &noise);
}

bool Frame8Detector::finish_by_model(const Eigen::Matrix3d& map, const MapNoise& noise, int rotation, Detection& det) {
  Detection measured = det;
  if (report(map, rotation, measured, &noise, MapSpace::pixels) != Rejection::none) return false;
  det = measured;
  return true;
}

}  // namespace markerd::detector::frame8
