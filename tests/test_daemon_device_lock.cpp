// markerd and the rig's device locks (docs/rig.md, "Device lock"): the real
// markerd on a Modbus TCP rig whose drives are simulated drive servers in
// this process, its locks in a directory of the test's own
// (MARKERD_LOCK_DIR). While markerd runs, every device of its rig is refused
// to any other holder (this process, markerctl rig), naming markerd; while
// another process holds one, markerd waits, naming the device and the
// holder to its log and to systemd, has not spoken to a drive, and starts
// once the device is free (or stops on SIGTERM).

#include <gtest/gtest.h>

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>  // program_invocation_short_name
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "support/child_process.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
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
    test_support::prepare_markerd_dir(dir_);
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

// systemd's notification socket, in a test: the datagrams markerd's
// sd_notify() sends (STATUS=, READY=1, EXTEND_TIMEOUT_USEC=), all of them.
class NotifySocket {
 public:
  explicit NotifySocket(const fs::path& path) : path_(path.string()) {
    fd_.reset(::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0));
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, path_.c_str(), sizeof address.sun_path - 1);
    if (!fd_ || ::bind(fd_.get(), reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
      throw std::runtime_error("notify socket " + path_ + ": " + std::strerror(errno));
    }
  }

  [[nodiscard]] const std::string& path() const { return path_; }

  // True once what has arrived holds `text`; false after `timeout`.
  bool wait_for(const std::string& text, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      char datagram[4096];
      ssize_t n = 0;
      while ((n = ::recv(fd_.get(), datagram, sizeof datagram, MSG_DONTWAIT)) > 0) {
        received_.append(datagram, static_cast<std::size_t>(n));
        received_ += '\n';
      }
      if (received_.find(text) != std::string::npos) return true;
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(20ms);
    }
  }

  [[nodiscard]] const std::string& received() const { return received_; }

 private:
  std::string path_;
  UniqueFd fd_;
  std::string received_;
};

// markerd under "systemd": its notifications to `notify`, its output to output().
void start_notifying(test_support::ChildProcess& markerd, const fs::path& config, const fs::path& output,
                     const NotifySocket& notify) {
  const UniqueFd out = test_support::open_or_throw(output, O_WRONLY | O_CREAT | O_APPEND);
  test_support::ProcessOptions options;
  options.environment = {"NOTIFY_SOCKET=" + notify.path()};
  markerd.start_with({MARKERD_PATH, "--config", config.string()}, out.get(), out.get(), options);
}

// Another process (here this one, as a markerctl rig session would) holds a
// device of markerd's rig: markerd does not exit, which under systemd would
// restart it every RestartSec until its start limit gave up; it waits,
// saying what is held by whom in its log and to systemd (before READY, with
// the start timeout extended), opens nothing, and starts once the device is
// free.
TEST_F(MarkerdDeviceLock, MarkerdWaitsForARigAnotherProcessHoldsAndStartsOnceItIsFree) {
  const std::vector<rig::DeviceClaim> claims = rig::device_claims(rig_config_);
  ASSERT_FALSE(claims.empty());
  // This process holds one of the two drives: markerd must not open the rig,
  // not even the free drive.
  std::optional<rig::DeviceLock> held(rig::DeviceLock({claims.back()}));
  const std::string holder = fmt::format("is in use by {} (pid {}: ", program_invocation_short_name, ::getpid());
  NotifySocket notify(dir_ / "notify.sock");
  test_support::ChildProcess markerd;
  start_notifying(markerd, config(), output(), notify);

  ASSERT_TRUE(notify.wait_for("STATUS=waiting for the rig's devices: " + claims.back().what + " " + holder, 60s))
      << notify.received() << test_support::read_file(output());
  EXPECT_NE(notify.received().find("EXTEND_TIMEOUT_USEC="), std::string::npos) << notify.received();
  // A while later: still waiting, not ready, and nothing opened.
  EXPECT_FALSE(notify.wait_for("READY=1", 2s)) << notify.received();
  EXPECT_FALSE(markerd.exited().has_value()) << test_support::read_file(output());
  EXPECT_FALSE(fs::exists(dir_ / "control.sock"));
  EXPECT_EQ(rail_.state(1).requests, 0U) << "markerd spoke to the rail's drive";
  EXPECT_EQ(turntable_.state(1).requests, 0U) << "markerd spoke to the turntable's drive";
  const std::string waiting = test_support::read_file(output());
  EXPECT_NE(waiting.find(claims.back().what + " " + holder), std::string::npos) << waiting;
  EXPECT_NE(waiting.find("markerd waits until it is free, and starts then (SIGTERM stops it)"), std::string::npos)
      << waiting;

  // In-process the refusal is the DeviceLockError Daemon's constructor
  // documents, saying that the lock is held.
  try {
    const daemon::Daemon in_process(daemon::load_daemon_config(config()));
    ADD_FAILURE() << "a Daemon started on a rig another process holds";
  } catch (const rig::DeviceLockError& e) {
    EXPECT_TRUE(e.held()) << e.what();
  }

  // Once the holder lets go, markerd starts by itself.
  held.reset();
  ASSERT_NO_THROW((void)test_support::connect_control(markerd, dir_ / "control.sock", output(), 60s))
      << test_support::read_file(output());
  EXPECT_TRUE(notify.wait_for("READY=1", 30s)) << notify.received();
  EXPECT_GT(rail_.state(1).requests, 0U);
  EXPECT_NE(test_support::read_file(output()).find("the rig's devices are free after "), std::string::npos);
  const std::optional<int> stopped = markerd.terminate(30s);
  ASSERT_TRUE(stopped.has_value()) << "markerd did not stop on SIGTERM";
  EXPECT_EQ(test_support::exit_code(*stopped), 0) << test_support::read_file(output());
}

