# Setup step: vivid's capture and output nodes, for video looped from one to
# the other (needs --module 'vivid ...' with node_types=0x101: one capture and
# one output node).
#
#   --setup vivid-loop
#
# Exports:
#   HIL_VIVID_CAPTURE   the capture node, e.g. /dev/video0
#   HIL_VIVID_OUTPUT    the output node, e.g. /dev/video1
#   HIL_VIVID_PLATFORM  vivid's platform device (vivid.0): writing it to
#                       /sys/bus/platform/drivers/vivid/unbind removes the
#                       device under an open file, as an unplug would
#   HIL_VIVID_MODULE    a copy of vivid.ko in the command's /run, so that the
#                       command can load the module again (finit_module)
#                       after unloading it (delete_module)
#   HIL_VIVID_PARAMS    the parameters vivid was loaded with
set -e

capture=
output=
for node in /sys/class/video4linux/video*; do
  [ -e "$node/name" ] || continue
  case $(cat "$node/name") in
    vivid-*-vid-cap) capture=/dev/${node##*/} ;;
    vivid-*-vid-out) output=/dev/${node##*/} ;;
  esac
done
if [ -z "$capture" ] || [ -z "$output" ]; then
  echo "vivid-loop: no vivid capture and output nodes (load vivid with node_types=0x101)" >&2
  exit 1
fi
platform=$(basename "$(readlink -f "/sys/class/video4linux/${capture#/dev/}/device")")
[ -e "/sys/bus/platform/drivers/vivid/$platform" ] || {
  echo "vivid-loop: $capture's device $platform is not bound to the vivid driver" >&2
  exit 1
}

mkdir -p "$HIL_HOST/run/markerd-hil"
cp /hil/modules/vivid.ko "$HIL_HOST/run/markerd-hil/vivid.ko"
params=$(awk '$1 == "vivid.ko" { $1 = ""; sub(/^ +/, ""); print; exit }' /hil/modules.list)

{
  echo "export HIL_VIVID_CAPTURE=$capture"
  echo "export HIL_VIVID_OUTPUT=$output"
  echo "export HIL_VIVID_PLATFORM=$platform"
  echo "export HIL_VIVID_MODULE=/run/markerd-hil/vivid.ko"
  echo "export HIL_VIVID_PARAMS='$params'"
} >>"$HIL_ENV"
echo "vivid-loop: capture $capture, output $output, device $platform"
