#include "markerd/rig/gpio_stepper.hpp"

#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <limits>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "markerd/base/errno_text.hpp"
#include "markerd/rig/motion_profile.hpp"

namespace markerd::rig {
namespace {

constexpr std::int64_t kNsPerSecond = 1'000'000'000;
// The longest single sleep of the step thread. Between slow steps it wakes at
// least this often to notice an abort, so that busy clears promptly after an
// emergency stop even when the next step is far away.
constexpr std::int64_t kSleepSliceNs = 2'000'000;
constexpr int kMaxRtPriority = 99;
// Step pulses up to this width are timed by spinning on the clock (the vDSO,
// no system call): a sleep that short costs a whole wake-up latency (tens of
// microseconds) and would make every pulse, and every step, that much longer.
// Wider pulses sleep, so that the step thread never burns much CPU.
constexpr std::int64_t kSpinPulseMaxNs = 20'000;

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * kNsPerSecond + ts.tv_nsec;
}

// Saturated at about 31 years (and NaN taken as that): a profile time or a
// timeout beyond it must not overflow the nanosecond count into the past.
std::int64_t seconds_to_ns(double seconds) {
  constexpr double kMaxSeconds = 1e9;
  return std::llround((std::isnan(seconds) ? kMaxSeconds : std::clamp(seconds, -kMaxSeconds, kMaxSeconds)) * 1e9);
}

void sleep_until_ns(std::int64_t due_ns) {
  const timespec due{static_cast<time_t>(due_ns / kNsPerSecond), static_cast<long>(due_ns % kNsPerSecond)};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &due, nullptr) == EINTR) {
  }
}

// CAP_IPC_LOCK lifts RLIMIT_MEMLOCK; read it from the effective capability set
// rather than linking libcap for one bit.
bool has_cap_ipc_lock() {
  std::ifstream status("/proc/self/status");
  std::string key;
  while (status >> key) {
    if (key == "CapEff:") {
      std::string hex;
      status >> hex;
      constexpr int kCapIpcLock = 14;
      return ((std::stoull(hex, nullptr, 16) >> kCapIpcLock) & 1U) != 0;
    }
    status.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
  }
  return false;
}

// Locks the process's memory once, so that no page fault delays a step. Only
// where the lock is unlimited: with a finite RLIMIT_MEMLOCK, MCL_FUTURE would
// make later allocations of the whole daemon fail once the limit is reached.
void lock_memory_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    rlimit limit{};
    getrlimit(RLIMIT_MEMLOCK, &limit);
    if (limit.rlim_cur != RLIM_INFINITY && !has_cap_ipc_lock()) {
      spdlog::warn(
          "gpio stepper: memory not locked (RLIMIT_MEMLOCK is {} KiB and no CAP_IPC_LOCK): a page fault can delay "
          "a step; run the service with LimitMEMLOCK=infinity (docs/rig-gpio.md)",
          limit.rlim_cur / 1024);
      return;
    }
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
      spdlog::warn("gpio stepper: mlockall failed ({}): a page fault can delay a step", errno_text(errno));
    }
  });
}

// SCHED_FIFO for the calling thread. Refused (EPERM) without CAP_SYS_NICE or
// an RLIMIT_RTPRIO: the drive stays correct, only its steps are less even.
bool make_realtime(int priority) {
  // Normal threads have 50 us of timer slack: far too coarse for steps.
  // SCHED_FIFO threads have none; this covers the fallback.
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  if (priority <= 0) return false;
  const sched_param param{priority};
  const int error = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
  if (error == 0) return true;
  static std::once_flag once;
  std::call_once(once, [&] {
    spdlog::warn(
        "gpio stepper: SCHED_FIFO priority {} refused ({}): stepping with normal scheduling, correct but less "
        "even; grant it with LimitRTPRIO / CPUSchedulingPolicy=fifo (docs/rig-gpio.md)",
        priority, errno_text(error));
  });
  return false;
}

// Touches the stack the step loop will use, so that its pages are resident
// (and locked, after mlockall) before the first step.
[[gnu::noinline]] void prefault_stack() {
  volatile unsigned char stack[64 * 1024];
  for (std::size_t i = 0; i < sizeof stack; i += 1024) stack[i] = 0;
}

const char* input_key(std::size_t input) {
  static constexpr const char* keys[] = {"limit_min", "limit_max", "home", "estop"};
  return keys[input];
}

