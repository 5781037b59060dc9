#include "report_plots.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <fstream>
#include <optional>
#include <set>
#include <stdexcept>
#include <string_view>
#include <utility>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

extern char** environ;

namespace markerd::sweep::plots {

namespace fs = std::filesystem;

namespace {

constexpr const char* kRateVsDistance = "rate-vs-distance";
constexpr const char* kPoseErrorVsDistance = "pose-error-vs-distance";
constexpr const char* kPoseErrorVsAngle = "pose-error-vs-angle";
constexpr const char* kRateMap = "rate-map";

// Colours that stay apart in print and for the colour-blind; a run keeps its
// colour in every plot.
constexpr std::array<const char*, 6> kRunColours = {"#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9"};

const char* run_colour(std::size_t run) { return kRunColours[run % kRunColours.size()]; }

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

// A number for a .dat file; NaN, which gnuplot skips, for one missing.
std::string dat(const std::optional<double>& value) { return value ? fmt::format("{:.6g}", *value) : "NaN"; }

struct PlotFile {
  std::string name;  // without extension
  int width = 800;   // of the SVG, in pixels; the PDF keeps its shape
  int height = 500;
  std::string body;                                       // what draws it, on whichever terminal is set
  std::vector<std::pair<std::string, std::string>> data;  // file name, contents
};

// The script draws the body twice, as SVG and as PDF: one script, so a plot
// and its PDF for a paper cannot drift apart. The PDF is 128 pixels to the
// inch (800 pixels: 6.25 in, about a page's text width) with a 9 pt font,
// which LaTeX can place at its own size without rescaling the text much.
std::string script_of(const PlotFile& plot) {
  constexpr double kPixelsPerInch = 128;
  return fmt::format(
      "# Drawn by markerd's sweep report from the .dat files beside it; to draw it again:\n"
      "#   gnuplot {0}.gp   (in this directory: writes {0}.svg and {0}.pdf)\n"
      "do for [format in \"svg pdf\"] {{\n"
      "reset\n"
      "set encoding utf8\n"
      // noenhanced: run ids and grid names keep their underscores.
      "if (format eq \"svg\") {{\n"
      "  set terminal svg size {1},{2} dynamic noenhanced font 'sans,12' background '#ffffff'\n"
      "}} else {{\n"
      "  set terminal pdfcairo size {3:.4g}in,{4:.4g}in noenhanced font 'sans,9'\n"
      "}}\n"
      "set output '{0}.'.format\n"
      "set grid\n"
      "{5}"
      "unset output\n"
      "}}\n",
      plot.name, plot.width, plot.height, plot.width / kPixelsPerInch, plot.height / kPixelsPerInch, plot.body);
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
  [[nodiscard]] double margin(double margin_fraction, double minimum_margin) const {
    return std::max((high - low) * margin_fraction, minimum_margin);
  }
  // Room around the points so the first and last are not on the frame.
  [[nodiscard]] std::string gp(double margin_fraction, double minimum_margin) const {
    const double m = margin(margin_fraction, minimum_margin);
    return fmt::format("[{:.6g}:{:.6g}]", low - m, high + m);
  }
};

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

// The thesis's limits for the markers the runs measured (the paper
// marker's for a run that does not say, as Table 6.1 compares it).
std::vector<const ThesisLimits*> thesis_of(const std::vector<RunSummary>& runs) {
  std::vector<const ThesisLimits*> limits;
  for (const auto& run : runs) {
    const ThesisLimits* l = thesis_limits(run.marker.mounting.value_or(Mounting::paper));
    if (l != nullptr && std::find(limits.begin(), limits.end(), l) == limits.end()) limits.push_back(l);
  }
  return limits;
}

// A dotted vertical line at x = `at` (inside `range`), labelled along it:
// where the thesis found a limit.
std::string reference_line(int& number, double at, std::string_view label) {
  ++number;
  return fmt::format(
      "set arrow {0} from {1:.6g}, graph 0 to {1:.6g}, graph 1 nohead dt 3 lw 1.5 lc rgb '#777777' back\n"
      "set label {0} {2} at {1:.6g}, graph 0.03 rotate by 90 left offset -0.6,0 textcolor rgb '#555555' front\n",
      number, at, gp_string(label));
}

bool inside(const Range& range, double at, double margin) {
  return !range.empty && at >= range.low - margin && at <= range.high + margin;
}

// The thesis's maximum distances, on an axis of distance in metres.
std::string distance_references(const std::vector<RunSummary>& runs, const Range& distances, double margin) {
  std::string lines;
  int number = 0;
  for (const ThesisLimits* l : thesis_of(runs)) {
    if (!inside(distances, l->max_distance_m, margin)) continue;
    lines += reference_line(number, l->max_distance_m,
                            fmt::format("thesis, {}: {:.0f} cm", l->marker, l->max_distance_m * 100));
  }
  return lines;
}

// The thesis's maximum angles, on an axis of angle in degrees: on each side
// the data reaches.
std::string angle_references(const std::vector<RunSummary>& runs, const Range& angles, double margin) {
  std::string lines;
  int number = 0;
  for (const ThesisLimits* l : thesis_of(runs)) {
    for (const auto& [distance, angle] : l->max_angle_deg) {
      for (const double at : {angle, -angle}) {
        if (!inside(angles, at, margin)) continue;
        lines += reference_line(number, at,
                                fmt::format("thesis, {}: {:.0f}° at {:.0f} cm", l->marker, angle, distance * 100));
      }
    }
  }
  return lines;
}

const char* const kClearReferences = "unset arrow\nunset label\n";

PlotFile rate_vs_distance_plot(const std::vector<RunSummary>& runs) {
  PlotFile plot{kRateVsDistance, 800, 500, {}, {}};
  std::string curves;
  Range distances;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const auto facing = facing_by_distance(runs[r]);
    if (facing.empty()) continue;
    std::string data = fmt::format(
        "# {}: facing points; the rate's 95% interval (Wilson)\n"
        "# distance_m rate_pct rate_low_pct rate_high_pct frames detected\n",
        runs[r].run_id);
    for (const auto* p : facing) {
      data += fmt::format("{:.6g} {:.6g} {:.6g} {:.6g} {} {}\n", p->distance_m, 100 * p->rate,
                          100 * p->rate_interval.low, 100 * p->rate_interval.high, p->frames, p->detected);
      distances.add(p->distance_m);
    }
    const std::string file = fmt::format("{}-{}.dat", kRateVsDistance, r + 1);
    plot.data.emplace_back(file, data);
    curves +=
        fmt::format("{}{} using 1:2:3:4 with yerrorlines lw 2 pt 7 ps 0.8 lc rgb '{}' title {}",
                    curves.empty() ? "" : ", \\\n     ", gp_string(file), run_colour(r), gp_string(runs[r].run_id));
  }
  plot.body +=
      "set title 'Detection rate of the facing points (|angle| < 0.5°) against distance, with 95% intervals'\n"
      "set xlabel 'distance (m)'\nset ylabel 'detection rate (%)'\nset key bottom left opaque box\n";
  if (curves.empty()) {
    plot.body += gp_empty_panel("no facing points in the run");
    return plot;
  }
  plot.body += distance_references(runs, distances, distances.margin(0.05, 0.02));
  plot.body += fmt::format("set xrange {}\nset yrange [0:105]\nplot {}{}\n", distances.gp(0.05, 0.02), curves,
                           threshold_lines(runs));
  return plot;
}

// The three pose errors a point has, each a median over its frames with the
// median's 95% interval: columns of a .dat line, and the panels drawing them.
struct ErrorPanel {
  std::optional<MedianEstimate> PointSummary::*field;
  const char* label;
};
constexpr std::array<ErrorPanel, 3> kErrorPanels = {{
    {&PointSummary::median_distance_error_pct, "|distance error| (% of the true distance)"},
    {&PointSummary::median_translation_error_mm, "translation error (mm)"},
    {&PointSummary::median_rotation_error_deg, "rotation error (°)"},
}};
constexpr const char* kErrorColumns =
    "distance_error_pct low high translation_error_mm low high rotation_error_deg low high";

bool has_errors(const PointSummary& p) {
  return std::any_of(kErrorPanels.begin(), kErrorPanels.end(), [&](const ErrorPanel& e) { return bool(p.*e.field); });
}

// Median, low, high of each panel's error; an interval's ends are the
// median's own when it has none (under 6 frames), so its bar has no length.
std::string error_columns(const PointSummary& p) {
  std::string line;
  for (const auto& panel : kErrorPanels) {
    const auto& m = p.*panel.field;
    const std::optional<double> median = m ? std::optional(m->median) : std::nullopt;
    line += fmt::format(" {} {} {}", dat(median), dat(m ? m->low.value_or(m->median) : median),
                        dat(m ? m->high.value_or(m->median) : median));
  }
  return line;
}

// The error panels, one above the other over one x axis, each plotting
// `curves(column)` where column is the panel's first data column.
template <typename Curves>
std::string error_panels(const std::string& x_range, const std::string& references, Curves curves) {
  std::string body =
      fmt::format("set xrange {}\nset yrange [0:*]\nset offsets 0, 0, graph 0.08, 0\n{}", x_range, references);
  for (std::size_t i = 0; i < kErrorPanels.size(); ++i) {
    body += fmt::format("set ylabel {}\nplot {}\n", gp_string(kErrorPanels[i].label), curves(2 + 3 * i));
    // The references' lines in every panel, their words in the first only.
    if (i == 0) body += "unset label\n";
  }
  return body + kClearReferences;
}

PlotFile pose_error_vs_distance_plot(const std::vector<RunSummary>& runs) {
  PlotFile plot{kPoseErrorVsDistance, 800, 1000, {}, {}};
  std::vector<std::pair<std::string, std::size_t>> files;  // file, run
  Range distances;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    std::string data = fmt::format(
        "# {}: facing points with a pose error, medians over each point's frames and their 95% intervals\n"
        "# distance_m {}\n",
        runs[r].run_id, kErrorColumns);
    bool any = false;
    for (const auto* p : facing_by_distance(runs[r])) {
      if (!has_errors(*p)) continue;
      data += fmt::format("{:.6g}{}\n", p->distance_m, error_columns(*p));
      distances.add(p->distance_m);
      any = true;
    }
    if (!any) continue;
    files.emplace_back(fmt::format("{}-{}.dat", kPoseErrorVsDistance, r + 1), r);
    plot.data.emplace_back(files.back().first, data);
  }
  // Panels over one distance axis: percent, millimetres and degrees would
  // fight over a shared y axis, and a second y axis is easy to misread.
  plot.body +=
      "set multiplot layout 3,1 title 'Pose error of the facing points against distance (medians over each point''s "
      "frames, 95% intervals)'\n"
      "set key top left opaque box\nset xlabel 'distance (m)'\n";
  if (files.empty()) {
    for (std::size_t i = 0; i < kErrorPanels.size(); ++i) {
      plot.body += gp_empty_panel("no pose errors (no pose, or no ground truth)");
    }
  } else {
    const double margin = distances.margin(0.05, 0.02);
    plot.body +=
        error_panels(distances.gp(0.05, 0.02), distance_references(runs, distances, margin), [&](std::size_t column) {
          std::string curves;
          for (const auto& [file, r] : files) {
            curves += fmt::format("{}{} using 1:{}:{}:{} with yerrorlines lw 2 pt 7 ps 0.8 lc rgb '{}' title {}",
                                  curves.empty() ? "" : ", \\\n     ", gp_string(file), column, column + 1, column + 2,
                                  run_colour(r), gp_string(runs[r].run_id));
          }
          return curves;
        });
  }
  plot.body += "unset multiplot\n";
  return plot;
}

