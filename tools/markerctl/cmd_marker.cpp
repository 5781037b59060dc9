// markerctl marker: a printable marker at an exact physical size (SVG, PDF,
// PNG at a dpi), or with --image-px the ideal pixel image of the marker.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

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

int run_marker(const MarkerOptions& o) {
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
  const double margin_mm = parse_length_m(o.margin, BareUnit::millimetre, "--margin") * 1e3;
  if (margin_mm < 0) throw usage_error("--margin", fmt::format("'{}' must not be negative", o.margin));

  const std::string ext = lower_extension(o.output);
  if (ext != ".svg" && ext != ".pdf" && ext != ".png") {
    throw usage_error("-o", fmt::format("'{}': the format comes from the extension: .svg, .pdf or .png "
                                        "(or --image-px N for a pixel image)",
                                        o.output));
  }
  markerd::detector::PrintSpec spec;
  spec.family = family;
  spec.id = o.id;
  spec.size_mm = size_mm;
  spec.margin_mm = margin_mm;
  spec.dpi = o.dpi;
  markerd::detector::write_printable_marker(spec, o.output);
  if (o.json) {
    nlohmann::ordered_json j;
    j["output"] = o.output;
    j["family"] = markerd::detector::family_info(family).name;
    j["id"] = o.id;
    j["size_mm"] = size_mm;
    j["margin_mm"] = margin_mm;
    j["dpi"] = ext == ".png" ? nlohmann::ordered_json(o.dpi) : nlohmann::ordered_json(nullptr);
    std::cout << json_line(j) << '\n';
    return 0;
  }
  std::cout << fmt::format("{}: {} id {}, {:g} mm marker, {:g} mm margin{}\n", o.output,
                           markerd::detector::family_info(family).name, o.id, size_mm, margin_mm,
                           ext == ".png" ? fmt::format(", {:g} dpi", o.dpi) : std::string());
  return 0;
}

}  // namespace

void add_marker_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<MarkerOptions>();
  CLI::App* app = parent.add_subcommand("marker", "Write a printable marker (SVG, PDF or PNG) or its ideal image");
  app->footer(
      "Write a printable marker at an exact physical size. The format comes from the extension of -o:\n"
      ".svg and .pdf are vector files at true size; .png is rendered at --dpi. The page is the marker\n"
      "plus --margin on every side; the family, id and size are printed in the margin beside a 10 mm\n"
      "scale bar (check it after printing: printers like to scale). frame8's hole is drawn as a cut line.\n"
      "With --image-px N, write instead the ideal marker image, N px for the marker's size (plus the\n"
      "quiet zone ArUco and AprilTag need), pixel-exact when N is a multiple of the family's cells\n"
      "(frame8 10, aruco4x4_50 6, tag36h11 8); any format OpenCV writes (.png, .pgm, .bmp, .tif).");
  app->add_option("--family", o->family, "Marker family: " + family_names())->type_name("NAME")->capture_default_str();
  app->add_option("--id", o->id, "Marker id: " + id_ranges())->required();
  auto* size = app->add_option("--size", o->size,
                               "Marker size: frame8's outer edge, the black border of ArUco/AprilTag "
                               "(80mm, 8cm, 0.08m; a bare number is mm). Required for a print")
                   ->type_name("LENGTH");
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
  image_px->excludes(size)->excludes(margin)->excludes(dpi);
  no_quiet->needs(image_px);
  app->add_flag("--json", o->json, "What was written as one JSON object instead of text");
  app->add_option("-o,--output", o->output, "Output file")->type_name("FILE")->required();
  commands.push_back({app, [o] { return run_marker(*o); }});
}

}  // namespace markerctl
