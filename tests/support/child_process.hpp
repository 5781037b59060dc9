#pragma once
// Programs run by tests and by the soak driver (tools/soak/): markerd and
// markerctl as child processes that can be killed at any moment, markerd's
// control socket once it accepts, and JSON-lines files read back as a reader
// would (every complete line must parse). Header-only and free of GoogleTest,
// so that a program that is not a test can use it too; a test turns the
// errors into failures.

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "markerd/daemon/control/control_client.hpp"

namespace markerd::test_support {

namespace fs = std::filesystem;

inline std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void write_file(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

inline std::string describe_wait_status(int status) {
  if (WIFEXITED(status)) return "exit status " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "killed by signal " + std::to_string(WTERMSIG(status));
  return "wait status " + std::to_string(status);
}

// A child process whose standard output and error are appended to a file.
// Whatever happens to its owner, it does not outlive the object, nor the
// thread that started it (PR_SET_PDEATHSIG: start children from a thread
// that lives as long as they should).
class ChildProcess {
 public:
  ChildProcess() = default;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ChildProcess(ChildProcess&& other) noexcept : pid_(std::exchange(other.pid_, -1)) {}
  ChildProcess& operator=(ChildProcess&& other) noexcept {
    if (this != &other) {
      if (pid_ > 0) (void)kill9();
      pid_ = std::exchange(other.pid_, -1);
    }
    return *this;
  }
  ~ChildProcess() {
    if (pid_ > 0) (void)kill9();
  }

  // Runs argv[0] with `argv`; its stdout and stderr are appended to `output`.
  // std::runtime_error when it is running already or fork fails. A program
  // that cannot be executed exits 127.
  void start(const std::vector<std::string>& argv, const fs::path& output) { start(argv, output, output); }

  // The same with stdout appended to `output`, stderr to `errors`.
  void start(const std::vector<std::string>& argv, const fs::path& output, const fs::path& errors) {
    if (pid_ > 0) throw std::runtime_error(argv.at(0) + " is running already");
    // Everything the child needs is made before fork(): the parent may have
    // threads, so the child may only make async-signal-safe calls.
    std::vector<std::string> args = argv;
    std::vector<char*> pointers;
    for (auto& a : args) pointers.push_back(a.data());
    pointers.push_back(nullptr);
    const std::string out_path = output.string();
    const std::string err_path = errors.string();
    const bool same = output == errors;
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
    if (pid == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);
      if (::getppid() != parent) _exit(125);
      const int in = ::open("/dev/null", O_RDONLY);
      const int out = ::open(out_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      const int err = same ? out : ::open(err_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (in < 0 || out < 0 || err < 0 || ::dup2(in, 0) < 0 || ::dup2(out, 1) < 0 || ::dup2(err, 2) < 0) _exit(126);
      ::execv(pointers[0], pointers.data());
      _exit(127);
    }
    pid_ = pid;
  }

  [[nodiscard]] bool running() const { return pid_ > 0; }
  [[nodiscard]] pid_t pid() const { return pid_; }

  // Has it ended by itself? Reaps it then: its wait status.
  [[nodiscard]] std::optional<int> exited() {
    if (pid_ <= 0) return std::nullopt;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) != pid_) return std::nullopt;
    pid_ = -1;
    return status;
  }

  void signal(int signal_number) const {
    if (pid_ > 0) ::kill(pid_, signal_number);
  }

  // SIGKILL and reap; the wait status.
  int kill9() {
    ::kill(pid_, SIGKILL);
    return reap();
  }

  // SIGTERM and reap; the wait status, or nothing when it has not ended
  // within `timeout` (it is still running then).
  std::optional<int> terminate(std::chrono::milliseconds timeout) {
    ::kill(pid_, SIGTERM);
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      if (auto status = exited()) return status;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return std::nullopt;
  }

 private:
  int reap() {
    int status = 0;
    while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
    }
    pid_ = -1;
    return status;
  }

  pid_t pid_ = -1;
};

// markerd's control socket at `socket`, once it accepts. std::runtime_error
// when markerd (`markerd`, running) ends first, with its wait status and
// `output` (its output file), or when `timeout` passes.
inline std::unique_ptr<daemon::ControlClient> connect_control(ChildProcess& markerd, const fs::path& socket,
                                                              const fs::path& output,
                                                              std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::string last_error;
  for (;;) {
    if (const auto status = markerd.exited()) {
      throw std::runtime_error("markerd ended (" + describe_wait_status(*status) +
                               ") before its control socket accepted:\n" + read_file(output));
    }
    try {
      return std::make_unique<daemon::ControlClient>(socket);
    } catch (const daemon::ControlClientError& e) {
      last_error = e.what();
    }
    if (std::chrono::steady_clock::now() > deadline) {
      throw std::runtime_error("markerd's control socket did not accept within " + std::to_string(timeout.count()) +
                               " ms: " + last_error);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

// A JSON-lines file as a reader takes it: what parsed, what did not.
struct JsonLines {
  std::size_t lines = 0;      // complete lines ('\n'-terminated)
  std::size_t objects = 0;    // of which JSON objects
  std::vector<std::string> problems;  // each line that is not a JSON object: its number, why, its start
  bool ends_whole = true;     // empty, or its last byte is a '\n'
  std::string tail;           // the bytes after the last '\n' (a torn last line)
};

// Reads `text` (a JSON-lines file's content). At most `max_problems` are kept.
inline JsonLines check_json_lines(std::string_view text, std::size_t max_problems = 10) {
  JsonLines r;
  std::size_t start = 0;
  for (std::size_t end = text.find('\n'); end != std::string_view::npos; end = text.find('\n', start)) {
    ++r.lines;
    const std::string_view line = text.substr(start, end - start);
    const nlohmann::json document = nlohmann::json::parse(line, nullptr, false);
    if (document.is_object()) {
      ++r.objects;
    } else if (r.problems.size() < max_problems) {
      r.problems.push_back("line " + std::to_string(r.lines) + " is not " +
                           (document.is_discarded() ? "whole JSON" : "a JSON object") + ": " +
                           std::string(line.substr(0, 200)));
    }
    start = end + 1;
  }
  if (start < text.size()) {
    r.ends_whole = false;
    r.tail = std::string(text.substr(start));
  }
  return r;
}

inline JsonLines check_json_lines_file(const fs::path& file, std::size_t max_problems = 10) {
  return check_json_lines(read_file(file), max_problems);
}

}  // namespace markerd::test_support
