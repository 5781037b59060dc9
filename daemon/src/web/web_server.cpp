#include "markerd/daemon/web/web_server.hpp"

#include <fcntl.h>
#include <netdb.h>
#include <pthread.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <opencv2/core.hpp>
#include <regex>
#include <string_view>
#include <thread>

#include "markerd/base/ascii.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "web_page.hpp"

// Last: it brings in <resolv.h>, whose _res macro breaks Eigen's headers
// (through web_server.hpp's) when they come after it.
#include <httplib.h>

namespace markerd::daemon {

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

constexpr const char* kBoundary = "markerdframe";
// Threads of the server's pool: one per preview, the rest for the page's
// requests (a browser keeps up to six connections).
constexpr std::size_t kThreads = WebServer::kMaxPreviews + 8;
// A client that takes no bytes for this long is dropped; an idle keep-alive
// connection is closed after a second, so that stop() never waits for one.
constexpr time_t kIoTimeoutS = 5;
constexpr time_t kKeepAliveS = 1;
// How long a preview waits for a frame before it looks whether it must stop.
constexpr auto kPreviewPoll = 200ms;

// What a browser may do with what markerd serves: the page's own scripts and
// styles, its images; nothing from elsewhere, nothing framed.
const char* kPageSecurity =
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
    "frame-ancestors 'none'; base-uri 'none'; form-action 'none'";
// A report file opened on its own (an SVG, an HTML page a later report may
// write) runs no script.
const char* kReportSecurity = "sandbox; default-src 'none'; img-src 'self'; style-src 'unsafe-inline'";

bool annotated(const httplib::Request& request) {
  return !request.has_param("annotate") || request.get_param_value("annotate") != "0";
}

void text(httplib::Response& response, int status, const std::string& body) {
  response.status = status;
  response.set_content(body + "\n", "text/plain; charset=utf-8");
}

// A report file's name: one path component of the characters a report
// writes, not hidden. Everything else (a '/', "..", a NUL, a '%' that
// survived decoding) is no file of the report.
bool report_name(const std::string& name) {
  static const std::regex kName("[A-Za-z0-9][A-Za-z0-9._-]{0,127}");
  return std::regex_match(name, kName) && name.find("..") == std::string::npos;
}

// Text for an HTML page: the characters that would be markup, escaped.
std::string html_text(std::string_view text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '&': out += "&amp;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string report_type(const std::string& name) {
  const auto dot = name.rfind('.');
  const std::string extension = dot == std::string::npos ? std::string() : ascii_lower(name.substr(dot + 1));
  if (extension == "svg") return "image/svg+xml";
  if (extension == "png") return "image/png";
  if (extension == "json" || extension == "jsonl") return "application/json";
  if (extension == "html") return "text/html; charset=utf-8";
  if (extension == "csv" || extension == "md" || extension == "txt" || extension == "gp" || extension == "dat") {
    return "text/plain; charset=utf-8";  // shown, not downloaded
  }
  return "application/octet-stream";
}

// Why binding `host`:`port` fails, found by trying it: cpp-httplib says only
// that it did.
std::string bind_problem(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICHOST | AI_NUMERICSERV | AI_PASSIVE;
  addrinfo* found = nullptr;
  const std::string service = std::to_string(port);
  if (const int error = ::getaddrinfo(host.c_str(), service.c_str(), &hints, &found); error != 0) {
    return ::gai_strerror(error);
  }
  std::string problem = "cpp-httplib could not listen there";
  UniqueFd fd(::socket(found->ai_family, found->ai_socktype | SOCK_CLOEXEC, found->ai_protocol));
  if (!fd) {
    problem = errno_text(errno);
  } else if (::bind(fd.get(), found->ai_addr, found->ai_addrlen) != 0) {
    problem = errno_text(errno);
  }
  ::freeaddrinfo(found);
  return problem;
}

}  // namespace

WebServer::WebServer(WebSettings settings, WebSources sources)
    : settings_(std::move(settings)), sources_(std::move(sources)), server_(std::make_unique<httplib::Server>()) {
  server_->new_task_queue = [] { return new httplib::ThreadPool(kThreads); };
  // SO_REUSEADDR, not cpp-httplib's SO_REUSEPORT: a second markerd on the
  // same port must be refused, not handed half the connections.
  server_->set_socket_options([](socket_t sock) {
    const int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
    ::fcntl(sock, F_SETFD, FD_CLOEXEC);
  });
  server_->set_read_timeout(kIoTimeoutS, 0);
  server_->set_write_timeout(kIoTimeoutS, 0);
  server_->set_keep_alive_timeout(kKeepAliveS);
  server_->set_payload_max_length(64 * 1024);
  server_->set_default_headers({{"Cache-Control", "no-store"},
                                {"X-Content-Type-Options", "nosniff"},
                                {"Referrer-Policy", "no-referrer"},
                                {"Content-Security-Policy", kPageSecurity}});
  route();
}

