// Register maps (the shipped ones and the format's errors), value encoding,
// and the Modbus tables of the rig config: [rig.buses.<name>] and
// [rig.<axis>.modbus].

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/modbus_drive.hpp"
#include "markerd/rig/register_map.hpp"

using markerd::ConfigError;
using markerd::ConfigTable;
using namespace markerd::rig;

namespace {

const std::filesystem::path kSourceDir = MARKERD_SOURCE_DIR;

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

// The smallest valid map, to which each error test adds one mistake.
const std::string kMinimal = R"([target_position]
address = 0
[velocity]
address = 2
[acceleration]
address = 4
[commands.start]
address = 8
value = 1
[commands.stop]
address = 8
value = 2
[status]
address = 0
busy = 1
[actual_position]
address = 1
)";

RegisterMap parse(const std::string& text) { return parse_register_map(ConfigTable::parse(text, "map.toml")); }

}  // namespace

TEST(RegisterMap, ShippedMapsLoad) {
  const auto generic = load_register_map(kSourceDir / "config/drives/generic.toml");
  EXPECT_EQ(generic.target_position.address, 0x0000);
  EXPECT_EQ(generic.target_position.words, 2);
  EXPECT_TRUE(generic.target_position.is_signed);
  EXPECT_EQ(generic.start.write.value, 1);
  EXPECT_TRUE(generic.start.self_clearing);
  EXPECT_EQ(generic.status.table, RegisterTable::input);
  EXPECT_EQ(generic.describe_alarm(0x30), "0x30 (overload)");
  EXPECT_EQ(generic.describe_alarm(0x99), "0x99");

  const auto az = load_register_map(kSourceDir / "config/drives/oriental-az.toml");
  EXPECT_EQ(az.target_position.address, 0x005C);
  EXPECT_EQ(az.start.write.address, 0x0066);
  EXPECT_EQ(az.start.write.words, 2);
  EXPECT_EQ(az.move_constants.size(), 3u);
  EXPECT_EQ(az.status.address, 0x007F);
  EXPECT_EQ(az.alarm_code->address, 0x0080);

  const auto leadshine = load_register_map(kSourceDir / "config/drives/leadshine-pr.toml");
  EXPECT_EQ(leadshine.target_position.address, 0x6201);
  EXPECT_EQ(leadshine.start.write.address, 0x6207);
  EXPECT_EQ(leadshine.start.write.value, 0x10);
  EXPECT_TRUE(leadshine.acceleration.reciprocal);
}

TEST(RegisterMap, WordOrderAndSign) {
  RegisterValue v;
  v.words = 2;
  v.is_signed = true;
  std::uint16_t r[2];
  v.pack(-70000, r);
  EXPECT_EQ(r[0], 0xFFFE);
  EXPECT_EQ(r[1], 0xEE90);
  EXPECT_EQ(v.unpack(r), -70000);
  v.word_order = WordOrder::low_first;
  v.pack(0x12345678, r);
  EXPECT_EQ(r[0], 0x5678);
  EXPECT_EQ(r[1], 0x1234);
  EXPECT_EQ(v.unpack(r), 0x12345678);
  v.is_signed = false;
  v.pack(0xFFFFFFFFLL, r);
  EXPECT_EQ(v.unpack(r), 0xFFFFFFFFLL);
  v.words = 1;
  v.is_signed = true;
  v.pack(-2, r);
  EXPECT_EQ(r[0], 0xFFFE);
  EXPECT_EQ(v.unpack(r), -2);
}

TEST(RegisterMap, ScalesAndRanges) {
  // Leadshine's units at 10000 pulses/rev: rpm and ms per 1000 rpm.
  const auto m = load_register_map(kSourceDir / "config/drives/leadshine-pr.toml");
  EXPECT_EQ(m.velocity.to_raw(50000), 300);    // 50000 steps/s = 300 rpm
  EXPECT_EQ(m.acceleration.to_raw(1e6), 167);  // 6000 rpm/s: 1000 rpm in 167 ms
  EXPECT_NEAR(m.acceleration.to_steps(167), 998024, 1);
  EXPECT_EQ(m.velocity.to_raw(2e7), std::nullopt);  // 120000 rpm: beyond 16 bits
  EXPECT_EQ(m.velocity.to_raw(-100), std::nullopt);
  EXPECT_EQ(m.acceleration.to_raw(0), std::nullopt);
  EXPECT_EQ(m.target_position.to_raw(-3e9), std::nullopt);
  EXPECT_EQ(m.target_position.to_raw(-2147483648.0), -2147483648LL);
}

