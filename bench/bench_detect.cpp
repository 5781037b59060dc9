// Detection time per frame, frame8 against its peers (ArUco with OpenCV's
// default parameters, libapriltag tag36h11 at full resolution), single
// threaded, on rendered frames of the thesis camera and of the same lens at
// 3x the resolution. Every family sees its own marker in the same scenes:
// the same poses, the same backgrounds, the same noise.
//
//   bench_detect [google benchmark flags]
//
// After the table it prints the time ratios peer / frame8 per resolution (the
// baseline the issue asks for), from CPU time: everything runs on one thread,
// and CPU time does not count the waits of a machine shared with other work.
// BM_RenderScene times the renderer, the simulated camera's cost per frame.

#include <benchmark/benchmark.h>

#include <cstdio>
#include <exception>
#include <map>
#include <memory>
#include <opencv2/core/utility.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/detector/render.hpp"

namespace {

using markerd::detector::Family;

constexpr int kFrames = 20;
constexpr double kMarkerSize = 0.08;

struct FrameSet {
  std::vector<markerd::detector::GreyImage> images;
  std::vector<int> ids;
};

// The scene of frame i, the same for every family but for the marker drawn.
markerd::detector::Scene scene_for(Family family, int i) {
  markerd::detector::Scene s;
  s.family = family;
  const auto& info = markerd::detector::family_info(family);
  s.id = info.first_default_id + (37 * i + 11) % info.default_id_count();
  s.marker_size_m = kMarkerSize;
  const double t = static_cast<double>(i) / (kFrames - 1);
  const double distance = 0.3 + t * (2.5 - 0.3);
  // Yaw and the small off-axis shift run through their range on another
  // stride than distance, so that far and turned frames are not all the same ones.
  const double yaw = 60.0 * static_cast<double>((7 * i) % kFrames) / (kFrames - 1);
  const double roll = -10.0 + 20.0 * static_cast<double>((3 * i) % kFrames) / (kFrames - 1);
  const double offset = 0.05 * distance * ((i % 3) - 1);
  s.pose = markerd::detector::facing_pose(distance, yaw, 0, roll, offset, -0.5 * offset);
  s.noise_sigma = 2;
  s.blur_sigma_px = 0.6;
  s.clutter = true;
  s.seed = 1000 + static_cast<std::uint64_t>(i);
  return s;
}

// Rendered once per (family, resolution), outside every timing loop; the
// renderer is far slower than any detector.
const FrameSet& frames(Family family, const markerd::detector::CameraModel& camera) {
  static std::map<std::pair<Family, int>, FrameSet> cache;
  auto [it, inserted] = cache.try_emplace({family, camera.width});
  if (inserted) {
    for (int i = 0; i < kFrames; ++i) {
      const markerd::detector::Scene s = scene_for(family, i);
      it->second.images.push_back(markerd::detector::render_scene(camera, s));
      it->second.ids.push_back(s.id);
    }
  }
  return it->second;
}

void run_detector(benchmark::State& state, Family family, markerd::detector::Mounting mounting,
                  const markerd::detector::CameraModel& camera) {
  std::unique_ptr<markerd::detector::MarkerDetector> detector;
  try {
    markerd::detector::DetectorConfig config;
    config.family = family;
    config.frame8.mounting = mounting;
    detector = markerd::detector::make_detector(config);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  const FrameSet& set = frames(family, camera);
  std::vector<markerd::detector::Detection> found;
  // Warm-up outside the timing (the first frames of a size size the
  // buffers), and the detected fraction over the set, each frame once: the
  // timed loop below rarely stops on a whole number of rounds.
  int detected = 0;
  for (std::size_t i = 0; i < set.images.size(); ++i) {
    detector->detect(set.images[i].view(), found);
    for (const auto& d : found) {
      if (d.id == set.ids[i]) {
        ++detected;
        break;
      }
    }
  }

  std::size_t next = 0;
  for (auto _ : state) {
    detector->detect(set.images[next].view(), found);
    benchmark::DoNotOptimize(found.data());
    next = (next + 1) % set.images.size();
  }
  state.SetItemsProcessed(state.iterations());
  state.counters["detected"] = static_cast<double>(detected) / static_cast<double>(set.images.size());
}

// A marker about 140 px across, with noise and blur, a new seed every frame.
void run_renderer(benchmark::State& state, const markerd::detector::CameraModel& camera) {
  markerd::detector::Scene s;
  s.pose = markerd::detector::facing_pose(0.3, 20);
  s.noise_sigma = 2;
  s.blur_sigma_px = 0.7;
  for (auto _ : state) {
    ++s.seed;
    const markerd::detector::GreyImage img = markerd::detector::render_scene(camera, s);
    benchmark::DoNotOptimize(img.view().data);
  }
  state.SetItemsProcessed(state.iterations());
}

struct Entry {
  const char* name;
  Family family;
  markerd::detector::Mounting mounting = markerd::detector::Mounting::any;
};
// frame8 as a new user runs it (not told the mounting: every search), and as
// markerd runs it when its config says the marker is printed on paper, as
// these are.
constexpr Entry kFamilies[] = {
    {"BM_Frame8", Family::frame8},
    {"BM_Frame8Paper", Family::frame8, markerd::detector::Mounting::paper},
    {"BM_Aruco", Family::aruco4x4_50},
    {"BM_AprilTag", Family::tag36h11},
};

// The console table as usual, plus the mean time per frame of every run, for
// the ratios printed at the end.
class RatioReporter : public benchmark::ConsoleReporter {
 public:
  using ConsoleReporter::ConsoleReporter;

  void ReportRuns(const std::vector<Run>& runs) override {
    for (const Run& r : runs) {
      if (r.run_type != Run::RT_Iteration || r.error_occurred) continue;
      auto& [sum, count] = times_[r.run_name.function_name];
      sum += r.GetAdjustedCPUTime() * to_ms(r.time_unit);
      ++count;
    }
    ConsoleReporter::ReportRuns(runs);
  }

  void print_ratios(const std::vector<std::string>& resolutions) const {
    std::printf("\nTime per frame against frame8 (CPU time; > 1 means frame8 is faster):\n");
    for (const auto& res : resolutions) {
      for (const auto& [frame8, told] : {std::pair{"BM_Frame8", ""}, std::pair{"BM_Frame8Paper", " told paper"}}) {
        const auto base = mean(std::string(frame8) + "/" + res);
        for (const auto& [bench, label] : {std::pair{"BM_Aruco", "ArUco"}, std::pair{"BM_AprilTag", "AprilTag"}}) {
          const auto other = mean(std::string(bench) + "/" + res);
          if (base && other) {
            std::printf("  %-9s %-8s / frame8%s: %6.2f  (%.3f ms / %.3f ms)\n", res.c_str(), label, told,
                        *other / *base, *other, *base);
          } else {
            std::printf("  %-9s %-8s / frame8%s: n/a (one of the two was not measured in this run)\n", res.c_str(),
                        label, told);
          }
        }
      }
    }
  }

 private:
  static double to_ms(benchmark::TimeUnit unit) {
    switch (unit) {
      case benchmark::kNanosecond: return 1e-6;
      case benchmark::kMicrosecond: return 1e-3;
      case benchmark::kMillisecond: return 1.0;
      case benchmark::kSecond: return 1e3;
    }
    return 1.0;
  }
  [[nodiscard]] std::optional<double> mean(const std::string& name) const {
    const auto it = times_.find(name);
    if (it == times_.end() || it->second.second == 0) return std::nullopt;
    return it->second.first / it->second.second;
  }

  std::map<std::string, std::pair<double, int>> times_;
};

}  // namespace

int main(int argc, char** argv) {
  // OpenCV would spread ArUco over its thread pool; every detector gets one core.
  cv::setNumThreads(1);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;

  // Cameras live as long as the registered benchmarks that capture them.
  static const markerd::detector::CameraModel small = markerd::detector::CameraModel::thesis_640x480();
  static const markerd::detector::CameraModel large = small.scaled_to(1920, 1440);
  const std::vector<std::pair<std::string, const markerd::detector::CameraModel*>> resolutions = {
      {"640x480", &small}, {"1920x1440", &large}};
  std::vector<std::string> names;
  for (const auto& [res, camera] : resolutions) {
    names.push_back(res);
    for (const Entry& e : kFamilies) {
      const markerd::detector::CameraModel* cam = camera;
      const Family family = e.family;
      const markerd::detector::Mounting mounting = e.mounting;
      benchmark::RegisterBenchmark((std::string(e.name) + "/" + res).c_str(), [family, mounting,
                                                                               cam](benchmark::State& s) {
        run_detector(s, family, mounting, *cam);
      })->Unit(benchmark::kMillisecond);
    }
  }

  benchmark::RegisterBenchmark("BM_RenderScene/640x480", [](benchmark::State& s) {
    run_renderer(s, small);
  })->Unit(benchmark::kMillisecond);

  RatioReporter reporter(benchmark::ConsoleReporter::OO_Tabular);
  benchmark::RunSpecifiedBenchmarks(&reporter);
  reporter.print_ratios(names);
  benchmark::Shutdown();
  return 0;
}
