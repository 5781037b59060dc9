// markerctl's commands that talk to a running markerd over its control
// socket: status, detections (follow the detection log live), call (any
// command, raw), and `markerctl rig ...` without --config. The protocol is
// docs/control.md; the client side is markerd::daemon::ControlClient.

#include "cmd_daemon.hpp"

#include <signal.h>
#include <unistd.h>

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdlib>
#include <initializer_list>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "live_line.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/control/control_server.hpp"

namespace markerctl {

using markerd::daemon::ControlClient;
using markerd::daemon::ControlClientError;
using nlohmann::json;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

std::string control_socket_path(const std::string& option) {
  if (!option.empty()) return option;
  if (const char* env = std::getenv("MARKERD_SOCKET"); env != nullptr && *env != '\0') return env;
  return markerd::daemon::kDefaultControlSocket;
}

namespace {

using Daemon = DaemonConnection;

// ---------------------------------------------------------------- status

// Numbers from a status document that may lack them (an older markerd, a
// daemon without a rig): the path's value, or `fallback`.
const json& at(const json& document, std::initializer_list<const char*> path) {
  static const json missing;
  const json* j = &document;
  for (const char* key : path) {
    if (!j->is_object() || !j->contains(key)) return missing;
    j = &(*j)[key];
  }
  return *j;
}

std::string text_of(const json& value, std::string_view fallback = "?") {
  if (value.is_string()) return value.get<std::string>();
  if (value.is_null()) return std::string(fallback);
  return value.dump(-1, ' ', false, json::error_handler_t::replace);
}

std::string number_text(const json& value, int decimals) {
  return value.is_number() ? fmt::format("{:.{}f}", value.get<double>(), decimals) : "?";
}

// "1 client", "3 clients", "? clients" for a count the status lacks.
std::string counted(const json& count, std::string_view noun) {
  return fmt::format("{} {}{}", text_of(count), noun, count.is_number() && count.get<double>() == 1 ? "" : "s");
}

// True where `key` is there and true: a status from another version may
// lack any key, and the summary reads every one through at().
bool flag(const json& document, const char* key) {
  const json& value = at(document, {key});
  return value.is_boolean() && value.get<bool>();
}

std::string axis_summary(const json& axis) {
  std::string text = fmt::format("{} {}, {}", number_text(at(axis, {"position"}), 3), text_of(at(axis, {"unit"}), ""),
                                 text_of(at(axis, {"state"})));
  text += flag(axis, "homed") ? ", homed" : ", not homed";
  if (flag(axis, "settled")) text += ", settled";
  if (const json& fault = at(axis, {"fault"}); !fault.is_null()) text += "; fault: " + text_of(fault);
  return text;
}

// What an operator looks at first, a line a part, on one screen: the daemon,
// the camera and the detector with their frame rates, the pipeline, the
// log, the rig, the sweep, the socket. The whole document is --json's.
std::string status_summary(const json& s) {
  std::string out;
  const auto line = [&out](std::string_view label, const std::string& text) {
    out += fmt::format("{:<10} {}\n", label, text);
  };
  line("markerd", at(s, {"responsive"}).is_boolean() && !flag(s, "responsive") ? "NOT responsive" : "responsive");

  const json& camera = at(s, {"camera"});
  std::string camera_text =
      fmt::format("{}, {}; {} fps, {} frames", text_of(at(camera, {"state"})), text_of(at(camera, {"source"})),
                  number_text(at(camera, {"fps"}), 1), text_of(at(camera, {"frames"})));
  if (const json& corrupt = at(camera, {"corrupt"}); corrupt.is_number() && corrupt.get<double>() > 0) {
    camera_text += fmt::format(", {} corrupt", text_of(corrupt));
  }
  // The frame rate says the frames come; the age of the last one is worth a
  // word only when it says they have stopped.
  if (const json& age = at(camera, {"last_frame_age_ms"}); age.is_number() && age.get<double>() >= 1000) {
    camera_text += fmt::format(", last frame {:.1f} s ago", age.get<double>() / 1000);
  }
  line("camera", camera_text);
  if (const json& error = at(camera, {"last_error"}); !error.is_null()) line("", "last error: " + text_of(error));

  const json& pipeline = at(s, {"pipeline"});
  line("detector",
       fmt::format("{} fps, {} frames, {} failed; {} ms p50, {} ms p99", number_text(at(pipeline, {"detect_fps"}), 1),
                   text_of(at(pipeline, {"detect", "out"})), text_of(at(pipeline, {"detect", "failed"})),
                   number_text(at(pipeline, {"latency", "detect", "p50_ms"}), 1),
                   number_text(at(pipeline, {"latency", "detect", "p99_ms"}), 1)));
  line("pipeline", fmt::format("{}, {}; {} dropped", text_of(at(pipeline, {"policy"})),
                               counted(at(pipeline, {"workers"}), "worker"), text_of(at(pipeline, {"dropped"}))));

  const json& log = at(s, {"log"});
  std::string log_text = fmt::format("{}; {} lines", text_of(at(log, {"file"}), "none"), text_of(at(log, {"lines"})));
  if (const json& lost = at(log, {"lines_lost"}); lost.is_number() && lost.get<double>() > 0) {
    log_text += fmt::format(", {} lost", text_of(lost));
  }
  line("log", log_text);
  if (const json& error = at(log, {"last_error"}); !error.is_null()) line("", "last error: " + text_of(error));

  const json& rig = at(s, {"rig"});
  if (!rig.is_object()) {
    line("rig", "none");
  } else {
    line("rail", axis_summary(at(rig, {"rail"})));
    line("turntable", axis_summary(at(rig, {"turntable"})));
    line("truth", fmt::format("distance {} m, yaw {} deg", number_text(at(rig, {"ground_truth", "distance_m"}), 4),
                              number_text(at(rig, {"ground_truth", "yaw_deg"}), 3)));
  }

  const json& sweep = at(s, {"sweep"});
  if (!sweep.is_object()) {
    line("sweep", "none (markerd has no rig)");
  } else if (sweep.value("state", std::string()) == "idle") {
    line("sweep", "no run since markerd started");
  } else {
    line("sweep", fmt::format("run {}", text_of(at(sweep, {"run_id"}))));
    // Within the 80 columns of the screen, the label's 11 taken; the reason
    // on a line of its own, whole.
    json progress = sweep;
    progress.erase("reason");
    line("", sweep_progress_line(progress, 69));
    if (const json& reason = at(sweep, {"reason"}); reason.is_string() && !reason.get<std::string>().empty()) {
      line("", text_of(at(sweep, {"state"})) + ": " + text_of(reason));
    }
  }
  line("control",
       fmt::format("{}, {}", text_of(at(s, {"control", "socket"})), counted(at(s, {"control", "clients"}), "client")));
  return out;
}

int run_status(const std::string& socket, bool as_json) {
  Daemon daemon(socket, "status");
  const json status = daemon.call({{"cmd", "status"}});
  if (as_json) {
    std::cout << status.dump(-1, ' ', false, json::error_handler_t::replace) << '\n';
  } else {
    std::cout << status_summary(status);
  }
  return 0;
}

// ---------------------------------------------------------------- detections

int run_detections(const std::string& socket, std::uint64_t count) {
  Daemon daemon(socket, "detections");
  (void)daemon.call({{"cmd", "detections"}});
  std::uint64_t printed = 0;
  while (count == 0 || printed < count) {
    const auto line = daemon.read_line(std::nullopt);
    if (!line) continue;
    // The server's own lines in a stream are objects whose first member is
    // "event"; the detection log's lines never are.
    if (line->starts_with(R"({"event":)")) {
      const json event = json::parse(*line, nullptr, false);
      if (event.is_object() && event.value("event", std::string()) == "dropped") {
        std::cout.flush();
        std::cerr << fmt::format("markerctl: detections: {} lines dropped (this reader fell behind)\n",
                                 event.value("lines", std::uint64_t{0}))
                  << std::flush;
      }
      continue;
    }
    // Each line as it comes: a pipe to jq or grep sees it at once.
    std::cout << *line << '\n' << std::flush;
    ++printed;
  }
  return 0;
}

// ---------------------------------------------------------------- call

int run_call(const std::string& socket, const std::string& command, const std::string& arguments_option,
             double timeout_s) {
  // More than markerd takes in one request line is refused here.
  const std::string arguments =
      arguments_option == "-"
          ? read_standard_input(markerd::daemon::ControlSettings{}.max_request_bytes, "the arguments", "call")
          : arguments_option;
  json request = json::object();
  if (!arguments.empty()) {
    try {
      request = json::parse(arguments);
    } catch (const json::parse_error& e) {
      std::string_view why = e.what();
      if (const auto end = why.find("] "); end != std::string_view::npos) why.remove_prefix(end + 2);
      throw usage_error("call", fmt::format("the arguments are not JSON: {}", why));
    }
    if (!request.is_object()) {
      throw usage_error(
          "call",
          fmt::format(R"(the arguments must be a JSON object, e.g. '{{"axis": "rail"}}', got '{}')", arguments));
    }
  }
  request["cmd"] = command;
  Daemon daemon(socket, "call " + command);
  std::string line;
  const json reply = daemon.raw_call(
      request, std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::duration<double>(timeout_s)), &line);
  std::cout << line << '\n';
  if (!reply.value("ok", false)) throw runtime_error(daemon.context(), reply.value("error", std::string("refused")));
  return 0;
}

// ---------------------------------------------------------------- rig

std::string signal_text(int signal) {
  const char* abbrev = sigabbrev_np(signal);
  return abbrev != nullptr ? fmt::format("SIG{}", abbrev) : fmt::format("signal {}", signal);
}

std::string position_text(const json& axis, std::string_view key = "position") {
  return fmt::format("{:.3f} {}", axis.value(key, 0.0), axis.value("unit", std::string()));
}

std::string inputs_text(const json& inputs) {
  std::string text;
  for (const char* name : {"limit_min", "limit_max", "home", "estop"}) {
    if (!inputs.value(name, false)) continue;
    if (!text.empty()) text += ' ';
    text += name;
  }
  return text.empty() ? "none active" : text + " active";
}

bool in_motion(const json& axis) { return axis.value("moving", false); }

class DaemonRig {
 public:
  explicit DaemonRig(const DaemonRigRequest& request) : request_(request), daemon_(request.socket, request.context) {}

