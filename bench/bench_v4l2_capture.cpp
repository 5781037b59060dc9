// The cost per frame of markerd's V4L2 capture path inside the qemu guest,
// against v4l2-ctl reading the same frames: the figure. Runs in the
// guest, against vivid looped from its HDMI output to its HDMI capture input
// with rendered markers fed into the output (tests/hil/vivid_scene_feeder.hpp,
// the same feeder as the hil_markerd_vivid test):
//
//   tools/hil/hil-run --module 'vivid n_devs=1 node_types=0x101 num_inputs=2 input_types=0x0c
//       num_outputs=1 output_types=0x01 vid_cap_nr=0 vid_out_nr=1' --setup vivid-loop
//       -- build/bench/bench_v4l2_capture
//
// Each round measures, on the same node, input, format (YUYV 640x480 at the
// HDMI timings' 59.94 Hz) and number of mmap buffers (4):
//   markerd   V4l2Source: wait_frame, a frame-pool slot, fill (YUYV to grey
//             in one pass into the slot), release: the capture thread's work
//             without the pipeline. The CPU time of this thread alone
//             (CLOCK_THREAD_CPUTIME_ID), so the feeder's thread is not in it.
//   v4l2-ctl  `v4l2-ctl -d NODE --stream-mmap=4 --stream-count=K`: dequeues
//             each buffer, prints a '<' (to standard error) and queues it
//             again, without reading its pixels. Its CPU time from
//             /proc/PID/schedstat, read when its '<' for the first and for
//             the last measured frame arrive.
// Both are measured over the same frames after the same warmup, so neither
// the start (loading, opening, allocating buffers) nor the first frames
// count. The CPU time is the guest's own accounting (the scheduler's
// nanoseconds); the work vivid's kernel threads do for either (looping the
// output into the capture buffers) is in neither. The guest's clock is the
// host's: a host busy with other work stretches both readers' times, the
// cheaper one's relatively more, so the ratio comes out lower on a loaded
// host. Run it on a quiet one.

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>  // environ (g++ defines _GNU_SOURCE)

// "potential null pointer dereference" in std::string inlined from CLI11's
// CLI::detail::split (as tools/markerctl/main.cpp explains).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "markerd/daemon/capture/pixel_convert.hpp"
#include "markerd/daemon/capture/v4l2_source.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "vivid_scene_feeder.hpp"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace markerd;
using namespace markerd::daemon;

constexpr int kBuffers = 4;  // v4l2-ctl's default for --stream-mmap, and markerd's

// CPU time as the scheduler counts it (nanoseconds), and wall time. The
// user and system split is left out: the tick accounting samples it at
// 250 Hz, a few dozen samples over a run, too few to mean anything.
struct Cost {
  double cpu_s = 0;
  double wall_s = 0;
  Cost operator-(const Cost& other) const { return {cpu_s - other.cpu_s, wall_s - other.wall_s}; }
};

double now_s() { return std::chrono::duration<double>(Clock::now().time_since_epoch()).count(); }

// This thread's.
Cost thread_cost() {
  timespec cpu{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu);
  return {static_cast<double>(cpu.tv_sec) + 1e-9 * static_cast<double>(cpu.tv_nsec), now_s()};
}

// Another process's (single-threaded): /proc/PID/schedstat's time on the CPU.
Cost process_cost(pid_t pid) {
  std::ifstream schedstat(fmt::format("/proc/{}/schedstat", pid));
  std::uint64_t on_cpu_ns = 0;
  if (!(schedstat >> on_cpu_ns)) throw std::runtime_error(fmt::format("cannot read /proc/{}/schedstat", pid));
  return {1e-9 * static_cast<double>(on_cpu_ns), now_s()};
}

// The pixels of a looped frame are those of one of the scenes, byte for byte.
bool shows_a_scene(const detector::GreyView& image, const std::vector<detector::GreyImage>& scenes) {
  return std::any_of(scenes.begin(), scenes.end(), [&](const detector::GreyImage& scene) {
    if (image.width != scene.width() || image.height != scene.height()) return false;
    for (int y = 0; y < image.height; ++y) {
      if (std::memcmp(image.row(y), scene.row(y), static_cast<std::size_t>(image.width)) != 0) return false;
    }
    return true;
  });
}

struct SourceRun {
  Cost cost;
  std::uint64_t first_sequence = 0;
  std::uint64_t last_sequence = 0;
};

