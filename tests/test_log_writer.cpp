// The detection log's writer: whole lines under SIGKILL, the repair of a
// partial last line on open, rotation by size and by run without
// overwriting, the fsync policies, reopen for logrotate, and errors that name
// the file and the cause.

#include <gtest/gtest.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "detection_log_samples.hpp"
#include "markerd/daemon/detection_record.hpp"
#include "markerd/daemon/log_writer.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

using test_support::read_file;
using test_support::TempDir;
using test_support::write_file;

// The files of a run, in index order.
std::vector<fs::path> run_files(const fs::path& dir, const std::string& run) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().filename().string().starts_with("detections-" + run + "-")) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

LogWriterConfig config_for(const fs::path& dir, std::string run = "run1") {
  LogWriterConfig c;
  c.directory = dir;
  c.run_id = std::move(run);
  c.fsync = FsyncPolicy::never;
  return c;
}

std::string numbered_line(int n) { return "{\"n\":" + std::to_string(n) + ",\"pad\":\"xxxxxxxxxxxxxxxx\"}\n"; }

TEST(LogWriter, AppendsWholeLinesToTheRunsFirstFile) {
  const TempDir dir;
  {
    LogWriter writer(config_for(dir.path()));
    EXPECT_EQ(writer.current_path(), dir.path() / "detections-run1-000.jsonl");
    for (int i = 0; i < 3; ++i) writer.append(numbered_line(i));
    const LogWriterStats s = writer.stats();
    EXPECT_EQ(s.lines, 3U);
    EXPECT_EQ(s.bytes, 3 * numbered_line(0).size());
    EXPECT_EQ(s.files_opened, 1U);
  }
  EXPECT_EQ(read_file(dir.path() / "detections-run1-000.jsonl"),
            numbered_line(0) + numbered_line(1) + numbered_line(2));
}

TEST(LogWriter, TakesOnlyOneCompleteLine) {
  const TempDir dir;
  LogWriter writer(config_for(dir.path()));
  EXPECT_THROW(writer.append(""), std::invalid_argument);
  EXPECT_THROW(writer.append("{\"a\":1}"), std::invalid_argument);
  EXPECT_THROW(writer.append("{\"a\":1}\n{\"a\":2}\n"), std::invalid_argument);
  EXPECT_EQ(writer.stats().lines, 0U);
}

TEST(LogWriter, RejectsNamesThatAreNotPlainFileNameParts) {
  const TempDir dir;
  for (const char* run : {"", "../etc", "a/b", ".hidden", "a b", "x\n"}) {
    EXPECT_THROW(LogWriter(config_for(dir.path(), run)), std::invalid_argument) << run;
  }
  LogWriterConfig c = config_for(dir.path());
  c.prefix = "det/ections";
  EXPECT_THROW(LogWriter{c}, std::invalid_argument);
  EXPECT_TRUE(fs::is_empty(dir.path()));
}

TEST(LogWriter, RotatesBySizeWithoutSplittingALine) {
  const TempDir dir;
  const std::size_t line_size = numbered_line(0).size();
  LogWriterConfig c = config_for(dir.path());
  c.max_bytes = 3 * line_size + line_size / 2;  // room for three lines
  {
    LogWriter writer(c);
    for (int i = 0; i < 10; ++i) writer.append(numbered_line(i));
    EXPECT_EQ(writer.current_path().filename(), "detections-run1-003.jsonl");
  }
  const auto files = run_files(dir.path(), "run1");
  ASSERT_EQ(files.size(), 4U);
  std::string all;
  for (std::size_t i = 0; i < files.size(); ++i) {
    EXPECT_EQ(files[i].filename(), "detections-run1-00" + std::to_string(i) + ".jsonl");
    const std::string content = read_file(files[i]);
    EXPECT_LE(content.size(), c.max_bytes);
    EXPECT_EQ(content.size(), (i < 3 ? 3 : 1) * line_size) << files[i];
    all += content;
  }
  std::string expected;
  for (int i = 0; i < 10; ++i) expected += numbered_line(i);
  EXPECT_EQ(all, expected);
}

