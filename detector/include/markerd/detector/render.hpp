#pragma once
// The scene renderer: a printed marker at a pose in front of a camera model,
// over a cluttered background, the way a real camera would see it. It is the
// ground truth of the tests and benchmarks and the seed of the simulated
// camera. Deterministic for a given seed.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/detector/pose.hpp"

namespace markerd::detector {

// What lies at a point of the printed marker: reflectance 0 (ink) .. 1
// (paper), or nothing (the frame8 hole when cut out, and outside the print).
class MarkerPattern {
 public:
  // frame8's hole is cut out when `cut_hole`, printed white otherwise.
  MarkerPattern(Family family, int id, bool cut_hole = false);
  // u, v in units of the family's size: the marker square spans [-0.5, 0.5]
  // (u to the right, v up); the quiet zone of ArUco and AprilTag lies
  // outside it and is printed white.
  [[nodiscard]] std::optional<float> reflectance(double u, double v) const;
  // Half-width of the printed area (marker plus quiet zone), in the same units.
  [[nodiscard]] double printed_half_extent() const { return half_extent_; }
  [[nodiscard]] Family family() const { return family_; }
  [[nodiscard]] int id() const { return id_; }

 private:
  Family family_;
  int id_;
  bool cut_hole_;
  double half_extent_ = 0.5;
  int grid_ = 10;                    // cells across the marker square
  std::vector<std::uint8_t> cells_;  // grid_ x grid_, row 0 at the top; 1 = white
};

// The rounded cover frame of a flush-mounted socket or switch that the print
// is glued onto (SOCKET_FRAME.md). Seen from the front it is a square ring;
// in section, from the outside in: a vertical side from the wall up to the
// outer roll, the roll (a quarter circle) up to the flat band, the band, the
// inner roll (a quarter circle) down towards the opening, a vertical drop.
struct CoverFrame {
  double outer_m = 0.086;          // outer side (square, seen from the front)
  double opening_m = 0.056;        // side of the square opening; the print's hole is cut to it
  double height_m = 0.010;         // from the wall to the flat band
  double outer_roll_m = 0.006;     // radius of the rounding at the outer edge
  double inner_roll_m = 0.006;     // radius of the rounding down into the opening
  double corner_radius_m = 0.010;  // outer corners' rounding seen from the front (the opening's follow, scaled)
  float reflectance = 0.85F;       // the frame's plastic where the print does not cover it
};

// A socket outlet's cover frame (86 mm, 10 mm high, 6 mm rolls: the part of
// issue 18's trials, the defaults above) and a light switch's. Within one
// range socket and switch share the same frame; the switch preset is the flat
// end of the typical parts (8 mm high, 3 mm rolls) so that a second geometry
// is covered. Both take the 80 mm frame8 print: its 56 mm hole is the opening.
CoverFrame socket_frame();
CoverFrame switch_frame();

// The rules between a frame's dimensions (each value's own range is the
// caller's: the renderer and markerd's config differ there). The first one
// broken, as the field it names and why ("opening_m", "must be less than
// outer_m (0.086 m), got 0.09 m"); nothing when the frame is consistent.
struct FrameProblem {
  std::string field;
  std::string why;
};
std::optional<FrameProblem> cover_frame_problem(const CoverFrame& frame);

// What the opening (or a cut hole without a frame) shows. none: the
// background, as a cut hole always did. socket: a Schuko outlet's plate a
// little below the frame's inner edge with its recess (39 mm across, 17.5 mm
// deep, dark inside) and two pin holes (4.8 mm on 19 mm centres, along the
// marker's X). rocker: a switch's rocker filling most of the opening, its top
// a few mm proud of the frame's inner edge, in a dark gap.
enum class Insert { none, socket, rocker };

// How the lens blurs. gaussian: a Gaussian of blur_sigma_px. disc: a lens
// out of focus, a uniform disc of the same second moment (radius twice the
// sigma), whose edges ring where a Gaussian's fade.
enum class BlurModel { gaussian, disc };

// The sensor's noise. gaussian: the same noise_sigma at every grey. shot:
// photon shot noise (its variance grows with the signal) on read noise of
// half noise_sigma, together noise_sigma at mid-grey (128): darker pixels
// are cleaner, lighter ones noisier, as on a real sensor.
enum class NoiseModel { gaussian, shot };

// What the clutter behind the marker is (when Scene::clutter). shapes:
// random rectangles, ellipses, lines, grey ramps, dark square frames,
// checkered patches and short strings over an illumination gradient. The
// others are the things a camera in a house sees that look like a square
// marker, under the same gradient: tiles (a wall of square or oblong tiles
// in lighter or darker grout), keyboard (rows of rounded keys with letters
// on them), checkerboard (a whole calibration board), windows (a facade's
// grid of dark panes in light frames, with mullions), text (a printed page)
// and outlets (socket and switch cover plates without a marker).
enum class Background { shapes, tiles, keyboard, checkerboard, windows, text, outlets };

// Every kind, shapes first; the names as on the command line.
std::span<const Background> all_backgrounds();
std::string_view to_string(Background background);
std::optional<Background> background_from_string(std::string_view name);

// An object in front of the marker: an opaque flat polygon parallel to the
// marker's plane.
struct Occluder {
  std::vector<Eigen::Vector2d> polygon;  // in the marker frame's X, Y (metres), any simple polygon
  double z_m = 0.03;                     // its height above the marker's plane (towards the camera)
  float reflectance = 0.1F;
};

enum class MarkerSide { top, right, bottom, left };

// A flat print of any picture in place of the marker: a calibration board
// (board.hpp's board_page_image), or whatever a test needs in front of the
// camera. Grey levels 0 (ink) to 255 (paper) map linearly onto the print's
// ink and paper reflectances; texels are squares of texel_m a side, read
// between their centres bilinearly. The picture is centred on the marker
// frame's origin, its columns along +X and its top row towards +Y (as the
// marker's); outside it nothing is printed.
struct PlanarPrint {
  GreyImage image;
  double texel_m = 0;
};

// An occluder covering one whole side of the marker from well beyond its
// outer edge to `depth_fraction` of the marker's size in from that edge
// (0.2: the ring and the black line of that side, as in issue 18).
Occluder side_occluder(MarkerSide side, double marker_size_m, double depth_fraction = 0.2, float reflectance = 0.1F,
                       double z_m = 0.03);

struct Scene {
  Family family = Family::frame8;
  int id = 165;
  double marker_size_m = 0.08;
  bool cut_hole = false;
  MarkerPose pose;  // marker frame in the camera frame
  // When set, this picture is printed instead of the marker (family, id,
  // marker_size_m and cut_hole then go unused); a flat print only, with no
  // frame, insert, paper margin or occluders.
  std::shared_ptr<const PlanarPrint> print;

