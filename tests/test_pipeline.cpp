// The frame pipeline: the pool, the live and lossless policies, order
// restored over several workers, shutdown with frames in flight, release
// hooks, failures, counters and latency histograms. Slow stages are made
// with detectors and sinks that block on a gate the test opens, never with
// sleeps; waits on the pipeline have generous timeouts.

#include "markerd/daemon/pipeline.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <semaphore>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;
constexpr auto kPatience = 60s;  // for a loaded 2-core machine under ASan

// A door a stage waits at until the test opens it.
class Gate {
 public:
  void open() {
    {
      const std::lock_guard lock(mutex_);
      open_ = true;
    }
    cv_.notify_all();
  }
  void pass() {
    std::unique_lock lock(mutex_);
    cv_.wait(lock, [&] { return open_; });
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  bool open_ = false;
};

// Test frames are 4x4 images whose first two pixels hold the frame's number;
// the test detectors report it as the detection id, so the sink sees which
// pixels a worker actually read.
std::vector<detector::GreyImage> numbered_images(int count) {
  std::vector<detector::GreyImage> images;
  for (int k = 0; k < count; ++k) {
    detector::GreyImage image(4, 4, 0);
    image.at(0, 0) = static_cast<std::uint8_t>(k % 256);
    image.at(1, 0) = static_cast<std::uint8_t>(k / 256);
    images.push_back(std::move(image));
  }
  return images;
}

int number_in(const detector::GreyView& image) { return image.at(0, 0) + 256 * image.at(1, 0); }

// Reads the number; optionally announces each call and waits at a gate
// first, and optionally opens another gate when done (to force an order).
class NumberDetector : public detector::MarkerDetector {
 public:
  Gate* gate = nullptr;
  std::counting_semaphore<1000>* entered = nullptr;
  Gate* open_when_done = nullptr;
  int busy_work = 0;  // multiplies a pixel sum, to vary the workers' pace

  [[nodiscard]] detector::Family family() const override { return detector::Family::frame8; }
  void detect(const detector::GreyView& image, std::vector<detector::Detection>& out) override {
    if (entered != nullptr) entered->release();
    if (gate != nullptr) gate->pass();
    if (image.empty()) throw detector::DetectorError("frame8: empty image");
    out.clear();
    detector::Detection d;
    d.id = number_in(image);
    volatile unsigned sum = 0;
    for (int k = 0; k < busy_work * (d.id % 7); ++k) sum = sum + image.at(k % 4, (k / 4) % 4);
    out.push_back(d);
    if (open_when_done != nullptr) open_when_done->open();
  }
};

std::vector<std::unique_ptr<detector::MarkerDetector>> detectors(std::vector<NumberDetector*> handles) {
  std::vector<std::unique_ptr<detector::MarkerDetector>> out;
  for (NumberDetector* d : handles) out.emplace_back(d);
  return out;
}

// `count` detectors that each announce a frame at `entered`, then wait at
// `gate`: the test holds the workers with frames in hand.
std::vector<std::unique_ptr<detector::MarkerDetector>> gated_detectors(std::size_t count, Gate& gate,
                                                                       std::counting_semaphore<1000>& entered) {
  std::vector<std::unique_ptr<detector::MarkerDetector>> out;
  for (std::size_t i = 0; i < count; ++i) {
    auto detector = std::make_unique<NumberDetector>();
    detector->gate = &gate;
    detector->entered = &entered;
    out.push_back(std::move(detector));
  }
  return out;
}

struct Written {
  std::uint64_t sequence;
  FrameStatus status;
  std::string cause;
  std::vector<int> ids;
};

class RecordingSink : public FrameSink {
 public:
  Gate* gate = nullptr;
  std::counting_semaphore<1000>* entered = nullptr;
  std::optional<std::uint64_t> throw_on;

