// The file source: rendered marker images written to a directory come back in
// name order with the same pixels, paced or as fast as asked, looping or
// ending; broken and odd-sized images become corrupt frames naming the file;
// a video file plays the same way; [camera.file] is read with its errors.

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <vector>

#include <unistd.h>

#include "image_fixtures.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/file_source.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "markerd/detector/render.hpp"
#include "support/temp_dir.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

detector::GreyImage render_frame(int index, int width = 160, int height = 120) {
  detector::Scene scene;
  scene.family = detector::Family::frame8;
  scene.id = 100 + index;
  scene.pose = detector::facing_pose(0.45, -20.0 + 10.0 * index);
  scene.supersample = 2;
  scene.seed = static_cast<std::uint64_t>(index) + 1;
  return detector::render_scene(detector::CameraModel::thesis_640x480().scaled_to(width, height), scene);
}

cv::Mat as_mat(const detector::GreyImage& image) {
  return cv::Mat(image.height(), image.width(), CV_8UC1, const_cast<std::uint8_t*>(image.data())).clone();
}

cv::Mat as_mat(const detector::GreyView& view) {
  return cv::Mat(view.height, view.width, CV_8UC1, const_cast<std::uint8_t*>(view.data),
                 static_cast<std::size_t>(view.stride));
}

bool same_pixels(const detector::GreyView& view, const cv::Mat& expected) {
  if (view.width != expected.cols || view.height != expected.rows) return false;
  return cv::countNonZero(as_mat(view) != expected) == 0;
}

class FileSourceTest : public testing::Test {
 protected:
  void SetUp() override { fs::create_directories(dir_ / "frames"); }

  fs::path frames() const { return dir_ / "frames"; }

  // Writes rendered frames as frame_0000.png, ... (last first, so that only
  // their names order them) and returns their pixels.
  std::vector<cv::Mat> write_frames(int count, int width = 160, int height = 120) {
    std::vector<cv::Mat> images;
    for (int i = 0; i < count; ++i) images.push_back(as_mat(render_frame(i, width, height)));
    for (int i = count - 1; i >= 0; --i) {
      EXPECT_TRUE(cv::imwrite(frame_path(i).string(), images[static_cast<std::size_t>(i)]));
    }
    return images;
  }
  fs::path frame_path(int index) const {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.png", index);
    return frames() / name;
  }

  void start(const FileSourceSettings& settings) {
    source_ = make_file_source(settings);
    pool_ =
        std::make_unique<FramePool>(FramePoolConfig{.slots = 2, .pixel_bytes = source_->geometry().slot_pixel_bytes});
    source_->open();
  }
  void start(const fs::path& path, double fps = 0, bool loop = false) {
    start(FileSourceSettings{.path = path, .fps = fps, .loop = loop});
  }

  // The next frame filled, or null when none came within the timeout. The
  // caller hands it back with done().
  Frame* next(std::chrono::milliseconds timeout = 2000ms) {
    if (!source_->wait_frame(timeout)) return nullptr;
    Frame* frame = pool_->try_acquire();
    EXPECT_NE(frame, nullptr);
    if (frame == nullptr) return nullptr;
    source_->fill(*frame);
    return frame;
  }
  void done(Frame* frame) { pool_->release(*frame); }

  const test_support::TempDir temp_{"markerd-file-source"};
  const fs::path dir_ = temp_.path();
  std::unique_ptr<CaptureSource> source_;
  std::unique_ptr<FramePool> pool_;
};

