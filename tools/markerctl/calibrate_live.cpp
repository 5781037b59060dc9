#include "calibrate_live.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <optional>
#include <utility>

#include "cmd_daemon.hpp"
#include "cmd_snapshot.hpp"
#include "common.hpp"
#include "live_line.hpp"
#include "markerd/detector/view_picker.hpp"
#include "signal_watch.hpp"

namespace markerctl {

namespace {

namespace det = markerd::detector;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

// markerd copies a frame for readers every 100 ms while someone asks
// (daemon/latest_frame.hpp): asking faster gets the same frame again.
constexpr std::chrono::milliseconds kPollInterval{100};
// No new frame for this long: the camera stopped, or a replay ended.
constexpr std::chrono::seconds kStalledAfter{10};

std::string coverage_text(const det::ViewPicker& picker) {
  const det::RegionPoints& regions = picker.region_points();
  const auto covered = std::count_if(regions.begin(), regions.end(), [](int n) { return n > 0; });
  if (picker.kept().empty()) return "no view yet";
  if (covered == static_cast<long>(regions.size())) return "points in every region";
  return fmt::format("no points yet in {}", det::empty_regions(regions));
}

std::string advice(const det::Pick& pick, const det::BoardPoints& points, int min_points) {
  switch (pick.verdict) {
    case det::PickVerdict::no_board: return "no board in view";
    case det::PickVerdict::too_few_points:
      return fmt::format("{} of the board's points in view, {} needed: show more of it", points.image.size(),
                         min_points);
    case det::PickVerdict::moving:
      return pick.moved_px ? fmt::format("hold the board still (it moved {:.1f} px)", *pick.moved_px)
                           : std::string("hold the board still");
    case det::PickVerdict::like_a_kept_view:
      return fmt::format("move or tilt the board: this is like view {}", pick.view + 1);
    case det::PickVerdict::kept: break;
  }
  return {};
}

// The frame's pixels, grey, from the snapshot's PGM.
cv::Mat decode_frame(const json& reply) {
  const cv::Mat grey = cv::imdecode(snapshot_image_bytes(reply, "calibrate"), cv::IMREAD_GRAYSCALE);
  if (grey.empty())
    throw runtime_error("calibrate", "markerd's snapshot holds no readable image (its PGM does not decode)");
  return grey;
}

}  // namespace

LiveViews gather_live_views(const LiveCalibrationOptions& options, det::BoardDetector& detector, int min_points) {
  namespace fs = std::filesystem;
  if (!options.keep_dir.empty()) {
    std::error_code ec;
    fs::create_directories(options.keep_dir, ec);
    if (ec || !fs::is_directory(options.keep_dir)) {
      throw runtime_error("--keep", fmt::format("{}: cannot make the directory: {}", options.keep_dir,
                                                ec ? ec.message() : "a file of that name is in the way"));
    }
  }
  DaemonConnection daemon(options.socket, "calibrate");
  const SignalWatch signals;
  LiveLine live(std::cerr, STDERR_FILENO);
  LiveViews result;
  std::optional<det::ViewPicker> picker;
  det::ViewPickerOptions picker_options;
  picker_options.min_points = min_points;
  std::uint64_t last_copy = 0;
  Clock::time_point last_new_frame = Clock::now();
  live.show("calibrate: waiting for markerd's frames");
  for (;;) {
    const SignalWatch::Wake wake = signals.wait(kPollInterval);
    if (wake.signal != 0) {
      live.print(
          fmt::format("calibrate: {}: taking no more views, {} kept", signal_name(wake.signal), result.views.size()));
      result.interrupted = true;
      return result;
    }
    const json reply = daemon.raw_call({{"cmd", "snapshot"}, {"format", "pgm"}}, std::chrono::seconds(30));
    if (!reply.value("ok", false)) {
      const std::string error = reply.value("error", std::string("refused"));
      // Before the camera's first frame: wait for it like for any other.
      if (error.rfind("no frame yet", 0) != 0) throw runtime_error("calibrate", "markerd: " + error);
    } else if (const std::uint64_t copy = reply["frame"].value("copy", std::uint64_t{0}); copy != last_copy) {
      last_copy = copy;
      last_new_frame = Clock::now();
      const cv::Mat grey = decode_frame(reply);
      if (!picker) {
        result.width = grey.cols;
        result.height = grey.rows;
        picker.emplace(grey.cols, grey.rows, picker_options);
      } else if (grey.cols != result.width || grey.rows != result.height) {
        throw runtime_error("calibrate", fmt::format("markerd's frames changed size from {}x{} to {}x{}: the views "
                                                     "of one calibration need one size",
                                                     result.width, result.height, grey.cols, grey.rows));
      }
      const det::GreyView view{grey.data, grey.cols, grey.rows, static_cast<int>(grey.step)};
      det::BoardPoints points = detector.detect(view);
      const det::Pick pick = picker->offer(points);
      const std::uint64_t sequence = reply["frame"].value("sequence", std::uint64_t{0});
      if (pick.verdict == det::PickVerdict::kept) {
        det::CalibrationView& kept = result.views.emplace_back();
        kept.name = fmt::format("frame {}", sequence);
        if (!options.keep_dir.empty()) {
          const fs::path file = fs::path(options.keep_dir) / fmt::format("view-{:02}.png", result.views.size());
          if (!cv::imwrite(file.string(), grey)) {
            throw runtime_error("--keep", fmt::format("cannot write {}", file.string()));
          }
          kept.name = file.string();
        }
        kept.points = std::move(points);
        live.print(fmt::format("calibrate: view {} of {} kept: {}, {} points; {}", result.views.size(), options.views,
                               kept.name, kept.points.image.size(), coverage_text(*picker)));
        if (std::cmp_greater_equal(result.views.size(), options.views)) return result;
      } else {
        live.show({fmt::format("calibrate: {} of {} views", result.views.size(), options.views),
                   advice(pick, points, min_points), coverage_text(*picker)},
                  "; ");
      }
    }
    if (Clock::now() - last_new_frame > kStalledAfter) {
      throw runtime_error(
          "calibrate",
          fmt::format("markerd sent no new frame for {} s: markerctl status shows the camera ({} "
                      "view{} kept{})",
                      kStalledAfter.count(), result.views.size(), result.views.size() == 1 ? "" : "s",
                      options.keep_dir.empty() || result.views.empty()
                          ? std::string()
                          : fmt::format(", in {}: markerctl calibrate takes them as files", options.keep_dir)));
    }
  }
}

}  // namespace markerctl
