#pragma once
// markerd's read-only web page (docs/web.md), served by cpp-httplib on its
// own threads: the page itself (compiled in), a live annotated preview
// (MJPEG), a snapshot, the state as JSON (the rig, the sweep, the
// detections) and the last sweep run's report files. GET and HEAD only.
//
// Nothing here touches the pipeline: frames come from the LatestFrame slot,
// and each is encoded once however many watch it. Every client has a
// thread of the server's pool; a slow one stalls only its own (its writes
// time out), a limited number of previews stream at once, and stop() ends
// them all within a fraction of a second.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/frame_annotation.hpp"
#include "markerd/daemon/latest_frame.hpp"
#include "markerd/daemon/web/web_settings.hpp"

namespace httplib {
class Server;
struct Request;
struct Response;
}  // namespace httplib

namespace markerd::daemon {

// The server cannot listen (the address is in use, not this machine's):
// what() names the address and the cause.
class WebServerError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// What the page shows, asked for on the server's threads (each must be safe
// to call from any thread, at any time until stop() returns).
struct WebSources {
  const LatestFrame* latest = nullptr;  // must outlive the server
  AnnotationContext annotation;
  // /state.json: the rig, the sweep, the camera, ... as one object.
  std::function<nlohmann::json()> state;
  // The directory of the last sweep run's report files; nothing when there
  // is none. The run's id goes with it.
  struct Report {
    std::string run_id;
    std::filesystem::path directory;
  };
  std::function<std::optional<Report>()> report;
};

class WebServer {
 public:
  // Previews streaming at once; one more is refused (503) until one ends.
  static constexpr std::size_t kMaxPreviews = 4;
  // Report files are served up to this size.
  static constexpr std::uintmax_t kMaxReportFileBytes = 64ULL << 20;

  WebServer(WebSettings settings, WebSources sources);
  ~WebServer();  // stop()
  WebServer(const WebServer&) = delete;
  WebServer& operator=(const WebServer&) = delete;

  // Binds the address (WebServerError when it cannot) and starts serving.
  void start();
  // Ends the previews, closes the listening socket, and waits for the
  // server's threads. Idempotent.
  void stop() noexcept;

  // The port bound (the one chosen, for port 0); 0 before start().
  [[nodiscard]] int port() const noexcept { return port_.load(std::memory_order_relaxed); }
  // "http://127.0.0.1:8080/"; "http://[::1]:8080/".
  [[nodiscard]] std::string url() const;
  [[nodiscard]] const WebSettings& settings() const noexcept { return settings_; }
  [[nodiscard]] std::size_t previews() const noexcept { return previews_.load(std::memory_order_relaxed); }

 private:
  struct Encoded {
    std::uint64_t copy = 0;
    std::shared_ptr<const std::vector<std::uint8_t>> bytes;
  };

  void route();
  void serve_preview(const httplib::Request& request, httplib::Response& response);
  void serve_snapshot(const httplib::Request& request, httplib::Response& response, ImageFormat format);
  void serve_report_index(httplib::Response& response, bool as_json);
  void serve_report_file(const std::string& name, httplib::Response& response);
  // The frame as JPEG, encoded once for every preview and snapshot that asks.
  std::shared_ptr<const std::vector<std::uint8_t>> jpeg_of(const HeldFrame& frame, bool annotated);

  const WebSettings settings_;
  const WebSources sources_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  std::atomic<int> port_{0};
  std::atomic<bool> stopping_{false};
  std::atomic<std::size_t> previews_{0};
  std::mutex encode_mutex_;
  Encoded encoded_[2];  // plain, annotated
  bool stopped_ = false;
};

}  // namespace markerd::daemon
