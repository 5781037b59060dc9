#include "markerd/detector/camera_model.hpp"

#include <yaml-cpp/yaml.h>
#include <opencv2/core.hpp>
#include <opencv2/core/persistence.hpp>

#include <fmt/format.h>
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <fstream>
#include <limits>
#include <string_view>
#include <tuple>
#include <unordered_set>
#include <vector>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/read_file.hpp"

namespace markerd::detector {
namespace {

// A calibration is a few kilobytes; a larger file is not one.
constexpr std::size_t kMaxCameraFileBytes = std::size_t{1} << 20;

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what) {
  throw CameraModelError(fmt::format("{}: {}", path.string(), what));
}

// Camera files are read with yaml-cpp, not with OpenCV's cv::FileStorage:
// OpenCV 4.6's YAML parser never returns on some malformed files (four
// shapes found by fuzz_camera_model, docs/fuzzing.md) and its XML parser
// dereferences a null pointer on others. OpenCV's calibration writes YAML
// 1.0 under a directive of its own spelling, "%YAML:1.0", which is no YAML
// directive: it is blanked (the line numbers stay those of the file).
// What is left is plain YAML, so ROS's camera_info files (the same keys,
// without the !!opencv-matrix tags) and JSON read the same way.
std::string as_plain_yaml(std::string text) {
  constexpr std::string_view bom = "\xEF\xBB\xBF";
  if (std::string_view(text).substr(0, bom.size()) == bom) text.erase(0, bom.size());
  if (std::string_view(text).substr(0, 6) == "%YAML:") text.erase(0, std::min(text.find('\n'), text.size()));
  return text;
}

std::string where(const YAML::Node& node) { return fmt::format("line {}", node.Mark().line + 1); }

// The keys a camera file gives, each once: YAML leaves a repeated key to the
// reader, and a file that says fx twice says nothing certain.
void check_keys_unique(const YAML::Node& map, const std::filesystem::path& path, const std::string& in) {
  std::unordered_set<std::string> seen;
  for (const auto& entry : map) {
    if (!entry.first.IsScalar()) fail(path, fmt::format("{}: a key {}that is not a name", where(entry.first), in));
    if (!seen.insert(entry.first.Scalar()).second) {
      fail(path, fmt::format("{}: key '{}' {}given twice", where(entry.first), entry.first.Scalar(), in));
    }
  }
}

// A YAML number: decimal (as std::from_chars reads it, with an optional
// '+'), or .inf / .nan in YAML's spellings. A decimal beyond double's range
// is infinite, as a parser that rounds would make it; the range checks that
// follow refuse it by name.
bool parse_number(std::string_view s, double& value) {
  bool negative = false;
  std::string_view body = s;
  if (!body.empty() && (body[0] == '+' || body[0] == '-')) {
    negative = body[0] == '-';
    body.remove_prefix(1);
  }
  for (const std::string_view inf : {".inf", ".Inf", ".INF"}) {
    if (body == inf) {
      value = negative ? -std::numeric_limits<double>::infinity() : std::numeric_limits<double>::infinity();
      return true;
    }
  }
  for (const std::string_view nan : {".nan", ".NaN", ".NAN", ".Nan"}) {
    if (s == nan) {
      value = std::numeric_limits<double>::quiet_NaN();
      return true;
    }
  }
  if (body.empty() || !(std::isdigit(static_cast<unsigned char>(body[0])) || body[0] == '.')) return false;
  double magnitude = 0;
  const auto [end, ec] = std::from_chars(body.data(), body.data() + body.size(), magnitude);
  if (end != body.data() + body.size()) return false;
  if (ec == std::errc::result_out_of_range) {
    // Too large or too small: which, from the exponent's sign.
    const bool tiny = body.find("e-") != std::string_view::npos || body.find("E-") != std::string_view::npos;
    magnitude = tiny ? 0.0 : std::numeric_limits<double>::infinity();
  } else if (ec != std::errc{}) {
    return false;
  }
  value = negative ? -magnitude : magnitude;
  return true;
}

double read_number(const YAML::Node& node, const std::filesystem::path& path, const std::string& what) {
  double value = 0;
  if (!node.IsScalar() || !parse_number(node.Scalar(), value)) {
    fail(path, fmt::format("{}: {} is not a number", where(node), what));
  }
  return value;
}

// Larger than any sensor's side, and small enough that width * height and
// the detector's buffers fit their types.
constexpr int kMaxImageSide = 65535;

int read_image_side(const YAML::Node& root, const std::filesystem::path& path, const char* key) {
  const YAML::Node node = root[key];
  if (!node) fail(path, fmt::format("missing key '{}'", key));
  const double value = read_number(node, path, fmt::format("key '{}'", key));
  // Checked before the conversion: inf, NaN or 1e34 do not fit an int.
  if (!(value >= 1 && value <= kMaxImageSide) || value != std::floor(value)) {
    fail(path, fmt::format("{}: key '{}' must be a whole number of pixels from 1 to {}, got {}", where(node), key,
                           kMaxImageSide, node.Scalar()));
  }
  return static_cast<int>(value);
}

struct Matrix {
  int rows = 0;
  int cols = 0;
  std::vector<double> values;  // row by row
  [[nodiscard]] double at(int r, int c) const { return values[static_cast<std::size_t>(r * cols + c)]; }
};

// OpenCV's element types of one channel; "3d" and the like are images, not
// a camera's matrices, and their values would be read in the wrong places.
bool single_channel_type(const std::string& dt) { return dt.size() == 1 && dt.find_first_of("ucwsifd") == 0; }

// A matrix as OpenCV writes it (a !!opencv-matrix map: rows, cols, dt,
// data) or as ROS's camera_info does (rows, cols, data). The declared size
// is checked before the data is read.
Matrix read_matrix(const YAML::Node& root, const std::filesystem::path& path, const char* key,
                   bool (*size_ok)(int rows, int cols), const char* expected) {
  const YAML::Node node = root[key];
  if (!node) fail(path, fmt::format("missing key '{}'", key));
  const std::string in = fmt::format("in '{}' ", key);
  if (!node.IsMap()) fail(path, fmt::format("{}: key '{}' is not a matrix (rows, cols and data)", where(node), key));
  check_keys_unique(node, path, in);
  const YAML::Node rows = node["rows"];
  const YAML::Node cols = node["cols"];
  const YAML::Node data = node["data"];
  if (!rows || !cols || !data || !data.IsSequence()) {
    fail(path, fmt::format("{}: key '{}' is not a matrix (rows, cols and data)", where(node), key));
  }
  const double r = read_number(rows, path, fmt::format("'{}' rows", key));
  const double c = read_number(cols, path, fmt::format("'{}' cols", key));
  const auto whole = [](double v) { return v >= 0 && v <= std::numeric_limits<int>::max() && v == std::floor(v); };
  if (!whole(r) || !whole(c) || !size_ok(static_cast<int>(r), static_cast<int>(c))) {
    fail(path,
         fmt::format("{}: key '{}' must be {}, got {}x{}", where(node), key, expected, rows.Scalar(), cols.Scalar()));
  }
  Matrix m{static_cast<int>(r), static_cast<int>(c), {}};
  if (data.size() != static_cast<std::size_t>(m.rows) * static_cast<std::size_t>(m.cols)) {
    fail(path,
         fmt::format("{}: key '{}' declares {}x{} but holds {} values", where(data), key, m.rows, m.cols, data.size()));
  }
  if (const YAML::Node dt = node["dt"]; dt && !(dt.IsScalar() && single_channel_type(dt.Scalar()))) {
    fail(path, fmt::format("{}: key '{}' has dt '{}': a matrix of one channel of numbers (such as d) is expected",
                           where(dt), key, dt.IsScalar() ? dt.Scalar() : std::string("(not a name)")));
  }
  m.values.reserve(data.size());
  for (const auto& value : data) {
    const double v = read_number(value, path, fmt::format("a value of '{}'", key));
    if (!std::isfinite(v)) fail(path, fmt::format("{}: key '{}' holds a value that is not finite", where(value), key));
    m.values.push_back(v);
  }
  return m;
}

bool is_3x3(int rows, int cols) { return rows == 3 && cols == 3; }

bool is_distortion_size(int rows, int cols) {
  const int n = rows == 1 ? cols : (cols == 1 ? rows : 0);
  return n == 4 || n == 5 || n == 8 || n == 12 || n == 14;
}

// ROS's camera_info names its lens model. Its plumb_bob and
// rational_polynomial are OpenCV's model with 5 and 8 coefficients; its
// equidistant model (OpenCV's fisheye) has 4 coefficients of another
// model, which read as k1 k2 p1 p2 would be a wrong lens, not an error.
void check_distortion_model(const YAML::Node& root, const std::filesystem::path& path, std::size_t coefficients) {
  const YAML::Node node = root["distortion_model"];
  if (!node) return;
  const std::string name = node.IsScalar() ? node.Scalar() : std::string();
  const std::size_t expected = name == "plumb_bob" ? 5 : (name == "rational_polynomial" ? 8 : 0);
  if (expected == 0) {
    fail(path, fmt::format("{}: distortion_model '{}' is not supported: plumb_bob or rational_polynomial (OpenCV's "
                           "model; an equidistant or fisheye lens needs another model)",
                           where(node), name));
  }
  if (coefficients != expected) {
    fail(path, fmt::format("{}: distortion_model '{}' has {} coefficients, the file gives {}", where(node), name,
                           expected, coefficients));
  }
}

// A focal length beyond this many image widths would be a lens of several
// metres before a phone's sensor: a typo or garbage, not a calibration.
constexpr double kMaxFocalPerSide = 1000;
// The principal point of a shifted or cropped lens may lie off the image,
// but not more than this many image sizes away.
constexpr double kMaxPrincipalOffsetPerSide = 10;

void check_intrinsics(const CameraModel& cam, const Matrix& k, const std::filesystem::path& path) {
  for (const auto& [f, side, name] : {std::tuple{cam.fx, cam.width, "fx"}, std::tuple{cam.fy, cam.height, "fy"}}) {
    if (!(f > 0 && f <= kMaxFocalPerSide * side)) {
      fail(path, fmt::format("key 'camera_matrix': {} must be positive and at most {} pixels (1000 image sizes), "
                             "got {}",
                             name, kMaxFocalPerSide * side, f));
    }
  }
  for (const auto& [c, side, name] : {std::tuple{cam.cx, cam.width, "cx"}, std::tuple{cam.cy, cam.height, "cy"}}) {
    const double reach = kMaxPrincipalOffsetPerSide * side;
    if (!(c >= -reach && c <= side + reach)) {
      fail(path, fmt::format("key 'camera_matrix': {} must be from {} to {} pixels (within 10 image sizes of the "
                             "image), got {}",
                             name, -reach, side + reach, c));
    }
  }
  if (std::abs(k.at(0, 1)) > 1e-9) fail(path, "key 'camera_matrix': a skewed pixel grid is not supported");
  // The last row and the zeros are what any calibration writes; anything
  // else is not a pinhole camera's matrix and would be silently ignored.
  const bool pinhole = k.at(1, 0) == 0 && k.at(2, 0) == 0 && k.at(2, 1) == 0 && k.at(2, 2) == 1;
  if (!pinhole) fail(path, "key 'camera_matrix' must be fx, 0, cx / 0, fy, cy / 0, 0, 1");
}

CameraModel parse(const YAML::Node& root, const std::filesystem::path& path) {
  if (!root.IsMap()) fail(path, "the camera file is not a map of keys (image_width, camera_matrix, ...)");
  check_keys_unique(root, path, "");
  CameraModel cam;
  cam.width = read_image_side(root, path, "image_width");
  cam.height = read_image_side(root, path, "image_height");

  const Matrix k = read_matrix(root, path, "camera_matrix", is_3x3, "3x3");
  cam.fx = k.at(0, 0);
  cam.fy = k.at(1, 1);
  cam.cx = k.at(0, 2);
  cam.cy = k.at(1, 2);
  check_intrinsics(cam, k, path);

  const Matrix d = read_matrix(root, path, "distortion_coefficients", is_distortion_size,
                               "1xN or Nx1 with N 4, 5, 8, 12 or 14 (OpenCV's model)");
  check_distortion_model(root, path, d.values.size());
  const std::vector<double>& v = d.values;
  for (std::size_t i = 0; i < std::min<std::size_t>(v.size(), 12); ++i) cam.dist[i] = v[i];
  if (v.size() == 14 && (v[12] != 0.0 || v[13] != 0.0)) {
    fail(path, "key 'distortion_coefficients': the tilted-sensor terms (tauX, tauY) are not supported");
  }
  return cam;
}

// A double as YAML 1.1 and 1.2 readers (yaml-cpp, PyYAML) both take it for
// a float, to the last bit: the shortest form that reads back, with a
// decimal point and a signed exponent (PyYAML reads 1e-05 as a string).
std::string yaml_float(double v) {
  std::string text = fmt::format("{}", v);
  const std::size_t e = text.find('e');
  std::string mantissa = text.substr(0, e);
  std::string exponent = e == std::string::npos ? std::string() : text.substr(e + 1);
  if (mantissa.find('.') == std::string::npos) mantissa += ".0";
  if (!exponent.empty() && exponent[0] != '-' && exponent[0] != '+') exponent.insert(0, "+");
  return exponent.empty() ? mantissa : mantissa + "e" + exponent;
}

std::string yaml_matrix(int rows, int cols, const std::vector<double>& data) {
  std::string values;
  for (const double v : data) values += fmt::format("{}{}", values.empty() ? "" : ", ", yaml_float(v));
  return fmt::format("  rows: {}\n  cols: {}\n  data: [{}]\n", rows, cols, values);
}

// ROS's camera_info, laid out as its camera_calibration_parsers write it.
void save_camera_info(const CameraModel& c, int coefficients, const std::filesystem::path& path,
                      std::string_view camera_name) {
  if (coefficients > 8) {
    throw CameraModelError(
        fmt::format("{}: ROS's camera_info has no thin-prism terms (s1 to s4): the lens needs "
                    "OpenCV's format",
                    path.string()));
  }
  const std::string name(camera_name);
  if (!CameraModel::is_ros_camera_name(name)) {
    throw CameraModelError(
        fmt::format("{}: camera name '{}' must be letters, digits and _ (then also - . /)", path.string(), name));
  }
  const std::vector<double> d(c.dist.begin(), c.dist.begin() + coefficients);
  std::string text = fmt::format("image_width: {}\nimage_height: {}\ncamera_name: {}\n", c.width, c.height, name);
  text += "camera_matrix:\n" + yaml_matrix(3, 3, {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1});
  text += fmt::format("distortion_model: {}\n", coefficients == 5 ? "plumb_bob" : "rational_polynomial");
  text += "distortion_coefficients:\n" + yaml_matrix(1, coefficients, d);
  text += "rectification_matrix:\n" + yaml_matrix(3, 3, {1, 0, 0, 0, 1, 0, 0, 0, 1});
  text += "projection_matrix:\n" + yaml_matrix(3, 4, {c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0});
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw CameraModelError(fmt::format("{}: cannot write the camera file: {}", path.string(), errno_text(errno)));
  f << text;
  f.close();
  if (!f) throw CameraModelError(fmt::format("{}: write failed: {}", path.string(), errno_text(errno)));
}

}  // namespace

