#include "markerd/detector/print.hpp"

#include <cairo-pdf.h>
#include <cairo-svg.h>
#include <cairo.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "markerd/base/ascii.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/detector/frame8.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::detector {
namespace {

constexpr double kMmPerInch = 25.4;
constexpr double kPointsPerMm = 72.0 / kMmPerInch;
constexpr double kMinMarginMm = 5;  // room for the label and the scale bar
constexpr double kMaxPageMm = 5000;
constexpr int kMaxPngSide = 32767;    // cairo's image surface limit
constexpr double kCutLineMm = 0.025;  // a cutter's hairline (0.001 in)

// Paper/ink from the rendering pattern, with the hole printed white.
bool is_white(const MarkerPattern& pattern, double u, double v) {
  const auto r = pattern.reflectance(u, v);
  return !r || *r > 0.5F;
}

void check_id(Family family, int id, const std::string& where) {
  const FamilyInfo& info = family_info(family);
  if (id < 0 || id >= info.id_count) {
    throw PrintError(
        fmt::format("{}: id {} is out of range for {} (valid: 0..{})", where, id, info.name, info.id_count - 1));
  }
}

// ------------------------------------------------------------------ drawing

struct Layout {
  double cell_mm;     // one grid cell
  double printed_mm;  // marker plus quiet zone
  double page_w_mm;
  double page_h_mm;
  double marker_x_mm;  // top-left of the marker square (without quiet zone)
  double marker_y_mm;
};

Layout layout_for(const PrintSpec& spec) {
  const FamilyInfo& info = family_info(spec.family);
  Layout l{};
  l.cell_mm = spec.size_mm / info.size_cells;
  l.printed_mm = l.cell_mm * (info.size_cells + 2 * info.quiet_zone_cells);
  // The margin is counted from the quiet zone: a label inside it would break
  // ArUco's and AprilTag's detection.
  l.page_w_mm = l.printed_mm + 2 * spec.margin_mm;
  l.page_h_mm = l.page_w_mm;
  l.marker_x_mm = spec.margin_mm + l.cell_mm * info.quiet_zone_cells;
  l.marker_y_mm = l.marker_x_mm;
  return l;
}

// The label row in the bottom margin, below `bottom_mm` (the printed
// area's lower edge): a 10 mm scale bar to check the printer's scale, then
// the text.
void draw_label(cairo_t* cr, double margin_mm, double bottom_mm, const std::string& what) {
  const double left = margin_mm;
  const double mid_y = bottom_mm + margin_mm * 0.5;
  const double font_mm = std::clamp(margin_mm * 0.3, 1.5, 3.5);
  const double tick = font_mm * 0.45;
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_rectangle(cr, left, mid_y - 0.2, 10.0, 0.4);
  cairo_rectangle(cr, left, mid_y - tick, 0.2, 2 * tick);
  cairo_rectangle(cr, left + 10.0 - 0.2, mid_y - tick, 0.2, 2 * tick);
  cairo_fill(cr);

  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, font_mm);
  const std::string text = "10 mm   " + what;
  cairo_move_to(cr, left + 10.0 + font_mm, mid_y + font_mm * 0.35);
  cairo_show_text(cr, text.c_str());
}

