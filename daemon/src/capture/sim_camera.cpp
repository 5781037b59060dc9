#include "markerd/daemon/capture/sim_camera.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <thread>
#include <utility>

#include "markerd/detector/render.hpp"

namespace markerd::daemon {

namespace {

// 1 Mi samples: a frame up to a megapixel reads no sample twice.
constexpr std::size_t kNoiseSamples = std::size_t{1} << 20;

std::uint64_t splitmix(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ULL);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

}  // namespace

SimCameraSettings parse_sim_camera_settings(const ConfigTable& t) {
  t.allow_only({"fps",     "exposure",    "blur_sigma_px",     "noise_sigma",    "supersample",     "clutter",
                "distort", "seed",        "rail_mm",           "turntable_deg",  "outage_every_s",  "outage_s",
                "cover",   "cover_depth", "cover_reflectance", "cover_height_m", "background_grey", "ambient",
                "gain",    "auto_gain"});
  SimCameraSettings s;
  s.fps = t.optional<double>("fps", s.fps);
  if (!(s.fps > 0 && s.fps <= 1000)) t.fail("fps", fmt::format("must be > 0 and <= 1000, got {}", s.fps));
  s.exposure = t.optional<double>("exposure", s.exposure, {kSimExposureMin, kSimExposureMax});
  s.gain = t.optional<std::int64_t>("gain", s.gain, {kSimGainMin, kSimGainMax, "%"});
  if ((s.gain - kSimGainMin) % kSimGainStep != 0) {
    t.fail("gain",
           fmt::format("must be a multiple of {} % (as the gain control's steps), got {}", kSimGainStep, s.gain));
  }
  s.auto_gain = t.optional<bool>("auto_gain", s.auto_gain);
  s.blur_sigma_px = t.optional<double>("blur_sigma_px", s.blur_sigma_px);
  if (!(s.blur_sigma_px >= 0 && s.blur_sigma_px <= 20)) {
    t.fail("blur_sigma_px", fmt::format("must be 0 .. 20, got {}", s.blur_sigma_px));
  }
  s.noise_sigma = t.optional<double>("noise_sigma", s.noise_sigma);
  if (!(s.noise_sigma >= 0 && s.noise_sigma <= 40)) {
    t.fail("noise_sigma", fmt::format("must be 0 .. 40 (grey levels), got {}", s.noise_sigma));
  }
  s.supersample = t.optional<int>("supersample", s.supersample);
  if (s.supersample < 1 || s.supersample > 8)
    t.fail("supersample", fmt::format("must be 1 .. 8, got {}", s.supersample));
  s.clutter = t.optional<bool>("clutter", s.clutter);
  s.distort = t.optional<bool>("distort", s.distort);
  // The ranges are markerctl render's, where it has one.
  if (t.contains("background_grey") && s.clutter) {
    t.fail("background_grey",
           "is the plain background's grey, but clutter = true draws random shapes instead "
           "(set clutter = false, or remove background_grey)");
  }
  s.background_grey = t.optional<double>("background_grey", s.background_grey, {0, 255, "grey levels"});
  // No ambient light at all would leave a face turned away from the light black and the shading undefined.
  s.ambient = t.optional<double>("ambient", s.ambient, {0.01, 1});
  if (t.contains("cover")) {
    const toml::array* sides = t.raw().get("cover")->as_array();
    if (sides == nullptr) t.fail("cover", R"(must be a list of sides, e.g. ["left"])");
    for (const toml::node& node : *sides) {
      const auto name = node.value<std::string>();
      const auto side = name ? marker_side_from_name(*name) : std::nullopt;
      if (!side) {
        t.fail("cover", fmt::format(R"(sides are "top", "right", "bottom", "left"; got {})",
                                    name ? fmt::format("\"{}\"", *name) : std::string("a value that is not a string")));
      }
      if (std::find(s.cover.begin(), s.cover.end(), *side) != s.cover.end()) {
        t.fail("cover", fmt::format("names \"{}\" twice", *name));
      }
      s.cover.push_back(*side);
    }
  }
  for (const char* key : {"cover_depth", "cover_reflectance", "cover_height_m"}) {
    if (t.contains(key) && s.cover.empty()) {
      t.fail(key, "is set, but nothing is covered (cover = [\"left\"], ... names the sides)");
    }
  }
  s.cover_depth = t.optional<double>("cover_depth", s.cover_depth, {0.01, 1, "of the marker's size"});
  s.cover_reflectance = static_cast<float>(t.optional<double>("cover_reflectance", s.cover_reflectance, {0, 1}));
  // Above the marker's plane (a frame's band is up to a few cm high), within a metre of it.
  s.cover_height_m = t.optional<double>("cover_height_m", s.cover_height_m, {0.001, 1, "m"});
  const auto seed = t.optional<std::int64_t>("seed", 1);
  if (seed < 0) t.fail("seed", fmt::format("must be >= 0, got {}", seed));
  s.seed = static_cast<std::uint64_t>(seed);
  // The rig's own ranges: a kilometre of rail, a turn either way.
  s.rail_mm = t.optional<double>("rail_mm", s.rail_mm, {-1e6, 1e6, "mm"});
  s.turntable_deg = t.optional<double>("turntable_deg", s.turntable_deg, {-360, 360, "deg"});
  // A day is far beyond any soak; a tenth of a second is a few frames.
  const double every_s = t.optional<double>("outage_every_s", 0.0, {0, 86400, "s"});
  const double for_s = t.optional<double>("outage_s", 5.0, {0.1, 3600, "s"});
  if (every_s > 0) {
    if (for_s >= every_s) {
      t.fail("outage_s", fmt::format("must be shorter than outage_every_s ({} s), got {} s", every_s, for_s));
    }
    s.outage_every = std::chrono::milliseconds(std::llround(every_s * 1000));
    s.outage_for = std::chrono::milliseconds(std::llround(for_s * 1000));
  }
  return s;
}

std::optional<detector::MarkerSide> marker_side_from_name(std::string_view name) {
  using detector::MarkerSide;
  for (const MarkerSide side : {MarkerSide::top, MarkerSide::right, MarkerSide::bottom, MarkerSide::left}) {
    if (name == to_string(side)) return side;
  }
  return std::nullopt;
}

std::string_view to_string(detector::MarkerSide side) {
  switch (side) {
    case detector::MarkerSide::top: return "top";
    case detector::MarkerSide::right: return "right";
    case detector::MarkerSide::bottom: return "bottom";
    case detector::MarkerSide::left: return "left";
  }
  return "?";
}

SimCamera::SimCamera(SimCameraSettings settings, detector::CameraModel camera, rig::RigGeometry geometry)
    : settings_(std::move(settings)),
      camera_(camera),
      geometry_(geometry),
      exposure_(settings_.exposure),
      gain_(settings_.gain),
      auto_gain_(settings_.auto_gain),
      scene_(make_scene()) {
  if (camera_.width <= 0 || camera_.height <= 0) {
    throw CaptureError(CaptureError::Kind::config, "simulated camera: the camera model has no image size");
  }
  name_ = fmt::format("sim {}x{}@{:g}", camera_.width, camera_.height, settings_.fps);
  period_ = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(1.0 / settings_.fps));
  // The table holds whole grey levels: the rendered image is whole levels
  // too, and rounding the sum is what a sensor's converter does.
  noise_.resize(kNoiseSamples);
  std::mt19937_64 engine(settings_.seed ^ 0x6E6F697365ULL);
  std::normal_distribution<double> normal(0.0, settings_.noise_sigma);
  for (auto& sample : noise_) {
    sample = static_cast<std::int8_t>(std::clamp(std::lround(normal(engine)), -127L, 127L));
  }
  noise_state_ = settings_.seed;
}