  void write(const Frame& frame) override {
    if (entered != nullptr) entered->release();
    if (gate != nullptr) gate->pass();
    Written w{frame.sequence, frame.status, std::string(frame.cause()), {}};
    for (const auto& d : frame.detections) w.ids.push_back(d.id);
    {
      const std::lock_guard lock(mutex_);
      written_.push_back(std::move(w));
    }
    cv_.notify_all();
    if (throw_on && *throw_on == frame.sequence) throw std::runtime_error("disk full");
  }
  // The frames written so far, once there are at least `count`.
  std::vector<Written> wait_for(std::size_t count) {
    std::unique_lock lock(mutex_);
    EXPECT_TRUE(cv_.wait_for(lock, kPatience, [&] { return written_.size() >= count; }))
        << "only " << written_.size() << " of " << count << " frames written";
    return written_;
  }
  std::vector<std::uint64_t> sequences() {
    const std::lock_guard lock(mutex_);
    std::vector<std::uint64_t> s;
    for (const auto& w : written_) s.push_back(w.sequence);
    return s;
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Written> written_;
};

// Counts each frame's release-hook calls, by sequence.
struct Releases {
  explicit Releases(std::size_t frames) : counts(frames) {}
  static void on_release(void* context, std::uint64_t sequence) noexcept {
    static_cast<Releases*>(context)->counts[sequence].fetch_add(1);
  }
  std::vector<std::atomic<int>> counts;
};

// Plays a capture source that lends its pixels: acquire, fill, publish.
// False when the pipeline dropped the frame at acquire.
bool offer(Pipeline& pipeline, const std::vector<detector::GreyImage>& images, Releases& releases,
           std::uint64_t sequence) {
  Frame* frame = pipeline.acquire();
  if (frame == nullptr) return false;
  frame->sequence = sequence;
  frame->source_id = 7;
  frame->image = images.at(sequence);
  frame->set_release({&Releases::on_release, &releases, sequence});
  pipeline.publish(*frame);
  return true;
}

PipelineConfig config(DropPolicy policy, std::size_t slots) {
  PipelineConfig c;
  c.policy = policy;
  c.pool.slots = slots;
  return c;
}

// Waits until the pipeline's figures satisfy `done`.
template <class Pred>
bool wait_for_stats(const Pipeline& pipeline, Pred done) {
  const auto deadline = std::chrono::steady_clock::now() + kPatience;
  while (!done(pipeline.stats())) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

void expect_balanced(const PipelineStats& s) {
  EXPECT_EQ(s.capture.in, s.capture.out + s.capture.dropped);
  EXPECT_EQ(s.capture.out, s.detect.out + s.detect.dropped);
  EXPECT_EQ(s.detect.out, s.log.in);
  EXPECT_EQ(s.log.in, s.log.out + s.log.failed);
  EXPECT_EQ(s.pool_free, s.pool_slots);
}

void expect_each_released_once(const Releases& releases, std::size_t frames) {
  for (std::size_t k = 0; k < frames; ++k) EXPECT_EQ(releases.counts[k].load(), 1) << "frame " << k;
}

// ---- the pool ----

TEST(FramePool, HandsOutEverySlotOnceWithItsOwnAlignedPixels) {
  FramePool pool({.slots = 3, .pixel_bytes = 100, .detections = 5});
  EXPECT_EQ(pool.size(), 3U);
  EXPECT_EQ(pool.available(), 3U);
  std::vector<Frame*> taken;
  while (Frame* f = pool.try_acquire()) taken.push_back(f);
  ASSERT_EQ(taken.size(), 3U);
  EXPECT_EQ(pool.available(), 0U);
  for (std::size_t i = 0; i < taken.size(); ++i) {
    EXPECT_TRUE(pool.owns(*taken[i]));
    EXPECT_EQ(taken[i]->pixel_buffer().size(), 100U);
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(taken[i]->pixel_buffer().data()) % kCacheLineBytes, 0U);
    EXPECT_GE(taken[i]->detections.capacity(), 5U);
    for (std::size_t j = 0; j < i; ++j) EXPECT_NE(taken[i]->pixel_buffer().data(), taken[j]->pixel_buffer().data());
  }
  Frame stranger;
  EXPECT_FALSE(pool.owns(stranger));
  for (Frame* f : taken) pool.release(*f);
  EXPECT_EQ(pool.available(), 3U);
  EXPECT_THROW(FramePool({.slots = 0}), std::invalid_argument);
}

TEST(FramePool, ReleaseRunsTheHookOnceAndAcquireResetsTheSlot) {
  FramePool pool({.slots = 1, .pixel_bytes = 16});
  Releases releases(1);
  Frame* f = pool.try_acquire();
  ASSERT_NE(f, nullptr);
  f->sequence = 42;
  f->set_cause("broken MJPEG");
  f->status = FrameStatus::corrupt_frame;
  f->detections.resize(3);
  EXPECT_THROW(f->use_pixel_buffer(5, 4), std::length_error);
  const detector::GreyView view = f->use_pixel_buffer(4, 4);
  EXPECT_EQ(view.data, f->pixel_buffer().data());
  f->set_release({&Releases::on_release, &releases, 0});
  pool.release(*f);
  EXPECT_EQ(releases.counts[0].load(), 1);
  Frame* again = pool.try_acquire();
  ASSERT_EQ(again, f);
  EXPECT_EQ(again->sequence, 0U);
  EXPECT_EQ(again->status, FrameStatus::ok);
  EXPECT_TRUE(again->cause().empty());
  EXPECT_TRUE(again->detections.empty());
  EXPECT_GE(again->detections.capacity(), 3U);
  EXPECT_FALSE(again->has_release());
  again->release_source();
  EXPECT_EQ(releases.counts[0].load(), 1);
  pool.release(*again);
}

TEST(FramePool, ACauseIsCutToItsCapacity) {
  Frame f;
  f.set_cause(std::string(Frame::kCauseCapacity + 50, 'x'));
  EXPECT_EQ(f.cause().size(), Frame::kCauseCapacity);
}

// ---- lossless ----

TEST(Pipeline, LosslessDeliversEveryFrameInOrderWithSeveralWorkers) {
  constexpr int kFrames = 600;
  const auto images = numbered_images(kFrames);
  Releases releases(kFrames);
  RecordingSink sink;
  std::vector<NumberDetector*> workers;
  for (int i = 0; i < 3; ++i) {
    workers.push_back(new NumberDetector);
    workers.back()->busy_work = 2000 * (i + 1);  // the workers finish out of step
  }
  Pipeline pipeline(config(DropPolicy::lossless, 5), detectors(workers), sink);
  for (int k = 0; k < kFrames; ++k) ASSERT_TRUE(offer(pipeline, images, releases, k));
  const auto written = sink.wait_for(kFrames);
  pipeline.stop();
  ASSERT_EQ(written.size(), static_cast<std::size_t>(kFrames));
  for (int k = 0; k < kFrames; ++k) {
    EXPECT_EQ(written[k].sequence, static_cast<std::uint64_t>(k));
    EXPECT_EQ(written[k].ids, std::vector<int>{k}) << "frame " << k << " carries another frame's detections";
  }
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.capture.out, static_cast<std::uint64_t>(kFrames));
  EXPECT_EQ(s.detect.in, static_cast<std::uint64_t>(kFrames));
  EXPECT_EQ(s.log.out, static_cast<std::uint64_t>(kFrames));
  EXPECT_EQ(s.dropped(), 0U);
  EXPECT_EQ(s.capture_to_log.count, static_cast<std::uint64_t>(kFrames));
  expect_balanced(s);
  expect_each_released_once(releases, kFrames);
}

// Frame 1 is made to finish before frame 0; the log still writes 0 first.
TEST(Pipeline, LosslessRestoresOrderWhenALaterFrameFinishesFirst) {
  const auto images = numbered_images(4);
  Releases releases(4);
  RecordingSink sink;
  Gate first_done;
  auto* slow = new NumberDetector;
  auto* fast = new NumberDetector;
  slow->gate = &first_done;            // worker 0 waits on frame 0...
  fast->open_when_done = &first_done;  // ...until worker 1 has finished frame 1
  Pipeline pipeline(config(DropPolicy::lossless, 4), detectors({slow, fast}), sink);
  for (int k = 0; k < 4; ++k) ASSERT_TRUE(offer(pipeline, images, releases, k));
  sink.wait_for(4);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2, 3}));
  expect_balanced(pipeline.stats());
  expect_each_released_once(releases, 4);
}

