// markerd_soak: the soak test (docs/soak.md). Runs markerd on the simulated
// rig for an hour (by default) of back-to-back sweeps under kill -9, a disk
// that fills, a camera that drops out and followers that come and go; then
// checks the records, the logs and markerd's memory, descriptors and threads.
// Needs root (it mounts a tmpfs). Exit status 0: every check held.

// Before anything includes <string>: g++ 12's false "potential null pointer
// dereference" in CLI11's string splitting, as in tools/markerctl/main.cpp.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include <fmt/format.h>

#include <cctype>
#include <exception>
#include <iostream>
#include <stdexcept>
#include <string>

#include "soak.hpp"

namespace {

// "3600", "3600s", "90m", "1h", "1.5h": seconds.
std::chrono::seconds parse_duration(const std::string& text) {
  std::size_t used = 0;
  double value = 0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    throw CLI::ValidationError("--duration", "not a duration: '" + text + "' (e.g. 3600, 300s, 90m, 1h)");
  }
  const std::string unit = text.substr(used);
  double scale = 1;
  if (unit == "h") {
    scale = 3600;
  } else if (unit == "m" || unit == "min") {
    scale = 60;
  } else if (!unit.empty() && unit != "s") {
    throw CLI::ValidationError("--duration", "unknown unit '" + unit + "' in '" + text + "' (s, m or h)");
  }
  if (!(value > 0) || value * scale > 7 * 24 * 3600) {
    throw CLI::ValidationError("--duration", "must be more than 0 and at most a week, got '" + text + "'");
  }
  return std::chrono::seconds(static_cast<long long>(value * scale));
}

}  // namespace

int main(int argc, char** argv) {
  markerd::soak::Options o;
  o.markerd = MARKERD_PATH;
  o.markerctl = MARKERCTL_PATH;
  o.source_dir = MARKERD_SOURCE_DIR;
  o.work_dir = MARKERD_SOAK_WORK_DIR;  // the build directory's soak/
  std::string duration = "1h";

  CLI::App app(
      "The soak test: markerd on the simulated rig, sweeps back to back, kill -9 at random moments, a disk that "
      "fills and frees, a camera that drops out, followers that come and go; then every record checked and "
      "markerd's memory, descriptors and threads compared. Runs as root (it mounts a tmpfs). docs/soak.md.");
  app.add_option("--duration", duration, "How long: 3600, 300s, 90m, 1h")->capture_default_str();
  app.add_option("--time-scale", o.time_scale, "The simulated rig's time scale")
      ->check(CLI::Range(1.0, 1000.0))
      ->capture_default_str();
  app.add_option("--seed", o.seed, "Seeds every random choice")->capture_default_str();
  app.add_option("--kills-per-hour", o.kills_per_hour, "kill -9 of markerd, at random moments")
      ->check(CLI::Range(0.0, 3600.0))
      ->capture_default_str();
  app.add_option("--calm-tail", o.calm_tail, "The last fraction of the duration without kills, for the memory trend")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  app.add_option("--work-dir", o.work_dir, "Where everything goes (new, empty, or an earlier soak's)")
      ->capture_default_str();
  app.add_option("--disk-mib", o.disk_mib, "Size of the tmpfs for markerd's logs and state")
      ->check(CLI::Range(16, 4096))
      ->capture_default_str();
  app.add_option("--disk-fills-per-hour", o.disk_fills_per_hour, "How often the disk is filled")
      ->check(CLI::Range(0.0, 360.0))
      ->capture_default_str();
  app.add_option("--disk-full-s", o.disk_full_s, "How long it stays full")
      ->check(CLI::Range(1.0, 600.0))
      ->capture_default_str();
  app.add_option("--camera-outage-every-s", o.camera_outage_every_s,
                 "The simulated camera drops out this often (0: never)")
      ->check(CLI::Range(0.0, 86400.0))
      ->capture_default_str();
  app.add_option("--camera-outage-s", o.camera_outage_s, "for this long")
      ->check(CLI::Range(0.1, 60.0))
      ->capture_default_str();
  app.add_option("--max-followers", o.max_followers, "Followers attached at most")
      ->check(CLI::Range(0, 12))
      ->capture_default_str();
  app.add_option("--follower-changes-per-minute", o.follower_changes_per_minute, "Attach or detach one, this often")
      ->check(CLI::Range(0.0, 600.0))
      ->capture_default_str();
  app.add_option("--stalls-per-hour", o.stalls_per_hour,
                 "A detections follower stopped (SIGSTOP) for 30 to 90 s, this often")
      ->check(CLI::Range(0.0, 3600.0))
      ->capture_default_str();
  app.add_option("--sample-every-s", o.sample_every_s, "markerd's RSS, threads and descriptors, this often")
      ->check(CLI::Range(0.5, 600.0))
      ->capture_default_str();
  app.add_option("--warm-up-s", o.warm_up_s, "A markerd's memory is judged after this much of its life")
      ->check(CLI::Range(0.0, 3600.0))
      ->capture_default_str();
  app.add_option("--markerd", o.markerd, "The markerd to soak")->capture_default_str();
  app.add_option("--markerctl", o.markerctl, "The markerctl the followers run")->capture_default_str();
  // A mistake on the command line: exit status 2, as for a soak that cannot begin.
  try {
    app.parse(argc, argv);
    o.duration = parse_duration(duration);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (o.camera_outage_every_s > 0 && o.camera_outage_s >= o.camera_outage_every_s) {
    std::cerr << "markerd_soak: --camera-outage-s must be shorter than --camera-outage-every-s\n";
    return 2;
  }
  try {
    return markerd::soak::run_soak(o);
  } catch (const std::exception& e) {
    std::cerr << "markerd_soak: " << e.what() << "\n";
    return 2;
  }
}
