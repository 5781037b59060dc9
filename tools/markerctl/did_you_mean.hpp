#pragma once
// What main() says when a command line names a command or an option that
// markerctl does not have: which word, where, and the names it has that are
// nearest to it ("markerctl markr" -> did you mean 'marker'?). CLI11 alone
// reports the first rule broken, which for a mistyped option is often a
// required option it then misses ("--id is required" for "--sise 80mm").

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace CLI {
class App;
}

namespace markerctl {

struct UnknownName {
  std::string command;  // the command it was given to: "sweep", "rig move", "" for markerctl itself
  bool is_option = false;
  std::string name;                      // as typed, without "=value": "statsu", "--sise"
  std::vector<std::string> suggestions;  // the nearest names, best first; empty when none is near
};

// The first word of `args` (argv without the program's name) that names no
// command or option where it stands, walking the commands as CLI11 does;
// nothing when every word is known (the error is then another: CLI11's own).
std::optional<UnknownName> find_unknown_name(const CLI::App& app, const std::vector<std::string>& args);

// "unknown command 'markr'; did you mean 'marker'?"
std::string describe(const UnknownName& unknown);

// Optimal string alignment distance: insertions, deletions, substitutions and
// swaps of neighbours count one each (so "statsu" is one from "status").
std::size_t edit_distance(std::string_view a, std::string_view b);

// The names nearest `typed` that are near enough to be what was meant: at
// most two edits, and fewer than half the name's letters (so that "xy" does
// not suggest "rig"), those at the smallest distance, in `names`' order.
std::vector<std::string> nearest_names(std::string_view typed, const std::vector<std::string>& names);

}  // namespace markerctl
