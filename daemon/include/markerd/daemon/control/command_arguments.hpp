#pragma once
// Reading a control command's arguments (docs/control.md#protocol): by
// name, by type and, where one applies, within a range, with errors in the
// protocol's words that name the argument, what it must be and what was
// given ("argument 'reason' must be a string, got a number (42)"). Every
// handler reads its arguments through these, never with nlohmann's get<>()
// or value(), whose type errors name nothing. A handler first lists what it
// takes (expect_arguments), so that a misspelt argument is refused before
// the command does anything.

#include <cstdint>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markerd::daemon {

// What a handler throws to refuse a request: the reply is
// {"ok": false, "error": what()}. Any other std::exception becomes an error
// reply too; ControlError says the words are meant for the client.
class ControlError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// ControlError naming the first member of the request other than "cmd",
// "id" and `known`, and the arguments the command does take.
void expect_arguments(const nlohmann::json& request, std::initializer_list<std::string_view> known);

// The range a number argument must lie in, both ends included; `unit`, when
// given, is named in the error.
template <class T>
struct ArgumentRange {
  T min;
  T max;
  std::string_view unit = {};
};

// Each returns the argument's value, or nothing when it is absent or null;
// ControlError when it has another type, or lies outside the range.
[[nodiscard]] std::optional<std::string> string_argument(const nlohmann::json& request, std::string_view name);
// Finite numbers only.
[[nodiscard]] std::optional<double> number_argument(const nlohmann::json& request, std::string_view name);
[[nodiscard]] std::optional<double> number_argument(const nlohmann::json& request, std::string_view name,
                                                    ArgumentRange<double> range);
// A whole number (2.0 counts; 2.5 does not), in the range.
[[nodiscard]] std::optional<std::int64_t> integer_argument(const nlohmann::json& request, std::string_view name,
                                                           ArgumentRange<std::int64_t> range);
[[nodiscard]] std::optional<bool> bool_argument(const nlohmann::json& request, std::string_view name);
// A string that must be one of `choices` ("argument 'axis' must be rail,
// turntable or both, got 'rial'").
[[nodiscard]] std::optional<std::string> choice_argument(const nlohmann::json& request, std::string_view name,
                                                         std::initializer_list<std::string_view> choices);

// "a number", "a string", ...: a JSON value's type in the protocol's errors.
[[nodiscard]] const char* json_type_name(const nlohmann::json& value);

}  // namespace markerd::daemon
