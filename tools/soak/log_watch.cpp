#include "log_watch.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <fstream>
#include <sstream>
#include <string_view>

namespace markerd::soak {

namespace fs = std::filesystem;

namespace {

constexpr std::uint64_t kFnvOffset = 14695981039346656037ULL;
constexpr std::uint64_t kFnvPrime = 1099511628211ULL;

std::uint64_t fnv1a(std::string_view bytes, std::uint64_t hash = kFnvOffset) {
  for (const char c : bytes) {
    hash ^= static_cast<unsigned char>(c);
    hash *= kFnvPrime;
  }
  return hash;
}

bool read_all(const fs::path& file, std::string& text) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return false;
  std::ostringstream s;
  s << in.rdbuf();
  text = std::move(s).str();
  return true;
}

}  // namespace

void LogWatch::look(const fs::path& file, std::vector<std::string>& problems) {
  auto [it, inserted] = files_.try_emplace(file);
  if (inserted) ++totals_.files;
  Seen& seen = it->second;
  std::string text;
  if (!read_all(file, text)) {
    if (seen.bytes > 0)
      problems.push_back(fmt::format("{}: gone, with {} bytes already logged", file.string(), seen.bytes));
    files_.erase(it);
    return;
  }
  if (text.size() < seen.bytes || fnv1a(std::string_view(text).substr(0, seen.bytes)) != seen.hash) {
    problems.push_back(fmt::format("{}: the {} bytes already logged were {} (now {} bytes)", file.string(), seen.bytes,
                                   text.size() < seen.bytes ? "cut" : "changed", text.size()));
    // Start again from what is there, so that one loss is reported once.
    seen = Seen{};
  }
  const std::string_view all(text);
  std::size_t start = seen.bytes;
  for (std::size_t end = all.find('\n', start); end != std::string_view::npos; end = all.find('\n', start)) {
    const std::string_view line = all.substr(start, end - start);
    ++totals_.lines;
    const nlohmann::json document = nlohmann::json::parse(line, nullptr, false);
    if (!document.is_object()) {
      ++totals_.bad_lines;
      if (totals_.bad_lines <= 20) {
        problems.push_back(fmt::format("{}: a line at byte {} is not {}: {}", file.string(), start,
                                       document.is_discarded() ? "whole JSON" : "a JSON object",
                                       std::string(line.substr(0, 160))));
      }
    }
    start = end + 1;
  }
  totals_.bytes += start - seen.bytes;
  seen.hash = fnv1a(all.substr(seen.bytes, start - seen.bytes), seen.hash);
  seen.bytes = start;
  seen.tail = std::string(all.substr(start));
}

void LogWatch::retire(const fs::path& file, bool must_end_whole, std::vector<std::string>& problems) {
  look(file, problems);
  const auto it = files_.find(file);
  if (it == files_.end()) return;
  if (!it->second.tail.empty()) {
    ++totals_.torn_tails;
    if (must_end_whole) {
      problems.push_back(fmt::format("{}: ends with a partial line ({} bytes: {})", file.string(),
                                     it->second.tail.size(), it->second.tail.substr(0, 160)));
    }
  }
  files_.erase(it);
}

std::vector<fs::path> LogWatch::watched() const {
  std::vector<fs::path> out;
  for (const auto& [path, seen] : files_) out.push_back(path);
  return out;
}

}  // namespace markerd::soak
