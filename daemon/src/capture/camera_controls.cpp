#include "markerd/daemon/capture/camera_controls.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <type_traits>

#include "markerd/base/ascii.hpp"
#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/daemon/capture/v4l2_settings.hpp"

namespace markerd::daemon {

namespace {

// A whole number given as one, or as a number without a fraction (JSON's 2.0).
std::optional<std::int64_t> whole_number(const ControlInput& input) {
  if (const auto* i = std::get_if<std::int64_t>(&input)) return *i;
  if (const auto* d = std::get_if<double>(&input)) {
    // 2^63 itself is not an int64: the bound is exclusive.
    if (std::isfinite(*d) && std::floor(*d) == *d && std::abs(*d) < 9.2e18) return static_cast<std::int64_t>(*d);
  }
  return std::nullopt;
}

std::optional<double> real_number(const ControlInput& input) {
  if (const auto* i = std::get_if<std::int64_t>(&input)) return static_cast<double>(*i);
  if (const auto* d = std::get_if<double>(&input); d != nullptr && std::isfinite(*d)) return *d;
  return std::nullopt;
}

std::optional<std::int64_t> whole_of(const std::optional<ControlValue>& value) {
  if (!value) return std::nullopt;
  if (const auto* i = std::get_if<std::int64_t>(&*value)) return *i;
  if (const auto* b = std::get_if<bool>(&*value)) return *b ? 1 : 0;
  if (const auto* d = std::get_if<double>(&*value)) return static_cast<std::int64_t>(std::llround(*d));
  return std::nullopt;
}

std::optional<double> real_of(const std::optional<ControlValue>& value) {
  if (!value) return std::nullopt;
  return std::visit([](auto v) { return static_cast<double>(v); }, *value);
}

std::string menu_text(const CameraControlInfo& c) {
  std::string text;
  for (const auto& item : c.menu) text += fmt::format("{}{}: {}", text.empty() ? "" : ", ", item.index, item.name);
  return text.empty() ? std::string("no items") : text;
}

bool same_value(const ControlValue& a, const ControlValue& b) {
  return std::visit([](auto x) { return static_cast<double>(x); }, a) ==
         std::visit([](auto x) { return static_cast<double>(x); }, b);
}

ControlValue check_allowed(const CameraControlInfo& c, ControlValue value) {
  if (c.allowed.empty()) return value;
  for (const auto& allowed : c.allowed) {
    if (same_value(allowed, value)) return value;
  }
  throw ControlValueError(fmt::format("{} is not one of its values: {}", to_text(value), describe_range(c)));
}

ControlValue check_integer(const CameraControlInfo& c, const ControlInput& input) {
  const auto value = whole_number(input);
  if (!value) {
    const char* what = std::holds_alternative<double>(input) ? "a whole number" : "a number";
    throw ControlValueError(
        fmt::format("{} is not {}: an integer control, {}", to_text(input), what, describe_range(c)));
  }
  const auto min = whole_of(c.minimum);
  const auto max = whole_of(c.maximum);
  if ((min && *value < *min) || (max && *value > *max)) {
    throw ControlValueError(fmt::format("{} is out of its range {}", *value, describe_range(c)));
  }
  if (c.step > 1) {
    const std::int64_t base = min.value_or(0);
    const auto offset = static_cast<std::uint64_t>(*value - base);
    if (offset % c.step != 0) {
      const auto below = base + static_cast<std::int64_t>(offset - offset % c.step);
      const auto above = below + static_cast<std::int64_t>(c.step);
      throw ControlValueError(fmt::format("{} is not on its steps: {} + a multiple of {} ({} or {} are)", *value, base,
                                          c.step, below, above));
    }
  }
  return check_allowed(c, *value);
}

ControlValue check_menu(const CameraControlInfo& c, const ControlInput& input) {
  if (const auto* text = std::get_if<std::string>(&input)) {
    for (const auto& item : c.menu) {
      if (ascii_lower(item.name) == ascii_lower(*text) || v4l2_control_name(item.name) == v4l2_control_name(*text)) {
        return item.index;
      }
    }
    throw ControlValueError(fmt::format("'{}' is not one of its items ({})", *text, menu_text(c)));
  }
  if (const auto index = whole_number(input)) {
    for (const auto& item : c.menu) {
      if (item.index == *index) return *index;
    }
    throw ControlValueError(fmt::format("{} is not one of its items ({})", *index, menu_text(c)));
  }
  throw ControlValueError(fmt::format("a menu: give an item's number or name ({})", menu_text(c)));
}

}  // namespace

bool has_flag(const CameraControlInfo& control, std::string_view flag) {
  return std::find(control.flags.begin(), control.flags.end(), flag) != control.flags.end();
}

bool is_automatic_mode(std::string_view name) {
  const std::string lower = ascii_lower(name);
  // V4L2's auto_exposure, white_balance_automatic, autogain, focus_automatic_continuous;
  // libcamera's AeEnable, AwbEnable, AwbMode, AeExposureMode (the automatic modes' own).
  return lower.find("auto") != std::string::npos || lower.starts_with("ae") || lower.starts_with("awb");
}

ControlValue check_control_value(const CameraControlInfo& c, const ControlInput& input) {
  if (has_flag(c, "read-only")) throw ControlValueError("read-only: it can be read, not set");
  switch (c.kind) {
    case ControlKind::boolean: {
      if (const auto* b = std::get_if<bool>(&input)) return *b;
      if (const auto i = whole_number(input); i && (*i == 0 || *i == 1)) return *i == 1;
      throw ControlValueError(fmt::format("{} is not a boolean: give true or false", to_text(input)));
    }
    case ControlKind::integer: return check_integer(c, input);
    case ControlKind::menu: return check_menu(c, input);
    case ControlKind::bitmask: {
      const auto value = whole_number(input);
      if (!value)
        throw ControlValueError(fmt::format("{} is not a number: a bitmask, {}", to_text(input), describe_range(c)));
      const auto mask = static_cast<std::uint64_t>(whole_of(c.maximum).value_or(0));
      if ((static_cast<std::uint64_t>(*value) & ~mask) != 0) {
        throw ControlValueError(fmt::format("{:#x} has bits outside the mask {:#x}", *value, mask));
      }
      return *value;
    }
    case ControlKind::real: {
      const auto value = real_number(input);
      if (!value) {
        throw ControlValueError(
            fmt::format("{} is not a number: a real control, {}", to_text(input), describe_range(c)));
      }
      const auto min = real_of(c.minimum);
      const auto max = real_of(c.maximum);
      if ((min && *value < *min) || (max && *value > *max)) {
        throw ControlValueError(fmt::format("{} is out of its range {}", to_text(input), describe_range(c)));
      }
      return check_allowed(c, *value);
    }
    case ControlKind::other: break;
  }
  throw ControlValueError(c.why_not_settable.empty() ? fmt::format("a {} control: markerd cannot set it", c.type)
                                                     : c.why_not_settable);
}

std::string describe_range(const CameraControlInfo& c) {
  if (!c.allowed.empty() && c.kind != ControlKind::menu) {
    std::string values;
    for (const auto& v : c.allowed) values += fmt::format("{}{}", values.empty() ? "" : ", ", to_text(v));
    return "one of " + values;
  }
  switch (c.kind) {
    case ControlKind::boolean: return "true or false";
    case ControlKind::menu: return menu_text(c);
    case ControlKind::bitmask:
      return fmt::format("bits within {:#x}", static_cast<std::uint64_t>(whole_of(c.maximum).value_or(0)));
    case ControlKind::integer:
    case ControlKind::real: {
      std::string text;
      if (c.minimum && c.maximum) {
        text = fmt::format("{} to {}", to_text(*c.minimum), to_text(*c.maximum));
      } else if (c.minimum) {
        text = fmt::format("at least {}", to_text(*c.minimum));
      } else if (c.maximum) {
        text = fmt::format("at most {}", to_text(*c.maximum));
      } else {
        text = "any number";
      }
      if (c.kind == ControlKind::integer && c.step > 1) text += fmt::format(" in steps of {}", c.step);
      return text;
    }
    case ControlKind::other: break;
  }
  return c.why_not_settable.empty() ? fmt::format("a {} control", c.type) : c.why_not_settable;
}

std::string to_text(const ControlValue& value) {
  return std::visit(
      [](auto v) -> std::string {
        if constexpr (std::is_same_v<decltype(v), bool>) {
          return v ? "true" : "false";
        } else {
          return fmt::format("{}", v);
        }
      },
      value);
}

std::string to_text(const ControlInput& value) {
  if (const auto* text = std::get_if<std::string>(&value)) return fmt::format("'{}'", *text);
  if (const auto* b = std::get_if<bool>(&value)) return to_text(ControlValue(*b));
  if (const auto* i = std::get_if<std::int64_t>(&value)) return to_text(ControlValue(*i));
  return to_text(ControlValue(std::get<double>(value)));
}

std::string value_text(const CameraControlInfo& control, const ControlValue& value) {
  if (control.kind == ControlKind::menu) {
    if (const auto* index = std::get_if<std::int64_t>(&value)) {
      for (const auto& item : control.menu) {
        if (item.index == *index) return fmt::format("{} ({})", *index, item.name);
      }
    }
  }
  return to_text(value);
}

nlohmann::json to_json(const ControlValue& value) {
  return std::visit([](auto v) { return nlohmann::json(v); }, value);
}

nlohmann::json to_json(const CameraControlInfo& c) {
  using nlohmann::json;
  const auto or_null = [](const std::optional<ControlValue>& v) { return v ? to_json(*v) : json(nullptr); };
  json j{{"name", c.name},
         {"type", c.type},
         {"value", or_null(c.value)},
         {"min", or_null(c.minimum)},
         {"max", or_null(c.maximum)}};
  j["step"] = c.kind == ControlKind::integer ? json(std::max<std::uint64_t>(c.step, 1)) : json(nullptr);
  j["default"] = or_null(c.default_value);
  j["range"] = describe_range(c);
  if (!c.menu.empty()) {
    j["menu"] = json::array();
    for (const auto& item : c.menu) j["menu"].push_back({{"index", item.index}, {"name", item.name}});
  }
  if (!c.allowed.empty()) {
    j["values"] = json::array();
    for (const auto& v : c.allowed) j["values"].push_back(to_json(v));
  }
  j["flags"] = c.flags;
  j["settable"] = c.kind != ControlKind::other && !has_flag(c, "read-only");
  if (c.kind == ControlKind::other && !c.why_not_settable.empty()) j["why_not_settable"] = c.why_not_settable;
  return j;
}

ControlInput control_input_from_json(const nlohmann::json& value) {
  if (value.is_boolean()) return value.get<bool>();
  if (value.is_number_unsigned()) {
    const auto u = value.get<std::uint64_t>();
    if (u > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
      throw ControlValueError(fmt::format("{} is beyond any control's range", u));
    }
    return static_cast<std::int64_t>(u);
  }
  if (value.is_number_integer()) return value.get<std::int64_t>();
  if (value.is_number_float()) return value.get<double>();
  if (value.is_string()) return value.get<std::string>();
  throw ControlValueError(fmt::format("give a number, true or false, or a menu item's name; got {}",
                                      value.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace)));
}

