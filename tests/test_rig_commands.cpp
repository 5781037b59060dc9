// The rig's commands on the control socket, on the shipped simulated rig
// (config/rig-sim.toml) in scaled time, through a server in this process:
// status, home, move (absolute and relative), stop and emergency stop,
// enable and disable, the errors of each in the axis's words, and that no
// command waits for the motion it starts. Then the real markerctl's
// `rig ...` without --config against the same server.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/control/control_server.hpp"
#include "markerd/daemon/control/rig_commands.hpp"
#include "markerd/rig/rig_config.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using namespace markerd::daemon;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using markerd::test_support::CapturedProcess;
using markerd::test_support::Outcome;

namespace {

class RigCommands : public testing::Test {
 protected:
  void SetUp() override {
    markerd::rig::RigConfig config = markerd::rig::load_rig_config(MARKERD_SOURCE_DIR "/config/rig-sim.toml");
    // The rail's homing from its start at 1200 mm takes 48 simulated
    // seconds, 2.4 s here. Its moves go at the homing's search velocity,
    // half the shipped speed, so that one across the rail lasts long enough
    // (4 s) for a markerctl started meanwhile, even under a sanitizer, to
    // stop it on its way.
    config.sim.time_scale = 20;
    config.rail.axis.max_velocity = 25;
    rig_ = markerd::rig::make_rig(config);
    // As markerd does before it serves: the axes' supervisors have read
    // their drives once (a status before that holds no position yet).
    const auto deadline = Clock::now() + 10s;
    const auto looked = [](const markerd::rig::Axis& a) { return a.status().updated != Clock::time_point{}; };
    while (!(looked(rig_->rail()) && looked(rig_->turntable())) && Clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
    }
    ControlSettings settings;
    settings.socket_path = dir_ / "control.sock";
    server_ = std::make_unique<ControlServer>(settings);
    register_rig_commands(*server_, *rig_);
    server_->start();
    client_ = std::make_unique<ControlClient>(settings.socket_path);
  }
  void TearDown() override {
    client_.reset();
    server_.reset();
    rig_.reset();
  }

  json call(const json& request) { return client_->call(request); }

  // A command that must succeed.
  json ok(const json& request) {
    const json reply = call(request);
    EXPECT_EQ(reply.value("ok", false), true) << request << " -> " << reply;
    return reply;
  }
  // The error of a command that must fail.
  std::string error(const json& request) {
    const json reply = call(request);
    EXPECT_EQ(reply.value("ok", true), false) << request << " -> " << reply;
    return reply.value("error", std::string());
  }

  json status() { return ok({{"cmd", "rig.status"}}); }

  // The status once `done` holds for it (polled as markerctl would).
  json wait_for(const std::function<bool(const json&)>& done, std::chrono::seconds timeout = 60s) {
    const auto deadline = Clock::now() + timeout;
    json s = status();
    while (!done(s) && Clock::now() < deadline) {
      std::this_thread::sleep_for(10ms);
      s = status();
    }
    EXPECT_TRUE(done(s)) << "timed out; last status: " << s;
    return s;
  }
  json wait_settled() {
    return wait_for([](const json& s) { return s["settled"].get<bool>(); });
  }
  void home_both() {
    ok({{"cmd", "rig.home"}});
    const json s = wait_settled();
    ASSERT_TRUE(s["rail"]["homed"].get<bool>() && s["turntable"]["homed"].get<bool>()) << s;
  }

