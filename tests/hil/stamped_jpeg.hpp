#pragma once
// The MJPEG frames of the emulated webcam (uvc_gadget_server.cpp): a scene's
// YUYV frame stamped with the frame's number (uvc_frames.hpp) and encoded as
// a webcam's JPEG (YCbCr 4:2:2, baseline, the standard Huffman tables).
//
// Encoding 640x480 takes about 10 ms in the HIL guest under TCG, a third of
// a frame interval at 30 frames per second on its one processor, which the
// host side's decoding and detection need. Only the stamp changes from frame
// to frame, and it lies within the first row of MCUs (8 pixel rows at 4:2:2).
// So each scene is encoded once with a restart marker after every MCU row,
// which makes each row's entropy-coded segment stand alone (the DC
// predictions start again, the bits are padded to a byte), and each frame
// encodes only its stamped first row and puts that segment in place of the
// scene's first one. The result is byte for byte the JPEG of the stamped
// frame (tests/hil/test_stamped_jpeg.cpp checks that), for about a sixtieth
// of the work.

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace markerd::hil {

// A JPEG of `rows` rows of a YUYV image `width` pixels wide (rows of
// width * 2 bytes), YCbCr 4:2:2 at `quality`; with a restart marker after
// every row of MCUs when `restart_every_row`.
std::vector<std::uint8_t> encode_yuyv_jpeg(const std::uint8_t* yuyv, int width, int rows, int quality,
                                           bool restart_every_row);

class StampedJpeg {
 public:
  // One YUYV frame of `width` x `height` pixels; `height` a multiple of 8.
  StampedJpeg(std::span<const std::uint8_t> yuyv, int width, int height, int quality);

  // Writes the JPEG of the frame stamped with `number` into `out` and
  // returns its length. Throws std::length_error when it does not fit.
  std::size_t write(std::uint32_t number, std::span<std::uint8_t> out);

 private:
  int width_;
  int quality_;
  std::vector<std::uint8_t> first_row_;  // the scene's first MCU row, YUYV, unstamped
  std::vector<std::uint8_t> stamped_;    // scratch: that row stamped
  std::vector<std::uint8_t> head_;       // the scene's JPEG up to its first entropy-coded segment
  std::vector<std::uint8_t> tail_;       // from the restart marker after that segment to the end
};

}  // namespace markerd::hil
