#include "markerd/daemon/web/web_state.hpp"

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "markerd/daemon/control/rig_commands.hpp"
#include "markerd/daemon/control/snapshot_command.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_status.hpp"

namespace markerd::daemon {

namespace fs = std::filesystem;

nlohmann::json web_state_json(const Daemon& daemon) {
  nlohmann::json j;
  j["camera"] = to_json(daemon.capture().status());
  const PipelineStats pipeline = daemon.pipeline().stats();
  j["pipeline"] = {{"detected", pipeline.detect.out},
                   {"failed", pipeline.detect.failed},
                   {"dropped", pipeline.dropped()},
                   {"policy", daemon.pipeline().policy() == DropPolicy::live ? "live" : "lossless"}};
  if (const auto frame = daemon.latest_frame().latest()) {
    j["frame"] = held_frame_json(*frame);
  } else {
    j["frame"] = nullptr;
  }
  j["rig"] = daemon.rig() != nullptr ? rig_status_json(*daemon.rig()) : nlohmann::json();
  j["sweep"] = daemon.sweep() != nullptr ? sweep::to_json(daemon.sweep()->progress()) : nlohmann::json();
  const auto report = last_report(daemon);
  j["report"] = report ? nlohmann::json{{"run_id", report->run_id}} : nlohmann::json();
  j["status"] = daemon.status_line();
  return j;
}

std::optional<WebSources::Report> last_report(const Daemon& daemon) {
  if (daemon.sweep() == nullptr) return std::nullopt;
  const auto has_report = [](const fs::path& run) {
    std::error_code ec;
    return !run.empty() && fs::is_regular_file(run / "report" / "report.md", ec);
  };
  const fs::path current = daemon.sweep()->progress().run_directory;
  if (has_report(current)) return WebSources::Report{current.filename().string(), current / "report"};
  // A run still going has no report yet: the one before it has.
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(daemon.config().sweep.directory / "runs", ec)) {
    if (entry.is_directory(ec)) names.push_back(entry.path().filename().string());
  }
  std::sort(names.rbegin(), names.rend());
  for (const std::string& name : names) {
    const fs::path run = daemon.config().sweep.directory / "runs" / name;
    if (has_report(run)) return WebSources::Report{name, run / "report"};
  }
  return std::nullopt;
}

}  // namespace markerd::daemon