WebServer::~WebServer() { stop(); }

void WebServer::route() {
  // Read-only: a request that would change something has no handler to reach.
  server_->set_pre_routing_handler([](const httplib::Request& request, httplib::Response& response) {
    if (request.method == "GET" || request.method == "HEAD") return httplib::Server::HandlerResponse::Unhandled;
    response.set_header("Allow", "GET, HEAD");
    text(response, 405,
         fmt::format("{} is not served: markerd's web page is read-only (GET and HEAD)", request.method));
    return httplib::Server::HandlerResponse::Handled;
  });
  // Its own errors' words stay; cpp-httplib's bare ones (no route) get some.
  server_->set_error_handler(
      httplib::Server::HandlerWithResponse([](const httplib::Request& request, httplib::Response& response) {
        if (!response.body.empty() || response.content_provider_) return httplib::Server::HandlerResponse::Unhandled;
        text(response, response.status,
             response.status == 404 ? fmt::format("{}: no such page", request.path)
                                    : fmt::format("error {}", response.status));
        return httplib::Server::HandlerResponse::Handled;
      }));
  server_->set_exception_handler(
      [](const httplib::Request& request, httplib::Response& response, std::exception_ptr error) {
        std::string why = "an internal error";
        try {
          if (error) std::rethrow_exception(error);
        } catch (const std::exception& e) {
          why = e.what();
        } catch (...) {  // NOLINT(bugprone-empty-catch): reported as an internal error below
        }
        spdlog::warn("web: {} failed: {}", request.path, why);
        text(response, 500, fmt::format("{} failed: {}", request.path, why));
      });

  server_->Get("/", [](const httplib::Request&, httplib::Response& response) {
    response.set_content(std::string(web_page::kIndexHtml), "text/html; charset=utf-8");
  });
  server_->Get("/app.js", [](const httplib::Request&, httplib::Response& response) {
    response.set_content(std::string(web_page::kAppJs), "text/javascript; charset=utf-8");
  });
  server_->Get("/style.css", [](const httplib::Request&, httplib::Response& response) {
    response.set_content(std::string(web_page::kStyleCss), "text/css; charset=utf-8");
  });
  server_->Get("/state.json", [this](const httplib::Request&, httplib::Response& response) {
    nlohmann::json state = sources_.state ? sources_.state() : nlohmann::json::object();
    state["web"] = {{"preview_fps", settings_.preview_fps}, {"previews", previews()}, {"max_previews", kMaxPreviews}};
    response.set_content(state.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace), "application/json");
  });
  server_->Get("/preview.mjpg", [this](const httplib::Request& request, httplib::Response& response) {
    serve_preview(request, response);
  });
  server_->Get("/snapshot.jpg", [this](const httplib::Request& request, httplib::Response& response) {
    serve_snapshot(request, response, ImageFormat::jpeg);
  });
  server_->Get("/snapshot.png", [this](const httplib::Request& request, httplib::Response& response) {
    serve_snapshot(request, response, ImageFormat::png);
  });
  server_->Get("/report", [](const httplib::Request&, httplib::Response& response) {
    response.status = 301;
    response.set_header("Location", "/report/");
  });
  server_->Get("/report/",
               [this](const httplib::Request&, httplib::Response& response) { serve_report_index(response, false); });
  server_->Get("/report/index.json",
               [this](const httplib::Request&, httplib::Response& response) { serve_report_index(response, true); });
  server_->Get("/report/(.*)", [this](const httplib::Request& request, httplib::Response& response) {
    serve_report_file(request.matches[1].str(), response);
  });
}

