// The V4L2 source against the kernel's vivid driver. Runs inside Debian's
// kernel under qemu (ctest's hil_v4l2, tools/hil/hil-run), as root, with
// vivid loaded as one capture and one output node and the vivid-loop setup
// step's variables:
//   HIL_VIVID_CAPTURE, HIL_VIVID_OUTPUT  the two nodes
//   HIL_VIVID_PLATFORM                   vivid's platform device, to unbind
//   HIL_VIVID_MODULE, HIL_VIVID_PARAMS   vivid.ko and its parameters, to load
//                                        it again after unloading it
// Outside such a guest every test skips.
//
// Frames the test writes into the output node come back on the capture node
// byte for byte (vivid's video loop: HDMI output to HDMI input, the same DV
// timings, format and field on both sides, the capture's "Loop Video" on and
// its OSD text off). Each frame carries its number in its pixels, so the
// test knows which frame came back and that every pixel did. The test talks
// to vivid directly (its own descriptors, ioctls and control ids) only to
// drive the far side and to read back what the source did.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/capture/v4l2_listing.hpp"
#include "markerd/daemon/capture/v4l2_source.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "markerd_child.hpp"
#include "v4l2_node.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

using hil::errno_text;
using hil::kHdmiInput;
using hil::kHeight;
using hil::kWidth;
using hil::LoopOutput;
using hil::must;
using hil::Node;
using hil::timings_640x480p60;
using hil::xioctl;

// Generous: the guest is emulated (TCG) on a loaded 2-core host.
constexpr auto kFrameTimeout = 5000ms;

// vivid's own controls (drivers/media/test-drivers/vivid/vivid-ctrls.c).
constexpr std::uint32_t kOsdTextMode = 0x00f0f001;
constexpr std::uint32_t kLoopVideo = 0x00f0f025;

const char* env(const char* name) {
  const char* value = std::getenv(name);
  return value != nullptr && *value != '\0' ? value : nullptr;
}

struct Vivid {
  std::string capture, output, platform, module, params;
};

std::optional<Vivid> vivid_from_env() {
  const char* names[] = {"HIL_VIVID_CAPTURE", "HIL_VIVID_OUTPUT", "HIL_VIVID_PLATFORM", "HIL_VIVID_MODULE"};
  for (const char* name : names) {
    if (env(name) == nullptr) return std::nullopt;
  }
  return Vivid{env("HIL_VIVID_CAPTURE"), env("HIL_VIVID_OUTPUT"), env("HIL_VIVID_PLATFORM"), env("HIL_VIVID_MODULE"),
               env("HIL_VIVID_PARAMS") != nullptr ? env("HIL_VIVID_PARAMS") : ""};
}

std::int32_t get_control(const std::string& node, std::uint32_t id) {
  Node n(node);
  v4l2_control control{id, 0};
  must(n.fd(), VIDIOC_G_CTRL, &control, "VIDIOC_G_CTRL");
  return control.value;
}

// A control's id by its name as v4l2-ctl prints it, looked up without the
// code under test.
std::uint32_t control_id(int fd, const std::string& name) {
  v4l2_query_ext_ctrl q{};
  q.id = V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND;
  while (xioctl(fd, VIDIOC_QUERY_EXT_CTRL, &q) == 0) {
    if (v4l2_control_name(q.name) == name) return q.id;
    const std::uint32_t next = q.id | V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND;
    q = {};
    q.id = next;
  }
  throw std::runtime_error("vivid has no control " + name);
}

constexpr int kWebcamInput = 0;

// Selects the capture node's input before the source opens it; the HDMI
// input gets the timings the output sends.
void select_capture_input(const std::string& capture, int input) {
  Node n(capture);
  must(n.fd(), VIDIOC_S_INPUT, &input, "VIDIOC_S_INPUT");
  if (input == kHdmiInput) {
    auto timings = timings_640x480p60();
    must(n.fd(), VIDIOC_S_DV_TIMINGS, &timings, "capture VIDIOC_S_DV_TIMINGS");
  }
}

// ---------------------------------------------------------------- the far side

// The pixels of frame `number`: its number in the first four bytes of the
// first row, a pattern that moves with the number everywhere else.
std::uint8_t luma(std::uint32_t number, int x, int y) {
  if (y == 0 && x < 4) return static_cast<std::uint8_t>(number >> (8 * x));
  return static_cast<std::uint8_t>(x + 3 * y + 7 * static_cast<int>(number));
}

