#pragma once
// markerd as a child process of a HIL test, and its detection log read back:
// what tests/hil/test_markerd_vivid.cpp and test_markerd_uvc.cpp share; and
// a command's output (markerctl's, in test_v4l2_hil.cpp too).

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>  // popen
#include <sys/wait.h>
#include <unistd.h>  // environ (g++ defines _GNU_SOURCE)

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "support/files.hpp"

namespace markerd::hil {

using Clock = std::chrono::steady_clock;

namespace fs = std::filesystem;
using nlohmann::json;

inline const char* env(const char* name) {
  const char* value = std::getenv(name);  // NOLINT(concurrency-mt-unsafe): read before any thread starts
  return value != nullptr && *value != '\0' ? value : nullptr;
}

inline bool wait_until(const std::function<bool()>& done, std::chrono::milliseconds timeout,
                       std::chrono::milliseconds interval = std::chrono::milliseconds(100)) {
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    if (done()) return true;
    if (Clock::now() >= deadline) return false;
    std::this_thread::sleep_for(interval);
  }
}

// Waits until `count()` reaches `target` (or `stop()` holds), for as long
// as the count keeps growing: a guest under emulation on a loaded host may
// log a frame every few seconds, and how fast is no test's business. False
// when the count stood still for `stall`, or after `cap` in all.
inline bool wait_for_progress(const std::function<std::size_t()>& count, std::size_t target,
                              const std::function<bool()>& stop, std::chrono::milliseconds stall,
                              std::chrono::milliseconds cap) {
  const auto start = Clock::now();
  auto last_change = start;
  std::size_t last = count();
  for (;;) {
    const std::size_t now_count = count();
    if (now_count >= target || stop()) return true;
    const auto now = Clock::now();
    if (now_count != last) {
      last = now_count;
      last_change = now;
    }
    if (now - last_change >= stall || now - start >= cap) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
}

inline double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

using test_support::read_file;

// ---------------------------------------------------------------- markerd

// markerd as a child process, its standard output and error in a file.
class MarkerdProcess {
 public:
  MarkerdProcess(const std::string& markerd, const fs::path& config, const fs::path& output) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&actions, 1, output.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, 1, 2);
    std::string program = markerd;
    std::string flag = "--config";
    std::string config_path = config.string();
    char* argv[] = {program.data(), flag.data(), config_path.data(), nullptr};
    // The test has threads (a feeder, a follower): posix_spawn, not fork.
    const int error = ::posix_spawn(&pid_, program.c_str(), &actions, nullptr, argv, environ);
    posix_spawn_file_actions_destroy(&actions);
    if (error != 0) throw std::runtime_error("posix_spawn " + program + ": " + std::strerror(error));
  }
  ~MarkerdProcess() {
    if (!exit_status_) {
      ::kill(pid_, SIGKILL);
      int status = 0;
      ::waitpid(pid_, &status, 0);
    }
  }
  MarkerdProcess(const MarkerdProcess&) = delete;
  MarkerdProcess& operator=(const MarkerdProcess&) = delete;

  [[nodiscard]] bool running() {
    if (exit_status_) return false;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) exit_status_ = status;
    return !exit_status_;
  }
  // The wait status once it has exited.
  [[nodiscard]] std::optional<int> exit_status() const { return exit_status_; }

  // SIGTERM, then its wait status; nothing when it has not exited in time.
  std::optional<int> terminate(std::chrono::milliseconds timeout) {
    if (running()) ::kill(pid_, SIGTERM);
    wait_until([this] { return !running(); }, timeout, std::chrono::milliseconds(20));
    return exit_status_;
  }

 private:
  pid_t pid_ = -1;
  std::optional<int> exit_status_;
};

// A shell command's standard output and error, its wait status in `status`;
// prints how long it took (markerctl loads OpenCV's libraries: seconds under TCG).
inline std::string run_command(const std::string& command, int& status) {
  const auto start = Clock::now();
  std::string out;
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) throw std::runtime_error(std::string("popen: ") + std::strerror(errno));
  std::array<char, 4096> chunk{};
  std::size_t n = 0;
  while ((n = std::fread(chunk.data(), 1, chunk.size(), pipe)) > 0) out.append(chunk.data(), n);
  status = ::pclose(pipe);
  std::cout << command << ": " << std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start).count()
            << " ms\n";
  return out;
}

// Polls markerd's status (through `status`) until `done` holds for it, or
// markerd exits, or `timeout` passes; the last status either way (a client
// error as {"client_error": ...}).
inline json wait_for_status(const std::function<json()>& status, const std::function<bool(const json&)>& done,
                            std::chrono::milliseconds timeout, MarkerdProcess& markerd) {
  json last;
  wait_until(
      [&] {
        if (!markerd.running()) return true;
        try {
          last = status();
        } catch (const std::exception& e) {
          last = {{"client_error", e.what()}};
          return false;
        }
        return done(last);
      },
      timeout, std::chrono::milliseconds(50));
  return last;
}

inline std::string describe_wait_status(int status) {
  if (WIFEXITED(status)) return "exit status " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return std::string("killed by ") + strsignal(WTERMSIG(status));
  return "wait status " + std::to_string(status);
}

// ---------------------------------------------------------------- the log

struct LogFile {
  std::vector<json> lines;  // the complete lines, parsed
  std::size_t unparsable = 0;
  bool ends_whole = true;  // the last byte is the last line's '\n'
};

// The run's detection log, as a reader following it takes it: complete
// lines only (a line being written has no '\n' yet).
inline LogFile read_log(const fs::path& directory) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(directory)) {
    if (entry.path().extension() == ".jsonl") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  LogFile log;
  for (const auto& file : files) {
    const std::string text = read_file(file);
    std::size_t start = 0;
    for (std::size_t end = text.find('\n'); end != std::string::npos; end = text.find('\n', start)) {
      json line = json::parse(text.begin() + static_cast<std::ptrdiff_t>(start),
                              text.begin() + static_cast<std::ptrdiff_t>(end), nullptr, false);
      if (line.is_discarded()) {
        ++log.unparsable;
      } else {
        log.lines.push_back(std::move(line));
      }
      start = end + 1;
    }
    if (start != text.size()) log.ends_whole = false;
  }
  return log;
}

inline Clock::time_point capture_time(const json& line) {
  return Clock::time_point(std::chrono::nanoseconds(line.at("frame").at("capture_monotonic_ns").get<std::int64_t>()));
}

// ---------------------------------------------------------------- truth

inline Eigen::Vector3d vector3(const json& a) {
  return {a.at(0).get<double>(), a.at(1).get<double>(), a.at(2).get<double>()};
}

inline Eigen::Matrix3d rotation_of(const Eigen::Vector3d& rvec) {
  const double angle = rvec.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, rvec / angle).toRotationMatrix();
}

inline double rotation_between_deg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const Eigen::AngleAxisd difference(a.transpose() * b);
  return std::abs(difference.angle()) * 180.0 / M_PI;
}

}  // namespace markerd::hil
