// The frame8 detector on arbitrary pixels, at arbitrary sizes up to VGA.
//
// Input: a 9-byte header, then pixels.
//   0-1  width - 1 (little endian, modulo 640)     2-3  height - 1 (modulo 480)
//   4    bit 0: with the camera model and a marker size (the pose path)
//        bit 1: uniform_ids   bit 2: model_small_cells   bit 3: rows padded
//        bits 4-7: decimate (modulo 9: 0 automatic .. 8)
//   5    threshold_offset - 1 (modulo 100)   6  min_hole_side_px - 2
//   7    min_margin * 255                    8  blur_sigma_px * 51
// The options span the ranges the detector accepts (markerd's config
// accepts more: docs/fuzzing.md, findings). The pixels repeat
// to fill the image (none: a black one). The image lies in a buffer of
// exactly its size, so that a read past its last pixel is a sanitizer
// report. Every option set must give a detector, and what it reports must
// be a marker: a valid id, finite corners, a margin in [0, 1], a finite pose.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include <fmt/format.h>

#include "fuzz_support.hpp"
#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"

namespace {

constexpr std::size_t kHeaderBytes = 9;
constexpr int kMaxWidth = 640;
constexpr int kMaxHeight = 480;

bool finite(const markerd::detector::Quad& quad) {
  return std::all_of(quad.begin(), quad.end(),
                     [](const markerd::detector::Point2& p) { return std::isfinite(p.x) && std::isfinite(p.y); });
}

void check(const markerd::detector::Detection& d, int width, int height) {
  using markerd::fuzz::finding;
  if (d.family != markerd::detector::Family::frame8)
    finding(fmt::format("a frame8 detector reported family {}", static_cast<int>(d.family)));
  if (d.id < 0 || d.id >= markerd::detector::family_info(markerd::detector::Family::frame8).id_count)
    finding(fmt::format("id {} reported", d.id));
  if (!finite(d.corners)) finding(fmt::format("id {}: corners that are not finite ({}x{})", d.id, width, height));
  if (d.inner_corners && !finite(*d.inner_corners))
    finding(fmt::format("id {}: inner corners that are not finite", d.id));
  if (!(d.margin >= 0 && d.margin <= 1)) finding(fmt::format("id {}: margin {}", d.id, d.margin));
  if (d.pose) {
    const auto& t = d.pose->best.translation;
    if (!t.allFinite() || !d.pose->best.rotation.allFinite())
      finding(fmt::format("id {}: a pose that is not finite", d.id));
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < kHeaderBytes) return 0;
  const int width = 1 + (data[0] | (data[1] << 8)) % kMaxWidth;
  const int height = 1 + (data[2] | (data[3] << 8)) % kMaxHeight;
  const std::uint8_t flags = data[4];
  const bool with_pose = (flags & 1u) != 0;
  const bool padded = (flags & 8u) != 0;

  markerd::detector::DetectorConfig config;
  config.family = markerd::detector::Family::frame8;
  config.frame8.uniform_ids = (flags & 2u) != 0;
  config.frame8.model_small_cells = (flags & 4u) != 0;
  config.frame8.decimate = (flags >> 4) % 9;
  config.frame8.threshold_offset = 1 + data[5] % 100;
  config.frame8.min_hole_side_px = 2.0 + data[6];
  config.frame8.min_margin = data[7] / 255.0 * 0.99;
  config.frame8.blur_sigma_px = data[8] / 51.0;
  if (with_pose) {
    config.camera = markerd::detector::CameraModel::thesis_640x480().scaled_to(width, height);
    config.marker_size_m = 0.08;
  }

  const std::ptrdiff_t stride = width + (padded ? 13 : 0);
  const std::size_t bytes =
      static_cast<std::size_t>(stride) * static_cast<std::size_t>(height - 1) + static_cast<std::size_t>(width);
  const std::uint8_t* pixels = data + kHeaderBytes;
  const std::size_t pixel_count = size - kHeaderBytes;
  // Exactly the bytes the view spans, on the heap: ASan sees any read past them.
  const std::unique_ptr<std::uint8_t[]> buffer(new std::uint8_t[bytes]);
  for (std::size_t i = 0; i < bytes; ++i) buffer[i] = pixel_count == 0 ? 0 : pixels[i % pixel_count];

  const markerd::detector::GreyView view{buffer.get(), width, height, stride};
  const std::unique_ptr<markerd::detector::MarkerDetector> detector = markerd::detector::make_detector(config);
  std::vector<markerd::detector::Detection> found;
  detector->detect(view, found);
  for (const auto& d : found) check(d, width, height);
  return 0;
}