// The number of the frame `image` shows, when every pixel is that frame's.
std::optional<std::uint32_t> frame_number(const detector::GreyView& image) {
  if (image.width != kWidth || image.height != kHeight || image.data == nullptr) return std::nullopt;
  const std::uint8_t* row0 = image.row(0);
  const std::uint32_t number = row0[0] | (row0[1] << 8) | (row0[2] << 16) | (static_cast<std::uint32_t>(row0[3]) << 24);
  for (int y = 0; y < image.height; ++y) {
    const std::uint8_t* row = image.row(y);
    for (int x = 0; x < image.width; ++x) {
      if (row[x] != luma(number, x, y)) return std::nullopt;
    }
  }
  return number;
}

// Writes numbered frames into vivid's HDMI output from a thread of its own,
// requeueing each buffer the moment the driver is done with it: a queue that
// runs dry makes the capture fall back to its test pattern.
class LoopWriter {
 public:
  LoopWriter(const std::string& output, std::uint32_t fourcc) : output_(output, fourcc), fourcc_(fourcc) {
    for (std::uint32_t i = 0; i < output_.count(); ++i) queue(i);
    output_.stream_on();
    thread_ = std::jthread([this](const std::stop_token& stop) { run(stop); });
  }

  ~LoopWriter() {
    thread_.request_stop();
    thread_.join();
    output_.stream_off();
  }
  LoopWriter(const LoopWriter&) = delete;
  LoopWriter& operator=(const LoopWriter&) = delete;

  [[nodiscard]] std::uint32_t written() const { return next_.load(); }
  [[nodiscard]] const std::string& error() const { return error_; }  // after the destructor's join: read in tests only

 private:
  void queue(std::uint32_t index) {
    const std::uint32_t number = next_.fetch_add(1);
    std::uint8_t* data = output_.buffer(index).data;
    const std::uint32_t stride = output_.stride();
    for (int y = 0; y < kHeight; ++y) {
      std::uint8_t* row = data + static_cast<std::size_t>(y) * stride;
      for (int x = 0; x < kWidth; ++x) {
        if (fourcc_ == V4L2_PIX_FMT_YUYV) {
          row[2 * x] = luma(number, x, y);
          row[2 * x + 1] = 128;
        } else {
          row[x] = luma(number, x, y);
        }
      }
    }
    if (fourcc_ == V4L2_PIX_FMT_NV12) {  // neutral chroma after the Y plane
      std::memset(data + static_cast<std::size_t>(stride) * kHeight, 128,
                  static_cast<std::size_t>(stride) * kHeight / 2);
    }
    if (const int e = output_.queue(index); e != 0) {
      throw std::runtime_error("output VIDIOC_QBUF: " + std::string(std::strerror(e)));
    }
  }

  void run(const std::stop_token& stop) {
    try {
      while (!stop.stop_requested()) {
        pollfd p{output_.fd(), POLLOUT, 0};
        if (::poll(&p, 1, 50) <= 0) continue;
        const auto done = output_.dequeue();
        if (!done) {
          if (errno == EAGAIN) continue;
          throw std::runtime_error(errno_text("output VIDIOC_DQBUF"));
        }
        queue(*done);
      }
    } catch (const std::exception& e) {
      error_ = e.what();
    }
  }

  LoopOutput output_;
  std::uint32_t fourcc_;
  std::atomic<std::uint32_t> next_{0};
  std::string error_;
  std::jthread thread_;
};

// ---------------------------------------------------------------- fixture

class V4l2Hil : public testing::Test {
 protected:
  void SetUp() override {
    auto vivid = vivid_from_env();
    if (!vivid) GTEST_SKIP() << "no vivid devices: run through ctest -R hil_v4l2 (tools/hil/hil-run)";
    vivid_ = *vivid;
  }

  [[nodiscard]] V4l2Settings loop_settings(V4l2PixelFormat format) const {
    V4l2Settings s;
    s.device = vivid_.capture;
    s.format = format;
    s.width = kWidth;
    s.height = kHeight;
    s.input = kHdmiInput;
    s.controls = {{"loop_video", true, "test"}, {"osd_text_mode", std::string("None"), "test"}};
    return s;
  }

  [[nodiscard]] V4l2Settings webcam_settings(V4l2PixelFormat format, int width, int height) const {
    V4l2Settings s;
    s.device = vivid_.capture;
    s.format = format;
    s.width = width;
    s.height = height;
    s.input = kWebcamInput;
    return s;
  }

