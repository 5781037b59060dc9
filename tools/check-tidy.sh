#!/usr/bin/env bash
# Runs clang-tidy (Debian's clang-tidy 14) with the checks of .clang-tidy on
# the product's own code: base, detector, rig, sweep, daemon and tools. Every
# finding is an error; tools/run-tests.sh (and so CI) runs this.
#
#   tools/check-tidy.sh [FILE-REGEX]   default: every product source file
#
# The tests, benchmarks and fuzz targets are left out: at five to fifteen
# seconds a file (clang parses OpenCV, Eigen and spdlog for each) they would
# double the check's part of a CI run, and their code runs under the
# sanitizers in the tests instead.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
build=build-tidy

# A compile database of its own: the normal build's has GCC's precompiled
# headers in its commands, which clang cannot read. Configuring only; nothing
# is compiled.
cmake -S . -B "$build" -G Ninja -DCMAKE_EXPORT_COMPILE_COMMANDS=ON -DMARKERD_PCH=OFF \
  -DMARKERD_BUILD_TESTS=OFF -DMARKERD_BUILD_BENCH=OFF >/dev/null

regex=${1:-"^$root/(base|detector|rig/src|sweep|daemon|tools)/.*\\.cpp\$"}
count=$(grep -oP '"file": "\K[^"]+' "$build/compile_commands.json" | grep -cE "$regex" || true)
echo "check-tidy: clang-tidy on $count files"
if ! run-clang-tidy -p "$build" -j "$(nproc)" -quiet "$regex" 2>&1 | sed 's/\x1b\[[0-9;]*m//g' >"$build/tidy.log"; then
  # Only the findings: clang-tidy also counts the warnings it suppressed in
  # system headers, file by file.
  grep -vE '^[0-9]+ warnings? (and [0-9]+ errors? )?generated\.$|^Suppressed [0-9]+ warnings|^Use -header-filter|^Running clang-tidy|^clang-tidy-14 |^$' \
    "$build/tidy.log" >&2 || true
  echo "check-tidy: findings above (the checks are in .clang-tidy; a false finding gets a NOLINT(check) with its reason)" >&2
  exit 1
fi
echo "check-tidy: no findings"
