#include "markerd/rig/modbus_drive.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include "markerd/base/read_file.hpp"
#include "markerd/rig/motion_profile.hpp"

namespace markerd::rig {

namespace {

// A planned duration or timeout as a clock duration, saturated at a day: a
// crawl over the whole travel must not overflow the nanosecond count into a
// deadline in the past.
std::chrono::steady_clock::duration bounded_seconds(double seconds) {
  constexpr double kMaxSeconds = 86400;
  const double s = std::isnan(seconds) ? kMaxSeconds : std::clamp(seconds, 0.0, kMaxSeconds);
  return std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(s));
}

}  // namespace

ModbusDriveSettings parse_modbus_drive(const ConfigTable& t, const std::filesystem::path& config_dir) {
  t.allow_only({"bus", "unit_id", "map", "completion_margin_ms"});
  ModbusDriveSettings s;
  s.bus = t.required<std::string>("bus");
  // 0 is the RTU broadcast address (no replies) and 248..255 are reserved.
  s.unit_id = static_cast<int>(t.required<std::int64_t>("unit_id", {1, 247}));
  const std::filesystem::path map = t.required<std::string>("map");
  s.map = map.is_absolute() ? map : config_dir / map;
  try {
    (void)check_regular_file(s.map, ConfigTable::kMaxFileBytes, "the register map");
  } catch (const FileError& e) {
    if (e.missing()) t.fail("map", fmt::format("no such file: {}", s.map.string()));
    t.fail("map", e.what());
  }
  s.completion_margin = std::chrono::milliseconds(
      t.optional<std::int64_t>("completion_margin_ms", s.completion_margin.count(), {0, 600000, "ms"}));
  return s;
}

// The reads of one poll: the status, the actual position and (when it lies
// near them) the alarm code, merged into as few requests as the map allows,
// since on a 19200-baud line every request costs milliseconds.
struct ModbusDrive::ReadPlan {
  struct Block {
    RegisterTable table;
    int first;
    int last;
    std::vector<std::uint16_t> data;
  };
  struct Location {
    int block = -1;
    int address = 0;
  };
  static constexpr int kMaxGap = 8;     // registers read in vain to save a request
  static constexpr int kMaxBlock = 64;  // well below the 125 of one request

  std::vector<Block> blocks;
  Location status, position, alarm;
  std::vector<std::uint8_t> status_bits;  // status in discrete inputs or coils
  std::vector<std::uint16_t> alarm_only;  // the alarm code when it has a request of its own

  // Places `count` registers at `address` into a block, extending one when
  // that stays compact; with `may_add` false, fails rather than add a block.
  Location place(RegisterTable table, int address, int count, bool may_add) {
    const int last = address + count - 1;
    for (std::size_t i = 0; i < blocks.size(); ++i) {
      auto& b = blocks[i];
      if (b.table != table) continue;
      const int first = std::min(b.first, address);
      const int end = std::max(b.last, last);
      const bool near = address <= b.last + kMaxGap + 1 && last >= b.first - kMaxGap - 1;
      if (near && end - first + 1 <= kMaxBlock) {
        b.first = first;
        b.last = end;
        return Location{static_cast<int>(i), address};
      }
    }
    if (!may_add) return {};
    blocks.push_back(Block{table, address, last, {}});
    return Location{static_cast<int>(blocks.size()) - 1, address};
  }

  explicit ReadPlan(const RegisterMap& map) {
    if (is_bit_table(map.status.table)) {
      status_bits.resize(static_cast<std::size_t>(map.status.read_count()));
    } else {
      status = place(map.status.table, map.status.address, map.status.words, true);
    }
    position = place(map.actual_position.table, map.actual_position.address, map.actual_position.words, true);
    if (map.alarm_code) {
      alarm = place(map.alarm_code->table, map.alarm_code->address, map.alarm_code->words, false);
      if (alarm.block < 0) alarm_only.resize(static_cast<std::size_t>(map.alarm_code->words));
    }
    for (auto& b : blocks) b.data.resize(static_cast<std::size_t>(b.last - b.first + 1));
  }

  [[nodiscard]] std::span<const std::uint16_t> at(const Location& l, int words) const {
    const auto& b = blocks[static_cast<std::size_t>(l.block)];
    return std::span<const std::uint16_t>(b.data).subspan(static_cast<std::size_t>(l.address - b.first),
                                                          static_cast<std::size_t>(words));
  }
};

