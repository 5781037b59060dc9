// The device lock: which devices each kind of rig claims, all-or-none
// locking, the holder named in a refusal, and the kernel releasing the lock
// of a process that ended.

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "markerd/rig/device_lock.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

using namespace markerd::rig;
namespace fs = std::filesystem;

namespace {

const fs::path kSourceDir = MARKERD_SOURCE_DIR;

using markerd::test_support::read_file;

std::string refusal(const std::vector<DeviceClaim>& claims, const fs::path& dir) {
  try {
    DeviceLock lock(claims, dir);
  } catch (const DeviceLockError& e) {
    return e.what();
  }
  return "(not refused)";
}

DeviceClaim claim(std::string kind, std::string device, std::string what) {
  return DeviceClaim{std::move(kind), std::move(device), std::move(what)};
}

}  // namespace

TEST(DeviceClaims, OnePerDeviceOfEachShippedRig) {
  const auto sim = device_claims(load_rig_config(kSourceDir / "config/rig-sim.toml"));
  ASSERT_EQ(sim.size(), 1u);
  const std::string sim_path = fs::weakly_canonical(kSourceDir / "config/rig-sim.toml").string();
  EXPECT_EQ(sim[0].kind, "sim");
  EXPECT_EQ(sim[0].device, sim_path);
  EXPECT_EQ(sim[0].what, "rail's and turntable's simulated rig " + sim_path);

  const auto gpio = device_claims(load_rig_config(kSourceDir / "config/rig-gpio.toml"));
  ASSERT_EQ(gpio.size(), 1u);
  EXPECT_EQ(gpio[0].kind, "gpio");
  EXPECT_EQ(gpio[0].device, "/dev/gpiochip0");
  EXPECT_EQ(gpio[0].what, "rail's and turntable's GPIO chip gpiochip0");

  const auto rtu = device_claims(load_rig_config(kSourceDir / "config/rig-modbus-rtu.toml"));
  ASSERT_EQ(rtu.size(), 1u);
  EXPECT_EQ(rtu[0].kind, "serial");
  EXPECT_EQ(rtu[0].what, "rail's and turntable's /dev/ttyUSB0");

  const auto tcp = device_claims(load_rig_config(kSourceDir / "config/rig-modbus-tcp.toml"));
  ASSERT_EQ(tcp.size(), 2u);
  EXPECT_EQ(tcp[0].device, "192.168.10.21:502");
  EXPECT_EQ(tcp[0].what, "rail's Modbus TCP 192.168.10.21:502");
  EXPECT_EQ(tcp[1].what, "turntable's Modbus TCP 192.168.10.22:502");
}

TEST(DeviceClaims, TwoNamesOfOneSerialDeviceLockOneFile) {
  markerd::test_support::TempDir dir;
  const fs::path device = dir.path() / "ttyUSB7";
  std::ofstream(device) << "";
  const fs::path by_id = dir.path() / "usb-FTDI_FT232R-if00-port0";
  fs::create_symlink(device, by_id);
  const std::string map = (kSourceDir / "config/drives/generic.toml").string();
  markerd::test_support::TomlConfig::load(kSourceDir / "config/rig-modbus-rtu.toml")
      .set("rig.buses.rtu0.device", by_id.string())
      .set("rig.rail.modbus.map", map)
      .set("rig.turntable.modbus.map", map)
      .write(dir.path() / "rig.toml");
  const auto claims = device_claims(load_rig_config(dir.path() / "rig.toml"));
  ASSERT_EQ(claims.size(), 1u);
  EXPECT_EQ(claims[0].device, fs::weakly_canonical(device).string());
  EXPECT_EQ(claims[0].what, "rail's and turntable's " + by_id.string());
  const auto named = DeviceLock::file_for(claim("serial", fs::weakly_canonical(device).string(), ""), dir.path());
  EXPECT_EQ(DeviceLock::file_for(claims[0], dir.path()), named);
  EXPECT_EQ(DeviceLock::file_for(claim("serial", "/dev/ttyUSB0", ""), "/locks"),
            fs::path("/locks/serial-dev_ttyUSB0.lock"));
  EXPECT_EQ(DeviceLock::file_for(claim("tcp", "[::1]:502", ""), "/locks"), fs::path("/locks/tcp-1__502.lock"));
}

