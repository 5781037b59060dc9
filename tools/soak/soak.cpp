#include "soak.hpp"

#include <fmt/format.h>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "followers.hpp"
#include "log_watch.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "markerd/sweep/records.hpp"
#include "process_sampler.hpp"
#include "run_checks.hpp"
#include "small_disk.hpp"
#include "support/child_process.hpp"

namespace markerd::soak {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;
using namespace std::chrono_literals;
using test_support::read_file;
using test_support::write_file;

// Marks a work directory as the soak's, so that clearing it never removes
// anything else.
constexpr const char* kStamp = ".markerd-soak";
// How long a run may say "running" at one step (Soak::observe()).
constexpr auto kStillLimit = 60s;

// Seven points, two measurements of four frames each: fourteen steps, a run
// of some tens of seconds at a high time scale.
constexpr const char* kPlan = R"toml(name = "soak"
description = "the soak test's sweep (tools/soak)"
frames_per_point = 4
repeats = 2
settle_s = 0.1
point_timeout_s = 20
detection_threshold = 0.9
fault_timeout_s = 60

[marker]
family = "frame8"
id = 165
size_m = 0.08

[[grid]]
name = "distance"
distance_m = [0.4, 0.8, 1.2, 1.6]
angle_deg = [0.0]

[[grid]]
name = "angle"
distance_m = [0.5]
angle_deg = [20.0, 40.0, 60.0]
)toml";

Clock::duration duration_of(double s) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

std::string mib(std::int64_t kib) { return fmt::format("{:.1f} MiB", static_cast<double>(kib) / 1024.0); }

// Clears `dir` for a new soak: it must be empty, or a soak's.
void prepare_work_dir(const fs::path& dir) {
  fs::create_directories(dir);
  const bool empty = fs::is_empty(dir);
  if (!empty && !fs::exists(dir / kStamp)) {
    throw std::runtime_error(fmt::format(
        "{}: not empty and not a soak's work directory (no {}); give an empty or new one", dir.string(), kStamp));
  }
  SmallDisk::unmount_stale(dir / "disk");
  for (const auto& entry : fs::directory_iterator(dir)) fs::remove_all(entry.path());
  write_file(dir / kStamp, "a markerd soak's work directory; the next soak clears it\n");
}

// An exponentially distributed wait with the given rate per hour (none: never).
Clock::time_point next_after(std::mt19937_64& rng, double per_hour) {
  if (per_hour <= 0) return Clock::time_point::max();
  return Clock::now() + duration_of(std::exponential_distribution<double>(per_hour / 3600.0)(rng));
}

class Soak {
 public:
  explicit Soak(const Options& o) : o_(o), rng_(o.seed) {}

  int run();

 private:
  // Setup.
  void write_configs();
  // markerd.
  void start_markerd();
  void kill_markerd();
  void markerd_ended_by_itself(int status);
  // One pass of the loop.
  void tick();
  void poll_status();
  void observe(const json& status);
  void start_run();
  void sample();
  void look_at_files();
  void archive(const std::filesystem::path& run);
  // The end.
  void finish();
  void wait_for_the_run_to_end();
  std::vector<std::filesystem::path> stop_markerd();
  void report();

  std::optional<json> call(const json& request);
  void problem(const std::string& what) {
    problems_.push_back(fmt::format("[{:.0f} s] {}", since(began_), what));
    std::cerr << "soak: " << problems_.back() << "\n";
  }

  const Options& o_;
  std::mt19937_64 rng_;
  Clock::time_point began_ = Clock::now();
  Clock::time_point end_ = began_;
  std::vector<std::string> problems_;

  fs::path dir_, logs_, state_, archive_, socket_, output_;
  std::string plan_text_;
  std::unique_ptr<SmallDisk> disk_;
  std::unique_ptr<SampleLog> samples_;
  std::unique_ptr<Followers> followers_;
  LogWatch logs_watch_;
  LogWatch records_watch_;

  test_support::ChildProcess markerd_;
  std::unique_ptr<daemon::ControlClient> client_;
  int instance_ = 0;  // the markerd running now (1: the first)
  int started_ = 0;   // markerds started
  Clock::time_point instance_started_{};
  std::optional<Clock::time_point> restart_at_;

