#!/usr/bin/env bash
# Installs everything markerd builds, tests and benchmarks with, from Debian's
# archive (bookworm). Idempotent: apt-get skips what is already installed, and
# the package lists are refreshed only when they are missing or a day old.
set -euo pipefail

packages=(
  # toolchain
  build-essential cmake pkg-config ninja-build git
  # required libraries
  libopencv-dev libopencv-contrib-dev libeigen3-dev libspdlog-dev libfmt-dev
  libgpiod-dev libmodbus-dev libcamera-dev libsystemd-dev
  # detector peers and file formats
  libapriltag-dev libcairo2-dev libturbojpeg0-dev
  # PNG files read with libpng's own API (its messages caught): image_file.cpp
  libpng-dev
  # command line, config, JSON
  libcli11-dev libtomlplusplus-dev nlohmann-json3-dev
  # camera files (OpenCV's calibration YAML and ROS's camera_info):
  # detector/src/camera_model.cpp
  libyaml-cpp-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # peers for the rig's tests: a serial line pair for Modbus RTU, a Modbus
  # server this project did not write (for Debian's /usr/bin/python3)
  socat python3-pymodbus
  # pymodbus 3.0's server module imports pyserial and serial_asyncio (its
  # Recommends, which --no-install-recommends leaves out)
  python3-serial python3-serial-asyncio
  # hardware-in-the-loop tests: Debian's kernel under qemu, a busybox initramfs
  qemu-system-x86 busybox-static cpio
  # libjpeg's own API, for the emulated webcam's MJPEG (restart markers,
  # which TurboJPEG 2.1 cannot write: tests/hil/stamped_jpeg.hpp)
  libjpeg-dev
  # v4l2-ctl, the reference reader bench/bench_v4l2_capture.cpp measures
  # markerd's V4L2 capture path against inside the guest
  v4l-utils
  # systemd-udevd, run inside the guest: libcamera learns of cameras plugged
  # in and pulled out only from udev's events
  udev
  # the service's tests: systemd-analyze (verify, security), systemd-sysusers
  # and systemd-tmpfiles, which a container image may lack
  systemd
  # the layout and bug checks of tools/run-tests.sh (tools/check-format.sh,
  # tools/check-tidy.sh)
  clang-format clang-tidy
  # the fuzz build (tools/run-fuzz.sh): clang and its runtime libraries,
  # libFuzzer among them
  clang libclang-rt-14-dev
  # the man pages' tests (tests/manpages/, tests/systemd/check-install.sh):
  # man and lexgrog render and index them, groff with its warnings; a
  # container image may lack both
  man-db groff-base
  # markerd's web page (daemon/src/web/, docs/web.md): cpp-httplib; and the
  # page's test in a real browser (tests/web/check_page.py), headless
  libcpp-httplib-dev chromium
  # the sweep reports' plots (markerctl report, test_sweep_summary): gnuplot
  # renders SVG and PDF (its pdfcairo terminal) from the scripts the report
  # writes; -nox leaves out X and Qt
  gnuplot-nox
  # the report's PDF plots read back as a PDF reader sees them (pdfinfo,
  # pdftotext: test_sweep_summary)
  poppler-utils
  # markerctl's live lines as a user sees them (test_markerctl_rig,
  # test_control_streams): the tests run it inside tmux at 80x24 and read the
  # screen back, which a pipe cannot show; without tmux they fail
  tmux
  # a sweep run's Bluesky documents checked against the event model's JSON
  # schemas (tests/bluesky/check_documents.py, run by test_sweep_run and
  # test_sweep_kill with Debian's /usr/bin/python3)
  python3-jsonschema
)

if [[ $(id -u) -ne 0 ]]; then
  sudo=sudo
else
  sudo=
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
if [[ ${#missing[@]} -eq 0 ]]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

lists=/var/lib/apt/lists
if [[ -z $(find "$lists" -maxdepth 1 -name '*Packages*' -mmin -1440 2>/dev/null | head -1) ]]; then
  $sudo apt-get update -qq
fi
echo "install-deps: installing ${missing[*]}"
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
