// The log stage's cost per record: formatting a frame outcome as a JSON line,
// and formatting plus appending it to a file under each fsync policy.

#include <benchmark/benchmark.h>
#include <stdlib.h>

#include <filesystem>
#include <string>

#include "detection_log_samples.hpp"
#include "markerd/daemon/detection_record.hpp"
#include "markerd/daemon/log_writer.hpp"

namespace {

using markerd::daemon::DetectionRecordFormatter;
using markerd::daemon::FsyncPolicy;
using markerd::daemon::LogWriter;
using markerd::daemon::LogWriterConfig;
namespace samples = markerd::daemon::samples;
namespace fs = std::filesystem;

// Records with 1, 3, 5 and 7 posed detections in turn (about 0.6 to 4 KB).
void BM_FormatRecord(benchmark::State& state) {
  const samples::Stream stream;
  DetectionRecordFormatter formatter;
  std::uint64_t seq = 0;
  std::size_t bytes = 0;
  for (auto _ : state) {
    const std::string_view line = formatter.format(stream.at(seq++));
    bytes += line.size();
    benchmark::DoNotOptimize(line.data());
  }
  state.SetBytesProcessed(static_cast<std::int64_t>(bytes));
}
BENCHMARK(BM_FormatRecord);

void BM_FormatAndAppend(benchmark::State& state) {
  std::string dir = (fs::temp_directory_path() / "markerd-bench-log-XXXXXX").string();
  if (::mkdtemp(dir.data()) == nullptr) {
    state.SkipWithError("mkdtemp failed");
    return;
  }
  {
    const samples::Stream stream;
    LogWriterConfig config;
    config.directory = dir;
    config.run_id = "bench";
    config.max_bytes = 64ULL << 20;
    config.fsync = static_cast<FsyncPolicy>(state.range(0));
    LogWriter writer(config);
    DetectionRecordFormatter formatter;
    std::uint64_t seq = 0;
    for (auto _ : state) {
      writer.append(formatter.format(stream.at(seq++)));
      writer.sync_if_due();
    }
    state.SetBytesProcessed(static_cast<std::int64_t>(writer.stats().bytes));
    state.SetLabel(std::string(markerd::daemon::to_string(config.fsync)));
  }
  fs::remove_all(dir);
}
BENCHMARK(BM_FormatAndAppend)
    ->Arg(static_cast<int>(FsyncPolicy::never))
    ->Arg(static_cast<int>(FsyncPolicy::interval))
    ->Arg(static_cast<int>(FsyncPolicy::every_line))
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