TEST(Pipeline, LosslessCaptureWaitsForAFreeSlot) {
  const auto images = numbered_images(3);
  Releases releases(3);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(DropPolicy::lossless, 2), gated_detectors(1, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  ASSERT_TRUE(offer(pipeline, images, releases, 1));
  ASSERT_EQ(pipeline.stats().pool_free, 0U);
  // The capture role moves to a thread that blocks in acquire until a slot frees up.
  std::atomic<bool> got_slot{false};
  std::jthread capture([&](const std::stop_token&) { got_slot = offer(pipeline, images, releases, 2); });
  gate.open();
  capture.join();
  EXPECT_TRUE(got_slot);
  sink.wait_for(3);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2}));
  EXPECT_EQ(pipeline.stats().dropped(), 0U);
  expect_each_released_once(releases, 3);
}

TEST(Pipeline, LosslessAcquireGivesUpWhenItsCaptureIsStopped) {
  const auto images = numbered_images(2);
  Releases releases(2);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(DropPolicy::lossless, 1), gated_detectors(1, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  Frame not_a_slot;
  Frame* got = &not_a_slot;
  std::jthread capture([&](const std::stop_token& stop) { got = pipeline.acquire(stop); });
  capture.request_stop();
  capture.join();
  EXPECT_EQ(got, nullptr);
  gate.open();
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0}));
  EXPECT_EQ(pipeline.stats().pool_free, 1U);
}

// ---- live ----

