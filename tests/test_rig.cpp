// The rig: its ground truth against the detector's renderer (the test links
// the detector; the rig library does not), the snapshot seqlock under a
// concurrent writer, and a simulated rig built from config/rig-sim.toml.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <atomic>
#include <chrono>
#include <cmath>
#include <numbers>
#include <string>
#include <thread>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/render.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/rig_config.hpp"

using namespace markerd::rig;
using namespace std::chrono_literals;

namespace {

double px_distance(markerd::detector::Point2 a, markerd::detector::Point2 b) {
  return std::hypot(a.x - b.x, a.y - b.y);
}

}  // namespace

TEST(Geometry, GroundTruthEqualsTheRenderersPose) {
  RigGeometry g;
  g.d0_mm = 300;
  g.yaw0_deg = 5;  // the turntable reads 5 deg when the marker faces the camera
  for (double d : {0.3, 0.5, 0.95, 1.7, 2.8}) {
    for (double yaw : {-75.0, -30.0, -5.0, 0.0, 12.5, 45.0, 80.0}) {
      SCOPED_TRACE(testing::Message() << "d " << d << " yaw " << yaw);
      const MarkerGroundTruth truth = ground_truth(g, d * 1000 - 300, yaw + 5);
      const markerd::detector::MarkerPose pose = markerd::detector::facing_pose(d, yaw);
      EXPECT_LT((truth.rotation - pose.rotation).norm(), 1e-12);
      EXPECT_LT((truth.translation - pose.translation).norm(), 1e-12);
      EXPECT_NEAR(truth.distance_m, d, 1e-12);
      EXPECT_NEAR(truth.yaw_deg, yaw, 1e-12);
    }
  }
}

TEST(Geometry, APositiveTurntableAngleTurnsTheMarkerLikeThePositiveYaw) {
  const markerd::detector::CameraModel camera = markerd::detector::CameraModel::thesis_640x480();
  RigGeometry g;
  g.d0_mm = 300;
  markerd::detector::Scene rig_scene;
  markerd::detector::Scene renderer_scene;
  rig_scene.pose.rotation = ground_truth(g, 650, 30).rotation;
  rig_scene.pose.translation = ground_truth(g, 650, 30).translation;
  renderer_scene.pose = markerd::detector::facing_pose(0.95, 30);
  const markerd::detector::Quad rig_corners = markerd::detector::project_marker_corners(camera, rig_scene);
  const markerd::detector::Quad renderer_corners = markerd::detector::project_marker_corners(camera, renderer_scene);
  for (std::size_t k = 0; k < 4; ++k) EXPECT_LT(px_distance(rig_corners[k], renderer_corners[k]), 1e-9) << k;
  // Both turn the marker's right edge away from the camera: it is farther
  // (its +X axis points along +z) and looks shorter than the left edge.
  EXPECT_GT(ground_truth(g, 650, 30).rotation.col(0).z(), 0.4);
  const double left = px_distance(rig_corners[0], rig_corners[3]);
  const double right = px_distance(rig_corners[1], rig_corners[2]);
  EXPECT_LT(right, left * 0.97);
  // And a negative angle mirrors it.
  rig_scene.pose.rotation = ground_truth(g, 650, -30).rotation;
  const markerd::detector::Quad mirrored = markerd::detector::project_marker_corners(camera, rig_scene);
  EXPECT_GT(px_distance(mirrored[1], mirrored[2]), px_distance(mirrored[0], mirrored[3]) * 1.03);
}

TEST(Geometry, CameraOffsetsMoveTheMarkerTheOtherWay) {
  RigGeometry g;
  g.d0_mm = 300;
  g.camera_offset_x_mm = 20;   // camera right of the rail's line
  g.camera_offset_y_mm = -15;  // and above it (camera y points down)
  const MarkerGroundTruth truth = ground_truth(g, 200, 25);
  const markerd::detector::MarkerPose pose = markerd::detector::facing_pose(0.5, 25, 0, 0, -0.020, 0.015);
  EXPECT_LT((truth.rotation - pose.rotation).norm(), 1e-12);
  EXPECT_LT((truth.translation - pose.translation).norm(), 1e-12);
}

