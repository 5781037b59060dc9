#include <gtest/gtest.h>

#include <cmath>

#include "markerd/rig/motion_profile.hpp"

using markerd::rig::TrapezoidProfile;

TEST(TrapezoidProfile, LongMoveCruisesAtMaxVelocity) {
  const TrapezoidProfile p(1000, 100, 50);  // 2 s to reach 100, 100 units each ramp
  EXPECT_DOUBLE_EQ(p.peak_velocity(), 100);
  EXPECT_NEAR(p.duration(), 2 + 8 + 2, 1e-12);
  EXPECT_NEAR(p.position_at(1), 25, 1e-12);
  EXPECT_NEAR(p.position_at(2), 100, 1e-12);
  EXPECT_NEAR(p.position_at(6), 500, 1e-12);
  EXPECT_NEAR(p.position_at(11), 975, 1e-12);
  EXPECT_NEAR(p.position_at(12), 1000, 1e-12);
  EXPECT_NEAR(p.position_at(99), 1000, 1e-12);
  EXPECT_NEAR(p.velocity_at(5), 100, 1e-12);
  EXPECT_NEAR(p.velocity_at(11), 50, 1e-12);
}

TEST(TrapezoidProfile, ShortMoveIsATriangle) {
  const TrapezoidProfile p(100, 1000, 100);  // never reaches v_max: peak sqrt(a d) = 100
  EXPECT_NEAR(p.peak_velocity(), 100, 1e-9);
  EXPECT_NEAR(p.duration(), 2, 1e-9);
  EXPECT_NEAR(p.position_at(1), 50, 1e-9);
}

TEST(TrapezoidProfile, TimeAtInvertsPositionAt) {
  for (double v_start : {0.0, 30.0, 150.0}) {
    const TrapezoidProfile p(1000, 100, 50, v_start);
    for (double x = 0; x <= 1000; x += 7.25) {
      EXPECT_NEAR(p.position_at(p.time_at(x)), x, 1e-6) << "v_start " << v_start << " x " << x;
    }
    // Monotonic: steps are due in order.
    double last = -1;
    for (int n = 1; n <= 1000; ++n) {
      const double t = p.time_at(n);
      EXPECT_GT(t, last);
      last = t;
    }
    EXPECT_NEAR(p.time_at(1000), p.duration(), 1e-9);
  }
}

TEST(TrapezoidProfile, StartingAboveMaxDeceleratesFirst) {
  const TrapezoidProfile p(1000, 100, 50, 200);
  EXPECT_DOUBLE_EQ(p.peak_velocity(), 100);
  EXPECT_NEAR(p.velocity_at(0), 200, 1e-12);
  EXPECT_NEAR(p.velocity_at(1), 150, 1e-12);
  EXPECT_NEAR(p.position_at(p.duration()), 1000, 1e-9);
}

TEST(TrapezoidProfile, BrakingCoversItsStoppingDistance) {
  const auto b = TrapezoidProfile::braking(100, 50);
  EXPECT_NEAR(b.distance(), 100, 1e-12);
  EXPECT_NEAR(b.duration(), 2, 1e-12);
  EXPECT_NEAR(b.position_at(1), 75, 1e-12);
  // A move shorter than the stopping distance brakes (and says how far it went).
  const TrapezoidProfile p(10, 100, 50, 100);
  EXPECT_NEAR(p.distance(), 100, 1e-12);
}

TEST(TrapezoidProfile, RejectsBadArguments) {
  EXPECT_THROW(TrapezoidProfile(-1, 1, 1), std::invalid_argument);
  EXPECT_THROW(TrapezoidProfile(1, 0, 1), std::invalid_argument);
  EXPECT_THROW(TrapezoidProfile(1, 1, 0), std::invalid_argument);
  EXPECT_THROW(TrapezoidProfile(1, 1, std::nan("")), std::invalid_argument);
}
