// markerctl's helpers as functions (tools/markerctl/): the names suggested
// for a mistyped command or option, and live lines fitted to a terminal's
// width. The real binary's messages are test_markerctl.cpp's; its live lines
// on an 80-column terminal test_markerctl_rig.cpp's and test_control_streams.cpp's.

#include <gtest/gtest.h>

#include <string>
#include <vector>

// CLI11 before anything else that includes <string> (tools/markerctl/main.cpp says why).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include "did_you_mean.hpp"
#include "live_line.hpp"

namespace {

using markerctl::edit_distance;
using markerctl::find_unknown_name;
using markerctl::nearest_names;
using Names = std::vector<std::string>;

TEST(EditDistance, CountsInsertionsDeletionsSubstitutionsAndSwaps) {
  EXPECT_EQ(edit_distance("marker", "marker"), 0u);
  EXPECT_EQ(edit_distance("markr", "marker"), 1u);    // a letter left out
  EXPECT_EQ(edit_distance("markeer", "marker"), 1u);  // one too many
  EXPECT_EQ(edit_distance("sise", "size"), 1u);       // one wrong
  EXPECT_EQ(edit_distance("statsu", "status"), 1u);   // two swapped
  EXPECT_EQ(edit_distance("", "rig"), 3u);
  EXPECT_EQ(edit_distance("rig", ""), 3u);
  EXPECT_EQ(edit_distance("detect", "render"), 5u);
}

TEST(NearestNames, SuggestsTheClosestWithinTwoEditsAndUnderHalfTheName) {
  const Names commands{"marker", "render", "detect", "evaluate", "rig", "status", "sweep", "report"};
  EXPECT_EQ(nearest_names("markr", commands), Names{"marker"});
  EXPECT_EQ(nearest_names("statsu", commands), Names{"status"});
  EXPECT_EQ(nearest_names("reprot", commands), Names{"report"});
  // Two edits from "rig" is most of it: no suggestion.
  EXPECT_EQ(nearest_names("xy", commands), Names{});
  EXPECT_EQ(nearest_names("frobnicate", commands), Names{});
  // Ties are all named, in the order given.
  EXPECT_EQ(nearest_names("rendor", Names{"render", "vendor"}), (Names{"render", "vendor"}));
  // Options are compared without their dashes.
  EXPECT_EQ(nearest_names("--sise", Names{"--help", "--size", "--id"}), Names{"--size"});
  EXPECT_EQ(nearest_names("-size", Names{"--size"}), Names{"--size"});
}

// A tree like markerctl's: options with and without values, a subcommand
// with subcommands, one that falls through to its parent's options, one with
// positional arguments.
class UnknownNames : public ::testing::Test {
 protected:
  void SetUp() override {
    app_.require_subcommand(1);
    CLI::App* marker = app_.add_subcommand("marker");
    marker->add_option("--size", text_);
    marker->add_option("-o,--output", text_);
    marker->add_flag("--json", flag_);
    CLI::App* sweep = app_.add_subcommand("sweep");
    sweep->add_subcommand("status")->add_flag("--follow", flag_);
    sweep->add_subcommand("start")->add_option("plan", text_);
    CLI::App* rig = app_.add_subcommand("rig");
    rig->add_option("--config", text_);
    rig->add_subcommand("status")->fallthrough();
  }

  std::optional<markerctl::UnknownName> unknown(const Names& args) const { return find_unknown_name(app_, args); }

