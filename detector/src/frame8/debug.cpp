// The debug output (Frame8Options::debug_dir): the threshold image, the
// candidates drawn on the image, and what became of each, by stage.

#include <fmt/format.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "frame8/detector.hpp"

namespace markerd::detector::frame8 {

const char* Frame8Detector::read_name(Read how) {
  switch (how) {
    case Read::sampled: return "sampled";
    case Read::step_only: return "step_only";
    case Read::profile_fit: return "profile_fit";
    case Read::ring_model: return "ring_model";
    case Read::aligned_ring_model: return "aligned_ring_model";
    case Read::second_pass: return "second_pass";
    case Read::side_hidden: return "side_hidden";
    case Read::inset: return "inset";
    case Read::ring_edges: return "ring_edges";
    case Read::ring_alignment: return "ring_alignment";
    case Read::model_check: return "model_check";
  }
  return "?";
}

namespace {

void write_image(const std::string& path, const cv::Mat& image) {
  bool written = false;
  try {
    written = cv::imwrite(path, image);
  } catch (const cv::Exception& e) {
    throw DetectorError(fmt::format("frame8 debug output: cannot write {}: {}", path, e.what()));
  }
  if (!written) throw DetectorError(fmt::format("frame8 debug output: cannot write {}", path));
}

void write_text(const std::string& path, const std::string& text) {
  const std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "w"), &std::fclose);
  if (!f || std::fwrite(text.data(), 1, text.size(), f.get()) != text.size() || std::fflush(f.get()) != 0) {
    throw DetectorError(fmt::format("frame8 debug output: cannot write {}", path));
  }
}

}  // namespace

// The light pixels of the working image: what the look under way's
// segmentation saw (threshold.png, and threshold-second.png for the second
// look).
void Frame8Detector::write_debug_threshold() const {
  cv::Mat threshold(work_.height, work_.width, CV_8UC1, cv::Scalar(0));
  for (const Run& run : runs_) {
    std::uint8_t* row = threshold.ptr<std::uint8_t>(run.y);
    std::fill(row + run.x0, row + run.x1, std::uint8_t{255});
  }
  write_image(fmt::format("{}/{:04}-threshold{}.png", config_.frame8.debug_dir, debug_frame_,
                          rule_ == LocalRule::valley ? "-second" : ""),
              threshold);
}

void Frame8Detector::write_debug(const std::vector<Detection>& out) {
  const std::string prefix = fmt::format("{}/{:04}-", config_.frame8.debug_dir, debug_frame_++);

  // A candidate read and then dropped as part of a larger marker is no
  // longer among the detections.
  auto reported = [&](const DebugCandidate& c) {
    return std::any_of(out.begin(), out.end(), [&](const Detection& d) {
      return d.id == c.id && d.corners[0].x == c.first_corner.x && d.corners[0].y == c.first_corner.y;
    });
  };
  const cv::Mat grey(full_.height, full_.width, CV_8UC1, const_cast<std::uint8_t*>(full_.data),
                     static_cast<std::size_t>(full_.stride));
  cv::Mat drawn;
  cv::cvtColor(grey, drawn, cv::COLOR_GRAY2BGR);
  std::string json = fmt::format(R"({{"frame": {}, "width": {}, "height": {}, "decimate": {}, "candidates": [)",
                                 debug_frame_ - 1, full_.width, full_.height, decimate_);
  for (std::size_t i = 0; i < debug_candidates_.size(); ++i) {
    const DebugCandidate& c = debug_candidates_[i];
    const bool read = c.why == Rejection::none;
    const bool kept = read && reported(c);
    const cv::Scalar colour = kept ? cv::Scalar(0, 200, 0) : read ? cv::Scalar(0, 200, 255) : cv::Scalar(0, 0, 255);
    for (std::size_t k = 0; k < 4; ++k) {
      const Point2 a = c.quad[k], b = c.quad[(k + 1) % 4];
      cv::line(drawn, cv::Point(static_cast<int>(std::lround(a.x)), static_cast<int>(std::lround(a.y))),
               cv::Point(static_cast<int>(std::lround(b.x)), static_cast<int>(std::lround(b.y))), colour, 1,
               cv::LINE_AA);
    }
    cv::putText(drawn, std::to_string(i),
                cv::Point(static_cast<int>(std::lround(c.quad[0].x)), static_cast<int>(std::lround(c.quad[0].y)) - 2),
                cv::FONT_HERSHEY_PLAIN, 0.8, colour, 1, cv::LINE_AA);

    json += fmt::format(R"({}{{"index": {}, "look": "{}", "corners": [)", i ? ", " : "", i,
                        i >= debug_model_look_from_    ? "model"
                        : i >= debug_second_look_from_ ? "second"
                                                       : "first");
    for (std::size_t k = 0; k < 4; ++k) {
      json += fmt::format("{}[{:.2f}, {:.2f}]", k ? ", " : "", c.quad[k].x, c.quad[k].y);
    }
    json += "]";
    if (kept) {
      json += fmt::format(R"(, "result": "detected", "id": {})", c.id);
    } else if (read) {
      json += fmt::format(R"(, "result": "nested", "id": {}, "reason": "inside a larger detection")", c.id);
    } else {
      json += fmt::format(R"(, "result": "rejected", "stage": "{}", "reason": "{}")", stage_name(stage_of(c.why)),
                          rejection_name(c.why));
    }
    if (!c.attempts.empty()) {
      json += R"(, "reads": [)";
      for (std::size_t k = 0; k < c.attempts.size(); ++k) {
        const auto& [how, why] = c.attempts[k];
        json += fmt::format(R"({}{{"read": "{}", )", k ? ", " : "", read_name(how));
        json += why == Rejection::none
                    ? std::string(R"("result": "read"})")
                    : fmt::format(R"("stage": "{}", "reason": "{}"}})", stage_name(stage_of(why)), rejection_name(why));
      }
      json += "]";
    }
    json += "}";
  }
  json += "]}\n";
  write_image(prefix + "candidates.png", drawn);
  write_text(prefix + "candidates.json", json);
}

}  // namespace markerd::detector::frame8
