#pragma once
// Reads of files a user names (configs, plans, camera models, images): only a
// regular file is read, and only up to a limit, so that a directory, a FIFO, a
// device such as /dev/zero or a file far too large is refused at once with an
// error that says which, instead of hanging or filling memory.

#include <cstddef>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markerd {

class FileError : public std::runtime_error {
 public:
  explicit FileError(const std::string& message, bool missing = false)
      : std::runtime_error(message), missing_(missing) {}

  // Nothing is there by that name (the caller may say "no such rig file"),
  // as opposed to something there that cannot be used or a name that the
  // file system cannot look up at all (too long, a loop of links).
  [[nodiscard]] bool missing() const noexcept { return missing_; }

 private:
  bool missing_;
};

// The whole file. `what` names the file's role in errors ("the config", "the
// plan"): "plan.toml: the plan is a directory, not a file". The size is checked
// before reading and again while reading (a file may grow).
[[nodiscard]] std::string read_regular_file(const std::filesystem::path& path, std::size_t max_bytes,
                                            std::string_view what);

// Checks what read_regular_file checks without reading, for files that a
// library then opens itself (an image decoder, OpenCV's FileStorage), and for
// a path a config names, where every reason it cannot be used (missing, a
// directory, a name too long) must become the config's error at its key:
// unlike std::filesystem::exists or status, it throws nothing but FileError.
// Returns the file's size.
std::size_t check_regular_file(const std::filesystem::path& path, std::size_t max_bytes, std::string_view what);

// "64 KiB", "1.5 MiB": sizes in errors.
[[nodiscard]] std::string format_bytes(std::size_t bytes);

}  // namespace markerd
