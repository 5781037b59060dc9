#pragma once
// A named stream of text lines (the detection log's lines, later a sweep's
// progress) from one producer thread to the control server, which copies
// each line out to the clients that follow the stream (docs/control.md).
//
// The producer is a pipeline stage and must never wait for a client: a
// line is copied into a ring of bytes allocated at construction, or, when
// the ring is full, dropped and counted. publish() takes no lock, makes no
// allocation, and at most one system call (a write to an eventfd that wakes
// the server, and only when the server has not been woken since it last
// looked). The consumer learns of drops in order: every line carries the
// number of lines dropped before it, so the server can tell its clients
// where lines are missing and how many.
//
// Exactly one producer thread and one consumer thread (the server's).

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <string_view>

#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/spsc_ring.hpp"

namespace markerd::daemon {

struct LineBroadcastStats {
  std::uint64_t published = 0;  // lines stored for the server
  std::uint64_t dropped = 0;    // lines lost: the ring was full (the server behind), or a line longer than the ring
  std::uint64_t unheard = 0;    // lines offered while nobody followed the stream (not stored, not dropped)
};

class LineBroadcast {
 public:
  static constexpr std::size_t kDefaultCapacityBytes = std::size_t{1} << 20;

  // `name` is the stream's name in the protocol ("detections"). The ring
  // holds `capacity_bytes` rounded up to a power of two (at least 4 KiB);
  // each line takes its length plus 16 bytes, rounded up to 8. Throws
  // std::system_error when the eventfd cannot be created.
  explicit LineBroadcast(std::string name, std::size_t capacity_bytes = kDefaultCapacityBytes);
  ~LineBroadcast();
  LineBroadcast(const LineBroadcast&) = delete;
  LineBroadcast& operator=(const LineBroadcast&) = delete;

  [[nodiscard]] const std::string& name() const noexcept { return name_; }
  [[nodiscard]] std::size_t capacity() const noexcept { return mask_ + 1; }

  // ---- producer (one thread) ----

  // Offers one line: no '\n' but an optional final one (the consumer ends
  // every line with exactly one). True when it was stored; false when nobody
  // follows the stream (counted as unheard) or it had to be dropped
  // (counted). Never waits.
  bool publish(std::string_view line) noexcept;

  // Whether anybody follows the stream: a producer may skip formatting
  // lines nobody will read.
  [[nodiscard]] bool listening() const noexcept { return listening_.load(std::memory_order_relaxed); }

  // ---- consumer (one thread) ----

  // Readable when lines (or drops) may be waiting: the server polls it.
  [[nodiscard]] int wake_fd() const noexcept { return wake_fd_.get(); }

  void set_listening(bool listening) noexcept { listening_.store(listening, std::memory_order_relaxed); }

  // Hands every waiting line to on_line(std::string_view line) (without its
  // '\n'; valid during the call only), in publication order, and each run of
  // dropped lines to on_dropped(std::uint64_t count) at its place in the
  // order. Resets the wake fd first, so a line published during the drain
  // wakes the server again.
  template <class OnLine, class OnDropped>
  void drain(OnLine&& on_line, OnDropped&& on_dropped);

  // Any thread.
  [[nodiscard]] LineBroadcastStats stats() const noexcept;

 private:
  struct Header {
    std::uint32_t length;  // of the line, or kPadding for the unused end of the ring
    std::uint32_t reserved;
    std::uint64_t dropped_before;  // lines the producer had dropped in all, before this one
  };
  static_assert(sizeof(Header) == 16);
  static constexpr std::uint32_t kPadding = 0xFFFFFFFFU;
  static constexpr std::size_t kAlign = 8;

  static constexpr std::size_t record_bytes(std::size_t length) noexcept {
    return (sizeof(Header) + length + kAlign - 1) & ~(kAlign - 1);
  }
  bool drop() noexcept;
  void ring_bell() noexcept;
  void clear_bell() noexcept;

  const std::string name_;
  const std::size_t mask_;
  const std::unique_ptr<char[]> bytes_;
  UniqueFd wake_fd_;

  // Positions are byte counts since the start; 64 bits never wrap.
  alignas(kCacheLineBytes) std::atomic<std::uint64_t> tail_{0};  // written by the producer
  std::uint64_t cached_head_ = 0;                                // the producer's last view of head_
  std::uint64_t producer_published_ = 0;
  std::uint64_t producer_dropped_ = 0;
  std::uint64_t producer_unheard_ = 0;
  std::atomic<std::uint64_t> published_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> unheard_{0};

  alignas(kCacheLineBytes) std::atomic<std::uint64_t> head_{0};  // written by the consumer
  std::uint64_t reported_dropped_ = 0;                           // the consumer's: drops handed to on_dropped

  // Raised by the producer when it writes to the eventfd, lowered by the
  // consumer when it reads it: one wake-up per drain, not one per line.
  alignas(kCacheLineBytes) std::atomic<bool> bell_pending_{false};
  std::atomic<bool> listening_{false};
};

template <class OnLine, class OnDropped>
void LineBroadcast::drain(OnLine&& on_line, OnDropped&& on_dropped) {
  clear_bell();
  std::uint64_t head = head_.load(std::memory_order_relaxed);
  // A few rounds at most: a producer that keeps publishing is left for the
  // next wake-up rather than holding the server here.
  for (int round = 0; round < 4; ++round) {
    const std::uint64_t tail = tail_.load(std::memory_order_acquire);
    while (head != tail) {
      const std::size_t offset = static_cast<std::size_t>(head) & mask_;
      const std::size_t to_end = capacity() - offset;
      if (to_end < sizeof(Header)) {  // too short for a header: skipped by the producer too
        head += to_end;
        continue;
      }
      Header header;
      std::memcpy(&header, bytes_.get() + offset, sizeof header);
      if (header.length == kPadding) {
        head += to_end;
        continue;
      }
      if (header.dropped_before > reported_dropped_) {
        on_dropped(header.dropped_before - reported_dropped_);
        reported_dropped_ = header.dropped_before;
      }
      on_line(std::string_view(bytes_.get() + offset + sizeof(Header), header.length));
      head += record_bytes(header.length);
      // Each record's room goes back at once: a producer in a burst gets it
      // while the server copies the rest out.
      head_.store(head, std::memory_order_release);
    }
    head_.store(head, std::memory_order_release);
    // Drops after the last line: reported now unless another line came
    // meanwhile (its header then places them; the drop count is stored
    // after the line it follows, so seeing the count means seeing the line).
    const std::uint64_t dropped = dropped_.load(std::memory_order_acquire);
    if (tail_.load(std::memory_order_acquire) != head) continue;
    if (dropped > reported_dropped_) {
      on_dropped(dropped - reported_dropped_);
      reported_dropped_ = dropped;
    }
    return;
  }
}

}  // namespace markerd::daemon
