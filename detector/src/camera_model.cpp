#include "markerd/detector/camera_model.hpp"

#include <opencv2/core.hpp>
#include <opencv2/core/persistence.hpp>

#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include <exception>
#include <stdexcept>
#include <string_view>
#include <tuple>

#include "markerd/base/read_file.hpp"

namespace markerd::detector {
namespace {

// A calibration is a few kilobytes; a larger file is not one.
constexpr std::size_t kMaxCameraFileBytes = std::size_t{1} << 20;

// OpenCV's parse errors read "<source>(<line>): <what>", the source empty
// for text parsed from memory: "line 5: Missing ':' between key and value".
// OpenCV 4.6 passes that text as the exception's function and the parser
// function's name as its message (FileStorage::Impl::parseError swaps them),
// so both are looked at.
std::string parse_error_words(const cv::Exception& e) {
  for (const std::string* text : {&e.err, &e.func}) {
    std::string_view line(*text);
    if (!line.empty() && line.back() == '\n') line.remove_suffix(1);
    if (line.find('\n') != std::string_view::npos) continue;
    const auto close = line.find("): ");
    const auto open = line.substr(0, close).rfind('(');
    if (close == std::string_view::npos || open == std::string_view::npos) continue;
    const std::string_view number = line.substr(open + 1, close - open - 1);
    const bool digits = !number.empty() && number.find_first_not_of("0123456789") == std::string_view::npos;
    if (digits) return fmt::format("line {}: {}", number, line.substr(close + 3));
  }
  return e.err;
}

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what) {
  throw CameraModelError(fmt::format("{}: {}", path.string(), what));
}

// OpenCV's reader can fail with exceptions of the standard library's own,
// not cv::Exception. The one known (OpenCV 4.6's YAMLParser::parseKey, and
// upstream since): an indented line with nothing before its ':' makes the
// key's end step back over the indentation, past the key's start, and the
// negative length reaches std::string as std::length_error. At the top
// level the same key is OpenCV's "An empty key", so that line is named.
std::string reader_failure_words(std::string_view text, const std::exception& e) {
  if (dynamic_cast<const std::length_error*>(&e) != nullptr) {
    std::size_t number = 1;
    for (std::size_t start = 0; start < text.size(); ++number) {
      const std::size_t end = std::min(text.find('\n', start), text.size());
      const std::string_view line = text.substr(start, end - start);
      const std::size_t first = line.find_first_not_of(' ');
      if (first != std::string_view::npos && first > 0 && line[first] == ':') {
        return fmt::format("line {}: an empty key (a ':' with no name before it)", number);
      }
      start = end + 1;
    }
  }
  return fmt::format("OpenCV's reader failed: {}", e.what());
}

// The only format read is OpenCV's YAML. OpenCV picks its parser from the
// first bytes alone (after a UTF-8 byte order mark): "%YAML", "{" for JSON,
// "<?xml". Its XML parser dereferences a null pointer on some corrupt files
// (a segmentation fault in FileStorage::open, OpenCV 4.6), which no
// try/catch survives, so a file that is not YAML never reaches OpenCV.
// JSON goes too: one parser to trust, the one OpenCV's and ROS's
// calibration tools write.
//
// Its YAML parser loops forever on a "---" with more on its line followed by
// another such line ("---L:1.0", "-----": found by fuzz_camera_model, OpenCV
// 4.6), so "---", the document start, must stand alone on its line.
void check_document_starts(const std::filesystem::path& path, std::string_view text) {
  int number = 1;
  for (std::size_t start = 0; start < text.size(); ++number) {
    const std::size_t end = std::min(text.find('\n', start), text.size());
    std::string_view line = text.substr(start, end - start);
    // Indented too (" ---r:", the second such file the fuzzer found).
    line.remove_prefix(std::min(line.size(), line.find_first_not_of(" \t")));
    if (line.substr(0, 3) == "---" && line.size() > 3 && line[3] != ' ' && line[3] != '\t' && line[3] != '\r') {
      fail(path, fmt::format("line {}: '---' (a YAML document start) must stand alone on its line", number));
    }
    start = end + 1;
  }
}

void check_yaml(const std::filesystem::path& path, std::string_view text) {
  constexpr std::string_view bom = "\xEF\xBB\xBF";
  if (text.substr(0, bom.size()) == bom) text.remove_prefix(bom.size());
  if (text.substr(0, 5) == "%YAML") {
    check_document_starts(path, text);
    return;
  }
  const std::size_t first = text.find_first_not_of(" \t\r\n");
  const std::string_view start = first == std::string_view::npos ? std::string_view{} : text.substr(first);
  if (start.substr(0, 1) == "<") {
    fail(path, "XML camera files are not read: convert it to OpenCV's YAML (a file that begins with %YAML:1.0)");
  }
  if (start.substr(0, 1) == "{") {
    fail(path, "JSON camera files are not read: convert it to OpenCV's YAML (a file that begins with %YAML:1.0)");
  }
  fail(path, "the camera file is not OpenCV's YAML: it must begin with %YAML:1.0");
}

// The declared size of a matrix, checked before OpenCV reads it: OpenCV
// allocates rows x cols first and compares the data with it afterwards, so
// "rows: 100000000" in a small file would reserve gigabytes.
void check_matrix_header(const cv::FileNode& node, const std::filesystem::path& path, const char* key,
                         bool (*size_ok)(int rows, int cols), const char* expected) {
  if (!node.isMap()) fail(path, fmt::format("key '{}' is not a matrix", key));
  const cv::FileNode rows = node["rows"];
  const cv::FileNode cols = node["cols"];
  const cv::FileNode data = node["data"];
  if (!rows.isInt() || !cols.isInt() || !data.isSeq()) {
    fail(path, fmt::format("key '{}' is not a matrix (rows, cols and data)", key));
  }
  const int r = static_cast<int>(rows);
  const int c = static_cast<int>(cols);
  if (!size_ok(r, c)) fail(path, fmt::format("key '{}' must be {}, got {}x{}", key, expected, r, c));
  if (data.size() != static_cast<std::size_t>(r) * static_cast<std::size_t>(c)) {
    fail(path, fmt::format("key '{}' declares {}x{} but holds {} values", key, r, c, data.size()));
  }
}

cv::Mat read_matrix(const cv::FileNode& root, const std::filesystem::path& path, const char* key,
                    bool (*size_ok)(int rows, int cols), const char* expected) {
  const cv::FileNode node = root[key];
  if (node.empty()) fail(path, fmt::format("missing key '{}'", key));
  check_matrix_header(node, path, key, size_ok, expected);
  cv::Mat m;
  try {
    node >> m;
  } catch (const cv::Exception&) {
    fail(path, fmt::format("key '{}' is not a matrix", key));
  }
  if (m.empty() || m.channels() != 1) fail(path, fmt::format("key '{}' is not a matrix of numbers", key));
  m.convertTo(m, CV_64F);
  for (auto it = m.begin<double>(); it != m.end<double>(); ++it) {
    if (!std::isfinite(*it)) fail(path, fmt::format("key '{}' holds a value that is not finite", key));
  }
  return m;
}

bool is_3x3(int rows, int cols) { return rows == 3 && cols == 3; }

bool is_distortion_size(int rows, int cols) {
  const int n = rows == 1 ? cols : (cols == 1 ? rows : 0);
  return n == 4 || n == 5 || n == 8 || n == 12 || n == 14;
}

// Larger than any sensor's side, and small enough that width * height and
// the detector's buffers fit their types.
constexpr int kMaxImageSide = 65535;

int read_image_side(const cv::FileNode& root, const std::filesystem::path& path, const char* key) {
  const cv::FileNode node = root[key];
  if (node.empty()) fail(path, fmt::format("missing key '{}'", key));
  if (!node.isInt() && !node.isReal()) fail(path, fmt::format("key '{}' is not a number", key));
  const double value = node.real();
  // Checked before the conversion: 1e309 (inf), NaN or 1e34 do not fit an int.
  if (!(value >= 1 && value <= kMaxImageSide) || value != std::floor(value)) {
    fail(path,
         fmt::format("key '{}' must be a whole number of pixels from 1 to {}, got {}", key, kMaxImageSide, value));
  }
  return static_cast<int>(value);
}

// A focal length beyond this many image widths would be a lens of several
// metres before a phone's sensor: a typo or garbage, not a calibration.
constexpr double kMaxFocalPerSide = 1000;
// The principal point of a shifted or cropped lens may lie off the image,
// but not more than this many image sizes away.
constexpr double kMaxPrincipalOffsetPerSide = 10;

void check_intrinsics(const CameraModel& cam, const cv::Mat& k, const std::filesystem::path& path) {
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
  if (std::abs(k.at<double>(0, 1)) > 1e-9) fail(path, "key 'camera_matrix': a skewed pixel grid is not supported");
  // The last row and the zeros are what any calibration writes; anything
  // else is not a pinhole camera's matrix and would be silently ignored.
  const bool pinhole =
      k.at<double>(1, 0) == 0 && k.at<double>(2, 0) == 0 && k.at<double>(2, 1) == 0 && k.at<double>(2, 2) == 1;
  if (!pinhole) fail(path, "key 'camera_matrix' must be fx, 0, cx / 0, fy, cy / 0, 0, 1");
}

CameraModel parse(const cv::FileStorage& fs, const std::filesystem::path& path) {
  // fs[key] asserts a map at the top: a list there is a wrong file, not a crash.
  const cv::FileNode root = fs.root();
  if (!root.isMap()) fail(path, "the camera file is not a map of keys (image_width, camera_matrix, ...)");
  CameraModel cam;
  cam.width = read_image_side(root, path, "image_width");
  cam.height = read_image_side(root, path, "image_height");

  const cv::Mat k = read_matrix(root, path, "camera_matrix", is_3x3, "3x3");
  cam.fx = k.at<double>(0, 0);
  cam.fy = k.at<double>(1, 1);
  cam.cx = k.at<double>(0, 2);
  cam.cy = k.at<double>(1, 2);
  check_intrinsics(cam, k, path);

  const cv::Mat d = read_matrix(root, path, "distortion_coefficients", is_distortion_size,
                                "1xN or Nx1 with N 4, 5, 8, 12 or 14 (OpenCV's model)");
  const int n = static_cast<int>(d.total());
  const auto* v = d.ptr<double>();
  for (int i = 0; i < std::min(n, 12); ++i) cam.dist[static_cast<std::size_t>(i)] = v[i];
  if (n == 14 && (v[12] != 0.0 || v[13] != 0.0)) {
    fail(path, "key 'distortion_coefficients': the tilted-sensor terms (tauX, tauY) are not supported");
  }
  return cam;
}

}  // namespace