void WebServer::start() {
  if (server_->is_running() || thread_.joinable()) throw std::logic_error("web server: started twice");
  const std::string address = settings_.host.find(':') != std::string::npos
                                  ? fmt::format("[{}]:{}", settings_.host, settings_.port)
                                  : fmt::format("{}:{}", settings_.host, settings_.port);
  int port = settings_.port;
  if (port == 0) {
    port = server_->bind_to_any_port(settings_.host);
    if (port < 0) port = 0;
  } else if (!server_->bind_to_port(settings_.host, port)) {
    port = 0;
  }
  if (port == 0) {
    throw WebServerError(fmt::format("{}: the web page cannot listen on {}: {}", settings_.listen_origin, address,
                                     bind_problem(settings_.host, settings_.port)));
  }
  port_.store(port, std::memory_order_relaxed);
  thread_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "markerd-web");
    if (!server_->listen_after_bind()) spdlog::error("web: the server stopped listening on its own");
  });
  // stop() may come at once: it must find the server running, or its
  // socket would stay open and the thread waiting in accept().
  const auto deadline = Clock::now() + 10s;
  while (!server_->is_running() && Clock::now() < deadline) std::this_thread::sleep_for(1ms);
  if (!settings_.loopback()) {
    spdlog::warn("web: serving {} to the network (web.listen = {}): whoever reaches it sees the camera", url(),
                 address);
  } else {
    spdlog::info("web: serving {}", url());
  }
}

void WebServer::stop() noexcept {
  if (stopped_) return;
  stopped_ = true;
  stopping_.store(true, std::memory_order_relaxed);
  if (sources_.latest != nullptr) sources_.latest->wake_all();
  if (thread_.joinable()) {
    // listen_after_bind() returns once the pool's threads are done: each
    // preview within kPreviewPoll, each other request when it is answered.
    server_->stop();
    thread_.join();
  }
}

std::string WebServer::url() const {
  const std::string host = settings_.host == "0.0.0.0" ? "127.0.0.1" : settings_.host == "::" ? "::1" : settings_.host;
  return host.find(':') != std::string::npos ? fmt::format("http://[{}]:{}/", host, port())
                                             : fmt::format("http://{}:{}/", host, port());
}

std::shared_ptr<const std::vector<std::uint8_t>> WebServer::jpeg_of(const HeldFrame& frame, bool annotate) {
  const std::lock_guard lock(encode_mutex_);
  Encoded& cached = encoded_[annotate ? 1 : 0];
  if (cached.bytes && cached.copy == frame.copy) return cached.bytes;
  const cv::Mat image = annotate ? annotated_image(frame, sources_.annotation) : grey_image(frame);
  cached.bytes = std::make_shared<const std::vector<std::uint8_t>>(encode_image(image, ImageFormat::jpeg, 80));
  cached.copy = frame.copy;
  return cached.bytes;
}

void WebServer::serve_snapshot(const httplib::Request& request, httplib::Response& response, ImageFormat format) {
  const auto frame = sources_.latest != nullptr ? sources_.latest->latest() : nullptr;
  if (!frame) {
    text(response, 503, "no frame yet: the camera has delivered none since markerd started");
    return;
  }
  const bool annotate = annotated(request);
  if (format == ImageFormat::jpeg) {
    const auto bytes = jpeg_of(*frame, annotate);
    response.set_content(reinterpret_cast<const char*>(bytes->data()), bytes->size(), "image/jpeg");
  } else {
    const std::vector<std::uint8_t> bytes =
        encode_image(annotate ? annotated_image(*frame, sources_.annotation) : grey_image(*frame), format);
    response.set_content(reinterpret_cast<const char*>(bytes.data()), bytes.size(), std::string(mime_type(format)));
  }
  response.set_header("X-Markerd-Frame", std::to_string(frame->sequence));
}

