#pragma once
// The rig: the rail (camera distance) and the turntable (marker angle), their
// geometry, and a snapshot of both that any thread reads without a lock (the
// capture thread stamps every frame with one).

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <type_traits>

#include "markerd/rig/axis.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/sim_clock.hpp"

namespace markerd::rig {

class GpioBackend;
class ModbusBus;

// What the drives of a rig share, and what must therefore outlive every one
// of them: the simulated clock of its simulated devices, one ModbusBus per
// RS-485 line or TCP connection (its thread serves every drive on it), and
// the GPIO line backend its GPIO axes were requested through. Empty members
// are devices the rig does not use.
struct RigDevices {
  std::shared_ptr<SimClock> sim_clock;
  std::map<std::string, std::shared_ptr<ModbusBus>> buses;  // by [rig.buses.<name>]
  std::shared_ptr<GpioBackend> gpio;
};

// One writer publishes a trivially copyable value; any number of readers copy
// it out without locks and without allocating, retrying while a write is in
// progress (a seqlock). The value lives in relaxed atomic words between a
// sequence counter's release/acquire fences, so there is no data race in the
// C++ sense and a reader never returns a torn value.
template <class T>
class SeqlockCell {
  static_assert(std::is_trivially_copyable_v<T>, "SeqlockCell holds trivially copyable values");

 public:
  SeqlockCell() { store(T{}); }
  explicit SeqlockCell(const T& value) { store(value); }

  // One writer at a time (the caller makes sure).
  void store(const T& value) noexcept {
    std::array<std::uint64_t, kWords> words{};
    std::memcpy(words.data(), &value, sizeof(T));
    const std::uint64_t seq = sequence_.load(std::memory_order_relaxed);
    sequence_.store(seq + 1, std::memory_order_relaxed);  // odd: a write is in progress
    std::atomic_thread_fence(std::memory_order_release);
    for (std::size_t i = 0; i < kWords; ++i) words_[i].store(words[i], std::memory_order_relaxed);
    sequence_.store(seq + 2, std::memory_order_release);
  }

  [[nodiscard]] T load() const noexcept {
    std::array<std::uint64_t, kWords> words{};
    for (;;) {
      const std::uint64_t before = sequence_.load(std::memory_order_acquire);
      if ((before & 1U) != 0) {
        std::this_thread::yield();
        continue;
      }
      for (std::size_t i = 0; i < kWords; ++i) words[i] = words_[i].load(std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (sequence_.load(std::memory_order_relaxed) == before) break;
    }
    T value;
    std::memcpy(static_cast<void*>(&value), words.data(), sizeof(T));
    return value;
  }

 private:
  static constexpr std::size_t kWords = (sizeof(T) + sizeof(std::uint64_t) - 1) / sizeof(std::uint64_t);
  std::atomic<std::uint64_t> sequence_{0};
  std::array<std::atomic<std::uint64_t>, kWords> words_{};
};

struct AxisSnapshot {
  double position = 0;  // user units (mm, deg)
  double target = 0;
  AxisState state = AxisState::disabled;
  bool homed = false;
  bool settled = false;
  bool fault = false;
  bool moving = false;  // moving, homing or stopping
};

struct RigSnapshot {
  std::uint64_t sequence = 0;                    // 1 for the first snapshot, +1 for each one after; 0: none yet
  std::chrono::steady_clock::time_point time{};  // when the axes' states were read
  AxisSnapshot rail;
  AxisSnapshot turntable;

  [[nodiscard]] bool settled() const { return rail.settled && turntable.settled; }
};

class Rig {
 public:
  // `devices`: what the axes' drives share (their clock, buses, GPIO
  // backend); the rig keeps them until after the axes are gone. The rig
  // starts publishing snapshots at once.
  Rig(std::unique_ptr<Axis> rail, std::unique_ptr<Axis> turntable, RigGeometry geometry, RigDevices devices = {});
  ~Rig();  // emergency-stops both axes, then releases the axes and, after them, the devices
  Rig(const Rig&) = delete;
  Rig& operator=(const Rig&) = delete;

  [[nodiscard]] Axis& rail() { return *rail_; }
  [[nodiscard]] Axis& turntable() { return *turntable_; }
  [[nodiscard]] const Axis& rail() const { return *rail_; }
  [[nodiscard]] const Axis& turntable() const { return *turntable_; }
  [[nodiscard]] const RigGeometry& geometry() const { return geometry_; }
  // The clock of the rig's simulated devices, or null when none is simulated.
  [[nodiscard]] const std::shared_ptr<SimClock>& sim_clock() const { return devices_.sim_clock; }
  [[nodiscard]] const RigDevices& devices() const { return devices_; }

  // The latest snapshot: lock-free, allocation-free, any thread. Published
  // every kSnapshotPeriod and whenever an axis's status changes.
  [[nodiscard]] RigSnapshot snapshot() const noexcept { return snapshot_.load(); }
  static constexpr std::chrono::milliseconds kSnapshotPeriod{3};

  // The marker pose for the positions in a snapshot (measured, not targets).
  [[nodiscard]] MarkerGroundTruth ground_truth(const RigSnapshot& snapshot) const;

  void emergency_stop() noexcept;

 private:
  void run(const std::stop_token& stop);
  void publish();

  RigGeometry geometry_;
  RigDevices devices_;  // declared before the axes: destroyed after them
  SeqlockCell<RigSnapshot> snapshot_;
  std::uint64_t sequence_ = 0;  // the publisher thread's own
  // Axis listeners raise `dirty_` so the publisher wakes before its period.
  std::mutex wake_mutex_;
  std::condition_variable_any wake_;
  bool dirty_ = false;  // under wake_mutex_
  std::unique_ptr<Axis> rail_;
  std::unique_ptr<Axis> turntable_;
  std::jthread publisher_;
};

}  // namespace markerd::rig
