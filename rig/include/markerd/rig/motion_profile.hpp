#pragma once
// The trapezoidal (constant acceleration) velocity profile shared by every
// backend that plans its own motion: the GPIO stepper times its steps from it,
// the simulated axis and the simulated Modbus drive move along it.

namespace markerd::rig {

class TrapezoidProfile {
 public:
  TrapezoidProfile() = default;
  // A move of `distance` >= 0 starting at velocity `v_start` (0 <= v_start, in the
  // direction of motion) and ending at rest, with |velocity| <= v_max and
  // |acceleration| <= accel. If v_start is above v_max it first decelerates to
  // v_max. If the distance is shorter than the braking distance from v_start,
  // the profile overshoots: use braking() for stops instead.
  TrapezoidProfile(double distance, double v_max, double accel, double v_start = 0);

  // Braking from v_start to rest at `accel`: distance v_start^2 / (2 accel).
  static TrapezoidProfile braking(double v_start, double accel);

  [[nodiscard]] double distance() const { return distance_; }
  [[nodiscard]] double duration() const { return t1_ + t2_ + t3_; }
  [[nodiscard]] double peak_velocity() const { return v_peak_; }

  // Position and velocity at time t (clamped to [0, duration()]).
  [[nodiscard]] double position_at(double t) const;
  [[nodiscard]] double velocity_at(double t) const;
  // The time at which the position first reaches p (clamped to [0, distance()]):
  // step n of a stepper is due at time_at(n).
  [[nodiscard]] double time_at(double p) const;

 private:
  double distance_ = 0, v_start_ = 0, v_peak_ = 0, accel_ = 1;
  double t1_ = 0, t2_ = 0, t3_ = 0;  // accelerate (or decelerate to v_peak), cruise, decelerate
  double d1_ = 0, d2_ = 0;           // distance covered by the end of phase 1 and phase 2
};

}  // namespace markerd::rig