TEST(LogWriter, ALineLongerThanTheLimitGetsAFileOfItsOwn) {
  const TempDir dir;
  LogWriterConfig c = config_for(dir.path());
  c.max_bytes = 64;
  const std::string long_line = "{\"x\":\"" + std::string(200, 'y') + "\"}\n";
  {
    LogWriter writer(c);
    writer.append(numbered_line(0).substr(0, 20) + "\n");
    writer.append(long_line);
    writer.append("{}\n");
  }
  const auto files = run_files(dir.path(), "run1");
  ASSERT_EQ(files.size(), 3U);
  EXPECT_EQ(read_file(files[1]), long_line);
  EXPECT_EQ(read_file(files[2]), "{}\n");
}

TEST(LogWriter, ANewRunStartsItsOwnFiles) {
  const TempDir dir;
  LogWriter writer(config_for(dir.path(), "20240501T120000Z"));
  writer.append(numbered_line(1));
  writer.start_run("20240501T130000Z");
  EXPECT_EQ(writer.run_id(), "20240501T130000Z");
  EXPECT_EQ(writer.current_path(), dir.path() / "detections-20240501T130000Z-000.jsonl");
  writer.append(numbered_line(2));
  EXPECT_EQ(read_file(dir.path() / "detections-20240501T120000Z-000.jsonl"), numbered_line(1));
  EXPECT_EQ(read_file(dir.path() / "detections-20240501T130000Z-000.jsonl"), numbered_line(2));
  EXPECT_THROW(writer.start_run("../x"), std::invalid_argument);
  EXPECT_EQ(make_run_id(std::chrono::sys_days(std::chrono::year{2024} / 5 / 1) + 12h + 3min + 4s + 999ms),
            "20240501T120304Z");
}

TEST(LogWriter, ARestartedRunContinuesItsNewestFileAndNeverOverwrites) {
  const TempDir dir;
  const std::size_t line_size = numbered_line(0).size();
  LogWriterConfig c = config_for(dir.path());
  c.max_bytes = 2 * line_size;
  // Another run with a name that starts alike, and a stranger's file in the
  // way of the rotation: neither is touched.
  write_file(dir.path() / "detections-run1-x-000.jsonl", "other run\n");
  write_file(dir.path() / "detections-run1-002.jsonl.bak", "backup\n");
  {
    LogWriter writer(c);
    writer.append(numbered_line(0));
  }
  {
    LogWriter writer(c);  // continues 000, which has room for one more
    EXPECT_EQ(writer.current_path().filename(), "detections-run1-000.jsonl");
    writer.append(numbered_line(1));
    write_file(dir.path() / "detections-run1-001.jsonl", "someone else's\n");
    writer.append(numbered_line(2));  // 000 is full, 001 exists: 002
    EXPECT_EQ(writer.current_path().filename(), "detections-run1-002.jsonl");
    writer.append(numbered_line(3));
  }
  {
    LogWriter writer(c);  // 002 is full: 003
    EXPECT_EQ(writer.current_path().filename(), "detections-run1-003.jsonl");
  }
  EXPECT_EQ(read_file(dir.path() / "detections-run1-000.jsonl"), numbered_line(0) + numbered_line(1));
  EXPECT_EQ(read_file(dir.path() / "detections-run1-001.jsonl"), "someone else's\n");
  EXPECT_EQ(read_file(dir.path() / "detections-run1-002.jsonl"), numbered_line(2) + numbered_line(3));
  EXPECT_EQ(read_file(dir.path() / "detections-run1-x-000.jsonl"), "other run\n");
  EXPECT_EQ(read_file(dir.path() / "detections-run1-002.jsonl.bak"), "backup\n");
}