// A camera faster than detection: the frame waiting for the worker is
// replaced by each newer one, so the worker's next frame is the newest.
TEST(Pipeline, LiveKeepsOnlyTheNewestFrameWaitingAndCountsTheDrops) {
  const auto images = numbered_images(6);
  Releases releases(6);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(DropPolicy::live, 4), gated_detectors(1, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));    // frame 0 is in the detector, which is stuck
  ASSERT_TRUE(offer(pipeline, images, releases, 1));  // waits, with slots to spare
  for (int k = 2; k <= 5; ++k) {
    ASSERT_TRUE(offer(pipeline, images, releases, k)) << "live capture never waits";
    EXPECT_EQ(releases.counts[k - 1].load(), 1) << "frame " << k - 1 << " was waiting: dropped, its buffer given back";
    EXPECT_EQ(releases.counts[k].load(), 0) << "frame " << k;
  }
  EXPECT_EQ(releases.counts[0].load(), 0);
  PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.detect.dropped, 4U);
  EXPECT_EQ(s.capture.dropped, 0U);
  EXPECT_EQ(s.pool_free, 2U) << "one frame detecting, one waiting: the rest of the pool is never needed";
  gate.open();
  sink.wait_for(2);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 5}));
  s = pipeline.stats();
  EXPECT_EQ(s.dropped(), 4U);
  expect_balanced(s);
  expect_each_released_once(releases, 6);
}

// With two workers each keeps its own newest waiting frame; the dropped
// frames' places keep the log's order right.
TEST(Pipeline, LiveKeepsEachWorkersNewestFrameAndTheOrder) {
  const auto images = numbered_images(8);
  Releases releases(8);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(DropPolicy::live, 6), gated_detectors(2, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(offer(pipeline, images, releases, 1));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));                                 // both workers are stuck
  for (int k = 2; k <= 3; ++k) ASSERT_TRUE(offer(pipeline, images, releases, k));  // one waiting for each
  for (int k = 4; k <= 7; ++k) {
    ASSERT_TRUE(offer(pipeline, images, releases, k));
    EXPECT_EQ(releases.counts[k - 2].load(), 1) << "frame " << k - 2 << " waited for the same worker: dropped";
  }
  gate.open();
  sink.wait_for(4);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 6, 7}));
  for (const auto& w : sink.wait_for(4)) EXPECT_EQ(w.ids, std::vector<int>{static_cast<int>(w.sequence)});
  EXPECT_EQ(pipeline.stats().detect.dropped, 4U);
  expect_balanced(pipeline.stats());
  expect_each_released_once(releases, 8);
}

// No slot free and nothing waiting for the worker the new frame goes to:
// the oldest frame waiting for another worker gives its slot.
TEST(Pipeline, LiveTakesTheOldestWaitingSlotWhenThePoolIsEmpty) {
  const auto images = numbered_images(5);
  Releases releases(5);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(DropPolicy::live, 3), gated_detectors(2, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(offer(pipeline, images, releases, 1));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));    // both workers are stuck
  ASSERT_TRUE(offer(pipeline, images, releases, 2));  // the last slot, waiting for worker 0
  ASSERT_TRUE(offer(pipeline, images, releases, 3));  // for worker 1: takes frame 2's slot
  EXPECT_EQ(releases.counts[2].load(), 1);
  ASSERT_TRUE(offer(pipeline, images, releases, 4));  // for worker 0: takes frame 3's
  EXPECT_EQ(releases.counts[3].load(), 1);
  gate.open();
  sink.wait_for(3);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 4}));
  for (const auto& w : sink.wait_for(3)) EXPECT_EQ(w.ids, std::vector<int>{static_cast<int>(w.sequence)});
  EXPECT_EQ(pipeline.stats().detect.dropped, 2U);
  expect_balanced(pipeline.stats());
  expect_each_released_once(releases, 5);
}

// Every slot past detection (one in the sink, one waiting for it): nothing
// waits that could be dropped, so the new frame itself is refused.
TEST(Pipeline, LiveRefusesTheNewFrameWhenNoFrameWaitsForDetection) {
  const auto images = numbered_images(3);
  Releases releases(3);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  sink.gate = &gate;
  sink.entered = &entered;
  Pipeline pipeline(config(DropPolicy::live, 2), detectors({new NumberDetector}), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  ASSERT_TRUE(offer(pipeline, images, releases, 1));
  ASSERT_TRUE(wait_for_stats(pipeline, [](const PipelineStats& s) { return s.detect.out == 2; }));
  EXPECT_FALSE(offer(pipeline, images, releases, 2));
  EXPECT_EQ(pipeline.stats().capture.dropped, 1U);
  gate.open();
  sink.wait_for(2);
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1}));
  expect_balanced(pipeline.stats());
  EXPECT_EQ(releases.counts[2].load(), 0) << "a refused frame was never the pipeline's";
}

// ---- shutdown ----

