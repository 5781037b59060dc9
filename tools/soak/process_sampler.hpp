#pragma once
// markerd's resources as the kernel counts them (/proc/<pid>): resident
// memory, threads, open file descriptors; sampled every few seconds into a
// CSV, and the trend of a series of samples.

#include <sys/types.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

namespace markerd::soak {

struct ProcessUsage {
  std::int64_t rss_kib = 0;  // VmRSS
  int threads = 0;           // entries of /proc/<pid>/task
  int fds = 0;               // entries of /proc/<pid>/fd
};

// Nothing when the process has gone (or is a zombie without its tables).
std::optional<ProcessUsage> read_process_usage(pid_t pid);

// The files a process has open (the targets of /proc/<pid>/fd's links).
std::vector<std::filesystem::path> open_files(pid_t pid);

struct Sample {
  double elapsed_s = 0;  // since the soak began
  int instance = 0;      // which markerd (1: the first started; one more per restart)
  pid_t pid = 0;
  double uptime_s = 0;  // of this markerd
  ProcessUsage usage;
  int followers = 0;  // attached at the time
  std::string sweep_state;
  bool disk_full = false;
};

// Appends samples to a CSV file, a header first.
class SampleLog {
 public:
  explicit SampleLog(const std::filesystem::path& file);
  void append(const Sample& sample);

 private:
  std::ofstream out_;
};

// Least-squares slope of y over x (per unit of x); 0 with fewer than two points.
double slope(const std::vector<double>& x, const std::vector<double>& y);

}  // namespace markerd::soak
