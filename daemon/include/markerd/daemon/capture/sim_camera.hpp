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
//
// Its controls, as a camera's (camera.get, camera.set): exposure (the
// scene's, so a change renders again), gain (scales each frame's grey
// levels), auto_gain (the camera picks the gain that brings the image to
// mid-grey; gain is inactive meanwhile), and the sensor noise, read-only.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/detector/render.hpp"
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
  // What the print is mounted on ([marker] mounting): glued onto a cover
  // frame, what its cut hole shows, the paper beyond its edge.
  std::optional<detector::CoverFrame> frame;
  detector::Insert insert = detector::Insert::none;
  double margin_m = 0;
  // The scene around it ([camera.sim]): objects covering whole sides of the
  // marker (markerctl render's --cover and its options), the plain
  // background's grey, the share of unshaded light.
  std::vector<detector::MarkerSide> cover;
  double cover_depth = 0.2;  // a share of the marker's size, in from its outer edge
  float cover_reflectance = 0.1F;
  double cover_height_m = 0.03;
  double background_grey = 128;  // with clutter = false
  double ambient = 0.3;
  // Imaging (see markerd::Scene).
  double exposure = 1.0;  // kSimExposure's range; also the exposure control's default
  // The gain, in percent of the rendered grey levels (kSimGain's range and
  // step), and the automatic gain; the controls' defaults.
  std::int64_t gain = 100;
  bool auto_gain = false;
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

// The ranges of the simulated camera's controls, and of the config keys that
// set them at start.
inline constexpr double kSimExposureMin = 0.01;
inline constexpr double kSimExposureMax = 4;
inline constexpr std::int64_t kSimGainMin = 25;
inline constexpr std::int64_t kSimGainMax = 400;
inline constexpr std::int64_t kSimGainStep = 25;

// [camera.sim]: the imaging, the frame rate and the scene around the marker;
// the marker and its mounting come from the config's [marker] table and the
// image size from the camera model.
SimCameraSettings parse_sim_camera_settings(const ConfigTable& table);
// "top", "right", "bottom", "left": the config's words, markerctl render's --cover.
[[nodiscard]] std::string_view to_string(detector::MarkerSide side);
[[nodiscard]] std::optional<detector::MarkerSide> marker_side_from_name(std::string_view name);

class SimCamera final : public CaptureSource {
 public:
  // `camera` fixes the image size and the lens. `geometry` turns rig
  // positions into the marker's pose, as Rig::ground_truth does: the
  // simulated world's, which [rig.sim.geometry] may set apart from the
  // geometry markerd's ground truth states (docs/rig.md). The rig
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

  // Any thread: exposure, gain, auto_gain and noise_sigma (read-only); a
  // value written shows from the next frame on.
  [[nodiscard]] std::vector<CameraControlInfo> read_controls() override;
  void write_control(const CameraControlInfo& control, const ControlValue& value) override;

  // Any thread: the mean grey level of the last frame delivered, what a
  // change of exposure or gain shows in the frames.
  [[nodiscard]] double mean_grey() const noexcept { return mean_grey_.load(std::memory_order_relaxed); }

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
  [[nodiscard]] detector::Scene make_scene() const;
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

  // The controls, written by any thread, read by fill().
  std::atomic<double> exposure_;
  std::atomic<std::int64_t> gain_;
  std::atomic<bool> auto_gain_;
  std::atomic<double> mean_grey_{0};

  detector::Scene scene_;                                 // all but the pose, which each render sets
  detector::GreyImage clean_;                             // the last noise-free render
  double clean_mean_ = 0;                                 // its mean grey level (auto_gain's measure)
  std::optional<std::pair<double, double>> rendered_at_;  // its rail and turntable positions
  std::uint64_t renders_ = 0;
  // Sensor noise: a table of Gaussian samples (in grey levels, rounded) read
  // from a random place for each frame, so that a frame costs no random
  // number per pixel.
  std::vector<std::int8_t> noise_;
  std::uint64_t noise_state_ = 0;
};

}  // namespace markerd::daemon
