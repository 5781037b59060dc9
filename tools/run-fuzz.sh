#!/usr/bin/env bash
# Builds the libFuzzer targets of fuzz/ (clang, ASan and UBSan: build-fuzz/)
# and runs them one after the other, each for --time seconds (default 60)
# or --runs executions, then prints the executions and findings of each.
#
#   tools/run-fuzz.sh                      every target, 60 s each
#   tools/run-fuzz.sh plan control --time 600
#   tools/run-fuzz.sh detector --runs 10000000
#   tools/run-fuzz.sh records --merge      also merge new coverage into fuzz/corpus/records
#   tools/run-fuzz.sh --keep-going         go on after a finding (libFuzzer's -fork=1)
#
# Each target fuzzes a working copy of its corpus (build-fuzz/corpus/<target>,
# seeded from fuzz/corpus/<target> and kept between runs); the repository's
# corpus changes only with --merge. A finding's input lands in
# fuzz/findings/<target>/ (crash-*, leak-*, timeout-*, oom-*; not committed).
# One fuzzer process at a time, no -jobs or -workers: the machine is shared.
# Exits 1 when any target had a finding. docs/fuzzing.md has the rest.
set -euo pipefail
cd "$(dirname "$0")/.."

all_targets=(daemon_config rig_config plan register_map camera_model control records detector)
targets=()
time_s=60
runs=
merge=0
keep_going=0
while [[ $# -gt 0 ]]; do
  case $1 in
    --time) time_s=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --merge) merge=1; shift ;;
    --keep-going) keep_going=1; shift ;;
    -h|--help) sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "run-fuzz: unknown option $1" >&2; exit 2 ;;
    *)
      if [[ ! " ${all_targets[*]} " =~ " $1 " ]]; then
        echo "run-fuzz: unknown target '$1' (targets: ${all_targets[*]})" >&2
        exit 2
      fi
      targets+=("$1"); shift ;;
  esac
done
[[ ${#targets[@]} -gt 0 ]] || targets=("${all_targets[@]}")

build=build-fuzz
# -O2 for speed, line tables for the sanitizers' reports, and assertions
# left on (no -DNDEBUG). No precompiled headers: this build is where a file
# that forgets an #include (and compiled only thanks to them) fails.
if [[ ! -f $build/CMakeCache.txt ]]; then
  CC=clang CXX=clang++ cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -gline-tables-only" \
    -DMARKERD_FUZZ=ON -DMARKERD_BUILD_TESTS=OFF -DMARKERD_BUILD_BENCH=OFF -DMARKERD_PCH=OFF
fi
cmake --build "$build" -j"${JOBS:-$(nproc)}" --target "${targets[@]/#/fuzz_}"

dictionary() {
  case $1 in
    daemon_config|rig_config|plan|register_map) echo fuzz/dict/toml.dict ;;
    control|records) echo fuzz/dict/json.dict ;;
    camera_model) echo fuzz/dict/camera.dict ;;
  esac
}

# Per target: what it needs beyond the defaults.
extra_args() {
  case $1 in
    # Room for 256x256 distinct pixels (smaller inputs repeat to fill any
    # size up to 640x480).
    detector) echo -max_len=65545 ;;
  esac
}

# The first line of a report, wherever libFuzzer's output put it.
finding_pattern='(runtime error: |ERROR: (Address|Leak|UndefinedBehavior)Sanitizer|ERROR: libFuzzer: (timeout|out-of-memory|deadly signal)|what\(\): |fuzz: finding: ).*'

summary=()
failed=0
for t in "${targets[@]}"; do
  work=$build/corpus/$t
  findings=fuzz/findings/$t
  log=$build/logs/$t.log
  mkdir -p "$work" "$findings" "$build/logs"
  cp -n fuzz/corpus/"$t"/* "$work"/ 2>/dev/null || true
  args=(-max_total_time="$time_s" -timeout=30 -rss_limit_mb=4096 -print_final_stats=1
        -artifact_prefix="$findings/")
  [[ -n $runs ]] && args+=(-runs="$runs")
  # shellcheck disable=SC2207
  args+=($(extra_args "$t"))
  # One child at a time, restarted after each finding, which it saves.
  [[ $keep_going -eq 1 ]] && args+=(-fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1)
  dict=$(dictionary "$t")
  [[ -n $dict ]] && args+=(-dict="$dict")
  list_findings() { find "$findings" -type f ! -name 'slow-unit-*' | sort; }
  before=$(list_findings)
  scratch=/dev/shm/markerd-fuzz-$t-$$
  echo "run-fuzz: $t (${runs:+$runs runs, at most }${time_s} s), log in $log"
  rc=0
  MARKERD_FUZZ_SCRATCH=$scratch \
    ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:symbolize=1 \
    UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    LSAN_OPTIONS=suppressions=$PWD/tests/lsan.supp \
    "$build/fuzz/fuzz_$t" "${args[@]}" "$work" >"$log" 2>&1 || rc=$?
  rm -rf "$scratch"
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  # -fork=1 prints no final stats: its last progress line counts every child's.
  [[ -n $execs && $execs != 0 ]] || execs=$(sed -n 's/^#\([0-9][0-9]*\): .*/\1/p' "$log" | tail -1)
  new_files=$(comm -13 <(echo "$before") <(list_findings) | sed '/^$/d')
  new=$(echo -n "$new_files" | grep -c . || true)
  if [[ $rc -ne 0 || $new -gt 0 ]]; then
    failed=1
    echo "run-fuzz: $t: FINDING (exit $rc): $(grep -m1 -oE "$finding_pattern" "$log" | cut -c1-300 || echo 'see the log')"
    [[ -n $new_files ]] && sed 's/^/run-fuzz:   input: /' <<<"$new_files"
  fi
  if [[ $merge -eq 1 ]]; then
    "$build/fuzz/fuzz_$t" -merge=1 ${dict:+-dict="$dict"} fuzz/corpus/"$t" "$work" >>"$log" 2>&1 || true
  fi
  summary+=("$(printf '%-14s %12s executions  %s finding(s)  corpus %s inputs' "$t" "${execs:-?}" "$new" \
    "$(find "$work" -type f | wc -l)")")
done

echo
printf 'run-fuzz: %s\n' "${summary[@]}"
exit "$failed"
