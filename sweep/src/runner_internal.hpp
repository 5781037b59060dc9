#pragma once
// What SweepRunner's files share (runner.cpp: starting a run and the run
// thread; runner_journal.cpp: the journal that lets the next markerd resume
// or end it; run_report.cpp: what a run reports; start_record.cpp: the
// host and rig a run's start record names). Not part of the library's
// interface.

#include <chrono>
#include <cstddef>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"
#include "markerd/sweep/runner.hpp"

namespace markerd::sweep {

struct SweepRunner::Run {
  SweepPlan plan;
  std::vector<PlanStep> steps;
  std::filesystem::path directory;
  std::string run_id;
  std::string start_uid;  // its start document's (empty for a run recorded before runs had uids)
  std::string stop_uid;   // made ahead, so that ending a run needs nothing that can fail
  RunRecorder recorder;
  std::size_t done = 0;
  bool start_paused = false;
  std::optional<double> last_rate;
  std::optional<PlanStep> current;
  // This markerd's share of the run, for the estimate of what remains.
  std::chrono::steady_clock::time_point began = std::chrono::steady_clock::now();
  std::optional<std::chrono::steady_clock::time_point> ended;
  std::size_t done_at_begin = 0;
  std::chrono::duration<double> estimate_per_step{0};
};

// The journal's states (SweepRunner::write_journal).
inline constexpr std::string_view kJournalRunning = "running";
inline constexpr std::string_view kJournalPaused = "paused";
inline constexpr std::string_view kJournalStopped = "stopped";

// A reason as the journal keeps it, cut to a length its file's first block
// holds.
std::string journal_reason(std::string_view reason);
// The journal, read and its fields' types checked; std::runtime_error (or
// FileError) naming what is wrong.
nlohmann::json read_journal(const std::filesystem::path& path);

// A run's end as its stop record says it, and back.
ExitStatus exit_status(RunState state);
RunState run_state(ExitStatus status);

// A run that has ended: its documents.jsonl (documents.hpp) made from its
// records. Before the journal is removed, so that a markerd killed in
// between writes it at its start. A failure is logged, never thrown: the
// run's records are whole without it, and it can be made again from them.
void write_run_documents(const std::filesystem::path& run_directory) noexcept;

// What a run's start record says of the machine and the rig.
std::string this_hostname();
nlohmann::json rig_record(const rig::RigConfig& config);

}  // namespace markerd::sweep