  // What markerd's sweep.status said last, and of each run.
  std::string state_now_;
  std::string run_now_;
  std::map<std::string, RunObservation> runs_;
  Clock::time_point next_start_try_{};
  // The run that says it is running, its steps done, and since when both
  // are unchanged: a run that holds still is a run nobody runs.
  std::string still_run_;
  std::size_t still_steps_ = 0;
  Clock::time_point still_since_{};
  bool still_reported_ = false;
  std::map<std::string, std::uint64_t> start_refusals_;
  std::uint64_t runs_started_ = 0;

  // Events.
  std::uint64_t kills_ = 0;
  std::uint64_t kills_while_full_ = 0;
  std::uint64_t fills_ = 0;
  std::uint64_t crashes_ = 0;
  std::uint64_t hangs_ = 0;
  std::optional<Clock::time_point> full_until_;
  Clock::time_point next_kill_{}, next_fill_{}, next_follower_{}, next_stall_{};
  Clock::time_point next_status_{}, next_sample_{}, next_look_{};

  // Resources.
  struct InstanceSeries {
    std::vector<double> uptime_s;
    std::vector<double> rss_kib;
  };
  std::map<int, InstanceSeries> series_;
  std::optional<ProcessUsage> baseline_;  // the first markerd, idle, before anything happened
  std::optional<ProcessUsage> at_end_;    // the last, idle again, at the end
  std::optional<std::int64_t> rss_start_kib_;
  std::uint64_t samples_taken_ = 0;
};

void Soak::write_configs() {
  std::string rig = read_file(fs::path(o_.source_dir) / "config/rig-sim.toml");
  const std::string scale = "time_scale = 1.0";
  const auto at = rig.find(scale);
  if (at == std::string::npos) throw std::runtime_error("config/rig-sim.toml has no line '" + scale + "'");
  rig.replace(at, scale.size(), fmt::format("time_scale = {}", o_.time_scale));
  write_file(dir_ / "rig.toml", rig);
  write_file(dir_ / "markerd.toml",
             fmt::format(R"(# Written by the soak (tools/soak): the simulated rig, its camera dropping
# out on a schedule, the logs and state on a small tmpfs.
rig = "rig.toml"

[marker]
family = "frame8"
id = 165
size_m = 0.08

[camera]
source = "sim"
model = "{}/config/cameras/thesis-640x480.yaml"
frame_timeout_ms = 1000
reopen_delay_ms = 100
reopen_max_delay_ms = 1000

[camera.sim]
fps = 30
noise_sigma = 2.0
supersample = 2
{}

[pipeline]
policy = "live"

[log]
directory = "disk/logs"
max_file_mb = 4
fsync = "interval"

[control]
socket = "control.sock"

[sweep]
directory = "disk/state"
)",
                         o_.source_dir,
                         o_.camera_outage_every_s > 0 ? fmt::format("outage_every_s = {}\noutage_s = {}",
                                                                    o_.camera_outage_every_s, o_.camera_outage_s)
                                                      : "# the camera does not drop out (--camera-outage-every-s 0)"));
  write_file(dir_ / "soak.toml", kPlan);
  plan_text_ = kPlan;
}

void Soak::start_markerd() {
  ++instance_;
  ++started_;
  client_.reset();
  still_run_.clear();  // a resumed run starts its clock again
  markerd_.start({o_.markerd, "--config", (dir_ / "markerd.toml").string()}, output_);
  instance_started_ = Clock::now();
  restart_at_.reset();
  try {
    client_ = test_support::connect_control(markerd_, socket_, output_, 60s);
  } catch (const std::exception& e) {
    problem(fmt::format("markerd {} did not come up: {}", instance_, e.what()));
    if (markerd_.running()) (void)markerd_.kill9();
    restart_at_ = Clock::now() + 2s;
  }
}

