#pragma once
// The renderer's random numbers (internal to it): the backgrounds
// (render_background.cpp) and the sensor noise (render.cpp) draw from it.

#include <cstdint>
#include <random>

namespace markerd::detector::render {

// Variates from mt19937_64 by our own formulas: the standard distributions
// are implementation-defined, and the rendered bytes must not change with
// the standard library.
class Random {
 public:
  explicit Random(std::uint64_t seed) : engine_(seed) {}
  std::uint64_t bits() { return engine_(); }
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  int integer(int lo, int hi_inclusive) { return lo + static_cast<int>(uniform() * (hi_inclusive - lo + 1)); }

 private:
  std::mt19937_64 engine_;
};

}  // namespace markerd::detector::render
