// The pipeline allocates nothing per frame once running: rendered frames go
// through two frame8 workers and the log stage while every global allocation,
// on any thread, is counted. The frames lend their pixels (as a V4L2 mmap
// buffer would), so the sink also checks that no stage copied them.
// A binary of its own: it replaces the global operator new.

#include <gtest/gtest.h>

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <thread>
#include <vector>

#include "markerd/daemon/latest_frame.hpp"
#include "markerd/daemon/pipeline.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"

#include "counting_new.hpp"

namespace markerd::daemon {
namespace {

// Counts frames and detections without allocating, and notices a frame
// whose pixels are not the ones its source lent.
class CountingSink : public FrameSink {
 public:
  explicit CountingSink(const std::vector<detector::GreyImage>& images) : images_(images) {}
  void write(const Frame& frame) override {
    const detector::GreyImage& lent = images_[frame.sequence % images_.size()];
    if (frame.image.data != lent.data()) copied_.fetch_add(1, std::memory_order_relaxed);
    if (frame.status != FrameStatus::ok) failed_.fetch_add(1, std::memory_order_relaxed);
    detections_.fetch_add(frame.detections.size(), std::memory_order_relaxed);
    written_.fetch_add(1, std::memory_order_release);
    written_.notify_all();
  }
  void wait_for(std::uint64_t count) {
    for (std::uint64_t n = written_.load(std::memory_order_acquire); n < count;
         n = written_.load(std::memory_order_acquire)) {
      written_.wait(n, std::memory_order_acquire);
    }
  }
  std::atomic<std::uint64_t> detections_{0};
  std::atomic<std::uint64_t> copied_{0};
  std::atomic<std::uint64_t> failed_{0};

 private:
  const std::vector<detector::GreyImage>& images_;
  std::atomic<std::uint64_t> written_{0};
};

struct ReleaseCount {
  static void on_release(void* context, std::uint64_t) noexcept {
    static_cast<std::atomic<std::uint64_t>*>(context)->fetch_add(1, std::memory_order_relaxed);
  }
};

TEST(PipelineNoAllocation, SteadyStateFramesThroughFrame8WorkersAllocateNothing) {
  const detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  std::vector<detector::GreyImage> images;
  for (int k = 0; k < 6; ++k) {
    detector::Scene scene;
    scene.id = 23 * k + 9;
    scene.pose = detector::facing_pose(0.35 + 0.25 * k, -30 + 12.0 * k, 0, 9.0 * k);
    scene.supersample = 2;
    scene.noise_sigma = 2;
    scene.blur_sigma_px = 0.6;
    scene.seed = static_cast<std::uint64_t>(k + 1);
    images.push_back(detector::render_scene(camera, scene));
  }
  CountingSink sink(images);
  std::atomic<std::uint64_t> released{0};
  std::vector<std::unique_ptr<detector::MarkerDetector>> workers;
  for (int i = 0; i < 2; ++i) workers.push_back(detector::make_detector(detector::DetectorConfig{}));
  PipelineConfig config;
  config.policy = DropPolicy::lossless;  // every frame detected: the same work in each run
  config.pool.slots = 4;
  Pipeline pipeline(config, std::move(workers), sink);

  std::uint64_t sequence = 0;
  auto run = [&](int rounds) {
    for (int r = 0; r < rounds; ++r) {
      for (std::size_t i = 0; i < images.size(); ++i, ++sequence) {
        Frame* frame = pipeline.acquire();
        if (frame == nullptr) return;
        frame->sequence = sequence;
        frame->capture_time = Clock::now();
        frame->image = images[sequence % images.size()];
        frame->set_release({&ReleaseCount::on_release, &released, sequence});
        pipeline.publish(*frame);
      }
    }
    sink.wait_for(sequence);
  };
  // Warm-up: each worker's detector grows its buffers on the frames it will
  // see again (frames alternate between the workers in a fixed rotation).
  run(2);
  const std::uint64_t detections_before = sink.detections_.load();
  g_allocations = 0;
  g_counting = true;
  run(5);
  g_counting = false;
  const long allocations = g_allocations.load();
  pipeline.stop();

  EXPECT_EQ(allocations, 0);
  EXPECT_GT(sink.detections_.load(), detections_before) << "the frames hold markers; finding none proves nothing";
  EXPECT_EQ(sink.copied_.load(), 0U) << "a frame reached the log with pixels other than its source's";
  EXPECT_EQ(sink.failed_.load(), 0U);
  EXPECT_EQ(released.load(), sequence);
  EXPECT_EQ(pipeline.stats().pool_free, 4U);
}

// The log stage's offer of each frame to the newest-frame slot (the
// snapshot, the web page) copies it into buffers that grew on the first
// frames, while a reader takes and drops the copies.
TEST(PipelineNoAllocation, OfferingFramesToTheNewestFrameSlotAllocatesNothing) {
  const detector::GreyImage image(640, 480, 77);
  std::vector<detector::Detection> detections(3);
  FrameRecordInput record;
  record.detections = detections;
  record.rig = rig::RigSnapshot{};
  record.truth = rig::MarkerGroundTruth{};
  LatestFrameSettings settings;
  settings.watched_interval = std::chrono::milliseconds(0);
  settings.unwatched_interval = std::chrono::milliseconds(0);
  LatestFrame slot(settings);
  for (std::uint64_t seq = 0; seq < 2 * settings.buffers; ++seq) {  // every buffer grows once
    record.sequence = seq;
    slot.offer(record, image);
    (void)slot.latest();
  }
  g_allocations = 0;
  g_counting = true;
  for (std::uint64_t seq = 100; seq < 400; ++seq) {
    record.sequence = seq;
    slot.offer(record, image);
    const std::shared_ptr<const HeldFrame> held = slot.latest();
    if (held->sequence != seq) break;
  }
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 0);
  EXPECT_EQ(slot.latest()->sequence, 399U);
  EXPECT_EQ(slot.stats().busy, 0U);
}

// The counter itself works, on another thread too.
TEST(PipelineNoAllocation, CounterSeesAllocationsOnAnyThread) {
  g_allocations = 0;
  g_counting = true;
  std::thread([] { const auto v = std::make_unique<std::vector<int>>(1000); }).join();
  g_counting = false;
  EXPECT_GE(g_allocations.load(), 2);
}

}  // namespace
}  // namespace markerd::daemon
