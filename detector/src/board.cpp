#include "markerd/detector/board.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <utility>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "markerd/base/config_table.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/frame8.hpp"

namespace markerd::detector {
namespace {

struct Dictionary {
  std::string_view name;
  cv::aruco::PREDEFINED_DICTIONARY_NAME id;
};

constexpr std::array kDictionaries{
    Dictionary{"4x4_50", cv::aruco::DICT_4X4_50},
    Dictionary{"4x4_100", cv::aruco::DICT_4X4_100},
    Dictionary{"4x4_250", cv::aruco::DICT_4X4_250},
    Dictionary{"4x4_1000", cv::aruco::DICT_4X4_1000},
    Dictionary{"5x5_50", cv::aruco::DICT_5X5_50},
    Dictionary{"5x5_100", cv::aruco::DICT_5X5_100},
    Dictionary{"5x5_250", cv::aruco::DICT_5X5_250},
    Dictionary{"5x5_1000", cv::aruco::DICT_5X5_1000},
    Dictionary{"6x6_50", cv::aruco::DICT_6X6_50},
    Dictionary{"6x6_100", cv::aruco::DICT_6X6_100},
    Dictionary{"6x6_250", cv::aruco::DICT_6X6_250},
    Dictionary{"6x6_1000", cv::aruco::DICT_6X6_1000},
    Dictionary{"7x7_50", cv::aruco::DICT_7X7_50},
    Dictionary{"7x7_100", cv::aruco::DICT_7X7_100},
    Dictionary{"7x7_250", cv::aruco::DICT_7X7_250},
    Dictionary{"7x7_1000", cv::aruco::DICT_7X7_1000},
    Dictionary{"aruco_original", cv::aruco::DICT_ARUCO_ORIGINAL},
    Dictionary{"apriltag_16h5", cv::aruco::DICT_APRILTAG_16h5},
    Dictionary{"apriltag_25h9", cv::aruco::DICT_APRILTAG_25h9},
    Dictionary{"apriltag_36h10", cv::aruco::DICT_APRILTAG_36h10},
    Dictionary{"apriltag_36h11", cv::aruco::DICT_APRILTAG_36h11},
};

constexpr auto kDictionaryNames = [] {
  std::array<std::string_view, kDictionaries.size()> names{};
  for (std::size_t i = 0; i < names.size(); ++i) names[i] = kDictionaries[i].name;
  return names;
}();

std::optional<cv::aruco::PREDEFINED_DICTIONARY_NAME> dictionary_id(std::string_view name) {
  for (const auto& d : kDictionaries) {
    if (d.name == name) return d.id;
  }
  return std::nullopt;
}

cv::Ptr<cv::aruco::Dictionary> dictionary(std::string_view name) {
  const auto id = dictionary_id(name);
  if (!id) throw BoardError(fmt::format("unknown ArUco dictionary '{}'", name));
  return cv::aruco::getPredefinedDictionary(*id);
}

int charuco_marker_count(const BoardSpec& b) { return b.cols * b.rows / 2; }

constexpr int kMaxSide = 100;
constexpr double kMinSizeM = 0.001;
constexpr double kMaxSizeM = 1.0;

}  // namespace

std::optional<BoardProblem> board_problem(const BoardSpec& b) {
  // A chessboard of fewer squares has no inner corner to find in both
  // directions; a frame8 board may be a row of markers.
  const int least = b.type == BoardType::frame8 ? 1 : 3;
  for (const auto& [value, name] : {std::pair{b.cols, "cols"}, std::pair{b.rows, "rows"}}) {
    if (value < least || value > kMaxSide) {
      return BoardProblem{name, fmt::format("must be from {} to {} ({}), got {}", least, kMaxSide,
                                            b.type == BoardType::frame8 ? "markers" : "squares", value)};
    }
  }
  if (!(b.size_m >= kMinSizeM && b.size_m <= kMaxSizeM)) {
    return BoardProblem{"size_m", fmt::format("must be from {} to {} m, got {} m", kMinSizeM, kMaxSizeM, b.size_m)};
  }
  switch (b.type) {
    case BoardType::chessboard: break;
    case BoardType::charuco: {
      if (!(b.marker_size_m > 0 && b.marker_size_m < b.size_m)) {
        return BoardProblem{"marker_size_m", fmt::format("must be more than zero and less than the square ({} m), "
                                                         "got {} m",
                                                         b.size_m, b.marker_size_m)};
      }
      if (!dictionary_id(b.dictionary)) {
        return BoardProblem{
            "dictionary", fmt::format("must be one of {}, got '{}'", fmt::join(kDictionaryNames, ", "), b.dictionary)};
      }
      const int size = dictionary(b.dictionary)->bytesList.rows;
      if (charuco_marker_count(b) > size) {
        return BoardProblem{"dictionary", fmt::format("'{}' holds {} markers, a {}x{} ChArUco board needs {}",
                                                      b.dictionary, size, b.cols, b.rows, charuco_marker_count(b))};
      }
      break;
    }
    case BoardType::frame8: {
      if (b.cols * b.rows < 2) return BoardProblem{"cols", "a frame8 board needs at least 2 markers"};
      // A cell of paper at least between markers: touching, their rings
      // would run into one another.
      if (!(b.spacing_m >= b.size_m / frame8::grid && b.spacing_m <= b.size_m * 10)) {
        return BoardProblem{"spacing_m", fmt::format("must be from a tenth (a cell) to ten times the marker's size "
                                                     "({} to {} m), got {} m",
                                                     b.size_m / frame8::grid, b.size_m * 10, b.spacing_m)};
      }
      if (b.ids.size() != static_cast<std::size_t>(b.cols * b.rows)) {
        return BoardProblem{"ids", fmt::format("must give one id for each of the {}x{} markers ({}), got {}", b.cols,
                                               b.rows, b.cols * b.rows, b.ids.size())};
      }
      std::array<bool, 256> seen{};
      for (const int id : b.ids) {
        if (id < 0 || id > 255) return BoardProblem{"ids", fmt::format("id {} is not a frame8 id (0 to 255)", id)};
        if (frame8::near_uniform(id)) {
          return BoardProblem{"ids", fmt::format("id {} is near-uniform (0, 1, 126, 127, 128, 129, 254, 255): "
                                                 "read less far than the others, or not at all",
                                                 id)};
        }
        if (seen[static_cast<std::size_t>(id)]) return BoardProblem{"ids", fmt::format("id {} is given twice", id)};
        seen[static_cast<std::size_t>(id)] = true;
      }
      break;
    }
  }
  return std::nullopt;
}

namespace {

// ------------------------------------------------------------ the board file

BoardSpec parse_board(const ConfigTable& t) {
  BoardSpec b;
  const auto type = board_type_from_string(t.required<std::string>("type"));
  if (!type) t.fail("type", "must be \"chessboard\", \"charuco\" or \"frame8\"");
  b.type = *type;
  switch (b.type) {
    case BoardType::chessboard: t.allow_only({"type", "cols", "rows", "size_m"}); break;
    case BoardType::charuco: t.allow_only({"type", "cols", "rows", "size_m", "marker_size_m", "dictionary"}); break;
    case BoardType::frame8: t.allow_only({"type", "cols", "rows", "size_m", "spacing_m", "ids"}); break;
  }
  b.cols = t.required<int>("cols", {1, kMaxSide});
  b.rows = t.required<int>("rows", {1, kMaxSide});
  b.size_m = t.required<double>("size_m", {kMinSizeM, kMaxSizeM, "m"});
  if (b.type == BoardType::charuco) {
    b.marker_size_m = t.required<double>("marker_size_m", {0.0, kMaxSizeM, "m"});
    b.dictionary = t.required<std::string>("dictionary");
  }
  if (b.type == BoardType::frame8) {
    b.spacing_m = t.required<double>("spacing_m", {0.0, 10 * kMaxSizeM, "m"});
    const toml::array* ids = t.raw().get_as<toml::array>("ids");
    if (ids == nullptr) t.fail("ids", "must be a list of the markers' ids, row by row from the top left");
    for (const auto& node : *ids) {
      const auto id = node.value<std::int64_t>();
      if (!id || !node.is_integer()) t.fail("ids", "must be a list of whole numbers (frame8 ids, 0 to 255)");
      b.ids.push_back(static_cast<int>(std::clamp<std::int64_t>(*id, -1, 256)));
    }
  }
  if (const auto problem = board_problem(b)) t.fail(problem->field, problem->why);
  return b;
}

// ---------------------------------------------------------------- detection

cv::Mat as_mat(const GreyView& view) {
  // The detectors only read the pixels; the const_cast is for cv::Mat's constructor.
  return {view.height, view.width, CV_8UC1, const_cast<std::uint8_t*>(view.data),
          static_cast<std::size_t>(view.stride)};
}

// A chessboard's (or a ChArUco board's) inner corner k, counted row by row
// from the top left, as OpenCV numbers them.
Eigen::Vector3d inner_corner(const BoardSpec& b, int k) {
  const int per_row = b.cols - 1;
  const int col = k % per_row, row = k / per_row;  // whole squares
  return {(col + 1) * b.size_m, (row + 1) * b.size_m, 0.0};
}

}  // namespace

struct BoardDetector::Impl {
  BoardSpec board;
  cv::Ptr<cv::aruco::Dictionary> aruco;
  cv::Ptr<cv::aruco::CharucoBoard> charuco;
  cv::Ptr<cv::aruco::DetectorParameters> aruco_parameters;
  std::unique_ptr<MarkerDetector> frame8;
  std::array<int, 256> marker_of_id{};  // frame8: the board's marker of each id, -1 for none
  std::vector<Detection> detections;

