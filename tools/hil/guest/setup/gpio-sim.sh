# Setup step: one simulated GPIO chip (needs --module gpio-sim).
#
#   --setup 'gpio-sim NAME LINE...'   one line per LINE: its name, or "-" for
#                                     an unnamed line
#   --setup 'gpio-sim NAME COUNT'     COUNT unnamed lines
#
# The chip's label is NAME, so it can be found by label as well as by path.
# Exports, with NAME upper-cased and dashes made underscores:
#   HIL_GPIO_SIM_<NAME>_CHIP   the character device, e.g. /dev/gpiochip0
#   HIL_GPIO_SIM_<NAME>_SYSFS  the simulator's directory, whose sim_gpio<K>/
#                              value (read) and pull (write "pull-up" or
#                              "pull-down") stand for line K's far end
set -e

if [ $# -lt 2 ]; then
  echo "gpio-sim: usage: gpio-sim NAME LINE... | NAME COUNT" >&2
  exit 2
fi
name=$1
shift

device=/sys/kernel/config/gpio-sim/$name
bank=$device/bank0
mkdir "$device" "$bank"
echo "$name" >"$bank/label"

if [ $# -eq 1 ] && [ -n "${1##*[!0-9]*}" ]; then
  echo "$1" >"$bank/num_lines"
else
  offset=0
  for line in "$@"; do
    if [ "$line" != - ]; then
      mkdir "$bank/line$offset"
      echo "$line" >"$bank/line$offset/name"
    fi
    offset=$((offset + 1))
  done
  echo "$offset" >"$bank/num_lines"
fi
echo 1 >"$device/live"

chip=$(cat "$bank/chip_name")
sysfs=/sys/devices/platform/$(cat "$device/dev_name")/$chip
[ -c "/dev/$chip" ] || { echo "gpio-sim: /dev/$chip did not appear" >&2; exit 1; }
[ -d "$sysfs" ] || { echo "gpio-sim: $sysfs did not appear" >&2; exit 1; }

var=HIL_GPIO_SIM_$(echo "$name" | tr 'a-z-' 'A-Z_')
echo "export ${var}_CHIP=/dev/$chip" >>"$HIL_ENV"
echo "export ${var}_SYSFS=$sysfs" >>"$HIL_ENV"
echo "gpio-sim: $name is /dev/$chip ($sysfs), $(cat "$bank/num_lines") lines"
