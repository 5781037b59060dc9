// Sweep plans: the shipped plans parse into the thesis's points, ranges do not
// drift, every mistake names the line and the key, the steps come in the
// planned order, axis targets invert the rig's geometry, and the dry run
// finds points beyond the soft limits and estimates the run's duration.

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "markerd/rig/geometry.hpp"
#include "markerd/rig/motion_profile.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"

using namespace markerd::sweep;
using markerd::ConfigError;

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

std::string plan_error(const std::string& text) {
  return error_of([&] { (void)parse_plan(text); });
}

markerd::rig::RigConfig sim_rig() { return markerd::rig::load_rig_config(kSourceDir / "config/rig-sim.toml"); }

// A plan with the given grids and everything else at small, round values.
std::string plan_text(const std::string& grids, int repeats = 1) {
  return "name = \"test\"\nframes_per_point = 10\nrepeats = " + std::to_string(repeats) + "\nsettle_s = 0.5\n\n" +
         grids;
}

std::vector<std::pair<double, double>> visits(const std::vector<PlanStep>& steps) {
  std::vector<std::pair<double, double>> points;
  for (const PlanStep& step : steps) {
    if (step.repeat == 0) points.emplace_back(step.distance_m, step.angle_deg);
  }
  return points;
}

}  // namespace

TEST(SweepPlan, ShippedDistancePlanIsTheThesisSweep) {
  const SweepPlan plan = load_plan(kSourceDir / "config/plans/thesis-distance.toml");
  EXPECT_EQ(plan.name, "thesis-distance");
  EXPECT_EQ(plan.repeats, 5);
  EXPECT_EQ(plan.frames_per_point, 10);
  EXPECT_EQ(plan.settle, std::chrono::milliseconds(500));
  EXPECT_EQ(plan.point_timeout, std::chrono::milliseconds(30000));
  EXPECT_EQ(plan.fault_timeout, std::chrono::milliseconds(600000));
  EXPECT_DOUBLE_EQ(plan.detection_threshold, 0.9);
  EXPECT_EQ(plan.marker.family, markerd::detector::Family::frame8);
  EXPECT_EQ(plan.marker.id, 165);
  EXPECT_DOUBLE_EQ(plan.marker.size_m, 0.08);
  ASSERT_EQ(plan.grids.size(), 1U);
  const PlanGrid& grid = plan.grids[0];
  EXPECT_EQ(grid.name, "distance");
  ASSERT_EQ(grid.distances_m.size(), 26U);
  EXPECT_EQ(grid.distances_m.front(), 0.3);
  EXPECT_EQ(grid.distances_m.back(), 2.8);
  EXPECT_EQ(grid.angles_deg, std::vector<double>{0.0});
  const auto steps = plan_steps(plan);
  EXPECT_EQ(steps.size(), 130U);
  EXPECT_EQ(steps.back().point, 25U);
}

TEST(SweepPlan, ShippedAnglePlansAreTheThesisSweeps) {
  for (const auto& [file, distance] :
       {std::pair{"thesis-angle-50cm.toml", 0.5}, std::pair{"thesis-angle-95cm.toml", 0.95}}) {
    SCOPED_TRACE(file);
    const SweepPlan plan = load_plan(kSourceDir / "config/plans" / file);
    EXPECT_EQ(plan.repeats, 5);
    ASSERT_EQ(plan.grids.size(), 1U);
    EXPECT_EQ(plan.grids[0].distances_m, std::vector<double>{distance});
    const auto& angles = plan.grids[0].angles_deg;
    ASSERT_EQ(angles.size(), 18U);
    EXPECT_EQ(angles.front(), 0.0);
    EXPECT_EQ(angles[1], 5.0);
    EXPECT_EQ(angles.back(), 85.0);
    EXPECT_EQ(plan_steps(plan).size(), 90U);
  }
}

// The socket marker's sweeps (thesis 6.2.2 and 6.2.3): its distance sweep
// lands on the thesis's 72, 78 and 81 cm and goes on as far as the paper
// plan's; its angle sweeps at 50 and 72 cm, where the thesis measured it,
// and at 95 cm, where the thesis did not find it at all.
TEST(SweepPlan, ShippedSocketPlansAreTheThesisSocketSweeps) {
  const SweepPlan distance = load_plan(kSourceDir / "config/plans/thesis-socket-distance.toml");
  EXPECT_EQ(distance.name, "thesis-socket-distance");
  EXPECT_EQ(distance.marker.mounting, Mounting::socket);
  EXPECT_EQ(distance.repeats, 5);
  std::vector<double> distances;
  for (const PlanGrid& grid : distance.grids) {
    EXPECT_EQ(grid.angles_deg, std::vector<double>{0.0}) << grid.name;
    distances.insert(distances.end(), grid.distances_m.begin(), grid.distances_m.end());
  }
  EXPECT_TRUE(std::is_sorted(distances.begin(), distances.end()));
  for (const double thesis : {0.72, 0.78, 0.81}) {
    EXPECT_NE(std::find(distances.begin(), distances.end(), thesis), distances.end()) << thesis;
  }
  EXPECT_EQ(distances.front(), 0.3);
  EXPECT_EQ(distances.back(), 2.8);
  EXPECT_EQ(distances.size(), 43U);

  for (const auto& [file, at] :
       {std::pair{"thesis-socket-angle-50cm.toml", 0.5}, std::pair{"thesis-socket-angle-72cm.toml", 0.72},
        std::pair{"thesis-socket-angle-95cm.toml", 0.95}}) {
    SCOPED_TRACE(file);
    const SweepPlan plan = load_plan(kSourceDir / "config/plans" / file);
    EXPECT_EQ(plan.marker.mounting, Mounting::socket);
    EXPECT_EQ(plan.repeats, 5);
    ASSERT_EQ(plan.grids.size(), 1U);
    EXPECT_EQ(plan.grids[0].distances_m, std::vector<double>{at});
    ASSERT_EQ(plan.grids[0].angles_deg.size(), 18U);
    EXPECT_EQ(plan.grids[0].angles_deg.back(), 85.0);
  }
  // The paper plans say so: a report pairs them with the socket's runs.
  for (const char* file : {"thesis.toml", "thesis-distance.toml", "thesis-angle-50cm.toml", "thesis-angle-95cm.toml"}) {
    EXPECT_EQ(load_plan(kSourceDir / "config/plans" / file).marker.mounting, Mounting::paper) << file;
  }
}

