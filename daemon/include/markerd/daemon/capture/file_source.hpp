#pragma once
// The file source: replays a directory of images (taken in name order) or a
// video file as a camera, at a set frame rate or as fast as the pipeline
// takes frames (what a lossless replay wants). Every frame is decoded to grey
// straight into the frame slot's own pixel buffer. See docs/capture.md.

#include <filesystem>
#include <memory>

#include "markerd/base/config_table.hpp"
#include "markerd/daemon/capture/capture_source.hpp"

namespace markerd::daemon {

struct FileSourceSettings {
  // A directory of images (the formats ImageFileReader reads, image_file.hpp,
  // recognised by their extension) or a video file OpenCV's VideoCapture reads. Absolute
  // once parsed: a relative path in the config is taken from the config
  // file's directory.
  std::filesystem::path path;
  double fps = 0;     // 0: a frame whenever the pipeline asks; > 0: paced on the steady clock
  bool loop = false;  // start again after the last frame instead of ending
};

// Reads [camera.file]. `config_dir` is the directory of the config file.
[[nodiscard]] FileSourceSettings parse_file_source_settings(const ConfigTable& table,
                                                            const std::filesystem::path& config_dir);

// Probes the path at once, so that geometry() is known before open(): lists
// the directory and reads the header of its first readable image, or reads
// the video's first frame. Throws CaptureError: not_found for a missing path or a
// directory without images, config for a path no image or frame can be read
// from.
[[nodiscard]] std::unique_ptr<CaptureSource> make_file_source(const FileSourceSettings& settings);

}  // namespace markerd::daemon
