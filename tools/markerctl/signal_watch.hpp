#pragma once
// The interrupt signals of a markerctl command that moves a rig, read from a
// signalfd by the command's own wait loop, so that the stop runs on the main
// thread with the full rig at hand, not in a signal handler.

#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <fmt/format.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <stdexcept>
#include <string>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"

namespace markerctl {

// SIGINT, SIGTERM, SIGHUP and SIGQUIT, blocked in this thread and in every
// thread started after it (the rig's), and read from a signalfd. They stay
// blocked until the process ends: a late one must not kill it half way
// through disabling the axes. SIGINT, SIGHUP and SIGQUIT stay ignored when
// the process was started with them ignored (a background job of a shell,
// nohup), as every Unix command does; SIGTERM is always taken.
class SignalWatch {
 public:
  SignalWatch() {
    sigemptyset(&set_);
    for (const int s : {SIGINT, SIGTERM, SIGHUP, SIGQUIT}) {
      struct sigaction current {};
      sigaction(s, nullptr, &current);
      if (s != SIGTERM && current.sa_handler == SIG_IGN) continue;
      // An ignored signal would be discarded even while blocked.
      if (current.sa_handler == SIG_IGN) ::signal(s, SIG_DFL);
      sigaddset(&set_, s);
    }
    if (const int error = pthread_sigmask(SIG_BLOCK, &set_, nullptr); error != 0) {
      throw std::runtime_error(fmt::format("cannot block the interrupt signals: {}", markerd::errno_text(error)));
    }
    fd_.reset(signalfd(-1, &set_, SFD_CLOEXEC | SFD_NONBLOCK));
    if (!fd_) throw std::runtime_error(fmt::format("signalfd: {}", markerd::errno_text(errno)));
  }
  SignalWatch(const SignalWatch&) = delete;
  SignalWatch& operator=(const SignalWatch&) = delete;

  struct Wake {
    int signal = 0;      // the signal received, or 0
    bool input = false;  // `input_fd` is readable
  };
  // Sleeps up to `timeout`, waking early for a signal or input.
  Wake wait(std::chrono::milliseconds timeout, int input_fd = -1) const {
    std::array<pollfd, 2> fds{{{fd_.get(), POLLIN, 0}, {input_fd, POLLIN, 0}}};
    const nfds_t count = input_fd >= 0 ? 2 : 1;
    Wake wake;
    if (::poll(fds.data(), count, static_cast<int>(timeout.count())) <= 0) return wake;
    if ((fds[0].revents & POLLIN) != 0) {
      signalfd_siginfo info{};
      if (::read(fd_.get(), &info, sizeof info) == static_cast<ssize_t>(sizeof info)) {
        wake.signal = static_cast<int>(info.ssi_signo);
      }
    }
    wake.input = count == 2 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR)) != 0;
    return wake;
  }

 private:
  sigset_t set_{};
  markerd::UniqueFd fd_;
};

inline std::string signal_name(int signal) {
  const char* abbrev = sigabbrev_np(signal);
  return abbrev != nullptr ? fmt::format("SIG{}", abbrev) : fmt::format("signal {}", signal);
}

}  // namespace markerctl
