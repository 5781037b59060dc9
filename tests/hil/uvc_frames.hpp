#pragma once
// What the UVC gadget server (uvc_gadget_server.cpp) sends and what the
// tests on the host side of the emulated webcam (test_uvc_hil.cpp) read back:
// the frame number stamped into each frame's pixels, which scene a frame
// number shows, and the server's records.
//
// A number in the pixels, not the stream's own sequence: uvcvideo and
// libcamera count the frames they received, and only the pixels tell which
// of the frames sent arrived, so that order and loss are checked, not
// assumed.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "markerd/detector/image.hpp"

namespace markerd::hil {

// The number, then its complement, one bit per cell of kStampCellWidth x
// kStampRows pixels along the top of the frame, least significant first:
// 512 of the 640 pixels of the first two rows, far from the markers of
// feeder_scenes(), which sit near the middle.
constexpr int kStampBits = 32;
constexpr int kStampCellWidth = 8;
constexpr int kStampRows = 2;
constexpr std::uint8_t kStampDark = 16;
constexpr std::uint8_t kStampLight = 235;

// Writes `number` into the Y samples of a YUYV frame (Y at every even byte).
inline void stamp_yuyv(std::uint8_t* yuyv, std::size_t stride, std::uint32_t number) {
  for (int cell = 0; cell < 2 * kStampBits; ++cell) {
    const std::uint32_t word = cell < kStampBits ? number : ~number;
    const bool bit = ((word >> (cell % kStampBits)) & 1U) != 0;
    for (int y = 0; y < kStampRows; ++y) {
      std::uint8_t* row = yuyv + static_cast<std::size_t>(y) * stride;
      for (int x = cell * kStampCellWidth; x < (cell + 1) * kStampCellWidth; ++x) {
        row[2 * x] = bit ? kStampLight : kStampDark;
      }
    }
  }
}

// The stamped number of a grey frame; nothing when the stamp does not read
// back as a number and its complement (a torn or foreign frame).
inline std::optional<std::uint32_t> read_stamp(const detector::GreyView& image) {
  if (image.empty() || image.width < 2 * kStampBits * kStampCellWidth || image.height < kStampRows) return std::nullopt;
  std::uint64_t bits = 0;
  for (int cell = 0; cell < 2 * kStampBits; ++cell) {
    int sum = 0;
    for (int y = 0; y < kStampRows; ++y) {
      for (int x = cell * kStampCellWidth; x < (cell + 1) * kStampCellWidth; ++x) sum += image.at(x, y);
    }
    if (sum > (kStampDark + kStampLight) / 2 * kStampCellWidth * kStampRows) bits |= std::uint64_t{1} << cell;
  }
  const auto number = static_cast<std::uint32_t>(bits);
  if (static_cast<std::uint32_t>(bits >> kStampBits) != ~number) return std::nullopt;
  return number;
}

// The server shows scene (number / frames_per_scene) % scenes of
// feeder_scenes() in frame `number`.
inline std::size_t scene_of(std::uint32_t number, std::uint32_t frames_per_scene, std::size_t scenes) {
  return (number / frames_per_scene) % scenes;
}

// The server's records, in its --out-dir, one JSON object a line, each line
// written whole:
//   frames.jsonl    {"frame": n, "scene": s, "id": id, "format": "YUYV" or "MJPEG",
//                   "bytes": b, "queued_ns": t} when frame n went to the gadget
//                   (VIDIOC_QBUF), and {"frame": n, "done_ns": t,
//                   "error": false} when the gadget gave its buffer back, the
//                   frame encoded into USB requests (or failed: the host stopped)
//   controls.jsonl  every class request of the host as it came: {"t_ns", "request"
//                   ("GET_CUR", "SET_CUR", "GET_MIN", ...), "interface" ("control" or
//                   "streaming"), "entity", "selector", "name" ("brightness",
//                   "ae_mode", "probe", "commit", "request_error_code" or
//                   "unknown"), "length", "stalled"}; and after a SET_CUR, its data
//                   stage: {"t_ns", "request": "SET_CUR", "name", "length",
//                   "stalled": false} with "value" (an integer) for brightness and
//                   ae_mode; "requested_interval", "frame_interval" (the one
//                   chosen), "requested_format_index" and "format" (the one
//                   chosen, "YUYV" or "MJPEG") for a probe or commit
// Times are CLOCK_MONOTONIC in nanoseconds, the clock of V4L2's and
// libcamera's frame timestamps and of steady_clock.
constexpr const char* kFramesRecord = "frames.jsonl";
constexpr const char* kControlsRecord = "controls.jsonl";

// The complete lines of a record the server may still be writing (a line
// being written has no '\n' yet).
inline std::vector<nlohmann::json> read_records(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  std::vector<nlohmann::json> lines;
  std::size_t start = 0;
  for (std::size_t end = text.find('\n'); end != std::string::npos; end = text.find('\n', start)) {
    lines.push_back(nlohmann::json::parse(text.substr(start, end - start)));
    start = end + 1;
  }
  return lines;
}

// A frame of frames.jsonl, its two lines joined.
struct SentFrame {
  int id = -1;  // -1: only its "done" line was read
  std::size_t scene = 0;
  std::string format;  // "YUYV" or "MJPEG"
  std::size_t bytes = 0;
  std::int64_t queued_ns = 0;
  std::optional<std::int64_t> done_ns;
  bool error = false;
};

inline std::map<std::uint32_t, SentFrame> sent_frames(const std::filesystem::path& dir) {
  std::map<std::uint32_t, SentFrame> frames;
  for (const nlohmann::json& line : read_records(dir / kFramesRecord)) {
    SentFrame& f = frames[line.at("frame").get<std::uint32_t>()];
    if (line.contains("queued_ns")) {
      f.id = line.at("id").get<int>();
      f.scene = line.at("scene").get<std::size_t>();
      f.format = line.at("format").get<std::string>();
      f.bytes = line.at("bytes").get<std::size_t>();
      f.queued_ns = line.at("queued_ns").get<std::int64_t>();
    } else {
      f.done_ns = line.at("done_ns").get<std::int64_t>();
      f.error = line.at("error").get<bool>();
    }
  }
  return frames;
}

}  // namespace markerd::hil