// stop() while both workers are stuck and four frames were offered after
// theirs: live has dropped two and discards the two waiting, lossless
// detects all four; every slot comes back either way.
void stop_with_frames_in_flight(DropPolicy policy, const std::vector<std::uint64_t>& expected_written) {
  const auto images = numbered_images(6);
  Releases releases(6);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  Pipeline pipeline(config(policy, 6), gated_detectors(2, gate, entered), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  ASSERT_TRUE(offer(pipeline, images, releases, 1));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  for (int k = 2; k < 6; ++k) ASSERT_TRUE(offer(pipeline, images, releases, k));
  // The workers are asked to stop while their detectors are stuck; they
  // finish the frame in hand, then drain or discard the rest.
  pipeline.request_stop();
  gate.open();
  pipeline.stop();
  EXPECT_EQ(sink.sequences(), expected_written);
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.pool_free, 6U);
  EXPECT_EQ(s.log.out, expected_written.size());
  EXPECT_EQ(s.detect.dropped, 6 - expected_written.size());
  expect_balanced(s);
  expect_each_released_once(releases, 6);
  EXPECT_EQ(pipeline.acquire(), nullptr) << "a stopped pipeline takes no frames";
}

TEST(Pipeline, LiveStopDiscardsWaitingFramesAndReturnsEverySlot) {
  stop_with_frames_in_flight(DropPolicy::live, {0, 1});
}

TEST(Pipeline, LosslessStopDrainsEveryFrameAndReturnsEverySlot) {
  stop_with_frames_in_flight(DropPolicy::lossless, {0, 1, 2, 3, 4, 5});
}

TEST(Pipeline, AnAbandonedFrameIsReleasedOnceAndItsSlotReused) {
  Releases releases(1);
  RecordingSink sink;
  for (DropPolicy policy : {DropPolicy::live, DropPolicy::lossless}) {
    releases.counts[0] = 0;
    Pipeline pipeline(config(policy, 1), detectors({new NumberDetector}), sink);
    Frame* frame = pipeline.acquire();
    ASSERT_NE(frame, nullptr);
    frame->set_release({&Releases::on_release, &releases, 0});
    pipeline.abandon(*frame);
    EXPECT_EQ(releases.counts[0].load(), 1);
    EXPECT_EQ(pipeline.acquire(), frame) << "the only slot is free again";
    pipeline.abandon(*frame);
    pipeline.stop();
    EXPECT_EQ(releases.counts[0].load(), 1);
    EXPECT_EQ(pipeline.stats().pool_free, 1U);
    EXPECT_EQ(pipeline.stats().capture.in, 0U) << "an abandoned frame was never offered";
  }
}

// ---- failures ----

TEST(Pipeline, DetectorErrorsAndCorruptFramesReachTheLogWithTheirCause) {
  const auto images = numbered_images(1);
  RecordingSink sink;
  Pipeline pipeline(config(DropPolicy::lossless, 2), detectors({new NumberDetector}), sink);
  Frame* frame = pipeline.acquire();
  ASSERT_NE(frame, nullptr);
  frame->sequence = 0;  // no image: the detector throws
  pipeline.publish(*frame);
  frame = pipeline.acquire();
  ASSERT_NE(frame, nullptr);
  frame->sequence = 1;
  frame->image = images[0];
  frame->status = FrameStatus::corrupt_frame;
  frame->set_cause("/dev/video0: MJPEG frame 1 ends early");
  pipeline.publish(*frame);
  const auto written = sink.wait_for(2);
  pipeline.stop();
  ASSERT_EQ(written.size(), 2U);
  EXPECT_EQ(written[0].status, FrameStatus::detector_error);
  EXPECT_EQ(written[0].cause, "frame8: empty image");
  EXPECT_EQ(written[1].status, FrameStatus::corrupt_frame);
  EXPECT_EQ(written[1].cause, "/dev/video0: MJPEG frame 1 ends early");
  EXPECT_TRUE(written[1].ids.empty()) << "a corrupt frame is not detected";
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.detect.failed, 2U);
  EXPECT_EQ(s.detect_duration.count, 1U) << "the detector ran on the first frame only";
  expect_balanced(s);
}

// ---- encoded frames ----

// A test codec: a frame's two encoded bytes are its number; anything else
// is broken. Counts its calls.
std::atomic<int> decodes{0};
void decode_number(Frame& frame) noexcept {
  decodes.fetch_add(1);
  const auto data = frame.encoded();
  if (data.size() != 2) {
    frame.image = {};
    frame.status = FrameStatus::corrupt_frame;
    frame.set_cause("test codec: not two bytes");
    return;
  }
  std::span<std::uint8_t> pixels = frame.pixel_buffer();
  std::fill(pixels.begin(), pixels.end(), std::uint8_t{0});
  pixels[0] = data[0];
  pixels[1] = data[1];
}