  BoardPoints chessboard(const cv::Mat& image) const;
  BoardPoints charuco_points(const cv::Mat& image) const;
  void refine_charuco_corners(const cv::Mat& image, const std::vector<std::vector<cv::Point2f>>& marker_corners,
                              const std::vector<int>& marker_ids, std::vector<int>& ids,
                              std::vector<cv::Point2f>& corners) const;
  BoardPoints frame8_points(const GreyView& view);
};

BoardPoints BoardDetector::Impl::chessboard(const cv::Mat& image) const {
  std::vector<cv::Point2f> corners;
  // The sector-based detector (Duda and Frese), robust to blur, noise and
  // strong distortion; its own upsampled refinement (CALIB_CB_ACCURACY)
  // costs three times as long as cornerSubPix below, which refines as far.
  const int flags = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE;
  const cv::Size grid(board.cols - 1, board.rows - 1);
  if (!cv::findChessboardCornersSB(image, grid, corners, flags)) return {};
  // Each corner's window reaches 0.4 of the way to its nearest neighbour,
  // so that it holds no other corner.
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 40, 0.001);
  std::vector<cv::Point2f> refined = corners;
  for (std::size_t k = 0; k < corners.size(); ++k) {
    const int i = static_cast<int>(k) % grid.width, j = static_cast<int>(k) / grid.width;
    double nearest = 1e9;
    for (const auto& [di, dj] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}}) {
      if (i + di < 0 || i + di >= grid.width || j + dj < 0 || j + dj >= grid.height) continue;
      nearest =
          std::min(nearest, cv::norm(corners[static_cast<std::size_t>((j + dj) * grid.width + i + di)] - corners[k]));
    }
    const int half = std::clamp(static_cast<int>(0.4 * nearest), 2, 10);
    std::vector<cv::Point2f> one{corners[k]};
    cv::cornerSubPix(image, one, cv::Size(half, half), cv::Size(-1, -1), criteria);
    refined[k] = one[0];
  }
  BoardPoints points;
  for (std::size_t k = 0; k < refined.size(); ++k) {
    points.image.push_back({refined[k].x, refined[k].y});
    points.object.push_back(inner_corner(board, static_cast<int>(k)));
    points.index.push_back(static_cast<int>(k));
  }
  return points;
}