void Soak::kill_markerd() {
  // The run's state just before: one that had already ended (failed on a
  // full disk, say) is not cut off by the kill, and must not be resumed.
  if (client_) poll_status();
  client_.reset();
  if (!markerd_.running()) return;  // it ended by itself meanwhile (reported)
  (void)markerd_.kill9();
  ++kills_;
  if (disk_->full()) ++kills_while_full_;
  // The run the journal names, if it had not ended: the next markerd must
  // resume it at the step its records hold now.
  try {
    const fs::path journal = state_ / "sweep-journal.json";
    if (fs::exists(journal)) {
      const fs::path run = json::parse(read_file(journal)).value("run_directory", "");
      RunObservation& observed = runs_[run.filename().string()];
      if (fs::exists(run / "start.json") && !fs::exists(run / "stop.json") && observed.ended_as.empty()) {
        observed.cut_at.push_back(sweep::read_run(run).points.size());
      }
    }
  } catch (const std::exception& e) {
    problem(fmt::format("after kill {}: the journal's run cannot be read: {}", kills_, e.what()));
  }
  state_now_.clear();
  restart_at_ = Clock::now() + duration_of(std::uniform_real_distribution<double>(0.2, 2.0)(rng_));
}

void Soak::markerd_ended_by_itself(int status) {
  ++crashes_;
  client_.reset();
  problem(fmt::format("markerd {} ended by itself ({}); its output: {}", instance_,
                      test_support::describe_wait_status(status), output_.string()));
  state_now_.clear();
  restart_at_ = Clock::now() + 1s;
}

std::optional<json> Soak::call(const json& request) {
  for (int attempt = 0; attempt < 2; ++attempt) {
    try {
      if (!client_) client_ = std::make_unique<daemon::ControlClient>(socket_);
      return client_->call(request, 15s);
    } catch (const daemon::ControlClientError& e) {
      client_.reset();
      if (const auto status = markerd_.exited()) {
        markerd_ended_by_itself(*status);
        return std::nullopt;
      }
      // An idle connection may be closed by markerd; a second try is a new one.
      if (attempt == 1) {
        ++hangs_;
        problem(fmt::format("markerd {} does not answer {}: {}; killing it", instance_, request.value("cmd", ""),
                            e.what()));
        kill_markerd();
      }
    }
  }
  return std::nullopt;
}

void Soak::observe(const json& s) {
  state_now_ = s.value("state", "");
  run_now_ = s.value("run_id", "");
  if (run_now_.empty()) return;
  RunObservation& r = runs_[run_now_];
  r.states.insert(state_now_);
  const std::size_t steps = s.value("steps_done", std::size_t{0});
  r.most_steps_seen = std::max<std::size_t>(r.most_steps_seen, steps);
  // At the soak's time scale a step takes well under a second, homing a few;
  // a camera outage suspends a run and a full disk fails it. A run that says
  // "running" at the same step for a minute has no thread running it (as
  // once after a start the disk refused half way).
  const auto now = Clock::now();
  if (state_now_ != "running") {
    still_run_.clear();  // the clock starts at the first poll that finds it running again
  } else if (run_now_ != still_run_ || steps != still_steps_) {
    still_run_ = run_now_;
    still_steps_ = steps;
    still_since_ = now;
    still_reported_ = false;
  } else if (!still_reported_ && now - still_since_ > kStillLimit) {
    problem(fmt::format("run {} has said running at step {} for {:.0f} s without a step", run_now_, steps,
                        std::chrono::duration<double>(now - still_since_).count()));
    still_reported_ = true;
  }
  const bool ended = state_now_ == "done" || state_now_ == "failed" || state_now_ == "aborted";
  if (ended && r.ended_as.empty()) {
    r.ended_as = state_now_;
    r.ended_reason = s.value("reason", "");
  } else if (!r.ended_as.empty() && state_now_ != r.ended_as && !r.came_back) {
    problem(fmt::format("run {} was reported {} ({}), and later {}", run_now_, r.ended_as, r.ended_reason, state_now_));
    r.came_back = true;
  }
}

void Soak::poll_status() {
  const auto reply = call({{"cmd", "sweep.status"}});
  if (!reply) return;
  if (!reply->value("ok", false)) {
    problem("sweep.status refused: " + reply->dump());
    return;
  }
  observe(*reply);
}

