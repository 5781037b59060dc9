#include <gtest/gtest.h>

#include <fstream>

#include "markerd/base/config_table.hpp"
#include "support/temp_dir.hpp"

using markerd::ConfigError;
using markerd::ConfigTable;

namespace {

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

const char* kText = R"(# a rig
[rig.rail]
max_velocity = 50
acceleration = 20.5
name = "rail"

[rig.turntable]
max_velocity = "fast"
)";

}  // namespace

TEST(ConfigTable, ReadsTypedValuesAndIntegersAsNumbers) {
  const auto root = ConfigTable::parse(kText, "rig.toml");
  const auto rail = root.table("rig").table("rail");
  EXPECT_EQ(rail.key_path(), "rig.rail");
  EXPECT_DOUBLE_EQ(rail.required<double>("max_velocity"), 50);
  EXPECT_EQ(rail.required<int>("max_velocity"), 50);
  EXPECT_DOUBLE_EQ(rail.required<double>("acceleration"), 20.5);
  EXPECT_EQ(rail.required<std::string>("name"), "rail");
  EXPECT_EQ(rail.optional<int>("retries", 3), 3);
  EXPECT_FALSE(rail.maybe<double>("backlash").has_value());
}

TEST(ConfigTable, ErrorsNameFileLineAndKey) {
  const auto root = ConfigTable::parse(kText, "rig.toml");
  const auto turntable = root.table("rig").table("turntable");
  EXPECT_EQ(error_of([&] { (void)turntable.required<double>("max_velocity"); }),
            "rig.toml:8: rig.turntable.max_velocity: must be a number");
  const auto rail = root.table("rig").table("rail");
  EXPECT_EQ(error_of([&] { (void)rail.required<int>("acceleration"); }),
            "rig.toml:4: rig.rail.acceleration: must be an integer");
  EXPECT_EQ(error_of([&] { (void)rail.required<double>("backlash"); }),
            "rig.toml:2: [rig.rail]: missing key 'rig.rail.backlash' (a number)");
  EXPECT_EQ(error_of([&] {
              rail.allow_only({"max_velocity", "acceleration"});
            }),
            "rig.toml:5: rig.rail.name: unknown key (known here: max_velocity, acceleration)");
  EXPECT_EQ(error_of([&] { rail.fail("acceleration", "must be > 0"); }),
            "rig.toml:4: rig.rail.acceleration: must be > 0");
  EXPECT_EQ(error_of([&] { (void)root.table("camera"); }), "rig.toml: missing table [camera]");
}

TEST(ConfigTable, SyntaxErrorsAndMissingFilesAreConfigErrors) {
  EXPECT_EQ(error_of([] { (void)ConfigTable::parse("a = \n", "x.toml"); }).rfind("x.toml:1:", 0), 0u);
  const auto missing = error_of([] { (void)ConfigTable::load_file("/nonexistent/rig.toml"); });
  EXPECT_EQ(missing.rfind("/nonexistent/rig.toml", 0), 0u) << missing;
  const markerd::test_support::TempDir dir;
  EXPECT_EQ(ConfigTable::load_file(dir.write("config_table.toml", kText))
                .table("rig")
                .table("rail")
                .required<std::string>("name"),
            "rail");
}

TEST(ConfigTable, AnythingButARegularFileIsRefusedByName) {
  const auto dir = error_of([] { (void)ConfigTable::load_file("/tmp"); });
  EXPECT_NE(dir.find("is a directory, not a file"), std::string::npos) << dir;
  const auto device = error_of([] { (void)ConfigTable::load_file("/dev/zero"); });
  EXPECT_NE(device.find("is a character device, not a file"), std::string::npos) << device;
}

TEST(ConfigTable, RangesNameTheirBoundsAndUnit) {
  const auto root = ConfigTable::parse(R"([axis]
settle_ms = 9223372036854775807
time_scale = 1e308
ratio = nan
speed = 12.5
count = 70000
)",
                                       "rig.toml");
  const auto axis = root.table("axis");
  EXPECT_EQ(error_of([&] {
              (void)axis.required<std::int64_t>("settle_ms", {0, 60000, "ms"});
            }),
            "rig.toml:2: axis.settle_ms: must be from 0 to 60000 ms, got 9223372036854775807");
  EXPECT_EQ(error_of([&] {
              (void)axis.optional<double>("time_scale", 1.0, {1, 1000});
            }),
            "rig.toml:3: axis.time_scale: must be from 1 to 1000, got 1e+308");
  EXPECT_EQ(error_of([&] {
              (void)axis.optional<double>("ratio", 1.0, {0, 1});
            }),
            "rig.toml:4: axis.ratio: must be a finite number, got nan");
  EXPECT_DOUBLE_EQ(axis.required<double>("speed", {0, 100, "mm/s"}), 12.5);
  EXPECT_DOUBLE_EQ(axis.optional<double>("absent", 7.0, {0, 100}), 7.0);
  EXPECT_EQ(error_of([&] {
              (void)axis.required<double>("absent", {0, 100});
            }),
            "rig.toml:1: [axis]: missing key 'axis.absent' (a number)");
}

TEST(ConfigTable, AnIntegerTooLargeForItsSettingSaysSo) {
  const auto root = ConfigTable::parse("[axis]\nsettle_ms = 9223372036854775807\ncount = 70000\n", "rig.toml");
  EXPECT_EQ(error_of([&] { (void)root.table("axis").required<int>("settle_ms"); }),
            "rig.toml:2: axis.settle_ms: must be an integer from -2147483648 to 2147483647, got 9223372036854775807");
  EXPECT_EQ(root.table("axis").required<int>("count"), 70000);
}
