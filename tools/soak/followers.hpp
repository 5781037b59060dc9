#pragma once
// Clients that follow markerd while the soak runs: `markerctl detections`
// (the detection stream) and `markerctl sweep status --follow`, attached
// and detached at random, now and then stopped for a while (SIGSTOP: a
// reader that falls behind) and let go again. A detections follower's
// output is checked when it ends: every complete line it printed is a JSON
// object.

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "support/child_process.hpp"

namespace markerd::soak {

struct FollowerTotals {
  std::uint64_t attached = 0;
  std::uint64_t detached = 0;          // ended by the soak (SIGTERM or SIGKILL)
  std::uint64_t ended_by_markerd = 0;  // ended by themselves: markerd killed, a run followed to its end
  std::uint64_t stalls = 0;            // SIGSTOPs (a reader falling behind)
  std::uint64_t lines = 0;             // detection lines the followers printed, all parsed
  std::uint64_t bad_lines = 0;
  std::uint64_t dropped_notices = 0;  // "lines dropped" notices on their stderr
};

class Followers {
 public:
  Followers(std::string markerctl, std::filesystem::path socket, std::filesystem::path directory);

  // Starts a follower of a random kind.
  void attach(std::mt19937_64& rng);
  // Ends a random follower that is not stalled (SIGTERM or SIGKILL).
  void detach(std::mt19937_64& rng, std::vector<std::string>& problems);
  // Stops a random detections follower for `for_time` (it reads nothing meanwhile).
  void stall(std::mt19937_64& rng, std::chrono::milliseconds for_time);
  // Lets stalled followers go on when their time is up, and collects the ones that ended.
  void tick(std::vector<std::string>& problems);
  // Ends them all.
  void detach_all(std::vector<std::string>& problems);

  [[nodiscard]] int attached() const { return static_cast<int>(followers_.size()); }
  [[nodiscard]] const FollowerTotals& totals() const { return totals_; }

 private:
  struct Follower {
    test_support::ChildProcess process;
    bool detections = false;
    std::filesystem::path out;
    std::filesystem::path err;
    bool stalled = false;
    std::chrono::steady_clock::time_point stalled_until{};
  };
  void finish(Follower& follower, bool killed_by_us, std::vector<std::string>& problems);

  std::string markerctl_;
  std::filesystem::path socket_;
  std::filesystem::path directory_;
  std::vector<Follower> followers_;
  std::uint64_t next_number_ = 1;
  FollowerTotals totals_;
};

}  // namespace markerd::soak
