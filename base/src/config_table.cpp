#include "markerd/base/config_table.hpp"

#include "markerd/base/read_file.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

namespace markerd {

ConfigTable::ConfigTable(std::shared_ptr<const toml::table> root, std::string source)
    : ConfigTable(root, root.get(), std::move(source), "") {}

ConfigTable::ConfigTable(std::shared_ptr<const toml::table> root, const toml::table* table, std::string source,
                         std::string key_path)
    : root_(std::move(root)), table_(table), source_(std::move(source)), key_path_(std::move(key_path)) {}

ConfigTable ConfigTable::load_file(const std::filesystem::path& path) {
  std::string text;
  try {
    text = read_regular_file(path, kMaxFileBytes, "the config file");
  } catch (const FileError& e) {
    throw ConfigError(e.what());
  }
  return parse(text, path.string());
}

ConfigTable ConfigTable::parse(std::string_view text, std::string source) {
  try {
    return ConfigTable(std::make_shared<const toml::table>(toml::parse(text, source)), source);
  } catch (const toml::parse_error& e) {
    const auto& begin = e.source().begin;
    throw ConfigError(fmt::format("{}:{}:{}: {}", source, begin.line, begin.column, e.description()));
  }
}

std::string ConfigTable::full_key(std::string_view key) const {
  return key_path_.empty() ? std::string(key) : fmt::format("{}.{}", key_path_, key);
}

std::string ConfigTable::where(const toml::node* node) const {
  if (node != nullptr && node->source().begin.line > 0) return fmt::format("{}:{}", source_, node->source().begin.line);
  if (table_->source().begin.line > 0) return fmt::format("{}:{}", source_, table_->source().begin.line);
  return source_;
}

void ConfigTable::fail(std::string_view message) const {
  // The root table has no line worth naming.
  if (key_path_.empty()) throw ConfigError(fmt::format("{}: {}", source_, message));
  throw ConfigError(fmt::format("{}: [{}]: {}", where(nullptr), key_path_, message));
}

void ConfigTable::fail(std::string_view key, std::string_view message) const {
  throw ConfigError(fmt::format("{}: {}: {}", where(table_->get(key)), full_key(key), message));
}

void ConfigTable::allow_only(std::initializer_list<std::string_view> known) const {
  for (const auto& [key, node] : *table_) {
    bool found = false;
    for (auto k : known) found = found || k == key.str();
    if (!found) {
      std::string list;
      for (auto k : known) list += fmt::format("{}{}", list.empty() ? "" : ", ", k);
      throw ConfigError(fmt::format("{}: {}: unknown key (known here: {})", where(&node), full_key(key.str()), list));
    }
  }
}

namespace {

template <class T>
constexpr std::string_view type_name() {
  if constexpr (std::is_same_v<T, bool>)
    return "a boolean";
  else if constexpr (std::is_same_v<T, double>)
    return "a number";
  else if constexpr (std::is_integral_v<T>)
    return "an integer";
  else
    return "a string";
}

// Converts a node to T, or nothing when its type does not fit.
template <class T>
std::optional<T> convert(const toml::node& node) {
  if constexpr (std::is_same_v<T, bool>) {
    if (auto v = node.value_exact<bool>()) return *v;
  } else if constexpr (std::is_same_v<T, double>) {
    if (node.is_floating_point()) return *node.value<double>();
    if (node.is_integer()) return static_cast<double>(*node.value_exact<std::int64_t>());
  } else if constexpr (std::is_integral_v<T>) {
    if (auto v = node.value_exact<std::int64_t>()) {
      if (*v < static_cast<std::int64_t>(std::numeric_limits<T>::min()) ||
          *v > static_cast<std::int64_t>(std::numeric_limits<T>::max())) {
        return std::nullopt;
      }
      return static_cast<T>(*v);
    }
  } else {
    if (auto v = node.value_exact<std::string>()) return *v;
  }
  return std::nullopt;
}

}  // namespace

template <class T>
std::optional<T> ConfigTable::maybe(std::string_view key) const {
  const toml::node* node = table_->get(key);
  if (node == nullptr) return std::nullopt;
  auto value = convert<T>(*node);
  if (!value) {
    if constexpr (std::is_integral_v<T> && !std::is_same_v<T, bool>) {
      // An integer too large for the setting deserves better than "must be an integer".
      if (auto v = node->value_exact<std::int64_t>()) {
        fail(key, fmt::format("must be an integer from {} to {}, got {}", std::numeric_limits<T>::min(),
                              std::numeric_limits<T>::max(), *v));
      }
    }
    fail(key, fmt::format("must be {}", type_name<T>()));
  }
  return value;
}

template <class T>
std::optional<T> ConfigTable::maybe(std::string_view key, Range<T> range) const {
  auto value = maybe<T>(key);
  if (!value) return value;
  const std::string unit = range.unit.empty() ? std::string() : fmt::format(" {}", range.unit);
  if constexpr (std::is_floating_point_v<T>) {
    if (!std::isfinite(*value)) fail(key, fmt::format("must be a finite number, got {}", *value));
  }
  if (*value < range.min || *value > range.max) {
    fail(key, fmt::format("must be from {} to {}{}, got {}", range.min, range.max, unit, *value));
  }
  return value;
}

template <class T>
T ConfigTable::required(std::string_view key, Range<T> range) const {
  (void)required<T>(key);
  return *maybe<T>(key, range);
}

template <class T>
T ConfigTable::optional(std::string_view key, T fallback, Range<T> range) const {
  auto value = maybe<T>(key, range);
  return value ? *value : fallback;
}

template <class T>
T ConfigTable::required(std::string_view key) const {
  auto value = maybe<T>(key);
  if (!value) fail(fmt::format("missing key '{}' ({})", full_key(key), type_name<T>()));
  return *value;
}

template <class T>
T ConfigTable::optional(std::string_view key, T fallback) const {
  auto value = maybe<T>(key);
  return value ? *value : fallback;
}

std::optional<ConfigTable> ConfigTable::maybe_table(std::string_view key) const {
  const toml::node* node = table_->get(key);
  if (node == nullptr) return std::nullopt;
  if (!node->is_table()) fail(key, "must be a table");
  return ConfigTable(root_, node->as_table(), source_, full_key(key));
}

ConfigTable ConfigTable::table(std::string_view key) const {
  auto t = maybe_table(key);
  if (!t) fail(fmt::format("missing table [{}]", full_key(key)));
  return *t;
}

#define MARKERD_CONFIG_TYPE(T)                                             \
  template std::optional<T> ConfigTable::maybe<T>(std::string_view) const; \
  template T ConfigTable::required<T>(std::string_view) const;             \
  template T ConfigTable::optional<T>(std::string_view, T) const;
MARKERD_CONFIG_TYPE(bool)
MARKERD_CONFIG_TYPE(int)
MARKERD_CONFIG_TYPE(std::int64_t)
MARKERD_CONFIG_TYPE(double)
MARKERD_CONFIG_TYPE(std::string)
#undef MARKERD_CONFIG_TYPE

#define MARKERD_CONFIG_RANGED_TYPE(T)                                                \
  template std::optional<T> ConfigTable::maybe<T>(std::string_view, Range<T>) const; \
  template T ConfigTable::required<T>(std::string_view, Range<T>) const;             \
  template T ConfigTable::optional<T>(std::string_view, T, Range<T>) const;
MARKERD_CONFIG_RANGED_TYPE(int)
MARKERD_CONFIG_RANGED_TYPE(std::int64_t)
MARKERD_CONFIG_RANGED_TYPE(double)
#undef MARKERD_CONFIG_RANGED_TYPE

}  // namespace markerd