TEST(LogWriter, APartialLastLineIsCutOffOnOpen) {
  const TempDir dir;
  const fs::path file = dir.path() / "detections-run1-000.jsonl";
  struct Case {
    std::string before;
    std::string kept;
  };
  const std::string long_tail(10'000, 'z');  // longer than one read chunk
  const std::string zeros(5'000, '\0');      // a tail a power cut left as zero bytes
  for (const Case& k :
       {Case{numbered_line(0) + numbered_line(1) + "{\"n\":2,\"pa", numbered_line(0) + numbered_line(1)},
        Case{"{\"n\":0", ""}, Case{numbered_line(0) + long_tail, numbered_line(0)},
        Case{numbered_line(0) + zeros, numbered_line(0)}, Case{numbered_line(0), numbered_line(0)}}) {
    write_file(file, k.before);
    {
      LogWriter writer(config_for(dir.path()));
      const LogWriterStats s = writer.stats();
      const bool cut = k.kept.size() != k.before.size();
      EXPECT_EQ(s.tails_repaired, cut ? 1U : 0U);
      EXPECT_EQ(s.tail_bytes_cut, k.before.size() - k.kept.size());
      writer.append(numbered_line(7));
    }
    EXPECT_EQ(read_file(file), k.kept + numbered_line(7));
    fs::remove(file);
  }
}

TEST(LogWriter, ANewRunCutsThePartialLastLineAKilledEarlierRunLeft) {
  const TempDir dir;
  // The earlier run's last file, cut off mid-line by a kill; an older file
  // of it and another prefix's file, which are not this writer's business.
  const fs::path killed = dir.path() / "detections-20261201T070000Z-001.jsonl";
  const fs::path older = dir.path() / "detections-20261201T070000Z-000.jsonl";
  const fs::path other = dir.path() / "points-20261201T080000Z-000.jsonl";
  write_file(killed, numbered_line(0) + "{\"n\":1,\"pa");
  write_file(older, numbered_line(5));
  write_file(other, "{\"x\":");
  {
    LogWriter writer(config_for(dir.path(), "20261201T073000Z"));
    EXPECT_EQ(writer.stats().tails_repaired, 1U);
    writer.append(numbered_line(2));
  }
  EXPECT_EQ(read_file(killed), numbered_line(0));
  EXPECT_EQ(read_file(older), numbered_line(5));
  EXPECT_EQ(read_file(other), "{\"x\":");
  EXPECT_EQ(read_file(dir.path() / "detections-20261201T073000Z-000.jsonl"), numbered_line(2));
}

TEST(LogWriter, ReopenFollowsLogrotate) {
  const TempDir dir;
  const fs::path file = dir.path() / "detections-run1-000.jsonl";
  LogWriter writer(config_for(dir.path()));
  writer.append(numbered_line(0));
  fs::rename(file, dir.path() / "detections-run1-000.jsonl.1");  // logrotate's create mode
  writer.append(numbered_line(1));                               // still the renamed file, until SIGHUP
  writer.reopen();
  writer.append(numbered_line(2));
  writer.reopen();  // nothing renamed: the same file, continued
  writer.append(numbered_line(3));
  EXPECT_EQ(read_file(dir.path() / "detections-run1-000.jsonl.1"), numbered_line(0) + numbered_line(1));
  EXPECT_EQ(read_file(file), numbered_line(2) + numbered_line(3));
  EXPECT_EQ(writer.current_path(), file);
}

// --- fsync policies ---

TEST(LogWriterFsync, EveryLineSyncsEachLineAndCloseSyncsAgain) {
  const TempDir dir;
  LogWriterConfig c = config_for(dir.path());
  c.fsync = FsyncPolicy::every_line;
  LogWriter writer(c);
  for (int i = 0; i < 5; ++i) {
    writer.append(numbered_line(i));
    EXPECT_EQ(writer.stats().fsyncs, static_cast<std::uint64_t>(i + 1));
  }
  EXPECT_FALSE(writer.sync_deadline());
  writer.reopen();
  EXPECT_EQ(writer.stats().fsyncs, 6U);
}

TEST(LogWriterFsync, NeverSyncsOnlyOnCloseAndRotation) {
  const TempDir dir;
  LogWriterConfig c = config_for(dir.path());
  c.max_bytes = 3 * numbered_line(0).size();
  LogWriter writer(c);
  for (int i = 0; i < 3; ++i) writer.append(numbered_line(i));
  EXPECT_EQ(writer.stats().fsyncs, 0U);
  EXPECT_FALSE(writer.sync_deadline());
  writer.append(numbered_line(3));  // rotates
  EXPECT_EQ(writer.stats().fsyncs, 1U);
  writer.start_run("run2");
  EXPECT_EQ(writer.stats().fsyncs, 2U);
}

TEST(LogWriterFsync, IntervalSyncsEveryLineWithinItsInterval) {
  const TempDir dir;
  auto now = std::make_shared<std::chrono::steady_clock::time_point>(std::chrono::steady_clock::time_point(1000s));
  const auto t0 = *now;
  LogWriterConfig c = config_for(dir.path());
  c.fsync = FsyncPolicy::interval;
  c.fsync_interval = 1000ms;
  c.clock = [now] { return *now; };
  LogWriter writer(c);
  EXPECT_FALSE(writer.sync_deadline()) << "nothing written, nothing to sync";

  writer.append(numbered_line(0));
  ASSERT_TRUE(writer.sync_deadline());
  EXPECT_EQ(*writer.sync_deadline(), t0 + 1000ms);
  *now = t0 + 999ms;
  writer.sync_if_due();
  writer.append(numbered_line(1));  // the oldest unsynced line sets the deadline
  EXPECT_EQ(*writer.sync_deadline(), t0 + 1000ms);
  EXPECT_EQ(writer.stats().fsyncs, 0U);

  *now = t0 + 1000ms;  // the owner's timer fires, no line coming
  writer.sync_if_due();
  EXPECT_EQ(writer.stats().fsyncs, 1U);
  EXPECT_FALSE(writer.sync_deadline());
  writer.sync_if_due();
  EXPECT_EQ(writer.stats().fsyncs, 1U) << "nothing new to sync";

  *now = t0 + 5s;
  writer.append(numbered_line(2));
  EXPECT_EQ(*writer.sync_deadline(), t0 + 6s);
  *now = t0 + 7s;  // the owner was late; the next append syncs
  writer.append(numbered_line(3));
  EXPECT_EQ(writer.stats().fsyncs, 2U);
  EXPECT_FALSE(writer.sync_deadline());

  LogWriterConfig zero = c;
  zero.fsync_interval = 0ms;
  EXPECT_THROW(LogWriter{zero}, std::invalid_argument);
  EXPECT_EQ(to_string(FsyncPolicy::every_line), "every_line");
  EXPECT_EQ(fsync_policy_from_name("interval"), FsyncPolicy::interval);
  EXPECT_FALSE(fsync_policy_from_name("sometimes"));
}

// --- errors ---

TEST(LogWriterErrors, AMissingOrUnusableDirectoryNamesThePathAndTheCause) {
  const TempDir dir;
  const auto expect_error = [](const LogWriterConfig& c, const std::string& path, const std::string& cause) {
    try {
      LogWriter writer(c);
      ADD_FAILURE() << "no error for " << path;
    } catch (const LogWriteError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(path), std::string::npos) << what;
      EXPECT_NE(what.find(cause), std::string::npos) << what;
      EXPECT_EQ(e.path().string().find(path), 0U) << e.path();
    }
  };
  expect_error(config_for(dir.path() / "gone"), (dir.path() / "gone").string(), "No such file or directory");
  write_file(dir.path() / "plain-file", "x");
  expect_error(config_for(dir.path() / "plain-file"), (dir.path() / "plain-file").string(), "Not a directory");
  if (::geteuid() != 0) {  // root writes anywhere: the mode is no obstacle to it
    fs::create_directory(dir.path() / "read-only");
    fs::permissions(dir.path() / "read-only", fs::perms::owner_read | fs::perms::owner_exec);
    expect_error(config_for(dir.path() / "read-only"), (dir.path() / "read-only").string(), "Permission denied");
  }
}

TEST(LogWriterErrors, ADirectoryGoneWhileWritingFailsTheRotationClearlyAndKeepsTheLines) {
  const TempDir dir;
  const fs::path logs = dir.path() / "logs";
  fs::create_directory(logs);
  LogWriterConfig c = config_for(logs);
  c.max_bytes = 2 * numbered_line(0).size();
  LogWriter writer(c);
  writer.append(numbered_line(0));
  const fs::path kept = dir.path() / "kept.jsonl";
  fs::rename(logs / "detections-run1-000.jsonl", kept);
  fs::remove(logs);
  writer.append(numbered_line(1));  // the open file is still there
  try {
    writer.append(numbered_line(2));
    ADD_FAILURE() << "rotation into a removed directory did not fail";
  } catch (const LogWriteError& e) {
    EXPECT_EQ(e.path(), logs / "detections-run1-001.jsonl");
    EXPECT_NE(std::string(e.what()).find("cannot create"), std::string::npos) << e.what();
    EXPECT_EQ(e.error(), std::errc::no_such_file_or_directory);
  }
  EXPECT_EQ(writer.stats().write_errors, 1U);
  EXPECT_EQ(read_file(kept), numbered_line(0) + numbered_line(1));
  // The directory comes back: the next line goes on where the file left off.
  fs::create_directory(logs);
  writer.append(numbered_line(2));
  EXPECT_EQ(read_file(logs / "detections-run1-000.jsonl"), numbered_line(2));
}

// A child process meets a file-size limit (as a full disk would stop it): the
// line that crosses it is written short, then refused; the writer cuts the
// short part off again and reports the file and the cause.
TEST(LogWriterErrors, AWriteThatCannotFinishLeavesOnlyWholeLines) {
  const TempDir dir;
  const std::size_t line_size = numbered_line(0).size();
  const rlim_t limit = 5 * line_size + line_size / 2;
  const fs::path report = dir.path() / "error.txt";
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::signal(SIGXFSZ, SIG_IGN);  // EFBIG instead of death
    const rlimit rl{limit, limit};
    ::setrlimit(RLIMIT_FSIZE, &rl);
    int code = 1;
    try {
      LogWriter writer(config_for(dir.path()));
      for (int i = 0; i < 100; ++i) writer.append(numbered_line(i));
    } catch (const LogWriteError& e) {
      std::ofstream(report) << e.what() << '\n' << e.error().value();
      code = 0;
    } catch (...) {
      code = 2;
    }
    ::_exit(code);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "the child saw no LogWriteError";
  const std::string message = read_file(report);
  EXPECT_NE(message.find((dir.path() / "detections-run1-000.jsonl").string() + ": cannot write: File too large"),
            std::string::npos)
      << message;
  std::string expected;
  for (int i = 0; i < 5; ++i) expected += numbered_line(i);
  EXPECT_EQ(read_file(dir.path() / "detections-run1-000.jsonl"), expected);
}

// --- kill -9 ---

// Parses every complete line of the run's files, in order, and checks that
// the sequence numbers run on from `first` without a gap. Returns the next
// sequence number, the partial line the last file ends in (if any) and where
// the last file begins.
struct RunContent {
  std::uint64_t next = 0;
  std::string tail;
  std::uint64_t last_file_first = 0;
};
RunContent check_run(const fs::path& dir, const std::string& run, std::uint64_t max_bytes, std::uint64_t first) {
  RunContent out;
  out.next = first;
  const auto files = run_files(dir, run);
  for (std::size_t f = 0; f < files.size(); ++f) {
    out.last_file_first = out.next;
    const std::string content = read_file(files[f]);
    EXPECT_LE(content.size(), max_bytes) << files[f];
    std::size_t begin = 0;
    while (begin < content.size()) {
      const std::size_t end = content.find('\n', begin);
      if (end == std::string::npos) {
        EXPECT_EQ(f, files.size() - 1) << "a partial line before the last file: " << files[f];
        out.tail = content.substr(begin);
        break;
      }
      const auto j = nlohmann::json::parse(content.substr(begin, end - begin), nullptr, false);
      EXPECT_FALSE(j.is_discarded()) << files[f] << " at byte " << begin;
      if (j.is_discarded()) return out;
      EXPECT_EQ(j.at("frame").at("sequence").get<std::uint64_t>(), out.next) << files[f] << " at byte " << begin;
      out.next = j.at("frame").at("sequence").get<std::uint64_t>() + 1;
      begin = end + 1;
    }
  }
  return out;
}

std::uintmax_t run_bytes(const fs::path& dir, const std::string& run) {
  std::uintmax_t total = 0;
  for (const auto& f : run_files(dir, run)) {
    std::error_code ignored;  // a file the child is creating right now
    const std::uintmax_t size = fs::file_size(f, ignored);
    if (!ignored) total += size;
  }
  return total;
}

// Removes the run's files but the newest, once checked: keeps the test's
// disk use and its checking time per round bounded.
void remove_older_files(const fs::path& dir, const std::string& run) {
  auto files = run_files(dir, run);
  if (!files.empty()) files.pop_back();
  for (const auto& f : files) fs::remove(f);
}

// Kills the child on every way out of the test.
struct ChildGuard {
  pid_t pid = -1;
  ~ChildGuard() {
    if (pid > 0) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, nullptr, 0);
    }
  }
};

