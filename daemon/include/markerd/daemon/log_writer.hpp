#pragma once
// The detection log's file writer: appends whole lines to
// <directory>/<prefix>-<run id>-<NNN>.jsonl, rotating by size and by run,
// syncing by a stated policy. Durability rests on three things
// (docs/detection-log.md): each line goes to the kernel in one write() on a
// file opened O_APPEND, complete in memory first; a failed write is cut back
// to where its line began; and opening a file cuts off a partial last line
// (what a kill inside write() or a power cut leaves) before anything is
// appended.
//
// Thread model: one thread owns a LogWriter and makes every call (the
// pipeline's log stage). SIGHUP is handled by that thread calling reopen(),
// never from the signal handler. Only stats() may be called from any thread.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>

#include "markerd/base/unique_fd.hpp"

namespace markerd::daemon {

enum class FsyncPolicy : std::uint8_t {
  never,       // the kernel writes back when it chooses; lines survive a crash of markerd, not of the machine
  interval,    // every line is on disk within `fsync_interval` of being written (see sync_deadline())
  every_line,  // each append() returns after its line is on disk
};
[[nodiscard]] std::string_view to_string(FsyncPolicy policy);
[[nodiscard]] std::optional<FsyncPolicy> fsync_policy_from_name(std::string_view name);

struct LogWriterConfig {
  std::filesystem::path directory;  // must exist (systemd's LogsDirectory=); never created here
  std::string prefix = "detections";
  std::string run_id;  // letters, digits, '.', '_' and '-'; not starting with '.'; see make_run_id()
  // A new file when the next line would take the current one past this size;
  // 0: no limit. A single line longer than this gets a file of its own.
  std::uint64_t max_bytes = 256ULL << 20;
  FsyncPolicy fsync = FsyncPolicy::interval;
  std::chrono::milliseconds fsync_interval{1000};
  // The clock of the interval policy; tests substitute their own.
  std::function<std::chrono::steady_clock::time_point()> clock = [] { return std::chrono::steady_clock::now(); };
};

// A failure to open, write, sync or close a log file: what() names the file
// and the cause ("detection log /var/log/markerd/detections-x-000.jsonl:
// cannot write: No space left on device").
class LogWriteError : public std::runtime_error {
 public:
  LogWriteError(std::filesystem::path path, std::string_view action, std::error_code error);
  [[nodiscard]] const std::filesystem::path& path() const { return path_; }
  [[nodiscard]] std::error_code error() const { return error_; }

 private:
  std::filesystem::path path_;
  std::error_code error_;
};

struct LogWriterStats {
  std::uint64_t lines = 0;
  std::uint64_t bytes = 0;
  std::uint64_t fsyncs = 0;          // completed syncs of a log file's data
  std::uint64_t files_opened = 0;    // created or continued
  std::uint64_t tails_repaired = 0;  // partial last lines cut off on open
  std::uint64_t tail_bytes_cut = 0;
  std::uint64_t write_errors = 0;  // append() calls that threw
};

// "20240501T120000Z": a run id from a UTC time, sortable as text.
[[nodiscard]] std::string make_run_id(std::chrono::system_clock::time_point t);

class LogWriter {
 public:
  // Continues the run's newest file when one exists and has room (after
  // cutting a partial last line), otherwise creates the run's next file (a
  // new run first cuts a partial last line off the newest file of an
  // earlier run of the prefix: a killed writer's).
  // Throws LogWriteError when it can do neither, std::invalid_argument for a
  // bad run id or prefix.
  explicit LogWriter(LogWriterConfig config);
  ~LogWriter();  // syncs and closes; a failure then is logged, not thrown
  LogWriter(const LogWriter&) = delete;
  LogWriter& operator=(const LogWriter&) = delete;

  // Appends one complete line (ends with '\n', holds no other '\n';
  // std::invalid_argument otherwise) in one write(), rotating first when it
  // would not fit. On a failure (disk full, file too large, directory gone)
  // throws LogWriteError with whatever part of the line reached the file cut
  // off again, so the lines before it stay intact; the next append() tries
  // again (reopening the file first if it had to be closed).
  void append(std::string_view line);

  // The interval policy's timer: when the oldest unsynced line was written
  // `fsync_interval` ago, or earlier, sync now. append() calls it too; the
  // owner calls it by sync_deadline() when no lines come, e.g. by bounding
  // its wait for the next record.
  void sync_if_due();
  // When sync_if_due() must next be called; empty when nothing waits for a
  // sync (or the policy is not `interval`).
  [[nodiscard]] std::optional<std::chrono::steady_clock::time_point> sync_deadline() const;
  void sync();  // now, whatever the policy

  // Syncs and closes the file and opens the same name again: after
  // logrotate has renamed it, a new file; otherwise the same one, continued.
  void reopen();
  // Syncs and closes the file and starts the new run's first file.
  void start_run(std::string run_id);

  [[nodiscard]] const std::filesystem::path& current_path() const { return path_; }
  [[nodiscard]] const std::string& run_id() const { return config_.run_id; }
  [[nodiscard]] LogWriterStats stats() const;

 private:
  void open_run();  // the run's newest file if it has room, else its next one
  bool open_file(unsigned index, bool create_only);
  void cut_partial_last_line();
  void repair_previous_run();
  void rotate();
  void close_file();  // syncs, then closes; throws on failure
  void write_whole(std::string_view line);
  [[nodiscard]] std::filesystem::path file_path(unsigned index) const;

  LogWriterConfig config_;
  UniqueFd fd_;
  unsigned index_ = 0;  // NNN of the current file
  std::filesystem::path path_;
  std::uint64_t file_bytes_ = 0;
  std::optional<std::chrono::steady_clock::time_point> oldest_unsynced_;

  // Counters: written by the owning thread only, read by stats() from any thread.
  struct Counters {
    std::atomic<std::uint64_t> lines{0}, bytes{0}, fsyncs{0}, files_opened{0}, tails_repaired{0}, tail_bytes_cut{0},
        write_errors{0};
  } counters_;
};

}  // namespace markerd::daemon
