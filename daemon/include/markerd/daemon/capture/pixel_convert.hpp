#pragma once
// Grey images from the pixel formats a camera sends that are not grey
// already: YUYV (its Y bytes, in one pass) and MJPEG (decoded by
// libjpeg-turbo's TurboJPEG API straight to grey, which decodes the Y
// component only; the same decoder reads JPEG files, image_file.hpp). Both
// write into a buffer the caller owns (a frame slot's pixel_buffer()) and
// allocate nothing themselves per frame.

#include <cstddef>
#include <cstdint>
#include <span>

namespace markerd::daemon {

class Frame;

// Copies the Y of every YUYV pixel (Y0 U Y1 V, two pixels in four bytes)
// into `grey`. `yuyv_stride` and `grey_stride` are bytes from one row to the
// next; `width` is in pixels and even.
void yuyv_to_grey(const std::uint8_t* yuyv, std::ptrdiff_t yuyv_stride, int width, int height, std::uint8_t* grey,
                  std::ptrdiff_t grey_stride) noexcept;

// One TurboJPEG decompressor: markerd's one JPEG decoder, for a camera's
// MJPEG frames (MjpegDecoder) and for JPEG files (image_file.hpp). Used by one
// thread at a time.
class JpegDecoder {
 public:
  enum class Outcome {
    ok,
    damaged,  // TurboJPEG warned: truncated data, a corrupt entropy segment
    failed,   // not a JPEG, or one TurboJPEG cannot decode to grey
  };

  // Throws std::runtime_error when TurboJPEG cannot make a decompressor.
  JpegDecoder();
  ~JpegDecoder();
  JpegDecoder(const JpegDecoder&) = delete;
  JpegDecoder& operator=(const JpegDecoder&) = delete;

  // The size the JPEG's frame header (SOF) declares, read without decoding
  // the image: a caller checks it before it commits memory to the pixels.
  [[nodiscard]] Outcome read_size(std::span<const std::uint8_t> jpeg, int& width, int& height) noexcept;

  // Decodes the Y component of `jpeg`, which read_size() found to be `width`
  // x `height`, into `grey` (rows of `grey_stride` bytes). Stops at the first
  // warning: a damaged image is no measurement, whole or not.
  [[nodiscard]] Outcome decode_grey(std::span<const std::uint8_t> jpeg, int width, int height, std::uint8_t* grey,
                                    std::ptrdiff_t grey_stride) noexcept;

  // TurboJPEG's words for the last failure; valid until the next call.
  [[nodiscard]] const char* message() const noexcept;

 private:
  void* handle_ = nullptr;  // tjhandle
};

// A camera's MJPEG frames, decoded by one JpegDecoder kept from frame to
// frame; used by one thread at a time.
class MjpegDecoder {
 public:
  // Throws std::runtime_error when TurboJPEG cannot make a decompressor.
  MjpegDecoder() = default;

  // Decodes `jpeg`, which must be a `width` x `height` image, into `grey`
  // (rows of `grey_stride` bytes). Returns null on success, or why the frame
  // cannot be read: TurboJPEG's own message (a warning such as a truncated
  // image counts: half a frame is no measurement), or a size other than the
  // one asked for. The text stays valid until the next call.
  [[nodiscard]] const char* decode(std::span<const std::uint8_t> jpeg, int width, int height, std::uint8_t* grey,
                                   std::ptrdiff_t grey_stride) noexcept;

 private:
  JpegDecoder jpeg_;
  char message_[160] = {};
};

// The DecodeFunction (frame.hpp) of the sources' MJPEG frames: decodes
// Frame::encoded() into the frame's image, which the source pointed at the
// slot's pixels (use_pixel_buffer()), or marks the frame corrupt_frame with
// the decoder's words. Each thread that decodes (each pipeline worker) has a
// decompressor of its own, made on its first frame.
void decode_mjpeg_frame(Frame& frame) noexcept;

}  // namespace markerd::daemon
