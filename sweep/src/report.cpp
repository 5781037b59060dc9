#include "markerd/sweep/report.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <set>
#include <stdexcept>
#include <system_error>
#include <utility>
#include <vector>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/base/utc_time.hpp"
#include "markerd/detector/family.hpp"

extern char** environ;

namespace markerd::sweep {

namespace fs = std::filesystem;

namespace {

constexpr const char* kRateVsDistance = "rate-vs-distance";
constexpr const char* kPoseErrorVsDistance = "pose-error-vs-distance";
constexpr const char* kRateMap = "rate-map";
constexpr std::string_view kNone = "—";

// Colours that stay apart in print and for the colour-blind; a run keeps its
// colour in every plot.
constexpr std::array<const char*, 6> kRunColours = {"#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9"};

const char* run_colour(std::size_t run) { return kRunColours[run % kRunColours.size()]; }

void write_text(const fs::path& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (out) out.close();
  if (!out) throw std::runtime_error(fmt::format("{}: cannot write: {}", path.string(), errno_text(errno)));
}

double norm(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

std::string trimmed(std::string text) {
  while (!text.empty() && (text.back() == '\n' || text.back() == ' ' || text.back() == '\r')) text.pop_back();
  return text;
}

// ---------------------------------------------------------------------------
// gnuplot

// Runs `program script` in `directory`, where the script and its data files
// are, so the script names them relatively and a user can re-run it there.
// posix_spawn rather than system(): no shell to quote a path for, and the
// program's own exit status and stderr come back unaltered.
void run_gnuplot(const std::string& program, const fs::path& directory, const std::string& script) {
  // A relative program path would be looked up from the new working directory.
  const std::string executable = program.find('/') == std::string::npos ? program : fs::absolute(program).string();
  int stderr_pipe[2];
  if (::pipe2(stderr_pipe, O_CLOEXEC) != 0) {
    throw std::runtime_error(fmt::format("gnuplot: cannot make a pipe: {}", errno_text(errno)));
  }
  UniqueFd read_end(stderr_pipe[0]);
  UniqueFd write_end(stderr_pipe[1]);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, write_end.get(), STDERR_FILENO);
  posix_spawn_file_actions_addchdir_np(&actions, directory.c_str());
  std::string script_argument = script;
  std::vector<char*> argv = {const_cast<char*>(executable.c_str()), script_argument.data(), nullptr};
  pid_t pid = 0;
  const int spawn_error = ::posix_spawnp(&pid, executable.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  write_end.reset();  // gnuplot's copy is the only writer left: its end is our end of file
  if (spawn_error != 0) {
    throw std::runtime_error(fmt::format("gnuplot: cannot run '{}': {} (install gnuplot-nox, or leave the plots out)",
                                         program, errno_text(spawn_error)));
  }
  std::string messages;
  char buffer[4096];
  for (;;) {
    const ssize_t n = ::read(read_end.get(), buffer, sizeof buffer);
    if (n > 0) {
      messages.append(buffer, static_cast<std::size_t>(n));
    } else if (n == 0 || errno != EINTR) {
      break;
    }
  }
  read_end.reset();
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) {
      throw std::runtime_error(fmt::format("gnuplot: waiting for '{}': {}", program, errno_text(errno)));
    }
  }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return;
  const std::string how = WIFEXITED(status) ? fmt::format("exit status {}", WEXITSTATUS(status))
                                            : fmt::format("killed by signal {}", WTERMSIG(status));
  messages = trimmed(std::move(messages));
  // The end of a long complaint holds the line that failed.
  constexpr std::size_t kKeep = 2000;
  if (messages.size() > kKeep) messages = "..." + messages.substr(messages.size() - kKeep);
  throw std::runtime_error(fmt::format("gnuplot '{}' failed on {}: {}{}{}", program, (directory / script).string(), how,
                                       messages.empty() ? "" : ": ", messages));
}

// A gnuplot string literal: single quotes take everything but a single quote,
// which doubles.
std::string gp_string(std::string_view text) {
  std::string quoted = "'";
  for (const char c : text) {
    if (c == '\'') quoted += '\'';
    quoted += c;
  }
  return quoted + "'";
}

std::string gp_preamble(const std::string& name, int width, int height) {
  return fmt::format(
      "# Drawn by markerd's sweep report from the .dat files beside it; to draw it again:\n"
      "#   gnuplot {0}.gp   (in this directory)\n"
      "set encoding utf8\n"
      // noenhanced: run ids and grid names keep their underscores.
      "set terminal svg size {1},{2} dynamic noenhanced font 'sans,12' background '#ffffff'\n"
      "set output '{0}.svg'\n"
      "set grid\n",
      name, width, height);
}

// What a panel with nothing to draw shows instead of failing: gnuplot
// refuses an empty plot command and cannot autoscale over no data.
std::string gp_empty_panel(std::string_view why) {
  return fmt::format(
      "set xrange [0:1]\nset yrange [0:1]\nset label 1 {} at graph 0.5,0.5 center\nplot NaN notitle\nunset label 1\n",
      gp_string(why));
}

struct Range {
  double low = 0;
  double high = 0;
  bool empty = true;
  void add(double value) {
    low = empty ? value : std::min(low, value);
    high = empty ? value : std::max(high, value);
    empty = false;
  }
  // Room around the points so the first and last are not on the frame.
  [[nodiscard]] std::string gp(double margin_fraction, double minimum_margin) const {
    const double margin = std::max((high - low) * margin_fraction, minimum_margin);
    return fmt::format("[{:.6g}:{:.6g}]", low - margin, high + margin);
  }
};

std::vector<const PointSummary*> facing_by_distance(const RunSummary& run) {
  std::vector<const PointSummary*> facing;
  for (const auto& p : run.points) {
    if (is_facing(p)) facing.push_back(&p);
  }
  std::stable_sort(facing.begin(), facing.end(),
                   [](const PointSummary* a, const PointSummary* b) { return a->distance_m < b->distance_m; });
  return facing;
}

std::string threshold_lines(const std::vector<RunSummary>& runs) {
  std::set<double> thresholds;
  for (const auto& run : runs) thresholds.insert(run.detection_threshold);
  std::string plots;
  for (const double t : thresholds) {
    plots += fmt::format(", \\\n     {:.6g} with lines dt 2 lw 1.5 lc rgb '#555555' title 'threshold {:.4g} %'",
                         100 * t, 100 * t);
  }
  return plots;
}

struct PlotFile {
  std::string name;  // without extension: NAME.gp draws NAME.svg
  std::string script;
  std::vector<std::pair<std::string, std::string>> data;  // file name, contents
};

PlotFile rate_vs_distance_plot(const std::vector<RunSummary>& runs) {
  PlotFile plot{kRateVsDistance, gp_preamble(kRateVsDistance, 800, 500), {}};
  std::string curves;
  Range distances;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const auto facing = facing_by_distance(runs[r]);
    if (facing.empty()) continue;
    std::string data = fmt::format("# {}: facing points\n# distance_m rate_pct frames detected\n", runs[r].run_id);
    for (const auto* p : facing) {
      data += fmt::format("{:.4f} {:.3f} {} {}\n", p->distance_m, 100 * p->rate, p->frames, p->detected);
      distances.add(p->distance_m);
    }
    const std::string file = fmt::format("{}-{}.dat", kRateVsDistance, r + 1);
    plot.data.emplace_back(file, data);
    curves +=
        fmt::format("{}{} using 1:2 with linespoints lw 2 pt 7 ps 0.8 lc rgb '{}' title {}",
                    curves.empty() ? "" : ", \\\n     ", gp_string(file), run_colour(r), gp_string(runs[r].run_id));
  }
  plot.script +=
      "set title 'Detection rate of the facing points (|angle| < 0.5°) against distance'\n"
      "set xlabel 'distance (m)'\nset ylabel 'detection rate (%)'\nset key bottom left opaque box\n";
  if (curves.empty()) {
    plot.script += gp_empty_panel("no facing points in the run");
    return plot;
  }
  plot.script += fmt::format("set xrange {}\nset yrange [0:105]\nplot {}{}\n", distances.gp(0.05, 0.02), curves,
                             threshold_lines(runs));
  return plot;
}

