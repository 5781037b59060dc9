// markerd: the measurement rig's daemon. Reads one TOML config, then runs the
// camera, the detection pipeline, the detection log and the rig until
// SIGTERM. Under systemd (Type=notify) it reports READY and STATUS, pings
// the watchdog while its threads are responsive, and logs to the journal.
//
//   markerd --config /etc/markerd/markerd.toml
//   markerd --config FILE --check-config     validate and exit (--no-lock-check: not the device locks)
//
// Exit status: 0 after SIGTERM/SIGINT or a good config check, 1 when it
// cannot start (the cause on stderr or in the journal), 2 for a usage error.

// g++ 12 at -O2 reports a false "potential null pointer dereference" in
// std::string inlined from CLI::App (see tools/markerctl/main.cpp).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#pragma GCC diagnostic pop

#include <fmt/format.h>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/sinks/systemd_sink.h>
#include <spdlog/spdlog.h>
#include <systemd/sd-daemon.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <iostream>
#include <opencv2/core/utils/logger.hpp>
#include <optional>
#include <string>
#include <vector>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/rig/device_lock.hpp"

#ifndef MARKERD_VERSION
#define MARKERD_VERSION "unknown"
#endif

namespace {

// systemd connects stderr to the journal and says so in JOURNAL_STREAM; then
// the journal's own fields (priority, and the message without a timestamp)
// serve better than text.
void set_up_logging() {
  const char* journal = std::getenv("JOURNAL_STREAM");  // NOLINT(concurrency-mt-unsafe): before any thread
  std::shared_ptr<spdlog::logger> logger;
  if (journal != nullptr && *journal != '\0') {
    logger = std::make_shared<spdlog::logger>("markerd", std::make_shared<spdlog::sinks::systemd_sink_mt>("markerd"));
    logger->set_pattern("%v");
  } else {
    logger = std::make_shared<spdlog::logger>("markerd", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  }
  spdlog::set_default_logger(logger);
  spdlog::flush_on(spdlog::level::info);
}

// The signals markerd acts on are taken synchronously by the main thread
// (sigtimedwait), so no handler runs inside another thread's critical
// section; blocked here, before any thread starts, every thread inherits
// the mask.
sigset_t block_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  return set;
}

// The rig's device locks, waited for while another process holds one (a
// markerctl rig session): exiting instead would have systemd start markerd
// again every RestartSec until its start limit left the unit failed. The
// wait comes before READY, so systemd's start timeout is extended while it
// lasts, and the status says what is held by whom. Nothing when SIGTERM or
// SIGINT ends the wait.
std::optional<markerd::rig::DeviceLock> wait_for_rig_devices(const markerd::rig::RigConfig& rig,
                                                             const sigset_t& signals) {
  const std::vector<markerd::rig::DeviceClaim> claims = markerd::rig::device_claims(rig);
  const auto since = std::chrono::steady_clock::now();
  std::string reported;
  for (;;) {
    try {
      markerd::rig::DeviceLock lock(claims);
      if (!reported.empty()) {
        spdlog::info("the rig's devices are free after {:.0f} s of waiting; starting",
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count());
      }
      return lock;
    } catch (const markerd::rig::DeviceLockError& e) {
      if (!e.held()) throw;  // a lock that cannot be taken at all does not come free
      if (e.what() != reported) {
        spdlog::warn("{}; markerd waits until it is free, and starts then (SIGTERM stops it)", e.what());
        reported = e.what();
      }
      // Renewed every second: while the wait goes on, so does the start.
      sd_notifyf(0, "STATUS=waiting for the rig's devices: %s\nEXTEND_TIMEOUT_USEC=%llu", e.what(),
                 static_cast<unsigned long long>(10'000'000));
    }
    const timespec second{1, 0};
    const int sig = sigtimedwait(&signals, nullptr, &second);
    if (sig == SIGTERM || sig == SIGINT) {
      spdlog::info("{}: stopping while waiting for the rig's devices", sig == SIGTERM ? "SIGTERM" : "SIGINT");
      return std::nullopt;
    }
  }
}

int run(const std::string& config_path) {
  const sigset_t signals = block_signals();
  markerd::daemon::DaemonConfig config = markerd::daemon::load_daemon_config(config_path);
  spdlog::set_level(spdlog::level::from_str(config.log.level));
  spdlog::info("markerd {} starting with {}", MARKERD_VERSION, config_path);

  std::optional<markerd::rig::DeviceLock> rig_lock;
  if (config.rig) {
    rig_lock = wait_for_rig_devices(*config.rig, signals);
    if (!rig_lock) return 0;
  }
  markerd::daemon::Daemon daemon(std::move(config), std::move(rig_lock));
  daemon.start();
  spdlog::info("detection log: {}", daemon.log().current_path());

  std::uint64_t watchdog_usec = 0;
  const bool watchdog = sd_watchdog_enabled(0, &watchdog_usec) > 0;
  // Half the watchdog period, as sd_watchdog_enabled(3) advises; the status
  // refreshes at least once a second.
  auto tick = std::chrono::milliseconds(1000);
  if (watchdog) tick = std::min(tick, std::chrono::milliseconds(watchdog_usec / 2000));
  sd_notifyf(0, "READY=1\nSTATUS=%s", daemon.status_line().c_str());

  std::string last_status;
  bool reported_unresponsive = false;
  for (;;) {
    const timespec timeout{static_cast<time_t>(tick.count() / 1000),
                           static_cast<long>((tick.count() % 1000) * 1'000'000)};
    const int sig = sigtimedwait(&signals, nullptr, &timeout);
    if (sig == SIGTERM || sig == SIGINT) {
      spdlog::info("{}: stopping", sig == SIGTERM ? "SIGTERM" : "SIGINT");
      sd_notify(0, "STOPPING=1\nSTATUS=stopping: stopping motion and flushing the detection log");
      break;
    }
    if (sig == SIGHUP) {
      spdlog::info("SIGHUP: reopening the detection log");
      sd_notify(0, "RELOADING=1");
      daemon.reopen_logs();
      sd_notify(0, "READY=1");
    }
    const bool responsive = daemon.responsive();
    if (watchdog && responsive) sd_notify(0, "WATCHDOG=1");
    if (!responsive && !reported_unresponsive) {
      spdlog::error("a daemon thread stopped responding: {}; the watchdog is no longer pinged", daemon.status_line());
    }
    reported_unresponsive = !responsive;
    std::string status = daemon.status_line();
    if (status != last_status) {
      sd_notifyf(0, "STATUS=%s", status.c_str());
      last_status = std::move(status);
    }
  }
  daemon.stop();
  spdlog::info("stopped: {}", daemon.status_line());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"markerd: the frame-marker measurement rig's daemon (docs/daemon.md)", "markerd"};
  app.set_version_flag("--version", fmt::format("markerd {}", MARKERD_VERSION));
  std::string config_path = "/etc/markerd/markerd.toml";
  bool check_only = false;
  bool no_lock_check = false;
  app.add_option("-c,--config", config_path, "the configuration file")->capture_default_str();
  CLI::Option* check =
      app.add_flag("--check-config", check_only, "read and check the configuration, print what it sets up, and exit");
  app.add_flag("--no-lock-check", no_lock_check,
               "with --check-config: leave out whether the rig's device locks are free (the start waits for them)")
      ->needs(check);
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << fmt::format("markerd: {} (see 'markerd --help')\n", e.what());
    return 2;
  }
  // OpenCV logs its own view of a failure; markerd reports each in its own words.
  cv::utils::logging::setLogLevel(cv::utils::logging::LOG_LEVEL_SILENT);

  if (check_only) {
    try {
      const auto config = markerd::daemon::load_daemon_config(config_path);
      markerd::daemon::check_control_setup(config.control);
      markerd::daemon::check_detector_setup(config);
      // Another process on one of the rig's devices (a markerctl rig
      // session, a running markerd) would keep markerd from driving it; the
      // locks are taken and let go at once.
      if (config.rig && !no_lock_check) {
        try {
          const markerd::rig::DeviceLock lock(markerd::rig::device_claims(*config.rig));
        } catch (const markerd::rig::DeviceLockError& e) {
          throw std::runtime_error(fmt::format("{}: rig: {}{}", config_path, e.what(),
                                               e.held() ? " (markerd would wait for it at start)" : ""));
        }
      }
      std::cout << fmt::format(
          "{}: ok (camera: {}, marker: {} id {} {} m {}, rig: {}, detection log: {}, control: {})\n", config_path,
          config.camera.source_kind, markerd::detector::family_info(config.marker.family).name, config.marker.id,
          config.marker.size_m, markerd::sweep::mounting_text(config.marker.mounting), config.rig ? "yes" : "none",
          config.log.directory.string(), config.control.socket.string());
      return 0;
    } catch (const std::exception& e) {
      std::cerr << fmt::format("markerd: {}\n", e.what());
      return 1;
    }
  }

  set_up_logging();
  try {
    return run(config_path);
  } catch (const std::exception& e) {
    spdlog::critical("cannot start: {}", e.what());
    sd_notifyf(0, "STATUS=cannot start: %s", e.what());
    return 1;
  }
}
