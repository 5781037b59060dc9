#include "live_line.hpp"

#include <sys/ioctl.h>
#include <unistd.h>

#include <charconv>
#include <cstdlib>

namespace markerctl {
namespace {

// The first byte of a UTF-8 character: anything but a continuation byte.
bool starts_character(char c) { return (static_cast<unsigned char>(c) & 0xc0) != 0x80; }

}  // namespace

std::size_t display_columns(std::string_view text) {
  std::size_t columns = 0;
  for (const char c : text) columns += starts_character(c) ? 1 : 0;
  return columns;
}

std::string_view fit_to_columns(std::string_view text, std::size_t columns) {
  std::size_t used = 0;
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (!starts_character(text[i])) continue;
    if (used == columns) return text.substr(0, i);
    ++used;
  }
  return text;
}

std::string join_fitting(const std::vector<std::string>& parts, std::string_view separator, std::size_t columns) {
  std::string line;
  for (const std::string& part : parts) {
    const std::size_t needed =
        display_columns(line) + (line.empty() ? 0 : display_columns(separator)) + display_columns(part);
    if (needed > columns) {
      if (line.empty()) line = fit_to_columns(part, columns);
      break;
    }
    if (!line.empty()) line += separator;
    line += part;
  }
  return line;
}

std::string join_keeping(const std::vector<LinePart>& parts, std::size_t columns) {
  std::vector<bool> kept(parts.size(), true);
  const auto join = [&] {
    std::string line;
    bool first = true;
    for (std::size_t i = 0; i < parts.size(); ++i) {
      if (!kept[i]) continue;
      if (!first) line += parts[i].separator;
      line += parts[i].text;
      first = false;
    }
    return line;
  };
  std::string line = join();
  for (std::size_t left = parts.size(); left > 1 && display_columns(line) > columns; --left) {
    std::size_t least = parts.size();
    for (std::size_t i = 0; i < parts.size(); ++i) {
      if (kept[i] && (least == parts.size() || parts[i].keep <= parts[least].keep)) least = i;
    }
    kept[least] = false;
    line = join();
  }
  return std::string(fit_to_columns(line, columns));
}

std::size_t terminal_columns(int fd) {
  winsize size{};
  if (::ioctl(fd, TIOCGWINSZ, &size) == 0 && size.ws_col > 0) return size.ws_col;
  if (const char* env = std::getenv("COLUMNS"); env != nullptr) {
    std::size_t columns = 0;
    const std::string_view text(env);
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), columns);
    if (ec == std::errc{} && end == text.data() + text.size() && columns > 0) return columns;
  }
  return 80;
}

LiveLine::LiveLine(std::ostream& out, int fd) : out_(out), fd_(fd), terminal_(::isatty(fd) != 0) {}

LiveLine::~LiveLine() { clear(); }

std::size_t LiveLine::width() const {
  const std::size_t columns = terminal_columns(fd_);
  return columns > 1 ? columns - 1 : 1;
}

void LiveLine::show(std::string_view text) {
  if (!terminal_) return;
  out_ << '\r' << fit_to_columns(text, width()) << "\x1b[K" << std::flush;
  shown_ = true;
}

void LiveLine::show(const std::vector<std::string>& parts, std::string_view separator) {
  if (!terminal_) return;
  show(join_fitting(parts, separator, width()));
}

void LiveLine::print(std::string_view text) {
  clear();
  out_ << text << '\n' << std::flush;
}

void LiveLine::clear() {
  if (!shown_) return;
  out_ << "\r\x1b[K" << std::flush;
  shown_ = false;
}

void LiveLine::keep() {
  if (!shown_) return;
  out_ << '\n' << std::flush;
  shown_ = false;
}

}  // namespace markerctl