void Soak::start_run() {
  const auto reply = call({{"cmd", "sweep.start"}, {"plan", plan_text_}, {"source", "soak.toml"}});
  if (!reply) return;
  if (reply->value("ok", false)) {
    ++runs_started_;
    runs_[reply->value("run_id", "")];
    poll_status();
    return;
  }
  // Refused: the disk is full, or the run just resumed is going. Counted by cause.
  std::string why = reply->value("error", "");
  if (why.find("No space left on device") != std::string::npos) why = "No space left on device";
  ++start_refusals_[why.substr(0, 100)];
  next_start_try_ = Clock::now() + 2s;
}

void Soak::sample() {
  if (!markerd_.running()) return;
  const auto usage = read_process_usage(markerd_.pid());
  if (!usage) return;
  Sample s;
  s.elapsed_s = since(began_);
  s.instance = instance_;
  s.pid = markerd_.pid();
  s.uptime_s = since(instance_started_);
  s.usage = *usage;
  s.followers = followers_->attached();
  s.sweep_state = state_now_;
  s.disk_full = disk_->full();
  samples_->append(s);
  ++samples_taken_;
  if (s.uptime_s >= o_.warm_up_s) {
    series_[instance_].uptime_s.push_back(s.uptime_s);
    series_[instance_].rss_kib.push_back(static_cast<double>(usage->rss_kib));
    if (!rss_start_kib_) rss_start_kib_ = usage->rss_kib;
  }
}

// The detection logs and the runs' JSON-lines files: nothing written before
// is lost, every line parses. Log files markerd has closed (an earlier
// markerd's, or rotated) are checked a last time and removed, as logrotate
// would, so that the logs alone do not fill the small disk.
void Soak::look_at_files() {
  std::set<fs::path> open;
  if (markerd_.running()) {
    for (const fs::path& f : open_files(markerd_.pid())) open.insert(f);
  }
  std::vector<fs::path> logs;
  for (const auto& entry : fs::directory_iterator(logs_)) logs.push_back(entry.path());
  std::sort(logs.begin(), logs.end());
  const bool may_remove = markerd_.running() && !open.empty() && !disk_->full();
  for (const fs::path& file : logs) {
    // The newest file stays whatever the descriptors said: markerd may have
    // opened it (a rotation) since they were read.
    if (may_remove && !open.contains(file) && file != logs.back()) {
      logs_watch_.retire(file, false, problems_);
      fs::remove(file);
    } else {
      logs_watch_.look(file, problems_);
    }
  }
  std::string journal_names;
  try {
    if (fs::exists(state_ / "sweep-journal.json")) {
      journal_names = json::parse(read_file(state_ / "sweep-journal.json")).value("run_directory", "");
    }
  } catch (const std::exception&) {  // NOLINT(bugprone-empty-catch): being replaced; the next look reads it
  }
  const bool run_now_ended = state_now_ == "done" || state_now_ == "failed" || state_now_ == "aborted";
  for (const auto& entry : fs::directory_iterator(state_ / "runs")) {
    const fs::path& run = entry.path();
    const bool ended =
        fs::exists(run / "stop.json") && run.string() != journal_names && (run.filename() != run_now_ || run_now_ended);
    for (const char* name : {"points.jsonl", "events.jsonl"}) {
      const fs::path file = run / name;
      if (!fs::exists(file)) continue;
      if (ended) {
        records_watch_.retire(file, true, problems_);
      } else {
        records_watch_.look(file, problems_);
      }
    }
    if (ended) archive(run);
  }
}

// An ended run's records leave the small disk (which they would fill in an
// hour) for the work directory, where the final checks read them.
void Soak::archive(const fs::path& run) {
  std::error_code ec;
  fs::copy(run, archive_ / run.filename(), fs::copy_options::recursive, ec);
  if (ec) {
    problem(fmt::format("cannot copy {} to {}: {}", run.string(), archive_.string(), ec.message()));
    return;
  }
  fs::remove_all(run);
}

