#pragma once
// markerd as a child process of the tests and of the soak driver
// (tools/soak/): its control socket once it accepts, and JSON-lines files
// read back as a reader would (every complete line must parse). Header-only
// and free of GoogleTest, so that a program that is not a test can use it
// too; a test turns the errors into failures.

#include <chrono>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "files.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "process.hpp"

namespace markerd::test_support {

namespace fs = std::filesystem;

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
  std::size_t lines = 0;              // complete lines ('\n'-terminated)
  std::size_t objects = 0;            // of which JSON objects
  std::vector<std::string> problems;  // each line that is not a JSON object: its number, why, its start
  bool ends_whole = true;             // empty, or its last byte is a '\n'
  std::string tail;                   // the bytes after the last '\n' (a torn last line)
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
