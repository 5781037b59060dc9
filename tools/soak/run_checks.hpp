#pragma once
// The truth of the sweep runs' records after the soak: each run either done
// with every planned measurement exactly once, in order, or failed or
// aborted with its cause in its stop record and its measurements up to
// there exactly once; nothing the soak saw recorded lost since; a run seen
// to fail never coming back as done; one "restarted" event per kill that
// cut the run off, at the step the records then held.

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

namespace markerd::soak {

// What the soak saw of a run while it went (through sweep.status and at kills).
struct RunObservation {
  std::set<std::string> states;  // every state sweep.status reported for it
  std::string ended_as;          // the first end state seen (done, failed, aborted); empty while none
  std::string ended_reason;
  bool came_back = false;           // reported in another state after it had ended (said once)
  std::size_t most_steps_seen = 0;  // the largest steps_done seen
  std::vector<std::size_t> cut_at;  // per kill -9 that cut it off: the steps then recorded
};

struct RunTotals {
  std::uint64_t runs = 0;
  std::uint64_t done = 0;
  std::uint64_t failed = 0;
  std::uint64_t aborted = 0;
  std::uint64_t unended = 0;          // without a stop record
  std::uint64_t planned = 0;          // measurements planned, over all runs
  std::uint64_t recorded = 0;         // point records
  std::uint64_t duplicates = 0;       // point records of a step recorded before
  std::uint64_t missing = 0;          // steps before the last recorded one without a record
  std::uint64_t planned_in_done = 0;  // measurements planned by the runs that ended done
  std::uint64_t not_measured = 0;     // planned by failed or aborted runs, never measured
  std::uint64_t restarted_events = 0;
  std::uint64_t cut_off_kills = 0;
  std::uint64_t camera_suspensions = 0;                 // "suspended" events with the camera as the cause
  std::map<std::string, std::uint64_t> failure_causes;  // stop reasons of failed runs, shortened
};

// markerd in the soak locks its simulated rig (the config file
// `rig_config`) in the soak's own lock directory (MARKERD_LOCK_DIR), not the
// machine's /run/lock/markerd, where the machine's own markerd or a
// markerctl rig session would meet it: a problem in words when `directory`
// holds no lock file of that rig.
std::optional<std::string> lock_directory_problem(const std::filesystem::path& directory,
                                                  const std::filesystem::path& rig_config);

// Reads every run under `runs_directory` and checks it against `seen`
// (by run id); problems are appended, each naming the run.
RunTotals check_runs(const std::filesystem::path& runs_directory, const std::map<std::string, RunObservation>& seen,
                     std::vector<std::string>& problems);

}  // namespace markerd::soak
