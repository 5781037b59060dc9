#pragma once
// The soak: markerd on the simulated rig running one sweep after another for
// a long time at a high time scale, while the soak attaches and detaches
// followers, kills markerd with SIGKILL at random moments (and starts it
// again, as systemd would), fills its small disk and frees it, and its
// simulated camera drops out on a schedule. It samples markerd's memory,
// threads and descriptors, watches every JSON-lines file markerd writes, and
// at the end checks the runs' records (run_checks.hpp). docs/soak.md.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <string>

namespace markerd::soak {

struct Options {
  std::chrono::seconds duration{3600};
  double time_scale = 100;  // the simulated rig's
  std::uint64_t seed = 1;
  double kills_per_hour = 30;  // kill -9, at exponentially distributed moments
  double calm_tail = 0.25;     // the last fraction of the duration without kills (one markerd lives through it)
  std::filesystem::path work_dir;
  std::uint64_t disk_mib = 64;  // the tmpfs holding markerd's logs and state
  double disk_fills_per_hour = 12;
  double disk_full_s = 20;            // how long the disk stays full
  double camera_outage_every_s = 90;  // [camera.sim] outage_every_s
  double camera_outage_s = 3;
  int max_followers = 4;
  double follower_changes_per_minute = 6;
  double stalls_per_hour = 60;  // a detections follower stopped (SIGSTOP) for a few seconds
  double sample_every_s = 5;
  double warm_up_s = 60;  // RSS before this much of a markerd's life is not judged
  std::string markerd;    // the programs
  std::string markerctl;
  std::string source_dir;  // the repository (config/rig-sim.toml, the camera model)
};

// Runs the soak; prints the summary; 0 when every check held, 1 otherwise.
// std::runtime_error when it cannot even begin (not root, a work directory
// that is not the soak's).
int run_soak(const Options& options);

}  // namespace markerd::soak
