// markerctl report: the report of a sweep run, or of several side by side,
// rebuilt from the runs' records alone (no daemon needed, and a run that was
// cut off still reports what it measured): report.md with the thesis's Table
// 6.1, the CSVs and the gnuplot plots (sweep/report.hpp).

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "common.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/report.hpp"
#include "markerd/sweep/summary.hpp"

namespace markerctl {
namespace {

namespace fs = std::filesystem;

struct ReportCommandOptions {
  std::vector<std::string> runs;
  std::string output;
  bool no_plots = false;
};

// read_run's messages name the file; the directory is what the user typed.
std::string naming(const std::string& directory, const std::string& why) {
  return why.find(directory) == std::string::npos ? fmt::format("{}: {}", directory, why) : why;
}

int run_report(const ReportCommandOptions& o) {
  if (o.runs.size() > 1 && o.output.empty()) {
    throw usage_error("report", "-o OUT_DIR is required for several runs (their reports would go into each)");
  }
  std::vector<markerd::sweep::RunRecords> runs;
  for (const auto& directory : o.runs) {
    std::error_code error;
    const auto status = fs::status(directory, error);
    if (!fs::exists(status)) {
      throw runtime_error(
          "report", fmt::format("{}: no such run directory{}", directory,
                                error && error != std::errc::no_such_file_or_directory ? " (" + error.message() + ")"
                                                                                       : std::string()));
    }
    if (!fs::is_directory(status)) throw runtime_error("report", fmt::format("{}: not a directory", directory));
    try {
      runs.push_back(markerd::sweep::read_run(directory));
    } catch (const std::exception& e) {
      throw runtime_error("report", naming(directory, e.what()));
    }
  }

  markerd::sweep::ReportOptions options;
  options.output_directory = o.output.empty() ? fs::path(o.runs.front()) / "report" : fs::path(o.output);
  options.plots = !o.no_plots;
  markerd::sweep::ReportFiles files;
  try {
    files = markerd::sweep::write_report(runs, options);
  } catch (const std::exception& e) {
    throw runtime_error("report", e.what());
  }

  std::vector<markerd::sweep::RunSummary> summaries;
  for (const auto& run : runs) summaries.push_back(markerd::sweep::summarize(run));
  // The path alone on the first line, for scripts; the table for people.
  std::cout << files.report.string() << "\n\n" << markerd::sweep::table_6_1(summaries);
  return 0;
}

}  // namespace

void add_report_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<ReportCommandOptions>();
  CLI::App* app =
      parent.add_subcommand("report", "The report of a sweep run (or several side by side) from its records");
  app->footer(
      "Reads each RUN_DIR's records (start.json, points.jsonl, events.jsonl, stop.json) and writes into OUT_DIR:\n"
      "report.md (the run, the thesis's Table 6.1, every point, appendix C's translation vectors, the events),\n"
      "summary.csv (one line per point), translation.csv (one line per measurement) and, unless --no-plots,\n"
      "rate-vs-distance.svg, pose-error-vs-distance.svg and rate-map.svg, drawn by gnuplot (gnuplot-nox) from the\n"
      ".gp and .dat files kept beside them. Several runs: one column or curve per run, and per-run CSVs\n"
      "(summary-RUN_ID.csv, ...). A run still going (or cut off) reports what it has, as 'incomplete'.\n"
      "Prints the path of report.md, then Table 6.1. Exit status: 0 written, 1 a run that cannot be read or a\n"
      "report that cannot be written (gnuplot missing or failing), 2 bad usage.");
  app->add_option("run", o->runs, "A sweep run's directory, as markerd wrote it")->type_name("RUN_DIR")->required();
  app->add_option("-o,--output", o->output, "Where the report goes (default RUN_DIR/report; required for several runs)")
      ->type_name("OUT_DIR");
  app->add_flag("--no-plots", o->no_plots, "Tables and CSVs only (gnuplot not needed)");
  commands.push_back({app, [o] { return run_report(*o); }});
}

}  // namespace markerctl
