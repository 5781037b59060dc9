#include "rig_units.hpp"

#include <fmt/format.h>

#include "common.hpp"

namespace markerctl {

std::string unit_list(std::span<const UnitScale> units) {
  std::string list;
  for (std::size_t i = 0; i < units.size(); ++i) {
    if (i > 0) list += i + 1 == units.size() ? " or " : ", ";
    list += units[i].name;
  }
  return list;
}

std::optional<double> scale_of(std::span<const UnitScale> units, std::string_view unit) {
  for (const auto& u : units) {
    if (u.name == unit) return u.scale;
  }
  return std::nullopt;
}

double parse_quantity(std::string_view text, const AxisKind& kind) {
  const auto parsed = split_number(text);
  if (!parsed) {
    throw usage_error(kind.option, fmt::format("'{}' is not a value with a unit (examples: {})", text, kind.examples));
  }
  if (parsed->unit.empty()) {
    throw usage_error(kind.option,
                      fmt::format("'{}' needs a unit: {} (examples: {})", text, unit_list(kind.units), kind.examples));
  }
  const auto scale = scale_of(kind.units, parsed->unit);
  if (!scale) {
    throw usage_error(kind.option, fmt::format("'{}': unknown unit '{}' for the {} (use {})", text, parsed->unit,
                                               kind.name, unit_list(kind.units)));
  }
  return parsed->value * *scale;
}

double to_axis_units(double base_value, const AxisKind& kind, const markerd::rig::AxisSettings& axis,
                     const std::string& context) {
  const auto scale = scale_of(kind.units, axis.unit);
  if (!scale) {
    throw runtime_error(context, fmt::format("the {}'s unit in the config is '{}'; markerctl rig converts to {} only",
                                             kind.name, axis.unit, unit_list(kind.units)));
  }
  return base_value / *scale;
}

}  // namespace markerctl