// OpenCV 4.6 refines a ChArUco corner with cornerSubPix under a dead zone
// as large as its window, which leaves the corner where the markers'
// homography put it: half a pixel off along each axis, as the markers'
// corners are (measured on rendered views). Each corner is refined here
// again, in a window that keeps clear of the markers beside it: the
// nearest marker corner lies on the diagonal, so the window's half side
// stays under its distance over the square root of 2. A corner with less
// room than a window of 2 px each way (a board seen at a grazing angle,
// its squares' white rims a pixel wide) is dropped: it was measured up to
// 2 px off there. So is one that the refinement moved out of its window.
void BoardDetector::Impl::refine_charuco_corners(const cv::Mat& image,
                                                 const std::vector<std::vector<cv::Point2f>>& marker_corners,
                                                 const std::vector<int>& marker_ids, std::vector<int>& ids,
                                                 std::vector<cv::Point2f>& corners) const {
  constexpr int kLeastHalf = 2;
  constexpr int kMostHalf = 10;
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 40, 0.001);
  std::size_t kept = 0;
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const auto id = static_cast<std::size_t>(ids[k]);
    double nearest = 1e9;
    for (std::size_t j = 0; j < charuco->nearestMarkerIdx[id].size(); ++j) {
      const int marker = charuco->ids[static_cast<std::size_t>(charuco->nearestMarkerIdx[id][j])];
      const auto it = std::find(marker_ids.begin(), marker_ids.end(), marker);
      if (it == marker_ids.end()) continue;
      const auto& quad = marker_corners[static_cast<std::size_t>(it - marker_ids.begin())];
      nearest = std::min(nearest,
                         cv::norm(quad[static_cast<std::size_t>(charuco->nearestMarkerCorners[id][j])] - corners[k]));
    }
    const int room = static_cast<int>(nearest / std::sqrt(2.0) - 1.5);
    if (room < kLeastHalf) continue;
    const int half = std::min(room, kMostHalf);
    const cv::Point2f start = corners[k];
    // The window must lie within the image.
    if (start.x < half + 1 || start.y < half + 1 || start.x > image.cols - half - 2 ||
        start.y > image.rows - half - 2) {
      continue;
    }
    std::vector<cv::Point2f> one{start};
    cv::cornerSubPix(image, one, cv::Size(half, half), cv::Size(-1, -1), criteria);
    if (std::abs(one[0].x - start.x) > half || std::abs(one[0].y - start.y) > half) continue;
    corners[kept] = one[0];
    ids[kept] = ids[k];
    ++kept;
  }
  corners.resize(kept);
  ids.resize(kept);
}

