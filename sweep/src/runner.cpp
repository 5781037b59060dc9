#include "markerd/sweep/runner.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "markerd/base/utc_time.hpp"
#include "markerd/base/uuid.hpp"
#include "markerd/rig/motion_profile.hpp"
#include "markerd/sweep/documents.hpp"
#include "markerd/sweep/report.hpp"
#include "runner_internal.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <utility>

namespace markerd::sweep {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// Why the run thread left what it was doing.
class SweepRunner::Interrupted {
 public:
  enum class Kind { stop, abort, pause, fault, timeout };
  Interrupted(Kind what, std::string why = {}) : kind(what), cause(std::move(why)) {}
  Kind kind;
  std::string cause;
};

namespace {

// A run that cannot go on: its stop record says why.
class RunFailed : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// How far an axis may be from its target and still be "there": a step (the
// drive's resolution) plus a closed-loop drive's deadband.
double position_tolerance(const rig::AxisSettings& axis) {
  return std::abs(axis.units_per_step) * 1.01 + axis.retry_deadband;
}

// The corners of the detection make_frame_sample took for the plan's
// marker (the first of its family and id), for the record.
void keep_corners(FrameSample& sample, const FrameObservation& frame, const PlanMarker& marker) {
  const auto to_record = [](const detector::Quad& quad) {
    ImageCorners c{};
    for (std::size_t i = 0; i < 4; ++i) c[i] = {quad[i].x, quad[i].y};
    return c;
  };
  for (const detector::Detection& d : frame.detections) {
    if (d.family != marker.family || d.id != marker.id) continue;
    sample.corners_px = to_record(d.corners);
    if (d.inner_corners) sample.inner_corners_px = to_record(*d.inner_corners);
    return;
  }
}

}  // namespace

SweepRunner::SweepRunner(rig::Rig& rig, rig::RigConfig rig_config, SweepEnvironment& environment,
                         RunnerSettings settings)
    : rig_(rig), rig_config_(std::move(rig_config)), environment_(environment), settings_(std::move(settings)) {}

SweepRunner::~SweepRunner() { stop(); }

PlanCheck SweepRunner::check(const SweepPlan& plan) const {
  if (auto problem = marker_problem(plan.marker, environment_.detector_config(), environment_.marker_mounting())) {
    throw SweepError(fmt::format("plan {} cannot run on this markerd: {}", plan.source, *problem));
  }
  return check_plan(plan, rig_config_, environment_.camera_fps());
}

fs::path SweepRunner::start(SweepPlan plan) {
  const std::lock_guard lock(start_mutex_);
  {
    const std::lock_guard state_lock(mutex_);
    if (state_ == RunState::running || state_ == RunState::paused || state_ == RunState::suspended) {
      throw SweepError(fmt::format("run {} is {}: abort it first", run_->run_id, to_string(state_)));
    }
  }
  // The previous run's thread has ended the run; it may still be logging.
  if (thread_.joinable()) thread_.join();
  // A previous run that ended while its stop record could not be written
  // (a full disk) is ended in its records before a new run replaces the
  // journal that says how it ended.
  std::error_code ec;
  if (fs::exists(settings_.journal, ec)) {
    nlohmann::json previous;
    try {
      previous = read_journal(settings_.journal);
    } catch (const std::exception&) {
      previous = nlohmann::json::object();  // unreadable: reported at markerd's start; the operator starts anew
    }
    if (previous.contains("stop")) {
      try {
        finish_ended_run(previous);
      } catch (const std::exception& e) {
        throw SweepError(
            fmt::format("the previous run {} ended, but its stop record still cannot be written ({}); "
                        "free space in {} first",
                        previous.value("run_directory", std::string()), e.what(), settings_.runs_directory.string()));
      }
    }
  }
  const PlanCheck checked = check(plan);
  if (!checked.ok()) {
    std::string message = fmt::format("plan {} does not fit this rig:", plan.source);
    for (const std::string& problem : checked.problems) message += "\n  " + problem;
    throw SweepError(message);
  }

  auto run = std::make_unique<Run>();
  const auto now = std::chrono::system_clock::now();
  run->run_id = format_utc(now, UtcForm::compact) + "-" + plan.name;
  run->directory = settings_.runs_directory / run->run_id;
  for (int n = 2; fs::exists(run->directory); ++n) {
    run->directory = settings_.runs_directory / fmt::format("{}-{}", run->run_id, n);
  }
  run->run_id = run->directory.filename().string();
  run->steps = checked.steps;
  run->estimate_per_step = checked.estimated_duration / std::max<std::size_t>(1, checked.steps.size());

  RunStart start;
  start.uid = new_uuid4();
  start.primary_descriptor_uid = new_uuid4();
  run->start_uid = start.uid;
  run->stop_uid = new_uuid4();
  start.run_id = run->run_id;
  start.time = now;
  start.software_version = settings_.software_version;
  start.hostname = this_hostname();
  start.plan = plan;
  start.steps = run->steps.size();
  start.config = environment_.config_record();
  start.camera = environment_.camera_record();
  start.marker = environment_.marker_record();
  start.rig = rig_record(rig_config_);
  start.detection_log = environment_.detection_log_path();
  // The journal first: a markerd killed between here and the run's first
  // record finds a journal naming a run that never started, and forgets it,
  // rather than a started run that no journal names.
  write_journal(run->directory, kJournalRunning, false);
  const fs::path directory = run->directory;
  const std::string run_id = run->run_id;
  const std::size_t steps = run->steps.size();
  try {
    run->recorder = RunRecorder::create(directory, start);
    run->recorder.append_event({now, "started", {}, 0});
    run->plan = std::move(plan);
    launch(std::move(run));
  } catch (const std::exception&) {
    // The run never started: nothing was measured, and the client hears why.
    // Its half-made directory (a full disk fails here) would otherwise stay
    // behind, looking like a run that never ended, with a journal naming it.
    run.reset();  // closes its records, unless launch() had taken it
    std::error_code ignored;
    fs::remove_all(directory, ignored);
    fs::remove(settings_.journal, ignored);
    throw;
  }
  spdlog::info("sweep {}: started, {} steps ({} points), about {:.0f} s", run_id, steps, checked.points,
               checked.estimated_duration.count());
  return directory;
}

// The run's journal is the caller's to write first: launch() writes
// nothing, so that a start the disk refuses is refused before the runner says
// it is running. (It once wrote the journal again after setting the state: a
// disk that filled in between left a run "running" with no thread to run it,
// which no later start could replace. The soak found it.)
void SweepRunner::launch(std::unique_ptr<Run> run) {
  if (thread_.joinable()) thread_.join();  // the previous run's thread, finished
  {
    const std::lock_guard collection_lock(collection_mutex_);
    marker_ = run->plan.marker;
    detector_marker_size_m_ = environment_.detector_config().marker_size_m;
  }
  const bool paused = run->start_paused;
  {
    const std::lock_guard lock(mutex_);
    run_ = std::move(run);
    state_ = RunState::running;
    pause_requested_ = paused;
    abort_requested_ = false;
    reason_.clear();
    phase_.clear();
  }
  changed_.notify_all();
  try {
    thread_ = std::jthread([this](const std::stop_token& stop) { run_thread(stop); });
  } catch (...) {
    const std::lock_guard lock(mutex_);
    run_.reset();
    state_ = RunState::idle;
    throw;
  }
}

void SweepRunner::pause() {
  const std::lock_guard lock(mutex_);
  if (state_ != RunState::running && state_ != RunState::suspended) {
    throw SweepError(fmt::format("no run to pause (the runner is {})", to_string(state_)));
  }
  pause_requested_ = true;
  changed_.notify_all();
}

void SweepRunner::resume() {
  const std::lock_guard lock(mutex_);
  if (state_ != RunState::paused) throw SweepError(fmt::format("no paused run (the runner is {})", to_string(state_)));
  pause_requested_ = false;
  changed_.notify_all();
}

void SweepRunner::abort(std::string reason) {
  const std::lock_guard lock(mutex_);
  if (state_ != RunState::running && state_ != RunState::paused && state_ != RunState::suspended) {
    throw SweepError(fmt::format("no run to abort (the runner is {})", to_string(state_)));
  }
  abort_requested_ = true;
  abort_reason_ = std::move(reason);
  changed_.notify_all();
}

void SweepRunner::stop() {
  if (thread_.joinable()) {
    thread_.request_stop();
    changed_.notify_all();
    collection_changed_.notify_all();
    thread_.join();
  }
}

SweepProgress SweepRunner::progress() const {
  const std::lock_guard lock(mutex_);
  SweepProgress p;
  p.state = state_;
  p.reason = reason_;
  p.phase = phase_;
  if (!run_) return p;
  p.run_id = run_->run_id;
  p.run_directory = run_->directory;
  p.plan_name = run_->plan.name;
  p.steps_done = run_->done;
  p.steps_total = run_->steps.size();
  p.step = run_->current;
  p.frames_per_point = run_->plan.frames_per_point;
  p.last_rate = run_->last_rate;
  p.elapsed = run_->ended.value_or(Clock::now()) - run_->began;
  const std::size_t remaining = p.steps_total - p.steps_done;
  const std::size_t done_here = run_->done - run_->done_at_begin;
  if (state_ == RunState::running || state_ == RunState::paused || state_ == RunState::suspended) {
    // Measured pace once a few steps are done here, the dry run's estimate before.
    const auto per_step = done_here >= 3 ? p.elapsed / static_cast<double>(done_here) : run_->estimate_per_step;
    p.remaining = per_step * static_cast<double>(remaining);
  }
  {
    const std::lock_guard collection_lock(collection_mutex_);
    if (collection_.active) p.frames_collected = static_cast<int>(collection_.samples.size());
  }
  return p;
}

RunState SweepRunner::wait_finished(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  changed_.wait_for(lock, timeout, [&] {
    return state_ == RunState::done || state_ == RunState::aborted || state_ == RunState::failed;
  });
  return state_;
}

void SweepRunner::observe(const FrameObservation& frame) noexcept {
  const std::lock_guard lock(collection_mutex_);
  Collection& c = collection_;
  if (!c.active || frame.capture_time < c.not_before) return;
  if (!frame.readable) {
    ++c.corrupt;
    return;
  }
  if (frame.rig) {
    // A frame from while an axis was off its target (a fault moved it, a
    // stop) is not a frame of this point.
    const rig::RigSnapshot& s = *frame.rig;
    if (!s.settled() || std::abs(s.rail.position - c.rail_target) > c.rail_tolerance ||
        std::abs(s.turntable.position - c.turntable_target) > c.turntable_tolerance) {
      return;
    }
    if (!c.have_snapshot) {
      c.first_snapshot = s;
      c.have_snapshot = true;
    }
  }
  c.samples.push_back(
      make_frame_sample(frame, marker_, detector_marker_size_m_));  // within the capacity reserved for the step
  if (c.samples.back().detected) keep_corners(c.samples.back(), frame, marker_);
  if (static_cast<int>(c.samples.size()) >= c.wanted) {
    c.active = false;
    collection_changed_.notify_all();
  }
}

// ---- the run thread ----

void SweepRunner::run_thread(const std::stop_token& stop) {
  pthread_setname_np(pthread_self(), "markerd-sweep");
  stop_ = stop;
  int attempts = 0;
  try {
    for (;;) {
      PlanStep step;
      {
        const std::lock_guard lock(mutex_);
        if (run_->done >= run_->steps.size()) break;
        step = run_->steps[run_->done];
        run_->current = step;
      }
      try {
        checkpoint();
        prepare_axes();
        execute_step(step);
        attempts = 0;
      } catch (const Interrupted& interrupted) {
        switch (interrupted.kind) {
          case Interrupted::Kind::stop: leave_for_restart(); return;
          case Interrupted::Kind::abort: {
            std::string reason;
            {
              const std::lock_guard lock(mutex_);
              reason = abort_reason_;
            }
            end_run(RunState::aborted, reason);
            return;
          }
          case Interrupted::Kind::pause: wait_paused(); break;
          case Interrupted::Kind::fault: suspend(interrupted.cause); break;
          case Interrupted::Kind::timeout:
            if (++attempts >= settings_.step_attempts) {
              throw RunFailed(fmt::format("step {}: {} ({} attempts)", step.index, interrupted.cause, attempts));
            }
            spdlog::warn("sweep {}: step {}: {}; trying it again", run_->run_id, step.index, interrupted.cause);
            append_event({std::chrono::system_clock::now(), "retried", interrupted.cause, step.index});
            break;
        }
      }
    }
    end_run(RunState::done, {});
  } catch (const Interrupted& interrupted) {
    // Raised while paused or suspended: markerd stopping, or an abort.
    if (interrupted.kind == Interrupted::Kind::stop) {
      leave_for_restart();
      return;
    }
    std::string reason;
    {
      const std::lock_guard lock(mutex_);
      reason = abort_reason_;
    }
    end_run(RunState::aborted, reason);
  } catch (const std::exception& e) {
    spdlog::error("sweep {}: failed: {}", run_->run_id, e.what());
    end_run(RunState::failed, e.what());
  }
}

void SweepRunner::append_event(const RunEvent& event) {
  const std::lock_guard records(records_mutex_);
  run_->recorder.append_event(event);
}

bool SweepRunner::record_event(const std::string& kind, const std::string& reason) noexcept {
  try {
    const std::lock_guard lock(mutex_);
    if (!run_ || (state_ != RunState::running && state_ != RunState::paused && state_ != RunState::suspended)) {
      return false;
    }
    const std::lock_guard records(records_mutex_);
    run_->recorder.append_event({std::chrono::system_clock::now(), kind, reason, run_->done});
    return true;
  } catch (const std::exception& e) {
    // The run ended a moment ago (its records are closed), or the disk
    // refuses the line: the caller's own log has the event all the same.
    spdlog::warn("sweep: cannot record the event '{}' ({}): {}", kind, reason, e.what());
    return false;
  }
}

void SweepRunner::checkpoint() {
  if (stop_.stop_requested()) throw Interrupted(Interrupted::Kind::stop);
  {
    const std::lock_guard lock(mutex_);
    if (abort_requested_) throw Interrupted(Interrupted::Kind::abort);
    if (pause_requested_) throw Interrupted(Interrupted::Kind::pause);
  }
  if (auto cause = fault()) throw Interrupted(Interrupted::Kind::fault, std::move(*cause));
}

void SweepRunner::sleep_checked(Clock::duration duration) {
  const auto until = Clock::now() + duration;
  for (;;) {
    checkpoint();
    const auto now = Clock::now();
    if (now >= until) return;
    std::unique_lock lock(mutex_);
    changed_.wait_for(lock, std::min<Clock::duration>(until - now, std::chrono::milliseconds(20)));
  }
}

std::optional<std::string> SweepRunner::fault() const {
  if (auto problem = environment_.camera_problem()) return "camera: " + *problem;
  for (const rig::Axis* axis : {&rig_.rail(), &rig_.turntable()}) {
    const rig::AxisStatus s = axis->status();
    if (s.state == rig::AxisState::fault) return fmt::format("{}: {}", axis->settings().name, s.fault);
  }
  return std::nullopt;
}

void SweepRunner::set_phase(const char* phase) {
  const std::lock_guard lock(mutex_);
  phase_ = phase;
}

void SweepRunner::prepare_axes() {
  std::array<rig::Axis*, 2> axes{&rig_.rail(), &rig_.turntable()};
  bool homing = false;
  std::chrono::milliseconds timeout{0};
  for (rig::Axis* axis : axes) {
    const rig::AxisStatus s = axis->status();
    if (s.state == rig::AxisState::disabled) axis->enable();
    if (!s.homed) {
      if (!homing) set_phase("homing");
      homing = true;
      spdlog::info("sweep {}: homing the {}", run_->run_id, axis->settings().name);
      axis->home();
      timeout = std::max(timeout, axis->settings().homing.timeout);
    }
  }
  if (!homing) return;
  const auto deadline = Clock::now() + timeout + std::chrono::seconds(5);
  for (;;) {
    checkpoint();
    const rig::RigSnapshot s = rig_.snapshot();
    if (s.rail.homed && s.turntable.homed && !s.rail.moving && !s.turntable.moving) return;
    if (Clock::now() > deadline) throw Interrupted(Interrupted::Kind::timeout, "homing did not finish in time");
    std::unique_lock lock(mutex_);
    changed_.wait_for(lock, std::chrono::milliseconds(10));
  }
}

void SweepRunner::execute_step(const PlanStep& step) {
  const auto started = std::chrono::system_clock::now();
  move_to(step);
  // The point timeout covers what follows the move: a long move is no fault
  // (its own deadline follows from the axes' profiles).
  collect(step, started, Clock::now() + run_->plan.point_timeout);
}

Clock::duration SweepRunner::move_allowance(double rail_distance, double turntable_distance) const {
  const auto duration = [](const rig::AxisSettings& a, double distance) {
    return rig::TrapezoidProfile(std::abs(distance) + 2 * a.backlash, a.max_velocity, a.acceleration).duration() +
           std::chrono::duration<double>(a.settle_time).count();
  };
  double seconds = std::max(duration(rig_config_.rail.axis, rail_distance),
                            duration(rig_config_.turntable.axis, turntable_distance));
  if (const auto& clock = rig_.sim_clock(); clock && !clock->is_manual()) seconds /= clock->time_scale();
  // Twice the profile's time and some: a drive that takes longer than that is stuck.
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(2 * seconds + 5));
}