TEST_F(FileSourceTest, ReadsRenderedImagesInNameOrderWithTheirPixels) {
  const auto images = write_frames(5);
  std::ofstream(frames() / "notes.txt") << "not a frame\n";
  cv::imwrite((frames() / ".hidden.png").string(), images[0]);

  auto source = make_file_source(FileSourceSettings{.path = frames()});
  const CaptureGeometry geometry = source->geometry();  // before open(): the pool is sized from it
  EXPECT_EQ(geometry.width, 160);
  EXPECT_EQ(geometry.height, 120);
  EXPECT_EQ(geometry.slot_pixel_bytes, 160U * 120U);
  EXPECT_EQ(geometry.frame_rate, 0.0);
  EXPECT_NE(source->name().find(frames().string()), std::string::npos) << source->name();
  EXPECT_FALSE(source->is_open());

  start(frames());
  EXPECT_TRUE(source_->is_open());
  auto previous = Clock::time_point{};
  for (int i = 0; i < 5; ++i) {
    EXPECT_FALSE(source_->at_end());
    const auto before = Clock::now();
    Frame* frame = next();
    ASSERT_NE(frame, nullptr) << "frame " << i;
    EXPECT_EQ(frame->status, FrameStatus::ok) << frame->cause();
    EXPECT_EQ(frame->sequence, static_cast<std::uint64_t>(i));
    EXPECT_TRUE(same_pixels(frame->image, images[static_cast<std::size_t>(i)])) << "frame " << i;
    EXPECT_EQ(frame->image.data, frame->pixel_buffer().data());  // decoded into the slot, no copy of its own
    EXPECT_GE(frame->capture_time, before);
    EXPECT_GE(frame->capture_time, previous);
    previous = frame->capture_time;
    done(frame);
  }
  EXPECT_TRUE(source_->at_end());
  const auto before = Clock::now();
  EXPECT_FALSE(source_->wait_frame(2000ms));
  EXPECT_LT(Clock::now() - before, 500ms);  // an ended source does not sit out the timeout
  EXPECT_TRUE(source_->at_end());
}

TEST_F(FileSourceTest, PacesFramesAtTheSetRate) {
  write_frames(3);
  constexpr double kFps = 40;
  constexpr int kFrames = 13;
  start(frames(), kFps, /*loop=*/true);
  EXPECT_EQ(source_->geometry().frame_rate, kFps);

  std::vector<Clock::time_point> times;
  for (int i = 0; i < kFrames; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr);
    times.push_back(frame->capture_time);
    done(frame);
  }
  const double elapsed = std::chrono::duration<double>(times.back() - times.front()).count();
  const double expected = (kFrames - 1) / kFps;  // 0.3 s
  EXPECT_GT(elapsed, 0.9 * expected);
  EXPECT_LT(elapsed, 2.5 * expected);  // a loaded machine is slower, never faster

  // A frame further off than the timeout: false after the timeout, then the frame.
  start(frames(), /*fps=*/2.0);
  Frame* first = next();
  ASSERT_NE(first, nullptr);
  const auto first_time = first->capture_time;
  done(first);
  const auto before = Clock::now();
  EXPECT_FALSE(source_->wait_frame(50ms));
  const auto waited = Clock::now() - before;
  EXPECT_GE(waited, 45ms);
  EXPECT_LT(waited, 400ms);
  Frame* second = next(1000ms);
  ASSERT_NE(second, nullptr);
  EXPECT_EQ(second->sequence, 1U);
  EXPECT_GE(second->capture_time - first_time, 450ms);
  done(second);
}

TEST_F(FileSourceTest, UnpacedSourceDeliversAsFastAsAsked) {
  write_frames(2);
  start(frames(), /*fps=*/0, /*loop=*/true);
  const auto before = Clock::now();
  for (int i = 0; i < 20; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr);
    done(frame);
  }
  // Twenty 160x120 PNG decodes: milliseconds; paced at any rate that would
  // show, it would take seconds.
  EXPECT_LT(Clock::now() - before, 1500ms);
}

TEST_F(FileSourceTest, LoopsBackToTheFirstImage) {
  const auto images = write_frames(3);
  start(frames(), 0, /*loop=*/true);
  for (int i = 0; i < 7; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr);
    EXPECT_EQ(frame->sequence, static_cast<std::uint64_t>(i));  // counts on across the loop
    EXPECT_TRUE(same_pixels(frame->image, images[static_cast<std::size_t>(i % 3)])) << "frame " << i;
    EXPECT_FALSE(source_->at_end());
    done(frame);
  }
}

TEST_F(FileSourceTest, UnreadableImagesAreCorruptFramesNamingTheFile) {
  const auto images = write_frames(4);
  std::ofstream(frame_path(1), std::ios::trunc) << "this is no PNG";
  // A PNG cut in half: the header reads, the pixels do not.
  std::vector<std::uint8_t> png;
  cv::imencode(".png", images[2], png);
  std::ofstream(frame_path(2), std::ios::trunc | std::ios::binary)
      .write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size() / 2));

  start(frames());
  for (int i = 0; i < 4; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr);
    EXPECT_EQ(frame->sequence, static_cast<std::uint64_t>(i));
    if (i == 1 || i == 2) {
      EXPECT_EQ(frame->status, FrameStatus::corrupt_frame) << "frame " << i;
      EXPECT_NE(frame->cause().find(frame_path(i).filename().string()), std::string_view::npos) << frame->cause();
      EXPECT_TRUE(frame->image.empty());
    } else {
      EXPECT_EQ(frame->status, FrameStatus::ok) << frame->cause();
      EXPECT_TRUE(same_pixels(frame->image, images[static_cast<std::size_t>(i)]));  // the source went on
    }
    done(frame);
  }
  EXPECT_TRUE(source_->at_end());
}

