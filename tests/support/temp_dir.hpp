#pragma once
// A temporary directory per use: fresh (mkdtemp, so parallel test processes
// and repeated runs never share one) and removed with everything in it.
// GoogleTest-free.

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>

#include "files.hpp"

namespace markerd::test_support {

class TempDir {
 public:
  // A new directory <system temp dir>/<prefix>-XXXXXX.
  explicit TempDir(std::string_view prefix = "markerd-test") {
    std::string pattern = (std::filesystem::temp_directory_path() / (std::string(prefix) + "-XXXXXX")).string();
    if (::mkdtemp(pattern.data()) == nullptr) {
      throw std::runtime_error("mkdtemp " + pattern + ": " + std::strerror(errno));
    }
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return path_; }
  [[nodiscard]] std::filesystem::path operator/(const std::filesystem::path& name) const { return path_ / name; }

  // Writes `text` to the file `name` in the directory; its path.
  std::filesystem::path write(const std::filesystem::path& name, std::string_view text) const {
    const std::filesystem::path file = path_ / name;
    write_file(file, text);
    return file;
  }

 private:
  std::filesystem::path path_;
};

}  // namespace markerd::test_support
