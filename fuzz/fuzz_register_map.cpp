// Modbus register maps (register_map.cpp), as a rig config's `map = ...`
// loads them. ConfigError is the one error the parser may raise. A map it
// accepts must also work: every register it names lies in Modbus's 16-bit
// address space, every fixed value written reads back as itself, and every
// value in steps that converts to a raw value packs and unpacks to it.

#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>

#include <fmt/format.h>

#include "fuzz_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/rig/register_map.hpp"

namespace {

using markerd::rig::RegisterCommand;
using markerd::rig::RegisterMap;
using markerd::rig::RegisterTable;
using markerd::rig::RegisterValue;
using markerd::rig::RegisterWrite;

void check_span(std::string_view what, int address, int count) {
  if (count < 1 || address < 0 || address + count - 1 > 0xFFFF) {
    markerd::fuzz::finding(
        fmt::format("{}: {} register(s) from {} leave the 16-bit address space", what, count, address));
  }
}

void check_value(std::string_view what, const RegisterValue& v) {
  check_span(what, v.address, v.words);
  for (const double steps : {0.0, 1.0, -1.0, 0.5, 1234.5, -98765.25, 1e6, -1e6, 1e9, 1e15, -1e300, 1e-300}) {
    const std::optional<std::int64_t> raw = v.to_raw(steps);
    if (!raw) continue;
    if (*raw < v.min_raw() || *raw > v.max_raw()) {
      markerd::fuzz::finding(
          fmt::format("{}: to_raw({}) = {} is outside [{}, {}]", what, steps, *raw, v.min_raw(), v.max_raw()));
    }
    std::array<std::uint16_t, 2> registers{};
    v.pack(*raw, registers);
    if (v.unpack(registers) != *raw) {
      markerd::fuzz::finding(fmt::format("{}: raw {} does not survive pack and unpack", what, *raw));
    }
    (void)v.to_steps(*raw);
  }
}

void check_write(std::string_view what, const RegisterWrite& w, std::int64_t value) {
  check_span(what, w.address, w.words);
  if (w.table != RegisterTable::holding) return;
  std::array<std::uint16_t, 2> registers{};
  w.pack(value, registers);
  RegisterWrite as_configured = w;
  as_configured.value = value;
  if (as_configured.unpack(registers) != value) {
    markerd::fuzz::finding(fmt::format("{}: value {} does not survive pack and unpack", what, value));
  }
}

void check_command(std::string_view what, const std::optional<RegisterCommand>& c) {
  if (!c) return;
  check_write(what, c->write, c->write.value);
  if (c->release) check_write(what, c->write, *c->release);
  if (c->off_value) check_write(what, c->write, *c->off_value);
}

void check_map(const RegisterMap& map) {
  for (const RegisterWrite& w : map.setup) check_write("setup", w, w.value);
  for (const RegisterWrite& w : map.move_constants) check_write("move_constants", w, w.value);
  check_value("target_position", map.target_position);
  check_value("velocity", map.velocity);
  check_value("acceleration", map.acceleration);
  if (map.deceleration) check_value("deceleration", *map.deceleration);
  check_value("actual_position", map.actual_position);
  if (map.alarm_code) check_value("alarm_code", *map.alarm_code);
  check_command("start", map.start);
  check_command("stop", map.stop);
  check_command("home", map.home);
  check_command("alarm_reset", map.alarm_reset);
  check_command("enable", map.enable);
  check_command("emergency_stop", map.emergency_stop);

  const auto& status = map.status;
  check_span("status", status.address, status.read_count());
  if (status.read_count() > 32) markerd::fuzz::finding("status: more than 32 bits to read");
  std::array<std::uint16_t, 2> registers{0xA5A5, 0x5A5A};
  std::array<std::uint8_t, 32> bits{};
  for (std::size_t i = 0; i < bits.size(); i += 3) bits[i] = 1;
  const std::uint32_t field =
      markerd::rig::is_bit_table(status.table)
          ? status.bits_from_bits(std::span(bits).first(static_cast<std::size_t>(status.read_count())))
          : status.bits_from_registers(registers);
  for (const auto& bit : {status.ready, status.busy, status.in_position, status.alarm, status.homed, status.enabled,
                          status.limit_min, status.limit_max, status.home_switch}) {
    (void)markerd::rig::StatusBits::test(field, bit);
  }
  for (const auto& [code, text] : map.alarm_texts) (void)map.describe_alarm(code);
  (void)map.describe_alarm(-1);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  RegisterMap map;
  try {
    map = markerd::rig::parse_register_map(
        markerd::ConfigTable::parse(markerd::fuzz::as_text(data, size), "fuzz-map.toml"));
  } catch (const markerd::ConfigError& e) {
    markerd::fuzz::expected_error(e);
    return 0;
  }
  check_map(map);
  return 0;
}
