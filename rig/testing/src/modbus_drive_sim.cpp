#include "markerd/rig/testing/modbus_drive_sim.hpp"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <optional>
#include <span>
#include <stdexcept>
#include <thread>
#include <utility>

#include "markerd/rig/motion_profile.hpp"

namespace markerd::rig {

namespace {

// Modbus RTU's CRC-16 (polynomial 0xA001, reflected, initial 0xFFFF), sent
// low byte first.
std::uint16_t crc16(std::span<const std::uint8_t> bytes) {
  std::uint16_t crc = 0xFFFF;
  for (const std::uint8_t b : bytes) {
    crc ^= b;
    for (int i = 0; i < 8; ++i) crc = (crc & 1u) != 0 ? static_cast<std::uint16_t>((crc >> 1) ^ 0xA001u) : crc >> 1;
  }
  return crc;
}

void close_fd(int& fd) {
  if (fd >= 0) ::close(fd);
  fd = -1;
}

struct Range {
  RegisterTable table;
  int first;
  int last;
};

constexpr int kRtuHeader = 1;  // unit id before the PDU
constexpr int kTcpHeader = 7;  // MBAP header, unit id last

}  // namespace

struct ModbusDriveSim::Impl {
  struct Fault {
    enum class Kind : std::uint8_t { none, delay, drop, corrupt_crc, exception, wrong_unit } kind = Kind::none;
    int remaining = 0;  // < 0: until cleared
    std::chrono::milliseconds delay{0};
    int code = 0;  // exception code, or the unit a wrong reply names
  };

  struct Unit {
    ModbusSimUnit config;
    modbus_mapping_t* mapping = nullptr;
    std::vector<Range> read_only;

    // The motor: at rest at `origin`, or moving from it along `profile` since
    // sim time t0, in `direction`. Physical coordinates; the drive reports
    // physical - reference.
    double origin = 0;
    double reference = 0;
    bool moving = false;
    bool homing = false;
    TrapezoidProfile profile;
    int direction = 1;
    double t0 = 0;
    double stall_fraction = 1;
    bool enabled = false;
    bool homed = false;
    bool alarm = false;
    std::int64_t alarm_code = 0;
    std::int64_t target = 0;
    ModbusSimState counters;
    Fault fault;
    std::vector<ModbusSimWrite> writes;

    Unit() = default;
    Unit(const Unit&) = delete;
    Unit& operator=(const Unit&) = delete;
    ~Unit() {
      if (mapping != nullptr) modbus_mapping_free(mapping);
    }
  };

  std::map<int, std::unique_ptr<Unit>> units;
  bool tcp = false;
  ModbusSimTcp tcp_settings;
  ModbusSimRtu rtu_settings;
  std::shared_ptr<const SimClock> clock;

  mutable std::mutex mutex;     // the units (model, mapping, faults, records)
  modbus_t* link = nullptr;     // RTU: the open device; TCP: receives requests on a client's socket
  modbus_t* replies = nullptr;  // builds replies into `capture`, so that faults can alter them
  int capture[2] = {-1, -1};
  int wake = -1;
  int listener = -1;
  int bound_port = 0;
  std::vector<int> clients;
  // Late replies waiting for their time: the server answers other requests
  // (other units on the line, other connections) meanwhile, as the other
  // drives of a bus would.
  struct Pending {
    std::chrono::steady_clock::time_point due;
    int fd;
    std::vector<std::uint8_t> bytes;
  };
  std::vector<Pending> pending;
  std::atomic<bool> stopping{false};
  std::atomic<bool> drop_clients{false};
  std::jthread thread;

  Impl(std::vector<ModbusSimUnit> unit_list, std::shared_ptr<const SimClock> c) : clock(std::move(c)) {
    if (!clock) clock = std::make_shared<const SimClock>(1.0);
    for (auto& config : unit_list) {
      if (config.unit_id < 1 || config.unit_id > 247) {
        throw std::invalid_argument(fmt::format("ModbusDriveSim: unit id {} is not 1..247", config.unit_id));
      }
      if (units.contains(config.unit_id)) {
        throw std::invalid_argument(fmt::format("ModbusDriveSim: unit id {} given twice", config.unit_id));
      }
      auto u = std::make_unique<Unit>();
      u->config = std::move(config);
      init_unit(*u);
      units.emplace(u->config.unit_id, std::move(u));
    }
  }