void WebServer::serve_preview(const httplib::Request& request, httplib::Response& response) {
  if (sources_.latest == nullptr) {
    text(response, 404, "no camera");
    return;
  }
  // One slot per preview, given back when its response is destroyed.
  std::size_t count = previews_.load(std::memory_order_relaxed);
  do {
    if (count >= kMaxPreviews) {
      response.set_header("Retry-After", "5");
      text(response, 503, fmt::format("{} previews are streaming, markerd's limit: close one and reload", count));
      return;
    }
  } while (!previews_.compare_exchange_weak(count, count + 1, std::memory_order_relaxed));
  auto slot = std::shared_ptr<void>(nullptr, [this](void*) { previews_.fetch_sub(1, std::memory_order_relaxed); });

  struct Stream {
    std::uint64_t last = 0;
    Clock::time_point next{};
  };
  auto stream = std::make_shared<Stream>();
  const bool annotate = annotated(request);
  const auto interval =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / settings_.preview_fps));
  response.set_content_provider(
      fmt::format("multipart/x-mixed-replace; boundary={}", kBoundary),
      [this, slot, stream, annotate, interval](std::size_t, httplib::DataSink& sink) {
        // One frame per call; cpp-httplib calls again until the server stops
        // or a write fails (the client went, or took nothing for kIoTimeoutS).
        if (stopping_.load(std::memory_order_relaxed)) return false;
        if (const auto now = Clock::now(); now < stream->next) {
          std::this_thread::sleep_for(std::min<Clock::duration>(stream->next - now, kPreviewPoll));
          return true;
        }
        const auto frame = sources_.latest->wait_newer(stream->last, Clock::now() + kPreviewPoll);
        if (stopping_.load(std::memory_order_relaxed)) return false;
        if (!frame || frame->copy <= stream->last) return true;
        const auto jpeg = jpeg_of(*frame, annotate);
        const std::string header = fmt::format(
            "--{}\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\n"
            "X-Markerd-Frame: {}\r\n\r\n",
            kBoundary, jpeg->size(), frame->sequence);
        if (!sink.write(header.data(), header.size())) return false;
        if (!sink.write(reinterpret_cast<const char*>(jpeg->data()), jpeg->size())) return false;
        if (!sink.write("\r\n", 2)) return false;
        stream->last = frame->copy;
        stream->next = Clock::now() + interval;
        return true;
      });
}

void WebServer::serve_report_index(httplib::Response& response, bool as_json) {
  const auto report = sources_.report ? sources_.report() : std::nullopt;
  nlohmann::json index{{"run_id", nullptr}, {"files", nlohmann::json::array()}};
  if (report) {
    index["run_id"] = report->run_id;
    std::vector<std::string> names;
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(report->directory, ec)) {
      const std::string name = entry.path().filename().string();
      if (report_name(name) && entry.is_regular_file(ec) && !entry.is_symlink(ec)) names.push_back(name);
    }
    std::sort(names.begin(), names.end());
    for (const std::string& name : names) index["files"].push_back(name);
  }
  if (as_json) {
    response.set_content(index.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace), "application/json");
    return;
  }
  std::string html =
      "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>markerd: the last run's report</title>"
      "<link rel=\"stylesheet\" href=\"/style.css\"></head><body><main>\n";
  if (!report) {
    html += "<p>No sweep run has a report yet.</p>\n";
  } else {
    // A run id carries the plan's name, which may hold anything; file
    // names are report_name()s, which need no escaping.
    html += fmt::format("<h1>Run {}</h1>\n<ul>\n", html_text(report->run_id));
    for (const auto& name : index["files"]) {
      html += fmt::format("<li><a href=\"{0}\">{0}</a></li>\n", name.get<std::string>());
    }
    html += "</ul>\n";
  }
  html += "<p><a href=\"/\">back to the live view</a></p></main></body></html>\n";
  response.set_content(html, "text/html; charset=utf-8");
}

void WebServer::serve_report_file(const std::string& name, httplib::Response& response) {
  if (!report_name(name)) {
    text(response, 404, "no such report file (a report file's name is one path component)");
    return;
  }
  const auto report = sources_.report ? sources_.report() : std::nullopt;
  if (!report) {
    text(response, 404, "no sweep run has a report yet");
    return;
  }
  const std::filesystem::path path = report->directory / name;
  // O_NOFOLLOW: a link placed in the report directory leads nowhere.
  const UniqueFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK));
  struct stat st {};
  if (!fd || ::fstat(fd.get(), &st) != 0 || !S_ISREG(st.st_mode)) {
    text(response, 404, fmt::format("{}: no such file in run {}'s report", name, report->run_id));
    return;
  }
  if (static_cast<std::uintmax_t>(st.st_size) > kMaxReportFileBytes) {
    text(response, 413, fmt::format("{}: larger than the {} MiB the page serves", name, kMaxReportFileBytes >> 20));
    return;
  }
  std::string body(static_cast<std::size_t>(st.st_size), '\0');
  std::size_t got = 0;
  while (got < body.size()) {
    const ssize_t n = ::read(fd.get(), body.data() + got, body.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    got += static_cast<std::size_t>(n);
  }
  body.resize(got);
  // In place of the page's policy, not beside it (cpp-httplib adds its
  // default headers before the handler runs): a plot's inline styles apply.
  response.headers.erase("Content-Security-Policy");
  response.set_header("Content-Security-Policy", kReportSecurity);
  response.set_content(body, report_type(name));
}

}  // namespace markerd::daemon
