#pragma once
// What the web page shows of a running markerd: its state.json, and where
// the last sweep run's report is.

#include <nlohmann/json.hpp>
#include <optional>

#include "markerd/daemon/web/web_server.hpp"

namespace markerd::daemon {

class Daemon;

// /state.json: `camera` (the capture loop), `pipeline` (frames detected and
// dropped), `frame` (the newest held frame: its number, age, detections and
// truth; null before the first), `rig` (as rig.status; null without a rig),
// `sweep` (as sweep.status; null without a rig), `report` (the last run's
// id, or null).
[[nodiscard]] nlohmann::json web_state_json(const Daemon& daemon);

// The newest run with a report: the sweep's current or last run, else the
// newest run directory (their names start with the UTC time) that has
// report/report.md. Nothing without a rig, or before any run has one.
[[nodiscard]] std::optional<WebSources::Report> last_report(const Daemon& daemon);

}  // namespace markerd::daemon
