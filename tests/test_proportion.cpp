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

// The count a rate needs before its interval tells it from a threshold:
// 100% at a threshold of 90% needs 35 frames (0.9 z^2 / 0.1 = 34.6), and
// 80% the same (z^2 0.09 / 0.01); 34 of 34 still reaches below 90%.
TEST(WilsonTrialsToExclude, TheCountWhereTheIntervalLeavesTheThresholdOut) {
  EXPECT_EQ(wilson_trials_to_exclude(1.0, 0.9), 35);
  EXPECT_GE(wilson_interval(35, 35).low, 0.9);
  EXPECT_LT(wilson_interval(34, 34).low, 0.9);
  EXPECT_EQ(wilson_trials_to_exclude(0.8, 0.9), 35);
  EXPECT_LT(wilson_interval(28, 35).high, 0.9);
  EXPECT_GE(wilson_interval(24, 30).high, 0.9);
  // Far from the threshold a frame or two is enough; on it, nothing is.
  EXPECT_EQ(wilson_trials_to_exclude(0.0, 0.9), 1);
  EXPECT_EQ(wilson_trials_to_exclude(0.9, 0.9), std::nullopt);
  EXPECT_EQ(wilson_trials_to_exclude(0.93, 0.9), 385);  // z^2 0.09 / 0.0009 = 384.2
}

}  // namespace
}  // namespace markerd::base
