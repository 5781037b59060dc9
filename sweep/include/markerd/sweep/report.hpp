#pragma once
// The report of one run, or of several side by side: Markdown with the
// thesis's Table 6.1, the per-point table, appendix C's translation vectors,
// and plots drawn by gnuplot (detection rate and pose error against
// distance, detection rate over distance x angle). Built from the records
// alone, so `markerctl report RUN_DIR` can rebuild it at any time.

#include <filesystem>
#include <string>
#include <vector>

#include "markerd/sweep/records.hpp"
#include "markerd/sweep/summary.hpp"

namespace markerd::sweep {

struct ReportOptions {
  std::filesystem::path output_directory;  // created if missing
  bool plots = true;                       // false: tables only (no gnuplot needed)
  std::string gnuplot = "gnuplot";         // the program, found on PATH
};

struct ReportFiles {
  std::filesystem::path report;  // report.md
  std::vector<std::filesystem::path> csv;
  std::vector<std::filesystem::path> plots;
};

// One run: its report. Several: side by side (one column or curve per run),
// the runs named by their run ids. std::runtime_error naming what failed
// (an unwritable directory, gnuplot missing or failing with its message).
ReportFiles write_report(const std::vector<RunRecords>& runs, const ReportOptions& options);

}  // namespace markerd::sweep
