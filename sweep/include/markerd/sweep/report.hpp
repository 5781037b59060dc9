#pragma once
// The report of one run, or of several side by side: Markdown with the
// thesis's Table 6.1 and the threshold calls behind its limits, the
// per-point table, appendix C's translation vectors, and plots drawn by
// gnuplot as SVG and PDF (detection rate against distance, pose error
// against distance and against angle, detection rate over distance x angle;
// 95% intervals as error bars, the thesis's limits as reference lines).
// Built from the records alone, so `markerctl report RUN_DIR` can rebuild it
// at any time.

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
  std::string table_6_1;        // Table 6.1 as report.md has it, with its notes
  std::string threshold_calls;  // the calls behind its limits, as report.md has them (threshold_calls())
};

// One run: its report. Several: side by side (one column or curve per run),
// the runs named by their run ids. std::runtime_error naming what failed
// (an unwritable directory, gnuplot missing or failing with its message).
ReportFiles write_report(const std::vector<RunRecords>& runs, const ReportOptions& options);

// The runs of one marker as mounted (the thesis's paper marker or its socket
// marker): its distance run and its angle runs, say.
struct MarkerRuns {
  Mounting mounting = Mounting::paper;
  std::vector<RunRecords> runs;
};

// The thesis's two markers compared, as its Table 6.1 does: a column for each
// marker's runs taken together (summarize_together), beside the thesis's
// column for that marker (table_6_1_by_marker); everything else as for
// several runs, one column or curve per run, the runs' table naming each
// run's marker. std::invalid_argument for a marker without runs, or whose
// runs measured different markers or at different thresholds; otherwise as
// write_report.
ReportFiles write_report_by_marker(const std::vector<MarkerRuns>& markers, const ReportOptions& options);

}  // namespace markerd::sweep
