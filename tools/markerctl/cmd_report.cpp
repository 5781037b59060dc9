// markerctl report: the report of a sweep run, or of several side by side,
// or of the paper and the socket marker's runs compared as the thesis's Table
// 6.1 compares them, rebuilt from the runs' records alone (no daemon needed,
// and a run that was cut off still reports what it measured): report.md with
// Table 6.1, the CSVs and the gnuplot plots (sweep/report.hpp).

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
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
  std::vector<std::string> paper;   // --paper: the paper marker's runs, for Table 6.1's paper column
  std::vector<std::string> socket;  // --socket: the socket marker's
  std::string output;
  bool no_plots = false;
  bool json = false;
};

// read_run's messages name the file; the directory is what the user typed.
std::string naming(const std::string& directory, const std::string& why) {
  return why.find(directory) == std::string::npos ? fmt::format("{}: {}", directory, why) : why;
}

// `argument`: how the user gave the directory ("runs/x", "--socket runs/x"),
// for the errors.
markerd::sweep::RunRecords read_run_directory(const std::string& directory, const std::string& argument) {
  std::error_code error;
  const auto status = fs::status(directory, error);
  if (!fs::exists(status)) {
    throw runtime_error(
        "report", fmt::format("{}: no such run directory{}", argument,
                              error && error != std::errc::no_such_file_or_directory ? " (" + error.message() + ")"
                                                                                     : std::string()));
  }
  if (!fs::is_directory(status)) throw runtime_error("report", fmt::format("{}: not a directory", argument));
  try {
    return markerd::sweep::read_run(directory);
  } catch (const std::exception& e) {
    throw runtime_error("report", naming(argument, e.what()));
  }
}

using markerd::sweep::Mounting;

// The runs given for one marker's column, checked against what their plans
// say they measured.
markerd::sweep::MarkerRuns read_marker_runs(const std::vector<std::string>& directories, Mounting mounting,
                                            std::string_view option) {
  markerd::sweep::MarkerRuns marker{mounting, {}};
  for (const auto& directory : directories) {
    const std::string argument = fmt::format("{} {}", option, directory);
    marker.runs.push_back(read_run_directory(directory, argument));
    const markerd::sweep::RunStart& start = marker.runs.back().start;
    const auto stated = start.marker_mounting();
    if (stated && *stated != mounting) {
      throw usage_error("report",
                        fmt::format("{}: the run's {} its marker was mounted {} ([marker] "
                                    "mounting = \"{}\"), not {}",
                                    argument, start.plan.marker.mounting ? "plan says" : "markerd config said",
                                    markerd::sweep::mounting_text(*stated), markerd::sweep::to_string(*stated),
                                    markerd::sweep::mounting_text(mounting)));
    }
  }
  std::vector<const markerd::sweep::RunRecords*> together;
  for (const auto& run : marker.runs) together.push_back(&run);
  try {
    (void)markerd::sweep::summarize_together(together);
  } catch (const std::invalid_argument& e) {
    throw usage_error("report", fmt::format("{}: {}", option, e.what()));
  }
  return marker;
}

// Runs given as RUN_DIR... whose plans all say they measured the paper or
// the socket marker, both among them: the thesis's comparison, by what the
// records say. Anything else is reported run by run, as before.
std::optional<std::vector<markerd::sweep::MarkerRuns>> markers_by_records(
    const std::vector<markerd::sweep::RunRecords>& runs) {
  markerd::sweep::MarkerRuns paper{Mounting::paper, {}};
  markerd::sweep::MarkerRuns socket{Mounting::socket, {}};
  for (const auto& run : runs) {
    const auto mounting = run.start.marker_mounting();
    if (mounting == Mounting::paper) {
      paper.runs.push_back(run);
    } else if (mounting == Mounting::socket) {
      socket.runs.push_back(run);
    } else {
      return std::nullopt;
    }
  }
  if (paper.runs.empty() || socket.runs.empty()) return std::nullopt;
  return std::vector{std::move(paper), std::move(socket)};
}

void refuse_a_run_given_twice(const std::vector<std::pair<std::string, std::string>>& given) {
  for (std::size_t i = 0; i < given.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      std::error_code error;
      if (fs::equivalent(given[i].second, given[j].second, error)) {
        throw usage_error("report", fmt::format("{} {}: the same run as {} {}", given[i].first, given[i].second,
                                                given[j].first, given[j].second));
      }
    }
  }
}

