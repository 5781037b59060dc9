#pragma once
// JSON-lines files watched while markerd writes them (the detection logs, a
// run's points.jsonl and events.jsonl): at every look, the bytes seen
// before are still there, unchanged (nothing already logged is lost), and
// every complete line since parses as a JSON object. Each line is parsed
// once; a line being written (no '\n' yet) waits for the next look.

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace markerd::soak {

struct WatchTotals {
  std::uint64_t files = 0;
  std::uint64_t lines = 0;       // complete lines parsed
  std::uint64_t bad_lines = 0;   // complete lines that are not JSON objects
  std::uint64_t bytes = 0;       // bytes of complete lines
  std::uint64_t torn_tails = 0;  // files retired with a partial last line (markerd killed mid-write)
};

class LogWatch {
 public:
  // Looks at `file` again. A problem (appended to `problems`) when bytes seen
  // before have gone or changed, or a new line does not parse.
  void look(const std::filesystem::path& file, std::vector<std::string>& problems);

  // Looks a last time and forgets the file (it is about to be removed, or
  // the soak ends). A partial last line is counted as a torn tail; when
  // `must_end_whole`, it is a problem.
  void retire(const std::filesystem::path& file, bool must_end_whole, std::vector<std::string>& problems);

  [[nodiscard]] bool watching(const std::filesystem::path& file) const { return files_.contains(file); }
  [[nodiscard]] std::vector<std::filesystem::path> watched() const;
  [[nodiscard]] const WatchTotals& totals() const { return totals_; }

 private:
  struct Seen {
    std::uint64_t bytes = 0;                       // the complete lines checked so far
    std::uint64_t hash = 14695981039346656037ULL;  // FNV-1a of those bytes (its offset basis: none yet)
    std::string tail;                              // what followed them at the last look
  };
  std::map<std::filesystem::path, Seen> files_;
  WatchTotals totals_;
};

}  // namespace markerd::soak
