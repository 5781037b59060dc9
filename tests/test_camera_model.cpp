// CameraModel (detector/src/camera_model.cpp): the calibration file, its
// errors, and the distortion model against OpenCV's own functions.

#include <gtest/gtest.h>

#include <sys/stat.h>
#include <unistd.h>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "markerd/detector/camera_model.hpp"
#include "support/temp_dir.hpp"

namespace markerd::detector {
namespace {

namespace fs = std::filesystem;

const fs::path kThesisFile = fs::path(MARKERD_SOURCE_DIR) / "config/cameras/thesis-640x480.yaml";

using test_support::TempDir;

const std::string kHeader = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n";
const std::string kGoodMatrix =
    "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
    "   data: [ 516., 0., 319., 0., 515., 238., 0., 0., 1. ]\n";
const std::string kGoodDistortion =
    "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
    "   data: [ 0.3495, -2.2549, 0., 0., 4.9959 ]\n";

// Expects load() to throw CameraModelError naming the file and `key`.
void expect_load_error(const fs::path& file, const std::string& key) {
  try {
    (void)CameraModel::load(file);
    ADD_FAILURE() << "no error for " << file;
  } catch (const CameraModelError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(file.filename().string()), std::string::npos) << msg;
    EXPECT_NE(msg.find(key), std::string::npos) << msg;
  }
}

// Moderate lenses with every term of OpenCV's model in use.
CameraModel with_coefficients(int n) {
  CameraModel c = CameraModel::thesis_640x480();
  const std::array<double, 12> all = {-0.28,  0.11,  0.0012, -0.0007, -0.021, 0.05,
                                      -0.012, 0.003, 0.0015, -0.0004, 0.0009, 0.0002};
  c.dist = {};
  for (int i = 0; i < n; ++i) c.dist[static_cast<std::size_t>(i)] = all[static_cast<std::size_t>(i)];
  return c;
}

cv::Matx33d camera_matrix(const CameraModel& c) { return {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1}; }

std::vector<double> coefficients(const CameraModel& c, int n) { return {c.dist.begin(), c.dist.begin() + n}; }

TEST(CameraModel, LoadsTheThesisCamera) {
  const CameraModel c = CameraModel::load(kThesisFile);
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
  EXPECT_EQ(c.fx, 516);
  EXPECT_EQ(c.fy, 515);
  EXPECT_EQ(c.cx, 319);
  EXPECT_EQ(c.cy, 238);
  const std::array<double, 12> expect = {0.3495, -2.2549, 0, 0, 4.9959, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_EQ(c.dist, expect);
  EXPECT_TRUE(c.has_distortion());
  // The built-in thesis camera, used where no file is given, is this file.
  const CameraModel builtin = CameraModel::thesis_640x480();
  EXPECT_EQ(builtin.width, c.width);
  EXPECT_EQ(builtin.height, c.height);
  EXPECT_EQ(builtin.fx, c.fx);
  EXPECT_EQ(builtin.fy, c.fy);
  EXPECT_EQ(builtin.cx, c.cx);
  EXPECT_EQ(builtin.cy, c.cy);
  EXPECT_EQ(builtin.dist, c.dist);
}

TEST(CameraModel, MissingFile) {
  expect_load_error(fs::path(MARKERD_SOURCE_DIR) / "config/cameras/no-such-camera.yaml", "no-such-camera.yaml");
}

TEST(CameraModel, FileWithoutCameraMatrix) {
  const TempDir dir;
  expect_load_error(dir.write("no-matrix.yaml", kHeader + kGoodDistortion), "camera_matrix");
}

TEST(CameraModel, CameraMatrixTwoByThree) {
  const TempDir dir;
  const std::string m =
      "camera_matrix: !!opencv-matrix\n   rows: 2\n   cols: 3\n   dt: d\n"
      "   data: [ 516., 0., 319., 0., 515., 238. ]\n";
  expect_load_error(dir.write("two-by-three.yaml", kHeader + m + kGoodDistortion), "camera_matrix");
}

TEST(CameraModel, SevenDistortionCoefficients) {
  const TempDir dir;
  const std::string d =
      "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 7\n   dt: d\n"
      "   data: [ 0.1, -0.2, 0., 0., 0.3, 0.01, 0.02 ]\n";
  expect_load_error(dir.write("seven.yaml", kHeader + kGoodMatrix + d), "distortion_coefficients");
}

TEST(CameraModel, ValidFileInTheSameDirectoryLoads) {
  // The error tests above are only meaningful if their base file is good.
  const TempDir dir;
  const CameraModel c = CameraModel::load(dir.write("good.yaml", kHeader + kGoodMatrix + kGoodDistortion));
  EXPECT_EQ(c.fx, 516);
  EXPECT_EQ(c.dist[4], 4.9959);
}

// A directory, a FIFO, a device or a file far too large where the camera
// file belongs: refused at once by name, not handed to OpenCV's parser.
TEST(CameraModel, WhatIsNoFileIsRefusedByName) {
  const TempDir dir;
  fs::create_directories(dir.path() / "camera.yaml");
  expect_load_error(dir.path() / "camera.yaml", "the camera file is a directory, not a file");
  ASSERT_EQ(::mkfifo((dir.path() / "pipe.yaml").c_str(), 0600), 0);
  expect_load_error(dir.path() / "pipe.yaml", "the camera file is a FIFO, not a file");  // no writer: no wait
  expect_load_error("/dev/zero", "the camera file is a character device, not a file");
  expect_load_error(dir.write("huge.yaml", kHeader + std::string(std::size_t{2} << 20, '#')), "larger than the 1 MiB");
}

// What the YAML parser finds wrong is said with the file and the line.
TEST(CameraModel, ParseErrorsNameTheFileAndTheLine) {
  const TempDir dir;
  expect_load_error(dir.write("unclosed.yaml", kHeader + "camera_matrix: [ 1, 2\n" + kGoodDistortion),
                    "the camera file cannot be parsed: line ");
  expect_load_error(dir.write("empty.yaml", "\n"), "the camera file is empty");
  expect_load_error(dir.write("header-only.yaml", "%YAML:1.0\n"), "the camera file is empty");
  expect_load_error(dir.write("notes.yaml", "these are notes, not a calibration\n"), "not a map of keys");
  expect_load_error(dir.write("tabs.yaml", kHeader + "camera_matrix:\n\trows: 3\n"),
                    "the camera file cannot be parsed: line 6: ");
}

// Files on which OpenCV 4.6's YAML parser never returned (found by
// fuzz_camera_model, docs/fuzzing.md): each is a wrong camera file, said
// at once. A hang here is the test's timeout.
TEST(CameraModel, FilesThatHungOpenCvsParserAreRefused) {
  const TempDir dir;
  for (const std::string text : {"%YAML:1.0\n---L:1.0\n-----\nx\n", "%YAML:1.0\n ---r: 1\n  \n :  -\nd\n",
                                 "%YAML:1.0\n r: x\n:  -\nd\n", "%YAML:1.0\n a: 1\n--'-\ni\n"}) {
    EXPECT_THROW((void)CameraModel::load(dir.write("hung-opencv.yaml", text)), CameraModelError) << text;
  }
  // A document start with spaces or a comment after it is one.
  const std::string spaced = "%YAML:1.0\n---   # the camera\nimage_width: 640\nimage_height: 480\n";
  EXPECT_EQ(CameraModel::load(dir.write("spaced.yaml", spaced + kGoodMatrix + kGoodDistortion)).width, 640);
}

// XML is refused by name (OpenCV 4.6's XML parser crashed on some corrupt
// files, and one format is enough). JSON is YAML, and reads as such.
TEST(CameraModel, XmlIsRefusedByNameAndJsonIsRead) {
  const TempDir dir;
  const std::string xml =
      "<?xml version=\"1.0\"?>\n<opencv_storage>\n<image_width>640</image_width>\n"
      "<image_height>480</image_height>\n</opencv_storage>\n";
  expect_load_error(dir.write("good.xml", xml), "XML camera files are not read");
  expect_load_error(
      dir.write("corrupt.xml", "<?xml version=" + std::string(200, '\0') + "\"1.0\"?>\n<opencv_storage>\n<a"),
      "XML camera files are not read");
  const std::string json =
      R"({ "image_width": 640, "image_height": 480,
           "camera_matrix": { "type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
                              "data": [ 516.0, 0, 319, 0, 515, 238, 0, 0, 1 ] },
           "distortion_coefficients": { "rows": 1, "cols": 5, "data": [ 0.3495, -2.2549, 0, 0, 4.9959 ] } })";
  const CameraModel from_json = CameraModel::load(dir.write("camera.json", json));
  EXPECT_EQ(from_json.fx, 516);
  EXPECT_EQ(from_json.dist[4], 4.9959);
  expect_load_error(dir.write("half.json", "{ \"image_width\": 640 }\n"), "missing key 'image_height'");
  // A byte order mark before %YAML is still YAML.
  const CameraModel c =
      CameraModel::load(dir.write("bom.yaml", "\xEF\xBB\xBF" + kHeader + kGoodMatrix + kGoodDistortion));
  EXPECT_EQ(c.width, 640);
}