PlotFile pose_error_plot(const std::vector<RunSummary>& runs) {
  PlotFile plot{kPoseErrorVsDistance, gp_preamble(kPoseErrorVsDistance, 800, 700), {}};
  std::string distance_curves;
  std::string translation_curves;
  Range distances;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    std::string data = fmt::format(
        "# {}: facing points with a pose error, medians over their frames\n"
        "# distance_m median_abs_distance_error_pct median_translation_error_mm\n",
        runs[r].run_id);
    bool any = false;
    for (const auto* p : facing_by_distance(runs[r])) {
      if (!p->median_distance_error_pct || !p->median_translation_error_mm) continue;
      data += fmt::format("{:.4f} {:.4f} {:.3f}\n", p->distance_m, *p->median_distance_error_pct,
                          *p->median_translation_error_mm);
      distances.add(p->distance_m);
      any = true;
    }
    if (!any) continue;
    const std::string file = fmt::format("{}-{}.dat", kPoseErrorVsDistance, r + 1);
    plot.data.emplace_back(file, data);
    const std::string style =
        fmt::format("with linespoints lw 2 pt 7 ps 0.8 lc rgb '{}' title {}", run_colour(r), gp_string(runs[r].run_id));
    distance_curves +=
        fmt::format("{}{} using 1:2 {}", distance_curves.empty() ? "" : ", \\\n     ", gp_string(file), style);
    translation_curves +=
        fmt::format("{}{} using 1:3 {}", translation_curves.empty() ? "" : ", \\\n     ", gp_string(file), style);
  }
  // Two panels over one distance axis: percent and millimetres would fight
  // over a shared y axis, and a second y axis is easy to misread.
  plot.script +=
      "set multiplot layout 2,1 title 'Pose error of the facing points against distance (medians over each point''s "
      "frames)'\n"
      "set key top left opaque box\nset xlabel 'distance (m)'\n";
  if (distance_curves.empty()) {
    plot.script += gp_empty_panel("no pose errors (no pose, or no ground truth)");
    plot.script += gp_empty_panel("no pose errors (no pose, or no ground truth)");
  } else {
    const std::string x_range = distances.gp(0.05, 0.02);
    plot.script += fmt::format(
        "set xrange {0}\nset yrange [0:*]\nset offsets 0, 0, graph 0.08, 0\nset ylabel '|distance error| (% of the "
        "true distance)'\nplot {1}\n"
        "set ylabel 'translation error (mm)'\nplot {2}\n",
        x_range, distance_curves, translation_curves);
  }
  plot.script += "unset multiplot\n";
  return plot;
}

