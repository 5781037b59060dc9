// The detector allocates nothing per frame once warmed up: every global
// allocation is counted while it runs.

#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>
#include <vector>

#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"

#include "counting_new.hpp"

namespace markerd::detector {
namespace {

std::vector<GreyImage> frames(const CameraModel& cam) {
  std::vector<GreyImage> out;
  for (int k = 0; k < 12; ++k) {
    Scene s;
    s.id = 11 * k + 5;
    s.pose = facing_pose(0.3 + 0.2 * k, -50 + 9.0 * k, 0, 13.0 * k, 0.01 * (k % 3), 0);
    s.noise_sigma = 2;
    s.blur_sigma_px = 0.6;
    s.supersample = 2;
    s.seed = static_cast<std::uint64_t>(k + 1);
    out.push_back(render_scene(cam, s));
  }
  return out;
}

long allocations_in_steady_state(MarkerDetector& det, const std::vector<GreyImage>& images) {
  std::vector<Detection> out;
  out.reserve(64);
  for (const auto& img : images) det.detect(img, out);  // warm-up: buffers grow to size
  g_allocations = 0;
  g_counting = true;
  int found = 0;
  for (int round = 0; round < 3; ++round) {
    for (const auto& img : images) {
      det.detect(img, out);
      found += static_cast<int>(out.size());
    }
  }
  g_counting = false;
  EXPECT_GT(found, 0) << "the frames hold markers; a detector that finds none proves nothing";
  return g_allocations.load();
}

TEST(NoAllocation, Frame8WithoutPose) {
  const CameraModel cam = CameraModel::thesis_640x480();
  auto det = make_detector(DetectorConfig{});
  EXPECT_EQ(allocations_in_steady_state(*det, frames(cam)), 0);
}

TEST(NoAllocation, Frame8WithPose) {
  const CameraModel cam = CameraModel::thesis_640x480();
  DetectorConfig cfg;
  cfg.camera = cam;
  cfg.marker_size_m = 0.08;
  auto det = make_detector(cfg);
  EXPECT_EQ(allocations_in_steady_state(*det, frames(cam)), 0);
}

// The far frames and the white cells of the near markers (small light
// squares in a dark surround) send candidates through the ring model, and
// three markers at 2.9 m (cells of 1.4 px) through the model's own look,
// taken where the other looks found nothing: it reads the first, and
// nothing in the other two.
TEST(NoAllocation, Frame8WithTheRingModel) {
  const CameraModel cam = CameraModel::thesis_640x480();
  DetectorConfig cfg;
  cfg.camera = cam;
  cfg.marker_size_m = 0.08;
  cfg.frame8.model_small_cells = true;
  auto det = make_detector(cfg);
  std::vector<GreyImage> images = frames(cam);
  for (const int k : {6, 8, 12}) {
    Scene s;
    s.id = 1 + (k * 37) % 254;
    const double shift_px = (k % 7) * 6 - 18;
    s.pose = facing_pose(2.9, 0, 0, -5 + k % 10, shift_px * 2.9 / cam.fx, -shift_px * 2.9 / cam.fy);
    s.noise_sigma = 2;
    s.blur_sigma_px = 0.6;
    s.clutter = true;
    s.seed = static_cast<std::uint64_t>(500 + k);
    images.push_back(render_scene(cam, s));
  }
  DetectorConfig sampled_only = cfg;
  sampled_only.frame8.model_small_cells = false;
  std::vector<Detection> by_model, by_sampling;
  det->detect(images[images.size() - 3], by_model);
  make_detector(sampled_only)->detect(images[images.size() - 3], by_sampling);
  ASSERT_EQ(by_model.size(), 1U) << "the frame the model's look reads";
  ASSERT_TRUE(by_sampling.empty()) << "the frame the model's look reads";
  EXPECT_EQ(allocations_in_steady_state(*det, images), 0);
}

TEST(NoAllocation, Frame8AtHighResolution) {
  const CameraModel cam = CameraModel::thesis_640x480().scaled_to(1920, 1440);
  auto det = make_detector(DetectorConfig{});
  EXPECT_EQ(allocations_in_steady_state(*det, frames(cam)), 0);
}

// The counter itself works: a vector that grows is seen.
TEST(NoAllocation, CounterSeesAllocations) {
  g_allocations = 0;
  g_counting = true;
  std::vector<int> v;
  v.resize(1000);
  g_counting = false;
  EXPECT_GE(g_allocations.load(), 1);
}

}  // namespace
}  // namespace markerd::detector
