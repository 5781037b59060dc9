#include "markerd/base/read_file.hpp"

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstring>

namespace markerd {

namespace {

[[noreturn]] void fail(const std::filesystem::path& path, std::string_view what, std::string_view message) {
  throw FileError(fmt::format("{}: {} {}", path.string(), what, message));
}

// ENAMETOOLONG has two causes, and a user with a path of several hundred
// bytes wants to know which limit it breaks.
std::string name_too_long_words(const std::filesystem::path& path) {
  std::size_t longest = 0;
  for (const auto& part : path) longest = std::max(longest, part.native().size());
  if (longest > NAME_MAX) {
    return fmt::format("cannot be used: a name in its path is {} bytes long, longer than the {} a file system takes",
                       longest, NAME_MAX);
  }
  if (path.native().size() >= PATH_MAX) {
    return fmt::format("cannot be used: its path is {} bytes long, longer than the {} a path may be",
                       path.native().size(), PATH_MAX - 1);
  }
  return fmt::format("cannot be read: {}", errno_text(ENAMETOOLONG));  // too long once its links are followed
}

// stat() or open() failed with `error`.
[[noreturn]] void fail_to_look_up(const std::filesystem::path& path, std::string_view what, int error) {
  const std::string words =
      error == ENAMETOOLONG ? name_too_long_words(path) : fmt::format("cannot be read: {}", errno_text(error));
  // ENOTDIR: a part of the path is a file, so nothing lies beneath it.
  throw FileError(fmt::format("{}: {} {}", path.string(), what, words), error == ENOENT || error == ENOTDIR);
}

std::string_view kind_of(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

void check_stat(const std::filesystem::path& path, const struct stat& st, std::size_t max_bytes,
                std::string_view what) {
  if (!S_ISREG(st.st_mode)) {
    const auto kind = kind_of(st.st_mode);
    if (kind == "not a regular file") fail(path, what, "is not a regular file");
    fail(path, what, fmt::format("is {}, not a file", kind));
  }
  if (static_cast<std::uintmax_t>(st.st_size) > max_bytes) {
    fail(path, what,
         fmt::format("is {} ({} bytes), larger than the {} allowed", format_bytes(static_cast<std::size_t>(st.st_size)),
                     st.st_size, format_bytes(max_bytes)));
  }
}

}  // namespace

std::string format_bytes(std::size_t bytes) {
  if (bytes < 1024) return fmt::format("{} bytes", bytes);
  const double kib = static_cast<double>(bytes) / 1024.0;
  if (kib < 1024) return fmt::format("{:.{}f} KiB", kib, bytes % 1024 == 0 ? 0 : 1);
  const double mib = kib / 1024.0;
  if (mib < 1024) return fmt::format("{:.{}f} MiB", mib, bytes % (1024 * 1024) == 0 ? 0 : 1);
  return fmt::format("{:.1f} GiB", mib / 1024.0);
}

std::size_t check_regular_file(const std::filesystem::path& path, std::size_t max_bytes, std::string_view what) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) fail_to_look_up(path, what, errno);
  check_stat(path, st, max_bytes, what);
  return static_cast<std::size_t>(st.st_size);
}

std::string read_regular_file(const std::filesystem::path& path, std::size_t max_bytes, std::string_view what) {
  // O_NONBLOCK: opening a FIFO must not wait for a writer before fstat can
  // tell that it is one; on a regular file the flag changes nothing.
  const UniqueFd file(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY));
  if (!file) fail_to_look_up(path, what, errno);
  const int fd = file.get();
  struct stat st {};
  if (::fstat(fd, &st) != 0) fail(path, what, fmt::format("cannot be read: {}", errno_text(errno)));
  check_stat(path, st, max_bytes, what);

  std::string text(static_cast<std::size_t>(st.st_size), '\0');
  std::size_t used = 0;
  for (;;) {
    if (used == text.size()) {
      if (text.size() > max_bytes) {
        fail(path, what, fmt::format("grew beyond the {} allowed while it was read", format_bytes(max_bytes)));
      }
      text.resize(std::min(max_bytes + 1, std::max<std::size_t>(text.size() * 2, 4096)));
    }
    const ssize_t n = ::read(fd, text.data() + used, text.size() - used);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail(path, what, fmt::format("cannot be read: {}", errno_text(errno)));
    }
    if (n == 0) break;
    used += static_cast<std::size_t>(n);
  }
  if (used > max_bytes)
    fail(path, what, fmt::format("grew beyond the {} allowed while it was read", format_bytes(max_bytes)));
  text.resize(used);
  return text;
}

}  // namespace markerd