TEST(SweepPlan, MarkerMountingIsOptionalAndNamed) {
  const std::string grid = "[[grid]]\nname = \"g\"\ndistance_m = [0.5]\nangle_deg = [0]\n";
  EXPECT_EQ(parse_plan("name = \"x\"\n" + grid).marker.mounting, std::nullopt);
  for (const auto& [name, mounting] :
       {std::pair{"paper", Mounting::paper}, std::pair{"socket", Mounting::socket},
        std::pair{"switch", Mounting::light_switch}, std::pair{"cut_hole", Mounting::cut_hole}}) {
    const SweepPlan plan = parse_plan(std::string("name = \"x\"\n[marker]\nmounting = \"") + name + "\"\n" + grid);
    EXPECT_EQ(plan.marker.mounting, mounting) << name;
    EXPECT_EQ(to_string(mounting), name);
  }
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nmounting = \"wall\"\n" + grid),
            "<string>:3: marker.mounting: unknown mounting 'wall' (known: paper, socket, switch, cut_hole)");
}

TEST(SweepPlan, ShippedDemoPlanHoldsAllThree) {
  const SweepPlan plan = load_plan(kSourceDir / "config/plans/thesis.toml");
  EXPECT_EQ(plan.name, "thesis");
  EXPECT_EQ(plan.repeats, 5);
  EXPECT_EQ(plan.frames_per_point, 8);
  EXPECT_EQ(plan.settle, std::chrono::milliseconds(200));
  ASSERT_EQ(plan.grids.size(), 3U);
  EXPECT_EQ(plan.grids[0].name, "angle-50cm");
  EXPECT_EQ(plan.grids[1].name, "angle-95cm");
  EXPECT_EQ(plan.grids[2].name, "distance");
  const auto steps = plan_steps(plan);
  ASSERT_EQ(steps.size(), (18U + 18U + 26U) * 5U);
  EXPECT_EQ(steps.back().point, 61U);
  EXPECT_EQ(steps.front().distance_m, 0.5);
  EXPECT_EQ(steps.front().angle_deg, 0.0);
  // The first step of the third grid: point 36, the distance sweep's start.
  EXPECT_EQ(steps[36 * 5].grid, 2U);
  EXPECT_EQ(steps[36 * 5].point, 36U);
  EXPECT_EQ(steps[36 * 5].distance_m, 0.3);
  EXPECT_EQ(steps.back().distance_m, 2.8);
}

TEST(SweepPlan, TextIsKeptVerbatimAndParsesBackToTheSamePlan) {
  const auto path = kSourceDir / "config/plans/thesis.toml";
  const SweepPlan plan = load_plan(path);
  EXPECT_EQ(plan.text, markerd::test_support::read_file(path));
  EXPECT_EQ(plan.source, path.string());

  const SweepPlan again = parse_plan(plan.text, plan.source);
  EXPECT_EQ(again.name, plan.name);
  EXPECT_EQ(again.description, plan.description);
  EXPECT_EQ(again.frames_per_point, plan.frames_per_point);
  EXPECT_EQ(again.repeats, plan.repeats);
  EXPECT_EQ(again.settle, plan.settle);
  EXPECT_EQ(again.point_timeout, plan.point_timeout);
  EXPECT_EQ(again.fault_timeout, plan.fault_timeout);
  EXPECT_EQ(again.detection_threshold, plan.detection_threshold);
  EXPECT_EQ(again.marker.id, plan.marker.id);
  ASSERT_EQ(again.grids.size(), plan.grids.size());
  for (std::size_t g = 0; g < plan.grids.size(); ++g) {
    EXPECT_EQ(again.grids[g].name, plan.grids[g].name);
    EXPECT_EQ(again.grids[g].distances_m, plan.grids[g].distances_m);
    EXPECT_EQ(again.grids[g].angles_deg, plan.grids[g].angles_deg);
  }
}

