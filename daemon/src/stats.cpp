#include "markerd/daemon/stats.hpp"

#include <algorithm>
#include <bit>

namespace markerd::daemon {

std::size_t LatencyHistogram::bucket_of(std::int64_t ns) noexcept {
  if (ns < 2 * kSubBuckets) return ns < 0 ? 0 : static_cast<std::size_t>(ns);
  const auto value = static_cast<std::uint64_t>(ns);
  const int exponent = static_cast<int>(std::bit_width(value)) - 1;
  if (exponent > kMaxExponent) return kBuckets - 1;
  // The top kSubBucketBits + 1 bits of the value: its octave and its eighth
  // within the octave. Values under 2 * kSubBuckets are their own bucket.
  const int shift = exponent - kSubBucketBits;
  return static_cast<std::size_t>(shift) * kSubBuckets + static_cast<std::size_t>(value >> shift);
}

std::uint64_t LatencyHistogram::bucket_lower(std::size_t bucket) noexcept {
  if (bucket < 2 * kSubBuckets) return bucket;
  const std::size_t shift = bucket / kSubBuckets - 1;
  const std::uint64_t mantissa = bucket - shift * kSubBuckets;  // kSubBuckets .. 2 * kSubBuckets - 1
  return mantissa << shift;
}

std::uint64_t LatencyHistogram::bucket_upper(std::size_t bucket) noexcept {
  if (bucket < 2 * kSubBuckets) return bucket;
  const std::size_t shift = bucket / kSubBuckets - 1;
  return bucket_lower(bucket) + (std::uint64_t{1} << shift) - 1;
}

void LatencyHistogram::record(std::chrono::nanoseconds duration) noexcept {
  const std::int64_t ns = std::max<std::int64_t>(duration.count(), 0);
  buckets_[bucket_of(ns)].fetch_add(1, std::memory_order_relaxed);
  sum_ns_.fetch_add(static_cast<std::uint64_t>(ns), std::memory_order_relaxed);
  std::uint64_t max = max_ns_.load(std::memory_order_relaxed);
  while (static_cast<std::uint64_t>(ns) > max &&
         !max_ns_.compare_exchange_weak(max, static_cast<std::uint64_t>(ns), std::memory_order_relaxed)) {
  }
}

LatencySummary LatencyHistogram::summary() const noexcept {
  std::array<std::uint64_t, kBuckets> counts{};
  std::uint64_t total = 0;
  for (std::size_t b = 0; b < kBuckets; ++b) {
    counts[b] = buckets_[b].load(std::memory_order_relaxed);
    total += counts[b];
  }
  LatencySummary s;
  s.count = total;
  if (total == 0) return s;
  const std::uint64_t max = max_ns_.load(std::memory_order_relaxed);
  s.max = std::chrono::nanoseconds(max);
  s.mean = std::chrono::nanoseconds(sum_ns_.load(std::memory_order_relaxed) / total);
  // The q-quantile is the ceil(q * total)-th smallest value; it is reported
  // as the middle of its bucket, never above the largest value seen.
  auto quantile = [&](std::uint64_t per_mille) {
    const std::uint64_t rank = std::max<std::uint64_t>(1, (total * per_mille + 999) / 1000);
    std::uint64_t seen = 0;
    for (std::size_t b = 0; b < kBuckets; ++b) {
      seen += counts[b];
      if (seen >= rank) {
        const std::uint64_t middle = bucket_lower(b) + (bucket_upper(b) - bucket_lower(b)) / 2;
        return std::chrono::nanoseconds(std::min(middle, max));
      }
    }
    return std::chrono::nanoseconds(max);
  };
  s.p50 = quantile(500);
  s.p99 = quantile(990);
  return s;
}

StageCounts StageCounters::snapshot() const noexcept {
  return {in_.load(std::memory_order_relaxed), out_.load(std::memory_order_relaxed),
          dropped_.load(std::memory_order_relaxed), failed_.load(std::memory_order_relaxed)};
}

std::int64_t RateMeter::bucket_index(Clock::time_point t) noexcept {
  return std::chrono::duration_cast<std::chrono::milliseconds>(t.time_since_epoch()).count() / kBucket.count();
}

void RateMeter::tick(Clock::time_point now) noexcept {
  const std::int64_t index = bucket_index(now);
  if (first_.load(std::memory_order_relaxed) == kNever) first_.store(index, std::memory_order_relaxed);
  Bucket& b = buckets_[static_cast<std::size_t>(index) % kBuckets];
  if (b.index.load(std::memory_order_relaxed) != index) {
    // A bucket of time long past: emptied before it says it counts this one.
    b.count.store(0, std::memory_order_relaxed);
    b.index.store(index, std::memory_order_release);
  }
  // One counting thread: no read-modify-write needed.
  b.count.store(b.count.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
}

std::optional<double> RateMeter::rate(Clock::time_point now) const noexcept {
  const std::int64_t current = bucket_index(now);
  const std::int64_t first = first_.load(std::memory_order_relaxed);
  if (first == kNever) return std::nullopt;
  const std::int64_t from = std::max(first, current - static_cast<std::int64_t>(kBuckets - 1));
  if (from >= current) return std::nullopt;
  std::uint64_t events = 0;
  for (std::int64_t i = from; i < current; ++i) {
    const Bucket& b = buckets_[static_cast<std::size_t>(i) % kBuckets];
    // A bucket that moved on to another time while being read counts for
    // nothing: the counter's one thread was ahead of this reader's clock.
    if (b.index.load(std::memory_order_acquire) != i) continue;
    const std::uint64_t count = b.count.load(std::memory_order_relaxed);
    if (b.index.load(std::memory_order_acquire) == i) events += count;
  }
  const double seconds = std::chrono::duration<double>(kBucket).count() * static_cast<double>(current - from);
  return static_cast<double>(events) / seconds;
}

}  // namespace markerd::daemon
