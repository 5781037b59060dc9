// The detection log's record: every field parsed back from the line, nulls
// for what is missing or not finite, string escaping, and the schema table of
// docs/detection-log.md kept in step with the formatter.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <sstream>
#include <string>

#include "detection_log_samples.hpp"
#include "markerd/daemon/detection_record.hpp"
#include "support/files.hpp"

namespace markerd::daemon {
namespace {

using nlohmann::json;

// Half a unit of the last decimal the schema promises, plus rounding slack.
constexpr double kPixelTol = 0.5e-4 + 1e-12;
constexpr double kPoseTol = 0.5e-7 + 1e-12;
constexpr double kMmTol = 0.5e-4 + 1e-9;
constexpr double kDegTol = 0.5e-5 + 1e-9;

json parse_line(std::string_view line) {
  EXPECT_FALSE(line.empty());
  EXPECT_EQ(line.back(), '\n');
  EXPECT_EQ(line.find('\n'), line.size() - 1) << "one record, one line";
  return json::parse(line);
}

void expect_vector(const json& j, const Eigen::Vector3d& v, double tol) {
  ASSERT_TRUE(j.is_array());
  ASSERT_EQ(j.size(), 3U);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(j[i].get<double>(), v[i], tol) << i;
}

void expect_quaternion(const json& j, const Eigen::Quaterniond& q) {
  ASSERT_EQ(j.size(), 4U);
  EXPECT_NEAR(j[0].get<double>(), q.w(), kPoseTol);
  EXPECT_NEAR(j[1].get<double>(), q.x(), kPoseTol);
  EXPECT_NEAR(j[2].get<double>(), q.y(), kPoseTol);
  EXPECT_NEAR(j[3].get<double>(), q.z(), kPoseTol);
}

void expect_quad(const json& j, const detector::Quad& quad) {
  ASSERT_EQ(j.size(), 4U);
  for (std::size_t i = 0; i < 4; ++i) {
    ASSERT_EQ(j[i].size(), 2U);
    EXPECT_NEAR(j[i][0].get<double>(), quad[i].x, kPixelTol) << i;
    EXPECT_NEAR(j[i][1].get<double>(), quad[i].y, kPixelTol) << i;
  }
}

void expect_axis(const json& j, const rig::AxisSnapshot& a, const std::string& unit, double tol) {
  EXPECT_NEAR(j.at("position_" + unit).get<double>(), a.position, tol);
  EXPECT_NEAR(j.at("target_" + unit).get<double>(), a.target, tol);
  EXPECT_EQ(j.at("state"), rig::to_string(a.state));
  EXPECT_EQ(j.at("homed"), a.homed);
  EXPECT_EQ(j.at("settled"), a.settled);
  EXPECT_EQ(j.at("fault"), a.fault);
  EXPECT_EQ(j.at("moving"), a.moving);
}

void expect_pose(const json& j, const detector::MarkerPose& pose, const rig::MarkerGroundTruth& truth) {
  expect_vector(j.at("rvec"), pose.rvec(), kPoseTol);
  expect_quaternion(j.at("quaternion"), pose.quaternion());
  expect_vector(j.at("tvec"), pose.translation, kPoseTol);
  EXPECT_NEAR(j.at("reprojection_error_px").get<double>(), pose.reprojection_error_px, kPixelTol);
  const json& e = j.at("error");
  const double offset_m = (pose.translation - truth.translation).norm();
  EXPECT_NEAR(e.at("translation_mm").get<double>(), 1e3 * offset_m, kMmTol);
  EXPECT_NEAR(e.at("translation_pct").get<double>(), 100 * offset_m / truth.translation.norm(), 1e-5);
  EXPECT_NEAR(e.at("distance_mm").get<double>(), 1e3 * (pose.translation.norm() - truth.translation.norm()), kMmTol);
  const double angle = Eigen::AngleAxisd(truth.rotation.transpose() * pose.rotation).angle();
  EXPECT_NEAR(e.at("rotation_deg").get<double>(), angle * 180 / std::numbers::pi, kDegTol);
}

TEST(DetectionRecord, FullRecordRoundTripsEveryField) {
  const samples::FullRecord full;
  DetectionRecordFormatter formatter;
  const json j = parse_line(formatter.format(full.input));
  const FrameRecordInput& in = full.input;

  EXPECT_EQ(j.at("schema"), kDetectionLogSchema);
  EXPECT_EQ(j.at("status"), "ok");
  EXPECT_TRUE(j.at("cause").is_null());

  const json& frame = j.at("frame");
  EXPECT_EQ(frame.at("sequence").get<std::uint64_t>(), in.sequence);
  EXPECT_EQ(frame.at("capture_monotonic_ns").get<std::int64_t>(), 123'460'000'000);
  EXPECT_EQ(frame.at("capture_utc"), "2024-02-29T23:59:58.123456Z");
  EXPECT_EQ(frame.at("source"), in.source);
  EXPECT_EQ(frame.at("width"), 1920);
  EXPECT_EQ(frame.at("height"), 1080);
  EXPECT_DOUBLE_EQ(j.at("detection_time_ms").get<double>(), 3.456789);

  const json& rig = j.at("rig");
  EXPECT_EQ(rig.at("sequence"), 4711);
  EXPECT_EQ(rig.at("monotonic_ns").get<std::int64_t>(), 123'456'789'012);
  EXPECT_EQ(rig.at("settled"), in.rig->settled());
  EXPECT_FALSE(rig.at("settled").get<bool>()) << "the sample's turntable is still moving";
  expect_axis(rig.at("rail"), in.rig->rail, "mm", kMmTol);
  expect_axis(rig.at("turntable"), in.rig->turntable, "deg", kDegTol);

  const json& truth = j.at("truth");
  detector::MarkerPose truth_pose;
  truth_pose.rotation = full.truth.rotation;
  truth_pose.translation = full.truth.translation;
  expect_vector(truth.at("rvec"), truth_pose.rvec(), kPoseTol);
  expect_quaternion(truth.at("quaternion"), truth_pose.quaternion());
  expect_vector(truth.at("tvec"), full.truth.translation, kPoseTol);
  EXPECT_NEAR(truth.at("distance_m").get<double>(), 0.8, kPoseTol);
  EXPECT_NEAR(truth.at("yaw_deg").get<double>(), 30.0, kDegTol);

  const json& dets = j.at("detections");
  ASSERT_EQ(dets.size(), 2U);
  const detector::Detection& f8 = full.found[0];
  const json& d0 = dets[0];
  EXPECT_EQ(d0.at("family"), "frame8");
  EXPECT_EQ(d0.at("id"), 165);
  expect_quad(d0.at("corners"), f8.corners);
  expect_quad(d0.at("inner_corners"), *f8.inner_corners);
  EXPECT_EQ(d0.at("quarter_turns"), 1);
  EXPECT_EQ(d0.at("orientation_ambiguous"), true);
  EXPECT_EQ(d0.at("bits_corrected"), 2);
  EXPECT_NEAR(d0.at("margin").get<double>(), f8.margin, 0.5e-5 + 1e-12);
  const json& pose = d0.at("pose");
  EXPECT_EQ(pose.at("ambiguous"), true);
  expect_pose(pose.at("best"), f8.pose->best, full.truth);
  expect_pose(pose.at("alternative"), *f8.pose->alternative, full.truth);
  // The sample's best pose is (1.234567, -0.654321, 4.1) mm and 0.0123 rad from the truth.
  EXPECT_NEAR(pose.at("best").at("error").at("translation_mm").get<double>(), 4.33155, 1e-4);
  EXPECT_NEAR(pose.at("best").at("error").at("rotation_deg").get<double>(), 0.0123 * 180 / std::numbers::pi, kDegTol);

  const json& d1 = dets[1];
  EXPECT_EQ(d1.at("family"), "aruco4x4_50");
  EXPECT_EQ(d1.at("id"), 7);
  expect_quad(d1.at("corners"), full.found[1].corners);
  EXPECT_TRUE(d1.at("inner_corners").is_null());
  EXPECT_TRUE(d1.at("pose").is_null());
}

TEST(DetectionRecord, AFrameThatCouldNotBeDetected) {
  FrameRecordInput in;
  in.status = FrameStatus::corrupt_frame;
  in.cause = "MJPEG decode failed: premature end of data segment";
  in.sequence = 17;
  in.source = "sim";
  DetectionRecordFormatter formatter;
  const json j = parse_line(formatter.format(in));
  EXPECT_EQ(j.at("status"), "corrupt_frame");
  EXPECT_EQ(j.at("cause"), in.cause);
  EXPECT_EQ(j.at("frame").at("sequence"), 17);
  EXPECT_EQ(j.at("frame").at("capture_utc"), "1970-01-01T00:00:00.000000Z");
  EXPECT_TRUE(j.at("rig").is_null());
  EXPECT_TRUE(j.at("truth").is_null());
  EXPECT_EQ(j.at("detections"), json::array());
  EXPECT_EQ(to_string(FrameStatus::detector_error), "detector_error");
}

TEST(DetectionRecord, PosesWithoutTruthHaveNoError) {
  samples::FullRecord full;
  full.input.truth.reset();
  DetectionRecordFormatter formatter;
  const json j = parse_line(formatter.format(full.input));
  EXPECT_TRUE(j.at("truth").is_null());
  EXPECT_TRUE(j.at("detections")[0].at("pose").at("best").at("error").is_null());
  EXPECT_TRUE(j.at("detections")[0].at("pose").at("alternative").at("error").is_null());
  expect_vector(j.at("detections")[0].at("pose").at("best").at("tvec"), full.found[0].pose->best.translation, kPoseTol);
}

TEST(DetectionRecord, NonFiniteNumbersAreNull) {
  samples::FullRecord full;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  full.found[0].corners[2].x = nan;
  full.found[0].margin = -inf;
  full.found[0].pose->best.translation.y() = inf;
  full.found[0].pose->alternative->reprojection_error_px = nan;
  full.input.rig->rail.position = nan;
  // A truth at the camera centre: the error in percent of distance is infinite.
  full.input.truth->translation.setZero();
  full.input.truth->distance_m = nan;
  DetectionRecordFormatter formatter;
  const std::string_view line = formatter.format(full.input);
  EXPECT_EQ(line.find("nan"), std::string_view::npos) << line;
  EXPECT_EQ(line.find("inf"), std::string_view::npos) << line;
  const json j = parse_line(line);
  const json& d = j.at("detections")[0];
  EXPECT_TRUE(d.at("corners")[2][0].is_null());
  EXPECT_NEAR(d.at("corners")[2][1].get<double>(), full.found[0].corners[2].y, kPixelTol);
  EXPECT_TRUE(d.at("margin").is_null());
  EXPECT_TRUE(d.at("pose").at("best").at("tvec")[1].is_null());
  EXPECT_TRUE(d.at("pose").at("best").at("error").at("translation_mm").is_null());
  EXPECT_TRUE(d.at("pose").at("alternative").at("reprojection_error_px").is_null());
  EXPECT_TRUE(d.at("pose").at("alternative").at("error").at("translation_pct").is_null());
  EXPECT_TRUE(j.at("rig").at("rail").at("position_mm").is_null());
  EXPECT_TRUE(j.at("truth").at("distance_m").is_null());
}

TEST(DetectionRecord, StringsAreEscapedAndValidUtf8) {
  FrameRecordInput in;
  in.source = "cam \"A\"\\B\nline2\ttab\r\x01\x1f\x7f µm 🎯";
  in.status = FrameStatus::detector_error;
  // Not UTF-8: a stray continuation byte, a truncated sequence, an overlong
  // '/', a surrogate, a lead byte past U+10FFFF; each bad byte becomes U+FFFD.
  const std::string bad = std::string("a\x80") + "b\xE2\x82" + "c\xC0\xAF" + "d\xED\xA0\x80" + "e\xF5\x80" + "\xE2";
  in.cause = bad;
  DetectionRecordFormatter formatter;
  const std::string_view line = formatter.format(in);
  const json j = parse_line(line);
  EXPECT_EQ(j.at("frame").at("source"), in.source);
  const std::string r = "\xEF\xBF\xBD";
  EXPECT_EQ(j.at("cause"), "a" + r + "b" + r + r + "c" + r + r + "d" + r + r + r + "e" + r + r + r);
}

TEST(DetectionRecord, UtcTimes) {
  using namespace std::chrono;
  DetectionRecordFormatter formatter;
  FrameRecordInput in;
  const auto utc_of = [&](system_clock::time_point t) {
    in.capture_utc = t;
    return parse_line(formatter.format(in)).at("frame").at("capture_utc").get<std::string>();
  };
  EXPECT_EQ(utc_of(sys_days(year{2038} / 1 / 19) + hours(3) + minutes(14) + seconds(8)), "2038-01-19T03:14:08.000000Z");
  // Microseconds are truncated towards the past, also before 1970.
  EXPECT_EQ(utc_of(system_clock::time_point(nanoseconds(1'999))), "1970-01-01T00:00:00.000001Z");
  EXPECT_EQ(utc_of(system_clock::time_point(microseconds(-1))), "1969-12-31T23:59:59.999999Z");
}

TEST(DetectionRecord, TheBufferIsReusedWithoutRemnants) {
  const samples::FullRecord full;
  FrameRecordInput small;
  small.sequence = 3;
  DetectionRecordFormatter formatter;
  const std::string first(formatter.format(full.input));
  const std::string second(formatter.format(small));
  EXPECT_LT(second.size(), first.size());
  EXPECT_EQ(parse_line(second).at("frame").at("sequence"), 3);
  EXPECT_EQ(formatter.format(full.input), first);
}

// --- The schema table of docs/detection-log.md against the formatter ---

// Every key path of a record: "a.b" for key b of object a, "a[].b" for key b
// of the objects in array a. Objects count as keys too (so "rig" is one).
void collect_keys(const json& j, const std::string& prefix, std::set<std::string>& keys) {
  if (j.is_object()) {
    for (const auto& [key, value] : j.items()) {
      const std::string path = prefix.empty() ? key : prefix + "." + key;
      keys.insert(path);
      collect_keys(value, path, keys);
    }
  } else if (j.is_array()) {
    for (const json& element : j) {
      if (element.is_object()) collect_keys(element, prefix + "[]", keys);
    }
  }
}

std::string read_doc() {
  std::string text = test_support::read_file(std::filesystem::path(MARKERD_SOURCE_DIR) / "docs/detection-log.md");
  EXPECT_FALSE(text.empty()) << "docs/detection-log.md";
  return text;
}

// The keys of the table under "### Keys": the first cell of each row, in backticks.
std::set<std::string> documented_keys(const std::string& doc) {
  std::set<std::string> keys;
  std::istringstream lines(doc.substr(doc.find("### Keys")));
  std::string line;
  bool in_table = false;
  while (std::getline(lines, line)) {
    if (line.starts_with("| key |")) {
      in_table = true;
      continue;
    }
    if (!in_table || line.starts_with("| ---")) continue;
    if (!line.starts_with("| `")) break;
    const std::size_t end = line.find('`', 3);
    EXPECT_NE(end, std::string::npos) << line;
    EXPECT_TRUE(keys.insert(line.substr(3, end - 3)).second) << "documented twice: " << line;
  }
  return keys;
}

TEST(DetectionLogSchema, EveryKeyOfAFullRecordIsDocumentedAndNoOther) {
  const std::set<std::string> documented = documented_keys(read_doc());
  ASSERT_GT(documented.size(), 40U) << "the key table was not found";
  const samples::FullRecord full;
  DetectionRecordFormatter formatter;
  std::set<std::string> emitted;
  collect_keys(parse_line(formatter.format(full.input)), "", emitted);
  for (const auto& key : emitted) EXPECT_TRUE(documented.contains(key)) << "not in docs/detection-log.md: " << key;
  for (const auto& key : documented) EXPECT_TRUE(emitted.contains(key)) << "documented but not written: " << key;
}

TEST(DetectionLogSchema, TheExampleIsAValidRecordOfTheSchema) {
  const std::string doc = read_doc();
  const std::size_t example = doc.find("### Example");
  ASSERT_NE(example, std::string::npos);
  const std::size_t begin = doc.find("```json\n", example);
  ASSERT_NE(begin, std::string::npos);
  const std::size_t line_begin = begin + 8;
  const std::string line = doc.substr(line_begin, doc.find('\n', line_begin) + 1 - line_begin);
  // What the formatter writes for the example's frame (the sample's frame8
  // detection alone), for the doc when the schema changes.
  samples::FullRecord frame;
  frame.input.detections = std::span<const detector::Detection>(frame.found).first(1);
  DetectionRecordFormatter formatter;
  SCOPED_TRACE("the formatter writes for this frame:\n" + std::string(formatter.format(frame.input)));
  const json j = json::parse(line, nullptr, false);
  ASSERT_FALSE(j.is_discarded()) << "the example is no JSON line";
  EXPECT_EQ(j.at("schema"), kDetectionLogSchema);
  std::set<std::string> keys;
  collect_keys(j, "", keys);
  EXPECT_EQ(keys, documented_keys(doc));
}

}  // namespace
}  // namespace markerd::daemon