// ROS's camera_info YAML, as its camera_calibration package writes it: the
// same keys without OpenCV's tags, and the lens model named.
const std::string kRosCameraInfo =
    "image_width: 640\nimage_height: 480\ncamera_name: rail_camera\n"
    "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [516.0, 0.0, 319.0, 0.0, 515.0, 238.0, 0.0, 0.0, 1.0]\n"
    "distortion_model: plumb_bob\n"
    "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0.3495, -2.2549, 0.0, 0.0, 4.9959]\n"
    "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n"
    "projection_matrix:\n  rows: 3\n  cols: 4\n"
    "  data: [516.0, 0.0, 319.0, 0.0, 0.0, 515.0, 238.0, 0.0, 0.0, 0.0, 1.0, 0.0]\n";

TEST(CameraModel, ReadsRosCameraInfo) {
  const TempDir dir;
  const CameraModel ros = CameraModel::load(dir.write("ost.yaml", kRosCameraInfo));
  const CameraModel opencv = CameraModel::load(kThesisFile);
  EXPECT_EQ(ros.width, opencv.width);
  EXPECT_EQ(ros.fx, opencv.fx);
  EXPECT_EQ(ros.cy, opencv.cy);
  EXPECT_EQ(ros.dist, opencv.dist);

  const auto with_model = [&](const std::string& model, const std::string& distortion) {
    std::string text = kRosCameraInfo;
    text.replace(text.find("plumb_bob"), 9, model);
    const std::string old_data = "  cols: 5\n  data: [0.3495, -2.2549, 0.0, 0.0, 4.9959]";
    text.replace(text.find(old_data), old_data.size(), distortion);
    return text;
  };
  const CameraModel rational = CameraModel::load(
      dir.write("rational.yaml",
                with_model("rational_polynomial", "  cols: 8\n  data: [0.1, -0.2, 0, 0, 0.3, 0.01, 0.02, 0.03]")));
  EXPECT_EQ(rational.dist[7], 0.03);
  // The fisheye model's four coefficients are not k1 k2 p1 p2.
  expect_load_error(dir.write("fisheye.yaml", with_model("equidistant", "  cols: 4\n  data: [0.1, 0.01, 0.001, 0]")),
                    "line 8: distortion_model 'equidistant' is not supported");
  expect_load_error(dir.write("short.yaml", with_model("plumb_bob", "  cols: 4\n  data: [0.1, 0.01, 0.001, 0]")),
                    "distortion_model 'plumb_bob' has 5 coefficients, the file gives 4");
}

