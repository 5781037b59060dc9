#pragma once
// Whole files as strings, for the tests and the soak driver (tools/soak/):
// reading back what a program wrote, writing a fixture. GoogleTest-free.

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markerd::test_support {

// The file's bytes; a file that is absent or unreadable reads as empty, as
// an output file a program has not written yet does.
inline std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

// Replaces the file's content with `text`. A fixture that could not be
// written would make the test about something else: std::runtime_error.
inline void write_file(const std::filesystem::path& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  out.close();
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

}  // namespace markerd::test_support
