// ImageFileReader (daemon/src/capture/image_file.cpp): every format it reads
// gives the pixels cv::imread(IMREAD_GRAYSCALE) gives; a file cut short, a
// JPEG with damaged data, a PNG declaring 30000x30000 pixels, a directory and
// a FIFO are errors naming the file and the cause, and no decoder prints
// anything of its own.

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <random>
#include <string>
#include <vector>

#include "image_fixtures.hpp"
#include "markerd/daemon/capture/image_file.hpp"
#include "support/temp_dir.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;
using test_support::Bytes;

class ImageFile : public testing::Test {
 protected:
  [[nodiscard]] fs::path path(const std::string& name) const { return dir_ / name; }

  // A colour scene with edges, gradients and noise, so that each format's
  // compression and colour conversion has something to do.
  static cv::Mat colour_scene() {
    cv::Mat image(120, 160, CV_8UC3);
    std::mt19937 rng(3);
    for (int y = 0; y < image.rows; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        const int noise = static_cast<int>(rng() % 16);
        const bool square = x > 40 && x < 110 && y > 30 && y < 90;
        image.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<std::uint8_t>(square ? 20 + noise : 2 * x / 3 + noise),
                                              static_cast<std::uint8_t>(255 - 2 * y + noise / 2),
                                              static_cast<std::uint8_t>((x + y) / 2 + noise));
      }
    }
    return image;
  }

  static Bytes encode(const std::string& extension, const cv::Mat& image) {
    Bytes bytes;
    EXPECT_TRUE(cv::imencode(extension, image, bytes)) << extension;
    return bytes;
  }

  // open() and decode() must throw ImageFileError naming the file and
  // `cause`, with nothing on stderr.
  void expect_error(const fs::path& file, const std::string& cause) const {
    testing::internal::CaptureStderr();
    std::string message;
    try {
      (void)read_grey_image(file);
    } catch (const ImageFileError& e) {
      message = e.what();
    }
    const std::string printed = testing::internal::GetCapturedStderr();
    ASSERT_FALSE(message.empty()) << file << " was read without an error";
    EXPECT_EQ(message.rfind(file.string() + ": ", 0), 0u) << message;
    EXPECT_NE(message.find(cause), std::string::npos) << message;
    EXPECT_EQ(printed, "") << "a decoder printed on stderr for " << file;
  }

  const test_support::TempDir temp_{"markerd-image-file"};
  const fs::path dir_ = temp_.path();
};

TEST_F(ImageFile, EveryFormatDecodesAsImreadDecodesIt) {
  const cv::Mat colour = colour_scene();
  cv::Mat grey;
  cv::extractChannel(colour, grey, 1);
  cv::Mat deep;
  grey.convertTo(deep, CV_16U, 257.0);
  const std::vector<std::pair<std::string, cv::Mat>> files = {
      {"colour.png", colour}, {"grey.png", grey},     {"deep.png", deep},     {"colour.jpg", colour},
      {"grey.jpg", grey},     {"grey.pgm", grey},     {"colour.ppm", colour}, {"colour.bmp", colour},
      {"grey.bmp", grey},     {"colour.tif", colour}, {"grey.tiff", grey}};
  for (const auto& [name, image] : files) {
    ASSERT_TRUE(cv::imwrite(path(name).string(), image)) << name;
    const cv::Mat expected = cv::imread(path(name).string(), cv::IMREAD_GRAYSCALE);
    testing::internal::CaptureStderr();
    const detector::GreyImage read = read_grey_image(path(name));
    EXPECT_EQ(testing::internal::GetCapturedStderr(), "") << name;
    ASSERT_EQ(read.width(), expected.cols) << name;
    ASSERT_EQ(read.height(), expected.rows) << name;
    const cv::Mat got(read.height(), read.width(), CV_8UC1, const_cast<std::uint8_t*>(read.data()));
    EXPECT_EQ(cv::countNonZero(got != expected), 0) << name << ": not the pixels imread gives";
  }
}

TEST_F(ImageFile, ATruncatedJpegIsAnErrorSayingSo) {
  test_support::write_bytes(path("half.jpg"), test_support::first_half(encode(".jpg", colour_scene())));
  expect_error(path("half.jpg"), "the JPEG is truncated");
}

TEST_F(ImageFile, AJpegWithCorruptDataIsAnErrorSayingSo) {
  const Bytes corrupt = test_support::with_corrupt_entropy_data(encode(".jpg", colour_scene()));
  ASSERT_FALSE(corrupt.empty());
  test_support::write_bytes(path("corrupt.jpg"), corrupt);
  expect_error(path("corrupt.jpg"), "the JPEG is corrupt");
}

TEST_F(ImageFile, ATruncatedPngIsAnErrorSayingSo) {
  test_support::write_bytes(path("half.png"), test_support::first_half(encode(".png", colour_scene())));
  expect_error(path("half.png"), "the PNG is truncated");
}

TEST_F(ImageFile, APngWithADamagedChunkIsAnError) {
  Bytes png = encode(".png", colour_scene());
  png[png.size() / 2] ^= 0x55;  // inside IDAT: its CRC no longer matches
  test_support::write_bytes(path("damaged.png"), png);
  expect_error(path("damaged.png"), "the PNG is corrupt");
}

