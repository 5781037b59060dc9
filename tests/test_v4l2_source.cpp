// The V4L2 source on a machine without cameras: the pixel conversions (YUYV's
// Y bytes, MJPEG decoded to grey by TurboJPEG, broken MJPEG), [camera.v4l2]
// and its errors, the names a device may be given by, the device listing on
// a /dev without video nodes and on a fake one, and the errors of opening a
// device that is missing or is no V4L2 device, and markerctl cameras' errors
// and empty listing. Against the real driver: tests/hil/test_v4l2_hil.cpp.

#include <gtest/gtest.h>
#include <turbojpeg.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/pixel_convert.hpp"
#include "markerd/daemon/capture/v4l2_listing.hpp"
#include "markerd/daemon/capture/v4l2_source.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;
// Says what the text was when the part is missing.
testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return testing::AssertionSuccess();
  return testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

// ---------------------------------------------------------------- YUYV

std::uint8_t test_luma(int x, int y) { return static_cast<std::uint8_t>((x * 7 + y * 13 + (x * y) % 31) & 0xff); }

TEST(YuyvToGrey, TakesEveryYByteAtAnyWidthAndStride) {
  // Widths around the 16-pixel vector step, strides with padding.
  for (const int width : {2, 14, 16, 18, 32, 46, 640}) {
    const int height = 5;
    const std::ptrdiff_t in_stride = 2 * width + 12;
    const std::ptrdiff_t out_stride = width + 3;
    std::vector<std::uint8_t> yuyv(static_cast<std::size_t>(in_stride * height), 0xAA);
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        yuyv[static_cast<std::size_t>(y * in_stride + 2 * x)] = test_luma(x, y);
        yuyv[static_cast<std::size_t>(y * in_stride + 2 * x + 1)] = static_cast<std::uint8_t>(x % 2 ? 200 : 50);
      }
    }
    std::vector<std::uint8_t> grey(static_cast<std::size_t>(out_stride * height), 0x11);
    yuyv_to_grey(yuyv.data(), in_stride, width, height, grey.data(), out_stride);
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        ASSERT_EQ(grey[static_cast<std::size_t>(y * out_stride + x)], test_luma(x, y))
            << "width " << width << " at " << x << "," << y;
      }
      for (std::ptrdiff_t x = width; x < out_stride; ++x) {
        ASSERT_EQ(grey[static_cast<std::size_t>(y * out_stride + x)], 0x11) << "wrote past the row, width " << width;
      }
    }
  }
}

// ---------------------------------------------------------------- MJPEG

// A camera's MJPEG: YCbCr 4:2:2 from an RGB image whose three channels are
// the grey value, so the Y the decoder gives back is that value.
std::vector<std::uint8_t> encode_jpeg(int width, int height, const std::function<std::uint8_t(int, int)>& value) {
  std::vector<std::uint8_t> rgb(static_cast<std::size_t>(width * height * 3));
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const auto v = value(x, y);
      std::fill_n(rgb.begin() + (y * width + x) * 3, 3, v);
    }
  }
  tjhandle handle = tjInitCompress();
  unsigned char* jpeg = nullptr;
  unsigned long size = 0;
  const int result = tjCompress2(handle, rgb.data(), width, 0, height, TJPF_RGB, &jpeg, &size, TJSAMP_422, 95, 0);
  std::vector<std::uint8_t> out;
  if (result == 0) out.assign(jpeg, jpeg + size);
  tjFree(jpeg);
  tjDestroy(handle);
  if (result != 0) ADD_FAILURE() << "tjCompress2 failed";
  return out;
}

std::uint8_t smooth(int x, int y) { return static_cast<std::uint8_t>(40 + (x + 2 * y) / 8); }