// markerd's capture path: `warmup` frames, then `frames` measured.
SourceRun run_source(const V4l2Settings& settings, int warmup, int frames,
                     const std::vector<detector::GreyImage>& scenes) {
  const auto source = make_v4l2_source(settings);
  FramePool pool({.slots = 4, .pixel_bytes = source->geometry().slot_pixel_bytes});
  source->open();
  const auto next = [&]() -> Frame& {
    if (!source->wait_frame(std::chrono::seconds(5))) {
      throw std::runtime_error(source->name() + ": no frame within 5 s");
    }
    Frame* frame = pool.try_acquire();
    if (frame == nullptr) throw std::logic_error("the frame pool is empty");
    source->fill(*frame);
    if (frame->status != FrameStatus::ok) throw std::runtime_error(source->name() + ": " + std::string(frame->cause()));
    return *frame;
  };
  const auto check = [&](Frame& frame) {
    if (!shows_a_scene(frame.image, scenes)) {
      throw std::runtime_error(
          fmt::format("{}: frame {} is not one the feeder sent: vivid does not loop (the "
                      "capture's test pattern instead?)",
                      source->name(), frame.sequence));
    }
  };
  for (int i = 0; i < warmup; ++i) {
    Frame& frame = next();
    if (i == warmup - 1) check(frame);
    pool.release(frame);
  }
  SourceRun run;
  const Cost start = thread_cost();
  for (int i = 0; i < frames; ++i) {
    Frame& frame = next();
    if (i == 0) run.first_sequence = frame.sequence;
    run.last_sequence = frame.sequence;
    pool.release(frame);
  }
  run.cost = thread_cost() - start;
  Frame& last = next();
  check(last);
  pool.release(last);
  source->close();
  return run;
}

// `v4l2-ctl -d NODE --stream-mmap=4 --stream-count=K`, measured from its
// `warmup`th frame to its `warmup + frames`th: it prints a '<' to standard
// error for each frame it dequeues, and its CPU time is read as each of those
// two arrives. What it printed comes back in `printed`.
Cost run_v4l2_ctl(const std::string& program, const std::string& device, int warmup, int frames, std::string& printed) {
  std::vector<std::string> args = {program, "-d", device, fmt::format("--stream-mmap={}", kBuffers),
                                   fmt::format("--stream-count={}", warmup + frames + 10)};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  int err[2];
  if (::pipe2(err, O_CLOEXEC) != 0) throw std::runtime_error(std::string("pipe2: ") + std::strerror(errno));
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, err[1], 2);
  pid_t pid = -1;
  const int error = ::posix_spawn(&pid, program.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(err[1]);
  if (error != 0) {
    ::close(err[0]);
    throw std::runtime_error(fmt::format("cannot run {}: {} (v4l2-ctl is in Debian's v4l-utils: tools/install-deps.sh)",
                                         program, std::strerror(error)));
  }
  std::optional<Cost> at_warmup, at_end;
  int dequeued = 0;
  printed.clear();
  char chunk[256];
  for (;;) {
    const ssize_t n = ::read(err[0], chunk, sizeof chunk);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    for (ssize_t i = 0; i < n; ++i) {
      if (chunk[i] != '<') continue;
      ++dequeued;
      if (dequeued == warmup) at_warmup = process_cost(pid);
      if (dequeued == warmup + frames) at_end = process_cost(pid);
    }
    printed.append(chunk, static_cast<std::size_t>(n));
  }
  ::close(err[0]);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || !at_warmup || !at_end) {
    throw std::runtime_error(fmt::format(
        "{} failed ({}, {} frames): {}", fmt::join(args, " "),
        WIFEXITED(status) ? fmt::format("exit status {}", WEXITSTATUS(status)) : std::string("killed by a signal"),
        dequeued, printed));
  }
  return *at_end - *at_warmup;
}

// v4l2-ctl's count of the frames vivid's sequence skipped ("dropped
// buffers: N" at the end of its per-second lines), over the whole run.
int v4l2_ctl_dropped(const std::string& printed) {
  int dropped = 0;
  const std::string key = "dropped buffers: ";
  for (std::size_t at = printed.find(key); at != std::string::npos; at = printed.find(key, at + 1)) {
    dropped = std::max(dropped, std::atoi(printed.c_str() + at + key.size()));
  }
  return dropped;
}