// The first problem with the settings, as (key, message), for the config
// parser (ConfigError with the key's line) and the constructor (DriveError).
// The supported-rate cap is the parser's: a configured rig never exceeds it,
// while bench_step_timing builds drives directly to measure beyond it.
enum class RateCap : bool { ignore, enforce };
std::optional<std::pair<std::string, std::string>> settings_problem(const GpioStepperSettings& s, RateCap cap) {
  using namespace std::chrono;
  auto problem = [](std::string key, std::string message) {
    return std::optional<std::pair<std::string, std::string>>(std::in_place, std::move(key), std::move(message));
  };
  const std::pair<const char*, const std::optional<GpioLineSpec>*> lines[] = {
      {"step", nullptr},           {"dir", nullptr},  {"enable", nullptr}, {"limit_min", &s.limit_min},
      {"limit_max", &s.limit_max}, {"home", &s.home}, {"estop", &s.estop}};
  const GpioLineSpec* required[] = {&s.step, &s.dir, &s.enable};
  std::vector<std::pair<const char*, const GpioLineSpec*>> used;
  for (std::size_t i = 0; i < std::size(lines); ++i) {
    const GpioLineSpec* spec = i < 3 ? required[i] : (lines[i].second->has_value() ? &**lines[i].second : nullptr);
    if (spec == nullptr) continue;
    if (spec->line.empty()) return problem(lines[i].first, "no line given");
    for (const auto& [other_key, other] : used) {
      if (other->chip == spec->chip && other->line == spec->line) {
        return problem(lines[i].first, fmt::format("line '{}' is already used by {}", spec->line, other_key));
      }
    }
    used.emplace_back(lines[i].first, spec);
  }
  if (!(s.max_step_rate > 0)) return problem("max_step_rate", fmt::format("must be > 0, got {}", s.max_step_rate));
  if (cap == RateCap::enforce && s.max_step_rate > kGpioStepperMaxStepRate) {
    return problem("max_step_rate",
                   fmt::format("{} steps/s is above what this backend supports ({} steps/s: the step timing of Linux "
                               "user space, see docs/rig-gpio.md); use a Modbus drive or a pulse generator for faster "
                               "motion, or coarser microstepping",
                               s.max_step_rate, kGpioStepperMaxStepRate));
  }
  if (s.step_pulse <= nanoseconds(0)) return problem("step_pulse_us", "must be > 0");
  // The line must also stay low at least as long as it was high.
  const double period_ns = 1e9 / s.max_step_rate;
  if (2.0 * static_cast<double>(s.step_pulse.count()) > period_ns) {
    return problem("step_pulse_us", fmt::format("{} us high plus as long low does not fit a step period of {:.1f} us "
                                                "at max_step_rate {} steps/s",
                                                s.step_pulse.count() / 1e3, period_ns / 1e3, s.max_step_rate));
  }
  if (s.dir_setup < nanoseconds(0)) return problem("dir_setup_us", "must be >= 0");
  if (s.enable_settle < nanoseconds(0) || s.enable_settle > seconds(10)) {
    return problem("enable_settle_ms", "must be between 0 and 10000");
  }
  if (s.debounce < nanoseconds(0) || s.debounce > seconds(1))
    return problem("debounce_ms", "must be between 0 and 1000");
  if (s.rt_priority < 0 || s.rt_priority > kMaxRtPriority) {
    return problem("rt_priority", fmt::format("must be 0 (normal scheduling) or a SCHED_FIFO priority 1 to {}, got {}",
                                              kMaxRtPriority, s.rt_priority));
  }
  if (s.consumer.empty()) return problem("consumer", "must not be empty");
  return std::nullopt;
}

}  // namespace

// ---------------------------------------------------------------- config

