# Setup step: the host tree's systemd-udevd, running in the guest for as
# long as the command does. libcamera lists only the devices that udev has
# initialised (its database under /run/udev) and learns of a camera plugged
# in or pulled out only from udev's events; without udevd it would see
# neither. Give it before the steps that make the devices.
#
#   --setup udevd
#
# Exports:
#   HIL_UDEVD_PID   systemd-udevd's process id in the guest
set -e

udevd=/lib/systemd/systemd-udevd
# (A link to /bin/udevadm: looked at from inside the host's tree.)
chroot "$HIL_HOST" test -x "$udevd" || {
  echo "udevd: no $udevd in the host's tree (tools/install-deps.sh installs udev)" >&2
  exit 1
}
# Under chroot: the host tree's rules and helpers, the command's /run (a
# tmpfs) for the database and the control socket.
chroot "$HIL_HOST" "$udevd" --resolve-names=never </dev/null >"$HIL_HOST/run/udevd.log" 2>&1 &
pid=$!
waited=0
until [ -S "$HIL_HOST/run/udev/control" ]; do
  if ! kill -0 "$pid" 2>/dev/null || [ "$waited" -ge 300 ]; then
    echo "udevd: systemd-udevd did not start; its output:" >&2
    cat "$HIL_HOST/run/udevd.log" >&2
    exit 1
  fi
  sleep 0.1
  waited=$((waited + 1))
done
# What the modules made before udevd ran: announced again, as at boot.
chroot "$HIL_HOST" udevadm trigger --action=add --type=subsystems
chroot "$HIL_HOST" udevadm trigger --action=add --type=devices
chroot "$HIL_HOST" udevadm settle --timeout=120 || { echo "udevd: the boot's events did not settle in 120 s" >&2; exit 1; }
echo "export HIL_UDEVD_PID=$pid" >>"$HIL_ENV"
echo "udevd: systemd-udevd running, pid $pid"