TEST(MjpegDecoder, DecodesToGreyIntoTheCallersRows) {
  const int width = 320;
  const int height = 240;
  const auto jpeg = encode_jpeg(width, height, smooth);
  MjpegDecoder decoder;
  const std::ptrdiff_t stride = width + 16;
  std::vector<std::uint8_t> grey(static_cast<std::size_t>(stride * height), 0x5A);
  // Twice with the same decoder: the handle is kept from frame to frame.
  for (int round = 0; round < 2; ++round) {
    const char* error = decoder.decode(jpeg, width, height, grey.data(), stride);
    ASSERT_EQ(error, nullptr) << error;
    int worst = 0;
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        worst = std::max(worst, std::abs(grey[static_cast<std::size_t>(y * stride + x)] - smooth(x, y)));
      }
      for (std::ptrdiff_t x = width; x < stride; ++x) ASSERT_EQ(grey[static_cast<std::size_t>(y * stride + x)], 0x5A);
    }
    EXPECT_LE(worst, 3) << "a quality-95 JPEG of a smooth ramp decodes within a few levels";
  }
}

TEST(MjpegDecoder, BrokenFramesSayWhy) {
  const int width = 160;
  const int height = 120;
  const auto jpeg = encode_jpeg(width, height, smooth);
  MjpegDecoder decoder;
  std::vector<std::uint8_t> grey(static_cast<std::size_t>(width * height));

  // Cut short, as a camera's frame that lost its end.
  const std::vector<std::uint8_t> truncated(jpeg.begin(), jpeg.begin() + static_cast<std::ptrdiff_t>(jpeg.size() / 2));
  const char* error = decoder.decode(truncated, width, height, grey.data(), width);
  ASSERT_NE(error, nullptr);
  EXPECT_TRUE(contains(std::string(error), "MJPEG: "));

  const std::vector<std::uint8_t> garbage(2000, 0x42);
  error = decoder.decode(garbage, width, height, grey.data(), width);
  ASSERT_NE(error, nullptr);
  EXPECT_TRUE(contains(std::string(error), "MJPEG: "));

  error = decoder.decode({}, width, height, grey.data(), width);
  ASSERT_NE(error, nullptr);
  EXPECT_TRUE(contains(std::string(error), "empty"));

  error = decoder.decode(jpeg, 640, 480, grey.data(), width);
  ASSERT_NE(error, nullptr);
  EXPECT_EQ(std::string(error), "MJPEG: the frame is 160x120, the stream was set up for 640x480");

  // Still decodes a good frame after the broken ones.
  EXPECT_EQ(decoder.decode(jpeg, width, height, grey.data(), width), nullptr);
}

// What the sources lend a pipeline worker: the frame is decoded into its
// slot's pixels, the source's buffer given back once, by decode() and never
// again; a broken one is marked corrupt with the decoder's words.
TEST(MjpegFrame, DecodesIntoTheSlotAndGivesTheBufferBackOnce) {
  const int width = 160;
  const int height = 120;
  const auto jpeg = encode_jpeg(width, height, smooth);
  const std::vector<std::uint8_t> truncated(jpeg.begin(), jpeg.begin() + static_cast<std::ptrdiff_t>(jpeg.size() / 2));
  FramePool pool({.slots = 1, .pixel_bytes = static_cast<std::size_t>(width * height)});
  int released = 0;
  const ReleaseHook count_release{[](void* context, std::uint64_t) noexcept { ++*static_cast<int*>(context); },
                                  &released, 0};

  Frame* frame = pool.try_acquire();
  ASSERT_NE(frame, nullptr);
  frame->use_pixel_buffer(width, height);
  frame->set_encoded(jpeg, &decode_mjpeg_frame);
  frame->set_release(count_release);
  ASSERT_TRUE(frame->is_encoded());
  frame->decode();
  EXPECT_EQ(released, 1) << "the encoded buffer goes back once decoded";
  EXPECT_FALSE(frame->is_encoded());
  EXPECT_TRUE(frame->encoded().empty());
  ASSERT_EQ(frame->status, FrameStatus::ok) << frame->cause();
  ASSERT_EQ(frame->image.width, width);
  EXPECT_EQ(frame->image.data, frame->pixel_buffer().data());
  int worst = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) worst = std::max(worst, std::abs(frame->image.at(x, y) - smooth(x, y)));
  }
  EXPECT_LE(worst, 3);
  frame->decode();
  pool.release(*frame);
  EXPECT_EQ(released, 1) << "decoded once, released once";

  frame = pool.try_acquire();
  ASSERT_NE(frame, nullptr);
  frame->use_pixel_buffer(width, height);
  frame->set_encoded(truncated, &decode_mjpeg_frame);
  frame->set_release(count_release);
  frame->decode();
  EXPECT_EQ(released, 2);
  EXPECT_EQ(frame->status, FrameStatus::corrupt_frame);
  EXPECT_TRUE(contains(std::string(frame->cause()), "MJPEG: ")) << frame->cause();
  EXPECT_TRUE(frame->image.empty());
  pool.release(*frame);
  EXPECT_EQ(released, 2);
}

