// The frame pipeline at a camera's pace: rendered frames (a few scenes,
// rendered once and cycled) are offered at a set rate, lent to the pipeline
// without a copy as a V4L2 mmap buffer would be, detected with frame8 and
// handed to a sink that only counts. Prints frames offered and dropped,
// latencies and CPU time per frame. The figure is the default:
//
//   bench_pipeline --width 1920 --height 1080 --fps 60 --seconds 10 --workers 1 --policy live

#include <sys/resource.h>

// "potential null pointer dereference" in std::string inlined from CLI11's
// CLI::detail::split (as tools/markerctl/main.cpp explains).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop
#include <fmt/format.h>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/pipeline.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"

namespace {

using markerd::daemon::Clock;
using markerd::daemon::DropPolicy;
using markerd::daemon::Frame;
using markerd::daemon::FrameSink;
using markerd::daemon::LatencySummary;
using markerd::daemon::Pipeline;

class CountingSink : public FrameSink {
 public:
  void write(const Frame& frame) override {
    ++frames;
    if (!frame.detections.empty()) ++with_marker;
  }
  std::uint64_t frames = 0;  // the log stage's thread only; read after stop()
  std::uint64_t with_marker = 0;
};

void count_release(void* context, std::uint64_t) noexcept {
  static_cast<std::atomic<std::uint64_t>*>(context)->fetch_add(1, std::memory_order_relaxed);
}

double cpu_seconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto seconds = [](const timeval& t) {
    return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec);
  };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

double ms(std::chrono::nanoseconds d) { return static_cast<double>(d.count()) / 1e6; }

void print_latency(const char* name, const LatencySummary& s) {
  fmt::print("{:<20} p50 {:7.2f} ms   p99 {:7.2f} ms   max {:7.2f} ms   ({} frames)\n", name, ms(s.p50), ms(s.p99),
             ms(s.max), s.count);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Frames through the pipeline at a camera's rate: drops, latency, CPU per frame"};
  int width = 1920;
  int height = 1080;
  double fps = 60;
  double seconds = 10;
  int workers = 1;
  std::size_t slots = 4;
  int scenes = 4;
  std::string policy_name = "live";
  app.add_option("--width", width, "frame width, pixels")->check(CLI::Range(64, 8192));
  app.add_option("--height", height, "frame height, pixels")->check(CLI::Range(48, 8192));
  app.add_option("--fps", fps, "frames offered per second")->check(CLI::Range(1.0, 1000.0));
  app.add_option("--seconds", seconds, "how long to run")->check(CLI::Range(0.5, 3600.0));
  app.add_option("--workers", workers, "detection workers")->check(CLI::Range(1, 16));
  app.add_option("--slots", slots, "frame slots (frames in flight)")->check(CLI::Range(1, 256));
  app.add_option("--scenes", scenes, "distinct rendered scenes, cycled")->check(CLI::Range(1, 64));
  app.add_option("--policy", policy_name, "live or lossless")->check(CLI::IsMember({"live", "lossless"}));
  CLI11_PARSE(app, argc, argv);
  const DropPolicy policy = policy_name == "live" ? DropPolicy::live : DropPolicy::lossless;

  // The thesis lens at the requested resolution; markers from near to far,
  // turned, over clutter, as the simulated camera renders them.
  const markerd::detector::CameraModel camera =
      markerd::detector::CameraModel::thesis_640x480().scaled_to(width, height);
  std::vector<markerd::detector::GreyImage> images;
  const auto render_start = Clock::now();
  for (int k = 0; k < scenes; ++k) {
    markerd::detector::Scene scene;
    scene.id = 37 * k + 11;
    scene.pose = markerd::detector::facing_pose(0.4 + 0.3 * k, -20 + 13.0 * k, 0, 7.0 * k);
    scene.supersample = 2;
    scene.noise_sigma = 2;
    scene.blur_sigma_px = 0.6;
    scene.seed = static_cast<std::uint64_t>(k + 1);
    images.push_back(markerd::detector::render_scene(camera, scene));
  }
  fmt::print("rendered {} scenes of {}x{} in {:.1f} s\n", scenes, width, height,
             std::chrono::duration<double>(Clock::now() - render_start).count());

  std::vector<std::unique_ptr<markerd::detector::MarkerDetector>> detectors;
  for (int i = 0; i < workers; ++i)
    detectors.push_back(markerd::detector::make_detector(markerd::detector::DetectorConfig{}));
  CountingSink sink;
  std::atomic<std::uint64_t> released{0};
  markerd::daemon::PipelineConfig config;
  config.policy = policy;
  config.pool.slots = slots;
  Pipeline pipeline(config, std::move(detectors), sink);

  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / fps));
  const auto frames = static_cast<std::uint64_t>(seconds * fps);
  const double cpu_before = cpu_seconds();
  const auto start = Clock::now();
  std::uint64_t late = 0;  // ticks the capture thread itself missed (it was not scheduled in time)
  for (std::uint64_t seq = 0; seq < frames; ++seq) {
    const auto tick = start + period * static_cast<std::int64_t>(seq);
    std::this_thread::sleep_until(tick);
    if (Clock::now() - tick > period) ++late;
    Frame* frame = pipeline.acquire();
    if (frame == nullptr) continue;  // dropped: a driver would requeue its buffer now
    frame->sequence = seq;
    frame->capture_time = tick;  // as a driver stamps it: when the frame was taken
    frame->image = images[seq % images.size()];
    frame->set_release({&count_release, &released, seq});
    pipeline.publish(*frame);
  }
  pipeline.stop();
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  const double cpu = cpu_seconds() - cpu_before;

  const auto s = pipeline.stats();
  fmt::print("{} s at {} fps, {}x{}, {} worker(s), {} slots, {} policy\n", seconds, fps, width, height, workers, slots,
             policy_name);
  fmt::print("frames offered {}   detected {}   logged {}   dropped {} ({} refused at capture, {} dropped waiting)\n",
             s.capture.in, s.detect.out, s.log.out, s.dropped(), s.capture.dropped, s.detect.dropped);
  fmt::print("frames with a marker found {} of {}; capture ticks missed by the bench's own thread {}\n",
             sink.with_marker, sink.frames, late);
  print_latency("capture -> detect", s.capture_to_detect);
  print_latency("detect", s.detect_duration);
  print_latency("capture -> log", s.capture_to_log);
  fmt::print("CPU {:.3f} s over {:.2f} s wall: {:.2f} ms per frame offered ({:.0f}% of one core)\n", cpu, wall,
             1e3 * cpu / static_cast<double>(s.capture.in), 100 * cpu / wall);
  if (released.load() != s.capture.out) {
    fmt::print(stderr, "error: {} release hooks ran for {} frames published\n", released.load(), s.capture.out);
    return 1;
  }
  return 0;
}
