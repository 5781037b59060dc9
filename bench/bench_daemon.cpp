// markerd as a whole on the simulated source: the simulated camera at a set
// size and frame rate over the simulated rig (standing still at a point of a
// sweep), frame8 detection, and the detection log written to a temporary
// directory, exactly as markerd runs them. Prints frames captured and
// dropped, capture-to-log latency and CPU time per frame. The issue's figure:
//
//   bench_daemon --width 1920 --height 1080 --fps 60 --seconds 10

#include <sys/resource.h>

// "potential null pointer dereference" in std::string inlined from CLI11's
// CLI::detail::split (as tools/markerctl/main.cpp explains).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop
#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include "markerd/daemon/daemon.hpp"
#include "markerd/detector/camera_model.hpp"

namespace {

namespace fs = std::filesystem;

double cpu_seconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto seconds = [](const timeval& t) {
    return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec);
  };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

double ms(std::chrono::nanoseconds d) { return static_cast<double>(d.count()) / 1e6; }

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"markerd on the simulated source: drops, capture-to-log latency, CPU per frame"};
  int width = 1920, height = 1080, workers = 1;
  double fps = 60, seconds = 10, distance_m = 0.95, yaw_deg = 30;
  std::string policy = "live", fsync = "interval", rig_file;
  app.add_option("--width", width)->capture_default_str();
  app.add_option("--height", height)->capture_default_str();
  app.add_option("--fps", fps)->capture_default_str();
  app.add_option("--seconds", seconds)->capture_default_str();
  app.add_option("--workers", workers)->capture_default_str();
  app.add_option("--policy", policy, "live or lossless")->capture_default_str();
  app.add_option("--fsync", fsync, "never, interval or every_line")->capture_default_str();
  app.add_option("--distance", distance_m, "the marker's distance (m), shown through the default geometry")
      ->capture_default_str();
  app.add_option("--yaw", yaw_deg, "the marker's yaw (deg)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::warn);

  const fs::path dir = fs::temp_directory_path() / fmt::format("markerd-bench-daemon-{}", ::getpid());
  fs::create_directories(dir / "logs");
  // The thesis's lens at the asked resolution.
  markerd::detector::CameraModel::thesis_640x480().scaled_to(width, height).save(dir / "camera.yaml");
  {
    std::ofstream config(dir / "markerd.toml");
    config << fmt::format(R"([camera]
source = "sim"
model = "camera.yaml"
[camera.sim]
fps = {}
rail_mm = {}
turntable_deg = {}
[detector]
workers = {}
[pipeline]
policy = "{}"
[log]
directory = "logs"
fsync = "{}"
[control]
socket = "control.sock"
)",
                          fps, distance_m * 1000 - 300, yaw_deg, workers, policy, fsync);
  }
  double cpu = 0;
  {
    markerd::daemon::Daemon daemon(markerd::daemon::load_daemon_config(dir / "markerd.toml"));
    daemon.start();
    // The first frame renders the scene; measure from the second second on.
    std::this_thread::sleep_for(std::chrono::seconds(1));
    const auto before = daemon.pipeline().stats();
    const std::uint64_t frames_before = daemon.capture().status().frames;
    const double cpu_before = cpu_seconds();
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    const double cpu_after = cpu_seconds();
    const auto after = daemon.pipeline().stats();
    const auto capture = daemon.capture().status();
    const std::uint64_t frames = capture.frames - frames_before;
    cpu = (cpu_after - cpu_before) / static_cast<double>(std::max<std::uint64_t>(frames, 1));
    fmt::print("markerd, simulated source {}x{} at {:g} fps, {} worker(s), {}, fsync {}, {:g} s:\n", width, height, fps,
               workers, policy, fsync, seconds);
    fmt::print("  frames captured   {} (expected {:.0f})\n", frames, fps * seconds);
    fmt::print("  frames dropped    {}\n", after.dropped() - before.dropped());
    fmt::print("  capture to log    p50 {:.2f} ms, p99 {:.2f} ms, max {:.2f} ms (whole run)\n",
               ms(after.capture_to_log.p50), ms(after.capture_to_log.p99), ms(after.capture_to_log.max));
    fmt::print("  detection         p50 {:.2f} ms, p99 {:.2f} ms\n", ms(after.detect_duration.p50),
               ms(after.detect_duration.p99));
    fmt::print("  CPU per frame     {:.2f} ms (all threads: render+noise, detection, log)\n", cpu * 1e3);
    daemon.stop();
    const auto log = daemon.log().stats();
    fmt::print("  log lines         {} ({:.1f} MB)\n", log.writer.lines, static_cast<double>(log.writer.bytes) / 1e6);
  }
  fs::remove_all(dir);
  return 0;
}
