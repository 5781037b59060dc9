#pragma once
// Image files read as 8-bit grey: the frames of the file source and the
// images of `markerctl detect`. A file is read only if it is a regular file
// of bounded size, its declared size (PNG IHDR, JPEG SOF, the PNM, BMP and
// TIFF headers) is checked before anything is decoded, and an image that does
// not decode whole (truncated, corrupt, a decoder's warning) is an error
// naming the file and the cause; the decoders print nothing themselves.
//
// Why here, in the daemon's capture: the JPEG decoder is the capture's MJPEG
// decoder (pixel_convert.hpp: one TurboJPEG path for camera frames and
// files), and the file source, which replays image files as a camera, is its
// main user. The detector takes pixels (GreyView) and stays free of image
// codecs; markerctl already links this library.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>

#include "markerd/detector/image.hpp"

namespace markerd::daemon {

// The largest image read: 64 megapixels (8000 x 8000; a 16-bit RGBA PNG of
// that size is 512 MiB of decoder rows), and no side longer than 65535 (the
// JPEG's own limit), so that a row buffer stays small too.
inline constexpr std::int64_t kMaxImagePixels = 64'000'000;
inline constexpr int kMaxImageSide = 65535;
// An image file larger than this is refused before it is read: an
// uncompressed 64-megapixel RGB image is 192 MB.
inline constexpr std::size_t kMaxImageFileBytes = std::size_t{256} << 20;

// what(): "<path>: <cause>".
class ImageFileError : public std::runtime_error {
 public:
  ImageFileError(const std::filesystem::path& path, std::string cause);
  // Why, without the path: "the PNG is truncated (...)".
  [[nodiscard]] const std::string& cause() const noexcept { return cause_; }

 private:
  std::string cause_;
};

struct ImageSize {
  int width = 0;
  int height = 0;
};

// Reads image files one after the other, keeping its decoders from one to
// the next. PNG (libpng) and JPEG (TurboJPEG) are decoded here; PNM, BMP and
// TIFF by OpenCV once their header has been checked. Other formats are
// refused. EXIF orientation is ignored: an image is taken as stored.
class ImageFileReader {
 public:
  ImageFileReader();
  ~ImageFileReader();
  ImageFileReader(const ImageFileReader&) = delete;
  ImageFileReader& operator=(const ImageFileReader&) = delete;

  // Reads the file and the size its header declares, refusing what is not a
  // regular file, what is larger than kMaxImageFileBytes, an unknown format
  // and a declared size beyond kMaxImagePixels or kMaxImageSide. Throws
  // ImageFileError.
  ImageSize open(const std::filesystem::path& path);
  // The same for an image already in memory (one read from standard input),
  // `path` naming it in errors.
  ImageSize open_bytes(std::string bytes, const std::filesystem::path& path);

  // Decodes the file open() read into `grey`, the open() size with rows of
  // `stride` bytes. Throws ImageFileError when it does not decode whole; the
  // rows are then undefined.
  void decode(std::uint8_t* grey, std::ptrdiff_t stride);

 private:
  enum class Format { none, png, jpeg, pnm, bmp, tiff };
  struct Decoders;
  std::unique_ptr<Decoders> decoders_;
  std::filesystem::path path_;
  std::string bytes_;
  Format format_ = Format::none;
  ImageSize size_;
};

// One image file as grey (open() and decode()). Throws ImageFileError.
[[nodiscard]] detector::GreyImage read_grey_image(const std::filesystem::path& path);

}  // namespace markerd::daemon