GpioStepperSettings parse_gpio_stepper(const ConfigTable& t) {
  t.allow_only({"chip", "consumer", "step", "dir", "enable", "limit_min", "limit_max", "home", "estop", "step_pulse_us",
                "dir_setup_us", "enable_settle_ms", "debounce_ms", "max_step_rate", "rt_priority"});
  GpioStepperSettings s;
  const auto chip = t.required<std::string>("chip");
  if (chip.empty()) t.fail("chip", "must name a chip (a path, gpiochipN or the chip's label)");

  auto line = [&](std::string_view key) -> std::optional<GpioLineSpec> {
    const auto sub = t.maybe_table(key);
    if (!sub) return std::nullopt;
    sub->allow_only({"line", "active_low"});
    GpioLineSpec spec{chip, "", sub->optional<bool>("active_low", false)};
    // An integer is an offset; a string is a line name (or an offset in digits).
    if (const toml::node* node = sub->raw().get("line"); node != nullptr && node->is_integer()) {
      spec.line = std::to_string(sub->required<std::int64_t>("line", {0, 65535}));
    } else {
      spec.line = sub->required<std::string>("line");
      if (spec.line.empty()) sub->fail("line", "must not be empty");
    }
    return spec;
  };
  auto required_line = [&](std::string_view key) {
    auto spec = line(key);
    if (!spec) t.fail(fmt::format("missing table '{}' ({} = {{ line = ..., active_low = ... }})", key, key));
    return *spec;
  };
  s.step = required_line("step");
  s.dir = required_line("dir");
  s.enable = required_line("enable");
  s.limit_min = line("limit_min");
  s.limit_max = line("limit_max");
  s.home = line("home");
  s.estop = line("estop");

  // Converted to nanoseconds only once in range.
  auto duration = [&](std::string_view key, double scale_ns, std::chrono::nanoseconds fallback,
                      ConfigTable::Range<double> range) {
    const auto value = t.maybe<double>(key, range);
    if (!value) return fallback;
    return std::chrono::nanoseconds(std::llround(*value * scale_ns));
  };
  s.step_pulse = duration("step_pulse_us", 1e3, s.step_pulse, {0.001, 100000, "us"});
  s.dir_setup = duration("dir_setup_us", 1e3, s.dir_setup, {0, 100000, "us"});
  s.enable_settle = duration("enable_settle_ms", 1e6, s.enable_settle, {0, 10000, "ms"});
  s.debounce = duration("debounce_ms", 1e6, s.debounce, {0, 1000, "ms"});
  // Beyond kGpioStepperMaxStepRate settings_problem explains what to use instead.
  s.max_step_rate = t.optional<double>("max_step_rate", s.max_step_rate, {1, 1e9, "steps/s"});
  s.rt_priority = t.optional<int>("rt_priority", s.rt_priority);  // its range and meaning: settings_problem
  s.consumer = t.optional<std::string>("consumer", s.consumer);
  if (auto problem = settings_problem(s, RateCap::enforce)) {
    if (t.contains(problem->first)) t.fail(problem->first, problem->second);
    t.fail(fmt::format("{}: {}", problem->first, problem->second));
  }
  return s;
}

// ---------------------------------------------------------------- the drive

enum class GpioStepperDrive::End : std::uint8_t {
  completed,  // every step of the profile issued
  watch_met,  // the watched input reached its state (stopped at once, or braked after it)
  stopped,    // stop() was requested; braked to rest
  limit,      // the limit switch ahead tripped; stopped at once
  aborted,    // disabled (emergency stop, e-stop input, enable(false)); stopped at once
  timeout,    // the segment's deadline passed; stopped at once
};

struct GpioStepperDrive::Command {
  enum class Kind : std::uint8_t { move, homing } kind = Kind::move;
  std::int64_t target_steps = 0;
  double max_steps_per_s = 0;
  double accel_steps_per_s2 = 0;
  HomingSteps homing;
};

// One stretch of motion in one direction along one trapezoidal profile.
struct GpioStepperDrive::Segment {
  int direction = +1;
  std::int64_t steps = 0;
  double max_steps_per_s = 0;
  double accel_steps_per_s2 = 0;
  // Optionally, an input that ends the segment when it reaches `watch_active`
  // (but not before `watch_after` steps): at once, or with a braking ramp.
  Input watch = input_count;
  bool watch_active = true;
  std::int64_t watch_after = 0;
  bool brake_on_watch = false;
  std::int64_t deadline_ns = std::numeric_limits<std::int64_t>::max();
};

struct GpioStepperDrive::InputChannel {
  std::unique_ptr<GpioInput> line;
  std::atomic<bool> active{false};            // debounced, published to every thread
  std::optional<std::int64_t> release_check;  // input thread: when to confirm a release
};

GpioStepperDrive::GpioStepperDrive(std::string axis_name, GpioStepperSettings settings, GpioBackend& backend)
    : name_(fmt::format("{} (gpio {})", axis_name, settings.step.chip)), settings_(std::move(settings)) {
  if (auto problem = settings_problem(settings_, RateCap::ignore)) {
    throw DriveError(fmt::format("{}: {}: {}", name_, problem->first, problem->second));
  }
  auto with_name = [&](auto&& request) {
    try {
      return request();
    } catch (const DriveError& e) {
      throw DriveError(fmt::format("{}: {}", name_, e.what()));
    }
  };
  // Outputs start inactive: no step, and the driver unpowered until enable().
  step_ = with_name([&] { return backend.request_output(settings_.step, false, settings_.consumer); });
  dir_ = with_name([&] { return backend.request_output(settings_.dir, false, settings_.consumer); });
  enable_line_ = with_name([&] { return backend.request_output(settings_.enable, false, settings_.consumer); });
  const std::optional<GpioLineSpec>* specs[] = {&settings_.limit_min, &settings_.limit_max, &settings_.home,
                                                &settings_.estop};
  for (std::size_t i = 0; i < input_count; ++i) {
    if (!specs[i]->has_value()) continue;
    auto channel = std::make_unique<InputChannel>();
    // Events are requested before the level is read, so no edge between the
    // two can be lost.
    channel->line = with_name([&] { return backend.request_input(**specs[i], true, settings_.consumer); });
    channel->active = with_name([&] { return channel->line->get(); });
    inputs_[i] = std::move(channel);
  }
  if (input_active(estop)) raise_alarm("e-stop input active at start", AlarmAction::none);

  if (settings_.rt_priority > 0) lock_memory_once();
  shutdown_fd_ = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (shutdown_fd_ < 0) throw DriveError(fmt::format("{}: eventfd: {}", name_, errno_text(errno)));
  try {
    input_thread_ = std::jthread([this](std::stop_token stop) { input_thread_main(stop); });
    step_thread_ = std::jthread([this](std::stop_token stop) { step_thread_main(stop); });
    step_thread_ready_.wait(false);
  } catch (...) {
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto ignored = ::write(shutdown_fd_, &one, sizeof one);
    if (input_thread_.joinable()) input_thread_.join();
    close(shutdown_fd_);
    throw;
  }
}