// Draws the page in millimetres (the caller has set up the scale). Ink is
// one path filled once, so that adjacent black cells show no seams.
void draw_page(cairo_t* cr, const PrintSpec& spec, const Layout& l) {
  const FamilyInfo& info = family_info(spec.family);
  const int n = info.size_cells;
  const double c = l.cell_mm;
  const double x0 = l.marker_x_mm, y0 = l.marker_y_mm;
  const MarkerPattern pattern(spec.family, spec.id, false);

  cairo_new_path(cr);
  cairo_set_fill_rule(cr, CAIRO_FILL_RULE_WINDING);
  if (spec.family == Family::frame8) {
    const auto cells = frame8::ring_cells(spec.id);
    for (int r = 0; r < n; ++r) {
      for (int k = 0; k < n; ++k) {
        if (cells[static_cast<std::size_t>(r * n + k)] == 0) cairo_rectangle(cr, x0 + k * c, y0 + r * c, c, c);
      }
    }
    // The line: its outer square clockwise, the hole counter-clockwise
    // (negative width), so that the winding rule leaves the hole empty.
    const double lo = frame8::line_outer * c, li = frame8::line_inner * c;
    const double side = n * c;
    cairo_rectangle(cr, x0 + lo, y0 + lo, side - 2 * lo, side - 2 * lo);
    cairo_rectangle(cr, x0 + side - li, y0 + li, -(side - 2 * li), side - 2 * li);
  } else {
    for (int r = 0; r < n; ++r) {
      for (int k = 0; k < n; ++k) {
        const double u = (k + 0.5) / n - 0.5, v = 0.5 - (r + 0.5) / n;
        if (!is_white(pattern, u, v)) cairo_rectangle(cr, x0 + k * c, y0 + r * c, c, c);
      }
    }
  }
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_fill(cr);

  if (spec.family == Family::frame8) {
    // The cut line: red is what laser cutters and plotters take as "cut";
    // centred on the line's inner edge, so the cut is where the detector looks.
    const double li = frame8::line_inner * c, side = n * c;
    cairo_rectangle(cr, x0 + li, y0 + li, side - 2 * li, side - 2 * li);
    cairo_set_source_rgb(cr, 1, 0, 0);
    cairo_set_line_width(cr, kCutLineMm);
    cairo_stroke(cr);
  }

  draw_label(cr, spec.margin_mm, spec.margin_mm + l.printed_mm,
             fmt::format("{} id {}   size {:g} mm", info.name, spec.id, spec.size_mm));
}

// A board's page: the ink as one path (touching rectangles show no seams),
// then its label.
void draw_board_page(cairo_t* cr, const BoardPrintSpec& spec) {
  const BoardSpec& b = spec.board;
  cairo_new_path(cr);
  cairo_set_fill_rule(cr, CAIRO_FILL_RULE_WINDING);
  for (const InkRect& r : board_ink(b)) {
    cairo_rectangle(cr, spec.margin_mm + r.x * 1e3, spec.margin_mm + r.y * 1e3, r.width * 1e3, r.height * 1e3);
  }
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_fill(cr);
  std::string text = fmt::format("{} {}x{}", to_string(b.type), b.cols, b.rows);
  switch (b.type) {
    case BoardType::chessboard: text += fmt::format(", square {:g} mm", b.size_m * 1e3); break;
    case BoardType::charuco:
      text += fmt::format(", square {:g} mm, marker {:g} mm, {}", b.size_m * 1e3, b.marker_size_m * 1e3, b.dictionary);
      break;
    case BoardType::frame8:
      // The ids themselves are the board file's: a long list has no room here.
      text += fmt::format(", marker {:g} mm, spacing {:g} mm, ids from {}", b.size_m * 1e3, b.spacing_m * 1e3,
                          b.ids.front());
      break;
  }
  draw_label(cr, spec.margin_mm, spec.margin_mm + b.height_m() * 1e3, text);
}

// ------------------------------------------------------------------ output

cairo_status_t append_to_string(void* closure, const unsigned char* data, unsigned int length) {
  static_cast<std::string*>(closure)->append(reinterpret_cast<const char*>(data), length);
  return CAIRO_STATUS_SUCCESS;
}

using SurfacePtr = std::unique_ptr<cairo_surface_t, decltype(&cairo_surface_destroy)>;
using ContextPtr = std::unique_ptr<cairo_t, decltype(&cairo_destroy)>;

void check_status(cairo_status_t status, const std::filesystem::path& out) {
  if (status != CAIRO_STATUS_SUCCESS) {
    throw PrintError(fmt::format("{}: cairo failed: {}", out.string(), cairo_status_to_string(status)));
  }
}

// A page to write: its size, its PDF title, and what draws it (in
// millimetres).
struct Page {
  double width_mm = 0;
  double height_mm = 0;
  std::string title;
  std::function<void(cairo_t*)> draw;
};

