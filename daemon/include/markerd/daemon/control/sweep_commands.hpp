#pragma once
// The sweep's commands on the control socket (docs/control.md#sweep):
//
//   sweep.check   plan: TOML text [, source: name]   the dry run: points, problems, estimated duration
//   sweep.start   plan: TOML text [, source: name]   starts a run; replies with its id and directory
//   sweep.status                                      state, step, progress, estimate, the last rate
//   sweep.pause   sweep.resume   sweep.abort [reason: text]
//
// The plan travels as text: markerd (its own user, ProtectHome=) may not be
// able to read the file where the operator keeps it, and the run's records
// keep the text as it ran.

#include "markerd/daemon/control/control_server.hpp"
#include "markerd/sweep/runner.hpp"

namespace markerd::daemon {

// `runner` must outlive the server.
void register_sweep_commands(ControlServer& server, sweep::SweepRunner& runner);

}  // namespace markerd::daemon
