#include "common.hpp"
#include "markerd/base/ascii.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/base/read_file.hpp"

#include <unistd.h>

#include <fmt/format.h>

#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>

namespace markerctl {
namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

}  // namespace

std::optional<NumberAndUnit> split_number(std::string_view text) {
  text = trim(text);
  // from_chars rejects a leading '+', which people do type.
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc{} || !std::isfinite(value)) return std::nullopt;
  return NumberAndUnit{
      value,
      markerd::ascii_lower(trim(std::string_view(end, static_cast<std::size_t>(text.data() + text.size() - end))))};
}

double parse_length_m(std::string_view text, BareUnit bare, std::string_view option) {
  const auto parsed = split_number(text);
  if (!parsed) {
    throw usage_error(std::string(option), fmt::format("'{}' is not a length (examples: 80mm, 8cm, 0.08m)", text));
  }
  const std::string& unit = parsed->unit;
  double scale = 0;
  if (unit.empty()) {
    scale = bare == BareUnit::millimetre ? 1e-3 : 1.0;
  } else if (unit == "mm") {
    scale = 1e-3;
  } else if (unit == "cm") {
    scale = 1e-2;
  } else if (unit == "m") {
    scale = 1.0;
  } else if (unit == "in") {
    scale = 0.0254;
  } else {
    throw usage_error(std::string(option),
                      fmt::format("'{}' is not a length: unknown unit '{}' (use mm, cm, m or in)", text, unit));
  }
  return parsed->value * scale;
}

double parse_angle_deg(std::string_view text, std::string_view option) {
  const auto parsed = split_number(text);
  if (!parsed) {
    throw usage_error(std::string(option), fmt::format("'{}' is not an angle (examples: 30, 30deg, 0.5rad)", text));
  }
  const std::string& unit = parsed->unit;
  if (unit.empty() || unit == "deg" || unit == "\xc2\xb0") return parsed->value;
  if (unit == "rad") return parsed->value * 180.0 / std::numbers::pi;
  throw usage_error(std::string(option),
                    fmt::format("'{}' is not an angle: unknown unit '{}' (use deg or rad)", text, unit));
}

std::vector<double> parse_values(std::string_view text, std::string_view option,
                                 const std::function<double(std::string_view)>& parse_one) {
  std::vector<double> values;
  text = trim(text);
  if (text.find(':') != std::string_view::npos) {
    std::array<std::string_view, 3> parts{};
    std::size_t n = 0;
    std::string_view rest = text;
    while (n < 3) {
      const auto colon = rest.find(':');
      parts[n++] = rest.substr(0, colon);
      if (colon == std::string_view::npos) {
        rest = {};
        break;
      }
      rest.remove_prefix(colon + 1);
    }
    if (n != 3 || !rest.empty()) {
      throw usage_error(std::string(option), fmt::format("'{}' is not a range: write first:last:step", text));
    }
    const double first = parse_one(parts[0]);
    const double last = parse_one(parts[1]);
    const double step = parse_one(parts[2]);
    if (!(step > 0) || last < first) {
      throw usage_error(std::string(option),
                        fmt::format("'{}': a range needs first <= last and a positive step", text));
    }
    // The tolerance keeps "0.3:3.0:0.3" from losing its last point to rounding.
    const double count = std::floor((last - first) / step + 1e-9) + 1;
    if (count > 10000) throw usage_error(std::string(option), fmt::format("'{}' has too many points", text));
    for (int i = 0; i < static_cast<int>(count); ++i) values.push_back(first + i * step);
    return values;
  }
  std::string_view rest = text;
  while (true) {
    const auto comma = rest.find(',');
    const auto item = trim(rest.substr(0, comma));
    if (item.empty()) throw usage_error(std::string(option), fmt::format("'{}' has an empty value", text));
    values.push_back(parse_one(item));
    if (comma == std::string_view::npos) break;
    rest.remove_prefix(comma + 1);
  }
  return values;
}

std::string family_names() {
  std::string names;
  for (const auto& info : markerd::detector::all_families()) {
    if (!names.empty()) names += ", ";
    names += info.name;
  }
  return names;
}

markerd::detector::Family parse_family(std::string_view name, std::string_view option) {
  if (auto family = markerd::detector::family_from_name(name)) return *family;
  throw usage_error(std::string(option), fmt::format("unknown family '{}' (known: {})", name, family_names()));
}

void check_id(markerd::detector::Family family, int id, std::string_view option) {
  const auto& info = markerd::detector::family_info(family);
  if (id < 0 || id >= info.id_count) {
    throw usage_error(std::string(option),
                      fmt::format("{} is not a {} id (valid ids are 0 to {})", id, info.name, info.id_count - 1));
  }
}

markerd::detector::CameraModel load_camera(const std::string& path) {
  if (path.empty()) return markerd::detector::CameraModel::thesis_640x480();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw runtime_error("--camera", fmt::format("{}: no such file", path));
  try {
    return markerd::detector::CameraModel::load(path);
  } catch (const markerd::detector::CameraModelError& e) {
    // The loader's message already names the file.
    throw runtime_error("--camera", e.what());
  }
}

std::string read_standard_input(std::size_t max_bytes, std::string_view what, const std::string& context) {
  if (::isatty(STDIN_FILENO) != 0) {
    throw usage_error(context, fmt::format("'-' reads {} from standard input, which is a terminal: pipe or redirect "
                                           "it in (markerctl ... - < FILE)",
                                           what));
  }
  std::string bytes;
  std::array<char, 65536> buffer{};
  for (;;) {
    const ssize_t n = ::read(STDIN_FILENO, buffer.data(), buffer.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      throw runtime_error(context,
                          fmt::format("{}: cannot be read: {}", standard_input_name, markerd::errno_text(errno)));
    }
    if (n == 0) return bytes;
    if (bytes.size() + static_cast<std::size_t>(n) > max_bytes) {
      throw runtime_error(context, fmt::format("{}: {} is larger than the {} allowed", standard_input_name, what,
                                               markerd::format_bytes(max_bytes)));
    }
    bytes.append(buffer.data(), static_cast<std::size_t>(n));
  }
}

std::string json_line(const nlohmann::ordered_json& value) {
  return value.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

double rounded(double value, int digits) {
  const double scale = std::pow(10.0, digits);
  const double r = std::round(value * scale) / scale;
  return std::isfinite(r) ? r : value;
}

}  // namespace markerctl
