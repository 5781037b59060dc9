#include "markerd/rig/rig.hpp"

#include <stdexcept>
#include <utility>

namespace markerd::rig {

namespace {

AxisSnapshot snapshot_of(const AxisStatus& s) {
  AxisSnapshot a;
  a.position = s.position;
  a.target = s.target;
  a.state = s.state;
  a.homed = s.homed;
  a.settled = s.settled;
  a.fault = s.state == AxisState::fault;
  a.moving = s.state == AxisState::moving || s.state == AxisState::homing || s.state == AxisState::stopping;
  return a;
}

}  // namespace

Rig::Rig(std::unique_ptr<Axis> rail, std::unique_ptr<Axis> turntable, RigGeometry geometry, RigDevices devices)
    : geometry_(geometry), devices_(std::move(devices)), rail_(std::move(rail)), turntable_(std::move(turntable)) {
  if (!rail_ || !turntable_) throw std::invalid_argument("Rig: both the rail and the turntable axis are required");
  auto on_change = [this](const AxisStatus&) {
    {
      const std::lock_guard<std::mutex> lock(wake_mutex_);
      dirty_ = true;
    }
    wake_.notify_one();
  };
  rail_->set_status_listener(on_change);
  turntable_->set_status_listener(on_change);
  publish();
  publisher_ = std::jthread([this](const std::stop_token& stop) { run(stop); });
}

Rig::~Rig() {
  emergency_stop();
  publisher_.request_stop();
  if (publisher_.joinable()) publisher_.join();
  rail_->set_status_listener({});
  turntable_->set_status_listener({});
}

void Rig::emergency_stop() noexcept {
  rail_->emergency_stop();
  turntable_->emergency_stop();
}

MarkerGroundTruth Rig::ground_truth(const RigSnapshot& snapshot) const {
  return rig::ground_truth(geometry_, snapshot.rail.position, snapshot.turntable.position);
}

void Rig::publish() {
  RigSnapshot s;
  s.time = std::chrono::steady_clock::now();
  s.rail = snapshot_of(rail_->status());
  s.turntable = snapshot_of(turntable_->status());
  s.sequence = ++sequence_;
  snapshot_.store(s);
}

void Rig::run(const std::stop_token& stop) {
  while (!stop.stop_requested()) {
    {
      std::unique_lock<std::mutex> lock(wake_mutex_);
      wake_.wait_for(lock, stop, kSnapshotPeriod, [this] { return dirty_; });
      dirty_ = false;
    }
    if (stop.stop_requested()) break;
    publish();
  }
}

}  // namespace markerd::rig