  CLI::App app_{"test", "markerctl"};
  std::string text_;
  bool flag_ = false;
};

TEST_F(UnknownNames, AMistypedCommandIsNamedWithWhereItWasGiven) {
  auto u = unknown({"markr"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->command, "");
  EXPECT_FALSE(u->is_option);
  EXPECT_EQ(u->name, "markr");
  EXPECT_EQ(u->suggestions, Names{"marker"});
  EXPECT_EQ(markerctl::describe(*u), "unknown command 'markr'; did you mean 'marker'?");

  u = unknown({"sweep", "statsu", "--follow"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->command, "sweep");
  EXPECT_EQ(u->suggestions, Names{"status"});

  u = unknown({"rig", "--config", "x.toml", "stauts"});
  ASSERT_TRUE(u) << "the option's value is not taken for a command";
  EXPECT_EQ(u->command, "rig");
  EXPECT_EQ(u->name, "stauts");

  u = unknown({"frobnicate"});
  ASSERT_TRUE(u);
  EXPECT_EQ(markerctl::describe(*u), "unknown command 'frobnicate'");
}

TEST_F(UnknownNames, AMistypedOptionIsNamedWithoutItsValue) {
  auto u = unknown({"marker", "--sise", "80mm"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->command, "marker");
  EXPECT_TRUE(u->is_option);
  EXPECT_EQ(u->name, "--sise");
  EXPECT_EQ(u->suggestions, Names{"--size"});
  EXPECT_EQ(markerctl::describe(*u), "unknown option '--sise'; did you mean '--size'?");

  u = unknown({"marker", "--sise=80mm"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->name, "--sise");

  // A parent's option is found through a fall-through command, and suggested.
  EXPECT_FALSE(unknown({"rig", "status", "--config", "x.toml"}));
  u = unknown({"rig", "status", "--confg", "x.toml"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->command, "rig status");
  EXPECT_EQ(u->suggestions, Names{"--config"});

  u = unknown({"sweep", "status", "--folow"});
  ASSERT_TRUE(u);
  EXPECT_EQ(u->command, "sweep status");
  EXPECT_EQ(u->suggestions, Names{"--follow"});
}

TEST_F(UnknownNames, KnownWordsValuesAndPositionalsAreNotTakenForMistakes) {
  EXPECT_FALSE(unknown({"marker", "--size", "80mm", "-o", "m.svg", "--json"}));
  EXPECT_FALSE(unknown({"marker", "-om.svg", "--size=80mm"}));
  // A value that looks like an option's name is the option's value.
  EXPECT_FALSE(unknown({"marker", "--output", "--size"}));
  // A plan's name is a positional, not a command.
  EXPECT_FALSE(unknown({"sweep", "start", "statsu.toml"}));
  EXPECT_FALSE(unknown({"sweep", "start", "-"}));
  // After "--" every word is positional.
  EXPECT_FALSE(unknown({"sweep", "start", "--", "--plan"}));
  // An extra argument where a command takes none is CLI11's to report.
  EXPECT_FALSE(unknown({"marker", "--size", "80mm", "extra"}));
}

}  // namespace

namespace {

using markerctl::display_columns;
using markerctl::fit_to_columns;
using markerctl::join_fitting;
using markerctl::join_keeping;
using markerctl::LinePart;

TEST(LiveLine, ColumnsAreCharactersNotBytes) {
  EXPECT_EQ(display_columns(""), 0u);
  EXPECT_EQ(display_columns("rail 250.000 mm"), 15u);
  EXPECT_EQ(display_columns("30.0\xc2\xb0"), 5u);  // "30.0°": ° is two bytes, one column
  EXPECT_EQ(display_columns("\xc2\xb1"
                            "0.5 mm"),
            7u);  // "±0.5 mm"
}

TEST(LiveLine, FittingCutsAtTheWidthAndNeverInsideACharacter) {
  EXPECT_EQ(fit_to_columns("rail 250.000 mm", 80), "rail 250.000 mm");
  EXPECT_EQ(fit_to_columns("rail 250.000 mm", 4), "rail");
  EXPECT_EQ(fit_to_columns("rail 250.000 mm", 0), "");
  // "yaw 30°!" cut after the degree sign keeps both of its bytes, before it neither.
  EXPECT_EQ(fit_to_columns("yaw 30\xc2\xb0!", 7), "yaw 30\xc2\xb0");
  EXPECT_EQ(fit_to_columns("yaw 30\xc2\xb0!", 6), "yaw 30");
  const std::string long_line(138, '#');
  EXPECT_EQ(display_columns(fit_to_columns(long_line, 79)), 79u);
}

TEST(LiveLine, PartsThatDoNotFitAreLeftOutFromTheLast) {
  const std::vector<std::string> parts{"rail 6.975 mm idle (homed)", "turntable 0.5\xc2\xb0 idle", "step 5 mm, 1 deg"};
  EXPECT_EQ(join_fitting(parts, " | ", 200),
            "rail 6.975 mm idle (homed) | turntable 0.5\xc2\xb0 idle | step 5 mm, 1 deg");
  // 26 + 3 + 19 columns: the third does not fit (the ° counted as one).
  EXPECT_EQ(join_fitting(parts, " | ", 48), "rail 6.975 mm idle (homed) | turntable 0.5\xc2\xb0 idle");
  EXPECT_EQ(join_fitting(parts, " | ", 47), "rail 6.975 mm idle (homed)");
  // The first alone is cut.
  EXPECT_EQ(join_fitting(parts, " | ", 10), "rail 6.975");
}

TEST(LiveLine, PartsLeastKeptAreLeftOutFirstAndTheRestKeepTheirOrder) {
  // A sweep's progress: the bar, the steps, the state, the point, the
  // phase, the rate, the time left, as sweep_progress_line keeps them.
  const std::vector<LinePart> parts{{"[####------]", 4, ""},   {" 169/310 ", 9, " "}, {"running", 8, " "},
                                    {"0.95 m 75.0 deg #5", 8}, {"collecting 4/6", 3}, {"rate 83%", 2},
                                    {"about 40s left", 8}};
  const std::string whole =
      "[####------]  169/310  running  0.95 m 75.0 deg #5  collecting 4/6  rate 83%  about 40s left";
  EXPECT_EQ(join_keeping(parts, 200), whole);
  EXPECT_EQ(join_keeping(parts, display_columns(whole)), whole);
  // One column less: the rate goes first, then the phase, then the bar.
  EXPECT_EQ(join_keeping(parts, display_columns(whole) - 1),
            "[####------]  169/310  running  0.95 m 75.0 deg #5  collecting 4/6  about 40s left");
  EXPECT_EQ(join_keeping(parts, 70), "[####------]  169/310  running  0.95 m 75.0 deg #5  about 40s left");
  EXPECT_EQ(join_keeping(parts, 60), " 169/310  running  0.95 m 75.0 deg #5  about 40s left");
  // Of equals, the later goes first: the time left before the point.
  EXPECT_EQ(join_keeping(parts, 40), " 169/310  running  0.95 m 75.0 deg #5");
  EXPECT_EQ(join_keeping(parts, 17), " 169/310  running");
  // The last part left is cut.
  EXPECT_EQ(join_keeping(parts, 5), " 169/");
  EXPECT_EQ(join_keeping({}, 80), "");
}

}  // namespace
