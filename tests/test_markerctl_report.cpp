// markerctl report, end to end on run directories written as markerd writes
// them (RunRecorder): the paper and the socket marker's runs compared in
// Table 6.1's two columns, chosen on the command line or by what the runs'
// plans say, and every wrong argument named in its error.

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"
#include "support/files.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"

namespace {

namespace fs = std::filesystem;
using markerd::test_support::Outcome;
using markerd::test_support::TempDir;
using namespace markerd::sweep;

// A one-grid plan: `distances` x `angles`, one measurement of 40 frames a
// point (enough for a rate's 95% interval to tell 100 % from a 90 %
// threshold); `mounting` empty: the plan does not say.
std::string plan_text(const std::string& name, const std::string& mounting, const std::string& distances,
                      const std::string& angles) {
  return "name = \"" + name + "\"\nframes_per_point = 40\nrepeats = 1\n\n[marker]\nfamily = \"frame8\"\nid = 165\n" +
         "size_m = 0.08\n" + (mounting.empty() ? "" : "mounting = \"" + mounting + "\"\n") +
         "\n[[grid]]\nname = \"g\"\ndistance_m = " + distances + "\nangle_deg = " + angles + "\n";
}

// A finished run of `plan_source` in `directory`: at each of the plan's
// points the marker is found in `detected(distance, angle)` tenths of the
// frames.
// `marker`: the marker markerd's config described, as start.json keeps it.
template <typename Detected>
fs::path write_run(const fs::path& directory, const std::string& plan_source, Detected detected,
                   const nlohmann::json& marker = nlohmann::json::object()) {
  RunStart start;
  start.plan = parse_plan(plan_source, "plan.toml");
  start.marker = marker;
  start.run_id = start.plan.name;
  start.time = std::chrono::system_clock::from_time_t(1'796'105'700);
  const std::vector<PlanStep> steps = plan_steps(start.plan);
  start.steps = steps.size();
  RunRecorder recorder = RunRecorder::create(directory, start);
  for (const PlanStep& step : steps) {
    PointRecord r;
    r.step = step.index;
    r.grid = step.grid;
    r.point = step.point;
    r.repeat = step.repeat;
    r.distance_m = step.distance_m;
    r.angle_deg = step.angle_deg;
    r.truth_distance_m = step.distance_m;
    r.truth_tvec_m = {0, 0, step.distance_m};
    const int found = detected(step.distance_m, step.angle_deg);
    for (int i = 0; i < 40; ++i) {
      FrameSample f;
      f.sequence = static_cast<std::uint64_t>(i);
      f.detected = i < 4 * found;
      r.frames.push_back(f);
    }
    recorder.append_point(r);
  }
  recorder.finish(RunStop{start.time + std::chrono::minutes(10), ExitStatus::done, "", steps.size(), "", ""});
  return directory;
}

Outcome markerctl(const std::vector<std::string>& args) {
  std::vector<std::string> argv{MARKERCTL_PATH};
  argv.insert(argv.end(), args.begin(), args.end());
  Outcome r = markerd::test_support::run_program(argv);
  if (r.timed_out) ADD_FAILURE() << "markerctl did not finish: " << r.describe();
  return r;
}

class MarkerctlReport : public ::testing::Test {
 protected:
  void SetUp() override {
    fs::create_directories(dir_.path());
    // The paper marker: found facing to 1.2 m, to 60 deg at 50 cm.
    paper_distance_ =
        write_run(dir_.path() / "paper-distance", plan_text("paper-distance", "paper", "[0.5, 0.8, 1.2, 1.5]", "[0]"),
                  [](double d, double) { return d <= 1.2 ? 10 : 0; });
    paper_angle_ =
        write_run(dir_.path() / "paper-angle-50cm", plan_text("paper-angle-50cm", "paper", "[0.5]", "[0, 30, 60, 75]"),
                  [](double, double a) { return a <= 60 ? 10 : 2; });
    // The socket marker: found facing to 0.81 m, never at 0.95 m; to 45
    // deg at 50 cm; no angle run at 72 cm.
    socket_distance_ = write_run(dir_.path() / "socket-distance",
                                 plan_text("socket-distance", "socket", "[0.72, 0.78, 0.81, 0.84, 0.95]", "[0]"),
                                 [](double d, double) { return d <= 0.81 ? 10
                                                               : d < 0.9 ? 6
                                                                         : 0; });
    socket_angle_ = write_run(dir_.path() / "socket-angle-50cm",
                              plan_text("socket-angle-50cm", "socket", "[0.5]", "[0, 15, 30, 45, 60]"),
                              [](double, double a) { return a <= 45 ? 10 : 0; });
  }

  [[nodiscard]] std::string out() const { return (dir_.path() / "out").string(); }

  TempDir dir_;
  fs::path paper_distance_;
  fs::path paper_angle_;
  fs::path socket_distance_;
  fs::path socket_angle_;
};

const char* const kDistanceRow = "| Maximum detection distance | 120 cm | 120 cm | 81 cm | 81 cm |";
const char* const kAngle50Row = "| Maximum viewing angle at 50 cm | 60° | 60° | 45° | 45° |";
const char* const kAngle72Row = "| Maximum viewing angle at 72 cm | not measured | not swept | 30° | not swept |";
const char* const kAngle95Row =
    "| Maximum viewing angle at 95 cm | 45° (stable to 30°) | not swept | not detected | not swept |";

TEST_F(MarkerctlReport, PaperAndSocketOptionsFillTheTwoColumns) {
  const Outcome r = markerctl({"report", "--socket", socket_distance_.string(), socket_angle_.string(), "--paper",
                               paper_distance_.string(), paper_angle_.string(), "-o", out(), "--no-plots"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out.substr(0, r.out.find('\n')), (fs::path(out()) / "report.md").string());
  // The paper marker's columns first, whatever the order of the options.
  EXPECT_NE(r.out.find("| | Thesis: paper marker | Paper marker: paper-distance, paper-angle-50cm (frame8 #165, 80 mm, "
                       "on paper) | Thesis: socket marker | Socket marker: socket-distance, socket-angle-50cm"),
            std::string::npos)
      << r.out;
  for (const char* row : {kDistanceRow, kAngle50Row, kAngle72Row, kAngle95Row}) {
    EXPECT_NE(r.out.find(row), std::string::npos) << row << "\n" << r.out;
  }
  const std::string md = markerd::test_support::read_file(fs::path(out()) / "report.md");
  EXPECT_NE(md.find(kDistanceRow), std::string::npos) << md;
}

// As the README's demo runs it: one run's directory, the report beside its
// records, every file a paper needs, the table and its calls printed.
TEST_F(MarkerctlReport, OneRunsReportHasEveryFileWithItsPlotsAsSvgAndPdf) {
  if (!markerd::test_support::find_program("gnuplot")) {
    GTEST_SKIP() << "gnuplot is not on PATH (tools/install-deps.sh installs gnuplot-nox)";
  }
  const Outcome r = markerctl({"report", paper_distance_.string()});
  ASSERT_EQ(r.code, 0) << r.describe();
  const fs::path report = paper_distance_ / "report";
  EXPECT_EQ(r.out.substr(0, r.out.find('\n')), (report / "report.md").string());
  // 40 frames a point: decided, the maximum distance and the call on it.
  EXPECT_NE(r.out.find("| Maximum detection distance | 120 cm | 120 cm |"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\nThreshold calls:\n\n| Run | Limit | Found | Call |"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("| paper-distance | Maximum detection distance | 120 cm | decided |"), std::string::npos)
      << r.out;
  for (const char* file : {"report.md", "summary.csv", "translation.csv"}) {
    EXPECT_TRUE(fs::is_regular_file(report / file)) << file;
  }
  for (const char* plot : {"rate-vs-distance", "pose-error-vs-distance", "pose-error-vs-angle", "rate-map"}) {
    const std::string name = plot;
    EXPECT_NE(markerd::test_support::read_file(report / (name + ".svg")).find("<svg"), std::string::npos) << name;
    EXPECT_EQ(markerd::test_support::read_file(report / (name + ".pdf")).substr(0, 5), "%PDF-") << name;
    EXPECT_TRUE(fs::is_regular_file(report / (name + ".gp"))) << name;
  }
}

TEST_F(MarkerctlReport, RunsWhosePlansSayTheirMountingPairThemselves) {
  const Outcome r = markerctl({"report", paper_distance_.string(), socket_distance_.string(), paper_angle_.string(),
                               socket_angle_.string(), "-o", out(), "--no-plots"});
  ASSERT_EQ(r.code, 0) << r.describe();
  for (const char* row : {kDistanceRow, kAngle50Row, kAngle72Row}) {
    EXPECT_NE(r.out.find(row), std::string::npos) << row << "\n" << r.out;
  }
}

TEST_F(MarkerctlReport, RunsOfOneMountingStaySideBySide) {
  const Outcome r = markerctl({"report", paper_distance_.string(), paper_angle_.string(), "-o", out(), "--no-plots"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_NE(r.out.find("| | Thesis: paper marker | paper-distance (frame8 #165, 80 mm, on paper) | paper-angle-50cm "),
            std::string::npos)
      << r.out;
  EXPECT_EQ(r.out.find("socket"), std::string::npos) << r.out;
}

TEST_F(MarkerctlReport, ARunUnderTheWrongMarkerIsNamed) {
  const Outcome r = markerctl({"report", "--paper", paper_distance_.string(), "--socket", socket_distance_.string(),
                               paper_angle_.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: report: --socket " + paper_angle_.string() +
                       ": the run's plan says its marker was mounted on paper ([marker] mounting = \"paper\"), not on "
                       "a socket frame\n");
  EXPECT_FALSE(fs::exists(out()));
}

// A plan without a mounting ran on what markerd's config said: a run that
// markerd recorded on paper does not go into the socket column.
TEST_F(MarkerctlReport, ARunWhosePlanDoesNotSayIsPlacedByWhatMarkerdRecorded) {
  const fs::path run = write_run(
      dir_.path() / "unsaid-paper", plan_text("unsaid-paper", "", "[0.5, 0.7]", "[0.0]"),
      [](double, double) { return 10; }, nlohmann::json{{"mounting", "paper"}});
  const Outcome r = markerctl({"report", "--paper", paper_distance_.string(), "--socket", socket_distance_.string(),
                               run.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: report: --socket " + run.string() +
                       ": the run's markerd config said its marker was mounted on paper ([marker] mounting = "
                       "\"paper\"), not on a socket frame\n");
  const Outcome ok = markerctl({"report", "--paper", paper_distance_.string(), run.string(), "--socket",
                                socket_distance_.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(ok.code, 0) << ok.describe();
}

TEST_F(MarkerctlReport, BadArgumentsAreNamed) {
  const std::string missing = (dir_.path() / "no-such-run").string();
  const Outcome absent = markerctl({"report", "--paper", paper_distance_.string(), "--socket", missing, "-o", out()});
  EXPECT_EQ(absent.code, 1) << absent.describe();
  EXPECT_EQ(absent.err, "markerctl: report: --socket " + missing + ": no such run directory\n");

  const Outcome mixed =
      markerctl({"report", paper_distance_.string(), "--socket", socket_distance_.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(mixed.code, 2) << mixed.describe();
  EXPECT_EQ(mixed.err, "markerctl: report: RUN_DIR " + paper_distance_.string() +
                           ": give the runs either as RUN_DIR... or with --paper and --socket, not both\n");

  const Outcome no_output =
      markerctl({"report", "--paper", paper_distance_.string(), "--socket", socket_distance_.string(), "--no-plots"});
  EXPECT_EQ(no_output.code, 2) << no_output.describe();
  EXPECT_NE(no_output.err.find("-o OUT_DIR is required for several runs"), std::string::npos) << no_output.err;

  const Outcome none = markerctl({"report", "-o", out()});
  EXPECT_EQ(none.code, 2) << none.describe();
  EXPECT_EQ(none.err, "markerctl: report: no runs: give RUN_DIR..., or --paper RUN_DIR... and --socket RUN_DIR...\n");
  EXPECT_FALSE(fs::exists(out()));
}

TEST_F(MarkerctlReport, OneRunInBothColumnsIsNamed) {
  // A plan that does not say its mounting fits either column, but not both.
  const fs::path unstated = write_run(dir_.path() / "unstated", plan_text("unstated", "", "[0.5, 0.7]", "[0]"),
                                      [](double, double) { return 10; });
  const Outcome r = markerctl({"report", "--paper", unstated.string(), "--socket", socket_distance_.string(),
                               (dir_.path() / "." / "unstated").string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: report: --socket " + (dir_.path() / "." / "unstated").string() +
                       ": the same run as --paper " + unstated.string() + "\n");
}

TEST_F(MarkerctlReport, RunsOfDifferentMarkersInOneColumnAreNamed) {
  const fs::path other =
      write_run(dir_.path() / "socket-other", plan_text("socket-other", "socket", "[0.5]", "[0, 30]"),
                [](double, double) { return 10; });
  // The same plan for another id.
  const fs::path other_id = write_run(
      dir_.path() / "socket-id-12",
      "name = \"socket-id-12\"\nrepeats = 1\n[marker]\nid = 12\nmounting = \"socket\"\n[[grid]]\nname = \"g\"\n"
      "distance_m = [0.5]\nangle_deg = [0, 30]\n",
      [](double, double) { return 10; });
  const Outcome ok =
      markerctl({"report", "--socket", socket_distance_.string(), other.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(ok.code, 0) << ok.describe();
  const Outcome r =
      markerctl({"report", "--socket", socket_distance_.string(), other_id.string(), "-o", out(), "--no-plots"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err,
            "markerctl: report: --socket: runs socket-distance (frame8 #165, 80 mm, on a socket frame) and "
            "socket-id-12 (frame8 #12, 80 mm, on a socket frame) measured different markers\n");
}

// --json: what was written, for scripts, and nothing else on stdout.
TEST_F(MarkerctlReport, JsonNamesTheFilesWrittenAndHoldsTheTable) {
  const Outcome text = markerctl({"report", "--paper", paper_distance_.string(), "-o", out(), "--no-plots"});
  ASSERT_EQ(text.code, 0) << text.describe();
  const Outcome r = markerctl({"report", "--paper", paper_distance_.string(), "-o", out(), "--no-plots", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  ASSERT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << "one line: " << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["report"], (fs::path(out()) / "report.md").string());
  EXPECT_TRUE(j["plots"].empty()) << "--no-plots";
  ASSERT_FALSE(j["csv"].empty());
  for (const auto& csv : j["csv"]) EXPECT_TRUE(fs::exists(csv.get<std::string>())) << csv;
  // The same table and threshold calls as the text's: the path, a blank
  // line, the table, then the calls under their heading.
  const std::string kCalls = "\nThreshold calls:\n\n";
  const std::size_t table = text.out.find("\n\n") + 2, calls = text.out.find(kCalls);
  ASSERT_NE(calls, std::string::npos) << text.out;
  EXPECT_EQ(j["table_6_1"], text.out.substr(table, calls - table));
  EXPECT_EQ(j["threshold_calls"], text.out.substr(calls + kCalls.size()));
}

}  // namespace
