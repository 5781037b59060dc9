#pragma once
// Programs run by the tests and by the soak driver (tools/soak/): a child
// process that does not outlive its owner, and a program run to its end with
// its outcome (exit code, standard output and error). GoogleTest-free, so
// that a program that is not a test can use it too; a test turns the errors
// (std::runtime_error) into failures.

#include <fcntl.h>
#include <grp.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

extern char** environ;

namespace markerd::test_support {

namespace fs = std::filesystem;

inline std::string describe_wait_status(int status) {
  if (WIFEXITED(status)) return "exit status " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "killed by signal " + std::to_string(WTERMSIG(status));
  return "wait status " + std::to_string(status);
}

// Where a program is: `name` itself when it names a path (has a '/'), else
// the first executable file `name` in PATH's directories, as execvp finds it.
inline std::optional<fs::path> find_program(const std::string& name) {
  if (name.find('/') != std::string::npos) return fs::path(name);
  const char* path = std::getenv("PATH");
  std::string_view dirs = path != nullptr ? path : "";
  while (!dirs.empty()) {
    const std::string_view dir = dirs.substr(0, dirs.find(':'));
    dirs.remove_prefix(std::min(dirs.size(), dir.size() + 1));
    if (dir.empty()) continue;
    const fs::path candidate = fs::path(dir) / name;
    if (::access(candidate.c_str(), X_OK) == 0 && !fs::is_directory(candidate)) return candidate;
  }
  return std::nullopt;
}

// The exit code as a shell reports it: 128 + the signal's number when a
// signal ended the program.
inline int exit_code(int wait_status) {
  return WIFEXITED(wait_status) ? WEXITSTATUS(wait_status) : 128 + WTERMSIG(wait_status);
}

inline UniqueFd open_or_throw(const fs::path& path, int flags) {
  const int fd = ::open(path.c_str(), flags | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error("cannot open " + path.string() + ": " + markerd::errno_text(errno));
  return UniqueFd(fd);
}

// How a child process runs besides its arguments.
struct ProcessOptions {
  // Changes to this process's environment: "NAME=value" sets NAME, "NAME" removes it.
  std::vector<std::string> environment;
  // Runs it as this user id, with the group id of the same number and no
  // supplementary groups (this process must be root); it exits 125 when it
  // cannot switch.
  std::optional<uid_t> user;
  // CapturedProcess: stderr into stdout, interleaved as a terminal shows them
  // (Outcome::err stays empty).
  bool merge_output = false;
  // Standard input from this file instead of /dev/null.
  std::optional<fs::path> input = std::nullopt;
};

// A child process with standard input from /dev/null (or ProcessOptions::input). Whatever happens to its
// owner, it does not outlive the object, nor the thread that started it
// (PR_SET_PDEATHSIG: start children from a thread that lives as long as they
// should).
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

  // Runs argv[0] (a path, or a name looked up in PATH) with `argv`; its
  // stdout and stderr are appended to `output`. std::runtime_error when it is
  // running already, is not found, a file cannot be opened or fork fails. A
  // program that cannot be executed exits 127.
  void start(const std::vector<std::string>& argv, const fs::path& output) { start(argv, output, output); }

  // The same with stdout appended to `output`, stderr to `errors`.
  void start(const std::vector<std::string>& argv, const fs::path& output, const fs::path& errors) {
    const UniqueFd out = open_or_throw(output, O_WRONLY | O_CREAT | O_APPEND);
    const UniqueFd err = output == errors ? UniqueFd() : open_or_throw(errors, O_WRONLY | O_CREAT | O_APPEND);
    start_with(argv, out.get(), err.get() >= 0 ? err.get() : out.get(), ProcessOptions{});
  }

  // Runs argv[0] with `argv`, its stdout and stderr onto the descriptors
  // `out` and `err` (the caller keeps its own).
  void start_with(const std::vector<std::string>& argv, int out, int err, const ProcessOptions& options) {
    if (pid_ > 0) throw std::runtime_error(argv.at(0) + " is running already");
    // Everything the child needs is made before fork(): the parent may have
    // threads, so the child may only make async-signal-safe calls.
    const std::optional<fs::path> program = find_program(argv.at(0));
    if (!program) throw std::runtime_error(argv.at(0) + ": no such program in PATH");
    std::vector<std::string> args = argv;
    std::string program_path = program->string();
    std::vector<char*> arg_pointers;
    for (auto& a : args) arg_pointers.push_back(a.data());
    arg_pointers.push_back(nullptr);
    std::vector<std::string> env = environment_with(options.environment);
    const bool switch_user = options.user.has_value();
    const uid_t user = options.user.value_or(0);
    std::vector<char*> env_pointers;
    for (auto& e : env) env_pointers.push_back(e.data());
    env_pointers.push_back(nullptr);
    const UniqueFd in = open_or_throw(options.input.value_or("/dev/null"), O_RDONLY);
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
    if (pid == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);
      if (::getppid() != parent) _exit(125);
      if (::dup2(in.get(), 0) < 0 || ::dup2(out, 1) < 0 || ::dup2(err, 2) < 0) _exit(126);
      if (switch_user && (::setgroups(0, nullptr) != 0 || ::setgid(user) != 0 || ::setuid(user) != 0)) _exit(125);
      ::execve(program_path.c_str(), arg_pointers.data(), env_pointers.data());
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

  // Its wait status once it has ended, or nothing when `timeout` passes first
  // (it is still running then).
  [[nodiscard]] std::optional<int> wait_for(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      if (auto status = exited()) return status;
      if (std::chrono::steady_clock::now() > deadline) return std::nullopt;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
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
    return wait_for(timeout);
  }

 private:
  static std::vector<std::string> environment_with(const std::vector<std::string>& overrides) {
    const auto name_of = [](std::string_view entry) { return entry.substr(0, entry.find('=')); };
    std::vector<std::string> env;
    for (char** e = environ; *e != nullptr; ++e) {
      const std::string_view entry(*e);
      bool overridden = false;
      for (const auto& o : overrides) overridden |= name_of(o) == name_of(entry);
      if (!overridden) env.emplace_back(entry);
    }
    for (const auto& o : overrides) {
      if (o.find('=') != std::string::npos) env.push_back(o);
    }
    return env;
  }

  int reap() {
    int status = 0;
    while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
    }
    pid_ = -1;
    return status;
  }

  pid_t pid_ = -1;
};

// How a program run to its end went.
struct Outcome {
  int code = -1;  // exit_code(): 128 + the signal's number when a signal ended it
  std::string out;
  std::string err;
  bool timed_out = false;  // killed when its time was up

