// A sweep run's records (records.cpp), read back as markerd reads them to
// resume an interrupted run and as `markerctl report` reads them, then
// expanded and summarised as those do.
//
// Input: the run directory's files, separated by NUL bytes (which no record
// holds, and which leave every file free to end as it likes, a partial last
// line included):
//   start.json \0 points.jsonl \0 events.jsonl \0 stop.json
// A file whose section is missing is absent (an empty section is an empty
// file); a fifth section and more are ignored. read_run reports every problem as a std::runtime_error naming the
// file and the line (a ConfigError for the plan inside start.json); any
// other exception type is a finding, as is a summary that throws.

#include <array>
#include <cstddef>
#include <string>
#include <string_view>
#include <system_error>
#include <typeinfo>
#include <vector>

#include "fuzz_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/summary.hpp"

namespace {

constexpr std::array<const char*, 4> kFiles{"start.json", "points.jsonl", "events.jsonl", "stop.json"};
std::vector<std::string_view> sections(std::string_view input) {
  std::vector<std::string_view> parts;
  std::size_t begin = 0;
  while (parts.size() < kFiles.size()) {
    const std::size_t end = input.find('\0', begin);
    parts.push_back(input.substr(begin, end == std::string_view::npos ? std::string_view::npos : end - begin));
    if (end == std::string_view::npos) break;
    begin = end + 1;
  }
  return parts;
}

bool expected(const std::runtime_error& e) {
  return typeid(e) == typeid(std::runtime_error) || typeid(e) == typeid(markerd::ConfigError);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path run = [] {
    const auto dir = markerd::fuzz::scratch_dir() / "run";
    std::filesystem::create_directories(dir);
    return dir;
  }();
  const std::vector<std::string_view> parts = sections(markerd::fuzz::as_text(data, size));
  for (std::size_t i = 0; i < kFiles.size(); ++i) {
    const auto path = run / kFiles[i];
    if (i < parts.size()) {
      markerd::fuzz::write_file(path, parts[i]);
    } else {
      std::error_code ec;
      std::filesystem::remove(path, ec);
    }
  }

  markerd::sweep::RunRecords records;
  try {
    records = markerd::sweep::read_run(run);
  } catch (const std::runtime_error& e) {
    if (!expected(e)) throw;
    markerd::fuzz::expected_error(e);
    return 0;
  }
  // What resuming does with them: the plan's steps, and the points against them.
  const auto steps = markerd::sweep::plan_steps(records.start.plan);
  for (std::size_t i = 0; i < records.points.size() && i < steps.size(); ++i) {
    (void)(records.points[i].step == steps[i].index);
  }
  const markerd::sweep::RunSummary summary = markerd::sweep::summarize(records);
  (void)markerd::sweep::points_csv(summary);
  (void)markerd::sweep::translation_csv(summary);
  (void)markerd::sweep::table_6_1({summary});
  return 0;
}
