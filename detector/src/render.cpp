#include "markerd/detector/render.hpp"

#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <numbers>
#include <opencv2/aruco.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "markerd/detector/frame8.hpp"
#include "render_background.hpp"
#include "render_random.hpp"
#include "render_surface.hpp"

namespace markerd::detector {
namespace {

using render::Random;
using surface::kInk;
using surface::kPaper;
// The noise stream is independent of the clutter stream, so that changing the
// noise level does not move the clutter.
constexpr std::uint64_t kNoiseSeedMix = 0x9E3779B97F4A7C15ULL;

// Sensor noise: a frame needs 300k normal variates, which from the polar
// method cost as much as the whole marker. Instead each 16 bits of the
// engine's output pick one of 65536 equiprobable quantiles of the standard
// normal: four variates per engine call, the distribution exact to 1e-5 in
// probability, its tails cut at 4.3 sigma (well past what matters to a grey
// level).
class NormalQuantiles {
 public:
  static constexpr int kBits = 16;
  static constexpr int kSize = 1 << kBits;

  NormalQuantiles() {
    table_.resize(kSize);
    for (int i = 0; i < kSize / 2; ++i) {
      // Upper half by Newton's method on the normal CDF, mirrored below.
      const double p = (kSize / 2.0 + i + 0.5) / kSize;
      double x = 0;
      for (int iter = 0; iter < 100; ++iter) {
        const double cdf = 0.5 * std::erfc(-x / std::numbers::sqrt2);
        const double pdf = std::exp(-0.5 * x * x) / std::sqrt(2 * std::numbers::pi);
        const double step = (cdf - p) / pdf;
        x -= step;
        if (std::abs(step) < 1e-12) break;
      }
      table_[static_cast<std::size_t>(kSize / 2 + i)] = static_cast<float>(x);
      table_[static_cast<std::size_t>(kSize / 2 - 1 - i)] = static_cast<float>(-x);
    }
  }
  [[nodiscard]] float operator[](std::uint64_t index) const { return table_[index & (kSize - 1)]; }

