#pragma once
// Exclusive use of a rig's devices between processes. Two processes driving
// one motor (markerd and a markerctl bring-up session, or two of either)
// would fight over its lines or its bus, so every process that drives a rig
// first locks each device its config uses: each GPIO chip, each serial
// device, each Modbus TCP host:port, and for simulated axes the config file
// itself (its simulated machine).
//
// The locks are flock(2) locks on one file per device in a lock directory
// (/run/lock/markerd, or $MARKERD_LOCK_DIR; created when missing). The kernel
// drops a lock when its holder exits, however it exits, so a lock is never
// stale; the file holds the holder's PID and command line so that a refusal
// says who to ask: "rail's /dev/ttyUSB0 is in use by markerd (pid 1234: ...)".
// All the locks of a rig are taken in one fixed order (by file name), without
// waiting, and all are released when one is refused.

#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "markerd/base/unique_fd.hpp"
#include "markerd/rig/rig_config.hpp"

namespace markerd::rig {

// One device to lock.
struct DeviceClaim {
  std::string kind;    // "gpio", "serial", "tcp", "sim": the lock file's prefix
  std::string device;  // the device, normalised so that two names of one device lock one file
  std::string what;    // for messages: "rail's /dev/gpiochip0", "rail's and turntable's /dev/ttyUSB0"
};

// The devices a rig config uses, one claim per device, in lock order.
[[nodiscard]] std::vector<DeviceClaim> device_claims(const RigConfig& config);

// Another process holds a device (or the lock directory is unusable); the
// message names the device, what uses it and the holder.
class DeviceLockError : public std::runtime_error {
 public:
  explicit DeviceLockError(const std::string& message, bool held = false) : std::runtime_error(message), held_(held) {}
  // Another holder has the lock (it is free once that one lets go), rather
  // than a lock that cannot be taken at all (a directory or file that
  // cannot be made or opened).
  [[nodiscard]] bool held() const noexcept { return held_; }

 private:
  bool held_;
};

class DeviceLock {
 public:
  // $MARKERD_LOCK_DIR when set and not empty, else /run/lock/markerd.
  [[nodiscard]] static std::filesystem::path default_directory();

  // Locks every claimed device, or none: DeviceLockError on the first one
  // held by another process (or another DeviceLock of this one). Never waits.
  explicit DeviceLock(std::vector<DeviceClaim> claims, const std::filesystem::path& directory = default_directory());
  ~DeviceLock();  // releases every lock
  DeviceLock(DeviceLock&& other) noexcept;
  DeviceLock& operator=(DeviceLock&& other) noexcept;
  DeviceLock(const DeviceLock&) = delete;
  DeviceLock& operator=(const DeviceLock&) = delete;

  [[nodiscard]] const std::vector<DeviceClaim>& claims() const { return claims_; }
  // The lock files held, in the order they were taken.
  [[nodiscard]] std::vector<std::filesystem::path> files() const;

  // The lock file of a claim: <directory>/<kind>-<device, sanitised>.lock.
  [[nodiscard]] static std::filesystem::path file_for(const DeviceClaim& claim, const std::filesystem::path& directory);

 private:
  void release() noexcept;

  std::vector<DeviceClaim> claims_;
  std::vector<std::filesystem::path> files_;
  std::vector<UniqueFd> fds_;
};

// device_claims(config), locked in the default directory.
[[nodiscard]] DeviceLock lock_rig_devices(const RigConfig& config);

}  // namespace markerd::rig
