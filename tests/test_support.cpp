// The tests' own support (support/): what the other tests rely on it for.
// A config edit that misses its key fails loudly, a program's outcome is
// what it did, a temporary directory is fresh and goes away.

#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>

#include <toml++/toml.h>

#include "support/files.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd::test_support {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(TomlConfig, ChangesTheValueAndKeepsTheRest) {
  const TempDir dir;
  const fs::path file = write_sim_rig_config(dir / "rig.toml", 50.0);
  const toml::table written = toml::parse_file(file.string());
  EXPECT_EQ(written.at_path("rig.sim.time_scale").value<double>(), 50.0);
  const toml::table shipped = toml::parse_file((kSourceTree / "config/rig-sim.toml").string());
  EXPECT_EQ(written.at_path("rig.rail.settle_ms").value<std::int64_t>(),
            shipped.at_path("rig.rail.settle_ms").value<std::int64_t>());
  EXPECT_EQ(written.at_path("rig.turntable.backend").value<std::string>(), "sim");
}

TEST(TomlConfig, AKeyThatIsNotThereOrOfAnotherTypeIsAnError) {
  const fs::path shipped = kSourceTree / "config/rig-sim.toml";
  TomlConfig config = TomlConfig::load(shipped);
  EXPECT_EQ(error_of([&] { config.set("rig.sim.timescale", 50.0); }),
            shipped.string() + ": no key rig.sim.timescale to set");
  EXPECT_EQ(error_of([&] { config.set("rig.sim.time_scale", "fast"); }),
            shipped.string() + ": rig.sim.time_scale is not a string");
  EXPECT_EQ(error_of([&] { config.set("rig.rail.settle_ms", 0.5); }),
            shipped.string() + ": rig.rail.settle_ms is not a floating-point number");
  const TempDir dir;
  const fs::path broken = dir.write("broken.toml", "[rig\n");
  EXPECT_EQ(error_of([&] { (void)TomlConfig::load(broken); }).rfind(broken.string() + ":1: ", 0), 0U);
}

TEST(RunProgram, ReportsExitCodeAndBothStreams) {
  const Outcome o = run_program({"sh", "-c", "echo out; echo err >&2; exit 3"});
  EXPECT_EQ(o.code, 3);
  EXPECT_EQ(o.out, "out\n");
  EXPECT_EQ(o.err, "err\n");
  EXPECT_FALSE(o.timed_out);

  ProcessOptions merged;
  merged.merge_output = true;
  const Outcome m = run_program({"sh", "-c", "echo one; echo two >&2; echo three"}, merged);
  EXPECT_EQ(m.out, "one\ntwo\nthree\n");
  EXPECT_EQ(m.err, "");
}

TEST(RunProgram, ChangesTheEnvironmentAsAsked) {
  ::setenv("MARKERD_TEST_SUPPORT_GONE", "here", 1);
  ProcessOptions options;
  options.environment = {"MARKERD_TEST_SUPPORT_SET=yes", "MARKERD_TEST_SUPPORT_GONE"};
  const Outcome o =
      run_program({"sh", "-c", "echo \"${MARKERD_TEST_SUPPORT_SET}-${MARKERD_TEST_SUPPORT_GONE-unset}\""}, options);
  ::unsetenv("MARKERD_TEST_SUPPORT_GONE");
  EXPECT_EQ(o.out, "yes-unset\n") << o.describe();
}

TEST(RunProgram, KillsAProgramPastItsTimeAndNamesOneNotFound) {
  const Outcome o = run_program({"sleep", "60"}, {}, 200ms);
  EXPECT_TRUE(o.timed_out);
  EXPECT_EQ(o.code, 128 + SIGKILL);
  EXPECT_EQ(error_of([] { (void)run_program({"markerd-test-no-such-program"}); }),
            "markerd-test-no-such-program: no such program in PATH");
  EXPECT_EQ(run_program({"/nonexistent/program"}).code, 127) << "a path is executed as given";
}

TEST(TempDir, IsFreshAndGoesAwayWithEverythingInIt) {
  fs::path kept;
  {
    const TempDir a("markerd-test-support");
    const TempDir b("markerd-test-support");
    EXPECT_NE(a.path(), b.path());
    EXPECT_TRUE(fs::is_directory(a.path()));
    EXPECT_TRUE(fs::is_empty(a.path()));
    fs::create_directories(a / "sub");
    EXPECT_EQ(read_file(a.write("sub/file", "text")), "text");
    kept = a.path();
  }
  EXPECT_FALSE(fs::exists(kept));
}

TEST(Files, AnAbsentFileReadsAsEmptyAndAFailedWriteThrows) {
  EXPECT_EQ(read_file("/nonexistent/file"), "");
  EXPECT_EQ(error_of([] { write_file("/nonexistent/file", "x"); }), "cannot write /nonexistent/file");
}

}  // namespace
}  // namespace markerd::test_support
