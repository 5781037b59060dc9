#include "markerd/daemon/frame_annotation.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "markerd/base/ascii.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/pose.hpp"

namespace markerd::daemon {

namespace {

cv::Scalar colour(const std::uint8_t (&bgr)[3]) { return {double(bgr[0]), double(bgr[1]), double(bgr[2])}; }

cv::Point2d pixel(const detector::Point2& p) { return {p.x, p.y}; }

// Line widths and text grow with the image, so that a 1920x1440 frame scaled
// down in a browser shows them as a 640x480 one does.
double scale_of(const cv::Mat& image) { return std::max(1.0, image.cols / 640.0); }

int thickness(const cv::Mat& image, double base = 1.0) {
  return std::max(1, static_cast<int>(std::lround(base * scale_of(image))));
}

// Sub-pixel lines: OpenCV's shift of 4 bits keeps a quarter of a pixel.
void line(cv::Mat& image, const cv::Point2d& a, const cv::Point2d& b, const cv::Scalar& c, int width) {
  constexpr int kShift = 4;
  constexpr double kOne = 1 << kShift;
  cv::line(image, {static_cast<int>(std::lround(a.x * kOne)), static_cast<int>(std::lround(a.y * kOne))},
           {static_cast<int>(std::lround(b.x * kOne)), static_cast<int>(std::lround(b.y * kOne))}, c, width,
           cv::LINE_AA, kShift);
}

// Text in `c` on a dark box, legible over any background.
void label(cv::Mat& image, const std::string& text, cv::Point origin, const cv::Scalar& c) {
  const double font_scale = 0.45 * scale_of(image);
  const int width = thickness(image);
  int baseline = 0;
  const cv::Size size = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, font_scale, width, &baseline);
  cv::rectangle(image, {origin.x - 2, origin.y - size.height - 3}, {origin.x + size.width + 2, origin.y + baseline + 1},
                cv::Scalar(0, 0, 0), cv::FILLED);
  cv::putText(image, text, origin, cv::FONT_HERSHEY_SIMPLEX, font_scale, c, width, cv::LINE_AA);
}

// Points of the marker frame in pixels; nothing for a point behind the
// camera, which has no place in the image.
std::optional<cv::Point2d> projected(const detector::CameraModel& camera, const detector::MarkerPose& pose,
                                     const Eigen::Vector3d& point) {
  const Eigen::Vector3d in_camera = pose.rotation * point + pose.translation;
  if (!(in_camera.z() > 1e-6)) return std::nullopt;
  const detector::Point2 p = detector::project(camera, pose, point);
  if (!std::isfinite(p.x) || !std::isfinite(p.y)) return std::nullopt;
  return pixel(p);
}

void draw_square(cv::Mat& image, const detector::CameraModel& camera, const detector::MarkerPose& pose, double side,
                 const cv::Scalar& c, int width) {
  const double h = side / 2;
  // Each edge in steps, so that a distorting lens bends it as it bends the print.
  const Eigen::Vector3d corners[4] = {{-h, h, 0}, {h, h, 0}, {h, -h, 0}, {-h, -h, 0}};
  constexpr int kSteps = 8;
  for (int e = 0; e < 4; ++e) {
    const Eigen::Vector3d& a = corners[e];
    const Eigen::Vector3d& b = corners[(e + 1) % 4];
    for (int s = 0; s < kSteps; ++s) {
      const auto p = projected(camera, pose, a + (b - a) * (double(s) / kSteps));
      const auto q = projected(camera, pose, a + (b - a) * (double(s + 1) / kSteps));
      if (p && q) line(image, *p, *q, c, width);
    }
  }
}

void draw_axes(cv::Mat& image, const detector::CameraModel& camera, const detector::MarkerPose& pose, double length) {
  const auto origin = projected(camera, pose, Eigen::Vector3d::Zero());
  if (!origin) return;
  const std::pair<Eigen::Vector3d, cv::Scalar> axes[3] = {
      {{length, 0, 0}, colour(AnnotationColours::kAxisX)},
      {{0, length, 0}, colour(AnnotationColours::kAxisY)},
      {{0, 0, length}, colour(AnnotationColours::kAxisZ)},
  };
  for (const auto& [end, c] : axes) {
    if (const auto tip = projected(camera, pose, end)) line(image, *origin, *tip, c, thickness(image, 2));
  }
}

detector::MarkerPose pose_of(const rig::MarkerGroundTruth& truth) {
  detector::MarkerPose pose;
  pose.rotation = truth.rotation;
  pose.translation = truth.translation;
  return pose;
}

std::string axis_text(std::string_view name, const rig::AxisSnapshot& axis, std::string_view unit) {
  std::string state(rig::to_string(axis.state));
  if (axis.fault) state = "fault";
  return fmt::format("{} {:.1f} {} ({}{}{})", name, axis.position, unit, state, axis.homed ? "" : ", not homed",
                     axis.settled ? ", settled" : "");
}

}  // namespace

