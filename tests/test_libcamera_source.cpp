// The libcamera source on a machine without cameras: [camera.libcamera] is
// read with its errors, the shared camera manager starts (and restarts) and
// lists what there is, opening a camera that is not there says so and names
// the cameras that are, and close() is safe whenever. Streaming needs a
// camera: the qemu UVC gadget test (tests/hil/test_uvc_hil.cpp) covers it; nothing here fakes
// a libcamera Camera (libcamera offers no way to make one outside a pipeline
// handler).

#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/libcamera_source.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;

// libcamera logs each manager start to stderr (its version, at INFO, and a
// warning when no IPA modules are installed, as on this machine). Its logger
// reads LIBCAMERA_LOG_LEVELS once, when libcamera first logs, so this is set
// before any test runs; a level given in the environment is kept.
const bool kQuietLibcamera = [] { return ::setenv("LIBCAMERA_LOG_LEVELS", "*:ERROR", 0) == 0; }();

// libcamera finds cameras through media controller devices only.
bool machine_has_media_devices() {
  std::error_code error;
  for (const auto& entry : std::filesystem::directory_iterator("/dev", error)) {
    if (entry.path().filename().string().starts_with("media")) return true;
  }
  return false;
}

LibcameraSettings parse(const std::string& body) {
  const auto config = ConfigTable::parse("[camera.libcamera]\n" + body, "markerd.toml");
  return parse_libcamera_settings(config.table("camera").table("libcamera"));
}

