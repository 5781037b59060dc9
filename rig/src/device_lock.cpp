#include "markerd/rig/device_lock.hpp"

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <utility>
#include <variant>

namespace markerd::rig {
namespace {

constexpr const char* kDefaultDirectory = "/run/lock/markerd";
constexpr const char* kDirectoryVariable = "MARKERD_LOCK_DIR";

// A path with its symbolic links resolved where they exist, so that
// /dev/serial/by-id/usb-FTDI-... and /dev/ttyUSB0 lock the same file.
std::string resolved_path(const std::string& path) {
  std::error_code ec;
  const auto absolute = std::filesystem::absolute(path, ec);
  if (ec) return path;
  const auto canonical = std::filesystem::weakly_canonical(absolute, ec);
  return ec ? absolute.lexically_normal().string() : canonical.string();
}

bool is_chip_name(const std::string& chip) {
  constexpr std::string_view prefix = "gpiochip";
  return chip.size() > prefix.size() && chip.starts_with(prefix) &&
         std::all_of(chip.begin() + static_cast<std::ptrdiff_t>(prefix.size()), chip.end(),
                     [](unsigned char c) { return c >= '0' && c <= '9'; });
}

// "gpiochip0" and "/dev/gpiochip0" are one chip. A chip given by its label
// stays a label: two configs naming one chip by label and by name are not
// told apart here (the kernel still refuses a line held twice).
std::string gpio_chip_device(const std::string& chip) {
  if (chip.find('/') != std::string::npos) return resolved_path(chip);
  if (is_chip_name(chip)) return resolved_path("/dev/" + chip);
  return chip;
}

std::string tcp_device(const ModbusBusSettings& bus) {
  return bus.host.find(':') != std::string::npos ? fmt::format("[{}]:{}", bus.host, bus.port)
                                                 : fmt::format("{}:{}", bus.host, bus.port);
}

// FNV-1a: stable across processes and builds, unlike std::hash.
std::uint64_t fnv1a(std::string_view text) {
  std::uint64_t hash = 0xcbf29ce484222325ULL;
  for (const unsigned char c : text) {
    hash ^= c;
    hash *= 0x100000001b3ULL;
  }
  return hash;
}

std::string sanitised(std::string_view device) {
  std::string name;
  for (const char c : device) {
    const bool plain =
        (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '-' || c == '_';
    name += plain ? c : '_';
  }
  name.erase(0, name.find_first_not_of('_'));
  if (name.empty() || name.find_first_not_of('.') == std::string::npos) name = "_" + name;
  // Keep well under NAME_MAX (255); the hash keeps long names apart.
  constexpr std::size_t kMaxName = 160;
  if (name.size() > kMaxName) name = fmt::format("{}-{:016x}", name.substr(0, kMaxName - 17), fnv1a(device));
  return name;
}

// Up to 64 KiB of a file from its start (plain reads: iostreams trip g++ 12's
// -Wnull-dereference).
std::string read_head(int fd) {
  std::string text;
  char buffer[4096];
  off_t offset = 0;
  while (text.size() < 64 * 1024) {
    const ssize_t n = ::pread(fd, buffer, sizeof buffer, offset);
    if (n <= 0) break;
    text.append(buffer, static_cast<std::size_t>(n));
    offset += n;
  }
  return text;
}

// This process, as other processes' refusals name it: its PID and command line.
std::string holder_record() {
  std::string command;
  if (const UniqueFd fd(::open("/proc/self/cmdline", O_RDONLY | O_CLOEXEC)); fd) command = read_head(fd.get());
  while (!command.empty() && command.back() == '\0') command.pop_back();
  std::replace(command.begin(), command.end(), '\0', ' ');
  std::replace(command.begin(), command.end(), '\n', ' ');
  return fmt::format("{}\n{}\n", ::getpid(), command);
}

// "markerd (pid 1234: markerd --config /etc/markerd/rig.toml)" from a lock file.
std::string describe_holder(int fd) {
  const std::string text = read_head(fd);
  const auto first_end = text.find('\n');
  const std::string pid = text.substr(0, first_end);
  std::string command = first_end == std::string::npos ? std::string() : text.substr(first_end + 1);
  command = command.substr(0, command.find('\n'));
  if (pid.empty()) return "another process (it has not recorded itself in the lock file yet)";
  const std::string program = command.empty()
                                  ? std::string("a process")
                                  : std::filesystem::path(command.substr(0, command.find(' '))).filename().string();
  return command.empty() ? fmt::format("{} (pid {})", program, pid)
                         : fmt::format("{} (pid {}: {})", program, pid, command);
}

std::string join_users(const std::vector<std::string>& users) {
  std::string text;
  for (std::size_t i = 0; i < users.size(); ++i) {
    if (i > 0) text += i + 1 == users.size() ? " and " : ", ";
    text += users[i] + "'s";
  }
  return text;
}

}  // namespace

std::vector<DeviceClaim> device_claims(const RigConfig& config) {
  struct Use {
    std::string shown;               // the device as the messages name it
    std::vector<std::string> users;  // the axes using it
  };
  std::map<std::pair<std::string, std::string>, Use> uses;  // by (kind, device)
  const auto add = [&](std::string kind, std::string device, std::string shown, const std::string& axis) {
    Use& use = uses[{std::move(kind), std::move(device)}];
    if (use.shown.empty()) use.shown = std::move(shown);
    if (std::find(use.users.begin(), use.users.end(), axis) == use.users.end()) use.users.push_back(axis);
  };
  for (const AxisConfig* axis : {&config.rail, &config.turntable}) {
    const std::string& name = axis->axis.name;
    if (std::holds_alternative<SimDriveSettings>(axis->drive)) {
      // A simulated machine lives in the process that runs it; two processes
      // on one config would each move "the" rig their own way.
      const std::string path = config.source.starts_with('<') ? config.source : resolved_path(config.source);
      add("sim", path, fmt::format("simulated rig {}", path), name);
    } else if (const auto* gpio = std::get_if<GpioStepperSettings>(&axis->drive)) {
      std::set<std::string> chips{gpio->step.chip, gpio->dir.chip, gpio->enable.chip};
      for (const auto* line : {&gpio->limit_min, &gpio->limit_max, &gpio->home, &gpio->estop}) {
        if (*line) chips.insert((*line)->chip);
      }
      for (const auto& chip : chips) add("gpio", gpio_chip_device(chip), fmt::format("GPIO chip {}", chip), name);
    } else if (const auto* modbus = std::get_if<ModbusAxisSettings>(&axis->drive)) {
      const auto bus = config.buses.find(modbus->drive.bus);
      if (bus == config.buses.end()) {
        throw std::invalid_argument(fmt::format("{}: no Modbus bus '{}' in the config", name, modbus->drive.bus));
      }
      const ModbusBusSettings& b = bus->second;
      if (b.transport == ModbusTransport::rtu) {
        add("serial", resolved_path(b.device), b.device, name);
      } else {
        add("tcp", tcp_device(b), fmt::format("Modbus TCP {}", tcp_device(b)), name);
      }
    }
  }
  std::vector<DeviceClaim> claims;
  for (auto& [key, use] : uses) {
    claims.push_back(DeviceClaim{key.first, key.second, fmt::format("{} {}", join_users(use.users), use.shown)});
  }
  return claims;
}

std::filesystem::path DeviceLock::default_directory() {
  const char* dir = std::getenv(kDirectoryVariable);
  return dir != nullptr && *dir != '\0' ? std::filesystem::path(dir) : std::filesystem::path(kDefaultDirectory);
}

std::filesystem::path DeviceLock::file_for(const DeviceClaim& claim, const std::filesystem::path& directory) {
  return directory / fmt::format("{}-{}.lock", sanitised(claim.kind), sanitised(claim.device));
}

DeviceLock::DeviceLock(std::vector<DeviceClaim> claims, const std::filesystem::path& directory) {
  std::error_code ec;
  if (std::filesystem::create_directories(directory, ec)) {
    // Like /run/lock itself: every user's processes may add lock files, and
    // the sticky bit keeps them from removing each other's.
    ::chmod(directory.c_str(), 01777);
  } else if (ec) {
    throw DeviceLockError(fmt::format("cannot create the device lock directory {}: {} (set {} to another directory)",
                                      directory.string(), ec.message(), kDirectoryVariable));
  }
  // One fixed order for every process (by file name); claims that come to the
  // same file are one lock.
  std::map<std::filesystem::path, DeviceClaim> by_file;
  for (auto& claim : claims) {
    auto path = file_for(claim, directory);
    const auto [it, inserted] = by_file.try_emplace(path, claim);
    if (!inserted) it->second.what += " and " + claim.what;
  }
  const std::string record = holder_record();
  try {
    for (auto& [path, claim] : by_file) {
      UniqueFd fd(::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0666));
      // Another user's lock file: it can be locked, but not written.
      if (!fd && errno == EACCES) fd.reset(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW));
      if (!fd) {
        const int error = errno;
        throw DeviceLockError(
            fmt::format("{}: cannot open the lock file {}: {}", claim.what, path.string(), errno_text(error)));
      }
      if (::flock(fd.get(), LOCK_EX | LOCK_NB) != 0) {
        const int error = errno;
        const std::string holder = error == EWOULDBLOCK ? describe_holder(fd.get()) : std::string();
        if (error == EWOULDBLOCK) {
          throw DeviceLockError(fmt::format("{} is in use by {} (lock file {})", claim.what, holder, path.string()),
                                true);
        }
        throw DeviceLockError(fmt::format("{}: cannot lock {}: {}", claim.what, path.string(), errno_text(error)));
      }
      // Best effort: a refusal without the holder's name is still a refusal.
      if (::ftruncate(fd.get(), 0) == 0) {
        [[maybe_unused]] const auto written = ::pwrite(fd.get(), record.data(), record.size(), 0);
      }
      fds_.push_back(std::move(fd));
      files_.push_back(path);
      claims_.push_back(claim);
    }
  } catch (...) {
    release();
    throw;
  }
}