// The capture node is still where the bench put it: v4l2-ctl streams with
// the node's current input and format, the ones V4l2Source set.
void check_node_state(const std::string& capture) {
  hil::Node n(capture);
  int input = -1;
  hil::must(n.fd(), VIDIOC_G_INPUT, &input, "VIDIOC_G_INPUT");
  v4l2_format f{};
  f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  hil::must(n.fd(), VIDIOC_G_FMT, &f, "VIDIOC_G_FMT");
  if (input != hil::kHdmiInput || f.fmt.pix.pixelformat != V4L2_PIX_FMT_YUYV ||
      f.fmt.pix.width != static_cast<std::uint32_t>(hil::kWidth) ||
      f.fmt.pix.height != static_cast<std::uint32_t>(hil::kHeight)) {
    throw std::runtime_error(fmt::format("{}: input {}, {} {}x{}: not what the bench set up", capture, input,
                                         fourcc_text(f.fmt.pix.pixelformat), f.fmt.pix.width, f.fmt.pix.height));
  }
}

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"markerd's V4L2 capture path against v4l2-ctl, CPU per frame, inside the HIL guest (docs/hil.md)"};
  int frames = 300, warmup = 30, rounds = 5;
  std::string v4l2_ctl = "/usr/bin/v4l2-ctl";
  app.add_option("--frames", frames, "frames measured per run")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--warmup", warmup, "frames read before measuring")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--rounds", rounds, "rounds of both")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--v4l2-ctl", v4l2_ctl, "the v4l2-ctl to run")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  const char* capture = std::getenv("HIL_VIVID_CAPTURE");  // NOLINT(concurrency-mt-unsafe): before any thread
  const char* output = std::getenv("HIL_VIVID_OUTPUT");    // NOLINT(concurrency-mt-unsafe)
  if (capture == nullptr || output == nullptr) {
    std::cerr << "bench_v4l2_capture: no vivid loop (HIL_VIVID_CAPTURE, HIL_VIVID_OUTPUT): run it in the guest,\n"
                 "  tools/hil/hil-run --module 'vivid n_devs=1 node_types=0x101 num_inputs=2 input_types=0x0c "
                 "num_outputs=1 output_types=0x01 vid_cap_nr=0 vid_out_nr=1' --setup vivid-loop -- "
                 "build/bench/bench_v4l2_capture\n";
    return 2;
  }
  try {
    std::vector<detector::GreyImage> scenes;
    std::vector<std::vector<std::uint8_t>> yuyv;
    for (const detector::Scene& scene : hil::feeder_scenes()) {
      scenes.push_back(detector::render_scene(hil::feeder_camera(), scene));
      yuyv.push_back(hil::to_yuyv(scenes.back()));
    }
    hil::select_hdmi_input(capture);
    hil::SceneFeeder feeder(output, yuyv, 60);

    V4l2Settings settings;
    settings.device = capture;
    settings.format = V4l2PixelFormat::yuyv;
    settings.width = hil::kWidth;
    settings.height = hil::kHeight;
    settings.input = hil::kHdmiInput;
    settings.buffers = kBuffers;
    settings.controls = {{"loop_video", true, "bench"}, {"osd_text_mode", std::string("None"), "bench"}};

    fmt::print("{} YUYV {}x{}, input {} (HDMI, looped from {}), {} buffers; {} frames per run after {} warmup\n",
               capture, hil::kWidth, hil::kHeight, hil::kHdmiInput, output, kBuffers, frames, warmup);
    fmt::print("{:>5}  {:>17}  {:>5}  {:>18}  {:>5}  {:>6}\n", "round", "markerd CPU us/fr", "fps",
               "v4l2-ctl CPU us/fr", "fps", "ratio");
    std::vector<double> ours, theirs, ratios;
    for (int round = 1; round <= rounds; ++round) {
      const SourceRun source = run_source(settings, warmup, frames, scenes);
      check_node_state(capture);
      std::string printed;
      const Cost reference = run_v4l2_ctl(v4l2_ctl, capture, warmup, frames, printed);
      check_node_state(capture);
      const double n = frames;
      const double ours_us = 1e6 * source.cost.cpu_s / n;
      const double theirs_us = 1e6 * reference.cpu_s / n;
      ours.push_back(ours_us);
      theirs.push_back(theirs_us);
      ratios.push_back(ours_us / theirs_us);
      fmt::print("{:>5}  {:>17.1f}  {:>5.1f}  {:>18.1f}  {:>5.1f}  {:>6.2f}\n", round, ours_us, n / source.cost.wall_s,
                 theirs_us, n / reference.wall_s, ours_us / theirs_us);
      // vivid's sequence counts the frames its capture thread skipped when it
      // ran late (under TCG it does) and those a reader did not take in time.
      fmt::print("       skipped in vivid's sequence: markerd {} of {}; v4l2-ctl {} of its {}\n",
                 source.last_sequence - source.first_sequence + 1 - static_cast<std::uint64_t>(frames), frames,
                 v4l2_ctl_dropped(printed), warmup + frames + 10);
    }
    if (!feeder.error().empty()) throw std::runtime_error("the feeder stopped: " + feeder.error());
    // The one pass v4l2-ctl does not make, alone: the same conversion of a
    // frame in memory, as often.
    std::vector<std::uint8_t> grey(static_cast<std::size_t>(hil::kWidth) * hil::kHeight);
    const Cost convert_start = thread_cost();
    for (int i = 0; i < frames; ++i) {
      yuyv_to_grey(yuyv[static_cast<std::size_t>(i) % yuyv.size()].data(), 2 * hil::kWidth, hil::kWidth, hil::kHeight,
                   grey.data(), hil::kWidth);
    }
    const Cost convert = thread_cost() - convert_start;
    if (!shows_a_scene(detector::GreyView{grey.data(), hil::kWidth, hil::kHeight, hil::kWidth}, scenes)) {
      throw std::logic_error("yuyv_to_grey did not give the scene back");
    }
    fmt::print(
        "median CPU per frame: markerd's capture path {:.1f} us, v4l2-ctl {:.1f} us; "
        "median of the rounds' ratios {:.2f} (min {:.2f}, max {:.2f})\n",
        median(ours), median(theirs), median(ratios), *std::min_element(ratios.begin(), ratios.end()),
        *std::max_element(ratios.begin(), ratios.end()));
    fmt::print("of which YUYV to grey (yuyv_to_grey on a frame in memory, as often): {:.1f} us per frame\n",
               1e6 * convert.cpu_s / frames);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "bench_v4l2_capture: " << e.what() << '\n';
    return 1;
  }
}
