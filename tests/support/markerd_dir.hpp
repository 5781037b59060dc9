#pragma once
// A directory for a markerd under test.

#include <cstdlib>
#include <filesystem>

namespace markerd::test_support {

// markerd's device locks go to dir/locks (MARKERD_LOCK_DIR, which markerd
// children inherit and this process's own DeviceLocks read), not the
// machine's /run/lock/markerd, and its logs/ and state/ directories exist.
// It sets the environment: call it before any thread starts.
inline void prepare_markerd_dir(const std::filesystem::path& dir) {
  ::setenv("MARKERD_LOCK_DIR", (dir / "locks").c_str(), 1);  // NOLINT(concurrency-mt-unsafe): no threads yet
  std::filesystem::create_directories(dir / "logs");
  std::filesystem::create_directories(dir / "state");
}

}  // namespace markerd::test_support