 private:
  std::vector<float> table_;
};

const NormalQuantiles& normal_quantiles() {
  static const NormalQuantiles table;
  return table;
}

Eigen::Matrix3d rot_x(double rad) { return Eigen::AngleAxisd(rad, Eigen::Vector3d::UnitX()).toRotationMatrix(); }
Eigen::Matrix3d rot_y(double rad) { return Eigen::AngleAxisd(rad, Eigen::Vector3d::UnitY()).toRotationMatrix(); }
Eigen::Matrix3d rot_z(double rad) { return Eigen::AngleAxisd(rad, Eigen::Vector3d::UnitZ()).toRotationMatrix(); }
double deg(double d) { return d * std::numbers::pi / 180.0; }

void check_id(Family family, int id) {
  const FamilyInfo& info = family_info(family);
  if (id < 0 || id >= info.id_count) {
    throw std::out_of_range(fmt::format("{}: id {} is out of range (0..{})", info.name, id, info.id_count - 1));
  }
}

// A uniform disc of `radius` pixels, its rim pixels weighted by the share of
// them inside (16 x 16 samples each), normalised to sum 1.
cv::Mat disc_kernel(double radius) {
  const int half = static_cast<int>(std::ceil(radius));
  cv::Mat kernel(2 * half + 1, 2 * half + 1, CV_32F);
  constexpr int kSamples = 16;
  double sum = 0;
  for (int y = -half; y <= half; ++y) {
    for (int x = -half; x <= half; ++x) {
      int inside = 0;
      for (int sy = 0; sy < kSamples; ++sy) {
        for (int sx = 0; sx < kSamples; ++sx) {
          const double px = x - 0.5 + (sx + 0.5) / kSamples, py = y - 0.5 + (sy + 0.5) / kSamples;
          inside += px * px + py * py <= radius * radius ? 1 : 0;
        }
      }
      const double w = static_cast<double>(inside) / (kSamples * kSamples);
      kernel.at<float>(y + half, x + half) = static_cast<float>(w);
      sum += w;
    }
  }
  kernel /= sum;
  return kernel;
}

// Encodes and decodes the frame as JPEG (baseline, 4:2:0 does not apply to
// grey), in place.
void through_jpeg(GreyImage& image, int quality) {
  const cv::Mat view(image.height(), image.width(), CV_8U, image.data());
  std::vector<std::uint8_t> encoded;
  if (!cv::imencode(".jpg", view, encoded, {cv::IMWRITE_JPEG_QUALITY, quality})) {
    throw std::runtime_error("render: JPEG encoding failed");
  }
  const cv::Mat decoded = cv::imdecode(encoded, cv::IMREAD_GRAYSCALE);
  if (decoded.size() != view.size()) throw std::runtime_error("render: JPEG decoding gave another size");
  decoded.copyTo(view);
}

void check_inputs(const CameraModel& camera, const Scene& scene) {
  if (camera.width <= 0 || camera.height <= 0) throw std::invalid_argument("render: camera has no image size");
  if (!(camera.fx > 0) || !(camera.fy > 0)) throw std::invalid_argument("render: camera needs positive focal lengths");
  if (!(scene.marker_size_m > 0)) throw std::invalid_argument("render: marker_size_m must be positive");
  if (!std::isfinite(scene.exposure) || scene.exposure < 0) throw std::invalid_argument("render: bad exposure");
  if (!std::isfinite(scene.blur_sigma_px) || !std::isfinite(scene.noise_sigma)) {
    throw std::invalid_argument("render: blur and noise must be finite");
  }
  if (scene.jpeg_quality < 0 || scene.jpeg_quality > 100) {
    throw std::invalid_argument("render: jpeg_quality must be 0 (none) to 100");
  }
  check_id(scene.family, scene.id);
  surface::check_surface_inputs(scene);
  if (scene.print) {
    const PlanarPrint& p = *scene.print;
    if (p.image.empty()) throw std::invalid_argument("render: print.image is empty");
    if (!std::isfinite(p.texel_m) || !(p.texel_m > 0)) {
      throw std::invalid_argument(fmt::format("render: print.texel_m must be more than zero, got {}", p.texel_m));
    }
    if (!surface::is_flat_print(scene) || scene.cut_hole || scene.insert != Insert::none) {
      throw std::invalid_argument("render: a print is rendered flat: no frame, insert, cut hole, margin or occluders");
    }
  }
}

// A PlanarPrint's reflectance at (x, y) metres in the marker frame; none
// outside it (and everywhere when there is no print).
class PrintSampler {
 public:
  explicit PrintSampler(const PlanarPrint* print) : image_(print != nullptr ? &print->image : nullptr) {
    if (print == nullptr) return;
    per_m_ = 1.0 / print->texel_m;
    width_ = print->image.width();
    height_ = print->image.height();
  }

  [[nodiscard]] std::optional<float> operator()(double x, double y) const {
    const double u = x * per_m_ + 0.5 * width_;   // texels from the left edge
    const double v = 0.5 * height_ - y * per_m_;  // from the top edge
    // Written so that NaN falls outside; without a print the extent is empty.
    if (!(u >= 0 && u < width_ && v >= 0 && v < height_)) return std::nullopt;
    // Bilinear between texel centres (at half-integers), the edge texels
    // held to the picture's edge: an edge between ink and paper that cairo
    // drew as one grey texel lies where that grey says, not on a texel's side.
    const double fu = u - 0.5, fv = v - 0.5;
    const double iu = std::floor(fu), iv = std::floor(fv);
    const auto a = static_cast<float>(fu - iu), b = static_cast<float>(fv - iv);
    const int i0 = std::clamp(static_cast<int>(iu), 0, width_ - 1), i1 = std::min(i0 + 1, width_ - 1);
    const int j0 = std::clamp(static_cast<int>(iv), 0, height_ - 1), j1 = std::min(j0 + 1, height_ - 1);
    const auto at = [this](int i, int j) { return static_cast<float>(image_->at(i, j)); };
    const float top = at(i0, j0) + (at(i1, j0) - at(i0, j0)) * a;
    const float bottom = at(i0, j1) + (at(i1, j1) - at(i0, j1)) * a;
    const float grey = top + (bottom - top) * b;
    return kInk + (kPaper - kInk) * (grey / 255.0F);
  }