void Soak::tick() {
  const auto now = Clock::now();
  if (!markerd_.running()) {
    if (restart_at_ && now >= *restart_at_) start_markerd();
  } else if (const auto status = markerd_.exited()) {
    markerd_ended_by_itself(*status);
  }

  if (markerd_.running() && now >= next_status_) {
    poll_status();
    next_status_ = now + 500ms;
    const bool idle = state_now_ == "idle" || state_now_ == "done" || state_now_ == "failed" || state_now_ == "aborted";
    if (markerd_.running() && idle && now >= next_start_try_) start_run();
  }

  const bool calm = now >= began_ + std::chrono::duration_cast<Clock::duration>(
                                        std::chrono::duration<double>(o_.duration) * (1.0 - o_.calm_tail));
  if (now >= next_kill_) {
    if (!calm && markerd_.running()) kill_markerd();
    next_kill_ = next_after(rng_, o_.kills_per_hour);
  }
  if (full_until_ && now >= *full_until_) {
    disk_->free();
    full_until_.reset();
  }
  if (now >= next_fill_) {
    if (!disk_->full()) {
      (void)disk_->fill();
      ++fills_;
      full_until_ = now + duration_of(o_.disk_full_s);
    }
    next_fill_ = next_after(rng_, o_.disk_fills_per_hour);
  }
  if (now >= next_follower_) {
    const int n = followers_->attached();
    const bool attach = n == 0 || (n < o_.max_followers && std::bernoulli_distribution(0.5)(rng_));
    if (attach && markerd_.running()) {
      followers_->attach(rng_);
    } else if (!attach) {
      followers_->detach(rng_, problems_);
    }
    next_follower_ = next_after(rng_, o_.follower_changes_per_minute * 60);
  }
  if (now >= next_stall_) {
    followers_->stall(rng_, std::chrono::milliseconds(std::uniform_int_distribution<int>(30000, 90000)(rng_)));
    next_stall_ = next_after(rng_, o_.stalls_per_hour);
  }
  followers_->tick(problems_);
  if (now >= next_sample_) {
    sample();
    next_sample_ = now + duration_of(o_.sample_every_s);
  }
  if (now >= next_look_) {
    look_at_files();
    next_look_ = now + 15s;
  }
}

// Polls until no run is going (idle or ended), for up to 10 minutes.
void Soak::wait_for_the_run_to_end() {
  const auto deadline = Clock::now() + 10min;
  for (;;) {
    if (!markerd_.running()) {
      if (restart_at_) start_markerd();
      if (!markerd_.running()) return;
    } else if (const auto status = markerd_.exited()) {
      markerd_ended_by_itself(*status);
      continue;
    }
    poll_status();
    if (state_now_ == "idle" || state_now_ == "done" || state_now_ == "failed" || state_now_ == "aborted") return;
    if (Clock::now() > deadline) {
      problem(fmt::format("the last run ({}) did not end within 10 min; it is {}", run_now_, state_now_));
      return;
    }
    std::this_thread::sleep_for(500ms);
  }
}

// SIGTERM, and exit status 0 within a minute; the files it had open.
std::vector<fs::path> Soak::stop_markerd() {
  std::vector<fs::path> open;
  if (markerd_.running()) open = open_files(markerd_.pid());
  client_.reset();
  if (markerd_.running()) {
    const auto status = markerd_.terminate(60s);
    if (!status) {
      problem("markerd did not stop within 60 s of SIGTERM");
      (void)markerd_.kill9();
    } else if (!WIFEXITED(*status) || WEXITSTATUS(*status) != 0) {
      problem("markerd ended SIGTERM with " + test_support::describe_wait_status(*status));
    }
  }
  return open;
}

