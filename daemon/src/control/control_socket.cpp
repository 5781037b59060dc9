#include "control_socket.hpp"

#include <fcntl.h>
#include <grp.h>
#include <pwd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <vector>

#include "markerd/base/errno_text.hpp"

namespace markerd::daemon {

namespace {

[[noreturn]] void socket_error(const std::filesystem::path& path, std::string_view why) {
  throw ControlSocketError(fmt::format("control socket {}: {}", path.string(), why));
}

sockaddr_un socket_address(const std::filesystem::path& path) {
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  const std::string& text = path.native();
  if (text.size() >= sizeof address.sun_path) {
    socket_error(path, fmt::format("the path is {} bytes long; a Unix socket's address holds at most {}", text.size(),
                                   sizeof address.sun_path - 1));
  }
  std::memcpy(address.sun_path, text.c_str(), text.size() + 1);
  return address;
}

std::optional<gid_t> group_id(const std::string& name) {
  long size = ::sysconf(_SC_GETGR_R_SIZE_MAX);
  std::vector<char> buffer(size > 0 ? static_cast<std::size_t>(size) : 16384);
  for (;;) {
    group entry{};
    group* found = nullptr;
    const int error = ::getgrnam_r(name.c_str(), &entry, buffer.data(), buffer.size(), &found);
    if (error == ERANGE) {
      buffer.resize(buffer.size() * 2);
      continue;
    }
    if (error != 0 || found == nullptr) return std::nullopt;
    return found->gr_gid;
  }
}

// Whether a process accepts connections on the socket at `path`: true when
// one does, false when nobody listens (a stale socket file); a
// ControlSocketError when it cannot be told.
bool someone_listens(const std::filesystem::path& path, const sockaddr_un& address) {
  const UniqueFd fd(::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0));
  if (!fd) socket_error(path, fmt::format("socket(): {}", errno_text(errno)));
  const int result = ::connect(fd.get(), reinterpret_cast<const sockaddr*>(&address), sizeof address);
  const int error = errno;
  if (result == 0) return true;
  // EAGAIN: a listener whose backlog is full, which is alive all the same.
  if (error == EAGAIN || error == EINPROGRESS) return true;
  if (error == ECONNREFUSED) return false;
  socket_error(path, fmt::format("exists, and connecting to it to see whether a markerd still listens failed: {}",
                                 errno_text(error)));
}

bool member_of(gid_t gid) {
  if (::getegid() == gid) return true;
  const int count = ::getgroups(0, nullptr);
  if (count <= 0) return false;
  std::vector<gid_t> groups(static_cast<std::size_t>(count));
  const int got = ::getgroups(count, groups.data());
  return got > 0 && std::find(groups.begin(), groups.begin() + got, gid) != groups.begin() + got;
}

std::string user_name(uid_t uid) {
  std::vector<char> buffer(16384);
  passwd entry{};
  passwd* found = nullptr;
  if (::getpwuid_r(uid, &entry, buffer.data(), buffer.size(), &found) != 0 || found == nullptr) {
    return fmt::format("uid {}", uid);
  }
  return fmt::format("'{}'", found->pw_name);
}

}  // namespace

std::optional<std::string> find_socket_path_problem(const ControlSettings& settings) {
  const std::filesystem::path& path = settings.socket_path;
  if (path.empty()) return "no path configured";
  if (path.native().size() >= sizeof(sockaddr_un::sun_path)) {
    return fmt::format("the path is {} bytes long; a Unix socket's address holds at most {}", path.native().size(),
                       sizeof(sockaddr_un::sun_path) - 1);
  }
  std::filesystem::path directory = path.parent_path();
  if (directory.empty()) directory = ".";
  struct stat st {};
  if (::stat(directory.c_str(), &st) != 0) {
    const int error = errno;
    return fmt::format("its directory {}: {}{}", directory.string(), errno_text(error),
                       error == ENOENT ? " (it is not created here: systemd's RuntimeDirectory= does)" : "");
  }
  if (!S_ISDIR(st.st_mode)) return fmt::format("{} is not a directory", directory.string());
  // bind() makes the socket file: it needs to write in the directory.
  if (::faccessat(AT_FDCWD, directory.c_str(), W_OK | X_OK, AT_EACCESS) != 0) {
    const int error = errno;
    return fmt::format("markerd, running as user {}, cannot make the socket in {}: {}", user_name(::geteuid()),
                       directory.string(), errno_text(error));
  }
  if (::lstat(path.c_str(), &st) == 0 && !S_ISSOCK(st.st_mode)) {
    return "exists and is not a socket; it is left alone";
  }
  return std::nullopt;
}

