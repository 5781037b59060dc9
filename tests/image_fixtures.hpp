#pragma once
// Broken image files made in the tests rather than committed: a file cut
// short, a JPEG whose entropy-coded data is damaged, a PNG whose header
// declares a decompression bomb, a FIFO.

#include <sys/stat.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace markerd::test_support {

using Bytes = std::vector<std::uint8_t>;

inline void write_bytes(const std::filesystem::path& path, const Bytes& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

inline Bytes first_half(const Bytes& bytes) {
  return {bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(bytes.size() / 2)};
}

// Flips every bit of a run of bytes in the middle of the entropy-coded data
// (after the start-of-scan header, before the end-of-image marker): the
// headers stay whole, so the file looks like a JPEG of the right size.
inline Bytes with_corrupt_entropy_data(Bytes jpeg) {
  std::size_t scan = 0;
  for (std::size_t i = 2; i + 3 < jpeg.size(); ++i) {
    if (jpeg[i] == 0xff && jpeg[i + 1] == 0xda) {
      scan = i + 2 + ((std::size_t{jpeg[i + 2]} << 8) | jpeg[i + 3]);
      break;
    }
  }
  if (scan == 0 || scan + 16 >= jpeg.size()) return {};
  const std::size_t data = jpeg.size() - 2 - scan;
  for (std::size_t i = scan + data / 3; i < scan + data / 3 + data / 4; ++i) {
    jpeg[i] = static_cast<std::uint8_t>(~jpeg[i]);
  }
  return jpeg;
}

inline std::uint32_t crc32(const std::uint8_t* data, std::size_t size) {
  std::uint32_t crc = 0xffffffffU;
  for (std::size_t i = 0; i < size; ++i) {
    crc ^= data[i];
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ (0xedb88320U & (0U - (crc & 1U)));
  }
  return ~crc;
}

inline void append_png_chunk(Bytes& png, const char (&type)[5], const Bytes& data) {
  const auto put32 = [&png](std::uint32_t v) {
    for (int shift = 24; shift >= 0; shift -= 8) png.push_back(static_cast<std::uint8_t>(v >> shift));
  };
  put32(static_cast<std::uint32_t>(data.size()));
  const std::size_t start = png.size();
  png.insert(png.end(), type, type + 4);
  png.insert(png.end(), data.begin(), data.end());
  put32(crc32(png.data() + start, png.size() - start));
}

// A valid-looking PNG (8-bit grey) whose IHDR declares width x height, with
// one empty IDAT and IEND: some 60 bytes that a decoder that trusts the
// header would meet with width x height bytes of memory.
inline Bytes png_declaring(std::uint32_t width, std::uint32_t height) {
  Bytes png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  Bytes ihdr;
  for (const std::uint32_t v : {width, height}) {
    for (int shift = 24; shift >= 0; shift -= 8) ihdr.push_back(static_cast<std::uint8_t>(v >> shift));
  }
  ihdr.insert(ihdr.end(), {8, 0, 0, 0, 0});  // depth 8, grey, deflate, no filter, no interlace
  append_png_chunk(png, "IHDR", ihdr);
  append_png_chunk(png, "IDAT", {0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01});  // zlib of nothing
  append_png_chunk(png, "IEND", {});
  return png;
}

inline bool make_fifo(const std::filesystem::path& path) { return ::mkfifo(path.c_str(), 0600) == 0; }

}  // namespace markerd::test_support