int run_report(const ReportCommandOptions& o) {
  const bool by_option = !o.paper.empty() || !o.socket.empty();
  if (by_option && !o.runs.empty()) {
    throw usage_error("report", fmt::format("RUN_DIR {}: give the runs either as RUN_DIR... or with --paper and "
                                            "--socket, not both",
                                            o.runs.front()));
  }
  if (!by_option && o.runs.empty()) {
    throw usage_error("report", "no runs: give RUN_DIR..., or --paper RUN_DIR... and --socket RUN_DIR...");
  }
  const std::size_t run_count = o.runs.size() + o.paper.size() + o.socket.size();
  if (run_count > 1 && o.output.empty()) {
    throw usage_error("report", "-o OUT_DIR is required for several runs (their reports would go into each)");
  }

  std::vector<markerd::sweep::RunRecords> runs;
  std::optional<std::vector<markerd::sweep::MarkerRuns>> markers;
  if (by_option) {
    std::vector<std::pair<std::string, std::string>> given;
    for (const auto& directory : o.paper) given.emplace_back("--paper", directory);
    for (const auto& directory : o.socket) given.emplace_back("--socket", directory);
    markers.emplace();
    if (!o.paper.empty()) markers->push_back(read_marker_runs(o.paper, Mounting::paper, "--paper"));
    if (!o.socket.empty()) markers->push_back(read_marker_runs(o.socket, Mounting::socket, "--socket"));
    refuse_a_run_given_twice(given);
  } else {
    for (const auto& directory : o.runs) runs.push_back(read_run_directory(directory, directory));
    markers = markers_by_records(runs);
  }

  markerd::sweep::ReportOptions options;
  const std::string& first = !o.runs.empty() ? o.runs.front() : !o.paper.empty() ? o.paper.front() : o.socket.front();
  options.output_directory = o.output.empty() ? fs::path(first) / "report" : fs::path(o.output);
  options.plots = !o.no_plots;
  markerd::sweep::ReportFiles files;
  try {
    files = markers ? markerd::sweep::write_report_by_marker(*markers, options)
                    : markerd::sweep::write_report(runs, options);
  } catch (const std::invalid_argument& e) {
    // The runs of one marker's column, paired by what their plans say, do not go together.
    throw usage_error("report", fmt::format("RUN_DIR...: {}", e.what()));
  } catch (const std::exception& e) {
    throw runtime_error("report", e.what());
  }

  if (o.json) {
    // What was written, for scripts: the files, and Table 6.1 as report.md has it.
    nlohmann::ordered_json j;
    j["report"] = files.report.string();
    j["csv"] = nlohmann::ordered_json::array();
    for (const auto& csv : files.csv) j["csv"].push_back(csv.string());
    j["plots"] = nlohmann::ordered_json::array();
    for (const auto& plot : files.plots) j["plots"].push_back(plot.string());
    j["table_6_1"] = files.table_6_1;
    j["threshold_calls"] = files.threshold_calls;
    std::cout << json_line(j) << '\n';
    return 0;
  }
  // The path alone on the first line, for scripts; the table and how sure
  // its limits are for people.
  std::cout << files.report.string() << "\n\n" << files.table_6_1 << "\nThreshold calls:\n\n" << files.threshold_calls;
  return 0;
}

}  // namespace

void add_report_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<ReportCommandOptions>();
  CLI::App* app =
      parent.add_subcommand("report", "The report of a sweep run (or several side by side) from its records");
  app->footer(
      "Reads each RUN_DIR's records (start.json, points.jsonl, events.jsonl, stop.json) and writes into OUT_DIR:\n"
      "report.md (the run, the thesis's Table 6.1 and its threshold calls, every point, appendix C's translation\n"
      "vectors, the events), summary.csv (one line per point), translation.csv (one line per measurement) and,\n"
      "unless --no-plots, rate-vs-distance, pose-error-vs-distance, pose-error-vs-angle and rate-map, each as .svg\n"
      "and .pdf, drawn by gnuplot (gnuplot-nox) from the .gp and .dat files kept beside them. Rates carry their\n"
      "95% intervals, median errors theirs. Several runs: one column or curve per run, and per-run CSVs\n"
      "(summary-RUN_ID.csv, ...). A run still going (or cut off) reports what it has, as 'incomplete'.\n"
      "--paper RUN_DIR... --socket RUN_DIR...: the thesis's two markers compared, Table 6.1 with a column for each\n"
      "marker's runs together beside the thesis's; runs whose plans say [marker] mounting = \"paper\" or \"socket\",\n"
      "both among them, are compared so when given as RUN_DIR... too.\n"
      "Prints the path of report.md, then Table 6.1 and its threshold calls (--json: one JSON object, \"report\",\n"
      "\"csv\", \"plots\", \"table_6_1\" and \"threshold_calls\"). Exit status: 0 written, 1 a run that cannot be\n"
      "read or a report that cannot be written (gnuplot missing or failing), 2 bad usage.");
  app->add_option("run", o->runs, "A sweep run's directory, as markerd wrote it")->type_name("RUN_DIR");
  app->add_option("--paper", o->paper,
                  "The paper marker's runs (its distance run, its angle runs): Table 6.1's paper column")
      ->type_name("RUN_DIR");
  app->add_option("--socket", o->socket, "The socket marker's runs: Table 6.1's socket column")->type_name("RUN_DIR");
  app->add_option("-o,--output", o->output, "Where the report goes (default RUN_DIR/report; required for several runs)")
      ->type_name("OUT_DIR");
  app->add_flag("--no-plots", o->no_plots, "Tables and CSVs only (gnuplot not needed)");
  app->add_flag("--json", o->json, "One JSON object: the files written and Table 6.1");
  commands.push_back({app, [o] { return run_report(*o); }});
}

}  // namespace markerctl