  ~Impl() {
    stop();
    if (link != nullptr) modbus_free(link);
    if (replies != nullptr) modbus_free(replies);
  }

  // ---------------------------------------------------------------- model

  static void init_unit(Unit& u) {
    const RegisterMap& m = u.config.map;
    // Size each table to what the map names, so that other addresses get
    // exception 02 as on a real drive.
    std::map<RegisterTable, std::pair<int, int>> extent;
    const auto cover = [&](RegisterTable t, int address, int count) {
      auto [it, fresh] = extent.try_emplace(t, address, address + count - 1);
      if (!fresh) {
        it->second.first = std::min(it->second.first, address);
        it->second.second = std::max(it->second.second, address + count - 1);
      }
    };
    for (const auto* list : {&m.setup, &m.move_constants}) {
      for (const auto& w : *list) cover(w.table, w.address, w.words);
    }
    for (const auto* v : {&m.target_position, &m.velocity, &m.acceleration, &m.actual_position}) {
      cover(v->table, v->address, v->words);
    }
    if (m.deceleration) cover(m.deceleration->table, m.deceleration->address, m.deceleration->words);
    if (m.alarm_code) cover(m.alarm_code->table, m.alarm_code->address, m.alarm_code->words);
    for (const auto* c : {&m.start, &m.stop}) cover(c->write.table, c->write.address, c->write.words);
    for (const auto* c : {&m.home, &m.alarm_reset, &m.enable, &m.emergency_stop}) {
      if (*c) cover((*c)->write.table, (*c)->write.address, (*c)->write.words);
    }
    cover(m.status.table, m.status.address, m.status.read_count());
    const auto span_of = [&](RegisterTable t) -> std::pair<unsigned, unsigned> {
      const auto it = extent.find(t);
      if (it == extent.end()) return {0, 0};
      return {static_cast<unsigned>(it->second.first), static_cast<unsigned>(it->second.second - it->second.first + 1)};
    };
    const auto [coil0, coils] = span_of(RegisterTable::coil);
    const auto [di0, dis] = span_of(RegisterTable::discrete_input);
    const auto [hr0, hrs] = span_of(RegisterTable::holding);
    const auto [ir0, irs] = span_of(RegisterTable::input);
    u.mapping = modbus_mapping_new_start_address(coil0, coils, di0, dis, hr0, hrs, ir0, irs);
    if (u.mapping == nullptr) throw std::bad_alloc();

    if (!is_bit_table(m.status.table) || m.status.table == RegisterTable::coil) {
      u.read_only.push_back(Range{m.status.table, m.status.address, m.status.address + m.status.read_count() - 1});
    }
    u.read_only.push_back(Range{m.actual_position.table, m.actual_position.address,
                                m.actual_position.address + m.actual_position.words - 1});
    if (m.alarm_code) {
      u.read_only.push_back(
          Range{m.alarm_code->table, m.alarm_code->address, m.alarm_code->address + m.alarm_code->words - 1});
    }

    u.origin = u.config.start_position_steps;
    u.reference = 0;
    u.homed = u.config.homed;
    u.enabled = u.config.enabled || !m.enable;
    u.target = std::llround(u.origin);
  }

  static std::uint16_t* registers(Unit& u, RegisterTable table, int address) {
    auto* mp = u.mapping;
    if (table == RegisterTable::holding) return mp->tab_registers + (address - mp->start_registers);
    return mp->tab_input_registers + (address - mp->start_input_registers);
  }

  static std::uint8_t* bits(Unit& u, RegisterTable table, int address) {
    auto* mp = u.mapping;
    if (table == RegisterTable::coil) return mp->tab_bits + (address - mp->start_bits);
    return mp->tab_input_bits + (address - mp->start_input_bits);
  }

  static double steps_of(Unit& u, const RegisterValue& v) {
    return v.to_steps(v.unpack(std::span<const std::uint16_t>(registers(u, v.table, v.address), v.words)));
  }

  // Where the motor is at sim time `now`, and how fast it goes.
  static std::pair<double, double> kinematics(const Unit& u, double now) {
    if (!u.moving) return {u.origin, 0.0};
    const double t = now - u.t0;
    double travelled = u.profile.position_at(t);
    double speed = u.profile.velocity_at(t);
    if (u.stall_fraction < 1 && travelled >= u.stall_fraction * u.profile.distance()) {
      travelled = u.stall_fraction * u.profile.distance();
      speed = 0;
    }
    return {u.origin + u.direction * travelled, speed * u.direction};
  }