void SweepRunner::move_to(const PlanStep& step) {
  const AxisTargets targets = axis_targets(rig_config_.geometry, step.distance_m, step.angle_deg);
  const double rail_tolerance = position_tolerance(rig_config_.rail.axis);
  const double turntable_tolerance = position_tolerance(rig_config_.turntable.axis);
  const auto there = [&](const rig::RigSnapshot& s) {
    return s.settled() && std::abs(s.rail.position - targets.rail) <= rail_tolerance &&
           std::abs(s.turntable.position - targets.turntable) <= turntable_tolerance;
  };
  {
    const std::lock_guard lock(collection_mutex_);
    collection_.rail_target = targets.rail;
    collection_.turntable_target = targets.turntable;
    collection_.rail_tolerance = rail_tolerance;
    collection_.turntable_tolerance = turntable_tolerance;
  }
  const rig::RigSnapshot before = rig_.snapshot();
  if (there(before)) return;  // a repeat at the same point: no move, no re-approach
  set_phase("moving");
  const auto deadline =
      Clock::now() + move_allowance(targets.rail - before.rail.position, targets.turntable - before.turntable.position);
  try {
    rig_.rail().move_to(targets.rail);
    rig_.turntable().move_to(targets.turntable);
  } catch (const rig::AxisError& e) {
    throw Interrupted(Interrupted::Kind::fault, e.what());
  } catch (const rig::DriveError& e) {
    throw Interrupted(Interrupted::Kind::fault, e.what());
  }
  for (;;) {
    checkpoint();
    if (there(rig_.snapshot())) return;
    if (Clock::now() > deadline) {
      const rig::RigSnapshot s = rig_.snapshot();
      throw Interrupted(Interrupted::Kind::timeout,
                        fmt::format("the axes did not settle at rail {:.3f}, turntable {:.3f} in time (they are at "
                                    "{:.3f} and {:.3f})",
                                    targets.rail, targets.turntable, s.rail.position, s.turntable.position));
    }
    std::unique_lock lock(mutex_);
    changed_.wait_for(lock, std::chrono::milliseconds(5));
  }
}