BoardPoints BoardDetector::Impl::charuco_points(const cv::Mat& image) const {
  std::vector<std::vector<cv::Point2f>> marker_corners, rejected;
  std::vector<int> marker_ids;
  cv::aruco::detectMarkers(image, aruco, marker_corners, marker_ids, aruco_parameters, rejected);
  if (marker_ids.empty()) return {};
  // Markers missed at first, looked for again where the board says they are.
  const cv::Ptr<cv::aruco::Board> as_board = charuco;
  cv::aruco::refineDetectedMarkers(image, as_board, marker_corners, marker_ids, rejected);
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  // Each corner from the markers on both sides of it (minMarkers 2): one
  // misread marker places no corner.
  cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, image, charuco, corners, ids, cv::noArray(),
                                       cv::noArray(), 2);
  refine_charuco_corners(image, marker_corners, marker_ids, ids, corners);
  BoardPoints points;
  for (std::size_t k = 0; k < ids.size(); ++k) {
    points.image.push_back({corners[k].x, corners[k].y});
    points.object.push_back(inner_corner(board, ids[k]));
    points.index.push_back(ids[k]);
  }
  return points;
}

BoardPoints BoardDetector::Impl::frame8_points(const GreyView& view) {
  frame8->detect(view, detections);
  std::array<int, 256> seen{};
  for (const Detection& d : detections) {
    if (d.id >= 0 && d.id < 256) ++seen[static_cast<std::size_t>(d.id)];
  }
  BoardPoints points;
  const double pitch = board.size_m + board.spacing_m;
  for (const Detection& d : detections) {
    // A marker whose white corner was hidden may be turned a quarter: its
    // corners would pair with the wrong board points.
    if (d.id < 0 || d.id >= 256 || seen[static_cast<std::size_t>(d.id)] != 1 || d.orientation_ambiguous) continue;
    const int marker = marker_of_id[static_cast<std::size_t>(d.id)];
    if (marker < 0 || !d.inner_corners) continue;
    // The hole's corners, which the detector measures: the outer ones it
    // extrapolates from them as if the lens were distortion-free, which
    // places them outwards under a barrel lens, most at the image's edges
    // (measured on rendered views: 0.1 px, the focal length 0.15% short).
    const double in = frame8::line_inner * board.size_m / frame8::grid;
    const int col = marker % board.cols, row = marker / board.cols;  // whole markers
    const double x0 = col * pitch + in, y0 = row * pitch + in;
    const double side = board.size_m - 2 * in;
    const std::array<Eigen::Vector3d, 4> corners{Eigen::Vector3d(x0, y0, 0), Eigen::Vector3d(x0 + side, y0, 0),
                                                 Eigen::Vector3d(x0 + side, y0 + side, 0),
                                                 Eigen::Vector3d(x0, y0 + side, 0)};
    for (std::size_t k = 0; k < 4; ++k) {
      points.image.push_back((*d.inner_corners)[k]);
      points.object.push_back(corners[k]);
      points.index.push_back(marker * 4 + static_cast<int>(k));
    }
  }
  return points;
}