  // Ends a motion whose profile has run out (a stalled one never ends).
  static void settle(Unit& u, double now) {
    if (!u.moving || u.stall_fraction < 1 || now - u.t0 < u.profile.duration()) return;
    u.origin += u.direction * u.profile.distance();
    u.moving = false;
    if (u.homing) {
      u.homing = false;
      u.reference = u.origin;  // the switch (physical 0) becomes position 0
      u.homed = true;
    }
  }

  static void freeze(Unit& u, double now) {
    u.origin = kinematics(u, now).first;
    u.moving = false;
    u.homing = false;
  }

  static void run_to(Unit& u, double now, double physical_target, double velocity, double acceleration) {
    u.origin = kinematics(u, now).first;
    const double distance = std::abs(physical_target - u.origin);
    u.direction = physical_target >= u.origin ? 1 : -1;
    u.profile = TrapezoidProfile(distance, velocity, acceleration);
    u.t0 = now;
    u.moving = true;
  }

  static void command_start(Unit& u, double now) {
    const RegisterMap& m = u.config.map;
    // A drive that is not ready ignores START, as real ones do; the client
    // then sees a move that never finishes.
    if (u.alarm || !u.enabled || u.moving) return;
    const double target = steps_of(u, m.target_position);
    const double velocity = steps_of(u, m.velocity);
    const double acceleration = steps_of(u, m.acceleration);
    if (!(velocity > 0) || !(acceleration > 0) || !std::isfinite(velocity) || !std::isfinite(acceleration)) {
      raise(u, now, kSimAlarmInvalidMove);
      return;
    }
    u.target = std::llround(target);
    run_to(u, now, target + u.reference, velocity, acceleration);
    ++u.counters.moves;
    u.counters.last_velocity = velocity;
    u.counters.last_acceleration = acceleration;
  }

  static void command_stop(Unit& u, double now) {
    ++u.counters.stops;
    if (!u.moving) return;
    const auto [position, velocity] = kinematics(u, now);
    const RegisterMap& m = u.config.map;
    double decel = steps_of(u, m.deceleration ? *m.deceleration : m.acceleration);
    if (!(decel > 0) || !std::isfinite(decel)) decel = u.config.homing_acceleration;
    u.origin = position;
    u.homing = false;
    if (velocity == 0) {
      u.moving = false;
      return;
    }
    u.direction = velocity > 0 ? 1 : -1;
    u.profile = TrapezoidProfile::braking(std::abs(velocity), decel);
    u.t0 = now;
  }

  static void command_home(Unit& u, double now) {
    if (u.alarm || !u.enabled || u.moving) return;
    ++u.counters.homings;
    u.homed = false;
    run_to(u, now, 0.0, u.config.homing_velocity, u.config.homing_acceleration);
    u.homing = true;
  }

  static void raise(Unit& u, double now, std::int64_t code) {
    freeze(u, now);
    u.alarm = true;
    u.alarm_code = code;
  }

  // The status bits, position and alarm code as the map serves them.
  static void publish(Unit& u, double now) {
    settle(u, now);
    const RegisterMap& m = u.config.map;
    const double physical = kinematics(u, now).first;
    const double position = physical - u.reference;
    const bool in_position = !u.moving && !u.alarm && std::abs(position - static_cast<double>(u.target)) < 0.5;
    std::uint32_t field = 0;
    const auto set = [&field](const std::optional<int>& bit, bool on) {
      if (bit && on) field |= 1u << *bit;
    };
    const auto& s = m.status;
    set(s.ready, u.enabled && !u.alarm && !u.moving);
    set(s.busy, u.moving);
    set(s.in_position, in_position);
    set(s.alarm, u.alarm);
    set(s.homed, u.homed);
    set(s.enabled, u.enabled);
    set(s.home_switch, physical <= 0.5);
    if (is_bit_table(s.table)) {
      for (int i = 0; i < s.read_count(); ++i) bits(u, s.table, s.address)[i] = (field >> i) & 1u;
    } else {
      std::uint16_t words[2];
      RegisterWrite layout{s.table, s.address, s.words, s.word_order, 0};
      layout.pack(field, std::span(words, static_cast<std::size_t>(s.words)));
      std::copy_n(words, s.words, registers(u, s.table, s.address));
    }
    const auto& p = m.actual_position;
    const double raw =
        std::clamp(std::round(position * p.scale), static_cast<double>(p.min_raw()), static_cast<double>(p.max_raw()));
    p.pack(static_cast<std::int64_t>(raw),
           std::span(registers(u, p.table, p.address), static_cast<std::size_t>(p.words)));
    if (m.alarm_code) {
      const auto& a = *m.alarm_code;
      a.pack(u.alarm ? u.alarm_code : 0,
             std::span(registers(u, a.table, a.address), static_cast<std::size_t>(a.words)));
    }
  }