 private:
  const GreyImage* image_;
  double per_m_ = 0;
  int width_ = 0;
  int height_ = 0;
};

// The camera's view of a marker-frame point (in metres) as a pixel; nullopt
// behind the camera.
std::optional<Point2> project_point(const CameraModel& camera, const Scene& scene, const Eigen::Vector3d& p) {
  const Eigen::Vector3d c = scene.pose.rotation * p + scene.pose.translation;
  if (!(c.z() > 1e-9)) return std::nullopt;
  const Point2 n{c.x() / c.z(), c.y() / c.z()};
  if (scene.distort) return camera.normalized_to_pixel(n);
  return Point2{camera.fx * n.x + camera.cx, camera.fy * n.y + camera.cy};
}

// The ideal normalized point that camera.distort() maps to `d`, by Newton's
// method from `start` (a neighbour's solution): the camera's own undistort()
// starts cold at every call, which made it most of a frame's render time.
Point2 invert_distortion(const CameraModel& camera, Point2 d, Point2 start) {
  Point2 p = start;
  for (int iter = 0; iter < 12; ++iter) {
    const Point2 f = camera.distort(p);
    const double ex = f.x - d.x, ey = f.y - d.y;
    if (ex * ex + ey * ey < 1e-26) return p;
    constexpr double h = 1e-7;
    const Point2 fx = camera.distort({p.x + h, p.y});
    const Point2 fy = camera.distort({p.x, p.y + h});
    const double a = (fx.x - f.x) / h, b = (fy.x - f.x) / h;
    const double c = (fx.y - f.y) / h, e = (fy.y - f.y) / h;
    const double det = a * e - b * c;
    if (!(std::abs(det) > 1e-12)) break;
    p.x -= (e * ex - b * ey) / det;
    p.y -= (-c * ex + a * ey) / det;
  }
  return camera.undistort(d);  // no convergence from here: the careful way
}

// Marker pixels: each pixel of the marker's bounding box is the mean of
// supersample^2 rays through it. A flat print's rays are cut with its plane
// (the path every flat scene has always taken, byte for byte); anything
// else (a frame, a margin, an insert, occluders) is traced through the
// surface model.
void draw_marker(cv::Mat& image, const CameraModel& camera, const Scene& scene) {
  // On a frame the print's hole is always cut out: it is glued around the opening.
  const MarkerPattern pattern(scene.family, scene.id, scene.cut_hole || scene.frame.has_value());
  // A print's plane is carried in metres, the marker's in units of its size.
  const PrintSampler picture(scene.print.get());
  const double s = scene.print ? 1.0 : scene.marker_size_m;
  const Eigen::Matrix3d& r = scene.pose.rotation;
  const Eigen::Vector3d& t = scene.pose.translation;
  std::optional<surface::SurfaceModel> solid;
  if (!surface::is_flat_print(scene)) solid.emplace(scene, pattern);

  // The plane's homography: marker (u, v, 1) in units of S -> camera point.
  Eigen::Matrix3d h;
  h.col(0) = r.col(0) * s;
  h.col(1) = r.col(1) * s;
  h.col(2) = t;
  // Seen edge-on a flat marker has no area; a solid one still has its depth.
  if (!solid && std::abs(h.determinant()) < 1e-15) return;
  // Lattice rays are carried mapped to the plane's (u, v, w) for the flat
  // print, and as directions in the marker frame (metres) for the solid.
  const Eigen::Matrix3d to_marker = solid ? Eigen::Matrix3d(r.transpose()) : Eigen::Matrix3d(h.inverse());
  const Eigen::Vector3d eye = -(r.transpose() * t);  // the camera centre in the marker frame
  // Seen from behind, a print shows the blank back of the paper.
  const bool front = r.col(2).dot(t) < 0;

  // Bounding box from the outlines (the printed square, or the solid's),
  // densely sampled because lens distortion bends the edges.
  std::vector<std::vector<Eigen::Vector3d>> outlines;
  if (solid) {
    outlines = solid->outlines();
  } else if (scene.print) {
    const double ex = 0.5 * scene.print->image.width() * scene.print->texel_m;
    const double ey = 0.5 * scene.print->image.height() * scene.print->texel_m;
    outlines.push_back({{-ex, ey, 0}, {ex, ey, 0}, {ex, -ey, 0}, {-ex, -ey, 0}});
  } else {
    const double e = pattern.printed_half_extent() * s;
    outlines.push_back({{-e, e, 0}, {e, e, 0}, {e, -e, 0}, {-e, -e, 0}});
  }
  int x0 = 0, y0 = 0, x1 = image.cols - 1, y1 = image.rows - 1;
  {
    double minx = 1e300, miny = 1e300, maxx = -1e300, maxy = -1e300;
    bool behind = false;
    constexpr int kSteps = 64;
    for (const auto& line : outlines) {
      for (std::size_t k = 0; k < line.size() && !behind; ++k) {
        const Eigen::Vector3d& from = line[k];
        const Eigen::Vector3d& to = line[(k + 1) % line.size()];
        for (int i = 0; i < kSteps; ++i) {
          const auto px = project_point(camera, scene, from + (to - from) * i / kSteps);
          if (!px) {
            behind = true;
            break;
          }
          minx = std::min(minx, px->x), maxx = std::max(maxx, px->x);
          miny = std::min(miny, px->y), maxy = std::max(maxy, px->y);
        }
      }
    }
    if (!behind) {
      constexpr double kMargin = 2;
      const auto clampi = [](double v, int lo, int hi) {
        return static_cast<int>(std::clamp(v, static_cast<double>(lo), static_cast<double>(hi)));
      };
      x0 = clampi(std::floor(minx - kMargin), 0, image.cols);
      x1 = clampi(std::ceil(maxx + kMargin), -1, image.cols - 1);
      y0 = clampi(std::floor(miny - kMargin), 0, image.rows);
      y1 = clampi(std::ceil(maxy + kMargin), -1, image.rows - 1);
    }
  }
  if (x1 < x0 || y1 < y0) return;

  // Rays are computed exactly at the pixel corners and interpolated
  // bilinearly inside the pixel: undistortion is iterative and too slow per
  // sample, and over one pixel the inverse distortion is linear to better
  // than 1e-3 px even at the corners of the thesis's strong lens (6e-4 px
  // measured). The ray is carried already mapped through to_marker (a linear
  // map, so the interpolation commutes with it).
  const bool use_distortion = scene.distort && camera.has_distortion();
  const int nx = x1 - x0 + 2;
  std::vector<Point2> solved(static_cast<std::size_t>(nx));
  std::optional<Point2> row_start;  // the previous row's first solution
  const auto lattice_row = [&](double py, std::vector<Eigen::Vector3d>& rays) {
    for (int i = 0; i < nx; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const Point2 d{(x0 - 0.5 + i - camera.cx) / camera.fx, (py - camera.cy) / camera.fy};
      Point2 n = d;
      if (use_distortion) {
        // Warm start by extrapolating along the row: Newton then needs one
        // or two steps, against ten or more from a cold start.
        Point2 start = d;
        if (i >= 2) {
          start = 2.0 * solved[k - 1] - solved[k - 2];
        } else if (i == 1) {
          start = solved[0] + Point2{1.0 / camera.fx, 0};
        } else if (row_start) {
          start = *row_start + Point2{0, 1.0 / camera.fy};
        }
        n = invert_distortion(camera, d, start);
        solved[k] = n;
        if (i == 0) row_start = n;
      }
      rays[k] = to_marker * Eigen::Vector3d(n.x, n.y, 1.0);
    }
  };
  std::vector<Eigen::Vector3d> upper(static_cast<std::size_t>(nx)), lower(static_cast<std::size_t>(nx));
  lattice_row(y0 - 0.5, upper);

  const int ss = std::clamp(scene.supersample, 1, 32);
  std::vector<double> offsets(static_cast<std::size_t>(ss));
  for (int i = 0; i < ss; ++i) offsets[static_cast<std::size_t>(i)] = (i + 0.5) / ss;
  const double samples = static_cast<double>(ss) * ss;
  const double level = scene.exposure * 255.0;

  // The per-sample choice of path is made once, at compile time: the flat
  // path's inner loop is exactly what it was before there were solids and
  // prints.
  const auto draw_rows = [&]<bool kSolid, bool kPicture>() {
    for (int y = y0; y <= y1; ++y) {
      lattice_row(y + 0.5, lower);
      auto* row = image.ptr<float>(y);
      for (int x = x0; x <= x1; ++x) {
        const auto k = static_cast<std::size_t>(x - x0);
        const Eigen::Vector3d& a = upper[k];
        const Eigen::Vector3d& b = upper[k + 1];
        const Eigen::Vector3d& c = lower[k];
        const Eigen::Vector3d& d = lower[k + 1];
        double reflect = 0;
        int misses = 0;
        for (double fy : offsets) {
          const Eigen::Vector3d left = a + (c - a) * fy;
          const Eigen::Vector3d right = b + (d - b) * fy;
          for (double fx : offsets) {
            const Eigen::Vector3d m = left + (right - left) * fx;
            if constexpr (kSolid) {
              const surface::RaySample hit = solid->trace(eye, m);
              if (hit.background) {
                ++misses;
              } else {
                reflect += hit.reflectance;
              }
            } else {
              // w <= 0: the ray meets the plane behind the camera, or never.
              std::optional<float> rf;
              if constexpr (kPicture) {
                if (m.z() > 0) rf = picture(m.x() / m.z(), m.y() / m.z());
              } else {
                if (m.z() > 0) rf = pattern.reflectance(m.x() / m.z(), m.y() / m.z());
              }
              if (rf) {
                reflect += front ? *rf : kPaper;
              } else {
                ++misses;
              }
            }
          }
        }
        row[x] = static_cast<float>((reflect * level + misses * static_cast<double>(row[x])) / samples);
      }
      std::swap(upper, lower);
    }
  };
  if (solid) {
    draw_rows.operator()<true, false>();
  } else if (scene.print) {
    draw_rows.operator()<false, true>();
  } else {
    draw_rows.operator()<false, false>();
  }
}

GreyImage render_impl(const CameraModel& camera, const Scene& scene, bool with_marker) {
  check_inputs(camera, scene);
  cv::Mat image;
  render::make_background(camera.width, camera.height, scene).convertTo(image, CV_32F, scene.exposure);
  if (with_marker) draw_marker(image, camera, scene);
  if (scene.blur_sigma_px > 0) {
    if (scene.blur_model == BlurModel::disc) {
      cv::filter2D(image, image, -1, disc_kernel(2 * scene.blur_sigma_px), cv::Point(-1, -1), 0, cv::BORDER_REPLICATE);
    } else {
      cv::GaussianBlur(image, image, cv::Size(0, 0), scene.blur_sigma_px, scene.blur_sigma_px, cv::BORDER_REPLICATE);
    }
  }
  GreyImage out(camera.width, camera.height);
  Random noise(scene.seed ^ kNoiseSeedMix);
  const NormalQuantiles* normal = scene.noise_sigma > 0 ? &normal_quantiles() : nullptr;
  const auto sigma = static_cast<float>(scene.noise_sigma);
  // Shot noise: variance read^2 + v / gain, read = sigma / 2, and sigma^2
  // in all at v = 128.
  const bool shot = scene.noise_model == NoiseModel::shot;
  const float read_variance = 0.25F * sigma * sigma;
  const float per_grey = 0.75F * sigma * sigma / 128.0F;
  std::uint64_t bits = 0;
  int left = 0;  // unused 16-bit fields in `bits`
  for (int y = 0; y < camera.height; ++y) {
    const float* src = image.ptr<float>(y);
    std::uint8_t* dst = out.row(y);
    for (int x = 0; x < camera.width; ++x) {
      float v = src[x];
      if (normal != nullptr) {
        if (left == 0) {
          bits = noise.bits();
          left = 4;
        }
        const float s = shot ? std::sqrt(read_variance + per_grey * std::max(v, 0.0F)) : sigma;
        v += s * (*normal)[bits];
        bits >>= NormalQuantiles::kBits;
        --left;
      }
      dst[x] = static_cast<std::uint8_t>(std::clamp(std::floor(v + 0.5F), 0.0F, 255.0F));
    }
  }
  if (scene.jpeg_quality > 0) through_jpeg(out, scene.jpeg_quality);
  return out;
}

}  // namespace

MarkerPattern::MarkerPattern(Family family, int id, bool cut_hole) : family_(family), id_(id), cut_hole_(cut_hole) {
  check_id(family, id);
  const FamilyInfo& info = family_info(family);
  grid_ = info.size_cells;
  half_extent_ = 0.5 * (info.size_cells + 2 * info.quiet_zone_cells) / info.size_cells;
  cells_.assign(static_cast<std::size_t>(grid_ * grid_), 1);
  switch (family) {
    case Family::frame8: {
      const auto ring = frame8::ring_cells(id);
      cells_.assign(ring.begin(), ring.end());
      break;
    }
    case Family::aruco4x4_50: {
      const auto dict = cv::aruco::getPredefinedDictionary(cv::aruco::DICT_4X4_50);
      cv::Mat bits;
      // One pixel per cell, border included: exactly the cell grid.
      cv::aruco::drawMarker(dict, id, grid_, bits, 1);
      for (int r = 0; r < grid_; ++r) {
        for (int c = 0; c < grid_; ++c) {
          cells_[static_cast<std::size_t>(r * grid_ + c)] = bits.at<std::uint8_t>(r, c) > 127 ? 1 : 0;
        }
      }
      break;
    }
    case Family::tag36h11: {
      const std::unique_ptr<apriltag_family_t, void (*)(apriltag_family_t*)> fam(tag36h11_create(), tag36h11_destroy);
      if (fam->width_at_border != grid_ || fam->reversed_border ||
          fam->total_width != grid_ + 2 * info.quiet_zone_cells) {
        throw std::logic_error("tag36h11: unexpected layout in libapriltag");
      }
      // As libapriltag's apriltag_to_image (whose image_u8_destroy lives in
      // libapriltag-utils, which pkg-config does not link): black border,
      // then the code's bits, most significant first, at (bit_x, bit_y)
      // counted from the black border's corner.
      std::fill(cells_.begin(), cells_.end(), 0);
      const std::uint64_t code = fam->codes[id];
      for (std::uint32_t i = 0; i < fam->nbits; ++i) {
        if ((code >> (fam->nbits - 1 - i)) & 1U) {
          cells_[static_cast<std::size_t>(fam->bit_y[i]) * static_cast<std::size_t>(grid_) + fam->bit_x[i]] = 1;
        }
      }
      break;
    }
  }
}

std::optional<float> MarkerPattern::reflectance(double u, double v) const {
  // Written so that NaN falls outside.
  if (!(std::abs(u) <= half_extent_ && std::abs(v) <= half_extent_)) return std::nullopt;
  if (!(std::abs(u) <= 0.5 && std::abs(v) <= 0.5)) return kPaper;  // quiet zone
  const double gx = (u + 0.5) * grid_;
  const double gy = (0.5 - v) * grid_;
  const int col = std::min(static_cast<int>(gx), grid_ - 1);
  const int row = std::min(static_cast<int>(gy), grid_ - 1);
  const std::uint8_t cell = cells_[static_cast<std::size_t>(row * grid_ + col)];
  if (cell == 2) {  // frame8 inside the ring: the line, then the hole
    const double in = std::min(std::min(gx, grid_ - gx), std::min(gy, grid_ - gy));
    if (in < frame8::line_inner) return kInk;
    if (cut_hole_) return std::nullopt;
    return kPaper;
  }
  return cell != 0 ? kPaper : kInk;
}

MarkerPose facing_pose(double distance_m, double yaw_deg, double pitch_deg, double roll_deg, double offset_x_m,
                       double offset_y_m) {
  Eigen::Matrix3d facing;
  facing << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  MarkerPose pose;
  pose.rotation = facing * rot_y(deg(yaw_deg)) * rot_x(deg(pitch_deg)) * rot_z(deg(roll_deg));
  pose.translation = Eigen::Vector3d(offset_x_m, offset_y_m, distance_m);
  return pose;
}

GreyImage render_scene(const CameraModel& camera, const Scene& scene) { return render_impl(camera, scene, true); }

GreyImage render_background(const CameraModel& camera, const Scene& scene) { return render_impl(camera, scene, false); }

Quad project_marker_corners(const CameraModel& camera, const Scene& scene, double scale) {
  const double h = scene.marker_size_m * scale / 2;
  static constexpr std::array<std::array<double, 2>, 4> signs{{{-1, 1}, {1, 1}, {1, -1}, {-1, -1}}};
  Quad quad;
  for (std::size_t k = 0; k < 4; ++k) {
    const auto px = project_point(camera, scene, Eigen::Vector3d(signs[k][0] * h, signs[k][1] * h, 0));
    // Behind the camera: no pixel; NaN makes every later comparison fail loudly.
    quad[k] = px.value_or(Point2{std::nan(""), std::nan("")});
  }
  return quad;
}

}  // namespace markerd::detector