DeviceLock::~DeviceLock() { release(); }

DeviceLock::DeviceLock(DeviceLock&& other) noexcept
    : claims_(std::move(other.claims_)), files_(std::move(other.files_)), fds_(std::move(other.fds_)) {
  other.claims_.clear();
  other.files_.clear();
  other.fds_.clear();
}

DeviceLock& DeviceLock::operator=(DeviceLock&& other) noexcept {
  if (this != &other) {
    release();
    claims_ = std::move(other.claims_);
    files_ = std::move(other.files_);
    fds_ = std::move(other.fds_);
    other.claims_.clear();
    other.files_.clear();
    other.fds_.clear();
  }
  return *this;
}

std::vector<std::filesystem::path> DeviceLock::files() const { return files_; }

void DeviceLock::release() noexcept {
  // In reverse order; the files stay (unlinking a lock file races with a
  // process that has just opened it), emptied of this holder's record.
  for (auto fd = fds_.rbegin(); fd != fds_.rend(); ++fd) {
    [[maybe_unused]] const int truncated = ::ftruncate(fd->get(), 0);
    fd->reset();
  }
  fds_.clear();
  files_.clear();
  claims_.clear();
}

DeviceLock lock_rig_devices(const RigConfig& config) { return DeviceLock(device_claims(config)); }

}  // namespace markerd::rig
