#pragma once
// The frame8 code (docs/frame-marker.md): 36 ring cells on a 10 x 10 grid, the
// 8-bit id repeated on every edge, read clockwise, corners C0 C2 C3 black and
// C1 white.

#include <array>
#include <cstdint>

namespace markerd::detector::frame8 {

inline constexpr int grid = 10;
inline constexpr double hole_fraction = 0.7;  // hole side / outer side
inline constexpr double line_inner = 1.5;     // line from 1.0 to 1.5 cells in
inline constexpr double line_outer = 1.0;

struct Cell {
  int col;  // 0..9 from the left
  int row;  // 0..9 from the top
};

// Ring cell of bit `bit` (7 = most significant) on edge `edge` (0 top, 1 right,
// 2 bottom, 3 left), following the clockwise reading order.
Cell data_cell(int edge, int bit);
// Corner k: 0 top-left, 1 top-right, 2 bottom-right, 3 bottom-left.
Cell corner_cell(int k);

// 10 x 10 cells, row 0 at the top: 1 = white, 0 = black, 2 = the line or hole
// (not a ring cell).
std::array<std::uint8_t, grid * grid> ring_cells(int id);

// A ring whose every edge is one colour but for a cell at either end: ids
// 0 and 255, and 1, 128, 126, 127, 129 and 254. A grid of light squares
// parted by dark lines (tiles, a keyboard's keys, windows) shows one as a
// square's ring: the neighbouring squares for the cells, and at each end
// the crossing line or its absence. The detector asks more of these reads
// (0 and 255 only with uniform_ids; the others, under 3 px a cell, only
// when read twice and confirmed by the ring model, and with one edge's
// cells outvoted only where that edge reads as hidden), so they reach less
// far than other ids and a print of one with an edge's cells painted over
// is not read.
constexpr bool near_uniform(int id) {
  const int core = (id >> 1) & 0x3F;
  return core == 0 || core == 0x3F;
}

}  // namespace markerd::detector::frame8