void render_to(cairo_surface_t* surface, double scale, bool white_page, const Page& page,
               const std::filesystem::path& out) {
  check_status(cairo_surface_status(surface), out);
  const ContextPtr cr(cairo_create(surface), cairo_destroy);
  if (white_page) {
    cairo_set_source_rgb(cr.get(), 1, 1, 1);
    cairo_paint(cr.get());
  }
  cairo_scale(cr.get(), scale, scale);
  page.draw(cr.get());
  check_status(cairo_status(cr.get()), out);
}

std::uint32_t crc32(const unsigned char* data, std::size_t n, std::uint32_t crc = 0) {
  static const auto table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1U) ? 0xEDB88320U ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  crc = ~crc;
  for (std::size_t i = 0; i < n; ++i) crc = table[(crc ^ data[i]) & 0xFFU] ^ (crc >> 8);
  return ~crc;
}

void put_be32(std::string& s, std::uint32_t v) {
  for (int shift = 24; shift >= 0; shift -= 8) s.push_back(static_cast<char>((v >> shift) & 0xFFU));
}

// cairo writes no pHYs chunk; without it a printer guesses the resolution.
std::string with_phys(const std::string& png, double dpi, const std::filesystem::path& out) {
  // Signature (8) + IHDR (4 length + 4 type + 13 data + 4 CRC).
  constexpr std::size_t kAfterIhdr = 8 + 25;
  if (png.size() < kAfterIhdr || png.compare(12, 4, "IHDR") != 0) {
    throw PrintError(fmt::format("{}: cairo wrote an unexpected PNG", out.string()));
  }
  const auto ppm = static_cast<std::uint32_t>(std::lround(dpi / 0.0254));
  std::string chunk;
  put_be32(chunk, 9);
  chunk += "pHYs";
  put_be32(chunk, ppm);
  put_be32(chunk, ppm);
  chunk.push_back(1);  // unit: metre
  put_be32(chunk, crc32(reinterpret_cast<const unsigned char*>(chunk.data()) + 4, chunk.size() - 4));
  std::string result = png.substr(0, kAfterIhdr);
  result += chunk;
  result.append(png, kAfterIhdr, std::string::npos);
  return result;
}

void write_file(const std::filesystem::path& out, const std::string& bytes) {
  std::ofstream f(out, std::ios::binary | std::ios::trunc);
  if (!f) throw PrintError(fmt::format("{}: cannot open for writing: {}", out.string(), errno_text(errno)));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  f.close();
  if (!f) throw PrintError(fmt::format("{}: write failed: {}", out.string(), errno_text(errno)));
}

void check_extension(const std::filesystem::path& out) {
  const std::string ext = ascii_lower(out.extension().string());
  if (ext != ".svg" && ext != ".pdf" && ext != ".png") {
    throw PrintError(
        fmt::format("{}: unsupported extension '{}' (use .svg, .pdf or .png)", out.string(), out.extension().string()));
  }
}

void check_margin(double margin_mm, const std::filesystem::path& out) {
  if (!std::isfinite(margin_mm) || margin_mm < kMinMarginMm) {
    throw PrintError(fmt::format("{}: margin_mm must be at least {} mm for the label, got {}", out.string(),
                                 kMinMarginMm, margin_mm));
  }
}

