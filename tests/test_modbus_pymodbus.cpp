// The wire format of ModbusDrive against a Modbus server this project did not
// write: Debian's python3-pymodbus 3.0 (tests/modbus/pymodbus_server.py),
// started with /usr/bin/python3, which reports every write that reached its
// datastore. A map with the low word first, a coil as start trigger pulsed
// 1 then 0, status bits in discrete inputs and the position in input
// registers exercises FC02, FC04, FC05, FC06 and FC16.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/modbus_drive.hpp"
#include "markerd/rig/register_map.hpp"
#include "modbus/peers.hpp"

using namespace markerd::rig;
using markerd::test_support::wait_for;

namespace {

const std::filesystem::path kSourceDir = MARKERD_SOURCE_DIR;
const std::filesystem::path kDebianPython = "/usr/bin/python3";

// Addresses shared with the script's command line.
constexpr int kTarget = 0x10;    // holding 0x10..0x11, low word first
constexpr int kPosition = 0x20;  // input 0x20..0x21
constexpr int kStartCoil = 3;

const char* kMap = R"([drive]
description = "pymodbus wire-format test"
word_order = "low_first"

[setup.mode]
address = 0x30
value = 7

[target_position]
address = 0x10
signed = true

[velocity]
address = 0x12

[acceleration]
address = 0x14

[commands.start]
table = "coil"
address = 3
value = 1
release = 0

[commands.stop]
table = "coil"
address = 4
value = 1
release = 0

[commands.enable]
table = "coil"
address = 5
value = 1
off_value = 0

[status]
table = "discrete"
address = 0
ready = 0
busy = 1
in_position = 2
alarm = 3

[actual_position]
table = "input"
address = 0x20
)";

struct Write {
  std::string table;
  int address = 0;
  std::vector<int> values;
  bool operator==(const Write&) const = default;
};

std::ostream& operator<<(std::ostream& os, const Write& w) {
  os << w.table << " " << w.address << " [";
  for (const int v : w.values) os << v << " ";
  return os << "]";
}

// The script's JSON lines: {"table": "hr", "address": 16, "values": [1, 2]}.
std::vector<Write> read_log(const std::filesystem::path& log) {
  std::vector<Write> writes;
  std::ifstream in(log);
  const std::regex line(R"re(\{"table": "(\w+)", "address": (\d+), "values": \[([\d, ]*)\]\})re");
  for (std::string text; std::getline(in, text);) {
    std::smatch m;
    if (!std::regex_match(text, m, line)) continue;
    Write w{m[1], std::stoi(m[2]), {}};
    std::stringstream values(m[3]);
    for (std::string v; std::getline(values, v, ',');) w.values.push_back(std::stoi(v));
    writes.push_back(w);
  }
  return writes;
}

}  // namespace

TEST(ModbusPymodbus, WritesAMoveInTheConfiguredWordOrderAndPulsesTheTrigger) {
  if (!std::filesystem::exists(kDebianPython)) GTEST_SKIP() << kDebianPython << " is missing";
  markerd::test_support::TempDir dir;
  const auto port_file = dir.path() / "port";
  const auto log = dir.path() / "writes.jsonl";
  markerd::test_support::PeerProcess server(
      {kDebianPython.string(), (kSourceDir / "tests/modbus/pymodbus_server.py").string(), "--port-file",
       port_file.string(), "--log", log.string(), "--target", std::to_string(kTarget), "--position",
       std::to_string(kPosition), "--start-coil", std::to_string(kStartCoil)},
      dir.path() / "server.out");
  ASSERT_TRUE(wait_for([&] { return std::filesystem::exists(port_file) || !server.running(); }));
  ASSERT_TRUE(std::filesystem::exists(port_file))
      << "the pymodbus server did not start; see its output in " << (dir.path() / "server.out");
  int port = 0;
  std::ifstream(port_file) >> port;
  ASSERT_GT(port, 0);

  ModbusBusSettings settings;
  settings.name = "pymodbus";
  settings.transport = ModbusTransport::tcp;
  settings.host = "127.0.0.1";
  settings.port = port;
  settings.response_timeout = std::chrono::milliseconds(1000);
  settings.poll_period = std::chrono::milliseconds(20);
  auto bus = std::make_shared<ModbusBus>(settings);
  ModbusDrive drive("rail", bus, 1, parse_register_map(markerd::ConfigTable::parse(kMap, "pymodbus-test.toml")));
  drive.enable(true);
  drive.start_move(0x12345, 0x20000 + 7, 100000);
  // The server "moves" on the trigger: the target words come back as the
  // actual position, read with FC04 and decoded in the same word order.
  ASSERT_TRUE(wait_for([&] {
    const auto s = drive.status();
    return !s.busy && s.position_steps == 0x12345;
  })) << drive.status().alarm_cause;
  drive.start_move(-2, 1000, 100000);
  ASSERT_TRUE(wait_for([&] {
    const auto s = drive.status();
    return !s.busy && s.position_steps == -2;
  })) << drive.status().alarm_cause;
  EXPECT_FALSE(drive.status().alarm) << drive.status().alarm_cause;

  const std::vector<Write> expected = {
      {"hr", 0x30, {7}},  // setup, FC06
      {"co", 5, {1}},     // enable, FC05
      // target 0x00012345, velocity 0x00020007, acceleration 100000 =
      // 0x000186A0, low word first, one FC16; then the trigger pulse.
      {"hr", 0x10, {0x2345, 0x0001, 0x0007, 0x0002, 0x86A0, 0x0001}},
      {"co", 3, {1}},
      {"co", 3, {0}},
      {"hr", 0x10, {0xFFFE, 0xFFFF, 1000, 0, 0x86A0, 0x0001}},  // -2
      {"co", 3, {1}},
      {"co", 3, {0}},
  };
  ASSERT_TRUE(wait_for([&] { return read_log(log).size() >= expected.size(); }));
  EXPECT_EQ(read_log(log), expected);
}
