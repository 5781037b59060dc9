#include "markerd/daemon/pipeline.hpp"

#include <pthread.h>

#include <algorithm>
#include <cassert>
#include <cstdio>
#include <exception>
#include <stdexcept>
#include <utility>

namespace markerd::daemon {

namespace {

// Room in each ring for every slot plus three vacancies per slot: a live
// pipeline drops a waiting frame by leaving a vacancy in its place, and only
// a worker stuck for several pool-fulls of frames fills its ring with them
// (the capture then refuses frames instead of waiting).
constexpr std::size_t kRingPlacesPerSlot = 4;
constexpr std::size_t kMinRingCapacity = 16;

// Visible in top -H, ps -L and gdb; Linux allows 15 characters.
void name_this_thread(const char* name) noexcept { pthread_setname_np(pthread_self(), name); }

}  // namespace

Pipeline::Pipeline(const PipelineConfig& config, std::vector<std::unique_ptr<detector::MarkerDetector>> detectors,
                   FrameSink& sink)
    : policy_(config.policy), sink_(sink), pool_(config.pool) {
  if (detectors.empty()) throw std::invalid_argument("pipeline: at least one detector (one per worker) is needed");
  const std::size_t ring_capacity = std::max(kRingPlacesPerSlot * config.pool.slots, kMinRingCapacity);
  workers_.reserve(detectors.size());
  for (auto& detector : detectors) {
    if (!detector) throw std::invalid_argument("pipeline: a worker was given no detector");
    workers_.push_back(std::make_unique<Worker>(std::move(detector), ring_capacity));
  }
  for (std::size_t i = 0; i < workers_.size(); ++i) {
    workers_[i]->thread = std::jthread([this, i](const std::stop_token& stop) { run_worker(*workers_[i], i, stop); });
  }
  log_thread_ = std::jthread([this](const std::stop_token& stop) { run_log(stop); });
}

Pipeline::~Pipeline() { stop(); }

// ---- capture ----

Frame* Pipeline::acquire(const std::stop_token& stop) {
  if (stopped_) return nullptr;
  Frame* frame = nullptr;
  if (policy_ == DropPolicy::live) {
    frame = take_slot_live();
    if (frame == nullptr) {
      capture_counts_.add_in();
      capture_counts_.add_dropped();
      return nullptr;
    }
  } else {
    frame = std::exchange(spare_, nullptr);
    if (frame == nullptr) frame = pool_.acquire(stop);
    if (frame == nullptr) return nullptr;
  }
  frame->capture_time = Clock::now();
  return frame;
}

Frame* Pipeline::take_slot_live() {
  // The frame will go to this worker; a worker stuck for so long that its
  // ring is all vacancies cannot take it, whatever slot it would be in.
  Worker& target = *workers_[next_ticket_ % workers_.size()];
  if (target.input.full()) return nullptr;
  // A frame still waiting for this worker is older than the one coming:
  // live detection takes each worker's newest frame, so the older one is
  // dropped and its slot reused. A camera faster than detection thus waits
  // at most one frame per worker, not a pool-full.
  while (Frame* waiting = target.input.oldest_waiting()) {
    if (Frame* frame = take_back(target, waiting)) return frame;
  }
  if (Frame* frame = std::exchange(spare_, nullptr)) return frame;
  if (Frame* frame = pool_.try_acquire()) return frame;
  return take_back_oldest_waiting();
}

Frame* Pipeline::take_back(Worker& holder, Frame* frame) noexcept {
  if (!holder.input.take_back(frame)) return nullptr;  // the worker popped it in the meantime
  detect_counts_.add_dropped();
  frame->release_source();
  frame->reset();
  return frame;
}

Frame* Pipeline::take_back_oldest_waiting() noexcept {
  for (;;) {
    Frame* oldest = nullptr;
    Worker* holder = nullptr;
    for (auto& worker : workers_) {
      // Only this thread writes a frame's ticket, so reading it here races
      // with nothing, even when a worker has just popped the frame.
      Frame* frame = worker->input.oldest_waiting();
      if (frame != nullptr && (oldest == nullptr || frame->ticket_ < oldest->ticket_)) {
        oldest = frame;
        holder = worker.get();
      }
    }
    if (oldest == nullptr) return nullptr;  // every slot is being detected or logged
    if (Frame* frame = take_back(*holder, oldest)) return frame;
    // The worker popped it in the meantime: look again.
  }
}

void Pipeline::publish(Frame& frame) {
  assert(pool_.owns(frame));
  if (stopped_) {
    // Acquired before stop(), against its contract; the slot is not lost.
    pool_.release(frame);
    return;
  }
  frame.ticket_ = next_ticket_++;
  frame.times.published = Clock::now();
  capture_counts_.add_in();
  capture_counts_.add_out();
  // Lossless: at most every slot is in a ring, which has room for all of
  // them. Live: take_slot_live checked that this ring had room, and only
  // this thread pushes.
  const bool pushed = workers_[frame.ticket_ % workers_.size()]->input.try_push(&frame);
  assert(pushed);
  (void)pushed;
}

void Pipeline::abandon(Frame& frame) noexcept {
  assert(pool_.owns(frame) && spare_ == nullptr);
  frame.release_source();
  if (stopped_) {
    pool_.release(frame);
    return;
  }
  frame.reset();
  spare_ = &frame;
}

// ---- detection ----

void Pipeline::run_worker(Worker& worker, std::size_t index, const std::stop_token& stop) {
  char name[16];
  std::snprintf(name, sizeof name, "markerd-det%zu", index);
  name_this_thread(name);
  // The log stage runs until every worker has stopped, so pushing to it
  // never needs to give up; it waits only while the log stage is behind.
  const std::stop_token never;
  while (!stop.stop_requested()) {
    if (const auto item = worker.input.try_pop()) {
      if (Frame* frame = *item) detect(worker, *frame);
      worker.output.push(*item, never);
      continue;
    }
    worker.input.wait_for_item(stop);
  }
  // stop() runs after the capture's last publish: what is queued now is all
  // this worker will get.
  while (const auto item = worker.input.try_pop()) {
    if (Frame* frame = *item) {
      if (policy_ == DropPolicy::lossless) {
        detect(worker, *frame);
      } else {
        frame->discarded_ = true;
        detect_counts_.add_dropped();
      }
    }
    worker.output.push(*item, never);
  }
}

void Pipeline::detect(Worker& worker, Frame& frame) noexcept {
  detect_counts_.add_in();
  frame.times.detect_start = Clock::now();
  capture_to_detect_.record(frame.times.detect_start - frame.capture_time);
  // Only now, for a frame that is detected: see Frame::set_encoded. Its
  // time counts as detection's.
  frame.decode();
  if (frame.status == FrameStatus::ok) {
    try {
      worker.detector->detect(frame.image, frame.detections);
    } catch (const std::exception& e) {
      frame.detections.clear();
      frame.status = FrameStatus::detector_error;
      frame.set_cause(e.what());
    } catch (...) {
      frame.detections.clear();
      frame.status = FrameStatus::detector_error;
      frame.set_cause("the detector threw something other than an exception");
    }
    frame.times.detect_end = Clock::now();
    detect_duration_.record(frame.times.detect_end - frame.times.detect_start);
  } else {
    frame.times.detect_end = frame.times.detect_start;
  }
  if (frame.status != FrameStatus::ok) detect_counts_.add_failed();
  detect_counts_.add_out();
}

// ---- log ----

void Pipeline::run_log(const std::stop_token& stop) {
  name_this_thread("markerd-log");
  // Ticket t went to worker t % n, and each worker keeps its frames' order
  // (vacancies included), so collecting in the same rotation restores the
  // publication order.
  const std::size_t n = workers_.size();
  const std::chrono::milliseconds idle_period = sink_.idle_period();
  std::uint64_t next = 0;
  for (;;) {
    SpscRing<Frame*>& from = workers_[next % n]->output;
    if (const auto item = from.try_pop()) {
      log(*item);
      ++next;
      continue;
    }
    if (idle_period.count() <= 0) {
      if (!from.wait_for_item(stop)) break;
      continue;
    }
    if (from.wait_for_item_until(stop, Clock::now() + idle_period)) continue;
    if (stop.stop_requested()) break;
    try {
      sink_.idle();
    } catch (...) {  // NOLINT(bugprone-empty-catch): idle() is no frame to count; the sink reports its own errors
    }
  }
  // stop() stops this stage after joining the workers: the rings hold the
  // last of every worker's frames.
  while (const auto item = workers_[next % n]->output.try_pop()) {
    log(*item);
    ++next;
  }
}

void Pipeline::log(Frame* frame) noexcept {
  if (frame == nullptr) return;  // dropped while it waited; the capture reused its slot
  if (frame->discarded_) {
    pool_.release(*frame);
    return;
  }
  log_counts_.add_in();
  frame->times.log_start = Clock::now();
  try {
    sink_.write(*frame);
    log_counts_.add_out();
  } catch (...) {
    log_counts_.add_failed();
  }
  capture_to_log_.record(Clock::now() - frame->capture_time);
  pool_.release(*frame);
}

// ---- lifetime and figures ----

void Pipeline::request_stop() noexcept {
  for (auto& worker : workers_) worker->thread.request_stop();
}

void Pipeline::stop() {
  if (stopped_) return;
  stopped_ = true;
  // Workers first, so that the log stage, stopped last, sees their final frames.
  request_stop();
  for (auto& worker : workers_) {
    if (worker->thread.joinable()) worker->thread.join();
  }
  log_thread_.request_stop();
  if (log_thread_.joinable()) log_thread_.join();
  // With every stage joined, this thread owns what is left: frames published
  // after request_stop() that no worker took, and the capture's spare slot.
  for (auto& worker : workers_) {
    while (const auto item = worker->input.try_pop()) {
      if (Frame* frame = *item) {
        detect_counts_.add_dropped();
        pool_.release(*frame);
      }
    }
  }
  if (Frame* frame = std::exchange(spare_, nullptr)) pool_.release(*frame);
}

PipelineStats Pipeline::stats() const noexcept {
  PipelineStats s;
  s.capture = capture_counts_.snapshot();
  s.detect = detect_counts_.snapshot();
  s.log = log_counts_.snapshot();
  s.capture_to_detect = capture_to_detect_.summary();
  s.detect_duration = detect_duration_.summary();
  s.capture_to_log = capture_to_log_.summary();
  s.pool_slots = pool_.size();
  s.pool_free = pool_.available();
  return s;
}

}  // namespace markerd::daemon
