#include "rig_session.hpp"

#include <unistd.h>

#include <filesystem>
#include <iostream>

#include "live_line.hpp"
#include "markerd/base/config_table.hpp"

namespace markerctl {

using markerd::rig::AxisSettings;
using markerd::rig::AxisState;
using markerd::rig::AxisStatus;
using namespace std::chrono_literals;

bool in_motion(AxisState state) {
  return state == AxisState::moving || state == AxisState::homing || state == AxisState::stopping;
}

std::string position_text(const AxisSettings& axis, double value) { return fmt::format("{:.3f} {}", value, axis.unit); }

std::string inputs_text(const markerd::rig::DriveInputs& in) {
  std::string text;
  const std::pair<bool, const char*> inputs[] = {
      {in.limit_min, "limit_min"}, {in.limit_max, "limit_max"}, {in.home, "home"}, {in.estop, "estop"}};
  for (const auto& [active, name] : inputs) {
    if (!active) continue;
    if (!text.empty()) text += ' ';
    text += name;
  }
  return text.empty() ? "none active" : text + " active";
}

nlohmann::ordered_json axis_json(const AxisSettings& settings, const AxisStatus& s) {
  nlohmann::ordered_json j;
  j["state"] = markerd::rig::to_string(s.state);
  j["homed"] = s.homed;
  j["settled"] = s.settled;
  j["position"] = rounded(s.position, 6);
  j["target"] = rounded(s.target, 6);
  j["unit"] = settings.unit;
  j["inputs"] = {{"limit_min", s.inputs.limit_min},
                 {"limit_max", s.inputs.limit_max},
                 {"home", s.inputs.home},
                 {"estop", s.inputs.estop}};
  j["fault"] = s.state == AxisState::fault ? nlohmann::ordered_json(s.fault) : nlohmann::ordered_json(nullptr);
  return j;
}

namespace {

// markerd's config where a rig config belongs (the one markerd runs with is
// the first file at hand): what it is, the rig file it names or that it
// names none, and what to pass instead. Nothing when it is no markerd config
// or has its rig inline ([rig] tables, which load as a rig config does).
std::optional<std::string> markerd_config_given(const std::string& path) {
  std::optional<markerd::ConfigTable> root;
  try {
    root = markerd::ConfigTable::load_file(path);
  } catch (const markerd::ConfigError&) {
    return std::nullopt;  // the rig config's loader says what is wrong with it
  }
  const toml::node* rig = root->raw().get("rig");
  const std::string elsewhere = "or leave out --config to move the rig of the markerd that runs";
  if (rig != nullptr && rig->is_string()) {
    const std::string named = rig->value<std::string>().value_or("");
    const std::filesystem::path file = std::filesystem::path(named).is_absolute()
                                           ? std::filesystem::path(named)
                                           : std::filesystem::path(path).parent_path() / named;
    return fmt::format(
        "{} is markerd's config, not a rig config: its rig is in {} (line {}: rig = \"{}\"); pass "
        "--config {}, {}",
        path, file.string(), rig->source().begin.line, named, file.string(), elsewhere);
  }
  if (rig == nullptr && (root->contains("camera") || root->contains("marker"))) {
    return fmt::format(
        "{} is markerd's config, not a rig config, and it names no rig (no [rig] tables, no rig = "
        "FILE): pass a rig config (config/rig-sim.toml and the other config/rig-*.toml are examples), "
        "{}",
        path, elsewhere);
  }
  return std::nullopt;
}

}  // namespace

Session::Session(const std::string& config_path, std::string context) : context_(std::move(context)) {
  if (auto problem = markerd_config_given(config_path)) throw usage_error(context_, *problem);
  try {
    config_ = markerd::rig::load_rig_config(config_path);
  } catch (const markerd::ConfigError& e) {
    throw runtime_error(context_, e.what());
  }
  try {
    lock_.emplace(markerd::rig::lock_rig_devices(config_));
  } catch (const markerd::rig::DeviceLockError& e) {
    throw runtime_error(context_, e.what());
  }
  try {
    rig_ = markerd::rig::make_rig(config_);
  } catch (const std::exception& e) {
    throw runtime_error(context_, fmt::format("cannot start the rig: {}", e.what()));
  }
  // The axes' first statuses come from the drives as constructed; wait for
  // their supervisors to have looked once (a drive alarm becomes a fault).
  const auto started = std::chrono::steady_clock::now();
  const auto looked = [&](const markerd::rig::Axis& a) { return a.status().updated > started; };
  while (!(looked(rig_->rail()) && looked(rig_->turntable())) && std::chrono::steady_clock::now() - started < 2s) {
    if (const int s = signals_.wait(5ms).signal) interrupted(s);
  }
}

Session::~Session() {
  if (!rig_) return;
  for (markerd::rig::Axis* axis : axes()) {
    const markerd::rig::AxisStatus s = axis->status();
    if (in_motion(s.state)) {
      axis->emergency_stop();
    } else if (s.state == markerd::rig::AxisState::idle) {
      try {
        axis->disable();
      } catch (const std::exception&) {
        axis->emergency_stop();
      }
    }
  }
  rig_.reset();
}

void Session::prepare(markerd::rig::Axis& axis, bool for_homing) {
  const markerd::rig::AxisStatus s = axis.status();
  if (s.state == markerd::rig::AxisState::fault) {
    if (!for_homing) {
      throw runtime_error(context_, fmt::format("{} is in fault ({}); home it (--home) to clear the fault",
                                                axis.settings().name, s.fault));
    }
    text() << fmt::format("{}: clearing the fault ({})\n", axis.settings().name, s.fault) << std::flush;
    axis.clear_fault();
  }
  if (axis.status().state == markerd::rig::AxisState::disabled) axis.enable();
}

void Session::home(markerd::rig::Axis& axis) {
  prepare(axis, true);
  text() << fmt::format("{}: homing\n", axis.settings().name) << std::flush;
  axis.home();
  follow({&axis}, "homing");
  const markerd::rig::AxisStatus s = axis.status();
  text() << fmt::format("{}: homed at {}\n", axis.settings().name, position_text(axis.settings(), s.position))
         << std::flush;
}

void Session::follow(const std::vector<markerd::rig::Axis*>& moving, std::string_view doing) {
  // On a terminal the progress is one line redrawn in place (a homing of 50 s
  // printed 50 lines); a pipe or a file gets only the lines before and after.
  LiveLine live(*text_, text_fd_);
  auto next_progress = std::chrono::steady_clock::now();
  std::vector<std::optional<std::chrono::steady_clock::time_point>> idle_since(moving.size());
  for (;;) {
    bool all_settled = true;
    for (std::size_t i = 0; i < moving.size(); ++i) {
      const markerd::rig::Axis& axis = *moving[i];
      const markerd::rig::AxisSettings& settings = axis.settings();
      const markerd::rig::AxisStatus s = axis.status();
      if (s.state == markerd::rig::AxisState::fault) {
        throw runtime_error(context_, fmt::format("{}: {} failed: {}", settings.name, doing, s.fault));
      }
      if (s.state == markerd::rig::AxisState::disabled) {
        throw runtime_error(context_, fmt::format("{}: disabled while {}", settings.name, doing));
      }
      if (s.settled) continue;
      all_settled = false;
      // Idle but not settled: in position and settling, or (a closed-loop
      // drive) drifting outside its deadband; the second must not hang.
      if (s.state != markerd::rig::AxisState::idle) {
        idle_since[i].reset();
      } else if (!idle_since[i]) {
        idle_since[i] = std::chrono::steady_clock::now();
      } else if (std::chrono::steady_clock::now() - *idle_since[i] > settings.settle_time + 10s) {
        throw runtime_error(
            context_, fmt::format("{}: did not settle at {} (at {})", settings.name, position_text(settings, s.target),
                                  position_text(settings, s.position)));
      }
    }
    if (all_settled) return;
    if (live.on_terminal() && std::chrono::steady_clock::now() >= next_progress) {
      next_progress = std::chrono::steady_clock::now() + 200ms;
      std::vector<std::string> parts;
      for (const markerd::rig::Axis* axis : moving) {
        const markerd::rig::AxisStatus s = axis->status();
        const char* state = s.settled                                  ? "settled"
                            : s.state == markerd::rig::AxisState::idle ? "settling"
                                                                       : markerd::rig::to_string(s.state);
        parts.push_back(
            fmt::format("{}: {}, at {}", axis->settings().name, state, position_text(axis->settings(), s.position)));
      }
      live.show(parts, " | ");
    }
    if (const int signal = signals_.wait(20ms).signal) {
      live.clear();
      interrupted(signal);
    }
  }
}

void Session::interrupted(int signal) {
  std::cout << std::flush;
  std::cerr << fmt::format("markerctl: {}: {}: stopping the axes\n", context_, signal_name(signal)) << std::flush;
  bool emergency = false;
  for (markerd::rig::Axis* axis : axes()) {
    if (!in_motion(axis->status().state)) continue;
    try {
      axis->stop();
    } catch (const std::exception&) {
      axis->emergency_stop();
    }
  }
  // Braking takes max_velocity / acceleration; a drive that does not come
  // to rest in far more than that is not to be waited for.
  auto longest_brake = 0s;
  for (markerd::rig::Axis* axis : axes()) {
    const auto& s = axis->settings();
    longest_brake =
        std::max(longest_brake, std::chrono::seconds(static_cast<int>(s.max_velocity / s.acceleration) + 1));
  }
  const auto deadline = std::chrono::steady_clock::now() + 2 * longest_brake + 3s;
  const auto all = axes();
  while (std::any_of(all.begin(), all.end(), [](markerd::rig::Axis* a) { return in_motion(a->status().state); })) {
    const int again = signals_.wait(20ms).signal;
    if (again != 0 || std::chrono::steady_clock::now() > deadline) {
      emergency = true;
      for (markerd::rig::Axis* axis : axes()) axis->emergency_stop();
      break;
    }
  }
  for (markerd::rig::Axis* axis : axes()) {
    if (axis->status().state != markerd::rig::AxisState::idle) continue;
    try {
      axis->disable();
    } catch (const std::exception&) {
      axis->emergency_stop();
    }
  }
  throw runtime_error(context_, fmt::format("interrupted by {}: {}, axes disabled ({})", signal_name(signal),
                                            emergency ? "emergency stop" : "stopped", positions()));
}

std::string Session::positions() {
  std::string text;
  for (markerd::rig::Axis* axis : axes()) {
    if (!text.empty()) text += ", ";
    text += fmt::format("{} at {}", axis->settings().name, position_text(axis->settings(), axis->status().position));
  }
  return text;
}

void Session::print_ground_truth() {
  const auto truth =
      markerd::rig::ground_truth(rig_->geometry(), rig_->rail().status().position, rig_->turntable().status().position);
  text() << fmt::format("ground truth: distance {:.4f} m, yaw {:.3f} deg\n", truth.distance_m, truth.yaw_deg);
}

}  // namespace markerctl