TEST(Geometry, MarkerOffsetsTurnWithTheMarkerAndTheRailSignFlipsTheRail) {
  RigGeometry g;
  g.d0_mm = 1000;
  g.marker_offset_normal_mm = 10;  // the printed face 10 mm in front of the axis
  g.marker_offset_lateral_mm = 5;  // and its centre 5 mm to its right
  MarkerGroundTruth t = ground_truth(g, 0, 0);
  EXPECT_LT((t.translation - Eigen::Vector3d(0.005, 0, 0.990)).norm(), 1e-12);
  // Turned by 90 deg the face points to the camera's right (+x) and the
  // marker's right side points away from the camera.
  t = ground_truth(g, 0, 90);
  EXPECT_LT((t.translation - Eigen::Vector3d(0.010, 0, 1.005)).norm(), 1e-12);
  g.rail_sign = -1;
  t = ground_truth(g, 250, 0);
  EXPECT_NEAR(t.distance_m, 0.750, 1e-12);
  EXPECT_NEAR(t.translation.z(), 0.740, 1e-12);
}

TEST(Geometry, ATiltedRailMovesTheAxisAlongItsDirectionAndThePlanInvertsIt) {
  RigGeometry g;
  g.d0_mm = 400;
  g.camera_offset_x_mm = 10;
  g.rail_tilt_x_deg = 2;   // the axis drifts to the camera's right as the camera moves away
  g.rail_tilt_y_deg = -1;  // and up
  const MarkerGroundTruth at0 = ground_truth(g, 0, 0);
  const MarkerGroundTruth at = ground_truth(g, 1000, 0);
  const double a = 2 * std::numbers::pi / 180;
  const double b = -1 * std::numbers::pi / 180;
  const Eigen::Vector3d u(std::sin(a) * std::cos(b), std::sin(b), std::cos(a) * std::cos(b));
  EXPECT_LT((at0.translation - Eigen::Vector3d(-0.010, 0, 0.400)).norm(), 1e-12);
  EXPECT_LT((at.translation - at0.translation - 1.0 * u).norm(), 1e-12);
  EXPECT_NEAR(at.distance_m, 0.4 + u.z(), 1e-12);
  EXPECT_NEAR(axis_distance_mm(g, 1000), 1000 * at.distance_m, 1e-9);
  EXPECT_NEAR(rail_for_distance_mm(g, 1000 * at.distance_m), 1000, 1e-9);
  g.rail_sign = -1;
  EXPECT_NEAR(rail_for_distance_mm(g, axis_distance_mm(g, -250)), -250, 1e-9);
  // Without a tilt, exactly the rail's old arithmetic.
  g = RigGeometry{};
  g.d0_mm = 300.1;
  EXPECT_EQ(ground_truth(g, 123.4, 5).distance_m, (300.1 + 123.4) / 1000.0);
  EXPECT_EQ(rail_for_distance_mm(g, 1000), 1000 - 300.1);
}

TEST(SeqlockCell, ReadersNeverSeeATornSnapshot) {
  SeqlockCell<RigSnapshot> cell;
  // The writer goes on until each reader has seen this many different
  // snapshots (so reads and writes did interleave), or the time runs out.
  constexpr std::uint64_t kSnapshotsSeen = 2000;
  constexpr int kReaders = 2;
  std::atomic<int> satisfied{0};
  std::atomic<bool> done{false};
  std::atomic<std::uint64_t> written{0};
  std::thread writer([&] {
    const auto give_up = std::chrono::steady_clock::now() + 60s;
    for (std::uint64_t k = 1; satisfied.load() < kReaders && std::chrono::steady_clock::now() < give_up; ++k) {
      // Every field follows from k: a torn read mixes two k.
      RigSnapshot s;
      s.sequence = k;
      s.time = std::chrono::steady_clock::time_point(std::chrono::nanoseconds(k * 7));
      s.rail.position = static_cast<double>(k);
      s.rail.target = -static_cast<double>(k);
      s.rail.homed = (k & 1U) != 0;
      s.rail.state = static_cast<AxisState>(k % 6);
      s.turntable.position = 0.5 * static_cast<double>(k);
      s.turntable.target = 3.0 * static_cast<double>(k);
      s.turntable.settled = k % 3 == 0;
      cell.store(s);
      written = k;
    }
    done = true;
  });
  std::vector<std::thread> readers;
  std::atomic<std::uint64_t> torn{0}, backwards{0}, reads{0};
  for (int r = 0; r < kReaders; ++r) {
    readers.emplace_back([&] {
      std::uint64_t last = 0, distinct = 0, count = 0;
      while (!done.load()) {
        const RigSnapshot s = cell.load();
        ++count;
        const std::uint64_t k = s.sequence;
        if (k < last) backwards.fetch_add(1);
        if (k != last && ++distinct == kSnapshotsSeen) satisfied.fetch_add(1);
        last = k;
        if (k == 0) continue;  // the writer has not begun
        const bool consistent =
            s.time.time_since_epoch() == std::chrono::nanoseconds(k * 7) && s.rail.position == static_cast<double>(k) &&
            s.rail.target == -static_cast<double>(k) && s.rail.homed == ((k & 1U) != 0) &&
            s.rail.state == static_cast<AxisState>(k % 6) && s.turntable.position == 0.5 * static_cast<double>(k) &&
            s.turntable.target == 3.0 * static_cast<double>(k) && s.turntable.settled == (k % 3 == 0);
        if (!consistent) torn.fetch_add(1);
      }
      reads.fetch_add(count);
    });
  }
  writer.join();
  for (auto& r : readers) r.join();
  EXPECT_EQ(satisfied.load(), kReaders);  // the readers ran while the writer wrote
  EXPECT_EQ(torn.load(), 0U);
  EXPECT_EQ(backwards.load(), 0U);
  EXPECT_EQ(cell.load().sequence, written.load());
  RecordProperty("writes", std::to_string(written.load()));
  RecordProperty("reads", std::to_string(reads.load()));
}

