#!/usr/bin/env bash
# Applies uvc.patch to Debian's dummy_hcd.c. Runs in the build directory.
# Without fuzz, so that a kernel whose dummy_hcd.c changed around the edits
# fails here rather than building a module that was never checked.
set -euo pipefail

patch -p1 --fuzz=0 --no-backup-if-mismatch <"$HIL_RECIPE/uvc.patch"