TEST_F(ImageFile, ADamagedTextChunkDoesNotRefuseThePixels) {
  cv::Mat grey;
  cv::extractChannel(colour_scene(), grey, 1);
  const Bytes png = encode(".png", grey);
  // A tEXt chunk right after IHDR (8 + 25 bytes in), its CRC broken.
  Bytes text_chunk;
  test_support::append_png_chunk(text_chunk, "tEXt", {'C', 'o', 'm', 'm', 'e', 'n', 't', 0, 'h', 'i'});
  text_chunk.back() ^= 0xff;
  Bytes damaged(png.begin(), png.begin() + 33);
  damaged.insert(damaged.end(), text_chunk.begin(), text_chunk.end());
  damaged.insert(damaged.end(), png.begin() + 33, png.end());
  test_support::write_bytes(path("text.png"), damaged);
  testing::internal::CaptureStderr();
  const detector::GreyImage read = read_grey_image(path("text.png"));
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  ASSERT_EQ(read.width(), grey.cols);
  const cv::Mat got(read.height(), read.width(), CV_8UC1, const_cast<std::uint8_t*>(read.data()));
  EXPECT_EQ(cv::countNonZero(got != grey), 0);
}

TEST_F(ImageFile, ADecompressionBombIsRefusedByItsHeader) {
  const Bytes bomb = test_support::png_declaring(30000, 30000);
  ASSERT_LT(bomb.size(), 100u);
  test_support::write_bytes(path("bomb.png"), bomb);
  expect_error(path("bomb.png"), "the PNG declares 30000x30000 pixels (900.0 megapixels), more than the 64");
  // A side beyond 65535 with few pixels (a row buffer of 400 KB a channel).
  test_support::write_bytes(path("wide.png"), test_support::png_declaring(100000, 1));
  expect_error(path("wide.png"), "100000x1");
  // The same header with a size markerd reads gets as far as the data.
  test_support::write_bytes(path("small.png"), test_support::png_declaring(64, 64));
  expect_error(path("small.png"), "the PNG is corrupt");
}

TEST_F(ImageFile, ADirectoryOrAFifoIsRefusedAtOnce) {
  fs::create_directories(path("frames.png"));
  expect_error(path("frames.png"), "is a directory, not a file");
  ASSERT_TRUE(test_support::make_fifo(path("pipe.jpg")));
  expect_error(path("pipe.jpg"), "is a FIFO, not a file");  // without waiting for a writer
  expect_error(path("missing.png"), "No such file or directory");
}

TEST_F(ImageFile, TruncatedFilesOfTheOtherFormatsAreErrors) {
  const cv::Mat colour = colour_scene();
  for (const std::string extension : {".ppm", ".bmp", ".tif"}) {
    const std::string name = "half" + extension;
    test_support::write_bytes(path(name), test_support::first_half(encode(extension, colour)));
    expect_error(path(name), "the ");
  }
  cv::Mat grey;
  cv::extractChannel(colour, grey, 0);
  test_support::write_bytes(path("half.pgm"), test_support::first_half(encode(".pgm", grey)));
  expect_error(path("half.pgm"), "the PNM is truncated");
}

TEST_F(ImageFile, WhatIsNoImageIsNamed) {
  test_support::write_bytes(path("notes.png"), {'n', 'o', 't', 'e', 's'});
  expect_error(path("notes.png"), "not an image markerd reads");
  test_support::write_bytes(path("empty.jpg"), {});
  expect_error(path("empty.jpg"), "the image is empty");
  test_support::write_bytes(path("header.jpg"), {0xff, 0xd8, 0xff, 0xe0});
  expect_error(path("header.jpg"), "the JPEG's header cannot be read: the data ends before its frame header");
}

// open() gives the declared size without decoding: the file source and
// markerctl compare it with the size they expect before they decode.
TEST_F(ImageFile, OpenGivesTheDeclaredSizeBeforeDecoding) {
  ImageFileReader reader;
  cv::Mat grey;
  cv::extractChannel(colour_scene(), grey, 2);
  for (const std::string extension : {".png", ".jpg", ".pgm", ".bmp", ".tif"}) {
    test_support::write_bytes(path("a" + extension), encode(extension, grey));
    const ImageSize size = reader.open(path("a" + extension));
    EXPECT_EQ(size.width, 160) << extension;
    EXPECT_EQ(size.height, 120) << extension;
  }
  // A decoder kept from file to file decodes each whole; a stride wider
  // than the row leaves the bytes past it alone.
  test_support::write_bytes(path("b.jpg"), encode(".jpg", colour_scene()));
  for (int round = 0; round < 2; ++round) {
    (void)reader.open(path("b.jpg"));
    std::vector<std::uint8_t> rows(static_cast<std::size_t>(170 * 120), 0x5a);
    reader.decode(rows.data(), 170);
    for (int y = 0; y < 120; ++y) {
      for (int x = 160; x < 170; ++x) ASSERT_EQ(rows[static_cast<std::size_t>(y * 170 + x)], 0x5a);
    }
  }
}

}  // namespace
}  // namespace markerd::daemon