  // The next frame, filled into a slot of `pool`.
  static Frame& next_frame(CaptureSource& source, FramePool& pool) {
    if (!source.wait_frame(kFrameTimeout)) throw std::runtime_error(source.name() + ": no frame within the timeout");
    Frame* frame = pool.try_acquire();
    if (frame == nullptr) throw std::runtime_error("the test's frame pool is empty");
    source.fill(*frame);
    return *frame;
  }

  Vivid vivid_;
};

CaptureError capture_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const CaptureError& e) {
    return e;
  }
  return {CaptureError::Kind::io, "(no error)"};
}

// ---------------------------------------------------------------- tests

TEST_F(V4l2Hil, ListsVividsFormatsSizesAndControls) {
  select_capture_input(vivid_.capture, kWebcamInput);
  const auto devices = list_v4l2_devices();
  ASSERT_EQ(devices.size(), 1U) << "the output node is no capture device";
  const auto& d = devices[0];
  EXPECT_EQ(d.path, vivid_.capture);
  EXPECT_TRUE(d.error.empty()) << d.error;
  EXPECT_EQ(d.driver, "vivid");
  EXPECT_EQ(d.card.rfind("vivid", 0), 0U) << d.card;
  EXPECT_FALSE(d.multiplanar);
  ASSERT_EQ(d.inputs.size(), 2U);
  EXPECT_EQ(d.current_input, 0U);

  const auto format = [&](const std::string& fourcc) -> const V4l2FormatInfo* {
    for (const auto& f : d.formats) {
      if (f.fourcc_text == fourcc) return &f;
    }
    return nullptr;
  };
  for (const char* fourcc : {"YUYV", "GREY", "NV12"}) EXPECT_NE(format(fourcc), nullptr) << fourcc;
  const auto* yuyv = format("YUYV");
  ASSERT_NE(yuyv, nullptr);
  // The webcam input's discrete sizes, each with its frame rates.
  const auto size = std::find_if(yuyv->sizes.begin(), yuyv->sizes.end(),
                                 [](const V4l2FrameSize& s) { return s.width == 640 && s.height == 480; });
  ASSERT_NE(size, yuyv->sizes.end());
  EXPECT_FALSE(size->intervals.discrete.empty());

  const auto control = [&](const std::string& name) -> const V4l2ControlInfo* {
    for (const auto& c : d.controls) {
      if (c.name == name) return &c;
    }
    return nullptr;
  };
  const auto* brightness = control("brightness");
  ASSERT_NE(brightness, nullptr);
  EXPECT_EQ(brightness->type, "int");
  EXPECT_EQ(brightness->minimum, 0);
  EXPECT_EQ(brightness->maximum, 255);
  ASSERT_TRUE(brightness->value.has_value());
  const auto* loop = control("loop_video");
  ASSERT_NE(loop, nullptr);
  EXPECT_EQ(loop->type, "bool");
  EXPECT_EQ(loop->id, kLoopVideo);
  const auto* osd = control("osd_text_mode");
  ASSERT_NE(osd, nullptr);
  EXPECT_EQ(osd->type, "menu");
  ASSERT_EQ(osd->menu.size(), 3U);
  EXPECT_EQ(osd->menu[2].name, "None");

  const auto json = to_json(d);
  EXPECT_EQ(json["path"], vivid_.capture);
  EXPECT_EQ(json["driver"], "vivid");
  EXPECT_FALSE(json["formats"].empty());
  EXPECT_FALSE(json["controls"].empty());

  // The output node, asked for by path, says what it is.
  const auto output = describe_v4l2_device(vivid_.output);
  EXPECT_EQ(output.error, "not a video capture device");
}

#ifdef MARKERCTL_PATH
using hil::run_command;

// One run only: markerctl links OpenCV, whose hundreds of libraries take
// seconds to load under TCG. The JSON is to_json's, tested above; the
// refusal of a node that captures nothing is tested on the host.
TEST_F(V4l2Hil, MarkerctlCamerasPrintsTheListing) {
  int status = 0;
  const std::string table = run_command(std::string(MARKERCTL_PATH) + " cameras --backend v4l2", status);
  ASSERT_EQ(status, 0) << table;
  EXPECT_NE(table.find(vivid_.capture + "  vivid"), std::string::npos) << table;
  EXPECT_EQ(table.find(vivid_.output), std::string::npos) << "lists capture nodes only: " << table;
  EXPECT_NE(table.find("    YUYV    YUYV 4:2:2\n"), std::string::npos) << table;
  EXPECT_NE(table.find("osd_text_mode"), std::string::npos) << table;
  EXPECT_NE(table.find("0: All, 1: Counters Only, 2: None"), std::string::npos) << table;
}
#endif

