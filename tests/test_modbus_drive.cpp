// ModbusDrive against the simulated drive, a real Modbus server, over
// loopback TCP and over RTU through a socat pty pair: moves, homing, stops,
// two drives on one RTU line, and every injected fault ending as the right
// DriveError or alarm after the bus's bounded retries, then recovering.

#include <gtest/gtest.h>
#include <modbus.h>

#include <atomic>
#include <filesystem>
#include <future>
#include <memory>
#include <string>
#include <thread>

#include "markerd/rig/axis.hpp"
#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/modbus_drive.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "modbus/peers.hpp"

using namespace markerd::rig;
using markerd::test_support::wait_for;
using std::chrono::milliseconds;

namespace {

const std::filesystem::path kSourceDir = MARKERD_SOURCE_DIR;

RegisterMap generic_map() { return load_register_map(kSourceDir / "config/drives/generic.toml"); }

ModbusSimUnit sim_unit(int id, double start_position = 0, bool homed = true) {
  ModbusSimUnit u;
  u.unit_id = id;
  u.map = generic_map();
  u.start_position_steps = start_position;
  u.homed = homed;
  return u;
}

// Timeouts generous enough for a loaded 2-core machine under ASan; the fault
// tests make their faults last longer than all attempts together.
ModbusBusSettings common_settings(std::string name) {
  ModbusBusSettings s;
  s.name = std::move(name);
  s.response_timeout = milliseconds(250);
  s.byte_timeout = milliseconds(50);
  s.retries = 2;
  s.poll_period = milliseconds(20);
  return s;
}

ModbusBusSettings tcp_settings(int port) {
  auto s = common_settings("tcp0");
  s.transport = ModbusTransport::tcp;
  s.host = "127.0.0.1";
  s.port = port;
  return s;
}

ModbusBusSettings rtu_settings(const std::filesystem::path& device) {
  auto s = common_settings("rtu0");
  s.transport = ModbusTransport::rtu;
  s.device = device.string();
  s.baud = 115200;
  s.parity = 'E';
  return s;
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const DriveError& e) {
    return e.what();
  }
  return "(no DriveError)";
}

bool idle(const ModbusDrive& d) { return !d.status().busy; }

bool reaches(const ModbusDrive& d, std::int64_t target) {
  return wait_for([&] {
    const auto s = d.status();
    return !s.busy && !s.alarm && s.position_steps == target;
  });
}

// A simulator over loopback TCP and a bus connected to it.
struct TcpRig {
  ModbusDriveSim sim;
  std::shared_ptr<ModbusBus> bus;
  explicit TcpRig(std::vector<ModbusSimUnit> units) : sim(std::move(units), ModbusSimTcp{}) {
    sim.start();
    bus = std::make_shared<ModbusBus>(tcp_settings(sim.port()));
  }
};

// A simulator on one end of a pty pair, serving several unit ids, and a bus
// on the other end.
struct RtuRig {
  markerd::test_support::TempDir dir;
  markerd::test_support::SocatPtyPair line{dir.path()};
  ModbusDriveSim sim;
  std::shared_ptr<ModbusBus> bus;
  explicit RtuRig(std::vector<ModbusSimUnit> units, int retries = 2)
      : sim(std::move(units), ModbusSimRtu{line.b().string(), 115200, 'E', 8, 1}) {
    sim.start();
    auto settings = rtu_settings(line.a());
    settings.retries = retries;
    bus = std::make_shared<ModbusBus>(settings);
  }
};

}  // namespace

TEST(ModbusDriveTcp, MovesToPositionWithOneRequestForDataAndTrigger) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  EXPECT_EQ(drive.name(), "rail (modbus unit 1 on tcp0)");
  EXPECT_FALSE(drive.status().enabled);
  drive.enable(true);
  ASSERT_TRUE(wait_for([&] { return drive.status().enabled; }));
  EXPECT_TRUE(rig.sim.state(1).enabled);

  rig.sim.clear_writes(1);
  drive.start_move(-70000, 200000, 2e6);
  EXPECT_TRUE(drive.status().busy);
  ASSERT_TRUE(reaches(drive, -70000)) << drive.status().alarm_cause;
  const auto state = rig.sim.state(1);
  EXPECT_EQ(state.target_steps, -70000);
  EXPECT_DOUBLE_EQ(state.last_velocity, 200000);
  EXPECT_DOUBLE_EQ(state.last_acceleration, 2e6);
  EXPECT_EQ(state.moves, 1);

  // Target, velocity, acceleration, deceleration (int32, high word first) and
  // the start command, in one FC16 request.
  const auto writes = rig.sim.writes(1);
  ASSERT_EQ(writes.size(), 1u);
  EXPECT_EQ(writes[0].table, RegisterTable::holding);
  EXPECT_EQ(writes[0].address, 0x0000);
  const std::vector<std::uint16_t> expected = {0xFFFE, 0xEE90, 0x0003, 0x0D40, 0x001E, 0x8480, 0x001E, 0x8480, 1};
  EXPECT_EQ(writes[0].values, expected);
}

