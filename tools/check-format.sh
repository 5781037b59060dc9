#!/usr/bin/env bash
# Checks that every C++ file of the project is laid out as .clang-format says
# (clang-format 14, Debian's; tools/run-tests.sh runs it first). With --fix,
# reformats them instead.
#
#   tools/check-format.sh          exit 1 and list the files that differ
#   tools/check-format.sh --fix    reformat them in place
set -euo pipefail
cd "$(dirname "$0")/.."

fix=0
[[ ${1:-} == --fix ]] && fix=1
mapfile -t files < <(git ls-files '*.cpp' '*.hpp' '*.h' ':!:fuzz/corpus/**')
if [[ $fix -eq 1 ]]; then
  clang-format -i --style=file "${files[@]}"
  exit 0
fi
bad=()
for f in "${files[@]}"; do
  clang-format --style=file --dry-run --Werror "$f" >/dev/null 2>&1 || bad+=("$f")
done
if [[ ${#bad[@]} -gt 0 ]]; then
  echo "check-format: ${#bad[@]} file(s) not laid out as .clang-format says (tools/check-format.sh --fix):" >&2
  printf '  %s\n' "${bad[@]}" >&2
  exit 1
fi
echo "check-format: ${#files[@]} files as .clang-format says"
