#!/usr/bin/env bash
# The README's main job: installs the dependencies, builds, and runs the
# end-to-end demonstration of the detector: markers rendered through the
# thesis's camera at several distances and viewing angles, detected, and
# summed up as tables, frame8 beside ArUco and AprilTag. Extra arguments go
# to `markerctl evaluate`.
set -euo pipefail
cd "$(dirname "$0")/.."

bash tools/install-deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j"$(nproc)" --target markerctl
./build/tools/markerctl evaluate --family all "$@"