TEST_F(FileSourceTest, AnImageOfAnotherSizeIsACorruptFrame) {
  const auto images = write_frames(3);
  cv::imwrite(frame_path(1).string(), as_mat(render_frame(1, 80, 60)));
  start(frames());
  Frame* frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->status, FrameStatus::ok);
  done(frame);

  frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->status, FrameStatus::corrupt_frame);
  const std::string cause(frame->cause());
  EXPECT_NE(cause.find("frame_0001.png"), std::string::npos) << cause;
  EXPECT_NE(cause.find("80x60"), std::string::npos) << cause;
  EXPECT_NE(cause.find("160x120"), std::string::npos) << cause;
  EXPECT_NE(cause.find("frame_0000.png"), std::string::npos) << cause;  // what set the size
  done(frame);

  frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->status, FrameStatus::ok);
  EXPECT_TRUE(same_pixels(frame->image, images[2]));
  done(frame);
}

TEST_F(FileSourceTest, FirstReadableImageSetsTheSize) {
  const auto images = write_frames(2);
  std::ofstream(frames() / "frame_.png") << "broken, and first in name order";
  start(frames());
  EXPECT_EQ(source_->geometry().width, 160);
  Frame* frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->status, FrameStatus::corrupt_frame);
  done(frame);
  frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_TRUE(same_pixels(frame->image, images[0]));
  done(frame);
}

// A JPEG cut short or with damaged data decodes to a picture with grey or
// garbled blocks; the frame is corrupt with the decoder's cause, not a
// measurement. A header declaring a decompression bomb is refused before
// anything is decoded, as the first image too.
TEST_F(FileSourceTest, DamagedJpegsAndBombsAreCorruptFramesSayingWhy) {
  const auto images = write_frames(4);
  std::vector<std::uint8_t> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", images[1], jpeg));
  fs::remove(frame_path(1));
  fs::remove(frame_path(2));
  test_support::write_bytes(frames() / "frame_0001.jpg", test_support::first_half(jpeg));
  test_support::write_bytes(frames() / "frame_0002.jpg", test_support::with_corrupt_entropy_data(jpeg));
  test_support::write_bytes(frames() / "frame_.png", test_support::png_declaring(30000, 30000));  // first in name order

  start(frames());
  EXPECT_EQ(source_->geometry().width, 160);
  const std::vector<std::pair<std::string, std::string>> expected = {{"frame_.png", "declares 30000x30000 pixels"},
                                                                     {"frame_0000.png", ""},
                                                                     {"frame_0001.jpg", "the JPEG is truncated"},
                                                                     {"frame_0002.jpg", "the JPEG is corrupt"},
                                                                     {"frame_0003.png", ""}};
  for (const auto& [file, cause] : expected) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr) << file;
    if (cause.empty()) {
      EXPECT_EQ(frame->status, FrameStatus::ok) << file << ": " << frame->cause();
    } else {
      EXPECT_EQ(frame->status, FrameStatus::corrupt_frame) << file;
      const std::string text(frame->cause());
      EXPECT_NE(text.find("image " + file + ": "), std::string::npos) << text;
      EXPECT_NE(text.find(cause), std::string::npos) << text;
      EXPECT_TRUE(frame->image.empty());
    }
    done(frame);
  }
  EXPECT_TRUE(source_->at_end());
}