// The points of each distance a run swept in angle, by angle: one block a
// distance.
std::vector<std::vector<const PointSummary*>> angle_sweeps(const RunSummary& run) {
  std::vector<std::vector<const PointSummary*>> sweeps;
  for (const auto& entry : run.max_angle) {
    std::vector<const PointSummary*> at_distance;
    for (const auto& p : run.points) {
      if (std::abs(p.distance_m - entry.distance_m) <= 0.0005) at_distance.push_back(&p);
    }
    std::stable_sort(at_distance.begin(), at_distance.end(),
                     [](const PointSummary* a, const PointSummary* b) { return a->angle_deg < b->angle_deg; });
    sweeps.push_back(std::move(at_distance));
  }
  return sweeps;
}

// Curves told apart by distance within a run: its colour, a dash and a
// point shape each.
std::string sweep_style(std::size_t run, std::size_t sweep) {
  return fmt::format("lw 2 pt {} ps 0.8 dt {} lc rgb '{}'", 7 + 2 * (sweep % 4), 1 + sweep % 4, run_colour(run));
}

PlotFile pose_error_vs_angle_plot(const std::vector<RunSummary>& runs) {
  PlotFile plot{kPoseErrorVsAngle, 800, 1000, {}, {}};
  struct Curve {
    std::string file;
    std::size_t block;
    std::size_t run;
    std::size_t sweep;
    std::string title;
  };
  std::vector<Curve> curves;
  Range angles;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    std::string data = fmt::format(
        "# {}: one block per distance swept over angle (gnuplot's index), medians over each point's frames and "
        "their 95% intervals\n# angle_deg {} distance_m\n",
        runs[r].run_id, kErrorColumns);
    const std::string file = fmt::format("{}-{}.dat", kPoseErrorVsAngle, r + 1);
    std::size_t block = 0;
    const auto sweeps = angle_sweeps(runs[r]);
    for (std::size_t s = 0; s < sweeps.size(); ++s) {
      std::string lines;
      for (const auto* p : sweeps[s]) {
        if (!has_errors(*p)) continue;
        lines += fmt::format("{:.6g}{} {:.6g}\n", p->angle_deg, error_columns(*p), p->distance_m);
        angles.add(p->angle_deg);
      }
      if (lines.empty()) continue;
      data += lines + "\n\n";
      curves.push_back(Curve{file, block++, r, s,
                             fmt::format("{}{:.3g} m", runs.size() > 1 ? runs[r].run_id + ", " : std::string(),
                                         sweeps[s].front()->distance_m)});
    }
    if (block > 0) plot.data.emplace_back(file, data);
  }
  plot.body +=
      "set multiplot layout 3,1 title 'Pose error against viewing angle, one curve per distance (medians over "
      "each point''s frames, 95% intervals)'\n"
      "set key top left opaque box\nset xlabel 'viewing angle (°)'\n";
  if (curves.empty()) {
    for (std::size_t i = 0; i < kErrorPanels.size(); ++i) {
      plot.body += gp_empty_panel("no pose errors at a distance swept in angle");
    }
  } else {
    const double margin = angles.margin(0.05, 2);
    plot.body += error_panels(angles.gp(0.05, 2), angle_references(runs, angles, margin), [&](std::size_t column) {
      std::string text;
      for (const auto& c : curves) {
        text += fmt::format("{}{} index {} using 1:{}:{}:{} with yerrorlines {} title {}",
                            text.empty() ? "" : ", \\\n     ", gp_string(c.file), c.block, column, column + 1,
                            column + 2, sweep_style(c.run, c.sweep), gp_string(c.title));
      }
      return text;
    });
  }
  plot.body += "unset multiplot\n";
  return plot;
}