ModbusDrive::ModbusDrive(std::string axis_name, std::shared_ptr<ModbusBus> bus, int unit_id, RegisterMap map,
                         std::chrono::milliseconds completion_margin)
    : name_(fmt::format("{} (modbus unit {} on {})", axis_name, unit_id, bus->settings().name)),
      bus_(std::move(bus)),
      unit_(unit_id),
      map_(std::move(map)),
      completion_margin_(completion_margin),
      plan_(std::make_unique<ReadPlan>(map_)) {
  client_ = bus_->attach(ModbusBus::Client{[this](ModbusLink& link) { poll(link); },
                                           [this](ModbusLink& link) { emergency_writes(link); }});
  try {
    bus_->execute([this](ModbusLink& link) {
      for (const auto& w : map_.setup) write_fixed(link, w, w.value);
      read_and_apply(link, 0);
    });
  } catch (const DriveError& e) {
    bus_->detach(client_);
    throw DriveError(fmt::format("{}: no working connection to the drive: {}", name_, e.what()));
  }
}

ModbusDrive::~ModbusDrive() { bus_->detach(client_); }

DriveStatus ModbusDrive::status() const {
  std::lock_guard lock(mutex_);
  return status_;
}

void ModbusDrive::write_fixed(ModbusLink& link, const RegisterWrite& write, std::int64_t value, int attempts) {
  if (write.table == RegisterTable::coil) {
    link.write_coil(unit_, write.address, value != 0, attempts);
    return;
  }
  std::uint16_t registers[2] = {0, 0};
  write.pack(value, std::span(registers, static_cast<std::size_t>(write.words)));
  link.write_registers(unit_, write.address, std::span<const std::uint16_t>(registers, write.words),
                       map_.single_writes_fc16, attempts);
}

void ModbusDrive::write_command(ModbusLink& link, const RegisterCommand& command, bool on, int attempts) {
  write_fixed(link, command.write, on ? command.write.value : *command.off_value, attempts);
  if (command.release) write_fixed(link, command.write, *command.release, attempts);
}

std::int64_t ModbusDrive::encode(const RegisterValue& value, double steps, std::string_view what,
                                 bool must_be_positive) const {
  const auto raw = value.to_raw(steps);
  if (raw && (!must_be_positive || *raw > 0)) return *raw;
  throw DriveError(
      fmt::format("{}: {} {} is {} in the drive's units ({} 0x{:04X}, scale {}{}), outside its range {}..{}{}", name_,
                  what, steps, value.reciprocal ? value.scale / steps : steps * value.scale, to_string(value.table),
                  value.address, value.scale, value.reciprocal ? ", reciprocal" : "", value.min_raw(), value.max_raw(),
                  raw && *raw == 0 ? " (rounds to 0: below the drive's resolution)" : ""));
}

void ModbusDrive::write_move(ModbusLink& link, const std::int64_t raw[4]) {
  // The move's holding registers as one image, so that adjacent fields go out
  // in one FC16 request; a start command right after them joins the same
  // request, as drives with a motion block expect (Leadshine's PR0 block, the
  // AZ series' direct data operation): the drive sees the data and the
  // trigger at once.
  std::map<int, std::uint16_t> image;
  std::vector<const RegisterWrite*> coils;
  const auto put = [&image](const auto& field, std::int64_t value) {
    std::uint16_t registers[2] = {0, 0};
    field.pack(value, std::span(registers, static_cast<std::size_t>(field.words)));
    for (int i = 0; i < field.words; ++i) image[field.address + i] = registers[i];
  };
  for (const auto& w : map_.move_constants) {
    if (w.table == RegisterTable::coil) {
      coils.push_back(&w);
    } else {
      put(w, w.value);
    }
  }
  put(map_.target_position, raw[0]);
  put(map_.velocity, raw[1]);
  put(map_.acceleration, raw[2]);
  if (map_.deceleration) put(*map_.deceleration, raw[3]);
  const auto& start = map_.start.write;
  const bool start_joins = start.table == RegisterTable::holding && image.rbegin()->first + 1 == start.address;
  if (start_joins) put(start, start.value);

  for (const auto* c : coils) link.write_coil(unit_, c->address, c->value != 0);
  std::vector<std::uint16_t> run;
  for (auto it = image.begin(); it != image.end();) {
    const int first = it->first;
    run.clear();
    int next = first;
    // 123 registers is FC16's limit.
    while (it != image.end() && it->first == next && run.size() < 123) {
      run.push_back(it->second);
      ++it;
      ++next;
    }
    link.write_registers(unit_, static_cast<std::uint16_t>(first), run, map_.single_writes_fc16);
  }
  if (!start_joins) write_fixed(link, start, start.value);
  if (map_.start.release) write_fixed(link, start, *map_.start.release);
}

