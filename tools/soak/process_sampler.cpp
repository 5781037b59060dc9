#include "process_sampler.hpp"

#include <fmt/format.h>

#include <stdexcept>
#include <string_view>
#include <system_error>

namespace markerd::soak {

namespace fs = std::filesystem;

namespace {

int count_entries(const fs::path& directory, bool& gone) {
  std::error_code ec;
  int n = 0;
  for (fs::directory_iterator it(directory, ec), end; !ec && it != end; it.increment(ec)) ++n;
  if (ec) gone = true;
  return n;
}

}  // namespace

std::optional<ProcessUsage> read_process_usage(pid_t pid) {
  const fs::path proc = fs::path("/proc") / std::to_string(pid);
  std::ifstream status(proc / "status");
  if (!status) return std::nullopt;
  ProcessUsage usage;
  bool have_rss = false;
  for (std::string line; std::getline(status, line);) {
    constexpr std::string_view key = "VmRSS:";
    if (line.compare(0, key.size(), key) == 0) {
      usage.rss_kib = std::stoll(line.substr(key.size()));  // "  12345 kB"
      have_rss = true;
    }
  }
  if (!have_rss) return std::nullopt;  // a zombie has no memory to report
  bool gone = false;
  usage.threads = count_entries(proc / "task", gone);
  usage.fds = count_entries(proc / "fd", gone);
  if (gone) return std::nullopt;
  return usage;
}

std::vector<fs::path> open_files(pid_t pid) {
  std::vector<fs::path> files;
  std::error_code ec;
  const fs::path fd_dir = fs::path("/proc") / std::to_string(pid) / "fd";
  for (fs::directory_iterator it(fd_dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code link_ec;
    const fs::path target = fs::read_symlink(it->path(), link_ec);
    if (!link_ec) files.push_back(target);
  }
  return files;
}

SampleLog::SampleLog(const fs::path& file) : out_(file) {
  if (!out_) throw std::runtime_error("cannot write " + file.string());
  out_ << "elapsed_s,instance,pid,uptime_s,rss_kib,threads,fds,followers,sweep_state,disk_full\n";
  out_.flush();
}

void SampleLog::append(const Sample& s) {
  out_ << fmt::format("{:.1f},{},{},{:.1f},{},{},{},{},{},{}\n", s.elapsed_s, s.instance, s.pid, s.uptime_s,
                      s.usage.rss_kib, s.usage.threads, s.usage.fds, s.followers,
                      s.sweep_state.empty() ? "-" : s.sweep_state, s.disk_full ? 1 : 0);
  out_.flush();
}

double slope(const std::vector<double>& x, const std::vector<double>& y) {
  const std::size_t n = std::min(x.size(), y.size());
  if (n < 2) return 0;
  double mx = 0;
  double my = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mx += x[i];
    my += y[i];
  }
  mx /= static_cast<double>(n);
  my /= static_cast<double>(n);
  double sxy = 0;
  double sxx = 0;
  for (std::size_t i = 0; i < n; ++i) {
    sxy += (x[i] - mx) * (y[i] - my);
    sxx += (x[i] - mx) * (x[i] - mx);
  }
  return sxx > 0 ? sxy / sxx : 0;
}

}  // namespace markerd::soak
