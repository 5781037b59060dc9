#pragma once
// The control socket's `snapshot` (docs/control.md#snapshot): markerd's
// newest frame as an image in the reply line, base64 in JSON like every
// other reply, with what is known of it.
//
//   snapshot [format: png|jpeg|jpg|pgm] [annotate: bool]
//
// The frame comes from the LatestFrame slot and is encoded on the control
// server's thread, never the pipeline's.

#include <nlohmann/json.hpp>

#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/frame_annotation.hpp"
#include "markerd/daemon/latest_frame.hpp"

namespace markerd::daemon {

// `latest` must outlive the server.
void register_snapshot_command(ControlServer& server, const LatestFrame& latest, AnnotationContext context);

// What is known of a held frame, as `snapshot` replies and the web page's
// state.json has it: `frame` (copy, sequence, capture_utc, age_ms, width,
// height, status), `detections` (family, id, corners, margin, pose), `rig`
// (the snapshot stamped on the frame, or null), `truth` (or null).
[[nodiscard]] nlohmann::json held_frame_json(const HeldFrame& frame);

}  // namespace markerd::daemon
