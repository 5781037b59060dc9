#include "markerd/base/proportion.hpp"

#include <gtest/gtest.h>

namespace markerd::base {
namespace {

constexpr double kZ = 1.959963984540054;

// At 0 of n and n of n the interval has a closed form, z^2 / (n + z^2)
// from the end: the frames a rate of 100% rests on show in its width.
TEST(WilsonInterval, NoneAndAllOfNHaveTheClosedFormBounds) {
  const ProportionInterval none = wilson_interval(0, 50);
  EXPECT_DOUBLE_EQ(none.low, 0);
  EXPECT_NEAR(none.high, kZ * kZ / (50 + kZ * kZ), 1e-12);
  const ProportionInterval all = wilson_interval(50, 50);
  EXPECT_NEAR(all.low, 50 / (50 + kZ * kZ), 1e-12);
  EXPECT_DOUBLE_EQ(all.high, 1);
  // 0 false detections in 10,000 frames: under 4 in 10,000, not "none".
  EXPECT_NEAR(wilson_interval(0, 10000).high, 3.84e-4, 1e-6);
}

TEST(WilsonInterval, ContainsTheRateAndNarrowsWithTrials) {
  const ProportionInterval few = wilson_interval(45, 50);
  EXPECT_NEAR(few.low, 0.78640, 1e-5);
  EXPECT_NEAR(few.high, 0.95652, 1e-5);
  const ProportionInterval many = wilson_interval(450, 500);
  EXPECT_LT(many.low, 0.9);
  EXPECT_GT(many.high, 0.9);
  EXPECT_LT(many.high - many.low, (few.high - few.low) / 2);
  // Symmetric about one half under swapping successes and failures.
  const ProportionInterval other = wilson_interval(5, 50);
  EXPECT_NEAR(other.low, 1 - few.high, 1e-12);
  EXPECT_NEAR(other.high, 1 - few.low, 1e-12);
}

TEST(WilsonInterval, NoTrialsSayNothing) {
  const ProportionInterval none = wilson_interval(0, 0);
  EXPECT_DOUBLE_EQ(none.low, 0);
  EXPECT_DOUBLE_EQ(none.high, 1);
}

}  // namespace
}  // namespace markerd::base
