// Stage 4d, the bit votes: each bit decided over the four edges, each edge
// weighted by how well its cells are resolved; one wrong edge per bit is
// corrected, a second rejects the candidate.

#include "frame8/detector.hpp"

#include <algorithm>
#include <cmath>

namespace markerd::detector::frame8 {

// How well an edge's cells are resolved along the edge, 0..1: a cell under
// a pixel wide is blurred into its neighbours.
double Frame8Detector::edge_weight(const Homography& H, int edge) {
  const frame8::Cell a = frame8::data_cell(edge, 6), b = frame8::data_cell(edge, 1);
  const double pitch = distance(grid_point(H, a.col + 0.5, a.row + 0.5), grid_point(H, b.col + 0.5, b.row + 0.5)) / 5.0;
  return std::clamp((pitch - 0.7) / 1.3, 0.02, 1.0);
}

double Frame8Detector::confirming_cell_size(const Homography& H, CellSize size) {
  double best = 0;
  for (int edge = 0; edge < 4; ++edge) {
    const frame8::Cell a = frame8::data_cell(edge, 6), b = frame8::data_cell(edge, 1);
    const Point2 ga{a.col + 0.5, a.row + 0.5}, gb{b.col + 0.5, b.row + 0.5};
    const Point2 along_grid = (1.0 / 5.0) * (gb - ga);
    const Point2 mid = 0.5 * (ga + gb);
    const Point2 across_grid{-along_grid.y, along_grid.x};
    const Point2 at = grid_point(H, mid), along = grid_point(H, mid + along_grid);
    const Point2 across = grid_point(H, mid + across_grid);
    const double across_len = distance(at, across);
    if (across_len <= 0) continue;
    // The distance between the lines that part a cell from its neighbours
    // along the edge: the along step's part square to the across one.
    best = std::max(best, std::abs(cross(at, along, across)) / across_len);
  }
  return std::min(size.mean, best);
}

// The edges' weights in the votes. The two short edges of a marker turned
// far have cells of about a pixel along them, blurred into each other, while
// its two long edges read cleanly: then the short ones have no vote, and
// their corners are read from their profiles once the code is known
// (short_edges.cpp). Only for that shape: a lone short edge is no turned
// marker, and must keep its say.
void Frame8Detector::weigh_edges(const Homography& H, RingRead& r) {
  // The edge_weight() an edge needs to vote when others are resolved (cells of 1.2 px).
  constexpr double kVotingEdge = 0.38;
  auto& weight = r.weight;
  for (int e = 0; e < 4; ++e) weight[static_cast<std::size_t>(e)] = edge_weight(H, e);
  r.short_side = -1;
  for (int e = 0; e < 2; ++e) {
    const auto s0 = static_cast<std::size_t>(e), s1 = static_cast<std::size_t>(e + 2);
    const auto l0 = static_cast<std::size_t>(e + 1), l1 = static_cast<std::size_t>((e + 3) % 4);
    if (weight[s0] < kVotingEdge && weight[s1] < kVotingEdge && weight[l0] >= 1.0 && weight[l1] >= 1.0) {
      weight[s0] = weight[s1] = 0.0;
      r.short_side = e;
    }
  }
  if (r.hidden.side >= 0) weight[static_cast<std::size_t>(r.hidden.side)] = 0.0;
}

Rejection Frame8Detector::vote_bits(RingRead& r) {
  r.id = 0;
  r.corrected = 0;
  r.erased = 0;
  r.outvoted = {};
  r.margin = 1.0;
  r.fewest_agreeing = 4;
  for (int b = 0; b < 8; ++b) {
    double sum = 0, wsum = 0;
    for (int e = 0; e < 4; ++e) {
      const auto& c = r.cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      if (!c.valid) continue;
      sum += r.weight[static_cast<std::size_t>(e)] * r.soft(c.mean);
      wsum += r.weight[static_cast<std::size_t>(e)];
    }
    if (wsum <= 0) return Rejection::bit_without_vote;
    const bool bit = sum > 0;
    int agree = 0, dissent = 0;
    for (int e = 0; e < 4; ++e) {
      const auto& c = r.cell[static_cast<std::size_t>(e)][static_cast<std::size_t>(b)];
      if (r.weight[static_cast<std::size_t>(e)] == 0.0) continue;  // an edge without a vote
      if (!c.valid && r.hidden.side >= 0) continue;                // hidden, not erased
      if (!r.clear(c)) {
        ++r.erased;
        continue;  // an erasure, not a vote
      }
      if ((r.soft(c.mean) > 0) == bit) {
        ++agree;
      } else {
        ++dissent;
        r.outvoted[static_cast<std::size_t>(e)] |= static_cast<std::uint8_t>(1U << b);
      }
    }
    // At most one wrong edge per bit position is correctable; a second is detected.
    if (dissent > 1 || agree < 1 || agree <= dissent) return Rejection::bit_uncorrectable;
    // With a side hidden the code has lost a quarter of its redundancy
    // already: what is left must agree, twice at least, on every bit.
    if (r.hidden.side >= 0 && (dissent > 0 || agree < 2)) return Rejection::bit_uncorrectable;
    r.corrected += dissent;
    r.fewest_agreeing = std::min(r.fewest_agreeing, agree);
    r.margin = std::min(r.margin, std::abs(sum) / wsum);
    if (bit) r.id |= 1 << b;
  }
  return Rejection::none;
}

}  // namespace markerd::detector::frame8