// Plays a source that lends its frames encoded (as MJPEG is).
bool offer_encoded(Pipeline& pipeline, const std::vector<std::vector<std::uint8_t>>& payloads, Releases& releases,
                   std::uint64_t sequence) {
  Frame* frame = pipeline.acquire();
  if (frame == nullptr) return false;
  frame->sequence = sequence;
  frame->use_pixel_buffer(4, 4);
  frame->set_encoded(payloads.at(sequence), &decode_number);
  frame->set_release({&Releases::on_release, &releases, sequence});
  pipeline.publish(*frame);
  return true;
}

std::vector<std::vector<std::uint8_t>> numbered_payloads(int count) {
  std::vector<std::vector<std::uint8_t>> payloads;
  for (int k = 0; k < count; ++k) {
    payloads.push_back({static_cast<std::uint8_t>(k % 256), static_cast<std::uint8_t>(k / 256)});
  }
  return payloads;
}

TEST(Pipeline, EncodedFramesAreDecodedOnlyWhenDetectedAndGoBackOnceDecoded) {
  decodes = 0;
  const auto payloads = numbered_payloads(6);
  Releases releases(6);
  RecordingSink sink;
  Gate gate;
  std::counting_semaphore<1000> entered(0);
  PipelineConfig c = config(DropPolicy::live, 4);
  c.pool.pixel_bytes = 16;
  Pipeline pipeline(c, gated_detectors(1, gate, entered), sink);
  ASSERT_TRUE(offer_encoded(pipeline, payloads, releases, 0));
  ASSERT_TRUE(entered.try_acquire_for(kPatience));
  EXPECT_EQ(decodes.load(), 1);
  EXPECT_EQ(releases.counts[0].load(), 1) << "decoded: the source's buffer goes back before detection ends";
  for (int k = 1; k <= 5; ++k) ASSERT_TRUE(offer_encoded(pipeline, payloads, releases, k));
  for (int k = 1; k <= 4; ++k) EXPECT_EQ(releases.counts[k].load(), 1) << "frame " << k << " dropped while it waited";
  EXPECT_EQ(decodes.load(), 1) << "the frames dropped while they waited were never decoded";
  gate.open();
  const auto written = sink.wait_for(2);
  pipeline.stop();
  ASSERT_EQ(written.size(), 2U);
  for (const Written& w : written) {
    EXPECT_EQ(w.status, FrameStatus::ok) << w.cause;
    EXPECT_EQ(w.ids, std::vector<int>{static_cast<int>(w.sequence)}) << "the detector read the decoded pixels";
  }
  EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 5}));
  EXPECT_EQ(decodes.load(), 2);
  expect_balanced(pipeline.stats());
  expect_each_released_once(releases, 6);
}

TEST(Pipeline, AnEncodedFrameThatDoesNotDecodeIsLoggedCorrupt) {
  decodes = 0;
  std::vector<std::vector<std::uint8_t>> payloads = numbered_payloads(2);
  payloads[1] = {1, 2, 3};
  Releases releases(2);
  RecordingSink sink;
  PipelineConfig c = config(DropPolicy::lossless, 2);
  c.pool.pixel_bytes = 16;
  Pipeline pipeline(c, detectors({new NumberDetector}), sink);
  ASSERT_TRUE(offer_encoded(pipeline, payloads, releases, 0));
  ASSERT_TRUE(offer_encoded(pipeline, payloads, releases, 1));
  const auto written = sink.wait_for(2);
  pipeline.stop();
  ASSERT_EQ(written.size(), 2U);
  EXPECT_EQ(written[0].status, FrameStatus::ok);
  EXPECT_EQ(written[1].status, FrameStatus::corrupt_frame);
  EXPECT_EQ(written[1].cause, "test codec: not two bytes");
  EXPECT_TRUE(written[1].ids.empty()) << "a frame that does not decode is not detected";
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.detect.failed, 1U);
  EXPECT_EQ(s.detect_duration.count, 1U);
  expect_balanced(s);
  expect_each_released_once(releases, 2);
}

TEST(Pipeline, ASinkThatThrowsIsCountedAndTheSlotStillReturns) {
  const auto images = numbered_images(3);
  Releases releases(3);
  RecordingSink sink;
  sink.throw_on = 1;
  Pipeline pipeline(config(DropPolicy::lossless, 2), detectors({new NumberDetector}), sink);
  for (int k = 0; k < 3; ++k) ASSERT_TRUE(offer(pipeline, images, releases, k));
  sink.wait_for(3);
  pipeline.stop();
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.log.failed, 1U);
  EXPECT_EQ(s.log.out, 2U);
  expect_balanced(s);
  expect_each_released_once(releases, 3);
}

// A sink with housekeeping: idle() runs on the log stage's thread while no
// frames come, and not in place of them.
class IdleCountingSink : public RecordingSink {
 public:
  [[nodiscard]] std::chrono::milliseconds idle_period() const override { return std::chrono::milliseconds(5); }
  void idle() override {
    idle_thread = std::this_thread::get_id();
    idles.fetch_add(1);
    if (throw_from_idle) throw std::runtime_error("idle failed");
  }
  std::atomic<int> idles{0};
  std::thread::id idle_thread;
  bool throw_from_idle = false;
};

