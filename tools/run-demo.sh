#!/usr/bin/env bash
# The README's main job: installs the dependencies, builds, and runs the
# thesis's experiments unattended on the simulated rig. markerd starts with
# the simulated camera, rail and turntable (config/markerd-sim.toml, its rig
# time-scaled so the run takes a few minutes), markerctl starts the plan
# config/plans/thesis.toml (the viewing-angle sweeps at 50 and 95 cm and the
# distance sweep, five measurements per point) and follows it, and
# markerctl report writes the report with its plots and prints Table 6.1.
#
#   bash tools/run-demo.sh [PLAN...] [--config FILE] [--time-scale N]
#
# Several plans run one after the other on the same markerd. --config runs
# another simulated config (config/markerd-sim-socket.toml: the marker on a
# socket frame, for the plans config/plans/thesis-socket-*.toml).
# Everything it writes is under build/demo/ (build/demo-CONFIG/ for another
# config: config, logs, run records, report); markerd is stopped when the
# script ends, however it ends.
set -euo pipefail
cd "$(dirname "$0")/.."
top=$PWD

plans=()
config=config/markerd-sim.toml
time_scale=20
while [[ $# -gt 0 ]]; do
  case $1 in
    --time-scale) time_scale=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    -h|--help) sed -n '2,18p' "$0"; exit 0 ;;
    *) plans+=("$1"); shift ;;
  esac
done
[[ ${#plans[@]} -gt 0 ]] || plans=(config/plans/thesis.toml)
[[ -f $config ]] || { echo "run-demo: --config $config: no such file" >&2; exit 1; }

bash tools/install-deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j"$(nproc)" --target markerd markerctl

demo=$top/build/demo
# Another config's runs go beside the default's, so that both can be reported together.
[[ $config -ef config/markerd-sim.toml ]] || demo=$top/build/demo-$(basename "$config" .toml)
rm -rf "$demo"
mkdir -p "$demo/logs" "$demo/state"
# The shipped simulated rig, with its simulated time running faster than
# real time: moves and homing shrink, frames still come at the camera's rate.
sed "s/^time_scale = .*/time_scale = $time_scale/" config/rig-sim.toml > "$demo/rig-sim.toml"
grep -q "^time_scale = $time_scale" "$demo/rig-sim.toml" || { echo "run-demo: config/rig-sim.toml has no time_scale line" >&2; exit 1; }
# The config (config/markerd-sim.toml) with this directory's rig, logs,
# state and socket in place of systemd's directories.
sed -e "s|^rig = .*|rig = \"rig-sim.toml\"|" \
    -e "s|^model = \"cameras/|model = \"$top/config/cameras/|" \
    -e "s|^group = .*||" \
    "$config" > "$demo/markerd.toml"
sed -i -e '/^\[log\]/a directory = "logs"' -e '/^\[control\]/a socket = "control.sock"' \
       -e '/^\[sweep\]/a directory = "state"' "$demo/markerd.toml"
for table in log control sweep; do
  grep -q "^\[$table\]" "$demo/markerd.toml" || { echo "run-demo: $config has no [$table] table" >&2; exit 1; }
done

markerctl=$top/build/tools/markerctl
export MARKERD_SOCKET=$demo/control.sock
"$top/build/daemon/markerd" --config "$demo/markerd.toml" > "$demo/markerd.log" 2>&1 &
markerd_pid=$!
trap 'kill "$markerd_pid" 2>/dev/null; wait "$markerd_pid" 2>/dev/null || true' EXIT
for _ in $(seq 100); do
  [[ -S $MARKERD_SOCKET ]] && break
  kill -0 "$markerd_pid" 2>/dev/null || { cat "$demo/markerd.log" >&2; exit 1; }
  sleep 0.1
done

run_dirs=()
for plan in "${plans[@]}"; do
  echo "== dry run: $plan"
  "$markerctl" sweep check "$plan"
  echo "== the sweep (markerd's log: $demo/markerd.log)"
  "$markerctl" sweep start --wait "$plan"
  run_dirs+=("$(ls -d "$demo"/state/runs/*/ | tail -1)")
done
echo "== report"
if [[ ${#run_dirs[@]} -eq 1 ]]; then
  "$markerctl" report "${run_dirs[0]}"
else
  "$markerctl" report -o "$demo/report" "${run_dirs[@]}"
fi
