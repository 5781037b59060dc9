#include "markerd/sweep/report.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <optional>
#include <set>
#include <stdexcept>
#include <system_error>
#include <utility>
#include <vector>

#include "markerd/base/utc_time.hpp"
#include "markerd/detector/family.hpp"
#include "report_plots.hpp"

namespace markerd::sweep {

namespace fs = std::filesystem;

namespace {

constexpr std::string_view kNone = "—";

using plots::write_report_file;

double norm(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

// ---------------------------------------------------------------------------
// report.md

std::string time_text(std::chrono::system_clock::time_point time) {
  if (time == std::chrono::system_clock::time_point{}) return std::string(kNone);
  return format_utc(time, UtcForm::readable);
}

std::string cell(std::string_view text) {
  std::string escaped;
  for (const char c : text) {
    if (c == '|') escaped += '\\';
    escaped += (c == '\n') ? ' ' : c;
  }
  return escaped;
}

std::string vector_text(const std::array<double, 3>& v) {
  return fmt::format("[{:.4f}, {:.4f}, {:.4f}]", v[0], v[1], v[2]);
}

std::string cm_text(double metres) {
  const double cm = metres * 100;
  return std::abs(cm - std::round(cm)) < 0.05 ? fmt::format("{:.0f} cm", cm) : fmt::format("{:.1f} cm", cm);
}

std::string angle_text(double degrees) {
  return std::abs(degrees - std::round(degrees)) < 0.005 ? fmt::format("{:.0f}", degrees)
                                                         : fmt::format("{:.2f}", degrees);
}

std::string marker_text(const PlanMarker& marker) {
  const double mm = marker.size_m * 1000;
  const bool whole = std::abs(mm - std::round(mm)) < 0.05;
  return fmt::format("{} #{}, {:.{}f} mm{}", detector::family_info(marker.family).name, marker.id, mm, whole ? 0 : 1,
                     marker.mounting ? fmt::format(", {}", mounting_text(*marker.mounting)) : std::string());
}

std::string status_text(const RunRecords& run) {
  if (!run.stop) return "incomplete (no stop record: the run goes on, or was cut off)";
  std::string text(to_string(run.stop->status));
  if (!run.stop->reason.empty()) text += ": " + run.stop->reason;
  return text;
}

// `columns`: empty, or the Table 6.1 column each run is in.
std::string runs_table(const std::vector<const RunRecords*>& runs, const std::vector<RunSummary>& summaries,
                       const std::vector<std::string>& columns) {
  std::string header = "| |";
  std::string rule = "| --- |";
  for (const auto& s : summaries) {
    header += fmt::format(" {} |", cell(s.run_id));
    rule += " --- |";
  }
  std::vector<std::pair<std::string, std::vector<std::string>>> rows = {
      {"Plan", {}},         {"Marker", {}}, {"Status", {}},        {"Started", {}}, {"Stopped", {}},
      {"Measurements", {}}, {"Frames", {}}, {"Detected when", {}}, {"Software", {}}};
  bool any_torn = false;
  if (!columns.empty()) rows.emplace_back("Table 6.1 column", columns);
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const auto& run = *runs[r];
    const auto& s = summaries[r];
    int frames = 0;
    int corrupt = 0;
    for (const auto& p : s.points) {
      frames += p.frames;
      corrupt += p.frames_corrupt;
    }
    rows[0].second.push_back(s.plan_name.empty() ? std::string(kNone) : s.plan_name);
    rows[1].second.push_back(marker_text(s.marker));
    rows[2].second.push_back(status_text(run));
    rows[3].second.push_back(time_text(run.start.time));
    rows[4].second.push_back(run.stop ? time_text(run.stop->time) : std::string(kNone));
    // A start document without the plan's step count says nothing about the whole.
    rows[5].second.push_back(
        run.start.steps > 0 ? fmt::format("{} of {} ({} points)", run.points.size(), run.start.steps, s.points.size())
                            : fmt::format("{} ({} points)", run.points.size(), s.points.size()));
    rows[6].second.push_back(corrupt > 0 ? fmt::format("{} ({} corrupt, not counted)", frames, corrupt)
                                         : fmt::format("{}", frames));
    rows[7].second.push_back(fmt::format("rate ≥ {:.4g} %", 100 * s.detection_threshold));
    rows[8].second.push_back(run.start.software_version.empty()
                                 ? std::string(kNone)
                                 : fmt::format("markerd {}{}", run.start.software_version,
                                               run.start.hostname.empty() ? "" : " on " + run.start.hostname));
    any_torn = any_torn || run.torn_lines > 0;
  }
  if (any_torn) {
    rows.emplace_back("Torn lines", std::vector<std::string>{});
    for (const auto* run : runs) {
      rows.back().second.push_back(
          run->torn_lines > 0 ? fmt::format("{} (a partial last line, ignored)", run->torn_lines) : "0");
    }
  }
  std::string table = header + '\n' + rule + '\n';
  for (const auto& [name, cells] : rows) {
    table += "| " + name + " |";
    for (const auto& c : cells) table += ' ' + cell(c) + " |";
    table += '\n';
  }
  return table;
}

// A median over a point's frames and its 95% interval, "0.12 [0.10, 0.15]".
std::string median_text(const std::optional<MedianEstimate>& m, int decimals) {
  if (!m) return std::string(kNone);
  if (!m->low || !m->high) return fmt::format("{:.{}f}", m->median, decimals);
  return fmt::format("{:.{}f} [{:.{}f}, {:.{}f}]", m->median, decimals, *m->low, decimals, *m->high, decimals);
}

std::string detected_text(const PointSummary& p) {
  const char* reached = p.reached ? "yes" : "no";
  if (p.call != RateCall::uncertain) return reached;
  if (!p.frames_to_decide) return fmt::format("{}, in doubt (on the threshold)", reached);
  return fmt::format("{}, in doubt ({} frames would tell)", reached, *p.frames_to_decide);
}

std::string points_table(const RunSummary& s) {
  if (s.points.empty()) return "No measurement recorded.\n";
  std::string table =
      "| Grid | Distance (m) | Angle (°) | Frames | Rate [95% interval] | Detected | Mean tvec (m) | \\|Distance "
      "error\\| (%) | Translation error (mm) | Rotation error (°) | Jitter of the distance (mm) |\n"
      "| --- | ---: | ---: | ---: | ---: | :---: | --- | ---: | ---: | ---: | ---: |\n";
  for (const auto& p : s.points) {
    const std::string tvec =
        p.tvec_m[0].n > 0 ? vector_text({p.tvec_m[0].mean, p.tvec_m[1].mean, p.tvec_m[2].mean}) : std::string(kNone);
    const std::string jitter =
        p.distance_m_estimated.n > 1 ? fmt::format("{:.2f}", 1000 * p.distance_m_estimated.stddev) : std::string(kNone);
    table +=
        fmt::format("| {} | {:.3f} | {} | {} | {:.1f} % [{:.1f}, {:.1f}] | {} | {} | {} | {} | {} | {} |\n",
                    cell(p.grid_name.empty() ? fmt::format("{}", p.grid) : p.grid_name), p.distance_m,
                    angle_text(p.angle_deg), p.frames, 100 * p.rate, 100 * p.rate_interval.low,
                    100 * p.rate_interval.high, detected_text(p), tvec, median_text(p.median_distance_error_pct, 2),
                    median_text(p.median_translation_error_mm, 2), median_text(p.median_rotation_error_deg, 2), jitter);
  }
  table += fmt::format(
      "\nRate: frames that found the marker, with its 95% interval (Wilson). Detected: rate at or above {:.4g} %; "
      "in doubt when the interval holds the threshold, with the frames a point at that rate would need for it not "
      "to. Mean tvec: over the frames with a pose. Errors: the median over the frames with a pose and ground "
      "truth, with the median's 95% interval (from the order statistics; none under 6 frames); the distance "
      "error as |(|t| − |t_true|)| of the true distance. This is the accuracy at the point. Jitter: the standard "
      "deviation of the estimated distance |t| over the point's frames, of one scene that does not move: how "
      "well a measurement repeats, not how far it is from the truth.\n",
      100 * s.detection_threshold);
  return table;
}

// As the thesis's appendix C: the facing points (its distance sweep), each
// measurement's mean translation vector, then the mean of those vectors and
// its norm. The mean of the measurements, as the thesis took it, not of all
// frames: the two differ when a measurement lost frames.
std::string appendix_c_table(const RunSummary& s) {
  const auto facing = facing_by_distance(s);
  if (facing.empty()) return "No facing points (|angle| < 0.5°) in this run.\n";
  std::string table =
      "| Measurement | Stepper motor steps | Distance | Translation vector (m) |\n| :---: | :---: | :---: | :---: |\n";
  for (const auto* p : facing) {
    std::array<double, 3> sum{};
    int with_pose = 0;
    for (const auto& m : p->measurements) {
      const std::string steps = m.rail_steps ? fmt::format("{}", *m.rail_steps) : std::string(kNone);
      const std::string vector = m.mean_tvec_m ? vector_text(*m.mean_tvec_m) : "no pose";
      table += fmt::format("| {} | {} | {} | {} |\n", m.repeat + 1, steps, cm_text(p->distance_m), vector);
      if (!m.mean_tvec_m) continue;
      for (std::size_t i = 0; i < 3; ++i) sum[i] += (*m.mean_tvec_m)[i];
      ++with_pose;
    }
    if (with_pose == 0) {
      table += fmt::format("| Mean translation vector | | | {} |\n| Norm | | | {} |\n", kNone, kNone);
      continue;
    }
    for (auto& v : sum) v /= with_pose;
    table += fmt::format("| Mean translation vector | | | {} |\n| Norm | | | {:.4f} |\n", vector_text(sum), norm(sum));
  }
  return table;
}

std::string events_table(const RunRecords& run) {
  if (run.events.empty()) return "No events recorded.\n";
  std::size_t suspensions = 0;
  for (const auto& e : run.events) suspensions += e.kind == "suspended" ? 1 : 0;
  std::string text = suspensions == 0
                         ? std::string("No suspensions.\n\n")
                         : fmt::format("{} suspension{}; causes below.\n\n", suspensions, suspensions == 1 ? "" : "s");
  text += "| Time | Event | Step | Cause |\n| --- | --- | ---: | --- |\n";
  for (const auto& e : run.events) {
    text += fmt::format("| {} | {} | {} | {} |\n", time_text(e.time), cell(e.kind), e.step,
                        e.reason.empty() ? std::string(kNone) : cell(e.reason));
  }
  return text;
}

// A file name from a run id: anything but letters, digits, '.', '-' and '_'
// becomes '_', and a second run of the same id gets a number.
std::string file_stem(const std::string& run_id, std::set<std::string>& taken) {
  std::string stem;
  for (const char c : run_id) {
    const bool plain =
        (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '-' || c == '_';
    stem += plain ? c : '_';
  }
  if (stem.empty() || stem.front() == '.') stem = "run" + stem;
  std::string unique = stem;
  for (int n = 2; !taken.insert(unique).second; ++n) unique = fmt::format("{}-{}", stem, n);
  return unique;
}

}  // namespace

namespace {

// The report of `runs` (their summaries beside them) around `table` as its
// Table 6.1, `calls` as the threshold calls behind its limits: one column or
// curve per run everywhere else. `columns`: empty, or the Table 6.1 column
// each run is in; `preface`: what precedes the runs' table.
ReportFiles write_runs_report(const std::vector<const RunRecords*>& runs, const std::vector<RunSummary>& summaries,
                              std::string table, std::string calls, const std::vector<std::string>& columns,
                              const std::string& preface, const ReportOptions& options) {
  std::error_code error;
  fs::create_directories(options.output_directory, error);
  if (error) {
    throw std::runtime_error(
        fmt::format("{}: cannot create the report directory: {}", options.output_directory.string(), error.message()));
  }

  ReportFiles files;
  std::vector<std::pair<std::string, std::string>> csv_names;  // summary, translation per run
  std::set<std::string> taken;
  for (const auto& s : summaries) {
    if (summaries.size() == 1) {
      csv_names.emplace_back("summary.csv", "translation.csv");
    } else {
      const std::string stem = file_stem(s.run_id, taken);
      csv_names.emplace_back("summary-" + stem + ".csv", "translation-" + stem + ".csv");
    }
  }
  for (std::size_t r = 0; r < summaries.size(); ++r) {
    write_report_file(options.output_directory / csv_names[r].first, points_csv(summaries[r]));
    write_report_file(options.output_directory / csv_names[r].second, translation_csv(summaries[r]));
    files.csv.push_back(options.output_directory / csv_names[r].first);
    files.csv.push_back(options.output_directory / csv_names[r].second);
  }

  if (options.plots) files.plots = plots::draw_all(summaries, options);

  std::string ids;
  for (const auto& s : summaries) ids += (ids.empty() ? "" : ", ") + s.run_id;
  const bool side_by_side = summaries.size() > 1;
  std::string md = fmt::format("# Sweep report: {}\n\n", ids);
  md += preface;
  md += runs_table(runs, summaries, columns);
  md += "\n## Table 6.1\n\n" + table;
  md += "\n## Threshold calls\n\n" + calls;

  if (options.plots) {
    md += "\n## Plots\n\n";
    std::string pdfs;
    for (const auto& plot : plots::plot_names()) {
      md += fmt::format("![{}]({}.svg)\n\n", plot.caption, plot.name);
      pdfs += fmt::format("{}`{}.pdf`", pdfs.empty() ? "" : ", ", plot.name);
    }
    md += fmt::format(
        "Error bars: 95% intervals, Wilson's for the rates, the order statistics' for the median errors (whose "
        "bars cover the jitter of a point's frames, not a bias they share). Dotted lines: the thesis's limits for "
        "the marker measured (its maximum distance, its maximum angle at each distance it measured); dashed: the "
        "detection threshold. Each plot is drawn by gnuplot from the `.gp` script and `.dat` files beside it "
        "(`gnuplot NAME.gp` in this directory draws it again), as SVG for this page and as PDF for a paper "
        "({}). The rate over distance and angle is drawn as curves of rate against angle, one per distance swept "
        "over angle, or as a heat map for a run that sweeps angle at more than {} distances.\n",
        pdfs, plots::kMostAngleCurves);
  }

  for (std::size_t r = 0; r < summaries.size(); ++r) {
    const std::string suffix = side_by_side ? ": " + summaries[r].run_id : "";
    md += fmt::format("\n## Points{}\n\n", suffix) + points_table(summaries[r]);
    md += fmt::format("\n## Appendix C: translation vectors{}\n\n", suffix) + appendix_c_table(summaries[r]);
    md += fmt::format("\n## Events{}\n\n", suffix) + events_table(*runs[r]);
  }

  md += "\n## Files\n\n";
  for (std::size_t r = 0; r < summaries.size(); ++r) {
    md += fmt::format("- `{}`: one line per point{}; `{}`: one line per measurement (appendix C)\n", csv_names[r].first,
                      side_by_side ? " of " + summaries[r].run_id : "", csv_names[r].second);
  }

  files.report = options.output_directory / "report.md";
  write_report_file(files.report, md);
  files.table_6_1 = std::move(table);
  files.threshold_calls = std::move(calls);
  return files;
}

}  // namespace

ReportFiles write_report(const std::vector<RunRecords>& runs, const ReportOptions& options) {
  if (runs.empty()) throw std::invalid_argument("write_report: no runs");
  std::vector<const RunRecords*> pointers;
  std::vector<RunSummary> summaries;
  for (const auto& run : runs) {
    pointers.push_back(&run);
    summaries.push_back(summarize(run));
  }
  const std::string preface = runs.size() > 1 ? "Runs side by side, one column or curve each.\n\n" : "";
  std::vector<const RunSummary*> called;
  for (const auto& s : summaries) called.push_back(&s);
  return write_runs_report(pointers, summaries, table_6_1(summaries), threshold_calls(called), {}, preface, options);
}

ReportFiles write_report_by_marker(const std::vector<MarkerRuns>& markers, const ReportOptions& options) {
  if (markers.empty()) throw std::invalid_argument("write_report_by_marker: no markers");
  std::vector<const RunRecords*> pointers;
  std::vector<RunSummary> summaries;
  std::vector<std::string> columns;
  std::vector<MarkerColumn> table_columns;
  std::string preface;
  for (const auto& marker : markers) {
    if (marker.runs.empty()) {
      throw std::invalid_argument(fmt::format("no runs of the marker {}", mounting_text(marker.mounting)));
    }
    std::vector<const RunRecords*> of_marker;
    for (const auto& run : marker.runs) {
      of_marker.push_back(&run);
      pointers.push_back(&run);
      summaries.push_back(summarize(run));
      columns.emplace_back(fmt::format("marker {}", mounting_text(marker.mounting)));
    }
    table_columns.push_back(MarkerColumn{marker.mounting, summarize_together(of_marker)});
    preface += fmt::format("{} of the marker {}: {}", preface.empty() ? "Runs" : "; runs",
                           mounting_text(marker.mounting), table_columns.back().runs.run_id);
  }
  preface +=
      ".\n\nTable 6.1 has a column for each marker's runs taken together, beside the thesis's column for that "
      "marker; the other tables and the plots have one column or curve per run.\n\n";
  std::vector<const RunSummary*> called;
  for (const auto& column : table_columns) called.push_back(&column.runs);
  return write_runs_report(pointers, summaries, table_6_1_by_marker(table_columns), threshold_calls(called), columns,
                           preface, options);
}

}  // namespace markerd::sweep
