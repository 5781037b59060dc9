#include "markerd/daemon/log_writer.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <exception>
#include <utility>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/base/utc_time.hpp"

namespace markerd::daemon {

namespace {

std::error_code errno_code(int error) { return {error, std::generic_category()}; }

// Names become file names: nothing that could leave the directory, hide the
// file, or make "<prefix>-<run>-<NNN>.jsonl" ambiguous to the shell.
void check_name_part(std::string_view what, std::string_view name) {
  const bool valid = !name.empty() && name.front() != '.' && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == '-';
  });
  if (!valid) {
    throw std::invalid_argument(
        fmt::format("detection log {} '{}': use letters, digits, '.', '_' and '-', not starting with '.'", what, name));
  }
}

// The NNN of "<stem><NNN>.jsonl", or nothing for another name.
std::optional<unsigned> file_index(std::string_view name, std::string_view stem) {
  constexpr std::string_view kSuffix = ".jsonl";
  if (name.size() <= stem.size() + kSuffix.size() || !name.starts_with(stem) || !name.ends_with(kSuffix)) {
    return std::nullopt;
  }
  const std::string_view digits = name.substr(stem.size(), name.size() - stem.size() - kSuffix.size());
  if (digits.size() > 9 || !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    return std::nullopt;
  }
  unsigned index = 0;
  for (const char c : digits) index = index * 10 + static_cast<unsigned>(c - '0');
  return index;
}

// Makes a new directory entry survive a power cut (the file's own sync does
// not cover the entry). Where the file system cannot sync a directory, the
// entry is as durable as that file system makes it: worth a warning, no more.
void sync_directory(const std::filesystem::path& directory) {
  const UniqueFd fd(::open(directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (!fd || ::fsync(fd.get()) != 0) {
    spdlog::warn("detection log directory {}: cannot sync: {}", directory.string(), errno_text(errno));
  }
}

}  // namespace

std::string_view to_string(FsyncPolicy policy) {
  switch (policy) {
    case FsyncPolicy::never: return "never";
    case FsyncPolicy::interval: return "interval";
    case FsyncPolicy::every_line: return "every_line";
  }
  return "unknown";
}

std::optional<FsyncPolicy> fsync_policy_from_name(std::string_view name) {
  for (const FsyncPolicy p : {FsyncPolicy::never, FsyncPolicy::interval, FsyncPolicy::every_line}) {
    if (to_string(p) == name) return p;
  }
  return std::nullopt;
}

LogWriteError::LogWriteError(std::filesystem::path path, std::string_view action, std::error_code error)
    : std::runtime_error(fmt::format("detection log {}: {}: {}", path.string(), action, error.message())),
      path_(std::move(path)),
      error_(error) {}

std::string make_run_id(std::chrono::system_clock::time_point t) { return format_utc(t, UtcForm::compact); }

LogWriter::LogWriter(LogWriterConfig config) : config_(std::move(config)) {
  check_name_part("prefix", config_.prefix);
  check_name_part("run id", config_.run_id);
  if (config_.fsync == FsyncPolicy::interval && config_.fsync_interval <= std::chrono::milliseconds::zero()) {
    throw std::invalid_argument("detection log: the fsync interval must be more than zero");
  }
  open_run();
}

LogWriter::~LogWriter() {
  try {
    close_file();
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
  }
}

std::filesystem::path LogWriter::file_path(unsigned index) const {
  return config_.directory / fmt::format("{}-{}-{:03}.jsonl", config_.prefix, config_.run_id, index);
}

void LogWriter::open_run() {
  const std::string stem = fmt::format("{}-{}-", config_.prefix, config_.run_id);
  std::optional<unsigned> newest;
  std::error_code error;
  for (std::filesystem::directory_iterator it(config_.directory, error), end; !error && it != end;
       it.increment(error)) {
    if (const auto index = file_index(it->path().filename().native(), stem)) {
      newest = std::max(newest.value_or(0), *index);
    }
  }
  if (error) throw LogWriteError(config_.directory, "cannot list the log directory", error);

  if (newest) {
    open_file(*newest, false);
    if (config_.max_bytes == 0 || file_bytes_ < config_.max_bytes) return;
    rotate();
  } else {
    repair_previous_run();
    index_ = 0;
    if (!open_file(0, true)) rotate();  // created meanwhile by someone else: never append to it
  }
}

// A writer killed inside write() leaves a partial line at the end of its
// run's last file, and the next markerd starts a run of its own, in files of
// its own: so before it does, it cuts that tail, and every file in the
// directory holds whole lines only. Run ids sort as text, so the newest file
// of the prefix is the greatest name.
void LogWriter::repair_previous_run() {
  const std::string prefix = config_.prefix + "-";
  std::filesystem::path newest;
  std::error_code error;
  for (std::filesystem::directory_iterator it(config_.directory, error), end; !error && it != end;
       it.increment(error)) {
    const std::string name = it->path().filename().string();
    if (name.size() > prefix.size() + 6 && name.compare(0, prefix.size(), prefix) == 0 && name.ends_with(".jsonl") &&
        name > newest.filename().string()) {
      newest = it->path();
    }
  }
  if (newest.empty()) return;
  UniqueFd fd(::open(newest.c_str(), O_RDWR | O_CLOEXEC));
  struct stat st {};
  if (!fd || ::fstat(fd.get(), &st) != 0) {
    spdlog::warn("detection log {}: cannot open it to check its last line: {}", newest.string(), errno_text(errno));
    return;
  }
  fd_ = std::move(fd);
  path_ = newest;
  file_bytes_ = static_cast<std::uint64_t>(st.st_size);
  try {
    if (file_bytes_ > 0) cut_partial_last_line();
  } catch (const LogWriteError& e) {
    spdlog::warn("{} (the lines before it are intact)", e.what());
  }
  fd_.reset();
  path_.clear();
  file_bytes_ = 0;
  oldest_unsynced_.reset();
}

// Opens the file of `index`: with `create_only` a new file or nothing (false
// when the name exists), otherwise the existing file continued or a new one.
// An existing file's partial last line is cut off before anything is added.
bool LogWriter::open_file(unsigned index, bool create_only) {
  std::filesystem::path path = file_path(index);
  const int flags = O_RDWR | O_APPEND | O_CLOEXEC | O_CREAT | (create_only ? O_EXCL : 0);
  UniqueFd fd(::open(path.c_str(), flags, 0640));
  if (!fd) {
    if (create_only && errno == EEXIST) return false;
    throw LogWriteError(std::move(path), create_only ? "cannot create" : "cannot open", errno_code(errno));
  }
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) throw LogWriteError(std::move(path), "cannot stat", errno_code(errno));
  fd_ = std::move(fd);
  index_ = index;
  path_ = std::move(path);
  file_bytes_ = static_cast<std::uint64_t>(st.st_size);
  oldest_unsynced_.reset();
  counters_.files_opened.fetch_add(1, std::memory_order_relaxed);
  try {
    if (file_bytes_ > 0) cut_partial_last_line();
  } catch (const LogWriteError&) {
    fd_.reset();  // not left open on a tail nobody could cut
    throw;
  }
  sync_directory(config_.directory);
  return true;
}

