#include "stamped_jpeg.hpp"

// jpeglib.h needs size_t and FILE declared first (a block of their own,
// which clang-format does not sort past).
#include <csetjmp>
#include <cstdio>
#include <cstdlib>

#include <jpeglib.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <string>

#include "uvc_frames.hpp"

namespace markerd::hil {
namespace {

constexpr int kMcuRows = 8;  // pixel rows of an MCU at 4:2:2 (h2v1)
constexpr std::uint8_t kMarker = 0xFF;
constexpr std::uint8_t kStartOfScan = 0xDA;
constexpr std::uint8_t kRestart0 = 0xD0;
constexpr std::uint8_t kEndOfImage = 0xD9;

// libjpeg reports errors by calling error_exit, which must not return: it
// jumps back to the encoder's frame, which throws from there, so that no
// C++ exception crosses libjpeg's C frames.
struct ErrorManager {
  jpeg_error_mgr base{};
  std::jmp_buf jump{};
  char message[JMSG_LENGTH_MAX] = {};
};

[[noreturn]] void jump_out(j_common_ptr cinfo) {
  auto* errors = reinterpret_cast<ErrorManager*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, errors->message);
  std::longjmp(errors->jump, 1);
}

// jpeg_mem_dest's buffer, which libjpeg allocates and may move while it
// grows; behind a pointer so that the jump back finds its latest value.
struct Output {
  unsigned char* data = nullptr;
  unsigned long size = 0;  // NOLINT(google-runtime-int): jpeg_mem_dest's type
};

// Where the entropy-coded data of a JPEG's (only) scan begins: just after
// its SOS segment. Segments before it are a marker and a big-endian length
// that counts itself.
std::size_t scan_data_start(std::span<const std::uint8_t> jpeg) {
  std::size_t at = 2;  // after SOI
  while (at + 4 <= jpeg.size()) {
    if (jpeg[at] != kMarker) break;
    const std::uint8_t marker = jpeg[at + 1];
    const std::size_t length = (std::size_t{jpeg[at + 2]} << 8) | jpeg[at + 3];
    at += 2 + length;
    if (marker == kStartOfScan) return at;
  }
  throw std::runtime_error("stamped JPEG: no scan in the encoder's output");
}

// The first marker `second` (0xFF then `second`) at or after `from`. In
// entropy-coded data every 0xFF byte is followed by a stuffed 0x00, so a
// marker found there is a marker.
std::size_t find_marker(std::span<const std::uint8_t> jpeg, std::size_t from, std::uint8_t second) {
  for (std::size_t i = from; i + 1 < jpeg.size(); ++i) {
    if (jpeg[i] == kMarker && jpeg[i + 1] == second) return i;
  }
  throw std::runtime_error("stamped JPEG: a marker missing from the encoder's output");
}

}  // namespace

