#pragma once
// A bounded lock-free queue between exactly two threads, one pushing and one
// popping: the link between two stages of the frame pipeline. Neither side
// takes a lock or allocates after construction; each side waits, when it
// must, on a futex that the other side rings, so a stage with nothing to do
// sleeps instead of spinning.
//
// The producer may also take back an item it pushed that the consumer has
// not popped yet (the live policy drops the oldest waiting frame this way).
// The taken-back item's place stays in the queue as a vacancy, the value
// T{}, which the consumer pops like any item: positions are never skipped,
// so a consumer that knows what the n-th push was for still does.

#include <algorithm>
#include <atomic>
#include <bit>
#include <cassert>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <ctime>
#include <memory>
#include <optional>
#include <stdexcept>
#include <stop_token>
#include <type_traits>

#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace markerd::daemon {

// Indices written by different threads live on different cache lines, or
// every push would invalidate the consumer's line and every pop the
// producer's (false sharing). 64 bytes on every x86-64 and most ARM cores;
// std::hardware_destructive_interference_size is not used because GCC warns
// that its value may differ between compiler versions, and this header is
// an interface.
inline constexpr std::size_t kCacheLineBytes = 64;

template <class T>
class SpscRing {
  static_assert(std::is_trivially_copyable_v<T> && std::atomic<T>::is_always_lock_free,
                "SpscRing holds values that fit a lock-free atomic (pointers, integers)");

 public:
  // The capacity is `min_capacity` rounded up to a power of two, so that a
  // position maps to its slot with a mask.
  explicit SpscRing(std::size_t min_capacity)
      : mask_(capacity_for(min_capacity) - 1), slots_(new std::atomic<T>[mask_ + 1]()) {}

  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  [[nodiscard]] std::size_t capacity() const noexcept { return mask_ + 1; }

  // ---- producer side (one thread) ----

  // False when the ring is full. Pushing T{} pushes a vacancy: a place the
  // consumer pops as T{}, which the pipeline uses to keep a dropped frame's
  // place from one stage to the next.
  bool try_push(T item) noexcept {
    const std::uint32_t tail = tail_.load(std::memory_order_relaxed);
    if (tail - cached_head_ > mask_) {
      cached_head_ = head_.load(std::memory_order_acquire);
      if (tail - cached_head_ > mask_) return false;
    }
    slots_[tail & mask_].store(item, std::memory_order_relaxed);
    tail_.store(tail + 1, std::memory_order_release);
    wake(consumer_asleep_, item_bell_);
    return true;
  }

  // Waits for room. False when `stop` was requested before there was room.
  bool push(T item, const std::stop_token& stop) {
    for (;;) {
      if (try_push(item)) return true;
      if (stop.stop_requested()) return false;
      sleep_until(producer_asleep_, space_bell_, stop, [this] { return !full(); });
    }
  }

  [[nodiscard]] bool full() const noexcept {
    return tail_.load(std::memory_order_relaxed) - head_.load(std::memory_order_acquire) > mask_;
  }

  // The oldest item neither popped nor taken back, or T{} when there is none.
  // The consumer may pop it at any moment after this returns.
  [[nodiscard]] T oldest_waiting() const noexcept {
    const std::uint32_t tail = tail_.load(std::memory_order_relaxed);
    for (std::uint32_t pos = head_.load(std::memory_order_acquire); pos != tail; ++pos) {
      const T item = slots_[pos & mask_].load(std::memory_order_relaxed);
      if (item != T{}) return item;
    }
    return T{};
  }

  // Takes `item` back if the consumer has not popped it yet, leaving a
  // vacancy in its place. Items must be unique among those waiting.
  bool take_back(T item) noexcept {
    assert(item != T{});
    const std::uint32_t tail = tail_.load(std::memory_order_relaxed);
    for (std::uint32_t pos = head_.load(std::memory_order_acquire); pos != tail; ++pos) {
      T expected = item;
      // The consumer claims a slot with an exchange and the producer with a
      // compare-exchange on the same word: exactly one of them gets the item.
      if (slots_[pos & mask_].compare_exchange_strong(expected, T{}, std::memory_order_relaxed)) return true;
    }
    return false;
  }