TEST_F(V4l2Hil, YuyvFramesComeBackAsTheirYInOrder) {
  LoopWriter writer(vivid_.output, V4L2_PIX_FMT_YUYV);
  select_capture_input(vivid_.capture, kHdmiInput);
  const auto source = make_v4l2_source(loop_settings(V4l2PixelFormat::yuyv));
  ASSERT_EQ(source->geometry().slot_pixel_bytes, static_cast<std::size_t>(kWidth * kHeight));
  FramePool pool({.slots = 4, .pixel_bytes = source->geometry().slot_pixel_bytes});
  const auto streaming = Clock::now();  // no frame of this stream can be stamped earlier
  source->open();
  ASSERT_TRUE(source->is_open());
  EXPECT_NEAR(source->geometry().frame_rate, 60.0, 0.1) << "the HDMI input runs at its timings' rate";

  // The source set the loop controls by name (a boolean, a menu item's name).
  EXPECT_EQ(get_control(vivid_.capture, kLoopVideo), 1);
  EXPECT_EQ(get_control(vivid_.capture, kOsdTextMode), 2);

  constexpr int kFrames = 40;
  std::vector<std::uint32_t> numbers;
  std::optional<std::uint64_t> last_sequence;
  std::optional<Clock::time_point> last_time;
  for (int i = 0; i < kFrames; ++i) {
    Frame& frame = next_frame(*source, pool);
    const auto now = Clock::now();
    EXPECT_EQ(frame.status, FrameStatus::ok) << frame.cause();
    EXPECT_EQ(frame.image.data, frame.pixel_buffer().data()) << "YUYV converts into the slot";
    EXPECT_FALSE(frame.has_release()) << "the buffer went back at once";
    const auto number = frame_number(frame.image);
    EXPECT_TRUE(number.has_value()) << "frame " << i << " is not one the test wrote (sequence " << frame.sequence
                                    << ")";
    if (number) numbers.push_back(*number);
    if (last_sequence) {
      EXPECT_GT(frame.sequence, *last_sequence);
    }
    if (last_time) {
      EXPECT_GT(frame.capture_time, *last_time);
    }
    // vivid stamps a frame with the nominal end of its period, which it
    // reckons from the start of streaming and may hand over before: up to a
    // period (16.7 ms at 60 Hz) and a scheduler tick ahead of the clock.
    EXPECT_LE(frame.capture_time, now + 25ms);
    EXPECT_GE(frame.capture_time, streaming) << "the driver's timestamp is on the monotonic clock";
    last_sequence = frame.sequence;
    last_time = frame.capture_time;
    pool.release(frame);
  }
  source->close();
  EXPECT_FALSE(source->is_open());
  ASSERT_EQ(numbers.size(), static_cast<std::size_t>(kFrames));
  EXPECT_TRUE(std::is_sorted(numbers.begin(), numbers.end())) << "frames came back out of order";
  EXPECT_GT(numbers.back(), numbers.front());
  const std::set<std::uint32_t> distinct(numbers.begin(), numbers.end());
  // Capture and output run on vivid's two threads at the same 60 Hz; under
  // emulation the capture takes the same output frame twice as often as the
  // writer falls behind, which is the host's load: a figure, printed below.
  std::cout << "looped back " << kFrames << " frames: numbers " << numbers.front() << " to " << numbers.back() << ", "
            << distinct.size() << " distinct, of " << writer.written() << " written\n";
  EXPECT_LE(numbers.back(), writer.written());
}

