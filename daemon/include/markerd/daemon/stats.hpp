#pragma once
// The pipeline's counters and latency histograms. Stage threads update them
// with relaxed atomic increments (no lock, no allocation, no ordering cost
// on the frame path); any thread reads a snapshot. A snapshot is not one
// consistent cut: a counter read a moment after another may include a frame
// the other does not yet, which is harmless for figures and is why the
// invariants between stages hold exactly only once the pipeline is stopped.

#include <array>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>

namespace markerd::daemon {

struct LatencySummary {
  std::uint64_t count = 0;
  // Percentiles to within 1/16 of their value (the bucket's middle; see
  // LatencyHistogram), max and mean exact.
  std::chrono::nanoseconds p50{0};
  std::chrono::nanoseconds p99{0};
  std::chrono::nanoseconds max{0};
  std::chrono::nanoseconds mean{0};
};

// Durations in nanoseconds in log-scale buckets: exact below 16 ns, then
// eight buckets per power of two, so a bucket is at most 1/8 of its lower
// bound wide, up to 2^40 ns (18 minutes); longer durations share the last
// bucket. 304 counters, 2.4 KB.
class LatencyHistogram {
 public:
  static constexpr int kSubBucketBits = 3;
  static constexpr int kSubBuckets = 1 << kSubBucketBits;
  static constexpr int kMaxExponent = 39;  // highest bit of the largest distinguished value
  static constexpr std::size_t kBuckets = (kMaxExponent - kSubBucketBits + 1) * kSubBuckets + kSubBuckets;

  void record(std::chrono::nanoseconds duration) noexcept;
  [[nodiscard]] LatencySummary summary() const noexcept;

  // The bucket of a duration in ns (negative durations count as 0), and the
  // range of durations a bucket holds.
  [[nodiscard]] static std::size_t bucket_of(std::int64_t ns) noexcept;
  [[nodiscard]] static std::uint64_t bucket_lower(std::size_t bucket) noexcept;
  [[nodiscard]] static std::uint64_t bucket_upper(std::size_t bucket) noexcept;  // inclusive

 private:
  std::array<std::atomic<std::uint64_t>, kBuckets> buckets_{};
  std::atomic<std::uint64_t> sum_ns_{0};
  std::atomic<std::uint64_t> max_ns_{0};
};

// Events per second over a recent window: the frame rates of the capture
// and of detection in the status. One thread counts (tick(): two relaxed
// loads and stores, no lock, no allocation), any thread reads (rate()).
// Time falls into buckets of kBucket; the rate is over the complete buckets
// of the last kWindow, or of the time since the first tick when that is
// shorter (the bucket in progress is left out: only part of it has passed).
class RateMeter {
 public:
  using Clock = std::chrono::steady_clock;
  static constexpr std::chrono::milliseconds kBucket{250};
  static constexpr std::chrono::milliseconds kWindow{5000};

  // The counting thread: one event at `now`.
  void tick(Clock::time_point now) noexcept;
  // Events per second; nothing before a whole bucket has passed since the
  // first tick. 0 once no event came for a window.
  [[nodiscard]] std::optional<double> rate(Clock::time_point now) const noexcept;

 private:
  static constexpr std::size_t kBuckets = kWindow / kBucket + 1;  // the window's, and the one in progress
  static constexpr std::int64_t kNever = std::numeric_limits<std::int64_t>::min();
  struct Bucket {
    std::atomic<std::int64_t> index{kNever};  // which bucket of time it counts now
    std::atomic<std::uint64_t> count{0};
  };
  [[nodiscard]] static std::int64_t bucket_index(Clock::time_point t) noexcept;

  std::array<Bucket, kBuckets> buckets_{};
  std::atomic<std::int64_t> first_{kNever};  // the bucket of the first tick
};

struct StageCounts {
  std::uint64_t in = 0;       // frames that entered the stage
  std::uint64_t out = 0;      // frames it passed on (or, for the log stage, wrote)
  std::uint64_t dropped = 0;  // frames it let go without passing them on
  std::uint64_t failed = 0;   // frames it passed on with an error (detection) or could not write (log)
};

class StageCounters {
 public:
  void add_in() noexcept { in_.fetch_add(1, std::memory_order_relaxed); }
  void add_out() noexcept { out_.fetch_add(1, std::memory_order_relaxed); }
  void add_dropped() noexcept { dropped_.fetch_add(1, std::memory_order_relaxed); }
  void add_failed() noexcept { failed_.fetch_add(1, std::memory_order_relaxed); }
  [[nodiscard]] StageCounts snapshot() const noexcept;

 private:
  std::atomic<std::uint64_t> in_{0};
  std::atomic<std::uint64_t> out_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> failed_{0};
};

struct PipelineStats {
  // capture: in = frames the source offered, out = published to detection,
  //          dropped = refused for want of a slot (live).
  // detect:  in = frames a worker took, out = frames passed to the log stage
  //          (failed: of those, the detector threw or the frame was corrupt),
  //          dropped = frames dropped while waiting (live) or discarded at stop.
  // log:     in = frames received, out = written, failed = the sink threw.
  // Once stopped: capture.in = capture.out + capture.dropped,
  // capture.out = detect.out + detect.dropped, detect.out = log.in,
  // log.in = log.out + log.failed.
  StageCounts capture;
  StageCounts detect;
  StageCounts log;
  LatencySummary capture_to_detect;  // capture time to a worker starting on the frame
  LatencySummary detect_duration;    // the detector's call
  LatencySummary capture_to_log;     // capture time to the sink's write returning
  std::size_t pool_slots = 0;
  std::size_t pool_free = 0;

  [[nodiscard]] std::uint64_t dropped() const noexcept { return capture.dropped + detect.dropped; }
};

}  // namespace markerd::daemon