TEST(ModbusDriveTcp, HomesWithTheDrivesOwnSequence) {
  TcpRig rig({sim_unit(1, 3000, false)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  ASSERT_TRUE(wait_for([&] { return drive.status().enabled && drive.status().position_steps == 3000; }));
  EXPECT_FALSE(drive.status().homed);
  HomingSteps homing;
  homing.timeout_s = 30;
  drive.start_homing(homing);
  ASSERT_TRUE(wait_for([&] {
    const auto s = drive.status();
    return !s.busy && s.homed;
  })) << drive.status().alarm_cause;
  EXPECT_EQ(drive.status().position_steps, 0);
  EXPECT_FALSE(drive.status().alarm);
  EXPECT_EQ(rig.sim.state(1).homings, 1);
}

TEST(ModbusDriveTcp, StopEndsAMoveShortOfItsTarget) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  drive.start_move(1'000'000, 5000, 50000);  // 200 s at full speed
  ASSERT_TRUE(wait_for([&] { return rig.sim.state(1).position_steps > 500; }));
  drive.stop();
  ASSERT_TRUE(wait_for([&] { return idle(drive); }));
  const auto s = drive.status();
  EXPECT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_GT(s.position_steps, 500);
  EXPECT_LT(s.position_steps, 1'000'000);
  EXPECT_EQ(rig.sim.state(1).stops, 1);
  EXPECT_FALSE(rig.sim.state(1).moving);
}

TEST(ModbusDriveTcp, EmergencyStopHaltsAndDisablesAtOnce) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  drive.start_move(1'000'000, 5000, 50000);
  ASSERT_TRUE(wait_for([&] { return rig.sim.state(1).moving; }));
  drive.emergency_stop();
  ASSERT_TRUE(wait_for([&] {
    const auto s = rig.sim.state(1);
    return s.emergency_stops == 1 && !s.enabled && !s.moving;
  }));
  ASSERT_TRUE(wait_for([&] { return !drive.status().enabled && !drive.status().busy; }));
  EXPECT_FALSE(drive.status().alarm);
}

TEST(ModbusDriveTcp, DriveAlarmFaultsWithItsCodeUntilReset) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  drive.start_move(1'000'000, 5000, 50000);
  ASSERT_TRUE(wait_for([&] { return rig.sim.state(1).moving; }));
  rig.sim.raise_alarm(1, 0x30);
  ASSERT_TRUE(wait_for([&] { return drive.status().alarm; }));
  auto s = drive.status();
  EXPECT_EQ(s.alarm_cause, "drive alarm 0x30 (overload)");
  ASSERT_TRUE(wait_for([&] { return idle(drive); }));
  EXPECT_NE(error_of([&] { drive.start_move(0, 5000, 50000); }).find("in alarm (drive alarm 0x30 (overload))"),
            std::string::npos);

  drive.reset_alarm();
  EXPECT_FALSE(drive.status().alarm) << drive.status().alarm_cause;
  EXPECT_EQ(rig.sim.state(1).alarm_resets, 1);
  const auto here = drive.status().position_steps;
  drive.start_move(here - 100, 5000, 50000);
  EXPECT_TRUE(reaches(drive, here - 100)) << drive.status().alarm_cause;
}

