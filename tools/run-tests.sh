#!/usr/bin/env bash
# The README's test command: installs the dependencies, checks the layout of
# the C++ files and runs clang-tidy's bug checks, builds with warnings as
# errors, runs every test, then builds again under AddressSanitizer and
# UndefinedBehaviorSanitizer and runs every test but the hardware-in-the-loop
# ones once more.
set -euo pipefail
cd "$(dirname "$0")/.."

bash tools/install-deps.sh
# The layout first: seconds, and a file .clang-format would change fails CI.
bash tools/check-format.sh
# clang-tidy's bug checks (.clang-tidy) on the product's code: a finding fails CI.
bash tools/check-tidy.sh

jobs=$(nproc)
# Line tables only (-g1), as in the sanitizer build: a failure's backtrace
# still names function and line, and the build is about a quarter faster than
# with full debug information.
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
  -DMARKERD_WERROR=ON
cmake --build build -j"$jobs"
ctest --test-dir build -j"$jobs" --output-on-failure

# The sanitizer build skips the benchmarks (built above, never run by tests)
# and the hardware-in-the-loop tests: run above against the kernel's drivers
# under qemu, a second run costs CI five to ten minutes. The V4L2 and GPIO
# code they drive then runs unsanitized in CI; docs/hil.md has the command
# that runs them sanitized. Line tables only (-g1): the sanitizers' reports
# still name the function and line, and compiling is a tenth faster.
cmake -S . -B build-sanitize -G Ninja -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS_DEBUG=-g1 -DMARKERD_WERROR=ON \
  -DMARKERD_SANITIZE=ON -DMARKERD_BUILD_BENCH=OFF -DMARKERD_BUILD_HIL=OFF
cmake --build build-sanitize -j"$jobs"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-sanitize -j"$jobs" --output-on-failure
