// markerctl rig end to end: each test runs the real binary (MARKERCTL_PATH)
// on a simulated rig in scaled time, or on a Modbus TCP rig whose drives are
// simulated drive servers in this process, with the device locks in a
// directory of the test's own (MARKERD_LOCK_DIR), and checks what it printed
// and exited with. Children are always killed and reaped, even when a test
// fails.

#include <fcntl.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "modbus/peers.hpp"
#include "support/files.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/tmux.hpp"
#include "support/toml_config.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using namespace std::chrono_literals;

namespace {

const fs::path kSourceDir = MARKERD_SOURCE_DIR;

using markerd::test_support::CapturedProcess;
using markerd::test_support::exit_code;
using markerd::test_support::Outcome;
using markerd::test_support::read_file;

// markerctl with `args`, started, its device locks in `lock_dir`.
std::unique_ptr<CapturedProcess> start_markerctl(const std::vector<std::string>& args, const fs::path& lock_dir) {
  std::vector<std::string> argv{MARKERCTL_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  return std::make_unique<CapturedProcess>(
      argv, markerd::test_support::ProcessOptions{{"MARKERD_LOCK_DIR=" + lock_dir.string()}, std::nullopt});
}

class MarkerctlRig : public ::testing::Test {
 protected:
  [[nodiscard]] fs::path dir() const { return temp_.path(); }
  [[nodiscard]] fs::path lock_dir() const { return temp_.path() / "locks"; }

  Outcome run(const std::vector<std::string>& args) {
    Outcome outcome = start_markerctl(args, lock_dir())->wait();
    if (outcome.timed_out) ADD_FAILURE() << "markerctl did not finish: " << outcome.describe();
    return outcome;
  }

  // config/rig-sim.toml at `time_scale` simulated seconds per real second.
  std::string sim_config(double time_scale) {
    return markerd::test_support::write_sim_rig_config(dir() / fmt::format("rig-sim-x{}.toml", time_scale), time_scale)
        .string();
  }

  const markerd::test_support::TempDir temp_{"markerd-markerctl-rig"};
};

// "rail: at 250.000 mm" -> 250
std::optional<double> reported(const std::string& out, const std::string& what) {
  std::smatch m;
  if (!std::regex_search(out, m, std::regex(what + " (-?[0-9]+\\.[0-9]+)"))) return std::nullopt;
  return std::stod(m[1]);
}

}  // namespace

TEST_F(MarkerctlRig, StatusShowsEachAxisAndTheGroundTruth) {
  const std::string config = sim_config(50);
  const Outcome text = run({"rig", "--config", config, "status"});
  ASSERT_EQ(text.code, 0) << text.describe();
  EXPECT_NE(text.out.find("rail       disabled, not homed: position 0.000 mm, target 0.000 mm; inputs: none active"),
            std::string::npos)
      << text.out;
  EXPECT_NE(text.out.find("turntable  disabled, not homed: position 0.000 deg"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("ground truth: distance 0.3000 m, yaw 0.000 deg"), std::string::npos) << text.out;

  const Outcome j = run({"rig", "status", "--json", "--config", config});
  ASSERT_EQ(j.code, 0) << j.describe();
  const json status = json::parse(j.out);
  EXPECT_EQ(status["rail"]["state"], "disabled");
  EXPECT_EQ(status["rail"]["homed"], false);
  EXPECT_EQ(status["rail"]["unit"], "mm");
  EXPECT_EQ(status["turntable"]["unit"], "deg");
  EXPECT_EQ(status["turntable"]["inputs"]["estop"], false);
  EXPECT_TRUE(status["rail"]["fault"].is_null());
  EXPECT_DOUBLE_EQ(status["ground_truth"]["distance_m"].get<double>(), 0.3);
  EXPECT_DOUBLE_EQ(status["ground_truth"]["tvec"][2].get<double>(), 0.3);
}

TEST_F(MarkerctlRig, HomeHomesTheRailThenTheTurntable) {
  const std::string config = sim_config(50);
  const Outcome both = run({"rig", "--config", config, "home"});
  ASSERT_EQ(both.code, 0) << both.describe();
  const auto rail_at = both.out.find("rail: homing");
  const auto turntable_at = both.out.find("turntable: homing");
  ASSERT_NE(rail_at, std::string::npos) << both.out;
  ASSERT_NE(turntable_at, std::string::npos) << both.out;
  EXPECT_LT(rail_at, turntable_at) << "the rail homes first";
  // The rail homes on limit_min at -3 mm (home_offset), the turntable on its
  // home flag at 0 deg.
  EXPECT_NEAR(reported(both.out, "rail: homed at").value_or(1e9), -3.0, 0.1) << both.out;
  EXPECT_NEAR(reported(both.out, "turntable: homed at").value_or(1e9), 0.0, 0.05) << both.out;

  const Outcome one = run({"rig", "--config", config, "home", "--axis", "turntable"});
  ASSERT_EQ(one.code, 0) << one.describe();
  EXPECT_EQ(one.out.find("rail:"), std::string::npos) << one.out;
  EXPECT_NE(one.out.find("turntable: homed at"), std::string::npos) << one.out;

  EXPECT_EQ(run({"rig", "--config", config, "home", "--axis", "camera"}).code, 2);
}

TEST_F(MarkerctlRig, ValuesNeedTheirUnits) {
  const std::string config = sim_config(50);
  struct Case {
    std::vector<std::string> args;
    std::string error;
  };
  const Case cases[] = {
      {{"move", "--rail", "250"}, "markerctl: --rail: '250' needs a unit: mm, cm or m (examples: 250mm, 25cm, 0.25m)"},
      {{"move", "--turntable", "30mm"},
       "markerctl: --turntable: '30mm': unknown unit 'mm' for the turntable (use deg or rad)"},
      {{"move", "--rail", "30deg"}, "markerctl: --rail: '30deg': unknown unit 'deg' for the rail (use mm, cm or m)"},
      {{"jog", "--turntable", "2"}, "markerctl: --turntable: '2' needs a unit: deg or rad"},
      {{"move", "--rail", "far"}, "markerctl: --rail: 'far' is not a value with a unit"},
      {{"move"}, "markerctl: rig move: give --rail, --turntable or both"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args{"rig", "--config", config};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome r = run(args);
    EXPECT_EQ(r.code, 2) << r.describe();
    EXPECT_EQ(r.err.rfind(c.error, 0), 0u) << r.describe();
    EXPECT_EQ(r.out, "");
  }
}

TEST_F(MarkerctlRig, AMoveBeforeHomingIsRefused) {
  const std::string config = sim_config(50);
  const Outcome r = run({"rig", "--config", config, "move", "--rail", "250mm"});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err.rfind("markerctl: rig move: rail is not homed: home it first, or pass --home", 0), 0u)
      << r.describe();
  EXPECT_EQ(r.out, "") << "nothing moved";

  // Outside the soft limits: refused before anything homes.
  const Outcome far = run({"rig", "--config", config, "move", "--home", "--rail", "3m"});
  EXPECT_EQ(far.code, 1) << far.describe();
  EXPECT_EQ(far.err, "markerctl: rig move: rail: move to 3000.000 mm refused: outside the soft limits [0, 2500] mm\n");
  EXPECT_EQ(far.out, "");
}

TEST_F(MarkerctlRig, MoveWithHomeHomesThenMovesBothAxes) {
  const std::string config = sim_config(50);
  const Outcome r = run({"rig", "--config", config, "move", "--home", "--rail", "25cm", "--turntable", "0.5rad"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NE(r.out.find("rail: homed at"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("turntable: homed at"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("rail: at 250.000 mm\n"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("turntable: at 28.650 deg\n"), std::string::npos) << r.out;  // 0.5 rad on 0.01 deg steps
  EXPECT_NE(r.out.find("ground truth: distance 0.5500 m, yaw 28.650 deg"), std::string::npos) << r.out;

  // Relative, from where homing left the axes (rail -3 mm, turntable 0 deg).
  const Outcome jog = run({"rig", "--config", config, "jog", "--home", "--rail", "+5mm", "--turntable", "-2deg"});
  ASSERT_EQ(jog.code, 0) << jog.describe();
  EXPECT_NEAR(reported(jog.out, "rail: at").value_or(1e9), 2.0, 0.1) << jog.out;
  EXPECT_NEAR(reported(jog.out, "turntable: at").value_or(1e9), -2.0, 0.02) << jog.out;
}

// --json: standard output is one JSON line, the rig as status --json shows
// it once the command is done; the lines in words go to standard error.
TEST_F(MarkerctlRig, HomeMoveAndJogWithJsonPrintTheRigOnceDone) {
  const std::string config = sim_config(50);
  Outcome r = run({"rig", "--config", config, "home", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  json j = json::parse(r.out);  // throws on anything but one JSON document
  EXPECT_EQ(j["config"], config);
  EXPECT_EQ(j["rail"]["homed"], true);
  EXPECT_EQ(j["turntable"]["homed"], true);
  EXPECT_NEAR(j["rail"]["position"].get<double>(), -3.0, 0.1);
  EXPECT_NE(r.err.find("rail: homing\n"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("ground truth: distance "), std::string::npos) << r.err;

  r = run({"rig", "--config", config, "move", "--home", "--rail", "25cm", "--turntable", "30deg", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  j = json::parse(r.out);
  EXPECT_NEAR(j["rail"]["position"].get<double>(), 250.0, 1e-6);
  EXPECT_EQ(j["rail"]["settled"], true);
  EXPECT_NEAR(j["ground_truth"]["yaw_deg"].get<double>(), 30.0, 1e-6);
  EXPECT_NE(r.err.find("rail: at 250.000 mm\n"), std::string::npos) << r.err;

  r = run({"rig", "--config", config, "jog", "--home", "--turntable", "-2deg", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  j = json::parse(r.out);
  EXPECT_NEAR(j["turntable"]["position"].get<double>(), -2.0, 0.02);

  // A refusal is an error, as without --json: nothing on standard output.
  r = run({"rig", "--config", config, "move", "--rail", "25cm", "--json"});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.out, "");
}

// markerd's config where a rig config belongs: the error says what it is,
// where its rig is, and what to pass.
TEST_F(MarkerctlRig, MarkerdsConfigIsNamedWithTheRigFileToPass) {
  const std::string markerd_sim = (kSourceDir / "config/markerd-sim.toml").string();
  const std::string rig_sim = (kSourceDir / "config/rig-sim.toml").string();
  Outcome r = run({"rig", "--config", markerd_sim, "status"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: rig status: " + markerd_sim + " is markerd's config, not a rig config: its rig is in " +
                       rig_sim + " (line 5: rig = \"rig-sim.toml\"); pass --config " + rig_sim +
                       ", or leave out --config to move the rig of the markerd that runs\n");
  EXPECT_EQ(r.out, "");
  // The rig it names is what to pass, and works.
  const std::string config = sim_config(50);
  EXPECT_EQ(run({"rig", "--config", config, "status"}).code, 0);

  // A markerd config without a rig.
  const fs::path no_rig = dir() / "markerd.toml";
  {
    std::ofstream out(no_rig);
    out << "[camera]\nsource = \"sim\"\n";
  }
  r = run({"rig", "--config", no_rig.string(), "home"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: rig home: " + no_rig.string() +
                       " is markerd's config, not a rig config, and it names no rig (no [rig] tables, no rig = FILE): "
                       "pass a rig config (config/rig-sim.toml and the other config/rig-*.toml are examples), or "
                       "leave out --config to move the rig of the markerd that runs\n");
}

TEST_F(MarkerctlRig, ASecondProcessIsRefusedWhileTheFirstHoldsTheRig) {
  // Real time: the homing alone takes about 50 s, far longer than the test needs.
  const std::string config = sim_config(1);
  const auto first = start_markerctl({"rig", "--config", config, "move", "--home", "--rail", "2400mm"}, lock_dir());
  // The first holds the lock once its record is in the lock file.
  const fs::path lock_file =
      markerd::rig::DeviceLock::file_for({"sim", fs::weakly_canonical(config).string(), ""}, lock_dir());
  std::string record;
  ASSERT_TRUE(markerd::test_support::wait_for(
      [&] {
        record = read_file(lock_file);
        return record.rfind(std::to_string(first->pid()) + "\n", 0) == 0;
      },
      30s))
      << lock_file << ": " << record;
  ASSERT_TRUE(
      markerd::test_support::wait_for([&] { return first->out().find("rail: homing") != std::string::npos; }, 30s));

  const Outcome second = run({"rig", "--config", config, "status"});
  EXPECT_EQ(second.code, 1) << second.describe();
  EXPECT_NE(second.err.find("is in use by markerctl (pid " + std::to_string(first->pid()) + ": "), std::string::npos)
      << second.describe();
  EXPECT_EQ(second.err.rfind("markerctl: rig status: rail's and turntable's simulated rig ", 0), 0u)
      << second.describe();

  // SIGINT: a controlled stop, the axes disabled, a non-zero exit.
  ASSERT_EQ(::kill(first->pid(), SIGINT), 0);
  const Outcome interrupted = first->wait();
  EXPECT_EQ(interrupted.code, 1) << interrupted.describe();
  EXPECT_NE(interrupted.err.find("markerctl: rig move: interrupted by SIGINT: stopped, axes disabled (rail at "),
            std::string::npos)
      << interrupted.describe();
  // The lock went with it.
  const Outcome third = run({"rig", "--config", config, "status"});
  EXPECT_EQ(third.code, 0) << third.describe();
}

TEST_F(MarkerctlRig, AModbusTcpRigMovesBothAxes) {
  const auto clock = std::make_shared<markerd::rig::SimClock>(20.0);
  const auto unit = [](double start_steps) {
    markerd::rig::ModbusSimUnit u;
    u.unit_id = 1;
    u.map = markerd::rig::load_register_map(kSourceDir / "config/drives/generic.toml");
    u.start_position_steps = start_steps;
    return u;
  };
  markerd::rig::ModbusDriveSim rail({unit(20000)}, markerd::rig::ModbusSimTcp{}, clock);
  markerd::rig::ModbusDriveSim turntable({unit(500)}, markerd::rig::ModbusSimTcp{}, clock);
  rail.start();
  turntable.start();
  const std::string config =
      markerd::test_support::write_modbus_tcp_rig_config(dir() / "rig-modbus-tcp.toml", rail.port(), turntable.port())
          .string();

  const Outcome r = run({"rig", "--config", config, "move", "--home", "--rail", "100mm", "--turntable", "10deg"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NEAR(reported(r.out, "rail: at").value_or(1e9), 100.0, 0.05) << r.out;
  EXPECT_NEAR(reported(r.out, "turntable: at").value_or(1e9), 10.0, 0.05) << r.out;
  EXPECT_EQ(rail.state(1).target_steps, 10000);
  EXPECT_EQ(turntable.state(1).target_steps, 278);  // 10 deg at 0.036 deg per step
  EXPECT_FALSE(rail.state(1).enabled) << "the axes end disabled";
  EXPECT_FALSE(turntable.state(1).enabled);

  // A drive that keeps its reference (closed loop) stays homed for the next
  // process: no --home needed.
  const Outcome again = run({"rig", "--config", config, "move", "--rail", "150mm"});
  ASSERT_EQ(again.code, 0) << again.describe();
  EXPECT_EQ(again.out.find("homing"), std::string::npos) << again.out;
  EXPECT_NEAR(reported(again.out, "rail: at").value_or(1e9), 150.0, 0.05) << again.out;
  EXPECT_EQ(rail.state(1).homings, 1);
}

// ---------------------------------------------------------------- interactive jog

namespace {

// markerctl on a pseudo-terminal: the test types keys into it and reads the screen.
class OnTerminal {
 public:
  OnTerminal(const std::vector<std::string>& args, const fs::path& lock_dir) {
    // Wide enough for the whole status line: these tests type keys and read
    // what they did (the line fitted to 80 columns is a test of its own).
    winsize size{};
    size.ws_col = 200;
    size.ws_row = 50;
    if (::openpty(&master_, &slave_, nullptr, nullptr, &size) != 0) throw std::runtime_error("openpty failed");
    ::tcgetattr(slave_, &before_);
    std::vector<std::string> argv{MARKERCTL_PATH};
    argv.insert(argv.end(), args.begin(), args.end());
    const std::string lock_env = "MARKERD_LOCK_DIR=" + lock_dir.string();
    pid_ = ::fork();
    if (pid_ == 0) {
      ::setsid();
      ::ioctl(slave_, TIOCSCTTY, 0);
      ::dup2(slave_, 0);
      ::dup2(slave_, 1);
      ::dup2(slave_, 2);
      ::close(master_);
      ::putenv(const_cast<char*>(lock_env.c_str()));
      std::vector<char*> raw;
      for (auto& a : argv) raw.push_back(a.data());
      raw.push_back(nullptr);
      ::execv(raw[0], raw.data());
      ::_exit(127);
    }
  }
  ~OnTerminal() {
    if (pid_ > 0 && !status_) {
      ::kill(pid_, SIGKILL);
      int ignored = 0;
      ::waitpid(pid_, &ignored, 0);
    }
    ::close(master_);
    ::close(slave_);
  }
  OnTerminal(const OnTerminal&) = delete;
  OnTerminal& operator=(const OnTerminal&) = delete;

  [[nodiscard]] pid_t pid() const { return pid_; }
  void type(const std::string& keys) {
    ASSERT_EQ(::write(master_, keys.data(), keys.size()), static_cast<ssize_t>(keys.size()));
  }

  // Reads the screen until `text` appears after `from` (true) or the time is up.
  bool wait_for(const std::string& text, std::chrono::seconds timeout = 30s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (screen_.find(text, seen_) == std::string::npos) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      read_some(50ms);
    }
    seen_ = screen_.find(text, seen_) + text.size();
    return true;
  }

  int wait_exit() {
    int status = 0;
    while (::waitpid(pid_, &status, WNOHANG) == 0) read_some(20ms);
    status_ = status;
    read_some(0ms);
    return exit_code(status);
  }

  [[nodiscard]] const std::string& screen() const { return screen_; }
  // The terminal's mode now, as the process left it, against before it ran.
  [[nodiscard]] bool mode_restored() const {
    termios now{};
    ::tcgetattr(slave_, &now);
    return now.c_lflag == before_.c_lflag && now.c_iflag == before_.c_iflag && now.c_oflag == before_.c_oflag;
  }

 private:
  void read_some(std::chrono::milliseconds timeout) {
    pollfd fd{master_, POLLIN, 0};
    if (::poll(&fd, 1, static_cast<int>(timeout.count())) <= 0) return;
    char buffer[4096];
    const ssize_t n = ::read(master_, buffer, sizeof buffer);
    if (n > 0) screen_.append(buffer, static_cast<std::size_t>(n));
  }

  int master_ = -1, slave_ = -1;
  termios before_{};
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::string screen_;
  std::size_t seen_ = 0;
};

}  // namespace

TEST_F(MarkerctlRig, InteractiveJogOnATerminal) {
  const std::string config = sim_config(50);
  {
    OnTerminal jog({"rig", "--config", config, "jog"}, lock_dir());
    ASSERT_TRUE(jog.wait_for("q quits")) << jog.screen();
    ASSERT_TRUE(jog.wait_for("step 5 mm, 1 deg")) << jog.screen();
    jog.type("\x1b[C");  // not homed yet: refused
    ASSERT_TRUE(jog.wait_for("rail is not homed: press h to home")) << jog.screen();
    jog.type("h");
    ASSERT_TRUE(jog.wait_for("turntable: homed at")) << jog.screen();
    jog.type("\x1b[C\x1b[C");  // rail +5 mm, twice: from -3.025 to 6.975 mm
    ASSERT_TRUE(jog.wait_for("rail 6.975 mm idle (homed)")) << jog.screen();
    jog.type("-\x1b[B");  // a smaller step (1 mm, 0.5 deg), turntable down
    ASSERT_TRUE(jog.wait_for("turntable -0.500 deg idle (homed, home active)")) << jog.screen();
    jog.type("q");
    EXPECT_EQ(jog.wait_exit(), 0) << jog.screen();
    EXPECT_TRUE(jog.mode_restored()) << "the terminal was left in raw mode";
    EXPECT_NE(jog.screen().find("rail at 6.975 mm, turntable at -0.500 deg"), std::string::npos) << jog.screen();
  }
  {
    // A signal in the middle: the terminal is restored all the same.
    OnTerminal jog({"rig", "--config", config, "jog"}, lock_dir());
    ASSERT_TRUE(jog.wait_for("step 5 mm, 1 deg")) << jog.screen();
    ASSERT_EQ(::kill(jog.pid(), SIGTERM), 0);
    EXPECT_EQ(jog.wait_exit(), 1) << jog.screen();
    EXPECT_TRUE(jog.mode_restored()) << "the terminal was left in raw mode";
    EXPECT_NE(jog.screen().find("interrupted by SIGTERM"), std::string::npos) << jog.screen();
  }
}

// ---------------------------------------------------------------- live lines at 80 columns

namespace {

// Characters, not bytes: what a line takes on the terminal.
std::size_t columns_of(const std::string& line) {
  std::size_t n = 0;
  for (const char c : line) n += (static_cast<unsigned char>(c) & 0xc0) != 0x80 ? 1 : 0;
  return n;
}

// The screen as the user sees it: no line wider than the terminal (tmux joins
// what it wrapped), and the live line, the rows containing `live`, at most
// `most` times (a redraw that wrapped would leave a stale copy each time).
void expect_one_screen(const markerd::test_support::TmuxScreen& screen, const std::string& live, int most) {
  const auto lines = screen.lines();
  int live_rows = 0;
  for (const std::string& line : lines) {
    EXPECT_LE(columns_of(line), 80u) << "a line wider than the terminal:\n" << line << "\nscreen:\n" << screen.text();
    if (line.find(live) != std::string::npos) ++live_rows;
  }
  EXPECT_LE(live_rows, most) << "stale copies of the live line '" << live << "':\n" << screen.text();
}

}  // namespace

// The interactive jog's status line on an 80-column terminal: it is wider
// than that, so it is laid out to fit, and every redraw replaces it.
TEST_F(MarkerctlRig, InteractiveJogFitsAnEightyColumnTerminal) {
  const std::string config = sim_config(50);
  markerd::test_support::TmuxScreen screen({MARKERCTL_PATH, "rig", "--config", config, "jog"},
                                           {"MARKERD_LOCK_DIR=" + lock_dir().string()}, 80, 24, dir());
  ASSERT_TRUE(screen.wait_for("| turntable")) << screen.text();
  screen.send_keys({"h"});
  ASSERT_TRUE(screen.wait_for("turntable: homed at")) << screen.text();
  // Moves, step changes and redraws: the line changes many times.
  screen.send_keys({"Right", "Right", "+", "Up", "Right", "-", "Down"});
  ASSERT_TRUE(screen.wait_for("step 5 mm, 1 deg")) << screen.text();
  // Rail -3.025 + 5 + 5 + 10 mm, turntable 0 + 5 - 1 deg.
  ASSERT_TRUE(screen.wait_for("rail 16.975 mm idle (homed) | turntable 4.000 deg idle (homed")) << screen.text();
  expect_one_screen(screen, "| turntable", 1);
  screen.send_keys({"q"});
  ASSERT_TRUE(screen.wait_for("[exit 0]")) << screen.text();
  expect_one_screen(screen, "| turntable", 0);
  EXPECT_NE(screen.text().find("rail at 16.975 mm, turntable at 4.000 deg"), std::string::npos) << screen.text();
}

// Homing shows its progress on one line redrawn in place, not a line a
// second, and leaves the lines before and after it.
TEST_F(MarkerctlRig, HomingProgressIsOneLine) {
  // The rail's homing from 1200 mm takes 48 simulated seconds: several
  // seconds here, many redraws.
  const std::string config = sim_config(8);
  markerd::test_support::TmuxScreen screen({MARKERCTL_PATH, "rig", "--config", config, "home", "--axis", "rail"},
                                           {"MARKERD_LOCK_DIR=" + lock_dir().string()}, 80, 24, dir());
  ASSERT_TRUE(screen.wait_for("rail: homing, at")) << screen.text();
  // Until it ends, look at the screen as it goes.
  while (screen.text().find("[exit") == std::string::npos) {
    expect_one_screen(screen, "rail: homing, at", 1);
    if (HasFailure()) break;
    std::this_thread::sleep_for(200ms);
  }
  ASSERT_TRUE(screen.wait_for("[exit 0]")) << screen.text();
  expect_one_screen(screen, ", at ", 0);
  const std::string text = screen.text();
  EXPECT_NE(text.find("rail: homing\n"), std::string::npos) << text;
  EXPECT_NE(text.find("rail: homed at"), std::string::npos) << text;
}