void SweepRunner::collect(const PlanStep& step, std::chrono::system_clock::time_point started,
                          Clock::time_point deadline) {
  set_phase("settling");
  std::chrono::duration<double> settle = run_->plan.settle;
  // A simulated rig runs on its own clock: the plan's settle time is in the
  // rig's seconds.
  if (const auto& clock = rig_.sim_clock(); clock && !clock->is_manual()) settle /= clock->time_scale();
  sleep_checked(std::chrono::duration_cast<Clock::duration>(settle));

  const int wanted = run_->plan.frames_per_point;
  {
    const std::lock_guard lock(collection_mutex_);
    collection_.samples.clear();
    collection_.samples.reserve(static_cast<std::size_t>(wanted));
    collection_.wanted = wanted;
    collection_.corrupt = 0;
    collection_.have_snapshot = false;
    collection_.not_before = Clock::now();
    collection_.active = true;
  }
  set_phase("collecting");
  // Whatever interrupts the collection ends it: frames after an
  // interruption belong to the step's next attempt.
  struct EndCollection {
    SweepRunner& runner;
    ~EndCollection() {
      const std::lock_guard lock(runner.collection_mutex_);
      runner.collection_.active = false;
    }
  } end_collection{*this};

  for (;;) {
    checkpoint();
    std::unique_lock lock(collection_mutex_);
    if (collection_changed_.wait_for(lock, std::chrono::milliseconds(20), [&] { return !collection_.active; })) break;
    if (Clock::now() > deadline) {
      throw Interrupted(Interrupted::Kind::timeout,
                        fmt::format("{} of {} frames at the point in time", collection_.samples.size(), wanted));
    }
  }

  PointRecord record;
  {
    const std::lock_guard lock(collection_mutex_);
    record.frames = collection_.samples;
    record.frames_corrupt = collection_.corrupt;
    const rig::RigSnapshot s = collection_.have_snapshot ? collection_.first_snapshot : rig_.snapshot();
    record.rail = s.rail.position;
    record.turntable = s.turntable.position;
    const rig::MarkerGroundTruth truth = rig_.ground_truth(s);
    for (int i = 0; i < 3; ++i) record.truth_tvec_m[static_cast<std::size_t>(i)] = truth.translation[i];
    record.truth_distance_m = truth.distance_m;
    record.truth_yaw_deg = truth.yaw_deg;
  }
  record.step = step.index;
  record.grid = step.grid;
  record.point = step.point;
  record.repeat = step.repeat;
  record.distance_m = step.distance_m;
  record.angle_deg = step.angle_deg;
  record.started = started;
  record.finished = std::chrono::system_clock::now();
  record.uid = new_uuid4();
  {
    const std::lock_guard records(records_mutex_);
    run_->recorder.append_point(record);  // the step is done once this returns
  }

  int detected = 0;
  for (const FrameSample& f : record.frames) detected += f.detected ? 1 : 0;
  const std::lock_guard lock(mutex_);
  ++run_->done;
  run_->last_rate =
      record.frames.empty() ? 0.0 : static_cast<double>(detected) / static_cast<double>(record.frames.size());
}