// The rate map chooses per run. A plan shaped like the thesis's sweeps
// distance at 0° and angle at one or two distances: as a heat map that is a
// row and a column or two of cells in an empty field, and the shape of the
// fall-off is hard to read from colours; as curves of rate against angle,
// one per distance, it reads at a glance and the threshold can be drawn.
// Past a handful of distances swept over angle the curves tangle, and the
// points fill distance x angle well enough for a heat map to read better.
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

std::string angle_curves_panel(const std::vector<RunSummary>& runs, std::size_t index, PlotFile& plot) {
  const RunSummary& run = runs[index];
  const auto sweeps = angle_sweeps(run);
  const std::string title =
      run.run_id + ": detection rate against viewing angle, one curve per distance, with 95% intervals";
  if (sweeps.empty()) {
    return fmt::format("set title {}\n", gp_string(title)) + gp_empty_panel("no angle sweep in the run");
  }

  const std::string file = fmt::format("{}-{}.dat", kRateMap, index + 1);
  std::string data = fmt::format(
      "# {}: one block per distance swept over angle (gnuplot's index); the rate's 95% interval (Wilson)\n"
      "# angle_deg rate_pct distance_m rate_low_pct rate_high_pct frames detected\n",
      run.run_id);
  std::string curves;
  Range angles;
  for (std::size_t block = 0; block < sweeps.size(); ++block) {
    for (const auto* p : sweeps[block]) {
      data += fmt::format("{:.6g} {:.6g} {:.6g} {:.6g} {:.6g} {} {}\n", p->angle_deg, 100 * p->rate, p->distance_m,
                          100 * p->rate_interval.low, 100 * p->rate_interval.high, p->frames, p->detected);
      angles.add(p->angle_deg);
    }
    data += "\n\n";
    curves += fmt::format("{}{} index {} using 1:2:4:5 with yerrorlines lw 2 pt 7 ps 0.8 lc {} title {}",
                          curves.empty() ? "" : ", \\\n     ", gp_string(file), block, block + 1,
                          gp_string(fmt::format("{:.3f} m", sweeps[block].front()->distance_m)));
  }
  plot.data.emplace_back(file, data);
  const std::vector<RunSummary> this_run = {run};
  return fmt::format(
      "set title {}\nset xlabel 'viewing angle (°)'\nset ylabel 'detection rate (%)'\n"
      "set xrange {}\nset yrange [0:105]\nunset colorbox\nset key outside right top box\n{}"
      "plot {}, \\\n     {:.6g} with lines dt 2 lw 1.5 lc rgb '#555555' title 'threshold {:.4g} %'\n{}",
      gp_string(title), angles.gp(0.05, 2), angle_references(this_run, angles, angles.margin(0.05, 2)), curves,
      100 * run.detection_threshold, 100 * run.detection_threshold, kClearReferences);
}