TEST(SweepPlan, LoadingAMissingFileNamesIt) {
  const auto path = kSourceDir / "config/plans/no-such-plan.toml";
  const std::string error = error_of([&] { (void)load_plan(path); });
  EXPECT_EQ(error, path.string() + ": the plan cannot be read: No such file or directory");
}

TEST(SweepPlan, OnlyARegularFileOfAtMostTheLimitIsReadAsAPlan) {
  // /dev/zero never ends and a FIFO without a writer never answers: both are
  // refused at once, by what they are.
  EXPECT_EQ(error_of([] { (void)load_plan("/dev/zero"); }), "/dev/zero: the plan is a character device, not a file");
  const markerd::test_support::TempDir dir("markerd-plan");
  const auto fifo = dir / "fifo.toml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(error_of([&] { (void)load_plan(fifo); }), fifo.string() + ": the plan is a FIFO, not a file");
  EXPECT_THROW((void)load_plan(kSourceDir / "config/plans"), ConfigError);

  // One byte over the limit, in a file and as text (what markerd's sweep
  // commands are sent): the size and the limit, before anything is parsed.
  const std::string grid = "[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\n";
  std::string big = "name = \"big\"\n" + grid;
  big += "#" + std::string(kMaxPlanBytes - big.size() - 2, 'x') + "\n";
  ASSERT_EQ(big.size(), kMaxPlanBytes);
  EXPECT_EQ(parse_plan(big).name, "big");  // at the limit: fine
  big.insert(0, " ");
  EXPECT_EQ(plan_error(big), "<string>: the plan is 128.0 KiB (131073 bytes), larger than the 128 KiB allowed");
  const auto file = dir.write("big.toml", big);
  EXPECT_EQ(error_of([&] { (void)load_plan(file); }),
            file.string() + ": the plan is 128.0 KiB (131073 bytes), larger than the 128 KiB allowed");
}

TEST(SweepPlan, EveryNumberHasARangeThatMeansSomething) {
  const std::string grid = "[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\n";
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nsize_m = 1e300\n" + grid),
            "<string>:3: marker.size_m: must be from 0.005 to 2 m, got 1e+300");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nsize_m = 0.001\n" + grid),
            "<string>:3: marker.size_m: must be from 0.005 to 2 m, got 0.001");
  EXPECT_EQ(plan_error("name = \"x\"\nframes_per_point = 1000000\n" + grid),
            "<string>:2: frames_per_point: must be from 1 to 10000 frames, got 1000000");
  EXPECT_EQ(plan_error("name = \"x\"\nrepeats = 9223372036854775807\n" + grid),
            "<string>:2: repeats: must be an integer from -2147483648 to 2147483647, got 9223372036854775807");
  EXPECT_EQ(plan_error("name = \"x\"\nsettle_s = 1e9\n" + grid),
            "<string>:2: settle_s: must be from 0 to 600 s, got 1000000000");
  EXPECT_EQ(plan_error("name = \"x\"\npoint_timeout_s = inf\n" + grid),
            "<string>:2: point_timeout_s: must be a finite number, got inf");
  EXPECT_EQ(plan_error("name = \"x\"\nfault_timeout_s = 1e7\n" + grid),
            "<string>:2: fault_timeout_s: must be from 0 to 604800 s (0: wait for ever), got 10000000");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5, 1e300]\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m: element 1: must be from 0.01 to 100 m (from the camera to the turntable "
            "axis), got 1e+300");
  // A step far below anything a rig resolves: the range, not a count of 300 digits.
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = { from = 0.3, to = 2.8, step = 1e-300 }\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m.step: must be from 0.0001 to 100 m, got 1e-300");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = { from = 0, to = 80, step = 1e-300 }\n")),
            "<string>:8: grid[0].angle_deg.step: must be from 0.001 to 180 deg, got 1e-300");
  // A range whose end is far off: the count stays short.
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = { from = 0.3, to = 1e300, step = 1 }\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m.step: makes 1e+300 values from 0.3 to 1e+300, more than 10000");
  // The points a plan expands to are bounded, across grids too.
  std::string grids;
  for (int g = 0; g < 3; ++g) {
    grids += "[[grid]]\nname = \"g" + std::to_string(g) +
             "\"\ndistance_m = { from = 0.1, to = 10, step = 0.001 }\nangle_deg = { from = 0, to = 50, step = 1 }\n";
  }
  EXPECT_EQ(plan_error(plan_text(grids)),
            "<string>: the plan makes at least 1009902 measurements (points times repeats), more than 1000000");
}