// ---------------------------------------------------------------- setting

namespace {

const CameraControlInfo* find_control(const std::vector<CameraControlInfo>& controls, std::string_view name) {
  const auto it = std::find_if(controls.begin(), controls.end(), [&](const auto& c) { return c.name == name; });
  return it == controls.end() ? nullptr : &*it;
}

std::string control_names(const std::vector<CameraControlInfo>& controls) {
  std::vector<std::string> names;
  for (const auto& c : controls) names.push_back(c.name);
  std::sort(names.begin(), names.end());
  std::string text;
  for (const auto& n : names) text += fmt::format("{}{}", text.empty() ? "" : ", ", n);
  return text.empty() ? std::string("none") : text;
}

[[noreturn]] void unknown_control(const CaptureSource& source, const std::vector<CameraControlInfo>& controls,
                                  std::string_view name) {
  for (const auto& c : controls) {
    if (ascii_lower(c.name) == ascii_lower(name)) {
      throw ControlValueError(
          fmt::format("{} has no control '{}': did you mean '{}'? Nothing was changed", source.name(), name, c.name));
    }
  }
  throw ControlValueError(fmt::format("{} has no control '{}' (its controls: {}); nothing was changed", source.name(),
                                      name, control_names(controls)));
}

// What holds an inactive control: the automatic modes, with their values.
std::string automatic_modes(const std::vector<CameraControlInfo>& controls) {
  std::string text;
  for (const auto& c : controls) {
    if (!is_automatic_mode(c.name) || c.kind == ControlKind::other || has_flag(c, "read-only")) continue;
    text += fmt::format("{}{}{}", text.empty() ? "" : ", ", c.name, c.value ? " = " + value_text(c, *c.value) : "");
  }
  return text;
}

struct Planned {
  std::string name;
  ControlValue value;
};

}  // namespace

