// markerctl snapshot: markerd's newest frame over the control socket
// (`snapshot`, docs/control.md#snapshot), saved as PNG, JPEG or PGM by the
// file's extension; --annotate has markerd draw what it knows on it.

#include "cmd_snapshot.hpp"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "cmd_daemon.hpp"
#include "markerd/base/ascii.hpp"
#include "markerd/base/base64.hpp"
#include "markerd/daemon/frame_annotation.hpp"

namespace markerctl {

namespace {

using markerd::daemon::ImageFormat;
using nlohmann::json;

struct SnapshotOptions {
  std::string socket;
  std::string output = "snapshot.png";
  bool annotate = false;
  bool json = false;
};

ImageFormat format_of(const std::string& path) {
  const std::string extension = std::filesystem::path(path).extension().string();
  const auto format = markerd::daemon::image_format_from_name(extension.empty() ? "" : extension.substr(1));
  if (!format) {
    throw usage_error("snapshot", fmt::format("-o {}: the format comes from the extension, which must be .png, .jpg, "
                                              ".jpeg or .pgm{}",
                                              path, extension.empty() ? " (it has none)" : ""));
  }
  return *format;
}

// One line for people: the file, the frame, what was found, where the rig stood.
std::string summary(const json& reply, const std::string& path) {
  const json& frame = reply["frame"];
  std::string text =
      fmt::format("{}: frame {} ({}x{}, {:.0f} ms old, {} bytes{})", path, frame.value("sequence", 0),
                  frame.value("width", 0), frame.value("height", 0), frame.value("age_ms", 0.0),
                  reply["image"].value("bytes", 0), reply["image"].value("annotated", false) ? ", annotated" : "");
  const json& detections = reply["detections"];
  if (detections.empty()) {
    text += "; no marker detected";
  } else {
    text += fmt::format("; {} detected:", detections.size());
    for (const json& d : detections) {
      text += fmt::format(" {} {}", d.value("family", std::string()), d.value("id", -1));
      if (d["pose"].is_object()) text += fmt::format(" at {:.3f} m", d["pose"].value("distance_m", 0.0));
    }
  }
  if (reply["truth"].is_object()) {
    text += fmt::format("; truth {:.3f} m, {:.1f} deg", reply["truth"].value("distance_m", 0.0),
                        reply["truth"].value("yaw_deg", 0.0));
  }
  return text;
}

int run_snapshot(const SnapshotOptions& o) {
  const ImageFormat format = format_of(o.output);
  if (o.annotate && format == ImageFormat::pgm) {
    throw usage_error("snapshot", "--annotate draws in colour: save it as .png or .jpg, not .pgm");
  }
  DaemonConnection daemon(o.socket, "snapshot");
  json reply = daemon.call(
      {{"cmd", "snapshot"}, {"format", std::string(markerd::daemon::to_string(format))}, {"annotate", o.annotate}},
      std::chrono::seconds(30));
  const std::vector<std::uint8_t> bytes = snapshot_image_bytes(reply, "snapshot");
  json& image = reply["image"];
  {
    std::ofstream file(o.output, std::ios::binary | std::ios::trunc);
    if (file) file.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
    if (file) file.close();
    if (!file) throw runtime_error("snapshot", fmt::format("cannot write {}", o.output));
  }
  image.erase("data");
  image.erase("encoding");
  reply["file"] = o.output;
  if (o.json) {
    std::cout << reply.dump(-1, ' ', false, json::error_handler_t::replace) << '\n';
  } else {
    std::cout << summary(reply, o.output) << '\n';
  }
  return 0;
}

}  // namespace

std::vector<std::uint8_t> snapshot_image_bytes(const json& reply, const std::string& context) {
  const json& image = reply["image"];
  auto bytes = markerd::base64_decode(image.value("data", std::string()));
  if (!bytes || bytes->size() != image.value("bytes", std::size_t{0})) {
    throw runtime_error(context,
                        "markerd's reply holds no readable image (its base64 data does not decode to "
                        "the bytes it announces)");
  }
  return std::move(*bytes);
}

void add_snapshot_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<SnapshotOptions>();
  CLI::App* app = parent.add_subcommand("snapshot", "Save markerd's newest frame as an image (PNG, JPEG or PGM)");
  app->add_option("-o,--output", o->output, "The image file; its extension gives the format (default snapshot.png)")
      ->type_name("FILE");
  app->add_flag("--annotate", o->annotate,
                "Draw the detections (outline, id, pose axes), the ground truth and the rig's state on it");
  app->add_flag("--json", o->json, "Print what is known of the frame as one JSON object, the file's name with it");
  app->add_option("--socket", o->socket,
                  "markerd's control socket (default: $MARKERD_SOCKET, else /run/markerd/control.sock)")
      ->type_name("PATH");
  app->footer(
      "Talks to a running markerd over its control socket (docs/control.md). The frame is the newest\n"
      "markerd copied out of its pipeline: it copies one every half second (every tenth while someone\n"
      "watches), so a frame is that much older at most than the pipeline's latest. Example:\n"
      "  markerctl snapshot --annotate -o aim.png");
  commands.push_back({app, [o] { return run_snapshot(*o); }});
}

}  // namespace markerctl
