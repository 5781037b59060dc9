#include "markerd/rig/register_map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <string_view>
#include <utility>

namespace markerd::rig {

const char* to_string(RegisterTable table) {
  switch (table) {
    case RegisterTable::coil: return "coil";
    case RegisterTable::discrete_input: return "discrete input";
    case RegisterTable::holding: return "holding register";
    case RegisterTable::input: return "input register";
  }
  return "?";
}

namespace {

std::uint32_t combine(std::span<const std::uint16_t> registers, int words, WordOrder order) {
  if (words == 1) return registers[0];
  const std::uint32_t first = registers[0];
  const std::uint32_t second = registers[1];
  return order == WordOrder::high_first ? (first << 16) | second : (second << 16) | first;
}

void split(std::uint32_t value, int words, WordOrder order, std::span<std::uint16_t> registers) {
  if (words == 1) {
    registers[0] = static_cast<std::uint16_t>(value);
    return;
  }
  const auto high = static_cast<std::uint16_t>(value >> 16);
  const auto low = static_cast<std::uint16_t>(value & 0xFFFFu);
  registers[0] = order == WordOrder::high_first ? high : low;
  registers[1] = order == WordOrder::high_first ? low : high;
}

}  // namespace

std::int64_t RegisterValue::min_raw() const {
  if (!is_signed) return 0;
  return words == 1 ? std::numeric_limits<std::int16_t>::min() : std::numeric_limits<std::int32_t>::min();
}

std::int64_t RegisterValue::max_raw() const {
  if (is_signed) {
    return words == 1 ? std::numeric_limits<std::int16_t>::max() : std::numeric_limits<std::int32_t>::max();
  }
  return words == 1 ? std::numeric_limits<std::uint16_t>::max() : std::numeric_limits<std::uint32_t>::max();
}

std::optional<std::int64_t> RegisterValue::to_raw(double steps) const {
  double raw = 0;
  if (reciprocal) {
    if (!(steps > 0)) return std::nullopt;
    raw = scale / steps;
  } else {
    raw = steps * scale;
  }
  if (!std::isfinite(raw)) return std::nullopt;
  raw = std::round(raw);
  if (raw < static_cast<double>(min_raw()) || raw > static_cast<double>(max_raw())) return std::nullopt;
  return static_cast<std::int64_t>(raw);
}

double RegisterValue::to_steps(std::int64_t raw) const {
  if (reciprocal) return raw == 0 ? 0.0 : scale / static_cast<double>(raw);
  return static_cast<double>(raw) / scale;
}

void RegisterValue::pack(std::int64_t raw, std::span<std::uint16_t> registers) const {
  split(static_cast<std::uint32_t>(raw), words, word_order, registers);
}

std::int64_t RegisterValue::unpack(std::span<const std::uint16_t> registers) const {
  const std::uint32_t u = combine(registers, words, word_order);
  if (!is_signed) return u;
  return words == 1 ? static_cast<std::int64_t>(static_cast<std::int16_t>(u))
                    : static_cast<std::int64_t>(static_cast<std::int32_t>(u));
}

void RegisterWrite::pack(std::int64_t raw, std::span<std::uint16_t> registers) const {
  split(static_cast<std::uint32_t>(raw), words, word_order, registers);
}

std::int64_t RegisterWrite::unpack(std::span<const std::uint16_t> registers) const {
  // Command values are compared with what was configured, which may be
  // negative (e.g. a -1 trigger): sign-extend when the configured value is.
  const std::uint32_t u = combine(registers, words, word_order);
  if (value >= 0) return u;
  return words == 1 ? static_cast<std::int64_t>(static_cast<std::int16_t>(u))
                    : static_cast<std::int64_t>(static_cast<std::int32_t>(u));
}

int StatusBits::read_count() const {
  if (!is_bit_table(table)) return words;
  int highest = 0;
  for (const auto& bit : {ready, busy, in_position, alarm, homed, enabled, limit_min, limit_max, home_switch}) {
    if (bit) highest = std::max(highest, *bit);
  }
  return highest + 1;
}

std::uint32_t StatusBits::bits_from_registers(std::span<const std::uint16_t> registers) const {
  return combine(registers, words, word_order);
}

std::uint32_t StatusBits::bits_from_bits(std::span<const std::uint8_t> bits) const {
  std::uint32_t field = 0;
  for (std::size_t i = 0; i < bits.size() && i < 32; ++i) {
    if (bits[i] != 0) field |= 1u << i;
  }
  return field;
}

std::string RegisterMap::describe_alarm(std::int64_t code) const {
  const auto it = alarm_texts.find(code);
  if (it == alarm_texts.end()) return fmt::format("0x{:02X}", code);
  return fmt::format("0x{:02X} ({})", code, it->second);
}

// ---------------------------------------------------------------------------
// Parsing

namespace {

struct Span {
  RegisterTable table;
  int first;
  int last;
  std::string key;
};

RegisterTable parse_table(const ConfigTable& t, std::initializer_list<RegisterTable> allowed, RegisterTable fallback) {
  const auto name = t.maybe<std::string>("table");
  if (!name) return fallback;
  const std::pair<std::string_view, RegisterTable> names[] = {
      {"holding", RegisterTable::holding},
      {"input", RegisterTable::input},
      {"coil", RegisterTable::coil},
      {"discrete", RegisterTable::discrete_input},
  };
  std::string list;
  for (const auto& [text, table] : names) {
    if (std::find(allowed.begin(), allowed.end(), table) == allowed.end()) continue;
    if (*name == text) return table;
    list += fmt::format("{}\"{}\"", list.empty() ? "" : ", ", text);
  }
  t.fail("table", fmt::format("must be one of {} here, got \"{}\"", list, *name));
}

std::uint16_t parse_address(const ConfigTable& t) {
  return static_cast<std::uint16_t>(t.required<std::int64_t>("address", {0, 0xFFFF}));
}

WordOrder parse_word_order(const ConfigTable& t, WordOrder fallback) {
  const auto text = t.maybe<std::string>("word_order");
  if (!text) return fallback;
  if (*text == "high_first") return WordOrder::high_first;
  if (*text == "low_first") return WordOrder::low_first;
  t.fail("word_order", fmt::format("must be \"high_first\" or \"low_first\", got \"{}\"", *text));
}

int parse_words(const ConfigTable& t, int fallback) { return t.optional<int>("words", fallback, {1, 2}); }

struct ValueDefaults {
  std::initializer_list<RegisterTable> tables;
  RegisterTable table;
  int words;
  bool is_signed;
};

RegisterValue parse_value(const ConfigTable& t, WordOrder order, const ValueDefaults& d) {
  t.allow_only({"table", "address", "words", "word_order", "signed", "scale", "reciprocal"});
  RegisterValue v;
  v.table = parse_table(t, d.tables, d.table);
  v.address = parse_address(t);
  v.words = parse_words(t, d.words);
  v.word_order = parse_word_order(t, order);
  v.is_signed = t.optional<bool>("signed", d.is_signed);
  // Register units per step (or, reciprocal, register units times steps):
  // wide enough for any drive's rpm or time units, narrow enough that no
  // conversion overflows a double.
  v.scale = t.optional<double>("scale", 1.0, {1e-12, 1e12});
  v.reciprocal = t.optional<bool>("reciprocal", false);
  if (v.reciprocal && v.is_signed) t.fail("reciprocal", "a reciprocal value cannot be signed");
  return v;
}

void check_fits(const ConfigTable& t, std::string_view key, std::int64_t value, RegisterTable table, int words) {
  if (table == RegisterTable::coil) {
    if (value != 0 && value != 1) t.fail(key, fmt::format("a coil takes 0 or 1, got {}", value));
    return;
  }
  const std::int64_t lo = words == 1 ? -32768 : std::numeric_limits<std::int32_t>::min();
  const std::int64_t hi = words == 1 ? 65535 : std::numeric_limits<std::uint32_t>::max();
  if (value < lo || value > hi) {
    t.fail(key, fmt::format("{} does not fit in {} register{}", value, words, words == 1 ? "" : "s"));
  }
}

RegisterWrite parse_write_fields(const ConfigTable& t, WordOrder order) {
  RegisterWrite w;
  w.table = parse_table(t, {RegisterTable::holding, RegisterTable::coil}, RegisterTable::holding);
  w.address = parse_address(t);
  w.words = parse_words(t, 1);
  if (w.table == RegisterTable::coil && w.words != 1) t.fail("words", "a coil is one bit: words must be 1");
  w.word_order = parse_word_order(t, order);
  w.value = t.required<std::int64_t>("value");
  check_fits(t, "value", w.value, w.table, w.words);
  return w;
}

RegisterWrite parse_write(const ConfigTable& t, WordOrder order) {
  t.allow_only({"table", "address", "words", "word_order", "value"});
  return parse_write_fields(t, order);
}

RegisterCommand parse_command(const ConfigTable& t, WordOrder order, bool is_enable) {
  if (is_enable) {
    t.allow_only({"table", "address", "words", "word_order", "value", "off_value", "release", "self_clearing"});
  } else {
    t.allow_only({"table", "address", "words", "word_order", "value", "release", "self_clearing"});
  }
  RegisterCommand c;
  c.write = parse_write_fields(t, order);
  c.release = t.maybe<std::int64_t>("release");
  if (c.release) check_fits(t, "release", *c.release, c.write.table, c.write.words);
  c.self_clearing = t.optional<bool>("self_clearing", false);
  if (c.release && c.self_clearing)
    t.fail("self_clearing", "a command is either released by the client or self-clearing");
  if (is_enable) {
    c.off_value = t.required<std::int64_t>("off_value");
    check_fits(t, "off_value", *c.off_value, c.write.table, c.write.words);
  }
  return c;
}

StatusBits parse_status(const ConfigTable& t, WordOrder order) {
  t.allow_only({"table", "address", "words", "word_order", "ready", "busy", "in_position", "alarm", "homed", "enabled",
                "limit_min", "limit_max", "home_switch"});
  StatusBits s;
  s.table =
      parse_table(t, {RegisterTable::holding, RegisterTable::input, RegisterTable::discrete_input, RegisterTable::coil},
                  RegisterTable::input);
  s.address = parse_address(t);
  if (is_bit_table(s.table)) {
    if (t.contains("words")) t.fail("words", "status bits in discrete inputs or coils have no words");
    if (t.contains("word_order")) t.fail("word_order", "status bits in discrete inputs or coils have no word order");
  } else {
    s.words = parse_words(t, 1);
    s.word_order = parse_word_order(t, order);
  }
  const int bit_limit = is_bit_table(s.table) ? 32 : 16 * s.words;
  const auto bit = [&](std::string_view key) -> std::optional<int> {
    const auto b = t.maybe<int>(key);
    if (b && (*b < 0 || *b >= bit_limit)) t.fail(key, fmt::format("bit must be 0 to {}, got {}", bit_limit - 1, *b));
    return b;
  };
  s.ready = bit("ready");
  s.busy = bit("busy");
  s.in_position = bit("in_position");
  s.alarm = bit("alarm");
  s.homed = bit("homed");
  s.enabled = bit("enabled");
  s.limit_min = bit("limit_min");
  s.limit_max = bit("limit_max");
  s.home_switch = bit("home_switch");
  if (!s.busy && !s.in_position) t.fail("a status needs a busy or an in_position bit to tell when a move ends");
  return s;
}

// Named subtables ([setup.<name>]) as fixed writes, in address order.
std::vector<RegisterWrite> parse_writes(const ConfigTable& parent, WordOrder order) {
  std::vector<RegisterWrite> writes;
  for (const auto& [key, node] : parent.raw()) {
    writes.push_back(parse_write(parent.table(key.str()), order));
  }
  std::sort(writes.begin(), writes.end(), [](const RegisterWrite& a, const RegisterWrite& b) {
    return std::pair(a.table, a.address) < std::pair(b.table, b.address);
  });
  return writes;
}

std::string format_span(const Span& s) {
  if (s.first == s.last) return fmt::format("{} 0x{:04X}", to_string(s.table), s.first);
  return fmt::format("{}s 0x{:04X}..0x{:04X}", to_string(s.table), s.first, s.last);
}

}  // namespace

RegisterMap parse_register_map(const ConfigTable& root) {
  root.allow_only({"drive", "setup", "move_constants", "target_position", "velocity", "acceleration", "deceleration",
                   "commands", "status", "actual_position", "alarm_code", "alarm_codes"});
  RegisterMap map;
  map.source = root.source();

  WordOrder order = WordOrder::high_first;
  if (const auto drive = root.maybe_table("drive")) {
    drive->allow_only({"description", "word_order", "single_writes"});
    map.description = drive->optional<std::string>("description", "");
    order = parse_word_order(*drive, order);
    const auto single = drive->optional<std::string>("single_writes", "fc06");
    if (single != "fc06" && single != "fc16") {
      drive->fail("single_writes", fmt::format("must be \"fc06\" or \"fc16\", got \"{}\"", single));
    }
    map.single_writes_fc16 = single == "fc16";
  }

  if (const auto setup = root.maybe_table("setup")) map.setup = parse_writes(*setup, order);
  if (const auto constants = root.maybe_table("move_constants")) map.move_constants = parse_writes(*constants, order);

  const ValueDefaults written{{RegisterTable::holding}, RegisterTable::holding, 2, false};
  ValueDefaults position = written;
  position.is_signed = true;
  map.target_position = parse_value(root.table("target_position"), order, position);
  map.velocity = parse_value(root.table("velocity"), order, written);
  map.acceleration = parse_value(root.table("acceleration"), order, written);
  if (const auto t = root.maybe_table("deceleration")) map.deceleration = parse_value(*t, order, written);

  const auto commands = root.table("commands");
  commands.allow_only({"start", "stop", "home", "alarm_reset", "enable", "emergency_stop"});
  map.start = parse_command(commands.table("start"), order, false);
  map.stop = parse_command(commands.table("stop"), order, false);
  if (const auto t = commands.maybe_table("home")) map.home = parse_command(*t, order, false);
  if (const auto t = commands.maybe_table("alarm_reset")) map.alarm_reset = parse_command(*t, order, false);
  if (const auto t = commands.maybe_table("enable")) map.enable = parse_command(*t, order, true);
  if (const auto t = commands.maybe_table("emergency_stop")) map.emergency_stop = parse_command(*t, order, false);

  map.status = parse_status(root.table("status"), order);
  const ValueDefaults read{{RegisterTable::holding, RegisterTable::input}, RegisterTable::input, 2, true};
  map.actual_position = parse_value(root.table("actual_position"), order, read);
  if (const auto t = root.maybe_table("alarm_code")) {
    ValueDefaults code = read;
    code.words = 1;
    code.is_signed = false;
    map.alarm_code = parse_value(*t, order, code);
  }
  if (const auto texts = root.maybe_table("alarm_codes")) {
    for (const auto& [key, node] : texts->raw()) {
      const std::string k(key.str());
      std::int64_t code = 0;
      try {
        std::size_t used = 0;
        code = std::stoll(k, &used, 0);
        if (used != k.size()) throw std::invalid_argument(k);
      } catch (const std::exception&) {
        texts->fail(k, "alarm code keys are numbers, e.g. \"0x30\" or \"48\"");
      }
      map.alarm_texts[code] = texts->required<std::string>(k);
    }
  }

  // The move's registers are written in one go: two fields sharing a register
  // would silently overwrite each other, and a command inside them would fire
  // with the data. Commands may share a register among themselves (one
  // command register, several values).
  std::vector<std::pair<Span, const ConfigTable*>> data;
  const auto target_t = root.table("target_position");
  const auto velocity_t = root.table("velocity");
  const auto accel_t = root.table("acceleration");
  const auto decel_t = root.maybe_table("deceleration");
  const auto span_of = [](const RegisterValue& v, std::string key) {
    return Span{v.table, v.address, v.address + v.words - 1, std::move(key)};
  };
  data.emplace_back(span_of(map.target_position, "target_position"), &target_t);
  data.emplace_back(span_of(map.velocity, "velocity"), &velocity_t);
  data.emplace_back(span_of(map.acceleration, "acceleration"), &accel_t);
  if (map.deceleration) data.emplace_back(span_of(*map.deceleration, "deceleration"), &*decel_t);
  std::vector<Span> constants;
  for (const auto& w : map.move_constants) {
    constants.push_back(Span{w.table, w.address, w.address + w.words - 1, "move_constants"});
  }
  const auto overlaps = [](const Span& a, const Span& b) {
    return a.table == b.table && a.first <= b.last && b.first <= a.last;
  };
  for (std::size_t i = 0; i < data.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      if (overlaps(data[i].first, data[j].first)) {
        data[i].second->fail("address", fmt::format("{} overlaps {} ({})", format_span(data[i].first),
                                                    data[j].first.key, format_span(data[j].first)));
      }
    }
    for (const auto& c : constants) {
      if (overlaps(data[i].first, c)) {
        data[i].second->fail(
            "address", fmt::format("{} overlaps a move constant ({})", format_span(data[i].first), format_span(c)));
      }
    }
  }
  const std::pair<const char*, const std::optional<RegisterCommand>*> optional_commands[] = {
      {"home", &map.home},
      {"alarm_reset", &map.alarm_reset},
      {"enable", &map.enable},
      {"emergency_stop", &map.emergency_stop}};
  std::vector<std::pair<const char*, const RegisterCommand*>> all_commands = {{"start", &map.start},
                                                                              {"stop", &map.stop}};
  for (const auto& [name, command] : optional_commands) {
    if (*command) all_commands.emplace_back(name, &**command);
  }
  for (const auto& [name, command] : all_commands) {
    const Span s{command->write.table, command->write.address, command->write.address + command->write.words - 1, name};
    for (const auto& [d, table] : data) {
      if (overlaps(s, d)) {
        commands.table(name).fail("address", fmt::format("{} overlaps {} ({})", format_span(s), d.key, format_span(d)));
      }
    }
  }
  return map;
}

RegisterMap load_register_map(const std::filesystem::path& path) {
  return parse_register_map(ConfigTable::load_file(path));
}

}  // namespace markerd::rig
