#pragma once
// markerctl's commands that talk to a running markerd over its control
// socket (docs/control.md): status, detections, call, and `markerctl rig`
// without --config (cmd_rig.cpp parses its options and hands them here).

#include <chrono>
#include <functional>
#include <string>
#include <vector>

#include "common.hpp"

namespace markerctl {

void add_daemon_commands(CLI::App& parent, Commands& commands);

// The socket markerctl talks to: --socket when given, else $MARKERD_SOCKET,
// else /run/markerd/control.sock.
std::string control_socket_path(const std::string& option);

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
  std::string context;  // "rig move": the prefix of errors
  std::string socket;   // --socket, or empty
  bool json = false;              // status
  std::string home_axis;          // home: "rail", "turntable", or empty for both
  std::vector<DaemonRigTarget> targets;  // move
  bool relative = false;          // move: by the values (jog)
  bool home_first = false;        // move: home the axes that are not homed first
  bool emergency = false;         // stop
  bool wait = true;               // home, move, stop: until the axes are at rest
  // Sleeps up to the given time; returns the number of a signal that came
  // meanwhile, or 0. A signal while waiting stops the rig.
  std::function<int(std::chrono::milliseconds)> wait_for_signal;
};

int run_rig_on_daemon(const DaemonRigRequest& request);

}  // namespace markerctl