// The rate map chooses per run. A plan shaped like the thesis's sweeps
// distance at 0° and angle at one or two distances: as a heat map that is a
// row and a column or two of cells in an empty field, and the shape of the
// fall-off is hard to read from colours; as curves of rate against angle,
// one per distance, it reads at a glance and the threshold can be drawn.
// Past a handful of distances swept over angle the curves tangle, and the
// points fill distance x angle well enough for a heat map to read better.
constexpr std::size_t kMostAngleCurves = 4;

bool fills_a_heat_map(const RunSummary& run) { return run.max_angle.size() > kMostAngleCurves; }

// Half the smallest gap between distinct values: the half-width of a cell.
double half_cell(std::vector<double> values, double fallback) {
  std::sort(values.begin(), values.end());
  double smallest = 0;
  for (std::size_t i = 1; i < values.size(); ++i) {
    const double gap = values[i] - values[i - 1];
    if (gap > 1e-9 && (smallest == 0 || gap < smallest)) smallest = gap;
  }
  return smallest > 0 ? smallest / 2 : fallback;
}

std::string heat_map_panel(const RunSummary& run, std::size_t index, PlotFile& plot) {
  std::string data = fmt::format("# {}: every point\n# distance_m angle_deg rate_pct\n", run.run_id);
  std::vector<double> distances;
  std::vector<double> angles;
  for (const auto& p : run.points) {
    data += fmt::format("{:.4f} {:.3f} {:.3f}\n", p.distance_m, p.angle_deg, 100 * p.rate);
    distances.push_back(p.distance_m);
    angles.push_back(p.angle_deg);
  }
  const std::string file = fmt::format("{}-{}.dat", kRateMap, index + 1);
  plot.data.emplace_back(file, data);
  // Boxes centred on the points rather than `with image`, which needs a
  // complete regular grid; a plan's blocks need not form one.
  const double dx = half_cell(distances, 0.025);
  const double dy = half_cell(angles, 2.5);
  return fmt::format(
      "set title {}\nset xlabel 'distance (m)'\nset ylabel 'viewing angle (°)'\n"
      "set xrange [*:*]\nset yrange [*:*]\nunset key\nset colorbox\nset cblabel 'detection rate (%)'\n"
      "plot {} using 1:2:({:.6g}):({:.6g}):3 with boxxyerror fs solid 1.0 noborder lc palette notitle\n",
      gp_string(run.run_id + ": detection rate over distance and angle"), gp_string(file), dx, dy);
}

