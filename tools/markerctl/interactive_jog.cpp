#include "interactive_jog.hpp"

#include "live_line.hpp"

#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <deque>
#include <iostream>
#include <string>
#include <vector>

namespace markerctl {
namespace {

using markerd::errno_text;
using markerd::rig::Axis;
using markerd::rig::AxisSettings;
using markerd::rig::AxisState;
using markerd::rig::AxisStatus;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// The terminal in raw mode (no echo, no line editing, keys as they come, no
// signals from ^C: it arrives as a key), restored when this ends, including
// by an exception. Crashes (SIGSEGV, SIGABRT, ...) restore it from their
// signal handler before the default action; the interrupt signals end the
// jog loop through the SignalWatch, and the destructor restores it.
class RawTerminal {
 public:
  explicit RawTerminal(int fd) : fd_(fd) {
    if (tcgetattr(fd_, &saved_) != 0) throw std::runtime_error(fmt::format("tcgetattr: {}", errno_text(errno)));
    crash_fd_ = fd_;
    crash_saved_ = saved_;
    crash_armed_ = 1;
    struct sigaction action {};
    action.sa_handler = &RawTerminal::on_crash;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESETHAND;
    for (std::size_t i = 0; i < kCrashSignals.size(); ++i) sigaction(kCrashSignals[i], &action, &previous_[i]);
    termios raw = saved_;
    raw.c_lflag &= ~static_cast<tcflag_t>(ICANON | ECHO | ISIG | IEXTEN);
    raw.c_iflag &= ~static_cast<tcflag_t>(IXON | ICRNL);
    raw.c_cc[VMIN] = 0;
    raw.c_cc[VTIME] = 0;
    if (tcsetattr(fd_, TCSANOW, &raw) != 0) {
      const int error = errno;
      restore();
      throw std::runtime_error(fmt::format("tcsetattr: {}", errno_text(error)));
    }
  }
  ~RawTerminal() { restore(); }
  RawTerminal(const RawTerminal&) = delete;
  RawTerminal& operator=(const RawTerminal&) = delete;

 private:
  static constexpr std::array<int, 5> kCrashSignals{SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT};

  void restore() {
    crash_armed_ = 0;
    tcsetattr(fd_, TCSANOW, &saved_);
    for (std::size_t i = 0; i < kCrashSignals.size(); ++i) sigaction(kCrashSignals[i], &previous_[i], nullptr);
  }

  // Async-signal-safe: tcsetattr, then the default action (SA_RESETHAND).
  static void on_crash(int signal) {
    if (crash_armed_ != 0) tcsetattr(crash_fd_, TCSANOW, &crash_saved_);
    raise(signal);
  }

  int fd_;
  termios saved_{};
  std::array<struct sigaction, kCrashSignals.size()> previous_{};
  static inline volatile sig_atomic_t crash_armed_ = 0;
  static inline int crash_fd_ = -1;
  static inline termios crash_saved_{};
};

enum class Key {
  none,
  rail_up,
  rail_down,
  turntable_up,
  turntable_down,
  bigger,
  smaller,
  home,
  stop,
  estop,
  quit,
  interrupt
};

// Keys from the bytes read so far; an incomplete escape sequence stays in `pending`.
std::vector<Key> take_keys(std::string& pending) {
  std::vector<Key> keys;
  std::size_t i = 0;
  while (i < pending.size()) {
    const char c = pending[i];
    if (c == '\x1b') {
      if (i + 2 >= pending.size()) break;  // wait for the rest
      if (pending[i + 1] == '[' || pending[i + 1] == 'O') {
        switch (pending[i + 2]) {
          case 'A': keys.push_back(Key::turntable_up); break;
          case 'B': keys.push_back(Key::turntable_down); break;
          case 'C': keys.push_back(Key::rail_up); break;
          case 'D': keys.push_back(Key::rail_down); break;
          default: break;
        }
        i += 3;
      } else {
        i += 1;  // a lone escape
      }
      continue;
    }
    switch (c) {
      case '+':
      case '=': keys.push_back(Key::bigger); break;
      case '-':
      case '_': keys.push_back(Key::smaller); break;
      case 'h':
      case 'H': keys.push_back(Key::home); break;
      case 's':
      case 'S': keys.push_back(Key::stop); break;
      case ' ': keys.push_back(Key::estop); break;
      case 'q':
      case 'Q':
      case '\x04': keys.push_back(Key::quit); break;
      case '\x03':
      case '\x1c': keys.push_back(Key::interrupt); break;
      default: break;
    }
    ++i;
  }
  pending.erase(0, i);
  return keys;
}

// Step sizes, from fine to coarse: rail (mm) and turntable (deg) together.
constexpr std::array<std::pair<double, double>, 7> kJogSteps{
    {{0.1, 0.05}, {0.5, 0.1}, {1, 0.5}, {5, 1}, {10, 5}, {50, 10}, {100, 30}}};
constexpr std::size_t kInitialJogStep = 3;

class InteractiveJog {
 public:
  explicit InteractiveJog(Session& session) : session_(session) {}

