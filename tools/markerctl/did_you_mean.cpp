#include "did_you_mean.hpp"

// CLI11 before <string> (main.cpp says why).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include <fmt/format.h>

#include <algorithm>
#include <numeric>

namespace markerctl {
namespace {

bool has_positionals(const CLI::App& app) {
  return !app.get_options([](const CLI::Option* o) { return !o->nonpositional(); }).empty();
}

const CLI::App* subcommand_named(const CLI::App& app, std::string_view name) {
  for (const CLI::App* sub : app.get_subcommands({})) {
    if (sub->get_name() == name) return sub;
    const auto& aliases = sub->get_aliases();
    if (std::find(aliases.begin(), aliases.end(), name) != aliases.end()) return sub;
  }
  return nullptr;
}

// An option of `app`, or of a parent it falls through to (markerctl rig
// status --config FILE), as CLI11 looks for it.
const CLI::Option* option_named(const CLI::App* app, const std::string& name) {
  for (; app != nullptr; app = app->get_fallthrough() ? app->get_parent() : nullptr) {
    if (const CLI::Option* option = app->get_option_no_throw(name)) return option;
  }
  return nullptr;
}

std::vector<std::string> long_option_names(const CLI::App* app) {
  std::vector<std::string> names;
  for (; app != nullptr; app = app->get_fallthrough() ? app->get_parent() : nullptr) {
    for (const CLI::Option* option : app->get_options()) {
      for (const std::string& name : option->get_lnames()) names.push_back("--" + name);
    }
  }
  return names;
}

std::string command_path(const CLI::App* app) {
  std::string path;
  for (; app != nullptr && app->get_parent() != nullptr; app = app->get_parent()) {
    path = path.empty() ? app->get_name() : app->get_name() + " " + path;
  }
  return path;
}

}  // namespace

std::size_t edit_distance(std::string_view a, std::string_view b) {
  // Three rows of the dynamic programme: the swap looks two rows back.
  std::vector<std::size_t> before(b.size() + 1);
  std::vector<std::size_t> previous(b.size() + 1);
  std::vector<std::size_t> current(b.size() + 1);
  std::iota(previous.begin(), previous.end(), std::size_t{0});
  for (std::size_t i = 1; i <= a.size(); ++i) {
    current[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t substitution = previous[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1);
      current[j] = std::min({previous[j] + 1, current[j - 1] + 1, substitution});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) {
        current[j] = std::min(current[j], before[j - 2] + 1);
      }
    }
    std::swap(before, previous);
    std::swap(previous, current);
  }
  return previous[b.size()];
}

std::vector<std::string> nearest_names(std::string_view typed, const std::vector<std::string>& names) {
  // Options are compared without their dashes: "-size" is one edit from
  // "--size", not two.
  const auto bare = [](std::string_view s) {
    while (s.starts_with('-')) s.remove_prefix(1);
    return s;
  };
  std::vector<std::string> nearest;
  std::size_t best = 2;
  for (const std::string& name : names) {
    const std::size_t d = edit_distance(bare(typed), bare(name));
    if (d > 2 || 2 * d >= bare(name).size() || d > best) continue;
    if (d < best) nearest.clear();
    best = d;
    if (std::find(nearest.begin(), nearest.end(), name) == nearest.end()) nearest.push_back(name);
  }
  return nearest;
}

std::optional<UnknownName> find_unknown_name(const CLI::App& app, const std::vector<std::string>& args) {
  const CLI::App* at = &app;
  bool positional_taken = false;  // a positional of `at` was given: later words are its values
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& word = args[i];
    if (word == "--") return std::nullopt;  // what follows is positional
    if (word.size() > 1 && word.front() == '-' && !std::isdigit(static_cast<unsigned char>(word[1]))) {
      const bool long_name = word.starts_with("--");
      const std::size_t equals = word.find('=');
      // "-ofile" and "-vq" are short names with a value or more flags: the
      // first letter is the option.
      const std::string name = long_name ? word.substr(0, equals) : word.substr(0, 2);
      const CLI::Option* option = option_named(at, name);
      if (option == nullptr) {
        return UnknownName{command_path(at), true, name,
                           long_name ? nearest_names(name, long_option_names(at)) : std::vector<std::string>{}};
      }
      const bool value_attached = long_name ? equals != std::string::npos : word.size() > 2;
      if (option->get_items_expected_max() > 0 && !value_attached) ++i;
      continue;
    }
    if (!positional_taken) {
      if (const CLI::App* sub = subcommand_named(*at, word)) {
        at = sub;
        continue;
      }
      if (!has_positionals(*at)) {
        std::vector<std::string> names;
        for (const CLI::App* sub : at->get_subcommands({})) names.push_back(sub->get_name());
        if (names.empty()) return std::nullopt;  // an extra argument: CLI11 says so
        return UnknownName{command_path(at), false, word, nearest_names(word, names)};
      }
    }
    positional_taken = true;
  }
  return std::nullopt;
}

std::string describe(const UnknownName& unknown) {
  std::string text = fmt::format("unknown {} '{}'", unknown.is_option ? "option" : "command", unknown.name);
  if (unknown.suggestions.empty()) return text;
  text += "; did you mean ";
  for (std::size_t i = 0; i < unknown.suggestions.size(); ++i) {
    if (i > 0) text += i + 1 == unknown.suggestions.size() ? " or " : ", ";
    text += fmt::format("'{}'", unknown.suggestions[i]);
  }
  return text + "?";
}

}  // namespace markerctl