std::vector<std::uint8_t> encode_yuyv_jpeg(const std::uint8_t* yuyv, int width, int rows, int quality,
                                           bool restart_every_row) {
  std::vector<JSAMPLE> line(static_cast<std::size_t>(width) * 3);
  Output output;
  jpeg_compress_struct cinfo{};
  ErrorManager errors;
  cinfo.err = jpeg_std_error(&errors.base);
  errors.base.error_exit = jump_out;
  if (setjmp(errors.jump) != 0) {  // NOLINT(cert-err52-cpp): libjpeg's error protocol; see ErrorManager
    jpeg_destroy_compress(&cinfo);
    std::free(output.data);  // NOLINT(cppcoreguidelines-no-malloc): jpeg_mem_dest's malloc
    throw std::runtime_error(std::string("libjpeg: ") + errors.message);
  }
  jpeg_create_compress(&cinfo);
  jpeg_mem_dest(&cinfo, &output.data, &output.size);
  cinfo.image_width = static_cast<JDIMENSION>(width);
  cinfo.image_height = static_cast<JDIMENSION>(rows);
  cinfo.input_components = 3;
  cinfo.in_color_space = JCS_YCbCr;
  jpeg_set_defaults(&cinfo);
  jpeg_set_quality(&cinfo, quality, TRUE);
  // 4:2:2, what UVC webcams send: Y at full width, Cb and Cr at half.
  cinfo.comp_info[0].h_samp_factor = 2;
  cinfo.comp_info[0].v_samp_factor = 1;
  for (int c = 1; c < 3; ++c) {
    cinfo.comp_info[c].h_samp_factor = 1;
    cinfo.comp_info[c].v_samp_factor = 1;
  }
  if (restart_every_row) cinfo.restart_in_rows = 1;
  jpeg_start_compress(&cinfo, TRUE);
  while (cinfo.next_scanline < cinfo.image_height) {
    const std::uint8_t* in = yuyv + static_cast<std::size_t>(cinfo.next_scanline) * width * 2;
    for (int x = 0; x < width; x += 2, in += 4) {
      JSAMPLE* out = &line[static_cast<std::size_t>(x) * 3];
      out[0] = in[0];
      out[1] = in[1];
      out[2] = in[3];
      out[3] = in[2];
      out[4] = in[1];
      out[5] = in[3];
    }
    JSAMPROW row = line.data();
    jpeg_write_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_compress(&cinfo);
  jpeg_destroy_compress(&cinfo);
  std::vector<std::uint8_t> jpeg(output.data, output.data + output.size);
  std::free(output.data);  // NOLINT(cppcoreguidelines-no-malloc)
  return jpeg;
}

StampedJpeg::StampedJpeg(std::span<const std::uint8_t> yuyv, int width, int height, int quality)
    : width_(width), quality_(quality) {
  const auto row_bytes = static_cast<std::size_t>(width) * 2;
  if (height % kMcuRows != 0 || yuyv.size() != row_bytes * static_cast<std::size_t>(height)) {
    throw std::invalid_argument("StampedJpeg: not a YUYV frame of whole MCU rows");
  }
  if (kStampRows > kMcuRows) throw std::invalid_argument("StampedJpeg: the stamp spans two MCU rows");
  first_row_.assign(yuyv.begin(), yuyv.begin() + static_cast<std::ptrdiff_t>(row_bytes * kMcuRows));
  stamped_.resize(first_row_.size());
  const std::vector<std::uint8_t> scene = encode_yuyv_jpeg(yuyv.data(), width, height, quality, true);
  const std::size_t first_segment = scan_data_start(scene);
  const std::size_t second_segment = find_marker(scene, first_segment, kRestart0);
  head_.assign(scene.begin(), scene.begin() + static_cast<std::ptrdiff_t>(first_segment));
  tail_.assign(scene.begin() + static_cast<std::ptrdiff_t>(second_segment), scene.end());
}

std::size_t StampedJpeg::write(std::uint32_t number, std::span<std::uint8_t> out) {
  std::copy(first_row_.begin(), first_row_.end(), stamped_.begin());
  stamp_yuyv(stamped_.data(), static_cast<std::size_t>(width_) * 2, number);
  const std::vector<std::uint8_t> row = encode_yuyv_jpeg(stamped_.data(), width_, kMcuRows, quality_, false);
  const std::size_t begin = scan_data_start(row);
  const std::size_t end = find_marker(row, begin, kEndOfImage);
  const std::size_t length = head_.size() + (end - begin) + tail_.size();
  if (length > out.size()) {
    throw std::length_error("stamped JPEG: " + std::to_string(length) + " bytes for a buffer of " +
                            std::to_string(out.size()));
  }
  std::uint8_t* at = std::copy(head_.begin(), head_.end(), out.data());
  at = std::copy(row.begin() + static_cast<std::ptrdiff_t>(begin), row.begin() + static_cast<std::ptrdiff_t>(end), at);
  std::copy(tail_.begin(), tail_.end(), at);
  return length;
}

}  // namespace markerd::hil
