#include "markerd/rig/sim_clock.hpp"

#include <cmath>
#include <stdexcept>

namespace markerd::rig {

namespace {
using seconds_d = std::chrono::duration<double>;
}

SimClock::SimClock(double time_scale) : time_scale_(time_scale), epoch_(steady::now()) {
  if (!std::isfinite(time_scale) || !(time_scale > 0)) {
    throw std::invalid_argument("SimClock: time_scale must be a finite number > 0");
  }
}

SimClock::SimClock(Manual) : manual_(true), epoch_(steady::now()) {}

double SimClock::now() const {
  if (manual_) return static_cast<double>(manual_ns_.load(std::memory_order_acquire)) * 1e-9;
  return to_sim(steady::now());
}

SimClock::steady::time_point SimClock::to_steady(double sim_seconds) const {
  return epoch_ + std::chrono::duration_cast<steady::duration>(seconds_d(sim_seconds / time_scale_));
}

double SimClock::to_sim(steady::time_point t) const {
  return std::chrono::duration_cast<seconds_d>(t - epoch_).count() * time_scale_;
}

void SimClock::advance(double seconds) {
  if (!manual_) throw std::logic_error("SimClock::advance: only a manual clock can be advanced");
  if (!(seconds >= 0)) throw std::invalid_argument("SimClock::advance: seconds must be >= 0");
  manual_ns_.fetch_add(std::llround(seconds * 1e9), std::memory_order_acq_rel);
}

}  // namespace markerd::rig