TEST_F(V4l2Hil, GreyIsLentWithoutACopyAndTheReleaseHookRequeues) {
  LoopWriter writer(vivid_.output, V4L2_PIX_FMT_GREY);
  select_capture_input(vivid_.capture, kHdmiInput);
  auto settings = loop_settings(V4l2PixelFormat::grey);
  settings.buffers = 3;
  const auto source = make_v4l2_source(settings);
  EXPECT_EQ(source->geometry().slot_pixel_bytes, 0U);
  FramePool pool({.slots = 8, .pixel_bytes = 0});
  source->open();

  // Hold every buffer: the driver then has none to fill, and no frame comes.
  std::vector<Frame*> held;
  std::set<const std::uint8_t*> addresses;
  for (int i = 0; i < settings.buffers; ++i) {
    Frame& frame = next_frame(*source, pool);
    EXPECT_EQ(frame.status, FrameStatus::ok) << frame.cause();
    EXPECT_TRUE(frame.pixel_buffer().empty());
    EXPECT_TRUE(frame.has_release()) << "lent, to be given back by the pipeline";
    EXPECT_TRUE(frame_number(frame.image).has_value()) << "the lent pixels are the frame the test wrote";
    addresses.insert(frame.image.data);
    held.push_back(&frame);
  }
  EXPECT_EQ(addresses.size(), static_cast<std::size_t>(settings.buffers)) << "one mmap buffer each";
  EXPECT_FALSE(source->wait_frame(400ms)) << "a frame came with every buffer lent";

  // Giving one back (the hook runs on this thread here, as on the log
  // stage's in the daemon) queues it again: frames flow.
  pool.release(*held.front());
  held.erase(held.begin());
  Frame& again = next_frame(*source, pool);
  EXPECT_TRUE(addresses.count(again.image.data) == 1) << "a frame in one of the same buffers";
  EXPECT_TRUE(frame_number(again.image).has_value());
  held.push_back(&again);

  // Closed with frames still lent: their pixels stay readable until they
  // are released, after close(), and a reopen gets the device back.
  source->close();
  for (Frame* frame : held) EXPECT_TRUE(frame_number(frame->image).has_value());
  source->open();
  Frame& reopened = next_frame(*source, pool);
  EXPECT_TRUE(frame_number(reopened.image).has_value());
  for (Frame* frame : held) pool.release(*frame);
  pool.release(reopened);
  for (int i = 0; i < 5; ++i) pool.release(next_frame(*source, pool));
  source->close();
}

TEST_F(V4l2Hil, Nv12LendsItsYPlane) {
  LoopWriter writer(vivid_.output, V4L2_PIX_FMT_NV12);
  select_capture_input(vivid_.capture, kHdmiInput);
  const auto source = make_v4l2_source(loop_settings(V4l2PixelFormat::nv12));
  FramePool pool({.slots = 4, .pixel_bytes = 0});
  source->open();
  for (int i = 0; i < 5; ++i) {
    Frame& frame = next_frame(*source, pool);
    EXPECT_EQ(frame.status, FrameStatus::ok) << frame.cause();
    EXPECT_TRUE(frame.has_release());
    EXPECT_GE(frame.image.stride, kWidth);
    EXPECT_TRUE(frame_number(frame.image).has_value()) << "the Y plane is the frame the test wrote";
    pool.release(frame);
  }
  source->close();
}

TEST_F(V4l2Hil, ControlsSetByNameReachTheDriverAndBadOnesAreNamed) {
  select_capture_input(vivid_.capture, kWebcamInput);
  auto settings = webcam_settings(V4l2PixelFormat::yuyv, 320, 180);
  settings.controls = {{"brightness", std::int64_t{77}, "test:1: camera.v4l2.controls.brightness"},
                       {"osd_text_mode", std::int64_t{1}, "test:2: camera.v4l2.controls.osd_text_mode"},
                       {"loop_video", false, "test:3: camera.v4l2.controls.loop_video"}};
  settings.fps = 30;
  auto source = make_v4l2_source(settings);
  source->open();
  {
    Node n(vivid_.capture);
    const auto brightness = control_id(n.fd(), "brightness");
    EXPECT_EQ(get_control(vivid_.capture, brightness), 77);
    // The frame rate went through VIDIOC_S_PARM (the webcam input's 320x180
    // offers 60, 50, 40, 30, ... fps) and reads back as what the source reports.
    v4l2_streamparm parm{};
    parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    must(n.fd(), VIDIOC_G_PARM, &parm, "VIDIOC_G_PARM");
    EXPECT_EQ(parm.parm.capture.timeperframe.numerator, 1U);
    EXPECT_EQ(parm.parm.capture.timeperframe.denominator, 30U);
    EXPECT_DOUBLE_EQ(source->geometry().frame_rate, 30.0);
  }
  EXPECT_EQ(get_control(vivid_.capture, kOsdTextMode), 1);
  EXPECT_EQ(get_control(vivid_.capture, kLoopVideo), 0);
  source->close();

  settings.controls = {{"brightnes", std::int64_t{77}, "test:1: camera.v4l2.controls.brightnes"}};
  source = make_v4l2_source(settings);
  auto e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  const std::string unknown = e.what();
  EXPECT_NE(unknown.find("control brightnes (test:1: camera.v4l2.controls.brightnes): the device has no such "
                         "control (it has: "),
            std::string::npos)
      << unknown;
  EXPECT_NE(unknown.find("brightness, contrast"), std::string::npos) << unknown;
  EXPECT_FALSE(source->is_open());

  settings.controls = {{"brightness", std::int64_t{300}, "test:1: camera.v4l2.controls.brightness"}};
  source = make_v4l2_source(settings);
  e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  EXPECT_NE(std::string(e.what()).find("300 is out of its range 0 to 255"), std::string::npos) << e.what();

  settings.controls = {{"osd_text_mode", std::string("Some"), "test:1: camera.v4l2.controls.osd_text_mode"}};
  source = make_v4l2_source(settings);
  e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  EXPECT_NE(std::string(e.what()).find("'Some' is not one of its items (0: All, 1: Counters Only, 2: None)"),
            std::string::npos)
      << e.what();
}

