#pragma once
// Lines redrawn in place on a terminal: the interactive jog's status, a
// sweep's progress, an axis homing or moving. Each redraw is cut to the
// terminal's width as it is at that moment (a window resized meanwhile
// included), so that a line never wraps: a wrapped line leaves a stale row
// behind at every redraw and the screen fills up.

#include <cstddef>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace markerctl {

// The columns UTF-8 text takes on a terminal: one per character ("°" and
// "±" one each; markerctl prints no wide or combining characters).
std::size_t display_columns(std::string_view text);

// The longest start of `text` that takes at most `columns` columns, never
// cutting a character in two.
std::string_view fit_to_columns(std::string_view text, std::size_t columns);

// `parts` joined by `separator`, as many as fit in `columns` from the first
// (the most important) on; the first alone is cut to fit.
std::string join_fitting(const std::vector<std::string>& parts, std::string_view separator, std::size_t columns);

// A part of a line that may be left out when the line is too wide: the
// parts of the lowest `keep` go first (of equals, the later one), and what
// is left keeps its order. `separator` goes before it unless it comes first.
struct LinePart {
  std::string text;
  int keep = 0;
  std::string separator = "  ";
};

// The parts that fit in `columns`, leaving out the least kept first; the
// last part left alone is cut to fit.
std::string join_keeping(const std::vector<LinePart>& parts, std::size_t columns);

// The width of the terminal on `fd` (TIOCGWINSZ), else $COLUMNS, else 80.
std::size_t terminal_columns(int fd);

// One live line on the terminal `fd`, written to `out`. Nothing is drawn
// when `fd` is not a terminal (a pipe or a file gets the permanent lines
// only). The line is cleared when this ends, an exception's way out too.
class LiveLine {
 public:
  LiveLine(std::ostream& out, int fd);
  ~LiveLine();
  LiveLine(const LiveLine&) = delete;
  LiveLine& operator=(const LiveLine&) = delete;

  [[nodiscard]] bool on_terminal() const { return terminal_; }
  // The columns a line may take now (the terminal's, less the last).
  [[nodiscard]] std::size_t columns() const { return width(); }

  // Redraws the line: its start that fits, the rest of the row cleared. The
  // last column is left free: a character there makes some terminals wrap.
  void show(std::string_view text);
  // Redraws it from parts, as many as fit (join_fitting).
  void show(const std::vector<std::string>& parts, std::string_view separator);
  // A permanent line above the live one (on a terminal the live line is
  // cleared first and drawn again by the next show()).
  void print(std::string_view text);
  // Clears the live line.
  void clear();
  // Leaves the live line on the screen as it is drawn, a permanent line.
  void keep();

 private:
  [[nodiscard]] std::size_t width() const;

  std::ostream& out_;
  int fd_;
  bool terminal_;
  bool shown_ = false;
};

}  // namespace markerctl