cv::Mat grey_image(const HeldFrame& frame) {
  const cv::Mat view(frame.height, frame.width, CV_8UC1, const_cast<std::uint8_t*>(frame.pixels.data()));
  return view.clone();
}

std::vector<std::string> annotation_text(const HeldFrame& frame, const AnnotationContext& context) {
  std::vector<std::string> lines;
  lines.push_back(fmt::format("frame {}  {}x{}", frame.sequence, frame.width, frame.height));
  if (frame.rig) {
    lines.push_back(axis_text("rail", frame.rig->rail, context.rail_unit) + "  " +
                    axis_text("turntable", frame.rig->turntable, context.turntable_unit));
  }
  if (frame.truth) {
    lines.push_back(
        fmt::format("truth: distance {:.3f} m, yaw {:.1f} deg", frame.truth->distance_m, frame.truth->yaw_deg));
  }
  if (frame.status != FrameStatus::ok) {
    lines.push_back(fmt::format("frame {}", to_string(frame.status)));
  } else if (frame.detections.empty()) {
    lines.emplace_back("no marker detected");
  } else {
    std::string text = fmt::format("{} detected:", frame.detections.size());
    for (const auto& d : frame.detections) {
      text += fmt::format(" {} {}", detector::family_info(d.family).name, d.id);
      if (d.pose) text += fmt::format(" at {:.3f} m", d.pose->best.translation.norm());
    }
    lines.push_back(std::move(text));
  }
  return lines;
}

cv::Mat annotated_image(const HeldFrame& frame, const AnnotationContext& context) {
  cv::Mat image;
  cv::cvtColor(grey_image(frame), image, cv::COLOR_GRAY2BGR);
  if (context.camera && frame.truth &&
      (context.camera->width == frame.width && context.camera->height == frame.height)) {
    draw_square(image, *context.camera, pose_of(*frame.truth), context.marker_size_m, colour(AnnotationColours::kTruth),
                thickness(image));
  }
  for (const auto& d : frame.detections) {
    const cv::Scalar outline = colour(AnnotationColours::kOutline);
    for (std::size_t i = 0; i < d.corners.size(); ++i) {
      line(image, pixel(d.corners[i]), pixel(d.corners[(i + 1) % d.corners.size()]), outline, thickness(image, 2));
    }
    if (d.pose && context.camera && context.camera->width == frame.width) {
      draw_axes(image, *context.camera, d.pose->best, context.marker_size_m / 2);
    }
    // The id beside the marker's top-left corner (its own, however it is turned).
    const cv::Point2d at = pixel(d.corners[0]);
    label(image, fmt::format("{}", d.id), {static_cast<int>(at.x) + 4, static_cast<int>(at.y) - 4}, outline);
  }
  const int step = static_cast<int>(std::lround(16 * scale_of(image)));
  int y = step;
  for (const std::string& text : annotation_text(frame, context)) {
    label(image, text, {6, y}, cv::Scalar(255, 255, 255));
    y += step;
  }
  return image;
}

std::optional<ImageFormat> image_format_from_name(std::string_view name) {
  const std::string lower = ascii_lower(name);
  if (lower == "png") return ImageFormat::png;
  if (lower == "jpg" || lower == "jpeg") return ImageFormat::jpeg;
  if (lower == "pgm") return ImageFormat::pgm;
  return std::nullopt;
}

std::string_view to_string(ImageFormat format) {
  switch (format) {
    case ImageFormat::png: return "png";
    case ImageFormat::jpeg: return "jpeg";
    case ImageFormat::pgm: return "pgm";
  }
  return "?";
}

std::string_view mime_type(ImageFormat format) {
  switch (format) {
    case ImageFormat::png: return "image/png";
    case ImageFormat::jpeg: return "image/jpeg";
    case ImageFormat::pgm: return "image/x-portable-graymap";
  }
  return "application/octet-stream";
}

std::vector<std::uint8_t> encode_image(const cv::Mat& image, ImageFormat format, int jpeg_quality) {
  if (format == ImageFormat::pgm && image.channels() != 1) {
    throw std::invalid_argument("PGM holds grey images only: an annotated frame is in colour (use PNG or JPEG)");
  }
  std::vector<int> parameters;
  const char* extension = ".png";
  switch (format) {
    case ImageFormat::png:
      // Level 1: a snapshot is for looking at now, not for keeping small.
      parameters = {cv::IMWRITE_PNG_COMPRESSION, 1};
      break;
    case ImageFormat::jpeg:
      extension = ".jpg";
      parameters = {cv::IMWRITE_JPEG_QUALITY, std::clamp(jpeg_quality, 1, 100)};
      break;
    case ImageFormat::pgm:
      extension = ".pgm";
      parameters = {cv::IMWRITE_PXM_BINARY, 1};
      break;
  }
  std::vector<std::uint8_t> bytes;
  if (!cv::imencode(extension, image, bytes, parameters)) {
    throw std::runtime_error(
        fmt::format("OpenCV could not encode a {}x{} image as {}", image.cols, image.rows, to_string(format)));
  }
  return bytes;
}

}  // namespace markerd::daemon
