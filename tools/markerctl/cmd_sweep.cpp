// markerctl sweep: plans run by markerd's sweep runner (docs/sweep.md).
//
//   sweep check PLAN [--config FILE]   the dry run: points, limits, estimated duration
//   sweep start PLAN [--wait]          starts a run; --wait follows it to its end
//   sweep status [--follow]            a progress bar, the step, the rate, the time left
//   sweep pause | resume | abort [--reason TEXT]
//
// The plan file is read here and sent as text: markerd may not be allowed to
// read where the operator keeps it, and the run's records keep the text. A
// plan over sweep::kMaxPlanBytes (or not a regular file) is refused here,
// before anything is sent.

#include <unistd.h>

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "cmd_daemon.hpp"
#include "common.hpp"
#include "live_line.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/sweep/plan.hpp"

namespace markerctl {

namespace {

using nlohmann::json;
using namespace std::chrono_literals;

// A plan's text and the name it goes by in errors and in the run's records.
struct PlanText {
  std::string text;
  std::string source;
};

PlanText read_plan_text(const std::string& context, const std::string& path) {
  if (path == "-")
    return {read_standard_input(markerd::sweep::kMaxPlanBytes, "the plan", context), standard_input_name};
  try {
    return {markerd::sweep::read_plan_file(path), path};
  } catch (const markerd::ConfigError& e) {
    throw runtime_error(context, e.what());
  }
}

std::string duration_text(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const auto s = static_cast<long>(std::lround(seconds));
  if (s >= 3600) return fmt::format("{}h{:02}m", s / 3600, (s % 3600) / 60);
  if (s >= 60) return fmt::format("{}m{:02}s", s / 60, s % 60);
  return fmt::format("{}s", s);
}

std::string progress_bar(std::size_t done, std::size_t total, std::size_t width) {
  const std::size_t filled = total == 0 ? 0 : std::min(width, width * done / total);
  return "[" + std::string(filled, '#') + std::string(width - filled, '-') + "]";
}

// The line's parts, the bar `bar_width` cells wide, each with how long it
// stays in a line too narrow for all: the steps done longest, then the
// state, the step in hand and the time left; the bar goes before them, the
// phase before the bar, the last rate before the phase, and the reason
// (which a terminal's callers print on a line of their own) first.
std::vector<LinePart> progress_parts(const json& p, std::size_t bar_width) {
  const auto done = p.value("steps_done", std::size_t{0});
  const auto total = p.value("steps_total", std::size_t{0});
  std::vector<LinePart> parts;
  parts.push_back({progress_bar(done, total, bar_width), 4, ""});
  parts.push_back({fmt::format("{:>4}/{:<4}", done, total), 9, " "});
  parts.push_back({p.value("state", std::string("?")), 8, " "});
  // A key a status lacks (another version's, or a run that has not got
  // that far) is null: a const json's operator[] has no such key to give.
  static const json none;
  const auto key = [&p](const char* name) -> const json& {
    const auto it = p.find(name);
    return it == p.end() ? none : *it;
  };
  const json& step = key("step");
  if (step.is_object()) {
    parts.push_back({fmt::format("{:.2f} m {:.1f} deg #{}", step.value("distance_m", 0.0), step.value("angle_deg", 0.0),
                                 step.value("repeat", 0) + 1),
                     8});
  }
  const std::string phase = p.value("phase", std::string());
  if (phase == "collecting") {
    parts.push_back(
        {fmt::format("collecting {}/{}", p.value("frames_collected", 0), p.value("frames_per_point", 0)), 3});
  } else if (!phase.empty()) {
    parts.push_back({phase, 3});
  }
  if (const json& rate = key("last_rate"); rate.is_number()) {
    parts.push_back({fmt::format("rate {:.0f}%", 100 * rate.get<double>()), 2});
  }
  if (const json& left = key("remaining_s"); left.is_number()) {
    parts.push_back({"about " + duration_text(left.get<double>()) + " left", 8});
  }
  const std::string reason = p.value("reason", std::string());
  if (!reason.empty()) parts.push_back({"(" + reason + ")", 1});
  return parts;
}

}  // namespace

// One line: "[#######-------------]  23/62  running  0.95 m 30.0 deg  collecting 3/6  rate 100%  about 2m10s left"
std::string sweep_progress_line(const json& p, std::size_t columns) {
  constexpr std::size_t kBar = 24;
  constexpr std::size_t kNarrowBar = 10;
  std::string line = join_keeping(progress_parts(p, kBar), std::string::npos);
  if (display_columns(line) <= columns) return line;
  return join_keeping(progress_parts(p, kNarrowBar), columns);
}

namespace {

bool finished(const std::string& state) { return state == "done" || state == "aborted" || state == "failed"; }

// Follows the run until it ends; on a terminal the bar redraws in place.
// With `as_json`, sweep.status's reply each time it changes, a line each
// (JSON Lines), the last one the run's end. Exit status: 0 done, 1 aborted
// or failed.
int follow(DaemonConnection& daemon, bool as_json) {
  LiveLine live(std::cout, STDOUT_FILENO);
  const bool tty = !as_json && live.on_terminal();
  std::string last;
  std::string last_reason;
  for (;;) {
    const json p = daemon.call({{"cmd", "sweep.status"}});
    const std::string state = p.value("state", std::string());
    if (as_json) {
      std::string line = json_line(p);
      if (line != last) std::cout << line << '\n' << std::flush;
      last = std::move(line);
      if (state == "idle") return exit_runtime;
    } else {
      if (state == "idle") {
        std::cout << "no run since markerd started\n";
        return exit_runtime;
      }
      if (tty) {
        // The reason (a fault while suspended) has a line of its own above
        // the live one, whole, once each time it changes: the live line is
        // cut to the terminal's width, its reason left out first.
        const std::string reason = p.value("reason", std::string());
        if (!reason.empty() && reason != last_reason && !finished(state)) live.print(state + ": " + reason);
        last_reason = reason;
        json progress = p;
        progress.erase("reason");
        live.show(sweep_progress_line(progress, live.columns()));
      } else if (std::string line = sweep_progress_line(p); line != last) {
        std::cout << line << '\n' << std::flush;
        last = std::move(line);
      }
    }
    if (finished(state)) {
      if (!as_json) {
        // The final state stays on the screen.
        live.keep();
        // Two lines: with the run's directory one would not fit 80 columns.
        const std::string reason = p.value("reason", std::string());
        std::cout << fmt::format("run {}: {}{}\nrecords in {}\n", p.value("run_id", std::string()), state,
                                 reason.empty() ? std::string() : " (" + reason + ")",
                                 p.value("run_directory", std::string()));
      }
      return state == "done" ? 0 : exit_runtime;
    }
    std::this_thread::sleep_for(tty ? 250ms : 1s);
  }
}

int run_check(const std::string& socket, const std::string& plan_path, const std::string& config_path, bool as_json) {
  const std::string context = "sweep check";
  const auto [text, source] = read_plan_text(context, plan_path);
  if (!config_path.empty()) {
    // Offline: against the rig and camera of a config, without markerd.
    try {
      const markerd::sweep::SweepPlan plan = markerd::sweep::parse_plan(text, source);
      const markerd::daemon::DaemonConfig config = markerd::daemon::load_daemon_config(config_path);
      if (!config.rig)
        throw runtime_error(context, fmt::format("{} has no rig to check the plan against", config_path));
      if (auto problem = markerd::sweep::marker_problem(plan.marker, markerd::daemon::detector_config(config),
                                                        config.marker.mounting)) {
        throw runtime_error(context, fmt::format("plan {} cannot run with {}: {}", source, config_path, *problem));
      }
      const double fps = std::visit([](const auto& s) { return s.fps; }, config.camera.source);
      const markerd::sweep::PlanCheck check = markerd::sweep::check_plan(plan, *config.rig, fps);
      std::cout << markerd::sweep::format_plan_check(plan, check);
      return check.ok() ? 0 : exit_runtime;
    } catch (const markerd::ConfigError& e) {
      throw runtime_error(context, e.what());
    }
  }
  DaemonConnection daemon(socket, context);
  const json reply = daemon.call({{"cmd", "sweep.check"}, {"plan", text}, {"source", source}});
  if (as_json) {
    std::cout << reply.dump() << '\n';
  } else {
    std::cout << reply.value("text", std::string());
  }
  return reply.value("fits", false) ? 0 : exit_runtime;
}

int run_start(const std::string& socket, const std::string& plan_path, bool wait, bool as_json) {
  const std::string context = "sweep start";
  const auto [text, source] = read_plan_text(context, plan_path);
  DaemonConnection daemon(socket, context);
  const json reply = daemon.call({{"cmd", "sweep.start"}, {"plan", text}, {"source", source}});
  if (as_json) {
    std::cout << reply.dump() << '\n';
  } else {
    std::cout << fmt::format("run {} started: {} steps\nrecords in {}\n", reply.value("run_id", std::string()),
                             reply.value("steps", 0), reply.value("run_directory", std::string()));
  }
  return wait ? follow(daemon, as_json) : 0;
}

int run_status(const std::string& socket, bool follow_run, bool as_json) {
  DaemonConnection daemon(socket, "sweep status");
  if (follow_run) return follow(daemon, as_json);
  const json p = daemon.call({{"cmd", "sweep.status"}});
  if (as_json) {
    std::cout << p.dump() << '\n';
    return 0;
  }
  if (p.value("state", std::string()) == "idle") {
    std::cout << "no run since markerd started\n";
    return 0;
  }
  std::cout << fmt::format("run {} (plan {}), records in {}\n", p.value("run_id", std::string()),
                           p.value("plan", std::string()), p.value("run_directory", std::string()))
            << sweep_progress_line(p) << '\n';
  return 0;
}

int run_simple(const std::string& socket, const std::string& command, json arguments, bool as_json) {
  DaemonConnection daemon(socket, "sweep " + command);
  arguments["cmd"] = "sweep." + command;
  (void)daemon.call(std::move(arguments));
  const json p = daemon.call({{"cmd", "sweep.status"}});
  std::cout << (as_json ? json_line(p) : sweep_progress_line(p)) << '\n';
  return 0;
}

}  // namespace

void add_sweep_command(CLI::App& parent, Commands& commands) {
  const char* socket_help = "markerd's control socket (default: $MARKERD_SOCKET, else /run/markerd/control.sock)";
  CLI::App* sweep = parent.add_subcommand("sweep", "Unattended sweeps of distance and viewing angle, run by markerd");
  sweep->require_subcommand(1);
  sweep->footer("Plans: docs/sweep.md; examples in config/plans/. Reports: markerctl report RUN_DIR.");

  struct Options {
    std::string socket;
    std::string plan;
    std::string config;
    std::string reason = "aborted by the operator";
    bool wait = false;
    bool follow = false;
    bool json = false;
  };
  auto o = std::make_shared<Options>();

  CLI::App* check =
      sweep->add_subcommand("check", "Dry run: the plan's points, what does not fit the rig, the duration");
  check->add_option("plan", o->plan, "The plan (TOML); - reads it from standard input")->required()->type_name("PLAN");
  check
      ->add_option("--config", o->config,
                   "Check against this markerd config's rig and camera instead of the running markerd's")
      ->type_name("FILE");
  check->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  check->add_flag("--json", o->json, "The reply as JSON");
  commands.push_back({check, [o] { return run_check(o->socket, o->plan, o->config, o->json); }});

  CLI::App* start = sweep->add_subcommand("start", "Start a run of a plan");
  start->add_option("plan", o->plan, "The plan (TOML); - reads it from standard input")->required()->type_name("PLAN");
  start->add_flag("--wait", o->wait, "Follow the run to its end (exit 0 when done, 1 when aborted or failed)");
  start->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  start->add_flag("--json", o->json, "The reply as JSON; with --wait, then sweep.status as JSON lines as it changes");
  commands.push_back({start, [o] { return run_start(o->socket, o->plan, o->wait, o->json); }});

  CLI::App* status = sweep->add_subcommand("status", "The run's progress, step, last detection rate and time left");
  status->add_flag("--follow", o->follow, "Follow the run to its end");
  status->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  status->add_flag("--json", o->json, "sweep.status's reply as JSON; with --follow, a line each time it changes");
  commands.push_back({status, [o] { return run_status(o->socket, o->follow, o->json); }});

  CLI::App* pause = sweep->add_subcommand("pause", "Stop the axes and hold the run at its step");
  pause->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  pause->add_flag("--json", o->json, "sweep.status's reply afterwards as JSON");
  commands.push_back({pause, [o] { return run_simple(o->socket, "pause", json::object(), o->json); }});

  CLI::App* resume = sweep->add_subcommand("resume", "Resume a paused run at its step");
  resume->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  resume->add_flag("--json", o->json, "sweep.status's reply afterwards as JSON");
  commands.push_back({resume, [o] { return run_simple(o->socket, "resume", json::object(), o->json); }});

  CLI::App* abort = sweep->add_subcommand("abort", "End the run; the axes stop and are disabled");
  abort->add_option("--reason", o->reason, "Why, for the run's stop record")->type_name("TEXT");
  abort->add_option("--socket", o->socket, socket_help)->type_name("PATH");
  abort->add_flag("--json", o->json, "sweep.status's reply afterwards as JSON");
  commands.push_back({abort, [o] { return run_simple(o->socket, "abort", json{{"reason", o->reason}}, o->json); }});
}

}  // namespace markerctl