CameraModel CameraModel::load(const std::filesystem::path& path) {
  // Read here, bounded: a directory, a FIFO or /dev/zero is refused by name.
  std::string text;
  try {
    text = read_regular_file(path, kMaxCameraFileBytes, "the camera file");
  } catch (const FileError& e) {
    throw CameraModelError(e.what());
  }
  text = as_plain_yaml(std::move(text));
  const std::size_t first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) fail(path, "the camera file is empty");
  if (text[first] == '<') {
    fail(path, "XML camera files are not read: write it as YAML (OpenCV's cv::FileStorage with a .yaml name does)");
  }
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    fail(path, fmt::format("the camera file cannot be parsed: line {}: {}", e.mark.line + 1, e.msg));
  }
  // yaml-cpp throws on questions its nodes cannot answer (a subscript of a
  // sequence, say): each is a wrong camera file.
  try {
    return parse(root, path);
  } catch (const YAML::Exception& e) {
    fail(path, fmt::format("the camera file is not a camera model: line {}: {}", e.mark.line + 1, e.msg));
  }
}

void CameraModel::save(const std::filesystem::path& path, CameraFileFormat format, std::string_view camera_name) const {
  int n = 12;
  while (n > 5 && dist[static_cast<std::size_t>(n - 1)] == 0.0) --n;
  n = n <= 5 ? 5 : (n <= 8 ? 8 : 12);
  if (format == CameraFileFormat::ros) {
    save_camera_info(*this, n, path, camera_name);
    return;
  }
  cv::FileStorage fs(path.string(), cv::FileStorage::WRITE);
  if (!fs.isOpened()) throw CameraModelError(fmt::format("{}: cannot write the camera file", path.string()));
  fs << "image_width" << width << "image_height" << height;
  const cv::Mat k = (cv::Mat_<double>(3, 3) << fx, 0, cx, 0, fy, cy, 0, 0, 1);
  fs << "camera_matrix" << k;
  cv::Mat d(1, n, CV_64F);
  for (int i = 0; i < n; ++i) d.at<double>(0, i) = dist[static_cast<std::size_t>(i)];
  fs << "distortion_coefficients" << d;
}

