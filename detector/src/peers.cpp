#include "peers.hpp"

#include <apriltag/apriltag.h>
#include <apriltag/common/image_u8.h>
#include <apriltag/common/zarray.h>
#include <apriltag/tag36h11.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <opencv2/aruco.hpp>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

namespace markerd::detector {
namespace {

// Shared by both peers: the same preconditions and the same pose as frame8, so
// that a comparison measures the detectors and nothing else.
class PeerBase : public MarkerDetector {
 public:
  explicit PeerBase(const DetectorConfig& config) : camera_(config.camera), marker_size_m_(config.marker_size_m) {}

 protected:
  void check_image(const GreyView& image) const {
    if (image.empty()) throw DetectorError("detect: empty image");
    if (camera_ && (image.width != camera_->width || image.height != camera_->height)) {
      throw DetectorError("detect: image is " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                          " but the camera model is " + std::to_string(camera_->width) + "x" +
                          std::to_string(camera_->height));
    }
  }

  // Every field but the corners, which the caller has already set.
  void finish(Detection& d) const {
    d.quarter_turns = quarter_turns(d.corners);
    if (camera_) d.pose = estimate_square_pose(*camera_, d.corners, marker_size_m_);
  }

 private:
  // Neither peer reports its rotation in the image, but the corners carry it:
  // the direction from the centre to the top edge's midpoint.
  static int quarter_turns(const Quad& q) {
    const Point2 centre = 0.25 * (q[0] + q[1] + q[2] + q[3]);
    const Point2 up = 0.5 * (q[0] + q[1]) - centre;
    // 0 for "up" (-y in the image), +pi/2 when the top faces the image's right.
    const double angle = std::atan2(up.x, -up.y);
    const long turns = std::lround(angle / (std::numbers::pi / 2));
    return static_cast<int>(((turns % 4) + 4) % 4);
  }

  std::optional<CameraModel> camera_;
  double marker_size_m_ = 0;
};

// ---------------------------------------------------------------------------
// ArUco, exactly as a user of OpenCV 4.6 would run it: default parameters
// (no corner refinement), since the benchmark compares against that baseline.
class ArucoDetector final : public PeerBase {
 public:
  explicit ArucoDetector(const DetectorConfig& config)
      : PeerBase(config),
        dictionary_(cv::aruco::getPredefinedDictionary(cv::aruco::DICT_4X4_50)),
        params_(cv::aruco::DetectorParameters::create()) {}

  [[nodiscard]] Family family() const override { return Family::aruco4x4_50; }

  void detect(const GreyView& image, std::vector<Detection>& out) override {
    out.clear();
    check_image(image);
    cv::aruco::detectMarkers(as_mat(image), dictionary_, corners_, ids_, params_);
    for (std::size_t i = 0; i < ids_.size(); ++i) {
      Detection d;
      d.family = Family::aruco4x4_50;
      d.id = ids_[i];
      // OpenCV returns the marker's own TL, TR, BR, BL (clockwise from the
      // corner that is top-left in the dictionary's bit layout), with pixel
      // centres at integers: already our order and convention.
      for (std::size_t k = 0; k < 4; ++k) {
        d.corners[k] = {corners_[i][k].x, corners_[i][k].y};
      }
      // OpenCV 4.6 keeps neither the corrected bit count nor a read quality.
      d.bits_corrected = 0;
      d.margin = 1.0;
      finish(d);
      out.push_back(d);
    }
  }

 private:
  // A cv::Mat borrows the pixels (detectMarkers never writes its input) unless
  // its step cannot express the view's stride (a bottom-up view).
  cv::Mat as_mat(const GreyView& image) {
    if (image.stride >= image.width) {
      return {image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.data),
              static_cast<std::size_t>(image.stride)};
    }
    copy_.create(image.height, image.width, CV_8UC1);
    for (int y = 0; y < image.height; ++y) {
      std::memcpy(copy_.ptr(y), image.row(y), static_cast<std::size_t>(image.width));
    }
    return copy_;
  }

  cv::Ptr<cv::aruco::Dictionary> dictionary_;
  cv::Mat copy_;
  cv::Ptr<cv::aruco::DetectorParameters> params_;
  std::vector<std::vector<cv::Point2f>> corners_;
  std::vector<int> ids_;
};

// ---------------------------------------------------------------------------
// libapriltag, tag36h11 at full resolution (quad_decimate 1) on one thread.
class AprilTagDetector final : public PeerBase {
 public:
  explicit AprilTagDetector(const DetectorConfig& config) : PeerBase(config) {
    family_ = tag36h11_create();
    detector_ = apriltag_detector_create();
    if (!family_ || !detector_) {
      release();
      throw DetectorError("libapriltag: cannot create the detector");
    }
    apriltag_detector_add_family(detector_, family_);
    detector_->quad_decimate = 1.0f;
    detector_->nthreads = 1;
    // With quad_decimate 1, a non-zero quad_sigma would blur the caller's
    // pixels in place; the wrapping below relies on it staying 0.
    detector_->quad_sigma = 0.0f;
  }
  ~AprilTagDetector() override { release(); }
  AprilTagDetector(const AprilTagDetector&) = delete;
  AprilTagDetector& operator=(const AprilTagDetector&) = delete;