// No more faults; the last run goes to its end; markerd, idle again, is
// measured against the first one, then stopped with SIGTERM; every record
// is checked.
void Soak::finish() {
  std::cout << fmt::format("soak: {:.0f} s: ending: the disk freed, followers detached, the last run finishing\n",
                           since(began_))
            << std::flush;
  if (disk_->full()) disk_->free();
  full_until_.reset();
  followers_->detach_all(problems_);
  if (!markerd_.running()) start_markerd();
  wait_for_the_run_to_end();
  // The end is measured after a run done, as the start was before any: a run
  // that failed may hold its records open until the next one replaces it.
  if (state_now_ != "done") {
    std::cout << fmt::format("soak: the last run ended {}; one more, which must end done\n",
                             state_now_.empty() ? "nowhere" : state_now_);
    const std::string before = run_now_;
    const auto until = Clock::now() + 30s;
    while (run_now_ == before && markerd_.running() && Clock::now() < until) {
      start_run();  // a refusal (say, an end still to be written) is tried again
      if (run_now_ == before) std::this_thread::sleep_for(2s);
    }
    wait_for_the_run_to_end();
    if (state_now_ != "done") {
      problem(fmt::format("with the faults over, a run did not end done but {} ({})", state_now_, run_now_));
    }
  }
  look_at_files();

  // Idle: no run, no followers; the soak's own connection, as at the start.
  if (markerd_.running()) {
    const auto until = Clock::now() + 15s;
    do {
      std::this_thread::sleep_for(1s);
      sample();
      at_end_ = read_process_usage(markerd_.pid());
    } while (at_end_ && baseline_ && (at_end_->fds > baseline_->fds || at_end_->threads > baseline_->threads) &&
             Clock::now() < until);
  }
  const int measured = instance_;
  std::vector<fs::path> open = stop_markerd();
  // A run that ended on a full disk may have its end only in the journal:
  // the next markerd writes its stop record (docs/sweep.md), as a restart
  // of the service would.
  if (fs::exists(state_ / "sweep-journal.json")) {
    std::cout << "soak: a sweep journal is left after SIGTERM; starting markerd once more, which settles it\n";
    start_markerd();
    wait_for_the_run_to_end();
    const std::vector<fs::path> more = stop_markerd();
    open.insert(open.end(), more.begin(), more.end());
  }
  instance_ = measured;  // the memory judged is the long-lived one's
  // The last markerd stopped cleanly: its files end whole. Earlier ones were
  // killed, and may have been cut in the middle of a line.
  for (const auto& entry : fs::directory_iterator(logs_)) logs_watch_.look(entry.path(), problems_);
  for (const fs::path& file : logs_watch_.watched()) {
    logs_watch_.retire(file, std::find(open.begin(), open.end(), file) != open.end(), problems_);
  }
  for (const fs::path& file : records_watch_.watched()) records_watch_.retire(file, true, problems_);
  if (fs::exists(state_ / "sweep-journal.json")) {
    std::string journal = read_file(state_ / "sweep-journal.json");
    while (!journal.empty() && journal.back() == '\n') journal.pop_back();
    problem("a sweep journal is left: " + journal);
    fs::copy(state_ / "sweep-journal.json", dir_ / "sweep-journal.json");
  }
  for (const auto& entry : fs::directory_iterator(state_ / "runs")) archive(entry.path());
}

