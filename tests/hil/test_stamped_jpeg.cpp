// The emulated webcam's MJPEG frames (stamped_jpeg.hpp), on the build
// machine: a frame spliced from the scene's JPEG and its stamped first row
// is the very JPEG of the stamped frame, and markerd's own decoder reads it
// back with its number.

#include "stamped_jpeg.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <vector>

#include "markerd/daemon/capture/pixel_convert.hpp"
#include "uvc_frames.hpp"
#include "vivid_scene_feeder.hpp"

namespace markerd::hil {
namespace {

constexpr int kQuality = 90;

class StampedJpegTest : public ::testing::Test {
 protected:
  void SetUp() override {
    grey_ = detector::render_scene(feeder_camera(), feeder_scenes().front());
    yuyv_ = to_yuyv(grey_);
  }
  detector::GreyImage grey_;
  std::vector<std::uint8_t> yuyv_;
};

TEST_F(StampedJpegTest, IsTheJpegOfTheStampedFrameByteForByte) {
  StampedJpeg jpeg(yuyv_, kWidth, kHeight, kQuality);
  std::vector<std::uint8_t> out(static_cast<std::size_t>(kWidth) * kHeight * 2);
  for (const std::uint32_t number : {0U, 1U, 0x12345678U, 0xFFFFFFFFU}) {
    std::vector<std::uint8_t> stamped = yuyv_;
    stamp_yuyv(stamped.data(), static_cast<std::size_t>(kWidth) * 2, number);
    const std::vector<std::uint8_t> whole = encode_yuyv_jpeg(stamped.data(), kWidth, kHeight, kQuality, true);
    const std::size_t length = jpeg.write(number, out);
    EXPECT_EQ(std::vector<std::uint8_t>(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(length)), whole)
        << "frame " << number;
  }
}

TEST_F(StampedJpegTest, DecodesToTheFrameWithItsNumber) {
  StampedJpeg jpeg(yuyv_, kWidth, kHeight, kQuality);
  std::vector<std::uint8_t> out(static_cast<std::size_t>(kWidth) * kHeight * 2);
  daemon::MjpegDecoder decoder;
  detector::GreyImage decoded(kWidth, kHeight);
  for (const std::uint32_t number : {7U, 0xA5A5A5A5U}) {
    const std::size_t length = jpeg.write(number, out);
    const char* why = decoder.decode({out.data(), length}, kWidth, kHeight, decoded.row(0), kWidth);
    ASSERT_EQ(why, nullptr) << why;
    EXPECT_EQ(read_stamp(decoded.view()), number);
    // Below the stamp, the scene as rendered, up to the JPEG's loss (mostly
    // the rendered sensor noise: 1.5 grey levels on average at quality 90;
    // a mix-up of the components would be tens).
    long difference = 0;  // NOLINT(google-runtime-int)
    for (int y = kStampRows; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) difference += std::abs(int{decoded.row(y)[x]} - int{grey_.row(y)[x]});
    }
    EXPECT_LT(static_cast<double>(difference) / (kWidth * (kHeight - kStampRows)), 3.0);
  }
}

TEST_F(StampedJpegTest, SaysWhenTheBufferIsTooSmall) {
  StampedJpeg jpeg(yuyv_, kWidth, kHeight, kQuality);
  std::vector<std::uint8_t> out(1000);
  EXPECT_THROW(jpeg.write(1, out), std::length_error);
}

}  // namespace
}  // namespace markerd::hil