// ---------------------------------------------------------------- settings

V4l2Settings parse(const std::string& text) {
  const auto root = ConfigTable::parse(text, "markerd.toml");
  return parse_v4l2_settings(root.table("camera").table("v4l2"));
}

std::string parse_error(const std::string& text) {
  try {
    parse(text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(V4l2Settings, ReadsEveryKey) {
  const auto s = parse(R"([camera.v4l2]
device = "/dev/v4l/by-id/usb-cam-video-index0"
format = "mjpg"
width = 1280
height = 720
fps = 30
buffers = 6
input = 1
[camera.v4l2.controls]
auto_exposure = "Manual Mode"
exposure_time_absolute = 150
focus_automatic_continuous = false
power_line_frequency = 1
)");
  EXPECT_EQ(s.device, "/dev/v4l/by-id/usb-cam-video-index0");
  EXPECT_EQ(s.format, V4l2PixelFormat::mjpg);
  EXPECT_EQ(s.width, 1280);
  EXPECT_EQ(s.height, 720);
  EXPECT_DOUBLE_EQ(s.fps, 30.0);
  EXPECT_EQ(s.buffers, 6);
  ASSERT_TRUE(s.input.has_value());
  EXPECT_EQ(*s.input, 1);
  ASSERT_EQ(s.controls.size(), 4U);
  const auto find = [&](const std::string& name) {
    return *std::find_if(s.controls.begin(), s.controls.end(), [&](const auto& c) { return c.name == name; });
  };
  EXPECT_EQ(std::get<std::string>(find("auto_exposure").value), "Manual Mode");
  EXPECT_EQ(std::get<std::int64_t>(find("exposure_time_absolute").value), 150);
  EXPECT_EQ(std::get<bool>(find("focus_automatic_continuous").value), false);
  // Where it came from, for errors the device finds at open().
  EXPECT_EQ(find("exposure_time_absolute").origin, "markerd.toml:11: camera.v4l2.controls.exposure_time_absolute");
}

TEST(V4l2Settings, Defaults) {
  const auto s = parse("[camera.v4l2]\ndevice = \"/dev/video0\"\nwidth = 640\nheight = 480\n");
  EXPECT_EQ(s.format, V4l2PixelFormat::yuyv);
  EXPECT_EQ(s.fps, 0.0);
  EXPECT_EQ(s.buffers, 4);
  EXPECT_FALSE(s.input.has_value());
  EXPECT_TRUE(s.controls.empty());
  for (const auto* name : {"GREY", "grey", "NV12", "YUYV", "MJPEG"}) {
    EXPECT_NO_THROW(
        parse(std::string("[camera.v4l2]\ndevice = \"x\"\nwidth = 640\nheight = 480\nformat = \"") + name + "\"\n"))
        << name;
  }
}

TEST(V4l2Settings, ErrorsNameFileLineAndKey) {
  const std::string head = "[camera.v4l2]\ndevice = \"/dev/video0\"\nwidth = 640\nheight = 480\n";
  EXPECT_EQ(parse_error(head + "format = \"RGB3\"\n"),
            "markerd.toml:5: camera.v4l2.format: unknown format 'RGB3' (use GREY, YUYV, NV12 or MJPG)");
  EXPECT_TRUE(contains(parse_error(head + "fromat = \"GREY\"\n"),
                       "markerd.toml:5: camera.v4l2.fromat: unknown key (known here: device, format"));
  EXPECT_TRUE(contains(parse_error(head + "buffers = 1\n"), "markerd.toml:5: camera.v4l2.buffers: must be 2 to 32"));
  EXPECT_TRUE(contains(parse_error(head + "fps = 0\n"), "camera.v4l2.fps: must be > 0"));
  EXPECT_TRUE(contains(parse_error(head + "input = -1\n"), "camera.v4l2.input: must be an input's index"));
  EXPECT_TRUE(contains(parse_error(head + "input = 9223372036854775807\n"),
                       "camera.v4l2.input: must be an input's index, 0 to 255, got 9223372036854775807"));
  EXPECT_TRUE(contains(parse_error("[camera.v4l2]\ndevice = \"x\"\nwidth = 641\nheight = 480\n"),
                       "markerd.toml:3: camera.v4l2.width: must be even for YUYV"));
  EXPECT_TRUE(
      contains(parse_error("[camera.v4l2]\ndevice = \"x\"\nwidth = 640\n"), "missing key 'camera.v4l2.height'"));
  EXPECT_TRUE(contains(parse_error("[camera.v4l2]\ndevice = \"\"\nwidth = 640\nheight = 480\n"),
                       "camera.v4l2.device: must not be empty"));
  EXPECT_EQ(parse_error(head + "[camera.v4l2.controls]\n\"Exposure Time, Absolute\" = 100\n"),
            "markerd.toml:6: camera.v4l2.controls.Exposure Time, Absolute: write control names as v4l2-ctl prints "
            "them: 'exposure_time_absolute'");
  EXPECT_EQ(parse_error(head + "[camera.v4l2.controls]\ngain = 1.5\n"),
            "markerd.toml:6: camera.v4l2.controls.gain: must be an integer, a boolean, or the name of a menu item");
}

TEST(V4l2Settings, GeometryIsKnownBeforeOpen) {
  V4l2Settings s;
  s.device = "/dev/video-markerd-test-missing";
  s.width = 640;
  s.height = 480;
  s.fps = 30;
  for (const auto format : {V4l2PixelFormat::yuyv, V4l2PixelFormat::mjpg}) {
    s.format = format;
    const auto source = make_v4l2_source(s);
    EXPECT_EQ(source->geometry().slot_pixel_bytes, 640U * 480U) << to_string(format) << " converts into the slot";
    EXPECT_EQ(source->geometry().width, 640);
    EXPECT_EQ(source->geometry().frame_rate, 30.0);
  }
  for (const auto format : {V4l2PixelFormat::grey, V4l2PixelFormat::nv12}) {
    s.format = format;
    EXPECT_EQ(make_v4l2_source(s)->geometry().slot_pixel_bytes, 0U) << to_string(format) << " lends its buffers";
  }
}

TEST(V4l2Names, ControlNamesAsV4l2CtlPrintsThem) {
  EXPECT_EQ(v4l2_control_name("Exposure Time, Absolute"), "exposure_time_absolute");
  EXPECT_EQ(v4l2_control_name("White Balance Temperature"), "white_balance_temperature");
  EXPECT_EQ(v4l2_control_name("Power Line Frequency"), "power_line_frequency");
  EXPECT_EQ(v4l2_control_name("Inject V4L2_BUF_FLAG_ERROR"), "inject_v4l2_buf_flag_error");
  EXPECT_EQ(v4l2_control_name("  (Leading) and trailing -- "), "leading_and_trailing");
  EXPECT_EQ(fourcc_text(0x56595559), "YUYV");
  EXPECT_EQ(fourcc_text(fourcc_of(V4l2PixelFormat::mjpg)), "MJPG");
  EXPECT_EQ(fourcc_text(fourcc_of(V4l2PixelFormat::grey)), "GREY");
  EXPECT_EQ(fourcc_text(0x20363159), "Y16");
  EXPECT_EQ(fourcc_text(0x20363159U | (1U << 31)), "Y16-BE");
}

// ---------------------------------------------------------------- devices

// A /dev of our own: video nodes that are plain files, and the udev links.
class FakeDev : public testing::Test {
 protected:
  void SetUp() override {
    fs::create_directories(dev_ / "v4l" / "by-id");
    fs::create_directories(dev_ / "v4l" / "by-path");
  }

  void touch(const std::string& name) const { std::ofstream(dev_ / name) << "not a camera"; }

  const test_support::TempDir temp_{"markerd-v4l2"};
  const fs::path dev_ = temp_.path();
};

TEST_F(FakeDev, ResolvesPathsLinksAndBareNames) {
  touch("video0");
  fs::create_symlink("../../video0", dev_ / "v4l/by-id/usb-Acme_Cam-video-index0");
  fs::create_symlink("../../video0", dev_ / "v4l/by-path/pci-0000:00:14.0-usb-0:1:1.0-video-index0");

  EXPECT_EQ(resolve_v4l2_device("/dev/video7", dev_), fs::path("/dev/video7")) << "a path is taken as it is";
  EXPECT_EQ(resolve_v4l2_device("usb-Acme_Cam-video-index0", dev_), dev_ / "v4l/by-id/usb-Acme_Cam-video-index0");
  EXPECT_EQ(resolve_v4l2_device("pci-0000:00:14.0-usb-0:1:1.0-video-index0", dev_),
            dev_ / "v4l/by-path/pci-0000:00:14.0-usb-0:1:1.0-video-index0");
  EXPECT_EQ(resolve_v4l2_device("video0", dev_), dev_ / "video0");
  try {
    (void)resolve_v4l2_device("usb-Other_Cam-video-index0", dev_);
    FAIL() << "a missing bare name resolved";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_TRUE(contains(std::string(e.what()), "v4l2 usb-Other_Cam-video-index0: no such device"));
    EXPECT_TRUE(contains(std::string(e.what()), (dev_ / "v4l/by-id/usb-Other_Cam-video-index0").string()));
    EXPECT_TRUE(contains(std::string(e.what()), (dev_ / "v4l/by-path/usb-Other_Cam-video-index0").string()));
  }
}

TEST_F(FakeDev, ListingOfADevWithoutVideoNodesIsEmpty) {
  touch("null");
  touch("video");    // no number
  touch("videoX1");  // not a video node name
  touch("video1.bak");
  EXPECT_TRUE(list_v4l2_devices(dev_).empty());
  EXPECT_TRUE(list_v4l2_devices(dev_ / "does-not-exist").empty());
}

TEST_F(FakeDev, ANodeThatIsNoV4l2DeviceIsListedWithWhy) {
  touch("video10");
  touch("video2");
  fs::create_symlink("../../video2", dev_ / "v4l/by-id/usb-Acme_Cam-video-index0");
  const auto devices = list_v4l2_devices(dev_);
  ASSERT_EQ(devices.size(), 2U);
  EXPECT_EQ(devices[0].path, (dev_ / "video2").string()) << "in number order, not name order";
  EXPECT_EQ(devices[1].path, (dev_ / "video10").string());
  EXPECT_TRUE(contains(devices[0].error, "not a V4L2 device (VIDIOC_QUERYCAP: "));
  ASSERT_EQ(devices[0].stable_names.size(), 1U);
  EXPECT_EQ(devices[0].stable_names[0], (dev_ / "v4l/by-id/usb-Acme_Cam-video-index0").string());
  EXPECT_TRUE(devices[1].stable_names.empty());

  const auto json = to_json(devices[0]);
  EXPECT_EQ(json["path"], (dev_ / "video2").string());
  EXPECT_EQ(json["stable_names"].size(), 1U);
  EXPECT_TRUE(contains(json["error"].get<std::string>(), "not a V4L2 device"));
  EXPECT_FALSE(json.contains("formats"));
}

bool this_machine_has_video_nodes();

TEST(V4l2Devices, ThisMachinesListingMatchesItsDev) {
  if (this_machine_has_video_nodes()) GTEST_SKIP() << "this machine has /dev/video* nodes; the HIL test covers them";
  EXPECT_TRUE(list_v4l2_devices().empty());
}

V4l2Settings settings_for(const std::string& device) {
  V4l2Settings s;
  s.device = device;
  s.width = 640;
  s.height = 480;
  return s;
}

CaptureError open_error(CaptureSource& source) {
  try {
    source.open();
  } catch (const CaptureError& e) {
    return e;
  }
  return {CaptureError::Kind::io, "(no error)"};
}

TEST(V4l2Source, AMissingDeviceIsNotFoundAndNamed) {
  const auto source = make_v4l2_source(settings_for("/dev/video-markerd-test-missing"));
  EXPECT_EQ(source->name(), "v4l2 /dev/video-markerd-test-missing");
  EXPECT_FALSE(source->is_open());
  const auto e = open_error(*source);
  EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
  EXPECT_EQ(std::string(e.what()),
            "v4l2 /dev/video-markerd-test-missing: cannot open /dev/video-markerd-test-missing: No such file or "
            "directory (not plugged in, or its driver not loaded)");
  EXPECT_FALSE(source->is_open());
  source->close();  // safe when not open
  source->close();

  const auto by_name = make_v4l2_source(settings_for("usb-Nobody_Cam-video-index0"));
  const auto e2 = open_error(*by_name);
  EXPECT_EQ(e2.kind(), CaptureError::Kind::not_found);
  EXPECT_TRUE(contains(std::string(e2.what()), "/dev/v4l/by-id/usb-Nobody_Cam-video-index0"));
}

TEST(V4l2Source, AFileThatIsNoV4l2DeviceIsAConfigError) {
  const auto source = make_v4l2_source(settings_for("/dev/null"));
  const auto e = open_error(*source);
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  EXPECT_TRUE(contains(std::string(e.what()), "v4l2 /dev/null: not a V4L2 device (VIDIOC_QUERYCAP: "));
  EXPECT_FALSE(source->is_open());
}

bool this_machine_has_video_nodes() {
  for (const auto& entry : fs::directory_iterator("/dev")) {
    if (entry.path().filename().string().rfind("video", 0) == 0) return true;
  }
  return false;
}

#ifdef MARKERCTL_PATH
// markerctl's output (stdout and stderr, as a terminal shows them) and exit status.
std::string markerctl(std::vector<std::string> arguments, int& exit_status) {
  arguments.insert(arguments.begin(), MARKERCTL_PATH);
  test_support::ProcessOptions options;
  options.merge_output = true;
  const test_support::Outcome outcome = test_support::run_program(arguments, options);
  exit_status = outcome.code;
  return outcome.out;
}

TEST(MarkerctlCameras, NamesWhatItCannotList) {
  int status = 0;
  std::string out = markerctl({"cameras", "/dev/null"}, status);
  EXPECT_EQ(status, 1);
  EXPECT_TRUE(contains(out, "markerctl: cameras: /dev/null: not a V4L2 device (VIDIOC_QUERYCAP: "));
  out = markerctl({"cameras", "usb-Nobody_Cam-video-index0"}, status);
  EXPECT_EQ(status, 1);
  EXPECT_TRUE(contains(out,
                       "markerctl: cameras: v4l2 usb-Nobody_Cam-video-index0: no such device: none of "
                       "/dev/v4l/by-id/usb-Nobody_Cam-video-index0"));
}

TEST(MarkerctlCameras, SaysSoWhenThereIsNoCamera) {
  if (this_machine_has_video_nodes()) GTEST_SKIP() << "this machine has /dev/video* nodes";
  int status = 0;
  EXPECT_EQ(markerctl({"cameras"}, status),
            "no V4L2 capture devices (no /dev/video* node that captures video)\nno libcamera cameras\n");
  EXPECT_EQ(status, 0);
  EXPECT_EQ(markerctl({"cameras", "--backend", "v4l2"}, status),
            "no V4L2 capture devices (no /dev/video* node that captures video)\n");
  EXPECT_EQ(status, 0);
  EXPECT_EQ(markerctl({"cameras", "--backend", "libcamera"}, status), "no libcamera cameras\n");
  EXPECT_EQ(status, 0);
  EXPECT_EQ(markerctl({"cameras", "--json"}, status), "");
  EXPECT_EQ(status, 0);
  EXPECT_EQ(markerctl({"cameras", "--backend", "libcamera", "usb-1d6b:0104"}, status),
            "markerctl: cameras: libcamera has no camera 'usb-1d6b:0104' (it has: none)\n");
  EXPECT_EQ(status, 1);
}
#endif

}  // namespace
}  // namespace markerd::daemon
