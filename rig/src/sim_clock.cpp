#include "markerd/rig/sim_clock.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace markerd::rig {

namespace {
using seconds_d = std::chrono::duration<double>;
}

SimClock::SimClock(double time_scale) : time_scale_(time_scale), epoch_(steady::now()) {
  if (!(time_scale > 0 && time_scale <= kMaxTimeScale)) {
    throw std::invalid_argument(
        fmt::format("SimClock: time_scale must be > 0 and at most {}, got {}", kMaxTimeScale, time_scale));
  }
}

SimClock::SimClock(Manual) : manual_(true), epoch_(steady::now()) {}

double SimClock::now() const {
  if (manual_) return static_cast<double>(manual_ns_.load(std::memory_order_acquire)) * 1e-9;
  return to_sim(steady::now());
}

SimClock::steady::time_point SimClock::to_steady(double sim_seconds) const {
  // A time far beyond any run would overflow the nanosecond count: clamp it.
  const double real_s = std::clamp(sim_seconds / time_scale_, -kMaxAdvance, kMaxAdvance);
  return epoch_ + std::chrono::duration_cast<steady::duration>(seconds_d(std::isnan(real_s) ? 0.0 : real_s));
}

double SimClock::to_sim(steady::time_point t) const {
  return std::chrono::duration_cast<seconds_d>(t - epoch_).count() * time_scale_;
}

void SimClock::advance(double seconds) {
  if (!manual_) throw std::logic_error("SimClock::advance: only a manual clock can be advanced");
  if (!(seconds >= 0 && seconds <= kMaxAdvance)) {
    throw std::invalid_argument(
        fmt::format("SimClock::advance: seconds must be from 0 to {}, got {}", kMaxAdvance, seconds));
  }
  const std::int64_t ns = std::llround(seconds * 1e9);
  constexpr auto kMaxNs = static_cast<std::int64_t>(kMaxAdvance * 1e9);
  std::int64_t now = manual_ns_.load(std::memory_order_acquire);
  do {
    if (now > kMaxNs - ns) {
      throw std::invalid_argument(fmt::format("SimClock::advance: the clock would pass {} s", kMaxAdvance));
    }
  } while (!manual_ns_.compare_exchange_weak(now, now + ns, std::memory_order_acq_rel));
}

}  // namespace markerd::rig
