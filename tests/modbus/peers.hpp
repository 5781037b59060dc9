#pragma once
// The real peers of the Modbus tests and benchmark: a child process that is
// always terminated and reaped (socat, Debian's python), and a socat
// pseudo-terminal pair standing in for an RS-485 line. GoogleTest-free, so
// that bench/bench_modbus.cpp can use it too.

#include <chrono>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace markerd::test_support {

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

// A peer program (found in PATH when not named by its path) with its output
// in `log`. The destructor terminates it (SIGTERM, then SIGKILL after 5 s)
// and reaps it; should this process die first, the kernel kills it
// (PR_SET_PDEATHSIG), so no test leaves a peer behind.
class PeerProcess {
 public:
  PeerProcess(const std::vector<std::string>& argv, const std::filesystem::path& log) { process_.start(argv, log); }
  ~PeerProcess() {
    if (process_.running() && !process_.terminate(std::chrono::seconds(5))) (void)process_.kill9();
  }
  PeerProcess(const PeerProcess&) = delete;
  PeerProcess& operator=(const PeerProcess&) = delete;

  // Still running (not exited)?
  bool running() { return process_.running() && !process_.exited(); }

 private:
  test_support::ChildProcess process_;
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
  PeerProcess socat_;
};

}  // namespace markerd::test_support
