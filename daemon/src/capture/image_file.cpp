#include "markerd/daemon/capture/image_file.hpp"

#include <png.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <csetjmp>
#include <cstring>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string_view>
#include <vector>

#include "markerd/base/read_file.hpp"
#include "markerd/daemon/capture/pixel_convert.hpp"

namespace markerd::daemon {

namespace {

std::span<const std::uint8_t> as_bytes(const std::string& bytes) {
  return {reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()};
}

std::uint32_t big_endian_32(const std::uint8_t* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) | p[3];
}
std::uint32_t little_endian_32(const std::uint8_t* p) {
  return (std::uint32_t{p[3]} << 24) | (std::uint32_t{p[2]} << 16) | (std::uint32_t{p[1]} << 8) | p[0];
}
std::uint16_t little_endian_16(const std::uint8_t* p) { return static_cast<std::uint16_t>(p[0] | (p[1] << 8)); }

// A declared size, wider than int: a header may declare anything.
struct DeclaredSize {
  std::int64_t width = 0;
  std::int64_t height = 0;
};

// ------------------------------------------------------------------ headers

constexpr std::array<std::uint8_t, 8> kPngSignature = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

// IHDR must come first: signature, length 13, "IHDR", width, height.
std::string png_size(std::span<const std::uint8_t> b, DeclaredSize& size) {
  if (b.size() < 24) return "the PNG is truncated: it ends inside its header";
  if (big_endian_32(b.data() + 8) != 13 || std::memcmp(b.data() + 12, "IHDR", 4) != 0) {
    return "the PNG is corrupt: it does not begin with its header chunk (IHDR)";
  }
  size = {big_endian_32(b.data() + 16), big_endian_32(b.data() + 20)};
  return {};
}

// "P5 640 480 255": the numbers, with '#' comments to the end of a line.
std::string pnm_size(std::span<const std::uint8_t> b, DeclaredSize& size) {
  std::size_t i = 2;
  std::array<std::int64_t, 2> numbers{};
  for (auto& number : numbers) {
    for (;;) {
      if (i >= b.size()) return "the PNM is truncated: it ends inside its header";
      if (b[i] == '#') {
        while (i < b.size() && b[i] != '\n') ++i;
      } else if (b[i] == ' ' || b[i] == '\t' || b[i] == '\r' || b[i] == '\n') {
        ++i;
      } else {
        break;
      }
    }
    if (b[i] < '0' || b[i] > '9') return "the PNM is corrupt: its header holds no size";
    for (int digits = 0; i < b.size() && b[i] >= '0' && b[i] <= '9'; ++i, ++digits) {
      if (digits == 9) return "the PNM is corrupt: its header declares a size of more than 9 digits";
      number = number * 10 + (b[i] - '0');
    }
  }
  size = {numbers[0], numbers[1]};
  return {};
}

// BITMAPFILEHEADER (14 bytes), then the DIB header: 12 bytes (OS/2, 16-bit
// sides) or larger (32-bit sides; a negative height: rows top down).
std::string bmp_size(std::span<const std::uint8_t> b, DeclaredSize& size) {
  if (b.size() < 26) return "the BMP is truncated: it ends inside its header";
  const std::uint32_t header_size = little_endian_32(b.data() + 14);
  if (header_size == 12) {
    size = {little_endian_16(b.data() + 18), little_endian_16(b.data() + 20)};
    return {};
  }
  if (header_size < 16) return fmt::format("the BMP is corrupt: a header of {} bytes", header_size);
  const auto width = static_cast<std::int32_t>(little_endian_32(b.data() + 18));
  const auto height = static_cast<std::int32_t>(little_endian_32(b.data() + 22));
  size = {width, height < 0 ? -static_cast<std::int64_t>(height) : height};
  return {};
}

// The first directory's ImageWidth (256) and ImageLength (257), SHORT or LONG.
std::string tiff_size(std::span<const std::uint8_t> b, DeclaredSize& size) {
  if (b.size() < 8) return "the TIFF is truncated: it ends inside its header";
  const bool little = b[0] == 'I';
  const auto u16 = [&](std::size_t at) {
    return static_cast<std::uint32_t>(little ? b[at] | (b[at + 1] << 8) : (b[at] << 8) | b[at + 1]);
  };
  const auto u32 = [&](std::size_t at) { return little ? little_endian_32(&b[at]) : big_endian_32(&b[at]); };
  if (u16(2) == 43) return "the TIFF is a BigTIFF, which markerd does not read";
  const std::size_t directory = u32(4);
  if (directory > b.size() || b.size() - directory < 2) return "the TIFF is truncated: its directory is missing";
  const std::size_t entries = u16(directory);
  if ((b.size() - directory - 2) / 12 < entries) return "the TIFF is truncated: it ends inside its directory";
  std::int64_t width = -1;
  std::int64_t height = -1;
  for (std::size_t e = 0; e < entries; ++e) {
    const std::size_t at = directory + 2 + 12 * e;
    const std::uint32_t tag = u16(at);
    const std::uint32_t type = u16(at + 2);
    if (tag != 256 && tag != 257) continue;
    if (type != 3 && type != 4) return fmt::format("the TIFF is corrupt: its tag {} is of type {}", tag, type);
    const std::int64_t value = type == 3 ? u16(at + 8) : u32(at + 8);
    (tag == 256 ? width : height) = value;
  }
  if (width < 0 || height < 0) return "the TIFF is corrupt: its directory declares no image size";
  size = {width, height};
  return {};
}

// -------------------------------------------------------------------- PNG

// libpng reports through these rather than on stderr.
struct PngContext {
  std::span<const std::uint8_t> bytes;
  std::size_t offset = 0;
  bool truncated = false;
  std::string error;
  std::string warning;  // the first
};

void png_read_bytes(png_structp png, png_bytep out, std::size_t length) {
  auto* context = static_cast<PngContext*>(png_get_io_ptr(png));
  if (length > context->bytes.size() - context->offset) {
    context->truncated = true;
    png_error(png, "the file ends before the image does");
  }
  std::memcpy(out, context->bytes.data() + context->offset, length);
  context->offset += length;
}

void png_on_error(png_structp png, png_const_charp message) {
  auto* context = static_cast<PngContext*>(png_get_error_ptr(png));
  if (context->error.empty()) context->error = message;
  png_longjmp(png, 1);
}

void png_on_warning(png_structp png, png_const_charp message) {
  auto* context = static_cast<PngContext*>(png_get_error_ptr(png));
  if (context->warning.empty()) context->warning = message;
}

// Decodes to 8-bit grey with the transformations OpenCV's imread applies for
// IMREAD_GRAYSCALE (the same weights, so that both give the same pixels).
// Everything with a destructor lives in the caller: libpng leaves by
// longjmp. Returns whether libpng finished without an error.
bool decode_png(PngContext& context, int width, int height, std::uint8_t* grey, std::ptrdiff_t stride,
                std::vector<png_bytep>& rows) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &context, png_on_error, png_on_warning);
  if (png == nullptr) {
    context.error = "libpng cannot make a decoder";
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    context.error = "libpng cannot make a decoder";
    return false;
  }
  rows.resize(static_cast<std::size_t>(height));
  for (int y = 0; y < height; ++y) rows[static_cast<std::size_t>(y)] = grey + y * stride;
  if (setjmp(png_jmpbuf(png)) != 0) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_set_read_fn(png, &context, png_read_bytes);
  png_set_user_limits(png, kMaxImageSide, kMaxImageSide);
  // Every warning left refuses the image, so only those about the pixels
  // may remain: a damaged text chunk or an sRGB profile that libpng knows to
  // be wrong (common in files from image editors) says nothing about the
  // grey levels read here. A critical chunk's CRC error stays an error.
  png_set_crc_action(png, PNG_CRC_DEFAULT, PNG_CRC_QUIET_USE);
