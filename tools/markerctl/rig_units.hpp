#pragma once
// Values with units on markerctl rig's command line: the rail in mm, cm or m,
// the turntable in deg or rad. A bare number is refused: "250" means
// millimetres to one person and metres to the next, and a rail moved by the
// wrong factor hits its end.

#include <array>
#include <numbers>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "markerd/rig/axis.hpp"

namespace markerctl {

// Units a value may carry, scaled to the quantity's base unit (mm, deg).
struct UnitScale {
  std::string_view name;
  double scale;
};
constexpr std::array<UnitScale, 3> kLengthUnits{{{"mm", 1.0}, {"cm", 10.0}, {"m", 1000.0}}};
constexpr std::array<UnitScale, 2> kAngleUnits{{{"deg", 1.0}, {"rad", 180.0 / std::numbers::pi}}};

struct AxisKind {
  const char* name;    // "rail", "turntable": the config's axis
  const char* option;  // "--rail"
  std::span<const UnitScale> units;
  const char* examples;
};
constexpr AxisKind kRail{"rail", "--rail", kLengthUnits, "250mm, 25cm, 0.25m"};
constexpr AxisKind kTurntable{"turntable", "--turntable", kAngleUnits, "30deg, 0.5rad"};

// "mm, cm or m": the units a kind takes, for errors.
std::string unit_list(std::span<const UnitScale> units);
std::optional<double> scale_of(std::span<const UnitScale> units, std::string_view unit);
// A value with its unit, in the axis kind's base unit (mm, deg); a usage
// error naming the option otherwise.
double parse_quantity(std::string_view text, const AxisKind& kind);
// A base-unit value in the axis's own unit (its config's `unit`).
double to_axis_units(double base_value, const AxisKind& kind, const markerd::rig::AxisSettings& axis,
                     const std::string& context);

}  // namespace markerctl