GpioStepperDrive::~GpioStepperDrive() {
  disable_now(false);
  step_thread_.request_stop();
  if (step_thread_.joinable()) step_thread_.join();
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto ignored = ::write(shutdown_fd_, &one, sizeof one);
  input_thread_.request_stop();
  if (input_thread_.joinable()) input_thread_.join();
  close(shutdown_fd_);
}

bool GpioStepperDrive::input_active(Input input) const {
  return inputs_[input] != nullptr && inputs_[input]->active.load(std::memory_order_acquire);
}

// The fault's consequences (the enable line inactive first: fail safe; home
// lost) and the alarm are published together, under alarm_mutex_, so that
// status() never shows a drive disabled by a fault without its alarm. The
// log lines follow, outside the locks.
void GpioStepperDrive::raise_alarm(std::string cause, AlarmAction action) {
  std::optional<std::string> disable_failure;
  {
    const std::lock_guard lock(alarm_mutex_);
    if (action == AlarmAction::disable) {
      disable_failure = switch_off(true);
    } else if (action == AlarmAction::lose_home) {
      homed_.store(false);
    }
    if (!alarm_.load()) {  // the first cause is the one to act on
      alarm_cause_ = cause;
      alarm_.store(true);
    }
  }
  if (disable_failure) spdlog::critical("{}: cannot disable the driver: {}", name_, *disable_failure);
  spdlog::error("{}: {}", name_, cause);
}

std::optional<std::string> GpioStepperDrive::switch_off(bool lose_home) noexcept {
  const std::lock_guard lock(enable_mutex_);
  abort_.store(true);
  std::optional<std::string> failure;
  try {
    enable_line_->set(false);
  } catch (const std::exception& e) {
    failure = e.what();
  }
  enabled_.store(false);
  if (lose_home) homed_.store(false);
  return failure;
}

void GpioStepperDrive::disable_now(bool lose_home) noexcept {
  std::optional<std::string> failure;
  {
    // Disabled and home lost appear together in status().
    const std::lock_guard lock(alarm_mutex_);
    failure = switch_off(lose_home);
  }
  if (failure) spdlog::critical("{}: cannot disable the driver: {}", name_, *failure);
}

void GpioStepperDrive::emergency_stop() noexcept {
  disable_now(true);
  spdlog::warn("{}: emergency stop at step {}: disabled, home lost", name_, position_.load());
}

