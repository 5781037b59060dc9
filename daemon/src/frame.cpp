#include "markerd/daemon/frame.hpp"

#include <algorithm>
#include <cassert>
#include <stdexcept>
#include <string>
#include <utility>

namespace markerd::daemon {

void Frame::set_cause(std::string_view cause) noexcept {
  cause_length_ = std::min(cause.size(), cause_.size());
  std::copy_n(cause.data(), cause_length_, cause_.data());
}

void Frame::mark_corrupt(std::string_view cause) noexcept {
  image = {};
  status = FrameStatus::corrupt_frame;
  set_cause(cause);
}

detector::GreyView Frame::use_pixel_buffer(int width, int height) {
  const auto bytes = static_cast<std::size_t>(std::max(width, 0)) * static_cast<std::size_t>(std::max(height, 0));
  if (width <= 0 || height <= 0 || bytes > pixel_buffer_.size()) {
    throw std::length_error("frame pool: a " + std::to_string(width) + "x" + std::to_string(height) +
                            " grey image does not fit a slot of " + std::to_string(pixel_buffer_.size()) +
                            " bytes (the pool's pixel size is set from the camera's format at start)");
  }
  image = detector::GreyView{pixel_buffer_.data(), width, height, width};
  return image;
}

void Frame::set_release(ReleaseHook hook) noexcept {
  // A frame borrows from one source buffer at a time; replacing a hook that
  // was never called would leak that buffer.
  assert(!release_);
  release_ = hook;
}

void Frame::set_encoded(std::span<const std::uint8_t> data, DecodeFunction decoder) noexcept {
  encoded_ = data;
  decode_ = decoder;
}

void Frame::decode() noexcept {
  const DecodeFunction decoder = std::exchange(decode_, nullptr);
  if (decoder == nullptr) return;
  decoder(*this);
  encoded_ = {};
  release_source();
}

void Frame::release_source() noexcept {
  const ReleaseHook hook = release_;
  release_ = {};
  if (hook) hook.release(hook.context, hook.token);
}

void Frame::reset() noexcept {
  assert(!release_);
  sequence = 0;
  capture_time = {};
  source_id = 0;
  rig.reset();
  image = {};
  encoded_ = {};
  decode_ = nullptr;
  status = FrameStatus::ok;
  detections.clear();
  times = {};
  cause_length_ = 0;
  ticket_ = 0;
  discarded_ = false;
}

}  // namespace markerd::daemon