void ModbusDrive::refresh_alarm_locked() {
  status_.alarm = !drive_alarm_.empty() || !local_fault_.empty();
  if (!drive_alarm_.empty() && !local_fault_.empty()) {
    status_.alarm_cause = fmt::format("{}; {}", drive_alarm_, local_fault_);
  } else {
    status_.alarm_cause = drive_alarm_.empty() ? local_fault_ : drive_alarm_;
  }
}

void ModbusDrive::read_and_apply(ModbusLink& link, int attempts) {
  auto& plan = *plan_;
  for (auto& b : plan.blocks) {
    link.read_registers(unit_, b.table, static_cast<std::uint16_t>(b.first), b.data, attempts);
  }
  std::uint32_t field = 0;
  if (is_bit_table(map_.status.table)) {
    link.read_bits(unit_, map_.status.table, map_.status.address, plan.status_bits, attempts);
    field = map_.status.bits_from_bits(plan.status_bits);
  } else {
    field = map_.status.bits_from_registers(plan.at(plan.status, map_.status.words));
  }
  const auto& s = map_.status;
  const double position =
      map_.actual_position.to_steps(map_.actual_position.unpack(plan.at(plan.position, map_.actual_position.words)));
  const bool alarm_bit = StatusBits::test(field, s.alarm);
  std::optional<std::int64_t> alarm_code;
  if (alarm_bit && map_.alarm_code) {
    if (plan.alarm.block >= 0) {
      alarm_code = map_.alarm_code->unpack(plan.at(plan.alarm, map_.alarm_code->words));
    } else {
      link.read_registers(unit_, map_.alarm_code->table, map_.alarm_code->address, plan.alarm_only, attempts);
      alarm_code = map_.alarm_code->unpack(plan.alarm_only);
    }
  }

  const bool busy = StatusBits::test(field, s.busy);
  const bool in_position = !s.in_position || StatusBits::test(field, s.in_position);
  // Without a busy bit, "not in position" is the sign that a move started.
  const bool moving = busy || (s.in_position && !StatusBits::test(field, s.in_position));
  const auto now = std::chrono::steady_clock::now();
  bool stop_needed = false;

  std::unique_lock lock(mutex_);
  status_.position_steps = std::llround(position);
  status_.enabled = s.enabled ? StatusBits::test(field, s.enabled) : commanded_enabled_;
  status_.inputs.limit_min = StatusBits::test(field, s.limit_min);
  status_.inputs.limit_max = StatusBits::test(field, s.limit_max);
  status_.inputs.home = StatusBits::test(field, s.home_switch);
  const bool homed_bit = StatusBits::test(field, s.homed);

  if (alarm_bit) {
    drive_alarm_ = alarm_code ? fmt::format("drive alarm {}", map_.describe_alarm(*alarm_code)) : "drive alarm";
    motion_ = Motion::none;  // a drive in alarm has stopped on its own
  } else {
    drive_alarm_.clear();
  }

  if (motion_ != Motion::none) {
    motion_seen_busy_ = motion_seen_busy_ || moving;
    // The status read right after a start command may still show the end of
    // the previous move: a move is over once the drive was seen moving, or
    // stands at the target, and is idle and in position again.
    bool finished = false;
    if (motion_ == Motion::move) {
      finished = !busy && in_position && (motion_seen_busy_ || status_.position_steps == motion_target_);
    } else if (motion_ == Motion::homing) {
      finished = !busy && (motion_seen_busy_ || (s.homed && homed_bit && !homed_before_homing_));
      if (finished && s.homed && !homed_bit) {
        local_fault_ =
            fmt::format("{}: homing ended without a position reference (homed bit {} clear)", name_, *s.homed);
      }
    } else {
      finished = !busy;
    }
    if (finished) {
      if (motion_ == Motion::homing && !s.homed) homed_latched_ = true;
      motion_ = Motion::none;
    } else if (now > motion_deadline_) {
      const double elapsed = std::chrono::duration<double>(now - motion_started_).count();
      if (motion_ == Motion::move) {
        local_fault_ = fmt::format(
            "{}: move to {} steps not finished {:.1f} s after its start (planned {:.1f} s): at {} steps, drive {}; "
            "stopped",
            name_, motion_target_, elapsed, motion_planned_s_, status_.position_steps,
            busy ? "still busy" : "idle but not in position");
      } else {
        local_fault_ = fmt::format("{}: {} not finished after {:.1f} s: at {} steps, drive {}; stopped", name_,
                                   motion_ == Motion::homing ? "homing" : "stop", elapsed, status_.position_steps,
                                   busy ? "still busy" : "idle");
      }
      motion_ = Motion::none;
      stop_needed = true;
    }
  }
  status_.homed = s.homed ? homed_bit : homed_latched_;
  status_.busy = busy || motion_ != Motion::none;
  refresh_alarm_locked();
  lock.unlock();
  if (stop_needed) {
    // Fail safe: whatever the drive is doing, it is not what was planned.
    try {
      write_command(link, map_.stop);
    } catch (const DriveError&) {
      // The fault is latched already; a dead line gets its own fault next poll.
    }
  }
}