  const markerd::test_support::TempDir temp_{"markerd-rig-commands"};
  const fs::path dir_ = temp_.path();
  std::unique_ptr<markerd::rig::Rig> rig_;
  std::unique_ptr<ControlServer> server_;
  std::unique_ptr<ControlClient> client_;
};

TEST_F(RigCommands, StatusReportsEachAxisAndTheGroundTruth) {
  const json s = status();
  for (const char* axis : {"rail", "turntable"}) {
    EXPECT_EQ(s[axis]["state"], "disabled") << s;
    EXPECT_EQ(s[axis]["homed"], false);
    EXPECT_EQ(s[axis]["settled"], false);
    EXPECT_EQ(s[axis]["moving"], false);
    EXPECT_TRUE(s[axis]["fault"].is_null());
    EXPECT_EQ(s[axis]["inputs"]["estop"], false);
  }
  EXPECT_EQ(s["rail"]["unit"], "mm");
  EXPECT_EQ(s["turntable"]["unit"], "deg");
  EXPECT_EQ(s["rail"]["min_position"], 0.0);
  EXPECT_EQ(s["rail"]["max_position"], 2500.0);
  // Unhomed, an open-loop drive counts from where it stood at power-on.
  EXPECT_EQ(s["rail"]["position"].get<double>(), 0.0);
  EXPECT_EQ(s["turntable"]["position"].get<double>(), 0.0);
  EXPECT_NEAR(s["ground_truth"]["distance_m"].get<double>(), 0.3, 1e-12);
  EXPECT_NEAR(s["ground_truth"]["yaw_deg"].get<double>(), 0.0, 1e-12);
  EXPECT_EQ(s["ground_truth"]["tvec"].size(), 3U);
  EXPECT_EQ(s["ground_truth"]["quaternion"].size(), 4U);
  EXPECT_GE(s["snapshot"]["sequence"].get<std::uint64_t>(), 1U);
  EXPECT_EQ(error({{"cmd", "rig.status"}, {"axis", "rail"}}), "unknown argument 'axis': rig.status takes none");
}

TEST_F(RigCommands, HomeAndMoveStartTheMotionAndReturnAndStatusFollowsIt) {
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", 250}}),
            "rail: move to 250 mm refused: the axis is not homed; rig.home first");

  auto before = Clock::now();
  json reply = ok({{"cmd", "rig.home"}, {"axis", "both"}});
  EXPECT_LT(Clock::now() - before, 500ms) << "rig.home waited for the homing";
  EXPECT_EQ(reply["homing"], (json{"rail", "turntable"}));
  json s = status();
  EXPECT_EQ(s["rail"]["state"], "homing") << s;
  EXPECT_EQ(s["rail"]["moving"], true);
  EXPECT_EQ(error({{"cmd", "rig.home"}}), "rail: home refused: the axis is busy (homing); wait, or rig.stop first");
  s = wait_settled();
  EXPECT_TRUE(s["rail"]["homed"].get<bool>());
  // The switch latched at home_offset; the slow latch's braking overshoots
  // by less than a step (see test_rig).
  EXPECT_NEAR(s["rail"]["position"].get<double>(), -3.0, 0.05);
  EXPECT_NEAR(s["turntable"]["position"].get<double>(), 0.0, 0.05);

  before = Clock::now();
  reply = ok({{"cmd", "rig.move"}, {"rail", 650}, {"turntable", -30}});
  EXPECT_LT(Clock::now() - before, 500ms) << "rig.move waited for the move";
  EXPECT_EQ(reply["moving"], (json{{"rail", 650.0}, {"turntable", -30.0}}));
  s = status();
  EXPECT_EQ(s["rail"]["state"], "moving") << s;
  EXPECT_EQ(s["rail"]["target"], 650.0);
  EXPECT_EQ(s["settled"], false);
  EXPECT_NE(error({{"cmd", "rig.move"}, {"rail", 700}}).find("rail: move to 700 mm refused: the axis is busy"),
            std::string::npos);
  s = wait_settled();
  EXPECT_DOUBLE_EQ(s["rail"]["position"].get<double>(), 650.0);
  EXPECT_DOUBLE_EQ(s["turntable"]["position"].get<double>(), -30.0);
  EXPECT_NEAR(s["ground_truth"]["distance_m"].get<double>(), 0.95, 1e-12);
  EXPECT_NEAR(s["ground_truth"]["yaw_deg"].get<double>(), -30.0, 1e-12);

  // Relative: from where the axis stands.
  reply = ok({{"cmd", "rig.move"}, {"rail", -50}, {"turntable", 12.5}, {"relative", true}});
  EXPECT_EQ(reply["moving"], (json{{"rail", 600.0}, {"turntable", -17.5}}));
  s = wait_settled();
  EXPECT_DOUBLE_EQ(s["rail"]["position"].get<double>(), 600.0);
  EXPECT_DOUBLE_EQ(s["turntable"]["position"].get<double>(), -17.5);