void GpioStepperDrive::wait_until_idle() {
  // The step thread notices an abort within one sleep slice.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(1);
  while (busy_.load()) {
    if (std::chrono::steady_clock::now() > deadline) {
      throw DriveError(fmt::format("{}: the step thread has not stopped after a second", name_));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
}

void GpioStepperDrive::enable(bool on) {
  if (!on) {
    // Disabling under motion drops the step count's meaning.
    disable_now(busy_.load());
    return;
  }
  if (inputs_failed_.load()) throw DriveError(fmt::format("{}: cannot enable: the input thread failed", name_));
  if (input_active(estop)) throw DriveError(fmt::format("{}: cannot enable: e-stop input active", name_));
  if (enabled_.load()) return;
  wait_until_idle();  // an aborted move may still be finishing its last sleep slice
  const std::lock_guard lock(enable_mutex_);
  enable_line_->set(true);
  enabled_at_ns_.store(now_ns());
  abort_.store(false);
  enabled_.store(true);
}

void GpioStepperDrive::check_can_move(int direction, double steps_per_s, const char* what) const {
  if (busy_.load()) throw DriveError(fmt::format("{}: busy: a move or homing is in progress", name_));
  if (inputs_failed_.load()) throw DriveError(fmt::format("{}: the input thread failed; restart the drive", name_));
  if (alarm_.load()) {
    const std::lock_guard lock(alarm_mutex_);
    throw DriveError(fmt::format("{}: alarm latched ({}); reset the alarm first", name_, alarm_cause_));
  }
  if (input_active(estop)) throw DriveError(fmt::format("{}: e-stop input active", name_));
  if (!enabled_.load()) throw DriveError(fmt::format("{}: not enabled", name_));
  if (!(steps_per_s > 0) || steps_per_s > settings_.max_step_rate) {
    throw DriveError(fmt::format("{}: {} at {} steps/s: must be > 0 and at most max_step_rate = {} steps/s", name_,
                                 what, steps_per_s, settings_.max_step_rate));
  }
  const Input ahead = direction > 0 ? limit_max : limit_min;
  if (direction != 0 && input_active(ahead)) {
    throw DriveError(
        fmt::format("{}: {} active: cannot move towards it (moving away is allowed)", name_, input_key(ahead)));
  }
}

void GpioStepperDrive::start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) {
  const std::int64_t distance = target_steps - position_.load();
  const int direction = distance > 0 ? +1 : (distance < 0 ? -1 : 0);
  check_can_move(direction, max_steps_per_s, "move");
  if (!(accel_steps_per_s2 > 0)) {
    throw DriveError(fmt::format("{}: acceleration must be > 0 steps/s^2, got {}", name_, accel_steps_per_s2));
  }
  if (distance == 0) return;
  auto command = std::make_unique<Command>();
  command->kind = Command::Kind::move;
  command->target_steps = target_steps;
  command->max_steps_per_s = max_steps_per_s;
  command->accel_steps_per_s2 = accel_steps_per_s2;
  stop_requested_.store(false);
  busy_.store(true);
  {
    const std::lock_guard lock(command_mutex_);
    pending_ = std::move(command);
  }
  command_ready_.notify_one();
}

void GpioStepperDrive::start_homing(const HomingSteps& homing) {
  const Input target = homing.target == HomingSteps::Switch::home        ? home
                       : homing.target == HomingSteps::Switch::limit_min ? limit_min
                                                                         : limit_max;
  if (inputs_[target] == nullptr) {
    throw DriveError(fmt::format("{}: homing needs the {} input, and [gpio] configures no {} line", name_,
                                 input_key(target), input_key(target)));
  }
  if (homing.direction != 1 && homing.direction != -1) {
    throw DriveError(fmt::format("{}: homing direction must be +1 or -1, got {}", name_, homing.direction));
  }
  if ((target == limit_min && homing.direction > 0) || (target == limit_max && homing.direction < 0)) {
    throw DriveError(fmt::format("{}: homing on {} must search towards it (direction {})", name_, input_key(target),
                                 target == limit_min ? -1 : +1));
  }
  // A day bounds the step count the timeout allows (and its nanoseconds).
  if (!(homing.accel_steps_per_s2 > 0) || homing.backoff_steps < 0 ||
      !(homing.timeout_s > 0 && homing.timeout_s <= 86400)) {
    throw DriveError(
        fmt::format("{}: homing needs an acceleration > 0, a backoff >= 0 and a timeout from 0 to a day", name_));
  }
  check_can_move(0, homing.search_steps_per_s, "homing search");
  check_can_move(0, homing.latch_steps_per_s, "homing latch");
  // The limit ahead of the search blocks homing unless it is the switch sought.
  const Input ahead = homing.direction > 0 ? limit_max : limit_min;
  if (ahead != target && input_active(ahead)) {
    throw DriveError(
        fmt::format("{}: {} active: cannot search towards it for {}", name_, input_key(ahead), input_key(target)));
  }
  auto command = std::make_unique<Command>();
  command->kind = Command::Kind::homing;
  command->homing = homing;
  stop_requested_.store(false);
  homed_.store(false);
  busy_.store(true);
  {
    const std::lock_guard lock(command_mutex_);
    pending_ = std::move(command);
  }
  command_ready_.notify_one();
}

void GpioStepperDrive::stop() {
  if (busy_.load()) stop_requested_.store(true);
}

void GpioStepperDrive::reset_alarm() {
  if (inputs_failed_.load()) throw DriveError(fmt::format("{}: the input thread failed; restart the drive", name_));
  if (input_active(estop))
    throw DriveError(fmt::format("{}: cannot reset the alarm: e-stop input still active", name_));
  const std::lock_guard lock(alarm_mutex_);
  alarm_.store(false);
  alarm_cause_.clear();
}

DriveStatus GpioStepperDrive::status() const {
  DriveStatus s;
  s.position_steps = position_.load();
  s.busy = busy_.load();
  {
    // Under the lock that disables and alarms: a fault is seen whole.
    const std::lock_guard lock(alarm_mutex_);
    s.enabled = enabled_.load();
    s.homed = homed_.load();
    s.alarm = alarm_.load();
    s.alarm_cause = alarm_cause_;
  }
  s.inputs.limit_min = input_active(limit_min);
  s.inputs.limit_max = input_active(limit_max);
  s.inputs.home = input_active(home);
  s.inputs.estop = input_active(estop);
  return s;
}

GpioStepperStats GpioStepperDrive::stats() const {
  return GpioStepperStats{missed_deadlines_.load(), std::chrono::nanoseconds(max_lateness_ns_.load()),
                          std::chrono::nanoseconds(move_origin_ns_.load()), realtime_.load()};
}

// ---------------------------------------------------------------- step thread

void GpioStepperDrive::step_thread_main(const std::stop_token& stop) {
  realtime_.store(make_realtime(settings_.rt_priority));
  prefault_stack();
  step_thread_ready_.store(true);
  step_thread_ready_.notify_all();
  for (;;) {
    std::unique_ptr<Command> command;
    {
      std::unique_lock lock(command_mutex_);
      if (!command_ready_.wait(lock, stop, [&] { return pending_ != nullptr; })) return;
      command = std::move(pending_);
    }
    run(*command);
    busy_.store(false);
  }
}

void GpioStepperDrive::run(const Command& command) {
  max_lateness_ns_.store(0, std::memory_order_relaxed);
  try {
    if (command.kind == Command::Kind::homing) {
      run_homing(command.homing);
      return;
    }
    const std::int64_t distance = command.target_steps - position_.load();
    Segment move;
    move.direction = distance > 0 ? +1 : -1;
    move.steps = distance > 0 ? distance : -distance;
    move.max_steps_per_s = command.max_steps_per_s;
    move.accel_steps_per_s2 = command.accel_steps_per_s2;
    if (run_segment(move) == End::limit) {
      // At speed, an abrupt stop may lose steps: the position is no longer trusted.
      const Input ahead = move.direction > 0 ? limit_max : limit_min;
      raise_alarm(fmt::format("{} tripped at step {} while moving towards it: stopped at once, home lost",
                              input_key(ahead), position_.load()),
                  AlarmAction::lose_home);
    }
  } catch (const std::exception& e) {
    raise_alarm(fmt::format("{}; drive disabled", e.what()), AlarmAction::disable);
  }
}

void GpioStepperDrive::run_homing(const HomingSteps& homing) {
  const Input target = homing.target == HomingSteps::Switch::home        ? home
                       : homing.target == HomingSteps::Switch::limit_min ? limit_min
                                                                         : limit_max;
  const char* sought = input_key(target);
  const std::int64_t deadline = now_ns() + seconds_to_ns(homing.timeout_s);
  // Open-ended segments: long enough that only the switch or the deadline ends them.
  auto open_ended = [&](double v) {
    return static_cast<std::int64_t>(std::ceil(v * homing.timeout_s + v * v / homing.accel_steps_per_s2)) + 1;
  };
  auto fail = [&](End end, const char* phase) {
    if (end == End::stopped || end == End::aborted) return;  // commanded: no alarm
    if (end == End::limit) {
      raise_alarm(
          fmt::format("homing ({}): a limit switch tripped at step {} before {}: check the {} switch and "
                      "its wiring, and the homing direction",
                      phase, position_.load(), sought, sought));
    } else if (end == End::timeout) {
      raise_alarm(fmt::format("homing ({}): {} did not {} within the timeout of {} s (at step {})", phase, sought,
                              std::string_view(phase) == "back off" ? "release" : "activate", homing.timeout_s,
                              position_.load()));
    } else {
      raise_alarm(fmt::format("homing ({}): ended at step {} without {} changing", phase, position_.load(), sought));
    }
  };

  // 1. Search towards the switch (skipped when already on it). A home switch
  //    has travel beyond it: brake. A limit switch is the end of travel: stop at once.
  if (!input_active(target)) {
    Segment search;
    search.direction = homing.direction;
    search.steps = open_ended(homing.search_steps_per_s);
    search.max_steps_per_s = homing.search_steps_per_s;
    search.accel_steps_per_s2 = homing.accel_steps_per_s2;
    search.watch = target;
    search.brake_on_watch = target == home;
    search.deadline_ns = deadline;
    if (const End end = run_segment(search); end != End::watch_met) return fail(end, "search");
  }
  // 2. Back off until the switch releases, and at least backoff_steps.
  Segment backoff;
  backoff.direction = -homing.direction;
  backoff.steps = open_ended(homing.search_steps_per_s);
  backoff.max_steps_per_s = homing.search_steps_per_s;
  backoff.accel_steps_per_s2 = homing.accel_steps_per_s2;
  backoff.watch = target;
  backoff.watch_active = false;
  backoff.watch_after = homing.backoff_steps;
  backoff.brake_on_watch = true;
  backoff.deadline_ns = deadline;
  if (const End end = run_segment(backoff); end != End::watch_met) return fail(end, "back off");
  // 3. Approach slowly and stop at once on the switch: that step is the reference.
  Segment latch;
  latch.direction = homing.direction;
  latch.steps = open_ended(homing.latch_steps_per_s);
  latch.max_steps_per_s = homing.latch_steps_per_s;
  latch.accel_steps_per_s2 = homing.accel_steps_per_s2;
  latch.watch = target;
  latch.deadline_ns = deadline;
  if (const End end = run_segment(latch); end != End::watch_met) return fail(end, "latch");
  position_.store(homing.home_position_steps);
  homed_.store(true);
  spdlog::info("{}: homed on {}: position set to {}", name_, sought, homing.home_position_steps);
}

void GpioStepperDrive::set_direction(int direction) {
  if (direction == direction_) return;
  dir_->set(direction > 0);
  direction_set_ns_ = now_ns();
  direction_ = direction;
}

// Sleeps to an absolute due time in slices, returning false as soon as the
// drive is disabled.
bool GpioStepperDrive::sleep_until(std::int64_t due_ns) const {
  for (;;) {
    if (abort_.load(std::memory_order_relaxed)) return false;
    const std::int64_t now = now_ns();
    if (now >= due_ns) return true;
    sleep_until_ns(std::min(due_ns, now + kSleepSliceNs));
  }
}

// The real-time loop. Between the first and the last step it makes no
// allocation and takes no lock; its only system calls are the line writes and
// the sleeps (the clock is read through the vDSO).
GpioStepperDrive::End GpioStepperDrive::run_segment(const Segment& segment) {
  const std::atomic<bool>* limit_ahead = nullptr;
  if (const Input ahead = segment.direction > 0 ? limit_max : limit_min; inputs_[ahead] && ahead != segment.watch) {
    limit_ahead = &inputs_[ahead]->active;
  }
  const std::atomic<bool>* watched = segment.watch != input_count ? &inputs_[segment.watch]->active : nullptr;
  if (limit_ahead != nullptr && limit_ahead->load()) return End::limit;

  set_direction(segment.direction);
  // t = 0 of the profile: after the direction's setup time and the enable's
  // settle time; the first step follows at time_at(1).
  std::int64_t origin = std::max({now_ns(), direction_set_ns_ + settings_.dir_setup.count(),
                                  enabled_at_ns_.load() + settings_.enable_settle.count()});
  TrapezoidProfile profile(static_cast<double>(segment.steps), segment.max_steps_per_s, segment.accel_steps_per_s2);
  std::int64_t total = segment.steps;
  std::int64_t done_in_profile = 0;
  std::int64_t done_in_segment = 0;
  bool braking = false;
  End braked_for = End::stopped;
  const std::int64_t pulse_ns = settings_.step_pulse.count();
  move_origin_ns_.store(origin, std::memory_order_relaxed);

  while (done_in_profile < total) {
    const double t_previous = done_in_profile == 0 ? 0.0 : profile.time_at(static_cast<double>(done_in_profile));
    const double t_next = profile.time_at(static_cast<double>(done_in_profile + 1));
    const std::int64_t due = origin + seconds_to_ns(t_next);
    if (!sleep_until(due)) return End::aborted;

    // Decided at the step's due time, before its pulse.
    if (limit_ahead != nullptr && limit_ahead->load(std::memory_order_acquire)) return End::limit;
    if (!braking) {
      bool brake = false;
      if (watched != nullptr && done_in_segment >= segment.watch_after &&
          watched->load(std::memory_order_acquire) == segment.watch_active) {
        if (!segment.brake_on_watch) return End::watch_met;
        brake = true;
        braked_for = End::watch_met;
      } else if (stop_requested_.load(std::memory_order_relaxed)) {
        brake = true;
        braked_for = End::stopped;
      }
      if (brake) {
        // Re-plan from the last step: decelerate from the velocity the profile
        // had there. Its first step falls about one interval after that step.
        profile = TrapezoidProfile::braking(profile.velocity_at(t_previous), segment.accel_steps_per_s2);
        origin += seconds_to_ns(t_previous);
        total = static_cast<std::int64_t>(std::floor(profile.distance()));
        done_in_profile = 0;
        braking = true;
        move_origin_ns_.store(origin, std::memory_order_relaxed);
        continue;
      }
      if (now_ns() > segment.deadline_ns) return End::timeout;
    }

    // A step later than a quarter of its interval is a missed deadline: the
    // rest of the profile slips by the lateness instead of bursting steps to
    // catch up, so no interval is ever shorter than planned minus that quarter.
    const std::int64_t now = now_ns();
    const std::int64_t lateness = now - due;
    const std::int64_t tolerance = seconds_to_ns(t_next - t_previous) / 4;
    if (lateness > tolerance) {
      missed_deadlines_.fetch_add(1, std::memory_order_relaxed);
      origin += lateness;
    }
    if (lateness > max_lateness_ns_.load(std::memory_order_relaxed)) {
      max_lateness_ns_.store(lateness, std::memory_order_relaxed);
    }

    step_->set(true);
    const std::int64_t pulse_end = now_ns() + pulse_ns;  // from after the write: the pulse is at least this wide
    if (pulse_ns <= kSpinPulseMaxNs) {
      while (now_ns() < pulse_end) {
      }
    } else {
      sleep_until_ns(pulse_end);
    }
    step_->set(false);
    position_.fetch_add(segment.direction, std::memory_order_release);
    ++done_in_profile;
    ++done_in_segment;
  }
  return braking ? braked_for : End::completed;
}

// ---------------------------------------------------------------- input thread

void GpioStepperDrive::on_input_active(Input input) {
  spdlog::info("{}: {} active at step {}", name_, input_key(input), position_.load());
  if (input == estop) {
    raise_alarm(fmt::format("e-stop input active at step {}: drive disabled, home lost", position_.load()),
                AlarmAction::disable);
  }
}

// Debounce: an input becomes active on its first edge (a limit or e-stop acts
// at once; a home switch latches on its first contact, the repeatable point),
// and inactive only after it has read inactive for the debounce time with no
// edge in between, so contact bounce neither releases nor re-trips it.
void GpioStepperDrive::input_thread_main(const std::stop_token& stop) {
  make_realtime(settings_.rt_priority);
  std::vector<pollfd> fds{{shutdown_fd_, POLLIN, 0}};
  std::vector<InputChannel*> channel_of{nullptr};
  std::vector<Input> input_of{input_count};
  for (std::size_t i = 0; i < input_count; ++i) {
    if (!inputs_[i]) continue;
    fds.push_back({inputs_[i]->line->event_fd(), POLLIN, 0});
    channel_of.push_back(inputs_[i].get());
    input_of.push_back(static_cast<Input>(i));
  }
  const std::int64_t debounce_ns = settings_.debounce.count();
  try {
    while (!stop.stop_requested()) {
      std::int64_t next_check = std::numeric_limits<std::int64_t>::max();
      for (std::size_t k = 1; k < fds.size(); ++k) {
        if (channel_of[k]->release_check) next_check = std::min(next_check, *channel_of[k]->release_check);
      }
      int timeout_ms = -1;
      if (next_check != std::numeric_limits<std::int64_t>::max()) {
        timeout_ms = static_cast<int>(std::max<std::int64_t>(0, (next_check - now_ns() + 999'999) / 1'000'000));
      }
      if (poll(fds.data(), fds.size(), timeout_ms) < 0) {
        if (errno == EINTR) continue;
        throw DriveError(fmt::format("poll on the inputs: {}", errno_text(errno)));
      }
      if (fds[0].revents != 0) return;
      const std::int64_t now = now_ns();
      for (std::size_t k = 1; k < fds.size(); ++k) {
        InputChannel& channel = *channel_of[k];
        if ((fds[k].revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
          throw DriveError(fmt::format("the {} line's event descriptor failed", input_key(input_of[k])));
        }
        if ((fds[k].revents & POLLIN) == 0) continue;
        bool edge_to_active = false;
        while (const auto event = channel.line->read_event()) edge_to_active = edge_to_active || event->active;
        const bool level = channel.line->get();
        if (edge_to_active || level) {
          if (!channel.active.exchange(true, std::memory_order_acq_rel)) on_input_active(input_of[k]);
        }
        if (level) {
          channel.release_check.reset();
        } else if (channel.active.load()) {
          channel.release_check = now + debounce_ns;  // every edge restarts the quiet time
        }
      }
      for (std::size_t k = 1; k < fds.size(); ++k) {
        InputChannel& channel = *channel_of[k];
        if (!channel.release_check || *channel.release_check > now_ns()) continue;
        channel.release_check.reset();
        if (!channel.line->get()) {
          channel.active.store(false, std::memory_order_release);
          spdlog::info("{}: {} released at step {}", name_, input_key(input_of[k]), position_.load());
        }
      }
    }
  } catch (const std::exception& e) {
    // Without its inputs the axis cannot stop at its limits: stop for good.
    inputs_failed_.store(true);
    raise_alarm(fmt::format("input monitoring failed ({}): drive disabled until restarted", e.what()),
                AlarmAction::disable);
  }
}

std::unique_ptr<Drive> make_gpio_stepper_drive(std::string axis_name, const GpioStepperSettings& settings) {
  const auto backend = make_gpiod1_backend();
  return std::make_unique<GpioStepperDrive>(std::move(axis_name), settings, *backend);
}

}  // namespace markerd::rig