TEST(LogWriterKill, SigkillAtRandomMomentsNeverLeavesATornOrMissingLine) {
  const TempDir dir;
  const samples::Stream stream;
  const std::string run = "kill";
  constexpr std::uint64_t kMaxBytes = 1024 * 1024;  // rotations happen under fire too
  constexpr int kRounds = 100;
  std::mt19937 rng(20240501);
  std::uniform_int_distribution<int> delay_us(0, 10'000);
  int torn_tails = 0;
  RunContent content;

  for (int round = 0; round < kRounds; ++round) {
    const std::uint64_t start = content.next;
    const std::uintmax_t bytes_before = run_bytes(dir.path(), run);
    ChildGuard child;
    child.pid = ::fork();
    ASSERT_GE(child.pid, 0);
    if (child.pid == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);
      try {
        LogWriterConfig c = config_for(dir.path(), run);
        c.max_bytes = kMaxBytes;
        LogWriter writer(c);
        DetectionRecordFormatter formatter;
        for (std::uint64_t seq = start; seq < start + 1'000'000; ++seq) writer.append(formatter.format(stream.at(seq)));
      } catch (...) {
        ::_exit(3);
      }
      ::_exit(4);  // never killed: the parent's wait below reports it
    }
    // Kill a child that is writing, not one still starting (slow under ASan):
    // wait for its first bytes, then a random moment.
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (run_bytes(dir.path(), run) == bytes_before) {
      ASSERT_LT(std::chrono::steady_clock::now(), deadline) << "the child wrote nothing in 60 s";
      std::this_thread::sleep_for(100us);
    }
    std::this_thread::sleep_for(std::chrono::microseconds(delay_us(rng)));
    ASSERT_EQ(::kill(child.pid, SIGKILL), 0);
    int status = 0;
    ASSERT_EQ(::waitpid(child.pid, &status, 0), child.pid);
    child.pid = -1;
    ASSERT_TRUE(WIFSIGNALED(status)) << "the writer exited by itself with " << WEXITSTATUS(status);

    content = check_run(dir.path(), run, kMaxBytes, content.last_file_first);
    ASSERT_FALSE(HasFailure()) << "round " << round;
    remove_older_files(dir.path(), run);
    ASSERT_GE(content.next, start) << "round " << round << " lost lines that were written";
    if (!content.tail.empty()) {
      ++torn_tails;
      // The only damage a kill can do: the next record, begun and not ended.
      DetectionRecordFormatter formatter;
      const std::string_view next = formatter.format(stream.at(content.next));
      EXPECT_TRUE(next.starts_with(content.tail))
          << "round " << round << ": the tail is no prefix of record " << content.next;
    }
  }
  // The last writer's leftovers are repaired by the next one to open the run.
  {
    LogWriterConfig c = config_for(dir.path(), run);
    c.max_bytes = kMaxBytes;
    LogWriter writer(c);
    EXPECT_EQ(writer.stats().tails_repaired, content.tail.empty() ? 0U : 1U);
    DetectionRecordFormatter formatter;
    writer.append(formatter.format(stream.at(content.next)));
  }
  const RunContent final_content = check_run(dir.path(), run, kMaxBytes, content.last_file_first);
  EXPECT_TRUE(final_content.tail.empty());
  EXPECT_EQ(final_content.next, content.next + 1);
  EXPECT_GT(content.next, static_cast<std::uint64_t>(kRounds)) << "the children wrote too little to prove anything";
  std::cout << "[ figures  ] " << kRounds << " kills, " << content.next << " lines, the last file "
            << run_files(dir.path(), run).back().filename() << ", " << torn_tails
            << " kills left a partial last line (repaired on the next open)\n";
}

}  // namespace
}  // namespace markerd::daemon
