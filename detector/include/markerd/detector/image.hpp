#pragma once
// Grey images as the detector sees them: a borrowed view (a camera's mmap
// buffer, a cv::Mat, a frame-pool slot) and an owning image for the renderer
// and the tests. The detector never copies the pixels of a view.

#include <cstddef>
#include <cstdint>
#include <vector>

namespace markerd::detector {

struct GreyView {
  const std::uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride = 0;  // bytes from one row to the next

  [[nodiscard]] bool empty() const { return data == nullptr || width <= 0 || height <= 0; }
  [[nodiscard]] const std::uint8_t* row(int y) const { return data + y * stride; }
  [[nodiscard]] std::uint8_t at(int x, int y) const { return row(y)[x]; }
};

class GreyImage {
 public:
  GreyImage() = default;
  GreyImage(int width, int height, std::uint8_t fill = 0)
      : width_(width), height_(height), pixels_(static_cast<std::size_t>(width) * height, fill) {}

  [[nodiscard]] int width() const { return width_; }
  [[nodiscard]] int height() const { return height_; }
  [[nodiscard]] bool empty() const { return pixels_.empty(); }
  [[nodiscard]] std::uint8_t* data() { return pixels_.data(); }
  [[nodiscard]] const std::uint8_t* data() const { return pixels_.data(); }
  [[nodiscard]] std::uint8_t* row(int y) { return pixels_.data() + static_cast<std::size_t>(y) * width_; }
  [[nodiscard]] const std::uint8_t* row(int y) const { return pixels_.data() + static_cast<std::size_t>(y) * width_; }
  [[nodiscard]] std::uint8_t& at(int x, int y) { return row(y)[x]; }
  [[nodiscard]] std::uint8_t at(int x, int y) const { return row(y)[x]; }
  [[nodiscard]] GreyView view() const { return {pixels_.data(), width_, height_, width_}; }
  operator GreyView() const { return view(); }  // NOLINT(google-explicit-constructor): a view is cheap

 private:
  int width_ = 0;
  int height_ = 0;
  std::vector<std::uint8_t> pixels_;
};

}  // namespace markerd::detector
