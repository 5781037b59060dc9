#pragma once
// The frame pipeline: capture -> detection workers -> log stage, joined by
// lock-free single-producer single-consumer rings, over a frame pool
// allocated at start. Design, ownership and policies: docs/pipeline.md.
//
// The capture side is driven by whoever owns the source, from one thread:
//
//   while (running) {
//     Frame* frame = pipeline.acquire(stop);   // live: never waits
//     if (!frame) { requeue the driver's buffer; continue; }   // dropped (or stopped)
//     frame->sequence = ...; frame->capture_time = ...; frame->rig = rig.snapshot();
//     frame->image = view of the mmap buffer; frame->set_release({requeue, this, index});
//     pipeline.publish(*frame);
//   }
//
// Detection runs on one std::jthread per detector; the log stage on one
// more, which hands frames to the FrameSink in publication order.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <stop_token>
#include <thread>
#include <vector>

#include "markerd/daemon/frame.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "markerd/daemon/spsc_ring.hpp"
#include "markerd/daemon/stats.hpp"
#include "markerd/detector/detector.hpp"

namespace markerd::daemon {

enum class DropPolicy : std::uint8_t {
  // The capture never waits, and detection takes the newest frames: a frame
  // still waiting for the worker the new frame goes to is dropped and its
  // slot reused, so each worker has at most one frame waiting. When no slot
  // is free, the oldest frame waiting (for any worker) is dropped; when no
  // frame is waiting either (every slot is being detected or logged), the
  // new frame is refused. Stopping discards frames not yet detected.
  live,
  // Every published frame is detected and logged: acquire() waits for a
  // free slot. Stopping drains every frame in flight.
  lossless,
};

struct PipelineConfig {
  DropPolicy policy = DropPolicy::live;
  // Frames in flight at most, and their buffers (see FramePoolConfig).
  FramePoolConfig pool;
};

class Pipeline {
 public:
  // One worker thread per detector (detectors are not thread-safe). Starts
  // the stage threads. `sink` must outlive the pipeline. Throws
  // std::invalid_argument without a detector.
  Pipeline(const PipelineConfig& config, std::vector<std::unique_ptr<detector::MarkerDetector>> detectors,
           FrameSink& sink);
  ~Pipeline();  // stop()
  Pipeline(const Pipeline&) = delete;
  Pipeline& operator=(const Pipeline&) = delete;

  // ---- the capture thread (one thread; one frame between acquire and publish) ----

  // A reset frame slot with capture_time set to now, or null: live, when the
  // frame must be dropped (counted); lossless, when `stop` was requested
  // while waiting for a slot; either, once the pipeline is stopped.
  [[nodiscard]] Frame* acquire(const std::stop_token& stop = {});
  // Hands the frame to detection; the pipeline owns it from here.
  void publish(Frame& frame);
  // Gives back an acquired frame that will not be published (the source
  // could not fill it); runs its release hook if it has one.
  void abandon(Frame& frame) noexcept;

  // Stops the stages: live discards the frames waiting for detection,
  // lossless drains them; detected frames are logged either way. Every slot
  // is back in the pool and every release hook has run when it returns.
  // Call it from the capture thread or once that thread has stopped calling
  // acquire/publish. Idempotent; the pipeline does not restart.
  void stop();
  // The first half of stop(), from any thread, without waiting: the workers
  // finish the frame in hand and then drain or discard (so a frame published
  // after this may be stranded until stop() collects it).
  void request_stop() noexcept;

  // ---- any thread ----
  [[nodiscard]] PipelineStats stats() const noexcept;
  [[nodiscard]] DropPolicy policy() const noexcept { return policy_; }
  [[nodiscard]] std::size_t worker_count() const noexcept { return workers_.size(); }
  [[nodiscard]] const FramePool& pool() const noexcept { return pool_; }

 private:
  // Frames reach a worker through `input` and the log stage through
  // `output`. A null in either is the place of a frame dropped while it
  // waited: workers take frames in strict rotation by ticket and the log
  // stage collects them in the same rotation, so every ticket must keep its
  // place for the order to come out right.
  struct Worker {
    Worker(std::unique_ptr<detector::MarkerDetector> d, std::size_t ring_capacity)
        : detector(std::move(d)), input(ring_capacity), output(ring_capacity) {}
    std::unique_ptr<detector::MarkerDetector> detector;
    SpscRing<Frame*> input;
    SpscRing<Frame*> output;
    std::jthread thread;
  };

  Frame* take_slot_live();
  // Drops `frame`, waiting in `holder`'s input, and hands back its reset
  // slot; null when the worker popped it first.
  Frame* take_back(Worker& holder, Frame* frame) noexcept;
  Frame* take_back_oldest_waiting() noexcept;
  void run_worker(Worker& worker, std::size_t index, const std::stop_token& stop);
  void detect(Worker& worker, Frame& frame) noexcept;
  void run_log(const std::stop_token& stop);
  void log(Frame* frame) noexcept;

  const DropPolicy policy_;
  FrameSink& sink_;
  FramePool pool_;
  std::vector<std::unique_ptr<Worker>> workers_;

  StageCounters capture_counts_;
  StageCounters detect_counts_;
  StageCounters log_counts_;
  LatencyHistogram capture_to_detect_;
  LatencyHistogram detect_duration_;
  LatencyHistogram capture_to_log_;

  // The capture thread's own.
  std::uint64_t next_ticket_ = 0;
  Frame* spare_ = nullptr;  // an abandoned or reclaimed slot, used before the pool's
  bool stopped_ = false;

  std::jthread log_thread_;  // last: started after, and stopped before, everything it uses
};

}  // namespace markerd::daemon