TEST(ModbusDriveTcp, ExceptionRepliesFailTheCommandAfterBoundedRetries) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  const auto before = rig.bus->counters();
  rig.sim.exception_replies(1, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
  const auto message = error_of([&] { drive.start_move(1000, 5000, 50000); });
  EXPECT_NE(message.find("rail (modbus unit 1 on tcp0): move to 1000 steps failed: modbus bus tcp0 (127.0.0.1:"),
            std::string::npos)
      << message;
  EXPECT_NE(message.find(", unit 1: write 9 holding registers at 0x0000: exception reply 0x04 (Slave device or server "
                         "failure) (3 attempts)"),
            std::string::npos)
      << message;
  const auto after = rig.bus->counters();
  EXPECT_GE(after.retries - before.retries, 2u);
  EXPECT_GE(after.failures - before.failures, 1u);
  ASSERT_TRUE(wait_for([&] { return drive.status().alarm; }));
  EXPECT_EQ(rig.sim.state(1).moves, 0);  // an exception reply means "not executed"

  // Latched until reset; once the drive answers again, the reset clears it.
  rig.sim.clear_reply_faults(1);
  EXPECT_TRUE(drive.status().alarm);
  drive.reset_alarm();
  EXPECT_FALSE(drive.status().alarm) << drive.status().alarm_cause;
  drive.enable(true);
  drive.start_move(1000, 5000, 50000);
  EXPECT_TRUE(reaches(drive, 1000)) << drive.status().alarm_cause;
}

TEST(ModbusDriveTcp, RepliesLaterThanTheTimeoutLoseCommunication) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  rig.sim.delay_replies(1, milliseconds(1500));
  ASSERT_TRUE(wait_for([&] { return drive.status().alarm; }));
  const auto cause = drive.status().alarm_cause;
  EXPECT_NE(cause.find("rail (modbus unit 1 on tcp0): lost communication: modbus bus tcp0"), std::string::npos)
      << cause;
  EXPECT_NE(cause.find("unit 1: read 4 input registers at 0x0000: no reply within 250 ms (3 attempts)"),
            std::string::npos)
      << cause;

  // Recovery: the replies are on time again, the stale ones are discarded,
  // and a reset clears the latched fault.
  rig.sim.clear_reply_faults(1);
  ASSERT_TRUE(wait_for([&] {
    try {
      drive.reset_alarm();
    } catch (const DriveError&) {
      return false;
    }
    return !drive.status().alarm;
  }));
  drive.enable(true);
  drive.start_move(-500, 5000, 50000);
  EXPECT_TRUE(reaches(drive, -500)) << drive.status().alarm_cause;
}

TEST(ModbusDriveTcp, ATransientLossIsRetriedWithoutAFault) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  const auto before = rig.bus->counters();
  rig.sim.drop_requests(1, 1);
  drive.start_move(2000, 20000, 200000);
  EXPECT_TRUE(reaches(drive, 2000)) << drive.status().alarm_cause;
  EXPECT_GE(rig.bus->counters().retries - before.retries, 1u);
  EXPECT_EQ(rig.bus->counters().failures, before.failures);
  EXPECT_EQ(rig.sim.state(1).moves, 1);
}

TEST(ModbusDriveTcp, AMoveThatNeverReachesItsTargetFaultsAndStops) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map(), milliseconds(300));
  drive.enable(true);
  rig.sim.stall_at(1, 0.5);
  drive.start_move(10000, 100000, 1e6);  // planned 0.2 s
  ASSERT_TRUE(wait_for([&] { return drive.status().alarm; }));
  const auto cause = drive.status().alarm_cause;
  EXPECT_NE(cause.find("rail (modbus unit 1 on tcp0): move to 10000 steps not finished"), std::string::npos) << cause;
  EXPECT_NE(cause.find("at 5000 steps, drive still busy; stopped"), std::string::npos) << cause;
  EXPECT_TRUE(wait_for([&] { return rig.sim.state(1).stops == 1; }));

  rig.sim.clear_stall(1);
  drive.reset_alarm();
  EXPECT_FALSE(drive.status().alarm) << drive.status().alarm_cause;
  drive.start_move(10000, 100000, 1e6);
  EXPECT_TRUE(reaches(drive, 10000)) << drive.status().alarm_cause;
}

TEST(ModbusDriveTcp, ReconnectsAfterTheConnectionDrops) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  const auto before = rig.bus->counters();
  rig.sim.disconnect_clients();
  ASSERT_TRUE(wait_for([&] { return rig.bus->counters().reconnects > before.reconnects; }));
  drive.start_move(300, 5000, 50000);
  EXPECT_TRUE(reaches(drive, 300)) << drive.status().alarm_cause;
  EXPECT_EQ(rig.bus->counters().failures, before.failures);
}