BoardDetector::BoardDetector(BoardSpec board) : impl_(std::make_unique<Impl>()) {
  check_board(board);
  impl_->board = std::move(board);
  const BoardSpec& b = impl_->board;
  switch (b.type) {
    case BoardType::chessboard: break;
    case BoardType::charuco: {
      impl_->aruco = dictionary(b.dictionary);
      impl_->charuco = cv::aruco::CharucoBoard::create(b.cols, b.rows, static_cast<float>(b.size_m),
                                                       static_cast<float>(b.marker_size_m), impl_->aruco);
      impl_->aruco_parameters = cv::aruco::DetectorParameters::create();
      // The board's corners are numbered here as OpenCV numbers them: a
      // version that numbered them otherwise would pair wrong points.
      const auto& corners = impl_->charuco->chessboardCorners;
      for (std::size_t k = 0; k < corners.size(); ++k) {
        const Eigen::Vector3d p = inner_corner(b, static_cast<int>(k));
        if (std::abs(corners[k].x - p.x()) > 1e-6 || std::abs(corners[k].y - p.y()) > 1e-6) {
          throw std::logic_error("ChArUco: OpenCV numbers the board's corners otherwise than expected");
        }
      }
      break;
    }
    case BoardType::frame8: {
      DetectorConfig config;
      config.family = Family::frame8;
      // A board is a flat print with its holes printed white.
      config.frame8.mounting = Mounting::paper;
      impl_->frame8 = make_detector(config);
      impl_->marker_of_id.fill(-1);
      for (std::size_t k = 0; k < b.ids.size(); ++k) {
        impl_->marker_of_id[static_cast<std::size_t>(b.ids[k])] = static_cast<int>(k);
      }
      break;
    }
  }
}

BoardDetector::~BoardDetector() = default;

const BoardSpec& BoardDetector::board() const { return impl_->board; }

BoardPoints BoardDetector::detect(const GreyView& image) {
  if (image.empty()) throw BoardError("an empty image");
  switch (impl_->board.type) {
    case BoardType::chessboard: return impl_->chessboard(as_mat(image));
    case BoardType::charuco: return impl_->charuco_points(as_mat(image));
    case BoardType::frame8: return impl_->frame8_points(image);
  }
  return {};
}

// ------------------------------------------------------------------ the spec

std::string_view to_string(BoardType type) {
  switch (type) {
    case BoardType::chessboard: return "chessboard";
    case BoardType::charuco: return "charuco";
    case BoardType::frame8: return "frame8";
  }
  return "unknown";
}

std::optional<BoardType> board_type_from_string(std::string_view name) {
  for (const BoardType t : {BoardType::chessboard, BoardType::charuco, BoardType::frame8}) {
    if (to_string(t) == name) return t;
  }
  return std::nullopt;
}

double BoardSpec::width_m() const {
  return type == BoardType::frame8 ? cols * size_m + (cols - 1) * spacing_m : cols * size_m;
}

double BoardSpec::height_m() const {
  return type == BoardType::frame8 ? rows * size_m + (rows - 1) * spacing_m : rows * size_m;
}

int BoardSpec::point_count() const { return type == BoardType::frame8 ? 4 * cols * rows : (cols - 1) * (rows - 1); }

std::span<const std::string_view> dictionary_names() { return kDictionaryNames; }

std::vector<int> frame8_board_ids(int first_id, int count) {
  std::vector<int> ids;
  for (int id = std::max(first_id, 0); id < 256 && static_cast<int>(ids.size()) < count; ++id) {
    if (!frame8::near_uniform(id)) ids.push_back(id);
  }
  return ids;
}

void check_board(const BoardSpec& board) {
  if (const auto problem = board_problem(board)) {
    throw BoardError(fmt::format("{} board: {} {}", to_string(board.type), problem->field, problem->why));
  }
}

BoardSpec load_board(const std::filesystem::path& path) {
  try {
    return parse_board(ConfigTable::load_file(path));
  } catch (const ConfigError& e) {
    throw BoardError(e.what());
  }
}

std::string board_file_text(const BoardSpec& b) {
  check_board(b);
  std::string text = fmt::format(
      "# A calibration board, as `markerctl marker --board` printed it: markerctl\n"
      "# calibrate --board FILE reads it (docs/calibration.md). Lengths in metres.\n"
      "# Measure the print: where the printer scaled it, write what the ruler says.\n"
      "type = \"{}\"\ncols = {}\nrows = {}\n",
      to_string(b.type), b.cols, b.rows);
  switch (b.type) {
    case BoardType::chessboard: text += fmt::format("size_m = {}  # a square's side\n", b.size_m); break;
    case BoardType::charuco:
      text += fmt::format(
          "size_m = {}  # a square's side\nmarker_size_m = {}  # an ArUco marker's side\ndictionary = \"{}\"\n",
          b.size_m, b.marker_size_m, b.dictionary);
      break;
    case BoardType::frame8:
      text += fmt::format(
          "size_m = {}  # a marker's outer edge\nspacing_m = {}  # paper between markers\n"
          "ids = [{}]  # row by row from the top left\n",
          b.size_m, b.spacing_m, fmt::join(b.ids, ", "));
      break;
  }
  return text;
}

