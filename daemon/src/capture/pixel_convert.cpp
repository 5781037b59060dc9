#include "markerd/daemon/capture/pixel_convert.hpp"

#include <turbojpeg.h>

#include <cassert>
#include <cstdio>
#include <exception>
#include <memory>
#include <stdexcept>
#include <string>

#include "markerd/daemon/frame.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace markerd::daemon {

namespace {

void yuyv_row_to_grey(const std::uint8_t* in, std::uint8_t* out, int width) noexcept {
  int x = 0;
#if defined(__SSE2__)
  // 16 pixels a step: the Y bytes are the low byte of each 16-bit word;
  // masking the chroma off and packing with unsigned saturation keeps them.
  const __m128i low_bytes = _mm_set1_epi16(0x00ff);
  for (; x + 16 <= width; x += 16) {
    const __m128i a = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + 2 * x));
    const __m128i b = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + 2 * x + 16));
    const __m128i y = _mm_packus_epi16(_mm_and_si128(a, low_bytes), _mm_and_si128(b, low_bytes));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + x), y);
  }
#endif
  for (; x < width; ++x) out[x] = in[2 * x];
}

}  // namespace

void yuyv_to_grey(const std::uint8_t* yuyv, std::ptrdiff_t yuyv_stride, int width, int height, std::uint8_t* grey,
                  std::ptrdiff_t grey_stride) noexcept {
  for (int y = 0; y < height; ++y) {
    yuyv_row_to_grey(yuyv + y * yuyv_stride, grey + y * grey_stride, width);
  }
}

JpegDecoder::JpegDecoder() : handle_(tjInitDecompress()) {
  if (handle_ == nullptr) {
    throw std::runtime_error(std::string("TurboJPEG: cannot make a decompressor: ") + tjGetErrorStr2(nullptr));
  }
}

JpegDecoder::~JpegDecoder() { tjDestroy(handle_); }

JpegDecoder::Outcome JpegDecoder::read_size(std::span<const std::uint8_t> jpeg, int& width, int& height) noexcept {
  int subsampling = 0;
  int colorspace = 0;
  if (tjDecompressHeader3(handle_, jpeg.data(), jpeg.size(), &width, &height, &subsampling, &colorspace) != 0) {
    return tjGetErrorCode(handle_) == TJERR_WARNING ? Outcome::damaged : Outcome::failed;
  }
  return Outcome::ok;
}

JpegDecoder::Outcome JpegDecoder::decode_grey(std::span<const std::uint8_t> jpeg, int width, int height,
                                              std::uint8_t* grey, std::ptrdiff_t grey_stride) noexcept {
  // LIMITSCANS: a progressive JPEG of thousands of tiny scans takes minutes
  // to decode; no camera or encoder writes more than a few dozen.
  if (tjDecompress2(handle_, jpeg.data(), jpeg.size(), grey, width, static_cast<int>(grey_stride), height, TJPF_GRAY,
                    TJFLAG_STOPONWARNING | TJFLAG_LIMITSCANS) != 0) {
    return tjGetErrorCode(handle_) == TJERR_WARNING ? Outcome::damaged : Outcome::failed;
  }
  return Outcome::ok;
}

const char* JpegDecoder::message() const noexcept { return tjGetErrorStr2(handle_); }

const char* MjpegDecoder::decode(std::span<const std::uint8_t> jpeg, int width, int height, std::uint8_t* grey,
                                 std::ptrdiff_t grey_stride) noexcept {
  if (jpeg.empty()) {
    std::snprintf(message_, sizeof message_, "MJPEG: the frame is empty (0 bytes)");
    return message_;
  }
  int jpeg_width = 0;
  int jpeg_height = 0;
  if (jpeg_.read_size(jpeg, jpeg_width, jpeg_height) != JpegDecoder::Outcome::ok) {
    std::snprintf(message_, sizeof message_, "MJPEG: %s", jpeg_.message());
    return message_;
  }
  if (jpeg_width != width || jpeg_height != height) {
    std::snprintf(message_, sizeof message_, "MJPEG: the frame is %dx%d, the stream was set up for %dx%d", jpeg_width,
                  jpeg_height, width, height);
    return message_;
  }
  if (jpeg_.decode_grey(jpeg, width, height, grey, grey_stride) != JpegDecoder::Outcome::ok) {
    std::snprintf(message_, sizeof message_, "MJPEG: %s", jpeg_.message());
    return message_;
  }
  return nullptr;
}

void decode_mjpeg_frame(Frame& frame) noexcept {
  thread_local std::unique_ptr<MjpegDecoder> decoder;
  if (!decoder) {
    try {
      decoder = std::make_unique<MjpegDecoder>();
    } catch (const std::exception& e) {
      return frame.mark_corrupt(e.what());
    }
  }
  const detector::GreyView image = frame.image;
  assert(image.data == frame.pixel_buffer().data());
  if (const char* why =
          decoder->decode(frame.encoded(), image.width, image.height, frame.pixel_buffer().data(), image.stride)) {
    frame.mark_corrupt(why);
  }
}

}  // namespace markerd::daemon