  // Commands whose register the client just wrote, in a fixed order: a move
  // block that ends with its start command has its data in place by then.
  static void take_commands(Unit& u, RegisterTable table, int first, int last, double now) {
    const RegisterMap& m = u.config.map;
    const auto written = [&](const RegisterCommand& c) -> std::optional<std::int64_t> {
      const auto& w = c.write;
      if (w.table != table || w.address < first || w.address + w.words - 1 > last) return std::nullopt;
      if (table == RegisterTable::coil) return *bits(u, table, w.address);
      return w.unpack(std::span<const std::uint16_t>(registers(u, table, w.address), w.words));
    };
    const auto clear = [&](const RegisterCommand& c) {
      if (!c.self_clearing) return;
      if (table == RegisterTable::coil) {
        *bits(u, table, c.write.address) = 0;
      } else {
        std::fill_n(registers(u, table, c.write.address), c.write.words, std::uint16_t{0});
      }
    };
    if (m.enable) {
      if (const auto v = written(*m.enable)) {
        if (*v == m.enable->write.value) u.enabled = true;
        if (*v == *m.enable->off_value) {
          freeze(u, now);
          u.enabled = false;
        }
      }
    }
    if (m.alarm_reset) {
      if (const auto v = written(*m.alarm_reset); v && *v == m.alarm_reset->write.value) {
        u.alarm = false;
        u.alarm_code = 0;
        ++u.counters.alarm_resets;
        clear(*m.alarm_reset);
      }
    }
    if (m.emergency_stop) {
      if (const auto v = written(*m.emergency_stop); v && *v == m.emergency_stop->write.value) {
        freeze(u, now);
        ++u.counters.emergency_stops;
        clear(*m.emergency_stop);
      }
    }
    if (const auto v = written(m.stop); v && *v == m.stop.write.value) {
      command_stop(u, now);
      clear(m.stop);
    }
    if (m.home) {
      if (const auto v = written(*m.home); v && *v == m.home->write.value) {
        command_home(u, now);
        clear(*m.home);
      }
    }
    if (const auto v = written(m.start); v && *v == m.start.write.value) {
      command_start(u, now);
      clear(m.start);
    }
  }

  // ------------------------------------------------------------ requests

  struct Reply {
    std::vector<std::uint8_t> bytes;
    std::chrono::milliseconds delay{0};
  };

  [[nodiscard]] std::vector<std::uint8_t> captured() {
    std::vector<std::uint8_t> out;
    std::array<std::uint8_t, 512> buffer{};
    for (;;) {
      const ssize_t n = ::recv(capture[1], buffer.data(), buffer.size(), MSG_DONTWAIT);
      if (n <= 0) break;
      out.insert(out.end(), buffer.begin(), buffer.begin() + n);
    }
    return out;
  }

