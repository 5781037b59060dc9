#include "markerd/daemon/frame_pool.hpp"

#include <cassert>
#include <new>
#include <stdexcept>

namespace markerd::daemon {

namespace {

constexpr std::size_t round_up_to_line(std::size_t bytes) {
  return (bytes + kCacheLineBytes - 1) / kCacheLineBytes * kCacheLineBytes;
}

}  // namespace

void FramePool::PixelsDeleter::operator()(std::uint8_t* p) const noexcept {
  ::operator delete[](p, std::align_val_t{kCacheLineBytes});
}

FramePool::FramePool(const FramePoolConfig& config)
    : slot_count_(config.slots),
      frames_(config.slots > 0 ? new Frame[config.slots] : nullptr),
      free_(config.slots > 0 ? config.slots : 1) {
  if (config.slots == 0) throw std::invalid_argument("frame pool: at least one frame slot is needed");
  // One block for every slot's pixels, each slot starting on its own cache
  // line so that two threads writing neighbouring slots never share one.
  const std::size_t stride = round_up_to_line(config.pixel_bytes);
  if (stride > 0) {
    pixels_.reset(
        static_cast<std::uint8_t*>(::operator new[](stride* config.slots, std::align_val_t{kCacheLineBytes})));
  }
  for (std::size_t i = 0; i < config.slots; ++i) {
    Frame& frame = frames_[i];
    if (stride > 0) frame.pixel_buffer_ = {pixels_.get() + i * stride, config.pixel_bytes};
    frame.detections.reserve(config.detections);
    const bool pushed = free_.try_push(&frame);
    assert(pushed);
    (void)pushed;
  }
}

Frame* FramePool::try_acquire() noexcept {
  const auto slot = free_.try_pop();
  if (!slot) return nullptr;
  (*slot)->reset();
  return *slot;
}

Frame* FramePool::acquire(const std::stop_token& stop) {
  for (;;) {
    if (Frame* frame = try_acquire()) return frame;
    if (!free_.wait_for_item(stop)) return nullptr;
  }
}

void FramePool::release(Frame& frame) noexcept {
  assert(owns(frame));
  frame.release_source();
  // The ring holds every slot at once, so there is always room.
  const bool pushed = free_.try_push(&frame);
  assert(pushed);
  (void)pushed;
}

bool FramePool::owns(const Frame& frame) const noexcept {
  const Frame* first = frames_.get();
  // Compared as integers: relational comparison of pointers into different
  // objects is unspecified.
  const auto address = reinterpret_cast<std::uintptr_t>(&frame);
  const auto begin = reinterpret_cast<std::uintptr_t>(first);
  const auto end = reinterpret_cast<std::uintptr_t>(first + slot_count_);
  return address >= begin && address < end && (address - begin) % sizeof(Frame) == 0;
}

}  // namespace markerd::daemon
