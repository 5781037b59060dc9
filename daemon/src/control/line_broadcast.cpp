#include "markerd/daemon/control/line_broadcast.hpp"

#include <sys/eventfd.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <system_error>

namespace markerd::daemon {
namespace {

std::size_t ring_capacity(std::size_t requested) {
  constexpr std::size_t kMinimum = 4096;
  return std::bit_ceil(std::max(requested, kMinimum));
}

}  // namespace

LineBroadcast::LineBroadcast(std::string name, std::size_t capacity_bytes)
    : name_(std::move(name)), mask_(ring_capacity(capacity_bytes) - 1), bytes_(std::make_unique<char[]>(mask_ + 1)) {
  wake_fd_.reset(::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC));
  if (!wake_fd_) {
    throw std::system_error(errno, std::generic_category(), "stream " + name_ + ": eventfd");
  }
}

LineBroadcast::~LineBroadcast() = default;

bool LineBroadcast::publish(std::string_view line) noexcept {
  if (!listening_.load(std::memory_order_relaxed)) {
    unheard_.store(++producer_unheard_, std::memory_order_relaxed);
    return false;
  }
  if (!line.empty() && line.back() == '\n') line.remove_suffix(1);
  const std::size_t need = record_bytes(line.size());
  if (line.size() >= kPadding || need > capacity()) return drop();

  std::uint64_t tail = tail_.load(std::memory_order_relaxed);
  const std::size_t offset = static_cast<std::size_t>(tail) & mask_;
  const std::size_t to_end = capacity() - offset;
  // A record never wraps: the consumer hands out each line as one view.
  const std::size_t skip = to_end < need ? to_end : 0;
  if (tail + skip + need - cached_head_ > capacity()) {
    cached_head_ = head_.load(std::memory_order_acquire);
    if (tail + skip + need - cached_head_ > capacity()) return drop();
  }
  if (skip >= sizeof(Header)) {
    const Header padding{kPadding, 0, 0};
    std::memcpy(bytes_.get() + offset, &padding, sizeof padding);
  }
  tail += skip;
  char* record = bytes_.get() + (static_cast<std::size_t>(tail) & mask_);
  const Header header{static_cast<std::uint32_t>(line.size()), 0, producer_dropped_};
  std::memcpy(record, &header, sizeof header);
  std::memcpy(record + sizeof header, line.data(), line.size());
  tail_.store(tail + need, std::memory_order_release);
  published_.store(++producer_published_, std::memory_order_relaxed);
  ring_bell();
  return true;
}

bool LineBroadcast::drop() noexcept {
  // Release: a consumer that sees this count also sees every line stored
  // before the drop (drain() relies on it to report drops in order).
  dropped_.store(++producer_dropped_, std::memory_order_release);
  ring_bell();
  return false;
}

void LineBroadcast::ring_bell() noexcept {
  // acq_rel pairs with clear_bell(): when this finds the bell already
  // pending, the consumer's coming exchange reads this one and with it the
  // line just stored, so its drain sees that line.
  if (!bell_pending_.exchange(true, std::memory_order_acq_rel)) {
    const std::uint64_t one = 1;
    // EFD_NONBLOCK: an eventfd write fails only when its counter would
    // overflow 2^64 - 2, which one write per drain never reaches.
    [[maybe_unused]] const ssize_t n = ::write(wake_fd_.get(), &one, sizeof one);
  }
}

void LineBroadcast::clear_bell() noexcept {
  std::uint64_t count = 0;
  [[maybe_unused]] const ssize_t n = ::read(wake_fd_.get(), &count, sizeof count);
  bell_pending_.exchange(false, std::memory_order_acq_rel);
}

LineBroadcastStats LineBroadcast::stats() const noexcept {
  LineBroadcastStats s;
  s.published = published_.load(std::memory_order_relaxed);
  s.dropped = dropped_.load(std::memory_order_relaxed);
  s.unheard = unheard_.load(std::memory_order_relaxed);
  return s;
}

}  // namespace markerd::daemon