TEST_F(FileSourceTest, MissingPathOrNoImagesIsNotFound) {
  const fs::path missing = dir_ / "no-such-run";
  try {
    (void)make_file_source(FileSourceSettings{.path = missing});
    FAIL() << "a missing path was accepted";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_NE(std::string(e.what()).find(missing.string()), std::string::npos) << e.what();
  }

  std::ofstream(frames() / "notes.txt") << "no images here\n";
  try {
    (void)make_file_source(FileSourceSettings{.path = frames()});
    FAIL() << "a directory without images was accepted";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_NE(std::string(e.what()).find("no images"), std::string::npos) << e.what();
  }

  // Gone between start and a reopen.
  write_frames(1);
  start(frames());
  source_->close();
  fs::remove_all(frames());
  try {
    source_->open();
    FAIL() << "opened a directory that is gone";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_NE(std::string(e.what()).find(frames().string()), std::string::npos) << e.what();
  }
}

TEST_F(FileSourceTest, ColourImagesAreConvertedToGrey) {
  const cv::Mat grey = as_mat(render_frame(0));
  std::vector<cv::Mat> channels = {grey, 255 - grey, grey / 2};  // B, G, R all different
  cv::Mat colour;
  cv::merge(channels, colour);
  ASSERT_TRUE(cv::imwrite((frames() / "colour.png").string(), colour));
  ASSERT_TRUE(cv::imwrite((frames() / "colour2.jpg").string(), colour));

  start(frames());
  Frame* frame = next();
  ASSERT_NE(frame, nullptr);
  ASSERT_EQ(frame->status, FrameStatus::ok) << frame->cause();
  EXPECT_TRUE(same_pixels(frame->image, cv::imread((frames() / "colour.png").string(), cv::IMREAD_GRAYSCALE)));
  cv::Mat converted;
  cv::cvtColor(colour, converted, cv::COLOR_BGR2GRAY);
  double max_difference = 0;
  cv::Mat difference;
  cv::absdiff(as_mat(frame->image), converted, difference);
  cv::minMaxLoc(difference, nullptr, &max_difference);
  EXPECT_LE(max_difference, 2.0);                                // libpng's and OpenCV's weights round differently
  EXPECT_NE(cv::countNonZero(as_mat(frame->image) != grey), 0);  // really converted, not one channel
  done(frame);

  frame = next();  // a JPEG, colour too
  ASSERT_NE(frame, nullptr);
  ASSERT_EQ(frame->status, FrameStatus::ok) << frame->cause();
  EXPECT_TRUE(same_pixels(frame->image, cv::imread((frames() / "colour2.jpg").string(), cv::IMREAD_GRAYSCALE)));
  done(frame);
}

TEST_F(FileSourceTest, SkipGivesTheFrameUpAndCountsIt) {
  const auto images = write_frames(3);
  start(frames());
  ASSERT_TRUE(source_->wait_frame(1000ms));
  source_->skip();  // the live pipeline dropped it
  Frame* frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->sequence, 1U);
  EXPECT_TRUE(same_pixels(frame->image, images[1]));
  done(frame);
}

TEST_F(FileSourceTest, ReopenStartsFromTheFirstImage) {
  const auto images = write_frames(3);
  start(frames());
  for (int i = 0; i < 2; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr);
    done(frame);
  }
  source_->close();
  source_->close();  // twice: safe
  EXPECT_FALSE(source_->is_open());
  EXPECT_THROW((void)source_->wait_frame(10ms), CaptureError);
  source_->open();
  Frame* frame = next();
  ASSERT_NE(frame, nullptr);
  EXPECT_EQ(frame->sequence, 0U);
  EXPECT_TRUE(same_pixels(frame->image, images[0]));
  done(frame);
}

TEST_F(FileSourceTest, ClosingANeverOpenedSourceIsSafe) {
  write_frames(1);
  auto source = make_file_source(FileSourceSettings{.path = frames()});
  source->close();
  EXPECT_FALSE(source->is_open());
  EXPECT_FALSE(source->at_end());
}