  int run() {
    RawTerminal terminal(STDIN_FILENO);
    // Within 80 columns, as the status line below it.
    std::cout << "markerctl rig jog: left/right arrows jog the rail, up/down the turntable;\n"
                 "+ and - change the step; h homes both axes; s stops;\n"
                 "space is an EMERGENCY STOP; q quits (the axes are then disabled).\n"
              << std::flush;
    std::string pending;
    std::vector<std::string> shown;
    auto next_redraw = Clock::now();
    for (;;) {
      const auto wake = session_.signals().wait(50ms, STDIN_FILENO);
      if (wake.signal != 0) {
        end_line();
        session_.interrupted(wake.signal);
      }
      if (wake.input) {
        char buffer[64];
        const ssize_t n = ::read(STDIN_FILENO, buffer, sizeof buffer);
        if (n == 0) return quit();  // the terminal is gone
        if (n > 0) pending.append(buffer, static_cast<std::size_t>(n));
        for (const Key key : take_keys(pending)) {
          if (key == Key::quit) return quit();
          if (key == Key::interrupt) {
            end_line();
            session_.interrupted(SIGINT);
          }
          handle(key);
        }
      }
      advance();
      // Redrawn once a second unchanged too: the terminal may have been resized.
      std::vector<std::string> parts = status_parts();
      if (parts != shown || Clock::now() >= next_redraw) {
        live_.show(parts, " | ");
        shown = std::move(parts);
        next_redraw = Clock::now() + 1s;
      }
    }
  }

 private:
  struct Jog {
    std::optional<double> goal;  // the target still to be commanded
  };

  Axis& axis(std::size_t i) { return *session_.axes()[i]; }

  void message(const std::string& text) { live_.print(text); }
  void end_line() { live_.clear(); }

  void handle(Key key) {
    switch (key) {
      case Key::rail_up: jog(0, +1); break;
      case Key::rail_down: jog(0, -1); break;
      case Key::turntable_up: jog(1, +1); break;
      case Key::turntable_down: jog(1, -1); break;
      // Said on a line of its own too: a narrow terminal leaves the step out of the status line.
      case Key::bigger:
        step_ = std::min(step_ + 1, kJogSteps.size() - 1);
        message(step_text());
        break;
      case Key::smaller:
        step_ = step_ > 0 ? step_ - 1 : 0;
        message(step_text());
        break;
      case Key::home:
        homing_.assign({0, 1});
        homing_started_ = false;
        for (auto& j : jogs_) j.goal.reset();
        break;
      case Key::stop:
        cancel();
        for (Axis* a : session_.axes()) {
          try {
            a->stop();
          } catch (const std::exception& e) {
            message(e.what());
          }
        }
        break;
      case Key::estop:
        cancel();
        for (Axis* a : session_.axes()) a->emergency_stop();
        message("EMERGENCY STOP: both axes disabled; press h to home them again");
        break;
      default: break;
    }
  }

  void cancel() {
    homing_.clear();
    homing_started_ = false;
    for (auto& j : jogs_) j.goal.reset();
  }