PlotFile rate_map_plot(const std::vector<RunSummary>& runs) {
  const int panels = static_cast<int>(std::max<std::size_t>(runs.size(), 1));
  PlotFile plot{kRateMap, 800, 450 * panels, {}, {}};
  plot.body +=
      "set cbrange [0:100]\n"
      // Viridis: ordered in lightness, so it reads in grey and for the colour-blind.
      "set palette defined (0 '#440154', 25 '#3b528b', 50 '#21918c', 75 '#5ec962', 100 '#fde725')\n";
  plot.body += fmt::format("set multiplot layout {},1\n", panels);
  if (runs.empty()) plot.body += gp_empty_panel("no runs");
  for (std::size_t r = 0; r < runs.size(); ++r) {
    plot.body += fills_a_heat_map(runs[r]) ? heat_map_panel(runs[r], r, plot) : angle_curves_panel(runs, r, plot);
  }
  plot.body += "unset multiplot\n";
  return plot;
}

std::vector<fs::path> draw(const PlotFile& plot, const ReportOptions& options) {
  for (const auto& [file, contents] : plot.data) write_report_file(options.output_directory / file, contents);
  const std::string script = plot.name + ".gp";
  write_report_file(options.output_directory / script, script_of(plot));
  const std::vector<fs::path> drawn = {options.output_directory / (plot.name + ".svg"),
                                       options.output_directory / (plot.name + ".pdf")};
  // An earlier report's plot must not pass for this one's.
  for (const auto& file : drawn) {
    std::error_code ignored;
    fs::remove(file, ignored);
  }
  run_gnuplot(options.gnuplot, options.output_directory, script);
  for (const auto& file : drawn) {
    if (!fs::exists(file))
      throw std::runtime_error(fmt::format("gnuplot '{}' wrote no {}", options.gnuplot, file.string()));
  }
  return drawn;
}

}  // namespace

void write_report_file(const fs::path& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (out) out.close();
  if (!out) throw std::runtime_error(fmt::format("{}: cannot write: {}", path.string(), errno_text(errno)));
}

const std::vector<PlotName>& plot_names() {
  static const std::vector<PlotName> names = {
      {kRateVsDistance, "Detection rate against distance"},
      {kPoseErrorVsDistance, "Pose error against distance"},
      {kPoseErrorVsAngle, "Pose error against viewing angle"},
      {kRateMap, "Detection rate over distance and angle"},
  };
  return names;
}

std::vector<fs::path> draw_all(const std::vector<RunSummary>& runs, const ReportOptions& options) {
  std::vector<fs::path> files;
  for (const auto& plot : {rate_vs_distance_plot(runs), pose_error_vs_distance_plot(runs),
                           pose_error_vs_angle_plot(runs), rate_map_plot(runs)}) {
    for (auto& file : draw(plot, options)) files.push_back(std::move(file));
  }
  return files;
}

}  // namespace markerd::sweep::plots
