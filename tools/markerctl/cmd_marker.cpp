// markerctl marker: a printable marker at an exact physical size (SVG, PDF,
// PNG at a dpi), or with --image-px the ideal pixel image of the marker;
// with --board a calibration board, and its board file beside it.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "board_options.hpp"
#include "common.hpp"
#include "markerd/base/ascii.hpp"
#include "markerd/detector/frame8.hpp"
#include "markerd/detector/print.hpp"

namespace markerctl {
namespace {

struct MarkerOptions {
  std::string family = "frame8";
  int id = -1;
  std::string size;
  std::string margin = "10mm";
  double dpi = 300;
  int image_px = 0;
  bool no_quiet_zone = false;
  bool json = false;
  std::string output;
  BoardOptions board;
  CLI::Option* family_option = nullptr;
  CLI::Option* id_option = nullptr;
  CLI::Option* image_px_option = nullptr;
};

std::string lower_extension(const std::filesystem::path& path) {
  return markerd::ascii_lower(path.extension().string());
}

std::string id_ranges() {
  std::string out;
  for (const auto& info : markerd::detector::all_families()) {
    out += fmt::format("{}{} 0-{}", out.empty() ? "" : ", ", info.name, info.id_count - 1);
  }
  return out;
}

int write_image(const MarkerOptions& o, markerd::detector::Family family) {
  if (!cv::haveImageWriter(o.output)) {
    throw usage_error("-o",
                      fmt::format("'{}': no image format for this extension (use .png, .pgm, .bmp, .tif)", o.output));
  }
  const auto& info = markerd::detector::family_info(family);
  if (o.image_px % info.size_cells != 0) {
    std::cerr << fmt::format(
        "markerctl: note: {} px is not a multiple of the {} cells of a {} marker; cell edges will be blurred\n",
        o.image_px, info.size_cells, info.name);
  }
  const markerd::detector::GreyImage image =
      markerd::detector::ideal_marker_image(family, o.id, o.image_px, !o.no_quiet_zone);
  // imwrite only reads the pixels; the const_cast is for cv::Mat's constructor.
  const cv::Mat mat(image.height(), image.width(), CV_8UC1, const_cast<std::uint8_t*>(image.data()));
  bool ok = false;
  try {
    ok = cv::imwrite(o.output, mat);
  } catch (const cv::Exception& e) {
    throw runtime_error(o.output, fmt::format("cannot write the image: {}", e.err));
  }
  if (!ok) throw runtime_error(o.output, "cannot write the image (does the directory exist?)");
  if (o.json) {
    nlohmann::ordered_json j;
    j["output"] = o.output;
    j["family"] = info.name;
    j["id"] = o.id;
    j["width_px"] = image.width();
    j["height_px"] = image.height();
    j["marker_px"] = o.image_px;
    std::cout << json_line(j) << '\n';
    return 0;
  }
  std::cout << fmt::format("{}: {} id {}, {}x{} px image ({} px marker)\n", o.output, info.name, o.id, image.width(),
                           image.height(), o.image_px);
  return 0;
}

std::string print_extension(const MarkerOptions& o) {
  const std::string ext = lower_extension(o.output);
  if (ext != ".svg" && ext != ".pdf" && ext != ".png") {
    throw usage_error("-o", fmt::format("'{}': the format comes from the extension: .svg, .pdf or .png{}", o.output,
                                        o.board.board.empty() ? " (or --image-px N for a pixel image)" : ""));
  }
  return ext;
}

double margin_mm(const MarkerOptions& o) {
  const double margin = parse_length_m(o.margin, BareUnit::millimetre, "--margin") * 1e3;
  if (margin < 0) throw usage_error("--margin", fmt::format("'{}' must not be negative", o.margin));
  return margin;
}

// A calibration board, and beside it (the print's name with .toml) the
// board file that markerctl calibrate --board reads.
int write_board(const MarkerOptions& o) {
  for (const CLI::Option* option : {o.family_option, o.id_option, o.image_px_option}) {
    if (option->count() > 0) throw usage_error(option->get_name(), "is for a single marker, not a --board");
  }
  BoardOptions board = o.board;
  board.size = o.size;  // marker's own --size
  markerd::detector::BoardPrintSpec spec;
  spec.board = board_from_options(board, false);
  spec.margin_mm = margin_mm(o);
  spec.dpi = o.dpi;
  const std::string ext = print_extension(o);
  const std::filesystem::path board_file = std::filesystem::path(o.output).replace_extension(".toml");
  markerd::detector::write_printable_board(spec, o.output);
  try {
    markerd::detector::save_board(spec.board, board_file);
  } catch (const markerd::detector::BoardError& e) {
    throw runtime_error("marker", e.what());
  }
  const double width_mm = markerd::detector::board_page_width_mm(spec);
  const double height_mm = markerd::detector::board_page_height_mm(spec);
  if (o.json) {
    const markerd::detector::BoardSpec& b = spec.board;
    nlohmann::ordered_json j;
    j["output"] = o.output;
    j["board_file"] = board_file.string();
    j["board_type"] = to_string(b.type);
    j["cols"] = b.cols;
    j["rows"] = b.rows;
    j["size_mm"] = b.size_m * 1e3;
    j["marker_size_mm"] = b.type == markerd::detector::BoardType::charuco
                              ? nlohmann::ordered_json(b.marker_size_m * 1e3)
                              : nlohmann::ordered_json(nullptr);
    j["dictionary"] = b.type == markerd::detector::BoardType::charuco ? nlohmann::ordered_json(b.dictionary)
                                                                      : nlohmann::ordered_json(nullptr);
    j["spacing_mm"] = b.type == markerd::detector::BoardType::frame8
                          ? nlohmann::ordered_json(rounded(b.spacing_m * 1e3, 6))
                          : nlohmann::ordered_json(nullptr);
    j["ids"] = b.type == markerd::detector::BoardType::frame8 ? nlohmann::ordered_json(b.ids)
                                                              : nlohmann::ordered_json(nullptr);
    j["points"] = b.point_count();
    j["margin_mm"] = spec.margin_mm;
    j["page_width_mm"] = rounded(width_mm, 3);
    j["page_height_mm"] = rounded(height_mm, 3);
    j["dpi"] = ext == ".png" ? nlohmann::ordered_json(o.dpi) : nlohmann::ordered_json(nullptr);
    std::cout << json_line(j) << '\n';
    return 0;
  }
  std::cout << fmt::format(
      "{}: {}, {:g} mm margin, page {:g} x {:g} mm{}\n{}: the board file (markerctl calibrate "
      "--board {})\n",
      o.output, describe_board(spec.board), spec.margin_mm, rounded(width_mm, 3), rounded(height_mm, 3),
      ext == ".png" ? fmt::format(", {:g} dpi", o.dpi) : std::string(), board_file.string(), board_file.string());
  return 0;
}

int run_marker(const MarkerOptions& o) {
  if (!o.board.board.empty()) return write_board(o);
  for (const CLI::Option* option : {o.board.type_option, o.board.marker_size_option, o.board.spacing_option,
                                    o.board.dictionary_option, o.board.first_id_option}) {
    if (option->count() > 0) throw usage_error(option->get_name(), "is for a calibration board: give --board too");
  }
  if (o.id_option->count() == 0) {
    throw usage_error("--id", "a marker needs its id, e.g. --id 165 (or --board COLSxROWS for a calibration board)");
  }
  const markerd::detector::Family family = parse_family(o.family);
  check_id(family, o.id);
  if (family == markerd::detector::Family::frame8 && markerd::detector::frame8::near_uniform(o.id)) {
    std::cerr << fmt::format(
        "markerctl: note: frame8 id {} is near-uniform (every edge one colour but its end cells), as tiles and "
        "keyboard keys look: it is read less far than other ids{}\n",
        o.id, o.id == 0 || o.id == 255 ? ", and only with uniform_ids" : "");
  }
  if (o.image_px > 0) return write_image(o, family);

  if (o.size.empty()) throw usage_error("--size", "a print needs the marker size, e.g. --size 80mm (or --image-px N)");
  const double size_mm = parse_length_m(o.size, BareUnit::millimetre, "--size") * 1e3;
  if (!(size_mm > 0)) throw usage_error("--size", fmt::format("'{}' must be more than zero", o.size));
  const double margin = margin_mm(o);
  const std::string ext = print_extension(o);
  markerd::detector::PrintSpec spec;
  spec.family = family;
  spec.id = o.id;
  spec.size_mm = size_mm;
  spec.margin_mm = margin;
  spec.dpi = o.dpi;
  markerd::detector::write_printable_marker(spec, o.output);
  if (o.json) {
    nlohmann::ordered_json j;
    j["output"] = o.output;
    j["family"] = markerd::detector::family_info(family).name;
    j["id"] = o.id;
    j["size_mm"] = size_mm;
    j["margin_mm"] = margin;
    j["dpi"] = ext == ".png" ? nlohmann::ordered_json(o.dpi) : nlohmann::ordered_json(nullptr);
    std::cout << json_line(j) << '\n';
    return 0;
  }
  std::cout << fmt::format("{}: {} id {}, {:g} mm marker, {:g} mm margin{}\n", o.output,
                           markerd::detector::family_info(family).name, o.id, size_mm, margin,
                           ext == ".png" ? fmt::format(", {:g} dpi", o.dpi) : std::string());
  return 0;
}

}  // namespace

void add_marker_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<MarkerOptions>();
  CLI::App* app = parent.add_subcommand(
      "marker", "Write a printable marker or calibration board (SVG, PDF or PNG), or a marker's ideal image");
  app->footer(
      "Write a printable marker at an exact physical size. The format comes from the extension of -o:\n"
      ".svg and .pdf are vector files at true size; .png is rendered at --dpi. The page is the marker\n"
      "plus --margin on every side; the family, id and size are printed in the margin beside a 10 mm\n"
      "scale bar (check it after printing: printers like to scale). frame8's hole is drawn as a cut line.\n"
      "With --image-px N, write instead the ideal marker image, N px for the marker's size (plus the\n"
      "quiet zone ArUco and AprilTag need), pixel-exact when N is a multiple of the family's cells\n"
      "(frame8 10, aruco4x4_50 6, tag36h11 8); any format OpenCV writes (.png, .pgm, .bmp, .tif).\n"
      "With --board COLSxROWS, write a calibration board instead (docs/calibration.md): --board-type\n"
      "chessboard (COLSxROWS squares, --size a square), charuco (squares, --size a square, --marker-size\n"
      "the ArUco marker in each white square, --dictionary) or frame8 (COLSxROWS markers, --size a\n"
      "marker, --spacing between them, ids from --first-id up). Beside it, with the extension .toml,\n"
      "goes its board file, which markerctl calibrate --board FILE reads.");
  app->add_option("--family", o->family, "Marker family: " + family_names())->type_name("NAME")->capture_default_str();
  o->family_option = app->get_option("--family");
  o->id_option = app->add_option("--id", o->id, "Marker id: " + id_ranges() + ". Required but for --board");
  auto* size = app->add_option("--size", o->size,
                               "Marker size: frame8's outer edge, the black border of ArUco/AprilTag; with --board "
                               "a square, or a frame8 marker (80mm, 8cm, 0.08m; a bare number is mm). Required "
                               "for a print")
                   ->type_name("LENGTH");
  o->board.size_option = size;
  add_board_options(app, o->board, "Write a calibration board of COLS x ROWS squares (frame8: markers)", "COLSxROWS");
  auto* margin = app->add_option("--margin", o->margin, "Paper around the marker (a bare number is mm)")
                     ->type_name("LENGTH")
                     ->capture_default_str();
  auto* dpi = app->add_option("--dpi", o->dpi, "Resolution of a .png print")
                  ->capture_default_str()
                  ->check(CLI::Range(10.0, 10000.0));
  auto* image_px = app->add_option("--image-px", o->image_px,
                                   "Write the ideal marker image with the marker N px wide instead of a print")
                       ->check(CLI::Range(1, 100000));
  auto* no_quiet = app->add_flag("--no-quiet-zone", o->no_quiet_zone,
                                 "With --image-px: leave out the white quiet zone of ArUco/AprilTag");
  o->image_px_option = image_px;
  image_px->excludes(size)->excludes(margin)->excludes(dpi);
  no_quiet->needs(image_px);
  app->add_flag("--json", o->json, "What was written as one JSON object instead of text");
  app->add_option("-o,--output", o->output, "Output file")->type_name("FILE")->required();
  commands.push_back({app, [o] { return run_marker(*o); }});
}

}  // namespace markerctl