  void jog(std::size_t i, int direction) {
    Axis& a = axis(i);
    const AxisSettings& settings = a.settings();
    const AxisStatus s = a.status();
    if (!homing_.empty()) return message("homing in progress: wait, or press s to stop it");
    if (!s.homed) return message(fmt::format("{} is not homed: press h to home", settings.name));
    if (s.state == AxisState::fault)
      return message(fmt::format("{} is in fault ({}): press h to home", settings.name, s.fault));
    const double step = i == 0 ? kJogSteps[step_].first : kJogSteps[step_].second;
    const double base = jogs_[i].goal ? *jogs_[i].goal : (in_motion(s.state) ? s.target : s.position);
    const double wanted = base + direction * step;
    const double goal = std::clamp(wanted, settings.min_position, settings.max_position);
    if (goal != wanted)
      message(fmt::format("{}: at the soft limit ({})", settings.name, position_text(settings, goal)));
    jogs_[i].goal = goal;
  }

  // Carries the homing sequence and the jog goals forward.
  void advance() {
    if (!homing_.empty()) {
      Axis& a = axis(homing_.front());
      const AxisStatus s = a.status();
      if (!homing_started_) {
        try {
          session_.prepare(a, true);
          a.home();
          homing_started_ = true;
          message(fmt::format("{}: homing", a.settings().name));
        } catch (const std::exception& e) {
          message(e.what());
          cancel();
        }
      } else if (s.state != AxisState::homing) {
        homing_started_ = false;
        homing_.pop_front();
        if (s.homed && s.state == AxisState::idle) {
          message(fmt::format("{}: homed at {}", a.settings().name, position_text(a.settings(), s.position)));
        } else {
          message(fmt::format("{}: homing ended {}", a.settings().name,
                              s.state == AxisState::fault ? "in fault: " + s.fault : "without a reference"));
          cancel();
        }
      }
      return;
    }
    for (std::size_t i = 0; i < jogs_.size(); ++i) {
      if (!jogs_[i].goal) continue;
      Axis& a = axis(i);
      const AxisStatus s = a.status();
      if (s.state == AxisState::fault) {
        jogs_[i].goal.reset();
        continue;
      }
      if (in_motion(s.state)) continue;  // the goal follows when this leg ends
      const double goal = *jogs_[i].goal;
      jogs_[i].goal.reset();
      try {
        session_.prepare(a, false);
        a.move_to(goal);
      } catch (const std::exception& e) {
        message(e.what());
      }
    }
  }

  [[nodiscard]] std::string step_text() const {
    return fmt::format("step {:g} mm, {:g} deg", kJogSteps[step_].first, kJogSteps[step_].second);
  }

  // The status line's parts, the most important first: what fits the
  // terminal's width is shown.
  std::vector<std::string> status_parts() {
    std::vector<std::string> parts;
    for (Axis* a : session_.axes()) {
      const AxisStatus s = a->status();
      std::string flags = s.homed ? "homed" : "not homed";
      if (s.inputs.limit_min || s.inputs.limit_max || s.inputs.home || s.inputs.estop) {
        flags += ", " + inputs_text(s.inputs);
      }
      parts.push_back(fmt::format("{} {} {} ({})", a->settings().name, position_text(a->settings(), s.position),
                                  markerd::rig::to_string(s.state), flags));
    }
    const auto truth =
        markerd::rig::ground_truth(session_.rig().geometry(), axis(0).status().position, axis(1).status().position);
    parts.push_back(step_text());
    parts.push_back(fmt::format("d {:.3f} m, yaw {:.2f} deg", truth.distance_m, truth.yaw_deg));
    return parts;
  }

  // q: a controlled stop, then the Session disables the axes.
  int quit() {
    cancel();
    for (Axis* a : session_.axes()) {
      if (in_motion(a->status().state)) a->stop();
    }
    const auto all = session_.axes();
    while (std::any_of(all.begin(), all.end(), [](Axis* a) { return in_motion(a->status().state); })) {
      if (const int s = session_.signals().wait(20ms).signal) {
        end_line();
        session_.interrupted(s);
      }
    }
    end_line();
    std::cout << session_.positions() << '\n';
    return 0;
  }

  Session& session_;
  LiveLine live_{std::cout, STDOUT_FILENO};
  std::array<Jog, 2> jogs_{};
  std::deque<std::size_t> homing_;  // axes (0 rail, 1 turntable) still to home, in order
  bool homing_started_ = false;
  std::size_t step_ = kInitialJogStep;
};

}  // namespace

int run_interactive_jog(Session& session) { return InteractiveJog(session).run(); }

}  // namespace markerctl
