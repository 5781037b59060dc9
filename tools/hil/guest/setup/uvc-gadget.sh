# Setup step: a USB webcam that the guest presents to itself. A UVC gadget
# (configfs, usb_f_uvc) on the emulated controller dummy_hcd is enumerated by
# the kernel's own uvcvideo, with a frame server from the host's tree behind
# it. Needs --module dummy_hcd (tools/hil/modules/dummy_hcd/, isochronous
# transfers emulated), --module usb_f_uvc and --module uvcvideo.
#
#   --setup 'uvc-gadget SERVER [ARG...]'
#
# SERVER (a path in the host's tree) runs in the background under chroot
# with --device <the gadget's output node> --out-dir <HIL_UVC_SERVER_DIR>
# and ARG...; it must subscribe to the gadget's UVC events, which is what
# connects the gadget to the bus (tests/hil/uvc_gadget_server.cpp). It keeps
# running while the command does.
#
# The gadget: YUYV and MJPEG, each 640x480 at 30 and 15 frames per second
# (intervals 333333 and 666666 in 100 ns units), isochronous packets of up to
# 3 x 1024 bytes,
# and usb_f_uvc's default controls (the camera terminal's auto-exposure mode,
# the processing unit's brightness).
#
# libcamera sees only devices that udev has initialised, and learns of an
# unplug and a replug from udev's events: give --setup udevd first.
#
# Exports:
#   HIL_UVC_CAPTURE        the camera's capture node on the host side, e.g. /dev/video1
#   HIL_UVC_MEDIA          its media controller node, e.g. /dev/media0
#   HIL_UVC_OUTPUT         the gadget's output node, where the server writes frames
#   HIL_UVC_GADGET         the gadget's configfs directory: writing "" to its
#                          UDC unplugs the camera, writing HIL_UVC_UDC to it
#                          plugs it in again
#   HIL_UVC_UDC            the controller the gadget is bound to (dummy_udc.0)
#   HIL_UVC_SERVER_DIR     the server's records (frames.jsonl, controls.jsonl)
#   HIL_UVC_SERVER_LOG     its standard output and error
#   HIL_UVC_SERVER_PID     its process id in the guest
set -e

if [ $# -lt 1 ]; then
  echo "uvc-gadget: usage: uvc-gadget SERVER [ARG...]" >&2
  exit 2
fi
server=$1
shift
[ -x "$HIL_HOST$server" ] || { echo "uvc-gadget: no server $server in the host's tree" >&2; exit 1; }
[ -S "$HIL_HOST/run/udev/control" ] || { echo "uvc-gadget: no udevd running (give --setup udevd first)" >&2; exit 1; }

udc=dummy_udc.0
[ -e "/sys/class/udc/$udc" ] || { echo "uvc-gadget: no $udc (load the dummy_hcd module)" >&2; exit 1; }
gadgets=/sys/kernel/config/usb_gadget
[ -d "$gadgets" ] || { echo "uvc-gadget: no $gadgets (load libcomposite)" >&2; exit 1; }

# Every attribute is written before anything is linked: usb_f_uvc refuses
# changes (EBUSY) to a format, frame or header that is linked.
g=$gadgets/markerd
mkdir "$g"
echo 0x1d6b >"$g/idVendor"   # Linux Foundation
echo 0x0104 >"$g/idProduct"  # Multifunction Composite Gadget
echo 0x0100 >"$g/bcdDevice"
mkdir "$g/strings/0x409"
echo markerd >"$g/strings/0x409/manufacturer"
echo "markerd HIL webcam" >"$g/strings/0x409/product"
echo hil0001 >"$g/strings/0x409/serialnumber"

f=$g/functions/uvc.0
mkdir "$f"
echo 3072 >"$f/streaming_maxpacket"
mkdir "$f/control/header/h"
# The same frame size and intervals in both formats; an MJPEG frame's
# buffer is the size of a YUYV one.
for frame in "$f/streaming/uncompressed/u/480p" "$f/streaming/mjpeg/m/480p"; do
  mkdir -p "$frame"
  echo 640 >"$frame/wWidth"
  echo 480 >"$frame/wHeight"
  echo 614400 >"$frame/dwMaxVideoFrameBufferSize"
  echo 333333 >"$frame/dwDefaultFrameInterval"
  printf '333333\n666666\n' >"$frame/dwFrameInterval"
  echo $((640 * 480 * 16 * 15)) >"$frame/dwMinBitRate"
  echo $((640 * 480 * 16 * 30)) >"$frame/dwMaxBitRate"
done
mkdir "$f/streaming/header/h"

ln -s "$f/control/header/h" "$f/control/class/fs/h"
ln -s "$f/control/header/h" "$f/control/class/ss/h"
# The order of these links numbers the formats: YUYV 1, MJPEG 2 (the
# server's bFormatIndex).
ln -s "$f/streaming/uncompressed/u" "$f/streaming/header/h/u"
ln -s "$f/streaming/mjpeg/m" "$f/streaming/header/h/m"
for speed in fs hs ss; do ln -s "$f/streaming/header/h" "$f/streaming/class/$speed/h"; done

mkdir -p "$g/configs/c.1/strings/0x409"
echo "UVC camera" >"$g/configs/c.1/strings/0x409/configuration"
echo 500 >"$g/configs/c.1/MaxPower"
ln -s "$f" "$g/configs/c.1/uvc.0"
echo "$udc" >"$g/UDC"

# The function's video node sits under the UDC's gadget device; uvcvideo's
# (once enumerated) under the USB interface it bound to.
output=
for node in /sys/class/video4linux/video*; do
  [ -e "$node" ] || continue
  case $(readlink -f "$node") in
    */"$udc"/*) output=/dev/${node##*/} ;;
  esac
