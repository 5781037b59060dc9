#include "small_disk.hpp"

#include <fcntl.h>
#include <sys/mount.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

namespace markerd::soak {

namespace fs = std::filesystem;

namespace {

fs::path ballast_of(const fs::path& mount_point) { return mount_point / "ballast"; }

bool is_mount_point(const fs::path& path) {
  std::ifstream mounts("/proc/self/mounts");
  const std::string target = fs::weakly_canonical(path).string();
  for (std::string device, where, rest; mounts >> device >> where && std::getline(mounts, rest);) {
    if (where == target) return true;
  }
  return false;
}

}  // namespace

SmallDisk::SmallDisk(fs::path mount_point, std::uint64_t size_mib) : mount_point_(std::move(mount_point)) {
  fs::create_directories(mount_point_);
  const std::string options = "size=" + std::to_string(size_mib) + "m,mode=0755";
  if (::mount("markerd-soak", mount_point_.c_str(), "tmpfs", MS_NOSUID | MS_NODEV, options.c_str()) != 0) {
    const int error = errno;
    throw std::runtime_error("cannot mount a tmpfs (" + options + ") at " + mount_point_.string() + ": " +
                             errno_text(error) + (error == EPERM ? " (the soak must run as root)" : ""));
  }
  mounted_ = true;
}

SmallDisk::~SmallDisk() {
  try {
    unmount();
  } catch (...) {  // NOLINT(bugprone-empty-catch): a destructor reports nothing; unmount() said it already
  }
}

std::uint64_t SmallDisk::fill() {
  const fs::path ballast = ballast_of(mount_point_);
  const UniqueFd fd(::open(ballast.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644));
  if (!fd) throw std::runtime_error("cannot create " + ballast.string() + ": " + errno_text(errno));
  std::uint64_t written = 0;
  // Large writes first, then pages, then single bytes: full to the last block.
  for (const std::size_t chunk : {std::size_t{1} << 20, std::size_t{4096}, std::size_t{1}}) {
    const std::vector<char> bytes(chunk, 0);
    for (;;) {
      const ssize_t n = ::write(fd.get(), bytes.data(), bytes.size());
      if (n > 0) {
        written += static_cast<std::uint64_t>(n);
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && errno != ENOSPC) {
        throw std::runtime_error("writing " + ballast.string() + ": " + errno_text(errno));
      }
      break;
    }
  }
  full_ = true;
  return written;
}

void SmallDisk::free() {
  std::error_code ec;
  fs::remove(ballast_of(mount_point_), ec);
  if (ec) throw std::runtime_error("cannot remove " + ballast_of(mount_point_).string() + ": " + ec.message());
  full_ = false;
}

std::uint64_t SmallDisk::free_bytes() const {
  struct statvfs s {};
  if (::statvfs(mount_point_.c_str(), &s) != 0) return 0;
  return static_cast<std::uint64_t>(s.f_bavail) * s.f_frsize;
}

std::uint64_t SmallDisk::size_bytes() const {
  struct statvfs s {};
  if (::statvfs(mount_point_.c_str(), &s) != 0) return 0;
  return static_cast<std::uint64_t>(s.f_blocks) * s.f_frsize;
}

void SmallDisk::unmount() {
  if (!mounted_) return;
  mounted_ = false;
  if (::umount2(mount_point_.c_str(), MNT_DETACH) != 0) {
    throw std::runtime_error("cannot unmount " + mount_point_.string() + ": " + errno_text(errno));
  }
}

void SmallDisk::unmount_stale(const fs::path& mount_point) {
  std::error_code ec;
  if (!fs::exists(mount_point, ec) || !is_mount_point(mount_point)) return;
  if (::umount2(mount_point.c_str(), MNT_DETACH) != 0) {
    throw std::runtime_error("cannot unmount " + mount_point.string() +
                             " (left by an earlier soak): " + errno_text(errno));
  }
}

}  // namespace markerd::soak