// The mean grey level of a frame captured once earlier buffers have drained
// (vivid's webcam input draws its test pattern with the brightness set).
double settled_mean(CaptureSource& source, FramePool& pool) {
  double mean = 0;
  for (int i = 0; i < 6; ++i) {
    if (!source.wait_frame(kFrameTimeout)) throw std::runtime_error(source.name() + ": no frame within the timeout");
    Frame* frame = pool.try_acquire();
    if (frame == nullptr) throw std::runtime_error("the test's frame pool is empty");
    source.fill(*frame);
    double sum = 0;
    for (int y = 0; y < frame->image.height; ++y) {
      const std::uint8_t* row = frame->image.row(y);
      for (int x = 0; x < frame->image.width; ++x) sum += row[x];
    }
    mean = sum / (static_cast<double>(frame->image.width) * frame->image.height);
    pool.release(*frame);
  }
  return mean;
}

std::string set_refusal(CaptureSource& source, const std::vector<ControlAssignment>& assignments) {
  try {
    (void)set_camera_controls(source, assignments);
    return "(set)";
  } catch (const ControlValueError& e) {
    return e.what();
  }
}

TEST_F(V4l2Hil, ControlsAreReadAndSetWhileStreamingAllOrNoneAndSetAgainAtAReopen) {
  select_capture_input(vivid_.capture, kWebcamInput);
  auto settings = webcam_settings(V4l2PixelFormat::yuyv, 320, 180);
  settings.controls = {{"brightness", std::int64_t{77}, "test:1: camera.v4l2.controls.brightness"}};
  auto source = make_v4l2_source(settings);
  EXPECT_THROW((void)source->read_controls(), CaptureError) << "not open: nothing to read";
  source->open();
  FramePool pool({2, 320 * 180, 4});

  const auto find = [](const std::vector<CameraControlInfo>& controls,
                       const std::string& name) -> std::optional<CameraControlInfo> {
    for (const auto& c : controls) {
      if (c.name == name) return c;
    }
    return std::nullopt;
  };
  auto controls = source->read_controls();
  auto brightness = find(controls, "brightness");
  ASSERT_TRUE(brightness.has_value());
  EXPECT_EQ(brightness->kind, ControlKind::integer);
  EXPECT_EQ(describe_range(*brightness), "0 to 255");
  ASSERT_TRUE(brightness->value.has_value());
  EXPECT_EQ(std::get<std::int64_t>(*brightness->value), 77) << "the config's value";
  const auto osd = find(controls, "osd_text_mode");
  ASSERT_TRUE(osd.has_value());
  EXPECT_EQ(describe_range(*osd), "0: All, 1: Counters Only, 2: None");

  const std::uint32_t brightness_id = brightness->id;
  const std::uint32_t contrast_id = [&] {
    Node n(vivid_.capture);
    return control_id(n.fd(), "contrast");
  }();
  const double dim = settled_mean(*source, pool);
  const auto changes = set_camera_controls(*source, std::vector<ControlAssignment>{{"brightness", std::int64_t{200}}});
  ASSERT_EQ(changes.size(), 1U);
  EXPECT_EQ(std::get<std::int64_t>(*changes[0].old_value), 77);
  EXPECT_EQ(get_control(vivid_.capture, brightness_id), 200) << "the driver has it";
  const double bright = settled_mean(*source, pool);
  EXPECT_GT(bright, dim + 20) << "vivid draws its test pattern brighter";
  EXPECT_EQ(std::get<std::int64_t>(*find(source->read_controls(), "brightness")->value), 200);

  // Refused, naming the control and its range, and nothing changes.
  const std::int32_t contrast = get_control(vivid_.capture, contrast_id);
  EXPECT_EQ(
      set_refusal(*source, {{"contrast", std::int64_t{(contrast + 10) % 256}}, {"brightness", std::int64_t{300}}}),
      "brightness: 300 is out of its range 0 to 255; nothing was changed");
  EXPECT_EQ(set_refusal(*source, {{"osd_text_mode", std::string("Some")}}),
            "osd_text_mode: 'Some' is not one of its items (0: All, 1: Counters Only, 2: None); nothing was changed");
  EXPECT_EQ(get_control(vivid_.capture, brightness_id), 200);
  EXPECT_EQ(get_control(vivid_.capture, contrast_id), contrast);
  for (const auto& c : controls) {
    if (c.type != "button") continue;
    EXPECT_EQ(set_refusal(*source, {{c.name, std::int64_t{1}}}),
              c.name + ": a button (an action, not a setting); nothing was changed");
    break;
  }

  // vivid's gain is held by its automatic gain (V4L2_CID_AUTOGAIN, "Gain,
  // Automatic"): refused while that is on, taken with it turned off in the
  // same set.
  std::string names;
  for (const auto& c : controls) names += " " + c.name;
  ASSERT_TRUE(find(controls, "gain_automatic") && find(controls, "gain")) << "vivid's controls:" << names;
  (void)set_camera_controls(*source, std::vector<ControlAssignment>{{"gain_automatic", true}});
  EXPECT_TRUE(has_flag(*find(source->read_controls(), "gain"), "inactive"));
  const std::string inactive = set_refusal(*source, {{"gain", std::int64_t{50}}});
  EXPECT_EQ(inactive.rfind("gain: inactive now (an automatic mode holds it: ", 0), 0U) << inactive;
  EXPECT_NE(inactive.find("gain_automatic = true"), std::string::npos) << inactive;
  (void)set_camera_controls(*source,
                            std::vector<ControlAssignment>{{"gain", std::int64_t{50}}, {"gain_automatic", false}});
  EXPECT_EQ(std::get<std::int64_t>(*find(source->read_controls(), "gain")->value), 50);

  // A reopen sets the config's controls, then those set at run time.
  source->close();
  {
    Node n(vivid_.capture);
    v4l2_control reset{brightness_id, 10};
    must(n.fd(), VIDIOC_S_CTRL, &reset, "VIDIOC_S_CTRL");
  }
  source->open();
  EXPECT_EQ(get_control(vivid_.capture, brightness_id), 200);
  source->close();
  EXPECT_THROW((void)set_camera_controls(*source, std::vector<ControlAssignment>{{"brightness", std::int64_t{100}}}),
               CaptureError)
      << "closed: nothing to set";
}