  // ---- consumer side (one thread) ----

  // The oldest position's value (T{} for a vacancy), or nothing when empty.
  std::optional<T> try_pop() noexcept {
    const std::uint32_t head = head_.load(std::memory_order_relaxed);
    if (head == cached_tail_) {
      cached_tail_ = tail_.load(std::memory_order_acquire);
      if (head == cached_tail_) return std::nullopt;
    }
    const T item = slots_[head & mask_].exchange(T{}, std::memory_order_relaxed);
    // Release: the producer reuses the slot only after it sees this index,
    // so the exchange above is ordered before its next store there.
    head_.store(head + 1, std::memory_order_release);
    wake(producer_asleep_, space_bell_);
    return item;
  }

  // Waits until there is something to pop. False when `stop` was requested
  // while the ring was empty.
  bool wait_for_item(const std::stop_token& stop) {
    for (;;) {
      if (has_item()) return true;
      if (stop.stop_requested()) return false;
      sleep_until(consumer_asleep_, item_bell_, stop, [this] { return has_item(); });
    }
  }

  // The same, giving up at `deadline` (on steady_clock): false then too.
  bool wait_for_item_until(const std::stop_token& stop, std::chrono::steady_clock::time_point deadline) {
    for (;;) {
      if (has_item()) return true;
      if (stop.stop_requested()) return false;
      const auto left = deadline - std::chrono::steady_clock::now();
      if (left <= std::chrono::steady_clock::duration::zero()) return false;
      sleep_until(
          consumer_asleep_, item_bell_, stop, [this] { return has_item(); }, left);
    }
  }

  // ---- either side ----

  // Positions pushed and not yet popped (vacancies included); exact only
  // when called by one of the two threads with the other one idle.
  [[nodiscard]] std::size_t size() const noexcept {
    // Head first: the tail read after it is never behind it, though it may
    // be a lap's worth ahead of it for a third thread.
    const std::uint32_t head = head_.load(std::memory_order_acquire);
    const std::uint32_t tail = tail_.load(std::memory_order_acquire);
    return std::min<std::size_t>(tail - head, capacity());
  }

 private:
  static std::size_t capacity_for(std::size_t min_capacity) {
    // Positions are 32-bit and wrap; their difference stays exact while the
    // capacity is at most half their range.
    if (min_capacity == 0 || min_capacity > (std::size_t{1} << 31))
      throw std::invalid_argument("SpscRing: capacity must be between 1 and 2^31");
    return std::bit_ceil(min_capacity);
  }

  [[nodiscard]] bool has_item() const noexcept {
    return head_.load(std::memory_order_relaxed) != tail_.load(std::memory_order_acquire);
  }

  // Sleeping and waking. A side that must wait raises its `asleep` flag and
  // sleeps on a bell, a counter the other side advances to wake it (a futex
  // wait returns only when the word it watches changes, and a stop request
  // must be able to end a wait too). The futex is called directly rather
  // than through std::atomic::wait, which has no timeout. The other side rings
  // only when the flag is up, so a push or pop costs a fence and a load,
  // not a system call, while nobody sleeps. The two seq_cst fences (one in
  // sleep_until between raising the flag and checking the condition, one in
  // wake between the change and reading the flag) make sure that either the
  // sleeper sees the change or the waker sees the flag (Dekker's pattern).
  static void ring(std::atomic<std::uint32_t>& bell) noexcept {
    bell.fetch_add(1, std::memory_order_release);
    syscall(SYS_futex, futex_word(bell), FUTEX_WAKE_PRIVATE, INT32_MAX, nullptr, nullptr, 0);
  }

