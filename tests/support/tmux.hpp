#pragma once
// A program run on a terminal of a given size, as a user runs it: inside a
// tmux session of its own (a server on a socket in the test's directory),
// its screen read back as tmux shows it. For the tests of what is redrawn in
// place (live lines), which a pipe cannot show. tmux is one of the test
// dependencies (tools/install-deps.sh); without it these tests fail, saying so.

#include <chrono>
#include <filesystem>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "support/process.hpp"

namespace markerd::test_support {

class TmuxScreen {
 public:
  // Starts `argv` (with the environment changes `environment`, as
  // ProcessOptions takes them) on a `columns` x `rows` terminal. When it
  // ends the pane stays, its last line "[exit N]". std::runtime_error when
  // tmux is not on PATH or does not start.
  TmuxScreen(const std::vector<std::string>& argv, const std::vector<std::string>& environment, int columns, int rows,
             const std::filesystem::path& dir)
      : socket_(dir / "tmux.sock") {
    if (!find_program("tmux")) {
      throw std::runtime_error(
          "tmux is not on PATH: the live-line tests run markerctl inside it (tools/install-deps.sh installs it)");
    }
    std::string command = "env";
    for (const std::string& e : environment) command += " " + quoted(e);
    for (const std::string& a : argv) command += " " + quoted(a);
    command += "; echo \"[exit $?]\"; sleep 3600";
    const Outcome r = tmux({"new-session", "-d", "-x", std::to_string(columns), "-y", std::to_string(rows), "-s",
                            "test", "sh", "-c", command});
    if (r.code != 0) throw std::runtime_error("tmux new-session failed: " + r.describe());
    started_ = true;
  }
  ~TmuxScreen() {
    if (started_) (void)tmux({"kill-server"});
  }
  TmuxScreen(const TmuxScreen&) = delete;
  TmuxScreen& operator=(const TmuxScreen&) = delete;

  // The screen's lines as tmux shows them, a line wrapped by the terminal
  // joined again (so that a line too long for the terminal shows as such),
  // trailing empty lines left out.
  [[nodiscard]] std::vector<std::string> lines() const {
    const Outcome r = tmux({"capture-pane", "-p", "-J", "-t", "test"});
    if (r.code != 0) throw std::runtime_error("tmux capture-pane failed: " + r.describe());
    std::vector<std::string> lines;
    std::istringstream in(r.out);
    for (std::string line; std::getline(in, line);) lines.push_back(line);
    while (!lines.empty() && lines.back().find_first_not_of(' ') == std::string::npos) lines.pop_back();
    return lines;
  }

  [[nodiscard]] std::string text() const {
    std::string text;
    for (const std::string& line : lines()) text += line + '\n';
    return text;
  }

  // Polls the screen until `text` is on it; false when `timeout` passes.
  [[nodiscard]] bool wait_for(const std::string& text, std::chrono::seconds timeout = std::chrono::seconds(120)) const {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (this->text().find(text) == std::string::npos) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return true;
  }

  // Types keys as tmux's send-keys names them ("h", "Right", "q").
  void send_keys(const std::vector<std::string>& keys) const {
    std::vector<std::string> args{"send-keys", "-t", "test"};
    args.insert(args.end(), keys.begin(), keys.end());
    const Outcome r = tmux(args);
    if (r.code != 0) throw std::runtime_error("tmux send-keys failed: " + r.describe());
  }

 private:
  static std::string quoted(const std::string& word) {
    std::string q = "'";
    for (const char c : word) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
  }

  [[nodiscard]] Outcome tmux(const std::vector<std::string>& args) const {
    std::vector<std::string> argv{"tmux", "-S", socket_.string()};
    argv.insert(argv.end(), args.begin(), args.end());
    return run_program(argv, {}, std::chrono::seconds(60));
  }

  std::filesystem::path socket_;
  bool started_ = false;
};

}  // namespace markerd::test_support
