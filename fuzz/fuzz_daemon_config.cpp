// markerd's config (daemon_config.cpp): the TOML text of a markerd.toml,
// parsed as if it lay in the repository's config/, so that `rig =
// "rig-sim.toml"` and `model = "cameras/thesis-640x480.yaml"` reach the
// shipped rig and camera files and their parsers too. ConfigError is the
// one error it may raise. A config it accepts must give markerd its
// detectors: what --check-config passes must not fail when markerd starts.

#include <string>

#include "fuzz_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/daemon/daemon_config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::string source = (markerd::fuzz::config_dir() / "fuzz-input.toml").string();
  try {
    const auto root = markerd::ConfigTable::parse(markerd::fuzz::as_text(data, size), source);
    const markerd::daemon::DaemonConfig config = markerd::daemon::parse_daemon_config(root);
    (void)markerd::detector::make_detector(markerd::daemon::detector_config(config));
  } catch (const markerd::ConfigError& e) {
    markerd::fuzz::expected_error(e);
  }
  return 0;
}