// A file that does not end in '\n' ends in part of a line: a writer killed
// inside write() (the kernel copies page by page and stops between pages for
// a fatal signal) or a power cut that lost the tail. Cutting it back to the
// last '\n' makes the next line start on a line of its own.
void LogWriter::cut_partial_last_line() {
  std::array<char, 4096> chunk{};
  std::uint64_t end = file_bytes_;  // the part after `end` holds no '\n'
  std::uint64_t keep = 0;
  while (end > 0) {
    const std::size_t size = static_cast<std::size_t>(std::min<std::uint64_t>(chunk.size(), end));
    const std::uint64_t offset = end - size;
    std::size_t got = 0;
    while (got < size) {
      const ssize_t n = ::pread(fd_.get(), chunk.data() + got, size - got, static_cast<off_t>(offset + got));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) throw LogWriteError(path_, "cannot read its last line", errno_code(n < 0 ? errno : EIO));
      got += static_cast<std::size_t>(n);
    }
    if (const void* newline = ::memrchr(chunk.data(), '\n', size)) {
      keep = offset + static_cast<std::uint64_t>(static_cast<const char*>(newline) - chunk.data()) + 1;
      break;
    }
    end = offset;
  }
  if (keep == file_bytes_) return;
  const std::uint64_t cut = file_bytes_ - keep;
  if (::ftruncate(fd_.get(), static_cast<off_t>(keep)) != 0) {
    throw LogWriteError(path_, "cannot cut off its partial last line", errno_code(errno));
  }
  file_bytes_ = keep;
  counters_.tails_repaired.fetch_add(1, std::memory_order_relaxed);
  counters_.tail_bytes_cut.fetch_add(cut, std::memory_order_relaxed);
  spdlog::warn(
      "detection log {}: cut off a partial last line of {} bytes (a write interrupted by a kill or a power cut)",
      path_.string(), cut);
  sync();  // the cut is on disk before any line follows it
}

void LogWriter::rotate() {
  std::exception_ptr close_failure;
  try {
    close_file();
  } catch (const LogWriteError&) {
    close_failure = std::current_exception();  // the old file's problem: still move on to a new one
  }
  unsigned index = index_ + 1;
  while (!open_file(index, true)) ++index;  // never onto an existing file
  if (close_failure) std::rethrow_exception(close_failure);
}

