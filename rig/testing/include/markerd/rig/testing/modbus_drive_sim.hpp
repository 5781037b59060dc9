#pragma once
// A simulated Modbus drive: a real Modbus server (libmodbus's server side)
// that runs a drive's motion model behind a register map file, the same file
// its client ModbusDrive reads. Over TCP it listens on a host and port (port
// 0: an ephemeral one, see port()); over RTU it serves a serial device, e.g.
// one end of a pseudo-terminal pair, answering several unit ids on one line
// as the drives of a shared RS-485 bus do.
//
// The model: a move commanded through the map's start command runs along a
// TrapezoidProfile (the map's velocity and acceleration registers, decoded
// with the map's scales) in the time of a SimClock; stop brakes at the
// deceleration (or acceleration); the home command drives to the home switch
// at physical position 0 and makes it the reference (position 0, homed);
// disable and emergency stop freeze the motor where it is. The status bits,
// the actual position and the alarm code are served as the map places them;
// registers the map reads from (status, position, alarm code) refuse writes
// with exception 02, as a drive's read-only registers do.
//
// Faults for tests and demos: replies later than the client waits, requests
// lost on the line (no reply), corrupted CRCs (RTU), exception replies,
// replies from the wrong unit, an alarm with a code, a move that never
// reaches its position, and (TCP) dropped connections. Everything the clients
// wrote is recorded for inspection.

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "markerd/rig/register_map.hpp"
#include "markerd/rig/sim_clock.hpp"

namespace markerd::rig {

struct ModbusSimUnit {
  int unit_id = 1;
  RegisterMap map;
  double start_position_steps = 0;  // physical position at power-on; the home switch is at 0
  bool homed = false;               // referenced at power-on (position = physical position)
  bool enabled = false;             // output stage on at power-on (always on for maps without enable)
  double homing_velocity = 4000;    // steps/s
  double homing_acceleration = 40000;
};

struct ModbusSimTcp {
  std::string host = "127.0.0.1";  // numeric IPv4
  int port = 0;                    // 0: an ephemeral port
};

struct ModbusSimRtu {
  std::string device;
  int baud = 19200;
  char parity = 'E';
  int data_bits = 8;
  int stop_bits = 1;
};

// What a unit's model looks like now.
struct ModbusSimState {
  double position_steps = 0;  // reported (relative to the reference)
  double velocity_steps_per_s = 0;
  std::int64_t target_steps = 0;  // of the last move
  bool enabled = false, moving = false, homing = false, homed = false, in_position = false, alarm = false;
  std::int64_t alarm_code = 0;
  int moves = 0, homings = 0, stops = 0, emergency_stops = 0, alarm_resets = 0;
  double last_velocity = 0, last_acceleration = 0;  // of the last move, steps/s and steps/s^2
  std::uint64_t requests = 0;                       // requests addressed to this unit
};

// One write a client made, as the server took it.
struct ModbusSimWrite {
  RegisterTable table = RegisterTable::holding;
  std::uint16_t address = 0;
  std::vector<std::uint16_t> values;  // registers, or 0/1 per coil
};

// Alarm codes the simulator raises on its own.
inline constexpr std::int64_t kSimAlarmInvalidMove = 0x70;  // a start with zero velocity or acceleration

class ModbusDriveSim {
 public:
  // A null clock runs in real time. Validates the units (std::invalid_argument
  // for duplicate or out-of-range unit ids). Call start() to serve.
  ModbusDriveSim(std::vector<ModbusSimUnit> units, ModbusSimTcp tcp, std::shared_ptr<const SimClock> clock = nullptr);
  ModbusDriveSim(std::vector<ModbusSimUnit> units, ModbusSimRtu rtu, std::shared_ptr<const SimClock> clock = nullptr);
  ~ModbusDriveSim();  // stop()
  ModbusDriveSim(const ModbusDriveSim&) = delete;
  ModbusDriveSim& operator=(const ModbusDriveSim&) = delete;

  // Binds the port or opens the device and starts the server thread;
  // std::runtime_error naming the cause when it cannot.
  void start();
  // Closes every connection and joins the thread; the model keeps its state.
  void stop();
  [[nodiscard]] int port() const;  // TCP, after start()

  // Faults on the next `count` requests to `unit` (count < 0: until cleared).
  // One kind at a time per unit: a new one replaces the old.
  void delay_replies(int unit, std::chrono::milliseconds delay, int count = -1);
  void drop_requests(int unit, int count = -1);                          // lost on the line: not executed, no reply
  void corrupt_crc(int unit, int count = -1);                            // executed, reply with a broken CRC (RTU only)
  void exception_replies(int unit, int exception_code, int count = -1);  // not executed
  void reply_as_unit(int unit, int other_unit, int count = -1);          // executed, reply names another unit
  void clear_reply_faults(int unit);

  // The drive's own faults.
  void raise_alarm(int unit, std::int64_t code);  // stops the motor; cleared by the alarm reset command
  void stall_at(int unit, double fraction);       // moves stop at this fraction of their distance and stay busy
  void clear_stall(int unit);
  void disconnect_clients();  // TCP: closes every open connection

  [[nodiscard]] ModbusSimState state(int unit) const;
  [[nodiscard]] std::vector<ModbusSimWrite> writes(int unit) const;
  void clear_writes(int unit);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace markerd::rig
