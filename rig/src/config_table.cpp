#include "markerd/rig/config_table.hpp"

#include <fmt/format.h>

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
  try {
    return ConfigTable(std::make_shared<const toml::table>(toml::parse_file(path.string())), path.string());
  } catch (const toml::parse_error& e) {
    const auto& begin = e.source().begin;
    if (begin.line == 0) throw ConfigError(fmt::format("{}: {}", path.string(), e.description()));
    throw ConfigError(fmt::format("{}:{}:{}: {}", path.string(), begin.line, begin.column, e.description()));
  }
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
  if constexpr (std::is_same_v<T, bool>) return "a boolean";
  else if constexpr (std::is_same_v<T, double>) return "a number";
  else if constexpr (std::is_integral_v<T>) return "an integer";
  else return "a string";
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
  if (!value) fail(key, fmt::format("must be {}", type_name<T>()));
  return value;
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

#define MARKERD_CONFIG_TYPE(T)                                          \
  template std::optional<T> ConfigTable::maybe<T>(std::string_view) const; \
  template T ConfigTable::required<T>(std::string_view) const;            \
  template T ConfigTable::optional<T>(std::string_view, T) const;
MARKERD_CONFIG_TYPE(bool)
MARKERD_CONFIG_TYPE(int)
MARKERD_CONFIG_TYPE(std::int64_t)
MARKERD_CONFIG_TYPE(double)
MARKERD_CONFIG_TYPE(std::string)
#undef MARKERD_CONFIG_TYPE

}  // namespace markerd
