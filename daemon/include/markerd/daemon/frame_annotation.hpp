#pragma once
// A held frame as a picture for people: the grey image as it came, or
// annotated in colour with what markerd knows of it (each detection's
// outline, id and pose axes; where the rig's geometry says the marker is;
// the rig's state), and encoded as PNG, JPEG or PGM. The one place that
// draws, for `markerctl snapshot --annotate` and the web page's preview
// alike. Runs on the reader's thread (the control server, the web server's),
// never the pipeline's.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/daemon/latest_frame.hpp"
#include "markerd/detector/camera_model.hpp"

namespace cv {
class Mat;
}

namespace markerd::daemon {

// What the drawing needs beyond the frame: poses and the ground truth are
// projected through the camera model (without one, only outlines and ids
// are drawn), the marker's size gives the truth's outline and the axes'
// length, the units label the rig's positions.
struct AnnotationContext {
  std::optional<detector::CameraModel> camera;
  double marker_size_m = 0.08;
  std::string rail_unit = "mm";
  std::string turntable_unit = "deg";
};

// The colours, BGR, so that tests find what was drawn where.
struct AnnotationColours {
  static constexpr std::uint8_t kOutline[3] = {0, 230, 0};  // a detection's outline and id: green
  static constexpr std::uint8_t kTruth[3] = {255, 0, 255};  // the ground truth's outline: magenta
  static constexpr std::uint8_t kAxisX[3] = {0, 0, 255};    // pose axes: x red,
  static constexpr std::uint8_t kAxisY[3] = {0, 255, 255};  // y yellow (green is the outline's),
  static constexpr std::uint8_t kAxisZ[3] = {255, 128, 0};  // z blue
};

// The frame's grey pixels as a one-channel image (a copy).
[[nodiscard]] cv::Mat grey_image(const HeldFrame& frame);
// The frame in colour with everything drawn on it.
[[nodiscard]] cv::Mat annotated_image(const HeldFrame& frame, const AnnotationContext& context);
// The lines of text drawn in the top left corner: the frame, the rig's
// axes, the ground truth, the detections.
[[nodiscard]] std::vector<std::string> annotation_text(const HeldFrame& frame, const AnnotationContext& context);

enum class ImageFormat : std::uint8_t { png, jpeg, pgm };
// "png", "jpg", "jpeg", "pgm" (any case); nothing otherwise.
[[nodiscard]] std::optional<ImageFormat> image_format_from_name(std::string_view name);
[[nodiscard]] std::string_view to_string(ImageFormat format);  // "png", "jpeg", "pgm"
[[nodiscard]] std::string_view mime_type(ImageFormat format);
// Encodes `image` (grey or BGR). PGM takes grey images only:
// std::invalid_argument for a colour one. std::runtime_error when OpenCV
// cannot encode.
[[nodiscard]] std::vector<std::uint8_t> encode_image(const cv::Mat& image, ImageFormat format, int jpeg_quality = 85);

}  // namespace markerd::daemon