std::string angle_curves_panel(const RunSummary& run, std::size_t index, PlotFile& plot) {
  std::vector<const PointSummary*> swept;
  for (const auto& entry : run.max_angle) {
    std::vector<const PointSummary*> at_distance;
    for (const auto& p : run.points) {
      if (std::abs(p.distance_m - entry.distance_m) <= 0.0005) at_distance.push_back(&p);
    }
    std::stable_sort(at_distance.begin(), at_distance.end(),
                     [](const PointSummary* a, const PointSummary* b) { return a->angle_deg < b->angle_deg; });
    swept.insert(swept.end(), at_distance.begin(), at_distance.end());
    swept.push_back(nullptr);  // the end of one distance's block
  }
  const std::string title = run.run_id + ": detection rate against viewing angle, one curve per distance";
  if (swept.empty())
    return fmt::format("set title {}\n", gp_string(title)) + gp_empty_panel("no angle sweep in the run");

  const std::string file = fmt::format("{}-{}.dat", kRateMap, index + 1);
  std::string data = fmt::format(
      "# {}: one block per distance swept over angle (gnuplot's index)\n# angle_deg rate_pct distance_m\n", run.run_id);
  std::string curves;
  Range angles;
  std::size_t block = 0;
  const PointSummary* block_first = nullptr;
  for (const auto* p : swept) {
    if (p == nullptr) {
      data += "\n\n";
      curves += fmt::format("{}{} index {} using 1:2 with linespoints lw 2 pt 7 ps 0.8 lc {} title {}",
                            curves.empty() ? "" : ", \\\n     ", gp_string(file), block, block + 1,
                            gp_string(fmt::format("{:.3f} m", block_first->distance_m)));
      ++block;
      block_first = nullptr;
      continue;
    }
    if (block_first == nullptr) block_first = p;
    data += fmt::format("{:.3f} {:.3f} {:.4f}\n", p->angle_deg, 100 * p->rate, p->distance_m);
    angles.add(p->angle_deg);
  }
  plot.data.emplace_back(file, data);
  return fmt::format(
      "set title {}\nset xlabel 'viewing angle (°)'\nset ylabel 'detection rate (%)'\n"
      "set xrange {}\nset yrange [0:105]\nunset colorbox\nset key outside right top box\n"
      "plot {}, \\\n     {:.6g} with lines dt 2 lw 1.5 lc rgb '#555555' title 'threshold {:.4g} %'\n",
      gp_string(title), angles.gp(0.05, 2), curves, 100 * run.detection_threshold, 100 * run.detection_threshold);
}

PlotFile rate_map_plot(const std::vector<RunSummary>& runs) {
  const int panels = static_cast<int>(std::max<std::size_t>(runs.size(), 1));
  PlotFile plot{kRateMap, gp_preamble(kRateMap, 800, 450 * panels), {}};
  plot.script +=
      "set cbrange [0:100]\n"
      // Viridis: ordered in lightness, so it reads in grey and for the colour-blind.
      "set palette defined (0 '#440154', 25 '#3b528b', 50 '#21918c', 75 '#5ec962', 100 '#fde725')\n";
  plot.script += fmt::format("set multiplot layout {},1\n", panels);
  if (runs.empty()) plot.script += gp_empty_panel("no runs");
  for (std::size_t r = 0; r < runs.size(); ++r) {
    plot.script += fills_a_heat_map(runs[r]) ? heat_map_panel(runs[r], r, plot) : angle_curves_panel(runs[r], r, plot);
  }
  plot.script += "unset multiplot\n";
  return plot;
}

fs::path draw(const PlotFile& plot, const ReportOptions& options) {
  for (const auto& [file, contents] : plot.data) write_text(options.output_directory / file, contents);
  const std::string script = plot.name + ".gp";
  write_text(options.output_directory / script, plot.script);
  const fs::path svg = options.output_directory / (plot.name + ".svg");
  // An earlier report's plot must not pass for this one's.
  std::error_code ignored;
  fs::remove(svg, ignored);
  run_gnuplot(options.gnuplot, options.output_directory, script);
  if (!fs::exists(svg)) {
    throw std::runtime_error(fmt::format("gnuplot '{}' wrote no {}", options.gnuplot, svg.string()));
  }
  return svg;
}

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