TEST_F(V4l2Hil, AFormatOrSizeTheDeviceCannotDoIsRefusedWithWhatItOffers) {
  select_capture_input(vivid_.capture, kWebcamInput);
  auto source = make_v4l2_source(webcam_settings(V4l2PixelFormat::yuyv, 1000, 500));
  auto e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  std::string text = e.what();
  EXPECT_NE(text.find("VIDIOC_S_FMT: asked for YUYV 1000x500, the device gives YUYV "), std::string::npos) << text;
  EXPECT_NE(text.find("640x480"), std::string::npos) << "names the sizes it offers: " << text;

  source = make_v4l2_source(webcam_settings(V4l2PixelFormat::mjpg, 640, 480));
  e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  text = e.what();
  EXPECT_NE(text.find("asked for MJPG 640x480, the device gives "), std::string::npos) << text;

  auto settings = webcam_settings(V4l2PixelFormat::yuyv, 640, 480);
  settings.input = 5;
  source = make_v4l2_source(settings);
  e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  text = e.what();
  EXPECT_NE(text.find("VIDIOC_S_INPUT 5: no such input (it has 0 \""), std::string::npos) << text;

  auto output = webcam_settings(V4l2PixelFormat::yuyv, 640, 480);
  output.device = vivid_.output;
  output.input.reset();
  source = make_v4l2_source(output);
  e = capture_error([&] { source->open(); });
  EXPECT_EQ(e.kind(), CaptureError::Kind::config);
  EXPECT_NE(std::string(e.what()).find("is not a video capture device"), std::string::npos) << e.what();
}