void Soak::report() {
  std::vector<std::string> checks;
  const RunTotals runs = check_runs(archive_, runs_, checks);
  for (const std::string& c : checks) problem(c);

  // Memory: the last markerd (it lived through the calm tail) after its warm-up.
  std::string rss_line = "RSS: not enough samples after the warm-up";
  const auto last = series_.find(instance_);
  if (last != series_.end() && last->second.rss_kib.size() >= 3) {
    const auto& s = last->second;
    const double first = s.rss_kib.front();
    const double final_rss = s.rss_kib.back();
    const double per_hour = slope(s.uptime_s, s.rss_kib) * 3600.0;
    const double span_min = (s.uptime_s.back() - s.uptime_s.front()) / 60.0;
    rss_line = fmt::format("RSS of the last markerd over {:.1f} min after its warm-up: {} -> {}, slope {:+.1f} MiB/h",
                           span_min, mib(static_cast<std::int64_t>(first)), mib(static_cast<std::int64_t>(final_rss)),
                           per_hour / 1024.0);
    // A leak grows with the frames, the runs and the clients served; what
    // the allocator keeps after the warm-up does not. Bounded in size, not
    // time: a faster machine must not pass a leak a slower one fails.
    const double allowed = std::max(8.0 * 1024.0, 0.10 * first);
    if (final_rss - first > allowed) {
      problem(fmt::format("markerd's memory grew from {} to {} after its warm-up (allowed: {})",
                          mib(static_cast<std::int64_t>(first)), mib(static_cast<std::int64_t>(final_rss)),
                          mib(static_cast<std::int64_t>(allowed))));
    }
  } else {
    problem(
        "too few samples of the last markerd after its warm-up to judge its memory (a longer soak, or a shorter "
        "--warm-up)");
  }
  if (baseline_ && at_end_) {
    if (at_end_->fds > baseline_->fds) {
      problem(fmt::format("file descriptors: {} open at the start, {} at the end (both idle)", baseline_->fds,
                          at_end_->fds));
    }
    if (at_end_->threads > baseline_->threads) {
      problem(fmt::format("threads: {} at the start, {} at the end (both idle)", baseline_->threads, at_end_->threads));
    }
  } else {
    problem("markerd's descriptors and threads could not be measured at the start and the end");
  }
  if (runs.runs == 0) problem("no run was started");
  if (runs.done == 0) problem("no run ended done");

  // The camera's outages as markerd saw them: lost, and streaming again.
  std::uint64_t camera_lost = 0;
  std::uint64_t camera_back = 0;
  {
    std::ifstream log(output_);
    for (std::string line; std::getline(log, line);) {
      if (line.find("lost: ") != std::string::npos && line.find("simulated outage") != std::string::npos &&
          line.find(" camera ") != std::string::npos && line.find(" sweep ") == std::string::npos) {
        ++camera_lost;
      }
      if (line.find("streaming again") != std::string::npos) ++camera_back;
    }
  }
  const WatchTotals& l = logs_watch_.totals();
  const WatchTotals& r = records_watch_.totals();
  const FollowerTotals& f = followers_->totals();
  std::string refusals;
  for (const auto& [why, n] : start_refusals_) refusals += fmt::format("\n    {} x {}", n, why);
  std::string causes;
  for (const auto& [why, n] : runs.failure_causes) causes += fmt::format("\n    {} x {}", n, why);
  std::ostringstream out;
  out << fmt::format(
      "soak summary (seed {}, time scale {}, work directory {}; the runs' records in runs/)\n"
      "  duration: {:.2f} h ({:.0f} s)\n"
      "  markerd: {} started, {} kill -9 ({} while the disk was full), {} ended by itself, {} did not answer\n"
      "  disk: {} fills of the {} MiB tmpfs, {} s each\n"
      "  camera: {}: lost {} times, streaming again {} times; {} runs suspended by it\n"
      "  runs: {} ({} done, {} failed, {} aborted, {} without a stop record); {} starts refused{}\n"
      "  failed runs' causes:{}\n"
      "  measurements: {} planned, {} recorded, {} duplicates, {} missing; {} planned by done runs, all recorded; "
      "{} left unmeasured by failed runs\n"
      "  kills that cut a run off: {}; restarted events: {}\n"
      "  detection log: {} files, {} lines, {} not parsed, {:.1f} MiB; {} files cut mid-line by a kill\n"
      "  run records: {} files, {} lines, {} not parsed\n"
      "  followers: {} attached, {} detached, {} ended with markerd or the run, {} stalled; {} lines, {} not parsed, "
      "{} drop notices\n"
      "  {}\n"
      "  RSS at the start (first sample after the warm-up): {}; at the end: {}\n"
      "  descriptors: {} at the start, {} at the end; threads: {} at the start, {} at the end (idle)\n"
      "  samples: {} in {}\n",
      o_.seed, o_.time_scale, dir_.string(), since(began_) / 3600.0, since(began_), started_, kills_, kills_while_full_,
      crashes_, hangs_, fills_, o_.disk_mib, o_.disk_full_s,
      o_.camera_outage_every_s > 0
          ? fmt::format("outages every {} s for {} s", o_.camera_outage_every_s, o_.camera_outage_s)
          : std::string("no outages"),
      camera_lost, camera_back, runs.camera_suspensions, runs.runs, runs.done, runs.failed, runs.aborted, runs.unended,
      [&] {
        std::uint64_t n = 0;
        for (const auto& [why, count] : start_refusals_) n += count;
        return n;
      }(),
      refusals, causes.empty() ? " none" : causes, runs.planned, runs.recorded, runs.duplicates, runs.missing,
      runs.planned_in_done, runs.not_measured, runs.cut_off_kills, runs.restarted_events, l.files, l.lines, l.bad_lines,
      static_cast<double>(l.bytes) / (1024.0 * 1024.0), l.torn_tails, r.files, r.lines, r.bad_lines, f.attached,
      f.detached, f.ended_by_markerd, f.stalls, f.lines, f.bad_lines, f.dropped_notices, rss_line,
      rss_start_kib_ ? mib(*rss_start_kib_) : "-", at_end_ ? mib(at_end_->rss_kib) : "-",
      baseline_ ? std::to_string(baseline_->fds) : "-", at_end_ ? std::to_string(at_end_->fds) : "-",
      baseline_ ? std::to_string(baseline_->threads) : "-", at_end_ ? std::to_string(at_end_->threads) : "-",
      samples_taken_, (dir_ / "samples.csv").string());
  if (problems_.empty()) {
    out << "every check held\n";
  } else {
    out << fmt::format("{} problem(s):\n", problems_.size());
    for (const std::string& p : problems_) out << "  " << p << "\n";
  }
  std::cout << out.str();
  write_file(dir_ / "summary.txt", out.str());
}