  // The rig's snapshot, which the capture stamps frames with, agrees.
  const auto snapshot = rig_->snapshot();
  EXPECT_DOUBLE_EQ(snapshot.rail.position, 600.0);
  EXPECT_DOUBLE_EQ(snapshot.turntable.position, -17.5);
}

TEST_F(RigCommands, RefusedMovesNameTheAxisAndTheReasonAndMoveNothing) {
  home_both();
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", 3000}}),
            "rail: move to 3000 mm refused: outside the soft limits [0, 2500] mm");
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", 500}, {"turntable", 120}}),
            "turntable: move to 120 deg refused: outside the soft limits [-90, 90] deg");
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"turntable", -100}, {"relative", true}}),
            "turntable: move by -100 deg (to -100 deg) refused: outside the soft limits [-90, 90] deg")
      << "turntable homed at 0";
  const json s = status();
  EXPECT_EQ(s["rail"]["state"], "idle") << "a refused move of both axes moved the rail: " << s;
  EXPECT_NEAR(s["rail"]["target"].get<double>(), -3.0, 0.05);

  EXPECT_EQ(error({{"cmd", "rig.move"}, {"camera", 5}}),
            "unknown argument 'camera' (for rig.move: rail, turntable, relative)");
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", "250mm"}}),
            R"(argument 'rail' must be a number, got a string ("250mm"))");
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", 250}, {"relative", 1}}),
            "argument 'relative' must be true or false, got a number (1)");
  EXPECT_EQ(error({{"cmd", "rig.move"}}),
            "rig.move needs a target: rail, turntable or both (numbers in the axes' units)");
  EXPECT_EQ(error({{"cmd", "rig.home"}, {"axis", "camera"}}),
            "argument 'axis' must be rail, turntable or both, got 'camera'");
  EXPECT_EQ(error({{"cmd", "rig.home"}, {"axis", 1}}),
            "argument 'axis' must be rail, turntable or both, got a number (1)");
  EXPECT_EQ(error({{"cmd", "rig.stop"}, {"emergency", "yes"}}),
            R"(argument 'emergency' must be true or false, got a string ("yes"))");
  EXPECT_EQ(error({{"cmd", "rig.status"}, {"verbose", true}}), "unknown argument 'verbose': rig.status takes none");
  EXPECT_EQ(error({{"cmd", "rig.enable"}, {"axis", "camera"}}),
            "argument 'axis' must be rail, turntable or both, got 'camera'");
}

TEST_F(RigCommands, StopRampsDownAndAnEmergencyStopFaultsUntilHomed) {
  home_both();
  EXPECT_EQ(ok({{"cmd", "rig.stop"}})["stopping"], json::array()) << "nothing was moving";

  ok({{"cmd", "rig.move"}, {"rail", 2400}});
  wait_for([](const json& s) { return s["rail"]["position"].get<double>() > 100; });
  const json reply = ok({{"cmd", "rig.stop"}});
  EXPECT_EQ(reply["stopping"], (json{"rail"}));
  EXPECT_EQ(reply["emergency"], false);
  json s = wait_for([](const json& st) { return !st["rail"]["moving"].get<bool>(); });
  EXPECT_EQ(s["rail"]["state"], "idle") << s;
  EXPECT_TRUE(s["rail"]["homed"].get<bool>()) << "a controlled stop keeps the reference";
  EXPECT_LT(s["rail"]["position"].get<double>(), 2300.0) << "the rail went on to its target";
  EXPECT_GT(s["rail"]["position"].get<double>(), 100.0);
  // It moves again from there.
  ok({{"cmd", "rig.move"}, {"rail", 500}});
  s = wait_settled();
  EXPECT_DOUBLE_EQ(s["rail"]["position"].get<double>(), 500.0);

  ok({{"cmd", "rig.move"}, {"rail", 2000}, {"turntable", 60}});
  EXPECT_EQ(ok({{"cmd", "rig.stop"}, {"emergency", true}})["emergency"], true);
  s = status();
  for (const char* axis : {"rail", "turntable"}) {
    EXPECT_EQ(s[axis]["state"], "fault") << s;
    EXPECT_EQ(s[axis]["fault"], "emergency stop");
  }
  EXPECT_EQ(error({{"cmd", "rig.move"}, {"rail", 600}}),
            "rail: move to 600 mm refused: the axis is in fault (emergency stop); rig.home clears the fault");
  // Homing clears the fault and brings the reference back.
  ok({{"cmd", "rig.home"}});
  s = wait_settled();
  EXPECT_TRUE(s["rail"]["fault"].is_null()) << s;
  EXPECT_TRUE(s["rail"]["homed"].get<bool>());
  ok({{"cmd", "rig.move"}, {"rail", 100}});
  s = wait_settled();
  EXPECT_DOUBLE_EQ(s["rail"]["position"].get<double>(), 100.0);
}

