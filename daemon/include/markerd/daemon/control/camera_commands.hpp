#pragma once
// The camera's controls on the control socket (docs/control.md#camera):
//
//   camera.get  [names: [NAME, ...]]             every control (or those named): value, range, step, default, menu
//   camera.set  controls: {NAME: VALUE, ...}     sets them all or none; replies with each change
//
// Controls are read and set on the capture source's device while it
// streams (CaptureSource::read_controls, write_control), each value checked
// against the control's range first (camera_controls.hpp). Every change is
// logged with its old and new value, and recorded in the events of the
// sweep run going on, if there is one.

#include <functional>
#include <string>

#include "markerd/daemon/capture/capture_loop.hpp"
#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/daemon/control/control_server.hpp"

namespace markerd::daemon {

// Called with each change in words ("gain 100 -> 200"), for the records of
// a sweep run going on; may be empty.
using ControlChangeRecorder = std::function<void(const std::string& change)>;

// `source` and `capture` must outlive the server.
void register_camera_commands(ControlServer& server, CaptureSource& source, const CaptureLoop& capture,
                              ControlChangeRecorder record);

}  // namespace markerd::daemon
