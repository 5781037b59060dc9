#pragma once
// The options that say which calibration board, shared by `markerctl
// marker --board` (which prints it) and `markerctl calibrate` (which finds
// it), so that the same words print and read the same board.

#include <string>

#include "markerd/detector/board.hpp"

namespace CLI {
class App;
class Option;
}  // namespace CLI

namespace markerctl {

struct BoardOptions {
  std::string board;  // COLSxROWS, or (where a file is allowed) a board file
  std::string type = "chessboard";
  std::string size;  // marker: its own --size option; calibrate: added here
  std::string marker_size;
  std::string spacing;
  std::string dictionary;
  int first_id = 0;
  // What the command line gave, for the rules between options.
  CLI::Option* type_option = nullptr;
  CLI::Option* size_option = nullptr;
  CLI::Option* marker_size_option = nullptr;
  CLI::Option* spacing_option = nullptr;
  CLI::Option* dictionary_option = nullptr;
  CLI::Option* first_id_option = nullptr;
};

// Adds --board (with its help and type name), --board-type, --marker-size,
// --spacing, --dictionary and --first-id to `app`; the caller adds --size,
// whose help differs, and stores it in size_option.
void add_board_options(CLI::App* app, BoardOptions& o, const std::string& board_help, const std::string& board_type);

// The board the options describe. With `file_allowed`, --board may name a
// board file instead of COLSxROWS; the geometry is then the file's, and
// geometry options beside it are refused. Usage errors name the option.
markerd::detector::BoardSpec board_from_options(const BoardOptions& o, bool file_allowed);

// "chessboard 9x6, square 25 mm" and the like, for a command's output.
std::string describe_board(const markerd::detector::BoardSpec& board);

}  // namespace markerctl
