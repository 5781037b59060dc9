#!/usr/bin/env bash
# Checks a service unit as CI does: `systemd-analyze verify` has
# nothing to say about it, and `systemd-analyze security --offline=yes` rates
# its overall exposure at most MAX (default 2.5). Prints the security table
# either way, so that a failure shows which settings cost what.
#
#   check-unit.sh UNIT_FILE [MAX]
#
# Exit status 0 when both hold, 1 otherwise (the reason on the last line).
set -euo pipefail

fail() {
  echo "check-unit: FAIL: $*"
  exit 1
}

[[ $# -ge 1 && $# -le 2 ]] || { echo "usage: check-unit.sh UNIT_FILE [MAX]" >&2; exit 2; }
unit=$(realpath "$1")
max=${2:-2.5}
name=$(basename "$unit")
[[ -f $unit ]] || fail "no unit file $unit"
[[ $max =~ ^[0-9]+(\.[0-9])?$ ]] || fail "MAX must be an exposure with at most one decimal, such as 2.5, got '$max'"
command -v systemd-analyze >/dev/null ||
  fail "systemd-analyze not found: it comes with Debian's package systemd (tools/install-deps.sh installs it)"
export SYSTEMD_COLORS=0 SYSTEMD_PAGER=

# The programs the unit starts must exist for verify: the tests' copy of the
# unit names the built markerd.
while read -r program; do
  [[ -x $program ]] || fail "$name starts $program, which does not exist or is not executable (build it first)"
done < <(sed -n 's/^Exec[A-Za-z]*=[-@:+!]*\([^ ]*\).*/\1/p' "$unit" | sort -u)

# verify exits 0 even when it ignores an unknown key or a value it cannot
# parse, so any line it prints about this unit is a failure. Lines about
# other units (the system's own, pulled in as dependencies) are shown only.
verify_rc=0
verify_output=$(systemd-analyze verify --man=no "$unit" 2>&1) || verify_rc=$?
ours=$(grep -F -e "$unit" -e "$name:" <<<"$verify_output" || true)
others=$(grep -v -F -e "$unit" -e "$name:" <<<"$verify_output" || true)
[[ -z $others ]] || printf 'check-unit: note from systemd-analyze verify, about other units:\n%s\n' "$others"
if [[ -n $ours || $verify_rc -ne 0 ]]; then
  printf '%s\n' "$verify_output"
  fail "systemd-analyze verify $name (exit $verify_rc)"
fi
echo "check-unit: systemd-analyze verify $name: clean"

# --threshold takes the exposure in tenths and makes the command fail above
# it; the overall line is read as well, so that a failure says by how much
# and an error of the command itself is not mistaken for a rating.
threshold=$(awk -v m="$max" 'BEGIN { printf "%d", m * 10 + 0.5 }')
security_rc=0
table=$(systemd-analyze security --no-pager --offline=yes --threshold="$threshold" "$unit" 2>&1) || security_rc=$?
printf '%s\n' "$table"
exposure=$(sed -n 's/.*Overall exposure level for [^:]*: \([0-9][0-9.]*\).*/\1/p' <<<"$table")
[[ -n $exposure ]] || fail "systemd-analyze security printed no overall exposure (exit $security_rc)"
if awk -v e="$exposure" -v m="$max" 'BEGIN { exit !(e > m) }'; then
  fail "$name: exposure $exposure is above $max"
fi
[[ $security_rc -eq 0 ]] || fail "systemd-analyze security exited $security_rc at exposure $exposure"
echo "check-unit: $name: exposure $exposure, at most $max"