void ModbusDrive::latch_comm_fault(ModbusLink& link, const std::string& cause) {
  bool first = false;
  {
    std::lock_guard lock(mutex_);
    first = local_fault_.empty();
    if (first) local_fault_ = fmt::format("{}: lost communication: {}", name_, cause);
    motion_ = Motion::none;
    refresh_alarm_locked();
  }
  // Whatever the drive is doing now, nobody watches it: try once to stop it.
  if (first) emergency_writes(link);
}

void ModbusDrive::poll(ModbusLink& link) {
  bool faulted = false;
  {
    std::lock_guard lock(mutex_);
    faulted = !local_fault_.empty();
  }
  try {
    // A drive already known to be unreachable gets a single try per poll, so
    // that it does not hold the line for its retries and starve the others.
    read_and_apply(link, faulted ? 1 : 0);
  } catch (const DriveError& e) {
    latch_comm_fault(link, e.what());
  }
}

void ModbusDrive::emergency_writes(ModbusLink& link) noexcept {
  const RegisterCommand* commands[2] = {nullptr, nullptr};
  if (map_.emergency_stop) commands[0] = &*map_.emergency_stop;
  if (map_.enable) commands[1] = &*map_.enable;
  if (!commands[0] && !commands[1]) commands[0] = &map_.stop;
  for (const RegisterCommand* c : commands) {
    if (c == nullptr) continue;
    try {
      write_command(link, *c, c->off_value.has_value() ? false : true);
    } catch (const std::exception& e) {
      try {
        std::lock_guard lock(mutex_);
        if (local_fault_.empty()) local_fault_ = fmt::format("{}: emergency stop not confirmed: {}", name_, e.what());
        refresh_alarm_locked();
      } catch (...) {
      }
    }
  }
}

void ModbusDrive::fail_command(std::string_view what, const DriveError& error) {
  // The request may have reached the drive before the failure: latch the
  // fault and try to stop, as for any doubt about what the drive does.
  {
    std::lock_guard lock(mutex_);
    if (local_fault_.empty()) local_fault_ = fmt::format("{}: {} failed: {}", name_, what, error.what());
    motion_ = Motion::none;
    refresh_alarm_locked();
  }
  try {
    bus_->execute([this](ModbusLink& link) { write_command(link, map_.stop, true, 1); });
  } catch (const DriveError&) {
    // Unreachable: the latched fault says so already.
  }
  throw DriveError(fmt::format("{}: {} failed: {}", name_, what, error.what()));
}

void ModbusDrive::enable(bool on) {
  try {
    bus_->execute([&](ModbusLink& link) {
      if (map_.enable) write_command(link, *map_.enable, on);
      std::lock_guard lock(mutex_);
      commanded_enabled_ = on;
      if (!map_.status.enabled) status_.enabled = on;
    });
  } catch (const DriveError& e) {
    fail_command(on ? "enable" : "disable", e);
  }
}