// YAML leaves a repeated key to the reader: a camera file that says a
// value twice is refused, not read one way or the other.
TEST(CameraModel, AKeyGivenTwiceIsRefused) {
  const TempDir dir;
  expect_load_error(dir.write("twice.yaml", kHeader + "image_width: 1280\n" + kGoodMatrix + kGoodDistortion),
                    "line 5: key 'image_width' given twice");
  const std::string matrix =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   rows: 3\n   dt: d\n"
      "   data: [ 516., 0., 319., 0., 515., 238., 0., 0., 1. ]\n";
  expect_load_error(dir.write("rows-twice.yaml", kHeader + matrix + kGoodDistortion),
                    "line 8: key 'rows' in 'camera_matrix' given twice");
}

TEST(CameraModel, ImageSizeOutOfRangeIsRefused) {
  const TempDir dir;
  for (const std::string width : {"1e309", ".Nan", "-.Inf", "1e34", "0", "-640", "65536", "640.5"}) {
    const std::string text =
        "%YAML:1.0\n---\nimage_width: " + width + "\nimage_height: 480\n" + kGoodMatrix + kGoodDistortion;
    expect_load_error(dir.write("width.yaml", text),
                      "key 'image_width' must be a whole number of pixels from 1 to 65535");
  }
  const std::string text = "%YAML:1.0\n---\nimage_width: 65535\nimage_height: 480\n" + kGoodMatrix + kGoodDistortion;
  EXPECT_EQ(CameraModel::load(dir.write("widest.yaml", text)).width, 65535);
}