TEST(SweepPlan, APlanForAFamilyTheDetectorDoesNotFindIsAProblem) {
  markerd::detector::DetectorConfig frame8;
  frame8.family = markerd::detector::Family::frame8;
  const PlanMarker tag{markerd::detector::Family::tag36h11, 5, 0.16, std::nullopt};
  const auto problem = marker_problem(tag, frame8, Mounting::paper);
  ASSERT_TRUE(problem.has_value());
  EXPECT_NE(problem->find("tag36h11"), std::string::npos) << *problem;
  EXPECT_NE(problem->find("frame8"), std::string::npos) << *problem;
  EXPECT_FALSE(marker_problem({markerd::detector::Family::frame8, 165, 0.16, std::nullopt}, frame8, Mounting::paper)
                   .has_value());
  // frame8's 0 and 255 come only with uniform_ids.
  const auto zero = marker_problem({markerd::detector::Family::frame8, 0, 0.08, std::nullopt}, frame8, Mounting::paper);
  ASSERT_TRUE(zero.has_value());
  EXPECT_NE(zero->find("uniform_ids"), std::string::npos) << *zero;
  frame8.frame8.uniform_ids = true;
  EXPECT_FALSE(
      marker_problem({markerd::detector::Family::frame8, 0, 0.08, std::nullopt}, frame8, Mounting::paper).has_value());
}

TEST(SweepPlan, APlanForAnotherMountingThanMarkerdsIsAProblem) {
  markerd::detector::DetectorConfig frame8;
  const PlanMarker socket{markerd::detector::Family::frame8, 165, 0.08, Mounting::socket};
  const auto problem = marker_problem(socket, frame8, Mounting::paper);
  ASSERT_TRUE(problem.has_value());
  EXPECT_NE(problem->find("the plan's marker is mounted \"socket\""), std::string::npos) << *problem;
  EXPECT_NE(problem->find("markerd's is mounted \"paper\""), std::string::npos) << *problem;
  EXPECT_FALSE(marker_problem(socket, frame8, Mounting::socket).has_value());
  // A plan that does not say matches any mounting.
  const PlanMarker unsaid{markerd::detector::Family::frame8, 165, 0.08, std::nullopt};
  for (const Mounting m : {Mounting::paper, Mounting::socket, Mounting::light_switch, Mounting::cut_hole}) {
    EXPECT_FALSE(marker_problem(unsaid, frame8, m).has_value()) << to_string(m);
  }
}

TEST(SweepPlan, FloatRangesReachTheirEndWithoutDrift) {
  const SweepPlan plan = parse_plan(plan_text(R"([[grid]]
distance_m = { from = 0.3, to = 2.8, step = 0.1 }
angle_deg = { from = -30, to = 30, step = 7.5 }
)"));
  const auto& distances = plan.grids[0].distances_m;
  ASSERT_EQ(distances.size(), 26U);
  // Each value is the double nearest its decimal, as a list would give it:
  // 0.3 + 3 * 0.1 is 0.6000000000000001, 0.3 + 12 * 0.1 is 1.5000000000000002.
  for (std::size_t i = 0; i < distances.size(); ++i) {
    EXPECT_EQ(distances[i], std::round((0.3 + 0.1 * static_cast<double>(i)) * 10) / 10) << i;
  }
  EXPECT_EQ(distances[3], 0.6);
  EXPECT_EQ(distances[12], 1.5);
  EXPECT_NEAR(distances.back(), 2.8, 1e-12);
  EXPECT_EQ(plan.grids[0].angles_deg, (std::vector<double>{-30, -22.5, -15, -7.5, 0, 7.5, 15, 22.5, 30}));
}

TEST(SweepPlan, RangesStopAtTheLastStepWithinTheirEnd) {
  const SweepPlan plan = parse_plan(plan_text(R"([[grid]]
distance_m = { from = 1, to = 2, step = 0.3 }
angle_deg = { from = 10, to = 10, step = 1 }
)"));
  ASSERT_EQ(plan.grids[0].distances_m.size(), 4U);
  EXPECT_EQ(plan.grids[0].distances_m.back(), 1.9);
  EXPECT_EQ(plan.grids[0].angles_deg, std::vector<double>{10.0});
}

TEST(SweepPlan, ListsKeepTheirOrderAndDefaultsApply) {
  const SweepPlan plan = parse_plan(R"(name = "lists"
[[grid]]
distance_m = [0.95, 0.5]
angle_deg = [20, -10, 0]
)");
  EXPECT_EQ(plan.grids[0].name, "grid0");
  EXPECT_EQ(plan.grids[0].distances_m, (std::vector<double>{0.95, 0.5}));
  EXPECT_EQ(plan.grids[0].angles_deg, (std::vector<double>{20, -10, 0}));
  EXPECT_EQ(plan.grids[0].order, SweepOrder::grid);
  EXPECT_EQ(plan.grids[0].slow_axis, SweepAxis::distance);
  const SweepPlan defaults;
  EXPECT_EQ(plan.frames_per_point, defaults.frames_per_point);
  EXPECT_EQ(plan.repeats, defaults.repeats);
  EXPECT_EQ(plan.settle, defaults.settle);
  EXPECT_EQ(plan.point_timeout, defaults.point_timeout);
  EXPECT_EQ(plan.fault_timeout, defaults.fault_timeout);
  EXPECT_EQ(plan.detection_threshold, defaults.detection_threshold);
  EXPECT_EQ(plan.marker.family, markerd::detector::Family::frame8);
  EXPECT_EQ(plan.marker.id, 165);
  EXPECT_EQ(plan.description, "");
  EXPECT_EQ(plan.source, "<string>");
  EXPECT_EQ(visits(plan_steps(plan)), (std::vector<std::pair<double, double>>{
                                          {0.95, 20}, {0.95, -10}, {0.95, 0}, {0.5, 20}, {0.5, -10}, {0.5, 0}}));
}

TEST(SweepPlan, ErrorsNameTheLineAndTheKey) {
  const std::string grids = R"([[grid]]
name = "near"
distance_m = [0.5]
angle_deg = [0]

[[grid]]
name = "far"
distance_m = { from = 1.0, to = 2.0, step = 0 }
angle_deg = [0]
)";
  // plan_text puts 5 lines before the grids: "far"'s distance_m is line 13.
  EXPECT_EQ(plan_error(plan_text(grids)), "<string>:13: grid[1].distance_m.step: must be from 0.0001 to 100 m, got 0");

  EXPECT_EQ(plan_error(plan_text(R"([[grid]]
distance_m = [0.5]
angle_deg = { from = 0, to = 90, step = 5 }
)")),
            "<string>:8: grid[0].angle_deg.to: the range reaches 90: must lie strictly between -90 and 90 (degrees "
            "from facing the camera), got 90");
  EXPECT_EQ(plan_error(plan_text(R"([[grid]]
distance_m = [0.5, 0, 1.0]
angle_deg = [0]
)")),
            "<string>:7: grid[0].distance_m: element 1: must be from 0.01 to 100 m (from the camera to the turntable "
            "axis), got 0");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = []\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m: is empty: a grid needs at least one value on each axis");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = [nan]\n")),
            "<string>:8: grid[0].angle_deg: element 0: must be a finite number, got nan");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5, \"far\"]\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m: element 1 must be a number");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5, 0.5]\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m: lists 0.5 twice");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5]\n")),
            "<string>:6: [grid[0]]: missing key 'grid[0].angle_deg' (a list of numbers, or a range { from, to, "
            "step })");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = { from = 2, to = 1, step = 0.1 }\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m.to: must be >= from (2), got 1 (a range ascends; for another order list "
            "the values)");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = { from = 0.01, to = 2, step = 1e-4 }\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m.step: makes 19901 values from 0.01 to 2, more than 10000");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = 0.5\nangle_deg = [0]\n")),
            "<string>:7: grid[0].distance_m: must be a list of numbers ([0.5, 0.95]) or a range ({ from = 0.3, to = "
            "2.8, step = 0.1 })");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\norder = \"zigzag\"\n")),
            "<string>:9: grid[0].order: must be \"grid\" or \"snake\", got \"zigzag\"");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\nslow_axis = \"yaw\"\n")),
            "<string>:9: grid[0].slow_axis: must be \"distance\" or \"angle\", got \"yaw\"");
  EXPECT_EQ(plan_error(plan_text("[[grid]]\nname = \"a\"\ndistance_m = [0.5]\nangle_deg = [0]\n"
                                 "[[grid]]\nname = \"a\"\ndistance_m = [0.6]\nangle_deg = [0]\n")),
            "<string>:11: grid[1].name: \"a\" names an earlier grid already");
}

