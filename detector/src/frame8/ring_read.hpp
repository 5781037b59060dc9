#pragma once
// What stage 4 (decoding) knows of a candidate's ring as its sub-stages read
// it: the cells (4a), the grey model (4b), the orientation (4c) and the bits
// (4d), checked as a whole by 4e.

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>

#include "frame8/common.hpp"

namespace markerd::detector::frame8 {

struct RingRead {
  // What a read of a quad with one side hidden (hidden_side.cpp) leaves out.
  HiddenSide hidden;

  // 4a: the corner cells C0..C3 and, per edge, the data cells by bit.
  std::array<CellSample, 4> corner{};
  std::array<std::array<CellSample, 8>, 4> cell{};

  // 4b: black and white levels of the ring, the threshold between them, and
  // how far from it a clear read must be (soft units).
  double black = 0, white = 0, thr = 0, contrast = 0;
  double confident = 0;
  int white_corner = 0;  // the whitest corner: C1 unless 4c decides otherwise

  // 4c and 4d: each edge's weight in the votes (0: no vote), the first of a
  // far-turned marker's two short sides (-1: none), how clearly the corners
  // give the orientation, and whether the short edges' profiles decide it.
  std::array<double, 4> weight{};
  int short_side = -1;
  double orientation_clarity = 0;
  bool corners_read = false;
  bool by_short_edges = false;
  // The white corner was hidden: C1 is one of the hidden side's two corners,
  // and white_corner names one of them.
  bool orientation_ambiguous = false;

  // 4d: the code, its cell reads overruled and erased, per edge the cells
  // the other edges outvoted (bit b set where the edge's cell for bit b
  // was), the fewest clear reads that agreed on a bit, and the weakest
  // bit's margin.
  int id = 0, corrected = 0, erased = 0, fewest_agreeing = 0;
  std::array<std::uint8_t, 4> outvoted{};
  double margin = 1.0;

  // How many of edge e's cells the other edges outvoted.
  [[nodiscard]] int outvoted_cells(int e) const { return std::popcount(outvoted[static_cast<std::size_t>(e)]); }
  // A grey level on the ring's scale: -1 black, +1 white.
  [[nodiscard]] double soft(double v) const { return std::clamp((v - thr) / (0.5 * contrast), -1.0, 1.0); }
  // A cell read clearly and, where resolved, one colour all over; otherwise
  // it is an erasure (an occluder's edge, or clutter that is no cell at all).
  [[nodiscard]] bool clear(const CellSample& c) const {
    const double lo = soft(c.lo), hi = soft(c.hi);
    return c.valid && ((lo > confident && hi > confident) || (lo < -confident && hi < -confident));
  }
};

}  // namespace markerd::detector::frame8
