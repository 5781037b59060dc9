#pragma once
// The V4L2 capture source (a UVC webcam, a capture card, vivid in the tests);
// its settings are in v4l2_settings.hpp, the listing of devices in
// v4l2_listing.hpp. See docs/capture.md.
//
// The source streams through mmap buffers. GREY frames, and the Y plane of
// NV12 frames, are lent to the pipeline without a copy: the frame points into
// the mmap buffer and its release hook queues the buffer again. YUYV frames
// are converted into the frame slot's own pixels and the buffer goes back at
// once. MJPEG frames are lent encoded: the pipeline worker that detects one
// decodes it into the slot's pixels and the buffer goes back then
// (Frame::set_encoded), so frames dropped while they wait are never decoded.

#include <filesystem>
#include <memory>
#include <string_view>

#include "markerd/daemon/capture/capture_source.hpp"
#include "markerd/daemon/capture/v4l2_settings.hpp"

namespace markerd::daemon {

// Throws std::runtime_error when TurboJPEG cannot start (MJPG only).
std::unique_ptr<CaptureSource> make_v4l2_source(const V4l2Settings& settings);

// The device node a configured name means: a path is taken as it is (a
// by-id or by-path link opens the node it points at); a bare name is looked
// up in <dev_dir>/v4l/by-id, then <dev_dir>/v4l/by-path. Throws CaptureError
// (not_found) naming both places when a bare name is in neither.
std::filesystem::path resolve_v4l2_device(std::string_view device, const std::filesystem::path& dev_dir = "/dev");

}  // namespace markerd::daemon
