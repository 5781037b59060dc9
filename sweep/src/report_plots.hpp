#pragma once
// The report's plots (report.hpp): gnuplot scripts and their data written
// into the report's directory, each run by gnuplot once to draw the plot as
// SVG (for the Markdown report and browsers) and as PDF (for LaTeX), from
// the same script so the two never differ.

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/sweep/report.hpp"
#include "markerd/sweep/summary.hpp"

namespace markerd::sweep::plots {

// One plot's name (without extension: NAME.gp draws NAME.svg and NAME.pdf)
// and what report.md calls it.
struct PlotName {
  const char* name;
  const char* caption;
};

// The plots, in the order report.md shows them.
[[nodiscard]] const std::vector<PlotName>& plot_names();

// The rate map draws a heat map for a run that sweeps angle at more than
// this many distances, curves of rate against angle otherwise.
inline constexpr std::size_t kMostAngleCurves = 4;

// Writes `text` to `path`, replacing it; std::runtime_error naming the path.
void write_report_file(const std::filesystem::path& path, std::string_view text);

// Writes every plot's script and data and runs gnuplot on each; returns the
// SVG and PDF files, two a plot. std::runtime_error naming what failed.
std::vector<std::filesystem::path> draw_all(const std::vector<RunSummary>& runs, const ReportOptions& options);

}  // namespace markerd::sweep::plots