std::string spread_text(const Spread& s, int decimals) {
  if (s.n == 0) return std::string(kNone);
  if (s.n == 1) return fmt::format("{:.{}f}", s.mean, decimals);
  return fmt::format("{:.{}f} ± {:.{}f}", s.mean, decimals, s.stddev, decimals);
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

std::string points_table(const RunSummary& s) {
  if (s.points.empty()) return "No measurement recorded.\n";
  std::string table =
      "| Grid | Distance (m) | Angle (°) | Frames | Rate | Detected | Mean tvec (m) | Distance error (%) | Rotation "
      "error (°) |\n| --- | ---: | ---: | ---: | ---: | :---: | --- | ---: | ---: |\n";
  for (const auto& p : s.points) {
    const std::string tvec =
        p.tvec_m[0].n > 0 ? vector_text({p.tvec_m[0].mean, p.tvec_m[1].mean, p.tvec_m[2].mean}) : std::string(kNone);
    table += fmt::format("| {} | {:.3f} | {} | {} | {:.1f} % | {} | {} | {} | {} |\n",
                         cell(p.grid_name.empty() ? fmt::format("{}", p.grid) : p.grid_name), p.distance_m,
                         angle_text(p.angle_deg), p.frames, 100 * p.rate, p.reached ? "yes" : "no", tvec,
                         spread_text(p.distance_error_pct, 2), spread_text(p.rotation_error_deg, 2));
  }
  table +=
      "\nRate: frames that found the marker; Detected: rate at or above the threshold. Mean tvec: over the frames "
      "with a pose. Errors: mean ± sample standard deviation over the frames with a pose and ground truth; the "
      "distance error is signed (|t| − |t_true|), of the true distance.\n";
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
// Table 6.1: one column or curve per run everywhere else. `columns`: empty,
// or the Table 6.1 column each run is in; `preface`: what precedes the runs'
// table.
ReportFiles write_runs_report(const std::vector<const RunRecords*>& runs, const std::vector<RunSummary>& summaries,
                              std::string table, const std::vector<std::string>& columns, const std::string& preface,
                              const ReportOptions& options) {
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
    write_text(options.output_directory / csv_names[r].first, points_csv(summaries[r]));
    write_text(options.output_directory / csv_names[r].second, translation_csv(summaries[r]));
    files.csv.push_back(options.output_directory / csv_names[r].first);
    files.csv.push_back(options.output_directory / csv_names[r].second);
  }

  if (options.plots) {
    for (const auto& plot : {rate_vs_distance_plot(summaries), pose_error_plot(summaries), rate_map_plot(summaries)}) {
      files.plots.push_back(draw(plot, options));
    }
  }

  std::string ids;
  for (const auto& s : summaries) ids += (ids.empty() ? "" : ", ") + s.run_id;
  const bool side_by_side = summaries.size() > 1;
  std::string md = fmt::format("# Sweep report: {}\n\n", ids);
  md += preface;
  md += runs_table(runs, summaries, columns);
  md += "\n## Table 6.1\n\n" + table;

  if (options.plots) {
    md += fmt::format(
        "\n## Plots\n\n"
        "![Detection rate against distance]({0}.svg)\n\n"
        "![Pose error against distance]({1}.svg)\n\n"
        "![Detection rate over distance and angle]({2}.svg)\n\n"
        "Each plot is drawn by gnuplot from the `.gp` script and `.dat` files beside it (`gnuplot {0}.gp` in this "
        "directory draws it again). The rate over distance and angle is drawn as curves of rate against angle, one "
        "per distance swept over angle, or as a heat map for a run that sweeps angle at more than {3} distances.\n",
        kRateVsDistance, kPoseErrorVsDistance, kRateMap, kMostAngleCurves);
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
  write_text(files.report, md);
  files.table_6_1 = std::move(table);
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
  return write_runs_report(pointers, summaries, table_6_1(summaries), {}, preface, options);
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
  return write_runs_report(pointers, summaries, table_6_1_by_marker(table_columns), columns, preface, options);
}

}  // namespace markerd::sweep
