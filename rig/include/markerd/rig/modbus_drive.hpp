#pragma once
// A Drive over Modbus: an integrated stepper or servo drive that plans its own
// motion, reached through a ModbusBus at one unit id and described by a
// RegisterMap. A move writes the target, velocity and ramps and then the
// start command; the bus thread polls the status bits and the actual position
// every poll period, so status() never blocks, and decides from them when a
// move or a homing has finished.
//
// Faults, all latched until reset_alarm(): the drive's alarm bit (with its
// alarm code when the map has one); a request that failed after the bus's
// retries (lost communication, after which the drive is sent a best-effort
// emergency stop); a move or homing that does not finish in time (the drive
// is stopped). The messages name the axis, the bus, the unit, the register
// and the cause.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/drive.hpp"
#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/register_map.hpp"

namespace markerd::rig {

struct ModbusDriveSettings {
  std::string bus;            // the name of a [rig.buses.<name>] table
  int unit_id = 1;            // 1..247
  std::filesystem::path map;  // absolute, resolved against the config's directory
  // A move still unfinished this long after its planned duration (x 1.5)
  // faults the drive.
  std::chrono::milliseconds completion_margin{2000};
};

// Parses [rig.<axis>.modbus]: bus, unit_id, map (relative to config_dir),
// completion_margin_ms. ConfigError naming file:line:key.
ModbusDriveSettings parse_modbus_drive(const ConfigTable& modbus_table, const std::filesystem::path& config_dir);

class ModbusDrive final : public Drive {
 public:
  // Attaches to the bus, runs the map's setup writes and reads the drive's
  // status once: DriveError when the drive does not answer.
  ModbusDrive(std::string axis_name, std::shared_ptr<ModbusBus> bus, int unit_id, RegisterMap map,
              std::chrono::milliseconds completion_margin = std::chrono::milliseconds(2000));
  ~ModbusDrive() override;

  [[nodiscard]] std::string_view name() const override { return name_; }
  void enable(bool on) override;
  void start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) override;
  // The drive homes with its own homing parameters; only the timeout is used.
  void start_homing(const HomingSteps& homing) override;
  void stop() override;
  void reset_alarm() override;
  void emergency_stop() noexcept override;
  [[nodiscard]] DriveStatus status() const override;

  [[nodiscard]] const RegisterMap& map() const { return map_; }
  [[nodiscard]] int unit_id() const { return unit_; }

 private:
  struct ReadPlan;
  enum class Motion : std::uint8_t { none, move, homing, stopping };

  void write_command(ModbusLink& link, const RegisterCommand& command, bool on = true, int attempts = 0);
  void write_fixed(ModbusLink& link, const RegisterWrite& write, std::int64_t value, int attempts = 0);
  void write_move(ModbusLink& link, const std::int64_t raw[4]);
  void poll(ModbusLink& link);
  void read_and_apply(ModbusLink& link, int attempts);
  void emergency_writes(ModbusLink& link) noexcept;
  void latch_comm_fault(ModbusLink& link, const std::string& cause);
  // A value in drive units; DriveError when it does not fit (or, for speeds
  // and ramps, rounds to 0).
  [[nodiscard]] std::int64_t encode(const RegisterValue& value, double steps, std::string_view what,
                                    bool must_be_positive) const;
  [[noreturn]] void fail_command(std::string_view what, const DriveError& error);
  void refresh_alarm_locked();

  const std::string name_;
  const std::shared_ptr<ModbusBus> bus_;
  const int unit_;
  const RegisterMap map_;
  const std::chrono::milliseconds completion_margin_;
  std::unique_ptr<ReadPlan> plan_;
  ModbusBus::ClientId client_ = 0;

  // Guards everything below: written by the bus thread (polls, command jobs)
  // and by the axis thread, read by status() from any thread.
  mutable std::mutex mutex_;
  DriveStatus status_;
  bool commanded_enabled_ = false;
  bool homed_latched_ = false;  // maps without a homed bit: a homing finished
  std::string drive_alarm_;     // the drive's own alarm, while its bit is set
  std::string local_fault_;     // communication, timeout: latched until reset_alarm()
  Motion motion_ = Motion::none;
  std::int64_t motion_target_ = 0;
  bool motion_seen_busy_ = false;
  bool homed_before_homing_ = false;
  std::chrono::steady_clock::time_point motion_started_{}, motion_deadline_{};
  double motion_planned_s_ = 0;
};

}  // namespace markerd::rig