  // Where the command's lines in words go: standard error when standard
  // output is the command's JSON (--json).
  [[nodiscard]] std::ostream& text() const { return request_.json ? std::cerr : std::cout; }
  [[nodiscard]] int text_fd() const { return request_.json ? STDERR_FILENO : STDOUT_FILENO; }

  // The end of home, move and stop: with --json, the rig as rig.status
  // shows it now.
  int finish() {
    if (request_.json) std::cout << status().dump(-1, ' ', false, json::error_handler_t::replace) << '\n' << std::flush;
    return 0;
  }

  json status() { return daemon_.call({{"cmd", "rig.status"}}); }
  json call(const json& request) { return daemon_.call(request); }

  // "rail at 250.000 mm, turntable at 30.000 deg"
  std::string positions(const json& status) {
    return fmt::format("rail at {}, turntable at {}", position_text(status["rail"]),
                       position_text(status["turntable"]));
  }

  void print_ground_truth(const json& status) {
    const json& truth = status["ground_truth"];
    text() << fmt::format("ground truth: distance {:.4f} m, yaw {:.3f} deg\n", truth.value("distance_m", 0.0),
                          truth.value("yaw_deg", 0.0));
  }

  // Waits until every axis in `axes` has settled (or, for a stop, is at
  // rest), printing progress every second. A fault ends it with an error
  // naming the axis and the cause; a signal stops the rig.
  json follow(const std::vector<std::string>& axes, std::string_view doing, bool rest_is_enough = false) {
    // On a terminal the progress is one line redrawn in place; a pipe or a
    // file gets only the lines before and after.
    LiveLine live(text(), text_fd());
    auto next_progress = Clock::now();
    std::vector<std::optional<Clock::time_point>> idle_since(axes.size());
    for (;;) {
      const json s = status();
      bool done = true;
      for (std::size_t i = 0; i < axes.size(); ++i) {
        const json& a = s[axes[i]];
        const std::string state = a.value("state", std::string());
        if (!a["fault"].is_null()) {
          throw runtime_error(request_.context,
                              fmt::format("{}: {} failed: {}", axes[i], doing, a["fault"].get<std::string>()));
        }
        if (rest_is_enough ? !in_motion(a) : a.value("settled", false)) continue;
        if (state == "disabled") {
          throw runtime_error(request_.context, fmt::format("{}: disabled while {}", axes[i], doing));
        }
        done = false;
        // Idle but not settled: settling, or (a closed-loop drive) drifting
        // outside its deadband; the second must not hang.
        if (state != "idle") {
          idle_since[i].reset();
        } else if (!idle_since[i]) {
          idle_since[i] = Clock::now();
        } else if (Clock::now() - *idle_since[i] > 15s) {
          throw runtime_error(request_.context, fmt::format("{}: did not settle at {} (at {})", axes[i],
                                                            position_text(a, "target"), position_text(a)));
        }
      }
      if (done) return s;
      if (live.on_terminal() && Clock::now() >= next_progress) {
        next_progress = Clock::now() + 200ms;
        std::vector<std::string> parts;
        for (const std::string& name : axes) {
          const json& a = s[name];
          const std::string state = a.value("state", std::string());
          parts.push_back(fmt::format("{}: {}, at {}", name,
                                      a.value("settled", false) ? "settled"
                                      : state == "idle"         ? "settling"
                                                                : state,
                                      position_text(a)));
        }
        live.show(parts, " | ");
      }
      const int signal = request_.wait_for_signal ? request_.wait_for_signal(50ms) : 0;
      if (signal == 0 && !request_.wait_for_signal) std::this_thread::sleep_for(50ms);
      if (signal != 0) {
        live.clear();
        interrupted(signal);
      }
    }
  }

