#include "markerd/detector/frame8.hpp"

#include <stdexcept>

namespace markerd::detector::frame8 {

Cell data_cell(int edge, int bit) {
  // Position along the edge in reading order: 0 for the most significant bit.
  const int k = 7 - bit;
  switch (edge) {
    case 0: return {1 + k, 0};  // top, left to right
    case 1: return {9, 1 + k};  // right, top to bottom
    case 2: return {8 - k, 9};  // bottom, right to left
    case 3: return {0, 8 - k};  // left, bottom to top
    default: throw std::out_of_range("frame8::data_cell: edge");
  }
}

Cell corner_cell(int k) {
  static constexpr Cell corners[4] = {{0, 0}, {9, 0}, {9, 9}, {0, 9}};
  return corners[k & 3];
}

std::array<std::uint8_t, grid * grid> ring_cells(int id) {
  if (id < 0 || id > 255) throw std::out_of_range("frame8: id must be 0..255");
  std::array<std::uint8_t, grid * grid> cells{};
  cells.fill(2);
  for (int k = 0; k < 4; ++k) {
    const Cell c = corner_cell(k);
    cells[c.row * grid + c.col] = (k == 1) ? 1 : 0;
  }
  for (int edge = 0; edge < 4; ++edge) {
    for (int bit = 0; bit < 8; ++bit) {
      const Cell c = data_cell(edge, bit);
      cells[c.row * grid + c.col] = static_cast<std::uint8_t>((id >> bit) & 1);
    }
  }
  return cells;
}

}  // namespace markerd::detector::frame8
