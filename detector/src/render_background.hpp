#pragma once
// The background behind the marker (internal to the renderer): the random
// shapes, the marker-like textures of Background, or a flat grey.
// render.cpp draws the marker over it, then blurs, adds noise and encodes.

#include <opencv2/core.hpp>

#include "markerd/detector/render.hpp"

namespace markerd::detector::render {

// The scene's background at width x height in grey levels: 8-bit when
// cluttered, float when flat (background_grey need not be a whole level).
// Deterministic for scene.seed.
cv::Mat make_background(int width, int height, const Scene& scene);

}  // namespace markerd::detector::render