  [[nodiscard]] std::string describe() const {
    return (timed_out ? "killed after its time was up, exit " : "exit ") + std::to_string(code) + "\n--- stdout\n" +
           out + "--- stderr\n" + err;
  }
};

// A program whose standard output and error are kept in memory files: no
// pipe that a chatty child could fill, no file left in the test's directory,
// and what it wrote so far readable while it runs.
class CapturedProcess {
 public:
  explicit CapturedProcess(const std::vector<std::string>& argv, const ProcessOptions& options = {})
      : out_(memory_file("stdout")), err_(memory_file("stderr")) {
    child_.start_with(argv, out_.get(), options.merge_output ? out_.get() : err_.get(), options);
  }

  [[nodiscard]] pid_t pid() const { return child_.pid(); }
  [[nodiscard]] std::string out() const { return contents(out_); }
  [[nodiscard]] std::string err() const { return contents(err_); }

  // Waits for its end; past `timeout` it is killed (Outcome::timed_out).
  Outcome wait(std::chrono::milliseconds timeout = std::chrono::minutes(5)) {
    if (!status_) {
      status_ = child_.wait_for(timeout);
      if (!status_) {
        timed_out_ = true;
        status_ = child_.kill9();
      }
    }
    return Outcome{exit_code(*status_), out(), err(), timed_out_};
  }

 private:
  static UniqueFd memory_file(const char* name) {
    const int fd = ::memfd_create(name, MFD_CLOEXEC);
    if (fd < 0) throw std::runtime_error(std::string("memfd_create: ") + std::strerror(errno));
    return UniqueFd(fd);
  }

  static std::string contents(const UniqueFd& file) {
    std::string text;
    char chunk[4096];
    for (off_t at = 0;;) {
      const ssize_t n = ::pread(file.get(), chunk, sizeof chunk, at);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      text.append(chunk, static_cast<std::size_t>(n));
      at += n;
    }
    return text;
  }

  UniqueFd out_, err_;
  ChildProcess child_;
  std::optional<int> status_;
  bool timed_out_ = false;
};

// Runs argv[0] with `argv` to its end (killed after `timeout`).
inline Outcome run_program(const std::vector<std::string>& argv, const ProcessOptions& options = {},
                           std::chrono::milliseconds timeout = std::chrono::minutes(5)) {
  return CapturedProcess(argv, options).wait(timeout);
}

}  // namespace markerd::test_support
