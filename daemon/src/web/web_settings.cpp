#include "markerd/daemon/web/web_settings.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>

#include <fmt/format.h>

#include <charconv>

namespace markerd::daemon {

namespace {

bool ipv4(const std::string& host) {
  in_addr address{};
  return ::inet_pton(AF_INET, host.c_str(), &address) == 1;
}

bool ipv6(const std::string& host) {
  in6_addr address{};
  return ::inet_pton(AF_INET6, host.c_str(), &address) == 1;
}

}  // namespace

bool WebSettings::loopback() const {
  in_addr v4{};
  if (::inet_pton(AF_INET, host.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (::inet_pton(AF_INET6, host.c_str(), &v6) == 1) return IN6_IS_ADDR_LOOPBACK(&v6) != 0;
  return false;
}

WebSettings parse_web_settings(const ConfigTable& t) {
  t.allow_only({"enabled", "listen", "preview_fps"});
  WebSettings w;
  w.enabled = t.optional<bool>("enabled", w.enabled);
  const std::string fallback = fmt::format("{}:{}", w.host, w.port);
  const std::string listen = t.optional<std::string>("listen", fallback);
  // "HOST:PORT" or "[HOST6]:PORT"; numbers only, so that what is exposed
  // never depends on a name service.
  const auto bad = [&](std::string_view why) {
    t.fail("listen", fmt::format("must be \"ADDRESS:PORT\" with a numeric address (\"127.0.0.1:8080\", "
                                 "\"[::1]:8080\"; \"0.0.0.0:8080\" for every interface), got \"{}\": {}",
                                 listen, why));
  };
  if (listen.find('\0') != std::string::npos) bad("a NUL character");
  std::string host;
  std::string port_text;
  if (listen.starts_with('[')) {
    const auto close = listen.find("]:");
    if (close == std::string::npos) bad("an IPv6 address in brackets must be followed by :PORT");
    host = listen.substr(1, close - 1);
    port_text = listen.substr(close + 2);
    if (!ipv6(host)) bad(fmt::format("\"{}\" is not an IPv6 address", host));
  } else {
    const auto colon = listen.rfind(':');
    if (colon == std::string::npos) bad("no port");
    host = listen.substr(0, colon);
    port_text = listen.substr(colon + 1);
    if (host.find(':') != std::string::npos) bad("an IPv6 address goes in brackets");
    if (!ipv4(host)) bad(fmt::format("\"{}\" is not an IPv4 address", host));
  }
  int port = -1;
  const auto [end, error] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (error != std::errc() || end != port_text.data() + port_text.size() || port < 0 || port > 65535) {
    bad(fmt::format("the port must be 0 to 65535, got \"{}\"", port_text));
  }
  w.host = host;
  w.port = port;
  // Each frame is encoded once per second per rate, whoever watches.
  w.preview_fps = t.optional<double>("preview_fps", w.preview_fps, {0.5, 30, "frames per second"});
  const toml::node* node = t.raw().get("listen");
  w.listen_origin = node != nullptr && node->source().begin.line > 0
                        ? fmt::format("{}:{}: web.listen", t.source(), node->source().begin.line)
                        : fmt::format("{}: web.listen", t.source());
  return w;
}

}  // namespace markerd::daemon
