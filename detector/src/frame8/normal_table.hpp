#pragma once
// The standard normal distribution and density, tabulated: the frame8
// detector's models need tens of them per pixel or profile sample, and erfc
// costs more than the rest of that work.

#include <array>
#include <cmath>
#include <cstddef>
#include <numbers>

namespace markerd::detail {

struct NormalTable {
  static constexpr double kRange = 8;
  static constexpr int kPerUnit = 64;
  static constexpr int kSize = static_cast<int>(2 * kRange * kPerUnit) + 2;
  std::array<double, kSize> cdf_table{}, pdf_table{};

  NormalTable() {
    for (int i = 0; i < kSize; ++i) {
      const double z = -kRange + static_cast<double>(i) / kPerUnit;
      cdf_table[static_cast<std::size_t>(i)] = 0.5 * std::erfc(-z / std::numbers::sqrt2);
      pdf_table[static_cast<std::size_t>(i)] = std::exp(-0.5 * z * z) / std::sqrt(2 * std::numbers::pi);
    }
  }

  // Phi(z) alone, as at() gives it.
  [[nodiscard]] double cdf(double z) const {
    if (z <= -kRange) return 0;
    if (z >= kRange) return 1;
    const double f = (z + kRange) * kPerUnit;
    const auto i = static_cast<std::size_t>(f);
    const double t = f - static_cast<double>(i);
    return cdf_table[i] + t * (cdf_table[i + 1] - cdf_table[i]);
  }

  // Phi(z) and phi(z), linearly interpolated (off by under 1e-5).
  void at(double z, double& c, double& p) const {
    if (z <= -kRange) {
      c = p = 0;
      return;
    }
    if (z >= kRange) {
      c = 1;
      p = 0;
      return;
    }
    const double f = (z + kRange) * kPerUnit;
    const auto i = static_cast<std::size_t>(f);
    const double t = f - static_cast<double>(i);
    c = cdf_table[i] + t * (cdf_table[i + 1] - cdf_table[i]);
    p = pdf_table[i] + t * (pdf_table[i + 1] - pdf_table[i]);
  }
};

inline const NormalTable& normal_table() {
  static const NormalTable table;
  return table;
}

}  // namespace markerd::detail