std::string with_camera_matrix(const std::string& data) {
  return kHeader + "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ " + data + " ]\n" +
         kGoodDistortion;
}

TEST(CameraModel, CameraMatrixOutOfRangeIsRefused) {
  const TempDir dir;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"516., 0., 319., 0., .Inf, 238., 0., 0., 1.", "not finite"},
      {"516., 0., .Inf, 0., 515., 238., 0., 0., 1.", "not finite"},
      {".Nan, 0., 319., 0., 515., 238., 0., 0., 1.", "not finite"},
      {"516., 0., 319., 0., 515., 238., 0., 0., -.Inf", "not finite"},
      {"1e300, 0., 319., 0., 515., 238., 0., 0., 1.", "fx must be positive and at most 640000 pixels"},
      {"516., 0., 319., 0., 0., 238., 0., 0., 1.", "fy must be positive and at most 480000 pixels"},
      {"516., 0., 1e12, 0., 515., 238., 0., 0., 1.", "cx must be from -6400 to 7040 pixels"},
      {"516., 0., 319., 0., 515., -1e6, 0., 0., 1.", "cy must be from -4800 to 5280 pixels"},
      {"516., 0., 319., 0., 515., 238., 0., 0., 2.", "must be fx, 0, cx / 0, fy, cy / 0, 0, 1"},
  };
  for (const auto& [data, words] : cases) expect_load_error(dir.write("matrix.yaml", with_camera_matrix(data)), words);
  const std::string d =
      "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ 0.1, .Nan, 0., 0., 0. "
      "]\n";
  expect_load_error(dir.write("nan-k2.yaml", kHeader + kGoodMatrix + d),
                    "'distortion_coefficients' holds a value that is not finite");
}

TEST(CameraModel, TopLevelListIsACameraModelError) {
  const TempDir dir;
  expect_load_error(dir.write("list.yaml", "%YAML:1.0\n- 1\n- 2\n"), "not a map of keys");
}