std::optional<std::string> find_socket_group_problem(const ControlSettings& settings) {
  if (settings.group.empty()) return std::nullopt;
  const std::optional<gid_t> gid = group_id(settings.group);
  if (!gid) {
    return fmt::format(
        "group '{}' does not exist (create it, e.g. with systemd-sysusers, or name another in "
        "[control] group)",
        settings.group);
  }
  // Only root, or a member, may give a file to a group.
  if (::geteuid() != 0 && !member_of(*gid)) {
    return fmt::format(
        "markerd, running as user {}, is not a member of group '{}' and cannot give the socket to it "
        "(the unit's Group= or SupplementaryGroups= makes it one)",
        user_name(::geteuid()), settings.group);
  }
  return std::nullopt;
}

ListeningSocket listen_on_control_socket(const ControlSettings& settings) {
  const std::filesystem::path& path = settings.socket_path;
  if (path.empty()) throw ControlSocketError("control socket: no path configured");
  if ((settings.mode & ~mode_t{0777}) != 0 || (settings.mode & 0007) != 0) {
    socket_error(path, fmt::format("mode 0{:o} would give other users access; the socket moves the rig",
                                   static_cast<unsigned>(settings.mode)));
  }
  if (const auto problem = find_socket_path_problem(settings)) socket_error(path, *problem);
  if (const auto problem = find_socket_group_problem(settings)) socket_error(path, *problem);
  const sockaddr_un address = socket_address(path);
  std::optional<gid_t> gid;
  if (!settings.group.empty()) gid = group_id(settings.group);

  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (!S_ISSOCK(st.st_mode)) socket_error(path, "exists and is not a socket; it is left alone");
    if (someone_listens(path, address)) {
      socket_error(path, "another process is listening on it (is another markerd running?); it is left alone");
    }
    if (::unlink(path.c_str()) != 0 && errno != ENOENT) {
      socket_error(path, fmt::format("cannot remove the stale socket: {}", errno_text(errno)));
    }
    spdlog::info("control socket {}: replaced a stale socket (left by a process that ended without removing it)",
                 path.string());
  }

  UniqueFd fd(::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
  if (!fd) socket_error(path, fmt::format("socket(): {}", errno_text(errno)));
  if (::bind(fd.get(), reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
    socket_error(path, fmt::format("cannot bind: {}", errno_text(errno)));
  }
  // Owner, group and mode are set between bind() and listen(): until
  // listen() every connect() is refused, so no client ever reaches the
  // socket with the permissions the umask gave it.
  const auto fail_bound = [&](const std::string& why) {
    fd.reset();
    ::unlink(path.c_str());
    socket_error(path, why);
  };
  if (gid && ::chown(path.c_str(), static_cast<uid_t>(-1), *gid) != 0) {
    const int error = errno;
    fail_bound(fmt::format("cannot give it to group '{}': {}{}", settings.group, errno_text(error),
                           error == EPERM ? " (markerd must run as a member of that group: the unit's Group= or "
                                            "SupplementaryGroups=)"
                                          : ""));
  }
  if (::chmod(path.c_str(), settings.mode) != 0) {
    fail_bound(
        fmt::format("cannot set its mode to 0{:o}: {}", static_cast<unsigned>(settings.mode), errno_text(errno)));
  }
  if (::lstat(path.c_str(), &st) != 0) fail_bound(fmt::format("cannot stat it after bind: {}", errno_text(errno)));
  if (::listen(fd.get(), static_cast<int>(std::min<std::size_t>(settings.max_clients, 128))) != 0) {
    fail_bound(fmt::format("cannot listen: {}", errno_text(errno)));
  }
  return {std::move(fd), st.st_dev, st.st_ino};
}

}  // namespace markerd::daemon