void ModbusDrive::start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) {
  std::int64_t start_position = 0;
  {
    std::lock_guard lock(mutex_);
    if (status_.alarm) throw DriveError(fmt::format("{}: in alarm ({}); reset it first", name_, status_.alarm_cause));
    if (status_.busy) throw DriveError(fmt::format("{}: busy, cannot start a move to {} steps", name_, target_steps));
    start_position = status_.position_steps;
  }
  if (!(max_steps_per_s > 0) || !(accel_steps_per_s2 > 0)) {
    throw DriveError(fmt::format("{}: a move needs a velocity and an acceleration > 0, got {} and {}", name_,
                                 max_steps_per_s, accel_steps_per_s2));
  }
  const std::int64_t raw[4] = {
      encode(map_.target_position, static_cast<double>(target_steps), "target position", false),
      encode(map_.velocity, max_steps_per_s, "velocity", true),
      encode(map_.acceleration, accel_steps_per_s2, "acceleration", true),
      map_.deceleration ? encode(*map_.deceleration, accel_steps_per_s2, "deceleration", true) : 0};
  const double planned = TrapezoidProfile(static_cast<double>(std::llabs(target_steps - start_position)),
                                          max_steps_per_s, accel_steps_per_s2)
                             .duration();
  try {
    bus_->execute([&](ModbusLink& link) {
      write_move(link, raw);
      // Set on the bus thread, after the trigger and before the next poll.
      std::lock_guard lock(mutex_);
      motion_ = Motion::move;
      motion_target_ = target_steps;
      motion_seen_busy_ = false;
      motion_planned_s_ = planned;
      motion_started_ = std::chrono::steady_clock::now();
      motion_deadline_ = motion_started_ + bounded_seconds(planned * 1.5) + completion_margin_;
      status_.busy = true;
    });
  } catch (const DriveError& e) {
    fail_command(fmt::format("move to {} steps", target_steps), e);
  }
}

void ModbusDrive::start_homing(const HomingSteps& homing) {
  if (!map_.home) throw DriveError(fmt::format("{}: the register map {} has no home command", name_, map_.source));
  {
    std::lock_guard lock(mutex_);
    if (status_.alarm) throw DriveError(fmt::format("{}: in alarm ({}); reset it first", name_, status_.alarm_cause));
    if (status_.busy) throw DriveError(fmt::format("{}: busy, cannot start homing", name_));
  }
  try {
    bus_->execute([&](ModbusLink& link) {
      write_command(link, *map_.home);
      std::lock_guard lock(mutex_);
      motion_ = Motion::homing;
      motion_seen_busy_ = false;
      homed_before_homing_ = status_.homed;
      homed_latched_ = false;
      motion_started_ = std::chrono::steady_clock::now();
      motion_deadline_ = motion_started_ + bounded_seconds(homing.timeout_s);
      status_.busy = true;
    });
  } catch (const DriveError& e) {
    fail_command("homing", e);
  }
}

void ModbusDrive::stop() {
  try {
    bus_->execute([&](ModbusLink& link) {
      write_command(link, map_.stop);
      std::lock_guard lock(mutex_);
      if (motion_ != Motion::none) {
        motion_ = Motion::stopping;
        motion_started_ = std::chrono::steady_clock::now();
        motion_deadline_ = motion_started_ + completion_margin_;
      }
    });
  } catch (const DriveError& e) {
    fail_command("stop", e);
  }
}

void ModbusDrive::reset_alarm() {
  try {
    bus_->execute([&](ModbusLink& link) {
      if (map_.alarm_reset) write_command(link, *map_.alarm_reset);
      {
        std::lock_guard lock(mutex_);
        local_fault_.clear();
        refresh_alarm_locked();
      }
      read_and_apply(link, 0);
    });
  } catch (const DriveError& e) {
    fail_command("alarm reset", e);
  }
}

void ModbusDrive::emergency_stop() noexcept {
  try {
    std::lock_guard lock(mutex_);
    motion_ = Motion::none;
    commanded_enabled_ = false;
  } catch (...) {
    // Only a broken mutex throws; the writes below matter more.
  }
  bus_->request_urgent(client_);
}

}  // namespace markerd::rig
