#include "fuzz_support.hpp"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <system_error>

namespace markerd::fuzz {

namespace {

// MARKERD_FUZZ_SCRATCH when set (tools/run-fuzz.sh names one, and removes
// it after a crash, when no exit handler runs).
std::filesystem::path make_scratch_dir() {
  std::error_code ec;
  std::filesystem::path dir;
  if (const char* named = std::getenv("MARKERD_FUZZ_SCRATCH"); named != nullptr && *named != '\0') {
    dir = named;
  } else {
    const std::filesystem::path base = std::filesystem::is_directory("/dev/shm", ec)
                                           ? std::filesystem::path("/dev/shm")
                                           : std::filesystem::temp_directory_path();
    dir = base / ("markerd-fuzz-" + std::to_string(::getpid()));
  }
  std::filesystem::remove_all(dir, ec);
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    std::fprintf(stderr, "fuzz: cannot create %s: %s\n", dir.c_str(), ec.message().c_str());
    std::abort();
  }
  return dir;
}

void remove_scratch_dir() {
  std::error_code ec;
  std::filesystem::remove_all(scratch_dir(), ec);
}

}  // namespace

std::filesystem::path config_dir() { return MARKERD_FUZZ_CONFIG_DIR; }

const std::filesystem::path& scratch_dir() {
  // Never destroyed: the exit handler that removes it runs after static destructors.
  static const std::filesystem::path* const dir = [] {
    const auto* made = new std::filesystem::path(make_scratch_dir());
    std::atexit(remove_scratch_dir);
    return made;
  }();
  return *dir;
}

void write_file(const std::filesystem::path& path, std::string_view bytes) {
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  file.close();
  if (!file) {
    std::fprintf(stderr, "fuzz: cannot write %s\n", path.c_str());
    std::abort();
  }
}

void expected_error(const std::exception& e) {
  static const bool verbose = std::getenv("MARKERD_FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "fuzz: expected error: %s\n", e.what());
}

void finding(std::string_view what) {
  std::fprintf(stderr, "fuzz: finding: %.*s\n", static_cast<int>(what.size()), what.data());
  std::abort();
}

}  // namespace markerd::fuzz