TEST(SweepPlan, TopLevelErrorsNameTheLineAndTheKey) {
  const std::string grid = "[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\n";
  EXPECT_EQ(plan_error("name = \"a b\"\n" + grid),
            "<string>:1: name: must be 1 to 64 of A-Z a-z 0-9 . _ - (it names the plan's runs), got \"a b\"");
  EXPECT_EQ(plan_error(grid), "<string>: missing key 'name' (a string)");
  EXPECT_EQ(plan_error("name = \"x\"\nrepeats = 0\n" + grid),
            "<string>:2: repeats: must be from 1 to 1000 measurements per point, got 0");
  EXPECT_EQ(plan_error("name = \"x\"\nframes_per_point = 2.5\n" + grid),
            "<string>:2: frames_per_point: must be an integer");
  EXPECT_EQ(plan_error("name = \"x\"\nsettle_s = -1\n" + grid),
            "<string>:2: settle_s: must be from 0 to 600 s, got -1");
  EXPECT_EQ(plan_error("name = \"x\"\npoint_timeout_s = 0\n" + grid),
            "<string>:2: point_timeout_s: must be from 0.1 to 86400 s, got 0");
  EXPECT_EQ(plan_error("name = \"x\"\ndetection_threshold = 1.5\n" + grid),
            "<string>:2: detection_threshold: must lie in (0, 1] (a share of the frames), got 1.5");
  EXPECT_EQ(plan_error("name = \"x\"\n"), "<string>: missing [[grid]]: a plan visits the points of one or more grids");
  EXPECT_EQ(plan_error("name = \"x\"\n[grid]\ndistance_m = [0.5]\nangle_deg = [0]\n"),
            "<string>:2: grid: must be one or more [[grid]] tables (two brackets)");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nfamily = \"qr\"\n" + grid),
            "<string>:3: marker.family: unknown family 'qr' (known: frame8, aruco4x4_50, tag36h11)");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nid = 256\n" + grid),
            "<string>:3: marker.id: must be 0 .. 255 for frame8, got 256");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nfamily = \"aruco4x4_50\"\n" + grid),
            "<string>:2: marker.id: must be 0 .. 49 for aruco4x4_50, got 165 (the default: give the marker's id)");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nsize_m = 0\n" + grid),
            "<string>:3: marker.size_m: must be from 0.005 to 2 m, got 0");
  EXPECT_EQ(plan_error("name = \"x\"\nname = \"y\"\n" + grid).substr(0, 11), "<string>:2:");  // TOML syntax
}