TEST(Pipeline, TheSinksIdleHousekeepingRunsWhileNoFramesCome) {
  const auto images = numbered_images(2);
  Releases releases(2);
  IdleCountingSink sink;
  sink.throw_from_idle = true;  // ignored: the sink reports its own errors
  Pipeline pipeline(config(DropPolicy::lossless, 2), detectors({new NumberDetector}), sink);
  ASSERT_TRUE(offer(pipeline, images, releases, 0));
  sink.wait_for(1);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (sink.idles.load() < 3 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_GE(sink.idles.load(), 3);
  ASSERT_TRUE(offer(pipeline, images, releases, 1));  // frames still flow after idle periods
  sink.wait_for(2);
  pipeline.stop();
  EXPECT_NE(sink.idle_thread, std::this_thread::get_id());
  const PipelineStats s = pipeline.stats();
  EXPECT_EQ(s.log.out, 2U);
  EXPECT_EQ(s.log.failed, 0U);
  expect_balanced(s);
}

TEST(Pipeline, NeedsADetector) {
  RecordingSink sink;
  EXPECT_THROW({ Pipeline p(config(DropPolicy::live, 2), {}, sink); }, std::invalid_argument);
  std::vector<std::unique_ptr<detector::MarkerDetector>> null_detector(1);
  EXPECT_THROW({ Pipeline p(config(DropPolicy::live, 2), std::move(null_detector), sink); }, std::invalid_argument);
}

// ---- the real detector ----

// Rendered scenes through two frame8 workers, the pixels written into the
// slots' own buffers as a simulated camera would: every frame's ids are its
// own scene's.
TEST(Pipeline, Frame8WorkersDetectRenderedFramesInOrder) {
  const detector::CameraModel camera = detector::CameraModel::thesis_640x480();
  const std::vector<int> ids = {17, 165, 203};
  std::vector<detector::GreyImage> scenes;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    detector::Scene scene;
    scene.id = ids[i];
    scene.pose = detector::facing_pose(0.4 + 0.2 * static_cast<double>(i), 10.0 * static_cast<double>(i));
    scene.supersample = 2;
    scene.noise_sigma = 1;
    scene.seed = i + 1;
    scenes.push_back(detector::render_scene(camera, scene));
  }
  RecordingSink sink;
  std::vector<std::unique_ptr<detector::MarkerDetector>> workers;
  for (int i = 0; i < 2; ++i) workers.push_back(detector::make_detector(detector::DetectorConfig{}));
  PipelineConfig c = config(DropPolicy::lossless, 4);
  c.pool.pixel_bytes = 640 * 480;
  Pipeline pipeline(c, std::move(workers), sink);
  constexpr int kFrames = 12;
  for (int k = 0; k < kFrames; ++k) {
    Frame* frame = pipeline.acquire();
    ASSERT_NE(frame, nullptr);
    const detector::GreyImage& scene = scenes[k % scenes.size()];
    frame->sequence = static_cast<std::uint64_t>(k);
    frame->use_pixel_buffer(scene.width(), scene.height());
    std::copy_n(scene.data(), 640 * 480, frame->pixel_buffer().data());
    pipeline.publish(*frame);
  }
  const auto written = sink.wait_for(kFrames);
  pipeline.stop();
  ASSERT_EQ(written.size(), static_cast<std::size_t>(kFrames));
  for (int k = 0; k < kFrames; ++k) {
    EXPECT_EQ(written[k].sequence, static_cast<std::uint64_t>(k));
    EXPECT_EQ(written[k].ids, std::vector<int>{ids[k % ids.size()]}) << "frame " << k;
  }
}

// ---- figures ----

TEST(LatencyHistogram, BucketsTileTheRangeWithBoundedWidth) {
  for (std::size_t b = 0; b < LatencyHistogram::kBuckets; ++b) {
    const std::uint64_t lo = LatencyHistogram::bucket_lower(b);
    const std::uint64_t hi = LatencyHistogram::bucket_upper(b);
    ASSERT_LE(lo, hi);
    EXPECT_EQ(LatencyHistogram::bucket_of(static_cast<std::int64_t>(lo)), b);
    EXPECT_EQ(LatencyHistogram::bucket_of(static_cast<std::int64_t>(hi)), b);
    if (b + 1 < LatencyHistogram::kBuckets) {
      EXPECT_EQ(LatencyHistogram::bucket_lower(b + 1), hi + 1);
    }
    EXPECT_LE((hi - lo + 1) * 8, std::max<std::uint64_t>(lo, 8)) << "bucket " << b;
  }
  EXPECT_EQ(LatencyHistogram::bucket_of(-5), 0U);
  EXPECT_EQ(LatencyHistogram::bucket_of(std::int64_t{1} << 50), LatencyHistogram::kBuckets - 1);
}