void SweepRunner::wait_paused() {
  stop_motion();
  {
    const std::lock_guard lock(mutex_);
    state_ = RunState::paused;
    phase_.clear();
  }
  changed_.notify_all();
  write_journal(run_->directory, kJournalPaused, true);
  const std::size_t at = run_->done;
  append_event({std::chrono::system_clock::now(), "paused", {}, at});
  spdlog::info("sweep {}: paused at step {}", run_->run_id, at);
  {
    std::unique_lock lock(mutex_);
    while (pause_requested_ && !abort_requested_ && !stop_.stop_requested()) {
      changed_.wait_for(lock, std::chrono::milliseconds(50));
    }
    if (stop_.stop_requested()) throw Interrupted(Interrupted::Kind::stop);
    if (abort_requested_) throw Interrupted(Interrupted::Kind::abort);
    state_ = RunState::running;
  }
  changed_.notify_all();
  write_journal(run_->directory, kJournalRunning, false);
  append_event({std::chrono::system_clock::now(), "resumed", {}, at});
  spdlog::info("sweep {}: resumed at step {}", run_->run_id, at);
}

void SweepRunner::suspend(const std::string& cause) {
  stop_motion();
  {
    const std::lock_guard lock(mutex_);
    state_ = RunState::suspended;
    reason_ = cause;
    phase_.clear();
  }
  changed_.notify_all();
  const std::size_t at = run_->done;
  append_event({std::chrono::system_clock::now(), "suspended", cause, at});
  spdlog::warn("sweep {}: suspended at step {}: {}", run_->run_id, at, cause);

  const auto since = Clock::now();
  auto retry_after = settings_.fault_retry_first;
  auto next_retry = since + retry_after;
  std::string current = cause;
  for (;;) {
    {
      std::unique_lock lock(mutex_);
      changed_.wait_for(lock, std::chrono::milliseconds(50));
      if (abort_requested_) throw Interrupted(Interrupted::Kind::abort);
    }
    if (stop_.stop_requested()) throw Interrupted(Interrupted::Kind::stop);
    const std::optional<std::string> now_fault = fault();
    if (!now_fault) break;
    current = *now_fault;
    const auto now = Clock::now();
    if (run_->plan.fault_timeout.count() > 0 && now - since > run_->plan.fault_timeout) {
      throw RunFailed(fmt::format("{} (suspended for longer than the plan's fault_timeout of {} s)", current,
                                  run_->plan.fault_timeout.count() / 1000.0));
    }
    if (now >= next_retry) {
      // A drive in alarm stays in alarm until it is reset; resetting it is
      // how a run finds out whether the cause has gone (an e-stop released,
      // a bus answering again). Refusals are the answer "not yet".
      for (rig::Axis* axis : {&rig_.rail(), &rig_.turntable()}) {
        if (axis->status().state != rig::AxisState::fault) continue;
        try {
          axis->clear_fault();
        } catch (const std::exception& e) {
          spdlog::debug("sweep {}: {} still in fault: {}", run_->run_id, axis->settings().name, e.what());
        }
      }
      retry_after = std::min(retry_after * 2, settings_.fault_retry_max);
      next_retry = now + retry_after;
    }
  }
  {
    const std::lock_guard lock(mutex_);
    state_ = RunState::running;
    reason_.clear();
  }
  changed_.notify_all();
  append_event({std::chrono::system_clock::now(), "fault_cleared", cause, at});
  spdlog::info("sweep {}: the fault cleared; resuming at step {}", run_->run_id, at);
}