CameraModel CameraModel::load(const std::filesystem::path& path) {
  // Read here, bounded, and parsed from memory: FileStorage would open a
  // directory, a FIFO or /dev/zero and fail (or wait) without saying why.
  std::string text;
  try {
    text = read_regular_file(path, kMaxCameraFileBytes, "the camera file");
  } catch (const FileError& e) {
    throw CameraModelError(e.what());
  }
  if (text.find_first_not_of(" \t\r\n") == std::string::npos) fail(path, "the camera file is empty");
  check_yaml(path, text);
  cv::FileStorage fs;
  bool opened = false;
  try {
    opened = fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY);
  } catch (const cv::Exception& e) {
    fail(path, fmt::format("the camera file cannot be parsed: {}", parse_error_words(e)));
  } catch (const std::exception& e) {
    fail(path, fmt::format("the camera file cannot be parsed: {}", reader_failure_words(text, e)));
  }
  if (!opened) fail(path, "the camera file is not OpenCV's YAML");
  // OpenCV asserts on what it does not expect in a node it is asked about;
  // any of those is a wrong camera file, never an escaping cv::Exception.
  try {
    return parse(fs, path);
  } catch (const CameraModelError&) {
    throw;
  } catch (const cv::Exception& e) {
    fail(path, fmt::format("the camera file is not a camera model: {}", e.err));
  } catch (const std::exception& e) {
    fail(path, fmt::format("the camera file is not a camera model: OpenCV's reader failed: {}", e.what()));
  }
}

void CameraModel::save(const std::filesystem::path& path) const {
  cv::FileStorage fs(path.string(), cv::FileStorage::WRITE);
  if (!fs.isOpened()) throw CameraModelError(fmt::format("{}: cannot write the camera file", path.string()));
  fs << "image_width" << width << "image_height" << height;
  const cv::Mat k = (cv::Mat_<double>(3, 3) << fx, 0, cx, 0, fy, cy, 0, 0, 1);
  fs << "camera_matrix" << k;
  int n = 12;
  while (n > 5 && dist[static_cast<std::size_t>(n - 1)] == 0.0) --n;
  n = n <= 5 ? 5 : (n <= 8 ? 8 : 12);
  cv::Mat d(1, n, CV_64F);
  for (int i = 0; i < n; ++i) d.at<double>(0, i) = dist[static_cast<std::size_t>(i)];
  fs << "distortion_coefficients" << d;
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