// SIGTERM while markerd waits for its rig's devices (systemctl stop): it
// stops at once, exit 0, having started nothing.
TEST_F(MarkerdDeviceLock, SigtermEndsTheWaitForTheRigsDevices) {
  const std::vector<rig::DeviceClaim> claims = rig::device_claims(rig_config_);
  const rig::DeviceLock held({claims.front()});
  NotifySocket notify(dir_ / "notify.sock");
  test_support::ChildProcess markerd;
  start_notifying(markerd, config(), output(), notify);
  ASSERT_TRUE(notify.wait_for("STATUS=waiting for the rig's devices: ", 60s))
      << notify.received() << test_support::read_file(output());
  const std::optional<int> stopped = markerd.terminate(30s);
  ASSERT_TRUE(stopped.has_value()) << "markerd did not stop on SIGTERM while waiting";
  EXPECT_EQ(test_support::exit_code(*stopped), 0) << test_support::read_file(output());
  EXPECT_NE(test_support::read_file(output()).find("SIGTERM: stopping while waiting for the rig's devices"),
            std::string::npos)
      << test_support::read_file(output());
  EXPECT_EQ(notify.received().find("READY=1"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "control.sock"));
  EXPECT_EQ(rail_.state(1).requests, 0U);
}

// markerd --check-config takes the rig's locks and lets go at once: a
// device another process holds is a failed check naming the device and the
// holder with its pid; --no-lock-check (the unit's ExecStartPre, since the
// start waits for the device) leaves that out.
TEST_F(MarkerdDeviceLock, CheckConfigReportsAHeldDeviceNamingItsHolder) {
  const std::vector<rig::DeviceClaim> claims = rig::device_claims(rig_config_);
  std::optional<rig::DeviceLock> held(rig::DeviceLock({claims.back()}));
  const std::string holder = fmt::format("is in use by {} (pid {}: ", program_invocation_short_name, ::getpid());
  Outcome r = test_support::run_program({MARKERD_PATH, "--check-config", "--config", config().string()});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err.rfind("markerd: " + config().string() + ": rig: " + claims.back().what + " " + holder, 0), 0U)
      << r.describe();
  EXPECT_NE(r.err.find("(markerd would wait for it at start)\n"), std::string::npos) << r.describe();
  EXPECT_EQ(r.out, "");

  r = test_support::run_program({MARKERD_PATH, "--check-config", "--no-lock-check", "--config", config().string()});
  EXPECT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out.rfind(config().string() + ": ok (", 0), 0U) << r.describe();

  held.reset();
  r = test_support::run_program({MARKERD_PATH, "--check-config", "--config", config().string()});
  EXPECT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(refusal(claims), "(not refused)") << "the check let go of every lock";
  EXPECT_EQ(rail_.state(1).requests, 0U) << "a check speaks to no drive";

  r = test_support::run_program({MARKERD_PATH, "--no-lock-check", "--config", config().string()});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_NE(r.err.find("--no-lock-check requires --check-config"), std::string::npos) << r.describe();
}

}  // namespace
}  // namespace markerd
