// The main of a fuzz target in the normal (gcc) builds: runs the target
// once over every file it is given, and every file of every directory it is
// given, in name order. The tests (label fuzz-replay) run each target over
// its corpus this way, so the sanitizer build of tools/run-tests.sh replays
// every corpus under ASan and UBSan, and a crash once fixed stays fixed.
//
// Each input's name is printed before it runs: a finding aborts the
// process, and the last name printed is the input that did it.

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "fuzz_support.hpp"
#include "markerd/base/read_file.hpp"

namespace {

// libFuzzer's inputs are far smaller; a larger file is not an input.
constexpr std::size_t kMaxInputBytes = 16 * 1024 * 1024;

std::vector<std::filesystem::path> inputs_of(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_directory(path, ec)) return {path};
  std::vector<std::filesystem::path> files;
  for (const auto& entry : std::filesystem::directory_iterator(path)) {
    if (entry.is_regular_file()) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR_OR_FILE...\n", argv[0]);
    return 2;
  }
  std::size_t count = 0;
  for (int i = 1; i < argc; ++i) {
    const std::vector<std::filesystem::path> files = inputs_of(argv[i]);
    if (files.empty()) {
      // An empty corpus would pass without testing anything.
      std::fprintf(stderr, "replay: %s holds no inputs\n", argv[i]);
      return 1;
    }
    for (const auto& file : files) {
      std::string bytes;
      try {
        bytes = markerd::read_regular_file(file, kMaxInputBytes, "the input");
      } catch (const markerd::FileError& e) {
        std::fprintf(stderr, "replay: %s\n", e.what());
        return 1;
      }
      std::printf("replay: %s (%zu bytes)\n", file.c_str(), bytes.size());
      std::fflush(stdout);
      LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
      ++count;
    }
  }
  std::printf("replay: %zu inputs, no findings\n", count);
  return 0;
}