// A line "   : d" in a matrix (a key with no name: it hung or broke OpenCV's
// reader, docs/fuzzing.md) is refused naming its line.
TEST(CameraModel, AKeyWithoutANameIsRefusedWithItsLine) {
  const TempDir dir;
  const std::string matrix =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   : d\n   cols: 3\n   dt: d\n"
      "   data: [ 516., 0., 319., 0., 515., 238., 0., 0., 1. ]\n";
  expect_load_error(dir.write("empty-key.yaml", kHeader + matrix + kGoodDistortion),
                    "line 7: a key in 'camera_matrix' that is not a name");
}

// The size a matrix declares is checked before its data is read, and its
// data must be one channel of numbers.
TEST(CameraModel, DeclaredMatrixSizeIsCheckedBeforeReading) {
  const TempDir dir;
  const std::string huge =
      "camera_matrix: !!opencv-matrix\n   rows: 100000000\n   cols: 3\n   dt: d\n   data: [ 1., 2., 3. ]\n";
  expect_load_error(dir.write("huge.yaml", kHeader + huge + kGoodDistortion), "must be 3x3, got 100000000x3");
  const std::string long_distortion =
      "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 2000000000\n   dt: d\n   data: [ 0. ]\n";
  expect_load_error(dir.write("long.yaml", kHeader + kGoodMatrix + long_distortion), "got 1x2000000000");
  const std::string short_data =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 516., 0., 319. ]\n";
  expect_load_error(dir.write("short.yaml", kHeader + short_data + kGoodDistortion), "declares 3x3 but holds 3 values");
  // Three channels per element: 27 values where a 3x3 matrix has 9.
  std::string data = "1";
  for (int i = 2; i <= 27; ++i) data += ", " + std::to_string(i);
  const std::string three_channels =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: \"3d\"\n   data: [ " + data + " ]\n";
  expect_load_error(dir.write("channels.yaml", kHeader + three_channels + kGoodDistortion),
                    "declares 3x3 but holds 27 values");
  const std::string nine_in_three_channels =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: \"3d\"\n"
      "   data: [ 516., 0., 319., 0., 515., 238., 0., 0., 1. ]\n";
  expect_load_error(dir.write("dt.yaml", kHeader + nine_in_three_channels + kGoodDistortion),
                    "line 8: key 'camera_matrix' has dt '3d'");
  // A column of coefficients, as some tools write it, is read.
  const std::string column =
      "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ 0.1, 0.2, 0., 0., 0.3 "
      "]\n";
  EXPECT_EQ(CameraModel::load(dir.write("column.yaml", kHeader + kGoodMatrix + column)).dist[4], 0.3);
}

// markerctl and markerd print their own error (the CameraModelError) and
// nothing of a library's.
TEST(CameraModel, WrongFilesPrintNothingButTheError) {
  const TempDir dir;
  const std::vector<std::string> wrong = {
      kHeader + "camera_matrix: [ 1, 2\n",
      "%YAML:1.0\n\t image_width: 640\n",
      "%YAML:1.0\n- 1\n",
      kHeader +
          "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: q\n   data: [ 1, 2, 3, 4, 5, 6, 7, 8, 9 ]\n",
      kHeader +
          "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ a, b, c, d, e, f, g, h, i ]\n",
      kHeader + "camera_matrix: !!binary |\n  AAAA\n",
  };
  for (const std::string& text : wrong) {
    const fs::path file = dir.write("wrong.yaml", text);
    testing::internal::CaptureStderr();
    EXPECT_THROW((void)CameraModel::load(file), CameraModelError) << text;
    EXPECT_EQ(testing::internal::GetCapturedStderr(), "") << text;
  }
}