  // An interrupt while markerctl waits: the rig is stopped with a ramp (a
  // second interrupt, or a stop that does not end, makes it an emergency
  // stop), and the command fails.
  [[noreturn]] void interrupted(int signal) {
    std::cout << std::flush;
    std::cerr << fmt::format("markerctl: {}: {}: stopping the rig\n", request_.context, signal_text(signal))
              << std::flush;
    (void)call({{"cmd", "rig.stop"}});
    bool emergency = false;
    const auto deadline = Clock::now() + 30s;
    json s = status();
    while (in_motion(s["rail"]) || in_motion(s["turntable"])) {
      const int again = request_.wait_for_signal ? request_.wait_for_signal(50ms) : 0;
      if (again != 0 || Clock::now() > deadline) {
        emergency = true;
        (void)call({{"cmd", "rig.stop"}, {"emergency", true}});
        s = status();
        break;
      }
      s = status();
    }
    throw runtime_error(request_.context, fmt::format("interrupted by {}: {} ({})", signal_text(signal),
                                                      emergency ? "emergency stop" : "rig stopped", positions(s)));
  }

 private:
  const DaemonRigRequest& request_;
  Daemon daemon_;
};

int rig_status(DaemonRig& rig, const DaemonRigRequest& request) {
  const json s = rig.status();
  if (request.json) {
    std::cout << s.dump(-1, ' ', false, json::error_handler_t::replace) << '\n';
    return 0;
  }
  for (const char* name : {"rail", "turntable"}) {
    const json& a = s[name];
    std::cout << fmt::format("{:<10} {}, {}{}: position {}, target {}; inputs: {}\n", name,
                             a.value("state", std::string()), a.value("homed", false) ? "homed" : "not homed",
                             a.value("settled", false) ? ", settled" : "", position_text(a), position_text(a, "target"),
                             inputs_text(a["inputs"]));
    if (!a["fault"].is_null()) std::cout << fmt::format("{:<10} fault: {}\n", "", a["fault"].get<std::string>());
  }
  rig.print_ground_truth(s);
  return 0;
}

void home_and_follow(DaemonRig& rig, const std::vector<std::string>& axes, bool wait) {
  const json axis = axes.size() == 1 ? json(axes.front()) : json("both");
  (void)rig.call({{"cmd", "rig.home"}, {"axis", axis}});
  for (const std::string& name : axes) rig.text() << fmt::format("{}: homing\n", name) << std::flush;
  if (!wait) return;
  const json s = rig.follow(axes, "homing");
  for (const std::string& name : axes) {
    rig.text() << fmt::format("{}: homed at {}\n", name, position_text(s[name])) << std::flush;
  }
}

int rig_home(DaemonRig& rig, const DaemonRigRequest& request) {
  std::vector<std::string> axes;
  if (request.home_axis.empty() || request.home_axis == "rail") axes.emplace_back("rail");
  if (request.home_axis.empty() || request.home_axis == "turntable") axes.emplace_back("turntable");
  home_and_follow(rig, axes, request.wait);
  if (request.wait) rig.print_ground_truth(rig.status());
  return rig.finish();
}

int rig_move(DaemonRig& rig, const DaemonRigRequest& request) {
  json s = rig.status();
  json move = {{"cmd", "rig.move"}, {"relative", request.relative}};
  std::vector<std::string> axes;
  std::vector<std::string> to_home;
  for (const DaemonRigTarget& target : request.targets) {
    const json& a = s[target.axis];
    move[target.axis] = target.in_unit(a.value("unit", std::string()));
    axes.push_back(target.axis);
    if (request.home_first && (!a.value("homed", false) || !a["fault"].is_null())) to_home.push_back(target.axis);
  }
  // Homing first is markerctl's doing, not the daemon's: a command to the
  // daemon starts one thing and returns.
  if (!to_home.empty()) home_and_follow(rig, to_home, true);
  const json reply = rig.call(move);
  for (const std::string& name : axes) {
    rig.text() << fmt::format("{}: moving to {:.3f} {}\n", name, reply["moving"].value(name, 0.0),
                              s[name].value("unit", std::string()))
               << std::flush;
  }
  if (!request.wait) return rig.finish();
  s = rig.follow(axes, request.relative ? "jog" : "move");
  for (const std::string& name : axes) rig.text() << fmt::format("{}: at {}\n", name, position_text(s[name]));
  rig.print_ground_truth(s);
  return rig.finish();
}

int rig_stop(DaemonRig& rig, const DaemonRigRequest& request) {
  const json reply = rig.call({{"cmd", "rig.stop"}, {"emergency", request.emergency}});
  if (request.emergency) {
    rig.text() << "emergency stop: both axes disabled; home them again (markerctl rig home)\n" << std::flush;
  } else if (reply["stopping"].empty()) {
    rig.text() << "nothing was moving\n" << std::flush;
  } else {
    std::vector<std::string> names = reply["stopping"].get<std::vector<std::string>>();
    for (const std::string& name : names) rig.text() << fmt::format("{}: stopping\n", name) << std::flush;
    if (request.wait) (void)rig.follow(names, "stop", true);
  }
  rig.text() << rig.positions(rig.status()) << '\n';
  return rig.finish();
}

}  // namespace

