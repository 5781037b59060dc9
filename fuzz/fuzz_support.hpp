#pragma once
// What the fuzz targets share: where the repository's config/ is (so that a
// config naming "rig-sim.toml" or "cameras/thesis-640x480.yaml" finds the
// shipped files), a scratch directory in memory for the readers that only
// take a path, and the rule for what a target may let pass.
//
// A target catches the errors its entry point documents (ConfigError,
// CameraModelError, ...) and nothing else: any other exception escapes
// LLVMFuzzerTestOneInput, std::terminate names its type and message, and
// libFuzzer (or replay_main) reports the input as a finding, as it does a
// crash, a sanitizer report or a hang.

#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>
#include <string_view>

namespace markerd::fuzz {

// The repository's config/ (MARKERD_FUZZ_CONFIG_DIR, set by fuzz/CMakeLists.txt).
[[nodiscard]] std::filesystem::path config_dir();

// A directory of this process's own, in /dev/shm when it is there (files
// written for every input must not wear a disk), removed at exit.
[[nodiscard]] const std::filesystem::path& scratch_dir();

// Replaces `path` with exactly `bytes`; aborts when it cannot (the machine,
// not the input, is at fault).
void write_file(const std::filesystem::path& path, std::string_view bytes);

[[nodiscard]] inline std::string_view as_text(const std::uint8_t* data, std::size_t size) {
  return {reinterpret_cast<const char*>(data), size};
}

// An error the entry point documents: nothing to report, but printed when
// MARKERD_FUZZ_VERBOSE is set, to see why a seed is refused.
void expected_error(const std::exception& e);

// Prints why the input is a finding and aborts: for checks of the results
// (a reply that is not JSON), where there is no exception to escape.
[[noreturn]] void finding(std::string_view what);

}  // namespace markerd::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);