void save_board(const BoardSpec& board, const std::filesystem::path& path) {
  const std::string text = board_file_text(board);
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw BoardError(fmt::format("{}: cannot open for writing: {}", path.string(), errno_text(errno)));
  f << text;
  f.close();
  if (!f) throw BoardError(fmt::format("{}: write failed: {}", path.string(), errno_text(errno)));
}

std::vector<InkRect> board_ink(const BoardSpec& b) {
  check_board(b);
  std::vector<InkRect> ink;
  const double s = b.size_m;
  switch (b.type) {
    case BoardType::chessboard:
      for (int j = 0; j < b.rows; ++j) {
        for (int i = 0; i < b.cols; ++i) {
          if ((i + j) % 2 == 0) ink.push_back({i * s, j * s, s, s});
        }
      }
      break;
    case BoardType::charuco: {
      // Where OpenCV places each marker (its white squares) is taken from
      // its board; the positions themselves are computed here in double.
      const auto dict = dictionary(b.dictionary);
      const auto board = cv::aruco::CharucoBoard::create(b.cols, b.rows, static_cast<float>(s),
                                                         static_cast<float>(b.marker_size_m), dict);
      std::vector<bool> white(static_cast<std::size_t>(b.cols * b.rows), false);
      const int cells = dict->markerSize + 2;  // the code and its black border
      const double cell = b.marker_size_m / cells;
      for (std::size_t k = 0; k < board->ids.size(); ++k) {
        const auto& c = board->objPoints[k];
        const int i = static_cast<int>(std::floor((c[0].x + c[2].x) / 2 / s));
        const int j = static_cast<int>(std::floor((c[0].y + c[2].y) / 2 / s));
        white[static_cast<std::size_t>(j * b.cols + i)] = true;
        cv::Mat bits;
        cv::aruco::drawMarker(dict, board->ids[k], cells, bits, 1);  // one pixel a cell
        const double x0 = i * s + (s - b.marker_size_m) / 2, y0 = j * s + (s - b.marker_size_m) / 2;
        for (int r = 0; r < cells; ++r) {
          for (int q = 0; q < cells; ++q) {
            if (bits.at<std::uint8_t>(r, q) < 128) ink.push_back({x0 + q * cell, y0 + r * cell, cell, cell});
          }
        }
      }
      for (int j = 0; j < b.rows; ++j) {
        for (int i = 0; i < b.cols; ++i) {
          if (!white[static_cast<std::size_t>(j * b.cols + i)]) ink.push_back({i * s, j * s, s, s});
        }
      }
      break;
    }
    case BoardType::frame8: {
      const double cell = s / frame8::grid, pitch = s + b.spacing_m;
      const double lo = frame8::line_outer * cell, width = (frame8::line_inner - frame8::line_outer) * cell;
      for (std::size_t m = 0; m < b.ids.size(); ++m) {
        const std::size_t col = m % static_cast<std::size_t>(b.cols), row = m / static_cast<std::size_t>(b.cols);
        const double x0 = static_cast<double>(col) * pitch, y0 = static_cast<double>(row) * pitch;
        const auto cells = frame8::ring_cells(b.ids[m]);
        for (int r = 0; r < frame8::grid; ++r) {
          for (int q = 0; q < frame8::grid; ++q) {
            if (cells[static_cast<std::size_t>(r * frame8::grid + q)] == 0) {
              ink.push_back({x0 + q * cell, y0 + r * cell, cell, cell});
            }
          }
        }
        // The line, 1.0 to 1.5 cells in, as four bars; the hole is paper.
        const double inner = s - 2 * lo;
        ink.push_back({x0 + lo, y0 + lo, inner, width});
        ink.push_back({x0 + lo, y0 + s - lo - width, inner, width});
        ink.push_back({x0 + lo, y0 + lo, width, inner});
        ink.push_back({x0 + s - lo - width, y0 + lo, width, inner});
      }
      break;
    }
  }
  return ink;
}

}  // namespace markerd::detector