CaptureGeometry SimCamera::geometry() const {
  return {camera_.width, camera_.height,
          static_cast<std::size_t>(camera_.width) * static_cast<std::size_t>(camera_.height), settings_.fps};
}

std::optional<std::string> SimCamera::absent() {
  if (unplugged_.load(std::memory_order_relaxed)) return "unplugged (simulated)";
  if (settings_.outage_every.count() <= 0) return std::nullopt;
  const auto age = std::chrono::steady_clock::now() - created_;
  const auto n = static_cast<std::uint64_t>(age / settings_.outage_every);  // outages begun by now
  if (n == 0 || age - settings_.outage_every * n >= settings_.outage_for) return std::nullopt;
  if (n != outage_seen_) {
    outage_seen_ = n;
    outages_.fetch_add(1, std::memory_order_relaxed);
  }
  return fmt::format("dropped out (simulated outage {}: {} s every {} s)", n,
                     std::chrono::duration<double>(settings_.outage_for).count(),
                     std::chrono::duration<double>(settings_.outage_every).count());
}

void SimCamera::open() {
  if (auto why = absent()) throw CaptureError(CaptureError::Kind::not_found, name_ + ": " + *why);
  open_ = true;
  next_frame_ = std::chrono::steady_clock::now();
}

bool SimCamera::wait_frame(std::chrono::milliseconds timeout) {
  if (!open_) throw CaptureError(CaptureError::Kind::io, name_ + ": not open");
  if (auto why = absent()) {
    open_ = false;
    throw CaptureError(CaptureError::Kind::vanished, name_ + ": " + *why);
  }
  const auto now = std::chrono::steady_clock::now();
  if (next_frame_ > now + timeout) {
    std::this_thread::sleep_for(timeout);
    return false;
  }
  std::this_thread::sleep_until(next_frame_);
  // A late frame (rendering took longer than a period) starts the next
  // period from now: the camera does not try to catch up with a burst.
  next_frame_ = std::max(next_frame_ + period_, std::chrono::steady_clock::now());
  return true;
}

