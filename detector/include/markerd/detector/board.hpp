#pragma once
// Calibration boards: a chessboard, a ChArUco board and a board of frame8
// markers. What a board is (its geometry, also as the small TOML board file
// `markerctl marker --board` writes beside its print), the ink to print it
// with, and where its points lie in an image (docs/calibration.md).
//
// The board frame is OpenCV's: its origin at the pattern's top-left corner
// (the outer corner of the first square, or of the first marker), x to the
// right along the print, y down it, z into it, in metres. A board's points
// are a chessboard's inner corners, a ChArUco board's chessboard corners
// (OpenCV's numbering), or the four corners of each frame8 marker's hole (the inner
// edge of its line, what the detector measures).

#include <Eigen/Core>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/detector/geometry.hpp"
#include "markerd/detector/image.hpp"

namespace markerd::detector {

class BoardError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class BoardType { chessboard, charuco, frame8 };

std::string_view to_string(BoardType type);
std::optional<BoardType> board_type_from_string(std::string_view name);

struct BoardSpec {
  BoardType type = BoardType::chessboard;
  int cols = 0;  // squares across (chessboard, charuco) or markers (frame8)
  int rows = 0;  // squares or markers down
  // A square's side (chessboard, charuco) or a frame8 marker's outer edge.
  double size_m = 0;
  double marker_size_m = 0;  // charuco: the ArUco marker in each white square
  double spacing_m = 0;      // frame8: the paper between neighbouring markers
  std::string dictionary;    // charuco: the ArUco dictionary, as dictionary_names() spells it
  std::vector<int> ids;      // frame8: the markers' ids, row by row from the top left

  // The pattern's extent (without the paper round it).
  [[nodiscard]] double width_m() const;
  [[nodiscard]] double height_m() const;
  // How many points the board has (see above).
  [[nodiscard]] int point_count() const;
};

// What a board's options leave out, as `markerctl marker --board` and
// `markerctl calibrate` fill it in: a ChArUco marker 0.6 of its square,
// frame8 markers a quarter of their size apart, the dictionary 4x4_50.
// A ChArUco corner is refined in a window clear of the markers beside it:
// at 0.75 of the square (a common layout) the white rim round a marker
// left tilted views a window of 2 px or less each way, and their corners
// were dropped or measured up to 2 px off; at 0.6 the rendered views'
// corners were found 0.045 px from the truth on average, against 0.068.
inline constexpr double kDefaultCharucoMarkerShare = 0.6;
inline constexpr double kDefaultFrame8SpacingShare = 0.25;
inline constexpr std::string_view kDefaultDictionary = "4x4_50";

// The ArUco dictionaries a ChArUco board may use: 4x4_50 .. 7x7_1000,
// aruco_original, apriltag_16h5, apriltag_25h9, apriltag_36h10, apriltag_36h11.
std::span<const std::string_view> dictionary_names();

// `count` frame8 ids from `first_id` up, leaving out the near-uniform ones
// (frame8::near_uniform: read less far, and mimicked by tiles); fewer when
// the ids run out before 256.
std::vector<int> frame8_board_ids(int first_id, int count);

// The first rule of a board that `board` breaks: the field ("marker_size_m",
// as the board file names it) and why; nothing when it is a board.
struct BoardProblem {
  std::string field;
  std::string why;
};
std::optional<BoardProblem> board_problem(const BoardSpec& board);
// Throws BoardError naming the field that is wrong and why.
void check_board(const BoardSpec& board);

// The board file: TOML, lengths in metres. Reading checks it whole, and an
// error names the file, the line and the key.
BoardSpec load_board(const std::filesystem::path& path);
std::string board_file_text(const BoardSpec& board);
void save_board(const BoardSpec& board, const std::filesystem::path& path);

// What is printed: axis-aligned black rectangles in the board frame
// (metres; they may touch or overlap), paper elsewhere.
struct InkRect {
  double x = 0;  // left edge
  double y = 0;  // top edge
  double width = 0;
  double height = 0;
};
std::vector<InkRect> board_ink(const BoardSpec& board);

// The board's points seen in one image, in step: the pixel (sub-pixel,
// pixel centres at integers) and the board-frame point (z = 0) of each,
// with its index on the board (0 .. point_count() - 1).
struct BoardPoints {
  std::vector<Point2> image;
  std::vector<Eigen::Vector3d> object;
  std::vector<int> index;
};

// Finds a board in images. A chessboard is found whole or not at
// (cv::findChessboardCornersSB); a ChArUco board and a frame8 board may be
// partly in view or hidden, and give the points of what is seen (ChArUco
// corners between two detected markers; the corners of each frame8 marker
// read with a board id, an id read twice in one image giving none).
// Not thread-safe.
class BoardDetector {
 public:
  explicit BoardDetector(BoardSpec board);  // checks it first
  ~BoardDetector();
  BoardDetector(const BoardDetector&) = delete;
  BoardDetector& operator=(const BoardDetector&) = delete;

  [[nodiscard]] const BoardSpec& board() const;
  // Empty when the board is not found.
  [[nodiscard]] BoardPoints detect(const GreyView& image);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace markerd::detector
