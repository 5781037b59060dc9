#pragma once
// The simulated time of a rig. Every simulated device of one rig (its axes
// now, a simulated camera later) reads the same SimClock, so that a frame
// stamped at simulated time t sees the axes where they were at t.
//
// A running clock advances `time_scale` simulated seconds per real second of
// std::chrono::steady_clock, counted from its construction; a manual clock
// (tests) advances only when told to, so a test can step a simulation through
// exact instants without sleeping.

#include <atomic>
#include <chrono>
#include <cstdint>

namespace markerd::rig {

class SimClock {
 public:
  using steady = std::chrono::steady_clock;

  // A running clock: simulated seconds = real elapsed seconds * time_scale.
  // time_scale must be > 0 and at most kMaxTimeScale (std::invalid_argument):
  // beyond it a poll period of the axes spans so much simulated time that
  // a drive's events (a switch, a timeout) can no longer be told apart in a
  // double, and the simulation would give false reasons or none.
  static constexpr double kMaxTimeScale = 1000;
  explicit SimClock(double time_scale = 1.0);

  // A clock that stands still until advance() is called:
  // std::make_shared<SimClock>(SimClock::Manual{}).
  struct Manual {};
  explicit SimClock(Manual);

  [[nodiscard]] bool is_manual() const { return manual_; }
  [[nodiscard]] double time_scale() const { return time_scale_; }

  // Simulated seconds since the clock's epoch. Thread-safe.
  [[nodiscard]] double now() const;

  // The mapping between simulated seconds and steady_clock, for stamping
  // simulated data with real times and back. A manual clock maps its
  // simulated seconds 1:1 onto steady_clock from its epoch.
  [[nodiscard]] steady::time_point epoch() const { return epoch_; }
  [[nodiscard]] steady::time_point to_steady(double sim_seconds) const;
  [[nodiscard]] double to_sim(steady::time_point t) const;

  // Manual clocks only (std::logic_error otherwise): moves time forward by
  // `seconds`, from 0 to kMaxAdvance (std::invalid_argument otherwise, and
  // when the clock would pass kMaxAdvance in total).
  static constexpr double kMaxAdvance = 1e9;  // about 31 years, in nanoseconds well within int64
  void advance(double seconds);

  SimClock(const SimClock&) = delete;
  SimClock& operator=(const SimClock&) = delete;

 private:
  double time_scale_ = 1.0;
  bool manual_ = false;
  steady::time_point epoch_;
  // Manual clocks: simulated time in nanoseconds. An atomic because tests
  // advance it from one thread while device threads read it.
  std::atomic<std::int64_t> manual_ns_{0};
};

}  // namespace markerd::rig
