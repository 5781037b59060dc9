#pragma once
// One interface for every marker family. A detector owns its working memory:
// after the first frames of a given size, detect() allocates nothing (the
// output vector keeps its capacity). A detector is not thread-safe; run one
// per worker thread.

#include <cstdint>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detection.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"

namespace markerd::detector {

class DetectorError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// What a frame8 print is mounted on, as far as finding it goes: each
// mounting shows the hole its own way, and the detector searches only for
// the ways the mounting it is told can (docs/architecture.md, "What each
// mounting is searched for"). Not told, it searches for all of them.
enum class Mounting : std::uint8_t {
  any,          // every search: the mounting is not known
  paper,        // flat, the hole printed white: a light quad enclosed by the line
  cover_frame,  // cut out and glued onto a socket's or a switch's rounded frame
  cut_hole,     // flat, the hole cut out: whatever lies behind shows through
};

struct Frame8Options {
  // The ranges the detector accepts, which markerd's config enforces too.
  static constexpr int kMinThresholdOffset = 1;
  static constexpr int kMaxThresholdOffset = 100;
  static constexpr double kMaxBlurSigmaPx = 5.0;

  // Segmentation runs on the image decimated by this factor; 0 picks one from
  // the image size (1 up to about 1 MP, then 2). Refinement and decoding
  // always use the full-resolution image.
  int decimate = 0;
  // Adaptive threshold: a pixel is dark when it is this many grey levels
  // below the mean of its neighbourhood.
  int threshold_offset = 6;
  // Smallest hole side, in full-resolution pixels, that is worth decoding
  // (the long side; the short side, of a marker turned far, may be 2 px less).
  double min_hole_side_px = 5.0;
  // Least decoding margin (0..1) that a detection must reach.
  double min_margin = 0.12;
  // Report ids 0 and 255. Their rings have no structure: a dark square frame
  // with one light corner reads as 0, a light outline with three dark
  // corners as 255, and cluttered scenes hold such shapes (measured: about
  // one cluttered frame in a hundred gives a 0). Off unless a rig uses them.
  bool uniform_ids = false;
  // Read cells under about three pixels, where sampling fails, by fitting a
  // model of the blurred ring to the pixels (levels and map together). A
  // fit costs a few million instructions, and clutter offers several
  // candidates a frame that reach it, so the model reads only in a look of
  // its own, taken where every other look found nothing (docs/
  // architecture.md, stage 4). Measured (100 frames a point, the print
  // with its margin): 97% at 2.7 m against 86% without it.
  bool model_small_cells = true;
  // The camera's blur as a Gaussian sigma in pixels, on top of each pixel's
  // own area, for that model; a focused lens is about 0.5 to 1.
  double blur_sigma_px = 0.6;
  // What the print is mounted on. Told `paper`, the detector leaves out the
  // searches for a hole displaced by a frame's roll, parted by what shows
  // through it, or no lighter than the line: on bench_detect's flat
  // markers in clutter, half its time.
  Mounting mounting = Mounting::any;
  // Debug output, for when a marker is not found: empty is off. Otherwise a
  // directory (created if missing) into which every detect() call n (from 0)
  // writes NNNN-threshold.png (the working image's light pixels, white;
  // NNNN-threshold-second.png too where a second look was taken),
  // NNNN-candidates.png (each candidate's quad on the image: green read,
  // red rejected, with its index) and NNNN-candidates.json (per candidate
  // its corners, and for a rejected one the stage and the reason, with
  // every read tried). Slow and allocating: never in a measurement.
  std::string debug_dir;
};

struct DetectorConfig {
  Family family = Family::frame8;
  Frame8Options frame8;
  // With both, every detection carries its pose.
  std::optional<CameraModel> camera;
  double marker_size_m = 0;  // family's "size" (see FamilyInfo)
};

class MarkerDetector {
 public:
  virtual ~MarkerDetector() = default;
  [[nodiscard]] virtual Family family() const = 0;
  // Appends nothing and clears `out` when nothing is found. Throws
  // DetectorError for an empty image or a camera model of another size.
  virtual void detect(const GreyView& image, std::vector<Detection>& out) = 0;
};

std::unique_ptr<MarkerDetector> make_detector(const DetectorConfig& config);

}  // namespace markerd::detector
