#pragma once
// Configs for the tests made from the shipped examples (config/) and the
// tests' own data files (tests/data/): the file parsed with toml++, a value
// or two changed in the parsed tables, the result written out. Never a text
// replacement: a key that is not where the test expects it is an error
// (std::runtime_error naming the file and the key), not a file silently
// left as it was. GoogleTest-free.

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>

#include <toml++/toml.h>

namespace markerd::test_support {

#ifndef MARKERD_SOURCE_DIR
#error "toml_config.hpp needs MARKERD_SOURCE_DIR, the source tree (config/, tests/data/)"
#endif
inline const std::filesystem::path kSourceTree = MARKERD_SOURCE_DIR;

class TomlConfig {
 public:
  // std::runtime_error with the file, line and reason when it does not parse.
  static TomlConfig load(const std::filesystem::path& file) {
    try {
      return TomlConfig(file, toml::parse_file(file.string()));
    } catch (const toml::parse_error& e) {
      std::ostringstream what;
      what << file.string() << ":" << e.source().begin.line << ": " << e.description();
      throw std::runtime_error(what.str());
    }
  }

  // Sets the value at `key` ("rig.sim.time_scale", "rig.rail.modbus.port"),
  // which must be there already and of the same type (a floating-point
  // value stays one, an integer one, a string one).
  template <class T>
  TomlConfig& set(std::string_view key, const T& value) {
    toml::node* node = table_.at_path(key).node();
    if (node == nullptr) throw std::runtime_error(source_.string() + ": no key " + std::string(key) + " to set");
    if constexpr (std::is_same_v<T, bool>) {
      replace(node->as_boolean(), key, "a boolean", value);
    } else if constexpr (std::is_integral_v<T>) {
      replace(node->as_integer(), key, "an integer", static_cast<std::int64_t>(value));
    } else if constexpr (std::is_floating_point_v<T>) {
      replace(node->as_floating_point(), key, "a floating-point number", static_cast<double>(value));
    } else {
      replace(node->as_string(), key, "a string", std::string(value));
    }
    return *this;
  }

  // Writes the tables as TOML (comments and layout are not kept); its path.
  std::filesystem::path write(const std::filesystem::path& file) const {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out << table_ << '\n';
    out.close();
    if (!out) throw std::runtime_error("cannot write " + file.string());
    return file;
  }

  [[nodiscard]] const toml::table& table() const { return table_; }

 private:
  TomlConfig(std::filesystem::path source, toml::table table) : source_(std::move(source)), table_(std::move(table)) {}

  template <class Value, class T>
  void replace(Value* node, std::string_view key, const char* kind, T value) const {
    if (node == nullptr) throw std::runtime_error(source_.string() + ": " + std::string(key) + " is not " + kind);
    *node = std::move(value);
  }

  std::filesystem::path source_;
  toml::table table_;
};

// config/rig-sim.toml, the simulated rig, with its simulated time running
// `time_scale` times as fast as real time (so that homing and long moves take
// a moment), written to `file`; its path.
inline std::filesystem::path write_sim_rig_config(const std::filesystem::path& file, double time_scale) {
  return TomlConfig::load(kSourceTree / "config/rig-sim.toml").set("rig.sim.time_scale", time_scale).write(file);
}

// config/rig-modbus-tcp.toml with its two buses at simulated drive servers
// on this machine (ModbusDriveSim, rig/testing/) listening on `rail_port` and
// `turntable_port`, response timeouts for a loaded machine running
// sanitizers, and the drives' map paths made absolute; written to `file`,
// its path.
inline std::filesystem::path write_modbus_tcp_rig_config(const std::filesystem::path& file, int rail_port,
                                                         int turntable_port) {
  const std::string map = (kSourceTree / "config/drives/generic.toml").string();
  return TomlConfig::load(kSourceTree / "config/rig-modbus-tcp.toml")
      .set("rig.buses.rail.host", "127.0.0.1")
      .set("rig.buses.rail.port", rail_port)
      .set("rig.buses.rail.response_timeout_ms", 500)
      .set("rig.buses.turntable.host", "127.0.0.1")
      .set("rig.buses.turntable.port", turntable_port)
      .set("rig.buses.turntable.response_timeout_ms", 500)
      .set("rig.rail.modbus.map", map)
      .set("rig.turntable.modbus.map", map)
      .write(file);
}

}  // namespace markerd::test_support
