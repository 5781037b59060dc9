#pragma once
// markerctl rig jog on a terminal: the arrow keys jog the rail and the
// turntable, + and - change the step, h homes, s stops, space is an
// emergency stop, q quits.

#include "rig_session.hpp"

namespace markerctl {

// Runs until q, an interrupt or an error; the terminal is restored whichever.
int run_interactive_jog(Session& session);

}  // namespace markerctl