TEST(Rig, ASimulatedRigFromTheShippedConfigHomesMovesAndPublishesSnapshots) {
  RigConfig config = load_rig_config(MARKERD_SOURCE_DIR "/config/rig-sim.toml");
  config.sim.time_scale = 100;  // a minute of homing in well under a second
  const std::unique_ptr<Rig> rig = make_rig(config);
  ASSERT_NE(rig->sim_clock(), nullptr);
  EXPECT_EQ(rig->sim_clock()->time_scale(), 100);

  const RigSnapshot first = rig->snapshot();
  EXPECT_GE(first.sequence, 1U);
  EXPECT_EQ(first.rail.state, AxisState::disabled);
  EXPECT_FALSE(first.rail.homed);

  for (Axis* axis : {&rig->rail(), &rig->turntable()}) {
    axis->enable();
    axis->home();
  }
  ASSERT_TRUE(rig->rail().wait_settled(60s)) << rig->rail().status().fault;
  ASSERT_TRUE(rig->turntable().wait_settled(60s)) << rig->turntable().status().fault;
  // The switch edge is home_offset; the slow latch brakes v^2 / 2a past it:
  // 80^2 / 8000 = 0.8 steps on the rail (reported as a whole step), 50^2 /
  // 12000 = 0.2 steps on the turntable.
  EXPECT_DOUBLE_EQ(rig->rail().status().position, -121 * 0.025);
  EXPECT_DOUBLE_EQ(rig->turntable().status().position, 0.0);

  rig->rail().move_to(650);       // d = 0.95 m
  rig->turntable().move_to(-30);  // through the backlash approach: overshoot to -30.2, then up
  ASSERT_TRUE(rig->rail().wait_settled(60s)) << rig->rail().status().fault;
  ASSERT_TRUE(rig->turntable().wait_settled(60s)) << rig->turntable().status().fault;

  // The snapshot follows within a publishing period or an axis change.
  RigSnapshot s;
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  do {
    s = rig->snapshot();
  } while (!s.settled() && std::chrono::steady_clock::now() < deadline);
  ASSERT_TRUE(s.settled());
  EXPECT_GT(s.sequence, first.sequence);
  EXPECT_GT(s.time, first.time);
  EXPECT_DOUBLE_EQ(s.rail.position, 650);
  EXPECT_DOUBLE_EQ(s.turntable.position, -30);
  EXPECT_TRUE(s.rail.homed && s.turntable.homed);
  EXPECT_FALSE(s.rail.fault || s.turntable.fault || s.rail.moving || s.turntable.moving);

  const MarkerGroundTruth truth = rig->ground_truth(s);
  const markerd::detector::MarkerPose pose = markerd::detector::facing_pose(0.95, -30);
  EXPECT_LT((truth.rotation - pose.rotation).norm(), 1e-12);
  EXPECT_LT((truth.translation - pose.translation).norm(), 1e-12);

  // Snapshots keep coming while nothing changes (the periodic publication).
  const std::uint64_t before = rig->snapshot().sequence;
  const auto until = std::chrono::steady_clock::now() + 10s;
  while (rig->snapshot().sequence == before && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(1ms);
  EXPECT_GT(rig->snapshot().sequence, before);

  // The axes stop one after the other: a snapshot published between the
  // two shows the rail faulted and the turntable not yet.
  rig->emergency_stop();
  const auto stop_deadline = std::chrono::steady_clock::now() + 10s;
  while (!(rig->snapshot().rail.fault && rig->snapshot().turntable.fault) &&
         std::chrono::steady_clock::now() < stop_deadline)
    std::this_thread::sleep_for(1ms);
  EXPECT_TRUE(rig->snapshot().rail.fault);
  EXPECT_TRUE(rig->snapshot().turntable.fault);
}
