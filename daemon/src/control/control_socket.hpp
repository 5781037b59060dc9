#pragma once
// The control socket's file: its path and group checked, a stale socket
// replaced, and the socket bound with its owner, group and mode set before
// any client can connect. Internal to control.

#include <sys/types.h>

#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/control/control_server.hpp"

namespace markerd::daemon {

struct ListeningSocket {
  UniqueFd fd;    // listening, non-blocking
  dev_t dev = 0;  // the socket file's identity: the server removes it at stop
  ino_t ino = 0;  // only if it is still the one it made
};

// A ControlSocketError naming the path and what is wrong; on failure nothing
// is left behind (a socket file this call made is removed).
ListeningSocket listen_on_control_socket(const ControlSettings& settings);

}  // namespace markerd::daemon