TEST(RegisterMap, ErrorsNameFileLineAndKey) {
  EXPECT_NO_THROW(parse(kMinimal));
  EXPECT_EQ(error_of([] { parse(kMinimal + "[deceleration]\naddress = 3\n"); }),
            "map.toml:19: deceleration.address: holding registers 0x0003..0x0004 overlaps velocity (holding registers "
            "0x0002..0x0003)");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[commands.home]\naddress = 5\nvalue = 3\n"); }),
            "map.toml:19: commands.home.address: holding register 0x0005 overlaps acceleration (holding registers "
            "0x0004..0x0005)");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[alarm_code]\ntable = \"coil\"\naddress = 9\n"); }),
            "map.toml:19: alarm_code.table: must be one of \"holding\", \"input\" here, got \"coil\"");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[commands.enable]\naddress = 9\nvalue = 1\n"); }),
            "map.toml:18: [commands.enable]: missing key 'commands.enable.off_value' (an integer)");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[drive]\nword_order = \"big\"\n"); }),
            "map.toml:19: drive.word_order: must be \"high_first\" or \"low_first\", got \"big\"");
  EXPECT_EQ(
      error_of([] { parse(kMinimal + "[velocity2]\naddress = 9\n"); }).rfind("map.toml:18: velocity2: unknown key", 0),
      0u);
  std::string no_busy = kMinimal;
  no_busy.replace(no_busy.find("busy = 1"), 8, "ready = 0");
  EXPECT_EQ(error_of([&] { parse(no_busy); }),
            "map.toml:13: [status]: a status needs a busy or an in_position bit to tell when a move ends");
  std::string bad_bit = kMinimal;
  bad_bit.replace(bad_bit.find("busy = 1"), 8, "busy = 16");
  EXPECT_EQ(error_of([&] { parse(bad_bit); }), "map.toml:15: status.busy: bit must be 0 to 15, got 16");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[deceleration]\naddress = 9223372036854775807\n"); }),
            "map.toml:19: deceleration.address: must be from 0 to 65535, got 9223372036854775807");
  EXPECT_EQ(error_of([] { parse(kMinimal + "[deceleration]\naddress = 9\nscale = 1e300\n"); }),
            "map.toml:20: deceleration.scale: must be from 1e-12 to 1000000000000, got 1e+300");
  std::string coil_value = kMinimal;
  const std::string stop = "[commands.stop]\naddress = 8\nvalue = 2";
  coil_value.replace(coil_value.find(stop), stop.size(), "[commands.stop]\ntable = \"coil\"\naddress = 8\nvalue = 2");
  EXPECT_EQ(error_of([&] { parse(coil_value); }), "map.toml:13: commands.stop.value: a coil takes 0 or 1, got 2");
}

TEST(ModbusConfig, BusTablesOfTheShippedRigs) {
  const auto rtu_root = ConfigTable::load_file(kSourceDir / "config/rig-modbus-rtu.toml");
  const auto rtu = parse_modbus_bus(rtu_root.table("rig").table("buses").table("rtu0"));
  EXPECT_EQ(rtu.name, "rtu0");
  EXPECT_EQ(rtu.transport, ModbusTransport::rtu);
  EXPECT_EQ(rtu.device, "/dev/ttyUSB0");
  EXPECT_EQ(rtu.baud, 115200);
  EXPECT_EQ(rtu.parity, 'E');
  EXPECT_EQ(rtu.response_timeout.count(), 100);
  EXPECT_EQ(rtu.byte_timeout.count(), 20);
  EXPECT_EQ(rtu.retries, 2);
  EXPECT_EQ(rtu.poll_period.count(), 50);
  EXPECT_EQ(rtu.describe(), "rtu0 (/dev/ttyUSB0, 115200 8E1)");

  const auto config_dir = kSourceDir / "config";
  for (const char* axis : {"rail", "turntable"}) {
    const auto d = parse_modbus_drive(rtu_root.table("rig").table(axis).table("modbus"), config_dir);
    EXPECT_EQ(d.bus, "rtu0");
    EXPECT_EQ(d.map, config_dir / "drives/generic.toml");
    EXPECT_NO_THROW(load_register_map(d.map));
  }
  EXPECT_EQ(parse_modbus_drive(rtu_root.table("rig").table("turntable").table("modbus"), config_dir).unit_id, 2);

  const auto tcp_root = ConfigTable::load_file(kSourceDir / "config/rig-modbus-tcp.toml");
  const auto tcp = parse_modbus_bus(tcp_root.table("rig").table("buses").table("turntable"));
  EXPECT_EQ(tcp.transport, ModbusTransport::tcp);
  EXPECT_EQ(tcp.describe(), "turntable (192.168.10.22:502)");
  EXPECT_EQ(parse_modbus_drive(tcp_root.table("rig").table("rail").table("modbus"), config_dir).bus, "rail");
}