int Soak::run() {
  if (::geteuid() != 0) {
    throw std::runtime_error(
        "the soak must run as root: it mounts a small tmpfs for markerd's logs and state, to fill it");
  }
  dir_ = fs::absolute(o_.work_dir);
  prepare_work_dir(dir_);
  // The device locks of the markerds it starts in a directory of its own,
  // not the machine's /run/lock/markerd: a markerd of the machine's own, or
  // a markerctl rig session, must not meet the soak's there (nor the soak
  // theirs). Before any thread: every child inherits it.
  fs::create_directories(dir_ / "locks");
  ::setenv("MARKERD_LOCK_DIR", (dir_ / "locks").c_str(), 1);  // NOLINT(concurrency-mt-unsafe): no threads yet
  disk_ = std::make_unique<SmallDisk>(dir_ / "disk", o_.disk_mib);
  logs_ = dir_ / "disk/logs";
  state_ = dir_ / "disk/state";
  archive_ = dir_ / "runs";
  fs::create_directories(archive_);
  fs::create_directories(logs_);
  fs::create_directories(state_);
  socket_ = dir_ / "control.sock";
  output_ = dir_ / "markerd.out";
  write_configs();
  samples_ = std::make_unique<SampleLog>(dir_ / "samples.csv");
  followers_ = std::make_unique<Followers>(o_.markerctl, socket_, dir_ / "followers");

  began_ = Clock::now();
  end_ = began_ + o_.duration;
  std::cout << fmt::format("soak: {} s, seed {}, time scale {}, in {} (markerd's output: {})\n", o_.duration.count(),
                           o_.seed, o_.time_scale, dir_.string(), output_.string())
            << std::flush;
  start_markerd();
  if (!markerd_.running()) throw std::runtime_error("markerd does not start; its output: " + read_file(output_));
  if (auto misplaced = lock_directory_problem(dir_ / "locks", dir_ / "rig.toml")) problem(*misplaced);
  // The baseline: the first markerd idle, a few seconds in (its threads up,
  // the camera streaming), before any run, fault or follower.
  std::this_thread::sleep_for(3s);
  baseline_ = read_process_usage(markerd_.pid());

  next_kill_ = next_after(rng_, o_.kills_per_hour);
  next_fill_ = next_after(rng_, o_.disk_fills_per_hour);
  next_follower_ = Clock::now();
  next_stall_ = next_after(rng_, o_.stalls_per_hour);
  auto next_progress = Clock::now() + 60s;
  while (Clock::now() < end_) {
    tick();
    if (Clock::now() >= next_progress) {
      std::cout << fmt::format("soak: {:.0f} s: markerd {}, {} kills, {} fills, {} runs started, {} problems\n",
                               since(began_), instance_, kills_, fills_, runs_started_, problems_.size())
                << std::flush;
      next_progress += 60s;
    }
    std::this_thread::sleep_for(50ms);
  }
  finish();
  report();
  disk_.reset();
  return problems_.empty() ? 0 : 1;
}

}  // namespace

int run_soak(const Options& options) {
  Soak soak(options);
  return soak.run();
}

}  // namespace markerd::soak
