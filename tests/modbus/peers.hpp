#pragma once
// The real peers of the Modbus tests and benchmark: a temporary directory, a
// child process that is always killed and reaped (socat, Debian's python),
// and a socat pseudo-terminal pair standing in for an RS-485 line.
// GoogleTest-free, so that bench/bench_modbus.cpp can use it too.

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace markerd::test {

// Polls `condition` every 2 ms until it holds (true) or `timeout` passes.
inline bool wait_for(const std::function<bool()>& condition,
                     std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

// A fresh directory under the system's temp directory, removed with
// everything in it.
class TempDir {
 public:
  TempDir() {
    std::string pattern = (std::filesystem::temp_directory_path() / "markerd-modbus-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  [[nodiscard]] const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// A child process with its output in `log`. The destructor terminates and
// reaps it; should this process die first, the kernel sends the child
// SIGTERM (PR_SET_PDEATHSIG), so no test leaves a peer behind.
class ChildProcess {
 public:
  ChildProcess(std::vector<std::string> argv, const std::filesystem::path& log) {
    std::vector<char*> args;
    for (auto& a : argv) args.push_back(a.data());
    args.push_back(nullptr);
    const pid_t parent = ::getpid();
    pid_ = ::fork();
    if (pid_ < 0) throw std::runtime_error("fork failed");
    if (pid_ == 0) {
      // Only async-signal-safe calls between fork and exec.
      ::prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (::getppid() != parent) ::_exit(127);
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
      if (fd >= 0) {
        ::dup2(fd, STDOUT_FILENO);
        ::dup2(fd, STDERR_FILENO);
      }
      ::execvp(args[0], args.data());
      ::_exit(127);
    }
  }
  ~ChildProcess() { terminate(); }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // Still running (not exited)?
  bool running() {
    if (pid_ <= 0) return false;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return false;
    }
    return true;
  }

  void terminate() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGTERM);
    int status = 0;
    for (int i = 0; i < 500; ++i) {  // up to 5 s, then no more patience
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }

 private:
  pid_t pid_ = -1;
};

// Two pseudo-terminals joined by socat: bytes written to one end are read at
// the other, like the two ends of a serial line. libmodbus opens each end as
// a serial device (the baud rate is not enforced by a pty).
class SocatPtyPair {
 public:
  explicit SocatPtyPair(const std::filesystem::path& dir)
      : a_(dir / "a"),
        b_(dir / "b"),
        socat_({"socat", "-d", "-d", "pty,raw,echo=0,link=" + a_.string(), "pty,raw,echo=0,link=" + b_.string()},
               dir / "socat.log") {
    if (!wait_for([&] { return std::filesystem::exists(a_) && std::filesystem::exists(b_); },
                  std::chrono::seconds(10))) {
      throw std::runtime_error("socat did not create " + a_.string() + " and " + b_.string() + " (see " +
                               (dir / "socat.log").string() + ")");
    }
  }
  [[nodiscard]] const std::filesystem::path& a() const { return a_; }
  [[nodiscard]] const std::filesystem::path& b() const { return b_; }

 private:
  std::filesystem::path a_, b_;
  ChildProcess socat_;
};

}  // namespace markerd::test