std::vector<ControlChange> set_camera_controls(CaptureSource& source, std::span<const ControlAssignment> assignments) {
  if (assignments.empty()) throw ControlValueError("no controls given");
  std::vector<CameraControlInfo> controls = source.read_controls();
  std::vector<Planned> plan;
  for (const auto& a : assignments) {
    if (std::any_of(plan.begin(), plan.end(), [&](const Planned& p) { return p.name == a.name; })) {
      throw ControlValueError(fmt::format("{} is given twice; nothing was changed", a.name));
    }
    const CameraControlInfo* c = find_control(controls, a.name);
    if (c == nullptr) unknown_control(source, controls, a.name);
    try {
      plan.push_back({a.name, check_control_value(*c, a.value)});
    } catch (const ControlValueError& e) {
      throw ControlValueError(fmt::format("{}: {}; nothing was changed", a.name, e.what()));
    }
  }
  std::stable_partition(plan.begin(), plan.end(), [](const Planned& p) { return is_automatic_mode(p.name); });

  std::vector<ControlChange> done;
  // Puts back what was written, and says so in the error it returns.
  const auto refusal = [&](const std::string& why) {
    // Back as they were, the last written first.
    std::string undone;
    for (auto it = done.rbegin(); it != done.rend(); ++it) {
      if (!it->old_value) {
        undone += fmt::format("; {} stays {} (its value before could not be read)", it->control.name,
                              value_text(it->control, it->new_value));
        continue;
      }
      try {
        source.write_control(it->control, *it->old_value);
      } catch (const std::exception& e) {
        undone +=
            fmt::format("; {} stays {}: putting back {} failed: {}", it->control.name,
                        value_text(it->control, it->new_value), value_text(it->control, *it->old_value), e.what());
      }
    }
    return ControlValueError(why + (undone.empty() ? "; nothing was changed" : undone));
  };
  for (std::size_t i = 0; i < plan.size(); ++i) {
    if (i > 0) controls = source.read_controls();  // an earlier write may have changed what this one may do
    const CameraControlInfo* c = find_control(controls, plan[i].name);
    if (c == nullptr) throw refusal(fmt::format("{}: the camera no longer has it", plan[i].name));
    if (has_flag(*c, "inactive")) {
      const std::string modes = automatic_modes(controls);
      throw refusal(fmt::format("{}: inactive now{}", c->name,
                                modes.empty() ? std::string(" (another control holds it)")
                                              : fmt::format(" (an automatic mode holds it: {}; set that first, in the "
                                                            "same command or before)",
                                                            modes)));
    }
    try {
      source.write_control(*c, plan[i].value);
    } catch (const std::exception& e) {
      throw refusal(fmt::format("{}: {} refused: {}", c->name, value_text(*c, plan[i].value), e.what()));
    }
    done.push_back({*c, c->value, plan[i].value});
  }
  return done;
}

}  // namespace markerd::daemon

namespace markerd::daemon {

void CaptureSource::write_control(const CameraControlInfo& control, const ControlValue& /*value*/) {
  throw CaptureError(CaptureError::Kind::config, fmt::format("{} has no control {}", name(), control.name));
}

}  // namespace markerd::daemon
