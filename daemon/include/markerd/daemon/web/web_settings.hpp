#pragma once
// markerd.toml's [web] table: the read-only web page (docs/web.md). Off
// unless the config turns it on; on, it listens on the loopback address
// unless the config names another.

#include <string>

#include "markerd/base/config_table.hpp"

namespace markerd::daemon {

struct WebSettings {
  bool enabled = false;
  // A numeric address: IPv4 ("127.0.0.1", "0.0.0.0") or IPv6 ("::1", "::"),
  // written "[::1]:8080" in `listen`.
  std::string host = "127.0.0.1";
  int port = 8080;  // 0: any free port (status and the log say which)
  double preview_fps = 10;
  // "markerd.toml:60: web.listen", for the errors found at start.
  std::string listen_origin;

  [[nodiscard]] bool loopback() const;
};

// ConfigError naming the file, line and key for anything else.
[[nodiscard]] WebSettings parse_web_settings(const ConfigTable& table);

}  // namespace markerd::daemon
