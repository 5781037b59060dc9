// SweepRunner's journal: the file in the state directory that names the run
// in progress, so that the next markerd resumes a run that was cut off and
// ends one that ended without its stop record (docs/sweep.md).

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <array>
#include <stdexcept>
#include <system_error>

#include "markerd/base/read_file.hpp"
#include "markerd/base/uuid.hpp"
#include "runner_internal.hpp"

namespace markerd::sweep {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

// A journal is read whole; anything near this is not one.
constexpr std::size_t kMaxJournalBytes = 64 * 1024;
// The in-place fallback must stay within the journal file's first block.
constexpr std::size_t kMaxJournalReason = 1500;

// The journal's fields have the types markerd writes there; a journal
// edited or damaged otherwise is refused naming the field, never with
// nlohmann's own message (nor half-read).
void check_journal_fields(const nlohmann::json& journal) {
  if (!journal.is_object()) throw std::runtime_error("not a JSON object");
  struct Field {
    const char* key;
    bool (*fits)(const nlohmann::json&);
    const char* wanted;
  };
  static constexpr std::array<Field, 6> kFields{{
      {"run_directory", [](const nlohmann::json& v) { return v.is_string(); }, "a string"},
      {"state", [](const nlohmann::json& v) { return v.is_string(); }, "a string"},
      {"reason", [](const nlohmann::json& v) { return v.is_string(); }, "a string"},
      {"paused", [](const nlohmann::json& v) { return v.is_boolean(); }, "true or false"},
      {"step", [](const nlohmann::json& v) { return v.is_number_unsigned(); }, "a whole number from 0"},
      {"stop", [](const nlohmann::json& v) { return v.is_object(); }, "a JSON object (a stop record)"},
  }};
  for (const Field& f : kFields) {
    const auto it = journal.find(f.key);
    if (it != journal.end() && !f.fits(*it)) {
      throw std::runtime_error(fmt::format("\"{}\" must be {}, got {}", f.key, f.wanted, it->dump()));
    }
  }
}

// For a message only: the stop record's status, whatever the record holds.
std::string exit_status_in(const nlohmann::json& stop) {
  const auto it = stop.find("exit_status");
  return it != stop.end() && it->is_string() ? it->get<std::string>() : std::string("?");
}

}  // namespace

std::string journal_reason(std::string_view reason) {
  if (reason.size() <= kMaxJournalReason) return std::string(reason);
  return std::string(reason.substr(0, kMaxJournalReason)) + "...";
}

nlohmann::json read_journal(const fs::path& path) {
  nlohmann::json journal = nlohmann::json::parse(read_regular_file(path, kMaxJournalBytes, "the sweep journal"));
  check_journal_fields(journal);
  return journal;
}