int run_rig_on_daemon(const DaemonRigRequest& request) {
  DaemonRig rig(request);
  switch (request.action) {
    case DaemonRigRequest::Action::status: return rig_status(rig, request);
    case DaemonRigRequest::Action::home: return rig_home(rig, request);
    case DaemonRigRequest::Action::move: return rig_move(rig, request);
    case DaemonRigRequest::Action::stop: return rig_stop(rig, request);
  }
  return exit_runtime;
}

void add_daemon_commands(CLI::App& parent, Commands& commands) {
  const char* socket_help = "markerd's control socket (default: $MARKERD_SOCKET, else /run/markerd/control.sock)";
  const std::string access_footer =
      "Talks to a running markerd over its control socket (docs/control.md). Access is for the socket's\n"
      "group (the config's [control] group): run as a member of it.";

  struct StatusOptions {
    std::string socket;
    bool json = false;
  };
  auto status_options = std::make_shared<StatusOptions>();
  CLI::App* status = parent.add_subcommand("status", "What markerd is doing: capture, detection, logs and the rig");
  status->add_option("--socket", status_options->socket, socket_help)->type_name("PATH");
  status->add_flag("--json", status_options->json, "The whole status document as one JSON object");
  status->footer(access_footer);
  commands.push_back({status, [status_options] { return run_status(status_options->socket, status_options->json); }});

  struct DetectionsOptions {
    std::string socket;
    std::uint64_t count = 0;
  };
  auto detections_options = std::make_shared<DetectionsOptions>();
  CLI::App* detections =
      parent.add_subcommand("detections", "Follow the detection log live: one JSON line per frame, as it is logged");
  detections->add_option("--socket", detections_options->socket, socket_help)->type_name("PATH");
  detections->add_option("--count", detections_options->count, "Stop after N lines (default: follow until stopped)")
      ->type_name("N");
  detections->footer(access_footer +
                     "\nLines are the detection log's (docs/detection-log.md). A reader slower than the daemon\n"
                     "loses lines rather than holding it up: stderr then says how many.");
  commands.push_back({detections, [detections_options] {
                        return run_detections(detections_options->socket, detections_options->count);
                      }});

  struct CallOptions {
    std::string socket;
    std::string command;
    std::string arguments;
    double timeout_s = 10;
  };
  auto call_options = std::make_shared<CallOptions>();
  CLI::App* call = parent.add_subcommand("call", "Send markerd one command and print its reply (raw protocol)");
  call->add_option("command", call_options->command, "The command (markerctl call help lists them)")
      ->type_name("CMD")
      ->required();
  call->add_option("arguments", call_options->arguments,
                   "Its arguments as a JSON object; - reads them from standard input")
      ->type_name("JSON-ARGS");
  call->add_option("--socket", call_options->socket, socket_help)->type_name("PATH");
  call->add_option("--timeout", call_options->timeout_s, "Seconds to wait for the reply (default 10)")
      ->type_name("SECONDS")
      ->check(CLI::PositiveNumber);
  call->footer(access_footer +
               "\nPrints the reply line as it came; exit 1 when it says \"ok\": false. Example:\n"
               "  markerctl call rig.move '{\"rail\": 250, \"turntable\": 30}'");
  commands.push_back({call, [call_options] {
                        return run_call(call_options->socket, call_options->command, call_options->arguments,
                                        call_options->timeout_s);
                      }});
}

}  // namespace markerctl