void SimCamera::skip() noexcept { ++sequence_; }

detector::Scene SimCamera::make_scene() const {
  detector::Scene scene;
  scene.family = settings_.family;
  scene.id = settings_.id;
  scene.marker_size_m = settings_.marker_size_m;
  scene.cut_hole = settings_.cut_hole;
  scene.frame = settings_.frame;
  scene.insert = settings_.insert;
  scene.paper_margin_m = settings_.margin_m;
  for (const detector::MarkerSide side : settings_.cover) {
    scene.occluders.push_back(detector::side_occluder(side, settings_.marker_size_m, settings_.cover_depth,
                                                      settings_.cover_reflectance, settings_.cover_height_m));
  }
  scene.background_grey = settings_.background_grey;
  scene.ambient = settings_.ambient;
  scene.exposure = settings_.exposure;
  scene.blur_sigma_px = settings_.blur_sigma_px;
  scene.noise_sigma = 0;  // added per frame
  scene.supersample = settings_.supersample;
  scene.clutter = settings_.clutter;
  scene.distort = settings_.distort;
  scene.seed = settings_.seed;
  return scene;
}

void SimCamera::render_if_moved(double rail_mm, double turntable_deg) {
  if (rendered_at_ && rendered_at_->first == rail_mm && rendered_at_->second == turntable_deg) return;
  const rig::MarkerGroundTruth truth = rig::ground_truth(geometry_, rail_mm, turntable_deg);
  scene_.pose.rotation = truth.rotation;
  scene_.pose.translation = truth.translation;
  clean_ = detector::render_scene(camera_, scene_);
  const std::size_t pixels = static_cast<std::size_t>(clean_.width()) * static_cast<std::size_t>(clean_.height());
  std::uint64_t sum = 0;
  for (std::size_t i = 0; i < pixels; ++i) sum += clean_.data()[i];
  clean_mean_ = pixels > 0 ? static_cast<double>(sum) / static_cast<double>(pixels) : 0;
  rendered_at_ = {rail_mm, turntable_deg};
  ++renders_;
}

