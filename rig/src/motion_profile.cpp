#include "markerd/rig/motion_profile.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace markerd::rig {

TrapezoidProfile::TrapezoidProfile(double distance, double v_max, double accel, double v_start)
    : distance_(distance), v_start_(v_start), accel_(accel) {
  if (!(distance >= 0) || !(v_max > 0) || !(accel > 0) || !(v_start >= 0)) {
    throw std::invalid_argument("TrapezoidProfile: distance and v_start must be >= 0, v_max and accel > 0");
  }
  const double braking_distance = v_start * v_start / (2 * accel);
  if (distance <= braking_distance) {
    // Too short to stop in: brake, and report the distance actually covered.
    *this = braking(v_start, accel);
    return;
  }
  // Peak of the triangle through v_start; capped by v_max (a trapezoid). If
  // v_start is above v_max, phase 1 decelerates to v_max.
  const double v_triangle = std::sqrt(accel * distance + v_start * v_start / 2);
  v_peak_ = std::min(v_triangle, v_max);
  if (v_start > v_max) v_peak_ = v_max;
  t1_ = std::abs(v_peak_ - v_start) / accel;
  d1_ = std::abs(v_peak_ * v_peak_ - v_start * v_start) / (2 * accel);
  t3_ = v_peak_ / accel;
  const double d3 = v_peak_ * v_peak_ / (2 * accel);
  const double cruise = std::max(0.0, distance - d1_ - d3);
  t2_ = v_peak_ > 0 ? cruise / v_peak_ : 0;
  d2_ = d1_ + cruise;
}

TrapezoidProfile TrapezoidProfile::braking(double v_start, double accel) {
  if (!(accel > 0) || !(v_start >= 0)) throw std::invalid_argument("TrapezoidProfile::braking: bad arguments");
  TrapezoidProfile p;
  p.accel_ = accel;
  p.v_start_ = v_start;
  p.v_peak_ = v_start;
  p.t3_ = v_start / accel;
  p.distance_ = v_start * v_start / (2 * accel);
  return p;
}

double TrapezoidProfile::position_at(double t) const {
  t = std::clamp(t, 0.0, duration());
  if (t < t1_) {
    const double s = v_peak_ >= v_start_ ? 1.0 : -1.0;
    return v_start_ * t + s * accel_ * t * t / 2;
  }
  if (t < t1_ + t2_) return d1_ + v_peak_ * (t - t1_);
  const double to_end = duration() - t;
  return distance_ - accel_ * to_end * to_end / 2;
}

double TrapezoidProfile::velocity_at(double t) const {
  if (t <= 0) return v_start_;
  if (t >= duration()) return 0;
  if (t < t1_) return v_start_ + (v_peak_ >= v_start_ ? 1.0 : -1.0) * accel_ * t;
  if (t < t1_ + t2_) return v_peak_;
  return accel_ * (duration() - t);
}

double TrapezoidProfile::time_at(double p) const {
  p = std::clamp(p, 0.0, distance_);
  if (p < d1_) {
    // Solve v_start t +- a t^2 / 2 = p for the first root.
    if (v_peak_ >= v_start_) return (std::sqrt(v_start_ * v_start_ + 2 * accel_ * p) - v_start_) / accel_;
    return (v_start_ - std::sqrt(std::max(0.0, v_start_ * v_start_ - 2 * accel_ * p))) / accel_;
  }
  if (p < d2_) return t1_ + (p - d1_) / v_peak_;
  // Counted back from the end, where the profile comes to rest: stable near it.
  return duration() - std::sqrt(2 * (distance_ - p) / accel_);
}

}  // namespace markerd::rig