  Reply handle(const std::uint8_t* request, int length) {
    const int header = tcp ? kTcpHeader : kRtuHeader;
    if (length < header + 1) return {};
    const int unit_id = request[header - 1];
    const int function = request[header];
    std::lock_guard lock(mutex);
    const auto it = units.find(unit_id);
    // Another drive's request on a shared line (or a broadcast): not ours.
    if (it == units.end()) return {};
    Unit& u = *it->second;
    ++u.counters.requests;
    Fault fault;
    if (u.fault.kind != Fault::Kind::none && u.fault.remaining != 0) {
      fault = u.fault;
      if (u.fault.remaining > 0) --u.fault.remaining;
    }
    if (fault.kind == Fault::Kind::drop) return {};
    Reply reply;
    if (fault.kind == Fault::Kind::exception) {
      modbus_reply_exception(replies, request, static_cast<unsigned>(fault.code));
      reply.bytes = captured();
      return reply;
    }

    // What the request writes, if anything.
    const int address = length >= header + 3 ? (request[header + 1] << 8) | request[header + 2] : 0;
    const int quantity = length >= header + 5 ? (request[header + 3] << 8) | request[header + 4] : 0;
    std::optional<Range> written;
    if (function == 0x05) written = Range{RegisterTable::coil, address, address};
    if (function == 0x06) written = Range{RegisterTable::holding, address, address};
    if (function == 0x0F) written = Range{RegisterTable::coil, address, address + quantity - 1};
    if (function == 0x10) written = Range{RegisterTable::holding, address, address + quantity - 1};
    if (written) {
      for (const auto& r : u.read_only) {
        if (r.table == written->table && r.first <= written->last && written->first <= r.last) {
          modbus_reply_exception(replies, request, MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
          reply.bytes = captured();
          return reply;
        }
      }
    }

    const double now = clock->now();
    publish(u, now);
    if (modbus_reply(replies, request, length, u.mapping) < 0) return {};
    reply.bytes = captured();
    // modbus_reply answers an invalid request with an exception: then nothing
    // was written.
    const bool accepted = reply.bytes.size() > static_cast<std::size_t>(header) && (reply.bytes[header] & 0x80) == 0;
    if (written && accepted) {
      ModbusSimWrite record{written->table, static_cast<std::uint16_t>(written->first), {}};
      for (int a = written->first; a <= written->last; ++a) {
        record.values.push_back(written->table == RegisterTable::coil ? *bits(u, written->table, a)
                                                                      : *registers(u, written->table, a));
      }
      u.writes.push_back(std::move(record));
      take_commands(u, written->table, written->first, written->last, now);
      publish(u, now);
    }

    if (fault.kind == Fault::Kind::corrupt_crc && !reply.bytes.empty()) reply.bytes.back() ^= 0xA5;
    if (fault.kind == Fault::Kind::wrong_unit && !reply.bytes.empty()) {
      reply.bytes[static_cast<std::size_t>(header - 1)] = static_cast<std::uint8_t>(fault.code);
      if (!tcp) {
        const std::uint16_t crc = crc16(std::span(reply.bytes.data(), reply.bytes.size() - 2));
        reply.bytes[reply.bytes.size() - 2] = static_cast<std::uint8_t>(crc & 0xFF);
        reply.bytes[reply.bytes.size() - 1] = static_cast<std::uint8_t>(crc >> 8);
      }
    }
    if (fault.kind == Fault::Kind::delay) reply.delay = fault.delay;
    return reply;
  }

  // Milliseconds until the next late reply is due (-1: none), for poll().
  [[nodiscard]] int until_next_reply() const {
    if (pending.empty()) return -1;
    auto due = pending.front().due;
    for (const auto& p : pending) due = std::min(due, p.due);
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(due - std::chrono::steady_clock::now());
    return static_cast<int>(std::max<std::int64_t>(0, left.count()));
  }

  void send_due_replies() {
    const auto now = std::chrono::steady_clock::now();
    for (auto it = pending.begin(); it != pending.end();) {
      if (it->due > now) {
        ++it;
        continue;
      }
      if (tcp) {
        send_all(it->fd, it->bytes);
      } else if (::write(it->fd, it->bytes.data(), it->bytes.size()) < 0) {
        // A line that cannot be written is noticed by the next read.
      }
      it = pending.erase(it);
    }
  }

  void answer(int fd, Reply reply) {
    if (reply.bytes.empty()) return;
    if (reply.delay.count() > 0) {
      pending.push_back(Pending{std::chrono::steady_clock::now() + reply.delay, fd, std::move(reply.bytes)});
      return;
    }
    if (tcp) {
      send_all(fd, reply.bytes);
    } else if (::write(fd, reply.bytes.data(), reply.bytes.size()) < 0) {
      // As above.
    }
  }

  void drain_wake() {
    std::uint64_t count = 0;
    while (::read(wake, &count, sizeof count) > 0) {
    }
  }

  static bool send_all(int fd, const std::vector<std::uint8_t>& bytes) {
    std::size_t sent = 0;
    while (sent < bytes.size()) {
      const ssize_t n = ::send(fd, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
      if (n <= 0) return false;
      sent += static_cast<std::size_t>(n);
    }
    return true;
  }

  // ----------------------------------------------------------------- RTU

  // Reads exactly n bytes, each within `gap` of the previous; false on a
  // gap (a truncated frame) or a stop.
  bool read_exact(int fd, std::uint8_t* out, int n, int gap_ms) {
    int got = 0;
    while (got < n) {
      pollfd p[2] = {{fd, POLLIN, 0}, {wake, POLLIN, 0}};
      if (::poll(p, 2, gap_ms) <= 0) return false;
      if ((p[1].revents & POLLIN) != 0) {
        drain_wake();
        if (stopping.load()) return false;
      }
      if ((p[0].revents & POLLIN) == 0) continue;
      const ssize_t r = ::read(fd, out + got, static_cast<std::size_t>(n - got));
      if (r <= 0) return false;
      got += static_cast<int>(r);
    }
    return true;
  }

  // Discards bytes until the line has been quiet for `quiet_ms`.
  void resync(int fd, int quiet_ms) {
    std::array<std::uint8_t, 256> sink{};
    for (;;) {
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, quiet_ms) <= 0 || stopping.load()) return;
      if (::read(fd, sink.data(), sink.size()) <= 0) return;
    }
  }