#ifdef PNG_SKIP_sRGB_CHECK_PROFILE
  png_set_option(png, PNG_SKIP_sRGB_CHECK_PROFILE, PNG_OPTION_ON);
#endif
  png_read_info(png, info);
  png_uint_32 png_width = 0;
  png_uint_32 png_height = 0;
  int depth = 0;
  int colour_type = 0;
  png_get_IHDR(png, info, &png_width, &png_height, &depth, &colour_type, nullptr, nullptr, nullptr);
  if (png_width != static_cast<png_uint_32>(width) || png_height != static_cast<png_uint_32>(height)) {
    png_error(png, "the size in the header changed");
  }
  if (depth == 16) png_set_strip_16(png);
  png_set_strip_alpha(png);
  if (colour_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if ((colour_type & PNG_COLOR_MASK_COLOR) == 0 && depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  if ((colour_type & PNG_COLOR_MASK_COLOR) != 0) png_set_rgb_to_gray(png, PNG_ERROR_ACTION_NONE, 0.299, 0.587);
  (void)png_set_interlace_handling(png);
  png_read_update_info(png, info);
  if (png_get_rowbytes(png, info) != static_cast<std::size_t>(width)) png_error(png, "does not decode to 8-bit grey");
  png_read_image(png, rows.data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

// ----------------------------------------------------------------- OpenCV

// OpenCV's imdecode reports a decoder's exception on std::cerr (and its
// logger writes there too); the reader reports it as its own error instead.
// Only markerd's main thread writes std::cerr, before the capture starts and
// after it ends.
class CerrCapture {
 public:
  CerrCapture() : saved_(std::cerr.rdbuf(text_.rdbuf())) {}
  ~CerrCapture() { std::cerr.rdbuf(saved_); }
  CerrCapture(const CerrCapture&) = delete;
  CerrCapture& operator=(const CerrCapture&) = delete;
  [[nodiscard]] std::string text() const { return text_.str(); }

 private:
  std::ostringstream text_;
  std::streambuf* saved_;
};

// "OpenCV(4.6.0) /build/.../bitstrm.cpp:97: error: (-2:Unspecified error)
// Unexpected end of input stream in function 'readMore'": the words after
// the error code.
std::string opencv_words(std::string text) {
  if (const auto error = text.find("error: ("); error != std::string::npos) {
    const auto close = text.find(") ", error);
    if (close != std::string::npos) text = text.substr(close + 2);
  }
  if (const auto newline = text.find('\n'); newline != std::string::npos) text.resize(newline);
  if (text.size() > 160) text.resize(160);
  return text;
}

}  // namespace

ImageFileError::ImageFileError(const std::filesystem::path& path, std::string cause)
    : std::runtime_error(fmt::format("{}: {}", path.string(), cause)), cause_(std::move(cause)) {}

struct ImageFileReader::Decoders {
  JpegDecoder jpeg;
  std::vector<png_bytep> png_rows;
};

ImageFileReader::ImageFileReader() : decoders_(std::make_unique<Decoders>()) {}
ImageFileReader::~ImageFileReader() = default;

ImageSize ImageFileReader::open(const std::filesystem::path& path) {
  path_ = path;
  format_ = Format::none;
  bytes_.clear();
  std::string bytes;
  try {
    bytes = read_regular_file(path, kMaxImageFileBytes, "the image");
  } catch (const FileError& e) {
    // "<path>: the image is a directory, not a file": the cause is what
    // follows the path.
    std::string cause = e.what();
    const std::string prefix = path.string() + ": ";
    if (cause.starts_with(prefix)) cause.erase(0, prefix.size());
    throw ImageFileError(path, cause);
  }
  return open_bytes(std::move(bytes), path);
}

ImageSize ImageFileReader::open_bytes(std::string bytes, const std::filesystem::path& path) {
  path_ = path;
  format_ = Format::none;
  bytes_ = std::move(bytes);
  if (bytes_.size() > kMaxImageFileBytes) {
    throw ImageFileError(path,
                         fmt::format("the image is larger than the {} allowed", format_bytes(kMaxImageFileBytes)));
  }
  const auto b = as_bytes(bytes_);
  if (b.empty()) throw ImageFileError(path, "the image is empty (0 bytes)");

  Format format = Format::none;
  DeclaredSize size;
  std::string problem;
  std::string_view name;
  if (b.size() >= kPngSignature.size() && std::equal(kPngSignature.begin(), kPngSignature.end(), b.begin())) {
    format = Format::png;
    name = "PNG";
    problem = png_size(b, size);
  } else if (b.size() >= 3 && b[0] == 0xff && b[1] == 0xd8 && b[2] == 0xff) {
    format = Format::jpeg;
    name = "JPEG";
    int width = 0;
    int height = 0;
    const auto outcome = decoders_->jpeg.read_size(b, width, height);
    if (outcome != JpegDecoder::Outcome::ok) {
      const std::string words = decoders_->jpeg.message();
      const bool truncated = words.find("Premature end") != std::string::npos;
      problem = fmt::format("the JPEG's header cannot be read{} (TurboJPEG: {})", truncated ? ": it is truncated" : "",
                            words);
    } else if (width <= 0 || height <= 0) {
      // TurboJPEG's header reader meets the end of the data (its own, or the
      // end of image it supplies for data cut short) before a frame header.
      problem = "the JPEG's header cannot be read: the data ends before its frame header (SOF); truncated";
    }
    size = {width, height};
  } else if (b.size() >= 2 && b[0] == 'P' && b[1] >= '1' && b[1] <= '6') {
    format = Format::pnm;
    name = "PNM";
    problem = pnm_size(b, size);
  } else if (b.size() >= 2 && b[0] == 'B' && b[1] == 'M') {
    format = Format::bmp;
    name = "BMP";
    problem = bmp_size(b, size);
  } else if (b.size() >= 4 && ((b[0] == 'I' && b[1] == 'I' && b[2] == 42 && b[3] == 0) ||
                               (b[0] == 'M' && b[1] == 'M' && b[2] == 0 && (b[3] == 42 || b[3] == 43)) ||
                               (b[0] == 'I' && b[1] == 'I' && b[2] == 43 && b[3] == 0))) {
    format = Format::tiff;
    name = "TIFF";
    problem = tiff_size(b, size);
  } else {
    throw ImageFileError(path, "not an image markerd reads (PNG, JPEG, PNM, BMP or TIFF, told by its first bytes)");
  }
  if (!problem.empty()) throw ImageFileError(path, problem);
  if (size.width <= 0 || size.height <= 0) {
    throw ImageFileError(path, fmt::format("the {} declares an empty image ({}x{})", name, size.width, size.height));
  }
  if (size.width > kMaxImageSide || size.height > kMaxImageSide || size.width * size.height > kMaxImagePixels) {
    throw ImageFileError(
        path, fmt::format("the {} declares {}x{} pixels ({:.1f} megapixels), more than the {} megapixels and {} "
                          "pixels a side markerd reads",
                          name, size.width, size.height, static_cast<double>(size.width * size.height) / 1e6,
                          kMaxImagePixels / 1'000'000, kMaxImageSide));
  }
  format_ = format;
  size_ = {static_cast<int>(size.width), static_cast<int>(size.height)};
  return size_;
}

void ImageFileReader::decode(std::uint8_t* grey, std::ptrdiff_t stride) {
  const auto b = as_bytes(bytes_);
  switch (format_) {
    case Format::none: throw ImageFileError(path_, "decode() without an image open()ed");
    case Format::png: {
      PngContext context;
      context.bytes = b;
      const bool decoded = decode_png(context, size_.width, size_.height, grey, stride, decoders_->png_rows);
      if (context.truncated) {
        throw ImageFileError(path_, "the PNG is truncated: the file ends before the image does");
      }
      if (!decoded) throw ImageFileError(path_, fmt::format("the PNG is corrupt (libpng: {})", context.error));
      if (!context.warning.empty()) {
        throw ImageFileError(path_, fmt::format("the PNG is corrupt (libpng warns: {})", context.warning));
      }
      return;
    }
    case Format::jpeg: {
      JpegDecoder& jpeg = decoders_->jpeg;
      const auto outcome = jpeg.decode_grey(b, size_.width, size_.height, grey, stride);
      if (outcome == JpegDecoder::Outcome::ok) return;
      const std::string words = jpeg.message();
      if (outcome == JpegDecoder::Outcome::failed) {
        throw ImageFileError(path_, fmt::format("the JPEG cannot be decoded (TurboJPEG: {})", words));
      }
      const bool truncated = words.find("Premature end") != std::string::npos;
      throw ImageFileError(path_,
                           fmt::format("the JPEG is {} (TurboJPEG: {})", truncated ? "truncated" : "corrupt", words));
    }
    case Format::pnm:
    case Format::bmp:
    case Format::tiff: break;
  }
  const std::string_view name = format_ == Format::pnm ? "PNM" : format_ == Format::bmp ? "BMP" : "TIFF";
  // OpenCV keeps a header's memory when the size and type it asks for match;
  // a decoder that fails releases it.
  cv::Mat slot(size_.height, size_.width, CV_8UC1, grey, static_cast<std::size_t>(stride));
  const cv::Mat encoded(1, static_cast<int>(b.size()), CV_8UC1, const_cast<std::uint8_t*>(b.data()));
  std::string printed;
  {
    const CerrCapture capture;
    try {
      cv::imdecode(encoded, cv::IMREAD_GRAYSCALE | cv::IMREAD_IGNORE_ORIENTATION, &slot);
    } catch (const cv::Exception& e) {
      printed = e.what();
    }
    if (printed.empty()) printed = capture.text();
  }
  if (slot.data != grey || slot.cols != size_.width || slot.rows != size_.height || !printed.empty()) {
    if (printed.find("Unexpected end of input stream") != std::string::npos) {
      throw ImageFileError(path_, fmt::format("the {} is truncated (OpenCV: {})", name, opencv_words(printed)));
    }
    throw ImageFileError(
        path_, printed.empty() ? fmt::format("the {} cannot be decoded (OpenCV's decoder gave no image)", name)
                               : fmt::format("the {} cannot be decoded (OpenCV: {})", name, opencv_words(printed)));
  }
}

detector::GreyImage read_grey_image(const std::filesystem::path& path) {
  ImageFileReader reader;
  const ImageSize size = reader.open(path);
  detector::GreyImage image(size.width, size.height);
  reader.decode(image.data(), size.width);
  return image;
}

}  // namespace markerd::daemon
