#pragma once
// markerctl's commands that talk to a running markerd over its control
// socket (docs/control.md): status, detections, call, and `markerctl rig`
// without --config (cmd_rig.cpp parses its options and hands them here).

#include <chrono>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common.hpp"
#include "markerd/daemon/control/control_client.hpp"

namespace markerctl {

void add_daemon_commands(CLI::App& parent, Commands& commands);

// A sweep's progress (sweep.status's reply) on one line: the bar, the step,
// the phase, the last rate, the time left, the reason (cmd_sweep.cpp). In
// fewer `columns` than it takes, the bar narrows and parts are left out,
// the reason, the rate, the phase and the bar first, so that the steps done,
// the step in hand and the time left stay.
std::string sweep_progress_line(const nlohmann::json& progress, std::size_t columns = std::string::npos);

// The socket markerctl talks to: --socket when given, else $MARKERD_SOCKET,
// else /run/markerd/control.sock.
std::string control_socket_path(const std::string& option);

// A connection to markerd for one markerctl command: errors carry the
// command's name ("markerctl: status: cannot connect to ...").
class DaemonConnection {
 public:
  DaemonConnection(const std::string& socket_option, std::string context) : context_(std::move(context)) {
    try {
      client_.emplace(control_socket_path(socket_option));
    } catch (const markerd::daemon::ControlClientError& e) {
      throw runtime_error(context_, e.what());
    }
  }

  // The reply of a command that must succeed, without "id" and "ok".
  nlohmann::json call(nlohmann::json request, std::chrono::milliseconds timeout = std::chrono::seconds(10)) {
    nlohmann::json reply = raw_call(std::move(request), timeout);
    if (!reply.value("ok", false)) throw runtime_error(context_, reply.value("error", std::string("refused")));
    reply.erase("id");
    reply.erase("ok");
    return reply;
  }

  // The reply as it came, whatever "ok" says.
  nlohmann::json raw_call(nlohmann::json request, std::chrono::milliseconds timeout = std::chrono::seconds(10),
                          std::string* line = nullptr) {
    try {
      return client_->call(std::move(request), timeout, line);
    } catch (const markerd::daemon::ControlClientError& e) {
      throw runtime_error(context_, e.what());
    }
  }

  std::optional<std::string> read_line(std::optional<std::chrono::milliseconds> timeout) {
    try {
      return client_->read_line(timeout);
    } catch (const markerd::daemon::ControlClientError& e) {
      throw runtime_error(context_, e.what());
    }
  }

  [[nodiscard]] const std::string& context() const { return context_; }

 private:
  std::string context_;
  std::optional<markerd::daemon::ControlClient> client_;
};

// One axis's part of `markerctl rig move|jog` sent to markerd.
struct DaemonRigTarget {
  std::string axis;  // "rail", "turntable"
  // The value as given, converted to the unit the daemon's axis reports
  // ("mm", "deg"); a CommandError when it does not convert.
  std::function<double(const std::string& axis_unit)> in_unit;
};

struct DaemonRigRequest {
  enum class Action { status, home, move, stop };
  Action action = Action::status;
  std::string context;                   // "rig move": the prefix of errors
  std::string socket;                    // --socket, or empty
  bool json = false;                     // status; home, move, stop: the rig once done, as JSON
  std::string home_axis;                 // home: "rail", "turntable", or empty for both
  std::vector<DaemonRigTarget> targets;  // move
  bool relative = false;                 // move: by the values (jog)
  bool home_first = false;               // move: home the axes that are not homed first
  bool emergency = false;                // stop
  bool wait = true;                      // home, move, stop: until the axes are at rest
  // Sleeps up to the given time; returns the number of a signal that came
  // meanwhile, or 0. A signal while waiting stops the rig.
  std::function<int(std::chrono::milliseconds)> wait_for_signal;
};

int run_rig_on_daemon(const DaemonRigRequest& request);

}  // namespace markerctl