bool CameraModel::is_ros_camera_name(std::string_view name) {
  // Also a name YAML takes as a plain string, unquoted.
  const auto plain = [](char ch, bool first) {
    const bool alnum = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9');
    return alnum || ch == '_' || (!first && (ch == '-' || ch == '.' || ch == '/'));
  };
  if (name.empty()) return false;
  for (std::size_t i = 0; i < name.size(); ++i) {
    if (!plain(name[i], i == 0)) return false;
  }
  return true;
}

CameraModel CameraModel::thesis_640x480() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = 516;
  c.fy = 515;
  c.cx = 319;
  c.cy = 238;
  c.dist = {0.3495, -2.2549, 0.0, 0.0, 4.9959};
  return c;
}

CameraModel CameraModel::scaled_to(int new_width, int new_height) const {
  CameraModel c = *this;
  const double sx = static_cast<double>(new_width) / width;
  const double sy = static_cast<double>(new_height) / height;
  c.width = new_width;
  c.height = new_height;
  c.fx = fx * sx;
  c.fy = fy * sy;
  // Pixel centres sit at integers: the centre of pixel 0 moves with the scale.
  c.cx = (cx + 0.5) * sx - 0.5;
  c.cy = (cy + 0.5) * sy - 0.5;
  return c;
}