// The page as SVG, PDF or PNG (at `dpi`), from the extension.
void write_page(const Page& page, double dpi, const std::filesystem::path& out) {
  if (page.width_mm > kMaxPageMm || page.height_mm > kMaxPageMm) {
    throw PrintError(fmt::format("{}: page of {:g} x {:g} mm is larger than {} mm", out.string(), page.width_mm,
                                 page.height_mm, kMaxPageMm));
  }
  const std::string ext = ascii_lower(out.extension().string());
  std::string bytes;
  if (ext == ".svg") {
    // The document unit mm makes the user unit one millimetre: width="..mm".
    const SurfacePtr surface(
        cairo_svg_surface_create_for_stream(append_to_string, &bytes, page.width_mm, page.height_mm),
        cairo_surface_destroy);
    cairo_svg_surface_set_document_unit(surface.get(), CAIRO_SVG_UNIT_MM);
    render_to(surface.get(), 1.0, false, page, out);
    cairo_surface_finish(surface.get());
    check_status(cairo_surface_status(surface.get()), out);
  } else if (ext == ".pdf") {
    const SurfacePtr surface(cairo_pdf_surface_create_for_stream(append_to_string, &bytes, page.width_mm * kPointsPerMm,
                                                                 page.height_mm * kPointsPerMm),
                             cairo_surface_destroy);
    cairo_pdf_surface_set_metadata(surface.get(), CAIRO_PDF_METADATA_TITLE, page.title.c_str());
    cairo_pdf_surface_set_metadata(surface.get(), CAIRO_PDF_METADATA_CREATOR, "markerd");
    render_to(surface.get(), kPointsPerMm, false, page, out);
    cairo_surface_finish(surface.get());
    check_status(cairo_surface_status(surface.get()), out);
  } else {
    if (!std::isfinite(dpi) || dpi <= 0) {
      throw PrintError(fmt::format("{}: dpi must be positive, got {}", out.string(), dpi));
    }
    const double px_per_mm = dpi / kMmPerInch;
    const double w = std::round(page.width_mm * px_per_mm), h = std::round(page.height_mm * px_per_mm);
    if (w < 1 || h < 1 || w > kMaxPngSide || h > kMaxPngSide) {
      throw PrintError(
          fmt::format("{}: {:g} x {:g} px at {:g} dpi is outside 1..{} px", out.string(), w, h, dpi, kMaxPngSide));
    }
    const SurfacePtr surface(cairo_image_surface_create(CAIRO_FORMAT_RGB24, static_cast<int>(w), static_cast<int>(h)),
                             cairo_surface_destroy);
    render_to(surface.get(), px_per_mm, true, page, out);
    cairo_surface_flush(surface.get());
    std::string png;
    check_status(cairo_surface_write_to_png_stream(surface.get(), append_to_string, &png), out);
    bytes = with_phys(png, dpi, out);
  }
  write_file(out, bytes);
}

}  // namespace

GreyImage ideal_marker_image(Family family, int id, int side_px, bool with_quiet_zone) {
  check_id(family, id, "ideal_marker_image");
  if (side_px <= 0 || side_px > 100000) {
    throw PrintError(fmt::format("ideal_marker_image: side_px {} must be 1..100000", side_px));
  }
  const FamilyInfo& info = family_info(family);
  const MarkerPattern pattern(family, id, false);
  const int quiet_px =
      with_quiet_zone
          ? static_cast<int>(std::lround(static_cast<double>(side_px) * info.quiet_zone_cells / info.size_cells))
          : 0;
  const int total = side_px + 2 * quiet_px;
  GreyImage img(total, total, 255);
  // Pattern units per pixel; pixel x covers [x, x+1) from the marker's left edge.
  const double unit = 1.0 / side_px;
  const auto white_at = [&](double px, double py) {
    return is_white(pattern, (px - quiet_px) * unit - 0.5, 0.5 - (py - quiet_px) * unit);
  };
  // Pixels that straddle an edge get their area coverage (4 x 4 samples);
  // the others are pure. Ink and paper are unions of rectangles at least half
  // a cell wide; once that is a pixel or more, each rectangle that reaches
  // into a pixel covers one of its corners, so agreeing corners mean no edge.
  const bool corner_test = side_px >= 2 * info.size_cells;
  constexpr int kSub = 4;
  constexpr double kInset = 1e-6;
  for (int y = 0; y < total; ++y) {
    std::uint8_t* row = img.row(y);
    for (int x = 0; x < total; ++x) {
      if (corner_test) {
        const bool a = white_at(x + kInset, y + kInset);
        if (a == white_at(x + 1 - kInset, y + kInset) && a == white_at(x + kInset, y + 1 - kInset) &&
            a == white_at(x + 1 - kInset, y + 1 - kInset)) {
          row[x] = a ? 255 : 0;
          continue;
        }
      }
      int white = 0;
      for (int j = 0; j < kSub; ++j) {
        for (int i = 0; i < kSub; ++i) white += white_at(x + (i + 0.5) / kSub, y + (j + 0.5) / kSub) ? 1 : 0;
      }
      row[x] = static_cast<std::uint8_t>((white * 255 + kSub * kSub / 2) / (kSub * kSub));
    }
  }
  return img;
}