  // Imaging: grey levels of ink and paper under the exposure.
  double exposure = 1.0;  // scales the whole image (1 = paper at ~225)
  double blur_sigma_px = 0.0;
  BlurModel blur_model = BlurModel::gaussian;
  double noise_sigma = 0.0;  // grey levels (noise_model says how it varies with the grey)
  NoiseModel noise_model = NoiseModel::gaussian;
  int jpeg_quality = 0;  // 1..100: the frame goes through JPEG at this quality, as an MJPEG camera sends it; 0: not
  int supersample = 4;   // samples per pixel along each axis
  bool clutter = true;   // a cluttered background (background says which), else the flat background_grey
  Background background = Background::shapes;
  bool distort = true;  // apply the camera's lens distortion
  std::uint64_t seed = 1;

  // What the print is glued onto and what stands in front of it. With all of
  // these at their defaults the marker is the flat print it always was, and
  // renders byte for byte as before they existed.
  std::optional<CoverFrame> frame;  // glued onto a rounded frame (the hole is then cut out)
  Insert insert = Insert::none;     // behind the opening, or behind a cut hole without a frame
  float insert_reflectance = 0.85F;
  double paper_margin_m = 0;  // white paper beyond the marker's outer edge (the print as `markerctl marker` makes it)
  std::vector<Occluder> occluders;
  double background_grey = 128;  // the flat background's grey level when clutter is false
  // Direction towards the light in the camera frame (x right, y down, z
  // forward): above, left of and behind the camera. Shading is Lambertian
  // and normalised so that a surface parallel to the marker's plane shows
  // its reflectance exactly as a flat print does: only the rolls, walls and
  // the insert's faces turned against the plane get lighter or darker.
  Eigen::Vector3d light{-0.3, -0.5, -1.0};
  double ambient = 0.3;  // share of the light that reaches every surface unshaded
};

// A pose looking straight at the marker from `distance_m`, the marker turned
// by `yaw_deg` about its own vertical axis (as the rig's turntable does), and
// `roll_deg` in its plane; offset_px moves it off the optical axis.
MarkerPose facing_pose(double distance_m, double yaw_deg, double pitch_deg = 0, double roll_deg = 0,
                       double offset_x_m = 0, double offset_y_m = 0);

GreyImage render_scene(const CameraModel& camera, const Scene& scene);

// Pixel positions of the marker's outer corners (TL, TR, BR, BL) in the
// rendered image, through the same model as render_scene (truth for tests).
// They are the corners of the flat S x S square in the plane Z = 0: on a
// cover frame that is the plane of the flat band, centred on the opening
// (the pose's meaning on a non-flat marker); the print's own corners lie a
// little below it, on the outer roll.
Quad project_marker_corners(const CameraModel& camera, const Scene& scene, double scale = 1.0);

// Clutter only (the same background render_scene draws), for false-positive tests.
GreyImage render_background(const CameraModel& camera, const Scene& scene);

}  // namespace markerd::detector
