#pragma once
// Markers for the real world: an ideal image at any resolution, and a
// printable file at an exact physical size (SVG, PDF, PNG at a given dpi);
// calibration boards (board.hpp) the same way.

#include <filesystem>
#include <stdexcept>

#include "markerd/detector/board.hpp"
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

struct BoardPrintSpec {
  BoardSpec board;
  double margin_mm = 10;  // paper round the pattern (a chessboard's quiet zone), for the label
  double dpi = 300;       // PNG only
};

// The page: the board's pattern plus the margin on every side.
double board_page_width_mm(const BoardPrintSpec& spec);
double board_page_height_mm(const BoardPrintSpec& spec);

// A board at true size, as write_printable_marker prints a marker: the
// format from the extension, the board described in the bottom margin
// beside a 10 mm scale bar. Throws PrintError (and BoardError for a board
// that check_board refuses).
void write_printable_board(const BoardPrintSpec& spec, const std::filesystem::path& out);

// The same page as a grey image, `px_per_m` pixels a metre (0 ink, 255
// paper, edges by their area): what the renderer puts before a camera
// (render.hpp's PlanarPrint, texel_m = 1 / px_per_m). Drawn from the page's
// top-left corner, so that the board frame's origin is margin_mm in from it
// both ways; the image is the page's size rounded to whole pixels.
GreyImage board_page_image(const BoardPrintSpec& spec, double px_per_m);

}  // namespace markerd::detector