bool SweepRunner::resume_from_journal() {
  const std::lock_guard lock(start_mutex_);
  std::error_code ec;
  // A temporary left by a journal write that was cut off (a crash, a full
  // disk) is not the journal: that is only ever replaced whole, by rename.
  fs::remove(fs::path(settings_.journal).concat(".tmp"), ec);
  if (!fs::exists(settings_.journal, ec)) return false;
  nlohmann::json journal;
  try {
    journal = read_journal(settings_.journal);
  } catch (const std::exception& e) {
    throw std::runtime_error(fmt::format("sweep journal {}: cannot be read: {}", settings_.journal.string(), e.what()));
  }
  const fs::path directory = journal.value("run_directory", "");
  if (!fs::exists(directory / "start.json", ec)) {
    spdlog::warn("sweep journal {}: run {} never started (markerd stopped while starting it); forgetting it",
                 settings_.journal.string(), directory.string());
    fs::remove(settings_.journal, ec);
    return false;
  }
  if (journal.contains("stop")) {
    // The run ended (failed, aborted, done) and markerd could not write its
    // stop record, or stopped before it removed the journal: it is not
    // resumed, whatever its records hold.
    try {
      finish_ended_run(journal);
    } catch (const std::exception& e) {
      spdlog::error("sweep journal {}: run {} ended ({}), and its stop record still cannot be written: {}",
                    settings_.journal.string(), directory.string(), exit_status_in(journal["stop"]), e.what());
    }
    return false;
  }
  RunRecords records = read_run(directory);
  if (records.stop) {
    // The run ended but markerd stopped before it removed the journal
    // (maybe before it wrote the run's documents).
    write_run_documents(directory);
    fs::remove(settings_.journal, ec);
    return false;
  }
  for (std::size_t i = 0; i < records.points.size(); ++i) {
    if (records.points[i].step != i) {
      throw std::runtime_error(fmt::format("sweep run {}: points.jsonl line {} holds step {}, expected {}",
                                           directory.string(), i + 1, records.points[i].step, i));
    }
  }
  auto run = std::make_unique<Run>();
  run->plan = records.start.plan;
  run->steps = plan_steps(run->plan);
  if (run->steps.size() != records.start.steps) {
    throw std::runtime_error(fmt::format("sweep run {}: its plan now expands to {} steps, it started with {}",
                                         directory.string(), run->steps.size(), records.start.steps));
  }
  if (auto problem = marker_problem(run->plan.marker, environment_.detector_config(), environment_.marker_mounting())) {
    throw std::runtime_error(fmt::format("sweep run {}: {}", directory.string(), *problem));
  }
  run->directory = directory;
  run->run_id = records.start.run_id;
  run->start_uid = records.start.uid;
  run->stop_uid = new_uuid4();
  run->done = records.points.size();
  run->done_at_begin = run->done;
  run->start_paused = journal.value("paused", false);
  if (!records.points.empty()) {
    const PointRecord& last = records.points.back();
    int detected = 0;
    for (const FrameSample& f : last.frames) detected += f.detected ? 1 : 0;
    if (!last.frames.empty()) run->last_rate = static_cast<double>(detected) / static_cast<double>(last.frames.size());
  }
  run->estimate_per_step = check_plan(run->plan, rig_config_, environment_.camera_fps()).estimated_duration /
                           std::max<std::size_t>(1, run->steps.size());
  // The interruption and its cause: markerd stopping wrote "stopped" (and a
  // "stopped" event); a journal still saying the run was going means
  // markerd ended without a word.
  const std::string state = journal.value("state", std::string(kJournalRunning));
  const std::string cause =
      state == kJournalStopped
          ? fmt::format("markerd stopped at step {} ({})", journal.value("step", run->done),
                        journal.value("reason", std::string("no reason recorded")))
          : fmt::format("markerd ended without stopping the run (a crash, kill -9 or a power cut) while it was {}",
                        state);
  run->recorder = RunRecorder::resume(directory);
  run->recorder.append_event(
      {std::chrono::system_clock::now(), "restarted",
       fmt::format("{}; markerd started again, continuing at step {} of {}", cause, run->done, run->steps.size()),
       run->done});
  write_journal(directory, run->start_paused ? kJournalPaused : kJournalRunning, run->start_paused);
  spdlog::info("sweep {}: resuming at step {} of {} ({})", run->run_id, run->done, run->steps.size(), cause);
  launch(std::move(run));
  return true;
}