  // A lock-free std::atomic<std::uint32_t> is the 32-bit word itself.
  static std::uint32_t* futex_word(std::atomic<std::uint32_t>& bell) noexcept {
    static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t) &&
                  std::atomic<std::uint32_t>::is_always_lock_free);
    return reinterpret_cast<std::uint32_t*>(&bell);  // NOLINT(cppcoreguidelines-pro-type-reinterpret-cast)
  }

  // Sleeps while the bell still reads `seen`, at most `timeout` (none when
  // zero). Spurious returns are fine: every caller re-checks its condition.
  static void futex_wait(std::atomic<std::uint32_t>& bell, std::uint32_t seen,
                         std::chrono::steady_clock::duration timeout) noexcept {
    timespec relative{};
    timespec* limit = nullptr;
    if (timeout > std::chrono::steady_clock::duration::zero()) {
      const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(timeout).count();
      relative.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
      relative.tv_nsec = static_cast<long>(ns % 1'000'000'000);
      limit = &relative;
    }
    syscall(SYS_futex, futex_word(bell), FUTEX_WAIT_PRIVATE, seen, limit, nullptr, 0);
  }

  static void wake(const std::atomic<bool>& asleep, std::atomic<std::uint32_t>& bell) noexcept {
    std::atomic_thread_fence(std::memory_order_seq_cst);
    if (asleep.load(std::memory_order_relaxed)) ring(bell);
  }

  // Returns when `ready()` may have become true or `stop` was requested.
  // It polls for a few microseconds first: when the two sides run at about
  // the same pace, the other side is about to act, and without the poll the
  // waiting side would sleep, and cost the other side a system call to wake
  // it, after almost every item.
  template <class Ready>
  static void sleep_until(std::atomic<bool>& asleep, std::atomic<std::uint32_t>& bell, const std::stop_token& stop,
                          Ready ready,
                          std::chrono::steady_clock::duration timeout = std::chrono::steady_clock::duration::zero()) {
    for (int i = 0; i < kPollsBeforeSleep; ++i) {
      if (ready()) return;
      cpu_relax();
    }
    asleep.store(true, std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_seq_cst);
    // Read after the fence: a ring this read misses comes later and ends
    // the wait; one it sees carries the change with it (acquire), so
    // ready() below sees it too.
    const std::uint32_t seen = bell.load(std::memory_order_acquire);
    if (!ready() && !stop.stop_requested()) {
      const std::stop_callback on_stop(stop, [&bell] { ring(bell); });
      futex_wait(bell, seen, timeout);
      std::atomic_thread_fence(std::memory_order_acquire);
    }
    asleep.store(false, std::memory_order_relaxed);
  }

  static constexpr int kPollsBeforeSleep = 100;

  // Tells the core that this is a spin-wait loop (saves power, and on x86
  // avoids the memory-order mis-speculation when the awaited line changes).
  static void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    asm volatile("yield" ::: "memory");
#endif
  }

  const std::uint32_t mask_;
  const std::unique_ptr<std::atomic<T>[]> slots_;

  // Written by the producer.
  alignas(kCacheLineBytes) std::atomic<std::uint32_t> tail_{0};
  std::uint32_t cached_head_ = 0;  // the producer's last view of head_

  // Written by the consumer.
  alignas(kCacheLineBytes) std::atomic<std::uint32_t> head_{0};
  std::uint32_t cached_tail_ = 0;  // the consumer's last view of tail_

  // Written only around sleeps, read after every push or pop: a line of
  // their own stays in both cores' caches.
  alignas(kCacheLineBytes) std::atomic<bool> consumer_asleep_{false};
  std::atomic<bool> producer_asleep_{false};
  std::atomic<std::uint32_t> item_bell_{0};   // rung by the producer (and a stop request)
  std::atomic<std::uint32_t> space_bell_{0};  // rung by the consumer (and a stop request)
  // (The class's alignment rounds its size up to whole lines, so nothing
  // that follows a ring in memory shares the consumer's line either.)
};

}  // namespace markerd::daemon
