#pragma once
// Markers for the real world: an ideal image at any resolution, and a
// printable file at an exact physical size (SVG, PDF, PNG at a given dpi).

#include <filesystem>
#include <stdexcept>

#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"

namespace markerd::detector {

class PrintError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The marker square (plus the quiet zone ArUco and AprilTag need), axis
// aligned, side_px pixels for the marker's size (FamilyInfo::size_cells),
// black 0 and white 255; frame8's hole is white. Pixel-exact when side_px is
// a multiple of the grid.
GreyImage ideal_marker_image(Family family, int id, int side_px, bool with_quiet_zone = true);

struct PrintSpec {
  Family family = Family::frame8;
  int id = 0;
  double size_mm = 80;    // the family's size (frame8: the outer edge)
  double margin_mm = 10;  // paper around the marker, for the label and cutting
  double dpi = 300;       // PNG only
};

// Format from the extension: .svg, .pdf or .png. The frame8 hole is drawn as a
// cut line; the family, id and size are printed outside the marker, beside a
// 10 mm scale bar to check the printer's scale. Throws PrintError.
void write_printable_marker(const PrintSpec& spec, const std::filesystem::path& out);

}  // namespace markerd::detector