  // One request frame from the line, framed by its function code (the
  // requests a drive gets: 01..06, 15, 16), its CRC checked as a slave does:
  // a bad frame is dropped without a reply. 0 when there is none.
  int read_rtu_frame(int fd, std::uint8_t* frame) {
    // Generous between bytes: a pty on a loaded machine delivers in bursts.
    constexpr int kGapMs = 100;
    if (!read_exact(fd, frame, 2, kGapMs)) return 0;
    const int function = frame[1];
    int have = 2;
    int length = 0;
    if (function >= 0x01 && function <= 0x06) {
      length = 8;
    } else if (function == 0x0F || function == 0x10) {
      if (!read_exact(fd, frame + 2, 5, kGapMs)) return 0;
      have = 7;
      length = 7 + frame[6] + 2;
    }
    if (length == 0 || length > MODBUS_RTU_MAX_ADU_LENGTH || !read_exact(fd, frame + have, length - have, kGapMs)) {
      resync(fd, 20);
      return 0;
    }
    const std::uint16_t crc = crc16(std::span<const std::uint8_t>(frame, static_cast<std::size_t>(length - 2)));
    if (frame[length - 2] != (crc & 0xFF) || frame[length - 1] != (crc >> 8)) return 0;
    return length;
  }

  void serve_rtu() {
    const int fd = modbus_get_socket(link);
    std::array<std::uint8_t, MODBUS_RTU_MAX_ADU_LENGTH> frame{};
    while (!stopping.load()) {
      pollfd p[2] = {{fd, POLLIN, 0}, {wake, POLLIN, 0}};
      if (::poll(p, 2, until_next_reply()) < 0 && errno != EINTR) return;
      if ((p[1].revents & POLLIN) != 0) drain_wake();
      send_due_replies();
      if ((p[0].revents & POLLIN) == 0) continue;
      const int length = read_rtu_frame(fd, frame.data());
      if (length > 0) answer(fd, handle(frame.data(), length));
    }
  }

  // ----------------------------------------------------------------- TCP

