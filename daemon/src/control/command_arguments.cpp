#include "markerd/daemon/control/command_arguments.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace markerd::daemon {

using nlohmann::json;

namespace {

// What was given, as the client wrote it, short enough for an error line.
std::string excerpt(const json& value) {
  constexpr std::size_t kMaxBytes = 60;
  std::string text = value.dump(-1, ' ', false, json::error_handler_t::replace);
  if (text.size() > kMaxBytes) {
    text.resize(kMaxBytes);
    text += "...";
  }
  return text;
}

std::string given(const json& value) { return fmt::format("{} ({})", json_type_name(value), excerpt(value)); }

const json* argument(const json& request, std::string_view name) {
  const auto it = request.find(name);
  if (it == request.end() || it->is_null()) return nullptr;
  return &*it;
}

[[noreturn]] void wrong_type(std::string_view name, std::string_view wanted, const json& value) {
  throw ControlError(fmt::format("argument '{}' must be {}, got {}", name, wanted, given(value)));
}

template <class T>
std::string range_text(const ArgumentRange<T>& range) {
  return fmt::format("from {} to {}{}{}", range.min, range.max, range.unit.empty() ? "" : " ", range.unit);
}

// "rail, turntable or both"
std::string alternatives(std::initializer_list<std::string_view> choices) {
  std::string text;
  std::size_t i = 0;
  for (const auto choice : choices) {
    if (i > 0) text += i + 1 == choices.size() ? " or " : ", ";
    text += choice;
    ++i;
  }
  return text;
}

}  // namespace

const char* json_type_name(const json& value) {
  switch (value.type()) {
    case json::value_t::null: return "null";
    case json::value_t::object: return "an object";
    case json::value_t::array: return "an array";
    case json::value_t::string: return "a string";
    case json::value_t::boolean: return "a boolean";
    case json::value_t::number_integer:
    case json::value_t::number_unsigned:
    case json::value_t::number_float: return "a number";
    default: return "binary data";
  }
}

void expect_arguments(const json& request, std::initializer_list<std::string_view> known) {
  for (const auto& [key, value] : request.items()) {
    if (key == "cmd" || key == "id") continue;
    if (std::find(known.begin(), known.end(), key) != known.end()) continue;
    std::string list;
    for (const auto k : known) list += fmt::format("{}{}", list.empty() ? "" : ", ", k);
    const auto cmd = request.find("cmd");
    const std::string command = cmd != request.end() && cmd->is_string() ? cmd->get<std::string>() : "the command";
    throw ControlError(list.empty() ? fmt::format("unknown argument '{}': {} takes none", key, command)
                                    : fmt::format("unknown argument '{}' (for {}: {})", key, command, list));
  }
}

std::optional<std::string> string_argument(const json& request, std::string_view name) {
  const json* value = argument(request, name);
  if (value == nullptr) return std::nullopt;
  if (!value->is_string()) wrong_type(name, "a string", *value);
  return value->get<std::string>();
}

std::optional<double> number_argument(const json& request, std::string_view name) {
  const json* value = argument(request, name);
  if (value == nullptr) return std::nullopt;
  if (!value->is_number()) wrong_type(name, "a number", *value);
  const double number = value->get<double>();
  if (!std::isfinite(number)) throw ControlError(fmt::format("argument '{}' must be a finite number", name));
  return number;
}

std::optional<double> number_argument(const json& request, std::string_view name, ArgumentRange<double> range) {
  const auto number = number_argument(request, name);
  if (number && !(*number >= range.min && *number <= range.max)) {
    throw ControlError(fmt::format("argument '{}' must be {}, got {}", name, range_text(range), *number));
  }
  return number;
}

std::optional<std::int64_t> integer_argument(const json& request, std::string_view name,
                                             ArgumentRange<std::int64_t> range) {
  const json* value = argument(request, name);
  if (value == nullptr) return std::nullopt;
  if (!value->is_number()) wrong_type(name, "a whole number", *value);
  if (value->is_number_integer() && !value->is_number_unsigned()) {
    const auto number = value->get<std::int64_t>();
    if (number >= range.min && number <= range.max) return number;
  } else if (value->is_number_unsigned()) {
    const auto number = value->get<std::uint64_t>();
    if (range.max >= 0 && number <= static_cast<std::uint64_t>(range.max) &&
        static_cast<std::int64_t>(number) >= range.min) {
      return static_cast<std::int64_t>(number);
    }
  } else {
    const double number = value->get<double>();
    if (std::isfinite(number) && number != std::trunc(number)) wrong_type(name, "a whole number", *value);
    // Only a double inside int64_t's range converts; one outside it (or
    // not finite) is out of the argument's range too.
    if (number >= -0x1p63 && number < 0x1p63) {
      const auto whole = static_cast<std::int64_t>(number);
      if (whole >= range.min && whole <= range.max) return whole;
    }
  }
  throw ControlError(fmt::format("argument '{}' must be {}, got {}", name, range_text(range), excerpt(*value)));
}

std::optional<bool> bool_argument(const json& request, std::string_view name) {
  const json* value = argument(request, name);
  if (value == nullptr) return std::nullopt;
  if (!value->is_boolean()) wrong_type(name, "true or false", *value);
  return value->get<bool>();
}

std::optional<std::string> choice_argument(const json& request, std::string_view name,
                                           std::initializer_list<std::string_view> choices) {
  const json* value = argument(request, name);
  if (value == nullptr) return std::nullopt;
  if (!value->is_string()) wrong_type(name, alternatives(choices), *value);
  const std::string& text = value->get_ref<const std::string&>();
  if (std::find(choices.begin(), choices.end(), text) == choices.end()) {
    throw ControlError(fmt::format("argument '{}' must be {}, got '{}'", name, alternatives(choices), text));
  }
  return text;
}

}  // namespace markerd::daemon