void SimCamera::fill(Frame& frame) {
  const double rail = frame.rig ? frame.rig->rail.position : settings_.rail_mm;
  const double turntable = frame.rig ? frame.rig->turntable.position : settings_.turntable_deg;
  // A new exposure is a new scene: rendered again, once.
  if (const double exposure = exposure_.load(std::memory_order_relaxed); exposure != scene_.exposure) {
    scene_.exposure = exposure;
    rendered_at_.reset();
  }
  try {
    render_if_moved(rail, turntable);
  } catch (const std::exception& e) {
    // A scene the renderer refuses is this frame's problem, not the
    // camera's: the frame is logged with the cause and capture goes on.
    frame.sequence = sequence_++;
    mark_corrupt(frame, "simulated camera cannot render rail {} mm, turntable {} deg: {}", rail, turntable, e.what());
    rendered_at_.reset();
    return;
  }
  frame.sequence = sequence_++;
  frame.use_pixel_buffer(clean_.width(), clean_.height());
  std::uint8_t* dst = frame.pixel_buffer().data();
  const std::uint8_t* src = clean_.data();
  const std::size_t pixels = static_cast<std::size_t>(clean_.width()) * static_cast<std::size_t>(clean_.height());
  // The gain in 1/256ths, applied before the noise as a sensor's amplifier
  // does: automatic, the one that brings the render's mean to mid-grey,
  // within the gain control's range.
  const double gain = auto_gain_.load(std::memory_order_relaxed)
                          ? std::clamp(128.0 / std::max(clean_mean_, 1.0), static_cast<double>(kSimGainMin) / 100,
                                       static_cast<double>(kSimGainMax) / 100)
                          : static_cast<double>(gain_.load(std::memory_order_relaxed)) / 100;
  const auto g = static_cast<int>(std::lround(gain * 256));
  std::uint64_t sum = 0;
  // Stamped when the image is complete, as a driver stamps a frame at the
  // end of its readout: the simulated sensor's work is not the pipeline's.
  if (settings_.noise_sigma <= 0) {
    for (std::size_t i = 0; i < pixels; ++i) {
      const int v = std::min((src[i] * g + 128) >> 8, 255);
      dst[i] = static_cast<std::uint8_t>(v);
      sum += static_cast<std::uint64_t>(v);
    }
  } else {
    // In runs that do not wrap around the table, so that the loop body is
    // plain element-wise arithmetic the compiler vectorises.
    std::size_t at = splitmix(noise_state_) & (noise_.size() - 1);
    for (std::size_t done = 0; done < pixels;) {
      const std::size_t run = std::min(pixels - done, noise_.size() - at);
      const std::uint8_t* s = src + done;
      const std::int8_t* n = noise_.data() + at;
      std::uint8_t* d = dst + done;
      for (std::size_t i = 0; i < run; ++i) {
        const int v = std::clamp(((s[i] * g + 128) >> 8) + n[i], 0, 255);
        d[i] = static_cast<std::uint8_t>(v);
        sum += static_cast<std::uint64_t>(v);
      }
      done += run;
      at = 0;
    }
  }
  mean_grey_.store(static_cast<double>(sum) / static_cast<double>(pixels), std::memory_order_relaxed);
  frame.capture_time = std::chrono::steady_clock::now();
}

std::vector<CameraControlInfo> SimCamera::read_controls() {
  const bool automatic = auto_gain_.load(std::memory_order_relaxed);
  std::vector<CameraControlInfo> controls(4);
  CameraControlInfo& auto_gain = controls[0];
  auto_gain.name = "auto_gain";
  auto_gain.type = "bool";
  auto_gain.kind = ControlKind::boolean;
  auto_gain.value = automatic;
  auto_gain.minimum = false;
  auto_gain.maximum = true;
  auto_gain.default_value = settings_.auto_gain;

  CameraControlInfo& exposure = controls[1];
  exposure.name = "exposure";
  exposure.type = "float";
  exposure.kind = ControlKind::real;
  exposure.value = exposure_.load(std::memory_order_relaxed);
  exposure.minimum = kSimExposureMin;
  exposure.maximum = kSimExposureMax;
  exposure.default_value = settings_.exposure;

  CameraControlInfo& gain = controls[2];
  gain.name = "gain";
  gain.type = "int";
  gain.kind = ControlKind::integer;
  gain.value = gain_.load(std::memory_order_relaxed);
  gain.minimum = kSimGainMin;
  gain.maximum = kSimGainMax;
  gain.step = kSimGainStep;
  gain.default_value = settings_.gain;
  if (automatic) gain.flags.emplace_back("inactive");

  // The noise table is drawn once, when the camera is made.
  CameraControlInfo& noise = controls[3];
  noise.name = "noise_sigma";
  noise.type = "float";
  noise.kind = ControlKind::real;
  noise.value = settings_.noise_sigma;
  noise.minimum = 0.0;
  noise.maximum = 40.0;
  noise.default_value = settings_.noise_sigma;
  noise.flags.emplace_back("read-only");
  for (std::uint32_t i = 0; i < controls.size(); ++i) controls[i].id = i + 1;
  return controls;
}

void SimCamera::write_control(const CameraControlInfo& control, const ControlValue& value) {
  if (control.name == "exposure" && std::holds_alternative<double>(value)) {
    exposure_.store(std::get<double>(value), std::memory_order_relaxed);
  } else if (control.name == "gain" && std::holds_alternative<std::int64_t>(value)) {
    gain_.store(std::get<std::int64_t>(value), std::memory_order_relaxed);
  } else if (control.name == "auto_gain" && std::holds_alternative<bool>(value)) {
    auto_gain_.store(std::get<bool>(value), std::memory_order_relaxed);
  } else {
    throw CaptureError(CaptureError::Kind::config,
                       fmt::format("{}: control {} cannot take {}", name_, control.name, to_text(value)));
  }
}

}  // namespace markerd::daemon