  void serve_tcp() {
    std::array<std::uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> request{};
    std::vector<pollfd> fds;
    while (!stopping.load()) {
      if (drop_clients.exchange(false)) {
        while (!clients.empty()) close_client(clients.back());
      }
      fds.clear();
      fds.push_back({wake, POLLIN, 0});
      fds.push_back({listener, POLLIN, 0});
      for (const int c : clients) fds.push_back({c, POLLIN, 0});
      if (::poll(fds.data(), fds.size(), until_next_reply()) < 0 && errno != EINTR) return;
      if ((fds[0].revents & POLLIN) != 0) drain_wake();
      send_due_replies();
      if ((fds[1].revents & POLLIN) != 0) {
        const int c = ::accept4(listener, nullptr, nullptr, SOCK_CLOEXEC);
        if (c >= 0) clients.push_back(c);
      }
      for (std::size_t i = 2; i < fds.size(); ++i) {
        if ((fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
        int fd = fds[i].fd;
        modbus_set_socket(link, fd);
        const int length = modbus_receive(link, request.data());
        if (length > 0) answer(fd, handle(request.data(), length));
        if (length < 0) close_client(fd);
      }
    }
  }

  void close_client(int fd) {
    clients.erase(std::find(clients.begin(), clients.end(), fd));
    std::erase_if(pending, [fd](const Pending& p) { return p.fd == fd; });
    ::close(fd);
  }

  // ------------------------------------------------------------- control

  void start() {
    if (thread.joinable()) return;
    stopping = false;
    wake = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (wake < 0 || ::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, capture) != 0) {
      throw std::runtime_error(fmt::format("ModbusDriveSim: {}", std::strerror(errno)));
    }
    if (tcp) {
      start_tcp();
    } else {
      start_rtu();
    }
    modbus_set_socket(replies, capture[0]);
    thread = std::jthread([this] { tcp ? serve_tcp() : serve_rtu(); });
  }

  void start_tcp() {
    if (link == nullptr) {
      link = modbus_new_tcp(tcp_settings.host.c_str(), tcp_settings.port);
      replies = modbus_new_tcp(tcp_settings.host.c_str(), tcp_settings.port);
      if (link == nullptr || replies == nullptr) throw std::runtime_error("ModbusDriveSim: libmodbus context");
      // A request's bytes arrive together; a client that stalls mid-frame is
      // dropped rather than holding the server.
      modbus_set_byte_timeout(link, 0, 200000);
    }
    listener = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int yes = 1;
    ::setsockopt(listener, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<std::uint16_t>(tcp_settings.port));
    if (::inet_pton(AF_INET, tcp_settings.host.c_str(), &addr.sin_addr) != 1) {
      throw std::runtime_error(fmt::format("ModbusDriveSim: \"{}\" is not a numeric IPv4 address", tcp_settings.host));
    }
    if (::bind(listener, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 || ::listen(listener, 8) != 0) {
      const int err = errno;
      close_fd(listener);
      throw std::runtime_error(fmt::format("ModbusDriveSim: cannot listen on {}:{}: {}", tcp_settings.host,
                                           tcp_settings.port, std::strerror(err)));
    }
    socklen_t len = sizeof addr;
    ::getsockname(listener, reinterpret_cast<sockaddr*>(&addr), &len);
    bound_port = ntohs(addr.sin_port);
  }

  void start_rtu() {
    const auto& r = rtu_settings;
    if (link == nullptr) {
      link = modbus_new_rtu(r.device.c_str(), r.baud, r.parity, r.data_bits, r.stop_bits);
      replies = modbus_new_rtu(r.device.c_str(), r.baud, r.parity, r.data_bits, r.stop_bits);
      if (link == nullptr || replies == nullptr) {
        throw std::runtime_error(fmt::format("ModbusDriveSim: libmodbus refuses RTU settings for {}", r.device));
      }
    }
    // libmodbus opens the device and sets its line discipline (raw, baud,
    // parity); the frames themselves are read here, since libmodbus's RTU
    // server answers one unit id only.
    if (modbus_connect(link) != 0) {
      throw std::runtime_error(fmt::format("ModbusDriveSim: cannot open {}: {}", r.device, modbus_strerror(errno)));
    }
  }

  void stop() {
    if (thread.joinable()) {
      stopping = true;
      const std::uint64_t one = 1;
      if (::write(wake, &one, sizeof one) < 0) {
        // An eventfd write fails only on overflow, which leaves it readable.
      }
      thread.join();
    }
    for (int& c : clients) close_fd(c);
    clients.clear();
    pending.clear();
    close_fd(listener);
    if (link != nullptr && !tcp) modbus_close(link);
    close_fd(capture[0]);
    close_fd(capture[1]);
    close_fd(wake);
  }

  Unit& unit(int id) {
    const auto it = units.find(id);
    if (it == units.end()) throw std::invalid_argument(fmt::format("ModbusDriveSim: no unit {}", id));
    return *it->second;
  }

  void set_fault(int id, Fault fault) {
    std::lock_guard lock(mutex);
    unit(id).fault = fault;
  }
};

ModbusDriveSim::ModbusDriveSim(std::vector<ModbusSimUnit> units, ModbusSimTcp tcp,
                               std::shared_ptr<const SimClock> clock)
    : impl_(std::make_unique<Impl>(std::move(units), std::move(clock))) {
  impl_->tcp = true;
  impl_->tcp_settings = std::move(tcp);
}

ModbusDriveSim::ModbusDriveSim(std::vector<ModbusSimUnit> units, ModbusSimRtu rtu,
                               std::shared_ptr<const SimClock> clock)
    : impl_(std::make_unique<Impl>(std::move(units), std::move(clock))) {
  impl_->tcp = false;
  impl_->rtu_settings = std::move(rtu);
}

ModbusDriveSim::~ModbusDriveSim() = default;

void ModbusDriveSim::start() { impl_->start(); }
void ModbusDriveSim::stop() { impl_->stop(); }
int ModbusDriveSim::port() const { return impl_->bound_port; }

void ModbusDriveSim::delay_replies(int unit, std::chrono::milliseconds delay, int count) {
  impl_->set_fault(unit, Impl::Fault{Impl::Fault::Kind::delay, count, delay, 0});
}

void ModbusDriveSim::drop_requests(int unit, int count) {
  impl_->set_fault(unit, Impl::Fault{Impl::Fault::Kind::drop, count, {}, 0});
}

void ModbusDriveSim::corrupt_crc(int unit, int count) {
  if (impl_->tcp) throw std::logic_error("ModbusDriveSim::corrupt_crc: Modbus TCP frames have no CRC");
  impl_->set_fault(unit, Impl::Fault{Impl::Fault::Kind::corrupt_crc, count, {}, 0});
}

void ModbusDriveSim::exception_replies(int unit, int exception_code, int count) {
  impl_->set_fault(unit, Impl::Fault{Impl::Fault::Kind::exception, count, {}, exception_code});
}

void ModbusDriveSim::reply_as_unit(int unit, int other_unit, int count) {
  impl_->set_fault(unit, Impl::Fault{Impl::Fault::Kind::wrong_unit, count, {}, other_unit});
}

void ModbusDriveSim::clear_reply_faults(int unit) { impl_->set_fault(unit, Impl::Fault{}); }

void ModbusDriveSim::raise_alarm(int unit, std::int64_t code) {
  std::lock_guard lock(impl_->mutex);
  Impl::raise(impl_->unit(unit), impl_->clock->now(), code);
}

void ModbusDriveSim::stall_at(int unit, double fraction) {
  std::lock_guard lock(impl_->mutex);
  impl_->unit(unit).stall_fraction = std::clamp(fraction, 0.0, 1.0);
}

void ModbusDriveSim::clear_stall(int unit) {
  std::lock_guard lock(impl_->mutex);
  auto& u = impl_->unit(unit);
  // The motor stays where it stalled; the move is over.
  if (u.moving && u.stall_fraction < 1) Impl::freeze(u, impl_->clock->now());
  u.stall_fraction = 1;
}

void ModbusDriveSim::disconnect_clients() {
  impl_->drop_clients = true;
  const std::uint64_t one = 1;
  if (impl_->wake >= 0 && ::write(impl_->wake, &one, sizeof one) < 0) {
    // Overflow only: the eventfd is readable anyway.
  }
}

ModbusSimState ModbusDriveSim::state(int unit) const {
  std::lock_guard lock(impl_->mutex);
  auto& u = impl_->unit(unit);
  const double now = impl_->clock->now();
  Impl::settle(u, now);
  const auto [physical, velocity] = Impl::kinematics(u, now);
  ModbusSimState s = u.counters;
  s.position_steps = physical - u.reference;
  s.velocity_steps_per_s = velocity;
  s.target_steps = u.target;
  s.enabled = u.enabled;
  s.moving = u.moving;
  s.homing = u.homing;
  s.homed = u.homed;
  s.in_position = !u.moving && !u.alarm && std::abs(s.position_steps - static_cast<double>(u.target)) < 0.5;
  s.alarm = u.alarm;
  s.alarm_code = u.alarm_code;
  return s;
}

std::vector<ModbusSimWrite> ModbusDriveSim::writes(int unit) const {
  std::lock_guard lock(impl_->mutex);
  return impl_->unit(unit).writes;
}

void ModbusDriveSim::clear_writes(int unit) {
  std::lock_guard lock(impl_->mutex);
  impl_->unit(unit).writes.clear();
}

}  // namespace markerd::rig
