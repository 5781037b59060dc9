#include "markerd/base/proportion.hpp"

#include <algorithm>
#include <cmath>

namespace markerd::base {

ProportionInterval wilson_interval(std::int64_t successes, std::int64_t trials, double z) {
  if (trials <= 0) return {};
  const auto n = static_cast<double>(trials);
  const double p = static_cast<double>(std::clamp<std::int64_t>(successes, 0, trials)) / n;
  const double z2 = z * z;
  const double centre = (p + z2 / (2 * n)) / (1 + z2 / n);
  const double half = z / (1 + z2 / n) * std::sqrt(p * (1 - p) / n + z2 / (4 * n * n));
  return {std::max(0.0, centre - half), std::min(1.0, centre + half)};
}

std::optional<std::int64_t> wilson_trials_to_exclude(double proportion, double threshold, double z) {
  const double gap = proportion - threshold;
  if (gap == 0) return std::nullopt;
  const double trials = z * z * threshold * (1 - threshold) / (gap * gap);
  // Past any count a run could collect; also keeps the cast defined.
  constexpr double kMost = 1e15;
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(std::min(trials, kMost))));
}

}  // namespace markerd::base