TEST(DeviceLock, CreatesItsDirectoryAndRecordsTheHolder) {
  markerd::test_support::TempDir dir;
  const fs::path locks = dir.path() / "run" / "markerd";
  DeviceLock lock({claim("gpio", "/dev/gpiochip0", "rail's GPIO chip gpiochip0")}, locks);
  EXPECT_EQ((fs::status(locks).permissions() & fs::perms::all), fs::perms::all);
  ASSERT_EQ(lock.files().size(), 1u);
  EXPECT_EQ(lock.files()[0], locks / "gpio-dev_gpiochip0.lock");
  const std::string record = read_file(lock.files()[0]);
  EXPECT_EQ(record.rfind(std::to_string(::getpid()) + "\n", 0), 0u) << record;
  EXPECT_NE(record.find("test_device_lock"), std::string::npos) << record;
}

TEST(DeviceLock, TheDirectoryComesFromTheEnvironment) {
  const char* saved = std::getenv("MARKERD_LOCK_DIR");
  const std::string restore = saved != nullptr ? saved : "";
  ::setenv("MARKERD_LOCK_DIR", "/tmp/elsewhere", 1);
  EXPECT_EQ(DeviceLock::default_directory(), fs::path("/tmp/elsewhere"));
  ::unsetenv("MARKERD_LOCK_DIR");
  EXPECT_EQ(DeviceLock::default_directory(), fs::path("/run/lock/markerd"));
  if (saved != nullptr) ::setenv("MARKERD_LOCK_DIR", restore.c_str(), 1);
}

TEST(DeviceLock, AllOrNoneAndTheRefusalNamesTheHolder) {
  markerd::test_support::TempDir dir;
  const DeviceClaim chip = claim("gpio", "/dev/gpiochip0", "rail's GPIO chip gpiochip0");
  const DeviceClaim serial = claim("serial", "/dev/ttyUSB0", "turntable's /dev/ttyUSB0");
  auto held = std::make_unique<DeviceLock>(std::vector<DeviceClaim>{serial}, dir.path());

  // gpio-... sorts before serial-...: the chip is taken first, then released
  // when the serial device is refused.
  const std::string error = refusal({serial, chip}, dir.path());
  const std::string expected =
      "turntable's /dev/ttyUSB0 is in use by test_device_lock (pid " + std::to_string(::getpid()) + ": ";
  EXPECT_EQ(error.rfind(expected, 0), 0u) << error;
  EXPECT_NE(error.find("(lock file " + (dir.path() / "serial-dev_ttyUSB0.lock").string() + ")"), std::string::npos)
      << error;
  EXPECT_NO_THROW(DeviceLock({chip}, dir.path())) << "the chip stayed locked after the refusal";

  // Released with its holder, and emptied of its record.
  held.reset();
  EXPECT_EQ(read_file(dir.path() / "serial-dev_ttyUSB0.lock"), "");
  DeviceLock both({serial, chip}, dir.path());
  EXPECT_EQ(both.files().size(), 2u);
  // Moving a lock keeps it held.
  DeviceLock moved = std::move(both);
  EXPECT_EQ(moved.files().size(), 2u);
  EXPECT_NE(refusal({chip}, dir.path()), "(not refused)");
}

TEST(DeviceLock, AnotherProcessIsRefusedUntilTheHolderEnds) {
  markerd::test_support::TempDir dir;
  const DeviceClaim sim = claim("sim", "/etc/rig.toml", "rail's simulated rig /etc/rig.toml");
  int locked[2], release[2];
  ASSERT_EQ(::pipe(locked), 0);
  ASSERT_EQ(::pipe(release), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(locked[0]);
    ::close(release[1]);
    int code = 0;
    try {
      DeviceLock lock({sim}, dir.path());
      const char ready = 'x';
      if (::write(locked[1], &ready, 1) != 1) code = 2;
      char ignored = 0;
      while (::read(release[0], &ignored, 1) > 0) {
      }
    } catch (...) {
      code = 1;
    }
    ::_exit(code);
  }
  ::close(locked[1]);
  ::close(release[0]);
  char ready = 0;
  ASSERT_EQ(::read(locked[0], &ready, 1), 1) << "the child did not take the lock";
  const std::string error = refusal({sim}, dir.path());
  EXPECT_EQ(
      error.rfind(
          "rail's simulated rig /etc/rig.toml is in use by test_device_lock (pid " + std::to_string(child) + ": ", 0),
      0u)
      << error;
  ::close(release[1]);  // the child ends
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  ::close(locked[0]);
  EXPECT_NO_THROW(DeviceLock({sim}, dir.path()));
}