// The socket's sixteen connections all held by clients that say nothing (a
// dashboard left open, a script that never closed its socket): the
// operator's emergency stop still gets through, and acts.
TEST_F(RigCommands, AnEmergencyStopGetsThroughWhileIdleClientsHoldEverySlot) {
  home_both();
  ok({{"cmd", "rig.move"}, {"rail", 2400}});
  const fs::path socket = dir_ / "control.sock";
  std::vector<std::unique_ptr<ControlClient>> idle;
  for (std::size_t i = 1; i < server_->settings().max_clients; ++i) {  // client_ holds the first
    idle.push_back(std::make_unique<ControlClient>(socket));
  }
  ControlClient operator_client(socket);
  const json reply = operator_client.call({{"cmd", "rig.stop"}, {"emergency", true}});
  EXPECT_EQ(reply.value("ok", false), true) << reply;
  EXPECT_EQ(reply["emergency"], true);
  // Its status shows the stop took; anything else waits for a free slot.
  const json s = operator_client.call({{"cmd", "rig.status"}});
  for (const char* axis : {"rail", "turntable"}) {
    EXPECT_EQ(s[axis]["state"], "fault") << s;
    EXPECT_EQ(s[axis]["fault"], "emergency stop") << s;
  }
  const json refused = operator_client.call({{"cmd", "rig.home"}});
  EXPECT_EQ(refused.value("error", std::string()),
            "too many clients (16 connected; beyond the limit only rig.status, rig.stop are served); try again later");
  EXPECT_EQ(server_->stats().beyond_limit, 1U);
}

TEST_F(RigCommands, EnableAndDisableOneAxisOrBoth) {
  EXPECT_EQ(ok({{"cmd", "rig.enable"}})["enabled"], (json{"rail", "turntable"}));
  json s = status();
  EXPECT_EQ(s["rail"]["state"], "idle");
  EXPECT_EQ(s["turntable"]["state"], "idle");
  EXPECT_EQ(ok({{"cmd", "rig.disable"}, {"axis", "turntable"}})["disabled"], (json{"turntable"}));
  s = status();
  EXPECT_EQ(s["rail"]["state"], "idle");
  EXPECT_EQ(s["turntable"]["state"], "disabled");

  // An axis in motion is not switched off under the carriage.
  ok({{"cmd", "rig.home"}, {"axis", "rail"}});
  EXPECT_EQ(error({{"cmd", "rig.disable"}, {"axis", "rail"}}),
            "rail: disable refused: the axis is homing; stop() and wait, or emergency_stop()");
  ok({{"cmd", "rig.stop"}});
}

// ---------------------------------------------------------------- markerctl rig without --config

class MarkerctlRigOnTheDaemon : public RigCommands {
 protected:
  Outcome run(std::vector<std::string> args) { return finish(*start(std::move(args))); }

  // markerctl rig --socket ... ARGS, started.
  std::unique_ptr<CapturedProcess> start(std::vector<std::string> args) {
    args.insert(args.begin(), {MARKERCTL_PATH, "rig", "--socket", (dir_ / "control.sock").string()});
    return std::make_unique<CapturedProcess>(args);
  }

  // Waits for it (killing it after two minutes) and collects its output.
  static Outcome finish(CapturedProcess& markerctl) {
    Outcome outcome = markerctl.wait(120s);
    if (outcome.timed_out) ADD_FAILURE() << "markerctl did not finish";
    return outcome;
  }
};

