#include "run_checks.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <exception>

#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/records.hpp"

namespace markerd::soak {

namespace fs = std::filesystem;

std::optional<std::string> lock_directory_problem(const fs::path& directory, const fs::path& rig_config) {
  try {
    for (const rig::DeviceClaim& claim : rig::device_claims(rig::load_rig_config(rig_config))) {
      const fs::path file = rig::DeviceLock::file_for(claim, directory);
      if (!fs::exists(file)) {
        return fmt::format(
            "markerd did not lock {} in the soak's lock directory (no {}): it locks elsewhere, "
            "where the machine's own markerd or a markerctl rig session would meet it",
            claim.what, file.string());
      }
    }
  } catch (const std::exception& e) {
    return fmt::format("the rig's device locks cannot be checked: {}", e.what());
  }
  return std::nullopt;
}

namespace {

// A failure's cause without the parts that differ from run to run (paths,
// step numbers), so that causes can be counted.
std::string cause_kind(const std::string& reason) {
  for (const char* known : {"No space left on device", "simulated outage", "unplugged", "timed out", "fault_timeout"}) {
    if (reason.find(known) != std::string::npos) return known;
  }
  return reason.substr(0, 80);
}

void check_run(const fs::path& directory, const std::map<std::string, RunObservation>& seen, RunTotals& totals,
               std::vector<std::string>& problems) {
  const std::string id = directory.filename().string();
  const auto problem = [&](const std::string& what) { problems.push_back(fmt::format("run {}: {}", id, what)); };
  sweep::RunRecords records;
  try {
    records = sweep::read_run(directory);
  } catch (const std::exception& e) {
    problem(fmt::format("its records cannot be read: {}", e.what()));
    return;
  }
  ++totals.runs;
  const std::size_t steps = records.start.steps;
  totals.planned += steps;
  totals.recorded += records.points.size();
  if (records.torn_lines != 0) problem(fmt::format("{} torn line(s) in its records", records.torn_lines));

  // Every step exactly once, in order.
  std::vector<int> times(steps, 0);
  std::size_t highest = 0;
  for (std::size_t i = 0; i < records.points.size(); ++i) {
    const sweep::PointRecord& p = records.points[i];
    if (p.step >= steps) {
      problem(fmt::format("points.jsonl line {} holds step {}, beyond the plan's {} steps", i + 1, p.step, steps));
      continue;
    }
    if (++times[p.step] > 1) {
      ++totals.duplicates;
      problem(fmt::format("step {} recorded {} times (points.jsonl line {})", p.step, times[p.step], i + 1));
    } else if (p.step != i) {
      problem(fmt::format("points.jsonl line {} holds step {}, expected {}", i + 1, p.step, i));
    }
    highest = std::max(highest, p.step + 1);
    const auto wanted = static_cast<std::size_t>(records.start.plan.frames_per_point);
    if (p.frames.size() != wanted) {
      problem(fmt::format("step {} has {} frames, the plan asks for {}", p.step, p.frames.size(), wanted));
    }
  }
  for (std::size_t s = 0; s < highest; ++s) {
    if (times[s] == 0) {
      ++totals.missing;
      problem(fmt::format("step {} has no record, though later steps have", s));
    }
  }

  // How it ended, and that the records say so.
  const auto it = seen.find(id);
  const RunObservation* observed = it == seen.end() ? nullptr : &it->second;
  if (!records.stop) {
    ++totals.unended;
    problem(
        fmt::format("no stop record: the run never ended ({} of {} steps recorded{})", records.points.size(), steps,
                    observed && !observed->ended_as.empty()
                        ? fmt::format("; markerd had reported it {}: {}", observed->ended_as, observed->ended_reason)
                        : ""));
  } else {
    const sweep::RunStop& stop = *records.stop;
    const std::string status(sweep::to_string(stop.status));
    if (stop.steps_done != records.points.size()) {
      problem(fmt::format("its stop record says {} steps done, points.jsonl holds {}", stop.steps_done,
                          records.points.size()));
    }
    if (stop.status == sweep::ExitStatus::done) {
      ++totals.done;
      totals.planned_in_done += steps;
      if (records.points.size() != steps)
        problem(fmt::format("done with {} of {} steps recorded", records.points.size(), steps));
    } else {
      ++(stop.status == sweep::ExitStatus::failed ? totals.failed : totals.aborted);
      totals.not_measured += steps > records.points.size() ? steps - records.points.size() : 0;
      if (stop.reason.empty()) problem(fmt::format("{} without a cause in its stop record", status));
      if (stop.status == sweep::ExitStatus::failed) ++totals.failure_causes[cause_kind(stop.reason)];
    }
    if (observed && !observed->ended_as.empty() && observed->ended_as != status) {
      problem(fmt::format("markerd reported it {} ({}), but its stop record says {}", observed->ended_as,
                          observed->ended_reason, status));
    }
  }

  if (observed) {
    if (observed->most_steps_seen > records.points.size()) {
      problem(fmt::format("markerd reported {} steps done, the records now hold {}: recorded measurements were lost",
                          observed->most_steps_seen, records.points.size()));
    }
    // One restarted event per kill that cut the run off, at the step the records then held.
    std::vector<std::size_t> restarted_at;
    for (const sweep::RunEvent& e : records.events) {
      if (e.kind == "restarted") restarted_at.push_back(e.step);
    }
    totals.restarted_events += restarted_at.size();
    totals.cut_off_kills += observed->cut_at.size();
    if (restarted_at != observed->cut_at) {
      problem(fmt::format("restarted events at steps [{}], the kills cut it off at steps [{}]",
                          fmt::join(restarted_at, ", "), fmt::join(observed->cut_at, ", ")));
    }
  }
  for (const sweep::RunEvent& e : records.events) {
    if (e.kind == "suspended" && e.reason.rfind("camera", 0) == 0) ++totals.camera_suspensions;
  }
}

}  // namespace

RunTotals check_runs(const fs::path& runs_directory, const std::map<std::string, RunObservation>& seen,
                     std::vector<std::string>& problems) {
  RunTotals totals;
  std::vector<fs::path> runs;
  for (const auto& entry : fs::directory_iterator(runs_directory)) {
    if (entry.is_directory()) runs.push_back(entry.path());
  }
  std::sort(runs.begin(), runs.end());
  for (const fs::path& run : runs) check_run(run, seen, totals, problems);
  for (const auto& [id, observation] : seen) {
    if (!fs::exists(runs_directory / id))
      problems.push_back(fmt::format("run {}: markerd reported it, its directory is gone", id));
  }
  return totals;
}

}  // namespace markerd::soak
