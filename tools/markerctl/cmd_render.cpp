// markerctl render: one camera view of a printed marker (render_scene), and
// its true corners and pose as one JSON line, so that a render is also the
// truth a test compares a detection against.

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "common.hpp"
#include "markerd/detector/render.hpp"

namespace markerctl {
namespace {

struct RenderOptions {
  std::string dist;
  std::string yaw = "0";
  std::string pitch = "0";
  std::string roll = "0";
  std::string offset_x = "0";
  std::string offset_y = "0";
  std::string family = "frame8";
  int id = -1;
  std::string size = "0.08";
  std::string camera;
  double noise = 0;
  double blur = 0;
  std::string blur_model = "gaussian";
  std::string noise_model = "gaussian";
  double exposure = 1;
  int supersample = 4;
  bool no_clutter = false;
  std::string background = "shapes";
  bool no_distort = false;
  bool cut_hole = false;
  bool json = false;  // the truth line is JSON either way; accepted as every command with output accepts it
  std::string frame = "none";
  std::string insert = "none";
  double frame_reflectance = markerd::detector::CoverFrame{}.reflectance;
  std::string margin = "0";
  std::vector<std::string> cover;
  double cover_depth = 0.2;
  double cover_reflectance = 0.1;
  std::string cover_height = "3cm";
  double background_grey = 128;
  double ambient = 0.3;
  std::uint64_t seed = 1;
  std::string output;
};

markerd::detector::MarkerSide parse_side(const std::string& name) {
  using markerd::detector::MarkerSide;
  if (name == "top") return MarkerSide::top;
  if (name == "right") return MarkerSide::right;
  if (name == "bottom") return MarkerSide::bottom;
  return MarkerSide::left;  // CLI::IsMember has let nothing else through
}

// Truth is printed finer than any detector resolves (1e-6 px, 1e-9 m).
nlohmann::ordered_json point_json(markerd::detector::Point2 p) { return {rounded(p.x, 6), rounded(p.y, 6)}; }

int run_render(const RenderOptions& o) {
  markerd::detector::Scene scene;
  scene.family = parse_family(o.family);
  // 165 is the thesis's example id; other families start at 0.
  scene.id = o.id >= 0 ? o.id : (scene.family == markerd::detector::Family::frame8 ? 165 : 0);
  check_id(scene.family, scene.id);
  scene.marker_size_m = parse_length_m(o.size, BareUnit::metre, "--size");
  if (!(scene.marker_size_m > 0)) throw usage_error("--size", fmt::format("'{}' must be more than zero", o.size));
  const double dist = parse_length_m(o.dist, BareUnit::metre, "--dist");
  if (!(dist > 0)) throw usage_error("--dist", fmt::format("'{}' must be more than zero", o.dist));
  const double yaw = parse_angle_deg(o.yaw, "--yaw");
  const double pitch = parse_angle_deg(o.pitch, "--pitch");
  const double roll = parse_angle_deg(o.roll, "--roll");
  const double offset_x = parse_length_m(o.offset_x, BareUnit::metre, "--offset-x");
  const double offset_y = parse_length_m(o.offset_y, BareUnit::metre, "--offset-y");
  if (!cv::haveImageWriter(o.output)) {
    throw usage_error("-o",
                      fmt::format("'{}': no image format for this extension (use .png, .pgm, .bmp, .tif)", o.output));
  }

  const markerd::detector::CameraModel camera = load_camera(o.camera);
  scene.cut_hole = o.cut_hole;
  scene.pose = markerd::detector::facing_pose(dist, yaw, pitch, roll, offset_x, offset_y);
  scene.exposure = o.exposure;
  scene.blur_sigma_px = o.blur;
  scene.noise_sigma = o.noise;
  // CLI::IsMember has let only the models' names through.
  scene.blur_model =
      o.blur_model == "disc" ? markerd::detector::BlurModel::disc : markerd::detector::BlurModel::gaussian;
  scene.noise_model =
      o.noise_model == "shot" ? markerd::detector::NoiseModel::shot : markerd::detector::NoiseModel::gaussian;
  scene.supersample = o.supersample;
  scene.clutter = !o.no_clutter;
  // CLI::IsMember has let only the kinds' names through.
  scene.background = markerd::detector::background_from_string(o.background).value_or(scene.background);
  scene.distort = !o.no_distort;
  scene.seed = o.seed;
  if (o.frame != "none") {
    scene.frame = o.frame == "socket" ? markerd::detector::socket_frame() : markerd::detector::switch_frame();
    scene.frame->reflectance = static_cast<float>(o.frame_reflectance);
  }
  scene.insert = o.insert == "socket"   ? markerd::detector::Insert::socket
                 : o.insert == "rocker" ? markerd::detector::Insert::rocker
                                        : markerd::detector::Insert::none;
  // A bare number is millimetres, as in `markerctl marker --margin`.
  scene.paper_margin_m = parse_length_m(o.margin, BareUnit::millimetre, "--margin");
  if (scene.paper_margin_m < 0) throw usage_error("--margin", fmt::format("'{}' must not be negative", o.margin));
  const double cover_height = parse_length_m(o.cover_height, BareUnit::metre, "--cover-height");
  if (!(cover_height > 0)) {
    throw usage_error("--cover-height", fmt::format("'{}' must be more than zero", o.cover_height));
  }
  for (const auto& side : o.cover) {
    scene.occluders.push_back(markerd::detector::side_occluder(parse_side(side), scene.marker_size_m, o.cover_depth,
                                                               static_cast<float>(o.cover_reflectance), cover_height));
  }
  scene.background_grey = o.background_grey;
  scene.ambient = o.ambient;

  const markerd::detector::GreyImage image = markerd::detector::render_scene(camera, scene);
  const markerd::detector::Quad corners = markerd::detector::project_marker_corners(camera, scene);

  // imwrite only reads the pixels; the const_cast is for cv::Mat's constructor.
  const cv::Mat mat(image.height(), image.width(), CV_8UC1, const_cast<std::uint8_t*>(image.data()));
  bool ok = false;
  try {
    ok = cv::imwrite(o.output, mat);
  } catch (const cv::Exception& e) {
    throw runtime_error(o.output, fmt::format("cannot write the image: {}", e.err));
  }
  if (!ok) throw runtime_error(o.output, "cannot write the image (does the directory exist?)");

  nlohmann::ordered_json line;
  line["file"] = o.output;
  line["family"] = markerd::detector::family_info(scene.family).name;
  line["id"] = scene.id;
  line["size_m"] = scene.marker_size_m;
  line["corners"] = nlohmann::ordered_json::array();
  for (const auto& c : corners) line["corners"].push_back(point_json(c));
  const Eigen::Vector3d rvec = scene.pose.rvec();
  const Eigen::Quaterniond q = scene.pose.quaternion();
  const Eigen::Vector3d& t = scene.pose.translation;
  line["rvec"] = {rounded(rvec.x(), 9), rounded(rvec.y(), 9), rounded(rvec.z(), 9)};
  line["tvec"] = {rounded(t.x(), 9), rounded(t.y(), 9), rounded(t.z(), 9)};
  line["quaternion"] = {rounded(q.w(), 9), rounded(q.x(), 9), rounded(q.y(), 9), rounded(q.z(), 9)};
  line["width"] = image.width();
  line["height"] = image.height();
  std::cout << json_line(line) << '\n';
  return 0;
}

}  // namespace

void add_render_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<RenderOptions>();
  CLI::App* app = parent.add_subcommand("render", "Render a camera view of a marker and print its true corners");
  app->footer(
      std::string("Render what a camera sees of a printed marker: the marker at --dist in front of the camera,\n"
                  "turned by --yaw about its vertical axis (as the rig's turntable turns it), over a cluttered\n"
                  "background, with lens distortion, blur and noise. Writes the image to -o and prints one JSON\n"
                  "line on stdout: {\"file\", \"family\", \"id\", \"size_m\", \"corners\": [[x,y] x4, TL TR BR BL of\n"
                  "the outer square, pixels], \"rvec\", \"tvec\" (metres), \"quaternion\" [w,x,y,z], \"width\",\n"
                  "\"height\"} - the truth to compare a detection against.\n"
                  "Without --camera, the thesis camera is used:\n  ") +
      thesis_camera_text + ".\nAngles are degrees (30, 30deg, 0.5rad); lengths metres unless a unit is given.");
  app->add_option("--dist", o->dist, "Distance, camera centre to marker centre along the optical axis (0.95, 95cm)")
      ->type_name("LENGTH")
      ->required();
  app->add_option("--yaw", o->yaw, "Turn of the marker about its vertical axis")
      ->type_name("ANGLE")
      ->capture_default_str();
  app->add_option("--pitch", o->pitch, "Tilt of the marker about its horizontal axis")
      ->type_name("ANGLE")
      ->capture_default_str();
  app->add_option("--roll", o->roll, "Turn of the marker in its own plane")->type_name("ANGLE")->capture_default_str();
  app->add_option("--offset-x", o->offset_x, "Move the marker right of the optical axis")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--offset-y", o->offset_y, "Move the marker down from the optical axis")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--family", o->family, "Marker family: " + family_names())->type_name("NAME")->capture_default_str();
  app->add_option("--id", o->id, "Marker id (default 165 for frame8, 0 for the others)");
  app->add_option("--size", o->size, "Marker size (frame8: outer edge; others: black border)")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--camera", o->camera,
                  "Camera calibration (OpenCV's YAML or ROS camera_info); default: the thesis camera")
      ->type_name("FILE");
  app->add_option("--noise", o->noise, "Sensor noise, grey levels (sigma; with --noise-model shot, at mid-grey)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 255.0));
  app->add_option("--noise-model", o->noise_model,
                  "gaussian (the same sigma at every grey), or shot (shot noise on read noise)")
      ->type_name("MODEL")
      ->capture_default_str()
      ->check(CLI::IsMember({"gaussian", "shot"}));
  app->add_option("--blur", o->blur, "Lens blur, pixels (sigma)")->capture_default_str()->check(CLI::Range(0.0, 100.0));
  app->add_option("--blur-model", o->blur_model, "gaussian, or disc (a lens out of focus: a disc of radius 2 sigma)")
      ->type_name("MODEL")
      ->capture_default_str()
      ->check(CLI::IsMember({"gaussian", "disc"}));
  app->add_option("--exposure", o->exposure, "Brightness scale (1: paper at about 225)")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 100.0));
  app->add_option("--supersample", o->supersample, "Samples per pixel along each axis")
      ->capture_default_str()
      ->check(CLI::Range(1, 16));
  app->add_flag("--no-clutter", o->no_clutter, "Plain background instead of random shapes");
  std::vector<std::string> kinds;
  for (const auto kind : markerd::detector::all_backgrounds()) kinds.emplace_back(markerd::detector::to_string(kind));
  app->add_option("--background", o->background,
                  "The clutter: shapes (random shapes), or things that look like markers: tiles, keyboard, "
                  "checkerboard, windows, text, outlets")
      ->check(CLI::IsMember(kinds))
      ->type_name("KIND")
      ->capture_default_str();
  app->add_flag("--no-distort", o->no_distort, "Ignore the camera's lens distortion");
  app->add_flag("--cut-hole", o->cut_hole, "frame8: the hole is cut out (the background shows through)");
  app->add_option("--frame", o->frame,
                  "Glue the print onto a rounded cover frame (its hole cut out): none, socket (86 mm, 10 mm "
                  "high, 6 mm rolls), switch (8 mm high, 3 mm rolls)")
      ->type_name("NAME")
      ->capture_default_str()
      ->check(CLI::IsMember({"none", "socket", "switch"}));
  app->add_option("--frame-reflectance", o->frame_reflectance, "The frame's plastic where the print does not cover it")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app->add_option("--insert", o->insert,
                  "What the opening (or a cut hole) shows: none (the background), socket (a Schuko outlet), "
                  "rocker (a light switch)")
      ->type_name("NAME")
      ->capture_default_str()
      ->check(CLI::IsMember({"none", "socket", "rocker"}));
  app->add_option("--margin", o->margin,
                  "White paper around the marker, as markerctl marker prints it (a bare number is mm)")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--cover", o->cover,
                  "Cover one side of the marker (ring and line) by an object in front of it; repeatable")
      ->type_name("SIDE")
      ->check(CLI::IsMember({"top", "right", "bottom", "left"}));
  app->add_option("--cover-depth", o->cover_depth,
                  "How far the cover reaches in from the marker's outer edge, a share of its size")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 1.0));
  app->add_option("--cover-reflectance", o->cover_reflectance, "The cover's reflectance (0 black .. 1 white)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app->add_option("--cover-height", o->cover_height, "The cover's height above the marker's plane, towards the camera")
      ->type_name("LENGTH")
      ->capture_default_str();
  app->add_option("--background-grey", o->background_grey, "Grey level of the plain background (with --no-clutter)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 255.0));
  app->add_option("--ambient", o->ambient, "Share of unshaded light on a frame's rolls and an insert (1: no shading)")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 1.0));
  app->add_option("--seed", o->seed, "Seed of the clutter and noise")->capture_default_str();
  app->add_flag("--json", o->json, "The truth as one JSON line (printed so with or without it)");
  app->add_option("-o,--output", o->output, "Output image (.png, .pgm, .bmp, .tif)")->type_name("FILE")->required();
  commands.push_back({app, [o] { return run_render(*o); }});
}

}  // namespace markerctl