void SweepRunner::finish_ended_run(const nlohmann::json& journal) {
  const fs::path directory = journal.value("run_directory", "");
  std::error_code ec;
  if (!fs::exists(directory / "start.json", ec)) {
    // Its records are gone (the operator removed them): nothing to end.
    spdlog::warn("sweep journal {}: run {} has no records any more; forgetting it", settings_.journal.string(),
                 directory.string());
    fs::remove(settings_.journal, ec);
    return;
  }
  const RunRecords records = read_run(directory);
  RunStop stop;
  if (records.stop) {
    stop = *records.stop;
  } else {
    try {
      stop = stop_from_json(journal.at("stop"));
    } catch (const std::exception& e) {
      throw std::runtime_error(fmt::format("sweep journal {}: \"stop\": {}", settings_.journal.string(), e.what()));
    }
  }
  // A journal written before runs had uids holds a stop without them.
  if (stop.uid.empty()) stop.uid = new_uuid4();
  if (stop.run_start.empty()) stop.run_start = records.start.uid;
  std::string shown = stop.reason;
  std::exception_ptr failure;
  if (!records.stop) {
    stop.reason += stop.reason.empty() ? "" : " ";
    stop.reason +=
        "(this stop record was written from the journal when markerd started again: it had not been "
        "written when the run ended)";
    try {
      write_file_atomically(directory / "stop.json", to_json(stop).dump(2) + "\n");
      shown = stop.reason;
    } catch (const std::exception& e) {
      failure = std::current_exception();
      shown += fmt::format(" (its stop record could not be written: {}; the journal keeps it)", e.what());
    }
  }
  if (!failure) {
    write_run_documents(directory);
    fs::remove(settings_.journal, ec);
  }
  spdlog::warn("sweep {}: {} at step {}, not resumed: {}", records.start.run_id, to_string(stop.status),
               stop.steps_done, shown);
  // The runner shows how that run ended, as if it had just ended here.
  auto run = std::make_unique<Run>();
  run->plan = records.start.plan;
  run->steps = plan_steps(run->plan);
  run->directory = directory;
  run->run_id = records.start.run_id;
  run->done = records.points.size();
  run->done_at_begin = run->done;
  run->ended = Clock::now();
  run->began = *run->ended;
  {
    const std::lock_guard lock(mutex_);
    if (state_ != RunState::running && state_ != RunState::paused && state_ != RunState::suspended) {
      run_ = std::move(run);
      state_ = run_state(stop.status);
      reason_ = shown;
      phase_.clear();
    }
  }
  changed_.notify_all();
  if (failure) std::rethrow_exception(failure);
}

void SweepRunner::write_journal(const fs::path& run_directory, std::string_view state, bool paused,
                                std::string_view reason) {
  nlohmann::json journal{{"run_directory", run_directory.string()}, {"state", state}, {"paused", paused}};
  if (run_ && run_->directory == run_directory) journal["step"] = run_->done;
  if (!reason.empty()) journal["reason"] = journal_reason(reason);
  write_file_atomically(settings_.journal, journal.dump() + "\n");
}

bool SweepRunner::record_end_in_journal(RunState state, const std::string& reason) noexcept {
  try {
    RunStop stop;
    stop.time = std::chrono::system_clock::now();
    stop.status = exit_status(state);
    stop.reason = journal_reason(reason);
    stop.steps_done = run_->done;
    stop.uid = run_->stop_uid;
    stop.run_start = run_->start_uid;
    const nlohmann::json journal{{"run_directory", run_->directory.string()},
                                 {"state", to_string(state)},
                                 {"paused", false},
                                 {"step", run_->done},
                                 {"stop", to_json(stop)}};
    const std::string text = journal.dump() + "\n";
    try {
      write_file_atomically(settings_.journal, text);
    } catch (const std::exception& e) {
      // A full disk has no room for a new temporary; the journal's own
      // block has room for this.
      spdlog::error("sweep {}: cannot replace the journal ({}); overwriting it in place", run_->run_id, e.what());
      overwrite_file_in_place(settings_.journal, text);
    }
    return true;
  } catch (const std::exception& e) {
    // A journal that still says "running" would have the next markerd resume
    // a run that ended. Without it the run is not resumed; its records end
    // without a stop record, as an incomplete run.
    std::error_code ec;
    fs::remove(settings_.journal, ec);
    spdlog::error("sweep {}: cannot record in the journal that the run {} ({}); {}", run_->run_id, to_string(state),
                  e.what(),
                  ec ? fmt::format("nor remove the journal ({}): the next markerd may resume the run", ec.message())
                     : std::string("removed the journal, so that no markerd resumes the run"));
    return false;
  }
}

}  // namespace markerd::sweep
