// markerctl rig: bring-up of a rig without the daemon. Loads the rig config,
// locks its devices against every other process (markerd, another
// markerctl), builds the rig and runs one command: status, home, move, or
// jog (relative moves, or an interactive jog on a terminal). Without
// --config the same commands (and stop) go to a running markerd over its
// control socket instead (cmd_daemon.cpp).
//
// Fail safe: whatever way the command ends, the axes end disabled. An
// interrupt (SIGINT, SIGTERM, SIGHUP, SIGQUIT) stops the motion with a
// controlled ramp, then disables; a second one, or any error, stops it at
// once (emergency stop). The signals are blocked in every thread and read
// from a signalfd by the command's own wait loop, so that the stop runs on
// the main thread with the full rig at hand, not in a signal handler.

#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <iostream>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cmd_daemon.hpp"
#include "common.hpp"
#include "interactive_jog.hpp"
#include "rig_session.hpp"
#include "rig_units.hpp"
#include "signal_watch.hpp"

namespace markerctl {
namespace {

using markerd::rig::Axis;
using markerd::rig::AxisError;
using markerd::rig::AxisSettings;
using markerd::rig::AxisState;
using markerd::rig::AxisStatus;

// ---------------------------------------------------------------- status

struct RigOptions {
  std::string config;
  bool json = false;
  std::string home_axis;  // home: "", "rail" or "turntable"
  std::string rail;       // move, jog
  std::string turntable;
  bool home = false;  // move, jog: home what is not homed first
  // markerd's rig (no --config):
  std::string socket;
  bool emergency = false;  // stop
  bool no_wait = false;    // home, move, jog, stop: return once the daemon has started it
};

// The rig as status --json shows it, and home, move and jog --json once done.
nlohmann::ordered_json status_document(Session& session, const std::string& config) {
  auto& rig = session.rig();
  const AxisStatus rail = rig.rail().status();
  const AxisStatus turntable = rig.turntable().status();
  const auto truth = markerd::rig::ground_truth(rig.geometry(), rail.position, turntable.position);
  nlohmann::ordered_json j;
  j["config"] = config;
  j["rail"] = axis_json(rig.rail().settings(), rail);
  j["turntable"] = axis_json(rig.turntable().settings(), turntable);
  const Eigen::Quaterniond q(truth.rotation);
  j["ground_truth"] = {
      {"distance_m", rounded(truth.distance_m, 9)},
      {"yaw_deg", rounded(truth.yaw_deg, 9)},
      {"tvec",
       {rounded(truth.translation.x(), 9), rounded(truth.translation.y(), 9), rounded(truth.translation.z(), 9)}},
      {"quaternion", {rounded(q.w(), 9), rounded(q.x(), 9), rounded(q.y(), 9), rounded(q.z(), 9)}}};
  return j;
}

// A command's session: with --json its lines in words go to standard error,
// standard output keeping the one JSON line of the end.
std::unique_ptr<Session> open_session(const RigOptions& o, const std::string& context) {
  auto session = std::make_unique<Session>(o.config, context);
  if (o.json) session->text_to_stderr();
  return session;
}

// The end of home, move and jog: the ground truth in words, and with --json
// the rig as the command leaves it (markerctl disables the axes after it).
int finish(Session& session, const RigOptions& o) {
  session.print_ground_truth();
  if (o.json) std::cout << json_line(status_document(session, o.config)) << '\n' << std::flush;
  return 0;
}

int run_status(const RigOptions& o, const std::string& context) {
  Session session(o.config, context);
  if (o.json) {
    std::cout << json_line(status_document(session, o.config)) << '\n';
    return 0;
  }
  auto& rig = session.rig();
  for (const Axis* axis : {&rig.rail(), &rig.turntable()}) {
    const AxisSettings& settings = axis->settings();
    const AxisStatus s = axis->status();
    std::cout << fmt::format("{:<10} {}, {}{}: position {}, target {}; inputs: {}\n", settings.name,
                             markerd::rig::to_string(s.state), s.homed ? "homed" : "not homed",
                             s.settled ? ", settled" : "", position_text(settings, s.position),
                             position_text(settings, s.target), inputs_text(s.inputs));
    if (s.state == AxisState::fault) std::cout << fmt::format("{:<10} fault: {}\n", "", s.fault);
  }
  session.print_ground_truth();
  return 0;
}

// ---------------------------------------------------------------- home

int run_home(const RigOptions& o, const std::string& context) {
  std::vector<const AxisKind*> kinds;
  if (o.home_axis.empty() || o.home_axis == "rail") kinds.push_back(&kRail);
  if (o.home_axis.empty() || o.home_axis == "turntable") kinds.push_back(&kTurntable);
  const auto session = open_session(o, context);
  for (const AxisKind* kind : kinds) session->home(session->axis(*kind));
  return finish(*session, o);
}

// ---------------------------------------------------------------- move, jog

// One axis's part of a move or jog: the value as given, in the axis's base unit.
struct Request {
  const AxisKind* kind;
  double base_value;
};

std::vector<Request> requests_of(const RigOptions& o) {
  std::vector<Request> requests;
  if (!o.rail.empty()) requests.push_back({&kRail, parse_quantity(o.rail, kRail)});
  if (!o.turntable.empty()) requests.push_back({&kTurntable, parse_quantity(o.turntable, kTurntable)});
  return requests;
}

void check_soft_limits(const Session& session, const AxisSettings& axis, double target, std::string_view what) {
  if (target < axis.min_position || target > axis.max_position) {
    throw runtime_error(session.context(),
                        fmt::format("{}: {} to {} refused: outside the soft limits [{}, {}] {}", axis.name, what,
                                    position_text(axis, target), axis.min_position, axis.max_position, axis.unit));
  }
}

// Absolute (move) or relative (jog) moves of the requested axes, together.
int run_motion(const RigOptions& o, const std::vector<Request>& requests, bool relative, const std::string& context) {
  const auto held = open_session(o, context);
  Session& session = *held;
  // Everything is checked before anything moves.
  std::vector<double> values;
  for (const Request& r : requests) {
    Axis& axis = session.axis(*r.kind);
    const AxisSettings& settings = axis.settings();
    values.push_back(to_axis_units(r.base_value, *r.kind, settings, context));
    if (!relative) check_soft_limits(session, settings, values.back(), "move");
    const AxisStatus s = axis.status();
    if (!o.home && !s.homed) {
      throw runtime_error(context, fmt::format("{} is not homed: home it first, or pass --home to home it before the "
                                               "{} (a new process starts unhomed: an open-loop stepper loses its "
                                               "reference when the process that homed it ends)",
                                               settings.name, relative ? "jog" : "move"));
    }
    if (!o.home && s.state == AxisState::fault) {
      throw runtime_error(
          context, fmt::format("{} is in fault ({}); pass --home to clear it and home again", settings.name, s.fault));
    }
  }
  for (const Request& r : requests) {
    Axis& axis = session.axis(*r.kind);
    const AxisStatus s = axis.status();
    if (!s.homed || s.state == AxisState::fault) session.home(axis);
  }
  std::vector<Axis*> moving;
  for (std::size_t i = 0; i < requests.size(); ++i) {
    Axis& axis = session.axis(*requests[i].kind);
    session.prepare(axis, false);
    double target = values[i];
    if (relative) {
      target += axis.status().position;
      check_soft_limits(session, axis.settings(), target,
                        fmt::format("jog by {:+g} {}", values[i], axis.settings().unit));
    }
    try {
      axis.move_to(target);
    } catch (const AxisError& e) {
      throw runtime_error(context, e.what());
    }
    session.text() << fmt::format("{}: moving to {}\n", axis.settings().name, position_text(axis.settings(), target))
                   << std::flush;
    moving.push_back(&axis);
  }
  session.follow(moving, relative ? "jog" : "move");
  for (const Axis* axis : moving) {
    session.text() << fmt::format("{}: at {}\n", axis->settings().name,
                                  position_text(axis->settings(), axis->status().position));
  }
  return finish(session, o);
}

// ---------------------------------------------------------------- markerd's rig

// The command for a running markerd: values keep their units until the
// daemon says which unit its axis counts in.
int run_on_daemon(const RigOptions& o, DaemonRigRequest::Action action, bool relative, const std::string& context,
                  const SignalWatch* signals) {
  DaemonRigRequest request;
  request.action = action;
  request.context = context;
  request.socket = o.socket;
  request.json = o.json;
  request.home_axis = o.home_axis;
  request.relative = relative;
  request.home_first = o.home;
  request.emergency = o.emergency;
  request.wait = !o.no_wait;
  for (const Request& r : requests_of(o)) {
    const AxisKind* kind = r.kind;
    const double base_value = r.base_value;
    request.targets.push_back({kind->name, [kind, base_value, context](const std::string& unit) {
                                 const auto scale = scale_of(kind->units, unit);
                                 if (!scale) {
                                   throw runtime_error(context, fmt::format("markerd's {} counts in '{}'; markerctl "
                                                                            "rig converts to {} only",
                                                                            kind->name, unit, unit_list(kind->units)));
                                 }
                                 return base_value / *scale;
                               }});
  }
  if (signals != nullptr) {
    request.wait_for_signal = [signals](std::chrono::milliseconds timeout) { return signals->wait(timeout).signal; };
  }
  return run_rig_on_daemon(request);
}

// ---------------------------------------------------------------- the command

struct RigSubcommands {
  CLI::App* status;
  CLI::App* home;
  CLI::App* move;
  CLI::App* jog;
  CLI::App* stop;
};

// Without --config: the command goes to markerd's rig. Signals are watched
// only while a command waits for motion.
int run_markerd_rig(const RigOptions& o, const RigSubcommands& sub) {
  using Action = DaemonRigRequest::Action;
  const bool waits = !o.no_wait && !sub.status->parsed();
  std::optional<SignalWatch> signals;
  if (waits) signals.emplace();
  const SignalWatch* watch = signals ? &*signals : nullptr;
  if (sub.status->parsed()) return run_on_daemon(o, Action::status, false, "rig status", watch);
  if (sub.home->parsed()) return run_on_daemon(o, Action::home, false, "rig home", watch);
  if (sub.stop->parsed()) return run_on_daemon(o, Action::stop, false, "rig stop", watch);
  const bool jogging = sub.jog->parsed();
  const std::string context = jogging ? "rig jog" : "rig move";
  if (requests_of(o).empty()) {
    throw usage_error(context, jogging ? "give --rail or --turntable (the interactive jog needs --config: it drives "
                                         "the rig itself)"
                                       : "give --rail, --turntable or both");
  }
  return run_on_daemon(o, Action::move, jogging, context, watch);
}

// With --config: markerctl builds the rig and drives it itself.
int run_configured_rig(const RigOptions& o, const RigSubcommands& sub) {
  if (o.no_wait) throw usage_error("rig", "--no-wait is for markerd's rig (without --config)");
  if (sub.stop->parsed()) {
    throw usage_error("rig stop",
                      "stop is for markerd's rig (without --config); a rig driven with --config stops when its "
                      "command ends");
  }
  if (sub.status->parsed()) return run_status(o, "rig status");
  if (sub.home->parsed()) return run_home(o, "rig home");
  if (sub.move->parsed()) {
    const auto requests = requests_of(o);
    if (requests.empty()) throw usage_error("rig move", "give --rail, --turntable or both");
    return run_motion(o, requests, false, "rig move");
  }
  if (sub.jog->parsed()) {
    const auto requests = requests_of(o);
    if (!requests.empty()) return run_motion(o, requests, true, "rig jog");
    if (o.home) throw usage_error("rig jog", "--home goes with --rail or --turntable");
    if (isatty(STDIN_FILENO) == 0 || isatty(STDOUT_FILENO) == 0) {
      throw usage_error("rig jog", "give --rail or --turntable, or run it on a terminal for the interactive jog");
    }
    Session session(o.config, "rig jog");
    const int status = run_interactive_jog(session);
    // The jog itself is the terminal's; --json gives the state it ended in.
    if (o.json) std::cout << json_line(status_document(session, o.config)) << '\n' << std::flush;
    return status;
  }
  throw usage_error("rig", "no rig command given (status, home, move, jog or stop)");
}

// Routes the rig's and the drives' log lines to stderr, so that stdout holds
// only the command's output (status --json is one JSON line).
void log_to_stderr() {
  static std::once_flag once;
  std::call_once(once, [] {
    auto logger = spdlog::stderr_color_mt("markerctl-rig");
    logger->set_pattern("markerctl: rig: [%l] %v");
    spdlog::set_default_logger(std::move(logger));
  });
}

}  // namespace

void add_rig_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<RigOptions>();
  CLI::App* app = parent.add_subcommand(
      "rig", "Bring up a rig: status, homing, moves and jogging, from its config or through markerd");
  app->require_subcommand(1);
  app->footer(
      "Runs one command on the rig a config describes (config/rig-*.toml, docs/rig.md), then disables the axes.\n"
      "The rig's devices are locked first: a command refuses to run while another process (markerd, which\n"
      "holds them while it runs, or another markerctl rig) holds them, and names that process. Values take a\n"
      "unit: the rail mm, cm or m, the turntable deg or rad. A new process starts with the axes unhomed (an\n"
      "open-loop stepper loses its reference when the process that drove it ends): pass --home to move or jog\n"
      "to home what is not homed.\n"
      "An interrupt (Ctrl-C, SIGTERM) stops the motion with a ramp, disables the axes and exits with 1.\n"
      "Exit status: 0 done, 1 refused or failed (a fault, the devices in use, an interrupt), 2 bad usage.\n"
      "Without --config, status, home, move, jog --rail/--turntable and stop go to a running markerd (its\n"
      "rig, through the control socket: --socket, else $MARKERD_SOCKET, else /run/markerd/control.sock);\n"
      "the axes stay as markerd keeps them, and an interrupt while waiting stops the rig.");
  app->add_option("--config", o->config, "The rig config (TOML with a [rig] table); without it, markerd's rig")
      ->type_name("FILE");
  app->add_option("--socket", o->socket, "markerd's control socket, for markerd's rig (no --config)")
      ->type_name("PATH");

