// The rig's config (rig_config.cpp): the [rig] tables of a TOML file, parsed
// as if it lay in the repository's config/, so that a Modbus axis's `map =
// "drives/generic.toml"` reaches the shipped register maps. ConfigError is
// the one error it may raise.

#include <string>

#include "fuzz_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/rig/rig_config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::string source = (markerd::fuzz::config_dir() / "fuzz-input.toml").string();
  try {
    const auto root = markerd::ConfigTable::parse(markerd::fuzz::as_text(data, size), source);
    (void)markerd::rig::parse_rig_config(root);
  } catch (const markerd::ConfigError& e) {
    markerd::fuzz::expected_error(e);
  }
  return 0;
}
