#pragma once
// The simulated camera: renders the scene that the rig's positions at capture
// time imply (the marker on the turntable, seen from the camera on the rail,
// through the camera model), at a set frame rate. With the simulated rig it
// makes a sweep consistent end to end: every frame's pixels, its rig snapshot
// and the ground truth logged beside it describe the same moment.
//
// Rendering is the expensive part (supersampled, anti-aliased), and the scene
// only changes when an axis moves. So the noise-free image is rendered once
// per distinct pair of positions and kept; each frame is that image plus
// fresh sensor noise, written into the frame slot in one pass. While the rig
// stands still a frame costs one pass over its pixels and allocates nothing;
// while an axis moves every frame is a new render (tens of milliseconds at
// 640x480, more with supersampling), and the frame rate drops accordingly.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

struct SimCameraSettings {
  double fps = 30;  // frames per second, paced on the steady clock
  // The marker on the turntable (the config's [marker] table).
  detector::Family family = detector::Family::frame8;
  int id = 165;
  double marker_size_m = 0.08;
  bool cut_hole = false;  // frame8's hole printed white (true: cut out, showing the background)
  // Imaging (see markerd::Scene).
  double exposure = 1.0;
  double blur_sigma_px = 0.6;
  double noise_sigma = 2.0;  // grey levels
  int supersample = 3;
  bool clutter = true;
  bool distort = true;
  std::uint64_t seed = 1;
  // Without a rig: the fixed rail and turntable positions to render.
  double rail_mm = 650.0;
  double turntable_deg = 0.0;
  // Fault injection on a schedule (for soak tests; zero: never): every
  // `outage_every` of the camera's life it vanishes for `outage_for`, as
  // set_unplugged() does, then comes back.
  std::chrono::milliseconds outage_every{0};
  std::chrono::milliseconds outage_for{0};
};

// [camera.sim]: the imaging and the frame rate; the marker comes from the
// config's [marker] table and the image size from the camera model.
SimCameraSettings parse_sim_camera_settings(const ConfigTable& table);

class SimCamera final : public CaptureSource {
 public:
  // `camera` fixes the image size and the lens. `geometry` turns rig
  // positions into the marker's pose, as Rig::ground_truth does. The rig
  // positions come with each frame: the capture loop stamps frame.rig before
  // fill(); a frame without a snapshot shows the settings' fixed positions.
  SimCamera(SimCameraSettings settings, detector::CameraModel camera, rig::RigGeometry geometry);

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override;
  void open() override;
  void close() noexcept override { open_ = false; }
  [[nodiscard]] bool is_open() const noexcept override { return open_; }
  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override;
  void fill(Frame& frame) override;
  void skip() noexcept override;

  // Fault injection, from any thread: an unplugged camera vanishes at its
  // next frame (CaptureError vanished) and cannot be opened (not_found)
  // until it is plugged in again, as a USB camera pulled from its socket.
  // The settings' outage schedule unplugs it the same way.
  void set_unplugged(bool unplugged) noexcept { unplugged_.store(unplugged, std::memory_order_relaxed); }

  // Scheduled outages begun so far.
  [[nodiscard]] std::uint64_t outages() const noexcept { return outages_.load(std::memory_order_relaxed); }

  // Renders so far (one per distinct pair of positions shown).
  [[nodiscard]] std::uint64_t renders() const noexcept { return renders_; }

 private:
  void render_if_moved(double rail_mm, double turntable_deg);
  // Why the camera is away now (unplugged, or in a scheduled outage); nothing while it is there.
  [[nodiscard]] std::optional<std::string> absent();

  SimCameraSettings settings_;
  detector::CameraModel camera_;
  rig::RigGeometry geometry_;
  std::string name_;
  std::chrono::steady_clock::duration period_{};

  bool open_ = false;
  std::atomic<bool> unplugged_{false};
  std::chrono::steady_clock::time_point created_ = std::chrono::steady_clock::now();  // the outage schedule's origin
  std::uint64_t outage_seen_ = 0;  // the last scheduled outage counted (1: the first)
  std::atomic<std::uint64_t> outages_{0};
  std::chrono::steady_clock::time_point next_frame_{};
  std::uint64_t sequence_ = 0;

  detector::GreyImage clean_;                             // the last noise-free render
  std::optional<std::pair<double, double>> rendered_at_;  // its rail and turntable positions
  std::uint64_t renders_ = 0;
  // Sensor noise: a table of Gaussian samples (in grey levels, rounded) read
  // from a random place for each frame, so that a frame costs no random
  // number per pixel.
  std::vector<std::int8_t> noise_;
  std::uint64_t noise_state_ = 0;
};

}  // namespace markerd::daemon
