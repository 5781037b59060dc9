#pragma once
// The marker as a solid (internal to the renderer): the print glued onto a
// rounded cover frame or lying flat, what shows through its hole, and the
// objects in front of it, traced one ray at a time. render.cpp keeps the
// camera, the pixels and the background; a scene with none of these things
// never reaches this file (is_flat_print), so flat prints render exactly as
// they did before it existed.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "markerd/detector/render.hpp"

namespace markerd::detector::surface {

// The print's white (paper) and black (ink) reflectances.
inline constexpr float kPaper = 0.88F;
inline constexpr float kInk = 0.05F;

// Throws std::invalid_argument naming the Scene field that is wrong.
void check_surface_inputs(const Scene& scene);

// A flat print with nothing around, behind or in front of it: the scene
// renderer's plane-cutting path.
bool is_flat_print(const Scene& scene);

struct RaySample {
  bool background = true;  // the pixel's background shows (wall, clutter)
  float reflectance = 0;   // otherwise: reflectance times shading
};

class SurfaceModel {
 public:
  // `pattern` must outlive the model; it is the print with its hole cut out
  // whenever there is a frame.
  SurfaceModel(const Scene& scene, const MarkerPattern& pattern);

  // What a ray from `origin` along `dir` (marker frame, metres; dir need not
  // be a unit vector) sees first.
  [[nodiscard]] RaySample trace(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const;

  // Closed polylines (marker frame, metres) whose projections enclose every
  // point that trace() can hit, for the renderer's bounding box.
  [[nodiscard]] std::vector<std::vector<Eigen::Vector3d>> outlines() const;

 private:
  struct Polygon {
    std::vector<Eigen::Vector2d> points;
    Eigen::Vector2d lo, hi;  // bounding box, for a cheap rejection
    double z = 0;
    float reflectance = 0;
  };
  // A square with rounded corners, centred on the origin, in plan.
  struct RoundedSquare {
    double half = 0;
    double radius = 0;
    [[nodiscard]] double distance(double x, double y) const;          // signed: negative inside
    [[nodiscard]] Eigen::Vector2d outward(double x, double y) const;  // unit gradient of distance()
  };
  enum class Region : std::uint8_t { wall, frame, plate, recess, pin, rocker, gap };
  struct Height {
    double z;
    Region region;
    // Plan distance from this point within which the height is z all
    // round (0 on a roll): the march's safe step over empty space.
    double free = 0;
  };

  [[nodiscard]] Height frame_height(double x, double y) const;
  [[nodiscard]] Height insert_height(double x, double y) const;
  [[nodiscard]] Height height(double x, double y) const {
    return has_frame_ ? frame_height(x, y) : insert_height(x, y);
  }
  // Marches the height field from s0 (at the top, z = 0, where the height
  // is h0) to s1 (below its lowest level) and shades the first point below it.
  [[nodiscard]] RaySample march(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double s0, double s1,
                                Height h0) const;
  // `h` is the height at p's plan position.
  [[nodiscard]] RaySample shade_hit(const Eigen::Vector3d& p, const Height& h) const;
  [[nodiscard]] RaySample shade_frame(const Eigen::Vector3d& p, bool on_face) const;
  // The print, the paper margin or the plastic under print coordinates (metres).
  [[nodiscard]] float print_or(const Eigen::Vector2d& print_xy, float otherwise) const;
  [[nodiscard]] float shading(const Eigen::Vector3d& normal) const;
  [[nodiscard]] bool occluded(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double before_s,
                              float& reflectance) const;

  const MarkerPattern& pattern_;
  double size_m_;
  double print_half_m_;  // the printed marker (quiet zone included)
  double paper_half_m_;  // the paper: print plus margin
  bool has_frame_;
  CoverFrame frame_;  // the scene's, or the default one that sets an insert's depth
  RoundedSquare outer_, opening_, rocker_;
  Insert insert_;
  float insert_reflectance_;
  double plate_z_ = 0, recess_z_ = 0, pin_z_ = 0, rocker_z_ = 0, gap_z_ = 0;
  double lowest_z_ = 0;    // nothing lies below
  Eigen::Vector3d light_;  // unit, marker frame
  double ambient_;
  double flat_shade_;  // the unnormalised shading of the marker's plane
  std::vector<Polygon> occluders_;
};

}  // namespace markerd::detector::surface