TEST(CameraModel, SaveLoadRoundTrip) {
  const TempDir dir;
  for (int n : {5, 8, 12}) {
    CameraModel c = with_coefficients(n);
    c.fx = 1234.567890123456789;
    c.cy = 987.6543210987654;
    const fs::path p = dir.path() / ("round-trip-" + std::to_string(n) + ".yaml");
    c.save(p);
    const CameraModel back = CameraModel::load(p);
    EXPECT_EQ(back.width, c.width);
    EXPECT_EQ(back.height, c.height);
    EXPECT_EQ(back.fx, c.fx);
    EXPECT_EQ(back.fy, c.fy);
    EXPECT_EQ(back.cx, c.cx);
    EXPECT_EQ(back.cy, c.cy);
    EXPECT_EQ(back.dist, c.dist) << n << " coefficients";
    // What OpenCV's own reader sees in the file.
    cv::FileStorage f(p.string(), cv::FileStorage::READ);
    cv::Mat d;
    f["distortion_coefficients"] >> d;
    EXPECT_EQ(static_cast<int>(d.total()), n);
  }
}

// ROS's camera_info as save() writes it: the keys and layout of ROS's
// camera_calibration_parsers, numbers that YAML 1.1 readers (PyYAML) take
// for floats, and the same doubles back through load() as OpenCV's file.
TEST(CameraModel, SavesRosCameraInfo) {
  const TempDir dir;
  for (int n : {5, 8}) {
    CameraModel c = with_coefficients(n);
    c.fx = 1234.567890123456789;
    c.cy = 987.6543210987654;
    c.dist[1] = 1e-5;  // shortest as 1e-05: written 1.0e-05
    const fs::path ros = dir.path() / ("ros-" + std::to_string(n) + ".yaml");
    const fs::path opencv = dir.path() / ("opencv-" + std::to_string(n) + ".yaml");
    c.save(ros, CameraFileFormat::ros, "rail_camera");
    c.save(opencv);
    const CameraModel from_ros = CameraModel::load(ros);
    const CameraModel from_opencv = CameraModel::load(opencv);
    for (const CameraModel* back : {&from_ros, &from_opencv}) {
      EXPECT_EQ(back->width, c.width);
      EXPECT_EQ(back->height, c.height);
      EXPECT_EQ(back->fx, c.fx);
      EXPECT_EQ(back->fy, c.fy);
      EXPECT_EQ(back->cx, c.cx);
      EXPECT_EQ(back->cy, c.cy);
      EXPECT_EQ(back->dist, c.dist) << n << " coefficients";
    }
    const std::string text = test_support::read_file(ros);
    EXPECT_EQ(
        text.rfind("image_width: 640\nimage_height: 480\ncamera_name: rail_camera\ncamera_matrix:\n  rows: 3\n", 0), 0U)
        << text;
    EXPECT_NE(text.find(n == 5 ? "distortion_model: plumb_bob\n" : "distortion_model: rational_polynomial\n"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("1.0e-05"), std::string::npos) << text;
    EXPECT_NE(text.find("rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, "
                        "0.0, 1.0]\n"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("projection_matrix:\n  rows: 3\n  cols: 4\n  data: [1234.567890123457, 0.0, 319.0, 0.0, 0.0, "
                        "515.0, 987.6543210987654, 0.0, 0.0, 0.0, 1.0, 0.0]\n"),
              std::string::npos)
        << text;
    // No number without a decimal point, none with an unsigned exponent.
    EXPECT_EQ(text.find(", 0,"), std::string::npos) << text;
    EXPECT_EQ(text.find("e0"), std::string::npos) << text;
  }
  // Thin-prism terms have no place in camera_info; a camera name must stay
  // a plain YAML word.
  EXPECT_THROW(with_coefficients(12).save(dir.path() / "prism.yaml", CameraFileFormat::ros), CameraModelError);
  for (const char* name : {"", "two words", "a: b", "#x", "-x", "q\"uote"}) {
    EXPECT_FALSE(CameraModel::is_ros_camera_name(name)) << name;
    EXPECT_THROW(CameraModel::thesis_640x480().save(dir.path() / "named.yaml", CameraFileFormat::ros, name),
                 CameraModelError)
        << name;
  }
  for (const char* name : {"camera", "head_camera", "rig/rail-cam.1", "_x"}) {
    EXPECT_TRUE(CameraModel::is_ros_camera_name(name)) << name;
  }
  EXPECT_THROW(CameraModel::thesis_640x480().save(dir.path() / "no-such-dir" / "x.yaml", CameraFileFormat::ros),
               CameraModelError);
}

TEST(CameraModel, DistortionAgreesWithProjectPoints) {
  for (int n : {5, 8, 12}) {
    const CameraModel c = n == 5 ? CameraModel::thesis_640x480() : with_coefficients(n);
    std::vector<cv::Point3d> pts;
    for (double x = -0.7; x <= 0.7001; x += 0.05) {
      for (double y = -0.55; y <= 0.5501; y += 0.05) pts.emplace_back(x, y, 1.0);
    }
    std::vector<cv::Point2d> img;
    cv::projectPoints(pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), camera_matrix(c), coefficients(c, n), img);
    double worst = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      const Point2 px = c.normalized_to_pixel({pts[i].x, pts[i].y});
      const Point2 d = c.distort({pts[i].x, pts[i].y});
      worst = std::max({worst, std::abs(px.x - img[i].x), std::abs(px.y - img[i].y)});
      EXPECT_NEAR(c.fx * d.x + c.cx, img[i].x, 1e-9);
      EXPECT_NEAR(c.fy * d.y + c.cy, img[i].y, 1e-9);
    }
    EXPECT_LT(worst, 1e-9) << n << " coefficients";
  }
}

