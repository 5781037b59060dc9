#pragma once
// The sweep runner: inside markerd, it walks a plan's steps on the rig. For
// each step it moves both axes, waits until they have settled and the plan's
// settle time has passed, collects the configured number of frames captured
// after that moment (the daemon hands it every frame outcome), writes the
// step's point record and so checkpoints the run. Design: docs/sweep.md.
//
// States: idle -> running <-> paused, running <-> suspended (a fault), and
// then done, aborted or failed. A run that ends, however it ends, leaves both
// axes stopped and disabled. A journal file in the state directory names the
// run in progress and its state, so that markerd, restarted after a crash, a
// kill -9, a power cut or a SIGTERM, resumes it at the first step without a
// record: no step done twice, none lost. A run that ended (failed, aborted,
// done) has that written to the journal before anything else, and is never
// resumed.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "markerd/detector/detection.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"

namespace markerd::sweep {

enum class RunState : std::uint8_t { idle, running, paused, suspended, done, aborted, failed };
[[nodiscard]] std::string_view to_string(RunState state);

// One frame outcome, as the daemon's log stage sees it. Views: valid during
// the call only.
struct FrameObservation {
  std::chrono::steady_clock::time_point capture_time{};
  std::uint64_t sequence = 0;
  bool readable = true;  // false: a corrupt frame or one the detector refused
  std::optional<rig::RigSnapshot> rig;
  std::optional<rig::MarkerGroundTruth> truth;
  std::span<const detector::Detection> detections;
};

// A frame reduced to what a point record keeps: the plan's marker found or
// not, its pose, and the pose's error against the truth.
// `detector_marker_size_m` is the size the detector posed the marker with
// (markerd's config); the pose is rescaled to the plan's marker size. That is
// exact: a square of side k s seen at the same corners lies at k times the
// translation, with the same rotation and reprojection error.
[[nodiscard]] FrameSample make_frame_sample(const FrameObservation& frame, const PlanMarker& marker,
                                            double detector_marker_size_m);

// What the runner needs from the daemon around it.
class SweepEnvironment {
 public:
  virtual ~SweepEnvironment() = default;
  // Why the camera delivers no frames now ("camera /dev/video0: vanished"),
  // or nothing when it streams. A problem suspends the run.
  [[nodiscard]] virtual std::optional<std::string> camera_problem() const = 0;
  // Frames per second the camera delivers (for estimates; 0: unknown).
  [[nodiscard]] virtual double camera_fps() const = 0;
  // What markerd's detectors find (the family, frame8's options) and the
  // marker size their poses assume.
  [[nodiscard]] virtual detector::DetectorConfig detector_config() const = 0;
  // What the marker on the turntable is mounted on (the config's [marker]).
  [[nodiscard]] virtual Mounting marker_mounting() const = 0;
  // Parts of the start document: the config markerd runs with, the camera
  // (source, model), where the detection log goes.
  [[nodiscard]] virtual nlohmann::json config_record() const = 0;
  [[nodiscard]] virtual nlohmann::json camera_record() const = 0;
  // The marker as the config describes it (family, id, size, mounting, frame).
  [[nodiscard]] virtual nlohmann::json marker_record() const = 0;
  [[nodiscard]] virtual std::string detection_log_path() const = 0;
};

struct RunnerSettings {
  std::filesystem::path runs_directory;  // one directory per run is made here; must exist
  std::filesystem::path journal;         // the file naming the run in progress (state directory)
  std::string software_version;
  // A faulted drive is reset (its alarm cleared) at these intervals, doubling
  // up to the maximum, while the plan's fault_timeout allows.
  std::chrono::milliseconds fault_retry_first{1000};
  std::chrono::milliseconds fault_retry_max{30000};
  // Consecutive time-outs of one step (frames that do not come, an axis that
  // does not settle) before the run fails.
  int step_attempts = 3;
};

// An error the runner reports to a command (a run already going, a plan that
// does not fit the rig, no run to pause).
class SweepError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct SweepProgress {
  RunState state = RunState::idle;
  std::string run_id;
  std::filesystem::path run_directory;
  std::string plan_name;
  std::size_t steps_done = 0;
  std::size_t steps_total = 0;
  std::optional<PlanStep> step;  // the step in hand
  std::string phase;             // "homing", "moving", "settling", "collecting", ""
  int frames_collected = 0;      // of the step in hand
  int frames_per_point = 0;
  std::optional<double> last_rate;                         // the last recorded measurement's detection rate
  std::string reason;                                      // suspended: the fault; ended: why
  std::chrono::duration<double> elapsed{0};                // running time of this markerd's share of the run
  std::optional<std::chrono::duration<double>> remaining;  // estimate
};
[[nodiscard]] nlohmann::json to_json(const SweepProgress& progress);

class SweepRunner {
 public:
  // `rig` and `environment` must outlive the runner.
  SweepRunner(rig::Rig& rig, rig::RigConfig rig_config, SweepEnvironment& environment, RunnerSettings settings);
  ~SweepRunner();  // stop()
  SweepRunner(const SweepRunner&) = delete;
  SweepRunner& operator=(const SweepRunner&) = delete;