TEST(ModbusDriveTcp, ValuesOutsideTheRegistersAreRefusedBeforeAnyWrite) {
  TcpRig rig({sim_unit(1)});
  ModbusDrive drive("rail", rig.bus, 1, generic_map());
  drive.enable(true);
  rig.sim.clear_writes(1);
  const auto message = error_of([&] { drive.start_move(3'000'000'000LL, 5000, 50000); });
  EXPECT_NE(
      message.find("target position 3000000000 is 3000000000 in the drive's units (holding register 0x0000, scale 1), "
                   "outside its range -2147483648..2147483647"),
      std::string::npos)
      << message;
  EXPECT_TRUE(rig.sim.writes(1).empty());
  EXPECT_FALSE(drive.status().alarm);
}

TEST(ModbusDriveTcp, AnAxisHomesMovesAndSettlesOverIt) {
  TcpRig rig({sim_unit(1, 1500, false)});
  AxisSettings settings;
  settings.name = "rail";
  settings.unit = "mm";
  settings.units_per_step = 0.01;
  settings.min_position = 0;
  settings.max_position = 100;
  settings.max_velocity = 50;
  settings.acceleration = 500;
  settings.settle_time = milliseconds(50);
  settings.retry_deadband = 0.02;
  settings.homing.timeout = std::chrono::seconds(30);
  Axis axis(settings, std::make_unique<ModbusDrive>("rail", rig.bus, 1, generic_map()));
  axis.enable();
  axis.home();
  ASSERT_TRUE(wait_for([&] { return axis.status().homed && axis.status().state == AxisState::idle; }))
      << axis.status().fault;
  axis.move_to(25.0);
  ASSERT_TRUE(axis.wait_settled(std::chrono::seconds(20))) << axis.status().fault;
  EXPECT_NEAR(axis.status().position, 25.0, 1e-9);
  EXPECT_EQ(rig.sim.state(1).target_steps, 2500);

  // A drive alarm faults the axis with the drive's words.
  rig.sim.raise_alarm(1, 0x20);
  ASSERT_TRUE(wait_for([&] { return axis.status().state == AxisState::fault; }));
  EXPECT_NE(axis.status().fault.find("drive alarm 0x20 (overcurrent)"), std::string::npos) << axis.status().fault;
}

TEST(ModbusBus, ADeviceThatCannotBeOpenedIsAClearError) {
  ModbusBusSettings s = rtu_settings("/nonexistent/ttyRS485");
  EXPECT_EQ(error_of([&] { ModbusBus bus(s); }),
            "modbus bus rtu0 (/nonexistent/ttyRS485, 115200 8E1): cannot open /nonexistent/ttyRS485: No such file or "
            "directory");
}

// A request queued behind a bus thread that does not come back fails within
// a bound, instead of holding its caller (an axis command, a stop) for ever.
TEST(ModbusBus, ARequestQueuedBehindAStuckBusFailsWithinABound) {
  ModbusDriveSim sim({sim_unit(1)}, ModbusSimTcp{});
  sim.start();
  auto settings = tcp_settings(sim.port());
  settings.retries = 0;
  settings.response_timeout = milliseconds(10);
  ModbusBus bus(settings);
  std::atomic<bool> release{false};
  std::atomic<bool> inside{false};
  std::thread stuck([&] {
    bus.execute([&](ModbusLink&) {
      inside = true;
      while (!release) std::this_thread::sleep_for(milliseconds(1));
    });
  });
  ASSERT_TRUE(wait_for([&] { return inside.load(); }));
  auto queued = std::async(std::launch::async, [&] { return error_of([&] { bus.execute([](ModbusLink&) {}); }); });
  const bool returned = queued.wait_for(std::chrono::seconds(30)) == std::future_status::ready;
  release = true;
  stuck.join();
  ASSERT_TRUE(returned) << "the queued request still waits";
  EXPECT_EQ(queued.get(), "modbus bus tcp0 (127.0.0.1:" + std::to_string(sim.port()) +
                              "): the request waited 900 ms for the bus without being sent (the bus thread is stuck)");
  // The bus goes on: the next request is served.
  bool served = false;
  bus.execute([&](ModbusLink&) { served = true; });
  EXPECT_TRUE(served);
}

TEST(ModbusDriveRtu, TwoDrivesShareOneLineByUnitId) {
  RtuRig rig({sim_unit(1), sim_unit(2)});
  ModbusDrive rail("rail", rig.bus, 1, generic_map());
  ModbusDrive turntable("turntable", rig.bus, 2, generic_map());
  rail.enable(true);
  turntable.enable(true);
  rail.start_move(40000, 100000, 1e6);
  turntable.start_move(-9000, 50000, 5e5);
  EXPECT_TRUE(reaches(rail, 40000)) << rail.status().alarm_cause;
  EXPECT_TRUE(reaches(turntable, -9000)) << turntable.status().alarm_cause;
  EXPECT_EQ(rig.sim.state(1).target_steps, 40000);
  EXPECT_EQ(rig.sim.state(2).target_steps, -9000);
  EXPECT_EQ(rig.sim.state(1).moves, 1);
  EXPECT_EQ(rig.sim.state(2).moves, 1);
  EXPECT_EQ(rig.bus->counters().failures, 0u);
}

TEST(ModbusDriveRtu, CorruptedCrcsFaultOnlyTheirDrive) {
  RtuRig rig({sim_unit(1), sim_unit(2)});
  ModbusDrive rail("rail", rig.bus, 1, generic_map());
  ModbusDrive turntable("turntable", rig.bus, 2, generic_map());
  rail.enable(true);
  turntable.enable(true);
  rig.sim.corrupt_crc(2);
  ASSERT_TRUE(wait_for([&] { return turntable.status().alarm; }));
  const auto cause = turntable.status().alarm_cause;
  EXPECT_NE(cause.find("turntable (modbus unit 2 on rtu0): lost communication: modbus bus rtu0"), std::string::npos)
      << cause;
  EXPECT_NE(cause.find("unit 2: read 4 input registers at 0x0000: reply with a bad CRC (3 attempts)"),
            std::string::npos)
      << cause;
  // The other drive on the line carries on.
  rail.start_move(1234, 50000, 5e5);
  EXPECT_TRUE(reaches(rail, 1234)) << rail.status().alarm_cause;

  rig.sim.clear_reply_faults(2);
  turntable.reset_alarm();
  EXPECT_FALSE(turntable.status().alarm) << turntable.status().alarm_cause;
}

TEST(ModbusDriveRtu, RepliesFromAnotherUnitAreRejected) {
  RtuRig rig({sim_unit(1)});
  ModbusDrive rail("rail", rig.bus, 1, generic_map());
  rail.enable(true);
  rig.sim.reply_as_unit(1, 9);
  const auto message = error_of([&] { rail.start_move(100, 5000, 50000); });
  EXPECT_NE(message.find("unit 1: write 9 holding registers at 0x0000: reply from another unit (3 attempts)"),
            std::string::npos)
      << message;
}

TEST(ModbusDriveRtu, ATransientBadFrameIsRetriedWithoutAFault) {
  RtuRig rig({sim_unit(1)});
  ModbusDrive rail("rail", rig.bus, 1, generic_map());
  rail.enable(true);
  const auto before = rig.bus->counters();
  rig.sim.corrupt_crc(1, 1);
  rail.start_move(777, 50000, 5e5);
  EXPECT_TRUE(reaches(rail, 777)) << rail.status().alarm_cause;
  EXPECT_GE(rig.bus->counters().retries - before.retries, 1u);
  EXPECT_EQ(rig.bus->counters().failures, before.failures);
}

TEST(ModbusDriveRtu, AnEmergencyStopJumpsAheadOfARequestBeingRetried) {
  RtuRig rig({sim_unit(1), sim_unit(2)}, 6);
  ModbusDrive rail("rail", rig.bus, 1, generic_map());
  ModbusDrive turntable("turntable", rig.bus, 2, generic_map());
  rail.enable(true);
  turntable.enable(true);
  rail.start_move(1'000'000, 5000, 50000);
  ASSERT_TRUE(wait_for([&] { return rig.sim.state(1).moving; }));
  // The turntable stops answering: its requests hold the line for seven
  // attempts of 250 ms each.
  const auto before = rig.bus->counters();
  rig.sim.delay_replies(2, milliseconds(5000));
  ASSERT_TRUE(wait_for([&] { return rig.bus->counters().retries > before.retries; }));
  rail.emergency_stop();
  // The rail's emergency stop went out between two of those attempts, before
  // the turntable's request gave up.
  ASSERT_TRUE(wait_for([&] {
    const auto s = rig.sim.state(1);
    return s.emergency_stops == 1 && !s.enabled && !s.moving;
  }));
  EXPECT_EQ(rig.bus->counters().failures, before.failures);
}
