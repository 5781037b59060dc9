#pragma once
// markerctl snapshot: markerd's newest frame saved as an image file.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common.hpp"

namespace markerctl {

void add_snapshot_command(CLI::App& parent, Commands& commands);

// The image bytes of a `snapshot` reply (its base64 `image.data`), checked
// against the size the reply announces. CommandError in `context` when they
// do not decode to that size.
std::vector<std::uint8_t> snapshot_image_bytes(const nlohmann::json& reply, const std::string& context);

}  // namespace markerctl