TEST(CameraModel, UndistortAgreesWithOpenCvAndRoundTrips) {
  // OpenCV's undistortPoints is a fixed-point iteration. For the thesis lens
  // it converges over most of the image, but not near the image corners
  // (distorted radius above about 0.75): there, even 100000 iterations leave
  // it 69 px off when its answer is projected back. Where it converges (its
  // own round trip closes) we must agree with it; everywhere we must close.
  const CameraModel c = CameraModel::thesis_640x480();
  std::vector<cv::Point2d> px;
  for (int y = 0; y < c.height; y += 4) {
    for (int x = 0; x < c.width; x += 4) px.emplace_back(x, y);
  }
  px.emplace_back(639, 479);
  std::vector<cv::Point2d> cv_norm;
  cv::undistortPoints(px, cv_norm, camera_matrix(c), coefficients(c, 5), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 1000, 1e-15));
  double worst_cv = 0, worst_trip = 0, smallest_unconverged_radius = 1e9;
  int opencv_converged = 0;
  for (std::size_t i = 0; i < px.size(); ++i) {
    const Point2 p{px[i].x, px[i].y};
    const Point2 n = c.pixel_to_normalized(p);
    worst_trip = std::max(worst_trip, distance(c.normalized_to_pixel(n), p));
    const bool converged = distance(c.normalized_to_pixel({cv_norm[i].x, cv_norm[i].y}), p) < 1e-9;
    if (converged) {
      ++opencv_converged;
      worst_cv = std::max({worst_cv, std::abs(n.x - cv_norm[i].x), std::abs(n.y - cv_norm[i].y)});
    } else {
      smallest_unconverged_radius =
          std::min(smallest_unconverged_radius, std::hypot((p.x - c.cx) / c.fx, (p.y - c.cy) / c.fy));
    }
  }
  std::cout << "[ undistort] thesis camera: OpenCV converged at " << opencv_converged << "/" << px.size()
            << " points (not beyond distorted radius " << smallest_unconverged_radius << "), worst difference there "
            << worst_cv << "; our worst round trip " << worst_trip << " px\n";
  EXPECT_LT(worst_cv, 1e-11);
  EXPECT_LT(worst_trip, 1e-9);
  EXPECT_GT(opencv_converged, static_cast<int>(px.size() * 99 / 100));
  EXPECT_GT(smallest_unconverged_radius, 0.7);

  // Every pixel of the image, not just a grid, round-trips.
  double worst_all = 0;
  for (int y = 0; y < c.height; ++y) {
    for (int x = 0; x < c.width; ++x) {
      const Point2 p{static_cast<double>(x), static_cast<double>(y)};
      worst_all = std::max(worst_all, distance(c.normalized_to_pixel(c.pixel_to_normalized(p)), p));
    }
  }
  EXPECT_LT(worst_all, 1e-9);
}