TEST_F(FileSourceTest, PlaysAVideoFile) {
  const fs::path video = dir_ / "run.avi";
  constexpr int kFrames = 6;
  std::vector<cv::Mat> images;
  {
    cv::VideoWriter writer(video.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10, cv::Size(160, 120),
                           /*isColor=*/false);
    if (!writer.isOpened()) GTEST_SKIP() << "this OpenCV cannot write MJPG into an .avi";
    for (int i = 0; i < kFrames; ++i) {
      images.push_back(as_mat(render_frame(i)));
      writer.write(images.back());
    }
  }
  start(video);
  EXPECT_EQ(source_->geometry().width, 160);
  EXPECT_EQ(source_->geometry().height, 120);
  for (int i = 0; i < kFrames; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr) << "frame " << i;
    ASSERT_EQ(frame->status, FrameStatus::ok) << frame->cause();
    EXPECT_EQ(frame->sequence, static_cast<std::uint64_t>(i));
    EXPECT_EQ(frame->image.data, frame->pixel_buffer().data());
    // MJPEG is lossy: close to the rendered frame, and closer to it than to
    // its neighbours.
    const double own = cv::norm(as_mat(frame->image), images[static_cast<std::size_t>(i)], cv::NORM_L1) / (160 * 120);
    const double other =
        cv::norm(as_mat(frame->image), images[static_cast<std::size_t>((i + 1) % kFrames)], cv::NORM_L1) / (160 * 120);
    EXPECT_LT(own, 3.0) << "frame " << i;
    EXPECT_LT(own, other) << "frame " << i;
    done(frame);
  }
  EXPECT_FALSE(source_->wait_frame(1000ms));
  EXPECT_TRUE(source_->at_end());

  start(video, 0, /*loop=*/true);
  for (int i = 0; i < kFrames + 2; ++i) {
    Frame* frame = next();
    ASSERT_NE(frame, nullptr) << "frame " << i;
    const double own =
        cv::norm(as_mat(frame->image), images[static_cast<std::size_t>(i % kFrames)], cv::NORM_L1) / (160 * 120);
    EXPECT_LT(own, 3.0) << "frame " << i;
    done(frame);
  }
  EXPECT_FALSE(source_->at_end());
}

TEST_F(FileSourceTest, AFileThatIsNoVideoIsAConfigError) {
  const fs::path text = dir_ / "notes.txt";
  std::ofstream(text) << "not a video\n";
  try {
    (void)make_file_source(FileSourceSettings{.path = text});
    FAIL() << "a text file was accepted as a video";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::config);
    EXPECT_NE(std::string(e.what()).find(text.string()), std::string::npos) << e.what();
  }
}

// ---- [camera.file] ----

FileSourceSettings parse(const std::string& body, const fs::path& config_dir = "/etc/markerd") {
  const auto config = ConfigTable::parse("[camera.file]\n" + body, "markerd.toml");
  return parse_file_source_settings(config.table("camera").table("file"), config_dir);
}

std::string parse_error(const std::string& body) {
  try {
    (void)parse(body);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(FileSourceSettingsTest, ReadsTheTableAndResolvesRelativePaths) {
  const auto settings = parse("path = \"runs/sweep-3\"\nfps = 30\nloop = true\n", "/etc/markerd");
  EXPECT_EQ(settings.path, fs::path("/etc/markerd/runs/sweep-3"));
  EXPECT_EQ(settings.fps, 30.0);
  EXPECT_TRUE(settings.loop);

  const auto defaults = parse("path = \"/srv/replay/../replay/a.avi\"\n");
  EXPECT_EQ(defaults.path, fs::path("/srv/replay/a.avi"));
  EXPECT_EQ(defaults.fps, 0.0);
  EXPECT_FALSE(defaults.loop);
}

TEST(FileSourceSettingsTest, ErrorsNameTheFileLineAndKey) {
  EXPECT_EQ(parse_error("path = \"x\"\nfps = -5\n"),
            "markerd.toml:3: camera.file.fps: must be >= 0 (0: as fast as the pipeline takes frames) and at most 1000, "
            "got -5");
  EXPECT_EQ(parse_error("path = \"x\"\nfps = 1e308\n"),
            "markerd.toml:3: camera.file.fps: must be >= 0 (0: as fast as the pipeline takes frames) and at most 1000, "
            "got 1e+308");
  const std::string unknown = parse_error("path = \"x\"\nrate = 5\n");
  EXPECT_NE(unknown.find("markerd.toml:3: camera.file.rate: unknown key"), std::string::npos) << unknown;
  const std::string missing = parse_error("fps = 5\n");
  EXPECT_NE(missing.find("camera.file.path"), std::string::npos) << missing;
  EXPECT_NE(parse_error("path = \"\"\n").find("camera.file.path: must name"), std::string::npos);
  EXPECT_NE(parse_error("path = \"x\"\nloop = 1\n").find("camera.file.loop: must be a boolean"), std::string::npos);
}

}  // namespace
}  // namespace markerd::daemon
