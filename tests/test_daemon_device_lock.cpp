// markerd and the rig's device locks (docs/rig.md, "Device lock"): the real
// markerd on a Modbus TCP rig whose drives are simulated drive servers in
// this process, its locks in a directory of the test's own
// (MARKERD_LOCK_DIR). While markerd runs, every device of its rig is refused
// to any other holder (this process, markerctl rig), naming markerd; while
// another process holds one, markerd does not start, names the device and
// the holder, and has not spoken to a drive.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>  // program_invocation_short_name
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "support/child_process.hpp"
#include "support/files.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using test_support::Outcome;

rig::ModbusSimUnit drive_unit() {
  rig::ModbusSimUnit u;
  u.unit_id = 1;
  u.map = rig::load_register_map(test_support::kSourceTree / "config/drives/generic.toml");
  return u;
}

// The refusal a DeviceLock of `claims` gets, or "(not refused)".
std::string refusal(const std::vector<rig::DeviceClaim>& claims) {
  try {
    const rig::DeviceLock lock(claims);
  } catch (const rig::DeviceLockError& e) {
    return e.what();
  }
  return "(not refused)";
}

class MarkerdDeviceLock : public testing::Test {
 protected:
  void SetUp() override {
    // Before any thread starts: the markerd children inherit it, and this
    // process's own DeviceLocks use the same directory.
    ::setenv("MARKERD_LOCK_DIR", (dir_ / "locks").c_str(), 1);  // NOLINT(concurrency-mt-unsafe): no threads yet
    fs::create_directories(dir_ / "logs");
    fs::create_directories(dir_ / "state");
    rail_.start();
    turntable_.start();
    test_support::write_modbus_tcp_rig_config(dir_ / "rig.toml", rail_.port(), turntable_.port());
    test_support::TomlConfig::load(test_support::kSourceTree / "tests/data/markerd-sweep.toml")
        .set("camera.model", (test_support::kSourceTree / "config/cameras/thesis-640x480.yaml").string())
        .write(config());
    rig_config_ = rig::load_rig_config(dir_ / "rig.toml");
  }

  [[nodiscard]] fs::path config() const { return dir_ / "markerd.toml"; }
  [[nodiscard]] fs::path output() const { return dir_ / "markerd.out"; }

  // markerd started on config(); its control socket accepts once its
  // constructor (which takes the locks) has run.
  void start_markerd(test_support::ChildProcess& markerd) {
    markerd.start({MARKERD_PATH, "--config", config().string()}, output());
    (void)test_support::connect_control(markerd, dir_ / "control.sock", output(), 60s);
  }

  const test_support::TempDir temp_{"markerd-daemon-lock"};
  const fs::path dir_ = temp_.path();
  const std::shared_ptr<rig::SimClock> clock_ = std::make_shared<rig::SimClock>(1.0);
  rig::ModbusDriveSim rail_{{drive_unit()}, rig::ModbusSimTcp{}, clock_};
  rig::ModbusDriveSim turntable_{{drive_unit()}, rig::ModbusSimTcp{}, clock_};
  rig::RigConfig rig_config_;
};

TEST_F(MarkerdDeviceLock, WhileMarkerdRunsItsRigsDevicesAreRefusedNamingMarkerd) {
  const std::vector<rig::DeviceClaim> claims = rig::device_claims(rig_config_);
  ASSERT_EQ(claims.size(), 2U);  // the rail's and the turntable's TCP drive
  test_support::ChildProcess markerd;
  ASSERT_NO_THROW(start_markerd(markerd)) << test_support::read_file(output());

  // Every device, each on its own: markerd holds them all, not just the first.
  const std::string holder =
      fmt::format("is in use by markerd (pid {}: {} --config {})", markerd.pid(), MARKERD_PATH, config().string());
  for (const rig::DeviceClaim& claim : claims) {
    const std::string refused = refusal({claim});
    EXPECT_EQ(refused.rfind(claim.what + " " + holder + " (lock file ", 0), 0U) << refused;
  }
  EXPECT_NE(refusal(claims).find(holder), std::string::npos);

  // markerctl rig, the bring-up session an engineer would start.
  const Outcome markerctl =
      test_support::run_program({MARKERCTL_PATH, "rig", "--config", (dir_ / "rig.toml").string(), "status"});
  EXPECT_EQ(markerctl.code, 1) << markerctl.describe();
  EXPECT_EQ(markerctl.err.rfind("markerctl: rig status: ", 0), 0U) << markerctl.describe();
  EXPECT_NE(markerctl.err.find(holder), std::string::npos) << markerctl.describe();
  EXPECT_EQ(markerctl.out, "") << markerctl.describe();

  // Stopped, markerd leaves the devices free.
  const std::optional<int> stopped = markerd.terminate(30s);
  ASSERT_TRUE(stopped.has_value()) << "markerd did not stop on SIGTERM";
  EXPECT_EQ(test_support::exit_code(*stopped), 0) << test_support::read_file(output());
  EXPECT_EQ(refusal(claims), "(not refused)");
}

TEST_F(MarkerdDeviceLock, MarkerdDoesNotStartOnARigAnotherProcessHolds) {
  const std::vector<rig::DeviceClaim> claims = rig::device_claims(rig_config_);
  ASSERT_FALSE(claims.empty());
  // This process holds one of the two drives: markerd must not open the rig,
  // not even the free drive.
  std::optional<rig::DeviceLock> held(rig::DeviceLock({claims.back()}));
  const std::string holder = fmt::format("is in use by {} (pid {}: ", program_invocation_short_name, ::getpid());

  // A markerd that took no lock would run until stopped: the time limit ends it.
  const Outcome refused = test_support::run_program({MARKERD_PATH, "--config", config().string()}, {}, 60s);
  EXPECT_FALSE(refused.timed_out) << "markerd started on a rig another process holds";
  EXPECT_EQ(refused.code, 1) << refused.describe();
  EXPECT_NE(refused.err.find("cannot start: " + claims.back().what + " " + holder), std::string::npos)
      << refused.describe();
  EXPECT_FALSE(fs::exists(dir_ / "control.sock"));
  EXPECT_EQ(rail_.state(1).requests, 0U) << "markerd spoke to the rail's drive";
  EXPECT_EQ(turntable_.state(1).requests, 0U) << "markerd spoke to the turntable's drive";

  // In-process the refusal is the DeviceLockError Daemon's constructor documents.
  EXPECT_THROW(const daemon::Daemon in_process(daemon::load_daemon_config(config())), rig::DeviceLockError);

  // Once the holder lets go, the same markerd starts.
  held.reset();
  test_support::ChildProcess markerd;
  ASSERT_NO_THROW(start_markerd(markerd)) << test_support::read_file(output());
  EXPECT_GT(rail_.state(1).requests, 0U);
  const std::optional<int> stopped = markerd.terminate(30s);
  ASSERT_TRUE(stopped.has_value()) << "markerd did not stop on SIGTERM";
  EXPECT_EQ(test_support::exit_code(*stopped), 0) << test_support::read_file(output());
}

}  // namespace
}  // namespace markerd