void LogWriter::close_file() {
  if (!fd_) return;
  std::exception_ptr failure;
  try {
    sync();
  } catch (const LogWriteError&) {
    failure = std::current_exception();
  }
  // Linux closes the descriptor even when close() reports an error: never retry.
  if (fd_.close() != 0 && !failure && errno != EINTR) {
    failure = std::make_exception_ptr(LogWriteError(path_, "cannot close", errno_code(errno)));
  }
  if (failure) std::rethrow_exception(failure);
}

void LogWriter::append(std::string_view line) {
  if (line.empty() || line.back() != '\n' || std::memchr(line.data(), '\n', line.size() - 1) != nullptr) {
    throw std::invalid_argument("detection log: append() takes one complete line ending in '\\n'");
  }
  try {
    if (!fd_) open_file(index_, false);  // closed by an earlier failure
    if (config_.max_bytes != 0 && file_bytes_ > 0 && file_bytes_ + line.size() > config_.max_bytes) rotate();
    write_whole(line);
    counters_.lines.fetch_add(1, std::memory_order_relaxed);
    counters_.bytes.fetch_add(line.size(), std::memory_order_relaxed);
    switch (config_.fsync) {
      case FsyncPolicy::never: break;
      case FsyncPolicy::interval:
        if (!oldest_unsynced_) oldest_unsynced_ = config_.clock();
        sync_if_due();
        break;
      case FsyncPolicy::every_line: sync(); break;
    }
  } catch (const LogWriteError&) {
    counters_.write_errors.fetch_add(1, std::memory_order_relaxed);
    throw;
  }
}

// One write() for the whole line in all but the rarest case; a short write
// (a signal, a file-size limit reached) continues from where it stopped. If
// the line cannot be finished, the part that reached the file is cut off
// again, so the file still ends on a whole line.
void LogWriter::write_whole(std::string_view line) {
  std::size_t written = 0;
  while (written < line.size()) {
    const ssize_t n = ::write(fd_.get(), line.data() + written, line.size() - written);
    if (n > 0) {
      written += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    const int error = n < 0 ? errno : EIO;
    if (written > 0) {
      // O_APPEND put the part at the file's end, wherever that was.
      struct stat st {};
      if (::fstat(fd_.get(), &st) != 0 || ::ftruncate(fd_.get(), st.st_size - static_cast<off_t>(written)) != 0) {
        // Left for the repair on open: close, and the next append reopens.
        spdlog::error("detection log {}: cannot cut off a partly written line: {}", path_.string(), errno_text(errno));
        fd_.reset();
      }
    }
    throw LogWriteError(path_, "cannot write", errno_code(error));
  }
  file_bytes_ += line.size();
}

void LogWriter::sync_if_due() {
  const auto deadline = sync_deadline();
  if (deadline && config_.clock() >= *deadline) sync();
}

std::optional<std::chrono::steady_clock::time_point> LogWriter::sync_deadline() const {
  if (config_.fsync != FsyncPolicy::interval || !oldest_unsynced_) return std::nullopt;
  return *oldest_unsynced_ + config_.fsync_interval;
}

void LogWriter::sync() {
  if (!fd_) return;
  // fdatasync: the data and the file size, which is all a reader needs; the
  // timestamps can wait.
  int result = 0;
  do {
    result = ::fdatasync(fd_.get());
  } while (result != 0 && errno == EINTR);
  if (result != 0) throw LogWriteError(path_, "cannot sync", errno_code(errno));
  oldest_unsynced_.reset();
  counters_.fsyncs.fetch_add(1, std::memory_order_relaxed);
}

void LogWriter::reopen() {
  std::exception_ptr close_failure;
  try {
    close_file();
  } catch (const LogWriteError&) {
    close_failure = std::current_exception();
  }
  open_file(index_, false);
  if (close_failure) std::rethrow_exception(close_failure);
}

void LogWriter::start_run(std::string run_id) {
  check_name_part("run id", run_id);
  std::exception_ptr close_failure;
  try {
    close_file();
  } catch (const LogWriteError&) {
    close_failure = std::current_exception();
  }
  config_.run_id = std::move(run_id);
  open_run();
  if (close_failure) std::rethrow_exception(close_failure);
}

LogWriterStats LogWriter::stats() const {
  constexpr auto r = std::memory_order_relaxed;
  return {counters_.lines.load(r),        counters_.bytes.load(r),          counters_.fsyncs.load(r),
          counters_.files_opened.load(r), counters_.tails_repaired.load(r), counters_.tail_bytes_cut.load(r),
          counters_.write_errors.load(r)};
}

}  // namespace markerd::daemon