TEST(SweepPlan, UnknownKeysAreRejectedEverywhere) {
  const std::string grid = "[[grid]]\ndistance_m = [0.5]\nangle_deg = [0]\n";
  EXPECT_EQ(plan_error("name = \"x\"\nrepeat = 3\n" + grid),
            "<string>:2: repeat: unknown key (known here: name, description, frames_per_point, repeats, settle_s, "
            "point_timeout_s, detection_threshold, fault_timeout_s, marker, grid)");
  EXPECT_EQ(plan_error("name = \"x\"\n" + grid + "angles_deg = [5]\n"),
            "<string>:5: grid[0].angles_deg: unknown key (known here: name, distance_m, angle_deg, order, slow_axis)");
  EXPECT_EQ(plan_error("name = \"x\"\n[[grid]]\ndistance_m = { from = 1, to = 2, by = 0.5 }\nangle_deg = [0]\n"),
            "<string>:3: grid[0].distance_m.by: unknown key (known here: from, to, step)");
  EXPECT_EQ(plan_error("name = \"x\"\n[marker]\nsize = 0.1\n" + grid),
            "<string>:3: marker.size: unknown key (known here: family, id, size_m, mounting)");
}

TEST(SweepPlan, GridOrderRunsTheFastAxisTheSameWayEveryRow) {
  const SweepPlan plan = parse_plan(plan_text(R"([[grid]]
distance_m = [0.5, 1.0]
angle_deg = [0, 10, 20]
)"));
  EXPECT_EQ(visits(plan_steps(plan)),
            (std::vector<std::pair<double, double>>{{0.5, 0}, {0.5, 10}, {0.5, 20}, {1.0, 0}, {1.0, 10}, {1.0, 20}}));
}

TEST(SweepPlan, SnakeOrderReversesTheFastAxisOnOddRows) {
  const SweepPlan by_distance = parse_plan(plan_text(R"([[grid]]
distance_m = [0.5, 1.0, 1.5]
angle_deg = [0, 10, 20]
order = "snake"
)"));
  EXPECT_EQ(visits(plan_steps(by_distance)),
            (std::vector<std::pair<double, double>>{
                {0.5, 0}, {0.5, 10}, {0.5, 20}, {1.0, 20}, {1.0, 10}, {1.0, 0}, {1.5, 0}, {1.5, 10}, {1.5, 20}}));

  const SweepPlan by_angle = parse_plan(plan_text(R"([[grid]]
distance_m = [0.5, 1.0, 1.5]
angle_deg = [0, 10]
order = "snake"
slow_axis = "angle"
)"));
  EXPECT_EQ(visits(plan_steps(by_angle)),
            (std::vector<std::pair<double, double>>{{0.5, 0}, {1.0, 0}, {1.5, 0}, {1.5, 10}, {1.0, 10}, {0.5, 10}}));
}

TEST(SweepPlan, RepeatsAreConsecutiveAndPointsNumberedAcrossGrids) {
  const SweepPlan plan = parse_plan(plan_text(R"([[grid]]
distance_m = [0.5, 1.0]
angle_deg = [0]

[[grid]]
distance_m = [2.0]
angle_deg = [30]
)",
                                              3));
  const auto steps = plan_steps(plan);
  ASSERT_EQ(steps.size(), 9U);
  const std::size_t expected_grid[] = {0, 0, 0, 0, 0, 0, 1, 1, 1};
  const std::size_t expected_point[] = {0, 0, 0, 1, 1, 1, 2, 2, 2};
  const double expected_distance[] = {0.5, 0.5, 0.5, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0};
  for (std::size_t i = 0; i < steps.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(steps[i].index, i);
    EXPECT_EQ(steps[i].grid, expected_grid[i]);
    EXPECT_EQ(steps[i].point, expected_point[i]);
    EXPECT_EQ(steps[i].repeat, static_cast<int>(i % 3));
    EXPECT_EQ(steps[i].distance_m, expected_distance[i]);
  }
  EXPECT_EQ(steps[8].angle_deg, 30.0);
}

TEST(SweepPlan, AxisTargetsInvertTheGroundTruth) {
  markerd::rig::RigGeometry geometry;
  geometry.d0_mm = 3100.0;  // the rail runs towards the marker from 3.1 m
  geometry.yaw0_deg = 12.5;
  geometry.rail_sign = -1;
  geometry.camera_offset_x_mm = 15.0;
  geometry.camera_offset_y_mm = -40.0;
  geometry.marker_offset_normal_mm = 4.0;
  geometry.marker_offset_lateral_mm = -2.5;

  const AxisTargets near = axis_targets(geometry, 0.3, -20.0);
  EXPECT_NEAR(near.rail, 2800.0, 1e-9);
  EXPECT_NEAR(near.turntable, -7.5, 1e-12);
  for (const double distance : {0.3, 0.95, 1.7, 2.8}) {
    for (const double angle : {-85.0, -5.0, 0.0, 42.5, 85.0}) {
      const AxisTargets targets = axis_targets(geometry, distance, angle);
      const auto truth = markerd::rig::ground_truth(geometry, targets.rail, targets.turntable);
      EXPECT_NEAR(truth.distance_m, distance, 1e-12) << distance << " m " << angle << " deg";
      EXPECT_NEAR(truth.yaw_deg, angle, 1e-12) << distance << " m " << angle << " deg";
    }
  }
}

TEST(SweepPlanCheck, ShippedPlansFitTheSimulatedRig) {
  const auto rig = sim_rig();
  for (const char* file : {"thesis.toml", "thesis-distance.toml", "thesis-angle-50cm.toml", "thesis-angle-95cm.toml",
                           "thesis-socket-distance.toml", "thesis-socket-angle-50cm.toml",
                           "thesis-socket-angle-72cm.toml", "thesis-socket-angle-95cm.toml"}) {
    SCOPED_TRACE(file);
    const SweepPlan plan = load_plan(kSourceDir / "config/plans" / file);
    const PlanCheck check = check_plan(plan, rig, 30.0);
    EXPECT_TRUE(check.ok());
    EXPECT_EQ(check.problems, std::vector<std::string>{});
    EXPECT_EQ(check.warnings, std::vector<std::string>{});
    EXPECT_EQ(check.steps.size(), plan_steps(plan).size());
    EXPECT_GT(check.estimated_duration.count(), 0.0);
  }
  const PlanCheck demo = check_plan(load_plan(kSourceDir / "config/plans/thesis.toml"), rig, 30.0);
  EXPECT_EQ(demo.points, 62U);
  // Every measurement waits 0.2 s and collects 6 frames at 30 fps; the moves
  // and the axes' settling come on top.
  EXPECT_GT(demo.estimated_duration.count(), 310 * 0.4);
  EXPECT_LT(demo.estimated_duration.count(), 15 * 60.0);
}

TEST(SweepPlanCheck, PointsBeyondTheSoftLimitsAreProblemsOncePerPoint) {
  const auto rig = sim_rig();
  const SweepPlan plan = parse_plan(plan_text(R"([[grid]]
name = "far"
distance_m = [0.2, 2.8, 3.0]
angle_deg = [0, 89.5]
)",
                                              5));
  const PlanCheck check = check_plan(plan, rig, 0);
  EXPECT_FALSE(check.ok());
  EXPECT_EQ(check.points, 6U);
  EXPECT_EQ(check.problems,
            (std::vector<std::string>{
                "point 0 (grid \"far\": 0.2 m, 0 deg): rail -100 mm is below its min_position 0 mm",
                "point 1 (grid \"far\": 0.2 m, 89.5 deg): rail -100 mm is below its min_position 0 mm",
                "point 4 (grid \"far\": 3 m, 0 deg): rail 2700 mm is beyond its max_position 2500 mm",
                "point 5 (grid \"far\": 3 m, 89.5 deg): rail 2700 mm is beyond its max_position 2500 mm",
            }));

  // The turntable's limits, through the geometry's yaw0.
  auto turned = rig;
  turned.geometry.yaw0_deg = 5.0;
  const PlanCheck turned_check = check_plan(plan, turned, 0);
  ASSERT_EQ(turned_check.problems.size(), 5U);
  EXPECT_EQ(turned_check.problems[2],
            "point 3 (grid \"far\": 2.8 m, 89.5 deg): turntable 94.5 deg is beyond its "
            "max_position 90 deg");
  EXPECT_EQ(turned_check.problems[4],
            "point 5 (grid \"far\": 3 m, 89.5 deg): rail 2700 mm is beyond its "
            "max_position 2500 mm; turntable 94.5 deg is beyond its max_position 90 deg");
}

// The hand-computed estimates use config/rig-sim.toml: rail 50 mm/s, 100
// mm/s^2, settle 200 ms, no backlash; turntable 30 deg/s, 60 deg/s^2, settle
// 300 ms, backlash 0.2 deg approached from below.
TEST(SweepPlanCheck, EstimateOfARailMoveMatchesTheHandComputedValue) {
  auto rig = sim_rig();
  const SweepPlan plan = parse_plan(plan_text("[[grid]]\ndistance_m = [0.5, 0.6]\nangle_deg = [0]\n"));
  // First point: no move (the start is unknown), settle 0.5 s + 10 frames at
  // 10 fps = 1.5 s. Second: 100 mm, accelerating 0.5 s (12.5 mm), cruising 75
  // mm (1.5 s), braking 0.5 s: 2.5 s, + the rail's 0.2 s + 1.5 s = 4.2 s.
  const PlanCheck check = check_plan(plan, rig, 10.0);
  EXPECT_NEAR(check.estimated_duration.count(), 5.7, 5.7 * 0.01);
  EXPECT_EQ(check.fps, 10.0);

  // Simulated at 10x: the move takes 0.25 s of real time; settling does not shrink.
  rig.sim.time_scale = 10.0;
  EXPECT_NEAR(check_plan(plan, rig, 10.0).estimated_duration.count(), 3.45, 3.45 * 0.01);

  // Frame rate unknown: the frames cost nothing.
  rig.sim.time_scale = 1.0;
  EXPECT_NEAR(check_plan(plan, rig, 0).estimated_duration.count(), 3.7, 3.7 * 0.01);
}

TEST(SweepPlanCheck, EstimateCountsTheBacklashOvershoot) {
  const auto rig = sim_rig();
  // Turning down from 10 to 0 deg against approach_direction = 1: to -0.2 deg
  // (10.2 deg, too short to reach 30 deg/s: 2 sqrt(10.2 / 60) = 0.8246 s),
  // then up 0.2 deg (2 sqrt(0.2 / 60) = 0.1155 s), + 0.3 s settling.
  const SweepPlan down = parse_plan(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = [10, 0]\n"));
  const double expected_down = 1.5 + (0.8246 + 0.1155 + 0.3 + 1.5);
  EXPECT_NEAR(check_plan(down, rig, 10.0).estimated_duration.count(), expected_down, expected_down * 0.01);
  // Turning up reaches 0 deg directly: 2 sqrt(10 / 60) = 0.8165 s.
  const SweepPlan up = parse_plan(plan_text("[[grid]]\ndistance_m = [0.5]\nangle_deg = [0, 10]\n"));
  const double expected_up = 1.5 + (0.8165 + 0.3 + 1.5);
  EXPECT_NEAR(check_plan(up, rig, 10.0).estimated_duration.count(), expected_up, expected_up * 0.01);
}

TEST(SweepPlanCheck, RepeatsAndSimultaneousMovesCostWhatTheSlowerAxisTakes) {
  const auto rig = sim_rig();
  // Two repeats per point; the second point moves both axes: the rail 100 mm
  // (2.5 s + 0.2 s) and the turntable 10 deg up (0.8165 s + 0.3 s): the rail
  // decides. Each of the 4 measurements waits 0.5 s and takes 1 s of frames.
  const SweepPlan plan = parse_plan(plan_text("[[grid]]\ndistance_m = [0.5, 0.6]\nangle_deg = [0]\n", 2) +
                                    "[[grid]]\ndistance_m = [0.6]\nangle_deg = [10]\n");
  const PlanCheck check = check_plan(plan, rig, 10.0);
  EXPECT_EQ(check.steps.size(), 6U);
  EXPECT_EQ(check.points, 3U);
  const double expected = 6 * 1.5 + (2.5 + 0.2) + (0.8165 + 0.3);
  EXPECT_NEAR(check.estimated_duration.count(), expected, expected * 0.01);
}

TEST(SweepPlanCheck, MeasurementsLongerThanThePointTimeoutAreWarnings) {
  const auto rig = sim_rig();
  // A long move is no reason for a warning: the runner allows moves their
  // own time. 10 frames at 0.25 fps are (40 s + 0.5 s settle > 30 s).
  const SweepPlan plan = parse_plan(plan_text("[[grid]]\ndistance_m = [0.3, 2.8]\nangle_deg = [0]\n", 2));
  EXPECT_EQ(check_plan(plan, rig, 10.0).warnings, std::vector<std::string>{});
  const PlanCheck check = check_plan(plan, rig, 0.25);
  EXPECT_TRUE(check.ok());
  EXPECT_EQ(check.warnings, std::vector<std::string>{"every measurement's settling and frames take about 40.5 s, "
                                                     "longer than point_timeout_s = 30: each will time out"});
}

TEST(SweepPlanCheck, FormatsTheDryRun) {
  const auto rig = sim_rig();
  const SweepPlan plan = parse_plan(R"(name = "demo"
frames_per_point = 10
repeats = 2
settle_s = 0.5
[[grid]]
name = "near"
distance_m = [0.5, 0.6]
angle_deg = { from = 0, to = 10, step = 5 }
order = "snake"
[[grid]]
distance_m = [3.0]
angle_deg = [0]
)",
                                    "demo.toml");
  // Each of the 14 measurements: 0.5 s + 10 frames at 30 fps = 0.833 s. Moves:
  // 0 -> 5 -> 10 deg (0.577 s + 0.3 s each), 0.5 -> 0.6 m (2.5 s + 0.2 s),
  // 10 -> 5 -> 0 deg with the backlash overshoot (0.589 s + 0.115 s + 0.3 s
  // each), 0.6 -> 3.0 m (48.5 s + 0.2 s): 66.8 s in all.
  const std::string text = format_plan_check(plan, check_plan(plan, rig, 30.0));
  EXPECT_EQ(text, R"(plan "demo" (demo.toml): 7 points in 2 grids, 2 measurements of 10 frames each: 14 measurements
  grid 0 "near": 6 points: 2 distances 0.5 .. 0.6 m x 3 angles 0 .. 10 deg, snake order, slow axis distance
  grid 1 "grid1": 1 point: 3 m x 0 deg, grid order, slow axis distance
estimated duration: 1 min 07 s (moves, settling, frames at 30 fps; homing not included)
1 point outside the axes' soft limits:
  point 6 (grid "grid1": 3 m, 0 deg): rail 2700 mm is beyond its max_position 2500 mm
)");
}