TEST_F(V4l2Hil, AStallReturnsFalseAndABrokenFrameIsPublishedCorrupt) {
  select_capture_input(vivid_.capture, kWebcamInput);
  auto settings = webcam_settings(V4l2PixelFormat::grey, 320, 180);
  settings.controls = {{"percentage_of_dropped_buffers", std::int64_t{100}, "test"}};
  auto source = make_v4l2_source(settings);
  FramePool pool({.slots = 4, .pixel_bytes = 0});
  source->open();
  // vivid drops every buffer: nothing comes.
  const auto start = Clock::now();
  EXPECT_FALSE(source->wait_frame(500ms));
  EXPECT_GE(Clock::now() - start, 500ms);
  source->close();

  settings.controls = {{"percentage_of_dropped_buffers", std::int64_t{0}, "test"}};
  source = make_v4l2_source(settings);
  source->open();
  pool.release(next_frame(*source, pool));
  {
    // vivid's error injection: the next buffer comes with V4L2_BUF_FLAG_ERROR.
    Node n(vivid_.capture);
    v4l2_control press{control_id(n.fd(), "inject_v4l2_buf_flag_error"), 1};
    must(n.fd(), VIDIOC_S_CTRL, &press, "press inject_v4l2_buf_flag_error");
  }
  bool corrupt_seen = false;
  for (int i = 0; i < 10 && !corrupt_seen; ++i) {
    Frame& frame = next_frame(*source, pool);
    if (frame.status == FrameStatus::corrupt_frame) {
      corrupt_seen = true;
      EXPECT_EQ(frame.cause(), "the driver marked the frame broken (V4L2_BUF_FLAG_ERROR)");
      EXPECT_TRUE(frame.image.empty());
      EXPECT_FALSE(frame.has_release()) << "a broken frame's buffer goes back at once";
    }
    pool.release(frame);
  }
  EXPECT_TRUE(corrupt_seen);
  // The stream goes on.
  Frame& after = next_frame(*source, pool);
  EXPECT_EQ(after.status, FrameStatus::ok);
  pool.release(after);
  source->close();
}

// Last: it unloads and reloads vivid.
TEST_F(V4l2Hil, ADeviceRemovedWhileStreamingVanishesAndComesBack) {
  select_capture_input(vivid_.capture, kWebcamInput);
  const auto source = make_v4l2_source(webcam_settings(V4l2PixelFormat::yuyv, 320, 180));
  FramePool pool({.slots = 4, .pixel_bytes = source->geometry().slot_pixel_bytes});
  source->open();
  for (int i = 0; i < 3; ++i) pool.release(next_frame(*source, pool));

  // The driver lets go of the device under the open file, as a USB camera's
  // does when it is unplugged. (Unloading the module itself must wait: the
  // open file holds it.)
  {
    std::ofstream unbind("/sys/bus/platform/drivers/vivid/unbind");
    unbind << vivid_.platform << std::flush;
    ASSERT_TRUE(unbind) << "cannot unbind " << vivid_.platform;
  }
  const auto lost = capture_error([&] {
    for (int i = 0; i < 20; ++i) {
      if (source->wait_frame(1000ms)) pool.release(next_frame(*source, pool));
    }
  });
  EXPECT_EQ(lost.kind(), CaptureError::Kind::vanished) << lost.what();
  EXPECT_NE(std::string(lost.what()).find("v4l2 " + vivid_.capture + ": "), std::string::npos) << lost.what();
  std::cout << "removed while streaming: " << lost.what() << '\n';
  source->close();

  // Closed, the source holds nothing of vivid: the module unloads.
  ASSERT_EQ(::syscall(SYS_delete_module, "vivid", O_NONBLOCK), 0) << errno_text("delete_module vivid");
  const auto gone = capture_error([&] { source->open(); });
  EXPECT_EQ(gone.kind(), CaptureError::Kind::not_found) << gone.what();
  std::cout << "reopened while unloaded: " << gone.what() << '\n';
  EXPECT_FALSE(source->is_open());

  // Loaded again, the same source opens it again.
  {
    const int module = ::open(vivid_.module.c_str(), O_RDONLY | O_CLOEXEC);
    ASSERT_GE(module, 0) << errno_text("open " + vivid_.module);
    const long loaded = ::syscall(SYS_finit_module, module, vivid_.params.c_str(), 0);
    const int load_errno = errno;
    ::close(module);
    ASSERT_EQ(loaded, 0) << "finit_module vivid: " << std::strerror(load_errno);
  }
  for (int i = 0; i < 50 && !fs::exists(vivid_.capture); ++i) std::this_thread::sleep_for(100ms);
  source->open();
  for (int i = 0; i < 3; ++i) {
    Frame& frame = next_frame(*source, pool);
    EXPECT_EQ(frame.status, FrameStatus::ok);
    pool.release(frame);
  }
  source->close();
}

}  // namespace
}  // namespace markerd::daemon
