// The log stage allocates nothing per record once warmed up: formatting a
// record and appending it to the file are counted in a binary of their own,
// which replaces operator new (as test_no_alloc does for the detector).

#include <gtest/gtest.h>
#include <stdlib.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <new>
#include <string>

#include "detection_log_samples.hpp"
#include "markerd/daemon/detection_record.hpp"
#include "markerd/daemon/log_writer.hpp"
#include "support/temp_dir.hpp"

#include "counting_new.hpp"

namespace markerd::daemon {
namespace {

namespace fs = std::filesystem;

TEST(LogNoAllocation, FormattingAndAppendingARecord) {
  const test_support::TempDir dir("markerd-test-log-alloc");
  {
    const samples::Stream stream;
    LogWriterConfig config;
    config.directory = dir.path();
    config.run_id = "alloc";
    config.max_bytes = 0;  // a rotation builds a path: allowed, but not per record
    config.fsync = FsyncPolicy::interval;
    config.fsync_interval = std::chrono::milliseconds(5);  // syncs happen while counting
    LogWriter writer(config);
    DetectionRecordFormatter formatter;
    for (std::uint64_t seq = 0; seq < 8; ++seq) writer.append(formatter.format(stream.at(seq)));  // warm-up

    g_allocations = 0;
    g_counting = true;
    std::size_t bytes = 0;
    for (std::uint64_t seq = 8; seq < 2008; ++seq) {
      const std::string_view line = formatter.format(stream.at(seq));
      bytes += line.size();
      writer.append(line);
      writer.sync_if_due();
    }
    g_counting = false;
    EXPECT_EQ(g_allocations.load(), 0);
    EXPECT_EQ(writer.stats().lines, 2008U);
    EXPECT_GT(bytes, 2000U * 1000U) << "records with detections, poses and truth";
  }
}

// The counter itself works: a string that grows is seen.
TEST(LogNoAllocation, CounterSeesAllocations) {
  g_allocations = 0;
  g_counting = true;
  std::string s(1000, 'x');
  g_counting = false;
  EXPECT_GE(g_allocations.load(), 1);
  EXPECT_EQ(s.size(), 1000U);
}

}  // namespace
}  // namespace markerd::daemon
