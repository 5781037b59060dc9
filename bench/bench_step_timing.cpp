// Step timing of the GPIO stepper's step thread, against the recording line
// backend (which only stamps CLOCK_MONOTONIC per edge, like a logic analyser
// on the step line). For each rate: one move that ramps up in 0.1 s, cruises,
// and ramps down; every step's rising edge is compared with its planned time,
// move_origin + TrapezoidProfile::time_at(n). Prints Markdown: the figures of
// docs/rig-gpio.md come from this program.
//
//   bench_step_timing [--rt-priority 50] [--seconds 2] [--rates 1000,2000,5000]
//
// Then a sweep in 500 steps/s increments up to 10000 steps/s, beyond the cap
// configurations may ask for (kGpioStepperMaxStepRate), finds the highest
// rate moved without a missed deadline.

// First, before anything includes <string>: g++ 12 at -O2 reports a false
// "potential null pointer dereference" in std::string inlined from CLI11's
// CLI::detail::split (as tools/markerctl/main.cpp explains).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "markerd/rig/gpio_stepper.hpp"
#include "markerd/rig/motion_profile.hpp"
#include "markerd/rig/testing/gpio_recording.hpp"

namespace {

using namespace markerd::rig;
using namespace std::chrono_literals;

struct Result {
  double rate = 0;
  std::size_t steps = 0;
  double achieved_rate = 0;                   // steps/s over the cruise, from the recorded edges
  double p50_us = 0, p99_us = 0, max_us = 0;  // |actual - planned| per step, slips included
  double interval_p50_us = 0, interval_p99_us = 0, interval_max_us = 0;  // |actual - planned| per interval
  double max_lateness_us = 0;  // the step thread's own measure, against its slipped schedule
  std::uint64_t missed = 0;
};

double percentile(std::vector<double> v, double q) {
  const auto k = static_cast<std::size_t>(
      std::min<double>(static_cast<double>(v.size()) - 1, std::floor(q * static_cast<double>(v.size()))));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

std::string load_average() {
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  in >> one >> five >> fifteen;
  return fmt::format("{} {} {}", one, five, fifteen);
}

constexpr double kSweepMax = 10000;

class Bench {
 public:
  explicit Bench(int rt_priority)
      : gpio_("bench", {"STEP", "DIR", "ENABLE"}, std::size_t{1} << 22), drive_("bench", settings(rt_priority), gpio_) {
    drive_.enable(true);
  }

  Result run(double rate, double seconds) {
    // A 0.1 s ramp each way around the cruise.
    const double accel = rate / 0.1;
    const auto steps = static_cast<std::int64_t>(std::llround(rate * seconds));
    const std::size_t before = gpio_.edge_count("STEP");
    const std::uint64_t missed_before = drive_.stats().missed_deadlines;
    direction_ = -direction_;
    drive_.start_move(drive_.status().position_steps + direction_ * steps, rate, accel);
    while (drive_.status().busy) std::this_thread::sleep_for(10ms);
    const auto status = drive_.status();
    if (status.alarm) throw std::runtime_error(status.alarm_cause);

    const TrapezoidProfile plan(static_cast<double>(steps), rate, accel);
    const double origin = std::chrono::duration<double>(drive_.stats().move_origin).count();
    std::vector<double> rises;
    const auto edges = gpio_.edges("STEP");
    for (std::size_t i = before; i < edges.size(); ++i) {
      if (edges[i].active) rises.push_back(std::chrono::duration<double>(edges[i].time).count());
    }
    if (rises.size() != static_cast<std::size_t>(steps)) {
      throw std::runtime_error(fmt::format("{} steps recorded, {} planned", rises.size(), steps));
    }
    std::vector<double> errors_us;
    std::vector<double> interval_errors_us;
    errors_us.reserve(rises.size());
    interval_errors_us.reserve(rises.size());
    for (std::size_t n = 0; n < rises.size(); ++n) {
      const double planned = origin + plan.time_at(static_cast<double>(n + 1));
      errors_us.push_back(std::abs(rises[n] - planned) * 1e6);
      if (n == 0) continue;
      const double planned_interval = plan.time_at(static_cast<double>(n + 1)) - plan.time_at(static_cast<double>(n));
      interval_errors_us.push_back(std::abs((rises[n] - rises[n - 1]) - planned_interval) * 1e6);
    }
    // The cruise: between the ends of the two ramps.
    const auto ramp_steps = static_cast<std::size_t>(std::ceil(rate * rate / (2 * accel))) + 1;
    const std::size_t first = ramp_steps, last = rises.size() - 1 - ramp_steps;
    Result r;
    r.rate = rate;
    r.steps = rises.size();
    r.achieved_rate = static_cast<double>(last - first) / (rises[last] - rises[first]);
    r.p50_us = percentile(errors_us, 0.5);
    r.p99_us = percentile(errors_us, 0.99);
    r.max_us = *std::max_element(errors_us.begin(), errors_us.end());
    r.interval_p50_us = percentile(interval_errors_us, 0.5);
    r.interval_p99_us = percentile(interval_errors_us, 0.99);
    r.interval_max_us = *std::max_element(interval_errors_us.begin(), interval_errors_us.end());
    r.max_lateness_us = static_cast<double>(drive_.stats().max_lateness.count()) / 1e3;
    r.missed = drive_.stats().missed_deadlines - missed_before;
    return r;
  }

  [[nodiscard]] bool realtime() const { return drive_.stats().realtime; }

 private:
  static GpioStepperSettings settings(int rt_priority) {
    GpioStepperSettings s;
    s.step = {"bench", "STEP"};
    s.dir = {"bench", "DIR"};
    s.enable = {"bench", "ENABLE"};
    s.step_pulse = 5us;
    s.dir_setup = 10us;
    s.enable_settle = 1ms;
    s.max_step_rate = kSweepMax;  // above the configurable cap: measuring it is the point
    s.rt_priority = rt_priority;
    return s;
  }

  RecordingGpioBackend gpio_;
  GpioStepperDrive drive_;
  std::int64_t direction_ = -1;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("Step timing of the GPIO stepper's step thread against its planned profile");
  int rt_priority = 50;
  double seconds = 2;
  std::vector<double> rates{1000, 2000, 5000};
  app.add_option("--rt-priority", rt_priority, "SCHED_FIFO priority of the step thread, 0 = normal scheduling")
      ->check(CLI::Range(0, 99))
      ->capture_default_str();
  app.add_option("--seconds", seconds, "length of each move, seconds")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--rates", rates, "step rates of the table, steps/s, comma-separated")
      ->delimiter(',')
      ->check(CLI::Range(1.0, kSweepMax));
  CLI11_PARSE(app, argc, argv);

  try {
    Bench bench(rt_priority);
    const std::string load_before = load_average();
    fmt::print("## GPIO step timing (recording backend, step pulse 5 us)\n\n");
    fmt::print("step thread: {}; load average before: {}\n\n",
               bench.realtime() ? fmt::format("SCHED_FIFO {}", rt_priority) : std::string("normal scheduling"),
               load_before);
    fmt::print(
        "| rate (steps/s) | steps | achieved (steps/s) | error p50 (us) | p99 (us) | max (us) | interval error p50 "
        "(us) | p99 (us) | max (us) | max lateness (us) | missed |\n");
    fmt::print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n");
    for (const double rate : rates) {
      const Result r = bench.run(rate, seconds);
      fmt::print("| {:.0f} | {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {} |\n",
                 r.rate, r.steps, r.achieved_rate, r.p50_us, r.p99_us, r.max_us, r.interval_p50_us, r.interval_p99_us,
                 r.interval_max_us, r.max_lateness_us, r.missed);
      std::fflush(stdout);
    }

    fmt::print("\nsweep, {} s per rate:\n\n", seconds / 2);
    fmt::print("| rate (steps/s) | error p99 (us) | interval error p99 (us) | max lateness (us) | missed |\n");
    fmt::print("| ---: | ---: | ---: | ---: | ---: |\n");
    double highest_clean = 0;
    bool clean_so_far = true;
    for (double rate = 500; rate <= kSweepMax; rate += 500) {
      const Result r = bench.run(rate, seconds / 2);
      fmt::print("| {:.0f} | {:.1f} | {:.1f} | {:.1f} | {} |\n", r.rate, r.p99_us, r.interval_p99_us, r.max_lateness_us,
                 r.missed);
      std::fflush(stdout);
      clean_so_far = clean_so_far && r.missed == 0;
      if (clean_so_far) highest_clean = rate;
    }
    fmt::print(
        "\nhighest rate without a missed deadline at it and below: {:.0f} steps/s (configurations are capped "
        "at {:.0f})\n",
        highest_clean, kGpioStepperMaxStepRate);
    fmt::print("load average after: {}\n", load_average());
  } catch (const std::exception& e) {
    fmt::print(stderr, "bench_step_timing: {}\n", e.what());
    return 1;
  }
  return 0;
}