done
[ -n "$output" ] || { echo "uvc-gadget: usb_f_uvc made no video node under $udc" >&2; exit 1; }

dir=/run/markerd-hil/uvc-gadget
mkdir -p "$HIL_HOST$dir"
log=$dir/server.log
chroot "$HIL_HOST" "$server" --device "$output" --out-dir "$dir" "$@" </dev/null >"$HIL_HOST$log" 2>&1 &
pid=$!

# The server renders its frames before it connects the gadget: seconds under
# TCG, more on a loaded host.
capture=
waited=0
while [ -z "$capture" ]; do
  for node in /sys/class/video4linux/video*; do
    # index 0: uvcvideo's capture node, not its metadata node
    [ -e "$node/index" ] || continue
    [ "$(cat "$node/index")" = 0 ] || continue
    driver=$(readlink -f "$node/device/driver" 2>/dev/null || true)
    if [ "${driver##*/}" = uvcvideo ]; then capture=/dev/${node##*/}; fi
  done
  [ -n "$capture" ] && break
  if ! kill -0 "$pid" 2>/dev/null; then
    echo "uvc-gadget: the server $server exited; its output:" >&2
    cat "$HIL_HOST$log" >&2
    exit 1
  fi
  if [ "$waited" -ge 1200 ]; then
    echo "uvc-gadget: uvcvideo found no camera within 120 s; the server's output:" >&2
    cat "$HIL_HOST$log" >&2
    exit 1
  fi
  sleep 0.1
  waited=$((waited + 1))
done

interface=$(readlink -f "/sys/class/video4linux/${capture#/dev/}/device")
media=
for node in "$interface"/media*; do
  [ -e "$node/dev" ] && media=/dev/${node##*/}
done
[ -n "$media" ] || { echo "uvc-gadget: no media node under $interface" >&2; exit 1; }

# libcamera lists the camera once udev has initialised its nodes.
chroot "$HIL_HOST" udevadm settle --timeout=120 || { echo "uvc-gadget: udev did not settle in 120 s" >&2; exit 1; }

{
  echo "export HIL_UVC_CAPTURE=$capture"
  echo "export HIL_UVC_MEDIA=$media"
  echo "export HIL_UVC_OUTPUT=$output"
  echo "export HIL_UVC_GADGET=$g"
  echo "export HIL_UVC_UDC=$udc"
  echo "export HIL_UVC_SERVER_DIR=$dir"
  echo "export HIL_UVC_SERVER_LOG=$log"
  echo "export HIL_UVC_SERVER_PID=$pid"
} >>"$HIL_ENV"
echo "uvc-gadget: camera $capture ($media, $interface), gadget output $output, server pid $pid"