bool CameraModel::has_distortion() const {
  for (double v : dist) {
    if (v != 0.0) return true;
  }
  return false;
}

Point2 CameraModel::distort(Point2 p) const {
  const auto& k = dist;
  const double x = p.x, y = p.y;
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double radial = (1 + k[0] * r2 + k[1] * r4 + k[4] * r6) / (1 + k[5] * r2 + k[6] * r4 + k[7] * r6);
  const double xd = x * radial + 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x) + k[8] * r2 + k[9] * r4;
  const double yd = y * radial + k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y + k[10] * r2 + k[11] * r4;
  return {xd, yd};
}

Point2 CameraModel::undistort(Point2 d) const {
  if (!has_distortion()) return d;
  // Newton's method on distort(p) = d with a numerical Jacobian: converges in
  // a few steps where OpenCV's fixed-point iteration stalls on strong lenses.
  Point2 p = d;
  for (int iter = 0; iter < 20; ++iter) {
    const Point2 f = distort(p);
    const double ex = f.x - d.x, ey = f.y - d.y;
    if (ex * ex + ey * ey < 1e-24) break;
    constexpr double h = 1e-7;
    const Point2 fx_ = distort({p.x + h, p.y});
    const Point2 fy_ = distort({p.x, p.y + h});
    const double a = (fx_.x - f.x) / h, b = (fy_.x - f.x) / h;
    const double c = (fx_.y - f.y) / h, e = (fy_.y - f.y) / h;
    const double det = a * e - b * c;
    if (std::abs(det) < 1e-12) break;
    p.x -= (e * ex - b * ey) / det;
    p.y -= (-c * ex + a * ey) / det;
  }
  return p;
}

Point2 CameraModel::pixel_to_normalized(Point2 px) const { return undistort({(px.x - cx) / fx, (px.y - cy) / fy}); }

Point2 CameraModel::normalized_to_pixel(Point2 n) const {
  const Point2 d = distort(n);
  return {fx * d.x + cx, fy * d.y + cy};
}

}  // namespace markerd::detector