TEST(ModbusConfig, BusAndDriveErrorsNameFileLineAndKey) {
  const auto bus = [](const std::string& body) {
    return error_of([&] {
      const auto root = ConfigTable::parse("[rig.buses.rtu0]\n" + body, "rig.toml");
      (void)parse_modbus_bus(root.table("rig").table("buses").table("rtu0"));
    });
  };
  EXPECT_EQ(bus("type = \"rtu\"\ndevice = \"/dev/ttyS0\"\nbaud = 14400\n"),
            "rig.toml:4: rig.buses.rtu0.baud: must be a standard rate (1200 to 921600), got 14400");
  EXPECT_EQ(bus("type = \"rtu\"\ndevice = \"/dev/ttyS0\"\nparity = \"E\"\n"),
            "rig.toml:4: rig.buses.rtu0.parity: must be \"none\", \"even\" or \"odd\", got \"E\"");
  EXPECT_EQ(bus("type = \"tcp\"\nhost = \"10.0.0.2\"\ndevice = \"/dev/ttyS0\"\n")
                .rfind("rig.toml:4: rig.buses.rtu0.device: unknown key", 0),
            0u);
  // Refused when markerd starts otherwise: --check-config must say so.
  EXPECT_EQ(bus("type = \"rtu\"\ndevice = \"\"\n"),
            "rig.toml:3: rig.buses.rtu0.device: must name the serial device (a path such as /dev/ttyUSB0)");
  EXPECT_EQ(bus("type = \"tcp\"\nhost = \"\"\n"),
            "rig.toml:3: rig.buses.rtu0.host: must name the server (a host name or an address)");
  EXPECT_EQ(bus("type = \"can\"\n"), "rig.toml:2: rig.buses.rtu0.type: must be \"rtu\" or \"tcp\", got \"can\"");
  EXPECT_EQ(bus("type = \"rtu\"\ndevice = \"/dev/ttyS0\"\nretries = 11\n"),
            "rig.toml:4: rig.buses.rtu0.retries: must be from 0 to 10, got 11");
  // The timeouts bound every wait on the bus: no overflow into a short or
  // negative one.
  EXPECT_EQ(bus("type = \"rtu\"\ndevice = \"/dev/ttyS0\"\nresponse_timeout_ms = 9223372036854775807\n"),
            "rig.toml:4: rig.buses.rtu0.response_timeout_ms: must be from 1 to 10000 ms, got 9223372036854775807");
  EXPECT_EQ(bus("type = \"tcp\"\nhost = \"10.0.0.2\"\nport = 4294967798\n"),
            "rig.toml:4: rig.buses.rtu0.port: must be from 1 to 65535, got 4294967798");

  const auto drive = [](const std::string& body) {
    return error_of([&] {
      const auto root = ConfigTable::parse("[rig.rail.modbus]\n" + body, "rig.toml");
      (void)parse_modbus_drive(root.table("rig").table("rail").table("modbus"), kSourceDir / "config");
    });
  };
  EXPECT_EQ(drive("bus = \"rtu0\"\nunit_id = 0\nmap = \"drives/generic.toml\"\n"),
            "rig.toml:3: rig.rail.modbus.unit_id: must be from 1 to 247, got 0");
  EXPECT_EQ(drive("bus = \"rtu0\"\nunit_id = 1\nmap = \"drives/generic.toml\"\ncompletion_margin_ms = -1\n"),
            "rig.toml:5: rig.rail.modbus.completion_margin_ms: must be from 0 to 600000 ms, got -1");
  // A directory where the map belongs is named at the key, not parsed as an empty map.
  EXPECT_EQ(drive("bus = \"rtu0\"\nunit_id = 1\nmap = \"drives\"\n"),
            "rig.toml:4: rig.rail.modbus.map: " + (kSourceDir / "config/drives").string() +
                ": the register map is a directory, not a file");
  EXPECT_EQ(drive("bus = \"rtu0\"\nunit_id = 1\nmap = \"drives/nothing.toml\"\n"),
            "rig.toml:4: rig.rail.modbus.map: no such file: " + (kSourceDir / "config/drives/nothing.toml").string());
  const std::string long_name = std::string(256, 'm') + ".toml";
  EXPECT_EQ(drive("bus = \"rtu0\"\nunit_id = 1\nmap = \"drives/" + long_name + "\"\n"),
            "rig.toml:4: rig.rail.modbus.map: " + (kSourceDir / "config/drives" / long_name).string() +
                ": the register map cannot be used: a name in its path is 261 bytes long, longer than the 255 a "
                "file system takes");
}
