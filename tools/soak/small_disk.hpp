#pragma once
// markerd's logs and state on a file system of their own, small enough to
// fill: a tmpfs mounted with size= (mounting needs root). The soak fills it
// with a ballast file until the kernel says ENOSPC, holds it full, and frees
// it again, as a disk that something else filled up and an operator cleaned.

#include <cstdint>
#include <filesystem>

namespace markerd::soak {

class SmallDisk {
 public:
  // Mounts a tmpfs of `size_mib` at `mount_point` (created if missing).
  // std::runtime_error naming the mount point and the cause when it cannot
  // (not root, no tmpfs).
  SmallDisk(std::filesystem::path mount_point, std::uint64_t size_mib);
  ~SmallDisk();  // frees the ballast and unmounts
  SmallDisk(const SmallDisk&) = delete;
  SmallDisk& operator=(const SmallDisk&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return mount_point_; }

  // Writes the ballast until the file system is full; the bytes it took.
  std::uint64_t fill();
  // Removes the ballast.
  void free();
  [[nodiscard]] bool full() const { return full_; }

  [[nodiscard]] std::uint64_t free_bytes() const;
  [[nodiscard]] std::uint64_t size_bytes() const;

  // Unmounts now (after the records have been read and copied away).
  void unmount();

  // Unmounts a tmpfs left at `mount_point` by a soak that was itself killed.
  static void unmount_stale(const std::filesystem::path& mount_point);

 private:
  std::filesystem::path mount_point_;
  bool mounted_ = false;
  bool full_ = false;
};

}  // namespace markerd::soak
