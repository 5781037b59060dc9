#pragma once
// The register map of a Modbus drive, read from a TOML file, so that any
// integrated stepper or servo drive is described without code: where the
// target position, velocity and acceleration go and in which units, which
// writes start, stop and home a move, reset an alarm and enable the output
// stage, and where the status bits, the actual position and the alarm code
// are read. ModbusDrive speaks to a drive through it and ModbusDriveSim serves
// the same file, so the simulator and the client can never disagree on a
// register. docs/rig-modbus.md describes the file format; config/drives/ holds
// the shipped maps.
//
// Units: every value in the map converts between the drive's raw register
// value and the Drive interface's units (motor steps, steps/s, steps/s^2)
// with a scale: raw = steps * scale, or raw = scale / steps for drives that
// take a ramp as a time (reciprocal = true).

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "markerd/base/config_table.hpp"

namespace markerd::rig {

// The four Modbus data tables, and the function codes that reach them:
// coils 01/05/15, discrete inputs 02, holding registers 03/06/16, input
// registers 04.
enum class RegisterTable : std::uint8_t { coil, discrete_input, holding, input };
const char* to_string(RegisterTable table);  // "coil", "discrete input", ...
[[nodiscard]] constexpr bool is_bit_table(RegisterTable t) {
  return t == RegisterTable::coil || t == RegisterTable::discrete_input;
}

// How a 32-bit value lies in two consecutive 16-bit registers.
enum class WordOrder : std::uint8_t { high_first, low_first };

// A number in one or two registers.
struct RegisterValue {
  RegisterTable table = RegisterTable::holding;
  std::uint16_t address = 0;
  int words = 1;  // 1 or 2
  WordOrder word_order = WordOrder::high_first;
  bool is_signed = false;
  double scale = 1;         // raw = steps * scale
  bool reciprocal = false;  // raw = scale / steps

  [[nodiscard]] std::int64_t min_raw() const;
  [[nodiscard]] std::int64_t max_raw() const;
  // The raw value for a value in steps (rounded), or nothing when it does not
  // fit the register(s).
  [[nodiscard]] std::optional<std::int64_t> to_raw(double steps) const;
  // The value in steps for a raw value (0 for a reciprocal value of raw 0).
  [[nodiscard]] double to_steps(std::int64_t raw) const;
  // Registers <-> raw value, honouring words, word order and sign.
  void pack(std::int64_t raw, std::span<std::uint16_t> registers) const;
  [[nodiscard]] std::int64_t unpack(std::span<const std::uint16_t> registers) const;
};

// A write of a fixed value: setup writes, per-move constants, commands.
struct RegisterWrite {
  RegisterTable table = RegisterTable::holding;  // holding or coil
  std::uint16_t address = 0;
  int words = 1;
  WordOrder word_order = WordOrder::high_first;
  std::int64_t value = 0;

  // The registers of `value` (holding only).
  void pack(std::int64_t raw, std::span<std::uint16_t> registers) const;
  [[nodiscard]] std::int64_t unpack(std::span<const std::uint16_t> registers) const;
};

// A command (start, stop, home, ...): `value` written to a register or coil.
// Drives differ in how a command is taken: some act on the write and expect
// the register to be released again (release: the client writes it right
// after, a pulse), some clear it themselves once they took it (self_clearing:
// the simulator models that; the client does nothing more), some act on the
// level (neither).
struct RegisterCommand {
  RegisterWrite write;
  std::optional<std::int64_t> release;
  bool self_clearing = false;
  // For enable only: the value that disables the output stage.
  std::optional<std::int64_t> off_value;
};

// Where the status bits are: bit numbers within a status register (one or two
// words), or offsets from `address` for discrete inputs and coils.
struct StatusBits {
  RegisterTable table = RegisterTable::input;
  std::uint16_t address = 0;
  int words = 1;
  WordOrder word_order = WordOrder::high_first;
  std::optional<int> ready, busy, in_position, alarm, homed, enabled;
  std::optional<int> limit_min, limit_max, home_switch;

  // Registers (or bits) to read to see every mapped bit.
  [[nodiscard]] int read_count() const;
  // The status as one bit field, from what read_count() read.
  [[nodiscard]] std::uint32_t bits_from_registers(std::span<const std::uint16_t> registers) const;
  [[nodiscard]] std::uint32_t bits_from_bits(std::span<const std::uint8_t> bits) const;
  [[nodiscard]] static bool test(std::uint32_t field, std::optional<int> bit) {
    return bit && ((field >> *bit) & 1u) != 0;
  }
};

struct RegisterMap {
  std::string source;       // the file, for messages
  std::string description;  // [drive] description
  // FC16 for single-register writes too, for drives without FC06.
  bool single_writes_fc16 = false;

  // Written once when a drive is attached, in address order (e.g. the
  // operation type of a direct-data block, "forced enable by software").
  std::vector<RegisterWrite> setup;
  // Written with every move, before the start command (e.g. a path's mode).
  std::vector<RegisterWrite> move_constants;

  RegisterValue target_position;
  RegisterValue velocity;
  RegisterValue acceleration;
  std::optional<RegisterValue> deceleration;  // absent: the drive uses acceleration for both

  RegisterCommand start;
  RegisterCommand stop;
  std::optional<RegisterCommand> home;
  std::optional<RegisterCommand> alarm_reset;
  std::optional<RegisterCommand> enable;          // with off_value
  std::optional<RegisterCommand> emergency_stop;  // absent: enable's off_value, else stop

  StatusBits status;
  RegisterValue actual_position;
  std::optional<RegisterValue> alarm_code;
  std::map<std::int64_t, std::string> alarm_texts;  // [alarm_codes]

  // "0x30 (overcurrent)" or "0x30".
  [[nodiscard]] std::string describe_alarm(std::int64_t code) const;
};

// Reads a map file; ConfigError naming file:line:key for anything wrong.
RegisterMap load_register_map(const std::filesystem::path& path);
// The same from a parsed document (its root table).
RegisterMap parse_register_map(const ConfigTable& root);

}  // namespace markerd::rig