  [[nodiscard]] Family family() const override { return Family::tag36h11; }

  void detect(const GreyView& image, std::vector<Detection>& out) override {
    out.clear();
    check_image(image);
    image_u8_t wrapped = wrap(image);
    zarray_t* found = apriltag_detector_detect(detector_, &wrapped);
    const int n = zarray_size(found);
    for (int i = 0; i < n; ++i) {
      apriltag_detection_t* det = nullptr;
      zarray_get(found, i, &det);
      Detection d;
      d.family = Family::tag36h11;
      d.id = det->id;
      // p[] runs counter-clockwise from the tag's (-1, 1), which is the
      // bottom-left of an upright tag in the image: BL, BR, TR, TL.
      // libapriltag puts pixel centres at +0.5 (pixel i spans [i, i+1)),
      // OpenCV and we at integers.
      for (int k = 0; k < 4; ++k) {
        const double* p = det->p[3 - k];
        d.corners[static_cast<std::size_t>(k)] = {p[0] - kPixelOffset, p[1] - kPixelOffset};
      }
      d.bits_corrected = det->hamming;
      d.margin = margin_from_decision(det->decision_margin);
      finish(d);
      out.push_back(d);
    }
    apriltag_detections_destroy(found);
  }

  static constexpr double kPixelOffset = 0.5;

 private:
  // decision_margin is the smaller of the mean distances (grey levels) of the
  // white and of the black data bits from their local threshold. Ink at 0
  // and paper at 255 put the threshold at 127.5 and every bit that far from
  // it, so 127.5 maps to 1 and a bit on the threshold to 0. The decoder's
  // sharpening can push it a little past 127.5; that clamps to 1.
  static double margin_from_decision(float decision_margin) {
    return std::clamp(static_cast<double>(decision_margin) / 127.5, 0.0, 1.0);
  }

  // libapriltag reads an image_u8_t {width, height, stride, buf} with an
  // int32 stride and never writes it (quad_sigma 0): wrap the caller's
  // pixels when the stride fits, copy them into a buffer kept between
  // frames otherwise (a bottom-up view, a stride beyond int32).
  image_u8_t wrap(const GreyView& image) {
    const bool fits = image.stride >= image.width && image.stride <= std::numeric_limits<std::int32_t>::max();
    std::uint8_t* buf = nullptr;
    std::int32_t stride = 0;
    if (fits) {
      buf = const_cast<std::uint8_t*>(image.data);
      stride = static_cast<std::int32_t>(image.stride);
    } else {
      const auto w = static_cast<std::size_t>(image.width);
      copy_.resize(w * static_cast<std::size_t>(image.height));
      for (int y = 0; y < image.height; ++y) std::memcpy(copy_.data() + y * w, image.row(y), w);
      buf = copy_.data();
      stride = image.width;
    }
    return image_u8_t{image.width, image.height, stride, buf};
  }

  void release() {
    if (detector_) apriltag_detector_destroy(detector_);
    if (family_) tag36h11_destroy(family_);
    detector_ = nullptr;
    family_ = nullptr;
  }

  apriltag_family_t* family_ = nullptr;
  apriltag_detector_t* detector_ = nullptr;
  std::vector<std::uint8_t> copy_;
};

void check_family(const DetectorConfig& config, Family expected, const char* what) {
  if (config.family != expected) throw DetectorError(std::string(what) + ": config.family is another family");
  if (config.camera.has_value() != (config.marker_size_m > 0)) {
    throw DetectorError(std::string(what) + ": a pose needs both a camera model and a marker size");
  }
}

}  // namespace

std::unique_ptr<MarkerDetector> make_aruco_detector(const DetectorConfig& config) {
  check_family(config, Family::aruco4x4_50, "make_aruco_detector");
  return std::make_unique<ArucoDetector>(config);
}

std::unique_ptr<MarkerDetector> make_apriltag_detector(const DetectorConfig& config) {
  check_family(config, Family::tag36h11, "make_apriltag_detector");
  return std::make_unique<AprilTagDetector>(config);
}

}  // namespace markerd::detector