  const char* json_help =
      "Once done, the rig as status --json shows it, one JSON line (the progress goes to standard error)";
  CLI::App* status = app->add_subcommand("status", "Each axis's state, position and inputs, and the ground truth");
  status->add_flag("--json", o->json, "One JSON object instead of text");
  status->fallthrough();

  CLI::App* home = app->add_subcommand("home", "Home the axes (both by default, the rail first) and wait");
  home->add_option("--axis", o->home_axis, "Only this axis")
      ->type_name("rail|turntable")
      ->check(CLI::IsMember({"rail", "turntable"}));
  home->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the homing has started");
  home->add_flag("--json", o->json, json_help);
  home->fallthrough();

  CLI::App* move = app->add_subcommand("move", "Move the axes to absolute positions and wait until settled");
  move->add_option("--rail", o->rail, "Rail position (250mm, 25cm, 0.25m)")->type_name("LENGTH");
  move->add_option("--turntable", o->turntable, "Turntable angle (30deg, 0.5rad)")->type_name("ANGLE");
  move->add_flag("--home", o->home, "Home the axes that are not homed first");
  move->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the move has started");
  move->add_flag("--json", o->json, json_help);
  move->fallthrough();

  CLI::App* jog = app->add_subcommand(
      "jog", "Move the axes by relative steps; without --rail/--turntable on a terminal, jog interactively");
  jog->add_option("--rail", o->rail, "Rail step (+5mm, -1cm)")->type_name("LENGTH");
  jog->add_option("--turntable", o->turntable, "Turntable step (+2deg, -0.1rad)")->type_name("ANGLE");
  jog->add_flag("--home", o->home, "Home the axes that are not homed first");
  jog->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the move has started");
  jog->add_flag("--json", o->json, json_help);
  jog->footer(
      "Interactive keys: left/right arrows jog the rail, up/down the turntable; + and - change the step\n"
      "(0.1 mm / 0.05 deg up to 100 mm / 30 deg); h homes both axes; s stops; space is an emergency stop\n"
      "(the axes are disabled and must be homed again); q quits.");
  jog->fallthrough();

  CLI::App* stop = app->add_subcommand("stop", "markerd's rig: stop both axes (with a ramp) and wait until they rest");
  stop->add_flag("--emergency", o->emergency, "Stop at once and disable the axes (they must be homed again)");
  stop->add_flag("--no-wait", o->no_wait, "Return once the stop has been sent");
  stop->add_flag("--json", o->json, json_help);
  stop->fallthrough();

  const RigSubcommands sub{status, home, move, jog, stop};
  commands.push_back({app, [o, sub] {
                        log_to_stderr();
                        return o->config.empty() ? run_markerd_rig(*o, sub) : run_configured_rig(*o, sub);
                      }});
}

}  // namespace markerctl
