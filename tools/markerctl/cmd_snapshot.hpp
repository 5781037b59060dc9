#pragma once
// markerctl snapshot: markerd's newest frame saved as an image file.

#include "common.hpp"

namespace markerctl {

void add_snapshot_command(CLI::App& parent, Commands& commands);

}  // namespace markerctl
