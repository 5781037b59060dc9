#pragma once
// A rate measured by counting (frames detected of frames seen, wrong ids of
// reads) and how far the true rate may lie from it. The Wilson score
// interval: unlike the normal approximation it stays inside [0, 1] and is
// not zero-width at 0 of n or n of n, which is where detection rates sit.

#include <cstdint>
#include <optional>

namespace markerd::base {

struct ProportionInterval {
  double low = 0;
  double high = 1;
};

// The two-sided interval of confidence `z` standard deviations (1.96: 95%)
// for `successes` of `trials`; [0, 1] without trials.
ProportionInterval wilson_interval(std::int64_t successes, std::int64_t trials, double z = 1.959963984540054);

// How many trials a rate measured as `proportion` needs before its Wilson
// interval of confidence `z` leaves out `threshold`, the rate staying as it
// is: the n where an edge of the interval meets the threshold, (p - t)^2 =
// z^2 t (1 - t) / n. Empty when the proportion is the threshold: no count
// tells a rate from itself. At least 1.
std::optional<std::int64_t> wilson_trials_to_exclude(double proportion, double threshold, double z = 1.959963984540054);

}  // namespace markerd::base