TEST(CameraModel, UndistortAgreesWithOpenCvForModerateLenses) {
  for (int n : {5, 8, 12}) {
    const CameraModel c = with_coefficients(n);
    std::vector<cv::Point2d> px;
    for (int y = 0; y < c.height; y += 16) {
      for (int x = 0; x < c.width; x += 16) px.emplace_back(x, y);
    }
    std::vector<cv::Point2d> cv_norm;
    cv::undistortPoints(px, cv_norm, camera_matrix(c), coefficients(c, n), cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 1000, 1e-15));
    double worst = 0;
    for (std::size_t i = 0; i < px.size(); ++i) {
      const Point2 ours = c.pixel_to_normalized({px[i].x, px[i].y});
      worst = std::max({worst, std::abs(ours.x - cv_norm[i].x), std::abs(ours.y - cv_norm[i].y)});
    }
    EXPECT_LT(worst, 1e-11) << n << " coefficients";
  }
}

TEST(CameraModel, UndistortRoundTripsForRichModels) {
  for (int n : {8, 12}) {
    const CameraModel c = with_coefficients(n);
    double worst = 0;
    for (int y = 0; y < c.height; y += 7) {
      for (int x = 0; x < c.width; x += 7) {
        const Point2 p{static_cast<double>(x), static_cast<double>(y)};
        worst = std::max(worst, distance(c.normalized_to_pixel(c.pixel_to_normalized(p)), p));
      }
    }
    EXPECT_LT(worst, 1e-9) << n << " coefficients";
  }
}

TEST(CameraModel, ScaledToKeepsPixelCentresConsistent) {
  const CameraModel small = CameraModel::thesis_640x480();
  const CameraModel big = small.scaled_to(1920, 1440);
  EXPECT_EQ(big.width, 1920);
  EXPECT_EQ(big.height, 1440);
  EXPECT_EQ(big.dist, small.dist);
  EXPECT_DOUBLE_EQ(big.fx, 3 * small.fx);
  EXPECT_DOUBLE_EQ(big.fy, 3 * small.fy);
  // Pixel (i, j) of the small image covers pixels 3i..3i+2 of the big one; its
  // centre is the big image's pixel (3i + 1, 3j + 1).
  EXPECT_DOUBLE_EQ(big.cx, 3 * small.cx + 1);
  EXPECT_DOUBLE_EQ(big.cy, 3 * small.cy + 1);
  for (double y = 0; y < 480; y += 37) {
    for (double x = 0; x < 640; x += 41) {
      const Point2 n_small = small.pixel_to_normalized({x, y});
      const Point2 n_big = big.pixel_to_normalized({3 * x + 1, 3 * y + 1});
      EXPECT_NEAR(n_small.x, n_big.x, 1e-12);
      EXPECT_NEAR(n_small.y, n_big.y, 1e-12);
      const Point2 p_big = big.normalized_to_pixel(n_small);
      EXPECT_NEAR(p_big.x, 3 * x + 1, 1e-8);
      EXPECT_NEAR(p_big.y, 3 * y + 1, 1e-8);
    }
  }
  // The image's outer edges (pixel -0.5 and width - 0.5) map onto each other.
  const Point2 corner = small.pixel_to_normalized({639.5, 479.5});
  const Point2 corner_big = big.pixel_to_normalized({1919.5, 1439.5});
  EXPECT_NEAR(corner.x, corner_big.x, 1e-12);
  EXPECT_NEAR(corner.y, corner_big.y, 1e-12);
}

}  // namespace
}  // namespace markerd::detector