std::string parse_error(const std::string& body) {
  try {
    (void)parse(body);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(LibcameraSettingsTest, ReadsTheTable) {
  ASSERT_TRUE(kQuietLibcamera);
  const auto settings = parse(R"(camera = "/base/soc/i2c0mux/i2c@1/imx219@10"
pixel_format = "NV12"
width = 1280
height = 720
fps = 30
buffers = 6
[camera.libcamera.controls]
ExposureTime = 8000
AnalogueGain = 2.0
AeEnable = false
Brightness = 0
)");
  EXPECT_EQ(settings.camera, "/base/soc/i2c0mux/i2c@1/imx219@10");
  EXPECT_EQ(settings.format, LibcameraPixelFormat::nv12);
  EXPECT_EQ(settings.width, 1280);
  EXPECT_EQ(settings.height, 720);
  EXPECT_EQ(settings.fps, 30.0);
  EXPECT_EQ(settings.buffers, 6);
  ASSERT_EQ(settings.controls.size(), 4U);
  for (const auto& control : settings.controls) {
    if (control.name == "ExposureTime") {
      EXPECT_EQ(std::get<std::int64_t>(control.value), 8000);
      EXPECT_EQ(control.origin, "markerd.toml:9: camera.libcamera.controls.ExposureTime");
    } else if (control.name == "AnalogueGain") {
      EXPECT_EQ(std::get<double>(control.value), 2.0);
    } else if (control.name == "AeEnable") {
      EXPECT_FALSE(std::get<bool>(control.value));
    } else if (control.name == "Brightness") {
      EXPECT_EQ(std::get<double>(control.value), 0.0);  // a float control takes an integer too
    } else {
      ADD_FAILURE() << "unexpected control " << control.name;
    }
  }
}

TEST(LibcameraSettingsTest, Defaults) {
  const auto settings = parse("width = 640\nheight = 480\n");
  EXPECT_EQ(settings.camera, "");  // the first camera
  EXPECT_EQ(settings.format, LibcameraPixelFormat::yuyv);
  EXPECT_EQ(settings.fps, 0.0);
  EXPECT_EQ(settings.buffers, 4);
  EXPECT_TRUE(settings.controls.empty());
  EXPECT_EQ(parse("width = 640\nheight = 480\npixel_format = \"GREY\"\n").format, LibcameraPixelFormat::r8);
  EXPECT_EQ(parse("width = 640\nheight = 480\npixel_format = \"R8\"\n").format, LibcameraPixelFormat::r8);
  EXPECT_EQ(parse("width = 640\nheight = 480\npixel_format = \"MJPEG\"\n").format, LibcameraPixelFormat::mjpeg);
  EXPECT_EQ(parse("width = 640\nheight = 480\npixel_format = \"MJPG\"\n").format, LibcameraPixelFormat::mjpeg);
}

TEST(LibcameraSettingsTest, ErrorsNameTheFileLineAndKey) {
  EXPECT_EQ(parse_error("width = 640\nheight = 480\npixel_format = \"H264\"\n"),
            "markerd.toml:4: camera.libcamera.pixel_format: unknown pixel format 'H264' (known: YUYV, NV12, R8, GREY, "
            "MJPEG, MJPG)");
  EXPECT_NE(parse_error("height = 480\n").find("camera.libcamera.width"), std::string::npos);
  EXPECT_EQ(parse_error("width = 641\nheight = 480\n"),
            "markerd.toml:2: camera.libcamera.width: must be even for YUYV (two pixels share their colour), got 641");
  EXPECT_EQ(parse("width = 641\nheight = 480\npixel_format = \"NV12\"\n").width, 641);
  EXPECT_EQ(parse_error("width = 640\nheight = 0\n"),
            "markerd.toml:3: camera.libcamera.height: must be > 0 and at most 16384, got 0");
  EXPECT_EQ(parse_error("width = 2147483646\nheight = 480\n"),
            "markerd.toml:2: camera.libcamera.width: must be > 0 and at most 16384, got 2147483646");
  EXPECT_EQ(
      parse_error("width = 640\nheight = 480\nfps = -1\n"),
      "markerd.toml:4: camera.libcamera.fps: must be >= 0 (0: the camera's own frame rate) and at most 1000, got -1");
  EXPECT_EQ(parse_error("width = 640\nheight = 480\nfps = 1e308\n"),
            "markerd.toml:4: camera.libcamera.fps: must be >= 0 (0: the camera's own frame rate) and at most 1000, got "
            "1e+308");
  EXPECT_EQ(parse_error("width = 640\nheight = 480\nbuffers = 0\n"),
            "markerd.toml:4: camera.libcamera.buffers: must be between 1 and 32, got 0");
  EXPECT_NE(parse_error("width = 640\nheight = 480\nformat = \"YUYV\"\n")
                .find("markerd.toml:4: camera.libcamera.format: unknown key"),
            std::string::npos);
}

TEST(LibcameraSettingsTest, ControlsAreCheckedAgainstLibcamerasNames) {
  const std::string head = "width = 640\nheight = 480\n[camera.libcamera.controls]\n";
  const std::string unknown = parse_error(head + "Exposure = 100\n");
  EXPECT_NE(unknown.find("markerd.toml:5: camera.libcamera.controls.Exposure: libcamera has no control 'Exposure'"),
            std::string::npos)
      << unknown;
  EXPECT_NE(unknown.find("ExposureTime"), std::string::npos) << unknown;  // the list of what there is

  EXPECT_EQ(parse_error(head + "ExposureTime = 1.5\n"),
            "markerd.toml:5: camera.libcamera.controls.ExposureTime: must be an integer");
  EXPECT_EQ(parse_error(head + "ExposureTime = 3000000000\n"),
            "markerd.toml:5: camera.libcamera.controls.ExposureTime: must be a 32-bit integer, got 3000000000");
  EXPECT_EQ(parse_error(head + "AeEnable = 1\n"),
            "markerd.toml:5: camera.libcamera.controls.AeEnable: must be a boolean");
  EXPECT_EQ(parse_error(head + "AnalogueGain = \"high\"\n"),
            "markerd.toml:5: camera.libcamera.controls.AnalogueGain: must be a number");
  EXPECT_EQ(parse_error(head + "FrameDurationLimits = [33333, 33333]\n"),
            "markerd.toml:5: camera.libcamera.controls.FrameDurationLimits: "
            "set the frame rate with [camera.libcamera] fps");
  EXPECT_EQ(parse_error(head + "ColourGains = [1.5, 2.0]\n"),
            "markerd.toml:5: camera.libcamera.controls.ColourGains: an array control cannot be set from the config");
  EXPECT_EQ(parse_error(head + "ScalerCrop = 1\n"),
            "markerd.toml:5: camera.libcamera.controls.ScalerCrop: a rectangle control cannot be set from the config");
}

TEST(LibcameraSourceTest, GeometryComesFromTheSettingsBeforeOpen) {
  auto yuyv = make_libcamera_source(parse("width = 640\nheight = 480\nfps = 15\n"));
  EXPECT_EQ(yuyv->geometry().width, 640);
  EXPECT_EQ(yuyv->geometry().height, 480);
  EXPECT_EQ(yuyv->geometry().slot_pixel_bytes, 640U * 480U);  // converted into the slots
  EXPECT_EQ(yuyv->geometry().frame_rate, 15.0);
  EXPECT_EQ(yuyv->name(), "libcamera (first camera) YUYV 640x480@15");

  auto nv12 = make_libcamera_source(parse("camera = \"cam0\"\npixel_format = \"NV12\"\nwidth = 640\nheight = 480\n"));
  EXPECT_EQ(nv12->geometry().slot_pixel_bytes, 0U);  // the Y plane is lent
  EXPECT_EQ(nv12->name(), "libcamera cam0 NV12 640x480");
}

TEST(LibcameraSourceTest, ListsTheCamerasThereAre) {
  const auto cameras = list_libcamera_cameras();
  if (!machine_has_media_devices()) {
    EXPECT_TRUE(cameras.empty());
  }
  for (const auto& camera : cameras) {
    EXPECT_FALSE(camera.id.empty());
    const auto json = to_json(camera);
    EXPECT_EQ(json["id"], camera.id);
    EXPECT_TRUE(json["formats"].is_array());
    EXPECT_TRUE(json["controls"].is_array());
  }
}

TEST(LibcameraSourceTest, ListingAsJson) {
  LibcameraCameraInfo camera;
  camera.id = "\\_SB_.PCI0.XHC_.RHUB.HS04-4:1.0-0c45:6366";
  camera.model = "USB 2.0 Camera";
  camera.location = "external";
  camera.formats.push_back(LibcameraStreamFormat{"YUYV", {{640, 480}, {1280, 720}}, {640, 480}, {1280, 720}});
  camera.controls.push_back(LibcameraControlInfo{"AeEnable", "bool", false, true, true, {}});
  camera.controls.push_back(
      LibcameraControlInfo{"ExposureTime", "int32", std::int64_t{100}, std::int64_t{500000}, std::monostate{}, {}});
  camera.controls.push_back(LibcameraControlInfo{"Brightness", "float", -1.0, 1.0, 0.0, {}});

  const auto json = to_json(camera);
  EXPECT_EQ(json["backend"], "libcamera");
  EXPECT_EQ(json["id"], camera.id);
  EXPECT_EQ(json["model"], "USB 2.0 Camera");
  EXPECT_EQ(json["location"], "external");
  EXPECT_TRUE(json["rotation"].is_null());
  EXPECT_FALSE(json.contains("error"));
  ASSERT_EQ(json["formats"].size(), 1U);
  EXPECT_EQ(json["formats"][0]["pixel_format"], "YUYV");
  EXPECT_EQ(json["formats"][0]["sizes"][1]["width"], 1280);
  EXPECT_EQ(json["formats"][0]["sizes"][1]["height"], 720);
  EXPECT_EQ(json["formats"][0]["max_size"]["width"], 1280);
  ASSERT_EQ(json["controls"].size(), 3U);
  EXPECT_EQ(json["controls"][0]["name"], "AeEnable");
  EXPECT_EQ(json["controls"][0]["default"], true);
  EXPECT_EQ(json["controls"][1]["max"], 500000);
  EXPECT_TRUE(json["controls"][1]["default"].is_null());
  EXPECT_EQ(json["controls"][2]["min"], -1.0);
  EXPECT_FALSE(json["controls"][2].contains("values"));
}

TEST(LibcameraSourceTest, OpeningAMissingCameraIsNotFoundAndNamesWhatThereIs) {
  if (machine_has_media_devices()) {
    GTEST_SKIP() << "this machine has media devices: libcamera may find cameras";
  }
  auto source = make_libcamera_source(parse("camera = \"no-such-camera\"\nwidth = 640\nheight = 480\n"));
  try {
    source->open();
    FAIL() << "opened a camera that does not exist";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_EQ(std::string(e.what()),
              "libcamera no-such-camera YUYV 640x480: no camera 'no-such-camera' (libcamera's cameras: none)");
  }
  EXPECT_FALSE(source->is_open());
  source->close();  // after a failed open

  auto first = make_libcamera_source(parse("width = 640\nheight = 480\n"));
  try {
    first->open();
    FAIL() << "opened a first camera on a machine without cameras";
  } catch (const CaptureError& e) {
    EXPECT_EQ(e.kind(), CaptureError::Kind::not_found);
    EXPECT_EQ(std::string(e.what()), "libcamera (first camera) YUYV 640x480: libcamera finds no camera");
  }
}

TEST(LibcameraSourceTest, CloseWhenNotOpenIsSafe) {
  auto source = make_libcamera_source(parse("width = 640\nheight = 480\n"));
  EXPECT_FALSE(source->is_open());
  source->close();
  source->close();
  source->skip();  // nothing ready: nothing to give back
  EXPECT_FALSE(source->is_open());
  EXPECT_FALSE(source->at_end());
  EXPECT_THROW((void)source->wait_frame(10ms), CaptureError);
}

// libcamera aborts the process on a second CameraManager; the listing and the
// sources share one, made again after the last user let the old one go.
TEST(LibcameraSourceTest, OneCameraManagerAtATimeAcrossThreads) {
  const LibcameraSettings absent = parse("camera = \"absent\"\nwidth = 64\nheight = 48\n");
  std::vector<std::thread> threads;
  for (int t = 0; t < 3; ++t) {
    threads.emplace_back([t, &absent] {
      for (int i = 0; i < 10; ++i) {
        if ((i + t) % 2 == 0) {
          (void)list_libcamera_cameras();
        } else {
          auto source = make_libcamera_source(absent);
          try {
            source->open();
          } catch (const CaptureError&) {
          }
        }
      }
    });
  }
  for (auto& thread : threads) thread.join();
  SUCCEED();  // the process is alive: no two managers at once
}

}  // namespace
}  // namespace markerd::daemon
