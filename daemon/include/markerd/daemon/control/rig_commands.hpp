#pragma once
// The rig's commands on the control socket (docs/control.md#rig):
//
//   rig.status                                  the axes and the ground truth their positions imply
//   rig.home    [axis: rail|turntable|both]     clears a fault, enables and starts homing
//   rig.move    [rail: N] [turntable: N] [relative: bool]   starts moves, in the axes' units
//   rig.stop    [emergency: bool]               a controlled stop, or an emergency stop
//   rig.enable  [axis: ...]   rig.disable [axis: ...]
//
// Every command starts what it asks for and returns: a move or a homing runs
// on the axes' own threads and rig.status shows how it goes. A command
// that moves more than one axis checks them all before it starts any.

#include <nlohmann/json.hpp>

#include "markerd/daemon/control/control_server.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

// `rig` must outlive the server.
void register_rig_commands(ControlServer& server, rig::Rig& rig);

// rig.status's reply: per axis its state, homed, settled, moving, fault
// (the cause, or null), position, target, unit, soft limits and inputs, as
// the axis reports them now; the ground truth of the two positions; and
// the sequence and age of the rig's latest snapshot.
[[nodiscard]] nlohmann::json rig_status_json(const rig::Rig& rig);

}  // namespace markerd::daemon
