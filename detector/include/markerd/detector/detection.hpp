#pragma once
#include <optional>

#include "markerd/detector/family.hpp"
#include "markerd/detector/geometry.hpp"
#include "markerd/detector/pose.hpp"

namespace markerd::detector {

struct Detection {
  Family family = Family::frame8;
  int id = -1;
  // Outer printed square, sub-pixel, in the marker frame's order (TL, TR, BR, BL).
  Quad corners{};
  // frame8 only: the inner corners of the black line (the hole's square, side
  // 0.7 S), in the same order. What the detector actually measures.
  std::optional<Quad> inner_corners;
  // Quarter turns of the marker in the image: 0 when its top edge faces the
  // image top, 1 when it faces the image right (turned 90 deg clockwise), ...
  int quarter_turns = 0;
  // frame8 only: the white corner was hidden (a side of the marker covered),
  // so the marker's orientation is one of two a quarter turn apart. The id
  // holds either way; corners, quarter_turns and pose follow one of the two.
  bool orientation_ambiguous = false;
  // Cell reads the code overruled (frame8: edges outvoted per bit position).
  int bits_corrected = 0;
  // How clearly the code was read, 0 (a coin toss) to 1 (every cell at full
  // contrast, every vote unanimous).
  double margin = 0;
  // Present when the detector was given a camera model and a marker size.
  std::optional<PoseEstimate> pose;
};

}  // namespace markerd::detector