void write_printable_marker(const PrintSpec& spec, const std::filesystem::path& out) {
  check_extension(out);
  check_id(spec.family, spec.id, out.string());
  if (!std::isfinite(spec.size_mm) || spec.size_mm <= 0) {
    throw PrintError(fmt::format("{}: size_mm must be positive, got {}", out.string(), spec.size_mm));
  }
  check_margin(spec.margin_mm, out);
  const Layout l = layout_for(spec);
  Page page;
  page.width_mm = l.page_w_mm;
  page.height_mm = l.page_h_mm;
  page.title = fmt::format("{} id {}, {:g} mm", family_info(spec.family).name, spec.id, spec.size_mm);
  page.draw = [&](cairo_t* cr) { draw_page(cr, spec, l); };
  write_page(page, spec.dpi, out);
}

double board_page_width_mm(const BoardPrintSpec& spec) { return spec.board.width_m() * 1e3 + 2 * spec.margin_mm; }
double board_page_height_mm(const BoardPrintSpec& spec) { return spec.board.height_m() * 1e3 + 2 * spec.margin_mm; }

void write_printable_board(const BoardPrintSpec& spec, const std::filesystem::path& out) {
  check_extension(out);
  check_board(spec.board);
  check_margin(spec.margin_mm, out);
  Page page;
  page.width_mm = board_page_width_mm(spec);
  page.height_mm = board_page_height_mm(spec);
  page.title = fmt::format("{} board {}x{}", to_string(spec.board.type), spec.board.cols, spec.board.rows);
  page.draw = [&](cairo_t* cr) { draw_board_page(cr, spec); };
  write_page(page, spec.dpi, out);
}

GreyImage board_page_image(const BoardPrintSpec& spec, double px_per_m) {
  check_board(spec.board);
  const std::filesystem::path what = "board_page_image";
  check_margin(spec.margin_mm, what);
  const double px_per_mm = px_per_m / 1e3;
  const double w = std::round(board_page_width_mm(spec) * px_per_mm);
  const double h = std::round(board_page_height_mm(spec) * px_per_mm);
  if (!std::isfinite(px_per_m) || w < 1 || h < 1 || w > kMaxPngSide || h > kMaxPngSide) {
    throw PrintError(
        fmt::format("board_page_image: {} x {} px at {} px/m is outside 1..{} px", w, h, px_per_m, kMaxPngSide));
  }
  // Ink as coverage in an alpha image: paper is what is left.
  const SurfacePtr surface(cairo_image_surface_create(CAIRO_FORMAT_A8, static_cast<int>(w), static_cast<int>(h)),
                           cairo_surface_destroy);
  Page page;
  page.draw = [&](cairo_t* cr) { draw_board_page(cr, spec); };
  render_to(surface.get(), px_per_mm, false, page, what);
  cairo_surface_flush(surface.get());
  GreyImage image(static_cast<int>(w), static_cast<int>(h));
  const unsigned char* data = cairo_image_surface_get_data(surface.get());
  const int stride = cairo_image_surface_get_stride(surface.get());
  for (int y = 0; y < image.height(); ++y) {
    const unsigned char* src = data + static_cast<std::ptrdiff_t>(y) * stride;
    std::uint8_t* dst = image.row(y);
    for (int x = 0; x < image.width(); ++x) dst[x] = static_cast<std::uint8_t>(255 - src[x]);
  }
  return image;
}

}  // namespace markerd::detector
