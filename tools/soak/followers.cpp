#include "followers.hpp"

#include <fmt/format.h>
#include <signal.h>

#include <algorithm>
#include <fstream>
#include <system_error>

namespace markerd::soak {

namespace fs = std::filesystem;

Followers::Followers(std::string markerctl, fs::path socket, fs::path directory)
    : markerctl_(std::move(markerctl)), socket_(std::move(socket)), directory_(std::move(directory)) {
  fs::create_directories(directory_);
}

void Followers::attach(std::mt19937_64& rng) {
  Follower f;
  f.detections = std::bernoulli_distribution(0.6)(rng);
  const std::uint64_t n = next_number_++;
  f.out = directory_ / fmt::format("{}-{}.out", n, f.detections ? "detections" : "status");
  f.err = directory_ / fmt::format("{}-{}.err", n, f.detections ? "detections" : "status");
  std::vector<std::string> argv{markerctl_};
  if (f.detections) {
    argv.insert(argv.end(), {"detections", "--socket", socket_.string()});
  } else {
    argv.insert(argv.end(), {"sweep", "status", "--follow", "--socket", socket_.string()});
  }
  f.process.start(argv, f.out, f.err);
  ++totals_.attached;
  followers_.push_back(std::move(f));
}

void Followers::detach(std::mt19937_64& rng, std::vector<std::string>& problems) {
  // A stalled follower stays until its stall is over: it is there to fall
  // far enough behind for markerd to drop lines for it.
  std::vector<std::size_t> candidates;
  for (std::size_t i = 0; i < followers_.size(); ++i) {
    if (!followers_[i].stalled) candidates.push_back(i);
  }
  if (candidates.empty()) return;
  const std::size_t i = candidates[std::uniform_int_distribution<std::size_t>(0, candidates.size() - 1)(rng)];
  Follower& f = followers_[i];
  f.process.signal(SIGCONT);  // a stopped process would hold a SIGTERM until it runs again
  if (std::bernoulli_distribution(0.5)(rng)) {
    (void)f.process.kill9();
  } else if (!f.process.terminate(std::chrono::seconds(5))) {
    problems.push_back(fmt::format("follower {} did not end within 5 s of SIGTERM", f.out.filename().string()));
    (void)f.process.kill9();
  }
  ++totals_.detached;
  finish(f, true, problems);
  followers_.erase(followers_.begin() + static_cast<std::ptrdiff_t>(i));
}

void Followers::stall(std::mt19937_64& rng, std::chrono::milliseconds for_time) {
  std::vector<Follower*> candidates;
  for (Follower& f : followers_) {
    if (f.detections && !f.stalled) candidates.push_back(&f);
  }
  if (candidates.empty()) return;
  Follower& f = *candidates[std::uniform_int_distribution<std::size_t>(0, candidates.size() - 1)(rng)];
  f.process.signal(SIGSTOP);
  f.stalled = true;
  f.stalled_until = std::chrono::steady_clock::now() + for_time;
  ++totals_.stalls;
}

void Followers::tick(std::vector<std::string>& problems) {
  const auto now = std::chrono::steady_clock::now();
  for (auto it = followers_.begin(); it != followers_.end();) {
    if (it->stalled && now >= it->stalled_until) {
      it->process.signal(SIGCONT);
      it->stalled = false;
    }
    if (it->process.exited()) {
      ++totals_.ended_by_markerd;
      finish(*it, false, problems);
      it = followers_.erase(it);
    } else {
      ++it;
    }
  }
}

void Followers::detach_all(std::vector<std::string>& problems) {
  while (!followers_.empty()) {
    Follower& f = followers_.back();
    f.process.signal(SIGCONT);
    if (!f.process.terminate(std::chrono::seconds(5))) {
      problems.push_back(fmt::format("follower {} did not end within 5 s of SIGTERM", f.out.filename().string()));
      (void)f.process.kill9();
    }
    ++totals_.detached;
    finish(f, true, problems);
    followers_.pop_back();
  }
}

void Followers::finish(Follower& f, bool killed_by_us, std::vector<std::string>& problems) {
  if (f.detections) {
    const test_support::JsonLines lines = test_support::check_json_lines_file(f.out, 5);
    totals_.lines += lines.objects;
    totals_.bad_lines += lines.lines - lines.objects;
    for (const std::string& p : lines.problems)
      problems.push_back(fmt::format("follower {}: {}", f.out.filename().string(), p));
    // markerctl prints each line whole; only a kill in the middle of a write
    // could leave part of one.
    if (!lines.ends_whole && !killed_by_us) {
      problems.push_back(fmt::format("follower {}: its output ends with a partial line", f.out.filename().string()));
    }
    std::ifstream err(f.err);
    for (std::string line; std::getline(err, line);) {
      if (line.find("lines dropped") != std::string::npos || line.find("line dropped") != std::string::npos) {
        ++totals_.dropped_notices;
      }
    }
  }
  std::error_code ec;
  fs::remove(f.out, ec);
  fs::remove(f.err, ec);
}

}  // namespace markerd::soak