void SweepRunner::stop_motion() noexcept {
  for (rig::Axis* axis : {&rig_.rail(), &rig_.turntable()}) {
    try {
      const rig::AxisStatus s = axis->status();
      if (s.state == rig::AxisState::moving || s.state == rig::AxisState::homing) axis->stop();
    } catch (const std::exception& e) {
      spdlog::error("sweep: stopping the {} failed ({}); emergency stop", axis->settings().name, e.what());
      axis->emergency_stop();
    }
  }
}

void SweepRunner::stop_and_disable() noexcept {
  stop_motion();
  const auto deadline = Clock::now() + std::chrono::seconds(5);
  while (Clock::now() < deadline) {
    const rig::RigSnapshot s = rig_.snapshot();
    if (!s.rail.moving && !s.turntable.moving) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  for (rig::Axis* axis : {&rig_.rail(), &rig_.turntable()}) {
    try {
      axis->disable();
    } catch (const std::exception& e) {
      spdlog::error("sweep: disabling the {} failed ({}); emergency stop", axis->settings().name, e.what());
      axis->emergency_stop();
    }
  }
}

void SweepRunner::leave_for_restart() noexcept {
  // markerd stops: the journal stays, and says so, and so do the run's
  // events; the next markerd resumes here and names the interruption.
  stop_motion();
  const std::size_t at = run_->done;
  bool paused = false;
  {
    const std::lock_guard lock(mutex_);
    paused = pause_requested_;
  }
  const std::string reason = "markerd was stopped (SIGTERM, SIGINT or its service stopped)";
  try {
    write_journal(run_->directory, kJournalStopped, paused, reason);
    append_event({std::chrono::system_clock::now(), "stopped", reason, at});
  } catch (const std::exception& e) {
    // The journal still names the run: the next markerd resumes it, and
    // records the interruption without its cause.
    spdlog::error("sweep {}: cannot record that markerd stops: {}", run_->run_id, e.what());
  }
  spdlog::info("sweep {}: markerd stops at step {}; the run resumes when it starts again", run_->run_id, at);
  set_phase("");
}

void SweepRunner::end_run(RunState state, const std::string& reason) {
  // The axes are told to stop first (it takes no disk), then the end goes
  // into the journal, the file a restarted markerd reads: from then on the
  // run can never be resumed as though it had only been cut off.
  stop_motion();
  const bool recorded = record_end_in_journal(state, reason);
  stop_and_disable();
  RunStop record;
  record.time = std::chrono::system_clock::now();
  record.status = exit_status(state);
  record.reason = reason;
  record.steps_done = run_->done;
  record.uid = run_->stop_uid;
  record.run_start = run_->start_uid;
  std::string ended_reason = reason;
  try {
    {
      const std::lock_guard records(records_mutex_);
      run_->recorder.finish(record);
    }
    write_run_documents(run_->directory);
    std::error_code ec;
    fs::remove(settings_.journal, ec);
  } catch (const std::exception& e) {
    // The journal stays, saying how the run ended: the next markerd (or the
    // next start) writes the stop record from it and does not resume the run.
    spdlog::error("sweep {}: cannot write its stop record: {}", run_->run_id, e.what());
    ended_reason += fmt::format(" (its stop record could not be written: {}{})", e.what(),
                                recorded ? "; the journal keeps it"
                                         : "; nor could the journal record the end: it was removed, so that the run "
                                           "is not resumed");
  }
  // The summary the operator finds in the morning, from the records alone:
  // the tables now; `markerctl report` draws the plots (running gnuplot is
  // not a device daemon's business).
  try {
    ReportOptions options;
    options.output_directory = run_->directory / "report";
    options.plots = false;
    write_report({read_run(run_->directory)}, options);
  } catch (const std::exception& e) {
    spdlog::error("sweep {}: cannot write its summary: {}", run_->run_id, e.what());
  }
  {
    const std::lock_guard lock(mutex_);
    state_ = state;
    reason_ = ended_reason;
    phase_.clear();
    run_->current.reset();
    run_->ended = Clock::now();
  }
  changed_.notify_all();
  if (state == RunState::done) {
    spdlog::info("sweep {}: done, {} steps; records in {}", run_->run_id, run_->done, run_->directory.string());
  } else {
    spdlog::warn("sweep {}: {} at step {}: {}", run_->run_id, to_string(state), run_->done, ended_reason);
  }
}

void write_run_documents(const fs::path& run_directory) noexcept {
  try {
    const RunRecords records = read_run(run_directory);
    if (records.start.uid.empty()) {
      spdlog::info("sweep {}: no {}: the run began before markerd gave its records uids", records.start.run_id,
                   kDocumentsFile);
      return;
    }
    write_documents(records);
  } catch (const std::exception& e) {
    spdlog::error("sweep run {}: cannot write its {}: {}", run_directory.string(), kDocumentsFile, e.what());
  }
}

}  // namespace markerd::sweep
