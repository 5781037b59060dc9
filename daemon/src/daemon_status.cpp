#include "markerd/daemon/daemon_status.hpp"

#include <fmt/chrono.h>
#include <fmt/format.h>

#include <cmath>

#include "markerd/base/utc_time.hpp"
#include "markerd/daemon/control/rig_commands.hpp"
#include "markerd/daemon/daemon.hpp"

namespace markerd::daemon {

namespace {

double ms(std::chrono::nanoseconds d) { return static_cast<double>(d.count()) / 1e6; }

nlohmann::json to_json(const StageCounts& c) {
  return {{"in", c.in}, {"out", c.out}, {"dropped", c.dropped}, {"failed", c.failed}};
}

nlohmann::json to_json(const LatencySummary& l) {
  return {
      {"count", l.count}, {"p50_ms", ms(l.p50)}, {"p99_ms", ms(l.p99)}, {"max_ms", ms(l.max)}, {"mean_ms", ms(l.mean)}};
}

nlohmann::json to_json(const rig::AxisSnapshot& a) {
  return {{"position", a.position}, {"target", a.target},   {"state", rig::to_string(a.state)},
          {"homed", a.homed},       {"settled", a.settled}, {"fault", a.fault},
          {"moving", a.moving}};
}

}  // namespace

nlohmann::json to_json(const CaptureStatus& s) {
  nlohmann::json j = {{"state", to_string(s.state)}, {"source", s.source},   {"frames", s.frames},
                      {"dropped", s.dropped},        {"corrupt", s.corrupt}, {"stalls", s.stalls},
                      {"failures", s.failures},      {"reopens", s.reopens}};
  j["last_error"] = s.last_error.empty() ? nlohmann::json() : nlohmann::json(s.last_error);
  j["last_error_utc"] =
      s.last_error.empty() ? nlohmann::json() : nlohmann::json(format_utc(s.last_error_time, UtcForm::seconds));
  j["fps"] = s.fps ? nlohmann::json(std::round(*s.fps * 100) / 100) : nlohmann::json();
  if (s.last_frame_time.time_since_epoch().count() > 0 && s.frames > 0) {
    j["last_frame_age_ms"] = ms(std::chrono::steady_clock::now() - s.last_frame_time);
  } else {
    j["last_frame_age_ms"] = nullptr;
  }
  return j;
}

nlohmann::json to_json(const PipelineStats& s) {
  return {{"capture", to_json(s.capture)},
          {"detect", to_json(s.detect)},
          {"log", to_json(s.log)},
          {"dropped", s.dropped()},
          {"latency",
           {{"capture_to_detect", to_json(s.capture_to_detect)},
            {"detect", to_json(s.detect_duration)},
            {"capture_to_log", to_json(s.capture_to_log)}}},
          {"pool", {{"slots", s.pool_slots}, {"free", s.pool_free}}}};
}

nlohmann::json to_json(const DetectionLogSinkStats& s) {
  nlohmann::json j = {{"lines", s.writer.lines},
                      {"bytes", s.writer.bytes},
                      {"fsyncs", s.writer.fsyncs},
                      {"files_opened", s.writer.files_opened},
                      {"tails_repaired", s.writer.tails_repaired},
                      {"write_errors", s.writer.write_errors},
                      {"lines_lost", s.lines_lost}};
  j["last_error"] = s.last_error.empty() ? nlohmann::json() : nlohmann::json(s.last_error);
  return j;
}

nlohmann::json to_json(const rig::RigSnapshot& s) {
  return {{"sequence", s.sequence},
          {"settled", s.settled()},
          {"rail", to_json(s.rail)},
          {"turntable", to_json(s.turntable)}};
}

nlohmann::json status_json(const Daemon& daemon) {
  nlohmann::json j;
  j["responsive"] = daemon.responsive();
  j["camera"] = to_json(daemon.capture().status());
  j["pipeline"] = to_json(daemon.pipeline().stats());
  j["pipeline"]["policy"] = daemon.pipeline().policy() == DropPolicy::live ? "live" : "lossless";
  j["pipeline"]["workers"] = daemon.pipeline().worker_count();
  const auto detect_fps = daemon.log().frame_rate();
  j["pipeline"]["detect_fps"] = detect_fps ? nlohmann::json(std::round(*detect_fps * 100) / 100) : nlohmann::json();
  nlohmann::json log = to_json(daemon.log().stats());
  log["file"] = daemon.log().current_path();
  j["log"] = std::move(log);
  j["rig"] = daemon.rig() != nullptr ? rig_status_json(*daemon.rig()) : nlohmann::json();
  j["sweep"] = daemon.sweep() != nullptr ? sweep::to_json(daemon.sweep()->progress()) : nlohmann::json();
  j["control"] = {{"socket", daemon.control().settings().socket_path.string()},
                  {"clients", daemon.control().stats().clients}};
  if (const WebServer* web = daemon.web()) {
    j["web"] = {{"url", web->url()}, {"listen_loopback", web->settings().loopback()}, {"previews", web->previews()}};
  } else {
    j["web"] = nullptr;
  }
  j["status"] = daemon.status_line();
  return j;
}

}  // namespace markerd::daemon