TEST(LatencyHistogram, PercentilesOfKnownValues) {
  LatencyHistogram h;
  EXPECT_EQ(h.summary().count, 0U);
  EXPECT_EQ(h.summary().p99, 0ns);
  // 1..1000 us once each: p50 = 500 us, p99 = 990 us, max 1000 us, mean 500.5 us.
  for (int us = 1000; us >= 1; --us) h.record(std::chrono::microseconds(us));
  const LatencySummary s = h.summary();
  EXPECT_EQ(s.count, 1000U);
  EXPECT_EQ(s.max, 1000us);
  EXPECT_EQ(s.mean, 500500ns);
  EXPECT_NEAR(static_cast<double>(s.p50.count()), 500e3, 500e3 / 16);
  EXPECT_NEAR(static_cast<double>(s.p99.count()), 990e3, 990e3 / 16);
  // One outlier among many equal values moves p99 only once it is 1% of them.
  LatencyHistogram g;
  for (int i = 0; i < 99; ++i) g.record(2ms);
  g.record(50ms);
  EXPECT_NEAR(static_cast<double>(g.summary().p99.count()), 2e6, 2e6 / 16);
  EXPECT_EQ(g.summary().max, 50ms);
  g.record(50ms);
  EXPECT_NEAR(static_cast<double>(g.summary().p99.count()), 50e6, 50e6 / 16);
  // Small values are exact; a negative duration (a clock step between
  // stamps that came from different sources) counts as zero.
  LatencyHistogram e;
  e.record(7ns);
  e.record(-3ns);
  EXPECT_EQ(e.summary().max, 7ns);
  EXPECT_EQ(e.summary().p99, 7ns);
  EXPECT_EQ(e.summary().p50, 0ns);
}

// ---- the frame rates of the status

// Ticks at given times (offsets from a time well into the clock's range,
// whole buckets from its start), so nothing depends on this machine's speed.
RateMeter::Clock::time_point at(std::chrono::milliseconds offset) {
  return RateMeter::Clock::time_point(std::chrono::hours(1) + offset);
}

TEST(RateMeter, CountsPerSecondOverTheCompleteBucketsOfTheWindow) {
  RateMeter meter;
  EXPECT_FALSE(meter.rate(at(0ms)).has_value()) << "nothing counted yet";
  // 30 events a second for 2 s: one every 33 ms from the start of a bucket.
  for (int i = 0; i < 60; ++i) meter.tick(at(std::chrono::milliseconds(i * 100 / 3)));
  EXPECT_FALSE(meter.rate(at(200ms)).has_value()) << "the first bucket is not complete yet";
  // At 2 s: eight complete buckets of 250 ms hold all 60 events.
  ASSERT_TRUE(meter.rate(at(2000ms)).has_value());
  EXPECT_DOUBLE_EQ(*meter.rate(at(2000ms)), 30.0);
  // The bucket in progress is left out: at 2.1 s still the same eight.
  EXPECT_DOUBLE_EQ(*meter.rate(at(2100ms)), 30.0);
  // No events since: the window (5 s) slides over the silence.
  EXPECT_DOUBLE_EQ(*meter.rate(at(4000ms)), 15.0) << "60 events over the 4 s since the first";
  EXPECT_DOUBLE_EQ(*meter.rate(at(6000ms)), 6.0) << "the window from 1 s on holds the last 30 events";
  EXPECT_DOUBLE_EQ(*meter.rate(at(7000ms)), 0.0) << "nothing within the last 5 s";
}

TEST(RateMeter, ARateChangeShowsWithinTheWindowAndOldBucketsAreReused) {
  RateMeter meter;
  // 10 a second for 10 s, then 40 a second for 10 s: the buckets' ring
  // (21 of them) goes round several times.
  int ms = 0;
  for (; ms < 10000; ms += 100) meter.tick(at(std::chrono::milliseconds(ms)));
  EXPECT_DOUBLE_EQ(*meter.rate(at(10000ms)), 10.0);
  for (; ms < 12500; ms += 25) meter.tick(at(std::chrono::milliseconds(ms)));
  EXPECT_DOUBLE_EQ(*meter.rate(at(12500ms)), (2.5 * 10 + 2.5 * 40) / 5) << "half of each in the window";
  for (; ms < 20000; ms += 25) meter.tick(at(std::chrono::milliseconds(ms)));
  EXPECT_DOUBLE_EQ(*meter.rate(at(20000ms)), 40.0);
}

}  // namespace
}  // namespace markerd::daemon