  // Dry run of a plan on this rig, camera and detector. SweepError when the
  // detector cannot measure the plan's marker (marker_problem).
  [[nodiscard]] PlanCheck check(const SweepPlan& plan) const;
  // Starts a run: SweepError when one is going, the plan does not fit the
  // rig (naming the points) or its marker the detector, or the previous run
  // ended without its stop record and it still cannot be written;
  // std::runtime_error when the records cannot be written. Returns the run's
  // directory.
  std::filesystem::path start(SweepPlan plan);
  // At markerd's start: when the journal names a run that was interrupted
  // (markerd stopped, crashed, was killed, lost power), continues it (paused
  // if it was paused), records the interruption and its cause, and returns
  // true. A run the journal says has ended (failed, aborted, done: its stop
  // record could not be written then) is not resumed: its stop record is
  // written now if it can be, and the runner shows that run's end. A journal
  // that cannot be read is an error naming it; a finished run's stale journal
  // is removed.
  bool resume_from_journal();

  void pause();                                                // SweepError unless running or suspended
  void resume();                                               // SweepError unless paused
  void abort(std::string reason = "aborted by the operator");  // SweepError unless a run is going

  // markerd stops: the run thread stops where it is (motion stopped), the
  // journal and the run's events record it, and the next markerd resumes the
  // run. Idempotent.
  void stop();

  [[nodiscard]] SweepProgress progress() const;
  // Blocks until the run has ended (done, aborted, failed) or the timeout
  // passes; returns the state then.
  RunState wait_finished(std::chrono::milliseconds timeout) const;

  // The log stage's thread, for every frame outcome: brief, never blocks on
  // the run, allocates nothing once the collection buffer has grown.
  void observe(const FrameObservation& frame) noexcept;

  // Any thread: an event of the run going on (running, paused or
  // suspended) for its records, at the step it is at: something done to the
  // rig or the camera from outside the run (a camera control set, kind
  // "camera_control"). False when no run is going or the line could not be
  // written (logged).
  bool record_event(const std::string& kind, const std::string& reason) noexcept;

 private:
  struct Run;
  class Interrupted;

  void launch(std::unique_ptr<Run> run);
  void run_thread(const std::stop_token& stop);
  void prepare_axes();
  void execute_step(const PlanStep& step);
  void move_to(const PlanStep& step);
  [[nodiscard]] std::chrono::steady_clock::duration move_allowance(double rail_distance,
                                                                   double turntable_distance) const;
  void collect(const PlanStep& step, std::chrono::system_clock::time_point started,
               std::chrono::steady_clock::time_point deadline);
  void wait_paused();
  void suspend(const std::string& cause);
  // Throws Interrupted when the run must leave what it is doing: markerd
  // stopping, an abort, a pause, a fault.
  void checkpoint();
  void sleep_checked(std::chrono::steady_clock::duration duration);
  void end_run(RunState state, const std::string& reason);
  void leave_for_restart() noexcept;
  void stop_motion() noexcept;
  void stop_and_disable() noexcept;
  [[nodiscard]] std::optional<std::string> fault() const;
  // The journal's states: "running", "paused" (a run going), "stopped"
  // (markerd stopped it, to be resumed), "done", "aborted", "failed" (ended:
  // never resumed).
  void write_journal(const std::filesystem::path& run_directory, std::string_view state, bool paused,
                     std::string_view reason = {});
  // The end, in the journal, before anything else; when the journal cannot
  // be replaced (a full disk), overwritten in place. When neither works the
  // journal is removed, so that the run is not resumed, and this is false.
  bool record_end_in_journal(RunState state, const std::string& reason) noexcept;
  // A journal naming a run that ended: writes its stop record if missing and
  // removes the journal. Leaves the runner showing that run's end. Throws
  // when the stop record cannot be written.
  void finish_ended_run(const nlohmann::json& journal);
  void set_phase(const char* phase);
  // The run thread's events; records_mutex_ lets record_event() write too.
  void append_event(const RunEvent& event);

  rig::Rig& rig_;
  rig::RigConfig rig_config_;
  SweepEnvironment& environment_;
  RunnerSettings settings_;

  mutable std::mutex mutex_;  // guards everything below
  mutable std::condition_variable changed_;
  std::unique_ptr<Run> run_;
  RunState state_ = RunState::idle;
  bool pause_requested_ = false;
  bool abort_requested_ = false;
  std::string abort_reason_;
  std::string reason_;
  std::string phase_;
  std::mutex start_mutex_;  // one start() or resume_from_journal() at a time
  // The open run's records, written by the run thread and by record_event();
  // taken after mutex_ where both are held.
  std::mutex records_mutex_;
  std::stop_token stop_;  // the run thread's own

  // The collection of the step in hand, filled by observe() (log thread).
  struct Collection {
    bool active = false;
    std::chrono::steady_clock::time_point not_before{};
    double rail_target = 0;
    double turntable_target = 0;
    double rail_tolerance = 0;
    double turntable_tolerance = 0;
    rig::RigSnapshot first_snapshot{};
    bool have_snapshot = false;
    int wanted = 0;
    int corrupt = 0;
    std::vector<FrameSample> samples;  // capacity kept from step to step
  };
  mutable std::mutex collection_mutex_;
  std::condition_variable collection_changed_;
  Collection collection_;
  PlanMarker marker_;                  // the run's, read by observe() under collection_mutex_
  double detector_marker_size_m_ = 0;  // what the detector's poses assume, ditto

  std::jthread thread_;
};

}  // namespace markerd::sweep