TEST_F(MarkerctlRigOnTheDaemon, StatusHomeMoveJogAndStopGoThroughTheSocket) {
  Outcome r = run({"status"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out,
            "rail       disabled, not homed: position 0.000 mm, target 0.000 mm; inputs: none active\n"
            "turntable  disabled, not homed: position 0.000 deg, target 0.000 deg; inputs: none active\n"
            "ground truth: distance 0.3000 m, yaw 0.000 deg\n");

  r = run({"move", "--rail", "25cm"});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err, "markerctl: rig move: rail: move to 250 mm refused: the axis is not homed; rig.home first\n");

  // --home homes what is not homed, then moves; values keep their units
  // (0.5 rad is 28.648 deg, and the turntable's step 0.01 deg).
  r = run({"move", "--home", "--rail", "25cm", "--turntable", "0.5rad"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NE(r.out.find("rail: homing\n"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("rail: moving to 250.000 mm\n"), std::string::npos) << r.out;
  EXPECT_NE(
      r.out.find("rail: at 250.000 mm\nturntable: at 28.650 deg\nground truth: distance 0.5500 m, yaw 28.650 deg\n"),
      std::string::npos)
      << r.out;
  EXPECT_NEAR(rig_->rail().status().position, 250.0, 1e-9);
  EXPECT_NEAR(rig_->turntable().status().position, 28.65, 1e-9);

  r = run({"jog", "--rail", "+5mm"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NEAR(rig_->rail().status().position, 255.0, 1e-9);

  r = run({"move", "--rail", "3m"});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err, "markerctl: rig move: rail: move to 3000 mm refused: outside the soft limits [0, 2500] mm\n");

  r = run({"status", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json s = json::parse(r.out);
  EXPECT_NEAR(s["rail"]["position"].get<double>(), 255.0, 1e-9);
  EXPECT_EQ(s["rail"]["homed"], true);

  r = run({"stop"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out, "nothing was moving\nrail at 255.000 mm, turntable at 28.650 deg\n");

  r = run({"move", "--no-wait", "--rail", "2500mm"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(rig_->rail().status().state, markerd::rig::AxisState::moving);
  r = run({"stop"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out.substr(0, 15), "rail: stopping\n") << r.out;
  EXPECT_EQ(rig_->rail().status().state, markerd::rig::AxisState::idle);
  EXPECT_LT(rig_->rail().status().position, 2400.0);

  // --json: the rig as rig.status shows it once done, on standard output
  // alone; the lines in words on standard error.
  r = run({"move", "--rail", "300mm", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  json j = json::parse(r.out);
  EXPECT_NEAR(j["rail"]["position"].get<double>(), 300.0, 1e-9);
  EXPECT_EQ(j["rail"]["settled"], true);
  EXPECT_NE(r.err.find("rail: at 300.000 mm\n"), std::string::npos) << r.err;
  r = run({"jog", "--turntable", "+1deg", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NEAR(json::parse(r.out)["turntable"]["position"].get<double>(), 29.65, 1e-9);
  r = run({"home", "--axis", "turntable", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(json::parse(r.out)["turntable"]["homed"], true);
  r = run({"stop", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.err.rfind("nothing was moving\nrail at 300.000 mm, ", 0), 0U) << r.err;
  EXPECT_TRUE(json::parse(r.out).contains("rail"));

  r = run({"jog"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err,
            "markerctl: rig jog: give --rail or --turntable (the interactive jog needs --config: it drives the "
            "rig itself)\n");
}

TEST_F(MarkerctlRigOnTheDaemon, AnInterruptWhileWaitingStopsTheRig) {
  home_both();
  const auto markerctl = start({"move", "--rail", "2400mm"});
  // Once the move is under way, Ctrl-C.
  wait_for([](const json& s) { return s["rail"]["position"].get<double>() > 50; });
  ASSERT_EQ(::kill(markerctl->pid(), SIGINT), 0);
  const Outcome r = finish(*markerctl);
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_NE(r.err.find("markerctl: rig move: SIGINT: stopping the rig\n"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("markerctl: rig move: interrupted by SIGINT: rig stopped (rail at "), std::string::npos)
      << r.err;
  const json s = status();
  EXPECT_EQ(s["rail"]["state"], "idle") << "the daemon's axes stay enabled: " << s;
  EXPECT_TRUE(s["rail"]["homed"].get<bool>());
  EXPECT_LT(s["rail"]["position"].get<double>(), 2300.0) << s;
}

}  // namespace
