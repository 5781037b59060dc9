#include "markerd/daemon/control/snapshot_command.hpp"

#include <fmt/format.h>

#include <cmath>
#include <opencv2/core.hpp>

#include "markerd/base/base64.hpp"
#include "markerd/base/utc_time.hpp"
#include "markerd/daemon/control/command_arguments.hpp"
#include "markerd/daemon/daemon_status.hpp"
#include "markerd/detector/family.hpp"

namespace markerd::daemon {

namespace {

// Pixels to a hundredth, metres to a tenth of a millimetre: what the
// measurement holds, in a line a person can read.
double round_to(double value, double step) { return std::round(value / step) * step; }

nlohmann::json vector_json(const Eigen::Vector3d& v) {
  return {round_to(v.x(), 1e-5), round_to(v.y(), 1e-5), round_to(v.z(), 1e-5)};
}

nlohmann::json quaternion_json(const Eigen::Matrix3d& rotation) {
  const Eigen::Quaterniond q(rotation);
  return {round_to(q.w(), 1e-6), round_to(q.x(), 1e-6), round_to(q.y(), 1e-6), round_to(q.z(), 1e-6)};
}

nlohmann::json detection_json(const detector::Detection& d) {
  nlohmann::json corners = nlohmann::json::array();
  for (const auto& c : d.corners) corners.push_back({round_to(c.x, 0.01), round_to(c.y, 0.01)});
  nlohmann::json j{{"family", detector::family_info(d.family).name},
                   {"id", d.id},
                   {"corners", std::move(corners)},
                   {"margin", round_to(d.margin, 1e-3)}};
  if (d.pose) {
    j["pose"] = {{"distance_m", round_to(d.pose->best.translation.norm(), 1e-5)},
                 {"tvec", vector_json(d.pose->best.translation)},
                 {"quaternion", quaternion_json(d.pose->best.rotation)},
                 {"reprojection_error_px", round_to(d.pose->best.reprojection_error_px, 1e-3)}};
  } else {
    j["pose"] = nullptr;
  }
  return j;
}

}  // namespace

nlohmann::json held_frame_json(const HeldFrame& frame) {
  const double age_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - frame.capture_time).count();
  nlohmann::json j;
  j["frame"] = {{"copy", frame.copy},
                {"sequence", frame.sequence},
                {"capture_utc", format_utc(frame.capture_utc, UtcForm::milliseconds)},
                {"age_ms", round_to(age_ms, 0.1)},
                {"width", frame.width},
                {"height", frame.height},
                {"status", std::string(to_string(frame.status))}};
  nlohmann::json detections = nlohmann::json::array();
  for (const auto& d : frame.detections) detections.push_back(detection_json(d));
  j["detections"] = std::move(detections);
  j["rig"] = frame.rig ? to_json(*frame.rig) : nlohmann::json();
  if (frame.truth) {
    j["truth"] = {{"distance_m", round_to(frame.truth->distance_m, 1e-6)},
                  {"yaw_deg", round_to(frame.truth->yaw_deg, 1e-4)},
                  {"tvec", vector_json(frame.truth->translation)},
                  {"quaternion", quaternion_json(frame.truth->rotation)}};
  } else {
    j["truth"] = nullptr;
  }
  return j;
}

void register_snapshot_command(ControlServer& server, const LatestFrame& latest, AnnotationContext context) {
  server.register_command(
      "snapshot",
      [&latest, context = std::move(context)](const nlohmann::json& request) {
        expect_arguments(request, {"format", "annotate"});
        const std::string format_name =
            choice_argument(request, "format", {"png", "jpeg", "jpg", "pgm"}).value_or("png");
        const ImageFormat format = *image_format_from_name(format_name);
        const bool annotate = bool_argument(request, "annotate").value_or(false);
        if (annotate && format == ImageFormat::pgm) {
          throw ControlError("an annotated snapshot is in colour: format png or jpeg, not pgm");
        }
        const std::shared_ptr<const HeldFrame> frame = latest.latest();
        if (!frame) {
          throw ControlError(
              "no frame yet: the camera has delivered none since markerd started (markerctl status "
              "shows the camera)");
        }
        const cv::Mat image = annotate ? annotated_image(*frame, context) : grey_image(*frame);
        const std::vector<std::uint8_t> bytes = encode_image(image, format);
        nlohmann::json reply = held_frame_json(*frame);
        reply["image"] = {{"format", std::string(to_string(format))},
                          {"annotated", annotate},
                          {"bytes", bytes.size()},
                          {"encoding", "base64"},
                          {"data", base64_encode(bytes)}};
        return reply;
      },
      "markerd's newest frame as an image (format png, jpeg or pgm; annotate: the detections, the truth, the rig), "
      "base64, with its detections and the rig's state");
}

}  // namespace markerd::daemon
