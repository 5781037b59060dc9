#pragma once
// Typed access to a TOML table for the config parsers: every error names the
// file, the line and the full key ("rig.toml:14: rig.rail.max_velocity: must be
// > 0, got -3"), and keys nobody reads are errors too, so a typo cannot pass
// silently. Parsers read each table once into their typed structs; nothing
// deeper sees TOML.

#include <toml++/toml.h>

#include <cstddef>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markerd {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ConfigTable {
 public:
  // The root table of a parsed document. `source` names it in errors (a file
  // path, or "<string>").
  ConfigTable(std::shared_ptr<const toml::table> root, std::string source);

  // Parses a file; a syntax error, a missing file, or anything but a regular
  // file of at most kMaxFileBytes becomes a ConfigError.
  static ConfigTable load_file(const std::filesystem::path& path);
  static constexpr std::size_t kMaxFileBytes = 1024 * 1024;
  static ConfigTable parse(std::string_view text, std::string source = "<string>");

  [[nodiscard]] const std::string& source() const { return source_; }
  [[nodiscard]] const std::string& key_path() const { return key_path_; }  // "" for the root
  [[nodiscard]] const toml::table& raw() const { return *table_; }
  [[nodiscard]] bool contains(std::string_view key) const { return table_->contains(key); }

  // Values: integers are accepted where a double is asked for; nothing else
  // converts. Missing required keys and wrong types are errors.
  template <class T>
  [[nodiscard]] T required(std::string_view key) const;
  template <class T>
  [[nodiscard]] T optional(std::string_view key, T fallback) const;
  template <class T>
  [[nodiscard]] std::optional<T> maybe(std::string_view key) const;

  // The same with the range that the value means something in physically (a
  // settle time, a time scale, a marker's size): a value outside it, or a
  // number that is not finite, is an error naming the range and its unit.
  template <class T>
  struct Range {
    T min;
    T max;
    std::string_view unit = {};
  };
  template <class T>
  [[nodiscard]] T required(std::string_view key, Range<T> range) const;
  template <class T>
  [[nodiscard]] T optional(std::string_view key, T fallback, Range<T> range) const;
  template <class T>
  [[nodiscard]] std::optional<T> maybe(std::string_view key, Range<T> range) const;

  [[nodiscard]] ConfigTable table(std::string_view key) const;
  [[nodiscard]] std::optional<ConfigTable> maybe_table(std::string_view key) const;

  // Errors about this table, or about one of its keys, with the key's line.
  [[noreturn]] void fail(std::string_view message) const;
  [[noreturn]] void fail(std::string_view key, std::string_view message) const;
  // Fails on the first key of this table not in `known`.
  void allow_only(std::initializer_list<std::string_view> known) const;

 private:
  ConfigTable(std::shared_ptr<const toml::table> root, const toml::table* table, std::string source,
              std::string key_path);
  [[nodiscard]] std::string full_key(std::string_view key) const;
  [[nodiscard]] std::string where(const toml::node* node) const;

  std::shared_ptr<const toml::table> root_;  // keeps the document alive
  const toml::table* table_;
  std::string source_;
  std::string key_path_;
};

// Defined in config_table.cpp for: bool, std::int64_t, int, double, std::string;
// the ranged ones for std::int64_t, int and double.

}  // namespace markerd
