#include "board_options.hpp"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <charconv>
#include <cmath>
#include <filesystem>

#include "common.hpp"

namespace markerctl {
namespace {

using markerd::detector::BoardSpec;
using markerd::detector::BoardType;

bool given(const CLI::Option* option) { return option != nullptr && option->count() > 0; }

// "9x6" as 9 and 6; nothing when the text is not two whole numbers with an x between.
std::optional<std::pair<int, int>> parse_cols_rows(const std::string& text) {
  const std::size_t x = text.find_first_of("xX");
  if (x == std::string::npos || x == 0 || x + 1 == text.size()) return std::nullopt;
  int cols = 0, rows = 0;
  const char* begin = text.data();
  const char* end = begin + text.size();
  const auto [after_cols, ec1] = std::from_chars(begin, begin + x, cols);
  const auto [after_rows, ec2] = std::from_chars(begin + x + 1, end, rows);
  if (ec1 != std::errc{} || ec2 != std::errc{} || after_cols != begin + x || after_rows != end) return std::nullopt;
  return std::pair{cols, rows};
}

// A length from the command line in metres, to the nanometre: 36mm is 0.036
// in the board file, not 36 * 0.001 = 0.036000000000000004.
double board_length_m(const std::string& text, std::string_view option) {
  return std::round(parse_length_m(text, BareUnit::millimetre, option) * 1e9) / 1e9;
}

std::string board_name(BoardType type) {
  switch (type) {
    case BoardType::chessboard: return "a chessboard";
    case BoardType::charuco: return "a ChArUco board";
    case BoardType::frame8: return "a frame8 board";
  }
  return "a board";
}

// "2-13" or "124-125,130-132": ids as runs.
std::string id_runs(const std::vector<int>& ids) {
  std::string text;
  for (std::size_t i = 0; i < ids.size();) {
    std::size_t j = i;
    while (j + 1 < ids.size() && ids[j + 1] == ids[j] + 1) ++j;
    text += fmt::format("{}{}", text.empty() ? "" : ",",
                        j == i ? std::to_string(ids[i]) : fmt::format("{}-{}", ids[i], ids[j]));
    i = j + 1;
  }
  return text;
}

// The option that sets each field of a board, for errors.
std::string option_of(const std::string& field) {
  if (field == "cols" || field == "rows") return "--board";
  if (field == "size_m") return "--size";
  if (field == "marker_size_m") return "--marker-size";
  if (field == "spacing_m") return "--spacing";
  if (field == "dictionary") return "--dictionary";
  if (field == "ids") return "--first-id";
  return "--board";
}

// What a board problem says about a field, said of its option: lengths in
// millimetres, as the options are mostly given.
std::string board_problem_text(const BoardSpec& b, const markerd::detector::BoardProblem& p) {
  if (p.field == "size_m") return fmt::format("must be from 1 mm to 1 m, got {:g} mm", b.size_m * 1e3);
  if (p.field == "marker_size_m") {
    return fmt::format("must be more than zero and less than --size ({:g} mm), got {:g} mm", b.size_m * 1e3,
                       b.marker_size_m * 1e3);
  }
  if (p.field == "spacing_m") {
    return fmt::format("must be from a tenth (a cell) to ten times the marker's size ({:g} to {:g} mm), got {:g} mm",
                       b.size_m * 1e2, b.size_m * 1e4, b.spacing_m * 1e3);
  }
  return p.why;
}

}  // namespace

void add_board_options(CLI::App* app, BoardOptions& o, const std::string& board_help, const std::string& board_type) {
  app->add_option("--board", o.board, board_help)->type_name(board_type);
  o.type_option = app->add_option("--board-type", o.type, "Calibration board: chessboard, charuco or frame8")
                      ->type_name("TYPE")
                      ->check(CLI::IsMember({"chessboard", "charuco", "frame8"}))
                      ->capture_default_str();
  o.marker_size_option =
      app->add_option("--marker-size", o.marker_size,
                      fmt::format("charuco: the ArUco marker's side (default {:g} of --size; a bare number is mm)",
                                  markerd::detector::kDefaultCharucoMarkerShare))
          ->type_name("LENGTH");
  o.spacing_option = app->add_option("--spacing", o.spacing,
                                     fmt::format("frame8: paper between markers (default {:g} of --size; a bare "
                                                 "number is mm)",
                                                 markerd::detector::kDefaultFrame8SpacingShare))
                         ->type_name("LENGTH");
  o.dictionary_option =
      app->add_option("--dictionary", o.dictionary,
                      fmt::format("charuco: the ArUco dictionary (default {})", markerd::detector::kDefaultDictionary))
          ->type_name("NAME")
          ->check(CLI::IsMember(std::vector<std::string>(markerd::detector::dictionary_names().begin(),
                                                         markerd::detector::dictionary_names().end())));
  o.first_id_option = app->add_option("--first-id", o.first_id,
                                      "frame8: the first marker's id; the others follow, leaving out the "
                                      "near-uniform ones")
                          ->capture_default_str()
                          ->check(CLI::Range(0, 255));
}

BoardSpec board_from_options(const BoardOptions& o, bool file_allowed) {
  const auto cols_rows = parse_cols_rows(o.board);
  if (!cols_rows) {
    if (!file_allowed) {
      throw usage_error("--board", fmt::format("'{}' is not COLSxROWS (for example 9x6)", o.board));
    }
    std::error_code ec;
    if (!std::filesystem::exists(o.board, ec)) {
      throw usage_error("--board",
                        fmt::format("'{}' is neither COLSxROWS (for example 9x6) nor a board file", o.board));
    }
    BoardSpec board;
    try {
      board = markerd::detector::load_board(o.board);
    } catch (const markerd::detector::BoardError& e) {
      throw runtime_error("--board", e.what());
    }
    for (const CLI::Option* option :
         {o.size_option, o.marker_size_option, o.spacing_option, o.dictionary_option, o.first_id_option}) {
      if (given(option)) {
        throw usage_error(option->get_name(), fmt::format("the board file {} gives the board's geometry", o.board));
      }
    }
    if (given(o.type_option) && o.type != to_string(board.type)) {
      throw usage_error("--board-type", fmt::format("'{}', but the board file {} is a {} board", o.type, o.board,
                                                    to_string(board.type)));
    }
    return board;
  }

  BoardSpec b;
  b.type = *markerd::detector::board_type_from_string(o.type);
  b.cols = cols_rows->first;
  b.rows = cols_rows->second;
  if (o.size.empty()) {
    throw usage_error("--size", fmt::format("{} needs the size of its {} (for example --size 25mm)", board_name(b.type),
                                            b.type == BoardType::frame8 ? "markers" : "squares"));
  }
  b.size_m = board_length_m(o.size, "--size");
  const auto only_for = [&](const CLI::Option* option, BoardType type) {
    if (given(option) && b.type != type) {
      throw usage_error(option->get_name(), fmt::format("is for {}, not {}", board_name(type), board_name(b.type)));
    }
  };
  only_for(o.marker_size_option, BoardType::charuco);
  only_for(o.dictionary_option, BoardType::charuco);
  only_for(o.spacing_option, BoardType::frame8);
  only_for(o.first_id_option, BoardType::frame8);
  if (b.type == BoardType::charuco) {
    b.marker_size_m = o.marker_size.empty()
                          ? std::round(b.size_m * markerd::detector::kDefaultCharucoMarkerShare * 1e9) / 1e9
                          : board_length_m(o.marker_size, "--marker-size");
    b.dictionary = o.dictionary.empty() ? std::string(markerd::detector::kDefaultDictionary) : o.dictionary;
  }
  if (b.type == BoardType::frame8) {
    b.spacing_m = o.spacing.empty() ? std::round(b.size_m * markerd::detector::kDefaultFrame8SpacingShare * 1e9) / 1e9
                                    : board_length_m(o.spacing, "--spacing");
    const int count = b.cols * b.rows;
    b.ids = markerd::detector::frame8_board_ids(o.first_id, count);
    if (static_cast<int>(b.ids.size()) < count && b.cols >= 1 && b.rows >= 1) {
      throw usage_error("--first-id", fmt::format("a {}x{} board needs {} ids; from {} up there are {} that are not "
                                                  "near-uniform",
                                                  b.cols, b.rows, count, o.first_id, b.ids.size()));
    }
  }
  if (const auto problem = markerd::detector::board_problem(b)) {
    throw usage_error(option_of(problem->field), board_problem_text(b, *problem));
  }
  return b;
}

std::string describe_board(const BoardSpec& b) {
  std::string text = fmt::format("{} {}x{}", to_string(b.type), b.cols, b.rows);
  switch (b.type) {
    case BoardType::chessboard: return text + fmt::format(", square {:g} mm", b.size_m * 1e3);
    case BoardType::charuco:
      return text +
             fmt::format(", square {:g} mm, marker {:g} mm, {}", b.size_m * 1e3, b.marker_size_m * 1e3, b.dictionary);
    case BoardType::frame8:
      return text + fmt::format(", marker {:g} mm, spacing {:g} mm, ids {}", b.size_m * 1e3, b.spacing_m * 1e3,
                                id_runs(b.ids));
  }
  return text;
}

}  // namespace markerctl
